"""Simulated PSF fields (Berge et al. 2012, section 3).

A :class:`ReferenceBasis` (PCA of the stars of a reference image, 90% of the variance) gives
the building blocks of mock PSFs; :func:`make_psf_field` makes an image of stars and
galaxy-PSFs whose PCA weights vary across the field as Gaussian random fields with power
spectrum P(k) ~ k^-11/4 (:func:`gaussian_random_field`, :class:`RandomFieldSampler`).

Conventions
-----------
- **PSF model.** The PSF at position ``r`` is ``mean + sum_i w_i(r) * component_i``; each
  weight is ``coeff_mean_i + coeff_std_i * g_i(r)`` where the ``g_i`` are independent
  Gaussian random fields with P(k) ~ k^-slope, normalised to zero mean and unit variance over
  the image. They are drawn on a grid of ``grid_size`` (256) nodes along the longer side of
  the image and interpolated with cubic splines: for the paper's 10,032 x 7,769 pixel image a
  cell is 39 pixels (7.9 arcsec at 0.2 arcsec/pixel); this sets the smallest scale of PSF
  variation. Each synthesised stamp is passed through ``StampNormalizer(flux=True,
  center=True)`` (unit sum, adaptive centroid at the stamp centre), the package-wide
  convention; the true ``coeffs`` are the projection of that normalised stamp on the basis,
  i.e. what the measurement pipeline returns for a noiseless star.
- **Positions.** Every PSF is centred on an integer pixel (x = column, y = row, 0-based) at
  least half a stamp from the edges; no two stamps overlap (random positions closer than one
  stamp side along both x and y to an already placed PSF are re-drawn). Sub-pixel positions
  are a later refinement.
- **S/N** = mean of the star's pixels / background rms (the paper's definition), "the star's
  pixels" being the pixels of its noiseless stamp at or above half of the stamp's peak (the
  FWHM core, :func:`core_mask`). The flux of a star is ``snr * noise_rms / mean(core pixels
  of its unit-flux stamp)``. :func:`realistic_snr` draws the paper's realistic distribution
  (20 to 1000, peaking at 100).
- **Galaxy-PSFs** are drawn in the image with a fixed S/N (``galaxy_snr=1000``) or left out
  (``galaxy_snr=None``); their noiseless stamps (``field.galaxies["stamp"]``) are the truth a
  PSF model must predict.
- **Noise.** White Gaussian background of rms ``noise_rms`` (default: the reference image's
  background rms), float32, zero mean (a sky-subtracted image).
- **Seeds.** ``random_state`` (int, SeedSequence or Generator) seeds one generator that
  spawns four independent streams: random fields, star positions, galaxy-PSF positions,
  noise. The same seed gives an identical field, and the PSF pattern of a seed does not
  depend on ``snr``. A study of N simulations uses
  ``np.random.SeedSequence(seed).spawn(N)``, one child per simulation, as ``random_state``.
"""

from ._field import PSFField, core_mask, make_psf_field, realistic_snr
from ._random_field import RandomFieldSampler, as_generator, gaussian_random_field, random_field_power
from ._reference import ReferenceBasis, read_fits_image

__all__ = [
    "PSFField",
    "RandomFieldSampler",
    "ReferenceBasis",
    "as_generator",
    "core_mask",
    "gaussian_random_field",
    "make_psf_field",
    "random_field_power",
    "read_fits_image",
    "realistic_snr",
]
