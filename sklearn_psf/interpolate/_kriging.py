"""Ordinary and universal Kriging with bounded variograms, measurement noise and
maximum-likelihood hyperparameters."""

from __future__ import annotations

import functools
import numbers
import warnings
from numbers import Integral, Real

import numpy as np
from sklearn.utils._param_validation import Interval, StrOptions
from sklearn.utils.validation import check_is_fitted

from ._base import (
    FewStarsWarning,
    _check_n_neighbors,
    _check_n_samples,
    _merge_duplicates,
    _NoiseAwareInterpolator,
)
from ._kriging_co import coregionalization_frame
from ._kriging_exact import (
    ExactSolve,
    NoiseGroups,
    correlation,
    fit_coupled,
    fit_exact,
    loo_exact,
    noise_groups,
    predict_exact,
)
from ._kriging_hyper import (
    _MIN_ML_STARS,
    _NAME,
    Hyperparameters,
    _KrigingHyperparameters,
    drift_design,
    drift_powers,
    geometry,
    transform,
)
from ._kriging_local import LocalSolve, fit_local, predict_local
from ._variogram import variogram_models

#: fewer distinct stars than this: a FewStarsWarning (the sill is a variance of few values)
_FEW_STARS = 5
#: n_neighbors="auto": exact Kriging up to this many stars, local Kriging beyond with
_AUTO_EXACT_STARS = 1000
_AUTO_NEIGHBORS = 30


def _check_param(value, name, lo, hi, auto=True, lo_open=False):
    if auto and isinstance(value, str) and value == "auto":
        return
    ok = isinstance(value, numbers.Real) and not isinstance(value, bool) and np.isfinite(value)
    if not ok or value > hi or value < lo or (lo_open and value == lo):
        bounds = f"{'(' if lo_open else '['}{lo}, {hi}]"
        suffix = " or 'auto'" if auto else ""
        raise ValueError(f"{_NAME}: {name} must be a number in {bounds}{suffix}, got {value!r}.")


