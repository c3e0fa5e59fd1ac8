"""The paper's study, an application built on the library.

Bergé et al. (2012) compare interpolation schemes on simulated PSF fields. This subpackage
runs that comparison with the library (:mod:`sklearn_psf.interpolate`,
:mod:`sklearn_psf.preprocessing`, :mod:`sklearn_psf.measure`, :mod:`sklearn_psf.model`,
:mod:`sklearn_psf.metrics`, :mod:`sklearn_psf.simulate`, :mod:`sklearn_psf.datasets`) and is
used by the command line (:mod:`sklearn_psf.cli`); imports flow that way only.

- :mod:`sklearn_psf.study.compare`: a run is simulations x schemes (configurations, the
  schemes and the paper's PSF model, evaluation at the galaxy-PSFs, cross-validated
  hyperparameters, the optimal predictor on the same field).
- :mod:`sklearn_psf.study.report`: the report's sections (summaries, survey verdicts, the
  paper's findings, files, ``report.md``).
- :mod:`sklearn_psf.study.plotting`: the figures, by family.
- :mod:`sklearn_psf.study.exposures`: the multi-exposure study (per-exposure vs pooled models,
  sigma_sys^2 against the number of exposures, the Stage IV verdict).
"""
