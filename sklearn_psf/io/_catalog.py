"""Reading star (or galaxy) position catalogues: FITS tables, SExtractor catalogues, CSV."""

from __future__ import annotations

import os

import numpy as np
from astropy.io import fits
from astropy.table import Table

from ._image import _FileError, _one_line, _tolerant_fits

__all__ = ["read_catalog", "write_ldac"]

# (x, y) column pairs tried in this order; True: the convention is 1-based (FITS/SExtractor).
_POSITION_COLUMNS = (
    ("xwin_image", "ywin_image", True),
    ("x_image", "y_image", True),
    ("x", "y", False),
    ("xcentroid", "ycentroid", False),  # photutils
    ("x_0", "y_0", False),
)
_SKY_COLUMNS = (("alphawin_j2000", "deltawin_j2000"), ("alpha_j2000", "delta_j2000"),
                ("ra", "dec"))
_FLUX_COLUMNS = ("flux", "flux_auto", "flux_psf", "flux_aper")
_SNR_COLUMNS = ("snr", "snr_win", "s/n")
_FLAG_COLUMNS = ("flags", "flag")
# further SExtractor measurements, copied under the lower-case names the star selector reads
_MEASURED_COLUMNS = (("peak", ("peak", "flux_max")), ("flux_radius", ("flux_radius",)),
                     ("class_star", ("class_star",)), ("spread_model", ("spread_model",)),
                     ("background", ("background",)))
_TEXT_SUFFIXES = (".csv", ".txt", ".dat", ".ecsv", ".tsv", ".cat")


def _is_sextractor_ascii(path):
    """SExtractor ASCII_HEAD catalogues start with '#   1 NUMBER ...' column lines."""
    with open(path, "rb") as f:
        head = f.read(80)
    return head.lstrip().startswith(b"#") and b"SIMPLE" not in head[:10]


def _ldac_header(hdul):
    """The image header SExtractor stores in LDAC_IMHEAD, or None.

    SExtractor writes it as one cell of a column ``Field Header Card`` with ``TDIM = (80,
    N)``: N cards that numpy returns without their trailing blanks, each padded back to 80
    characters here (older writers store one string of N x 80 characters).
    """
    if "LDAC_IMHEAD" not in hdul:
        return None
    data = hdul["LDAC_IMHEAD"].data
    if data is None or len(data) == 0:
        return None
    cell = data[0][0]
    if isinstance(cell, (str, bytes)):
        cards = [cell]
    else:
        cards = list(np.asarray(cell).ravel())
    width = 80
    text = "".join((c.decode("ascii", "replace") if isinstance(c, bytes) else str(c))
                   .ljust(width) for c in cards)
    return fits.Header.fromstring(text)


def write_ldac(path, objects: Table, header=None, overwrite: bool = False) -> None:
    """Write a SExtractor FITS_LDAC catalogue (what PSFEx reads).

    HDU 1 ``LDAC_IMHEAD`` holds the image header as SExtractor writes it: one cell of the
    column ``Field Header Card`` with ``TDIM = (80, N)``, the N 80-character cards; HDU 2
    ``LDAC_OBJECTS`` the objects.

    Parameters
    ----------
    path : str or os.PathLike
    objects : astropy.table.Table
        SExtractor columns, e.g. ``X_IMAGE``, ``Y_IMAGE`` (1-based), ``FLUX_RADIUS``,
        ``VIGNET`` (n, v, v).
    header : astropy.io.fits.Header, optional
        Image header (``SATURATE``, WCS...); empty by default.
    overwrite : bool, default=False

    Examples
    --------
    >>> import os, tempfile
    >>> import numpy as np
    >>> from astropy.io import fits
    >>> from astropy.table import Table
    >>> from sklearn_psf.io import read_catalog, write_ldac
    >>> path = os.path.join(tempfile.mkdtemp(), "cat.ldac")
    >>> write_ldac(path, Table({"X_IMAGE": [11.0], "Y_IMAGE": [21.0],
    ...                         "VIGNET": np.zeros((1, 5, 5), np.float32)}),
    ...            header=fits.Header({"SATURATE": 5e4}))
    >>> cat = read_catalog(path)
    >>> cat["x"][0], cat.meta["image_header"]["SATURATE"]
    (np.float64(10.0), 50000.0)
    """
    text = (header or fits.Header()).tostring(endcard=True, padding=False)
    cards = np.array([[text[i:i + 80] for i in range(0, len(text), 80)]])
    head = fits.BinTableHDU.from_columns(
        [fits.Column(name="Field Header Card", format=f"{cards.size * 80}A",
                     dim=f"(80, {cards.size})", array=cards)],
        name="LDAC_IMHEAD")
    objs = fits.table_to_hdu(Table(objects))
    objs.name = "LDAC_OBJECTS"
    fits.HDUList([fits.PrimaryHDU(), head, objs]).writeto(os.fspath(path), overwrite=overwrite)


