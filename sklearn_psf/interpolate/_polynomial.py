"""Polynomial interpolation over the whole field: monomial and Chebyshev bases."""

from __future__ import annotations

import itertools
import warnings
from itertools import combinations_with_replacement
from math import comb
from numbers import Integral

import numpy as np
from numpy.polynomial import chebyshev
from sklearn.utils._param_validation import Interval, StrOptions
from sklearn.utils.validation import check_is_fitted

from ._base import RankDeficientWarning, _NoiseAwareInterpolator


def _exponents(n_features: int, degree: int) -> np.ndarray:
    """All exponent vectors of total degree <= degree, ordered by total degree.

    Returns an int array of shape (comb(n_features + degree, degree), n_features).
    """
    rows = []
    for total in range(degree + 1):
        for combo in combinations_with_replacement(range(n_features), total):
            e = np.zeros(n_features, dtype=int)
            np.add.at(e, list(combo), 1)
            rows.append(e)
    return np.array(rows, dtype=int).reshape(-1, n_features)


def _group_exponents(n_features: int, degrees) -> np.ndarray:
    """PSFEx's groups: total degree <= ``degrees[0]`` in (x, y) (the first two features) times
    each further feature j to a power <= ``degrees[j - 1]`` (products of the groups' terms)."""
    blocks = [_exponents(min(n_features, 2), int(degrees[0]))]
    for g in degrees[1:]:
        blocks.append(np.arange(int(g) + 1).reshape(-1, 1))
    rows = [np.concatenate(parts) for parts in itertools.product(*blocks)]
    rows.sort(key=lambda e: (e.sum(), tuple(-e)))
    return np.array(rows, dtype=int).reshape(-1, n_features)


def _n_terms(n_features: int, degree: int) -> int:
    return comb(n_features + degree, degree)


def _design(U, exponents, degree, basis):
    """Design matrix prod_k P_{e_k}(u_k) with P the monomials or Chebyshev polynomials."""
    A = np.ones((U.shape[0], exponents.shape[0]))
    for k in range(U.shape[1]):
        if basis == "chebyshev":
            V = chebyshev.chebvander(U[:, k], degree)
        else:
            V = np.vander(U[:, k], degree + 1, increasing=True)
        A *= V[:, exponents[:, k]]
    return A


def _weighted_lstsq(A, Y, sqrt_w):
    """Least squares of each column of Y with row weights ``sqrt_w**2`` (None: unweighted).

    Columns sharing their weights share one solve. Returns coef and the smallest rank.
    """
    if sqrt_w is None:
        coef, _, rank, _ = np.linalg.lstsq(A, Y, rcond=None)
        return coef, rank
    coef = np.empty((A.shape[1], Y.shape[1]))
    unique, inverse = np.unique(sqrt_w.T, axis=0, return_inverse=True)
    ranks = []
    for g, w in enumerate(unique):
        cols = np.flatnonzero(inverse.reshape(-1) == g)
        coef[:, cols], _, rank, _ = np.linalg.lstsq(A * w[:, None], Y[:, cols] * w[:, None],
                                                    rcond=None)
        ranks.append(rank)
    return coef, min(ranks)


