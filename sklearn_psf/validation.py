"""Validating a PSF model on reserved stars, as PIFF does, and its diagnostic figures.

:func:`fit_and_validate` keeps a random (seeded) fraction of the stars out of the fit,
predicts the PSF at their positions and compares the shapes (adaptive-moment e1, e2, size)
of the observed, normalised reserved stars with the model's, summarises the residuals (mean,
rms) and measures rho1 to rho5 (Jarvis et al. 2016, :func:`sklearn_psf.metrics.rho_statistics`)
on them.
Optionally the interpolation scheme is chosen first by K-fold cross-validation on the fitted
stars with the correlation scorers. The figures (:func:`plot_stamp_residuals`,
:func:`plot_whiskers`, :func:`plot_rho_statistics`, :func:`plot_psf_maps`) are what
``sklearn-psf fit`` writes next to the model.
"""

from __future__ import annotations

import inspect
import warnings

import numpy as np
from astropy.table import Table
from sklearn.base import clone
from sklearn.model_selection import KFold, cross_validate
from sklearn.utils import check_random_state

from ._validation import as_stamps
from .measure import adaptive_moments
from .metrics import RHO_NAMES, make_ellipticity_rms_scorer, make_rho1_scorer, rho_statistics
from .metrics._correlation import EmptyBinsWarning
from .model import PSFModel
from .io import pixel_to_sky
from .preprocessing import StampNormalizer

__all__ = ["fit_and_validate", "plot_stamp_residuals", "plot_whiskers", "plot_rho1",
           "plot_rho_statistics", "plot_psf_maps"]


def _as_model(candidate):
    if isinstance(candidate, PSFModel):
        return clone(candidate)
    if hasattr(candidate, "fit") and hasattr(candidate, "predict"):
        return PSFModel(interpolator=clone(candidate))
    raise TypeError(f"Expected a PSFModel or an interpolating regressor, got "
                    f"{type(candidate).__name__}.")


def _accepted(model, fit_params):
    """The fit parameters ``model.fit`` accepts (pixel weights only where supported)."""
    accepted = inspect.signature(model.fit).parameters
    return {k: v for k, v in fit_params.items() if k in accepted}


def _rho1_bins(X, stamp_size):
    span = np.ptp(X, axis=0)
    max_sep = 0.5 * float(np.hypot(*span))
    min_sep = max(float(stamp_size), max_sep / 100.0)
    return min_sep, max(max_sep, 2.0 * min_sep)


def _rms(a):
    return float(np.sqrt(np.mean(np.square(a)))) if len(a) else float("nan")


