"""Files in and out: FITS images and weight maps, star catalogues, PSF stamps, world
coordinates, and Source Extractor and PSFEx run on files.

This subpackage reads and writes files, nothing more: what lies between an exposure's files
and a validated model (star selection, stamps, the fit) is :mod:`sklearn_psf.exposure`'s, the
model files are :mod:`sklearn_psf.model`'s. To try it without data,
:func:`sklearn_psf.simulate.write_example_exposure` writes a simulated exposure (image, weight
HDU, SExtractor-like catalogue, galaxy positions, truth) to a folder, and
:func:`sklearn_psf.simulate.write_example_ldac` a FITS_LDAC catalogue with vignettes::

    from sklearn_psf.io import read_catalog, read_image

    image, weight, header = read_image("c4d_ooi.fits.fz", hdu=1, weight_hdu=2)
    stars = read_catalog("c4d_ooi_cat.fits")            # X_IMAGE -> 1-based, converted
    ldac = read_catalog("ccd01.ldac")                   # header in meta["image_header"]

Notes for real data:

- Positions are 0-based (x = column) inside the package. SExtractor's ``X_IMAGE``,
  ``Y_IMAGE``, ``XWIN_IMAGE``, ``YWIN_IMAGE`` (and PSFEx/PIFF-style FITS conventions) are
  1-based: :func:`read_catalog` recognises those names and subtracts 1; for plain ``x``,
  ``y`` columns say ``one_based=True`` (``--one-based``) when they follow the FITS convention.
- A SExtractor ``FLAGS`` column is kept as ``flags``; ``SNR_WIN`` or ``FLUX_AUTO /
  FLUXERR_AUTO`` as ``snr``.
- ``LDAC_IMHEAD`` is SExtractor's image header, one cell of ``TDIM (80, N)`` cards: it is
  read with its ``SATURATE``, ``GAIN`` and WCS (TPV included), without a warning.
- A non-standard FITS header (e.g. ESO's ``ESO-LOG`` cards) is read with a
  :class:`FITSHeaderWarning`, never refused; a truncated file is.
- With a celestial WCS in the image (or LDAC) header, positions convert to and from
  (RA, Dec) (:func:`celestial_wcs`, :func:`pixel_to_sky`, :func:`sky_to_pixel`).
- :func:`draw_psf` draws a model's PSF at exact positions (the stamp's centre pixel
  ``floor(x + 0.5)``), :func:`extrapolation_flags` flags positions outside the stars' convex
  hull or farther from any star than 3 times their median spacing, and
  :func:`write_psf_stamps` writes the PSFs of a galaxy catalogue to one file.
"""

from .._files import InputError
from ._catalog import CatalogColumnWarning, read_catalog, write_catalog_rows, write_ldac
from ._draw import draw_psf, extrapolation_flags
from ._image import FITSHeaderWarning, read_image
from ._psf_stamps import read_psf_stamps, write_psf_stamps
from ._sextractor import (
    DEFAULT_SEXTRACTOR_CONFIG,
    DEFAULT_SEXTRACTOR_PARAMS,
    ProgramError,
    ProgramNotFoundError,
    find_program,
    run_psfex,
    run_sextractor,
    write_sextractor_config,
)
from ._wcs import celestial_wcs, pixel_to_sky, sky_to_pixel

__all__ = [
    "CatalogColumnWarning",
    "DEFAULT_SEXTRACTOR_CONFIG",
    "DEFAULT_SEXTRACTOR_PARAMS",
    "FITSHeaderWarning",
    "InputError",
    "ProgramError",
    "ProgramNotFoundError",
    "celestial_wcs",
    "draw_psf",
    "extrapolation_flags",
    "find_program",
    "pixel_to_sky",
    "read_catalog",
    "read_image",
    "read_psf_stamps",
    "run_psfex",
    "run_sextractor",
    "write_sextractor_config",
    "sky_to_pixel",
    "write_catalog_rows",
    "write_ldac",
    "write_psf_stamps",
]
