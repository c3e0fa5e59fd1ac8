"""A saved model back on the sky: its PSF at the positions of a catalogue (the galaxies),
with their shapes and whether each is extrapolated; what ``sklearn-psf predict`` writes."""

from __future__ import annotations

import os

import numpy as np
from astropy.table import Table

from .._files import InputError, check_memory

__all__ = ["predict_catalog"]

#: PSFs drawn at once (and between two calls of ``progress``).
_CHUNK = 5000


def _model_and_summary(model, summary):
    """The fitted model and its validation summary (read from the file when ``model`` is a
    path, else ``summary`` or {}); the model as error messages name it."""
    from ..model import load_model, read_model_validation

    if isinstance(model, (str, os.PathLike)):
        path = os.fspath(model)
        return load_model(path), summary or read_model_validation(path)[1] or {}, repr(path)
    return model, summary or {}, "the model"


def _positions(catalog, source, radec, wcs):
    """Pixel positions (n, 2) of the catalogue, and their (RA, Dec) when a WCS gives them."""
    from ..io import pixel_to_sky, sky_to_pixel

    X = np.column_stack([np.asarray(catalog["x"]), np.asarray(catalog["y"])])
    if len(X) == 0:
        raise InputError(f"the catalogue {source} has no rows")
    bad = ~np.isfinite(X).all(axis=1)
    if bad.any():
        raise InputError(f"{int(bad.sum())} positions of {source} are NaN or infinite "
                         f"(first at row {int(np.flatnonzero(bad)[0])})")
    if radec:
        return sky_to_pixel(wcs, X), X
    return X, None if wcs is None else pixel_to_sky(wcs, X)


def _key_values(catalog, keys, source):
    """The model's extra dimensions at each row, from the catalogue's own columns."""
    from ._inputs import key_columns

    extra = key_columns(catalog, keys, f"the catalogue {source!r}")
    bad = ~np.isfinite(extra).all(axis=1)
    if bad.any():
        raise InputError(f"{int(bad.sum())} rows of {source} have NaN or infinite values in "
                         f"{', '.join(keys)} (first at row {int(np.flatnonzero(bad)[0])}): "
                         "the model needs them")
    return extra


