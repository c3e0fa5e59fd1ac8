"""make_psf_field: mock PSF field images (Berge et al. 2012, section 3), with truth.

The conventions (PSF model, positions, S/N, contaminants, weights, seeds) are documented in
:mod:`sklearn_psf.simulate`.
"""

from __future__ import annotations

import numbers
import warnings

import numpy as np
from astropy.table import Table
from scipy.spatial import cKDTree

from ..datasets import ReferenceBasis, load_default_reference
from ..datasets._reference import _version
from ..measure import adaptive_moments
from ..preprocessing import StampNormalizer, cut_stamps
from ._contaminants import (
    apply_defects,
    contaminate_stars,
    field_cosmic_rays,
    field_galaxies,
    render,
)
from ._chromatic import chromatic_stamps, draw_colours
from ._field import PSFField, core_mask, realistic_snr
from ._random_field import RandomFieldSampler, as_generator
from ._settings import (
    ContaminantSettings,
    DetectorSettings,
    SourceSettings,
    _check_int,
    _settings,
)

__all__ = ["make_psf_field"]

#: Default smallest scale of the PSF variations (arcsec): the random fields' grid cell.
DEFAULT_SMALLEST_SCALE = 8.0
#: Extra distance (pixels) between objects when stars carry contaminants: a neighbour (up to
#: 8 pixels away) or a contaminating galaxy (stamps 16 pixels wider) reaches 8 pixels further.
_CONTAMINANT_REACH = 8


def _grid_positions(n, lo, hi_x, hi_y, stamp):
    """About n integer points on a regular grid inside [lo, hi_x] x [lo, hi_y]."""
    wx, wy = hi_x - lo + 1, hi_y - lo + 1
    ncol = max(1, int(round(np.sqrt(n * wx / wy))))
    nrow = max(1, int(round(n / ncol)))
    xs = np.floor(lo + (np.arange(ncol) + 0.5) * wx / ncol)
    ys = np.floor(lo + (np.arange(nrow) + 0.5) * wy / nrow)
    if (ncol > 1 and np.min(np.diff(xs)) < stamp) or (nrow > 1 and np.min(np.diff(ys)) < stamp):
        raise ValueError(
            f"A grid of {n} galaxy-PSFs is too dense for the image: neighbouring stamps of side "
            f"{stamp} would overlap. Use fewer galaxy-PSFs or a larger image."
        )
    gx, gy = np.meshgrid(xs, ys)
    return np.column_stack([gx.ravel(), gy.ravel()])


def _draw_positions(n, fixed, lo, hi_x, hi_y, stamp, rng, what):
    """n random integer positions, no stamp overlapping ``fixed`` or each other."""
    placed = [np.asarray(fixed, dtype=np.float64).reshape(-1, 2)]
    need = n
    for _ in range(200):
        if need == 0:
            break
        m = int(need * 1.3) + 16
        cand = np.column_stack([rng.integers(lo, hi_x + 1, m), rng.integers(lo, hi_y + 1, m)])
        cand = cand.astype(np.float64)
        existing = np.concatenate(placed)
        if len(existing):
            d, _ = cKDTree(existing).query(cand, p=np.inf)
            cand = cand[d >= stamp]
        if len(cand) > 1:
            pairs = cKDTree(cand).query_pairs(stamp - 0.5, p=np.inf, output_type="ndarray")
            if len(pairs):
                keep = np.ones(len(cand), dtype=bool)
                keep[pairs.max(axis=1)] = False
                cand = cand[keep]
        cand = cand[:need]
        placed.append(cand)
        need -= len(cand)
    if need:
        raise ValueError(
            f"Could not place {n} non-overlapping {what} of stamp side {stamp} on the image: "
            "use fewer objects, smaller stamps or a larger image."
        )
    return np.concatenate(placed[1:]) if n else np.zeros((0, 2))



def _truth(reference, positions, sampler, normalizer, basis, source=None):
    """Truth stamps, coefficients and moments; ``source`` (a dict of
    :func:`chromatic_stamps`'s keywords) makes each PSF that of its source."""
    n = len(positions)
    s2 = reference.stamp_size ** 2
    if n == 0:
        k = reference.n_components
        return np.zeros((0, s2)), np.zeros((0, k)), Table(
            {"e1": np.zeros(0), "e2": np.zeros(0), "sigma": np.zeros(0),
             "flag": np.zeros(0, dtype=np.int64)})
    weights = reference.coeff_mean + reference.coeff_std * sampler(positions)
    stamps = normalizer.transform(reference.synthesize(weights))
    if source is not None:
        stamps = normalizer.transform(chromatic_stamps(stamps, **source))
    coeffs = basis.transform(stamps)
    return stamps, coeffs, adaptive_moments(stamps)


