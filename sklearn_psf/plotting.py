"""Figures of the PSF interpolation study (Bergé et al. 2012, figures 1 to 11).

Every function builds a :class:`matplotlib.figure.Figure` with the object-oriented API (no
``pyplot`` state is created or changed), returns it and never shows it: save it with
``fig.savefig(path)``. The functions read the tables of
:class:`sklearn_psf.compare.StudyResult` (``scores``, ``correlations``, ``galaxies``) or any
object with the same attributes, so they also work on tables read back from disk.

Conventions shared by all figures

- A scheme has the same colour in every figure: :data:`SCHEME_COLORS` (the paper's black /
  red / green for polynomial / Delaunay / Kriging), other names get a stable colour from
  :func:`scheme_color`.
- Residuals are *model minus truth*.
- Quantities are named ``"e1"``, ``"e2"`` (ellipticity components) or ``"coeff0"`` ..
  ``"coeff3"`` (PCA coefficients, columns ``coeffs_true`` / ``coeffs_model``).
- When the data a figure needs are absent (no grid galaxy-PSFs, no S/N configurations, ...)
  the function raises :class:`MissingDataError`, a ``ValueError`` saying what is missing;
  :func:`sklearn_psf.report.write_report` catches it and notes the skipped figure.
- Correlation functions are drawn as ``|xi|`` on log-log axes; where the value (the mean over
  simulations) is negative the point is marked with an open circle, so that a sign change is
  never hidden by the absolute value.
"""

from __future__ import annotations

import itertools
import re
import zlib
from collections.abc import Sequence

import numpy as np
from matplotlib.colors import LogNorm, Normalize
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

__all__ = [
    "SCHEME_COLORS",
    "KIND_COLORS",
    "MissingDataError",
    "scheme_color",
    "residual_component",
    "plot_psf_examples",
    "plot_ellipticity_maps",
    "plot_component_maps",
    "plot_residual_pairs",
    "plot_correlation_functions",
    "plot_snr_study",
    "density_groups",
    "plot_density_boxplots",
    "plot_density_stats",
    "plot_outlier_study",
]

#: Colour of each interpolation scheme, the same in every figure (paper: polynomial black,
#: Delaunay red, Kriging green).
SCHEME_COLORS = {
    "polynomial": "black",
    "delaunay": "tab:red",
    "kriging": "tab:green",
    "kriging-spherical": "tab:olive",
    "shepard": "tab:purple",
    "rbf": "tab:orange",
    "chebyshev": "tab:brown",
    "polynomial-auto": "tab:gray",
}

#: Colour of each kind of correlation function (paper's fig_cor): input, model, residual.
KIND_COLORS = {"input": "black", "model": "tab:red", "residual": "tab:green"}

_FALLBACK_COLORS = ["tab:blue", "tab:pink", "tab:cyan", "darkgoldenrod", "navy", "teal"]
_RESIDUAL_SERIES_COLORS = ["tab:green", "tab:blue", "tab:purple", "tab:orange", "tab:cyan"]
_PAPER_SCHEMES = ("polynomial", "delaunay", "kriging")


class MissingDataError(ValueError):
    """The data a figure needs are not in the result (the figure cannot be drawn)."""


def scheme_color(scheme: str) -> str:
    """Colour of an interpolation scheme, stable across figures and sessions.

    Parameters
    ----------
    scheme : str
        Scheme name, e.g. ``"kriging"``.

    Returns
    -------
    color : str
        A matplotlib colour: :data:`SCHEME_COLORS` for known names, otherwise a colour chosen
        from a fixed palette by a checksum of the name.

    Examples
    --------
    >>> from sklearn_psf.plotting import scheme_color
    >>> scheme_color("kriging")
    'tab:green'
    >>> scheme_color("my-scheme") == scheme_color("my-scheme")
    True
    """
    if scheme in SCHEME_COLORS:
        return SCHEME_COLORS[scheme]
    return _FALLBACK_COLORS[zlib.crc32(str(scheme).encode()) % len(_FALLBACK_COLORS)]


# ----------------------------------------------------------------------------- table helpers


