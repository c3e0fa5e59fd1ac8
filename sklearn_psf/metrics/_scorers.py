"""Scorers for cross_validate / GridSearchCV: ``scorer(estimator, X, y)``, greater is better.

X holds the positions (n, 2) where the PSF is scored (galaxy-PSFs or held-out stars), y the
true stamps there (flattened (n, s*s) or (n, s, s)). The predicted stamps are
``estimator.predict(X)``; ellipticities of both come from
:func:`sklearn_psf.measure.adaptive_moments`, and rows flagged in either are left out.
Scorers are instances of module-level classes, so they pickle and run under joblib
(``n_jobs``).
"""

from __future__ import annotations

import warnings

import numpy as np

from .._validation import as_stamps
from ._correlation import EmptyBinsWarning, ellipticity_correlation
from ._systematics import ELL_RANGE, N_ELL, shear_bias_bound, sigma_sys2

__all__ = [
    "FlaggedStampsWarning",
    "ellipticity_residuals",
    "make_coefficient_rms_scorer",
    "make_ellipticity_rms_scorer",
    "make_rho1_scorer",
    "make_sigma_sys_scorer",
]


class FlaggedStampsWarning(UserWarning):
    """Some stamps could not be measured by adaptive_moments and were left out."""


def ellipticity_residuals(stamps_true, stamps_model, *, max_flagged_fraction: float = 0.5):
    """Ellipticity residuals de = e_true - e_model of two sets of stamps, measured once.

    Parameters
    ----------
    stamps_true, stamps_model : array-like of shape (n, s*s) or (n, s, s)
        True and modelled stamps at the same n positions (same stamp size).
    max_flagged_fraction : float, default=0.5
        Largest fraction of rows that may be flagged by
        :func:`sklearn_psf.measure.adaptive_moments` (in either set) before a ValueError.
        When some rows are flagged a :class:`FlaggedStampsWarning` gives their number.

    Returns
    -------
    de1, de2 : ndarray of shape (n_kept,)
        Residual components of the rows measured in both sets.
    mask : ndarray of bool, shape (n,)
        True for the kept rows (use ``X[mask]`` to align positions).

    Raises
    ------
    ValueError
        When the shapes differ or more than ``max_flagged_fraction`` of the rows are flagged.

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.metrics import ellipticity_residuals
    >>> y, x = np.mgrid[0:21, 0:21] - 10.0
    >>> round_psf = np.exp(-(x**2 + y**2) / 8.0)
    >>> elongated = np.exp(-(x**2 / 10.0 + y**2 / 6.0))
    >>> de1, de2, mask = ellipticity_residuals(np.stack([round_psf, elongated]),
    ...                                        np.stack([round_psf, round_psf]))
    >>> np.round(de1, 3), mask
    (array([0.  , 0.25]), array([ True,  True]))
    """
    from ..measure import adaptive_moments

    true = as_stamps(stamps_true, name="stamps_true")
    model = as_stamps(stamps_model, name="stamps_model")
    if true.shape != model.shape:
        raise ValueError(
            f"stamps_true and stamps_model must have the same shape, got {true.shape} and "
            f"{model.shape}."
        )
    if not 0 <= max_flagged_fraction <= 1:
        raise ValueError(f"max_flagged_fraction must be in [0, 1], got {max_flagged_fraction}.")
    n = true.shape[0]
    if n == 0:
        raise ValueError("No stamps given.")
    m_true = adaptive_moments(true)
    m_model = adaptive_moments(model)
    flag_true = np.asarray(m_true["flag"]) != 0
    flag_model = np.asarray(m_model["flag"]) != 0
    mask = ~(flag_true | flag_model)
    n_bad = int(n - mask.sum())
    if n_bad > max_flagged_fraction * n:
        raise ValueError(
            f"adaptive_moments flagged {n_bad} of {n} rows ({int(flag_true.sum())} true stamps, "
            f"{int(flag_model.sum())} model stamps), more than max_flagged_fraction="
            f"{max_flagged_fraction}: check that the stamps are centred, background-subtracted "
            "and of positive flux, or raise max_flagged_fraction."
        )
    if n_bad:
        warnings.warn(
            f"{n_bad} of {n} rows could not be measured by adaptive_moments "
            f"({int(flag_true.sum())} true, {int(flag_model.sum())} model stamps) and are left "
            "out of the residuals.",
            FlaggedStampsWarning,
            stacklevel=2,
        )
    de1 = np.asarray(m_true["e1"])[mask] - np.asarray(m_model["e1"])[mask]
    de2 = np.asarray(m_true["e2"])[mask] - np.asarray(m_model["e2"])[mask]
    return de1, de2, mask


