"""The hyperparameters of :class:`~sklearn_psf.interpolate.KrigingRegressor` by maximum
likelihood, the estimator's side of it: which likelihood (exact or Vecchia's) on how many
stars, ``drift="auto"``'s choice of the drift by the Bayesian information criterion, the
factors on the extra features (``extra_scaling="auto"``), the range's floor at the stars'
spacing, and the warm start's state. They live on :class:`_KrigingHyperparameters`, a mixin
that ``KrigingRegressor`` inherits; the likelihood itself and its optimiser are in
``_kriging_ml``, the Kriging systems in ``_kriging_exact`` and ``_kriging_local``."""

from __future__ import annotations

import warnings

import numpy as np
from scipy.spatial import cKDTree
from sklearn.utils import check_random_state

from ._base import ShortRangeWarning, _check_n_samples
from ._kriging_ml import fit_hyperparameters
from ._kriging_vecchia import position_order

_DRIFT_DEGREE = {None: 0, "linear": 1, "quadratic": 2}
#: maximum likelihood needs at least this many stars
_MIN_ML_STARS = 10
#: likelihood="auto": the exact likelihood when (factorisations per step) x n^3 is at most
#: this (~0.005 s per step on one core; 460 stars with one noise pattern, 320 with three,
#: 250 with six); beyond, an exact step of ~390 stars costs ~3.5 of Vecchia's per target and
#: L-BFGS-B takes ~2x as many steps as Vecchia's quasi-Newton
_EXACT_ML_COST = 1e8
#: extra_scaling="auto": the factors by the exact likelihood of at most
#: (this / factorisations per step)^(1/3) stars (200 with one noise pattern, 117 with five)
_EXTRA_ML_COST = 8e6
#: and to a gradient of this per star (far below the factors' statistical error)
_EXTRA_GTOL = 1e-4
#: and keeps a finite correlation length along an extra dimension only when it raises the
#: log-likelihood by this much over none (a likelihood-ratio test at ~5% for one parameter)
_EXTRA_LR_MIN = 2.0
#: likelihood="auto" beyond that: Vecchia's approximation with this many neighbours
_VECCHIA_NEIGHBORS = 10

_NAME = "KrigingRegressor"
#: drift="auto" compares the drifts by Vecchia's likelihood of at most this many stars
_DRIFT_ML_STARS = 400


def _spacing(P):
    """Median distance from a star to its nearest neighbour (0 for a single star)."""
    if len(P) < 2:
        return 0.0
    dist, _ = cKDTree(P).query(P, k=2)
    return float(np.median(dist[:, 1]))


