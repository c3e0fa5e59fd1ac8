"""Several PSF models (this package's, PSFEx, PIFF) validated on the same reserved stars."""

from __future__ import annotations

import inspect
import os

import numpy as np
from astropy.table import Table

from .._files import InputError
from .._validation import as_stamps
from ..metrics import FOURTH_RHO_NAMES, RHO_NAMES
from ._external import PiffModel, PSFExModel, load_psf_model, model_kind
from ..measure import adaptive_moments
from ..preprocessing import stamp_fwhm
from ..preprocessing._normalize import phase_ramp
from ..preprocessing._superres import UNDERSAMPLED_FWHM
from ._residuals import FIXED_WEIGHT_SIGMA, measure_residuals, moments_kind, rho_bins

__all__ = ["validate_models", "COMPARISON_COLUMNS", "UNUSABLE_STAR_REASONS"]

#: Columns of the comparison table, after ``model`` and ``kind`` (see :func:`validate_models`).
COMPARISON_COLUMNS = ("rank", "n_measured", "chi2_dof", "chi2_dof_median", "e_rms", "de1_mean",
                      "de1_rms", "de2_mean", "de2_rms", "dsigma_mean", "dsigma_rms",
                      "resid_rms", "dM22_rel_mean", "dM22_rel_rms", "dM4_rel_rms") + tuple(
                          f"{r}_mean_abs" for r in RHO_NAMES + FOURTH_RHO_NAMES)


def _fit_size(stamps, s):
    """Model stamps cropped or zero-padded about their centre pixel to s x s, unit sum."""
    cube = as_stamps(stamps)
    m = cube.shape[1]
    if m == s:
        return cube.reshape(len(cube), -1)
    if (m - s) % 2:
        raise ValueError(f"The model's stamps are {m} pixels wide and the stars' {s}: both "
                         "must be odd (or both even) to share a centre pixel.")
    if m > s:
        k = (m - s) // 2
        cube = cube[:, k:k + s, k:k + s]
    else:
        k = (s - m) // 2
        cube = np.pad(cube, ((0, 0), (k, k), (k, k)))
    cube = cube / cube.sum(axis=(1, 2), keepdims=True)
    return cube.reshape(len(cube), -1)


#: Why :func:`validate_models` leaves a star out (counted in ``table.meta["left_out"]``).
UNUSABLE_STAR_REASONS = ("no_pixels", "non_finite", "non_positive_flux")


def _usable_stars(cube, weights):
    """Which stars can be compared, and the count left out for each of
    :data:`UNUSABLE_STAR_REASONS`: every pixel masked (NaN or zero weight), an infinite pixel,
    a total flux over the unmasked pixels that is not positive (a crowded or empty stamp)."""
    flat = cube.reshape(len(cube), -1)
    masked = np.isnan(flat)
    if weights is not None:
        w = np.asarray(weights, dtype=np.float64).reshape(flat.shape)
        masked |= ~(w > 0)
    tests = {"no_pixels": masked.all(axis=1),
             "non_finite": np.isinf(flat).any(axis=1),
             "non_positive_flux": ~(np.where(masked, 0.0, np.nan_to_num(flat)).sum(axis=1) > 0)}
    keep = np.ones(len(flat), dtype=bool)
    counts = {}
    for name in UNUSABLE_STAR_REASONS:
        counts[name] = int(np.count_nonzero(keep & tests[name]))
        keep &= ~tests[name]
    return keep, counts


def _common_moments(cube, weights, predictions):
    """The moments every model is measured with: adaptive ones, unless they fail on more
    than half of the stars or of one model's stamps (then a fixed weight of sigma
    :data:`FIXED_WEIGHT_SIGMA`, for all: undersampled stars, or a model whose wings make
    adaptive moments diverge)."""
    n = len(cube)
    s = cube.shape[1]
    w = None if weights is None else np.asarray(weights, np.float64).reshape(n, s, s)
    d = np.where(np.isnan(cube), 0.0, cube)
    if w is not None:
        w = np.where(np.isnan(cube), 0.0, w)
    stamps = [(d, w)] + [(np.asarray(p).reshape(n, s, s), None) for p in predictions]
    for stamp, weight in stamps:
        flags = np.asarray(adaptive_moments(stamp, weights=weight)["flag"])
        if np.mean(flags != 0) > 0.5:
            return FIXED_WEIGHT_SIGMA
    return "adaptive"


