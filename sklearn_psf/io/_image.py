"""Reading FITS images (plain or tile-compressed) with their weight/mask plane."""

from __future__ import annotations

import contextlib
import os
import warnings

import numpy as np
from astropy.io import fits
from astropy.utils.exceptions import AstropyUserWarning

from .._files import InputError
from .._files import one_line as _one_line

__all__ = ["read_image", "FITSHeaderWarning"]

_READ_ERRORS = (OSError, TypeError, KeyError, IndexError, ValueError, EOFError,
                fits.VerifyError)


class FITSHeaderWarning(UserWarning):
    """A FITS header breaks the standard (e.g. ESO's ``ESO-LOG`` cards); it was read as is."""


@contextlib.contextmanager
def _tolerant_fits(path):
    """Read FITS under this: a truncated or corrupt file raises (an HDU cut short, or whose
    ``CHECKSUM``/``DATASUM`` keywords do not match it: open with ``checksum=True``), a
    non-standard header only warns once.

    astropy reports all of these as warnings; header problems never stop the reading (real
    instruments write non-standard keywords), truncation and corruption do.
    """
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        yield
    header_notes = []
    for w in caught:
        text = _one_line(w.message)
        if issubclass(w.category, AstropyUserWarning):
            if "truncated" in text or "file is corrupted" in text:
                raise _FileError(f"Could not read {path!r}: a truncated or corrupt FITS file "
                                 f"({text[:160]}).")
            if "sum verification failed" in text:  # CHECKSUM / DATASUM of an HDU
                raise _FileError(f"Could not read {path!r}: a corrupt FITS file "
                                 f"({text.rstrip('.')}: its CHECKSUM/DATASUM keywords do not "
                                 "match its content).")
            if "zero-based indexing" not in text and "Verification reported" not in text:
                header_notes.append(text)
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    if header_notes:
        warnings.warn(f"{path!r} has a non-standard FITS header, read as it is "
                      f"({len(header_notes)} note(s), first: {header_notes[0][:160]})",
                      FITSHeaderWarning, stacklevel=3)


class _FileError(InputError):
    """A clear message about the file's content (re-raised as it is)."""


def _level(value, name):
    """A saturation level (or gain) as a float, None for None; an :class:`InputError` for
    anything else than a positive number."""
    if value is None:
        return None
    try:
        level = float(value)
    except (TypeError, ValueError):
        level = np.nan
    if not level > 0:
        raise InputError(f"{name} must be a positive number, got {value!r}.")
    return level


def _checked_header(header, path):
    """``header`` without a ``SATURATE`` that is not a positive number (warned): the image is
    read, with no saturation level from its header."""
    value = header.get("SATURATE")
    if value is not None and not (isinstance(value, (int, float)) and not isinstance(value, bool)
                                  and value > 0):
        warnings.warn(f"{path!r}: the header's SATURATE = {value!r} is not a positive number: "
                      "ignored (give the level with saturation=, --saturation)",
                      FITSHeaderWarning, stacklevel=3)
        del header["SATURATE"]
    return header


def _is_fits(path) -> bool:
    """Whether ``path`` is an uncompressed FITS file; one whose size is not a whole number of
    2880-byte FITS blocks is cut short (or corrupt), and refused."""
    with open(path, "rb") as f:
        if f.read(9) != b"SIMPLE  =":
            return False
    size = os.path.getsize(path)
    if size % 2880:
        raise _FileError(f"Could not read {path!r}: a truncated or corrupt FITS file (its "
                         f"{size} bytes are not a whole number of 2880-byte FITS blocks).")
    return True


def _hdu_key(hdu):
    """An HDU index (int, or a string of digits) or an EXTNAME (str)."""
    if hdu is None or isinstance(hdu, (int, np.integer)):
        return hdu
    if isinstance(hdu, str):
        text = hdu.strip()
        return int(text) if text.lstrip("-").isdigit() else text
    raise TypeError(f"hdu must be an index or an EXTNAME, got {type(hdu).__name__}.")


def _describe(hdul):
    return ", ".join(f"{i}:{h.name or '-'}({type(h).__name__})" for i, h in enumerate(hdul))


