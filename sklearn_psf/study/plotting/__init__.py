"""Figures of the PSF interpolation study (Bergé et al. 2012, figures 1 to 11).

Every function builds a :class:`matplotlib.figure.Figure` with the object-oriented API (no
``pyplot`` state is created or changed), returns it and never shows it: save it with
``fig.savefig(path)``. The functions read the tables of
:class:`sklearn_psf.study.compare.StudyResult` (``scores``, ``correlations``, ``galaxies``) or any
object with the same attributes, so they also work on tables read back from disk.

Conventions shared by all figures

- A scheme has the same colour in every figure: :data:`SCHEME_COLORS` (the paper's black /
  red / green for polynomial / Delaunay / Kriging), other names get a stable colour from
  :func:`scheme_color`.
- Residuals are *model minus truth*.
- Quantities are named ``"e1"``, ``"e2"`` (ellipticity components) or ``"coeff0"`` ..
  ``"coeff3"`` (PCA coefficients, columns ``coeffs_true`` / ``coeffs_model``).
- When the data a figure needs are absent (no grid galaxy-PSFs, no S/N configurations, ...)
  the function raises :class:`MissingDataError`, a ``ValueError`` saying what is missing;
  :func:`sklearn_psf.study.report.write_report` catches it and notes the skipped figure.
- Correlation functions are drawn as ``|xi|`` on log-log axes; where the value (the mean over
  simulations) is negative the point is marked with an open circle, so that a sign change is
  never hidden by the absolute value.

The figures are grouped by family: example stamps (``_stamps``), maps of one simulation and
residual pairs (``_maps``), correlation functions and the S/N study (``_correlations``),
stellar density (``_density``) and the outlier study (``_outliers``).
"""

from ._common import KIND_COLORS, SCHEME_COLORS, MissingDataError, residual_component, scheme_color
from ._correlations import plot_correlation_functions, plot_snr_study
from ._density import density_groups, plot_density_boxplots, plot_density_stats
from ._maps import plot_component_maps, plot_ellipticity_maps, plot_residual_pairs
from ._outliers import plot_outlier_study
from ._stamps import plot_psf_examples

__all__ = [
    "SCHEME_COLORS",
    "KIND_COLORS",
    "MissingDataError",
    "scheme_color",
    "residual_component",
    "plot_psf_examples",
    "plot_ellipticity_maps",
    "plot_component_maps",
    "plot_residual_pairs",
    "plot_correlation_functions",
    "plot_snr_study",
    "density_groups",
    "plot_density_boxplots",
    "plot_density_stats",
    "plot_outlier_study",
]
