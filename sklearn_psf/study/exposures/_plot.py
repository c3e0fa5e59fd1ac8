"""Figure of the multi-exposure study: sigma_sys^2 against the number of exposures."""

from __future__ import annotations

import numpy as np

from ...metrics import survey_table


def _regimes(scores):
    """(variance ratio, dither) -> rows of that regime (one regime, NaN, without the columns)."""
    if "variance_ratio" not in scores.colnames:
        return {(float("nan"), float("nan")): scores}
    out = {}
    for key in dict.fromkeys(zip(np.asarray(scores["variance_ratio"], float),
                                 np.asarray(scores["dither"], float))):
        sel = (np.asarray(scores["variance_ratio"], float) == key[0]) & (
            np.asarray(scores["dither"], float) == key[1])
        out[key] = scores[sel]
    return out


def _median_band(scores, scheme, n_stars):
    sel = (np.asarray(scores["scheme"]).astype(str) == scheme) & (
        np.asarray(scores["n_stars"]) == n_stars)
    counts = np.unique(np.asarray(scores["n_exposures"])[sel])
    values = [np.asarray(scores["sigma_sys2"])[sel & (np.asarray(scores["n_exposures"]) == n)]
              for n in counts]
    return counts, np.array([np.percentile(v, q) for v in values for q in (16, 50, 84)]
                            ).reshape(len(counts), 3)


def plot_sigma_sys_vs_exposures(result, surveys=None):
    """sigma_sys^2 of the exposure-averaged residual against the number of exposures.

    One panel per regime (rows: atmospheric / static variance; columns: dither): median over
    simulations with the 16-84% band, per scheme and number of stars per exposure, log-log,
    with the survey requirements (:func:`~sklearn_psf.metrics.survey_table`) as horizontal
    lines.

    Parameters
    ----------
    result : ExposureStudyResult
    surveys : astropy.table.Table, optional
        Columns ``survey`` and ``sigma_sys2``; default the paper's three surveys.

    Returns
    -------
    fig : matplotlib Figure

    Examples
    --------
    >>> import matplotlib
    >>> matplotlib.use("Agg")
    >>> from astropy.table import Table
    >>> from sklearn_psf.study.exposures import plot_sigma_sys_vs_exposures
    >>> from sklearn_psf.study.exposures import ExposureStudyResult
    >>> scores = Table({"scheme": ["pooled"] * 2, "n_stars": [100, 100],
    ...                 "n_exposures": [1, 10], "sigma_sys2": [5e-6, 3e-7]})
    >>> fig = plot_sigma_sys_vs_exposures(ExposureStudyResult(scores, Table(), None))
    >>> len(fig.axes)
    1
    """
    import matplotlib.pyplot as plt

    regimes = _regimes(result.scores)
    ratios = list(dict.fromkeys(v for v, _ in regimes))
    dithers = list(dict.fromkeys(d for _, d in regimes))
    fig, axes = plt.subplots(len(ratios), len(dithers), squeeze=False, sharex=True, sharey=True,
                             figsize=(max(3.6 * len(dithers), 6.0), 2.6 * len(ratios) + 1.8),
                             layout="constrained")
    table = survey_table() if surveys is None else surveys
    all_scores = result.scores
    styles = {"per-exposure": ("C0", "o"), "pooled": ("C3", "s"), "oracle": ("0.3", "^")}
    schemes = list(dict.fromkeys(np.asarray(all_scores["scheme"]).astype(str)))
    stars = np.unique(np.asarray(all_scores["n_stars"]))
    for (v, d), scores in regimes.items():
        ax = axes[ratios.index(v), dithers.index(d)]
        for j, scheme in enumerate(schemes):
            color, marker = styles.get(scheme, (f"C{j + 4}", "v"))
            for k, m in enumerate(stars):
                counts, band = _median_band(scores, scheme, m)
                if not len(counts):
                    continue
                line = ("-", "--", ":", "-.")[k % 4]
                ax.plot(counts, band[:, 1], line, color=color, marker=marker, ms=4,
                        label=f"{scheme}, {m} stars/exposure")
                ax.fill_between(counts, band[:, 0], band[:, 2], color=color, alpha=0.12)
        for i, row in enumerate(table):
            ax.axhline(row["sigma_sys2"], color="0.5", ls=("--", ":", "-.")[i % 3], lw=0.8,
                       label=f"{row['survey']} requirement {row['sigma_sys2']:.1e}")
        ax.set_xscale("log")
        ax.set_yscale("log")
        if np.isfinite(v):
            ax.set_title(f"atm/static variance {v:g}, dither {d:g} px", fontsize=8)
        ax.tick_params(labelsize=7)
    counts = np.unique(np.asarray(all_scores["n_exposures"]))
    for ax in axes[-1]:
        ax.set_xticks(counts)
        ax.set_xticklabels([str(int(n)) for n in counts])
        ax.minorticks_off()
        ax.set_xlabel("number of exposures N", fontsize=8)
    for ax in axes[:, 0]:
        ax.set_ylabel(r"$\sigma^2_{\rm sys}$ (exposure-averaged)", fontsize=8)
    handles, labels = axes[0, 0].get_legend_handles_labels()
    # below the panels, inside the figure: no label runs off its right edge
    fig.legend(handles, labels, fontsize=7, loc="outside lower center", ncols=2,
               frameon=False)
    fig.suptitle("PSF systematics against the number of exposures\n(median over "
                 "simulations, 16-84% band)", fontsize=9)
    return fig
