"""Figure of the multi-exposure study: sigma_sys^2 against the number of exposures."""

from __future__ import annotations

import numpy as np

from ...metrics import survey_table


def _median_band(scores, scheme, n_stars):
    sel = (np.asarray(scores["scheme"]).astype(str) == scheme) & (
        np.asarray(scores["n_stars"]) == n_stars)
    counts = np.unique(np.asarray(scores["n_exposures"])[sel])
    values = [np.asarray(scores["sigma_sys2"])[sel & (np.asarray(scores["n_exposures"]) == n)]
              for n in counts]
    return counts, np.array([np.percentile(v, q) for v in values for q in (16, 50, 84)]
                            ).reshape(len(counts), 3)


def plot_sigma_sys_vs_exposures(result, ax=None, surveys=None):
    """sigma_sys^2 of the exposure-averaged residual against the number of exposures.

    Median over simulations with the 16-84% band, per scheme and number of stars per
    exposure, log-log, with the survey requirements (:func:`~sklearn_psf.metrics.survey_table`)
    as horizontal lines.

    Parameters
    ----------
    result : ExposureStudyResult
    ax : matplotlib Axes, optional
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

    fig, ax = (plt.subplots(figsize=(8.6, 4.6)) if ax is None else (ax.figure, ax))
    scores = result.scores
    styles = {"per-exposure": ("C0", "o"), "pooled": ("C3", "s")}
    stars = np.unique(np.asarray(scores["n_stars"]))
    for j, scheme in enumerate(dict.fromkeys(np.asarray(scores["scheme"]).astype(str))):
        color, marker = styles.get(scheme, (f"C{j + 4}", "^"))
        for k, m in enumerate(stars):
            counts, band = _median_band(scores, scheme, m)
            if not len(counts):
                continue
            line = ("-", "--", ":", "-.")[k % 4]
            ax.plot(counts, band[:, 1], line, color=color, marker=marker,
                    label=f"{scheme}, {m} stars/exposure")
            ax.fill_between(counts, band[:, 0], band[:, 2], color=color, alpha=0.15)
    table = survey_table() if surveys is None else surveys
    for i, row in enumerate(table):
        ax.axhline(row["sigma_sys2"], color="0.4", ls=("--", ":", "-.")[i % 3], lw=1)
        ax.annotate(f"{row['survey']} {row['sigma_sys2']:.1e}", (1.0, row["sigma_sys2"]),
                    xycoords=("axes fraction", "data"), ha="right", va="bottom", fontsize=8,
                    color="0.3")
    ax.set_xscale("log")
    ax.set_yscale("log")
    counts = np.unique(np.asarray(scores["n_exposures"]))
    ax.set_xlim(counts.min() / 1.15, counts.max() * 2.2)  # room for the survey labels
    ax.set_xticks(counts)
    ax.set_xticklabels([str(int(n)) for n in counts])
    ax.minorticks_off()
    ax.set_xlabel("number of exposures")
    ax.set_ylabel(r"$\sigma^2_{\rm sys}$ of the exposure-averaged residual")
    ax.set_title("PSF systematics against the number of exposures\n"
                 "(median over simulations, 16-84% band)", fontsize=10)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    fig.tight_layout()
    return fig
