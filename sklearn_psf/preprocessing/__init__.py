"""Preprocessing of star stamps: cutting, normalisation, PCA basis and outlier rejection."""

from ._basis import FixedBasis
from ._normalize import CentringWarning, StampNormalizer, fourier_shift
from ._outliers import IQROutlierDetector
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
    "CUT_OK",
    "CUT_OFF_EDGE",
    "CUT_NAN",
    "CUT_MASKED",
    "CUT_BAD_POSITION",
]