def _table(positions, stamps, coeffs, mom, snr, flux):
    return Table({
        "x": positions[:, 0], "y": positions[:, 1], "stamp": stamps, "coeffs": coeffs,
        "e1": np.asarray(mom["e1"], dtype=np.float64), "e2": np.asarray(mom["e2"], dtype=np.float64),
        "sigma": np.asarray(mom["sigma"], dtype=np.float64),
        "moments_flag": np.asarray(mom["flag"], dtype=np.int64),
        "snr": np.asarray(snr, dtype=np.float64), "flux": np.asarray(flux, dtype=np.float64),
    })


def _star_kinds(n, fractions, rng):
    """Contaminant kind of each star ("" = clean): exact counts, random stars."""
    kinds = np.full(n, "", dtype=object)
    order = rng.permutation(n)
    start = 0
    for kind, frac in fractions.items():
        m = int(round(frac * n))
        kinds[order[start:start + m]] = kind
        start += m
    return kinds


def make_psf_field(
    reference: ReferenceBasis | None = None,
    n_stars: int = 1000,
    n_galaxies: int = 2000,
    galaxy_layout: str = "random",
    snr=100.0,
    image_shape=(7769, 10032),
    pixel_scale: float | None = None,
    stamp_size: int | None = None,
    star_positions=None,
    slope: float = 11 / 4,
    random_state=None,
    *,
    galaxy_snr: float | None = 1000.0,
    smallest_scale: float = DEFAULT_SMALLEST_SCALE,
    subpixel: bool = True,
    grid_size: int | None = None,
    galaxy_positions=None,
    weight_fields=None,
    contaminants: ContaminantSettings | dict | None = None,
    detector: DetectorSettings | None = None,
    sources: SourceSettings | None = None,
) -> PSFField:
    """Simulate a PSF field image with stars and galaxy-PSFs (Berge et al. 2012, sect. 3).

    Conventions (S/N, contaminants, weights, seeds): :mod:`sklearn_psf.simulate` and
    :ref:`simulations`. The defaults give the paper's clean study with sub-pixel positions.

    Parameters
    ----------
    reference : ReferenceBasis, optional
        Basis of the PSFs; default :func:`sklearn_psf.datasets.load_default_reference`.
    n_stars, n_galaxies : int, default=1000 and 2000
        Stars and galaxy-PSFs at random positions.
    galaxy_layout : {"random", "grid"}, default="random"
        Galaxy-PSFs at random or on a grid (about ``n_galaxies`` of them).
    snr : float or array-like of shape (n_stars,), default=100
        S/N of every star (> 0); :func:`realistic_snr` draws the paper's distribution.
    image_shape : tuple (ny, nx), default=(7769, 10032)
        The paper's Subaru image.
    pixel_scale, stamp_size : float and odd int, optional
        Arcsec per pixel and stamp side; default the reference's (larger: zero-padded).
    star_positions, galaxy_positions : array-like of shape (n, 2), optional
        (x, y) positions kept as given instead of ``n_stars`` / ``n_galaxies`` random ones.
    slope, smallest_scale : float, default=11/4 and 8.0
        Power-spectrum slope and cell (arcsec) of the PSF weights' random fields.
    random_state : None, int, SeedSequence or Generator
        Seed (see the module documentation).
    galaxy_snr : float or None, default=1000
        S/N of the galaxy-PSFs drawn in the image; None leaves them out of the image.
    subpixel : bool, default=True
        PSFs at their exact sub-pixel positions; False: on pixel centres (the paper's).
    grid_size : int, optional
        Deprecated (use ``smallest_scale``): random-field nodes along the longer side.
    weight_fields : callable, optional
        ``weight_fields(positions)`` -> (n, n_components) fields replacing the random ones.
    contaminants : ContaminantSettings or dict, optional
        Contaminants on the stars (truth: ``stars["contaminant"]``) and objects elsewhere in
        the image; a dict ``{kind: fraction of the stars}`` is short for
        ``ContaminantSettings(fractions=...)``. Default none.
    detector : DetectorSettings, optional
        Background noise (default the reference image's rms, else 1), Poisson noise,
        saturation and masked pixels; default :class:`DetectorSettings`'s, no defect.
    sources : SourceSettings, optional
        PSFs depending on their source's colour or flux; default the position's alone.

    Returns
    -------
    PSFField

    Raises
    ------
    ValueError
        For n_stars < 1, snr <= 0 or of the wrong length, stars off the image, stamps larger
        than the image, objects too many to fit without overlap, more bad columns than the
        image has.
    TypeError
        For settings of the wrong type.

    Examples
    --------
    >>> from sklearn_psf.simulate import DetectorSettings, make_psf_field
    >>> field = make_psf_field(n_stars=50, n_galaxies=40, image_shape=(1000, 1200), random_state=42)
    >>> field.image.shape, len(field.stars), field.stars["stamp"].shape[0], len(field.galaxies)
    ((1000, 1200), 50, 50, 40)
    >>> dirty = make_psf_field(n_stars=40, n_galaxies=0, image_shape=(800, 800),
    ...                        contaminants={"cosmic_ray": 0.1, "binary": 0.1},
    ...                        detector=DetectorSettings(bad_columns=1), random_state=0)
    >>> sorted(set(map(str, dirty.stars["contaminant"]))), int((dirty.weight == 0).all(0).sum())
    (['', 'binary', 'cosmic_ray'], 1)
    """
    contaminants = _settings(contaminants, ContaminantSettings, "contaminants", "fractions")
    detector = _settings(detector, DetectorSettings, "detector")
    sources = _settings(sources, SourceSettings, "sources")
    reference, (ny, nx) = _check_reference(reference, stamp_size, image_shape)
    s = reference.stamp_size
    h = s // 2
    if galaxy_layout not in ("random", "grid"):
        raise ValueError(f"galaxy_layout must be 'random' or 'grid', got {galaxy_layout!r}.")
    n_galaxies = _check_int("n_galaxies", n_galaxies, 0)
    if detector.bad_columns > nx:
        raise ValueError(f"bad_columns ({detector.bad_columns}) exceeds the image width {nx}.")
    box = (h, nx - 1 - h, ny - 1 - h)
    fixed_stars = None
    if star_positions is not None:
        fixed_stars = _fixed_star_positions(star_positions, subpixel, box, s, (ny, nx))
        n_stars = len(fixed_stars)
    n_stars = _check_int("n_stars", n_stars, 1)
    snr_arr = _check_snr(snr, n_stars)
    if galaxy_snr is not None and not (np.isfinite(galaxy_snr) and galaxy_snr > 0):
        raise ValueError(f"galaxy_snr must be positive or None, got {galaxy_snr}.")
    noise_rms = detector.noise_rms
    if noise_rms is None:
        noise_rms = reference.noise_rms if reference.noise_rms else 1.0
    noise_rms = float(noise_rms)
    if not (np.isfinite(noise_rms) and noise_rms > 0):
        raise ValueError(f"noise_rms must be positive, got {noise_rms}.")
    pixel_scale = reference.pixel_scale if pixel_scale is None else float(pixel_scale)
    smallest_scale = _smallest_scale(smallest_scale, grid_size, (ny, nx), pixel_scale)
    cell = float(smallest_scale) / pixel_scale

    seed = int(random_state) if isinstance(random_state, numbers.Integral) else None
    rng = as_generator(random_state)
    (field_rng, star_rng, gal_rng, noise_rng, sub_rng, cont_rng, defect_rng,
     source_rng) = rng.spawn(8)

    # with contaminants on stars, 8 more pixels between objects (a neighbour's or a galaxy's
    # light stays out of the other stars' stamps: the clean stars stay clean)
    gap = s + _CONTAMINANT_REACH if any(contaminants.fractions.values()) else s
    star_pos, gal_pos = _positions(n_stars, n_galaxies, fixed_stars, galaxy_positions,
                                   galaxy_layout, subpixel, box, gap,
                                   (star_rng, gal_rng, sub_rng))

    sampler = weight_fields if weight_fields is not None else RandomFieldSampler(
        (ny, nx), reference.n_components, slope, cell=cell, random_state=field_rng)
    normalizer = StampNormalizer(flux=True, center=True).fit(reference.mean.reshape(1, -1))
    basis = reference.as_transformer(normalize=False)

    def truth(positions, source=None):
        return _truth(reference, positions, sampler, normalizer, basis, source)

    def flux_for(stamps, target):
        core = core_mask(stamps)
        return target * noise_rms / ((stamps * core).sum(axis=1) / core.sum(axis=1))

    star_source, gal_source, columns = _sources(sources, snr_arr, len(gal_pos), pixel_scale,
                                                source_rng)
    star_stamps, star_coeffs, star_mom = truth(star_pos, star_source)
    gal_stamps, gal_coeffs, gal_mom = truth(gal_pos, gal_source)
    star_flux = flux_for(star_stamps, snr_arr)
    if galaxy_snr is None:
        gal_snr, gal_flux = np.zeros(len(gal_pos)), np.zeros(len(gal_pos))
    else:
        gal_snr = np.full(len(gal_pos), float(galaxy_snr))
        gal_flux = flux_for(gal_stamps, gal_snr) if len(gal_pos) else np.zeros(0)

    stars = _table(star_pos, star_stamps, star_coeffs, star_mom, snr_arr, star_flux)
    galaxies = _table(gal_pos, gal_stamps, gal_coeffs, gal_mom, gal_snr, gal_flux)
    for table, values in zip((stars, galaxies), columns):
        for name, v in values.items():
            table[name] = v
    kinds = _star_kinds(n_stars, contaminants.fractions, cont_rng)

    # the image: sources (noiseless canvas when the Poisson noise needs them), then noise
    if detector.gain is None:
        canvas = noise_rng.standard_normal((ny, nx), dtype=np.float32)
        canvas *= np.float32(noise_rms)
    else:
        canvas = np.zeros((ny, nx), dtype=np.float32)
    clean = kinds == ""
    render(canvas, star_pos[clean], star_stamps[clean], star_flux[clean])
    if galaxy_snr is not None:
        render(canvas, gal_pos, gal_stamps, gal_flux)
    rows, cont_snr = contaminate_stars(canvas, stars, kinds, cont_rng, noise_rms,
                                       float(contaminants.min_snr), contaminants.ranges)
    rows += _field_objects(canvas, np.vstack([star_pos, gal_pos]), contaminants, box, s,
                           subpixel, cont_rng, noise_rms, truth, flux_for)
    image, weight = _noise_and_defects(canvas, detector, noise_rms, noise_rng, defect_rng)
    del canvas
    _star_columns(stars, kinds, cont_snr, image, weight, star_pos, s, detector.saturation)
    meta = {"seed": seed, "slope": float(slope), "smallest_scale": float(smallest_scale),
            "cell": cell, "field_scales": [float(v) for v in sampler.scales],
            "galaxy_layout": galaxy_layout, "subpixel": bool(subpixel),
            "gain": detector.gain, "saturation": detector.saturation, "version": _version()}
    return PSFField(image, noise_rms, pixel_scale, reference, stars, galaxies, meta,
                    weight=weight, contaminants=_contaminant_table(rows))


