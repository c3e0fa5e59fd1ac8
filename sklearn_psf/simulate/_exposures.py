"""make_exposures: several dithered exposures of one field, static optics plus atmosphere.

Each exposure is a :class:`PSFField` made by :func:`make_psf_field` (same conventions: noise,
sub-pixel positions, S/N, contaminants, weights); what the exposures share is set here.
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass, field

import numpy as np
from astropy.table import Table, vstack

from ..datasets import ReferenceBasis, load_default_reference
from ._field import realistic_snr
from ._make import DEFAULT_SMALLEST_SCALE, make_psf_field
from ._random_field import RandomFieldSampler

__all__ = ["ExposureSet", "make_exposures"]


class _ExposurePattern:
    """Unit-variance weight fields of one exposure: ``(g_static + a * g_atm) / sqrt(1 + a^2)``."""

    def __init__(self, static, atmosphere, ratio):
        self.static, self.atmosphere, self.ratio = static, atmosphere, float(ratio)
        self.scales = static.scales

    def __call__(self, positions):
        return (self.static(positions) + self.ratio * self.atmosphere(positions)) / np.sqrt(
            1.0 + self.ratio ** 2)


@dataclass
class ExposureSet:
    """Exposures of one field made by :func:`make_exposures`.

    Attributes
    ----------
    exposures : list of PSFField
        One simulated image per exposure, in its own chip (pixel) coordinates, with its truth:
        ``exposures[i].galaxies`` holds the galaxy-PSFs in the order of ``galaxies``.
    dithers : ndarray of shape (n_exposures, 2)
        Pointing offset of each exposure (pixels): chip position = sky position - dither.
    galaxies : astropy.table.Table
        Sky positions ``x``, ``y`` (chip coordinates of a zero dither) of the galaxies, each
        observed in every exposure.
    meta : dict
        The settings (``atmosphere_ratio``, ``atmosphere_slope``, ``dither``, ...).
    patterns : list
        The weight fields of each exposure (static and atmospheric random fields), for
        :meth:`weight_covariance`.
    """

    exposures: list
    dithers: np.ndarray
    galaxies: Table
    meta: dict = field(default_factory=dict)
    patterns: list = field(default_factory=list, repr=False)

    def __len__(self) -> int:
        return len(self.exposures)

    @property
    def pixel_scale(self) -> float:
        """Arcsec per pixel."""
        return self.exposures[0].pixel_scale

    @property
    def reference(self):
        """The reference basis of the exposures' PSF (:class:`ReferenceBasis`)."""
        return self.exposures[0].reference

    def weight_covariance(self, X_a, X_b=None) -> np.ndarray:
        """True covariance of the PSF weights (PCA coefficients) between (x, y, exposure) rows.

        Weight ``k`` of exposure ``e`` at chip position ``r`` is ``coeff_mean_k + coeff_std_k
        (g_k(r) + a h_{k,e}(r)) / sqrt(1 + a^2)`` (see :func:`make_exposures`), so the
        covariance is ``coeff_std_k^2 / (1 + a^2) (C_k(r, r') + a^2 [e = e'] H_{k,e}(r, r'))``
        with ``C`` and ``H`` the covariances of the drawn static and atmospheric fields
        (:meth:`RandomFieldSampler.covariance` with ``field=k``: given each draw's
        normalisation). With :meth:`coefficient_noise_cov` this is what the best linear
        unbiased predictor of the coefficients over all exposures (an oracle) needs.

        Parameters
        ----------
        X_a : array-like of shape (n_a, 3)
            Chip positions (x, y) and exposure index.
        X_b : array-like of shape (n_b, 3), optional
            Default ``X_a``.

        Returns
        -------
        cov : ndarray of shape (n_components, n_a, n_b)

        Examples
        --------
        >>> import numpy as np
        >>> from sklearn_psf.simulate import make_exposures
        >>> exp = make_exposures(2, n_stars=5, n_galaxies=2, image_shape=(600, 600),
        ...                      atmosphere_ratio=1.0, random_state=0)
        >>> c = exp.weight_covariance(np.array([[300.0, 300.0, 0], [300.0, 300.0, 1]]))
        >>> c.shape, bool(np.all(c[:, 0, 0] > c[:, 0, 1]))   # the atmospheres differ
        ((5, 2, 2), True)
        """
        if not self.patterns:
            raise ValueError("This ExposureSet holds no weight fields (patterns): make it with "
                             "make_exposures.")
        A = np.asarray(X_a, dtype=np.float64)
        B = A if X_b is None else np.asarray(X_b, dtype=np.float64)
        for name, M in (("X_a", A), ("X_b", B)):
            if M.ndim != 2 or M.shape[1] != 3:
                raise ValueError(f"{name} must have shape (n, 3): x, y, exposure; got {M.shape}.")
        a2 = float(self.meta["atmosphere_ratio"]) ** 2
        std2 = np.asarray(self.reference.coeff_std, dtype=np.float64) ** 2 / (1.0 + a2)
        static = self.patterns[0].static
        out = _per_field(static, A[:, :2], B[:, :2]) * std2[:, None, None]
        if a2 == 0:
            return out
        ea, eb = A[:, 2].astype(np.int64), B[:, 2].astype(np.int64)
        for e in np.intersect1d(ea, eb):
            ia, ib = np.flatnonzero(ea == e), np.flatnonzero(eb == e)
            atm = _per_field(self.patterns[e].atmosphere, A[ia, :2], B[ib, :2])
            out[:, ia[:, None], ib[None, :]] += a2 * std2[:, None, None] * atm
        return out

    def coefficient_noise_cov(self, exposures=None, measurement: str = "wls") -> np.ndarray:
        """True coefficient noise covariance of the stars of :meth:`star_data`, in its order.

        Parameters
        ----------
        exposures : sequence of int, optional
            Exposures to use (default all).
        measurement : {"wls", "paper"}, default="wls"
            See :meth:`PSFField.coefficient_noise_cov`.

        Returns
        -------
        noise_cov : ndarray of shape (n_stars, n_components, n_components)
            :meth:`PSFField.coefficient_noise_cov` of each exposure's stars whose stamp was
            cut.
        """
        idx = range(len(self)) if exposures is None else exposures
        return np.concatenate([self.exposures[i].coefficient_noise_cov(measurement)[
            np.asarray(self.exposures[i].star_stamps()[-1]) == 0] for i in idx])

    def star_data(self, exposures=None, *, return_weights: bool = False):
        """Stars of the exposures for a multi-exposure model: X = (x, y, exposure), stamps.

        Parameters
        ----------
        exposures : sequence of int, optional
            Exposures to use (default all).
        return_weights : bool, default=False
            Also return the pixel weights of the stamps.

        Returns
        -------
        X : ndarray of shape (n_stars, 3)
            Chip position and exposure index of each star whose stamp was cut (flag 0).
        stamps : ndarray of shape (n_stars, s*s)
            Raw stamps cut from each exposure's image.
        weights : ndarray of shape (n_stars, s*s)
            Only with ``return_weights``.
        """
        idx = range(len(self)) if exposures is None else exposures
        parts = []
        for i in idx:
            f = self.exposures[i]
            out = f.star_stamps(return_weights=return_weights)
            ok = np.asarray(out[-1]) == 0
            X = np.column_stack([f.stars["x"], f.stars["y"], np.full(len(f.stars), float(i))])
            parts.append((X[ok], *(a[ok] for a in out[:-1])))
        return tuple(np.concatenate(p) for p in zip(*parts))

    def galaxy_data(self, exposures=None):
        """Galaxy-PSFs of the exposures with their truth: X = (x, y, exposure) and a table.

        Returns
        -------
        X : ndarray of shape (n_exposures * n_galaxies, 3)
            Chip position and exposure index, exposure after exposure.
        truth : astropy.table.Table
            ``galaxy`` (row in ``galaxies``), ``exposure``, ``e1``, ``e2``, ``coeffs``.
        """
        idx = range(len(self)) if exposures is None else exposures
        Xs, rows = [], []
        for i in idx:
            g = self.exposures[i].galaxies
            Xs.append(np.column_stack([g["x"], g["y"], np.full(len(g), float(i))]))
            rows.append(Table({"galaxy": np.arange(len(g)), "exposure": np.full(len(g), i),
                               "e1": g["e1"], "e2": g["e2"], "coeffs": g["coeffs"]}))
        return np.concatenate(Xs), vstack(rows)