def _require_columns(table, columns, what):
    if table is None:
        raise MissingDataError(f"{what} is missing: the result has no such table.")
    missing = [c for c in columns if c not in table.colnames]
    if missing:
        raise ValueError(
            f"{what} lacks the column(s) {missing}; it has {table.colnames}. Pass a table "
            "with the StudyResult schema (see sklearn_psf.compare.StudyResult)."
        )


def _mask(table, **equal):
    mask = np.ones(len(table), dtype=bool)
    for name, value in equal.items():
        if value is None:
            continue
        mask &= np.asarray(table[name]) == value
    return mask


def _unique_in_order(values):
    """Distinct values as strings, in order of first appearance."""
    return list(dict.fromkeys(np.asarray(values).astype(str).tolist()))


def _as_list(value):
    if isinstance(value, str):
        return [value]
    return list(value)


def _check_schemes(schemes):
    schemes = _as_list(schemes)
    if not schemes:
        raise ValueError("schemes is empty: pass at least one scheme name, e.g. ['kriging'].")
    return schemes


def residual_component(rows, quantity: str):
    """Input, model and residual (model minus truth) of one quantity for the given rows.

    Parameters
    ----------
    rows : astropy.table.Table
        Rows of a ``galaxies`` table.
    quantity : str
        ``"e1"``, ``"e2"`` or ``"coeffK"`` (PCA coefficient K, from the ``coeffs_true`` and
        ``coeffs_model`` array columns).

    Returns
    -------
    true, model, residual : ndarray of shape (len(rows),)

    Examples
    --------
    >>> from astropy.table import Table
    >>> from sklearn_psf.plotting import residual_component
    >>> t = Table({"e1_true": [0.1], "e1_model": [0.12]})
    >>> [round(float(v[0]), 3) for v in residual_component(t, "e1")]
    [0.1, 0.12, 0.02]
    """
    if quantity in ("e1", "e2"):
        _require_columns(rows, [f"{quantity}_true", f"{quantity}_model"], "galaxies")
        true = np.asarray(rows[f"{quantity}_true"], dtype=float)
        model = np.asarray(rows[f"{quantity}_model"], dtype=float)
    else:
        match = re.fullmatch(r"coeff(\d+)", str(quantity))
        if match is None:
            raise ValueError(
                f"quantity must be 'e1', 'e2' or 'coeffK' (K = 0, 1, ...), got {quantity!r}."
            )
        k = int(match.group(1))
        _require_columns(rows, ["coeffs_true", "coeffs_model"], "galaxies")
        ct = np.asarray(rows["coeffs_true"], dtype=float).reshape(len(rows), -1)
        cm = np.asarray(rows["coeffs_model"], dtype=float).reshape(len(rows), -1)
        if k >= ct.shape[1]:
            raise MissingDataError(
                f"{quantity!r} asked for, but the galaxies table holds only {ct.shape[1]} "
                f"PCA coefficients (coeff0 .. coeff{ct.shape[1] - 1})."
            )
        true, model = ct[:, k], cm[:, k]
    return true, model, model - true


def _quantity_label(quantity):
    if quantity in ("e1", "e2"):
        return f"$e_{quantity[1]}$"
    return f"PCA coefficient {quantity[5:]}"


def _default_simulation(galaxies, config, schemes, layout):
    mask = _mask(galaxies, config=config, layout=layout) & np.isin(
        np.asarray(galaxies["scheme"]), schemes
    )
    if not mask.any():
        raise MissingDataError(
            f"no galaxy-PSFs with config={config!r}, layout={layout!r} for schemes {schemes}."
        )
    return int(np.min(np.asarray(galaxies["simulation"])[mask]))


def _map_rows(galaxies, schemes, config, simulation, layout):
    """Rows of one simulation for each scheme, sorted identically (by y then x)."""
    _require_columns(galaxies, ["config", "simulation", "scheme", "layout", "x", "y"], "galaxies")
    if simulation is None:
        simulation = _default_simulation(galaxies, config, schemes, layout)
    out = {}
    for scheme in schemes:
        rows = galaxies[
            _mask(galaxies, config=config, simulation=simulation, scheme=scheme, layout=layout)
        ]
        if len(rows) == 0:
            raise MissingDataError(
                f"no {layout!r} galaxy-PSFs for scheme {scheme!r} in config {config!r}, "
                f"simulation {simulation}."
            )
        order = np.lexsort((np.asarray(rows["x"]), np.asarray(rows["y"])))
        out[scheme] = rows[order]
    return out, simulation


