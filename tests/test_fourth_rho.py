"""The fourth-moment correlation functions (DES Y6 PSF diagnostics) against a brute-force sum
over every pair, and their place in the reserved-star residuals and the fit's report."""

import numpy as np
import pytest

from sklearn_psf.metrics import FOURTH_RHO_NAMES, fourth_moment_rho_statistics
from sklearn_psf.validation import measure_residuals


def _brute(X, a, b, edges, auto):
    """Mean of Re(a_i conj(b_j)) over the pairs whose separation falls in each bin: the
    unordered pairs i < j for an auto-correlation, the ordered pairs i != j for a cross one
    (xi+ of spin-2 fields and the scalar <a b> are both this: the rotation to each pair's
    frame cancels in a_i conj(b_j))."""
    d = np.hypot(*(X[:, None, :] - X[None, :, :]).transpose(2, 0, 1))
    prod = np.real(a[:, None] * np.conj(b[None, :]))
    i, j = np.triu_indices(len(X), 1) if auto else np.nonzero(~np.eye(len(X), dtype=bool))
    k = np.searchsorted(edges, d[i, j]) - 1
    inside = (k >= 0) & (k < len(edges) - 1)
    total = np.bincount(k[inside], prod[i, j][inside], len(edges) - 1)
    count = np.bincount(k[inside], minlength=len(edges) - 1)
    return total / count, count / (1 if auto else 2)


def test_against_brute_force_pair_sums():
    rng = np.random.default_rng(1)
    n = 250
    X = rng.uniform(0, 1000, (n, 2))
    smooth = np.cos(X[:, 0] / 200) + np.sin(X[:, 1] / 300)
    dM31, dM13 = 0.02 * smooth + rng.normal(0, 0.01, n), rng.normal(0, 0.01, n)
    dM22 = 0.03 * smooth + rng.normal(0, 0.01, n)
    de1, de2 = 0.01 * smooth + rng.normal(0, 0.005, n), rng.normal(0, 0.005, n)
    dT = rng.normal(0, 0.01, n) + 0.005 * smooth
    min_sep, max_sep, nbins = 20.0, 600.0, 5
    rho = fourth_moment_rho_statistics(X, dM31, dM13, dM22, de1, de2, dT, min_sep=min_sep,
                                       max_sep=max_sep, nbins=nbins, bin_slop=0,
                                       num_threads=1)
    assert tuple(rho) == FOURTH_RHO_NAMES
    edges = np.exp(np.linspace(np.log(min_sep), np.log(max_sep), nbins + 1))
    m4, e = dM31 + 1j * dM13, de1 + 1j * de2
    cases = {"rho_M4": (m4, m4, True), "rho_eM4": (e, m4, False),
             "rho_M22": (dM22, dM22, True), "rho_TM22": (dT, dM22, False)}
    for name, (a, b, auto) in cases.items():
        xi, pairs = _brute(X, a, b, edges, auto)
        # exact pair binning (bin_slop=0): the same sums, to TreeCorr's rounding (measured
        # 3e-8 relative)
        np.testing.assert_allclose(rho[name].xi, xi, rtol=1e-6, atol=1e-14, err_msg=name)
        np.testing.assert_allclose(rho[name].npairs, pairs * (1 if auto else 2), rtol=0,
                                   err_msg=name)
    assert rho["rho_M22"].xi[0] > 0  # the smooth part correlates at small separations


def test_reserved_star_residuals_carry_the_fourth_moment_diagnostics():
    """Stars of a Gaussian PSF of sigma 2.2 against a model of sigma 2.0: every star's
    relative fourth moments differ by the analytic amount (a Gaussian under its adaptive weight
    has M22 = 2 sigma^4, M31 = M13 = 0), and the spin-0 correlation is its square."""
    rng = np.random.default_rng(0)
    n, s = 40, 25
    yy, xx = np.mgrid[0:s, 0:s] - (s - 1) / 2

    def gauss(sigma):
        g = np.exp(-0.5 * (xx**2 + yy**2) / sigma**2)
        return g / g.sum()

    X = rng.uniform(0, 2000, (n, 2))
    stars = np.tile(1e6 * gauss(2.2), (n, 1, 1))
    table, summary = measure_residuals(X, stars, np.tile(gauss(2.0), (n, 1, 1)),
                                       weights=np.ones((n, s, s)), nbins=3)
    expected = (2 * 2.2**4 - 2 * 2.0**4) / 2.2**4  # dM22 / sigma_star^4
    assert summary["dM22_rel_mean"] == pytest.approx(expected, rel=2e-3)
    assert summary["dM4_rel_rms"] < 1e-6
    xi = np.asarray(summary["rho_M22"]["xi"])
    np.testing.assert_allclose(xi[np.isfinite(xi)], expected**2, rtol=4e-3)
    assert np.nanmax(np.abs(summary["rho_M4"]["xi"])) < 1e-10


def test_verdict_fourth_moment_residuals_are_their_noise_for_a_constant_psf():
    """Stars of one Gaussian PSF with white noise of known variance: the model (fitted on the
    others) is the PSF up to its small fitting error, so the reserved stars' fourth-moment
    residuals are their noise, and their rms over the Monte Carlo noise rms is ~1, as the
    ellipticity's (measured 0.86 and 1.01, e 1.02, on 60 reserved stars)."""
    import warnings

    from sklearn_psf.validation import fit_and_validate

    rng = np.random.default_rng(5)
    n, s = 300, 21
    yy, xx = np.mgrid[0:s, 0:s] - (s - 1) / 2
    psf = np.exp(-0.5 * (xx**2 / 2.2**2 + yy**2 / 1.9**2))
    psf /= psf.sum()
    X = rng.uniform(0, 3000, (n, 2))
    noise = 2.0
    stars = 4000.0 * psf + rng.normal(0.0, noise, (n, s, s))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _, _, summary = fit_and_validate(X, stars, weights=np.full((n, s, s), noise**-2),
                                         reserve=0.2, random_state=0)
    for key in ("e_resid_over_noise", "dM22_resid_over_noise", "dM4_resid_over_noise"):
        assert 0.75 < summary[key] < 1.35, (key, summary[key])
