"""The multi-exposure study: sigma_sys^2 of exposure-averaged PSF residuals against N."""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field
from numbers import Integral

import numpy as np
from astropy.table import Table
from joblib import Parallel, delayed
from sklearn.base import clone
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import MinMaxScaler
from threadpoolctl import threadpool_limits

from ...measure import adaptive_moments
from ...metrics import ellipticity_correlation, shear_bias_bound, sigma_sys2
from ...interpolate import KrigingRegressor
from ...model import PerExposurePSFModel, PooledPSFModel, PSFModel

ARCMIN = 60.0  # arcsec per arcmin

#: Default sizes: 10 arcmin chips (3000 x 3000 pixels of 0.2 arcsec) with 1.2 and 2.4 stars
#: per arcmin^2 (the paper's density and twice it) per exposure, 6 galaxy-PSFs per arcmin^2,
#: up to 20 exposures (4800 stars pooled).
DEFAULTS = {"n_exposures": (1, 2, 5, 10, 20), "n_stars": (120, 240), "n_galaxies": 600,
            "image_shape": (3000, 3000), "snr": 100.0, "atmosphere_ratio": 0.5,
            "dither": 300.0, "theta_bins": (0.3, 8.0, 8)}


def default_exposure_schemes() -> dict:
    """The multi-exposure schemes: one PSF model per exposure, and the pooled model.

    The pooled model's mean pattern is fitted on the stars of every exposure (thousands of
    them) with local Kriging (100 neighbours, hyperparameters by maximum likelihood); on 2400
    stars of 10 exposures its sigma_sys^2 was within 0.2% of exact Kriging's, at 4800 stars
    exact Kriging needs 1 GiB per fit.

    Returns
    -------
    schemes : dict
        ``{"per-exposure": PerExposurePSFModel(), "pooled": PooledPSFModel(model=PSFModel(
        interpolator=MinMaxScaler + KrigingRegressor(range="auto", n_neighbors=100)))}``.

    Examples
    --------
    >>> from sklearn_psf.study.exposures import default_exposure_schemes
    >>> sorted(default_exposure_schemes())
    ['per-exposure', 'pooled']
    """
    mean = PSFModel(interpolator=make_pipeline(
        MinMaxScaler(), KrigingRegressor(range="auto", n_neighbors=100)))
    return {"per-exposure": PerExposurePSFModel(), "pooled": PooledPSFModel(model=mean)}


