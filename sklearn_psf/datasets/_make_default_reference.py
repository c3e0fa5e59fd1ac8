"""Regenerate the reference bases shipped in ``sklearn_psf/datasets/data``.

Run ``python -m sklearn_psf.datasets._make_default_reference`` (needs GalSim, a test/bench
dependency; the shipped FITS files themselves load with the core dependencies only). It
writes both bases, made from the same reference image and the same selected stars:

- ``default_reference.fits``: PCA keeping 90% of the variance (5 components), the default;
- ``default_reference_13.fits``: the first 13 principal components, the size of the paper's
  Subaru basis (13 components at 90% of its stars' variance), selected with
  ``load_default_reference(n_components=13)``. Its first 5 components are those of the
  default basis (94% of the variance in all); components 6-13 hold 0.1-0.2% of the variance
  each, mostly the reference stars' noise, as the later components of a real basis of stars
  of finite S/N do (their coefficient spread is measured on the same stars).

How the default reference is made
---------------------------------
A ground-based-like reference image (2400 x 2400 pixels at 0.2 arcsec/pixel, 8 x 8 arcmin)
is rendered with GalSim, then analysed by :meth:`ReferenceBasis.from_image` exactly as a real
image would be (sep background and detection, point-source selection, stamps, normalisation,
PCA keeping 90% of the variance):

- PSF = Kolmogorov atmosphere (FWHM 0.7 arcsec) sheared by a small coherent atmospheric
  shear (g1, g2) = (0.015, 0.0075), convolved with a GalSim ``OpticalPSF`` (lambda/D = 0.04
  arcsec, central obscuration 0.3) whose aberrations (in waves) vary smoothly with the field
  position (u, v) in [-1, 1]^2: defocus 0.3 + 0.05 (u^2 + v^2), astigmatism
  (0.05 + A (u^2 - v^2), 0.025 + 2 A u v) with A = ``ASTIG``, coma (0.1 u, 0.1 v), and
  drawn with the pixel response. The resulting FWHM is about 0.84 arcsec.
- 300 stars at random sub-pixel positions at least 40 pixels apart, fluxes log-uniform in
  [1.5e5, 2e6] counts; 6 saturated bright stars (clipped at SATURATE = 4e5 counts) and 40
  exponential galaxies (half-light radius 0.6-1.2 arcsec) that the selection must reject.
- Sky of 300 counts plus Gaussian noise of rms 10 counts.

The amplitude ``ASTIG`` was tuned (by hand, a few runs of :func:`_check`) so that the
*default simulation* (``make_psf_field()`` with this reference) has PSF ellipticities with
mean |e| ~ 0.05 and standard deviation of |e| ~ 0.02, the values quoted by Berge et al.
(2012) for their simulations; the figures measured on the shipped file are printed by
:func:`_check`.
"""

from __future__ import annotations

import os
import sys
import tempfile

import numpy as np

ASTIG = 0.10
IMAGE_SIZE = 2400
N_STARS = 300
STAMP_SIZE = 25
PIXEL_SCALE = 0.2
SEED = 20120425
OUT = os.path.join(os.path.dirname(__file__), "data", "default_reference.fits")
OUT_13 = os.path.join(os.path.dirname(__file__), "data", "default_reference_13.fits")


def _psf(galsim, u, v, astig=ASTIG):
    atm = galsim.Kolmogorov(fwhm=0.7).shear(g1=0.015, g2=0.0075)
    opt = galsim.OpticalPSF(
        lam_over_diam=0.04, obscuration=0.3,
        defocus=0.3 + 0.05 * (u**2 + v**2),
        astig1=0.05 + astig * (u**2 - v**2), astig2=0.025 + astig * 2 * u * v,
        coma1=0.1 * u, coma2=0.1 * v,
    )
    return galsim.Convolve(atm, opt)


def _place(image, arr, x, y):
    """Add ``arr`` (odd side) to ``image`` with its central pixel at integer (x, y)."""
    h = arr.shape[0] // 2
    ny, nx = image.shape
    y0, x0 = y - h, x - h
    sy = slice(max(0, -y0), arr.shape[0] - max(0, y0 + arr.shape[0] - ny))
    sx = slice(max(0, -x0), arr.shape[1] - max(0, x0 + arr.shape[1] - nx))
    image[max(0, y0):min(ny, y0 + arr.shape[0]), max(0, x0):min(nx, x0 + arr.shape[1])] += arr[sy, sx]


