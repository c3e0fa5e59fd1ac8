"""The multi-exposure study: sigma_sys^2 of exposure-averaged PSF residuals against N by regime."""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field
from numbers import Integral

import numpy as np
from astropy.table import Table
from joblib import Parallel, delayed
from sklearn.base import clone
from sklearn.frozen import FrozenEstimator
from threadpoolctl import threadpool_limits

from ...measure import adaptive_moments
from ...metrics import ellipticity_correlation, shear_bias_bound, sigma_sys2
from ...model import PerExposurePSFModel, PooledPSFModel, PSFModel
from ...preprocessing import StampPCA
from .._names import ORACLE
from ..compare import FieldOracle

ARCMIN = 60.0  # arcsec per arcmin

#: Default sizes: 10 arcmin chips (3000 x 3000 pixels of 0.2 arcsec) with 1.2 and 2.4 stars
#: per arcmin^2 (the paper's density and twice it) per exposure, 600 galaxy-PSFs in the part of
#: the sky every exposure covers, up to 8 exposures; nine regimes: atmospheric / static
#: variance 0.2, 1, 5 (static 83%, 50%, 17% of the PSF variance) x dithers up to 0, 300, 1000
#: pixels (0, 1, 3.3 arcmin).
DEFAULTS = {"n_exposures": (1, 2, 4, 8), "n_stars": (120, 240), "n_galaxies": 600,
            "image_shape": (3000, 3000), "snr": 100.0, "variance_ratios": (0.2, 1.0, 5.0),
            "dithers": (0.0, 300.0, 1000.0), "theta_bins": (0.3, 3.0, 6)}


class _SharedBasis(FrozenEstimator):
    """A fitted basis that fitting leaves as it is (and cloning keeps): one basis for every
    model of a simulation."""

    def fit(self, X, y=None, *args, **kwargs):
        return self


def default_exposure_schemes(basis=None) -> dict:
    """The multi-exposure schemes: one PSF model per exposure, and the pooled model.

    Both use ``basis``, so that they differ only in how they interpolate: each exposure on
    its own, or all exposures with a static and an atmospheric part
    (:class:`~sklearn_psf.interpolate.ExposureKrigingRegressor`). The study passes one
    :class:`~sklearn_psf.preprocessing.StampPCA` fitted on the stars of all the simulation's
    exposures, frozen (fitting the models leaves it unchanged).

    Parameters
    ----------
    basis : transformer, optional
        Basis of the models (``PSFModel(basis=basis)``); default each model's own
        ``StampPCA()``.

    Returns
    -------
    schemes : dict
        ``{"per-exposure": PerExposurePSFModel(model), "pooled": PooledPSFModel(model)}``
        with ``model = PSFModel(basis=basis)``.

    Examples
    --------
    >>> from sklearn_psf.study.exposures import default_exposure_schemes
    >>> sorted(default_exposure_schemes())
    ['per-exposure', 'pooled']
    """
    model = PSFModel(basis=basis)
    return {"per-exposure": PerExposurePSFModel(model=model),
            "pooled": PooledPSFModel(model=model)}


@dataclass
class ExposureStudyResult:
    """Results of :func:`run_exposure_study`.

    Attributes
    ----------
    scores : astropy.table.Table
        One row per (regime, simulation, n_stars, scheme, n_exposures): ``variance_ratio``
        (atmospheric / static PSF variance), ``dither`` (largest pointing offset, pixels),
        ``simulation``, ``seed``, ``n_stars`` (per exposure), ``scheme``, ``n_exposures``,
        ``e_rms`` (per-exposure residual), ``e_rms_averaged`` (residual averaged over the
        exposures of each galaxy), ``rho_exposures`` (correlation of one galaxy's residuals
        between two of its exposures, NaN for one exposure), ``rho1_mean_abs``,
        ``sigma_sys2`` (of the averaged residual), ``fit_seconds``.
    correlations : astropy.table.Table
        The same rows' ``xi``: Rowe's D1 of the exposure-averaged residual over ``theta``.
    theta : ndarray
        Separations of the correlation bins, arcmin.
    config : dict
    """

    scores: Table
    correlations: Table
    theta: np.ndarray
    config: dict = field(default_factory=dict)


