"""
PSF model of a (simulated) exposure: FITS image in, validated model file out
=============================================================================

The Monday-morning workflow of PIFF and PSFEx users, with sklearn_psf:

1. read a FITS image (here tile-compressed, with its weight HDU) and select stars;
2. cut their stamps, skipping stars that are masked, saturated or too close to an edge;
3. fit a PSF model on most stars and validate it on reserved ones (shape residuals,
   rho1-rho5);
4. save the model to a FITS file, load it later and evaluate the PSF at galaxy positions;
5. the PSFEx way: a SExtractor FITS_LDAC catalogue of every detection, with ``VIGNET``
   stamps and no image: select the stars, fit, and draw the PSF at sub-pixel positions.

The exposure is simulated by the package itself
(:func:`sklearn_psf.simulate.write_example_exposure`, built on
:func:`sklearn_psf.simulate.make_psf_field`), so the example needs no download and we can
compare with the true PSF. On a real CCD, replace the file names (see
:mod:`sklearn_psf.exposure`; :func:`sklearn_psf.exposure.fit_exposure` is the whole path in
one call); the command line does the same in two commands::

    sklearn-psf fit exposure.fits.fz --hdu SCI --weight-hdu WGT -o psf.fits
    sklearn-psf predict psf.fits --positions galaxies.csv -o galaxy_psfs.fits
    sklearn-psf fit --stars catalog.ldac -o psf.fits        # vignettes alone
    sklearn-psf predict psf.fits --positions galaxies.cat --centered -o galaxy_psfs.fits

Set ``SKLEARN_PSF_EXAMPLE_SIZE=small`` for a quick run (a smaller image, fewer stars).
"""
# sphinx_gallery_multi_image = "single"

# %%
# A simulated exposure written as survey files
# --------------------------------------------
# ``exposure.fits.fz`` holds the image (HDU ``SCI``, with a ``SATURATE`` keyword) and an
# inverse-variance weight map (HDU ``WGT``). Three stars are spoiled as on real data: one
# sits on masked pixels, one has a NaN pixel, one is saturated.
import os
import tempfile

import matplotlib.pyplot as plt
import numpy as np
from astropy.table import Table

from sklearn_psf.exposure import extract_star_stamps, find_stars
from sklearn_psf.io import read_image
from sklearn_psf.simulate import write_example_exposure, write_example_ldac
from sklearn_psf.measure import adaptive_moments
from sklearn_psf.model import PSFModel
from sklearn_psf.validation import fit_and_validate, plot_stamp_residuals, plot_whiskers

small = os.environ.get("SKLEARN_PSF_EXAMPLE_SIZE") == "small"
n_stars, side = (150, 1500) if small else (600, 4000)
folder = tempfile.mkdtemp()
paths = write_example_exposure(folder, n_stars=n_stars, image_shape=(side, side),
                               n_galaxies=300, compress=True, random_state=0)
image, weight, header = read_image(paths["image"], hdu="SCI", weight_hdu="WGT")
print(f"image {image.shape}, {np.isnan(image).sum()} NaN pixel, "
      f"{(weight == 0).sum()} masked pixels, SATURATE = {header['SATURATE']:.0f}")

# %%
# Star selection and stamps
# -------------------------
# Without a catalogue, :func:`~sklearn_psf.exposure.find_stars` detects sources with ``sep``
# and keeps isolated, unsaturated point sources on the flux-radius locus; each rejected
# detection is counted under its reason. (With a SExtractor catalogue,
# ``read_catalog("stars.fits")`` reads 1-based ``X_IMAGE``/``Y_IMAGE``.)
stars = find_stars(image, weight=weight, stamp_size=25, saturation=header["SATURATE"])
print(f"{stars.meta['n_detections']} detections, {len(stars)} stars; rejected:",
      {k: v for k, v in stars.meta["rejected"].items() if v})
cut = extract_star_stamps(image, stars, 25, weight=weight, saturation=header["SATURATE"])
print(cut)

# %%
# Fit and validate on reserved stars
# ----------------------------------
# 20% of the stars (seeded) are kept out of the fit; the model, ``PSFModel()`` with its
# noise-aware defaults (a basis of the components above the noise, chi^2 outlier rejection,
# Kriging with each star's noise), fitted with the weight map's pixel weights, is compared
# with them.
model, residuals, summary = fit_and_validate(cut.positions, cut.stamps, reserve=0.2,
                                             random_state=0, weights=cut.weights)
print(f"fitted on {summary['n_fit']} stars ({summary['n_outliers']} outliers), "
      f"validated on {summary['n_measured']}: e rms {summary['e_rms']:.4f}, "
      f"size rms {summary['dsigma_rms']:.4f} px, |rho1| {summary['rho1_mean_abs']:.1e}")

# %%
# The reserved stars, the model at their positions and the residuals, and the ellipticity
# pattern over the field (the residual whiskers are amplified five times).
plot_stamp_residuals(residuals, n=4)
plot_whiskers(residuals)

# %%
# Save, load, predict at galaxy positions
# ---------------------------------------
# The model file is a self-describing FITS file (format in
# :func:`sklearn_psf.model.save_model`); it stores the reserved-star residuals too. Loading
# refits nothing but the interpolator on the stored coefficients: predictions are identical.
model_path = os.path.join(folder, "psf.fits")
model.save(model_path, residuals=residuals, summary=summary)
loaded = PSFModel.load(model_path)
galaxies = Table.read(paths["galaxies"])
X_gal = np.column_stack([galaxies["x"], galaxies["y"]])
psfs = loaded.predict(X_gal)
assert np.allclose(psfs, model.predict(X_gal), rtol=1e-12, atol=0)

