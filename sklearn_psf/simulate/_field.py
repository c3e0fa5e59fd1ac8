"""Mock PSF field images (Berge et al. 2012, section 3).

The conventions (PSF model, positions, S/N, seeds) are documented in
:mod:`sklearn_psf.simulate`.
"""

from __future__ import annotations

import numbers
import os
import warnings

import numpy as np
from astropy.io import fits
from astropy.table import Table
from scipy.spatial import cKDTree

from ..measure import adaptive_moments
from ..preprocessing import StampNormalizer, cut_stamps
from ._random_field import RandomFieldSampler, as_generator
from ._reference import ReferenceBasis, _version

__all__ = ["PSFField", "make_psf_field", "realistic_snr", "core_mask"]

_FIELD_FORMAT = "SKPSF-FIELD"


def realistic_snr(n: int, random_state=None, *, low: float = 20.0, high: float = 1000.0,
                  mode: float = 100.0, sigma: float = 0.6) -> np.ndarray:
    """Draw star S/N from the paper's "realistic" distribution (20 to 1000, peaking near 100).

    A log-normal distribution whose density in S/N peaks at ``mode`` (ln S/N normal with
    standard deviation ``sigma`` and mean ``ln(mode) + sigma^2``: median 143, mean 163 for the
    defaults), truncated to [low, high] by re-drawing.

    Parameters
    ----------
    n : int
        Number of stars.
    random_state : None, int, SeedSequence or Generator
    low, high : float, default=20, 1000
    mode : float, default=100
    sigma : float, default=0.6

    Returns
    -------
    snr : ndarray of shape (n,)

    Examples
    --------
    >>> from sklearn_psf.simulate import realistic_snr
    >>> s = realistic_snr(1000, random_state=0)
    >>> bool(s.min() >= 20 and s.max() <= 1000)
    True
    """
    n = int(n)
    if n < 0:
        raise ValueError(f"n must be >= 0, got {n}.")
    if not (0 < low < mode < high) or not sigma > 0:
        raise ValueError("Need 0 < low < mode < high and sigma > 0.")
    rng = as_generator(random_state)
    mu = np.log(mode) + sigma**2
    out = np.empty(n)
    filled = 0
    while filled < n:
        draw = np.exp(rng.normal(mu, sigma, size=2 * (n - filled) + 10))
        draw = draw[(draw >= low) & (draw <= high)][: n - filled]
        out[filled:filled + draw.size] = draw
        filled += draw.size
    return out


def core_mask(stamps, fraction: float = 0.5) -> np.ndarray:
    """Pixels of each noiseless stamp at or above ``fraction`` of its peak (the S/N pixels).

    Parameters
    ----------
    stamps : ndarray of shape (n, p)
    fraction : float, default=0.5

    Returns
    -------
    mask : boolean ndarray of shape (n, p)
    """
    s = np.asarray(stamps, dtype=np.float64)
    return s >= fraction * s.max(axis=1, keepdims=True)


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


