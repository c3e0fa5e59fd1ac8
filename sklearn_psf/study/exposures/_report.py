"""The report section of the multi-exposure study: per regime, the exponent with N, the
correlation between exposures, the ratio to the exposure oracle and the verdict against Stage IV."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from astropy.table import Table

from ...metrics import ELL_RANGE, survey_table
from .._names import ORACLE
from ._plot import _regimes, plot_sigma_sys_vs_exposures

STAGE_IV = float(survey_table()["sigma_sys2"][2])

#: Where the regimes come from (the report's "Assumptions" paragraph).
LITERATURE = (
    "Regimes. The simulated PSF of exposure e is a static (optical) pattern fixed to the chip "
    "plus an atmospheric pattern drawn afresh for each exposure, both Gaussian random fields "
    "with the same power spectrum (P(k) ~ k^-11/4, Kolmogorov-like, after Rowe 2010) and the "
    "same smallest scale (8 arcsec), hence the same correlation lengths; only their variances "
    "differ. The simulation's default, atmospheric / static rms 0.5 (variance ratio 0.25: 80% "
    "of the PSF variance static), is the long-exposure regime: Heymans et al. (2012, MNRAS "
    "421, 381; CFHT) measure the amplitude of the atmospheric PSF ellipticity pattern to fall "
    "as t^-1/2 with exposure time t (its variance as 1/t), negligible beyond t = 180 s, "
    "correlated on scales below a few arcmin and uncorrelated between exposures more than "
    "50 s apart (which the simulation's independent atmospheres assume). Shorter exposures "
    "move towards the atmosphere: DES (90 s exposures) models the PSF of every exposure on "
    "its own for that reason (PSFEx per CCD, Jarvis et al. 2016, MNRAS 460, 2245; Piff over "
    "the focal plane, Jarvis et al. 2021, MNRAS 501, 1282), HSC (Mandelbaum et al. 2018, "
    "PASJ 70, S25) fits PSFEx per CCD and exposure, and Rubin's 15 s exposures may be "
    "dominated by the atmosphere (Chang et al. 2012, MNRAS 427, 2572). The study sweeps the "
    "variance ratio over 0.2, 1 and 5 (static 83%, 50%, 17%): with variance ~ 1/t, a factor "
    "25 in exposure time. None of these papers gives the ratio for a given telescope and "
    "time in the simulation's units: the ratios are a bracket, not a calibration.")


def _regime_key(row):
    cols = row.colnames
    return (float(row["variance_ratio"]) if "variance_ratio" in cols else float("nan"),
            float(row["dither"]) if "dither" in cols else float("nan"))


def _medians(scores) -> Table:
    """Median and 84th percentile of sigma_sys2 per (scheme, n_stars, n_exposures)."""
    keys = ("scheme", "n_stars", "n_exposures")
    groups = {}
    for row in scores:
        groups.setdefault(tuple(row[k] for k in keys), []).append(float(row["sigma_sys2"]))
    rows = [(str(s), int(m), int(n), float(np.median(v)), float(np.percentile(v, 84)), len(v))
            for (s, m, n), v in groups.items()]
    return Table(rows=rows, names=[*keys, "sigma_sys2_median", "sigma_sys2_p84",
                                   "n_simulations"])


def _slope(med, scheme, m):
    """Exponent of a power law in N fitted to a scheme's medians at N >= 2 (and intercept)."""
    sub = med[(med["scheme"] == scheme) & (med["n_stars"] == m) & (med["n_exposures"] >= 2)]
    if len(sub) < 2:
        return np.nan, np.nan
    slope, icpt = np.polyfit(np.log(np.asarray(sub["n_exposures"], float)),
                             np.log(np.asarray(sub["sigma_sys2_median"], float)), 1)
    return float(slope), float(icpt)


