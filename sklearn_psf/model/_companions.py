"""Stars with an unresolved companion: a departure from the interpolation shaped as one.

A faint companion (a few per cent of the star's flux, 1-3 pixels away) is absorbed by the
star's own fit on the basis: the fit widens the star and elongates it along the separation,
so its pixel residual shows little (the basis holds 40-80% of such a companion's second
moments; the chi^2 test of the pixels catches a few per cent of them). What gives it away is
that the star's coefficients then depart from their interpolation from the other stars in the
direction a companion moves them (a larger size, an ellipticity along the separation), and
that the rest of the companion, which the basis cannot hold, stays in the star's pixel
residual with the shape a companion leaves there. :func:`companion_log_p` is the
matched-filter (likelihood-ratio) test of both for a companion of positive flux at each
offset of a grid, in units of their noise: the coefficients' departure in units of the
star's coefficient noise and the model's error (the interpolation's, 1.5-4 times the noise
variance on the package's default field at S/N 100), the pixel residual in units of the
pixel noise and the basis's own error. On the default field (1000 stars, 10% of them with a
companion of 2-8% of their flux at 1-3 pixels, S/N 100, ten seeds) the test with the pixels
catches 42-57% of the companions, the coefficients alone 28-43%.
"""

from __future__ import annotations

import numpy as np
from scipy import stats

from ..preprocessing import fourier_shift

#: Level of the companion test: the fraction of clean stars it rejects at most. A clean star
#: lost costs the model one star of hundreds; a companion kept biases the PSF's size.
COMPANION_P_VALUE = 0.01
#: Offsets (pixels) of the companions searched: a grid of step 1 px, 1-4 px from the star.
_STEP, _MIN_SEP, _MAX_SEP = 1.0, 0.5, 4.0
_FLUX_RATIO = 0.05  # companion / star flux of the templates (the test is scale-free)


def companion_offsets():
    """(dx, dy) offsets of the companions searched, shape (J, 2)."""
    g = np.arange(-_MAX_SEP, _MAX_SEP + _STEP / 2, _STEP)
    dx, dy = (a.ravel() for a in np.meshgrid(g, g))
    r = np.hypot(dx, dy)
    keep = (r >= _MIN_SEP) & (r <= _MAX_SEP + 1e-9)
    return np.column_stack([dx[keep], dy[keep]])


def companion_signatures(basis, coefficients, pixels=False):
    """Change of a star's measured coefficients per companion, at each searched offset.

    The typical star (the basis's stamp at the median ``coefficients``) with a companion of
    ``_FLUX_RATIO`` of its flux at each offset, measured as the basis measures stars
    (``project`` for a noise-aware basis, else ``transform``), less the star alone.

    With ``pixels`` (a basis with ``project`` only), also what the basis leaves of each
    companion: the pair's pixel residual against its own fit, per unit of the pair's flux,
    in the frame where the pair's adaptive centroid is at the stamp's centre (as the stars'
    fits centre them).

    Returns
    -------
    signatures : ndarray of shape (J, k)
    residuals : ndarray of shape (J, s*s)
        Only with ``pixels``.
    """
    k = coefficients.shape[1]
    typical = np.asarray(basis.inverse_transform(np.nanmedian(coefficients, axis=0)
                                                 .reshape(1, k)), dtype=np.float64)
    s = int(round(np.sqrt(typical.size)))
    offsets = companion_offsets()
    star = typical.reshape(1, s, s)
    pairs = star + _FLUX_RATIO * fourier_shift(np.broadcast_to(star, (len(offsets), s, s)),
                                               offsets[:, 0], offsets[:, 1])
    stamps = np.concatenate([star, pairs]).reshape(len(offsets) + 1, -1)
    if not hasattr(basis, "project"):
        coef = np.asarray(basis.transform(stamps), dtype=np.float64)
        return coef[1:] - coef[:1]
    fit = basis.project(stamps, np.ones_like(stamps))
    coef = fit.coefficients
    if not pixels:
        return coef[1:] - coef[:1]
    resid = fourier_shift((stamps - fit.model).reshape(-1, s, s), -fit.offsets[:, 0],
                          -fit.offsets[:, 1]).reshape(len(stamps), -1) / fit.flux[:, None]
    return coef[1:] - coef[:1], resid[1:] - resid[:1]


