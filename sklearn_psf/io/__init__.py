"""Real data in and out: FITS images and star catalogues, star selection, model files.

To try the workflow without data, :func:`sklearn_psf.simulate.write_example_exposure` writes a
simulated exposure (image, weight HDU, SExtractor-like catalogue, galaxy positions, truth) to a
folder, and :func:`sklearn_psf.simulate.write_example_ldac` a FITS_LDAC catalogue with vignettes.

Running on a survey exposure
----------------------------
A single CCD of a survey exposure, e.g. a DECam or HSC calexp, usually comes as a
multi-extension (often tile-compressed ``.fits.fz``) FITS file with the science image, a
weight (inverse variance) or mask plane, and a SExtractor catalogue::

    # DECam community-pipeline CCD: HDU 'SCI' (or index 1), its weight in 'WGT'
    sklearn-psf fit c4d_ooi.fits.fz --hdu 1 --weight-hdu 2 \\
        --stars c4d_ooi_cat.fits --one-based --interpolator kriging -o ccd01_psf.fits
    # positions of galaxies (0-based x, y columns, or SExtractor X_IMAGE/Y_IMAGE)
    sklearn-psf predict ccd01_psf.fits --positions galaxies.fits -o ccd01_galaxy_psfs.fits

or, in Python::

    from sklearn_psf.io import read_image, read_catalog
    from sklearn_psf.exposure import extract_star_stamps
    from sklearn_psf.validation import fit_and_validate

    image, weight, header = read_image("c4d_ooi.fits.fz", hdu=1, weight_hdu=2)
    stars = read_catalog("c4d_ooi_cat.fits")            # X_IMAGE -> 1-based, converted
    cut = extract_star_stamps(image, stars, 25, weight=weight,
                              saturation=header.get("SATURATE"))
    model, residuals, summary = fit_and_validate(cut.positions, cut.stamps, reserve=0.2,
                                                 random_state=0)
    model.save("ccd01_psf.fits", residuals=residuals, summary=summary)

Notes for real data:

- Positions are 0-based (x = column) inside the package. SExtractor's ``X_IMAGE``,
  ``Y_IMAGE``, ``XWIN_IMAGE``, ``YWIN_IMAGE`` (and PSFEx/PIFF-style FITS conventions) are
  1-based: :func:`read_catalog` recognises those names and subtracts 1; for plain ``x``,
  ``y`` columns say ``one_based=True`` (``--one-based``) when they follow the FITS convention.
- A SExtractor ``FLAGS`` column (non-zero: blended, saturated, truncated) skips a star;
  ``SNR_WIN`` or ``FLUX_AUTO / FLUXERR_AUTO`` is kept as ``snr``.
- Without a catalogue, :func:`find_stars` selects stars on the flux-radius locus; pass the
  ``SATURATE`` level of the header (read automatically by the command line).
- The weight HDU masks bad pixels (zero weight): stars with a masked pixel in their core are
  skipped; masked pixels in the wings are set to the background.
- One model per CCD: PSF variations are not continuous across chip gaps
  (``sklearn-psf fit mef.fits --hdu all`` fits every CCD of a multi-extension file).
- A non-standard FITS header (e.g. ESO's ``ESO-LOG`` cards) is read with a
  :class:`FITSHeaderWarning`, never refused; a truncated file is.

PSFEx's input: a catalogue with vignettes, no image
---------------------------------------------------
A SExtractor FITS_LDAC catalogue of every detection with ``VIGNET`` stamps is enough::

    sklearn-psf fit --stars ccd01.ldac -o ccd01_psf.fits
    sklearn-psf predict ccd01_psf.fits --positions galaxies.cat --centered -o psfs.fits

or, in Python, in one call (:func:`sklearn_psf.exposure.fit_exposure`, what ``fit`` runs)::

    fit = fit_exposure(catalog="ccd01.ldac")            # model, residuals, summary, report()

or step by step::

    stars = read_catalog("ccd01.ldac")                  # header in meta["image_header"]
    keep, counts = select_stars(stars, saturation=stars.meta["image_header"]["SATURATE"])
    cut = extract_vignettes(stars[keep])                # -1e30 pixels -> weight 0
    # (fit_exposure also masks the neighbours' pixels: neighbour_masks(stars, rows, side))
    model, residuals, summary = fit_and_validate(cut.positions, cut.stamps,
                                                 weights=cut.weights)
    psf = draw_psf(model, [[1021.37, 88.62]], centered=True, oversampling=3)

- :func:`select_stars` is the one star selector (:func:`find_stars` applies it to the
  sources it measures): flags, S/N, saturation, isolation, then the size-magnitude locus of
  ``FLUX_RADIUS`` (the primary point-source test), ``SPREAD_MODEL``/``CLASS_STAR`` only where
  they agree with the locus; every rejection is counted by reason, and too few stars raise an
  error naming the parameter that relaxes each cut.
- ``LDAC_IMHEAD`` is SExtractor's image header, one cell of ``TDIM (80, N)`` cards: it is
  read with its ``SATURATE``, ``GAIN`` and WCS (TPV included), without a warning.
- Vignette centre: pixel ``round(X_IMAGE)`` (1-based), i.e. ``floor(x + 0.5)`` of the
  0-based ``x``, at index ``side // 2`` of every stamp in the package, of odd or even side
  (see :func:`extract_vignettes`); :func:`draw_psf` shifts the model's PSF to the exact
  position.
- With a celestial WCS in the image (or LDAC) header, ``fit`` measures rho1-rho5 in arcmin
  and ``predict --radec`` takes (RA, Dec) (:func:`celestial_wcs`, :func:`sky_to_pixel`).
- ``predict`` flags extrapolated rows (:func:`extrapolation_flags`: outside the stars'
  convex hull, or farther from any star than 3 times their median spacing).
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
