"""Writing a fitted model as a PSFEx ``.psf`` file: read back by GalSim and Source Extractor."""

import numpy as np
import pytest
from astropy.io import fits
from astropy.table import Table

galsim = pytest.importorskip("galsim")
import galsim.des  # noqa: E402

from sklearn_psf import make_psf_field  # noqa: E402
from sklearn_psf.io import find_program, read_catalog, run_sextractor
from sklearn_psf.exposure import extract_vignettes, select_stars
from sklearn_psf.model import PSFModel, make_interpolator  # noqa: E402
from sklearn_psf.validation import PSFExModel, psfex_terms, to_psfex, write_psfex  # noqa: E402



@pytest.fixture(scope="module")
def fitted():
    shape = (1500, 1500)
    f = make_psf_field(n_stars=250, n_galaxies=0, image_shape=shape, snr=200.0,
                       random_state=0)
    stamps, weights, flags = f.star_stamps(return_weights=True)
    X = np.column_stack([f.stars["x"], f.stars["y"]])[flags == 0]
    return PSFModel().fit(X, stamps[flags == 0], weights=weights[flags == 0]), shape


def _hsm(stamps):
    out = []
    for s in stamps:
        r = galsim.hsm.FindAdaptiveMom(galsim.Image(np.asarray(s, dtype=float)))
        out.append((r.observed_shape.e1, r.observed_shape.e2, r.moments_sigma,
                    r.moments_centroid.x, r.moments_centroid.y))
    return np.array(out)


def test_galsim_draws_the_written_model(fitted, tmp_path):
    """DES_PSFEx at 100 positions equals the full model to the approximation error written."""
    model, shape = fitted
    out = to_psfex(model, tmp_path / "ccd.psf", image_shape=shape)
    h = fits.getheader(out.path, "PSF_DATA")
    assert h["POLDEG1"] == out.degree and h["APXPIX"] == pytest.approx(out.pixel_rms)
    assert h["POLNAME1"] == "XWIN_IMAGE" and h["LOADED"] == len(model.X_fit_)
    assert h["ACCEPTED"] == model.inlier_mask_.sum() and h["PSF_SAMP"] == 1.0
    assert h["APXCV"] == pytest.approx(out.cv_error[out.degree])
    assert h["APXMODEL"] == pytest.approx(out.model_error)
    # the smallest degree within half the model's own uncertainty, else (this field's
    # small-scale variations: none up to 8) the smallest within 5% of the best
    within = out.cv_error <= 0.5 * out.model_error
    if not within.any():
        within = out.cv_error <= 1.05 * out.cv_error.min()
    assert 0 <= out.degree <= 8 and within[out.degree] and not within[:out.degree].any()

    s = model.stamp_size_
    psfex = galsim.des.DES_PSFEx(str(out.path))
    X = np.random.default_rng(1).uniform(0, shape[1] - 1, (100, 2))
    got = np.array([psfex.getPSF(galsim.PositionD(x + 1.0, y + 1.0))
                    .drawImage(nx=s, ny=s, scale=1.0, method="no_pixel").array for x, y in X])
    full = model.predict(X).reshape(-1, s, s)
    peak = full.max(axis=(1, 2)).mean()
    assert np.sqrt(np.mean((got - full) ** 2)) / peak < 1.5 * out.pixel_rms + 1e-5
    a, b = _hsm(got), _hsm(full)
    assert np.sqrt(np.mean(np.sum((a[:, :2] - b[:, :2]) ** 2, axis=1))) < 1.5 * out.e_rms + 1e-4
    assert np.sqrt(np.mean((a[:, 2] - b[:, 2]) ** 2)) < 1.5 * out.size_rms + 1e-4
    # both centred on the same pixel (PSFEx's n // 2), to a hundredth of a pixel
    np.testing.assert_allclose(a[:, 3:], b[:, 3:], atol=0.01)
    # a constant model (degree 0) is worse than the chosen degree, by the same measure
    assert out.degree == 0 or out.cv_error[0] > out.cv_error[out.degree]


