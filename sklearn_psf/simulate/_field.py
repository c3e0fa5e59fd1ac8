"""Mock PSF field images (Berge et al. 2012, section 3).

The conventions (PSF model, positions, S/N, contaminants, weights, seeds) are documented in
:mod:`sklearn_psf.simulate`.
"""

from __future__ import annotations

import os

import numpy as np
from astropy.io import fits
from astropy.table import Table

from ..datasets._reference import ReferenceBasis, _version
from ..measure import adaptive_moments
from ..preprocessing import StampNormalizer, cut_stamps, fourier_shift
from ._random_field import RandomFieldSampler, as_generator

__all__ = ["PSFField", "realistic_snr", "core_mask"]

_FIELD_FORMAT = "SKPSF-FIELD"


def realistic_snr(n: int, random_state=None, *, low: float = 20.0, high: float = 1000.0,
                  mode: float = 100.0, sigma: float = 0.6) -> np.ndarray:
    """Draw star S/N from the paper's "realistic" distribution (20 to 1000, peaking near 100).

    A log-normal distribution whose density in S/N peaks at ``mode`` (ln S/N normal with
    standard deviation ``sigma`` and mean ``ln(mode) + sigma^2``: median 143, mean 163 for the
    defaults), truncated to [low, high] by re-drawing.

    Parameters
    ----------
    n : int
        Number of stars.
    random_state : None, int, SeedSequence or Generator
    low, high : float, default=20, 1000
    mode : float, default=100
    sigma : float, default=0.6

    Returns
    -------
    snr : ndarray of shape (n,)

    Examples
    --------
    >>> from sklearn_psf.simulate import realistic_snr
    >>> s = realistic_snr(1000, random_state=0)
    >>> bool(s.min() >= 20 and s.max() <= 1000)
    True
    """
    n = int(n)
    if n < 0:
        raise ValueError(f"n must be >= 0, got {n}.")
    if not (0 < low < mode < high) or not sigma > 0:
        raise ValueError("Need 0 < low < mode < high and sigma > 0.")
    rng = as_generator(random_state)
    mu = np.log(mode) + sigma**2
    out = np.empty(n)
    filled = 0
    while filled < n:
        draw = np.exp(rng.normal(mu, sigma, size=2 * (n - filled) + 10))
        draw = draw[(draw >= low) & (draw <= high)][: n - filled]
        out[filled:filled + draw.size] = draw
        filled += draw.size
    return out


def core_mask(stamps, fraction: float = 0.5) -> np.ndarray:
    """Pixels of each noiseless stamp at or above ``fraction`` of its peak (the S/N pixels).

    Parameters
    ----------
    stamps : ndarray of shape (n, p)
    fraction : float, default=0.5

    Returns
    -------
    mask : boolean ndarray of shape (n, p)
    """
    s = np.asarray(stamps, dtype=np.float64)
    return s >= fraction * s.max(axis=1, keepdims=True)