def _residuals(model, exp, n):
    """Ellipticity residuals (n exposures, n_galaxies, 2), NaN where moments fail."""
    X_gal, truth = exp.galaxy_data(range(n))
    mom = adaptive_moments(model.predict(X_gal))
    de = np.column_stack([np.asarray(mom["e1"]) - truth["e1"],
                          np.asarray(mom["e2"]) - truth["e2"]])
    de[np.asarray(mom["flag"]) != 0] = np.nan
    return de.reshape(n, len(exp.galaxies), 2)


def exposure_correlation(residuals) -> float:
    """Correlation of a galaxy's PSF residuals between two of its exposures.

    ``mean_{e != e'} <de_e . de_e'> / mean_e <|de_e|^2>`` over galaxies (``.`` the dot
    product of the (e1, e2) residuals): 0 when exposures err independently, 1 when every
    exposure makes the same error. The residual averaged over N exposures then has variance
    ``<|de|^2> (1/N + rho (1 - 1/N))``.

    Parameters
    ----------
    residuals : ndarray of shape (n_exposures, n_galaxies, 2)

    Returns
    -------
    rho : float
        NaN for one exposure.

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.study.exposures import exposure_correlation
    >>> same = np.ones((3, 10, 2))
    >>> float(exposure_correlation(same))
    1.0
    """
    de = np.asarray(residuals, dtype=np.float64)
    n = de.shape[0]
    if n < 2:
        return float("nan")
    good = np.isfinite(de).all(axis=(0, 2))
    de = de[:, good]
    total = de.sum(axis=0)
    own = np.sum(de ** 2, axis=(0, 2)).mean() / n
    cross = (np.sum(total ** 2, axis=1).mean() - n * own) / (n * (n - 1))
    return float(cross / own)


def _scores(de, exp, theta_bins):
    """Scores of the galaxies' residuals averaged over their exposures, and their D1."""
    n = de.shape[0]
    per_galaxy = np.nanmean(de, axis=0)
    good = np.isfinite(per_galaxy).all(axis=1)
    pos = np.column_stack([exp.galaxies["x"], exp.galaxies["y"]])[good] * exp.pixel_scale / ARCMIN
    min_sep, max_sep, nbins = theta_bins
    xi = ellipticity_correlation(pos, per_galaxy[good, 0], per_galaxy[good, 1], min_sep=min_sep,
                                 max_sep=max_sep, nbins=nbins, num_threads=1)
    theta, d1 = np.asarray(xi.theta_nominal), np.asarray(xi.xi, dtype=float)
    filled = np.isfinite(d1)
    scores = {
        "e_rms": float(np.sqrt(np.nanmean(np.sum(de ** 2, axis=2)))),
        "e_rms_averaged": float(np.sqrt(np.mean(np.sum(per_galaxy[good] ** 2, axis=1)))),
        "rho_exposures": exposure_correlation(de) if n > 1 else float("nan"),
        "rho1_mean_abs": float(np.nanmean(np.abs(d1))),
        "sigma_sys2": float(sigma_sys2(theta[filled], shear_bias_bound(d1[filled]))),
    }
    return scores, d1, theta


def _run_one(regime, sim, seed, n_stars, schemes, settings):
    from ...simulate import make_exposures

    ratio, dither = regime
    with threadpool_limits(1), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        counts = sorted(settings["n_exposures"])
        exp = make_exposures(counts[-1], n_stars=n_stars, n_galaxies=settings["n_galaxies"],
                             snr=settings["snr"], image_shape=settings["image_shape"],
                             atmosphere_ratio=float(np.sqrt(ratio)), dither=dither,
                             random_state=seed)
        X, stamps = exp.star_data()
        if schemes is None:  # one basis for both schemes, from the stars of all exposures
            schemes = default_exposure_schemes(_SharedBasis(StampPCA().fit(stamps)))
        if settings["oracle"]:
            schemes = {**schemes, ORACLE: None}
        rows, theta = [], None
        for name, scheme in schemes.items():
            # exposures are fitted independently by a per-exposure model: fit once on all
            separable = isinstance(scheme, PerExposurePSFModel)
            fitted, fit_seconds = None, 0.0
            for n in counts:
                if fitted is None or not separable:
                    start = time.perf_counter()
                    sel = X[:, -1] < n if not separable else slice(None)
                    fitted = (FieldOracle(exp) if scheme is None
                              else clone(scheme)).fit(X[sel], stamps[sel])
                    fit_seconds = time.perf_counter() - start
                scores, d1, theta = _scores(_residuals(fitted, exp, n), exp,
                                            settings["theta_bins"])
                rows.append({"variance_ratio": float(ratio), "dither": float(dither),
                             "simulation": sim, "seed": seed, "n_stars": n_stars,
                             "scheme": name, "n_exposures": n, **scores,
                             "fit_seconds": fit_seconds, "xi": d1})
    return rows, theta, exp.pixel_scale


