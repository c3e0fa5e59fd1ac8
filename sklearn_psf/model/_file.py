"""PSF model files: a self-describing FITS format, written atomically.

A model file is a container (:mod:`sklearn_psf._persist` describes the protocol): it writes
the parameters and the fitted state of the model and of each of its parts, which their
classes give (``_get_state``), and on loading builds each part from its parameters and asks
its class to restore its state (``_set_state``). A new fitted attribute is added to its
class's state, not here.

Format 8 (``SKPSFFMT = 'SKPSF-MODEL'``, ``FORMAT = 8``)
-------------------------------------------------------
HDU 0 (primary, no data)
    ``SKPSFFMT``, ``FORMAT`` (format version, int), ``SKPSFVER`` (package version that wrote
    it), ``STAMPSZ`` (s), ``NCOMP`` (k), ``NSTARS``, ``NINLIER``, ``INTERP`` (interpolator
    class), ``DATE`` (UTC); a multi-exposure model (:func:`save_exposure_model`) has
    ``MULTIEXP`` (``'pooled'`` or ``'per-exposure'``), ``EXPCOL``, ``NFEAT`` and ``STAMPSZ``.
``SPEC`` (binary table: ``key``, ``json``)
    ``model``: the fitted model as JSON, ``{"__estimator__": "module.Class", "params":
    {...}, "state": {...}}``: its ``get_params(deep=False)`` and its ``_get_state()``, whose
    fitted parts (basis, outlier detector, interpolator, the models of a multi-exposure
    model) are described in the same way, recursively (a part without state, e.g. a
    scikit-learn estimator, by its parameters only); arrays of more than 16 values are
    ``{"__array__": "EXTNAME", "dtype": ...}``, the image HDU of that name, smaller ones
    are written inline; a tuple is ``{"__tuple__": [...]}``, a dict ``{"__dict__": {...}}``.
    Also ``versions`` (numpy, scikit-learn, astropy, sklearn_psf) and, after validation,
    ``validation_summary``.
Image HDUs named after the path of their array in the state
    ``BASIS_MEAN``, ``BASIS_COMPONENTS``, ``BASIS_FINE_MEAN``, ``X_FIT``, ``COEFFICIENTS``,
    ``COEFFICIENT_COV``, ``INLIER_MASK`` (uint8 for booleans)...
``RESERVED`` (binary table, optional)
    Reserved-star residuals of :func:`sklearn_psf.validation.fit_and_validate`.
``RHO1`` (binary table, optional)
    rho1 on the reserved stars (``theta``, ``xi``, ``sigma_xi``, ``npairs``).

Loading restores the basis and the outlier detector from their states, and fits the
interpolator on the stored stars, which solves with the choices its state holds (Kriging's
hyperparameters and drift, a polynomial's degree: no likelihood, no search); a part without
state is fitted on the stored data (deterministic). Predictions are identical to the saved
model's, and the file does not depend on pickled internals of any library version.

Formats 1-7 (read by ``_file_legacy``)
-------------------------------------
HDU 0 (primary, no data)
    ``SKPSFFMT``, ``FORMAT`` (format version, int), ``SKPSFVER`` (package version that wrote
    it), ``STAMPSZ`` (s), ``NCOMP`` (k), ``NSTARS``, ``NINLIER``, ``INTERP`` (interpolator
    class), ``DATE`` (UTC).
``SPEC`` (binary table: ``key``, ``json``)
    JSON descriptions of the constructor parameters: ``interpolator``, ``basis``,
    ``outliers`` (a scikit-learn/sklearn_psf estimator is ``{"__estimator__": "module.Class",
    "params": {...}}`` of its ``get_params(deep=False)``; array parameters point to ``ARRAY_i``
    HDUs), ``normalizers`` (the fitted basis's :class:`StampNormalizer` steps), ``versions``
    (numpy, scikit-learn, astropy, sklearn_psf) and, after validation, ``validation_summary``.
``BASIS_MEAN`` (image (s, s)) and ``BASIS_COMPONENTS`` (image (k, s, s))
    The fitted linear basis: stamps = coefficients @ components + mean.
``STARS`` (binary table)
    ``x``, ``y`` (0-based), ``coeffs`` (k per row) and ``inlier`` of every fitted star: the
    interpolator's training data; from format 2, ``coeff_var`` (their noise variance, for a
    noise-aware basis), ``fit_flag`` and ``outlier_score``.
``ARRAY_0``, ... (images, optional)
    Array-valued constructor parameters (e.g. a ``FixedBasis``'s components).
``RESERVED`` (binary table, optional)
    Reserved-star residuals of :func:`sklearn_psf.validation.fit_and_validate`.
``RHO1`` (binary table, optional)
    rho1 on the reserved stars (``theta``, ``xi``, ``sigma_xi``, ``npairs``).

Format 2 adds the noise-aware basis (``SPEC`` entry ``basis_kind``: ``"stamppca"``, with
``stamppca`` holding its noise level and variances; the basis is then rebuilt as a fitted
:class:`~sklearn_psf.preprocessing.StampPCA`).

Format 3 adds the ``STARS`` column ``coeff_cov`` (k*k per row: the coefficients' full noise
covariance, for co-Kriging) and multi-exposure models (:func:`save_exposure_model`): their
primary header adds ``MULTIEXP`` (``'pooled'`` or ``'per-exposure'``), ``EXPCOL`` and
``NFEAT``; a pooled model is the HDUs above for its one model (``STARS`` with an ``exposure``
column) plus an ``EXPOSURES`` table; a per-exposure model has an ``EXPOSURES`` table
(``exposure``, ``ncomp``) and the HDUs of each exposure's model with names prefixed by
``E<i>_`` (``E0_SPEC``, ``E0_STARS``, ...).

A super-resolved basis (:class:`~sklearn_psf.preprocessing.SuperResolvedPCA`, for
undersampled stars) is ``basis_kind`` ``"superres"``: its ``stamppca`` entry adds the fine
grid (``fine_mean_``, ``fine_components_``, ``oversampling_``, ``fine_size_``, ``fwhm_``,
``spatial_degree_``: 0 when absent; ``band_limit_``, cycles per pixel: ``oversampling_ / 2``
when absent);
the ``BASIS_*`` HDUs hold the basis drawn at the pixels' sampling.

Format 4 changes no HDU: the default interpolator (``interpolator`` null in ``SPEC``) scales
positions with :class:`~sklearn_psf.interpolate.IsotropicScaler`; files of formats 1-3 were
fitted with ``MinMaxScaler`` and are still refitted with it, so that they predict as when saved;
likewise a pooled model's :class:`~sklearn_psf.interpolate.ExposureKrigingRegressor`, which
now scales positions by the longer side too, refits a file of formats 1-3 with each axis
scaled to [0, 1]. A model with extra dimensions (``X`` columns beyond (x, y): a colour, a
magnitude) stores them as the ``STARS`` column ``extra`` (one value per extra column and star,
in ``fit``'s order); older readers do not know it.

Format 5 changes no HDU: the default interpolator's drift is chosen by the likelihood
(``drift="auto"``); files of formats 1-4 are refitted with the constant mean they were fitted
with.

Format 6 changes no HDU: ``PSFModel`` refits its interpolator in the second outlier round
and the final fit from the previous round's hyperparameters (``warm_start``); ``SPEC``'s
``warm_starts`` holds, for each Kriging step so fitted (by its parameter path, ``""`` for the
interpolator itself), the drift and hyperparameters its fit started from, so that loading
repeats that fit.

Format 7 moves a super-resolved basis's fine grid out of ``SPEC``'s ``stamppca`` entry (JSON
text) into the images ``BASIS_FINE_MEAN`` (S, S) and ``BASIS_FINE_COMPONENTS`` (k, S, S):
written as text, the grid of 35-pixel stamps sampled 3 times finer took 10 s to save (a
2.5-million-character column) and as long to read; files of formats 1-6 are read as before.
"""

