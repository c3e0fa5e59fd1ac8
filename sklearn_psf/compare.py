"""The paper's comparison of interpolation schemes, as a study over simulated PSF fields.

For every simulation of every configuration, a :class:`~sklearn_psf.model.PSFModel` per
interpolation scheme is fitted on the stars measured from the simulated image (the paper's
pipeline: stamp normalisation, the simulation's own PCA basis, the IQR cut) and evaluated at the
galaxy-PSFs, where the true PSF is known. This is cross-validation with a predefined split
(train = stars, test = galaxy-PSFs): :func:`paper_split` builds that split for
``cross_validate`` and ``GridSearchCV``, and :func:`run_study` runs it over many simulations
with the diagnostics of the paper (residual ellipticities, PCA-coefficient residuals,
ellipticity correlation functions and the implied weak-lensing systematics).

Simulations are reproducible: simulation ``i`` of a study seeded with ``random_state`` uses the
``i``-th child of ``numpy.random.SeedSequence(random_state)``, whatever the configuration,
so that configurations are compared on the same PSF fields, and serial, ``n_jobs`` and Dask
runs give the same tables.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field, replace
from numbers import Integral, Real

import numpy as np
from astropy.table import Table, vstack
from joblib import Parallel, delayed
from scipy.spatial import cKDTree
from sklearn.base import clone
from sklearn.model_selection import PredefinedSplit
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import MinMaxScaler
from threadpoolctl import threadpool_limits

from .interpolate import (
    ChebyshevRegressor,
    DelaunayRegressor,
    KrigingRegressor,
    PolynomialRegressor,
    RBFRegressor,
    ShepardRegressor,
)
from .measure import adaptive_moments
from .metrics import ellipticity_correlation, shear_bias_bound, sigma_sys2
from .model import PSFModel
from .preprocessing import IQROutlierDetector, StampNormalizer

__all__ = [
    "SimulationConfig",
    "StudyResult",
    "default_schemes",
    "make_psf_model",
    "paper_split",
    "run_study",
    "snr_study_configs",
    "density_study_configs",
    "outlier_study_configs",
]

ARCMIN = 60.0  # arcsec per arcmin


def default_schemes() -> dict:
    """The interpolation schemes compared by the paper, with its settings.

    Every scheme works on positions scaled to the unit square (``MinMaxScaler``), as the paper
    normalises the image to 0 < x, y < 1.

    Returns
    -------
    schemes : dict
        Scheme name -> unfitted scikit-learn pipeline ``MinMaxScaler() + regressor``:
        ``polynomial`` (degree 5, the paper's best), ``polynomial-auto`` (degree chosen from the
        data), ``chebyshev`` (degree 5), ``shepard`` (p = 3), ``rbf`` (Gaussian kernel, expected
        to be unstable), ``delaunay``, ``kriging`` (exponential variogram, range 0.5, nugget 0)
        and ``kriging-spherical``.

    Examples
    --------
    >>> from sklearn_psf.compare import default_schemes
    >>> sorted(default_schemes())[:3]
    ['chebyshev', 'delaunay', 'kriging']
    """
    regressors = {
        "polynomial": PolynomialRegressor(degree=5),
        "polynomial-auto": PolynomialRegressor(degree="auto"),
        "chebyshev": ChebyshevRegressor(degree=5),
        "shepard": ShepardRegressor(power=3.0),
        # epsilon in units of 1 / (unit-square length): the kernel width is ~ 1/10 of the field.
        "rbf": RBFRegressor(kernel="gaussian", epsilon=10.0),
        "delaunay": DelaunayRegressor(),
        "kriging": KrigingRegressor(variogram="exponential", range=0.5, nugget=0.0),
        "kriging-spherical": KrigingRegressor(variogram="spherical", range=0.5, nugget=0.0),
    }
    return {name: make_pipeline(MinMaxScaler(), reg) for name, reg in regressors.items()}


def make_psf_model(interpolator, reference=None, iqr: bool = True, alpha: float = 3.5) -> PSFModel:
    """The paper's PSF model: normalised stamps, a PCA basis, the IQR cut and an interpolator.

    Parameters
    ----------
    interpolator : regressor
        Maps positions to PCA coefficients (e.g. an entry of :func:`default_schemes`).
    reference : ReferenceBasis, optional
        When given, the basis is the reference's fixed basis (the paper forces the
        simulation's basis so that coefficients can be compared with the truth); otherwise a
        PCA keeping 90% of the variance is fitted on the stars.
    iqr : bool
        Reject outlying stars with the interquartile-range test.
    alpha : float
        The IQR test's parameter (3.5 in the paper).

    Returns
    -------
    model : PSFModel

    Examples
    --------
    >>> from sklearn_psf.compare import default_schemes, make_psf_model
    >>> model = make_psf_model(default_schemes()["kriging"])
    >>> type(model).__name__
    'PSFModel'
    """
    basis = None
    if reference is not None:
        basis = make_pipeline(StampNormalizer(), reference.as_transformer())
    outliers = IQROutlierDetector(alpha=alpha) if iqr else None
    return PSFModel(interpolator=interpolator, basis=basis, outliers=outliers)


def paper_split(X_stars, y_stars, X_galaxies, y_galaxies):
    """Stack stars and galaxy-PSFs with the paper's predefined split.

    Parameters
    ----------
    X_stars, y_stars : array-like
        Star positions (n, 2) and their measured stamps (n, s*s): the training set.
    X_galaxies, y_galaxies : array-like
        Galaxy-PSF positions (m, 2) and their true stamps (m, s*s): the test set.

    Returns
    -------
    X, y : ndarray
        Stars then galaxy-PSFs.
    cv : PredefinedSplit
        One split, train = stars and test = galaxy-PSFs, for ``cross_validate`` or
        ``GridSearchCV``.

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.compare import paper_split
    >>> X, y, cv = paper_split(np.zeros((3, 2)), np.zeros((3, 9)), np.ones((2, 2)), np.ones((2, 9)))
    >>> [(tr.tolist(), te.tolist()) for tr, te in cv.split(X, y)]
    [([0, 1, 2], [3, 4])]
    """
    X_stars, X_galaxies = np.asarray(X_stars, float), np.asarray(X_galaxies, float)
    y_stars, y_galaxies = np.asarray(y_stars, float), np.asarray(y_galaxies, float)
    if y_stars.shape[1:] != y_galaxies.shape[1:]:
        raise ValueError(
            f"stars and galaxy-PSFs must have stamps of the same size, got {y_stars.shape[1:]} "
            f"and {y_galaxies.shape[1:]}."
        )
    X = np.vstack([X_stars, X_galaxies])
    y = np.vstack([y_stars, y_galaxies])
    test_fold = np.r_[np.full(len(X_stars), -1), np.zeros(len(X_galaxies), dtype=int)]
    return X, y, PredefinedSplit(test_fold)


@dataclass(frozen=True)
class SimulationConfig:
    """One configuration of the study: how the PSF field is simulated and the stars selected.

    Parameters
    ----------
    label : str
        Name of the configuration in the result tables.
    n_stars, n_galaxies : int
        Stars used to build the model, galaxy-PSFs where it is evaluated [1000, 2000].
    snr : float or "realistic"
        Star S/N (mean of the star's pixels over the background rms) [100]; ``"realistic"``
        draws the paper's distribution from 20 to 1000 peaking near 100.
    min_snr : float, optional
        Drop stars whose S/N is below this before fitting.
    outlier_fraction : float
        Fraction of stars turned into outliers (a blended companion star) before fitting.
    iqr : bool
        Whether the models reject outlying stars with the IQR test.
    galaxy_layout : {"random", "grid"}
        Galaxy-PSFs at random positions (for correlation functions) or on a grid (for maps).
    image_shape : tuple of int
        (ny, nx) of the simulated image [7769, 10032].
    pixel_scale : float
        Arcsec per pixel [0.2].
    """

    label: str = "default"
    n_stars: int = 1000
    n_galaxies: int = 2000
    snr: float | str = 100.0
    min_snr: float | None = None
    outlier_fraction: float = 0.0
    iqr: bool = True
    galaxy_layout: str = "random"
    image_shape: tuple = (7769, 10032)
    pixel_scale: float = 0.2

    def validate(self):
        """Raise ValueError when a setting is out of range."""
        if not isinstance(self.n_stars, Integral) or self.n_stars < 3:
            raise ValueError(f"n_stars must be an integer >= 3, got {self.n_stars!r}.")
        if not isinstance(self.n_galaxies, Integral) or self.n_galaxies < 2:
            raise ValueError(f"n_galaxies must be an integer >= 2, got {self.n_galaxies!r}.")
        if isinstance(self.snr, str):
            if self.snr != "realistic":
                raise ValueError(f"snr must be a positive number or 'realistic', got {self.snr!r}.")
        elif not isinstance(self.snr, Real) or not self.snr > 0:
            raise ValueError(f"snr must be a positive number or 'realistic', got {self.snr!r}.")
        if not 0 <= self.outlier_fraction < 0.5:
            raise ValueError(f"outlier_fraction must be in [0, 0.5), got {self.outlier_fraction}.")
        if self.galaxy_layout not in ("random", "grid"):
            raise ValueError(f"galaxy_layout must be 'random' or 'grid', got {self.galaxy_layout!r}.")
        return self


def snr_study_configs(base: SimulationConfig | None = None) -> list[SimulationConfig]:
    """The paper's S/N study: S/N 100, 700, the realistic distribution, and it without S/N < 100.

    Examples
    --------
    >>> [c.label for c in snr_study_configs()]
    ['snr=100', 'snr=700', 'snr=realistic', 'snr=realistic,min_snr=100']
    """
    base = base or SimulationConfig()
    return [
        replace(base, label="snr=100", snr=100.0),
        replace(base, label="snr=700", snr=700.0),
        replace(base, label="snr=realistic", snr="realistic"),
        replace(base, label="snr=realistic,min_snr=100", snr="realistic", min_snr=100.0),
    ]


def density_study_configs(
    base: SimulationConfig | None = None, n_stars=(250, 500, 1000, 2000, 4000)
) -> list[SimulationConfig]:
    """The paper's global-density study: the same fields sampled by more or fewer stars.

    Examples
    --------
    >>> [c.label for c in density_study_configs(n_stars=(250, 4000))]
    ['n_stars=250', 'n_stars=4000']
    """
    base = base or SimulationConfig()
    return [replace(base, label=f"n_stars={n}", n_stars=int(n)) for n in n_stars]


def outlier_study_configs(
    base: SimulationConfig | None = None, fraction: float = 0.02
) -> list[SimulationConfig]:
    """The paper's outlier study: planted outlying stars, with and without the IQR cut.

    Examples
    --------
    >>> [c.label for c in outlier_study_configs()]
    ['outliers=0.02,iqr=on', 'outliers=0.02,iqr=off']
    """
    base = base or SimulationConfig()
    return [
        replace(base, label=f"outliers={fraction:g},iqr=on", outlier_fraction=fraction, iqr=True),
        replace(base, label=f"outliers={fraction:g},iqr=off", outlier_fraction=fraction, iqr=False),
    ]


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
    requirements, surveys, wiener, tuning : optional
        D1 limits per sigma_sys^2 level, the survey requirement table, the Wiener-filter
        optimum bands, and the hyperparameters chosen by cross-validation, when computed.
    """

    scores: Table
    correlations: Table
    theta: np.ndarray
    galaxies: Table
    config: dict = field(default_factory=dict)
    requirements: dict | None = None
    surveys: Table | None = None
    wiener: dict | None = None
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


def _local_density(X_stars, X_galaxies, radius_pixels):
    """Number of stars within ``radius_pixels`` of each galaxy-PSF."""
    return cKDTree(X_stars).query_ball_point(X_galaxies, r=radius_pixels, return_length=True)


def _rms(a):
    return float(np.sqrt(np.nanmean(np.square(a))))


def _evaluate(model, X_gal, gal, theta_bins, pixel_scale):
    """Model minus truth at galaxy-PSFs: scalar scores, correlation functions, per-galaxy rows."""
    stamps = model.predict(X_gal)
    mom = adaptive_moments(stamps)
    ok = (np.asarray(mom["flag"]) == 0) & (np.asarray(gal["flag"]) == 0)
    if ok.sum() < 2:
        raise RuntimeError("adaptive moments failed on almost every model PSF.")
    e1_m, e2_m = np.asarray(mom["e1"]), np.asarray(mom["e2"])
    e1_t, e2_t = np.asarray(gal["e1"]), np.asarray(gal["e2"])
    coeffs_m = model.predict_coefficients(X_gal)
    coeffs_t = np.asarray(gal["coeffs"])
    k = min(coeffs_m.shape[1], coeffs_t.shape[1])
    de1, de2 = (e1_m - e1_t)[ok], (e2_m - e2_t)[ok]

    pos = X_gal[ok] * pixel_scale / ARCMIN
    min_sep, max_sep, nbins = theta_bins
    xi = {}
    for kind, (a, b) in {
        "input": (e1_t[ok], e2_t[ok]),
        "model": (e1_m[ok], e2_m[ok]),
        "residual": (de1, de2),
    }.items():
        # one thread: TreeCorr's threaded sums vary in the last digits from run to run, and
        # the study is parallel over simulations already
        xi[kind] = ellipticity_correlation(pos, a, b, min_sep=min_sep, max_sep=max_sep,
                                           nbins=nbins, num_threads=1)
    theta = np.asarray(xi["residual"].theta_nominal)
    d1 = np.asarray(xi["residual"].xi)
    filled = np.isfinite(d1)  # bins without pairs (small fields) are left out of the integral
    implied = (float(sigma_sys2(theta[filled], shear_bias_bound(d1[filled])))
               if filled.sum() >= 2 else np.nan)
    scores = {
        "e_rms": _rms(np.hypot(de1, de2)),
        "e1_rms": _rms(de1),
        "e2_rms": _rms(de2),
        "coeff_rms": _rms(coeffs_m[:, :k] - coeffs_t[:, :k]),
        "rho1_mean_abs": float(np.nanmean(np.abs(d1))) if filled.any() else np.nan,
        "sigma_sys2": implied,
    }
    rows = {
        "x": X_gal[:, 0],
        "y": X_gal[:, 1],
        "e1_true": e1_t,
        "e2_true": e2_t,
        "e1_model": np.where(ok, e1_m, np.nan),
        "e2_model": np.where(ok, e2_m, np.nan),
        "coeffs_true": coeffs_t[:, :4],
        "coeffs_model": coeffs_m[:, :4],
    }
    return scores, xi, rows


def _run_one(config, sim_index, seed, schemes, reference, theta_bins):
    """One simulation of one configuration, every scheme: rows of the three result tables.

    BLAS runs on one thread, so that a simulation gives the same digits wherever it runs
    (serially, in a joblib worker or on a Dask worker); the study is parallel over simulations.
    """
    with threadpool_limits(1):
        return _run_one_simulation(config, sim_index, seed, schemes, reference, theta_bins)


def _run_one_simulation(config, sim_index, seed, schemes, reference, theta_bins):
    from .simulate import make_psf_field, realistic_snr

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
               "flag": np.zeros(len(gal), dtype=int)}
    density = _local_density(X_stars, X_gal, ARCMIN / config.pixel_scale)

    score_rows, corr_rows, gal_tables = [], [], []
    for name, interpolator in schemes.items():
        model = make_psf_model(clone(interpolator), reference=reference, iqr=config.iqr)
        start = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # ill-conditioned schemes (RBF) are part of the study
            model.fit(X_stars, y_stars)
            fit_seconds = time.perf_counter() - start
            scores, xi, rows = _evaluate(model, X_gal, gal_mom, theta_bins, config.pixel_scale)
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
    theta = np.asarray(xi["residual"].theta_nominal)
    return score_rows, corr_rows, vstack(gal_tables), theta


