"""Fourth moments of PSF stamps under their adaptive Gaussian weight (PIFF's definitions)."""

from __future__ import annotations

import numpy as np
from astropy.table import Table

from ._moments import adaptive_moments

__all__ = ["fourth_moments"]

#: the columns of :func:`fourth_moments`: spin 0 (M22), spin 2 (M31, M13), spin 4 (M40, M04)
FOURTH_MOMENTS = ("M22", "M31", "M13", "M40", "M04")


def fourth_moments(stamps, moments=None) -> Table:
    """Fourth moments of each stamp under its adaptive Gaussian weight.

    The definitions of PIFF's ``piff.util.calculate_moments(star, fourth_order=True)`` (used
    by the Dark Energy Survey's Year 6 PSF diagnostics), in pixel units: with ``W`` the
    best-fitting elliptical Gaussian of :func:`adaptive_moments` (unit flux, covariance
    ``M``, centred on its centroid) evaluated at the pixel centres, ``I`` the stamp,
    ``(u, v)`` a pixel's offset from the centroid (u along columns) and ``r^2 = u^2 + v^2``,
    each moment is ``sum(W I f) / sum(W I)`` with ``f``

    - ``M22``: ``r^4`` (spin 0),
    - ``M31``: ``r^2 (u^2 - v^2)`` and ``M13``: ``r^2 (2 u v)`` (spin 2),
    - ``M40``: ``u^4 - 6 u^2 v^2 + v^4`` and ``M04``: ``4 u v (u^2 - v^2)`` (spin 4).

    Masked (NaN) pixels take the weight's value scaled to the stamp's unmasked flux, as PIFF
    fills them.

    Parameters
    ----------
    stamps : array-like of shape (n, s*s) or (n, s, s)
        Stamps, NaN for masked pixels.
    moments : astropy.table.Table, optional
        Their :func:`adaptive_moments` (computed when not given).

    Returns
    -------
    table : astropy.table.Table
        Columns ``M22``, ``M31``, ``M13``, ``M40``, ``M04`` (pixels^4), NaN where the
        adaptive moments are flagged.

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.measure import fourth_moments
    >>> yy, xx = np.mgrid[0:31, 0:31] - 15.0
    >>> stamp = np.exp(-0.5 * (xx**2 + yy**2) / 2.0**2)    # round Gaussian, sigma 2
    >>> t = fourth_moments(stamp[None])
    >>> # its product with the weight is a Gaussian of variance 2: <r^4> = 8 * 2^2
    >>> round(float(t["M22"][0]), 3), round(float(t["M31"][0]), 6)
    (32.0, 0.0)
    """
    cube = np.asarray(stamps, dtype=np.float64)
    if cube.ndim == 2:
        s = int(round(np.sqrt(cube.shape[1])))
        if s * s != cube.shape[1]:
            raise ValueError(f"stamps have {cube.shape[1]} pixels each: pass square stamps.")
        cube = cube.reshape(-1, s, s)
    if cube.ndim != 3 or cube.shape[1] != cube.shape[2]:
        raise ValueError(f"stamps must have shape (n, s*s) or (n, s, s), got {cube.shape}.")
    n, s, _ = cube.shape
    if moments is None:
        moments = adaptive_moments(cube)
    if len(moments) != n:
        raise ValueError(f"moments has {len(moments)} rows for {n} stamps.")
    cols = {name: np.asarray(moments[name], dtype=np.float64)[:, None, None]
            for name in ("x0", "y0", "Mxx", "Mxy", "Myy")}
    grid = np.arange(s, dtype=np.float64)
    u = grid[None, :] - cols["x0"][:, 0]  # (n, s): along columns
    v = grid[None, :] - cols["y0"][:, 0]  # (n, s): along rows
    det = cols["Mxx"] * cols["Myy"] - cols["Mxy"] ** 2
    with np.errstate(invalid="ignore", divide="ignore"):
        rho2 = ((cols["Myy"] / det) * (u * u)[:, None, :]
                - (2 * cols["Mxy"] / det) * (v[:, :, None] * u[:, None, :])
                + (cols["Mxx"] / det) * (v * v)[:, :, None])
        weight = np.exp(-0.5 * rho2) / (2 * np.pi * np.sqrt(det))
        masked = np.isnan(cube)
        if masked.any():
            data = np.where(masked, 0.0, cube)
            scale = data.sum(axis=(1, 2)) / np.where(masked, 0.0, weight).sum(axis=(1, 2))
            cube = np.where(masked, weight * scale[:, None, None], data)
        wi = weight * cube
        wi /= wi.sum(axis=(1, 2), keepdims=True)
        # the monomial moments m_ab = sum wi u^a v^b (a + b = 4), rows v, columns u
        along_u = wi @ np.stack([u**a for a in range(5)], axis=2)  # (n, s rows, 5)
        m = {(a, 4 - a): np.einsum("ni,ni->n", v ** (4 - a), along_u[:, :, a])
             for a in range(5)}
        terms = {"M22": m[4, 0] + 2 * m[2, 2] + m[0, 4],          # r^4
                 "M31": m[4, 0] - m[0, 4],                         # r^2 (u^2 - v^2)
                 "M13": 2 * (m[3, 1] + m[1, 3]),                   # r^2 2uv
                 "M40": m[4, 0] - 6 * m[2, 2] + m[0, 4],           # u^4 - 6u^2v^2 + v^4
                 "M04": 4 * (m[3, 1] - m[1, 3])}                   # 4uv (u^2 - v^2)
        good = np.asarray(moments["flag"]) == 0
        return Table({name: np.where(good, f, np.nan) for name, f in terms.items()})
