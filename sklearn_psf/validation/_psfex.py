"""Writing a PSF in PSFEx's ``.psf`` format (what PSFEx writes; GalSim and Source Extractor read).

:func:`write_psfex` writes given polynomial planes; :func:`to_psfex` writes a fitted model of
this package, its interpolated PSF approximated by a polynomial of the position.
"""

from __future__ import annotations

import numpy as np
from astropy.io import fits

from .._files import write_fits_atomic

__all__ = ["psfex_terms", "to_psfex", "write_psfex"]


def psfex_terms(X, degree: int, polzero, polscal) -> np.ndarray:
    """PSFEx's polynomial terms of positions: (n, (degree+1)(degree+2)/2).

    With u = (x - polzero[0]) / polscal[0] and v = (y - polzero[1]) / polscal[1], the terms
    are u^i v^j for j = 0..degree, i = 0..degree-j, in that order (i fastest): the order of
    the ``PSF_MASK`` planes. The PSF at a position is ``terms @ PSF_MASK``.

    Parameters
    ----------
    X : array-like of shape (n, 2)
        Positions in the model's convention (PSFEx: 1-based ``X_IMAGE``, ``Y_IMAGE``).
    degree : int
    polzero, polscal : pair of float
        ``POLZERO1/2`` and ``POLSCAL1/2``.

    Returns
    -------
    terms : ndarray of shape (n, (degree+1)(degree+2)/2)

    Examples
    --------
    >>> from sklearn_psf.validation import psfex_terms
    >>> psfex_terms([[3.0, 5.0]], 2, (1.0, 1.0), (2.0, 2.0)).tolist()  # u = 1, v = 2
    [[1.0, 1.0, 1.0, 2.0, 2.0, 4.0]]
    """
    X = np.asarray(X, dtype=np.float64)
    u = (X[:, 0] - polzero[0]) / polscal[0]
    v = (X[:, 1] - polzero[1]) / polscal[1]
    d = int(degree)
    return np.column_stack([u**i * v**j for j in range(d + 1) for i in range(d + 1 - j)])


