"""Colour and flux as dimensions of the PSF model (the PSF of each source).

Estimator level: the extra correlation lengths (``KrigingRegressor(extra_scaling="auto")``)
against scikit-learn's ``GaussianProcessRegressor`` with an anisotropic (ARD) Matern kernel,
the linear trend's extrapolation, PSFEx's degree groups for polynomials.

Model level, on small simulated fields (``make_psf_field``; 400 stars at S/N 50-500, 1500
galaxies; the same seed for every variant, so that stars, PSF pattern and noise are shared):
the size residual ``ds = (sigma_model - sigma_true) / sigma_true`` at the galaxies (adaptive
moments) of the default model on (x, y) and on (x, y, extra columns). "Paired" figures
subtract the position-only model's ``ds`` on the control field (no colour or flux
dependence), which removes the interpolation error both share and leaves what the colour or
flux does; ``benchmarks/bench_extra_dimensions.py`` gives the figures on 10 larger fields.
"""

import warnings

import numpy as np
import pytest
from sklearn.gaussian_process import GaussianProcessRegressor
from sklearn.gaussian_process.kernels import ConstantKernel, Matern, WhiteKernel
from sklearn.utils.estimator_checks import parametrize_with_checks

from sklearn_psf.interpolate import (
    ChebyshevRegressor,
    IsotropicScaler,
    KrigingRegressor,
    PolynomialRegressor,
)
from sklearn_psf.measure import adaptive_moments
from sklearn_psf.model import PSFModel, make_default_interpolator
from sklearn_psf.simulate import SourceSettings, make_psf_field


# the checks' random data have no spatial correlation to find, and duplicated rows: warned by
# design (the fallbacks are asserted in tests/test_interpolate*.py)
@pytest.mark.filterwarnings("ignore::sklearn_psf.interpolate.ShortRangeWarning")
@pytest.mark.filterwarnings("ignore::sklearn_psf.interpolate.DuplicateStarsWarning")
@parametrize_with_checks([IsotropicScaler(n_positions=2),
                          KrigingRegressor(range="auto", extra_scaling="auto",
                                           extra_drift="linear")],
                         expected_failed_checks=lambda est: {})
def test_sklearn_compatible(estimator, check):
    check(estimator)


def test_extra_lengths_are_the_gaussian_process_likelihood_optimum():
    """One correlation length per extra dimension by maximum likelihood. Reference:
    GaussianProcessRegressor with ConstantKernel * Matern(nu=0.5, ARD lengths: the range on
    x and y, range / extra_scaling_ on the colour) + the noise, on the values less the GLS
    mean: its log-likelihood equals ours, and its gradient vanishes there (the x and y lengths
    tied, as ours are)."""
    rng = np.random.default_rng(3)
    n = 150
    X = np.column_stack([rng.uniform(size=(n, 2)), rng.uniform(size=n)])
    y = np.sin(8 * X[:, 0]) + np.cos(7 * X[:, 1]) + 0.8 * np.sin(5 * X[:, 2])
    noise = 1e-2
    y_obs = y + rng.normal(0, np.sqrt(noise), n)
    reg = KrigingRegressor(range="auto", extra_scaling="auto", likelihood="exact").fit(
        X, y_obs, noise_var=np.full(n, noise))
    a, e = reg.range_, reg.extra_scaling_[0]
    assert 0.05 < e < 5.0  # the colour matters: a length of the order of the range
    kernel = (ConstantKernel(reg.sill_[0]) * Matern([a, a, a / e], nu=0.5)
              + WhiteKernel(noise, "fixed"))
    gp = GaussianProcessRegressor(kernel, optimizer=None).fit(X, y_obs - reg.mean_[0])
    ll, grad = gp.log_marginal_likelihood(gp.kernel_.theta, eval_gradient=True)
    assert ll == pytest.approx(reg.log_likelihood_, abs=1e-6 * n)
    tied = np.array([grad[0], grad[1] + grad[2], grad[3]])  # sill, (x, y) length, colour
    assert np.abs(tied).max() < 1e-2  # measured 1e-4 (the range is inside its bounds)
    # and a dimension moved off its optimum lowers the likelihood (the gradient is not 0)
    off = gp.kernel_.clone_with_theta(gp.kernel_.theta + [0, 0, 0, 0.3])
    assert gp.log_marginal_likelihood(off.theta) < ll - 0.1


