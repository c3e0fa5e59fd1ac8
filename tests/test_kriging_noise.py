"""Per-star measurement noise (``fit(..., noise_var=...)``) in the interpolators.

References: scikit-learn's GaussianProcessRegressor(alpha=noise_var) for Kriging, numpy's
lstsq on rows scaled by 1/sigma for the polynomials, scipy's RBFInterpolator with an
array smoothing for RBF.
"""

import numpy as np
import pytest
import sklearn
from numpy.polynomial import chebyshev
from scipy.interpolate import RBFInterpolator
from sklearn.gaussian_process import GaussianProcessRegressor
from sklearn.gaussian_process.kernels import ConstantKernel, Matern, WhiteKernel
from sklearn.model_selection import GridSearchCV, KFold, cross_validate
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import MinMaxScaler

from sklearn_psf.interpolate import (
    ChebyshevRegressor,
    DelaunayRegressor,
    DuplicateStarsWarning,
    KrigingRegressor,
    PolynomialRegressor,
    RBFRegressor,
    ShepardRegressor,
)


def field(P, seed=0, n_targets=3):
    """A smooth field: one plane wave per target, amplitudes 1 to 0.1."""
    rng = np.random.default_rng(seed + 1000)
    k = rng.normal(scale=3.0, size=(n_targets, 2))
    return np.cos(P @ k.T + rng.uniform(0, 6, n_targets)) * np.logspace(0, -1, n_targets)


def noisy_stars(n=120, n_targets=3, seed=0):
    """Field at random positions, heteroscedastic noise per star (S/N 20 to 1000)."""
    rng = np.random.default_rng(seed)
    X = rng.uniform(size=(n, 2))
    truth = field(X, seed, n_targets)
    snr = np.exp(rng.uniform(np.log(20), np.log(1000), size=(n, 1)))
    noise_var = (np.abs(truth).mean(axis=0) / snr) ** 2 * rng.uniform(0.5, 2, (n, n_targets))
    Y = truth + rng.normal(size=truth.shape) * np.sqrt(noise_var)
    Xq = rng.uniform(0.02, 0.98, size=(200, 2))
    return X, Y, noise_var, Xq


@pytest.mark.parametrize("nugget", [0.0, 0.1])
def test_kriging_noise_matches_gaussian_process_alpha(nugget):
    X, Y, noise_var, Xq = noisy_stars()
    a = 0.4
    reg = KrigingRegressor(range=a, nugget=nugget).fit(X, Y, noise_var=noise_var)
    pred, std = reg.predict(Xq, return_std=True)
    for t in range(Y.shape[1]):
        sill = Y[:, t].var()
        # ordinary Kriging = a GP with a constant mean of flat prior: a constant kernel of
        # huge variance (1e6 sills) reproduces it to ~1e-7; WhiteKernel = the nugget,
        # alpha = the per-star noise (not added at the queries, as ours)
        kernel = (ConstantKernel(sill * (1 - nugget), "fixed")
                  * Matern(length_scale=a, length_scale_bounds="fixed", nu=0.5)
                  + ConstantKernel(1e6 * sill, "fixed"))
        if nugget:
            kernel = kernel + WhiteKernel(sill * nugget, "fixed")
        gpr = GaussianProcessRegressor(kernel, alpha=noise_var[:, t], optimizer=None)
        mu, sd = gpr.fit(X, Y[:, t]).predict(Xq, return_std=True)
        np.testing.assert_allclose(pred[:, t], mu, rtol=1e-6, atol=1e-6 * np.sqrt(sill))
        # GPR's variance carries the (finite) prior variance of the mean: compare to 1e-6
        np.testing.assert_allclose(std[:, t], sd, rtol=1e-6, atol=1e-6 * np.sqrt(sill))


