"""Tests of sklearn_psf.study.plotting: the plotted data must equal independent computations."""

import itertools

import matplotlib

matplotlib.use("Agg")

import numpy as np
import pytest
from astropy.table import Table, vstack
from matplotlib.collections import PolyCollection, QuadMesh
from matplotlib.colors import LogNorm
from matplotlib.quiver import Quiver

from sklearn_psf.study import plotting
from sklearn_psf.study.plotting import MissingDataError

SCHEMES = ["polynomial", "delaunay", "kriging"]


def make_galaxies(schemes=SCHEMES, configs=("default",), n_sim=2, nx=5, ny=4, n_random=30,
                  seed=0, residual_scale=None, n_coeffs=4, shuffle=True):
    """Galaxy-PSF table with the StudyResult schema; residual sizes set per scheme."""
    rng = np.random.default_rng(seed)
    residual_scale = residual_scale or {"polynomial": 0.02, "delaunay": 0.01, "kriging": 0.005}
    gx, gy = np.meshgrid(np.arange(nx) * 100.0 + 50, np.arange(ny) * 80.0 + 40)
    tables = []
    for config in configs:
        for sim in range(n_sim):
            x = np.r_[gx.ravel(), rng.uniform(0, 500, n_random)]
            y = np.r_[gy.ravel(), rng.uniform(0, 320, n_random)]
            layout = np.array(["grid"] * gx.size + ["random"] * n_random)
            n = len(x)
            e1, e2 = rng.normal(0, 0.05, n), rng.normal(0, 0.05, n)
            coeffs = rng.normal(0, 0.03, (n, n_coeffs))
            density = rng.integers(0, 4, n).astype(float)
            common = rng.normal(0, 1, (2, n))  # shared part: residuals of schemes correlate
            for scheme in schemes:
                s = residual_scale.get(scheme, 0.01)
                r = s * (common + rng.normal(0, 1, (2, n)))
                t = Table({
                    "config": [config] * n, "simulation": np.full(n, sim),
                    "scheme": [scheme] * n, "layout": layout, "x": x, "y": y,
                    "e1_true": e1, "e2_true": e2, "e1_model": e1 + r[0], "e2_model": e2 + r[1],
                    "coeffs_true": coeffs,
                    "coeffs_model": coeffs + 0.2 * s * rng.normal(0, 1, (n, n_coeffs)),
                    "local_density": density,
                })
                if shuffle:
                    t = t[rng.permutation(n)]
                tables.append(t)
    return vstack(tables)


def make_result(schemes=SCHEMES, configs=("default",), n_sim=3, nbins=6, seed=1,
                requirements=True, oracle=False):
    """A StudyResult-like object with correlation functions (some negative values)."""
    rng = np.random.default_rng(seed)
    theta = np.geomspace(0.5, 20, nbins)
    rows = []
    all_schemes = [*schemes, "oracle"] if oracle else schemes
    for config, scheme, sim in itertools.product(configs, all_schemes, range(n_sim)):
        for kind, amp in (("input", 1e-3), ("model", 9e-4), ("residual", 1e-5)):
            xi = amp * np.exp(-theta / 5) * rng.uniform(0.5, 1.5, nbins)
            if kind == "residual":
                xi[-2:] = -np.abs(xi[-2:])  # negative at large scales
            rows.append((config, sim, scheme, kind, xi, 0.1 * np.abs(xi)))
    correlations = Table(rows=rows, names=["config", "simulation", "scheme", "kind", "xi",
                                           "xi_err"])

    class Result:
        pass

    result = Result()
    result.correlations, result.theta = correlations, theta
    result.requirements = {lvl: lvl * 10 * theta**-0.8 for lvl in (1e-5, 1e-6, 1e-7)} \
        if requirements else None
    return result


def panels(fig):
    return [ax for ax in fig.axes if ax.get_label() != "<colorbar>"]


