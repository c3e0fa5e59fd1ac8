"""sklearn_psf: point spread function modelling and interpolation as scikit-learn estimators."""

__version__ = "0.1.0.dev0"
