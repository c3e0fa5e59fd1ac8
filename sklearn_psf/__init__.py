"""sklearn_psf: point spread function modelling and interpolation as scikit-learn estimators.

The estimators a user reaches for first are importable from here; everything else lives in the
public subpackages. The library: :mod:`sklearn_psf.interpolate`,
:mod:`sklearn_psf.preprocessing`, :mod:`sklearn_psf.measure`, :mod:`sklearn_psf.model`,
:mod:`sklearn_psf.metrics`, :mod:`sklearn_psf.simulate`, :mod:`sklearn_psf.datasets`,
:mod:`sklearn_psf.io`, :mod:`sklearn_psf.validation`; the paper's study built on it:
:mod:`sklearn_psf.study`; the command line on top: :mod:`sklearn_psf.cli`.

The names below are imported on first use (PEP 562), so that ``import sklearn_psf`` and the
command line's ``--help`` stay fast.
"""

import importlib

from ._version import __version__

#: Where each top-level name lives.
_WHERE = {
    "ChebyshevRegressor": "interpolate",
    "DelaunayRegressor": "interpolate",
    "KrigingRegressor": "interpolate",
    "PolynomialRegressor": "interpolate",
    "RBFRegressor": "interpolate",
    "ShepardRegressor": "interpolate",
    "ChiSquareOutlierDetector": "preprocessing",
    "FixedBasis": "preprocessing",
    "IQROutlierDetector": "preprocessing",
    "StampNormalizer": "preprocessing",
    "StampPCA": "preprocessing",
    "cut_stamps": "preprocessing",
    "adaptive_moments": "measure",
    "PSFModel": "model",
    "load_default_reference": "datasets",
    "make_psf_field": "simulate",
}

__all__ = sorted(_WHERE)


def __getattr__(name):
    if name in _WHERE:
        value = getattr(importlib.import_module(f".{_WHERE[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_WHERE))
