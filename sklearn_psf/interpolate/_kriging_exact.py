"""Exact Kriging: factorisations, the co-Kriging system, predictions and leave-one-out
(private; the functions take a fitted :class:`KrigingRegressor` in exact mode)."""

from __future__ import annotations

import warnings

import numpy as np
from scipy.linalg import cho_solve, lapack, solve_triangular
from scipy.spatial.distance import cdist
from sklearn.exceptions import ConvergenceWarning

from ._base import _query_chunks
from ._kriging_co import _CG_MAXITER, CoupledSystem

_NAME = "KrigingRegressor"
#: exact mode with per-target noise keeps one factor per target: at most this many bytes
_MAX_FACTOR_BYTES = 4 * 2**30


def fit_exact(reg, U, Y, F, keep_covariance=False):
    """Factorisations, dual and drift coefficients of the (independent) targets; returns
    the normalised covariance of the stars when ``keep_covariance`` (else None: it is
    factorised in place)."""
    n, n_groups = U.shape[0], len(reg._group_targets)
    if n_groups > 1 and n_groups * n * n * 8 > _MAX_FACTOR_BYTES:
        raise ValueError(
            f"{_NAME}: {n} stars with noise_var need one {n} x {n} factorisation per "
            f"target ({n_groups} targets: {n_groups * n * n * 8 / 2**30:.1f} GiB). Use "
            "local Kriging (n_neighbors='auto' or 30 for instance) or fewer stars."
        )
    C0 = reg._correlation(cdist(U, U))
    np.fill_diagonal(C0, 1.0)
    reg._factors = []
    reg.dual_coef_ = np.empty_like(Y)
    reg.drift_coef_ = np.empty((F.shape[1], Y.shape[1]))
    for g, (ratio, targets) in enumerate(zip(reg._noise_ratio_groups,
                                             reg._group_targets)):
        # the last group factorises C0 in place (C0.T is the same symmetric matrix in
        # Fortran order: no copy of an n_stars^2 array without noise); the others a plain
        # copy, seen in Fortran order (no transposing copy)
        last = g == n_groups - 1 and not keep_covariance
        C = C0.T if last else C0.copy().T
        if ratio is not None:
            C[np.diag_indices_from(C)] += ratio
        # the upper triangle is zeroed (clean=1): inverses of L need no copy to clean it
        L, info = lapack.dpotrf(C, lower=1, clean=1, overwrite_a=1)
        if info != 0:
            raise ValueError(
                f"{_NAME}: the Kriging covariance matrix is not positive definite "
                "(stars almost at the same position relative to the range, or a "
                "variogram invalid in this dimension). Add a small nugget (e.g. "
                "nugget=1e-6), lower the range, or merge close stars."
            )
        L = (L, True)
        KiF = cho_solve(L, F, check_finite=False)
        FKiF_inv = np.linalg.inv(F.T @ KiF)
        beta = FKiF_inv @ (KiF.T @ Y[:, targets])
        reg.drift_coef_[:, targets] = beta
        reg.dual_coef_[:, targets] = cho_solve(L, Y[:, targets] - F @ beta,
                                               check_finite=False)
        reg._factors.append((L[0], KiF, FKiF_inv))
    reg.mean_ = reg.drift_coef_[0].copy()
    return C0 if keep_covariance else None


def fit_coupled(reg, C0, Z, F, noise_z):
    """Exact co-Kriging: dual and drift coefficients (in the targets' frame of ``y``) of
    the system with every star's full noise covariance; the independent targets' ones
    are kept for the leave-one-out predictions."""
    system = CoupledSystem(C0, reg._sill_fit, noise_z, reg._factors, reg._group_of, F)
    alpha, beta, reg.n_cg_iter_ = system.solve_gls(Z)
    if reg.n_cg_iter_ >= _CG_MAXITER:
        warnings.warn(f"{_NAME}: the co-Kriging system did not converge in {_CG_MAXITER} "
                      "conjugate-gradient iterations (noise covariances far from one "
                      "another's shape?); predictions may be inaccurate.", ConvergenceWarning,
                      stacklevel=4)
    reg._dual_independent = reg.dual_coef_
    A_inv = reg._frame[1]
    reg.dual_coef_ = (alpha * reg._sill_fit) @ A_inv
    reg.drift_coef_ = beta @ A_inv
    reg.mean_ = reg.drift_coef_[0].copy()


def predict_exact(reg, U, Fq, return_std):
    """Predictions (m, T) and normalised variances (m, n_groups) of exact Kriging."""
    m, T = U.shape[0], reg.dual_coef_.shape[1]
    pred = np.empty((m, T))
    var = np.empty((m, len(reg._factors))) if return_std else None
    for sl in _query_chunks(m, reg._U_fit.shape[0]):
        D = cdist(U[sl], reg._U_fit)
        on_star = np.flatnonzero(D.min(axis=1) == 0)
        zero = D[on_star] == 0
        c = reg._correlation(D)
        c[on_star] = np.where(zero, 1.0, c[on_star])  # variogram 0 at distance 0
        np.matmul(c, reg.dual_coef_, out=pred[sl])
        pred[sl] += Fq[sl] @ reg.drift_coef_
        if not return_std:
            continue
        for g, (L, KiF, FKiF_inv) in enumerate(reg._factors):
            u = Fq[sl] - c @ KiF
            # c^T C^-1 c = |L^-1 c|^2: a triangular solve on c.T (Fortran-contiguous;
            # overwritten in place for the last group)
            last = g == len(reg._factors) - 1
            v = solve_triangular(L, c.T, lower=True, check_finite=False,
                                 overwrite_b=last)
            q = np.einsum("ij,ij->j", v, v)
            var[sl, g] = 1.0 - q + np.einsum("ip,pq,iq->i", u, FKiF_inv, u)
            if reg._noise_ratio_groups[g] is None:
                var[sl, g][on_star] = 0.0  # exactly 0 on a star, not rounding noise
    return pred, var


def loo_exact(reg):
    """Leave-one-out predictions and residual variances of the frame's targets."""
    pdiag = np.empty_like(reg._z_fit)
    for g, (L, KiF, FKiF_inv) in enumerate(reg._factors):
        Linv, info = lapack.dtrtri(L, lower=1)  # upper triangle zero, as L's
        d = np.einsum("ij,ij->j", Linv, Linv) - np.einsum("ip,pq,iq->i", KiF, FKiF_inv,
                                                          KiF)
        pdiag[:, reg._group_targets[g]] = d[:, None]
    dual = reg.dual_coef_ if reg._frame is None else reg._dual_independent
    return reg._z_fit - dual / pdiag, reg._sill_fit / pdiag
