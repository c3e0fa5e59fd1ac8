"""Running the study: every scheme on every simulation of every configuration."""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field
from numbers import Integral

import numpy as np
from astropy.table import Table, vstack
from joblib import Parallel, delayed
from sklearn.base import clone
from threadpoolctl import threadpool_limits

from ...measure import fourth_moments
from ...model import PSFModel
from .._names import ORACLE
from ._configs import SimulationConfig, field_scale_kwargs
from ._evaluate import _evaluate, _local_density
from ._oracle import FieldOracle
from ._schemes import ARCMIN, default_schemes, make_psf_model


@dataclass
class StudyResult:
    """Results of :func:`run_study`.

    Attributes
    ----------
    scores : astropy.table.Table
        One row per (config, simulation, scheme): ``config``, ``simulation``, ``seed``,
        ``scheme``, ``n_stars``, ``n_inliers``, ``e_rms``, ``e1_rms``, ``e2_rms``,
        ``coeff_rms``, ``rho1_mean_abs``, ``sigma_sys2``, ``fit_seconds``.
    correlations : astropy.table.Table
        One row per (config, simulation, scheme, kind) with kind ``input``, ``model`` or
        ``residual`` (Rowe's D1): ``xi`` and ``xi_err`` array columns over ``theta``.
    theta : ndarray
        Separation of the correlation bins, arcmin.
    galaxies : astropy.table.Table
        One row per (config, simulation, scheme, galaxy-PSF): positions, true and model
        ellipticities, the first four true and model PCA coefficients, and the local stellar
        density (stars within 1 arcmin).
    config : dict
        The study's settings.
    requirements, surveys, tuning : optional
        D1 limits per sigma_sys^2 level, the survey requirement table and the
        hyperparameters chosen by cross-validation, when computed.
    """

    scores: Table
    correlations: Table
    theta: np.ndarray
    galaxies: Table
    config: dict = field(default_factory=dict)
    requirements: dict | None = None
    surveys: Table | None = None
    tuning: Table | None = None


def _plant_outliers(stamps, fraction, rng):
    """Blend a fraction of star stamps with a companion star (a realistic outlier)."""
    stamps = np.array(stamps, dtype=float)  # copy: the caller's stamps stay untouched
    n, npix = stamps.shape
    size = int(round(np.sqrt(npix)))
    n_out = int(round(fraction * n))
    chosen = rng.choice(n, size=n_out, replace=False)
    cube = stamps.reshape(n, size, size)
    for i in chosen:
        dy, dx = rng.integers(2, 5, size=2) * rng.choice([-1, 1], size=2)
        cube[i] += rng.uniform(0.3, 1.0) * np.roll(cube[i], (dy, dx), axis=(0, 1))
    return stamps, np.sort(chosen)


def _run_one(config, sim_index, seed, schemes, reference, theta_bins, oracle):
    """One simulation of one configuration, every scheme: rows of the three result tables.

    BLAS runs on one thread, so that a simulation gives the same digits wherever it runs
    (serially, in a joblib worker or on a Dask worker); the study is parallel over simulations.
    """
    with threadpool_limits(1):
        return _run_one_simulation(config, sim_index, seed, schemes, reference, theta_bins,
                                   oracle)


