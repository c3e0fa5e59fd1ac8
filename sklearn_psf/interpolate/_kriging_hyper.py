"""The hyperparameters of :class:`~sklearn_psf.interpolate.KrigingRegressor` by maximum
likelihood, the estimator's side of it: which likelihood (exact or Vecchia's) on how many
stars, ``drift="auto"``'s choice of the drift by the Bayesian information criterion, the
factors on the extra features (``extra_scaling="auto"``), the range's floor at the stars'
spacing, and the warm start's state. They live on :class:`_KrigingHyperparameters`, a mixin
that ``KrigingRegressor`` inherits, whose fits return a :class:`Hyperparameters` (they set
nothing on the estimator); with them, the drift's design and the anisotropy frame as plain
functions. The likelihood itself and its optimiser are in ``_kriging_ml``, the Kriging
systems in ``_kriging_exact`` and ``_kriging_local``."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
from scipy.spatial import cKDTree
from sklearn.utils import check_random_state

from ._base import ShortRangeWarning, _check_n_samples
from ._kriging_ml import fit_hyperparameters
from ._kriging_vecchia import position_order
from ._polynomial import _design, _exponents

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


def drift_powers(d, drift, extra_drift):
    """Drift exponents (q, d) in ``d`` features: ``drift``'s polynomial in all features, plus
    with ``extra_drift`` the linear (``"quadratic"``: and squared) terms of the features beyond
    the first two (and then a quadratic drift in the first two only)."""
    degree = _DRIFT_DEGREE[drift]
    if extra_drift in ("linear", "quadratic") and d > 2 and degree > 1:
        powers = np.pad(_exponents(2, degree), ((0, 0), (0, d - 2)))
    else:
        powers = _exponents(d, degree)
    if extra_drift in ("linear", "quadratic") and d > 2:
        units = np.eye(d, dtype=int)[2:]
        if extra_drift == "quadratic":
            units = np.vstack([units, 2 * units])
        new = [u for u in units if not (powers == u).all(axis=1).any()]
        powers = np.vstack([powers] + new) if new else powers
    return powers


def drift_design(X, center, half_width, powers):
    """Drift design rows of ``X``: monomials ``powers`` of the positions mapped to [-1, 1]
    over the training bounding box (``center``, ``half_width``)."""
    U = (X - center) / half_width
    return _design(U, powers, max(1, int(powers.max(initial=0))), "monomial")


def geometry(scaling, angle, extra):
    """The anisotropy matrix (2, 2), None when isotropic, and the factors on the extra
    features, None when all 1 (PyKrige's frame: rotate by -angle, stretch y)."""
    aniso = None
    if scaling != 1.0 or angle % 360.0 != 0.0:
        t = np.deg2rad(angle)
        rot = np.array([[np.cos(t), np.sin(t)], [-np.sin(t), np.cos(t)]])
        aniso = np.diag([1.0, scaling]) @ rot
    return aniso, (extra if (extra != 1.0).any() else None)


def transform(X, aniso, extra):
    """Positions in the anisotropy frame, the extra features multiplied by their factors
    (``aniso`` and ``extra`` of :func:`geometry`)."""
    if aniso is not None:
        return X @ aniso.T
    if extra is not None:
        X = X.copy()
        X[:, 2:] *= extra
    return X


def _extra_array(extra, n_extra):
    return (np.ones(n_extra) if extra is None
            else np.asarray(extra, dtype=np.float64).reshape(n_extra))


@dataclasses.dataclass(frozen=True)
class Hyperparameters:
    """A fit of the hyperparameters: range, nugget (fraction of the sill), sills (of the
    targets the likelihood saw), noise scale, anisotropy (angle in degrees) and factors on
    the extra features (n_features - 2,); with maximum likelihood its maximum, which
    likelihood (``"exact"`` or ``"vecchia"``), the range's floor (None when the range is
    given), whether the range fell to it, and the number of stars it used."""

    range: float
    nugget: float
    sill: np.ndarray
    noise_scale: float
    scaling: float
    angle: float
    extra: np.ndarray
    log_likelihood: float | None = None
    likelihood: str | None = None
    range_floor: float | None = None
    range_at_floor: bool = False
    ml_size: int | None = None

    def as_start(self):
        """As a ``start`` of :func:`fit_hyperparameters`."""
        return {"range": self.range, "nugget": self.nugget, "sill": self.sill,
                "noise_scale": self.noise_scale, "scaling": self.scaling,
                "angle": self.angle, "extra": list(self.extra)}


class _KrigingHyperparameters:
    """The hyperparameters' maximum-likelihood fit of :class:`KrigingRegressor` (a mixin:
    it reads the estimator's parameters; the fits are returned, not set)."""

    def _choose_drift(self, X, Y, noise, center, half_width):
        """``drift="auto"``: the drift (None, "linear", "quadratic") of the smallest Bayesian
        information criterion of the maximum likelihood, each candidate's hyperparameters
        fitted in turn by Vecchia's likelihood on at most ``_DRIFT_ML_STARS`` stars (cheap;
        the caller then fits the chosen drift's as ``likelihood`` says, starting from the
        candidate's :class:`Hyperparameters`, returned second). Factors on extra features
        fitted by the first candidate are held by the others (their fit is the costly one);
        those factors are returned third when the drift is that candidate (else None)."""
        n, best, first, previous = X.shape[0], (np.inf, None, None), None, None
        for k, drift in enumerate(_DRIFT_DEGREE):
            powers = drift_powers(X.shape[1], drift, self.extra_drift)
            m = powers.shape[0]
            if n < max(_MIN_ML_STARS, 2 * m + 1):
                break
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # the chosen drift's fit warns again
                # (each candidate from the previous one's optimum: fewer steps)
                fit = self._fit_hyperparameters(
                    X, Y, drift_design(X, center, half_width, powers), noise, previous,
                    drift=drift, held_extra=first, quick=True)
            previous = fit.as_start()
            bic = m * Y.shape[1] * np.log(fit.ml_size) - 2.0 * fit.log_likelihood
            if bic < best[0]:
                best = (bic, drift, fit)
            if k == 0 and X.shape[1] > 2:
                first = fit.extra.copy()
        return best[1], best[2], (first if best[1] is None else None)

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

    def _fit_hyperparameters(self, X, Y, F, noise, start=None, *, drift, held_extra=None,
                             quick=False):
        """The :class:`Hyperparameters` of values ``Y`` at positions ``X`` with drift design
        ``F``: the given ones, or maximum likelihood's for the ``"auto"`` ones (from
        ``start``, an :meth:`Hyperparameters.as_start`). ``drift``: the drift fitted (one
        that ``drift="auto"`` chose leaves the range at its floor without a warning);
        ``held_extra``: factors on the extra features held instead of ``extra_scaling``;
        ``quick``: a candidate of ``drift="auto"`` (at most ``_DRIFT_ML_STARS`` stars,
        Vecchia's likelihood)."""
        params = {"range_": self.range, "nugget": self.nugget, "noise_scale": self.noise_scale,
                  "scaling": self.anisotropy_scaling, "angle": self.anisotropy_angle}
        n_extra = max(X.shape[1] - 2, 0)
        extra = held_extra
        if extra is None:
            extra = self._extra_factors(X.shape[1])
        extra_free = isinstance(extra, str) and X.shape[1] > 2
        auto = [k for k, v in params.items() if isinstance(v, str)]
        if noise is None and "noise_scale" in auto:
            auto.remove("noise_scale")
        fixed_extra = None if isinstance(extra, str) else extra
        if extra_free:  # the extra factors first, then the rest as with fixed factors
            _check_n_samples(_NAME, X.shape[0], _MIN_ML_STARS, "to fit hyperparameters by "
                             "maximum likelihood (distinct positions)")
            fixed_extra = self._fit_extra_factors(X, Y, F, noise, params, auto + ["extra"],
                                                  start)
        fixed_extra = _extra_array(fixed_extra, n_extra)
        if not auto:
            return Hyperparameters(
                float(self.range), float(self.nugget), Y.var(axis=0),
                1.0 if self.noise_scale == "auto" else float(self.noise_scale),
                float(self.anisotropy_scaling), float(self.anisotropy_angle), fixed_extra)
        n = X.shape[0]
        _check_n_samples(_NAME, n, _MIN_ML_STARS, "to fit hyperparameters by maximum "
                         "likelihood (distinct positions)")
        geometry_free = "scaling" in auto or "angle" in auto
        neighbors, size = self._ml_plan(n, 1 if noise is None else Y.shape[1],
                                        geometry_free, quick)
        rng = np.random.default_rng(check_random_state(self.random_state).randint(2**31))
        sub = np.arange(n)
        if n > size:
            sub = np.sort(position_order(X, int(rng.integers(2**63)))[:size])
        frame = None if geometry_free else geometry(self.anisotropy_scaling,
                                                    self.anisotropy_angle, fixed_extra)
        P = X[sub] if geometry_free else transform(X[sub], *frame)
        noise_sub = None if noise is None else noise[sub]
        # (with the anisotropy fitted: the raw positions' spacing)
        floor = None
        if "range_" in auto:
            floor = _spacing(X if geometry_free else transform(X, *frame))
        params["extra"] = None
        fit = fit_hyperparameters(P, Y[sub], F[sub], noise_sub, self.variogram,
                                  neighbors=neighbors, rng=rng, start=start,
                                  range_floor=floor, **params)
        at_floor = floor is not None and fit["range"] <= floor * (1 + 1e-6)
        if at_floor:
            # no correlation the stars can resolve: the white part goes to a nugget, so that
            # the field between the stars is smooth (not spots of one spacing at each star)
            if not isinstance(self.nugget, str):
                # the nugget from the previous fit's (warm start), else from 0.1: from 0 (its
                # lower bound, where the likelihood is flat in its log) the steps stall
                nugget0 = start["nugget"] if start and 0 < start["nugget"] < 1 else 0.1
                fit = fit_hyperparameters(P, Y[sub], F[sub], noise_sub, self.variogram,
                                          neighbors=neighbors, rng=rng,
                                          start={**fit, "nugget": nugget0}, range_floor=floor,
                                          **{**params, "nugget": "auto"})
            if fit["range"] <= floor * (1 + 1e-6):
                # still no correlation beyond the spacing: all the signal is white, the
                # field is its (generalised-least-squares) mean
                fit["nugget"] = 1.0
            if not (self.drift == "auto" and drift is not None):
                # (a drift chosen by the likelihood that leaves only white noise: the field
                # is that polynomial, a model in its own right, not a warning)
                warnings.warn(
                    f"{_NAME}: maximum likelihood finds no spatial correlation at the stars' "
                    f"spacing (the range fell to its floor, the median distance to the nearest "
                    f"star, {floor:.3g}); with the nugget fitted "
                    f"({fit['nugget']:.2f} of the sill, range {fit['range']:.3g}) the field is "
                    "predicted smooth, close to its mean. More stars, or a constant model, may "
                    "serve as well.", ShortRangeWarning, stacklevel=4)
        return Hyperparameters(
            fit["range"], fit["nugget"], fit["sill"], fit["noise_scale"], float(fit["scaling"]),
            float(fit["angle"]), fixed_extra, log_likelihood=fit["log_likelihood"],
            likelihood="exact" if neighbors is None else "vecchia", range_floor=floor,
            range_at_floor=at_floor, ml_size=len(sub))

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

    def _ml_plan(self, n, n_factors, geometry_free, quick=False):
        """Vecchia neighbours (None: exact likelihood) and the number of stars to use
        (``quick``: for a candidate of ``drift="auto"``)."""
        size = min(n, int(self.max_ml_samples))
        if quick and not geometry_free:
            size = min(size, _DRIFT_ML_STARS)  # drift="auto"'s candidates
        if self.likelihood == "exact":
            return None, size
        if not isinstance(self.likelihood, str):
            return int(self.likelihood), size
        if n_factors * float(size) ** 3 <= _EXACT_ML_COST:
            if quick and not geometry_free:
                return _VECCHIA_NEIGHBORS, size  # drift="auto"'s candidates: cheaper
            return None, size
        if geometry_free:  # exact on the largest subset that keeps it cheap
            return None, max(_MIN_ML_STARS, int((_EXACT_ML_COST / n_factors) ** (1 / 3)))
        return _VECCHIA_NEIGHBORS, size