def _gaussian_stars(X, strength):
    """Unit-sum elliptical Gaussians whose size and e1 vary quadratically over a 1000-pixel
    field (``strength`` 0: a constant PSF)."""
    yy, xx = np.mgrid[0:15, 0:15] - 7.0
    u, v = (X[:, 0] - 500) / 500, (X[:, 1] - 500) / 500
    sig = 1.8 + strength * 0.5 * (u**2 + v**2 - 2 / 3)
    e1 = strength * 0.08 * u * v
    sx, sy = (sig * (1 + e1))[:, None, None], (sig * (1 - e1))[:, None, None]
    p = np.exp(-0.5 * (xx**2 / sx**2 + yy**2 / sy**2))
    return (p / p.sum(axis=(1, 2), keepdims=True)).reshape(len(X), -1)


# a constant PSF: the Kriging finds no spatial correlation and says so
@pytest.mark.filterwarnings("ignore::sklearn_psf.interpolate.ShortRangeWarning")
@pytest.mark.parametrize("strength", [0.0, 1.0])
def test_degree_follows_the_model_uncertainty(strength, tmp_path):
    """A constant PSF is written with degree 0 or 1, a strong quadratic variation with 2 or
    more; the model's uncertainty that sets it is that of the model against the truth (within
    a factor 2.5), and the written PSF is as close to the truth as the full model (1.2x)."""
    rng = np.random.default_rng(0)
    X = rng.uniform(0, 1000, (150, 2))
    stamps = 5e4 * _gaussian_stars(X, strength) + rng.normal(0.0, 10.0, (150, 225))
    model = PSFModel().fit(X, stamps, weights=np.full(stamps.shape, 0.01))
    out = to_psfex(model, tmp_path / "ccd.psf", image_shape=(1000, 1000))
    assert (out.degree <= 1) if strength == 0 else (out.degree >= 2)
    Q = rng.uniform(0, 1000, (300, 2))
    truth = _gaussian_stars(Q, strength)
    peak = truth.max(axis=1).mean()
    full = np.sqrt(np.mean((model.predict(Q) - truth) ** 2)) / peak
    written = np.sqrt(np.mean((PSFExModel(out.path, 15).predict(Q) - truth) ** 2)) / peak
    assert full / 2.5 < out.model_error < 2.5 * full    # measured 1.8x (constant), 0.7x
    assert written < 1.2 * full                           # measured 1.00x, 0.99x


def test_even_stamps_padded_to_psfex_centre(tmp_path):
    rng = np.random.default_rng(0)
    X = rng.uniform(0, 500, (60, 2))
    yy, xx = np.mgrid[0:16, 0:16] - 8.0          # centre at pixel 8 = 16 // 2
    sig = (1.6 + X[:, 0] / 1000.0)[:, None, None]
    stars = 4e4 * np.exp(-0.5 * (xx**2 + yy**2) / sig**2) / (2 * np.pi * sig**2)
    stamps = (stars + rng.normal(0.0, 5.0, stars.shape)).reshape(60, -1)
    model = PSFModel().fit(X, stamps, weights=np.full(stamps.shape, 1 / 25.0))
    out = to_psfex(model, tmp_path / "even.psf", extent=(0, 500, 0, 500), max_degree=2,
                   grid_size=12, chi2=1.02)
    h = fits.getheader(out.path, "PSF_DATA")
    assert (h["PSFAXIS1"], h["PSFAXIS2"]) == (17, 17) and h["CHI2"] == pytest.approx(1.02)
    img = galsim.des.DES_PSFEx(str(out.path)).getPSF(galsim.PositionD(251.0, 251.0)) \
        .drawImage(nx=17, ny=17, scale=1.0, method="no_pixel").array
    pred = model.predict([[250.0, 250.0]]).reshape(16, 16)
    np.testing.assert_allclose(img[:16, :16], pred, atol=2e-3 * pred.max())
    # an interpolator without a predicted standard deviation: the degree within 5% of the best
    poly = PSFModel(interpolator=make_interpolator("polynomial")).fit(
        X, stamps, weights=np.full(stamps.shape, 1 / 25.0))
    alt = to_psfex(poly, tmp_path / "poly.psf", extent=(0, 500, 0, 500), max_degree=2,
                   grid_size=12)
    assert alt.model_error is None and "APXMODEL" not in fits.getheader(alt.path, 1)
    assert alt.degree == np.flatnonzero(alt.cv_error <= 1.05 * alt.cv_error.min())[0]
    with pytest.raises(FileExistsError):
        to_psfex(model, out.path, extent=(0, 500, 0, 500))
    with pytest.raises(ValueError, match="extent"):
        to_psfex(model, tmp_path / "x.psf", extent=(0, 0, 0, 500))
    with pytest.raises(ValueError, match="max_degree"):
        to_psfex(model, tmp_path / "x.psf", max_degree=11)
    with pytest.raises(ValueError, match="accuracy"):
        to_psfex(model, tmp_path / "x.psf", accuracy=0)
    with pytest.raises(ValueError, match="fitted PSF model"):
        to_psfex(PSFModel(), tmp_path / "x.psf")


