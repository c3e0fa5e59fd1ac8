"""Reading star (or galaxy) position catalogues: FITS tables, SExtractor catalogues, CSV."""

from __future__ import annotations

import os
import warnings

import numpy as np
from astropy.io import fits
from astropy.table import Table

from .._files import InputError
from ._image import _checked_header, _FileError, _is_fits, _one_line, _tolerant_fits

__all__ = ["read_catalog", "write_catalog_rows", "write_ldac", "CatalogColumnWarning"]


class CatalogColumnWarning(UserWarning):
    """A catalogue column cannot be used (e.g. ``FLUX_RADIUS`` 0 in every row) and is left
    out; the catalogue is read without it."""

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
#: SExtractor's vector columns read as one number, as PSFEx reads them (``PHOTFLUX_KEY
#: FLUX_APER(1)``): the element of the ``aperture`` (``PHOT_APERTURES``) or of the
#: ``flux_fraction`` (``PHOT_FLUXFRAC``) chosen, 1-based.
_APERTURE_COLUMNS = ("flux_aper", "fluxerr_aper", "mag_aper", "magerr_aper")
_FRACTION_COLUMNS = ("flux_radius",)


def _ascii_vectors(table):
    """SExtractor ASCII_HEAD catalogues give a vector column ``NAME(k)`` as k columns
    ``NAME``, ``NAME_1`` ... ``NAME_{k-1}`` (astropy's reader): stacked back into one column,
    ``VIGNET(v, v)`` into shape (n, v, v)."""
    names = table.colnames
    out, i = Table(meta=table.meta), 0
    while i < len(names):
        name, k = names[i], 1
        while i + k < len(names) and names[i + k] == f"{name}_{k}":
            k += 1
        if k == 1:
            out[name] = table[name]
        else:
            cube = np.column_stack([np.asarray(table[c]) for c in names[i:i + k]])
            side = int(round(np.sqrt(k)))
            if name.upper() == "VIGNET" and side * side == k:
                cube = cube.reshape(len(table), side, side)
            out[name] = cube
        i += k
    return out


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
    column ``Field Header Card`` with ``TDIM = (80, N)``, the N 80-character cards padded with
    blanks; HDU 2 ``LDAC_OBJECTS`` the objects. PSFEx reads the file.

    Parameters
    ----------
    path : str or os.PathLike
    objects : astropy.table.Table
        SExtractor columns, e.g. ``X_IMAGE``, ``Y_IMAGE`` (1-based), ``FLUX_RADIUS``,
        ``VIGNET`` (n, v, v).
    header : astropy.io.fits.Header, optional
        Image header (``SATURATE``, WCS, ``NAXIS1``/``NAXIS2``...), written after the
        ``SIMPLE``, ``BITPIX``, ``NAXIS`` cards an image header begins with.
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
    header = fits.Header() if header is None else header
    shape = [header.get(k) for k in ("NAXIS1", "NAXIS2")]
    shape = shape if all(isinstance(v, (int, np.integer)) for v in shape) else []
    # an image header begins as SExtractor's does (PSFEx refuses one without SIMPLE)
    full = fits.Header([("SIMPLE", True), ("BITPIX", header.get("BITPIX", -32)),
                        ("NAXIS", len(shape))]
                       + [(f"NAXIS{i + 1}", v) for i, v in enumerate(shape)])
    full.extend(c for c in header.cards if c.keyword not in full and c.keyword != "END")
    text = full.tostring(endcard=True, padding=False)
    # one string of N x 80 characters, blank-padded as SExtractor writes it (PSFEx 3.21
    # crashes on cards padded with NUL bytes, which a column of N shorter strings gets)
    head = fits.BinTableHDU.from_columns(
        [fits.Column(name="Field Header Card", format=f"{len(text)}A",
                     array=np.array([text.encode("ascii")]))], name="LDAC_IMHEAD")
    head.header.set("TDIM1", f"(80, {len(text) // 80})", after="TFORM1")
    objs = fits.table_to_hdu(Table(objects))
    objs.name = "LDAC_OBJECTS"
    path = os.fspath(path)
    fits.HDUList([fits.PrimaryHDU(), head, objs]).writeto(path, overwrite=overwrite)
    # astropy ends the cell with NUL bytes in place of the last card's blanks: blanks back
    with fits.open(path) as hdul:
        start = hdul.fileinfo(1)["datLoc"]
    with open(path, "r+b") as f:
        f.seek(start)
        f.write(text.encode("ascii"))