from __future__ import annotations

import copy
import datetime
import importlib
import json
import os
import warnings
from typing import NamedTuple

import numpy as np
from astropy.io import fits
from astropy.table import Table
from astropy.utils.exceptions import AstropyUserWarning
from sklearn.base import BaseEstimator
from sklearn.pipeline import Pipeline
from sklearn.utils.validation import check_is_fitted

from .._files import one_line, write_fits_atomic
from .._version import __version__

__all__ = ["save_model", "read_model", "read_model_validation", "MODEL_FORMAT",
           "MODEL_FORMAT_VERSION"]

#: Value of the ``SKPSFFMT`` keyword of a model file.
MODEL_FORMAT = "SKPSF-MODEL"
#: Format version written by this version of the package (``FORMAT`` keyword), for PSF
#: model files and multi-exposure model files alike (the PSF model reader refuses the latter,
#: which carry ``MULTIEXP``).
MODEL_FORMAT_VERSION = 8
_KNOWN_FORMATS = (1, 2, 3, 4, 5, 6, 7, 8)
_ALLOWED_MODULES = ("sklearn", "sklearn_psf")
_INLINE = 16  # arrays of at most this many values are written in the JSON


# ----------------------------------------------------------------------------- descriptions
def _public_path(cls):
    """'package.Class' with the shortest public module exposing the class."""
    module = cls.__module__
    parts = module.split(".")
    for i in range(1, len(parts) + 1):
        candidate = ".".join(parts[:i])
        if any(p.startswith("_") for p in parts[:i]):
            break
        try:
            if getattr(importlib.import_module(candidate), cls.__name__, None) is cls:
                return f"{candidate}.{cls.__name__}"
        except ImportError:  # pragma: no cover
            break
    return f"{module}.{cls.__name__}"