def _undersampled_stars(cube, weights):
    """Whether the stars are undersampled: their median FWHM under
    :data:`~sklearn_psf.preprocessing.UNDERSAMPLED_FWHM` pixels (as :class:`PSFModel`
    decides for its basis)."""
    n = len(cube)
    fwhm = stamp_fwhm(np.where(np.isnan(cube), 0.0, cube).reshape(n, -1),
                      None if weights is None else np.asarray(weights).reshape(n, -1))
    return bool(np.isfinite(fwhm).any() and np.nanmedian(fwhm) < UNDERSAMPLED_FWHM)


def _drawn_at(model, X, s, phase):
    """``(stamps, render)``: the model's s x s stamps at X with each star at ``phase`` from
    the centre pixel, and ``render(offsets)`` drawing them at other offsets, for a model
    whose ``predict`` takes ``offsets`` and can draw them; ``(None, None)`` otherwise."""
    if "offsets" not in inspect.signature(model.predict).parameters:
        return None, None

    def render(offsets):
        return _fit_size(model.predict(X, offsets=offsets), s)

    try:
        return render(phase), render
    except ValueError:  # e.g. a basis without render
        return None, None


def _named_models(models, stamp_size, origin, chipnum):
    """{name: (model, kind)} from a dict, or a list of paths/models."""
    if isinstance(models, dict):
        items = list(models.items())
    else:
        items = []
        for i, m in enumerate(models):
            name = os.path.basename(os.fspath(m)) if isinstance(m, (str, os.PathLike)) \
                else type(m).__name__
            items.append((name, m))
    if not items:
        raise ValueError("Give at least one model to validate.")
    names = [str(n) for n, _ in items]
    out = {}
    for (name, m), label in zip(items, names):
        if names.count(label) > 1:  # same file name in two folders, or two instances
            label = f"{label} [{len(out) + 1}]"
        if isinstance(m, (str, os.PathLike)):
            kind = model_kind(m)
            out[label] = (load_psf_model(m, stamp_size, origin=origin, chipnum=chipnum), kind)
        elif hasattr(m, "predict"):
            kind = "psfex" if isinstance(m, PSFExModel) else \
                "piff" if isinstance(m, PiffModel) else "sklearn_psf"
            out[label] = (m, kind)
        else:
            raise TypeError(f"Model {name!r}: expected a file name or an object with predict, "
                            f"got {type(m).__name__}.")
    return out


