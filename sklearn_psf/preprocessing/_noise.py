"""Pixel weights of star stamps: checking given ones, estimating them from the stamps."""

from __future__ import annotations

import warnings

import numpy as np

from .._validation import as_stamps, rows_text
from ._pca_noise import weighted_pca

__all__ = ["estimate_pixel_weights", "check_pixel_weights"]

_MAD_TO_SIGMA = 1.4826
#: Standard deviation of a standard normal truncated to [-3, 3]: corrects the clipped std.
_CLIPPED_STD = 0.98656


def _nanmedian(a, axis, keepdims=False):
    """``np.nanmedian(a, axis)``, the same values (NaN where a slice is all NaN, without a
    warning), 3-4x faster on stamps: one sort, NaN last (NumPy's takes a masked-array path for
    axes shorter than 600)."""
    ordered = np.sort(a, axis=axis)
    k = (~np.isnan(a)).sum(axis=axis, keepdims=True)
    lo = np.take_along_axis(ordered, np.maximum((k - 1) // 2, 0), axis)
    hi = np.take_along_axis(ordered, np.maximum(k // 2 - (k == 0), 0), axis)
    out = np.where(k > 0, (lo + hi) / 2, np.nan)
    return out if keepdims else np.squeeze(out, axis)


def _border_noise(edge, design, n_iter=3):
    """Per-row noise of ``edge`` (n, m) pixels (NaN = masked) about a local background.

    The background of each row is a linear combination of the columns of ``design`` (m, p)
    (a constant, and the stars' mean wing and its gradients), fitted by least squares on the
    pixels within 3 sigma of it (a neighbour or a cosmic ray is clipped); the noise is the
    clipped standard deviation of the residuals, started from their median absolute deviation.
    Returns the noise and the number of pixels it used.
    """
    finite = np.isfinite(edge)
    data = np.where(finite, edge, 0.0)
    p = design.shape[1]
    outer = (design[:, :, None] * design[:, None, :]).reshape(len(design), p * p)
    keep = finite
    sigma = None
    for it in range(n_iter + 1):
        k = keep.astype(np.float64)
        normal = (k @ outer).reshape(-1, p, p)  # (matrix products: BLAS)
        rhs = (k * data) @ design
        sol = np.einsum("nij,nj->ni", np.linalg.pinv(normal, hermitian=True), rhs)
        resid = np.where(finite, data - sol @ design.T, np.nan)
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN rows: NaN noise
            if it == 0:
                sigma = _MAD_TO_SIGMA * _nanmedian(np.abs(resid), axis=1, keepdims=True)
            else:
                m = keep.sum(axis=1, keepdims=True)
                sigma = np.sqrt(np.where(keep, resid**2, 0.0).sum(axis=1, keepdims=True)
                                / (m - p)) / _CLIPPED_STD
            keep = finite & (np.abs(resid) <= 3.0 * sigma)
    return sigma[:, 0], keep.sum(axis=1)


def estimate_pixel_weights(stamps, *, border="auto", pooled="auto"):
    """Inverse-variance pixel weights estimated from each stamp's own border.

    Each stamp's noise is measured on the pixels of its outer ring of width ``border``
    (sky-dominated for a star stamp) after removing the local background there: a 3-sigma
    clipped standard deviation about the clipped mean, so that a neighbour or a star's wing at
    the edge does not count. Each stamp keeps its own level, which is what unit-sum
    (normalised) stamps, stamps of stars on different sky levels or with different gains, and
    raw stamps all need: the noise of a normalised stamp is the sky noise over the star's flux.

    A single stamp's estimate scatters (a 25x25 stamp's ring of width 4 has 336 pixels: about
    4% in sigma); where stamps share one noise level it is pooled: with ``pooled="auto"``, when
    the stamps' estimates scatter no more than their own precision allows (raw stamps from one
    image), every stamp consistent with their median within three times that precision gets the
    median, the others (e.g. the brightest stars, whose wings reach the border) keep their own.

    Every pixel gets weight ``1 / sigma^2``; NaN pixels get weight 0 (masked). The stars' own
    Poisson noise is not included: give weights (e.g. from the image's weight map and gain)
    when it matters.

    Parameters
    ----------
    stamps : array-like of shape (n, s*s) or (n, s, s)
    border : int or "auto", default="auto"
        Width of the ring of pixels used, in pixels; "auto": ``max(2, round(s / 6))`` (4 for
        25x25 stamps).
    pooled : "auto" or bool, default="auto"
        True: one noise level for all stamps (the median of their estimates); False: each
        stamp its own; "auto": pooled where the stamps share one level (see above).

    Returns
    -------
    weights : ndarray of shape (n, s*s)
        Inverse variance per pixel, 0 for NaN pixels. A stamp whose border is constant
        (noise-free simulations) gets a noise of 1e-6 of its peak.

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.preprocessing import estimate_pixel_weights
    >>> rng = np.random.default_rng(0)
    >>> noise = np.array([1.0, 1.0, 4.0])[:, None]      # the third stamp is 4 times noisier
    >>> stamps = rng.normal(0.0, 1.0, size=(3, 25 * 25)) * noise
    >>> sigma = 1 / np.sqrt(estimate_pixel_weights(stamps)[:, 0])
    >>> np.round(sigma, 1)
    array([1. , 1. , 4.1])
    """
    cube = as_stamps(stamps)
    n, s, _ = cube.shape
    if isinstance(border, str):
        if border != "auto":
            raise ValueError(f"border must be 'auto' or a width in pixels, got {border!r}.")
        border = max(2, int(round(s / 6)))
    border = int(border)
    if not 1 <= border <= s // 2:
        raise ValueError(f"border must be between 1 and {s // 2} pixels, got {border}.")
    if not (pooled == "auto" or isinstance(pooled, (bool, np.bool_))):
        raise ValueError(f"pooled must be 'auto', True or False, got {pooled!r}.")
    ring = np.ones((s, s), dtype=bool)
    ring[border:s - border, border:s - border] = False
    sigma, m = _border_noise(cube[:, ring], _background_design(cube, ring))
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN stamps
        peak = np.nanmax(np.abs(cube.reshape(n, -1)), axis=1)
    floor = 1e-6 * np.where(np.isfinite(peak) & (peak > 0), peak, 1.0)
    good = np.isfinite(sigma) & (sigma > floor)
    sigma = np.where(good, sigma, floor)
    if pooled is True or (pooled is np.True_):
        sigma = np.full(n, np.median(sigma))
    elif pooled == "auto" and good.sum() >= 5:
        sigma = _pool_where_equal(sigma, m, good)
    weights = np.broadcast_to((1.0 / sigma**2)[:, None], (n, s * s)).copy()
    weights[np.isnan(cube.reshape(n, -1))] = 0.0
    return weights


def _background_design(cube, ring, min_stamps=10):
    """Columns of the local background on the ``ring`` pixels: a constant and, with at least
    ``min_stamps`` stamps, the stars' wing there (median unit-sum stamp, after each stamp's
    border median) and its x and y
    gradients (a star off the centre pixel); unit-norm columns."""
    columns = [np.ones(int(ring.sum()))]
    if len(cube) >= min_stamps:
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            # each stamp's border median removed first: a constant sky level does not change
            # the template (nor, then, the noise estimated around it)
            sub = cube - _nanmedian(cube[:, ring], axis=1)[:, None, None]
            total = np.nansum(sub, axis=(1, 2))
            positive = total > 0
            if positive.sum() >= min_stamps:
                mean = _nanmedian(sub[positive] / total[positive, None, None], axis=0)
                if np.isfinite(mean).all():
                    gy, gx = np.gradient(mean)
                    columns += [mean[ring], gx[ring], gy[ring]]
    design = np.column_stack(columns)
    norm = np.linalg.norm(design, axis=0)
    return design / np.where(norm > 0, norm, 1.0)


def _pool_where_equal(sigma, m, good):
    """The stamps' noise, pooled to the median where they share one level (see
    :func:`estimate_pixel_weights`)."""
    log = np.log(sigma[good])
    centre = float(np.median(log))
    # standard deviation of ln(sigma) estimated from m Gaussian pixels: 1 / sqrt(2 (m - 1))
    precision = 1.0 / np.sqrt(2.0 * np.maximum(m - 1, 1))
    spread = _MAD_TO_SIGMA * float(np.median(np.abs(log - centre)))
    if spread > 1.5 * float(np.median(precision[good])):
        return sigma  # several levels: each stamp keeps its own
    same = good & (np.abs(np.log(sigma) - centre) <= 3.0 * precision)
    return np.where(same, np.exp(centre), sigma)


def check_pixel_weights(weights, n_stamps: int, n_pixels: int, stamps=None):
    """Validated float64 weights of shape (n, p); NaN stamp pixels get weight 0 (a copy).

    Parameters
    ----------
    weights : array-like of shape (n, p) or (n, s, s)
        Inverse variance of each pixel, >= 0; 0 marks a masked pixel.
    n_stamps, n_pixels : int
        Expected shape.
    stamps : ndarray of shape (n, p), optional
        Stamps whose NaN pixels are masked.

    Returns
    -------
    weights : ndarray of shape (n, p)

    Raises
    ------
    ValueError
        For a wrong shape, or negative, NaN or infinite weights (rows named).
    """
    w = np.array(weights, dtype=np.float64, copy=True)
    if w.ndim == 3:
        w = w.reshape(w.shape[0], -1)
    if w.shape != (n_stamps, n_pixels):
        raise ValueError(
            f"weights must have the shape of the stamps ({n_stamps}, {n_pixels}), got "
            f"{np.shape(weights)}."
        )
    bad = ~(np.isfinite(w) & (w >= 0)).all(axis=1)
    if bad.any():
        raise ValueError(
            f"weights hold negative, NaN or infinite values at rows "
            f"{rows_text(np.flatnonzero(bad))}: pass inverse variances >= 0, with 0 for "
            "masked pixels."
        )
    if stamps is not None:
        w[np.isnan(stamps)] = 0.0
    return w


#: Lags (pixels, along each axis) of the noise correlation :func:`noise_correlation` measures.
CORRELATION_LAGS = 2


def noise_correlation(z, max_lag=CORRELATION_LAGS, threshold=0.05):
    """The correlation of the stamps' noise between neighbouring pixels.

    Resampled images (a reprojected survey frame, a mosaic, a scanned plate) carry noise
    correlated over a few pixels; a colour sensor's raw mosaic, anticorrelated. Measured on
    standardised residuals ``z`` (each star's stamp less its model, over its noise; NaN
    where left out, e.g. masked pixels and the stars' cores, where the PSF's own variations
    would pass for correlated noise), pixels beyond 5 sigma (neighbours, defects) left out:
    the mean product of pairs at each lag up to ``max_lag`` along each axis, over the mean
    square.

    Parameters
    ----------
    z : ndarray of shape (n, s*s)
        Standardised residuals, NaN where left out.
    max_lag : int, default=2
    threshold : float, default=0.05
        Correlations below it in size (and within 4 times their sampling error of 0) count as
        none.

    Returns
    -------
    kernel : ndarray of shape (2 max_lag + 1, 2 max_lag + 1) or None
        The correlation at each lag (1 at the centre, symmetric), or None when no lag's
        correlation departs from 0 (white noise).

    Examples
    --------
    >>> import numpy as np
    >>> from scipy.ndimage import uniform_filter
    >>> from sklearn_psf.preprocessing._noise import noise_correlation
    >>> rng = np.random.default_rng(0)
    >>> white = rng.normal(size=(200, 25, 25))
    >>> noise_correlation(white.reshape(200, -1)) is None
    True
    >>> smooth = uniform_filter(white, size=(1, 2, 1)) * np.sqrt(2)  # averaged along y
    >>> k = noise_correlation(smooth.reshape(200, -1))
    >>> round(float(k[1, 2]), 1), round(float(k[2, 3]), 2)     # lag 1 along y, along x
    (0.5, 0.0)
    """
    n, p = z.shape
    s = int(round(np.sqrt(p)))
    z = np.asarray(z, dtype=np.float64).reshape(n, s, s)
    good = np.isfinite(z)
    z = np.where(good, z, 0.0)
    scale = np.sqrt((z**2).sum() / max(good.sum(), 1))
    good &= np.abs(z) <= 5 * scale
    z = np.where(good, z, 0.0)
    power = (z**2).sum() / max(good.sum(), 1)
    L = int(max_lag)
    kernel = np.zeros((2 * L + 1, 2 * L + 1))
    kernel[L, L] = 1.0
    significant = False
    for dy in range(0, L + 1):
        for dx in range(-L, L + 1):
            if dy == 0 and dx <= 0:
                continue
            lo, hi = max(0, -dx), s - max(0, dx)  # columns of the first pixel of each pair
            a, ga = z[:, :s - dy, lo:hi], good[:, :s - dy, lo:hi]
            b, gb = z[:, dy:, lo + dx:hi + dx], good[:, dy:, lo + dx:hi + dx]
            pairs = ga & gb
            count = int(pairs.sum())
            if count < 100:
                continue
            rho = float((a * b)[pairs].sum() / count / power)
            kernel[L + dy, L + dx] = kernel[L - dy, L - dx] = rho
            significant |= abs(rho) > max(threshold, 4.0 / np.sqrt(count))
    return kernel if significant else None


def standardised_residuals(x, mean, scale, weights, level=1e-2):
    """Residuals of normalised stamps from their mean over their noise, NaN on masked
    pixels and on the mean's core (where it exceeds ``level`` of its peak: the PSF's own
    variations are there), for :func:`noise_correlation`.

    Parameters
    ----------
    x : ndarray of shape (n, p)
        Normalised stamps: the raw ones divided by ``scale`` (at each star's phase for
        undersampled stars).
    mean : ndarray of shape (p,) or (n, p)
        Their mean (at each star's phase, for undersampled stars).
    scale : ndarray of shape (n,)
        Each stamp's normalisation (its flux).
    weights : ndarray of shape (n, p)
        The raw stamps' pixel weights (inverse variance, 0 = masked).
    level : float, default=0.01

    Returns
    -------
    ndarray of shape (n, p)
    """
    mean = np.broadcast_to(mean, x.shape)
    z = (x - mean) * np.sqrt(weights) * np.asarray(scale, dtype=np.float64)[:, None]
    outer = mean < level * mean.max(axis=1, keepdims=True)
    return np.where((weights > 0) & outer, z, np.nan)


def correlated_noise_factor(kernel, variances, star_weights, s, pixels=None, draws=3, seed=0):
    """How much noise correlated as ``kernel`` raises the largest eigenvalue of the stars'
    weighted covariance above white noise of the same variance (the ratio of the two, each
    averaged over ``draws`` pure-noise samples of these stars, paired: the same white draws
    filtered by the kernel's power spectrum). 1 for ``kernel`` None.

    Parameters
    ----------
    kernel : ndarray of shape (2L+1, 2L+1) or None
        From :func:`noise_correlation`.
    variances : ndarray of shape (n,)
        Each star's noise variance per pixel (of its normalised stamp).
    star_weights : ndarray of shape (n,)
        Each star's weight in the covariance.
    s : int
        Stamp side.
    pixels : ndarray of shape (s*s,), bool, optional
        The pixels the covariance is of (default all).
    draws : int, default=3
    seed : int, default=0

    Returns
    -------
    float
    """
    if kernel is None:
        return 1.0
    L = kernel.shape[0] // 2
    grid = np.zeros((s, s))
    for dy in range(-L, L + 1):
        for dx in range(-L, L + 1):
            grid[dy % s, dx % s] += kernel[L + dy, L + dx]
    psd = np.maximum(np.fft.rfft2(grid).real, 0.0)
    psd *= grid[0, 0] * s * s / max(float(np.fft.irfft2(psd, s=(s, s))[0, 0] * s * s), 1e-300)
    filt = np.sqrt(psd)
    rng = np.random.default_rng(seed)
    sd = np.sqrt(np.asarray(variances, dtype=np.float64))[:, None]
    u = np.asarray(star_weights, dtype=np.float64)
    top = np.zeros((2, draws))
    for k in range(draws):
        white = rng.standard_normal((len(sd), s, s))
        tinted = np.fft.irfft2(np.fft.rfft2(white) * filt, s=(s, s))
        for j, noise in enumerate((white, tinted)):
            flat = noise.reshape(len(sd), -1)
            top[j, k] = weighted_pca(sd * (flat if pixels is None else flat[:, pixels]), u,
                                      1)[2][0]
    return float(top[1].mean() / top[0].mean())
