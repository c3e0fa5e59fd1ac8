"""The diagnostic figures of a PSF model's validation (what ``sklearn-psf fit`` writes)."""

from __future__ import annotations

import numpy as np

from .._validation import as_stamps
from ..measure import adaptive_moments, fixed_moments
from ._residuals import FIXED_WEIGHT_SIGMA

__all__ = ["plot_stamp_residuals", "plot_whiskers", "plot_rho1", "plot_rho_statistics",
           "plot_psf_maps", "plot_residuals_against"]


#: The stamps' stretch: linear within this fraction of the peak, logarithmic above (asinh):
#: a PSF's wings at a few % of its peak stay visible next to its core.
_ASINH_WIDTH = 0.02


def plot_stamp_residuals(residuals, n: int = 5, pixel_scale: float | None = None):
    """Reserved stars, model PSFs at their positions and residuals (one column per star).

    Each column is drawn relative to its model's peak, so that faint and bright stars look
    alike: the star and the model on an asinh stretch (linear within 2% of the peak,
    logarithmic above, so the wings show next to the core), the residual star - model, in %
    of the peak, on a symmetric scale of its own (its 99.5th percentile of ``|star - model|``:
    one hot pixel or one bright star does not set the scale of the others).

    Parameters
    ----------
    residuals : astropy.table.Table
        From :func:`fit_and_validate` (``stamp_star``, ``stamp_model``, ``x``, ``y``).
    n : int, default=5
        Stars shown (spread over the table).
    pixel_scale : float, optional
        Arcsec per pixel for the axes; pixels when None.

    Returns
    -------
    fig : matplotlib.figure.Figure

    Examples
    --------
    >>> import numpy as np
    >>> from astropy.table import Table
    >>> from sklearn_psf.validation import plot_stamp_residuals
    >>> yy, xx = np.mgrid[-4:5, -4:5]
    >>> g = np.exp(-(xx**2 + yy**2) / 4.0).ravel(); g /= g.sum()
    >>> t = Table({"x": [1.0, 2.0], "y": [3.0, 4.0], "stamp_star": [g, g],
    ...            "stamp_model": [g * 0.99, g]})
    >>> len(plot_stamp_residuals(t).axes)  # 3 rows x 2 stars, 1 + 2 colour bars
    9
    """
    import matplotlib.pyplot as plt
    from matplotlib.colors import AsinhNorm

    if len(residuals) == 0:
        raise ValueError("No reserved stars to plot.")
    idx = np.unique(np.linspace(0, len(residuals) - 1, min(n, len(residuals))).astype(int))
    star = as_stamps(np.asarray(residuals["stamp_star"])[idx])
    model = as_stamps(np.asarray(residuals["stamp_model"])[idx])
    s = star.shape[1]
    half = s / 2 * (pixel_scale or 1.0)
    extent = (-half, half, -half, half)
    m = len(idx)
    fig, axes = plt.subplots(3, m, figsize=(2.2 * m + 1.0, 7.2), squeeze=False,
                             layout="constrained")
    peak = np.array([float(model[j].max()) or float(star[j].max()) or 1.0 for j in range(m)])
    norm = AsinhNorm(linear_width=_ASINH_WIDTH, vmin=-2 * _ASINH_WIDTH, vmax=1.0)
    for j in range(m):
        for i, img in enumerate((star[j], model[j])):
            im = axes[i, j].imshow(img / peak[j], origin="lower", extent=extent, cmap="magma",
                                   norm=norm, interpolation="nearest")
        resid = 100.0 * (star[j] - model[j]) / peak[j]
        lim = float(np.percentile(np.abs(resid), 99.5)) or 1.0
        rim = axes[2, j].imshow(resid, origin="lower", extent=extent, cmap="RdBu_r",
                                vmin=-lim, vmax=lim, interpolation="nearest")
        bar = fig.colorbar(rim, ax=axes[2, j], location="bottom", shrink=0.9, aspect=15)
        bar.ax.tick_params(labelsize=6)
        bar.set_label("% of the peak", fontsize=7)
        for ax in axes[:, j]:
            ax.tick_params(labelsize=6)
        axes[0, j].set_title(f"({residuals['x'][idx[j]]:.0f}, {residuals['y'][idx[j]]:.0f})",
                             fontsize=8)
    bar = fig.colorbar(im, ax=axes[:2, :], shrink=0.8)
    bar.set_ticks([-0.03, 0.0, 0.03, 0.1, 0.3, 1.0])
    bar.set_ticklabels(["-0.03", "0", "0.03", "0.1", "0.3", "1"])
    bar.set_label("fraction of the model's peak (asinh stretch)", fontsize=8)
    for i, label in enumerate(("reserved star", "model", "star - model")):
        axes[i, 0].set_ylabel(label)
    fig.suptitle("Reserved stars, model and residuals (each column relative to its model's "
                 "peak)")
    return fig


