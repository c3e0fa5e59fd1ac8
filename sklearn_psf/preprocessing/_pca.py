"""A PCA basis of noisy, masked star stamps whose size follows the signal, not the noise."""

from __future__ import annotations

import numbers
import warnings
from typing import NamedTuple

import numpy as np
from scipy.linalg import eigh
from sklearn.base import BaseEstimator, ClassNamePrefixFeaturesOutMixin, TransformerMixin
from sklearn.utils.validation import check_is_fitted, validate_data

from ..measure import adaptive_moments
from ._normalize import fourier_shift, phase_ramp
from .._validation import rows_text
from ._noise import check_pixel_weights, estimate_pixel_weights

__all__ = ["StampPCA", "StampFit", "StampFitWarning", "FIT_OK", "FIT_NO_CENTROID",
           "FIT_NO_FLUX"]

#: The star's flux, centroid and coefficients were fitted.
FIT_OK = 0
#: Adaptive moments failed: the star was fitted at the stamp centre and left out of the basis.
FIT_NO_CENTROID = 1
#: The fitted flux is not positive (noise or an empty stamp): coefficients are NaN.
FIT_NO_FLUX = 2

_CHUNK = 256  # stars per batch of shifted basis images
_REFINE_STEPS = 3  # Gauss-Newton steps on the offsets of stars with masked pixels


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


def _shifted(images_fft, phase):
    """Images (m, s, s) given by their rfft2, shifted by each star's phase: (n, m, s*s)."""
    n, s = phase.shape[0], phase.shape[1]
    out = np.fft.irfft2(images_fft[None, :, :, :] * phase[:, None, :, :], s=(s, s))
    return out.reshape(n, images_fft.shape[0], s * s)


def _weighted_pca(x, u, n_top):
    """Weighted mean, the n_top principal axes (rows), their variances, the total variance.

    The eigenproblem is solved on the smaller Gram matrix of the weighted, centred rows.
    """
    total = u.sum()
    mean = u @ x / total
    z = np.sqrt(u / total)[:, None] * (x - mean)
    small = z @ z.T if z.shape[0] <= z.shape[1] else z.T @ z
    m = small.shape[0]
    n_top = min(n_top, m)
    lam, vec = eigh(small, subset_by_index=[m - n_top, m - 1])
    lam, vec = np.maximum(lam[::-1], 0.0), vec[:, ::-1]
    if z.shape[0] <= z.shape[1]:
        axes = vec.T @ z
        axes /= np.maximum(np.linalg.norm(axes, axis=1, keepdims=True), 1e-300)
    else:
        axes = vec.T
    return mean, axes, lam, float(np.trace(small))


