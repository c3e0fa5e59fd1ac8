"""Shared test data: the real files of the project's ``shared/realdata`` folder, and a FITS_LDAC
catalogue shaped like SExtractor's output, rendered with GalSim (the truth known)."""

import os
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


def realdata_folder():
    """The real-data folder ``shared/realdata`` next to the repository (or next to the folder
    holding it, for a git worktree), or ``$SKLEARN_PSF_REALDATA``; None when absent."""
    candidates = [os.environ.get("SKLEARN_PSF_REALDATA")]
    candidates += [base / "shared" / "realdata" for base in (ROOT.parent, ROOT.parent.parent)]
    for folder in candidates:
        if folder and Path(folder).is_dir():
            return Path(folder)
    return None


@pytest.fixture(scope="session")
def realdata():
    """``realdata(name)``: the path of a real file, or the test is skipped (with the reason)."""

    def path(name):
        folder = realdata_folder()
        if folder is None:
            pytest.skip("real data absent: no shared/realdata folder next to the repository "
                        "(set SKLEARN_PSF_REALDATA to its path)")
        file = folder / name
        if not file.exists():
            pytest.skip(f"real data file {name} absent from {folder}")
        return file

    return path


# ------------------------------------------------------------------ a SExtractor-like catalogue
PIXEL_SCALE = 0.263  # arcsec per pixel (DECam)
SHAPE = (4096, 2048)  # (ny, nx) of a DECam CCD
SKY_SIGMA, GAIN, BACKGROUND, SATURATE = 8.9, 4.0, 280.0, 38000.0
VIGNET = 31


def _tpv_header():
    """A DECam-like image header: the cards around a TPV WCS, as SExtractor copies them."""
    from astropy.io import fits

    h = fits.Header()
    h["SIMPLE"], h["BITPIX"], h["NAXIS"] = True, -32, 2
    h["NAXIS1"], h["NAXIS2"] = SHAPE[1], SHAPE[0]
    h.add_comment("FITS (Flexible Image Transport System) format is defined in 'Astronomy")
    h["EXPTIME"] = (90.0, "[s] Exposure duration")
    h["FILTER"] = ("r DECam SDSS c0002 6415.0 1480.0", "Unique filter identifier")
    h["CCDNUM"] = (1, "CCD number")
    h["GAINA"], h["GAINB"] = (4.039, "[electrons/adu] Gain for amp A"), (3.781, "amp B")
    h["CTYPE1"], h["CTYPE2"] = "RA---TPV", "DEC--TPV"
    h["CRVAL1"], h["CRVAL2"] = 61.45, -52.376
    h["CRPIX1"], h["CRPIX2"] = 13423.2, 6307.3
    h["CD1_1"], h["CD1_2"] = -3.9e-09, 7.2859e-05
    h["CD2_1"], h["CD2_2"] = -7.2858e-05, 1.8e-09
    pv = {"PV1_0": 0.0025, "PV1_1": 1.0149, "PV1_2": -0.0048, "PV1_4": 0.0074, "PV1_5": -0.0202,
          "PV1_6": 0.0043, "PV2_0": -0.011, "PV2_1": 1.041, "PV2_2": -0.0076,
          "PV2_4": -0.0471, "PV2_5": 0.0149, "PV2_6": -0.0103}
    for key, value in pv.items():
        h[key] = (value, "Projection distortion parameter")
    h["RADESYS"] = "ICRS"
    h.add_history("DESDM: imcorrect -variancetype WEIGHT -interpolate_col 2.0")
    h["SATURATE"] = (SATURATE, "Global Saturate Value")
    h["GAIN"] = (GAIN, "e-/ADU")
    h["SEXVERS"] = ("SExtractor 2.18.10", "Extraction software")
    h["SEXBKDEV"] = (SKY_SIGMA, "Median background RMS (ADU)")
    return h


def _psf(x, y):
    """The PSF at pixel (x, y): a Moffat whose size and shape vary smoothly over the CCD."""
    import galsim

    u, v = x / SHAPE[1], y / SHAPE[0]
    fwhm = 1.0 + 0.15 * v - 0.05 * u  # arcsec
    return galsim.Moffat(beta=3.5, fwhm=fwhm).shear(g1=-0.04 + 0.08 * u, g2=-0.03 + 0.06 * v)


