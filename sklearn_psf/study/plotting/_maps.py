"""Maps of one simulation (whiskers, components) and residual pairs of schemes."""

from __future__ import annotations

import itertools

import numpy as np
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from ._common import (
    _as_list,
    _check_schemes,
    _edges,
    _grid_spacing,
    _lattice,
    _map_rows,
    _mask,
    MissingDataError,
    _new_figure,
    _quantity_label,
    _require_columns,
    residual_component,
    scheme_color,
)


def _sticks(e1, e2):
    """Whisker components: length |e| at the position angle atan2(e2, e1) / 2."""
    modulus = np.hypot(e1, e2)
    angle = 0.5 * np.arctan2(e2, e1)
    return modulus * np.cos(angle), modulus * np.sin(angle)


def plot_ellipticity_maps(galaxies, schemes, config: str = "default", simulation=None,
                          amplify: float = 3.0, layout: str = "grid",
                          reference: float | None = None) -> Figure:
    """Whisker maps of the PSF ellipticity: input, model and amplified residual (fig_ell).

    Each galaxy-PSF is drawn as a headless stick of length ``|e|`` at the position angle
    ``atan2(e2, e1) / 2`` (``quiver`` with ``pivot="middle"``). Columns: input (truth), model,
    residual ``e_model - e_true`` multiplied by ``amplify``; one row per scheme. All panels use
    the same stick scale, so lengths can be compared across panels (residuals after
    amplification).

    Parameters
    ----------
    galaxies : astropy.table.Table
        The ``galaxies`` table of a study result.
    schemes : sequence of str
        Schemes, one row each.
    config : str
        Configuration label.
    simulation : int, optional
        Simulation to map (default: the first one).
    amplify : float
        Factor applied to the residual sticks (3 in the paper).
    layout : {"grid", "random"}
        Which galaxy-PSFs to draw.
    reference : float, optional
        Ellipticity drawn as about 0.8 grid step (default: the 95th percentile of the input
        ``|e|``); shown in the quiver key.

    Returns
    -------
    fig : matplotlib.figure.Figure
        ``len(schemes)`` x 3 panels.

    Examples
    --------
    >>> from sklearn_psf.study.report import synthetic_study_result
    >>> from sklearn_psf.study.plotting import plot_ellipticity_maps
    >>> result = synthetic_study_result(n_simulations=1)
    >>> fig = plot_ellipticity_maps(result.galaxies, ["polynomial", "kriging"])
    >>> len(fig.axes)
    6
    """
    schemes = _check_schemes(schemes)
    if not amplify > 0:
        raise ValueError(f"amplify must be positive, got {amplify}.")
    rows_by_scheme, simulation = _map_rows(galaxies, schemes, config, simulation, layout)
    first = rows_by_scheme[schemes[0]]
    x0, y0 = np.asarray(first["x"], float), np.asarray(first["y"], float)
    spacing = _grid_spacing(x0, y0)
    if reference is None:
        modulus = np.hypot(np.asarray(first["e1_true"], float), np.asarray(first["e2_true"], float))
        reference = float(np.percentile(modulus, 95)) if np.any(modulus > 0) else 0.05
        reference = reference if reference > 0 else 0.05
    scale = reference / (0.8 * spacing)  # ellipticity units per pixel of stick length

    fig, axes = _new_figure(len(schemes), 3, panel=(3.6, 2.9), sharex=True, sharey=True)
    for i, scheme in enumerate(schemes):
        rows = rows_by_scheme[scheme]
        x, y = np.asarray(rows["x"], float), np.asarray(rows["y"], float)
        e1t, e1m, e1r = residual_component(rows, "e1")
        e2t, e2m, e2r = residual_component(rows, "e2")
        panels = [
            ("input", _sticks(e1t, e2t), "black"),
            (f"model: {scheme}", _sticks(e1m, e2m), scheme_color(scheme)),
            (f"residual x{amplify:g}: {scheme}", _sticks(amplify * e1r, amplify * e2r),
             scheme_color(scheme)),
        ]
        for j, (title, (u, v), color) in enumerate(panels):
            ax = axes[i, j]
            q = ax.quiver(x, y, u, v, color=color, pivot="middle", headwidth=0, headlength=0,
                          headaxislength=0, angles="xy", scale_units="xy", scale=scale,
                          width=0.004)
            q.set_gid(f"{scheme}:{['input', 'model', 'residual'][j]}")
            ax.set_title(title, fontsize=9, loc="left")
            ax.set_xlim(x0.min() - spacing / 2, x0.max() + spacing / 2)
            ax.set_ylim(y0.min() - spacing / 2, y0.max() + spacing / 2)
            ax.set_aspect("equal")
            if i == len(schemes) - 1:
                ax.set_xlabel("x [pixel]")
            if j == 0:
                ax.set_ylabel("y [pixel]")
            if i == 0:
                ref = reference / amplify if j == 2 else reference
                ax.quiverkey(q, 0.92, 1.05, reference, f"|e| = {ref:.2g}", labelpos="W",
                             fontproperties={"size": 7})
    fig.suptitle(f"PSF ellipticity, {config}, simulation {simulation} ({layout} galaxy-PSFs)")
    return fig


