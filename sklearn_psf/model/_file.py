"""PSF model files: a self-describing FITS format, written atomically.

Format (``SKPSFFMT = 'SKPSF-MODEL'``, ``FORMAT = 1``)
---------------------------------------------------
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

Loading rebuilds the basis (``StampNormalizer`` steps + a fitted :class:`FixedBasis` of the
stored mean and components, or the ``StampPCA``) and refits the interpolator (with the
stored hyperparameters and coefficient noise) and the outlier detector on the stored stars:
our interpolators are deterministic, so predictions are identical to the saved model's, and
the file does not depend on pickled internals of any library version.
"""

from __future__ import annotations

import datetime
import functools
import importlib
import json
import os
import warnings

import numpy as np
from astropy.io import fits
from astropy.table import Table
from astropy.utils.exceptions import AstropyUserWarning
from sklearn.base import BaseEstimator, clone
from sklearn.pipeline import Pipeline, make_pipeline
from sklearn.preprocessing import MinMaxScaler

from .._files import one_line, write_fits_atomic
from ..interpolate import ExposureKrigingRegressor
from .._version import __version__
from ._defaults import _constant_interpolator, make_default_interpolator
from ._noise import fit_interpolator, kriging_steps

__all__ = ["save_model", "read_model", "read_model_validation", "MODEL_FORMAT",
           "MODEL_FORMAT_VERSION"]

#: Value of the ``SKPSFFMT`` keyword of a model file.
MODEL_FORMAT = "SKPSF-MODEL"
#: Format version written by this version of the package (``FORMAT`` keyword), for PSF
#: model files and multi-exposure model files alike (the PSF model reader refuses the latter,
#: which carry ``MULTIEXP``).
MODEL_FORMAT_VERSION = 7
_ALLOWED_MODULES = ("sklearn", "sklearn_psf")


# ----------------------------------------------------------------------------- estimator specs
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


def _encode(obj, arrays, where):
    if obj is None or isinstance(obj, (bool, str)):
        return obj
    if isinstance(obj, (int, float)):
        return obj
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        arrays.append(np.asarray(obj))
        return {"__array__": len(arrays) - 1}
    if isinstance(obj, tuple):
        return {"__tuple__": [_encode(v, arrays, where) for v in obj]}
    if isinstance(obj, list):
        return [_encode(v, arrays, where) for v in obj]
    if isinstance(obj, dict):
        return {"__dict__": {str(k): _encode(v, arrays, where) for k, v in obj.items()}}
    if isinstance(obj, BaseEstimator):
        path = _public_path(type(obj))
        if path.split(".")[0] not in _ALLOWED_MODULES:
            raise ValueError(
                f"Cannot store the {where} {type(obj).__name__} (module {type(obj).__module__}) "
                "in a model file: only scikit-learn and sklearn_psf estimators are described "
                "there. Save this model with joblib.dump instead."
            )
        params = obj.get_params(deep=False)
        return {"__estimator__": path,
                "params": {k: _encode(v, arrays, where) for k, v in params.items()}}
    raise ValueError(
        f"Cannot store a parameter of type {type(obj).__name__} of the {where} in a model "
        "file; save this model with joblib.dump instead."
    )


def _decode(obj, arrays):
    if isinstance(obj, list):
        return [_decode(v, arrays) for v in obj]
    if not isinstance(obj, dict):
        return obj
    if "__array__" in obj:
        return np.array(arrays[int(obj["__array__"])], copy=True)
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
            return cls(**params)
        except TypeError as exc:
            raise ValueError(f"Cannot rebuild {path} from the model file: {exc}.") from None
    raise ValueError(f"Unknown entry in the model file's description: {obj!r}.")


def _json_default(obj):
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (dict,)):
        return dict(obj)
    return str(obj)


# ----------------------------------------------------------------------------- the basis
def _leaf_steps(transformer):
    if isinstance(transformer, Pipeline):
        out = []
        for _, step in transformer.steps:
            if step is None or step == "passthrough":
                continue
            out.extend(_leaf_steps(step))
        return out
    return [transformer]


