"""Positions scaled by one factor for every axis: distances keep their proportions."""

from __future__ import annotations

import numbers
from numbers import Integral

import numpy as np
from sklearn.base import BaseEstimator, OneToOneFeatureMixin, TransformerMixin, _fit_context
from sklearn.utils._param_validation import Interval
from sklearn.utils.validation import check_is_fitted, validate_data

__all__ = ["IsotropicScaler"]


class IsotropicScaler(OneToOneFeatureMixin, TransformerMixin, BaseEstimator):
    """Scale positions into [0, 1] along their longest side, with the same factor on every axis.

    ``(X - X.min(axis=0)) / max(X.max(axis=0) - X.min(axis=0))``: what
    :class:`sklearn.preprocessing.MinMaxScaler` does on a square field, but on a rectangular
    one the shorter side maps to [0, s] with s < 1 instead of being stretched to [0, 1]. A
    field whose statistics are the same in every direction on the detector (an isotropic
    covariance, as a PSF's variations over square pixels) stays isotropic, so that an
    isotropic variogram fits it; ``MinMaxScaler`` would stretch it by the ratio of the sides
    (1.29 on the package's default 10,032 x 7,769 pixel field, where the default model's
    ellipticity error at the galaxies was then larger, see ``benchmarks/README.md``).
    Distances in the scaled frame are the input's distances times ``scale_``: a Kriging range
    of 0.2 is 0.2 times the field's longer side.

    Further columns that are not positions (a colour, a magnitude: the model's extra
    dimensions) must not share the positions' factor (a colour spanning 3 would vanish beside
    positions spanning 4000): with ``n_positions=2`` only the first two columns share it and
    each further column is scaled into [0, 1] by its own span.

    Parameters
    ----------
    n_positions : int or None, default=None
        Number of leading columns that share the one factor (the positions); each further
        column gets its own. None: every column shares it.

    Attributes
    ----------
    min_ : ndarray of shape (n_features,)
        Smallest value of each feature seen in fit (subtracted).
    scale_ : float
        The positions' factor: 1 / (largest span of the position columns), 1 when they are
        all constant.
    feature_scale_ : ndarray of shape (n_features,)
        The factor of each column: ``scale_`` for the positions, 1 / (own span) for the
        further columns (1 when constant).
    n_features_in_ : int

    See Also
    --------
    sklearn.preprocessing.MinMaxScaler : each feature to [0, 1] (the paper's choice).

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.interpolate import IsotropicScaler
    >>> X = np.array([[0.0, 0.0], [4000.0, 1000.0], [2000.0, 2000.0]])
    >>> IsotropicScaler().fit_transform(X)
    array([[0.  , 0.  ],
           [1.  , 0.25],
           [0.5 , 0.5 ]])

    A colour column beside the positions keeps its own scale:

    >>> Xc = np.column_stack([X, [0.5, 2.0, 3.5]])
    >>> IsotropicScaler(n_positions=2).fit_transform(Xc)
    array([[0.  , 0.  , 0.  ],
           [1.  , 0.25, 0.5 ],
           [0.5 , 0.5 , 1.  ]])
    """

    _parameter_constraints: dict = {
        "n_positions": [Interval(Integral, 1, None, closed="left"), None],
    }

    def __init__(self, n_positions=None):
        self.n_positions = n_positions

    @_fit_context(prefer_skip_nested_validation=True)
    def fit(self, X, y=None):
        """Learn the minimum of each feature and the largest span.

        Parameters
        ----------
        X : array-like of shape (n_samples, n_features)
            Positions (the first ``n_positions`` columns share one factor), then any
            further features, each scaled by its own span.
        y : ignored
            Accepted for scikit-learn's API.

        Returns
        -------
        self : IsotropicScaler
        """
        m = self.n_positions
        if m is not None and (isinstance(m, bool) or not isinstance(m, numbers.Integral)
                              or m < 1):
            raise ValueError(f"IsotropicScaler: n_positions must be None or a positive "
                             f"integer, got {m!r}.")
        X = validate_data(self, X, dtype=np.float64, reset=True)
        self.min_ = X.min(axis=0)
        spans = X.max(axis=0) - self.min_
        m = X.shape[1] if m is None else min(int(m), X.shape[1])
        span = float(np.max(spans[:m]))
        self.scale_ = 1.0 / span if span > 0 else 1.0
        own = 1.0 / np.where(spans[m:] > 0, spans[m:], 1.0)
        self.feature_scale_ = np.concatenate([np.full(m, self.scale_), own])
        return self

    def transform(self, X):
        """Scaled positions ``(X - min_) * feature_scale_``.

        Parameters
        ----------
        X : array-like of shape (n_samples, n_features)
            Positions and features in the columns of ``fit``; values outside the
            fitted range scale beyond [0, 1], without a warning.

        Returns
        -------
        X_scaled : ndarray of shape (n_samples, n_features)
        """
        check_is_fitted(self)
        X = validate_data(self, X, dtype=np.float64, reset=False)
        # (scalers pickled before feature_scale_ existed: one factor for every column)
        return (X - self.min_) * getattr(self, "feature_scale_", self.scale_)

    def inverse_transform(self, X):
        """Positions in the input's units from scaled ones.

        Parameters
        ----------
        X : array-like of shape (n_samples, n_features)

        Returns
        -------
        X_original : ndarray of shape (n_samples, n_features)
        """
        check_is_fitted(self)
        X = validate_data(self, X, dtype=np.float64, reset=False)
        return X / getattr(self, "feature_scale_", self.scale_) + self.min_
