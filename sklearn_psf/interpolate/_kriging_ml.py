"""Maximum-likelihood Kriging hyperparameters, all targets at once (private).

Model of target ``t`` at the stars: ``y_t = F beta_t + z_t + e_t`` with ``z_t`` a
Gaussian field of covariance ``p_t (R(a) + nu I)`` (``R`` the variogram's correlation,
``nu`` the nugget over the partial sill) and ``e_t`` the measurement noise of variance
``kappa * noise_t``. Range ``a``, ``nu`` and ``kappa`` are shared by the targets, the
partial sill ``p_t`` is per target and the drift coefficients ``beta_t`` are profiled
out (generalised least squares). The sum of the targets' log-likelihoods is maximised
on the log-parameters with analytic gradients: by L-BFGS-B for the exact likelihood, by
quasi-Newton steps started from the expected (Fisher) information for Vecchia's approximation
(whose information is cheap).
"""

from __future__ import annotations

import itertools

import numpy as np
from scipy.linalg import lapack
from scipy.optimize import minimize
from scipy.spatial.distance import cdist
from threadpoolctl import threadpool_limits

from ._kriging_vecchia import VECCHIA_PARAMS, VecchiaTerms
from ._variogram import _CORRELATIONS, _corr_dlog_range

_LOG_2PI = np.log(2.0 * np.pi)
#: bounds of the nugget-to-partial-sill ratio nu, the noise scale and the partial sill
#: (the latter in units of the target's variance)
_NU_BOUNDS = (1e-6, 1e3)
_KAPPA_BOUNDS = (1e-3, 1e3)
_P_BOUNDS = (1e-3, 1e3)
#: convergence: largest gradient component per star (the log-likelihood grows as n and its
#: curvature in the log-parameters too, so that the parameters are within ~1e-8 of the optimum)
_GTOL = 1e-8


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


_GEOMETRY = ("range", "scaling", "angle")
_ORDER = ("range", "scaling", "angle", "nu", "kappa")


def _order(n_extra):
    """Parameter names in ``theta``'s order: ``extra0``, ``extra1``... are the factors on the
    features beyond the first two (one correlation length per extra dimension)."""
    return _ORDER[:3] + tuple(f"extra{j}" for j in range(n_extra)) + _ORDER[3:]


class _Parameters:
    """Free and fixed parameters; ``theta`` holds the free ones (log-values, the angle in
    radians) in the order of :func:`_order`, then the log partial sills."""

    def __init__(self, Y, variogram, free, fixed, n_extra=0):
        self.variogram, self.free, self.fixed = variogram, free, fixed
        self.n, self.T = Y.shape
        self.order = _order(n_extra)
        self.n_extra = n_extra

    def unpack(self, theta):
        values = dict(self.fixed)
        names = [name for name in self.order if name in self.free]
        for name, t in zip(names, theta):
            values[name] = t if name == "angle" else np.exp(t)
        values["p"] = np.exp(theta[len(names):])
        return values

    def _pack_gradient(self, grad):
        g = [grad[name] for name in self.order if name in self.free]
        return -np.concatenate([np.asarray(g, dtype=float), grad["p"]])


