"""Catalogue columns as dimensions of the model: ``sklearn-psf fit --keys`` and ``predict``
on a chromatic field (``make_psf_field(sources=SourceSettings(chromatic=True))``: each
star's PSF depends on its g-i), checked against the library's ``fit_exposure(keys=...)``
and ``draw_psf``."""

import numpy as np
import pytest
from astropy.table import Table
from numpy.testing import assert_allclose

from sklearn_psf.cli import main
from sklearn_psf.exposure import fit_exposure, key_columns
from sklearn_psf.io import CatalogColumnWarning, draw_psf, extrapolation_flags
from sklearn_psf.model import load_model, read_model_validation
from sklearn_psf.simulate import SourceSettings, make_psf_field
from sklearn_psf.validation import PSFQualityWarning, validate_models


@pytest.fixture(scope="module")
def chromatic(tmp_path_factory):
    """A star catalogue (VIGNETs, 0-based x, y, a G_I column with 3 NaN) and a galaxy one."""
    folder = tmp_path_factory.mktemp("chromatic")
    field = make_psf_field(n_stars=120, n_galaxies=40, image_shape=(1200, 1200), snr=300.0,
                           sources=SourceSettings(chromatic=True, airmass=1.2),
                           random_state=4)
    stamps, _, _ = field.star_stamps(return_weights=True)
    side = int(round(np.sqrt(stamps.shape[1])))
    colour = np.array(field.stars["g_i"], dtype=float)
    colour[[5, 17, 60]] = np.nan
    stars = Table({"x": field.stars["x"], "y": field.stars["y"],
                   "VIGNET": stamps.reshape(-1, side, side), "G_I": colour})
    galaxies = Table({"x": field.galaxies["x"], "y": field.galaxies["y"],
                      "G_I": field.galaxies["g_i"]})
    paths = {"stars": folder / "stars.fits", "galaxies": folder / "galaxies.fits"}
    stars.write(paths["stars"])
    galaxies.write(paths["galaxies"])
    return paths, field


def _run(args, capsys):
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def test_fit_with_keys_then_predict_equals_the_library(tmp_path, chromatic, capsys):
    paths, field = chromatic
    model_path = tmp_path / "psf.fits"
    with pytest.warns(CatalogColumnWarning, match="3 of the 120 stars"):
        code, out, err = _run(["fit", "--stars", paths["stars"], "--no-select", "--keys",
                               "G_I", "-o", model_path, "--no-plots"], capsys)
    assert code == 0, err
    assert "missing_key 3" in out  # counted among the skipped stars
    # the verdict gives the fourth moments' residuals and their correlation functions
    assert "spin-0 dM22 mean" in out and "rho_M4" in out and "rho_TM22" in out
    model = load_model(model_path)
    _, summary = read_model_validation(model_path)
    assert summary["keys"] == ["G_I"]
    assert model.X_fit_.shape[1] == 3  # x, y, g-i
    assert np.isfinite(model.X_fit_).all()

    # the library call: same stars, same model, same PSFs at the galaxies (any case of the key)
    with pytest.warns(CatalogColumnWarning), \
            pytest.warns(PSFQualityWarning, match="exceed their measurement noise"):
        fit = fit_exposure(catalog=str(paths["stars"]), select=False, keys=["g_i"])
    assert fit.summary["keys"] == ["G_I"]
    assert_allclose(fit.model.X_fit_, model.X_fit_)
    gal = field.galaxies
    X_gal = np.column_stack([gal["x"], gal["y"], gal["g_i"]])
    expected = draw_psf(fit.model, X_gal, centered=False)

    out_path = tmp_path / "gal.fits"
    code, out, err = _run(["predict", model_path, "--positions", paths["galaxies"],
                           "-o", out_path], capsys)
    assert code == 0, err
    assert "model dimensions x, y, G_I" in out
    table = Table.read(out_path, hdu="PSF")
    assert_allclose(np.asarray(table["psf"]), expected, rtol=0, atol=1e-12)
    # the model follows the colour: the same position drawn at another g-i differs
    bluer = draw_psf(model, X_gal[:1] - [0, 0, 1.0], centered=False)
    assert np.abs(bluer - expected[:1]).max() > 0
    # galaxies bluer than every star (g-i below 0.3) are flagged as extrapolated
    flags = extrapolation_flags(model.X_fit_, X_gal)
    assert_allclose(np.asarray(table["extrapolated"]), flags)
    lo = model.X_fit_[:, 2].min()
    assert np.asarray(table["extrapolated"])[X_gal[:, 2] < lo].all()
    assert (X_gal[:, 2] < lo).sum() >= 1  # the galaxies' colours reach 0, the stars' 0.3


