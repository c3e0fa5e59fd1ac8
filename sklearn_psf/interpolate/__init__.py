"""Interpolation schemes of Berge et al. (2012) as scikit-learn regressors.

Each regressor maps star positions ``X`` (n_samples, n_features) to values ``y``
(n_samples,) or (n_samples, n_targets), e.g. PCA coefficients of the stars.
"""

from ._base import (
    DuplicateStarsWarning,
    FewStarsWarning,
    RankDeficientWarning,
    ShortRangeWarning,
)
from ._delaunay import DelaunayRegressor
from ._exposure_kriging import ExposureKrigingRegressor
from ._kriging import KrigingRegressor
from ._variogram import (
    exponential_variogram,
    gaussian_variogram,
    spherical_variogram,
    variogram_models,
)
from ._polynomial import ChebyshevRegressor, PolynomialRegressor
from ._rbf import RBFRegressor
from ._scaler import IsotropicScaler
from ._shepard import ShepardRegressor

__all__ = [
    "ChebyshevRegressor",
    "DelaunayRegressor",
    "DuplicateStarsWarning",
    "ExposureKrigingRegressor",
    "FewStarsWarning",
    "IsotropicScaler",
    "KrigingRegressor",
    "PolynomialRegressor",
    "RBFRegressor",
    "RankDeficientWarning",
    "ShepardRegressor",
    "ShortRangeWarning",
    "exponential_variogram",
    "gaussian_variogram",
    "spherical_variogram",
    "variogram_models",
]
