"""From an exposure's files to a validated PSF model, and back.

:mod:`sklearn_psf.io` reads and writes the files; this subpackage holds what lies between them
and the model: the exposure read for a fit (:func:`read_exposure`), the star selection
(:func:`select_stars` on a catalogue, :func:`find_stars` on an image, the neighbours' masks),
the stars' stamps (:func:`extract_star_stamps` from an image, :func:`extract_vignettes` from a
catalogue's ``VIGNET``), the whole of ``sklearn-psf fit`` as one call (:func:`fit_exposure`),
the model back at a catalogue's positions (:func:`predict_catalog`, ``sklearn-psf
predict``) and the K-fold cross-validation of a catalogue's stars
(:func:`cross_validate_catalog`).

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

or, in Python, in one call each::

    from sklearn_psf.exposure import fit_exposure, predict_catalog

    fit = fit_exposure("c4d_ooi.fits.fz", "c4d_ooi_cat.fits", hdu=1, weight_hdu=2,
                       one_based=True)                  # model, summary, report()
    fit.model.save("ccd01_psf.fits", residuals=fit.residuals, summary=fit.summary)
    psfs = predict_catalog("ccd01_psf.fits", "galaxies.fits")   # a table: psf, e1, e2, ...

or step by step::

    from sklearn_psf.exposure import extract_star_stamps
    from sklearn_psf.io import read_catalog, read_image
    from sklearn_psf.validation import fit_and_validate

    image, weight, header = read_image("c4d_ooi.fits.fz", hdu=1, weight_hdu=2)
    stars = read_catalog("c4d_ooi_cat.fits")            # X_IMAGE -> 1-based, converted
    cut = extract_star_stamps(image, stars, 25, weight=weight,
                              saturation=header.get("SATURATE"))
    model, residuals, summary = fit_and_validate(cut.positions, cut.stamps, reserve=0.2,
                                                 random_state=0)

Notes for real data:

- A SExtractor ``FLAGS`` column (non-zero: blended, saturated, truncated) skips a star.
- Without a catalogue, :func:`find_stars` selects stars on the size-magnitude locus; pass the
  ``SATURATE`` level of the header (:func:`fit_exposure` reads it).
- The weight HDU masks bad pixels (zero weight): stars with a masked pixel in their core are
  skipped; masked pixels in the wings are set to the background.
- One model per CCD: PSF variations are not continuous across chip gaps
  (``sklearn-psf fit mef.fits --hdu all`` fits every CCD of a multi-extension file).

PSFEx's input: a catalogue with vignettes, no image
---------------------------------------------------
A SExtractor FITS_LDAC catalogue of every detection with ``VIGNET`` stamps is enough::

    sklearn-psf fit --stars ccd01.ldac -o ccd01_psf.fits
    sklearn-psf predict ccd01_psf.fits --positions galaxies.cat --centered -o psfs.fits

or, in Python, in one call (what ``fit`` runs)::

    fit = fit_exposure(catalog="ccd01.ldac")            # model, residuals, summary, report()

or step by step::

    from sklearn_psf.exposure import extract_vignettes, select_stars
    from sklearn_psf.io import draw_psf, read_catalog

    stars = read_catalog("ccd01.ldac")                  # header in meta["image_header"]
    keep, counts = select_stars(stars, saturation=stars.meta["image_header"]["SATURATE"])
    cut = extract_vignettes(stars[keep])                # -1e30 pixels -> weight 0
    # (fit_exposure also masks the neighbours' pixels: neighbour_masks(stars, rows, side))
    model, residuals, summary = fit_and_validate(cut.positions, cut.stamps,
                                                 weights=cut.weights)
    psf = draw_psf(model, [[1021.37, 88.62]], centered=True, oversampling=3)

- :func:`select_stars` is the one star selector (:func:`find_stars` applies it to the
  sources it measures): flags, S/N, saturation, crowding, then the size-magnitude locus (the
  primary point-source test), ``SPREAD_MODEL``/``CLASS_STAR`` only where they agree with the
  locus; every rejection is counted by reason, and too few stars raise an error naming the
  parameter that relaxes each cut (:class:`SelectionCuts` holds them for
  :func:`fit_exposure`).
- Vignette centre: pixel ``round(X_IMAGE)`` (1-based), i.e. ``floor(x + 0.5)`` of the
  0-based ``x``, at index ``side // 2`` of every stamp in the package, of odd or even side
  (see :func:`extract_vignettes`); :func:`~sklearn_psf.io.draw_psf` shifts the model's PSF to
  the exact position.
- ``predict`` (:func:`predict_catalog`) flags extrapolated rows
  (:func:`~sklearn_psf.io.extrapolation_flags`) and takes (RA, Dec) with the fit's WCS.
"""

from ._crossval import CrossValidation, cross_validate_catalog
from ._fit import ExposureFit, SelectionCuts, StarSelectionError, fit_exposure
from ._inputs import ExposureInputs, key_columns, read_exposure
from ._predict import predict_catalog
from ._select import (PSFEX_FLAG_MASK, SELECTION_OPTIONS, SELECTION_REASONS, neighbour_masks,
                      saturation_level, select_stars)
from ._stars import REJECTION_REASONS, StarStamps, extract_star_stamps, find_stars
from ._vignettes import VIGNET_MASKED, extract_vignettes

__all__ = [
    "CrossValidation",
    "ExposureFit",
    "ExposureInputs",
    "SelectionCuts",
    "StarSelectionError",
    "cross_validate_catalog",
    "fit_exposure",
    "key_columns",
    "read_exposure",
    "PSFEX_FLAG_MASK",
    "REJECTION_REASONS",
    "SELECTION_OPTIONS",
    "SELECTION_REASONS",
    "StarStamps",
    "VIGNET_MASKED",
    "extract_star_stamps",
    "extract_vignettes",
    "find_stars",
    "neighbour_masks",
    "predict_catalog",
    "saturation_level",
    "select_stars",
]
