"""sklearn_psf: point spread function modelling and interpolation as scikit-learn estimators.

The estimators a user reaches for first are importable from here; everything else lives in the
public subpackages (:mod:`sklearn_psf.interpolate`, :mod:`sklearn_psf.preprocessing`,
:mod:`sklearn_psf.measure`, :mod:`sklearn_psf.simulate`, :mod:`sklearn_psf.datasets`,
:mod:`sklearn_psf.metrics`, :mod:`sklearn_psf.compare`, :mod:`sklearn_psf.plotting`,
:mod:`sklearn_psf.report`).
"""

from ._version import __version__

from .datasets import load_default_reference
from .interpolate import (
    ChebyshevRegressor,
    DelaunayRegressor,
    KrigingRegressor,
    PolynomialRegressor,
    RBFRegressor,
    ShepardRegressor,
)
from .measure import adaptive_moments
from .model import PSFModel
from .preprocessing import (
    ChiSquareOutlierDetector,
    FixedBasis,
    IQROutlierDetector,
    StampNormalizer,
    StampPCA,
    cut_stamps,
)
from .simulate import make_psf_field

__all__ = [
    "ChebyshevRegressor",
    "ChiSquareOutlierDetector",
    "DelaunayRegressor",
    "FixedBasis",
    "IQROutlierDetector",
    "KrigingRegressor",
    "PSFModel",
    "PolynomialRegressor",
    "RBFRegressor",
    "ShepardRegressor",
    "StampNormalizer",
    "StampPCA",
    "adaptive_moments",
    "cut_stamps",
    "load_default_reference",
    "make_psf_field",
]
