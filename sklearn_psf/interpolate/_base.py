"""Input checks and helpers shared by the interpolation regressors (private)."""

from __future__ import annotations

import warnings

import numpy as np
from sklearn.base import BaseEstimator, RegressorMixin
from sklearn.utils.validation import check_is_fitted, validate_data

#: Queries are processed in chunks so that a (chunk, n_stars) distance matrix stays small.
_MAX_CHUNK = 2048
_CHUNK_ELEMENTS = 2**22  # about 32 MB of float64 per (chunk, n_stars) array


class DuplicateStarsWarning(UserWarning):
    """Several stars share exactly the same position; their values were averaged."""


class RankDeficientWarning(UserWarning):
    """The least-squares design matrix of a polynomial fit is rank deficient."""


def _query_chunks(n_queries: int, n_stars: int):
    """Yield slices over queries so that a (chunk, n_stars) array stays bounded."""
    size = int(max(1, min(_MAX_CHUNK, _CHUNK_ELEMENTS // max(n_stars, 1))))
    for start in range(0, n_queries, size):
        yield slice(start, min(start + size, n_queries))


def _merge_duplicates(X, Y, *, owner: str, reason: str):
    """Average the targets of stars with exactly the same position.

    Returns ``X, Y`` unchanged (same objects) when all positions are distinct; otherwise
    warns with :class:`DuplicateStarsWarning` and returns new arrays with one row per
    distinct position, whose target is the mean of the duplicated stars' targets.
    """
    unique, index, inverse, counts = np.unique(
        X, axis=0, return_index=True, return_inverse=True, return_counts=True
    )
    if unique.shape[0] == X.shape[0]:
        return X, Y
    inverse = inverse.reshape(-1)
    duplicated = np.flatnonzero(counts > 1)
    duplicated = duplicated[np.argsort(index[duplicated])][:3]  # in order of appearance
    groups = [np.flatnonzero(inverse == g).tolist() for g in duplicated]
    n_dup = int(np.sum(counts[counts > 1]))
    warnings.warn(
        f"{owner}: {n_dup} stars share {int(np.sum(counts > 1))} duplicated positions "
        f"(e.g. star indices {groups}); {reason} Their values were averaged, one star per "
        "position. Remove or merge duplicated stars yourself to silence this warning.",
        DuplicateStarsWarning,
        stacklevel=3,
    )
    Y_merged = np.zeros((unique.shape[0], Y.shape[1]))
    np.add.at(Y_merged, inverse, Y)
    Y_merged /= counts[:, None]
    # keep the order of first appearance, so that results do not depend on sorting
    order = np.argsort(index, kind="stable")
    return unique[order], Y_merged[order]


def _check_n_samples(owner: str, n_samples: int, n_min: int, what: str) -> None:
    if n_samples < n_min:
        raise ValueError(
            f"{owner} needs at least {n_min} samples (stars) {what}; got n_samples = "
            f"{n_samples}. Provide more stars or choose a simpler setting."
        )


class _BaseInterpolator(RegressorMixin, BaseEstimator):
    """Common fit/predict plumbing: validation, output shape, tags.

    Subclasses implement ``_fit(X, Y)`` with ``Y`` of shape (n_samples, n_targets) and
    ``_predict(X)`` returning (n_queries, n_targets).
    """

    def __sklearn_tags__(self):
        tags = super().__sklearn_tags__()
        tags.target_tags.multi_output = True
        tags.target_tags.single_output = True
        return tags

    def _validate_fit_data(self, X, y):
        X, y = validate_data(
            self, X, y, multi_output=True, y_numeric=True, dtype=np.float64,
            ensure_all_finite=True,
        )
        y = np.asarray(y, dtype=np.float64)
        self._y_ndim = y.ndim
        # copies: the fitted model never aliases (and never modifies) the caller's arrays
        X = np.array(X, dtype=np.float64, order="C", copy=True)
        Y = np.array(y.reshape(y.shape[0], -1), dtype=np.float64, order="C", copy=True)
        self.n_targets_ = Y.shape[1]
        return X, Y

    def _validate_predict_data(self, X):
        check_is_fitted(self)
        return validate_data(self, X, reset=False, dtype=np.float64, ensure_all_finite=True)

    def _format_output(self, Y):
        if self._y_ndim == 1:
            return Y[:, 0]
        return Y

    def fit(self, X, y):
        """Fit the interpolator to the stars.

        Parameters
        ----------
        X : array-like of shape (n_samples, n_features)
            Star positions.
        y : array-like of shape (n_samples,) or (n_samples, n_targets)
            Values at the stars (e.g. PCA coefficients of the stars' stamps).

        Returns
        -------
        self : object
            The fitted regressor.
        """
        X, Y = self._validate_fit_data(X, y)
        self._fit(X, Y)
        return self

    def predict(self, X):
        """Interpolate at new positions.

        Parameters
        ----------
        X : array-like of shape (n_queries, n_features)
            Query positions.

        Returns
        -------
        y_pred : ndarray of shape (n_queries,) or (n_queries, n_targets)
            Interpolated values, 1-D when the regressor was fitted on a 1-D ``y``.
        """
        X = self._validate_predict_data(X)
        return self._format_output(self._predict(X))


def _check_n_neighbors(owner: str, n_neighbors):
    """``None`` or a positive integer (returned as int); a ValueError otherwise."""
    if n_neighbors is None:
        return None
    if (
        isinstance(n_neighbors, (bool, np.bool_))
        or not isinstance(n_neighbors, (int, np.integer))
        or n_neighbors < 1
    ):
        raise ValueError(
            f"{owner}: n_neighbors must be None (all stars) or a positive integer, got "
            f"{n_neighbors!r}."
        )
    return int(n_neighbors)
