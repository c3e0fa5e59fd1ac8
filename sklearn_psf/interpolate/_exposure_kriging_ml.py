"""Maximum likelihood of ExposureKrigingRegressor's static and atmospheric parts (private).

Model of target ``t``: ``y_t = mu_t + s_t(x) + [same exposure] a_t(x) + noise`` with
covariance ``p_t R(h / a_s) + q_t [e = e'] R(h / a_a) + diag(noise_t)``. The ranges are shared
by the targets, the sills are per target, ``mu_t`` is profiled out (generalised least
squares); the summed negative log-likelihood is minimised by L-BFGS-B on the log-parameters
with analytic gradients, from the best of a few starting points.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import lapack
from scipy.optimize import minimize
from scipy.spatial.distance import cdist
from threadpoolctl import threadpool_limits

from ._variogram import _CORRELATIONS, _corr_dlog_range

_LOG_2PI = np.log(2.0 * np.pi)
_P_BOUNDS = (1e-6, 1e3)  # sills, in units of the target's variance
_RANGE_BOUNDS = (1e-3, 10.0)  # ranges, in units of the unit square
#: relative diagonal term keeping noise-free systems factorisable
JITTER = 1e-10


def _cho_inverse(K):
    """(inverse of SPD K as a full symmetric matrix, log|K|), or (None, None); K overwritten."""
    L, info = lapack.dpotrf(K, lower=1, clean=1, overwrite_a=1)
    if info != 0:
        return None, None
    logdet = 2.0 * np.sum(np.log(np.diag(L)))
    Ki, info = lapack.dpotri(L, lower=1, overwrite_c=1)
    if info != 0:
        return None, None
    Ki = np.tril(Ki)
    Ki += np.tril(Ki, -1).T
    return Ki, logdet


class _JointLikelihood:
    """Negative log-likelihood of the stars (targets summed) and its gradient in
    ``theta = (log a_s, log a_a, log p_1..p_T, log q_1..q_T)``."""

    def __init__(self, U, exposure, Y, noise, variogram):
        self.D = cdist(U, U)
        self.same = exposure[:, None] == exposure[None, :]
        self.Y, self.noise, self.variogram = Y, noise, variogram
        self.n, self.T = Y.shape

    def __call__(self, theta):
        n, T = self.n, self.T
        a_s, a_a = np.exp(theta[:2])
        p, q = np.exp(theta[2:2 + T]), np.exp(theta[2 + T:])
        r_s, r_a = self.D / a_s, self.D / a_a
        Rs = _CORRELATIONS[self.variogram](r_s.copy())
        Ra = _CORRELATIONS[self.variogram](r_a.copy()) * self.same
        dRs = _corr_dlog_range(self.variogram, r_s, Rs)
        dRa = _corr_dlog_range(self.variogram, r_a, Ra) * self.same
        ones = np.ones(n)
        nll, grad = 0.0, np.zeros(2 + 2 * T)
        for t in range(T):
            K = p[t] * Rs + q[t] * Ra
            K[np.diag_indices(n)] += (0.0 if self.noise is None else self.noise[:, t]) \
                + JITTER * (p[t] + q[t])
            Ki, logdet = _cho_inverse(np.asfortranarray(K))
            if Ki is None:
                return 1e300, np.zeros_like(theta)
            y = self.Y[:, t]
            k1 = Ki @ ones
            mu = (k1 @ y) / k1.sum()
            alpha = Ki @ (y - mu)
            nll += 0.5 * (alpha @ (y - mu) + logdet + n * _LOG_2PI)
            # d nll / d log(par) = -(alpha' dK alpha - tr(K^-1 dK)) / 2
            for j, (scale, dK) in enumerate(((p[t], dRs), (q[t], dRa))):
                grad[j] -= 0.5 * scale * (alpha @ dK @ alpha - np.vdot(Ki, dK))
            grad[2 + t] -= 0.5 * p[t] * (alpha @ Rs @ alpha - np.vdot(Ki, Rs))
            grad[2 + T + t] -= 0.5 * q[t] * (alpha @ Ra @ alpha - np.vdot(Ki, Ra))
        return nll, grad


def fit_joint_hyperparameters(U, exposure, Y, noise, variogram, *, range_, atmosphere_range):
    """Maximum-likelihood ranges and sills of the static and atmospheric parts.

    Parameters
    ----------
    U : ndarray (n, d)
        Positions (scaled to the unit square).
    exposure : ndarray (n,)
        Exposure of each star.
    Y : ndarray (n, T)
    noise : ndarray (n, T) or None
    variogram : str
    range_, atmosphere_range : float or "auto"

    Returns
    -------
    dict with ``range``, ``atmosphere_range``, ``static_sill`` (T,), ``atmosphere_sill`` (T,)
    (in the units of Y squared) and ``log_likelihood``.
    """
    n, T = Y.shape
    scale = Y.std(axis=0)
    scale[scale == 0] = 1.0
    Ys = Y / scale
    Ns = None if noise is None else noise / scale**2
    fun = _JointLikelihood(U, exposure, Ys, Ns, variogram)
    mean_noise = 0.0 if Ns is None else Ns.mean(axis=0)
    p0 = np.log(np.clip(1.0 - mean_noise, 0.1, 1.0) / 2.0) * np.ones(T)
    fixed = {0: range_, 1: atmosphere_range}
    bounds = [tuple(np.log(_RANGE_BOUNDS))] * 2 + [tuple(np.log(_P_BOUNDS))] * (2 * T)
    for j, value in fixed.items():
        if not isinstance(value, str):
            bounds[j] = (np.log(value), np.log(value))
    starts = []
    for a_s in (0.1, 0.5):
        for a_a in (0.1, 0.5):
            for split in (0.2, 0.8):
                x0 = np.concatenate([[np.log(a_s), np.log(a_a)], p0 + np.log(2 * split),
                                     p0 + np.log(2 * (1 - split))])
                for j, value in fixed.items():
                    if not isinstance(value, str):
                        x0[j] = np.log(value)
                starts.append(x0)
    with threadpool_limits(limits=1, user_api="blas"):
        x0 = min(starts, key=lambda s: fun(s)[0])
        res = minimize(fun, x0, jac=True, method="L-BFGS-B", bounds=bounds,
                       options={"maxiter": 200, "maxfun": 300, "ftol": 1e-9, "gtol": 1e-5})
    theta = res.x
    return {"range": float(np.exp(theta[0])), "atmosphere_range": float(np.exp(theta[1])),
            "static_sill": np.exp(theta[2:2 + T]) * scale**2,
            "atmosphere_sill": np.exp(theta[2 + T:]) * scale**2,
            "log_likelihood": float(-res.fun - n * np.sum(np.log(scale))),
            "n_iter": int(res.nit)}