def run_study(
    configs=None,
    schemes=None,
    n_simulations: int = 50,
    random_state: int = 0,
    reference=None,
    n_jobs: int | None = None,
    theta_bins=(0.5, 20.0, 10),
    progress=None,
) -> StudyResult:
    """Run the paper's comparison: every scheme on every simulation of every configuration.

    Parameters
    ----------
    configs : SimulationConfig or list of SimulationConfig, optional
        The simulated data; default: the paper's (1000 stars, 2000 galaxy-PSFs, S/N 100).
    schemes : dict, optional
        Scheme name -> interpolator (positions -> PCA coefficients); default
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

    Returns
    -------
    StudyResult

    Examples
    --------
    >>> from sklearn_psf.compare import SimulationConfig, default_schemes, run_study
    >>> config = SimulationConfig(n_stars=150, n_galaxies=200, image_shape=(1500, 2000))
    >>> schemes = {k: v for k, v in default_schemes().items() if k in ("kriging", "polynomial")}
    >>> result = run_study(config, schemes, n_simulations=1, theta_bins=(0.3, 5.0, 4))
    >>> sorted(set(result.scores["scheme"].tolist()))
    ['kriging', 'polynomial']
    """
    from .datasets import load_default_reference

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
    min_sep, max_sep, nbins = theta_bins
    if not 0 < min_sep < max_sep:
        raise ValueError(f"theta_bins must have 0 < min_sep < max_sep, got {theta_bins}.")
    reference = load_default_reference() if reference is None else reference

    children = np.random.SeedSequence(random_state).spawn(n_simulations)
    seeds = [int(c.generate_state(1, dtype=np.uint32)[0]) for c in children]
    tasks = [(c, i, seeds[i]) for c in configs for i in range(n_simulations)]
    # few tasks of seconds each: dispatch them all at once, one per batch (joblib's default
    # keeps 2 * n_jobs in flight, which leaves Dask workers waiting on callbacks)
    jobs = Parallel(n_jobs=n_jobs, return_as="generator_unordered", pre_dispatch="all",
                    batch_size=1)(
        delayed(_run_one)(c, i, s, schemes, reference, theta_bins) for c, i, s in tasks
    )
    outputs = []
    for out in jobs:
        outputs.append(out)
        if progress is not None:
            progress()

    score_rows = [r for out in outputs for r in out[0]]
    corr_rows = [r for out in outputs for r in out[1]]
    order = {label: k for k, label in enumerate(labels)}
    scheme_order = {name: k for k, name in enumerate(schemes)}

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
            "schemes": list(schemes),
            "configs": [c.__dict__.copy() for c in configs],
            "pixel_scale": configs[0].pixel_scale,
            "image_shape": tuple(configs[0].image_shape),
        },
    )


