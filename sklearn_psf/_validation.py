"""Input checks shared by every module of sklearn_psf."""

import numpy as np


def as_stamps(stamps, *, name="stamps", copy=False):
    """Return a float64 stamp cube of shape (n, s, s).

    Parameters
    ----------
    stamps : array-like of shape (n, s, s) or (n, s*s)
        Square postage stamps, either as images or flattened row by row.
    name : str
        Name used in error messages.
    copy : bool
        Always return a copy, so that the caller may modify it.

    Returns
    -------
    cube : ndarray of shape (n, s, s)

    Raises
    ------
    ValueError
        When the stamps are not square or the array has the wrong number of dimensions.
    """
    arr = np.array(stamps, dtype=np.float64, copy=copy or None)
    if arr.ndim == 3:
        if arr.shape[1] != arr.shape[2]:
            raise ValueError(f"{name} must be square, got stamps of shape {arr.shape[1:]}.")
        return arr
    if arr.ndim == 2:
        size = int(round(np.sqrt(arr.shape[1])))
        if size * size != arr.shape[1] or size == 0:
            raise ValueError(
                f"{name} has {arr.shape[1]} pixels per row, which is not a square number: "
                "pass flattened square stamps of shape (n, s*s) or images of shape (n, s, s)."
            )
        return arr.reshape(arr.shape[0], size, size)
    raise ValueError(f"{name} must have shape (n, s, s) or (n, s*s), got {arr.ndim} dimensions.")


def rows_text(rows, limit: int = 10) -> str:
    """``"3, 7, 12"``: row numbers for an error message, the first ``limit`` of them."""
    rows = [int(r) for r in rows]
    text = ", ".join(map(str, rows[:limit]))
    if len(rows) > limit:
        text += f", ... ({len(rows)} rows)"
    return text