def cheapest_configuration(result, requirement: float = STAGE_IV) -> dict:
    """The cheapest configuration whose median sigma_sys^2 meets a requirement.

    Over the schemes a user can run (the exposure oracle, which knows the truth, is left
    out). Cheapest = fewest stars in all (stars per exposure x exposures), then fewest
    exposures. When none meets it, each (scheme, stars per exposure) is given at its largest
    number of exposures with its shortfall (median / requirement) and the number of exposures
    a power law sigma_sys^2 ~ N^slope fitted to its medians (N >= 2) would need, an
    extrapolation (inf beyond 10^4 exposures or when sigma_sys^2 does not fall).

    Parameters
    ----------
    result : ExposureStudyResult
        Of one regime (or a table without regime columns).
    requirement : float, default=Stage IV's (1.25e-7, :func:`~sklearn_psf.metrics.survey_table`)

    Returns
    -------
    verdict : dict
        ``met`` (bool), ``best`` (row of the cheapest configuration, or None) and
        ``shortfalls`` (list of dicts: scheme, n_stars, n_exposures, sigma_sys2_median,
        factor, slope, n_needed).

    Examples
    --------
    >>> from astropy.table import Table
    >>> from sklearn_psf.study.exposures import cheapest_configuration
    >>> from sklearn_psf.study.exposures import ExposureStudyResult
    >>> scores = Table({"scheme": ["pooled"] * 3, "n_stars": [100] * 3,
    ...                 "n_exposures": [1, 2, 4], "sigma_sys2": [4e-6, 2e-6, 1e-6]})
    >>> v = cheapest_configuration(ExposureStudyResult(scores, Table(), None))
    >>> v["met"], round(v["shortfalls"][0]["factor"], 1), round(v["shortfalls"][0]["n_needed"])
    (False, 8.0, 32)
    """
    med = _medians(result.scores)
    med = med[med["scheme"] != ORACLE]
    ok = med[med["sigma_sys2_median"] < requirement]
    best = None
    if len(ok):
        ok["total_stars"] = ok["n_stars"] * ok["n_exposures"]
        ok.sort(["total_stars", "n_exposures", "sigma_sys2_median"])
        best = {k: ok[0][k].item() if hasattr(ok[0][k], "item") else ok[0][k]
                for k in ok.colnames}
    shortfalls = []
    for scheme in dict.fromkeys(med["scheme"]):
        for m in np.unique(med["n_stars"]):
            sub = med[(med["scheme"] == scheme) & (med["n_stars"] == m)]
            if not len(sub):
                continue
            sub.sort("n_exposures")
            last = sub[-1]
            slope, icpt = _slope(med, scheme, m)
            n_needed = np.nan
            if np.isfinite(slope):
                n_needed = np.inf
                if slope < 0:
                    n_needed = float(np.exp((np.log(requirement) - icpt) / slope))
                    n_needed = n_needed if n_needed <= 1e4 else np.inf
            shortfalls.append({"scheme": str(scheme), "n_stars": int(m),
                               "n_exposures": int(last["n_exposures"]),
                               "sigma_sys2_median": float(last["sigma_sys2_median"]),
                               "factor": float(last["sigma_sys2_median"]) / requirement,
                               "slope": float(slope), "n_needed": n_needed})
    return {"met": best is not None, "best": best, "shortfalls": shortfalls,
            "requirement": requirement}


def _paired(scores, a, b, column="sigma_sys2", power=1):
    """Per (n_stars, n_exposures): fraction of simulations where a < b, median ratio a / b,
    and the 16-84% range of the ratio, of ``column`` to the power ``power``."""
    rows = []
    s = np.asarray(scores["scheme"]).astype(str)
    for m in np.unique(scores["n_stars"]):
        for n in np.unique(scores["n_exposures"]):
            sel = (np.asarray(scores["n_stars"]) == m) & (np.asarray(scores["n_exposures"]) == n)
            pa, pb = scores[sel & (s == a)], scores[sel & (s == b)]
            if not len(pa) or len(pa) != len(pb):
                continue
            pa.sort("simulation")
            pb.sort("simulation")
            ratio = (np.asarray(pa[column]) / np.asarray(pb[column])) ** power
            rows.append((int(m), int(n), float(np.mean(ratio < 1)), float(np.median(ratio)),
                         float(np.percentile(ratio, 16)), float(np.percentile(ratio, 84))))
    return rows