# ----------------------------------------------------------------------------- fig_ell1comp


def _draw_map(ax, x, y, values, norm, cmap):
    lattice = _lattice(x, y)
    if lattice is not None:
        ux, uy, ix, iy = lattice
        grid = np.full((len(uy), len(ux)), np.nan)
        grid[iy, ix] = values
        return ax.pcolormesh(_edges(ux), _edges(uy), np.ma.masked_invalid(grid), norm=norm,
                             cmap=cmap, shading="flat")
    return ax.scatter(x, y, c=values, norm=norm, cmap=cmap, s=8, marker="s", linewidths=0)


def plot_component_maps(galaxies, schemes, quantity="e1", config: str = "default",
                        simulation=None, layout: str = "grid", limits=None,
                        residual_limit: float | None = None, cmap: str = "viridis",
                        residual_cmap: str = "RdBu_r", percentile: float = 99.0) -> Figure:
    """Colour maps of input, model and residual of e1, e2 or a PCA coefficient (fig_ell1comp,
    fig_coeff0).

    Parameters
    ----------
    galaxies : astropy.table.Table
        The ``galaxies`` table of a study result.
    schemes : sequence of str
        Schemes, one row each (per quantity).
    quantity : str or sequence of str
        ``"e1"``, ``"e2"``, ``"coeff0"`` .. ``"coeff3"``; a sequence stacks one block of rows
        per quantity (the paper's e1 above e2).
    config : str
        Configuration label.
    simulation : int, optional
        Simulation to map (default: the first one).
    layout : {"grid", "random"}
        Grid galaxy-PSFs are drawn as cells (``pcolormesh``), others as coloured squares.
    limits : (float, float), optional
        Colour range of input and model (default: the ``100 - percentile`` and
        ``percentile`` percentiles of the input), shared by all schemes.
    residual_limit : float, optional
        The residual colour range is ``[-residual_limit, residual_limit]`` (default: the
        ``percentile`` percentile of ``|residual|`` over all schemes): symmetric, and for a
        useful model narrower than the input range, as in the paper.
    cmap, residual_cmap : str
        Colour maps of input/model and of the residual (diverging).
    percentile : float
        Percentile used for the default colour ranges.

    Returns
    -------
    fig : matplotlib.figure.Figure
        ``len(quantity) * len(schemes)`` x 3 panels, plus colour bars.

    Examples
    --------
    >>> from sklearn_psf.study.report import synthetic_study_result
    >>> from sklearn_psf.study.plotting import plot_component_maps
    >>> result = synthetic_study_result(n_simulations=1)
    >>> fig = plot_component_maps(result.galaxies, ["kriging"], quantity="coeff0")
    >>> sum(ax.get_label() != "<colorbar>" for ax in fig.axes)
    3
    """
    schemes = _check_schemes(schemes)
    quantities = _as_list(quantity)
    rows_by_scheme, simulation = _map_rows(galaxies, schemes, config, simulation, layout)
    nrows = len(quantities) * len(schemes)
    fig, axes = _new_figure(nrows, 3, panel=(3.4, 2.6), sharex=True, sharey=True)
    for qi, q in enumerate(quantities):
        data = {s: residual_component(rows_by_scheme[s], q) for s in schemes}
        true0 = data[schemes[0]][0]
        if limits is None:
            lo, hi = np.percentile(true0, [100 - percentile, percentile])
            if hi <= lo:
                lo, hi = lo - 1e-3, hi + 1e-3
        else:
            lo, hi = map(float, limits)
        if residual_limit is None:
            all_res = np.abs(np.concatenate([data[s][2] for s in schemes]))
            rlim = float(np.percentile(all_res, percentile))
            rlim = rlim if rlim > 0 else 1e-6
        else:
            rlim = float(residual_limit)
        norm, rnorm = Normalize(lo, hi), Normalize(-rlim, rlim)
        block_axes, res_axes, mappable, rmappable = [], [], None, None
        for si, scheme in enumerate(schemes):
            i = qi * len(schemes) + si
            rows = rows_by_scheme[scheme]
            x, y = np.asarray(rows["x"], float), np.asarray(rows["y"], float)
            true, model, resid = data[scheme]
            for j, (values, title) in enumerate(
                [(true, "input"), (model, f"model: {scheme}"), (resid, f"residual: {scheme}")]
            ):
                ax = axes[i, j]
                if j < 2:
                    mappable = _draw_map(ax, x, y, values, norm, cmap)
                    block_axes.append(ax)
                else:
                    rmappable = _draw_map(ax, x, y, values, rnorm, residual_cmap)
                    res_axes.append(ax)
                ax.set_gid(f"{q}:{scheme}:{['input', 'model', 'residual'][j]}")
                ax.set_title(f"{_quantity_label(q)} {title}", fontsize=9)
                ax.set_aspect("equal")
                if i == nrows - 1:
                    ax.set_xlabel("x [pixel]")
                if j == 0:
                    ax.set_ylabel("y [pixel]")
        fig.colorbar(mappable, ax=block_axes, label=f"{_quantity_label(q)}", shrink=0.8,
                     extend="both")
        fig.colorbar(rmappable, ax=res_axes, label=f"residual {_quantity_label(q)}",
                     shrink=0.8, extend="both")
    fig.suptitle(f"Input, model and residual, {config}, simulation {simulation} "
                 f"({layout} galaxy-PSFs)")
    return fig


