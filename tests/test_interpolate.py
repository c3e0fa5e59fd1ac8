"""Interpolation regressors against independent references (PyKrige, scipy, formulas)."""

import numpy as np
import pytest
from pykrige.ok import OrdinaryKriging
from scipy.interpolate import LinearNDInterpolator, RBFInterpolator
from scipy.spatial.distance import cdist
from threadpoolctl import threadpool_limits

from sklearn_psf.interpolate import (
    ChebyshevRegressor,
    DelaunayRegressor,
    KrigingRegressor,
    PolynomialRegressor,
    RBFRegressor,
    ShepardRegressor,
    exponential_variogram,
    spherical_variogram,
    variogram_models,
)


def smooth_field(X, seed=0, n_targets=3):
    """A smooth random field: sums of random plane waves, different scale per target."""
    rng = np.random.default_rng(seed)
    out = []
    for t in range(n_targets):
        k = rng.normal(scale=4.0, size=(6, X.shape[1]))
        phase = rng.uniform(0, 2 * np.pi, size=6)
        amp = rng.normal(size=6) * 10.0 ** (t - 1)
        out.append(np.cos(X @ k.T + phase) @ amp)
    return np.column_stack(out)


@pytest.fixture
def stars():
    rng = np.random.default_rng(1)
    X = rng.uniform(size=(150, 2))
    Xq = np.vstack([rng.uniform(-0.05, 1.05, size=(300, 2)), X[:10]])  # incl. 10 on stars
    return X, smooth_field(X), Xq


# ------------------------------------------------------------------ Kriging vs PyKrige
# PyKrige's models (pykrige/variogram_models.py), m = [psill, range, nugget]:
#   exponential: psill * (1 - exp(-d / (range / 3))) + nugget  -> range_pk = 3 a
#   spherical:   psill * (1.5 d/range - 0.5 (d/range)^3) + nugget, psill + nugget beyond
#                -> range_pk = a
#   gaussian:    psill * (1 - exp(-d^2 / (4 range / 7)^2)) + nugget -> range_pk = 7 a / 4
# Ours: sill * ((1 - nugget) shape(h / a) + nugget) with sill = column variance, so
#   psill = sill * (1 - nugget), nugget_pk = sill * nugget (passed as a dict with "psill":
#   PyKrige's list form takes the full sill instead).
# PyKrige sets the diagonal of its Kriging matrix to 0 (gamma(0) = 0) and, with
# exact_values=True, also gamma = 0 for a query on a star: the same convention as ours.
# pseudo_inv=False: plain inverse of the bordered matrix (well conditioned here).
RANGE_PK = {"exponential": 3.0, "spherical": 1.0, "gaussian": 7.0 / 4.0}


@pytest.mark.parametrize(
    "variogram, a, nugget",
    [
        ("exponential", 0.5, 0.0),
        ("exponential", 0.3, 0.2),
        ("spherical", 0.5, 0.0),
        ("spherical", 0.7, 0.1),
        ("gaussian", 0.2, 0.05),
    ],
)
def test_kriging_matches_pykrige(stars, variogram, a, nugget):
    X, Y, Xq = stars
    reg = KrigingRegressor(variogram=variogram, range=a, nugget=nugget).fit(X, Y)
    pred, std = reg.predict(Xq, return_std=True)
    for t in range(Y.shape[1]):
        sill = Y[:, t].var()
        ok = OrdinaryKriging(
            X[:, 0], X[:, 1], Y[:, t], variogram_model=variogram,
            variogram_parameters={
                "psill": sill * (1 - nugget), "range": RANGE_PK[variogram] * a,
                "nugget": sill * nugget,
            },
            exact_values=True, pseudo_inv=False,
        )
        z, ss = ok.execute("points", Xq[:, 0], Xq[:, 1], backend="vectorized")
        scale = np.abs(Y[:, t]).max()
        np.testing.assert_allclose(pred[:, t], z, rtol=1e-6, atol=1e-9 * scale)
        np.testing.assert_allclose(std[:, t] ** 2, ss, rtol=1e-6, atol=1e-9 * sill)
    # exact at the stars, zero standard deviation there
    np.testing.assert_allclose(pred[-10:], Y[:10], rtol=1e-9, atol=1e-12)
    assert np.all(std[-10:] == 0)


def test_kriging_single_output_shapes_and_sill_scaling(stars):
    X, Y, Xq = stars
    multi = KrigingRegressor().fit(X, Y)
    pred, std = multi.predict(Xq, return_std=True)
    assert pred.shape == std.shape == (len(Xq), 3)
    single = KrigingRegressor().fit(X, Y[:, 1])
    p1, s1 = single.predict(Xq, return_std=True)
    assert p1.shape == s1.shape == (len(Xq),)
    np.testing.assert_allclose(p1, pred[:, 1], rtol=1e-12, atol=1e-12)
    # one normalised system: std / sqrt(sill) is the same for every target
    ratio = std / np.sqrt(Y.var(axis=0))
    np.testing.assert_allclose(ratio, ratio[:, :1].repeat(3, axis=1), rtol=1e-10, atol=1e-14)