def _check_reference(reference, stamp_size, image_shape):
    """The reference (padded to ``stamp_size``) and the image's (ny, nx)."""
    if reference is None:
        reference = load_default_reference()
    if not isinstance(reference, ReferenceBasis):
        raise TypeError(f"reference must be a ReferenceBasis, got {type(reference).__name__}.")
    if stamp_size is not None and int(stamp_size) != reference.stamp_size:
        reference = reference.padded(stamp_size)
    s = reference.stamp_size
    try:
        ny, nx = (int(v) for v in image_shape)
    except (TypeError, ValueError):
        raise ValueError(f"image_shape must be (ny, nx), got {image_shape!r}.") from None
    if ny < s or nx < s:
        raise ValueError(
            f"The stamp side {s} is larger than the image {image_shape}: use a larger image."
        )
    return reference, (ny, nx)


def _fixed_star_positions(star_positions, subpixel, box, s, shape):
    """The given star positions, checked (on the image, at least half a stamp from its
    edges; a warning when stamps overlap), on pixel centres unless ``subpixel``."""
    lo, hi_x, hi_y = box
    sp = np.array(star_positions, dtype=np.float64, copy=True)
    if sp.ndim != 2 or sp.shape[1] != 2:
        raise ValueError(f"star_positions must have shape (n, 2), got {sp.shape}.")
    if not np.all(np.isfinite(sp)):
        raise ValueError("star_positions hold NaN or infinite values.")
    near = np.floor(sp + 0.5)
    if not subpixel:
        sp = near
    off = (near[:, 0] < lo) | (near[:, 0] > hi_x) | (near[:, 1] < lo) | (near[:, 1] > hi_y)
    if off.any():
        raise ValueError(
            f"{np.count_nonzero(off)} of the star_positions are off the image or closer than "
            f"half a stamp ({lo} pixels) to its edge (image shape {shape}, x = column): "
            "drop them or use a larger image."
        )
    if len(sp) > 1:
        close = cKDTree(sp).query_pairs(s - 0.5, p=np.inf, output_type="ndarray")
        if len(close):
            warnings.warn(
                f"{len(close)} pairs of the given star_positions are closer than a stamp "
                f"({s} pixels): their stamps overlap in the image.", UserWarning,
                stacklevel=3)
    return sp


