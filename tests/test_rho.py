"""rho1-rho5 (Jarvis et al. 2016) against a brute-force pair sum, flat and on the sky."""

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from sklearn_psf.metrics import RHO_NAMES, rho_statistics


def _pair_sum(d, a, b, min_sep, max_sep, nbins):
    """Mean Re(a_i b_j*) over ordered pairs i != j (unordered i < j when a is b) in log bins."""
    n = len(a)
    if a is b:
        i, j = np.triu_indices(n, k=1)
    else:
        i, j = np.nonzero(~np.eye(n, dtype=bool))
    sep = d[i, j]
    prod = (a[i] * np.conj(b[j])).real
    keep = (sep >= min_sep) & (sep < max_sep)
    idx = np.floor(np.log(sep[keep] / min_sep) / (np.log(max_sep / min_sep) / nbins)).astype(int)
    npairs = np.bincount(idx, minlength=nbins)
    return np.bincount(idx, weights=prod[keep], minlength=nbins) / npairs, npairs


def _shapes(X, scale, rng):
    """Star and model shapes: smooth PSF field, a model with smooth errors and noisy stars."""
    n = len(X)
    u, v = X[:, 0] / scale, X[:, 1] / scale
    e_model = 0.04 * np.exp(1j * (u + 0.5 * v)) + 0.01
    T_model = 8.0 * (1 + 0.05 * np.sin(v))
    e_star = e_model + 0.01 * np.cos(2 * u) + 0.003 * (rng.standard_normal(n)
                                                        + 1j * rng.standard_normal(n))
    T_star = T_model * (1 + 0.02 * np.cos(u) + 0.005 * rng.standard_normal(n))
    return e_star, T_star, e_model, T_model


def _expected(d, e_star, T_star, e_model, T_model, *binning):
    de = e_star - e_model
    edt = e_star * (T_star - T_model) / T_star
    pairs = {"rho1": (de, de), "rho2": (e_star, de), "rho3": (edt, edt), "rho4": (de, edt),
             "rho5": (e_star, edt)}
    return {k: _pair_sum(d, a, a if a is b else b, *binning) for k, (a, b) in pairs.items()}


def test_rho_statistics_match_brute_force():
    rng = np.random.default_rng(3)
    X = rng.uniform(0, 2000, (700, 2))
    e_star, T_star, e_model, T_model = _shapes(X, 400.0, rng)
    binning = (20.0, 1500.0, 6)
    rho = rho_statistics(X, e_star.real, e_star.imag, T_star, e_model.real, e_model.imag,
                         T_model, min_sep=binning[0], max_sep=binning[1], nbins=binning[2],
                         bin_slop=0, num_threads=1)
    d = np.hypot(X[:, None, 0] - X[None, :, 0], X[:, None, 1] - X[None, :, 1])
    expected = _expected(d, e_star, T_star, e_model, T_model, *binning)
    assert tuple(rho) == RHO_NAMES
    for name in RHO_NAMES:
        xi, npairs = expected[name]
        assert_array_equal(rho[name].npairs, npairs, err_msg=name)
        assert_allclose(rho[name].xi, xi, rtol=1e-6, atol=1e-12, err_msg=name)
    # the statistics differ: rho2 (e x de) is dominated by the PSF field, rho3 is second order
    assert np.abs(rho["rho2"].xi).max() > 10 * np.abs(rho["rho3"].xi).max()


def test_rho_statistics_on_the_sky_use_great_circle_separations():
    rng = np.random.default_rng(4)
    n = 500
    ra0, dec0 = 150.0, 2.2
    radec = np.column_stack([ra0 + rng.uniform(-0.15, 0.15, n),
                             dec0 + rng.uniform(-0.15, 0.15, n)])
    e_star, T_star, e_model, T_model = _shapes(radec * 3600 / 60.0, 1.0, rng)
    binning = (0.5, 15.0, 5)  # arcmin
    rho = rho_statistics(radec, e_star.real, e_star.imag, T_star, e_model.real, e_model.imag,
                         T_model, min_sep=binning[0], max_sep=binning[1], nbins=binning[2],
                         sky=True, bin_slop=0, num_threads=1)
    ra, dec = np.radians(radec).T
    cos_d = (np.sin(dec[:, None]) * np.sin(dec[None, :])
             + np.cos(dec[:, None]) * np.cos(dec[None, :]) * np.cos(ra[:, None] - ra[None, :]))
    d = np.degrees(np.arccos(np.clip(cos_d, -1, 1))) * 60.0
    expected = _expected(d, e_star, T_star, e_model, T_model, *binning)
    for name in RHO_NAMES:
        xi, npairs = expected[name]
        assert_array_equal(rho[name].npairs, npairs, err_msg=name)
        # TreeCorr parallel-transports the shapes along the great circle: tiny on 0.3 degree
        assert_allclose(rho[name].xi, xi, rtol=2e-3, atol=1e-7, err_msg=name)
    # the catalogues were built on one thread (num_threads), TreeCorr's setting restored
    import treecorr.util
    assert treecorr.util.max_omp_threads is None


def test_rho_statistics_bad_input():
    X = np.random.default_rng(0).uniform(0, 100, (20, 2))
    z = np.zeros(20)
    with pytest.raises(ValueError, match="T_star must be positive"):
        rho_statistics(X, z, z, z, z, z, z + 1, min_sep=1, max_sep=50, nbins=3)
    with pytest.raises(ValueError, match="e1_model has 19 values"):
        rho_statistics(X, z, z, z + 1, z[:19], z, z + 1, min_sep=1, max_sep=50, nbins=3)