def test_keys_errors(tmp_path, chromatic, capsys):
    paths, _ = chromatic
    # an unknown column: one line naming it and listing some that exist
    code, out, err = _run(["fit", "--stars", paths["stars"], "--no-select", "--keys",
                           "MAG_AUTO", "-o", tmp_path / "m.fits", "--no-plots"], capsys)
    assert code == 2
    assert "no column 'MAG_AUTO'" in err and "G_I" in err and "Traceback" not in err
    assert not (tmp_path / "m.fits").exists()
    # --keys with --psfex: refused before any work
    code, out, err = _run(["fit", "--stars", paths["stars"], "--no-select", "--keys", "G_I",
                           "-o", tmp_path / "m.fits", "--psfex", tmp_path / "m.psf"], capsys)
    assert code == 2 and "--psfex" in err

    # predict at galaxies without the key column, or with NaN in it
    model_path = tmp_path / "psf.fits"
    with pytest.warns(CatalogColumnWarning):
        code, _, err = _run(["fit", "--stars", paths["stars"], "--no-select", "--keys", "G_I",
                             "-o", model_path, "--no-plots"], capsys)
    assert code == 0, err
    galaxies = Table.read(paths["galaxies"])
    no_colour = tmp_path / "no_colour.fits"
    galaxies[["x", "y"]].write(no_colour)
    code, _, err = _run(["predict", model_path, "--positions", no_colour,
                         "-o", tmp_path / "p.fits"], capsys)
    assert code == 2 and "no column 'G_I'" in err
    nan_colour = tmp_path / "nan_colour.fits"
    galaxies["G_I"][2] = np.nan
    galaxies.write(nan_colour)
    code, _, err = _run(["predict", model_path, "--positions", nan_colour,
                         "-o", tmp_path / "p.fits"], capsys)
    assert code == 2 and "1 rows" in err and "row 2" in err
    # --keys of predict: another column name, but as many as the model has
    code, _, err = _run(["predict", model_path, "--positions", paths["galaxies"], "--keys",
                         "x", "y", "-o", tmp_path / "p.fits"], capsys)
    assert code == 2 and "1 dimensions after x, y (G_I); --keys gives 2" in err
    assert not (tmp_path / "p.fits").exists()


def test_key_columns_and_library_errors(chromatic):
    paths, _ = chromatic
    table = Table({"x": [1.0, 2.0], "y": [0.0, 1.0], "MAG": np.ma.array([20.0, 21.0],
                                                                        mask=[False, True]),
                   "NAME": ["a", "b"], "VEC": np.zeros((2, 3))})
    assert_allclose(key_columns(table, ["mag"]), [[20.0], [np.nan]])  # masked -> NaN
    with pytest.raises(ValueError, match="'NAME'.*one number per row"):
        key_columns(table, ["name"])
    with pytest.raises(ValueError, match="'VEC'.*one number per row"):
        key_columns(table, ["VEC"])
    with pytest.raises(ValueError, match="no column 'colour'"):
        fit_exposure(catalog=str(paths["stars"]), select=False, keys=["colour"])
    # extrapolation needs the fitted columns, all of them
    with pytest.raises(ValueError, match="columns of X_fit"):
        extrapolation_flags(np.zeros((5, 3)), np.zeros((2, 2)))


def test_validate_reads_the_keys_of_the_model(tmp_path, chromatic, capsys):
    paths, _ = chromatic
    model_path = tmp_path / "psf.fits"
    with pytest.warns(CatalogColumnWarning):
        assert _run(["fit", "--stars", paths["stars"], "--no-select", "--keys", "G_I",
                     "-o", model_path, "--no-plots"], capsys)[0] == 0
    stars = Table.read(paths["stars"])
    colour = np.ma.filled(np.ma.asarray(stars["G_I"], dtype=float), np.nan)
    good = np.isfinite(colour)
    clean = tmp_path / "clean.fits"
    stars[good].write(clean)
    code, out, err = _run(["validate", "--stars", clean, "-m", model_path, "-o",
                           tmp_path / "val", "--no-plots"], capsys)
    assert code == 0, err
    assert "model dimensions after x, y: G_I" in out
    table = Table.read(tmp_path / "val" / "validation.csv")
    # the same residuals as the library's on the same stars with their colours
    X = np.column_stack([stars["x"], stars["y"], colour])[good]
    vignets = np.asarray(stars["VIGNET"])[good]
    lib, _ = validate_models(X, vignets, [str(model_path)])
    assert table["e_rms"][0] == pytest.approx(lib["e_rms"][0], abs=5e-5)  # printed to 4 places
    assert np.isfinite(table["dM22_rel_rms"][0]) and np.isfinite(table["rho_M4_mean_abs"][0])
    with pytest.raises(ValueError, match="1 dimensions after x, y"):
        validate_models(X[:, :2], vignets, [str(model_path)])
    # the stars without their colour column: an error naming it
    stars[["x", "y", "VIGNET"]].write(tmp_path / "plain.fits")
    code, _, err = _run(["validate", "--stars", tmp_path / "plain.fits", "-m", model_path,
                         "-o", tmp_path / "val2", "--no-plots"], capsys)
    assert code == 2 and "no column 'G_I'" in err
