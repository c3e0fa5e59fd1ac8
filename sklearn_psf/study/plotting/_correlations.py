"""Ellipticity correlation functions over simulations, and the S/N study."""

from __future__ import annotations

import re

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import NullLocator

from .._names import ORACLE
from ._common import (
    _as_list,
    _check_schemes,
    KIND_COLORS,
    _mask,
    MissingDataError,
    _new_figure,
    _require_columns,
    _RESIDUAL_SERIES_COLORS,
    _unique_in_order,
)


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


#: Lines of each kind of correlation: the input broad and light, under the model's thin line,
#: so that a model following the input closely leaves both visible.
KIND_LINES = {"input": {"lw": 5.0, "alpha": 0.35, "zorder": 1.9}, "model": {"lw": 1.2}}


def _draw_xi(ax, theta, xi_stack, color, label, gid, band=True, kind=None):
    """|mean xi| as a line (styled by ``KIND_LINES[kind]``), open circles where the mean is
    negative, 16-84% band."""
    mean = xi_stack.mean(axis=0)
    absmean = np.abs(mean)
    shown = np.where(absmean > 0, absmean, np.nan)
    (line,) = ax.plot(theta, shown, color=color, label=label,
                      **{"lw": 1.5, **KIND_LINES.get(kind, {})})
    line.set_gid(gid)
    negative = mean < 0
    if negative.any():
        ax.plot(theta[negative], absmean[negative], ls="none", marker="o", mfc="none",
                mec=color, ms=5, gid=f"{gid}:negative")
    if band and len(xi_stack) > 1:
        lo, hi = np.percentile(xi_stack, [16, 84], axis=0)
        # a band that contains zero reaches down to the bottom of the axis (_log_ylim)
        band_lo = np.where(lo > 0, lo, np.where(hi < 0, -hi, _BOTTOM))
        band_hi = np.maximum(np.abs(lo), np.abs(hi))
        band_hi = np.where(band_hi > 0, band_hi, _BOTTOM)
        ax.fill_between(theta, band_lo, band_hi, color=color, alpha=0.2, lw=0, gid=f"{gid}:band")
    return line


_BOTTOM = 1e-30  # lower edge of a band containing zero, below any axis limit


def _log_ylim(*axes):
    """Log y limits from the lines drawn (bands containing zero run off the bottom)."""
    values = np.concatenate([np.asarray(line.get_ydata(), float).ravel()
                             for ax in axes for line in ax.get_lines()] or [np.zeros(0)])
    values = values[np.isfinite(values) & (values > 0)]
    if values.size:
        for ax in axes:
            ax.set_ylim(values.min() / 5, values.max() * 3)


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
            # labelled in the right margin, clear of the curves
            ax.annotate(rf"$\sigma^2_{{sys}}$={float(level):.0e}", (1.01, shown[k]),
                        xycoords=("axes fraction", "data"), fontsize=8, color="0.3",
                        ha="left", va="center", annotation_clip=False)


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

    One panel per scheme: ``|xi+|`` of the input (a broad light black line, under the model's
    thin red one: a model that follows the input leaves both visible), model (red) and
    residual (green, Rowe's D1), each the mean over the simulations of ``config``, with the
    16-84% spread
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
    >>> from sklearn_psf.study.report import synthetic_study_result
    >>> from sklearn_psf.study.plotting import plot_correlation_functions
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
            _draw_xi(ax, theta, xi, KIND_COLORS[kind], kind, f"{scheme}:{kind}", kind=kind)
        _draw_requirements(ax, theta, requirements)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(f"{scheme} ({n_sim} simulations)", fontsize=10)
        ax.set_xlabel(r"$\theta$ [arcmin]")
        if i % ncols == 0:
            ax.set_ylabel(r"$|\xi_+(\theta)|$")
        if i == 0:
            ax.legend(fontsize=7, loc="lower left")
    _log_ylim(*fig.axes)
    for ax in fig.axes:  # minor ticks on ~10 decades are invisible and half the drawing time
        ax.yaxis.set_minor_locator(NullLocator())
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
    When the correlations have the scheme ``oracle`` (the best linear unbiased predictor with
    the simulation's true covariance and noise, on the same fields), its residual at each S/N
    is drawn dashed in the colour of that S/N (with its 16-84% band over simulations for the
    reference S/N): the optimum a scheme can reach on these fields.

    Parameters
    ----------
    result : StudyResult
        Needs ``correlations`` and ``theta``; ``requirements`` is optional.
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
    >>> from sklearn_psf.study.report import synthetic_study_result
    >>> from sklearn_psf.study.plotting import plot_snr_study
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
    fig = Figure(figsize=(6.4, 5.4), layout="constrained")
    ax = fig.add_subplot()
    for i, config in enumerate(configs):
        kinds = ("input", "model", "residual") if i == 0 else ("residual",)
        for kind in kinds:
            xi = _xi_stack(correlations, config, scheme, kind, len(theta))
            color = KIND_COLORS[kind] if kind != "residual" else \
                _RESIDUAL_SERIES_COLORS[i % len(_RESIDUAL_SERIES_COLORS)]
            line = _draw_xi(ax, theta, xi, color, f"{kind}, {config}", f"snr:{config}:{kind}",
                            band=kind == "residual", kind=kind)
            line.set_gid(f"snr:{config}:{kind}")
        try:
            oracle = _xi_stack(correlations, config, ORACLE, "residual", len(theta))
        except MissingDataError:
            continue
        # the oracle's band for the reference S/N only: more bands would hide the curves
        line = _draw_xi(ax, theta, oracle, color, f"oracle residual, {config}",
                        f"oracle:{config}", band=i == 0)
        line.set_linestyle("--")
        line.set_gid(f"oracle:{config}")
    _draw_requirements(ax, theta, getattr(result, "requirements", None))
    ax.set_xscale("log")
    ax.set_yscale("log")
    _log_ylim(ax)
    ax.set_xlabel(r"$\theta$ [arcmin]")
    ax.set_ylabel(r"$|\xi_+(\theta)|$")
    fig.legend(*ax.get_legend_handles_labels(), loc="outside lower center", ncols=3, fontsize=6)
    ax.set_title(f"{scheme}: correlation functions vs star S/N")
    return fig


# ----------------------------------------------------------------------------- fig_densell