def fit_and_validate(X, stamps, model=None, reserve: float = 0.2, random_state=None, *,
                     candidates=None, cv: int = 5, rho1_nbins: int = 6, weights=None,
                     wcs=None):
    """Fit a PSF model on most stars and validate it on reserved ones.

    1. A random fraction ``reserve`` of the stars (seeded by ``random_state``) is set aside;
       they are not used in the fit.
    2. If ``candidates`` are given, each is scored by ``cv``-fold cross-validation
       (:func:`sklearn.model_selection.cross_validate`) on the remaining stars with
       :func:`~sklearn_psf.metrics.make_ellipticity_rms_scorer` and
       :func:`~sklearn_psf.metrics.make_rho1_scorer`; the one with the best mean ellipticity
       score is used.
    3. The model is fitted on the remaining stars.
    4. The reserved stars are normalised (:class:`~sklearn_psf.preprocessing.StampNormalizer`)
       and measured with :func:`~sklearn_psf.measure.adaptive_moments`, like the model's
       stamps at their positions; residuals are star minus model.

    Note that the reserved-star residuals include the stars' own measurement noise: at S/N
    ~100 it is comparable with the model errors of a good scheme.

    Parameters
    ----------
    X : array-like of shape (n, 2)
        Star positions (x, y), 0-based pixels.
    stamps : array-like of shape (n, s*s) or (n, s, s)
        Background-subtracted star stamps (e.g. :func:`sklearn_psf.io.extract_star_stamps`).
        Not modified.
    model : PSFModel, optional
        Unfitted model (cloned); default ``PSFModel()`` (PCA 90% + Kriging).
    reserve : float, default=0.2
        Fraction of stars reserved, in [0, 1). 0 fits every star and returns an empty table.
    random_state : int, RandomState or None
        Seed of the reserved-star draw and of the cross-validation folds.
    candidates : dict, optional
        Name -> PSFModel or interpolating regressor (e.g.
        :func:`sklearn_psf.compare.default_schemes`); chosen by cross-validation. ``model``
        is then ignored.
    cv : int, default=5
        Folds of the cross-validation.
    rho1_nbins : int, default=6
        Logarithmic separation bins of rho1 (in pixels, from the stamp size to half the
        field's diagonal).
    weights : array-like of the stamps' shape, optional
        Pixel weights (inverse variance, 0 = masked), e.g. ``StarStamps.weights``; passed to
        ``PSFModel.fit`` when it accepts ``weights`` (masked pixels should then already be 0
        in ``stamps``, as the readers leave them).
    wcs : astropy.wcs.WCS, optional
        Celestial WCS of the image (:func:`sklearn_psf.io.celestial_wcs`): the rho
        statistics are then measured on the sky, in great-circle separations (arcmin); the
        summary's ``rho_theta_units`` says which.

    Returns
    -------
    model : PSFModel
        Fitted on the non-reserved stars.
    residuals : astropy.table.Table
        One row per reserved star: ``index`` (row in X), ``x``, ``y``, ``e1_star``,
        ``e2_star``, ``sigma_star``, ``e1_model``, ``e2_model``, ``sigma_model``, ``de1``,
        ``de2``, ``dsigma`` (star - model), ``resid_rms`` (pixel rms of the unit-flux
        residual stamp), ``flag`` (0: both measured; 1: star's moments failed; 2: model's),
        ``stamp_star``, ``stamp_model`` (normalised).
    summary : dict
        ``n_stars``, ``n_fit``, ``n_reserved``, ``n_measured``, ``n_inliers``,
        ``n_outliers``, ``de1_mean``, ``de1_rms``, ``de2_mean``, ``de2_rms``, ``e_rms``
        (sqrt <de1^2 + de2^2>), ``dsigma_mean``, ``dsigma_rms``, ``sigma_mean`` (pixels),
        ``rho1`` to ``rho5`` (Jarvis et al. 2016, :func:`~sklearn_psf.metrics.rho_statistics`
        with T = 2 sigma^2; each a dict of ``theta`` [``rho_theta_units``: pixel, or arcmin
        with a ``wcs``], ``xi``, ``sigma_xi``, ``npairs``, or None with fewer than 10
        measured stars), ``rho_theta_units``, ``rho1_mean_abs`` and, with candidates,
        ``cv`` (list of per-scheme mean/std scores) and ``scheme`` (the chosen one).

    Raises
    ------
    ValueError
        For ``reserve`` outside [0, 1), stamps/positions of different lengths, or too few
        stars to fit after reserving.

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.simulate import make_psf_field
    >>> from sklearn_psf.validation import fit_and_validate
    >>> field = make_psf_field(n_stars=80, n_galaxies=0, image_shape=(900, 900),
    ...                        snr=200.0, random_state=0)
    >>> stamps, flags = field.star_stamps(normalize=False)
    >>> X = np.column_stack([field.stars["x"], field.stars["y"]])
    >>> model, res, summary = fit_and_validate(X, stamps, reserve=0.25, random_state=0)
    >>> summary["n_reserved"], len(res)
    (20, 20)
    >>> bool(summary["e_rms"] < 0.05)
    True
    """
    X = np.array(X, dtype=np.float64, copy=True)
    if X.ndim != 2 or X.shape[1] != 2:
        raise ValueError(f"X must hold (x, y) positions of shape (n, 2), got {X.shape}.")
    cube = as_stamps(stamps)
    n, s = cube.shape[0], cube.shape[1]
    if n != X.shape[0]:
        raise ValueError(f"X has {X.shape[0]} positions but stamps has {n} stars.")
    y = cube.reshape(n, s * s)
    if not (0 <= float(reserve) < 1):
        raise ValueError(f"reserve must be a fraction in [0, 1), got {reserve!r}.")
    rng = check_random_state(random_state)
    n_res = int(round(float(reserve) * n))
    if reserve > 0:
        n_res = max(n_res, 1)
    if n - n_res < 3:
        raise ValueError(f"{n} stars leave {n - n_res} to fit after reserving {n_res}: "
                         "too few (need at least 3); use a smaller reserve or more stars.")
    order = rng.permutation(n)
    reserved = np.sort(order[:n_res])
    fit_rows = np.sort(order[n_res:])
    X_fit, y_fit = X[fit_rows], y[fit_rows]
    fit_params = {}
    if weights is not None:
        w = np.asarray(weights, dtype=np.float64).reshape(n, -1)
        if w.shape != y.shape:
            raise ValueError(f"weights must have the stamps' shape {cube.shape}, got "
                             f"{np.shape(weights)}.")
        if (w < 0).any() or not np.isfinite(w).all():
            raise ValueError("weights must be finite and >= 0 (0 = masked pixel).")
        fit_params = {"weights": w[fit_rows]}
    min_sep, max_sep = _rho1_bins(X, s)

    summary = {}
    if candidates:
        seed = int(rng.randint(0, 2**31 - 1))
        folds = KFold(n_splits=int(cv), shuffle=True, random_state=seed)
        scoring = {"e_rms": make_ellipticity_rms_scorer(),
                   "rho1": make_rho1_scorer(min_sep, max_sep, nbins=rho1_nbins)}
        rows = []
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", EmptyBinsWarning)
            for name, cand in candidates.items():
                cand = _as_model(cand)
                scores = cross_validate(cand, X_fit, y_fit, cv=folds, scoring=scoring,
                                        error_score=np.nan, params=_accepted(cand, fit_params))
                rows.append({"scheme": name,
                             "e_rms": float(-np.nanmean(scores["test_e_rms"])),
                             "e_rms_std": float(np.nanstd(scores["test_e_rms"])),
                             "rho1_mean_abs": float(-np.nanmean(scores["test_rho1"]))})
        finite = [r for r in rows if np.isfinite(r["e_rms"])]
        if not finite:
            raise ValueError("Every candidate scheme failed in cross-validation.")
        best = min(finite, key=lambda r: r["e_rms"])
        summary["cv"] = rows
        summary["scheme"] = best["scheme"]
        model = _as_model(candidates[best["scheme"]])
    else:
        model = PSFModel() if model is None else clone(model)
    model.fit(X_fit, y_fit, **_accepted(model, fit_params))

    k = len(reserved)
    summary.update({"n_stars": n, "n_fit": len(fit_rows), "n_reserved": k,
                    "n_inliers": int(np.sum(model.inlier_mask_)),
                    "n_outliers": int(np.sum(~model.inlier_mask_))})
    columns = ("e1_star", "e2_star", "sigma_star", "e1_model", "e2_model", "sigma_model",
               "de1", "de2", "dsigma", "resid_rms")
    table = Table({"index": reserved, "x": X[reserved, 0], "y": X[reserved, 1]})
    for c in columns:
        table[c] = np.full(k, np.nan)
    table["flag"] = np.zeros(k, dtype=np.int64)
    table["stamp_star"] = np.zeros((k, s * s))
    table["stamp_model"] = np.zeros((k, s * s))
    if k:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # uncentrable stars show up as flagged rows
            star = StampNormalizer().fit_transform(y[reserved])
        pred = model.predict(X[reserved])
        ms, mm = adaptive_moments(star), adaptive_moments(pred)
        flag = (np.asarray(ms["flag"]) != 0).astype(np.int64) \
            | 2 * (np.asarray(mm["flag"]) != 0)
        ok = flag == 0
        table["flag"] = flag
        table["stamp_star"], table["stamp_model"] = star, pred
        for side, mom in (("star", ms), ("model", mm)):
            for q in ("e1", "e2", "sigma"):
                table[f"{q}_{side}"] = np.where(ok, np.asarray(mom[q], dtype=np.float64), np.nan)
        table["de1"] = table["e1_star"] - table["e1_model"]
        table["de2"] = table["e2_star"] - table["e2_model"]
        table["dsigma"] = table["sigma_star"] - table["sigma_model"]
        table["resid_rms"] = np.sqrt(np.mean((star - pred) ** 2, axis=1))
    ok = np.asarray(table["flag"]) == 0
    de1, de2 = np.asarray(table["de1"])[ok], np.asarray(table["de2"])[ok]
    ds = np.asarray(table["dsigma"])[ok]
    summary.update({
        "n_measured": int(ok.sum()),
        "de1_mean": float(np.mean(de1)) if ok.any() else np.nan, "de1_rms": _rms(de1),
        "de2_mean": float(np.mean(de2)) if ok.any() else np.nan, "de2_rms": _rms(de2),
        "e_rms": _rms(np.hypot(de1, de2)),
        "dsigma_mean": float(np.mean(ds)) if ok.any() else np.nan, "dsigma_rms": _rms(ds),
        "sigma_mean": float(np.mean(np.asarray(table["sigma_star"])[ok])) if ok.any()
        else np.nan,
        "rho1": None, "rho1_mean_abs": np.nan,
    })
    summary.update(dict.fromkeys(RHO_NAMES[1:]))
    if ok.sum() >= 10:
        t = table[ok]
        where, sky = X[reserved][ok], {}
        if wcs is not None:  # xi+ ignores the uniform rotation of e from pixels to sky
            arcmin = 60.0 * float(np.sqrt(np.abs(np.linalg.det(wcs.pixel_scale_matrix))))
            where = pixel_to_sky(wcs, where)
            sky = {"sky": True, "min_sep": min_sep * arcmin, "max_sep": max_sep * arcmin}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", EmptyBinsWarning)
            rho = rho_statistics(where, t["e1_star"], t["e2_star"],
                                 2 * np.asarray(t["sigma_star"]) ** 2, t["e1_model"],
                                 t["e2_model"], 2 * np.asarray(t["sigma_model"]) ** 2,
                                 **{"min_sep": min_sep, "max_sep": max_sep, **sky},
                                 nbins=rho1_nbins, num_threads=1)
        summary["rho_theta_units"] = "arcmin" if sky else "pixel"
        for name, r in rho.items():
            summary[name] = {"theta": np.asarray(r.theta_nominal, dtype=float).tolist(),
                             "xi": np.asarray(r.xi, dtype=float).tolist(),
                             "sigma_xi": np.asarray(r.sigma_xi, dtype=float).tolist(),
                             "npairs": np.asarray(r.npairs, dtype=float).tolist()}
        xi = np.asarray(rho["rho1"].xi, dtype=float)
        if np.isfinite(xi).any():
            summary["rho1_mean_abs"] = float(np.nanmean(np.abs(xi)))
    return model, table, summary