def _lattice(x, y):
    """Unique x, y of points on a full rectangular lattice, or None when they are not."""
    ux, uy = np.unique(x), np.unique(y)
    if len(ux) * len(uy) > 1.5 * len(x) or len(ux) < 2 or len(uy) < 2:
        return None
    return ux, uy


def _edges(centres):
    c = np.asarray(centres, dtype=float)
    mids = 0.5 * (c[1:] + c[:-1])
    return np.concatenate([[2 * c[0] - mids[0]], mids, [2 * c[-1] - mids[-1]]])


def _grid_spacing(x, y):
    lattice = _lattice(x, y)
    if lattice is not None:
        steps = np.concatenate([np.diff(lattice[0]), np.diff(lattice[1])])
        return float(np.min(steps[steps > 0]))
    area = max(np.ptp(x), 1.0) * max(np.ptp(y), 1.0)
    return float(np.sqrt(area / max(len(x), 1)))


def _new_figure(nrows, ncols, panel=(3.2, 2.8), sharex=False, sharey=False):
    fig = Figure(figsize=(panel[0] * ncols + 0.8, panel[1] * nrows + 0.6), layout="constrained")
    axes = fig.subplots(nrows, ncols, squeeze=False, sharex=sharex, sharey=sharey)
    return fig, axes


# ----------------------------------------------------------------------------- fig_sim


def plot_psf_examples(stamps, positions=None, pixel_scale: float = 0.2, ncols: int | None = None,
                      floor: float = 1e-4, cmap: str = "magma") -> Figure:
    """Example PSF stamps with a logarithmic colour scale (paper's fig_sim).

    Parameters
    ----------
    stamps : array-like of shape (n, s, s) or (n, s*s)
        PSF stamps (e.g. 9 stars spread over the image).
    positions : array-like of shape (n, 2), optional
        (x, y) pixel positions of the stamps in the image, shown in the panel titles.
    pixel_scale : float
        Arcsec per pixel: the axes are in arcsec from the stamp centre.
    ncols : int, optional
        Panels per row (default: about the square root of n).
    floor : float
        Lower end of the colour scale as a fraction of the brightest pixel; pixels below it
        (including zero or negative noise) are shown at the floor colour.
    cmap : str
        Colour map.

    Returns
    -------
    fig : matplotlib.figure.Figure
        One panel per stamp, sharing one logarithmic colour scale.

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.plotting import plot_psf_examples
    >>> yy, xx = np.mgrid[-3:4, -3:4]
    >>> stamps = np.array([np.exp(-(xx**2 + yy**2) / w) for w in (2.0, 3.0)])
    >>> fig = plot_psf_examples(stamps, positions=[[10, 20], [500, 300]])
    >>> len(fig.axes) - 1  # panels, plus one colour bar
    2
    """
    from ._validation import as_stamps

    cube = as_stamps(stamps)
    n, size = cube.shape[0], cube.shape[1]
    if n == 0:
        raise MissingDataError("no stamps to plot: pass at least one PSF stamp.")
    if positions is not None:
        positions = np.asarray(positions, dtype=float)
        if positions.shape != (n, 2):
            raise ValueError(f"positions must have shape ({n}, 2) like the stamps, "
                             f"got {positions.shape}.")
    if not pixel_scale > 0:
        raise ValueError(f"pixel_scale must be positive (arcsec per pixel), got {pixel_scale}.")
    peak = float(np.max(cube))
    if not peak > 0:
        raise ValueError("the stamps have no positive pixel: a log colour scale needs flux.")
    ncols = int(ncols) if ncols else int(np.ceil(np.sqrt(n)))
    nrows = int(np.ceil(n / ncols))
    fig, axes = _new_figure(nrows, ncols, panel=(2.4, 2.4))
    norm = LogNorm(vmin=peak * floor, vmax=peak)
    half = size * pixel_scale / 2.0
    image, kept = None, []
    for i, ax in enumerate(axes.flat):
        if i >= n:
            ax.remove()
            continue
        kept.append(ax)
        image = ax.imshow(np.clip(cube[i], peak * floor, None), origin="lower", norm=norm,
                          cmap=cmap, extent=(-half, half, -half, half), interpolation="nearest")
        if positions is not None:
            ax.set_title(f"(x, y) = ({positions[i, 0]:.0f}, {positions[i, 1]:.0f}) px",
                         fontsize=8)
        ax.set_xlabel("arcsec", fontsize=8)
        ax.set_ylabel("arcsec", fontsize=8)
        ax.tick_params(labelsize=7)
    fig.colorbar(image, ax=kept, label="flux (log scale)")
    fig.suptitle(f"Example PSFs ({pixel_scale:g} arcsec/pixel)")
    return fig


