"""Readers of the model files of formats 1-7, written before the estimators stored their
own state (see :mod:`sklearn_psf.model._file` for those formats).

Such a file holds the basis's arrays and a description of its fitted attributes
(``SPEC``'s ``basis_kind``, ``stamppca``, ``normalizers``), the stars (``STARS``) and the
parameters of the interpolator and the outlier detector: the basis is restored from them
through its class's ``_set_state``; the interpolator, whose hyperparameters these files
do not hold, is fitted on the stored stars as it was (maximum likelihood included, from the
warm starts of format 6), and the outlier detector on the stored coefficients.
"""

from __future__ import annotations

import json

import numpy as np
from sklearn.base import clone
from sklearn.pipeline import Pipeline, make_pipeline
from sklearn.preprocessing import MinMaxScaler

from ..interpolate import ExposureKrigingRegressor
from ._defaults import _constant_interpolator, make_default_interpolator
from ._file import _decode
from ._noise import kriging_steps

#: the super-resolved basis's fine grid: images of its own (format 7; in ``stamppca`` before)
_FINE_HDUS = {"fine_mean_": "BASIS_FINE_MEAN", "fine_components_": "BASIS_FINE_COMPONENTS"}


def _default_interpolator(version):
    """The default interpolator that a file of format ``version`` was fitted with."""
    interp = make_default_interpolator()
    if version < 5:  # formats 1-4: a constant mean (drift=None)
        interp.set_params(krigingregressor__drift=None)
    if version >= 4:
        return interp
    # formats 1-3: the same Kriging on positions scaled by MinMaxScaler
    return make_pipeline(MinMaxScaler(), interp[-1])


def _basis(spec, content, arrays, mean, comps, k, s):
    """The fitted basis of a legacy file, of mean ``mean`` and components ``comps``."""
    from ..preprocessing import FixedBasis, StampNormalizer, StampPCA, SuperResolvedPCA

    mean = np.asarray(mean, dtype=np.float64).reshape(-1)
    comps = np.asarray(comps, dtype=np.float64).reshape(k, s * s)
    kind = spec.get("basis_kind", "linear")
    if kind in ("stamppca", "superres"):
        params = _decode(spec.get("basis_params", {}), arrays) or {}
        state = {**spec.get("stamppca", {}), "mean_": mean, "components_": comps,
                 "n_components_": k, "stamp_size_": s, "n_features_in_": s * s,
                 **{name: content[hdu] for name, hdu in _FINE_HDUS.items() if hdu in content}}
        cls = SuperResolvedPCA if kind == "superres" else StampPCA
        return cls(**params)._set_state(state)
    normalizers = [{key: _decode(v, arrays) for key, v in p.items()}
                   for p in spec["normalizers"]]
    steps = [(f"stampnormalizer{i or ''}", StampNormalizer(**p))
             for i, p in enumerate(normalizers)]
    steps.append(("fixedbasis", FixedBasis(comps, mean)))
    return Pipeline(steps).fit(mean.reshape(1, -1))


def read_legacy(header, content, path, model_class, version):
    """A ``model_class`` (PSFModel) from the HDUs of a file of format ``version`` (1-7)."""
    try:
        spec_table = content["SPEC"]
        spec = {str(k): json.loads(str(v)) for k, v in zip(spec_table["key"], spec_table["json"])}
        stars = content["STARS"]
        s, k = int(header["STAMPSZ"]), int(header["NCOMP"])
        mean, comps = content["BASIS_MEAN"], content["BASIS_COMPONENTS"]
    except (KeyError, ValueError, TypeError) as exc:
        raise ValueError(f"The model file {path!r} is incomplete (missing or damaged {exc}): "
                         "write it again.") from None
    arrays = {i: content[f"ARRAY_{i}"] for i in range(len([n for n in content
                                                           if n.startswith("ARRAY_")]))}
    interpolator = _decode(spec["interpolator"], arrays)
    model = model_class(interpolator=interpolator, basis=_decode(spec["basis"], arrays),
                        outliers=_decode(spec["outliers"], arrays))
    X = np.column_stack([np.asarray(stars[c], dtype=np.float64).reshape(len(stars), -1)
                         for c in ("x", "y", "exposure", "extra") if c in stars.colnames])
    n = len(X)
    columns = {"coefficient_var_": "coeff_var", "coefficient_cov_": "coeff_cov",
               "fit_flag_": "fit_flag", "outlier_score_": "outlier_score"}
    shapes = {"coeff_var": (n, k), "coeff_cov": (n, k, k), "fit_flag": (n,),
              "outlier_score": (n,)}
    state = {name: np.asarray(stars[col], dtype=np.int64 if col == "fit_flag" else
                              np.float64).reshape(shapes[col])
             for name, col in columns.items() if col in stars.colnames}
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
    for key, start in spec.get("warm_starts", {}).items():
        steps[key]._set_start_state(start)
    model._set_state({
        **state, "basis_": _basis(spec, content, arrays, mean, comps, k, s),
        "interpolator_": interp,
        "inlier_mask_": np.asarray(stars["inlier"], dtype=bool), "n_components_": k,
        "stamp_size_": s, "n_features_in_": X.shape[1], "X_fit_": X,
        "coefficients_": np.asarray(stars["coeffs"], dtype=np.float64).reshape(n, k),
        "spatial_model_": spatial})
    for key in spec.get("warm_starts", {}):
        steps[key].warm_start = given[key]
    return model


def read_legacy_exposure(header, content, path, model_class, psf_class, version):
    """A pooled or per-exposure model from a file of format ``version`` (3-7)."""
    try:
        exposures = np.asarray(content["EXPOSURES"]["exposure"], dtype=np.int64)
    except KeyError:
        raise ValueError(f"The model file {path!r} is incomplete (no EXPOSURES table): write "
                         "it again.") from None
    model = model_class(exposure_column=int(header["EXPCOL"]))
    if header.get("MULTIEXP") == "per-exposure":
        ncomp = np.asarray(content["EXPOSURES"]["ncomp"], dtype=np.int64)
        models = []
        for i, k in enumerate(ncomp):
            prefix = f"E{i}_"
            part = {name[len(prefix):]: value for name, value in content.items()
                    if name.startswith(prefix)}
            models.append(read_legacy({"STAMPSZ": header["STAMPSZ"], "NCOMP": int(k)},
                                      part, path, psf_class, version))
        model.set_params(model=_template(models[0], psf_class))
        return model._set_state({
            "models_": models, "exposures_": exposures, "n_features_in_": int(header["NFEAT"]),
            "inlier_mask_": np.concatenate([m.inlier_mask_ for m in models])})
    inner = read_legacy(header, content, path, psf_class, version)
    model.set_params(model=_template(inner, psf_class),
                     interpolator=inner.interpolator if len(exposures) > 1 else None)
    return model._set_state({
        "model_": inner, "exposures_": exposures, "inlier_mask_": inner.inlier_mask_,
        "n_components_": inner.n_components_, "n_features_in_": int(header["NFEAT"])})


def _template(model, psf_class):
    """The unfitted PSFModel template of a loaded model (its parameters but the interpolator)."""
    params = model.get_params(deep=False)
    params["interpolator"] = None
    return psf_class(**params)
