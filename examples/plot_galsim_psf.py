"""
=====================================================
Convolve galaxies with the model's PSF in GalSim
=====================================================

A shape-measurement code built on GalSim (metacalibration, ngmix, HSM) needs the PSF at each
galaxy as a GalSim object. :meth:`PSFModel.to_galsim <sklearn_psf.model.PSFModel.to_galsim>`
returns it as a ``galsim.InterpolatedImage`` in the image's world coordinates, centred on
its origin, so that ``galsim.Convolve(galaxy, psf)`` works as with any GalSim PSF. Here a
model is fitted on the stars of a simulated field, galaxies are convolved with the *true*
PSF (the simulation knows it), and their shapes are measured with GalSim's HSM twice: with
the true PSF and with the model's. The difference is the shear error the PSF model leaves.
"""

# %%
# Fit a PSF model on the stars of a simulated field
# -------------------------------------------------
import os

import galsim
import matplotlib.pyplot as plt
import numpy as np

from sklearn_psf import PSFModel, make_psf_field

SIZE = os.environ.get("SKLEARN_PSF_EXAMPLE_SIZE", "full")
if SIZE == "small":
    image_shape, n_stars, n_galaxies = (1500, 1500), 200, 40
else:
    image_shape, n_stars, n_galaxies = (4000, 4000), 1000, 300

field = make_psf_field(n_stars=n_stars, n_galaxies=n_galaxies, image_shape=image_shape,
                       snr=100.0, random_state=1)
stamps, weights, _ = field.star_stamps(return_weights=True)
X_stars = np.column_stack([field.stars["x"], field.stars["y"]])
model = PSFModel().fit(X_stars, stamps, weights=weights)
scale = field.pixel_scale  # arcsec per pixel
print(f"{len(X_stars)} stars, {model.n_components_} components, {scale} arcsec/pixel")

# %%
# The PSF at a galaxy, as a GalSim object
# ---------------------------------------
# ``wcs=scale`` makes the profile's coordinates arcsec (a GalSim or astropy WCS gives the
# local Jacobian at the position instead). The model's stamps include the pixel response,
# like PSFEx and PIFF PixelGrid models: draw anything convolved with it with
# ``method="no_pixel"``. Drawn on the stamp's own pixels, it gives back ``predict``'s stamp.
x, y = field.galaxies["x"][0], field.galaxies["y"][0]
psf = model.to_galsim(x, y, wcs=scale)
s = model.stamp_size_
drawn = psf.drawImage(nx=s, ny=s, scale=scale, method="no_pixel").array
print(f"largest difference from predict, relative to the peak: "
      f"{np.abs(drawn.ravel() - model.predict([[x, y]])[0]).max() / drawn.max():.1e}")

galaxy = galsim.Exponential(half_light_radius=0.6).shear(g1=0.2, g2=-0.1)
final = galsim.Convolve(galaxy, psf)
image = final.drawImage(nx=41, ny=41, scale=scale, method="no_pixel")

fig, axes = plt.subplots(1, 3, figsize=(10, 3.9), layout="constrained")
extent = (-20.5 * scale, 20.5 * scale, -20.5 * scale, 20.5 * scale)
panels = ((galaxy.drawImage(nx=41, ny=41, scale=scale).array, "galaxy"),
          (psf.drawImage(nx=41, ny=41, scale=scale, method="no_pixel").array,
           f"model PSF at ({x:.0f}, {y:.0f})"),
          (image.array, "galaxy convolved with the PSF"))
for ax, (img, title) in zip(axes, panels):
    ax.imshow(img, origin="lower", extent=extent, cmap="magma")
    ax.set_title(title, fontsize=10)
    ax.set_xlabel("arcsec")
axes[0].set_ylabel("arcsec")

# %%
# Shapes measured with the model's PSF and with the true PSF
# ----------------------------------------------------------
# Each galaxy (random shear, half-light radius 0.4 to 0.8 arcsec) is convolved with the true
# PSF at its position (the simulation's noiseless galaxy-PSF stamp). HSM's re-Gaussianization
# (``galsim.hsm.EstimateShear``) corrects its shape with a PSF image: the true one, or the
# model's drawn at the same place. With a perfect model both corrected shapes agree.
rng = np.random.default_rng(0)
X_gal = np.column_stack([field.galaxies["x"], field.galaxies["y"]])
true_psf = np.asarray(field.galaxies["stamp"]).reshape(-1, s, s)
e_true, e_model = [], []
for (gx, gy), truth in zip(X_gal, true_psf):
    g1, g2 = rng.uniform(-0.2, 0.2, 2)
    gal = galsim.Exponential(half_light_radius=rng.uniform(0.4, 0.8)).shear(g1=g1, g2=g2)
    true = galsim.InterpolatedImage(galsim.Image(truth, scale=scale))
    observed = galsim.Convolve(gal, true).drawImage(nx=41, ny=41, scale=scale,
                                                    method="no_pixel")
    psf_true = true.drawImage(nx=s, ny=s, scale=scale, method="no_pixel")
    psf_model = model.to_galsim(gx, gy, wcs=scale).drawImage(nx=s, ny=s, scale=scale,
                                                             method="no_pixel")
    a = galsim.hsm.EstimateShear(observed, psf_true)
    b = galsim.hsm.EstimateShear(observed, psf_model)
    e_true.append((a.corrected_e1, a.corrected_e2))
    e_model.append((b.corrected_e1, b.corrected_e2))
e_true, e_model = np.array(e_true), np.array(e_model)
de = e_model - e_true
print(f"{len(de)} galaxies: corrected e with the model's PSF - with the true PSF: "
      f"mean ({de[:, 0].mean():+.5f}, {de[:, 1].mean():+.5f}), "
      f"rms ({np.sqrt(np.mean(de[:, 0] ** 2)):.5f}, {np.sqrt(np.mean(de[:, 1] ** 2)):.5f})")

fig, axes = plt.subplots(1, 2, figsize=(9, 4), layout="constrained")
for k, ax in enumerate(axes):
    ax.plot(e_true[:, k], de[:, k], "o", ms=4)
    ax.axhline(0.0, color="0.5", lw=1)
    ax.set_xlabel(f"HSM corrected $e_{k + 1}$ with the true PSF")
    ax.set_ylabel(f"$e_{k + 1}$ (model PSF) $-$ $e_{k + 1}$ (true PSF)")
fig.suptitle("Shape error a galaxy inherits from the PSF model (noiseless galaxies)")

# %%
# PSF stamps for a whole catalogue, in one file
# ---------------------------------------------
# A pipeline that reads PSF images rather than GalSim objects gets them all at once:
# :func:`~sklearn_psf.io.write_psf_stamps` writes a FITS cube (HDU ``PSF``, read with
# ``astropy.io.fits.getdata(path, "PSF")``) with a ``POSITIONS`` table, or a ``.npz`` archive;
# ``oversampling`` and ``centered`` give oversampled or sub-pixel-placed stamps.
import tempfile

from sklearn_psf.io import read_psf_stamps, write_psf_stamps

path = os.path.join(tempfile.mkdtemp(), "galaxy_psfs.fits")
write_psf_stamps(path, model, X_gal, oversampling=2)
cube, positions = read_psf_stamps(path)
print(f"{cube.shape[0]} PSFs of {cube.shape[1]} x {cube.shape[2]} samples "
      f"({positions.meta['oversampling']} per pixel), "
      f"{int(positions['extrapolated'].sum())} extrapolated")