class _PolynomialBase(_NoiseAwareInterpolator):
    _basis = "monomial"
    _noise_positive = True

    def _scale(self, X):
        return (X - self.center_) / self.half_width_

    def _fit_degree(self, U, Y, degree, sqrt_w=None):
        exponents = (_exponents(U.shape[1], degree) if np.ndim(degree) == 0
                     else _group_exponents(U.shape[1], degree))
        A = _design(U, exponents, int(exponents.max(initial=0)), self._basis)
        coef, rank = _weighted_lstsq(A, Y, sqrt_w)
        return exponents, coef, rank, A

    def _check_degree(self, degree, name="degree"):
        if (
            not isinstance(degree, Integral)
            or isinstance(degree, bool)
            or degree < 0
        ):
            raise ValueError(
                f"{type(self).__name__}: {name} must be a non-negative integer, got {degree!r}."
            )

    def _check_group_degrees(self, degree, d):
        """A sequence of degrees: (x, y)'s, then one per further feature."""
        owner = type(self).__name__
        values = list(degree)
        for g in values:
            self._check_degree(g)
        if len(values) != max(d - 1, 1):
            raise ValueError(f"{owner}: a sequence of degrees holds the degree in (x, y) then one "
                             f"per further feature: {max(d - 1, 1)} values for {d} features, "
                             f"got {len(values)}.")
        return tuple(int(g) for g in values)

    def _set_fit(self, X, U, Y, degree, sqrt_w):
        owner = type(self).__name__
        n, d = X.shape
        if np.ndim(degree) == 1:  # PSFEx's groups: no lowering, a clear error instead
            degree = self._check_group_degrees(degree, d)
            m = len(_group_exponents(d, degree))
            if m > n:
                raise ValueError(f"{owner}: degrees {degree} give {m} terms, more than the "
                                 f"{n} stars: give lower degrees.")
            self.powers_, self.coef_, rank, _ = self._fit_degree(U, Y, degree, sqrt_w)
            if rank < m:
                warnings.warn(f"{owner}: the design matrix has rank {rank} < {m} terms; the "
                              "minimum-norm least-squares solution is used. Lower the degrees.",
                              RankDeficientWarning, stacklevel=4)
            self.degree_ = degree
            return
        capped = degree
        while capped > 0 and _n_terms(d, capped) > n:
            capped -= 1
        if capped < degree:
            warnings.warn(
                f"{owner}: {n} stars are fewer than the {_n_terms(d, degree)} terms of "
                f"degree {degree} in {d} features; the degree is lowered to {capped} "
                f"({_n_terms(d, capped)} terms). Give more stars or a lower degree.",
                RankDeficientWarning,
                stacklevel=4,
            )
        self.powers_, self.coef_, rank, _ = self._fit_degree(U, Y, capped, sqrt_w)
        if rank < self.powers_.shape[0]:
            warnings.warn(
                f"{owner}: the design matrix has rank {rank} < {self.powers_.shape[0]} terms "
                f"(stars aligned for degree {capped}); the minimum-norm least-squares "
                "solution is used. Lower the degree.",
                RankDeficientWarning,
                stacklevel=4,
            )
        self.degree_ = int(capped)

    def _bounds(self, X):
        lo, hi = X.min(axis=0), X.max(axis=0)
        self.center_ = (lo + hi) / 2.0
        half = (hi - lo) / 2.0
        half[half == 0] = 1.0
        self.half_width_ = half

    def _predict(self, X):
        A = _design(self._scale(X), self.powers_, int(self.powers_.max(initial=0)), self._basis)
        return A @ self.coef_


