"""Diagnostics of PSF models: ellipticity correlation functions, scorers, lensing systematics."""

from ._correlation import CorrelationResult, EmptyBinsWarning, ellipticity_correlation, rho1
from ._rho import RHO_NAMES, rho_statistics
from ._scorers import (
    CoefficientRMSScorer,
    EllipticityRMSScorer,
    FlaggedStampsWarning,
    Rho1Scorer,
    SigmaSysScorer,
    ellipticity_residuals,
    make_coefficient_rms_scorer,
    make_ellipticity_rms_scorer,
    make_rho1_scorer,
    make_sigma_sys_scorer,
)
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
from ._wiener import WienerBaseline, wiener_filter_baseline

__all__ = [
    "CoefficientRMSScorer",
    "EllipticityRMSScorer",
    "FlaggedStampsWarning",
    "Rho1Scorer",
    "SigmaSysScorer",
    "WienerBaseline",
    "ellipticity_residuals",
    "make_coefficient_rms_scorer",
    "make_ellipticity_rms_scorer",
    "make_rho1_scorer",
    "make_sigma_sys_scorer",
    "wiener_filter_baseline",
    "CorrelationResult",
    "DEFAULT_COSMOLOGY",
    "ELL_RANGE",
    "EmptyBinsWarning",
    "RHO_NAMES",
    "RequirementCurves",
    "SURVEYS",
    "ellipticity_correlation",
    "hankel_xi_to_cl",
    "requirement_curves",
    "rho1",
    "rho_statistics",
    "shear_bias_bound",
    "shear_cl",
    "sigma_sys2",
    "sigma_sys2_from_cl",
    "survey_requirement",
    "survey_table",
]
