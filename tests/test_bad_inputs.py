"""Bad and hostile inputs to ``sklearn-psf fit``, ``predict`` and ``validate``: each ends in a
one-line error naming the input, the column or the option (with counts where rows are
rejected), or in a warned fallback; no input file is ever changed."""

import hashlib
import os

import numpy as np
import pytest
from astropy.io import fits
from astropy.table import Table

from sklearn_psf.cli import main
from sklearn_psf.io import CatalogColumnWarning, InputError, read_catalog, read_image, write_ldac
from sklearn_psf.exposure import extract_star_stamps, extract_vignettes, select_stars
from sklearn_psf.simulate import write_example_exposure, write_example_ldac


def _digest(path):
    with open(path, "rb") as f:
        return hashlib.sha256(f.read()).hexdigest()


@pytest.fixture(scope="module")
def ldac(tmp_path_factory):
    """A FITS_LDAC catalogue of 40 stars and 10 galaxies (25x25 VIGNETs, 600x600 image)."""
    folder = tmp_path_factory.mktemp("ldac")
    return write_example_ldac(folder, n_stars=40, n_galaxies=10, image_shape=(600, 600),
                              random_state=0)["catalog"]


@pytest.fixture(scope="module")
def exposure(tmp_path_factory):
    folder = tmp_path_factory.mktemp("exposure")
    return write_example_exposure(folder, n_stars=40, n_galaxies=10, image_shape=(400, 400))


@pytest.fixture(scope="module")
def model(ldac, tmp_path_factory):
    out = str(tmp_path_factory.mktemp("model") / "model.fits")
    assert main(["fit", "--stars", ldac, "-o", out, "--no-plots",
                 "--interpolator", "polynomial"]) == 0
    return out


def _rewrite(src, dst, edit, header_edit=None):
    """A copy of the LDAC ``src`` with its objects table edited by ``edit(table)``."""
    cat = Table.read(src, hdu="LDAC_OBJECTS")
    header = read_catalog(src).meta["image_header"].copy()
    if header_edit is not None:
        header_edit(header)
    write_ldac(dst, edit(cat), header=header)
    return str(dst)


def _error(capsys, argv):
    """Run the command; return its one-line error (exit status 2)."""
    code = main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2, err
    line = [e for e in err if e.startswith("sklearn-psf: error:")]
    assert len(line) == 1, err
    return line[0]


def test_no_rows(ldac, tmp_path, capsys):
    path = _rewrite(ldac, tmp_path / "empty.ldac", lambda t: t[:0])
    before = _digest(path)
    msg = _error(capsys, ["fit", "--stars", path, "-o", str(tmp_path / "m.fits"),
                          "--no-plots"])
    assert "has no rows" in msg and "empty.ldac" in msg
    assert _digest(path) == before and not os.path.exists(tmp_path / "m.fits")