class PSFField:
    """A simulated PSF field: image, truth tables and the basis it was built from.

    Made by :func:`make_psf_field`; saved and read with :meth:`save` / :meth:`load`.

    Attributes
    ----------
    image : ndarray of shape (ny, nx), float32
        Stars (and galaxy-PSFs) plus Gaussian background noise; zero background level.
    noise_rms : float
        Background rms of the image.
    pixel_scale : float
        Arcsec per pixel.
    reference : ReferenceBasis
        The basis of the simulated PSFs (force it on the model, as in the paper).
    stars, galaxies : astropy.table.Table
        Truth: ``x``, ``y`` (integer pixel centres), ``stamp`` (normalised noiseless stamp,
        shape (s*s,) per row), ``coeffs`` (its coefficients in the basis), ``e1``, ``e2``,
        ``sigma`` (adaptive moments of the true stamp), ``moments_flag``, ``snr`` and
        ``flux`` as rendered (0 for galaxy-PSFs not rendered).
    meta : dict
        ``seed`` (int or None), ``slope``, ``grid_size``, ``galaxy_layout``, ``version``.
    """

    def __init__(self, image, noise_rms, pixel_scale, reference, stars, galaxies, meta=None):
        self.image = image
        self.noise_rms = float(noise_rms)
        self.pixel_scale = float(pixel_scale)
        self.reference = reference
        self.stars = stars
        self.galaxies = galaxies
        self.meta = dict(meta or {})

    @property
    def stamp_size(self) -> int:
        """Side of the stamps."""
        return self.reference.stamp_size

    def __repr__(self) -> str:
        ny, nx = self.image.shape
        return (f"PSFField(image={nx}x{ny}, n_stars={len(self.stars)}, "
                f"n_galaxies={len(self.galaxies)}, stamp_size={self.stamp_size}, "
                f"noise_rms={self.noise_rms:.4g})")

    def star_stamps(self, normalize: bool = True):
        """Stamps of the stars cut from the image (as for real data), not from the truth.

        Parameters
        ----------
        normalize : bool, default=True
            Normalise with ``StampNormalizer`` (unit flux, centred). Stamps flagged by
            ``cut_stamps`` are left as cut (they are not normalised).

        Returns
        -------
        stamps : ndarray of shape (n_stars, s*s)
        flags : ndarray of shape (n_stars,)
            ``cut_stamps`` flags (0 = clean).
        """
        s = self.stamp_size
        pos = np.column_stack([self.stars["x"], self.stars["y"]])
        stamps, flags = cut_stamps(self.image, pos, s)
        flat = stamps.reshape(len(pos), s * s)
        good = flags == 0
        if normalize and good.any():
            flat[good] = StampNormalizer(flux=True, center=True).fit_transform(flat[good])
        return flat, flags

    def measure_stars(self) -> Table:
        """Measure the stars on the image with the real-data pipeline.

        Stamps are cut at the star positions, normalised, projected on the reference basis
        (``reference.as_transformer``) and measured with adaptive moments. The S/N is measured
        the paper's way from the data alone: mean of the raw stamp's pixels at or above half
        its peak, over the background rms estimated from the image (1.4826 x median absolute
        deviation).

        Returns
        -------
        astropy.table.Table
            ``x``, ``y``, ``stamp`` (measured, normalised), ``coeffs``, ``e1``, ``e2``,
            ``sigma``, ``snr``, ``cut_flag``, ``moments_flag`` (NaN values for stars whose
            stamp is flagged).

        Examples
        --------
        >>> from sklearn_psf.simulate import make_psf_field
        >>> field = make_psf_field(n_stars=20, n_galaxies=10, image_shape=(600, 800),
        ...                        random_state=0)
        >>> m = field.measure_stars()
        >>> len(m), bool(abs(m["snr"].mean() / 100 - 1) < 0.1)
        (20, True)
        """
        s = self.stamp_size
        pos = np.column_stack([self.stars["x"], self.stars["y"]]).astype(np.float64)
        raw, flags = cut_stamps(self.image, pos, s)
        raw = raw.reshape(len(pos), s * s)
        n, k = len(pos), self.reference.n_components
        stamps = np.full((n, s * s), np.nan)
        coeffs = np.full((n, k), np.nan)
        e1, e2, sig = np.full(n, np.nan), np.full(n, np.nan), np.full(n, np.nan)
        mflag = np.full(n, -1, dtype=np.int64)
        snr = np.full(n, np.nan)
        rms = _robust_rms(self.image)
        good = np.flatnonzero(flags == 0)
        if good.size:
            basis = self.reference.as_transformer(normalize=False)
            norm = StampNormalizer(flux=True, center=True).fit_transform(raw[good])
            stamps[good] = norm
            coeffs[good] = basis.transform(norm)
            mom = adaptive_moments(norm)
            e1[good], e2[good], sig[good] = mom["e1"], mom["e2"], mom["sigma"]
            mflag[good] = mom["flag"]
            core = core_mask(raw[good])
            snr[good] = (raw[good] * core).sum(axis=1) / core.sum(axis=1) / rms
        return Table({"x": pos[:, 0], "y": pos[:, 1], "stamp": stamps, "coeffs": coeffs,
                      "e1": e1, "e2": e2, "sigma": sig, "snr": snr, "cut_flag": flags,
                      "moments_flag": mflag})

    # ------------------------------------------------------------------ I/O
    def save(self, path, overwrite: bool = False) -> None:
        """Write the field to FITS: image (primary), STARS, GALAXIES tables, REF_* basis.

        Header keywords of the primary HDU: PIXSCALE, NOISERMS, SEED (-1 if the field was not
        made from an int seed), SLOPE, GRIDSIZE, LAYOUT, STAMPSZ, SKPSFVER.

        Parameters
        ----------
        path : str or os.PathLike
        overwrite : bool, default=False
        """
        primary = fits.PrimaryHDU(np.asarray(self.image, dtype=np.float32))
        h = primary.header
        h["SKPSFFMT"] = (_FIELD_FORMAT, "sklearn_psf simulated PSF field")
        h["SKPSFVER"] = (self.meta.get("version", _version()), "sklearn_psf version")
        h["PIXSCALE"] = (self.pixel_scale, "arcsec per pixel")
        h["NOISERMS"] = (self.noise_rms, "background noise rms")
        seed = self.meta.get("seed")
        h["SEED"] = (-1 if seed is None else int(seed), "random_state (int) of the simulation")
        h["SLOPE"] = (float(self.meta.get("slope", np.nan)), "power spectrum slope")
        h["GRIDSIZE"] = (int(self.meta.get("grid_size", -1)), "random field grid cells")
        h["LAYOUT"] = (str(self.meta.get("galaxy_layout", "")), "galaxy-PSF layout")
        h["STAMPSZ"] = (self.stamp_size, "stamp side in pixels")
        stars = fits.table_to_hdu(self.stars)
        stars.name = "STARS"
        gals = fits.table_to_hdu(self.galaxies)
        gals.name = "GALAXIES"
        fits.HDUList([primary, stars, gals, *self.reference.to_hdus("REF_")]).writeto(
            os.fspath(path), overwrite=overwrite)

    @classmethod
    def load(cls, path) -> "PSFField":
        """Read a field written by :meth:`save`.

        Raises
        ------
        ValueError
            When the file is missing, not FITS, or not a saved PSF field.
        """
        path = os.fspath(path)
        if not os.path.exists(path):
            raise ValueError(f"File {path!r} does not exist.")
        try:
            with fits.open(path, memmap=False) as hdul:
                hdul.verify("exception")
                h = hdul[0].header
                if h.get("SKPSFFMT") != _FIELD_FORMAT:
                    raise ValueError(
                        f"{path!r} is not a simulated PSF field written by PSFField.save."
                    )
                image = np.array(hdul[0].data, dtype=np.float32)
                stars = Table.read(hdul["STARS"])
                gals = Table.read(hdul["GALAXIES"])
                ref = ReferenceBasis.from_hdulist(hdul, prefix="REF_")
                seed = int(h["SEED"])
                meta = {"seed": None if seed < 0 else seed, "slope": h["SLOPE"],
                        "grid_size": h["GRIDSIZE"], "galaxy_layout": h["LAYOUT"],
                        "version": h["SKPSFVER"]}
                return cls(image, h["NOISERMS"], h["PIXSCALE"], ref, stars, gals, meta)
        except ValueError:
            raise
        except (OSError, TypeError, KeyError, IndexError, fits.VerifyError) as exc:
            raise ValueError(
                f"Could not read {path!r} as a saved PSF field ({type(exc).__name__}: {exc})."
            ) from None


