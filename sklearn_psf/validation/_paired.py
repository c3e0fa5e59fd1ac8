"""Two models judged star by star on the same stars: a paired test of their chi^2."""

from __future__ import annotations

import numpy as np

__all__ = ["paired_comparison"]


def paired_comparison(chi2_a, chi2_b, dof, *, n_boot: int = 2000, random_state=0) -> dict:
    """Star-by-star comparison of two models' chi^2 on the same stars.

    Parameters
    ----------
    chi2_a, chi2_b : array-like of shape (n,)
        Each star's chi^2 against model a and model b (NaN: not measured, left out).
    dof : array-like of shape (n,)
        The stars' degrees of freedom (the same pixels for both models).
    n_boot : int, default=2000
        Bootstrap resamples of the stars for the interval of the mean difference.
    random_state : int, default=0

    Returns
    -------
    dict
        ``n`` (stars measured by both), ``a_lower`` (fraction of them where a's chi^2/dof
        is lower), ``sign_p`` (two-sided sign test of that fraction against 1/2),
        ``sum_ratio`` (summed chi^2 of a over b's), ``mean_diff`` (mean of a's minus b's
        chi^2/dof) and ``mean_diff_ci`` (its 95% bootstrap interval), ``median_ratio``
        (median of the stars' chi^2 ratio a / b).

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.validation import paired_comparison
    >>> rng = np.random.default_rng(0)
    >>> b = rng.chisquare(100, 200)
    >>> out = paired_comparison(0.9 * b, b, np.full(200, 100))
    >>> out["a_lower"], round(out["sum_ratio"], 3), bool(out["sign_p"] < 1e-10)
    (1.0, 0.9, True)
    """
    from scipy.stats import binomtest

    a, b = np.asarray(chi2_a, dtype=float), np.asarray(chi2_b, dtype=float)
    d = np.asarray(dof, dtype=float)
    ok = np.isfinite(a) & np.isfinite(b) & (d > 0)
    a, b, d = a[ok], b[ok], d[ok]
    n = int(ok.sum())
    if n == 0:
        return {"n": 0, "a_lower": np.nan, "sign_p": np.nan, "sum_ratio": np.nan,
                "mean_diff": np.nan, "mean_diff_ci": (np.nan, np.nan), "median_ratio": np.nan}
    diff = (a - b) / d
    lower, ties = int(np.sum(diff < 0)), int(np.sum(diff == 0))
    sign_p = binomtest(lower, n - ties, 0.5).pvalue if n > ties else 1.0
    rng = np.random.default_rng(random_state)
    boot = diff[rng.integers(0, n, (int(n_boot), n))].mean(axis=1)
    return {"n": n, "a_lower": lower / n, "sign_p": float(sign_p),
            "sum_ratio": float(a.sum() / b.sum()), "mean_diff": float(diff.mean()),
            "mean_diff_ci": (float(np.percentile(boot, 2.5)), float(np.percentile(boot, 97.5))),
            "median_ratio": float(np.median(a / b))}