_STAMPPCA_STATE = ("explained_variance_", "noise_variance_", "noise_edge_", "background_")
_SUPERRES_STATE = ("oversampling_", "fine_size_", "fwhm_", "spatial_degree_", "band_limit_")
#: The super-resolved basis's fine grid: images of its own (format 7; in ``stamppca`` before).
_FINE_HDUS = {"fine_mean_": "BASIS_FINE_MEAN", "fine_components_": "BASIS_FINE_COMPONENTS"}


def _describe_basis(basis, s):
    """(kind, normalizer params, mean (p,), components (k, p), extra state) of a fitted basis.

    ``kind`` is ``"stamppca"`` for :class:`StampPCA`, ``"linear"`` for StampNormalizer steps
    and a linear basis (PCA without whitening, FixedBasis); anything else raises.
    """
    from ..preprocessing import StampNormalizer, StampPCA, SuperResolvedPCA

    if isinstance(basis, StampPCA):
        fine = isinstance(basis, SuperResolvedPCA)
        state = {name: np.asarray(getattr(basis, name)).tolist()
                 for name in _STAMPPCA_STATE + _SUPERRES_STATE * fine}
        return "superres" if fine else "stamppca", [], basis.mean_, basis.components_, state
    leaves = _leaf_steps(basis)
    *pre, last = leaves
    bad = [type(t).__name__ for t in pre if not isinstance(t, StampNormalizer)]
    comps = getattr(last, "components_", None)
    mean = getattr(last, "mean_", None)
    if bad or comps is None or mean is None or getattr(last, "whiten", False):
        raise ValueError(
            "save_model stores a StampPCA basis, or StampNormalizer steps and a linear basis "
            "(PCA without whitening, FixedBasis); this model's basis is "
            f"{[type(t).__name__ for t in leaves]}. Save it with joblib.dump instead."
        )
    comps = np.asarray(comps, dtype=np.float64).reshape(len(comps), -1)
    mean = np.asarray(mean, dtype=np.float64).reshape(-1)
    if comps.shape[1] != s * s or mean.size != s * s:
        raise ValueError("The basis's components do not match the stamp size.")
    # the rebuilt basis must give the same stamps: check inverse_transform on a probe
    probe = np.random.default_rng(0).normal(size=(3, comps.shape[0]))
    if not np.allclose(basis.inverse_transform(probe), probe @ comps + mean, rtol=1e-12,
                       atol=1e-15):
        raise ValueError("The model's basis is not linear (inverse_transform differs from "
                         "coefficients @ components + mean): save it with joblib.dump instead.")
    return "linear", [t.get_params(deep=False) for t in pre], mean, comps, {}


def _rebuild_basis(kind, normalizer_params, mean, comps, params, state):
    from ..preprocessing import FixedBasis, StampNormalizer, StampPCA, SuperResolvedPCA

    if kind in ("stamppca", "superres"):
        basis = (SuperResolvedPCA if kind == "superres" else StampPCA)(**params)
        s = int(round(np.sqrt(mean.size)))
        basis.mean_, basis.components_ = mean, comps
        basis.n_components_, basis.stamp_size_, basis.n_features_in_ = len(comps), s, s * s
        basis._n_features_out = len(comps)
        for name in _STAMPPCA_STATE:
            if name in state:  # files written before background_ existed: no background
                setattr(basis, name, np.asarray(state[name], dtype=np.float64)
                        if name == "explained_variance_" else float(state[name]))
        basis.background_ = bool(getattr(basis, "background_", False))
        if kind == "superres":
            basis.fine_mean_ = np.asarray(state["fine_mean_"], dtype=np.float64).reshape(-1)
            basis.fine_components_ = np.asarray(state["fine_components_"],
                                                dtype=np.float64).reshape(len(comps), -1)
            basis.oversampling_, basis.fine_size_ = (int(state["oversampling_"]),
                                                     int(state["fine_size_"]))
            basis.fwhm_ = float(state["fwhm_"])
            # (files written before the joint refinement: none ran)
            basis.spatial_degree_ = int(state.get("spatial_degree_", 0))
            # (files written before band_limit_ was recorded: the grid's Nyquist disc)
            basis.band_limit_ = float(state.get("band_limit_", basis.oversampling_ / 2.0))
        return basis
    steps = [(f"stampnormalizer{i or ''}", StampNormalizer(**p))
             for i, p in enumerate(normalizer_params)]
    steps.append(("fixedbasis", FixedBasis(comps, mean)))
    pipe = Pipeline(steps)
    return pipe.fit(mean.reshape(1, -1))


