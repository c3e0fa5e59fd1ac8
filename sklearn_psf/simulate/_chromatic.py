"""The PSF of each source: colour (chromatic seeing, optics and refraction) and flux
(brighter-fatter) dependence of simulated PSFs.

A source of colour g-i is given the blackbody spectrum of that colour (AB magnitudes through
top-hat g, i bands); its PSF is the photon-weighted sum over an r-like band (550-700 nm, top
hat) of monochromatic PSFs: the field's PSF at ``BASE_WAVELENGTH`` dilated so that its second
moment is ``(1 - f) (w / w0)^-0.4 + f (w / w0)^2`` times the base one (seeing FWHM ~ w^-0.2,
diffraction ~ w, ``f`` the optics' share of the second moment) and shifted along the image's
y axis by the differential chromatic refraction at the stated airmass (Filippenko 1982's
formula, Edlen 1953's refractivity, at Cerro Pachon's pressure). The brighter-fatter effect
dilates the PSF in proportion to the source's S/N.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import map_coordinates, spline_filter1d

__all__ = ["blackbody_colour", "refraction"]

#: top-hat bands (nm): g, r (the PSF's band), i
G_BAND, R_BAND, I_BAND = (400.0, 550.0), (550.0, 700.0), (700.0, 850.0)
#: wavelength at which the field's PSF (the reference basis) is taken (nm)
BASE_WAVELENGTH = 620.0
#: wavelengths sampling the r band (bin centres, nm)
_N_WAVE = 16
_H_C_OVER_K = 1.4387769e7  # h c / k in nm K


def _planck(wave, temperature):
    """Blackbody f_lambda (arbitrary units) at ``wave`` nm, ``temperature`` K."""
    x = _H_C_OVER_K / (wave * np.asarray(temperature, dtype=np.float64)[..., None])
    return wave**-5.0 / np.expm1(np.minimum(x, 700.0))


def _band_mean_fnu(band, temperature):
    """Photon-weighted mean f_nu through a top-hat band (AB convention)."""
    wave = np.linspace(*band, 301)
    f_lambda = _planck(wave, temperature)
    # <f_nu> = int f_lambda lambda T dlambda / int T / lambda dlambda
    return np.trapezoid(f_lambda * wave, wave, axis=-1) / np.trapezoid(1.0 / wave, wave)


def blackbody_colour(temperature):
    """g-i (AB) of a blackbody through the top-hat g (400-550 nm) and i (700-850 nm) bands.

    Parameters
    ----------
    temperature : float or array-like
        Kelvin.

    Returns
    -------
    g_i : ndarray

    Examples
    --------
    >>> from sklearn_psf.simulate import blackbody_colour
    >>> [round(float(c), 2) for c in blackbody_colour([4000.0, 6000.0, 10000.0])]
    [1.59, 0.6, -0.17]
    """
    return -2.5 * np.log10(_band_mean_fnu(G_BAND, temperature)
                           / _band_mean_fnu(I_BAND, temperature))


_T_GRID = np.geomspace(1500.0, 1e5, 600)
_COLOUR_GRID = blackbody_colour(_T_GRID)  # decreasing with temperature


def _temperature(colour):
    c = np.asarray(colour, dtype=np.float64)
    lo, hi = _COLOUR_GRID[-1], _COLOUR_GRID[0]
    if np.any((c < lo) | (c > hi)):
        raise ValueError(f"g-i colours must be within [{lo:.2f}, {hi:.2f}] (blackbodies of "
                         f"{_T_GRID[-1]:.0f}-{_T_GRID[0]:.0f} K), got {c.min():.2f}-"
                         f"{c.max():.2f}.")
    return np.exp(np.interp(c, _COLOUR_GRID[::-1], np.log(_T_GRID[::-1])))


def refraction(wave, airmass, *, pressure=69.328, temperature=293.15, h2o_pressure=1.067):
    """Atmospheric refraction (arcsec) at ``wave`` nm and ``airmass`` (Filippenko 1982).

    Parameters
    ----------
    wave : float or array-like
        Wavelength in nm.
    airmass : float
        sec(zenith angle), >= 1.
    pressure, temperature, h2o_pressure : float
        kPa, K, kPa (defaults: Cerro Pachon).

    Returns
    -------
    refraction : ndarray
        Arcsec towards the zenith.

    Examples
    --------
    >>> from sklearn_psf.simulate import refraction
    >>> round(float(refraction(500.0, 1.2) - refraction(700.0, 1.2)), 3)
    0.293
    """
    sigma2 = (1e3 / np.asarray(wave, dtype=np.float64)) ** 2  # (1/micron)^2
    p_mmhg, f_mmhg, t_c = pressure * 7.50062, h2o_pressure * 7.50062, temperature - 273.15
    n1 = 64.328 + 29498.1 / (146.0 - sigma2) + 255.4 / (41.0 - sigma2)
    n1 *= p_mmhg * (1.0 + (1.049 - 0.0157 * t_c) * 1e-6 * p_mmhg) / (
        720.883 * (1.0 + 0.003661 * t_c))
    n1 -= (0.0624 - 0.000680 * sigma2) / (1.0 + 0.003661 * t_c) * f_mmhg
    tan_z = np.sqrt(max(float(airmass) ** 2 - 1.0, 0.0))
    return np.rad2deg(n1 * 1e-6 * tan_z) * 3600.0


def draw_colours(n, kind, rng):
    """g-i colours: stars 0.3-3.0 (70% near the main-sequence turn-off at 0.8, 30% M dwarfs
    near 2.4), galaxies 0-2 (60% blue cloud near 0.7, 40% red sequence near 1.4)."""
    if kind == "stars":
        parts, bounds = ((0.7, 0.8, 0.3), (0.3, 2.4, 0.4)), (0.3, 3.0)
    else:
        parts, bounds = ((0.6, 0.7, 0.3), (0.4, 1.4, 0.2)), (0.0, 2.0)
    out = np.empty(0)
    while len(out) < n:
        which = rng.random(2 * n + 8) < parts[0][0]
        draw = np.where(which, rng.normal(parts[0][1], parts[0][2], which.size),
                        rng.normal(parts[1][1], parts[1][2], which.size))
        out = np.concatenate([out, draw[(draw >= bounds[0]) & (draw <= bounds[1])]])
    return out[:n]


def _resample(stamps, dilation, shift, weight):
    """Sum over k of ``weight[:, k]`` times each stamp dilated by ``dilation[:, k]`` about its
    centre and moved by ``shift[k]`` pixels along y, flux kept (cubic splines)."""
    n, s, _ = stamps.shape
    c = (s - 1) / 2.0
    grid = np.arange(s) - c
    d = dilation[:, :, None, None]  # (n, K, 1, 1)
    yy = (grid[None, None, :, None] - shift[None, :, None, None]) / d + c
    xx = grid[None, None, None, :] / d + c
    yy, xx = np.broadcast_arrays(yy, xx)
    coef = spline_filter1d(spline_filter1d(stamps, 3, axis=1, mode="grid-constant"), 3,
                           axis=2, mode="grid-constant")
    out = np.empty_like(stamps)
    for i in range(n):
        moved = map_coordinates(coef[i], [yy[i], xx[i]], order=3, prefilter=False,
                                mode="grid-constant")
        out[i] = np.tensordot(weight[i] / dilation[i] ** 2, moved, axes=1)
    return out


def chromatic_stamps(stamps, colour=None, *, airmass=None, optics_fraction=0.1,
                     pixel_scale=0.2, size_factor=None):
    """The PSF of each source from the field's PSF at its position.

    Parameters
    ----------
    stamps : ndarray of shape (n, s*s)
        The field's PSF (at ``BASE_WAVELENGTH``) at each source, centred.
    colour : ndarray of shape (n,), optional
        g-i of each source (blackbody spectrum); None: monochromatic at the base wavelength.
    airmass : float, optional
        Differential chromatic refraction at this airmass (along y); None: none.
    optics_fraction : float, default=0.1
        Share of the PSF's second moment from the optics (scaling as the wavelength), the
        rest from the seeing (as the wavelength^-0.2).
    pixel_scale : float
        Arcsec per pixel.
    size_factor : ndarray of shape (n,), optional
        A further dilation of each source's PSF (the brighter-fatter effect).

    Returns
    -------
    stamps : ndarray of shape (n, s*s)
        Unit-flux stamps (not re-centred).
    """
    n, s2 = stamps.shape
    s = int(round(np.sqrt(s2)))
    cube = stamps.reshape(n, s, s).astype(np.float64)
    factor = np.ones(n) if size_factor is None else np.asarray(size_factor, dtype=np.float64)
    if colour is None:
        out = _resample(cube, factor[:, None], np.zeros(1), np.ones((n, 1)))
    else:
        edges = np.linspace(*R_BAND, _N_WAVE + 1)
        wave = (edges[1:] + edges[:-1]) / 2.0
        photons = _planck(wave, _temperature(colour)) * wave  # (n, n_wave)
        photons /= photons.sum(axis=1, keepdims=True)
        ratio = wave / BASE_WAVELENGTH
        dilation = np.sqrt((1.0 - optics_fraction) * ratio**-0.4 + optics_fraction * ratio**2)
        shift = np.zeros_like(wave)
        if airmass is not None:
            shift = (refraction(wave, airmass) - refraction(BASE_WAVELENGTH, airmass))
            shift = shift / pixel_scale
        out = _resample(cube, factor[:, None] * dilation, shift, photons)
    out = out.reshape(n, s2)
    return out / out.sum(axis=1, keepdims=True)
