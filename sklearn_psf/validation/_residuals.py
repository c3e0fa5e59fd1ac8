"""Residuals of a PSF model's stamps against stars: shapes, pixels, chi^2, rho1-rho5.

One measurement for every model: :func:`fit_and_validate` applies it to its reserved stars,
:func:`validate_models` to each model (this package's, PSFEx, PIFF) on the same stars.
"""

from __future__ import annotations

import warnings

import numpy as np
from astropy.table import Table

from .._validation import as_stamps
from ..io import pixel_to_sky
from ..measure import adaptive_moments, fixed_moments, fourth_moments
from ..metrics import FOURTH_RHO_NAMES, RHO_NAMES, fourth_moment_rho_statistics, \
    rho_statistics
from ..metrics._correlation import EmptyBinsWarning
from ..preprocessing import StampNormalizer, estimate_pixel_weights
from ..preprocessing._normalize import phase_ramp
from ..preprocessing._noise import check_pixel_weights

__all__ = ["measure_residuals", "rho_bins"]

#: Star-minus-model columns of the residual table (besides index, x, y, flag and stamps).
RESIDUAL_COLUMNS = ("e1_star", "e2_star", "sigma_star", "e1_model", "e2_model",
                    "sigma_model", "de1", "de2", "dsigma", "dM22", "dM31", "dM13",
                    "resid_rms", "chi2", "dof")


def rho_bins(X, stamp_size):
    """(min_sep, max_sep) of the rho statistics in pixels: the stamp size to half the
    diagonal of the positions' extent."""
    span = np.ptp(np.asarray(X, dtype=np.float64)[:, :2], axis=0)
    max_sep = 0.5 * float(np.hypot(*span))
    min_sep = max(float(stamp_size), max_sep / 100.0)
    return min_sep, max(max_sep, 2.0 * min_sep)


def _rms(a):
    return float(np.sqrt(np.mean(np.square(a)))) if len(a) else float("nan")


#: Width (pixels) of the fixed Gaussian weight of the moments of undersampled stars.
FIXED_WEIGHT_SIGMA = 1.5


def moments_kind(sigma):
    """The summary's ``moments`` text: which moments measured e and size."""
    if sigma is None:
        return "adaptive"
    return f"fixed-weight (round Gaussian weight of sigma {sigma:g} px)"


def shape_moments(sigma):
    """The moments e and size are measured with: adaptive (``sigma`` None) or with a fixed
    Gaussian weight of ``sigma`` pixels."""
    if sigma is None:
        return adaptive_moments
    return lambda stamps, weights=None: fixed_moments(stamps, sigma, weights=weights)


#: Gauss-Newton steps of the sub-pixel shift fitted with each model's flux and background.
SHIFT_STEPS = 4
#: Step (pixels) of the central differences of a model drawn again along its shift.
SHIFT_DELTA = 0.01


def _fit_linear(d, w, m):
    """Per-star weighted least squares of ``d = f m + b``: flux, background, their
    determinant (not positive: no fit)."""
    sw, smm, sm = w.sum(1), (w * m * m).sum(1), (w * m).sum(1)
    sdm, sd = (w * d * m).sum(1), (w * d).sum(1)
    det = smm * sw - sm**2
    with np.errstate(divide="ignore", invalid="ignore"):
        f = (sdm * sw - sd * sm) / det
        b = (smm * sd - sm * sdm) / det
    return np.nan_to_num(f), np.nan_to_num(b), det


def _centroid_shift(d, w, model):
    """(n, 2) shifts moving each model stamp's adaptive centroid onto its star's (0 where
    either is not measured): where :func:`_chi2` starts its fitted shift."""
    n, p = d.shape
    s = int(round(np.sqrt(p)))
    ms = adaptive_moments(d.reshape(n, s, s), weights=w.reshape(n, s, s))
    mm = adaptive_moments(model.reshape(n, s, s))
    shift = np.column_stack([np.asarray(ms["x0"], float) - np.asarray(mm["x0"], float),
                             np.asarray(ms["y0"], float) - np.asarray(mm["y0"], float)])
    return np.where(np.isfinite(shift) & (np.abs(shift) < 2.0), shift, 0.0)


