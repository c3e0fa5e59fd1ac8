"""The reference basis of the simulations: PCA of the stars of a (real) reference image.

It lives in :mod:`sklearn_psf.datasets` (the data) and is re-exported by
:mod:`sklearn_psf.simulate` (which builds fields from it); ``datasets`` never imports
``simulate``.

Berge et al. (2012), section 3: stars are extracted from a reference image with SExtractor, their
normalised stamps are decomposed by PCA keeping 90% of the variance, and the principal
components are the basis from which mock PSFs are built; the spread of each component's
coefficient over the reference stars sets the variance of the simulated weights. Here the
extraction uses ``sep`` (SExtractor's algorithms as a library).
"""

from __future__ import annotations

import os

import numpy as np
from astropy.io import fits
from astropy.table import Table
from sklearn.decomposition import PCA
from sklearn.pipeline import Pipeline

from .._validation import as_stamps
from ..preprocessing import FixedBasis, StampNormalizer, cut_stamps

__all__ = ["ReferenceBasis", "read_fits_image"]

_FORMAT = "SKPSF-REFERENCE"


def _version() -> str:
    from .._version import __version__

    return __version__


def read_fits_image(path, hdu=None) -> tuple[np.ndarray, fits.Header]:
    """Read a 2-D image from a FITS file, with clear errors.

    Parameters
    ----------
    path : str or os.PathLike
        FITS file.
    hdu : int or str, optional
        HDU to read; default the first HDU holding a 2-D image.

    Returns
    -------
    image : ndarray of shape (ny, nx), float64 (native byte order)
    header : astropy.io.fits.Header

    Raises
    ------
    ValueError
        When the file is missing, not a FITS file, or holds no 2-D image.
    """
    path = os.fspath(path)
    if not os.path.exists(path):
        raise ValueError(f"FITS file {path!r} does not exist.")
    try:
        with fits.open(path, memmap=False) as hdul:
            if hdu is None:
                candidates = [h for h in hdul if h.is_image and h.data is not None
                              and h.data.ndim == 2]
                if not candidates:
                    raise ValueError(f"{path!r} holds no 2-D image HDU.")
                chosen = candidates[0]
            else:
                chosen = hdul[hdu]
                if not chosen.is_image or chosen.data is None or chosen.data.ndim != 2:
                    raise ValueError(f"HDU {hdu!r} of {path!r} is not a 2-D image.")
            data = np.array(chosen.data, dtype=np.float64)
            header = chosen.header.copy()
    except ValueError:
        raise
    except (OSError, TypeError, KeyError, IndexError) as exc:
        raise ValueError(
            f"Could not read {path!r} as a FITS image ({type(exc).__name__}: {exc}); "
            "check that the file is a valid FITS file."
        ) from None
    return data, header


