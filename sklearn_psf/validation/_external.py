"""PSF models of other tools (PSFEx, PIFF) read with their own readers, predicting stamps as
:class:`~sklearn_psf.model.PSFModel` does, so that one validation measures them all."""

from __future__ import annotations

import os
import warnings

import numpy as np
from astropy.io import fits

from .._files import InputError, one_line
from .._optional import require
from ..preprocessing import StampNormalizer
from ._psfex import psfex_terms

__all__ = ["PSFExModel", "PiffModel", "load_psf_model", "model_kind"]

def _positions(X):
    X = np.asarray(X, dtype=np.float64)
    if X.ndim != 2 or X.shape[1] != 2:
        raise ValueError(f"positions must have shape (n, 2), got {X.shape}.")
    if not np.isfinite(X).all():
        row = int(np.flatnonzero(~np.isfinite(X).all(axis=1))[0])
        raise ValueError(f"positions hold NaN or infinite values (first at row {row}).")
    return X


def _odd_size(stamp_size):
    s = int(stamp_size)
    if s != stamp_size or s < 3 or s % 2 == 0:
        raise ValueError(f"stamp_size must be an odd integer >= 3, got {stamp_size!r}.")
    return s


def _normalised(cube, what):
    """Unit-sum stamps with their adaptive centroid on the centre pixel (the package's
    convention), flattened; the reader's own centring convention drops out."""
    n = cube.shape[0]
    flat = cube.reshape(n, -1)
    bad = ~(flat.sum(axis=1) > 0)
    if bad.any():
        raise ValueError(f"The {what} model gives no positive flux at {int(bad.sum())} of {n} "
                         f"positions (first at row {int(np.flatnonzero(bad)[0])}).")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a stamp whose moments fail stays unshifted
        return StampNormalizer().fit_transform(flat)


def _lanczos3(u):
    """GalSim's ``Lanczos(3)`` kernel, made to conserve a constant: its weights at any
    sub-pixel shift sum to 1 (GalSim's ``conserve_dc=True`` does so to ~1e-5)."""
    def raw(t):
        return np.where(np.abs(t) < 3.0, np.sinc(t) * np.sinc(t / 3.0), 0.0)

    frac = u - np.round(u)
    return raw(u) / sum(raw(frac - k) for k in range(-3, 4))


def _resampling(n_model, n_stamp, samp):
    """Weights (n_stamp, n_model) of the model's pixels at each stamp pixel along one axis:
    planes sampled every ``samp`` image pixels, interpolated with Lanczos-3 at the centres
    of image pixels, both arrays centred on their middle (``(n - 1) / 2``), as GalSim's
    ``InterpolatedImage`` drawn with ``method='no_pixel'``."""
    stamp = (np.arange(n_stamp) - (n_stamp - 1) / 2.0) / samp
    model = np.arange(n_model) - (n_model - 1) / 2.0
    return _lanczos3(stamp[:, None] - model[None, :])


