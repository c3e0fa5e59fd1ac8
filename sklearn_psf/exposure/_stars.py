"""Star selection on an image (size-magnitude locus) and star-stamp extraction with flags.

:func:`find_stars` is the package's one star finder: :meth:`ReferenceBasis.from_image
<sklearn_psf.simulate.ReferenceBasis.from_image>` and ``sklearn-psf fit`` both use it.
"""

from __future__ import annotations

import numpy as np
from astropy.table import Table

from .._files import InputError, check_memory
from ..preprocessing import cut_stamps
from ..preprocessing._stamps import CUT_BAD_POSITION, CUT_NAN, CUT_OFF_EDGE
from ..io._image import _level
from ._select import SELECTION_REASONS, select_stars

__all__ = ["find_stars", "extract_star_stamps", "StarStamps", "REJECTION_REASONS"]

#: Why :func:`extract_star_stamps` skips a catalogue star, in order of precedence.
REJECTION_REASONS = ("bad_position", "off_image", "edge", "catalog_flag", "masked", "nan",
                     "saturated")


def _bad_pixel_mask(data, weight):
    """True where a pixel is NaN/infinite or has zero (or non-finite) weight; None if none."""
    bad = ~np.isfinite(data)
    if weight is not None:
        w = np.asarray(weight)
        if w.shape != data.shape:
            raise InputError(f"weight must have the image's shape {data.shape}, got {w.shape}.")
        bad |= ~np.isfinite(w) | (w <= 0)
    return bad if bad.any() else None


def _cut(image, positions, s):
    """:func:`~sklearn_psf.preprocessing.cut_stamps` for a side of either parity: the star's
    pixel ``floor(x + 0.5)`` is at index ``s // 2`` (the centre of an odd stamp; for an even
    one, the pixel right of and above the stamp's centre point, as GalSim's ``Image.center``).
    An even stamp is the odd one of side s + 1 without its last row and column."""
    if s % 2:
        return cut_stamps(image, positions, s)
    stamps, flags = cut_stamps(image, positions, s + 1)
    stamps = np.ascontiguousarray(stamps[:, :s, :s])
    pos = np.asarray(positions, dtype=np.float64)
    finite = np.isfinite(pos).all(axis=1)
    c = np.floor(np.where(finite[:, None], pos, 0.0) + 0.5)
    ny, nx = np.shape(image)
    h = s // 2
    inside = ((c[:, 0] >= h) & (c[:, 0] + h - 1 <= nx - 1) & (c[:, 1] >= h)
              & (c[:, 1] + h - 1 <= ny - 1))
    flags = flags & ~(CUT_OFF_EDGE | CUT_NAN)  # judged again on the kept pixels
    flags |= np.where(finite & ~inside, CUT_OFF_EDGE, 0)
    flags |= np.where(finite & inside & ~np.isfinite(stamps).all(axis=(1, 2)), CUT_NAN, 0)
    return stamps, flags


def _image_vignettes(image, catalog, s, weight=None):
    """SExtractor-like ``VIGNET``s of every source of ``catalog`` cut from ``image``:
    background-subtracted, -1e30 on bad pixels and off the image, the source's pixel at index
    ``s // 2``; so that sources are measured (and their neighbours masked) as in a catalogue
    that holds VIGNETs."""
    raw = np.asarray(image, dtype=np.float64)
    n = len(catalog)
    check_memory(3 * 8 * n * (s + 1) ** 2, f"{n} cut-outs of {s} x {s} pixels")
    bad = _bad_pixel_mask(raw, weight)
    data = np.ascontiguousarray(np.where(bad, 0.0, raw) if bad is not None else raw)
    if min(raw.shape) >= 16:
        data = data - _background(data, bad).back()
    pos = np.column_stack([np.asarray(catalog["x"], dtype=np.float64),
                           np.asarray(catalog["y"], dtype=np.float64)])
    pos[~np.isfinite(pos).all(axis=1)] = -1e9  # off the image: every pixel masked
    cube, _ = _cut(data, pos, s)
    if bad is not None:
        masked, _ = _cut(bad.astype(np.float64), pos, s)
        cube[np.nan_to_num(masked, nan=1.0) > 0] = np.nan
    return np.where(np.isfinite(cube), cube, -1e30)