def sticks_reference(e1, e2):
    """Independent whisker reference: sqrt of the complex ellipticity has half its angle."""
    e = e1 + 1j * e2
    stick = np.sqrt(e) * np.sqrt(np.abs(e))
    return stick.real, stick.imag


def rows_of(galaxies, **equal):
    mask = np.ones(len(galaxies), bool)
    for k, v in equal.items():
        mask &= np.asarray(galaxies[k]) == v
    return galaxies[mask]


# --------------------------------------------------------------------------- ellipticity maps


def test_ellipticity_maps_quiver_data_equal_sticks():
    gal = make_galaxies()
    fig = plotting.plot_ellipticity_maps(gal, SCHEMES, amplify=3, simulation=1)
    assert len(panels(fig)) == len(SCHEMES) * 3
    for scheme in SCHEMES:
        rows = rows_of(gal, scheme=scheme, simulation=1, layout="grid")
        order = np.lexsort((np.asarray(rows["x"]), np.asarray(rows["y"])))
        rows = rows[order]
        quivers = {q.get_gid(): q for ax in fig.axes for q in ax.collections
                   if isinstance(q, Quiver)}
        e1t, e2t = np.asarray(rows["e1_true"]), np.asarray(rows["e2_true"])
        e1m, e2m = np.asarray(rows["e1_model"]), np.asarray(rows["e2_model"])
        expected = {
            "input": sticks_reference(e1t, e2t),
            "model": sticks_reference(e1m, e2m),
            "residual": sticks_reference(3 * (e1m - e1t), 3 * (e2m - e2t)),
        }
        for kind, (u, v) in expected.items():
            q = quivers[f"{scheme}:{kind}"]
            np.testing.assert_allclose(q.U, u, atol=1e-12)
            np.testing.assert_allclose(q.V, v, atol=1e-12)
            np.testing.assert_allclose(q.X, rows["x"])
            np.testing.assert_allclose(q.Y, rows["y"])
            assert q.pivot == "middle" and q.headwidth == 0


def test_ellipticity_maps_missing_layout_raises_missing_data():
    gal = make_galaxies()
    gal = gal[np.asarray(gal["layout"]) == "random"]
    with pytest.raises(MissingDataError, match="grid"):
        plotting.plot_ellipticity_maps(gal, SCHEMES)


# --------------------------------------------------------------------------- component maps


def test_component_maps_grid_values_and_colour_scales():
    gal = make_galaxies()
    fig = plotting.plot_component_maps(gal, SCHEMES, quantity="e1", simulation=0)
    axes = panels(fig)
    assert len(axes) == len(SCHEMES) * 3
    by_gid = {ax.get_gid(): ax for ax in axes}
    all_res = []
    for scheme in SCHEMES:
        rows = rows_of(gal, scheme=scheme, simulation=0, layout="grid")
        ux, uy = np.unique(rows["x"]), np.unique(rows["y"])
        grid = {}
        for kind, values in (("input", rows["e1_true"]), ("model", rows["e1_model"]),
                             ("residual", rows["e1_model"] - rows["e1_true"])):
            img = np.full((len(uy), len(ux)), np.nan)
            img[np.searchsorted(uy, rows["y"]), np.searchsorted(ux, rows["x"])] = values
            grid[kind] = img
        all_res.append(np.asarray(rows["e1_model"] - rows["e1_true"]))
        for kind in ("input", "model", "residual"):
            mesh = [c for c in by_gid[f"e1:{scheme}:{kind}"].collections
                    if isinstance(c, QuadMesh)][0]
            np.testing.assert_allclose(np.asarray(mesh.get_array()).ravel(), grid[kind].ravel())
    res_mesh = [c for c in by_gid["e1:kriging:residual"].collections if isinstance(c, QuadMesh)][0]
    in_mesh = [c for c in by_gid["e1:kriging:input"].collections if isinstance(c, QuadMesh)][0]
    rlim = np.percentile(np.abs(np.concatenate(all_res)), 99)
    assert res_mesh.norm.vmin == pytest.approx(-rlim) and res_mesh.norm.vmax == pytest.approx(rlim)
    assert res_mesh.cmap.name == "RdBu_r"
    assert rlim < in_mesh.norm.vmax - in_mesh.norm.vmin  # narrower than the input's range


