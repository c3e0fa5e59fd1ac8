"""Noise plumbing of PSFModel: routing per-star noise to interpolators, cross-predictions,
and standardised residuals for the chi^2 outlier test."""

from __future__ import annotations

import inspect

import numpy as np
from scipy import stats
from scipy.spatial import cKDTree
from sklearn import get_config
from sklearn.base import clone
from sklearn.model_selection import KFold
from sklearn.pipeline import Pipeline

from ..interpolate import KrigingRegressor

#: Quantile at which the model-error floors make residuals match pure noise: high enough
#: that heavy-tailed interpolation errors do not reject clean stars, low enough that up to
#: 20% of contaminated stars do not raise the floor.
_FLOOR_QUANTILE = 0.8


def _final_step(estimator):
    while isinstance(estimator, Pipeline):
        estimator = estimator.steps[-1][1]
    return estimator


def kriging_steps(interpolator):
    """(parameter path, step) of each KrigingRegressor in ``interpolator`` ("" for itself)."""
    found = [("", interpolator)] + list(interpolator.get_params(deep=True).items())
    return [(key, est) for key, est in found if isinstance(est, KrigingRegressor)]


def _step_path(estimator):
    """``"a__b__"`` prefix of the final step's parameters inside nested pipelines."""
    prefix = ""
    while isinstance(estimator, Pipeline):
        name, estimator = estimator.steps[-1]
        prefix += f"{name}__"
    return prefix


def accepts_noise(estimator, name="noise_var") -> bool:
    """Whether the (final step of the) interpolator's ``fit`` takes ``name``
    (``noise_var`` or ``noise_cov``)."""
    fit = getattr(_final_step(estimator), "fit", None)
    return fit is not None and name in inspect.signature(fit).parameters


def fit_interpolator(interpolator, X, coef, noise_var, noise_cov=None):
    """Fit (in place) with the coefficients' noise when the interpolator accepts it.

    The full covariance ``noise_cov`` (n, k, k) goes to interpolators whose ``fit`` takes
    it (co-Kriging), the variances ``noise_var`` (n, k) to those that take only them. With
    scikit-learn's metadata routing enabled, the noise is requested on the final step and
    routed; otherwise it is passed as ``<step>__noise_var`` (or ``__noise_cov``) through
    pipelines.
    """
    name, noise = "noise_var", noise_var
    if noise_cov is not None and accepts_noise(interpolator, "noise_cov"):
        name, noise = "noise_cov", noise_cov
    if noise is None or not accepts_noise(interpolator, name):
        return interpolator.fit(X, coef)
    if get_config().get("enable_metadata_routing", False):
        final = _final_step(interpolator)
        if final is not interpolator:
            final.set_fit_request(**{name: True})
        return interpolator.fit(X, coef, **{name: noise})
    return interpolator.fit(X, coef, **{f"{_step_path(interpolator)}{name}": noise})


def freeze_auto(template, fitted):
    """A clone of ``template`` whose ``"auto"`` parameters hold the values fitted by ``fitted``.

    A parameter ``p`` set to ``"auto"`` (e.g. Kriging's range) is replaced by the fitted
    attribute ``p_`` of the same (sub-)estimator, so that refits on subsets (the
    cross-predictions) reuse the hyperparameters instead of fitting them again.
    """
    frozen = clone(template)
    params = template.get_params(deep=True)
    fitted_params = fitted.get_params(deep=True)
    updates = {}
    for key, value in params.items():
        if not (isinstance(value, str) and value == "auto"):
            continue
        *owner, name = key.split("__")
        sub = fitted_params["__".join(owner)] if owner else fitted
        if hasattr(sub, f"{name}_"):
            updates[key] = getattr(sub, f"{name}_")
    return frozen.set_params(**updates) if updates else frozen


def cross_predict(interpolator, X, coef, noise_var, n_splits, random_state, noise_cov=None):
    """Coefficients of each star predicted by the interpolator fitted without its fold."""
    pred = np.empty_like(coef)
    folds = KFold(n_splits=min(n_splits, len(X)), shuffle=True, random_state=random_state)
    for train, test in folds.split(X):
        est = clone(interpolator)
        fit_interpolator(est, X[train], coef[train],
                         None if noise_var is None else noise_var[train],
                         None if noise_cov is None else noise_cov[train])
        pred[test] = np.asarray(est.predict(X[test]), dtype=np.float64).reshape(len(test), -1)
    return pred


def leave_out_predict(template, fitted, X, coef, noise_var, n_splits, random_state,
                      noise_cov=None):
    """Each star's coefficients predicted without it, and the relative size of that
    prediction's error variance from star to star (or None).

    In closed form when the fitted interpolator's final step offers ``loo_predict`` (Kriging:
    exact, from its factorisations, or local, from each star's nearest other stars; with
    its leave-one-out variance, larger for stars at the edges, whose prediction is an
    extrapolation); otherwise by
    ``n_splits``-fold cross-prediction with the hyperparameters ``fitted`` found (see
    :func:`freeze_auto`); NaN when the interpolator cannot be fitted on a fold.
    """
    final = _final_step(fitted)
    if hasattr(final, "loo_predict") and len(getattr(final, "X_fit_", ())) == len(coef):
        try:
            pred, std = final.loo_predict(return_std=True)
        except ValueError:  # too few stars for its neighbourhoods: fall back to folds
            pred = None
        if pred is not None:
            var = np.asarray(std, dtype=np.float64).reshape(len(coef), -1) ** 2
            return (np.asarray(pred, dtype=np.float64).reshape(len(coef), -1),
                    var / np.maximum(np.median(var, axis=0), 1e-300))
    try:
        return cross_predict(freeze_auto(template, fitted), X, coef, noise_var, n_splits,
                             random_state, noise_cov), None
    except ValueError:  # too few stars per fold for this interpolator: no coefficient test
        return np.full_like(coef, np.nan), None


