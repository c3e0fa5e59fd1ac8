"""Exact Kriging: factorisations, the co-Kriging system, predictions and leave-one-out
(private). :func:`fit_exact` and :func:`fit_coupled` take the stars and the model and return
an :class:`ExactSolve`, which :func:`predict_exact` and :func:`loo_exact` take with the stars;
none reads or sets a regressor's attributes."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
from scipy.linalg import cho_solve, lapack, solve_triangular
from scipy.spatial.distance import cdist
from sklearn.exceptions import ConvergenceWarning

from ._base import _query_chunks
from ._kriging_co import _CG_MAXITER, CoupledSystem
from ._variogram import _CORRELATIONS

_NAME = "KrigingRegressor"
#: exact mode with per-target noise keeps one factor per target: at most this many bytes
_MAX_FACTOR_BYTES = 4 * 2**30


def correlation(D, variogram, range_, nugget):
    """``(1 - nugget) rho(D / range_)``, overwriting ``D`` (a fresh distance matrix)."""
    D *= 1.0 / range_
    c = _CORRELATIONS[variogram](D)
    if nugget:
        c *= 1.0 - nugget
    return c


@dataclasses.dataclass(frozen=True)
class NoiseGroups:
    """The targets grouped by their normalised covariance (equal noise-to-sill ratios).

    ``ratios``: each group's noise-to-sill ratio of the stars, (n_stars,), or ``[None]``
    without noise; ``targets``: each group's target indices; ``of`` (n_targets,): the group
    of each target.
    """

    ratios: list
    targets: list
    of: np.ndarray


def noise_groups(noise, sill, n_targets):
    """:class:`NoiseGroups` of ``noise`` (n_stars, n_targets) or None and ``sill``."""
    if noise is None:
        return NoiseGroups([None], [np.arange(n_targets)], np.zeros(n_targets, dtype=int))
    sill = np.where(sill > 0, sill, np.inf)  # constant: exact
    ratio = noise / sill
    unique, inverse = np.unique(ratio.T, axis=0, return_inverse=True)
    of = inverse.reshape(-1)
    return NoiseGroups(list(unique), [np.flatnonzero(of == g) for g in range(len(unique))], of)


@dataclasses.dataclass(frozen=True)
class ExactSolve:
    """The solved exact Kriging system.

    ``factors``: per group of targets, ``(L, C^-1 F, (F^T C^-1 F)^-1)`` with ``L`` the lower
    Cholesky factor of the group's normalised covariance ``C``; ``dual_coef`` (n, T) and
    ``drift_coef`` (q, T) the dual and generalised-least-squares drift coefficients. After
    :func:`fit_coupled` (co-Kriging) those are the targets' of ``y``, ``dual_independent``
    the independent targets' dual coefficients (leave-one-out) and ``n_cg_iter`` the
    conjugate-gradient iterations; both None otherwise.
    """

    factors: list
    dual_coef: np.ndarray
    drift_coef: np.ndarray
    dual_independent: np.ndarray | None = None
    n_cg_iter: int | None = None


def fit_exact(U, Y, F, corr, groups, keep_covariance=False):
    """The :class:`ExactSolve` of the (independent) targets ``Y`` (n, T) at the transformed
    positions ``U`` with drift design ``F``, ``corr(D)`` the normalised correlation of
    distances ``D`` and ``groups`` the :class:`NoiseGroups`; and the normalised covariance of
    the stars when ``keep_covariance`` (else None: it is factorised in place)."""
    n, n_groups = U.shape[0], len(groups.targets)
    if n_groups > 1 and n_groups * n * n * 8 > _MAX_FACTOR_BYTES:
        raise ValueError(
            f"{_NAME}: {n} stars with noise_var need one {n} x {n} factorisation per "
            f"target ({n_groups} targets: {n_groups * n * n * 8 / 2**30:.1f} GiB). Use "
            "local Kriging (n_neighbors='auto' or 30 for instance) or fewer stars."
        )
    C0 = corr(cdist(U, U))
    np.fill_diagonal(C0, 1.0)
    factors = []
    dual_coef = np.empty_like(Y)
    drift_coef = np.empty((F.shape[1], Y.shape[1]))
    for g, (ratio, targets) in enumerate(zip(groups.ratios, groups.targets)):
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
        drift_coef[:, targets] = beta
        dual_coef[:, targets] = cho_solve(L, Y[:, targets] - F @ beta, check_finite=False)
        factors.append((L[0], KiF, FKiF_inv))
    solve = ExactSolve(factors, dual_coef, drift_coef)
    return solve, (C0 if keep_covariance else None)


def fit_coupled(solve, C0, Z, F, noise_z, sill, groups, A_inv):
    """Exact co-Kriging: ``solve`` (the independent targets' :class:`ExactSolve` in the frame
    ``z = y A``) with the dual and drift coefficients (in the targets' frame of ``y``) of the
    system with every star's full noise covariance ``noise_z`` (n, T, T, in the frame);
    ``sill`` (T,) the frame targets' sills and ``A_inv`` the frame's inverse."""
    system = CoupledSystem(C0, sill, noise_z, solve.factors, groups.of, F)
    alpha, beta, n_cg_iter = system.solve_gls(Z)
    if n_cg_iter >= _CG_MAXITER:
        warnings.warn(f"{_NAME}: the co-Kriging system did not converge in {_CG_MAXITER} "
                      "conjugate-gradient iterations (noise covariances far from one "
                      "another's shape?); predictions may be inaccurate.", ConvergenceWarning,
                      stacklevel=4)
    return dataclasses.replace(solve, dual_coef=(alpha * sill) @ A_inv,
                               drift_coef=beta @ A_inv, dual_independent=solve.dual_coef,
                               n_cg_iter=n_cg_iter)


def predict_exact(solve, U_fit, corr, groups, U, Fq, return_std):
    """Predictions (m, T) and normalised variances (m, n_groups) of exact Kriging: ``solve``
    the :class:`ExactSolve` of the stars at transformed positions ``U_fit``, ``corr`` and
    ``groups`` as for :func:`fit_exact`; ``U`` the transformed query positions and ``Fq``
    their drift design rows."""
    m, T = U.shape[0], solve.dual_coef.shape[1]
    pred = np.empty((m, T))
    var = np.empty((m, len(solve.factors))) if return_std else None
    for sl in _query_chunks(m, U_fit.shape[0]):
        D = cdist(U[sl], U_fit)
        on_star = np.flatnonzero(D.min(axis=1) == 0)
        zero = D[on_star] == 0
        c = corr(D)
        c[on_star] = np.where(zero, 1.0, c[on_star])  # variogram 0 at distance 0
        np.matmul(c, solve.dual_coef, out=pred[sl])
        pred[sl] += Fq[sl] @ solve.drift_coef
        if not return_std:
            continue
        for g, (L, KiF, FKiF_inv) in enumerate(solve.factors):
            u = Fq[sl] - c @ KiF
            # c^T C^-1 c = |L^-1 c|^2: a triangular solve on c.T (Fortran-contiguous;
            # overwritten in place for the last group)
            last = g == len(solve.factors) - 1
            v = solve_triangular(L, c.T, lower=True, check_finite=False,
                                 overwrite_b=last)
            q = np.einsum("ij,ij->j", v, v)
            var[sl, g] = 1.0 - q + np.einsum("ip,pq,iq->i", u, FKiF_inv, u)
            if groups.ratios[g] is None:
                var[sl, g][on_star] = 0.0  # exactly 0 on a star, not rounding noise
    return pred, var


def loo_exact(solve, Z, groups, sill):
    """Leave-one-out predictions and residual variances of the frame's targets ``Z`` (n, T)
    of sills ``sill`` (T,), ``solve`` their :class:`ExactSolve`."""
    pdiag = np.empty_like(Z)
    for g, (L, KiF, FKiF_inv) in enumerate(solve.factors):
        Linv, info = lapack.dtrtri(L, lower=1)  # upper triangle zero, as L's
        d = np.einsum("ij,ij->j", Linv, Linv) - np.einsum("ip,pq,iq->i", KiF, FKiF_inv,
                                                          KiF)
        pdiag[:, groups.targets[g]] = d[:, None]
    dual = solve.dual_coef if solve.dual_independent is None else solve.dual_independent
    return Z - dual / pdiag, sill / pdiag
