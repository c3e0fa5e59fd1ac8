"""The star selector: cuts of a source catalogue down to clean, isolated point sources.

:func:`select_stars` works on any catalogue with 0-based ``x``, ``y`` (and optional measured
columns, as :func:`~sklearn_psf.io.read_catalog` names them); :func:`~sklearn_psf.io.find_stars`
measures the sources of an image and applies the same cuts.
"""

from __future__ import annotations

import numpy as np
from astropy.table import Table
from scipy.spatial import cKDTree

__all__ = ["select_stars", "SELECTION_REASONS"]

#: Why a source is not selected as a star, in the order the cuts are applied (a source is
#: counted under the first cut it fails); ``bad_stamp`` is applied when stamps are cut.
SELECTION_REASONS = ("flags", "low_snr", "saturated", "near_edge", "crowded", "extended",
                     "off_locus", "bad_stamp")


def _shorth_mode(values, fraction=0.2):
    """Mode estimate: median of the shortest window holding ``fraction`` of the values."""
    v = np.sort(np.asarray(values, dtype=np.float64))
    m = max(3, int(np.ceil(fraction * v.size)))
    if v.size <= m:
        return float(np.median(v))
    spans = v[m - 1:] - v[: v.size - m + 1]
    i = int(np.argmin(spans))
    return float(np.median(v[i:i + m]))


def _column(table, name):
    """Column ``name`` (any case) as float64, or None."""
    lower = {c.lower(): c for c in table.colnames}
    if name not in lower:
        return None
    return np.asarray(table[lower[name]], dtype=np.float64)


def _peak(table):
    """Highest raw pixel of each source: ``peak`` (+ ``background``), or the vignette's max."""
    peak = _column(table, "peak")
    if peak is not None:
        back = _column(table, "background")
        peak = peak + (back if back is not None else 0.0)
    lower = {c.lower(): c for c in table.colnames}
    if "vignet" in lower:
        vig = np.asarray(table[lower["vignet"]], dtype=np.float64)
        vig = np.where(np.isfinite(vig) & (vig > -1e29), vig, -np.inf)
        vmax = vig.reshape(len(table), -1).max(axis=1)
        peak = vmax if peak is None else np.maximum(peak, vmax)
    return peak