def _check_X_y(X, y):
    X = np.asarray(X, dtype=np.float64)
    if X.ndim != 2 or X.shape[1] != 2:
        raise ValueError(f"X must hold positions of shape (n, 2), got shape {X.shape}.")
    n_y = np.shape(y)[0] if np.ndim(y) else 0
    if n_y != X.shape[0]:
        raise ValueError(f"X has {X.shape[0]} rows but y has {n_y}: pass one stamp per position.")
    return X


class _ResidualScorer:
    """Base class: ellipticity residuals of ``estimator.predict(X)`` against ``y``."""

    def _residuals(self, estimator, X, y):
        X = _check_X_y(X, y)
        de1, de2, mask = ellipticity_residuals(
            y, estimator.predict(X), max_flagged_fraction=self.max_flagged_fraction
        )
        return X[mask], de1, de2

    def _residual_correlation(self, estimator, X, y, scale=1.0):
        """D1 of the residuals in bins of the separation of ``X * scale`` (empty bins NaN)."""
        Xk, de1, de2 = self._residuals(estimator, X, y)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", category=EmptyBinsWarning)
            return ellipticity_correlation(Xk * scale, de1, de2, min_sep=self.min_sep,
                                           max_sep=self.max_sep, nbins=self.nbins,
                                           bin_slop=self.bin_slop, num_threads=self.num_threads)

    def __repr__(self):
        params = ", ".join(f"{k}={v!r}" for k, v in vars(self).items())
        return f"{type(self).__name__}({params})"


_STATISTICS = ("mean_abs", "max_abs", "rms")


def _reduce(xi, statistic):
    xi = xi[np.isfinite(xi)]
    if statistic == "mean_abs":
        return float(np.mean(np.abs(xi)))
    if statistic == "max_abs":
        return float(np.max(np.abs(xi)))
    return float(np.sqrt(np.mean(xi**2)))


class Rho1Scorer(_ResidualScorer):
    """Minus a summary of |rho1| (D1) over [min_sep, max_sep]; see :func:`make_rho1_scorer`."""

    def __init__(self, min_sep, max_sep, nbins, statistic, max_flagged_fraction, bin_slop,
                 num_threads):
        self.min_sep = min_sep
        self.max_sep = max_sep
        self.nbins = nbins
        self.statistic = statistic
        self.max_flagged_fraction = max_flagged_fraction
        self.bin_slop = bin_slop
        self.num_threads = num_threads

    def __call__(self, estimator, X, y) -> float:
        res = self._residual_correlation(estimator, X, y)
        return -_reduce(res.xi, self.statistic)  # NaN (empty) bins dropped


class EllipticityRMSScorer(_ResidualScorer):
    """Minus sqrt(<|de|^2>); see :func:`make_ellipticity_rms_scorer`."""

    def __init__(self, max_flagged_fraction):
        self.max_flagged_fraction = max_flagged_fraction

    def __call__(self, estimator, X, y) -> float:
        _, de1, de2 = self._residuals(estimator, X, y)
        return -float(np.sqrt(np.mean(de1**2 + de2**2)))


class CoefficientRMSScorer:
    """Minus the RMS of the basis-coefficient residuals; see :func:`make_coefficient_rms_scorer`."""

    def __init__(self, n_components):
        self.n_components = n_components

    def __call__(self, estimator, X, y) -> float:
        X = _check_X_y(X, y)
        stamps = np.asarray(y, dtype=np.float64)
        stamps = stamps.reshape(stamps.shape[0], -1)
        true = np.asarray(estimator.basis_.transform(stamps), dtype=np.float64)
        pred = np.asarray(estimator.predict_coefficients(X), dtype=np.float64)
        if true.shape != pred.shape:
            raise ValueError(
                f"predict_coefficients returned shape {pred.shape} but basis_.transform(y) gives "
                f"{true.shape}."
            )
        k = true.shape[1] if self.n_components is None else int(self.n_components)
        return -float(np.sqrt(np.mean((pred[:, :k] - true[:, :k]) ** 2)))

    def __repr__(self):
        return f"CoefficientRMSScorer(n_components={self.n_components!r})"


