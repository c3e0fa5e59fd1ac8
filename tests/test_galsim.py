"""The PSF handed to shape-measurement codes: GalSim objects and stamp files."""

import sys

import numpy as np
import pytest
from astropy.io import fits
from astropy.wcs import WCS
from numpy.testing import assert_allclose

from sklearn_psf.io import draw_psf, read_psf_stamps, write_psf_stamps
from sklearn_psf.measure import adaptive_moments
from sklearn_psf.model import PSFModel, to_galsim
from sklearn_psf.simulate import make_psf_field

galsim = pytest.importorskip("galsim")  # in the test extra


@pytest.fixture(scope="module")
def model():
    field = make_psf_field(n_stars=100, n_galaxies=0, image_shape=(1000, 1000), snr=200.0,
                           random_state=2)
    stamps, weights, _ = field.star_stamps(return_weights=True)
    X = np.column_stack([field.stars["x"], field.stars["y"]])
    return PSFModel().fit(X, stamps, weights=weights)


class Analytic:
    """A GalSim profile as a model: its pixel-integrated image, the same everywhere."""

    def __init__(self, profile, s=25):
        self.profile = profile
        image = profile.drawImage(nx=s, ny=s, scale=1.0, dtype=float).array.ravel()
        self.stamp = image / image.sum()

    def predict(self, X):
        return np.tile(self.stamp, (len(X), 1))


def test_drawn_psf_equals_predict_and_hsm_equals_adaptive_moments(model):
    rng = np.random.default_rng(0)
    X = rng.uniform(0, 1000, (100, 2))
    pred = model.predict(X)
    s = model.stamp_size_
    drawn = np.array([model.to_galsim(x, y).drawImage(nx=s, ny=s, scale=1.0, dtype=float,
                                                      method="no_pixel").array.ravel()
                      for x, y in X])
    diff = np.abs(drawn - pred).max(axis=1) / pred.max(axis=1)
    assert diff.max() < 1e-6  # measured 4e-16 (the interpolant goes through the samples)
    hsm = [galsim.hsm.FindAdaptiveMom(galsim.Image(d.reshape(s, s), scale=1.0)) for d in drawn]
    ours = adaptive_moments(pred)
    assert_allclose([h.observed_shape.e1 for h in hsm], ours["e1"], atol=1e-6, rtol=0)
    assert_allclose([h.observed_shape.e2 for h in hsm], ours["e2"], atol=1e-6, rtol=0)
    assert_allclose([h.moments_sigma for h in hsm], ours["sigma"], atol=1e-6, rtol=0)


def test_psf_lands_at_the_subpixel_position():
    truth = galsim.Gaussian(sigma=1.8).shear(g1=0.05, g2=-0.02)
    x, y = 120.3, 48.7  # 0-based pixel position
    psf = to_galsim(Analytic(truth), x, y)
    cx, cy = int(np.floor(x + 0.5)) + 1, int(np.floor(y + 0.5)) + 1  # GalSim: 1-based
    bounds = galsim.BoundsI(cx - 12, cx + 12, cy - 12, cy + 12)
    centre = galsim.PositionD(x + 1, y + 1)
    image = psf.drawImage(image=galsim.ImageD(bounds, scale=1.0), center=centre,
                          method="no_pixel")
    moments = galsim.hsm.FindAdaptiveMom(image)
    assert abs(moments.moments_centroid.x - centre.x) < 0.01  # measured 0.0017
    assert abs(moments.moments_centroid.y - centre.y) < 0.01  # measured 0.0024
    exact = truth.drawImage(image=galsim.ImageD(bounds, scale=1.0), center=centre)
    assert np.abs(image.array - exact.array).max() < 0.01 * exact.array.max()  # 0.0034
    # the package's own sub-pixel drawing (a cubic spline) agrees
    assert np.abs(image.array - draw_psf(Analytic(truth), [[x, y]])[0]).max() \
        < 0.01 * exact.array.max()  # measured 0.0022


@pytest.mark.parametrize("x, y", [(120.3, 48.7), (10.0, 20.0), (5.49, 7.51)])
def test_oversampled_centred_stamps_equal_galsims_drawing(x, y):
    # draw_psf's oversampled, sub-pixel-placed stamps against GalSim drawing the same PSF
    model = Analytic(galsim.Gaussian(sigma=1.8).shear(g1=0.05, g2=-0.02))
    ours = draw_psf(model, [[x, y]], centered=True, oversampling=3)[0]
    dx, dy = x - np.floor(x + 0.5), y - np.floor(y + 0.5)
    theirs = to_galsim(model, x, y).drawImage(nx=75, ny=75, scale=1 / 3, method="no_pixel",
                                              offset=(3 * dx, 3 * dy), dtype=float).array
    theirs /= theirs.sum()
    assert np.abs(ours - theirs).max() < 0.01 * theirs.max()  # measured 0.0022
    centroid = galsim.hsm.FindAdaptiveMom(galsim.Image(ours, scale=1 / 3)).moments_centroid
    assert_allclose([centroid.x - 38, centroid.y - 38], [3 * dx, 3 * dy], atol=0.01)


