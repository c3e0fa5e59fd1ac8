"""Fitting a PSF model with reserved stars and measuring its residuals on them."""

from __future__ import annotations

import inspect
import warnings

import numpy as np
from sklearn.base import clone
from sklearn.model_selection import KFold, cross_validate
from sklearn.utils import check_random_state

from .._validation import as_stamps
from ..metrics import make_ellipticity_rms_scorer, make_rho1_scorer
from ..measure import adaptive_moments
from ..metrics._correlation import EmptyBinsWarning
from ..model import PSFModel
from ..model._noise import pixel_residuals
from ..preprocessing import ChiSquareOutlierDetector, estimate_pixel_weights
from ._residuals import FIXED_WEIGHT_SIGMA, _centroid_shift, _chi2, measure_residuals, rho_bins
from ._verdict import PSFQualityWarning, model_verdict

__all__ = ["fit_and_validate"]


def _as_model(candidate):
    if isinstance(candidate, PSFModel):
        return clone(candidate)
    if hasattr(candidate, "fit") and hasattr(candidate, "predict"):
        return PSFModel(interpolator=clone(candidate))
    raise TypeError(f"Expected a PSFModel or an interpolating regressor, got "
                    f"{type(candidate).__name__}.")


def _undersampled(model, stamps, weights):
    """Whether the reserved stars are undersampled: the model's basis is super-resolved, or
    adaptive moments fail on more than half of them (with a basis that draws stars at
    sub-pixel offsets)."""
    if hasattr(model.basis_, "render_fine"):
        return True
    if not (hasattr(model.basis_, "project") and hasattr(model.basis_, "render")):
        return False
    s = int(round(np.sqrt(stamps.shape[1])))
    d = np.where(np.isfinite(stamps), stamps, 0.0).reshape(-1, s, s)
    w = None if weights is None else weights.reshape(-1, s, s)
    return bool(np.mean(np.asarray(adaptive_moments(d, weights=w)["flag"]) != 0) > 0.5)


def _accepted(model, fit_params):
    """The fit parameters ``model.fit`` accepts (pixel weights only where supported)."""
    accepted = inspect.signature(model.fit).parameters
    return {k: v for k, v in fit_params.items() if k in accepted}


#: More reserved stars than this fraction failing the outlier test is a PSFQualityWarning.
_MOST_OUTLIERS = 0.1


def _reserved_outliers(table, stamps, weights, model):
    """The reserved stars that the model's outlier test would reject: their pixels against
    the model's PSF at their position (flux, background and centroid fitted), in their noise
    with the model error (estimated on the reserved stars themselves), judged by a
    :class:`~sklearn_psf.preprocessing.ChiSquareOutlierDetector` at the model's p-value. A
    blend or a galaxy among them then does not spoil the statistics."""
    out = np.zeros(len(table), dtype=bool)
    ok = np.flatnonzero(np.asarray(table["flag"]) == 0)
    if ok.size < 5:
        return out
    d = np.asarray(stamps, dtype=np.float64)[ok]
    w = estimate_pixel_weights(d) if weights is None else np.asarray(weights, np.float64)[ok]
    w = np.where(np.isfinite(d), w, 0.0)
    d = np.where(w > 0, np.nan_to_num(d), 0.0)
    psf = np.asarray(table["stamp_model"], dtype=np.float64)[ok]
    n, s = len(ok), int(round(np.sqrt(psf.shape[1])))
    _, _, fitted = _chi2(d, w, psf, _centroid_shift(d, w, psf), return_model=True)
    usable = np.isfinite(fitted).all(axis=1)
    if usable.sum() < 5:
        return out
    z, _ = pixel_residuals(d[usable], fitted[usable], w[usable])
    detector = getattr(model, "outliers_", None)
    p_value = detector.p_value if isinstance(detector, ChiSquareOutlierDetector) else 1e-4
    rejected = ChiSquareOutlierDetector(p_value=p_value).fit(z).predict(z) == -1
    out[ok[np.flatnonzero(usable)[rejected]]] = True
    return out


