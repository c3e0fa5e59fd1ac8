"""Residuals against local and global stellar density."""

from __future__ import annotations

import re

import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from ._common import (
    _as_list,
    _check_schemes,
    _mask,
    MissingDataError,
    _new_figure,
    _quantity_label,
    _require_columns,
    residual_component,
    scheme_color,
    _unique_in_order,
)


def _global_density_values(galaxies, scores, configs, densities):
    present = _unique_in_order(galaxies["config"])
    if configs is None:
        configs = [c for c in present if c.startswith("n_stars=")]
    values = {}
    for c in configs:
        if densities is not None and c in densities:
            values[c] = float(densities[c])
        elif scores is not None and "n_stars" in scores.colnames and \
                np.any(_mask(scores, config=c)):
            values[c] = float(np.median(np.asarray(scores["n_stars"])[_mask(scores, config=c)]))
        else:
            match = re.fullmatch(r"n_stars=(\d+)", c)
            if match:
                values[c] = float(match.group(1))
    return {c: v for c, v in values.items() if c in present}


def density_groups(galaxies, schemes, by: str = "local", component: str = "e1",
                   config: str = "default", bins=None, scores=None, configs=None,
                   densities=None):
    """Residuals grouped by local or global stellar density (data of fig_densell*).

    Parameters
    ----------
    galaxies : astropy.table.Table
        The ``galaxies`` table of a study result.
    schemes : sequence of str
        Schemes to group.
    by : {"local", "global"}
        ``"local"``: bins of the ``local_density`` column (stars within 1 arcmin of the
        galaxy-PSF) over all simulations of ``config``. ``"global"``: one group per
        configuration, at its number of stars in the image.
    component : str
        ``"e1"``, ``"e2"`` or ``"coeffK"``.
    config : str
        Configuration for ``by="local"``.
    bins : int or array-like, optional
        ``by="local"`` only: bin edges, or a number of quantile bins. Default: one group per
        value when the densities are integers with at most 10 distinct values, else 6
        quantile bins.
    scores : astropy.table.Table, optional
        ``by="global"``: the ``n_stars`` of each configuration is read from it.
    configs : sequence of str, optional
        ``by="global"``: configurations to use (default: the ``"n_stars=N"`` ones).
    densities : dict, optional
        ``by="global"``: explicit configuration -> number of stars.

    Returns
    -------
    x : ndarray of shape (n_groups,)
        Density of each group: mean local density of its members, or stars in the image.
    labels : list of str
        Tick label of each group.
    residuals : dict
        scheme -> list of ``n_groups`` residual arrays (possibly empty).

    Examples
    --------
    >>> from sklearn_psf.study.report import synthetic_study_result
    >>> from sklearn_psf.study.plotting import density_groups
    >>> result = synthetic_study_result(n_simulations=2)
    >>> x, labels, res = density_groups(result.galaxies, ["kriging"], by="global",
    ...                                 scores=result.scores)
    >>> x.tolist()
    [250.0, 1000.0, 4000.0]
    """
    schemes = _check_schemes(schemes)
    if by not in ("local", "global"):
        raise ValueError(f"by must be 'local' or 'global', got {by!r}.")
    _require_columns(galaxies, ["config", "scheme"], "galaxies")
    residuals = {s: [] for s in schemes}
    if by == "global":
        values = _global_density_values(galaxies, scores, configs, densities)
        if len(set(values.values())) < 2:
            raise MissingDataError(
                "global density needs at least two configurations with different numbers of "
                "stars (e.g. 'n_stars=250', 'n_stars=1000'); found "
                f"{sorted(values) or 'none'}."
            )
        ordered = sorted(values, key=lambda c: values[c])
        for c in ordered:
            for s in schemes:
                rows = galaxies[_mask(galaxies, config=c, scheme=s)]
                residuals[s].append(residual_component(rows, component)[2])
        x = np.array([values[c] for c in ordered])
        return x, [f"{v:g}" for v in x], residuals

    if "local_density" not in galaxies.colnames:
        raise MissingDataError("the galaxies table has no local_density column.")
    sel = _mask(galaxies, config=config) & np.isin(np.asarray(galaxies["scheme"]), schemes)
    density_all = np.asarray(galaxies["local_density"], float)[sel]
    density_all = density_all[np.isfinite(density_all)]
    if density_all.size == 0:
        raise MissingDataError(f"no finite local_density for config {config!r}.")
    distinct = np.unique(density_all)
    if bins is None and np.all(distinct == np.round(distinct)) and len(distinct) <= 10:
        edges = None
    else:
        if bins is None or np.isscalar(bins):
            nb = 6 if bins is None else int(bins)
            edges = np.unique(np.quantile(density_all, np.linspace(0, 1, nb + 1)))
            if len(edges) < 2:
                edges = np.array([distinct[0] - 0.5, distinct[0] + 0.5])
        else:
            edges = np.asarray(bins, float)
    n_groups = len(distinct) if edges is None else len(edges) - 1
    sums, counts = np.zeros(n_groups), np.zeros(n_groups)
    for s in schemes:
        rows = galaxies[_mask(galaxies, config=config, scheme=s)]
        d = np.asarray(rows["local_density"], float)
        res = residual_component(rows, component)[2]
        if edges is None:
            idx = np.searchsorted(distinct, d)
            idx[~np.isin(d, distinct)] = -1
        else:
            idx = np.searchsorted(edges, d, side="right") - 1
            idx[d == edges[-1]] = n_groups - 1  # last bin closed on the right
            idx[(idx < 0) | (idx >= n_groups) | ~np.isfinite(d)] = -1
        for g in range(n_groups):
            member = idx == g
            residuals[s].append(res[member])
            sums[g] += d[member].sum()
            counts[g] += member.sum()
    if edges is None:
        x, labels = distinct.astype(float), [f"{v:g}" for v in distinct]
    else:
        centres = 0.5 * (edges[1:] + edges[:-1])
        x = np.divide(sums, counts, out=centres.copy(), where=counts > 0)
        labels = [f"{lo:g}-{hi:g}" for lo, hi in zip(edges[:-1], edges[1:])]
    return x, labels, residuals


