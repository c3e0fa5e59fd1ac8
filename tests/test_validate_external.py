"""PSFEx and PIFF models validated next to this package's on the same reserved stars."""

import os
import subprocess
import sys
import tempfile
import warnings

import numpy as np
import pytest
from astropy.io import fits
from astropy.table import Table
from numpy.testing import assert_allclose
from scipy.ndimage import map_coordinates

from sklearn_psf.cli import main
from sklearn_psf.io import write_ldac
from sklearn_psf.measure import adaptive_moments
from sklearn_psf.model import PSFModel, save_model
from sklearn_psf.preprocessing import StampNormalizer
from sklearn_psf.simulate import make_psf_field
from sklearn_psf.validation import (
    PSFExModel,
    PSFQualityWarning,
    fit_and_validate,
    load_psf_model,
    measure_residuals,
    model_kind,
    plot_model_comparison,
    psfex_terms,
    validate_models,
    write_psfex,
)

SHAPE = (1200, 1200)
N_RESERVED = 100


def fit_polynomial_psfex(path, X, stamps, degree):
    """PSFEx's pixel-basis model: each pixel of the normalised stamps a polynomial of the
    1-based position, fitted by least squares and written in PSFEx's format."""
    s = int(round(np.sqrt(stamps.shape[1])))
    zero, scale = (SHAPE[1] / 2 + 0.5, SHAPE[0] / 2 + 0.5), (float(SHAPE[1]), float(SHAPE[0]))
    terms = psfex_terms(X + 1.0, degree, zero, scale)
    planes = np.linalg.lstsq(terms, StampNormalizer().fit_transform(stamps), rcond=None)[0]
    write_psfex(path, planes.reshape(-1, s, s), zero, scale)
    return str(path)


@pytest.fixture(scope="module")
def field(tmp_path_factory):
    """Stars at S/N 200 with the truth known; 100 reserved, 160 fitted; three models."""
    folder = tmp_path_factory.mktemp("models")
    sim = make_psf_field(n_stars=N_RESERVED + 160, n_galaxies=0, image_shape=SHAPE,
                         snr=200.0, random_state=0)
    stamps, weights, _ = sim.star_stamps(return_weights=True)
    X = np.column_stack([sim.stars["x"], sim.stars["y"]])
    res, fit = np.arange(N_RESERVED), np.arange(N_RESERVED, len(X))
    ours = PSFModel().fit(X[fit], stamps[fit], weights=weights[fit])
    save_model(ours, folder / "ours.fits")
    return {
        "sim": sim, "X": X, "stamps": stamps, "weights": weights, "res": res, "fit": fit,
        "folder": folder, "ours": str(folder / "ours.fits"),
        "quadratic": fit_polynomial_psfex(folder / "quadratic.psf", X[fit], stamps[fit], 2),
        "constant": fit_polynomial_psfex(folder / "constant.psf", X[fit], stamps[fit], 0),
    }


def _truth_errors(model, X, truth):
    """Model - truth: e rms, and pixel rms after the chi^2's flux/background/centroid fit."""
    pred = model.predict(X)
    mp, mt = adaptive_moments(pred), adaptive_moments(truth)
    e = np.sqrt(np.mean((np.asarray(mp["e1"]) - mt["e1"]) ** 2
                        + (np.asarray(mp["e2"]) - mt["e2"]) ** 2))
    table, _ = measure_residuals(X, truth, pred, weights=np.ones_like(truth))
    return float(np.sqrt(np.sum(table["chi2"]) / np.sum(table["dof"]))), float(e)