def _run_one_simulation(config, sim_index, seed, schemes, reference, theta_bins, oracle):
    from ...simulate import make_psf_field, realistic_snr

    rng = np.random.default_rng(seed)
    snr = config.snr
    if snr == "realistic":
        snr = realistic_snr(config.n_stars, random_state=rng)
    sim = make_psf_field(
        reference=reference,
        n_stars=config.n_stars,
        n_galaxies=config.n_galaxies,
        galaxy_layout=config.galaxy_layout,
        snr=snr,
        image_shape=config.image_shape,
        pixel_scale=config.pixel_scale,
        random_state=seed,
        **field_scale_kwargs(config),
    )
    stars = sim.stars
    X_stars = np.column_stack([stars["x"], stars["y"]]).astype(float)
    y_stars, flags = sim.star_stamps()
    keep = np.asarray(flags) == 0
    if config.min_snr is not None:
        keep &= np.asarray(stars["snr"]) >= config.min_snr
    X_stars, y_stars = X_stars[keep], y_stars[keep]
    if config.outlier_fraction > 0:
        y_stars, _ = _plant_outliers(y_stars, config.outlier_fraction, rng)

    gal = sim.galaxies
    X_gal = np.column_stack([gal["x"], gal["y"]]).astype(float)
    gal_mom = {"e1": gal["e1"], "e2": gal["e2"], "coeffs": gal["coeffs"],
               "sigma": gal["sigma"], "flag": np.zeros(len(gal), dtype=int)}
    if config.label == SimulationConfig.label:  # the main comparison: its fourth moments too
        true_fourth = fourth_moments(np.asarray(gal["stamp"]))
        gal_mom.update({q: np.asarray(true_fourth[q]) for q in ("M22", "M31", "M13")})
    density = _local_density(X_stars, X_gal, ARCMIN / config.pixel_scale)

    models = {name: _study_model(scheme, reference, config.iqr) for name, scheme in schemes.items()}
    if oracle:
        models[ORACLE] = FieldOracle(sim)  # measures the raw stars itself
    score_rows, corr_rows, gal_tables = [], [], []
    for name, model in models.items():
        start = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # ill-conditioned schemes (RBF) are part of the study
            model.fit(X_stars, None if name == ORACLE else y_stars)
            fit_seconds = time.perf_counter() - start
            scores, xi, rows = _evaluate(model, X_gal, gal_mom, theta_bins, config.pixel_scale,
                                         same_basis=not isinstance(schemes.get(name), PSFModel))
        base = {"config": config.label, "simulation": sim_index, "seed": seed, "scheme": name}
        score_rows.append({**base, "n_stars": len(X_stars),
                           "n_inliers": int(np.sum(model.inlier_mask_)), **scores,
                           "fit_seconds": fit_seconds})
        for kind, res in xi.items():
            corr_rows.append({**base, "kind": kind, "xi": np.asarray(res.xi, float),
                              "xi_err": np.asarray(res.sigma_xi, float)})
        t = Table(rows)
        for key, value in base.items():
            t[key] = [value] * len(t)
        t["layout"] = config.galaxy_layout
        t["local_density"] = density
        gal_tables.append(t)
    if oracle:  # every scheme's e rms over the oracle's, on the same simulation
        floor = score_rows[-1]["e_rms"]
        for row in score_rows:
            row["e_rms_ratio"] = row["e_rms"] / floor
    theta = np.asarray(xi["residual"].theta_nominal)
    return score_rows, corr_rows, vstack(gal_tables), theta


def _study_model(scheme, reference, iqr):
    """A PSFModel given as a scheme is used as it is; a regressor gets the paper's model."""
    if isinstance(scheme, PSFModel):
        return clone(scheme)
    return make_psf_model(clone(scheme), reference=reference, iqr=iqr)


def run_study(
    configs=None,
    schemes=None,
    n_simulations: int = 50,
    random_state: int = 0,
    reference=None,
    n_jobs: int | None = None,
    theta_bins=(0.5, 20.0, 10),
    progress=None,
    oracle: bool = False,
) -> StudyResult:
    """Run the paper's comparison: every scheme on every simulation of every configuration.

    Parameters
    ----------
    configs : SimulationConfig or list of SimulationConfig, optional
        The simulated data; default: the paper's (1000 stars, 2000 galaxy-PSFs, S/N 100).
    schemes : dict, optional
        Scheme name -> interpolator (positions -> PCA coefficients), used in the paper's PSF
        model (:func:`make_psf_model`), or a :class:`~sklearn_psf.model.PSFModel` used as it
        is (its coefficients are in its own basis: ``coeff_rms`` is NaN); default
        :func:`default_schemes`.
    n_simulations : int
        Simulations per configuration [50].
    random_state : int
        Seed of the whole study; simulation ``i`` uses the ``i``-th child of
        ``numpy.random.SeedSequence(random_state)`` in every configuration.
    reference : ReferenceBasis, optional
        Basis of the simulations (default: the embedded reference). Models use it as a fixed
        basis, as the paper does.
    n_jobs : int, optional
        Simulations run in parallel through joblib; inside
        ``joblib.parallel_backend("dask")`` they run on a Dask cluster.
    theta_bins : (float, float, int)
        Minimum and maximum separation (arcmin) and number of log bins of the correlation
        functions.
    progress : callable, optional
        Called with no argument each time a simulation is done (e.g. a progress bar's update).
    oracle : bool
        Also evaluate the scheme ``oracle`` (:class:`FieldOracle`: the best linear unbiased
        predictor with the simulation's true covariance and noise) and give every scheme's
        ``e_rms_ratio``, its e rms over the oracle's on the same simulation.

    Returns
    -------
    StudyResult

    See Also
    --------
    run_studies : several studies in one pool of workers.

    Examples
    --------
    >>> from sklearn_psf.study.compare import SimulationConfig, default_schemes, run_study
    >>> config = SimulationConfig(n_stars=150, n_galaxies=200, image_shape=(1500, 2000))
    >>> schemes = {k: v for k, v in default_schemes().items() if k in ("kriging", "polynomial")}
    >>> result = run_study(config, schemes, n_simulations=1, theta_bins=(0.3, 5.0, 4))
    >>> sorted(set(result.scores["scheme"].tolist()))
    ['kriging', 'polynomial']
    """
    study = {"configs": configs, "schemes": schemes, "n_simulations": n_simulations,
             "oracle": oracle}
    return run_studies([study], random_state=random_state, reference=reference, n_jobs=n_jobs,
                       theta_bins=theta_bins, progress=progress)[0]


