"""A CCD exposure rendered with GalSim, for tests through the real pipeline (SExtractor, PSFEx).

Unlike :func:`make_psf_field` (PSFs built from a reference PCA basis), this renders physical
profiles: a Kolmogorov atmosphere lensed by a power-spectrum shear field, convolved with
field-dependent optics, on a sky-limited image with saturated stars, faint galaxies and dead
columns, so that a source detector and any PSF modeller meet what they meet on a real CCD,
with the truth known everywhere.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
from astropy.io import fits
from astropy.table import Table

from .._files import write_fits_atomic
from .._optional import require
from ._random_field import as_generator

__all__ = ["GalSimCCD", "render_galsim_ccd"]

_LAM_NM, _DIAM_M, _OBSCURATION = 700.0, 4.0, 0.3  # a 4-m telescope in the i band


def _galsim():
    return require("galsim", "render_galsim_ccd")


class _GroundPSF:
    """Kolmogorov seeing lensed by a shear field, convolved with field-dependent optics.

    The shear is a Gaussian random field with GalSim's ``PowerSpectrum`` (E mode,
    P(k) ~ k^-11/3, the Kolmogorov turbulence slope) on a 20-arcsec grid over the chip,
    rescaled to ``shear_rms`` per component and interpolated with bicubic splines; the optics
    are ``galsim.OpticalPSF`` (700 nm, 4 m, 30% obscuration) whose defocus, astigmatism and
    coma (in waves) are random low-order polynomials of the chip position.
    """

    def __init__(self, shape, pixel_scale, fwhm, shear_rms, rng):
        from scipy.interpolate import RectBivariateSpline

        galsim = _galsim()
        ny, nx = shape
        spacing = 20.0
        ngrid = int(math.ceil(max(nx, ny) * pixel_scale / spacing)) + 3
        ps = galsim.PowerSpectrum(e_power_function=lambda k: k ** (-11.0 / 3.0), units="arcsec")
        g1, g2 = ps.buildGrid(grid_spacing=spacing, ngrid=ngrid,
                              rng=galsim.BaseDeviate(int(rng.integers(1, 2**31))),
                              get_convergence=False)
        g1, g2 = np.asarray(g1), np.asarray(g2)
        scale = shear_rms / max(np.sqrt(0.5 * (g1.var() + g2.var())), 1e-12)
        # grid node (i, j) is at pixel (j, i) * spacing / pixel_scale - one cell (margin)
        nodes = (np.arange(ngrid) - 1.0) * spacing / pixel_scale
        self._g1 = RectBivariateSpline(nodes, nodes, (g1 - g1.mean()) * scale)
        self._g2 = RectBivariateSpline(nodes, nodes, (g2 - g2.mean()) * scale)
        self.fwhm = float(fwhm)
        self.center = ((nx - 1) / 2.0, (ny - 1) / 2.0)
        self.half = (nx / 2.0, ny / 2.0)
        # aberrations (waves) = c0 + c1 u + c2 v + c3 (u^2 + v^2), u, v in [-1, 1]
        base = {"defocus": (0.5, 0.0, 0.0, 0.25), "astig1": (0.05, 0.12, 0.0, 0.0),
                "astig2": (-0.03, 0.0, 0.12, 0.0), "coma1": (0.0, 0.08, 0.0, 0.0),
                "coma2": (0.0, 0.0, 0.08, 0.0)}
        # random amplitudes (x0.6-1.4) and signs (but defocus stays positive)
        self.aberrations = {}
        for k, v in base.items():
            sign = 1.0 if k == "defocus" else rng.choice([-1.0, 1.0], 4)
            self.aberrations[k] = np.asarray(v) * rng.uniform(0.6, 1.4, 4) * sign

    def shear(self, x, y):
        return float(self._g1(y, x, grid=False)), float(self._g2(y, x, grid=False))

    def __call__(self, x, y):
        galsim = _galsim()
        u = (x - self.center[0]) / self.half[0]
        v = (y - self.center[1]) / self.half[1]
        terms = np.array([1.0, u, v, u * u + v * v])
        waves = {k: float(c @ terms) for k, c in self.aberrations.items()}
        optics = galsim.OpticalPSF(lam=_LAM_NM, diam=_DIAM_M, obscuration=_OBSCURATION,
                                   scale_unit=galsim.arcsec, oversampling=1.0, pad_factor=1.0,
                                   suppress_warning=True, **waves)
        g1, g2 = self.shear(x, y)
        return galsim.Convolve(galsim.Kolmogorov(fwhm=self.fwhm).shear(g1=g1, g2=g2), optics)


@dataclass
class GalSimCCD:
    """A GalSim-rendered CCD and its truth (see :func:`render_galsim_ccd`).

    Attributes
    ----------
    image : ndarray of float32, shape (ny, nx)
        Sky + sources + noise, in ADU, clipped at the full well ``saturation``.
    weight : ndarray of float32, shape (ny, nx)
        Inverse variance of the sky noise; 0 on masked (dead) pixels.
    header : astropy.io.fits.Header
        ``GAIN``, ``SATURATE`` (99% of the full well: Source Extractor flags pixels
        strictly above it), ``SKYLEVEL``, ``PIXSCALE`` and a TAN WCS.
    stars, galaxies : astropy.table.Table
        Truth: 0-based ``x``, ``y`` (x = column), ``flux`` (ADU), ``snr``; stars also
        ``saturated`` (noiseless peak + sky above ``SATURATE``), galaxies ``hlr`` (arcsec), ``g1``,
        ``g2`` (intrinsic shape).
    psf : callable
        ``psf(x, y) -> galsim.GSObject``, the PSF at a 0-based pixel position (arcsec units).
    pixel_scale : float
        Arcsec per pixel.
    """

    image: np.ndarray
    weight: np.ndarray
    header: fits.Header
    stars: Table
    galaxies: Table
    psf: Callable = field(repr=False)
    pixel_scale: float = 0.263

    def psf_at(self, x, y):
        """The true PSF at the 0-based pixel position ``(x, y)``, a GalSim profile without pixel.

        Examples
        --------
        >>> from sklearn_psf.simulate import render_galsim_ccd
        >>> ccd = render_galsim_ccd(shape=(128, 128), n_stars=3, n_galaxies=0,
        ...                         n_saturated=0, random_state=0)
        >>> bool(0.9 < ccd.psf_at(64.0, 64.0).calculateFWHM() < 1.1)   # arcsec: seeing + optics
        True
        """
        return self.psf(float(x), float(y))

    def truth_stamps(self, x, y, stamp_size: int = 25, method: str = "auto",
                     offsets=None) -> np.ndarray:
        """The true pixel-convolved PSF at positions, normalised to unit sum.

        Parameters
        ----------
        x, y : array-like of shape (n,)
            0-based pixel positions.
        stamp_size : int, default=25
            Side of each stamp (pixels).
        method : str, default="auto"
            GalSim's ``drawImage`` method ("auto" convolves with the pixel; "no_pixel" does
            not).
        offsets : array-like of shape (n, 2), optional
            Where the PSF's centre lies from the stamp's centre pixel (pixels, x then y);
            default 0: centred on pixel ``stamp_size // 2`` (the package's convention, odd or
            even side).

        Returns
        -------
        stamps : ndarray of shape (n, stamp_size, stamp_size)

        Examples
        --------
        >>> from sklearn_psf.simulate import render_galsim_ccd
        >>> ccd = render_galsim_ccd(shape=(128, 128), n_stars=3, n_galaxies=0,
        ...                         n_saturated=0, random_state=0)
        >>> s = ccd.truth_stamps([10.0, 100.0], [20.0, 90.0], stamp_size=15)
        >>> s.shape, round(float(s[0].sum()), 6), int(s[0].argmax()) == 7 * 15 + 7
        ((2, 15, 15), 1.0, True)
        """
        x = np.atleast_1d(np.asarray(x, dtype=float))
        y = np.atleast_1d(np.asarray(y, dtype=float))
        if x.shape != y.shape or x.ndim != 1:
            raise ValueError(f"x and y must be 1-d of one length, got {x.shape} and {y.shape}.")
        side = int(stamp_size)
        if side < 3:
            raise ValueError(f"stamp_size must be at least 3, got {stamp_size!r}.")
        off = np.zeros((x.size, 2)) if offsets is None else np.asarray(offsets, float)
        if off.shape != (x.size, 2):
            raise ValueError(f"offsets must have shape ({x.size}, 2), got {off.shape}.")
        # galsim centres a profile on the true centre (side + 1) / 2 (1-based); the package's
        # centre pixel is side // 2 (0-based) = side // 2 + 1 (1-based)
        shift = side // 2 + 1 - (side + 1) / 2.0
        out = np.empty((x.size, side, side))
        for i in range(x.size):
            im = self.psf_at(x[i], y[i]).drawImage(
                nx=side, ny=side, scale=self.pixel_scale, method=method,
                offset=(shift + off[i, 0], shift + off[i, 1]))
            out[i] = im.array / im.array.sum()
        return out

    def write(self, folder, name: str = "ccd", *, overwrite: bool = False) -> Path:
        """Write the image and its weight map as FITS files for SExtractor.

        The image is ``<folder>/<name>.fits`` (primary HDU, with :attr:`header`); the weight
        map is ``<folder>/<name>.weight.fits`` (SExtractor's ``WEIGHT_TYPE MAP_WEIGHT``).

        Returns
        -------
        path : pathlib.Path
            The image's path.

        Examples
        --------
        >>> import tempfile
        >>> from sklearn_psf.simulate import render_galsim_ccd
        >>> ccd = render_galsim_ccd(shape=(64, 64), n_stars=2, n_galaxies=0,
        ...                         n_saturated=0, random_state=0)
        >>> ccd.write(tempfile.mkdtemp()).name
        'ccd.fits'
        """
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / f"{name}.fits"
        weight_path = self.weight_path(path)
        for p in (path, weight_path):
            if p.exists() and not overwrite:
                raise FileExistsError(f"{str(p)!r} already exists: pass overwrite=True.")
        write_fits_atomic(fits.HDUList([fits.PrimaryHDU(self.image, self.header)]), path,
                          overwrite=overwrite)
        write_fits_atomic(fits.HDUList([fits.PrimaryHDU(self.weight, self.header)]),
                          weight_path, overwrite=overwrite)
        return path

    @staticmethod
    def weight_path(image_path) -> Path:
        """The weight map's path written beside ``image_path`` by :meth:`write`."""
        p = Path(image_path)
        return p.with_name(p.name[: -len(".fits")] + ".weight.fits"
                           if p.name.endswith(".fits") else p.name + ".weight.fits")


def _flux_for_snr(snr, profile_sq_sum, sigma):
    """Flux of a source of sky-limited matched-filter S/N ``snr``: snr * sigma / sqrt(sum p^2)."""
    return snr * sigma / np.sqrt(profile_sq_sum)


def render_galsim_ccd(*, shape=(2048, 2048), pixel_scale: float = 0.263, n_stars: int = 600,
                      n_galaxies: int = 1000, psf=None, snr_range=(20.0, 1000.0),
                      n_saturated: int = 5, sky_level: float = 400.0, gain: float = 4.0,
                      saturation: float = 30000.0, fwhm: float = 0.9, shear_rms: float = 0.01,
                      galaxy_snr_range=(10.0, 80.0), n_bad_columns: int = 2,
                      margin: int = 8, random_state=None, noise_seed=None) -> GalSimCCD:
    """Render a DECam-like CCD with GalSim: stars, galaxies, sky noise, saturation, dead columns.

    Parameters
    ----------
    shape : (ny, nx), default=(2048, 2048)
    pixel_scale : float, default=0.263
        Arcsec per pixel (DECam's).
    n_stars : int, default=600
        Stars at uniform random sub-pixel positions, with S/N log-uniform in ``snr_range``.
    n_galaxies : int, default=1000
        Exponential galaxies (half-light radius log-uniform in 0.2-0.8 arcsec, intrinsic
        shear of random direction and size uniform in 0-0.4) convolved with the local PSF,
        S/N log-uniform in ``galaxy_snr_range``.
    psf : None, "ground" or callable, default=None
        ``None`` / ``"ground"``: a Kolmogorov atmosphere of FWHM ``fwhm`` lensed by a
        power-spectrum shear field of rms ``shear_rms`` per component, convolved with
        ``galsim.OpticalPSF`` (700 nm, 4 m, 30% obscuration) whose defocus, astigmatism and
        coma vary over the chip (random low-order polynomials). A callable
        ``psf(x, y) -> galsim.GSObject`` (0-based pixel positions, arcsec units) replaces it,
        e.g. an undersampled space-like PSF.
    snr_range : (float, float), default=(20, 1000)
        Sky-limited matched-filter S/N of the stars: ``flux = snr * sigma_sky /
        sqrt(sum p^2)`` with ``p`` the local unit-flux pixelised PSF.
    n_saturated : int, default=5
        Extra stars whose noiseless peak is 1.5-20 times ``saturation`` (log-uniform); their
        pixels are clipped at ``saturation`` (they are in ``stars`` with ``saturated=True``,
        as is any other star whose peak exceeds it).
    sky_level : float, default=400
        Sky background (ADU per pixel), left in the image; its Poisson noise (Gaussian,
        variance ``sky_level / gain``) sets ``sigma_sky``.
    gain : float, default=4
        Electrons per ADU; the sources' Poisson noise is added too (Gaussian approximation).
    saturation : float, default=30000
        Full well (ADU): pixels above it are clipped to it. The header's ``SATURATE`` is
        ``0.99 * saturation``, as on real detectors whose saturated pixels read at or above
        that keyword (Source Extractor flags only pixels strictly above ``SATURATE``).
    fwhm : float, default=0.9
        Seeing FWHM (arcsec) of the default PSF.
    shear_rms : float, default=0.01
        Rms of each shear component of the default PSF's atmosphere.
    galaxy_snr_range : (float, float), default=(10, 80)
    n_bad_columns : int, default=2
        Dead columns: 0 in the image, 0 in the weight map.
    margin : int, default=8
        Sources lie at least this many pixels from the edges.
    random_state : None, int, SeedSequence or Generator
        Seeds everything: the sources, the noise and the dead columns.
    noise_seed : None, int or SeedSequence, default=None
        When given, the pixel noise alone is drawn from this seed: the same ``random_state``
        with another ``noise_seed`` gives the same sources and dead columns under a new noise
        realisation (how far a figure measured on one CCD moves with its noise). ``None``:
        from ``random_state``.

    Returns
    -------
    GalSimCCD

    Notes
    -----
    Drawing costs about 10 ms per object (the optics are ``OpticalPSF(oversampling=1,
    pad_factor=1)``, the truth being the same profile): a full 2048 x 2048 CCD with 600 stars
    and 1000 galaxies takes about 20 s.

    Examples
    --------
    >>> from sklearn_psf.simulate import render_galsim_ccd
    >>> ccd = render_galsim_ccd(shape=(256, 256), n_stars=10, n_galaxies=5, n_saturated=1,
    ...                         random_state=1)
    >>> ccd.image.shape, len(ccd.stars), int(ccd.stars["saturated"].sum()) >= 1
    ((256, 256), 11, True)
    >>> float(ccd.image.max()) == 30000.0
    True
    """
    galsim = _galsim()
    rng = as_generator(random_state)
    if noise_seed is not None:
        integer = isinstance(noise_seed, (int, np.integer)) and not isinstance(
            noise_seed, (bool, np.bool_))
        if not (isinstance(noise_seed, np.random.SeedSequence) or integer and noise_seed >= 0):
            raise ValueError(f"noise_seed must be None, a non-negative integer or a "
                             f"SeedSequence, got {noise_seed!r}.")
        noise_rng = np.random.default_rng(noise_seed)
    ny, nx = (int(v) for v in shape)
    if min(ny, nx) <= 2 * margin + 16:
        raise ValueError(f"shape {shape!r} is too small for margin={margin}.")
    for name, value in (("n_stars", n_stars), ("n_galaxies", n_galaxies),
                        ("n_saturated", n_saturated), ("n_bad_columns", n_bad_columns)):
        if int(value) != value or value < 0:
            raise ValueError(f"{name} must be a non-negative integer, got {value!r}.")
    lo, hi = (float(v) for v in snr_range)
    if not 0 < lo <= hi:
        raise ValueError(f"snr_range must be (low, high) with 0 < low <= high, got {snr_range!r}.")
    if not (pixel_scale > 0 and sky_level > 0 and gain > 0 and saturation > sky_level):
        raise ValueError("pixel_scale, sky_level and gain must be positive and saturation above "
                         "sky_level.")
    if psf is None or (isinstance(psf, str) and psf == "ground"):
        psf = _GroundPSF((ny, nx), pixel_scale, fwhm, shear_rms, rng)
    elif not callable(psf):
        raise ValueError(f"psf must be None, 'ground' or a callable psf(x, y), got {psf!r}.")
    sigma = math.sqrt(sky_level / gain)

    def positions(n):
        return (rng.uniform(margin, nx - 1 - margin, n), rng.uniform(margin, ny - 1 - margin, n))

    noiseless = galsim.ImageD(nx, ny, scale=pixel_scale)

    def add(profile, x, y, half):
        ix, iy = int(round(x)) + 1, int(round(y)) + 1      # galsim pixels are 1-based
        bounds = galsim.BoundsI(ix - half, ix + half, iy - half, iy + half)
        stamp = profile.drawImage(image=galsim.ImageD(bounds, scale=pixel_scale),
                                  center=galsim.PositionD(x + 1.0, y + 1.0))
        overlap = bounds & noiseless.bounds
        noiseless[overlap] += stamp[overlap]
        return float(stamp.array.max())

    n_all = int(n_stars) + int(n_saturated)
    sx, sy = positions(n_all)
    snr = np.exp(rng.uniform(np.log(lo), np.log(hi), n_all))
    boost = np.ones(n_all)
    boost[n_stars:] = np.exp(rng.uniform(np.log(1.5), np.log(20.0), int(n_saturated)))
    flux = np.empty(n_all)
    peak = np.empty(n_all)
    for i in range(n_all):
        p = psf(float(sx[i]), float(sy[i]))
        unit = p.drawImage(nx=25, ny=25, scale=pixel_scale).array
        flux[i] = _flux_for_snr(snr[i], np.sum(unit**2), sigma)
        if i >= n_stars:  # a saturated star: its peak is boost x saturation
            flux[i] = boost[i] * (saturation - sky_level) / unit.max()
            snr[i] = flux[i] * np.sqrt(np.sum(unit**2)) / sigma
        half = 16 if i < n_stars and snr[i] < 300 else (24 if i < n_stars else 64)
        peak[i] = add(p.withFlux(flux[i]), sx[i], sy[i], half)
    stars = Table({"x": sx, "y": sy, "flux": flux, "snr": snr,
                   "saturated": peak + sky_level > 0.99 * saturation})

    gx, gy = positions(int(n_galaxies))
    hlr = np.exp(rng.uniform(np.log(0.2), np.log(0.8), gx.size))
    gmod = rng.uniform(0.0, 0.4, gx.size)
    beta = rng.uniform(0.0, np.pi, gx.size)
    g1, g2 = gmod * np.cos(2 * beta), gmod * np.sin(2 * beta)
    glo, ghi = (float(v) for v in galaxy_snr_range)
    gsnr = np.exp(rng.uniform(np.log(glo), np.log(ghi), gx.size))
    gflux = np.empty(gx.size)
    for i in range(gx.size):
        gal = galsim.Exponential(half_light_radius=hlr[i]).shear(g1=g1[i], g2=g2[i])
        prof = galsim.Convolve(gal, psf(float(gx[i]), float(gy[i])))
        unit = prof.drawImage(nx=33, ny=33, scale=pixel_scale).array
        gflux[i] = _flux_for_snr(gsnr[i], np.sum(unit**2), sigma)
        add(prof.withFlux(gflux[i]), gx[i], gy[i], 16)
    galaxies = Table({"x": gx, "y": gy, "flux": gflux, "snr": gsnr, "hlr": hlr,
                      "g1": g1, "g2": g2})

    signal = noiseless.array + sky_level
    noise = rng.standard_normal(signal.shape)  # drawn either way: the dead columns stay
    if noise_seed is not None:
        noise = noise_rng.standard_normal(signal.shape)
    noisy = signal + noise * np.sqrt(np.maximum(signal, 0) / gain)
    image = np.minimum(noisy, saturation).astype(np.float32)
    weight = np.full((ny, nx), 1.0 / sigma**2, dtype=np.float32)
    bad = rng.choice(np.arange(margin, nx - margin), int(n_bad_columns), replace=False)
    image[:, bad] = 0.0
    weight[:, bad] = 0.0

    header = fits.Header()
    header["GAIN"] = (float(gain), "electrons per ADU")
    header["SATURATE"] = (0.99 * float(saturation), "saturation level (ADU)")
    header["SKYLEVEL"] = (float(sky_level), "sky background (ADU), not subtracted")
    header["PIXSCALE"] = (float(pixel_scale), "arcsec per pixel")
    header["CTYPE1"], header["CTYPE2"] = "RA---TAN", "DEC--TAN"
    header["CRVAL1"], header["CRVAL2"] = 150.0, 2.0
    header["CRPIX1"], header["CRPIX2"] = (nx + 1) / 2.0, (ny + 1) / 2.0
    header["CD1_1"], header["CD1_2"] = -pixel_scale / 3600.0, 0.0
    header["CD2_1"], header["CD2_2"] = 0.0, pixel_scale / 3600.0
    header["CUNIT1"], header["CUNIT2"] = "deg", "deg"
    return GalSimCCD(image=image, weight=weight, header=header, stars=stars,
                     galaxies=galaxies, psf=psf, pixel_scale=float(pixel_scale))
