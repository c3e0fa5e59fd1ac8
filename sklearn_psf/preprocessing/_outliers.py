"""Inter-quartile-range outlier rejection (the paper's per-component IQR cut)."""

from __future__ import annotations

from numbers import Real

import numpy as np
from sklearn.base import BaseEstimator, OutlierMixin, _fit_context
from sklearn.utils._param_validation import Interval
from sklearn.utils.validation import check_is_fitted, validate_data

from .._persist import StateMixin

__all__ = ["IQROutlierDetector"]


class _OffsetOutlierMixin(OutlierMixin):
    """``decision_function`` and ``predict`` of an outlier detector from its
    ``score_samples`` and ``offset_`` (as scikit-learn's own detectors define them)."""

    def decision_function(self, X):
        """``score_samples(X) - offset_``: negative for outliers.

        Parameters
        ----------
        X : array-like of shape (n_samples, n_features)

        Returns
        -------
        decision : ndarray of shape (n_samples,)
        """
        return self.score_samples(X) - self.offset_

    def predict(self, X):
        """+1 for inliers, -1 for outliers.

        Parameters
        ----------
        X : array-like of shape (n_samples, n_features)

        Returns
        -------
        labels : ndarray of shape (n_samples,), int
        """
        return np.where(self.decision_function(X) >= 0, 1, -1)


class IQROutlierDetector(StateMixin, _OffsetOutlierMixin, BaseEstimator):
    """Flag samples with any feature beyond the inter-quartile fences.

    A sample is an outlier when, for any column j, ``X[:, j] < Q1_j - alpha * IQR_j`` or
    ``X[:, j] > Q3_j + alpha * IQR_j``, with quartiles of the data given to ``fit``
    (``np.percentile``, linear interpolation). With ``alpha = 3.5`` the paper removes about 1% of
    stars; on Gaussian data the rule rejects far less than that per column. It knows nothing
    of the stars' noise: on noisy stars whose coefficients spread with their S/N it rejects
    clean ones, the brightest and the faintest (how many: ``benchmarks/bench_noise.py``); it
    is the paper's option, :class:`ChiSquareOutlierDetector` the default of
    :class:`~sklearn_psf.model.PSFModel`.

    The score follows scikit-learn's outlier detectors (larger = more normal):
    ``score_samples(X) = -max_j d_j`` with ``d_j = max(lower_j - x_j, x_j - upper_j) / IQR_j``,
    the largest normalised excess beyond the fences; it is 0 on a fence, positive inside and
    negative outside. ``decision_function = score_samples - offset_`` with ``offset_ = 0``, and
    ``predict`` gives +1 (inlier) where it is >= 0 and -1 (outlier) elsewhere. A column with
    zero IQR uses 1 as its scale (any value off the constant is an outlier).

    Parameters
    ----------
    alpha : float, default=3.5
        Fence distance in units of the IQR.

    Attributes
    ----------
    q1_, q3_ : ndarray of shape (n_features,)
        First and third quartiles.
    lower_, upper_ : ndarray of shape (n_features,)
        Fences ``q1_ - alpha * iqr`` and ``q3_ + alpha * iqr``.
    offset_ : float
        0.
    n_features_in_ : int

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.preprocessing import IQROutlierDetector
    >>> X = np.array([[0.0], [1.0], [2.0], [3.0], [100.0]])
    >>> IQROutlierDetector(alpha=1.5).fit_predict(X)
    array([ 1,  1,  1,  1, -1])
    """

    _parameter_constraints: dict = {"alpha": [Interval(Real, 0, np.inf, closed="left")]}

    _state_attributes = ("q1_", "q3_", "lower_", "upper_", "offset_", "n_features_in_")

    def _set_state(self, state):
        super()._set_state(state)
        for name in ("q1_", "q3_", "lower_", "upper_"):
            setattr(self, name, np.asarray(getattr(self, name), dtype=np.float64))
        iqr = self.q3_ - self.q1_
        self._scale = np.where(iqr > 0, iqr, 1.0)
        return self

    def __init__(self, alpha: float = 3.5):
        self.alpha = alpha

    @_fit_context(prefer_skip_nested_validation=True)
    def fit(self, X, y=None):
        """Compute the quartiles and fences of X.

        Parameters
        ----------
        X : array-like of shape (n_samples, n_features)
            The values judged, one column at a time (e.g. the stars' coefficients on
            the basis); NaN is refused.
        y : ignored
            Accepted for scikit-learn's API.

        Returns
        -------
        self : IQROutlierDetector
        """
        alpha = float(self.alpha)
        X = validate_data(self, X, dtype=np.float64)
        self.q1_, self.q3_ = np.percentile(X, [25.0, 75.0], axis=0)
        iqr = self.q3_ - self.q1_
        self.lower_ = self.q1_ - alpha * iqr
        self.upper_ = self.q3_ + alpha * iqr
        self._scale = np.where(iqr > 0, iqr, 1.0)
        self.offset_ = 0.0
        return self

    def score_samples(self, X):
        """Minus the largest normalised excess beyond the fences (larger = more normal).

        Parameters
        ----------
        X : array-like of shape (n_samples, n_features)

        Returns
        -------
        scores : ndarray of shape (n_samples,)
        """
        check_is_fitted(self)
        X = validate_data(self, X, dtype=np.float64, reset=False)
        excess = np.maximum(self.lower_ - X, X - self.upper_) / self._scale
        return -excess.max(axis=1)