# ------------------------------------------------------------------------- the PSFEx format
def test_written_psfex_file_is_read_by_galsim_as_written():
    galsim = pytest.importorskip("galsim")
    import galsim.des

    rng = np.random.default_rng(1)
    planes = rng.normal(size=(6, 15, 15)).astype(np.float32)
    zero, scale = (1024.5, 2048.5), (2048.0, 4096.0)
    path = os.path.join(tempfile.mkdtemp(), "m.psf")
    write_psfex(path, planes, zero, scale, psf_samp=0.8)
    psfex = galsim.des.DES_PSFEx(path)
    assert (psfex.fit_order, psfex.sample_scale) == (2, pytest.approx(0.8))
    for x, y in [(1.0, 1.0), (2048.0, 4096.0), (1500.3, 77.7)]:
        expected = psfex_terms([[x, y]], 2, zero, scale)[0] @ planes.reshape(6, -1)
        got = psfex.getPSFArray(galsim.PositionD(x, y)).ravel()
        assert_allclose(got, expected, rtol=1e-5, atol=1e-5 * np.abs(expected).max())


def test_psfex_model_predicts_the_written_polynomial():
    # centred, point-symmetric planes: the normalisation does not move the PSF
    yy, xx = np.mgrid[-8:9, -8:9]
    planes = np.array([np.exp(-(xx**2 + yy**2) / (2 * w**2)) for w in (1.8, 0.4, 0.3)])
    zero, scale = (500.5, 500.5), (1000.0, 1000.0)
    path = os.path.join(tempfile.mkdtemp(), "m.psf")
    write_psfex(path, planes, zero, scale)
    model = PSFExModel(path)
    assert (model.stamp_size_, model.degree_) == (17, 1)
    X = np.array([[0.0, 0.0], [999.0, 999.0], [250.2, 700.9]])
    poly = psfex_terms(X + 1, 1, zero, scale) @ planes.reshape(3, -1)
    poly /= poly.sum(axis=1, keepdims=True)
    pred = model.predict(X)
    assert_allclose(pred, poly, atol=1e-6 * poly.max())
    # a larger stamp (zero beyond the model's 17 pixels), and positions 0-based by default
    big = PSFExModel(path, stamp_size=21).predict(X).reshape(3, 21, 21)
    assert_allclose(big[:, 2:19, 2:19].reshape(3, -1), poly, atol=1e-6 * poly.max())
    assert_allclose(PSFExModel(path, origin=0).predict(X + 1), poly, atol=1e-6 * poly.max())


def _galsim_drawn(path, X, stamp_size, offsets=None):
    """GalSim's own drawing of a .psf file (``DES_PSFEx``, ``method='no_pixel'``) at 0-based
    positions (each star at ``offsets`` from the centre pixel), each stamp of unit sum."""
    galsim = pytest.importorskip("galsim")
    import galsim.des

    psfex = galsim.des.DES_PSFEx(str(path))
    image = galsim.ImageD(stamp_size, stamp_size, scale=1.0)
    out = np.empty((len(X), stamp_size, stamp_size))
    offsets = np.zeros((len(X), 2)) if offsets is None else offsets
    for i, ((x, y), offset) in enumerate(zip(np.asarray(X) + 1.0, offsets)):
        psfex.getPSF(galsim.PositionD(x, y)).drawImage(image=image, method="no_pixel",
                                                       offset=tuple(offset))
        out[i] = image.array / image.array.sum()
    return out


def _ours_drawn(model, X):
    """PSFExModel's resampled polynomial before the normalisation, each stamp of unit sum."""
    planes = np.tensordot(psfex_terms(np.asarray(X) + 1.0, model.degree_, model._polzero,
                                      model._polscal), model._planes, axes=(1, 0))
    out = model._wy @ planes @ model._wx.T
    return out / out.sum(axis=(1, 2), keepdims=True)


