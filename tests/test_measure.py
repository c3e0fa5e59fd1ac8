"""Tests of sklearn_psf.measure.adaptive_moments against GalSim HSM and analytic Gaussians."""

import galsim
import numpy as np
import pytest

from sklearn_psf.measure import (
    FLAG_BAD_PIXELS,
    FLAG_NO_FLUX,
    adaptive_moments,
)
from sklearn_psf.measure import _moments

SIZE = 33

BACKENDS = ["numpy"] + (["numba"] if _moments._iterate_numba is not None else [])


@pytest.fixture(params=BACKENDS, autouse=True)
def backend(request, monkeypatch):
    """Every test runs on the numpy path and, when numba is installed, the compiled one."""
    monkeypatch.setattr(_moments, "_USE_NUMBA", request.param == "numba")
    return request.param


def _profiles():
    return {
        "gaussian": galsim.Gaussian(sigma=2.0).shear(e1=0.12, e2=-0.07),
        "moffat": galsim.Moffat(beta=3.0, fwhm=3.2).shear(g1=-0.05, g2=0.08),
        "kolmogorov": galsim.Kolmogorov(fwhm=2.8).shear(g1=0.04, g2=0.03),
        "round_small": galsim.Kolmogorov(fwhm=2.0),
    }


def _draw(prof, offset=(0.0, 0.0), size=SIZE):
    return prof.shift(*offset).drawImage(nx=size, ny=size, scale=1.0).array.astype(np.float64)


def _hsm(stamp):
    res = galsim.hsm.FindAdaptiveMom(galsim.Image(stamp, scale=1.0))
    return np.array([
        res.observed_shape.e1,
        res.observed_shape.e2,
        res.moments_sigma,
        res.moments_centroid.x - 1.0,
        res.moments_centroid.y - 1.0,
    ])


@pytest.fixture(scope="module")
def stamps():
    rng = np.random.default_rng(42)
    clean = []
    for prof in _profiles().values():
        for offset in [(0.0, 0.0), (0.37, -0.21), (-1.2, 0.8)]:
            clean.append(_draw(prof, offset))
    clean = np.array(clean)
    peak = clean.max(axis=(1, 2), keepdims=True)
    noisy = clean + rng.normal(0.0, 1.0, clean.shape) * peak / 200.0  # peak S/N 200
    return np.concatenate([clean, noisy])


def test_agrees_with_galsim_hsm(stamps):
    table = adaptive_moments(stamps)
    assert np.all(table["flag"] == 0)
    ref = np.array([_hsm(st) for st in stamps])
    ours = np.column_stack([table[c] for c in ("e1", "e2", "sigma", "x0", "y0")])
    np.testing.assert_allclose(ours[:, :2], ref[:, :2], rtol=0, atol=1e-6)
    np.testing.assert_allclose(ours[:, 2], ref[:, 2], rtol=1e-5)  # GalSim stores float32
    np.testing.assert_allclose(ours[:, 3:], ref[:, 3:], rtol=0, atol=1e-5)


def test_flat_and_cube_inputs_agree_and_input_untouched(stamps):
    before = stamps.copy()
    t_cube = adaptive_moments(stamps)
    t_flat = adaptive_moments(stamps.reshape(len(stamps), -1))
    np.testing.assert_array_equal(stamps, before)
    for col in ("e1", "e2", "sigma", "x0", "y0"):
        np.testing.assert_array_equal(t_cube[col], t_flat[col])


def test_matches_analytic_gaussian_covariance():
    # A finely sampled (not pixel-integrated) elliptical Gaussian: the adaptive covariance is
    # its covariance, e = (Mxx - Myy + 2i Mxy) / (Mxx + Myy) exactly (x along columns).
    cov = np.array([[6.0, 1.5], [1.5, 4.0]])
    icov = np.linalg.inv(cov)
    y, x = np.mgrid[0:41, 0:41].astype(float)
    x -= 20.3
    y -= 19.6
    img = np.exp(-0.5 * (icov[0, 0] * x**2 + 2 * icov[0, 1] * x * y + icov[1, 1] * y**2))
    t = adaptive_moments(img[None])
    assert t["flag"][0] == 0
    assert abs(t["e1"][0] - 2.0 / 10.0) < 1e-6
    assert abs(t["e2"][0] - 3.0 / 10.0) < 1e-6
    assert abs(t["sigma"][0] - np.linalg.det(cov) ** 0.25) < 1e-6
    assert abs(t["x0"][0] - 20.3) < 1e-6 and abs(t["y0"][0] - 19.6) < 1e-6
    # amplitude = total flux of the best-fitting Gaussian
    assert abs(t["amplitude"][0] - img.sum()) < 1e-6 * img.sum()