class _Step(NamedTuple):
    """A pipeline's step (name, estimator), whose arrays are named after the step."""

    name: str
    step: object


def _array_name(path, arrays):
    """A unique EXTNAME for the array at ``path`` (its keys, trailing ``_`` dropped)."""
    base = "_".join(str(p).rstrip("_") for p in path).upper()[:48] or "ARRAY"
    name, i = base, 1
    while name in arrays or name in _RESERVED_NAMES:
        name, i = f"{base}_{i}", i + 1
    return name


_RESERVED_NAMES = ("PRIMARY", "SPEC", "RESERVED", "RHO1")


def _encode(obj, arrays, where, fitted=False, path=()):
    """JSON description of ``obj``; arrays of more than ``_INLINE`` values go to ``arrays``
    (EXTNAME -> array). A ``fitted`` estimator gets its state (``_get_state``), its
    parameters are described unfitted (a pipeline's steps fitted)."""
    if obj is None or isinstance(obj, (bool, str, int, float)):
        return obj
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        ref = {"__array__": None, "dtype": obj.dtype.str, "shape": list(obj.shape)}
        if obj.size <= _INLINE:
            return {**ref, "values": obj.ravel().tolist()}
        same = [n for n, a in arrays.items() if a.dtype == obj.dtype and a.shape == obj.shape
                and np.array_equal(a, obj, equal_nan=True)]  # (written once)
        name = same[0] if same else _array_name(path, arrays)
        arrays[name] = obj
        return {**ref, "__array__": name}
    if isinstance(obj, _Step):
        return {"__tuple__": [obj.name, _encode(obj.step, arrays, obj.name, fitted,
                                                path[:-2] + (obj.name,))]}
    if isinstance(obj, (tuple, list)):
        items = [_encode(v, arrays, where, fitted, path + (i,)) for i, v in enumerate(obj)]
        return {"__tuple__": items} if isinstance(obj, tuple) else items
    if isinstance(obj, dict):
        return {"__dict__": {str(k): _encode(v, arrays, where, fitted, path + (k,))
                             for k, v in obj.items()}}
    if isinstance(obj, BaseEstimator):
        name = _public_path(type(obj))
        if name.split(".")[0] not in _ALLOWED_MODULES:
            raise ValueError(
                f"Cannot store the {where} {type(obj).__name__} (module {type(obj).__module__}) "
                "in a model file: only scikit-learn and sklearn_psf estimators are described "
                "there. Save this model with joblib.dump instead."
            )
        # (the state first: its arrays get the plain names)
        state = ({k: _encode(v, arrays, k.rstrip("_"), True, path + (k,))
                  for k, v in obj._get_state().items()}
                 if fitted and hasattr(obj, "_get_state") else None)
        params = obj.get_params(deep=False)
        if isinstance(obj, Pipeline):  # a fitted pipeline's steps are fitted; by their names
            params["steps"] = [_Step(n, s) for n, s in params["steps"]]
        out = {"__estimator__": name, "params": {
            k: _encode(v, arrays, k, fitted and isinstance(obj, Pipeline), path + (k,))
            for k, v in params.items()}}
        return out if state is None else {**out, "state": state}
    raise ValueError(
        f"Cannot store a parameter of type {type(obj).__name__} of the {where} in a model "
        "file; save this model with joblib.dump instead."
    )


