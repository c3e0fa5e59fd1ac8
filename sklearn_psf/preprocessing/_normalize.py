"""Flux normalisation and centring of postage stamps."""

from __future__ import annotations

import warnings
from numbers import Integral, Real

import numpy as np
from sklearn.base import BaseEstimator, OneToOneFeatureMixin, TransformerMixin, _fit_context
from sklearn.utils._param_validation import Interval
from sklearn.utils.validation import check_is_fitted, validate_data

from .._persist import StateMixin
from .._validation import rows_text
from ..measure._moments import adaptive_moments

__all__ = ["StampNormalizer", "CentringWarning", "fourier_shift"]


class CentringWarning(UserWarning):
    """A stamp could not be centred (its adaptive moments failed) and was left unshifted."""



def fourier_shift(cube, dx, dy):
    """Shift stamps by (dx, dy) pixels with a Fourier phase ramp (periodic, flux-conserving).

    Any side s: for even s the Nyquist frequency, which cannot carry a real shift, is left
    unshifted (see :func:`phase_ramp`); a sampled PSF has next to no power there.

    Parameters
    ----------
    cube : ndarray of shape (n, s, s)
        Stamps indexed [row=y, col=x].
    dx, dy : array-like of shape (n,)
        Shift along x (columns) and y (rows); the content moves by +dx, +dy.

    Returns
    -------
    shifted : ndarray of shape (n, s, s)

    Examples
    --------
    >>> import numpy as np
    >>> img = np.zeros((1, 5, 5)); img[0, 2, 2] = 1.0
    >>> out = fourier_shift(img, [1.0], [0.0])
    >>> np.round(out[0, 2], 12) + 0.0
    array([0., 0., 0., 1., 0.])
    """
    cube = np.asarray(cube, dtype=np.float64)
    s = cube.shape[-1]
    dx = np.asarray(dx, dtype=np.float64).reshape(-1)
    dy = np.asarray(dy, dtype=np.float64).reshape(-1)
    return np.fft.irfft2(np.fft.rfft2(cube) * phase_ramp(s, dx, dy), s=(s, s))


def phase_ramp(s, dx, dy):
    """Half-plane Fourier phase ramps (n, s, s//2+1) moving s x s images by (+dx, +dy) pixels.

    Multiply an ``rfft2`` by it and invert with ``irfft2``. For even ``s`` the Nyquist
    frequency cannot carry a real shift: its phase is dropped (kept symmetric).
    """
    ky = np.fft.fftfreq(s)
    kx = np.fft.rfftfreq(s)
    if s % 2 == 0:
        ky = np.where(np.abs(ky) == 0.5, 0.0, ky)
        kx = np.where(np.abs(kx) == 0.5, 0.0, kx)
    # separable: the product of a ramp along x and one along y (2 s exponentials per image)
    return (np.exp(-2j * np.pi * ky[None, :, None] * np.asarray(dy)[:, None, None])
            * np.exp(-2j * np.pi * kx[None, None, :] * np.asarray(dx)[:, None, None]))


