"""The interface of the stamp bases that :class:`~sklearn_psf.model.PSFModel` fits:
:class:`_BaseStampBasis`, which :class:`~sklearn_psf.preprocessing.StampPCA` (at the
pixels' sampling) and :class:`~sklearn_psf.preprocessing.SuperResolvedPCA` (on a finer grid)
implement, and what they share: the checks of the stamps and their weights, the stars'
first centroids and FWHM (:func:`stamp_fwhm`), the choice of the number of components, the
projection of stamps (:class:`StampFit`) and the persisted state."""

from __future__ import annotations

import numbers
import warnings
from numbers import Integral, Real
from typing import NamedTuple

import numpy as np
from sklearn.base import (
    BaseEstimator,
    ClassNamePrefixFeaturesOutMixin,
    TransformerMixin,
    _fit_context,
)
from sklearn.utils._param_validation import Interval, RealNotInt, StrOptions
from sklearn.utils.validation import check_is_fitted, validate_data

from .._persist import StateMixin
from .._validation import rows_text
from ..measure import adaptive_moments, fixed_moments
from ._noise import check_pixel_weights, estimate_pixel_weights
from ._pca_noise import noise_edge
from ._stamp_weights import border_level, model_weights, poisson_slope

__all__ = ["StampFit", "StampFitWarning", "FIT_OK", "FIT_NO_CENTROID", "FIT_NO_FLUX",
           "FALLBACK_SIGMA", "stamp_fwhm"]

#: The star's flux, centroid and coefficients were fitted.
FIT_OK = 0
#: No centroid (adaptive moments and the fixed-weight fallback failed): the star was fitted
#: at the stamp centre and left out of the basis.
FIT_NO_CENTROID = 1
#: Width (pixels) of the fixed Gaussian weight whose centre is a star's centroid where
#: adaptive moments fail (undersampled stars, see :func:`~sklearn_psf.measure.fixed_moments`).
FALLBACK_SIGMA = 1.5
#: The fitted flux is not positive (noise or an empty stamp): coefficients are NaN.
FIT_NO_FLUX = 2


_FWHM_PER_SIGMA = 2.0 * np.sqrt(2.0 * np.log(2.0))
_FWHM_WEIGHT = 1.0  # pixels: sigma of the fixed weight of stamp_fwhm


def normal_inverse(normal):
    """The pseudo-inverse of each symmetric positive semi-definite matrix of ``normal``
    (..., k, k), as ``np.linalg.pinv(normal, hermitian=True)`` gives it: by LU on the
    matrices scaled to a unit diagonal where that inverse is accurate (its product with
    the matrix within 1e-8 of the identity, its diagonal under 1e10: a condition number
    under ~1e8), by ``pinv`` elsewhere (a column without weight, a degenerate offset).
    The weighted least squares of the stars' fits solve thousands of such small systems:
    2-3x faster than ``pinv`` alone."""
    diag = np.einsum("...ii->...i", normal)
    scale = 1.0 / np.sqrt(np.where(diag > 0, diag, 1.0))
    outer = scale[..., :, None] * scale[..., None, :]
    scaled = normal * outer
    with np.errstate(all="ignore"):
        try:
            inv = np.linalg.inv(scaled)
        except np.linalg.LinAlgError:  # (one exactly singular matrix fails the batch)
            return np.linalg.pinv(normal, hermitian=True)
        off = np.abs(scaled @ inv - np.eye(normal.shape[-1])).max(axis=(-2, -1))
        good = ((diag > 0).all(axis=-1) & (off < 1e-8)
                & (np.einsum("...ii->...i", inv).max(axis=-1) < 1e10))
    inv *= outer
    if not good.all():
        inv[~good] = np.linalg.pinv(normal[~good], hermitian=True)
    return inv