class SigmaSysScorer(_ResidualScorer):
    """Minus the sigma_sys^2 implied by rho1; see :func:`make_sigma_sys_scorer`."""

    def __init__(self, min_sep, max_sep, nbins, arcmin_per_unit, p_gamma, size_ratio, ell_min,
                 ell_max, n_ell, extrapolation, max_flagged_fraction, bin_slop, num_threads):
        self.min_sep = min_sep
        self.max_sep = max_sep
        self.nbins = nbins
        self.arcmin_per_unit = arcmin_per_unit
        self.p_gamma = p_gamma
        self.size_ratio = size_ratio
        self.ell_min = ell_min
        self.ell_max = ell_max
        self.n_ell = n_ell
        self.extrapolation = extrapolation
        self.max_flagged_fraction = max_flagged_fraction
        self.bin_slop = bin_slop
        self.num_threads = num_threads

    def __call__(self, estimator, X, y) -> float:
        res = self._residual_correlation(estimator, X, y, scale=self.arcmin_per_unit)
        good = np.isfinite(res.xi)
        if good.sum() < 2:
            raise ValueError(
                f"Only {int(good.sum())} separation bin(s) between {self.min_sep} and "
                f"{self.max_sep} arcmin contain pairs: widen the range or use fewer bins."
            )
        d1 = res.xi[good]
        delta = np.sign(d1) * shear_bias_bound(d1, self.p_gamma, self.size_ratio)
        return -sigma_sys2(res.theta[good], delta, ell_min=self.ell_min, ell_max=self.ell_max,
                           n_ell=self.n_ell, extrapolation=self.extrapolation)


def _check_range(min_sep, max_sep, nbins):
    if not (np.isfinite(min_sep) and min_sep > 0 and np.isfinite(max_sep)):
        raise ValueError(f"min_sep must be positive and finite, got {min_sep!r}.")
    if min_sep >= max_sep:
        raise ValueError(f"min_sep ({min_sep}) must be smaller than max_sep ({max_sep}).")
    if int(nbins) != nbins or nbins < 1:
        raise ValueError(f"nbins must be a positive integer, got {nbins!r}.")


def make_rho1_scorer(
    min_sep: float,
    max_sep: float,
    *,
    nbins: int = 8,
    statistic: str = "mean_abs",
    max_flagged_fraction: float = 0.5,
    bin_slop: float | None = None,
    num_threads: int | None = 1,
) -> Rho1Scorer:
    """Scorer: minus a summary of |rho1(theta)| (Rowe's D1) between two separations.

    Parameters
    ----------
    min_sep, max_sep : float
        Separations (units of X) over which rho1 is measured in ``nbins`` log bins.
    nbins : int, default=8
    statistic : {"mean_abs", "max_abs", "rms"}, default="mean_abs"
        Summary of rho1 over the non-empty bins.
    max_flagged_fraction : float, default=0.5
        See :func:`ellipticity_residuals`.
    bin_slop : float, optional
        TreeCorr binning accuracy.
    num_threads : int or None, default=1
        TreeCorr threads per call (1 leaves the parallelism to joblib's ``n_jobs``).

    Returns
    -------
    scorer : callable ``scorer(estimator, X, y) -> float`` (greater is better)

    Examples
    --------
    >>> from sklearn_psf.metrics import make_rho1_scorer
    >>> scorer = make_rho1_scorer(1.0, 100.0, nbins=5)
    >>> scorer.statistic
    'mean_abs'
    """
    _check_range(min_sep, max_sep, nbins)
    if statistic not in _STATISTICS:
        raise ValueError(f"statistic must be one of {_STATISTICS}, got {statistic!r}.")
    return Rho1Scorer(float(min_sep), float(max_sep), int(nbins), statistic,
                      float(max_flagged_fraction), bin_slop, num_threads)