def _whisker(ax, x, y, e1, e2, scale, color, label):
    mod = np.hypot(e1, e2)
    ang = 0.5 * np.arctan2(e2, e1)
    ax.quiver(x, y, mod * np.cos(ang), mod * np.sin(ang), angles="xy", scale_units="xy",
              scale=1.0 / scale, headwidth=0, headlength=0, headaxislength=0, pivot="middle",
              color=color, label=label, width=0.004)


def plot_whiskers(residuals, amplify: float = 5.0, length: float | None = None):
    """Whisker plots of the ellipticity over the field: stars, model, amplified residual.

    Parameters
    ----------
    residuals : astropy.table.Table
        From :func:`fit_and_validate`.
    amplify : float, default=5
        Residual whiskers are drawn ``amplify`` times longer.
    length : float, optional
        Pixels of whisker per unit ellipticity; default: 1/12 of the field for the largest
        ellipticity.

    Returns
    -------
    fig : matplotlib.figure.Figure

    Examples
    --------
    >>> from astropy.table import Table
    >>> from sklearn_psf.validation import plot_whiskers
    >>> t = Table({"x": [0.0, 100.0], "y": [0.0, 50.0], "e1_star": [0.05, 0.0],
    ...            "e2_star": [0.0, 0.05], "e1_model": [0.04, 0.0], "e2_model": [0.0, 0.06],
    ...            "flag": [0, 0]})
    >>> len(plot_whiskers(t).axes)
    3
    """
    import matplotlib.pyplot as plt

    ok = np.asarray(residuals["flag"]) == 0
    if not ok.any():
        raise ValueError("No measured reserved stars to plot.")
    t = residuals[ok]
    x, y = np.asarray(t["x"]), np.asarray(t["y"])
    e1s, e2s = np.asarray(t["e1_star"]), np.asarray(t["e2_star"])
    e1m, e2m = np.asarray(t["e1_model"]), np.asarray(t["e2_model"])
    span = max(np.ptp(x), np.ptp(y), 1.0)
    emax = float(max(np.hypot(e1s, e2s).max(), np.hypot(e1m, e2m).max(), 1e-3))
    scale = length or span / 12.0 / emax
    # panels of the field's shape (a whisker's half-length of margin): a tall CCD gets tall,
    # narrow panels side by side, with no wide gaps between them
    pad = 0.6 * span / 12.0 * max(1.0, amplify * float(np.hypot(e1s - e1m, e2s - e2m).max())
                                  / emax)
    limits = ((x.min() - pad, x.max() + pad), (y.min() - pad, y.max() + pad))
    ratio = float(np.clip(np.ptp(limits[1]) / np.ptp(limits[0]), 0.2, 5.0))
    height = 4.2 if ratio >= 1 else float(np.clip(4.2 * ratio, 1.5, 4.2))
    width = float(np.clip(height / ratio, 1.3, 5.0))
    fig, axes = plt.subplots(1, 3, figsize=(3 * width + 1.4, height + 1.1), sharex=True,
                             sharey=True, layout="constrained")
    _whisker(axes[0], x, y, e1s, e2s, scale, "k", "stars")
    _whisker(axes[1], x, y, e1m, e2m, scale, "C0", "model")
    _whisker(axes[2], x, y, e1s - e1m, e2s - e2m, scale * amplify, "C3", "residual")
    titles = ("reserved stars", "model at the stars", f"star - model (x{amplify:g})")
    for ax, title in zip(axes, titles):
        ax.set_title(title, fontsize=10)
        ax.set_xlim(*limits[0])
        ax.set_ylim(*limits[1])
        ax.set_aspect("equal")
        ax.set_xlabel("x [pixel]")
        ax.tick_params(labelsize=7)
    axes[0].set_ylabel("y [pixel]")
    fig.suptitle(f"PSF ellipticity (whisker of e = 0.05: {0.05 * scale:.0f} pixels)",
                 fontsize=10)
    return fig


