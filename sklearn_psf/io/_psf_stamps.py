"""PSF stamps for a catalogue of galaxies, in one file a shape-measurement pipeline reads in
one call: a FITS cube with its positions, or a NumPy ``.npz`` archive."""

from __future__ import annotations

import os

import numpy as np
from astropy.io import fits
from astropy.table import Table

from .._files import write_fits_atomic
from ._draw import draw_psf, extrapolation_flags

__all__ = ["write_psf_stamps", "read_psf_stamps"]

_FORMATS = {".fits": "fits", ".fit": "fits", ".fits.gz": "fits", ".npz": "npz"}


def _format(path):
    name = os.fspath(path).lower()
    for ext, kind in _FORMATS.items():
        if name.endswith(ext):
            return kind
    raise ValueError(f"{os.fspath(path)!r}: name the file .fits (a FITS cube) or .npz "
                     "(a NumPy archive).")


def write_psf_stamps(path, model, positions, *, oversampling: int = 1, centered: bool = False,
                     ids=None, overwrite: bool = False) -> None:
    """Write the model's PSF at each galaxy position to one file, read back in one call.

    The stamps come from :func:`draw_psf` (unit sum; ``oversampling`` samples per pixel
    along each axis; with ``centered`` the PSF moved to each position's sub-pixel offset
    from its nearest pixel, otherwise centred on the stamp's centre pixel, the centring most
    shape codes expect of a PSF image).

    - ``.fits``: HDU 1 ``PSF``, an image cube (n, S, S), ``fits.getdata(path, "PSF")``;
      HDU 2 ``POSITIONS``, a table of ``id``, ``x``, ``y`` (0-based pixels) and
      ``extrapolated`` (:func:`extrapolation_flags`) in the cube's order. The ``PSF``
      header holds ``OVERSAMP``, ``PIXSCALE`` (image pixels per sample), ``CENTERED`` and
      ``STAMPSZ``.
    - ``.npz``: ``numpy.load(path)`` holds ``psf`` (n, S, S), ``id``, ``x``, ``y``,
      ``extrapolated``, ``oversampling`` and ``centered``.

    Parameters
    ----------
    path : str or os.PathLike
        Ending in ``.fits`` or ``.npz``.
    model : fitted PSFModel (or any model whose ``predict`` gives (n, s*s) stamps; the
        extrapolation flags need its ``X_fit_``, otherwise they are all False)
    positions : array-like of shape (n, 2) or (n, 2 + m)
        Galaxy positions (x, y), 0-based pixels, then the model's extra dimensions if it has
        any (see :func:`draw_psf`).
    oversampling : int, default=1
    centered : bool, default=False
    ids : array-like of shape (n,), optional
        Galaxy identifiers stored with the stamps; default 0 to n-1.
    overwrite : bool, default=False
        Replace an existing file (otherwise an error).

    Examples
    --------
    >>> import os, tempfile
    >>> import numpy as np
    >>> from astropy.io import fits
    >>> from sklearn_psf.io import write_psf_stamps
    >>> class Gaussian:                      # any model whose predict gives stamps
    ...     def predict(self, X):
    ...         yy, xx = np.mgrid[-7:8, -7:8]
    ...         g = np.exp(-(xx**2 + yy**2) / 8.0).ravel()
    ...         return np.tile(g / g.sum(), (len(X), 1))
    >>> path = os.path.join(tempfile.mkdtemp(), "galaxy_psfs.fits")
    >>> write_psf_stamps(path, Gaussian(), [[10.0, 20.0], [300.5, 41.2]], oversampling=2)
    >>> fits.getdata(path, "PSF").shape
    (2, 30, 30)
    """
    kind = _format(path)
    X = np.asarray(positions, dtype=np.float64)
    if X.ndim != 2 or X.shape[1] < 2 or len(X) == 0:
        raise ValueError(f"positions must have shape (n, 2) (or (n, 2 + m) with the model's "
                         f"extra dimensions) with n >= 1, got {X.shape}.")
    if os.path.exists(path) and not overwrite:
        raise FileExistsError(f"{os.fspath(path)!r} already exists: pass overwrite=True to "
                              "replace it.")
    ids = np.arange(len(X)) if ids is None else np.asarray(ids)
    if ids.shape != (len(X),):
        raise ValueError(f"ids must have one entry per position ({len(X)}), got shape "
                         f"{ids.shape}.")
    cube = draw_psf(model, X, centered=centered, oversampling=oversampling)
    fitted = getattr(model, "X_fit_", None)
    extrapolated = extrapolation_flags(fitted, X) if fitted is not None \
        else np.zeros(len(X), dtype=bool)
    size = cube.shape[1]
    if kind == "npz":
        folder = os.path.dirname(os.path.abspath(path))
        if not os.path.isdir(folder):
            raise FileNotFoundError(f"The folder {folder!r} of {os.fspath(path)!r} does not "
                                    "exist.")
        with open(path, "wb") as f:
            np.savez(f, psf=cube, id=ids, x=X[:, 0], y=X[:, 1], extrapolated=extrapolated,
                     oversampling=int(oversampling), centered=bool(centered))
        return
    image = fits.ImageHDU(cube, name="PSF")
    h = image.header
    h["STAMPSZ"] = (size, "stamp side in samples")
    h["OVERSAMP"] = (int(oversampling), "samples per image pixel along each axis")
    h["PIXSCALE"] = (1.0 / int(oversampling), "image pixels per sample")
    h["CENTERED"] = (bool(centered), "PSF moved to the sub-pixel position")
    h["COMMENT"] = ("Unit-sum PSF stamps, one plane per row of POSITIONS; centre pixel "
                    f"({(size - 1) // 2}, {(size - 1) // 2}) 0-based; the pixel response "
                    "is included (draw with GalSim's method='no_pixel').")
    table = fits.table_to_hdu(Table({"id": ids, "x": X[:, 0], "y": X[:, 1],
                                     "extrapolated": extrapolated}))
    table.name = "POSITIONS"
    table.header["COMMENT"] = "x, y: 0-based pixel positions (x = column)"
    write_fits_atomic(fits.HDUList([fits.PrimaryHDU(), image, table]), path, overwrite=True)


