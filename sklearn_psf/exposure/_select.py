"""The star selector: cuts of a source catalogue down to clean, isolated point sources.

:func:`select_stars` works on any catalogue with 0-based ``x``, ``y`` (and optional measured
columns, as :func:`~sklearn_psf.io.read_catalog` names them); :func:`find_stars` measures the
sources of an image and applies the same cuts.

The primary point-source criterion is the size-magnitude locus, as PSFEx and PIFF select stars:
point sources share the PSF's size at every flux, galaxies are larger, cosmic rays smaller.
SExtractor's ``CLASS_STAR`` and ``SPREAD_MODEL`` are secondary: each is checked against the
locus, and a cut that would reject most of the locus (``CLASS_STAR`` depends on the
``SEEING_FWHM`` the user gave SExtractor, often left unset) is reported and not applied.
"""

from __future__ import annotations

import itertools
import warnings

import numpy as np
from astropy.table import Table
from scipy.optimize import nnls
from scipy.spatial import cKDTree

from .._files import InputError

__all__ = ["select_stars", "neighbour_masks", "saturation_level", "PSFEX_FLAG_MASK",
           "SELECTION_REASONS", "SELECTION_OPTIONS"]

#: Why a source is not selected as a star, in the order the cuts are applied (a source is
#: counted under the first cut it fails); ``bad_stamp`` is applied when stamps are cut.
SELECTION_REASONS = ("bad_position", "flags", "low_snr", "saturated", "near_edge", "crowded",
                     "off_locus", "extended", "bad_stamp")

#: The parameter of :func:`select_stars` that relaxes each cut.
SELECTION_OPTIONS = {
    "flags": "flag_mask",
    "low_snr": "min_snr",
    "saturated": "saturation",
    "near_edge": "stamp_size",
    "crowded": "isolation",
    "off_locus": "locus_width",
    "extended": "max_spread_model / min_class_star",
}

#: Robust sigma from the median absolute deviation (Gaussian).
_MAD = 1.4826
#: A secondary cut that rejects more than this fraction of the locus is not applied.
_MOST = 0.5
#: PSFEx's default ``SAMPLE_FLAGMASK``: every SExtractor flag but 1 (neighbours close enough
#: to bias the photometry, which most stars of a real image have) rejects a source.
PSFEX_FLAG_MASK = 0xFE
#: Moffat index of the profile the mask radii are worked out with (from each source's
#: ``flux_radius``): wings between a Gaussian's and the atmosphere's (Kolmogorov).
_BETA = 3.0
#: A neighbour is masked out to where its surface brightness falls below this fraction of the
#: star's peak surface brightness.
_NEIGHBOUR_LEVEL = 1e-2
#: The locus's upper side, as a fraction of its lower side's half-width: 2.5 sigma above
#: against 3 below, since galaxies (larger) lie only above it.
_ABOVE = 5 / 6
#: Locus FWHM (pixels) below which a star's measured size depends on its sub-pixel phase:
#: at uniform random phases, the log of :func:`_sigma` scatters by 0.01-0.1 under 2 pixels,
#: 1e-3 at 2.3 and under 3e-4 from 2.5 (pixel-integrated Gaussians, and GalSim
#: ``OpticalPSF``s at 1.2 m / 700 nm and 2.4 m / 1.5 um drawn at several pixel scales).
_PHASE_FWHM = 2.3
#: FWHM per unit of each size column (a Gaussian's FWHM is 2.355 sigma, 2 half-light radii).
_FWHM_PER_SIZE = {"flux_radius": 2.0, "adaptive_sigma": 2.0 * np.sqrt(2.0 * np.log(2.0)),
                  "adaptive_sigma_masked": 2.0 * np.sqrt(2.0 * np.log(2.0))}


def _sizes_fluxes(catalog):
    """Moffat alpha (pixels, from ``flux_radius``; the median where unknown, else 2) and flux
    (NaN where unknown) of every source."""
    radius = _column(catalog, "flux_radius")
    n = len(catalog)
    # alpha = hlr / sqrt(2^(1/(beta-1)) - 1) for a Moffat profile
    alpha = np.full(n, np.nan) if radius is None else np.where(
        np.isfinite(radius) & (radius > 0), radius / np.sqrt(2 ** (1 / (_BETA - 1)) - 1),
        np.nan)
    fill = np.nanmedian(alpha) if np.isfinite(alpha).any() else 2.0
    alpha = np.where(np.isfinite(alpha), alpha, fill)
    flux = _column(catalog, "flux")
    flux = np.full(n, np.nan) if flux is None else np.where(np.isfinite(flux) & (flux > 0),
                                                             flux, np.nan)
    return alpha, flux