def _read_table(path, hdu):
    path = os.fspath(path)
    if not os.path.exists(path):
        raise ValueError(f"Catalogue file {path!r} does not exist.")
    lower = path.lower()
    try:
        with _tolerant_fits(path):
            if lower.endswith(_TEXT_SUFFIXES) or _is_sextractor_ascii(path):
                if _is_sextractor_ascii(path):
                    fmt = "ascii.sextractor"
                else:
                    fmt = ("ascii.ecsv" if lower.endswith(".ecsv")
                           else "ascii.csv" if lower.endswith(".csv") else "ascii")
                return Table.read(path, format=fmt)
            with fits.open(path, memmap=False) as hdul:
                if hdu is None:
                    names = [h.name for h in hdul]
                    if "LDAC_OBJECTS" in names:  # SExtractor FITS_LDAC
                        hdu = "LDAC_OBJECTS"
                    else:
                        tables = [i for i, h in enumerate(hdul)
                                  if isinstance(h, (fits.BinTableHDU, fits.TableHDU))]
                        if not tables:
                            raise _FileError(
                                f"{path!r} holds no table HDU: pass a FITS table, a SExtractor "
                                "catalogue or a CSV file with x, y columns."
                            )
                        hdu = tables[0]
                table = Table.read(hdul[hdu])
                header = _ldac_header(hdul)
                if header is not None:
                    table.meta["image_header"] = header
                return table
    except _FileError:
        raise
    except (ValueError, OSError, TypeError, KeyError, IndexError, EOFError,
            fits.VerifyError) as exc:
        raise ValueError(
            f"Could not read the catalogue {path!r} ({type(exc).__name__}: "
            f"{_one_line(exc)}); pass a complete FITS table, a SExtractor catalogue or a CSV "
            "file with x, y columns."
        ) from None