def test_component_maps_coefficient_random_layout_uses_scatter():
    gal = make_galaxies()
    fig = plotting.plot_component_maps(gal, ["kriging"], quantity="coeff2", layout="random",
                                       simulation=0)
    rows = rows_of(gal, scheme="kriging", simulation=0, layout="random")
    rows = rows[np.lexsort((np.asarray(rows["x"]), np.asarray(rows["y"])))]
    ax = {a.get_gid(): a for a in panels(fig)}["coeff2:kriging:residual"]
    sc = ax.collections[0]
    np.testing.assert_allclose(sc.get_offsets(), np.column_stack([rows["x"], rows["y"]]))
    expected = np.asarray(rows["coeffs_model"])[:, 2] - np.asarray(rows["coeffs_true"])[:, 2]
    np.testing.assert_allclose(np.asarray(sc.get_array()), expected)


def test_component_maps_bad_quantity():
    gal = make_galaxies()
    with pytest.raises(ValueError, match="quantity"):
        plotting.plot_component_maps(gal, SCHEMES, quantity="size")
    with pytest.raises(MissingDataError, match="coefficients"):
        plotting.plot_component_maps(make_galaxies(n_coeffs=2), SCHEMES, quantity="coeff3")


# --------------------------------------------------------------------------- residual pairs


def test_residual_pairs_correlation_and_contour_levels():
    gal = make_galaxies(n_sim=3)
    fig = plotting.plot_residual_pairs(gal, SCHEMES, quantity=("e1", "e2"))
    pairs = list(itertools.combinations(SCHEMES, 2))
    assert len(fig.axes) == 2 * len(pairs)
    texts = {t.get_gid(): t.get_text() for ax in fig.axes for t in ax.texts}
    for q in ("e1", "e2"):
        for a, b in pairs:
            ra = rows_of(gal, scheme=a)
            rb = rows_of(gal, scheme=b)
            # match by (simulation, x, y) with a dictionary, independently of the library
            lookup = {(int(r["simulation"]), float(r["x"]), float(r["y"])):
                      float(r[f"{q}_model"] - r[f"{q}_true"]) for r in rb}
            va = np.array([float(r[f"{q}_model"] - r[f"{q}_true"]) for r in ra])
            vb = np.array([lookup[(int(r["simulation"]), float(r["x"]), float(r["y"]))]
                           for r in ra])
            r_expected = np.corrcoef(va, vb)[0, 1]
            assert texts[f"r:{q}:{a}:{b}"] == f"r = {r_expected:.2f}"
    contours = [c for ax in fig.axes for c in ax.collections if c.get_gid() == "e1:delaunay:kriging"]
    np.testing.assert_allclose(contours[0].levels, np.arange(1, 10) / 10)


def test_residual_pairs_needs_two_schemes():
    with pytest.raises(MissingDataError):
        plotting.plot_residual_pairs(make_galaxies(), ["kriging"])


# --------------------------------------------------------------------------- correlation functions


