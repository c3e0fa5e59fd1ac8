"""Preprocessing of star stamps: cutting, normalisation, PCA basis and outlier rejection."""

from ._basis import FixedBasis
from ._normalize import CentringWarning, StampNormalizer, fourier_shift
from ._chi2 import ChiSquareOutlierDetector
from ._noise import estimate_pixel_weights
from ._outliers import IQROutlierDetector
from ._pca import StampPCA
from ._stamp_basis import (FIT_NO_CENTROID, FIT_NO_FLUX, FIT_OK, StampFit, StampFitWarning,
                           stamp_fwhm)
from ._superres import SuperResolvedPCA
from ._stamps import (
    CUT_BAD_POSITION,
    CUT_MASKED,
    CUT_NAN,
    CUT_OFF_EDGE,
    CUT_OK,
    cut_stamps,
)

__all__ = [
    "cut_stamps",
    "StampNormalizer",
    "CentringWarning",
    "fourier_shift",
    "FixedBasis",
    "IQROutlierDetector",
    "ChiSquareOutlierDetector",
    "StampPCA",
    "SuperResolvedPCA",
    "stamp_fwhm",
    "StampFit",
    "StampFitWarning",
    "estimate_pixel_weights",
    "FIT_OK",
    "FIT_NO_CENTROID",
    "FIT_NO_FLUX",
    "CUT_OK",
    "CUT_OFF_EDGE",
    "CUT_NAN",
    "CUT_MASKED",
    "CUT_BAD_POSITION",
]
