"""Diagnostics of PSF models: ellipticity correlation functions, scorers, lensing systematics."""

from ._correlation import CorrelationResult, EmptyBinsWarning, ellipticity_correlation, rho1
from ._systematics import (
    DEFAULT_COSMOLOGY,
    ELL_RANGE,
    SURVEYS,
    RequirementCurves,
    hankel_xi_to_cl,
    requirement_curves,
    shear_bias_bound,
    shear_cl,
    sigma_sys2,
    sigma_sys2_from_cl,
    survey_requirement,
    survey_table,
)

__all__ = [
    "CorrelationResult",
    "DEFAULT_COSMOLOGY",
    "ELL_RANGE",
    "EmptyBinsWarning",
    "RequirementCurves",
    "SURVEYS",
    "ellipticity_correlation",
    "hankel_xi_to_cl",
    "requirement_curves",
    "rho1",
    "shear_bias_bound",
    "shear_cl",
    "sigma_sys2",
    "sigma_sys2_from_cl",
    "survey_requirement",
    "survey_table",
]
