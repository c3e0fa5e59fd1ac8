"""Input checks and helpers shared by the interpolation regressors (private)."""

from __future__ import annotations

import warnings

import numpy as np
from sklearn.base import BaseEstimator, RegressorMixin, _fit_context
from sklearn.utils.validation import check_is_fitted, validate_data

#: Queries are processed in chunks so that a (chunk, n_stars) distance matrix stays small.
_MAX_CHUNK = 2048
_CHUNK_ELEMENTS = 2**22  # about 32 MB of float64 per (chunk, n_stars) array


class DuplicateStarsWarning(UserWarning):
    """Several stars share exactly the same position; their values were averaged."""


class RankDeficientWarning(UserWarning):
    """A polynomial fit has more terms than stars (degree lowered) or a rank-deficient design."""


class FewStarsWarning(UserWarning):
    """Too few stars for the fitted statistics (e.g. a Kriging sill) to mean much, or for
    the interpolator's maximum likelihood (``PSFModel`` then fits a constant PSF)."""


class ShortRangeWarning(UserWarning):
    """Maximum likelihood found no spatial correlation the stars can resolve: the Kriging
    range fell to the stars' spacing (``KrigingRegressor.range_at_floor_``)."""


def _query_chunks(n_queries: int, n_stars: int):
    """Yield slices over queries so that a (chunk, n_stars) array stays bounded."""
    size = int(max(1, min(_MAX_CHUNK, _CHUNK_ELEMENTS // max(n_stars, 1))))
    for start in range(0, n_queries, size):
        yield slice(start, min(start + size, n_queries))


def _merge_duplicates(X, Y, *, owner: str, reason: str, noise=None, noise_cov=None):
    """Merge the stars with exactly the same position.

    Returns ``X, Y, noise`` unchanged (same objects) when all positions are distinct;
    otherwise warns with :class:`DuplicateStarsWarning` and returns new arrays with one
    row per distinct position. Without ``noise`` (None) the merged value is the mean of
    the duplicated stars' values; with ``noise`` (n_samples, n_targets) of variances it
    is the inverse-variance weighted mean, of variance ``1 / sum(1 / noise)`` (stars of
    zero variance, if any in a group, take all the weight, equally shared). With
    ``noise_cov`` (n_samples, n_targets, n_targets) given, ``X, Y, noise, noise_cov`` are
    returned, the merged values weighted by the inverse covariances (pseudo-inverses).
    """
    unique, index, inverse, counts = np.unique(
        X, axis=0, return_index=True, return_inverse=True, return_counts=True
    )
    if unique.shape[0] == X.shape[0]:
        return (X, Y, noise) if noise_cov is None else (X, Y, noise, noise_cov)
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
        stacklevel=4,
    )

    def group_sum(values):
        out = np.zeros((unique.shape[0],) + values.shape[1:])
        np.add.at(out, inverse, values)
        return out

    order = np.argsort(index, kind="stable")
    if noise_cov is not None:
        precision = np.linalg.pinv(noise_cov, hermitian=True)
        total = group_sum(precision)
        cov = np.linalg.pinv(total, hermitian=True)
        Y_merged = np.einsum("itu,iu->it", cov, group_sum(
            np.einsum("itu,iu->it", precision, Y)))
        # groups without noise: the plain mean (exact values, covariance 0)
        exact = np.einsum("itt->i", total) == 0
        counts_col = np.bincount(inverse, minlength=len(unique))[:, None]
        Y_merged[exact] = (group_sum(Y) / counts_col)[exact]
        return unique[order], Y_merged[order], noise, cov[order]
    if noise is None:
        weights = np.ones_like(Y)
    else:
        exact = noise == 0
        exact_in_group = group_sum(exact.astype(float))[inverse] > 0
        weights = np.where(exact_in_group, exact, 1.0 / np.where(exact, 1.0, noise))
    wsum = group_sum(weights)
    Y_merged = group_sum(weights * Y) / wsum
    noise_merged = None
    if noise is not None:
        noise_merged = np.where(group_sum(exact.astype(float)) > 0, 0.0, 1.0 / wsum)
    # keep the order of first appearance, so that results do not depend on sorting
    return (unique[order], Y_merged[order],
            None if noise is None else noise_merged[order])


def _float_array(owner: str, name: str, value, what: str):
    """A fresh float64 array of ``value``, or a TypeError naming the parameter."""
    try:
        return np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise TypeError(f"{owner}: {name} must be an array of numbers ({what}), got "
                        f"{type(value).__name__}.") from None


def _bad_rows(owner: str, bad, message: str, fix: str):
    """ValueError naming the rows flagged in ``bad`` (n,), in counts."""
    rows = np.flatnonzero(bad)
    return ValueError(f"{owner}: {message}; rows {rows[:10].tolist()}"
                      f"{' ...' if rows.size > 10 else ''} ({rows.size} stars) are not. {fix}")


def _check_noise_var(owner: str, noise_var, n_samples: int, n_targets: int, *,
                     positive: bool = False):
    """Validate a ``noise_var`` fit parameter; None or a fresh (n_samples, n_targets) array."""
    if noise_var is None:
        return None
    nv = _float_array(owner, "noise_var", noise_var, "variances of the measurement noise of y")
    if nv.ndim == 1 and nv.shape[0] == n_samples:
        nv = np.repeat(nv[:, None], n_targets, axis=1)
    elif nv.shape != (n_samples, n_targets) and not (
        nv.shape == (n_samples, 1) and n_targets == 1
    ):
        raise ValueError(
            f"{owner}: noise_var must have shape ({n_samples},) or ({n_samples}, "
            f"{n_targets}) (one variance per star, or per star and target), got {nv.shape}."
        )
    nv = nv.reshape(n_samples, n_targets)
    bad = (~np.isfinite(nv) | (nv <= 0 if positive else nv < 0)).any(axis=1)
    if bad.any():
        what = "> 0 (a weighted least-squares fit)" if positive else ">= 0"
        raise _bad_rows(owner, bad, f"noise_var must be finite and {what}",
                        "Drop these stars or give them a finite variance.")
    return nv


def _check_noise_cov(owner: str, noise_cov, n_samples: int, n_targets: int):
    """Validate a ``noise_cov`` fit parameter: None or a fresh symmetric positive
    semi-definite (n_samples, n_targets, n_targets) array."""
    if noise_cov is None:
        return None
    cov = _float_array(owner, "noise_cov", noise_cov,
                       "covariances of the measurement noise of y across targets")
    if cov.shape != (n_samples, n_targets, n_targets):
        raise ValueError(
            f"{owner}: noise_cov must have shape ({n_samples}, {n_targets}, {n_targets}) (one "
            f"covariance matrix per star), got {cov.shape}."
        )
    bad = ~np.isfinite(cov).all(axis=(1, 2))
    sym = 0.5 * (cov + cov.transpose(0, 2, 1))
    sym[bad] = 0.0
    scale = np.maximum(np.abs(np.einsum("itt->i", sym)), 1e-300)
    bad |= np.abs(np.where(bad[:, None, None], 0.0, cov) - sym).max(axis=(1, 2)) > 1e-8 * scale
    bad |= np.linalg.eigvalsh(sym)[:, 0] < -1e-8 * scale
    cov = sym
    if bad.any():
        raise _bad_rows(owner, bad, "noise_cov must hold finite, symmetric, positive "
                        "semi-definite matrices", "Drop these stars or fix their covariances.")
    return cov


def _check_n_samples(owner: str, n_samples: int, n_min: int, what: str) -> None:
    if n_samples < n_min:
        raise ValueError(
            f"{owner} needs at least {n_min} samples (stars) {what}; got n_samples = "
            f"{n_samples}. Provide more stars or choose a simpler setting."
        )


def _check_finite(owner: str, a, what: str) -> None:
    """ValueError naming the rows holding NaN or inf (in the caller's numbering)."""
    bad = ~np.isfinite(a)
    if bad.any():
        rows = np.flatnonzero(bad.reshape(a.shape[0], -1).any(axis=1))
        raise ValueError(
            f"{owner}: {what} contains NaN or inf at rows {rows[:10].tolist()}"
            f"{' ...' if rows.size > 10 else ''} ({rows.size} rows). Drop these stars (or flag "
            "them as bad and leave them out) before fitting or predicting."
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

    #: the parameters' types and ranges, checked by ``fit`` (scikit-learn's validation);
    #: each regressor extends it with its own
    _parameter_constraints: dict = {}

    def _validate_fit_data(self, X, y):
        y_arr = np.asarray(y) if y is not None else None
        if y_arr is not None and y_arr.dtype.kind in "fc" and y_arr.ndim in (1, 2):
            _check_finite(type(self).__name__, y_arr, "y (values at the stars)")
        X, y = validate_data(
            self, X, y, multi_output=True, y_numeric=True, dtype=np.float64,
            ensure_all_finite=False,
        )
        y = np.asarray(y, dtype=np.float64)
        _check_finite(type(self).__name__, X, "X (star positions)")
        self._y_ndim = y.ndim
        # copies: the fitted model never aliases (and never modifies) the caller's arrays
        X = np.array(X, dtype=np.float64, order="C", copy=True)
        Y = np.array(y.reshape(y.shape[0], -1), dtype=np.float64, order="C", copy=True)
        self.n_targets_ = Y.shape[1]
        return X, Y

    def _set_fitted(self, state):
        """Make ``state`` (attribute name: value) the fitted state, in one place: the
        attributes the previous call set go first, so that nothing of a previous fit
        lingers (``_set_fitted({})`` at the start of a fit frees the previous fit's arrays
        before the new ones are allocated)."""
        for name in self.__dict__.pop("_fitted_names", ()):
            self.__dict__.pop(name, None)
        vars(self).update(state)
        self._fitted_names = tuple(state)

    def _set_state(self, state):
        """Hold what a saved fit chose (:mod:`sklearn_psf._persist`; the classes that save
        one define ``_get_state``): the next ``fit``, on the model file's stored stars,
        takes it from :meth:`_held_state_once` instead of choosing again."""
        self._held_state = dict(state)
        return self

    def _held_state_once(self):
        """The state :meth:`_set_state` holds, taken once (None: the fit chooses)."""
        return self.__dict__.pop("_held_state", None)

    def _validate_predict_data(self, X):
        check_is_fitted(self)
        X = validate_data(self, X, reset=False, dtype=np.float64, ensure_all_finite=False)
        _check_finite(type(self).__name__, X, "X (query positions)")
        return X

    def _format_output(self, Y):
        if self._y_ndim == 1:
            return Y[:, 0]
        return Y

    @_fit_context(prefer_skip_nested_validation=True)
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


class _NoiseAwareInterpolator(_BaseInterpolator):
    """An interpolator whose ``fit`` takes the per-star measurement noise: ``noise_var``, or
    ``noise_cov`` across targets.

    ``fit``'s signature carries both, so scikit-learn's metadata routing builds
    ``set_fit_request(noise_var=..., noise_cov=...)``. Subclasses implement
    ``_fit(X, Y, noise)`` with ``noise`` None or a validated (n_samples, n_targets) array of
    variances (given ``noise_cov``, its diagonal); with ``_joint_noise = True`` they
    implement ``_fit(X, Y, noise, noise_cov)`` and use the full covariance.
    """

    #: noise_var must be > 0 (weighted least squares) rather than >= 0
    _noise_positive = False
    #: _fit uses the full noise covariance across targets
    _joint_noise = False

    @_fit_context(prefer_skip_nested_validation=True)
    def fit(self, X, y, noise_var=None, noise_cov=None):
        """Fit the interpolator to the stars.

        Parameters
        ----------
        X : array-like of shape (n_samples, n_features)
            Star positions.
        y : array-like of shape (n_samples,) or (n_samples, n_targets)
            Values at the stars (e.g. PCA coefficients of the stars' stamps).
        noise_var : array-like of shape (n_samples,) or (n_samples, n_targets), default=None
            Variance of the measurement noise of each value of ``y``, in ``y``'s units
            squared (one per star, shared by the targets, or one per star and target).
            None: no measurement noise.
        noise_cov : array-like of shape (n_samples, n_targets, n_targets), default=None
            Covariance of each star's measurement noise across targets, instead of
            ``noise_var``: co-Kriging (:class:`KrigingRegressor`) uses it in full, the other
            interpolators its diagonal (the variances).

        Returns
        -------
        self : object
            The fitted regressor.
        """
        X, Y = self._validate_fit_data(X, y)
        owner = type(self).__name__
        if noise_cov is not None and noise_var is not None:
            raise ValueError(f"{owner}: give noise_var (independent targets) or noise_cov "
                             "(across targets), not both.")
        cov = _check_noise_cov(owner, noise_cov, X.shape[0], Y.shape[1])
        if cov is not None and not self._joint_noise:
            noise_var = np.einsum("itt->it", cov)
        noise = _check_noise_var(owner, noise_var, X.shape[0], Y.shape[1],
                                 positive=self._noise_positive)
        if self._joint_noise:
            self._fit(X, Y, noise, cov)
        else:
            self._fit(X, Y, noise)
        return self
