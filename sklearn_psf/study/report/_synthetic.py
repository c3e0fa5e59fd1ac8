"""A small fake study result with the StudyResult schema, for examples and tests."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
from astropy.table import Table



def synthetic_study_result(schemes=("polynomial", "delaunay", "kriging", "kriging-spherical"),
                           n_simulations: int = 3, random_state: int = 0) -> SimpleNamespace:
    """A small, fake study result with the StudyResult schema, for examples and tests.

    The numbers are **not** simulations: smooth ellipticity fields plus Gaussian residuals
    whose scale per scheme, S/N and star number mimic the paper's ordering. Use it to try the
    plotting and report functions; use :func:`sklearn_psf.study.compare.run_study` for real results.

    Parameters
    ----------
    schemes : sequence of str
        Scheme names.
    n_simulations : int
        Simulations per configuration.
    random_state : int
        Seed.

    Returns
    -------
    result : types.SimpleNamespace
        Attributes ``scores``, ``correlations``, ``theta``, ``galaxies``, ``config``,
        ``requirements`` (None), ``surveys`` (None). Configurations:
        ``default``, ``snr=100``, ``snr=700``, ``n_stars=250``, ``n_stars=1000``,
        ``n_stars=4000``; galaxy-PSFs on an 8 x 6 grid and 40 random positions.

    Examples
    --------
    >>> from sklearn_psf.study.report import synthetic_study_result
    >>> r = synthetic_study_result(n_simulations=2)
    >>> len(r.scores), r.theta.shape
    (48, (8,))
    """
    rng = np.random.default_rng(random_state)
    scale = {"polynomial": 0.02, "delaunay": 0.011, "kriging": 0.008,
             "kriging-spherical": 0.009}
    local_scheme = {"delaunay", "kriging", "kriging-spherical"}
    configs = {"default": (1000, 100.0), "snr=100": (1000, 100.0), "snr=700": (1000, 700.0),
               "n_stars=250": (250, 100.0), "n_stars=1000": (1000, 100.0),
               "n_stars=4000": (4000, 100.0)}
    ny, nx = 1500, 2000
    gx, gy = np.meshgrid(np.linspace(100, nx - 100, 8), np.linspace(100, ny - 100, 6))
    theta = np.geomspace(0.5, 30.0, 8)
    score_rows, corr_rows, gal_tables = [], [], []
    for config, (n_stars, snr) in configs.items():
        for sim in range(n_simulations):
            seed = int(rng.integers(2**31))
            xr, yr = rng.uniform(0, nx, 40), rng.uniform(0, ny, 40)
            x = np.r_[gx.ravel(), xr]
            y = np.r_[gy.ravel(), yr]
            layout = np.array(["grid"] * gx.size + ["random"] * 40)
            phase = rng.uniform(0, 2 * np.pi)
            e1 = 0.05 * np.sin(x / 400 + phase)
            e2 = 0.04 * np.cos(y / 300 - phase)
            coeffs = np.column_stack([0.02 * np.sin(x / 500 + k + phase) for k in range(4)])
            density = rng.poisson(n_stars * np.pi / 120.0, size=len(x)).astype(float)
            for scheme in schemes:
                s = scale.get(scheme, 0.015) * np.sqrt(100.0 / snr) ** 0.5
                if scheme in local_scheme:
                    s = s * np.sqrt(1000.0 / n_stars)
                # fewer outliers where the local density is high
                tail = rng.standard_t(3, size=(2, len(x))) / (1 + density / 10)
                r1, r2 = s * tail
                rc = 0.2 * s * rng.standard_normal((len(x), 4))
                gal = Table({
                    "config": [config] * len(x), "simulation": np.full(len(x), sim),
                    "scheme": [scheme] * len(x), "layout": layout, "x": x, "y": y,
                    "e1_true": e1, "e2_true": e2, "e1_model": e1 + r1, "e2_model": e2 + r2,
                    "coeffs_true": coeffs, "coeffs_model": coeffs + rc,
                    "local_density": density,
                })
                gal_tables.append(gal)
                e_rms = float(np.sqrt(np.mean(r1**2 + r2**2)))
                rho1 = float(0.3 * s**2 * rng.uniform(0.8, 1.2))
                score_rows.append((config, sim, seed, scheme, n_stars, n_stars - 3, e_rms,
                                   float(np.sqrt(np.mean(r1**2))), float(np.sqrt(np.mean(r2**2))),
                                   float(np.sqrt(np.mean(rc**2))), rho1, 0.04 * rho1,
                                   float(rng.uniform(0.01, 0.1))))
                xi_in = 1e-3 * np.exp(-theta / 10.0) * rng.uniform(0.9, 1.1)
                xi_res = rho1 * np.exp(-theta / 3.0) - 0.02 * rho1
                for kind, xi in (("input", xi_in), ("model", 0.9 * xi_in), ("residual", xi_res)):
                    corr_rows.append((config, sim, scheme, kind, xi, 0.1 * np.abs(xi)))
    from astropy.table import vstack

    scores = Table(rows=score_rows, names=[
        "config", "simulation", "seed", "scheme", "n_stars", "n_inliers", "e_rms", "e1_rms",
        "e2_rms", "coeff_rms", "rho1_mean_abs", "sigma_sys2", "fit_seconds"])
    correlations = Table(rows=corr_rows, names=["config", "simulation", "scheme", "kind", "xi",
                                                "xi_err"])
    return SimpleNamespace(
        scores=scores, correlations=correlations, theta=theta, galaxies=vstack(gal_tables),
        config={"pixel_scale": 0.2, "image_shape": (ny, nx), "n_simulations": n_simulations,
                "synthetic": True},
        requirements=None, surveys=None,
    )
