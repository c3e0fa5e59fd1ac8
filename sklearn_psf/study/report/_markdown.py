"""The text of report.md, section by section."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .._names import DEFAULT_MODEL, ORACLE
from ..plotting._common import _unique_in_order
from ._files import _jsonable
from ._findings import check_findings
from ._summary import PAPER_SURVEYS, _fmt, summarize, survey_verdicts
from ._yardsticks import (
    METRICS,
    MIN_SIMULATIONS,
    d1_rule,
    multipole_sensitivity,
    oracle_ratios,
    underpowered,
)


def _md_table(header, rows):
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c).replace("|", "\\|") for c in row) + " |"
              for row in rows]
    return "\n".join(lines)


def _cell(value):
    if isinstance(value, (float, np.floating)):
        return _fmt(value)
    return str(value)


def _range(summary_row, metric):
    med = summary_row[f"{metric}_median"]
    return f"{_fmt(med)} [{_fmt(summary_row[f'{metric}_p16'])}, " \
           f"{_fmt(summary_row[f'{metric}_p84'])}]"


def _markdown(result, config, schemes, figure_entries, notes, written):
    scores = result.scores
    summary = summarize(scores)
    lines = ["# PSF interpolation study", ""]
    lines += ["After Bergé et al. (2012): PSF models interpolated from stars are evaluated at "
              "galaxy-PSFs, where the true PSF is known. Residuals are model minus truth; "
              "statistics are over simulations (median and 16-84% range).", ""]

    findings = check_findings(result, config)
    lines += _summary_section(result, summary, config, findings)
    lines += _measured_section(result)

    # configuration
    lines += ["## Configuration", ""]
    study_config = getattr(result, "config", None) or {}
    sim_configs = study_config.get("configs") or []
    if study_config:
        lines += [_md_table(["setting", "value"],
                            [(k, json.dumps(_jsonable(v))) for k, v in study_config.items()
                             if k != "configs"]), ""]
    if sim_configs:  # one row per simulated configuration, one column per setting
        keys = [k for k in sim_configs[0] if k != "label"]
        lines += [_md_table(["configuration", *keys],
                            [(c.get("label", ""), *(json.dumps(_jsonable(c.get(k))) for k in keys))
                             for c in sim_configs]), ""]
    configs = _unique_in_order(scores["config"])
    lines += [f"- Configurations: {', '.join(configs)}",
              f"- Schemes: {', '.join(_unique_in_order(scores['scheme']))}",
              f"- Rows in the scores table: {len(scores)}", ""]

    # summary per scheme
    lines += [f"## Summary per scheme ({config})", ""]
    base = summary[np.asarray(summary["config"]).astype(str) == config]
    if len(base) == 0:
        lines += [f"No scores for the configuration {config!r}.", ""]
    else:
        metrics = [m for m in ("e_rms", "e_rms_ratio", "coeff_rms", "rho1_mean_abs", "sigma_sys2",
                               "dM22_rel_rms", "dM4_rel_rms")
                   if f"{m}_median" in summary.colnames]
        header = ["scheme", "simulations"] + [f"{m} median [16%, 84%]" for m in metrics]
        rows = []
        for r in base:
            failed = f" ({r['n_failed']} failed)" if "n_failed" in base.colnames and \
                r["n_failed"] else ""
            rows.append([r["scheme"], f"{r['n_simulations']}{failed}"] +
                        [_range(r, m) for m in metrics])
        lines += [_md_table(header, rows), ""]

        # ranking
        ranked = sorted(base, key=lambda r: (not np.isfinite(r["e_rms_median"]),
                                             r["e_rms_median"]))
        lines += ["### Ranking by e_rms (median, lower is better)", ""]
        lines += [f"{i + 1}. {r['scheme']}: {_fmt(r['e_rms_median'])}"
                  for i, r in enumerate(ranked)]
        lines += [""]

    other = [c for c in configs if c != config]
    if other and "e_rms_median" in summary.colnames:
        lines += ["## Other configurations", ""]
        cols = [m for m in ("e_rms", "sigma_sys2") if f"{m}_median" in summary.colnames]
        rows = [[r["config"], r["scheme"], r["n_simulations"]] + [_range(r, m) for m in cols]
                for r in summary if str(r["config"]) != config]
        lines += [_md_table(["config", "scheme", "simulations"] +
                            [f"{m} median [16%, 84%]" for m in cols], rows), ""]

    lines += _oracle_section(result, config)
    lines += _defaults_section(summary, config)

    # surveys
    lines += ["## Survey requirements", ""]
    surveys = getattr(result, "surveys", None)
    if "sigma_sys2" in scores.colnames:
        if surveys is None:
            lines += ["The result has no survey table: the paper's table 1 is used "
                      "(Amara & Refregier 2008, eq. 21).", ""]
        verdicts = survey_verdicts(scores, surveys, config)
        n_sim = int(base["n_simulations"].max()) if len(base) else 0
        lines += ["A scheme meets a survey's requirement when its median sigma_sys^2 over "
                  f"simulations (integrated over multipoles {ELL_RANGE_TEXT}) is below the "
                  f"survey's limit{underpowered(n_sim)}.", ""]
        rows = []
        for r in verdicts:
            word = "meets" if r["meets"] else "does not meet"
            sign = "<" if r["meets"] else ">="
            rows.append([r["scheme"], r["survey"],
                         f"{word} ({_fmt(r['sigma_sys2_median'])} {sign} "
                         f"{_fmt(r['requirement'])})", _fmt(r["sigma_sys2_p84"])])
        lines += [_md_table(["scheme", "survey", "verdict (median vs limit)",
                             "84th percentile"], rows), ""]
        lines += _assumption_sections(result, surveys if surveys is not None else PAPER_SURVEYS,
                                      config)
    else:
        lines += ["Not evaluated: the scores have no sigma_sys2 column.", ""]

    # findings
    lines += ["## The paper's findings checked against these data", ""]
    rows = [[f["finding"], f["verdict"] + f.get("power", ""), f["evidence"]]
            for f in findings]
    lines += [_md_table(["finding (Bergé et al. 2012)", "verdict", "evidence"], rows), ""]

    tuning = getattr(result, "tuning", None)
    if tuning is not None and len(tuning):
        lines += ["## Hyperparameters chosen by cross-validation", ""]
        lines += [_md_table(tuning.colnames,
                            [[_cell(row[c]) for c in tuning.colnames] for row in tuning]), ""]

    # figures
    lines += ["## Figures", ""]
    if not figure_entries:
        lines += ["No figures were written.", ""]
    for name, caption in figure_entries:
        lines += [f"![{name}]({name})", "", f"*{name}: {caption}*", ""]
    if notes:
        lines += ["## Notes", ""] + [f"- {n}" for n in notes] + [""]
    lines += ["## Files", ""] + [f"- `{Path(p).name}`" for p in written] + ["- `report.md`", ""]
    return "\n".join(lines)


def _summary_section(result, summary, config, findings):
    """What was found, first: the ranking against the optimum, the surveys' verdicts, the
    library's defaults and the paper's findings, each pointing to its section below."""
    base = summary[np.asarray(summary["config"]).astype(str) == config]
    if len(base) == 0 or "e_rms_median" not in base.colnames:
        return []
    study = getattr(result, "config", None) or {}
    n_sim = int(base["n_simulations"].max())
    lines = ["## Summary", ""]
    if study.get("quick") or n_sim < MIN_SIMULATIONS:
        lines += [f"{'A `--quick` run: ' if study.get('quick') else ''}{n_sim} simulation"
                  f"{'s' if n_sim != 1 else ''} of the `{config}` configuration, fewer than "
                  f"the {MIN_SIMULATIONS} a verdict needs: the verdicts are underpowered.", ""]
    ratios = oracle_ratios(result, config)
    ratio = {} if ratios is None else {str(r["scheme"]): r["e_rms_ratio_median"]
                                       for r in ratios}
    ranked = sorted((r for r in base if str(r["scheme"]) != ORACLE
                     and np.isfinite(r["e_rms_median"])), key=lambda r: r["e_rms_median"])

    def entry(r):
        scheme = str(r["scheme"])
        return f"{scheme} {_fmt(r['e_rms_median'])}" + (
            f" ({ratio[scheme]:.2f}x the oracle)" if scheme in ratio else "")

    if ranked:
        best = ", ".join(entry(r) for r in ranked[:3])
        lines += [f"- **Ranking** (median e_rms at the galaxy-PSFs, `{config}`; "
                  "\"Summary per scheme\"): best " + best
                  + (f"; worst {entry(ranked[-1])}" if len(ranked) > 3 else "")
                  + (f". The optimum on the same fields, `{ORACLE}`: "
                     f"{_fmt(float(base[np.asarray(base['scheme']) == ORACLE]['e_rms_median'][0]))}"
                     if ORACLE in np.asarray(base["scheme"]).astype(str) else "") + "."]
    if "sigma_sys2" in result.scores.colnames:
        verdicts = survey_verdicts(result.scores, getattr(result, "surveys", None), config)
        parts = []
        for survey in _unique_in_order(verdicts["survey"]):
            rows = verdicts[np.asarray(verdicts["survey"]) == survey]
            met = [str(r["scheme"]) for r in rows if r["meets"] and str(r["scheme"]) != ORACLE]
            parts.append(f"{survey} (sigma_sys^2 < {_fmt(rows['requirement'][0])}): "
                         + (f"met by {len(met)} of {len(rows) - (ORACLE in rows['scheme'])} "
                            f"schemes ({', '.join(met)})" if met else "met by none"))
        lines += ["- **Survey requirements** (median sigma_sys^2 against each survey's limit; "
                  "\"Survey requirements\"): " + "; ".join(parts) + "."]
    rows = {str(r["scheme"]): r for r in base}
    paper = next((s for s in ("kriging", "delaunay", "polynomial") if s in rows), None)
    if DEFAULT_MODEL in rows and paper is not None:
        d, p = rows[DEFAULT_MODEL]["e_rms_median"], rows[paper]["e_rms_median"]
        lines += [f"- **The library's defaults** (`{DEFAULT_MODEL}`, \"The library's defaults "
                  f"against the paper's settings\"): e_rms {_fmt(d)}, "
                  f"{abs(100 * (d - p) / p):.1f}% {'above' if d > p else 'below'} the paper's "
                  f"{paper} ({_fmt(p)})."]
    words = {"agrees": "agree", "disagrees": "disagree", "inconclusive": "inconclusive",
             "not tested": "not tested"}
    counts = {word: sum(f["verdict"] == v for f in findings) for v, word in words.items()}
    against = [f["finding"] for f in findings if f["verdict"] == "disagrees"]
    lines += [f"- **The paper's findings** ({len(findings)}; \"The paper's findings checked "
              "against these data\"): " + ", ".join(f"{n} {v}" for v, n in counts.items() if n)
              + (". Disagreeing: " + "; ".join(against) if against else "") + "."]
    later = [name for key, name in (("exposures", "the multi-exposure study"),
                                     ("colour", "the colour study"))
             if key in (study.get("studies") or ())]
    if later:
        lines += [f"- Further sections at the end: {' and '.join(later)}."]
    return lines + [""]


# ----------------------------------------------------------------------------- synthetic data


ELL_RANGE_TEXT = "10 <= l <= 2e4"


def _measured_section(result):
    """What was measured, in which units, under which assumptions."""
    config = getattr(result, "config", None) or {}
    lines = ["## What is measured", ""]
    lines += ["Each simulation is a PSF field whose PCA weights vary as Gaussian random fields "
              "(P(k) ~ k^-11/4) drawn on cells of the field's smallest scale (`smallest_scale`, "
              "arcsec; null = the simulations' default, 8 arcsec). The paper does not give "
              "it, and it sets how well any scheme can do (see the `scale=` configurations "
              "when present). Stars (noisy, measured on the image) train each scheme; "
              "galaxy-PSFs (noiseless truth) test it. Residuals are model minus truth. Scheme "
              "names: the paper's settings (e.g. `kriging`: exponential variogram, range 0.5 "
              "of the unit square, nugget 0; `rbf`: Gaussian kernel, epsilon 10), all in the "
              "paper's PSF model (the simulation's fixed basis, the IQR cut at 3.5); `-cv`: "
              "the same scheme at its cross-validated best (tuning table); "
              "`psfmodel-default`: `PSFModel()` with the library's own defaults (its basis "
              "is fitted on the stars, so its coeff_rms is n/a); `oracle`: see below.", ""]
    if config.get("reference"):
        lines += [f"Reference basis: `{config['reference']}`.", ""]
    lines += [_md_table(["column", "unit", "definition"], METRICS), "",
              "Positions `x`, `y` are in pixels (0-based, x = column), `local_density` counts "
              "stars within 1 arcmin; the FITS tables carry these units (TUNIT).", ""]
    lines += ["Assumptions of the verdicts: sigma_sys^2 integrates over multipoles "
              f"{ELL_RANGE_TEXT} (sensitivity row below); the oracle is co-Kriging of all "
              "coefficients jointly with the simulation's true covariance of the weight fields "
              "and each star's true k x k coefficient noise covariance, to first order in the "
              "pixel noise (the coefficients are the weights up to the stamps' flux "
              "normalisation and centring, a second-order change; the adaptive centroid's "
              "noise, under 3% of the coefficients' variance, is left out). "
              f"Verdicts from fewer than {MIN_SIMULATIONS} simulations are marked "
              "underpowered.", ""]
    if config.get("quick"):
        lines += ["**This is a `--quick` run: too few simulations to decide most verdicts.**", ""]
    return lines



def _oracle_section(result, config):
    table = oracle_ratios(result, config)
    if table is None:
        return []
    theta = np.asarray(result.theta, float)
    lines = ["## Against the optimum on the same fields (oracle)", ""]
    lines += ["`oracle` is the best linear unbiased predictor of all the PSF coefficients "
              "jointly (co-Kriging with a generalised-least-squares mean per component), with "
              "the simulation's true covariance of the weight fields and each star's true "
              "noise covariance, k x k (the components share the star's flux normalisation, "
              "so their noise is correlated). It measures each star the best way the package "
              "does: a weighted least-squares fit of the raw stamp with its pixel weights on "
              "the simulation's own basis (flux, adaptive centroid and coefficients; 2.8-3 "
              "times less noisy in the first two components than the paper's normalised and "
              "projected stamps, which the paper's schemes get). No scheme given the same "
              "stars can beat it on average: ratios > 1 measure how far a scheme is from "
              "optimal, and an e_rms ratio below 1 beyond its spread would mean the oracle is "
              "not the optimum. The oracle minimises the mean squared error of the "
              "coefficients, not D1 bin by bin, so a D1 ratio below 1 in some bins is no "
              "contradiction. D1 ratio per theta bin is |mean D1| of the scheme over the "
              "oracle's, in parentheses where either mean is within two standard errors of "
              "zero (the ratio is then noise).", ""]
    header = ["scheme", "e_rms / oracle median [16%, 84%]"] + [f"D1 ratio {t:.2g}'" for t in theta]
    rows = []
    for r in table:
        rows.append([r["scheme"], f"{_fmt(r['e_rms_ratio_median'])} [{_fmt(r['e_rms_ratio_p16'])}, "
                     f"{_fmt(r['e_rms_ratio_p84'])}]{underpowered(r['n_simulations'])}"]
                    + [_fmt(v) if ok else f"({_fmt(v)})"
                       for v, ok in zip(r["d1_ratio"], r["d1_significant"])])
    return lines + [_md_table(header, rows), ""]


def _assumption_sections(result, surveys, config):
    lines = []
    sens = multipole_sensitivity(result, config)
    if sens is not None:
        lines += ["### Sensitivity to the upper multipole", "",
                  "Median sigma_sys^2 over simulations when the integral stops at l_max "
                  "(the verdicts above use l_max = 2e4); survey limits: " +
                  ", ".join(f"{r['survey']} {_fmt(r['sigma_sys2'])}" for r in surveys) + ".", ""]
        lines += [_md_table(sens.colnames, [[_cell(r[c]) for c in sens.colnames] for r in sens]),
                  ""]
    rule = d1_rule(result, surveys, config)
    if rule is not None:
        lines += ["### The paper's rule: D1 against the requirement line, theta by theta", "",
                  "A scheme meets a survey when |mean D1| is below the D1 limit of the survey's "
                  "sigma_sys^2 (the dotted lines of fig_cor) in every theta bin.", ""]
        lines += [_md_table(["scheme", "survey", "bins below the line", "meets"],
                            [[r["scheme"], r["survey"], f"{r['bins_below']}/{r['bins']}",
                              "yes" if r["meets"] else "no"] for r in rule]), ""]
    return lines


def _defaults_section(summary, config):
    """``PSFModel()`` with the library's defaults next to the paper's settings."""
    base = summary[np.asarray(summary["config"]).astype(str) == config]
    rows = {str(r["scheme"]): r for r in base}
    if DEFAULT_MODEL not in rows:
        return []
    paper = [s for s in ("kriging", "delaunay", "polynomial") if s in rows]
    lines = ["## The library's defaults against the paper's settings", "",
             f"`{DEFAULT_MODEL}` is `PSFModel()` as a user gets it (its default basis, "
             "outlier rejection and interpolator); the paper's settings are a fixed "
             "reference basis, the IQR cut at 3.5 and each scheme's setting above.", ""]
    cols = [m for m in ("e_rms", "e_rms_ratio", "rho1_mean_abs", "sigma_sys2")
            if f"{m}_median" in base.colnames]
    lines += [_md_table(["scheme", *[f"{m} median" for m in cols]],
                        [[s, *[_fmt(rows[s][f"{m}_median"]) for m in cols]]
                         for s in [DEFAULT_MODEL, *paper]]), ""]
    if paper:
        d, p = rows[DEFAULT_MODEL]["e_rms_median"], rows[paper[0]]["e_rms_median"]
        change = 100 * (d - p) / p
        lines += [f"What changed: the defaults' median e_rms is {_fmt(d)}, "
                  f"{abs(change):.1f}% {'above' if change > 0 else 'below'} the paper's "
                  f"{paper[0]} ({_fmt(p)}).", ""]
    return lines
