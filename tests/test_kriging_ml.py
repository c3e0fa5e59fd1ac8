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
from scipy.optimize import minimize
from scipy.spatial.distance import cdist
from sklearn.gaussian_process import GaussianProcessRegressor
from sklearn.gaussian_process.kernels import ConstantKernel, Matern, WhiteKernel
from threadpoolctl import threadpool_limits

from sklearn_psf.interpolate import FewStarsWarning, KrigingRegressor, ShortRangeWarning
from sklearn_psf.interpolate._kriging_ml import _Likelihood, _VecchiaLikelihood


def gp_field(n, a, sills, nugget=0.0, seed=0, aniso=None):
    """Stars at random positions; a Gaussian field of exponential covariance, range a."""
    rng = np.random.default_rng(seed)
    X = rng.uniform(size=(n, 2))
    U = X if aniso is None else X @ aniso.T
    C = np.exp(-cdist(U, U) / a) * (1 - nugget) + nugget * np.eye(n)
    L = np.linalg.cholesky(C + 1e-12 * np.eye(n))
    Y = (L @ rng.normal(size=(n, len(sills)))) * np.sqrt(sills) + 3.0
    return X, Y, rng


def _tight(obj_func, initial_theta, bounds):
    """GPR's optimiser run to convergence (its default stops at a gradient of ~1e-5)."""
    res = minimize(obj_func, initial_theta, jac=True, method="L-BFGS-B", bounds=bounds,
                   options={"ftol": 1e-15, "gtol": 1e-9, "maxiter": 2000})
    return res.x, res.fun


def gpr_reference(X, y, noise_var, nugget, theta=None):
    """GaussianProcessRegressor with our exponential model, fitted to convergence."""
    kernel = ConstantKernel(1.0, (1e-4, 1e4)) * Matern(0.3, (1e-3, 1e2), nu=0.5)
    if nugget:
        kernel = kernel + WhiteKernel(0.1, (1e-8, 1e2))
    gpr = GaussianProcessRegressor(kernel, alpha=1e-10 if noise_var is None else noise_var,
                                   optimizer=_tight, random_state=0)
    if theta is not None:
        gpr.kernel = gpr.kernel.clone_with_theta(theta)
    with threadpool_limits(1):  # small matrices: BLAS threads only slow GPR down
        return gpr.fit(X, y)


@pytest.mark.parametrize("with_noise, nugget", [(False, True), (True, True), (True, False)])
def test_ml_on_all_stars_equals_gaussian_process_regressor(with_noise, nugget):
    # 400 stars, maximum likelihood on all of them: hyperparameters, log-likelihood and
    # predictions equal GPR's (fitted to convergence) to 1e-6
    n = 400
    X, Y, rng = gp_field(n, 0.2, [2.0], nugget=0.1 if nugget else 0.0, seed=1)
    y = Y[:, 0]
    noise_var = rng.uniform(0.05, 0.3, size=n) if with_noise else None
    if with_noise:
        y = y + rng.normal(size=n) * np.sqrt(noise_var)
    reg = KrigingRegressor(range="auto", nugget="auto" if nugget else 0.0).fit(
        X, y, noise_var=noise_var)
    assert reg.likelihood_ == "exact"
    ours = [reg.sill_[0] * (1 - reg.nugget_), reg.range_]
    if nugget:
        ours.append(reg.sill_[0] * reg.nugget_)
    gpr = gpr_reference(X, y - reg.mean_, noise_var, nugget,
                        theta=np.log(ours) + 0.3)  # start away from our optimum
    np.testing.assert_allclose(np.exp(gpr.kernel_.theta), ours, rtol=1e-6)
    assert reg.log_likelihood_ == pytest.approx(gpr.log_marginal_likelihood_value_, rel=1e-9)
    # GPR's log-likelihood at our parameters is ours
    assert gpr.log_marginal_likelihood(np.log(ours)) == pytest.approx(reg.log_likelihood_,
                                                                      rel=1e-10)
    Xq = np.random.default_rng(5).uniform(size=(200, 2))
    pred, std = reg.predict(Xq, return_std=True)
    gpred, gstd = gpr.predict(Xq, return_std=True)
    scale = np.abs(y - reg.mean_).max()
    np.testing.assert_allclose(pred, gpred + reg.mean_, rtol=0, atol=1e-6 * scale)
    if not nugget:  # GPR's std includes the white kernel (our nugget is part of the field)
        # GPR assumes a known mean: our variance adds the GLS mean's own uncertainty
        assert np.all(std >= gstd - 1e-9) and np.median(std / gstd) < 1.05