def test_real_psfex_file_round_trip(tmp_path, realdata):
    """PSFEx 3.17's own file, read with GalSim and written back by write_psfex: same file."""
    REAL = str(realdata("DECam_00241238_01_psfcat.psf"))
    hdu = fits.open(REAL)[1]
    ref = galsim.des.DES_PSFEx(REAL)
    h = hdu.header
    path = tmp_path / "back.psf"
    write_psfex(path, ref.basis, (ref.x_zero, ref.y_zero), (ref.x_scale, ref.y_scale),
                psf_samp=ref.sample_scale, names=(h["POLNAME1"], h["POLNAME2"]),
                header={k: h[k] for k in ("LOADED", "ACCEPTED", "CHI2", "PSF_FWHM")})
    back = fits.open(path)[1]
    keys = [k for k in h if k not in ("XTENSION", "BITPIX", "NAXIS", "NAXIS1", "NAXIS2",
                                      "PCOUNT", "GCOUNT", "TFIELDS", "TTYPE1", "TFORM1",
                                      "TDIM1", "EXTNAME")]
    assert [k for k in back.header if k in keys] == keys  # PSFEx's keys, in its order
    for k in keys:
        assert back.header[k] == pytest.approx(h[k], rel=1e-6) if isinstance(h[k], float) \
            else back.header[k] == h[k]
    np.testing.assert_array_equal(back.data["PSF_MASK"], hdu.data["PSF_MASK"])
    # our terms are GalSim's: the PSF at a position is terms @ PSF_MASK
    pos = [(100.0, 3000.0), (1800.0, 400.0)]
    planes = ref.basis.reshape(len(ref.basis), -1)
    for (x, y) in pos:
        mine = psfex_terms([[x, y]], ref.fit_order, (ref.x_zero, ref.y_zero),
                           (ref.x_scale, ref.y_scale)) @ planes
        np.testing.assert_allclose(mine.reshape(ref.basis.shape[1:]),
                                   ref.getPSFArray(galsim.PositionD(x, y)), rtol=1e-5,
                                   atol=1e-7)
    a = PSFExModel(REAL, stamp_size=31).predict(pos)
    b = PSFExModel(path, stamp_size=31).predict(pos)
    np.testing.assert_allclose(a, b, atol=1e-7)


@pytest.fixture(scope="module")
def sextracted(tmp_path_factory):
    if find_program("source-extractor") is None:
        pytest.skip("Source Extractor (source-extractor or sex) not installed")
    from sklearn_psf.simulate import render_galsim_ccd

    ccd = render_galsim_ccd(shape=(768, 768), n_stars=140, n_galaxies=160, n_saturated=1,
                            random_state=5)
    image = ccd.write(tmp_path_factory.mktemp("sm"))
    cat = run_sextractor(image, image.with_name("ccd.ldac"), weight_path=ccd.weight_path(image))
    return ccd, image, cat


