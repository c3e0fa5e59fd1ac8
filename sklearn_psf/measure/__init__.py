"""Measurement of PSF shapes: batched adaptive (Gaussian-weighted) moments, and
fixed-weight moments for undersampled stamps."""

from ._fourth import FOURTH_MOMENTS, fourth_moments
from ._moments import (
    FLAG_BAD_PIXELS,
    FLAG_DIVERGED,
    FLAG_MASKED,
    FLAG_MAX_ITER,
    FLAG_NO_FLUX,
    FLAG_OK,
    adaptive_moments,
    fixed_moments,
)

__all__ = [
    "adaptive_moments",
    "fourth_moments",
    "FOURTH_MOMENTS",
    "fixed_moments",
    "FLAG_OK",
    "FLAG_BAD_PIXELS",
    "FLAG_NO_FLUX",
    "FLAG_DIVERGED",
    "FLAG_MAX_ITER",
    "FLAG_MASKED",
]