def test_vecchia_likelihood_is_close_to_the_exact_one():
    # same data, exact and Vecchia (15 neighbours): hyperparameters within a few percent
    # (far inside their statistical error), predictions of the final (exact) system close
    X, Y, rng = gp_field(500, 0.2, [1.0, 0.2, 0.05], seed=13)
    noise = rng.uniform(0.5, 2.0, size=(500, 1)) * np.array([0.05, 0.01, 0.005])
    Y = Y + rng.normal(size=Y.shape) * np.sqrt(noise)
    exact = KrigingRegressor(range="auto", likelihood="exact").fit(X, Y, noise_var=noise)
    vecchia = KrigingRegressor(range="auto", likelihood=15).fit(X, Y, noise_var=noise)
    assert (exact.likelihood_, vecchia.likelihood_) == ("exact", "vecchia")
    assert vecchia.range_ == pytest.approx(exact.range_, rel=0.05)
    np.testing.assert_allclose(vecchia.sill_, exact.sill_, rtol=0.05)
    # log-likelihoods within 0.005 per value (measured 0.0016)
    assert abs(vecchia.log_likelihood_ - exact.log_likelihood_) < 0.005 * Y.size
    Xq = np.random.default_rng(0).uniform(size=(300, 2))
    diff = vecchia.predict(Xq) - exact.predict(Xq)
    assert np.all(np.sqrt((diff**2).mean(axis=0)) < 0.02 * np.sqrt(exact.sill_))


@pytest.mark.parametrize("drift", [None, "linear"])
def test_vecchia_with_all_earlier_stars_is_the_exact_likelihood(drift):
    # with as many neighbours as stars, Vecchia's likelihood and its gradient (range,
    # sills, nugget, noise scale) are the exact ones
    X, Y, rng = gp_field(60, 0.2, [1.0, 0.2], nugget=0.05, seed=15)
    noise = rng.uniform(0.01, 0.05, size=(60, 2))
    F = np.column_stack([np.ones(60)] + ([X] if drift else []))
    free, fixed = ["range", "nu", "kappa"], {"scaling": 1.0, "angle": 0.0}
    exact = _Likelihood(X, Y, F, noise, "exponential", free, fixed)
    vecchia = _VecchiaLikelihood(X, Y, F, noise, "exponential", free, fixed, 59, seed=3)
    for theta in ([np.log(0.2), np.log(0.05), 0.0, 0.0, np.log(0.2)],
                  [np.log(0.5), np.log(0.3), 0.4, -0.5, 0.1]):
        f_e, g_e = exact(np.array(theta))
        f_v, g_v = vecchia(np.array(theta))
        assert f_v == pytest.approx(f_e, rel=1e-10)
        np.testing.assert_allclose(g_v, g_e, rtol=1e-7, atol=1e-9 * np.abs(g_e).max())


def test_auto_likelihood_is_exact_where_cheap():
    X, Y, rng = gp_field(450, 0.2, [1.0, 0.5], seed=14)
    cheap = KrigingRegressor(range="auto").fit(X[:350], Y[:350], noise_var=np.full(350, 0.01))
    assert cheap.likelihood_ == "exact"  # 2 factorisations of 350 stars per step
    # 2 of 450: 1.8e8 > 1e8
    assert KrigingRegressor(range="auto").fit(
        X, Y, noise_var=np.full(450, 0.01)).likelihood_ == "vecchia"
    costly = KrigingRegressor(range="auto").fit(
        np.vstack([X, X + 1e-3])[:800], np.vstack([Y, Y])[:800],
        noise_var=rng.uniform(0.01, 0.02, size=(800, 2)))
    assert costly.likelihood_ == "vecchia"


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


def test_local_loo_predict_matches_bordered_systems_of_the_nearest_other_stars():
    X, Y, rng = gp_field(80, 0.3, [1.0, 0.2], seed=6)
    noise_var = rng.uniform(0.01, 0.05, size=(80, 2))
    a, nug, k = 0.3, 0.05, 10
    reg = KrigingRegressor(range=a, nugget=nug, n_neighbors=k).fit(X, Y, noise_var=noise_var)
    loo, loo_std = reg.loo_predict(return_std=True)
    for t in range(2):
        sill = Y[:, t].var()
        for i in (0, 33, 79):
            d = np.linalg.norm(X - X[i], axis=1)
            d[i] = np.inf
            near = np.argsort(d)[:k]
            C = (1 - nug) * np.exp(-cdist(X[near], X[near]) / a) + np.diag(
                nug + noise_var[near, t] / sill)
            A = np.block([[C, np.ones((k, 1))], [np.ones((1, k)), np.zeros((1, 1))]])
            rhs = np.append((1 - nug) * np.exp(-d[near] / a), 1.0)
            sol = np.linalg.solve(A, rhs)
            np.testing.assert_allclose(loo[i, t], sol[:k] @ Y[near, t], rtol=1e-9)
            var = sill * (1 - sol @ rhs) + noise_var[i, t]
            np.testing.assert_allclose(loo_std[i, t] ** 2, var, rtol=1e-8)
    # as many neighbours as stars: exact Kriging (the same system), exact leave-one-out
    small = KrigingRegressor(range=a, n_neighbors=10).fit(X[:10], Y[:10])
    assert small.n_neighbors_ is None
    np.testing.assert_allclose(small.loo_predict(),
                               KrigingRegressor(range=a).fit(X[:10], Y[:10]).loo_predict())


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