class PSFField:
    """A simulated PSF field: image, weight map, truth tables and the basis it was built from.

    Made by :func:`make_psf_field`; saved and read with :meth:`save` / :meth:`load`.

    Attributes
    ----------
    image : ndarray of shape (ny, nx), float32
        Stars (and galaxy-PSFs, contaminants) plus noise; zero background level. Masked
        pixels hold ``mask_value`` (0 by default), saturated ones the saturation level.
    noise_rms : float
        Background rms of the image.
    pixel_scale : float
        Arcsec per pixel.
    reference : ReferenceBasis
        The basis of the simulated PSFs (force it on the model, as in the paper).
    stars, galaxies : astropy.table.Table
        Truth: ``x``, ``y`` (exact positions, float; sub-pixel by default), ``stamp``
        (normalised, centred noiseless stamp, shape (s*s,) per row), ``coeffs`` (its
        coefficients in the basis), ``e1``, ``e2``, ``sigma`` (adaptive moments of the true
        stamp), ``moments_flag``, ``snr`` and ``flux`` as rendered (0 for galaxy-PSFs not
        rendered). ``stars`` also has ``contaminant`` (str, "" for a clean star, else
        "cosmic_ray", "neighbour", "galaxy" or "binary"), ``contaminant_snr`` (square
        root of the chi^2 the contaminant adds to the star's stamp; 0 when clean),
        ``n_masked`` (pixels of weight 0 in the star's stamp: bad pixels, columns,
        saturation) and ``saturated`` (a pixel of the stamp clipped at the saturation level).
    contaminants : astropy.table.Table
        One row per injected contaminant: ``kind`` (the four kinds above, "field_galaxy",
        "field_cosmic_ray"), ``star`` (row in ``stars``, -1 away from stars), ``x``, ``y``
        (neighbour/companion/track/galaxy position), ``flux``, ``size`` (half-light radius
        of a galaxy, separation of a neighbour or companion, length of a track, pixels),
        ``snr`` (as ``contaminant_snr``; NaN away from stars).
    meta : dict
        ``seed`` (int or None), ``slope``, ``smallest_scale`` (arcsec), ``cell`` (pixels),
        ``field_scales`` (the random fields' scales before normalisation, see
        :attr:`RandomFieldSampler.scales`), ``galaxy_layout``, ``subpixel``, ``gain``,
        ``saturation``, ``version``.
    """

    def __init__(self, image, noise_rms, pixel_scale, reference, stars, galaxies, meta=None,
                 *, weight=None, contaminants=None):
        self.image = image
        self.noise_rms = float(noise_rms)
        self.pixel_scale = float(pixel_scale)
        self.reference = reference
        self.stars = stars
        self.galaxies = galaxies
        self.meta = dict(meta or {})
        self._weight = weight
        self.contaminants = contaminants if contaminants is not None else Table(
            {"kind": np.zeros(0, dtype="U16"), "star": np.zeros(0, dtype=np.int64)})

    @property
    def stamp_size(self) -> int:
        """Side of the stamps."""
        return self.reference.stamp_size

    @property
    def weight(self) -> np.ndarray:
        """Weight map (ny, nx), float32: inverse variance of each pixel, 0 = masked/saturated.

        ``1 / noise_rms^2`` everywhere for a field without masks, saturation or ``gain``
        (built on each access: keep a reference rather than asking twice for a large image).
        """
        if self._weight is not None:
            return self._weight
        return np.full(self.image.shape, 1.0 / self.noise_rms**2, dtype=np.float32)

    def __repr__(self) -> str:
        ny, nx = self.image.shape
        return (f"PSFField(image={nx}x{ny}, n_stars={len(self.stars)}, "
                f"n_galaxies={len(self.galaxies)}, stamp_size={self.stamp_size}, "
                f"noise_rms={self.noise_rms:.4g})")

    def _positions(self):
        return np.column_stack([self.stars["x"], self.stars["y"]]).astype(np.float64)

    def star_stamps(self, normalize: bool | None = None, *, return_weights: bool = False):
        """Stamps of the stars cut from the image (as for real data), not from the truth.

        Stamps are cut centred on the nearest pixel of each star (``cut_stamps``), with the
        weight map, so that a masked pixel in a star's core flags it (``CUT_MASKED``).

        Parameters
        ----------
        normalize : bool, optional
            Normalise with ``StampNormalizer`` (unit flux, adaptive centroid moved to the
            stamp centre). Stamps flagged by ``cut_stamps`` are left as cut. Default True,
            or False with ``return_weights`` (raw stamps go with their weights).
        return_weights : bool, default=False
            Also return the weight stamps.

        Returns
        -------
        stamps : ndarray of shape (n_stars, s*s)
        weights : ndarray of shape (n_stars, s*s)
            Only with ``return_weights``: inverse variance of each raw pixel, 0 = masked
            (and for NaN pixels).
        flags : ndarray of shape (n_stars,)
            ``cut_stamps`` flags (0 = clean).

        Raises
        ------
        ValueError
            For ``normalize=True`` with ``return_weights=True`` (weights are those of the
            raw stamps).

        Examples
        --------
        >>> from sklearn_psf.simulate import DetectorSettings, make_psf_field
        >>> field = make_psf_field(n_stars=10, n_galaxies=0, image_shape=(300, 400),
        ...                        detector=DetectorSettings(masked_fraction=0.01),
        ...                        random_state=0)
        >>> stamps, weights, flags = field.star_stamps(return_weights=True)
        >>> stamps.shape == weights.shape, bool((weights == 0).any())
        (True, True)
        """
        if normalize is None:
            normalize = not return_weights
        if normalize and return_weights:
            raise ValueError("The weights are those of the raw stamps: call star_stamps("
                             "normalize=False, return_weights=True).")
        s = self.stamp_size
        pos = self._positions()
        stamps, flags = cut_stamps(self.image, pos, s, weight=self._weight)
        flat = stamps.reshape(len(pos), s * s)
        good = flags == 0
        if normalize and good.any():
            flat[good] = StampNormalizer(flux=True, center=True).fit_transform(flat[good])
        if not return_weights:
            return flat, flags
        if self._weight is None:
            w = np.full(flat.shape, 1.0 / self.noise_rms**2)
        else:
            w = cut_stamps(self._weight, pos, s)[0].reshape(flat.shape)
        w[~np.isfinite(flat) | ~np.isfinite(w)] = 0.0
        return flat, w, flags

    def coefficient_noise_cov(self, measurement: str = "wls") -> np.ndarray:
        """True noise covariance of each star's coefficients (k x k), from its pixel noise.

        The covariance of a measurement's coefficients about their noiseless value, to first
        order in the pixel noise, computed from the truth (each star's true stamp, flux and
        sub-pixel offset) and the pixel variances (``1 / weight``: background and, with
        ``gain``, the source's Poisson noise; masked pixels left out). The components are
        correlated through the flux normalisation, which every coefficient shares.

        Parameters
        ----------
        measurement : {"wls", "paper"}, default="wls"
            "wls": the weighted least-squares fit of the raw stamp with its weights on the
            reference basis, ``flux * shift(mean + c @ components, offset)`` at the star's
            adaptive centroid (what :meth:`sklearn_psf.preprocessing.StampPCA.project` does
            with the reference as its basis): ``J (A W A^T)^-1 J^T`` with A the shifted mean
            and components, W the pixel weights and J the derivative of
            ``c = a[1:] / a[0]``. For a star with masked pixels, whose offset the fit refines,
            the offset is a free parameter of the fit (its uncertainty is included). The
            noise of the adaptive centroid of an unmasked star is not included: it changes
            the coefficients' variance by less than the 3% that 3000 noise draws resolve
            at S/N 20-1000 (tested).
            "paper": the paper's measurement, the stamp normalised to unit sum and centred,
            then projected on the components (``reference.as_transformer()``):
            ``sum_p (c_ip - c_i . T)(c_jp - c_j . T) var_p / F^2`` for components c_i, c_j,
            true stamp T and flux F, the noise of the centring left out (the measured
            scatter about the truth is 0.94-1.08 times its diagonal at S/N 100). It is 2.8-3
            times the "wls" variance for the first two components.

        Returns
        -------
        cov : ndarray of shape (n_stars, n_components, n_components)

        Examples
        --------
        >>> import numpy as np
        >>> from sklearn_psf.simulate import make_psf_field
        >>> field = make_psf_field(n_stars=5, n_galaxies=0, image_shape=(300, 400),
        ...                        snr=[50.0, 100.0, 100.0, 200.0, 400.0], random_state=0)
        >>> wls, paper = field.coefficient_noise_cov(), field.coefficient_noise_cov("paper")
        >>> wls.shape, bool(np.all(wls[:, 0, 0] < paper[:, 0, 0]))
        ((5, 5, 5), True)
        """
        if measurement not in ("wls", "paper"):
            raise ValueError(f"measurement must be 'wls' or 'paper', got {measurement!r}.")
        k, s = self.reference.n_components, self.stamp_size
        comps = self.reference.components.reshape(k, -1)
        truth = np.asarray(self.stars["stamp"], dtype=np.float64)
        flux = np.asarray(self.stars["flux"], dtype=np.float64)
        _, w, _ = self.star_stamps(normalize=False, return_weights=True)
        if measurement == "paper":
            var = np.where(w > 0, 1.0 / np.where(w > 0, w, 1.0), 0.0)
            dev = comps[None, :, :] - (truth @ comps.T)[:, :, None]  # (n, k, p): c_ip - c_i.T
            return np.einsum("nip,njp->nij", dev * var[:, None, :], dev) / flux[:, None, None]**2
        pos = self._positions()
        offset = pos - np.floor(pos + 0.5)  # the star's centroid from the stamp's centre
        coef = np.asarray(self.stars["coeffs"], dtype=np.float64)
        basis = np.vstack([self.reference.mean.reshape(1, -1), comps]).reshape(-1, s, s)
        out = np.empty((len(pos), k, k))
        for start in range(0, len(pos), 128):
            sl = slice(start, start + 128)
            b = len(pos[sl])
            off = np.repeat(offset[sl], k + 1, axis=0)
            A = fourier_shift(np.tile(basis, (b, 1, 1)), off[:, 0], off[:, 1]).reshape(b, k + 1,
                                                                                   s * s)
            masked = (w[sl] == 0).any(axis=1)
            if masked.any():  # the offset is fitted too: d(model)/d(offset) as two columns
                model = np.einsum("bi,bip->bp", np.column_stack([np.ones(b), coef[sl]]), A)
                grad = _shift_gradient(model.reshape(b, s, s)) * flux[sl, None, None]
                A = np.concatenate([A, np.where(masked[:, None, None], grad, 0.0)], axis=1)
            fisher = np.einsum("bip,bjp->bij", A * w[sl, None, :], A)
            if masked.any():
                fisher[~masked, k + 1:, k + 1:] = np.eye(2)  # no offset parameter: decoupled
            cov_a = np.linalg.inv(fisher)[:, :k + 1, :k + 1]
            c = coef[sl]
            jac = np.zeros((b, k, k + 1))
            jac[:, :, 0] = -c / flux[sl, None]
            jac[:, np.arange(k), np.arange(1, k + 1)] = 1.0 / flux[sl, None]
            out[sl] = np.einsum("bim,bmq,bjq->bij", jac, cov_a, jac)
        return out

    def coefficient_noise_var(self) -> np.ndarray:
        """Diagonal of :meth:`coefficient_noise_cov` for the paper's measurement.

        The true noise variance of each star's coefficients measured the paper's way
        (normalised, centred stamp projected on the basis).

        Returns
        -------
        var : ndarray of shape (n_stars, n_components)

        Examples
        --------
        >>> from sklearn_psf.simulate import make_psf_field
        >>> field = make_psf_field(n_stars=5, n_galaxies=0, image_shape=(300, 400),
        ...                        snr=[50.0, 100.0, 100.0, 200.0, 400.0], random_state=0)
        >>> v = field.coefficient_noise_var()
        >>> v.shape, bool(v[0, 0] > v[1, 0] > v[3, 0] > v[4, 0])
        ((5, 5), True)
        """
        return np.einsum("nkk->nk", self.coefficient_noise_cov("paper")).copy()

    def weight_covariance(self, positions_a, positions_b=None, *,
                          ensemble: bool = False) -> np.ndarray:
        """True covariance of the PSF weights (PCA coefficients) between positions.

        Weight i at position r is ``coeff_mean_i + coeff_std_i * g_i(r)`` with independent
        random fields g_i (:class:`RandomFieldSampler`); the weights of different components
        are uncorrelated. The true coefficients of ``stars``/``galaxies`` equal those
        weights to 0.2% (the normalisation and centring of the synthesised stamp barely
        change them), so this, with :meth:`coefficient_noise_cov` for the noise, is what a
        best linear unbiased predictor (an oracle) of the coefficients needs.

        Parameters
        ----------
        positions_a : array-like of shape (n_a, 2)
            (x, y) pixel positions.
        positions_b : array-like of shape (n_b, 2), optional
            Default ``positions_a``.
        ensemble : bool, default=False
            False: the covariance given this field's draw (its grid means and scales, see
            ``RandomFieldSampler.covariance(field=i)``), the oracle's choice. True: the
            ensemble covariance over seeds (the same for every field of this set-up).

        Returns
        -------
        cov : ndarray of shape (n_components, n_a, n_b)

        Examples
        --------
        >>> import numpy as np
        >>> from sklearn_psf.simulate import make_psf_field
        >>> field = make_psf_field(n_stars=5, n_galaxies=0, image_shape=(600, 800),
        ...                        random_state=0)
        >>> c = field.weight_covariance(np.array([[100.0, 100.0], [400.0, 300.0]]))
        >>> c.shape
        (5, 2, 2)
        """
        variances, correlation = self.weight_covariance_factors(positions_a, positions_b,
                                                                ensemble=ensemble)
        return variances[:, None, None] * correlation[None]

    def weight_covariance_factors(self, positions_a, positions_b=None, *,
                                  ensemble: bool = False):
        """:meth:`weight_covariance` as ``variances[:, None, None] * correlation[None]``.

        Every component's random field has the same spatial structure; only its amplitude
        differs. This returns the two factors (the one ``(n_a, n_b)`` matrix instead of
        ``n_components`` copies of it), for predictors of many stars.

        Parameters
        ----------
        positions_a, positions_b, ensemble
            As for :meth:`weight_covariance`.

        Returns
        -------
        variances : ndarray of shape (n_components,)
        correlation : ndarray of shape (n_a, n_b)
            The covariance of a unit-variance field (``ensemble=True``), or of the field
            given its draw before its scale is applied (``ensemble=False``).

        Examples
        --------
        >>> import numpy as np
        >>> from sklearn_psf.simulate import make_psf_field
        >>> field = make_psf_field(n_stars=5, n_galaxies=0, image_shape=(600, 800),
        ...                        random_state=0)
        >>> pos = np.array([[100.0, 100.0], [400.0, 300.0]])
        >>> v, k = field.weight_covariance_factors(pos)
        >>> bool(np.allclose(v[:, None, None] * k, field.weight_covariance(pos)))
        True
        """
        sampler = RandomFieldSampler(self.image.shape, 0, self.meta.get("slope", 11 / 4),
                                     cell=self.meta["cell"])
        std2 = np.asarray(self.reference.coeff_std, dtype=np.float64) ** 2
        scales = self.meta.get("field_scales")
        if ensemble or scales is None:
            return std2, sampler.covariance(positions_a, positions_b)
        sampler.scales = np.ones(1)
        base = sampler.covariance(positions_a, positions_b, field=0)
        return std2 / np.asarray(scales, dtype=np.float64) ** 2, base

    def measure_stars(self) -> Table:
        """Measure the stars on the image with the real-data pipeline.

        Stamps are cut at the star positions, normalised, projected on the reference basis
        (``reference.as_transformer``) and measured with adaptive moments. The S/N is measured
        the paper's way from the data alone: mean of the pixels at or above half the peak of
        the normalised (centred) stamp scaled by the raw stamp's sum, over the background rms
        estimated from the image (1.4826 x median absolute deviation).

        Returns
        -------
        astropy.table.Table
            ``x``, ``y``, ``stamp`` (measured, normalised), ``coeffs``, ``e1``, ``e2``,
            ``sigma``, ``snr``, ``cut_flag``, ``moments_flag`` (NaN values for stars whose
            stamp is flagged).

        Examples
        --------
        >>> from sklearn_psf.simulate import make_psf_field
        >>> field = make_psf_field(n_stars=20, n_galaxies=10, image_shape=(600, 800),
        ...                        random_state=0)
        >>> m = field.measure_stars()
        >>> len(m), bool(abs(m["snr"].mean() / 100 - 1) < 0.1)
        (20, True)
        """
        s = self.stamp_size
        pos = self._positions()
        raw, flags = cut_stamps(self.image, pos, s, weight=self._weight)
        raw = raw.reshape(len(pos), s * s)
        n, k = len(pos), self.reference.n_components
        stamps = np.full((n, s * s), np.nan)
        coeffs = np.full((n, k), np.nan)
        e1, e2, sig = np.full(n, np.nan), np.full(n, np.nan), np.full(n, np.nan)
        mflag = np.full(n, -1, dtype=np.int64)
        snr = np.full(n, np.nan)
        rms = _robust_rms(self.image)
        good = np.flatnonzero(flags == 0)
        if good.size:
            basis = self.reference.as_transformer(normalize=False)
            norm = StampNormalizer(flux=True, center=True).fit_transform(raw[good])
            stamps[good] = norm
            coeffs[good] = basis.transform(norm)
            mom = adaptive_moments(norm)
            e1[good], e2[good], sig[good] = mom["e1"], mom["e2"], mom["sigma"]
            mflag[good] = mom["flag"]
            # on the centred stamp at the star's flux: the definition's pixels, whatever the
            # sub-pixel offset
            centred = norm * raw[good].sum(axis=1, keepdims=True)
            core = core_mask(centred)
            snr[good] = (centred * core).sum(axis=1) / core.sum(axis=1) / rms
        return Table({"x": pos[:, 0], "y": pos[:, 1], "stamp": stamps, "coeffs": coeffs,
                      "e1": e1, "e2": e2, "sigma": sig, "snr": snr, "cut_flag": flags,
                      "moments_flag": mflag})

    # ------------------------------------------------------------------ I/O
    def save(self, path, overwrite: bool = False) -> None:
        """Write the field to FITS: image (primary), STARS, GALAXIES tables, REF_* basis.

        Header keywords of the primary HDU: PIXSCALE, NOISERMS, SEED (-1 if the field was not
        made from an int seed), SLOPE, SMLSCALE (smallest scale, arcsec), CELL (pixels),
        SUBPIXEL, GAIN and SATURATE (when set), LAYOUT, STAMPSZ, SKPSFVER. Extensions: STARS,
        GALAXIES, CONTAMINANTS, WEIGHT (only when the field has masks, saturation or gain),
        REF_* (the basis).

        Parameters
        ----------
        path : str or os.PathLike
        overwrite : bool, default=False
        """
        primary = fits.PrimaryHDU(np.asarray(self.image, dtype=np.float32))
        h = primary.header
        h["SKPSFFMT"] = (_FIELD_FORMAT, "sklearn_psf simulated PSF field")
        h["SKPSFVER"] = (self.meta.get("version", _version()), "sklearn_psf version")
        h["PIXSCALE"] = (self.pixel_scale, "arcsec per pixel")
        h["NOISERMS"] = (self.noise_rms, "background noise rms")
        seed = self.meta.get("seed")
        h["SEED"] = (-1 if seed is None else int(seed), "random_state (int) of the simulation")
        h["SLOPE"] = (float(self.meta.get("slope", np.nan)), "power spectrum slope")
        h["SMLSCALE"] = (float(self.meta.get("smallest_scale", np.nan)),
                         "smallest scale of the PSF variations (arcsec)")
        h["CELL"] = (float(self.meta.get("cell", np.nan)), "random field grid cell (pixels)")
        h["SUBPIXEL"] = (bool(self.meta.get("subpixel", False)), "sub-pixel positions")
        for i, scale in enumerate(self.meta.get("field_scales") or []):
            h[f"FSCALE{i}"] = (float(scale), f"scale of random field {i} before normalising")
        for key, name in (("GAIN", "gain"), ("SATURATE", "saturation")):
            if self.meta.get(name) is not None:
                h[key] = float(self.meta[name])
        h["LAYOUT"] = (str(self.meta.get("galaxy_layout", "")), "galaxy-PSF layout")
        h["STAMPSZ"] = (self.stamp_size, "stamp side in pixels")
        stars = fits.table_to_hdu(self.stars)
        stars.name = "STARS"
        gals = fits.table_to_hdu(self.galaxies)
        gals.name = "GALAXIES"
        contam = fits.table_to_hdu(self.contaminants)
        contam.name = "CONTAMINANTS"
        extra = [] if self._weight is None else [fits.ImageHDU(self._weight, name="WEIGHT")]
        fits.HDUList([primary, stars, gals, contam, *extra,
                      *self.reference.to_hdus("REF_")]).writeto(os.fspath(path),
                                                                overwrite=overwrite)

    @classmethod
    def load(cls, path) -> "PSFField":
        """Read a field written by :meth:`save`.

        Raises
        ------
        ValueError
            When the file is missing, not FITS, or not a saved PSF field.
        """
        path = os.fspath(path)
        if not os.path.exists(path):
            raise ValueError(f"File {path!r} does not exist.")
        try:
            with fits.open(path, memmap=False) as hdul:
                hdul.verify("exception")
                h = hdul[0].header
                if h.get("SKPSFFMT") != _FIELD_FORMAT:
                    raise ValueError(
                        f"{path!r} is not a simulated PSF field written by PSFField.save."
                    )
                image = np.array(hdul[0].data, dtype=np.float32)
                stars = Table.read(hdul["STARS"])
                gals = Table.read(hdul["GALAXIES"])
                ref = ReferenceBasis.from_hdulist(hdul, prefix="REF_")
                seed = int(h["SEED"])
                cell = h.get("CELL")
                if cell is None:  # files of version <= 0.x: the grid size
                    cell = (max(image.shape) - 1) / (int(h["GRIDSIZE"]) - 1)
                meta = {"seed": None if seed < 0 else seed, "slope": h["SLOPE"],
                        "smallest_scale": float(cell) * h["PIXSCALE"], "cell": float(cell),
                        "subpixel": bool(h.get("SUBPIXEL", False)), "gain": h.get("GAIN"),
                        "saturation": h.get("SATURATE"), "galaxy_layout": h["LAYOUT"],
                        "field_scales": [h[f"FSCALE{i}"] for i in range(ref.n_components)]
                        if "FSCALE0" in h else None,
                        "version": h["SKPSFVER"]}
                weight = (np.array(hdul["WEIGHT"].data, dtype=np.float32)
                          if "WEIGHT" in hdul else None)
                contam = Table.read(hdul["CONTAMINANTS"]) if "CONTAMINANTS" in hdul else None
                return cls(image, h["NOISERMS"], h["PIXSCALE"], ref, stars, gals, meta,
                           weight=weight, contaminants=contam)
        except ValueError:
            raise
        except (OSError, TypeError, KeyError, IndexError, fits.VerifyError) as exc:
            raise ValueError(
                f"Could not read {path!r} as a saved PSF field ({type(exc).__name__}: {exc})."
            ) from None


def _shift_gradient(images):
    """Derivative of images (n, s, s) with respect to a shift of their content by (dx, dy):
    minus their spatial gradient, computed in Fourier space, shape (n, 2, s*s)."""
    n, s = images.shape[0], images.shape[-1]
    ft = np.fft.rfft2(images)
    kx = 2j * np.pi * np.fft.rfftfreq(s)[None, None, :]
    ky = 2j * np.pi * np.fft.fftfreq(s)[None, :, None]
    grad = -np.fft.irfft2(np.stack([ft * kx, ft * ky], axis=1), s=(s, s))
    return grad.reshape(n, 2, s * s)


def _robust_rms(image) -> float:
    """1.4826 x MAD of a subsample of the image (stars are sparse: a robust noise estimate)."""
    flat = np.asarray(image).ravel()
    step = max(1, flat.size // 2_000_000)
    sample = flat[::step].astype(np.float64)
    return float(1.4826 * np.median(np.abs(sample - np.median(sample))))