@dataclass
class ExposureStudyResult:
    """Results of :func:`run_exposure_study`.

    Attributes
    ----------
    scores : astropy.table.Table
        One row per (simulation, n_stars, scheme, n_exposures): ``simulation``, ``seed``,
        ``n_stars`` (per exposure), ``scheme``, ``n_exposures``, ``e_rms`` (per-exposure
        residual), ``e_rms_averaged`` (residual averaged over the exposures of each galaxy),
        ``rho1_mean_abs``, ``sigma_sys2`` (of the averaged residual), ``fit_seconds``.
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


def _averaged_residual(model, exp, n, theta_bins):
    """e residual of each galaxy averaged over the first n exposures, and its D1."""
    X_gal, truth = exp.galaxy_data(range(n))
    mom = adaptive_moments(model.predict(X_gal))
    ok = (np.asarray(mom["flag"]) == 0)
    de = np.column_stack([np.asarray(mom["e1"]) - truth["e1"],
                          np.asarray(mom["e2"]) - truth["e2"]])
    de[~ok] = np.nan
    n_gal = len(exp.galaxies)
    per_galaxy = np.nanmean(de.reshape(n, n_gal, 2), axis=0)
    good = np.isfinite(per_galaxy).all(axis=1)
    pos = np.column_stack([exp.galaxies["x"], exp.galaxies["y"]])[good] * exp.pixel_scale / ARCMIN
    min_sep, max_sep, nbins = theta_bins
    xi = ellipticity_correlation(pos, per_galaxy[good, 0], per_galaxy[good, 1], min_sep=min_sep,
                                 max_sep=max_sep, nbins=nbins, num_threads=1)
    theta, d1 = np.asarray(xi.theta_nominal), np.asarray(xi.xi, dtype=float)
    filled = np.isfinite(d1)
    scores = {
        "e_rms": float(np.sqrt(np.nanmean(np.sum(de ** 2, axis=1)))),
        "e_rms_averaged": float(np.sqrt(np.mean(np.sum(per_galaxy[good] ** 2, axis=1)))),
        "rho1_mean_abs": float(np.nanmean(np.abs(d1))),
        "sigma_sys2": float(sigma_sys2(theta[filled], shear_bias_bound(d1[filled]))),
    }
    return scores, d1, theta


def _run_one(sim, seed, n_stars, schemes, settings):
    from ...simulate import make_exposures

    with threadpool_limits(1), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        counts = sorted(settings["n_exposures"])
        exp = make_exposures(counts[-1], n_stars=n_stars, n_galaxies=settings["n_galaxies"],
                             snr=settings["snr"], image_shape=settings["image_shape"],
                             atmosphere_ratio=settings["atmosphere_ratio"],
                             dither=settings["dither"], random_state=seed)
        X, stamps = exp.star_data()
        rows, theta = [], None
        for name, scheme in schemes.items():
            # exposures are fitted independently by a per-exposure model: fit once on all
            separable = isinstance(scheme, PerExposurePSFModel)
            fitted, fit_seconds = None, 0.0
            for n in counts:
                if fitted is None or not separable:
                    start = time.perf_counter()
                    sel = X[:, -1] < n if not separable else slice(None)
                    fitted = clone(scheme).fit(X[sel], stamps[sel])
                    fit_seconds = time.perf_counter() - start
                scores, d1, theta = _averaged_residual(fitted, exp, n, settings["theta_bins"])
                rows.append({"simulation": sim, "seed": seed, "n_stars": n_stars,
                             "scheme": name, "n_exposures": n, **scores,
                             "fit_seconds": fit_seconds, "xi": d1})
    return rows, theta, exp.pixel_scale


def run_exposure_study(
    n_exposures=DEFAULTS["n_exposures"],
    n_stars=DEFAULTS["n_stars"],
    n_simulations: int = 6,
    schemes: dict | None = None,
    random_state: int = 0,
    *,
    n_galaxies: int = DEFAULTS["n_galaxies"],
    image_shape=DEFAULTS["image_shape"],
    snr=DEFAULTS["snr"],
    atmosphere_ratio: float = DEFAULTS["atmosphere_ratio"],
    dither: float = DEFAULTS["dither"],
    theta_bins=DEFAULTS["theta_bins"],
    n_jobs: int | None = None,
    progress=None,
) -> ExposureStudyResult:
    """sigma_sys^2 of the galaxy-PSF residual averaged over its exposures, against the number
    of exposures, per scheme and number of stars per exposure.

    Each simulation is :func:`~sklearn_psf.simulate.make_exposures` with the largest number of
    exposures; a study with N exposures uses its first N (the same sky, optics and galaxies:
    results are paired over N, schemes and simulations). For each scheme and N the model is
    fitted on the stars of those exposures, predicts every galaxy-PSF in each exposure, and
    the ellipticity residuals (model - truth, adaptive moments) of each galaxy are averaged
    over its N exposures, as a shape measured on N exposures averages their PSF errors. D1
    of that averaged residual on the galaxies' sky positions gives sigma_sys^2
    (:func:`~sklearn_psf.metrics.sigma_sys2`, multipoles 10-20000).

    Parameters
    ----------
    n_exposures : sequence of int, default=(1, 2, 5, 10, 20)
    n_stars : sequence of int, default=(120, 240)
        Stars per exposure (120 on the default 10 x 10 arcmin chip is the paper's density).
    n_simulations : int, default=6
    schemes : dict, optional
        Name -> multi-exposure model (X = x, y, exposure); default
        :func:`default_exposure_schemes`.
    random_state : int, default=0
        Simulation ``i`` uses the ``i``-th child of ``SeedSequence(random_state)``, whatever
        ``n_stars``.
    n_galaxies, image_shape, snr, atmosphere_ratio, dither :
        Passed to :func:`~sklearn_psf.simulate.make_exposures`.
    theta_bins : (float, float, int), default=(0.3, 8, 8)
        Separations of D1 (arcmin) and number of bins.
    n_jobs : int, optional
        Simulations in parallel through joblib (Dask inside
        ``joblib.parallel_backend("dask")``).
    progress : callable, optional
        Called after each simulation.

    Returns
    -------
    ExposureStudyResult

    Examples
    --------
    >>> from sklearn_psf.study.exposures import run_exposure_study
    >>> r = run_exposure_study((1, 2), (40,), n_simulations=1, n_galaxies=60,
    ...                        image_shape=(900, 900), dither=50, theta_bins=(0.3, 2.0, 4))
    >>> sorted(set(r.scores["n_exposures"].tolist()))
    [1, 2]
    """
    counts = sorted({int(n) for n in n_exposures})
    if not counts or counts[0] < 1:
        raise ValueError(f"n_exposures must hold positive integers, got {n_exposures!r}.")
    if not isinstance(n_simulations, Integral) or n_simulations < 1:
        raise ValueError(f"n_simulations must be a positive integer, got {n_simulations!r}.")
    schemes = default_exposure_schemes() if schemes is None else dict(schemes)
    if not schemes:
        raise ValueError("schemes is empty: give at least one multi-exposure model.")
    settings = {"n_exposures": counts, "n_galaxies": int(n_galaxies),
                "image_shape": tuple(int(v) for v in image_shape), "snr": snr,
                "atmosphere_ratio": float(atmosphere_ratio), "dither": float(dither),
                "theta_bins": tuple(theta_bins)}
    children = np.random.SeedSequence(random_state).spawn(n_simulations)
    seeds = [int(c.generate_state(1, dtype=np.uint32)[0]) for c in children]
    tasks = [(i, seeds[i], int(m)) for m in n_stars for i in range(n_simulations)]
    outputs = []
    for out in Parallel(n_jobs=n_jobs, return_as="generator_unordered", pre_dispatch="all",
                        batch_size=1)(delayed(_run_one)(i, s, m, schemes, settings)
                                      for i, s, m in tasks):
        outputs.append(out)
        if progress is not None:
            progress()
    order = {name: k for k, name in enumerate(schemes)}
    rows = sorted((r for out in outputs for r in out[0]),
                  key=lambda r: (r["n_stars"], r["simulation"], order[r["scheme"]],
                                 r["n_exposures"]))
    keys = ["simulation", "seed", "n_stars", "scheme", "n_exposures"]
    scores = Table(rows=[{k: v for k, v in r.items() if k != "xi"} for r in rows])
    correlations = Table(rows=[{**{k: r[k] for k in keys}, "xi": r["xi"]} for r in rows])
    pixel_scale = outputs[0][2]
    area = np.prod(settings["image_shape"]) * (pixel_scale / ARCMIN) ** 2
    return ExposureStudyResult(scores, correlations, outputs[0][1], config={
        **settings, "n_stars": [int(m) for m in n_stars], "n_simulations": n_simulations,
        "random_state": random_state, "seeds": seeds, "schemes": list(schemes),
        "area_arcmin2": float(area), "pixel_scale": float(pixel_scale)})
