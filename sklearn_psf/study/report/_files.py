"""Result tables written to disk (CSV, FITS, JSON), atomically."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from astropy.io import fits
from astropy.table import Table

from ..._files import write_atomic


def _atomic(path: Path, write):
    """``write(tmp)`` to a temporary path, renamed onto ``path`` once complete, with the
    permissions of the user's umask (:func:`sklearn_psf._files.write_atomic`)."""
    return write_atomic(path, write)


#: Units of the result tables' dimensional columns (FITS TUNIT; the rest are dimensionless).
UNITS = {"x": "pix", "y": "pix", "fit_seconds": "s", "local_density": "count"}


def _plain(table):
    """A shallow copy without metadata, with the units of :data:`UNITS`."""
    out = table.copy(copy_data=False)
    out.meta.clear()
    for name, unit in UNITS.items():
        if name in out.colnames:
            out[name].unit = unit
    return out


def _write_table(table, path, fmt):
    return _atomic(path, lambda tmp: _plain(table).write(tmp, format=fmt, overwrite=True))


def _write_correlations(correlations, theta, path):
    def write(tmp):
        hdus = [fits.PrimaryHDU(), fits.table_to_hdu(_plain(correlations))]
        hdus[1].name = "CORRELATIONS"
        if theta is not None:
            theta_hdu = fits.table_to_hdu(Table({"theta": np.asarray(theta, float)}))
            theta_hdu.name = "THETA"
            theta_hdu.header["TUNIT1"] = "arcmin"
            hdus.append(theta_hdu)
        fits.HDUList(hdus).writeto(tmp, overwrite=True)

    return _atomic(path, write)


def _jsonable(value):
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, (str, int, float, bool)) or value is None:
        return value
    return repr(value)
