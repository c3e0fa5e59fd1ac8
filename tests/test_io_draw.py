"""Sub-pixel and oversampled PSFs (draw_psf) against GalSim, and the extrapolation rule."""

import galsim
import numpy as np
import pytest
from numpy.testing import assert_allclose

from sklearn_psf.interpolate import ShortRangeWarning
from sklearn_psf.io import draw_psf, extrapolation_flags
from sklearn_psf.measure import adaptive_moments
from sklearn_psf.model import PSFModel

S, SIGMA = 25, 1.8
PSF = galsim.Gaussian(sigma=SIGMA).shear(e1=0.06, e2=-0.03)


def _galsim(offset=(0.0, 0.0), scale=1.0, size=S):
    """GalSim's pixel-integrated PSF on a size x size grid of pixel ``scale``, at ``offset``."""
    img = PSF.drawImage(nx=size, ny=size, scale=scale, offset=offset, method="auto")
    return img.array / img.array.sum()


@pytest.fixture(scope="module")
def model():
    """A PSFModel fitted on centred GalSim stars at 60 positions (constant PSF)."""
    rng = np.random.default_rng(0)
    X = rng.uniform(0, 2000, (60, 2))
    stamps = np.tile(_galsim().ravel() * 1e4, (60, 1)) + rng.normal(0, 1e-3, (60, S * S))
    with pytest.warns(ShortRangeWarning):  # a constant PSF: no spatial correlation to find
        return PSFModel().fit(X, stamps)


@pytest.mark.parametrize("x, y", [(1000.3, 500.8), (811.0, 1200.45), (250.6, 1499.5)])
def test_centered_psf_matches_galsim_offset(model, x, y):
    psf = draw_psf(model, [[x, y]], centered=True)[0]
    offset = (x - np.floor(x + 0.5), y - np.floor(y + 0.5))
    ref = _galsim(offset)
    assert np.abs(psf - ref).max() < 0.005 * ref.max()   # measured 0.10-0.17%
    mom = adaptive_moments(psf[None])
    assert_allclose([mom["x0"][0] - S // 2, mom["y0"][0] - S // 2], offset, atol=0.01)
    # the uncentred PSF is the model's own stamp, on the centre pixel
    plain = draw_psf(model, [[x, y]], centered=False)[0]
    assert_allclose(plain.ravel(), model.predict([[x, y]])[0], rtol=1e-12)


def test_oversampled_psf_shape_and_size(model):
    psf = draw_psf(model, [[1000.2, 700.0]], centered=True, oversampling=3)[0]
    assert psf.shape == (3 * S, 3 * S) and np.isclose(psf.sum(), 1.0)
    mom = adaptive_moments(psf[None])
    ref = adaptive_moments(_galsim((0.2, 0.0))[None])
    # one image pixel = 3 samples: the same size, ellipticity and sub-pixel centroid
    assert_allclose(mom["sigma"][0] / 3, ref["sigma"][0], rtol=0.01)
    assert_allclose([mom["e1"][0], mom["e2"][0]], [ref["e1"][0], ref["e2"][0]], atol=0.005)
    assert_allclose((mom["x0"][0] - (3 * S - 1) / 2) / 3, 0.2, atol=0.01)


def test_draw_psf_bad_input(model):
    with pytest.raises(ValueError, match="oversampling must be a positive integer"):
        draw_psf(model, [[1.0, 2.0]], oversampling=0)
    with pytest.raises(ValueError, match=r"NaN or infinite values \(first at row 1\)"):
        draw_psf(model, [[1.0, 2.0], [np.nan, 3.0]])
    with pytest.raises(ValueError, match=r"shape \(n, 2\)"):
        draw_psf(model, [1.0, 2.0])


def test_extrapolation_flags_rule():
    rng = np.random.default_rng(1)
    stars = rng.uniform(0, 1000, (200, 2))
    stars = stars[np.hypot(*(stars - 500).T) > 150]       # a hole in the middle
    queries = np.array([[500.0, 500.0],                   # inside the hull, in the hole
                        [1100.0, 500.0],                  # outside the hull
                        [300.0, 300.0]])                  # among stars
    flags = extrapolation_flags(stars, queries)
    assert flags.tolist() == [True, True, False]
    # independent check of the hull part: scipy's ConvexHull inequalities
    from scipy.spatial import ConvexHull

    hull = ConvexHull(stars)
    grid = rng.uniform(-200, 1200, (500, 2))
    outside = (grid @ hull.equations[:, :2].T + hull.equations[:, 2] > 1e-9).any(axis=1)
    assert (extrapolation_flags(stars, grid, max_distance=np.inf) == outside).all()