def run_exposure_study(
    n_exposures=DEFAULTS["n_exposures"],
    n_stars=DEFAULTS["n_stars"],
    n_simulations: int = 3,
    schemes: dict | None = None,
    random_state: int = 0,
    *,
    variance_ratios=DEFAULTS["variance_ratios"],
    dithers=DEFAULTS["dithers"],
    oracle: bool = True,
    n_galaxies: int = DEFAULTS["n_galaxies"],
    image_shape=DEFAULTS["image_shape"],
    snr=DEFAULTS["snr"],
    theta_bins=DEFAULTS["theta_bins"],
    n_jobs: int | None = None,
    progress=None,
) -> ExposureStudyResult:
    """sigma_sys^2 of the galaxy-PSF residual averaged over its exposures, against the number
    of exposures, per regime (atmospheric / static variance, dither), scheme and number of
    stars per exposure.

    Each simulation is :func:`~sklearn_psf.simulate.make_exposures` with the largest number of
    exposures; a study with N exposures uses its first N (the same sky, optics and galaxies:
    results are paired over N, schemes and simulations; simulation ``i`` has the same seed in
    every regime). For each scheme and N the model is fitted on the stars of those exposures,
    predicts every galaxy-PSF in each exposure, and the ellipticity residuals (model - truth,
    adaptive moments) of each galaxy are averaged over its N exposures, as a shape measured
    on N exposures averages their PSF errors. D1 of that averaged residual on the galaxies'
    sky positions gives sigma_sys^2 (:func:`~sklearn_psf.metrics.sigma_sys2`, multipoles
    10-20000).

    With ``oracle`` the scheme ``"oracle"`` is the exposure oracle: the best linear unbiased
    predictor of the coefficients from the stars of all N exposures jointly, with the
    simulation's true static and atmospheric covariances
    (:meth:`~sklearn_psf.simulate.ExposureSet.weight_covariance`) and each star's true
    coefficient noise (:class:`~sklearn_psf.study.compare.FieldOracle` on the exposures).

    Parameters
    ----------
    n_exposures : sequence of int, default=(1, 2, 4, 8)
    n_stars : sequence of int, default=(120, 240)
        Stars per exposure (120 on the default 10 x 10 arcmin chip is the paper's density).
    n_simulations : int, default=3
        Per regime and number of stars.
    schemes : dict, optional
        Name -> multi-exposure model (X = x, y, exposure); default
        :func:`default_exposure_schemes` with, in each simulation, one ``StampPCA`` fitted on
        the stars of all its exposures (the same basis for every scheme and N).
    random_state : int, default=0
        Simulation ``i`` uses the ``i``-th child of ``SeedSequence(random_state)``, whatever
        the regime and ``n_stars``.
    variance_ratios : sequence of float, default=(0.2, 1, 5)
        Atmospheric over static PSF variance (``make_exposures``'s ``atmosphere_ratio`` is the
        square root: a ratio of rms).
    dithers : sequence of float, default=(0, 300, 1000)
        Largest pointing offset along each axis, pixels.
    oracle : bool, default=True
    n_galaxies, image_shape, snr :
        Passed to :func:`~sklearn_psf.simulate.make_exposures`.
    theta_bins : (float, float, int), default=(0.3, 3, 6)
        Separations of D1 (arcmin) and number of bins (the galaxies lie where every exposure
        sees the sky: 3.2 arcmin wide with dithers of 1000 pixels on the default chip).
    n_jobs : int, optional
        (regime, simulation, n_stars) tasks in parallel through joblib (Dask inside
        ``joblib.parallel_backend("dask")``).
    progress : callable, optional
        Called after each task.

    Returns
    -------
    ExposureStudyResult

    Examples
    --------
    >>> from sklearn_psf.study.exposures import run_exposure_study
    >>> r = run_exposure_study((1, 2), (40,), n_simulations=1, variance_ratios=(1.0,),
    ...                        dithers=(50.0,), n_galaxies=60, image_shape=(900, 900),
    ...                        theta_bins=(0.3, 2.0, 4))
    >>> sorted(set(r.scores["scheme"].tolist()))
    ['oracle', 'per-exposure', 'pooled']
    """
    counts = sorted({int(n) for n in n_exposures})
    if not counts or counts[0] < 1:
        raise ValueError(f"n_exposures must hold positive integers, got {n_exposures!r}.")
    if not isinstance(n_simulations, Integral) or n_simulations < 1:
        raise ValueError(f"n_simulations must be a positive integer, got {n_simulations!r}.")
    names = list(default_exposure_schemes() if schemes is None else schemes)
    if not names:
        raise ValueError("schemes is empty: give at least one multi-exposure model.")
    if ORACLE in names:
        raise ValueError(f"{ORACLE!r} is the study's exposure oracle: name your scheme "
                         "otherwise.")
    regimes = [(float(v), float(d)) for v in variance_ratios for d in dithers]
    if not regimes or any(not (v >= 0 and d >= 0) for v, d in regimes):
        raise ValueError("variance_ratios and dithers must hold non-negative numbers, got "
                         f"{variance_ratios!r} and {dithers!r}.")
    settings = {"n_exposures": counts, "n_galaxies": int(n_galaxies),
                "image_shape": tuple(int(v) for v in image_shape), "snr": snr,
                "theta_bins": tuple(theta_bins), "oracle": bool(oracle)}
    children = np.random.SeedSequence(random_state).spawn(n_simulations)
    seeds = [int(c.generate_state(1, dtype=np.uint32)[0]) for c in children]
    # the largest tasks first: fewer idle workers at the end
    tasks = [(r, i, seeds[i], int(m)) for m in sorted(n_stars, reverse=True) for r in regimes
             for i in range(n_simulations)]
    outputs = []
    for out in Parallel(n_jobs=n_jobs, return_as="generator_unordered", pre_dispatch="all",
                        batch_size=1)(delayed(_run_one)(r, i, s, m,
                                                        None if schemes is None else dict(schemes),
                                                        settings)
                                      for r, i, s, m in tasks):
        outputs.append(out)
        if progress is not None:
            progress()
    order = {name: k for k, name in enumerate([*names, ORACLE])}
    rows = sorted((r for out in outputs for r in out[0]),
                  key=lambda r: (r["variance_ratio"], r["dither"], r["n_stars"],
                                 r["simulation"], order[r["scheme"]], r["n_exposures"]))
    keys = ["variance_ratio", "dither", "simulation", "seed", "n_stars", "scheme",
            "n_exposures"]
    scores = Table(rows=[{k: v for k, v in r.items() if k != "xi"} for r in rows])
    correlations = Table(rows=[{**{k: r[k] for k in keys}, "xi": r["xi"]} for r in rows])
    pixel_scale = outputs[0][2]
    area = np.prod(settings["image_shape"]) * (pixel_scale / ARCMIN) ** 2
    return ExposureStudyResult(scores, correlations, outputs[0][1], config={
        **{k: v for k, v in settings.items()}, "variance_ratios": [v for v in variance_ratios],
        "dithers": [float(d) for d in dithers], "n_stars": [int(m) for m in n_stars],
        "n_simulations": n_simulations, "random_state": random_state, "seeds": seeds,
        "schemes": names, "shared_basis": schemes is None, "area_arcmin2": float(area),
        "pixel_scale": float(pixel_scale)})