def _background(data, mask):
    """sep background (mesh of 16..64 pixels) of an image whose bad pixels are ``mask``."""
    import sep

    ny, nx = data.shape
    box = int(min(64, max(16, min(ny, nx) // 4)))
    return sep.Background(data, mask=mask, bw=box, bh=box)


def _find_stars(data, *, weight=None, stamp_size=25, detect_thresh=5.0, min_snr=20.0,
                saturation=None, isolation=None, locus_width="auto"):
    """Detection and point-source selection; returns (catalogue, background-subtracted image).

    ``data`` is a float64 C-contiguous image (NaN allowed: masked); not modified.
    """
    import sep

    s = int(stamp_size)
    if s != stamp_size or s < 3:
        raise InputError(f"stamp_size must be an integer >= 3, got {stamp_size!r}.")
    ny, nx = data.shape
    if s + 4 > min(ny, nx):
        raise InputError(
            f"stamp_size {s} is too large for an image of shape {data.shape}: the image "
            "must be at least stamp_size + 4 pixels on each side."
        )
    mask = _bad_pixel_mask(data, weight)
    if mask is not None:
        if mask.all():
            raise InputError("Every pixel of the image is NaN or has zero weight: no stars.")
        data = np.where(mask, 0.0, data)
    data = np.ascontiguousarray(data, dtype=np.float64)
    bkg = _background(data, mask)
    back = bkg.back()
    sub = data - back
    if mask is not None:
        sub[mask] = 0.0
    rms = float(bkg.globalrms)
    if not rms > 0:
        raise InputError("The image has a constant background (zero rms): no stars found.")
    old_stack = sep.get_extract_pixstack()
    sep.set_extract_pixstack(max(old_stack, 2_000_000))
    try:
        objs = sep.extract(sub, detect_thresh, err=rms, minarea=5, mask=mask)
    except Exception as exc:  # sep raises plain Exception for internal limits
        raise InputError(f"Source extraction failed: {exc}") from None
    finally:
        sep.set_extract_pixstack(old_stack)
    n_det = len(objs)
    counts = dict.fromkeys(SELECTION_REASONS, 0)
    empty = Table({"x": np.zeros(0), "y": np.zeros(0), "flux": np.zeros(0), "snr": np.zeros(0),
                   "flux_radius": np.zeros(0), "peak": np.zeros(0)})
    meta = {"n_detections": n_det, "locus_radius": np.nan, "noise_rms": rms,
            "rejected": counts}
    if n_det == 0:
        empty.meta.update(meta)
        return empty, sub
    x, y = objs["x"], objs["y"]
    half = (s - 1) / 2
    rmax = np.full(n_det, half)
    r_half, rflag = sep.flux_radius(sub, x, y, rmax, 0.5, subpix=5, mask=mask)
    sig = np.clip(2.0 * np.nan_to_num(r_half, nan=1.0) / 2.3548, 0.3, half)
    xw, yw, wflag = sep.winpos(sub, x, y, sig, mask=mask)
    aflux, aerr, aflag = sep.sum_circle(sub, xw, yw, half, err=rms, subpix=5, mask=mask)
    snr = np.where(aerr > 0, aflux / np.maximum(aerr, 1e-300), 0.0)

    sep_ok = ((objs["flag"] == 0) & (rflag == 0) & (wflag == 0) & (aflag == 0)
              & np.isfinite(r_half) & (r_half > 0))
    iy = np.clip(np.round(y).astype(int), 0, ny - 1)
    ix = np.clip(np.round(x).astype(int), 0, nx - 1)
    measured = Table({"x": xw, "y": yw, "flags": (~sep_ok).astype(np.int64), "snr": snr,
                      "flux": aflux, "peak": objs["peak"], "background": back[iy, ix],
                      "flux_radius": r_half})
    # the crowding cut uses the detection positions (windowed ones may be NaN)
    measured["x"][~np.isfinite(xw)] = x[~np.isfinite(xw)]
    measured["y"][~np.isfinite(yw)] = y[~np.isfinite(yw)]
    keep, cuts = select_stars(measured, min_snr=min_snr, saturation=saturation, stamp_size=s,
                              image_shape=(ny, nx), flag_mask=None,
                              isolation=s // 2 + 3 if isolation is None else isolation,
                              locus_width=locus_width, min_stars=0)
    locus = cuts["locus_radius"]
    counts.update({k: cuts[k] for k in SELECTION_REASONS})
    idx = np.flatnonzero(keep)
    if idx.size:
        _, flags = _cut(sub, np.column_stack([xw[idx], yw[idx]]), s)
        if mask is not None:
            # a masked pixel anywhere under the stamp: not a clean star
            mcube, _ = _cut(mask.astype(np.float64), np.column_stack([xw[idx], yw[idx]]), s)
            flags = flags | (np.nansum(mcube, axis=(1, 2)) > 0)
        counts["bad_stamp"] += int(np.count_nonzero(flags != 0))
        idx = idx[flags == 0]
    meta["locus_radius"] = locus
    table = Table(
        {"x": xw[idx], "y": yw[idx], "flux": aflux[idx], "snr": snr[idx],
         "flux_radius": r_half[idx], "peak": objs["peak"][idx]},
    )
    table.meta.update(meta)
    return table, sub


def find_stars(image, *, weight=None, stamp_size: int = 25, detect_thresh: float = 5.0,
               min_snr: float = 20.0, saturation: float | None = None,
               isolation: float | None = None, locus_width: float | str = "auto") -> Table:
    """Detect sources with ``sep`` and select isolated, unsaturated point sources.

    The selection is the flux-radius (size-magnitude) locus method:

    1. background and its rms with ``sep.Background`` (pixels that are NaN or of zero weight
       are masked); detection with ``sep.extract`` at ``detect_thresh`` times the global rms
       (min. area 5 pixels);
    2. for each detection: half-light radius (``sep.flux_radius``), windowed centroid
       (``sep.winpos``), aperture S/N within the stamp radius (``sep.sum_circle``);
    3. cuts, in this order (a detection is counted under the first it fails, see
       ``meta["rejected"]``): ``flags`` (blended, truncated or failed measurement),
       ``low_snr`` (S/N < ``min_snr``), ``saturated`` (peak + background >= 0.9 x
       ``saturation``), ``near_edge`` (closer than half a stamp + 2 pixels to an edge),
       ``crowded`` (another detection closer than ``isolation`` pixels along x and y),
       ``off_locus`` (half-light radius off the stellar locus: galaxies are larger, cosmic
       rays smaller), as :func:`select_stars` applies them, then ``bad_stamp`` (a stamp around
       the star would hold a NaN or masked pixel).

    Parameters
    ----------
    image : array-like of shape (ny, nx)
        The image (x = column, y = row). Not modified. NaN pixels are masked.
    weight : array-like of shape (ny, nx), optional
        Weight (inverse variance) or mask map: pixels of zero weight are masked.
    stamp_size : int, default=25
        Side of the stamps the stars will be cut into (sets the edge margin, the isolation and
        the aperture); odd or even, as :func:`extract_star_stamps`.
    detect_thresh : float, default=5.0
        Detection threshold in units of the background rms.
    min_snr : float, default=20.0
        Smallest aperture S/N of a selected star.
    saturation : float, optional
        Saturation level (counts, before background subtraction); None: no cut.
    isolation : float, optional
        Smallest distance (pixels, Chebyshev) to any other detection; default
        ``stamp_size // 2 + 3`` (see :func:`select_stars`).
    locus_width : float or "auto", default="auto"
        Relative half-width of the stellar locus in half-light radius; "auto": 3 times its
        scatter at each star's S/N (see :func:`select_stars`).

    Returns
    -------
    stars : astropy.table.Table
        Selected stars: ``x``, ``y`` (0-based windowed centroids), ``flux``, ``snr``,
        ``flux_radius``, ``peak``. ``meta``: ``n_detections``, ``locus_radius``,
        ``noise_rms`` and ``rejected`` (dict: reason -> number of detections dropped). May be
        empty (no error): the caller decides how many stars are enough.

    Raises
    ------
    ValueError
        For a non 2-D image, a stamp larger than the image, a constant or fully masked image.

    Examples
    --------
    >>> from sklearn_psf.exposure import find_stars
    >>> from sklearn_psf.simulate import make_psf_field
    >>> field = make_psf_field(n_stars=40, n_galaxies=0, image_shape=(600, 800),
    ...                        snr=300.0, random_state=0)
    >>> stars = find_stars(field.image)
    >>> len(stars) >= 35, sorted(stars.meta["rejected"])[:3]
    (True, ['bad_position', 'bad_stamp', 'crowded'])
    """
    data = np.asarray(image)
    if data.ndim != 2:
        raise InputError(f"image must be 2-D, got {data.ndim} dimensions.")
    data = np.array(data, dtype=np.float64, copy=True)
    table, _ = _find_stars(data, weight=weight, stamp_size=stamp_size,
                           detect_thresh=detect_thresh, min_snr=min_snr, saturation=saturation,
                           isolation=isolation, locus_width=locus_width)
    return table


class StarStamps:
    """Stamps of the usable stars of a catalogue, and why the others were skipped.

    Attributes
    ----------
    positions : ndarray of shape (m, 2)
        (x, y) 0-based positions of the used stars.
    stamps : ndarray of shape (m, s*s)
        Background-subtracted stamps (masked wing pixels set to 0).
    catalog : astropy.table.Table
        The input catalogue (every row) with columns ``used`` (bool) and ``reason`` ("" for
        used stars, else one of :data:`REJECTION_REASONS`).
    counts : dict
        ``{"input": n, "used": m, <reason>: count, ...}`` for every reason.
    weights : ndarray of shape (m, s*s) or None
        Pixel weights: inverse variance in the stamps' units, 0 for masked pixels; None when
        no weight map was given.
    rows : ndarray of shape (m,) or None
        Each used star's row in the catalogue the selection started from (set by
        :func:`~sklearn_psf.exposure.fit_exposure`; None otherwise).
    """

    def __init__(self, positions, stamps, catalog, counts, weights=None):
        self.positions = positions
        self.stamps = stamps
        self.catalog = catalog
        self.counts = counts
        self.weights = weights
        self.rows = None

    def __repr__(self):
        skipped = ", ".join(f"{k}={v}" for k, v in self.counts.items()
                            if k not in ("input", "used") and v)
        return (f"StarStamps(used={self.counts['used']} of {self.counts['input']}"
                + (f"; skipped: {skipped}" if skipped else "") + ")")


def extract_star_stamps(image, catalog, stamp_size: int = 25, *, weight=None,
                        saturation: float | None = None, subtract_background: bool = True,
                        core_size: int = 5) -> StarStamps:
    """Cut the stamps of catalogue stars, skipping (and counting) the unusable ones.

    A star is skipped, under the first reason that applies, when its position is NaN
    (``bad_position``), its centre pixel is outside the image (``off_image``), part of its
    stamp is outside (``edge``), its catalogue ``flags`` column is non-zero
    (``catalog_flag``), a pixel of zero weight or NaN lies in the central ``core_size``
    box (``masked``; NaN pixels count as masked when a weight map is given, as ``nan``
    otherwise), a NaN pixel lies anywhere in the stamp without a zero weight (``nan``), or a
    pixel of the stamp reaches ``saturation`` (``saturated``). Zero-weight pixels outside the
    core are set to the background (0) in the stamps.

    Parameters
    ----------
    image : array-like of shape (ny, nx)
        Not modified.
    catalog : astropy.table.Table or array-like of shape (n, 2)
        Star positions: a table with 0-based ``x``, ``y`` columns (and optionally ``flags``),
        as returned by :func:`~sklearn_psf.io.read_catalog` or :func:`find_stars`, or an
        (n, 2) array.
    stamp_size : int, default=25
        Stamp side. The star's pixel ``floor(x + 0.5)`` is at index ``stamp_size // 2``: the
        centre of an odd stamp; of an even one (e.g. 32), the pixel right of and above its
        centre point.
    weight : array-like of shape (ny, nx), optional
        Weight (inverse variance) or mask: zero means bad.
    saturation : float, optional
        Saturation level of the raw image; None: no saturation cut.
    subtract_background : bool, default=True
        Subtract the ``sep`` background (estimated with bad pixels masked) before cutting.
    core_size : int, default=5
        Side of the central box in which a masked pixel skips the star.

    Returns
    -------
    StarStamps

    Raises
    ------
    InputError
        When every position lies outside the image (a wrong catalogue, or 1-based positions
        read as 0-based), no star is usable, ``stamp_size`` exceeds the image, or the stamps
        would not fit in the free memory (refused before they are allocated, with the size
        needed).

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.exposure import extract_star_stamps
    >>> from sklearn_psf.simulate import make_psf_field
    >>> field = make_psf_field(n_stars=30, n_galaxies=0, image_shape=(500, 500),
    ...                        random_state=1)
    >>> pos = np.column_stack([field.stars["x"], field.stars["y"]])
    >>> pos = np.vstack([pos, [[-50.0, 10.0]]])          # one star off the image
    >>> out = extract_star_stamps(field.image, pos, subtract_background=False)
    >>> out.counts["used"], out.counts["off_image"]
    (30, 1)
    """
    img = np.asarray(image)
    if img.ndim != 2:
        raise InputError(f"image must be 2-D, got {img.ndim} dimensions.")
    ny, nx = img.shape
    if isinstance(catalog, Table):
        missing = [c for c in ("x", "y") if c not in catalog.colnames]
        if missing:
            raise InputError(
                f"The catalogue has no {' and '.join(missing)} column (columns: "
                f"{', '.join(catalog.colnames) or 'none'}): read it with read_catalog."
            )
        cat = Table(catalog, copy=True)
    else:
        pos = np.asarray(catalog, dtype=np.float64)
        if pos.ndim != 2 or pos.shape[1] != 2:
            raise InputError(f"positions must have shape (n, 2), got {pos.shape}.")
        cat = Table({"x": pos[:, 0], "y": pos[:, 1]})
    n = len(cat)
    if n == 0:
        raise InputError("The star catalogue is empty.")
    s = int(stamp_size)
    if s != stamp_size or s < 3:
        raise InputError(f"stamp_size must be an integer >= 3, got {stamp_size!r}.")
    if s > min(ny, nx):
        raise InputError(f"stamp_size {s} is larger than the image (ny, nx = {ny}, {nx}): "
                         "no star's stamp fits in it.")
    # the stamps, the raw stamps, their weights and masks (float64), as many again at once
    check_memory(6 * 8 * n * (s + 1) ** 2,
                 f"{n} stamps of {s} x {s} pixels (stamp_size)")
    pos = np.column_stack([np.asarray(cat["x"], dtype=np.float64),
                           np.asarray(cat["y"], dtype=np.float64)])
    raw = np.array(img, dtype=np.float64, copy=True)
    bad = _bad_pixel_mask(raw, weight)
    if subtract_background:
        data = np.where(bad, 0.0, raw) if bad is not None else raw
        data = np.ascontiguousarray(data)
        if min(ny, nx) >= 16:
            data = data - _background(data, bad).back()
    else:
        data = raw
    stamps, flags = _cut(data, pos, s)
    raws, _ = _cut(raw, pos, s)
    wcube = None
    if weight is not None:
        bad_cube, _ = _cut(bad.astype(np.float64) if bad is not None
                           else np.zeros((ny, nx)), pos, s)
        bad_cube = np.nan_to_num(bad_cube, nan=0.0) > 0
        wcube, _ = _cut(np.asarray(weight, dtype=np.float64), pos, s)
        wcube[bad_cube | ~np.isfinite(wcube)] = 0.0
    else:
        bad_cube = np.zeros(stamps.shape, dtype=bool)
    finite = np.isfinite(pos).all(axis=1)
    centre = np.floor(np.where(finite[:, None], pos, 0.0) + 0.5)
    off_image = finite & ((centre[:, 0] < 0) | (centre[:, 0] > nx - 1) | (centre[:, 1] < 0)
                          | (centre[:, 1] > ny - 1))
    h = s // 2
    c = max(1, min(int(core_size), s)) // 2
    core = (slice(None), slice(h - c, h + c + 1), slice(h - c, h + c + 1))
    masked = bad_cube[core].any(axis=(1, 2))
    # a NaN (or infinite) pixel of the image not masked by the weight map: the background
    # subtraction filled it, the raw stamp still holds it
    nan = ~np.isfinite(np.where(bad_cube, 0.0, raws)).all(axis=(1, 2)) \
        | ~np.isfinite(stamps).all(axis=(1, 2))
    stamps[bad_cube] = 0.0
    raws[bad_cube] = np.nan
    if weight is None:
        # without a weight map, NaN pixels in the core are "nan" too (nothing says "masked")
        masked[:] = False
    saturation = _level(saturation, "saturation")
    sat_flag = np.zeros(n, dtype=bool)
    if saturation is not None:
        with np.errstate(invalid="ignore"):
            sat_flag = np.nanmax(np.where(np.isfinite(raws), raws, -np.inf), axis=(1, 2)) \
                >= float(saturation)
    cat_flag = np.zeros(n, dtype=bool)
    if "flags" in cat.colnames:
        cat_flag = np.asarray(cat["flags"]) != 0
    tests = {
        "bad_position": (flags & CUT_BAD_POSITION) > 0,
        "off_image": off_image,
        "edge": (flags & CUT_OFF_EDGE) > 0,
        "catalog_flag": cat_flag,
        "masked": masked,
        "nan": nan,
        "saturated": sat_flag,
    }
    reason = np.full(n, "", dtype=object)
    for name in REJECTION_REASONS:
        reason[(reason == "") & tests[name]] = name
    used = reason == ""
    counts = {"input": n, "used": int(used.sum())}
    counts.update({name: int(np.count_nonzero(reason == name)) for name in REJECTION_REASONS})
    if counts["off_image"] + counts["bad_position"] == n:
        raise InputError(
            f"All {n} catalogue positions fall outside the image (shape ny, nx = {ny}, {nx}); "
            "check that the catalogue belongs to this image/HDU and whether its positions are "
            "1-based (SExtractor X_IMAGE: use one_based=True / --one-based)."
        )
    if not used.any():
        skipped = ", ".join(f"{k}: {v}" for k, v in counts.items()
                            if k not in ("input", "used") and v)
        raise InputError(f"None of the {n} catalogue stars is usable ({skipped}).")
    cat["used"] = used
    cat["reason"] = np.asarray(reason, dtype=str)
    return StarStamps(pos[used], stamps[used].reshape(-1, s * s), cat, counts,
                      None if wcube is None else wcube[used].reshape(-1, s * s))
