"""From an exposure's files to a validated PSF model, and back.

:mod:`sklearn_psf.io` reads and writes the files; this subpackage holds what lies between them
and the model: the star selection (:func:`select_stars`, :func:`find_stars` on an image, the
neighbours' masks), the stars' stamps (:func:`extract_star_stamps` from an image,
:func:`extract_vignettes` from a catalogue's ``VIGNET``).
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
