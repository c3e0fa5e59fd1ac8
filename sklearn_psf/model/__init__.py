"""The PSF model: a stamp basis, outlier rejection and an interpolator of coefficients."""

from ._defaults import (
    INTERPOLATORS,
    make_default_basis,
    make_interpolator,
    make_default_interpolator,
    make_paper_basis,
    make_paper_interpolator,
)
from ._file import MODEL_FORMAT, MODEL_FORMAT_VERSION, read_model_validation, save_model
from ._galsim import to_galsim
from ._pooled import FocalPlaneMapper, PerExposurePSFModel, PooledPSFModel
from ._psf_model import PSFModel, UnusableStarsWarning, load_model

__all__ = [
    "FocalPlaneMapper",
    "MODEL_FORMAT",
    "MODEL_FORMAT_VERSION",
    "PSFModel",
    "PerExposurePSFModel",
    "PooledPSFModel",
    "UnusableStarsWarning",
    "load_model",
    "make_default_basis",
    "make_default_interpolator",
    "make_interpolator",
    "make_paper_basis",
    "make_paper_interpolator",
    "read_model_validation",
    "save_model",
    "to_galsim",
]