def regime_summary(result) -> Table:
    """One row per (regime, scheme, stars per exposure): the exponent of sigma_sys^2 with N,
    the correlation between exposures and the ratio to the exposure oracle.

    Parameters
    ----------
    result : ExposureStudyResult

    Returns
    -------
    table : astropy.table.Table
        ``variance_ratio``, ``dither``, ``scheme``, ``n_stars``, ``slope`` (power law in N
        fitted to the medians at N >= 2), ``rho_exposures`` (median over simulations at the
        largest N), ``n_exposures`` (that N), ``sigma_sys2_median`` (at that N),
        ``oracle_ratio`` (median over simulations of sigma_sys^2 / the oracle's, paired, at
        that N; NaN without oracle), ``oracle_ratio_max`` (largest median ratio over N >= 2),
        ``oracle_ratio_e2`` (the same as ``oracle_ratio`` for the mean squared averaged
        residual ``e_rms_averaged**2``, whose expectation the oracle minimises; NaN without
        that column).

    Examples
    --------
    >>> from astropy.table import Table
    >>> from sklearn_psf.study.exposures import ExposureStudyResult, regime_summary
    >>> scores = Table({"scheme": ["pooled"] * 2, "n_stars": [100] * 2, "simulation": [0, 0],
    ...                 "n_exposures": [2, 8], "sigma_sys2": [4e-6, 1e-6],
    ...                 "rho_exposures": [0.1, 0.1]})
    >>> float(regime_summary(ExposureStudyResult(scores, Table(), None))["slope"][0])
    -1.0
    """
    rows = []
    for (v, d), scores in _regimes(result.scores).items():
        med = _medians(scores)
        schemes = list(dict.fromkeys(np.asarray(scores["scheme"]).astype(str)))
        for scheme in schemes:
            for m in np.unique(scores["n_stars"]):
                sel = (np.asarray(scores["scheme"]).astype(str) == scheme) & (
                    np.asarray(scores["n_stars"]) == m)
                if not sel.any():
                    continue
                n_max = int(np.max(scores["n_exposures"][sel]))
                last = scores[sel & (np.asarray(scores["n_exposures"]) == n_max)]
                ratio = ratio_max = ratio_e2 = np.nan
                if scheme != ORACLE and ORACLE in schemes:
                    paired = [r for r in _paired(scores, scheme, ORACLE) if r[0] == m]
                    ratio = next((r[3] for r in paired if r[1] == n_max), np.nan)
                    ratio_max = max((r[3] for r in paired if r[1] >= 2), default=np.nan)
                    if "e_rms_averaged" in scores.colnames:
                        ratio_e2 = next((r[3] for r in _paired(scores, scheme, ORACLE,
                                                                "e_rms_averaged", 2)
                                         if r[0] == m and r[1] == n_max), np.nan)
                rows.append((v, d, scheme, int(m), _slope(med, scheme, m)[0],
                             float(np.nanmedian(last["rho_exposures"]))
                             if "rho_exposures" in last.colnames and n_max > 1 else np.nan,
                             n_max, float(np.median(last["sigma_sys2"])), ratio, ratio_max,
                             ratio_e2))
    return Table(rows=rows, names=["variance_ratio", "dither", "scheme", "n_stars", "slope",
                                   "rho_exposures", "n_exposures", "sigma_sys2_median",
                                   "oracle_ratio", "oracle_ratio_max", "oracle_ratio_e2"])


def _regime_title(v, d):
    if not np.isfinite(v):
        return ""
    dithers = f"dithers up to {d:g} pixels" if d > 0 else "no dithers"
    return (f"### Atmospheric / static variance {v:g} (static {100 / (1 + v):.0f}% of the PSF "
            f"variance), {dithers}")