def test_source_extractor_uses_the_written_model(sextracted):
    """SPREAD_MODEL with our .psf as PSF_NAME: finite, ~0 for stars, positive for galaxies."""
    ccd, image, cat = sextracted
    stars = read_catalog(cat)
    keep, _ = select_stars(stars, saturation=ccd.header["SATURATE"])
    cut = extract_vignettes(stars[keep], 25)
    n = len(cut.stamps)
    model = PSFModel().fit(cut.positions, cut.stamps.reshape(n, -1),
                           weights=cut.weights.reshape(n, -1))
    out = to_psfex(model, image.with_name("ours.psf"), image_shape=ccd.image.shape)
    params = ["X_IMAGE", "Y_IMAGE", "XWIN_IMAGE", "YWIN_IMAGE", "FLAGS", "SPREAD_MODEL",
              "SPREADERR_MODEL"]
    sm_cat = run_sextractor(image, image.with_name("sm.cat"), weight_path=ccd.weight_path(image),
                            params=params, config={"PSF_NAME": out.path})
    t = Table.read(sm_cat, hdu=2)
    assert np.isfinite(t["SPREAD_MODEL"]).all() and np.isfinite(t["SPREADERR_MODEL"]).all()
    x, y = t["X_IMAGE"] - 1.0, t["Y_IMAGE"] - 1.0

    def matched(truth):
        d = np.hypot(truth["x"][:, None] - x[None, :], truth["y"][:, None] - y[None, :])
        return np.asarray(t["SPREAD_MODEL"])[d.argmin(axis=1)[d.min(axis=1) < 1.0]]

    sm_stars = matched(ccd.stars[~ccd.stars["saturated"] & (ccd.stars["snr"] > 30)])
    sm_gal = matched(ccd.galaxies)
    assert len(sm_stars) > 80 and len(sm_gal) > 60
    # SPREAD_MODEL's usual star/galaxy cut is 0.003 (e.g. DES); the stars sit at 0
    assert np.median(np.abs(sm_stars)) < 0.001
    assert np.mean(np.abs(sm_stars) < 0.003) > 0.95
    assert np.median(sm_gal) > 0.003 and np.mean(sm_gal > 0.003) > 0.7


def test_cli_fit_writes_psfex(tmp_path, capsys):
    from sklearn_psf.cli import main
    from sklearn_psf.simulate import write_example_ldac

    files = write_example_ldac(tmp_path, n_stars=100, n_galaxies=30, image_shape=(1000, 1000))
    psf = tmp_path / "ccd.psf"
    args = ["fit", "--stars", files["catalog"], "-o", tmp_path / "m.fits", "--no-plots",
            "--psfex", psf]
    assert main([str(a) for a in args]) == 0
    out = capsys.readouterr().out
    h = fits.getheader(psf, "PSF_DATA")
    assert f"PSFEx file: polynomial of degree {h['POLDEG1']} " in out
    assert f"pixel rms {h['APXPIX']:.2e}" in out
    assert f"error on a grid {h['APXCV']:.2e} of the peak" in out
    assert (h["PSFAXIS1"], h["POLNAME1"]) == (25, "XWIN_IMAGE")
    # no overwrite without --overwrite: the command stops before fitting
    code = main([str(a) for a in ["fit", "--stars", files["catalog"], "-o", tmp_path / "n.fits",
                                  "--no-plots", "--psfex", psf]])
    assert code == 2 and "already exists" in capsys.readouterr().err
    assert not (tmp_path / "n.fits").exists()
    other = tmp_path / "other.ldac"
    other.write_bytes(open(files["catalog"], "rb").read())
    code = main([str(a) for a in ["fit", "--stars", files["catalog"], other, "-o",
                                  tmp_path / "two.fits", "--no-plots", "--psfex",
                                  tmp_path / "two.psf"]])
    assert code == 2 and "one .psf file" in capsys.readouterr().err