def render_reference_image(seed=SEED, astig=ASTIG, n_stars=N_STARS, size=IMAGE_SIZE):
    """Render the GalSim reference image; return (image, header dict, true star positions)."""
    import galsim
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(seed)
    image = np.zeros((size, size))
    # positions: stars, bright (saturated) stars and galaxies, all 40 pixels apart
    n_bright, n_gal = 6, 40
    total = n_stars + n_bright + n_gal
    pos = np.zeros((0, 2))
    while len(pos) < total:
        cand = rng.uniform(30, size - 31, size=(2 * total, 2))
        for c in cand:
            if len(pos) == 0 or cKDTree(pos).query(c, p=np.inf)[0] >= 40:
                pos = np.vstack([pos, c])
            if len(pos) == total:
                break
    fluxes = np.exp(rng.uniform(np.log(1.5e5), np.log(2e6), n_stars))
    fluxes = np.concatenate([fluxes, np.full(n_bright, 5e7)])
    stamp = 41
    for (x, y), flux in zip(pos[: n_stars + n_bright], fluxes):
        u, v = 2 * x / size - 1, 2 * y / size - 1
        ix, iy = int(np.floor(x + 0.5)), int(np.floor(y + 0.5))
        img = _psf(galsim, u, v, astig).withFlux(flux).drawImage(
            nx=stamp, ny=stamp, scale=PIXEL_SCALE, offset=(x - ix, y - iy))
        _place(image, img.array, ix, iy)
    for x, y in pos[n_stars + n_bright:]:
        u, v = 2 * x / size - 1, 2 * y / size - 1
        ix, iy = int(np.floor(x + 0.5)), int(np.floor(y + 0.5))
        gal = galsim.Exponential(half_light_radius=rng.uniform(0.6, 1.2), flux=rng.uniform(5e4, 3e5))
        gal = gal.shear(g1=rng.normal(0, 0.2), g2=rng.normal(0, 0.2))
        img = galsim.Convolve(gal, _psf(galsim, u, v, astig)).drawImage(
            nx=stamp, ny=stamp, scale=PIXEL_SCALE, offset=(x - ix, y - iy))
        _place(image, img.array, ix, iy)
    saturate = 4e5
    image += 300.0 + rng.normal(0.0, 10.0, image.shape)
    np.minimum(image, saturate, out=image)
    header = {"PIXSCALE": PIXEL_SCALE, "SATURATE": saturate, "GAIN": 1.0}
    return image.astype(np.float32), header, pos[:n_stars]


def build(out=OUT, seed=SEED, astig=ASTIG, out_13=OUT_13):
    """Render the reference image, run ``ReferenceBasis.from_image`` on it, save the bases.

    Returns the 90%-variance basis and the 13-component one.
    """
    from astropy.io import fits

    from sklearn_psf.datasets import ReferenceBasis

    image, header, _ = render_reference_image(seed, astig)
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "reference_image.fits")
        hdu = fits.PrimaryHDU(image)
        for key, val in header.items():
            hdu.header[key] = val
        hdu.writeto(path)
        ref = ReferenceBasis.from_image(path, stamp_size=STAMP_SIZE)
        ref13 = ReferenceBasis.from_image(path, stamp_size=STAMP_SIZE, n_components=13)
    if out is not None:
        ref.save(out, overwrite=True)
    if out_13 is not None:
        ref13.save(out_13, overwrite=True)
    return ref, ref13


def _check(reference=None, seeds=(0, 1, 2, 3, 4), image_shape=(1500, 2000), n=1000):
    """Mean and std of |e| of the true PSFs in default simulations (a few seeds)."""
    from sklearn_psf.simulate import make_psf_field

    out = []
    for seed in seeds:
        f = make_psf_field(reference, n_stars=n, n_galaxies=0, image_shape=image_shape,
                           random_state=seed, smallest_scale=31.0)
        e = np.hypot(f.stars["e1"], f.stars["e2"])
        out.append((e.mean(), e.std(), np.std(f.stars["e1"]), np.std(f.stars["e2"])))
    return np.array(out)


if __name__ == "__main__":  # pragma: no cover
    astig = float(sys.argv[1]) if len(sys.argv) > 1 else ASTIG
    final = len(sys.argv) <= 1
    ref, ref13 = build(astig=astig, out=OUT if final else None, out_13=OUT_13 if final else None)
    stats = _check(ref)
    sys.stdout.write(f"{ref!r}\nselected stars: {len(ref.positions)} of "
                     f"{ref.catalog.meta['n_detections']} detections\n"
                     f"explained variance ratio: {np.round(ref.explained_variance_ratio, 3)}\n"
                     f"mean |e|, std |e|, std e1, std e2 per seed:\n{np.round(stats, 4)}\n"
                     f"13 components: variance {ref13.explained_variance_ratio.sum():.3f}; "
                     f"mean |e|, std |e| per seed:\n{np.round(_check(ref13)[:, :2], 4)}\n")