def combine_results(results) -> StudyResult:
    """Stack the tables of several studies (their configuration labels must differ).

    Examples
    --------
    >>> from sklearn_psf.compare import combine_results
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


# Hyperparameter grids searched by cross-validation (the paper tuned these by hand).
PARAM_GRIDS = {
    "polynomial": {"polynomialregressor__degree": [1, 2, 3, 4, 5, 6, 7]},
    "shepard": {"shepardregressor__power": [2.0, 3.0, 4.0, 5.0]},
    "rbf": {"rbfregressor__epsilon": [3.0, 10.0, 30.0]},
    "kriging": {
        "krigingregressor__range": [0.25, 0.5, 0.75],
        "krigingregressor__nugget": [0.0, 0.01, 0.1],
    },
}


def tune_schemes(
    config: SimulationConfig | None = None,
    param_grids=None,
    scoring=None,
    cv: int = 5,
    random_state: int = 0,
    reference=None,
    n_jobs: int | None = None,
    progress=None,
) -> Table:
    """Choose each scheme's hyperparameters by cross-validation on the stars of a simulation.

    As on real data, only the stars are used: ``GridSearchCV`` with a K-fold split of the
    stars, scored by the residual ellipticity correlation (:func:`~sklearn_psf.metrics.
    make_rho1_scorer`) of the held-out stars.

    Parameters
    ----------
    config : SimulationConfig, optional
        The simulated field (default: the paper's).
    param_grids : dict, optional
        Scheme name -> parameter grid of its ``MinMaxScaler + regressor`` pipeline (default
        :data:`PARAM_GRIDS`).
    scoring : callable, optional
        A scorer ``scorer(estimator, X, y)``; default minus the mean |rho1| between 1 and 10
        arcmin.
    cv : int
        Number of folds.
    random_state : int
        Seed of the simulation (the first simulation of :func:`run_study`) and of the folds.
    reference : ReferenceBasis, optional
        Basis of the simulation and of the models (default: the embedded reference).
    n_jobs : int, optional
        Parallel fits of ``GridSearchCV``.
    progress : callable, optional
        Called once per scheme tuned.

    Returns
    -------
    table : astropy.table.Table
        One row per scheme: ``scheme``, ``best_params`` (str), ``best_score``,
        ``default_score`` (the paper's setting, same folds).
    """
    from sklearn.model_selection import GridSearchCV, KFold, cross_val_score

    from .datasets import load_default_reference
    from .metrics import make_rho1_scorer
    from .simulate import make_psf_field

    config = (config or SimulationConfig()).validate()
    reference = load_default_reference() if reference is None else reference
    param_grids = PARAM_GRIDS if param_grids is None else param_grids
    unknown = sorted(set(param_grids) - set(default_schemes()))
    if unknown:
        raise ValueError(f"no scheme named {unknown[0]!r}; choose among {sorted(default_schemes())}.")
    if scoring is None:
        arcmin = ARCMIN / config.pixel_scale
        scoring = make_rho1_scorer(min_sep=1.0 * arcmin, max_sep=10.0 * arcmin, nbins=5)
    seed = int(np.random.SeedSequence(random_state).spawn(1)[0].generate_state(1, dtype=np.uint32)[0])
    sim = make_psf_field(reference=reference, n_stars=config.n_stars, n_galaxies=2,
                         snr=config.snr if config.snr != "realistic" else 100.0,
                         image_shape=config.image_shape, pixel_scale=config.pixel_scale,
                         random_state=seed)
    X = np.column_stack([sim.stars["x"], sim.stars["y"]]).astype(float)
    y, flags = sim.star_stamps()
    keep = np.asarray(flags) == 0
    X, y = X[keep], y[keep]
    folds = KFold(cv, shuffle=True, random_state=random_state)
    rows = []
    schemes = default_schemes()
    for name, grid in param_grids.items():
        model = make_psf_model(schemes[name], reference=reference, iqr=config.iqr)
        grid = {f"interpolator__{k}": v for k, v in grid.items()}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            search = GridSearchCV(model, grid, scoring=scoring, cv=folds, n_jobs=n_jobs).fit(X, y)
            default = cross_val_score(model, X, y, scoring=scoring, cv=folds, n_jobs=n_jobs)
        best = {k.split("__")[-1]: v for k, v in search.best_params_.items()}
        rows.append({"scheme": name, "best_params": ", ".join(f"{k}={v}" for k, v in best.items()),
                     "best_score": float(search.best_score_), "default_score": float(np.mean(default))})
        if progress is not None:
            progress()
    return Table(rows=rows)


def wiener_bands(config: SimulationConfig | None = None, theta_bins=(0.5, 20.0, 10),
                 noise_sigma: float = 0.01, e_rms: float = 0.02, n_realisations: int = 12,
                 random_state: int = 0) -> dict:
    """The paper's optimum: Wiener-filter residuals on Gaussian random fields (fig_corhsn bands).

    A Gaussian random field with the simulations' power spectrum, sampled by as many stars
    over the same area with measurement noise ``noise_sigma`` per ellipticity component, is
    interpolated with the true covariance (see
    :func:`~sklearn_psf.metrics.wiener_filter_baseline`).

    Returns
    -------
    bands : dict
        ``theta`` (arcmin) and the spans over realisations of the input (``input_lo``,
        ``input_hi``) and residual (``residual_lo``, ``residual_hi``) correlation functions.
    """
    from .metrics import wiener_filter_baseline

    config = (config or SimulationConfig()).validate()
    ny, nx = config.image_shape
    arcmin = config.pixel_scale / ARCMIN
    min_sep, max_sep, nbins = theta_bins
    base = wiener_filter_baseline(
        n_stars=config.n_stars, n_galaxies=config.n_galaxies, field_size=(nx * arcmin, ny * arcmin),
        e_rms=e_rms, noise_sigma=noise_sigma, n_realisations=n_realisations,
        min_sep=min_sep, max_sep=max_sep, nbins=nbins, random_state=random_state,
    )
    _, input_lo, input_hi = base.input_band
    _, residual_lo, residual_hi = base.residual_band
    return {"theta": np.asarray(base.theta), "input_lo": input_lo, "input_hi": input_hi,
            "residual_lo": residual_lo, "residual_hi": residual_hi}
