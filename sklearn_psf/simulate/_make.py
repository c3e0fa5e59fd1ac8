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
    CONTAMINANT_KINDS,
    CONTAMINANT_RANGES,
    apply_defects,
    contaminate_stars,
    field_cosmic_rays,
    field_galaxies,
    render,
)
from ._chromatic import chromatic_stamps, draw_colours
from ._field import PSFField, core_mask, realistic_snr
from ._random_field import RandomFieldSampler, as_generator

__all__ = ["make_psf_field"]

#: Default smallest scale of the PSF variations (arcsec): the random fields' grid cell.
DEFAULT_SMALLEST_SCALE = 8.0
#: Extra distance (pixels) between objects when stars carry contaminants: a neighbour (up to
#: 8 pixels away) or a contaminating galaxy (stamps 16 pixels wider) reaches 8 pixels further.
_CONTAMINANT_REACH = 8


def _check_int(name, value, minimum):
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise TypeError(f"{name} must be an integer, got {value!r}.")
    if value < minimum:
        raise ValueError(f"{name} must be >= {minimum}, got {value}.")
    return int(value)


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


def _check_contaminants(contaminants):
    if contaminants is None:
        return {}
    if not isinstance(contaminants, dict):
        raise TypeError("contaminants must be a dict {kind: fraction of the stars}, e.g. "
                        f"{{'cosmic_ray': 0.05}}; got {type(contaminants).__name__}.")
    out = {}
    for kind, frac in contaminants.items():
        if kind not in CONTAMINANT_KINDS:
            raise ValueError(f"Unknown contaminant {kind!r}: choose among {CONTAMINANT_KINDS}.")
        frac = float(frac)
        if not 0 <= frac <= 1:
            raise ValueError(f"The fraction of stars with a {kind!r} must be in [0, 1], "
                             f"got {frac}.")
        out[kind] = frac
    if sum(out.values()) > 1:
        raise ValueError(f"The contaminant fractions add up to {sum(out.values()):.3g} > 1.")
    return out