def _decode(obj, arrays):
    """The object of an :func:`_encode` description (files of every format); a described
    state is restored by the estimator's ``_set_state``."""
    if isinstance(obj, list):
        return [_decode(v, arrays) for v in obj]
    if not isinstance(obj, dict):
        return obj
    if "__array__" in obj:
        ref = obj["__array__"]
        if ref is None:
            return np.array(obj["values"], dtype=obj["dtype"]).reshape(obj["shape"])
        value = np.array(arrays[ref], copy=True)
        return value.astype(obj["dtype"]).reshape(obj["shape"]) if "dtype" in obj else value
    if "__tuple__" in obj:
        return tuple(_decode(v, arrays) for v in obj["__tuple__"])
    if "__dict__" in obj:
        return {k: _decode(v, arrays) for k, v in obj["__dict__"].items()}
    if "__estimator__" in obj:
        path = str(obj["__estimator__"])
        module, _, name = path.rpartition(".")
        if module.split(".")[0] not in _ALLOWED_MODULES:
            raise ValueError(f"The model file names the estimator {path!r}, outside "
                             "scikit-learn and sklearn_psf: refusing to import it.")
        try:
            cls = getattr(importlib.import_module(module), name)
        except (ImportError, AttributeError):
            raise ValueError(
                f"The model file needs the estimator {path!r}, which this installation does "
                "not provide (a different scikit-learn or sklearn_psf version?)."
            ) from None
        params = {k: _decode(v, arrays) for k, v in obj["params"].items()}
        try:
            estimator = cls(**params)
        except TypeError as exc:
            raise ValueError(f"Cannot rebuild {path} from the model file: {exc}.") from None
        if "state" in obj:
            estimator._set_state({k: _decode(v, arrays) for k, v in obj["state"].items()})
        return estimator
    raise ValueError(f"Unknown entry in the model file's description: {obj!r}.")


def _json_default(obj):
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    return str(obj)


