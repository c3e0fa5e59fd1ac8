"""The outlier study: scores with planted outliers, with and without the IQR cut."""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Patch

from ._common import (
    METRIC_LABELS,
    _as_list,
    MissingDataError,
    _new_figure,
    _require_columns,
    scheme_color,
    _unique_in_order,
)


def plot_outlier_study(scores, schemes=None, metrics=("e_rms", "rho1_mean_abs"),
                       configs=None) -> Figure:
    """Residuals with planted outlying stars, with and without the IQR cut (the paper's
    section 5.4).

    One panel per metric; for each scheme, one bar per configuration (median over simulations,
    error bar: 16-84% range). Local schemes (Delaunay, Kriging) are hurt most by outliers when
    the cut is off.

    Parameters
    ----------
    scores : astropy.table.Table
        The ``scores`` table of a study.
    schemes : list of str, optional
        Schemes to show (default: every scheme of the outlier configurations).
    metrics : sequence of str
        Columns of ``scores`` to plot, lower is better.
    configs : list of str, optional
        Configurations to compare (default: those whose label starts with ``outliers=``, and
        ``default`` when present, as the reference without outliers).

    Returns
    -------
    matplotlib.figure.Figure

    Examples
    --------
    >>> from astropy.table import Table
    >>> from sklearn_psf.study.plotting import plot_outlier_study
    >>> scores = Table({"config": ["outliers=0.02,iqr=on", "outliers=0.02,iqr=off"] * 2,
    ...                 "scheme": ["kriging"] * 2 + ["polynomial"] * 2,
    ...                 "e_rms": [0.010, 0.035, 0.016, 0.018]})
    >>> fig = plot_outlier_study(scores, metrics=("e_rms",))
    >>> len(fig.axes[0].patches)
    4
    """
    _require_columns(scores, ["config", "scheme", *metrics], "the outlier study")
    labels = np.asarray(scores["config"]).astype(str)
    if configs is None:
        configs = [c for c in _unique_in_order(labels) if c.startswith("outliers=")]
        if "default" in labels:
            configs = ["default", *configs]
    if not any(c.startswith("outliers=") for c in configs):
        raise MissingDataError("no outlier configuration ('outliers=...') in the scores.")
    names = np.asarray(scores["scheme"]).astype(str)
    in_study = np.isin(labels, [c for c in configs if c.startswith("outliers=")])
    schemes = _unique_in_order(names[in_study]) if schemes is None else _as_list(schemes)
    fig, axes = _new_figure(1, len(metrics), panel=(1.2 + 0.9 * len(schemes), 3.2))
    width = 0.8 / len(configs)
    hatches = ["", "//", "..", "xx", "\\\\"]
    for ax, metric in zip(axes[0], metrics):
        values = np.asarray(scores[metric], dtype=float)
        for j, config in enumerate(configs):
            for i, scheme in enumerate(schemes):
                v = values[(labels == config) & (names == scheme) & np.isfinite(values)]
                if v.size == 0:
                    continue
                lo, med, hi = np.percentile(v, [16, 50, 84])
                ax.bar(i + (j - (len(configs) - 1) / 2) * width, med, width,
                       yerr=[[med - lo], [hi - med]], color=scheme_color(scheme),
                       edgecolor="0.6", hatch=hatches[j % len(hatches)])
        ax.set_xticks(range(len(schemes)), schemes, rotation=30, ha="right")
        ax.set_ylim(bottom=0)  # bars start at zero: a linear axis
        ax.set_ylabel(f"{METRIC_LABELS.get(metric, metric)}\n(median over simulations)")
    handles = [Patch(facecolor="white", edgecolor="0.3", hatch=hatches[j % len(hatches)],
                     label=config) for j, config in enumerate(configs)]
    fig.legend(handles=handles, fontsize="small", loc="outside lower center", ncols=len(configs))
    fig.suptitle("Outlying stars: residuals with and without the IQR cut")
    return fig
