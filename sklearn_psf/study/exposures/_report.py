"""The report section of the multi-exposure study: verdict against Stage IV, paired gains."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from astropy.table import Table

from ...metrics import ELL_RANGE, survey_table

STAGE_IV = float(survey_table()["sigma_sys2"][2])


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


def cheapest_configuration(result, requirement: float = STAGE_IV) -> dict:
    """The cheapest configuration whose median sigma_sys^2 meets a requirement.

    Cheapest = fewest exposures, then fewest stars per exposure. When none meets it, each
    (scheme, stars per exposure) is given at its largest number of exposures with its
    shortfall (median / requirement) and the number of exposures a power law
    sigma_sys^2 ~ N^slope fitted to its medians (N >= 2) would need, an extrapolation (inf
    beyond 10^4 exposures or when sigma_sys^2 does not fall).

    Parameters
    ----------
    result : ExposureStudyResult
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
    ok = med[med["sigma_sys2_median"] < requirement]
    best = None
    if len(ok):
        ok.sort(["n_exposures", "n_stars", "sigma_sys2_median"])
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
            fit = sub[sub["n_exposures"] >= 2]
            slope, n_needed = np.nan, np.nan
            if len(fit) >= 2:
                slope, icpt = np.polyfit(np.log(fit["n_exposures"]),
                                         np.log(fit["sigma_sys2_median"]), 1)
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


def _paired(scores, a="pooled", b="per-exposure"):
    """Per (n_stars, n_exposures): fraction of simulations where a < b, median ratio a / b."""
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
            ratio = np.asarray(pa["sigma_sys2"]) / np.asarray(pb["sigma_sys2"])
            rows.append((int(m), int(n), float(np.mean(ratio < 1)), float(np.median(ratio))))
    return rows


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
    >>> "pooled with 10 exposures" in text
    True
    """
    cfg = result.config
    verdict = cheapest_configuration(result)
    lines = ["## Many exposures: what reaches Stage IV", ""]
    if figure:
        lines += [f"![sigma_sys^2 against the number of exposures]({figure})", ""]
    med = _medians(result.scores)
    lines += ["| scheme | stars/exposure | exposures | sigma_sys^2 median | 84% | simulations |",
              "|---|---|---|---|---|---|"]
    lines += [f"| {r['scheme']} | {r['n_stars']} | {r['n_exposures']} | "
              f"{r['sigma_sys2_median']:.2e} | {r['sigma_sys2_p84']:.2e} | {r['n_simulations']} |"
              for r in med]
    paired = _paired(result.scores) if "simulation" in result.scores.colnames else []
    if paired:
        lines += ["", "Pooled against per-exposure models, paired over simulations:", ""]
        lines += [f"- {m} stars/exposure, {n} exposure{'s' * (n > 1)}: " + (
            f"pooled lower in {100 * f:.0f}% of the simulations, median ratio pooled / "
            f"per-exposure {r:.2f}" + (" (one exposure: nothing to pool, both are one PSFModel, "
                                       "differing only by their interpolators)" if n == 1
                                       else "")) for m, n, f, r in paired]
    req = verdict["requirement"]
    lines.append("")
    if verdict["met"]:
        b = verdict["best"]
        lines.append(f"**Verdict.** The cheapest configuration found to meet Stage IV "
                     f"(sigma_sys^2 < {req:.1e}, median over simulations) is {b['scheme']} with "
                     f"{b['n_exposures']} exposures of {b['n_stars']} stars each "
                     f"(sigma_sys^2 = {b['sigma_sys2_median']:.2e}).")
    else:
        lines.append(f"**Verdict.** No configuration of this study meets Stage IV "
                     f"(sigma_sys^2 < {req:.1e}, median over simulations). Shortfalls:")
        lines.append("")
        for s in verdict["shortfalls"]:
            need = ""
            if np.isfinite(s["n_needed"]):
                need = (f"; a power law N^{s['slope']:.2f} fitted to its medians would reach it "
                        f"near {s['n_needed']:.0f} exposures (an extrapolation)")
            elif np.isfinite(s["slope"]):
                need = (f"; at its fitted rate N^{s['slope']:.2f} it would not reach it within "
                        "10^4 exposures")
            lines.append(f"- {s['scheme']}, {s['n_stars']} stars/exposure, {s['n_exposures']} "
                         f"exposures: sigma_sys^2 = {s['sigma_sys2_median']:.2e}, "
                         f"{s['factor']:.1f} times the requirement{need}.")
    if cfg:
        shape = cfg.get("image_shape", ("?", "?"))
        lines += ["", f"Assumptions: {cfg.get('n_simulations')} simulations per configuration; "
                  f"chips of {shape[1]} x {shape[0]} pixels "
                  f"({cfg.get('area_arcmin2', float('nan')):.0f} arcmin^2), "
                  f"{cfg.get('n_galaxies')} galaxy-PSFs, star S/N {cfg.get('snr')}, dithers up "
                  f"to {cfg.get('dither')} pixels, atmospheric / static pattern rms "
                  f"{cfg.get('atmosphere_ratio')}, PSF variations down to 8 arcsec; D1 over "
                  f"{cfg['theta_bins'][0]}-{cfg['theta_bins'][1]} arcmin, sigma_sys^2 over "
                  f"multipoles {ELL_RANGE[0]:.0f}-{ELL_RANGE[1]:.0f} (D1 held constant below "
                  "the smallest separation and tapered to zero above twice the largest); "
                  "galaxy residuals are averaged with equal weights over the exposures."]
    return "\n".join(lines) + "\n"


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

    from ._plot import plot_sigma_sys_vs_exposures

    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    result.scores.write(out / "exposure_scores.csv", overwrite=True)
    fig = plot_sigma_sys_vs_exposures(result)
    fig.savefig(out / "sigma_sys_vs_exposures.png", dpi=120)
    plt.close(fig)
    path = out / "exposures.md"
    path.write_text(exposure_report_section(result), encoding="utf-8")
    return path
