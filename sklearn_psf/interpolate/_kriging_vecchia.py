"""Vecchia's approximation of the Kriging likelihood: each star given its nearest earlier
stars (private).

The joint density of the stars' values is written as a product of conditionals
``p(y_1) p(y_2 | y_1) ... p(y_n | y_1..y_{n-1})`` over a pseudo-random order (drawn from the
stars' positions, so that it does not change for the other stars when one is left out), and
each conditional
keeps only the ``m`` nearest earlier stars (Vecchia 1988; Datta et al. 2016, "nearest-neighbour
Gaussian processes"; Guinness 2018). With ``m = n - 1`` it is the exact likelihood; with
``m`` of 10-30 the maximum-likelihood range and sills differ from the exact ones by about 1%
(much less than their statistical error) at a cost ``O(n m^3)`` instead of ``O(n^3)``.

Each conditional is Gaussian with mean ``b^T y_N`` and variance ``d = k_ii - c^T b``,
``b = C_NN^-1 c`` (``C_NN`` the covariance of the neighbours, ``c`` their covariance with the
star); the drift is profiled out by weighted least squares on the decorrelated residuals
``y_i - b^T y_N``. The compiled kernel solves the small systems star by star and returns what
the gradient needs: for each parameter, ``dd`` (derivative of ``d``) and the products of
``v = dc - dC b`` (``db = C^-1 v``) with ``C^-1 y_N`` and ``C^-1 F_N``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from scipy.spatial import cKDTree

#: parameters whose derivatives the kernel returns, in this order (log-parameters)
VECCHIA_PARAMS = ("range", "p", "nu", "kappa")
#: stars per chunk when finding the nearest earlier stars
_CHUNK = 512


def position_order(P, seed):
    """A pseudo-random order of the stars that depends only on each star's own position
    (and ``seed``): leaving a star out does not reshuffle the others (a hash of the bits of
    the coordinates, splitmix64's finaliser)."""
    bits = np.ascontiguousarray(P, dtype=np.float64).view(np.uint64)
    key = np.full(P.shape[0], np.uint64(seed))
    with np.errstate(over="ignore"):
        for j in range(bits.shape[1]):
            key = (key ^ bits[:, j]) * np.uint64(0x9E3779B97F4A7C15)
            key ^= key >> np.uint64(30)
            key *= np.uint64(0xBF58476D1CE4E5B9)
            key ^= key >> np.uint64(27)
            key *= np.uint64(0x94D049BB133111EB)
            key ^= key >> np.uint64(31)
    return np.argsort(key, kind="stable")


def vecchia_neighbours(P, m, seed):
    """A pseudo-random order of the stars (:func:`position_order`) and, for each, its ``m``
    nearest earlier stars.

    Returns ``order`` (n,) and ``nb`` (n, m): ``nb[j]`` are positions in ``order`` (earlier
    than ``j``), nearest first, padded with -1 for the first stars; and their count (n,).
    """
    n = P.shape[0]
    m = max(1, min(m, n - 1))
    order = position_order(P, seed)
    Q = P[order]
    nb = np.full((n, m), -1, dtype=np.int64)
    for s in range(0, n, _CHUNK):
        e = min(s + _CHUNK, n)
        dist, idx = [], []
        if s > 0:
            k = min(m, s)
            d, i = cKDTree(Q[:s]).query(Q[s:e], k=k)
            dist.append(d.reshape(e - s, k))
            idx.append(i.reshape(e - s, k))
        # earlier stars of the same chunk
        diff = Q[s:e, None, :] - Q[None, s:e, :]
        d = np.sqrt(np.einsum("ijk,ijk->ij", diff, diff))
        d[np.triu_indices(e - s)] = np.inf
        dist.append(d)
        idx.append(np.broadcast_to(np.arange(s, e), d.shape))
        dist, idx = np.concatenate(dist, axis=1), np.concatenate(idx, axis=1)
        k = min(m, dist.shape[1])
        sel = np.argsort(dist, axis=1, kind="stable")[:, :k]
        near = np.take_along_axis(dist, sel, axis=1)
        nb[s:e, :k] = np.where(np.isfinite(near), np.take_along_axis(idx, sel, axis=1), -1)
    return order, nb, (nb >= 0).sum(axis=1)


@njit(cache=True, nogil=True, fastmath={"reassoc", "contract", "arcp"})
def _solve(L, k, x):
    """``x <- C^-1 x`` in place, ``C = L L^T`` (the first ``k`` rows)."""
    for a in range(k):  # forward: L z = x
        t = x[a]
        for c in range(a):
            t -= L[a, c] * x[c]
        x[a] = t / L[a, a]
    for a in range(k - 1, -1, -1):  # backward: L^T x = z, column by column
        x[a] /= L[a, a]
        for c in range(a):
            x[c] -= L[a, c] * x[a]


@njit(cache=True, nogil=True, fastmath={"reassoc", "contract", "arcp"})
def _conditionals(R, dR, r, dr, noise_nb, noise, y_nb, y, F_nb, F, count, p, nu, kappa, free,
                  d_out, yt_out, Ft_out, dd_out, a_out, B_out,
                  fisher):  # pragma: no cover - compiled
    """Per star: conditional variance, decorrelated value and drift row, and the pieces of
    the gradient for the parameters with ``free[par]`` (see the module docstring); ``fisher``
    (4, 4) accumulates their expected information ``sum_i dd dd' / (2 d^2) + v C^-1 v' / d``.
    Returns False if a system is not positive definite."""
    n, m = r.shape
    q = F.shape[1]
    L = np.empty((m, m))
    bvec = np.empty(m)  # b = C^-1 c
    V = np.empty((4, m))  # v of each parameter
    U = np.empty((4, m))  # C^-1 v of each parameter (y_N and F_N enter through it)
    dCb = np.empty(m)
    for i in range(n):
        k = count[i]
        # Cholesky of C = p (R + nu I) + kappa diag(noise), row by row (L[a, :a+1])
        for a in range(k):
            for b in range(a + 1):
                t = p * R[i, a, b]
                if b == a:
                    t += p * nu + kappa * noise_nb[i, a]
                for c in range(b):
                    t -= L[a, c] * L[b, c]
                if b < a:
                    L[a, b] = t / L[b, b]
                elif t <= 0.0:
                    return False
                else:
                    L[a, a] = math.sqrt(t)
        for a in range(k):
            bvec[a] = p * r[i, a]
        _solve(L, k, bvec)
        cb = 0.0
        yt = y[i]
        for a in range(k):
            cb += p * r[i, a] * bvec[a]
            yt -= bvec[a] * y_nb[i, a]
        d_out[i] = p * (1.0 + nu) + kappa * noise[i] - cb
        yt_out[i] = yt
        for j in range(q):
            ft = F[i, j]
            for a in range(k):
                ft -= bvec[a] * F_nb[i, a, j]
            Ft_out[i, j] = ft
        # derivatives: v = dc - dC b, dd = dk - 2 dc.b + b.dC.b
        for par in range(4):
            if not free[par]:
                continue
            v = V[par]
            if par == 0:  # log range: dC = p dR, dc = p dr, dk = 0
                for a in range(k):
                    t = 0.0
                    for c in range(k):
                        t += dR[i, a, c] * bvec[c]
                    dCb[a] = p * t
                    v[a] = p * dr[i, a] - dCb[a]
                dk = 0.0
            elif par == 1:  # log p: dC = C - kappa diag(noise), dc = c, dk = p (1 + nu)
                for a in range(k):
                    v[a] = kappa * noise_nb[i, a] * bvec[a]  # c - C b + kappa N b
                    dCb[a] = p * r[i, a] - v[a]  # C b - kappa N b
                dk = p * (1.0 + nu)
            elif par == 2:  # log nu: dC = p nu I
                for a in range(k):
                    dCb[a] = p * nu * bvec[a]
                    v[a] = -dCb[a]
                dk = p * nu
            else:  # log kappa: dC = kappa diag(noise)
                for a in range(k):
                    dCb[a] = kappa * noise_nb[i, a] * bvec[a]
                    v[a] = -dCb[a]
                dk = kappa * noise[i]
            dd = dk
            for a in range(k):
                dd += -2.0 * (v[a] + dCb[a]) * bvec[a] + bvec[a] * dCb[a]
            dd_out[i, par] = dd
            u = U[par]
            for a in range(k):
                u[a] = v[a]
            _solve(L, k, u)
            av = 0.0  # v . C^-1 y_N
            for a in range(k):
                av += u[a] * y_nb[i, a]
            a_out[i, par] = av
            for j in range(q):  # v . C^-1 F_N
                t = 0.0
                for a in range(k):
                    t += u[a] * F_nb[i, a, j]
                B_out[i, par, j] = t
        d = d_out[i]
        for p1 in range(4):
            if not free[p1]:
                continue
            for p2 in range(p1 + 1):
                if not free[p2]:
                    continue
                t = 0.0  # v1 . C^-1 v2
                for a in range(k):
                    t += U[p1, a] * V[p2, a]
                fisher[p1, p2] += 0.5 * dd_out[i, p1] * dd_out[i, p2] / (d * d) + t / d
    return True


class VecchiaTerms:
    """The stars in Vecchia order with their neighbours' geometry, for one set of positions.

    ``P`` (n, d) positions in the anisotropy frame, ``Y`` (n, T), ``F`` (n, q), ``noise``
    (n, T) or None; ``m`` neighbours; ``seed`` of the order.
    """

    def __init__(self, P, Y, F, noise, m, seed):
        order, nb, self.count = vecchia_neighbours(P, m, seed)
        valid = nb >= 0
        safe = np.where(valid, nb, 0)
        Q = P[order]
        self.y, self.F = Y[order], F[order]
        self.noise = np.zeros_like(self.y) if noise is None else noise[order]
        PN = Q[safe]  # (n, m, d)
        diff = PN[:, :, None, :] - PN[:, None, :, :]
        self.D_nb = np.sqrt(np.einsum("ijkl,ijkl->ijk", diff, diff))
        diff = PN - Q[:, None, :]
        self.d_nb = np.where(valid, np.sqrt(np.einsum("ijk,ijk->ij", diff, diff)), 0.0)
        self.valid = valid
        # per target, contiguous: values and noise of each star and of its neighbours
        self.y_t = np.ascontiguousarray(self.y.T)
        self.noise_t = np.ascontiguousarray(self.noise.T)
        self.y_nb = np.ascontiguousarray(np.where(valid, self.y[safe].transpose(2, 0, 1), 0.0))
        self.noise_nb = np.ascontiguousarray(
            np.where(valid, self.noise[safe].transpose(2, 0, 1), 0.0))
        self.F_nb = np.where(valid[:, :, None], self.F[safe], 0.0)

    def target(self, t, R, dR, r, dr, p, nu, kappa, free):
        """Kernel outputs for target ``t`` (see :func:`_conditionals`; the information
        matrix symmetric), or None if not PD; ``free`` (4,) bool: the parameters of
        :data:`VECCHIA_PARAMS` to differentiate."""
        n, m = r.shape
        q = self.F.shape[1]
        d, yt = np.empty(n), np.empty(n)
        Ft = np.empty((n, q))
        dd, a = np.zeros((n, 4)), np.zeros((n, 4))
        B = np.zeros((n, 4, q))
        fisher = np.zeros((4, 4))
        ok = _conditionals(R, dR, r, dr, self.noise_nb[t], self.noise_t[t], self.y_nb[t],
                           self.y_t[t], self.F_nb, self.F, self.count, float(p), float(nu),
                           float(kappa), free, d, yt, Ft, dd, a, B, fisher)
        if not ok or not (d > 0).all():
            return None
        return d, yt, Ft, dd, a, B, fisher + np.tril(fisher, -1).T