def _check_snr(snr, n_stars):
    """The stars' S/N as an array of ``n_stars`` positive finite values."""
    snr_arr = np.array(snr, dtype=np.float64, copy=True)
    if snr_arr.ndim == 0:
        snr_arr = np.full(n_stars, float(snr_arr))
    if snr_arr.shape != (n_stars,):
        raise ValueError(f"snr must be a number or an array of {n_stars} values, got shape "
                         f"{snr_arr.shape}.")
    if not np.all(np.isfinite(snr_arr) & (snr_arr > 0)):
        raise ValueError("snr must be positive and finite (S/N = mean of the star's pixels / "
                         "background rms).")
    return snr_arr


def _smallest_scale(smallest_scale, grid_size, shape, pixel_scale):
    """The random fields' cell in arcsec, from the deprecated ``grid_size`` when given."""
    if grid_size is not None:
        warnings.warn("grid_size is deprecated: give the smallest scale of the PSF variations "
                      "in arcsec, smallest_scale (the random fields' grid cell).",
                      DeprecationWarning, stacklevel=3)
        cell = (max(shape) - 1) / (_check_int("grid_size", grid_size, 4) - 1)
        smallest_scale = cell * pixel_scale
    if not (np.isfinite(smallest_scale) and smallest_scale > 0):
        raise ValueError(f"smallest_scale must be a positive number of arcsec, got "
                         f"{smallest_scale}.")
    return smallest_scale