def companion_log_p(basis, coefficients, departure, noise, floors, reference=None,
                    pixels=None):
    """log10 of the p-value of each star under "no companion" (larger = more normal).

    For each star and searched offset, ``z = g' S^-1 r / sqrt(g' S^-1 g)`` where ``r`` is the
    departure of the star's coefficients from their interpolation from the other stars,
    ``S`` its covariance (the star's coefficient noise plus the model-error floors, the
    interpolation's error variance) and ``g`` the companion's signature
    (:func:`companion_signatures`): standard normal without a companion, large and positive
    when a companion of positive flux moves the star as ``g``. With ``pixels``, the part of
    the companion that the star's own fit leaves in its pixels is added to the same
    matched filter: ``z = (g' S^-1 r + h' W e) / sqrt(g' S^-1 g + h' W h)`` with ``e`` the
    star's pixel residual against its own fit, ``W`` its inverse variance (noise and model
    error) and ``h`` the residual a companion at that offset leaves (the two parts are
    independent: a weighted least-squares fit's residual is uncorrelated with its
    coefficients). The statistic is the largest ``z`` over the offsets. Its law without a
    companion is found by drawing from the statistic's Gaussian law for the ``reference``
    stars (at least 20,000 draws in all, seeded: the result is reproducible) and is taken
    as that of the largest of ``J_eff`` independent standard normals, ``J_eff`` set so that
    the two agree at the test's level (:data:`COMPANION_P_VALUE`): ``p = 1 - Phi(z)^J_eff``.
    The offsets' signatures are strongly correlated, so ``J_eff`` is a few. Departures with
    heavier tails than Gaussian (an interpolator's errors often have them, e.g. where it
    extrapolates) would make this too small: the statistic of a companion of negative
    flux, which no star has, has the law of the statistic without a companion, tails
    included, so ``p`` is at least the fraction of the reference stars whose negative-flux
    statistic reaches the star's.

    Parameters
    ----------
    basis : fitted basis
    coefficients : ndarray of shape (n, k)
    departure : ndarray of shape (n, k)
        Coefficients minus their prediction from the other stars.
    noise : ndarray of shape (n, k) or (n, k, k), or None
        The coefficients' noise variance (or covariance).
    floors : ndarray of shape (n, k)
        Model-error variance of each star's prediction.
    reference : boolean ndarray of shape (n,), optional
        Stars whose law without a companion calibrates the test (default all).
    pixels : tuple (residual, inverse_variance, flux, offsets), optional
        For a basis with ``project``: each star's pixel residual against its own fit
        (n, s*s, raw units, 0 where masked), its inverse variance (noise and model error,
        0 where masked), the fitted flux (n,) and adaptive centroid offsets (n, 2).

    Returns
    -------
    log_p : ndarray of shape (n,)
        0 for a star without a finite departure (its prediction failed).
    """
    n, k = departure.shape
    cov = np.einsum("nk,kl->nkl", floors, np.eye(k))
    if noise is not None:
        cov += noise if noise.ndim == 3 else np.einsum("nk,kl->nkl", noise, np.eye(k))
    known = np.isfinite(cov).all(axis=(1, 2)) & np.isfinite(departure).all(axis=1)
    known &= np.einsum("nkk->n", cov) > 0
    log_p = np.zeros(n)  # no prediction (e.g. an interpolator that failed on a fold)
    ref = known if reference is None else known & np.asarray(reference, bool)
    if ref.sum() < 2:
        return log_p
    # information form: score (n, m), its covariance (the information) (n, m, m), and the
    # companions' signatures (J, m) in the same space
    values, vectors = np.linalg.eigh(cov[known])
    inv = 1.0 / np.maximum(values, 1e-12 * values.max(axis=1, keepdims=True))
    info = np.einsum("nkl,nl,nml->nkm", vectors, inv, vectors)  # S^-1
    score = np.einsum("nkm,nm->nk", info, departure[known])
    if pixels is None or not hasattr(basis, "project"):
        g = companion_signatures(basis, coefficients)
    else:
        g, h = companion_signatures(basis, coefficients, pixels=True)
        g, score, info = _with_pixels(g, h, score, info, *(np.asarray(a)[known]
                                                           for a in pixels))
    log_p[known] = _log_p(g, score, info, ref[known])
    return log_p