def test_correlation_lines_equal_mean_xi():
    result = make_result()
    fig = plotting.plot_correlation_functions(result, SCHEMES)
    assert len(fig.axes) == len(SCHEMES)
    lines = {l.get_gid(): l for ax in fig.axes for l in ax.get_lines()}
    corr = result.correlations
    for scheme, kind in itertools.product(SCHEMES, ("input", "model", "residual")):
        sel = (np.asarray(corr["scheme"]) == scheme) & (np.asarray(corr["kind"]) == kind)
        mean = np.asarray(corr["xi"][sel]).mean(axis=0)
        np.testing.assert_allclose(lines[f"{scheme}:{kind}"].get_ydata(), np.abs(mean))
        np.testing.assert_allclose(lines[f"{scheme}:{kind}"].get_xdata(), result.theta)
        negative = lines.get(f"{scheme}:{kind}:negative")
        if np.any(mean < 0):
            np.testing.assert_allclose(negative.get_xdata(), result.theta[mean < 0])
            assert negative.get_markerfacecolor() == "none"
        else:
            assert negative is None
    for level in (1e-5, 1e-6, 1e-7):
        line = lines[f"requirement:{level:g}"]
        assert line.get_linestyle() == ":"
        np.testing.assert_allclose(line.get_ydata(), result.requirements[level])
    assert fig.axes[0].get_xscale() == "log" and fig.axes[0].get_yscale() == "log"


def test_correlation_without_requirements_and_missing_scheme():
    result = make_result(requirements=False)
    fig = plotting.plot_correlation_functions(result, ["kriging"])
    assert not [l for l in fig.axes[0].get_lines() if str(l.get_gid()).startswith("requirement")]
    with pytest.raises(MissingDataError, match="shepard"):
        plotting.plot_correlation_functions(result, ["kriging", "shepard"])


def test_snr_study_lines_and_oracle_bands():
    result = make_result(configs=("default", "snr=700", "snr=100"), oracle=True)
    fig = plotting.plot_snr_study(result, "kriging")
    ax = fig.axes[0]
    lines = {l.get_gid(): l for l in ax.get_lines()}
    corr = result.correlations
    for config, kind in (("snr=100", "input"), ("snr=100", "residual"), ("snr=700", "residual")):
        sel = ((np.asarray(corr["config"]) == config) & (np.asarray(corr["scheme"]) == "kriging")
               & (np.asarray(corr["kind"]) == kind))
        np.testing.assert_allclose(lines[f"snr:{config}:{kind}"].get_ydata(),
                                   np.abs(np.asarray(corr["xi"][sel]).mean(axis=0)))
    assert "snr:snr=700:input" not in lines and "snr:default:residual" not in lines
    bands = [c.get_gid() for c in ax.collections if isinstance(c, PolyCollection)]
    assert "oracle:snr=100:band" in bands and "oracle:snr=700:band" not in bands
    sel = ((np.asarray(corr["config"]) == "snr=700") & (np.asarray(corr["scheme"]) == "oracle")
           & (np.asarray(corr["kind"]) == "residual"))
    np.testing.assert_allclose(lines["oracle:snr=700"].get_ydata(),
                               np.abs(np.asarray(corr["xi"][sel]).mean(axis=0)))
    # every line is inside the y limits; bands containing zero run off the bottom
    low, high = ax.get_ylim()
    shown = np.concatenate([np.asarray(l.get_ydata(), float) for l in ax.get_lines()])
    shown = shown[np.isfinite(shown) & (shown > 0)]
    assert low < shown.min() and shown.max() < high
    with pytest.raises(MissingDataError, match="snr"):
        plotting.plot_snr_study(make_result(), "kriging")


# --------------------------------------------------------------------------- density