def write_catalog_rows(path, out, rows, *, invert: bool = False,
                       overwrite: bool = False) -> None:
    """Write a copy of a FITS catalogue holding only some of its sources.

    For a SExtractor FITS_LDAC file the ``LDAC_OBJECTS`` table is cut and every other HDU
    (the image header of ``LDAC_IMHEAD`` byte for byte, as PSFEx needs it) is kept; for a
    FITS table, its first table HDU is cut. What PSFEx or this package then reads is the
    same catalogue without the other sources (e.g. the reserved stars of a fit, or a
    cross-validation fold's training stars).

    Parameters
    ----------
    path : str or os.PathLike
        A FITS_LDAC or FITS table catalogue.
    out : str or os.PathLike
        The copy to write.
    rows : array-like of bool of shape (n,), or of int
        The sources to keep (a mask over the catalogue's rows, or their 0-based indices).
    invert : bool, default=False
        Keep every source but ``rows``.
    overwrite : bool, default=False

    Raises
    ------
    InputError
        A file that is not a FITS catalogue.

    Examples
    --------
    >>> import os, tempfile
    >>> import numpy as np
    >>> from astropy.table import Table
    >>> from sklearn_psf.io import read_catalog, write_catalog_rows, write_ldac
    >>> folder = tempfile.mkdtemp()
    >>> write_ldac(os.path.join(folder, "all.ldac"),
    ...            Table({"X_IMAGE": [11.0, 20.0, 30.0], "Y_IMAGE": [21.0, 5.0, 9.0]}))
    >>> write_catalog_rows(os.path.join(folder, "all.ldac"), os.path.join(folder, "two.ldac"),
    ...                    [0, 2])
    >>> read_catalog(os.path.join(folder, "two.ldac"))["x"].tolist()
    [10.0, 29.0]
    """
    from .._files import InputError

    path, out = os.fspath(path), os.fspath(out)
    try:
        hdul = fits.open(path)
    except OSError as exc:
        raise InputError(f"{path} is not a FITS catalogue ({exc})") from None
    with hdul:
        names = [h.name for h in hdul]
        target = "LDAC_OBJECTS" if "LDAC_OBJECTS" in names else next(
            (h.name for h in hdul if isinstance(h, fits.BinTableHDU)), None)
        if target is None:
            raise InputError(f"{path} holds no FITS table to cut")
        hdus = [h.copy() for h in hdul]
        heads = {i: (hdul.fileinfo(i)["datLoc"], hdul.fileinfo(i)["datSpan"])
                 for i, name in enumerate(names) if name == "LDAC_IMHEAD"}
    i = names.index(target)
    data = hdus[i].data
    keep = np.asarray(rows)
    if keep.dtype != bool:
        keep = np.isin(np.arange(len(data)), keep)
    if invert:
        keep = ~keep
    hdus[i] = fits.BinTableHDU(data[keep], header=hdus[i].header, name=target)
    fits.HDUList(hdus).writeto(out, overwrite=overwrite)
    # the image header's cell byte for byte (astropy pads it with NUL bytes, which PSFEx
    # 3.21 crashes on)
    with fits.open(out) as written:
        starts = {j: written.fileinfo(j)["datLoc"] for j in heads}
    with open(path, "rb") as src, open(out, "r+b") as dst:
        for j, (loc, span) in heads.items():
            src.seek(loc)
            dst.seek(starts[j])
            dst.write(src.read(span))