def _checked_study(configs=None, schemes=None, n_simulations=50, oracle=False):
    """A study's settings with their defaults, validated."""
    if configs is None:
        configs = [SimulationConfig()]
    elif isinstance(configs, SimulationConfig):
        configs = [configs]
    configs = [c.validate() for c in configs]
    labels = [c.label for c in configs]
    if len(set(labels)) != len(labels):
        raise ValueError(f"configuration labels must be unique, got {labels}.")
    schemes = default_schemes() if schemes is None else dict(schemes)
    if not schemes:
        raise ValueError("schemes is empty: give at least one interpolation scheme.")
    if not isinstance(n_simulations, Integral) or n_simulations < 1:
        raise ValueError(f"n_simulations must be a positive integer, got {n_simulations!r}.")
    return configs, schemes, n_simulations, bool(oracle)


def _cost(config, schemes, oracle):
    """A rough relative cost of one simulation (fits grow faster than linearly with stars)."""
    return (len(schemes) + 3 * oracle) * max(config.n_stars, 500) ** 1.2


def run_studies(
    studies,
    random_state: int = 0,
    reference=None,
    n_jobs: int | None = None,
    theta_bins=(0.5, 20.0, 10),
    progress=None,
    other_tasks=(),
) -> list:
    """Several studies (as :func:`run_study`) whose simulations share one pool of workers.

    Every simulation of every study is one task; the tasks are dispatched together, the
    costliest first (most schemes and stars), so that no worker waits for the end of one study
    before starting the next. The tables are the same as those of one :func:`run_study` per
    study, in any order and with any ``n_jobs``.

    Parameters
    ----------
    studies : list of dict
        Each with the keys ``configs``, ``schemes``, ``n_simulations`` and ``oracle`` of
        :func:`run_study` (missing keys take its defaults).
    random_state, reference, n_jobs, theta_bins, progress
        As for :func:`run_study`, shared by every study (``progress`` is called once per
        simulation of any study, and once per other task).
    other_tasks : sequence of joblib ``delayed`` calls, optional
        Independent tasks run in the same pool, before the simulations (e.g. a small side
        study as one task, while the workers have simulations to share).

    Returns
    -------
    list
        One StudyResult per study, in the order given, then the result of each other task.

    Examples
    --------
    >>> from sklearn_psf.study.compare import SimulationConfig, default_schemes, run_studies
    >>> config = SimulationConfig(n_stars=150, n_galaxies=200, image_shape=(1500, 2000))
    >>> schemes = {k: v for k, v in default_schemes().items() if k in ("kriging", "polynomial")}
    >>> from dataclasses import replace
    >>> studies = [{"configs": config, "schemes": schemes, "n_simulations": 1},
    ...            {"configs": replace(config, label="snr=700", snr=700.0),
    ...             "schemes": {"kriging": schemes["kriging"]}, "n_simulations": 1}]
    >>> first, second = run_studies(studies, theta_bins=(0.3, 5.0, 4))
    >>> len(first.scores), second.scores["config"].tolist()
    (2, ['snr=700'])
    """
    from ...datasets import load_default_reference

    studies = [_checked_study(**study) for study in studies]
    if not studies:
        raise ValueError("studies is empty: give at least one study.")
    min_sep, max_sep, nbins = theta_bins
    if not 0 < min_sep < max_sep:
        raise ValueError(f"theta_bins must have 0 < min_sep < max_sep, got {theta_bins}.")
    reference = load_default_reference() if reference is None else reference

    tasks, all_seeds = [], []
    for k, (configs, schemes, n_simulations, oracle) in enumerate(studies):
        children = np.random.SeedSequence(random_state).spawn(n_simulations)
        seeds = [int(c.generate_state(1, dtype=np.uint32)[0]) for c in children]
        all_seeds.append(seeds)
        tasks += [(k, c, i, seeds[i], schemes, oracle) for c in configs
                  for i in range(n_simulations)]
    tasks.sort(key=lambda t: -_cost(t[1], t[4], t[5]))  # stable: ties keep their order
    # tasks of seconds each: dispatch them all at once, one per batch (joblib's default keeps
    # 2 * n_jobs in flight, which leaves Dask workers waiting on callbacks)
    other_tasks = list(other_tasks)
    jobs = Parallel(n_jobs=n_jobs, return_as="generator_unordered", pre_dispatch="all",
                    batch_size=1)(
        [delayed(_tagged)(-1 - j, func, args, kwargs)
         for j, (func, args, kwargs) in enumerate(other_tasks)]
        + [delayed(_tagged)(k, _run_one, (c, i, s, schemes, reference, theta_bins, oracle), {})
           for k, c, i, s, schemes, oracle in tasks]
    )
    outputs = [[] for _ in studies]
    others = [None] * len(other_tasks)
    for k, out in jobs:
        if k < 0:
            others[-1 - k] = out
        else:
            outputs[k].append(out)
        if progress is not None:
            progress()
    return [_assemble(out, *study, seeds, random_state, theta_bins)
            for out, study, seeds in zip(outputs, studies, all_seeds)] + others


