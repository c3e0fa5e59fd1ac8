"""Validating a PSF model on reserved stars, as PIFF does, and its diagnostic figures.

:func:`fit_and_validate` keeps a random (seeded) fraction of the stars out of the fit,
predicts the PSF at their positions and compares the shapes (adaptive-moment e1, e2, size)
of the observed, normalised reserved stars with the model's, summarises the residuals (mean,
rms) and measures rho1 to rho5 (Jarvis et al. 2016, :func:`sklearn_psf.metrics.rho_statistics`)
on them, then says whether the model can be trusted: the reserved stars' residuals against their
own measurement noise, against a constant PSF fitted on the same stars (a
:class:`PSFQualityWarning` when the model is no better than that constant or its residuals exceed
the noise), the components the basis kept and why, the Kriging range against the stars' spacing.
Optionally the interpolation scheme is chosen first by K-fold cross-validation on the fitted
stars with the correlation scorers. The figures (:func:`plot_stamp_residuals`,
:func:`plot_whiskers`, :func:`plot_rho_statistics`, :func:`plot_psf_maps`) are what
``sklearn-psf fit`` writes next to the model.

Models of other tools on the same stars: :func:`validate_models` measures the same residuals
(:func:`measure_residuals`: e1, e2, size, chi^2 in the stars' noise, rho1 to rho5) of this
package's models, PSFEx ``.psf`` files (:class:`PSFExModel`, drawn as GalSim's
``galsim.des.DES_PSFEx`` draws them, without GalSim) and PIFF files (:class:`PiffModel`, read with ``piff.read``) on one
set of reserved stars, in one table and one set of figures (:func:`plot_model_comparison`);
``sklearn-psf validate`` on the command line. PIFF is optional:
``pip install 'sklearn-psf[piff]'``.
"""

from ._figures import (
    plot_psf_maps,
    plot_residuals_against,
    plot_rho1,
    plot_rho_statistics,
    plot_stamp_residuals,
    plot_whiskers,
)
from ._fit import fit_and_validate
from ._compare import COMPARISON_COLUMNS, UNUSABLE_STAR_REASONS, validate_models
from ._compare_figures import plot_model_comparison
from ._paired import paired_comparison
from ._external import PiffModel, PSFExModel, load_psf_model, model_kind
from ._psfex import psfex_terms, to_psfex, write_psfex
from ._residuals import measure_residuals, rho_bins
from ._verdict import PSFQualityWarning

__all__ = ["fit_and_validate", "PSFQualityWarning",
           "plot_stamp_residuals",
           "plot_whiskers", "plot_rho1", "plot_rho_statistics", "plot_psf_maps",
           "plot_residuals_against", "COMPARISON_COLUMNS", "UNUSABLE_STAR_REASONS",
           "PSFExModel", "PiffModel", "load_psf_model", "measure_residuals", "model_kind",
           "plot_model_comparison", "psfex_terms", "rho_bins", "to_psfex", "validate_models",
           "write_psfex", "paired_comparison"]