def _read_psfex(path):
    """``(planes (n_terms, ny, nx), degree, polzero, polscal, psf_samp)`` of a ``.psf`` file:
    PSFEx's layout (HDU 1, ``PSF_MASK`` and the ``POL*`` keywords); an InputError naming
    the file otherwise."""
    def bad(why):
        return InputError(f"{path!r} is not a PSFEx .psf file this package can read: {why}.")

    try:
        with fits.open(path, memmap=False) as hdul:
            if len(hdul) < 2 or not isinstance(hdul[1], fits.BinTableHDU) \
                    or "PSF_MASK" not in hdul[1].columns.names:
                raise bad("no PSF_MASK table in HDU 1")
            h = hdul[1].header
            planes = np.array(hdul[1].data["PSF_MASK"][0], dtype=np.float64)
    except OSError as exc:
        raise bad(one_line(exc)) from None
    if planes.ndim == 2:
        planes = planes[None]
    n_axes = int(h.get("POLNAXIS", 0))
    if n_axes == 0:  # PSFVAR_DEGREES 0: a constant PSF, no POL* keywords
        degree, polzero, polscal = 0, (0.0, 0.0), (1.0, 1.0)
    else:
        names = (str(h.get("POLNAME1", "")), str(h.get("POLNAME2", "")))
        if n_axes != 2 or int(h.get("POLNGRP", 1)) != 1 \
                or not (names[0].startswith("X") and names[0].endswith("IMAGE")
                        and names[1].startswith("Y") and names[1].endswith("IMAGE")):
            raise bad(f"its polynomial is of {n_axes} context parameters "
                      f"({', '.join(str(h.get(f'POLNAME{k}')) for k in range(1, n_axes + 1))}"
                      "): only the positions (X*_IMAGE, Y*_IMAGE) are read")
        try:
            degree = int(h["POLDEG1"])
            polzero = (float(h["POLZERO1"]), float(h["POLZERO2"]))
            polscal = (float(h["POLSCAL1"]), float(h["POLSCAL2"]))
        except KeyError as exc:
            raise bad(f"keyword {exc.args[0]} missing") from None
        if 0.0 in polscal:
            raise bad("POLSCAL is 0")
    if planes.ndim != 3 or len(planes) != (degree + 1) * (degree + 2) // 2:
        raise bad(f"PSF_MASK of shape {planes.shape} for a polynomial of degree {degree}, "
                  f"which has {(degree + 1) * (degree + 2) // 2} terms")
    if not np.isfinite(planes).all():
        raise bad("PSF_MASK holds NaN or infinite values")
    samp = float(h.get("PSF_SAMP", 1.0))
    if not samp > 0:
        raise bad(f"PSF_SAMP is {samp}")
    return planes, degree, polzero, polscal, samp


