"""Public names of :mod:`sklearn_psf.study.plotting` under their historical path."""

from .study.plotting import *  # noqa: F403
from .study.plotting import __all__  # noqa: F401
