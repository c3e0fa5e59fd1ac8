"""Kriging hyperparameters by maximum likelihood, leave-one-out, few stars, bad input.

Reference: scikit-learn's GaussianProcessRegressor with the equivalent kernel
``ConstantKernel(c) * Matern(length_scale=a, nu=0.5) + WhiteKernel(w)``: the exponential
variogram of range ``a`` is the Matern nu=0.5 correlation ``exp(-h / a)``; our sill is
``c + w`` and our nugget (a fraction of the sill) ``w / (c + w)``. GPR has a zero mean, we
profile a constant mean (generalised least squares): GPR is fitted on ``y - mean_``. At our
optimum the derivative of the profile likelihood in the mean is zero, so GPR's optimum on
that data is the same point (envelope theorem), with the same log-likelihood.
"""

import warnings

import numpy as np
import pytest
from scipy.spatial.distance import cdist
from sklearn.gaussian_process import GaussianProcessRegressor
from sklearn.gaussian_process.kernels import ConstantKernel, Matern, WhiteKernel
from threadpoolctl import threadpool_limits

from sklearn_psf.interpolate import FewStarsWarning, KrigingRegressor


def gp_field(n, a, sills, nugget=0.0, seed=0, aniso=None):
    """Stars at random positions; a Gaussian field of exponential covariance, range a."""
    rng = np.random.default_rng(seed)
    X = rng.uniform(size=(n, 2))
    U = X if aniso is None else X @ aniso.T
    C = np.exp(-cdist(U, U) / a) * (1 - nugget) + nugget * np.eye(n)
    L = np.linalg.cholesky(C + 1e-12 * np.eye(n))
    Y = (L @ rng.normal(size=(n, len(sills)))) * np.sqrt(sills) + 3.0
    return X, Y, rng


@pytest.mark.parametrize("with_noise", [False, True])
def test_ml_matches_gaussian_process_regressor(with_noise):
    X, Y, rng = gp_field(150, 0.2, [2.0], nugget=0.1, seed=1)
    y = Y[:, 0]
    noise_var = rng.uniform(0.05, 0.3, size=150) if with_noise else None
    if with_noise:
        y = y + rng.normal(size=150) * np.sqrt(noise_var)
    reg = KrigingRegressor(range="auto", nugget="auto", max_ml_samples=150).fit(
        X, y, noise_var=noise_var)
    kernel = (ConstantKernel(1.0, (1e-4, 1e4)) * Matern(0.3, (1e-3, 1e2), nu=0.5)
              + WhiteKernel(0.1, (1e-8, 1e2)))
    gpr = GaussianProcessRegressor(kernel, alpha=1e-10 if noise_var is None else noise_var,
                                   n_restarts_optimizer=1, random_state=0)
    with threadpool_limits(1):  # small matrices: BLAS threads only slow GPR down
        gpr.fit(X, y - reg.mean_)
    c = gpr.kernel_.k1.k1.constant_value
    a = gpr.kernel_.k1.k2.length_scale
    w = gpr.kernel_.k2.noise_level
    assert reg.range_ == pytest.approx(a, rel=0.03)
    assert reg.sill_[0] == pytest.approx(c + w, rel=0.03)
    assert reg.nugget_ == pytest.approx(w / (c + w), rel=0.03)
    assert reg.log_likelihood_ == pytest.approx(gpr.log_marginal_likelihood_value_, rel=1e-6)
    # and GPR's log-likelihood at our parameters is ours
    ours = np.log([reg.sill_[0] * (1 - reg.nugget_), reg.range_,
                   reg.sill_[0] * reg.nugget_])
    assert gpr.log_marginal_likelihood(ours) == pytest.approx(reg.log_likelihood_, rel=1e-9)


