"""Embedded data of sklearn_psf."""

from __future__ import annotations

import os

from ._reference import ReferenceBasis

__all__ = ["load_default_reference", "default_reference_path"]

_DATA = os.path.join(os.path.dirname(__file__), "data")


_FILES = {5: "default_reference.fits", 13: "default_reference_13.fits"}


def default_reference_path(n_components: int = 5) -> str:
    """Path of the FITS file of an embedded reference basis.

    Parameters
    ----------
    n_components : {5, 13}, default=5
        5: the default basis (90% of the variance); 13: the paper-sized basis.

    Returns
    -------
    str

    Examples
    --------
    >>> from sklearn_psf.datasets import default_reference_path
    >>> default_reference_path().endswith("default_reference.fits")
    True
    """
    if n_components not in _FILES:
        raise ValueError(f"The embedded reference bases have {sorted(_FILES)} components, "
                         f"got n_components={n_components!r}.")
    return os.path.join(_DATA, _FILES[n_components])


def load_default_reference(n_components: int = 5) -> ReferenceBasis:
    """Load an embedded reference basis (ground-based-like PSF at 0.2 arcsec/pixel).

    The basis is the PCA (90% of the variance) of 25 x 25 pixel stamps of the stars of a GalSim
    image: Kolmogorov atmosphere (FWHM 0.7 arcsec) with a small shear, convolved with an
    optical PSF whose defocus, astigmatism and coma vary smoothly over the field, extracted
    with :meth:`ReferenceBasis.from_image`. It was tuned so that the default simulation has
    PSF ellipticities of mean |e| ~ 0.05 and spread ~ 0.02 (Berge et al. 2012). How it was
    made: the script ``sklearn_psf/datasets/_make_default_reference.py`` of the source tree
    regenerates it (``python -m sklearn_psf.datasets._make_default_reference``).

    ``n_components=13`` selects the basis of the first 13 principal components of the same
    stars, the size of the paper's Subaru basis (13 components at 90% of the variance): its
    first 5 components are those of the default basis; components 6-13 hold 0.1-0.2% of the
    variance each, mostly the reference stars' noise, as the later components of a real basis
    of stars of finite S/N do.

    Parameters
    ----------
    n_components : {5, 13}, default=5
        5 (the default, 90% of the variance: only the signal of the reference stars) or 13.

    Returns
    -------
    ReferenceBasis

    Examples
    --------
    >>> from sklearn_psf.datasets import load_default_reference
    >>> ref = load_default_reference()
    >>> ref.stamp_size, ref.pixel_scale, ref.n_components
    (25, 0.2, 5)
    >>> load_default_reference(n_components=13).n_components
    13
    """
    return ReferenceBasis.load(default_reference_path(n_components))
