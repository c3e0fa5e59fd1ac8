"""``sklearn-psf fit`` and ``sklearn-psf predict`` end to end on a simulated exposure."""

import os

import numpy as np
import pytest
from astropy.io import fits
from astropy.table import Table
from numpy.testing import assert_allclose

from sklearn_psf.cli import main
from sklearn_psf.io import load_model, read_model_validation, write_example_exposure
from sklearn_psf.measure import adaptive_moments


@pytest.fixture(scope="module")
def exposure(tmp_path_factory):
    folder = tmp_path_factory.mktemp("exposure")
    return write_example_exposure(folder, n_stars=120, image_shape=(1300, 1300),
                                  n_galaxies=40, compress=True, random_state=2)


def _run(args, capsys):
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def test_fit_then_predict(tmp_path, exposure, capsys):
    model_path = tmp_path / "psf.fits"
    code, out, err = _run(["fit", exposure["image"], "--hdu", "SCI", "--weight-hdu", "WGT",
                           "-o", model_path, "--seed", "1"], capsys)
    assert code == 0, err
    assert "selected as stars" in out and "rejected:" in out
    assert "saturated 1" in out  # the clipped star is found and rejected
    assert "reserved stars" in out and "e rms" in out and "rho1" in out
    for name in ("stamps", "whiskers", "rho1"):
        assert (tmp_path / f"psf_{name}.png").stat().st_size > 1000
    model = load_model(model_path)
    residuals, summary = read_model_validation(model_path)
    assert summary["n_reserved"] == len(residuals) > 10
    assert summary["interpolator"] == "kriging"
    assert f"e rms {summary['e_rms']:.4f}" in out
    assert summary["e_rms"] < 0.03

    # with the SExtractor catalogue (1-based X_IMAGE): the spoiled stars are skipped, counted
    code, out, err = _run(["fit", exposure["image"], "--hdu", "1", "--weight-hdu", "2",
                           "--stars", exposure["stars"], "-o", tmp_path / "cat.fits",
                           "--no-plots", "--interpolator", "delaunay"], capsys)
    assert code == 0, err
    assert "stars used: 117 of 120 (skipped: masked 2, saturated 1)" in out
    assert "1-based X_IMAGE" in out
    assert not (tmp_path / "cat_stamps.png").exists()

    out_path = tmp_path / "psfs.fits"
    code, out, err = _run(["predict", model_path, "--positions", exposure["galaxies"],
                           "-o", out_path], capsys)
    assert code == 0, err
    table = Table.read(out_path)
    gal = Table.read(exposure["galaxies"])
    assert len(table) == len(gal) == 40
    X = np.column_stack([gal["x"], gal["y"]])
    stamps = model.predict(X)
    assert_allclose(table["psf"].reshape(40, -1), stamps, rtol=1e-12, atol=1e-15)
    mom = adaptive_moments(stamps)
    assert_allclose(table["e1"], mom["e1"])
    assert_allclose(table["sigma"], mom["sigma"])
    # the model's PSF at the galaxies is close to the truth there
    truth = Table.read(exposure["truth"])
    truth = truth[truth["kind"] == "galaxy"]
    de = np.hypot(table["e1"] - truth["e1"], table["e2"] - truth["e2"])
    assert np.sqrt(np.mean(de**2)) < 0.03
    # 1-based positions: the same PSFs
    one = Table({"x": gal["x"] + 1, "y": gal["y"] + 1})
    one.write(tmp_path / "one.csv", format="ascii.csv")
    code, _, err = _run(["predict", model_path, "--positions", tmp_path / "one.csv",
                         "--one-based", "-o", tmp_path / "psfs1.fits"], capsys)
    assert code == 0, err
    assert_allclose(Table.read(tmp_path / "psfs1.fits")["psf"], table["psf"], rtol=1e-12)


def _one_line_error(code, err, pattern):
    assert code == 2
    lines = [line for line in err.strip().splitlines() if "error" in line]
    assert len(lines) == 1 and lines[0].startswith("sklearn-psf: error: "), err
    assert "Traceback" not in err
    import re

    assert re.search(pattern, lines[0]), lines[0]