def test_ml_recovers_range_sills_and_noise_scale():
    sills = np.array([1.0, 0.1, 0.01, 1e-3])
    X, Y, rng = gp_field(400, 0.15, sills, seed=2)
    true_noise = rng.uniform(0.5, 2.0, size=(400, 1)) * sills * 0.05
    Y_obs = Y + rng.normal(size=Y.shape) * np.sqrt(true_noise)
    # the pixel-noise estimate is twice too large: noise_scale_ should find ~0.5
    reg = KrigingRegressor(range="auto", nugget="auto", noise_scale="auto",
                           max_ml_samples=400).fit(X, Y_obs, noise_var=2.0 * true_noise)
    assert reg.range_ == pytest.approx(0.15, rel=0.25)
    np.testing.assert_allclose(reg.sill_, sills, rtol=0.35)
    assert reg.noise_scale_ == pytest.approx(0.5, rel=0.3)
    assert reg.nugget_ < 0.05
    np.testing.assert_allclose(reg.noise_var_, 2.0 * true_noise * reg.noise_scale_)


def test_ml_subset_is_seeded_and_used():
    X, Y, _ = gp_field(260, 0.2, [1.0, 0.5], seed=3)
    a = KrigingRegressor(range="auto", max_ml_samples=100, random_state=5).fit(X, Y)
    b = KrigingRegressor(range="auto", max_ml_samples=100, random_state=5).fit(X, Y)
    c = KrigingRegressor(range="auto", max_ml_samples=100, random_state=6).fit(X, Y)
    assert a.range_ == b.range_ and a.range_ != c.range_
    # the subset only sets the hyperparameters: the Kriging system has all stars, exact
    # at each of them
    assert a.dual_coef_.shape == (260, 2)
    np.testing.assert_allclose(a.predict(X), Y, atol=1e-7 * np.abs(Y).max())


def test_range_only_auto_keeps_nugget_and_fits_sill():
    X, Y, _ = gp_field(120, 0.3, [4.0], seed=4)
    reg = KrigingRegressor(range="auto", nugget=0.0, max_ml_samples=120).fit(X, Y[:, 0])
    assert reg.nugget_ == 0.0
    assert reg.range_ == pytest.approx(0.3, rel=0.5)
    assert reg.log_likelihood_ is not None
    fixed = KrigingRegressor(range=0.3).fit(X, Y[:, 0])
    assert fixed.log_likelihood_ is None
    np.testing.assert_allclose(fixed.sill_, Y[:, 0].var())  # the paper's sill


@pytest.mark.parametrize("drift", [None, "linear"])
@pytest.mark.parametrize("with_noise", [False, True])
def test_loo_predict_matches_bordered_systems_without_the_star(drift, with_noise):
    X, Y, rng = gp_field(60, 0.3, [1.0, 0.2], seed=5)
    noise_var = rng.uniform(0.01, 0.05, size=(60, 2)) if with_noise else None
    a, nug = 0.3, 0.05
    reg = KrigingRegressor(range=a, nugget=nug, drift=drift).fit(X, Y, noise_var=noise_var)
    loo, loo_std = reg.loo_predict(return_std=True)
    F = np.column_stack([np.ones(60)] + ([X] if drift else []))
    for t in range(2):
        sill = Y[:, t].var()
        nv = np.zeros(60) if noise_var is None else noise_var[:, t]
        C = (1 - nug) * np.exp(-cdist(X, X) / a) + np.diag(nug + nv / sill)
        for i in (0, 17, 59):
            k = np.arange(60) != i
            p = F.shape[1]
            A = np.block([[C[np.ix_(k, k)], F[k]], [F[k].T, np.zeros((p, p))]])
            rhs = np.concatenate([(1 - nug) * np.exp(-cdist(X[i:i + 1], X[k])[0] / a), F[i]])
            sol = np.linalg.solve(A, rhs)
            lam, mu = sol[:59], sol[59:]
            np.testing.assert_allclose(loo[i, t], lam @ Y[k, t], rtol=1e-9, atol=1e-12)
            # residual variance: the Kriging variance at the star plus its own noise
            var = sill * (1 - lam @ rhs[:59] - mu @ rhs[59:]) + nv[i]
            np.testing.assert_allclose(loo_std[i, t] ** 2, var, rtol=1e-8)


def test_loo_needs_exact_mode():
    X, Y, _ = gp_field(30, 0.3, [1.0], seed=6)
    with pytest.raises(ValueError, match="n_neighbors=None"):
        KrigingRegressor(n_neighbors=10).fit(X, Y).loo_predict()


