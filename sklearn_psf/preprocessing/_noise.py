"""Pixel weights of star stamps: checking given ones, estimating them from the stamps."""

from __future__ import annotations

import warnings

import numpy as np

from .._validation import as_stamps, rows_text

__all__ = ["estimate_pixel_weights", "check_pixel_weights"]

_MAD_TO_SIGMA = 1.4826



def estimate_pixel_weights(stamps, *, border: int = 2, pooled: bool = True):
    """Inverse-variance pixel weights estimated from each stamp's border.

    The background noise of each stamp is 1.4826 times the median absolute deviation of the
    pixels in its outer ring of width ``border`` (sky-dominated for a star stamp; robust to a
    neighbour at the edge). With ``pooled=True`` (stamps from one image, one sky noise) every
    stamp gets the median of these estimates, which is far less noisy than each one (a 25x25
    stamp's ring has 184 pixels: about 10% scatter in sigma per stamp); otherwise each stamp
    keeps its own. Every pixel gets weight ``1 / sigma^2``; NaN pixels get weight 0 (masked).
    The stars' own Poisson noise is not included: give weights (e.g. from the image's weight
    map) when it matters, or when the stamps come from images of different depths.

    Parameters
    ----------
    stamps : array-like of shape (n, s*s) or (n, s, s)
    border : int, default=2
        Width of the ring of pixels used, in pixels.
    pooled : bool, default=True
        One noise level for all stamps (the median of the stamps' estimates).

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
    >>> stamps = rng.normal(0.0, 2.0, size=(3, 25 * 25))
    >>> w = estimate_pixel_weights(stamps)
    >>> bool(np.allclose(1 / np.sqrt(w[:, 0]), 2.0, rtol=0.2))
    True
    """
    cube = as_stamps(stamps)
    n, s, _ = cube.shape
    border = int(border)
    if not 1 <= border <= s // 2:
        raise ValueError(f"border must be between 1 and {s // 2} pixels, got {border}.")
    ring = np.ones((s, s), dtype=bool)
    ring[border:s - border, border:s - border] = False
    edge = cube[:, ring]
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN stamps: handled below
        med = np.nanmedian(edge, axis=1, keepdims=True)
        sigma = _MAD_TO_SIGMA * np.nanmedian(np.abs(edge - med), axis=1)
        peak = np.nanmax(np.abs(cube.reshape(n, -1)), axis=1)
    floor = 1e-6 * np.where(np.isfinite(peak) & (peak > 0), peak, 1.0)
    sigma = np.where(np.isfinite(sigma) & (sigma > floor), sigma, floor)
    if pooled:
        sigma = np.full(n, np.median(sigma))
    weights = np.broadcast_to((1.0 / sigma**2)[:, None], (n, s * s)).copy()
    weights[np.isnan(cube.reshape(n, -1))] = 0.0
    return weights


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
