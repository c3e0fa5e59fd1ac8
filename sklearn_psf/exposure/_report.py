"""The report of :func:`~sklearn_psf.exposure.fit_exposure`, line by line: what was
selected, then the verdict's summary in words."""

from __future__ import annotations

import numpy as np

from ._select import SELECTION_REASONS


def _selection_lines(counts, n_kept, head, max_spread_model, min_class_star):
    """The selection's counts in words: kept, rejected by cut, the locus, the S/N's origin,
    the secondary cuts not applied."""
    rejected = ", ".join(f"{k} {counts[k]}" for k in SELECTION_REASONS if counts.get(k))
    lines = [f"{head}{n_kept}" + (f" (rejected: {rejected})" if rejected else "")]
    size = {"flux_radius": "FLUX_RADIUS", "adaptive_sigma": "adaptive-moment sigma of the "
            "VIGNETs", "adaptive_sigma_masked": "adaptive-moment sigma of the VIGNETs, "
            "neighbours masked"}.get(counts.get("locus_size"))
    if size and np.isfinite(counts["locus_radius"]):
        lines.append(f"  size-magnitude locus: {size} {counts['locus_radius']:.3g} pixels "
                     f"(median over the selected stars), accepted within +-"
                     f"{counts['locus_width']:.1%} (median; wider at low S/N)")
    if counts.get("snr_from") == "vignets":
        lines.append("  S/N: in a Gaussian window on the VIGNETs, as Source Extractor's SNR_WIN "
                     "(the catalogue has none; its fluxes' S/N is lower for faint stars)")
    cuts = {"class_star": f"CLASS_STAR >= {min_class_star:g}",
            "spread_model": f"|SPREAD_MODEL| <= {max_spread_model:g}"}
    for name, fraction in counts.get("not_applied", {}).items():
        lines.append(f"  not applied: {cuts[name]}, which would reject {fraction:.0%} of the "
                     "sources on the size-magnitude locus"
                     + (" (the locus decides: SExtractor's CLASS_STAR depends on the "
                        "SEEING_FWHM and detection threshold it was given)"
                        if name == "class_star" else ""))
    return lines