def _persistent_basis(basis):
    """The fitted basis with each part writing its state: a linear scikit-learn step (PCA
    without whitening) becomes the fitted :class:`FixedBasis` of its mean and components;
    any other part without state cannot be stored."""
    from ..preprocessing import FixedBasis

    if isinstance(basis, Pipeline):
        stored = copy.copy(basis)
        stored.steps = [(name, step if step is None or isinstance(step, str)
                         else _persistent_basis(step)) for name, step in basis.steps]
        return stored
    if hasattr(basis, "_get_state"):
        return basis
    comps, mean = getattr(basis, "components_", None), getattr(basis, "mean_", None)
    linear = comps is not None and mean is not None and not getattr(basis, "whiten", False)
    if linear:
        comps = np.asarray(comps, dtype=np.float64).reshape(len(comps), -1)
        mean = np.asarray(mean, dtype=np.float64).reshape(-1)
        # the rebuilt basis must give the same stamps: inverse_transform on a probe
        probe = np.random.default_rng(0).normal(size=(3, comps.shape[0]))
        linear = comps.shape[1] == mean.size and np.allclose(
            basis.inverse_transform(probe), probe @ comps + mean, rtol=1e-12, atol=1e-15)
    if not linear:
        raise ValueError(
            "save_model stores a sklearn_psf basis (StampPCA, SuperResolvedPCA, "
            "StampNormalizer steps and a FixedBasis) or a linear basis (PCA without "
            f"whitening); this model's basis has a {type(basis).__name__}. Save it with "
            "joblib.dump instead.")
    return FixedBasis(comps, mean)._set_state({
        "components_": comps, "mean_": mean, "n_components_": len(comps),
        "n_features_in_": mean.size})


def _spec_hdus(entries, arrays, prefix=""):
    """The ``SPEC`` table of JSON ``entries`` and the image HDUs of ``arrays``."""
    rows = [(key, json.dumps(value, default=_json_default, allow_nan=True))
            for key, value in entries.items()]
    spec = fits.table_to_hdu(Table({"key": [r[0] for r in rows], "json": [r[1] for r in rows]}))
    spec.name = f"{prefix}SPEC"
    images = [fits.ImageHDU(np.asarray(a, dtype=np.uint8) if a.dtype == bool else a,
                            name=name) for name, a in arrays.items()]
    return [spec, *images]


def _versions():
    import astropy
    import sklearn

    return {"sklearn_psf": __version__, "numpy": np.__version__,
            "scikit-learn": sklearn.__version__, "astropy": astropy.__version__}


def _describe(model, where, summary=None):
    """(SPEC entries, arrays) of a fitted model (its basis made persistent)."""
    arrays = {}
    entries = {"model": _encode(model, arrays, where, fitted=True), "versions": _versions()}
    if summary is not None:
        entries["validation_summary"] = summary
    return entries, arrays


def _stored(model):
    """A shallow copy of a fitted PSFModel whose basis writes its state."""
    if not all(hasattr(model, name) for name in ("basis", "interpolator", "outliers")):
        raise TypeError(f"save_model needs a PSFModel, got {type(model).__name__}.")
    check_is_fitted(model)
    if not hasattr(model, "coefficients_"):
        raise ValueError("This PSFModel was fitted by an older sklearn_psf without the stars' "
                         "coefficients (coefficients_): refit it, or use joblib.dump.")
    stored = copy.copy(model)
    stored.basis_ = _persistent_basis(model.basis_)
    return stored


def _primary(**cards):
    primary = fits.PrimaryHDU()
    h = primary.header
    h["SKPSFFMT"] = (MODEL_FORMAT, "sklearn_psf PSF model file")
    h["FORMAT"] = (MODEL_FORMAT_VERSION, "format version of this model file")
    h["SKPSFVER"] = (__version__, "sklearn_psf version that wrote the file")
    for key, value in cards.items():
        h[key] = value
    h["DATE"] = (datetime.datetime.now(datetime.timezone.utc).strftime(
        "%Y-%m-%dT%H:%M:%S"), "UTC time of writing")
    return primary


def _model_cards(model):
    interp = model.interpolator_
    last = interp.steps[-1][1] if isinstance(interp, Pipeline) else interp
    return {"STAMPSZ": (int(model.stamp_size_), "stamp side in pixels"),
            "NCOMP": (int(model.n_components_), "number of basis components"),
            "NSTARS": (len(model.inlier_mask_), "stars given to fit"),
            "NINLIER": (int(np.sum(model.inlier_mask_)), "stars kept for the interpolation"),
            "INTERP": (type(last).__name__, "interpolator of the coefficients")}


