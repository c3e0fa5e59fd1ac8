"""
==========================
Simulate a PSF field image
==========================

The simulations of Bergé et al. (2012), section 3: mock PSFs are built from the principal
components of the stars of a reference image, with weights that vary across the field as
Gaussian random fields of power spectrum P(k) ~ k^-11/4. :func:`~sklearn_psf.simulate.make_psf_field`
draws the stars (S/N 100 by default) and the "galaxy-PSFs" (positions where the true PSF is
known, to test a model) into a noisy image, at sub-pixel positions. This example looks at one
simulation: the image, example PSFs and the ellipticity pattern; then at a field as real data
come: contaminated stars, masked pixels, a bad column, saturation, with the truth known.
"""

# %%
# One simulation
# --------------
# Galaxy-PSFs on a regular grid (``galaxy_layout="grid"``) make a whisker map; the default
# layout is random positions.
import os

import matplotlib.pyplot as plt
import numpy as np

from sklearn_psf import load_default_reference, make_psf_field
from sklearn_psf.simulate import DetectorSettings
from sklearn_psf.study.plotting import plot_psf_examples

SIZE = os.environ.get("SKLEARN_PSF_EXAMPLE_SIZE", "full")
if SIZE == "small":
    image_shape, n_stars, n_galaxies = (1500, 2000), 300, 300
else:
    image_shape, n_stars, n_galaxies = (7769, 10032), 1000, 2000

reference = load_default_reference()
print(reference)
field = make_psf_field(reference, n_stars=n_stars, n_galaxies=n_galaxies, galaxy_layout="grid",
                       image_shape=image_shape, random_state=3)
print(field)

# %%
# A cut-out of the image
# ----------------------
# 400 x 400 pixels (80 arcsec at 0.2 arcsec per pixel) at the centre of the image; stars are
# circled. Galaxy-PSFs are drawn in the image too, at S/N 1000
# (``galaxy_snr``), so that their positions are visible.
ny, nx = image_shape
x0, y0 = nx // 2 - 200, ny // 2 - 200
cut = field.image[y0:y0 + 400, x0:x0 + 400]
inside = ((field.stars["x"] >= x0) & (field.stars["x"] < x0 + 400)
          & (field.stars["y"] >= y0) & (field.stars["y"] < y0 + 400))
fig, ax = plt.subplots(figsize=(5, 5), layout="constrained")
ax.imshow(cut, origin="lower", cmap="gray", vmin=-2 * field.noise_rms, vmax=10 * field.noise_rms,
          extent=(x0 - 0.5, x0 + 399.5, y0 - 0.5, y0 + 399.5))
ax.scatter(field.stars["x"][inside], field.stars["y"][inside], s=300, facecolors="none",
           edgecolors="tab:orange", label="stars")
ax.set_xlabel("x (pixels)")
ax.set_ylabel("y (pixels)")
ax.legend(loc="upper right")
ax.set_title(f"{inside.sum()} stars in the cut-out")
plt.show()

# %%
# Example PSFs
# ------------
# Nine true (noiseless, normalised) stamps spread over the field, on a logarithmic colour
# scale as in the paper's fig_sim. The variations from one position to another are small:
# a few per cent in ellipticity.
order = np.lexsort((np.round(field.stars["x"] / (nx / 3)), np.round(field.stars["y"] / (ny / 3))))
chosen = order[np.linspace(0, len(order) - 1, 9).astype(int)]
positions = np.column_stack([field.stars["x"][chosen], field.stars["y"][chosen]])
fig = plot_psf_examples(field.stars["stamp"][chosen], positions=positions,
                        pixel_scale=field.pixel_scale)
plt.figure(fig)  # sklearn_psf.study.plotting returns figures outside pyplot: hand it to pyplot
plt.show()

# %%
# Ellipticity whisker map
# -----------------------
# The PSF ellipticity e = e1 + i e2 = (Q11 - Q22 + 2i Q12) / (Q11 + Q22) at the grid
# galaxy-PSFs: each whisker has length :math:`|e|` and position angle
# :math:`\arctan(e_2, e_1) / 2`.
e1, e2 = np.asarray(field.galaxies["e1"]), np.asarray(field.galaxies["e2"])
modulus = np.hypot(e1, e2)
angle = 0.5 * np.arctan2(e2, e1)
fig, ax = plt.subplots(figsize=(7, 5.5), layout="constrained")
q = ax.quiver(field.galaxies["x"], field.galaxies["y"], modulus * np.cos(angle),
              modulus * np.sin(angle), modulus, headwidth=0, headlength=0, headaxislength=0,
              pivot="middle", cmap="viridis", scale=0.2, scale_units="inches", width=0.004)
ax.quiverkey(q, 0.85, 1.03, 0.05, "|e| = 0.05", labelpos="E")
fig.colorbar(q, ax=ax, label="|e|")
ax.set_aspect("equal")
ax.set_xlabel("x (pixels)")
ax.set_ylabel("y (pixels)")
plt.show()

# %%
# The paper's simulations have PSF ellipticities of mean :math:`|e|` about 0.05 with a spread about
# 0.02; the default reference was tuned to match.
print(f"mean |e| = {modulus.mean():.4f}, standard deviation of |e| = {modulus.std():.4f}")
print(f"standard deviation of e1 = {e1.std():.4f}, of e2 = {e2.std():.4f}")

# %%
# A field as real data come
# -------------------------
# ``contaminants`` gives a fraction of the stars a cosmic ray, a blended neighbour, a binary
# companion or replaces them by a compact galaxy; ``field.stars["contaminant"]`` is the
# truth. The ``detector`` settings mask pixels and columns and saturate pixels, all of
# weight 0 in ``field.weight`` (inverse variance, including the stars' Poisson noise with
# ``gain``). The strengths and their reasons are in :mod:`sklearn_psf.simulate`.
dirty = make_psf_field(reference, n_stars=300, n_galaxies=0, image_shape=(1500, 2000),
                       snr=100.0, random_state=3,
                       contaminants={"cosmic_ray": 0.1, "neighbour": 0.1, "galaxy": 0.1,
                                     "binary": 0.1},
                       detector=DetectorSettings(masked_fraction=1e-3, bad_columns=2,
                                                 saturation=3000.0, gain=2.0))
raw, weights, flags = dirty.star_stamps(return_weights=True)
s = dirty.stamp_size
kinds = ["", "cosmic_ray", "neighbour", "galaxy", "binary"]
fig, axes = plt.subplots(2, 5, figsize=(9, 4), layout="constrained")
for j, kind in enumerate(kinds):
    rows = np.flatnonzero((dirty.stars["contaminant"] == kind) & (flags == 0))[:2]
    for i, r in enumerate(rows):
        ax = axes[i, j]
        ax.imshow(np.arcsinh(raw[r].reshape(s, s) / dirty.noise_rms), origin="lower",
                  cmap="gray")
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_title(f"{kind or 'clean'}\nsignal S/N {dirty.stars['contaminant_snr'][r]:.0f}",
                     fontsize=8)
fig.suptitle("Star stamps at S/N 100 (asinh scale); signal S/N = sqrt of the chi^2 added")
plt.show()

print(f"{int((dirty.weight == 0).sum())} pixels of weight 0 "
      f"({int((dirty.weight == 0).all(axis=0).sum())} bad columns, saturated cores, bad pixels); "
      f"{int(((weights == 0).any(axis=1)).sum())} of {len(raw)} star stamps hold some")