def write_psfex(path, psf_mask, polzero, polscal, *, psf_samp: float = 1.0,
                names=("X_IMAGE", "Y_IMAGE"), header=None, overwrite: bool = False) -> None:
    """Write a PSF whose pixels are polynomials of the position as a PSFEx ``.psf`` file.

    The layout is PSFEx's: HDU 1 ``PSF_DATA``, a binary table of one row whose ``PSF_MASK``
    column holds the (n_terms, ny, nx) planes, with the keywords ``POLNAXIS = 2``,
    ``POLNAME1/2 = 'X_IMAGE'/'Y_IMAGE'``, ``POLZERO1/2``, ``POLSCAL1/2``, ``POLGRP1/2 = 1``,
    ``POLNGRP = 1``, ``POLDEG1``, ``PSF_SAMP``, ``PSFNAXIS = 3`` and ``PSFAXIS1..3``. GalSim's
    ``galsim.des.DES_PSFEx`` (and :class:`PSFExModel`) read it: the PSF at ``(x, y)`` is
    ``psfex_terms([(x, y)], degree, polzero, polscal) @ psf_mask``, sampled every
    ``psf_samp`` image pixels.

    Parameters
    ----------
    path : str or os.PathLike
    psf_mask : array-like of shape (n_terms, ny, nx)
        One plane per polynomial term, in :func:`psfex_terms` order; n_terms must be
        (d+1)(d+2)/2 for a degree d.
    polzero, polscal : pair of float
        Position offset and scale of the polynomial (x, y), in the model's pixel convention
        (PSFEx: 1-based).
    psf_samp : float, default=1
        Image pixels per model pixel.
    names : pair of str, default=("X_IMAGE", "Y_IMAGE")
        ``POLNAME1/2``: the catalogue columns of the positions (PSFEx's usual configuration
        is ``XWIN_IMAGE``, ``YWIN_IMAGE``; Source Extractor computes them when it loads the
        file).
    header : dict, optional
        More cards, ``{name: value or (value, comment)}``; ``LOADED``, ``ACCEPTED``,
        ``CHI2`` and ``PSF_FWHM`` (in model pixels) go where PSFEx puts them, others after.
    overwrite : bool, default=False

    Examples
    --------
    >>> import os, tempfile
    >>> import numpy as np
    >>> from astropy.io import fits
    >>> from sklearn_psf.validation import write_psfex
    >>> path = os.path.join(tempfile.mkdtemp(), "ccd.psf")
    >>> write_psfex(path, np.ones((3, 7, 7)), polzero=(1024.5, 2048.5),
    ...             polscal=(2048.0, 4096.0))                  # degree 1: 3 planes
    >>> h = fits.getheader(path, 1)
    >>> h["POLDEG1"], h["PSFAXIS3"], fits.getdata(path, 1)["PSF_MASK"].shape
    (1, 3, (1, 3, 7, 7))
    """
    mask = np.asarray(psf_mask, dtype=np.float32)
    if mask.ndim != 3:
        raise ValueError(f"psf_mask must have shape (n_terms, ny, nx), got {mask.shape}.")
    n_terms, ny, nx = mask.shape
    degree = int(round((np.sqrt(8 * n_terms + 1) - 3) / 2))
    if (degree + 1) * (degree + 2) // 2 != n_terms:
        raise ValueError(f"psf_mask has {n_terms} planes: a polynomial of degree d in (x, y) "
                         "has (d+1)(d+2)/2 terms (1, 3, 6, 10, ...).")
    if not np.isfinite(mask).all():
        raise ValueError("psf_mask holds NaN or infinite values.")
    zero = [float(v) for v in polzero]
    scale = [float(v) for v in polscal]
    if len(zero) != 2 or len(scale) != 2 or not all(np.isfinite(zero + scale)) or \
            0.0 in scale:
        raise ValueError(f"polzero and polscal must be two finite numbers each, polscal not 0; "
                         f"got {polzero!r}, {polscal!r}.")
    column = fits.Column(name="PSF_MASK", format=f"{mask.size}E", dim=f"({nx}, {ny}, {n_terms})",
                         array=mask[None])
    names = [str(v) for v in names]
    if len(names) != 2 or not names[0].upper().startswith("X") or \
            not names[1].upper().startswith("Y"):
        raise ValueError(f"names must be the x and y columns, e.g. ('XWIN_IMAGE', "
                         f"'YWIN_IMAGE'), got {names!r}.")
    extra = {str(k).upper(): v if isinstance(v, tuple) else (v,)
             for k, v in (header or {}).items()}
    hdu = fits.BinTableHDU.from_columns([column], name="PSF_DATA")
    h = hdu.header
    h["LOADED"] = (int(extra.pop("LOADED", (0,))[0]), "number of loaded sources")
    h["ACCEPTED"] = (int(extra.pop("ACCEPTED", (0,))[0]), "number of accepted sources")
    if "CHI2" in extra:  # PSFEx's reduced chi2 of the stars on the model; omitted if unknown
        h["CHI2"] = (float(extra.pop("CHI2")[0]), "final chi2")
    h["POLNAXIS"] = (2, "number of context parameters")
    for k, name in ((1, names[0]), (2, names[1])):
        h[f"POLGRP{k}"] = (1, "polynom group for this context parameter")
        h[f"POLNAME{k}"] = (name, "name of this context parameter")
        h[f"POLZERO{k}"] = (zero[k - 1], "offset value for this context parameter")
        h[f"POLSCAL{k}"] = (scale[k - 1], "scale value for this context parameter")
    h["POLNGRP"] = (1, "number of polynom groups")
    h["POLDEG1"] = (degree, "polynom degree")
    h["PSF_FWHM"] = (float(extra.pop("PSF_FWHM", (3.0,))[0]), "PSF FWHM (model pixels)")
    h["PSF_SAMP"] = (float(psf_samp), "sampling step of the PSF data (image pixels)")
    h["PSFNAXIS"] = (3, "dimensionality of the PSF data")
    h["PSFAXIS1"] = (nx, "number of element along this axis")
    h["PSFAXIS2"] = (ny, "number of element along this axis")
    h["PSFAXIS3"] = (n_terms, "number of element along this axis")
    for key, card in extra.items():
        h[key] = card
    write_fits_atomic(fits.HDUList([fits.PrimaryHDU(), hdu]), path, overwrite=overwrite)