def _log_errorbars(ax, series, spread: float = 0.04):
    """Correlation functions with their error bars on log-log axes: ``|xi|`` (open symbols
    where negative), each lower bar clipped at the axis' bottom where ``|xi| - sigma`` is not
    positive (the value is consistent with 0), the vertical range that of the points and
    upper bars (not of the lower bars, which a log axis cannot show).

    ``series``: ``(r, style)`` pairs, ``r`` a dict with ``theta``, ``xi``, ``sigma_xi`` and
    ``style`` the ``errorbar`` keywords (``color``, ``label``...); series are shifted along
    theta by ``spread`` (relative) to stand side by side."""
    data = []
    for k, (r, style) in enumerate(series):
        theta, xi = np.asarray(r["theta"], float), np.asarray(r["xi"], float)
        err = np.nan_to_num(np.asarray(r["sigma_xi"], float), nan=0.0)
        ok = np.isfinite(xi) & (xi != 0) & np.isfinite(theta)
        shift = 1 + spread * (k - (len(series) - 1) / 2)
        data.append((theta[ok] * shift, np.abs(xi[ok]), err[ok], xi[ok] > 0, style))
    values = np.concatenate([d[1] for d in data]) if data else np.zeros(0)
    ax.set_xscale("log")
    if not values.size:
        return
    bottom = float(values.min()) / 4.0
    top = float(max(np.max(d[1] + d[2]) if d[1].size else 0.0 for d in data)) * 1.5
    for theta, value, err, positive, style in data:
        lower = np.minimum(err, value - bottom * 1.0001)
        negative = ~positive
        labelled = positive if positive.any() else negative
        for sel, face in ((positive, style.get("color")), (negative, "none")):
            kw = {"marker": "o", "ls": "none", **style,
                  "label": style.get("label") if sel is labelled else None}
            ax.errorbar(theta[sel], value[sel], yerr=[lower[sel], err[sel]], mfc=face,
                        capsize=0, **kw)
    ax.set_yscale("log")
    ax.set_ylim(bottom, top)


def plot_rho1(summary):
    """rho1 (D1) of the reserved stars' residuals against separation.

    Parameters
    ----------
    summary : dict
        From :func:`fit_and_validate` (its ``rho1`` entry).

    Returns
    -------
    fig : matplotlib.figure.Figure

    Examples
    --------
    >>> from sklearn_psf.validation import plot_rho1
    >>> s = {"rho1": {"theta": [10.0, 100.0], "xi": [1e-5, -2e-6], "sigma_xi": [1e-6, 1e-6]}}
    >>> len(plot_rho1(s).axes)
    1
    """
    import matplotlib.pyplot as plt

    r = summary.get("rho1")
    if not r:
        raise ValueError("The summary has no rho1 (fewer than 10 measured reserved stars).")
    fig, ax = plt.subplots(figsize=(5.5, 4), layout="constrained")
    _log_errorbars(ax, [(r, {"color": "C0", "label": r"$|\rho_1|$"})])
    ax.set_xlabel(r"separation $\theta$ [pixel]")
    ax.set_ylabel(r"$|\rho_1(\theta)|$")
    ax.set_title("rho1 of the reserved stars (star - model)")
    ax.legend(fontsize=8)
    return fig