@pytest.mark.parametrize("params, match", [  # scikit-learn's "The 'p' parameter of ..."
    ({"range": "big"}, "'range' parameter of KrigingRegressor must be"),
    ({"nugget": 1.5}, r"'nugget' parameter .* in the range \[0.0, 1.0\]"),
    ({"noise_scale": 0.0}, "'noise_scale' parameter .* must be"),
    ({"range": True}, "range must be a number"),  # the regressor's own: no boolean
    ({"drift": "cubic"}, "'drift' parameter .* must be"),
    ({"max_ml_samples": 3}, "max_ml_samples"),
    ({"likelihood": "vecchia"}, "'likelihood' parameter .* must be"),
    ({"likelihood": 0}, "'likelihood' parameter .* must be"),
    ({"likelihood": 10, "anisotropy_angle": "auto"}, "needs a fixed anisotropy"),
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


def test_no_spatial_correlation_gives_a_smooth_field_not_spots():
    # 100 stars whose values are spatially white (a real chip whose PSF does not vary at
    # the stars' spacing): the range stops at the stars' spacing, the nugget takes the white
    # variance, and a map of the field is smooth (close to the mean), not spots at the stars
    rng = np.random.default_rng(0)
    X = rng.uniform(size=(100, 2))
    Y = rng.normal(size=(100, 3)) * [1.0, 0.5, 0.2]
    noise = np.full((100, 3), 0.01)
    with pytest.warns(ShortRangeWarning, match="no spatial correlation"):
        reg = KrigingRegressor(range="auto").fit(X, Y, noise_var=noise)
    nearest = np.sort(cdist(X, X), axis=1)[:, 1]
    assert reg.range_floor_ == pytest.approx(np.median(nearest), rel=1e-12)
    assert reg.range_at_floor_ and reg.range_ >= reg.range_floor_
    assert reg.nugget_ > 0.9
    grid = np.stack(np.meshgrid(*[np.linspace(0, 1, 60)] * 2), -1).reshape(-1, 2)
    # measured 0.0005 of the values' spread; a range collapsed below the spacing gave a
    # constant with a spot of the star's value around each star
    assert np.all(reg.predict(grid).std(axis=0) < 0.01 * Y.std(axis=0))


def test_correlated_field_keeps_its_range_without_warning():
    X, Y, rng = gp_field(150, 0.2, [1.0, 0.3], seed=16)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        reg = KrigingRegressor(range="auto").fit(X, Y, noise_var=np.full(150, 1e-3))
    assert not reg.range_at_floor_ and reg.range_ > 2 * reg.range_floor_
    assert reg.nugget_ == 0.0
    fixed = KrigingRegressor(range=0.3).fit(X, Y)
    assert fixed.range_floor_ is None and not fixed.range_at_floor_


@pytest.mark.parametrize("likelihood", ["exact", 10])
def test_warm_start_refit_reaches_the_cold_optimum(likelihood):
    # an outlier round's refit: the same stars but a few; from the previous fit's
    # hyperparameters it reaches the optimum a fit from the grid reaches (the exact
    # likelihood to its 1e-8-per-star gradient; Vecchia's to a tenth of the parameters'
    # standard error), and keeps the drift chosen before
    X, Y, _ = gp_field(260, 0.25, [1.0, 0.3], nugget=0.05, seed=4)
    noise = np.full(Y.shape, 2e-3)
    keep = np.ones(len(X), dtype=bool)
    keep[::40] = False
    params = {"range": "auto", "nugget": "auto", "drift": "auto", "likelihood": likelihood}
    warm = KrigingRegressor(**params, warm_start=True).fit(X, Y, noise_var=noise)
    first_drift = warm.drift_
    warm.fit(X[keep], Y[keep], noise_var=noise[keep])
    cold = KrigingRegressor(**params).fit(X[keep], Y[keep], noise_var=noise[keep])
    assert warm.drift_ == first_drift == cold.drift_
    rel = 1e-5 if likelihood == "exact" else 0.1
    assert warm.range_ == pytest.approx(cold.range_, rel=rel)
    assert warm.nugget_ == pytest.approx(cold.nugget_, rel=rel, abs=1e-3)
    np.testing.assert_allclose(warm.sill_, cold.sill_, rtol=rel)
    assert warm.log_likelihood_ == pytest.approx(cold.log_likelihood_, abs=0.05)
    # without warm_start, the refit starts from the grid again: the cold fit exactly
    again = KrigingRegressor(**params).fit(X, Y, noise_var=noise)
    again.fit(X[keep], Y[keep], noise_var=noise[keep])
    assert again.range_ == cold.range_
    # what the warm fit started from (a model file stores it) is the first fit's optimum
    assert warm._start_state()["drift"] == first_drift and again._start_state() is None