def select_stars(catalog, *, min_snr: float = 50.0, saturation: float | None = None,
                 stamp_size: int = 25, image_shape=None, isolation: float | None = None,
                 locus_width: float | str = "auto", max_spread_model: float = 0.003,
                 min_class_star: float = 0.8):
    """Select clean, isolated point sources of a catalogue, counting each rejection by reason.

    Cuts, in this order (a source is counted under the first it fails; a cut whose columns
    are absent is skipped):

    - ``flags``: non-zero ``flags`` (SExtractor ``FLAGS``: blended, saturated, truncated...);
    - ``low_snr``: ``snr`` below ``min_snr``;
    - ``saturated``: highest raw pixel (``peak`` + ``background``, or the maximum of the
      ``VIGNET``) at or above 0.9 x ``saturation``;
    - ``near_edge``: closer than half a stamp + 2 pixels to the edge of ``image_shape``;
    - ``crowded``: another source of the catalogue closer than ``isolation`` pixels along x
      and y (their stamps would overlap);
    - ``extended``: ``|spread_model|`` above ``max_spread_model`` when that column exists,
      else ``class_star`` below ``min_class_star`` when that column exists;
    - ``off_locus``: the size-magnitude locus: ``flux_radius`` more than ``locus_width``
      (relative) from the stellar locus, the mode of the radii of the brighter half (by
      ``flux``) of the sources left. Stars share one radius at every magnitude; galaxies are
      larger, cosmic rays smaller. ``"auto"``: 3 times the robust scatter (1.4826 x median
      absolute relative deviation) of the sources within 15% of the locus, kept in
      [0.03, 0.1].

    Parameters
    ----------
    catalog : astropy.table.Table
        Sources with 0-based ``x``, ``y`` and optional columns ``flags``, ``snr``, ``flux``,
        ``peak``, ``background``, ``VIGNET``, ``flux_radius``, ``spread_model``,
        ``class_star`` (any case), as :func:`~sklearn_psf.io.read_catalog` returns them.
    min_snr : float, default=50
    saturation : float, optional
        Saturation level of the raw image; None: no cut.
    stamp_size : int, default=25
        Side of the stamps (edge margin, default isolation).
    image_shape : tuple (ny, nx), optional
        Shape of the image; None: no edge cut.
    isolation : float, optional
        Smallest Chebyshev distance to another source; default ``stamp_size``.
    locus_width : float or "auto", default="auto"
    max_spread_model : float, default=0.003
    min_class_star : float, default=0.8

    Returns
    -------
    keep : ndarray of bool, shape (n,)
        True for the selected stars.
    counts : dict
        Reason (every one of :data:`SELECTION_REASONS`) -> number of sources dropped, and
        ``locus_radius`` and ``locus_width`` (floats, NaN when no locus cut was made).

    Examples
    --------
    >>> import numpy as np
    >>> from astropy.table import Table
    >>> from sklearn_psf.io import select_stars
    >>> rng = np.random.default_rng(0)
    >>> radius = np.r_[rng.normal(2.0, 0.03, 60), rng.uniform(2.6, 5.0, 40)]
    >>> cat = Table({"x": rng.uniform(0, 4000, 100), "y": rng.uniform(0, 4000, 100),
    ...              "flux_radius": radius, "snr": np.full(100, 200.0)})
    >>> keep, counts = select_stars(cat)
    >>> int(keep[:60].sum()), int(keep[60:].sum()), counts["off_locus"]
    (60, 0, 40)
    """
    if not isinstance(catalog, Table):
        raise TypeError(f"catalog must be an astropy Table, got {type(catalog).__name__}.")
    missing = [c for c in ("x", "y") if c not in catalog.colnames]
    if missing:
        raise ValueError(f"The catalogue has no {' and '.join(missing)} column: read it with "
                         "read_catalog.")
    n = len(catalog)
    x, y = _column(catalog, "x"), _column(catalog, "y")
    counts = dict.fromkeys(SELECTION_REASONS, 0)
    keep = np.isfinite(x) & np.isfinite(y)

    def cut(name, ok):
        nonlocal keep
        ok = np.asarray(ok, dtype=bool)
        counts[name] += int(np.count_nonzero(keep & ~ok))
        keep &= ok

    counts["flags"] = int(np.count_nonzero(~keep))  # NaN positions
    flags = _column(catalog, "flags")
    if flags is not None:
        cut("flags", flags == 0)
    snr = _column(catalog, "snr")
    if snr is not None:
        cut("low_snr", np.nan_to_num(snr, nan=-np.inf) >= min_snr)
    peak = _peak(catalog) if saturation is not None else None
    if peak is not None:
        cut("saturated", peak < 0.9 * float(saturation))
    half = (int(stamp_size) - 1) / 2
    if image_shape is not None:
        ny, nx = image_shape
        margin = half + 2
        cut("near_edge", (x >= margin) & (x <= nx - 1 - margin) & (y >= margin)
            & (y <= ny - 1 - margin))
    if n > 1:
        finite = np.column_stack([np.nan_to_num(x, nan=-1e12), np.nan_to_num(y, nan=-1e12)])
        d, _ = cKDTree(finite).query(finite, k=2, p=np.inf)
        cut("crowded", d[:, 1] >= float(stamp_size if isolation is None else isolation))
    spread, cls = _column(catalog, "spread_model"), _column(catalog, "class_star")
    if spread is not None:
        cut("extended", np.abs(np.nan_to_num(spread, nan=np.inf)) <= max_spread_model)
    elif cls is not None:
        cut("extended", np.nan_to_num(cls, nan=-1.0) >= min_class_star)
    radius = _column(catalog, "flux_radius")
    counts["locus_radius"] = counts["locus_width"] = np.nan
    if radius is not None:
        cut("off_locus", np.isfinite(radius) & (radius > 0))
        left = np.flatnonzero(keep)
        if left.size >= 3:
            flux = _column(catalog, "flux")
            if flux is not None and left.size >= 10:
                left = left[np.argsort(-np.nan_to_num(flux[left], nan=-np.inf))]
                left = left[: max(5, left.size // 2)]
            locus = _shorth_mode(radius[left], 0.5 if left.size < 20 else 0.3)
            counts["locus_radius"] = locus
            rel = np.abs(radius / locus - 1.0)
            width = locus_width
            if isinstance(width, str):
                near = rel[keep & (rel <= 0.15)]
                width = float(np.clip(3 * 1.4826 * np.median(near), 0.03, 0.1))
            counts["locus_width"] = float(width)
            cut("off_locus", rel <= width)
    return keep, counts