# ----------------------------------------------------------------------------- save
def save_model(model, path, *, residuals=None, summary=None, overwrite: bool = False) -> None:
    """Write a fitted :class:`~sklearn_psf.model.PSFModel` to a FITS file.

    The file format is described in :mod:`sklearn_psf.model` (module ``_file``; and the user guide):
    primary header with ``SKPSFFMT = 'SKPSF-MODEL'`` and ``FORMAT`` (version), a ``SPEC``
    table holding the model's parameters and fitted state (that of its basis, outlier
    detector and interpolator), its arrays as images (``BASIS_MEAN``, ``X_FIT``,
    ``COEFFICIENTS``...) and, optionally, the reserved-star residuals (``RESERVED``) and
    their rho1 (``RHO1``). The file is written to a temporary file in the same folder, then
    renamed: never left half-written.

    Parameters
    ----------
    model : PSFModel
        Fitted model whose basis is a sklearn_psf basis (or pipeline of them, a PCA without
        whitening standing for a FixedBasis) and whose interpolator/outlier detector are
        scikit-learn or sklearn_psf estimators (use joblib for anything else).
    path : str or os.PathLike
    residuals : astropy.table.Table, optional
        Reserved-star residuals.
    summary : dict, optional
        Validation summary (JSON-able values; a ``rho1`` entry with ``theta``, ``xi``,
        ``sigma_xi``, ``npairs`` becomes the ``RHO1`` table).
    overwrite : bool, default=False

    Raises
    ------
    ValueError
        For an unfitted model or parts that cannot be described in the file.
    FileExistsError
        When ``path`` exists and ``overwrite`` is False.

    Examples
    --------
    >>> import os, tempfile
    >>> import numpy as np
    >>> from astropy.io import fits
    >>> from sklearn_psf.model import save_model
    >>> from sklearn_psf.model import PSFModel
    >>> from sklearn_psf.interpolate import PolynomialRegressor
    >>> rng = np.random.default_rng(0)
    >>> X = rng.uniform(0, 1000, (40, 2))
    >>> yy, xx = np.mgrid[0:11, 0:11] - 5.0
    >>> y = np.exp(-0.5 * (xx.ravel() ** 2 + yy.ravel() ** 2) / (1.5 + X[:, :1] / 1e3) ** 2)
    >>> model = PSFModel(interpolator=PolynomialRegressor(degree=2), outliers=None).fit(X, y)
    >>> path = os.path.join(tempfile.mkdtemp(), "psf.fits")
    >>> save_model(model, path)
    >>> fits.getheader(path)["FORMAT"], [h.name for h in fits.open(path)][1:3]
    (8, ['SPEC', 'BASIS_MEAN'])
    """
    stored = _stored(model)
    hdus = [_primary(**_model_cards(stored)),
            *_spec_hdus(*_describe(stored, "model", summary))]
    if residuals is not None:
        res = fits.table_to_hdu(Table(residuals))
        res.name = "RESERVED"
        hdus.append(res)
    if summary is not None and isinstance(summary.get("rho1"), dict):
        r = summary["rho1"]
        rho = fits.table_to_hdu(Table({key: np.asarray(r[key], dtype=np.float64)
                                       for key in ("theta", "xi", "sigma_xi", "npairs")
                                       if key in r}))
        rho.name = "RHO1"
        hdus.append(rho)
    write_fits_atomic(fits.HDUList(hdus), path, overwrite=overwrite)


# ----------------------------------------------------------------------------- load
class _ModelFileError(ValueError):
    pass