def exposure_report_section(result, figure: str | None = "sigma_sys_vs_exposures.png") -> str:
    """Markdown section of the multi-exposure study.

    Parameters
    ----------
    result : ExposureStudyResult
    figure : str or None
        File name of the figure to link.

    Returns
    -------
    text : str

    Examples
    --------
    >>> from astropy.table import Table
    >>> from sklearn_psf.study.exposures import exposure_report_section
    >>> from sklearn_psf.study.exposures import ExposureStudyResult
    >>> scores = Table({"scheme": ["pooled"] * 2, "n_stars": [100] * 2, "simulation": [0, 0],
    ...                 "n_exposures": [1, 10], "sigma_sys2": [5e-6, 1e-7]})
    >>> text = exposure_report_section(ExposureStudyResult(scores, Table(), None))
    >>> "pooled, 10 exposures of 100 stars" in text
    True
    """
    cfg = result.config or {}
    lines = ["## Many exposures: the regime, the pooled model and Stage IV", ""]
    lines += ["sigma_sys^2 (dimensionless) is that of the galaxy-PSF ellipticity residual "
              "averaged over a galaxy's exposures; `per-exposure` fits one PSF model per "
              "exposure, `pooled` one model on the stars of all exposures whose interpolation "
              "has a static and an atmospheric part with their variances and correlation "
              "lengths fitted by maximum likelihood, `oracle` is the "
              "best linear unbiased predictor from the stars of all exposures with the true "
              "static and atmospheric covariances and each star's true coefficient noise "
              "(given the stars' coefficients on the simulation's basis). slope: exponent of a "
              "power law sigma_sys^2 ~ N^slope fitted to the medians at N >= 2; rho: "
              "correlation of a galaxy's residuals between two of its exposures (the averaged "
              "residual's variance goes as 1/N + rho (1 - 1/N)); / oracle: median over "
              "simulations of sigma_sys^2 over the oracle's on the same simulation; "
              "e^2 / oracle: the same for the mean squared averaged residual "
              "(e_rms_averaged^2). Among predictors linear in the stars' coefficients, the "
              "oracle minimises the expectation of the latter (to first order in the errors; "
              "and of any positive quadratic form of the residuals), not sigma_sys^2, which keeps "
              "only D1 at 0.3-3 arcmin in absolute value: a model can fall below the oracle's "
              "sigma_sys^2 on a simulation, and both ratios scatter from one simulation to "
              "the next (a few independent patches of the PSF pattern where the galaxies "
              "lie)."
              + (" Both models use one basis, a StampPCA fitted on the stars of all the "
                 "simulation's exposures (so that they differ only in their interpolation)."
                 if cfg.get("shared_basis") else ""), ""]
    if figure:
        lines += [f"![sigma_sys^2 against the number of exposures, per regime]({figure})", ""]
    summary = regime_summary(result)
    for (v, d), scores in _regimes(result.scores).items():
        title = _regime_title(v, d)
        lines += [title, ""] if title else []
        sub = summary[(np.isnan(summary["variance_ratio"]) if np.isnan(v)
                       else summary["variance_ratio"] == v)
                      & (np.isnan(summary["dither"]) if np.isnan(d) else summary["dither"] == d)]
        lines += ["| scheme | stars/exposure | slope | rho at largest N | sigma_sys^2 at largest "
                  "N | / oracle at largest N | largest / oracle, N >= 2 | e^2 / oracle at "
                  "largest N |",
                  "|---|---|---|---|---|---|---|---|"]
        for r in sub:
            # the oracle's own ratios are its reference, not a figure; n/a: not measured
            missing = "reference" if r["scheme"] == ORACLE else "n/a"
            ratios = [_cell(r[c], f, missing) for c, f in (
                ("oracle_ratio", ".2f"), ("oracle_ratio_max", ".2f"), ("oracle_ratio_e2", ".3f"))]
            lines.append(f"| {r['scheme']} | {r['n_stars']} | {_cell(r['slope'], '.2f')} | "
                         f"{_cell(r['rho_exposures'], '.3f')} | {r['sigma_sys2_median']:.2e} "
                         f"(N = {r['n_exposures']}) | {' | '.join(ratios)} |")
        lines += _paired_lines(scores)
        lines += ["", _verdict_text(cheapest_configuration(
            type(result)(scores, Table(), None)))]
        lines.append("")
    lines += _assumptions(result, cfg)
    return "\n".join(lines) + "\n"