# ----------------------------------------------------------------------------- fig_ell


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
    >>> from sklearn_psf.report import synthetic_study_result
    >>> from sklearn_psf.plotting import plot_ellipticity_maps
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
        ux, uy = lattice
        grid = np.full((len(uy), len(ux)), np.nan)
        grid[np.searchsorted(uy, y), np.searchsorted(ux, x)] = values
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
    >>> from sklearn_psf.report import synthetic_study_result
    >>> from sklearn_psf.plotting import plot_component_maps
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
    >>> from sklearn_psf.report import synthetic_study_result
    >>> from sklearn_psf.plotting import plot_residual_pairs
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
    fig.suptitle(f"Residual pairs, {config} (contours 0.1..0.9 of the maximum)")
    return fig


# ----------------------------------------------------------------------------- fig_cor


def _xi_stack(correlations, config, scheme, kind, nbins):
    rows = correlations[_mask(correlations, config=config, scheme=scheme, kind=kind)]
    if len(rows) == 0:
        raise MissingDataError(
            f"no {kind!r} correlation functions for scheme {scheme!r} in config {config!r}."
        )
    xi = np.asarray(rows["xi"], dtype=float).reshape(len(rows), -1)
    if xi.shape[1] != nbins:
        raise ValueError(f"xi has {xi.shape[1]} bins but theta has {nbins}: they must match.")
    return xi


def _draw_xi(ax, theta, xi_stack, color, label, gid, band=True):
    """|mean xi| as a line, open circles where the mean is negative, 16-84% band."""
    mean = xi_stack.mean(axis=0)
    absmean = np.abs(mean)
    shown = np.where(absmean > 0, absmean, np.nan)
    (line,) = ax.plot(theta, shown, color=color, label=label, lw=1.5)
    line.set_gid(gid)
    negative = mean < 0
    if negative.any():
        ax.plot(theta[negative], absmean[negative], ls="none", marker="o", mfc="none",
                mec=color, ms=5, gid=f"{gid}:negative")
    if band and len(xi_stack) > 1:
        lo, hi = np.percentile(xi_stack, [16, 84], axis=0)
        positive = shown[np.isfinite(shown)]
        floor = 0.1 * positive.min() if positive.size else 1e-12
        band_lo = np.where(lo > 0, lo, np.where(hi < 0, -hi, floor))
        band_hi = np.maximum(np.abs(lo), np.abs(hi))
        band_hi = np.where(band_hi > 0, band_hi, floor)
        ax.fill_between(theta, band_lo, band_hi, color=color, alpha=0.2, lw=0, gid=f"{gid}:band")
    return line


def _draw_requirements(ax, theta, requirements):
    if not requirements:
        return
    for level in sorted(requirements, reverse=True):
        limit = np.asarray(requirements[level], dtype=float)
        if limit.shape != theta.shape:
            raise ValueError(f"requirement curve for {level} has shape {limit.shape}, "
                             f"theta has {theta.shape}.")
        shown = np.where(limit > 0, limit, np.nan)
        ax.plot(theta, shown, ls=":", color="0.4", lw=1, gid=f"requirement:{float(level):g}")
        good = np.flatnonzero(np.isfinite(shown))
        if good.size:
            k = good[-1]
            ax.annotate(rf"$\sigma^2_{{sys}}$={float(level):.0e}", (theta[k], shown[k]),
                        fontsize=6, color="0.3", ha="right", va="bottom")


def _correlation_inputs(result):
    correlations = getattr(result, "correlations", None)
    _require_columns(correlations, ["config", "scheme", "kind", "xi"], "correlations")
    theta = getattr(result, "theta", None)
    if theta is None:
        raise MissingDataError("the result has no theta (separations of the correlation bins).")
    return correlations, np.asarray(theta, dtype=float)