def _open_checked(path):
    """Read every HDU of a model file into memory; clear ValueErrors for bad files."""
    path = os.fspath(path)
    if not os.path.exists(path):
        raise ValueError(f"Model file {path!r} does not exist.")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", AstropyUserWarning)  # "may have been truncated"
            with fits.open(path, memmap=False, lazy_load_hdus=False) as hdul:
                hdul.verify("exception")
                header = hdul[0].header.copy()
                if header.get("SKPSFFMT") != MODEL_FORMAT:
                    raise _ModelFileError(
                        f"{path!r} is not a sklearn_psf PSF model file (no SKPSFFMT = "
                        f"'{MODEL_FORMAT}' keyword in its primary header); write one with "
                        "PSFModel.save or 'sklearn-psf fit'."
                    )
                content = {}
                for h in hdul[1:]:
                    if isinstance(h, (fits.BinTableHDU, fits.TableHDU)):
                        content[h.name] = Table.read(h)
                    else:
                        content[h.name] = np.array(h.data, dtype=np.float64)
                return header, content
    except _ModelFileError:
        raise
    except (OSError, TypeError, KeyError, IndexError, ValueError, EOFError, fits.VerifyError,
            AstropyUserWarning) as exc:
        raise ValueError(
            f"Could not read the model file {path!r} ({type(exc).__name__}: "
            f"{one_line(exc)}); the file "
            "is corrupt or truncated: write it again."
        ) from None


def _check_format(header, path):
    version = header.get("FORMAT")
    if not isinstance(version, (int, np.integer)) or isinstance(version, bool):
        raise ValueError(f"{path!r} has no integer FORMAT keyword: not a valid model file.")
    version = int(version)
    if version > MODEL_FORMAT_VERSION:
        raise ValueError(
            f"{path!r} is a model file of format version {version}, written by sklearn_psf "
            f"{header.get('SKPSFVER', '?')}; this sklearn_psf reads format versions up to "
            f"{MODEL_FORMAT_VERSION}: upgrade sklearn_psf to read it."
        )
    if version not in _KNOWN_FORMATS:
        raise ValueError(
            f"{path!r} has format version {version}, which no sklearn_psf release wrote "
            f"(known versions: {list(_KNOWN_FORMATS)}): the file is damaged or not a model file."
        )
    return version


def _read_state(content, path, model_class):
    """The fitted ``model_class`` described by the ``SPEC`` of a file of format 8."""
    try:
        spec = {str(k): json.loads(str(v))
                for k, v in zip(content["SPEC"]["key"], content["SPEC"]["json"])}
        description = spec["model"]
        name = description["__estimator__"].rpartition(".")[2]
    except (KeyError, ValueError, TypeError, AttributeError) as exc:
        raise ValueError(f"The model file {path!r} is incomplete (missing or damaged {exc}): "
                         "write it again.") from None
    if name not in [cls.__name__ for cls in model_class.__mro__]:
        raise ValueError(f"{path!r} holds a {name}, not a {model_class.__name__}.")
    try:  # (the class asked for: a subclass of the one saved)
        params = {k: _decode(v, content) for k, v in description["params"].items()}
        state = {k: _decode(v, content) for k, v in description["state"].items()}
        return model_class(**params)._set_state(state)
    except KeyError as exc:
        raise ValueError(f"The model file {path!r} is incomplete (missing or damaged {exc}): "
                         "write it again.") from None


def read_model(path, model_class):
    """Read a PSF model file written by :func:`save_model` into a ``model_class`` instance.

    The implementation of :func:`sklearn_psf.model.load_model` / ``PSFModel.load``.

    Files of every known format version (``FORMAT`` keyword, see
    :data:`MODEL_FORMAT_VERSION`) load; a newer or unknown version fails with a message
    naming the version and what to do.

    Parameters
    ----------
    path : str or os.PathLike
    model_class : type
        :class:`~sklearn_psf.model.PSFModel`.

    Returns
    -------
    model : PSFModel
        Fitted; predictions are identical to the saved model's.
    """
    path = os.fspath(path)
    header, content = _open_checked(path)
    if "MULTIEXP" in header:
        raise ValueError(f"{path!r} holds a multi-exposure model ({header['MULTIEXP']}): load "
                         "it with PooledPSFModel.load or PerExposurePSFModel.load.")
    version = _check_format(header, path)
    if version < 8:
        from ._file_legacy import read_legacy

        return read_legacy(header, content, path, model_class, version)
    return _read_state(content, path, model_class)


