"""Outlier rejection in units of each star's own noise (chi^2, as PIFF's outliers)."""

from __future__ import annotations

from numbers import Real

import numpy as np
from scipy import special, stats
from sklearn.base import BaseEstimator, _fit_context
from sklearn.utils._param_validation import Interval
from sklearn.utils.validation import check_is_fitted, validate_data

from .._persist import StateMixin
from ._outliers import _OffsetOutlierMixin

__all__ = ["ChiSquareOutlierDetector"]


class ChiSquareOutlierDetector(StateMixin, _OffsetOutlierMixin, BaseEstimator):
    """Flag rows of standardised residuals that noise alone would hardly make.

    Each row of ``X`` holds one star's residuals divided by their standard deviation
    (``(data - model) / sigma``), NaN where there is none (masked pixels). For a star that the
    model describes, the entries are standard normal; two tests, each at level ``p_value / 2``:

    - chi^2: ``sum z^2`` over the ``m`` finite entries against a chi^2 law with ``m`` degrees
      of freedom (an extended defect: a galaxy, a blended neighbour, a wrong model);
    - largest residual: ``max |z|`` against the largest of ``m`` standard normals (a sharp
      defect: a cosmic-ray hit, a hot pixel).

    ``score_samples`` is ``log10`` of the smaller p-value (times 2, Bonferroni over the two
    tests): larger is more normal. ``predict`` gives +1 (inlier) where ``score_samples >=
    offset_``, -1 elsewhere; ``offset_ = log10(p_value)``, raised so that at most
    ``max_remove`` of the rows ``fit`` saw fall below it.

    With ``population=True`` (the default) each test is judged against the rows' own
    population as well as against the noise law: each p-value is turned into a normal
    score ``u`` (0 for a typical noise row, larger for a rarer one), and ``u`` is taken
    relative to the robust location (median) and scale (1.4826 times the median absolute
    deviation) of the rows ``fit`` saw, whenever these exceed what pure noise gives (0 and
    1) by more than 3 times their sampling error. A noise model that is right leaves the test as it is; one that is wrong for every
    star (a missing Poisson term, a misjudged sky, noise correlated by resampling, the
    unresolved stars of a crowded field) shifts and widens the population's scores, and a
    star is then rejected only when it departs from the other stars, not from a noise law
    none of them follows.

    :class:`~sklearn_psf.model.PSFModel` (``outliers="chi2"``, its default) feeds it two sets
    of residuals per star, pixels against the star's own fit on the basis and coefficients
    against their interpolation from the other stars, with the model error added to the
    noise so that bright clean stars are not rejected for the model's own limits; it caps
    what its combined tests reject at ``max_remove`` of the stars.

    Parameters
    ----------
    p_value : float, default=1e-4
        Probability that a star whose residuals are pure noise is rejected.
    population : bool, default=True
        Judge the rows against their own population too (see above).
    max_remove : float or None, default=0.25
        Largest fraction of the rows ``fit`` saw that may be rejected (the worst first),
        as PIFF's ``max_remove``: a model never rests on a minority of its stars because
        their noise model is wrong. None: no cap.

    Attributes
    ----------
    offset_ : float
        ``log10(p_value)``, or higher when ``max_remove`` caps the rejections.
    location_, scale_ : ndarray of shape (2,)
        The population's location and scale of the normal scores of the chi^2 and the
        largest-residual tests (0 and 1 with ``population=False``).
    n_features_in_ : int

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.preprocessing import ChiSquareOutlierDetector
    >>> rng = np.random.default_rng(0)
    >>> z = rng.standard_normal((100, 50))
    >>> z[3, 7] = 12.0          # a cosmic-ray hit
    >>> z[5] *= 2.0             # a star twice as noisy as it should be
    >>> np.flatnonzero(ChiSquareOutlierDetector().fit_predict(z) == -1)
    array([3, 5])
    >>> z *= 1.3                # every star 1.3 times noisier than its weights say
    >>> np.flatnonzero(ChiSquareOutlierDetector().fit_predict(z) == -1)
    array([3, 5])
    """

    _parameter_constraints: dict = {
        "p_value": [Interval(Real, 0, 1, closed="neither")],
        "population": ["boolean"],
        "max_remove": [Interval(Real, 0, 1, closed="right"), None],
    }

    _state_attributes = ("location_", "scale_", "offset_", "n_features_in_")

    def _set_state(self, state):
        super()._set_state(state)
        self.location_ = np.asarray(self.location_, dtype=np.float64)
        self.scale_ = np.asarray(self.scale_, dtype=np.float64)
        return self

    def __init__(self, p_value: float = 1e-4, population: bool = True, max_remove=0.25):
        self.p_value = p_value
        self.population = population
        self.max_remove = max_remove

    @_fit_context(prefer_skip_nested_validation=True)
    def fit(self, X, y=None):
        """Learn the population's scores (and check the residuals).

        Parameters
        ----------
        X : array-like of shape (n_samples, n_residuals)
            Standardised residuals, NaN where missing.
        y : ignored

        Returns
        -------
        self : ChiSquareOutlierDetector
        """
        p, cap = self.p_value, self.max_remove
        if cap is not None and not (isinstance(cap, (int, float, np.floating))
                                    and not isinstance(cap, bool) and 0 < cap <= 1):
            raise ValueError(f"max_remove must be a fraction in (0, 1] or None, got {cap!r}.")
        z = validate_data(self, X, dtype=np.float64, ensure_all_finite="allow-nan")
        self.location_, self.scale_ = np.zeros(2), np.ones(2)
        u, m = self._normal_scores(z)
        rows = m > 0
        n = int(rows.sum())
        if self.population and n >= 5:
            med = np.median(u[rows], axis=0)
            mad = 1.4826 * np.median(np.abs(u[rows] - med), axis=0)
            # only departures from pure noise beyond 3 times their sampling error count
            # (the standard errors of a normal sample's median and MAD-based sigma)
            self.location_ = np.where(med > 3 * 1.2533 / np.sqrt(n), med, 0.0)
            self.scale_ = np.where(mad > 1 + 3 * 1.1664 / np.sqrt(n), mad, 1.0)
        self.offset_ = float(np.log10(p))
        if cap is not None:
            score = np.sort(self.score_samples(z))
            k = int(np.floor(cap * len(score)))  # rows that may fall below the offset
            if k < len(score) and score[k] < self.offset_:
                self.offset_ = float(score[k])  # the k worst rows stay below it
        return self

    @staticmethod
    def _normal_scores(z):
        """Each row's two tests as normal scores (the upper-tail quantile of their p-value
        under pure noise), and its count of finite entries."""
        finite = np.isfinite(z)
        m = finite.sum(axis=1)
        z2 = np.where(finite, z * z, 0.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            log_chi = stats.chi2.logsf(z2.sum(axis=1), np.maximum(m, 1))
            # P(max |z| >= t) for m standard normals = 1 - (1 - erfc(t / sqrt 2))^m
            tail = special.erfc(np.sqrt(z2.max(axis=1, initial=0.0)) / np.sqrt(2.0))
            log_max = np.log(-np.expm1(m * np.log1p(-np.minimum(tail, 1.0))))
            log_max = np.where(tail < 1e-12, np.log(m * tail), log_max)
        logp = np.column_stack([log_chi, log_max])
        logp = np.where(np.isfinite(logp), np.minimum(logp, 0.0), -np.inf)
        u = -special.ndtri_exp(np.maximum(logp, -1e300))
        return np.where(m[:, None] > 0, u, 0.0), m

    def score_samples(self, X):
        """log10 of the p-value of each row (larger = more normal): under pure noise, or,
        with ``population=True``, relative to the rows ``fit`` saw where they depart from
        pure noise.

        Parameters
        ----------
        X : array-like of shape (n_samples, n_residuals)

        Returns
        -------
        scores : ndarray of shape (n_samples,)
            0 for rows with no finite entry.
        """
        check_is_fitted(self)
        z = validate_data(self, X, dtype=np.float64, reset=False, ensure_all_finite="allow-nan")
        u, m = self._normal_scores(z)
        rel = (u - self.location_) / self.scale_
        logp = np.minimum(special.log_ndtr(-rel).min(axis=1) + np.log(2.0), 0.0)
        return np.where(m > 0, logp / np.log(10.0), 0.0)

    def __sklearn_tags__(self):
        tags = super().__sklearn_tags__()
        tags.input_tags.allow_nan = True
        return tags
