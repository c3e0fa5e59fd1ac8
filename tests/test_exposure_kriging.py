"""ExposureKrigingRegressor against a dense Gaussian process written out, brute-force
leave-one-out, scipy's multivariate normal and finite differences; the inducing-point mode
against the exact one; what maximum likelihood learns from the split."""

import numpy as np
import pytest
from scipy.optimize import approx_fprime
from scipy.spatial.distance import cdist
from scipy.stats import multivariate_normal
from sklearn.utils.estimator_checks import parametrize_with_checks

from sklearn_psf.interpolate import ExposureKrigingRegressor
from sklearn_psf.interpolate._exposure_kriging import _solved_state
from sklearn_psf.interpolate._exposure_kriging_ml import _JointLikelihood


def _stars(n_exp=4, per=30, seed=0):
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0.0, 1000.0, (n_exp * per, 2))
    exposure = np.repeat(np.arange(n_exp), per)
    return rng, xy, exposure


def _cov(U, e, V, f, p, q, a_s, a_a):
    D = cdist(U, V)
    return p * np.exp(-D / a_s) + q * np.exp(-D / a_a) * (e[:, None] == f[None, :])


def _draw(static, atmosphere, seed=0, n_exp=4, per=30, a_s=0.3, a_a=0.15, noise=1e-3):
    """Targets drawn from the model itself (two targets), positions and noise."""
    rng, xy, e = _stars(n_exp, per, seed)
    U = (xy - xy.min(0)) / (xy.max(0) - xy.min(0))
    K = _cov(U, e, U, e, static, atmosphere, a_s, a_a) + noise * np.eye(len(U))
    Y = rng.multivariate_normal(np.zeros(len(U)), K, size=2).T + np.array([0.5, -1.0])
    return np.column_stack([xy, e]), Y, np.full(Y.shape, noise)


def _dense_reference(reg, X, Y, noise, Xq):
    """Predictions and leave-one-out of the same model written out with dense inverses."""
    lo, span = X[:, :2].min(0), (X[:, :2].max(0) - X[:, :2].min(0)).max()
    U, Uq = (X[:, :2] - lo) / span, (Xq[:, :2] - lo) / span
    e, eq = X[:, 2].astype(int), Xq[:, 2].astype(int)
    pred, loo = np.empty((len(Xq), Y.shape[1])), np.empty_like(Y)
    for t in range(Y.shape[1]):
        p, q = reg.static_sill_[t], reg.atmosphere_sill_[t]
        args = (p, q, reg.range_, reg.atmosphere_range_)
        K = _cov(U, e, U, e, *args) + np.diag(noise[:, t] + 1e-10 * (p + q))
        Ki = np.linalg.inv(K)
        one = np.ones(len(U))
        mu = one @ Ki @ Y[:, t] / (one @ Ki @ one)
        pred[:, t] = mu + _cov(Uq, eq, U, e, *args) @ Ki @ (Y[:, t] - mu)
        for i in range(len(U)):
            k = np.delete(np.arange(len(U)), i)
            Kk = np.linalg.inv(K[np.ix_(k, k)])
            m = one[k] @ Kk @ Y[k, t] / (one[k] @ Kk @ one[k])
            loo[i, t] = m + K[i, k] @ Kk @ (Y[k, t] - m)
    return pred, loo


@pytest.mark.parametrize("aspect", [1.0, 2.5])
def test_exact_mode_is_the_dense_gaussian_process(aspect):
    # aspect 2.5: a rectangular field, whose distances keep their proportions (one factor)
    X, Y, noise = _draw(0.6, 0.3, per=20)
    X[:, 0] *= aspect
    reg = ExposureKrigingRegressor().fit(X, Y, noise_var=noise)
    assert reg.exact_
    rng = np.random.default_rng(1)
    Xq = np.column_stack([rng.uniform(0, 1000, (25, 2)) * [aspect, 1.0], rng.integers(0, 4, 25)])
    pred, loo = _dense_reference(reg, X, Y, noise, Xq)
    np.testing.assert_allclose(reg.predict(Xq), pred, rtol=0, atol=1e-9)
    np.testing.assert_allclose(reg.loo_predict(), loo, rtol=0, atol=1e-9)
    # the leave-one-out standard deviation: the residual's, for a chi statistic
    _, std = reg.loo_predict(return_std=True)
    z = (Y - loo) / std
    assert 0.6 < np.std(z) < 1.5


