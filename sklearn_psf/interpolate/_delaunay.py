"""Linear interpolation in the Delaunay triangulation of the stars."""

from __future__ import annotations

import numpy as np
from scipy.interpolate import LinearNDInterpolator
from scipy.spatial import Delaunay, QhullError, cKDTree
from sklearn.utils._param_validation import StrOptions
from threadpoolctl import threadpool_limits

from ._base import _BaseInterpolator, _check_n_samples, _merge_duplicates

_MAX_FEATURES = 6
_OUTSIDE = ("nearest", "error")


class DelaunayRegressor(_BaseInterpolator):
    """Piecewise-linear interpolation inside the Delaunay triangles of the stars.

    Inside the convex hull of the stars the value is the linear (barycentric)
    interpolation of the three stars of the enclosing triangle (n-D: of the simplex),
    as :class:`scipy.interpolate.LinearNDInterpolator` computes it. With one feature,
    interpolation is linear between consecutive stars along the line.

    Parameters
    ----------
    outside : {"nearest", "error"}, default="nearest"
        What to return at queries outside the convex hull of the stars, where the
        triangulation does not define a value:

        - ``"nearest"``: the value of the nearest star (a constant extrapolation);
        - ``"error"``: raise a ``ValueError`` that says how many queries are outside.

        Never NaN.

    Attributes
    ----------
    triangulation_ : scipy.spatial.Delaunay or None
        Triangulation of the stars (None when ``n_features_in_ == 1``).
    X_fit_ : ndarray of shape (n_stars, n_features)
        Distinct star positions (sorted along the line when ``n_features_in_ == 1``).
    y_fit_ : ndarray of shape (n_stars, n_targets)
        Values at ``X_fit_``.
    n_features_in_ : int
        Number of features seen during fit.

    Notes
    -----
    Stars sharing a position are merged (values averaged) with a
    :class:`DuplicateStarsWarning`: a triangulation keeps one vertex per position.
    Stars all on one line (2-D; in n-D, all in a lower-dimensional subspace) cannot be
    triangulated: ``ValueError``. Triangulations cost grows like
    ``n^ceil(n_features / 2)``, so ``n_features`` is limited to 6.

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.interpolate import DelaunayRegressor
    >>> X = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    >>> y = X[:, 0] + 2 * X[:, 1]
    >>> reg = DelaunayRegressor().fit(X, y)
    >>> reg.predict([[0.25, 0.5], [3.0, 0.0]])
    array([1.25, 1.  ])
    """

    _parameter_constraints: dict = {"outside": [StrOptions(set(_OUTSIDE))]}

    def __init__(self, outside="nearest"):
        self.outside = outside

    def _fit(self, X, Y):
        name = "DelaunayRegressor"
        d = X.shape[1]
        _check_n_samples(name, X.shape[0], min(d, _MAX_FEATURES) + 1, f"in {d} dimensions")
        if d > _MAX_FEATURES:
            raise ValueError(
                f"{name}: a Delaunay triangulation in {d} dimensions is too expensive; "
                f"use at most {_MAX_FEATURES} features (positions are usually 2-D)."
            )
        X, Y, _ = _merge_duplicates(
            X, Y, owner=name, reason="a triangulation has one vertex per position."
        )
        if d == 1:
            _check_n_samples(name, X.shape[0], 2, "(distinct positions) to interpolate along a line")
            order = np.argsort(X[:, 0], kind="stable")
            self.X_fit_, self.y_fit_ = X[order], Y[order]
            self.triangulation_ = None
            return
        _check_n_samples(
            name, X.shape[0], d + 1, f"(distinct positions) to triangulate in {d} dimensions"
        )
        try:
            self.triangulation_ = Delaunay(X)
            # the barycentric transforms are many tiny LAPACK calls: with threaded BLAS on
            # a busy machine they take seconds instead of microseconds. One thread, now.
            with threadpool_limits(limits=1, user_api="blas"):
                self.triangulation_.transform
        except QhullError:
            raise ValueError(
                f"{name}: the stars cannot be triangulated because they are degenerate: "
                + ("all stars lie on one line" if d == 2 else
                   f"all stars lie in a subspace of fewer than {d} dimensions")
                + ". Use stars spread over the field, or a 1-D input."
            ) from None
        self.X_fit_, self.y_fit_ = X, Y

    def _predict(self, X):
        if self.triangulation_ is None:
            x, xs = X[:, 0], self.X_fit_[:, 0]
            out = np.column_stack([np.interp(x, xs, col) for col in self.y_fit_.T])
            outside = (x < xs[0]) | (x > xs[-1])  # np.interp already holds the end values
        else:
            interp = LinearNDInterpolator(self.triangulation_, self.y_fit_, fill_value=np.nan)
            with threadpool_limits(limits=1, user_api="blas"):  # see _fit
                out = interp(X).reshape(X.shape[0], -1)
            outside = np.isnan(out).any(axis=1)
        if np.any(outside):
            if self.outside == "error":
                raise ValueError(
                    f"DelaunayRegressor(outside='error'): {int(outside.sum())} of "
                    f"{X.shape[0]} query points lie outside the convex hull of the stars. "
                    "Use outside='nearest' or restrict the queries to the hull."
                )
            if self.triangulation_ is not None:
                _, idx = cKDTree(self.X_fit_).query(X[outside])
                out[outside] = self.y_fit_[idx]
        return out
