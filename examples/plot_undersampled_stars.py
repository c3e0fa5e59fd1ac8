"""
=====================================================
Undersampled stars: the PSF on a finer grid
=====================================================

Euclid's VIS camera, Roman, HST and JWST's short wavelengths sample the PSF at under two
pixels per FWHM: each star shows the PSF at its own sub-pixel phase, and re-centring a stamp
by interpolation aliases it. For such stars ``PSFModel()`` chooses
:class:`~sklearn_psf.preprocessing.SuperResolvedPCA`: the pixel-convolved PSF on a grid
finer than the pixels, each star modelled as that profile sampled at its own phase, all
stars fitted together. The fine grid holds the frequencies the stars measure: the disc of
frequencies whose mean, fitted on half of the stars, best predicts the other half. Here
GalSim draws Euclid-VIS-like stars (an ``OpticalPSF`` through 1.2 m at 700 nm, 0.1"
pixels, FWHM ~1.5 pixels) and the model is compared with GalSim's truth and with the basis
made for well-sampled stars.
"""

# %%
# Undersampled stars at random phases
# -----------------------------------
import os

import galsim
import matplotlib.pyplot as plt
import numpy as np

from sklearn_psf import PSFModel
from sklearn_psf.measure import fixed_moments
from sklearn_psf.preprocessing import StampPCA

SIZE = os.environ.get("SKLEARN_PSF_EXAMPLE_SIZE", "full")
n_stars = 120 if SIZE == "small" else 300
scale, side, field_size = 0.1, 21, 2048.0  # arcsec per pixel, stamp side, field (pixels)
lam, diam = 700e-9, 1.2  # metres
optics = galsim.Convolve(
    galsim.OpticalPSF(lam=lam * 1e9, diam=diam, obscuration=0.3, scale_unit=galsim.arcsec,
                      aberrations=[0, 0, 0, 0, 0.02, 0.04, 0.03, 0.02, -0.02, 0.01, 0, 0.03]),
    galsim.Gaussian(sigma=0.025))


def psf_at(x, y):
    """The field's PSF at pixel (x, y): its size and shape vary linearly over the field."""
    u, v = x / field_size - 0.5, y / field_size - 0.5
    return optics.dilate(1 + 0.06 * u).shear(g1=0.03 * v, g2=0.02 * u)


def draw(profile, offset):
    return profile.drawImage(nx=side, ny=side, scale=scale, offset=tuple(offset)).array


rng = np.random.default_rng(1)
X = rng.uniform(0, field_size, (n_stars, 2))
phases = rng.uniform(-0.5, 0.5, (n_stars, 2))
stars = np.array([draw(psf_at(*p), o) for p, o in zip(X, phases)])
snr = rng.uniform(30, 1000, n_stars)
stars *= (snr / np.sqrt((stars**2).sum(axis=(1, 2))))[:, None, None]
stars += rng.normal(0.0, 1.0, stars.shape)  # sky noise of sigma 1
weights = np.ones_like(stars)

model = PSFModel().fit(X, stars, weights=weights)
basis = model.basis_
cutoff = diam / lam * scale / 206264.806  # the optics' diffraction cutoff, cycles per pixel
print(f"{n_stars} stars, median FWHM {basis.fwhm_:.2f} pixels: {type(basis).__name__}, "
      f"{basis.oversampling_} fine samples per pixel, {basis.n_components_} components")
print(f"band the stars measure: {basis.band_limit_:.2f} cycles per pixel "
      f"(the optics' D / lambda: {cutoff:.2f})")

# %%
# A star, the model at its phase, and the fine PSF's spectrum
# -----------------------------------------------------------
# ``predict(X, offsets=...)`` draws the model at any sub-pixel position (here the star's
# true phase); ``predict(X, fine=True)`` gives the fine grid. The fine PSF's power falls
# with the truth's (GalSim, drawn on the same grid) and holds nothing beyond the band.
k = int(np.argmax(snr))
star = stars[k] / stars[k].sum()
at_phase = model.predict(X[k:k + 1], offsets=phases[k:k + 1])[0].reshape(side, side)
S, f = basis.fine_size_, basis.oversampling_
fine = model.predict(X[k:k + 1], fine=True)[0].reshape(S, S)
truth = galsim.Convolve(psf_at(*X[k]), galsim.Pixel(scale)).drawImage(
    nx=S, ny=S, scale=scale / f, method="no_pixel").array