class PolynomialRegressor(_PolynomialBase):
    """Least-squares polynomial of total degree ``degree`` over the whole field.

    The model is ``sum c_e x1^e1 ... xn^en`` over all exponent vectors with
    ``e1 + ... + en <= degree`` (for positions (x, y): all ``x^i y^j`` with
    ``i + j <= degree``, as in PSFEx). Positions are mapped to [-1, 1] from the training
    bounding box before building the design matrix, for conditioning; the fitted
    polynomial is the same as a least-squares fit in raw coordinates (up to rounding).

    Parameters
    ----------
    degree : int, "auto" or sequence of int, default=5
        Total degree. ``"auto"`` chooses it in ``0 .. max_degree`` by the Bayesian
        information criterion (see Notes). A sequence gives a degree per group of features,
        as PSFEx's ``PSFVAR_GROUPS``/``PSFVAR_DEGREES``: the total degree in (x, y), then the
        degree in each further feature (a colour, a magnitude); the terms are the products
        of the groups' terms (``(3, 1)``: ``x^i y^j c^k`` with ``i + j <= 3``, ``k <= 1``).
    max_degree : int, default=8
        Largest degree tried when ``degree="auto"``; ignored otherwise.

    Attributes
    ----------
    degree_ : int or tuple of int
        Degree used (the chosen one when ``degree="auto"``; lowered with a warning when
        there are fewer stars than terms; the groups' degrees for a sequence).
    powers_ : ndarray of shape (n_terms, n_features)
        Exponent vector of each term.
    coef_ : ndarray of shape (n_terms, n_targets)
        Coefficients in the scaled coordinates ``(X - center_) / half_width_``.
    center_, half_width_ : ndarray of shape (n_features,)
        Centre and half width of the training bounding box.
    criterion_ : dict
        With ``degree="auto"``: BIC of each degree tried.
    n_features_in_ : int
        Number of features seen during fit.

    Notes
    -----
    ``degree="auto"``: the paper chooses the degree "by chi^2 minimisation but kept
    small". Without per-star measurement errors a reduced chi^2 cannot be computed, so
    the noise variance of each target is estimated from the residuals and the degree
    minimises the Bayesian information criterion summed over targets,
    ``sum_t [n log(RSS_t / n) + p log n]`` (p = number of terms): the chi^2 term with the
    estimated variance plus a penalty that keeps the degree small. Summing the
    per-target log-RSS makes the choice independent of each target's scale. Degrees
    with ``p >= n_samples`` are not tried.

    ``fit(X, y, noise_var=...)``: weighted least squares, weights ``1 / noise_var`` per
    star and target (the residuals of ``degree="auto"`` are weighted likewise). With
    fewer stars than terms the degree is lowered to the largest one with at most as
    many terms as stars, with a :class:`RankDeficientWarning` (as ``numpy.polyfit``
    warns); stars aligned for the degree give the minimum-norm solution, also warned.

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.interpolate import PolynomialRegressor
    >>> rng = np.random.default_rng(0)
    >>> X = rng.uniform(size=(50, 2))
    >>> y = 1 + 2 * X[:, 0] - X[:, 0] * X[:, 1]
    >>> reg = PolynomialRegressor(degree=2).fit(X, y)
    >>> np.round(reg.predict([[0.5, 0.5]]), 6)
    array([1.75])
    >>> PolynomialRegressor(degree="auto", max_degree=4).fit(X, y).degree_
    2

    A degree per group, as PSFEx's: cubic in (x, y), linear in a colour:

    >>> Xc = np.column_stack([X, rng.uniform(0, 3, 50)])
    >>> reg = PolynomialRegressor(degree=(3, 1)).fit(Xc, y + 0.1 * Xc[:, 2])
    >>> reg.powers_.shape, bool(np.allclose(reg.predict(Xc), y + 0.1 * Xc[:, 2]))
    ((20, 3), True)

    Weighted by per-star noise variances:

    >>> noise_var = rng.uniform(1e-4, 1e-2, size=50)
    >>> y_obs = y + rng.normal(size=50) * np.sqrt(noise_var)
    >>> reg = PolynomialRegressor(degree=2).fit(X, y_obs, noise_var=noise_var)
    >>> bool(abs(reg.predict([[0.5, 0.5]])[0] - 1.75) < 0.05)
    True
    """

    _parameter_constraints: dict = {
        "degree": [Interval(Integral, 0, None, closed="left"), StrOptions({"auto"}),
                   "array-like"],
        "max_degree": [Interval(Integral, 0, None, closed="left")],
    }

    def __init__(self, degree=5, max_degree=8):
        self.degree = degree
        self.max_degree = max_degree

    def _fit(self, X, Y, noise):
        self._bounds(X)
        U = self._scale(X)
        n, d = X.shape
        sqrt_w = None if noise is None else 1.0 / np.sqrt(noise)
        held = self._held_state_once()
        if held is not None:  # restored (see _set_state): the degree that fit chose
            degree = held["degree_"]
            if held.get("criterion_") is not None:
                self.criterion_ = {int(g): float(c) for g, c in held["criterion_"]}
        elif isinstance(self.degree, str):  # "auto"
            self._check_degree(self.max_degree, "max_degree")
            candidates = [g for g in range(self.max_degree + 1) if _n_terms(d, g) < n]
            if not candidates:
                raise ValueError(
                    "PolynomialRegressor(degree='auto') needs more samples (stars) than "
                    f"terms of the degree-0 polynomial to estimate the noise; got n_samples = {n}."
                )
            scale2 = np.maximum(Y.var(axis=0), np.finfo(float).tiny)
            self.criterion_ = {}
            for g in candidates:
                _, coef, _, A = self._fit_degree(U, Y, g, sqrt_w)
                res = Y - A @ coef
                rss = np.sum((res if sqrt_w is None else res * sqrt_w) ** 2, axis=0)
                rss = np.maximum(rss, n * scale2 * 1e-24)  # exact fits: avoid log(0)
                p = _n_terms(d, g)
                self.criterion_[g] = float(np.sum(n * np.log(rss / n) + p * np.log(n)))
            degree = min(self.criterion_, key=self.criterion_.get)
        elif np.ndim(self.degree) == 1:
            degree = self.degree
        else:
            self._check_degree(self.degree)
            degree = self.degree
        self._set_fit(X, U, Y, degree, sqrt_w)


    # (the protocol of sklearn_psf._persist: the state is the degree the fit chose;
    # restored, the next fit solves the least squares at that degree)
    def _get_state(self):
        check_is_fitted(self)
        degree = self.degree_
        criterion = getattr(self, "criterion_", None)
        return {"degree_": int(degree) if np.ndim(degree) == 0 else [int(g) for g in degree],
                "criterion_": None if criterion is None else [[int(g), float(c)] for g, c
                                                              in criterion.items()]}


