"""``sklearn-psf fit`` and ``sklearn-psf predict`` end to end on a simulated exposure."""

import ast
import os
import re
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from astropy.io import fits
from astropy.table import Table
from numpy.testing import assert_allclose

from sklearn_psf.cli import main
from sklearn_psf.io import FITSHeaderWarning, write_ldac
from sklearn_psf.model import load_model, read_model_validation
from sklearn_psf.simulate import write_example_exposure
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
    for name in ("stamps", "whiskers", "rho", "maps"):
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
    # the stars measured on the image's cut-outs: one saturated and one with a masked pixel
    # are rejected by the selection, one more with a masked core pixel skipped when cut
    assert "selected as stars: 118 (rejected: saturated 1, off_locus 1)" in out
    assert "stars used: 117 of 118 (skipped: masked 1)" in out
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
    assert_allclose(Table.read(tmp_path / "psfs1.fits")["psf"], table["psf"], rtol=1e-12,
                    atol=1e-15)  # x + 1 - 1 may differ from x by one ulp


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
         r"no position columns.*columns found: ra, dec; its \(RA, Dec\) columns ra, dec are "
         r"read with sky=True \(predict --radec"),
        (["fit", tmp_path / "cat.ldac", "-o", out],
         r"holds no 2-D image HDU .*FITS_LDAC catalogue: give it as the star catalogue "
         r"\(fit --stars CATALOG"),
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
    write_ldac(tmp_path / "cat.ldac", Table({"X_IMAGE": [10.0], "Y_IMAGE": [20.0]}))
    data = open(exposure["image"], "rb").read()
    (tmp_path / "trunc.fits").write_bytes(data[: len(data) // 2])
    for args, pattern in cases:
        code, _, err = _run(args, capsys)
        _one_line_error(code, err, pattern)
        assert not out.exists() and not (tmp_path / "p.fits").exists()
    leftovers = [n for n in os.listdir(tmp_path) if n.endswith(".tmp")]
    assert leftovers == []
    # --debug anywhere on the command line shows the traceback (the error is raised)
    for args in (["--debug", "fit", tmp_path / "cat.ldac", "-o", out],
                 ["fit", tmp_path / "cat.ldac", "--debug", "-o", out]):
        with pytest.raises(ValueError, match="FITS_LDAC catalogue"):
            main([str(a) for a in args])
    # argparse errors: exit 2 as well
    for args in (["fit", noise, "-o", out, "--reserve", "1.5"],
                 ["fit", noise, "-o", out, "--stamp-size", "3"],
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
    assert ("selected as stars: 118 (rejected: bad_position 1, saturated 1, near_edge 1, "
            "off_locus 1)") in out
    assert "stars used: 117 of 118 (skipped: masked 1)" in out
    assert load_model(tmp_path / "m.fits").X_fit_.shape == (117, 2)


# ------------------------------------------------------------------------------------------
# catalogue input (issue: real inputs as astronomers hold them)
# ------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def ldac(tmp_path_factory):
    from sklearn_psf.simulate import write_example_ldac

    return write_example_ldac(tmp_path_factory.mktemp("ldac"), n_stars=200, n_galaxies=200,
                              image_shape=(2400, 2400), random_state=5)


def test_fit_on_ldac_vignettes_alone_then_predict(tmp_path, ldac, capsys):
    """No image: the galaxies of the catalogue are rejected, the model matches the truth."""
    old = os.umask(0o022)
    try:
        code, out, err = _run(["fit", "--stars", ldac["catalog"], "-o", tmp_path / "m.fits",
                               "--min-snr", "20"], capsys)
    finally:
        os.umask(old)
    assert code == 0, err
    assert "off_locus" in out and "selected as stars" in out
    n_clean = int(((ldac["kind"] == "star") & (ldac["defect"] == "")).sum())
    model = load_model(tmp_path / "m.fits")
    fitted = model.X_fit_
    truth = ldac["truth"]
    from scipy.spatial import cKDTree

    true_xy = np.column_stack([truth["x"], truth["y"]])
    dist, nearest = cKDTree(true_xy).query(fitted)
    is_star = dist < 1e-6
    assert is_star.mean() > 0.95           # fitted objects are stars, not galaxies
    assert len(fitted) >= 0.9 * 0.8 * n_clean  # 80% fitted, 20% reserved
    for name in ("stamps", "whiskers", "rho", "maps"):
        path = tmp_path / f"m_{name}.png"
        assert path.stat().st_size > 1000
        assert path.stat().st_mode & 0o777 == 0o644   # readable by collaborators
    assert (tmp_path / "m.fits").stat().st_mode & 0o777 == 0o644
    _, summary = read_model_validation(tmp_path / "m.fits")
    assert all(summary[f"rho{k}"] is not None for k in range(1, 6))

    # predict at the true star positions given as RA-less SExtractor ASCII, sub-pixel centred
    cat = tmp_path / "pos.cat"
    truth = truth[np.unique(nearest[is_star])][:30]   # fitted stars: inside the hull
    rows = "".join(f"{i + 1:6d} {x + 1:15.9f} {y + 1:15.9f}\n"
                   for i, (x, y) in enumerate(zip(truth["x"], truth["y"])))
    cat.write_text("#   1 NUMBER    Running object number\n"
                   "#   2 X_IMAGE   Object position along x   [pixel]\n"
                   "#   3 Y_IMAGE   Object position along y   [pixel]\n" + rows
                   + f"{31:6d} {9000.0:12.4f} {9000.0:12.4f}\n")
    code, out, err = _run(["predict", tmp_path / "m.fits", "--positions", cat, "--centered",
                           "-o", tmp_path / "p.fits"], capsys)
    assert code == 0, err
    table = Table.read(tmp_path / "p.fits")
    assert table["extrapolated"].tolist() == [False] * 30 + [True]
    assert "1 extrapolated" in out
    de = np.hypot(table["e1"][:30] - truth["e1"], table["e2"][:30] - truth["e2"])
    assert np.sqrt(np.mean(de**2)) < 0.02

    # sky coordinates: the catalogue's WCS is kept with the model; RA/Dec in and out
    assert summary["rho_theta_units"] == "arcmin" and "wcs" in summary
    from astropy.wcs import WCS

    wcs = WCS(fits.Header.fromstring(summary["wcs"]))
    ra, dec = wcs.all_pix2world(truth["x"], truth["y"], 0)
    Table({"ALPHA_J2000": ra, "DELTA_J2000": dec}).write(tmp_path / "sky.fits")
    code, _, err = _run(["predict", tmp_path / "m.fits", "--positions", tmp_path / "sky.fits",
                         "--radec", "-o", tmp_path / "psky.fits"], capsys)
    assert code == 0, err
    sky = Table.read(tmp_path / "psky.fits")
    assert_allclose(sky["x"], truth["x"], atol=1e-6)
    assert_allclose(sky["y"], truth["y"], atol=1e-6)
    assert_allclose(sky["ra"], ra) and (sky["extrapolated"] == 0).all()
    assert_allclose(table["ra"][:30], ra, rtol=1e-12)  # pixel input: RA/Dec returned too


def test_predict_x_col_oversampling_and_errors(tmp_path, exposure, capsys, monkeypatch):
    model_path = tmp_path / "m.fits"
    code, _, err = _run(["fit", exposure["image"], "--hdu", "SCI", "--stars",
                         exposure["stars"], "-o", model_path, "--no-plots", "--reserve", "0",
                         "--interpolator", "polynomial"], capsys)
    assert code == 0, err
    Table({"XC": [300.5, 700.0], "YC": [400.0, 650.25]}).write(tmp_path / "g.csv",
                                                                format="ascii.csv")
    code, _, err = _run(["predict", model_path, "--positions", tmp_path / "g.csv", "--x-col",
                         "XC", "--y-col", "YC", "--oversampling", "3", "--centered", "-o",
                         tmp_path / "p.fits"], capsys)
    assert code == 0, err
    table = Table.read(tmp_path / "p.fits")
    s = load_model(model_path).stamp_size_
    assert table["psf"].shape == (2, 3 * s, 3 * s)
    plain = load_model(model_path).predict([[300.5, 400.0]])
    sigma_plain = adaptive_moments(plain)["sigma"][0]
    assert_allclose(table["sigma"][0], sigma_plain, rtol=0.02)   # in image pixels
    # an unwritable output fails before any work, naming the user's path
    import sklearn_psf.io
    import sklearn_psf.model

    def no_work(*args, **kwargs):
        raise AssertionError("the output must be checked before the work starts")

    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    early = [(["fit", exposure["image"], "-o", "/proc/m.fits"],   # even for root
              r"cannot write the output file '/proc/m\.fits'"),
             (["predict", model_path, "--positions", tmp_path / "g.csv", "-o",
               "/proc/p.fits"], r"cannot write the output file '/proc/p\.fits'")]
    if os.geteuid() != 0:   # root writes anywhere
        early.append((["fit", exposure["image"], "-o", locked / "m.fits"],
                      r"cannot write the output file .*locked/m\.fits"))
    try:
        with monkeypatch.context() as patch:
            patch.setattr(sklearn_psf.io, "read_image", no_work)
            patch.setattr(sklearn_psf.model, "load_model", no_work)
            for args, pattern in early:
                code, _, err = _run(args, capsys)
                _one_line_error(code, err, pattern)
    finally:
        locked.chmod(0o700)
    cases = [
        (["fit", "-o", tmp_path / "x.fits"], r"give a FITS image, or a catalogue"),
        (["fit", exposure["image"], "--stars", exposure["stars"], "--x-col", "X_IMAGE",
          "-o", tmp_path / "x.fits"], r"give both --x-col and --y-col"),
        (["fit", exposure["image"], "--stars", exposure["stars"], "--x-col", "XX",
          "--y-col", "YY", "-o", tmp_path / "x.fits"], r"stars\.fits.*no column 'XX'"),
        (["fit", "--stars", exposure["stars"], "-o", tmp_path / "x.fits"],
         r"stars\.fits: The catalogue has no VIGNET column"),
        (["predict", model_path, "--positions", tmp_path / "g.csv", "--radec",
          "-o", tmp_path / "p2.fits"], r"has no WCS"),
    ]
    for args, pattern in cases:
        code, _, err = _run(args, capsys)
        _one_line_error(code, err, pattern)


def test_multi_extension_one_model_per_ccd(tmp_path, exposure, capsys):
    with fits.open(exposure["image"]) as hdul:
        sci = hdul["SCI"]
        data, header = sci.data, sci.header
        ccds = [fits.ImageHDU(data, header=header, name="CCD1"),
                fits.ImageHDU(data[:, ::-1], header=header, name="CCD2")]
    fits.HDUList([fits.PrimaryHDU(), *ccds]).writeto(tmp_path / "mef.fits")
    code, out, err = _run(["fit", tmp_path / "mef.fits", "--hdu", "all", "-o",
                           tmp_path / "psf.fits", "--no-plots", "--interpolator",
                           "polynomial"], capsys)
    assert code == 0, err
    m1, m2 = load_model(tmp_path / "psf_CCD1.fits"), load_model(tmp_path / "psf_CCD2.fits")
    nx = data.shape[1]
    # CCD2 is CCD1 mirrored in x: its PSFs are the mirror images (e2 changes sign)
    X = np.array([[400.0, 500.0], [900.0, 300.0]])
    a = adaptive_moments(m1.predict(X))
    b = adaptive_moments(m2.predict(np.column_stack([nx - 1 - X[:, 0], X[:, 1]])))
    assert_allclose(b["e1"], a["e1"], atol=0.01)
    assert_allclose(b["e2"], -np.asarray(a["e2"]), atol=0.01)
    code, _, err = _run(["fit", tmp_path / "mef.fits", "--hdu", "all", "--weight-hdu", "1",
                         "-o", tmp_path / "psf.fits"], capsys)
    _one_line_error(code, err, r"--hdu all cannot take one --weight-hdu")


def test_non_standard_header_image_is_read(tmp_path, exposure, capsys):
    """An ESO-like keyword: a warning, the fit runs."""
    with fits.open(exposure["image"]) as hdul:
        data, header = hdul["SCI"].data, hdul["SCI"].header.copy()
    fits.PrimaryHDU(data, header=header).writeto(tmp_path / "eso.fits")
    raw = bytearray((tmp_path / "eso.fits").read_bytes())
    end = raw.find(b"END" + b" " * 77)
    raw[end:end + 160] = (b"ESO-LOG 1 = 'non-standard keyword'".ljust(80)
                          + b"END".ljust(80))
    (tmp_path / "eso.fits").write_bytes(bytes(raw))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        code, out, err = _run(["fit", tmp_path / "eso.fits", "--stars", exposure["stars"],
                               "-o", tmp_path / "m.fits", "--no-plots", "--reserve", "0",
                               "--interpolator", "polynomial"], capsys)
    assert code == 0, err
    header_warnings = [w for w in caught if "non-standard" in str(w.message)]
    assert len(header_warnings) == 1   # one clear warning, not astropy's raw ones
    assert issubclass(header_warnings[0].category, FITSHeaderWarning)


# ------------------------------------------------------------- catalogues as SExtractor writes
def _used_positions(path):
    """Positions of the stars a model file used: fitted inliers and reserved stars."""
    model = load_model(path)
    residuals, summary = read_model_validation(path)
    used = model.X_fit_[model.inlier_mask_]
    if residuals is not None:
        used = np.vstack([used, np.column_stack([residuals["x"], residuals["y"]])])
    return used, summary


def test_default_fit_on_a_sextractor_ldac(tmp_path, sextractor_ldac, capsys):
    """CLASS_STAR 0.55-0.75 for every point source, S/N 20-300, 30% galaxies, -1e30 pixels,
    the header in a TDIM (80, N) cell: the default command keeps the stars, not the galaxies,
    reads the header without a word, keeps its WCS (TPV) and SATURATE, and trusts its model."""
    from astropy.wcs import WCS
    from scipy.spatial import cKDTree

    cat = sextractor_ldac
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        code, out, err = _run(["fit", "--stars", cat["path"], "-o", tmp_path / "m.fits",
                               "--no-plots"], capsys)
    assert code == 0, err
    assert not [w for w in caught if issubclass(w.category, FITSHeaderWarning)]
    assert "warning" not in err  # a good model: no PSFQualityWarning
    assert "not applied: CLASS_STAR >= 0.8" in out and "100% of the sources" in out
    used, summary = _used_positions(tmp_path / "m.fits")
    dist, row = cKDTree(np.column_stack([cat["x"], cat["y"]])).query(used)
    assert dist.max() < 1e-3
    kind = cat["kind"][row]
    n_stars, n_gal = (cat["kind"] == "star").sum(), (cat["kind"] == "galaxy").sum()
    assert (kind == "star").sum() >= 0.9 * n_stars   # measured 0.986-1 (seeds 0-4)
    assert (kind == "galaxy").sum() <= 0.03 * n_gal    # measured 0 (seeds 0-4)
    assert not np.isin(kind, ["saturated", "blend"]).any()
    # the model file: SATURATE and the TPV WCS of the header (the catalogue's RA, Dec)
    assert summary["saturation"] == 38000.0 and summary["gain"] == 4.0
    wcs = WCS(fits.Header.fromstring(summary["wcs"]))
    with fits.open(cat["path"]) as hdul:
        objects = hdul["LDAC_OBJECTS"].data
        ra, dec = wcs.all_pix2world(objects["X_IMAGE"] - 1, objects["Y_IMAGE"] - 1, 0)
        assert np.max(np.abs(ra - objects["ALPHA_J2000"]) * 3600) < 1e-4   # arcsec
        assert np.max(np.abs(dec - objects["DELTA_J2000"]) * 3600) < 1e-4
    assert summary["rho_theta_units"] == "arcmin"
    # the verdict is printed: components and why, residuals against the noise, rho1-rho5
    assert "basis: " in out and "noise edge" in out
    assert "against their own noise" in out
    for k in range(1, 6):
        assert f"rho{k} " in out
    assert summary["e_resid_over_noise"] < 1.5 < summary["e_resid_over_noise_constant"]


def test_a_wrong_model_is_flagged(tmp_path, sextractor_ldac, capsys):
    """Without selection the galaxies are fitted as stars: the reserved ones fail the
    outlier test, more than 10% of the reserved stars, and fit says so."""
    code, out, err = _run(["fit", "--stars", sextractor_ldac["path"], "--no-select",
                           "-o", tmp_path / "m.fits", "--no-plots"], capsys)
    assert code == 0, err
    warned = [line for line in err.splitlines() if line.startswith("sklearn-psf: warning:")]
    # the reserved galaxies fail the outlier test (9 of 41), which says so
    assert any("fail the model's outlier test" in line for line in warned), err
    _, summary = read_model_validation(tmp_path / "m.fits")
    assert summary["n_reserved_outliers"] > 0.1 * summary["n_reserved"]


def test_too_few_stars_names_each_cut_and_its_option(tmp_path, sextractor_ldac, capsys):
    code, out, err = _run(["fit", "--stars", sextractor_ldac["path"], "--min-snr", "2000",
                           "-o", tmp_path / "m.fits"], capsys)
    _one_line_error(code, err, r"0 of the 205 sources .* pass the star selection: too few .*"
                    r"low_snr 200 \(--min-snr\), saturated 3 \(--saturation\)")
    assert "flags 2 (--flag-mask)" in err
    assert "sources in the catalogue: 205" in out   # what was found is printed first
    # every cut is an option: relaxing them lets every source through the cuts
    code, out, err = _run(["fit", "--stars", sextractor_ldac["path"], "--min-snr", "0",
                           "--flag-mask", "0", "--saturation", "1e9", "--locus-width", "10",
                           "--isolation", "0", "--min-class-star", "0", "-o",
                           tmp_path / "all.fits", "--no-plots"], capsys)
    assert code == 0 and "selected as stars: 205\n" in out


def test_outputs_are_never_overwritten_unless_told(tmp_path, exposure, capsys):
    model_path = tmp_path / "m.fits"
    args = ["fit", exposure["image"], "--hdu", "SCI", "--stars", exposure["stars"], "-o",
            model_path, "--reserve", "0", "--interpolator", "polynomial"]
    assert _run([*args, "--no-plots"], capsys)[0] == 0
    before = model_path.read_bytes()
    code, _, err = _run(args, capsys)
    _one_line_error(code, err, r"m\.fits' already exists: pass --overwrite to replace it")
    assert model_path.read_bytes() == before
    (tmp_path / "m2_maps.png").write_bytes(b"a figure of an earlier run")
    code, _, err = _run([*args[:-4], "-o", tmp_path / "m2.fits"], capsys)
    _one_line_error(code, err, r"m2_maps\.png' already exists")
    assert _run([*args, "--overwrite", "--no-plots"], capsys)[0] == 0
    Table({"x": [300.0], "y": [400.0]}).write(tmp_path / "g.csv", format="ascii.csv")
    pred = ["predict", model_path, "--positions", tmp_path / "g.csv", "-o", tmp_path / "p.fits"]
    assert _run(pred, capsys)[0] == 0
    code, _, err = _run(pred, capsys)
    _one_line_error(code, err, r"p\.fits' already exists: pass --overwrite")
    assert _run([*pred, "--overwrite"], capsys)[0] == 0


def test_nan_pixels_are_counted(tmp_path, exposure, capsys):
    with fits.open(exposure["image"]) as hdul:
        data = hdul["SCI"].data.astype(np.float32)
        header = hdul["SCI"].header
    data[:100, :1100] = np.nan
    fits.PrimaryHDU(data, header=header).writeto(tmp_path / "nan.fits")
    code, out, err = _run(["fit", tmp_path / "nan.fits", "-o", tmp_path / "m.fits",
                           "--no-plots", "--interpolator", "polynomial"], capsys)
    assert code == 0, err
    assert f"NaN pixels: {int(np.isnan(data).sum())} " in out


# ------------------------------------------------------------- many CCDs, in parallel or not
def _same_model_files(a, b):
    """Every HDU of two model files equal byte for byte but for the DATE card (the time of
    writing), and the same predictions."""
    with fits.open(a) as ha, fits.open(b) as hb:
        assert [h.name for h in ha] == [h.name for h in hb]
        for x, y in zip(ha, hb):
            hx, hy = x.header.copy(), y.header.copy()
            for h in (hx, hy):
                h.remove("DATE", ignore_missing=True)
            assert hx.tostring() == hy.tostring(), x.name
            if x.data is not None:
                assert np.asarray(x.data).tobytes() == np.asarray(y.data).tobytes(), x.name
    X = np.array([[10.0, 20.0], [650.0, 640.0], [1900.0, 90.0]])
    np.testing.assert_array_equal(load_model(a).predict(X), load_model(b).predict(X))


@pytest.fixture(scope="module")
def ccds(tmp_path_factory):
    """A multi-extension exposure of 3 CCDs (an example CCD of 200 stars, mirrored in x,
    flipped in y) and its models fitted one after the other (--n-jobs 1), by the command in a
    fresh process whose BLAS may use 2 threads (each fit of several must use one, whatever is
    loaded when: at this size 2 threads change the last bits of the models)."""
    folder = tmp_path_factory.mktemp("ccds")
    ccd = write_example_exposure(folder, n_stars=200, image_shape=(2000, 2000), n_galaxies=0,
                                 random_state=1)
    with fits.open(ccd["image"]) as hdul:
        data, header = hdul["SCI"].data, hdul["SCI"].header
        hdus = [fits.ImageHDU(d, header=header, name=f"CCD{k + 1}")
                for k, d in enumerate((data, data[:, ::-1], data[::-1]))]
    fits.HDUList([fits.PrimaryHDU(), *hdus]).writeto(folder / "mef.fits")
    (folder / "serial").mkdir()
    threads = {k: "2" for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}
    proc = subprocess.run([sys.executable, "-m", "sklearn_psf", "fit", str(folder / "mef.fits"),
                           "--hdu", "all", "--no-plots", "--n-jobs", "1", "-o",
                           str(folder / "serial" / "psf.fits")], capture_output=True,
                          text=True, env={**os.environ, **threads})
    assert proc.returncode == 0, proc.stderr
    return {"mef": folder / "mef.fits", "serial": folder / "serial", "out": proc.stdout}


@pytest.fixture
def environ_kept():
    """Restores os.environ: a Dask nanny sets its workers' variables in the process that
    starts it."""
    saved = dict(os.environ)
    yield
    os.environ.clear()
    os.environ.update(saved)


def test_ccds_in_parallel_give_the_serial_models(tmp_path, ccds, capsys):
    """--n-jobs 2: the same model files as one after the other (and as each CCD fitted on its
    own), each CCD's report in order."""
    names = [f"psf_CCD{k}.fits" for k in (1, 2, 3)]
    assert sorted(p.name for p in ccds["serial"].iterdir()) == names
    code, out, err = _run(["fit", ccds["mef"], "--hdu", "all", "--no-plots", "--n-jobs", "2",
                           "-o", tmp_path / "psf.fits"], capsys)
    assert code == 0, err
    for name in names:
        _same_model_files(ccds["serial"] / name, tmp_path / name)
    # the reports as the serial run prints them, in the CCDs' order, the paths as given
    assert out.replace(str(tmp_path), "OUT") == ccds["out"].replace(str(ccds["serial"]), "OUT")
    heads = [line for line in out.splitlines() if " -> " in line]
    assert heads == [f"{ccds['mef']}[CCD{k}] -> {tmp_path / f'psf_CCD{k}.fits'}"
                     for k in (1, 2, 3)]
    assert out.count("Wrote ") == 3 and out.count("reserved stars (star - model") == 3
    assert "fitting" in err   # the progress bar over the CCDs
    # a CCD fitted on its own: the same model (up to the BLAS threads' rounding)
    assert _run(["fit", ccds["mef"], "--hdu", "CCD2", "--no-plots", "-o",
                 tmp_path / "alone.fits"], capsys)[0] == 0
    X = np.array([[10.0, 20.0], [650.0, 640.0], [1900.0, 90.0]])
    assert_allclose(load_model(tmp_path / "alone.fits").predict(X),
                    load_model(tmp_path / "psf_CCD2.fits").predict(X), rtol=1e-9, atol=1e-14)


def _pid_after(seconds):
    import time

    time.sleep(seconds)
    return os.getpid()


def test_map_ordered_shares_the_items_with_a_worker_and_keeps_their_order():
    """The fits of many CCDs: this process and a worker each take the next item when free,
    the results come in the items' order, an item's exception is raised at its turn."""
    import math

    import cloudpickle

    from sklearn_psf.cli._parallel import map_ordered

    cloudpickle.register_pickle_by_value(sys.modules[__name__])  # the worker cannot import it
    try:
        pids = list(map_ordered(_pid_after, [0.25] * 12, n_jobs=2))
    finally:
        cloudpickle.unregister_pickle_by_value(sys.modules[__name__])
    assert os.getpid() in pids and len(set(pids)) == 2
    assert list(map_ordered(math.sqrt, [4, 9, 16, 25, 36], n_jobs=2)) == [2, 3, 4, 5, 6]
    results = map_ordered(math.sqrt, [4, -1, 9, 16], n_jobs=2)
    assert next(results) == 2
    with pytest.raises(ValueError, match="math domain error"):
        next(results)
    assert list(map_ordered(math.sqrt, [4, 9], n_jobs=1)) == [2, 3]


def test_ccds_on_a_dask_cluster_give_the_serial_models(tmp_path, ccds, capsys, environ_kept):
    distributed = pytest.importorskip("distributed", reason="the dask extra is not installed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        code, out, err = _run(["fit", ccds["mef"], "--hdu", "all", "--no-plots", "--scheduler",
                               cluster.scheduler_address, "-o", tmp_path / "psf.fits"], capsys)
    assert code == 0, err
    for k in (1, 2, 3):
        _same_model_files(ccds["serial"] / f"psf_CCD{k}.fits", tmp_path / f"psf_CCD{k}.fits")
    # Dask's default workers: the command says how to start them as fast as local processes
    note = [line for line in err.splitlines() if "MALLOC_TRIM_THRESHOLD_" in line]
    assert len(note) == 1 and "2 of the cluster's 2 Dask workers" in note[0]


def test_documented_dask_workers_leave_the_trim_threshold_unset():
    """The worker environment the note and docs/cli.rst give removes Dask's
    MALLOC_TRIM_THRESHOLD_ and keeps its one BLAS thread per worker."""
    pytest.importorskip("distributed", reason="the dask extra is not installed")
    import shlex

    from sklearn_psf.cli._parallel import FAST_WORKERS

    assignment = shlex.split(FAST_WORKERS)[0]
    name, value = assignment.split("=", 1)
    code = ("import dask, distributed; "
            "print(dask.config.get('distributed.nanny.pre-spawn-environ'))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          env={**os.environ, name: value})
    assert proc.returncode == 0, proc.stderr
    environ = ast.literal_eval(proc.stdout.strip())
    assert environ["MALLOC_TRIM_THRESHOLD_"] is None
    assert environ["OPENBLAS_NUM_THREADS"] == environ["OMP_NUM_THREADS"] == 1
    docs = (Path(__file__).parents[1] / "docs" / "cli.rst").read_text()
    assert FAST_WORKERS.split(" dask worker")[0] in docs   # the same setting documented


def test_documented_dask_preload_imports_the_fitting_code_before_the_first_task(
        environ_kept):
    """Workers started with the documented --preload have the modules a fit imports loaded
    before any task (a fresh cluster's first fits do not wait for them)."""
    distributed = pytest.importorskip("distributed", reason="the dask extra is not installed")
    import shlex

    from sklearn_psf.cli._parallel import FAST_WORKERS, PRELOAD

    words = shlex.split(FAST_WORKERS)
    assert words[words.index("--preload") + 1] == PRELOAD
    assert f"--preload {PRELOAD}" in (Path(__file__).parents[1] / "docs" / "cli.rst").read_text()
    fit_modules = ("sklearn", "sklearn_psf.io", "sklearn_psf.model", "sklearn_psf.validation")

    def loaded():
        return [m for m in fit_modules if m in sys.modules]

    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                                  dashboard_address=None, preload=[PRELOAD]) as cluster, \
            distributed.Client(cluster) as client:
        assert list(client.run(loaded).values()) == [list(fit_modules)]


def test_images_and_catalogues_paired_in_order(tmp_path, exposure, capsys):
    """Several images with one catalogue each: one model per image, named after it, each
    from its own catalogue."""
    with fits.open(exposure["image"]) as hdul:
        sci, wgt = hdul["SCI"], hdul["WGT"]
        nx = sci.data.shape[1]
        for name, flip in (("a", slice(None)), ("b", slice(None, None, -1))):
            fits.HDUList([fits.PrimaryHDU(),
                          fits.ImageHDU(sci.data[:, flip], header=sci.header, name="SCI"),
                          fits.ImageHDU(wgt.data[:, flip], name="WGT")]).writeto(
                tmp_path / f"{name}.fits")
    stars = Table.read(exposure["stars"])
    stars.write(tmp_path / "a_cat.fits")
    stars["X_IMAGE"] = nx + 1 - stars["X_IMAGE"]   # 1-based: pixel 1 <-> pixel nx
    stars.write(tmp_path / "b_cat.fits")
    args = ["fit", tmp_path / "a.fits", tmp_path / "b.fits", "--hdu", "SCI", "--weight-hdu",
            "WGT", "--stars", tmp_path / "a_cat.fits", tmp_path / "b_cat.fits", "--no-plots",
            "--interpolator", "polynomial", "--n-jobs", "2", "-o", tmp_path / "psf.fits"]
    code, out, err = _run(args, capsys)
    assert code == 0, err
    a, b = load_model(tmp_path / "psf_a.fits"), load_model(tmp_path / "psf_b.fits")
    assert len(a.X_fit_) == len(b.X_fit_) > 80
    assert_allclose(np.sort(nx - 1 - b.X_fit_[:, 0]), np.sort(a.X_fit_[:, 0]), atol=1e-9)
    # as many catalogues as images, or none
    code, _, err = _run(["fit", tmp_path / "a.fits", tmp_path / "b.fits", "--stars",
                         tmp_path / "a_cat.fits", "-o", tmp_path / "x.fits"], capsys)
    _one_line_error(code, err, r"1 catalogues \(--stars\) for 2 images: give one catalogue "
                               r"per image, in the same order, or none")
    # two inputs of the same name would write the same model file
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "a.fits").write_bytes((tmp_path / "a.fits").read_bytes())
    code, _, err = _run(["fit", tmp_path / "a.fits", tmp_path / "other" / "a.fits", "-o",
                         tmp_path / "y.fits"], capsys)
    _one_line_error(code, err, r"would both be written to .*y_a\.fits'")


def test_a_failed_ccd_leaves_the_others_written(tmp_path, exposure, capsys):
    """One CCD without stars: its error is reported, the other CCD's model is written, the
    command ends in error naming the failed CCD."""
    rng = np.random.default_rng(1)
    with fits.open(exposure["image"]) as hdul:
        good = fits.ImageHDU(hdul["SCI"].data, header=hdul["SCI"].header, name="GOOD")
    noise = fits.ImageHDU(rng.normal(0, 1, (400, 400)).astype(np.float32), name="EMPTY")
    fits.HDUList([fits.PrimaryHDU(), noise, good]).writeto(tmp_path / "mef.fits")
    code, out, err = _run(["fit", tmp_path / "mef.fits", "--hdu", "all", "--no-plots",
                           "--interpolator", "polynomial", "--n-jobs", "2", "-o",
                           tmp_path / "psf.fits"], capsys)
    assert code == 2
    errors = [line for line in err.splitlines() if line.startswith("sklearn-psf: error")]
    assert len(errors) == 2 and "Traceback" not in err
    assert re.search(r"^sklearn-psf: error: .*mef\.fits\[EMPTY\]: found 0 usable stars",
                     errors[0]), errors
    assert errors[1] == (f"sklearn-psf: error: 1 of 2 fits failed ({tmp_path / 'mef.fits'}"
                         "[EMPTY]: errors above); the other models were written")
    assert not (tmp_path / "psf_EMPTY.fits").exists()
    assert load_model(tmp_path / "psf_GOOD.fits").n_components_ >= 1
    assert "Wrote " in out
    # a number of jobs of 0 is refused by the parser
    with pytest.raises(SystemExit) as exc:
        main(["fit", str(tmp_path / "mef.fits"), "--n-jobs", "0", "-o", str(tmp_path / "z")])
    assert exc.value.code == 2
