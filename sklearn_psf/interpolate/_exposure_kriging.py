"""Kriging across exposures: a static pattern shared by every exposure plus each exposure's own.

Model of target ``t`` at star ``i`` (position ``x_i``, exposure ``e_i``)::

    y_t(i) = mu_t + s_t(x_i) + a_{t, e_i}(x_i) + eps_t(i)
    cov    = p_t R(|x_i - x_j| / a_s) + q_t [e_i = e_j] R(|x_i - x_j| / a_a) + diag(noise_t)

``s_t`` is the static (optical) pattern in chip (or focal-plane) coordinates, ``a_{t,e}`` the
atmospheric pattern of exposure ``e``, independent from exposure to exposure. Within one
exposure the dither is a constant shift, so sky and chip separations are equal: the
atmospheric term needs no dither. Ranges ``a_s``, ``a_a`` (shared by the targets) and the
sills ``p_t``, ``q_t`` are fitted by maximum likelihood with the mean ``mu_t`` profiled out
(generalised least squares); ``R`` is a variogram's correlation (:mod:`._variogram`).

With each star's noise covariance across the targets (``noise_cov``, co-Kriging) the targets
are modelled in the frame ``z = y A`` where they are nearly independent (the coregionalisation
frame of :mod:`._kriging_co`): each of ``z``'s targets has its own static and atmospheric
sills (a linear model of coregionalisation with two kernels), fitted by maximum likelihood
with the frame's marginal noise; the Kriging system is then solved exactly with the full
noise covariances by conjugate gradients, preconditioned by the independent targets' systems.

Exact solve up to ``max_exact_samples`` stars; beyond, the static part across exposures goes
through a grid of inducing points while every exposure's block (its atmosphere, its noise and
the static part between its own stars) stays exact (the partially independent training
conditional of Quinonero-Candela & Rasmussen 2005, with exposures as blocks), solved by
Woodbury's identity: cost ``O(n m^2 + n n_e^2)`` for ``n`` stars, ``m`` inducing points and
``n_e`` stars per exposure, memory ``O(n m)``.
"""

from __future__ import annotations

import dataclasses
import numbers
import warnings
from numbers import Integral, Real

import numpy as np
from scipy.linalg import LinAlgError, blas, cho_factor, cho_solve, lapack, solve_triangular
from scipy.spatial.distance import cdist
from sklearn.exceptions import ConvergenceWarning
from sklearn.utils import check_random_state
from sklearn.utils._param_validation import Interval, StrOptions
from sklearn.utils.validation import check_is_fitted

from ._base import _check_n_samples, _NoiseAwareInterpolator, _query_chunks
from ._exposure_kriging_ml import JITTER, fit_joint_hyperparameters
from ._kriging_co import _CG_MAXITER, CoupledSystem, coregionalization_frame
from ._variogram import _CORRELATIONS

__all__ = ["ExposureKrigingRegressor"]

_NAME = "ExposureKrigingRegressor"
_MIN_ML_STARS = 10


def _correlation(variogram, D, a):
    return _CORRELATIONS[variogram](D / a)


def split_exposure_column(X, column, owner=""):
    """(positions, integer exposure indices) of X whose column ``column`` holds the exposure.

    Parameters
    ----------
    X : ndarray of shape (n, n_features)
    column : int
        Column of the exposure index (negative counts from the end).
    owner : str, default=""
        Prefix of the error messages.

    Returns
    -------
    positions : ndarray of shape (n, n_features - 1)
    exposure : ndarray of shape (n,), int

    Raises
    ------
    ValueError
        With fewer than 2 columns, or when the exposure column is not integer.
    """
    if X.shape[1] < 2:
        raise ValueError(f"{owner}X must hold positions and an exposure column, got "
                         f"n_features = {X.shape[1]}.")
    col = column % X.shape[1]
    exposure = X[:, col]
    if not np.array_equal(exposure, np.round(exposure)):
        raise ValueError(f"{owner}column {col} of X (exposure_column) must hold integer "
                         "exposure indices.")
    return np.delete(X, col, axis=1), exposure.astype(np.int64)


