"""A PCA basis of noisy, masked star stamps whose size follows the signal, not the noise."""

from __future__ import annotations

import numbers

import numpy as np
import scipy.fft
from sklearn.base import _fit_context
from sklearn.utils._param_validation import StrOptions
from sklearn.utils.validation import check_is_fitted

from ._normalize import fourier_shift, phase_ramp
from ._noise import correlated_noise_factor, noise_correlation, standardised_residuals
from ._pca_noise import (core_pixels, noise_edge, radial_wings, ring_radii, star_weights,
                         sum_zero, weighted_pca)
from ._stamp_basis import (FIT_NO_CENTROID, FIT_NO_FLUX, FIT_OK, StampFit, _BaseStampBasis,
                           normal_inverse)
from ._stamp_weights import (border_level, has_background, mean_variance, model_weights,
                             poisson_slope, variances)

__all__ = ["StampPCA", "noise_edge", "radial_wings"]

_CHUNK = 256  # stars per batch of shifted basis images
#: Gauss-Newton steps on the offsets of stars with masked pixels, each with its template
_REFINE = ("mean", "mean", "model", "model")


def _irfft2(spectra, s):
    """Real s x s images of half-plane spectra, computed in single precision (a relative
    rounding of ~1e-7, far below the stamps' noise; 2.5x faster) and returned in double."""
    return scipy.fft.irfft2(spectra.astype(np.complex64, copy=False), s=(s, s),
                            workers=1).astype(np.float64)


def _shifted(images_fft, phase):
    """Images (m, s, s) given by their rfft2, shifted by each star's phase: (n, m, s*s)
    (the product of the spectra in single precision, as :func:`_irfft2` inverts them)."""
    n, s = phase.shape[0], phase.shape[1]
    out = _irfft2(images_fft.astype(np.complex64, copy=False)[None, :, :, :]
                  * phase.astype(np.complex64)[:, None, :, :], s)
    return out.reshape(n, images_fft.shape[0], s * s)


def _with_constant(A, extra):
    """Design images (b, m, p) with a constant image appended when ``extra``."""
    if not extra:
        return A
    return np.concatenate([A, np.ones((A.shape[0], 1, A.shape[2]))], axis=1)


