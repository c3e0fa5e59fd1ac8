"""Local Kriging: bordered systems of each query's nearest stars, solved in batches (private).

:func:`fit_local` returns the :class:`LocalSolve` of the stars, which :func:`predict_local`
takes with the stars."""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.spatial import cKDTree

#: Queries per batch of stacked bordered systems are bounded so that the batch's arrays
#: stay around this many float64 elements (~16 MB).
_LOCAL_BATCH_ELEMENTS = 2**21


@dataclasses.dataclass(frozen=True)
class LocalSolve:
    """Local Kriging's fit: the stars' k-d tree (transformed positions), the neighbours of
    each query and the targets' mean over the stars."""

    tree: cKDTree
    k: int
    mean: np.ndarray


def fit_local(U, Y, k, n_drift, drift):
    """The :class:`LocalSolve` of the stars at transformed positions ``U`` with values ``Y``,
    ``k`` neighbours per query and ``n_drift`` drift terms (of ``drift``, for the message)."""
    if k < n_drift:
        raise ValueError(f"KrigingRegressor: n_neighbors must be at least {n_drift} for "
                         f"drift={drift!r}, got {k}.")
    return LocalSolve(cKDTree(U), k, Y.mean(axis=0))


def _neighbours(tree, U, k, leave_out):
    """Distances and indices of the ``k`` nearest stars of each query; with ``leave_out``
    (n,) the query's own star index, that star is left out (the queries are stars)."""
    dist, idx = tree.query(U, k=k + (leave_out is not None))
    dist, idx = dist.reshape(len(U), -1), idx.reshape(len(U), -1)
    if leave_out is None:
        return dist, idx
    own = idx == leave_out[:, None]
    own[~own.any(axis=1), -1] = True  # own star not among them (duplicates): drop the last
    keep = ~own
    return dist[keep].reshape(len(U), k), idx[keep].reshape(len(U), k)


def predict_local(local, stars, corr, groups, U, Fq, return_std, leave_out=None):
    """Predictions (m, T) and normalised variances (m, n_groups) of local Kriging (in the
    frame of the independent targets, see :mod:`._kriging_co`).

    ``local`` is the :class:`LocalSolve` of the stars, ``stars`` their transformed positions,
    values (in that frame) and drift design rows, ``corr`` the normalised correlation of
    distances and ``groups`` the :class:`~._kriging_exact.NoiseGroups`; ``U`` the transformed
    query positions and ``Fq`` their drift design rows. Each query solves
    ``[C_k F_k; F_k^T 0] [lambda; mu] = [c_k; f]`` over its ``k`` nearest stars, with
    ``C_k`` the normalised covariance (plus the stars' noise, per group of targets).
    ``leave_out`` (m,): each query's own star, left out of its neighbours (leave-one-out).
    """
    Us, Ys, Fs = stars
    m, T = U.shape[0], Ys.shape[1]
    k, p = local.k, Fq.shape[1]
    ratios = groups.ratios  # list of (n_stars,) arrays or [None]
    pred = np.empty((m, T))
    var = np.empty((m, len(ratios))) if return_std else None
    batch = int(max(1, _LOCAL_BATCH_ELEMENTS // ((k + p) ** 2 + k * T)))
    diag = np.arange(k)
    for start in range(0, m, batch):
        sl = slice(start, min(start + batch, m))
        dist, idx = _neighbours(local.tree, U[sl], k,
                                None if leave_out is None else leave_out[sl])
        b = idx.shape[0]
        P = Us[idx]  # (b, k, d) neighbour positions
        A = np.zeros((b, k + p, k + p))
        D = A[:, :k, :k]
        diff = P[:, :, None, :] - P[:, None, :, :]
        np.sqrt(np.einsum("bijd,bijd->bij", diff, diff), out=D)
        del diff
        D[...] = corr(D)
        A[:, diag, diag] = 1.0  # distinct stars: nugget between them, 1 on the diagonal
        A[:, :k, k:] = Fs[idx]
        A[:, k:, :k] = np.swapaxes(A[:, :k, k:], 1, 2)
        rhs = np.empty((b, k + p))
        on = dist == 0
        rhs[:, :k] = corr(dist.copy())
        if leave_out is None:
            rhs[:, :k][on] = 1.0  # on a star: covariance 1 (the variogram is 0 there)
        else:
            on[:] = False  # another star at the same position is a distinct measurement
        rhs[:, k:] = Fq[sl]
        for g, ratio in enumerate(ratios):
            Ag = A
            if ratio is not None:
                Ag = A.copy()
                Ag[:, diag, diag] += ratio[idx]
            try:
                sol = np.linalg.solve(Ag, rhs[:, :, None])[:, :, 0]
            except np.linalg.LinAlgError:
                raise ValueError(
                    "KrigingRegressor: a local Kriging system is singular (stars almost at "
                    "the same position relative to the range, or too few neighbours for the "
                    "drift). Add a small nugget (e.g. nugget=1e-6), merge close stars or "
                    "raise n_neighbors."
                ) from None
            lam = sol[:, :k]
            targets = groups.targets[g]
            pred[sl, targets] = np.einsum("bk,bkt->bt", lam, Ys[idx][:, :, targets])
            if return_std:
                v = 1.0 - np.einsum("bk,bk->b", lam, rhs[:, :k])
                v -= np.einsum("bp,bp->b", sol[:, k:], rhs[:, k:])
                if ratio is None:
                    v[on.any(axis=1)] = 0.0
                var[sl, g] = v
    return pred, var
