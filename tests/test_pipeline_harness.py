"""The real-pipeline harness: GalSim-rendered CCDs, Source Extractor and PSFEx runners."""

import os

import numpy as np
import pytest
from astropy.io import fits
from astropy.table import Table

galsim = pytest.importorskip("galsim")

from sklearn_psf.io import (  # noqa: E402
    ProgramError,
    ProgramNotFoundError,
    find_program,
    run_psfex,
    run_sextractor,
)
from sklearn_psf.simulate import render_galsim_ccd  # noqa: E402

needs_sex = pytest.mark.skipif(find_program("source-extractor") is None,
                               reason="Source Extractor (source-extractor or sex) not installed")
needs_psfex = pytest.mark.skipif(find_program("psfex") is None, reason="PSFEx not installed")


@pytest.fixture(scope="module")
def ccd():
    return render_galsim_ccd(shape=(1024, 1024), n_stars=200, n_galaxies=150, n_saturated=3,
                             random_state=3)


@pytest.fixture(scope="module")
def written(ccd, tmp_path_factory):
    return ccd.write(tmp_path_factory.mktemp("ccd"))


@pytest.fixture(scope="module")
def catalog(written, ccd):
    if find_program("source-extractor") is None:
        pytest.skip("Source Extractor (source-extractor or sex) not installed")
    return run_sextractor(written, written.with_name("ccd.ldac"),
                          weight_path=ccd.weight_path(written))


def _hsm(stamp):
    r = galsim.hsm.FindAdaptiveMom(galsim.Image(np.asarray(stamp, dtype=float)))
    return r.observed_shape.e1, r.observed_shape.e2, r.moments_sigma


def _isolated(ccd, radius):
    xy = np.column_stack([np.r_[ccd.stars["x"], ccd.galaxies["x"]],
                          np.r_[ccd.stars["y"], ccd.galaxies["y"]]])
    n = len(ccd.stars)
    d = np.hypot(*(xy[:n, None, :] - xy[None, :, :]).transpose(2, 0, 1))
    d[np.arange(n), np.arange(n)] = np.inf
    return d.min(axis=1) > radius


def test_rendered_stars_match_their_truth_stamps(ccd):
    """HSM on the image's bright isolated stars equals HSM on truth_stamps at the same phase."""
    side = 25
    stars = ccd.stars
    good = ((stars["snr"] > 300) & ~stars["saturated"] & _isolated(ccd, 20)
            & (stars["x"] > side) & (stars["x"] < 1023 - side)
            & (stars["y"] > side) & (stars["y"] < 1023 - side))
    bad_cols = np.flatnonzero((ccd.weight == 0).all(axis=0))
    good &= np.abs(stars["x"][:, None] - bad_cols[None, :]).min(axis=1) > side
    assert good.sum() >= 15
    x, y = np.asarray(stars["x"][good]), np.asarray(stars["y"][good])
    ix, iy = np.floor(x + 0.5).astype(int), np.floor(y + 0.5).astype(int)
    h = side // 2
    cut = [ccd.image[j - h:j + h + 1, i - h:i + h + 1] - ccd.header["SKYLEVEL"]
           for i, j in zip(ix, iy)]
    truth = ccd.truth_stamps(x, y, stamp_size=side, offsets=np.column_stack([x - ix, y - iy]))
    obs = np.array([_hsm(c) for c in cut])
    ref = np.array([_hsm(t) for t in truth])
    # noise: e error ~ 2 / snr (< 0.007 here), size ~ 1 / snr
    de = obs[:, :2] - ref[:, :2]
    assert np.sqrt(np.mean(de**2)) < 0.01
    assert np.abs(de.mean(axis=0)).max() < 0.004
    assert np.median(np.abs(obs[:, 2] / ref[:, 2] - 1)) < 0.005
    # the truth varies over the field by much more than that difference
    assert ref[:, :2].std(axis=0).max() > 2 * np.sqrt(np.mean(de**2))


