"""
======================================================
Validate a PSFEx model and ours on the same stars
======================================================

Whether switching from PSFEx (or PIFF) to this package pays shows on stars that no model was
fitted on. :func:`~sklearn_psf.validation.validate_models` (``sklearn-psf validate`` on the
command line) reads each model with its own reader (PSFEx ``.psf`` files with GalSim's
``galsim.des.DES_PSFEx``, PIFF files with ``piff.read``), predicts the PSF at the reserved
stars and measures the same residuals for all: the stars' minus the models' ellipticity and
size, the chi^2 of each star against the model in the star's noise, and rho1 to rho5.

PSFEx itself is not a Python package; here its model, each pixel of the PSF a polynomial of
degree 2 of the position (PSFEx's ``PSFVAR_DEGREES 2`` with a pixel basis), is fitted by
least squares and written in PSFEx's format with :func:`~sklearn_psf.validation.write_psfex`.
``benchmarks/bench_validate.py`` runs the real SExtractor and PSFEx when they are installed.
"""

# %%
# A simulated field: stars to fit, stars to reserve
# -------------------------------------------------
import os
import tempfile

import numpy as np

from sklearn_psf import PSFModel, make_psf_field
from sklearn_psf.model import save_model
from sklearn_psf.preprocessing import StampNormalizer
from sklearn_psf.validation import (plot_model_comparison, psfex_terms, validate_models,
                                    write_psfex)

SIZE = os.environ.get("SKLEARN_PSF_EXAMPLE_SIZE", "full")
n_fit, n_reserved, shape = (200, 100, (1500, 1500)) if SIZE == "small" else \
    (800, 200, (4000, 4000))
field = make_psf_field(n_stars=n_fit + n_reserved, n_galaxies=0, image_shape=shape,
                       snr=100.0, random_state=3)
stamps, weights, _ = field.star_stamps(return_weights=True)
X = np.column_stack([field.stars["x"], field.stars["y"]])
reserved, fit = np.arange(n_reserved), np.arange(n_reserved, len(X))
folder = tempfile.mkdtemp()

# %%
# Two models of the fitted stars, as files
# ----------------------------------------
# This package's default model, saved as a model file; and PSFEx's polynomial model of the
# same stars' normalised stamps. PSFEx's polynomial takes 1-based ``X_IMAGE``, ``Y_IMAGE``
# (hence ``X + 1``); :class:`~sklearn_psf.validation.PSFExModel` converts the package's
# 0-based positions.
ours = PSFModel().fit(X[fit], stamps[fit], weights=weights[fit])
save_model(ours, os.path.join(folder, "ours.fits"))

s = field.stamp_size
zero, scale = ((shape[1] + 1) / 2, (shape[0] + 1) / 2), (float(shape[1]), float(shape[0]))
terms = psfex_terms(X[fit] + 1, 2, zero, scale)
planes = np.linalg.lstsq(terms, StampNormalizer().fit_transform(stamps[fit]), rcond=None)[0]
write_psfex(os.path.join(folder, "ccd.psf"), planes.reshape(-1, s, s), zero, scale)

# %%
# One table
# ---------
# ``rank`` orders the models by chi^2 per degree of freedom (1: the closest to the stars; a
# model as good as the noise allows has chi^2/dof near 1). ``e_rms`` and ``dsigma_rms``
# include the stars' own noise, the same for both models.
table, results = validate_models(
    X[reserved], stamps[reserved],
    {"sklearn_psf": os.path.join(folder, "ours.fits"),
     "PSFEx-format polynomial": os.path.join(folder, "ccd.psf")},
    weights=weights[reserved])
table["model", "kind", "rank", "chi2_dof", "e_rms", "dsigma_rms", "rho1_mean_abs"].pprint(
    max_width=140)

# %%
# The simulation knows the true PSF: the ranking can be checked against the models' true
# ellipticity errors at the reserved stars.
from sklearn_psf.measure import adaptive_moments
from sklearn_psf.validation import load_psf_model

truth = adaptive_moments(np.asarray(field.stars["stamp"])[reserved])
for name, path in (("sklearn_psf", "ours.fits"), ("PSFEx-format polynomial", "ccd.psf")):
    m = adaptive_moments(load_psf_model(os.path.join(folder, path), s).predict(X[reserved]))
    err = np.hypot(np.asarray(m["e1"]) - truth["e1"], np.asarray(m["e2"]) - truth["e2"])
    print(f"{name}: model - truth e rms {np.sqrt(np.mean(err ** 2)):.4f}")

# %%
# One set of figures
# ------------------
# rho1 to rho5, the residual distributions, the mean residual stamp in units of its noise and
# the residual whiskers across the field, one colour per model.
figures = plot_model_comparison(results)
