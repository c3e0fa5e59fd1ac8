"""PSF models of other tools (PSFEx, PIFF) read with their own readers, predicting stamps as
:class:`~sklearn_psf.model.PSFModel` does, so that one validation measures them all."""

from __future__ import annotations

import os
import warnings

import numpy as np
from astropy.io import fits

from .._files import InputError
from ..preprocessing import StampNormalizer

__all__ = ["PSFExModel", "PiffModel", "load_psf_model", "model_kind"]

_INSTALL = {
    "galsim": "pip install 'sklearn-psf[galsim]' (or: pip install galsim)",
    "piff": "pip install 'sklearn-psf[piff]' (or: pip install piff)",
}


def _require(module: str, what: str):
    """Import an optional dependency, or fail saying how to install it."""
    try:
        return __import__(module)
    except ImportError as exc:
        raise ImportError(f"{what} needs the optional package {module!r}, which is not "
                          f"installed: {_INSTALL[module]}.") from exc


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


class PSFExModel:
    """A PSFEx model (``.psf`` file), read with GalSim's ``galsim.des.DES_PSFEx``.

    ``predict(X)`` draws the PSF at each position on the pixel grid (``method='no_pixel'``:
    the model already includes the pixel response) in a stamp of ``stamp_size`` pixels, then
    normalises it as :meth:`PSFModel.predict <sklearn_psf.model.PSFModel.predict>` stamps
    are: unit sum, adaptive centroid on the centre pixel. Needs GalSim (``pip install
    'sklearn-psf[galsim]'``).

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
        galsim = _require("galsim", "Reading a PSFEx model")
        import galsim.des  # noqa: F401  (the subpackage is not imported by galsim itself)

        self.path = os.fspath(path)
        self.origin = int(origin)
        try:
            with fits.open(self.path, memmap=False) as hdul:
                hdu = hdul[1].copy()
            if hdu.header.get("POLNAXIS") == 0:
                # PSFVAR_DEGREES 0 (a constant PSF): PSFEx writes no POL* axes, which GalSim
                # wants; a polynomial of degree 0 in (X_IMAGE, Y_IMAGE) is the same PSF
                hdu.header.update({"POLNAXIS": 2, "POLNGRP": 1, "POLNAME1": "X_IMAGE",
                                   "POLNAME2": "Y_IMAGE", "POLZERO1": 0.0, "POLZERO2": 0.0,
                                   "POLSCAL1": 1.0, "POLSCAL2": 1.0, "POLGRP1": 1,
                                   "POLGRP2": 1, "POLDEG1": 0})
            self._psfex = galsim.des.DES_PSFEx(hdu)
        except (OSError, KeyError, IndexError) as exc:
            raise InputError(f"{self.path!r} is not a PSFEx .psf file GalSim can read: "
                             f"{exc}") from None
        self.degree_ = int(self._psfex.fit_order)
        self.sampling_ = float(self._psfex.sample_scale)
        if stamp_size is None:
            side = int(np.ceil(self._psfex.basis.shape[-1] * self.sampling_))
            stamp_size = side + 1 - side % 2
        self.stamp_size_ = _odd_size(stamp_size)

    def predict(self, X) -> np.ndarray:
        """Normalised PSF stamps (n, stamp_size_**2) at 0-based positions X (n, 2)."""
        import galsim

        X = _positions(X) + self.origin
        s = self.stamp_size_
        out = np.empty((len(X), s, s))
        image = galsim.ImageD(s, s, scale=1.0)
        for i, (x, y) in enumerate(X):
            psf = self._psfex.getPSF(galsim.PositionD(x, y))
            psf.drawImage(image=image, method="no_pixel")
            out[i] = image.array
        return _normalised(out, "PSFEx")


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
        piff = _require("piff", "Reading a PIFF model")
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
