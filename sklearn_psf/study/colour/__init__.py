"""The colour study: what a galaxy's colour costs a position-only PSF model, and what a colour
dimension gives back.

In a broad filter a star's PSF depends on its spectrum (seeing as wavelength^-0.2, diffraction
as wavelength, differential chromatic refraction): a model fitted on stars and evaluated at
galaxies of other colours is biased in size by their colour difference.
:func:`run_colour_study` simulates fields with and without that dependence (the same stars,
PSF pattern and noise; :func:`~sklearn_psf.simulate.make_psf_field` with
``sources=SourceSettings(chromatic=True)``), fits the default
:class:`~sklearn_psf.model.PSFModel` on (x, y) and on (x, y, g-i), and measures the size
residual at the galaxies against their colour; :func:`plot_colour_study` draws it,
:func:`colour_report_section` writes the report's section.
"""

from ._run import (
    ColourStudyResult,
    colour_report_section,
    colour_simulation,
    galaxy_residuals,
    plot_colour_study,
    run_colour_study,
    write_colour_report,
)

__all__ = ["ColourStudyResult", "colour_report_section", "colour_simulation",
           "galaxy_residuals", "plot_colour_study", "run_colour_study", "write_colour_report"]
