"""Interpolation regressors: scikit-learn tooling, bad input, duplicates, no mutation."""

import pickle
import warnings

import numpy as np
import pytest
from sklearn.base import clone
from sklearn.model_selection import GridSearchCV, KFold, cross_val_score
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import MinMaxScaler

from sklearn_psf.interpolate import (
    ChebyshevRegressor,
    DelaunayRegressor,
    DuplicateStarsWarning,
    FewStarsWarning,
    KrigingRegressor,
    PolynomialRegressor,
    RankDeficientWarning,
    RBFRegressor,
    ShepardRegressor,
)

ALL = [
    PolynomialRegressor(degree=3),
    ChebyshevRegressor(degree=3),
    RBFRegressor(kernel="thin_plate_spline"),
    ShepardRegressor(),
    KrigingRegressor(),
    DelaunayRegressor(),
]
IDS = [type(e).__name__ for e in ALL]


@pytest.fixture
def data():
    rng = np.random.default_rng(0)
    X = rng.uniform([0, 0], [2000, 1500], size=(120, 2))  # pixel-like coordinates
    u, v = X[:, 0] / 2000, X[:, 1] / 1500
    Y = np.column_stack([np.sin(3 * u) * v, u**2 - v, np.cos(2 * v)])
    return X, Y


@pytest.mark.parametrize("est", ALL, ids=IDS)
def test_pipeline_cv_clone_pickle(est, data):
    X, Y = data
    pipe = make_pipeline(MinMaxScaler(), clone(est))
    for y in (Y, Y[:, 0]):
        scores = cross_val_score(pipe, X, y, cv=KFold(3, shuffle=True, random_state=0))
        assert np.all(np.isfinite(scores)) and np.mean(scores) > 0.5
    fitted = pipe.fit(X, Y)
    again = pickle.loads(pickle.dumps(fitted))
    np.testing.assert_array_equal(again.predict(X[:7]), fitted.predict(X[:7]))
    assert clone(est).get_params() == est.get_params()


def test_gridsearch_over_kriging_range(data):
    X, Y = data
    pipe = make_pipeline(MinMaxScaler(), KrigingRegressor())
    search = GridSearchCV(pipe, {"krigingregressor__range": [0.05, 0.25, 0.5]}, cv=3).fit(X, Y)
    assert search.best_params_["krigingregressor__range"] in (0.05, 0.25, 0.5)
    assert search.predict(X[:4]).shape == (4, 3)


@pytest.mark.parametrize("est", ALL, ids=IDS)
def test_inputs_not_modified(est, data):
    X, Y = data
    X = X.copy()
    X[5] = X[6]  # a duplicate, so the merging path runs too
    Xq = X[:20] + 3.0
    copies = [a.copy() for a in (X, Y, Xq)]
    for a in (X, Y, Xq):
        a.flags.writeable = False
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DuplicateStarsWarning)
        clone(est).fit(X, Y).predict(Xq)
    for a, c in zip((X, Y, Xq), copies):
        np.testing.assert_array_equal(a, c)


@pytest.mark.parametrize("est", ALL, ids=IDS)
@pytest.mark.parametrize("where", ["X", "y", "Xq"])
@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_nan_inf_rejected(est, data, where, bad):
    X, Y = (a.copy() for a in data)
    if where == "Xq":
        Xq = X[:3].copy()
        Xq[1, 0] = bad
        with pytest.raises(ValueError, match="NaN|infinity"):
            clone(est).fit(X, Y).predict(Xq)
        return
    (X if where == "X" else Y)[4, 1] = bad
    with pytest.raises(ValueError, match="NaN|infinity"):
        clone(est).fit(X, Y)


@pytest.mark.parametrize("est", ALL, ids=IDS)
def test_mismatched_lengths(est, data):
    X, Y = data
    with pytest.raises(ValueError, match="inconsistent numbers of samples"):
        clone(est).fit(X[:-1], Y)
    with pytest.raises(ValueError, match="features"):
        clone(est).fit(X, Y).predict(np.ones((3, 3)))


@pytest.mark.parametrize(
    "est, n_ok, pattern",
    [
        (PolynomialRegressor(degree="auto"), 2, "n_samples = 1"),
        (KrigingRegressor(), 2, "at least 2 samples"),
        (DelaunayRegressor(), 3, "at least 3 samples"),
        (RBFRegressor(kernel="thin_plate_spline"), 3, "at least 3 samples"),
        (ShepardRegressor(), 1, None),
    ],
)
def test_too_few_stars(est, n_ok, pattern, data):
    X, Y = data
    if pattern is not None:
        with pytest.raises(ValueError, match=pattern):
            clone(est).fit(X[: n_ok - 1], Y[: n_ok - 1])
    if isinstance(est, KrigingRegressor):  # two stars: a sill of two values means little
        with pytest.warns(FewStarsWarning, match="only 2 distinct stars"):
            fitted = clone(est).fit(X[:n_ok], Y[:n_ok])
    else:
        fitted = clone(est).fit(X[:n_ok], Y[:n_ok])
    assert fitted.predict(X[:2]).shape == (2, 3)


