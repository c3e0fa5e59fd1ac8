"""An exposure read for a fit: its image (and weight map) and/or its source catalogue, with
the saturation level and gain the header (or the catalogue) gives; the catalogue's columns as
a model's extra dimensions."""

from __future__ import annotations

import contextlib
import os
from typing import NamedTuple

import numpy as np

from .._files import InputError, is_input_error

__all__ = ["ExposureInputs", "key_columns", "read_exposure"]


def _gain(header):
    """Detector gain (e-/ADU): GAIN, else the gain SExtractor used (SEXGAIN); None."""
    for key in ("GAIN", "SEXGAIN"):
        value = header.get(key)
        if isinstance(value, (int, float)) and value > 0:
            return float(value)
    return None


class ExposureInputs(NamedTuple):
    """An exposure as read by :func:`read_exposure`.

    Attributes
    ----------
    image : ndarray of shape (ny, nx) or None
        The image (None for a catalogue of VIGNETs alone).
    weight : ndarray or None
        Its weight map (inverse variance, 0 = bad pixel).
    header : dict-like
        The image's header, else the catalogue's image header (``LDAC_IMHEAD``), else {}.
    catalog : astropy.table.Table or None
        The catalogue (0-based ``x``, ``y``), None without one.
    saturation : float or None
        The saturation level given, else the header's ``SATURATE``, else the level at which
        the catalogue's brightest sources' peaks pile up
        (:func:`~sklearn_psf.exposure.saturation_level`).
    gain : float or None
        ``GAIN`` (else ``SEXGAIN``) of the header, e-/ADU.
    image_path, catalog_path : str or None
        Where they were read from (named in error messages).
    """

    image: object
    weight: object
    header: dict
    catalog: object
    saturation: float | None
    gain: float | None
    image_path: str | None = None
    catalog_path: str | None = None
    #: Where ``saturation`` comes from: "given", "header", "catalogue peaks" (with the
    #: number of sources piled up there) or None.
    saturation_source: str | None = None

    @property
    def has_vignettes(self) -> bool:
        """True when the stamps come from the catalogue's ``VIGNET`` (no image)."""
        return self.image is None and self.catalog is not None and "VIGNET" in [
            c.upper() for c in self.catalog.colnames]

    @property
    def default_stamp_size(self) -> int:
        """The side of the catalogue's VIGNETs, else 25."""
        if self.has_vignettes:
            name = [c for c in self.catalog.colnames if c.upper() == "VIGNET"][0]
            return int(np.shape(self.catalog[name])[1])
        return 25

    @property
    def image_shape(self):
        """(ny, nx) of the image, else of the catalogue's image header, else None."""
        if self.image is not None:
            return self.image.shape
        if "NAXIS2" in self.header and "NAXIS1" in self.header:
            return int(self.header["NAXIS2"]), int(self.header["NAXIS1"])
        return None

    def cut_stamps(self, catalog=None, stamp_size=None):
        """The stars' stamps (:class:`~sklearn_psf.exposure.StarStamps`): the catalogue's VIGNETs
        without an image (cropped to ``stamp_size``), else cut from the image (side 25 by
        default), with the weight map and the saturation level."""
        from ._stars import extract_star_stamps
        from ._vignettes import extract_vignettes

        catalog = self.catalog if catalog is None else catalog
        with _naming(self.catalog_path or self.image_path):
            if self.image is None:
                return extract_vignettes(catalog, stamp_size, saturation=self.saturation,
                                         gain=self.gain)
            return extract_star_stamps(self.image, catalog, stamp_size or 25,
                                       weight=self.weight, saturation=self.saturation)


@contextlib.contextmanager
def _naming(path):
    """Input errors about a file's content name the file (a failure that is not about the
    input goes on as it is: a bug must not pass for the user's fault)."""
    try:
        yield
    except ValueError as exc:
        if path is None or str(path) in str(exc) or not is_input_error(exc):
            raise
        raise InputError(f"{path}: {exc}") from None