class StampPCA(ClassNamePrefixFeaturesOutMixin, TransformerMixin, BaseEstimator):
    """PCA basis of noisy, masked star stamps, with as many components as the signal holds.

    The noise-aware replacement of ``make_pipeline(StampNormalizer(), PCA(0.9))``: it takes
    raw star stamps and their pixel weights (inverse variance, 0 = masked; estimated from each
    stamp's border when not given, see :func:`estimate_pixel_weights`) and

    1. measures each star's adaptive centroid on its unmasked pixels;
    2. iterates (``n_iter`` times): fills masked pixels with the current model of the star,
       normalises (flux) and centres (Fourier shift) the stamps, and computes a PCA weighted by
       each star's S/N (weight ``1 / v_i``, ``v_i`` the noise variance per pixel of the
       normalised stamp, capped at ``max_star_weight`` times the median so that a few bright
       stars do not make the basis); then fits every star by weighted least squares as
       ``flux * shift(mean + c @ components, centroid offset)`` on its unmasked pixels: the
       basis is moved to the star, never the masked data to the basis;
    3. keeps, with ``n_components="noise"``, the components whose variance is above the noise
       edge ``sigma^2 (1 + sqrt(p / n_eff))^2`` (the largest eigenvalue of the sample covariance
       of pure noise, Marchenko-Pastur), where ``sigma^2`` is the weighted mean noise variance
       per pixel of the normalised stamps, ``p`` the number of pixels and ``n_eff`` the
       effective number of stars ``(sum u)^2 / sum u^2``: noise alone cannot make such a
       component, and a component below it is mostly noise. At most ``max_components``.

    ``transform`` gives the weighted-least-squares coefficients (the stamps' coefficient
    noise, flux and offsets come from :meth:`project`), ``inverse_transform`` normalised
    (unit-sum), centred stamps. The flux convention is that of :class:`StampNormalizer`: the
    mean stamp sums to 1 and the components to 0.

    Parameters
    ----------
    n_components : "noise", int or float, default="noise"
        "noise": above the noise edge (see above). An int: that many. A float in (0, 1): as
        many as hold that fraction of the weighted variance (the paper's 0.9, noise-blind).
    max_components : int, default=20
        Upper bound for "noise" and float choices.
    n_iter : int, default=2
        Rounds of fill / normalise / PCA / fit.
    max_star_weight : float, default=10.0
        Cap of a star's PCA weight in units of the median star weight.
    guess_sigma : float, default=3.0
        Initial width (pixels) of the adaptive weight used to find centroids.

    Attributes
    ----------
    mean_ : ndarray of shape (p,)
        Mean normalised stamp (sums to 1).
    components_ : ndarray of shape (n_components_, p)
        Orthonormal principal stamps.
    explained_variance_ : ndarray
        Weighted variance along every principal axis (kept or not), largest first.
    noise_variance_ : float
        ``sigma^2``: weighted mean noise variance per pixel of the normalised stamps.
    noise_edge_ : float
        The noise edge the variances are compared with.
    n_components_ : int
    stamp_size_ : int
    n_features_in_ : int

    See Also
    --------
    sklearn_psf.model.PSFModel : uses it as its default basis.
    StampNormalizer, FixedBasis : the paper's noise-blind basis pieces.

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.preprocessing import StampPCA
    >>> rng = np.random.default_rng(0)
    >>> yy, xx = np.mgrid[0:15, 0:15] - 7.0
    >>> sig = rng.uniform(2.0, 2.2, size=(200, 1, 1))       # one true component: the size
    >>> stars = 1e4 * np.exp(-0.5 * (xx**2 + yy**2) / sig**2) / (2 * np.pi * sig**2)
    >>> stamps = (stars + rng.normal(0, 5.0, stars.shape)).reshape(200, -1)
    >>> basis = StampPCA().fit(stamps)
    >>> basis.n_components_
    1
    >>> basis.inverse_transform(basis.transform(stamps[:2])).sum(axis=1).round(6)
    array([1., 1.])
    """

    def __init__(self, n_components="noise", max_components: int = 20, n_iter: int = 2,
                 max_star_weight: float = 10.0, guess_sigma: float = 3.0):
        self.n_components = n_components
        self.max_components = max_components
        self.n_iter = n_iter
        self.max_star_weight = max_star_weight
        self.guess_sigma = guess_sigma

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
        centre = (s - 1) / 2.0
        off = np.column_stack([np.asarray(mom["x0"]) - centre, np.asarray(mom["y0"]) - centre])
        off[~ok | ~np.isfinite(off).all(axis=1)] = 0.0
        return off, ok

    @staticmethod
    def _centred(stamps, offsets, s):
        """Stamps (n, p) moved by minus their offsets (centroid to the stamp centre)."""
        n = stamps.shape[0]
        return fourier_shift(stamps.reshape(n, s, s), -offsets[:, 0],
                             -offsets[:, 1]).reshape(n, -1)

    # -- the weighted least-squares fit of stamps on the basis ------------------------------
    def _fit_stamps(self, d, w, offsets, mean, comps, s):
        """Per-star flux, coefficients, their covariance, the model stamps and the offsets.

        Stars with masked pixels get their offsets refined by Gauss-Newton steps on the same
        weighted least-squares problem: adaptive moments of a stamp with a hole are biased
        towards the side that is left, a fit of the basis is not.
        """
        n, p = d.shape
        basis = np.vstack([mean[None, :], comps]).reshape(-1, s, s)
        basis_fft = np.fft.rfft2(basis)
        ky = 2j * np.pi * np.fft.fftfreq(s)[None, None, :, None]
        kx = 2j * np.pi * np.fft.rfftfreq(s)[None, None, None, :]
        m = basis.shape[0]
        offsets = offsets.copy()
        a = np.full((n, m), np.nan)
        cov = np.full((n, m, m), np.nan)
        model = np.zeros((n, p))
        masked = (w == 0).any(axis=1)
        for start in range(0, n, _CHUNK):
            sl = slice(start, min(start + _CHUNK, n))
            refine = masked[sl]
            for step in range(1 + _REFINE_STEPS * bool(refine.any())):
                phase = phase_ramp(s, offsets[sl, 0], offsets[sl, 1])
                A = _shifted(basis_fft, phase)  # (b, m, p)
                if step > 0:
                    # d(model)/d(offset): minus the spatial derivative of the shifted model
                    mfft = np.einsum("bi,iyx->byx", a[sl], basis_fft)[:, None] * phase[:, None]
                    grad = -np.fft.irfft2(np.concatenate([mfft * kx, mfft * ky], axis=1),
                                          s=(s, s)).reshape(-1, 2, p)
                    G = np.concatenate([A, grad], axis=1)
                    Gw = G * w[sl, None, :]
                    resid = d[sl] - model[sl]
                    sol = np.einsum("bij,bj->bi",
                                    np.linalg.pinv(np.einsum("bip,bjp->bij", Gw, G),
                                                   hermitian=True),
                                    np.einsum("bip,bp->bi", Gw, resid))
                    move = np.clip(sol[:, m:], -0.5, 0.5) * refine[:, None]
                    offsets[sl] += move
                    phase = phase_ramp(s, offsets[sl, 0], offsets[sl, 1])
                    A = _shifted(basis_fft, phase)
                Aw = A * w[sl, None, :]
                normal = np.einsum("bip,bjp->bij", Aw, A)
                rhs = np.einsum("bip,bp->bi", Aw, d[sl])
                inv = np.linalg.pinv(normal, hermitian=True)
                a[sl] = np.einsum("bij,bj->bi", inv, rhs)
                cov[sl] = inv
                model[sl] = np.einsum("bi,bip->bp", a[sl], A)
        return a, cov, model, offsets

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

    def _choose(self, lam, total, noise, n_eff, p):
        cap = lam.size
        if not isinstance(self.n_components, numbers.Integral):
            cap = min(int(self.max_components), cap)
        lam = lam[:cap]
        real = lam > 1e-12 * lam[0] if lam.size and lam[0] > 0 else np.zeros(0, bool)
        if isinstance(self.n_components, str):
            edge = noise * (1.0 + np.sqrt(p / n_eff)) ** 2
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
    def fit(self, X, y=None, weights=None):
        """Fit the basis on raw star stamps.

        Parameters
        ----------
        X : array-like of shape (n, s*s)
            Raw star stamps (any flux units), NaN for masked pixels. Not modified.
        y : ignored
        weights : array-like of shape (n, s*s), optional
            Inverse variance of each pixel (0 = masked). Default: estimated from each
            stamp's border.

        Returns
        -------
        self : StampPCA
        """
        self._check_params()
        d, w, s = self._stamps_and_weights(X, weights, reset=True)
        n, p = d.shape
        offsets, ok = self._centroids(d, w, s)
        flux = (d * (w > 0)).sum(axis=1)
        usable = ok & (flux > 0)
        if usable.sum() < 2:
            raise ValueError("Fewer than 2 stamps have a measurable centroid and a positive "
                             "flux: these are not star stamps.")
        mean = None
        comps = np.zeros((0, p))
        a = None
        model = np.zeros((n, p))  # the stars' current model: fills their masked pixels
        for _ in range(int(self.n_iter)):
            safe = np.where(usable, flux, 1.0)
            x = self._centred(np.where(w > 0, d, model), offsets, s) / safe[:, None]
            # per-pixel noise variance of each normalised stamp (0 on filled pixels)
            v = np.where(w > 0, 1.0 / np.where(w > 0, w, 1.0), 0.0).mean(axis=1) / safe**2
            u = np.where(usable, 1.0 / np.maximum(v, 1e-300), 0.0)
            med = np.median(u[usable])
            u = np.minimum(u, self.max_star_weight * med)
            if a is None and (w == 0).any():
                # first round with masked pixels: fill them from the weighted mean of the
                # stars that have those pixels (sub-pixel offsets neglected), then re-centre
                have = (w > 0) & usable[:, None]
                mean = (u[:, None] * have * x).sum(0) / np.maximum((u[:, None] * have).sum(0),
                                                                   1e-300)
                model = flux[:, None] * fourier_shift(
                    np.broadcast_to(mean.reshape(1, s, s), (n, s, s)), offsets[:, 0],
                    offsets[:, 1]).reshape(n, p)
                x = self._centred(np.where(w > 0, d, model), offsets, s) / safe[:, None]
            n_top = int(self.max_components) + 1
            if isinstance(self.n_components, numbers.Integral):
                n_top = max(n_top, int(self.n_components))
            mean, axes, lam, total = _weighted_pca(x[usable], u[usable], n_top)
            noise = float((u * v).sum() / u.sum())
            n_eff = float(u.sum() ** 2 / (u**2).sum())
            k, edge = self._choose(lam, total, noise, n_eff, p)
            comps = axes[:k]
            a, cov, model, offsets = self._fit_stamps(d, w, offsets, mean, comps, s)
            flux_new, _, _, _, good = self._coefficients(a, cov)
            usable = ok & good
            if usable.sum() < 2:
                raise ValueError("Fewer than 2 stamps keep a positive flux on the basis: these "
                                 "are not star stamps.")
            flux = np.where(good, flux_new, flux)
        norm = mean.sum()
        self.mean_ = mean / norm
        self.components_ = comps
        self.explained_variance_ = lam / norm**2
        self.noise_variance_ = noise / norm**2
        self.noise_edge_ = edge / norm**2
        self.n_components_ = int(k)
        self.stamp_size_ = s
        self._n_features_out = self.n_components_
        return self

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
        offsets, ok = self._centroids(d, w, s)
        a, cov, model, offsets = self._fit_stamps(d, w, offsets, self.mean_,
                                                  self.components_, s)
        flux, coef, var, ccov, good = self._coefficients(a, cov)
        flag = np.where(ok, FIT_OK, FIT_NO_CENTROID)
        flag[~good] = FIT_NO_FLUX
        return StampFit(coef, var, flux, offsets, model, w, flag, ccov)

    def render(self, coefficients, flux=1.0, offsets=None):
        """Model stamps in the stars' frame: ``flux * shift(mean + c @ components, offsets)``.

        Parameters
        ----------
        coefficients : array-like of shape (n, n_components_)
        flux : float or array-like of shape (n,), default=1
        offsets : array-like of shape (n, 2), optional
            (dx, dy) shifts in pixels; default none (centred stamps).

        Returns
        -------
        stamps : ndarray of shape (n, s*s)
        """
        check_is_fitted(self)
        coef = self._check_coefficients(coefficients)
        n, s = coef.shape[0], self.stamp_size_
        stamps = self.mean_ + coef @ self.components_
        if offsets is not None:
            off = np.asarray(offsets, dtype=np.float64).reshape(n, 2)
            stamps = fourier_shift(stamps.reshape(n, s, s), off[:, 0], off[:, 1]).reshape(n, -1)
        return stamps * np.broadcast_to(np.asarray(flux, dtype=np.float64), (n,))[:, None]

    def _check_coefficients(self, C):
        coef = np.asarray(C, dtype=np.float64)
        if coef.ndim != 2 or coef.shape[1] != self.n_components_:
            raise ValueError(
                f"Coefficients must have shape (n, {self.n_components_}), got {coef.shape}."
            )
        return coef

    def fit_transform(self, X, y=None, weights=None):
        """Fit, then return the coefficients of X (see :meth:`transform`).

        Parameters
        ----------
        X : array-like of shape (n, s*s)
        y : ignored
        weights : array-like of shape (n, s*s), optional

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