def plot_rho_statistics(summary):
    """rho1 to rho5 of the reserved stars against separation, as PIFF plots them.

    Left: rho1, rho3, rho4 (the residual terms); right: rho2, rho5. With the fourth moments'
    correlation functions in the summary (``rho_M4`` ...,
    :func:`~sklearn_psf.metrics.fourth_moment_rho_statistics`), a second row: spin 2
    (``rho_M4``, ``rho_eM4``) and spin 0 (``rho_M22``, ``rho_TM22``). Negative values are
    drawn as open symbols at their absolute value.

    Parameters
    ----------
    summary : dict
        From :func:`fit_and_validate` (its ``rho1`` ... ``rho5`` entries).

    Returns
    -------
    fig : matplotlib.figure.Figure

    Examples
    --------
    >>> from sklearn_psf.validation import plot_rho_statistics
    >>> r = {"theta": [10.0, 100.0], "xi": [1e-5, -2e-6], "sigma_xi": [1e-6, 1e-6]}
    >>> len(plot_rho_statistics({f"rho{k}": r for k in range(1, 6)}).axes)
    2
    >>> four = {n: r for n in ("rho_M4", "rho_eM4", "rho_M22", "rho_TM22")}
    >>> len(plot_rho_statistics({**{f"rho{k}": r for k in range(1, 6)}, **four}).axes)
    4
    """
    import matplotlib.pyplot as plt

    if not summary.get("rho1"):
        raise ValueError("The summary has no rho statistics (fewer than 10 measured reserved "
                         "stars).")
    from matplotlib.ticker import NullFormatter

    labels = {f"rho{k}": (rf"$\rho_{k}$", f"C{k - 1}") for k in range(1, 6)}
    labels.update({"rho_M4": (r"$\langle dM_4^* dM_4 \rangle$", "C0"),
                   "rho_eM4": (r"$\langle de^* dM_4 \rangle$", "C1"),
                   "rho_M22": (r"$\langle dM_{22} dM_{22} \rangle$", "C2"),
                   "rho_TM22": (r"$\langle (dT/T) dM_{22} \rangle$", "C3")})
    fourth = bool(summary.get("rho_M4"))
    fig, axes = plt.subplots(1 + fourth, 2, figsize=(10, 4 + 3.5 * fourth),
                             layout="constrained", squeeze=False)
    panels = [(axes[0, 0], ("rho1", "rho3", "rho4")), (axes[0, 1], ("rho2", "rho5"))]
    if fourth:  # the fourth moments' (over sigma^4): spin 2, spin 0
        panels += [(axes[1, 0], ("rho_M4", "rho_eM4")), (axes[1, 1], ("rho_M22", "rho_TM22"))]
    for ax, names in panels:
        _log_errorbars(ax, [(summary[name], {"color": labels[name][1],
                                            "label": labels[name][0]})
                           for name in names if summary.get(name)], spread=0.03)
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_xlabel(rf"separation $\theta$ [{summary.get('rho_theta_units', 'pixel')}]")
        ax.set_ylabel(r"$|\rho(\theta)|$ (open: negative)")
        ax.legend(fontsize=8)
    if fourth:
        axes[1, 0].set_title("fourth moments, spin 2: M4 = M31 + i M13 (over sigma^4)",
                             fontsize=9)
        axes[1, 1].set_title("fourth moments, spin 0: M22 (over sigma^4)", fontsize=9)
    fig.suptitle("rho statistics of the reserved stars (Jarvis et al. 2016); error bars "
                 "reaching the bottom axis: consistent with 0", fontsize=11)
    return fig