def _robust_rms(image) -> float:
    """1.4826 x MAD of a subsample of the image (stars are sparse: a robust noise estimate)."""
    flat = np.asarray(image).ravel()
    step = max(1, flat.size // 2_000_000)
    sample = flat[::step].astype(np.float64)
    return float(1.4826 * np.median(np.abs(sample - np.median(sample))))


def _truth(reference, positions, sampler, normalizer, basis):
    n = len(positions)
    s2 = reference.stamp_size ** 2
    if n == 0:
        k = reference.n_components
        return np.zeros((0, s2)), np.zeros((0, k)), Table(
            {"e1": np.zeros(0), "e2": np.zeros(0), "sigma": np.zeros(0),
             "flag": np.zeros(0, dtype=np.int64)})
    weights = reference.coeff_mean + reference.coeff_std * sampler(positions)
    stamps = normalizer.transform(reference.synthesize(weights))
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


def _render(image, positions, stamps, flux):
    if len(positions) == 0:
        return
    s = int(round(np.sqrt(stamps.shape[1])))
    h = s // 2
    off = np.arange(-h, h + 1)
    rows = positions[:, 1].astype(np.intp)[:, None, None] + off[None, :, None]
    cols = positions[:, 0].astype(np.intp)[:, None, None] + off[None, None, :]
    values = (stamps * flux[:, None]).reshape(-1, s, s).astype(np.float32)
    np.add.at(image, (rows, cols), values)


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
    grid_size: int = 256,
) -> PSFField:
    """Simulate a PSF field image with stars and galaxy-PSFs (Berge et al. 2012, sect. 3).

    See the module documentation (:mod:`sklearn_psf.simulate`) for the conventions: PSF model,
    integer-pixel positions without overlap, S/N definition, seeds.

    Parameters
    ----------
    reference : ReferenceBasis, optional
        Basis of the PSFs; default :func:`sklearn_psf.datasets.load_default_reference`.
    n_stars : int, default=1000
        Number of stars at random positions (ignored when ``star_positions`` is given).
    n_galaxies : int, default=2000
        Number of galaxy-PSFs (about that number for the grid layout).
    galaxy_layout : {"random", "grid"}, default="random"
    snr : float or array-like of shape (n_stars,), default=100
        S/N of every star (> 0); see :func:`realistic_snr` for the paper's distribution.
    image_shape : tuple (ny, nx), default=(7769, 10032)
        The paper's Subaru image: 10,032 x 7,769 pixels.
    pixel_scale : float, optional
        Arcsec per pixel; default the reference's (0.2 for the default reference).
    stamp_size : int, optional
        Odd stamp side; default the reference's. Larger values zero-pad the basis.
    star_positions : array-like of shape (n, 2), optional
        (x, y) star positions, e.g. ``reference.positions``; rounded to the nearest pixel;
        every stamp must lie inside the image.
    slope : float, default=11/4
        Power-spectrum slope of the weights' random fields.
    random_state : None, int, SeedSequence or Generator
        Seed (see the module documentation).
    galaxy_snr : float or None, default=1000
        S/N of the galaxy-PSFs drawn in the image; None leaves them out of the image.
    noise_rms : float, optional
        Background rms; default the reference image's, else 1.
    grid_size : int, default=256
        Random-field grid cells along the longer side of the image.

    Returns
    -------
    PSFField

    Raises
    ------
    ValueError
        For n_stars < 1, snr <= 0 or of the wrong length, stars off the image, stamps larger
        than the image, or more objects than fit without overlap.

    Examples
    --------
    >>> from sklearn_psf.simulate import make_psf_field
    >>> field = make_psf_field(n_stars=50, n_galaxies=40, image_shape=(1000, 1200),
    ...                        random_state=42)
    >>> field.image.shape, field.image.dtype, len(field.stars), len(field.galaxies)
    ((1000, 1200), dtype('float32'), 50, 40)
    >>> field.stars["stamp"].shape == (50, field.stamp_size ** 2)
    True
    """
    if reference is None:
        from ..datasets import load_default_reference

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
    lo, hi_x, hi_y = h, nx - 1 - h, ny - 1 - h

    fixed_stars = None
    if star_positions is not None:
        sp = np.array(star_positions, dtype=np.float64, copy=True)
        if sp.ndim != 2 or sp.shape[1] != 2:
            raise ValueError(f"star_positions must have shape (n, 2), got {sp.shape}.")
        if not np.all(np.isfinite(sp)):
            raise ValueError("star_positions hold NaN or infinite values.")
        sp = np.floor(sp + 0.5)
        off = (sp[:, 0] < lo) | (sp[:, 0] > hi_x) | (sp[:, 1] < lo) | (sp[:, 1] > hi_y)
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

    seed = int(random_state) if isinstance(random_state, numbers.Integral) else None
    rng = as_generator(random_state)
    field_rng, star_rng, gal_rng, noise_rng = rng.spawn(4)

    # positions: fixed ones first, then random ones avoiding everything placed before
    grid = None
    if galaxy_layout == "grid" and n_galaxies:
        grid = _grid_positions(n_galaxies, lo, hi_x, hi_y, s)
        if fixed_stars is not None:
            d, _ = cKDTree(fixed_stars).query(grid, p=np.inf)
            clash = d < s
            if clash.any():
                warnings.warn(f"{np.count_nonzero(clash)} grid galaxy-PSFs overlapping the given "
                              "star positions were removed.", UserWarning, stacklevel=2)
                grid = grid[~clash]
    fixed = np.zeros((0, 2)) if grid is None else grid
    if fixed_stars is None:
        star_pos = _draw_positions(n_stars, fixed, lo, hi_x, hi_y, s, star_rng, "stars")
    else:
        star_pos = fixed_stars
    if grid is None:
        gal_pos = _draw_positions(n_galaxies, star_pos, lo, hi_x, hi_y, s, gal_rng,
                                  "galaxy-PSFs")
    else:
        gal_pos = grid

    sampler = RandomFieldSampler((ny, nx), reference.n_components, slope, grid_size, field_rng)
    normalizer = StampNormalizer(flux=True, center=True).fit(reference.mean.reshape(1, -1))
    basis = reference.as_transformer(normalize=False)
    star_stamps, star_coeffs, star_mom = _truth(reference, star_pos, sampler, normalizer, basis)
    gal_stamps, gal_coeffs, gal_mom = _truth(reference, gal_pos, sampler, normalizer, basis)

    def flux_for(stamps, target):
        core = core_mask(stamps)
        return target * noise_rms / ((stamps * core).sum(axis=1) / core.sum(axis=1))

    star_flux = flux_for(star_stamps, snr_arr)
    if galaxy_snr is None:
        gal_snr, gal_flux = np.zeros(len(gal_pos)), np.zeros(len(gal_pos))
    else:
        gal_snr = np.full(len(gal_pos), float(galaxy_snr))
        gal_flux = flux_for(gal_stamps, gal_snr) if len(gal_pos) else np.zeros(0)

    image = noise_rng.standard_normal((ny, nx), dtype=np.float32)
    image *= np.float32(noise_rms)
    _render(image, star_pos, star_stamps, star_flux)
    if galaxy_snr is not None:
        _render(image, gal_pos, gal_stamps, gal_flux)

    stars = _table(star_pos, star_stamps, star_coeffs, star_mom, snr_arr, star_flux)
    galaxies = _table(gal_pos, gal_stamps, gal_coeffs, gal_mom, gal_snr, gal_flux)
    meta = {"seed": seed, "slope": float(slope), "grid_size": int(grid_size),
            "galaxy_layout": galaxy_layout, "version": _version()}
    return PSFField(image, noise_rms, pixel_scale, reference, stars, galaxies, meta)