def _chi2(raw, weights, model, start=None, return_model=False, render=None):
    """chi^2 of each raw star stamp against its model stamp, and its degrees of freedom
    (and, with ``return_model``, the fitted model stamps ``flux * model + background``).

    The model stamp is moved to the star by a sub-pixel shift fitted with its flux and a
    constant background (Gauss-Newton steps from ``start``, (n, 2) shifts in pixels,
    default none), so that every model is judged at its best centring whatever its
    centroid convention: chi^2 = sum w (star - flux * model - background)^2 over the
    unmasked pixels, with dof = their number - 4 (flux, background, shift). The shift is
    a Fourier shift of ``model``, or, with ``render`` (``render(shifts)`` giving the
    model's (n, p) stamps drawn with each star at that shift from the centre pixel), the
    model drawn again at each step: a sampled stamp of an undersampled star aliases under
    a Fourier shift. NaN where the fit fails (no positive flux).
    """
    n, p = raw.shape
    s = int(round(np.sqrt(p)))
    w = weights.reshape(n, p)
    d = np.where(w > 0, np.nan_to_num(raw.reshape(n, p)), 0.0)
    shift = np.zeros((n, 2)) if start is None else np.nan_to_num(np.asarray(start, float))
    if render is None:
        spectrum = np.fft.rfft2(model.reshape(n, s, s))
        ky = np.fft.fftfreq(s)[None, :, None]
        kx = np.fft.rfftfreq(s)[None, None, :]
        if s % 2 == 0:  # the Nyquist frequency carries no shift (see phase_ramp)
            ky, kx = np.where(np.abs(ky) == 0.5, 0.0, ky), np.where(np.abs(kx) == 0.5, 0.0, kx)

        def draw(shift, slopes):
            moved = spectrum * phase_ramp(s, shift[:, 0], shift[:, 1])
            m = np.fft.irfft2(moved, s=(s, s)).reshape(n, p)
            if not slopes:
                return m, None
            # d(model)/d(shift) = minus the model's gradient
            return m, [-np.fft.irfft2(moved * (2j * np.pi * k), s=(s, s)).reshape(n, p)
                       for k in (kx, ky)]
    else:
        def draw(shift, slopes):
            m = np.asarray(render(shift), dtype=np.float64).reshape(n, p)
            if not slopes:
                return m, None
            return m, [(np.asarray(render(shift + h), np.float64)
                        - np.asarray(render(shift - h), np.float64)).reshape(n, p)
                       / (2 * SHIFT_DELTA) for h in SHIFT_DELTA * np.eye(2)]
    for step_number in range(SHIFT_STEPS + 1):
        last = step_number == SHIFT_STEPS
        m, slopes = draw(shift, not last)
        f, b, det = _fit_linear(d, w, m)
        if last:
            break
        G = np.stack([m, np.ones_like(m), f[:, None] * slopes[0], f[:, None] * slopes[1]],
                     axis=1)
        resid = d - f[:, None] * m - b[:, None]
        Gw = G * w[:, None, :]
        normal = Gw @ G.transpose(0, 2, 1)
        rhs = (Gw @ resid[:, :, None])[:, :, 0]
        try:
            step = np.linalg.solve(normal, rhs[:, :, None])[:, :, 0]
        except np.linalg.LinAlgError:
            step = (np.linalg.pinv(normal) @ rhs[:, :, None])[:, :, 0]
        good = np.isfinite(step).all(axis=1) & (f > 0)
        shift = shift + np.where(good[:, None], np.clip(step[:, 2:], -0.5, 0.5), 0.0)
    chi2 = (w * (d - f[:, None] * m - b[:, None]) ** 2).sum(1)
    dof = (w > 0).sum(1) - 4
    ok = np.isfinite(chi2) & (dof > 0) & (det > 0) & (f > 0)
    out = np.where(ok, chi2, np.nan), np.where(ok, dof, 0)
    if return_model:
        return *out, f[:, None] * m + b[:, None]
    return out


