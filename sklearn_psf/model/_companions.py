"""Stars with an unresolved companion: a departure from the interpolation shaped as one.

A faint companion (a few per cent of the star's flux, 1-3 pixels away) is absorbed by the
star's own fit on the basis: the fit widens the star and elongates it along the separation,
so its pixel residual shows little (the basis holds 40-80% of such a companion's second
moments; the chi^2 test of the pixels catches a few per cent of them). What gives it away is that the star's coefficients then depart from
their interpolation from the other stars in the direction a companion moves them: a larger
size and an ellipticity along the separation. :func:`companion_log_p` is the matched-filter
(likelihood-ratio) test of that departure for a companion of positive flux at each offset of
a grid, in units of the departure's noise (the star's coefficient noise) and the model's
error (the interpolation's), so that it catches the companions that move the PSF more than
the data can tell apart from noise, and only those.
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


def companion_signatures(basis, coefficients):
    """Change of a star's measured coefficients per companion, at each searched offset.

    The typical star (the basis's stamp at the median ``coefficients``) with a companion of
    ``_FLUX_RATIO`` of its flux at each offset, measured as the basis measures stars
    (``project`` for a noise-aware basis, else ``transform``), less the star alone.

    Returns
    -------
    signatures : ndarray of shape (J, k)
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
    if hasattr(basis, "project"):
        coef = basis.project(stamps, np.ones_like(stamps)).coefficients
    else:
        coef = np.asarray(basis.transform(stamps), dtype=np.float64)
    return coef[1:] - coef[:1]


def companion_log_p(basis, coefficients, departure, noise, floors, reference=None):
    """log10 of the p-value of each star under "no companion" (larger = more normal).

    For each star and searched offset, ``z = g' S^-1 r / sqrt(g' S^-1 g)`` where ``r`` is the
    departure of the star's coefficients from their interpolation from the other stars,
    ``S`` its covariance (the star's coefficient noise plus the model-error floors, the
    interpolation's error variance) and ``g`` the companion's signature
    (:func:`companion_signatures`): standard normal without a companion, large and positive
    when a companion of positive flux moves the star as ``g``. The statistic is the largest
    ``z`` over the offsets. Its law without a companion is found by drawing departures from
    ``N(0, S)`` for the ``reference`` stars (at least 20,000 in all, seeded: the result is
    reproducible) and is taken as that of the largest of ``J_eff`` independent standard
    normals, ``J_eff`` set so that the two agree at the test's level
    (:data:`COMPANION_P_VALUE`): ``p = 1 - Phi(z)^J_eff``. The offsets' signatures are
    strongly correlated, so ``J_eff`` is a few. Departures with heavier tails than Gaussian
    (an interpolator's errors often have them, e.g. where it extrapolates) would make this
    too small: the statistic of a companion of negative flux, which no star has, has the
    law of the statistic without a companion, tails included, so ``p`` is at least the
    fraction of the reference stars whose negative-flux statistic reaches the star's.

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
    log_p[known] = _log_p(basis, coefficients, departure[known], cov[known], ref[known])
    return log_p


def _log_p(basis, coefficients, departure, cov, ref):
    """companion_log_p on stars with a finite departure and covariance."""
    n, k = departure.shape
    g = companion_signatures(basis, coefficients)
    # whitened: z = u . eta with u = S^-1/2 g / |S^-1/2 g| and eta = S^-1/2 r
    values, vectors = np.linalg.eigh(cov)
    scale = 1.0 / np.sqrt(np.maximum(values, 1e-12 * values.max(axis=1, keepdims=True)))
    inv_root = np.einsum("nkl,nl,nml->nkm", vectors, scale, vectors)  # S^-1/2, symmetric
    u = np.einsum("nkm,jm->njk", inv_root, g)
    u /= np.maximum(np.linalg.norm(u, axis=2, keepdims=True), 1e-300)
    eta = np.einsum("nkm,nm->nk", inv_root, departure)
    z_all = np.einsum("njk,nk->nj", u, eta)
    z = z_all.max(axis=1)
    ref = np.flatnonzero(ref)
    draws = max(10, -(-20000 // max(len(ref), 1)))
    null = np.einsum("njk,dnk->dnj", u[ref], np.random.default_rng(0).standard_normal(
        (draws, len(ref), k))).max(axis=2)
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
