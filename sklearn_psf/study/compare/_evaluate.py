"""Model minus truth at the galaxy-PSFs: scores, correlation functions, per-galaxy rows."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ...measure import adaptive_moments, fourth_moments
from ...metrics import ellipticity_correlation, shear_bias_bound, sigma_sys2
from ._schemes import ARCMIN


def _local_density(X_stars, X_galaxies, radius_pixels):
    """Number of stars within ``radius_pixels`` of each galaxy-PSF."""
    return cKDTree(X_stars).query_ball_point(X_galaxies, r=radius_pixels, return_length=True)


def _rms(a):
    return float(np.sqrt(np.nanmean(np.square(a))))


def _evaluate(model, X_gal, gal, theta_bins, pixel_scale, same_basis=True):
    """Model minus truth at galaxy-PSFs: scalar scores, correlation functions, per-galaxy rows."""
    stamps = model.predict(X_gal)
    mom = adaptive_moments(stamps)
    ok = (np.asarray(mom["flag"]) == 0) & (np.asarray(gal["flag"]) == 0)
    if ok.sum() < 2:
        raise RuntimeError("adaptive moments failed on almost every model PSF.")
    e1_m, e2_m = np.asarray(mom["e1"]), np.asarray(mom["e2"])
    e1_t, e2_t = np.asarray(gal["e1"]), np.asarray(gal["e2"])
    coeffs_t = np.asarray(gal["coeffs"])
    # a model with its own basis has coefficients that cannot be compared with the truth's
    coeffs_m = (model.predict_coefficients(X_gal) if same_basis
                else np.full((len(X_gal), coeffs_t.shape[1]), np.nan))
    k = min(coeffs_m.shape[1], coeffs_t.shape[1])
    de1, de2 = (e1_m - e1_t)[ok], (e2_m - e2_t)[ok]

    pos = X_gal[ok] * pixel_scale / ARCMIN
    min_sep, max_sep, nbins = theta_bins
    xi = {}
    for kind, (a, b) in {
        "input": (e1_t[ok], e2_t[ok]),
        "model": (e1_m[ok], e2_m[ok]),
        "residual": (de1, de2),
    }.items():
        # one thread: TreeCorr's threaded sums vary in the last digits from run to run, and
        # the study is parallel over simulations already
        xi[kind] = ellipticity_correlation(pos, a, b, min_sep=min_sep, max_sep=max_sep,
                                           nbins=nbins, num_threads=1)
    theta = np.asarray(xi["residual"].theta_nominal)
    d1 = np.asarray(xi["residual"].xi)
    filled = np.isfinite(d1)  # bins without pairs (small fields) are left out of the integral
    implied = (float(sigma_sys2(theta[filled], shear_bias_bound(d1[filled])))
               if filled.sum() >= 2 else np.nan)
    if "M22" in gal:  # fourth moments, model - truth, over the true sigma^4
        four = fourth_moments(stamps, mom)
        s4 = np.asarray(gal["sigma"], dtype=float)[ok] ** 4
        dm = {q: (np.asarray(four[q]) - np.asarray(gal[q]))[ok] / s4
              for q in ("M22", "M31", "M13")}
        fourth = {"dM22_rel_rms": _rms(dm["M22"]),
                  "dM4_rel_rms": _rms(np.hypot(dm["M31"], dm["M13"]))}
    else:  # not measured in this configuration
        fourth = {"dM22_rel_rms": np.nan, "dM4_rel_rms": np.nan}
    scores = {
        "e_rms": _rms(np.hypot(de1, de2)),
        "e1_rms": _rms(de1),
        "e2_rms": _rms(de2),
        "coeff_rms": _rms(coeffs_m[:, :k] - coeffs_t[:, :k]),
        "rho1_mean_abs": float(np.nanmean(np.abs(d1))) if filled.any() else np.nan,
        "sigma_sys2": implied,
        **fourth,
    }
    rows = {
        "x": X_gal[:, 0],
        "y": X_gal[:, 1],
        "e1_true": e1_t,
        "e2_true": e2_t,
        "e1_model": np.where(ok, e1_m, np.nan),
        "e2_model": np.where(ok, e2_m, np.nan),
        "coeffs_true": coeffs_t[:, :4],
        "coeffs_model": coeffs_m[:, :4],
    }
    return scores, xi, rows