# ----------------------------------------------------------------------------- save
def save_model(model, path, *, residuals=None, summary=None, overwrite: bool = False) -> None:
    """Write a fitted :class:`~sklearn_psf.model.PSFModel` to a FITS file.

    The file format is described in :mod:`sklearn_psf.model` (module ``_file``; and the user guide):
    primary header with ``SKPSFFMT = 'SKPSF-MODEL'`` and ``FORMAT`` (version), a ``SPEC``
    table of JSON parameter descriptions, the basis (``BASIS_MEAN``, ``BASIS_COMPONENTS``),
    the fitted stars (``STARS``: positions, coefficients, inlier flag) and, optionally, the
    reserved-star residuals (``RESERVED``) and their rho1 (``RHO1``). The file is written to
    a temporary file in the same folder, then renamed: never left half-written.

    Parameters
    ----------
    model : PSFModel
        Fitted model whose basis is StampNormalizer steps + a linear basis (PCA without
        whitening or FixedBasis) and whose interpolator/outlier detector are scikit-learn or
        sklearn_psf estimators (use joblib for anything else).
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
    (7, ['SPEC', 'BASIS_MEAN'])
    """
    primary = fits.PrimaryHDU()
    h = primary.header
    h["SKPSFFMT"] = (MODEL_FORMAT, "sklearn_psf PSF model file")
    h["FORMAT"] = (MODEL_FORMAT_VERSION, "format version of this model file")
    h["SKPSFVER"] = (__version__, "sklearn_psf version that wrote the file")
    cards, hdus = _model_hdus(model, summary=summary)
    for key, value in cards.items():
        h[key] = value
    _stamp_date(h)
    hdus = [primary, *hdus]
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


def _stamp_date(header):
    header["DATE"] = (datetime.datetime.now(datetime.timezone.utc).strftime(
        "%Y-%m-%dT%H:%M:%S"), "UTC time of writing")