class KrigingRegressor(_KrigingHyperparameters, _NoiseAwareInterpolator):
    """Ordinary or universal Kriging; the paper's scheme with its defaults.

    The prediction at ``x`` is ``sum_i lambda_i y_i`` with weights minimising the
    variance under the variogram model, subject to unbiasedness (``sum_i lambda_i = 1``
    for ordinary Kriging, reproduction of a linear or quadratic drift for universal
    Kriging). Each target column ``t`` has its own sill ``sigma_t^2`` while range and
    nugget (a fraction of the sill) are shared.

    Parameters
    ----------
    variogram : {"exponential", "spherical", "gaussian"}, default="exponential"
        Variogram model, see :data:`variogram_models`. The exponential variogram of
        range ``a`` is the covariance ``Matern(length_scale=a, nu=0.5)``.
    range : float or "auto", default=0.5
        Range ``a`` in the units of ``X`` (0.5 is the paper's value for positions scaled to
        the unit square, ``make_pipeline(MinMaxScaler(), KrigingRegressor())``; on a
        rectangular field :class:`IsotropicScaler` keeps the distances' proportions).
        ``"auto"``: maximum likelihood (see Notes).
    nugget : float or "auto", default=0.0
        Nugget as a fraction of the sill, in [0, 1]. ``"auto"``: maximum likelihood.
    n_neighbors : int, "auto" or None, default=None
        ``None``: exact Kriging with all stars (one Cholesky factorisation, cost
        ``O(n_stars^3)``, memory ``O(n_stars^2)``, per noise pattern). An integer ``k``:
        local Kriging, each query predicted from its ``k`` nearest stars, for ``10^4``
        stars and more (``k`` >= the stars: exact Kriging, the same system). ``"auto"``:
        exact up to 1000 stars, local with 30 neighbours beyond (accuracy against exact
        Kriging: ``benchmarks/bench_scale.py``).
    noise_scale : float or "auto", default=1.0
        Factor on the ``noise_var`` given to :meth:`fit` (pixel-noise estimates are often
        off by a factor). ``"auto"``: maximum likelihood when ``noise_var`` is given.
    drift : {None, "linear", "quadratic", "auto"}, default=None
        ``None``: ordinary Kriging (constant unknown mean). ``"linear"`` / ``"quadratic"``:
        universal Kriging with an unknown polynomial mean of that degree in the
        positions (PyKrige's ``regional_linear`` drift for ``"linear"``; with
        ``extra_drift="linear"``, the degree is that of the first two features, the
        features beyond them linear). ``"auto"``: the one of the three whose maximum
        likelihood has the smallest Bayesian information criterion,
        ``-2 log L + (drift terms x targets) log(stars)`` (``None`` when no hyperparameter
        is fitted by maximum likelihood), so that a smooth trend over the field goes to the
        drift instead of stretching the range; a drift so chosen that leaves the range at
        its floor (see Notes) is the model, without a :class:`ShortRangeWarning`.
    anisotropy_scaling : float or "auto", default=1.0
        Geometric anisotropy, PyKrige's convention (2 features only): positions are
        rotated by ``-anisotropy_angle`` and their second coordinate multiplied by
        ``anisotropy_scaling`` before distances are computed; the range applies in that
        frame, so it is ``range / anisotropy_scaling`` along the rotated second axis.
        ``"auto"``: maximum likelihood, in [0.1, 10].
    anisotropy_angle : float or "auto", default=0.0
        Counter-clockwise angle in degrees of that rotation; ``"auto"``: maximum
        likelihood.
    extra_scaling : float, array-like or "auto", default=1.0
        Factor on each feature beyond the first two (the model's extra dimensions: a colour,
        a magnitude) before distances are computed, so that the correlation length along
        extra feature ``j`` is ``range / extra_scaling[j]`` (one number: the same factor on
        each). ``"auto"``: one factor per extra feature by maximum likelihood (automatic
        relevance determination: a feature the values do not depend on gets a length 1000
        times the range, and no weight), by the exact likelihood of a subset of at most
        ``(8e6 / factorisations per step)^(1/3)`` stars (200 with one noise pattern, drawn
        with ``random_state``); the other ``"auto"`` hyperparameters are then fitted again
        on all the stars with the factors held. Ignored with two features.
    extra_drift : {None, "linear", "quadratic"}, default=None
        ``"linear"``: the drift also holds a linear term in each feature beyond the first
        two (a trend along a colour or a magnitude, which predictions beyond the stars'
        range extrapolate instead of returning to the mean); ``"quadratic"``: a linear and a
        squared term in each (a curved trend, e.g. the PSF size against g-i; no cross terms).
    likelihood : "auto", "exact" or int, default="auto"
        Likelihood maximised when a hyperparameter is ``"auto"``. ``"exact"``: the
        Gaussian likelihood of all the stars (one ``n x n`` Cholesky factorisation per step,
        one per target when the targets' noise differs). An int ``m``: Vecchia's
        approximation, each star conditioned on its ``m`` nearest earlier stars in a random
        order (cost ``O(n m^3)``; its agreement with the exact likelihood is measured by
        ``benchmarks/bench_kriging.py --ml``). ``"auto"``: exact while (factorisations per
        step) x n^3 <= 1e8 (460 stars with one noise pattern or none) or when the
        anisotropy is fitted, Vecchia with 10 neighbours beyond.
    max_ml_samples : int, default=20000
        Maximum likelihood uses all the stars up to this many, a pseudo-random subset of this
        size beyond (drawn with ``random_state``); the final Kriging system uses all stars.
        With the anisotropy fitted and ``likelihood="auto"``, the exact likelihood runs on a
        subset of 1000 stars.
    random_state : int, RandomState instance or None, default=0
        Seed of that subset and of Vecchia's order (fixed by default, so that fits are
        reproducible).
    warm_start : bool, default=False
        When True and the regressor was fitted before on as many features, maximum
        likelihood starts from the previous fit's hyperparameters instead of its grid of
        starting points, and ``drift="auto"`` keeps the drift it chose then: a refit on
        nearly the same stars (:class:`~sklearn_psf.model.PSFModel`'s outlier rounds) takes
        a few steps, to the same optimum unless the likelihood has several maxima.

    Attributes
    ----------
    range_ : float
        Range used (fitted with ``range="auto"``).
    drift_ : {None, "linear", "quadratic"}
        Drift used (chosen with ``drift="auto"``).
    nugget_ : float
        Nugget used, as a fraction of the sill.
    sill_ : ndarray of shape (n_targets,)
        Sill of each target: its variance over the stars (numeric ``range`` and ``nugget``,
        the paper), the maximum-likelihood sill otherwise.
    coregionalization_ : ndarray of shape (n_targets, n_targets)
        Signal covariance between the targets (sills on the diagonal): fitted with
        ``noise_cov`` (co-Kriging, see Notes), ``diag(sill_)`` otherwise.
    noise_scale_ : float
        Factor applied to ``noise_var`` (1 without noise).
    anisotropy_scaling_, anisotropy_angle_ : float
        Anisotropy used (fitted when ``"auto"``; the angle in degrees).
    extra_scaling_ : ndarray of shape (n_features - 2,)
        Factors on the extra features (fitted when ``"auto"``; empty with two features).
    log_likelihood_ : float or None
        Maximum of the summed log-likelihood (as set by ``likelihood_``), None without
        maximum likelihood.
    n_neighbors_ : int or None
        Neighbours of each query in local mode, None in exact mode (``n_neighbors``,
        resolved when ``"auto"``).
    likelihood_ : {"exact", "vecchia"} or None
        The likelihood maximised (None without maximum likelihood).
    range_floor_ : float or None
        Lower bound of the fitted range: the stars' spacing (median distance from a star to
        its nearest neighbour, in the units of ``X``); None when the range is not fitted.
    range_at_floor_ : bool
        Maximum likelihood put the range at that floor: no spatial correlation the stars
        can resolve; the nugget was then fitted and a :class:`ShortRangeWarning` issued.
    X_fit_ : ndarray of shape (n_stars, n_features)
        Distinct star positions (duplicated positions merged when ``nugget=0``).
    y_fit_ : ndarray of shape (n_stars, n_targets)
        Values at those stars.
    noise_var_ : ndarray of shape (n_stars, n_targets) or None
        Measurement-noise variance of those values (after ``noise_scale_``).
    noise_cov_ : ndarray of shape (n_stars, n_targets, n_targets) or None
        Their noise covariance given as ``noise_cov`` (after ``noise_scale_``), else None.
    n_cg_iter_ : int
        Conjugate-gradient iterations of the co-Kriging system (exact mode, ``noise_cov``).
    drift_coef_ : ndarray of shape (n_drift_terms, n_targets)
        Generalised-least-squares drift coefficients (exact mode), in positions mapped to
        [-1, 1] over the training bounding box.
    mean_ : ndarray of shape (n_targets,)
        ``drift_coef_[0]``: the GLS mean or the drift at the field's centre (local mode:
        the targets' mean over the stars).
    dual_coef_ : ndarray of shape (n_stars, n_targets)
        ``C_t^-1 (y_t - F drift_coef_t)`` with ``C_t`` the covariance of the stars
        normalised by the sill (exact mode only).
    n_features_in_ : int
        Number of features seen during fit.

    Notes
    -----
    Exact mode solves simple Kriging with the generalised-least-squares drift (for bounded
    variograms, the bordered system of ordinary/universal Kriging); the stars' covariance
    normalised by the sill is ``C_t = (1 - nugget) rho(h / a)`` off the diagonal and
    ``1 + noise_var_t / sill_t`` on it (``GaussianProcessRegressor(alpha=noise_var)``'s
    model). Predictions are of the noise-free field. Without noise a query exactly on a star
    returns that star's value (standard deviation 0) even with a nugget; with ``nugget = 0``
    stars sharing a position are merged with a :class:`DuplicateStarsWarning` (values
    averaged, inverse-variance weighted). The fitted range is bounded below by the stars'
    spacing (``range_floor_``); at that floor the nugget is fitted too and a
    :class:`ShortRangeWarning` issued. Fewer than 5 distinct stars give a
    :class:`FewStarsWarning`; maximum likelihood needs 10. Maximum likelihood with
    ``likelihood="exact"`` matches ``GaussianProcessRegressor(kernel=ConstantKernel() *
    Matern(nu=0.5) + WhiteKernel())`` on ``y - mean_``. Co-Kriging, the likelihood's
    optimisation and the Kriging variance: :ref:`Kriging in detail <kriging-details>`.

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.interpolate import KrigingRegressor
    >>> rng = np.random.default_rng(0)
    >>> X = rng.uniform(size=(40, 2))
    >>> y = np.column_stack([np.sin(4 * X[:, 0]), X[:, 1] ** 2])
    >>> reg = KrigingRegressor(range=0.5).fit(X, y)
    >>> pred, std = reg.predict(X[:2], return_std=True)
    >>> bool(np.allclose(pred, y[:2])), bool(np.allclose(std, 0))
    (True, True)

    Noisy stars, hyperparameters by maximum likelihood, a linear drift:

    >>> noise_var = np.full(40, 1e-4)
    >>> y_obs = y + rng.normal(scale=1e-2, size=y.shape)
    >>> reg = KrigingRegressor(range="auto", nugget="auto", drift="linear")
    >>> reg = reg.fit(X, y_obs, noise_var=noise_var)
    >>> bool(reg.range_ > 0), reg.sill_.shape
    (True, (2,))
    >>> loo_pred, loo_std = reg.loo_predict(return_std=True)
    >>> loo_pred.shape
    (40, 2)

    Co-Kriging of two targets whose noise is correlated (0.8) star by star:

    >>> cov = np.array([[1.0, 0.8], [0.8, 1.0]]) * 1e-4 * rng.uniform(0.5, 2.0, (40, 1, 1))
    >>> reg = KrigingRegressor(range="auto").fit(X, y_obs, noise_cov=cov)
    >>> reg.coregionalization_.shape, reg.predict(X[:3]).shape
    ((2, 2), (3, 2))

    Local Kriging from the 20 nearest stars of each query:

    >>> local = KrigingRegressor(range=0.5, n_neighbors=20).fit(X, y)
    >>> bool(np.allclose(local.predict(X[:2]), y[:2]))
    True
    """

    _parameter_constraints: dict = {
        "variogram": [StrOptions(set(variogram_models))],
        "range": [Interval(Real, 0, np.inf, closed="neither"), StrOptions({"auto"})],
        "nugget": [Interval(Real, 0, 1, closed="both"), StrOptions({"auto"})],
        "n_neighbors": [Interval(Integral, 1, None, closed="left"), StrOptions({"auto"}),
                        None],
        "noise_scale": [Interval(Real, 0, np.inf, closed="neither"), StrOptions({"auto"})],
        "drift": [StrOptions({"linear", "quadratic", "auto"}), None],
        "anisotropy_scaling": [Interval(Real, 0, np.inf, closed="neither"),
                               StrOptions({"auto"})],
        "anisotropy_angle": [Interval(Real, -np.inf, np.inf, closed="neither"),
                             StrOptions({"auto"})],
        "extra_scaling": [Interval(Real, 0, np.inf, closed="neither"), "array-like",
                          StrOptions({"auto"})],
        "extra_drift": [StrOptions({"linear", "quadratic"}), None],
        "likelihood": [StrOptions({"auto", "exact"}), Interval(Integral, 1, None, closed="left")],
        "max_ml_samples": [Interval(Integral, _MIN_ML_STARS, None, closed="left")],
        "random_state": ["random_state"],
        "warm_start": ["boolean"],
    }

    def __init__(self, variogram="exponential", range=0.5, nugget=0.0, n_neighbors=None, *,
                 noise_scale=1.0, drift=None, anisotropy_scaling=1.0, anisotropy_angle=0.0,
                 extra_scaling=1.0, extra_drift=None, likelihood="auto",
                 max_ml_samples=20000, random_state=0, warm_start=False):
        self.variogram = variogram
        self.range = range
        self.nugget = nugget
        self.n_neighbors = n_neighbors
        self.noise_scale = noise_scale
        self.drift = drift
        self.anisotropy_scaling = anisotropy_scaling
        self.anisotropy_angle = anisotropy_angle
        self.extra_scaling = extra_scaling
        self.extra_drift = extra_drift
        self.likelihood = likelihood
        self.max_ml_samples = max_ml_samples
        self.random_state = random_state
        self.warm_start = warm_start

    # ------------------------------------------------------------------ geometry
    def _correlation(self, D):
        """(1 - nugget) rho(D / a), overwriting D (a fresh distance matrix)."""
        return correlation(D, self.variogram, self.range_, self.nugget_)

    def _transform(self, X):
        """Positions in the anisotropy frame (PyKrige's: rotate by -angle, stretch y), the
        extra features multiplied by their factors."""
        return transform(X, self._aniso, self._extra)

    def _drift_design(self, X):
        return drift_design(X, self._drift_center, self._drift_half_width, self._drift_powers)

    def _check_params(self, n_features):
        _check_param(self.range, "range", 0, np.inf, lo_open=True)
        _check_param(self.nugget, "nugget", 0, 1)
        _check_param(self.noise_scale, "noise_scale", 0, np.inf, lo_open=True)
        _check_param(self.anisotropy_scaling, "anisotropy_scaling", 0, np.inf, lo_open=True)
        _check_param(self.anisotropy_angle, "anisotropy_angle", -np.inf, np.inf)
        self._extra_factors(n_features)
        if isinstance(self.max_ml_samples, bool) or not isinstance(
            self.max_ml_samples, numbers.Integral
        ) or self.max_ml_samples < _MIN_ML_STARS:
            raise ValueError(
                f"{_NAME}: max_ml_samples must be an integer >= {_MIN_ML_STARS}, got "
                f"{self.max_ml_samples!r}."
            )
        lik = self.likelihood
        if not (isinstance(lik, str) and lik in ("auto", "exact")) and (
                isinstance(lik, (bool, str)) or not isinstance(lik, numbers.Integral)
                or lik < 1):
            raise ValueError(f"{_NAME}: likelihood must be 'auto', 'exact' or a number of "
                             f"neighbours >= 1, got {lik!r}.")
        aniso = (self.anisotropy_scaling, self.anisotropy_angle)
        if not isinstance(lik, str) and any(isinstance(v, str) for v in aniso):
            raise ValueError(f"{_NAME}: Vecchia's likelihood (likelihood={lik}) needs a fixed "
                             "anisotropy; use likelihood='exact' to fit it.")
        if aniso != (1.0, 0.0) and n_features != 2:
            raise ValueError(f"{_NAME}: anisotropy needs 2 features (x, y), got {n_features}.")

    def _extra_factors(self, n_features):
        """The fixed factors on the extra features (n_features - 2,), or "auto"."""
        value, n_extra = self.extra_scaling, max(n_features - 2, 0)
        if isinstance(value, str) and value == "auto":
            return value
        try:
            factors = np.broadcast_to(np.asarray(value, dtype=np.float64), (n_extra,))
        except (TypeError, ValueError):
            factors = None
        if factors is None or isinstance(value, (bool, str)) or not (
                np.all(np.isfinite(factors)) and np.all(factors > 0)):
            raise ValueError(f"{_NAME}: extra_scaling must be 'auto', a positive number or "
                             f"{n_extra} positive numbers (one per feature beyond the first "
                             f"two), got {value!r}.")
        return factors.copy()

    # ------------------------------------------------------------------ fit
    _joint_noise = True  # fit(noise_cov=...) is co-Kriging

    def _resolve_drift(self, X, Z, noise, previous, center, half_width):
        """The drift, the extra features' factors its fit holds (or None) and the start of
        that fit (None: from the grid): ``drift``, with the previous fit's start under
        ``warm_start``; ``"auto"``: None when no hyperparameter is fitted by maximum
        likelihood, the previous fit's drift under ``warm_start``, else
        :meth:`_choose_drift`'s."""
        start = None if previous is None else previous["ml"]
        if self.drift != "auto":
            return self.drift, None, start
        ml = any(isinstance(v, str) for v in (self.range, self.nugget, self.anisotropy_scaling,
                                               self.anisotropy_angle)) or (
            noise is not None and isinstance(self.noise_scale, str))
        if not ml:  # nothing fitted: ordinary Kriging
            return None, None, start
        if previous is not None:
            return previous["drift"], None, start
        drift, candidate, held = self._choose_drift(X, Z, noise, center, half_width)
        return drift, held, None if candidate is None else candidate.as_start()

    def _fit(self, X, Y, noise, noise_cov=None):
        self._check_params(X.shape[1])
        previous = getattr(self, "_warm", None) if self.warm_start else None
        if previous is not None and previous["n_features"] != X.shape[1]:
            previous = None
        self._set_fitted({})  # a previous fit's large arrays go first
        if self.nugget == 0:
            X, Y, noise, *cov = _merge_duplicates(
                X, Y, owner=_NAME, noise=noise, noise_cov=noise_cov,
                reason="with nugget=0 the Kriging system would be singular.",
            )
            noise_cov = cov[0] if cov else None
        n, d = X.shape
        lo, hi = X.min(axis=0), X.max(axis=0)
        center, half = (lo + hi) / 2.0, (hi - lo) / 2.0
        half_width = np.where(half > 0, half, 1.0)
        # co-Kriging: the targets are solved in the frame z = y A where they are nearly
        # independent (see _kriging_co); otherwise that frame is the identity
        frame, Z, noise_z = None, Y, None
        if noise_cov is not None:
            A, A_inv, noise_z = coregionalization_frame(Y, noise_cov)
            frame, Z = (A, A_inv), Y @ A
            noise = np.einsum("itt->it", noise_z).copy()
        restored = self._held_state_once()
        if restored is None:
            drift, held, start = self._resolve_drift(X, Z, noise, previous, center, half_width)
        else:
            drift, held, start = restored["drift_"], None, None
        powers = drift_powers(d, drift, self.extra_drift)
        n_drift = powers.shape[0]
        _check_n_samples(_NAME, n, max(2, n_drift + 1), "(distinct positions)")
        if n < _FEW_STARS:
            warnings.warn(
                f"{_NAME}: only {n} distinct stars; the sill (variance of the values) and "
                "the Kriging variances mean little. Use more stars or a constant model.",
                FewStarsWarning, stacklevel=3,
            )
        if isinstance(self.n_neighbors, str) and self.n_neighbors == "auto":
            k = None if n <= _AUTO_EXACT_STARS else _AUTO_NEIGHBORS
        else:
            k = _check_n_neighbors(_NAME, self.n_neighbors)
        if k is not None and k >= n:
            k = None  # neighbourhoods of all the stars: exact Kriging (the same system)
        F = drift_design(X, center, half_width, powers)
        if restored is None:
            hyper = self._fit_hyperparameters(X, Z, F, noise, start, drift=drift,
                                              held_extra=held)
            log_likelihood = hyper.log_likelihood
            if frame is not None and log_likelihood is not None:
                # the likelihood of y = z A^-1: the Jacobian of the frame, n log |det A|
                log_likelihood += n * np.linalg.slogdet(frame[0])[1]
        else:
            hyper = self._held_hyperparameters(restored)
            log_likelihood = restored["log_likelihood_"]
        aniso, extra = geometry(hyper.scaling, hyper.angle, hyper.extra)
        U = transform(X, aniso, extra)
        noise_fit = None if noise is None else noise * hyper.noise_scale
        groups = noise_groups(noise_fit, hyper.sill, Y.shape[1])
        state = {
            "_started_from": previous, "drift_": drift, "n_neighbors_": k,
            "_warm": {"n_features": d, "drift": drift,
                      "ml": None if log_likelihood is None else hyper.as_start()},
            "range_": hyper.range, "nugget_": hyper.nugget, "sill_": hyper.sill,
            "noise_scale_": hyper.noise_scale, "anisotropy_scaling_": hyper.scaling,
            "anisotropy_angle_": hyper.angle, "extra_scaling_": hyper.extra,
            "_aniso": aniso, "_extra": extra, "log_likelihood_": log_likelihood,
            "likelihood_": hyper.likelihood, "range_floor_": hyper.range_floor,
            "range_at_floor_": hyper.range_at_floor,
            "_drift_center": center, "_drift_half_width": half_width, "_drift_powers": powers,
            "_frame": frame, "X_fit_": X, "y_fit_": Y, "_U_fit": U, "_F_fit": F, "_z_fit": Z,
            "_sill_fit": hyper.sill, "_noise_fit": noise_fit, "noise_var_": noise_fit,
            "noise_cov_": None, "coregionalization_": np.diag(hyper.sill),
            "_noise_ratio_groups": groups.ratios, "_group_targets": groups.targets,
            "_group_of": groups.of,
        }
        if hyper.ml_size is not None:
            state["_ml_size"] = hyper.ml_size
        if noise_cov is not None:
            A_inv = frame[1]
            state["noise_cov_"] = noise_cov * hyper.noise_scale
            state["noise_var_"] = np.einsum("itt->it", state["noise_cov_"]).copy()
            state["coregionalization_"] = (A_inv.T * hyper.sill) @ A_inv
            state["sill_"] = np.diag(state["coregionalization_"]).copy()
        if k is not None:
            local = fit_local(U, Y, k, n_drift, drift)
            state.update(mean_=local.mean, _k=local.k, _tree=local.tree)
        else:
            corr = functools.partial(correlation, variogram=self.variogram,
                                     range_=hyper.range, nugget=hyper.nugget)
            solve, C0 = fit_exact(U, Z, F, corr, groups, keep_covariance=noise_cov is not None)
            if noise_cov is not None:
                solve = fit_coupled(solve, C0, Z, F, noise_z * hyper.noise_scale, hyper.sill,
                                    groups, frame[1])
                state.update(_dual_independent=solve.dual_independent,
                             n_cg_iter_=solve.n_cg_iter)
            state.update(_factors=solve.factors, dual_coef_=solve.dual_coef,
                         drift_coef_=solve.drift_coef, mean_=solve.drift_coef[0].copy())
        self._set_fitted(state)

    # ------------------------------------------------------------------ predict
    def _solve(self):
        """The fitted system, from the attributes: a :class:`LocalSolve` in local mode, an
        :class:`ExactSolve` in exact mode."""
        if self.n_neighbors_ is not None:
            return LocalSolve(self._tree, self._k, self.mean_)
        if self._frame is None:
            return ExactSolve(self._factors, self.dual_coef_, self.drift_coef_)
        return ExactSolve(self._factors, self.dual_coef_, self.drift_coef_,
                          self._dual_independent, self.n_cg_iter_)

    def _groups(self):
        return NoiseGroups(self._noise_ratio_groups, self._group_targets, self._group_of)

    def predict(self, X, return_std=False):
        """Kriging prediction, and optionally its standard deviation.

        Parameters
        ----------
        X : array-like of shape (n_queries, n_features)
            Query positions.
        return_std : bool, default=False
            Also return the Kriging standard deviation of each target (of the noise-free
            field; the nugget is part of the field).

        Returns
        -------
        y_pred : ndarray of shape (n_queries,) or (n_queries, n_targets)
            Predictions, 1-D when fitted on a 1-D ``y``.
        y_std : ndarray, same shape as ``y_pred``
            Kriging standard deviation (only with ``return_std=True``).
        """
        X = self._validate_predict_data(X)
        U, Fq = self._transform(X), self._drift_design(X)
        solve = self._solve()
        if isinstance(solve, LocalSolve):
            pred, var = predict_local(solve, (self._U_fit, self._z_fit, self._F_fit),
                                      self._correlation, self._groups(), U, Fq, return_std)
            if self._frame is not None:
                pred = pred @ self._frame[1]
        else:
            pred, var = predict_exact(solve, self._U_fit, self._correlation, self._groups(),
                                      U, Fq, return_std)
        pred = self._format_output(pred)
        if not return_std:
            return pred
        return pred, self._format_output(np.sqrt(self._to_targets(
            np.clip(var[:, self._group_of], 0.0, None) * self._sill_fit)))

    def _to_targets(self, var):
        """Variances of the frame's independent targets -> variances of the targets."""
        return var if self._frame is None else var @ self._frame[1] ** 2

    def loo_predict(self, return_std=False):
        """Leave-one-out predictions at the stars, in closed form.

        The prediction of star ``i`` from all the others with the fitted
        hyperparameters. Exact mode: ``y_i - [A^-1 b]_i / [A^-1]_ii`` with ``A`` the
        bordered Kriging system (Dubrule 1983), one triangular inversion per
        factorisation. Local mode: local Kriging of the star from its ``n_neighbors``
        nearest other stars. With ``noise_cov`` (co-Kriging) it is that of the independent
        targets of the frame the system is solved in (the off-diagonal noise of that frame
        left out).

        Parameters
        ----------
        return_std : bool, default=False
            Also return the standard deviation of ``y_i - prediction``: the Kriging
            variance at the star plus its own measurement noise.

        Returns
        -------
        y_loo : ndarray of shape (n_stars,) or (n_stars, n_targets)
            Predictions at the rows of ``X_fit_`` (the stars given to :meth:`fit`, less
            merged duplicates).
        y_std : ndarray, same shape as ``y_loo``
            Standard deviation of the leave-one-out residuals (only with
            ``return_std=True``); divide the residuals by it for a chi statistic.
        """
        check_is_fitted(self)
        solve = self._solve()
        if isinstance(solve, LocalSolve):
            n = self._U_fit.shape[0]  # (more stars than neighbours in local mode)
            pred, var = predict_local(solve, (self._U_fit, self._z_fit, self._F_fit),
                                      self._correlation, self._groups(), self._U_fit,
                                      self._F_fit, return_std, leave_out=np.arange(n))
            if return_std:  # the star's own noise adds to the Kriging variance
                var = np.clip(var[:, self._group_of], 0.0, None)
                if self._noise_fit is not None:
                    var = var + self._noise_fit / np.where(self._sill_fit > 0,
                                                           self._sill_fit, np.inf)
                var = var * self._sill_fit
        else:
            pred, var = loo_exact(solve, self._z_fit, self._groups(), self._sill_fit)
        if self._frame is not None:
            pred = pred @ self._frame[1]
        pred = self._format_output(pred)
        if not return_std:
            return pred
        return pred, self._format_output(np.sqrt(self._to_targets(var)))

    def _predict(self, X):  # pragma: no cover - predict is overridden
        raise NotImplementedError

    # ------------------------------------------------------------------ persistence
    # (the protocol of sklearn_psf._persist: the state is what the fit chose, the drift and
    # the hyperparameters; restored, the next fit solves the Kriging system with them held,
    # without the likelihood)
    def _get_state(self):
        check_is_fitted(self)
        ll, floor = self.log_likelihood_, self.range_floor_
        return {"drift_": self.drift_, "range_": float(self.range_),
                "nugget_": float(self.nugget_), "sill": np.asarray(self._sill_fit, float),
                "noise_scale_": float(self.noise_scale_),
                "anisotropy_scaling_": float(self.anisotropy_scaling_),
                "anisotropy_angle_": float(self.anisotropy_angle_),
                "extra_scaling_": np.asarray(self.extra_scaling_, float),
                "log_likelihood_": None if ll is None else float(ll),
                "likelihood_": self.likelihood_,
                "range_floor_": None if floor is None else float(floor),
                "range_at_floor_": bool(self.range_at_floor_)}

    @staticmethod
    def _held_hyperparameters(held):
        """The :class:`Hyperparameters` of a restored state (its likelihood set by ``_fit``)."""
        floor = held["range_floor_"]
        return Hyperparameters(
            range=float(held["range_"]), nugget=float(held["nugget_"]),
            sill=np.asarray(held["sill"], dtype=np.float64),
            noise_scale=float(held["noise_scale_"]),
            scaling=float(held["anisotropy_scaling_"]), angle=float(held["anisotropy_angle_"]),
            extra=np.asarray(held["extra_scaling_"], dtype=np.float64),
            likelihood=held["likelihood_"], range_floor=None if floor is None else float(floor),
            range_at_floor=bool(held["range_at_floor_"]))
