"""Weak-lensing systematics implied by PSF residuals (Berge et al. 2012, sect. 5.1).

Conventions
-----------
- Angles theta are in arcmin in every public function of this module.
- Multipoles: sigma_sys^2 integrates over ``ELL_RANGE = (10, 20000)`` by default, a standard
  range for cosmic-shear forecasts (Amara & Refregier 2008's exact range was not checked), on
  ``N_ELL = 512`` logarithmically spaced multipoles (Simpson's rule in ln l).
- Hankel transform xi -> C_l: the measured xi(theta) is interpolated (PCHIP in ln theta) onto a
  fine logarithmic grid (200 points per decade) and the integral
  C_l = 2 pi Int theta xi(theta) J0(l theta) dtheta of the piecewise-linear interpolant is
  done exactly with the antiderivatives of x J0(x) and x^2 J0(x) (Filon-type quadrature: no
  oscillation needs to be resolved).
- Outside the measured range (``extrapolation="smooth"``, the default) xi is held constant at
  xi(theta_min) down to theta = 0 and brought smoothly to zero between theta_max and
  2 theta_max with a cosine taper in ln theta (a hard cut would ring and add spurious high-l
  power to the integral of |C_l|). ``extrapolation="zero"`` sets xi = 0 outside.
- Cosmology of the requirement lines: flat LCDM with Omega_c = 0.25, Omega_b = 0.05, h = 0.7,
  n_s = 0.96, sigma_8 = 0.8, Eisenstein & Hu transfer function and halofit (pyccl), sources
  with n(z) ~ z^2 exp(-(z / z0)^1.5), z0 = z_median / 1.412.
"""

from __future__ import annotations

import atexit
import functools
from typing import NamedTuple

import numpy as np
from scipy import special
from scipy.integrate import simpson
from scipy.interpolate import PchipInterpolator

__all__ = [
    "DEFAULT_COSMOLOGY",
    "ELL_RANGE",
    "SURVEYS",
    "RequirementCurves",
    "hankel_xi_to_cl",
    "requirement_curves",
    "shear_bias_bound",
    "shear_cl",
    "sigma_sys2",
    "sigma_sys2_from_cl",
    "survey_requirement",
    "survey_table",
]

ARCMIN = np.pi / (180.0 * 60.0)
#: Default multipole range ``(l_min, l_max)`` of the sigma_sys^2 integral.
ELL_RANGE = (10.0, 20000.0)
N_ELL = 512

#: Parameters of ``pyccl.Cosmology`` for the LCDM shear power spectrum of the requirement
#: lines (:func:`shear_cl`): flat, Eisenstein & Hu transfer function, halofit.
DEFAULT_COSMOLOGY = {
    "Omega_c": 0.25,
    "Omega_b": 0.05,
    "h": 0.7,
    "n_s": 0.96,
    "sigma8": 0.8,
    "transfer_function": "eisenstein_hu",
    "matter_power_spectrum": "halofit",
}

#: Surveys of the paper's Table 2: area (deg^2), galaxy density (arcmin^-2), median redshift.
SURVEYS = {
    "CFHTLS": {"area_deg2": 170.0, "n_gal_arcmin2": 12.0, "z_median": 0.7},
    "COSMOS": {"area_deg2": 2.0, "n_gal_arcmin2": 50.0, "z_median": 0.9},
    "Stage IV": {"area_deg2": 15000.0, "n_gal_arcmin2": 30.0, "z_median": 0.9},
}


