"""Outlier rejection in units of each star's own noise (chi^2, as PIFF's outliers)."""

from __future__ import annotations

import numpy as np
from scipy import special, stats
from sklearn.base import BaseEstimator
from sklearn.utils.validation import check_is_fitted, validate_data

from ._outliers import _OffsetOutlierMixin

__all__ = ["ChiSquareOutlierDetector"]


class ChiSquareOutlierDetector(_OffsetOutlierMixin, BaseEstimator):
    """Flag rows of standardised residuals that noise alone would hardly make.

    Each row of ``X`` holds one star's residuals divided by their standard deviation
    (``(data - model) / sigma``), NaN where there is none (masked pixels). For a star that the
    model describes, the entries are standard normal; two tests, each at level ``p_value / 2``:

    - chi^2: ``sum z^2`` over the ``m`` finite entries against a chi^2 law with ``m`` degrees
      of freedom (an extended defect: a galaxy, a blended neighbour, a wrong model);
    - largest residual: ``max |z|`` against the largest of ``m`` standard normals (a sharp
      defect: a cosmic-ray hit, a hot pixel).

    ``score_samples`` is ``log10`` of the smaller p-value (times 2, Bonferroni over the two
    tests): larger is more normal. ``offset_ = log10(p_value)``; ``predict`` gives +1 (inlier)
    where ``score_samples >= offset_``, -1 elsewhere. Nothing is learnt from the data: the
    reference is the noise law itself, so ``fit`` only checks the input.

    :class:`~sklearn_psf.model.PSFModel` (``outliers="chi2"``, its default) feeds it two sets
    of residuals per star, pixels against the star's own fit on the basis and coefficients
    against their interpolation from the other stars, with the model error added to the
    noise so that bright clean stars are not rejected for the model's own limits.

    Parameters
    ----------
    p_value : float, default=1e-4
        Probability that a star whose residuals are pure noise is rejected.

    Attributes
    ----------
    offset_ : float
        ``log10(p_value)``.
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
    """

    def __init__(self, p_value: float = 1e-4):
        self.p_value = p_value

    def fit(self, X, y=None):
        """Check the residuals (nothing is learnt from them).

        Parameters
        ----------
        X : array-like of shape (n_samples, n_residuals)
            Standardised residuals, NaN where missing.
        y : ignored

        Returns
        -------
        self : ChiSquareOutlierDetector
        """
        p = self.p_value
        if not (isinstance(p, (int, float, np.floating)) and 0 < p < 1):
            raise ValueError(f"p_value must be a probability in (0, 1), got {p!r}.")
        validate_data(self, X, dtype=np.float64, ensure_all_finite="allow-nan")
        self.offset_ = float(np.log10(p))
        return self

    def score_samples(self, X):
        """log10 of the p-value of each row under pure noise (larger = more normal).

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
        finite = np.isfinite(z)
        m = finite.sum(axis=1)
        z2 = np.where(finite, z * z, 0.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            log_chi = stats.chi2.logsf(z2.sum(axis=1), np.maximum(m, 1))
            # P(max |z| >= t) for m standard normals = 1 - (1 - erfc(t / sqrt 2))^m
            tail = special.erfc(np.sqrt(z2.max(axis=1, initial=0.0)) / np.sqrt(2.0))
            log_max = np.log(-np.expm1(m * np.log1p(-np.minimum(tail, 1.0))))
            log_max = np.where(tail < 1e-12, np.log(m * tail), log_max)
        logp = np.minimum(np.minimum(log_chi, log_max) + np.log(2.0), 0.0)
        return np.where(m > 0, logp / np.log(10.0), 0.0)

    def __sklearn_tags__(self):
        tags = super().__sklearn_tags__()
        tags.input_tags.allow_nan = True
        return tags
