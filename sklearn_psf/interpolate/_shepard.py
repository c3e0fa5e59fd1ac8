"""Shepard (inverse distance weighting) interpolation."""

from __future__ import annotations

import numbers

import numpy as np
from scipy.spatial.distance import cdist

from ._base import _BaseInterpolator, _check_n_samples, _query_chunks


class ShepardRegressor(_BaseInterpolator):
    """Shepard interpolation: inverse-distance weighted mean of all stars.

    ``y(x) = sum_i y_i r_i^-p / sum_i r_i^-p`` with ``r_i = |x - x_i|`` over all stars.
    A query exactly on a star returns that star's value (the mean value of the stars
    there, if several share the position). Queries are processed in chunks, so memory
    stays bounded for any number of queries.

    Parameters
    ----------
    power : float, default=3.0
        Exponent ``p`` of the weights; the paper finds ``p >= 3`` works.

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

    def __init__(self, power=3.0):
        self.power = power

    def _fit(self, X, Y):
        p = self.power
        if not isinstance(p, numbers.Real) or not np.isfinite(p) or p <= 0:
            raise ValueError(f"ShepardRegressor: power must be a finite number > 0, got {p!r}.")
        _check_n_samples("ShepardRegressor", X.shape[0], 1, "")
        self.X_fit_, self.y_fit_ = X, Y

    def _predict(self, X):
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