def _density_xlabel(by, area=None):
    if by == "local":
        return "local stellar density [stars within 1 arcmin]"
    if area:
        return r"global stellar density [stars arcmin$^{-2}$]"
    return "global stellar density [stars in the image]"


def _per_area(labels, area):
    """Global-density group labels (numbers of stars) as densities per arcmin^2."""
    if not area:
        return labels
    return [f"{float(v) / area:.2g}" if re.fullmatch(r"[0-9.eE+]+", v) else v for v in labels]


def plot_density_boxplots(galaxies, schemes, by: str = "local", component="e1",
                          config: str = "default", bins=None, scores=None, configs=None,
                          densities=None, whis=(5.0, 95.0), area=None) -> Figure:
    """Box plots of residuals vs local or global stellar density (fig_densell, fig_densellglob).

    For each density group, one box per scheme (offset for visibility, scheme colours): the
    central line is the median, the box spans the central quartiles, the whiskers reach the
    5% and 95% points (``whis``) and the outer points are drawn individually, as in the paper.

    Parameters
    ----------
    galaxies : astropy.table.Table
        The ``galaxies`` table of a study result.
    schemes : sequence of str
        Schemes to compare.
    by : {"local", "global"}
        See :func:`density_groups`.
    component : str or sequence of str
        Residual component(s), one panel each (``"e1"``, ``"e2"``, ``"coeffK"``).
    config, bins, scores, configs, densities
        See :func:`density_groups`.
    whis : (float, float)
        Whisker percentiles.
    area : float, optional
        Area of the image in arcmin^2: global densities are then labelled in stars per
        arcmin^2 instead of numbers of stars.

    Returns
    -------
    fig : matplotlib.figure.Figure

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.study.report import synthetic_study_result
    >>> from sklearn_psf.study.plotting import plot_density_boxplots
    >>> result = synthetic_study_result(n_simulations=2)
    >>> fig = plot_density_boxplots(result.galaxies, ["polynomial", "kriging"], by="local")
    >>> fig.axes[0].get_xlabel()
    'local stellar density [stars within 1 arcmin]'
    """
    schemes = _check_schemes(schemes)
    components = _as_list(component)
    fig, axes = _new_figure(len(components), 1, panel=(7.0, 3.4))
    width = 0.8 / len(schemes)
    for ci, comp in enumerate(components):
        ax = axes[ci, 0]
        x, labels, residuals = density_groups(galaxies, schemes, by, comp, config, bins,
                                              scores, configs, densities)
        for si, scheme in enumerate(schemes):
            color = scheme_color(scheme)
            groups = [g for g, r in enumerate(residuals[scheme]) if r.size]
            if not groups:
                continue
            positions = np.array(groups, float) + (si - (len(schemes) - 1) / 2) * width
            bp = ax.boxplot([residuals[scheme][g] for g in groups], positions=positions,
                            widths=0.85 * width, whis=whis, showfliers=True, manage_ticks=False,
                            patch_artist=True,
                            boxprops={"facecolor": "none", "edgecolor": color},
                            medianprops={"color": color, "lw": 1.5},
                            whiskerprops={"color": color}, capprops={"color": color},
                            flierprops={"marker": ".", "markersize": 2, "markeredgecolor": color,
                                        "alpha": 0.5})
            for g, median in zip(groups, bp["medians"]):
                median.set_gid(f"median:{scheme}:{g}")
        ax.axhline(0, color="0.7", lw=0.5, zorder=0)
        ax.set_xticks(np.arange(len(labels)), _per_area(labels, area if by == "global" else None))
        ax.set_xlim(-0.6, len(labels) - 0.4)
        ax.set_xlabel(_density_xlabel(by, area if by == "global" else None))
        ax.set_ylabel(f"residual {_quantity_label(comp)}")
        ax.legend(handles=[Line2D([], [], color=scheme_color(s), label=s) for s in schemes],
                  fontsize=7, ncols=min(len(schemes), 4))
    where = config if by == "local" else "configurations by number of stars"
    fig.suptitle(f"Residuals vs {by} stellar density ({where}; whiskers {whis[0]:g}-"
                 f"{whis[1]:g}%)")
    return fig