# ----------------------------------------------------------------------------- fig_ecomp


def _matched_residuals(galaxies, scheme_a, scheme_b, quantity, config):
    """Residuals of two schemes at the same galaxy-PSFs (matched on simulation, layout, x, y)."""
    keys, res = [], []
    for scheme in (scheme_a, scheme_b):
        rows = galaxies[_mask(galaxies, config=config, scheme=scheme)]
        if len(rows) == 0:
            raise MissingDataError(f"no galaxy-PSFs for scheme {scheme!r} in config {config!r}.")
        key = np.rec.fromarrays(
            [np.asarray(rows["simulation"]), np.asarray(rows["layout"]).astype(str),
             np.asarray(rows["x"], float), np.asarray(rows["y"], float)],
            names="simulation,layout,x,y",
        )
        keys.append(np.asarray(key))
        res.append(residual_component(rows, quantity)[2])
    _, ia, ib = np.intersect1d(keys[0], keys[1], return_indices=True)
    if len(ia) < 2:
        raise MissingDataError(
            f"schemes {scheme_a!r} and {scheme_b!r} share fewer than 2 galaxy-PSFs in config "
            f"{config!r}: residual pairs need the same positions."
        )
    return res[0][ia], res[1][ib]


def _pearson(a, b):
    da, db = a - a.mean(), b - b.mean()
    denom = np.sqrt(np.sum(da * da) * np.sum(db * db))
    return float(np.sum(da * db) / denom) if denom > 0 else float("nan")