#: Share of the companions' pixel residuals (sum of squares over the offsets) that the few
#: orthonormal images the pixel part is reduced to must hold.
_PIXEL_ENERGY = 0.99


def _with_pixels(g, h, score, info, residual, inverse_variance, flux, offsets):
    """The coefficient part's signatures, score and information with the pixel part
    appended, in the span of the few orthonormal images that hold the companions' pixel
    residuals ``h`` (J, p)."""
    _, sv, vt = np.linalg.svd(h, full_matrices=False)
    energy = np.cumsum(sv**2) / max(np.sum(sv**2), 1e-300)
    r = int(np.searchsorted(energy, _PIXEL_ENERGY) + 1)
    images = vt[:r]  # (r, p), orthonormal
    n, p = residual.shape
    s = int(round(np.sqrt(p)))
    # h' W e per unit flux; the shift to the centred frame is orthogonal: <V, shift(x)> =
    # <shift^-1(V), x>, so the residual's weighted image is moved, not every template
    we = (np.asarray(inverse_variance, np.float64) * np.asarray(residual, np.float64)
          * np.asarray(flux, np.float64)[:, None])
    centred = fourier_shift(we.reshape(n, s, s), -offsets[:, 0], -offsets[:, 1])
    pix_score = centred.reshape(n, p) @ images.T
    products = (images[:, None, :] * images[None, :, :]).reshape(r * r, p)
    pix_info = ((inverse_variance * (flux**2)[:, None]) @ products.T).reshape(n, r, r)
    k = score.shape[1]
    full = np.zeros((n, k + r, k + r))
    full[:, :k, :k], full[:, k:, k:] = info, pix_info
    return (np.hstack([g, h @ images.T]), np.hstack([score, pix_score]), full)


def _log_p(g, score, info, ref):
    """companion_log_p from the score, its information and the signatures, on stars with
    finite ones."""
    norm = np.sqrt(np.maximum(np.einsum("nmj,jm->nj", info @ g.T, g), 1e-300))
    z_all = score @ g.T / norm
    z = z_all.max(axis=1)
    ref = np.flatnonzero(ref)
    # draws of the score from its law without a companion: L eta with L L' = info
    try:
        root = np.linalg.cholesky(info[ref])
    except np.linalg.LinAlgError:  # a singular information (e.g. a fully masked stamp)
        values, vectors = np.linalg.eigh(info[ref])
        root = vectors * np.sqrt(np.maximum(values, 0.0))[:, None, :]
    draws = max(10, -(-20000 // max(len(ref), 1)))
    eta = np.random.default_rng(0).standard_normal((draws, len(ref), g.shape[1]))
    null = ((root @ eta[..., None])[..., 0] @ g.T / norm[ref]).max(axis=2)
    level = float(np.quantile(null, 1.0 - COMPANION_P_VALUE))
    j_eff = np.log1p(-COMPANION_P_VALUE) / stats.norm.logcdf(level)
    # P(max of j_eff standard normals >= z) = 1 - Phi(z)^j_eff (~ j_eff Phi(-z) far out)
    with np.errstate(divide="ignore"):
        log_p = np.log(-np.expm1(j_eff * stats.norm.logcdf(z)))
    log_p = np.where(np.isfinite(log_p), log_p, np.log(j_eff) + stats.norm.logsf(z))
    # the empirical law of the negative-flux statistic, tails included
    anti = np.sort((-z_all[ref]).max(axis=1))
    beyond = len(anti) - np.searchsorted(anti, z, side="left")
    empirical = np.log((1.0 + beyond) / (1.0 + len(anti)))
    return np.maximum(log_p, empirical) / np.log(10.0)