def _model_hdus(model, *, summary=None, prefix="", exposure=False):
    """(primary-header cards, HDUs) describing one fitted PSFModel; HDU names get ``prefix``.

    With ``exposure``, the model's positions end with an exposure column (stored as the STARS
    table's ``exposure``).
    """
    from sklearn.utils.validation import check_is_fitted

    if not all(hasattr(model, name) for name in ("basis", "interpolator", "outliers")):
        raise TypeError(f"save_model needs a PSFModel, got {type(model).__name__}.")
    check_is_fitted(model)
    if not hasattr(model, "coefficients_"):
        raise ValueError("This PSFModel was fitted by an older sklearn_psf without the stars' "
                         "coefficients (coefficients_): refit it, or use joblib.dump.")
    d = model.X_fit_.shape[1]
    if (d != 3) if exposure else (d < 2):
        raise ValueError(f"Model files hold (x, y) star positions{' and an exposure' * exposure}"
                         f"; this model was fitted on {model.X_fit_.shape[1]} position columns: "
                         "use joblib.dump.")
    s, k = int(model.stamp_size_), int(model.n_components_)
    kind, normalizers, mean, comps, state = _describe_basis(model.basis_, s)
    arrays = []
    spec = {
        "interpolator": _encode(model.interpolator, arrays, "interpolator"),
        "basis_kind": kind,
        "stamppca": state,
        "basis_params": _encode(model.basis_.get_params(deep=False)
                                if kind in ("stamppca", "superres")
                                else {}, arrays, "basis"),
        "basis": _encode(model.basis, arrays, "basis"),
        "outliers": _encode(model.outliers, arrays, "outlier detector"),
        "normalizers": [{k2: _encode(v, arrays, "normalizer") for k2, v in p.items()}
                        for p in normalizers],
        "versions": _versions(),
    }
    starts = {key: step._start_state() for key, step in kriging_steps(model.interpolator_)}
    starts = {key: state for key, state in starts.items() if state is not None}
    if starts:
        spec["warm_starts"] = starts
    if getattr(model, "spatial_model_", "interpolator") != "interpolator":
        spec["spatial_model"] = model.spatial_model_  # too few stars: a constant PSF
    if summary is not None:
        spec["validation_summary"] = summary
    rows = [(key, json.dumps(value, default=_json_default, allow_nan=True))
            for key, value in spec.items()]
    interp = model.interpolator_
    last = interp.steps[-1][1] if isinstance(interp, Pipeline) else interp
    cards = {"STAMPSZ": (s, "stamp side in pixels"),
             "NCOMP": (k, "number of basis components"),
             "NSTARS": (len(model.inlier_mask_), "stars given to fit"),
             "NINLIER": (int(np.sum(model.inlier_mask_)), "stars kept for the interpolation"),
             "INTERP": (type(last).__name__, "interpolator of the coefficients")}
    spec_hdu = fits.table_to_hdu(Table({"key": [r[0] for r in rows],
                                        "json": [r[1] for r in rows]}))
    spec_hdu.name = f"{prefix}SPEC"
    hdus = [spec_hdu,
            fits.ImageHDU(mean.reshape(s, s), name=f"{prefix}BASIS_MEAN"),
            fits.ImageHDU(comps.reshape(k, s, s), name=f"{prefix}BASIS_COMPONENTS")]
    if kind == "superres":
        size = int(model.basis_.fine_size_)
        fine = {"fine_mean_": model.basis_.fine_mean_.reshape(size, size),
                "fine_components_": model.basis_.fine_components_.reshape(-1, size, size)}
        hdus += [fits.ImageHDU(np.asarray(fine[name], dtype=np.float64), name=prefix + hdu)
                 for name, hdu in _FINE_HDUS.items()]
    columns = {
        "x": np.asarray(model.X_fit_[:, 0], dtype=np.float64),
        "y": np.asarray(model.X_fit_[:, 1], dtype=np.float64),
        "coeffs": np.asarray(model.coefficients_, dtype=np.float64).reshape(-1, k),
        "inlier": np.asarray(model.inlier_mask_, dtype=bool),
        "fit_flag": np.asarray(model.fit_flag_, dtype=np.int64),
    }
    if exposure:
        columns["exposure"] = np.asarray(model.X_fit_[:, 2], dtype=np.int64)
    elif d > 2:  # the model's extra dimensions (colour, magnitude...), in fit's order
        columns["extra"] = np.asarray(model.X_fit_[:, 2:], dtype=np.float64)
    if model.coefficient_var_ is not None:
        columns["coeff_var"] = np.asarray(model.coefficient_var_, dtype=np.float64).reshape(-1, k)
    if getattr(model, "coefficient_cov_", None) is not None:
        columns["coeff_cov"] = np.asarray(model.coefficient_cov_,
                                          dtype=np.float64).reshape(-1, k * k)
    if model.outlier_score_ is not None:
        columns["outlier_score"] = np.asarray(model.outlier_score_, dtype=np.float64)
    stars = fits.table_to_hdu(Table(columns))
    stars.name = f"{prefix}STARS"
    hdus.append(stars)
    for i, arr in enumerate(arrays):
        hdus.append(fits.ImageHDU(np.asarray(arr), name=f"{prefix}ARRAY_{i}"))
    return cards, hdus


def _versions():
    import astropy
    import sklearn


    return {"sklearn_psf": __version__, "numpy": np.__version__,
            "scikit-learn": sklearn.__version__, "astropy": astropy.__version__}


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
    if version not in _READERS:
        raise ValueError(
            f"{path!r} has format version {version}, which no sklearn_psf release wrote "
            f"(known versions: {sorted(_READERS)}): the file is damaged or not a model file."
        )
    return version


def _default_interpolator(version):
    """The default interpolator that a file of format ``version`` was fitted with."""
    interp = make_default_interpolator()
    if version < 5:  # formats 1-4: a constant mean (drift=None)
        interp.set_params(krigingregressor__drift=None)
    if version >= 4:
        return interp
    # formats 1-3: the same Kriging on positions scaled by MinMaxScaler
    return make_pipeline(MinMaxScaler(), interp[-1])