def plot_residual_pairs(galaxies, schemes, quantity="e1", config: str = "default",
                        bins: int = 40, levels=None, percentile: float = 99.5) -> Figure:
    """2-D distributions of the residuals of each pair of schemes (fig_ecomp, fig_coeffscomp).

    For each pair, the residuals (model minus truth) at the same galaxy-PSFs of all simulations
    of ``config`` are histogrammed in 2-D, the histogram is normalised to a maximum of 1 and
    contoured at ``levels`` (0.1, 0.2, ..., 0.9 as in the paper). Pearson's correlation
    coefficient of the two residuals is written in each panel.

    Parameters
    ----------
    galaxies : astropy.table.Table
        The ``galaxies`` table of a study result.
    schemes : sequence of str
        At least two schemes; one panel per pair.
    quantity : str or sequence of str
        One row of panels per quantity (``"e1"``, ``"e2"``, ``"coeffK"``).
    config : str
        Configuration label.
    bins : int
        Histogram bins per axis.
    levels : sequence of float, optional
        Contour levels of the normalised histogram (default 0.1 .. 0.9 by 0.1).
    percentile : float
        The axes span +-(this percentile of the absolute residuals of both schemes).

    Returns
    -------
    fig : matplotlib.figure.Figure
        ``len(quantity)`` rows x ``n_pairs`` columns.

    Examples
    --------
    >>> from sklearn_psf.study.report import synthetic_study_result
    >>> from sklearn_psf.study.plotting import plot_residual_pairs
    >>> result = synthetic_study_result(n_simulations=2)
    >>> fig = plot_residual_pairs(result.galaxies, ["polynomial", "delaunay", "kriging"])
    >>> len(fig.axes)
    3
    """
    schemes = _check_schemes(schemes)
    if len(schemes) < 2:
        raise MissingDataError("residual pairs need at least two schemes.")
    _require_columns(galaxies, ["config", "simulation", "scheme", "layout", "x", "y"], "galaxies")
    levels = np.arange(1, 10) / 10.0 if levels is None else np.asarray(levels, float)
    quantities = _as_list(quantity)
    pairs = list(itertools.combinations(schemes, 2))
    fig, axes = _new_figure(len(quantities), len(pairs), panel=(3.0, 3.0))
    for qi, q in enumerate(quantities):
        for pi, (a, b) in enumerate(pairs):
            ax = axes[qi, pi]
            ra, rb = _matched_residuals(galaxies, a, b, q, config)
            lim = float(np.percentile(np.abs(np.concatenate([ra, rb])), percentile))
            lim = lim if lim > 0 else 1e-6
            edges = np.linspace(-lim, lim, bins + 1)
            hist, _, _ = np.histogram2d(ra, rb, bins=[edges, edges])
            centres = 0.5 * (edges[1:] + edges[:-1])
            if hist.max() > 0:
                cs = ax.contour(centres, centres, (hist / hist.max()).T, levels=levels,
                                cmap="viridis", linewidths=0.8)
                cs.set_gid(f"{q}:{a}:{b}")
            ax.axhline(0, color="0.7", lw=0.5)
            ax.axvline(0, color="0.7", lw=0.5)
            ax.set_xlim(-lim, lim)
            ax.set_ylim(-lim, lim)
            ax.set_aspect("equal")
            r = _pearson(ra, rb)
            ax.text(0.04, 0.95, f"r = {r:.2f}" if np.isfinite(r) else "r = n/a",
                    transform=ax.transAxes, va="top", fontsize=9, gid=f"r:{q}:{a}:{b}")
            ax.set_xlabel(f"residual {_quantity_label(q)}: {a}", fontsize=8)
            ax.set_ylabel(f"residual {_quantity_label(q)}: {b}", fontsize=8)
            ax.tick_params(labelsize=7)
            ax.xaxis.set_major_locator(MaxNLocator(3))  # few ticks: no overlapping labels
            ax.yaxis.set_major_locator(MaxNLocator(3))
    fig.suptitle(f"Residual pairs, {config} (contours 0.1..0.9 of the maximum)")
    return fig


# ----------------------------------------------------------------------------- fig_cor