def test_few_stars_warn_and_ml_needs_ten():
    X, Y, _ = gp_field(12, 0.3, [1.0], seed=7)
    with pytest.warns(FewStarsWarning, match="only 2 distinct stars"):
        KrigingRegressor().fit(X[:2], Y[:2])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        KrigingRegressor().fit(X[:5], Y[:5])
    with pytest.raises(ValueError, match="at least 10 samples.*maximum likelihood"):
        KrigingRegressor(range="auto").fit(X[:9], Y[:9])


def test_nan_message_names_rows_and_says_what_to_do():
    X, Y, _ = gp_field(20, 0.3, [1.0], seed=8)
    X[[3, 11], 0] = np.nan
    with pytest.raises(ValueError, match=r"NaN or inf at rows \[3, 11\].*Drop these stars") as e:
        KrigingRegressor().fit(X, Y)
    assert "HistGradientBoosting" not in str(e.value)
    X[[3, 11], 0] = 0.5
    Y[7] = np.inf
    with pytest.raises(ValueError, match=r"y \(values at the stars\) contains NaN or inf at "
                                         r"rows \[7\]"):
        KrigingRegressor().fit(X, Y)


@pytest.mark.parametrize("params, match", [
    ({"range": "big"}, "range must be a number"),
    ({"nugget": 1.5}, "nugget must be a number in"),
    ({"noise_scale": 0.0}, "noise_scale must be"),
    ({"drift": "cubic"}, "drift must be"),
    ({"max_ml_samples": 3}, "max_ml_samples"),
    ({"anisotropy_scaling": -1.0}, "anisotropy_scaling"),
])
def test_parameter_validation(params, match):
    X, Y, _ = gp_field(20, 0.3, [1.0], seed=9)
    with pytest.raises(ValueError, match=match):
        KrigingRegressor(**params).fit(X, Y)


def test_local_mode_uses_the_same_ml_hyperparameters():
    X, Y, _ = gp_field(150, 0.2, [1.0, 0.3], seed=10)
    exact = KrigingRegressor(range="auto", nugget="auto").fit(X, Y)
    local = KrigingRegressor(range="auto", nugget="auto", n_neighbors=150).fit(X, Y)
    assert local.range_ == exact.range_ and local.nugget_ == exact.nugget_
    Xq = np.random.default_rng(0).uniform(size=(20, 2))
    np.testing.assert_allclose(local.predict(Xq), exact.predict(Xq), rtol=1e-7, atol=1e-9)


def test_ml_recovers_geometric_anisotropy():
    # truth: PyKrige's frame rotated by 30 degrees, second axis stretched 3x, range 0.3
    t = np.deg2rad(30.0)
    M = np.diag([1.0, 3.0]) @ np.array([[np.cos(t), np.sin(t)], [-np.sin(t), np.cos(t)]])
    X, Y, _ = gp_field(300, 0.3, [1.0, 0.3, 0.1], seed=12, aniso=M)
    reg = KrigingRegressor(range="auto", nugget="auto", anisotropy_scaling="auto",
                           anisotropy_angle="auto", max_ml_samples=300).fit(X, Y)
    # compare the shape of the metric M^T M / a^2 (normalised to unit determinant), which
    # does not depend on the parametrisation (scaling s at angle theta is scaling 1/s at
    # theta + 90 degrees with range a s); the size trades off with the sill (for the
    # exponential model only sill / range is well determined on a bounded field)
    def shape(Q):
        return Q / np.sqrt(np.linalg.det(Q))

    Q = reg._aniso.T @ reg._aniso / reg.range_**2
    Q_true = M.T @ M / 0.3**2
    assert np.linalg.norm(shape(Q) - shape(Q_true)) / np.linalg.norm(shape(Q_true)) < 0.15
    iso = KrigingRegressor(range="auto", nugget="auto", max_ml_samples=300).fit(X, Y)
    assert reg.log_likelihood_ > iso.log_likelihood_ + 10