def _fixed_sigma(moments, d, w, usable):
    """The fixed weight's sigma for ``moments`` (None: adaptive moments)."""
    if isinstance(moments, str):
        if moments == "adaptive":
            return None
        if moments != "auto":
            raise ValueError(f"moments must be 'auto', 'adaptive' or a weight sigma in pixels, "
                             f"got {moments!r}.")
        if not usable.any():
            return None
        s = int(round(np.sqrt(d.shape[1])))
        flags = np.asarray(adaptive_moments(d[usable].reshape(-1, s, s),
                                            weights=w[usable].reshape(-1, s, s))["flag"])
        return FIXED_WEIGHT_SIGMA if np.mean(flags != 0) > 0.5 else None
    sigma = float(moments)
    if not (np.isfinite(sigma) and sigma > 0):
        raise ValueError(f"moments must be 'auto', 'adaptive' or a positive sigma, got "
                         f"{moments!r}.")
    return sigma


def measure_residuals(X, stamps, predicted, *, weights=None, wcs=None, min_sep=None,
                      max_sep=None, nbins: int = 6, index=None, moments="auto",
                      render=None):
    """Star-minus-model residuals of PSF stamps at given stars, and their summary.

    The stars are normalised (:class:`~sklearn_psf.preprocessing.StampNormalizer`) and
    measured with :func:`~sklearn_psf.measure.adaptive_moments`, like the model's stamps; each
    raw star is compared with the model moved to it (sub-pixel shift, flux and constant
    background fitted) in the star's noise: chi^2 over its unmasked pixels, ``dof`` = pixels
    - 4. Undersampled stars are measured with fixed-weight moments (``moments``). Details:
    :ref:`residuals-details` in the user guide.

    Parameters
    ----------
    X : array-like of shape (n, 2) or (n, 2 + m)
        Star positions (x, y), 0-based pixels, then optionally the model's extra dimensions
        (a colour, a magnitude: passed to the model, not used as positions).
    stamps : array-like of shape (n, s*s) or (n, s, s)
        Raw, background-subtracted star stamps (NaN = masked pixel). Not modified.
    predicted : array-like of the stamps' shape
        The model's stamps at X (unit sum, centred on the centre pixel, as
        ``PSFModel.predict``).
    weights : array-like of the stamps' shape, optional
        Pixel inverse variance of the stamps (0 = masked). Default: estimated from the
        stamps' borders (:func:`~sklearn_psf.preprocessing.estimate_pixel_weights`, which
        leaves out the stars' own Poisson noise).
    wcs : astropy.wcs.WCS, optional
        Celestial WCS: the rho statistics are then measured on the sky (arcmin).
    min_sep, max_sep : float, optional
        Separation range of the rho statistics in pixels; default :func:`rho_bins` of X.
    nbins : int, default=6
        Logarithmic separation bins of the rho statistics.
    index : array-like of shape (n,), optional
        Row numbers stored in the table's ``index`` column; default 0 to n-1.
    moments : "auto", "adaptive" or float, default="auto"
        Adaptive moments, or fixed-weight moments of that sigma (pixels), for undersampled
        stars (``predicted`` then drawn at each star's sub-pixel position); "auto":
        adaptive unless they fail on more than half of the stars (then sigma 1.5 pixels).
    render : callable, optional
        ``render(offsets)``: the model's stamps at X with each star at ``offsets`` ((n, 2)
        pixels from the centre pixel), e.g. ``lambda o: model.predict(X, offsets=o)``: the
        chi^2's shift is then fitted by drawing the model again (no Fourier shift).

    Returns
    -------
    table : astropy.table.Table
        One row per star: ``index``, ``x``, ``y``, ``e1_star``, ``e2_star``,
        ``sigma_star``, ``e1_model``, ``e2_model``, ``sigma_model``, ``de1``, ``de2``,
        ``dsigma`` (star - model), ``dM22``, ``dM31``, ``dM13`` (star - model fourth
        moments, :func:`~sklearn_psf.measure.fourth_moments`, pixels^4), ``resid_rms`` (pixel
        rms of the unit-flux residual), ``chi2``, ``dof`` (NaN and 0 where not fitted),
        ``flag`` (0: both measured; 1: star's moments failed; 2: model's), ``stamp_star``,
        ``stamp_model`` (normalised).
    summary : dict
        ``n_measured``, mean and rms of ``de1``, ``de2``, ``dsigma``, ``dM22`` (e.g.
        ``de1_mean``, ``de1_rms``), ``e_rms`` (sqrt <de1^2 + de2^2>), ``sigma_mean``,
        ``dM4_spin2_rms``, the fourth moments over sigma^4 (``dM22_rel_mean``, ...),
        ``chi2_dof`` (summed chi^2 over summed dof: 1 for a model as good as the noise
        allows), ``chi2_dof_median``, ``rho1`` to ``rho5`` and ``rho_M4``, ``rho_eM4``,
        ``rho_M22``, ``rho_TM22`` (dicts of ``theta``, ``xi``, ``sigma_xi``, ``npairs``, or
        None), ``rho_theta_units``, ``rho1_mean_abs``, ``moments``; see
        :ref:`residuals-details`.

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.validation import measure_residuals
    >>> rng = np.random.default_rng(0)
    >>> yy, xx = np.mgrid[0:15, 0:15] - 7.0
    >>> psf = np.exp(-0.5 * (xx**2 + yy**2) / 2.0**2); psf /= psf.sum()
    >>> X = rng.uniform(0, 500, (30, 2))
    >>> stars = 1e4 * psf + rng.normal(0.0, 1.0, (30, 15, 15))
    >>> table, summary = measure_residuals(X, stars, np.tile(psf, (30, 1, 1)),
    ...                                    weights=np.ones((30, 15, 15)))
    >>> bool(abs(summary["chi2_dof"] - 1) < 0.1), bool(summary["e_rms"] < 0.01)
    (True, True)
    """
    X = np.asarray(X, dtype=np.float64)
    cube = as_stamps(stamps)
    n, s = cube.shape[0], cube.shape[1]
    pred = as_stamps(predicted, name="predicted").reshape(-1, s * s) if n else \
        np.zeros((0, s * s))
    if X.ndim != 2 or X.shape[0] != n or X.shape[1] < 2 or pred.shape != (n, s * s):
        raise ValueError(f"X {X.shape}, stamps {cube.shape} and predicted {np.shape(predicted)} "
                         "must describe the same n stars with stamps of the same size.")
    y = cube.reshape(n, s * s)
    index = np.arange(n) if index is None else np.asarray(index)
    if min_sep is None or max_sep is None:
        min_sep, max_sep = rho_bins(X, s) if n else (1.0, 2.0)
    table = Table({"index": index, "x": X[:, 0], "y": X[:, 1]})
    for c in RESIDUAL_COLUMNS:
        table[c] = np.full(n, np.nan)
    table["dof"] = np.zeros(n, dtype=np.int64)
    table["flag"] = np.zeros(n, dtype=np.int64)
    table["stamp_star"] = np.zeros((n, s * s))
    table["stamp_model"] = np.zeros((n, s * s))
    if n:
        w = estimate_pixel_weights(y) if weights is None else \
            check_pixel_weights(weights, n, s * s, stamps=y)
        w = np.where(np.isnan(y), 0.0, w)
        d = np.where(w > 0, y, 0.0)
        usable = (w > 0).any(axis=1) & (d.sum(axis=1) > 0)  # others: flagged, not normalised
        sigma = _fixed_sigma(moments, d, w, usable)
        star = _normalised_stars(d, w, pred, usable, sigma)
        _shape_columns(table, star, pred, usable, sigma)
        if render is not None:  # the model drawn again at each shift, from the star's phase
            chi2, dof = _chi2(y, w, pred, X[:, :2] - np.floor(X[:, :2] + 0.5), render=render)
        else:
            chi2, dof = _chi2(y, w, pred,
                              _centroid_shift(d, w, pred) if sigma is None else None)
        # every star with a usable stamp has its chi^2, whether or not moments are measured
        table["chi2"] = np.where(usable, chi2, np.nan)
        table["dof"] = np.where(usable & np.isfinite(chi2), dof, 0)
    ok = np.asarray(table["flag"]) == 0
    de1, de2 = np.asarray(table["de1"])[ok], np.asarray(table["de2"])[ok]
    ds = np.asarray(table["dsigma"])[ok]
    chi2, dof = np.asarray(table["chi2"]), np.asarray(table["dof"])
    fitted = np.isfinite(chi2) & (dof > 0)
    summary = {
        "n_measured": int(ok.sum()),
        "de1_mean": float(np.mean(de1)) if ok.any() else np.nan, "de1_rms": _rms(de1),
        "de2_mean": float(np.mean(de2)) if ok.any() else np.nan, "de2_rms": _rms(de2),
        "e_rms": _rms(np.hypot(de1, de2)),
        "dsigma_mean": float(np.mean(ds)) if ok.any() else np.nan, "dsigma_rms": _rms(ds),
        "dM22_mean": float(np.mean(np.asarray(table["dM22"])[ok])) if ok.any() else np.nan,
        "dM22_rms": _rms(np.asarray(table["dM22"])[ok]),
        "dM4_spin2_rms": _rms(np.hypot(np.asarray(table["dM31"])[ok],
                                       np.asarray(table["dM13"])[ok])),
        **_relative_fourth(table, ok),
        "sigma_mean": float(np.mean(np.asarray(table["sigma_star"])[ok])) if ok.any()
        else np.nan,
        "chi2_dof": float(chi2[fitted].sum() / dof[fitted].sum()) if fitted.any() else np.nan,
        "chi2_dof_median": float(np.median(chi2[fitted] / dof[fitted])) if fitted.any()
        else np.nan,
        "rho1": None, "rho1_mean_abs": np.nan,
        "moments": moments_kind(sigma if n else None),
    }
    summary.update(dict.fromkeys(RHO_NAMES[1:] + FOURTH_RHO_NAMES))
    if ok.sum() >= 10:
        summary.update(_rho_summary(table[ok], X[ok][:, :2], wcs, min_sep, max_sep, nbins))
    return table, summary


