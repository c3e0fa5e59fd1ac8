"""A fixed, given basis of stamps (the paper forces the simulation's PCA basis on the model)."""

from __future__ import annotations

import numpy as np
from sklearn.base import (
    BaseEstimator,
    ClassNamePrefixFeaturesOutMixin,
    TransformerMixin,
    _fit_context,
)
from sklearn.utils.validation import check_is_fitted, validate_data

from .._persist import StateMixin

__all__ = ["FixedBasis"]


class FixedBasis(StateMixin, ClassNamePrefixFeaturesOutMixin, TransformerMixin, BaseEstimator):
    """Project stamps on a fixed, given set of basis stamps.

    ``transform`` returns the least-squares coefficients ``c`` minimising
    ``||(x - mean) - c @ components||``; the components need not be orthonormal (the
    pseudo-inverse is computed once, at ``fit``). ``inverse_transform`` rebuilds stamps
    ``c @ components + mean``. ``fit`` learns nothing from the data: it only checks that the
    stamps have the basis's number of pixels.

    Parameters
    ----------
    components : array-like of shape (k, p)
        Basis stamps, flattened (p = s*s pixels), one per row, e.g. ``PCA().components_``.
    mean : array-like of shape (p,), optional
        Stamp subtracted before projection (e.g. ``PCA().mean_``); default zero.

    Attributes
    ----------
    components_ : ndarray of shape (k, p)
    mean_ : ndarray of shape (p,)
    n_components_ : int
    n_features_in_ : int

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.preprocessing import FixedBasis
    >>> comps = np.array([[1.0, 0.0, 0.0, 1.0], [0.0, 1.0, 1.0, 0.0]])
    >>> fb = FixedBasis(comps).fit(np.zeros((1, 4)))
    >>> fb.transform([[2.0, 3.0, 3.0, 2.0]])
    array([[2., 3.]])
    >>> fb.inverse_transform([[1.0, -1.0]])
    array([[ 1., -1., -1.,  1.]])
    """

    _parameter_constraints: dict = {"components": ["array-like"], "mean": ["array-like", None]}

    _state_attributes = ("components_", "mean_", "n_components_", "n_features_in_")

    def _set_state(self, state):
        super()._set_state(state)
        self.components_ = np.asarray(self.components_, dtype=np.float64)
        self.mean_ = np.asarray(self.mean_, dtype=np.float64)
        self._pinv = np.linalg.pinv(self.components_)  # (p, k), as fit computes it
        self._n_features_out = self.n_components_
        return self

    def __init__(self, components, mean=None):
        self.components = components
        self.mean = mean

    @_fit_context(prefer_skip_nested_validation=True)
    def fit(self, X, y=None):
        """Check the basis and the stamps' size; compute the pseudo-inverse.

        Parameters
        ----------
        X : array-like of shape (n, p)
            Flattened stamps (only their number of pixels is used).
        y : ignored

        Returns
        -------
        self : FixedBasis
        """
        comps = np.array(self.components, dtype=np.float64, copy=True)
        if comps.ndim == 1:
            comps = comps[None, :]
        if comps.ndim == 3:  # (k, s, s) basis images
            comps = comps.reshape(comps.shape[0], -1)
        if comps.ndim != 2 or comps.shape[0] == 0:
            raise ValueError(
                f"components must have shape (n_components, n_pixels), got {comps.shape}."
            )
        if not np.all(np.isfinite(comps)):
            raise ValueError("components hold NaN or infinite values.")
        X = validate_data(self, X, dtype=np.float64)
        p = comps.shape[1]
        if X.shape[1] != p:
            raise ValueError(
                f"Stamps have {X.shape[1]} pixels but the basis has {p} pixels per component "
                f"(stamp side {np.sqrt(X.shape[1]):.4g} vs {np.sqrt(p):.4g}): cut stamps of "
                "the basis's size."
            )
        if self.mean is None:
            mean = np.zeros(p)
        else:
            mean = np.array(self.mean, dtype=np.float64, copy=True).ravel()
            if mean.shape != (p,) or not np.all(np.isfinite(mean)):
                raise ValueError(
                    f"mean must be a finite array of {p} pixels, got shape {mean.shape}."
                )
        if np.linalg.matrix_rank(comps) < comps.shape[0]:
            raise ValueError("components are linearly dependent: the projection is not unique.")
        self.components_ = comps
        self.mean_ = mean
        self.n_components_ = comps.shape[0]
        self._pinv = np.linalg.pinv(comps)  # (p, k)
        self._n_features_out = self.n_components_
        return self

    def transform(self, X):
        """Least-squares coefficients of the stamps on the basis.

        Parameters
        ----------
        X : array-like of shape (n, p)
            Stamps, flattened, with the ``p`` pixels of the fixed components (the
            mean is subtracted first).

        Returns
        -------
        coefficients : ndarray of shape (n, k)
        """
        check_is_fitted(self)
        X = validate_data(self, X, dtype=np.float64, reset=False)
        return (X - self.mean_) @ self._pinv

    def inverse_transform(self, X):
        """Rebuild stamps from coefficients.

        Parameters
        ----------
        X : array-like of shape (n, k)
            Coefficients.

        Returns
        -------
        stamps : ndarray of shape (n, p)
        """
        check_is_fitted(self)
        coef = np.asarray(X, dtype=np.float64)
        if coef.ndim != 2 or coef.shape[1] != self.n_components_:
            raise ValueError(
                f"Coefficients must have shape (n, {self.n_components_}), got {coef.shape}."
            )
        return coef @ self.components_ + self.mean_