def _mask_radius(alpha_n, flux_n, alpha_s, flux_s):
    """Radius out to which neighbours (Moffat alpha_n, flux_n) outshine ``_NEIGHBOUR_LEVEL``
    of the star's peak surface brightness: (1 + (r/alpha_n)^2)^-beta = level q, with
    q = (F_s / F_n) (alpha_n / alpha_s)^2; at least alpha_n (the neighbour's core)."""
    ratio = np.where(np.isfinite(flux_n) & np.isfinite(flux_s), flux_s / flux_n, 1.0)
    return _radius_at(alpha_n, ratio * (alpha_n / alpha_s) ** 2)


def _radius_at(alpha_n, q):
    """:func:`_mask_radius` of neighbours of Moffat alpha ``alpha_n`` at level ratio ``q``."""
    return alpha_n * np.sqrt(np.maximum((_NEIGHBOUR_LEVEL * q) ** (-1 / _BETA) - 1, 1.0))


_PAIRS = 4096  # (star, neighbour) pairs drawn at once by neighbour_masks


def _neighbour_discs(catalog, rows, stamp_size):
    """The other sources within reach (Chebyshev) of the stamps of side ``stamp_size`` of
    ``rows``, as pairs (k, j), sorted by k: source j near ``rows[k]``, with j's mask radius
    ``r`` against that star (:func:`_mask_radius`); and every source's x, y and alpha."""
    alpha, flux = _sizes_fluxes(catalog)
    x, y = _column(catalog, "x"), _column(catalog, "y")
    if len(rows) == 0:
        none = np.zeros(0, dtype=np.intp)
        return none, none, np.zeros(0), x, y, alpha
    reach = (int(stamp_size) - 1) / 2 + 1.5 + 30 * np.nanmax(alpha, initial=2.0)
    # each source's own reach, within that: its widest disc against any of the stars (their
    # least level ratio q), plus a stamp's half side and the largest star's core
    a_s, f_s = alpha[rows], flux[rows]
    known = np.isfinite(f_s)
    by_flux = np.min(np.where(known, f_s, np.inf) / a_s**2, initial=np.inf)
    by_size = np.min(np.where(known, np.inf, 1.0 / a_s**2), initial=np.inf)
    q = alpha**2 * np.where(np.isfinite(flux), np.minimum(by_flux / flux, by_size),
                            1.0 / np.max(a_s, initial=1.0) ** 2)
    own = _radius_at(alpha, q) + max(int(stamp_size) // 2 + 1.0, np.max(a_s, initial=0.0))
    xy = np.column_stack([np.nan_to_num(x, nan=-1e12), np.nan_to_num(y, nan=-1e12)])
    found = cKDTree(xy[rows]).query_ball_point(xy, np.minimum(own + 1e-6, reach), p=np.inf)
    j = np.repeat(np.arange(len(xy)), [len(near) for near in found])
    k = np.fromiter(itertools.chain.from_iterable(found), dtype=np.intp, count=len(j))
    order = np.argsort(k, kind="stable")
    k, j = k[order], j[order]
    other = j != rows[k]
    k, j = k[other], j[other]
    i = rows[k]
    return k, j, _mask_radius(alpha[j], flux[j], alpha[i], flux[i]), x, y, alpha


def _crowded(catalog, rows, stamp_size):
    """True for each of ``rows`` whose core (within alpha of its centre, about its FWHM)
    a neighbour's mask reaches (see :func:`neighbour_masks`)."""
    rows = np.asarray(rows, dtype=np.intp)
    k, j, r, x, y, alpha = _neighbour_discs(catalog, rows, stamp_size)
    i = rows[k]
    d = np.hypot(x[j] - x[i], y[j] - y[i])
    return np.bincount(k[d < r + alpha[i]], minlength=len(rows)) > 0


def neighbour_masks(catalog, rows, stamp_size: int):
    """Pixels of the stamps of the sources ``rows`` that their neighbours' light covers.

    Each other source of ``catalog`` is masked within a disc whose radius grows with its size
    (``flux_radius``) and its flux relative to the star's: out to where its surface brightness,
    taken as a Moffat profile (beta = 3) of its half-light radius and flux, falls below 1%
    of the star's peak surface brightness, and at least its Moffat alpha (see
    :func:`select_stars`, whose default crowding cut rejects only the stars whose core such a
    disc reaches). Without ``flux`` the sources count as equally bright; without
    ``flux_radius``, as large as the median source (else alpha = 2 pixels). The stamps are
    centred as the stamp cutters centre them: the star's pixel
    ``floor(x + 0.5)`` at index ``stamp_size // 2``.

    Parameters
    ----------
    catalog : astropy.table.Table
        Every source of the image (0-based ``x``, ``y``; ``flux_radius`` and ``flux`` when
        known), not only the stars.
    rows : array-like of int
        The stars' rows in ``catalog``.
    stamp_size : int

    Returns
    -------
    masks : ndarray of bool, shape (len(rows), stamp_size, stamp_size)
        True where a neighbour's light is.

    Examples
    --------
    >>> from astropy.table import Table
    >>> from sklearn_psf.exposure import neighbour_masks
    >>> cat = Table({"x": [50.0, 58.0], "y": [50.0, 50.0], "flux_radius": [1.5, 1.5],
    ...              "flux": [1000.0, 100.0]})
    >>> m = neighbour_masks(cat, [0], 25)
    >>> m.shape, bool(m[0, 12, 20]), bool(m[0, 12, 12])    # the neighbour's pixel, the star's
    ((1, 25, 25), True, False)
    """
    rows = np.asarray(rows, dtype=np.intp)
    s = int(stamp_size)
    if len(rows) == 0 or len(catalog) < 2:
        return np.zeros((len(rows), s, s), dtype=bool)
    offsets = np.arange(s) - s // 2
    k, j, r, x, y, _ = _neighbour_discs(catalog, rows, s)
    i = rows[k]
    ok = np.isfinite(x[i]) & np.isfinite(y[i])
    k, j, i, r = k[ok], j[ok], i[ok], r[ok]
    px = np.floor(x[i] + 0.5)[:, None] + offsets  # image pixel of each stamp column
    py = np.floor(y[i] + 0.5)[:, None] + offsets
    # only the discs that reach the stamp's box of pixel centres
    gap = np.hypot(np.clip(x[j], px[:, 0], px[:, -1]) - x[j],
                   np.clip(y[j], py[:, 0], py[:, -1]) - y[j])
    near = gap < r + 0.5
    k, j, r, px, py = k[near], j[near], r[near], px[near], py[near]
    # every pixel a disc reaches (its centre within r + half a pixel), row by row: the
    # columns c of dx(c)**2 < (r + 1/2)**2 - dy**2, an interval, marked by +1 at its start and
    # -1 past its end in each stamp row, then summed along the row
    marks = np.zeros(len(rows) * s * (s + 1), dtype=np.int32)
    for start in range(0, len(k), _PAIRS):  # (bounded memory: s ints per pair)
        sl = slice(start, start + _PAIRS)
        xj, dy2 = x[j[sl]], (py[sl] - y[j[sl]][:, None]) ** 2
        r2 = (r[sl] + 0.5)[:, None] ** 2
        room = r2 - dy2
        reach = np.sqrt(np.maximum(room, 0.0))
        lo = np.floor(xj[:, None] - px[sl, :1] - reach).astype(np.int64) + 1
        hi = np.ceil(xj[:, None] - px[sl, :1] + reach).astype(np.int64) - 1

        def inside(c):  # the disc's own test at column c (the bounds exact to rounding)
            return (px[sl, :1] + c - xj[:, None]) ** 2 + dy2 < r2

        lo += np.where(inside(lo - 1), -1, np.where(inside(lo), 0, 1))
        hi += np.where(inside(hi + 1), 1, np.where(inside(hi), 0, -1))
        lo, hi = np.clip(lo, 0, s), np.clip(hi + 1, 0, s)
        row = (k[sl, None] * s + np.arange(s)) * (s + 1)
        on = (room > 0) & (lo < hi)
        np.add.at(marks, (row + lo)[on], 1)
        np.add.at(marks, (row + hi)[on], -1)
    return np.cumsum(marks.reshape(len(rows), s, s + 1), axis=2)[:, :, :s] > 0


def _column(table, name):
    """Column ``name`` (any case) as float64, or None."""
    lower = {c.lower(): c for c in table.colnames}
    if name not in lower:
        return None
    return np.asarray(table[lower[name]], dtype=np.float64)


def _vignettes(table):
    lower = {c.lower(): c for c in table.colnames}
    if "vignet" not in lower:
        return None
    try:
        vig = np.asarray(table[lower["vignet"]], dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"The catalogue's {lower['vignet']} column is not numeric "
                         f"({table[lower['vignet']].dtype}).") from None
    return vig if vig.ndim == 3 else None


def _peak(table):
    """Highest raw pixel of each source: ``peak`` (+ ``background``), or the vignette's max
    (+ ``background``)."""
    back = _column(table, "background")
    back = 0.0 if back is None else back
    peak = _column(table, "peak")
    if peak is not None:
        peak = peak + back
    vig = _vignettes(table)
    if vig is not None:
        vig = np.where(np.isfinite(vig) & (vig > -1e29), vig, -np.inf)
        vmax = vig.reshape(len(table), -1).max(axis=1) + back
        peak = vmax if peak is None else np.maximum(peak, vmax)
    return peak


def saturation_level(catalog, *, min_sources: int = 5, tolerance: float = 0.005):
    """The level at which the brightest sources' highest pixels pile up, if they do.

    Saturated stars share their highest raw pixel (the detector's or the digitiser's
    limit, or the level a resampled mosaic clipped them to), which unsaturated stars do
    only by chance. Where a header gives no ``SATURATE``, this finds the level: the first
    of the five highest peaks (``peak`` + ``background``, else the ``VIGNET``'s maximum)
    that at least ``min_sources`` peaks lie within ``tolerance`` of (relative), their
    median. Source Extractor's default ``SATUR_LEVEL`` (50000) flags none of them on an
    image that saturates lower (e.g. a 14-bit camera).

    Parameters
    ----------
    catalog : astropy.table.Table
        A catalogue as :func:`~sklearn_psf.io.read_catalog` returns it.
    min_sources : int, default=5
    tolerance : float, default=0.005

    Returns
    -------
    level : float or None
        None where no level is shared, or the catalogue has no peaks.
    n_sources : int
        How many sources peak within ``tolerance`` of it (0 with no level).

    Examples
    --------
    >>> import numpy as np
    >>> from astropy.table import Table
    >>> peaks = np.r_[np.linspace(100.0, 9000.0, 200), np.full(8, 16383.0)]
    >>> saturation_level(Table({"x": peaks, "y": peaks, "peak": peaks}))
    (16383.0, 8)
    >>> saturation_level(Table({"x": peaks[:200], "y": peaks[:200], "peak": peaks[:200]}))
    (None, 0)
    """
    peak = _peak(catalog)
    if peak is None:
        return None, 0
    p = np.sort(np.asarray(peak, dtype=np.float64)[np.isfinite(peak)])[::-1]
    for level in p[:5]:
        near = np.abs(p - level) <= tolerance * abs(level)
        if level > 0 and near.sum() >= min_sources:
            return float(np.median(p[near])), int(near.sum())
    return None, 0


def _size(table, rows=None):
    """(size, name) of each source: with ``rows`` and ``VIGNET``s, the sigma (:func:`_sigma`)
    of those rows' VIGNETs with their neighbours masked (:func:`neighbour_masks`; NaN
    where not measurable); else ``flux_radius``; else the sigma of the ``VIGNET``. A VIGNET
    that sums to no positive flux, or whose sigma is not measured, is measured again with
    its local level removed (the median of its unmasked pixels within 3 of the border): a
    background off by a fraction of the sky noise is a pedestal that outweighs a faint star
    over a whole VIGNET (most stars of a DSLR frame's catalogue)."""
    vig = _vignettes(table)
    radius = _column(table, "flux_radius")
    if vig is not None and len(vig) and rows is not None and vig.shape[1] == vig.shape[2]:
        rows = np.asarray(rows)
        sub = vig[rows]
        valid = (np.isfinite(sub) & (sub > -1e29)
                 & ~neighbour_masks(table, rows, vig.shape[1]))
        sigma = np.full(len(table), np.nan)
        data = np.where(valid, sub, 0.0)
        for again in (False, True):
            if again:  # the others, their local level removed
                border = np.ones(sub.shape[1:], dtype=bool)
                border[3:-3, 3:-3] = False
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", RuntimeWarning)  # no border pixel left
                    level = np.nanmedian(np.where(valid & border, sub, np.nan), axis=(1, 2))
                data = np.where(valid, sub - np.nan_to_num(level)[:, None, None], 0.0)
            # measurable: enough unmasked pixels and a positive flux
            ok = ~np.isfinite(sigma[rows]) & (valid.sum(axis=(1, 2)) >= 9) \
                & (data.sum(axis=(1, 2)) > 0)
            if ok.any():
                sigma[rows[ok]] = _sigma(data[ok], valid[ok], vig.shape[1])
        return sigma, "adaptive_sigma_masked"
    if radius is not None:
        return radius, "flux_radius"
    if vig is None or len(vig) == 0:
        return None, None
    valid = np.isfinite(vig) & (vig > -1e29)
    return _sigma(np.where(valid, vig, 0.0), valid, vig.shape[1]), "adaptive_sigma"


def _windowed_snr(table, rows, fallback):
    """The S/N of each source in a Gaussian window on its ``VIGNET`` (rows ``rows``; the
    others keep ``fallback``), as Source Extractor's ``SNR_WIN``: the window's sigma is
    ``2 FLUX_RADIUS / 2.355`` (else the adaptive-moment sigma of the VIGNET), centred on the
    source's sub-pixel position; the noise of each pixel the VIGNET's own sky noise (1.4826
    times the median absolute deviation of its pixels within 3 of the border; the source's
    Poisson noise, which matters only far above any S/N cut, is left out), masked pixels
    left out. None without VIGNETs. On the GalSim CCD of
    ``tests/test_sextractor_matrix.py`` it is SExtractor's ``SNR_WIN`` times 1.04 (median;
    0.96-1.15 for 10-90% of the sources at S/N 10-40), where ``FLUX_AUTO / FLUXERR_AUTO`` is
    0.67 times it (0.64-0.77)."""
    vig = _vignettes(table)
    if vig is None or vig.shape[1] != vig.shape[2] or vig.shape[1] < 9:
        return None
    s = vig.shape[1]
    sub = vig[rows]
    valid = np.isfinite(sub) & (sub > -1e29)
    data = np.where(valid, sub, 0.0)
    yy, xx = np.mgrid[0:s, 0:s]
    ring = np.minimum(np.minimum(yy, xx), np.minimum(s - 1 - yy, s - 1 - xx)) < 3
    sky = np.where(valid & ring, data, np.nan).reshape(len(rows), -1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # an all-masked ring: NaN
        noise = 1.4826 * np.nanmedian(np.abs(sky - np.nanmedian(sky, axis=1)[:, None]), axis=1)
    radius = _column(table, "flux_radius")
    width = None if radius is None else 2.0 * radius[rows] / 2.3548
    if width is None or not (width > 0).any():
        width = _sigma(data, valid, s)
    width = np.clip(np.nan_to_num(width, nan=1.0), 0.5, s / 4)
    x, y = _column(table, "x")[rows], _column(table, "y")[rows]
    cx, cy = s // 2 + x - np.floor(x + 0.5), s // 2 + y - np.floor(y + 0.5)
    window = np.exp(-0.5 * ((xx - cx[:, None, None]) ** 2 + (yy - cy[:, None, None]) ** 2)
                    / width[:, None, None] ** 2) * valid
    with np.errstate(divide="ignore", invalid="ignore"):
        snr = (window * data).sum(axis=(1, 2)) / (
            noise * np.sqrt((window**2).sum(axis=(1, 2))))
    out = np.array(fallback, dtype=np.float64, copy=True)
    measured = np.isfinite(snr) & (noise > 0) & (valid.sum(axis=(1, 2)) >= 9)
    out[rows[measured]] = snr[measured]
    return out


def _sigma(data, valid, side):
    """Adaptive-moment sigma of the stamps; where adaptive moments fail (undersampled stars:
    "object too small"), the FWHM / 2.355 of :func:`~sklearn_psf.preprocessing.stamp_fwhm`
    (fixed-weight moments corrected for the weight); NaN where neither is measurable."""
    from ..measure import adaptive_moments
    from ..preprocessing import stamp_fwhm

    weights = valid.astype(np.float64)
    mom = adaptive_moments(data, weights=weights, guess_sigma=max(1.0, side / 10))
    sigma = np.where(np.asarray(mom["flag"]) == 0, np.asarray(mom["sigma"], float), np.nan)
    bad = np.flatnonzero(~np.isfinite(sigma))
    if bad.size:
        sigma[bad] = stamp_fwhm(data[bad], weights[bad]) / (2.0 * np.sqrt(2.0 * np.log(2.0)))
    return sigma


def _on_field(x, y, image_shape, header):
    """Finite positions whose pixel lies on the image (``image_shape``, else the extent
    ``NAXIS1`` x ``NAXIS2`` of the catalogue's image header, e.g. SExtractor's
    ``LDAC_IMHEAD``; only finiteness without either)."""
    ok = np.isfinite(x) & np.isfinite(y)
    if image_shape is None and header is not None:
        shape = [header.get(k) for k in ("NAXIS2", "NAXIS1")]
        if all(isinstance(v, (int, np.integer)) and v > 0 for v in shape):
            image_shape = shape
    if image_shape is not None:
        ny, nx = image_shape
        with np.errstate(invalid="ignore"):
            ok &= (x >= -0.5) & (x < nx - 0.5) & (y >= -0.5) & (y < ny - 0.5)
    return ok


def _densest(values, half_width):
    """Centre of the window of ``2 * half_width`` holding the most values (the mode)."""
    v = np.sort(values)
    stop = np.searchsorted(v, v + 2 * half_width, side="right")
    i = int(np.argmax(stop - np.arange(v.size)))
    return float(np.median(v[i:stop[i]]))


def _poly_design(u, v, order):
    return np.column_stack([u**i * v**j for i in range(order + 1)
                            for j in range(order + 1 - i)])


def _locus(log_size, bright, snr, x, y, width, fwhm_per_size=None):
    """The stellar locus of ``log_size`` over the field, and each source's allowed distance.

    1. Seed: the densest 16%-wide window of sizes among the brighter half of the sources
       (at least 10): stars pile up at one size, galaxies spread over larger ones.
    2. The locus centre varies over the field as the PSF: a polynomial in (x, y) (order 2
       with >= 30 locus stars, 1 with >= 10, else a constant) fitted to the sources near it,
       twice, with the width below.
    3. Width: the scatter about the centre grows at low S/N as measurement noise,
       ``s(snr)^2 = s0^2 + (a / snr)^2``, fitted on the sources *below* the locus (galaxies
       only lie above it) within 30%, in S/N bins (:func:`_scatter`); a source is on the
       locus within 3 s(snr) (``width="auto"``) or within ``width`` (relative). When the
       seed's FWHM (``fwhm_per_size`` times its size) is under ``_PHASE_FWHM`` pixels the
       stars are undersampled: their measured size also depends on their sub-pixel phase
       (0.025 in log size at FWHM 1.7 px, GalSim's Euclid-like ``OpticalPSF``), a
       non-Gaussian scatter that the 15-source bins sample unevenly (robust sigmas 0.011 to
       0.061 at every S/N on the Euclid-like seed-4 CCD of
       ``benchmarks/bench_undersampled.py``). With each bin weighted by its own variance the
       luckiest bin sets the width (there 3 s = 0.045 against stars spread over -0.077 to
       +0.069: 82.6% of the clean stars kept), so the bins are weighted by the fitted
       variance instead (``reweight``: 98.3%, no non-star). Well-sampled loci keep the
       own-variance weights, whose narrower width rejects more compact galaxies (the GalSim
       CCD of ``tests/test_sextractor_matrix.py``: 7 non-stars among 197 kept, against 12
       among 202 reweighted).

    Returns (centre, half_width) per source, in log size, or None when too few sources.
    """
    n = log_size.size
    if n < 3:
        return None
    order = np.argsort(-bright)
    top = order[: max(min(n, 10), n // 2)]
    seed = _densest(log_size[top], 0.08)
    reweight = fwhm_per_size is not None and fwhm_per_size * np.exp(seed) < _PHASE_FWHM
    u = (x - x.mean()) / max(np.ptp(x), 1.0)
    v = (y - y.mean()) / max(np.ptp(y), 1.0)
    near = np.zeros(n, dtype=bool)
    near[top] = np.abs(log_size[top] - seed) <= 0.1
    sigma = np.full(n, 0.05)
    for _ in range(3):
        deg = 2 if near.sum() >= 30 else 1 if near.sum() >= 10 else 0
        design = _poly_design(u, v, deg)
        w = 1.0 / sigma[near]  # faint sources count less
        coef, *_ = np.linalg.lstsq(design[near] * w[:, None], log_size[near] * w, rcond=None)
        centre = design @ coef
        d = log_size - centre
        if isinstance(width, str):
            sigma = _scatter(d, snr, reweight=reweight)
            half = 3.0 * sigma
        else:
            half = np.full(n, float(width))
        near = np.abs(d) <= half
        if near.sum() < 3:
            break
    return centre, half


def _scatter(d, snr, window=0.3, per_bin=15, reweight=False):
    """Scatter of the locus at each source's S/N from the sources below it (see _locus): one
    level, or ``s0^2 + (a / snr)^2`` fitted over S/N bins of ``per_bin`` sources when the
    S/N spans a factor 2 or more, each bin weighted by its own variance, or with
    ``reweight`` by the fitted one (3 passes)."""
    below = (d < 0) & (d > -window)
    if below.sum() < 3:
        return np.full(d.size, 0.05)
    if snr is not None:
        s_below = snr[below]
        spans = np.nanmax(s_below) >= 2 * np.nanmin(s_below) if np.isfinite(s_below).any() \
            else False
    if snr is None or below.sum() < 2 * per_bin or not spans:
        s = _MAD * float(np.median(-d[below]))
        return np.full(d.size, max(s, 0.01))
    idx = np.flatnonzero(below)
    idx = idx[np.argsort(snr[idx])]
    bins = np.array_split(idx, max(1, idx.size // per_bin))
    var = np.array([(_MAD * np.median(-d[b])) ** 2 for b in bins])
    inv2 = np.array([np.mean(1.0 / np.maximum(snr[b], 1e-3) ** 2) for b in bins])
    design = np.column_stack([np.ones_like(inv2), inv2])
    root_n = np.sqrt([len(b) for b in bins])
    fitted = var
    for _ in range(1 + 3 * reweight):
        w = root_n / np.maximum(fitted, 1e-8)  # relative precision
        (s0, a2), _ = nnls(design * w[:, None], var * w)
        fitted = s0 + a2 * inv2
    s = np.sqrt(s0 + a2 / np.maximum(np.nan_to_num(snr, nan=1.0), 1e-3) ** 2)
    return np.maximum(s, 0.01)


def _relax_text(counts, options):
    """``"low_snr 28 (min_snr), off_locus 40 (locus_width)"``: each reason's count and option."""
    return ", ".join(f"{k} {counts[k]} ({options[k]})" for k in SELECTION_REASONS
                     if counts.get(k) and k in options)


def select_stars(catalog, *, min_snr: float = 20.0, saturation: float | None = None,
                 flag_mask: int | None = PSFEX_FLAG_MASK, stamp_size: int = 25, image_shape=None,
                 isolation: float | None = None, locus_width: float | str = "auto",
                 max_spread_model: float = 0.003, min_class_star: float = 0.8,
                 min_stars: int = 1):
    """Select clean, isolated point sources of a catalogue, counting each rejection by reason.

    Cuts, in this order (a source is counted under the first it fails; a cut whose columns
    are absent is skipped; each is explained in :ref:`star-selection`): ``bad_position``
    (NaN, or off the image), ``flags`` (``flags & flag_mask``), ``low_snr``, ``saturated``
    (peak at or above 0.9 ``saturation``), ``near_edge``, ``crowded`` (a neighbour whose light
    reaches the star's core; farther ones are masked when the stamps are cut, see
    :func:`neighbour_masks`), ``off_locus`` (the size-magnitude locus, the primary
    point-source test), ``extended`` (``spread_model``, else ``class_star``, secondary: not
    applied where it would reject most of the locus).

    Parameters
    ----------
    catalog : astropy.table.Table
        Sources with 0-based ``x``, ``y`` and optional columns ``flags``, ``snr``, ``flux``,
        ``peak``, ``background``, ``VIGNET``, ``flux_radius``, ``spread_model``,
        ``spreaderr_model``, ``class_star`` (any case), as
        :func:`~sklearn_psf.io.read_catalog` returns them.
    min_snr : float, default=20
        Smallest S/N (PSFEx's default too): a noise-aware model uses faint stars.
    saturation : float, optional
        Saturation level of the raw image (header ``SATURATE``); None: no cut.
    flag_mask : int or None, default=PSFEX_FLAG_MASK
        Bits of ``flags`` that reject a source (None: every bit). PSFEx's default, ``0xfe``,
        keeps sources flagged 1 (neighbours close enough to bias the photometry: most stars
        of a real image); their neighbours are judged by the ``crowded`` cut.
    stamp_size : int, default=25
        Side of the stamps (edge margin, default isolation).
    image_shape : tuple (ny, nx), optional
        Shape of the image; None: no edge cut.
    isolation : float, optional
        Smallest Chebyshev distance to another source, pixels, instead of the default
        neighbour-aware ``crowded`` cut. 0: no crowding cut.
    locus_width : float or "auto", default="auto"
        Relative half-width of the locus below it (five sixths of it above); ``"auto"``: 3
        times the locus's scatter at each source's S/N below, 2.5 times above.
    max_spread_model : float, default=0.003
        Largest ``|spread_model|`` (plus 2 ``spreaderr_model``) of a point source.
    min_class_star : float, default=0.8
        Smallest ``class_star`` of a point source, used without a size column only.
    min_stars : int, default=1
        Fewer selected stars raise a ValueError that counts the sources dropped by each cut
        and names the parameter relaxing it. 0: never raise.

    Returns
    -------
    keep : ndarray of bool, shape (n,)
        True for the selected stars.
    counts : dict
        Reason (every one of :data:`SELECTION_REASONS`) -> number of sources dropped;
        ``locus_size`` (the size column: ``"flux_radius"``, ``"adaptive_sigma"`` or None),
        ``locus_radius`` (median size of the locus at the selected stars) and
        ``locus_width`` (their median relative half-width), NaN without a locus;
        ``not_applied``: secondary cut (``"spread_model"`` or ``"class_star"``) -> fraction
        of the locus it would have rejected, for cuts left out; ``snr_from`` (a catalogue
        without ``SNR_WIN``): ``"vignets"`` when the S/N was measured in a Gaussian window on
        the ``VIGNET``s, ``"fluxes"`` without them.

    Raises
    ------
    ValueError
        Without ``x``, ``y`` columns, or when fewer than ``min_stars`` stars are selected.

    Examples
    --------
    >>> import numpy as np
    >>> from astropy.table import Table
    >>> from sklearn_psf.exposure import select_stars
    >>> rng = np.random.default_rng(0)
    >>> radius = np.r_[rng.normal(2.0, 0.02, 60), rng.uniform(2.6, 5.0, 40)]
    >>> cat = Table({"x": rng.uniform(0, 4000, 100), "y": rng.uniform(0, 4000, 100),
    ...              "flux_radius": radius, "snr": np.full(100, 200.0),
    ...              "class_star": np.full(100, 0.6)})    # SEEING_FWHM left unset
    >>> keep, counts = select_stars(cat)
    >>> int(keep[:60].sum()), int(keep[60:].sum()), counts["off_locus"]
    (60, 0, 40)
    >>> counts["not_applied"]                 # a CLASS_STAR > 0.8 cut would drop every star
    {'class_star': 1.0}
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
    counts.update({"locus_size": None, "locus_radius": np.nan, "locus_width": np.nan,
                   "not_applied": {}})
    keep = np.ones(n, dtype=bool)

    def cut(name, ok):
        nonlocal keep
        ok = np.asarray(ok, dtype=bool)
        counts[name] += int(np.count_nonzero(keep & ~ok))
        keep &= ok

    cut("bad_position", _on_field(x, y, image_shape, catalog.meta.get("image_header")))
    flags = _column(catalog, "flags")
    if flags is not None:
        bits = np.nan_to_num(flags, nan=1.0).astype(np.int64)
        cut("flags", (bits & (-1 if flag_mask is None else int(flag_mask))) == 0)
    snr = _column(catalog, "snr")
    if snr is not None and catalog.meta.get("snr_from_fluxes") and keep.any():
        windowed = _windowed_snr(catalog, np.flatnonzero(keep), snr)
        counts["snr_from"] = "fluxes" if windowed is None else "vignets"
        snr = snr if windowed is None else windowed
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
    if n > 1 and isolation is None:
        left = np.flatnonzero(keep)
        ok = np.ones(n, dtype=bool)
        ok[left] = ~_crowded(catalog, left, stamp_size)
        cut("crowded", ok)
    elif n > 1:
        finite = np.column_stack([np.nan_to_num(x, nan=-1e12), np.nan_to_num(y, nan=-1e12)])
        d, _ = cKDTree(finite).query(finite, k=2, p=np.inf)
        cut("crowded", d[:, 1] >= float(isolation))

    size, size_name = (_size(catalog, np.flatnonzero(keep) if isolation is None else None)
                       if keep.any() else (None, None))
    on_locus = None
    if size is not None:
        counts["locus_size"] = size_name
        cut("off_locus", np.isfinite(size) & (size > 0))
        left = np.flatnonzero(keep)
        flux = _column(catalog, "flux")
        bright = flux if flux is not None else snr if snr is not None else -size
        found = _locus(np.log(size[left]), np.nan_to_num(bright[left], nan=-np.inf),
                       None if snr is None else snr[left], x[left], y[left], locus_width,
                       _FWHM_PER_SIZE.get(size_name))
        if found is not None:
            centre, width = found
            ok = np.zeros(n, dtype=bool)
            offset = np.log(size[left]) - centre  # galaxies lie above: a narrower side
            ok[left] = (offset >= -width) & (offset <= _ABOVE * width)
            cut("off_locus", ok)
            on = ok[left]
            if on.any():
                counts["locus_radius"] = float(np.exp(np.median(centre[on])))
                counts["locus_width"] = float(np.median(np.expm1(width[on])))
            on_locus = keep.copy()

    spread, cls = _column(catalog, "spread_model"), _column(catalog, "class_star")
    secondary = None
    if spread is not None:
        err = _column(catalog, "spreaderr_model")
        limit = max_spread_model + (0.0 if err is None else 2.0 * np.nan_to_num(err))
        secondary = ("spread_model", np.abs(np.nan_to_num(spread, nan=np.inf)) <= limit)
    elif cls is not None:
        secondary = ("class_star", np.nan_to_num(cls, nan=-1.0) >= min_class_star)
    if secondary is not None:
        name, ok = secondary
        rejected = float(np.mean(~ok[on_locus])) if on_locus is not None and on_locus.any() \
            else 0.0
        if name == "class_star" and size is not None:
            if rejected > 0:
                counts["not_applied"][name] = rejected
        elif rejected > _MOST:
            counts["not_applied"][name] = rejected
        else:
            cut("extended", ok)
    selected = int(keep.sum())
    if selected < int(min_stars):
        raise ValueError(
            f"{selected} of {n} sources pass the star selection, fewer than {int(min_stars)}: "
            f"dropped by cut (parameter relaxing it): "
            f"{_relax_text(counts, SELECTION_OPTIONS) or 'none'}.")
    return keep, counts
