"""Cutting square postage stamps out of an image."""

from __future__ import annotations

import numpy as np

__all__ = [
    "cut_stamps",
    "CUT_OK",
    "CUT_OFF_EDGE",
    "CUT_NAN",
    "CUT_MASKED",
    "CUT_BAD_POSITION",
]

#: The stamp is complete and clean.
CUT_OK = 0
#: Part of the stamp falls outside the image; those pixels are NaN in the returned stamp.
CUT_OFF_EDGE = 1
#: A NaN or infinite image pixel lies under the stamp.
CUT_NAN = 2
#: A pixel of zero weight (masked) lies under the core of the stamp.
CUT_MASKED = 4
#: The position itself is NaN or infinite; the whole stamp is NaN.
CUT_BAD_POSITION = 8


def cut_stamps(image, positions, size: int, weight=None, *, core_size: int = 3):
    """Cut square stamps centred on the nearest pixel of each position.

    Parameters
    ----------
    image : array-like of shape (ny, nx)
        The image, indexed ``image[y, x]`` (x = column). Not copied nor modified; any real
        dtype (e.g. big-endian FITS data) is accepted, stamps are returned as float64.
    positions : array-like of shape (n, 2)
        (x, y) positions, 0-based pixel coordinates with pixel centres at integers. Each stamp
        is centred on the pixel ``floor(x + 0.5), floor(y + 0.5)``.
    size : int
        Side of the stamps in pixels (odd, so that the stamp has a central pixel).
    weight : array-like of shape (ny, nx), optional
        Weight (inverse variance) or mask; a pixel of zero weight in the core of a stamp flags
        the stamp ``CUT_MASKED``. Pixels of zero weight outside the core are left as they are.
    core_size : int, default=3
        Side of the central box checked against the weight map.

    Returns
    -------
    stamps : ndarray of shape (n, size, size)
        float64 stamps. Pixels outside the image, and every pixel of a stamp at a non-finite
        position, are NaN.
    flags : ndarray of shape (n,), int
        0 for a clean stamp, otherwise a bit mask of ``CUT_OFF_EDGE`` (1), ``CUT_NAN`` (2),
        ``CUT_MASKED`` (4), ``CUT_BAD_POSITION`` (8). Bad stars are flagged, never raised on.

    Raises
    ------
    ValueError
        When the image is not 2-D, positions are not (n, 2), ``size`` is not a positive odd
        integer, or the weight map does not have the image's shape.

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.preprocessing import cut_stamps
    >>> image = np.arange(100.0).reshape(10, 10)
    >>> stamps, flags = cut_stamps(image, [[4.2, 5.0], [0.0, 5.0]], size=3)
    >>> stamps[0]
    array([[43., 44., 45.],
           [53., 54., 55.],
           [63., 64., 65.]])
    >>> flags
    array([0, 1])
    """
    img = np.asarray(image)
    if img.ndim != 2:
        raise ValueError(f"image must be a 2-D array (ny, nx), got {img.ndim} dimensions.")
    if not np.issubdtype(img.dtype, np.number) or np.issubdtype(img.dtype, np.complexfloating):
        raise TypeError(f"image must hold real numbers, got dtype {img.dtype}.")
    pos = np.asarray(positions, dtype=np.float64)
    if pos.ndim != 2 or pos.shape[1] != 2:
        raise ValueError(f"positions must have shape (n, 2) of (x, y), got shape {pos.shape}.")
    if isinstance(size, bool) or int(size) != size or size < 1 or size % 2 == 0:
        raise ValueError(f"size must be a positive odd integer, got {size!r}.")
    size = int(size)
    if isinstance(core_size, bool) or int(core_size) != core_size or core_size < 1:
        raise ValueError(f"core_size must be a positive integer, got {core_size!r}.")
    core_size = min(int(core_size), size)
    wgt = None
    if weight is not None:
        wgt = np.asarray(weight)
        if wgt.shape != img.shape:
            raise ValueError(
                f"weight must have the image's shape {img.shape}, got {wgt.shape}."
            )

    n = pos.shape[0]
    ny, nx = img.shape
    half = size // 2
    flags = np.zeros(n, dtype=np.int64)
    finite_pos = np.isfinite(pos).all(axis=1)
    flags[~finite_pos] |= CUT_BAD_POSITION
    centre = np.zeros((n, 2), dtype=np.int64)
    with np.errstate(invalid="ignore"):
        safe = np.where(finite_pos[:, None], np.clip(pos, -1e9, 1e9), 0.0)
    centre[:] = np.floor(safe + 0.5).astype(np.int64)

    offsets = np.arange(-half, half + 1)
    cols = centre[:, 0:1] + offsets  # (n, size)
    rows = centre[:, 1:2] + offsets
    col_ok = (cols >= 0) & (cols < nx)
    row_ok = (rows >= 0) & (rows < ny)
    inside = row_ok[:, :, None] & col_ok[:, None, :]
    off_edge = ~inside.all(axis=(1, 2)) & finite_pos
    flags[off_edge] |= CUT_OFF_EDGE

    rr = np.clip(rows, 0, ny - 1)[:, :, None]
    cc = np.clip(cols, 0, nx - 1)[:, None, :]
    stamps = img[rr, cc].astype(np.float64, copy=False)
    stamps = np.where(inside & finite_pos[:, None, None], stamps, np.nan)

    has_nan = ~np.isfinite(np.where(inside, stamps, 0.0)).all(axis=(1, 2)) & finite_pos
    flags[has_nan] |= CUT_NAN

    if wgt is not None:
        lo = half - core_size // 2
        core = slice(lo, lo + core_size)
        wcore = wgt[rr[:, core], cc[:, :, core]]
        masked = ((wcore == 0) | ~np.isfinite(wcore)) & inside[:, core, core]
        flags[masked.any(axis=(1, 2)) & finite_pos] |= CUT_MASKED
    return stamps, flags
