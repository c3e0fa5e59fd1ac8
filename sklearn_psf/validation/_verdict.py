"""Whether a fitted PSF model can be trusted: its reserved stars against their own noise.

The reserved stars' pixels are compared with the model's PSF at their positions (flux and
sub-pixel centroid fitted) and with a constant PSF fitted on the same stars (the weighted mean
of the model's coefficients), in units of each star's measurement noise; their ellipticity
residuals are compared with the ellipticity noise of each star (Monte Carlo: the model star with
noise drawn from the star's own pixel weights). The summary says how many components the basis
kept and why, and whether the Kriging range found by maximum likelihood is below the stars'
spacing.
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy.spatial import cKDTree

from ..measure import adaptive_moments, fourth_moments
from ..preprocessing import estimate_pixel_weights
from ._residuals import _centroid_shift, _chi2, shape_moments

__all__ = ["PSFQualityWarning"]

#: Residuals beyond this many times the noise (reduced chi^2, or e residual over e noise) warn.
NOISE_LIMIT = 2.0
#: noise realisations per reserved star for its ellipticity (and fourth-moment) noise: the
#: rms over ~100 reserved stars to ~3% (~6% for the fourth moments); 16 took 0.2 s of CPU of
#: a DECam-like CCD's 2.3 s fit
_DRAWS = 8


class PSFQualityWarning(UserWarning):
    """A fitted PSF model looks untrustworthy on its reserved stars.

    Issued by :func:`~sklearn_psf.validation.fit_and_validate` (whose summary keeps the texts
    in ``warnings``) when the model fits its reserved stars no better than a constant PSF,
    when their residuals exceed twice their measurement noise, or when the Kriging found no
    spatial correlation; ``sklearn-psf fit`` prints them.

    Examples
    --------
    >>> import warnings
    >>> from sklearn_psf.validation import PSFQualityWarning
    >>> with warnings.catch_warnings():
    ...     warnings.simplefilter("error", PSFQualityWarning)   # make a bad model fail
    ...     issubclass(PSFQualityWarning, UserWarning)
    True
    """


def _e_noise(model, w, rng, measure=adaptive_moments, fourth=False):
    """Per-star noise of e1 and e2: std over noise draws around the model star; with
    ``fourth`` also that of the fourth moments M22, M31, M13 (pixels^4), else None."""
    n, p = model.shape
    s = int(round(np.sqrt(p)))
    sigma = np.where(w > 0, 1.0 / np.sqrt(np.where(w > 0, w, 1.0)), 0.0)
    draws = model[:, None, :] + rng.standard_normal((n, _DRAWS, p)) * sigma[:, None, :]
    mask = np.broadcast_to((w > 0)[:, None, :], draws.shape).astype(np.float64)
    mom = measure(draws.reshape(-1, s, s), weights=mask.reshape(-1, s, s))
    ok = (np.asarray(mom["flag"]) == 0).reshape(n, _DRAWS)
    values = {q: mom[q] for q in ("e1", "e2")}
    if fourth:
        values.update(fourth_moments(np.where(mask > 0, draws, np.nan).reshape(-1, s, s),
                                     mom))
    out = {}
    for q in ("e1", "e2") + (("M22", "M31", "M13") if fourth else ()):
        v = np.where(ok, np.asarray(values[q], dtype=np.float64).reshape(n, _DRAWS), np.nan)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            out[q] = np.where(ok.sum(axis=1) >= 4, np.nanstd(v, axis=1, ddof=1), np.nan)
    e = np.column_stack([out["e1"], out["e2"]])
    return e, (np.column_stack([out["M22"], out["M31"], out["M13"]]) if fourth else None)


def _constant_psf(model, offsets=None):
    """The unit-sum PSF of a constant model in the same basis: the coefficients' mean over the
    kept stars, each weighted by its inverse noise variance when the basis gives it (drawn at
    each of ``offsets`` when given: (n, p))."""
    coef = np.asarray(model.coefficients_, dtype=np.float64)[model.inlier_mask_]
    var = getattr(model, "coefficient_var_", None)
    if var is not None:
        w = 1.0 / np.maximum(np.asarray(var, dtype=np.float64)[model.inlier_mask_], 1e-300)
        mean = (w * coef).sum(axis=0) / w.sum(axis=0)
    else:
        mean = coef.mean(axis=0)
    if offsets is not None:
        stamps = model.basis_.render(np.tile(mean, (len(offsets), 1)), offsets=offsets)
        return stamps / stamps.sum(axis=1, keepdims=True)
    stamp = np.asarray(model.basis_.inverse_transform(mean[None, :]), dtype=np.float64)[0]
    return stamp / stamp.sum()


def _components(model):
    """(k, reason) of the fitted basis."""
    basis = model.basis_
    k = int(model.n_components_)
    edge = getattr(basis, "noise_edge_", np.nan)
    lam = np.asarray(getattr(basis, "explained_variance_", []), dtype=np.float64)
    if edge is not None and np.isfinite(edge) and edge > 0 and lam.size:
        ratios = [f"component {i + 1} {lam[i] / edge:.2g} times" for i in (k - 1, k)
                  if 0 <= i < lam.size]
        return k, ("those above the noise edge, the largest variance noise alone would give "
                   "these stars (" + ", ".join(ratios) + " the edge)")
    n_comp = getattr(basis, "n_components", None)
    if isinstance(n_comp, float) and 0 < n_comp < 1:
        return k, f"the components holding {n_comp:.0%} of the variance"
    return k, "fixed by the basis"


def _kriging_range(model):
    """(range, median nearest-neighbour spacing of the stars) in the Kriging's coordinates,
    or None when the interpolator is not a fitted Kriging."""
    final = model.interpolator_
    while hasattr(final, "steps"):
        final = final.steps[-1][1]
    if not hasattr(final, "range_") or not hasattr(final, "X_fit_"):
        return None
    P = np.asarray(final.X_fit_, dtype=np.float64)
    if len(getattr(final, "extra_scaling_", ())):  # extra dimensions: the positions' spacing
        P = P[:, :2]
    if len(P) < 3:
        return None
    scale = np.ones(P.shape[1])
    if getattr(final, "anisotropy_scaling_", 1.0) not in (None, 1.0) and P.shape[1] == 2:
        scale[1] = float(final.anisotropy_scaling_)
    d, _ = cKDTree(P * scale).query(P * scale, k=2)
    return float(final.range_), float(np.median(d[:, 1]))


def model_verdict(model, X, stamps, weights, reserved, residuals, random_state=0,
                  sigma=None, offsets=None):
    """The verdict entries of :func:`fit_and_validate`'s summary (see there), and warnings.

    ``stamps`` (n, p) raw, NaN = masked; ``weights`` (n, p) or None (estimated stamp by
    stamp); ``reserved`` the rows of the reserved stars; ``residuals`` their table. For
    undersampled stars, ``sigma`` is the fixed weight of their moments and ``offsets`` their
    sub-pixel positions, at which the model's stamps (``residuals["stamp_model"]``) and the
    constant PSF are drawn.
    """
    k, reason = _components(model)
    out = {"n_components": k, "components_reason": reason, "chi2_dof_median": np.nan,
           "chi2_dof_median_constant": np.nan, "e_noise": np.nan,
           "e_resid_over_noise": np.nan,
           "e_resid_over_noise_constant": np.nan, "e_model_error": np.nan,
           "dM22_resid_over_noise": np.nan, "dM4_resid_over_noise": np.nan, "n_verdict": 0,
           "kriging_range": None,
           "star_spacing": None, "warnings": []}
    found = _kriging_range(model)
    if found is not None:
        out["kriging_range"], out["star_spacing"] = found
        if found[0] < found[1]:
            out["warnings"].append(
                f"maximum likelihood finds no spatial correlation of the PSF: the Kriging "
                f"range ({found[0]:.3g}) is below the stars' typical spacing ({found[1]:.3g}, "
                "median distance to the nearest star, the same units): between stars the "
                "model is close to a constant PSF")
    ok = np.asarray(residuals["flag"]) == 0
    rows = np.asarray(reserved)[ok]
    if rows.size < 5:
        return out
    y = np.asarray(stamps, dtype=np.float64)
    w = estimate_pixel_weights(y) if weights is None else np.asarray(weights, np.float64)
    d, w = np.where(np.isfinite(y[rows]), y[rows], 0.0), np.where(np.isfinite(y[rows]),
                                                                    w[rows], 0.0)
    n, p = d.shape
    s = int(round(np.sqrt(p)))
    # the model's chi^2 is measure_residuals' (flux, background and centroid fitted); the
    # constant PSF is measured the same way
    psf = np.asarray(residuals["stamp_model"], dtype=np.float64)[ok]
    chi2 = np.asarray(residuals["chi2"], dtype=np.float64)[ok]
    measure = shape_moments(sigma)
    if sigma is None:
        _, _, fitted = _chi2(d, w, psf, _centroid_shift(d, w, psf),
                             return_model=True)
        const = np.broadcast_to(_constant_psf(model), (n, p))
        chi2_c, _ = _chi2(d, w, const, _centroid_shift(d, w, const))
    else:  # undersampled: the model and the constant PSF at each star's phase
        _, _, fitted = _chi2(d, w, psf, return_model=True)
        const = _constant_psf(model, np.asarray(offsets, dtype=np.float64)[ok])
        chi2_c, _ = _chi2(d, w, const)
    dof = np.maximum(np.asarray(residuals["dof"], dtype=np.float64)[ok], 1)
    chi2, chi2_c = chi2 / dof, chi2_c / dof
    rng = np.random.default_rng(random_state)
    noise, noise4 = _e_noise(fitted, w, rng, measure, fourth=sigma is None)
    e_const = measure(const.reshape(n, s, s))
    de = np.column_stack([residuals["de1"], residuals["de2"]])[ok]
    de_c = np.column_stack([residuals["e1_star"], residuals["e2_star"]])[ok] - np.column_stack(
        [np.asarray(e_const["e1"], dtype=np.float64), np.asarray(e_const["e2"], np.float64)])
    good = np.isfinite(noise).all(axis=1) & (noise > 0).all(axis=1)
    out.update({
        "chi2_dof_median": float(np.nanmedian(chi2)),
        "chi2_dof_median_constant": float(np.nanmedian(chi2_c)),
        "chi2_total": float(np.nansum(chi2 * dof)),
        "chi2_total_constant": float(np.nansum(chi2_c * dof)),
        "n_verdict": int(n),
    })
    if good.sum() >= 5:
        out["e_noise"] = float(np.sqrt(np.mean(noise[good] ** 2)))
        var = np.mean(noise[good] ** 2)
        out["e_resid_over_noise"] = float(np.sqrt(np.mean(de[good] ** 2) / var))
        out["e_resid_over_noise_constant"] = float(np.sqrt(np.mean(de_c[good] ** 2) / var))
        out["e_model_error"] = float(np.sqrt(max(np.mean(de[good] ** 2) - var, 0.0)))
    if noise4 is not None:  # the fourth moments' residuals against their noise
        d4 = np.column_stack([residuals[q] for q in ("dM22", "dM31", "dM13")])[ok]
        fine = np.isfinite(noise4).all(axis=1) & np.isfinite(d4).all(axis=1)
        if fine.sum() >= 5:
            out["dM22_resid_over_noise"] = float(np.sqrt(
                np.mean(d4[fine, 0] ** 2) / np.mean(noise4[fine, 0] ** 2)))
            out["dM4_resid_over_noise"] = float(np.sqrt(
                np.mean(d4[fine, 1:] ** 2) / np.mean(noise4[fine, 1:] ** 2)))
    if out["chi2_total"] >= out["chi2_total_constant"] and \
            getattr(model, "spatial_model_", None) != "constant":  # (a constant is no better)
        out["warnings"].append(
            f"the model fits its {n} reserved stars no better than a constant PSF fitted on "
            f"the same stars (chi^2 summed over them {out['chi2_total']:.4g} against "
            f"{out['chi2_total_constant']:.4g}): either the PSF does not vary measurably "
            "over the field, or the model does not follow it")
    beyond = []
    if out["chi2_dof_median"] > NOISE_LIMIT:
        beyond.append("their median chi^2 per degree of freedom is "
                      f"{out['chi2_dof_median']:.2f}")
    if out["e_resid_over_noise"] > NOISE_LIMIT:
        beyond.append(f"their ellipticity residuals are {out['e_resid_over_noise']:.2f} times "
                      f"their ellipticity noise: beyond the noise, the model's own error is "
                      f"about {out['e_model_error']:.3g} per component of e")
    if beyond:
        out["warnings"].append(
            f"the reserved stars' residuals exceed their measurement noise (limit: "
            f"{NOISE_LIMIT:g} times): " + "; ".join(beyond) + ". Causes: the PSF varies on "
            "scales the stars do not sample (too few stars), contaminated stars or galaxies "
            "taken as stars, too few components, or pixel weights that underestimate the noise")
    return out