def plot_psf_maps(model, shape, n_grid: int = 20):
    """The model's PSF across the chip: ellipticity whiskers and size (sigma) on a grid.

    Parameters
    ----------
    model : fitted PSFModel
    shape : tuple (ny, nx)
        Image shape in pixels; the grid spans it.
    n_grid : int, default=20
        Grid points along the longer side.

    Returns
    -------
    fig : matplotlib.figure.Figure
        Left (top for a chip wider than tall): whiskers of e (length |e|, angle of the major
        axis); right (bottom): sigma [pixels], with the fitted stars as dots (adaptive
        moments, or, where they fail on most of the grid's stamps (undersampled PSFs),
        fixed-weight moments of sigma 1.5 pixels). The figure's
        size follows the chip's aspect, so that a tall CCD fills the page. A model with extra
        dimensions (a colour, a magnitude) is drawn at the fitted stars' median of each.

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.validation import plot_psf_maps
    >>> class Round:                            # any model with predict and X_fit_
    ...     X_fit_ = np.array([[10.0, 10.0], [90.0, 50.0]])
    ...     def predict(self, X):
    ...         yy, xx = np.mgrid[-5:6, -5:6]
    ...         g = np.exp(-(xx**2 + 0.8 * yy**2) / 6.0).ravel()
    ...         return np.tile(g / g.sum(), (len(X), 1))
    >>> len(plot_psf_maps(Round(), (60, 100), n_grid=6).axes)
    3
    """
    import matplotlib.pyplot as plt

    ny, nx = (int(v) for v in shape)
    step = max(ny, nx) / int(n_grid)
    xs = np.arange(step / 2, nx, step)
    ys = np.arange(step / 2, ny, step)
    gx, gy = np.meshgrid(xs, ys)
    X_fit = np.asarray(getattr(model, "X_fit_", np.zeros((0, 2))), dtype=float)
    grid = np.column_stack([gx.ravel(), gy.ravel()]
                           + [np.full(gx.size, np.median(c)) for c in X_fit[:, 2:].T])
    stamps = model.predict(grid)
    mom, moments = adaptive_moments(stamps), "adaptive"
    if np.mean(np.asarray(mom["flag"]) != 0) > 0.5:  # undersampled: fixed-weight moments
        mom = fixed_moments(stamps, FIXED_WEIGHT_SIGMA)
        moments = f"fixed-weight ({FIXED_WEIGHT_SIGMA:g} px)"
    e1 = np.asarray(mom["e1"], float).reshape(gx.shape)
    e2 = np.asarray(mom["e2"], float).reshape(gx.shape)
    sigma = np.asarray(mom["sigma"], float).reshape(gx.shape)
    # panel sizes follow the chip's aspect: side by side for square or tall chips (a DECam
    # CCD is 2048 x 4096), one above the other for wide ones; about 30 square inches each
    ratio = ny / nx
    width = float(np.clip(np.sqrt(30.0 / ratio), 2.5, 9.0))
    height = float(np.clip(width * ratio, 2.5, 8.0))
    width = height / ratio if ratio >= 1 else width
    tall = ratio >= 0.6
    size = (2 * width + 2.0, height + 1.2) if tall else (width + 2.0, 2 * height + 1.6)
    fig, axes = plt.subplots(1 if tall else 2, 2 if tall else 1, figsize=size,
                             layout="constrained", squeeze=False)
    axes = axes.ravel()
    emax = float(np.nanmax(np.hypot(e1, e2))) or 1e-3
    _whisker(axes[0], gx.ravel(), gy.ravel(), e1.ravel(), e2.ravel(), 0.9 * step / emax, "k",
             "model")
    axes[0].set_title(f"model ellipticity, {moments} moments\n(longest whisker: |e| = "
                      f"{emax:.3f})")
    # the size's variation over the chip, in % of its median: a colour bar of the variation
    # (0.03% over a CCD or 3%), not of the size itself around an offset
    median = float(np.nanmedian(sigma))
    change = 100.0 * (sigma / median - 1.0)
    lim = float(np.nanmax(np.abs(change))) or 1e-6
    im = axes[1].imshow(change, origin="lower", extent=(0, nx, 0, ny), cmap="RdBu_r",
                        vmin=-lim, vmax=lim, aspect="equal")
    bar = fig.colorbar(im, ax=axes[1], shrink=0.8,
                       label=rf"$\sigma$ / median $-$ 1 [%] (median {median:.3f} px)")
    bar.formatter.set_useOffset(False)
    stars = np.asarray(getattr(model, "X_fit_", np.zeros((0, 2))))
    axes[1].plot(stars[:, 0], stars[:, 1], ".", color="k", ms=2, label="fitted stars")
    axes[1].set_title(f"model size (sigma of the {moments} moments)\n"
                      f"{np.nanmin(sigma):.4f}-{np.nanmax(sigma):.4f} px; dots: fitted stars")
    for ax in axes:
        ax.set_xlim(0, nx)
        ax.set_ylim(0, ny)
        ax.set_aspect("equal")
        ax.set_xlabel("x [pixel]")
        ax.set_ylabel("y [pixel]")
    return fig