def test_positions_far_off_and_nan_counted(ldac, tmp_path, capsys):
    """10% of the positions 1e6 pixels off the catalogue's image (NAXIS1 x NAXIS2 of
    LDAC_IMHEAD), two NaN: rejected as bad_position and counted; the fit goes on."""
    def edit(t):
        t = Table(t, copy=True)
        n = len(t)
        t["X_IMAGE"][: n // 10] += 1e6
        t["XWIN_IMAGE"] = t["X_IMAGE"] if "XWIN_IMAGE" in t.colnames else t["X_IMAGE"]
        t["Y_IMAGE"][n // 10: n // 10 + 2] = np.nan
        return t

    path = _rewrite(ldac, tmp_path / "far.ldac", edit)
    n = len(read_catalog(path))
    keep, counts = select_stars(read_catalog(path), min_stars=0)
    assert counts["bad_position"] == n // 10 + 2 and counts["flags"] <= 2
    out = str(tmp_path / "m.fits")
    assert main(["fit", "--stars", path, "-o", out, "--no-plots",
                 "--interpolator", "polynomial"]) == 0
    report = capsys.readouterr().out
    assert f"bad_position {n // 10 + 2}" in report


def test_stamp_size_too_large(ldac, exposure, tmp_path, capsys):
    out = str(tmp_path / "m.fits")
    msg = _error(capsys, ["fit", exposure["image"], "--stars", exposure["stars"], "-o", out,
                          "--no-plots", "--stamp-size", "10001"])
    assert "10001" in msg and "--stamp-size" in msg and "image" in msg
    msg = _error(capsys, ["fit", "--stars", ldac, "-o", out, "--no-plots",
                          "--stamp-size", "10001"])
    assert "10001" in msg and "--stamp-size" in msg and "VIGNET" in msg and "crowded" not in msg
    assert not os.path.exists(out)


def test_stamps_beyond_memory_refused_before_allocation():
    """1e5 stamps of 1001 x 1001 pixels would need ~4e15 bytes: refused with the size."""
    image = np.zeros((1001, 1001), dtype=np.float32)
    positions = np.full((100_000, 2), 500.0)
    with pytest.raises(InputError, match=r"100000 stamps of 1001 x 1001.*GiB"):
        extract_star_stamps(image, positions, 1001, subtract_background=False)


@pytest.mark.parametrize("overwrite", [[], ["--overwrite"]])
def test_fit_never_writes_over_its_catalogue(ldac, tmp_path, capsys, overwrite):
    path = str(tmp_path / "in.ldac")
    with open(ldac, "rb") as src, open(path, "wb") as dst:
        dst.write(src.read())
    before = _digest(path)
    msg = _error(capsys, ["fit", "--stars", path, "-o", path, "--no-plots", *overwrite])
    assert "is the input" in msg and "never written over" in msg
    assert _digest(path) == before


@pytest.mark.parametrize("overwrite", [[], ["--overwrite"]])
def test_predict_never_writes_over_its_model(model, exposure, tmp_path, capsys, overwrite):
    path = str(tmp_path / "model.fits")
    with open(model, "rb") as src, open(path, "wb") as dst:
        dst.write(src.read())
    before = _digest(path)
    msg = _error(capsys, ["predict", path, "--positions", exposure["galaxies"], "-o", path,
                          *overwrite])
    assert "is the input" in msg
    assert _digest(path) == before


def test_validate_never_writes_over_its_catalogue(model, tmp_path, capsys):
    stars = tmp_path / "validation.csv"  # the name of validate's table
    Table({"x": [10.0], "y": [20.0]}).write(stars, format="ascii.csv")
    before = _digest(stars)
    msg = _error(capsys, ["validate", "--stars", str(stars), "-m", model, "-o",
                          str(tmp_path), "--overwrite", "--no-plots"])
    assert "is the input" in msg and _digest(stars) == before


def _corrupt_copy(src, dst, with_checksum):
    with fits.open(src) as hdul:
        hdul.writeto(dst, checksum=with_checksum)
    with fits.open(dst) as hdul:
        info = hdul.fileinfo(len(hdul) - 1)
    data = bytearray(open(dst, "rb").read())
    data[info["datLoc"] + info["datSpan"] // 2] ^= 0x40  # one byte of the data
    open(dst, "wb").write(bytes(data))
    return str(dst)


def test_checksum_mismatch_reported(ldac, exposure, tmp_path, capsys):
    bad = _corrupt_copy(ldac, tmp_path / "bad.ldac", with_checksum=True)
    before = _digest(bad)
    with pytest.raises(InputError, match="CHECKSUM/DATASUM"):
        read_catalog(bad)
    msg = _error(capsys, ["fit", "--stars", bad, "-o", str(tmp_path / "m.fits"),
                          "--no-plots"])
    assert "bad.ldac" in msg and "corrupt" in msg and _digest(bad) == before
    image = _corrupt_copy(exposure["image"], tmp_path / "bad.fits", with_checksum=True)
    with pytest.raises(InputError, match="CHECKSUM/DATASUM"):
        read_image(image)
    # without CHECKSUM keywords there is nothing to verify: read as it is
    read_catalog(_corrupt_copy(ldac, tmp_path / "plain.ldac", with_checksum=False))


def test_min_snr_negative_refused(ldac, tmp_path, capsys):
    for option in (["--min-snr", "-1"], ["--saturation", "0"], ["--isolation", "-3"],
                   ["--locus-width", "-0.1"]):
        with pytest.raises(SystemExit) as exc:
            main(["fit", "--stars", ldac, "-o", str(tmp_path / "m.fits"), *option])
        assert exc.value.code == 2
        assert option[0] in capsys.readouterr().err


@pytest.mark.parametrize("cut", [1000, 4000, 10000, 20000, -1000])
def test_truncated_fits(ldac, tmp_path, capsys, cut):
    data = open(ldac, "rb").read()
    path = tmp_path / "cut.ldac"
    path.write_bytes(data[:cut])
    with pytest.raises(InputError, match="truncated or corrupt"):
        read_catalog(path)
    msg = _error(capsys, ["fit", "--stars", str(path), "-o", str(tmp_path / "m.fits"),
                          "--no-plots"])
    assert "truncated or corrupt" in msg and "Field Header Card" not in msg


def test_flux_radius_all_zero_falls_back_with_a_warning(ldac, tmp_path, capsys):
    def edit(t):
        t = Table(t, copy=True)
        t["FLUX_RADIUS"] = 0.0
        return t

    path = _rewrite(ldac, tmp_path / "r0.ldac", edit)
    with pytest.warns(CatalogColumnWarning, match="FLUX_RADIUS is 0.*all 52 rows"):
        cat = read_catalog(path)
    assert "flux_radius" not in [c.lower() for c in cat.colnames]
    keep, counts = select_stars(cat, min_stars=0)
    assert counts["locus_size"] in ("adaptive_sigma", "adaptive_sigma_masked")
    assert keep.sum() >= 30 and counts["off_locus"] >= 8   # the galaxies, as with the column
    with pytest.warns(CatalogColumnWarning):
        assert main(["fit", "--stars", path, "-o", str(tmp_path / "m.fits"), "--no-plots",
                     "--interpolator", "polynomial"]) == 0
    assert "adaptive-moment sigma of the VIGNETs" in capsys.readouterr().out


def test_columns_of_the_wrong_kind(ldac, tmp_path):
    cat = Table.read(ldac, hdu="LDAC_OBJECTS")
    text = Table(cat, copy=True)
    text["X_IMAGE"] = np.array(["a"] * len(cat))
    with pytest.raises(InputError, match="'X_IMAGE' does not hold numbers"):
        read_catalog(text)
    with pytest.raises(InputError, match="no position columns.*NUMBER"):
        read_catalog(cat[["NUMBER", "VIGNET"]])
    flat = read_catalog(cat)
    flat["VIGNET"] = np.array(flat["VIGNET"]).reshape(len(flat), -1)
    with pytest.raises(InputError, match="VIGNET must hold square vignettes"):
        extract_vignettes(flat)
    with pytest.raises(InputError, match="aperture=2 .*FLUX_APER, which has 1"):
        read_catalog(Table({"x": [1.0], "y": [1.0], "FLUX_APER": [[3.0]]}), aperture=2)


def test_internal_errors_are_reported_as_bugs(monkeypatch, capsys, model, exposure,
                                              tmp_path):
    """A numpy failure that is not about the input: exit status 3, 'a bug', how to get the
    traceback; --debug (or SKLEARN_PSF_DEBUG=1) raises it."""
    import sklearn_psf.io

    def broken(*args, **kwargs):
        return np.zeros(3).reshape(2, 2)  # numpy's ValueError, not the input's

    monkeypatch.setattr(sklearn_psf.io, "read_catalog", broken)
    argv = ["predict", model, "--positions", exposure["galaxies"], "-o",
            str(tmp_path / "p.fits")]
    assert main(argv) == 3
    err = capsys.readouterr().err
    assert "internal error" in err and "bug" in err and "--debug" in err
    assert "SKLEARN_PSF_DEBUG=1" in err and "Traceback" not in err
    with pytest.raises(ValueError, match="cannot reshape"):
        main(["--debug", *argv])
    monkeypatch.setenv("SKLEARN_PSF_DEBUG", "1")
    with pytest.raises(ValueError, match="cannot reshape"):
        main(argv)
    assert not os.path.exists(tmp_path / "p.fits")


def test_validate_leaves_out_unusable_stars():
    """A crowded star of non-positive flux and a fully masked one are left out and counted;
    the other stars are compared as without them."""
    from sklearn_psf.validation import validate_models

    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0:15, 0:15] - 7.0
    psf = np.exp(-0.5 * (xx**2 + yy**2) / 2.0**2).ravel()
    psf /= psf.sum()

    class Constant:
        def predict(self, X):
            return np.tile(psf, (len(X), 1))

    X = rng.uniform(0, 500, (30, 2))
    stars = 1e4 * psf + rng.normal(0.0, 1.0, (30, 225))
    weights = np.ones_like(stars)
    clean, _ = validate_models(X[2:], stars[2:], {"m": Constant()}, weights=weights[2:])
    stars[0] = -np.abs(stars[0])
    weights[1] = 0.0
    table, _ = validate_models(X, stars, {"m": Constant()}, weights=weights)
    assert table.meta["left_out"] == {"no_pixels": 1, "non_finite": 0,
                                      "non_positive_flux": 1}
    assert table["n_measured"][0] == clean["n_measured"][0] == 28
    assert table["e_rms"][0] == clean["e_rms"][0]
    with pytest.raises(InputError, match="None of the 2 stars.*non_positive_flux 1"):
        validate_models(X[:2], stars[:2], {"m": Constant()}, weights=weights[:2])


def test_predict_refuses_stamps_beyond_memory(model, exposure, tmp_path, capsys):
    msg = _error(capsys, ["predict", model, "--positions", exposure["galaxies"], "-o",
                          str(tmp_path / "p.fits"), "--oversampling", "200000"])
    assert "--oversampling 200000" in msg and "GiB" in msg
    assert not os.path.exists(tmp_path / "p.fits")


def test_non_numeric_saturate_is_ignored_with_a_warning(ldac, tmp_path):
    from sklearn_psf.io import FITSHeaderWarning

    def text(header):
        header["SATURATE"] = "abc"

    path = _rewrite(ldac, tmp_path / "sat.ldac", lambda t: t, header_edit=text)
    with pytest.warns(FITSHeaderWarning, match="SATURATE = 'abc' is not a positive number"):
        cat = read_catalog(path)
    assert "SATURATE" not in cat.meta["image_header"]
    with pytest.raises(InputError, match="saturation must be a positive number, got 'abc'"):
        extract_vignettes(cat, saturation="abc")