@pytest.mark.parametrize("side, samp", [(24, 0.8), (31, 1.0), (40, 0.5), (21, 1.3)])
def test_psfex_model_draws_as_galsim_des_psfex(side, samp, tmp_path):
    """Odd and even PSF_MASK sides, PSF_SAMP below and above 1: the reader without GalSim
    draws what GalSim draws (measured: at most 4e-6 of the peak, from GalSim's approximate
    flux-conserving Lanczos correction; 3e-8 at PSF_SAMP 1 and 0.5)."""
    yy, xx = np.mgrid[0:side, 0:side] - (side - 1) / 2 - 0.3
    w = 2.0 / samp
    planes = np.array([np.exp(-(xx**2 + 1.3 * yy**2 + 0.4 * xx * yy) / (2 * w**2)),
                       0.1 * xx / w * np.exp(-(xx**2 + yy**2) / (2 * w**2)),
                       0.05 * np.exp(-(xx**2 + yy**2) / (2 * (0.7 * w)**2))])
    path = tmp_path / "m.psf"
    write_psfex(path, planes, (1000.0, 1000.0), (2000.0, 2000.0), psf_samp=samp)
    model = PSFExModel(path)
    s = model.stamp_size_
    X = np.array([[10.0, 20.0], [1500.2, 300.7], [1999.0, 1999.0]])
    ref = _galsim_drawn(path, X, s)
    assert np.abs(_ours_drawn(model, X) - ref).max() < 2e-5 * ref.max()
    normalised = StampNormalizer().fit_transform(ref.reshape(len(X), -1))
    assert np.abs(model.predict(X) - normalised).max() < 2e-5 * ref.max()


def test_real_psfex_file_drawn_without_galsim_as_galsim_draws_it(realdata, monkeypatch):
    """PSFEx 3.17's own DECam model (degree 2 in XWIN_IMAGE, YWIN_IMAGE, PSF_SAMP 0.5,
    101x101 planes) at 40 positions over the CCD: read with GalSim blocked, the stamps equal
    GalSim's DES_PSFEx drawing to 1e-6 of the peak (measured 4.5e-8), so do their adaptive
    moments."""
    path = realdata("DECam_00241238_01_psfcat.psf")
    X = np.random.default_rng(1).uniform([0, 0], [2048, 4096], (40, 2))
    with monkeypatch.context() as m:
        m.setitem(sys.modules, "galsim", None)
        model = load_psf_model(path)
        assert isinstance(model, PSFExModel)
        assert (model.degree_, model.sampling_, model.stamp_size_) == (2, 0.5, 51)
        ours, raw = model.predict(X), _ours_drawn(model, X)
    ref = _galsim_drawn(path, X, 51)
    assert np.abs(raw - ref).max() < 1e-6 * ref.max()
    normalised = StampNormalizer().fit_transform(ref.reshape(len(X), -1))
    assert np.abs(ours - normalised).max() < 1e-6 * ref.max()
    a, b = adaptive_moments(ours.reshape(-1, 51, 51)), adaptive_moments(normalised)
    for key in ("e1", "e2", "sigma"):
        assert_allclose(a[key], b[key], atol=1e-6)


def test_psfex_reader_refuses_what_it_cannot_draw(tmp_path):
    path = tmp_path / "mag.psf"
    write_psfex(path, np.ones((3, 5, 5)), (0.0, 0.0), (1.0, 1.0))
    with fits.open(path, mode="update") as hdul:
        hdul[1].header["POLNAME2"] = "MAG_AUTO"
    with pytest.raises(ValueError, match=r"mag.psf.*only the positions"):
        PSFExModel(path)
    with fits.open(path, mode="update") as hdul:
        hdul[1].header["POLNAME2"] = "Y_IMAGE"
        hdul[1].header["POLDEG1"] = 2
    with pytest.raises(ValueError, match=r"degree 2, which has 6 terms"):
        PSFExModel(path)


def test_write_psfex_refuses_bad_input(tmp_path):
    with pytest.raises(ValueError, match=r"\(d\+1\)\(d\+2\)/2"):
        write_psfex(tmp_path / "a.psf", np.ones((4, 5, 5)), (0, 0), (1, 1))
    with pytest.raises(ValueError, match="polscal"):
        write_psfex(tmp_path / "a.psf", np.ones((1, 5, 5)), (0, 0), (1, 0))
    write_psfex(tmp_path / "a.psf", np.ones((1, 5, 5)), (0, 0), (1, 1))
    with pytest.raises(FileExistsError, match="overwrite=True"):
        write_psfex(tmp_path / "a.psf", np.ones((1, 5, 5)), (0, 0), (1, 1))


