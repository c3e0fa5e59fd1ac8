"""Shared pieces of the study figures: scheme colours, table selection, map grids."""

from __future__ import annotations

import re
import zlib

import numpy as np
from matplotlib.figure import Figure


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
#: Axis labels of the scores' columns.
METRIC_LABELS = {
    "e_rms": "ellipticity residual rms",
    "e_rms_ratio": "e rms / oracle's",
    "coeff_rms": "PCA coefficient residual rms",
    "rho1_mean_abs": r"mean $|D_1|$ (residual $\xi_+$)",
    "sigma_sys2": r"implied $\sigma^2_{sys}$",
}


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
    >>> from sklearn_psf.study.plotting import scheme_color
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
            "with the StudyResult schema (see sklearn_psf.study.compare.StudyResult)."
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
    >>> from sklearn_psf.study.plotting import residual_component
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
    return f"PCA coefficient {int(quantity[5:]) + 1}"  # 1-based, as the paper numbers them


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


def _levels(values, tol=2.0):
    """Distinct levels of ``values`` up to ``tol`` pixels (sub-pixel offsets of a grid), and
    the level index of each value."""
    order = np.argsort(values)
    sorted_values = np.asarray(values, float)[order]
    starts = np.r_[True, np.diff(sorted_values) > tol]
    groups = np.cumsum(starts) - 1
    index = np.empty(len(values), dtype=int)
    index[order] = groups
    centres = np.bincount(groups, sorted_values) / np.bincount(groups)
    return centres, index


def _lattice(x, y):
    """Levels of x and y of points on a full rectangular lattice (to 2 pixels) and each point's
    level indices ``(ux, uy, ix, iy)``, or None when they are not on a lattice."""
    (ux, ix), (uy, iy) = _levels(x), _levels(y)
    if len(ux) * len(uy) > 1.5 * len(x) or len(ux) < 2 or len(uy) < 2:
        return None
    return ux, uy, ix, iy


def _edges(centres):
    c = np.asarray(centres, dtype=float)
    mids = 0.5 * (c[1:] + c[:-1])
    return np.concatenate([[2 * c[0] - mids[0]], mids, [2 * c[-1] - mids[-1]]])


def _grid_spacing(x, y):
    lattice = _lattice(x, y)
    if lattice is not None:
        steps = np.concatenate([np.diff(lattice[0]), np.diff(lattice[1])])  # level spacings
        return float(np.min(steps[steps > 0]))
    area = max(np.ptp(x), 1.0) * max(np.ptp(y), 1.0)
    return float(np.sqrt(area / max(len(x), 1)))


def _new_figure(nrows, ncols, panel=(3.2, 2.8), sharex=False, sharey=False):
    fig = Figure(figsize=(panel[0] * ncols + 0.8, panel[1] * nrows + 0.6), layout="constrained")
    axes = fig.subplots(nrows, ncols, squeeze=False, sharex=sharex, sharey=sharey)
    return fig, axes


# ----------------------------------------------------------------------------- fig_sim