# ----------------------------------------------------------------------------- figures
def plot_stamp_residuals(residuals, n: int = 5, pixel_scale: float | None = None):
    """Reserved stars, model PSFs at their positions and residuals (one column per star).

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
    >>> len(plot_stamp_residuals(t).axes)  # 3 rows x 2 stars, 3 colour bars
    9
    """
    import matplotlib.pyplot as plt

    if len(residuals) == 0:
        raise ValueError("No reserved stars to plot.")
    idx = np.unique(np.linspace(0, len(residuals) - 1, min(n, len(residuals))).astype(int))
    star = as_stamps(np.asarray(residuals["stamp_star"])[idx])
    model = as_stamps(np.asarray(residuals["stamp_model"])[idx])
    s = star.shape[1]
    half = s / 2 * (pixel_scale or 1.0)
    extent = (-half, half, -half, half)
    m = len(idx)
    fig, axes = plt.subplots(3, m, figsize=(2.1 * m + 0.8, 6.4), squeeze=False,
                             layout="constrained")
    vmax = float(max(star.max(), model.max()))
    rmax = float(np.abs(star - model).max()) or 1.0
    for j in range(m):
        for i, (img, kw) in enumerate((
                (star[j], {"cmap": "magma", "vmin": 0, "vmax": vmax}),
                (model[j], {"cmap": "magma", "vmin": 0, "vmax": vmax}),
                (star[j] - model[j], {"cmap": "RdBu_r", "vmin": -rmax, "vmax": rmax}))):
            im = axes[i, j].imshow(img, origin="lower", extent=extent,
                                   interpolation="nearest", **kw)
            axes[i, j].tick_params(labelsize=6)
            if j == m - 1:
                fig.colorbar(im, ax=axes[i, :], shrink=0.8)
        axes[0, j].set_title(f"({residuals['x'][idx[j]]:.0f}, {residuals['y'][idx[j]]:.0f})",
                             fontsize=8)
    for i, label in enumerate(("reserved star", "model", "star - model")):
        axes[i, 0].set_ylabel(label)
    fig.suptitle("Reserved stars, model and residuals (unit flux)")
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
    fig, axes = plt.subplots(1, 3, figsize=(13, 4.4), sharex=True, sharey=True,
                             layout="constrained")
    _whisker(axes[0], x, y, e1s, e2s, scale, "k", "stars")
    _whisker(axes[1], x, y, e1m, e2m, scale, "C0", "model")
    _whisker(axes[2], x, y, e1s - e1m, e2s - e2m, scale * amplify, "C3", "residual")
    titles = ("reserved stars", "model at the stars", f"star - model (x{amplify:g})")
    for ax, title in zip(axes, titles):
        ax.set_title(title)
        ax.set_aspect("equal")
        ax.set_xlabel("x [pixel]")
        ax.margins(0.05)
    axes[0].set_ylabel("y [pixel]")
    fig.suptitle(f"PSF ellipticity (whisker of e = 0.05: {0.05 * scale:.0f} pixels)")
    return fig


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
    theta, xi = np.asarray(r["theta"], float), np.asarray(r["xi"], float)
    err = np.asarray(r["sigma_xi"], float)
    fig, ax = plt.subplots(figsize=(5.5, 4), layout="constrained")
    pos = xi > 0
    ax.errorbar(theta[pos], xi[pos], yerr=err[pos], fmt="o", color="C0", label=r"$\rho_1 > 0$")
    ax.errorbar(theta[~pos], -xi[~pos], yerr=err[~pos], fmt="o", mfc="none", color="C0",
                label=r"$-\rho_1$ ($\rho_1 < 0$)")
    ax.set_xscale("log")
    if np.any(np.abs(xi[np.isfinite(xi)]) > 0):
        ax.set_yscale("log")
    ax.set_xlabel(r"separation $\theta$ [pixel]")
    ax.set_ylabel(r"$|\rho_1(\theta)|$")
    ax.set_title("rho1 of the reserved stars (star - model)")
    ax.legend(fontsize=8)
    return fig