def _normalised_stars(d, w, pred, usable, sigma):
    """The stars' stamps normalised to unit flux, centred unless undersampled (``sigma``
    given); ``usable`` loses (in place) the stars that cannot be normalised."""
    star = np.zeros_like(d)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # uncentrable stars show up as flagged rows
        if not usable.any():
            pass
        elif sigma is None:
            try:
                star[usable] = StampNormalizer().fit_transform(d[usable], weights=w[usable])
            except ValueError:  # one at a time: a star that cannot be normalised is flagged
                for i in np.flatnonzero(usable):
                    try:
                        star[i] = StampNormalizer().fit_transform(d[i:i + 1],
                                                                  weights=w[i:i + 1])[0]
                    except ValueError:
                        usable[i] = False
        else:  # undersampled: normalised, not moved (the model is at the star's phase);
            # masked pixels filled from the model
            star[usable] = np.where(w[usable] > 0, d[usable], pred[usable]
                                    * d[usable].sum(axis=1, keepdims=True))
            star[usable] /= star[usable].sum(axis=1, keepdims=True)
    return star


def _shape_columns(table, star, pred, usable, sigma):
    """Fill the table's flag, stamps, moments and star-minus-model columns (in place)."""
    n = len(star)
    measure = shape_moments(sigma)
    ms, mm = measure(star), measure(pred)
    if sigma is None:
        fs, fm = fourth_moments(star, ms), fourth_moments(pred, mm)
    else:  # the fourth moments are adaptive-weight moments: not for undersampled stars
        fs = fm = {q: np.full(n, np.nan) for q in ("M22", "M31", "M13")}
    flag = ((np.asarray(ms["flag"]) != 0) | ~usable).astype(np.int64) \
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
    for q in ("M22", "M31", "M13"):  # fourth moments: spin 0, spin 2 (star - model)
        table[f"d{q}"] = np.where(ok, np.asarray(fs[q]) - np.asarray(fm[q]), np.nan)
    table["resid_rms"] = np.sqrt(np.mean((star - pred) ** 2, axis=1))