class ChebyshevRegressor(_PolynomialBase):
    """Least-squares polynomial of total degree ``degree`` in a Chebyshev basis.

    The basis is ``T_i(u) T_j(v)`` with ``i + j <= degree`` (n-D: products of
    ``T_{e_k}(u_k)`` with total degree <= degree), where ``u, v`` are the positions
    mapped to [-1, 1] from the training bounding box. It spans the same space as
    :class:`PolynomialRegressor`, so at equal degree both predict the same values; the
    Chebyshev basis is better conditioned at high degree.

    Parameters
    ----------
    degree : int or sequence of int, default=5
        Total degree, or a degree per group of features as :class:`PolynomialRegressor`'s.

    Attributes
    ----------
    degree_ : int or tuple of int
        Degree used.
    powers_ : ndarray of shape (n_terms, n_features)
        Chebyshev index vector of each term.
    coef_ : ndarray of shape (n_terms, n_targets)
        Chebyshev coefficients.
    center_, half_width_ : ndarray of shape (n_features,)
        Centre and half width of the training bounding box.
    n_features_in_ : int
        Number of features seen during fit.

    Notes
    -----
    ``noise_var`` and too few stars: as :class:`PolynomialRegressor`.

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.interpolate import ChebyshevRegressor
    >>> rng = np.random.default_rng(0)
    >>> X = rng.uniform(size=(50, 2))
    >>> y = 1 + 2 * X[:, 0] - X[:, 0] * X[:, 1]
    >>> np.round(ChebyshevRegressor(degree=2).fit(X, y).predict([[0.5, 0.5]]), 6)
    array([1.75])
    """

    _basis = "chebyshev"

    _parameter_constraints: dict = {
        "degree": [Interval(Integral, 0, None, closed="left"), "array-like"],
    }

    def __init__(self, degree=5):
        self.degree = degree

    def _fit(self, X, Y, noise):
        if np.ndim(self.degree) != 1:
            self._check_degree(self.degree)
        self._bounds(X)
        sqrt_w = None if noise is None else 1.0 / np.sqrt(noise)
        self._set_fit(X, self._scale(X), Y, self.degree, sqrt_w)