class PSFExModel:
    """A PSFEx model (``.psf`` file), read and drawn without GalSim.

    The PSF at a position is PSFEx's: the ``PSF_MASK`` planes weighted by the polynomial
    terms of the position (:func:`~sklearn_psf.validation.psfex_terms`, with ``POLZERO`` and
    ``POLSCAL``), sampled every ``PSF_SAMP`` image pixels. ``predict(X)`` resamples it to
    image pixels as GalSim's ``galsim.des.DES_PSFEx`` draws it with ``method='no_pixel'``
    (the model already includes the pixel response): Lanczos-3 interpolation, the planes'
    middle ``(n - 1) / 2`` on the stamp's centre pixel. The stamps are then normalised as
    :meth:`PSFModel.predict <sklearn_psf.model.PSFModel.predict>` stamps are: unit sum,
    adaptive centroid on the centre pixel. Files of PSFEx itself (``PSFVAR_DEGREES`` 0 to
    any degree in ``X*_IMAGE``, ``Y*_IMAGE``, any ``PSF_SAMP``) and of
    :func:`~sklearn_psf.validation.write_psfex` are read; a polynomial in other catalogue
    columns (``PSFVAR_KEYS`` such as a magnitude) is refused.

    Parameters
    ----------
    path : str or os.PathLike
        PSFEx ``.psf`` file (a FITS table with ``PSF_MASK`` and the ``POL*`` keywords).
    stamp_size : int, optional
        Odd side of the predicted stamps; default the model's own size in image pixels
        (``PSFAXIS1 * PSF_SAMP``, made odd).
    origin : {0, 1}, default=1
        Pixel convention of the model: 1 for the FITS / SExtractor convention (``X_IMAGE``)
        that PSFEx's polynomial uses; positions given to :meth:`predict` are 0-based and
        converted.

    Attributes
    ----------
    stamp_size_ : int
    degree_ : int
        Degree of PSFEx's polynomial in (x, y).
    sampling_ : float
        ``PSF_SAMP``: image pixels per model pixel.

    Examples
    --------
    >>> import os, tempfile
    >>> import numpy as np
    >>> from sklearn_psf.validation import PSFExModel, write_psfex
    >>> yy, xx = np.mgrid[-7:8, -7:8]
    >>> mask = np.exp(-(xx**2 + yy**2) / 8.0)[None]        # degree 0: one constant PSF
    >>> path = os.path.join(tempfile.mkdtemp(), "ccd.psf")
    >>> write_psfex(path, mask, polzero=(500.0, 500.0), polscal=(1000.0, 1000.0))
    >>> psf = PSFExModel(path).predict([[100.0, 200.0]])
    >>> psf.shape, round(float(psf.sum()), 6)
    ((1, 225), 1.0)
    """

    def __init__(self, path, stamp_size=None, *, origin: int = 1):
        self.path = os.fspath(path)
        self.origin = int(origin)
        (self._planes, self.degree_, self._polzero, self._polscal,
         self.sampling_) = _read_psfex(self.path)
        if stamp_size is None:
            side = int(np.ceil(self._planes.shape[-1] * self.sampling_))
            stamp_size = side + 1 - side % 2
        self.stamp_size_ = _odd_size(stamp_size)
        _, ny, nx = self._planes.shape
        self._wy = _resampling(ny, self.stamp_size_, self.sampling_)
        self._wx = _resampling(nx, self.stamp_size_, self.sampling_)

    def predict(self, X, offsets=None) -> np.ndarray:
        """Normalised PSF stamps (n, stamp_size_**2) at 0-based positions X (n, 2).

        Without ``offsets``, centred: unit sum, adaptive centroid on the centre pixel. With
        ``offsets`` ((n, 2) pixels), each star drawn at that (dx, dy) from the centre pixel
        (the planes' middle there, Lanczos-3 at the shifted pixel centres, as PSFEx
        resamples its model to a star), unit sum, not moved.
        """
        X = _positions(X) + self.origin
        terms = psfex_terms(X, self.degree_, self._polzero, self._polscal)
        planes = np.tensordot(terms, self._planes, axes=(1, 0))  # (n, ny, nx)
        if offsets is None:
            return _normalised(self._wy @ planes @ self._wx.T, "PSFEx")
        off = np.asarray(offsets, dtype=np.float64).reshape(len(X), 2)
        _, ny, nx = self._planes.shape
        pixel = np.arange(self.stamp_size_) - (self.stamp_size_ - 1) / 2.0
        out = np.empty((len(X), self.stamp_size_ ** 2))
        for lo in range(0, len(X), 256):  # the per-star weights in chunks
            sl = slice(lo, lo + 256)
            wy, wx = (_lanczos3((pixel[None, :, None] - off[sl, k, None, None]) / self.sampling_
                                - (np.arange(m) - (m - 1) / 2.0)[None, None, :])
                      for k, m in ((1, ny), (0, nx)))
            out[sl] = (wy @ planes[sl] @ wx.transpose(0, 2, 1)).reshape(len(wy), -1)
        total = out.sum(axis=1, keepdims=True)
        if not (total > 0).all():
            raise ValueError(f"The PSFEx model gives no positive flux at "
                             f"{int(np.sum(~(total > 0)))} of {len(X)} positions.")
        return out / total


class PiffModel:
    """A PIFF model file, read with ``piff.read``.

    ``predict(X)`` draws the PSF at each position with PIFF's own ``PSF.draw`` (centred in
    the stamp, on the image's pixel grid through the model's WCS), then normalises it as
    :meth:`PSFModel.predict <sklearn_psf.model.PSFModel.predict>` stamps are: unit sum,
    adaptive centroid on the centre pixel. Needs PIFF (``pip install 'sklearn-psf[piff]'``).

    Parameters
    ----------
    path : str or os.PathLike
        File written by ``piff.PSF.write`` (or ``piffify``).
    stamp_size : int, default=25
        Odd side of the predicted stamps.
    origin : {0, 1}, default=1
        Pixel convention of the model's positions: 1 when PIFF was run on FITS images (GalSim
        images start at pixel 1); positions given to :meth:`predict` are 0-based.
    chipnum : int, optional
        CCD of a multi-chip model; required when the file holds several.

    Attributes
    ----------
    stamp_size_ : int
    psf_ : piff.PSF
        The model as PIFF reads it.
    """

    def __init__(self, path, stamp_size=25, *, origin: int = 1, chipnum=None):
        piff = require("piff", "Reading a PIFF model")
        self.path = os.fspath(path)
        self.origin = int(origin)
        self.chipnum = chipnum
        self.stamp_size_ = _odd_size(stamp_size)
        try:
            self.psf_ = piff.read(self.path)
        except (OSError, KeyError, ValueError) as exc:
            raise ValueError(f"{self.path!r} is not a PIFF file piff can read: {exc}") from None
        chips = list(self.psf_.wcs)
        if chipnum is None and len(chips) > 1:
            raise ValueError(f"{self.path!r} models {len(chips)} chips ({chips}): choose one "
                             "with chipnum.")
        if chipnum is not None and chipnum not in chips:
            raise ValueError(f"chipnum {chipnum!r} is not in {self.path!r} (chips: {chips}).")

    def predict(self, X) -> np.ndarray:
        """Normalised PSF stamps (n, stamp_size_**2) at 0-based positions X (n, 2)."""
        X = _positions(X) + self.origin
        s = self.stamp_size_
        out = np.empty((len(X), s, s))
        for i, (x, y) in enumerate(X):
            out[i] = self.psf_.draw(x, y, chipnum=self.chipnum, stamp_size=s, center=True).array
        return _normalised(out, "PIFF")


