"""The model's PSF as a GalSim object, to convolve galaxies with (GalSim is optional)."""

from __future__ import annotations

import numbers

import numpy as np

from .._optional import require

__all__ = ["to_galsim"]

def _local_wcs(galsim, wcs, x, y):
    """GalSim local WCS (a uniform Jacobian) at the 0-based pixel (x, y)."""
    if wcs is None:
        return galsim.PixelScale(1.0)
    if isinstance(wcs, numbers.Real) and not isinstance(wcs, bool):
        if not (np.isfinite(wcs) and wcs > 0):
            raise ValueError(f"A pixel scale must be finite and > 0, got {wcs!r}.")
        return galsim.PixelScale(float(wcs))
    pos = galsim.PositionD(x + 1.0, y + 1.0)  # GalSim's FITS WCS: 1-based pixels
    if isinstance(wcs, galsim.BaseWCS):
        return wcs.local(image_pos=pos)
    if hasattr(wcs, "pixel_to_world"):  # astropy.wcs.WCS
        return galsim.AstropyWCS(wcs=wcs).local(image_pos=pos)
    raise TypeError(f"wcs must be None, a pixel scale (float), a galsim WCS or an "
                    f"astropy.wcs.WCS, got {type(wcs).__name__}.")


def to_galsim(model, x: float, y: float, *, wcs=None, x_interpolant=None,
              gsparams=None):
    """The PSF at one position as a ``galsim.InterpolatedImage``, centred on its origin.

    The model's stamp at (x, y) (``model.predict``: unit sum, centroid on the centre pixel)
    becomes an interpolated profile whose centroid is the profile's origin and whose pixels
    carry the local WCS. So ``galsim.Convolve(galaxy, psf)`` keeps the galaxy where it is,
    and ``drawImage(..., center=galsim.PositionD(x + 1, y + 1))`` puts the PSF at the
    star's sub-pixel position on an image whose pixels follow GalSim's 1-based
    convention (``image.setOrigin(0, 0)`` for 0-based ones).

    The stamp is the pixel-convolved ("effective") PSF, as PSFEx and PIFF PixelGrid models
    are: draw the PSF, or a galaxy convolved with it, with ``method='no_pixel'`` (another
    method would convolve with the pixel twice). Drawn with ``method='no_pixel'`` on an
    ``s x s`` image of the same pixels, the PSF gives back ``model.predict``'s stamp (the
    interpolant goes through its samples). For a super-resolved basis
    (:class:`~sklearn_psf.preprocessing.SuperResolvedPCA`, undersampled stars), GalSim gets
    the fine profile (``model.predict(..., fine=True)``) on pixels ``oversampling_`` times
    smaller than the image's: drawn with ``method='no_pixel'`` at the image's pixels and any
    sub-pixel offset, it gives the pixels such a star has (up to the interpolant's error).

    Parameters
    ----------
    model : fitted PSFModel, or any model whose ``predict(X)`` gives (n, s*s) stamps
    x, y : float
        0-based pixel position (x = column), the package's convention.
    wcs : None, float, galsim.BaseWCS or astropy.wcs.WCS, optional
        None: the profile is in image pixels (pixel scale 1). A float: arcsec per pixel. A
        GalSim or astropy WCS of the image: its local Jacobian at (x, y) (evaluated at
        GalSim's 1-based ``image_pos = (x + 1, y + 1)``), so that the profile is in world
        coordinates (arcsec), sheared and rotated as the image's pixels are.
    x_interpolant : str or galsim.Interpolant, optional
        Real-space interpolant of ``galsim.InterpolatedImage``. Default "quintic" (GalSim's
        default), "lanczos5" for the fine profile of a super-resolved basis (its samples
        carry power up to ~0.8 of their Nyquist frequency, where quintic interpolation is
        off by ~2% of the peak, Lanczos-5 by ~0.3% on the package's tests).
    gsparams : galsim.GSParams, optional

    Returns
    -------
    psf : galsim.InterpolatedImage
        Flux 1.

    Raises
    ------
    ImportError
        When GalSim is not installed (the message says how to install it).

    Examples
    --------
    >>> import numpy as np
    >>> import galsim
    >>> from sklearn_psf.model import to_galsim
    >>> class Gaussian:                      # any model whose predict gives stamps
    ...     def predict(self, X):
    ...         yy, xx = np.mgrid[-7:8, -7:8]
    ...         g = np.exp(-(xx**2 + 0.8 * yy**2) / 8.0).ravel()
    ...         return np.tile(g / g.sum(), (len(X), 1))
    >>> psf = to_galsim(Gaussian(), 120.3, 48.9, wcs=0.2)     # 0.2 arcsec per pixel
    >>> image = psf.drawImage(nx=15, ny=15, scale=0.2, method="no_pixel")
    >>> bool(np.allclose(image.array.ravel(), Gaussian().predict([[0, 0]])[0], atol=1e-9))
    True
    >>> galaxy = galsim.Exponential(half_light_radius=0.5).shear(g1=0.1)
    >>> final = galsim.Convolve(galaxy, psf).drawImage(nx=33, ny=33, scale=0.2,
    ...                                               method="no_pixel")
    >>> round(float(final.array.sum()), 3)
    1.0
    """
    galsim = require("galsim", "to_galsim")
    x, y = float(x), float(y)
    if not (np.isfinite(x) and np.isfinite(y)):
        raise ValueError(f"The position must be finite, got ({x}, {y}).")
    local = _local_wcs(galsim, wcs, x, y)
    factor = int(getattr(getattr(model, "basis_", None), "oversampling_", 1))
    if x_interpolant is None:
        x_interpolant = "lanczos5" if factor > 1 else "quintic"
    if factor > 1:  # a super-resolved basis: the fine profile, on pixels `factor` times smaller
        stamp = np.asarray(model.predict(np.array([[x, y]]), fine=True), dtype=np.float64)[0]
        local = galsim.JacobianWCS(*(local.jacobian().getMatrix().ravel() / factor))
    else:
        stamp = np.asarray(model.predict(np.array([[x, y]])), dtype=np.float64)[0]
    s = int(round(np.sqrt(stamp.size)))
    if s * s != stamp.size:
        raise ValueError(f"The model predicts {stamp.size} pixels per stamp: not a square.")
    image = galsim.Image(np.ascontiguousarray(stamp.reshape(s, s)), wcs=local)
    return galsim.InterpolatedImage(image, x_interpolant=x_interpolant, gsparams=gsparams)
