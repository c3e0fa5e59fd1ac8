"""Public names of :mod:`sklearn_psf.study.report` under their historical path."""

from .study.report import *  # noqa: F403
from .study.report import __all__  # noqa: F401