class _KrigingHyperparameters:
    """The hyperparameters' maximum-likelihood fit of :class:`KrigingRegressor` (a mixin:
    it reads the estimator's parameters and sets its fitted attributes)."""

    def _choose_drift(self, X, Y, noise):
        """``drift="auto"``: the drift (None, "linear", "quadratic") of the smallest Bayesian
        information criterion of the maximum likelihood, each candidate's hyperparameters
        fitted in turn by Vecchia's likelihood on at most ``_DRIFT_ML_STARS`` stars (cheap;
        the caller then fits the chosen drift's as ``likelihood`` says, starting from the
        candidate's hyperparameters, returned third). Factors on extra features fitted by
        the first candidate are held by the others (their fit is the costly one); those
        factors are returned with the drift when it is that candidate (else None)."""
        n, best, first = X.shape[0], (np.inf, None, None), None
        self._quick_ml, previous = True, None
        try:
            for k, drift in enumerate(_DRIFT_DEGREE):
                self.drift_ = drift
                self._drift_powers = self._drift_powers_for(X.shape[1])
                m = self._drift_powers.shape[0]
                if n < max(_MIN_ML_STARS, 2 * m + 1):
                    break
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")  # the chosen drift's fit warns again
                    # (each candidate from the previous one's optimum: fewer steps)
                    self._fit_hyperparameters(X, Y, self._drift_design(X), noise, previous)
                previous = self._ml_result()
                bic = m * Y.shape[1] * np.log(self._ml_size) - 2.0 * self.log_likelihood_
                if bic < best[0]:
                    best = (bic, drift, previous)
                if k == 0 and X.shape[1] > 2:
                    first = self._held_extra = self.extra_scaling_.copy()
        finally:
            self._quick_ml, self._held_extra = False, None
        return (best[1], (first if best[1] == next(iter(_DRIFT_DEGREE)) else None),
                best[2])

    def _start_state(self):
        """What this fit started from with ``warm_start`` (JSON-able; None for a fit from
        the grid): a model file stores it so that loading repeats the same fit exactly."""
        state = getattr(self, "_started_from", None)
        if state is None:
            return None
        ml = state["ml"]
        return {"n_features": int(state["n_features"]), "drift": state["drift"],
                "ml": None if ml is None else {
                    key: (np.asarray(v, dtype=float).tolist() if key in ("sill", "extra")
                          else float(v)) for key, v in ml.items()}}

    def _set_start_state(self, state):
        """Make the next fit start from ``state`` (of :meth:`_start_state`)."""
        self._warm = dict(state)
        if state.get("ml") is not None:
            self._warm["ml"] = {**state["ml"], "sill": np.asarray(state["ml"]["sill"])}
        self.warm_start = True

    def _ml_result(self):
        """The fitted hyperparameters as a ``start`` of :func:`fit_hyperparameters` (sills of
        the targets the likelihood saw: the co-Kriging frame's)."""
        return {"range": self.range_, "nugget": self.nugget_, "sill": self.sill_,
                "noise_scale": self.noise_scale_, "scaling": self.anisotropy_scaling_,
                "angle": self.anisotropy_angle_, "extra": list(self.extra_scaling_)}

    def _fit_hyperparameters(self, X, Y, F, noise, start=None):
        params = {"range_": self.range, "nugget": self.nugget, "noise_scale": self.noise_scale,
                  "scaling": self.anisotropy_scaling, "angle": self.anisotropy_angle}
        extra = getattr(self, "_held_extra", None)
        if extra is None:
            extra = self._extra_factors(X.shape[1])
        extra_free = isinstance(extra, str) and X.shape[1] > 2
        auto = [k for k, v in params.items() if isinstance(v, str)] + ["extra"] * extra_free
        if noise is None and "noise_scale" in auto:
            auto.remove("noise_scale")
        fixed_extra = None if isinstance(extra, str) else extra
        self.log_likelihood_ = self.likelihood_ = self.range_floor_ = None
        self.range_at_floor_ = False
        if extra_free:  # the extra factors first, then the rest as with fixed factors
            _check_n_samples(_NAME, X.shape[0], _MIN_ML_STARS, "to fit hyperparameters by "
                             "maximum likelihood (distinct positions)")
            fixed_extra = self._fit_extra_factors(X, Y, F, noise, params, auto, start)
            extra_free = False
            auto.remove("extra")
        if not auto:
            self._set_anisotropy(self.anisotropy_scaling, self.anisotropy_angle, fixed_extra)
            self.range_, self.nugget_ = float(self.range), float(self.nugget)
            self.sill_ = Y.var(axis=0)
            self.noise_scale_ = 1.0 if self.noise_scale == "auto" else float(self.noise_scale)
            return
        n = X.shape[0]
        _check_n_samples(_NAME, n, _MIN_ML_STARS, "to fit hyperparameters by maximum "
                         "likelihood (distinct positions)")
        geometry_free = "scaling" in auto or "angle" in auto or extra_free
        neighbors, size = self._ml_plan(n, 1 if noise is None else Y.shape[1],
                                        geometry_free)
        rng = np.random.default_rng(check_random_state(self.random_state).randint(2**31))
        sub = np.arange(n)
        if n > size:
            sub = np.sort(position_order(X, int(rng.integers(2**63)))[:size])
        if not geometry_free:
            self._set_anisotropy(self.anisotropy_scaling, self.anisotropy_angle, fixed_extra)
        P = X[sub] if geometry_free else self._transform(X[sub])
        noise_sub = None if noise is None else noise[sub]
        self._ml_size = len(sub)
        if "range_" in auto:  # (with the extra factors fitted: the positions' spacing)
            self.range_floor_ = _spacing(X[:, :2] if extra_free else
                                         X if geometry_free else self._transform(X))
        params["extra"] = "auto" if extra_free else None
        fit = fit_hyperparameters(P, Y[sub], F[sub], noise_sub, self.variogram,
                                  neighbors=neighbors, rng=rng, start=start,
                                  range_floor=self.range_floor_, **params)
        if self.range_floor_ is not None and fit["range"] <= self.range_floor_ * (1 + 1e-6):
            # no correlation the stars can resolve: the white part goes to a nugget, so that
            # the field between the stars is smooth (not spots of one spacing at each star)
            self.range_at_floor_ = True
            if not isinstance(self.nugget, str):
                # the nugget from the previous fit's (warm start), else from 0.1: from 0 (its
                # lower bound, where the likelihood is flat in its log) the steps stall
                nugget0 = start["nugget"] if start and 0 < start["nugget"] < 1 else 0.1
                fit = fit_hyperparameters(P, Y[sub], F[sub], noise_sub, self.variogram,
                                          neighbors=neighbors, rng=rng,
                                          start={**fit, "nugget": nugget0},
                                          range_floor=self.range_floor_,
                                          **{**params, "nugget": "auto"})
            if fit["range"] <= self.range_floor_ * (1 + 1e-6):
                # still no correlation beyond the spacing: all the signal is white, the
                # field is its (generalised-least-squares) mean
                fit["nugget"] = 1.0
            if not (self.drift == "auto" and self.drift_ is not None):
                # (a drift chosen by the likelihood that leaves only white noise: the field
                # is that polynomial, a model in its own right, not a warning)
                warnings.warn(
                    f"{_NAME}: maximum likelihood finds no spatial correlation at the stars' "
                    f"spacing (the range fell to its floor, the median distance to the nearest "
                    f"star, {self.range_floor_:.3g}); with the nugget fitted "
                    f"({fit['nugget']:.2f} of the sill, range {fit['range']:.3g}) the field is "
                    "predicted smooth, close to its mean. More stars, or a constant model, may "
                    "serve as well.", ShortRangeWarning, stacklevel=4)
        self.likelihood_ = "exact" if neighbors is None else "vecchia"
        self._set_anisotropy(fit["scaling"], fit["angle"],
                             fit["extra"] if extra_free else fixed_extra)
        self.range_, self.nugget_, self.sill_ = fit["range"], fit["nugget"], fit["sill"]
        self.noise_scale_, self.log_likelihood_ = fit["noise_scale"], fit["log_likelihood"]

    def _fit_extra_factors(self, X, Y, F, noise, params, auto, start=None):
        """The factors on the extra features by the exact likelihood of a subset of the stars
        (the other "auto" hyperparameters fitted along with them, then refitted on all the
        stars with the factors held)."""
        n, n_factors = X.shape[0], 1 if noise is None else Y.shape[1]
        size = min(n, max(_MIN_ML_STARS, int((_EXTRA_ML_COST / n_factors) ** (1 / 3))))
        seed = check_random_state(self.random_state).randint(2**31)
        sub = np.arange(n)
        if n > size:
            rng = np.random.default_rng([seed, 1])
            sub = np.sort(position_order(X, int(rng.integers(2**63)))[:size])
        floor = _spacing(X[sub, :2]) if "range_" in auto else None
        P, Ys, Fs = X[sub], Y[sub], F[sub]
        Ns = None if noise is None else noise[sub]
        fit = fit_hyperparameters(P, Ys, Fs, Ns, self.variogram, range_floor=floor,
                                  gtol=_EXTRA_GTOL, start=start, **{**params, "extra": "auto"})
        factors = np.asarray(fit["extra"])
        # a dimension whose correlation length the likelihood does not need (less than
        # _EXTRA_LR_MIN better than with no correlation along it) gets none: on a subset of
        # the stars, noise alone shortens lengths that would otherwise decorrelate the stars
        span = np.ptp(P[:, :2], axis=0).max() if len(P) > 1 else 1.0
        spans = np.ptp(P[:, 2:], axis=0)
        lowest = 1e-3 * np.where(spans > 0, span / np.where(spans > 0, spans, 1.0), 1.0)
        for j in np.flatnonzero(factors > lowest * (1 + 1e-3)):
            trial = factors.copy()
            trial[j] = lowest[j]
            U = P.copy()
            U[:, 2:] *= trial
            fixed = {**params, "extra": None, "scaling": 1.0, "angle": 0.0}
            alt = fit_hyperparameters(U, Ys, Fs, Ns, self.variogram, range_floor=floor,
                                      gtol=_EXTRA_GTOL, start=fit, **fixed)
            if fit["log_likelihood"] - alt["log_likelihood"] < _EXTRA_LR_MIN:
                factors = trial
        return factors

    def _ml_plan(self, n, n_factors, geometry_free):
        """Vecchia neighbours (None: exact likelihood) and the number of stars to use."""
        size = min(n, int(self.max_ml_samples))
        if getattr(self, "_quick_ml", False) and not geometry_free:
            size = min(size, _DRIFT_ML_STARS)  # drift="auto"'s candidates
        if self.likelihood == "exact":
            return None, size
        if not isinstance(self.likelihood, str):
            return int(self.likelihood), size
        if n_factors * float(size) ** 3 <= _EXACT_ML_COST:
            if getattr(self, "_quick_ml", False) and not geometry_free:
                return _VECCHIA_NEIGHBORS, size  # drift="auto"'s candidates: cheaper
            return None, size
        if geometry_free:  # exact on the largest subset that keeps it cheap
            return None, max(_MIN_ML_STARS, int((_EXACT_ML_COST / n_factors) ** (1 / 3)))
        return _VECCHIA_NEIGHBORS, size
