"""Tests of sklearn_psf.measure.adaptive_moments against GalSim HSM and analytic Gaussians."""

import galsim
import numpy as np
import pytest

from sklearn_psf.measure import (
    FLAG_BAD_PIXELS,
    FLAG_MASKED,
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


def _hsm(stamp, mask=None):
    """HSM's moments; ``mask`` (True = bad) goes in as ``badpix``, its pixels zeroed for HSM
    (which multiplies the image by the mask, so a NaN there would spread)."""
    badpix = None
    if mask is not None:
        stamp = np.where(mask, 0.0, stamp)
        badpix = galsim.Image(mask.astype(np.int32))
    res = galsim.hsm.FindAdaptiveMom(galsim.Image(stamp, scale=1.0), badpix=badpix)
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
    inf = good.copy()
    inf[3, 4] = np.inf
    noise = rng.normal(0.0, 1.0, (20,) + good.shape)
    batch = np.concatenate([good[None], zero[None], inf[None], noise])
    t = adaptive_moments(batch)
    assert t["flag"][0] == 0
    assert t["flag"][1] & FLAG_NO_FLUX
    assert t["flag"][2] & FLAG_BAD_PIXELS
    # the same infinite pixel, masked, is left out
    w = np.ones_like(batch)
    w[2, 3, 4] = 0.0
    t_masked = adaptive_moments(batch[:3], weights=w[:3])
    assert t_masked["flag"][2] == 0
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
    weights = np.where(rng.random(cube.shape) < 0.05, 0.0, 1.0)
    weights[20:30, :, 16] = 0.0  # a masked column through the star
    weights[30:35, 14:19, 14:19] = 0.0  # masked cores (FLAG_MASKED)
    weights[35] = 0.0
    tables = {}
    for use in (False, True):
        _moments._USE_NUMBA = use
        tables[use] = adaptive_moments(cube)
        tables[use, "masked"] = adaptive_moments(cube, weights=weights)
    assert np.any(tables[True, "masked"]["flag"] == FLAG_MASKED)
    assert np.any(tables[True, "masked"]["flag"] == 0)
    # Which stamps fail, and which are FLAG_MASKED, agree; not always why the others fail: a
    # tiny star cut by a column collapses to a singular weight, which the compiled kernel
    # detects (FLAG_DIVERGED) before max_iter and the numpy path does not (GalSim fails too).
    flags = {use: np.asarray(tables[use, "masked"]["flag"]) for use in (False, True)}
    np.testing.assert_array_equal(flags[True] != 0, flags[False] != 0)
    np.testing.assert_array_equal(flags[True] & FLAG_MASKED, flags[False] & FLAG_MASKED)
    for col in ("e1", "e2", "sigma", "x0", "y0", "Mxx", "Mxy", "Myy", "amplitude"):
        np.testing.assert_allclose(tables[True, "masked"][col], tables[False, "masked"][col],
                                   rtol=0, atol=1e-6)
    np.testing.assert_array_equal(tables[True]["flag"], tables[False]["flag"])
    for col in ("e1", "e2", "sigma", "x0", "y0", "Mxx", "Mxy", "Myy", "amplitude"):
        np.testing.assert_allclose(tables[True][col], tables[False][col], rtol=0, atol=1e-6)


# ---------------------------------------------------------------- masked pixels (weights, NaN)


def _masked_batch(seed=7):
    """Noisy Gaussian, Moffat and Kolmogorov stamps at sub-pixel offsets, with 4% of random
    pixels masked and a bad column 2-5 px from the star; masked pixels hold garbage (NaN,
    +-1e30) and the weights are noisy inverse variances. Returns stamps, weights, mask and
    the stamps before masking."""
    rng = np.random.default_rng(seed)
    profs = list(_profiles().values())[:3]
    n = 36
    offsets = rng.uniform(-1.5, 1.5, (n, 2))
    clean = np.array([_draw(profs[i % 3], offsets[i]) for i in range(n)])
    sigma_noise = clean.max(axis=(1, 2)) / 150.0  # peak S/N 150
    stamps = clean + rng.normal(0.0, 1.0, clean.shape) * sigma_noise[:, None, None]
    mask = rng.random(stamps.shape) < 0.04
    centre = (SIZE - 1) // 2
    for i in range(n):
        step = rng.integers(2, 6) * rng.choice([-1, 1])
        mask[i, :, centre + int(round(offsets[i, 0])) + step] = True
    garbage = rng.choice([np.nan, 1e30, -1e30], size=stamps.shape)
    full = stamps
    stamps = np.where(mask, garbage, stamps)
    weights = rng.uniform(0.5, 2.0, stamps.shape) / sigma_noise[:, None, None] ** 2
    weights[mask] = 0.0
    return stamps, weights, mask, full


def test_masked_agrees_with_galsim_hsm_badpix():
    stamps, weights, mask, full = _masked_batch()
    s_before, w_before = stamps.copy(), weights.copy()
    table = adaptive_moments(stamps, weights=weights)
    np.testing.assert_array_equal(stamps, s_before)  # inputs untouched
    np.testing.assert_array_equal(weights, w_before)
    assert np.all(table["flag"] == 0)
    ref = np.array([_hsm(st, m) for st, m in zip(stamps, mask)])
    ours = np.column_stack([table[c] for c in ("e1", "e2", "sigma", "x0", "y0")])
    np.testing.assert_allclose(ours[:, :2], ref[:, :2], rtol=0, atol=1e-6)
    np.testing.assert_allclose(ours[:, 2], ref[:, 2], rtol=1e-6)  # GalSim stores float32
    np.testing.assert_allclose(ours[:, 3:], ref[:, 3:], rtol=0, atol=1e-6)
    # The masks matter: the same stamps measured with their pixels intact differ.
    intact = adaptive_moments(full)
    assert np.max(np.abs(intact["e1"] - ref[:, 0])) > 1e-3


def test_weights_only_mask_nan_is_masked_and_flat_layout():
    stamps, weights, mask, _ = _masked_batch()
    ref = adaptive_moments(stamps, weights=weights)
    # Positive weights do not re-weight: only zero / non-zero matters.
    binary = adaptive_moments(stamps, weights=(weights > 0).astype(float))
    # NaN pixels are masked without weights; flattened weights are accepted.
    nan_only = adaptive_moments(np.where(mask, np.nan, stamps))
    flat = adaptive_moments(stamps.reshape(len(stamps), -1),
                            weights=weights.reshape(len(stamps), -1))
    for t in (binary, nan_only, flat):
        for col in ("e1", "e2", "sigma", "x0", "y0", "amplitude", "n_iter", "flag"):
            np.testing.assert_array_equal(t[col], ref[col])
    # Unmasked stamps: weights of ones give the result without weights, bit for bit.
    clean = np.where(mask, 0.0, stamps)
    a = adaptive_moments(clean)
    b = adaptive_moments(clean, weights=np.ones_like(clean))
    for col in a.colnames:
        np.testing.assert_array_equal(a[col], b[col])


def test_masked_core_and_all_masked_are_flagged():
    cov = np.array([[4.0, 1.0], [1.0, 3.0]])  # sigma = det^(1/4) = 1.82 px
    icov = np.linalg.inv(cov)
    y, x = np.mgrid[0:25, 0:25] - 12.0
    img = np.exp(-0.5 * (icov[0, 0] * x**2 + 2 * icov[0, 1] * x * y + icov[1, 1] * y**2))
    weights = np.ones((12,) + img.shape)
    weights[0, 12, 12] = 0.0  # the centre pixel alone: 5% of the flux, measured
    for half in range(1, 9):  # masked square cores of side 3 to 17: 35% to 100% of the flux
        weights[half, 12 - half:13 + half, 12 - half:13 + half] = 0.0
    weights[9] = 0.0  # all masked
    batch = np.repeat(img[None], 12, axis=0)
    batch[10] = np.nan  # all NaN
    batch[11, :, 5:20] = np.nan  # NaN columns over the core, weight 0 elsewhere
    weights[11, :, :5] = 0.0
    t = adaptive_moments(batch, weights=weights)
    flag = np.asarray(t["flag"])
    assert flag[0] == 0
    ref = _hsm(img, weights[0] == 0)
    assert abs(t["e1"][0] - ref[0]) < 1e-6 and abs(t["e2"][0] - ref[1]) < 1e-6
    # 3x3 to 9x9 cores: HSM converges (sigma inflated by 50% to 150%), flagged here
    assert np.all(flag[1:5] == FLAG_MASKED)
    assert np.all(flag[5:] != 0)  # nothing left to measure (HSM fails too)
    assert np.all(flag[9:11] == FLAG_MASKED)
    for col in ("e1", "e2", "sigma", "x0", "y0", "amplitude"):
        assert np.all(np.isnan(np.asarray(t[col])[1:]))
    # A masked column through the centre of a small star (sigma 1.2 px, 31% of its flux) is
    # measured, as HSM does.
    small = _draw(galsim.Gaussian(sigma=1.2).shear(e1=0.1, e2=0.05))
    column = np.zeros(small.shape, dtype=bool)
    column[:, (SIZE - 1) // 2] = True
    t = adaptive_moments(small[None], weights=(~column)[None].astype(float))
    ref = _hsm(small, column)
    assert t["flag"][0] == 0
    assert abs(t["e1"][0] - ref[0]) < 1e-6 and abs(t["e2"][0] - ref[1]) < 1e-6
    # The flagged 5x5 case without the cut: HSM's moments, far from the star's (sigma 1.82)
    relaxed = adaptive_moments(img[None], weights=weights[2:3], max_masked_fraction=1.0)
    ref = _hsm(img, weights[2] == 0)
    assert relaxed["flag"][0] == 0 and relaxed["sigma"][0] > 3.0
    assert abs(relaxed["e1"][0] - ref[0]) < 1e-6 and abs(relaxed["e2"][0] - ref[1]) < 1e-6


def test_random_masks_never_give_unflagged_nan():
    rng = np.random.default_rng(11)
    profs = list(_profiles().values())
    cube = np.array([_draw(profs[i % 4], rng.uniform(-2, 2, 2)) for i in range(60)])
    cube += rng.normal(0.0, 0.01, cube.shape) * cube.max()
    weights = np.ones_like(cube)
    for i in range(60):  # random blobs of masked pixels, from none to most of the stamp
        cy, cx = rng.integers(8, 25, 2)
        r = rng.uniform(0, 14)
        weights[i][(np.arange(SIZE)[:, None] - cy) ** 2 + (np.arange(SIZE) - cx) ** 2 < r * r] = 0
    t = adaptive_moments(cube, weights=weights)
    flag = np.asarray(t["flag"])
    assert 0 < np.sum(flag == 0) < 60
    ok = flag == 0
    for col in ("e1", "e2", "sigma", "x0", "y0"):
        vals = np.asarray(t[col])
        assert np.all(np.isfinite(vals[ok])) and np.all(np.isnan(vals[~ok]))


def test_weights_errors():
    st = _draw(_profiles()["gaussian"])[None]
    with pytest.raises(ValueError, match="shape of the stamps"):
        adaptive_moments(st, weights=np.ones((1, 5, 5)))
    with pytest.raises(ValueError, match="shape of the stamps"):
        adaptive_moments(np.repeat(st, 2, axis=0), weights=np.ones_like(st))
    for value in (-1.0, np.nan, np.inf):
        w = np.ones((3,) + st.shape[1:])
        w[1, 4, 4] = value
        with pytest.raises(ValueError, match=r"rows 1:"):
            adaptive_moments(np.repeat(st, 3, axis=0), weights=w)
    for value in (0.0, 1.5, np.nan):
        with pytest.raises(ValueError, match="max_masked_fraction"):
            adaptive_moments(st, max_masked_fraction=value)
