"""Per-(configuration, scheme) summaries over simulations and survey verdicts."""

from __future__ import annotations

import re

import numpy as np
from astropy.table import Table

from ...metrics import survey_table
from ..plotting import MissingDataError
from ..plotting._common import _unique_in_order


#: Metrics summarised per (config, scheme), when present in the scores table.
SUMMARY_METRICS = ("e_rms", "e_rms_ratio", "e1_rms", "e2_rms", "coeff_rms", "rho1_mean_abs", "sigma_sys2",
                   "dM22_rel_rms", "dM4_rel_rms", "n_inliers", "fit_seconds")

_PAPER_TRIO = ("polynomial", "delaunay", "kriging")


#: The paper's table 1 (maximum sigma_sys^2 per survey), used when a result has no surveys.
PAPER_SURVEYS = survey_table()


def _fmt(value) -> str:
    value = float(value)
    if not np.isfinite(value):
        return "n/a"
    if value != 0 and (abs(value) < 1e-3 or abs(value) >= 1e4):
        return f"{value:.2e}"
    return f"{value:.4g}"


# ----------------------------------------------------------------------------- summarize


def summarize(scores: Table, metrics=None) -> Table:
    """Median and 16th / 84th percentiles over simulations, per (config, scheme).

    Parameters
    ----------
    scores : astropy.table.Table
        The ``scores`` table of a study result (one row per config, simulation, scheme).
    metrics : sequence of str, optional
        Columns to summarise (default: those of :data:`SUMMARY_METRICS` present).

    Returns
    -------
    summary : astropy.table.Table
        One row per (config, scheme), in order of first appearance, with ``config``,
        ``scheme``, ``n_simulations`` (rows), ``n_failed`` (rows whose ``e_rms`` is not
        finite, e.g. a failed fit) and, per metric, ``<metric>_median``, ``<metric>_p16``,
        ``<metric>_p84`` computed over the finite values (NaN when there are none).

    Examples
    --------
    >>> from astropy.table import Table
    >>> from sklearn_psf.study.report import summarize
    >>> scores = Table({"config": ["default"] * 3, "scheme": ["kriging"] * 3,
    ...                 "simulation": [0, 1, 2], "e_rms": [0.01, 0.03, 0.02]})
    >>> s = summarize(scores)
    >>> float(s["e_rms_median"][0]), int(s["n_simulations"][0])
    (0.02, 3)
    """
    if scores is None:
        raise ValueError("scores is None: pass the scores table of a study result.")
    for name in ("config", "scheme"):
        if name not in scores.colnames:
            raise ValueError(f"scores lacks the column {name!r}; it has {scores.colnames}.")
    if metrics is None:
        metrics = [m for m in SUMMARY_METRICS if m in scores.colnames]
    else:
        metrics = list(metrics)
        missing = [m for m in metrics if m not in scores.colnames]
        if missing:
            raise ValueError(f"scores lacks the metric column(s) {missing}.")
    configs = np.asarray(scores["config"]).astype(str)
    schemes = np.asarray(scores["scheme"]).astype(str)
    rows = []
    for config in _unique_in_order(configs):
        for scheme in _unique_in_order(schemes[configs == config]):
            sel = (configs == config) & (schemes == scheme)
            row = {"config": config, "scheme": scheme, "n_simulations": int(sel.sum())}
            if "e_rms" in scores.colnames:
                row["n_failed"] = int(np.sum(~np.isfinite(np.asarray(scores["e_rms"], float)[sel])))
            for m in metrics:
                values = np.asarray(scores[m], dtype=float)[sel]
                values = values[np.isfinite(values)]
                if values.size:
                    med, p16, p84 = np.median(values), *np.percentile(values, [16, 84])
                else:
                    med = p16 = p84 = np.nan
                row[f"{m}_median"], row[f"{m}_p16"], row[f"{m}_p84"] = med, p16, p84
            rows.append(row)
    if not rows:
        return Table(names=["config", "scheme", "n_simulations"], dtype=[str, str, int])
    return Table(rows=rows, names=list(rows[0]))


def _summary_value(summary, config, scheme, column):
    sel = (np.asarray(summary["config"]).astype(str) == config) & (
        np.asarray(summary["scheme"]).astype(str) == scheme
    )
    if not sel.any() or column not in summary.colnames:
        return None
    value = float(np.asarray(summary[column], float)[sel][0])
    return value if np.isfinite(value) else None


# ----------------------------------------------------------------------------- surveys


def survey_verdicts(scores: Table, surveys: Table | None = None,
                    config: str = "default") -> Table:
    """Which scheme meets which survey's requirement on the PSF systematics.

    A scheme *meets* a survey's requirement when the median over simulations of its implied
    ``sigma_sys2`` is below the survey's maximum ``sigma_sys2`` (Amara & Refregier 2008).

    Parameters
    ----------
    scores : astropy.table.Table
        The ``scores`` table (needs ``sigma_sys2``).
    surveys : astropy.table.Table, optional
        Columns ``survey`` and ``sigma_sys2``. Default: :data:`PAPER_SURVEYS` (the paper's
        table 1: CFHTLS 2e-6, COSMOS 8e-6, Stage IV 1.2e-7).
    config : str
        Configuration whose simulations are used.

    Returns
    -------
    verdicts : astropy.table.Table
        One row per (scheme, survey): ``scheme``, ``survey``, ``sigma_sys2_median``,
        ``sigma_sys2_p84``, ``requirement``, ``meets`` (bool).

    Examples
    --------
    >>> from astropy.table import Table
    >>> from sklearn_psf.study.report import survey_verdicts
    >>> scores = Table({"config": ["default"] * 2, "scheme": ["kriging", "polynomial"],
    ...                 "sigma_sys2": [1e-6, 5e-6]})
    >>> v = survey_verdicts(scores)
    >>> [(str(r["scheme"]), bool(r["meets"])) for r in v if r["survey"] == "CFHTLS"]
    [('kriging', True), ('polynomial', False)]
    """
    if "sigma_sys2" not in scores.colnames:
        raise MissingDataError("scores has no sigma_sys2 column: survey verdicts need it.")
    surveys = PAPER_SURVEYS if surveys is None else surveys
    for name in ("survey", "sigma_sys2"):
        if name not in surveys.colnames:
            raise ValueError(f"surveys lacks the column {name!r}; it has {surveys.colnames}.")
    summary = summarize(scores[np.asarray(scores["config"]).astype(str) == config],
                        metrics=["sigma_sys2"])
    rows = []
    for srow in summary:
        med = float(srow["sigma_sys2_median"])
        for survey in surveys:
            level = float(survey["sigma_sys2"])
            rows.append((str(srow["scheme"]), str(survey["survey"]), med,
                         float(srow["sigma_sys2_p84"]), level, bool(np.isfinite(med) and med < level)))
    names = ["scheme", "survey", "sigma_sys2_median", "sigma_sys2_p84", "requirement", "meets"]
    if not rows:
        return Table(names=names, dtype=[str, str, float, float, float, bool])
    return Table(rows=rows, names=names)


def _survey_key(name):
    return re.sub(r"[^a-z0-9]", "", str(name).lower())


# ----------------------------------------------------------------------------- findings
