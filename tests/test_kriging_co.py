"""Co-Kriging with each star's noise covariance across targets (KrigingRegressor noise_cov).

Reference: the dense multi-output Gaussian process written out here: the covariance of all
n x T values, ``kron(B, C0) + blockdiag(Sigma_i)`` (target-major order), solved with numpy,
with a generalised-least-squares mean per target.
"""

import numpy as np
import pytest
from scipy.spatial.distance import cdist

from sklearn_psf.interpolate import KrigingRegressor


def icm_field(n, a, B, seed, proportional=False, n_query=0):
    """Stars with an intrinsic-coregionalisation signal (covariance B, exponential
    correlation of range a) plus correlated noise, each star's own covariance; and
    ``n_query`` query positions with the signal there."""
    rng = np.random.default_rng(seed)
    T = B.shape[0]
    P = rng.uniform(size=(n + n_query, 2))
    C0 = np.exp(-cdist(P, P) / a)
    G = np.linalg.cholesky(C0 + 1e-12 * np.eye(len(P))) @ rng.normal(size=(len(P), T))
    S = 1.0 + G @ np.linalg.cholesky(B).T
    X, Y = P[:n], S[:n]
    base = np.array([[1.0, 0.8, 0.3], [0.8, 1.0, 0.2], [0.3, 0.2, 0.5]])[:T, :T] * 0.05
    scale = rng.uniform(0.3, 3.0, size=n)
    cov = scale[:, None, None] * base
    if not proportional:  # each star's correlations differ too (a common flux error)
        c = rng.normal(size=(n, T)) * 0.15
        cov = cov + 0.05 * scale[:, None, None] * c[:, :, None] * c[:, None, :]
    noise = np.einsum("itu,iu->it", np.linalg.cholesky(cov), rng.normal(size=(n, T)))
    return X, Y + noise, cov, rng, (P[n:], S[n:])


def dense(reg, X, Y, cov, Xq):
    """Dense multi-output BLUP (predictions, std) and log-likelihood with reg's model."""
    n, T = Y.shape
    B, a, nug = reg.coregionalization_, reg.range_, reg.nugget_
    C0 = (1 - nug) * np.exp(-cdist(X, X) / a) + nug * np.eye(n)
    K = np.kron(B, C0)
    for i in range(n):
        idx = np.arange(T) * n + i
        K[np.ix_(idx, idx)] += reg.noise_scale_ * cov[i]
    F = np.kron(np.eye(T), np.ones((n, 1)))
    y = Y.T.reshape(-1)
    Ki = np.linalg.inv(K)
    beta = np.linalg.solve(F.T @ Ki @ F, F.T @ Ki @ y)
    r = y - F @ beta
    c = (1 - nug) * np.exp(-cdist(Xq, X) / a)
    k = np.kron(B, c)  # (T m, T n)
    m = len(Xq)
    pred = (np.kron(np.eye(T), np.ones((m, 1))) @ beta + k @ Ki @ r).reshape(T, m).T
    # Kriging variance with the GLS mean's uncertainty (universal Kriging form)
    Fq = np.kron(np.eye(T), np.ones((m, 1)))
    u = Fq - k @ Ki @ F
    var = (np.diag(np.kron(B, np.ones((m, m)))) - np.einsum("ij,jk,ik->i", k, Ki, k)
           + np.einsum("ij,jk,ik->i", u, np.linalg.inv(F.T @ Ki @ F), u))
    _, logdet = np.linalg.slogdet(K)
    loglik = -0.5 * (r @ Ki @ r + logdet + n * T * np.log(2 * np.pi))
    return pred, np.sqrt(var.reshape(T, m).T), loglik


@pytest.mark.parametrize("proportional", [True, False])
def test_cokriging_equals_the_dense_multi_output_gp(proportional):
    B = np.array([[1.0, 0.6, 0.2], [0.6, 0.5, 0.1], [0.2, 0.1, 0.2]])
    X, Y, cov, rng, _ = icm_field(80, 0.3, B, seed=1, proportional=proportional)
    reg = KrigingRegressor(range=0.3).fit(X, Y, noise_cov=cov)
    Xq = rng.uniform(size=(50, 2))
    pred, std = reg.predict(Xq, return_std=True)
    ref, ref_std, _ = dense(reg, X, Y, cov, Xq)
    np.testing.assert_allclose(pred, ref, rtol=0, atol=1e-9 * np.ptp(Y))
    assert reg.n_cg_iter_ < (5 if proportional else 30)
    # the paper's convention without maximum likelihood: B is the targets' covariance
    np.testing.assert_allclose(reg.coregionalization_, np.cov(Y, rowvar=False, bias=True),
                               rtol=1e-10)
    np.testing.assert_allclose(reg.sill_, Y.var(axis=0), rtol=1e-10)
    if proportional:  # the frame's targets are then exactly independent: exact std
        np.testing.assert_allclose(std, ref_std, rtol=1e-8)
    else:  # from the frame's independent targets: close
        np.testing.assert_allclose(std, ref_std, rtol=0.05)


