"""Maximum-likelihood Kriging hyperparameters, all targets at once (private).

Model of target ``t`` at the stars: ``y_t = F beta_t + z_t + e_t`` with ``z_t`` a
Gaussian field of covariance ``p_t (R(a) + nu I)`` (``R`` the variogram's correlation,
``nu`` the nugget over the partial sill) and ``e_t`` the measurement noise of variance
``kappa * noise_t``. Range ``a``, ``nu`` and ``kappa`` are shared by the targets, the
partial sill ``p_t`` is per target and the drift coefficients ``beta_t`` are profiled
out (generalised least squares). The sum of the targets' log-likelihoods is maximised
with L-BFGS-B on the log-parameters, with analytic gradients.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import lapack
from scipy.optimize import minimize
from threadpoolctl import threadpool_limits

from ._variogram import _CORRELATIONS, _corr_dlog_range

_LOG_2PI = np.log(2.0 * np.pi)
#: bounds of the nugget-to-partial-sill ratio nu, the noise scale and the partial sill
#: (the latter in units of the target's variance)
_NU_BOUNDS = (1e-6, 1e3)
_KAPPA_BOUNDS = (1e-3, 1e3)
_P_BOUNDS = (1e-6, 1e3)


def _factor_solve(K, B):
    """``K^-1 B``, the inverse of K (lower triangle; the upper one is garbage) and log|K|.

    K (symmetric positive definite) is overwritten; (None, None, None) if not PD.
    """
    L, info = lapack.dpotrf(K, lower=1, clean=0, overwrite_a=1)
    if info != 0:
        return None, None, None
    logdet = 2.0 * np.sum(np.log(np.diag(L)))
    KiB, info = lapack.dpotrs(L, B, lower=1)
    Ki, info = lapack.dpotri(L, lower=1, overwrite_c=1)
    return KiB, Ki, logdet


class _Likelihood:
    """Negative total log-likelihood and its gradient in the log-parameters."""

    def __init__(self, D, Y, F, noise, variogram, free, fixed):
        self.D, self.Y, self.F, self.noise = D, Y, F, noise
        self.variogram, self.free, self.fixed = variogram, free, fixed
        self.n, self.T = Y.shape

    def unpack(self, theta):
        values = dict(self.fixed)
        i = 0
        for name in ("range", "nu", "kappa"):
            if name in self.free:
                values[name] = np.exp(theta[i])
                i += 1
        values["p"] = np.exp(theta[i:])
        return values

    def __call__(self, theta):
        v = self.unpack(theta)
        a, nu, kappa, p = v["range"], v["nu"], v["kappa"], v["p"]
        n, F, Y = self.n, self.F, self.Y
        q = F.shape[1]
        r = self.D / a
        R = _CORRELATIONS[self.variogram](r.copy())
        dR = _corr_dlog_range(self.variogram, r, R) if "range" in self.free else None
        # tr(K^-1 dR) from the lower triangle of K^-1 (Fortran order: Ki.T is C-contiguous)
        dR_up = 2.0 * np.triu(dR, 1) if dR is not None else None
        M = R
        M[np.diag_indices(n)] += nu
        FY = np.column_stack([F, Y])
        grad = {"range": 0.0, "nu": 0.0, "kappa": 0.0, "p": np.zeros(self.T)}
        nll = 0.0
        if self.noise is None:
            KiFY, Ki, logdetM = _factor_solve(M.copy(order="F"), FY)
            if Ki is None:
                return 1e300, np.zeros_like(theta)
            tr_dR_M = np.vdot(Ki.T, dR_up) if dR is not None else 0.0
            tr_M = np.trace(Ki)
        for t in range(self.T):
            y = Y[:, t]
            if self.noise is None:
                KiF, Kiy = KiFY[:, :q] / p[t], KiFY[:, q + t] / p[t]
                logdet = n * np.log(p[t]) + logdetM
                tr_dR, tr_I, N = tr_dR_M / p[t], tr_M / p[t], None
            else:
                N = kappa * self.noise[:, t]
                K = np.multiply(M, p[t], order="F")
                K[np.diag_indices(n)] += N
                sol, Ki, logdet = _factor_solve(K, FY[:, list(range(q)) + [q + t]])
                if Ki is None:
                    return 1e300, np.zeros_like(theta)
                KiF, Kiy = sol[:, :q], sol[:, q]
                tr_dR = np.vdot(Ki.T, dR_up) if dR is not None else 0.0
                diag_Ki = np.diag(Ki)
                tr_I = diag_Ki.sum()
            beta = np.linalg.solve(F.T @ KiF, KiF.T @ y)
            alpha = Kiy - KiF @ beta  # K^-1 (y - F beta)
            quad = (y - F @ beta) @ alpha
            nll += 0.5 * (quad + logdet + n * _LOG_2PI)
            # dL/dtheta = (alpha^T dK alpha - tr(K^-1 dK)) / 2, K = p (R + nu I) + N
            if N is None:
                grad["p"][t] = 0.5 * (quad - n)
            else:
                na2, nd = N @ (alpha * alpha), N @ diag_Ki
                grad["p"][t] = 0.5 * ((quad - na2) - (n - nd))
                grad["kappa"] += 0.5 * (na2 - nd)
            grad["nu"] += 0.5 * p[t] * nu * (alpha @ alpha - tr_I)
            if dR is not None:
                grad["range"] += 0.5 * p[t] * (alpha @ dR @ alpha - tr_dR)
        g = [grad[name] for name in ("range", "nu", "kappa") if name in self.free]
        return nll, -np.concatenate([np.asarray(g, dtype=float), grad["p"]])


def fit_hyperparameters(D, Y, F, noise, variogram, *, range_, nugget, noise_scale):
    """Maximum-likelihood range, nugget, sills and noise scale.

    Parameters
    ----------
    D : ndarray (n, n)
        Distances between the stars (after the anisotropy transform).
    Y : ndarray (n, T)
        Values at the stars.
    F : ndarray (n, p)
        Drift design matrix (a column of ones for ordinary Kriging).
    noise : ndarray (n, T) or None
        Measurement-noise variances.
    range_, nugget, noise_scale : float or "auto"
        Fixed values, or "auto" to fit them (``noise_scale`` only with ``noise``).

    Returns
    -------
    dict with ``range``, ``nugget`` (fraction of the sill), ``sill`` (T,), ``noise_scale``
    and ``log_likelihood`` (the maximum, in the units of ``Y``).
    """
    n, T = Y.shape
    scale = Y.std(axis=0)
    scale[scale == 0] = 1.0
    Ys = Y / scale
    Ns = None if noise is None else noise / scale**2
    free, fixed = [], {}
    if range_ == "auto":
        free.append("range")
    else:
        fixed["range"] = float(range_)
    if nugget == "auto":
        free.append("nu")
    else:
        fixed["nu"] = float(nugget) / max(1.0 - float(nugget), 1e-12)
    if Ns is not None and noise_scale == "auto":
        free.append("kappa")
    else:
        fixed["kappa"] = 1.0 if noise_scale == "auto" else float(noise_scale)
    fun = _Likelihood(D, Ys, F, Ns, variogram, free, fixed)

    dmax = float(D.max()) if D.size else 1.0
    dmax = dmax if dmax > 0 else 1.0
    mean_noise = 0.0 if Ns is None else Ns.mean(axis=0) * fixed.get("kappa", 1.0)
    p0 = np.log(np.clip(1.0 - mean_noise, 0.1, 1.0) / 1.1) * np.ones(T)
    bounds = []
    if "range" in free:
        bounds.append((np.log(1e-3 * dmax), np.log(10.0 * dmax)))
    if "nu" in free:
        bounds.append(tuple(np.log(_NU_BOUNDS)))
    if "kappa" in free:
        bounds.append(tuple(np.log(_KAPPA_BOUNDS)))
    bounds += [tuple(np.log(_P_BOUNDS))] * T

    # a few starting ranges; the local optimisation starts from the best of them
    head = [np.log(0.1)] if "nu" in free else []
    head += [0.0] if "kappa" in free else []
    starts = [
        np.concatenate([[np.log(f * dmax)] if "range" in free else [], head, p0])
        for f in ((0.05, 0.2, 0.8) if "range" in free else (1.0,))
    ]
    # one BLAS thread: on these small matrices threads only add synchronisation (and
    # stall badly on a busy machine)
    with threadpool_limits(limits=1, user_api="blas"):
        x0 = min(starts, key=lambda s: fun(s)[0])
        res = minimize(fun, x0, jac=True, method="L-BFGS-B", bounds=bounds,
                       options={"maxiter": 200, "maxfun": 400, "ftol": 1e-10, "gtol": 1e-6})
    v = fun.unpack(res.x)
    nu = v["nu"]
    return {
        "range": float(v["range"]),
        "nugget": float(nu / (1.0 + nu)),
        "sill": v["p"] * (1.0 + nu) * scale**2,
        "noise_scale": float(v["kappa"]),
        "log_likelihood": float(-res.fun - n * np.sum(np.log(scale))),
        "n_iter": int(res.nit),
    }