def _extent(model, image_shape, extent):
    if image_shape is not None and extent is not None:
        raise ValueError("give image_shape or extent, not both.")
    if image_shape is not None:
        ny, nx = (int(v) for v in image_shape)
        if nx < 2 or ny < 2:
            raise ValueError(f"image_shape must be (ny, nx) of at least 2 pixels each, got "
                             f"{image_shape!r}.")
        return 0.0, nx - 1.0, 0.0, ny - 1.0
    if extent is None:  # the stars' bounding box, as PSFEx takes it
        X = np.asarray(getattr(model, "X_fit_"), dtype=float)
        return X[:, 0].min(), X[:, 0].max(), X[:, 1].min(), X[:, 1].max()
    xmin, xmax, ymin, ymax = (float(v) for v in extent)
    if not (np.isfinite([xmin, xmax, ymin, ymax]).all() and xmax > xmin and ymax > ymin):
        raise ValueError(f"extent must be (xmin, xmax, ymin, ymax) with xmax > xmin and "
                         f"ymax > ymin, got {extent!r}.")
    return xmin, xmax, ymin, ymax


def _lstsq(terms, Y):
    return np.linalg.lstsq(terms, Y, rcond=None)[0]


def _shape_rms(a, b):
    """rms of |e_a - e_b| and of sigma_a - sigma_b (pixels), adaptive moments of both sets."""
    from ..measure import adaptive_moments

    ma, mb = adaptive_moments(a, guess_sigma=2.0), adaptive_moments(b, guess_sigma=2.0)
    ok = (np.asarray(ma["flag"]) == 0) & (np.asarray(mb["flag"]) == 0)
    de = np.hypot(ma["e1"] - mb["e1"], ma["e2"] - mb["e2"])[ok]
    ds = np.asarray(ma["sigma"] - mb["sigma"])[ok]
    return float(np.sqrt(np.mean(de**2))), float(np.sqrt(np.mean(ds**2)))


def _model_error(model, nodes, peak):
    """The model's own uncertainty over the nodes: rms pixel standard deviation of its
    stamps (relative to ``peak``) from the interpolator's predicted standard deviation of
    each coefficient (Kriging's), propagated through the basis; None when the model gives
    none."""
    basis, interp = getattr(model, "basis_", None), getattr(model, "interpolator_", None)
    if basis is None or interp is None or not hasattr(basis, "inverse_transform"):
        return None
    try:
        coef, std = interp.predict(nodes, return_std=True)
    except TypeError:  # an interpolator without a predicted standard deviation
        return None
    coef = np.asarray(coef, dtype=np.float64).reshape(len(nodes), -1)
    std = np.asarray(std, dtype=np.float64).reshape(coef.shape)
    if not np.isfinite(std).all():
        return None
    base = np.asarray(basis.inverse_transform(coef), dtype=np.float64)
    var = np.zeros_like(base)
    for k in range(coef.shape[1]):  # one standard deviation of each coefficient in turn
        step = coef.copy()
        step[:, k] += std[:, k]
        var += (np.asarray(basis.inverse_transform(step), dtype=np.float64) - base) ** 2
    return float(np.sqrt(np.mean(var)) / peak)