# --------------------------------------------------------------------------------------------
# Shear bias and survey requirements
# --------------------------------------------------------------------------------------------
def shear_bias_bound(d1, p_gamma: float = 1.84, size_ratio: float = 1 / 1.5):
    """Upper bound on the shear correlation bias from the PSF residual correlation D1.

    |delta xi+(theta)| <= |D1(theta) / P_gamma^2 * <(R_PSF / R_gal)^4>| with
    <(R_PSF / R_gal)^4> = ``size_ratio**4`` (Rowe 2010; Berge et al. 2012, eq. 10).

    Parameters
    ----------
    d1 : float or array-like
        Residual correlation D1 (rho1), e.g. ``rho1(...).xi``.
    p_gamma : float, default=1.84
        Shear susceptibility P_gamma.
    size_ratio : float, default=1/1.5
        Typical R_PSF / R_gal.

    Returns
    -------
    bound : float or ndarray
        Non-negative bound on |delta xi+|, same shape as ``d1``.

    Examples
    --------
    >>> from sklearn_psf.metrics import shear_bias_bound
    >>> round(float(shear_bias_bound(1e-6)), 12)
    5.8e-08
    """
    if p_gamma <= 0 or size_ratio <= 0:
        raise ValueError("p_gamma and size_ratio must be positive.")
    d1 = np.asarray(d1, dtype=np.float64)
    out = np.abs(d1) * size_ratio**4 / p_gamma**2
    return out if out.ndim else float(out)


def survey_requirement(area_deg2, n_gal_arcmin2, z_median):
    """Largest tolerable sigma_sys^2 for a survey (Amara & Refregier 2008, eq. 21).

    sigma_sys^2 < 1e-7 (A / 2e4 deg^2)^-0.5 (n_g / 35 arcmin^-2)^-0.5 ((1 + z_m) / 1.9)^-0.7.

    Parameters
    ----------
    area_deg2 : float or array-like
        Survey area A in deg^2.
    n_gal_arcmin2 : float or array-like
        Galaxy density n_g in arcmin^-2.
    z_median : float or array-like
        Median redshift z_m.

    Returns
    -------
    sigma_sys2 : float or ndarray

    Examples
    --------
    >>> from sklearn_psf.metrics import survey_requirement
    >>> f"{survey_requirement(170, 12, 0.7):.1e}"
    '2.0e-06'
    """
    area, ng, zm = (np.asarray(v, dtype=np.float64) for v in (area_deg2, n_gal_arcmin2, z_median))
    if np.any(area <= 0) or np.any(ng <= 0) or np.any(zm <= -1):
        raise ValueError("area_deg2 and n_gal_arcmin2 must be positive and z_median > -1.")
    out = 1e-7 * (area / 2e4) ** -0.5 * (ng / 35.0) ** -0.5 * ((1 + zm) / 1.9) ** -0.7
    return out if out.ndim else float(out)


def survey_table(surveys: dict | None = None):
    """Table of surveys with their maximal sigma_sys^2 (the paper's Table 2).

    Parameters
    ----------
    surveys : dict, optional
        ``{name: {"area_deg2": ..., "n_gal_arcmin2": ..., "z_median": ...}}``;
        :data:`SURVEYS` (CFHTLS, COSMOS, Stage IV) by default.

    Returns
    -------
    table : astropy.table.Table
        Columns survey, area_deg2, n_gal_arcmin2, z_median, sigma_sys2.

    Examples
    --------
    >>> from sklearn_psf.metrics import survey_table
    >>> t = survey_table()
    >>> [f"{v:.1e}" for v in t["sigma_sys2"]]
    ['2.0e-06', '8.4e-06', '1.2e-07']
    """
    from astropy.table import Table

    surveys = SURVEYS if surveys is None else surveys
    names = list(surveys)
    cols = {key: np.array([surveys[n][key] for n in names], dtype=np.float64)
            for key in ("area_deg2", "n_gal_arcmin2", "z_median")}
    table = Table({"survey": names, **cols})
    table["sigma_sys2"] = survey_requirement(cols["area_deg2"], cols["n_gal_arcmin2"],
                                             cols["z_median"])
    table["area_deg2"].unit = "deg2"
    table["n_gal_arcmin2"].unit = "arcmin-2"
    return table


# --------------------------------------------------------------------------------------------
# Hankel transform and sigma_sys^2
# --------------------------------------------------------------------------------------------
def _ell_grid(ell_min, ell_max, n_ell):
    if not (0 < ell_min < ell_max):
        raise ValueError(f"Need 0 < ell_min < ell_max, got ell_min={ell_min}, ell_max={ell_max}.")
    return np.geomspace(ell_min, ell_max, int(n_ell))


def _primitive_x_j0(x):
    """Antiderivative of x J0(x)."""
    return x * special.j1(x)