def read_psf_stamps(path):
    """Read a file written by :func:`write_psf_stamps`.

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    psf : ndarray of shape (n, S, S)
    positions : astropy.table.Table
        ``id``, ``x``, ``y``, ``extrapolated``; ``meta`` holds ``oversampling`` and
        ``centered``.

    Examples
    --------
    >>> import os, tempfile
    >>> import numpy as np
    >>> from sklearn_psf.io import read_psf_stamps, write_psf_stamps
    >>> class Round:
    ...     def predict(self, X):
    ...         return np.full((len(X), 25), 1 / 25)
    >>> path = os.path.join(tempfile.mkdtemp(), "psfs.npz")
    >>> write_psf_stamps(path, Round(), [[1.0, 2.0]])
    >>> psf, pos = read_psf_stamps(path)
    >>> psf.shape, pos["x"][0], pos.meta["oversampling"]
    ((1, 5, 5), np.float64(1.0), 1)
    """
    if _format(path) == "npz":
        with np.load(path) as data:
            table = Table({k: data[k] for k in ("id", "x", "y", "extrapolated")})
            table.meta.update(oversampling=int(data["oversampling"]),
                              centered=bool(data["centered"]))
            return np.array(data["psf"]), table
    with fits.open(path, memmap=False) as hdul:
        try:
            image, positions = hdul["PSF"], hdul["POSITIONS"]
        except KeyError:
            raise ValueError(f"{os.fspath(path)!r} has no PSF and POSITIONS HDUs: not written "
                             "by write_psf_stamps.") from None
        table = Table.read(positions)
        table.meta = {"oversampling": int(image.header["OVERSAMP"]),
                      "centered": bool(image.header["CENTERED"])}
        return np.array(image.data, dtype=np.float64), table
