"""Figures of several PSF models validated on the same stars (:func:`validate_models`)."""

from __future__ import annotations

import numpy as np

from .._validation import as_stamps
from ..metrics import RHO_NAMES
from ._figures import _log_errorbars, _whisker

__all__ = ["plot_model_comparison"]

_MARKERS = "osD^vP*X"


def _style(k):
    return {"color": f"C{k % 10}", "marker": _MARKERS[k % len(_MARKERS)]}


def _measured(table):
    return table[np.asarray(table["flag"]) == 0]


def _rho_figure(results, units):
    import matplotlib.pyplot as plt
    from matplotlib.ticker import NullFormatter

    fig, axes = plt.subplots(2, 3, figsize=(13, 7.5), layout="constrained")
    axes = axes.ravel()
    for j, name in enumerate(RHO_NAMES):
        ax = axes[j]
        drawn = []
        for k, (model, (_, summary)) in enumerate(results.items()):
            r = summary.get(name)
            if not r:
                continue
            drawn.append((r, {**_style(k), "ms": 5, "label": model}))
        _log_errorbars(ax, drawn)  # (lower bars clipped at the log axis' bottom)
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_title(rf"$\rho_{name[-1]}$", fontsize=12)
        ax.set_xlabel(rf"separation $\theta$ [{units}]")
        ax.set_ylabel(rf"$|\rho_{name[-1]}(\theta)|$")
        ax.grid(alpha=0.3, which="major")
    legend = axes[-1]
    legend.axis("off")
    handles, labels = axes[0].get_legend_handles_labels()
    if handles:
        legend.legend(handles, labels, loc="upper left", fontsize=10, title="model",
                      title_fontsize=10, frameon=False)
    legend.text(0.0, 0.35, "filled: positive, open: negative\n"
                r"$\rho_1 = \langle\delta e^*\delta e\rangle$, "
                r"$\rho_2 = \langle e^*\delta e\rangle$" "\n"
                r"$\rho_3 = \langle(e\,\delta T/T)^*(e\,\delta T/T)\rangle$" "\n"
                r"$\rho_4 = \langle\delta e^*(e\,\delta T/T)\rangle$, "
                r"$\rho_5 = \langle e^*(e\,\delta T/T)\rangle$" "\n"
                r"$\delta$ = star $-$ model, $T = 2\sigma^2$",
                transform=legend.transAxes, fontsize=9, va="top")
    fig.suptitle("rho statistics of the same reserved stars, one colour per model "
                 "(lower is better)")
    return fig


def _residuals_figure(results):
    import matplotlib.pyplot as plt

    quantities = (("de1", r"$e_1$ star $-$ model"), ("de2", r"$e_2$ star $-$ model"),
                  ("dsigma", r"$\sigma$ star $-$ model [pixel]"),
                  ("chi2_dof", r"$\chi^2$ / dof of each star"))
    fig, axes = plt.subplots(2, 2, figsize=(11, 7.5), layout="constrained")
    for ax, (key, label) in zip(axes.ravel(), quantities):
        values = {}
        for model, (table, _) in results.items():
            t = table if key == "chi2_dof" else _measured(table)  # every star has a chi^2
            if key == "chi2_dof":
                dof = np.asarray(t["dof"], float)
                v = np.asarray(t["chi2"], float) / np.where(dof > 0, dof, np.nan)
            else:
                v = np.asarray(t[key], float)
            values[model] = v[np.isfinite(v)]
        every = np.concatenate([v for v in values.values()] or [np.zeros(0)])
        if every.size == 0:
            ax.set_axis_off()
            continue
        if key == "chi2_dof":
            lo, hi = np.percentile(every, [0.5, 99.5])
            bins = np.linspace(min(lo, 0.9), max(hi, 1.1), 31)
            ax.axvline(1.0, color="0.5", ls=":", lw=1)
        else:
            lim = float(np.percentile(np.abs(every), 99.5)) or 1e-3
            bins = np.linspace(-lim, lim, 31)
            ax.axvline(0.0, color="0.5", ls=":", lw=1)
        for k, (model, v) in enumerate(values.items()):
            if key == "chi2_dof":
                stat = f"median {np.median(v):.2f}" if v.size else "none"
            else:
                stat = f"mean {np.mean(v):+.4f}, rms {np.sqrt(np.mean(v**2)):.4f}" \
                    if v.size else "none"
            ax.hist(v, bins=bins, histtype="step", lw=1.6, color=_style(k)["color"],
                    label=f"{model}: {stat}")
        ax.set_xlabel(label)
        ax.set_ylabel("reserved stars")
        ax.legend(fontsize=8, loc="upper left")
    fig.suptitle("Residuals of the same reserved stars (narrower around 0, or "
                 r"$\chi^2$/dof nearer 1, is better)")
    return fig