def _factor(K):
    """Lower Cholesky factor of K (overwritten), or a ValueError saying what to do."""
    try:
        return cho_factor(K, lower=True, overwrite_a=True, check_finite=False)
    except LinAlgError:
        raise ValueError(f"{_NAME}: the Kriging covariance matrix is not positive definite "
                         "(stars at the same position in one exposure without noise?). Merge "
                         "such stars or give noise_var.") from None


def _inverse_diagonal(L):
    """diag(K^-1) from the lower Cholesky factor L of K (the upper triangle is ignored)."""
    Linv = np.tril(lapack.dtrtri(L, lower=1)[0])
    return np.einsum("ij,ij->j", Linv, Linv)


class _CoupledExposureSystem(CoupledSystem):
    """``K V`` and the independent targets' bordered solve (constant mean) for co-Kriging
    across exposures: ``K_t = p_t Rs + q_t Ra`` per frame target plus every star's full noise
    covariance ``noise`` (n, T, T); ``factors`` the lower Cholesky factors of ``K_t`` plus the
    diagonal of the noise (and jitter)."""

    def __init__(self, Rs, Ra, p, q, noise, jitter, factors):
        self.Rs, self.Ra, self.p, self.q = Rs, Ra, p, q
        self.noise, self.jitter, self.L = noise, jitter, factors
        self.F = np.ones((Rs.shape[0], 1))
        self.k1 = [cho_solve((L, True), self.F[:, 0], check_finite=False) for L in factors]

    def matvec(self, V):
        return (self.Rs @ V) * self.p + (self.Ra @ V) * self.q + self.jitter * V \
            + np.einsum("itu,iu->it", self.noise, V)

    def project(self, R):
        G, V = np.empty_like(R), np.empty((1, R.shape[1]))
        for t, (L, k1) in enumerate(zip(self.L, self.k1)):
            w = cho_solve((L, True), R[:, t], check_finite=False)
            V[0, t] = w.sum() / k1.sum()
            G[:, t] = w - k1 * V[0, t]
        return G, V


@dataclasses.dataclass(frozen=True)
class _ExposureSolve:
    """The solved Kriging system of the frame's targets: their means (T,), dual coefficients
    ``K^-1 (y - mean)`` (n, T), the diagonal of the bordered system's inverse and the dual
    coefficients of the independent targets (leave-one-out), the conjugate-gradient iterations
    (co-Kriging, else 0) and with inducing points, the grid, its Cholesky factor and
    ``V`` (m, n)."""

    mean: np.ndarray
    dual_coef: np.ndarray
    loo_pdiag: np.ndarray
    dual_loo: np.ndarray
    n_cg_iter: int = 0
    inducing: tuple | None = None


def _diagonal(noise, t, n, p, q):
    """The diagonal added to target ``t``'s covariance: its noise and a jitter."""
    return (0.0 if noise is None else noise[:, t]) + JITTER * (p[t] + q[t]) * np.ones(n)


def _set_target(mean, dual, pdiag, t, k1, ky, y, diag_inv):
    """Mean, dual coefficients and leave-one-out diagonal of target t (written into
    ``mean``, ``dual``, ``pdiag``) from ``K^-1 1``, ``K^-1 y`` and ``diag(K^-1)``."""
    s = k1.sum()
    mean[t] = (k1 @ y) / s
    dual[:, t] = ky - mean[t] * k1  # K^-1 (y - mu)
    pdiag[:, t] = diag_inv - k1 * k1 / s


