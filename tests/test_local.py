"""Local (moving-neighbourhood) interpolation: n_neighbors of Kriging, Shepard and RBF.

References: exact Kriging (itself checked against PyKrige), PyKrige's own moving-window
ordinary Kriging (``n_closest_points``), a brute-force modified Shepard sum, and scipy's
``RBFInterpolator(neighbors=k)``.
"""

import numpy as np
import pytest
from pykrige.ok import OrdinaryKriging
from scipy.interpolate import RBFInterpolator
from scipy.spatial.distance import cdist

from sklearn_psf.interpolate import KrigingRegressor, RBFRegressor, ShepardRegressor


def field(n, n_targets=3, seed=0):
    rng = np.random.default_rng(seed)
    X = rng.uniform(size=(n, 2))
    k = rng.normal(scale=5.0, size=(n_targets, 6, 2))
    phase = rng.uniform(0, 2 * np.pi, size=(n_targets, 6))
    amp = rng.normal(size=(n_targets, 6))
    Y = np.einsum("tk,ntk->nt", amp, np.cos(np.einsum("nd,tkd->ntk", X, k) + phase))
    return X, Y


@pytest.mark.parametrize(
    "params",
    [dict(), dict(variogram="spherical", range=0.3, nugget=0.1),
     dict(variogram="gaussian", range=0.2, nugget=1e-3)],
)
def test_local_kriging_with_all_stars_is_exact_kriging(params):
    X, Y = field(150)
    Xq = np.vstack([np.random.default_rng(1).uniform(size=(200, 2)), X[:5]])
    exact = KrigingRegressor(**params).fit(X, Y)
    local = KrigingRegressor(n_neighbors=150, **params).fit(X, Y)
    p, s = exact.predict(Xq, return_std=True)
    pl, sl = local.predict(Xq, return_std=True)
    np.testing.assert_allclose(pl, p, rtol=0, atol=1e-10)
    np.testing.assert_allclose(sl, s, rtol=0, atol=1e-10)
    np.testing.assert_array_equal(sl[-5:], 0.0)  # on a star: exactly the star, std 0
    np.testing.assert_allclose(pl[-5:], Y[:5], atol=1e-12)
    np.testing.assert_allclose(local.sill_, Y.var(axis=0))  # the sill stays global


@pytest.mark.parametrize("variogram, nugget", [("exponential", 0.0), ("spherical", 0.2)])
def test_local_kriging_matches_pykrige_moving_window(variogram, nugget):
    X, Y = field(400, n_targets=2, seed=3)
    Xq = np.random.default_rng(4).uniform(size=(60, 2))
    a, k = 0.4, 12
    reg = KrigingRegressor(variogram=variogram, range=a, nugget=nugget, n_neighbors=k)
    pred, std = reg.fit(X, Y).predict(Xq, return_std=True)
    for t in range(Y.shape[1]):
        sill = Y[:, t].var()
        ok = OrdinaryKriging(
            X[:, 0], X[:, 1], Y[:, t], variogram_model=variogram,
            variogram_parameters={
                "psill": sill * (1 - nugget),
                "range": (3.0 if variogram == "exponential" else 1.0) * a,
                "nugget": sill * nugget,
            },
        )
        z, ss = ok.execute("points", Xq[:, 0], Xq[:, 1], backend="loop", n_closest_points=k)
        np.testing.assert_allclose(pred[:, t], z, rtol=1e-8, atol=1e-10)
        np.testing.assert_allclose(std[:, t] ** 2, ss, rtol=1e-7, atol=1e-12)


def test_local_kriging_close_to_exact_within_two_percent_of_field_rms():
    X, Y = field(2000, n_targets=4, seed=5)
    Xq = np.random.default_rng(6).uniform(size=(1000, 2))
    exact_reg = KrigingRegressor(range=0.5).fit(X, Y)
    local_reg = KrigingRegressor(range=0.5, n_neighbors=30).fit(X, Y)
    exact, local = exact_reg.predict(Xq), local_reg.predict(Xq)
    field_rms = Y.std(axis=0)
    rms_diff = np.sqrt(np.mean((local - exact) ** 2, axis=0))
    assert np.all(rms_diff < 0.02 * field_rms), rms_diff / field_rms
    # and local std: close to exact where neighbours screen the rest
    _, s_exact = exact_reg.predict(Xq[:100], return_std=True)
    _, s_local = local_reg.predict(Xq[:100], return_std=True)
    assert np.all(s_local >= s_exact * (1 - 1e-9))  # fewer stars: never more certain
    np.testing.assert_allclose(s_local, s_exact, rtol=0.1)


def test_local_kriging_single_output_and_one_neighbor():
    X, Y = field(50, n_targets=1)
    y = Y[:, 0]
    Xq = np.random.default_rng(2).uniform(size=(20, 2))
    pred, std = KrigingRegressor(n_neighbors=8).fit(X, y).predict(Xq, return_std=True)
    assert pred.shape == std.shape == (20,)
    nearest = np.argmin(cdist(Xq, X), axis=1)
    np.testing.assert_allclose(KrigingRegressor(n_neighbors=1).fit(X, y).predict(Xq),
                               y[nearest])


def modified_shepard(X, Y, Xq, p, k):
    D = cdist(Xq, X)
    order = np.argsort(D, axis=1)
    out = np.empty((len(Xq), Y.shape[1]))
    for i in range(len(Xq)):
        d = D[i, order[i, :k]]
        R = D[i, order[i, k]]
        w = ((R - d) / (R * d)) ** p
        out[i] = w @ Y[order[i, :k]] / w.sum()
    return out