class StampNormalizer(StateMixin, OneToOneFeatureMixin, TransformerMixin, BaseEstimator):
    """Normalise flattened square stamps to unit flux and centre them.

    The convention, used everywhere in sklearn_psf (simulation, model, test) so that PCA
    coefficients keep their meaning:

    1. flux: each stamp is divided by the sum of its pixels (sum = 1 afterwards);
    2. centring: the adaptive-moment centroid (Gaussian-weighted, robust to noise; see
       :func:`sklearn_psf.measure.adaptive_moments`) is moved to the stamp centre
       ((s-1)/2, (s-1)/2) (0-based; for an even side s, the corner shared by the four
       central pixels, GalSim's ``true_center``) by a sub-pixel Fourier shift, which
       conserves the flux exactly and treats the stamp as periodic (stamps should go to ~0
       at their border; for even s the Nyquist frequency, which cannot carry a real shift,
       is left unshifted: negligible for a sampled PSF). The shift is
       repeated (at most ``max_centring_steps`` times) until the centroid is within
       ``center_tol`` pixels of the centre; stamps already centred within ``center_tol`` are
       not shifted, which makes the transform idempotent.

    Stamps whose adaptive moments fail (e.g. pure noise) are left unshifted with a
    :class:`CentringWarning` naming the rows.

    Parameters
    ----------
    flux : bool, default=True
        Divide each stamp by its sum.
    center : bool, default=True
        Shift each stamp so that its adaptive centroid is at the stamp centre.
    center_tol : float, default=1e-4
        Centroid offset (pixels) below which a stamp counts as centred.
    max_centring_steps : int, default=3
        Largest number of measure-and-shift rounds.
    guess_sigma : float, default=3.0
        Initial width (pixels) of the adaptive weight used to find the centroid.

    Attributes
    ----------
    n_features_in_ : int
        Number of pixels per stamp (s*s).
    stamp_size_ : int
        Side s of the stamps.

    Notes
    -----
    ``inverse_transform`` returns its input unchanged (a copy): the original fluxes and offsets
    are not kept, so "inverse" stamps are the normalised ones. This makes
    ``Pipeline(...).inverse_transform`` work and return normalised stamps.

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.preprocessing import StampNormalizer
    >>> y, x = np.mgrid[0:15, 0:15]
    >>> star = 50.0 * np.exp(-0.5 * ((x - 7.3) ** 2 + (y - 6.8) ** 2) / 2.0**2)
    >>> out = StampNormalizer().fit_transform(star.reshape(1, -1))
    >>> print(round(out.sum(), 12))
    1.0
    """

    _parameter_constraints: dict = {
        "flux": ["boolean"],
        "center": ["boolean"],
        "center_tol": [Interval(Real, 0, None, closed="left")],
        "max_centring_steps": [Interval(Integral, 0, None, closed="left")],
        "guess_sigma": [Interval(Real, 0, None, closed="neither")],
    }

    _state_attributes = ("stamp_size_", "n_features_in_")

    def __init__(
        self,
        flux: bool = True,
        center: bool = True,
        center_tol: float = 1e-4,
        max_centring_steps: int = 3,
        guess_sigma: float = 3.0,
    ):
        self.flux = flux
        self.center = center
        self.center_tol = center_tol
        self.max_centring_steps = max_centring_steps
        self.guess_sigma = guess_sigma

    def _validate_stamp_size(self, n_features):
        s = int(round(np.sqrt(n_features)))
        if s * s != n_features:
            raise ValueError(
                f"Stamps have {n_features} pixels, not a square number: pass flattened square "
                "stamps of shape (n, s*s)."
            )
        return s

    @_fit_context(prefer_skip_nested_validation=True)
    def fit(self, X, y=None, weights=None):
        """Check the stamps and record their size.

        Parameters
        ----------
        X : array-like of shape (n, s*s)
            Flattened square stamps.
        y : ignored
        weights : ignored
            Accepted so that ``fit_transform(X, weights=...)`` works.

        Returns
        -------
        self : StampNormalizer
        """
        X = validate_data(self, X, dtype=np.float64, ensure_all_finite=False)
        self.stamp_size_ = self._validate_stamp_size(X.shape[1])
        return self

    def transform(self, X, weights=None):
        """Normalise and centre stamps.

        Parameters
        ----------
        X : array-like of shape (n, s*s)
            Flattened square stamps. Not modified. NaN pixels are masked pixels.
        weights : array-like of shape (n, s*s), optional
            Pixel weights (inverse variance); 0 marks a masked pixel. Only the mask is used:
            a masked pixel is filled with the stamp's value at the point-symmetric position
            through the star's adaptive centroid (the stamp rotated by 180 degrees about it,
            with a sub-pixel Fourier shift; three rounds of fill and re-measured centroid),
            before the flux normalisation and centring. PSFs are close to point-symmetric, so this is a fair fill for a
            few pixels; for stamps with many masked pixels prefer
            :class:`StampPCA`, which leaves them out of a weighted fit.

        Returns
        -------
        Xt : ndarray of shape (n, s*s)
            Normalised stamps (float64).

        Raises
        ------
        ValueError
            For infinite pixels, all-zero stamps or non-positive flux (naming the rows).
        """
        check_is_fitted(self)
        X = validate_data(self, X, dtype=np.float64, reset=False, ensure_all_finite=False,
                          copy=True)
        masked = np.isnan(X)
        if weights is not None:
            w = np.asarray(weights, dtype=np.float64).reshape(X.shape[0], -1)
            if w.shape != X.shape:
                raise ValueError(f"weights must have the shape of the stamps {X.shape}, got "
                                 f"{np.shape(weights)}.")
            masked |= w == 0
        bad = np.isinf(X).any(axis=1) | masked.all(axis=1)
        if bad.any():
            raise ValueError(
                f"Stamps with infinite or only masked pixels at rows "
                f"{rows_text(np.flatnonzero(bad))}: remove them (e.g. using the flags of "
                "cut_stamps) before normalising."
            )
        if masked.any():
            X = self._fill_masked(X, masked)
        total = X.sum(axis=1)
        zero = ~(X != 0).any(axis=1)
        if zero.any():
            raise ValueError(f"All-zero stamps at rows {rows_text(np.flatnonzero(zero))}.")
        if self.flux:
            nonpos = ~(total > 0)
            if nonpos.any():
                raise ValueError(
                    f"Stamps with non-positive total flux at rows "
                    f"{rows_text(np.flatnonzero(nonpos))}: they cannot be flux-normalised."
                )
            X /= total[:, None]
        if self.center:
            X = self._centre(X)
        return X

    @_fit_context(prefer_skip_nested_validation=True)
    def fit_transform(self, X, y=None, weights=None):
        """Fit, then normalise and centre X (see :meth:`transform`).

        Parameters
        ----------
        X : array-like of shape (n, s*s)
            Star stamps, flattened; not modified.
        y : ignored
            Accepted for scikit-learn's API.
        weights : array-like of shape (n, s*s), optional
            Inverse variance of each pixel (0 = masked), as :meth:`fit` takes them.

        Returns
        -------
        Xt : ndarray of shape (n, s*s)
        """
        return self.fit(X).transform(X, weights=weights)

    def _fill_masked(self, X, masked):
        """Masked pixels from their point-symmetric partner through the centroid."""
        s = self.stamp_size_
        rows = np.flatnonzero(masked.any(axis=1))
        cube = np.where(masked, 0.0, X)[rows].reshape(-1, s, s)
        mask = masked[rows].reshape(-1, s, s)
        centre = (s - 1) / 2.0
        weights = np.where(mask, 0.0, 1.0)
        for step in range(3):  # the centroid of a stamp with a hole is biased: measure, fill,
            # measure again on the filled stamp
            mom = adaptive_moments(cube, weights=weights if step == 0 else None,
                                   guess_sigma=self.guess_sigma)
            ok = np.asarray(mom["flag"]) == 0
            dx = np.where(ok, np.asarray(mom["x0"]) - centre, 0.0)
            dy = np.where(ok, np.asarray(mom["y0"]) - centre, 0.0)
            # the stamp rotated by 180 degrees about its centroid (a sub-pixel Fourier shift
            # of the flipped stamp): the point-symmetric partner of every pixel
            mirror = fourier_shift(cube[:, ::-1, ::-1], 2 * dx, 2 * dy)
            cube = np.where(mask, mirror, cube)
        X = np.where(masked, 0.0, X)
        X[rows] = cube.reshape(len(rows), -1)
        return X

    def _centre(self, X):
        s = self.stamp_size_
        cube = X.reshape(-1, s, s)
        centre = (s - 1) / 2.0
        todo = np.arange(cube.shape[0])
        failed = []
        for _ in range(int(self.max_centring_steps)):
            if not todo.size:
                break
            t = adaptive_moments(cube[todo], guess_sigma=self.guess_sigma)
            ok = np.asarray(t["flag"]) == 0
            failed.extend(todo[~ok].tolist())
            dx = centre - np.asarray(t["x0"])
            dy = centre - np.asarray(t["y0"])
            move = ok & ((np.abs(dx) > self.center_tol) | (np.abs(dy) > self.center_tol))
            if not move.any():
                break
            idx = todo[move]
            cube[idx] = fourier_shift(cube[idx], dx[move], dy[move])
            todo = idx
        if failed:
            warnings.warn(
                f"Adaptive moments failed for stamps at rows {rows_text(sorted(set(failed)))}; "
                "they were left uncentred.",
                CentringWarning,
                stacklevel=3,
            )
        return cube.reshape(X.shape)

    def inverse_transform(self, X):
        """Return the normalised stamps unchanged (a copy); see Notes.

        Parameters
        ----------
        X : array-like of shape (n, s*s)

        Returns
        -------
        X : ndarray of shape (n, s*s)
        """
        check_is_fitted(self)
        return np.array(X, dtype=np.float64, copy=True)

    def __sklearn_tags__(self):
        tags = super().__sklearn_tags__()
        tags.input_tags.allow_nan = True  # NaN pixels are masked pixels
        return tags
