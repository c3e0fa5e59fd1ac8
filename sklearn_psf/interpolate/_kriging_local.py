"""Local Kriging: bordered systems of each query's nearest stars, solved in batches (private)."""

from __future__ import annotations

import numpy as np

#: Queries per batch of stacked bordered systems are bounded so that the batch's arrays
#: stay around this many float64 elements (~16 MB).
_LOCAL_BATCH_ELEMENTS = 2**21


def predict_local(reg, U, Fq, return_std):
    """Predictions (m, T) and normalised variances (m, n_groups) of local Kriging (in the
    frame of the independent targets, see :mod:`._kriging_co`).

    ``reg`` is a fitted :class:`KrigingRegressor` in local mode, ``U`` the transformed
    query positions and ``Fq`` their drift design rows. Each query solves
    ``[C_k F_k; F_k^T 0] [lambda; mu] = [c_k; f]`` over its ``k`` nearest stars, with
    ``C_k`` the normalised covariance (plus the stars' noise, per group of targets).
    """
    m, T = U.shape[0], reg._z_fit.shape[1]
    k, p = reg._k, Fq.shape[1]
    ratios = reg._noise_ratio_groups  # list of (n_stars,) arrays or [None]
    pred = np.empty((m, T))
    var = np.empty((m, len(ratios))) if return_std else None
    batch = int(max(1, _LOCAL_BATCH_ELEMENTS // ((k + p) ** 2 + k * T)))
    Us, Ys, Fs = reg._U_fit, reg._z_fit, reg._F_fit
    diag = np.arange(k)
    for start in range(0, m, batch):
        sl = slice(start, min(start + batch, m))
        dist, idx = reg._tree.query(U[sl], k=k)
        if k == 1:
            dist, idx = dist[:, None], idx[:, None]
        b = idx.shape[0]
        P = Us[idx]  # (b, k, d) neighbour positions
        A = np.zeros((b, k + p, k + p))
        D = A[:, :k, :k]
        diff = P[:, :, None, :] - P[:, None, :, :]
        np.sqrt(np.einsum("bijd,bijd->bij", diff, diff), out=D)
        del diff
        D[...] = reg._correlation(D)
        A[:, diag, diag] = 1.0  # distinct stars: nugget between them, 1 on the diagonal
        A[:, :k, k:] = Fs[idx]
        A[:, k:, :k] = np.swapaxes(A[:, :k, k:], 1, 2)
        rhs = np.empty((b, k + p))
        on = dist == 0
        rhs[:, :k] = reg._correlation(dist.copy())
        rhs[:, :k][on] = 1.0  # on a star: covariance 1 (the variogram is 0 there)
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
            targets = reg._group_targets[g]
            pred[sl, targets] = np.einsum("bk,bkt->bt", lam, Ys[idx][:, :, targets])
            if return_std:
                v = 1.0 - np.einsum("bk,bk->b", lam, rhs[:, :k])
                v -= np.einsum("bp,bp->b", sol[:, k:], rhs[:, k:])
                if ratio is None:
                    v[on.any(axis=1)] = 0.0
                var[sl, g] = v
    return pred, var