def _check_ranges(ranges):
    if ranges is None:
        return None
    if not isinstance(ranges, dict):
        raise TypeError("contaminant_ranges must be a dict {kind: {'flux_ratio': (lo, hi), "
                        f"'separation': (lo, hi)}}, got {type(ranges).__name__}.")
    out = {}
    for kind, values in ranges.items():
        if kind not in CONTAMINANT_RANGES:
            raise ValueError(f"contaminant_ranges has no ranges for {kind!r}: give them for "
                             f"{sorted(CONTAMINANT_RANGES)}.")
        for name, (lo, hi) in values.items():
            if name not in CONTAMINANT_RANGES[kind]:
                raise ValueError(f"Unknown range {name!r} for {kind!r}: choose among "
                                 f"{sorted(CONTAMINANT_RANGES[kind])}.")
            if not 0 < float(lo) <= float(hi):
                raise ValueError(f"The {kind} {name} range must be 0 < lo <= hi, got "
                                 f"({lo}, {hi}).")
        out[kind] = {name: (float(lo), float(hi)) for name, (lo, hi) in values.items()}
    return out


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
    noise_rms: float | None = None,
    smallest_scale: float = DEFAULT_SMALLEST_SCALE,
    subpixel: bool = True,
    contaminants: dict | None = None,
    contaminant_min_snr: float = 0.0,
    contaminant_ranges: dict | None = None,
    n_field_cosmic_rays: int = 0,
    n_field_galaxies: int = 0,
    masked_fraction: float = 0.0,
    bad_columns: int = 0,
    saturation: float | None = None,
    gain: float | None = None,
    mask_value: float = 0.0,
    grid_size: int | None = None,
    galaxy_positions=None,
    weight_fields=None,
    chromatic: bool = False,
    airmass: float | None = None,
    optics_fraction: float = 0.1,
    brighter_fatter: float = 0.0,
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
    noise_rms : float, optional
        Background rms; default the reference image's, else 1.
    subpixel : bool, default=True
        PSFs at their exact sub-pixel positions; False: on pixel centres (the paper's).
    contaminants : dict, optional
        ``{kind: fraction of the stars}``, kinds "cosmic_ray", "neighbour", "galaxy",
        "binary"; default none. Truth: ``stars["contaminant"]``.
    contaminant_min_snr : float, default=0
        Least signal of each contaminant (0: their natural strength).
    contaminant_ranges : dict, optional
        Other flux-ratio and separation ranges of binaries and neighbours.
    n_field_cosmic_rays, n_field_galaxies : int, default=0
        Cosmic rays and extended galaxies elsewhere in the image, away from the stars.
    masked_fraction, bad_columns : float, int, default=0
        Fraction of the pixels masked at random; number of full bad columns.
    saturation, gain : float, optional
        Saturation level (pixels clipped, weight 0); electrons per unit (Poisson noise).
    mask_value : float, default=0.0
        Value written under masked pixels (``numpy.nan`` makes them NaN).
    grid_size : int, optional
        Deprecated (use ``smallest_scale``): random-field nodes along the longer side.
    weight_fields : callable, optional
        ``weight_fields(positions)`` -> (n, n_components) fields replacing the random ones.
    chromatic : bool, default=False
        Each source's PSF depends on its blackbody colour (column ``g_i``).
    airmass, optics_fraction : float, default=None and 0.1
        With ``chromatic``: refraction at ``airmass`` (>= 1, None: none), and the optics'
        share of the PSF's second moment, in [0, 1].
    brighter_fatter : float, default=0
        Each PSF dilated by ``1 + brighter_fatter * (snr - min) / (max - min)``.

    Returns
    -------
    PSFField

    Raises
    ------
    ValueError
        For n_stars < 1, snr <= 0 or of the wrong length, stars off the image, stamps larger
        than the image, objects too many to fit without overlap, unknown contaminants.

    Examples
    --------
    >>> from sklearn_psf.simulate import make_psf_field
    >>> field = make_psf_field(n_stars=50, n_galaxies=40, image_shape=(1000, 1200), random_state=42)
    >>> field.image.shape, len(field.stars), field.stars["stamp"].shape[0], len(field.galaxies)
    ((1000, 1200), 50, 50, 40)
    >>> dirty = make_psf_field(n_stars=40, n_galaxies=0, image_shape=(800, 800),
    ...                        contaminants={"cosmic_ray": 0.1, "binary": 0.1},
    ...                        bad_columns=1, random_state=0)
    >>> sorted(set(map(str, dirty.stars["contaminant"]))), int((dirty.weight == 0).all(0).sum())
    (['', 'binary', 'cosmic_ray'], 1)
    """
    if reference is None:
        reference = load_default_reference()
    if not isinstance(reference, ReferenceBasis):
        raise TypeError(f"reference must be a ReferenceBasis, got {type(reference).__name__}.")
    if stamp_size is not None and int(stamp_size) != reference.stamp_size:
        reference = reference.padded(stamp_size)
    s = reference.stamp_size
    h = s // 2
    try:
        ny, nx = (int(v) for v in image_shape)
    except (TypeError, ValueError):
        raise ValueError(f"image_shape must be (ny, nx), got {image_shape!r}.") from None
    if ny < s or nx < s:
        raise ValueError(
            f"The stamp side {s} is larger than the image {image_shape}: use a larger image."
        )
    if galaxy_layout not in ("random", "grid"):
        raise ValueError(f"galaxy_layout must be 'random' or 'grid', got {galaxy_layout!r}.")
    n_galaxies = _check_int("n_galaxies", n_galaxies, 0)
    n_field_cosmic_rays = _check_int("n_field_cosmic_rays", n_field_cosmic_rays, 0)
    n_field_galaxies = _check_int("n_field_galaxies", n_field_galaxies, 0)
    bad_columns = _check_int("bad_columns", bad_columns, 0)
    if bad_columns > nx:
        raise ValueError(f"bad_columns ({bad_columns}) exceeds the image width {nx}.")
    if not 0 <= float(masked_fraction) < 1:
        raise ValueError(f"masked_fraction must be in [0, 1), got {masked_fraction}.")
    for name, value in (("saturation", saturation), ("gain", gain)):
        if value is not None and not (np.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a positive number or None, got {value}.")
    fractions = _check_contaminants(contaminants)
    lo, hi_x, hi_y = h, nx - 1 - h, ny - 1 - h

    fixed_stars = None
    if star_positions is not None:
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
                f"half a stamp ({h} pixels) to its edge (image shape {(ny, nx)}, x = column): "
                "drop them or use a larger image."
            )
        if len(sp) > 1:
            close = cKDTree(sp).query_pairs(s - 0.5, p=np.inf, output_type="ndarray")
            if len(close):
                warnings.warn(
                    f"{len(close)} pairs of the given star_positions are closer than a stamp "
                    f"({s} pixels): their stamps overlap in the image.", UserWarning,
                    stacklevel=2)
        fixed_stars = sp
        n_stars = len(sp)
    n_stars = _check_int("n_stars", n_stars, 1)

    snr_arr = np.array(snr, dtype=np.float64, copy=True)
    if snr_arr.ndim == 0:
        snr_arr = np.full(n_stars, float(snr_arr))
    if snr_arr.shape != (n_stars,):
        raise ValueError(f"snr must be a number or an array of {n_stars} values, got shape "
                         f"{snr_arr.shape}.")
    if not np.all(np.isfinite(snr_arr) & (snr_arr > 0)):
        raise ValueError("snr must be positive and finite (S/N = mean of the star's pixels / "
                         "background rms).")
    if galaxy_snr is not None and not (np.isfinite(galaxy_snr) and galaxy_snr > 0):
        raise ValueError(f"galaxy_snr must be positive or None, got {galaxy_snr}.")
    if noise_rms is None:
        noise_rms = reference.noise_rms if reference.noise_rms else 1.0
    noise_rms = float(noise_rms)
    if not (np.isfinite(noise_rms) and noise_rms > 0):
        raise ValueError(f"noise_rms must be positive, got {noise_rms}.")
    pixel_scale = reference.pixel_scale if pixel_scale is None else float(pixel_scale)
    if grid_size is not None:
        warnings.warn("grid_size is deprecated: give the smallest scale of the PSF variations "
                      "in arcsec, smallest_scale (the random fields' grid cell).",
                      DeprecationWarning, stacklevel=2)
        cell = (max(ny, nx) - 1) / (_check_int("grid_size", grid_size, 4) - 1)
        smallest_scale = cell * pixel_scale
    if not (np.isfinite(smallest_scale) and smallest_scale > 0):
        raise ValueError(f"smallest_scale must be a positive number of arcsec, got "
                         f"{smallest_scale}.")
    cell = float(smallest_scale) / pixel_scale

    seed = int(random_state) if isinstance(random_state, numbers.Integral) else None
    rng = as_generator(random_state)
    (field_rng, star_rng, gal_rng, noise_rng, sub_rng, cont_rng, defect_rng,
     source_rng) = rng.spawn(8)

    # positions: fixed ones first, then random ones avoiding everything placed before; with
    # contaminants on stars, 8 more pixels between objects (a neighbour's or a galaxy's light
    # stays out of the other stars' stamps: the clean stars stay clean)
    gap = s + _CONTAMINANT_REACH if any(fractions.values()) else s
    grid = None
    if galaxy_positions is not None:
        grid = np.array(galaxy_positions, dtype=np.float64, copy=True).reshape(-1, 2)
        n_galaxies = len(grid)
    elif galaxy_layout == "grid" and n_galaxies:
        grid = _grid_positions(n_galaxies, lo, hi_x, hi_y, gap)
        if fixed_stars is not None:
            d, _ = cKDTree(fixed_stars).query(grid, p=np.inf)
            clash = d < gap
            if clash.any():
                warnings.warn(f"{np.count_nonzero(clash)} grid galaxy-PSFs overlapping the given "
                              "star positions were removed.", UserWarning, stacklevel=2)
                grid = grid[~clash]
    fixed = np.zeros((0, 2)) if grid is None else grid
    if fixed_stars is None:
        star_pos = _draw_positions(n_stars, fixed, lo, hi_x, hi_y, gap, star_rng, "stars")
    else:
        star_pos = fixed_stars
    if grid is None:
        gal_pos = _draw_positions(n_galaxies, star_pos, lo, hi_x, hi_y, gap, gal_rng,
                                  "galaxy-PSFs")
    else:
        gal_pos = grid
    if subpixel:  # uniform within the pixel (the nearest pixel stays the drawn one)
        if fixed_stars is None:
            star_pos = star_pos + sub_rng.uniform(-0.5, 0.5, star_pos.shape)
        if galaxy_positions is None:
            gal_pos = gal_pos + sub_rng.uniform(-0.5, 0.5, gal_pos.shape)

    sampler = weight_fields if weight_fields is not None else RandomFieldSampler(
        (ny, nx), reference.n_components, slope, cell=cell, random_state=field_rng)
    normalizer = StampNormalizer(flux=True, center=True).fit(reference.mean.reshape(1, -1))
    basis = reference.as_transformer(normalize=False)
    star_source, gal_source, columns = _sources(
        chromatic, airmass, optics_fraction, brighter_fatter, snr_arr, len(gal_pos),
        pixel_scale, source_rng)
    star_stamps, star_coeffs, star_mom = _truth(reference, star_pos, sampler, normalizer, basis,
                                                star_source)
    gal_stamps, gal_coeffs, gal_mom = _truth(reference, gal_pos, sampler, normalizer, basis,
                                             gal_source)

    def flux_for(stamps, target):
        core = core_mask(stamps)
        return target * noise_rms / ((stamps * core).sum(axis=1) / core.sum(axis=1))

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
    kinds = _star_kinds(n_stars, fractions, cont_rng)

    # the image: sources (noiseless canvas when the Poisson noise needs them), then noise
    if gain is None:
        canvas = noise_rng.standard_normal((ny, nx), dtype=np.float32)
        canvas *= np.float32(noise_rms)
    else:
        canvas = np.zeros((ny, nx), dtype=np.float32)
    clean = kinds == ""
    render(canvas, star_pos[clean], star_stamps[clean], star_flux[clean])
    if galaxy_snr is not None:
        render(canvas, gal_pos, gal_stamps, gal_flux)
    rows, cont_snr = contaminate_stars(canvas, stars, kinds, cont_rng, noise_rms,
                                       float(contaminant_min_snr),
                                       _check_ranges(contaminant_ranges))
    if n_field_galaxies or n_field_cosmic_rays:
        taken = np.vstack([star_pos, gal_pos])
        fg = _draw_positions(n_field_galaxies, taken, lo, hi_x, hi_y, s + 12, cont_rng,
                             "field galaxies")
        if subpixel and len(fg):
            fg = fg + cont_rng.uniform(-0.5, 0.5, fg.shape)
        fg_psf = _truth(reference, fg, sampler, normalizer, basis)[0]
        fg_flux = flux_for(fg_psf, realistic_snr(len(fg), cont_rng)) if len(fg) else []
        rows += field_galaxies(canvas, fg, fg_psf, fg_flux, cont_rng)
        cr = _draw_positions(n_field_cosmic_rays, np.vstack([taken, fg]), 3, nx - 4, ny - 4,
                             s, cont_rng, "field cosmic rays")
        rows += field_cosmic_rays(canvas, cr, cont_rng, noise_rms)
    if gain is None:
        image, source = canvas, None
    else:
        source = canvas
        image = noise_rng.standard_normal((ny, nx), dtype=np.float32)
        image *= np.float32(noise_rms)
        image += source
        lit = np.flatnonzero(source > 0)
        lam = source.ravel()[lit].astype(np.float64) * gain
        image.ravel()[lit] += ((noise_rng.poisson(lam) - lam) / gain).astype(np.float32)
    weight = None
    if gain is not None or masked_fraction > 0 or bad_columns or saturation is not None:
        weight = apply_defects(image, defect_rng, noise_rms, source=source, gain=gain,
                               masked_fraction=float(masked_fraction), bad_columns=bad_columns,
                               saturation=saturation, mask_value=mask_value)
    del source, canvas

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
    contam = _contaminant_table(rows)
    meta = {"seed": seed, "slope": float(slope), "smallest_scale": float(smallest_scale),
            "cell": cell, "field_scales": [float(v) for v in sampler.scales],
            "galaxy_layout": galaxy_layout, "subpixel": bool(subpixel),
            "gain": gain, "saturation": saturation, "version": _version()}
    return PSFField(image, noise_rms, pixel_scale, reference, stars, galaxies, meta,
                    weight=weight, contaminants=contam)


def _sources(chromatic, airmass, optics_fraction, brighter_fatter, snr, n_galaxies,
              pixel_scale, rng):
    """:func:`chromatic_stamps` keywords of the stars and the galaxies (None when the PSF
    is that of the position alone) and their truth columns."""
    if airmass is not None and not (chromatic and np.isfinite(airmass) and airmass >= 1):
        raise ValueError(f"airmass must be a number >= 1 and needs chromatic=True, got "
                         f"{airmass!r} (chromatic={chromatic}).")
    if not 0 <= float(optics_fraction) <= 1:
        raise ValueError(f"optics_fraction must be in [0, 1], got {optics_fraction}.")
    if not (np.isfinite(brighter_fatter) and brighter_fatter >= 0):
        raise ValueError(f"brighter_fatter must be a number >= 0, got {brighter_fatter}.")
    if not chromatic and not brighter_fatter:
        return None, None, ({}, {})
    colour_rng, flux_rng = rng.spawn(2)
    sources, columns = [], []
    lo, hi = float(snr.min()), float(snr.max())
    gal_snr = np.exp(flux_rng.uniform(np.log(lo / 5.0), np.log(lo), n_galaxies))
    for kind, own_snr in (("stars", snr), ("galaxies", gal_snr)):
        kw, cols = {"pixel_scale": pixel_scale}, {}
        if chromatic:
            n = len(own_snr)
            cols["g_i"] = kw["colour"] = draw_colours(n, kind, colour_rng)
            kw.update(airmass=airmass, optics_fraction=float(optics_fraction))
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
