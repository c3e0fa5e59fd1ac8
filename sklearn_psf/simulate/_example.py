"""A simulated exposure written as survey-like files (image + weight HDU, SExtractor catalogue)."""

from __future__ import annotations

import os

import numpy as np
from astropy.io import fits
from astropy.table import Table

__all__ = ["write_example_exposure", "write_example_ldac"]


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
    >>> from sklearn_psf.io import read_image
    >>> from sklearn_psf.simulate import write_example_exposure
    >>> paths = write_example_exposure(tempfile.mkdtemp(), n_stars=20,
    ...                                image_shape=(400, 500), n_galaxies=5)
    >>> image, weight, header = read_image(paths["image"], hdu="SCI", weight_hdu="WGT")
    >>> image.shape, int((weight == 0).sum()), "SATURATE" in header
    ((400, 500), 9, True)
    """
    from ._make import make_psf_field

    folder = os.fspath(folder)
    field = make_psf_field(n_stars=n_stars, n_galaxies=n_galaxies, image_shape=image_shape,
                           snr=snr, random_state=random_state, galaxy_snr=None)
    img = field.image.astype(np.float64)
    s = field.stamp_size
    h = s // 2
    weight = np.full(img.shape, 1.0 / field.noise_rms**2, dtype=np.float32)
    x0, y0 = np.asarray(field.stars["x"], float), np.asarray(field.stars["y"], float)
    xs, ys = np.floor(x0 + 0.5).astype(int), np.floor(y0 + 0.5).astype(int)  # centre pixels
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
    Table({"NUMBER": np.arange(1, n_stars + 1), "X_IMAGE": x0 + 1.0, "Y_IMAGE": y0 + 1.0,
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


def _example_wcs(shape, pixel_scale):
    """A TAN WCS centred on the image, north up, east left (as most survey CCDs)."""
    from astropy.wcs import WCS

    w = WCS(naxis=2)
    w.wcs.ctype = ["RA---TAN", "DEC--TAN"]
    w.wcs.crval = [150.0, 2.2]
    w.wcs.crpix = [(shape[1] + 1) / 2, (shape[0] + 1) / 2]
    w.wcs.cd = np.array([[-1.0, 0.0], [0.0, 1.0]]) * pixel_scale / 3600.0
    return w


def _sextractor_columns(vignettes, noise_rms, aperture=8.0, sub=5):
    """FLUX_AUTO, FLUXERR_AUTO, MAG_AUTO, FLUX_RADIUS, FLUX_MAX measured on the vignettes.

    FLUX_RADIUS interpolates the growth curve of sub x sub sub-pixels (as SExtractor does),
    so that it varies continuously with the source's size.
    """
    n, v, _ = vignettes.shape
    fine = (np.arange(v * sub) + 0.5) / sub - 0.5 - v // 2
    yy, xx = np.meshgrid(fine, fine, indexing="ij")
    r = np.hypot(xx, yy).ravel()
    pixel = (np.arange(v * sub) // sub)
    index = (pixel[:, None] * v + pixel[None, :]).ravel()
    inside = np.flatnonzero(r <= aperture)
    order = inside[np.argsort(r[inside])]
    radii = r[order]
    flat = np.where(vignettes > -1e29, vignettes, 0.0).reshape(n, -1)
    cum = np.cumsum(flat[:, index[order]], axis=1) / sub**2
    flux = cum[:, -1]
    half = np.array([np.interp(0.5 * f, np.maximum.accumulate(c), radii) if f > 0 else np.nan
                     for f, c in zip(flux, cum)])
    err = noise_rms * np.sqrt(np.pi * aperture**2)
    with np.errstate(divide="ignore", invalid="ignore"):
        mag = np.where(flux > 0, 25.0 - 2.5 * np.log10(np.maximum(flux, 1e-30)), 99.0)
    return {"FLUX_AUTO": flux, "FLUXERR_AUTO": np.full(n, err), "MAG_AUTO": mag,
            "FLUX_RADIUS": half, "FLUX_MAX": flat.max(axis=1)}


def write_example_ldac(folder, *, n_stars: int = 300, n_galaxies: int = 300,
                       image_shape=(3000, 3000), snr=100.0, random_state=0,
                       defects: bool = True) -> dict:
    """Write a simulated SExtractor FITS_LDAC catalogue with ``VIGNET`` stamps, as PSFEx reads.

    Stars are cut from a :func:`sklearn_psf.simulate.make_psf_field` image (the vignette
    side is the field's stamp size); galaxies are the true PSF at the field's galaxy
    positions convolved with an elliptical Gaussian (sigma 0.3 to 4 pixels along each axis:
    some barely resolved),
    with the same background noise and star-like fluxes. The catalogue columns
    (``X_IMAGE``, ``Y_IMAGE`` 1-based, ``FLUX_AUTO``, ``FLUXERR_AUTO``, ``MAG_AUTO``,
    ``FLUX_RADIUS``, ``FLUX_MAX``, ``FLAGS``, ``ALPHA_J2000``, ``DELTA_J2000``) are measured on
    the vignettes; the ``LDAC_IMHEAD`` header holds ``SATURATE``, ``GAIN`` and a TAN WCS.

    With ``defects``: 5% of the stars saturated (20 times brighter, clipped at ``SATURATE``;
    half of them with ``FLAGS`` 4), 10% with a masked column (-1e30) in the wing, 2% masked
    in the core, and ``n_stars // 20`` cosmic rays (single hot pixels) in the catalogue.

    Parameters
    ----------
    folder : str or os.PathLike
    n_stars, n_galaxies : int, default=300
    image_shape : tuple (ny, nx), default=(3000, 3000)
    snr : float or array-like of shape (n_stars,), default=100
        Star S/N (e.g. :func:`sklearn_psf.simulate.realistic_snr`); the galaxies take the
        stars' fluxes in random order.
    random_state : int, default=0
    defects : bool, default=True

    Returns
    -------
    paths : dict
        ``catalog`` (path of ``catalog.ldac``), ``kind`` (array: "star", "galaxy", "cosmic"
        per row), ``defect`` (array: "", "saturated", "masked_wing", "masked_core"),
        ``truth`` (table of the stars' true ``x``, ``y`` (0-based), ``e1``, ``e2``,
        ``sigma``), ``field``, ``saturate``.

    Examples
    --------
    >>> import tempfile
    >>> from sklearn_psf.io import read_catalog
    >>> from sklearn_psf.simulate import write_example_ldac
    >>> out = write_example_ldac(tempfile.mkdtemp(), n_stars=20, n_galaxies=10,
    ...                          image_shape=(800, 800))
    >>> cat = read_catalog(out["catalog"])
    >>> len(cat), cat["VIGNET"].shape[1:], "SATURATE" in cat.meta["image_header"]
    (31, (25, 25), True)
    """
    from scipy.ndimage import gaussian_filter

    from ..preprocessing import cut_stamps
    from ._make import make_psf_field
    from ..io import write_ldac

    rng = np.random.default_rng(random_state)
    field = make_psf_field(n_stars=n_stars, n_galaxies=n_galaxies, image_shape=image_shape,
                           snr=snr, random_state=random_state, galaxy_snr=None)
    s, noise = field.stamp_size, field.noise_rms
    star_pos = np.column_stack([field.stars["x"], field.stars["y"]]).astype(np.float64)
    stars, _ = cut_stamps(field.image, star_pos, s)
    gal_pos = np.column_stack([field.galaxies["x"], field.galaxies["y"]]).astype(np.float64)
    psf = np.asarray(field.galaxies["stamp"], dtype=np.float64).reshape(-1, s, s)
    flux = rng.choice(np.asarray(field.stars["flux"]), len(psf))
    gal = np.array([gaussian_filter(p, rng.uniform(0.3, 4.0, 2), mode="constant") * f
                    for p, f in zip(psf, flux)]) + rng.normal(0.0, noise, psf.shape)
    kinds = [np.full(n_stars, "star"), np.full(len(gal), "galaxy")]
    vignettes, positions = [stars, gal], [star_pos, gal_pos]
    defect = np.full(n_stars, "", dtype=object)
    flags = np.zeros(n_stars, dtype=np.int16)
    saturate = float(3.0 * stars.max())
    if defects:
        n_cr = n_stars // 20
        order = rng.permutation(n_stars)
        n_sat, n_wing, n_core = (max(1, int(round(f * n_stars))) for f in (0.05, 0.10, 0.02))
        sat, wing = order[:n_sat], order[n_sat:n_sat + n_wing]
        core = order[n_sat + n_wing:n_sat + n_wing + n_core]
        stars[sat] = np.minimum(20.0 * stars[sat], saturate)
        flags[sat[: n_sat // 2]] = 4
        stars[wing, :, s // 2 + 4] = -1e30
        stars[core, s // 2, s // 2] = -1e30
        defect[sat], defect[wing], defect[core] = "saturated", "masked_wing", "masked_core"
        cr = rng.normal(0.0, noise, (n_cr, s, s))
        cr[:, s // 2, s // 2] += rng.uniform(20, 100, n_cr) * noise
        vignettes.append(cr)
        positions.append(rng.uniform(s, min(image_shape) - s, (n_cr, 2)).round())
        kinds.append(np.full(n_cr, "cosmic"))
    vig = np.concatenate(vignettes).astype(np.float32)
    pos = np.concatenate(positions)
    kind = np.concatenate(kinds)
    n = len(vig)
    wcs = _example_wcs(image_shape, field.pixel_scale)
    ra, dec = wcs.all_pix2world(pos[:, 0], pos[:, 1], 0)
    table = Table({"NUMBER": np.arange(1, n + 1), "X_IMAGE": pos[:, 0] + 1.0,
                   "Y_IMAGE": pos[:, 1] + 1.0, "ALPHA_J2000": ra, "DELTA_J2000": dec})
    for name, col in _sextractor_columns(vig, noise).items():
        table[name] = col
    table["FLAGS"] = np.concatenate([flags, np.zeros(n - n_stars, dtype=np.int16)])
    table["VIGNET"] = vig
    header = wcs.to_header()
    header["NAXIS1"], header["NAXIS2"] = image_shape[1], image_shape[0]
    header["SATURATE"] = (saturate, "saturation level (ADU)")
    header["GAIN"] = (1.0, "e-/ADU")
    path = os.path.join(os.fspath(folder), "catalog.ldac")
    write_ldac(path, table, header=header, overwrite=True)
    truth = Table({"x": star_pos[:, 0], "y": star_pos[:, 1], "e1": field.stars["e1"],
                   "e2": field.stars["e2"], "sigma": field.stars["sigma"]})
    return {"catalog": path, "kind": kind,
            "defect": np.concatenate([defect, np.full(n - n_stars, "", dtype=object)]),
            "truth": truth, "field": field, "saturate": saturate}
