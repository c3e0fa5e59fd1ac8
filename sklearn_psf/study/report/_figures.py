"""The report's figures: which function draws each, with which data, and its caption."""

from __future__ import annotations

import numpy as np

from .. import plotting
from ..plotting import MissingDataError


def _map_source(galaxies, config):
    """Configuration and layout for the maps: grid galaxy-PSFs of ``config``, else of any
    configuration (e.g. the CLI's "grid" run), else the random galaxy-PSFs of ``config``."""
    if galaxies is None or "layout" not in galaxies.colnames:
        return config, "grid"
    configs = np.asarray(galaxies["config"]).astype(str)
    grid = np.asarray(galaxies["layout"]).astype(str) == "grid"
    if np.any(grid & (configs == config)):
        return config, "grid"
    if np.any(grid):
        return str(configs[grid][0]), "grid"
    return config, "random"


def _area_arcmin2(result):
    config = getattr(result, "config", None) or {}
    if "image_shape" not in config:
        return None
    ny, nx = config["image_shape"]
    return ny * nx * (float(config.get("pixel_scale", 0.2)) / 60.0) ** 2


def _figure_specs(result, config, schemes, map_schemes, stamps, positions):
    galaxies = getattr(result, "galaxies", None)
    scores = result.scores
    n_sim = len(np.unique(np.asarray(scores["simulation"])[
        np.asarray(scores["config"]).astype(str) == config])) if "simulation" in scores.colnames \
        else 0
    snr_scheme = "kriging" if "kriging" in schemes else schemes[0]

    def need_galaxies():
        if galaxies is None:
            raise MissingDataError("the result has no galaxies table.")
        return galaxies

    if stamps is None:
        stamps = getattr(result, "example_stamps", None)
        positions = getattr(result, "example_positions", None) if positions is None else positions
    pixel_scale = float(getattr(result, "config", {}).get("pixel_scale", 0.2)) \
        if isinstance(getattr(result, "config", None), dict) else 0.2

    def sim():
        if stamps is None:
            raise MissingDataError("no example PSF stamps were passed (stamps=...).")
        return plotting.plot_psf_examples(stamps, positions, pixel_scale=pixel_scale)

    trio = ", ".join(map_schemes)
    map_config, map_layout = _map_source(galaxies, config)
    where = f"config {map_config!r}, {map_layout} galaxy-PSFs"
    return [
        ("fig_sim", "Example PSFs of one simulation, logarithmic colour scale "
                    f"({pixel_scale:g} arcsec/pixel).", sim),
        ("fig_ell", f"PSF ellipticity whiskers of one simulation ({where}): input (left), "
                    f"model (middle), residual amplified 3x (right); rows: {trio}.",
         lambda: plotting.plot_ellipticity_maps(need_galaxies(), map_schemes, map_config,
                                                layout=map_layout)),
        ("fig_ell1comp", f"Input, model and residual maps of e1 (upper block) and e2 (lower "
                         f"block) ({where}), rows: {trio}. The residual colour scale is "
                         "symmetric and, for a useful model, narrower than the input's.",
         lambda: plotting.plot_component_maps(need_galaxies(), map_schemes, ("e1", "e2"),
                                              map_config, layout=map_layout)),
        ("fig_coeff0", f"Same as fig_ell1comp for the first two PCA coefficients; rows: {trio}.",
         lambda: plotting.plot_component_maps(need_galaxies(), map_schemes,
                                              ("coeff0", "coeff1"), map_config,
                                              layout=map_layout)),
        ("fig_coeff34", f"Same for the third and fourth PCA coefficients; rows: {trio}.",
         lambda: plotting.plot_component_maps(need_galaxies(), map_schemes,
                                              ("coeff2", "coeff3"), map_config,
                                              layout=map_layout)),
        ("fig_ecomp", f"2-D distributions of the e1 (top) and e2 (bottom) residuals of each pair "
                      f"of schemes over {n_sim} simulations; contours 0.1..0.9 of the maximum, "
                      "r: Pearson correlation.",
         lambda: plotting.plot_residual_pairs(need_galaxies(), map_schemes, ("e1", "e2"), config)),
        ("fig_coeffscomp", "Same as fig_ecomp for the first four PCA coefficients (rows).",
         lambda: plotting.plot_residual_pairs(need_galaxies(), map_schemes,
                                              ("coeff0", "coeff1", "coeff2", "coeff3"), config)),
        ("fig_cor", f"Ellipticity correlation functions averaged over {n_sim} simulations "
                    "(bands: 16-84% over simulations): input (black), model (red), residual "
                    "(green, D1); dotted: D1 limits for sigma_sys^2 levels; open circles mark "
                    "negative means.",
         lambda: plotting.plot_correlation_functions(result, schemes, config)),
        ("fig_corhsn", f"Correlation functions of {snr_scheme} for several star S/N: input and "
                       "model of the reference S/N, residuals of each S/N; dashed with bands: the "
                       "oracle's residual at each S/N (the optimum on the same fields).",
         lambda: plotting.plot_snr_study(result, snr_scheme)),
        ("fig_densell", "Box plots of the e1 and e2 residuals vs local stellar density (stars "
                        "within 1 arcmin); whiskers at 5% and 95%, points beyond drawn.",
         lambda: plotting.plot_density_boxplots(need_galaxies(), map_schemes, "local",
                                                ("e1", "e2"), config)),
        ("fig_densellvar", "Median and rms of the e1 and e2 residuals vs local stellar density.",
         lambda: plotting.plot_density_stats(need_galaxies(), map_schemes, "local",
                                             ("e1", "e2"), config)),
        ("fig_densellglob", "Same as fig_densell vs global stellar density (stars per "
                            "arcmin^2 of the image, one configuration each).",
         lambda: plotting.plot_density_boxplots(need_galaxies(), map_schemes, "global",
                                                ("e1", "e2"), config, scores=scores,
                                                area=_area_arcmin2(result))),
        ("fig_outliers", "Median ellipticity residual rms and mean |rho1| with planted outlying "
                         "stars, with and without the IQR cut (error bars: 16-84% over "
                         "simulations); 'default' has no planted outliers.",
         lambda: plotting.plot_outlier_study(scores)),
    ]