def test_delaunay_collinear_stars():
    X = np.column_stack([np.linspace(0, 1, 10), 2 * np.linspace(0, 1, 10) + 1])
    with pytest.raises(ValueError, match="all stars lie on one line"):
        DelaunayRegressor().fit(X, np.arange(10.0))


def test_delaunay_too_many_features():
    X = np.random.default_rng(0).normal(size=(30, 7))
    with pytest.raises(ValueError, match="at most 6 features"):
        DelaunayRegressor().fit(X, X[:, 0])


@pytest.mark.parametrize(
    "est",
    [KrigingRegressor(), KrigingRegressor(variogram="spherical"), RBFRegressor(),
     DelaunayRegressor()],
    ids=["kriging-exp", "kriging-sph", "rbf", "delaunay"],
)
def test_duplicates_are_averaged_with_warning(est, data):
    X, Y = data
    Xd = np.vstack([X, X[[3, 3, 10]]])
    Yd = np.vstack([Y, Y[[3, 3, 10]] + [[3.0, 0, 0], [-1.5, 0, 0], [0, 0, 2.0]]])
    # the reference: one star per position, value = mean of the duplicated stars
    Ym = Y.copy()
    Ym[3, 0] += 0.5
    Ym[10, 2] += 1.0
    with pytest.warns(DuplicateStarsWarning, match=r"star indices \[\[3, 120, 121\], \[10, 122\]\]"):
        got = clone(est).fit(Xd, Yd)
    ref = clone(est).fit(X, Ym)
    Xq = np.random.default_rng(1).uniform([0, 0], [2000, 1500], size=(50, 2))
    np.testing.assert_allclose(got.predict(Xq), ref.predict(Xq), rtol=1e-9, atol=1e-9)


def test_kriging_duplicates_with_nugget_need_no_merge(data):
    X, Y = data
    Xd, Yd = np.vstack([X, X[:1]]), np.vstack([Y, Y[:1] + 1.0])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        pred = KrigingRegressor(nugget=0.1, range=500.0).fit(Xd, Yd).predict(X[:5] + 1.0)
    assert np.all(np.isfinite(pred))


def test_kriging_near_singular_system_is_a_valueerror():
    rng = np.random.default_rng(0)
    X = rng.uniform(0, 1e-3, size=(60, 2))  # stars much closer than the range
    y = rng.normal(size=60)
    with pytest.raises(ValueError, match="nugget"):
        KrigingRegressor(variogram="gaussian", range=1.0).fit(X, y)
    # the suggested remedy works
    KrigingRegressor(variogram="gaussian", range=1.0, nugget=1e-6).fit(X, y)


def test_rbf_singular_system_is_a_valueerror():
    X = np.column_stack([np.linspace(0, 1, 8), np.linspace(0, 1, 8)])  # collinear
    with pytest.raises(ValueError, match="RBF system is singular"):
        RBFRegressor(kernel="thin_plate_spline").fit(X, np.arange(8.0))


def test_polynomial_rank_deficient_warns():
    X = np.column_stack([np.linspace(0, 1, 20), np.linspace(0, 1, 20)])  # collinear
    with pytest.warns(RankDeficientWarning, match="rank"):
        PolynomialRegressor(degree=2).fit(X, X[:, 0])


@pytest.mark.parametrize(
    "est, pattern",
    [
        (PolynomialRegressor(degree="high"), "'auto'"),
        # scikit-learn's parameter validation: "The 'p' parameter of Est must be ..."
        (PolynomialRegressor(degree=-1), r"'degree' parameter .* int in the range \[0, inf"),
        (PolynomialRegressor(degree="auto", max_degree=2.5), "max_degree"),
        (ChebyshevRegressor(degree=1.5), r"'degree' parameter .* an int in the range"),
        (RBFRegressor(kernel="cubic"), "'kernel' parameter of RBFRegressor must be a str among"),
        (RBFRegressor(epsilon=0), r"'epsilon' parameter .* in the range \(0.0, inf\)"),
        (RBFRegressor(smoothing=-1), r"'smoothing' parameter .* in the range \[0.0, inf\)"),
        (ShepardRegressor(power=0), "power"),
        (KrigingRegressor(variogram="matern"), "'variogram' parameter .* must be a str among"),
        (KrigingRegressor(range=0), "'range' parameter of KrigingRegressor must be"),
        (KrigingRegressor(nugget=1.5), r"'nugget' parameter .* in the range \[0.0, 1.0\]"),
        (DelaunayRegressor(outside="extrapolate"), "'outside' parameter .* must be a str among"),
    ],
)
def test_bad_parameters(est, pattern, data):
    X, Y = data
    with pytest.raises(ValueError, match=pattern):
        est.fit(X, Y)


def test_predict_before_fit():
    from sklearn.exceptions import NotFittedError

    for est in ALL:
        with pytest.raises(NotFittedError):
            clone(est).predict(np.zeros((2, 2)))
