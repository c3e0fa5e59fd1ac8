"""Bounded variogram models: correlation functions and the public variogram functions."""

from __future__ import annotations

import numpy as np


def _exp_corr(r):
    """exp(-r), computed in place on r (a fresh array owned by the caller)."""
    np.negative(r, out=r)
    return np.exp(r, out=r)


def _sph_corr(r):
    """1 - 1.5 r + 0.5 r^3 for r < 1, 0 beyond; in place on r."""
    np.minimum(r, 1.0, out=r)
    return 1.0 - r * (1.5 - 0.5 * r * r)


def _gau_corr(r):
    """exp(-r^2), in place on r."""
    np.square(r, out=r)
    np.negative(r, out=r)
    return np.exp(r, out=r)


#: correlation function rho(h / a) of each model: gamma = sill (1 - (1 - nugget) rho)
_CORRELATIONS = {"exponential": _exp_corr, "spherical": _sph_corr, "gaussian": _gau_corr}


def _corr_dlog_range(model, r, rho):
    """d rho / d log(a) at scaled distances ``r = h / a`` with ``rho = rho(r)``."""
    if model == "exponential":
        return rho * r
    if model == "gaussian":
        return 2.0 * rho * r * r
    inside = np.minimum(r, 1.0)
    return 1.5 * inside * (1.0 - inside * inside)


def _variogram(model, h, a, nugget, sill):
    h = np.asarray(h, dtype=np.float64)
    rho = _CORRELATIONS[model](h / a)
    gamma = sill * (1.0 - (1.0 - nugget) * rho)
    return np.where(h > 0, gamma, 0.0)


_DOC = """{title}

    {note}Parameters
    ----------
    h : array-like
        Distances (>= 0).
    range : float
        Range ``a`` in the units of ``h``{range_note}.
    nugget : float, default=0.0
        Nugget as a fraction of the sill, in [0, 1].
    sill : float, default=1.0
        Sill (value of the variogram at infinite distance).

    Returns
    -------
    gamma : ndarray
        Variogram values, the shape of ``h``.

    Examples
    --------
    >>> from sklearn_psf.interpolate import {name}
    {example}
    """


def _document(title, example, note="", range_note=""):
    def decorate(func):
        func.__doc__ = _DOC.format(
            title=title, name=func.__name__, example=example, note=note, range_note=range_note
        )
        return func

    return decorate


@_document(
    "Exponential variogram ``sill ((1 - nugget)(1 - exp(-h / range)) + nugget)``, 0 at h = 0.",
    ">>> exponential_variogram([0.0, 1.0], range=1.0, nugget=0.5, sill=2.0).round(4)\n"
    "    array([0.    , 1.6321])",
    note="The correlation ``exp(-h / range)`` is scikit-learn's ``Matern(length_scale=range, "
    "nu=0.5)``.\n\n    ",
)
def exponential_variogram(h, range, nugget=0.0, sill=1.0):
    return _variogram("exponential", h, range, nugget, sill)


@_document(
    "Spherical variogram ``sill ((1 - nugget)(1.5 h/a - 0.5 (h/a)^3) + nugget)`` for\n"
    "    0 < h < a, ``sill`` beyond, 0 at h = 0 (``a = range``).",
    ">>> spherical_variogram([0.0, 0.5, 2.0], range=1.0).round(4)\n"
    "    array([0.    , 0.6875, 1.    ])",
    range_note=": the variogram reaches the sill at ``h = a``",
)
def spherical_variogram(h, range, nugget=0.0, sill=1.0):
    return _variogram("spherical", h, range, nugget, sill)


@_document(
    "Gaussian variogram ``sill ((1 - nugget)(1 - exp(-(h / range)^2)) + nugget)``, 0 at h = 0.",
    ">>> gaussian_variogram([0.0, 1.0], range=1.0).round(4)\n    array([0.    , 0.6321])",
    note="Very smooth fields; the Kriging system becomes ill-conditioned when stars are much\n"
    "    closer than ``range`` (add a small nugget then).\n\n    ",
)
def gaussian_variogram(h, range, nugget=0.0, sill=1.0):
    return _variogram("gaussian", h, range, nugget, sill)


#: Variogram models by name: ``f(h, range, nugget=0.0, sill=1.0) -> gamma``.
variogram_models = {
    "exponential": exponential_variogram,
    "spherical": spherical_variogram,
    "gaussian": gaussian_variogram,
}
