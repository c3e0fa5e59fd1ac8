"""A PSF basis on a finer grid than the pixels, fitted on undersampled stars at their phases."""

from __future__ import annotations

import numbers
from dataclasses import dataclass
from numbers import Integral, Real

import numpy as np

from sklearn.base import _fit_context
from sklearn.utils._param_validation import Interval, StrOptions
from sklearn.utils.validation import check_is_fitted

from ..measure import adaptive_moments, fixed_moments
from ._noise import correlated_noise_factor, noise_correlation, standardised_residuals
from ._normalize import phase_ramp
from ._pca_noise import star_weights, sum_zero, weighted_pca
from ._stamp_weights import (border_level, has_background, model_weights, poisson_slope,
                             variances)
from ._stamp_basis import FALLBACK_SIGMA, _BaseStampBasis, normal_inverse, stamp_fwhm
from ._superres_grid import _CHUNK, _FineGrid

__all__ = ["SuperResolvedPCA", "UNDERSAMPLED_FWHM"]

#: Median star FWHM (pixels) below which stars count as undersampled (``PSFModel`` then
#: chooses :class:`SuperResolvedPCA`).
UNDERSAMPLED_FWHM = 2.0
_STEPS = 4  # Gauss-Newton steps on each star's offset
_GN_TOL = 1e-4
_MEAN_ROUNDS = 10  # at most, rounds of (mean, stars' offsets) before the components
_OFFSET_TOL = 1e-3  # pixels: the offsets have converged
_STALL = 0.5  # the offsets' median move shrinks by less than this from one round to the next:
# they wander within their noise (the mean's rounds stop)
_JOINT_ROUNDS = 4  # rounds of the spatial refinement (converged on Euclid-like stars)
_REFINED_ITER = 2  # at most, rounds of the components' fit before the spatial refinement
_STARS_PER_TERM = 30  # spatial_degree="auto": stars per term of the polynomial, at least
_MAX_DEGREE = 3  # spatial_degree="auto": at most


@dataclass
class _Stamps:
    """The stamps of a fit and what the fit updates about them."""

    d: np.ndarray  # (n, p) pixels, 0 where masked
    w: np.ndarray  # (n, p) pixel weights (their Poisson part from the models once fitted)
    w_given: np.ndarray  # (n, p) the weights given or estimated
    poisson: object  # the weights' Poisson slope (falsy: not computed from the pixels)
    ok: np.ndarray  # (n,) the stars with a first centroid
    usable: np.ndarray  # (n,) the stars that make the fine images
    pixel_var: np.ndarray  # (n,) mean noise variance of each star's pixels
    level: np.ndarray  # (n,) each star's background level


@dataclass
class _StarFits:
    """The stars fitted on fine images (:meth:`SuperResolvedPCA._settled_fits`)."""

    fine: np.ndarray  # (m, S*S) the images, re-centred and normalised
    start: np.ndarray  # (n, 2) the offsets the stars' fits started from
    a: np.ndarray  # (n, m) flux times [1, coefficients]
    model: np.ndarray  # (n, p) model pixels, without the background
    offsets: np.ndarray  # (n, 2) fitted offsets
    level: np.ndarray  # (n,) fitted background levels
    moved_ok: np.ndarray  # (n,) whether the offset fit stayed on the stamp


@dataclass
class _FineFit:
    """The fine images and the stars on them (:meth:`SuperResolvedPCA._fit_images`)."""

    fine: np.ndarray  # (1 + k, S*S) mean and components
    a: np.ndarray  # (n, 1 + k) flux times [1, coefficients]
    offsets: np.ndarray  # (n, 2)
    explained_variance: np.ndarray  # the residuals' PCA variances
    noise_edge: float
    noise_variance: float