def validate_models(X, stamps, models, *, weights=None, wcs=None, nbins: int = 6,
                    origin: int = 1, chipnum=None):
    """Validate several PSF models on the same reserved stars, side by side.

    Each model predicts the PSF at the stars (stamps cropped or zero-padded to the stars'
    size) and :func:`measure_residuals` measures the same residuals for all, in the same
    separation bins. Give stars none of the models was fitted on (reserved stars). Stars
    that cannot be compared (every pixel masked, an infinite pixel, no positive flux) are
    left out, counted by reason (:data:`UNUSABLE_STAR_REASONS`) in
    ``table.meta["left_out"]``. ``rank`` orders the models by ``chi2_dof`` (near 1: as good
    as the noise allows); how to read the table: :ref:`other-models`.

    Parameters
    ----------
    X : array-like of shape (n, 2) or (n, 2 + m)
        Star positions (x, y), 0-based pixels, then the extra dimensions (catalogue keys, see
        :func:`~sklearn_psf.exposure.fit_exposure`) of the models that have them: each model is
        given as many columns as it was fitted on (PSFEx and PIFF models: x, y).
    stamps : array-like of shape (n, s*s) or (n, s, s)
        Raw, background-subtracted star stamps (e.g. :func:`sklearn_psf.exposure.extract_vignettes`
        or :func:`~sklearn_psf.exposure.extract_star_stamps`), NaN = masked. Not modified.
    models : dict or list
        ``{name: model}`` or a list of models (named by file name); each a fitted
        :class:`~sklearn_psf.model.PSFModel` (or any object with ``predict`` giving
        unit-sum centred stamps) or a model file: this package's, a PSFEx ``.psf`` (needs
        GalSim) or a PIFF file (needs PIFF), see :func:`load_psf_model`.
    weights : array-like of the stamps' shape, optional
        Pixel inverse variance (0 = masked); default estimated from the stamps' borders.
    wcs : astropy.wcs.WCS, optional
        Celestial WCS: rho statistics on the sky (arcmin).
    nbins : int, default=6
        Logarithmic separation bins of the rho statistics (from the stamp size to half the
        stars' diagonal, :func:`rho_bins`).
    origin : {0, 1}, default=1
        Pixel convention of PSFEx and PIFF files (1: FITS, as SExtractor's ``X_IMAGE``).
    chipnum : int, optional
        CCD of multi-chip PIFF files.

    Returns
    -------
    table : astropy.table.Table
        One row per model: ``model`` (name), ``kind`` ("sklearn_psf", "psfex", "piff"),
        then :data:`COMPARISON_COLUMNS`: ``rank``, ``n_measured`` and the summary entries
        of :func:`measure_residuals` (``chi2_dof``, ``e_rms``, ... in pixels for sizes),
        ``resid_rms`` (mean over stars of the unit-flux residual stamp's pixel rms),
        ``dM22_rel_mean``, ``dM22_rel_rms``, ``dM4_rel_rms`` (the fourth moments' residuals
        over each star's sigma^4) and ``rho1_mean_abs`` ... ``rho5_mean_abs``,
        ``rho_M4_mean_abs`` ... ``rho_TM22_mean_abs`` (mean |rho| over the separation bins;
        :func:`~sklearn_psf.metrics.fourth_moment_rho_statistics`).
        ``table.meta`` holds ``left_out`` (see above) and ``moments`` (which moments
        measured e and size: adaptive ones, or, when they fail on more than half of the
        stars or of one model's stamps, a fixed Gaussian weight of sigma 1.5 pixels for
        every model).
    results : dict
        ``{name: (residuals, summary)}`` of :func:`measure_residuals` for each model (for
        the figures, :func:`plot_model_comparison`).

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.validation import validate_models
    >>> rng = np.random.default_rng(0)
    >>> yy, xx = np.mgrid[0:15, 0:15] - 7.0
    >>> def gaussian(sigma):
    ...     g = np.exp(-0.5 * (xx**2 + yy**2) / sigma**2).ravel()
    ...     return g / g.sum()
    >>> class Constant:                              # any model with predict
    ...     def __init__(self, sigma):
    ...         self.sigma = sigma
    ...     def predict(self, X):
    ...         return np.tile(gaussian(self.sigma), (len(X), 1))
    >>> X = rng.uniform(0, 500, (40, 2))
    >>> stars = 1e4 * gaussian(2.0) + rng.normal(0.0, 1.0, (40, 225))
    >>> table, results = validate_models(X, stars, {"right": Constant(2.0),
    ...                                             "too wide": Constant(2.2)},
    ...                                  weights=np.ones((40, 225)))
    >>> [str(name) for name in table["model"][np.argsort(table["rank"])]]
    ['right', 'too wide']
    """
    X = np.asarray(X, dtype=np.float64)
    cube = as_stamps(stamps)
    n, s = cube.shape[0], cube.shape[1]
    if X.ndim != 2 or X.shape[0] != n or X.shape[1] < 2:
        raise ValueError(f"X must hold the (x, y) of the {n} stars (then the extra dimensions "
                         f"of models that have them), shape ({n}, 2 + m); got {X.shape}.")
    if n < 1:
        raise InputError("No stars to validate on.")
    if weights is not None and np.shape(weights) not in (cube.shape, (n, s * s)):
        raise InputError(f"weights must have the stamps' shape {cube.shape}, got "
                         f"{np.shape(weights)}.")
    keep, left_out = _usable_stars(cube, weights)
    if not keep.any():
        raise InputError(f"None of the {n} stars can be compared (left out: "
                         + ", ".join(f"{k} {v}" for k, v in left_out.items() if v) + ").")
    index = np.flatnonzero(keep)  # the residual tables' rows are the input's
    if not keep.all():
        X, cube = X[keep], cube[keep]
        weights = None if weights is None else \
            np.asarray(weights, dtype=np.float64).reshape(n, -1)[keep]
    named = _named_models(models, s, origin, chipnum)
    min_sep, max_sep = rho_bins(X, s)
    predicted, renders = {}, {}
    # undersampled stars: each model that can is drawn at the stars' sub-pixel positions
    # and moved by drawing it again (a Fourier shift of its sampled stamp would alias)
    phase = X[:, :2] - np.floor(X[:, :2] + 0.5) if _undersampled_stars(cube, weights) \
        else None
    for name, (model, kind) in named.items():
        width = np.shape(getattr(model, "X_fit_", np.zeros((0, 2))))[1]
        if width > X.shape[1]:
            raise InputError(f"model {name!r} has {width - 2} dimensions after x, y (catalogue "
                             f"keys) but X gives {X.shape[1] - 2}")
        drawn, render = (None, None) if phase is None else \
            _drawn_at(model, X[:, :width], s, phase)
        if render is not None:
            predicted[name], renders[name] = drawn, render
        else:
            predicted[name] = _fit_size(model.predict(X[:, :width]), s)
            if phase is not None:  # a model drawn centred only: moved to the star's phase
                moved = np.fft.rfft2(predicted[name].reshape(-1, s, s)) \
                    * phase_ramp(s, phase[:, 0], phase[:, 1])
                predicted[name] = np.fft.irfft2(moved, s=(s, s)).reshape(len(X), -1)
    # undersampled stars are measured as they are (not moved) with a fixed weight
    moments = FIXED_WEIGHT_SIGMA if phase is not None else \
        _common_moments(cube, weights, predicted.values())
    results, rows = {}, []
    for name, (model, kind) in named.items():
        table, summary = measure_residuals(X, cube, predicted[name], weights=weights, wcs=wcs,
                                           min_sep=min_sep, max_sep=max_sep, nbins=nbins,
                                           index=index, moments=moments,
                                           render=renders.get(name))
        results[name] = (table, summary)
        ok = np.asarray(table["flag"]) == 0
        row = {"model": name, "kind": kind,
               "resid_rms": float(np.mean(np.asarray(table["resid_rms"])[ok])) if ok.any()
               else np.nan}
        for key in COMPARISON_COLUMNS:
            if key.endswith("_mean_abs") and key != "rho1_mean_abs":
                r = summary.get(key[:-len("_mean_abs")])
                xi = np.asarray(r["xi"], float) if r else np.array([np.nan])
                row[key] = float(np.nanmean(np.abs(xi))) if np.isfinite(xi).any() else np.nan
            elif key in summary:
                row[key] = summary[key]
        rows.append(row)
    chi = np.array([r["chi2_dof"] for r in rows], dtype=float)
    order = np.argsort(np.where(np.isfinite(chi), chi, np.inf), kind="stable")
    for rank, i in enumerate(order, start=1):
        rows[i]["rank"] = rank
    table = Table(rows=[[r[c] for c in ("model", "kind") + COMPARISON_COLUMNS] for r in rows],
                  names=("model", "kind") + COMPARISON_COLUMNS)
    for name in COMPARISON_COLUMNS[2:]:  # printed compactly; the values keep full precision
        table[name].info.format = ".2e" if name.startswith(("rho", "dM")) \
            or name == "resid_rms" else ".4f"
    table.meta["left_out"] = left_out
    table.meta["moments"] = moments_kind(None if moments == "adaptive" else moments)
    table.meta["rho_theta_units"] = next(
        (sm.get("rho_theta_units") for _, sm in results.values() if sm.get("rho_theta_units")),
        "pixel")
    return table, results
