"""The PSF model: a stamp basis, outlier rejection and an interpolator of coefficients."""

from ._defaults import (
    make_default_basis,
    make_default_interpolator,
    make_paper_basis,
    make_paper_interpolator,
)
from ._psf_model import PSFModel, UnusableStarsWarning

__all__ = [
    "PSFModel",
    "UnusableStarsWarning",
    "make_default_basis",
    "make_default_interpolator",
    "make_paper_basis",
    "make_paper_interpolator",
]