def _noise_covariances(n, T, seed):
    """Each star's noise covariance across T targets: correlated (a shared flux term) and of
    different shapes from star to star."""
    rng = np.random.default_rng(seed)
    M = rng.normal(size=(n, T, T)) * 0.02
    shared = rng.normal(size=T)[None, :, None] * rng.uniform(0.02, 0.06, n)[:, None, None]
    cov = M @ np.transpose(M, (0, 2, 1)) + shared @ np.transpose(shared, (0, 2, 1))
    return cov + 1e-4 * np.eye(T)


def test_co_kriging_is_the_dense_multi_output_gaussian_process():
    # three targets with correlated signal and each star's full noise covariance: the model
    # written out as one (n T x n T) system with the fitted coregionalisation matrices
    rng, xy, e = _stars(3, 20, seed=5)
    U = (xy - xy.min(0)) / (xy.max(0) - xy.min(0)).max()  # the regressor's isotropic scaling
    n, T = len(U), 3
    mix = np.array([[1.0, 0.5, 0.0], [0.0, 0.8, 0.3], [0.2, 0.0, 0.6]])
    G = np.stack([rng.multivariate_normal(np.zeros(n), _cov(U, e, U, e, 0.6, 0.4, 0.3, 0.15))
                  for _ in range(T)], axis=1)
    noise_cov = _noise_covariances(n, T, seed=6)
    Y = G @ mix + np.array([0.3, -0.2, 0.1]) + np.stack(
        [rng.multivariate_normal(np.zeros(T), c) for c in noise_cov])
    X = np.column_stack([xy, e])
    reg = ExposureKrigingRegressor().fit(X, Y, noise_cov=noise_cov)
    assert reg.exact_ and reg.n_cg_iter_ > 0
    Bs, Ba = reg.static_coregionalization_, reg.atmosphere_coregionalization_
    assert not np.allclose(Bs, np.diag(np.diag(Bs)))  # the targets' signals correlate
    np.testing.assert_allclose(np.diag(Bs), reg.static_sill_)
    # dense reference: K = Bs (x) Rs + Ba (x) Ra + blockdiag(noise), target-major order
    Rs = np.exp(-cdist(U, U) / reg.range_)
    Ra = np.exp(-cdist(U, U) / reg.atmosphere_range_) * (e[:, None] == e[None, :])
    K = np.kron(Bs, Rs) + np.kron(Ba, Ra)
    for i in range(n):
        K[i::n, i::n] += noise_cov[i]
    F = np.kron(np.eye(T), np.ones((n, 1)))  # one unknown mean per target
    Ki = np.linalg.inv(K)
    y = Y.T.ravel()
    mean = np.linalg.solve(F.T @ Ki @ F, F.T @ Ki @ y)
    Xq = np.column_stack([rng.uniform(0, 1000, (15, 2)), rng.integers(0, 3, 15)])
    Uq = (Xq[:, :2] - xy.min(0)) / (xy.max(0) - xy.min(0)).max()
    eq = Xq[:, 2].astype(int)
    Rsq = np.exp(-cdist(Uq, U) / reg.range_)
    Raq = np.exp(-cdist(Uq, U) / reg.atmosphere_range_) * (eq[:, None] == e[None, :])
    pred = (np.kron(Bs, Rsq) + np.kron(Ba, Raq)) @ Ki @ (y - F @ mean)
    np.testing.assert_allclose(reg.mean_, mean, rtol=0, atol=1e-7)
    np.testing.assert_allclose(reg.predict(Xq), mean + pred.reshape(T, -1).T, rtol=0, atol=1e-7)
    # the variances alone (no cross-target noise) give another, worse-informed answer
    diag = ExposureKrigingRegressor().fit(X, Y, noise_var=np.einsum("itt->it", noise_cov))
    assert np.abs(diag.predict(Xq) - reg.predict(Xq)).max() > 1e-3