def read_exposure(image=None, catalog=None, *, hdu=None, weight_hdu=None,
                  one_based: bool | None = None, x_col: str | None = None,
                  y_col: str | None = None, saturation: float | None = None) -> ExposureInputs:
    """Read an exposure: a FITS image (and its weight map) and/or a source catalogue.

    Parameters
    ----------
    image : str or os.PathLike, optional
        FITS image (:func:`~sklearn_psf.io.read_image`); optional with a catalogue holding
        ``VIGNET`` stamps.
    catalog : str, os.PathLike or astropy.table.Table, optional
        Source catalogue (:func:`~sklearn_psf.io.read_catalog`: FITS_LDAC, FITS table,
        SExtractor ASCII, CSV).
    hdu, weight_hdu : int or str, optional
        The image's HDU and its weight map's HDU.
    one_based, x_col, y_col :
        Position columns and their convention (see :func:`~sklearn_psf.io.read_catalog`).
    saturation : float, optional
        Saturation level; default the header's ``SATURATE``.

    Returns
    -------
    ExposureInputs

    Examples
    --------
    >>> import numpy as np
    >>> from astropy.table import Table
    >>> from sklearn_psf.exposure import read_exposure
    >>> cat = Table({"x": [10.0, 20.0], "y": [5.0, 8.0], "VIGNET": np.zeros((2, 15, 15))})
    >>> inputs = read_exposure(catalog=cat)
    >>> inputs.has_vignettes, inputs.default_stamp_size, inputs.image_shape
    (True, 15, None)
    """
    from ..io import read_catalog, read_image
    from ._select import saturation_level

    if image is None and catalog is None:
        raise InputError("Give an image, or a catalogue with VIGNET stamps.")
    header, data, weight, table = {}, None, None, None
    if image is not None:
        data, weight, header = read_image(image, hdu=hdu, weight_hdu=weight_hdu)
    catalog_path = None if catalog is None or not isinstance(catalog, (str, os.PathLike)) \
        else str(catalog)
    if catalog is not None:
        with _naming(catalog_path):
            table = read_catalog(catalog, one_based=one_based, x_col=x_col, y_col=y_col)
        if data is None:
            header = table.meta.get("image_header") or {}
    source = None if saturation is None else "given"
    if saturation is None and "SATURATE" in header:
        saturation, source = float(header["SATURATE"]), "header"
    if saturation is None and table is not None:
        saturation, piled = saturation_level(table)
        source = None if saturation is None else f"catalogue peaks ({piled} sources)"
    return ExposureInputs(data, weight, header, table, saturation, _gain(header),
                          None if image is None else str(image), catalog_path, source)


def key_columns(catalog, keys, where="the catalogue") -> np.ndarray:
    """The catalogue's columns ``keys`` as the model's extra dimensions, one column each.

    PSFEx's ``PSFVAR_KEYS``: any catalogue quantity (a colour, a magnitude, a flux) as a
    dimension of the model after the positions. Names are matched without regard to case.

    Parameters
    ----------
    catalog : astropy.table.Table
    keys : sequence of str
        Column names.
    where : str
        How error messages name the catalogue.

    Returns
    -------
    ndarray of shape (n, len(keys))
        float64 (NaN where a value is masked or missing).

    Raises
    ------
    InputError
        A key that is not a column (the message lists some that are), or a column that does
        not hold one number per row.

    Examples
    --------
    >>> from astropy.table import Table
    >>> from sklearn_psf.exposure import key_columns
    >>> cat = Table({"x": [1.0, 2.0], "y": [3.0, 4.0], "G_I": [0.5, 1.5]})
    >>> key_columns(cat, ["g_i"]).tolist()
    [[0.5], [1.5]]
    """
    lower = {name.lower(): name for name in catalog.colnames}
    out = np.empty((len(catalog), len(keys)))
    for j, key in enumerate(keys):
        name = lower.get(str(key).lower())
        if name is None:
            some = [c for c in catalog.colnames if np.ndim(catalog[c]) == 1][:12]
            raise InputError(f"{where} has no column {key!r} (a --keys / keys entry); "
                             f"columns include: {', '.join(some)}"
                             + (", ..." if len(catalog.colnames) > len(some) else ""))
        column = catalog[name]
        if np.ndim(column) != 1 or column.dtype.kind not in "biuf":
            raise InputError(f"{where}: column {name!r} (a --keys / keys entry) does not hold "
                             f"one number per row (dtype {column.dtype}, shape "
                             f"{np.shape(column)})")
        values = np.ma.asarray(column).astype(np.float64)
        out[:, j] = np.ma.filled(values, np.nan)
    return out