def test_local_density_boxplot_medians_and_whiskers():
    gal = make_galaxies(n_sim=3)
    fig = plotting.plot_density_boxplots(gal, SCHEMES, by="local", component="e2")
    ax = fig.axes[0]
    medians = {l.get_gid(): l for l in ax.get_lines() if str(l.get_gid()).startswith("median:")}
    densities = np.unique(gal["local_density"])  # integers 0..3: one group per value
    assert [t.get_text() for t in ax.get_xticklabels()] == [f"{d:g}" for d in densities]
    for scheme in SCHEMES:
        rows = rows_of(gal, scheme=scheme)
        res = np.asarray(rows["e2_model"] - rows["e2_true"])
        for g, d in enumerate(densities):
            values = res[np.asarray(rows["local_density"]) == d]
            line = medians[f"median:{scheme}:{g}"]
            np.testing.assert_allclose(line.get_ydata(), np.median(values))
            assert line.get_color() == plotting.SCHEME_COLORS[scheme]
    # whiskers reach the most extreme points inside the 5% / 95% percentiles
    rows = rows_of(gal, scheme="polynomial")
    res = np.asarray(rows["e2_model"] - rows["e2_true"])[np.asarray(rows["local_density"]) == 0]
    p5, p95 = np.percentile(res, [5, 95])
    tops = [max(l.get_ydata()) for l in ax.get_lines() if l.get_color() == "black"]
    assert np.max(res[res <= p95]) in tops
    assert len(res[(res < p5) | (res > p95)]) > 0


def test_global_density_boxplot_uses_n_stars_per_config():
    configs = ("default", "n_stars=250", "n_stars=1000")
    gal = make_galaxies(configs=configs, n_sim=2)
    scores = Table({"config": ["n_stars=250", "n_stars=1000"], "scheme": ["kriging"] * 2,
                    "n_stars": [240, 1010]})
    x, labels, res = plotting.density_groups(gal, ["kriging"], by="global", scores=scores)
    np.testing.assert_array_equal(x, [240, 1010])
    fig = plotting.plot_density_boxplots(gal, ["kriging"], by="global", scores=scores)
    medians = {l.get_gid(): l.get_ydata()[0] for l in fig.axes[0].get_lines()
               if str(l.get_gid()).startswith("median:")}
    for g, config in enumerate(["n_stars=250", "n_stars=1000"]):
        rows = rows_of(gal, scheme="kriging", config=config)
        assert medians[f"median:kriging:{g}"] == pytest.approx(
            np.median(rows["e1_model"] - rows["e1_true"]))
    with pytest.raises(MissingDataError, match="two configurations"):
        plotting.plot_density_boxplots(make_galaxies(), ["kriging"], by="global")


def test_density_stats_median_and_rms():
    gal = make_galaxies(n_sim=2)
    fig = plotting.plot_density_stats(gal, SCHEMES, component=("e1", "e2"))
    assert len(fig.axes) == 4
    lines = {l.get_gid(): l for ax in fig.axes for l in ax.get_lines()}
    rows = rows_of(gal, scheme="delaunay")
    d = np.asarray(rows["local_density"])
    res = np.asarray(rows["e1_model"] - rows["e1_true"])
    groups = [res[d == v] for v in np.unique(d)]
    np.testing.assert_allclose(lines["median:delaunay:e1"].get_ydata(),
                               [np.median(g) for g in groups])
    np.testing.assert_allclose(lines["rms:delaunay:e1"].get_ydata(),
                               [np.sqrt(np.mean(g**2)) for g in groups])
    np.testing.assert_allclose(lines["rms:delaunay:e1"].get_xdata(), np.unique(d))


def test_density_quantile_bins_cover_all_rows():
    gal = make_galaxies()
    gal["local_density"] = np.random.default_rng(3).uniform(0, 10, len(gal))
    x, labels, res = plotting.density_groups(gal, ["kriging"], bins=4)
    assert len(labels) == 4
    assert sum(len(r) for r in res["kriging"]) == np.sum(np.asarray(gal["scheme"]) == "kriging")


# --------------------------------------------------------------------------- examples, misc