def model_kind(path) -> str:
    """What a model file is: ``"sklearn_psf"``, ``"psfex"`` or ``"piff"``.

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    kind : str

    Raises
    ------
    ValueError
        For a file that is none of the three (or not a FITS file).

    Examples
    --------
    >>> import os, tempfile
    >>> import numpy as np
    >>> from sklearn_psf.validation import model_kind, write_psfex
    >>> path = os.path.join(tempfile.mkdtemp(), "ccd.psf")
    >>> write_psfex(path, np.ones((1, 5, 5)), polzero=(0.0, 0.0), polscal=(1.0, 1.0))
    >>> model_kind(path)
    'psfex'
    """
    from ..model import MODEL_FORMAT

    path = os.fspath(path)
    if not os.path.isfile(path):
        raise ValueError(f"model file {path!r} does not exist.")
    try:
        with fits.open(path, memmap=False) as hdul:
            primary = hdul[0].header
            if primary.get("SKPSFFMT") == MODEL_FORMAT:
                return "sklearn_psf"
            if "PIFF_VERSION" in primary:
                return "piff"
            if len(hdul) > 1 and "POLNAXIS" in hdul[1].header \
                    and "PSF_MASK" in getattr(hdul[1], "columns", ()).names:
                return "psfex"
    except (OSError, AttributeError) as exc:
        raise ValueError(f"{path!r} is not a FITS file: {exc}") from None
    raise ValueError(f"{path!r} is neither a sklearn_psf model file (SKPSFFMT keyword), a "
                     "PSFEx .psf file (PSF_MASK table with POLNAXIS) nor a PIFF file "
                     "(PIFF_VERSION keyword).")


def load_psf_model(path, stamp_size=None, *, origin: int = 1, chipnum=None):
    """Read any PSF model file: this package's, PSFEx's or PIFF's (see :func:`model_kind`).

    Parameters
    ----------
    path : str or os.PathLike
    stamp_size : int, optional
        Side of the stamps a PSFEx or PIFF model predicts (default: PSFEx's own size, 25 for
        PIFF); this package's models predict their own size.
    origin : {0, 1}, default=1
        Pixel convention of a PSFEx or PIFF model (see :class:`PSFExModel`).
    chipnum : int, optional
        CCD of a multi-chip PIFF model.

    Returns
    -------
    model : PSFModel, PSFExModel or PiffModel
        With ``predict(X)`` giving unit-sum, centred stamps at 0-based positions.

    Examples
    --------
    >>> import os, tempfile
    >>> import numpy as np
    >>> from sklearn_psf.validation import load_psf_model, write_psfex
    >>> path = os.path.join(tempfile.mkdtemp(), "ccd.psf")
    >>> write_psfex(path, np.ones((1, 5, 5)), polzero=(0.0, 0.0), polscal=(1.0, 1.0))
    >>> type(load_psf_model(path, stamp_size=9)).__name__
    'PSFExModel'
    """
    kind = model_kind(path)
    if kind == "sklearn_psf":
        from ..model import load_model

        return load_model(path)
    if kind == "psfex":
        return PSFExModel(path, stamp_size, origin=origin)
    return PiffModel(path, 25 if stamp_size is None else stamp_size, origin=origin,
                     chipnum=chipnum)