# ----------------------------------------------------------------------------- many exposures
def save_exposure_model(model, path, *, overwrite: bool = False) -> None:
    """Write a fitted multi-exposure model to a FITS model file.

    The implementation of ``PooledPSFModel.save`` and ``PerExposurePSFModel.save``: the
    container of :func:`save_model`, whose ``SPEC`` ``model`` entry describes the
    multi-exposure model (its PSF models in its state); the primary header has ``MULTIEXP``
    (``"pooled"`` or ``"per-exposure"``), ``EXPCOL`` (the model's ``exposure_column``),
    ``NFEAT`` (its number of input columns) and ``STAMPSZ``.

    Parameters
    ----------
    model : PooledPSFModel or PerExposurePSFModel
        Fitted.
    path : str or os.PathLike
    overwrite : bool, default=False
    """
    check_is_fitted(model)
    stored = copy.copy(model)
    if hasattr(model, "models_"):
        kind, models = "per-exposure", [_stored(m) for m in model.models_]
        stored.models_ = models
    else:
        kind, models = "pooled", [_stored(model.model_)]
        stored.model_ = models[0]
    cards = {"MULTIEXP": (kind, "one PSF model per exposure" if kind == "per-exposure"
                          else "one PSF model over all exposures"),
             "EXPCOL": (int(model.exposure_column), "column of X holding the exposure"),
             "NFEAT": (int(model.n_features_in_), "columns of X (positions and exposure)"),
             "STAMPSZ": _model_cards(models[0])["STAMPSZ"]}
    hdus = [_primary(**cards), *_spec_hdus(*_describe(stored, "model"))]
    write_fits_atomic(fits.HDUList(hdus), path, overwrite=overwrite)


def read_exposure_model(path, model_class, psf_class):
    """Read a file written by :func:`save_exposure_model` into a ``model_class`` instance.

    Parameters
    ----------
    path : str or os.PathLike
    model_class : type
        :class:`~sklearn_psf.model.PooledPSFModel` or
        :class:`~sklearn_psf.model.PerExposurePSFModel`, matching the file's ``MULTIEXP``.
    psf_class : type
        :class:`~sklearn_psf.model.PSFModel`.

    Returns
    -------
    model : fitted ``model_class``
    """
    path = os.fspath(path)
    header, content = _open_checked(path)
    version = _check_format(header, path)
    kind = header.get("MULTIEXP")
    wanted = "per-exposure" if "PerExposure" in model_class.__name__ else "pooled"
    if kind != wanted:
        how = {None: "load_model", "pooled": "PooledPSFModel.load",
               "per-exposure": "PerExposurePSFModel.load"}.get(kind, "the matching class")
        held = "a single PSFModel" if kind is None else f"a {kind} model"
        raise ValueError(f"{path!r} holds {held}, not a {wanted} model: load it with {how}.")
    if version < 8:
        from ._file_legacy import read_legacy_exposure

        return read_legacy_exposure(header, content, path, model_class, psf_class, version)
    return _read_state(content, path, model_class)


def read_model_validation(path):
    """The reserved-star residuals and validation summary stored in a model file.

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    residuals : astropy.table.Table or None
        The ``RESERVED`` table (None when the model was saved without validation).
    summary : dict or None
        The validation summary.

    Examples
    --------
    >>> from sklearn_psf.model import read_model_validation
    >>> read_model_validation  # doctest: +ELLIPSIS
    <function read_model_validation at ...>
    """
    header, content = _open_checked(path)
    _check_format(header, os.fspath(path))
    residuals = content.get("RESERVED")
    summary = None
    spec = content.get("SPEC")
    if spec is not None:
        for key, value in zip(spec["key"], spec["json"]):
            if str(key) == "validation_summary":
                summary = json.loads(str(value))
    return residuals, summary
