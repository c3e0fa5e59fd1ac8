"""scikit-learn's estimator checks for the stamp transformers and the PSF model.

The interpolation regressors and the IQR detector run these checks in their own test files.
Here, every check a stamp estimator cannot pass is listed with its reason: the checks feed
2 to 10 arbitrary features, while a stamp must have a square number of pixels and positive
flux, and a fixed basis fixes the number of pixels. The same behaviours (clone, pickle,
pipelines, fit/transform consistency, untouched input) are tested on real stamps in
tests/test_preprocessing.py and tests/test_model.py.

Every public estimator (the package's, its subpackages') declares scikit-learn's
``_parameter_constraints``, checked by ``fit``: ``check_param_validation`` (which
``parametrize_with_checks`` does not run) runs here on each.
"""

import numpy as np
import pytest
from sklearn.base import BaseEstimator
from sklearn.utils.estimator_checks import check_param_validation, parametrize_with_checks

import sklearn_psf
from sklearn_psf import interpolate, model, preprocessing

from sklearn_psf import FixedBasis, PSFModel, StampNormalizer
from sklearn_psf.preprocessing import ChiSquareOutlierDetector, StampPCA, SuperResolvedPCA

_NOT_SQUARE = ("the check's data have a non-square number of pixels (2-10 features); "
               "stamps must be square to be centred")
_NOT_STAMPS = ("the check's targets are 1 to 5 values per sample, many zero or negative: "
               "PSFModel's y must be star stamps of at least 3x3 pixels and positive flux, to "
               "be fitted on a basis")
_FIXED_SIZE = ("the check's data have 1-10 features; a FixedBasis of 9-pixel components only "
               "projects 9-pixel stamps")

_STAMP_DATA_CHECKS = [
    "check_dict_unchanged", "check_dont_overwrite_parameters", "check_dtype_object",
    "check_estimators_dtypes", "check_estimators_fit_returns_self", "check_estimators_nan_inf",
    "check_estimators_overwrite_params", "check_estimators_pickle",
    "check_f_contiguous_array_estimator", "check_fit2d_1sample", "check_fit2d_predict1d",
    "check_fit_check_is_fitted", "check_fit_idempotent", "check_fit_score_takes_y",
    "check_methods_sample_order_invariance", "check_methods_subset_invariance",
    "check_n_features_in", "check_pipeline_consistency", "check_readonly_memmap_input",
    "check_transformer_data_not_an_array", "check_transformer_general",
    "check_transformer_preserve_dtypes",
]
_MODEL_CHECKS = [
    "check_dict_unchanged", "check_dont_overwrite_parameters", "check_dtype_object",
    "check_estimators_dtypes",
    "check_estimators_fit_returns_self", "check_estimators_nan_inf",
    "check_estimators_overwrite_params", "check_estimators_pickle",
    "check_f_contiguous_array_estimator", "check_fit2d_predict1d", "check_fit_check_is_fitted",
    "check_fit_idempotent", "check_fit_score_takes_y", "check_methods_sample_order_invariance",
    "check_methods_subset_invariance", "check_n_features_in", "check_n_features_in_after_fitting",
    "check_pipeline_consistency", "check_positive_only_tag_during_fit",
    "check_readonly_memmap_input", "check_regressor_data_not_an_array",
    "check_regressor_multioutput", "check_regressors_int", "check_regressors_no_decision_function",
    "check_regressors_train",
]
_POPULATION = ("the check's blobs are not standardised residuals: every row is as far from the "
               "noise law as the others, and with population=True the detector judges rows "
               "against each other, so none is an outlier (ChiSquareOutlierDetector("
               "population=False), the noise law alone, passes this check)")

EXPECTED_FAILURES = {
    "PSFModel": dict.fromkeys(_MODEL_CHECKS, _NOT_STAMPS),
    "StampNormalizer": dict.fromkeys(_STAMP_DATA_CHECKS, _NOT_SQUARE),
    "StampPCA": {  # its 1-sample error names n_samples, as the check wants
        **dict.fromkeys(set(_STAMP_DATA_CHECKS) - {"check_fit2d_1sample"}, _NOT_SQUARE),
        "check_n_features_in_after_fitting": _NOT_SQUARE,
        "check_positive_only_tag_during_fit": _NOT_SQUARE,
    },
    "SuperResolvedPCA": {  # as StampPCA
        **dict.fromkeys(set(_STAMP_DATA_CHECKS) - {"check_fit2d_1sample"}, _NOT_SQUARE),
        "check_n_features_in_after_fitting": _NOT_SQUARE,
        "check_positive_only_tag_during_fit": _NOT_SQUARE,
    },
    "ChiSquareOutlierDetector": dict.fromkeys(["check_outliers_fit_predict",
                                               "check_outliers_train"], _POPULATION),
    "FixedBasis": {
        **dict.fromkeys(_STAMP_DATA_CHECKS, _FIXED_SIZE),
        "check_fit2d_1feature": _FIXED_SIZE,
        "check_n_features_in_after_fitting": _FIXED_SIZE,
        "check_positive_only_tag_during_fit": _FIXED_SIZE,
    },
}


def _expected(estimator):
    if getattr(estimator, "population", True) is False:
        return {}
    return EXPECTED_FAILURES.get(type(estimator).__name__, {})


@parametrize_with_checks(
    [StampNormalizer(),
     FixedBasis(components=[[1.0, 2, 0, 0, 1, 0, 0, 0, 1], [0.0, 1, 3, 0, 0, 1, 2, 0, 0]]),
     StampPCA(), SuperResolvedPCA(), ChiSquareOutlierDetector(),
     ChiSquareOutlierDetector(population=False), PSFModel()],
    expected_failed_checks=_expected,
)
def test_sklearn_compatible(estimator, check):
    check(estimator)


def _public_estimators():
    """One instance of each public estimator class, by name (required arguments given)."""
    required = {"FixedBasis": (np.eye(9)[:2],), "FocalPlaneMapper": ([[0.0, 0.0], [1.0, 1.0]],)}
    classes = {}
    for module in (sklearn_psf, interpolate, preprocessing, model):
        for name in module.__all__:
            obj = getattr(module, name)
            if isinstance(obj, type) and issubclass(obj, BaseEstimator):
                classes[name] = obj
    return {name: cls(*required.get(name, ())) for name, cls in sorted(classes.items())}


PUBLIC_ESTIMATORS = _public_estimators()


def test_public_estimators_listed():
    # the 18 estimators of the subpackages' __all__ (a new one joins the checks below)
    assert len(PUBLIC_ESTIMATORS) == 18
    assert {"KrigingRegressor", "StampPCA", "SuperResolvedPCA", "PSFModel",
            "PooledPSFModel", "ChiSquareOutlierDetector"} <= set(PUBLIC_ESTIMATORS)


@pytest.mark.parametrize("name", sorted(PUBLIC_ESTIMATORS))
def test_parameter_constraints_cover_parameters(name):
    estimator = PUBLIC_ESTIMATORS[name]
    constraints = type(estimator).__dict__.get("_parameter_constraints")
    assert constraints is not None, f"{name} declares no _parameter_constraints"
    assert set(constraints) == set(estimator.get_params(deep=False))


@pytest.mark.parametrize("name", sorted(PUBLIC_ESTIMATORS))
def test_param_validation(name):
    check_param_validation(name, PUBLIC_ESTIMATORS[name])