def _primitive_x2_j0(x):
    """Antiderivative of x^2 J0(x): x^2 J1 + x J0 - Int_0^x J0."""
    int_j0 = special.itj0y0(x)[0]
    return x * x * special.j1(x) + x * special.j0(x) - int_j0


@functools.lru_cache(maxsize=8)  # the same multipoles and separations for every xi of a study
def _primitives(ell, t):
    """Both antiderivatives at ``x = ell * t`` (tuples), shape (n_ell, n_nodes) each."""
    x = np.reshape(ell, (-1, 1)) * np.asarray(t)
    p1, p2 = _primitive_x_j0(x), _primitive_x2_j0(x)
    p1.flags.writeable = p2.flags.writeable = False  # shared by the cache
    return p1, p2


def _check_theta_xi(theta_arcmin, xi):
    theta = np.asarray(theta_arcmin, dtype=np.float64)
    xi = np.asarray(xi, dtype=np.float64)
    if theta.ndim != 1 or xi.shape != theta.shape:
        raise ValueError(
            f"theta and xi must be 1-d arrays of the same length, got shapes {theta.shape} and "
            f"{xi.shape}."
        )
    if theta.size < 2:
        raise ValueError("Need xi at two separations at least to transform it.")
    if not (np.all(np.isfinite(theta)) and np.all(np.isfinite(xi))):
        raise ValueError(
            "theta or xi contains NaN or infinite values (e.g. empty correlation bins); drop those "
            "bins first."
        )
    if np.any(theta <= 0) or np.any(np.diff(theta) <= 0):
        raise ValueError("theta must be positive and strictly increasing.")
    return theta, xi


def _piecewise_linear_nodes(theta, xi, extrapolation, points_per_decade=200, taper_factor=2.0):
    """Nodes (theta in arcmin, xi) of the piecewise-linear model of xi used in the transform."""
    n_fine = max(int(np.ceil(np.log10(theta[-1] / theta[0]) * points_per_decade)) + 1, 2)
    fine = np.geomspace(theta[0], theta[-1], n_fine)
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):  # flat runs of xi
        values = PchipInterpolator(np.log(theta), xi)(np.log(fine))
    if not np.all(np.isfinite(values)):
        raise ValueError("Could not interpolate xi(theta): check for extreme values.")
    if extrapolation == "zero":
        return fine, values, False
    if extrapolation != "smooth":
        raise ValueError(f"extrapolation must be 'smooth' or 'zero', got {extrapolation!r}.")
    n_taper = max(int(np.ceil(np.log10(taper_factor) * points_per_decade)), 8)
    tail = np.geomspace(theta[-1], theta[-1] * taper_factor, n_taper + 1)[1:]
    u = np.log(tail / theta[-1]) / np.log(taper_factor)
    tail_values = xi[-1] * np.cos(0.5 * np.pi * u) ** 2
    return np.concatenate([fine, tail]), np.concatenate([values, tail_values]), True


