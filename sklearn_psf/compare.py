"""Public names of :mod:`sklearn_psf.study.compare` under their historical path."""

from .study.compare import *  # noqa: F403
from .study.compare import __all__  # noqa: F401
from .study.compare import (  # noqa: F401
    ARCMIN,
    DEFAULT_MODEL,
    ORACLE,
    PARAM_GRIDS,
    FieldOracle,
    combine_results,
    example_stars,
    scale_study_configs,
    tune_schemes,
    tuned_schemes,
)