class SuperResolvedPCA(_FineGrid, _BaseStampBasis):
    """PCA basis on a grid finer than the pixels, for undersampled stars.

    Stars sampled at under ~2 pixels per FWHM (Euclid VIS, Roman, HST, JWST short
    wavelengths) each show the PSF at their own sub-pixel phase: centring a stamp by
    interpolation, as :class:`StampPCA` does, aliases it. Here the PSF's mean and components
    live on a grid ``oversampling`` times finer than the pixels (as PSFEx's ``PSF_SAMPLING``
    and PIFF's ``PixelGrid`` with a smaller scale), and each star is modelled as its own
    image of it:

    - the fine grid holds the pixel-convolved PSF (GalSim's default rendering, PSFEx's and
      PIFF's convention) sampled every ``1 / oversampling`` pixel; a star's pixels are that
      profile's values at the pixel centres for the star's sub-pixel position, obtained by a
      Fourier (band-limited, sinc) shift of the fine grid followed by keeping every
      ``oversampling``-th sample. This is exact when the pixel-convolved PSF has no power
      beyond the fine grid's Nyquist frequency, ``oversampling / 2`` cycles per pixel: a
      diffraction-limited PSF has none beyond ``D / lambda``, e.g. 0.83 cycles per pixel for
      1.2 m at 700 nm and 0.1" pixels, so ``oversampling=2`` holds it exactly (up to the
      wings beyond the stamp). The fine images are held to a disc in frequency,
      ``band_limit_`` cycles per pixel in radius: beyond the PSF's own band they would hold
      only noise, which a star's sampling aliases into its low frequencies. By default
      (``band_limit="auto"``) the disc is the one that best predicts stars the fit did not
      see: two means, each fitted on half of the stars over the whole square grid, are held
      to discs of radius 0.3, 0.4, ... cycles per pixel and drawn at the other half's stars
      (flux fitted); the disc of the least misfit is kept (with fewer than 20 stars, 45 at
      ``oversampling=3``, the grid's Nyquist disc). Within
      :class:`~sklearn_psf.model.PSFModel` the band is chosen in the first round, on the
      weights given, and held when the basis is fitted again without the outliers (the
      second round's calibrated weights, which hold the first model's error, take the
      weight off the stars' cores, where the band shows). On the Euclid-like CCD of
      ``benchmarks/bench_undersampled.py`` it finds 0.8 cycle per pixel, near the
      diffraction cutoff (0.83); figures in ``benchmarks/README.md``;
    - each star is ``flux * image(mean + c @ components, offset) (+ background)``; flux,
      coefficients, background and the sub-pixel offset are fitted on the star's unmasked
      pixels by weighted least squares (Gauss-Newton on the offset, started from the centre
      of a fixed Gaussian weight, or the adaptive centroid where it converges): centroids
      and fluxes come from the model itself, not from adaptive moments;
    - the fine-grid images are fitted through all stars together by weighted least squares
      (conjugate gradients on the normal equations, pixel weights times each star's weight,
      capped at ``max_star_weight`` times the median as in :class:`StampPCA`), so that stars
      at different phases constrain the fine grid together (the normal equations are a
      convolution in frequency, computed once per solve: an iteration's cost does not grow
      with the number of stars; each star's pixels are drawn by two 1-D sinc matrices). The
      mean and the stars' fluxes and offsets are fitted together by Gauss-Newton steps
      (each star's flux, offset and background profiled out of the fine grid's normal
      equations: variable projection),
      until the offsets move by less than 1e-3 pixel, or from the second step on their
      median move no longer halves from one round to the next (the offsets then wander
      within their noise: on the resampled SDSS frame of ``../shared/realdata`` the median
      move stays ~0.01 pixel for 10 rounds), at most 10 rounds; the mean is
      re-centred after each round so that its adaptive centroid (on the fine grid) is the
      stamp centre (the package's convention), and normalised so that, drawn at the pixels,
      it sums to 1;
    - weights whose Poisson part was computed from the noisy pixels themselves (variances
      exactly ``sky + max(pixel, 0) / gain`` per stamp, as
      :func:`~sklearn_psf.exposure.extract_vignettes` gives them) would weight each pixel by its
      own noise: upward fluctuations less, a bias of about ``-1 / gain`` per pixel that
      narrows the PSF (size bias -0.0005 on the Euclid-like CCDs of
      ``benchmarks/bench_undersampled.py``); that part is taken from the stars' models
      after each round of their fits (and in :meth:`project`). Other weights are used as
      given;
    - the number of components: the stars' residuals from the mean, each drawn at its own
      phase, are PCA'd at the pixels' sampling with the noise edge of :class:`StampPCA`
      (``n_components="noise"``); their coefficients start the fine components, which are
      then fitted with the mean by alternating least squares (the fine images given the
      stars' coefficients and offsets, then each star's fit; a step is halved until the
      weighted residual decreases; ``n_iter`` rounds at most). The components are kept
      orthogonal to the mean's shifts (which the offsets take) and on the PSF's core (the
      fine samples where the mean exceeds 1% of its peak, grown by one pixel): beyond it
      they fit noise (on the package's simulation of 120 stars at S/N 30-1000, the
      ellipticity error at the truth falls from 0.0066 without it to 0.0047);
    - with the stars' positions (``fit(..., positions=...)``, which
      :class:`~sklearn_psf.model.PSFModel` passes) and ``spatial_degree``, a joint
      refinement as PSFEx's: each star's coefficients are set by a polynomial of its
      position whose coefficients are fitted by linear least squares to all stars' pixels
      (given the fine images, the stars' fluxes and offsets), each star's flux, offset and
      background are refitted with its shape so held, and the fine images are refitted
      given the coefficients; 4 rounds, after at most 2 of the rounds above. Alone, each
      star constrains its coefficients through its single phase, where the components
      alias into one another (the error grows with the star's phase); jointly, stars at
      all phases constrain the smooth variation together. On noiseless Euclid-like stars
      the e rms at the truth falls from 0.0071 to 0.0036 (degree 2) and 0.0011 (degree 3).

    ``transform``, ``project`` (with each star's fitted offsets), ``inverse_transform``
    (stamps centred on the centre pixel at the pixels' sampling) and ``render`` (at any
    sub-pixel offset) work at the stars' sampling; :meth:`render_fine` gives the fine
    images (unit sum, centre at the fine grid's central sample).

    Parameters
    ----------
    oversampling : "auto" or int, default="auto"
        Fine samples per pixel. "auto": 2 (a pixel-convolved PSF up to 1 cycle per pixel
        along each axis), more accurate than 3 on real and simulated stars down to a FWHM
        of 1.2 pixels; 3 for a PSF with power well beyond 1 cycle per pixel (diffraction
        on coarse pixels) seen by many bright stars (``benchmarks/README.md``).
    n_components : "noise", int or float, default="noise"
        As :class:`StampPCA`'s.
    max_components : int, default=10
        Upper bound for "noise" and float choices.
    n_iter : int, default=6
        Rounds of (fine-grid fit, star fits) after the mean's. The components converge
        slowly: each star sees them at one phase, where they alias into one another, and
        with too few rounds the stars' coefficients take the error (on noiseless Euclid-like
        stars, e rms at the truth 0.0048 after 3 rounds, 0.0044 after 10, 0.0037 after 30);
        on noisy stars more rounds fit the noise (size rms 0.0010, 0.0014, 0.0018 and 0.0025
        after 3, 6, 10 and 30 rounds, e rms 0.0057, 0.0047, 0.0045, 0.0048). With the
        joint refinement (``spatial_degree`` and positions), at most 2 rounds precede it:
        more change nothing after it.
    max_star_weight : float, default=10.0
        Cap of a star's weight in units of the median star weight.
    guess_sigma : float, default=3.0
        Initial width (pixels) of the adaptive weight used to start the centroids.
    background : "auto" or bool, default="auto"
        As :class:`StampPCA`'s.
    spatial_degree : "auto", int or None, default="auto"
        Degree of the polynomial of the position (x, y) that the components' coefficients
        follow in the joint refinement (see above), used when ``fit`` is given the stars'
        positions and at least 3 stars per term of the polynomial; None or 0: none (the
        stars' own coefficients only, as without positions). "auto": the highest degree up
        to 3 with at least 30 stars per term (3 from 300 stars, 2 from 180, 1 from 90).
        On the Euclid-like CCDs of ``benchmarks/bench_undersampled.py`` (~440 stars; before
        the band limit above), degree 3 gives e rms at the truth 0.0043 and 0.0039 (seeds 3
        and 4; degree 2: 0.0050 and 0.0042; no refinement: 0.0050 and 0.0058); on the
        Roman-like one (~200 stars), degree 2 gives 0.0207 against degree 3's 0.0233.
    band_limit : "auto", float or None, default="auto"
        Radius (cycles per pixel) of the disc of frequencies the fine images hold (see
        above). "auto": the disc that best predicts stars left out. A float: the PSF's
        band limit, the optics' diffraction cutoff ``D / lambda`` times the pixel scale in
        radians (1.2 m at 700 nm with 0.1" pixels: 0.83; 2.4 m at 1.06 um with 0.11"
        pixels: 1.21), clipped by the square grid (``oversampling / 2`` along each axis).
        None: the whole square grid.
    support_radius : "auto", float or None, default="auto"
        Radius (pixels from the centre) beyond which the mean PSF is set to 0 before its
        band limit (which spreads the edge by about a pixel; the components are on the
        mean's core already). "auto": chosen with the band, the radius among 3, 4, 5,
        6, 8 and 10 pixels or none that best predicts stars left out, their flux and a
        constant background fitted. Beyond it the mean would hold what the stars' wings
        share with their surroundings (a crowded field's neighbours, unresolved stars) as
        much as the PSF: on the crowded 2MASS Galactic Centre mosaic it was chosen at 3
        pixels (FWHM 1.3), on Euclid-like stars (FWHM 1.5) at 8. None: the whole stamp.
    fit_size : "auto", odd int or None, default="auto"
        Side (pixels) of the square about each star that the fine images model, as PSFEx's
        ``PSF_SIZE``: the images are fitted on these pixels of each stamp only and are 0
        beyond them (the other pixels still give each star's background level: the fit
        starts from the whole stamp's border, :meth:`project` fits them as one pixel of
        their summed weight). "auto": ``2 * max(12, 5 * fwhm_) + 1`` pixels, within the
        stamp (25 for undersampled stars, PSFEx's default ``PSF_SIZE`` at its native
        sampling); the fit's cost grows with the side's square. None: the whole stamp.

    Attributes
    ----------
    fine_mean_ : ndarray of shape (S*S,)
        Mean PSF on the fine grid (S = ``fine_size_``), unit sum.
    fine_components_ : ndarray of shape (n_components_, S*S)
        Fine components, orthonormal and summing to zero.
    mean_, components_ : ndarray
        The same drawn at the pixels' sampling, centred (the star at the centre pixel).
    oversampling_ : int
    fine_size_ : int
        Side S of the fine grid (odd; the PSF centre at its central sample), over the
        ``fit_size_`` square.
    fwhm_ : float
        Median FWHM of the stars (pixels).
    spatial_degree_ : int
        Degree of the joint refinement's polynomial; 0 when none ran (no positions,
        ``spatial_degree`` None or 0, too few stars, or no component).
    band_limit_ : float
        Radius (cycles per pixel) of the fine images' disc of frequencies; the square
        grid's corner, ``oversampling_ / sqrt(2)``, for ``band_limit=None``.
    support_radius_ : float
        Radius (pixels) beyond which the mean is 0; infinite for none.
    fit_size_ : int
        Side (pixels) of the square the fine images model (``fine_size_`` covers it);
        ``stamp_size_`` for the whole stamp.
    explained_variance_, noise_variance_, noise_edge_ : float or ndarray
        Of the PCA of the residuals at the pixels' sampling (see above).
    background_ : bool
    n_components_ : int
    stamp_size_ : int
    n_features_in_ : int

    See Also
    --------
    StampPCA : the basis at the pixels' sampling (well-sampled stars).
    sklearn_psf.model.PSFModel : chooses this basis when the stars are undersampled.

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.preprocessing import SuperResolvedPCA
    >>> rng = np.random.default_rng(0)
    >>> yy, xx = np.mgrid[0:11, 0:11] - 5.0
    >>> off = rng.uniform(-0.5, 0.5, (60, 2, 1, 1))
    >>> stars = 1e4 * np.exp(-0.5 * ((xx - off[:, 0]) ** 2 + (yy - off[:, 1]) ** 2) / 0.6**2)
    >>> stamps = (stars + rng.normal(0, 3.0, stars.shape)).reshape(60, -1)
    >>> basis = SuperResolvedPCA().fit(stamps)
    >>> basis.oversampling_, basis.fine_size_
    (2, 23)
    >>> fit = basis.project(stamps)
    >>> bool(np.abs(fit.offsets - off[:, :, 0, 0]).max() < 0.02)
    True
    """

    _parameter_constraints: dict = {
        **_BaseStampBasis._parameter_constraints,
        "oversampling": [StrOptions({"auto"}), Interval(Integral, 1, None, closed="left")],
        "spatial_degree": [StrOptions({"auto"}), Interval(Integral, 0, None, closed="left"),
                           None],
        "band_limit": [StrOptions({"auto"}), Interval(Real, 0, np.inf, closed="neither"),
                       None],
        "support_radius": [StrOptions({"auto"}), Interval(Real, 0, None, closed="neither"),
                           None],
        "fit_size": [StrOptions({"auto"}), Interval(Integral, 3, None, closed="left"), None],
    }

    def __init__(self, oversampling="auto", n_components="noise", max_components: int = 10,
                 n_iter: int = 6, max_star_weight: float = 10.0, guess_sigma: float = 3.0,
                 background="auto", spatial_degree="auto", band_limit="auto",
                 support_radius="auto", fit_size="auto"):
        self.oversampling = oversampling
        self.n_components = n_components
        self.max_components = max_components
        self.n_iter = n_iter
        self.max_star_weight = max_star_weight
        self.guess_sigma = guess_sigma
        self.background = background
        self.spatial_degree = spatial_degree
        self.band_limit = band_limit
        self.support_radius = support_radius
        self.fit_size = fit_size

    _state_attributes = _BaseStampBasis._state_attributes + (
        "fine_mean_", "fine_components_", "oversampling_", "fine_size_", "fwhm_",
        "spatial_degree_", "band_limit_", "support_radius_", "fit_size_")

    def _refit_params(self):
        """The parameters that fix what this fit chose from the stars, for fitting the basis
        again on fewer of them (:class:`~sklearn_psf.model.PSFModel`'s outlier round): the
        band of ``band_limit="auto"`` and the support of ``support_radius="auto"``."""
        held = {"band_limit": self.band_limit_} if self.band_limit == "auto" else {}
        if self.support_radius == "auto":
            held["support_radius"] = (float(self.support_radius_)
                                      if np.isfinite(self.support_radius_) else None)
        return held

    def _set_state(self, state):
        state = {"spatial_degree_": 0,  # (states written before the joint refinement: none)
                 # (before band_limit_ was recorded: the grid's Nyquist disc)
                 "band_limit_": int(state["oversampling_"]) / 2.0,
                 "support_radius_": np.inf,  # (before the support: none)
                 "fit_size_": state["stamp_size_"], **state}  # (before the crop: none)
        super()._set_state(state)
        self.oversampling_, self.fine_size_ = int(self.oversampling_), int(self.fine_size_)
        self.spatial_degree_ = int(self.spatial_degree_)
        self.fwhm_, self.band_limit_ = float(self.fwhm_), float(self.band_limit_)
        self.support_radius_ = float(self.support_radius_)
        self.fit_size_ = int(self.fit_size_)
        self.fine_mean_ = np.asarray(self.fine_mean_, dtype=np.float64).reshape(-1)
        self.fine_components_ = np.asarray(self.fine_components_, dtype=np.float64).reshape(
            self.n_components_, -1)
        return self

    # -- the stars' fits on the basis -----------------------------------------------------
    def _fit_stars(self, d, w, offsets, fine, steps=_STEPS, held=None):
        """Per-star ``a`` (flux times [1, c]), its covariance, model (without background),
        offsets, background level and whether the offset fit stayed on the stamp. With
        ``held`` (n, m - 1), each star's coefficients are held at its row: only its flux,
        offset and background are fitted (``a``: the flux, (n, 1))."""
        n, p = d.shape
        s = self.fit_size_
        pad = p - s * s  # (a last column: the pixels beyond the square, summed; model 0)

        def padded(x):
            return np.concatenate([x, np.zeros(x.shape[:-1] + (pad,))], axis=-1) if pad else x

        mix = None if held is None else np.column_stack([np.ones(n), held])
        m = fine.shape[0] if held is None else 1
        extra = int(self.background_)
        offsets = offsets.copy()
        start = offsets.copy()
        a = np.full((n, m), np.nan)
        cov = np.full((n, m, m), np.nan)
        level = np.zeros(n)
        model = np.zeros((n, p))
        for lo in range(0, n, _CHUNK):
            sl = slice(lo, min(lo + _CHUNK, n))
            for step in range(steps + 1):
                A, slope = self._draw(fine, offsets[sl], None if mix is None else mix[sl],
                                      gradient=True)
                A = padded(A if mix is None else A[:, None])
                if extra:
                    A = np.concatenate([A, np.ones((A.shape[0], 1, p))], axis=1)
                Aw = A * w[sl, None, :]
                normal = Aw @ A.transpose(0, 2, 1)
                inv = normal_inverse(normal)
                sol = (inv @ (Aw @ d[sl, :, None]))[:, :, 0]
                if step == steps:
                    break
                # Gauss-Newton on the offsets, with flux, coefficients and background
                G = np.concatenate([A, padded(slope(sol[:, :m]))], axis=1)
                Gw = G * w[sl, None, :]
                resid = d[sl] - (sol[:, None, :] @ A)[:, 0]
                move = (normal_inverse(Gw @ G.transpose(0, 2, 1))
                        @ (Gw @ resid[:, :, None]))[:, -2:, 0]
                move = np.where(np.isfinite(move), np.clip(move, -0.3, 0.3), 0.0)
                offsets[sl] += move
            a[sl], cov[sl] = sol[:, :m], inv[:, :m, :m]
            if extra:
                level[sl] = sol[:, m]
            model[sl] = (sol[:, None, :m] @ A[:, :m])[:, 0]
        ok = np.isfinite(offsets).all(axis=1) & (np.abs(offsets - start).max(axis=1) < 2.0) \
            & (np.abs(offsets).max(axis=1) < 0.5 * s)
        offsets[~ok] = start[~ok]
        return a, cov, model, offsets, level, ok

    # -- the fine images' joint fit -----------------------------------------------------------
    def _jacobian(self, fine, a, offsets):
        """Each star's model pixels (n, p) and the rows (n, q, p) of the parameters profiled
        out of the fine images' Gauss-Newton step: its flux (the model over the flux), a
        constant (with a background) and its offset. The coefficients on the components
        are held: given them, the components are linear (alternating with the stars' fits,
        as alternating least squares does for a PCA), without the scale and rotation a
        joint step would leave free."""
        n = len(a)
        s = self.fit_size_
        model = np.empty((n, s * s))
        rows = []
        for lo in range(0, n, _CHUNK):
            sl = slice(lo, min(lo + _CHUNK, n))
            model[sl], slope = self._draw(fine, offsets[sl], a[sl], gradient=True)
            flux = np.where(a[sl, 0] != 0, a[sl, 0], 1.0)
            parts = [model[sl, None] / flux[:, None, None], slope(np.ones((len(flux), 1)))]
            if self.background_:
                parts.insert(1, np.ones((len(flux), 1, s * s)))
            rows.append(np.concatenate(parts, axis=1))
        return model, np.concatenate(rows)

    def _settle(self, fine):
        """Fine images band-limited (:meth:`_band`) and re-centred (:meth:`_recentre`), the
        mean normalised to unit sum, the components on the support, orthogonal to the mean's
        shifts (both before their band limit), orthonormal and summing to zero; the move
        (pixels) to add to the stars' offsets."""
        if np.isfinite(self.support_radius_):  # the mean set to 0 beyond its support
            fine = np.vstack([fine[:1] * self._disc(self.support_radius_), fine[1:]])
        fine, move = self._recentre(self._band_limited(fine))
        mean = fine[0] / fine[0].sum()
        comps = fine[1:]
        if len(comps):
            frame = self._frame(fine)
            comps = self._band_limited((comps - (comps @ frame.T) @ frame)
                                       * self._support(fine))
            comps = sum_zero(comps, mean)
        return np.vstack([mean[None], comps]), move

    def _recentre(self, fine):
        """Fine images moved so that the mean's centroid is the central sample; the move
        (pixels) to add to the stars' offsets."""
        size = self._grid(self.fit_size_)[1]
        f = self.oversampling_
        img = fine[:1].reshape(1, size, size)
        mom = adaptive_moments(img, guess_sigma=f * FALLBACK_SIGMA)
        if int(mom["flag"][0]) != 0:
            mom = fixed_moments(img, f * FALLBACK_SIGMA)
        c = (size - 1) / 2.0
        dx, dy = float(mom["x0"][0]) - c, float(mom["y0"][0]) - c
        if not (np.isfinite(dx) and np.isfinite(dy)):
            return fine, np.zeros(2)
        ramp = phase_ramp(size, np.array([-dx]), np.array([-dy]))
        moved = np.fft.irfft2(np.fft.rfft2(fine.reshape(-1, size, size)) * ramp,
                              s=(size, size)).reshape(fine.shape)
        return moved, np.array([dx, dy]) / f

    # -- estimator API ------------------------------------------------------------------------
    def _check_params(self):
        super()._check_params()
        o = self.oversampling
        if not (o == "auto" if isinstance(o, str) else
                isinstance(o, numbers.Integral) and not isinstance(o, bool) and o >= 1):
            raise ValueError(f"oversampling must be 'auto' or an int >= 1, got {o!r}.")
        g = self.spatial_degree
        if not (g is None or g == "auto" if isinstance(g, str) or g is None else
                isinstance(g, numbers.Integral) and not isinstance(g, bool) and g >= 0):
            raise ValueError(f"spatial_degree must be 'auto', None or an int >= 0, got {g!r}.")
        b = self.band_limit
        if not (b is None or (b == "auto" if isinstance(b, str) else
                              isinstance(b, numbers.Real) and not isinstance(b, bool)
                              and np.isfinite(b) and b > 0)):
            raise ValueError(f"band_limit must be 'auto', None or a positive number (cycles "
                             f"per pixel), got {b!r}.")
        r = self.support_radius
        if not (r is None or (r == "auto" if isinstance(r, str) else
                              isinstance(r, numbers.Real) and not isinstance(r, bool)
                              and r > 0)):
            raise ValueError(f"support_radius must be 'auto', None or a positive number "
                             f"(pixels), got {r!r}.")
        t = self.fit_size
        if not (t is None or (t == "auto" if isinstance(t, str) else
                              isinstance(t, numbers.Integral) and not isinstance(t, bool)
                              and t >= 3 and t % 2)):
            raise ValueError(f"fit_size must be 'auto', None or an odd int >= 3 (pixels), "
                             f"got {t!r}.")

    @_fit_context(prefer_skip_nested_validation=True)
    def fit(self, X, y=None, weights=None, positions=None):
        """Fit the fine-grid basis on raw star stamps.

        Parameters
        ----------
        X : array-like of shape (n, s*s)
            Raw star stamps (odd side s, the star near the centre pixel), NaN for masked
            pixels. Not modified.
        y : ignored
        weights : array-like of shape (n, s*s), optional
            Inverse variance of each pixel (0 = masked). Default: estimated from each
            stamp's border.
        positions : array-like of shape (n, 2) or (n, d), optional
            The stars' positions (x, y; further columns are ignored), which
            :class:`~sklearn_psf.model.PSFModel` passes: with ``spatial_degree``, the
            components are refined with coefficients that follow a polynomial of them.

        Returns
        -------
        self : SuperResolvedPCA
        """
        self._fit(X, weights, positions)
        return self

    def _fit(self, X, weights, positions=None):
        """:meth:`fit`; returns None (:meth:`fit_project` then projects the stars)."""
        self._check_params()
        d, w, s = self._stamps_and_weights(X, weights, reset=True)
        if positions is not None:
            positions = np.asarray(positions, dtype=np.float64)
            if positions.ndim != 2 or positions.shape[0] != len(d) or positions.shape[1] < 2:
                raise ValueError(f"positions must have shape (n_stars, 2) for the {len(d)} "
                                 f"stamps, got {positions.shape}.")
            if not np.isfinite(positions[:, :2]).all():
                raise ValueError("positions must be finite.")
        if s % 2 == 0:
            raise ValueError(f"SuperResolvedPCA needs stamps of odd side (the star at the "
                             f"centre pixel), got {s}x{s}.")
        self.stamp_size_ = s
        self.background_ = bool(has_background(d, w, s) if self.background == "auto"
                                else self.background)
        level = border_level(d, w, s)[0] if self.background_ else np.zeros(len(d))
        offsets, ok = self._centroids(d - level[:, None], w, s)
        flux = ((d - level[:, None]) * (w > 0)).sum(axis=1)
        usable = ok & (flux > 0)
        if usable.sum() < 2:
            raise ValueError("Fewer than 2 stamps have a measurable centroid and a positive "
                             "flux: these are not star stamps.")
        fwhm = stamp_fwhm((d - level[:, None])[usable], w[usable])
        self.fwhm_ = float(np.nanmedian(fwhm)) if np.isfinite(fwhm).any() else np.nan
        self.oversampling_ = 2 if self.oversampling == "auto" else int(self.oversampling)
        b = self.band_limit
        self.band_limit_ = (self.oversampling_ / 2.0 if b == "auto" else
                            np.sqrt(2.0) * self.oversampling_ / 2.0 if b is None else float(b))
        r = self.support_radius
        self.support_radius_ = np.inf if r is None or isinstance(r, str) else float(r)
        # the fine images model the square of side fit_size_ about each star (0 beyond it)
        self.fit_size_ = t = self._fit_side(s)
        d, w = self._crop(d, s, t), self._crop(w, s, t)
        stamps = _Stamps(d=d, w=w, w_given=w, poisson=poisson_slope(d, w), ok=ok,
                         usable=usable, pixel_var=variances(w).mean(axis=1), level=level)
        degree = 0 if positions is None else self._spatial_degree(int(usable.sum()))
        fit = self._fit_images(stamps, flux, offsets, degree)
        fine, k = fit.fine, fit.fine.shape[0] - 1
        if degree and k:
            fine = self._refine(stamps, positions[:, :2], degree, fine, fit.a, fit.offsets)
        self.spatial_degree_ = int(degree) if k else 0
        self.fine_mean_ = fine[0]
        self.fine_components_ = fine[1:]
        self.explained_variance_ = fit.explained_variance
        self.noise_variance_ = fit.noise_variance
        self.noise_edge_ = fit.noise_edge
        self.n_components_ = int(fine.shape[0] - 1)
        self.fine_size_ = self._grid(t)[1]
        self._n_features_out = self.n_components_
        drawn = self._embed(self._draw(fine, np.zeros((1, 2)))[0], t, s)
        self.mean_, self.components_ = drawn[0], drawn[1:]

    def _pixel_weights(self, stamps, flux):
        """The fine images' fit's weight of each pixel: its weight times its star's weight
        (``1 / v``, ``v`` the star's noise per pixel at ``flux``, capped as in
        :class:`StampPCA`), of the stars ``stamps.usable``."""
        safe = np.where(stamps.usable, np.abs(flux), 1.0)
        u = star_weights(stamps.pixel_var / safe**2, stamps.usable, self.max_star_weight)
        return stamps.w * (u * stamps.pixel_var / safe**2)[:, None]

    def _settled_fits(self, stamps, fine, offsets):
        """Re-centred, normalised fine images (:meth:`_settle`) and the stars' fits on them."""
        fine, move = self._settle(fine)
        a, cov, model, moved, level, moved_ok = self._fit_stars(stamps.d, stamps.w,
                                                                offsets + move, fine)
        return _StarFits(fine=fine, start=offsets + move, a=a, model=model, offsets=moved,
                         level=level, moved_ok=moved_ok)

    @staticmethod
    def _misfit(stamps, u, model, level):
        """Weighted squared residual of the usable stars from their models."""
        return float((u * (stamps.d - model - level[:, None]) ** 2)[stamps.usable].sum())

    def _fit_images(self, stamps, flux, offsets, degree):
        """The fine images and the stars' amplitudes and offsets: the mean's rounds (a
        Gauss-Newton step of the images, each star's flux, offset and background profiled
        out, shortened until the fit improves) until the offsets converge, then the
        components' count and their rounds (alternating least squares), at most ``n_iter``
        (``_REFINED_ITER`` before a joint refinement of ``degree``). ``stamps`` is updated
        (usable stars, weights, background levels)."""
        size = self._grid(self.fit_size_)[1]
        a = np.where(stamps.usable, flux, 0.0)[:, None]
        fine = np.zeros((1, size * size))
        lam, edge, noise = np.zeros(0), np.nan, np.nan
        k, counted, joint, typical = 0, False, 0, np.inf
        n_iter = min(int(self.n_iter), _REFINED_ITER) if degree else int(self.n_iter)
        u = self._pixel_weights(stamps, a[:, 0])
        fine = self._fit_fine(stamps.d - stamps.level[:, None], u, a, offsets, fine)
        for round_ in range(_MEAN_ROUNDS + n_iter):
            trial = None
            if round_:  # a Gauss-Newton step of the fine images and the stars' parameters,
                # shortened until the fit improves
                u = self._pixel_weights(stamps, a[:, 0])
                previous = self._misfit(stamps, u, model, fitted)
                target = stamps.d - stamps.level[:, None]
                if k:  # with components: the images given the stars' parameters (least
                    # squares; alternating with the stars' fits, as for a PCA)
                    step = self._fit_fine(target, u, a, offsets, fine,
                                          frame=self._support(fine)) - fine
                else:
                    model, J = self._jacobian(fine, a, offsets)
                    step = self._fit_fine(target - model, u, a, offsets,
                                          np.zeros_like(fine), J, _GN_TOL)
                for damping in (1.0, 0.5, 0.25, 0.125):
                    candidate = self._settled_fits(stamps, fine + damping * step, offsets)
                    if self._misfit(stamps, u, candidate.model, candidate.level) <= previous:
                        trial = candidate
                        break
            else:
                trial = self._settled_fits(stamps, fine, offsets)
            change, stalled = 0.0, False  # no step improves the fit: converged
            if trial is not None:
                fine, a, model, offsets = trial.fine, trial.a, trial.model, trial.offsets
                fitted, moved_ok = trial.level, trial.moved_ok
                moved = np.abs(offsets - trial.start)[stamps.usable]
                change = float(moved.max())
                stalled, typical = (round_ >= 2 and np.median(moved) > _STALL * typical,
                                    float(np.median(moved)))
            good = (a[:, 0] > 0) & moved_ok
            stamps.usable = stamps.ok & good
            if stamps.usable.sum() < 2:
                raise ValueError("Fewer than 2 stamps keep a positive flux on the basis: these "
                                 "are not star stamps.")
            if self.background_:
                stamps.level = np.where(good, fitted, stamps.level)
            a = np.where(stamps.usable[:, None], a, 0.0)
            if stamps.poisson and trial is not None:  # the Poisson part from the stars' models
                stamps.w = model_weights(stamps.d, stamps.w_given, np.where(
                    stamps.usable[:, None], model + stamps.level[:, None], np.nan),
                    stamps.poisson)
                stamps.pixel_var = variances(stamps.w).mean(axis=1)
            if counted:
                joint += 1
                if joint >= n_iter or trial is None:
                    break
            elif change < _OFFSET_TOL or stalled or round_ + 1 >= _MEAN_ROUNDS:
                # the mean and the offsets have converged: how many components the stars hold
                counted = True
                target = stamps.d - stamps.level[:, None]
                if "auto" in (self.band_limit, self.support_radius):  # what the stars hold
                    self._choose_band_and_support(target, self._pixel_weights(stamps, a[:, 0]),
                                                  a, offsets, stamps.usable)
                    fine = self._band_limited(fine)  # (the support: from the next _settle)
                k, lam, edge, noise, coef = self._components(
                    target, stamps.w, a, offsets, fine, stamps.usable, stamps.pixel_var)
                a = np.column_stack([a[:, 0], a[:, :1] * coef])
                fine = np.vstack([fine, np.zeros((k, size * size))])
        return _FineFit(fine=fine, a=a, offsets=offsets, explained_variance=lam,
                        noise_edge=edge, noise_variance=noise)

    def _spatial_degree(self, n_stars):
        """Degree of the joint refinement's polynomial for ``n_stars`` usable stars; 0 for
        none (``spatial_degree`` None or 0, or fewer than 3 stars per term)."""
        if self.spatial_degree == "auto":  # the highest with enough stars per term
            return max(g for g in range(_MAX_DEGREE + 1)
                       if g == 0 or (g + 1) * (g + 2) // 2 * _STARS_PER_TERM <= n_stars)
        degree = int(self.spatial_degree or 0)
        return degree if n_stars >= 3 * (degree + 1) * (degree + 2) // 2 else 0

    def _refine(self, stamps, positions, degree, fine, a, offsets):
        """The fine images refitted with each star's coefficients on the components set by
        a polynomial of its position (of degree ``degree``), fitted jointly to all stars'
        pixels, as PSFEx's: alternately the polynomial (linear least squares over all
        stars, given the images, fluxes and offsets), each star's flux, offset and
        background with its shape held, and the fine images given the coefficients."""
        d, w, level, usable = stamps.d, stamps.w, stamps.level, stamps.usable
        z = positions - positions.min(axis=0)
        z = 2.0 * z / np.where(z.max(axis=0) > 0, z.max(axis=0), 1.0) - 1.0  # in [-1, 1]
        terms = np.column_stack([z[:, 0] ** i * z[:, 1] ** (t - i)
                                 for t in range(degree + 1) for i in range(t + 1)])
        flux = a[:, 0]
        for _ in range(_JOINT_ROUNDS):
            if usable.sum() < 3 * terms.shape[1]:  # too many stars lost on the way
                break
            u = self._pixel_weights(stamps, flux) * usable[:, None]
            mean = self._draw(fine[:1], offsets)[:, 0]
            coef = terms @ self._spatial_fit(d - level[:, None] - flux[:, None] * mean, u,
                                             flux, offsets, fine, terms)
            flux, _, _, offsets, fitted, moved_ok = self._fit_stars(d, w, offsets, fine,
                                                                    held=coef)
            flux = flux[:, 0]
            good = (flux > 0) & moved_ok
            usable = usable & good
            if self.background_:
                level = np.where(good, fitted, level)
            amp = np.where(usable[:, None], flux[:, None] * np.column_stack(
                [np.ones(len(d)), coef]), 0.0)
            fine = self._fit_fine(d - level[:, None],
                                  self._pixel_weights(stamps, flux) * usable[:, None], amp,
                                  offsets, fine, frame=self._support(fine))
            fine, move = self._settle(fine)
            offsets = offsets + move
        return fine

    def _components(self, d, w, a, offsets, fine, usable, pixel_var):
        """Number of components, PCA variances, noise edge and noise of the residuals from
        the mean (each star at its phase, at the pixels' sampling) and each star's
        coefficients on the kept principal axes."""
        p = d.shape[1]
        flux = np.where(usable, a[:, 0], 1.0)
        drawn = self._draw(fine[:1], offsets)[:, 0]
        resid = np.where(w > 0, d / flux[:, None] - drawn, 0.0)
        v = pixel_var / flux**2
        u = star_weights(v, usable, self.max_star_weight)
        n_top = int(self.max_components) + 1
        if isinstance(self.n_components, numbers.Integral):
            n_top = max(n_top, int(self.n_components))
        centre, axes, lam, total = weighted_pca(resid[usable], u[usable], n_top)
        noise = float((u * v).sum() / u.sum())
        kernel = noise_correlation(standardised_residuals(
            (d / flux[:, None])[usable], drawn[usable], flux[usable], w[usable]))
        raise_by = correlated_noise_factor(kernel, v[usable], u[usable], self.fit_size_)
        k, edge = self._choose(lam, total, noise, u[usable] * v[usable] / u.sum(), p,
                               raise_by)
        coef = (resid - centre) @ axes[:k].T
        return k, lam, edge, noise, np.where(usable[:, None], coef, 0.0)

    def _project_stars(self, d, w, offsets, s):
        """Each star fitted through its own phase on the fine grid (Gauss-Newton on the
        offset from :class:`StampPCA`'s centroid), on the square of ``fit_size_``; the
        pixels beyond it, where the model is 0, enter the background level as one pixel of
        their summed weight and mean value (the same least squares as each of them)."""
        fine = np.vstack([self.fine_mean_[None], self.fine_components_])
        t = self.fit_size_
        if t < s:
            box = self._crop(np.arange(s * s)[None], s, t)[0]
            out = np.ones(s * s, dtype=bool)
            out[box] = False
            if self.background_:
                w_out = w[:, out].sum(axis=1)
                d_out = (w * d)[:, out].sum(axis=1) / np.where(w_out > 0, w_out, 1.0)
                d, w = np.column_stack([d[:, box], d_out]), np.column_stack([w[:, box], w_out])
            else:
                d, w = d[:, box], w[:, box]
        a, cov, model, offsets, level, ok = self._fit_stars(d, w, offsets, fine)
        return a, cov, self._embed(model[:, :t * t], t, s), offsets, level, ok

    def render(self, coefficients, flux=1.0, offsets=None):
        """Model stamps at the pixels' sampling, the star at ``offsets`` from the centre.

        ``flux * image(mean + c @ components, offset)``, drawn from the fine grid (see the
        class description): a star's pixels at any sub-pixel position, not a shifted stamp.

        Parameters
        ----------
        coefficients : array-like of shape (n, n_components_)
        flux : float or array-like of shape (n,), default=1
        offsets : array-like of shape (n, 2), optional
            (dx, dy) of the star from the centre pixel; default none.

        Returns
        -------
        stamps : ndarray of shape (n, s*s)
        """
        check_is_fitted(self)
        coef = self._check_coefficients(coefficients)
        n = coef.shape[0]
        off = np.zeros((n, 2)) if offsets is None else np.asarray(
            offsets, dtype=np.float64).reshape(n, 2)
        fine = np.vstack([self.fine_mean_[None], self.fine_components_])
        mix = np.column_stack([np.ones(n), coef])
        stamps = np.empty((n, self.fit_size_**2))
        for lo in range(0, n, _CHUNK):
            sl = slice(lo, min(lo + _CHUNK, n))
            stamps[sl] = self._draw(fine, off[sl], mix[sl])
        stamps = self._embed(stamps, self.fit_size_, self.stamp_size_)
        return stamps * np.broadcast_to(np.asarray(flux, dtype=np.float64), (n,))[:, None]

    def render_fine(self, coefficients, normalize=True):
        """The PSF on the fine grid: ``mean + c @ components`` (unit sum with ``normalize``).

        Parameters
        ----------
        coefficients : array-like of shape (n, n_components_)
        normalize : bool, default=True

        Returns
        -------
        images : ndarray of shape (n, fine_size_**2)
            The pixel-convolved PSF sampled every ``1 / oversampling_`` pixel, its centre at
            the central sample.
        """
        check_is_fitted(self)
        coef = self._check_coefficients(coefficients)
        images = self.fine_mean_ + coef @ self.fine_components_
        if normalize:
            images = images / images.sum(axis=1, keepdims=True)
        return images