def hankel_xi_to_cl(theta_arcmin, xi, ell, *, extrapolation: str = "smooth"):
    """Angular power spectrum of a correlation function: C_l = 2 pi Int theta xi J0(l theta) dtheta.

    Parameters
    ----------
    theta_arcmin : array-like of shape (n,)
        Increasing separations in arcmin.
    xi : array-like of shape (n,)
        Correlation function (e.g. delta xi+) at ``theta_arcmin``.
    ell : array-like
        Multipoles.
    extrapolation : {"smooth", "zero"}, default="smooth"
        Treatment of xi outside [theta[0], theta[-1]]: "smooth" holds it constant below
        theta[0] and tapers it to zero over [theta[-1], 2 theta[-1]]; "zero" sets it to zero.

    Returns
    -------
    cl : ndarray, same shape as ``ell``

    Notes
    -----
    xi is interpolated by PCHIP in ln theta onto 200 points per decade, and the integral of
    the resulting piecewise-linear function is computed exactly from the antiderivatives of
    x J0(x) = (x J1)' and x^2 J0(x) = (x^2 J1 + x J0 - Int_0^x J0)', so the result is accurate
    at any l without resolving the oscillations of J0.

    Examples
    --------
    A Gaussian xi = exp(-theta^2 / (2 s^2)) has C_l = 2 pi s^2 exp(-l^2 s^2 / 2):

    >>> import numpy as np
    >>> from sklearn_psf.metrics import hankel_xi_to_cl
    >>> s = 2.0  # arcmin
    >>> theta = np.geomspace(0.01, 20, 100)
    >>> ell = np.array([100.0, 1000.0, 3000.0])
    >>> cl = hankel_xi_to_cl(theta, np.exp(-theta**2 / (2 * s**2)), ell)
    >>> s_rad = s * np.pi / 180 / 60
    >>> np.allclose(cl, 2 * np.pi * s_rad**2 * np.exp(-ell**2 * s_rad**2 / 2), rtol=1e-3)
    True
    """
    theta, xi = _check_theta_xi(theta_arcmin, xi)
    ell = np.asarray(ell, dtype=np.float64)
    nodes, values, hold_below = _piecewise_linear_nodes(theta, xi, extrapolation)
    t = nodes * ARCMIN
    slope = np.diff(values) / np.diff(t)
    intercept = values[:-1] - slope * t[:-1]
    flat_ell = ell.reshape(-1, 1)
    p1, p2 = _primitives(tuple(flat_ell[:, 0]), tuple(t))
    integral = (intercept * np.diff(p1, axis=1) / flat_ell**2
                + slope * np.diff(p2, axis=1) / flat_ell**3).sum(axis=1)
    if hold_below:  # xi = xi(theta_min) on [0, theta_min]
        integral += values[0] * p1[:, 0] / flat_ell[:, 0] ** 2
    return (2 * np.pi * integral).reshape(ell.shape)


def sigma_sys2_from_cl(ell, cl) -> float:
    """sigma_sys^2 = (1 / 2 pi) Int |C_l| l (l + 1) dln l over the given multipoles (Simpson).

    Parameters
    ----------
    ell : array-like of shape (n,)
        Increasing multipoles, logarithmically spaced for accuracy.
    cl : array-like of shape (n,)
        Power spectrum of the systematic signal at ``ell``.

    Returns
    -------
    sigma_sys2 : float

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.metrics import sigma_sys2_from_cl
    >>> ell = np.geomspace(10, 20000, 512)
    >>> value = sigma_sys2_from_cl(ell, 1e-10 / (ell * (ell + 1)))
    >>> round(float(value / (1e-10 * np.log(2000) / (2 * np.pi))), 6)
    1.0
    """
    ell = np.asarray(ell, dtype=np.float64)
    cl = np.asarray(cl, dtype=np.float64)
    if ell.ndim != 1 or cl.shape != ell.shape or ell.size < 3:
        raise ValueError("ell and cl must be 1-d arrays of the same length (3 values at least).")
    if np.any(ell <= 0) or np.any(np.diff(ell) <= 0):
        raise ValueError("ell must be positive and strictly increasing.")
    return float(simpson(np.abs(cl) * ell * (ell + 1), x=np.log(ell)) / (2 * np.pi))


def sigma_sys2(
    theta_arcmin,
    delta_xi_plus,
    *,
    ell_min: float = ELL_RANGE[0],
    ell_max: float = ELL_RANGE[1],
    n_ell: int = N_ELL,
    extrapolation: str = "smooth",
) -> float:
    """Systematics variance sigma_sys^2 (Amara & Refregier 2008) implied by a bias delta xi+.

    sigma_sys^2 = (1 / 2 pi) Int |C_l^sys| l (l + 1) dln l, with C_l^sys the Hankel transform of
    ``delta_xi_plus`` (:func:`hankel_xi_to_cl`) on ``n_ell`` log-spaced multipoles in
    [``ell_min``, ``ell_max``].

    Parameters
    ----------
    theta_arcmin : array-like of shape (n,)
        Increasing separations in arcmin.
    delta_xi_plus : array-like of shape (n,)
        Bias of the shear correlation function, e.g. ``shear_bias_bound(rho1(...).xi)``.
    ell_min, ell_max : float, default=10, 20000
        Multipole range of the integral.
    n_ell : int, default=512
        Number of multipoles.
    extrapolation : {"smooth", "zero"}, default="smooth"
        Treatment of theta outside the measured range, see :func:`hankel_xi_to_cl`.

    Returns
    -------
    sigma_sys2 : float

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.metrics import sigma_sys2
    >>> theta = np.geomspace(0.1, 100, 30)
    >>> value = sigma_sys2(theta, 1e-7 * np.exp(-theta / 5))
    >>> bool(0 < value < 1e-7)
    True
    """
    ell = _ell_grid(ell_min, ell_max, n_ell)
    return sigma_sys2_from_cl(ell, hankel_xi_to_cl(theta_arcmin, delta_xi_plus, ell,
                                                   extrapolation=extrapolation))