def _positions(n_stars, n_galaxies, fixed_stars, galaxy_positions, galaxy_layout, subpixel,
               box, gap, rngs):
    """Star and galaxy-PSF positions: fixed ones first, then random ones avoiding everything
    placed before, ``gap`` pixels apart; then the sub-pixel offsets of the random ones."""
    star_rng, gal_rng, sub_rng = rngs
    grid = None
    if galaxy_positions is not None:
        grid = np.array(galaxy_positions, dtype=np.float64, copy=True).reshape(-1, 2)
        n_galaxies = len(grid)
    elif galaxy_layout == "grid" and n_galaxies:
        grid = _grid_positions(n_galaxies, *box, gap)
        if fixed_stars is not None:
            d, _ = cKDTree(fixed_stars).query(grid, p=np.inf)
            clash = d < gap
            if clash.any():
                warnings.warn(f"{np.count_nonzero(clash)} grid galaxy-PSFs overlapping the given "
                              "star positions were removed.", UserWarning, stacklevel=3)
                grid = grid[~clash]
    fixed = np.zeros((0, 2)) if grid is None else grid
    if fixed_stars is None:
        star_pos = _draw_positions(n_stars, fixed, *box, gap, star_rng, "stars")
    else:
        star_pos = fixed_stars
    if grid is None:
        gal_pos = _draw_positions(n_galaxies, star_pos, *box, gap, gal_rng, "galaxy-PSFs")
    else:
        gal_pos = grid
    if subpixel:  # uniform within the pixel (the nearest pixel stays the drawn one)
        if fixed_stars is None:
            star_pos = star_pos + sub_rng.uniform(-0.5, 0.5, star_pos.shape)
        if galaxy_positions is None:
            gal_pos = gal_pos + sub_rng.uniform(-0.5, 0.5, gal_pos.shape)
    return star_pos, gal_pos