def test_inducing_points_at_the_stars_are_exact(monkeypatch):
    # with the stars themselves as inducing points, the approximation is the exact model:
    # this checks the Woodbury algebra, the exposure blocks and the leave-one-out diagonal
    X, Y, noise = _draw(0.6, 0.3, per=20)
    exact = ExposureKrigingRegressor(range=0.3, atmosphere_range=0.15).fit(X, Y, noise_var=noise)
    lo, span = X[:, :2].min(0), (X[:, :2].max(0) - X[:, :2].min(0)).max()
    U = (X[:, :2] - lo) / span
    monkeypatch.setattr(ExposureKrigingRegressor, "_inducing_grid", lambda self, d, extent: U)
    blocks = ExposureKrigingRegressor(range=0.3, atmosphere_range=0.15, max_exact_samples=10)
    blocks.fit(X, Y, noise_var=noise)
    assert not blocks.exact_
    rng = np.random.default_rng(2)
    Xq = np.column_stack([rng.uniform(0, 1000, (30, 2)), rng.integers(0, 4, 30)])
    np.testing.assert_allclose(blocks.predict(Xq), exact.predict(Xq), rtol=0, atol=2e-5)
    np.testing.assert_allclose(blocks.loo_predict(), exact.loo_predict(), rtol=0, atol=2e-5)


def test_inducing_grid_close_to_exact():
    X, Y, noise = _draw(0.6, 0.3, n_exp=6, per=40, seed=3)
    exact = ExposureKrigingRegressor().fit(X, Y, noise_var=noise)
    approx = ExposureKrigingRegressor(max_exact_samples=100, n_inducing=400)
    approx.fit(X, Y, noise_var=noise)
    assert exact.exact_ and not approx.exact_
    assert approx.range_ == exact.range_  # the same maximum-likelihood fit
    rng = np.random.default_rng(4)
    Xq = np.column_stack([rng.uniform(0, 1000, (200, 2)), rng.integers(0, 6, 200)])
    diff = approx.predict(Xq) - exact.predict(Xq)
    signal = exact.predict(Xq) - exact.mean_
    # measured 3-4% of the field's rms with 400 inducing points
    assert np.sqrt(np.mean(diff ** 2)) < 0.08 * np.sqrt(np.mean(signal ** 2))


def test_likelihood_and_gradient():
    X, Y, noise = _draw(0.5, 0.5, per=15)
    U = (X[:, :2] - X[:, :2].min(0)) / (X[:, :2].max(0) - X[:, :2].min(0))
    e = X[:, 2].astype(int)
    fun = _JointLikelihood(U, e, Y, noise, "exponential")
    theta = np.log([0.3, 0.2, 0.5, 0.4, 0.3, 0.2])
    nll, grad = fun(theta)
    # against scipy's multivariate normal at the generalised-least-squares mean
    ref = 0.0
    for t, (p, q) in enumerate([(0.5, 0.3), (0.4, 0.2)]):
        K = _cov(U, e, U, e, p, q, 0.3, 0.2) + np.diag(noise[:, t] + 1e-10 * (p + q))
        Ki = np.linalg.inv(K)
        mu = Ki.sum(0) @ Y[:, t] / Ki.sum()
        ref -= multivariate_normal(np.full(len(U), mu), K).logpdf(Y[:, t])
    assert nll == pytest.approx(ref, rel=1e-9)
    numeric = approx_fprime(theta, lambda th: fun(th)[0], 1e-6)
    np.testing.assert_allclose(grad, numeric, rtol=1e-3, atol=1e-3)


