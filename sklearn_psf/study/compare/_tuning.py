"""Hyperparameters chosen by cross-validation on the stars."""

from __future__ import annotations

import warnings

import numpy as np
from astropy.table import Table

from ._configs import SimulationConfig, field_scale_kwargs
from ._schemes import ARCMIN, default_schemes, make_psf_model


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

    from ...datasets import load_default_reference
    from ...metrics import make_rho1_scorer
    from ...simulate import make_psf_field

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
                         random_state=seed, **field_scale_kwargs(config))
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