def _solve_floor(statistic, target):
    """Smallest t >= 0 with ``statistic(t) <= target`` (statistic decreasing in t)."""
    if statistic(0.0) <= target:
        return 0.0
    hi = 1e-12
    while statistic(hi) > target:
        hi *= 10.0
        if hi > 1e12:
            return hi
    lo = hi / 10.0 if hi > 1e-12 else 0.0
    for _ in range(60):
        mid = 0.5 * (lo + hi) if lo == 0.0 else np.sqrt(lo * hi)
        if statistic(mid) > target:
            lo = mid
        else:
            hi = mid
    return hi


def coefficient_residuals(X, coef, predicted, noise_var, reference=None, relative=None,
                          n_neighbors=20):
    """Standardised coefficient residuals against their cross-prediction.

    The variance of a residual is the star's coefficient noise plus the interpolation error
    variance, which depends on where the star is (edges, sparse regions): for each star and
    component it is the larger of a global ``tau_k^2`` — the smallest value that brings the
    80th percentile of ``r^2 / (noise_var + tau_k^2)`` down to that of a chi^2 with one degree
    of freedom — and the same statistic over its ``n_neighbors`` nearest other stars (the
    80th percentile of their noise-free squared residuals, scaled to a chi^2_1). With
    ``relative`` (n, k), the global floor of each star is scaled by it (the interpolator's
    own error variance at the star over its median). Floors come from the ``reference`` stars
    (boolean mask; default all).
    """
    r = coef - predicted
    var = np.zeros_like(r) if noise_var is None else noise_var
    rel = np.ones_like(r) if relative is None else relative
    ref = np.ones(len(r), dtype=bool) if reference is None else np.asarray(reference, bool)
    rr, vr, lr = r[ref], var[ref], rel[ref]
    target = float(stats.chi2.ppf(_FLOOR_QUANTILE, 1))
    tau2 = np.array([
        _solve_floor(lambda t, k=k: np.quantile(
            rr[:, k] ** 2 / np.maximum(vr[:, k] + t * lr[:, k], 1e-300), _FLOOR_QUANTILE),
            target)
        for k in range(r.shape[1])
    ]) * rel
    m = min(n_neighbors, int(ref.sum()) - 1)
    if m >= 5:
        _, idx = cKDTree(X[ref]).query(X, k=m + 1)
        # each star's m nearest reference stars other than itself
        own = np.flatnonzero(ref)[idx] == np.arange(len(X))[:, None]
        idx = _drop_self(idx, own, m)
        excess = np.maximum(rr**2 - vr, 0.0)[idx]  # (n, m, k)
        local = np.quantile(excess, _FLOOR_QUANTILE, axis=1) / target
        tau2 = np.maximum(tau2, local)
    return r / np.sqrt(np.maximum(var + tau2, 1e-300)), tau2


def _drop_self(idx, own, m):
    """The first m neighbour indices of each row, leaving out the row's own star."""
    order = np.argsort(own, axis=1, kind="stable")  # own (True) last
    return np.take_along_axis(idx, order, axis=1)[:, :m]


def pixel_residuals(stamps, model, weights, reference=None):
    """Standardised pixel residuals of stars against their own fit, NaN on masked pixels.

    The variance of a pixel is ``1 / w + eps^2 model^2``: the relative model error ``eps``
    (truncated basis, imperfect centring, the stars' own Poisson noise missing from
    estimated weights) is the smallest value that brings the 80th percentile of the
    reduced chi^2 of the brighter half of the stars down to that of pure noise.
    """
    good = weights > 0
    r2 = np.where(good, (stamps - model) ** 2, 0.0)
    inv_w = np.where(good, 1.0 / np.where(good, weights, 1.0), np.inf)
    m2 = model**2
    dof = np.maximum(good.sum(axis=1), 1)
    snr2 = np.where(good, weights * m2, 0.0).sum(axis=1)
    ref = np.ones(len(stamps), dtype=bool) if reference is None else np.asarray(reference, bool)
    bright = ref & (snr2 >= np.median(snr2[ref]))

    def reduced(t):
        return np.quantile((r2[bright] / (inv_w[bright] + t * m2[bright])).sum(axis=1)
                           / dof[bright], _FLOOR_QUANTILE)

    typical = float(np.median(dof[bright]))
    eps2 = _solve_floor(reduced, float(stats.chi2.ppf(_FLOOR_QUANTILE, typical)) / typical)
    z = (stamps - model) * np.sqrt(pixel_inverse_variance(weights, model, eps2))
    return np.where(good, z, np.nan), eps2


def pixel_inverse_variance(weights, model, eps2):
    """Inverse variance of each pixel with the relative model error ``eps2`` (as
    :func:`pixel_residuals` finds it): ``1 / (1 / w + eps2 model^2)``, 0 where ``w`` is 0."""
    good = weights > 0
    inv_w = 1.0 / np.where(good, weights, 1.0)
    return np.where(good, 1.0 / (inv_w + eps2 * model**2), 0.0)