def _field_objects(canvas, taken, contaminants, box, s, subpixel, rng, noise_rms, truth,
                   flux_for):
    """Draw the field galaxies and cosmic rays away from the ``taken`` positions; their
    truth rows."""
    n_gal, n_cr = contaminants.n_field_galaxies, contaminants.n_field_cosmic_rays
    if not (n_gal or n_cr):
        return []
    ny, nx = canvas.shape
    fg = _draw_positions(n_gal, taken, *box, s + 12, rng, "field galaxies")
    if subpixel and len(fg):
        fg = fg + rng.uniform(-0.5, 0.5, fg.shape)
    fg_psf = truth(fg)[0]
    fg_flux = flux_for(fg_psf, realistic_snr(len(fg), rng)) if len(fg) else []
    rows = field_galaxies(canvas, fg, fg_psf, fg_flux, rng)
    cr = _draw_positions(n_cr, np.vstack([taken, fg]), 3, nx - 4, ny - 4, s, rng,
                         "field cosmic rays")
    return rows + field_cosmic_rays(canvas, cr, rng, noise_rms)


def _noise_and_defects(canvas, detector, noise_rms, noise_rng, defect_rng):
    """The image (the canvas, plus its noise when it is the noiseless sources) and its
    weight map (None when every pixel is plain background noise)."""
    gain = detector.gain
    if gain is None:
        image, source = canvas, None
    else:
        source = canvas
        ny, nx = canvas.shape
        image = noise_rng.standard_normal((ny, nx), dtype=np.float32)
        image *= np.float32(noise_rms)
        image += source
        lit = np.flatnonzero(source > 0)
        lam = source.ravel()[lit].astype(np.float64) * gain
        image.ravel()[lit] += ((noise_rng.poisson(lam) - lam) / gain).astype(np.float32)
    weight = None
    if detector.needs_weight:
        weight = apply_defects(image, defect_rng, noise_rms, source=source, gain=gain,
                               masked_fraction=float(detector.masked_fraction),
                               bad_columns=detector.bad_columns,
                               saturation=detector.saturation, mask_value=detector.mask_value)
    return image, weight


def _star_columns(stars, kinds, cont_snr, image, weight, star_pos, s, saturation):
    """Add the stars' contaminant and detector truth columns (in place)."""
    n_stars = len(stars)
    stars["contaminant"] = np.array(kinds, dtype=str) if n_stars else np.zeros(0, dtype="U1")
    stars["contaminant_snr"] = np.zeros(n_stars)
    for i, v in cont_snr:
        stars["contaminant_snr"][i] = v
    n_masked, saturated = np.zeros(n_stars, dtype=np.int64), np.zeros(n_stars, dtype=bool)
    if weight is not None:
        w, _ = cut_stamps(weight, star_pos, s)
        n_masked = np.sum(w == 0, axis=(1, 2))
        if saturation is not None:
            cut, _ = cut_stamps(image, star_pos, s)
            saturated = np.any(cut == np.float32(saturation), axis=(1, 2))
    stars["n_masked"], stars["saturated"] = n_masked, saturated


def _sources(settings, snr, n_galaxies, pixel_scale, rng):
    """:func:`chromatic_stamps` keywords of the stars and the galaxies (None when the PSF
    is that of the position alone) and their truth columns."""
    if not settings.active:
        return None, None, ({}, {})
    chromatic, brighter_fatter = settings.chromatic, settings.brighter_fatter
    colour_rng, flux_rng = rng.spawn(2)
    sources, columns = [], []
    lo, hi = float(snr.min()), float(snr.max())
    gal_snr = np.exp(flux_rng.uniform(np.log(lo / 5.0), np.log(lo), n_galaxies))
    for kind, own_snr in (("stars", snr), ("galaxies", gal_snr)):
        kw, cols = {"pixel_scale": pixel_scale}, {}
        if chromatic:
            n = len(own_snr)
            cols["g_i"] = kw["colour"] = draw_colours(n, kind, colour_rng)
            kw.update(airmass=settings.airmass, optics_fraction=float(settings.optics_fraction))
        if brighter_fatter:
            span = hi - lo if hi > lo else 1.0
            kw["size_factor"] = 1.0 + brighter_fatter * (own_snr - lo) / span
            cols["source_snr"] = np.array(own_snr, dtype=np.float64)
        sources.append(kw)
        columns.append(cols)
    return sources[0], sources[1], columns


def _contaminant_table(rows):
    names = ("kind", "star", "x", "y", "flux", "size", "snr")
    if not rows:
        return Table({"kind": np.zeros(0, dtype="U16"), "star": np.zeros(0, dtype=np.int64),
                      **{n: np.zeros(0) for n in names[2:]}})
    return Table({n: [r[n] for r in rows] for n in names})