def test_model_kind(field, tmp_path):
    assert model_kind(field["ours"]) == "sklearn_psf"
    assert model_kind(field["quadratic"]) == "psfex"
    assert type(load_psf_model(field["ours"])).__name__ == "PSFModel"
    fits.PrimaryHDU(np.zeros((4, 4))).writeto(tmp_path / "image.fits")
    with pytest.raises(ValueError, match="neither a sklearn_psf model file"):
        model_kind(tmp_path / "image.fits")
    (tmp_path / "notes.txt").write_text("not FITS")
    with pytest.raises(ValueError, match="not a FITS file"):
        model_kind(tmp_path / "notes.txt")
    with pytest.raises(ValueError, match="does not exist"):
        model_kind(tmp_path / "missing.psf")


# ---------------------------------------------------------------- residuals in the noise
def test_chi2_of_the_true_psf_is_one_and_of_a_wrong_one_is_not(field):
    sim, res = field["sim"], field["res"]
    truth = np.asarray(sim.stars["stamp"])[res]
    rng = np.random.default_rng(3)
    sigma = 2e-4  # white noise of known level on unit-flux stars at sub-pixel offsets
    stars = 3.0 * truth + rng.normal(0.0, sigma, truth.shape)
    w = np.full(truth.shape, sigma**-2)
    table, summary = measure_residuals(field["X"][res], stars, truth, weights=w)
    dof = int(np.sum(table["dof"]))
    assert dof == N_RESERVED * (truth.shape[1] - 4)
    assert abs(summary["chi2_dof"] - 1.0) < 4 * np.sqrt(2.0 / dof)  # measured 0.994 (bound 0.023)
    # a model 10% wider is far outside the noise
    yy, xx = (np.mgrid[0:25, 0:25] - 12.0) / 1.1
    wide = np.array([map_coordinates(t.reshape(25, 25), [yy + 12, xx + 12], order=3).ravel()
                     for t in truth])
    wide /= wide.sum(axis=1, keepdims=True)
    _, bad = measure_residuals(field["X"][res], stars, wide, weights=w)
    assert bad["chi2_dof"] > 1.5 and bad["dsigma_mean"] < -0.05


def test_measure_residuals_flags_unusable_stars_and_checks_shapes(field):
    res = field["res"][:20]
    stamps = field["stamps"][res].copy()
    stamps[3] = 0.0
    pred = np.asarray(field["sim"].stars["stamp"])[res]
    table, summary = measure_residuals(field["X"][res], stamps, pred,
                                       weights=field["weights"][res])
    assert table["flag"][3] == 1 and np.isnan(table["chi2"][3]) and table["dof"][3] == 0
    assert summary["n_measured"] == 19 and np.isfinite(summary["chi2_dof"])
    with pytest.raises(ValueError, match="same n stars"):
        measure_residuals(field["X"][res], stamps, pred[:5])
    with pytest.raises(ValueError, match="negative, NaN or infinite values at rows 0,"):
        measure_residuals(field["X"][res], stamps, pred, weights=-field["weights"][res])


def test_fit_and_validate_reports_chi2_in_the_stars_noise(field):
    X, stamps, w = field["X"], field["stamps"], field["weights"]
    # chi^2 near 1 per pixel, while the ellipticity, far better measured at S/N 200, shows
    # the model's own error beyond the noise (2.4 times): the verdict says so
    with pytest.warns(PSFQualityWarning, match="ellipticity residuals are .* times"):
        _, table, summary = fit_and_validate(X, stamps, weights=w, reserve=0.3,
                                             random_state=0)
    assert "chi2" in table.colnames and (table["dof"][table["flag"] == 0] > 0).all()
    assert 0.9 < summary["chi2_dof"] < 1.3  # measured 1.06: noise plus the model's error


