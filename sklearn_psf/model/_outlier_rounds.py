"""The outlier rounds of :meth:`PSFModel.fit <sklearn_psf.model.PSFModel.fit>`: the basis
fitted on the stars kept so far, every star projected on it, the outlier test of each star
(its coefficients and pixels against the interpolator's cross-predictions from the trusted
stars, with the contaminated pixels and unresolved companions), and what carries over to
the next round (the weights in the pixel noise the stars showed, the interpolator refitted
from its previous hyperparameters). The methods live on :class:`_OutlierRounds`, a mixin
that ``PSFModel`` inherits; the loop over the rounds stays in ``PSFModel.fit``."""

from __future__ import annotations

import inspect
import warnings

import numpy as np
from sklearn.base import clone

from ..preprocessing import ChiSquareOutlierDetector
from ..preprocessing._stamp_basis import _BaseStampBasis
from ._companions import COMPANION_P_VALUE, companion_log_p
from ._noise import (
    coefficient_residuals,
    contaminated_pixels,
    fit_interpolator,
    kriging_steps,
    leave_out_predict,
    pixel_inverse_variance,
    pixel_residuals,
)


def _rows(keep, a, b):
    """An array of ``a``'s rows where ``keep``, ``b``'s elsewhere."""
    out = np.empty((len(keep),) + np.shape(a)[1:], dtype=np.result_type(a, b))
    out[keep], out[~keep] = a, b
    return out


def _calibrated(weights, stamp_fit, noise, usable):
    """The weights for the next round in the pixel noise the stars showed (``noise``, its
    sky scale and Poisson term from the stars' models; not the model error), where it
    departs from the given weights (a sky variance off by over 2%, or a Poisson term over
    2% of the sky's at the typical star's peak); else ``weights`` as they are."""
    if noise is None or stamp_fit is None:
        return weights
    w, model = stamp_fit.weights, stamp_fit.model
    good = w > 0
    v = np.median(1.0 / w[good]) if good.any() else 1.0
    peak = np.median(np.max(np.where(good, model, 0.0), axis=1)[usable]) if usable.any() \
        else 0.0
    if abs(noise.sky - 1.0) <= 0.02 and noise.poisson * peak <= 0.02 * v:
        return weights
    sky_poisson = noise._replace(eps2=0.0)
    out = np.where(good, 1.0 / np.where(good, sky_poisson.variance(w, model), 1.0), 0.0)
    return np.where(usable[:, None], out, w)


def _warm(template, fitted, on=True):
    """``fitted``, to be refitted on nearly the same stars (the second outlier round's, the
    final fit), with its Kriging steps' ``warm_start`` on: maximum likelihood starts from
    the previous fit's hyperparameters and ``drift="auto"`` keeps its drift. A clone of
    ``template`` (the unfitted interpolator) when there is no previous fit or no Kriging step
    in it. ``on=False`` puts back the template's ``warm_start``."""
    if fitted is None:
        return clone(template) if on else None
    steps = kriging_steps(fitted)
    if not steps:
        return clone(template) if on else fitted
    given = dict(kriging_steps(template))
    for key, step in steps:
        step.warm_start = on or bool(given[key].warm_start)
    return fitted