def stamp_fwhm(stamps, weights=None):
    """FWHM (pixels) of each star, well sampled or not (NaN where not measurable).

    Adaptive moments where they converge (FWHM = 2.355 sigma of the best-fitting Gaussian);
    elsewhere (stars under ~2 pixels per FWHM) the moments with a fixed Gaussian weight of
    sigma ``w`` = 1 pixel (:func:`~sklearn_psf.measure.fixed_moments`), corrected for the
    weight as for a Gaussian star (``C = (M^-1 - I / w^2)^-1``).

    Parameters
    ----------
    stamps : array-like of shape (n, s, s) or (n, s*s)
        Background-subtracted stamps (NaN = masked).
    weights : array-like of the stamps' shape, optional
        Pixel weights (0 = masked).

    Returns
    -------
    fwhm : ndarray of shape (n,)

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.preprocessing import stamp_fwhm
    >>> y, x = np.mgrid[0:15, 0:15] - 7.0
    >>> star = np.exp(-0.5 * ((x - 0.2) ** 2 + y**2) / 0.6**2)    # FWHM 1.41 px
    >>> print(np.round(stamp_fwhm(star[None]), 1))
    [1.4]
    """
    mom = adaptive_moments(stamps, weights=weights, guess_sigma=_FWHM_WEIGHT)
    fwhm = _FWHM_PER_SIGMA * np.asarray(mom["sigma"], dtype=np.float64)
    bad = np.flatnonzero(np.asarray(mom["flag"]) != 0)
    if bad.size:
        cube = np.asarray(stamps, dtype=np.float64)
        cube = cube.reshape(cube.shape[0], -1)[bad]
        wb = None if weights is None else np.asarray(weights, np.float64).reshape(
            len(fwhm), -1)[bad]
        t = fixed_moments(cube, _FWHM_WEIGHT, weights=wb)
        mxx, mxy, myy = (np.asarray(t[c], dtype=np.float64) for c in ("Mxx", "Mxy", "Myy"))
        with np.errstate(divide="ignore", invalid="ignore"):
            det = mxx * myy - mxy**2
            ixx = myy / det - 1.0 / _FWHM_WEIGHT**2
            iyy = mxx / det - 1.0 / _FWHM_WEIGHT**2
            ixy = -mxy / det
            idet = ixx * iyy - ixy**2
            ok = (idet > 0) & (ixx > 0)
            fwhm[bad] = np.where(ok, _FWHM_PER_SIGMA * np.abs(idet) ** -0.25, np.nan)
    return fwhm


class StampFitWarning(UserWarning):
    """Some stamps could not be fitted on the basis (see :class:`StampFit` flags)."""


class StampFit(NamedTuple):
    """Weighted least-squares fit of stamps on a :class:`StampPCA` basis.

    Each stamp ``d`` (raw units) is fitted as ``flux * shift(mean + coefficients @
    components, offset)`` by weighted least squares with its pixel weights.
    """

    #: ndarray (n, k): coefficients of the normalised, centred stamp.
    coefficients: np.ndarray
    #: ndarray (n, k): their noise variance propagated from the pixel weights.
    coefficient_var: np.ndarray
    #: ndarray (n,): fitted flux (sum of the model stamp).
    flux: np.ndarray
    #: ndarray (n, 2): (dx, dy) of the adaptive centroid from the stamp centre, in pixels.
    offsets: np.ndarray
    #: ndarray (n, p): the fitted model stamps in the stars' frame (flux and offset applied).
    model: np.ndarray
    #: ndarray (n, p): pixel weights used (given or estimated; 0 = masked).
    weights: np.ndarray
    #: ndarray (n,): ``FIT_OK`` (0), ``FIT_NO_CENTROID`` (1), ``FIT_NO_FLUX`` (2).
    flag: np.ndarray
    #: ndarray (n, k, k): the coefficients' full noise covariance (their correlations come
    #: mostly from the common flux normalisation), of diagonal ``coefficient_var``.
    coefficient_cov: np.ndarray | None = None