def plot_rho_statistics(summary):
    """rho1 to rho5 of the reserved stars against separation, as PIFF plots them.

    Left: rho1, rho3, rho4 (the residual terms); right: rho2, rho5. Negative values are
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
    """
    import matplotlib.pyplot as plt

    if not summary.get("rho1"):
        raise ValueError("The summary has no rho statistics (fewer than 10 measured reserved "
                         "stars).")
    from matplotlib.ticker import NullFormatter

    fig, axes = plt.subplots(1, 2, figsize=(10, 4), layout="constrained")
    panels = ((axes[0], ("rho1", "rho3", "rho4")), (axes[1], ("rho2", "rho5")))
    for ax, names in panels:
        for k, name in enumerate(names):
            r = summary.get(name)
            if not r:
                continue
            theta, xi = np.asarray(r["theta"], float), np.asarray(r["xi"], float)
            err = np.asarray(r["sigma_xi"], float)
            theta = theta * (1 + 0.03 * (k - 1))  # side by side
            pos = xi > 0
            color = f"C{int(name[-1]) - 1}"
            ax.errorbar(theta[pos], xi[pos], yerr=err[pos], fmt="o", color=color,
                        label=rf"$\rho_{name[-1]}$")
            ax.errorbar(theta[~pos], -xi[~pos], yerr=err[~pos], fmt="o", mfc="none",
                        color=color)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_xlabel(rf"separation $\theta$ [{summary.get('rho_theta_units', 'pixel')}]")
        ax.set_ylabel(r"$|\rho(\theta)|$ (open: negative)")
        ax.legend(fontsize=8)
    fig.suptitle("rho statistics of the reserved stars (Jarvis et al. 2016)")
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
        Left: whiskers of e (length |e|, angle of the major axis); right: sigma [pixels], with
        the fitted stars as dots.

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
    mom = adaptive_moments(model.predict(np.column_stack([gx.ravel(), gy.ravel()])))
    e1 = np.asarray(mom["e1"], float).reshape(gx.shape)
    e2 = np.asarray(mom["e2"], float).reshape(gx.shape)
    sigma = np.asarray(mom["sigma"], float).reshape(gx.shape)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.6), layout="constrained")
    emax = float(np.nanmax(np.hypot(e1, e2))) or 1e-3
    _whisker(axes[0], gx.ravel(), gy.ravel(), e1.ravel(), e2.ravel(), 0.9 * step / emax, "k",
             "model")
    axes[0].set_title(f"model ellipticity (longest whisker: |e| = {emax:.3f})")
    im = axes[1].imshow(sigma, origin="lower", extent=(0, nx, 0, ny), cmap="viridis",
                        aspect="equal")
    fig.colorbar(im, ax=axes[1], label=r"$\sigma$ [pixel]")
    stars = np.asarray(getattr(model, "X_fit_", np.zeros((0, 2))))
    axes[1].plot(stars[:, 0], stars[:, 1], ".", color="w", ms=2, label="fitted stars")
    axes[1].set_title("model size (adaptive-moment sigma)")
    for ax in axes:
        ax.set_xlim(0, nx)
        ax.set_ylim(0, ny)
        ax.set_aspect("equal")
        ax.set_xlabel("x [pixel]")
    axes[0].set_ylabel("y [pixel]")
    return fig
