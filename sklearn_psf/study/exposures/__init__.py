"""The multi-exposure study: which regime, which model, how many exposures and stars reach
Stage IV.

The paper ends by proposing to combine exposures. :func:`run_exposure_study` simulates dithered
exposures of one field (:func:`~sklearn_psf.simulate.make_exposures`: a static optical pattern
plus an atmospheric one per exposure) over a sweep of regimes (atmospheric / static variance,
dither), fits per-exposure and pooled PSF models
(:class:`~sklearn_psf.model.PerExposurePSFModel`, :class:`~sklearn_psf.model.PooledPSFModel`)
and the exposure oracle, and measures sigma_sys^2 of the galaxy-PSF residual averaged over the
exposures against their number; :func:`plot_sigma_sys_vs_exposures` draws it with the survey
requirements, :func:`regime_summary` gives each regime's exponent with N, correlation between
exposures and ratio to the oracle, and :func:`exposure_report_section` writes the report with
each regime's verdict (the cheapest configuration that meets Stage IV, or the shortfall).
"""

from ._plot import plot_sigma_sys_vs_exposures
from ._report import (
    cheapest_configuration,
    exposure_report_section,
    regime_summary,
    write_exposure_report,
)
from ._run import (
    ExposureStudyResult,
    default_exposure_schemes,
    exposure_correlation,
    run_exposure_study,
)

__all__ = [
    "ExposureStudyResult",
    "cheapest_configuration",
    "default_exposure_schemes",
    "exposure_correlation",
    "exposure_report_section",
    "plot_sigma_sys_vs_exposures",
    "regime_summary",
    "run_exposure_study",
    "write_exposure_report",
]