def _nice(value):
    """The largest of 1, 2, 5, 10, 20, ... not above value (at least 1)."""
    if not np.isfinite(value) or value < 2:
        return 1.0
    decade = 10.0 ** np.floor(np.log10(value))
    return float(max(m * decade for m in (1, 2, 5) if m * decade <= value))


def _stamps_figure(results):
    import matplotlib.pyplot as plt

    first = _measured(next(iter(results.values()))[0])
    if len(first) == 0:
        raise ValueError("No measured reserved stars to plot.")
    star = as_stamps(np.asarray(first["stamp_star"])).mean(axis=0)
    z = {}
    for model, (table, _) in results.items():
        t = _measured(table)
        diff = as_stamps(np.asarray(t["stamp_star"]) - np.asarray(t["stamp_model"]))
        if len(t) < 2:
            z[model] = np.zeros_like(star)
            continue
        err = diff.std(axis=0, ddof=1) / np.sqrt(len(t))
        z[model] = np.divide(diff.mean(axis=0), err, out=np.zeros_like(star), where=err > 0)
    m = len(z)
    fig, axes = plt.subplots(1, m + 1, figsize=(3.1 * (m + 1) + 1.4, 4.0),
                             layout="constrained", squeeze=False)
    axes = axes[0]
    half = star.shape[0] / 2
    extent = (-half, half, -half, half)
    im = axes[0].imshow(star / star.max(), origin="lower", extent=extent, cmap="magma",
                        interpolation="nearest")
    fig.colorbar(im, ax=axes[0], shrink=0.8, label="of the peak")
    axes[0].set_title("mean reserved star", fontsize=10)
    for ax, (model, zz) in zip(axes[1:], z.items()):
        im = ax.imshow(zz, origin="lower", extent=extent, cmap="RdBu_r", vmin=-5, vmax=5,
                       interpolation="nearest")
        ax.set_title(f"{model}\nrms {np.sqrt(np.mean(zz**2)):.2f}, "
                     f"|z| > 3: {int(np.sum(np.abs(zz) > 3))} pixels", fontsize=10)
    fig.colorbar(im, ax=axes[1:], shrink=0.8, extend="both",
                 label="z = mean(star $-$ model) / its standard error")
    for ax in axes:
        ax.set_xlabel("x [pixel]", fontsize=9)
        ax.tick_params(labelsize=8)
    axes[0].set_ylabel("y [pixel]", fontsize=9)
    fig.suptitle("Mean residual stamp of the reserved stars in units of its standard error "
                 "(unit flux; a pattern in one model only is that model's error)", fontsize=11)
    return fig