# ------------------------------------------------------------- several models, one table
def test_validate_ranks_the_models_as_their_true_errors(field):
    res, X = field["res"], field["X"]
    models = {"ours": field["ours"], "PSFEx quadratic": field["quadratic"],
              "PSFEx constant": field["constant"]}
    table, results = validate_models(X[res], field["stamps"][res], models,
                                     weights=field["weights"][res])
    assert list(table["model"]) == list(models)
    assert list(table["kind"]) == ["sklearn_psf", "psfex", "psfex"]
    assert sorted(table["rank"]) == [1, 2, 3]
    assert (table["n_measured"] == N_RESERVED).all()
    for name in ("chi2_dof", "e_rms", "dsigma_rms", "rho1_mean_abs", "rho5_mean_abs"):
        assert np.isfinite(table[name]).all(), name
    truth = np.asarray(field["sim"].stars["stamp"])[res]
    errors = {name: _truth_errors(load_psf_model(path, 25), X[res], truth)
              for name, path in models.items()}
    pixel = [errors[name][0] for name in table["model"]]
    e_true = [errors[name][1] for name in table["model"]]
    assert_allclose(np.argsort(table["chi2_dof"]), np.argsort(pixel))
    assert_allclose(np.argsort(table["e_rms"]), np.argsort(e_true))
    assert table["model"][np.argmin(table["rank"])] == "ours"
    # measured chi2/dof 1.064, 1.129, 1.266: each step well beyond its noise (~0.006)
    chi = np.sort(table["chi2_dof"])
    assert np.diff(chi).min() > 0.03
    # the same residual tables as measure_residuals on each model's stamps
    t_ours, s_ours = results["ours"]
    assert s_ours["chi2_dof"] == table["chi2_dof"][0]
    figures = plot_model_comparison(results)
    assert sorted(figures) == ["residuals", "rho", "stamps", "whiskers"]
    assert len(figures["rho"].axes) == 6


def test_validate_accepts_models_of_another_stamp_size(field):
    res = field["res"][:30]
    X, stamps, w = field["X"][res], field["stamps"][res], field["weights"][res]
    g = np.exp(-0.5 * ((np.mgrid[0:31, 0:31] - 15.0) ** 2).sum(axis=0) / 1.9**2)

    class Wide:  # 31 x 31 stamps for 25 x 25 stars: cropped about the centre
        def predict(self, X):
            return np.tile(g.ravel() / g.sum(), (len(X), 1))

    class Exact:
        def predict(self, X):
            c = g[3:28, 3:28]
            return np.tile(c.ravel() / c.sum(), (len(X), 1))

    table, _ = validate_models(X, stamps, {"wide": Wide(), "exact": Exact()}, weights=w)
    assert_allclose(table["chi2_dof"][0], table["chi2_dof"][1], rtol=1e-10)
    with pytest.raises(ValueError, match="odd"):
        validate_models(X, stamps, {"even": type("E", (), {"predict": lambda self, X:
                                                            np.ones((len(X), 24 * 24))})()})
    with pytest.raises(TypeError, match="object with predict"):
        validate_models(X, stamps, {"bad": 3})


def test_missing_optional_packages_say_how_to_install(field, monkeypatch):
    monkeypatch.setitem(sys.modules, "galsim", None)  # PSFEx files need no GalSim
    assert PSFExModel(field["quadratic"]).predict(field["X"][:2]).shape == (2, 25 * 25)
    monkeypatch.setitem(sys.modules, "piff", None)
    from sklearn_psf.validation import PiffModel

    with pytest.raises(ImportError, match=r"pip install 'sklearn-psf\[piff\]'"):
        PiffModel(field["quadratic"])