def _solved_state(solve, p, q, frame):
    """The regressor's attributes of ``solve`` with the frame targets' sills ``p`` (static),
    ``q`` (atmospheric): sills, mean and dual coefficients of each part in the targets' frame
    of ``y``."""
    state = {"_p": p, "_q": q, "mean_": solve.mean, "dual_coef_": solve.dual_coef,
             "_loo_pdiag": solve.loo_pdiag, "_dual_loo": solve.dual_loo,
             "n_cg_iter_": solve.n_cg_iter}
    if solve.inducing is not None:
        state["_Z"], state["_Lu"], state["_V"] = solve.inducing
    dual_static, dual_atm = solve.dual_coef * p, solve.dual_coef * q
    if frame is None:
        return {**state, "static_sill_": p, "atmosphere_sill_": q,
                "static_coregionalization_": np.diag(p),
                "atmosphere_coregionalization_": np.diag(q),
                "_dual_static": dual_static, "_dual_atm": dual_atm}
    A_inv = frame[1]
    static, atmosphere = (A_inv.T * p) @ A_inv, (A_inv.T * q) @ A_inv
    return {**state, "static_coregionalization_": static,
            "atmosphere_coregionalization_": atmosphere,
            "static_sill_": np.diag(static).copy(), "atmosphere_sill_": np.diag(atmosphere).copy(),
            "_dual_static": dual_static @ A_inv, "_dual_atm": dual_atm @ A_inv,
            "mean_": solve.mean @ A_inv}


def _check_positive(value, name, auto=True):
    if auto and isinstance(value, str) and value == "auto":
        return
    if not (isinstance(value, numbers.Real) and not isinstance(value, bool)
            and np.isfinite(value) and value > 0):
        raise ValueError(f"{_NAME}: {name} must be a positive number{' or auto' * auto}, got "
                         f"{value!r}.")


def _check_int(value, name, low):
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < low:
        raise ValueError(f"{_NAME}: {name} must be an integer >= {low}, got {value!r}.")