@pytest.mark.parametrize("power, k", [(2.0, 5), (3.0, 12)])
def test_local_shepard_matches_brute_force(power, k):
    X, Y = field(200)
    Xq = np.random.default_rng(7).uniform(size=(50, 2))
    pred = ShepardRegressor(power=power, n_neighbors=k).fit(X, Y).predict(Xq)
    np.testing.assert_allclose(pred, modified_shepard(X, Y, Xq, power, k), rtol=1e-10)
    # on a star: its value
    np.testing.assert_allclose(
        ShepardRegressor(n_neighbors=k).fit(X, Y).predict(X[:3]), Y[:3], atol=1e-12)


def test_local_shepard_with_all_stars_is_global_and_grid_ties_are_finite():
    X, Y = field(30)
    Xq = np.random.default_rng(8).uniform(size=(10, 2))
    np.testing.assert_allclose(
        ShepardRegressor(n_neighbors=30).fit(X, Y).predict(Xq),
        ShepardRegressor().fit(X, Y).predict(Xq))
    g = np.arange(4.0)
    grid = np.column_stack([np.repeat(g, 4), np.tile(g, 4)])
    vals = grid.sum(axis=1)
    # the query (1.5, 1.5) has 4 neighbours at the same distance, and so is the 5th
    pred = ShepardRegressor(n_neighbors=4).fit(grid, vals).predict([[1.5, 1.5]])
    np.testing.assert_allclose(pred, [3.0])


@pytest.mark.parametrize("kernel", ["thin_plate_spline", "gaussian"])
def test_local_rbf_matches_scipy_neighbors(kernel):
    X, Y = field(300)
    Xq = np.random.default_rng(9).uniform(size=(40, 2))
    pred = RBFRegressor(kernel=kernel, epsilon=3.0, n_neighbors=20).fit(X, Y).predict(Xq)
    ref = RBFInterpolator(X, Y, kernel=kernel, epsilon=3.0, neighbors=20)(Xq)
    np.testing.assert_allclose(pred, ref, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("est", [KrigingRegressor, ShepardRegressor, RBFRegressor])
@pytest.mark.parametrize("bad", [0, -3, 2.5, "10", True])
def test_bad_n_neighbors(est, bad):
    X, Y = field(20)
    with pytest.raises(ValueError, match="n_neighbors"):
        est(n_neighbors=bad).fit(X, Y)


def test_rbf_too_few_neighbors_for_polynomial():
    X, Y = field(20)
    with pytest.raises(ValueError, match="at least 3"):
        RBFRegressor(kernel="thin_plate_spline", n_neighbors=2).fit(X, Y)


def test_auto_neighbours_exact_where_cheap_local_beyond():
    rng = np.random.default_rng(3)
    X = rng.uniform(size=(1100, 2))
    y = np.column_stack([np.sin(3 * X[:, 0]) + X[:, 1], np.cos(2 * X[:, 1])])
    noise = np.full((1100, 2), 1e-4)
    small = KrigingRegressor(range=0.3, n_neighbors="auto").fit(X[:1000], y[:1000],
                                                                noise_var=noise[:1000])
    large = KrigingRegressor(range=0.3, n_neighbors="auto").fit(X, y, noise_var=noise)
    exact = KrigingRegressor(range=0.3).fit(X, y, noise_var=noise)
    assert small.n_neighbors_ is None and large.n_neighbors_ == 30
    Xq = rng.uniform(size=(200, 2))
    # local Kriging from 30 neighbours (a smooth field, range 0.3: far stars matter a little)
    diff = large.predict(Xq) - exact.predict(Xq)
    # measured: rms 0.0008, largest 0.008 of the spread
    assert np.sqrt(np.mean(diff**2)) < 2e-3 * np.ptp(y) and np.abs(diff).max() < 0.03 * np.ptp(y)
    loo_l, std_l = large.loo_predict(return_std=True)
    loo_e, std_e = exact.loo_predict(return_std=True)
    diff = loo_l - loo_e
    # measured: rms 0.0009, largest 0.017 of the spread; std within 0.8%
    assert np.sqrt(np.mean(diff**2)) < 2e-3 * np.ptp(y) and np.abs(diff).max() < 0.03 * np.ptp(y)
    np.testing.assert_allclose(std_l, std_e, rtol=0.05)


def test_kriging_refit_in_another_mode_keeps_nothing_of_the_previous_fit():
    """A refit sets the whole fitted state anew: nothing of a local or co-Kriging fit
    lingers after an exact one without noise, which predicts as a fresh fit does."""
    X, Y = field(60, n_targets=2)
    cov = np.array([[1.0, 0.5], [0.5, 1.0]]) * 1e-4 * np.ones((60, 1, 1))
    reg = KrigingRegressor(range=0.5, n_neighbors=20).fit(X, Y, noise_cov=cov)
    assert hasattr(reg, "_tree") and not hasattr(reg, "dual_coef_")
    reg.set_params(n_neighbors=None).fit(X, Y, noise_cov=cov)
    assert hasattr(reg, "n_cg_iter_") and not hasattr(reg, "_tree")
    reg.fit(X, Y)
    assert not hasattr(reg, "n_cg_iter_") and reg.noise_cov_ is None
    Xq = X[:5] + 0.01
    np.testing.assert_array_equal(reg.predict(Xq), KrigingRegressor(range=0.5).fit(X, Y)
                                  .predict(Xq))