def test_bad_stamps_are_flagged_not_raised():
    rng = np.random.default_rng(0)
    good = _draw(_profiles()["moffat"])
    zero = np.zeros_like(good)
    nan = good.copy()
    nan[3, 4] = np.nan
    noise = rng.normal(0.0, 1.0, (20,) + good.shape)
    batch = np.concatenate([good[None], zero[None], nan[None], noise])
    t = adaptive_moments(batch)
    assert t["flag"][0] == 0
    assert t["flag"][1] & FLAG_NO_FLUX
    assert t["flag"][2] & FLAG_BAD_PIXELS
    # Flagged rows carry NaN, never numbers that look valid.
    bad = np.asarray(t["flag"]) != 0
    assert np.all(np.isnan(np.asarray(t["e1"])[bad]))
    assert np.all(np.isnan(np.asarray(t["sigma"])[bad]))
    # Pure noise: flagged exactly where GalSim's HSM fails; where both converge they agree.
    ref_fail, ref_e1 = [], []
    for st in noise:
        res = galsim.hsm.FindAdaptiveMom(galsim.Image(st, scale=1.0), strict=False)
        ref_fail.append(bool(res.error_message))
        ref_e1.append(np.nan if res.error_message else res.observed_shape.e1)
    ref_fail = np.array(ref_fail)
    assert ref_fail.mean() >= 0.8
    np.testing.assert_array_equal(bad[3:], ref_fail)
    both = ~ref_fail
    np.testing.assert_allclose(np.asarray(t["e1"])[3:][both], np.array(ref_e1)[both], atol=1e-5)
    # The good stamp's result does not depend on the bad ones in its batch.
    alone = adaptive_moments(good[None])
    assert alone["e1"][0] == pytest.approx(t["e1"][0], abs=1e-12)


def test_guess_centroid_and_errors():
    st = _draw(_profiles()["gaussian"], (3.0, -2.0))
    t = adaptive_moments(st[None], guess_centroid=(19.0, 14.0))
    assert t["flag"][0] == 0
    assert t["x0"][0] == pytest.approx(19.0, abs=1e-4)
    assert t["y0"][0] == pytest.approx(14.0, abs=1e-4)
    with pytest.raises(ValueError, match="square"):
        adaptive_moments(np.ones((2, 5, 6)))
    with pytest.raises(ValueError, match="square number"):
        adaptive_moments(np.ones((2, 10)))
    with pytest.raises(ValueError, match="guess_sigma"):
        adaptive_moments(st[None], guess_sigma=-1)
    with pytest.raises(ValueError, match="guess_centroid"):
        adaptive_moments(st[None], guess_centroid=[[1.0, 2.0, 3.0]])


def test_max_iter_flag():
    st = _draw(_profiles()["kolmogorov"])
    t = adaptive_moments(st[None], max_iter=2)
    assert t["flag"][0] != 0 and np.isnan(t["e1"][0])


@pytest.mark.skipif(_moments._iterate_numba is None, reason="numba is not installed")
def test_numba_and_numpy_paths_agree():
    rng = np.random.default_rng(3)
    profs = list(_profiles().values())
    cube = np.array([_draw(profs[i % 4], rng.uniform(-1, 1, 2)) for i in range(40)])
    cube += rng.normal(0.0, 1e-4, cube.shape)
    cube[5, 3, 3] = np.inf
    cube[6] = 0.0
    tables = {}
    for use in (False, True):
        _moments._USE_NUMBA = use
        tables[use] = adaptive_moments(cube)
    np.testing.assert_array_equal(tables[True]["flag"], tables[False]["flag"])
    for col in ("e1", "e2", "sigma", "x0", "y0", "Mxx", "Mxy", "Myy", "amplitude"):
        np.testing.assert_allclose(tables[True][col], tables[False][col], rtol=0, atol=1e-6)
