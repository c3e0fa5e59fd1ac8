"""Universal Kriging (linear, quadratic drift) and geometric anisotropy against PyKrige.

Parameter mapping (as in test_interpolate.py): PyKrige's exponential model is
``psill (1 - exp(-d / (range_pk / 3))) + nugget_pk``, so ``range_pk = 3 a``,
``psill = sill (1 - nugget)`` and ``nugget_pk = sill * nugget`` with ``sill`` the column
variance (our sill with numeric range and nugget). Anisotropy: both rotate the positions
by ``-anisotropy_angle`` (degrees, counter-clockwise) and multiply the rotated second
coordinate by ``anisotropy_scaling``; the range applies in that frame on both sides.
Drift: PyKrige's ``regional_linear`` drift spans {1, x, y} like ``drift="linear"``; a
quadratic drift is PyKrige's ``functional_drift`` with x^2, xy, y^2 added. The drift
space does not depend on the coordinates it is written in, so PyKrige's (adjusted
frame) and ours (raw positions scaled to [-1, 1]) give the same predictor.
"""

import numpy as np
import pytest
from pykrige.ok import OrdinaryKriging
from pykrige.uk import UniversalKriging

from sklearn_psf.interpolate import KrigingRegressor


@pytest.fixture(scope="module")
def field():
    """A field with a strong gradient and an elongated pattern, noisy values."""
    rng = np.random.default_rng(11)
    X = rng.uniform(0, 100, size=(120, 2))  # pixel-like units
    u = X @ np.array([np.cos(0.6), np.sin(0.6)])
    Y = np.column_stack([
        0.02 * X[:, 0] - 0.01 * X[:, 1] + np.sin(u / 15.0),
        1e-4 * (X[:, 0] - 50) ** 2 + 0.3 * np.cos(X[:, 1] / 9.0),
    ]) + rng.normal(scale=0.01, size=(120, 2))
    Xq = rng.uniform(-5, 105, size=(150, 2))  # including slight extrapolation
    return X, Y, Xq


def pykrige_params(y, a, nugget):
    sill = y.var()
    return {"psill": sill * (1 - nugget), "range": 3.0 * a, "nugget": sill * nugget}


def quadratic_terms():
    return [lambda x, y: x**2, lambda x, y: x * y, lambda x, y: y**2]


@pytest.mark.parametrize("drift", ["linear", "quadratic"])
@pytest.mark.parametrize("a, nugget, scaling, angle", [
    (30.0, 0.0, 1.0, 0.0),
    (20.0, 0.1, 2.5, 35.0),
])
def test_universal_kriging_matches_pykrige(field, drift, a, nugget, scaling, angle):
    X, Y, Xq = field
    reg = KrigingRegressor(range=a, nugget=nugget, drift=drift, anisotropy_scaling=scaling,
                           anisotropy_angle=angle).fit(X, Y)
    pred, std = reg.predict(Xq, return_std=True)
    for t in range(2):
        uk = UniversalKriging(
            X[:, 0], X[:, 1], Y[:, t], variogram_model="exponential",
            variogram_parameters=pykrige_params(Y[:, t], a, nugget),
            anisotropy_scaling=scaling, anisotropy_angle=angle,
            drift_terms=["regional_linear"] + (["functional"] if drift == "quadratic" else []),
            functional_drift=quadratic_terms() if drift == "quadratic" else None,
            exact_values=True, pseudo_inv=False,
        )
        z, ss = uk.execute("points", Xq[:, 0], Xq[:, 1], backend="vectorized")
        scale = np.abs(Y[:, t]).max()
        np.testing.assert_allclose(pred[:, t], z, rtol=1e-6, atol=1e-6 * scale)
        np.testing.assert_allclose(std[:, t] ** 2, ss, rtol=1e-6, atol=1e-6 * Y[:, t].var())