def plot_density_stats(galaxies, schemes, by: str = "local", component="e1",
                       config: str = "default", bins=None, scores=None, configs=None,
                       densities=None) -> Figure:
    """Median and rms of the residuals vs stellar density (fig_densellvar).

    Parameters
    ----------
    galaxies : astropy.table.Table
        The ``galaxies`` table of a study result.
    schemes : sequence of str
        Schemes to compare (scheme colours).
    by : {"local", "global"}
        See :func:`density_groups`.
    component : str or sequence of str
        One row of two panels (median, rms) per component.
    config, bins, scores, configs, densities
        See :func:`density_groups`.

    Returns
    -------
    fig : matplotlib.figure.Figure
        Lines have gids ``"median:<scheme>:<component>"`` and ``"rms:<scheme>:<component>"``;
        x is the mean density of each group.

    Examples
    --------
    >>> from sklearn_psf.study.report import synthetic_study_result
    >>> from sklearn_psf.study.plotting import plot_density_stats
    >>> result = synthetic_study_result(n_simulations=2)
    >>> fig = plot_density_stats(result.galaxies, ["polynomial", "kriging"])
    >>> [ax.get_title() for ax in fig.axes]
    ['median of residual $e_1$', 'rms of residual $e_1$']
    """
    schemes = _check_schemes(schemes)
    components = _as_list(component)
    fig, axes = _new_figure(len(components), 2, panel=(3.8, 3.0), sharex=True)
    for ci, comp in enumerate(components):
        x, _, residuals = density_groups(galaxies, schemes, by, comp, config, bins, scores,
                                         configs, densities)
        for scheme in schemes:
            groups = residuals[scheme]
            median = np.array([np.median(r) if r.size else np.nan for r in groups])
            rms = np.array([np.sqrt(np.mean(r * r)) if r.size else np.nan for r in groups])
            for ax, values, stat in ((axes[ci, 0], median, "median"), (axes[ci, 1], rms, "rms")):
                ax.plot(x, values, marker="o", ms=4, color=scheme_color(scheme), label=scheme,
                        gid=f"{stat}:{scheme}:{comp}")
        axes[ci, 0].axhline(0, color="0.7", lw=0.5, zorder=0)
        for ax, stat in ((axes[ci, 0], "median"), (axes[ci, 1], "rms")):
            ax.set_title(f"{stat} of residual {_quantity_label(comp)}", fontsize=10)
            ax.set_ylabel(f"{stat} of residual {_quantity_label(comp)}", fontsize=8)
            ax.set_xlabel(_density_xlabel(by), fontsize=8)
        if by == "global":
            for ax in axes[ci]:
                ax.set_xscale("log")
        axes[ci, 1].set_ylim(bottom=0)
    axes[0, 0].legend(fontsize=7)
    return fig


# ----------------------------------------------------------------------------- outliers
