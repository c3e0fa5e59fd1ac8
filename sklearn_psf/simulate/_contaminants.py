"""Rendering with sub-pixel offsets, contaminants with truth, detector defects.

The strengths of the contaminants and the reasons for them are documented in
:mod:`sklearn_psf.simulate` (section *Contaminants*).
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy.signal import fftconvolve

from ..measure import adaptive_moments
from ..preprocessing import CentringWarning, StampNormalizer, fourier_shift

__all__ = ["CONTAMINANT_KINDS", "CONTAMINANT_RANGES"]

#: Kinds of contaminant that ``make_psf_field(contaminants={kind: fraction})`` puts on stars.
CONTAMINANT_KINDS = ("cosmic_ray", "neighbour", "galaxy", "binary")

#: Default ranges of the companions' flux ratio (companion / star, log-uniform) and
#: separation (pixels, uniform): an unresolved binary and a neighbour inside the stamp.
CONTAMINANT_RANGES = {
    "binary": {"flux_ratio": (0.01, 0.2), "separation": (0.5, 4.0)},
    "neighbour": {"flux_ratio": (0.1, 0.5), "separation": (3.0, 8.0)},
}

_GALAXY_SIDE_EXTRA = 16  # galaxies are drawn on stamps 16 pixels wider than the PSF's
_HLR_PER_SIGMA = 1.1774  # half-light radius / Gaussian sigma (the PSF's hlr from its moments)


def render(image, positions, stamps, flux) -> None:
    """Add ``flux * stamp`` to ``image`` at float ``positions`` (in place, clipped at edges).

    Each (odd-sided, centred) stamp is shifted by the sub-pixel offset of its position from
    the nearest pixel with a Fourier phase ramp, then added centred on that pixel.
    """
    n = len(positions)
    if n == 0:
        return
    pos = np.asarray(positions, dtype=np.float64)
    side = int(round(np.sqrt(stamps.shape[1])))
    cube = np.asarray(stamps, dtype=np.float64).reshape(n, side, side)
    centre = np.floor(pos + 0.5)
    d = pos - centre
    moved = np.any(d != 0.0, axis=1)
    if moved.any():
        cube = cube.copy()
        cube[moved] = fourier_shift(cube[moved], d[moved, 0], d[moved, 1])
    h = side // 2
    off = np.arange(-h, h + 1)
    rows = centre[:, 1].astype(np.intp)[:, None, None] + off[None, :, None]
    cols = centre[:, 0].astype(np.intp)[:, None, None] + off[None, None, :]
    rows, cols = np.broadcast_arrays(rows, cols)
    values = cube * np.asarray(flux, dtype=np.float64)[:, None, None]
    ny, nx = image.shape
    ok = (rows >= 0) & (rows < ny) & (cols >= 0) & (cols < nx)
    np.add.at(image, (rows[ok], cols[ok]), values[ok].astype(image.dtype))


def exponential_galaxy(psf, hlr, q, angle, side):
    """Unit-flux exponential profile (half-light radius ``hlr`` pixels along the geometric
    mean axis, axis ratio ``q``, position angle ``angle``) integrated over pixels (5 x 5
    sub-samples) and convolved with the normalised ``psf`` stamp, on a ``side`` x ``side``
    stamp centred on its central pixel."""
    sub = 5
    t = (np.arange(side * sub) - (side * sub - 1) / 2) / sub
    y, x = np.meshgrid(t, t, indexing="ij")
    c, s = np.cos(angle), np.sin(angle)
    u, v = c * x + s * y, -s * x + c * y
    r = np.sqrt(u**2 * q + v**2 / q)
    prof = np.exp(-r * 1.6783 / hlr).reshape(side, sub, side, sub).sum(axis=(1, 3))
    p = psf.reshape(int(round(np.sqrt(psf.size))), -1)
    out = fftconvolve(prof, p, mode="same")
    return out / out.sum()


def _cosmic_ray(rng, shape_side, peak, noise_rms):
    """Stamp of a 1-3 pixel cosmic-ray track within 3 pixels of the stamp centre, and its
    amplitude (the larger of 30-300 sky sigma, log-uniform, and 20-100% of the star's peak)."""
    stamp = np.zeros((shape_side, shape_side))
    c = shape_side // 2
    start = np.array([c, c]) + rng.integers(-3, 4, 2)
    step = np.array([[0, 1], [1, 0], [1, 1], [1, -1]])[rng.integers(4)]
    length = int(rng.integers(1, 4))
    amp = max(np.exp(rng.uniform(np.log(30.0), np.log(300.0))) * noise_rms,
              rng.uniform(0.2, 1.0) * peak)
    for i in range(length):
        y, x = start + i * step
        stamp[y, x] = amp * rng.uniform(0.6, 1.0)
    return stamp, length


def contaminate_stars(image, stars, kinds, rng, noise_rms, min_snr, ranges=None):
    """Render each star of ``stars`` (truth table) with its contaminant ``kinds[i]``.

    Returns the contaminant truth rows (list of dicts) and each star's contaminant S/N (the
    norm of the difference between the contaminated and the clean, flux- and centroid-matched
    noiseless stamp over the sky rms: the square root of the chi^2 the contaminant adds).
    Contaminants below ``min_snr`` are strengthened (up to 6 times) until they reach it;
    ``ranges`` (``CONTAMINANT_RANGES``' layout) replaces the default companions' ranges.
    """
    ranges = {kind: {**r, **(ranges or {}).get(kind, {})}
              for kind, r in CONTAMINANT_RANGES.items()}
    s = int(round(np.sqrt(len(stars["stamp"][0])))) if len(stars) else 0
    rows, snrs = [], []
    norm = StampNormalizer()
    for i in np.flatnonzero([k != "" for k in kinds]):
        kind = kinds[i]
        star = stars[i]
        pos = np.array([star["x"], star["y"]], dtype=np.float64)
        truth = np.asarray(star["stamp"], dtype=np.float64)
        flux = float(star["flux"])
        psf_hlr = _HLR_PER_SIGMA * float(star["sigma"])
        p = _draw_params(kind, rng, truth, flux, psf_hlr, noise_rms, s, ranges)
        for _ in range(7):
            parts = _parts(kind, p, pos, truth, flux, s)
            local = np.zeros((s, s))
            centre = np.floor(pos + 0.5)
            for ppos, pst, pflux in parts:
                render(local, (ppos - centre + s // 2)[None], pst[None], [pflux])
            total = local.sum()
            with warnings.catch_warnings():  # a track can defeat the centring: large residual
                warnings.simplefilter("ignore", CentringWarning)
                resid = (norm.fit_transform(local.reshape(1, -1))[0] - truth) * total
            snr = float(np.sqrt(np.sum(resid**2)) / noise_rms)
            if snr >= min_snr:
                break
            p = _strengthen(kind, p)
        for ppos, pst, pflux in parts:
            render(image, ppos[None], pst[None], [pflux])
        snrs.append((i, snr))
        rows.append({"kind": kind, "star": int(i), "x": float(p.get("x", pos[0])),
                     "y": float(p.get("y", pos[1])), "flux": float(p["cflux"]),
                     "size": float(p["size"]), "snr": snr})
    return rows, snrs


def _draw_params(kind, rng, truth, flux, psf_hlr, noise_rms, s, ranges):
    if kind == "cosmic_ray":
        st, length = _cosmic_ray(rng, s, flux * truth.max(), noise_rms)
        return {"stamp": st, "size": length, "cflux": st.sum()}
    if kind == "galaxy":
        return {"hlr": psf_hlr * rng.uniform(1.0, 3.0), "q": rng.uniform(0.4, 0.9),
                "pa": rng.uniform(0, np.pi), "psf_hlr": psf_hlr}
    ratio, sep = ranges[kind]["flux_ratio"], ranges[kind]["separation"]  # binary, neighbour
    return {"dist": rng.uniform(*sep), "angle": rng.uniform(0, 2 * np.pi),
            "frac": np.exp(rng.uniform(*np.log(ratio)))}


def _strengthen(kind, p):
    p = dict(p)
    if kind == "cosmic_ray":
        p["stamp"] = p["stamp"] * 2.0
    elif kind == "neighbour":
        p["frac"] = min(1.0, p["frac"] * 1.5)
    elif kind == "galaxy":
        p["hlr"] = min(6.0 * p["psf_hlr"], p["hlr"] * 1.4)
    else:
        p["dist"] = min(5.0, p["dist"] * 1.3)
        p["frac"] = min(1.0, p["frac"] * 1.3)
    return p


def _parts(kind, p, pos, truth, flux, s):
    """(position, stamp, flux) pieces that replace the clean star; fills p's truth keys."""
    if kind == "cosmic_ray":
        p["cflux"] = p["stamp"].sum()
        centre = np.floor(pos + 0.5)  # the track sits on pixels: no sub-pixel shift
        return [(pos, truth, flux), (centre, p["stamp"].ravel(), 1.0)]
    if kind == "galaxy":
        side = s + _GALAXY_SIDE_EXTRA
        psf = np.pad(truth.reshape(s, s), _GALAXY_SIDE_EXTRA // 2)
        gal = exponential_galaxy(psf, p["hlr"], p["q"], p["pa"], side)
        p["size"], p["cflux"] = p["hlr"], flux
        return [(pos, gal.ravel(), flux)]
    off = p["dist"] * np.array([np.cos(p["angle"]), np.sin(p["angle"])])
    p["x"], p["y"] = pos + off
    p["size"] = p["dist"]
    if kind == "neighbour":
        p["cflux"] = p["frac"] * flux
        return [(pos, truth, flux), (pos + off, truth, p["frac"] * flux)]
    q = p["frac"]  # binary: total flux kept, primary at the star's position
    p["cflux"] = q * flux / (1 + q)
    return [(pos, truth, flux / (1 + q)), (pos + off, truth, q * flux / (1 + q))]


def field_galaxies(image, positions, psfs, flux, rng):
    """Extended galaxies (exponential, hlr 1-3x the PSF's, axis ratio 0.4-0.9) rendered
    at ``positions`` with the local PSF stamps ``psfs`` and fluxes ``flux``; truth rows."""
    s = int(round(np.sqrt(psfs.shape[1]))) if len(psfs) else 0
    side = s + _GALAXY_SIDE_EXTRA
    rows = []
    sigma = np.asarray(adaptive_moments(psfs)["sigma"]) if len(psfs) else []
    for (x, y), psf, f, sig in zip(positions, psfs, flux, sigma):
        hlr = _HLR_PER_SIGMA * float(sig) * rng.uniform(1.0, 3.0)
        gal = exponential_galaxy(np.pad(psf.reshape(s, s), _GALAXY_SIDE_EXTRA // 2), hlr,
                                 rng.uniform(0.4, 0.9), rng.uniform(0, np.pi), side)
        render(image, np.array([[x, y]]), gal.reshape(1, -1), [f])
        rows.append({"kind": "field_galaxy", "star": -1, "x": float(x), "y": float(y),
                     "flux": float(f), "size": hlr, "snr": np.nan})
    return rows


def field_cosmic_rays(image, positions, rng, noise_rms, side=13):
    """Cosmic-ray tracks (1-3 pixels, 30-300 sky sigma) at ``positions``; truth rows."""
    rows = []
    for x, y in positions:
        st, length = _cosmic_ray(rng, side, 0.0, noise_rms)
        render(image, np.array([[x, y]]), st.reshape(1, -1), [1.0])
        rows.append({"kind": "field_cosmic_ray", "star": -1, "x": float(x), "y": float(y),
                     "flux": float(st.sum()), "size": float(length), "snr": np.nan})
    return rows


def apply_defects(image, rng, noise_rms, *, source=None, gain=None, masked_fraction=0.0,
                  bad_columns=0, saturation=None, mask_value=0.0):
    """Noise weight map, masks and saturation on a noisy ``image`` (modified in place).

    ``source`` is the noiseless source image (needed for the Poisson variance with ``gain``).
    Returns the weight map (float32): 1 / (noise_rms^2 + source / gain), 0 on masked and
    saturated pixels.
    """
    ny, nx = image.shape
    weight = np.full((ny, nx), 1.0 / noise_rms**2, dtype=np.float32)
    if gain is not None:
        lit = source > 0
        weight[lit] = 1.0 / (noise_rms**2 + source[lit] / gain)
    if saturation is not None:
        sat = image > saturation
        image[sat] = saturation
        weight[sat] = 0.0
    bad = np.zeros(0, dtype=np.intp)
    if masked_fraction > 0:
        bad = rng.integers(0, ny * nx, int(round(masked_fraction * ny * nx)))
    weight.ravel()[bad] = 0.0
    image.ravel()[bad] = mask_value
    if bad_columns:
        cols = rng.choice(nx, int(bad_columns), replace=False)
        weight[:, cols] = 0.0
        image[:, cols] = mask_value
    return weight