# %%
# The simulation's truth tells how good the PSF at the galaxies really is.
truth = Table.read(paths["truth"])
truth = truth[truth["kind"] == "galaxy"]
mom = adaptive_moments(psfs)
de = np.hypot(mom["e1"] - truth["e1"], mom["e2"] - truth["e2"])
print(f"PSF at {len(X_gal)} galaxies: e rms (model - truth) = {np.sqrt(np.mean(de**2)):.4f}; "
      f"reserved stars (star - model, includes the stars' noise) = {summary['e_rms']:.4f}")

fig, ax = plt.subplots(figsize=(5, 4), layout="constrained")
ax.scatter(truth["e1"], mom["e1"], s=8, label="e1")
ax.scatter(truth["e2"], mom["e2"], s=8, label="e2")
lim = np.abs(np.concatenate([truth["e1"], truth["e2"]])).max() * 1.1
ax.plot([-lim, lim], [-lim, lim], "k:", lw=1)
ax.set_xlabel("true PSF ellipticity at the galaxies")
ax.set_ylabel("model (loaded from the file)")
ax.legend()

# %%
# A SExtractor FITS_LDAC catalogue with vignettes, no image
# ---------------------------------------------------------
# PSFEx's input: every detection (here half of them galaxies, some barely resolved, plus
# cosmic rays, saturated stars and masked pixels) with its ``VIGNET`` stamp.
# :func:`~sklearn_psf.exposure.select_stars` keeps the unflagged, unsaturated sources of high
# S/N on the stellar locus of the size-magnitude diagram (``FLUX_RADIUS`` against
# ``MAG_AUTO``); :func:`~sklearn_psf.exposure.extract_vignettes` turns the masked pixels
# (-1e30) into zero-weight pixels.
from sklearn_psf.exposure import extract_vignettes, select_stars
from sklearn_psf.io import draw_psf, read_catalog
from sklearn_psf.simulate import realistic_snr
from sklearn_psf.validation import plot_psf_maps, plot_rho_statistics

ldac = write_example_ldac(folder, n_stars=n_stars // 2, n_galaxies=n_stars // 2,
                         image_shape=(side, side), random_state=1,
                         snr=realistic_snr(n_stars // 2, random_state=1, low=30.0))
catalog = read_catalog(ldac["catalog"])
saturate = catalog.meta["image_header"]["SATURATE"]
keep, counts = select_stars(catalog, min_snr=20, saturation=saturate)
kind = ldac["kind"]
print(f"kept {keep[kind == 'star'].sum()} of {(kind == 'star').sum()} stars, "
      f"{keep[kind == 'galaxy'].sum()} of {(kind == 'galaxy').sum()} galaxies; rejected:",
      {k: v for k, v in counts.items() if v and not k.startswith("locus")})

fig, ax = plt.subplots(figsize=(5.5, 4), layout="constrained")
for name, marker in (("galaxy", "x"), ("cosmic", "^"), ("star", "o")):
    sel = kind == name
    ax.scatter(catalog["MAG_AUTO"][sel], catalog["flux_radius"][sel], s=10, marker=marker,
               label=name, alpha=0.6)
ax.scatter(catalog["MAG_AUTO"][keep], catalog["flux_radius"][keep], s=30, facecolor="none",
           edgecolor="k", label="selected")
ax.set_xlabel("MAG_AUTO")
ax.set_ylabel("FLUX_RADIUS [pixel]")
ax.set_ylim(0, 6)
ax.set_title("size-magnitude diagram")
ax.legend(fontsize=8)

# %%
# Fit on the vignettes with their pixel weights, validate (rho1-rho5, Jarvis et al. 2016),
# and map the model's ellipticity and size across the chip.
vig = extract_vignettes(catalog[keep], saturation=saturate)
model2, residuals2, summary2 = fit_and_validate(vig.positions, vig.stamps, reserve=0.2,
                                                random_state=0, weights=vig.weights)
true_stars = ldac["truth"]
mom2 = adaptive_moments(model2.predict(np.column_stack([true_stars["x"], true_stars["y"]])))
de2 = np.hypot(mom2["e1"] - true_stars["e1"], mom2["e2"] - true_stars["e2"])
print(f"model - truth e rms at the stars: {np.sqrt(np.mean(de2**2)):.4f}")
plot_rho_statistics(summary2)
plot_psf_maps(model2, (side, side))

# %%
# The PSF where a galaxy really is: ``draw_psf`` shifts the model by the sub-pixel offset
# from the stamp's centre pixel ``floor(x + 0.5)`` (as PSFEx and PIFF draw it) and can
# oversample it.
psf = draw_psf(model2, [[1000.4, 800.0]], centered=True, oversampling=3)[0]
fig, axes = plt.subplots(1, 2, figsize=(7, 3.4), layout="constrained")
axes[0].imshow(draw_psf(model2, [[1000.4, 800.0]], centered=False)[0], origin="lower")
axes[0].set_title("pixel grid, centred on the pixel")
axes[1].imshow(psf, origin="lower")
axes[1].set_title("x = 1000.4: shifted, 3x oversampled")
plt.show()
