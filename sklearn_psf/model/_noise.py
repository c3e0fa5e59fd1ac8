"""Noise plumbing of PSFModel: routing per-star noise to interpolators, cross-predictions,
and standardised residuals for the chi^2 outlier test."""

from __future__ import annotations

import inspect
from typing import NamedTuple

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


class PixelNoise(NamedTuple):
    """The pixel noise the stars' residuals show: variance ``sky / w + poisson * max(model,
    0) + eps2 * model^2`` for a pixel of weight ``w`` and model value ``model``."""

    #: Scale of the given (or border-estimated) variances ``1 / w``.
    sky: float = 1.0
    #: Poisson variance per unit of the model's value (``1 / gain`` in the stamps' units)
    #: missing from ``1 / w``.
    poisson: float = 0.0
    #: Relative model error squared (truncated basis, imperfect centring).
    eps2: float = 0.0

    def variance(self, weights, model):
        """Each pixel's variance (infinite where ``weights`` is 0)."""
        good = weights > 0
        inv_w = np.where(good, 1.0 / np.where(good, weights, 1.0), np.inf)
        return self.sky * inv_w + self.poisson * np.maximum(model, 0.0) + self.eps2 * model**2


#: Largest number of pixels the noise calibration fits its three terms on.
_NOISE_PIXELS = 100_000


def _fit_variance(r2, design, theta):
    """Non-negative ``theta`` of the variance model ``design @ theta`` for the squared
    residuals ``r2``, by Fisher scoring (iteratively reweighted least squares: ``E[r^2] =
    V``, ``Var(r^2) = 2 V^2`` for Gaussian residuals); the first term (the sky's) is kept,
    the others dropped where they would go negative (every subset tried)."""
    from itertools import combinations

    k = design.shape[1]
    subsets = [(0, *c) for m in range(k) for c in combinations(range(1, k), m)]
    columns = np.ascontiguousarray(design.T)  # (k, N): each pass reads contiguous rows
    for _ in range(30):
        var = np.maximum(theta @ columns, 1e-300)
        dw = columns / (var * var)
        gram, rhs = dw @ columns.T, dw @ r2  # the weighted normal equations,
        norm = np.sqrt(np.diag(gram)) + 1e-300
        gram, rhs = gram / np.outer(norm, norm), rhs / norm  # columns scaled
        best, best_cost = theta, np.inf
        for cols in subsets:
            c = list(cols)
            sol = np.linalg.lstsq(gram[np.ix_(c, c)], rhs[c], rcond=None)[0]
            if (sol < 0).any():
                continue
            cost = float(sol @ gram[np.ix_(c, c)] @ sol - 2 * sol @ rhs[c])
            if cost < best_cost:
                best_cost, best = cost, np.zeros(k)
                best[c] = sol / norm[c]
        done = np.allclose(best, theta, rtol=1e-6, atol=0)
        theta = best
        if done:
            break
    return theta


def calibrate_pixel_noise(stamps, model, weights, reference=None, clip=5.0) -> PixelNoise:
    """The pixel noise of stars against their fitted models, learnt from their residuals.

    Real images rarely come with the noise model their stamps follow: no gain (so no
    Poisson term), a gain in the wrong units, noise correlated by resampling, a sky
    variance that the stamps' borders misjudge, and the model's own error in the bright
    cores. The variance of a pixel is taken as ``sky / w + poisson * max(model, 0) + eps2 *
    model^2`` (see :class:`PixelNoise`) and its three terms are fitted to the squared
    residuals of the ``reference`` stars' unmasked pixels (Gaussian likelihood, by Fisher
    scoring; non-negative terms), then again without the pixels beyond ``clip`` standard
    deviations of that noise (cosmic-ray hits, defects), then the stars whose reduced
    chi^2 exceeds the others' (by more than 4 robust standard deviations: blends,
    galaxies) left out and the fit repeated. Weights that already hold the right noise
    give ``sky`` near 1 and ``poisson`` near 0.

    Parameters
    ----------
    stamps, model, weights : ndarray of shape (n, p)
    reference : ndarray of shape (n,), bool, optional
        The stars to learn from (default all).
    clip : float, default=5

    Returns
    -------
    PixelNoise
    """
    good = weights > 0
    ref = np.ones(len(stamps), dtype=bool) if reference is None else np.asarray(reference, bool)
    v = np.where(good, 1.0 / np.where(good, weights, 1.0), 0.0)
    r2 = np.where(good, (stamps - model) ** 2, 0.0)
    star = np.broadcast_to(np.arange(len(stamps))[:, None], good.shape)[good]
    design = np.column_stack([v[good], np.maximum(model[good], 0.0), model[good] ** 2])
    r2_good = r2[good]
    if len(star) > _NOISE_PIXELS:  # three numbers: a fixed random subset of pixels will do
        sub = np.sort(np.random.default_rng(0).choice(len(star), _NOISE_PIXELS, replace=False))
        star, design, r2_good = star[sub], design[sub], r2_good[sub]
    theta = np.array([1.0, 0.0, 0.0])
    use = ref.copy()
    for _ in range(3):
        pix = use[star]
        if pix.sum() < 10:
            break
        d, r = design[pix], r2_good[pix]
        theta = _fit_variance(r, d, theta)
        for _ in range(2):  # then without the pixels far beyond that noise
            keep = r <= clip**2 * (d @ theta)
            theta = _fit_variance(r[keep], d[keep], theta)
        noise = PixelNoise(*theta)
        chi = np.where(good, r2 / np.where(good, noise.variance(weights, model), 1.0), 0.0)
        reduced = chi.sum(axis=1) / np.maximum(good.sum(axis=1), 1)
        med = np.median(reduced[ref])
        spread = 1.4826 * np.median(np.abs(reduced[ref] - med))
        new = ref & (reduced <= med + 4.0 * spread)
        if (new == use).all():
            break
        use = new
    return PixelNoise(*(float(t) for t in theta))