@pytest.mark.parametrize("scaling, angle", [(3.0, 0.0), (0.5, -60.0), (2.0, 120.0)])
def test_anisotropic_ordinary_kriging_matches_pykrige(field, scaling, angle):
    X, Y, Xq = field
    a, nugget = 25.0, 0.05
    reg = KrigingRegressor(range=a, nugget=nugget, anisotropy_scaling=scaling,
                           anisotropy_angle=angle).fit(X, Y)
    pred, std = reg.predict(Xq, return_std=True)
    for t in range(2):
        ok = OrdinaryKriging(
            X[:, 0], X[:, 1], Y[:, t], variogram_model="exponential",
            variogram_parameters=pykrige_params(Y[:, t], a, nugget),
            anisotropy_scaling=scaling, anisotropy_angle=angle,
            exact_values=True, pseudo_inv=False,
        )
        z, ss = ok.execute("points", Xq[:, 0], Xq[:, 1], backend="vectorized")
        scale = np.abs(Y[:, t]).max()
        np.testing.assert_allclose(pred[:, t], z, rtol=1e-6, atol=1e-6 * scale)
        np.testing.assert_allclose(std[:, t] ** 2, ss, rtol=1e-6, atol=1e-6 * Y[:, t].var())


def test_anisotropy_is_isotropic_kriging_in_the_rotated_stretched_frame(field):
    X, Y, Xq = field
    t = np.deg2rad(30.0)

    def frame(P):  # rotate by -30 degrees, then stretch the second axis by 4
        u = np.cos(t) * P[:, 0] + np.sin(t) * P[:, 1]
        v = -np.sin(t) * P[:, 0] + np.cos(t) * P[:, 1]
        return np.column_stack([u, 4.0 * v])

    aniso = KrigingRegressor(range=20.0, anisotropy_scaling=4.0, anisotropy_angle=30.0)
    p1, s1 = aniso.fit(X, Y).predict(Xq, return_std=True)
    p2, s2 = KrigingRegressor(range=20.0).fit(frame(X), Y).predict(frame(Xq), return_std=True)
    np.testing.assert_allclose(p1, p2, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(s1, s2, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("drift", [None, "linear", "quadratic"])
def test_local_universal_kriging_equals_exact_with_all_neighbours(field, drift):
    X, Y, Xq = field
    kw = dict(range=30.0, nugget=0.02, drift=drift, anisotropy_scaling=1.5,
              anisotropy_angle=10.0)
    pe, se = KrigingRegressor(**kw).fit(X, Y).predict(Xq, return_std=True)
    pl, sl = KrigingRegressor(n_neighbors=120, **kw).fit(X, Y).predict(Xq, return_std=True)
    np.testing.assert_allclose(pl, pe, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(sl, se, rtol=1e-6, atol=1e-9)


def test_drift_reproduces_its_polynomial_exactly():
    rng = np.random.default_rng(3)
    X = rng.uniform(size=(40, 2))
    Xq = rng.uniform(-0.5, 1.5, size=(30, 2))

    def quad(P):
        return 1 + 2 * P[:, 0] - P[:, 1] + 0.5 * P[:, 0] * P[:, 1] - P[:, 1] ** 2

    reg = KrigingRegressor(range=0.3, drift="quadratic").fit(X, quad(X))
    np.testing.assert_allclose(reg.predict(Xq), quad(Xq), rtol=1e-8, atol=1e-8)
    lin = KrigingRegressor(range=0.3, drift="linear").fit(X, 2 * X[:, 0] - X[:, 1])
    np.testing.assert_allclose(lin.predict(Xq), 2 * Xq[:, 0] - Xq[:, 1], atol=1e-8)


def test_anisotropy_needs_two_features():
    X = np.random.default_rng(0).uniform(size=(20, 3))
    with pytest.raises(ValueError, match="anisotropy needs 2 features"):
        KrigingRegressor(anisotropy_scaling=2.0).fit(X, X[:, 0])


def test_ml_with_drift_and_anisotropy():
    rng = np.random.default_rng(4)
    X = rng.uniform(size=(150, 2))
    y = 3 * X[:, 0] + np.sin(6 * X[:, 1]) + rng.normal(scale=0.01, size=150)
    reg = KrigingRegressor(range="auto", nugget="auto", drift="linear",
                           anisotropy_scaling=2.0).fit(X, y)
    assert np.isfinite(reg.log_likelihood_)
    # the linear trend is in the drift, not in the field
    iso = KrigingRegressor(range="auto", nugget="auto").fit(X, y)
    assert reg.sill_[0] < iso.sill_[0]


def _gp_draw(X, length, rng):
    """A zero-mean Gaussian field of exponential covariance (range ``length``) at X."""
    d = np.sqrt(((X[:, None] - X[None]) ** 2).sum(-1))
    return np.linalg.cholesky(np.exp(-d / length) + 1e-10 * np.eye(len(X))) @ \
        rng.normal(size=len(X))


@pytest.mark.parametrize("trend", [0.0, 1.0])
def test_auto_drift_is_the_smallest_bic(trend):
    """drift="auto": the drift of the smallest BIC, -2 log L + (terms x targets) log n, of
    the three fits by Vecchia's likelihood; then the fit with that drift (started from the
    candidate's hyperparameters). A quadratic trend
    (a PSF's optics over a CCD) gets the quadratic drift, a stationary field the constant
    mean."""
    rng = np.random.default_rng(3)
    X = rng.uniform(0, 1, (300, 2))
    u, v = X[:, 0] - 0.5, X[:, 1] - 0.5
    Y = np.column_stack([0.1 * _gp_draw(X, 0.1, rng) + trend * (u**2 + 2 * u * v),
                         0.1 * _gp_draw(X, 0.1, rng) + trend * (v**2 - u)])
    noise = np.full(Y.shape, 0.02**2)
    Y = Y + rng.normal(scale=0.02, size=Y.shape)
    bic = {}
    for drift, terms in ((None, 1), ("linear", 3), ("quadratic", 6)):
        ref = KrigingRegressor(range="auto", drift=drift, likelihood=10).fit(
            X, Y, noise_var=noise)
        bic[drift] = terms * 2 * np.log(300) - 2 * ref.log_likelihood_
    expected = min(bic, key=bic.get)
    assert expected == ("quadratic" if trend else None)
    auto = KrigingRegressor(range="auto", drift="auto").fit(X, Y, noise_var=noise)
    assert auto.drift_ == expected
    # the chosen drift's fit starts from the candidate's hyperparameters: the same optimum
    fixed = KrigingRegressor(range="auto", drift=expected).fit(X, Y, noise_var=noise)
    np.testing.assert_allclose(auto.predict(X[:20]), fixed.predict(X[:20]), rtol=1e-6,
                               atol=1e-9)
    assert auto.range_ == pytest.approx(fixed.range_, rel=1e-5)


def test_auto_drift_without_maximum_likelihood_is_ordinary_kriging():
    X = np.random.default_rng(0).uniform(size=(30, 2))
    auto = KrigingRegressor(range=0.5, drift="auto").fit(X, X[:, 0] ** 2)
    assert auto.drift_ is None
    np.testing.assert_array_equal(auto.predict(X[:5] + 0.01), KrigingRegressor(range=0.5).fit(
        X, X[:, 0] ** 2).predict(X[:5] + 0.01))
    # noise_scale="auto" without noise_var fits nothing either (it raised AttributeError)
    auto = KrigingRegressor(range=0.5, noise_scale="auto", drift="auto").fit(X, X[:, 0] ** 2)
    assert auto.drift_ is None and auto.log_likelihood_ is None
    with pytest.raises(ValueError, match="'drift' parameter of KrigingRegressor must be"):
        KrigingRegressor(range="auto", drift="cubic").fit(X, X[:, 0])
