"""Ordinary Kriging with bounded variograms, one factorisation for all targets."""

from __future__ import annotations

import numbers

import numpy as np
from scipy.linalg import LinAlgError, cho_factor, cho_solve, solve_triangular
from scipy.spatial import cKDTree
from scipy.spatial.distance import cdist

from ._base import (
    _BaseInterpolator,
    _check_n_neighbors,
    _check_n_samples,
    _merge_duplicates,
    _query_chunks,
)

#: Local Kriging: queries per batch of stacked (k+1, k+1) bordered systems are bounded so
#: that the batch's arrays stay around this many float64 elements (~16 MB).
_LOCAL_BATCH_ELEMENTS = 2**21


def _exp_corr(r):
    """exp(-r), computed in place on r (a fresh array owned by the caller)."""
    np.negative(r, out=r)
    return np.exp(r, out=r)


def _sph_corr(r):
    """1 - 1.5 r + 0.5 r^3 for r < 1, 0 beyond; in place on r."""
    np.minimum(r, 1.0, out=r)
    return 1.0 - r * (1.5 - 0.5 * r * r)


def _gau_corr(r):
    """exp(-r^2), in place on r."""
    np.square(r, out=r)
    np.negative(r, out=r)
    return np.exp(r, out=r)


#: correlation function rho(h / a) of each model: gamma = sill (1 - (1 - nugget) rho)
_CORRELATIONS = {"exponential": _exp_corr, "spherical": _sph_corr, "gaussian": _gau_corr}


def _variogram(model, h, a, nugget, sill):
    h = np.asarray(h, dtype=np.float64)
    rho = _CORRELATIONS[model](h / a)
    gamma = sill * (1.0 - (1.0 - nugget) * rho)
    return np.where(h > 0, gamma, 0.0)


def exponential_variogram(h, range, nugget=0.0, sill=1.0):
    """Exponential variogram ``sill ((1 - nugget)(1 - exp(-h / range)) + nugget)``, 0 at h = 0.

    Parameters
    ----------
    h : array-like
        Distances (>= 0).
    range : float
        Range ``a`` in the units of ``h``.
    nugget : float, default=0.0
        Nugget as a fraction of the sill, in [0, 1].
    sill : float, default=1.0
        Sill (value of the variogram at infinite distance).

    Returns
    -------
    gamma : ndarray
        Variogram values, the shape of ``h``.

    Examples
    --------
    >>> from sklearn_psf.interpolate import exponential_variogram
    >>> exponential_variogram([0.0, 1.0], range=1.0, nugget=0.5, sill=2.0).round(4)
    array([0.    , 1.6321])
    """
    return _variogram("exponential", h, range, nugget, sill)


def spherical_variogram(h, range, nugget=0.0, sill=1.0):
    """Spherical variogram ``sill ((1 - nugget)(1.5 h/a - 0.5 (h/a)^3) + nugget)`` for
    0 < h < a, ``sill`` beyond, 0 at h = 0 (``a = range``).

    Parameters
    ----------
    h : array-like
        Distances (>= 0).
    range : float
        Range ``a``: the variogram reaches the sill at ``h = a``.
    nugget : float, default=0.0
        Nugget as a fraction of the sill, in [0, 1].
    sill : float, default=1.0
        Sill.

    Returns
    -------
    gamma : ndarray
        Variogram values, the shape of ``h``.

    Examples
    --------
    >>> from sklearn_psf.interpolate import spherical_variogram
    >>> spherical_variogram([0.0, 0.5, 2.0], range=1.0).round(4)
    array([0.    , 0.6875, 1.    ])
    """
    return _variogram("spherical", h, range, nugget, sill)


def gaussian_variogram(h, range, nugget=0.0, sill=1.0):
    """Gaussian variogram ``sill ((1 - nugget)(1 - exp(-(h / range)^2)) + nugget)``, 0 at h = 0.

    Very smooth fields; the Kriging system becomes ill-conditioned when stars are much
    closer than ``range`` (add a small nugget then).

    Parameters
    ----------
    h : array-like
        Distances (>= 0).
    range : float
        Range ``a`` in the units of ``h``.
    nugget : float, default=0.0
        Nugget as a fraction of the sill, in [0, 1].
    sill : float, default=1.0
        Sill.

    Returns
    -------
    gamma : ndarray
        Variogram values, the shape of ``h``.

    Examples
    --------
    >>> from sklearn_psf.interpolate import gaussian_variogram
    >>> gaussian_variogram([0.0, 1.0], range=1.0).round(4)
    array([0.    , 0.6321])
    """
    return _variogram("gaussian", h, range, nugget, sill)