class ExposureKrigingRegressor(_NoiseAwareInterpolator):
    """Kriging over several exposures: a static pattern plus each exposure's own pattern.

    ``X`` holds the positions and an integer exposure column. The covariance of targets
    ``t`` at stars ``i`` and ``j`` is ``static_sill_[t] R(h / range_) + [same exposure]
    atmosphere_sill_[t] R(h / atmosphere_range_)`` plus each star's measurement noise
    (``noise_var``), with ``h`` the distance between the stars' positions scaled by the
    field's longer side (one factor for both axes, as
    :class:`~sklearn_psf.interpolate.IsotropicScaler`: the longer side spans [0, 1]) and ``R``
    the variogram's correlation. The ranges and sills are fitted by maximum
    likelihood on the stars of all exposures, so the model learns how much of the pattern
    every exposure shares: with no static part it predicts each exposure from its own stars
    (per-exposure Kriging); with no atmospheric part, from all stars as one static field.

    Predictions are the best linear unbiased predictor of the noise-free value at
    ``(position, exposure)``, for exposures seen in ``fit``. Given each star's noise
    covariance across the targets (``fit(X, y, noise_cov=...)``, as :class:`PSFModel` passes
    the coefficients' noise) the targets are co-Kriged: modelled in the frame where they are
    nearly independent, each with its own static and atmospheric sills, and solved with the
    full noise covariances (see Notes).

    Parameters
    ----------
    variogram : {"exponential", "spherical", "gaussian"}, default="exponential"
        Correlation of both parts.
    range : float or "auto", default="auto"
        Range of the static part, in units of the field's longer side;
        "auto": maximum likelihood. The sills are always fitted by maximum likelihood.
    atmosphere_range : float or "auto", default="auto"
        Range of the atmospheric part.
    exposure_column : int, default=-1
        Column of X holding the integer exposure index.
    max_ml_samples : int, default=300
        Maximum likelihood uses at most this many stars: every exposure's when there are few,
        otherwise the same number from each of at most ``max_ml_samples // 40`` exposures
        drawn at random (with ``random_state``), so that pairs of stars within and across
        exposures both inform the split.
    max_exact_samples : int, default=2000
        Up to this many stars the Kriging system is solved exactly; beyond, the static part
        between exposures goes through ``n_inducing`` inducing points (see Notes).
    n_inducing : int, default=900
        Inducing points on a grid of the same number of points along each axis over the
        stars' bounding box (rounded to a square number).
    random_state : int, RandomState instance or None, default=0
        Seed of the maximum-likelihood subset.

    Attributes
    ----------
    range_, atmosphere_range_ : float
        Fitted ranges (unit-square units).
    static_sill_, atmosphere_sill_ : ndarray of shape (n_targets,)
        Fitted sills of the two parts (of each target; with ``noise_cov``, the diagonals of
        ``static_coregionalization_`` and ``atmosphere_coregionalization_``).
    static_coregionalization_ : ndarray of shape (n_targets, n_targets)
        Signal covariance across the targets of the static part (diagonal without
        ``noise_cov``).
    atmosphere_coregionalization_ : ndarray of shape (n_targets, n_targets)
        The same for the atmospheric part.
    n_cg_iter_ : int
        Conjugate-gradient iterations of the co-Kriging solve (0 without ``noise_cov`` or
        in the inducing-point mode).
    mean_ : ndarray of shape (n_targets,)
        Generalised-least-squares mean.
    exposures_ : ndarray of int
        Exposures seen in fit.
    exact_ : bool
        Whether the Kriging system was solved exactly.
    log_likelihood_ : float
        Maximum log-likelihood (on the maximum-likelihood subset).
    noise_var_ : ndarray of shape (n_stars, n_targets) or None
    X_fit_ : ndarray of shape (n_stars, n_features)
        The stars given to fit (positions and exposure), rows of :meth:`loo_predict`.
    n_features_in_ : int

    Notes
    -----
    Above ``max_exact_samples`` the prior covariance is replaced by one that is exact within
    each exposure and goes through inducing points ``u`` between exposures:
    ``K ~ Q + blockdiag_e(K_ee - Q_ee + A_ee + N_e)`` with ``Q = p K_xu K_uu^-1 K_ux`` (the
    partially independent training conditional, Quinonero-Candela & Rasmussen 2005, with
    exposures as blocks); ``K^-1`` follows from Woodbury's identity with one factorisation per
    exposure block and one of size ``m = n_inducing``. Predictions use the same covariance:
    exact towards the query's own exposure, through the inducing points towards the others.

    The closed-form leave-one-out of :meth:`loo_predict` is Dubrule's (1983) with the
    generalised-least-squares mean, in both modes.

    Co-Kriging (``noise_cov``): with ``A`` solving the generalised eigenproblem of the
    targets' sample covariance against the stars' mean noise covariance, the frame ``z = y A``
    has nearly independent targets; each gets sills ``p_t``, ``q_t`` (the ranges are shared),
    so that the targets' signal covariance is ``A^-T diag(p) A^-1 Rs + A^-T diag(q) A^-1 Ra``.
    The exact mode solves the system with every star's full noise covariance (the frame's
    off-diagonal noise included) by preconditioned conjugate gradients; the inducing-point
    mode and the leave-one-out leave the frame's off-diagonal noise out.

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.interpolate import ExposureKrigingRegressor
    >>> rng = np.random.default_rng(0)
    >>> xy = rng.uniform(0, 1000, (120, 2))
    >>> exposure = np.repeat([0, 1, 2], 40)
    >>> static = np.sin(xy[:, 0] / 300.0)               # shared by every exposure
    >>> atmosphere = np.array([0.3, -0.2, 0.1])[exposure] * np.cos(xy[:, 1] / 200.0)
    >>> X = np.column_stack([xy, exposure])
    >>> reg = ExposureKrigingRegressor().fit(X, static + atmosphere,
    ...                                      noise_var=np.full(120, 1e-4))
    >>> bool(reg.static_sill_[0] > reg.atmosphere_sill_[0])
    True
    >>> reg.predict([[500.0, 500.0, 1]]).shape
    (1,)
    """

    _parameter_constraints: dict = {
        "variogram": [StrOptions(set(_CORRELATIONS))],
        "range": [Interval(Real, 0, np.inf, closed="neither"), StrOptions({"auto"})],
        "atmosphere_range": [Interval(Real, 0, np.inf, closed="neither"),
                             StrOptions({"auto"})],
        "exposure_column": [Interval(Integral, None, None, closed="neither")],
        "max_ml_samples": [Interval(Integral, _MIN_ML_STARS, None, closed="left")],
        "max_exact_samples": [Interval(Integral, 0, None, closed="left")],
        "n_inducing": [Interval(Integral, 4, None, closed="left")],
        "random_state": ["random_state"],
    }

    def __init__(self, variogram="exponential", range="auto", atmosphere_range="auto",
                 exposure_column=-1, max_ml_samples=300, max_exact_samples=2000,
                 n_inducing=900, random_state=0):
        self.variogram = variogram
        self.range = range
        self.atmosphere_range = atmosphere_range
        self.exposure_column = exposure_column
        self.max_ml_samples = max_ml_samples
        self.max_exact_samples = max_exact_samples
        self.n_inducing = n_inducing
        self.random_state = random_state

    # ------------------------------------------------------------------ input
    def _split(self, X):
        """Query positions (scaled as the stars') and exposures, known to the fit."""
        pos, exposure = split_exposure_column(X, self.exposure_column, f"{_NAME}: ")
        unknown = np.setdiff1d(exposure, self.exposures_)
        if len(unknown):
            raise ValueError(f"{_NAME}: exposures {unknown.tolist()} were not in the fit: "
                             "a model predicts only the exposures its stars came from.")
        return (pos - self._lo) / self._span, exposure

    def _check_params(self):
        _check_positive(self.range, "range")
        _check_positive(self.atmosphere_range, "atmosphere_range")
        _check_int(self.max_ml_samples, "max_ml_samples", _MIN_ML_STARS)
        _check_int(self.max_exact_samples, "max_exact_samples", 0)
        _check_int(self.n_inducing, "n_inducing", 4)

    # ------------------------------------------------------------------ fit
    _joint_noise = True  # fit(noise_cov=...) is co-Kriging
    _per_axis_scaling = False  # set by the reader of model files of formats 1-3

    def _fit(self, X, Y, noise, noise_cov=None):
        self._check_params()
        _check_n_samples(_NAME, X.shape[0], 3, "")
        self._set_fitted({})  # a previous fit's large arrays go first
        pos, exposure = split_exposure_column(X, self.exposure_column, f"{_NAME}: ")
        lo = pos.min(axis=0)
        span = pos.max(axis=0) - lo
        if self._per_axis_scaling:  # model files of formats 1-3: each axis to [0, 1]
            scale = np.where(span > 0, span, 1.0)
        else:  # one factor, the longer side (as IsotropicScaler): the field's own distances
            scale = float(span.max()) if span.max() > 0 else 1.0
        extent = np.where(span > 0, span / scale, 1.0)
        U = (pos - lo) / scale
        n, T = Y.shape
        exposures = np.unique(exposure)
        noise_var, frame, Z, noise_z = noise, None, Y, None
        if noise_cov is not None:  # co-Kriging in the frame of nearly independent targets
            A, A_inv, noise_z = coregionalization_frame(Y, noise_cov)
            frame, Z = (A, A_inv), Y @ A
            noise = np.einsum("itt->it", noise_z).copy()
            noise_var = np.einsum("itt->it", noise_cov).copy()
        restored = self._held_state_once()
        if restored is None:
            fit = self._fit_hyperparameters(U, exposure, exposures, Z, noise)
            log_likelihood = fit["log_likelihood"]
            if frame is not None:  # the likelihood of y = z A^-1: the frame's Jacobian
                log_likelihood += fit["n_stars"] * np.linalg.slogdet(frame[0])[1]
        else:
            fit = {"range": restored["range_"],
                   "atmosphere_range": restored["atmosphere_range_"],
                   "static_sill": np.asarray(restored["static_sill"], dtype=np.float64),
                   "atmosphere_sill": np.asarray(restored["atmosphere_sill"],
                                                 dtype=np.float64)}
            log_likelihood = restored["log_likelihood_"]
        exact = n <= self.max_exact_samples
        if exact:
            solve = self._fit_exact(U, exposure, Z, noise, noise_z, fit)
        else:
            solve = self._fit_inducing(U, exposure, Z, noise, noise_z, fit, extent)
        self._set_fitted({
            "_lo": lo, "_span": scale, "_extent": extent, "exposures_": exposures,
            "noise_var_": noise_var, "_frame": frame, "range_": fit["range"],
            "atmosphere_range_": fit["atmosphere_range"], "log_likelihood_": log_likelihood,
            "X_fit_": X, "_U_fit": U, "_e_fit": exposure, "_z_fit": Z, "exact_": exact,
            **_solved_state(solve, fit["static_sill"], fit["atmosphere_sill"], frame),
        })
        return self

    def _ml_subset(self, exposure, exposures):
        n = len(exposure)
        if n <= self.max_ml_samples:
            return np.arange(n)
        rng = check_random_state(self.random_state)
        groups = [np.flatnonzero(exposure == e) for e in exposures]
        n_exp = min(len(groups), max(2, self.max_ml_samples // 40))
        chosen = np.sort(rng.choice(len(groups), n_exp, replace=False))
        pool = np.concatenate([groups[g] for g in chosen])
        if len(pool) <= self.max_ml_samples:
            return pool
        per = self.max_ml_samples // n_exp
        return np.sort(np.concatenate([rng.choice(groups[g], min(per, len(groups[g])),
                                                  replace=False) for g in chosen]))

    def _fit_hyperparameters(self, U, exposure, exposures, Y, noise):
        """Ranges and sills (of ``Y``'s targets) by maximum likelihood on a subset of the
        stars: :func:`fit_joint_hyperparameters`'s result, with the subset's size
        (``n_stars``)."""
        sub = self._ml_subset(exposure, exposures)
        _check_n_samples(_NAME, len(sub), _MIN_ML_STARS,
                         "to fit the sills by maximum likelihood")
        fit = fit_joint_hyperparameters(
            U[sub], exposure[sub], Y[sub], None if noise is None else noise[sub],
            self.variogram, range_=self.range, atmosphere_range=self.atmosphere_range)
        return {**fit, "n_stars": len(sub)}

    def _fit_exact(self, U, exposure, Y, noise, noise_z, fit):
        """The :class:`_ExposureSolve` of all the stars (``fit``: ranges and sills)."""
        n, T = Y.shape
        p, q = fit["static_sill"], fit["atmosphere_sill"]
        D = cdist(U, U)
        Rs = _correlation(self.variogram, D, fit["range"])
        Ra = _correlation(self.variogram, D, fit["atmosphere_range"])
        Ra *= exposure[:, None] == exposure[None, :]
        del D
        mean, dual, pdiag = np.empty(T), np.empty((n, T)), np.empty((n, T))
        rhs = np.column_stack([np.ones(n), Y])
        factors = []
        for t in range(T):
            K = p[t] * Rs + q[t] * Ra
            K[np.diag_indices(n)] += _diagonal(noise, t, n, p, q)
            L = _factor(K)
            sol = cho_solve(L, rhs[:, [0, t + 1]], check_finite=False)
            _set_target(mean, dual, pdiag, t, sol[:, 0], sol[:, 1], Y[:, t],
                        _inverse_diagonal(L[0]))
            if noise_z is not None:  # (Fortran-ordered: solves without copies)
                factors.append(L[0])
        if noise_z is None:
            return _ExposureSolve(mean, dual, pdiag, dual)
        # co-Kriging: the full noise covariances, the independent targets as preconditioner
        system = _CoupledExposureSystem(Rs, Ra, p, q, noise_z, JITTER * (p + q), factors)
        alpha, beta, n_cg_iter = system.solve_gls(Y)
        if n_cg_iter >= _CG_MAXITER:
            warnings.warn(f"{_NAME}: the co-Kriging system did not converge in {_CG_MAXITER} "
                          "conjugate-gradient iterations (noise covariances far from one "
                          "another's shape?); predictions may be inaccurate.",
                          ConvergenceWarning, stacklevel=4)
        return _ExposureSolve(beta[0].copy(), alpha, pdiag, dual, n_cg_iter)

    # -- inducing points (PITC over exposure blocks)
    def _inducing_grid(self, d, extent):
        g = max(2, int(round(self.n_inducing ** (1.0 / d))))
        axes = [np.linspace(0.0, e, g) for e in extent]
        return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, d)

    def _fit_inducing(self, U, exposure, Y, noise, noise_z, fit, extent):
        """The :class:`_ExposureSolve` with the static part across exposures through a grid
        of inducing points over ``extent`` (``fit``: ranges and sills)."""
        n, T = Y.shape
        p_all, q_all = fit["static_sill"], fit["atmosphere_sill"]
        range_, atmosphere_range = fit["range"], fit["atmosphere_range"]
        Z = self._inducing_grid(U.shape[1], extent)
        m = len(Z)
        Kuu = _correlation(self.variogram, cdist(Z, Z), range_)
        Kuu[np.diag_indices(m)] += 1e-8
        Lu = cho_factor(Kuu, lower=True)[0]
        V = solve_triangular(Lu, _correlation(self.variogram, cdist(Z, U), range_),
                             lower=True, check_finite=False)  # (m, n): Q = p V^T V
        blocks = [np.flatnonzero(exposure == e) for e in np.unique(exposure)]
        # per exposure: static minus its inducing-point part, and the atmosphere (unit sills)
        parts = []
        for idx in blocks:
            D = cdist(U[idx], U[idx])
            Vb = V[:, idx]
            parts.append((_correlation(self.variogram, D.copy(), range_) - Vb.T @ Vb,
                          _correlation(self.variogram, D, atmosphere_range)))
        mean, dual, pdiag = np.empty(T), np.empty((n, T)), np.empty((n, T))
        VT = np.asfortranarray(V.T)  # (n, m): rows of each block contiguous per column
        G = np.empty((n, m), order="F")  # L_e^-1 V_e^T, block by block
        for t in range(T):
            p, q = p_all[t], q_all[t]
            diag = _diagonal(noise, t, n, p_all, q_all)
            rhs = np.column_stack([np.ones(n), Y[:, t]])
            r, lam_diag, factors = np.empty((n, 2)), np.empty(n), []
            for idx, (S, A) in zip(blocks, parts):
                B = p * S + q * A
                B[np.diag_indices(len(idx))] += diag[idx]
                Lb = _factor(B)[0]
                factors.append(Lb)
                G[idx] = solve_triangular(Lb, VT[idx], lower=True, check_finite=False)
                r[idx] = solve_triangular(Lb, rhs[idx], lower=True, check_finite=False)
                lam_diag[idx] = _inverse_diagonal(Lb)
            M = blas.dsyrk(1.0, G, trans=1, lower=1)
            # Woodbury: K^-1 = L^-T (I - G M^-1 G^T) L^-1 with L = blockdiag(L_e),
            # G = L^-1 V^T and M = I / p + G^T G (lower triangle)
            M[np.diag_indices(m)] += 1.0 / p
            Lm = _factor(M)
            z = r - G @ cho_solve(Lm, G.T @ r, check_finite=False)
            sol = np.empty_like(z)
            for idx, Lb in zip(blocks, factors):
                sol[idx] = solve_triangular(Lb, z[idx], lower=True, trans=1, check_finite=False)
                G[idx] = solve_triangular(Lb, G[idx], lower=True, trans=1, check_finite=False)
            # leave-one-out diagonal: diag(K^-1) = diag(L^-T L^-1) - |Lm^-1 (L^-T G)_i|^2, in
            # single precision (a variance for the outlier test, not a solution)
            W = solve_triangular(Lm[0].astype(np.float32), G.T.astype(np.float32), lower=True,
                                 check_finite=False)
            diag_inv = lam_diag - np.einsum("ij,ij->j", W, W, dtype=np.float64)
            _set_target(mean, dual, pdiag, t, sol[:, 0], sol[:, 1], Y[:, t], diag_inv)
        return _ExposureSolve(mean, dual, pdiag, dual, inducing=(Z, Lu, V))

    # ------------------------------------------------------------------ predict
    def _predict(self, X):
        U, exposure = self._split(X)
        out = np.empty((len(U), self.dual_coef_.shape[1]))
        if self.exact_:
            for sl in _query_chunks(len(U), len(self._U_fit)):
                out[sl] = self._predict_exact(U[sl], exposure[sl])
            return out
        # the static part through the inducing points: Q(x, X) p alpha = V_x^T (V p alpha)
        static_u = self._V @ self._dual_static  # (m, T)
        for e in np.unique(exposure):
            rows = np.flatnonzero(exposure == e)
            stars = np.flatnonzero(self._e_fit == e)
            for sl in _query_chunks(len(rows), max(len(stars), len(self._Z))):
                out[rows[sl]] = self._predict_inducing(U[rows[sl]], stars, static_u)
        return out

    def _predict_exact(self, U, exposure):
        D = cdist(U, self._U_fit)
        same = exposure[:, None] == self._e_fit[None, :]
        Ra = _correlation(self.variogram, D.copy(), self.atmosphere_range_) * same
        Rs = _correlation(self.variogram, D, self.range_)
        return self.mean_ + Ra @ self._dual_atm + Rs @ self._dual_static

    def _predict_inducing(self, U, stars, static_u):
        """Queries of one exposure: exact towards its own stars, inducing points beyond."""
        D = cdist(U, self._U_fit[stars])
        Vq = solve_triangular(self._Lu, _correlation(self.variogram, cdist(self._Z, U),
                                                     self.range_),
                              lower=True, check_finite=False)  # (m, q)
        Rs = _correlation(self.variogram, D.copy(), self.range_) - Vq.T @ self._V[:, stars]
        Ra = _correlation(self.variogram, D, self.atmosphere_range_)
        return (self.mean_ + Vq.T @ static_u + Rs @ self._dual_static[stars]
                + Ra @ self._dual_atm[stars])

    def loo_predict(self, return_std=False):
        """Leave-one-out predictions at the stars, in closed form.

        Parameters
        ----------
        return_std : bool, default=False
            Also return the standard deviation of ``y_i - prediction`` (the Kriging variance
            at the star plus its own noise).

        Returns
        -------
        y_loo : ndarray of shape (n_stars,) or (n_stars, n_targets)
        y_std : ndarray, same shape (only with ``return_std=True``)

        Notes
        -----
        With ``noise_cov`` (co-Kriging) it is that of the independent targets of the frame
        the system is solved in (the frame's off-diagonal noise left out).
        """
        pred = self._z_fit - self._dual_loo / self._loo_pdiag
        var = 1.0 / self._loo_pdiag
        if self._frame is not None:
            pred, var = pred @ self._frame[1], var @ self._frame[1] ** 2
        pred = self._format_output(pred)
        if not return_std:
            return pred
        return pred, self._format_output(np.sqrt(var))

    # ------------------------------------------------------------------ persistence
    # (the protocol of sklearn_psf._persist: the state is the hyperparameters the fit chose;
    # restored, the next fit solves the system with them held, without the likelihood)
    def _get_state(self):
        check_is_fitted(self)
        return {"range_": float(self.range_), "atmosphere_range_": float(self.atmosphere_range_),
                "static_sill": np.asarray(self._p, float),
                "atmosphere_sill": np.asarray(self._q, float),
                "log_likelihood_": float(self.log_likelihood_),
                "per_axis_scaling": bool(self._per_axis_scaling)}

    def _set_state(self, state):
        if state.get("per_axis_scaling"):
            self._per_axis_scaling = True
        return super()._set_state(state)
