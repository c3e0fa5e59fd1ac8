"""
=====================================================
Ellipticity correlations and weak-lensing systematics
=====================================================

A PSF model is judged by what its errors do to a cosmic-shear measurement. The paper's
diagnostics, on one simulation, for Kriging and a degree-5 polynomial:

- the ellipticity correlation function xi(theta) = <e(r) e*(r + theta)> of the true PSF, of
  the model, and of the residuals e_true - e_model (Rowe's D1, or rho1);
- the bound on the shear correlation bias implied by D1 (:func:`~sklearn_psf.metrics.shear_bias_bound`),
  turned into the systematics variance sigma_sys^2 of Amara & Réfrégier (2008)
  (:func:`~sklearn_psf.metrics.sigma_sys2`);
- the D1 that would give sigma_sys^2 = 1e-5, 1e-6, 1e-7 (:func:`~sklearn_psf.metrics.requirement_curves`),
  and the tolerable sigma_sys^2 of surveys (:func:`~sklearn_psf.metrics.survey_table`).
"""

# %%
# Fit two schemes on one simulation
# ---------------------------------
import os

import matplotlib.pyplot as plt
from matplotlib.ticker import LogLocator, NullFormatter, ScalarFormatter
import numpy as np

from sklearn_psf import adaptive_moments, make_psf_field
from sklearn_psf.study.compare import default_schemes, make_psf_model
from sklearn_psf.metrics import (
    ellipticity_correlation,
    requirement_curves,
    rho1,
    shear_bias_bound,
    sigma_sys2,
    survey_table,
)
from sklearn_psf.study.plotting import KIND_COLORS

SIZE = os.environ.get("SKLEARN_PSF_EXAMPLE_SIZE", "full")
if SIZE == "small":
    image_shape, n_stars, n_galaxies = (2000, 2600), 500, 1500
    min_sep, max_sep, nbins = 0.3, 6.0, 8  # arcmin
else:
    image_shape, n_stars, n_galaxies = (7769, 10032), 1000, 2000
    min_sep, max_sep, nbins = 0.5, 20.0, 10

field = make_psf_field(n_stars=n_stars, n_galaxies=n_galaxies, image_shape=image_shape,
                       random_state=4)
stamps, flags = field.star_stamps()
X_stars = np.column_stack([field.stars["x"], field.stars["y"]]).astype(float)[flags == 0]
X_gal = np.column_stack([field.galaxies["x"], field.galaxies["y"]]).astype(float)
e1_true, e2_true = np.asarray(field.galaxies["e1"]), np.asarray(field.galaxies["e2"])
theta_pos = X_gal * field.pixel_scale / 60.0  # positions in arcmin

schemes = default_schemes()
model_e = {}
measured = np.asarray(field.galaxies["moments_flag"]) == 0  # true PSF measured
for name in ("kriging", "polynomial"):
    model = make_psf_model(schemes[name], reference=field.reference)
    model.fit(X_stars, stamps[flags == 0])
    moments = adaptive_moments(model.predict(X_gal))
    measured &= np.asarray(moments["flag"]) == 0
    model_e[name] = np.asarray(moments["e1"]), np.asarray(moments["e2"])

# keep the galaxy-PSFs whose true and model stamps were all measured (flag 0)
print(f"{measured.sum()} of {len(X_gal)} galaxy-PSFs measured")
theta_pos, e1_true, e2_true = theta_pos[measured], e1_true[measured], e2_true[measured]
model_e = {name: (e1[measured], e2[measured]) for name, (e1, e2) in model_e.items()}

# %%
# Correlation functions
# ---------------------
# Positions in arcmin, so that the separations are in arcmin. The input and model
# correlations are close to each other; the residual correlation D1 is orders of magnitude
# smaller.
corr = {"input": ellipticity_correlation(theta_pos, e1_true, e2_true, min_sep=min_sep,
                                         max_sep=max_sep, nbins=nbins)}
for name, (e1, e2) in model_e.items():
    corr[f"model {name}"] = ellipticity_correlation(theta_pos, e1, e2, min_sep=min_sep,
                                                    max_sep=max_sep, nbins=nbins)
    corr[f"D1 {name}"] = rho1(theta_pos, e1_true, e2_true, e1, e2, min_sep=min_sep,
                              max_sep=max_sep, nbins=nbins)
theta = np.asarray(corr["input"].theta_nominal)

# %%
# Implied systematics
# -------------------
# :math:`|\delta\xi_+| \le |D_1| \, (R_\mathrm{PSF} / R_\mathrm{gal})^4 / P_\gamma^2` with
# :math:`P_\gamma = 1.84` and :math:`R_\mathrm{PSF} / R_\mathrm{gal} = 2/3` (the defaults), then sigma_sys^2 is the integral of the bias's power
# spectrum. Compare with the surveys' requirements.
implied = {name: sigma_sys2(theta, shear_bias_bound(np.asarray(corr[f"D1 {name}"].xi)))
           for name in model_e}
for name, value in implied.items():
    print(f"{name:>10}: mean |D1| = {np.mean(np.abs(corr[f'D1 {name}'].xi)):.2e}, "
          f"implied sigma_sys^2 = {value:.2e}")

surveys = survey_table()
for name, value in implied.items():
    surveys[f"{name} ok"] = [bool(value <= req) for req in surveys["sigma_sys2"]]
surveys["sigma_sys2"].format = ".1e"
print(surveys)

# %%
# The figure
# ----------
# :math:`|\xi|` on log axes (open symbols where the mean is negative), with the D1 limits of three
# sigma_sys^2 levels (dotted). A residual curve below a dotted line meets that level on
# these scales. A small field gives noisy correlations at large separations.
curves = requirement_curves(theta)
fig, axes = plt.subplots(1, 2, figsize=(10, 4.2), sharey=True, layout="constrained")
for ax, name in zip(axes, model_e):
    for label, kind in (("input", "input"), (f"model {name}", "model"), (f"D1 {name}", "residual")):
        xi = np.asarray(corr[label].xi)
        err = np.asarray(corr[label].sigma_xi)
        color = KIND_COLORS[kind]
        ax.errorbar(theta, np.abs(xi), yerr=err, color=color, ls="-", label=kind)
        pos = xi > 0
        ax.scatter(theta[pos], xi[pos], color=color, s=16, zorder=3)
        ax.scatter(theta[~pos], -xi[~pos], facecolors="white", edgecolors=color, s=16, zorder=3)
    for level, limit in zip(curves.levels, curves.d1_limit):
        ax.plot(theta, limit, ":", color="gray")
        ax.annotate(rf"$\sigma_\mathrm{{sys}}^2 = 10^{{{np.log10(level):.0f}}}$",
                    (theta[0], limit[0]), fontsize=9, color="0.35", xytext=(0, 3),
                    textcoords="offset points", va="bottom")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.xaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
    ax.xaxis.set_major_formatter(ScalarFormatter())
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.set_xlabel(r"$\theta$ [arcmin]")
    ax.set_title(rf"{name}: $\sigma_\mathrm{{sys}}^2$ = {implied[name]:.1e}")
axes[0].set_ylabel(r"$|\xi(\theta)|$")
axes[0].legend(loc="lower left")
plt.show()