@pytest.mark.parametrize("static, atmosphere", [(1.0, 0.02), (0.02, 1.0)])
def test_maximum_likelihood_learns_the_split(static, atmosphere):
    X, Y, noise = _draw(static, atmosphere, n_exp=5, per=40, seed=6)
    reg = ExposureKrigingRegressor().fit(X, Y, noise_var=noise)
    fraction = reg.static_sill_ / (reg.static_sill_ + reg.atmosphere_sill_)
    if static > atmosphere:
        assert np.all(fraction > 0.8)
    else:
        assert np.all(fraction < 0.2)
        # the atmosphere alone: an exposure is predicted from its own stars; other
        # exposures' values barely matter
        Y2 = Y.copy()
        Y2[X[:, 2] != 0] += np.random.default_rng(0).normal(0, 0.3, Y2[X[:, 2] != 0].shape)
        fixed = {k: getattr(reg, f"{k}_") for k in ("range", "atmosphere_range")}
        other = ExposureKrigingRegressor(**fixed).fit(X, Y2, noise_var=noise)
        # the same sills: only the data differ
        fit = {"range": other.range_, "atmosphere_range": other.atmosphere_range_,
               "static_sill": reg._p, "atmosphere_sill": reg._q}
        solve = other._fit_exact(other._U_fit, other._e_fit, other._z_fit, noise, None, fit)
        vars(other).update(_solved_state(solve, reg._p, reg._q, None))
        Xq = np.column_stack([np.full(20, 500.0), np.linspace(0, 1000, 20), np.zeros(20)])
        change = np.abs(other.predict(Xq) - reg.predict(Xq)).max()
        assert change < 0.1 * np.std(Y[X[:, 2] == 0], axis=0).min()


def test_bad_input():
    X, Y, noise = _draw(0.5, 0.5, per=15)
    reg = ExposureKrigingRegressor().fit(X, Y, noise_var=noise)
    with pytest.raises(ValueError, match=r"exposures \[9\] were not in the fit"):
        reg.predict([[10.0, 10.0, 9]])
    bad = X.copy()
    bad[0, 2] = 0.5
    with pytest.raises(ValueError, match="integer exposure"):
        ExposureKrigingRegressor().fit(bad, Y)
    with pytest.raises(ValueError, match="'range' parameter of ExposureKrigingRegressor must"):
        ExposureKrigingRegressor(range=-1.0).fit(X, Y)
    with pytest.raises(ValueError, match="n_inducing"):
        ExposureKrigingRegressor(n_inducing=1).fit(X, Y)
    with pytest.raises(ValueError, match="noise_var"):
        ExposureKrigingRegressor().fit(X, Y, noise_var=-noise)
    before = X.copy()
    ExposureKrigingRegressor(range=0.3, atmosphere_range=0.2).fit(X, Y)
    np.testing.assert_array_equal(X, before)


_RANDOM_X = ("the check's X has no integer exposure column: the exposure index is data, "
             "and a random float column is no index")
_FAILS = ["check_regressors_train", "check_regressor_data_not_an_array",
          "check_regressor_multioutput", "check_regressors_int", "check_fit2d_predict1d",
          "check_methods_sample_order_invariance", "check_methods_subset_invariance",
          "check_estimators_dtypes", "check_dtype_object", "check_pipeline_consistency",
          "check_estimators_pickle", "check_f_contiguous_array_estimator",
          "check_readonly_memmap_input", "check_fit_idempotent", "check_fit_check_is_fitted",
          "check_n_features_in", "check_dict_unchanged", "check_fit_score_takes_y",
          "check_estimators_overwrite_params", "check_dont_overwrite_parameters",
          "check_estimators_fit_returns_self", "check_n_features_in_after_fitting",
          "check_positive_only_tag_during_fit", "check_regressors_no_decision_function",
          "check_estimators_nan_inf", "check_supervised_y_2d"]


@parametrize_with_checks([ExposureKrigingRegressor()],
                         expected_failed_checks=lambda e: dict.fromkeys(_FAILS, _RANDOM_X))
def test_sklearn_compatible(estimator, check):
    check(estimator)
