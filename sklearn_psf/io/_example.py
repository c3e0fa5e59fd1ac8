"""A simulated exposure written as survey-like files (image + weight HDU, SExtractor catalogue)."""

from __future__ import annotations

import os

import numpy as np
from astropy.io import fits
from astropy.table import Table

__all__ = ["write_example_exposure"]


def write_example_exposure(folder, *, n_stars: int = 300, image_shape=(2000, 2000),
                           snr: float = 100.0, n_galaxies: int = 200, random_state=0,
                           compress: bool = False, defects: bool = True) -> dict:
    """Write a simulated exposure as a real survey CCD would come: no download needed.

    The image is :func:`sklearn_psf.simulate.make_psf_field` (stars only, S/N ``snr``, the
    embedded reference basis), written as the ``SCI`` HDU of ``exposure.fits`` (or a
    tile-compressed ``exposure.fits.fz``, lossless) with an inverse-variance ``WGT`` HDU and
    a ``SATURATE`` keyword. With ``defects``, three stars are spoiled as on real data:

    - star 0: a 3x3 patch of zero weight (a bad pixel mask) on its centre;
    - star 1: a NaN pixel next to its centre (weight left non-zero);
    - star 2: 50 times brighter and clipped at the ``SATURATE`` level.

    Also written: ``stars.fits``, a SExtractor-like catalogue of every star (``X_IMAGE``,
    ``Y_IMAGE``: 1-based; ``FLAGS`` 0); ``galaxies.csv``, random 0-based ``x``, ``y``
    positions where to evaluate the PSF; ``truth.fits``, the true PSF shapes (``x``, ``y``
    0-based, ``e1``, ``e2``, ``sigma``) at the stars and the galaxies (``kind`` column).

    Parameters
    ----------
    folder : str or os.PathLike
        Existing folder.
    n_stars : int, default=300
    image_shape : tuple (ny, nx), default=(2000, 2000)
    snr : float, default=100
    n_galaxies : int, default=200
        Positions in ``galaxies.csv`` (their PSFs are not drawn in the image).
    random_state : int, default=0
    compress : bool, default=False
        Write ``exposure.fits.fz`` (lossless tile compression, astropy ``CompImageHDU``).
    defects : bool, default=True

    Returns
    -------
    paths : dict
        ``image``, ``stars``, ``galaxies``, ``truth`` (file paths) and ``field`` (the
        :class:`~sklearn_psf.simulate.PSFField`, before the defects), ``saturate`` (level).

    Examples
    --------
    >>> import tempfile
    >>> from sklearn_psf.io import read_image, write_example_exposure
    >>> paths = write_example_exposure(tempfile.mkdtemp(), n_stars=20,
    ...                                image_shape=(400, 500), n_galaxies=5)
    >>> image, weight, header = read_image(paths["image"], hdu="SCI", weight_hdu="WGT")
    >>> image.shape, int((weight == 0).sum()), "SATURATE" in header
    ((400, 500), 9, True)
    """
    from ..simulate import make_psf_field

    folder = os.fspath(folder)
    field = make_psf_field(n_stars=n_stars, n_galaxies=n_galaxies, image_shape=image_shape,
                           snr=snr, random_state=random_state, galaxy_snr=None)
    img = field.image.astype(np.float64)
    s = field.stamp_size
    h = s // 2
    weight = np.full(img.shape, 1.0 / field.noise_rms**2, dtype=np.float32)
    xs = np.asarray(field.stars["x"], dtype=int)
    ys = np.asarray(field.stars["y"], dtype=int)
    peaks = img[ys, xs]
    saturate = float(2.0 * peaks.max())
    if defects and n_stars >= 4:
        weight[ys[0] - 1:ys[0] + 2, xs[0] - 1:xs[0] + 2] = 0.0
        img[ys[1], xs[1] + 1] = np.nan
        bright = 50.0 * field.stars["flux"][2] * np.asarray(field.stars["stamp"][2])
        img[ys[2] - h:ys[2] + h + 1, xs[2] - h:xs[2] + h + 1] += bright.reshape(s, s)
        img = np.minimum(img, saturate)
    header = fits.Header()
    header["SATURATE"] = (saturate, "saturation level (counts)")
    header["PIXSCALE"] = (field.pixel_scale, "arcsec per pixel")
    header["NOISERMS"] = (field.noise_rms, "background rms (simulation)")
    if compress:
        sci = fits.CompImageHDU(img.astype(np.float32), header=header, name="SCI",
                                quantize_level=0.0, compression_type="GZIP_2")
        name = "exposure.fits.fz"
    else:
        sci = fits.ImageHDU(img.astype(np.float32), header=header, name="SCI")
        name = "exposure.fits"
    paths = {"image": os.path.join(folder, name),
             "stars": os.path.join(folder, "stars.fits"),
             "galaxies": os.path.join(folder, "galaxies.csv"),
             "truth": os.path.join(folder, "truth.fits")}
    fits.HDUList([fits.PrimaryHDU(), sci, fits.ImageHDU(weight, name="WGT")]).writeto(
        paths["image"], overwrite=True)
    Table({"NUMBER": np.arange(1, n_stars + 1), "X_IMAGE": xs + 1.0, "Y_IMAGE": ys + 1.0,
           "FLAGS": np.zeros(n_stars, dtype=np.int16)}).write(paths["stars"], overwrite=True)
    gal = field.galaxies
    Table({"x": np.asarray(gal["x"], float), "y": np.asarray(gal["y"], float)}).write(
        paths["galaxies"], format="ascii.csv", overwrite=True)
    truth = Table({
        "kind": ["star"] * n_stars + ["galaxy"] * len(gal),
        "x": np.concatenate([field.stars["x"], gal["x"]]).astype(float),
        "y": np.concatenate([field.stars["y"], gal["y"]]).astype(float),
        "e1": np.concatenate([field.stars["e1"], gal["e1"]]),
        "e2": np.concatenate([field.stars["e2"], gal["e2"]]),
        "sigma": np.concatenate([field.stars["sigma"], gal["sigma"]]),
    })
    truth.write(paths["truth"], overwrite=True)
    paths["field"] = field
    paths["saturate"] = saturate
    return paths
