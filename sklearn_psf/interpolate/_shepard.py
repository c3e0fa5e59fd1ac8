"""Shepard (inverse distance weighting) interpolation."""

from __future__ import annotations

from numbers import Integral, Real

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.distance import cdist
from sklearn.utils._param_validation import Interval

from ._base import _BaseInterpolator, _check_n_neighbors, _check_n_samples, _query_chunks

_LOCAL_BATCH = 65536  # queries per cKDTree batch in local mode


class ShepardRegressor(_BaseInterpolator):
    """Shepard interpolation: inverse-distance weighted mean of all stars.

    ``y(x) = sum_i y_i r_i^-p / sum_i r_i^-p`` with ``r_i = |x - x_i|`` over all stars.
    A query exactly on a star returns that star's value (the mean value of the stars
    there, if several share the position). Queries are processed in chunks, so memory
    stays bounded for any number of queries.

    With ``n_neighbors=k``, the modified Shepard method (Franke & Nielson 1980) over the
    ``k`` nearest stars (found with :class:`scipy.spatial.cKDTree`): weights
    ``((R - r_i)_+ / (R r_i))^p`` with ``R`` the distance to the ``(k+1)``-th nearest
    star, so that a star's weight falls continuously to 0 as it leaves the neighbourhood.
    The cost is ``O(n_queries k log n_stars)`` instead of ``O(n_queries n_stars)``. When
    ``k >= n_stars`` (no ``(k+1)``-th star, ``R`` infinite) the weights are ``r_i^-p``: the
    global Shepard interpolation. Where all ``k`` neighbours are exactly at distance ``R``
    (ties, e.g. on a grid), their plain ``r_i^-p`` weights are used.

    Parameters
    ----------
    power : float, default=3.0
        Exponent ``p`` of the weights; the paper finds ``p >= 3`` works.
    n_neighbors : int or None, default=None
        ``None``: all stars (the paper's Shepard interpolation); an integer ``k``: modified
        Shepard over the ``k`` nearest stars (for large numbers of stars).

    Attributes
    ----------
    X_fit_ : ndarray of shape (n_samples, n_features)
        Star positions.
    y_fit_ : ndarray of shape (n_samples, n_targets)
        Star values.
    n_features_in_ : int
        Number of features seen during fit.

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.interpolate import ShepardRegressor
    >>> X = np.array([[0.0, 0.0], [1.0, 0.0]])
    >>> reg = ShepardRegressor(power=2).fit(X, [0.0, 1.0])
    >>> reg.predict([[0.0, 0.0], [0.5, 0.0], [0.25, 0.0]])
    array([0. , 0.5, 0.1])
    """

    _parameter_constraints: dict = {
        "power": [Interval(Real, 0, np.inf, closed="neither")],
        "n_neighbors": [Interval(Integral, 1, None, closed="left"), None],
    }

    def __init__(self, power=3.0, n_neighbors=None):
        self.power = power
        self.n_neighbors = n_neighbors

    def _fit(self, X, Y):
        _check_n_samples("ShepardRegressor", X.shape[0], 1, "")
        k = _check_n_neighbors("ShepardRegressor", self.n_neighbors)
        self.X_fit_, self.y_fit_ = X, Y
        self._tree = None if k is None or k >= X.shape[0] else cKDTree(X)

    def _predict(self, X):
        if getattr(self, "_tree", None) is not None:
            return self._predict_local(X)
        out = np.empty((X.shape[0], self.y_fit_.shape[1]))
        for sl in _query_chunks(X.shape[0], self.X_fit_.shape[0]):
            D = cdist(X[sl], self.X_fit_)
            dmin = D.min(axis=1, keepdims=True)
            exact = dmin[:, 0] == 0
            W = np.empty_like(D)
            # weights relative to the nearest star: in [0, 1], no overflow
            W[~exact] = (dmin[~exact] / D[~exact]) ** self.power
            W[exact] = D[exact] == 0
            out[sl] = (W @ self.y_fit_) / W.sum(axis=1, keepdims=True)
        return out

    def _predict_local(self, X):
        k = int(self.n_neighbors)
        out = np.empty((X.shape[0], self.y_fit_.shape[1]))
        for start in range(0, X.shape[0], _LOCAL_BATCH):
            sl = slice(start, min(start + _LOCAL_BATCH, X.shape[0]))
            dist, idx = self._tree.query(X[sl], k=k + 1)
            R = dist[:, k:]
            d, idx = dist[:, :k], idx[:, :k]
            exact = d[:, 0] == 0
            with np.errstate(divide="ignore", invalid="ignore"):
                # ((R - d) / (R d))^p relative to the nearest star's: no overflow
                dmin = d[:, :1]
                W = (np.clip(R - d, 0.0, None) / (R - dmin) * dmin / d) ** self.power
                tie = ~exact & ~(W.sum(axis=1) > 0)
                W[tie] = (dmin[tie] / d[tie]) ** self.power
            W[exact] = d[exact] == 0
            out[sl] = np.einsum("qk,qkt->qt", W, self.y_fit_[idx]) / W.sum(axis=1)[:, None]
        return out
