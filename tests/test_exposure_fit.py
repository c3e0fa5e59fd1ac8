"""The real-data path as one call (fit_exposure), the neighbour masks of the star selection,
and the reserved stars' outlier screening."""

import warnings

import numpy as np
import pytest
from astropy.table import Table

from sklearn_psf import make_psf_field
from sklearn_psf.exposure import (ExposureFit, SelectionCuts, StarSelectionError, fit_exposure,
                                  neighbour_masks, predict_catalog, read_exposure,
                                  select_stars)
from sklearn_psf.io import InputError
from sklearn_psf.validation import fit_and_validate


def _field(seed=3, n_stars=200):
    field = make_psf_field(n_stars=n_stars, n_galaxies=1, image_shape=(2000, 2000),
                           random_state=seed)
    stamps, weights, _ = field.star_stamps(normalize=False, return_weights=True)
    return np.column_stack([field.stars["x"], field.stars["y"]]), stamps, weights


def _e_rms(table):
    ok = np.asarray(table["flag"]) == 0
    return float(np.sqrt(np.mean(np.asarray(table["de1"])[ok] ** 2
                                 + np.asarray(table["de2"])[ok] ** 2)))


@pytest.mark.parametrize("offset, ratio", [((2, 3), 0.8), ((0, 5), 0.5)])
def test_one_reserved_blend_does_not_change_the_verdict(offset, ratio):
    """A blend among the reserved stars is rejected by the outlier test, counted and listed,
    and the reported e and size rms stay within 10% of those without it (with it in the
    statistics they would move by more)."""
    X, stamps, weights = _field()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _, clean, s0 = fit_and_validate(X, stamps, reserve=0.2, random_state=1,
                                        weights=weights)
        i = int(clean["index"][0])
        side = int(np.sqrt(stamps.shape[1]))
        blended = stamps.reshape(-1, side, side).copy()
        blended[i] += ratio * np.roll(blended[i], offset, axis=(0, 1))
        _, table, s1 = fit_and_validate(X, blended.reshape(len(X), -1), reserve=0.2,
                                        random_state=1, weights=weights)
    assert s0["n_reserved_outliers"] == 0
    assert s1["n_reserved_outliers"] == 1 and s1["reserved_outliers"] == [i]
    assert bool(table["outlier"][0]) and int(table["index"][0]) == i
    for key in ("e_rms", "dsigma_rms"):
        assert abs(s1[key] / s0[key] - 1) < 0.10, key
    # the same statistics with the blend in them: more than 10% off for e or size
    with_blend = _e_rms(table)
    assert with_blend / s0["e_rms"] > 1.10 or abs(
        np.sqrt(np.mean(np.asarray(table["dsigma"])[np.asarray(table["flag"]) == 0] ** 2))
        / s0["dsigma_rms"] - 1) > 0.10