def plot_residuals_against(residuals, values, label: str = "g - i", n_bins: int = 8):
    """Size and ellipticity residuals binned against a source quantity (colour, magnitude).

    What a model that ignores a dimension the PSF depends on leaves: a trend of the size
    residual with colour (chromatic seeing) or with magnitude (the brighter-fatter effect).

    Parameters
    ----------
    residuals : astropy.table.Table
        :func:`measure_residuals`' table (``de1``, ``de2``, ``dsigma``, ``sigma_star``,
        ``flag``).
    values : array-like of shape (n,)
        The quantity of each row (e.g. the reserved stars' g-i or magnitude).
    label : str, default="g - i"
        Its name on the x axis.
    n_bins : int, default=8
        Bins of equal counts.

    Returns
    -------
    fig : matplotlib.figure.Figure
        Top: ``dsigma / sigma_star``; bottom: ``de1`` and ``de2``; bin means with their
        standard errors.

    Examples
    --------
    >>> import numpy as np
    >>> from astropy.table import Table
    >>> from sklearn_psf.validation import plot_residuals_against
    >>> rng = np.random.default_rng(0)
    >>> c = rng.uniform(0.3, 3.0, 200)
    >>> t = Table({"de1": rng.normal(0, 0.01, 200), "de2": rng.normal(0, 0.01, 200),
    ...            "dsigma": 0.003 * (c - 1.5), "sigma_star": np.full(200, 2.0),
    ...            "flag": np.zeros(200, dtype=int)})
    >>> len(plot_residuals_against(t, c).axes)
    2
    """
    import matplotlib.pyplot as plt

    values = np.asarray(values, dtype=np.float64)
    if values.shape != (len(residuals),):
        raise ValueError(f"values must hold one number per residual row ({len(residuals)}), "
                         f"got shape {values.shape}.")
    ok = (np.asarray(residuals["flag"]) == 0) & np.isfinite(values)
    x = values[ok]
    series = {"dsigma / sigma": np.asarray(residuals["dsigma"])[ok]
              / np.asarray(residuals["sigma_star"])[ok],
              "de1": np.asarray(residuals["de1"])[ok], "de2": np.asarray(residuals["de2"])[ok]}
    edges = np.quantile(x, np.linspace(0, 1, int(n_bins) + 1)) if x.size else np.zeros(2)
    which = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, len(edges) - 2)
    fig, axes = plt.subplots(2, 1, figsize=(6, 6), sharex=True, layout="constrained")
    for name, y in series.items():
        ax = axes[0] if name.startswith("dsigma") else axes[1]
        centre, mean, err = [], [], []
        for b in range(len(edges) - 1):
            sel = which == b
            if sel.sum() >= 2:
                centre.append(np.mean(x[sel]))
                mean.append(np.mean(y[sel]))
                err.append(np.std(y[sel], ddof=1) / np.sqrt(sel.sum()))
        ax.errorbar(centre, mean, yerr=err, marker="o", capsize=2, label=name)
        ax.axhline(0.0, color="0.6", lw=0.8)
    axes[0].set_ylabel(r"$\delta\sigma / \sigma$ (star - model)")
    axes[1].set_ylabel(r"$\delta e$ (star - model)")
    axes[1].legend()
    axes[1].set_xlabel(label)
    return fig