def _read_table(path, hdu):
    path = os.fspath(path)
    if not os.path.exists(path):
        raise _FileError(f"Catalogue file {path!r} does not exist.")
    lower = path.lower()
    try:
        with _tolerant_fits(path):
            if not _is_fits(path) and (lower.endswith(_TEXT_SUFFIXES)
                                       or _is_sextractor_ascii(path)):
                if _is_sextractor_ascii(path):
                    return _ascii_vectors(Table.read(path, format="ascii.sextractor"))
                fmt = ("ascii.ecsv" if lower.endswith(".ecsv")
                       else "ascii.csv" if lower.endswith(".csv") else "ascii")
                return Table.read(path, format=fmt)
            with fits.open(path, memmap=False, lazy_load_hdus=False, checksum=True) as hdul:
                if hdu is None:
                    names = [h.name for h in hdul]
                    if "LDAC_OBJECTS" in names:  # SExtractor FITS_LDAC
                        hdu = "LDAC_OBJECTS"
                    elif "LDAC_IMHEAD" in names:
                        raise _FileError(
                            f"Could not read {path!r}: a truncated or corrupt FITS_LDAC file (an "
                            "LDAC_IMHEAD but no LDAC_OBJECTS table; HDUs: "
                            f"{', '.join(n or '-' for n in names)}).")
                    else:
                        tables = [i for i, h in enumerate(hdul)
                                  if isinstance(h, (fits.BinTableHDU, fits.TableHDU))]
                        if not tables:
                            raise _FileError(
                                f"{path!r} holds no table HDU: pass a FITS table, a SExtractor "
                                "catalogue or a CSV file with x, y columns."
                            )
                        hdu = tables[0]
                if not isinstance(hdul[hdu], (fits.BinTableHDU, fits.TableHDU)):
                    raise _FileError(f"{path!r}: HDU {hdu} ({hdul[hdu].name or 'unnamed'}) is "
                                     "not a table.")
                table = Table.read(hdul[hdu])
                header = _ldac_header(hdul)
                if header is not None:
                    table.meta["image_header"] = _checked_header(header, path)
                return table
    except _FileError:
        raise
    except (ValueError, OSError, TypeError, KeyError, IndexError, EOFError,
            UnicodeDecodeError, fits.VerifyError) as exc:
        raise _FileError(
            f"Could not read the catalogue {path!r} ({type(exc).__name__}: "
            f"{_one_line(exc)[:200]}); pass a complete FITS table (not a truncated or corrupt "
            "FITS file), a SExtractor catalogue or a CSV file with x, y columns."
        ) from None