def read_catalog(catalog, *, one_based: bool | None = None, x_col: str | None = None,
                 y_col: str | None = None, hdu=None, sky: bool = False) -> Table:
    """Read a catalogue of positions into a table with 0-based ``x``, ``y`` columns.

    Column names are matched without regard to case. Positions come from, in this order:
    ``x_col``/``y_col`` if given; ``XWIN_IMAGE``/``YWIN_IMAGE`` or ``X_IMAGE``/``Y_IMAGE``
    (SExtractor, **1-based**: the centre of the first pixel is 1.0); ``x``/``y``,
    ``xcentroid``/``ycentroid`` (photutils) or ``x_0``/``y_0`` (**0-based**, the package's
    convention). ``one_based`` overrides the convention of the name: True subtracts 1 from
    both coordinates, False keeps them.

    Optional columns are copied under standard names: ``flux`` (``FLUX``, ``FLUX_AUTO``,
    ``FLUX_PSF``, ``FLUX_APER``), ``snr`` (``SNR``, ``SNR_WIN``, else ``FLUX_AUTO /
    FLUXERR_AUTO``), ``flags`` (``FLAGS``, ``FLAG``; non-zero skips the star when stamps
    are cut), ``peak`` (``FLUX_MAX``), ``flux_radius``, ``class_star``, ``spread_model``,
    ``background`` (read by :func:`select_stars`). Other columns, e.g. ``VIGNET``, are kept
    as they are.

    Files: FITS tables (a FITS_LDAC catalogue's ``LDAC_OBJECTS``, its image header from
    ``LDAC_IMHEAD`` in ``meta["image_header"]``), SExtractor ASCII catalogues (``#   1
    NUMBER`` header lines, any suffix), CSV/ECSV and whitespace-separated text with a header
    line. A non-standard FITS header is read with a :class:`FITSHeaderWarning`.

    Parameters
    ----------
    catalog : str, os.PathLike or astropy.table.Table
        FITS table (first table HDU, or SExtractor's ``LDAC_OBJECTS``), CSV/ECSV/ASCII file,
        or a table.
    one_based : bool, optional
        Whether the positions are 1-based; default from the column names (see above).
    x_col, y_col : str, optional
        Names of the position columns.
    hdu : int or str, optional
        Table HDU of a FITS file.
    sky : bool, default=False
        Read (RA, Dec) in degrees instead, into ``x``, ``y`` as they are: ``x_col``/``y_col``,
        else ``ALPHAWIN_J2000``/``DELTAWIN_J2000``, ``ALPHA_J2000``/``DELTA_J2000`` or
        ``RA``/``DEC``.

    Returns
    -------
    astropy.table.Table
        Columns ``x``, ``y`` (float64, 0-based), then the optional standard columns and the
        others. ``meta``: ``x_column``, ``y_column``, ``one_based``.

    Raises
    ------
    ValueError
        For an unreadable file, or no position columns (the message lists the columns found).

    Examples
    --------
    >>> from astropy.table import Table
    >>> from sklearn_psf.io import read_catalog
    >>> sex = Table({"X_IMAGE": [1.0, 10.5], "Y_IMAGE": [1.0, 20.0], "FLAGS": [0, 2]})
    >>> cat = read_catalog(sex)
    >>> cat["x"].tolist(), cat["y"].tolist(), cat["flags"].tolist()
    ([0.0, 9.5], [0.0, 19.0], [0, 2])
    """
    if isinstance(catalog, Table):
        table = catalog
    else:
        table = _read_table(catalog, hdu)
    lower = {name.lower(): name for name in table.colnames}
    if (x_col is None) != (y_col is None):
        raise ValueError("Give both x_col and y_col, or neither.")
    if x_col is not None:
        missing = [c for c in (x_col, y_col) if c.lower() not in lower]
        if missing:
            raise ValueError(
                f"The catalogue has no column {missing[0]!r}; columns found: "
                f"{', '.join(table.colnames) or 'none'}."
            )
        xname, yname, convention = lower[x_col.lower()], lower[y_col.lower()], False
    elif sky:
        pairs = [(lower[a], lower[d]) for a, d in _SKY_COLUMNS if a in lower and d in lower]
        if not pairs:
            raise ValueError(
                "The catalogue has no (RA, Dec) columns: expected ALPHA_J2000, DELTA_J2000 or "
                f"RA, DEC, or give x_col/y_col; columns found: {', '.join(table.colnames)}.")
        (xname, yname), convention, one_based = pairs[0], False, False
    else:
        for xn, yn, conv in _POSITION_COLUMNS:
            if xn in lower and yn in lower:
                xname, yname, convention = lower[xn], lower[yn], conv
                break
        else:
            raise ValueError(
                "The catalogue has no position columns: expected x, y (0-based) or "
                "X_IMAGE, Y_IMAGE / XWIN_IMAGE, YWIN_IMAGE (SExtractor, 1-based), or give "
                "x_col/y_col (--x-col/--y-col); columns found: "
                f"{', '.join(table.colnames) or 'none'}."
            )
    base = convention if one_based is None else bool(one_based)
    try:
        x = np.asarray(table[xname], dtype=np.float64)
        y = np.asarray(table[yname], dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"Columns {xname!r}, {yname!r} do not hold numbers.") from None
    if x.ndim != 1:
        raise ValueError(f"Column {xname!r} must hold one number per row.")
    out = Table({"x": x - 1.0 if base else x, "y": y - 1.0 if base else y})
    for std, names in (("flux", _FLUX_COLUMNS), ("snr", _SNR_COLUMNS), ("flags", _FLAG_COLUMNS),
                       *_MEASURED_COLUMNS):
        for name in names:
            if name in lower:
                out[std] = np.asarray(table[lower[name]])
                break
    if "snr" not in out.colnames and "flux_auto" in lower and "fluxerr_auto" in lower:
        with np.errstate(divide="ignore", invalid="ignore"):
            out["snr"] = (np.asarray(table[lower["flux_auto"]], dtype=np.float64)
                          / np.asarray(table[lower["fluxerr_auto"]], dtype=np.float64))
    for name in table.colnames:
        if name not in (xname, yname) and name.lower() not in out.colnames \
                and name not in out.colnames:
            out[name] = table[name]
    out.meta.update({"x_column": xname, "y_column": yname, "one_based": base})
    if "image_header" in table.meta:
        out.meta["image_header"] = table.meta["image_header"]
    return out