class StampPCA(_BaseStampBasis):
    """PCA basis of noisy, masked star stamps, with as many components as the signal holds.

    The noise-aware replacement of ``make_pipeline(StampNormalizer(), PCA(0.9))``: it takes
    raw star stamps and their pixel weights (inverse variance, 0 = masked; estimated from each
    stamp's border when not given, see :func:`estimate_pixel_weights`) and

    1. measures each star's adaptive centroid on its unmasked pixels (less the median of the
       stamp's border when a local background is fitted, see ``background``), or, where
       adaptive moments fail (undersampled stars, under ~2 pixels per FWHM), the centre of a
       fixed round Gaussian weight of sigma 1.5 pixels
       (:func:`~sklearn_psf.measure.fixed_moments`);
    2. iterates (``n_iter`` times): fills masked pixels with the current model of the star,
       centres the stamps (Fourier shift), normalises each by its projection on the current
       mean stamp (a matched-filter flux: the noise of a flux measured so takes the noise
       along the star's own shape out of the normalised stamp, where the stamp's sum or a
       fitted flux would add a spurious "flux" component, 5-19 times the noise edge on
       stars of one PSF), and computes a PCA weighted by each star's S/N (weight
       ``u_i = 1 / v_i``, ``v_i`` the noise variance per pixel of the normalised stamp,
       capped at ``max_star_weight`` times the median so that a few bright stars do not
       make the basis); the principal axes are made to sum to zero (the same space with the
       mean) and every star is fitted by weighted least squares as
       ``flux * shift(mean + c @ components, centroid offset) (+ background)`` on its
       unmasked pixels: the basis is moved to the star, never the masked data to the basis.
       Weights whose Poisson part was computed from the noisy pixels themselves (variances
       exactly ``sky + max(pixel, 0) / gain`` per stamp, as
       :func:`~sklearn_psf.exposure.extract_vignettes` gives them with a gain; an image's weight
       map is used as given) weigh the pixels whose noise is down more and bias the fit low
       (fluxes -0.8%, sizes -0.07% on GalSim DECam-like stars at gain 4): after the first
       round the Poisson part is taken from the stars' fitted models instead, and
       :meth:`project` fits again with it;
    3. keeps, with ``n_components="noise"``, the components whose variance is above the noise
       edge: the 99th percentile of the largest eigenvalue that the stars' noise alone gives
       the weighted covariance of ``p - 1`` dimensions (``p`` pixels, one taken by the
       normalisation). Star i contributes ``u_i v_i / sum(u)`` to it; with such unequal
       contributions (stars of different S/N) the edge is that of the generalised
       Marchenko-Pastur law (``sigma^2 (1 + sqrt(p / n))^2`` when the
       contributions are equal), raised by the Tracy-Widom 99th percentile for ``n_eff``
       stars, ``n_eff = (sum c)^2 / sum c^2`` from the contributions ``c_i``. Pure noise
       (stars of one PSF, 1000 stars at S/N 100 or 20-1000) puts the top eigenvalue at
       0.95-0.99 of the edge. Noise correlated between neighbouring pixels (a resampled
       image, a scanned plate; measured on the stamps' borders) raises the edge by as much
       as it raises pure noise's largest eigenvalue for these stars (simulated,
       :func:`~sklearn_psf.preprocessing._noise.correlated_noise_factor`). At most
       ``max_components``.

    The noise of the adaptive centroids needs no allowance: centring by the adaptive
    centroid of a near-Gaussian star takes the noise along the shift directions out, as the
    matched-filter flux does along the star (one PSF at S/N 1e4: top eigenvalue 0.95-0.97 of
    the edge). What is kept is then structure of the stamps: PSF variations, and, at high
    S/N, whatever else the stamps really vary by. For the package's simulated stars
    (:func:`~sklearn_psf.simulate.make_psf_field`), the true components are the reference's
    5 and two shift modes: each synthesised stamp is normalised and re-centred, which adds to
    it the gradient of the mean stamp along x and y (variances ~1e-10 in unit-flux units,
    2000 times below the weakest physical component), so that the noiseless stamps span 7
    dimensions; 1000 stars keep 5 components at S/N 100-3000 and at the realistic mix
    (20-1000), 3 at S/N 50, and 7 at S/N 1e4. Stars drawn at sub-pixel offsets from a PSF that is not band-limited (sampled, not
    pixel-integrated, cores) also vary with the offset: components that a fit at high S/N
    rightly keeps.

    ``transform`` gives the weighted-least-squares coefficients (the stamps' coefficient
    noise, flux and offsets come from :meth:`project`), ``inverse_transform`` normalised
    (unit-sum), centred stamps. The flux convention is that of :class:`StampNormalizer`: the
    mean stamp sums to 1 and the components to 0.

    Parameters
    ----------
    n_components : "noise", int or float, default="noise"
        "noise": above the noise edge (see above). An int: that many. A float in (0, 1): as
        many as hold that fraction of the weighted variance (the paper's 0.9, noise-blind).
    max_components : int, default=20
        Upper bound for "noise" and float choices.
    n_iter : int, default=2
        Rounds of fill / normalise / PCA / fit.
    max_star_weight : float, default=10.0
        Cap of a star's PCA weight in units of the median star weight.
    guess_sigma : float, default=3.0
        Initial width (pixels) of the adaptive weight used to find centroids.
    background : "auto" or bool, default="auto"
        True: fit a constant local background with each star: the weighted least-squares
        model is ``flux * shift(mean + c @ components, offset) + background`` (the components
        sum to zero, so the constant costs the coefficients no precision), and centroids are
        measured after the median of the stamp's 2-pixel border is subtracted. Stars on a
        residual sky of either sign (real cutouts often sit on -100 to +100 counts) are then
        fitted, not dropped. The price: a PSF's flat far wings cannot be told from a
        background within a stamp, so the fitted PSF loses them (for the package's simulated
        PSFs, 1.5% of the flux on a 25x25 stamp: a size bias of -0.15 to -0.2%). False: the
        stamps are taken as background-subtracted. "auto": True when the stamps' borders
        show a background that the PSF's wings cannot make (a border median that departs
        from a common positive fraction of the star's flux by more than 4 times its noise on
        more than 5% of the stamps, or a negative one), else False; the choice is
        ``background_``.

    wings : "radial" or None, default="radial"
        Where the basis takes its shape from. "radial": the components live on the PSF's
        core (the pixels where the mean exceeds 1% of its peak, grown by one pixel, as
        :class:`SuperResolvedPCA`'s): their number is counted against the noise edge of
        those pixels, and the stamps' other light (neighbours, a crowded field's unresolved
        stars, sky structure) makes no component; and where a pixel of the weighted mean
        holds more noise than PSF (the wings of a large stamp, a real catalogue's 63x63
        VIGNETs around stars of S/N 30-300), the noise is taken out ring by ring
        (:func:`radial_wings`: the azimuthal profile and each pixel's departure from it
        kept in proportion to their signal), the components ending at the support radius,
        where the profile falls below its pixels' noise. Every prediction would otherwise
        carry the mean's pixel noise over the whole stamp: on the real DECam catalogue of
        ``../shared/realdata`` that noise made the model lose to PSFEx on most stars (see
        ``benchmarks/README.md``). None: the components and the mean over the whole stamp,
        every pixel's weighted mean (the paper's).

    Attributes
    ----------
    mean_ : ndarray of shape (p,)
        Mean normalised stamp (sums to 1).
    components_ : ndarray of shape (n_components_, p)
        Orthonormal stamps summing to zero, in order of variance: the principal axes of the
        normalised stamps, less their mean-stamp part (see above).
    explained_variance_ : ndarray
        Weighted variance along every principal axis (kept or not), largest first.
    noise_variance_ : float
        ``sigma^2``: weighted mean noise variance per pixel of the normalised stamps.
    noise_edge_ : float
        The noise edge the variances are compared with.
    background_ : bool
        Whether a local background is fitted with each star (see ``background``).
    support_radius_ : float
        Radius (pixels from the centre) beyond which the components are zero, with
        ``wings="radial"``: the first ring whose mean profile falls below its pixels' noise
        (infinite when none does, or with ``wings=None``).
    n_components_ : int
    stamp_size_ : int
    n_features_in_ : int

    See Also
    --------
    sklearn_psf.model.PSFModel : uses it as its default basis.
    StampNormalizer, FixedBasis : the paper's noise-blind basis pieces.

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.preprocessing import StampPCA
    >>> rng = np.random.default_rng(0)
    >>> yy, xx = np.mgrid[0:15, 0:15] - 7.0
    >>> sig = rng.uniform(2.0, 2.2, size=(200, 1, 1))       # one true component: the size
    >>> stars = 1e4 * np.exp(-0.5 * (xx**2 + yy**2) / sig**2) / (2 * np.pi * sig**2)
    >>> stamps = (stars + rng.normal(0, 5.0, stars.shape)).reshape(200, -1)
    >>> basis = StampPCA().fit(stamps)
    >>> basis.n_components_
    1
    >>> basis.inverse_transform(basis.transform(stamps[:2])).sum(axis=1).round(6)
    array([1., 1.])
    """

    _parameter_constraints: dict = {
        **_BaseStampBasis._parameter_constraints,
        "wings": [StrOptions({"radial"}), None],
    }

    def __init__(self, n_components="noise", max_components: int = 20, n_iter: int = 2,
                 max_star_weight: float = 10.0, guess_sigma: float = 3.0,
                 background="auto", wings="radial"):
        self.n_components = n_components
        self.max_components = max_components
        self.n_iter = n_iter
        self.max_star_weight = max_star_weight
        self.guess_sigma = guess_sigma
        self.background = background
        self.wings = wings

    _state_attributes = _BaseStampBasis._state_attributes + ("support_radius_",)

    # -- input ---------------------------------------------------------------------------
    def _check_params(self):
        super()._check_params()
        if self.wings not in ("radial", None):
            raise ValueError(f"wings must be 'radial' or None, got {self.wings!r}.")

    @staticmethod
    def _centred(stamps, offsets, s):
        """Stamps (n, p) moved by minus their offsets (centroid to the stamp centre)."""
        n = stamps.shape[0]
        return fourier_shift(stamps.reshape(n, s, s), -offsets[:, 0],
                             -offsets[:, 1]).reshape(n, -1)

    # -- the weighted least-squares fit of stamps on the basis ------------------------------
    def _fit_stamps(self, d, w, offsets, mean, comps, s):
        """Per-star flux, coefficients, their covariance, the model stamps (without the
        background), the offsets and the local background level.

        With ``background``, each stamp's constant background is a parameter of the same
        weighted least-squares fit (marginalised in the covariance). Stars with masked pixels
        get their offsets refined by Gauss-Newton steps fitting a template's flux, background
        and offset, every coefficient then fitted at it: two steps with the mean PSF, two with
        the star's own model. Adaptive moments of a stamp with a hole are biased towards the
        side that is left, a template fit is not; the whole basis's fit of the offset is
        nearly degenerate when the hole is in the core (a shift is then nearly a combination
        of components).
        """
        n, p = d.shape
        basis = np.vstack([mean[None, :], comps]).reshape(-1, s, s)
        basis_fft = np.fft.rfft2(basis)  # once: each star's design is a phase ramp of it
        basis_fft32 = basis_fft.astype(np.complex64)
        ky = 2j * np.pi * np.fft.fftfreq(s)[None, None, :, None]
        kx = 2j * np.pi * np.fft.rfftfreq(s)[None, None, None, :]
        m = basis.shape[0]
        extra = int(self.background_)  # the constant background's column
        offsets = offsets.copy()
        a = np.full((n, m), np.nan)
        cov = np.full((n, m, m), np.nan)
        level = np.zeros(n)
        model = np.zeros((n, p))

        def solve(rows, A):
            """Weighted least squares of the stamps ``rows`` on their design images A."""
            Aw = A * w[rows, None, :]
            # batched matrix products (BLAS), 1.5-2x faster than the equivalent einsums
            inv = normal_inverse(Aw @ A.transpose(0, 2, 1))
            sol = (inv @ (Aw @ d[rows, :, None]))[:, :, 0]
            a[rows], cov[rows] = sol[:, :m], inv[:, :m, :m]
            if extra:
                level[rows] = sol[:, m]
            model[rows] = (a[rows, None, :] @ A[:, :m])[:, 0]

        # Gauss-Newton steps refine the offsets of the stars with masked pixels only (the
        # others' offsets would not move), their design images carried over
        masked = (w == 0).any(axis=1)
        for start in range(0, n, _CHUNK):
            rows = np.arange(start, min(start + _CHUNK, n))
            phase = phase_ramp(s, offsets[rows, 0], offsets[rows, 1])
            A = _with_constant(_shifted(basis_fft32, phase), extra)  # (b, m + extra, p)
            solve(rows, A)
            sub = masked[rows]
            rows, phase = rows[sub], phase[sub]
            for step in range(len(_REFINE) * bool(sub.any())):
                # the offset of a template (with its flux and the background), every
                # coefficient then fitted at it: first the mean PSF (with pixels masked in
                # the core a shift is nearly a combination of components, so that the
                # whole basis's best offset wanders off), then the star's own model (the
                # mean alone is biased by the star's difference from it)
                if _REFINE[step] == "mean":
                    template = basis_fft[None, :1]  # (broadcast over the stars)
                else:
                    c = a[rows] / np.where(a[rows, :1] != 0, a[rows, :1], 1.0)
                    template = np.einsum("bi,iyx->byx", c, basis_fft)[:, None]
                G0 = _with_constant(_irfft2(template * phase[:, None], s).reshape(-1, 1, p),
                                    extra)  # (b, 1 + extra, p)
                Gw = G0 * w[rows, None, :]
                lin = (normal_inverse(Gw @ G0.transpose(0, 2, 1))
                       @ (Gw @ d[rows, :, None]))[:, :, 0]
                resid = d[rows] - (lin[:, None, :] @ G0)[:, 0]
                # d(template)/d(offset): minus its spatial derivative
                mfft = template * phase[:, None] * lin[:, :1, None, None]
                grad = -_irfft2(np.concatenate([mfft * kx, mfft * ky], axis=1),
                                s).reshape(-1, 2, p)
                G = np.concatenate([G0, grad], axis=1)
                Gw = G * w[rows, None, :]
                sol = (normal_inverse(Gw @ G.transpose(0, 2, 1))
                       @ (Gw @ resid[:, :, None]))[:, :, 0]
                offsets[rows] += np.clip(sol[:, 1 + extra:], -0.5, 0.5)
                phase = phase_ramp(s, offsets[rows, 0], offsets[rows, 1])
                if step + 1 == len(_REFINE) or _REFINE[step + 1] == "model":
                    # (the coefficients at the new offsets: the next step's template, or the
                    # result; a step of the mean's needs none)
                    solve(rows, _with_constant(_shifted(basis_fft32, phase), extra))
        return a, cov, model, offsets, level

    @_fit_context(prefer_skip_nested_validation=True)
    def fit(self, X, y=None, weights=None):
        """Fit the basis on raw star stamps.

        Parameters
        ----------
        X : array-like of shape (n, s*s)
            Raw star stamps (any flux units), NaN for masked pixels. Not modified.
        y : ignored
        weights : array-like of shape (n, s*s), optional
            Inverse variance of each pixel (0 = masked). Default: estimated from each
            stamp's border.

        Returns
        -------
        self : StampPCA
        """
        self._fit(X, weights)
        return self

    def _fit(self, X, weights, positions=None):
        """The fit; returns the stars' :class:`StampFit` of its last iteration (see
        :meth:`fit_project`). ``positions`` are not used."""
        self._check_params()
        d, w, s = self._stamps_and_weights(X, weights, reset=True)
        n, p = d.shape
        self.background_ = bool(has_background(d, w, s) if self.background == "auto"
                                else self.background)
        level = border_level(d, w, s)[0] if self.background_ else np.zeros(n)
        offsets, ok = self._centroids(d - level[:, None], w, s)
        flux = ((d - level[:, None]) * (w > 0)).sum(axis=1)
        usable = ok & (flux > 0)
        if usable.sum() < 2:
            raise ValueError("Fewer than 2 stamps have a measurable centroid and a positive "
                             "flux: these are not star stamps.")
        mean = None
        comps = np.zeros((0, p))
        a = None
        model = np.zeros((n, p))  # the stars' current model: fills their masked pixels
        pixel_var = variances(w).mean(axis=1)
        w_given, poisson = w, poisson_slope(d, w)
        for it in range(int(self.n_iter)):
            safe = np.where(usable, flux, 1.0)
            if a is None and (w == 0).any():
                # first round with masked pixels: fill them from the weighted mean of the
                # stars that have those pixels (sub-pixel offsets neglected)
                x = self._centred(np.where(w > 0, d - level[:, None], model), offsets,
                                  s) / safe[:, None]
                u = star_weights(pixel_var / safe**2, usable, self.max_star_weight)
                have = (w > 0) & usable[:, None]
                mean = (u[:, None] * have * x).sum(0) / np.maximum((u[:, None] * have).sum(0),
                                                                   1e-300)
                model = flux[:, None] * fourier_shift(
                    np.broadcast_to(mean.reshape(1, s, s), (n, s, s)), offsets[:, 0],
                    offsets[:, 1]).reshape(n, p)
            centred = self._centred(np.where(w > 0, d - level[:, None], model), offsets, s)
            if mean is None:  # first round: the weighted mean of the sum-normalised stamps
                u = star_weights(pixel_var / safe**2, usable, self.max_star_weight)
                mean = u[usable] @ (centred[usable] / safe[usable, None]) / u[usable].sum()
            # normalise each stamp by its projection on the mean stamp (a matched filter):
            # the flux's noise then takes the noise along the star's shape out of the
            # normalised stamp instead of adding a spurious "flux" component to it
            proj = centred @ mean / (mean @ mean)
            scale = np.where(usable & (proj > 0), proj, safe)
            x = centred / scale[:, None]
            v = pixel_var / scale**2  # noise variance per pixel of each normalised stamp
            u = star_weights(v, usable, self.max_star_weight)
            n_top = int(self.max_components) + 1
            if isinstance(self.n_components, numbers.Integral):
                n_top = max(n_top, int(self.n_components))
            # noise correlated between pixels (resampling) raises the noise edge
            kernel = noise_correlation(standardised_residuals(
                x[usable], u[usable] @ x[usable] / u[usable].sum(), scale[usable], w[usable]))
            core = np.ones(p, dtype=bool)
            if self.wings == "radial":  # the components live on the PSF's core
                core = core_pixels(u[usable] @ x[usable] / u[usable].sum(), s)
            mean, axes_core, lam, total = weighted_pca(x[usable][:, core], u[usable], n_top)
            mean = u[usable] @ x[usable] / u[usable].sum()
            axes = np.zeros((len(axes_core), p))
            axes[:, core] = axes_core
            noise = float((u * v).sum() / u.sum())
            raise_by = correlated_noise_factor(kernel, v[usable], u[usable], s, core)
            k, edge = self._choose(lam, total, noise, u[usable] * v[usable] / u.sum(),
                                   int(core.sum()), raise_by)
            axes, radius = axes[:k], np.inf
            if self.wings == "radial":  # the mean's faint wings: their signal, not its noise
                mean, radius = radial_wings(mean, mean_variance(w, scale, u), s,
                                            1.0 if kernel is None else kernel.sum())
                axes = np.where(ring_radii(s) < radius, axes, 0.0)
            mean = mean / mean.sum()
            comps = sum_zero(axes, mean)
            a, cov, model, offsets, fitted = self._fit_stamps(d, w, offsets, mean, comps, s)
            flux_new, coef, var, ccov, good = self._coefficients(a, cov)
            level = np.where(good, fitted, level)
            usable = ok & good
            if usable.sum() < 2:
                raise ValueError("Fewer than 2 stamps keep a positive flux on the basis: these "
                                 "are not star stamps.")
            flux = np.where(good, flux_new, flux)
            if poisson and it + 1 < self.n_iter:  # the next round's Poisson part: the models'
                w = model_weights(d, w_given, np.where(good[:, None], model + fitted[:, None],
                                                        np.nan), poisson)
                pixel_var = variances(w).mean(axis=1)
        norm = mean.sum()  # 1 (the mean was normalised before the last fit of the stars)
        self.mean_ = mean / norm
        self.components_ = comps
        self.explained_variance_ = lam / norm**2
        self.noise_variance_ = noise / norm**2
        self.noise_edge_ = edge / norm**2
        self.support_radius_ = radius
        self.n_components_ = int(k)
        self.stamp_size_ = s
        self._n_features_out = self.n_components_
        flag = np.where(ok, FIT_OK, FIT_NO_CENTROID)
        flag[~good] = FIT_NO_FLUX
        return StampFit(coef, var, flux_new, offsets, model + fitted[:, None], w, flag, ccov)

    def _project_stars(self, d, w, offsets, s):
        """Each star's fit on the basis for :meth:`project`: (amplitudes, their covariance,
        model, offsets, background level, whether the offset fit succeeded)."""
        a, cov, model, offsets, level = self._fit_stamps(d, w, offsets, self.mean_,
                                                         self.components_, s)
        return a, cov, model, offsets, level, np.ones(len(d), dtype=bool)

    def render(self, coefficients, flux=1.0, offsets=None):
        """Model stamps in the stars' frame: ``flux * shift(mean + c @ components, offsets)``.

        Parameters
        ----------
        coefficients : array-like of shape (n, n_components_)
        flux : float or array-like of shape (n,), default=1
        offsets : array-like of shape (n, 2), optional
            (dx, dy) shifts in pixels; default none (centred stamps).

        Returns
        -------
        stamps : ndarray of shape (n, s*s)
        """
        check_is_fitted(self)
        coef = self._check_coefficients(coefficients)
        n, s = coef.shape[0], self.stamp_size_
        stamps = self.mean_ + coef @ self.components_
        if offsets is not None:
            off = np.asarray(offsets, dtype=np.float64).reshape(n, 2)
            stamps = fourier_shift(stamps.reshape(n, s, s), off[:, 0], off[:, 1]).reshape(n, -1)
        return stamps * np.broadcast_to(np.asarray(flux, dtype=np.float64), (n,))[:, None]


def _stamp_pca_on_basis(mean, components, guess_sigma: float = 3.0,
                        background: bool = False) -> StampPCA:
    """A fitted :class:`StampPCA` whose basis is given, not learnt (e.g. a simulation's
    reference): ``project`` fits stars on it by weighted least squares.

    ``mean`` (p,) must sum to 1 and the ``components`` (k, p) be orthonormal and sum to 0
    (the convention of the bases :class:`StampPCA` fits).
    """
    mean = np.asarray(mean, dtype=np.float64).reshape(-1)
    comps = np.asarray(components, dtype=np.float64).reshape(-1, mean.size)
    return StampPCA(n_components=comps.shape[0], guess_sigma=guess_sigma,
                    background=background)._set_state({
                        "mean_": mean / mean.sum(), "components_": comps,
                        "n_components_": comps.shape[0], "background_": bool(background),
                        "stamp_size_": int(round(np.sqrt(mean.size))),
                        "n_features_in_": mean.size})
