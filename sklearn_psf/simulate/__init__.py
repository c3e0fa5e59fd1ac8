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
  the image. They are drawn on a grid of square cells of ``smallest_scale`` arcsec (default
  8 arcsec = 40 pixels at 0.2 arcsec/pixel) and interpolated with cubic splines: the cell is
  the smallest scale of PSF variation (no power at wavelengths below two cells). Their true
  covariance between any positions is :meth:`RandomFieldSampler.covariance` (per field) and
  :meth:`PSFField.weight_covariance` (per component, given the field's draw by default), with
  :meth:`PSFField.coefficient_noise_cov` the stars' true coefficient noise covariance: what
  a best-linear-unbiased oracle needs (tested: its predicted error variance matches its
  actual error over noise draws). Each synthesised stamp is passed through ``StampNormalizer(flux=True,
  center=True)`` (unit sum, adaptive centroid at the stamp centre), the package-wide
  convention; the true ``coeffs`` are the projection of that normalised stamp on the basis,
  i.e. what the measurement pipeline returns for a noiseless star.
- **Why 8 arcsec.** The paper does not give the smallest scale of its simulated PSF, yet it
  sets the interpolation floor of every scheme (noise-free e rms 0.0062 / 0.0084 / 0.0097 for
  cells of 31 / 16 / 8 arcsec). 8 arcsec is the cell the package's study was calibrated with
  (formerly ``grid_size=256`` on the paper's image, 7.9 arcsec) and a conservative choice:
  ground-based PSF patterns keep structure down to tens of arcsec in short exposures, so
  variations on scales below the mean star separation (~1 arcmin at 1 star/arcmin^2) must be
  there, and no interpolator can follow them from the stars: the floor is a property of the
  field, not of a scheme. Larger values (e.g. 30 arcsec) give smoother, easier fields.
- **Positions.** Random positions are uniform within pixels (``subpixel=True``, default)
  and each PSF is drawn at its exact position: its centred truth stamp shifted by the
  sub-pixel offset from the nearest pixel (a Fourier phase ramp, exact and flux-conserving
  for a band-limited PSF), then added around that pixel. ``cut_stamps`` (nearest pixel) +
  ``StampNormalizer`` (adaptive centroid to the stamp centre) undo the shift and recover the
  truth stamp. ``subpixel=False`` puts every PSF on an integer pixel centre (x = column,
  y = row, 0-based), the paper's setting. PSFs lie at least half a stamp from the edges; no
  two stamps overlap (random positions closer than one stamp side along both x and y to an
  already placed PSF are re-drawn; 8 pixels more when stars carry contaminants, so that a
  neighbour's or a galaxy's light stays out of the other stars' stamps).
- **S/N** = mean of the star's pixels / background rms (the paper's definition), "the star's
  pixels" being the pixels of its noiseless stamp at or above half of the stamp's peak (the
  FWHM core, :func:`core_mask`). The flux of a star is ``snr * noise_rms / mean(core pixels
  of its unit-flux stamp)``. :func:`realistic_snr` draws the paper's realistic distribution
  (20 to 1000, peaking at 100).
- **Galaxy-PSFs** are drawn in the image with a fixed S/N (``galaxy_snr=1000``) or left out
  (``galaxy_snr=None``); their noiseless stamps (``field.galaxies["stamp"]``) are the truth a
  PSF model must predict.
- **Noise and weights** (:class:`DetectorSettings`, ``make_psf_field``'s ``detector``).
  White Gaussian background of rms ``noise_rms`` (default: the reference image's background
  rms), float32, zero mean (a sky-subtracted image); with
  ``gain`` (electrons per image unit) also the Poisson noise of the sources. ``field.weight``
  is the inverse variance of each pixel (``1 / (noise_rms^2 + source / gain)``), 0 on masked
  pixels: ``masked_fraction`` of random bad pixels and ``bad_columns`` full columns, where the
  image holds ``mask_value`` (0 by default: what a sky-subtracted image with a weight map
  usually holds; ``numpy.nan`` is the alternative), and saturated pixels (above
  ``saturation``), clipped to the saturation level as in real data.
  :meth:`PSFField.star_stamps` returns the weight stamps with ``return_weights=True`` and
  :meth:`PSFField.coefficient_noise_cov` each star's true coefficient noise covariance.
- **Seeds.** ``random_state`` (int, SeedSequence or Generator) seeds one generator that
  spawns seven independent streams: random fields, star positions, galaxy-PSF positions,
  noise, sub-pixel offsets, contaminants, detector defects. The same seed gives an identical
  field, the PSF pattern of a seed does not depend on ``snr``, and the detector defects do
  not move the stars (contaminants on stars widen the spacing, see *Positions*). A study of N simulations uses
  ``np.random.SeedSequence(seed).spawn(N)``, one child per simulation, as ``random_state``.

Contaminants
------------
``make_psf_field(contaminants={"cosmic_ray": 0.05, "neighbour": 0.05, ...})`` (short for
``contaminants=ContaminantSettings(fractions={...})``, :class:`ContaminantSettings`) gives that
fraction of the stars (exact count, random stars) each contaminant; the default is none
(the paper's study stays clean). The truth is ``field.stars["contaminant"]`` ("" = clean)
and ``field.contaminants`` (one row each). Strengths are drawn from realistic ranges:

- ``"cosmic_ray"``: a 1-3 pixel track (or single hit) starting within 3 pixels of the star's
  centre, not convolved with the PSF, of amplitude the larger of 30-300 sky sigma
  (log-uniform; typical hits of a few thousand electrons over a sky noise of ~10-30 e-) and
  20-100% of the star's peak (a fainter hit on a bright star's core is hidden by it);
- ``"neighbour"``: a fainter star 3-8 pixels away (inside the stamp, unresolved by a
  detection with a 5-pixel minimum area) with 10-50% of the star's flux (log-uniform), same
  PSF;
- ``"galaxy"``: the star replaced by an exponential galaxy of the same flux, half-light
  radius 1-3 times the PSF's (1.18 x its moments sigma), axis ratio 0.4-0.9, random
  orientation, convolved with the local PSF (a compact galaxy on the stellar locus);
- ``"binary"``: an unresolved companion 0.5-4 pixels away (uniform) with 1-20% of the
  star's flux (log-uniform), same PSF, total flux kept: most are faint, and a companion of
  a few per cent at 1-3 pixels widens the star by more than the noise of a bright star.

``ContaminantSettings(ranges=...)`` sets other flux ratios and separations for binaries and
neighbours (e.g. ``{"binary": {"flux_ratio": (0.02, 0.08), "separation": (1, 3)}}``).
Contaminants come at this natural strength, many below the star's noise: a detector is
judged on what it catches of those that move the PSF (size, ellipticity), not on all. Its
``min_snr`` (default 0: off) strengthens each contaminant whose own signal, the square root
of the chi^2 it adds to the star's stamp after the flux and centroid are matched (column
``contaminant_snr``), is below it (amplitude x2, neighbour flux x1.5, galaxy radius x1.4,
binary separation and ratio x1.3, up to 6 times within caps), for tests on contaminants the
data reveal. Its ``n_field_cosmic_rays`` and ``n_field_galaxies`` put cosmic rays and
galaxies (S/N from :func:`realistic_snr`) elsewhere in the image, away from stars, for
catalogue-level tests.

Relation to :mod:`sklearn_psf.datasets`: the reference bases are data
(:class:`~sklearn_psf.datasets.ReferenceBasis`, re-exported here); ``simulate`` imports
``datasets``, never the reverse.
"""

from ..datasets import ReferenceBasis, read_fits_image
from ._chromatic import blackbody_colour, refraction
from ._example import write_example_exposure, write_example_ldac
from ._exposures import ExposureSet, make_exposures
from ._field import PSFField, core_mask, realistic_snr
from ._galsim_ccd import GalSimCCD, render_galsim_ccd
from ._make import make_psf_field
from ._random_field import RandomFieldSampler, as_generator, gaussian_random_field, random_field_power
from ._settings import ContaminantSettings, DetectorSettings, SourceSettings

__all__ = [
    "ContaminantSettings",
    "DetectorSettings",
    "ExposureSet",
    "GalSimCCD",
    "PSFField",
    "RandomFieldSampler",
    "ReferenceBasis",
    "SourceSettings",
    "as_generator",
    "blackbody_colour",
    "core_mask",
    "gaussian_random_field",
    "make_exposures",
    "make_psf_field",
    "random_field_power",
    "read_fits_image",
    "realistic_snr",
    "render_galsim_ccd",
    "refraction",
    "write_example_exposure",
    "write_example_ldac",
]