class _OutlierRounds:
    """The basis fit, projection and outlier test of each of :class:`PSFModel`'s outlier
    rounds (a mixin: ``_reject`` reads the estimator's ``cv`` and ``random_state``)."""

    @staticmethod
    def _fit_basis(basis, y, weights, keep, X=None):
        """The basis fitted on the stars ``keep``, and their StampFit on it when the basis
        gives it with the fit (``StampPCA``: its last iteration's), else None. A basis whose
        ``fit`` takes ``positions`` is given the stars' positions ``X``."""
        params = inspect.signature(basis.fit).parameters
        takes_weights = "weights" in params
        where = {"positions": X[keep]} if "positions" in params and X is not None else {}
        # (a stamp basis itself: a wrapper such as FrozenEstimator passes attributes through)
        if isinstance(basis, _BaseStampBasis) and (weights is not None or keep.all()):
            return basis, basis.fit_project(y[keep],
                                            None if weights is None else weights[keep],
                                            **where)
        if takes_weights and weights is not None:
            return basis.fit(y[keep], None, weights[keep], **where), None
        return basis.fit(y[keep], **where), None

    @staticmethod
    def _project(basis, y, weights, keep, fitted_stars=None):
        """Coefficients, their noise variance and covariance, fit flags and the StampFit
        (None for what a basis that knows no noise does not give) of every star; the stars
        ``keep`` from ``fitted_stars`` (their fit with the basis's) when given."""
        if hasattr(basis, "project"):
            if fitted_stars is None:
                fit = basis.project(y, weights)
            elif keep.all():
                fit = fitted_stars
            else:  # the stars left out of the basis fit: projected on it
                rest = basis.project(y[~keep], None if weights is None else weights[~keep])
                fit = type(fitted_stars)(*[
                    None if a is None else _rows(keep, a, b)
                    for a, b in zip(fitted_stars, rest)])
            cov = getattr(fit, "coefficient_cov", None)
            return fit.coefficients, fit.coefficient_var, cov, np.asarray(fit.flag), fit
        coef = np.asarray(basis.transform(y), dtype=np.float64)
        coef = coef.reshape(len(y), -1)
        return coef, None, None, np.zeros(len(y), dtype=np.int64), None

    def _reject(self, detector, X, y, coef, var, cov, trusted, usable, interp, stamp_fit,
                basis=None, previous=None):
        """Inlier mask over all stars, the detector's score (NaN where unusable), the
        interpolator fitted on the trusted stars (None unless the test is chi^2), the
        warnings of that fit (``previous``, the previous round's, refitted from its
        hyperparameters when given), the stars' contaminated pixels and their pixel noise
        (None unless the stars' own fits are known; see :func:`contaminated_pixels` and
        :func:`calibrate_pixel_noise`).

        The chi^2 test's references (leave-one-out or cross-predictions, model-error floors)
        come from the ``trusted`` stars only (the inliers of the previous round); every
        usable star is judged against them.
        """
        n = len(X)
        inliers = np.ones(n, dtype=bool)
        if detector is None:
            return inliers, None, None, [], None, None
        idx = np.flatnonzero(usable)
        score = np.full(n, np.nan)
        if not isinstance(detector, ChiSquareOutlierDetector):
            labels = np.asarray(detector.fit_predict(coef[idx]))
            inliers[idx] = labels == 1
            if hasattr(detector, "score_samples"):
                score[idx] = detector.score_samples(coef[idx])
            return inliers, score, None, [], None, None
        ref = trusted[idx]
        train = idx[ref]
        noise = None if var is None else var[train]
        noise_cov = None if cov is None else cov[train]
        # the interpolator's warnings are kept for when this fit becomes the final model
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            full = fit_interpolator(_warm(interp, previous), X[train], coef[train], noise,
                                    noise_cov)

        # the trusted stars are judged from the others (leave-one-out), the rest from all
        predicted = np.empty((len(idx), coef.shape[1]))
        predicted[ref], rel = leave_out_predict(interp, full, X[train], coef[train], noise,
                                                self.cv, self.random_state, noise_cov)
        if not ref.all():
            predicted[~ref] = np.asarray(full.predict(X[idx[~ref]]),
                                         dtype=np.float64).reshape(-1, coef.shape[1])
        relative = np.ones_like(predicted)
        if rel is not None:  # stars judged from outside: as far as the worst trusted one
            relative[ref] = rel
            relative[~ref] = rel.max(axis=0)
        z_coef, floors = coefficient_residuals(X[idx], coef[idx], predicted,
                                               None if var is None else var[idx],
                                               reference=ref, relative=relative)
        detector.fit(z_coef)
        ok = detector.predict(z_coef) == 1
        score[idx] = detector.score_samples(z_coef)
        pixels = hit = noise = None
        if stamp_fit is not None:
            data, model = np.where(np.isnan(y[idx]), 0.0, y[idx]), stamp_fit.model[idx]
            z_pix, noise = pixel_residuals(data, model, stamp_fit.weights[idx], reference=ref)
            hit = np.zeros(y.shape, dtype=bool)
            hit[idx] = contaminated_pixels(z_pix, model)
            pix = clone(detector).fit(z_pix)
            ok &= pix.predict(z_pix) == 1
            score[idx] = np.minimum(score[idx], pix.score_samples(z_pix))
            pixels = (np.where(np.isfinite(z_pix), data - model, 0.0),  # z_pix: NaN if masked
                      pixel_inverse_variance(stamp_fit.weights[idx], model, noise),
                      stamp_fit.flux[idx], stamp_fit.offsets[idx])
        if basis is not None:  # an unresolved companion: see model/_companions.py
            log_p = companion_log_p(basis, coef[idx], coef[idx] - predicted,
                                    None if var is None else var[idx], floors, ref, pixels)
            ok &= log_p >= np.log10(COMPANION_P_VALUE)
            score[idx] = np.minimum(score[idx], log_p)
        cap = detector.max_remove
        if cap is not None and (~ok).sum() > int(cap * len(idx)):
            # the combined tests reject at most max_remove of the stars: the worst ones
            worst = np.argsort(score[idx], kind="stable")[:int(cap * len(idx))]
            ok = np.ones(len(idx), dtype=bool)
            ok[worst] = False
        inliers[idx] = ok
        return inliers, score, full, caught, hit, noise