def predict_catalog(model, catalog, *, summary=None, one_based: bool | None = None,
                    x_col: str | None = None, y_col: str | None = None, radec: bool = False,
                    keys=None, centered: bool = False, oversampling: int = 1,
                    progress=None) -> Table:
    """The model's PSF at every position of a catalogue, with its shape.

    What ``sklearn-psf predict`` computes (the command writes the table to FITS): the
    catalogue read (:func:`~sklearn_psf.io.read_catalog`), its positions converted from
    (RA, Dec) with the fit's WCS if asked, the model's extra dimensions read from the same
    columns as in the fit, the PSFs drawn (:func:`~sklearn_psf.io.draw_psf`) and measured
    (adaptive moments), each row flagged when extrapolated
    (:func:`~sklearn_psf.io.extrapolation_flags`).

    Parameters
    ----------
    model : str, os.PathLike or fitted PSFModel
        A model file (its validation summary read with it), or a fitted model.
    catalog : str, os.PathLike or astropy.table.Table
        The positions, as :func:`~sklearn_psf.io.read_catalog` reads them (``one_based``,
        ``x_col``, ``y_col`` passed on); not modified.
    summary : dict, optional
        The fit's summary (:attr:`ExposureFit.summary`): its ``wcs`` and ``keys``. Default
        the model file's, else none.
    radec : bool, default=False
        The positions are (RA, Dec) in degrees, converted with the summary's WCS.
    keys : sequence of str, optional
        The catalogue's columns of the model's extra dimensions, in the fit's order; default
        the names the summary stores.
    centered : bool, default=False
        Shift each PSF by its position's sub-pixel offset (see :func:`~sklearn_psf.io.draw_psf`).
    oversampling : int, default=1
        Samples per pixel along each axis.
    progress : callable, optional
        Called as ``progress(done, total)`` with the number of PSFs drawn so far, before the
        first and after every 5000: a progress bar's hook.

    Returns
    -------
    astropy.table.Table
        ``x``, ``y`` (0-based pixels), ``ra``, ``dec`` (degrees, with a WCS), the
        catalogue's other columns, ``psf`` (n, S, S unit-sum stamps centred on pixel
        ``floor(x + 0.5)``, ``floor(y + 0.5)``), ``e1``, ``e2``, ``sigma`` (image pixels),
        ``moments_flag`` (non-zero: not measured), ``extrapolated``; ``meta["keys"]``, the
        extra dimensions' columns.

    Raises
    ------
    InputError
        A model and keys that do not agree, ``radec`` without a WCS, an empty catalogue,
        NaN positions or key values (the row named).

    Examples
    --------
    >>> import numpy as np
    >>> from astropy.table import Table
    >>> from sklearn_psf.exposure import predict_catalog
    >>> from sklearn_psf.interpolate import PolynomialRegressor
    >>> from sklearn_psf.model import PSFModel
    >>> from sklearn_psf.simulate import make_psf_field
    >>> field = make_psf_field(n_stars=40, n_galaxies=1, image_shape=(500, 500),
    ...                        random_state=0)
    >>> X = np.column_stack([field.stars["x"], field.stars["y"]])
    >>> stamps, _ = field.star_stamps()
    >>> model = PSFModel(interpolator=PolynomialRegressor(degree=1)).fit(X, stamps)
    >>> out = predict_catalog(model, Table({"x": [100.0, 250.5], "y": [40.0, 300.0]}))
    >>> out["psf"].shape, bool(np.allclose(out["psf"].sum(axis=(1, 2)), 1.0))
    ((2, 25, 25), True)
    >>> out["extrapolated"].tolist()
    [False, False]
    """
    from ..io import celestial_wcs, draw_psf, extrapolation_flags, read_catalog
    from ..measure import adaptive_moments
    from ._inputs import _naming

    model, summary, name = _model_and_summary(model, summary)
    wcs = celestial_wcs(summary.get("wcs"))
    keys = list(keys or summary.get("keys") or ())
    n_extra = model.X_fit_.shape[1] - 2
    if len(keys) != n_extra:
        named = f" ({', '.join(summary['keys'])})" if summary.get("keys") else ""
        raise InputError(f"the model {name} has {n_extra} dimensions after x, y{named}; "
                         + (f"--keys gives {len(keys)} ({', '.join(keys)})" if keys else
                            "it does not name their columns: give them with --keys (keys)"))
    if radec and wcs is None:
        raise InputError(f"radec / --radec: the model {name} has no WCS (its image had none)")
    path = os.fspath(catalog) if isinstance(catalog, (str, os.PathLike)) else None
    source = path or "the table"
    with _naming(path):
        catalog = read_catalog(catalog, one_based=one_based, x_col=x_col, y_col=y_col,
                               sky=radec)
    X, sky = _positions(catalog, source, radec, wcs)
    if keys:
        with _naming(path):
            X = np.column_stack([X, _key_values(catalog, keys, source)])
    size = model.stamp_size_ * oversampling
    check_memory(3 * 8 * len(X) * size**2, f"{len(X)} PSF stamps of {size} x {size} samples "
                 f"(--oversampling {oversampling})")
    stamps = np.empty((len(X), size, size))
    step = progress or (lambda done, total: None)
    step(0, len(X))
    for start in range(0, len(X), _CHUNK):
        stop = min(start + _CHUNK, len(X))
        stamps[start:stop] = draw_psf(model, X[start:stop], centered=centered,
                                      oversampling=oversampling)
        step(stop, len(X))
    mom = adaptive_moments(stamps)
    out = Table({"x": X[:, 0], "y": X[:, 1]})
    if sky is not None:
        out["ra"], out["dec"] = sky[:, 0], sky[:, 1]
    for column in catalog.colnames:
        if column not in out.colnames:
            out[column] = catalog[column]
    out["psf"] = stamps
    for column in ("e1", "e2", "sigma"):
        out[column] = np.asarray(mom[column], dtype=np.float64)
    if oversampling > 1:
        out["sigma"] /= oversampling  # in image pixels
    out["moments_flag"] = np.asarray(mom["flag"], dtype=np.int64)
    out["extrapolated"] = extrapolation_flags(model.X_fit_, X)
    out.meta["keys"] = keys
    return out