class _Likelihood(_Parameters):
    """Exact negative total log-likelihood and its gradient in the log-parameters.

    ``P`` are the positions (already in the anisotropy frame unless ``scaling`` or
    ``angle`` is free; then raw 2-D positions, rotated by ``-angle`` and the second
    coordinate multiplied by ``scaling``, angle in radians, not a log-parameter). With
    ``n_extra`` factors free, the columns of ``P`` beyond the first two are multiplied by
    them (``extra0``, ...) before distances are computed.
    """

    def __init__(self, P, Y, F, noise, variogram, free, fixed, n_extra=0):
        super().__init__(Y, variogram, free, fixed, n_extra)
        self.Y, self.F, self.noise = Y, F, noise
        self.aniso = "scaling" in free or "angle" in free
        self.geometry = [name for name in self.order
                         if name in free and (name in _GEOMETRY or name.startswith("extra"))]
        if self.aniso:
            self.dx = P[:, None, 0] - P[None, :, 0]
            self.dy = P[:, None, 1] - P[None, :, 1]
        elif n_extra:
            self.D2 = cdist(P[:, :2], P[:, :2], "sqeuclidean")
            self.dz2 = [(P[:, None, j] - P[None, :, j]) ** 2 for j in range(2, 2 + n_extra)]
        else:
            self.D = cdist(P, P)

    def _geometry(self, v):
        """Correlations R and d R / d(free geometric parameter), by name."""
        a = v["range"]
        extra = []
        if self.n_extra and not self.aniso:
            extra = [v[f"extra{j}"] ** 2 * dz2 for j, dz2 in enumerate(self.dz2)]
            D = np.sqrt(self.D2 + sum(extra))
        elif not self.aniso:
            D = self.D
        else:
            c, s_ = np.cos(v["angle"]), np.sin(v["angle"])
            u = c * self.dx + s_ * self.dy
            w = -s_ * self.dx + c * self.dy
            D = np.sqrt(u * u + (v["scaling"] * w) ** 2)
        r = D / a
        R = _CORRELATIONS[self.variogram](r.copy())
        grads = {}
        if self.geometry:
            dlog_a = _corr_dlog_range(self.variogram, r, R)  # = -rho'(r) r
            if "range" in self.free:
                grads["range"] = dlog_a
            if extra and "extra0" in self.free:  # dD/dlog e_j = (e_j dz_j)^2 / D
                D2 = np.where(D > 0, D * D, np.inf)
                for j, term in enumerate(extra):
                    grads[f"extra{j}"] = -dlog_a * term / D2
            if self.aniso:
                D2 = np.where(D > 0, D * D, np.inf)
                sc = v["scaling"]
                if "scaling" in self.free:  # dD/dlog s = (s w)^2 / D
                    grads["scaling"] = -dlog_a * (sc * w) ** 2 / D2
                if "angle" in self.free:  # dD/dangle = u w (1 - s^2) / D
                    grads["angle"] = -dlog_a * u * w * (1.0 - sc * sc) / D2
        return R, grads

    def __call__(self, theta):
        v = self.unpack(theta)
        nu, kappa, p = v["nu"], v["kappa"], v["p"]
        n, F, Y = self.n, self.F, self.Y
        q = F.shape[1]
        R, dRs = self._geometry(v)
        # tr(K^-1 dR) from the lower triangle of K^-1 (Fortran order: Ki.T is C-contiguous)
        dR_ups = {name: 2.0 * np.triu(dR, 1) for name, dR in dRs.items()}
        M = R
        M[np.diag_indices(n)] += nu
        FY = np.column_stack([F, Y])
        grad = dict.fromkeys(self.order, 0.0)
        grad["p"] = np.zeros(self.T)
        nll = 0.0
        if self.noise is None:
            KiFY, Ki, logdetM = _factor_solve(M.copy(order="F"), FY)
            if Ki is None:
                return 1e300, np.zeros_like(theta)
            tr_dR_M = {name: np.vdot(Ki.T, up) for name, up in dR_ups.items()}
            tr_M = np.trace(Ki)
        for t in range(self.T):
            y = Y[:, t]
            if self.noise is None:
                KiF, Kiy = KiFY[:, :q] / p[t], KiFY[:, q + t] / p[t]
                logdet = n * np.log(p[t]) + logdetM
                tr_dR = {name: tr / p[t] for name, tr in tr_dR_M.items()}
                tr_I, N = tr_M / p[t], None
            else:
                N = kappa * self.noise[:, t]
                K = np.multiply(M, p[t], order="F")
                K[np.diag_indices(n)] += N
                sol, Ki, logdet = _factor_solve(K, FY[:, list(range(q)) + [q + t]])
                if Ki is None:
                    return 1e300, np.zeros_like(theta)
                KiF, Kiy = sol[:, :q], sol[:, q]
                tr_dR = {name: np.vdot(Ki.T, up) for name, up in dR_ups.items()}
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
            for name, dR in dRs.items():
                grad[name] += 0.5 * p[t] * (alpha @ dR @ alpha - tr_dR[name])
        return nll, self._pack_gradient(grad)


