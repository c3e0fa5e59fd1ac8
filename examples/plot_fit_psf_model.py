"""
=======================================
Fit a PSF model and predict galaxy-PSFs
=======================================

The basic workflow of sklearn_psf on one simulated field: cut the stars from the image,
fit a :class:`~sklearn_psf.model.PSFModel` (a PCA basis of the noisy stamps with as many
components as stand above the noise, a chi^2 test of outlying stars, and Kriging of the PCA
coefficients with each star's noise), then predict the PSF at the positions of galaxies, where the simulation knows the true PSF.
"""

# %%
# Simulate a field
# ----------------
# :func:`~sklearn_psf.simulate.make_psf_field` draws stars (S/N 100) and galaxy-PSFs on a noisy image.
# The PSF varies across the field as Gaussian random fields of the weights of a reference PCA
# basis. The documentation builds this example at a reduced size.
import os

import matplotlib.pyplot as plt
import numpy as np

from sklearn_psf import PSFModel, adaptive_moments, make_psf_field

SIZE = os.environ.get("SKLEARN_PSF_EXAMPLE_SIZE", "full")
if SIZE == "small":
    image_shape, n_stars, n_galaxies = (1500, 2000), 300, 300
else:
    image_shape, n_stars, n_galaxies = (7769, 10032), 1000, 2000

field = make_psf_field(n_stars=n_stars, n_galaxies=n_galaxies, image_shape=image_shape,
                       random_state=0)
print(field)

# %%
# Stars as measured on the image
# ------------------------------
# As on real data, the star stamps are cut from the noisy image (not taken from the truth)
# and normalised to unit flux and centred. ``flags`` is non-zero for stamps that could not be
# cut cleanly (none here: the simulation keeps every stamp inside the image).
stamps, flags = field.star_stamps()
X_stars = np.column_stack([field.stars["x"], field.stars["y"]]).astype(float)
good = flags == 0
X_stars, stamps = X_stars[good], stamps[good]
print(f"{len(X_stars)} star stamps of {field.stamp_size} x {field.stamp_size} pixels")

# %%
# Fit the PSF model
# -----------------
# The default :class:`~sklearn_psf.model.PSFModel` keeps the principal components whose
# variance stands above the noise edge (the paper's 90% of the variance of *noisy* stamps would
# keep many more); ``inlier_mask_`` tells which stars passed the chi^2 outlier test.
model = PSFModel().fit(X_stars, stamps)
print(f"PCA components: {model.n_components_}, "
      f"stars kept by the outlier test: {model.inlier_mask_.sum()} of {len(X_stars)}")

# %%
# Predict at the galaxy positions
# -------------------------------
# ``predict`` returns normalised stamps; the truth of the simulation is the noiseless,
# normalised stamp of each galaxy-PSF. Their ellipticities, measured with adaptive moments
# (e = (Q11 - Q22 + 2i Q12) / (Q11 + Q22)), give the residual the weak-lensing analysis cares
# about.
X_gal = np.column_stack([field.galaxies["x"], field.galaxies["y"]]).astype(float)
predicted = model.predict(X_gal)
truth = np.asarray(field.galaxies["stamp"])

moments = adaptive_moments(predicted)
ok = np.asarray(moments["flag"]) == 0
de1 = np.asarray(moments["e1"]) - np.asarray(field.galaxies["e1"])
de2 = np.asarray(moments["e2"]) - np.asarray(field.galaxies["e2"])
e_true = np.hypot(field.galaxies["e1"], field.galaxies["e2"])
print(f"mean |e| of the true PSF: {np.mean(e_true):.4f}")
print(f"ellipticity residual rms: e1 {np.sqrt(np.mean(de1[ok] ** 2)):.4f}, "
      f"e2 {np.sqrt(np.mean(de2[ok] ** 2)):.4f}, "
      f"|de| {np.sqrt(np.mean(de1[ok] ** 2 + de2[ok] ** 2)):.4f}")

# %%
# The paper forces the simulation's own basis on the model, so that PCA coefficients can be
# compared with the truth: :func:`sklearn_psf.study.compare.make_psf_model` does that with
# ``reference=field.reference`` (5 components instead of the many fitted above). The
# ellipticity residuals barely change: they come from the interpolation of noisy stars.
from sklearn_psf.study.compare import default_schemes, make_psf_model

forced = make_psf_model(default_schemes()["kriging"], reference=field.reference)
forced.fit(X_stars, stamps)
mom_forced = adaptive_moments(forced.predict(X_gal))
ok_forced = np.asarray(mom_forced["flag"]) == 0
de_forced = np.hypot(np.asarray(mom_forced["e1"]) - field.galaxies["e1"],
                     np.asarray(mom_forced["e2"]) - field.galaxies["e2"])[ok_forced]
print(f"reference basis ({forced.n_components_} components): "
      f"|de| rms {np.sqrt(np.mean(de_forced ** 2)):.4f}")

# %%
# True, model and residual stamps
# -------------------------------
# Four galaxy-PSFs: the model is close to the truth; the residual (model minus truth, on a
# colour scale of +-1/30 of the PSF's peak) shows what the interpolation misses.
s = field.stamp_size
chosen = np.linspace(0, len(X_gal) - 1, 4).astype(int)
fig, axes = plt.subplots(3, len(chosen), figsize=(2.4 * len(chosen), 7.2), layout="constrained")
for j, i in enumerate(chosen):
    t, m = truth[i].reshape(s, s), predicted[i].reshape(s, s)
    vmax = t.max()
    axes[0, j].imshow(t, origin="lower", vmin=0, vmax=vmax, cmap="magma")
    axes[1, j].imshow(m, origin="lower", vmin=0, vmax=vmax, cmap="magma")
    im = axes[2, j].imshow(m - t, origin="lower", vmin=-vmax / 30, vmax=vmax / 30,
                           cmap="RdBu_r")
    axes[0, j].set_title(f"x={X_gal[i, 0]:.0f}, y={X_gal[i, 1]:.0f}", fontsize=9)
for row, label in enumerate(["truth", "model", "model - truth"]):
    axes[row, 0].set_ylabel(label)
for ax in axes.flat:
    ax.set_xticks([])
    ax.set_yticks([])
fig.colorbar(im, ax=axes[2, :], shrink=0.8, label="residual (unit-flux stamps)")
plt.show()