def _report(summary):
    """The lines of the report after the selection: basis, residuals, verdict."""
    from ..model._psf_model import MIN_LIKELIHOOD_STARS

    lines = []
    if "cv" in summary:
        lines.append("cross-validation (e rms): " + ", ".join(
            f"{r['scheme']} {r['e_rms']:.4f}" for r in summary["cv"])
            + f" -> {summary['scheme']}")
    interpolator = summary["interpolator"]
    if summary.get("spatial_model") == "constant":  # too few stars for its likelihood
        interpolator = (f"a constant PSF ({summary['n_inliers']} stars kept are fewer than "
                        f"the {MIN_LIKELIHOOD_STARS} that {interpolator}'s maximum likelihood "
                        "needs; PSFEx lowers its degree likewise)")
    lines.append(f"interpolator: {interpolator}; fitted stars: {summary['n_fit']}, "
                 f"outliers rejected: {summary['n_outliers']}, reserved: "
                 f"{summary['n_reserved']}")
    if "pixel_noise" in summary:
        noise = summary["pixel_noise"]
        gain = summary.get("gain")
        poisson = (f"a Poisson term of {noise['poisson']:.3g} per unit of flux (a gain of "
                   f"{1 / noise['poisson']:.3g} in the stamps' units) missing from them"
                   if noise["poisson"] > 0 else "no Poisson term missing from them")
        lines.append(f"pixel noise learnt from the stars' residuals: {noise['sky']:.3g} times "
                     f"the weights' variance, {poisson}, a model error of "
                     f"{np.sqrt(noise['eps2']):.2%} of each pixel's value (header gain: "
                     f"{'none' if gain is None else f'{gain:g}'}); the outlier test judges "
                     "the stars in it, and against each other")
    if summary.get("contaminated_stamps"):
        lines.append(f"pixels masked as holding light the star's model does not (uncatalogued "
                     f"neighbours, cosmic rays, defects; outside the cores): in "
                     f"{summary['contaminated_stamps']} stamps (median "
                     f"{summary['contaminated_median']} pixels)")
    if "n_components" in summary:
        lines.append(f"basis: {summary['n_components']} components: "
                     f"{summary['components_reason']}")
    if summary.get("kriging_range") is not None:
        lines.append(f"Kriging range (maximum likelihood): {summary['kriging_range']:.3g}; "
                     f"stars' typical spacing: {summary['star_spacing']:.3g} (median distance "
                     "to the nearest star; both in the interpolator's coordinates, the field "
                     "scaled to the unit square)")
    if summary.get("n_reserved_outliers"):
        rows = summary["reserved_outliers"]
        lines.append(f"reserved stars rejected by the outlier test (left out of what follows): "
                     f"{len(rows)} (rows " + ", ".join(map(str, rows[:10]))
                     + (", ..." if len(rows) > 10 else "") + " of the stars used)")
    if summary["n_measured"]:
        lines.append(
            f"reserved stars (star - model, {summary['n_measured']} measured): "
            f"e rms {summary['e_rms']:.4f} (e1 mean {summary['de1_mean']:+.4f} rms "
            f"{summary['de1_rms']:.4f}, e2 mean {summary['de2_mean']:+.4f} rms "
            f"{summary['de2_rms']:.4f}), size mean {summary['dsigma_mean']:+.4f} rms "
            f"{summary['dsigma_rms']:.4f} pixels; {summary.get('moments', 'adaptive')} moments")
    if summary.get("n_verdict"):
        lines.append(
            f"reserved stars against their own noise ({summary['n_verdict']} stars; a constant "
            f"PSF fitted on the same stars in brackets): median chi^2 per degree of freedom "
            f"{summary['chi2_dof_median']:.3f} ({summary['chi2_dof_median_constant']:.3f}); "
            f"e residual rms "
            f"over e noise rms {summary['e_resid_over_noise']:.2f} "
            f"({summary['e_resid_over_noise_constant']:.2f}; e noise per component "
            f"{summary['e_noise']:.4f}); 1 is pure noise")
    if summary.get("rho1"):
        unit = "arcmin" if "wcs" in summary else "pixel"
        means = []
        for k in range(1, 6):
            xi = np.asarray((summary.get(f"rho{k}") or {}).get("xi", []), dtype=float)
            means.append(f"rho{k} {np.nanmean(np.abs(xi)):.2e}" if np.isfinite(xi).any()
                         else f"rho{k} -")
        theta = summary["rho1"]["theta"]
        lines.append(f"rho statistics of the reserved stars (mean |rho| over {len(theta)} bins, "
                     f"{theta[0]:.3g}-{theta[-1]:.3g} {unit}): " + ", ".join(means))
    if np.isfinite(summary.get("dM22_rel_rms", np.nan)):
        lines.append(
            f"fourth moments, same stars (residual star - model over the star's sigma^4; a "
            f"Gaussian's M22 is 2): spin-0 dM22 mean {summary['dM22_rel_mean']:+.2e} rms "
            f"{summary['dM22_rel_rms']:.2e}, spin-2 |dM31 + i dM13| rms "
            f"{summary['dM4_rel_rms']:.2e}"
            + (f"; residual rms over noise rms {summary['dM22_resid_over_noise']:.2f} "
               f"(spin 0), {summary['dM4_resid_over_noise']:.2f} (spin 2)"
               if np.isfinite(summary.get("dM22_resid_over_noise", np.nan)) else ""))
    if summary.get("rho_M4"):
        means = []
        for name in ("rho_M4", "rho_eM4", "rho_M22", "rho_TM22"):
            xi = np.asarray((summary.get(name) or {}).get("xi", []), dtype=float)
            means.append(f"{name} {np.nanmean(np.abs(xi)):.2e}" if np.isfinite(xi).any()
                         else f"{name} -")
        lines.append("their correlation functions (mean |xi|, same bins; M4 = M31 + i M13, "
                     "e and T = 2 sigma^2 of the second moments): " + ", ".join(means))
    return lines