class _VecchiaLikelihood(_Parameters):
    """Vecchia's approximation of the negative log-likelihood (``m`` nearest earlier stars,
    see :mod:`._kriging_vecchia`) and its gradient; positions in the anisotropy frame."""

    def __init__(self, P, Y, F, noise, variogram, free, fixed, m, seed):
        super().__init__(Y, variogram, free, fixed)
        self.terms = VecchiaTerms(P, Y, F, noise, m, seed)
        # derivatives needed: the free parameters, and the partial sills always
        self.differentiate = np.array([name in free or name == "p" for name in VECCHIA_PARAMS])

    def __call__(self, theta, information=False):
        """Negative log-likelihood, its gradient and, with ``information``, the expected
        (Fisher) information of the log-parameters (in ``theta``'s order)."""
        v = self.unpack(theta)
        a, nu, kappa, p = v["range"], v["nu"], v["kappa"], v["p"]
        terms, corr = self.terms, _CORRELATIONS[self.variogram]
        scaled = terms.D_nb / a
        R = corr(scaled.copy())
        dR = _corr_dlog_range(self.variogram, scaled, R)
        scaled = terms.d_nb / a
        r = corr(scaled.copy())
        dr = _corr_dlog_range(self.variogram, scaled, r)
        nll = 0.0
        grad = dict.fromkeys(_ORDER, 0.0)
        grad["p"] = np.zeros(self.T)
        shared = [name for name in _ORDER if name in self.free]
        kernel_index = [VECCHIA_PARAMS.index(name) for name in shared]
        n_shared = len(shared)
        info = np.zeros((n_shared + self.T, n_shared + self.T))
        for t in range(self.T):
            out = terms.target(t, R, dR, r, dr, p[t], nu, kappa, self.differentiate)
            if out is None:
                fail = (1e300, np.zeros_like(theta))
                return fail + (np.eye(len(theta)),) if information else fail
            d, yt, Ft, dd, av, B, fisher = out
            w = 1.0 / d
            beta = np.linalg.lstsq(Ft.T @ (Ft * w[:, None]), Ft.T @ (yt * w), rcond=None)[0]
            e = yt - Ft @ beta
            ew = e * w
            nll += 0.5 * (np.sum(np.log(d)) + ew @ e + self.n * _LOG_2PI)
            # dL/dtheta = -0.5 sum[(1 - e^2/d) dd/d + 2 (e/d) de], de = -(a - B beta)
            g = ew @ (av - B @ beta) - 0.5 * ((1.0 - ew * e) * w) @ dd
            grad["range"] += g[0]
            grad["p"][t] = g[1]
            grad["nu"] += g[2]
            grad["kappa"] += g[3]
            if information:
                idx = kernel_index + [VECCHIA_PARAMS.index("p")]
                block = fisher[np.ix_(idx, idx)]
                pos = list(range(n_shared)) + [n_shared + t]
                info[np.ix_(pos, pos)] += block
        g = self._pack_gradient(grad)
        return (nll, g, info) if information else (nll, g)


def _fisher_quasi_newton(fun, starts, box, tol=1e-4, decrement=1e-2, max_iter=100):
    """Minimise ``fun`` (value, gradient and, with ``information=True``, the expected
    information) in a box from the best of ``starts``: Newton steps with a curvature matrix
    that starts as the expected (Fisher) information there and is corrected by BFGS updates
    from the gradients (the expected information alone converges only linearly, ~0.25 per
    step); the parameters held at a bound are left out of each step, steps are halved until
    the value decreases. Stops when the predicted decrease of the value is below
    ``decrement`` (1e-2 of a log-likelihood unit: the parameters within about a tenth of
    their standard error) or no parameter moves by more than ``tol``. Returns (x, value,
    iterations, evaluations)."""
    lo, hi = np.array(box, dtype=float).T
    points = [np.clip(np.asarray(x0, dtype=float), lo, hi) for x0 in starts]
    evaluated = [fun(x, information=True) for x in points]
    best = int(np.argmin([e[0] for e in evaluated]))
    x, (f, g, B) = points[best], evaluated[best]
    B = B + 1e-10 * np.trace(B) / len(x) * np.eye(len(x))
    n_eval = len(points)
    for it in range(1, max_iter + 1):
        free = ~(((x <= lo) & (g > 0)) | ((x >= hi) & (g < 0)))
        step = np.zeros_like(x)
        step[free] = -np.linalg.solve(B[np.ix_(free, free)], g[free])
        if -0.5 * g @ step < decrement:
            break
        for _ in range(30):
            new = np.clip(x + step, lo, hi)
            f_new, g_new = fun(new)
            n_eval += 1
            if f_new <= f + 1e-4 * g @ (new - x) or np.abs(new - x).max() < tol:
                break
            step *= 0.5
        s_, y_ = new - x, g_new - g
        if s_ @ y_ > 1e-12 * np.sqrt((s_ @ s_) * (y_ @ y_)):  # BFGS update, kept definite
            Bs = B @ s_
            B = B - np.outer(Bs, Bs) / (s_ @ Bs) + np.outer(y_, y_) / (s_ @ y_)
        moved = np.abs(s_).max()
        x, f, g = new, f_new, g_new
        if moved < tol:
            break
    return x, f, it, n_eval