def _read(header, content, path, model_class, version):
    """Every format (format 1: linear basis, no noise, interpolator refitted as given)."""
    try:
        spec_table = content["SPEC"]
        spec = {str(k): json.loads(str(v)) for k, v in zip(spec_table["key"], spec_table["json"])}
        mean = np.asarray(content["BASIS_MEAN"], dtype=np.float64).reshape(-1)
        comps = np.asarray(content["BASIS_COMPONENTS"], dtype=np.float64)
        stars = content["STARS"]
        s, k = int(header["STAMPSZ"]), int(header["NCOMP"])
    except (KeyError, ValueError, TypeError) as exc:
        raise ValueError(f"The model file {path!r} is incomplete (missing or damaged {exc}): "
                         "write it again.") from None
    comps = comps.reshape(k, s * s)
    arrays = [content[f"ARRAY_{i}"] for i in range(len([n for n in content
                                                        if n.startswith("ARRAY_")]))]
    interpolator = _decode(spec["interpolator"], arrays)
    model = model_class(interpolator=interpolator, basis=_decode(spec["basis"], arrays),
                        outliers=_decode(spec["outliers"], arrays))
    X = np.column_stack([np.asarray(stars[c], dtype=np.float64).reshape(len(stars), -1)
                         for c in ("x", "y", "exposure", "extra") if c in stars.colnames])
    n = len(X)
    coef = np.asarray(stars["coeffs"], dtype=np.float64).reshape(n, k)
    mask = np.asarray(stars["inlier"], dtype=bool)
    var = (np.asarray(stars["coeff_var"], dtype=np.float64).reshape(n, k)
           if "coeff_var" in stars.colnames else None)
    cov = (np.asarray(stars["coeff_cov"], dtype=np.float64).reshape(n, k, k)
           if "coeff_cov" in stars.colnames else None)
    # the model's own fit path, minus the basis: same interpolator, same data
    detector = model._make_outliers()
    if detector is not None:
        detector.fit(coef[np.isfinite(coef).all(axis=1)])
    interp = _default_interpolator(version) if interpolator is None else clone(interpolator)
    spatial = spec.get("spatial_model", "interpolator")
    if spatial == "constant":
        interp = _constant_interpolator()
    if version < 4 and isinstance(interp, ExposureKrigingRegressor):
        interp._per_axis_scaling = True  # as fitted then: each axis scaled to [0, 1]
    # (format 6: a fit that started from the previous outlier round's hyperparameters
    # starts from them again)
    steps = dict(kriging_steps(interp))
    given = {key: step.warm_start for key, step in steps.items()}
    for key, state in spec.get("warm_starts", {}).items():
        steps[key]._set_start_state(state)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # warnings were already shown when the model was fitted
        fit_interpolator(interp, X[mask], coef[mask], None if var is None else var[mask],
                         None if cov is None else cov[mask])
    for key in spec.get("warm_starts", {}):
        steps[key].warm_start = given[key]
    normalizers = [{key: _decode(v, arrays) for key, v in p.items()}
                   for p in spec["normalizers"]]
    model.basis_ = _rebuild_basis(spec.get("basis_kind", "linear"), normalizers, mean, comps,
                                  _decode(spec.get("basis_params", {}), arrays) or {},
                                  {**spec.get("stamppca", {}),
                                   **{name: content[hdu] for name, hdu in _FINE_HDUS.items()
                                      if hdu in content}})
    model.outliers_ = detector
    model.interpolator_ = interp
    model.inlier_mask_ = mask
    model.fit_flag_ = (np.asarray(stars["fit_flag"], dtype=np.int64)
                       if "fit_flag" in stars.colnames else np.zeros(n, dtype=np.int64))
    model.outlier_score_ = (np.asarray(stars["outlier_score"], dtype=np.float64)
                            if "outlier_score" in stars.colnames else None)
    model.n_components_ = k
    model.stamp_size_ = s
    model.n_features_in_ = X.shape[1]
    model.X_fit_ = X
    model.coefficients_ = coef
    model.coefficient_var_ = var
    model.coefficient_cov_ = cov
    model.spatial_model_ = spatial
    return model


_READERS = {v: functools.partial(_read, version=v) for v in (1, 2, 3, 4, 5, 6, 7)}


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
    return _READERS[version](header, content, path, model_class)


