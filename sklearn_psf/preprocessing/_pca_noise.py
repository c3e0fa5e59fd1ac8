"""The weighted PCA of the stamps and what their noise allows of it: the PCA itself (on the
smaller Gram matrix), the stars' capped weights, components made to sum to zero, the noise
edge (the generalised Marchenko-Pastur edge, with a Tracy-Widom margin) that bounds the
number of components :class:`StampPCA` keeps, and the mean's wings denoised ring by ring
(:func:`radial_wings`) beyond the PSF's core."""

from __future__ import annotations

import numpy as np
from scipy.linalg import eigh
from scipy.optimize import minimize_scalar

_TRACY_WIDOM_99 = 2.0234  # 99th percentile of the Tracy-Widom law (real case, TW1)


def weighted_pca(x, u, n_top):
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


def star_weights(v, usable, cap):
    """PCA weight of each star, ``1 / v`` (its S/N), capped at ``cap`` times the median of
    the usable stars; 0 for unusable ones."""
    u = np.where(usable, 1.0 / np.maximum(v, 1e-300), 0.0)
    return np.minimum(u, cap * np.median(u[usable]))


def sum_zero(axes, mean):
    """Orthonormal components summing to zero that span, with the unit-sum ``mean``, what the
    ``axes`` span with it (in their order)."""
    if not len(axes):
        return axes
    q, r = np.linalg.qr((axes - np.outer(axes.sum(axis=1), mean)).T)
    return (q * np.where(np.diag(r) < 0, -1.0, 1.0)).T


def ring_radii(s):
    """Each pixel's ring about the centre of an s x s stamp: ``floor(r)``, r in pixels."""
    yy, xx = np.mgrid[0:s, 0:s] - (s - 1) / 2.0
    return np.floor(np.hypot(xx, yy)).astype(np.int64).ravel()


def core_pixels(mean, s, level=1e-2):
    """Where the mean stamp exceeds ``level`` of its peak, grown by one pixel: the PSF's
    core, where its variations show (as :class:`SuperResolvedPCA`'s components' support)."""
    from scipy.ndimage import binary_dilation

    core = (mean > level * mean.max()).reshape(s, s)
    return binary_dilation(core).ravel()


def radial_wings(mean, var, s, correlation=1.0):
    """The mean PSF stamp with the noise of its faint wings taken out, ring by ring, and the
    radius of its support.

    In each 1-pixel ring about the centre, the mean is split into its ring average (the
    azimuthal profile) and each pixel's departure from it; each part is kept in proportion
    to its signal's share of signal plus noise (a Wiener factor): the profile by
    ``max(P^2 - N^2, 0) / P^2`` (``N^2`` the noise of the ring's average), the departures by
    ``S^2 / (S^2 + var)`` (``S^2`` their variance in the ring in excess of the pixels'
    noise). Where the stars measure the PSF well (the core) nothing changes; in the wings,
    where a single pixel of the mean holds more noise than PSF, what remains is the profile
    averaged over the ring (its noise divided by the ring's pixel count) and the shape the
    noise does not drown; beyond the last ring the stars detect, zero. The support radius is
    the first ring whose profile falls below its pixels' noise (infinite when none does).

    Parameters
    ----------
    mean : ndarray of shape (s*s,)
    var : ndarray of shape (s*s,)
        Noise variance of each pixel of ``mean``.
    s : int
    correlation : float, default=1
        How much more noise a ring's average holds than its pixels' independent noise
        would give (the sum of the noise's correlation over lags: 1 for white noise).

    Returns
    -------
    denoised : ndarray of shape (s*s,)
    radius : float
    """
    ring = ring_radii(s)
    count = np.bincount(ring).astype(np.float64)
    profile = np.bincount(ring, mean) / count
    dev = mean - profile[ring]
    noise = correlation * np.bincount(ring, var) / count**2
    excess = np.maximum(np.bincount(ring, dev**2 - var * (1.0 - 1.0 / count[ring])) / count,
                        0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        keep_profile = np.where(profile**2 > noise, 1.0 - noise / profile**2, 0.0)
        keep_dev = np.where(excess[ring] + var > 0, excess[ring] / (excess[ring] + var), 1.0)
    below = np.flatnonzero(np.abs(profile) < np.sqrt(np.bincount(ring, var) / count))
    radius = float(below[0]) if below.size else np.inf
    return profile[ring] * keep_profile[ring] + keep_dev * dev, radius


def noise_edge(contributions, p: int, quantile: bool = False) -> float:
    """Largest eigenvalue of ``sum_i c_i z_i z_i^T`` for ``z_i`` standard normal in ``p``
    dimensions, as the number of terms and ``p`` grow (the edge of the generalised
    Marchenko-Pastur law), or its 99th percentile for a finite sample.

    The upper edge of the support is ``p * min x(m)`` over ``-1 / max(c) < m < 0`` with
    ``x(m) = -1/m + sum_i c_i / (1 + c_i m) / p`` (Silverstein & Choi 1995). For equal
    ``c_i = sigma^2 / n`` this is Marchenko-Pastur's ``sigma^2 (1 + sqrt(p / n))^2``. With
    ``quantile=True``, the edge is raised by the 99th percentile of the Tracy-Widom law on
    Johnstone's (2001) scale, with ``n`` the effective number of terms
    ``(sum c)^2 / sum c^2`` less one (a mean removed): pure noise exceeds it in 1% of
    samples.

    Parameters
    ----------
    contributions : array-like of shape (n,)
        ``c_i >= 0``: each term's weight times its noise variance.
    p : int
        Dimension.
    quantile : bool, default=False
        The 99th percentile for a finite sample instead of the asymptotic edge.

    Returns
    -------
    edge : float

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.preprocessing._pca_noise import noise_edge
    >>> round(float(noise_edge(np.full(1000, 1e-3), 625) / (1 + np.sqrt(0.625)) ** 2), 6)
    1.0
    """
    c = np.asarray(contributions, dtype=np.float64)
    c = c[c > 0]
    if not c.size:
        return 0.0
    c_max = c.max()

    def x(t):  # t = m * c_max in (-1, 0)
        m = t / c_max
        return -1.0 / m + np.sum(c / (1.0 + c * m)) / p

    t = minimize_scalar(x, bounds=(-1.0 + 1e-12, -1e-12), method="bounded",
                        options={"xatol": 1e-12}).x
    edge = float(p * x(t))
    if not quantile:
        return edge
    # Johnstone (2001): the largest eigenvalue fluctuates about the edge on the scale
    # (1/sqrt(n) + 1/sqrt(p))^(1/3) / (sqrt(n) + sqrt(p)) (relative), n the effective number
    # of terms less the one the mean removes, following the Tracy-Widom law
    n = max(c.sum() ** 2 / (c**2).sum() - 1.0, 1.0)
    scale = (1.0 / np.sqrt(n) + 1.0 / np.sqrt(p)) ** (1.0 / 3.0) / (np.sqrt(n) + np.sqrt(p))
    return edge * (1.0 + _TRACY_WIDOM_99 * scale)