def _whiskers_figure(results, amplify):
    import matplotlib.pyplot as plt

    tables = {model: _measured(t) for model, (t, _) in results.items()}
    m = len(tables)
    first = next(iter(tables.values()))
    x, y = np.asarray(first["x"], float), np.asarray(first["y"], float)
    span = max(np.ptp(x), np.ptp(y), 1.0) if len(first) else 1.0
    emax = float(np.hypot(first["e1_star"], first["e2_star"]).max()) if len(first) else 0.05
    scale = span / 12.0 / max(emax, 1e-3)
    if amplify is None:  # the largest residuals about as long as the largest star whiskers
        big = max((float(np.percentile(np.hypot(t["de1"], t["de2"]), 95)) for t in
                   tables.values() if len(t)), default=0.0)
        amplify = _nice(emax / big) if big > 0 else 1.0
    fig, axes = plt.subplots(1, m + 1, figsize=(3.6 * (m + 1) + 0.8, 5.0), sharex=True,
                             sharey=True, layout="constrained", squeeze=False)
    axes = axes[0]
    if len(first):
        _whisker(axes[0], x, y, np.asarray(first["e1_star"]), np.asarray(first["e2_star"]),
                 scale, "k", "stars")
    axes[0].set_title("reserved stars: e", fontsize=10)
    for k, (ax, (model, t)) in enumerate(zip(axes[1:], tables.items())):
        de1, de2 = np.asarray(t["de1"], float), np.asarray(t["de2"], float)
        _whisker(ax, np.asarray(t["x"], float), np.asarray(t["y"], float), de1, de2,
                 scale * amplify, _style(k)["color"], model)
        rms = float(np.sqrt(np.mean(de1**2 + de2**2))) if len(t) else np.nan
        ax.set_title(f"{model}\nstar $-$ model (x{amplify:g}), rms {rms:.4f}", fontsize=10)
    for ax in axes:
        ax.set_aspect("equal")
        ax.margins(0.05)
        ax.set_xlabel("x [pixel]", fontsize=9)
        ax.tick_params(labelsize=8)
    axes[0].set_ylabel("y [pixel]", fontsize=9)
    fig.suptitle(f"Ellipticity of the stars and residual of each model (whisker of e = 0.05: "
                 f"{0.05 * scale:.0f} pixels; residuals {amplify:g} times longer)",
                 fontsize=11)
    return fig


def plot_model_comparison(results, *, amplify: float | None = None) -> dict:
    """The figures of :func:`validate_models`: every model on the same stars, side by side.

    Parameters
    ----------
    results : dict
        ``{name: (residuals, summary)}``, the second output of :func:`validate_models`.
    amplify : float, optional
        Residual whiskers are drawn ``amplify`` times longer than the stars'; default the
        largest of 1, 2, 5, 10, ... that keeps the models' 95th-percentile residual no
        longer than the stars' largest ellipticity.

    Returns
    -------
    figures : dict of matplotlib.figure.Figure
        ``"rho"``: rho1 to rho5 against separation, one colour per model (only when the
        summaries hold rho statistics, i.e. 10 or more measured stars); ``"residuals"``:
        histograms of the e1, e2 and size residuals and of each star's chi^2/dof;
        ``"stamps"``: the mean star and each model's mean residual stamp in units of its
        standard error (a pattern common to every model comes from the stars, e.g. their
        centring on a noisy centroid; one seen in one model only is that model's);
        ``"whiskers"``: the stars' ellipticity and each model's residual across the field.

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.validation import plot_model_comparison, validate_models
    >>> rng = np.random.default_rng(0)
    >>> yy, xx = np.mgrid[0:15, 0:15] - 7.0
    >>> g = np.exp(-0.5 * (xx**2 + yy**2) / 4.0).ravel(); g /= g.sum()
    >>> class Constant:
    ...     def predict(self, X):
    ...         return np.tile(g, (len(X), 1))
    >>> X = rng.uniform(0, 500, (30, 2))
    >>> stars = 1e4 * g + rng.normal(0.0, 1.0, (30, 225))
    >>> _, results = validate_models(X, stars, {"a": Constant(), "b": Constant()})
    >>> sorted(plot_model_comparison(results))
    ['residuals', 'rho', 'stamps', 'whiskers']
    """
    if not results:
        raise ValueError("No models to plot.")
    summaries = [sm for _, sm in results.values()]
    units = next((sm.get("rho_theta_units") for sm in summaries if sm.get("rho_theta_units")),
                 "pixel")
    figures = {}
    if any(sm.get("rho1") for sm in summaries):
        figures["rho"] = _rho_figure(results, units)
    figures["residuals"] = _residuals_figure(results)
    if len(_measured(next(iter(results.values()))[0])):  # shapes measured: their figures
        figures["stamps"] = _stamps_figure(results)
        figures["whiskers"] = _whiskers_figure(results, amplify)
    return figures