def test_dimension_without_effect_costs_nothing_and_trend_extrapolates():
    rng = np.random.default_rng(0)
    n = 200
    P = rng.uniform(size=(n, 2))
    c = rng.uniform(0.3, 3.0, n)
    field = np.sin(3 * P[:, 0]) + np.cos(2 * P[:, 1])
    noise = np.full(n, 1e-4)
    y = field + rng.normal(0, 1e-2, n)
    pos = KrigingRegressor(range="auto").fit(P, y, noise_var=noise)
    both = KrigingRegressor(range="auto", extra_scaling="auto", extra_drift="linear").fit(
        np.column_stack([P, c]), y, noise_var=noise)
    # no effect: a correlation length along the colour >= 100 times the range
    assert 1.0 / both.extra_scaling_[0] >= 100.0
    Q = rng.uniform(size=(300, 2))
    truth = np.sin(3 * Q[:, 0]) + np.cos(2 * Q[:, 1])
    err_pos = np.sqrt(np.mean((pos.predict(Q) - truth) ** 2))
    err_both = np.sqrt(np.mean((both.predict(np.column_stack([Q, rng.uniform(0, 2, 300)]))
                                - truth) ** 2))
    assert err_both <= 1.05 * err_pos
    # a linear trend in the colour, predicted beyond the stars' colours (0 < 0.3)
    slope = 0.05
    trend = KrigingRegressor(range="auto", extra_scaling="auto", extra_drift="linear").fit(
        np.column_stack([P, c]), y + slope * c, noise_var=noise)
    blue = np.column_stack([Q, np.zeros(300)])
    bias = np.mean(trend.predict(blue) - truth)
    assert abs(bias) < 0.1 * slope * 1.5  # vs slope * 1.65 for the mean colour's value
    flat = KrigingRegressor(range="auto", extra_scaling="auto").fit(
        np.column_stack([P, c]), y + slope * c, noise_var=noise)
    assert abs(np.mean(flat.predict(blue) - truth)) > 3 * abs(bias)


def test_position_only_default_unchanged():
    """On (x, y) the default pipeline with its extra-dimension settings is the former one."""
    rng = np.random.default_rng(1)
    X = rng.uniform(0, 2000, (120, 2)) * [1.0, 0.7]
    Y = np.column_stack([np.sin(X[:, 0] / 500), np.cos(X[:, 1] / 400)])
    Y = Y + rng.normal(0, 0.01, Y.shape)
    noise = np.full(Y.shape, 1e-4)
    new = make_default_interpolator().fit(X, Y, krigingregressor__noise_var=noise)
    old = KrigingRegressor(range="auto", drift="auto", n_neighbors="auto").fit(
        IsotropicScaler().fit_transform(X), Y, noise_var=noise)
    Q = rng.uniform(0, 1400, (50, 2))
    np.testing.assert_array_equal(new.predict(Q),
                                  old.predict(IsotropicScaler().fit(X).transform(Q)))


def test_polynomial_groups_as_psfex():
    """Degrees (3, 1): x^i y^j c^k with i + j <= 3, k <= 1 (PSFEx's groups): 20 terms,
    the least-squares fit on them (numpy's lstsq on the explicit design)."""
    rng = np.random.default_rng(2)
    X = np.column_stack([rng.uniform(size=(80, 2)), rng.uniform(0, 3, 80)])
    y = rng.normal(size=80)
    reg = PolynomialRegressor(degree=(3, 1)).fit(X, y)
    U = (X - (X.min(0) + X.max(0)) / 2) / ((X.max(0) - X.min(0)) / 2)
    cols = [U[:, 0] ** i * U[:, 1] ** j * U[:, 2] ** k
            for k in range(2) for i in range(4) for j in range(4 - i)]
    A = np.column_stack(cols)
    assert A.shape[1] == reg.powers_.shape[0] == 20
    np.testing.assert_allclose(reg.predict(X), A @ np.linalg.lstsq(A, y, rcond=None)[0],
                               atol=1e-10)
    # the Chebyshev basis spans the same space: the same predictions
    np.testing.assert_allclose(ChebyshevRegressor(degree=(3, 1)).fit(X, y).predict(X),
                               reg.predict(X), atol=1e-9)
    with pytest.raises(ValueError, match="2 values for 3 features"):
        PolynomialRegressor(degree=(3, 1, 1)).fit(X, y)


# ----------------------------------------------------------------------- model level
_N_STARS, _N_GALAXIES, _SHAPE, _SEED = 400, 1500, (2500, 2500), 0


def _design(table, extra):
    return np.column_stack([table["x"], table["y"]] + [table[c] for c in extra])