def _select(hdul, key, path, what):
    if key is None:
        for h in hdul:
            if h.is_image and h.data is not None and np.ndim(h.data) == 2:
                return h
        hint = ("; it is a SExtractor FITS_LDAC catalogue: give it as the star catalogue "
                "(fit --stars CATALOG, with its VIGNET stamps no image is needed)"
                if any(h.name == "LDAC_OBJECTS" for h in hdul) else "")
        raise _FileError(f"{path!r} holds no 2-D image HDU (HDUs: {_describe(hdul)}){hint}.")
    try:
        h = hdul[key]
    except (KeyError, IndexError):
        raise _FileError(
            f"{path!r} has no HDU {key!r} for the {what} (HDUs: {_describe(hdul)})."
        ) from None
    if not h.is_image or h.data is None or np.ndim(h.data) != 2:
        raise _FileError(
            f"HDU {key!r} of {path!r} ({what}) is not a 2-D image (HDUs: {_describe(hdul)})."
        )
    return h


def read_image(path, hdu=None, weight_hdu=None):
    """Read a 2-D image, and optionally its weight map, from a FITS file.

    Tile-compressed images (``.fits.fz``, astropy ``CompImageHDU``) are read like plain ones.

    Parameters
    ----------
    path : str or os.PathLike
        FITS file.
    hdu : int or str, optional
        Image HDU: index (0 = primary) or EXTNAME (e.g. ``"SCI"``); a string of digits is
        an index. Default: the first HDU holding a 2-D image.
    weight_hdu : int or str, optional
        HDU of the weight (inverse variance) or mask map, same shape as the image; zero
        means a bad pixel. Default: no weight map.

    Returns
    -------
    image : ndarray of shape (ny, nx), float64
    weight : ndarray of shape (ny, nx), float64, or None
    header : astropy.io.fits.Header
        Header of the image HDU (for a compressed HDU, the image header). Keywords of the
        primary header (e.g. ``SATURATE`` on DECam/HSC files) that are absent from it are
        copied in.

    Raises
    ------
    InputError
        For a missing, corrupt or truncated file (also one whose ``CHECKSUM``/``DATASUM``
        keywords do not match its content), an unknown HDU, an HDU that is not a 2-D image, or
        a weight map of another shape.

    Warns
    -----
    FITSHeaderWarning
        When a header breaks the FITS standard (non-standard keywords, malformed values): the
        file is read as it is.

    Examples
    --------
    >>> import os, tempfile
    >>> import numpy as np
    >>> from astropy.io import fits
    >>> from sklearn_psf.io import read_image
    >>> path = os.path.join(tempfile.mkdtemp(), "ccd.fits.fz")
    >>> fits.HDUList([fits.PrimaryHDU(),
    ...               fits.CompImageHDU(np.ones((20, 30), np.float32), name="SCI"),
    ...               fits.ImageHDU(np.ones((20, 30)), name="WGT")]).writeto(path)
    >>> image, weight, header = read_image(path, hdu="SCI", weight_hdu=2)
    >>> image.shape, weight.shape
    ((20, 30), (20, 30))
    """
    path = os.fspath(path)
    if not os.path.exists(path):
        raise _FileError(f"FITS file {path!r} does not exist.")
    key, wkey = _hdu_key(hdu), _hdu_key(weight_hdu)
    _is_fits(path)
    try:
        with _tolerant_fits(path):
            # every header is read: a truncated file fails here, whichever HDU is asked for
            with fits.open(path, memmap=False, lazy_load_hdus=False, checksum=True) as hdul:
                chosen = _select(hdul, key, path, "image")
                image = np.array(chosen.data, dtype=np.float64)
                header = chosen.header.copy()
                primary = hdul[0].header
                for card in primary.cards:
                    if card.keyword not in header and card.keyword not in (
                            "SIMPLE", "BITPIX", "NAXIS", "EXTEND", "COMMENT", "HISTORY", ""):
                        header[card.keyword] = (card.value, card.comment)
                weight = None
                if wkey is not None:
                    weight = np.array(_select(hdul, wkey, path, "weight map").data,
                                      dtype=np.float64)
    except _FileError:
        raise
    except _READ_ERRORS as exc:
        raise _FileError(
            f"Could not read {path!r} as a FITS image ({type(exc).__name__}: {_one_line(exc)}); "
            "it is not FITS, or a truncated or corrupt FITS file."
        ) from None
    header = _checked_header(header, path)
    if weight is not None and weight.shape != image.shape:
        raise _FileError(
            f"The weight map (HDU {weight_hdu!r}) has shape {weight.shape}, the image "
            f"{image.shape}: give the weight HDU that belongs to the image."
        )
    return image, weight, header