def _tagged(k, func, args, kwargs):
    """``func(*args, **kwargs)`` with the index of its study (negative: another task)."""
    return k, func(*args, **kwargs)


def _assemble(outputs, configs, schemes, n_simulations, oracle, seeds, random_state, theta_bins):
    """One study's result tables from its simulations' rows, in a fixed order."""
    labels = [c.label for c in configs]
    score_rows = [r for out in outputs for r in out[0]]
    corr_rows = [r for out in outputs for r in out[1]]
    order = {label: k for k, label in enumerate(labels)}
    scheme_order = {name: k for k, name in enumerate([*schemes, ORACLE])}

    def key(r):
        return (order[r["config"]], r["simulation"], scheme_order[r["scheme"]])

    score_rows.sort(key=key)
    corr_rows.sort(key=lambda r: (*key(r), ("input", "model", "residual").index(r["kind"])))
    galaxies = vstack([out[2] for out in outputs])
    galaxies = galaxies[np.lexsort((
        [scheme_order[s] for s in galaxies["scheme"]],
        np.asarray(galaxies["simulation"]),
        [order[c] for c in galaxies["config"]],
    ))]
    front = ["config", "simulation", "seed", "scheme", "layout"]
    galaxies = galaxies[front + [c for c in galaxies.colnames if c not in front]]
    return StudyResult(
        scores=Table(rows=score_rows),
        correlations=Table(rows=corr_rows),
        theta=outputs[0][3],
        galaxies=galaxies,
        config={
            "n_simulations": n_simulations,
            "random_state": random_state,
            "seeds": seeds,
            "theta_bins": tuple(theta_bins),
            "schemes": list(schemes) + ([ORACLE] if oracle else []),
            "configs": [c.__dict__.copy() for c in configs],
            "pixel_scale": configs[0].pixel_scale,
            "image_shape": tuple(configs[0].image_shape),
        },
    )


def combine_results(results) -> StudyResult:
    """Stack the tables of several studies (their configuration labels must differ).

    Examples
    --------
    >>> from sklearn_psf.study.compare import combine_results
    >>> combine_results([])
    Traceback (most recent call last):
    ...
    ValueError: combine_results needs at least one StudyResult.
    """
    results = list(results)
    if not results:
        raise ValueError("combine_results needs at least one StudyResult.")
    labels = [label for r in results for label in dict.fromkeys(r.scores["config"])]
    if len(set(labels)) != len(labels):
        raise ValueError(f"configuration labels repeat across studies: {labels}.")
    if any(not np.allclose(r.theta, results[0].theta) for r in results):
        raise ValueError("studies with different correlation bins cannot be combined.")
    config = dict(results[0].config)
    config["configs"] = [c for r in results for c in r.config.get("configs", [])]
    return StudyResult(
        scores=vstack([r.scores for r in results]),
        correlations=vstack([r.correlations for r in results]),
        theta=results[0].theta,
        galaxies=vstack([r.galaxies for r in results]),
        config=config,
    )