def _rho_summary(t, where, wcs, min_sep, max_sep, nbins):
    """The summary's rho statistics of the measured rows ``t`` at pixel positions
    ``where`` (on the sky, in arcmin, with ``wcs``)."""
    sky = {}
    if wcs is not None:  # xi+ ignores the uniform rotation of e from pixels to sky
        arcmin = 60.0 * float(np.sqrt(np.abs(np.linalg.det(wcs.pixel_scale_matrix))))
        where = pixel_to_sky(wcs, where)
        sky = {"sky": True, "min_sep": min_sep * arcmin, "max_sep": max_sep * arcmin}
    bins = {"min_sep": min_sep, "max_sep": max_sep, **sky}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", EmptyBinsWarning)
        rho = rho_statistics(where, t["e1_star"], t["e2_star"],
                             2 * np.asarray(t["sigma_star"]) ** 2, t["e1_model"],
                             t["e2_model"], 2 * np.asarray(t["sigma_model"]) ** 2,
                             **bins, nbins=nbins, num_threads=1)
        four = _relative_fourth_columns(t)
        if np.isfinite(four["dM22"]).all():  # adaptive moments: the fourth moments too
            dT = 1 - (np.asarray(t["sigma_model"]) / np.asarray(t["sigma_star"])) ** 2
            rho.update(fourth_moment_rho_statistics(
                where, four["dM31"], four["dM13"], four["dM22"], t["de1"], t["de2"], dT,
                **bins, nbins=nbins, num_threads=1))
    summary = {"rho_theta_units": "arcmin" if sky else "pixel"}
    for name, r in rho.items():
        summary[name] = {"theta": np.asarray(r.theta_nominal, dtype=float).tolist(),
                         "xi": np.asarray(r.xi, dtype=float).tolist(),
                         "sigma_xi": np.asarray(r.sigma_xi, dtype=float).tolist(),
                         "npairs": np.asarray(r.npairs, dtype=float).tolist()}
    xi = np.asarray(rho["rho1"].xi, dtype=float)
    if np.isfinite(xi).any():
        summary["rho1_mean_abs"] = float(np.nanmean(np.abs(xi)))
    return summary


def _relative_fourth_columns(table):
    """The fourth-moment residuals of a residual table in units of each star's sigma^4
    (dimensionless; a Gaussian's M22 is 2 sigma^4 under its adaptive weight)."""
    s4 = np.asarray(table["sigma_star"], dtype=np.float64) ** 4
    return {q: np.asarray(table[q], dtype=np.float64) / s4 for q in ("dM22", "dM31", "dM13")}


def _relative_fourth(table, ok):
    """Summary of the relative fourth-moment residuals of the measured stars ``ok``."""
    four = {k: v[ok] for k, v in _relative_fourth_columns(table).items()}
    finite = np.isfinite(four["dM22"])
    if not finite.any():
        return {"dM22_rel_mean": np.nan, "dM22_rel_rms": np.nan, "dM4_rel_rms": np.nan}
    return {"dM22_rel_mean": float(np.mean(four["dM22"][finite])),
            "dM22_rel_rms": _rms(four["dM22"][finite]),
            "dM4_rel_rms": _rms(np.hypot(four["dM31"], four["dM13"])[finite])}