class _BaseStampBasis(StateMixin, ClassNamePrefixFeaturesOutMixin, TransformerMixin,
                      BaseEstimator):
    """A basis of star stamps fitted on raw, noisy, masked stamps and their pixel weights.

    What :class:`~sklearn_psf.model.PSFModel` uses of a noise-aware basis: :meth:`fit_project`
    (the fit and the stars' :class:`StampFit` on it), :meth:`project` (other stars),
    :meth:`render` (model stamps at any flux and offset), ``transform`` /
    ``inverse_transform`` and the fitted ``mean_``, ``components_`` (at the pixels'
    sampling), ``n_components_`` and ``stamp_size_``. A subclass implements

    - ``_fit(X, weights, positions)``: fits the basis (setting the attributes of
      ``_state_attributes``) and returns the stars' :class:`StampFit` when its fit gives it
      (its last fit of the stars), else None (:meth:`fit_project` then projects them);
    - ``_project_stars(d, w, offsets, s)``: each star's fit on the fitted basis (amplitudes,
      their covariance, model, offsets, background level, whether the offset fit succeeded);
    - ``render``.

    Its state (:mod:`sklearn_psf._persist`) is ``_state_attributes``: a subclass adds its own
    fitted attributes there.
    """

    _parameter_constraints: dict = {
        "n_components": [StrOptions({"noise"}), Interval(Integral, 1, None, closed="left"),
                         Interval(RealNotInt, 0, 1, closed="neither")],
        "max_components": [Interval(Integral, 1, None, closed="left")],
        "n_iter": [Interval(Integral, 1, None, closed="left")],
        "max_star_weight": [Interval(Real, 1, np.inf, closed="left")],
        "guess_sigma": [Interval(Real, 0, None, closed="neither")],
        "background": ["boolean", StrOptions({"auto"})],
    }

    _state_attributes = ("mean_", "components_", "explained_variance_", "noise_variance_",
                         "noise_edge_", "background_", "n_components_", "stamp_size_",
                         "n_features_in_")

    def _set_state(self, state):
        super()._set_state(state)
        for name in ("n_components_", "stamp_size_", "n_features_in_"):
            setattr(self, name, int(getattr(self, name)))
        for name in ("noise_variance_", "noise_edge_"):
            if hasattr(self, name):
                setattr(self, name, float(getattr(self, name)))
        if hasattr(self, "explained_variance_"):
            self.explained_variance_ = np.asarray(self.explained_variance_, dtype=np.float64)
        self.mean_ = np.asarray(self.mean_, dtype=np.float64).reshape(-1)
        self.components_ = np.asarray(self.components_, dtype=np.float64).reshape(
            self.n_components_, -1)
        # (states written before background_ existed: no background)
        self.background_ = bool(getattr(self, "background_", False))
        self._n_features_out = self.n_components_
        return self

    # -- input ---------------------------------------------------------------------------
    def _check_params(self):
        nc = self.n_components
        ok = (nc == "noise" if isinstance(nc, str) else
              isinstance(nc, numbers.Integral) and not isinstance(nc, bool) and nc >= 1
              or isinstance(nc, numbers.Real) and 0 < nc < 1)
        if not ok:
            raise ValueError("n_components must be 'noise', an int >= 1 or a float in (0, 1), "
                             f"got {nc!r}.")
        for name in ("max_components", "n_iter"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < 1:
                raise ValueError(f"{name} must be an int >= 1, got {value!r}.")
        if not (np.isfinite(self.max_star_weight) and self.max_star_weight >= 1):
            raise ValueError(f"max_star_weight must be >= 1, got {self.max_star_weight!r}.")
        if not (isinstance(self.background, (bool, np.bool_)) or self.background == "auto"):
            raise ValueError(f"background must be 'auto', True or False, got "
                             f"{self.background!r}.")


    def _stamps_and_weights(self, X, weights, reset):
        X = validate_data(self, X, dtype=np.float64, reset=reset, ensure_all_finite="allow-nan")
        n, p = X.shape
        if reset and n < 2:
            raise ValueError(f"StampPCA needs at least 2 stamps, got n_samples = {n}.")
        if p < 9:
            raise ValueError(f"StampPCA needs stamps of at least 3x3 pixels, got n_features = "
                             f"{p}.")
        s = int(round(np.sqrt(p)))
        if s * s != p:
            raise ValueError(f"Stamps have {p} pixels, not a square number: pass flattened "
                             "square stamps of shape (n, s*s).")
        if np.isinf(X).any():
            rows = np.flatnonzero(np.isinf(X).any(axis=1))
            raise ValueError(f"Stamps with infinite pixels at rows {rows_text(rows)}: mask "
                             "them (NaN or weight 0).")
        if weights is None:
            w = estimate_pixel_weights(X)
        else:
            w = check_pixel_weights(weights, n, p, stamps=X)
        empty = ~(w > 0).any(axis=1)
        if empty.any():
            raise ValueError(f"Stamps with every pixel masked at rows "
                             f"{rows_text(np.flatnonzero(empty))}.")
        d = np.where(w > 0, X, 0.0)
        return d, w, s

    def _centroids(self, d, w, s):
        try:
            mom = adaptive_moments(d.reshape(-1, s, s), weights=w.reshape(-1, s, s),
                                   guess_sigma=self.guess_sigma)
        except TypeError:  # moments without mask support: masked pixels are zero already
            mom = adaptive_moments(d.reshape(-1, s, s), guess_sigma=self.guess_sigma)
        ok = np.asarray(mom["flag"]) == 0
        x0, y0 = np.asarray(mom["x0"], dtype=np.float64), np.asarray(mom["y0"], dtype=np.float64)
        if not ok.all():  # undersampled stars (adaptive moments fail below ~2 px FWHM): the
            # centre of a fixed Gaussian weight of FALLBACK_SIGMA
            bad = np.flatnonzero(~ok)
            fixed = fixed_moments(d[bad].reshape(-1, s, s), FALLBACK_SIGMA,
                                  weights=w[bad].reshape(-1, s, s))
            ok[bad] = np.asarray(fixed["flag"]) == 0
            x0[bad], y0[bad] = np.asarray(fixed["x0"]), np.asarray(fixed["y0"])
        centre = (s - 1) / 2.0
        off = np.column_stack([x0 - centre, y0 - centre])
        off[~ok | ~np.isfinite(off).all(axis=1)] = 0.0
        return off, ok


    @staticmethod
    def _coefficients(a, cov):
        """Flux, coefficients ``c = a[1:] / a[0]``, their noise covariance (delta method:
        ``J cov(a) J^T`` with ``J = [-c, I] / flux``) and its diagonal, and the good rows."""
        flux = a[:, 0]
        good = flux > 0
        safe = np.where(good, flux, 1.0)
        coef = a[:, 1:] / safe[:, None]
        cross = coef[:, :, None] * cov[:, None, 0, 1:]
        ccov = (cov[:, 1:, 1:] - cross - cross.transpose(0, 2, 1)
                + coef[:, :, None] * coef[:, None, :] * cov[:, :1, :1]) / safe[:, None, None] ** 2
        ccov = 0.5 * (ccov + ccov.transpose(0, 2, 1))
        var = np.maximum(np.einsum("bkk->bk", ccov), 0.0)
        coef[~good] = np.nan
        var[~good] = np.nan
        ccov[~good] = np.nan
        return flux, coef, var, ccov, good

    def _choose(self, lam, total, noise, contributions, p, raise_by=1.0):
        cap = lam.size
        if not isinstance(self.n_components, numbers.Integral):
            cap = min(int(self.max_components), cap)
        lam = lam[:cap]
        real = lam > 1e-12 * lam[0] if lam.size and lam[0] > 0 else np.zeros(lam.size, bool)
        if isinstance(self.n_components, str):
            edge = raise_by * noise_edge(contributions, p - 1, quantile=True)
            k = int(np.count_nonzero((lam > edge) & real))
        elif isinstance(self.n_components, numbers.Integral):
            edge = np.nan
            k = int(self.n_components)
            if k > lam.size:
                raise ValueError(f"n_components={k} but the stamps hold at most {lam.size} "
                                 "principal components.")
        else:
            edge = np.nan
            frac = np.cumsum(lam) / total if total > 0 else np.ones(lam.size)
            k = int(np.searchsorted(frac, self.n_components) + 1)
        return max(1, min(k, cap)), edge

    # -- estimator API ------------------------------------------------------------------------

    # -- estimator API ------------------------------------------------------------------------
    def _fit(self, X, weights, positions=None):  # pragma: no cover - abstract
        raise NotImplementedError

    def _project_stars(self, d, w, offsets, s):  # pragma: no cover - abstract
        raise NotImplementedError

    @_fit_context(prefer_skip_nested_validation=True)
    def fit_project(self, X, weights=None, positions=None) -> StampFit:
        """Fit the basis on stamps and fit each of them on it.

        ``fit(X, weights=weights)`` and then :meth:`project`, except where the basis's fit
        ends with a fit of the stars (:class:`StampPCA`): its last iteration's is returned,
        the offsets of stars with masked pixels refined from that iteration's instead of from
        their centroids.

        Parameters
        ----------
        X : array-like of shape (n, s*s)
            Raw star stamps, NaN for masked pixels. Not modified.
        weights : array-like of shape (n, s*s), optional
            Inverse variance per pixel (0 = masked); default estimated from the stamps.
        positions : array-like of shape (n, 2), optional
            The stars' positions, for a basis whose fit uses them
            (:class:`SuperResolvedPCA`); ignored by the others.

        Returns
        -------
        StampFit
        """
        fit = self._fit(X, weights, positions)
        return self.project(X, weights) if fit is None else fit

    def project(self, X, weights=None) -> StampFit:
        """Fit stamps on the basis: coefficients, their noise, flux, offsets and model.

        Parameters
        ----------
        X : array-like of shape (n, s*s)
            Raw stamps, NaN for masked pixels. Not modified.
        weights : array-like of shape (n, s*s), optional
            Inverse variance per pixel (0 = masked); default estimated from the stamps.

        Returns
        -------
        StampFit
        """
        check_is_fitted(self)
        d, w, s = self._stamps_and_weights(X, weights, reset=False)
        fit = self._project(d, w, s)
        poisson = poisson_slope(d, w)
        if poisson:  # fitted again, the weights' Poisson part from the stars' models
            predicted = np.where((fit.flag == FIT_OK)[:, None], fit.model, np.nan)
            fit = self._project(d, model_weights(d, w, predicted, poisson), s)
        return fit

    def _project(self, d, w, s):
        """:meth:`project`'s fit of the checked stamps ``d`` with the weights ``w``."""
        level = border_level(d, w, s)[0] if self.background_ else np.zeros(len(d))
        offsets, ok = self._centroids(d - level[:, None], w, s)
        a, cov, model, offsets, level, moved_ok = self._project_stars(d, w, offsets, s)
        flux, coef, var, ccov, good = self._coefficients(a, cov)
        flag = np.where(ok & moved_ok, FIT_OK, FIT_NO_CENTROID)
        flag[~good] = FIT_NO_FLUX
        return StampFit(coef, var, flux, offsets, model + level[:, None], w, flag, ccov)


    def _check_coefficients(self, C):
        coef = np.asarray(C, dtype=np.float64)
        if coef.ndim != 2 or coef.shape[1] != self.n_components_:
            raise ValueError(
                f"Coefficients must have shape (n, {self.n_components_}), got {coef.shape}."
            )
        return coef

    @_fit_context(prefer_skip_nested_validation=True)
    def fit_transform(self, X, y=None, weights=None):
        """Fit, then return the coefficients of X (see :meth:`transform`).

        Parameters
        ----------
        X : array-like of shape (n, s*s)
            Raw star stamps (odd side s), NaN for masked pixels; not modified.
        y : ignored
            Accepted for scikit-learn's API.
        weights : array-like of shape (n, s*s), optional
            Inverse variance of each pixel (0 = masked); default from each stamp's border.

        Returns
        -------
        coefficients : ndarray of shape (n, n_components_)
        """
        return self.fit(X, weights=weights).transform(X, weights=weights)

    def transform(self, X, weights=None):
        """Weighted-least-squares coefficients of stamps (normalised, centred convention).

        Stamps that cannot be fitted (no positive flux) get NaN coefficients, with a
        :class:`StampFitWarning` naming their rows.

        Parameters
        ----------
        X : array-like of shape (n, s*s)
        weights : array-like of shape (n, s*s), optional

        Returns
        -------
        coefficients : ndarray of shape (n, n_components_)
        """
        fit = self.project(X, weights)
        bad = fit.flag == FIT_NO_FLUX
        if bad.any():
            warnings.warn(f"Stamps at rows {rows_text(np.flatnonzero(bad))} have no positive "
                          "flux on the basis: their coefficients are NaN.", StampFitWarning,
                          stacklevel=2)
        return fit.coefficients

    def inverse_transform(self, X):
        """Normalised (unit-sum), centred stamps from coefficients.

        Parameters
        ----------
        X : array-like of shape (n, n_components_)

        Returns
        -------
        stamps : ndarray of shape (n, s*s)
        """
        check_is_fitted(self)
        stamps = self.mean_ + self._check_coefficients(X) @ self.components_
        return stamps / stamps.sum(axis=1, keepdims=True)

    def __sklearn_tags__(self):
        tags = super().__sklearn_tags__()
        tags.input_tags.allow_nan = True
        return tags