# ------------------------------------------------------------------------------- PIFF
def _fit_piff(path, X, stamps, weights):
    piff = pytest.importorskip("piff")
    import galsim

    s = 25
    stars = []
    for (x, y), d, w in zip(X, stamps, weights):
        cx, cy = int(np.floor(x + 0.5)) + 1, int(np.floor(y + 0.5)) + 1  # 1-based pixels
        b = galsim.BoundsI(cx - s // 2, cx + s // 2, cy - s // 2, cy + s // 2)
        image = galsim.Image(d.reshape(s, s).copy(), bounds=b, scale=1.0)
        weight = galsim.Image(w.reshape(s, s).copy(), bounds=b, scale=1.0)
        stars.append(piff.Star(piff.StarData(image, galsim.PositionD(x + 1, y + 1),
                                             weight=weight), None))
    psf = piff.SimplePSF(piff.PixelGrid(scale=1.0, size=13), piff.BasisPolynomial(order=1),
                         max_iter=2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        psf.fit(stars, {0: galsim.PixelScale(1.0)}, pointing=None)
    psf.write(str(path))
    return psf


def test_piff_model_is_read_drawn_and_validated(field):
    fit = field["fit"][:80]  # a small PIFF PixelGrid fit (about 3 s)
    path = field["folder"] / "model.piff"
    psf = _fit_piff(path, field["X"][fit], field["stamps"][fit], field["weights"][fit])
    assert model_kind(path) == "piff"
    res = field["res"]
    X = field["X"][res]
    model = load_psf_model(path, 25)
    pred = model.predict(X[:5])
    # PIFF's own drawing, centred in the stamp, normalised as ours
    for i, (x, y) in enumerate(X[:5]):
        own = psf.draw(x + 1, y + 1, stamp_size=25, center=True).array.ravel()
        own = StampNormalizer().fit_transform(own[None] / own.sum())[0]
        assert_allclose(pred[i], own, atol=1e-9)
    table, _ = validate_models(X, field["stamps"][res], [field["ours"], str(path)],
                               weights=field["weights"][res])
    assert list(table["kind"]) == ["sklearn_psf", "piff"]
    assert np.isfinite(table["chi2_dof"]).all() and np.isfinite(table["rho1_mean_abs"]).all()
    assert table["e_rms"][1] < 0.05  # measured 0.024 (13-pixel grid, 80 stars)


# ------------------------------------------------------------------------ command line
def test_cli_validate(field, tmp_path, capsys):
    sim, res = field["sim"], field["res"]
    image = tmp_path / "image.fits"
    fits.HDUList([fits.PrimaryHDU(sim.image), fits.ImageHDU(sim.weight, name="WGT")]
                 ).writeto(image)
    stars = tmp_path / "reserved.csv"
    Table({"x": field["X"][res, 0], "y": field["X"][res, 1]}).write(stars)
    out = tmp_path / "out"
    args = ["validate", str(image), "--weight-hdu", "WGT", "--stars", str(stars),
            "-m", field["ours"], "-m", field["quadratic"], "-o", str(out)]
    assert main(args) == 0
    text = capsys.readouterr().out
    assert f"stars: {N_RESERVED} used of {N_RESERVED} rows" in text
    assert "ours.fits" in text and "quadratic.psf" in text and "chi2/dof" in text
    table = Table.read(out / "validation.csv")
    assert list(table["kind"]) == ["sklearn_psf", "psfex"]
    assert table["rank"][0] == 1  # ours: the better model here
    for name in ("rho", "residuals", "stamps", "whiskers"):
        assert (out / f"validation_{name}.png").stat().st_size > 10000
    # an earlier run's outputs are not replaced without --overwrite
    assert main(args) == 2
    assert "already holds validation.csv" in capsys.readouterr().err
    # the same stars as a SExtractor catalogue with VIGNETs, no image, replacing that run
    s = sim.stamp_size
    ldac = tmp_path / "reserved.ldac"
    write_ldac(ldac, Table({"X_IMAGE": field["X"][res, 0] + 1, "Y_IMAGE": field["X"][res, 1] + 1,
                            "FLAGS": np.zeros(len(res), np.int16),
                            "VIGNET": field["stamps"][res].reshape(-1, s, s).astype(np.float32)}))
    assert main(["validate", "--stars", str(ldac), "-m", field["ours"], "-m",
                 field["constant"], "-o", str(out), "--no-plots", "--overwrite"]) == 0
    table = Table.read(out / "validation.csv")
    assert list(table["rank"]) == [1, 2] and (table["n_measured"] == N_RESERVED).all()
    assert "constant.psf" in capsys.readouterr().out
    # errors in one line
    assert main(["validate", "--stars", str(ldac), "-m", str(tmp_path / "missing.psf"),
                 "-o", str(tmp_path / "x")]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_cli_parser_imports_neither_galsim_nor_piff():
    code = ("import sys; from sklearn_psf.cli import build_parser; build_parser(); "
            "print(sorted(m for m in ('galsim', 'piff', 'sklearn_psf.validation', 'astropy') "
            "if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    assert out.strip() == "[]"


def test_psfex_model_drawn_at_offsets_as_galsim_draws_it(tmp_path):
    """``predict(X, offsets)`` draws each star at its sub-pixel (dx, dy) from the centre
    pixel as GalSim's DES_PSFEx drawn with that ``offset`` (``method='no_pixel'``), for an
    undersampled model (PSF_SAMP 0.4)."""
    side, samp = 31, 0.4
    yy, xx = np.mgrid[0:side, 0:side] - (side - 1) / 2
    w = 0.6 / samp
    planes = np.array([np.exp(-(xx**2 + 1.3 * yy**2 + 0.4 * xx * yy) / (2 * w**2)),
                       0.1 * xx / w * np.exp(-(xx**2 + yy**2) / (2 * w**2)),
                       0.05 * np.exp(-(xx**2 + yy**2) / (2 * (0.7 * w)**2))])
    path = tmp_path / "m.psf"
    write_psfex(path, planes, (1000.0, 1000.0), (2000.0, 2000.0), psf_samp=samp)
    model = PSFExModel(path, stamp_size=15)
    X = np.array([[10.0, 20.0], [1500.2, 300.7], [1999.0, 1999.0]])
    offsets = np.array([[0.3, -0.45], [-0.2, 0.1], [0.49, 0.0]])
    ref = _galsim_drawn(path, X, 15, offsets)
    got = model.predict(X, offsets=offsets).reshape(3, 15, 15)
    assert np.abs(got - ref).max() < 2e-5 * ref.max()


def _pixel_gaussian(offsets, s=15, sigma=0.5):
    """Unit-flux round Gaussians integrated over the pixels, centred at ``offsets`` from
    the centre pixel: undersampled stars drawn exactly at any phase."""
    from scipy.special import erf

    edges = np.arange(s + 1) - s // 2 - 0.5
    out = []
    for dx, dy in np.atleast_2d(offsets):
        fx = np.diff(erf((edges - dx) / (np.sqrt(2) * sigma))) / 2
        fy = np.diff(erf((edges - dy) / (np.sqrt(2) * sigma))) / 2
        out.append(np.outer(fy, fx).ravel())
    return np.array(out)


def test_undersampled_stars_judged_at_their_phase():
    """Undersampled stars (FWHM 1.2 px) at random sub-pixel positions, S/N ~1000: the true
    PSF judged with ``validate_models`` has chi^2/dof 1 when it can be drawn at each star's
    phase (measured 0.999); drawn centred and moved by a Fourier shift of its sampled
    stamp, the same truth aliases (measured 2.6e5): the judge that made a super-resolved
    model lose to PSFEx on the real undersampled SDSS frame."""
    rng = np.random.default_rng(3)
    n, s = 60, 15
    X = rng.uniform(50, 950, (n, 2))
    phase = X - np.floor(X + 0.5)
    stars = 1e5 * _pixel_gaussian(phase, s) + rng.normal(0.0, 1.0, (n, s * s))

    class Drawn:
        def predict(self, X, offsets=None):
            return _pixel_gaussian(np.zeros((len(X), 2)) if offsets is None else offsets, s)

    class Centred:
        def predict(self, X):
            return _pixel_gaussian(np.zeros((len(X), 2)), s)

    table, _ = validate_models(X, stars, {"drawn": Drawn(), "centred": Centred()},
                               weights=np.ones((n, s * s)))
    chi2 = dict(zip(table["model"], table["chi2_dof"]))
    assert abs(chi2["drawn"] - 1.0) < 0.05
    assert chi2["centred"] > 1.5
    assert table.meta["moments"].startswith("fixed")