def test_psf_examples_log_scale_and_data():
    yy, xx = np.mgrid[-4:5, -4:5]
    stamps = np.array([np.exp(-(xx**2 + yy**2) / w) for w in (2.0, 4.0, 6.0)])
    stamps[0, 0, 0] = -1e-3  # noise below zero must not break the log scale
    fig = plotting.plot_psf_examples(stamps.reshape(3, -1), positions=[[1, 2], [3, 4], [5, 6]])
    axes = panels(fig)
    assert len(axes) == 3
    image = axes[0].images[0]
    assert isinstance(image.norm, LogNorm)
    assert image.norm.vmax == pytest.approx(1.0)
    np.testing.assert_allclose(image.get_array(), np.clip(stamps[0], 1e-4, None))
    assert axes[1].get_title() == "(x, y) = (3, 4) px"
    with pytest.raises(ValueError, match="positions"):
        plotting.plot_psf_examples(stamps, positions=[[1, 2]])


def test_no_pyplot_state_and_consistent_colours():
    import matplotlib.pyplot as plt

    before = plt.get_fignums()
    gal = make_galaxies()
    plotting.plot_density_stats(gal, SCHEMES)
    plotting.plot_correlation_functions(make_result(), SCHEMES)
    assert plt.get_fignums() == before
    assert plotting.scheme_color("kriging") == "tab:green"
    assert plotting.scheme_color("new-scheme") == plotting.scheme_color("new-scheme")


def test_outlier_study_bars_are_the_medians():
    from sklearn_psf.study.plotting import plot_outlier_study

    rng = np.random.default_rng(1)
    rows = []
    for config, scale in (("default", 1.0), ("outliers=0.02,iqr=on", 1.05),
                          ("outliers=0.02,iqr=off", 3.0)):
        for scheme in ("polynomial", "kriging"):
            for sim in range(5):
                rows.append((config, scheme, sim, scale * rng.uniform(0.9, 1.1) * 0.01))
    scores = Table(rows=rows, names=["config", "scheme", "simulation", "e_rms"])
    fig = plot_outlier_study(scores, metrics=("e_rms",))
    heights = sorted(p.get_height() for p in fig.axes[0].patches)
    expected = sorted(np.median(scores["e_rms"][(scores["config"] == c) & (scores["scheme"] == s)])
                      for c in ("default", "outliers=0.02,iqr=on", "outliers=0.02,iqr=off")
                      for s in ("polynomial", "kriging"))
    np.testing.assert_allclose(heights, expected)
    ax = fig.axes[0]  # bars start at zero on a linear axis, labelled in words
    assert ax.get_yscale() == "linear" and ax.get_ylim()[0] == 0
    assert ax.get_ylabel().startswith("ellipticity residual rms")
    with pytest.raises(ValueError, match="outlier configuration"):
        plot_outlier_study(scores[scores["config"] == "default"], metrics=("e_rms",))


def test_figure_labels_name_what_is_drawn():
    gal = make_galaxies()
    fig = plotting.plot_density_stats(gal, SCHEMES, component=("e1",))
    assert [ax.get_ylabel() for ax in fig.axes] == ["median of residual $e_1$",
                                                   "rms of residual $e_1$"]
    fig = plotting.plot_component_maps(gal, SCHEMES, ("coeff2", "coeff3"), layout="grid")
    titles = " ".join(ax.get_title() for ax in fig.axes)
    assert "PCA coefficient 3" in titles and "PCA coefficient 4" in titles
    assert "PCA coefficient 2" not in titles  # 1-based, as the paper numbers them


def test_maps_of_a_grid_with_sub_pixel_offsets_are_meshes():
    gal = make_galaxies(n_random=0)
    rng = np.random.default_rng(3)
    gal["x"] = gal["x"] + rng.uniform(-0.5, 0.5, len(gal))  # sub-pixel positions
    gal["y"] = gal["y"] + rng.uniform(-0.5, 0.5, len(gal))
    fig = plotting.plot_component_maps(gal, SCHEMES, "e1", layout="grid")
    meshes = [c for ax in fig.axes for c in ax.collections if isinstance(c, QuadMesh)]
    assert len(meshes) >= 3 * len(SCHEMES)  # every panel (colour bars add theirs)
    assert meshes[0].get_array().shape == (4, 5)  # the 5 x 4 lattice, no gaps