# --------------------------------------------------------------------------------------------
# LCDM shear spectra (pyccl) and the requirement lines of the paper's fig_cor
# --------------------------------------------------------------------------------------------
def _cosmology_key(cosmology):
    if cosmology is None:
        return tuple(sorted(DEFAULT_COSMOLOGY.items()))
    if isinstance(cosmology, dict):
        params = {**DEFAULT_COSMOLOGY, **cosmology}
        return tuple(sorted(params.items()))
    import pyccl

    if isinstance(cosmology, pyccl.Cosmology):
        return cosmology
    raise TypeError(
        f"cosmology must be None, a dict of pyccl.Cosmology parameters or a pyccl.Cosmology, "
        f"got {type(cosmology).__name__}."
    )


@functools.lru_cache(maxsize=16)
def _cosmo_and_tracer(key, z_median):
    import pyccl

    cosmo = key if isinstance(key, pyccl.Cosmology) else pyccl.Cosmology(**dict(key))
    z0 = z_median / 1.412
    z = np.linspace(0.0, max(6.0 * z0, 4.0), 600)
    nz = z**2 * np.exp(-((z / z0) ** 1.5))
    tracer = pyccl.WeakLensingTracer(cosmo, dndz=(z, nz))
    return cosmo, tracer


@functools.lru_cache(maxsize=32)
def _shear_cl_cached(key, z_median, ell_tuple):
    import pyccl

    cosmo, tracer = _cosmo_and_tracer(key, z_median)
    cl = pyccl.angular_cl(cosmo, tracer, tracer, np.asarray(ell_tuple))
    cl = np.asarray(cl, dtype=np.float64)
    cl.flags.writeable = False
    return cl


@functools.lru_cache(maxsize=32)
def _shear_xi_plus_cached(key, z_median, theta_tuple):
    import pyccl

    cosmo, _ = _cosmo_and_tracer(key, z_median)
    ell = np.unique(np.geomspace(1, 1e5, 2000).round())
    cl = _shear_cl_cached(key, z_median, tuple(ell))
    xi = pyccl.correlation(cosmo, ell=ell, C_ell=np.array(cl),
                           theta=np.asarray(theta_tuple) / 60.0, type="GG+")
    xi = np.asarray(xi, dtype=np.float64)
    xi.flags.writeable = False
    return xi


def _clear_pyccl_caches():
    # pyccl objects free C memory in __del__; drop them before the interpreter tears down
    # the pyccl module, which otherwise prints "Exception ignored in ... __del__" at exit.
    _shear_xi_plus_cached.cache_clear()
    _shear_cl_cached.cache_clear()
    _cosmo_and_tracer.cache_clear()


atexit.register(_clear_pyccl_caches)


def _check_z(z_median):
    if not (np.isfinite(z_median) and z_median > 0):
        raise ValueError(f"z_median must be positive, got {z_median!r}.")
    return float(z_median)


def shear_cl(ell, z_median: float = 0.9, cosmology=None):
    """LCDM cosmic-shear power spectrum C_l (pyccl), cached.

    Parameters
    ----------
    ell : array-like
        Multipoles.
    z_median : float, default=0.9
        Median redshift of the sources, n(z) ~ z^2 exp(-(z / z0)^1.5), z0 = z_median / 1.412.
    cosmology : None, dict or pyccl.Cosmology
        None uses :data:`DEFAULT_COSMOLOGY` (sigma_8 = 0.8); a dict overrides some of its
        parameters.

    Returns
    -------
    cl : ndarray

    Examples
    --------
    >>> from sklearn_psf.metrics import shear_cl
    >>> cl = shear_cl([100.0, 1000.0])
    >>> bool(cl[0] > cl[1] > 0)
    True
    """
    ell = np.asarray(ell, dtype=np.float64)
    cl = _shear_cl_cached(_cosmology_key(cosmology), _check_z(z_median), tuple(ell.ravel()))
    return np.array(cl).reshape(ell.shape)