class ReferenceBasis:
    """PCA basis of reference stars: the building blocks of simulated PSFs.

    Parameters
    ----------
    components : array-like of shape (k, s, s) or (k, s*s)
        Principal components (orthonormal rows when they come from PCA), s odd.
    mean : array-like of shape (s, s) or (s*s,)
        Mean normalised stamp (unit sum, centred: the :class:`StampNormalizer` convention).
    coeff_std : array-like of shape (k,)
        Standard deviation of each component's coefficient over the reference stars.
    coeff_mean : array-like of shape (k,), optional
        Mean coefficient over the reference stars (zero for a PCA fitted on those stars).
    positions : array-like of shape (n, 2), optional
        (x, y) pixel positions of the reference stars.
    image_shape : tuple (ny, nx), optional
        Shape of the reference image.
    pixel_scale : float, default=0.2
        Arcseconds per pixel.
    noise_rms : float, optional
        Background rms of the reference image (counts per pixel).
    explained_variance_ratio : array-like of shape (k,), optional
        Fraction of the stars' variance held by each component.

    Attributes
    ----------
    stamp_size : int
    n_components : int
    catalog : astropy.table.Table or None
        The selected stars (only for :meth:`from_image`).

    Examples
    --------
    >>> from sklearn_psf.datasets import load_default_reference
    >>> ref = load_default_reference()
    >>> ref.stamp_size, ref.components.shape[0] == ref.coeff_std.shape[0]
    (25, True)
    >>> coeffs = ref.coeff_std[None, :] * [[1.0] * ref.n_components]
    >>> round(float(ref.synthesize(coeffs).sum()), 6)
    1.0
    """

    def __init__(self, components, mean, coeff_std, coeff_mean=None, positions=None,
                 image_shape=None, pixel_scale=0.2, noise_rms=None,
                 explained_variance_ratio=None):
        comps = np.array(components, dtype=np.float64, copy=True)
        if comps.ndim == 2:
            comps = as_stamps(comps, name="components", copy=False)
        if comps.ndim != 3 or comps.shape[1] != comps.shape[2] or comps.shape[0] == 0:
            raise ValueError(
                f"components must have shape (k, s, s) or (k, s*s) with k >= 1, got {comps.shape}."
            )
        s = comps.shape[1]
        if s % 2 == 0:
            raise ValueError(f"stamps must have an odd side (a central pixel), got {s}.")
        mean = np.array(mean, dtype=np.float64, copy=True).reshape(-1)
        if mean.size != s * s:
            raise ValueError(f"mean must have {s * s} pixels (side {s}), got {mean.size}.")
        k = comps.shape[0]
        coeff_std = np.array(coeff_std, dtype=np.float64, copy=True).reshape(-1)
        if coeff_std.shape != (k,) or np.any(~np.isfinite(coeff_std)) or np.any(coeff_std < 0):
            raise ValueError(f"coeff_std must be {k} finite non-negative numbers.")
        coeff_mean = (np.zeros(k) if coeff_mean is None
                      else np.array(coeff_mean, dtype=np.float64, copy=True).reshape(-1))
        if coeff_mean.shape != (k,):
            raise ValueError(f"coeff_mean must have {k} values, got {coeff_mean.shape}.")
        if not (np.all(np.isfinite(comps)) and np.all(np.isfinite(mean))
                and np.all(np.isfinite(coeff_mean))):
            raise ValueError("components, mean and coeff_mean must be finite.")
        if positions is not None:
            positions = np.array(positions, dtype=np.float64, copy=True)
            if positions.ndim != 2 or positions.shape[1] != 2:
                raise ValueError(f"positions must have shape (n, 2), got {positions.shape}.")
        if image_shape is not None:
            image_shape = tuple(int(n) for n in image_shape)
        pixel_scale = float(pixel_scale)
        if not (np.isfinite(pixel_scale) and pixel_scale > 0):
            raise ValueError(f"pixel_scale must be positive, got {pixel_scale}.")
        self.components = comps
        self.mean = mean.reshape(s, s)
        self.coeff_std = coeff_std
        self.coeff_mean = coeff_mean
        self.positions = positions
        self.image_shape = image_shape
        self.pixel_scale = pixel_scale
        self.noise_rms = None if noise_rms is None else float(noise_rms)
        self.explained_variance_ratio = (
            None if explained_variance_ratio is None
            else np.array(explained_variance_ratio, dtype=np.float64).reshape(-1)
        )
        self.catalog = None

    # ------------------------------------------------------------------ properties
    @property
    def stamp_size(self) -> int:
        """Side s of the stamps."""
        return int(self.components.shape[1])

    @property
    def n_components(self) -> int:
        """Number k of principal components."""
        return int(self.components.shape[0])

    def __repr__(self) -> str:
        n = 0 if self.positions is None else len(self.positions)
        return (f"ReferenceBasis(n_components={self.n_components}, stamp_size={self.stamp_size}, "
                f"n_stars={n}, pixel_scale={self.pixel_scale})")

    # ------------------------------------------------------------------ building
    @classmethod
    def from_stamps(cls, stamps, *, variance: float = 0.9, positions=None, image_shape=None,
                    pixel_scale: float = 0.2, noise_rms=None, normalize: bool = True,
                    n_components: int | None = None):
        """PCA basis of star stamps.

        Parameters
        ----------
        stamps : array-like of shape (n, s, s) or (n, s*s)
            Background-subtracted star stamps (s odd). Not modified.
        variance : float, default=0.9
            Fraction of the variance kept (0 < variance <= 1), as ``PCA(n_components=...)``.
        positions, image_shape, pixel_scale, noise_rms
            Stored as they are (see the class parameters).
        normalize : bool, default=True
            Normalise the stamps with ``StampNormalizer(flux=True, center=True)`` first (pass
            False only for stamps that are already normalised).
        n_components : int, optional
            Keep exactly this many components instead of a fraction of the variance.

        Returns
        -------
        ReferenceBasis

        Examples
        --------
        >>> import numpy as np
        >>> from sklearn_psf.datasets import ReferenceBasis
        >>> y, x = np.mgrid[0:15, 0:15] - 7.0
        >>> rng = np.random.default_rng(0)
        >>> q = rng.normal(0.0, 0.1, (30, 1, 1))
        >>> stars = np.exp(-0.5 * (x**2 / (2 + q) + y**2 / (2 - q)))
        >>> ref = ReferenceBasis.from_stamps(stars)
        >>> ref.n_components, ref.stamp_size
        (1, 15)
        """
        cube = as_stamps(stamps, copy=False)
        n, s, _ = cube.shape
        if s % 2 == 0:
            raise ValueError(f"stamps must have an odd side (a central pixel), got {s}.")
        if n < 3:
            raise ValueError(f"Need at least 3 star stamps to build a PCA basis, got {n}.")
        if not np.all(np.isfinite(cube)):
            raise ValueError("stamps hold NaN or infinite pixels: drop those stars first.")
        if not (0 < float(variance) <= 1):
            raise ValueError(f"variance must be in (0, 1], got {variance}.")
        flat = cube.reshape(n, s * s)
        if normalize:
            flat = StampNormalizer(flux=True, center=True).fit_transform(flat)
        keep = float(variance) if float(variance) < 1 else None
        if n_components is not None:
            keep = int(n_components)
            if keep != n_components or not 1 <= keep <= min(n, s * s):
                raise ValueError(f"n_components must be an integer in [1, {min(n, s * s)}] "
                                 f"(stars, pixels), got {n_components!r}.")
        pca = PCA(n_components=keep, svd_solver="full")
        coeffs = pca.fit_transform(flat)
        return cls(
            components=pca.components_,
            mean=pca.mean_,
            coeff_std=coeffs.std(axis=0, ddof=1),
            coeff_mean=coeffs.mean(axis=0),
            positions=positions,
            image_shape=image_shape,
            pixel_scale=pixel_scale,
            noise_rms=noise_rms,
            explained_variance_ratio=pca.explained_variance_ratio_,
        )

    @classmethod
    def from_image(cls, image, *, stamp_size: int = 25, variance: float = 0.9,
                   pixel_scale=None, hdu=None, detect_thresh: float = 5.0,
                   min_snr: float = 50.0, saturation=None, isolation=None,
                   locus_width: float = 0.1, min_stars: int = 5,
                   n_components: int | None = None):
        """Extract stars from an image with ``sep`` and build their PCA basis.

        Steps (the same for a real image and a simulated one; 1 to 3 are the package's star
        finder, :func:`sklearn_psf.exposure.find_stars`):

        1. background and its rms with ``sep.Background``; detection with ``sep.extract`` at
           ``detect_thresh`` times the global rms (min. area 5 pixels);
        2. for each detection: half-light radius (``sep.flux_radius``), windowed centroid
           (``sep.winpos``), aperture S/N within the stamp radius (``sep.sum_circle``);
        3. selection of point sources: sep flags 0 (not blended, not truncated), S/N >=
           ``min_snr``, unsaturated (peak + background below 0.9 x ``saturation``), isolated
           (no other detection closer than ``isolation`` pixels along x or y: their stamps
           would overlap), at least half a stamp + 2 pixels away from the image edges, and on
           the stellar locus: half-light radius within ``locus_width`` (relative) of the
           locus, found as the mode (shortest half-sample window) of the radii;
        4. stamps cut with :func:`~sklearn_psf.preprocessing.cut_stamps` from the
           background-subtracted image at the windowed centroids, then
           :meth:`from_stamps` (normalisation + PCA).

        Parameters
        ----------
        image : str, os.PathLike or array-like of shape (ny, nx)
            FITS file or image. Not modified.
        stamp_size : int, default=25
            Odd stamp side in pixels.
        variance : float, default=0.9
            Fraction of the variance kept by the PCA.
        pixel_scale : float, optional
            Arcsec per pixel; default the header's ``PIXSCALE`` keyword, else 0.2.
        hdu : int or str, optional
            HDU of a FITS file; default the first 2-D image.
        detect_thresh : float, default=5.0
            Detection threshold in units of the background rms.
        min_snr : float, default=50.0
            Smallest aperture S/N of a selected star.
        saturation : float, optional
            Saturation level (counts); default the header's ``SATURATE``, else none.
        isolation : float, optional
            Smallest distance to any other detection; default ``stamp_size``.
        locus_width : float, default=0.1
            Relative half-width of the stellar locus in half-light radius.
        min_stars : int, default=5
            Fewer selected stars raise a ValueError.
        n_components : int, optional
            Keep exactly this many components (see :meth:`from_stamps`).

        Returns
        -------
        ReferenceBasis
            With ``positions`` (the selected stars), ``image_shape``, ``noise_rms`` and a
            ``catalog`` table of the selected stars.

        Raises
        ------
        ValueError
            For an unreadable file, an image with NaN/infinite pixels, a stamp larger than the
            image, or fewer than ``min_stars`` stars.

        Examples
        --------
        >>> import numpy as np
        >>> from sklearn_psf.simulate import ReferenceBasis, make_psf_field
        >>> field = make_psf_field(n_stars=60, n_galaxies=0, image_shape=(800, 1000),
        ...                        snr=300.0, random_state=0)
        >>> ref = ReferenceBasis.from_image(field.image)
        >>> len(ref.positions) >= 50
        True
        """
        from ..exposure._stars import _find_stars

        header = None
        if isinstance(image, (str, os.PathLike)):
            data, header = read_fits_image(image, hdu=hdu)
        else:
            data = np.array(image, dtype=np.float64, copy=True)
            if data.ndim != 2:
                raise ValueError(f"image must be 2-D, got {data.ndim} dimensions.")
        if not np.all(np.isfinite(data)):
            raise ValueError(
                f"image holds {np.count_nonzero(~np.isfinite(data))} NaN or infinite pixels: "
                "replace them (e.g. by the background) or mask them before extracting stars."
            )
        if pixel_scale is None:
            pixel_scale = float(header.get("PIXSCALE", 0.2)) if header is not None else 0.2
        if saturation is None and header is not None and "SATURATE" in header:
            saturation = float(header["SATURATE"])
        stars, sub = _find_stars(
            np.ascontiguousarray(data), stamp_size=stamp_size, detect_thresh=detect_thresh,
            min_snr=min_snr, saturation=saturation, isolation=isolation,
            locus_width=locus_width,
        )
        n_det = stars.meta["n_detections"]
        if n_det < min_stars:
            raise ValueError(
                f"Found {n_det} sources above {detect_thresh} sigma in the image, fewer than "
                f"min_stars={min_stars}: the image has no (or too few) stars."
            )
        if len(stars) < min_stars:
            raise ValueError(
                f"Only {len(stars)} isolated, unsaturated point sources with S/N >= {min_snr} "
                f"were found (out of {n_det} detections), fewer than min_stars={min_stars}: "
                "the image has too few usable stars (lower min_snr or use a deeper image)."
            )
        s = int(stamp_size)
        ny, nx = data.shape
        positions = np.column_stack([np.asarray(stars["x"]), np.asarray(stars["y"])])
        stamps, _ = cut_stamps(sub, positions, s)
        rms = stars.meta["noise_rms"]
        ref = cls.from_stamps(
            stamps, variance=variance, positions=positions,
            image_shape=(ny, nx), pixel_scale=pixel_scale, noise_rms=rms,
            n_components=n_components,
        )
        ref.catalog = Table(
            {name: np.asarray(stars[name]) for name in
             ("x", "y", "flux", "snr", "flux_radius", "peak")},
            meta={"n_detections": n_det, "locus_radius": stars.meta["locus_radius"],
                  "rejected": dict(stars.meta["rejected"])},
        )
        return ref

    # ------------------------------------------------------------------ use
    def synthesize(self, coeffs) -> np.ndarray:
        """Stamps ``mean + coeffs @ components``, flattened (n, s*s).

        Parameters
        ----------
        coeffs : array-like of shape (n, k)

        Returns
        -------
        stamps : ndarray of shape (n, s*s)
        """
        c = np.asarray(coeffs, dtype=np.float64)
        if c.ndim != 2 or c.shape[1] != self.n_components:
            raise ValueError(f"coeffs must have shape (n, {self.n_components}), got {c.shape}.")
        return self.mean.reshape(1, -1) + c @ self.components.reshape(self.n_components, -1)

    def as_transformer(self, normalize: bool = True):
        """A fitted transformer measuring stamps in this basis.

        Parameters
        ----------
        normalize : bool, default=True
            Return ``Pipeline([StampNormalizer(), FixedBasis(components, mean)])`` (raw star
            stamps in); with False only the fitted ``FixedBasis`` (normalised stamps in).

        Returns
        -------
        transformer : sklearn Pipeline or FixedBasis, fitted
            ``transform`` gives coefficients (n, k), ``inverse_transform`` normalised stamps.

        Examples
        --------
        >>> from sklearn_psf.datasets import load_default_reference
        >>> ref = load_default_reference()
        >>> basis = ref.as_transformer()
        >>> basis.transform(ref.mean.reshape(1, -1)).shape == (1, ref.n_components)
        True
        """
        p = self.stamp_size ** 2
        fixed = FixedBasis(self.components.reshape(self.n_components, p), self.mean.reshape(-1))
        probe = self.mean.reshape(1, -1)
        if not normalize:
            return fixed.fit(probe)
        pipe = Pipeline([("normalize", StampNormalizer(flux=True, center=True)),
                         ("basis", fixed)])
        return pipe.fit(probe)

    def padded(self, stamp_size: int) -> "ReferenceBasis":
        """A copy with stamps zero-padded to a larger odd ``stamp_size`` (exact: no flux lost)."""
        s = self.stamp_size
        t = int(stamp_size)
        if t != stamp_size or t % 2 == 0 or t < s:
            raise ValueError(
                f"stamp_size must be an odd integer >= the reference's stamp size {s}, got "
                f"{stamp_size!r} (smaller stamps would cut the PSF and lose flux)."
            )
        pad = (t - s) // 2
        comps = np.pad(self.components, ((0, 0), (pad, pad), (pad, pad)))
        mean = np.pad(self.mean, pad)
        out = ReferenceBasis(comps, mean, self.coeff_std, self.coeff_mean, self.positions,
                             self.image_shape, self.pixel_scale, self.noise_rms,
                             self.explained_variance_ratio)
        return out

    # ------------------------------------------------------------------ I/O
    def to_hdus(self, prefix: str = "") -> list:
        """FITS extensions (ImageHDU / BinTableHDU) holding the basis, names with ``prefix``."""
        comp = fits.ImageHDU(self.components.astype(np.float64), name=f"{prefix}COMPONENTS")
        h = comp.header
        h["SKPSFFMT"] = (_FORMAT, "sklearn_psf reference basis")
        h["SKPSFVER"] = (_version(), "sklearn_psf version")
        h["PIXSCALE"] = (self.pixel_scale, "arcsec per pixel")
        h["STAMPSZ"] = (self.stamp_size, "stamp side in pixels")
        h["NCOMP"] = (self.n_components, "number of principal components")
        if self.noise_rms is not None:
            h["NOISERMS"] = (self.noise_rms, "reference image background rms")
        if self.image_shape is not None:
            h["IMNY"], h["IMNX"] = self.image_shape
        mean = fits.ImageHDU(self.mean.astype(np.float64), name=f"{prefix}MEAN")
        cols = {"coeff_mean": self.coeff_mean, "coeff_std": self.coeff_std}
        if self.explained_variance_ratio is not None:
            cols["explained_variance_ratio"] = self.explained_variance_ratio
        hdus = [comp, mean, fits.table_to_hdu(Table(cols))]
        hdus[-1].name = f"{prefix}COEFFS"
        if self.positions is not None:
            t = Table({"x": self.positions[:, 0], "y": self.positions[:, 1]})
            hdus.append(fits.table_to_hdu(t))
            hdus[-1].name = f"{prefix}POSITIONS"
        return hdus

    @classmethod
    def from_hdulist(cls, hdul, prefix: str = "") -> "ReferenceBasis":
        """Rebuild a basis from an open HDU list written by :meth:`to_hdus`."""
        try:
            comp = hdul[f"{prefix}COMPONENTS"]
            h = comp.header
            if h.get("SKPSFFMT") != _FORMAT:
                raise KeyError("SKPSFFMT")
            coeffs = Table(hdul[f"{prefix}COEFFS"].data)
            positions = None
            if f"{prefix}POSITIONS" in hdul:
                t = hdul[f"{prefix}POSITIONS"].data
                positions = np.column_stack([t["x"], t["y"]]).astype(np.float64)
            shape = (h["IMNY"], h["IMNX"]) if "IMNY" in h else None
            return cls(
                components=np.array(comp.data, dtype=np.float64),
                mean=np.array(hdul[f"{prefix}MEAN"].data, dtype=np.float64),
                coeff_std=np.asarray(coeffs["coeff_std"], dtype=np.float64),
                coeff_mean=np.asarray(coeffs["coeff_mean"], dtype=np.float64),
                positions=positions, image_shape=shape, pixel_scale=h["PIXSCALE"],
                noise_rms=h.get("NOISERMS"),
                explained_variance_ratio=(
                    np.asarray(coeffs["explained_variance_ratio"], dtype=np.float64)
                    if "explained_variance_ratio" in coeffs.colnames else None),
            )
        except KeyError as exc:
            raise ValueError(
                f"The FITS file holds no sklearn_psf reference basis (missing {exc}); write one "
                "with ReferenceBasis.save."
            ) from None

    def save(self, path, overwrite: bool = False) -> None:
        """Write the basis to a FITS file (read it back with :meth:`load`).

        Parameters
        ----------
        path : str or os.PathLike
        overwrite : bool, default=False
        """
        primary = fits.PrimaryHDU()
        primary.header["SKPSFVER"] = (_version(), "sklearn_psf version")
        fits.HDUList([primary, *self.to_hdus()]).writeto(os.fspath(path), overwrite=overwrite)

    @classmethod
    def load(cls, path) -> "ReferenceBasis":
        """Read a basis written by :meth:`save`.

        Raises
        ------
        ValueError
            When the file is missing, not FITS, or holds no reference basis.
        """
        path = os.fspath(path)
        if not os.path.exists(path):
            raise ValueError(f"File {path!r} does not exist.")
        try:
            with fits.open(path, memmap=False) as hdul:
                hdul.verify("exception")
                return cls.from_hdulist(hdul)
        except ValueError:
            raise
        except (OSError, TypeError, IndexError, fits.VerifyError) as exc:
            raise ValueError(
                f"Could not read {path!r} as a FITS file ({type(exc).__name__}: {exc})."
            ) from None

