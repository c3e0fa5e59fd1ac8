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
    u = grid[None, None, :] - cols["x0"]
    v = grid[:, None][None] - cols["y0"]
    det = cols["Mxx"] * cols["Myy"] - cols["Mxy"] ** 2
    rho2 = (cols["Myy"] * u * u - 2 * cols["Mxy"] * u * v + cols["Mxx"] * v * v) / det
    with np.errstate(invalid="ignore", divide="ignore"):
        weight = np.exp(-0.5 * rho2) / (2 * np.pi * np.sqrt(det))
        masked = np.isnan(cube)
        if masked.any():
            data = np.where(masked, 0.0, cube)
            scale = data.sum(axis=(1, 2)) / np.where(masked, 0.0, weight).sum(axis=(1, 2))
            cube = np.where(masked, weight * scale[:, None, None], data)
        wi = weight * cube
        wi = wi / wi.sum(axis=(1, 2), keepdims=True)
        uu, vv, uv = u * u, v * v, u * v
        r2, diff = uu + vv, uu - vv
        terms = {"M22": r2 * r2, "M31": r2 * diff, "M13": 2 * r2 * uv,
                 "M40": diff * diff - 4 * uv * uv, "M04": 4 * uv * diff}
        good = np.asarray(moments["flag"]) == 0
        return Table({name: np.where(good, (wi * f).sum(axis=(1, 2)), np.nan)
                      for name, f in terms.items()})
