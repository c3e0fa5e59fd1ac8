"""IsotropicScaler, and the default interpolator it makes isotropic."""

import warnings

import numpy as np
import pytest
from scipy.spatial.distance import pdist
from sklearn.base import clone
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import MinMaxScaler
from sklearn.utils.estimator_checks import parametrize_with_checks

from sklearn_psf.interpolate import IsotropicScaler, KrigingRegressor
from sklearn_psf.model import make_default_interpolator


@parametrize_with_checks([IsotropicScaler()])
def test_sklearn_compatible(estimator, check):
    check(estimator)


def test_one_factor_for_every_axis():
    rng = np.random.default_rng(0)
    X = rng.uniform([100.0, -50.0], [4100.0, 950.0], (200, 2))  # 4:1 rectangle
    scaler = IsotropicScaler().fit(X)
    U = scaler.transform(X)
    assert scaler.scale_ == pytest.approx(1.0 / np.ptp(X[:, 0]))
    assert U.min(axis=0) == pytest.approx([0.0, 0.0], abs=1e-15)
    assert U[:, 0].max() == pytest.approx(1.0)
    assert U[:, 1].max() == pytest.approx(np.ptp(X[:, 1]) / np.ptp(X[:, 0]))
    # distances keep their proportions (MinMaxScaler's do not on a rectangle)
    ratio = pdist(U) / pdist(X)
    assert np.ptp(ratio) < 1e-12 * ratio.max()
    mm = pdist(MinMaxScaler().fit_transform(X)) / pdist(X)
    assert np.ptp(mm) > 0.1 * mm.max()
    np.testing.assert_allclose(scaler.inverse_transform(U), X, rtol=1e-13)
    # on a square span it is MinMaxScaler
    square = np.vstack([X, [[100.0, -50.0], [4100.0, 3950.0]]])
    np.testing.assert_allclose(IsotropicScaler().fit_transform(square),
                               MinMaxScaler().fit_transform(square), atol=1e-14)


def test_constant_positions():
    X = np.full((5, 2), 3.0)
    scaler = IsotropicScaler().fit(X)
    assert scaler.scale_ == 1.0
    np.testing.assert_array_equal(scaler.transform(X), 0.0)


def _isotropic_draw(n, rng):
    """Noisy values of an isotropic Gaussian field (exponential covariance, range 1500 px)
    at n stars of a 4000 x 1000 pixel field, and their noise variance."""
    X = rng.uniform([0.0, 0.0], [4000.0, 1000.0], (n, 2))
    C = np.exp(-np.sqrt(((X[:, None] - X[None]) ** 2).sum(-1)) / 1500.0)
    L = np.linalg.cholesky(C + 1e-10 * np.eye(n))
    noise = np.full((n, 2), 0.05**2)
    y = L @ rng.standard_normal((n, 2)) + 0.05 * rng.standard_normal((n, 2))
    return X, y, noise


def _fit_predict(interp, X, y, noise, Q):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        interp.fit(X, y, krigingregressor__noise_var=noise)
    return interp.predict(Q)


def test_default_interpolator_is_rotation_invariant():
    """An isotropic model of an isotropic field predicts the same values whatever the
    orientation of the detector's axes: rotating stars and queries together (30 degrees)
    leaves the default interpolator's predictions unchanged, and MinMaxScaler's not."""
    rng = np.random.default_rng(1)
    X, y, noise = _isotropic_draw(80, rng)
    Q = rng.uniform([0.0, 0.0], [4000.0, 1000.0], (50, 2))
    t = np.deg2rad(30.0)
    R = np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]])
    pred = _fit_predict(make_default_interpolator(), X, y, noise, Q)
    turned = _fit_predict(make_default_interpolator(), X @ R.T, y, noise, Q @ R.T)
    np.testing.assert_allclose(turned, pred, atol=1e-6 * np.abs(y).max())
    minmax = make_pipeline(MinMaxScaler(), KrigingRegressor(range="auto", n_neighbors="auto"))
    a = _fit_predict(minmax, X, y, noise, Q)
    b = _fit_predict(clone(minmax), X @ R.T, y, noise, Q @ R.T)
    assert np.abs(a - b).max() > 1e-3 * np.abs(y).max()