def test_cokriging_maximum_likelihood_and_its_log_likelihood():
    B = np.array([[1.0, 0.6, 0.2], [0.6, 0.5, 0.1], [0.2, 0.1, 0.2]])
    X, Y, cov, rng, _ = icm_field(150, 0.2, B, seed=2, proportional=True)
    reg = KrigingRegressor(range="auto", nugget="auto", noise_scale="auto").fit(
        X, Y, noise_cov=cov)
    Xq = rng.uniform(size=(40, 2))
    ref, _, loglik = dense(reg, X, Y, cov, Xq)
    np.testing.assert_allclose(reg.predict(Xq), ref, rtol=0, atol=1e-9 * np.ptp(Y))
    # proportional noise: the frame's independent likelihoods are the full model's
    assert reg.log_likelihood_ == pytest.approx(loglik, rel=1e-9)
    # 150 stars: the range is loosely determined (0.118 measured for 0.2 with the nugget
    # and noise scale free), the signal covariance better
    assert reg.range_ == pytest.approx(0.2, rel=0.5)
    np.testing.assert_allclose(reg.coregionalization_, B, atol=0.25)
    np.testing.assert_allclose(reg.noise_cov_, cov * reg.noise_scale_)
    np.testing.assert_allclose(reg.noise_var_, np.einsum("itt->it", reg.noise_cov_))


def test_cokriging_leave_one_out_matches_refits_without_the_star():
    B = np.array([[1.0, 0.5], [0.5, 0.6]])
    X, Y, cov, _, _ = icm_field(50, 0.3, B, seed=3, proportional=True)
    reg = KrigingRegressor(range=0.3).fit(X, Y, noise_cov=cov)
    loo, loo_std = reg.loo_predict(return_std=True)
    for i in (0, 21, 49):
        keep = np.arange(50) != i
        sub = KrigingRegressor(range=0.3).fit(X[keep], Y[keep], noise_cov=cov[keep])
        # same hyperparameters as the full fit (its B), dense solve without star i
        sub.coregionalization_ = reg.coregionalization_
        ref, ref_std, _ = dense(sub, X[keep], Y[keep], cov[keep], X[i:i + 1])
        np.testing.assert_allclose(loo[i], ref[0], rtol=1e-7, atol=1e-9)
        np.testing.assert_allclose(loo_std[i] ** 2, ref_std[0] ** 2 + np.diag(cov[i]),
                                   rtol=1e-7)


def test_cokriging_beats_independent_kriging_with_correlated_noise():
    # noise correlated up to 0.8 between the targets: co-Kriging uses it, independent
    # Kriging with the same variances cannot; error against the true signal at queries
    B = np.diag([1.0, 0.5, 0.2]) * 0.1
    co_err, ind_err = [], []
    for seed in range(5):
        X, Y, cov, _, (Xq, truth) = icm_field(300, 0.15, B, seed=10 + seed, n_query=300)
        co = KrigingRegressor(range="auto").fit(X, Y, noise_cov=cov)
        ind = KrigingRegressor(range="auto").fit(X, Y, noise_var=np.einsum("itt->it", cov))
        co_err.append(np.mean((co.predict(Xq) - truth) ** 2))
        ind_err.append(np.mean((ind.predict(Xq) - truth) ** 2))
    co_err, ind_err = np.array(co_err), np.array(ind_err)
    assert np.all(co_err < ind_err) and np.mean(co_err / ind_err) < 0.97


def test_noise_cov_validation():
    X, Y, cov, _, _ = icm_field(20, 0.3, np.eye(2), seed=4)
    with pytest.raises(ValueError, match="not both"):
        KrigingRegressor().fit(X, Y, noise_var=np.ones(20), noise_cov=cov)
    with pytest.raises(ValueError, match=r"shape \(20, 2, 2\)"):
        KrigingRegressor().fit(X, Y, noise_cov=cov[:, :1, :1])
    bad = cov.copy()
    bad[3] = [[1.0, 2.0], [2.0, 1.0]]  # not positive semi-definite
    bad[5, 0, 1] = np.nan
    with pytest.raises(ValueError, match=r"rows \[3, 5\]"):
        KrigingRegressor().fit(X, Y, noise_cov=bad)
    given = cov.copy()
    KrigingRegressor().fit(X, Y, noise_cov=given)
    np.testing.assert_array_equal(given, cov)  # not modified


def test_duplicated_stars_merge_with_their_covariances():
    from sklearn_psf.interpolate import DuplicateStarsWarning

    X, Y, cov, _, _ = icm_field(30, 0.3, np.eye(2), seed=5)
    X2, Y2 = np.vstack([X, X[:2]]), np.vstack([Y, Y[:2] + 0.1])
    cov2 = np.concatenate([cov, 3 * cov[:2]])
    with pytest.warns(DuplicateStarsWarning):
        reg = KrigingRegressor(range=0.3).fit(X2, Y2, noise_cov=cov2)
    # inverse-covariance weights 3:1 between the two measurements of a position
    np.testing.assert_allclose(reg.y_fit_[:2], Y[:2] + 0.025, rtol=1e-10)
    np.testing.assert_allclose(reg.noise_cov_[:2], 0.75 * cov[:2], rtol=1e-10)
    # without noise: the plain mean
    with pytest.warns(DuplicateStarsWarning):
        exact = KrigingRegressor(range=0.3).fit(X2, Y2, noise_cov=np.zeros_like(cov2))
    np.testing.assert_allclose(exact.y_fit_[:2], Y[:2] + 0.05, rtol=1e-10)
