"""Radial basis function interpolation (through scipy.interpolate.RBFInterpolator)."""

from __future__ import annotations

from math import comb
from numbers import Integral, Real

import numpy as np
from scipy.interpolate import RBFInterpolator
from sklearn.utils._param_validation import Interval, StrOptions

from ._base import (
    _check_n_neighbors,
    _check_n_samples,
    _merge_duplicates,
    _NoiseAwareInterpolator,
)

#: kernels exposed, and the degree of the polynomial that scipy adds by default
_KERNELS = {
    "gaussian": 0,
    "multiquadric": 0,
    "inverse_multiquadric": 0,
    "thin_plate_spline": 1,
}


class RBFRegressor(_NoiseAwareInterpolator):
    """Radial basis function interpolation, ``y(x) = sum_i w_i phi(|x - x_i|) + P(x)``.

    A thin wrapper of :class:`scipy.interpolate.RBFInterpolator` (kernels and their
    definitions are scipy's, with ``r`` the Euclidean distance):

    - ``"gaussian"``: ``exp(-(epsilon r)^2)``
    - ``"multiquadric"``: ``-sqrt(1 + (epsilon r)^2)``
    - ``"inverse_multiquadric"``: ``1 / sqrt(1 + (epsilon r)^2)``
    - ``"thin_plate_spline"``: ``r^2 log r`` (scale invariant: ``epsilon`` has no effect)

    ``P`` is scipy's default polynomial: degree 1 for the thin-plate spline, a constant
    for the other kernels. The paper found RBF interpolation unstable and in need of
    tuning: ``epsilon`` must match the spacing of the stars in the units of ``X``.

    Parameters
    ----------
    kernel : {"gaussian", "multiquadric", "inverse_multiquadric", "thin_plate_spline"}, \
default="gaussian"
        Radial function.
    epsilon : float, default=1.0
        Shape parameter: the kernel is evaluated at ``epsilon * r``, so ``1 / epsilon`` is
        the kernel's length scale in the units of ``X``.
    smoothing : float, default=0.0
        Smoothing parameter of scipy (added to the kernel matrix's diagonal); 0 gives an
        exact interpolant.
    n_neighbors : int or None, default=None
        ``None``: one global RBF system of all stars. An integer ``k``: scipy's local
        interpolation (``RBFInterpolator(neighbors=k)``): each query uses an RBF system of
        its ``k`` nearest stars, for large numbers of stars. ``k`` must be at least the
        number of polynomial terms (3 for the thin-plate spline in 2-D).

    Attributes
    ----------
    interpolator_ : scipy.interpolate.RBFInterpolator
        The fitted scipy interpolator (the first one with per-target noise).
    interpolators_ : list of scipy.interpolate.RBFInterpolator
        One per group of targets sharing their smoothing (one without ``noise_var``).
    n_features_in_ : int
        Number of features seen during fit.

    Notes
    -----
    ``fit(X, y, noise_var=...)``: star ``i`` of target ``t`` gets the smoothing
    ``smoothing + noise_var[i, t] / var(y_t)``, the noise-to-signal ratio with the
    target's variance as the kernel's amplitude (the Gaussian-process equivalent for
    kernels equal to 1 at 0, gaussian and inverse multiquadric; a heuristic for the
    others). Targets with different ratios need one scipy interpolator each.

    With ``smoothing=0`` stars at exactly the same position make the system singular:
    their values are averaged with a :class:`DuplicateStarsWarning`. A singular system
    otherwise raises a ``ValueError`` suggesting to change ``epsilon`` or add smoothing.

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.interpolate import RBFRegressor
    >>> rng = np.random.default_rng(0)
    >>> X = rng.uniform(size=(30, 2))
    >>> y = np.sin(3 * X[:, 0]) + X[:, 1]
    >>> reg = RBFRegressor(kernel="thin_plate_spline").fit(X, y)
    >>> bool(np.allclose(reg.predict(X), y))
    True
    """

    _parameter_constraints: dict = {
        "kernel": [StrOptions(set(_KERNELS))],
        "epsilon": [Interval(Real, 0, np.inf, closed="neither")],
        "smoothing": [Interval(Real, 0, np.inf, closed="left")],
        "n_neighbors": [Interval(Integral, 1, None, closed="left"), None],
    }

    def __init__(self, kernel="gaussian", epsilon=1.0, smoothing=0.0, n_neighbors=None):
        self.kernel = kernel
        self.epsilon = epsilon
        self.smoothing = smoothing
        self.n_neighbors = n_neighbors

    def _fit(self, X, Y, noise):
        name = "RBFRegressor"
        if self.smoothing == 0:
            X, Y, noise = _merge_duplicates(
                X, Y, owner=name, noise=noise,
                reason="with smoothing=0 the RBF system would be singular.",
            )
        k = _check_n_neighbors(name, self.n_neighbors)
        degree = _KERNELS[self.kernel]
        n_poly = max(comb(X.shape[1] + degree, degree), 1)
        if k is not None and k < n_poly:
            raise ValueError(
                f"{name}: n_neighbors must be at least {n_poly} (the polynomial terms of the "
                f"{self.kernel} kernel in {X.shape[1]} features), got {k}."
            )
        _check_n_samples(
            name, X.shape[0], max(comb(X.shape[1] + degree, degree), 1),
            f"(distinct positions) for the degree-{degree} polynomial of the "
            f"{self.kernel} kernel in {X.shape[1]} features",
        )
        if noise is None:
            groups, smoothings = [np.arange(Y.shape[1])], [float(self.smoothing)]
        else:
            # per-star smoothing: the noise-to-signal ratio of each target (its variance
            # over the stars as the kernel's amplitude); targets with equal ratios share
            var = Y.var(axis=0)
            ratio = noise / np.where(var > 0, var, np.inf)
            unique, inverse = np.unique(ratio.T, axis=0, return_inverse=True)
            groups = [np.flatnonzero(inverse.reshape(-1) == g) for g in range(len(unique))]
            smoothings = [self.smoothing + r for r in unique]
        try:
            self.interpolators_ = [
                RBFInterpolator(
                    X, Y[:, cols], kernel=self.kernel, epsilon=float(self.epsilon),
                    smoothing=smooth, neighbors=k,
                )
                for cols, smooth in zip(groups, smoothings)
            ]
        except np.linalg.LinAlgError as exc:
            raise ValueError(
                f"{name}: the RBF system is singular ({exc}). Try another epsilon, a "
                "smoothing > 0, or check that the stars are not aligned (the thin-plate "
                "spline needs stars spanning every dimension)."
            ) from None

        self._groups = groups
        self.interpolator_ = self.interpolators_[0]

    def _predict(self, X):
        out = np.empty((X.shape[0], self.n_targets_))
        for cols, interp in zip(self._groups, self.interpolators_):
            out[:, cols] = interp(X)
        return out