def _flux_for_snr(snr, n_pix):
    """Flux whose aperture S/N (sky and Poisson noise, ``n_pix`` pixels) is ``snr``."""
    a = snr**2 / GAIN
    return 0.5 * (a + np.sqrt(a**2 + 4 * snr**2 * n_pix * SKY_SIGMA**2))


def make_sextractor_ldac(path, *, n_stars=140, galaxy_fraction=0.3, seed=0):
    """Write a FITS_LDAC catalogue shaped like SExtractor's, with GalSim-rendered vignettes.

    Point sources (``CLASS_STAR`` 0.55-0.75, aperture S/N 20-300, log-uniform), galaxies
    (exponential discs, half-light radius 0.3-1.5 arcsec, log-uniform, |g| < 0.4, the same
    S/N range and ``CLASS_STAR`` 0.02-0.7), three saturated stars (not flagged: only the header's
    ``SATURATE`` tells), three stars 12-13 pixels from the CCD edge (their vignette part beyond
    it at -1e30), a masked column (-1e30) in 10% of the vignettes, two blended pairs (``FLAGS``
    3). ``LDAC_IMHEAD`` holds a DECam-like header (``TDIM (80, N)``, ``SATURATE``, ``GAIN``, a
    TPV WCS). ``FLUX_AUTO``, ``FLUXERR_AUTO``, ``FLUX_RADIUS`` are measured with ``sep`` in a
    10-pixel aperture on the image (before masking: SExtractor measures the image, where bad
    columns are interpolated); positions are the true ones (1-based).

    Returns a dict: ``path``, ``kind`` ("star", "galaxy", "saturated", "blend" per row),
    ``x``, ``y`` (0-based true positions), ``e1``, ``e2``, ``sigma`` (the true PSF's adaptive
    moments at each row), ``header``.
    """
    import galsim
    import sep
    from astropy.table import Table
    from astropy.wcs import WCS

    from sklearn_psf.io import write_ldac
    from sklearn_psf.measure import adaptive_moments

    rng = np.random.default_rng(seed)
    n_gal = int(round(galaxy_fraction * n_stars / (1 - galaxy_fraction)))
    kinds = (["star"] * n_stars + ["galaxy"] * n_gal + ["saturated"] * 3 + ["blend"] * 2)
    n = len(kinds)
    # positions at least 40 pixels apart (closer pairs are SExtractor blends, flagged)
    pos = np.empty((0, 2))
    while len(pos) < n:
        p = rng.uniform([20, 20], [SHAPE[1] - 20, SHAPE[0] - 20])
        if not len(pos) or np.min(np.max(np.abs(pos - p), axis=1)) > 40:
            pos = np.vstack([pos, p])
    pos[:3] = [[12.3, 900.2], [1500.6, SHAPE[0] - 13.2], [SHAPE[1] - 12.7, 3000.4]]  # edges
    aperture, half = 10.0, VIGNET // 2
    n_pix = np.pi * aperture**2
    snr = np.exp(rng.uniform(np.log(20), np.log(300), n))
    vignettes = np.empty((n, VIGNET, VIGNET), np.float32)
    truth = np.empty((n, VIGNET, VIGNET))
    measured = np.empty((n, VIGNET, VIGNET))
    class_star = np.where(np.asarray(kinds) == "galaxy", rng.uniform(0.02, 0.7, n),
                          rng.uniform(0.55, 0.75, n))
    for i, kind in enumerate(kinds):
        x, y = pos[i]
        psf = _psf(x, y)
        offset = (x - np.floor(x + 0.5), y - np.floor(y + 0.5))
        truth[i] = psf.drawImage(nx=VIGNET, ny=VIGNET, scale=PIXEL_SCALE,
                                 offset=offset).array
        obj = psf
        if kind == "galaxy":
            hlr = np.exp(rng.uniform(np.log(0.3), np.log(1.5)))
            g = rng.uniform(0, 0.4)
            beta = rng.uniform(0, np.pi) * galsim.radians
            obj = galsim.Convolve(galsim.Exponential(half_light_radius=hlr)
                                  .shear(g=g, beta=beta), psf)
        flux = _flux_for_snr(snr[i], n_pix) * (200.0 if kind == "saturated" else 1.0)
        img = obj.withFlux(flux).drawImage(nx=VIGNET, ny=VIGNET, scale=PIXEL_SCALE,
                                           offset=offset).array
        if kind == "blend":
            img += np.roll(img, (3, 4), axis=(0, 1)) * 0.6
        var = SKY_SIGMA**2 + np.maximum(img, 0) / GAIN
        img = img + rng.normal(0.0, 1.0, img.shape) * np.sqrt(var)
        measured[i] = img = np.minimum(img, SATURATE - BACKGROUND)
        # the part beyond the CCD, and a bad column in 10% of the vignettes: -1e30 (SExtractor
        # measured the image, where the column is interpolated)
        iy, ix = np.mgrid[0:VIGNET, 0:VIGNET] - half
        ix, iy = ix + np.floor(x + 0.5), iy + np.floor(y + 0.5)
        img = img.copy()
        img[(ix < 0) | (ix > SHAPE[1] - 1) | (iy < 0) | (iy > SHAPE[0] - 1)] = -1e30
        if rng.uniform() < 0.1:
            img[:, half + rng.choice([-1, 1]) * rng.integers(5, 13)] = -1e30
        vignettes[i] = img
    flux_auto, fluxerr = np.empty(n), np.empty(n)
    radius = np.empty(n)
    for i in range(n):
        img = np.ascontiguousarray(measured[i])
        f, e, _ = sep.sum_circle(img, [half], [half], aperture, err=SKY_SIGMA, gain=GAIN,
                                 subpix=5)
        r, _ = sep.flux_radius(img, [half], [half], [aperture], 0.5, normflux=f, subpix=5)
        flux_auto[i], fluxerr[i], radius[i] = f[0], e[0], r[0]
    header = _tpv_header()
    wcs = WCS(header)
    ra, dec = wcs.all_pix2world(pos[:, 0], pos[:, 1], 0)
    flags = np.where(np.asarray(kinds) == "blend", 3, 0).astype(np.int16)
    objects = Table({
        "NUMBER": np.arange(1, n + 1, dtype=np.int32), "FLAGS": flags,
        "X_IMAGE": pos[:, 0] + 1.0, "Y_IMAGE": pos[:, 1] + 1.0,
        "XWIN_IMAGE": pos[:, 0] + 1.0, "YWIN_IMAGE": pos[:, 1] + 1.0,
        "ALPHA_J2000": ra, "DELTA_J2000": dec,
        "FLUX_AUTO": flux_auto.astype(np.float32), "FLUXERR_AUTO": fluxerr.astype(np.float32),
        "MAG_AUTO": (25.0 - 2.5 * np.log10(np.maximum(flux_auto, 1e-3))).astype(np.float32),
        "FLUX_RADIUS": radius.astype(np.float32),
        "FLUX_MAX": measured.max(axis=(1, 2)).astype(np.float32),
        "BACKGROUND": np.full(n, BACKGROUND, np.float32),
        "CLASS_STAR": class_star.astype(np.float32),
        "VIGNET": vignettes,
    })
    write_ldac(path, objects, header=header)
    mom = adaptive_moments(truth)
    return {"path": path, "kind": np.asarray(kinds), "x": pos[:, 0], "y": pos[:, 1],
            "e1": np.asarray(mom["e1"]), "e2": np.asarray(mom["e2"]),
            "sigma": np.asarray(mom["sigma"]), "header": header}


@pytest.fixture(scope="session")
def sextractor_ldac(tmp_path_factory):
    """:func:`make_sextractor_ldac`: 140 point sources, 60 galaxies, 3 saturated stars, 2 blends."""
    pytest.importorskip("galsim")
    return make_sextractor_ldac(tmp_path_factory.mktemp("sextractor") / "ccd01.ldac")


#: Test files holding the suite's longest tests (real-image cross-validations, 30-100 s
#: each): run first, so that the workers of ``-n auto`` do not wait on them at the end.
_LONGEST_FIRST = ("test_real_images.py",)


def pytest_collection_modifyitems(session, config, items):
    items.sort(key=lambda item: item.fspath.basename not in _LONGEST_FIRST)