# ----------------------------------------------------------------------------- many exposures
def save_exposure_model(model, path, *, overwrite: bool = False) -> None:
    """Write a fitted multi-exposure model to a FITS model file (format 3).

    The implementation of ``PooledPSFModel.save`` and ``PerExposurePSFModel.save``. The
    primary header has ``MULTIEXP`` (``"pooled"`` or ``"per-exposure"``), ``EXPCOL`` (the
    model's ``exposure_column``) and ``NFEAT`` (its number of input columns).

    - pooled: the HDUs of its one :class:`PSFModel` (``model_``), whose ``STARS`` table has an
      ``exposure`` column when it was fitted on several exposures;
    - per-exposure: an ``EXPOSURES`` table (``exposure``, ``ncomp``) and, for exposure row
      ``i``, the HDUs of its model with names prefixed by ``E<i>_``.

    Loading refits each interpolator on the stored stars (deterministic), so the loaded model
    predicts exactly as the saved one.

    Parameters
    ----------
    model : PooledPSFModel or PerExposurePSFModel
        Fitted.
    path : str or os.PathLike
    overwrite : bool, default=False
    """
    from sklearn.utils.validation import check_is_fitted

    check_is_fitted(model)
    primary = fits.PrimaryHDU()
    h = primary.header
    h["SKPSFFMT"] = (MODEL_FORMAT, "sklearn_psf PSF model file")
    h["FORMAT"] = (MODEL_FORMAT_VERSION, "format version of this model file")
    h["SKPSFVER"] = (__version__, "sklearn_psf version that wrote the file")
    h["EXPCOL"] = (int(model.exposure_column), "column of X holding the exposure")
    h["NFEAT"] = (int(model.n_features_in_), "columns of X (positions and exposure)")
    if hasattr(model, "models_"):
        h["MULTIEXP"] = ("per-exposure", "one PSF model per exposure")
        table = fits.table_to_hdu(Table({
            "exposure": np.asarray(model.exposures_, dtype=np.int64),
            "ncomp": np.array([m.n_components_ for m in model.models_], dtype=np.int64)}))
        table.name = "EXPOSURES"
        hdus = [table]
        for i, m in enumerate(model.models_):
            cards, parts = _model_hdus(m, prefix=f"E{i}_")
            hdus += parts
    else:
        h["MULTIEXP"] = ("pooled", "one PSF model over all exposures")
        cards, hdus = _model_hdus(model.model_, exposure=len(model.exposures_) > 1)
        for key, value in cards.items():
            h[key] = value
        exposures = fits.table_to_hdu(Table({"exposure": np.asarray(model.exposures_,
                                                                    dtype=np.int64)}))
        exposures.name = "EXPOSURES"
        hdus.append(exposures)
    h["STAMPSZ"] = cards["STAMPSZ"]
    _stamp_date(h)
    write_fits_atomic(fits.HDUList([primary, *hdus]), path, overwrite=overwrite)


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
    try:
        exposures = np.asarray(content["EXPOSURES"]["exposure"], dtype=np.int64)
    except KeyError:
        raise ValueError(f"The model file {path!r} is incomplete (no EXPOSURES table): write "
                         "it again.") from None
    model = model_class(exposure_column=int(header["EXPCOL"]))
    if kind == "per-exposure":
        ncomp = np.asarray(content["EXPOSURES"]["ncomp"], dtype=np.int64)
        models = []
        for i, k in enumerate(ncomp):
            prefix = f"E{i}_"
            part = {name[len(prefix):]: value for name, value in content.items()
                    if name.startswith(prefix)}
            models.append(_READERS[version]({"STAMPSZ": header["STAMPSZ"], "NCOMP": int(k)},
                                            part, path, psf_class))
        model.models_ = models
        model.inlier_mask_ = np.concatenate([m.inlier_mask_ for m in models])
        model.set_params(model=_template(models[0], psf_class))
    else:
        inner = _READERS[version](header, content, path, psf_class)
        model.model_ = inner
        model.inlier_mask_ = inner.inlier_mask_
        model.n_components_ = inner.n_components_
        model.set_params(model=_template(inner, psf_class),
                         interpolator=inner.interpolator if len(exposures) > 1 else None)
    model.exposures_ = exposures
    model.n_features_in_ = int(header["NFEAT"])
    return model


def _template(model, psf_class):
    """The unfitted PSFModel template of a loaded model (its parameters but the interpolator)."""
    params = model.get_params(deep=False)
    params["interpolator"] = None
    return psf_class(**params)


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