def fit_and_validate(X, stamps, model=None, reserve: float = 0.2, random_state=None, *,
                     candidates=None, cv: int = 5, rho1_nbins: int = 6, weights=None,
                     wcs=None):
    """Fit a PSF model on most stars and validate it on reserved ones.

    The model (or the best of ``candidates`` by cross-validation) is fitted on the stars not
    reserved and judged on the reserved ones: residuals (:func:`measure_residuals`), rho
    statistics, and a verdict in units of the stars' noise against a constant PSF. The steps
    and every summary entry: :ref:`validation-details` in the user guide.

    Parameters
    ----------
    X : array-like of shape (n, 2) or (n, 2 + m)
        Star positions (x, y), 0-based pixels, then optionally the model's extra dimensions.
    stamps : array-like of shape (n, s*s) or (n, s, s)
        Background-subtracted star stamps (e.g. :func:`sklearn_psf.exposure.extract_star_stamps`).
    model : PSFModel, optional
        Unfitted model (cloned); default ``PSFModel()``, the noise-aware model.
    reserve : float, default=0.2
        Fraction of stars reserved, in [0, 1). 0 fits every star and returns an empty table.
    random_state : int, RandomState or None
        Seed of the reserved-star draw and of the cross-validation folds.
    candidates : dict, optional
        Name -> PSFModel or interpolating regressor (e.g.
        :func:`sklearn_psf.study.compare.default_schemes`), chosen by cross-validation
        instead of ``model``.
    cv : int, default=5
        Folds of the cross-validation.
    rho1_nbins : int, default=6
        Logarithmic separation bins of the rho statistics.
    weights : array-like of the stamps' shape, optional
        Pixel inverse variance (0 = masked, already 0 in ``stamps``), passed to the fit.
    wcs : astropy.wcs.WCS, optional
        Celestial WCS: the rho statistics are then measured on the sky (arcmin).

    Returns
    -------
    model : PSFModel
        Fitted on the non-reserved stars.
    residuals : astropy.table.Table
        One row per reserved star, the columns of :func:`measure_residuals` and
        ``outlier`` (rejected by the model's outlier test: left out of the summary).
    summary : dict
        Counts (``n_fit``, ``n_reserved``, ...), the summary of :func:`measure_residuals`,
        with candidates ``cv`` and ``scheme``, and the verdict (``e_resid_over_noise``,
        ``chi2_dof_median``, each with its ``_constant``, ``warnings``, ...).

    Warns
    -----
    PSFQualityWarning
        When the model fits the reserved stars no better than the constant PSF, its
        residuals exceed twice the noise, or the Kriging range is below the stars' spacing.

    Raises
    ------
    ValueError
        For ``reserve`` outside [0, 1), stamps/positions of different lengths, or too few
        stars to fit after reserving.

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.simulate import make_psf_field
    >>> from sklearn_psf.validation import fit_and_validate
    >>> field = make_psf_field(n_stars=80, n_galaxies=0, image_shape=(900, 900),
    ...                        snr=200.0, random_state=0)
    >>> stamps, flags = field.star_stamps(normalize=False)
    >>> X = np.column_stack([field.stars["x"], field.stars["y"]])
    >>> import warnings
    >>> with warnings.catch_warnings(record=True) as caught:
    ...     warnings.simplefilter("always")
    ...     model, res, summary = fit_and_validate(X, stamps, reserve=0.25, random_state=0)
    >>> summary["n_reserved"], len(res), bool(summary["e_rms"] < 0.05)
    (20, 20, True)

    60 stars are too few for this PSF: residuals 3 times the noise (a constant PSF: 6).

    >>> round(summary["e_resid_over_noise"]), round(summary["e_resid_over_noise_constant"])
    (3, 6)
    >>> [w.category.__name__ for w in caught]
    ['PSFQualityWarning']
    """
    X = np.array(X, dtype=np.float64, copy=True)
    if X.ndim != 2 or X.shape[1] < 2:
        raise ValueError(f"X must hold (x, y) positions and optionally further columns (the "
                         f"model's extra dimensions), shape (n, 2 + m), got {X.shape}.")
    cube = as_stamps(stamps)
    n, s = cube.shape[0], cube.shape[1]
    if n != X.shape[0]:
        raise ValueError(f"X has {X.shape[0]} positions but stamps has {n} stars.")
    y = cube.reshape(n, s * s)
    if not (0 <= float(reserve) < 1):
        raise ValueError(f"reserve must be a fraction in [0, 1), got {reserve!r}.")
    rng = check_random_state(random_state)
    n_res = int(round(float(reserve) * n))
    if reserve > 0:
        n_res = max(n_res, 1)
    if n - n_res < 3:
        raise ValueError(f"{n} stars leave {n - n_res} to fit after reserving {n_res}: "
                         "too few (need at least 3); use a smaller reserve or more stars.")
    order = rng.permutation(n)
    reserved = np.sort(order[:n_res])
    fit_rows = np.sort(order[n_res:])
    X_fit, y_fit = X[fit_rows], y[fit_rows]
    fit_params = {}
    if weights is not None:
        w = np.asarray(weights, dtype=np.float64).reshape(n, -1)
        if w.shape != y.shape:
            raise ValueError(f"weights must have the stamps' shape {cube.shape}, got "
                             f"{np.shape(weights)}.")
        if (w < 0).any() or not np.isfinite(w).all():
            raise ValueError("weights must be finite and >= 0 (0 = masked pixel).")
        fit_params = {"weights": w[fit_rows]}
    min_sep, max_sep = rho_bins(X, s)

    summary = {}
    if candidates:
        seed = int(rng.randint(0, 2**31 - 1))
        folds = KFold(n_splits=int(cv), shuffle=True, random_state=seed)
        scoring = {"e_rms": make_ellipticity_rms_scorer(),
                   "rho1": make_rho1_scorer(min_sep, max_sep, nbins=rho1_nbins)}
        rows = []
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", EmptyBinsWarning)
            for name, cand in candidates.items():
                cand = _as_model(cand)
                scores = cross_validate(cand, X_fit, y_fit, cv=folds, scoring=scoring,
                                        error_score=np.nan, params=_accepted(cand, fit_params))
                rows.append({"scheme": name,
                             "e_rms": float(-np.nanmean(scores["test_e_rms"])),
                             "e_rms_std": float(np.nanstd(scores["test_e_rms"])),
                             "rho1_mean_abs": float(-np.nanmean(scores["test_rho1"]))})
        finite = [r for r in rows if np.isfinite(r["e_rms"])]
        if not finite:
            raise ValueError("Every candidate scheme failed in cross-validation.")
        best = min(finite, key=lambda r: r["e_rms"])
        summary["cv"] = rows
        summary["scheme"] = best["scheme"]
        model = _as_model(candidates[best["scheme"]])
    else:
        model = PSFModel() if model is None else clone(model)
    model.fit(X_fit, y_fit, **_accepted(model, fit_params))

    k = len(reserved)
    summary.update({"n_stars": n, "n_fit": len(fit_rows), "n_reserved": k,
                    "n_inliers": int(np.sum(model.inlier_mask_)),
                    "n_outliers": int(np.sum(~model.inlier_mask_)),
                    "spatial_model": getattr(model, "spatial_model_", "interpolator")})
    noise = getattr(model, "pixel_noise_", None)
    if noise is not None:  # what the fit learnt of the stars' noise
        summary["pixel_noise"] = {"sky": noise.sky, "poisson": noise.poisson,
                                  "eps2": noise.eps2}
    hit = getattr(model, "contaminated_pixels_", None)
    if hit is not None and np.any(hit):
        summary["contaminated_stamps"] = int(np.sum(hit > 0))
        summary["contaminated_median"] = int(np.median(hit[hit > 0]))
    pred = model.predict(X[reserved]) if k else np.zeros((0, s * s))
    w_res = None if weights is None else w[reserved]
    sigma = offsets = None
    if k and _undersampled(model, y[reserved], w_res):
        # undersampled stars: the model drawn at each star's fitted sub-pixel position, both
        # measured with fixed-weight moments
        offsets = model.basis_.project(y[reserved], w_res).offsets
        pred, sigma = model.predict(X[reserved], offsets=offsets), FIXED_WEIGHT_SIGMA
    options = {"wcs": wcs, "min_sep": min_sep, "max_sep": max_sep, "nbins": rho1_nbins,
               "moments": "adaptive" if sigma is None else sigma}
    table, measured = measure_residuals(X[reserved], y[reserved], pred, weights=w_res,
                                        index=reserved, **options)
    outlier = _reserved_outliers(table, y[reserved], w_res, model)
    table["outlier"] = outlier
    if outlier.any():  # the statistics and the verdict without them
        _, measured = measure_residuals(X[reserved[~outlier]], y[reserved[~outlier]],
                                        pred[~outlier], index=reserved[~outlier],
                                        weights=None if w_res is None else w_res[~outlier],
                                        **options)
    summary.update(measured)
    summary["n_reserved_outliers"] = int(outlier.sum())
    summary["reserved_outliers"] = [int(i) for i in reserved[outlier]]
    if hasattr(model, "coefficients_"):
        summary.update(model_verdict(model, X, y, None if weights is None else w,
                                     reserved[~outlier], table[~outlier],
                                     random_state=rng.randint(0, 2**31 - 1), sigma=sigma,
                                     offsets=None if offsets is None else offsets[~outlier]))
        n_out, n_meas = int(outlier.sum()), int(np.sum(np.asarray(table["flag"]) == 0))
        if n_out >= 2 and n_out > _MOST_OUTLIERS * n_meas:
            summary["warnings"].append(
                f"{n_out} of the {n_meas} measured reserved stars fail the model's outlier test "
                f"(more than {_MOST_OUTLIERS:.0%}; left out of the statistics): the stars "
                "include many galaxies, blends or defects, or the model does not describe them")
        for message in summary["warnings"]:
            warnings.warn(message, PSFQualityWarning, stacklevel=2)
    return model, table, summary