def read_catalog(catalog, *, one_based: bool | None = None, x_col: str | None = None,
                 y_col: str | None = None, hdu=None, sky: bool = False, aperture: int = 1,
                 flux_fraction: int = 1) -> Table:
    """Read a catalogue of positions into a table with 0-based ``x``, ``y`` columns.

    Column names are matched without regard to case. Positions come from ``x_col``/``y_col``
    if given, else SExtractor's ``XWIN_IMAGE``/``YWIN_IMAGE`` or ``X_IMAGE``/``Y_IMAGE``
    (**1-based**), else ``x``/``y``, ``xcentroid``/``ycentroid`` or ``x_0``/``y_0``
    (**0-based**). Optional columns are copied under standard names (``flux``, ``snr``,
    ``flags``, ``peak``, ``flux_radius``, ``class_star``, ``spread_model``, ``background``),
    SExtractor's vector aperture columns reduced to one element as PSFEx reads them; other
    columns are kept. Files: FITS tables (FITS_LDAC included), SExtractor ASCII catalogues,
    CSV/ECSV and whitespace-separated text. Which column feeds which name, the S/N without
    an ``SNR`` column and the vector columns: :ref:`catalogue-columns`.

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
    aperture : int, default=1
        Element (1-based, in the order of SExtractor's ``PHOT_APERTURES``) of the vector
        aperture columns to read.
    flux_fraction : int, default=1
        Element (1-based, in the order of ``PHOT_FLUXFRAC``) of a vector ``FLUX_RADIUS``.

    Returns
    -------
    astropy.table.Table
        Columns ``x``, ``y`` (float64, 0-based), then the optional standard columns and the
        others. ``meta``: ``x_column``, ``y_column``, ``one_based``, ``vector_elements``
        (``{column: element}`` of the vector columns reduced, if any), ``image_header`` (a
        FITS_LDAC catalogue's).

    Raises
    ------
    InputError
        For an unreadable, truncated or corrupt file (a FITS file's ``CHECKSUM``/``DATASUM``
        are verified where present), no rows, no position columns (the message lists the
        columns found), a column that does not hold one number per row, or an ``aperture`` /
        ``flux_fraction`` beyond the vector's size.

    Warns
    -----
    CatalogColumnWarning
        When ``FLUX_RADIUS`` holds no positive value (left out).
    FITSHeaderWarning
        When a FITS header is not standard (it is read all the same).

    Examples
    --------
    >>> from astropy.table import Table
    >>> from sklearn_psf.io import read_catalog
    >>> sex = Table({"X_IMAGE": [1.0, 10.5], "Y_IMAGE": [1.0, 20.0], "FLAGS": [0, 2]})
    >>> cat = read_catalog(sex)
    >>> cat["x"].tolist(), cat["y"].tolist(), cat["flags"].tolist()
    ([0.0, 9.5], [0.0, 19.0], [0, 2])
    >>> aper = Table({"X_IMAGE": [5.0], "Y_IMAGE": [7.0],      # 3 PHOT_APERTURES
    ...               "FLUX_APER": [[100.0, 150.0, 180.0]], "FLUXERR_APER": [[5.0, 6.0, 9.0]]})
    >>> cat = read_catalog(aper)
    >>> float(cat["flux"][0]), float(cat["snr"][0]), cat.meta["vector_elements"]["FLUX_APER"]
    ... # flux: FLUX_APER(1), as PSFEx; S/N: the best of the apertures, 150 / 6
    (100.0, 25.0, 1)
    >>> float(read_catalog(aper, aperture=3)["flux"][0])
    180.0
    """
    if isinstance(catalog, Table):
        table = catalog
        where = "The catalogue"
    else:
        table = _read_table(catalog, hdu)
        where = f"The catalogue {os.fspath(catalog)!r}"
    lower = {name.lower(): name for name in table.colnames}
    if (x_col is None) != (y_col is None):
        raise InputError("Give both x_col and y_col, or neither.")
    if x_col is not None:
        missing = [c for c in (x_col, y_col) if c.lower() not in lower]
        if missing:
            raise InputError(
                f"{where} has no column {missing[0]!r}; columns found: "
                f"{', '.join(table.colnames) or 'none'}."
            )
        xname, yname, convention = lower[x_col.lower()], lower[y_col.lower()], False
    elif sky:
        pairs = [(lower[a], lower[d]) for a, d in _SKY_COLUMNS if a in lower and d in lower]
        if not pairs:
            raise InputError(
                f"{where} has no (RA, Dec) columns: expected ALPHA_J2000, DELTA_J2000 or "
                f"RA, DEC, or give x_col/y_col; columns found: {', '.join(table.colnames)}.")
        (xname, yname), convention, one_based = pairs[0], False, False
    else:
        for xn, yn, conv in _POSITION_COLUMNS:
            if xn in lower and yn in lower:
                xname, yname, convention = lower[xn], lower[yn], conv
                break
        else:
            radec = [f"{lower[a]}, {lower[d]}" for a, d in _SKY_COLUMNS
                     if a in lower and d in lower]
            hint = (f"; its (RA, Dec) columns {radec[0]} are read with sky=True (predict "
                    "--radec, with the WCS of the model's image)" if radec else "")
            raise InputError(
                f"{where} has no position columns: expected x, y (0-based) or "
                "X_IMAGE, Y_IMAGE / XWIN_IMAGE, YWIN_IMAGE (SExtractor, 1-based), or give "
                "x_col/y_col (--x-col/--y-col); columns found: "
                f"{', '.join(table.colnames) or 'none'}{hint}."
            )
    if len(table) == 0:
        raise InputError(f"{where} has no rows (columns: {', '.join(table.colnames[:8])}"
                         f"{', ...' if len(table.colnames) > 8 else ''}).")
    base = convention if one_based is None else bool(one_based)
    x, y = (_numbers(table[name], name, where) for name in (xname, yname))
    columns, elements = _scalar_columns(table, lower, aperture, flux_fraction, where)
    out = Table({"x": x - 1.0 if base else x, "y": y - 1.0 if base else y})
    for std, names in (("flux", _FLUX_COLUMNS), ("snr", _SNR_COLUMNS), ("flags", _FLAG_COLUMNS),
                       *_MEASURED_COLUMNS):
        for name in names:
            if name in columns:
                out[std] = _numbers(columns[name], lower[name], where,
                                    integer=std == "flags")
                break
    if "snr" not in out.colnames:  # the best of the fluxes' S/N: closest to SNR_WIN's
        ratios = _flux_snr(table, lower, where)
        if ratios:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN rows stay NaN
                out["snr"] = np.nanmax(np.hstack(ratios), axis=1)
            out.meta["snr_from_fluxes"] = True  # (select_stars prefers the VIGNETs' window)
    dropped = set()
    if "flux_radius" in out.colnames and not (np.asarray(out["flux_radius"]) > 0).any():
        warnings.warn(
            f"{where}: {lower['flux_radius']} is 0, negative or NaN in all {len(out)} rows: "
            "left out, the star selection measures the sizes on the VIGNETs (adaptive "
            "moments) if there are any, else applies no size-magnitude cut.",
            CatalogColumnWarning, stacklevel=2)
        del out["flux_radius"]
        dropped.add(lower["flux_radius"])
    for name in table.colnames:
        if name not in (xname, yname) and name not in dropped \
                and name.lower() not in out.colnames and name not in out.colnames:
            out[name] = columns.get(name.lower(), table[name])
    out.meta.update({"x_column": xname, "y_column": yname, "one_based": base})
    if elements:
        out.meta["vector_elements"] = elements
    if "image_header" in table.meta:
        out.meta["image_header"] = table.meta["image_header"]
    return out