def fit_hyperparameters(P, Y, F, noise, variogram, *, range_, nugget, noise_scale,
                        scaling=1.0, angle=0.0, extra=None, neighbors=None, rng=None,
                        start=None, range_floor=None, gtol=_GTOL):
    """Maximum-likelihood range, nugget, sills, noise scale and anisotropy.

    Parameters
    ----------
    P : ndarray (n, d)
        Star positions: in the anisotropy frame when ``scaling`` and ``angle`` are
        numbers (they are then ignored), raw 2-D positions when either is "auto".
    Y : ndarray (n, T)
        Values at the stars.
    F : ndarray (n, p)
        Drift design matrix (a column of ones for ordinary Kriging).
    noise : ndarray (n, T) or None
        Measurement-noise variances.
    range_, nugget, noise_scale, scaling, angle : float or "auto"
        Fixed values, or "auto" to fit them (``noise_scale`` only with ``noise``);
        ``angle`` in degrees.
    extra : "auto" or None
        "auto": fit a factor on each column of ``P`` beyond the first two (raw columns; one
        correlation length per extra dimension, exact likelihood only); None: ``P`` is
        already in its final frame.
    neighbors : int or None
        None: the exact likelihood. An int ``m``: Vecchia's approximation with the ``m``
        nearest earlier stars in an order drawn from ``rng`` (fixed anisotropy only).
    rng : numpy Generator, optional
        Draws the Vecchia order.
    start : dict, optional
        A previous result of this function (``range``, ``nugget``, ``noise_scale``,
        ``scaling``, ``angle``, ``sill``): the optimisation starts there instead of from the
        best point of a grid (the sills from their default start when ``sill`` is missing or
        has another number of targets).
    range_floor : float, optional
        Lower bound of the range (default ``1e-3`` times the span of the positions).
    gtol : float, optional
        The exact likelihood's convergence: largest gradient component per star.

    Returns
    -------
    dict with ``range``, ``nugget`` (fraction of the sill), ``sill`` (T,), ``noise_scale``,
    ``scaling``, ``angle`` (degrees), ``extra`` (the factors, or None) and
    ``log_likelihood`` (the maximum, in the units of ``Y``).
    """
    n, T = Y.shape
    n_extra = P.shape[1] - 2 if isinstance(extra, str) else 0
    scale = Y.std(axis=0)
    scale[scale == 0] = 1.0
    Ys = Y / scale
    Ns = None if noise is None else noise / scale**2
    settings = {
        "range": (range_, float),
        "scaling": (scaling, float),
        "angle": (angle, np.deg2rad),
        "nu": (nugget, lambda g: float(g) / max(1.0 - float(g), 1e-12)),
        "kappa": (noise_scale, float),
    }
    free, fixed = [], {}
    for name, (value, convert) in settings.items():
        if isinstance(value, str) and (name != "kappa" or Ns is not None):
            free.append(name)
        else:
            fixed[name] = 1.0 if isinstance(value, str) else convert(value)
    free += [f"extra{j}" for j in range(n_extra)]
    if neighbors is None:
        fun = _Likelihood(P, Ys, F, Ns, variogram, free, fixed, n_extra)
    else:
        fun = _VecchiaLikelihood(P, Ys, F, Ns, variogram, free, fixed, neighbors,
                                 rng.integers(2**63))

    span = np.ptp(P[:, :2] if n_extra else P, axis=0).max() if n > 1 else 1.0
    span = span if span > 0 else 1.0
    # an extra column's factor in units of (position span / its own span): from a length
    # 1000 times the range (the dimension has no effect) to a hundredth of it
    extra_base = {}
    for j in range(n_extra):
        span_j = np.ptp(P[:, 2 + j]) if n > 1 else 0.0
        extra_base[f"extra{j}"] = np.log(span / span_j) if span_j > 0 else 0.0
    mean_noise = 0.0 if Ns is None else Ns.mean(axis=0) * fixed.get("kappa", 1.0)
    p0 = np.log(np.clip(1.0 - mean_noise, 0.1, 1.0) / 1.1) * np.ones(T)
    low = max(1e-3 * span, range_floor or 0.0)
    bounds = {
        "range": (np.log(low), np.log(max(10.0 * span, 2.0 * low))),
        "scaling": (np.log(0.1), np.log(10.0)),
        "angle": (-np.pi, np.pi),
        "nu": tuple(np.log(_NU_BOUNDS)),
        "kappa": tuple(np.log(_KAPPA_BOUNDS)),
        **{name: (base + np.log(1e-3), base + np.log(1e2)) for name, base in extra_base.items()},
    }
    # a few starting points (ranges, anisotropy directions); the local optimisation
    # starts from the best of them
    grid = {
        # Vecchia's quasi-Newton steps need no grid of ranges (the likelihood is unimodal
        # in the range): one start, the middle one
        "range": [np.log(max(f * span, low)) for f in
                  ((0.05, 0.2, 0.8) if neighbors is None else (0.2,))],
        "scaling": [np.log(2.0)],
        "angle": [0.0, np.pi / 3, 2 * np.pi / 3],
        "nu": [np.log(0.1)],
        "kappa": [0.0],
        **{name: [base + np.log(0.3)] for name, base in extra_base.items()},
    }
    names = [name for name in fun.order if name in free]
    box = [bounds[name] for name in names] + [tuple(np.log(_P_BOUNDS))] * T
    if start is None:
        starts = [np.concatenate([combo, p0])
                  for combo in itertools.product(*(grid[name] for name in names))]
    else:
        nu0 = start["nugget"] / max(1.0 - start["nugget"], 1e-12)
        previous = {"range": np.log(start["range"]), "scaling": np.log(start["scaling"]),
                    "angle": np.deg2rad(start["angle"]), "nu": np.log(max(nu0, 1e-300)),
                    "kappa": np.log(start["noise_scale"]),
                    **{f"extra{j}": np.log(e) for j, e in enumerate(start.get("extra") or ())}}
        sill = start.get("sill")
        p_start = p0 if sill is None or np.size(sill) != T else np.log(
            np.maximum(np.asarray(sill) / (1.0 + nu0) / scale**2, 1e-300))
        starts = [np.clip(np.concatenate([[previous[name] for name in names], p_start]),
                          *np.array(box).T)]
    # the exact likelihood's optimum to ~1e-8 (equal to GaussianProcessRegressor's) by
    # L-BFGS-B; Vecchia's approximation by quasi-Newton steps started from its expected
    # information, until the log-likelihood is within ~1e-2 of its maximum (the
    # approximation's own error in the parameters is ~1e-2)
    # one BLAS thread: on these small matrices threads only add synchronisation (and
    # stall badly on a busy machine)
    with threadpool_limits(limits=1, user_api="blas"):
        if neighbors is None:
            x0 = min(starts, key=lambda s: fun(s)[0]) if len(starts) > 1 else starts[0]
            res = minimize(fun, x0, jac=True, method="L-BFGS-B", bounds=box,
                           options={"maxiter": 500, "maxfun": 1000, "ftol": 1e-15,
                                    "gtol": gtol * n})
            x, value, n_iter, n_eval = res.x, res.fun, res.nit, res.nfev
        else:  # quasi-Newton from the expected information (cheap for the approximation)
            x, value, n_iter, n_eval = _fisher_quasi_newton(fun, starts, box)
    v = fun.unpack(x)
    nu = v["nu"]
    return {
        "range": float(v["range"]),
        "nugget": float(nu / (1.0 + nu)),
        "sill": v["p"] * (1.0 + nu) * scale**2,
        "noise_scale": float(v["kappa"]),
        "scaling": float(v["scaling"]),
        "angle": float(np.rad2deg(v["angle"])),
        "extra": [float(v[f"extra{j}"]) for j in range(n_extra)] if n_extra else None,
        "log_likelihood": float(-value - n * np.sum(np.log(scale))),
        "n_iter": int(n_iter),
        "n_eval": int(n_eval),
    }