radius = np.hypot(*np.meshgrid(np.fft.fftfreq(S), np.fft.fftfreq(S))) * f  # cycles/pixel
edges = np.arange(0.0, radius.max(), 0.05)
centres = edges[:-1] + 0.025


def ring_power(img):
    power = np.abs(np.fft.fft2(img / img.sum())) ** 2
    return np.array([power[(radius >= a) & (radius < a + 0.05)].mean() for a in edges[:-1]])


fig, axes = plt.subplots(1, 4, figsize=(14, 3.6), layout="constrained",
                         gridspec_kw={"width_ratios": [1, 1, 1, 1.6]})
c, half = side // 2, 4  # the central 9 x 9 pixels
crop = (slice(c - half, c + half + 1),) * 2
extent = (-half - 0.5, half + 0.5, -half - 0.5, half + 0.5)
vmax = star.max()
for ax, img, title in ((axes[0], star, f"star (S/N {snr[k]:.0f})"),
                       (axes[1], at_phase, "model at the star's phase")):
    im = ax.imshow(img[crop], origin="lower", cmap="magma", vmin=0, vmax=vmax, extent=extent)
    ax.set_title(title)
fig.colorbar(im, ax=axes[1], label="fraction of the flux", shrink=0.8)
resid = axes[2].imshow((star - at_phase)[crop], origin="lower", cmap="RdBu_r",
                       vmin=-0.1 * vmax, vmax=0.1 * vmax, extent=extent)
axes[2].set_title("star - model")
fig.colorbar(resid, ax=axes[2], label="fraction of the flux", shrink=0.8)
for ax in axes[:3]:
    ax.set_xlabel("x [pixel]")
axes[0].set_ylabel("y [pixel]")
spectrum = axes[3]
spectrum.semilogy(centres, ring_power(truth), "k-", label="truth (GalSim)")
spectrum.semilogy(centres, np.maximum(ring_power(fine), 1e-12), "C0.-", label="model")
spectrum.axvline(basis.band_limit_, color="C0", ls="--", label="band the stars measure")
spectrum.axvline(cutoff, color="C3", ls=":", label=r"optics' $D/\lambda$")
spectrum.set_ylim(1e-10, 2)
spectrum.set_xlabel("frequency [cycles per pixel]")
spectrum.set_ylabel("power (mean over a ring)")
spectrum.set_title("fine PSF's power spectrum")
spectrum.legend(fontsize=8)
plt.show()

# %%
# Accuracy at the truth
# ---------------------
# At 200 random positions, each model's stamp centred on the centre pixel and GalSim's
# truth, measured with moments of a fixed round Gaussian weight (sigma 1.5 pixels: adaptive
# moments fail on undersampled stamps, "object too small"). The basis made for well-sampled
# stars centres each stamp by interpolation, which aliases undersampled stars.
def centre(profile):
    """The package's centre of a PSF: the adaptive centroid of the pixel-convolved profile
    sampled every half pixel (GalSim's HSM), in pixels."""
    img = galsim.Convolve(profile, galsim.Pixel(scale)).drawImage(
        nx=51, ny=51, scale=scale / 2, method="no_pixel")
    c = galsim.hsm.FindAdaptiveMom(img).moments_centroid - img.true_center
    return np.array([c.x, c.y]) / 2


P = rng.uniform(0, field_size, (200, 2))
true = np.array([draw(p, -centre(p)) for p in (psf_at(*q) for q in P)])
mt = fixed_moments(true, 1.5)
rows = []
for name, fitted in (("super-resolved (the default here)", model),
                     ("StampPCA (well-sampled stars' basis)",
                      PSFModel(basis=StampPCA()).fit(X, stars, weights=weights))):
    mp = fixed_moments(fitted.predict(P).reshape(true.shape), 1.5)
    de = np.hypot(np.asarray(mp["e1"]) - mt["e1"], np.asarray(mp["e2"]) - mt["e2"])
    ds = (np.asarray(mp["sigma"]) - mt["sigma"]) / np.asarray(mt["sigma"])
    rows.append((name, np.sqrt(np.mean(de**2)), np.sqrt(np.mean(ds**2)), ds.mean()))
print(f"{'basis':<38} {'e rms':>8} {'size rms':>9} {'size bias':>10}")
for name, e, s, b in rows:
    print(f"{name:<38} {e:8.4f} {s:9.4f} {b:+10.4f}")
print("e: ellipticity (e1, e2) error; size: relative error of det(M)^(1/4)")
