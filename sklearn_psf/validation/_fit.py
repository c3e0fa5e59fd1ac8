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

    1. A random fraction ``reserve`` of the stars (seeded by ``random_state``) is set aside;
       they are not used in the fit.
    2. If ``candidates`` are given, each is scored by ``cv``-fold cross-validation
       (:func:`sklearn.model_selection.cross_validate`) on the remaining stars with
       :func:`~sklearn_psf.metrics.make_ellipticity_rms_scorer` and
       :func:`~sklearn_psf.metrics.make_rho1_scorer`; the one with the best mean ellipticity
       score is used.
    3. The model is fitted on the remaining stars.
    4. The reserved stars are normalised (:class:`~sklearn_psf.preprocessing.StampNormalizer`)
       and measured with :func:`~sklearn_psf.measure.adaptive_moments`, like the model's
       stamps at their positions; residuals are star minus model. Undersampled stars (a
       super-resolved basis, or adaptive moments failing on more than half of the reserved
       stars) are measured as they are, with fixed-weight moments
       (:func:`~sklearn_psf.measure.fixed_moments`, a round Gaussian weight of sigma 1.5
       pixels), against the model drawn at each star's sub-pixel position (fitted on the
       star's pixels by the basis); ``summary["moments"]`` says which.

    5. The verdict: each reserved star's pixels are fitted (flux and sub-pixel centroid) with
       the model's PSF and with a constant PSF fitted on the same stars (the inverse-variance
       weighted mean of the model's coefficients of its kept stars), in units of the star's
       pixel noise (``weights``, else estimated stamp by stamp); the ellipticity residuals
       are compared with the stars' ellipticity noise (the standard deviation of e over 16
       noise draws from the star's weights around its fitted model). A
       :class:`PSFQualityWarning` is issued (and its text kept in ``summary["warnings"]``)
       when the model fits the reserved stars no better than the constant PSF (summed
       chi^2), when the residuals exceed twice the noise (median reduced chi^2, or e residual
       rms over e noise rms), and when maximum likelihood gives the Kriging a range below the
       stars' typical spacing (no spatial correlation found).

    Note that the reserved-star residuals include the stars' own measurement noise: at S/N
    ~100 it is comparable with the model errors of a good scheme; the verdict's ratios
    (1 for pure noise) separate the two.

    Parameters
    ----------
    X : array-like of shape (n, 2) or (n, 2 + m)
        Star positions (x, y), 0-based pixels, then optionally the model's extra dimensions
        (a colour, a magnitude: passed to the model, not used as positions).
    stamps : array-like of shape (n, s*s) or (n, s, s)
        Background-subtracted star stamps (e.g. :func:`sklearn_psf.io.extract_star_stamps`).
        Not modified.
    model : PSFModel, optional
        Unfitted model (cloned); default ``PSFModel()`` (noise-aware: StampPCA basis,
        chi^2 outlier rejection, Kriging with its range fitted by maximum likelihood).
    reserve : float, default=0.2
        Fraction of stars reserved, in [0, 1). 0 fits every star and returns an empty table.
    random_state : int, RandomState or None
        Seed of the reserved-star draw and of the cross-validation folds.
    candidates : dict, optional
        Name -> PSFModel or interpolating regressor (e.g.
        :func:`sklearn_psf.study.compare.default_schemes`); chosen by cross-validation. ``model``
        is then ignored.
    cv : int, default=5
        Folds of the cross-validation.
    rho1_nbins : int, default=6
        Logarithmic separation bins of rho1 (in pixels, from the stamp size to half the
        field's diagonal).
    weights : array-like of the stamps' shape, optional
        Pixel weights (inverse variance, 0 = masked), e.g. ``StarStamps.weights``; passed to
        ``PSFModel.fit`` when it accepts ``weights`` (masked pixels should then already be 0
        in ``stamps``, as the readers leave them).
    wcs : astropy.wcs.WCS, optional
        Celestial WCS of the image (:func:`sklearn_psf.io.celestial_wcs`): the rho
        statistics are then measured on the sky, in great-circle separations (arcmin); the
        summary's ``rho_theta_units`` says which.

    Returns
    -------
    model : PSFModel
        Fitted on the non-reserved stars.
    residuals : astropy.table.Table
        One row per reserved star: ``index`` (row in X), ``x``, ``y``, ``e1_star``,
        ``e2_star``, ``sigma_star``, ``e1_model``, ``e2_model``, ``sigma_model``, ``de1``,
        ``de2``, ``dsigma`` (star - model), ``resid_rms`` (pixel rms of the unit-flux
        residual stamp), ``chi2``, ``dof`` (raw stamp against the model, in the star's
        noise), ``flag`` (0: both measured; 1: star's moments failed; 2: model's),
        ``stamp_star``, ``stamp_model`` (normalised); see :func:`measure_residuals`; and
        ``outlier``: True for the reserved stars that the model's outlier test rejects (their
        pixels against the model's PSF, flux and centroid fitted, in their noise plus the
        model error, by a :class:`~sklearn_psf.preprocessing.ChiSquareOutlierDetector` at
        the model's p-value): blends, galaxies, cosmic rays. They are left out of the summary's
        statistics and verdict.
    summary : dict
        ``n_stars``, ``n_fit``, ``n_reserved``, ``n_measured``, ``n_inliers``,
        ``n_outliers``, ``de1_mean``, ``de1_rms``, ``de2_mean``, ``de2_rms``, ``e_rms``
        (sqrt <de1^2 + de2^2>), ``dsigma_mean``, ``dsigma_rms``, ``sigma_mean`` (pixels),
        ``chi2_dof``, ``chi2_dof_median``, ``rho1`` to ``rho5`` (Jarvis et al. 2016,
        :func:`~sklearn_psf.metrics.rho_statistics` with T = 2 sigma^2; each a dict of
        ``theta`` [``rho_theta_units``: pixel, or arcmin with a ``wcs``], ``xi``,
        ``sigma_xi``, ``npairs``, or None with fewer than 10 measured stars),
        ``rho_theta_units``, ``rho1_mean_abs``, the fourth moments' residuals and their
        correlation functions (``dM22_rel_mean``, ``dM22_rel_rms``, ``dM4_rel_rms``,
        ``rho_M4``, ``rho_eM4``, ``rho_M22``, ``rho_TM22``: see :func:`measure_residuals`),
        ``spatial_model`` (the model's ``spatial_model_``: "constant" when its stars were
        too few for the interpolator), ``moments`` ("adaptive", or the fixed
        weight of the moments of undersampled stars, see 4.), ``n_reserved_outliers`` and
        ``reserved_outliers`` (their rows in X), and, with candidates,
        ``cv`` (list of per-scheme mean/std scores) and ``scheme`` (the chosen one). The
        verdict: ``n_components`` and ``components_reason`` (text: the noise edge and the
        variance of the last kept and first dropped components over it), ``n_verdict``
        (reserved stars used), ``chi2_dof_median`` / ``chi2_dof_median_constant`` (median of
        the stars' chi^2 per degree of freedom against the model / the constant PSF; 1 = pure
        noise), ``chi2_total`` /
        ``chi2_total_constant`` (summed over the stars), ``e_noise`` (rms ellipticity noise
        per component), ``e_resid_over_noise`` / ``e_resid_over_noise_constant`` (rms of the
        e residuals over the rms e noise), ``e_model_error`` (the residuals' rms per component
        of e with the noise removed in quadrature: the model's own error),
        ``dM22_resid_over_noise`` / ``dM4_resid_over_noise`` (rms of the spin-0 / spin-2
        fourth moments' residuals over the rms of their noise, from the same draws; NaN for
        undersampled stars), ``kriging_range``
        and ``star_spacing`` (median nearest-star distance, in the Kriging's coordinates;
        None without Kriging) and ``warnings`` (list of texts).

    Warns
    -----
    PSFQualityWarning
        When the model looks untrustworthy (see 5.).

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
    >>> summary["n_reserved"], len(res)
    (20, 20)
    >>> bool(summary["e_rms"] < 0.05)
    True

    At S/N 200 the 60 fitted stars are too few for this PSF's variations: the reserved
    stars' ellipticity residuals are 3 times their noise (a constant PSF: 6 times), and
    a :class:`PSFQualityWarning` says so.

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