#: Variogram models by name: ``f(h, range, nugget=0.0, sill=1.0) -> gamma``.
variogram_models = {
    "exponential": exponential_variogram,
    "spherical": spherical_variogram,
    "gaussian": gaussian_variogram,
}


class KrigingRegressor(_BaseInterpolator):
    """Ordinary Kriging, as in the paper (bordered system with the unbiasedness row).

    The prediction at ``x`` is ``sum_i lambda_i y_i`` with ``sum_i lambda_i = 1`` and
    weights minimising the variance under the variogram model. Each target column
    ``t`` has its own sill ``sigma_t^2`` (its variance over the stars, as in the paper)
    while range and nugget (a fraction of the sill) are shared, so the variogram
    divided by the sill is the same for all targets and a single factorisation of the
    Kriging system serves all of them.

    Parameters
    ----------
    variogram : {"exponential", "spherical", "gaussian"}, default="exponential"
        Variogram model, see :data:`variogram_models`.
    range : float, default=0.5
        Range ``a`` in the units of ``X`` (0.5 is the paper's value for positions in the
        unit square: use ``make_pipeline(MinMaxScaler(), KrigingRegressor())``).
    nugget : float, default=0.0
        Nugget as a fraction of the sill, in [0, 1].
    n_neighbors : int or None, default=None
        ``None``: exact Kriging with all stars (one factorisation of the ``n_stars``
        system, cost ``O(n_stars^3)`` and memory ``O(n_stars^2)``). An integer ``k``:
        local Kriging in a moving neighbourhood: each query is predicted by ordinary
        Kriging from its ``k`` nearest stars only (found with
        :class:`scipy.spatial.cKDTree`; small bordered systems solved in batches), cost
        ``O(n_queries k^3)``, for large numbers of stars (``10^4`` and more). Each
        neighbourhood has its own unbiasedness constraint (a local mean); the sill of each
        target stays the variance over all stars. ``k >= n_stars`` is exact Kriging with
        a per-query solve (slower than ``None``).

    Attributes
    ----------
    X_fit_ : ndarray of shape (n_stars, n_features)
        Distinct star positions.
    sill_ : ndarray of shape (n_targets,)
        Variance of each target over the stars.
    mean_ : ndarray of shape (n_targets,)
        Generalised-least-squares estimate of each target's mean (exact mode; in local
        mode the mean of the targets over the stars, for reference only).
    dual_coef_ : ndarray of shape (n_stars, n_targets)
        ``C^-1 (y - mean_)`` with ``C`` the normalised covariance matrix of the stars
        (exact mode only).
    y_fit_ : ndarray of shape (n_stars, n_targets)
        Star values (local mode only).
    n_features_in_ : int
        Number of features seen during fit.

    Notes
    -----
    For bounded variograms, ordinary Kriging with the bordered system
    ``[G 1; 1^T 0]`` equals simple Kriging with the generalised-least-squares mean and
    the covariance ``C = 1 - G`` (normalised by the sill). This implementation
    factorises ``C`` once (Cholesky) and predicts ``mean + c(x)^T C^-1 (y - mean)`` in
    chunks of queries; the Kriging variance is
    ``sill (1 - c^T C^-1 c + (1 - 1^T C^-1 c)^2 / 1^T C^-1 1)``.

    In local mode (``n_neighbors=k``) each query solves the bordered system
    ``[C_k 1; 1^T 0] [lambda; mu] = [c_k; 1]`` of its ``k`` nearest stars; the prediction
    is ``lambda^T y_k`` and the variance ``sill (1 - lambda^T c_k - mu)``.

    The variogram is 0 at distance 0, so a query exactly on a star returns that star's
    value (and standard deviation 0) even with a nugget.

    Between two different stars the nugget applies even at distance 0 (they are
    distinct measurements), so with ``nugget > 0`` stars sharing a position are kept.
    With ``nugget = 0`` they make the system singular: they are then merged (values
    averaged) with a :class:`DuplicateStarsWarning`. If the
    factorisation still fails (near-duplicates), a ``ValueError`` suggests a nugget.

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.interpolate import KrigingRegressor
    >>> rng = np.random.default_rng(0)
    >>> X = rng.uniform(size=(40, 2))
    >>> y = np.column_stack([np.sin(4 * X[:, 0]), X[:, 1] ** 2])
    >>> reg = KrigingRegressor(range=0.5).fit(X, y)
    >>> pred, std = reg.predict(X[:2], return_std=True)
    >>> bool(np.allclose(pred, y[:2])), bool(np.allclose(std, 0))
    (True, True)
    >>> reg.predict([[0.5, 0.5]]).shape
    (1, 2)

    Local Kriging from the 20 nearest stars of each query:

    >>> local = KrigingRegressor(range=0.5, n_neighbors=20).fit(X, y)
    >>> bool(np.allclose(local.predict(X[:2]), y[:2]))
    True
    """

    def __init__(self, variogram="exponential", range=0.5, nugget=0.0, n_neighbors=None):
        self.variogram = variogram
        self.range = range
        self.nugget = nugget
        self.n_neighbors = n_neighbors

    def _correlation(self, D):
        """(1 - nugget) rho(D / a), overwriting D (a fresh distance matrix)."""
        D *= 1.0 / self.range
        c = _CORRELATIONS[self.variogram](D)
        if self.nugget:
            c *= 1.0 - self.nugget
        return c

    def _star_covariance(self, X):
        # Between two different stars the nugget applies even at distance 0 (distinct
        # measurements at one position, as PyKrige does); only the diagonal is 1.
        C = self._correlation(cdist(X, X))
        np.fill_diagonal(C, 1.0)
        return C

    def _query_covariance(self, Xq):
        """Covariance of queries with stars (1 at distance 0) and the on-star rows."""
        D = cdist(Xq, self.X_fit_)
        on_star = np.flatnonzero(D.min(axis=1) == 0)
        zero = D[on_star] == 0
        c = self._correlation(D)
        c[on_star] = np.where(zero, 1.0, c[on_star])
        return c, on_star

    def _fit(self, X, Y):
        name = "KrigingRegressor"
        if self.variogram not in variogram_models:
            raise ValueError(
                f"{name}: variogram must be one of {sorted(variogram_models)}, "
                f"got {self.variogram!r}."
            )
        a, nug = self.range, self.nugget
        if not isinstance(a, numbers.Real) or not np.isfinite(a) or a <= 0:
            raise ValueError(f"{name}: range must be a finite number > 0, got {a!r}.")
        if not isinstance(nug, numbers.Real) or not 0 <= nug <= 1:
            raise ValueError(f"{name}: nugget must be a number in [0, 1], got {nug!r}.")
        if nug == 0:
            X, Y = _merge_duplicates(
                X, Y, owner=name, reason="with nugget=0 the Kriging system would be singular."
            )
        _check_n_samples(name, X.shape[0], 2, "(distinct positions)")
        k = _check_n_neighbors(name, self.n_neighbors)
        self.sill_ = Y.var(axis=0)
        self.X_fit_ = X
        if k is not None:
            self._fit_local(X, Y, k)
            return
        for attr in ("y_fit_", "_tree", "_k"):
            self.__dict__.pop(attr, None)
        C = self._star_covariance(X)
        try:
            # C is symmetric: its transpose is the same matrix in Fortran order, which LAPACK
            # factorises in place (no copy of an n_stars^2 array)
            factor = cho_factor(C.T, lower=True, overwrite_a=True, check_finite=False)
        except LinAlgError:
            raise ValueError(
                f"{name}: the Kriging covariance matrix is not positive definite (stars "
                "almost at the same position relative to the range, or a variogram invalid "
                "in this dimension). Add a small nugget (e.g. nugget=1e-6), lower the range, "
                "or merge close stars."
            ) from None
        ones = np.ones(X.shape[0])
        w = cho_solve(factor, ones, check_finite=False)
        self._one_c_one = float(ones @ w)
        self.mean_ = (w @ Y) / self._one_c_one
        self.dual_coef_ = cho_solve(factor, Y - self.mean_, check_finite=False)
        # The lower triangle holds L; the upper one is never read (no tril copy: at 10^4
        # stars that would be another 800 MB).
        self._chol = factor[0]
        self._c_inv_one = w

    def _fit_local(self, X, Y, k):
        for attr in ("dual_coef_", "_chol", "_c_inv_one", "_one_c_one"):
            self.__dict__.pop(attr, None)
        self.y_fit_ = Y
        self.mean_ = Y.mean(axis=0)
        self._k = min(k, X.shape[0])
        self._tree = cKDTree(X)

    def predict(self, X, return_std=False):
        """Kriging prediction, and optionally its standard deviation.

        Parameters
        ----------
        X : array-like of shape (n_queries, n_features)
            Query positions.
        return_std : bool, default=False
            Also return the Kriging standard deviation of each target.

        Returns
        -------
        y_pred : ndarray of shape (n_queries,) or (n_queries, n_targets)
            Predictions, 1-D when fitted on a 1-D ``y``.
        y_std : ndarray, same shape as ``y_pred``
            Kriging standard deviation (only with ``return_std=True``).
        """
        X = self._validate_predict_data(X)
        if getattr(self, "_tree", None) is not None:
            pred, var = self._predict_local(X, return_std)
        else:
            pred, var = self._predict_exact(X, return_std)
        pred = self._format_output(pred)
        if not return_std:
            return pred
        std = np.sqrt(np.clip(var, 0.0, None)[:, None] * self.sill_)
        return pred, self._format_output(std)

    def _predict_exact(self, X, return_std):
        m, T = X.shape[0], self.dual_coef_.shape[1]
        pred = np.empty((m, T))
        var = np.empty(m) if return_std else None
        for sl in _query_chunks(m, self.X_fit_.shape[0]):
            c, on_star = self._query_covariance(X[sl])
            np.matmul(c, self.dual_coef_, out=pred[sl])
            pred[sl] += self.mean_
            if return_std:
                u = 1.0 - c @ self._c_inv_one
                # c^T C^-1 c = |L^-1 c|^2: one triangular solve on the chunk, in place on
                # c.T (Fortran-contiguous, so LAPACK needs no copy; c is not used after).
                v = solve_triangular(self._chol, c.T, lower=True, check_finite=False,
                                     overwrite_b=True)
                q = np.einsum("ij,ij->j", v, v)
                var[sl] = 1.0 - q + u * u / self._one_c_one
                var[sl][on_star] = 0.0  # exactly 0 on a star, not rounding noise
        return pred, var

    def _predict_local(self, X, return_std):
        m, T = X.shape[0], self.y_fit_.shape[1]
        k = self._k
        pred = np.empty((m, T))
        var = np.empty(m) if return_std else None
        batch = int(max(1, _LOCAL_BATCH_ELEMENTS // ((k + 1) ** 2 + k * T)))
        Xs, Ys = self.X_fit_, self.y_fit_
        for start in range(0, m, batch):
            sl = slice(start, min(start + batch, m))
            dist, idx = self._tree.query(X[sl], k=k)
            if k == 1:
                dist, idx = dist[:, None], idx[:, None]
            b = idx.shape[0]
            P = Xs[idx]  # (b, k, d) neighbour positions
            # bordered systems [C 1; 1^T 0] of every query's neighbourhood, stacked
            A = np.empty((b, k + 1, k + 1))
            D = A[:, :k, :k]
            diff = P[:, :, None, :] - P[:, None, :, :]
            np.sqrt(np.einsum("bijd,bijd->bij", diff, diff), out=D)
            del diff
            D[...] = self._correlation(D)
            diag = np.arange(k)
            A[:, diag, diag] = 1.0  # distinct stars: nugget between them, 1 on the diagonal
            A[:, :k, k] = 1.0
            A[:, k, :k] = 1.0
            A[:, k, k] = 0.0
            rhs = np.empty((b, k + 1))
            on = dist == 0
            rhs[:, :k] = self._correlation(dist.copy())
            rhs[:, :k][on] = 1.0  # on a star: covariance 1 (the variogram is 0 there)
            rhs[:, k] = 1.0
            try:
                sol = np.linalg.solve(A, rhs[:, :, None])[:, :, 0]
            except np.linalg.LinAlgError:
                raise ValueError(
                    "KrigingRegressor: a local Kriging system is singular (stars almost at "
                    "the same position relative to the range). Add a small nugget (e.g. "
                    "nugget=1e-6) or merge close stars."
                ) from None
            lam = sol[:, :k]
            pred[sl] = np.einsum("bk,bkt->bt", lam, Ys[idx])
            if return_std:
                v = 1.0 - np.einsum("bk,bk->b", lam, rhs[:, :k]) - sol[:, k]
                v[on.any(axis=1)] = 0.0
                var[sl] = v
        return pred, var

    def _predict(self, X):  # pragma: no cover - predict is overridden
        raise NotImplementedError