def test_truth_stamps_centre_and_normalisation(ccd):
    for side in (24, 25):
        s = ccd.truth_stamps([500.0], [500.0], stamp_size=side, method="no_pixel")[0]
        assert s.sum() == pytest.approx(1.0)
        yy, xx = np.mgrid[:side, :side]
        assert (s * xx).sum() == pytest.approx(side // 2, abs=0.05)
        assert (s * yy).sum() == pytest.approx(side // 2, abs=0.05)
    with pytest.raises(ValueError, match="offsets"):
        ccd.truth_stamps([1.0, 2.0], [1.0, 2.0], offsets=[[0, 0]])


def test_saturation_masks_and_header(ccd):
    assert ccd.image.dtype == np.float32 and ccd.image.max() == 30000.0
    assert ccd.stars["saturated"].sum() >= 3
    dead = (ccd.weight == 0).all(axis=0)
    assert dead.sum() == 2 and (ccd.image[:, dead] == 0).all()
    assert ccd.header["SATURATE"] < ccd.image.max()
    sigma = np.sqrt(ccd.header["SKYLEVEL"] / ccd.header["GAIN"])
    assert np.median(ccd.weight[ccd.weight > 0]) == pytest.approx(sigma**-2, rel=1e-5)
    # the sky's noise is what the weight says (median absolute deviation of empty pixels)
    sky = ccd.image[:, ~dead] - ccd.header["SKYLEVEL"]
    assert 1.4826 * np.median(np.abs(sky)) == pytest.approx(sigma, rel=0.05)


def test_callable_psf_and_write(tmp_path):
    airy = galsim.Airy(lam_over_diam=0.08)      # undersampled at 0.11"/pixel

    ccd = render_galsim_ccd(shape=(128, 128), pixel_scale=0.11, n_stars=4, n_galaxies=2,
                            n_saturated=0, psf=lambda x, y: airy, random_state=0)
    ref = airy.drawImage(nx=15, ny=15, scale=0.11).array
    np.testing.assert_allclose(ccd.truth_stamps([64.0], [64.0], stamp_size=15)[0],
                               ref / ref.sum(), atol=1e-6)
    path = ccd.write(tmp_path)
    assert fits.getheader(path)["GAIN"] == 4.0
    np.testing.assert_array_equal(fits.getdata(ccd.weight_path(path)), ccd.weight)
    with pytest.raises(FileExistsError):
        ccd.write(tmp_path)
    with pytest.raises(ValueError, match="psf"):
        render_galsim_ccd(shape=(128, 128), psf="space")


def test_noise_seed_redraws_the_noise_alone():
    """Same random_state, another noise_seed: same sources and dead columns, the difference
    of two images is two independent noise draws (variance twice the pixels' own); no
    noise_seed: the image random_state alone gives."""
    kw = dict(shape=(160, 160), pixel_scale=0.11, n_stars=6, n_galaxies=3, n_saturated=0,
              psf=lambda x, y: galsim.Airy(lam_over_diam=0.1), random_state=4)
    a, b = render_galsim_ccd(**kw, noise_seed=1), render_galsim_ccd(**kw, noise_seed=2)
    own = render_galsim_ccd(**kw)
    np.testing.assert_array_equal(render_galsim_ccd(**kw).image, own.image)
    np.testing.assert_array_equal(render_galsim_ccd(**kw, noise_seed=1).image, a.image)
    for t in (a, own):
        np.testing.assert_array_equal(t.stars["x"], b.stars["x"])
        np.testing.assert_array_equal(t.galaxies["flux"], b.galaxies["flux"])
        np.testing.assert_array_equal(t.weight, b.weight)
    live = b.weight > 0
    diff = (a.image - b.image)[live]
    assert not np.array_equal(a.image, own.image)
    variance = 2 * (a.header["SKYLEVEL"] / a.header["GAIN"])   # the sky dominates the pixels
    assert abs(np.mean(diff)) < 5 * np.sqrt(variance / diff.size)
    assert np.var(diff) == pytest.approx(variance, rel=0.05)
    for bad in (-1, 1.5, "1", True):
        with pytest.raises(ValueError, match="noise_seed must be"):
            render_galsim_ccd(**kw, noise_seed=bad)


@needs_sex
def test_sextractor_finds_the_stars(ccd, catalog):
    cat = Table.read(catalog, hdu=2)
    assert cat["VIGNET"].shape[1:] == (35, 35) and cat["FLUX_APER"].shape[1] == 5
    x, y = cat["X_IMAGE"] - 1.0, cat["Y_IMAGE"] - 1.0
    # a star within 10 pixels (3 FWHM) of another source is blended with it, for any detector
    stars = ccd.stars[(ccd.stars["snr"] > 50) & ~ccd.stars["saturated"] & _isolated(ccd, 10)]
    assert len(stars) > 100
    d = np.hypot(stars["x"][:, None] - x[None, :], stars["y"][:, None] - y[None, :]).min(axis=1)
    assert np.mean(d < 1.0) >= 0.95
    # the header's GAIN and SATURATE reached Source Extractor: saturated stars are flagged
    sat = ccd.stars[ccd.stars["saturated"]]
    j = np.hypot(sat["x"][:, None] - x[None, :], sat["y"][:, None] - y[None, :]).argmin(axis=1)
    assert np.all(cat["FLAGS"][j] & 4)


@needs_sex
def test_sextractor_config_params_and_errors(written, tmp_path, monkeypatch):
    out = run_sextractor(written, tmp_path / "c.cat", vignet=None, catalog_type="FITS_1.0",
                         params=["X_IMAGE", "Y_IMAGE", "FLUX_APER", "FLUX_RADIUS"],
                         config={"DETECT_THRESH": 5, "PHOT_APERTURES": "5,10",
                                 "PHOT_FLUXFRAC": "0.5,0.8"})
    cat = Table.read(out, hdu=1)
    assert cat.colnames == ["X_IMAGE", "Y_IMAGE", "FLUX_APER", "FLUX_RADIUS"]
    assert cat["FLUX_APER"].shape[1] == 2 and cat["FLUX_RADIUS"].shape[1] == 2
    with pytest.raises(FileExistsError):
        run_sextractor(written, out)
    bad = tmp_path / "bad.fits"
    bad.write_text("not a FITS file")
    with pytest.raises(ProgramError, match="Source Extractor failed"):
        run_sextractor(bad, tmp_path / "bad.cat")
    monkeypatch.setenv("PATH", os.fspath(tmp_path))
    with pytest.raises(ProgramNotFoundError, match="not installed"):
        run_sextractor(written, tmp_path / "x.cat")


@needs_psfex
def test_psfex_runs_on_the_catalogue(ccd, catalog, tmp_path):
    from sklearn_psf.validation import PSFExModel

    psf = run_psfex(catalog, tmp_path, config={"NTHREADS": 1, "PSF_SIZE": "25,25",
                                               "PSFVAR_KEYS": "XWIN_IMAGE,YWIN_IMAGE"})
    h = fits.getheader(psf, "PSF_DATA")
    assert h["ACCEPTED"] >= 50 and h["POLNAME1"] == "XWIN_IMAGE"
    # PSFEx's model is close to the truth (shapes at 20 positions, GalSim HSM)
    rng = np.random.default_rng(0)
    xy = rng.uniform(100, 900, (20, 2))
    model = PSFExModel(psf, stamp_size=25).predict(xy).reshape(-1, 25, 25)
    truth = ccd.truth_stamps(xy[:, 0], xy[:, 1], stamp_size=25)
    got = np.array([_hsm(s) for s in model])
    ref = np.array([_hsm(s) for s in truth])
    assert np.sqrt(np.mean((got[:, :2] - ref[:, :2]) ** 2)) < 0.03
    assert np.median(np.abs(got[:, 2] / ref[:, 2] - 1)) < 0.05
    with pytest.raises(FileExistsError):
        run_psfex(catalog, tmp_path)
