"""
=====================================
A miniature of the paper's comparison
=====================================

``sklearn-psf compare`` runs the study of Bergé et al. (2012): every interpolation scheme on
many simulated PSF fields, evaluated at the galaxy-PSFs, then a report with the paper's
figures and its findings checked against the numbers. This example runs the same code
(:func:`sklearn_psf.study.compare.run_study` and :func:`sklearn_psf.study.report.write_report`)
on two small simulations and three schemes, next to the ``oracle``: the best linear unbiased
predictor with each simulation's true covariance and noise, the optimum no scheme can beat on
average. The conclusions of a study this small are not significant (the report flags every
verdict as underpowered): the paper used 50 simulations of 1000 stars each.
"""

# %%
# Run the study
# -------------
# Simulation ``i`` uses the ``i``-th child of ``numpy.random.SeedSequence(random_state)``, so
# the same seed gives the same tables, whether run serially or in parallel (``n_jobs``).
import os
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
from matplotlib.ticker import LogLocator, NullFormatter, ScalarFormatter

from sklearn_psf.metrics import requirement_curves, survey_table
from sklearn_psf.study.compare import SimulationConfig, default_schemes, run_study
from sklearn_psf.study.plotting import plot_correlation_functions
from sklearn_psf.study.report import summarize, write_report

SIZE = os.environ.get("SKLEARN_PSF_EXAMPLE_SIZE", "full")
if SIZE == "small":
    config = SimulationConfig(n_stars=300, n_galaxies=600, image_shape=(1500, 2000))
    theta_bins = (0.3, 5.0, 6)  # arcmin: the image is 6.7 x 5 arcmin
else:
    config = SimulationConfig(n_stars=1000, n_galaxies=2000, image_shape=(7769, 10032))
    theta_bins = (0.5, 20.0, 10)

names = ("polynomial", "delaunay", "kriging")
schemes = {name: default_schemes()[name] for name in names}
result = run_study(config, schemes, n_simulations=2, random_state=0, theta_bins=theta_bins,
                   oracle=True)
scores = result.scores["simulation", "scheme", "e_rms", "e_rms_ratio", "rho1_mean_abs",
                       "sigma_sys2"]
for col in ("e_rms", "rho1_mean_abs", "sigma_sys2"):
    scores[col].format = ".2e"
print(scores)

# %%
# Summary over simulations
# ------------------------
# Medians and 16-84% ranges per scheme, as in the report's table; ``e_rms_ratio`` is each
# scheme's e rms over the oracle's on the same simulation.
metrics = ["e_rms", "e_rms_ratio", "coeff_rms", "rho1_mean_abs", "sigma_sys2"]
summary = summarize(result.scores, metrics=metrics)
columns = ["scheme"] + [f"{m}_median" for m in metrics]
for col in columns[1:]:
    summary[col].format = ".2e"
print(summary[columns])

# %%
# The correlation figure (fig_cor)
# --------------------------------
# Input (black), model (red) and residual (green, D1) correlation functions, mean over the
# simulations with their spread, and the D1 limits for sigma_sys^2 = 1e-5, 1e-6, 1e-7
# (dotted) once ``result.requirements`` is set, as the command line does.
curves = requirement_curves(result.theta)
result.requirements = dict(zip(curves.levels, curves.d1_limit))
result.surveys = survey_table()
fig = plot_correlation_functions(result, list(names))
for ax in fig.axes:  # legible at page width: ticks at 1, 2, 5 x 10^k, larger level labels
    ax.xaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
    ax.xaxis.set_major_formatter(ScalarFormatter())
    ax.xaxis.set_minor_formatter(NullFormatter())
    for text in ax.texts:
        text.set_fontsize(8)
plt.figure(fig)  # the study's figures are built outside pyplot: hand it to pyplot
plt.show()

# %%
# The report
# ----------
# :func:`~sklearn_psf.study.report.write_report` writes the tables (CSV, FITS), the figures whose
# data the result holds (here only the correlation figure is asked for; the maps need a grid
# configuration, the S/N and density figures their studies) and ``report.md``, which checks
# the paper's findings against these numbers. Findings whose study was not run are reported
# as such.
with tempfile.TemporaryDirectory() as folder:
    paths = write_report(result, folder, figures={"fig_cor"})
    print("\n".join(sorted(p.name for p in paths)))
    report = Path(folder, "report.md").read_text()
findings = report[report.index("## The paper's findings"):]
print(findings[:findings.index("\n## ", 5)])
