"""Sky coordinates: the image's celestial WCS, (RA, Dec) <-> 0-based pixel positions.

Ellipticity correlations (xi+, rho1-rho5) are unchanged by a uniform rotation or reflection of
every ellipticity, so on one CCD the pixel-frame ellipticities are used as they are with
angular separations from the WCS.
"""

from __future__ import annotations

import warnings

import numpy as np

__all__ = ["celestial_wcs", "pixel_to_sky", "sky_to_pixel"]


def celestial_wcs(header):
    """The 2-D celestial WCS of a FITS header, or None when it has none.

    Parameters
    ----------
    header : astropy.io.fits.Header, dict or str
        Image header (e.g. from :func:`read_image`, or ``meta["image_header"]`` of an LDAC
        catalogue), or its text (``Header.tostring()``).

    Returns
    -------
    astropy.wcs.WCS or None

    Examples
    --------
    >>> from sklearn_psf.io import celestial_wcs
    >>> celestial_wcs({"NAXIS": 2}) is None
    True
    >>> w = celestial_wcs({"CTYPE1": "RA---TAN", "CTYPE2": "DEC--TAN", "CRVAL1": 150.0,
    ...                    "CRVAL2": 2.0, "CRPIX1": 1.0, "CRPIX2": 1.0,
    ...                    "CD1_1": -5e-5, "CD2_2": 5e-5})
    >>> w.has_celestial
    True
    """
    from astropy.io import fits
    from astropy.utils.exceptions import AstropyWarning
    from astropy.wcs import WCS

    if header is None:
        return None
    if isinstance(header, str):
        header = fits.Header.fromstring(header)
    elif not isinstance(header, fits.Header):
        header = fits.Header(dict(header))
    with warnings.catch_warnings():
        # WCS fixes and non-standard cards (reported once, when the file was read)
        warnings.simplefilter("ignore", AstropyWarning)
        try:
            wcs = WCS(header, naxis=2)
        except Exception:  # astropy raises many types for broken WCS keywords
            return None
    return wcs.celestial if wcs.has_celestial else None


def pixel_to_sky(wcs, X) -> np.ndarray:
    """(RA, Dec) in degrees of 0-based (x, y) pixel positions.

    Examples
    --------
    >>> from sklearn_psf.io import celestial_wcs, pixel_to_sky, sky_to_pixel
    >>> w = celestial_wcs({"CTYPE1": "RA---TAN", "CTYPE2": "DEC--TAN", "CRVAL1": 150.0,
    ...                    "CRVAL2": 2.0, "CRPIX1": 1.0, "CRPIX2": 1.0,
    ...                    "CD1_1": -5e-5, "CD2_2": 5e-5})
    >>> radec = pixel_to_sky(w, [[0.0, 0.0], [100.0, 50.0]])
    >>> radec[0].tolist()
    [150.0, 2.0]
    >>> sky_to_pixel(w, radec).round(6).tolist()
    [[0.0, 0.0], [100.0, 50.0]]
    """
    X = np.asarray(X, dtype=np.float64)
    return np.column_stack(wcs.all_pix2world(X[:, 0], X[:, 1], 0))


def sky_to_pixel(wcs, radec) -> np.ndarray:
    """0-based (x, y) pixel positions of (RA, Dec) in degrees (see :func:`pixel_to_sky`)."""
    radec = np.asarray(radec, dtype=np.float64)
    return np.column_stack(wcs.all_world2pix(radec[:, 0], radec[:, 1], 0))