def _per_field(sampler, a, b):
    """(n_fields, n_a, n_b) covariance of each drawn field of ``sampler`` (given its draw)."""
    base = sampler.covariance(a, b, field=0) * sampler.scales[0] ** 2
    return base[None] / sampler.scales[:, None, None] ** 2


def make_exposures(
    n_exposures: int = 5,
    reference: ReferenceBasis | None = None,
    n_stars: int = 200,
    n_galaxies: int = 300,
    snr=100.0,
    image_shape=(1500, 1500),
    *,
    atmosphere_ratio: float = 0.5,
    atmosphere_slope: float = 11 / 4,
    dither: float = 100.0,
    smallest_scale: float = DEFAULT_SMALLEST_SCALE,
    random_state=None,
    **field_kwargs,
) -> ExposureSet:
    """Simulate dithered exposures of one field: a static optical PSF pattern shared by every
    exposure plus an independent atmospheric pattern per exposure.

    The PSF weights of exposure ``j`` at chip position ``r`` are ``coeff_mean + coeff_std *
    (g_static(r) + a * g_atm_j(r)) / sqrt(1 + a^2)`` with ``a = atmosphere_ratio``: unit-
    variance Gaussian random fields (:class:`RandomFieldSampler`), ``g_static`` fixed to the
    chip (the optics), ``g_atm_j`` drawn afresh for each exposure (the atmosphere), so that
    the weights keep the reference's variance and ``a^2 / (1 + a^2)`` of it changes from
    exposure to exposure. Each exposure has its own stars (positions, S/N, noise) and
    observes the same galaxies, shifted on the chip by its dither: chip = sky - dither, with
    dithers uniform in [-dither, dither] pixels along x and y; galaxies are drawn in the part
    of the sky every exposure covers. The exposures are :func:`make_psf_field` images (the
    galaxy-PSFs are truth only unless ``galaxy_snr`` is given).

    Seeds: ``SeedSequence(random_state)`` spawns the static pattern's, the galaxies' and one
    seed per exposure (its dither, atmosphere, stars and noise), so the first exposures of a
    set of 10 are those of a set of 5 with the same ``random_state``.

    Parameters
    ----------
    n_exposures : int, default=5
    reference : ReferenceBasis, optional
        Default :func:`~sklearn_psf.datasets.load_default_reference`.
    n_stars : int, default=200
        Stars per exposure.
    n_galaxies : int, default=300
    snr : float or "realistic", default=100
        S/N of every star, or :func:`realistic_snr` drawn per exposure.
    image_shape : tuple (ny, nx), default=(1500, 1500)
        Chip of every exposure.
    atmosphere_ratio : float, default=0.5
        rms of the atmospheric pattern over the static one (0: a static PSF).
    atmosphere_slope : float, default=11/4
        Power-spectrum slope of the atmospheric pattern.
    dither : float, default=100
        Largest pointing offset along each axis, pixels.
    smallest_scale : float, default=8
        Smallest scale of both patterns, arcsec.
    random_state : None, int or SeedSequence
    **field_kwargs
        Passed to :func:`make_psf_field` (e.g. ``contaminants``, ``detector``,
        ``galaxy_snr``, ``pixel_scale``).

    Returns
    -------
    ExposureSet

    Examples
    --------
    >>> from sklearn_psf.simulate import make_exposures
    >>> exp = make_exposures(3, n_stars=40, n_galaxies=20, image_shape=(600, 600),
    ...                      random_state=0)
    >>> len(exp), exp.dithers.shape
    (3, (3, 2))
    >>> X, stamps = exp.star_data()
    >>> X.shape[1], sorted(set(X[:, 2].tolist()))
    (3, [0.0, 1.0, 2.0])
    """
    if isinstance(n_exposures, bool) or not isinstance(n_exposures, numbers.Integral) \
            or n_exposures < 1:
        raise ValueError(f"n_exposures must be a positive integer, got {n_exposures!r}.")
    for name, value in (("atmosphere_ratio", atmosphere_ratio), ("dither", dither)):
        if not (np.isfinite(value) and value >= 0):
            raise ValueError(f"{name} must be a non-negative number, got {value}.")
    reference = load_default_reference() if reference is None else reference
    if field_kwargs.get("stamp_size") is not None:
        reference = reference.padded(field_kwargs.pop("stamp_size"))
    ny, nx = (int(v) for v in image_shape)
    h = reference.stamp_size // 2
    margin = h + float(dither) + 1
    if min(nx, ny) <= 2 * margin:
        raise ValueError(f"The chip {image_shape} is too small for dithers of {dither} pixels "
                         f"and stamps of {reference.stamp_size}: use a larger chip or smaller "
                         "dithers.")
    seq = random_state if isinstance(random_state, np.random.SeedSequence) else \
        np.random.SeedSequence(random_state)
    static_seed, gal_seed, exp_parent = seq.spawn(3)
    exp_seeds = exp_parent.spawn(int(n_exposures))
    galaxy_snr = field_kwargs.pop("galaxy_snr", None)
    pixel_scale = field_kwargs.get("pixel_scale") or reference.pixel_scale
    cell = float(smallest_scale) / pixel_scale
    k = reference.n_components
    static = RandomFieldSampler((ny, nx), k, field_kwargs.get("slope", 11 / 4), cell=cell,
                                random_state=np.random.default_rng(static_seed))
    gal_rng = np.random.default_rng(gal_seed)
    sky = np.column_stack([gal_rng.uniform(margin, nx - 1 - margin, n_galaxies),
                           gal_rng.uniform(margin, ny - 1 - margin, n_galaxies)])
    exposures, dithers, patterns = [], [], []
    for s in exp_seeds:
        dither_rng, atm_rng, snr_rng, field_seed = s.spawn(4)
        d = np.random.default_rng(dither_rng).uniform(-dither, dither, 2)
        atm = RandomFieldSampler((ny, nx), k, atmosphere_slope, cell=cell,
                                 random_state=np.random.default_rng(atm_rng))
        star_snr = realistic_snr(n_stars, np.random.default_rng(snr_rng)) \
            if isinstance(snr, str) and snr == "realistic" else snr
        patterns.append(_ExposurePattern(static, atm, atmosphere_ratio))
        exposures.append(make_psf_field(
            reference, n_stars=n_stars, snr=star_snr, image_shape=(ny, nx),
            smallest_scale=smallest_scale, random_state=field_seed,
            galaxy_snr=galaxy_snr, galaxy_positions=sky - d, weight_fields=patterns[-1],
            **field_kwargs))
        dithers.append(d)
    meta = {"atmosphere_ratio": float(atmosphere_ratio),
            "atmosphere_slope": float(atmosphere_slope), "dither": float(dither),
            "smallest_scale": float(smallest_scale), "n_stars": int(n_stars),
            "snr": snr if isinstance(snr, str) else float(np.mean(snr))}
    return ExposureSet(exposures, np.array(dithers), Table({"x": sky[:, 0], "y": sky[:, 1]}),
                       meta, patterns)