def test_kriging_noise_smooths_and_helps():
    X, Y, noise_var, Xq = noisy_stars(n=300, seed=3)
    noise_var = noise_var * 25  # S/N 4 to 200: the noise matters
    Y = field(X, 3) + np.random.default_rng(9).normal(size=Y.shape) * np.sqrt(noise_var)
    exact = KrigingRegressor(range=0.4).fit(X, Y)
    smooth = KrigingRegressor(range=0.4).fit(X, Y, noise_var=noise_var)
    np.testing.assert_allclose(exact.predict(X), Y, atol=1e-9)
    # no longer exact at the stars: the residual there is of the order of the noise
    r = (smooth.predict(X) - Y) / np.sqrt(noise_var)
    assert 0.2 < np.sqrt(np.mean(r**2)) < 1.5
    # against the noise-free truth at the queries, the noise-aware fit is closer
    truth = field(Xq, 3)
    err_exact = np.mean((exact.predict(Xq) - truth) ** 2, axis=0)
    err_smooth = np.mean((smooth.predict(Xq) - truth) ** 2, axis=0)
    assert np.all(err_smooth < 0.8 * err_exact)


def test_kriging_noise_shared_column_and_groups():
    X, Y, noise_var, Xq = noisy_stars()
    shared = noise_var[:, 0]
    a = KrigingRegressor(range=0.3).fit(X, Y, noise_var=shared)
    b = KrigingRegressor(range=0.3).fit(X, Y, noise_var=np.repeat(shared[:, None], 3, 1))
    np.testing.assert_allclose(a.predict(Xq), b.predict(Xq), rtol=1e-12)
    # single target = the same column of the multi-target fit
    one = KrigingRegressor(range=0.3).fit(X, Y[:, 1], noise_var=noise_var[:, 1])
    p1, s1 = one.predict(Xq, return_std=True)
    full = KrigingRegressor(range=0.3).fit(X, Y, noise_var=noise_var)
    pf, sf = full.predict(Xq, return_std=True)
    np.testing.assert_allclose(p1, pf[:, 1], rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(s1, sf[:, 1], rtol=1e-10, atol=1e-14)
    # zero noise is the noise-free fit
    z = KrigingRegressor(range=0.3).fit(X, Y, noise_var=np.zeros(len(X)))
    np.testing.assert_allclose(z.predict(Xq), KrigingRegressor(range=0.3).fit(X, Y).predict(Xq),
                               rtol=1e-10, atol=1e-12)


def test_local_kriging_noise_equals_exact_with_all_neighbours():
    X, Y, noise_var, Xq = noisy_stars(n=60)
    for drift in (None, "linear"):
        exact = KrigingRegressor(range=0.3, drift=drift).fit(X, Y, noise_var=noise_var)
        local = KrigingRegressor(range=0.3, drift=drift, n_neighbors=60).fit(
            X, Y, noise_var=noise_var)
        pe, se = exact.predict(Xq, return_std=True)
        pl, sl = local.predict(Xq, return_std=True)
        np.testing.assert_allclose(pl, pe, rtol=1e-7, atol=1e-9)
        np.testing.assert_allclose(sl, se, rtol=1e-6, atol=1e-9)


def test_duplicates_merged_by_inverse_variance():
    X, Y, noise_var, Xq = noisy_stars(n=50)
    # star 0 observed three times with different noise
    X3 = np.vstack([X, X[[0, 0]]])
    extra = Y[[0, 0]] + np.array([[0.01], [-0.02]])
    Y3 = np.vstack([Y, extra])
    nv3 = np.vstack([noise_var, noise_var[[0, 0]] * np.array([[2.0], [0.5]])])
    with pytest.warns(DuplicateStarsWarning):
        reg = KrigingRegressor(range=0.3).fit(X3, Y3, noise_var=nv3)
    w = 1.0 / nv3[[0, 50, 51]]
    merged = (w * Y3[[0, 50, 51]]).sum(axis=0) / w.sum(axis=0)
    np.testing.assert_allclose(reg.y_fit_[0], merged, rtol=1e-12)
    np.testing.assert_allclose(reg.noise_var_[0], 1.0 / w.sum(axis=0), rtol=1e-12)
    # merging is exact for Kriging: a GP on the unmerged stars (three measurements of one
    # field value), with the merged fit's sills, predicts the same
    for t in range(3):
        kernel = (ConstantKernel(reg.sill_[t], "fixed")
                  * Matern(length_scale=0.3, length_scale_bounds="fixed", nu=0.5)
                  + ConstantKernel(1e6 * reg.sill_[t], "fixed"))
        gpr = GaussianProcessRegressor(kernel, alpha=nv3[:, t], optimizer=None)
        # (the huge constant kernel limits GPR's precision to ~1e-6 of the sill)
        np.testing.assert_allclose(reg.predict(Xq)[:, t], gpr.fit(X3, Y3[:, t]).predict(Xq),
                                   rtol=1e-5, atol=1e-5 * np.sqrt(reg.sill_[t]))
    # a star of zero noise among duplicates takes all the weight
    nv3[50] = 0.0
    with pytest.warns(DuplicateStarsWarning):
        reg = KrigingRegressor(range=0.3).fit(X3, Y3, noise_var=nv3)
    np.testing.assert_allclose(reg.y_fit_[0], Y3[50])
    assert np.all(reg.noise_var_[0] == 0)


@pytest.mark.parametrize("est", [KrigingRegressor(), PolynomialRegressor(degree=2),
                                 ChebyshevRegressor(degree=2), RBFRegressor()])
def test_noise_var_validation(est):
    X, Y, noise_var, _ = noisy_stars(n=30)
    with pytest.raises(ValueError, match=r"shape \(30,\) or \(30, 3\)"):
        est.fit(X, Y, noise_var=noise_var[:10])
    bad = noise_var.copy()
    bad[4, 1] = np.nan
    with pytest.raises(ValueError, match=r"rows \[4\]"):
        est.fit(X, Y, noise_var=bad)
    bad[4, 1] = -1.0
    with pytest.raises(ValueError, match=r"rows \[4\]"):
        est.fit(X, Y, noise_var=bad)
    with pytest.raises(TypeError, match="array of numbers"):
        est.fit(X, Y, noise_var="large")
    before = noise_var.copy()
    est.fit(X, Y, noise_var=noise_var)
    np.testing.assert_array_equal(noise_var, before)  # not modified in place


def test_polynomials_need_positive_noise():
    X, Y, noise_var, _ = noisy_stars(n=30)
    noise_var[3] = 0.0
    with pytest.raises(ValueError, match="> 0"):
        PolynomialRegressor(degree=2).fit(X, Y, noise_var=noise_var)


def test_shepard_and_delaunay_take_no_noise():
    import inspect

    for est in (ShepardRegressor, DelaunayRegressor):
        assert "noise_var" not in inspect.signature(est.fit).parameters
    for est in (KrigingRegressor, PolynomialRegressor, ChebyshevRegressor, RBFRegressor):
        assert "noise_var" in inspect.signature(est.fit).parameters


@pytest.mark.parametrize("cls", [PolynomialRegressor, ChebyshevRegressor])
def test_polynomial_weighted_least_squares(cls):
    X, Y, noise_var, Xq = noisy_stars(n=80)
    reg = cls(degree=3).fit(X, Y, noise_var=noise_var)
    # numpy reference in raw coordinates: rows scaled by 1/sigma, one solve per target
    powers = [(i, j) for i in range(4) for j in range(4 - i)]

    def design(P):
        if cls is PolynomialRegressor:
            return np.column_stack([P[:, 0] ** i * P[:, 1] ** j for i, j in powers])
        U = (P - reg.center_) / reg.half_width_
        return np.column_stack([chebyshev.chebval(U[:, 0], np.eye(4)[i])
                                * chebyshev.chebval(U[:, 1], np.eye(4)[j]) for i, j in powers])

    A, Aq = design(X), design(Xq)
    for t in range(3):
        s = 1.0 / np.sqrt(noise_var[:, t])
        coef = np.linalg.lstsq(A * s[:, None], Y[:, t] * s, rcond=None)[0]
        np.testing.assert_allclose(reg.predict(Xq)[:, t], Aq @ coef, rtol=1e-8, atol=1e-10)
    # a (n,) noise_var is one weight per star for every target
    one = cls(degree=3).fit(X, Y, noise_var=noise_var[:, 0])
    s = 1.0 / np.sqrt(noise_var[:, 0])
    coef = np.linalg.lstsq(A * s[:, None], Y * s[:, None], rcond=None)[0]
    np.testing.assert_allclose(one.predict(Xq), Aq @ coef, rtol=1e-8, atol=1e-10)


def test_polynomial_auto_degree_with_noise_runs_weighted():
    X, Y, noise_var, _ = noisy_stars(n=200)
    reg = PolynomialRegressor(degree="auto", max_degree=6).fit(X, Y, noise_var=noise_var)
    assert 2 <= reg.degree_ <= 6


def test_rbf_noise_is_per_star_smoothing():
    X, Y, noise_var, Xq = noisy_stars(n=80)
    reg = RBFRegressor(kernel="gaussian", epsilon=2.0, smoothing=1e-3).fit(
        X, Y, noise_var=noise_var)
    for t in range(3):
        ref = RBFInterpolator(X, Y[:, t], kernel="gaussian", epsilon=2.0,
                              smoothing=1e-3 + noise_var[:, t] / Y[:, t].var())
        np.testing.assert_allclose(reg.predict(Xq)[:, t], ref(Xq), rtol=1e-8, atol=1e-10)


# ------------------------------------------------------------------ metadata routing
def test_noise_var_routed_by_cross_validate_and_grid_search():
    X, Y, noise_var, _ = noisy_stars(n=90)
    cv = KFold(3, shuffle=True, random_state=0)
    with sklearn.config_context(enable_metadata_routing=True):
        reg = KrigingRegressor(range=0.3).set_fit_request(noise_var=True)
        routed = cross_validate(reg, X, Y, cv=cv, params={"noise_var": noise_var})
        search = GridSearchCV(reg, {"range": [0.2, 0.5]}, cv=cv).fit(
            X, Y, noise_var=noise_var)
    # the same folds by hand, with each training fold's noise
    manual = []
    for train, test in cv.split(X):
        fit = KrigingRegressor(range=0.3).fit(X[train], Y[train], noise_var=noise_var[train])
        manual.append(fit.score(X[test], Y[test]))
    np.testing.assert_allclose(routed["test_score"], manual, rtol=1e-12)
    unrouted = cross_validate(KrigingRegressor(range=0.3), X, Y, cv=cv)
    assert not np.allclose(routed["test_score"], unrouted["test_score"])
    best = search.best_estimator_
    assert best.noise_var_ is not None and best.noise_var_.shape == Y.shape


def test_pipeline_passes_noise_var_without_routing():
    X, Y, noise_var, Xq = noisy_stars(n=60)
    pipe = make_pipeline(MinMaxScaler(), KrigingRegressor())
    pipe.fit(X, Y, krigingregressor__noise_var=noise_var)
    U = MinMaxScaler().fit(X)
    ref = KrigingRegressor().fit(U.transform(X), Y, noise_var=noise_var)
    np.testing.assert_allclose(pipe.predict(Xq), ref.predict(U.transform(Xq)), rtol=1e-12)


@pytest.mark.parametrize("cls", [PolynomialRegressor, ChebyshevRegressor])
def test_default_degree_is_lowered_for_few_stars(cls):
    from sklearn_psf.interpolate import RankDeficientWarning

    X, Y, _, Xq = noisy_stars(n=12)
    with pytest.warns(RankDeficientWarning, match="lowered to 3"):
        reg = cls().fit(X, Y)  # degree 5: 21 terms > 12 stars; degree 3: 10 terms
    assert reg.degree_ == 3
    np.testing.assert_allclose(reg.predict(Xq), cls(degree=3).fit(X, Y).predict(Xq),
                               rtol=1e-12, atol=1e-12)


def test_exact_mode_with_per_target_noise_refuses_huge_memory(monkeypatch):
    import sklearn_psf.interpolate._kriging_exact as kriging_exact

    X, Y, noise_var, _ = noisy_stars(n=100)
    monkeypatch.setattr(kriging_exact, "_MAX_FACTOR_BYTES", 3 * 100 * 100 * 8 - 1)
    with pytest.raises(ValueError, match="one 100 x 100 factorisation per target.*n_neighbors"):
        KrigingRegressor().fit(X, Y, noise_var=noise_var)
    KrigingRegressor(n_neighbors=30).fit(X, Y, noise_var=noise_var)  # local mode is fine
    KrigingRegressor().fit(X, Y)  # one factorisation without noise