def plot_correlation_functions(result, schemes, config: str = "default",
                               ncols: int = 3) -> Figure:
    """PSF ellipticity correlation functions of input, model and residual (fig_cor).

    One panel per scheme: ``|xi+|`` of the input (black), model (red) and residual (green,
    Rowe's D1), each the mean over the simulations of ``config``, with the 16-84% spread
    over simulations as a band. Log-log axes; a negative mean is drawn at its absolute value
    with an open circle. When ``result.requirements`` is given, each level's D1 limit is drawn
    dotted and labelled.

    Parameters
    ----------
    result : StudyResult
        Needs ``correlations`` and ``theta``; ``requirements`` is optional.
    schemes : sequence of str
        One panel each.
    config : str
        Configuration label.
    ncols : int
        Panels per row.

    Returns
    -------
    fig : matplotlib.figure.Figure
        ``len(schemes)`` panels, shared axes.

    Examples
    --------
    >>> from sklearn_psf.report import synthetic_study_result
    >>> from sklearn_psf.plotting import plot_correlation_functions
    >>> result = synthetic_study_result(n_simulations=3)
    >>> fig = plot_correlation_functions(result, ["polynomial", "delaunay", "kriging"])
    >>> [ax.get_xscale() for ax in fig.axes]
    ['log', 'log', 'log']
    """
    schemes = _check_schemes(schemes)
    correlations, theta = _correlation_inputs(result)
    requirements = getattr(result, "requirements", None)
    ncols = max(1, min(int(ncols), len(schemes)))
    nrows = int(np.ceil(len(schemes) / ncols))
    fig, axes = _new_figure(nrows, ncols, panel=(3.6, 3.0), sharex=True, sharey=True)
    for i, ax in enumerate(axes.flat):
        if i >= len(schemes):
            ax.remove()
            continue
        scheme = schemes[i]
        n_sim = 0
        for kind in ("input", "model", "residual"):
            xi = _xi_stack(correlations, config, scheme, kind, len(theta))
            n_sim = len(xi)
            _draw_xi(ax, theta, xi, KIND_COLORS[kind], kind, f"{scheme}:{kind}")
        _draw_requirements(ax, theta, requirements)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(f"{scheme} ({n_sim} simulations)", fontsize=10)
        ax.set_xlabel(r"$\theta$ [arcmin]")
        if i % ncols == 0:
            ax.set_ylabel(r"$|\xi_+(\theta)|$")
        if i == 0:
            ax.legend(fontsize=7, loc="lower left")
    fig.suptitle(f"Ellipticity correlation functions, {config} "
                 "(open circles: negative mean, drawn at |xi|)")
    return fig


# ----------------------------------------------------------------------------- fig_corhsn


def _snr_value(label):
    match = re.fullmatch(r"snr=([0-9.eE+-]+)", label)
    return float(match.group(1)) if match else np.inf


def _snr_configs(correlations):
    labels = _unique_in_order(correlations["config"])
    snr = [c for c in labels if c.startswith("snr=")]
    if not snr:
        return []
    snr.sort(key=lambda c: (_snr_value(c), c))
    if "snr=100" not in snr and "default" in labels:
        snr.insert(0, "default")
    return snr


