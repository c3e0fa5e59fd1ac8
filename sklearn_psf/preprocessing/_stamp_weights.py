"""The stamps' pixel weights and local background, as the stamp bases fit them: the pixel
variances of the weights (and of a weighted mean of the stamps), the Poisson part of
weights that were computed from the noisy pixels themselves (its slope, and the weights
with it taken from the stars' models instead), and each stamp's border level, from which
:class:`StampPCA` and :class:`SuperResolvedPCA` decide whether the stamps carry a local
background."""

from __future__ import annotations

import warnings

import numpy as np

from ._noise import _nanmedian


def variances(w):
    """Pixel variances ``1 / w`` of the weights ``w``, 0 where a pixel is masked (``w = 0``)."""
    m = w > 0
    return np.where(m, 1.0 / np.where(m, w, 1.0), 0.0)


def mean_variance(w, scale, u):
    """Per-pixel noise variance of the weighted mean ``sum_i u_i x_i / sum(u)`` of the
    normalised stamps ``x_i = d_i / scale_i`` (pixel variances ``1 / w``; masked pixels,
    filled from a model, add none)."""
    c = u / u.sum()
    return (c**2 / np.where(c > 0, scale, 1.0) ** 2) @ variances(w)


def poisson_slope(d, w):
    """Slope ``c`` when each stamp's pixel variances ``1 / w`` are exactly ``sky + c *
    max(pixel, 0)`` (one ``sky`` per stamp): weights whose Poisson part was computed from
    the noisy pixels themselves (:func:`~sklearn_psf.exposure.extract_vignettes` with a gain, as
    ``sklearn-psf fit --stars`` reads a catalogue, ``c = 1 / gain``); 0 for any other
    weights."""
    m = w > 0
    cnt = np.maximum(m.sum(axis=1), 1)[:, None]
    v = variances(w)
    x = np.where(m, np.maximum(d, 0.0), 0.0)
    xc = np.where(m, x - x.sum(axis=1, keepdims=True) / cnt, 0.0)
    vc = np.where(m, v - v.sum(axis=1, keepdims=True) / cnt, 0.0)
    sxx = float((xc**2).sum())
    if not sxx > 0:
        return 0.0
    c = float((xc * vc).sum()) / sxx
    exact = ((vc - c * xc) ** 2).sum() <= 1e-8 * (vc**2).sum()
    return c if c > 0 and exact else 0.0


def model_weights(d, w, predicted, c):
    """The weights ``w`` with their Poisson part ``c * max(pixel, 0)`` (see
    :func:`poisson_slope`) taken from the stars' predicted pixels (NaN: kept) instead of
    the noisy ones, which give the pixels where the noise is up less weight and so bias
    the fit low (by ``c`` per pixel)."""
    if not c:
        return w
    m = w > 0
    var = 1.0 / np.where(m, w, 1.0) + c * (np.maximum(predicted, 0.0) - np.maximum(d, 0.0))
    return np.where(m & np.isfinite(predicted), 1.0 / np.where(m, var, 1.0), w)


def border_level(d, w, s, border=2):
    """Median of each stamp's unmasked pixels in its outer ring of ``border`` pixels (0 when
    the ring is all masked), a first estimate of its local background, and the noise of that
    median (1.2533 sigma / sqrt(pixels))."""
    ring = np.ones((s, s), dtype=bool)
    ring[border:s - border, border:s - border] = False
    good = w[:, ring.ravel()] > 0
    edge = np.where(good, d[:, ring.ravel()], np.nan)
    var = np.where(good, 1.0 / np.where(good, w[:, ring.ravel()], 1.0), np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-masked rings: 0 below
        level = _nanmedian(edge, axis=1)
        noise = 1.2533 * np.sqrt(_nanmedian(var, axis=1) / np.maximum(good.sum(axis=1), 1))
    ok = np.isfinite(level) & np.isfinite(noise)
    return np.where(ok, level, 0.0), np.where(ok, noise, np.inf)


def has_background(d, w, s):
    """Whether the stamps' borders show a local background that a PSF's wings cannot make.

    A PSF's wings put on each stamp's border a level proportional to the star's flux,
    positive, and nearly the same fraction of it for every star (2.4% scatter in the
    package's simulations). The stamps have a background when more than 5% of them have a
    border median more than 4 times its noise (plus 10% of the wings' level) away from that
    proportion, or when the common proportion is negative.
    """
    level, noise = border_level(d, w, s)
    flux = ((d - level[:, None]) * (w > 0)).sum(axis=1)
    good = (flux > 0) & np.isfinite(noise)
    if good.sum() < 2:
        return False
    kappa = max(float(np.median(level[good] / flux[good])), 0.0)
    wings = kappa * flux[good]
    off = np.abs(level[good] - wings) > 4.0 * np.hypot(noise[good], 0.1 * wings)
    return bool(off.mean() > 0.05)