def _size_residual(field, extra=()):
    stamps, weights, _ = field.star_stamps(return_weights=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = PSFModel().fit(_design(field.stars, extra), stamps, weights=weights)
    mom = adaptive_moments(model.predict(_design(field.galaxies, extra)))
    g = field.galaxies
    ds = (np.asarray(mom["sigma"]) - g["sigma"]) / g["sigma"]
    de2 = (np.asarray(mom["e1"]) - g["e1"]) ** 2 + (np.asarray(mom["e2"]) - g["e2"]) ** 2
    return np.asarray(ds), np.asarray(de2)


@pytest.fixture(scope="module")
def fields():
    rng = np.random.default_rng(_SEED)
    kw = dict(n_stars=_N_STARS, n_galaxies=_N_GALAXIES, image_shape=_SHAPE,
              snr=rng.uniform(50.0, 500.0, _N_STARS), random_state=_SEED)
    ctrl = make_psf_field(**kw)
    chrom = make_psf_field(sources=SourceSettings(chromatic=True, airmass=1.2), **kw)
    bf = make_psf_field(sources=SourceSettings(brighter_fatter=0.02), **kw)
    return ctrl, chrom, bf, _size_residual(ctrl)


def test_colour_dimension_removes_the_size_slope(fields):
    ctrl, chrom, _, (ds0, _) = fields
    colour = np.asarray(chrom.galaxies["g_i"])
    truth = np.polyfit(colour, np.log(chrom.galaxies["sigma"] / ctrl.galaxies["sigma"]), 1)[0]
    ds_pos, _ = _size_residual(chrom)
    ds_col, _ = _size_residual(chrom, ("g_i",))
    pos = np.polyfit(colour, ds_pos - ds0, 1)[0]
    col = np.polyfit(colour, ds_col - ds0, 1)[0]
    # the position-only model misses the true colour dependence (~ -0.1% per magnitude)
    assert truth < -5e-4
    assert pos == pytest.approx(-truth, rel=0.2)
    # the colour model removes most of it: measured 17% on this field (0.2-17% on five
    # fields, ~7% of it systematic: the linear trend fitted on the stars' colours, 0.3-3,
    # extrapolated to the galaxies', 0-2, of a slightly curved dependence); the issue's 10%
    # line is the 10-simulation benchmark's
    assert abs(col) <= 0.3 * abs(pos)


def test_flux_dimension_removes_the_brighter_fatter_bias(fields):
    ctrl, _, bf, (ds0, _) = fields
    ds_pos, _ = _size_residual(bf)
    ds_flux, _ = _size_residual(bf, ("source_snr",))
    # position-only: the galaxies (fainter than every star) get the average star's larger
    # PSF: about +1% (half the 2% growth, the S/N being uniform)
    assert (ds_pos - ds0).mean() == pytest.approx(0.01, rel=0.3)
    # with the flux: at most 1e-3 (measured -1.6e-4 paired, -2.6e-4 raw on this field)
    assert abs((ds_flux - ds0).mean()) <= 1e-3
    assert abs(ds_flux.mean()) <= 1e-3


def test_extra_columns_without_effect_keep_the_e_rms(fields):
    ctrl, chrom, bf, _ = fields
    for name in ("stars", "galaxies"):
        getattr(ctrl, name)["g_i"] = getattr(chrom, name)["g_i"]
        getattr(ctrl, name)["source_snr"] = getattr(bf, name)["source_snr"]
    _, de0 = _size_residual(ctrl)
    _, de_x = _size_residual(ctrl, ("g_i", "source_snr"))
    # within 1.02x of the position-only model's e rms (measured 1.014 on this field; see the
    # benchmark for 10 larger fields)
    assert np.sqrt(de_x.mean() / de0.mean()) <= 1.02


def test_quadratic_extra_drift_extrapolates_a_curved_trend():
    """extra_drift="quadratic": a value curved in the extra feature (analytic: 0.5 (c - 1)^2
    plus a field in x) is extrapolated to colours beyond the stars' range, where the linear
    trend misses it."""
    rng = np.random.default_rng(0)
    n = 150
    X = np.column_stack([rng.uniform(size=(n, 2)), rng.uniform(0.3, 3.0, n)])
    y = 0.5 * (X[:, 2] - 1) ** 2 + 0.1 * np.sin(5 * X[:, 0])
    q = np.array([[0.5, 0.5, 0.0], [0.5, 0.5, -0.5]])
    truth = 0.5 * (q[:, 2] - 1) ** 2 + 0.1 * np.sin(2.5)
    errors = {}
    for drift in ("linear", "quadratic"):
        reg = KrigingRegressor(range="auto", extra_scaling="auto", extra_drift=drift).fit(
            X, y, noise_var=np.full(n, 1e-6))
        errors[drift] = np.abs(reg.predict(q) - truth).max()
    assert errors["quadratic"] < 0.01  # measured 1.6e-3
    assert errors["linear"] > 0.3      # measured 1.46
    with pytest.raises(ValueError, match="extra_drift"):
        KrigingRegressor(extra_drift="cubic").fit(X, y)