class RequirementCurves(NamedTuple):
    """Upper limits on D1 for given sigma_sys^2 levels (the dotted lines of the paper's fig_cor).

    Attributes
    ----------
    theta : ndarray of shape (n_theta,)
        Separations in arcmin.
    levels : ndarray of shape (n_levels,)
        sigma_sys^2 levels.
    d1_limit : ndarray of shape (n_levels, n_theta)
        Largest D1 compatible with each level.
    xi_plus_shear : ndarray of shape (n_theta,)
        LCDM shear correlation function xi+ at ``theta``.
    sigma_sys2_shear : float
        The sigma_sys^2 integral applied to the shear C_l itself.
    """

    theta: np.ndarray
    levels: np.ndarray
    d1_limit: np.ndarray
    xi_plus_shear: np.ndarray
    sigma_sys2_shear: float


def requirement_curves(
    theta_arcmin,
    sigma_sys2_levels=(1e-5, 1e-6, 1e-7),
    *,
    z_median: float = 0.9,
    cosmology=None,
    p_gamma: float = 1.84,
    size_ratio: float = 1 / 1.5,
    ell_min: float = ELL_RANGE[0],
    ell_max: float = ELL_RANGE[1],
    n_ell: int = N_ELL,
) -> RequirementCurves:
    """Limits on the residual correlation D1 for sigma_sys^2 levels (paper's fig_cor).

    Taking delta xi+ = f xi+_shear (a constant fraction of the LCDM shear correlation function),
    sigma_sys^2 = f S with S = (1 / 2 pi) Int C_l l (l + 1) dln l of the shear C_l, so a level
    needs f = level / S, and, inverting :func:`shear_bias_bound`,
    D1_limit(theta) = f xi+_shear(theta) P_gamma^2 / size_ratio^4.

    Parameters
    ----------
    theta_arcmin : array-like of shape (n_theta,)
        Separations in arcmin.
    sigma_sys2_levels : sequence of float, default=(1e-5, 1e-6, 1e-7)
    z_median : float, default=0.9
        Median source redshift.
    cosmology : None, dict or pyccl.Cosmology
        See :func:`shear_cl`.
    p_gamma, size_ratio : float
        See :func:`shear_bias_bound`.
    ell_min, ell_max, n_ell
        Multipoles of the sigma_sys^2 integral, see :func:`sigma_sys2`.

    Returns
    -------
    curves : RequirementCurves

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.metrics import requirement_curves
    >>> curves = requirement_curves(np.geomspace(0.5, 20, 5))
    >>> curves.d1_limit.shape
    (3, 5)
    >>> bool(np.all(curves.d1_limit[0] > curves.d1_limit[1]))
    True
    """
    theta = np.atleast_1d(np.asarray(theta_arcmin, dtype=np.float64))
    if theta.ndim != 1 or not np.all(np.isfinite(theta)) or np.any(theta <= 0):
        raise ValueError("theta_arcmin must be a 1-d array of positive separations in arcmin.")
    levels = np.atleast_1d(np.asarray(sigma_sys2_levels, dtype=np.float64))
    if np.any(levels <= 0):
        raise ValueError("sigma_sys2_levels must be positive.")
    if p_gamma <= 0 or size_ratio <= 0:
        raise ValueError("p_gamma and size_ratio must be positive.")
    key = _cosmology_key(cosmology)
    z_median = _check_z(z_median)
    ell = _ell_grid(ell_min, ell_max, n_ell)
    s_shear = sigma_sys2_from_cl(ell, _shear_cl_cached(key, z_median, tuple(ell)))
    xi_shear = np.array(_shear_xi_plus_cached(key, z_median, tuple(theta)))
    fractions = levels / s_shear
    d1 = fractions[:, None] * xi_shear[None, :] * p_gamma**2 / size_ratio**4
    return RequirementCurves(theta, levels, d1, xi_shear, s_shear)