def to_psfex(model, path, *, image_shape=None, extent=None, max_degree: int = 8,
             grid_size: int = 32, n_splits: int = 5, accuracy: float = 0.5,
             tolerance: float = 0.05, names=("XWIN_IMAGE", "YWIN_IMAGE"), chi2=None,
             overwrite: bool = False):
    """Write a fitted PSF model as a PSFEx ``.psf`` file, its variation as a polynomial.

    The model's predicted stamps on a ``grid_size`` x ``grid_size`` grid over the field are
    fitted by least squares with polynomials of PSFEx's scaled positions (1-based,
    ``XWIN_IMAGE = x + 1``). The degree is the smallest whose ``n_splits``-fold
    cross-validated error is at most ``accuracy`` times the model's own uncertainty (else
    within ``tolerance`` of the best degree's): an error added in quadrature raises the
    model's by at most ``sqrt(1 + accuracy**2)``. The approximation's error at the grid's
    cell centres is returned and written in the header (``APXPIX``, ``APXE``, ``APXSIZE``,
    with ``APXCV``, ``APXMODEL``, ``APXDMAX``). Conventions and header: :ref:`psfex-file`.

    Parameters
    ----------
    model : fitted PSF model
        With ``predict(X) -> (m, s*s)`` stamps and ``stamp_size_`` (e.g.
        :class:`~sklearn_psf.model.PSFModel`).
    path : str or os.PathLike
        The ``.psf`` file to write.
    image_shape : (ny, nx), optional
        The image (CCD) the model describes: the polynomial covers it all.
    extent : (xmin, xmax, ymin, ymax), optional
        0-based region instead of ``image_shape``; default the fitted stars' bounding box,
        outside which the polynomial extrapolates: give the image's shape.
    max_degree : int, default=8
        Largest polynomial degree tried.
    grid_size : int, default=32
        Nodes per side of the grid the polynomial is fitted on.
    n_splits : int, default=5
        Folds of the cross-validation on the grid.
    accuracy : float, default=0.5
        Largest approximation error allowed, as a fraction of the model's uncertainty.
    tolerance : float, default=0.05
        Without the model's uncertainty (or no degree reaching ``accuracy``): excess of
        cross-validated error allowed for a lower degree than the best, relative.
    names : pair of str, default=("XWIN_IMAGE", "YWIN_IMAGE")
        ``POLNAME1/2``, PSFEx's usual position columns.
    chi2 : float, optional
        Written as ``CHI2`` (e.g. the reserved stars' chi^2 per degree of freedom of
        :func:`fit_and_validate`); omitted if not given.
    overwrite : bool, default=False

    Returns
    -------
    result : sklearn.utils.Bunch
        ``path``, ``degree``, ``cv_error`` (per degree 0..max_degree, rms pixel difference
        relative to the mean peak), ``model_error`` (the model's uncertainty in the same
        units, None when unknown), ``pixel_rms`` (relative to the peak), ``e_rms``,
        ``size_rms`` (pixels), ``polzero``, ``polscal`` (1-based, as written).

    Examples
    --------
    >>> import os, tempfile
    >>> import numpy as np
    >>> from sklearn_psf.model import PSFModel
    >>> from sklearn_psf.validation import to_psfex
    >>> rng = np.random.default_rng(0)
    >>> X = rng.uniform(0, 1000, (80, 2))
    >>> yy, xx = np.mgrid[0:15, 0:15] - 7.0
    >>> sig = (1.8 + X[:, 0] / 2000.0)[:, None, None]    # size grows along x
    >>> stars = 5e4 * np.exp(-0.5 * (xx**2 + yy**2) / sig**2) / (2 * np.pi * sig**2)
    >>> stamps = (stars + rng.normal(0.0, 10.0, stars.shape)).reshape(80, -1)
    >>> model = PSFModel().fit(X, stamps, weights=np.full(stamps.shape, 0.01))
    >>> out = to_psfex(model, os.path.join(tempfile.mkdtemp(), "ccd.psf"),
    ...                image_shape=(1000, 1000))
    >>> out.degree <= 8, bool(out.pixel_rms < 0.01), bool(out.size_rms < 0.01)
    (True, True, True)
    """
    from sklearn.model_selection import KFold
    from sklearn.utils import Bunch

    if not hasattr(model, "stamp_size_") or not hasattr(model, "predict"):
        raise ValueError("model must be a fitted PSF model with predict() and stamp_size_ "
                         "(e.g. a fitted PSFModel).")
    if int(max_degree) != max_degree or not 0 <= max_degree <= 10:
        raise ValueError(f"max_degree must be an integer in 0..10, got {max_degree!r}.")
    max_degree = int(max_degree)
    n_terms_max = (max_degree + 1) * (max_degree + 2) // 2
    if int(grid_size) != grid_size or grid_size**2 * (1 - 1 / n_splits) < 2 * n_terms_max:
        raise ValueError(f"grid_size={grid_size!r} is too small for degree {max_degree}: "
                         f"give at least {int(np.ceil(np.sqrt(3 * n_terms_max)))}.")
    if not tolerance >= 0:
        raise ValueError(f"tolerance must be >= 0, got {tolerance!r}.")
    if not accuracy > 0:
        raise ValueError(f"accuracy must be > 0, got {accuracy!r}.")
    xmin, xmax, ymin, ymax = _extent(model, image_shape, extent)
    polzero = ((xmin + xmax) / 2 + 1.0, (ymin + ymax) / 2 + 1.0)
    polscal = (xmax - xmin, ymax - ymin)
    s = int(model.stamp_size_)

    gx, gy = np.linspace(xmin, xmax, grid_size), np.linspace(ymin, ymax, grid_size)
    nodes = np.column_stack([a.ravel() for a in np.meshgrid(gx, gy)])
    cx, cy = (gx[:-1] + gx[1:]) / 2, (gy[:-1] + gy[1:]) / 2
    check = np.column_stack([a.ravel() for a in np.meshgrid(cx, cy)])
    Y = np.asarray(model.predict(nodes), dtype=np.float64)
    peak = float(Y.max(axis=1).mean())

    cv_error = np.empty(max_degree + 1)
    folds = list(KFold(n_splits=n_splits, shuffle=True, random_state=0).split(nodes))
    for d in range(max_degree + 1):
        T = psfex_terms(nodes + 1.0, d, polzero, polscal)
        sq = 0.0
        for train, test in folds:
            sq += np.sum((T[test] @ _lstsq(T[train], Y[train]) - Y[test]) ** 2)
        cv_error[d] = np.sqrt(sq / Y.size) / peak
    model_error = _model_error(model, nodes, peak)
    good = [] if model_error is None else np.flatnonzero(cv_error <= accuracy * model_error)
    degree = int(good[0]) if len(good) else \
        int(np.flatnonzero(cv_error <= (1 + tolerance) * cv_error.min())[0])

    planes = _lstsq(psfex_terms(nodes + 1.0, degree, polzero, polscal), Y)
    full = np.asarray(model.predict(check), dtype=np.float64)
    approx = psfex_terms(check + 1.0, degree, polzero, polscal) @ planes
    approx /= approx.sum(axis=1, keepdims=True)        # what PSFEx's readers draw
    pixel_rms = float(np.sqrt(np.mean((approx - full) ** 2)) / peak)
    e_rms, size_rms = _shape_rms(approx.reshape(-1, s, s), full.reshape(-1, s, s))
    centre = model.predict([[(xmin + xmax) / 2, (ymin + ymax) / 2]]).reshape(1, s, s)
    from ..measure import adaptive_moments

    fwhm = float(2 * np.sqrt(2 * np.log(2)) * adaptive_moments(centre, guess_sigma=2.0)
                 ["sigma"][0])

    planes = planes.reshape(-1, s, s)
    if s % 2 == 0:  # centre pixel s // 2 stays the centre of an odd side
        planes = np.pad(planes, ((0, 0), (0, 1), (0, 1)))
    inliers = getattr(model, "inlier_mask_", None)
    n_fit = len(getattr(model, "X_fit_", ()))
    header = {"LOADED": n_fit, "ACCEPTED": n_fit if inliers is None else int(np.sum(inliers)),
              "PSF_FWHM": fwhm if np.isfinite(fwhm) else 3.0,
              "APXDMAX": (max_degree, "largest polynomial degree tried"),
              "APXCV": (float(cv_error[degree]), "cross-validated rms pixel error / peak"),
              "APXPIX": (pixel_rms, "rms pixel error of the polynomial / peak"),
              "APXE": (e_rms, "rms |e| error of the polynomial"),
              "APXSIZE": (size_rms, "rms size (sigma, px) error of the polynomial"),
              "COMMENT": "written by sklearn_psf.validation.to_psfex: a model's basis times a "
                         "polynomial fitted on a grid"}
    if model_error is not None:
        header["APXMODEL"] = (model_error, "the model's own rms pixel uncertainty / peak")
    if chi2 is not None:
        header["CHI2"] = float(chi2)
    write_psfex(path, planes, polzero, polscal, psf_samp=1.0, names=names, header=header,
                overwrite=overwrite)
    return Bunch(path=path, degree=degree, cv_error=cv_error, model_error=model_error,
                 pixel_rms=pixel_rms, e_rms=e_rms, size_rms=size_rms, polzero=polzero,
                 polscal=polscal)
