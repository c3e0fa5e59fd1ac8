"""
==================================================
Many exposures: pooled and per-exposure PSF models
==================================================

The paper ends by proposing to combine exposures. Here several dithered exposures of one
field share a static optical PSF pattern, and each has its own atmospheric pattern
(:func:`~sklearn_psf.simulate.make_exposures`). We fit

- one :class:`~sklearn_psf.model.PSFModel` per exposure
  (:class:`~sklearn_psf.model.PerExposurePSFModel`, the paper's way), and
- a :class:`~sklearn_psf.model.PooledPSFModel`: one model on the stars of all exposures whose
  interpolation (:class:`~sklearn_psf.interpolate.ExposureKrigingRegressor`) has a static part
  shared by every exposure and an atmospheric part of each exposure's own, their variances and
  correlation lengths fitted by maximum likelihood,

with the exposure index passed as a third column of X. Then we follow the residual of the
galaxies' PSF, averaged over their exposures, as the number of exposures grows, and fit the
CCDs of one exposure in one model with focal-plane positions
(:class:`~sklearn_psf.model.FocalPlaneMapper`).
"""

# %%
# Simulate dithered exposures
# ---------------------------
# ``atmosphere_ratio`` is the rms of the atmospheric pattern over the static one's. The
# documentation builds this example at a reduced size.
import os
import tempfile
import warnings

import matplotlib.pyplot as plt
import numpy as np
from sklearn.pipeline import make_pipeline

from sklearn_psf.measure import adaptive_moments
from sklearn_psf.model import (
    FocalPlaneMapper,
    PerExposurePSFModel,
    PooledPSFModel,
    PSFModel,
    make_default_interpolator,
)
from sklearn_psf.simulate import make_exposures, make_psf_field

warnings.simplefilter("ignore")
SIZE = os.environ.get("SKLEARN_PSF_EXAMPLE_SIZE", "full")
small = SIZE == "small"
n_max = 6 if small else 10
exposures = make_exposures(n_max, n_stars=60 if small else 120, n_galaxies=200 if small else 600,
                           image_shape=(1500, 1500) if small else (3000, 3000),
                           atmosphere_ratio=0.5, dither=150.0, random_state=0)
X, stamps = exposures.star_data()
print(f"{len(exposures)} exposures, {len(X)} stars, X columns: x, y, exposure")

# %%
# Residuals averaged over the exposures
# -------------------------------------
# Each galaxy is seen in every exposure; a shape measured on N exposures averages their PSF
# errors. A per-exposure model fits each exposure independently: fitted once on all of them,
# its first N exposures are those of a study with N exposures.


def averaged_e_residual(model, n):
    X_gal, truth = exposures.galaxy_data(range(n))
    mom = adaptive_moments(model.predict(X_gal))
    de = np.column_stack([mom["e1"] - truth["e1"], mom["e2"] - truth["e2"]])
    return np.sqrt(np.nanmean(np.sum(np.nanmean(de.reshape(n, -1, 2), axis=0) ** 2, axis=1)))


counts = [1, 2, n_max // 2, n_max]
per_exposure = PerExposurePSFModel().fit(X, stamps)
rms = {"per-exposure": [averaged_e_residual(per_exposure, n) for n in counts], "pooled": []}
for n in counts:
    pooled = PooledPSFModel().fit(X[X[:, 2] < n], stamps[X[:, 2] < n])
    rms["pooled"].append(averaged_e_residual(pooled, n))

fig, ax = plt.subplots(figsize=(5.5, 4))
for name, values in rms.items():
    ax.plot(counts, values, "o-", label=name)
ax.set_xscale("log")
ax.set_xticks(counts, [str(n) for n in counts])
ax.minorticks_off()
ax.set_xlabel("number of exposures")
ax.set_ylabel("rms of the exposure-averaged e residual")
ax.legend()
fig.tight_layout()
for name, values in rms.items():
    print(name, " ".join(f"N={n}: {v:.4f}" for n, v in zip(counts, values)))

# %%
# What the pooled model learnt
# ----------------------------
# The fitted sills tell how much of each coefficient's variation the exposures share (the
# simulation puts 80% of the variance in the static pattern, ``atmosphere_ratio=0.5``).
# The model saves to the package's FITS model format and loads back identically.
interp = pooled.model_.interpolator_
static_fraction = interp.static_sill_ / (interp.static_sill_ + interp.atmosphere_sill_)
print("static fraction of each coefficient's variance:", np.round(static_fraction, 2))
print(f"ranges (unit square): static {interp.range_:.2f}, atmosphere "
      f"{interp.atmosphere_range_:.2f}")
path = os.path.join(tempfile.mkdtemp(), "pooled.fits")
pooled.save(path)
print("reloaded model predicts identically:",
      np.array_equal(PooledPSFModel.load(path).predict(X[:10]), pooled.predict(X[:10])))

# %%
# The full study, :func:`~sklearn_psf.study.exposures.run_exposure_study`, turns these
# residuals into sigma_sys^2 over many simulations and compares them with the Stage IV
# requirement (``python benchmarks/bench_exposures.py``).
#
# Several CCDs of one exposure in one model
# -----------------------------------------
# The stars of a 2 x 1 mosaic carry (x, y) on their CCD and the CCD index; a
# :class:`~sklearn_psf.model.FocalPlaneMapper` first in the interpolator puts them in
# focal-plane coordinates, so that one model spans both CCDs.
field = make_psf_field(n_stars=150, n_galaxies=50, image_shape=(1000, 1200), random_state=1)
origins = np.array([[0.0, 0.0], [620.0, 0.0]])  # CCDs of 580 pixels, a 40-pixel gap
xy = np.column_stack([field.stars["x"], field.stars["y"]])
star_stamps, _ = field.star_stamps()
on_ccd = (xy[:, 0] < 580) | (xy[:, 0] >= 620)
ccd = (xy[:, 0] >= 620).astype(int)
local = np.column_stack([xy[:, 0] - origins[ccd, 0], xy[:, 1], ccd])[on_ccd]
steps = [step for _, step in make_default_interpolator().steps]  # IsotropicScaler, Kriging
interp = make_pipeline(FocalPlaneMapper(origins), *steps)
mosaic = PSFModel(interpolator=interp).fit(local, star_stamps[on_ccd])
print(f"one model over 2 CCDs: {int(mosaic.inlier_mask_.sum())} stars kept of {len(local)}")