def test_galaxy_convolved_with_the_psf_equals_galsims_own_convolution():
    truth = galsim.Moffat(beta=3.0, fwhm=3.5).shear(g1=-0.03, g2=0.04)
    psf = to_galsim(Analytic(truth, s=35), 500.0, 500.0)
    galaxy = galsim.Exponential(half_light_radius=2.0).shear(g1=0.2, g2=0.1)
    ours = galsim.Convolve(galaxy, psf).drawImage(nx=49, ny=49, scale=1.0, method="no_pixel")
    exact = galsim.Convolve(galaxy, truth).drawImage(nx=49, ny=49, scale=1.0)  # + pixel
    assert np.abs(ours.array - exact.array).max() < 2e-3 * exact.array.max()  # 8.5e-4
    # HSM's PSF correction with our PSF image recovers the same shape as with the truth
    psf_image = psf.drawImage(nx=35, ny=35, scale=1.0, method="no_pixel")
    true_psf_image = truth.drawImage(nx=35, ny=35, scale=1.0)
    a = galsim.hsm.EstimateShear(ours, psf_image)
    b = galsim.hsm.EstimateShear(exact, true_psf_image)
    assert abs(a.corrected_e1 - b.corrected_e1) < 1e-3  # measured 4.5e-4 (e1 = 0.375)
    assert abs(a.corrected_e2 - b.corrected_e2) < 1e-3  # measured 1.3e-4


def test_world_coordinates():
    model = Analytic(galsim.Gaussian(sigma=1.6).shear(g1=0.1))
    # a pixel scale: drawn on the same pixels, the same stamp
    psf = to_galsim(model, 10.0, 20.0, wcs=0.2)
    drawn = psf.drawImage(nx=25, ny=25, scale=0.2, method="no_pixel", dtype=float).array
    assert_allclose(drawn.ravel(), model.stamp, atol=1e-12)
    assert psf.calculateMomentRadius() == pytest.approx(
        0.2 * to_galsim(model, 10.0, 20.0).calculateMomentRadius(), rel=1e-4)  # 9e-6
    # an astropy TAN WCS: its local Jacobian at the position (RA increasing to the east)
    w = WCS(naxis=2)
    w.wcs.ctype = ["RA---TAN", "DEC--TAN"]
    w.wcs.crval = [150.0, 2.0]
    w.wcs.crpix = [1000.0, 1000.0]
    w.wcs.cd = np.array([[-0.202, 0.01], [0.02, 0.2]]) / 3600.0
    local = to_galsim(model, 998.0, 999.0, wcs=w).image.wcs
    expected = galsim.JacobianWCS(0.202, -0.01, 0.02, 0.2)
    assert_allclose([local.dudx, local.dudy, local.dvdx, local.dvdy],
                    [expected.dudx, expected.dudy, expected.dvdx, expected.dvdy], rtol=1e-5)
    # a GalSim WCS, and drawing with that local WCS gives the stamp back
    jac = galsim.JacobianWCS(0.2, 0.01, -0.02, 0.21)
    psf = to_galsim(model, 5.0, 6.0, wcs=jac)
    drawn = psf.drawImage(nx=25, ny=25, wcs=jac, method="no_pixel", dtype=float).array
    assert_allclose(drawn.ravel(), model.stamp, atol=1e-12)


def test_to_galsim_bad_input(monkeypatch):
    model = Analytic(galsim.Gaussian(sigma=1.6))
    with pytest.raises(TypeError, match="pixel scale"):
        to_galsim(model, 1.0, 2.0, wcs="0.2")
    with pytest.raises(ValueError, match="> 0"):
        to_galsim(model, 1.0, 2.0, wcs=-0.2)
    with pytest.raises(ValueError, match="finite"):
        to_galsim(model, np.nan, 2.0)
    monkeypatch.setitem(sys.modules, "galsim", None)
    with pytest.raises(ImportError, match=r"pip install 'sklearn-psf\[galsim\]'"):
        to_galsim(model, 1.0, 2.0)


# ----------------------------------------------------------------- stamps for a catalogue
@pytest.mark.parametrize("name", ["psfs.fits", "psfs.npz"])
def test_psf_stamps_file_round_trip(model, tmp_path, name):
    rng = np.random.default_rng(1)
    X = rng.uniform(0, 1000, (30, 2))
    X[0] = [5000.0, 5000.0]  # far outside the stars: flagged
    path = tmp_path / name
    write_psf_stamps(path, model, X, oversampling=3, centered=True, ids=np.arange(100, 130))
    psf, positions = read_psf_stamps(path)
    assert_allclose(psf, draw_psf(model, X, centered=True, oversampling=3), rtol=0,
                    atol=1e-15)
    assert psf.shape == (30, 75, 75)
    assert_allclose(positions["x"], X[:, 0])
    assert list(positions["id"][:2]) == [100, 101]
    assert positions["extrapolated"][0] and not positions["extrapolated"][1:].all()
    assert positions.meta == {"oversampling": 3, "centered": True}
    if name.endswith(".fits"):  # one call for the cube, one for the positions
        assert fits.getdata(path, "PSF").shape == (30, 75, 75)
        assert fits.getheader(path, "PSF")["PIXSCALE"] == pytest.approx(1 / 3)
    else:
        assert np.load(path)["psf"].shape == (30, 75, 75)
    with pytest.raises(FileExistsError, match="overwrite=True"):
        write_psf_stamps(path, model, X)
    write_psf_stamps(path, model, X[:2], overwrite=True)
    assert read_psf_stamps(path)[0].shape == (2, 25, 25)


def test_psf_stamps_bad_input(model, tmp_path):
    with pytest.raises(ValueError, match=r"\.fits .* or \.npz"):
        write_psf_stamps(tmp_path / "psfs.h5", model, [[1.0, 2.0]])
    with pytest.raises(ValueError, match="ids must have one entry per position"):
        write_psf_stamps(tmp_path / "psfs.fits", model, [[1.0, 2.0]], ids=[1, 2])
    fits.PrimaryHDU(np.zeros(3)).writeto(tmp_path / "other.fits")
    with pytest.raises(ValueError, match="not written by write_psf_stamps"):
        read_psf_stamps(tmp_path / "other.fits")