def pixel_residuals(stamps, model, weights, reference=None):
    """Standardised pixel residuals of stars against their own fit, NaN on masked pixels,
    in the noise :func:`calibrate_pixel_noise` learns from the ``reference`` stars (with
    the model's own error), and that noise (a :class:`PixelNoise`)."""
    good = weights > 0
    noise = calibrate_pixel_noise(stamps, model, weights, reference)
    z = (stamps - model) * np.sqrt(pixel_inverse_variance(weights, model, noise))
    return np.where(good, z, np.nan), noise


def pixel_inverse_variance(weights, model, noise):
    """Inverse variance of each pixel in the calibrated ``noise`` (a :class:`PixelNoise`,
    as :func:`pixel_residuals` finds it), 0 where ``weights`` is 0."""
    good = weights > 0
    return np.where(good, 1.0 / np.where(good, noise.variance(weights, model), 1.0), 0.0)


def contaminated_pixels(z, model, threshold=5.0, core=0.05, most=0.25):
    """Pixels of each star's stamp that hold light its model does not (a neighbour missing
    from the catalogue, a cosmic-ray hit, a bad pixel), outside the star's core.

    ``z`` are the stars' standardised residuals (NaN where masked), ``model`` their fitted
    model stamps. Each ring's mean residual about the stamp's centre is taken out first (a
    departure common to a ring is the model's wings, not a neighbour). A pixel is
    contaminated where the residual, summed over its 3 x 3
    neighbourhood (over the square root of the pixels summed: unit variance for white
    noise; over the sums' robust spread outside the cores where that is larger, for noise
    correlated between pixels), or the pixel's own, departs by more than ``threshold`` (+1
    for a single pixel);
    the pixels around it are taken too (a 3 x 3 dilation). Only pixels where the model is
    below ``core`` times its peak count (the star's core is the star: a departure there is
    a defect of the star, judged by the outlier test), and a star with more than ``most``
    of its pixels hit gets none (its model, not a neighbour, is wrong).

    Returns
    -------
    ndarray of shape (n, p), bool
    """
    from scipy.ndimage import binary_dilation, uniform_filter

    n, p = z.shape
    s = int(round(np.sqrt(p)))
    finite = np.isfinite(z).reshape(n, s, s)
    # a ring's common departure is the model's (its wings), not a neighbour's: taken out
    yy, xx = np.mgrid[0:s, 0:s] - (s - 1) / 2.0
    ring = np.floor(np.hypot(xx, yy)).astype(np.int64).ravel()
    rings = ring.max() + 1
    index = (np.arange(n)[:, None] * rings + ring[None, :]).ravel()
    zf = np.where(np.isfinite(z), z, 0.0).ravel()
    count = np.bincount(index, np.isfinite(z).ravel(), minlength=n * rings)
    common = np.bincount(index, zf, minlength=n * rings) / np.maximum(count, 1)
    zz = np.where(finite, (zf - common[index]).reshape(n, s, s), 0.0)
    near = 9.0 * uniform_filter(finite.astype(np.float64), size=(1, 3, 3), mode="constant")
    summed = 9.0 * uniform_filter(zz, size=(1, 3, 3), mode="constant")
    smooth = summed / np.sqrt(np.maximum(near, 1.0))
    outer = (model < core * model.max(axis=1, keepdims=True)).reshape(n, s, s) & finite
    if outer.any():  # noise correlated between pixels (resampling) adds up in the sums
        spread = 1.4826 * np.median(np.abs(smooth[outer]))
        smooth = smooth / max(spread, 1.0)
    hit = (np.abs(smooth) > threshold) | (np.abs(zz) > threshold + 1.0)
    hit = binary_dilation(hit, structure=np.ones((1, 3, 3), dtype=bool))
    hit &= outer
    hit[hit.reshape(n, -1).mean(axis=1) > most] = False
    return hit.reshape(n, p)