#: (value, error, kind) column pairs giving a S/N without SNR/SNR_WIN: fluxes (S/N = flux /
#: error) and magnitudes (S/N = 2.5 / ln 10 / error, as SExtractor derives MAGERR).
_SNR_PAIRS = (("flux_auto", "fluxerr_auto", "flux"), ("flux_aper", "fluxerr_aper", "flux"),
              ("mag_auto", "magerr_auto", "mag"), ("mag_aper", "magerr_aper", "mag"))


def _flux_snr(table, lower, where):
    """Each S/N the catalogue's fluxes or magnitudes give (arrays (n, k), one column per
    aperture), in :data:`_SNR_PAIRS` order."""
    ratios = []
    for value, err, kind in _SNR_PAIRS:
        if value in lower and err in lower:
            try:
                v, e = (np.ma.filled(np.ma.asarray(table[lower[c]]).astype(np.float64),
                                     np.nan).reshape(len(table), -1) for c in (value, err))
            except (TypeError, ValueError):
                raise InputError(f"{where}: column {lower[value]!r} or {lower[err]!r} does "
                                 "not hold numbers.") from None
            if v.shape == e.shape:
                with np.errstate(divide="ignore", invalid="ignore"):
                    snr = v / e if kind == "flux" else 2.5 / np.log(10.0) / e
                    # (SExtractor writes 99 for the magnitudes it could not measure)
                    bad = ~(e > 0) | ((kind == "mag") & ~(np.abs(v) < 90))
                ratios.append(np.where(bad, np.nan, snr))
    return ratios


def _numbers(column, name, where, integer=False):
    """A catalogue column as float64 (int64 for ``integer``), one number per row; masked
    entries (ASCII catalogues) become NaN (-1, every flag bit, for ``integer``)."""
    col = np.ma.asarray(column)
    if col.ndim != 1:
        raise InputError(f"{where}: column {name!r} must hold one number per row, got "
                         f"shape {col.shape[1:]} per row.")
    try:
        values = col.astype(np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{where}: column {name!r} does not hold numbers "
                         f"(type {col.dtype}).") from None
    if integer:
        finite = np.ma.filled(values, np.nan)
        ok = np.isfinite(finite)
        return np.where(ok, np.nan_to_num(finite), -1).astype(np.int64)
    return np.ma.filled(values, np.nan)


def _scalar_columns(table, lower, aperture, flux_fraction, where):
    """``{lower-case name: column}`` with SExtractor's vector photometry reduced to one
    element (see ``_APERTURE_COLUMNS``), and ``{name: element}`` of the reduced ones."""
    columns, elements = {}, {}
    for key, name in lower.items():
        col = table[name]
        choice = (("aperture", aperture) if key in _APERTURE_COLUMNS
                  else ("flux_fraction", flux_fraction) if key in _FRACTION_COLUMNS else None)
        if choice is not None and np.ndim(col) == 2:
            option, k = choice
            size = np.shape(col)[1]
            if not (isinstance(k, (int, np.integer)) and 1 <= k <= size):
                raise InputError(f"{where}: {option}={k!r} chooses element {k!r} of {name}, "
                                 f"which has {size} (1 to {size}).")
            col = np.asarray(col)[:, k - 1]
            elements[name] = int(k)
        columns[key] = col
    return columns, elements