def test_kriging_chunking_matches_single_block(stars, monkeypatch):
    X, Y, Xq = stars
    reg = KrigingRegressor().fit(X, Y)
    full = reg.predict(Xq, return_std=True)
    import sklearn_psf.interpolate._base as base

    monkeypatch.setattr(base, "_MAX_CHUNK", 7)
    chunked = reg.predict(Xq, return_std=True)
    np.testing.assert_allclose(chunked[0], full[0], rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(chunked[1], full[1], rtol=1e-12, atol=1e-14)


def test_variogram_functions():
    h = np.array([0.0, 0.1, 0.5, 1.0, 3.0])
    a, nug, sill = 0.5, 0.2, 2.0
    expected = sill * ((1 - nug) * (1 - np.exp(-h / a)) + nug)
    expected[0] = 0.0
    np.testing.assert_allclose(exponential_variogram(h, a, nug, sill), expected)
    r = h / a
    expected = np.where(r < 1, sill * ((1 - nug) * (1.5 * r - 0.5 * r**3) + nug), sill)
    expected[0] = 0.0
    np.testing.assert_allclose(spherical_variogram(h, a, nug, sill), expected)
    assert set(variogram_models) >= {"exponential", "spherical"}


def test_kriging_beats_linear_polynomial_on_smooth_field():
    rng = np.random.default_rng(5)
    X = rng.uniform(size=(400, 2))
    Xt = rng.uniform(0.05, 0.95, size=(500, 2))
    y, yt = smooth_field(X, seed=3, n_targets=2), smooth_field(Xt, seed=3, n_targets=2)
    rms_k = np.sqrt(np.mean((KrigingRegressor().fit(X, y).predict(Xt) - yt) ** 2, axis=0))
    rms_p = np.sqrt(np.mean((PolynomialRegressor(1).fit(X, y).predict(Xt) - yt) ** 2, axis=0))
    assert np.all(rms_k < 0.2 * rms_p)


# ------------------------------------------------------------------ polynomial family
def test_polynomial_matches_raw_lstsq():
    rng = np.random.default_rng(2)
    X = rng.uniform([0, 0], [2000, 1500], size=(200, 2))  # pixel coordinates
    Y = smooth_field(X / 1500, seed=1)
    Xq = rng.uniform([0, 0], [2000, 1500], size=(100, 2))
    degree = 3
    terms = [(i, j) for i in range(degree + 1) for j in range(degree + 1 - i)]

    def design(Z):
        return np.column_stack([Z[:, 0] ** i * Z[:, 1] ** j for i, j in terms])

    coef, *_ = np.linalg.lstsq(design(X), Y, rcond=None)
    reg = PolynomialRegressor(degree=degree).fit(X, Y)
    assert reg.powers_.shape == (len(terms), 2)
    np.testing.assert_allclose(reg.predict(Xq), design(Xq) @ coef, rtol=1e-6, atol=1e-8)


def test_polynomial_general_n_features_matches_lstsq():
    rng = np.random.default_rng(3)
    X = rng.uniform(size=(80, 3))
    y = smooth_field(X, n_targets=1)[:, 0]
    terms = [(i, j, k) for i in range(3) for j in range(3) for k in range(3) if i + j + k <= 2]
    A = np.column_stack([X[:, 0] ** i * X[:, 1] ** j * X[:, 2] ** k for i, j, k in terms])
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    pred = PolynomialRegressor(degree=2).fit(X, y).predict(X)
    assert pred.shape == (80,)
    np.testing.assert_allclose(pred, A @ coef, rtol=1e-8, atol=1e-10)


@pytest.mark.parametrize("degree", [0, 2, 5])
def test_chebyshev_equals_monomial(stars, degree):
    X, Y, Xq = stars
    np.testing.assert_allclose(
        ChebyshevRegressor(degree=degree).fit(X, Y).predict(Xq),
        PolynomialRegressor(degree=degree).fit(X, Y).predict(Xq),
        rtol=1e-8, atol=1e-10 * np.abs(Y).max(),
    )


def test_polynomial_auto_degree():
    rng = np.random.default_rng(4)
    X = rng.uniform(size=(300, 2))
    u, v = X.T
    y = np.column_stack([1 + u - 2 * v**3 + u * v, 100 * (u**2 - v)])
    noisy = y + rng.normal(scale=[0.01, 1.0], size=y.shape)
    reg = PolynomialRegressor(degree="auto", max_degree=8).fit(X, noisy)
    assert reg.degree_ == 3
    assert set(reg.criterion_) == set(range(9))
    # pure noise: the constant model
    assert PolynomialRegressor(degree="auto").fit(X, rng.normal(size=300)).degree_ == 0
    # the cap: degrees with as many terms as stars are not tried
    few = PolynomialRegressor(degree="auto", max_degree=8).fit(X[:12], y[:12, 0])
    assert max(few.criterion_) == 3  # 10 terms < 12 stars, degree 4 has 15


# ------------------------------------------------------------------ RBF, Shepard, Delaunay
@pytest.mark.parametrize(
    "kernel", ["gaussian", "multiquadric", "inverse_multiquadric", "thin_plate_spline"]
)
def test_rbf_matches_scipy(stars, kernel):
    X, Y, Xq = stars
    reg = RBFRegressor(kernel=kernel, epsilon=3.0, smoothing=1e-8).fit(X, Y)
    ref = RBFInterpolator(X, Y, kernel=kernel, epsilon=3.0, smoothing=1e-8)(Xq)
    np.testing.assert_allclose(reg.predict(Xq), ref, rtol=1e-10, atol=1e-12)
    assert RBFRegressor(kernel=kernel, epsilon=3.0).fit(X, Y[:, 0]).predict(Xq).shape == (310,)


@pytest.mark.parametrize("power", [1.0, 3.0, 6.5])
def test_shepard_matches_formula(stars, power):
    X, Y, Xq = stars
    pred = ShepardRegressor(power=power).fit(X, Y).predict(Xq)
    D = cdist(Xq[:-10], X)
    W = D**-power
    np.testing.assert_allclose(pred[:-10], (W @ Y) / W.sum(axis=1)[:, None], rtol=1e-10)
    np.testing.assert_array_equal(pred[-10:], Y[:10])  # exact on the stars


def test_shepard_far_queries_no_overflow():
    X = np.array([[0.0], [1.0]])
    pred = ShepardRegressor(power=50).fit(X, [0.0, 1.0]).predict([[1e-9], [1e12], [0.5]])
    assert np.all(np.isfinite(pred))
    np.testing.assert_allclose(pred, [0.0, 0.5, 0.5], atol=1e-12)


def test_delaunay_matches_scipy_inside_and_nearest_outside(stars):
    X, Y, Xq = stars
    pred = DelaunayRegressor().fit(X, Y).predict(Xq)
    with threadpool_limits(limits=1, user_api="blas"):  # scipy's tiny LAPACK calls
        ref = LinearNDInterpolator(X, Y)(Xq)
    inside = ~np.isnan(ref).any(axis=1)
    assert 0 < (~inside).sum() < len(Xq)
    np.testing.assert_allclose(pred[inside], ref[inside], rtol=1e-10, atol=1e-12)
    nearest = cdist(Xq[~inside], X).argmin(axis=1)
    np.testing.assert_array_equal(pred[~inside], Y[nearest])
    with pytest.raises(ValueError, match=rf"{(~inside).sum()} of {len(Xq)} query points"):
        DelaunayRegressor(outside="error").fit(X, Y).predict(Xq)
    assert DelaunayRegressor().fit(X, Y[:, 0]).predict(Xq).shape == (len(Xq),)


def test_delaunay_one_feature_is_np_interp():
    rng = np.random.default_rng(0)
    x = rng.uniform(size=20)
    y = np.column_stack([np.sin(5 * x), x**2])
    xq = np.linspace(-0.2, 1.2, 57)
    pred = DelaunayRegressor().fit(x[:, None], y).predict(xq[:, None])
    order = np.argsort(x)
    for t in range(2):
        np.testing.assert_allclose(pred[:, t], np.interp(xq, x[order], y[order, t]))
    with pytest.raises(ValueError, match="outside the convex hull"):
        DelaunayRegressor(outside="error").fit(x[:, None], y).predict(xq[:, None])


def test_kriging_duplicated_stars_with_nugget_match_pykrige(stars):
    # two distinct measurements at one position are correlated 1 - nugget, as in PyKrige
    X, Y, Xq = stars
    Xd, yd = np.vstack([X, X[:5]]), np.concatenate([Y[:, 0], Y[:5, 0] + 0.05])
    reg = KrigingRegressor(range=0.4, nugget=0.3).fit(Xd, yd)
    pred, std = reg.predict(Xq[:-10], return_std=True)
    sill = yd.var()
    ok = OrdinaryKriging(
        Xd[:, 0], Xd[:, 1], yd, variogram_model="exponential",
        variogram_parameters={"psill": 0.7 * sill, "range": 1.2, "nugget": 0.3 * sill},
    )
    z, ss = ok.execute("points", Xq[:-10, 0], Xq[:-10, 1])
    np.testing.assert_allclose(pred, z, rtol=1e-6)
    np.testing.assert_allclose(std**2, ss, rtol=1e-6)