def _cell(value, spec, missing="n/a"):
    """A table cell: ``value`` formatted, or ``missing`` where it is not finite."""
    return format(value, spec) if np.isfinite(value) else missing


def _paired_lines(scores):
    schemes = set(np.asarray(scores["scheme"]).astype(str))
    if not {"pooled", "per-exposure"} <= schemes or "simulation" not in scores.colnames:
        return []
    rows = [r for r in _paired(scores, "pooled", "per-exposure") if r[1] > 1]
    if not rows:
        return []
    return ["", "Pooled / per-exposure sigma_sys^2, paired over simulations: " + "; ".join(
        f"{m} stars x {n}: median {r:.2f} [{lo:.2f}, {hi:.2f}], pooled lower in "
        f"{100 * f:.0f}%" for m, n, f, r, lo, hi in rows) + "."]


def _verdict_text(verdict):
    req = verdict["requirement"]
    if verdict["met"]:
        b = verdict["best"]
        return (f"**Stage IV** (sigma_sys^2 < {req:.1e}, median over simulations): cheapest "
                f"configuration {b['scheme']}, {b['n_exposures']} exposures of {b['n_stars']} "
                f"stars (sigma_sys^2 = {b['sigma_sys2_median']:.2e}).")
    parts = []
    for s in verdict["shortfalls"]:
        need = ""
        if np.isfinite(s["n_needed"]):
            need = (f", N^{s['slope']:.2f} would reach it near {s['n_needed']:.0f} exposures "
                    "(extrapolated)")
        elif np.isfinite(s["slope"]):
            need = f", not within 10^4 exposures at N^{s['slope']:.2f}"
        parts.append(f"{s['scheme']}, {s['n_exposures']} exposures of {s['n_stars']} stars: "
                     f"{s['factor']:.1f}x the requirement{need}")
    return (f"**Stage IV** (sigma_sys^2 < {req:.1e}, median over simulations) is not met; "
            "shortfalls: " + "; ".join(parts) + ".")


def _assumptions(result, cfg):
    if not cfg:
        return []
    shape = cfg.get("image_shape", ("?", "?"))
    theta = cfg.get("theta_bins", ("?", "?"))
    return ["### Assumptions", "",
            f"{cfg.get('n_simulations')} simulations per regime and number of stars (the same "
            f"seeds in every regime); chips of {shape[1]} x {shape[0]} pixels "
            f"({cfg.get('area_arcmin2', float('nan')):.0f} arcmin^2); "
            f"{cfg.get('n_galaxies')} galaxy-PSFs in the part of the sky every exposure sees; "
            f"star S/N {cfg.get('snr')}; dithers uniform within +-dither pixels along x and y; "
            f"PSF variations down to 8 arcsec; D1 over {theta[0]}-{theta[1]} arcmin, "
            f"sigma_sys^2 over multipoles {ELL_RANGE[0]:.0f}-{ELL_RANGE[1]:.0f} (D1 held "
            "constant below the smallest separation and tapered to zero above twice the "
            "largest); galaxy residuals averaged with equal weights over the exposures.", "",
            LITERATURE]


def write_exposure_report(result, directory) -> Path:
    """Write the study's tables, figure and ``exposures.md`` into ``directory``.

    Parameters
    ----------
    result : ExposureStudyResult
    directory : str or os.PathLike

    Returns
    -------
    path : pathlib.Path
        The Markdown file.
    """
    import matplotlib.pyplot as plt


    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    result.scores.write(out / "exposure_scores.csv", overwrite=True)
    regime_summary(result).write(out / "exposure_regimes.csv", overwrite=True)
    fig = plot_sigma_sys_vs_exposures(result)
    fig.savefig(out / "sigma_sys_vs_exposures.png", dpi=110)
    plt.close(fig)
    path = out / "exposures.md"
    path.write_text(exposure_report_section(result), encoding="utf-8")
    return path
