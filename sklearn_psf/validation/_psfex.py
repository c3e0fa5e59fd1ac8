"""Writing a polynomial PSF in PSFEx's ``.psf`` format (what PSFEx writes, GalSim reads)."""

from __future__ import annotations

import numpy as np
from astropy.io import fits

from .._files import write_fits_atomic

__all__ = ["write_psfex", "psfex_terms"]


def psfex_terms(X, degree: int, polzero, polscal) -> np.ndarray:
    """PSFEx's polynomial terms of positions: (n, (degree+1)(degree+2)/2).

    With u = (x - polzero[0]) / polscal[0] and v = (y - polzero[1]) / polscal[1], the terms
    are u^i v^j for j = 0..degree, i = 0..degree-j, in that order (i fastest): the order of
    the ``PSF_MASK`` planes. The PSF at a position is ``terms @ PSF_MASK``.

    Parameters
    ----------
    X : array-like of shape (n, 2)
        Positions in the model's convention (PSFEx: 1-based ``X_IMAGE``, ``Y_IMAGE``).
    degree : int
    polzero, polscal : pair of float
        ``POLZERO1/2`` and ``POLSCAL1/2``.

    Returns
    -------
    terms : ndarray of shape (n, (degree+1)(degree+2)/2)

    Examples
    --------
    >>> from sklearn_psf.validation import psfex_terms
    >>> psfex_terms([[3.0, 5.0]], 2, (1.0, 1.0), (2.0, 2.0)).tolist()  # u = 1, v = 2
    [[1.0, 1.0, 1.0, 2.0, 2.0, 4.0]]
    """
    X = np.asarray(X, dtype=np.float64)
    u = (X[:, 0] - polzero[0]) / polscal[0]
    v = (X[:, 1] - polzero[1]) / polscal[1]
    d = int(degree)
    return np.column_stack([u**i * v**j for j in range(d + 1) for i in range(d + 1 - j)])


def write_psfex(path, psf_mask, polzero, polscal, *, psf_samp: float = 1.0,
                overwrite: bool = False) -> None:
    """Write a PSF whose pixels are polynomials of the position as a PSFEx ``.psf`` file.

    The layout is PSFEx's: HDU 1 ``PSF_DATA``, a binary table of one row whose ``PSF_MASK``
    column holds the (n_terms, ny, nx) planes, with the keywords ``POLNAXIS = 2``,
    ``POLNAME1/2 = 'X_IMAGE'/'Y_IMAGE'``, ``POLZERO1/2``, ``POLSCAL1/2``, ``POLGRP1/2 = 1``,
    ``POLNGRP = 1``, ``POLDEG1``, ``PSF_SAMP``, ``PSFNAXIS = 3`` and ``PSFAXIS1..3``. GalSim's
    ``galsim.des.DES_PSFEx`` (and :class:`PSFExModel`) read it: the PSF at ``(x, y)`` is
    ``psfex_terms([(x, y)], degree, polzero, polscal) @ psf_mask``, sampled every
    ``psf_samp`` image pixels.

    Parameters
    ----------
    path : str or os.PathLike
    psf_mask : array-like of shape (n_terms, ny, nx)
        One plane per polynomial term, in :func:`psfex_terms` order; n_terms must be
        (d+1)(d+2)/2 for a degree d.
    polzero, polscal : pair of float
        Position offset and scale of the polynomial (x, y), in the model's pixel convention
        (PSFEx: 1-based).
    psf_samp : float, default=1
        Image pixels per model pixel.
    overwrite : bool, default=False

    Examples
    --------
    >>> import os, tempfile
    >>> import numpy as np
    >>> from astropy.io import fits
    >>> from sklearn_psf.validation import write_psfex
    >>> path = os.path.join(tempfile.mkdtemp(), "ccd.psf")
    >>> write_psfex(path, np.ones((3, 7, 7)), polzero=(1024.5, 2048.5),
    ...             polscal=(2048.0, 4096.0))                  # degree 1: 3 planes
    >>> h = fits.getheader(path, 1)
    >>> h["POLDEG1"], h["PSFAXIS3"], fits.getdata(path, 1)["PSF_MASK"].shape
    (1, 3, (1, 3, 7, 7))
    """
    mask = np.asarray(psf_mask, dtype=np.float32)
    if mask.ndim != 3:
        raise ValueError(f"psf_mask must have shape (n_terms, ny, nx), got {mask.shape}.")
    n_terms, ny, nx = mask.shape
    degree = int(round((np.sqrt(8 * n_terms + 1) - 3) / 2))
    if (degree + 1) * (degree + 2) // 2 != n_terms:
        raise ValueError(f"psf_mask has {n_terms} planes: a polynomial of degree d in (x, y) "
                         "has (d+1)(d+2)/2 terms (1, 3, 6, 10, ...).")
    if not np.isfinite(mask).all():
        raise ValueError("psf_mask holds NaN or infinite values.")
    zero = [float(v) for v in polzero]
    scale = [float(v) for v in polscal]
    if len(zero) != 2 or len(scale) != 2 or not all(np.isfinite(zero + scale)) or \
            0.0 in scale:
        raise ValueError(f"polzero and polscal must be two finite numbers each, polscal not 0; "
                         f"got {polzero!r}, {polscal!r}.")
    column = fits.Column(name="PSF_MASK", format=f"{mask.size}E", dim=f"({nx}, {ny}, {n_terms})",
                         array=mask[None])
    hdu = fits.BinTableHDU.from_columns([column], name="PSF_DATA")
    h = hdu.header
    h["LOADED"] = (0, "number of loaded sources (not recorded here)")
    h["POLNAXIS"] = (2, "number of context parameters")
    for k, name in ((1, "X_IMAGE"), (2, "Y_IMAGE")):
        h[f"POLGRP{k}"] = (1, "polynom group for this context parameter")
        h[f"POLNAME{k}"] = (name, "name of this context parameter")
        h[f"POLZERO{k}"] = (zero[k - 1], "offset value for this context parameter")
        h[f"POLSCAL{k}"] = (scale[k - 1], "scale value for this context parameter")
    h["POLNGRP"] = (1, "number of polynom groups")
    h["POLDEG1"] = (degree, "polynom degree")
    h["PSF_SAMP"] = (float(psf_samp), "sampling step of the PSF data (image pixels)")
    h["PSFNAXIS"] = (3, "dimensionality of the PSF data")
    h["PSFAXIS1"] = (nx, "number of element along this axis")
    h["PSFAXIS2"] = (ny, "number of element along this axis")
    h["PSFAXIS3"] = (n_terms, "number of element along this axis")
    write_fits_atomic(fits.HDUList([fits.PrimaryHDU(), hdu]), path, overwrite=overwrite)