def test_neighbour_masks_hold_the_neighbours_light():
    """GalSim renders a star and a neighbour (Moffat profiles of beta 3.5, the neighbour 3x
    brighter and 1.5x larger, 16 pixels away): no unmasked pixel of the star's stamp holds
    neighbour light above 1% of the star's peak (the masks assume beta = 3 wings), and none
    of the star's core is masked; a neighbour 4 pixels away makes the star crowded."""
    galsim = pytest.importorskip("galsim")
    s, x0, y0 = 33, 60.3, 50.6
    xn, yn = x0 + 16.0, y0 + 2.0
    image = galsim.ImageD(120, 100, scale=1.0)  # pixel i holds x = i - 1 + 1 (0-based below)
    star = galsim.Moffat(beta=3.5, fwhm=3.0).withFlux(1000.0)
    neighbour = galsim.Moffat(beta=3.5, fwhm=4.5).withFlux(3000.0)
    only_s, only_n = image.copy(), image.copy()
    star.drawImage(only_s, center=galsim.PositionD(x0 + 1, y0 + 1))
    neighbour.drawImage(only_n, center=galsim.PositionD(xn + 1, yn + 1))
    hlr = [star.calculateHLR(), neighbour.calculateHLR()]
    cat = Table({"x": [x0, xn], "y": [y0, yn], "flux_radius": hlr, "flux": [1000.0, 3000.0]})
    mask = neighbour_masks(cat, [0], s)[0]
    cx, cy = int(np.floor(x0 + 0.5)), int(np.floor(y0 + 0.5))
    cut = only_n.array[cy - s // 2: cy - s // 2 + s, cx - s // 2: cx - s // 2 + s]
    peak = only_s.array.max()
    assert cut[~mask].max() < 1e-2 * peak   # measured 0.76%
    assert cut[mask].sum() > 0.9 * cut.sum()
    yy, xx = np.mgrid[:s, :s] - s // 2
    core = np.hypot(xx + cx - x0, yy + cy - y0) < 3.0   # within a FWHM of the star
    assert not mask[core].any()
    # the selection rejects the star only when the neighbour reaches its core
    keep, counts = select_stars(cat, min_snr=0, stamp_size=s)
    assert keep[0] and counts["crowded"] == 0
    cat["x"][1] = x0 + 4.0
    keep, counts = select_stars(cat, min_snr=0, stamp_size=s, min_stars=0)
    assert not keep[0] and counts["crowded"] >= 1


def test_neighbour_masks_equal_every_disc_drawn_one_by_one():
    """On a crowded random field (sizes and fluxes within 100x of each other, NaN and edge
    positions), the masks equal each other source's disc drawn pixel by pixel over the whole
    stamp, and a star is crowded exactly when such a disc reaches alpha of its centre."""
    from sklearn_psf.exposure._select import _crowded, _mask_radius, _sizes_fluxes

    rng = np.random.default_rng(3)
    n, s = 120, 21
    cat = Table({"x": rng.uniform(-5, 200, n), "y": rng.uniform(0, 150, n),
                 "flux_radius": rng.uniform(0.8, 4.0, n), "flux": 10 ** rng.uniform(2, 4, n)})
    cat["x"][7] = np.nan
    rows = np.arange(0, n, 3)
    masks, crowded = neighbour_masks(cat, rows, s), _crowded(cat, rows, s)
    alpha, flux = _sizes_fluxes(cat)
    x, y = np.asarray(cat["x"]), np.asarray(cat["y"])
    offsets = np.arange(s) - s // 2
    for k, i in enumerate(rows):
        expected = np.zeros((s, s), dtype=bool)
        core_hit = False
        for j in range(n):
            if j == i or not (np.isfinite(x[j]) and np.isfinite(y[j])):
                continue
            r = _mask_radius(alpha[j], flux[j], alpha[i], flux[i])
            core_hit |= bool(np.hypot(x[j] - x[i], y[j] - y[i]) < r + alpha[i])
            if np.isfinite(x[i]) and np.isfinite(y[i]):
                px = np.floor(x[i] + 0.5) + offsets
                py = np.floor(y[i] + 0.5) + offsets
                expected |= ((px[None, :] - x[j]) ** 2 + (py[:, None] - y[j]) ** 2
                             < (r + 0.5) ** 2)
        np.testing.assert_array_equal(masks[k], expected)
        assert crowded[k] == core_hit
    assert masks.any(axis=(1, 2)).sum() > len(rows) // 2  # a crowded field indeed


def test_fit_exposure_is_the_command_s_fit(tmp_path, capsys):
    """fit_exposure gives the model and verdict that ``sklearn-psf fit`` saves."""
    from sklearn_psf.cli import main
    from sklearn_psf.io import write_ldac
    from sklearn_psf.model import load_model, read_model_validation

    X, stamps, _ = _field(seed=5, n_stars=80)
    side = int(np.sqrt(stamps.shape[1]))
    cat = Table({"X_IMAGE": X[:, 0] + 1, "Y_IMAGE": X[:, 1] + 1,
                 "VIGNET": stamps.reshape(-1, side, side).astype(np.float32)})
    path = tmp_path / "stars.ldac"
    write_ldac(path, cat)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = fit_exposure(catalog=path, select=False, interpolator="polynomial")
        assert main(["fit", "--stars", str(path), "--no-select", "--no-plots", "--interpolator",
                     "polynomial", "-o", str(tmp_path / "m.fits")]) == 0
    out = capsys.readouterr().out
    for line in fit.report():
        assert line in out
    saved = load_model(tmp_path / "m.fits")
    np.testing.assert_allclose(saved.predict(X[:5]), fit.model.predict(X[:5]), atol=1e-12)
    assert read_model_validation(tmp_path / "m.fits")[1]["e_rms"] == pytest.approx(
        fit.summary["e_rms"])
    with pytest.raises(StarSelectionError, match="min_snr"):
        fit_exposure(catalog=Table({"x": X[:, 0], "y": X[:, 1], "snr": np.full(len(X), 5.0),
                                    "VIGNET": stamps.reshape(-1, side, side)}))


def test_real_decam_psfex_input_beside_psfex(realdata, tmp_path, capsys, monkeypatch):
    """PSFEx's real input catalogue (DECam, 12 apertures, 63x63 VIGNETs): ``fit --psfex`` with
    no other option reads it without a warning and keeps at least 90% of its 117 stars (PSFEx
    accepted 105); ``validate`` then puts the model (its file and its .psf) beside PSFEx's own
    .psf on the reserved stars. All of it as in a base install: GalSim and PIFF absent."""
    import sys

    from astropy.io import fits

    from sklearn_psf.cli import main
    from sklearn_psf.io import read_catalog
    from sklearn_psf.model import read_model_validation

    cat = realdata("DECam_00241238_01_psfcat.ldac.fits")
    psf = realdata("DECam_00241238_01_psfcat.psf")
    model, ours_psf = tmp_path / "decam.fits", tmp_path / "decam.psf"
    monkeypatch.setitem(sys.modules, "galsim", None)
    monkeypatch.setitem(sys.modules, "piff", None)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert main(["fit", "--stars", str(cat), "-o", str(model), "--psfex", str(ours_psf),
                     "--no-plots"]) == 0
    out = capsys.readouterr().out
    assert not [w for w in caught if "header" in str(w.message).lower()], out
    residuals, summary = read_model_validation(model)
    assert summary["n_stars"] >= 0.9 * 117, out       # measured 107
    # the reserved stars, as a catalogue of their own (the same LDAC rows), for both models
    table = read_catalog(cat)
    reserved = np.isin(np.round(np.asarray(table["x"]), 3),
                       np.round(np.asarray(residuals["x"]), 3))
    assert reserved.sum() == len(residuals) >= 15
    with fits.open(cat) as hdul:
        hdul[2].data = hdul[2].data[reserved]
        hdul.writeto(tmp_path / "reserved.ldac")
    assert main(["validate", "--stars", str(tmp_path / "reserved.ldac"), "-m", str(model),
                 "-m", str(ours_psf), "-m", str(psf), "-o", str(tmp_path / "v"),
                 "--no-plots"]) == 0
    from astropy.table import Table as T

    table = T.read(tmp_path / "v" / "validation.csv", format="ascii.csv")
    assert sorted(table["kind"]) == ["psfex", "psfex", "sklearn_psf"]
    # the .psf approximates the model: the same chi^2 on the reserved stars within 1%
    chi2 = dict(zip(table["model"], table["chi2_dof"]))
    assert chi2["decam.psf"] == pytest.approx(chi2["decam.fits"], rel=0.01)
    assert len(set(table["n_measured"])) == 1 and table["n_measured"][0] >= 15


def test_internal_error_of_one_of_many_fits_is_reported_as_a_bug(tmp_path, capsys,
                                                                  monkeypatch):
    """Several inputs (fitted one after the other here): a failure inside numpy is reported as
    a bug of the package (exit status 3, --debug named), an input error as an error (2)."""
    import sklearn_psf.exposure as exposure
    from sklearn_psf.cli import main
    from sklearn_psf.io import write_ldac

    X, stamps, _ = _field(seed=5, n_stars=30)
    side = int(np.sqrt(stamps.shape[1]))
    cat = Table({"X_IMAGE": X[:, 0] + 1, "Y_IMAGE": X[:, 1] + 1,
                 "VIGNET": stamps.reshape(-1, side, side).astype(np.float32)})
    paths = [tmp_path / "a.ldac", tmp_path / "b.ldac"]
    for path in paths:
        write_ldac(path, cat)

    def broken(*args, **kwargs):
        return np.ones(2).reshape(3)   # a numpy failure, not about the input

    monkeypatch.setattr(exposure, "fit_exposure", broken)
    args = ["fit", "--stars", *map(str, paths), "--no-plots", "-o", str(tmp_path / "m.fits")]
    assert main(args) == 3
    err = capsys.readouterr().err
    assert err.count("sklearn-psf: internal error") == 3 and "--debug" in err

    def refused(*args, **kwargs):
        raise exposure.StarSelectionError("0 of 30 sources pass", {"low_snr": 30}, "hint")

    monkeypatch.setattr(exposure, "fit_exposure", refused)
    assert main(args + ["--overwrite"]) == 2
    err = capsys.readouterr().err
    assert "internal error" not in err and err.count("sklearn-psf: error:") == 3


def test_saturation_found_where_the_peaks_pile_up(tmp_path):
    """A catalogue whose header gives no SATURATE: the 8 brightest stars, clipped at a 14-bit
    camera's 16383, share their highest pixel; the fit finds that level, leaves them out as
    saturated and says so. Without the clipped stars no level is found."""
    from sklearn_psf.io import write_ldac

    X, stamps, _ = _field(seed=4, n_stars=60)
    side = int(np.sqrt(stamps.shape[1]))
    peaks = np.random.default_rng(0).uniform(300.0, 5000.0, len(X))
    cube = stamps.reshape(-1, side, side) * (peaks / stamps.max(axis=1))[:, None, None]
    bright = np.arange(8)
    cube[bright] = np.minimum(cube[bright] * 100.0, 16383.0)
    cat = Table({"X_IMAGE": X[:, 0] + 1, "Y_IMAGE": X[:, 1] + 1,
                 "FLUX_MAX": cube.max(axis=(1, 2)).astype(np.float32),
                 "VIGNET": cube.astype(np.float32)})
    path = tmp_path / "clipped.ldac"
    write_ldac(path, cat)
    inputs = read_exposure(catalog=path)
    assert inputs.saturation == pytest.approx(16383.0)
    assert inputs.saturation_source == "catalogue peaks (8 sources)"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = fit_exposure(catalog=path, interpolator="polynomial", reserve=0.0)
    assert fit.summary["saturation"] == pytest.approx(16383.0)
    assert "saturated 8" in "\n".join(fit.report())
    assert any(line.startswith("saturation level: 16383,") for line in fit.report())
    write_ldac(tmp_path / "unclipped.ldac", cat[8:])
    assert read_exposure(catalog=tmp_path / "unclipped.ldac").saturation is None


def test_selection_cuts_and_predict_catalog_of_a_fit():
    """fit_exposure's cuts are select_stars' keywords; its result is a dataclass whose
    summary predict_catalog reads (keys, WCS), refusing what the model cannot take."""
    import dataclasses

    X, stamps, _ = _field(seed=4, n_stars=60)
    side = int(np.sqrt(stamps.shape[1]))
    cat = Table({"x": X[:, 0], "y": X[:, 1], "VIGNET": stamps.reshape(-1, side, side)})
    assert SelectionCuts(min_snr=5).select_kwargs() == {
        "flag_mask": 0xfe, "min_snr": 5, "isolation": None, "locus_width": "auto",
        "max_spread_model": 0.003, "min_class_star": 0.8}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = fit_exposure(catalog=cat, select=False, interpolator="polynomial")
    assert isinstance(fit, ExposureFit) and dataclasses.is_dataclass(fit)
    assert [f.name for f in dataclasses.fields(fit)] == [
        "model", "residuals", "summary", "selection", "stars", "lines", "image_shape"]
    galaxies = Table({"x": [100.0, 1500.5], "y": [300.0, 20.25], "id": [7, 8]})
    out = predict_catalog(fit.model, galaxies, summary=fit.summary, oversampling=2)
    assert out["psf"].shape == (2, 2 * side, 2 * side) and list(out["id"]) == [7, 8]
    assert np.allclose(out["psf"].sum(axis=(1, 2)), 1.0)
    assert galaxies.colnames == ["x", "y", "id"]  # not modified
    with pytest.raises(InputError, match="has no WCS"):
        predict_catalog(fit.model, galaxies, summary=fit.summary, radec=True)
    with pytest.raises(InputError, match="0 dimensions after x, y; --keys gives 1"):
        predict_catalog(fit.model, galaxies, keys=["id"])
    with pytest.raises(InputError, match="no rows"):
        predict_catalog(fit.model, galaxies[:0])


def test_fit_exposure_takes_the_user_s_basis_without_changing_it():
    """basis= is the model's stamp basis (a clone: the user's object stays unfitted), the
    same model as PSFModel(basis=...) fitted on the stamps; with band_limit it is refused."""
    from sklearn.utils.validation import check_is_fitted
    from sklearn.exceptions import NotFittedError

    from sklearn_psf.model import PSFModel, make_interpolator
    from sklearn_psf.preprocessing import StampPCA

    X, stamps, weights = _field(seed=4, n_stars=60)
    side = int(np.sqrt(stamps.shape[1]))
    cat = Table({"x": X[:, 0], "y": X[:, 1], "VIGNET": stamps.reshape(-1, side, side)})
    basis = StampPCA(n_components=2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = fit_exposure(catalog=cat, select=False, interpolator="polynomial",
                           reserve=0.0, basis=basis)
        direct = PSFModel(basis=StampPCA(n_components=2),
                          interpolator=make_interpolator("polynomial")).fit(
            fit.stars.positions, fit.stars.stamps, weights=fit.stars.weights)
    with pytest.raises(NotFittedError):
        check_is_fitted(basis)
    assert fit.model.basis_.n_components_ == 2
    np.testing.assert_allclose(fit.model.predict(X[:5]), direct.predict(X[:5]), rtol=1e-10,
                               atol=1e-12)
    with pytest.raises(ValueError, match="band_limit or basis, not both"):
        fit_exposure(catalog=cat, select=False, band_limit=0.8, basis=basis)