def plot_snr_study(result, scheme: str = "kriging", configs=None) -> Figure:
    """Residual correlation functions for several star S/N (fig_corhsn).

    The first configuration is the reference: its input (black), model (red) and residual
    correlation functions are drawn; the other configurations add their residual (blue, ...).
    When ``result.wiener`` is given, the Wiener-filter optimum is shown as two shaded bands:
    the span of the Gaussian random fields' correlation functions (input) and of their
    residuals after Wiener filtering.

    Parameters
    ----------
    result : StudyResult
        Needs ``correlations`` and ``theta``; ``wiener`` and ``requirements`` are optional.
    scheme : str
        Interpolation scheme (Kriging in the paper).
    configs : sequence of str, optional
        Configurations to compare, reference first. Default: every ``"snr=..."``
        configuration by increasing S/N (non-numeric ones last), preceded by ``"default"``
        when there is no ``"snr=100"``.

    Returns
    -------
    fig : matplotlib.figure.Figure

    Examples
    --------
    >>> from sklearn_psf.report import synthetic_study_result
    >>> from sklearn_psf.plotting import plot_snr_study
    >>> result = synthetic_study_result(n_simulations=2)
    >>> fig = plot_snr_study(result, "kriging")
    >>> sorted(line.get_label() for line in fig.axes[0].get_lines()
    ...        if not line.get_label().startswith("_"))
    ['input, snr=100', 'model, snr=100', 'residual, snr=100', 'residual, snr=700']
    """
    correlations, theta = _correlation_inputs(result)
    configs = _snr_configs(correlations) if configs is None else _as_list(configs)
    if not configs:
        raise MissingDataError("no S/N configurations ('snr=...') in the correlations table.")
    fig = Figure(figsize=(6.0, 4.6), layout="constrained")
    ax = fig.add_subplot()
    wiener = getattr(result, "wiener", None)
    if wiener:
        wt = np.asarray(wiener["theta"], float)
        for lo_key, hi_key, color, label in [
            ("input_lo", "input_hi", "0.6", "Gaussian random fields (input)"),
            ("residual_lo", "residual_hi", "tab:cyan", "Wiener-filter optimum (residual)"),
        ]:
            lo, hi = np.asarray(wiener[lo_key], float), np.asarray(wiener[hi_key], float)
            ax.fill_between(wt, np.where(lo > 0, lo, np.nan), np.where(hi > 0, hi, np.nan),
                            color=color, alpha=0.3, lw=0, label=label, gid=f"wiener:{lo_key[:-3]}")
    for i, config in enumerate(configs):
        kinds = ("input", "model", "residual") if i == 0 else ("residual",)
        for kind in kinds:
            xi = _xi_stack(correlations, config, scheme, kind, len(theta))
            color = KIND_COLORS[kind] if kind != "residual" else \
                _RESIDUAL_SERIES_COLORS[i % len(_RESIDUAL_SERIES_COLORS)]
            line = _draw_xi(ax, theta, xi, color, f"{kind}, {config}", f"snr:{config}:{kind}",
                            band=kind == "residual")
            line.set_gid(f"snr:{config}:{kind}")
    _draw_requirements(ax, theta, getattr(result, "requirements", None))
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel(r"$\theta$ [arcmin]")
    ax.set_ylabel(r"$|\xi_+(\theta)|$")
    ax.legend(fontsize=7)
    ax.set_title(f"{scheme}: correlation functions vs star S/N")
    return fig


# ----------------------------------------------------------------------------- fig_densell


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
    >>> from sklearn_psf.report import synthetic_study_result
    >>> from sklearn_psf.plotting import density_groups
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


def _density_xlabel(by):
    if by == "local":
        return "local stellar density [stars within 1 arcmin]"
    return "global stellar density [stars in the image]"


def plot_density_boxplots(galaxies, schemes, by: str = "local", component="e1",
                          config: str = "default", bins=None, scores=None, configs=None,
                          densities=None, whis=(5.0, 95.0)) -> Figure:
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

    Returns
    -------
    fig : matplotlib.figure.Figure

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.report import synthetic_study_result
    >>> from sklearn_psf.plotting import plot_density_boxplots
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
        ax.set_xticks(np.arange(len(labels)), labels)
        ax.set_xlim(-0.6, len(labels) - 0.4)
        ax.set_xlabel(_density_xlabel(by))
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
    >>> from sklearn_psf.report import synthetic_study_result
    >>> from sklearn_psf.plotting import plot_density_stats
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
            ax.set_xlabel(_density_xlabel(by), fontsize=8)
        if by == "global":
            for ax in axes[ci]:
                ax.set_xscale("log")
        axes[ci, 1].set_ylim(bottom=0)
    axes[0, 0].legend(fontsize=7)
    return fig


# ----------------------------------------------------------------------------- outliers


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
    >>> from sklearn_psf.plotting import plot_outlier_study
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
        ax.set_yscale("log")
        ax.set_ylabel(f"{metric} (median over simulations)")
    handles = [Patch(facecolor="white", edgecolor="0.3", hatch=hatches[j % len(hatches)],
                     label=config) for j, config in enumerate(configs)]
    axes[0][0].legend(handles=handles, fontsize="small")
    fig.suptitle("Outlying stars: residuals with and without the IQR cut")
    return fig