def test_bad_inputs_exit_2(tmp_path, exposure, capsys):
    rng = np.random.default_rng(0)
    noise = tmp_path / "noise.fits"
    fits.PrimaryHDU(rng.normal(0, 1, (400, 400)).astype(np.float32)).writeto(noise)
    out = tmp_path / "m.fits"
    cases = [
        (["fit", noise, "-o", out], r"found 0 usable stars .* too few"),
        (["fit", exposure["image"], "--hdu", "SCI", "--stars", tmp_path / "far.csv", "-o", out],
         r"All 3 catalogue positions fall outside the image"),
        (["fit", exposure["image"], "--hdu", "SCI", "--stars", tmp_path / "cols.csv", "-o", out],
         r"no position columns.*columns found: ra, dec"),
        (["fit", tmp_path / "garbage.fits", "-o", out], r"Could not read .*FITS"),
        (["fit", tmp_path / "trunc.fits", "-o", out], r"Could not read .*FITS"),
        (["fit", tmp_path / "missing.fits", "-o", out], r"does not exist"),
        (["fit", exposure["image"], "--hdu", "NOPE", "-o", out], r"no HDU 'NOPE'"),
        (["fit", exposure["image"], "-o", tmp_path / "nodir" / "m.fits"], r"does not exist"),
        (["predict", noise, "--positions", exposure["galaxies"], "-o", tmp_path / "p.fits"],
         r"not a sklearn_psf PSF model file"),
        (["predict", tmp_path / "garbage.fits", "--positions", exposure["galaxies"], "-o",
          tmp_path / "p.fits"], r"corrupt or truncated"),
    ]
    Table({"x": [-500.0, 5000.0, 2000.0], "y": [10.0, 10.0, -300.0]}).write(
        tmp_path / "far.csv", format="ascii.csv")
    Table({"ra": [1.0], "dec": [2.0]}).write(tmp_path / "cols.csv", format="ascii.csv")
    (tmp_path / "garbage.fits").write_bytes(os.urandom(6000))
    data = open(exposure["image"], "rb").read()
    (tmp_path / "trunc.fits").write_bytes(data[: len(data) // 2])
    for args, pattern in cases:
        code, _, err = _run(args, capsys)
        _one_line_error(code, err, pattern)
        assert not out.exists() and not (tmp_path / "p.fits").exists()
    leftovers = [n for n in os.listdir(tmp_path) if n.endswith(".tmp")]
    assert leftovers == []
    # argparse errors: exit 2 as well
    for args in (["fit", noise, "-o", out, "--reserve", "1.5"],
                 ["fit", noise, "-o", out, "--stamp-size", "24"],
                 ["fit", noise, "-o", out, "--interpolator", "spline"],
                 ["predict", noise, "-o", out]):
        with pytest.raises(SystemExit) as exc:
            main([str(a) for a in args])
        assert exc.value.code == 2
    capsys.readouterr()


def test_some_positions_outside_are_skipped_and_counted(tmp_path, exposure, capsys):
    cat = Table.read(exposure["stars"])
    extra = Table({"NUMBER": [999, 1000], "X_IMAGE": [-100.0, 20.0], "Y_IMAGE": [50.0, 5.0],
                   "FLAGS": [0, 0]}, dtype=cat.dtype)
    from astropy.table import vstack

    vstack([cat, extra]).write(tmp_path / "stars.fits")
    code, out, err = _run(["fit", exposure["image"], "--hdu", "SCI", "--weight-hdu", "WGT",
                           "--stars", tmp_path / "stars.fits", "-o", tmp_path / "m.fits",
                           "--no-plots", "--reserve", "0"], capsys)
    assert code == 0, err
    assert "stars used: 117 of 122 (skipped: off_image 1, edge 1, masked 2, saturated 1)" in out
    assert load_model(tmp_path / "m.fits").X_fit_.shape == (117, 2)
