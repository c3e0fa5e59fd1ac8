"""Embedded data of sklearn_psf."""

from __future__ import annotations

import os

from ..simulate import ReferenceBasis

__all__ = ["load_default_reference", "default_reference_path"]

_DATA = os.path.join(os.path.dirname(__file__), "data")


def default_reference_path() -> str:
    """Path of the FITS file of the default reference basis shipped with the package.

    Returns
    -------
    str

    Examples
    --------
    >>> from sklearn_psf.datasets import default_reference_path
    >>> default_reference_path().endswith("default_reference.fits")
    True
    """
    return os.path.join(_DATA, "default_reference.fits")


def load_default_reference() -> ReferenceBasis:
    """Load the default reference basis (ground-based-like PSF at 0.2 arcsec/pixel).

    The basis is the PCA (90% of the variance) of 25 x 25 pixel stamps of the stars of a GalSim
    image: Kolmogorov atmosphere (FWHM 0.7 arcsec) with a small shear, convolved with an
    optical PSF whose defocus, astigmatism and coma vary smoothly over the field, extracted
    with :meth:`ReferenceBasis.from_image`. It was tuned so that the default simulation has
    PSF ellipticities of mean |e| ~ 0.05 and spread ~ 0.02 (Berge et al. 2012). How it was
    made, and the script that regenerates it: :mod:`sklearn_psf.datasets._make_default_reference`.

    Returns
    -------
    ReferenceBasis

    Examples
    --------
    >>> from sklearn_psf.datasets import load_default_reference
    >>> ref = load_default_reference()
    >>> ref.stamp_size, ref.pixel_scale
    (25, 0.2)
    """
    return ReferenceBasis.load(default_reference_path())
