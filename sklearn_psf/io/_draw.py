"""PSFs at exact (sub-pixel) positions, optionally oversampled, and extrapolation flags.

Convention (as PSFEx and PIFF draw a PSF): the stamp of a position (x, y) is centred on its
nearest pixel ``(floor(x + 0.5), floor(y + 0.5))``, the stamp's centre pixel
``((s-1)/2, (s-1)/2)``; with ``centered=True`` the profile inside the stamp is shifted by the
fractional offset ``(x - floor(x + 0.5), y - floor(y + 0.5))``, in [-0.5, 0.5), so its centroid
falls where the star is. ``PSFModel.predict`` returns the profile centred on the centre pixel
(the stars are centred by the normaliser before the fit).
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import map_coordinates
from scipy.spatial import Delaunay, QhullError, cKDTree

__all__ = ["draw_psf", "extrapolation_flags"]


def draw_psf(model, positions, *, centered: bool = True, oversampling: int = 1) -> np.ndarray:
    """The model PSF at each position, at its sub-pixel place, optionally oversampled.

    The model's pixel-grid stamp is resampled with a cubic spline
    (:func:`scipy.ndimage.map_coordinates`, zero outside the stamp; PSFEx uses a Lanczos
    kernel) at the points ``c + (j - (S - 1) / 2) / oversampling - offset`` of each axis
    (``c`` the centre pixel, ``S = s * oversampling``, ``offset`` the fractional position of
    the module's convention when ``centered``), then scaled to unit sum. With
    ``oversampling`` > 1 the samples are point values of the interpolated pixelated profile,
    spaced 1/oversampling pixel.

    Parameters
    ----------
    model : fitted PSFModel (or any estimator whose ``predict(X)`` returns (n, s*s) stamps)
    positions : array-like of shape (n, 2) or (n, 2 + m)
        (x, y), 0-based pixels, then the model's extra dimensions (a colour, a magnitude) if
        it has any: passed to ``predict``; the sub-pixel offsets come from (x, y).
    centered : bool, default=True
        Shift each PSF by its position's fractional offset.
    oversampling : int, default=1

    Returns
    -------
    ndarray of shape (n, S, S)
        Unit-sum PSFs, S = s * oversampling; with ``centered=False`` and ``oversampling=1``
        the model's ``predict`` stamps as they are.

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.io import draw_psf
    >>> class Gaussian:                      # any model whose predict gives stamps
    ...     def predict(self, X):
    ...         yy, xx = np.mgrid[-7:8, -7:8]
    ...         g = np.exp(-(xx**2 + yy**2) / 8.0).ravel()
    ...         return np.tile(g / g.sum(), (len(X), 1))
    >>> psf = draw_psf(Gaussian(), [[10.3, 20.0]])
    >>> xx = np.arange(15) - 7
    >>> round(float((psf[0].sum(axis=0) * xx).sum()), 2)   # centroid 0.3 pixel right
    0.3
    """
    X = np.asarray(positions, dtype=np.float64)
    if X.ndim != 2 or X.shape[1] < 2:
        raise ValueError(f"positions must have shape (n, 2) or (n, 2 + m) (x, y, then the "
                         f"model's extra dimensions), got {X.shape}.")
    if not np.isfinite(X).all():
        row = int(np.flatnonzero(~np.isfinite(X).all(axis=1))[0])
        raise ValueError(f"positions hold NaN or infinite values (first at row {row}).")
    n_over = int(oversampling)
    if n_over != oversampling or n_over < 1:
        raise ValueError(f"oversampling must be a positive integer, got {oversampling!r}.")
    flat = np.asarray(model.predict(X), dtype=np.float64)
    s = int(round(np.sqrt(flat.shape[1])))
    cube = flat.reshape(len(X), s, s)
    if not centered and n_over == 1:
        return cube  # the model's own stamps
    xy = X[:, :2]
    offset = xy - np.floor(xy + 0.5) if centered else np.zeros_like(xy)
    c = (s - 1) / 2
    size = s * n_over
    grid = c + (np.arange(size) - (size - 1) / 2) / n_over
    out = np.empty((len(X), size, size))
    for i in range(len(X)):
        rows, cols = np.meshgrid(grid - offset[i, 1], grid - offset[i, 0], indexing="ij")
        out[i] = map_coordinates(cube[i], [rows, cols], order=3, mode="constant", cval=0.0)
    return out / out.sum(axis=(1, 2), keepdims=True)


def extrapolation_flags(X_fit, X, max_distance: float | None = None) -> np.ndarray:
    """True where a position is extrapolated: outside the stars' convex hull, or far from them.

    Rule: a position is flagged when it lies outside the convex hull of the fitted stars
    (:class:`scipy.spatial.Delaunay`), or when its nearest fitted star is farther than
    ``max_distance``, by default 3 times the median distance between a star and its nearest
    neighbour (a hole in the star coverage). With extra dimensions (columns beyond x, y: a
    colour, a magnitude), the positions are judged on (x, y) and a value of an extra column
    outside the fitted stars' range of it is flagged too (a galaxy bluer than every star).

    Parameters
    ----------
    X_fit : array-like of shape (k, 2) or (k, 2 + m)
        Positions (and extra dimensions) of the fitted stars (``PSFModel.X_fit_``).
    X : array-like of shape (n, 2) or (n, 2 + m)
        The same columns as ``X_fit``.
    max_distance : float, optional

    Returns
    -------
    ndarray of bool, shape (n,)

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.io import extrapolation_flags
    >>> grid = np.array([[x, y] for x in range(0, 1001, 100) for y in range(0, 1001, 100)])
    >>> extrapolation_flags(grid, [[500.0, 500.0], [1200.0, 500.0], [50.0, 950.0]]).tolist()
    [False, True, False]
    >>> colour = np.linspace(0.3, 3.0, len(grid))          # a colour as a third column
    >>> extrapolation_flags(np.column_stack([grid, colour]),
    ...                     [[500.0, 500.0, 1.0], [500.0, 500.0, 0.1]]).tolist()
    [False, True]
    """
    X_fit = np.asarray(X_fit, dtype=np.float64)
    X = np.asarray(X, dtype=np.float64)
    if X_fit.ndim != 2 or X.ndim != 2 or X_fit.shape[1] < 2 or X.shape[1] != X_fit.shape[1]:
        raise ValueError(f"X must have the columns of X_fit ((x, y) then the model's extra "
                         f"dimensions): X_fit has shape {X_fit.shape}, X {X.shape}.")
    extra, extra_fit = X[:, 2:], X_fit[:, 2:]
    out_of_range = ((extra < extra_fit.min(axis=0)) | (extra > extra_fit.max(axis=0))).any(
        axis=1) if extra.shape[1] else np.zeros(len(X), dtype=bool)
    X_fit, X = X_fit[:, :2], X[:, :2]
    tree = cKDTree(X_fit)
    if max_distance is None:
        nn, _ = tree.query(X_fit, k=2) if len(X_fit) > 1 else (np.zeros((1, 2)), None)
        max_distance = 3.0 * float(np.median(nn[:, 1]))
    far = tree.query(X)[0] > max_distance
    try:
        outside = Delaunay(X_fit).find_simplex(X) < 0
    except (QhullError, ValueError):  # fewer than 3 stars or all aligned: no area
        outside = np.ones(len(X), dtype=bool)
    return outside | far | out_of_range