def make_ellipticity_rms_scorer(*, max_flagged_fraction: float = 0.5) -> EllipticityRMSScorer:
    """Scorer: minus the RMS ellipticity residual sqrt(<(de1^2 + de2^2)>).

    Parameters
    ----------
    max_flagged_fraction : float, default=0.5
        See :func:`ellipticity_residuals`.

    Returns
    -------
    scorer : callable ``scorer(estimator, X, y) -> float`` (greater is better)

    Examples
    --------
    >>> from sklearn_psf.metrics import make_ellipticity_rms_scorer
    >>> make_ellipticity_rms_scorer()
    EllipticityRMSScorer(max_flagged_fraction=0.5)
    """
    return EllipticityRMSScorer(float(max_flagged_fraction))


def make_coefficient_rms_scorer(*, n_components: int | None = None) -> CoefficientRMSScorer:
    """Scorer: minus the RMS residual of the basis (PCA) coefficients.

    Compares ``estimator.predict_coefficients(X)`` with ``estimator.basis_.transform(y)``
    (the true stamps projected on the fitted basis).

    Parameters
    ----------
    n_components : int, optional
        Use only the first ``n_components`` coefficients (all by default).

    Returns
    -------
    scorer : callable ``scorer(estimator, X, y) -> float`` (greater is better)

    Examples
    --------
    >>> from sklearn_psf.metrics import make_coefficient_rms_scorer
    >>> make_coefficient_rms_scorer(n_components=4)
    CoefficientRMSScorer(n_components=4)
    """
    if n_components is not None and (int(n_components) != n_components or n_components < 1):
        raise ValueError(f"n_components must be a positive integer or None, got {n_components!r}.")
    return CoefficientRMSScorer(n_components)


def make_sigma_sys_scorer(
    min_sep: float,
    max_sep: float,
    *,
    nbins: int = 8,
    arcmin_per_unit: float = 1.0,
    p_gamma: float = 1.84,
    size_ratio: float = 1 / 1.5,
    ell_min: float = ELL_RANGE[0],
    ell_max: float = ELL_RANGE[1],
    n_ell: int = N_ELL,
    extrapolation: str = "smooth",
    max_flagged_fraction: float = 0.5,
    bin_slop: float | None = None,
    num_threads: int | None = 1,
) -> SigmaSysScorer:
    """Scorer: minus the sigma_sys^2 implied by the residual correlation rho1.

    rho1 is measured in ``nbins`` log bins between ``min_sep`` and ``max_sep`` arcmin, turned
    into delta xi+ = rho1 size_ratio^4 / p_gamma^2 (:func:`shear_bias_bound`, keeping the sign
    of rho1) and integrated by :func:`sigma_sys2`.

    Parameters
    ----------
    min_sep, max_sep : float
        Separation range in arcmin.
    nbins : int, default=8
    arcmin_per_unit : float, default=1.0
        Size in arcmin of one unit of X (e.g. 0.2 / 60 for pixel positions at 0.2"/pixel).
    p_gamma, size_ratio : float
        See :func:`shear_bias_bound`.
    ell_min, ell_max, n_ell, extrapolation
        See :func:`sigma_sys2`.
    max_flagged_fraction : float, default=0.5
        See :func:`ellipticity_residuals`.
    bin_slop, num_threads
        TreeCorr settings (see :func:`make_rho1_scorer`).

    Returns
    -------
    scorer : callable ``scorer(estimator, X, y) -> float`` (greater is better)

    Examples
    --------
    >>> from sklearn_psf.metrics import make_sigma_sys_scorer
    >>> scorer = make_sigma_sys_scorer(0.5, 20.0, arcmin_per_unit=0.2 / 60)
    >>> scorer.nbins
    8
    """
    _check_range(min_sep, max_sep, nbins)
    if not (np.isfinite(arcmin_per_unit) and arcmin_per_unit > 0):
        raise ValueError(f"arcmin_per_unit must be positive, got {arcmin_per_unit!r}.")
    if extrapolation not in ("smooth", "zero"):
        raise ValueError(f"extrapolation must be 'smooth' or 'zero', got {extrapolation!r}.")
    if p_gamma <= 0 or size_ratio <= 0:
        raise ValueError("p_gamma and size_ratio must be positive.")
    return SigmaSysScorer(float(min_sep), float(max_sep), int(nbins), float(arcmin_per_unit),
                          float(p_gamma), float(size_ratio), float(ell_min), float(ell_max),
                          int(n_ell), extrapolation, float(max_flagged_fraction), bin_slop,
                          num_threads)
