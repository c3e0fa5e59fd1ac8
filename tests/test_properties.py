"""Properties every interpolator must have, for any star layout (hypothesis draws the layouts).

- Polynomial and Chebyshev regressors of degree d reproduce any polynomial of degree <= d.
- Delaunay triangulation reproduces any affine field inside the convex hull of the stars.
- Ordinary Kriging reproduces a constant field (the unbiasedness constraint) and is exact at
  the stars, whatever the variogram and range.
- Shepard's weights are convex: predictions lie between the smallest and largest star value,
  and equal the star's value on a star.
"""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial import Delaunay

from sklearn_psf.interpolate import (
    ChebyshevRegressor,
    DelaunayRegressor,
    KrigingRegressor,
    PolynomialRegressor,
    ShepardRegressor,
)

SETTINGS = settings(max_examples=25, deadline=None)


def _layout(seed, n):
    """n distinct star positions in the unit square and 50 query points."""
    rng = np.random.default_rng(seed)
    X = rng.uniform(0, 1, (n, 2))
    return X, rng.uniform(0, 1, (50, 2)), rng


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), degree=st.integers(0, 4), n=st.integers(40, 120))
def test_polynomials_reproduce_polynomials(seed, degree, n):
    X, Q, rng = _layout(seed, n)
    powers = [(i, j) for i in range(degree + 1) for j in range(degree + 1 - i)]
    coef = rng.normal(size=len(powers))

    def field(P):
        return sum(c * P[:, 0] ** i * P[:, 1] ** j for c, (i, j) in zip(coef, powers))

    for reg in (PolynomialRegressor(degree=degree), ChebyshevRegressor(degree=degree)):
        pred = reg.fit(X, field(X)).predict(Q)
        np.testing.assert_allclose(pred, field(Q), atol=1e-8 * (1 + np.abs(coef).sum()))


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(4, 80))
def test_delaunay_reproduces_affine_fields_inside_the_hull(seed, n):
    X, Q, rng = _layout(seed, n)
    Q = np.vstack([Q, X.mean(axis=0)])  # the centroid: at least one query inside the hull
    a, b, c = rng.normal(size=3)
    inside = Delaunay(X).find_simplex(Q) >= 0
    pred = DelaunayRegressor().fit(X, a + b * X[:, 0] + c * X[:, 1]).predict(Q[inside])
    np.testing.assert_allclose(pred, a + b * Q[inside, 0] + c * Q[inside, 1], atol=1e-9)


@pytest.mark.filterwarnings("ignore::sklearn_psf.interpolate.FewStarsWarning")
@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(3, 80),
       variogram=st.sampled_from(["exponential", "spherical"]),
       range_=st.floats(0.1, 1.5), nugget=st.sampled_from([0.0, 0.1]))
def test_kriging_is_unbiased_and_exact_at_the_stars(seed, n, variogram, range_, nugget):
    X, Q, rng = _layout(seed, n)
    y = rng.normal(size=(n, 2))
    kriging = KrigingRegressor(variogram=variogram, range=range_, nugget=nugget)
    np.testing.assert_allclose(kriging.fit(X, y).predict(X), y, atol=1e-7)
    # a constant field: the weights sum to one, so the prediction is the constant everywhere
    const = np.column_stack([np.full(n, 3.0), np.full(n, -1.5), y[:, 0]])
    pred = kriging.fit(X, const).predict(Q)
    np.testing.assert_allclose(pred[:, :2], np.broadcast_to([3.0, -1.5], (len(Q), 2)), atol=1e-8)


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(2, 80), power=st.floats(1.0, 6.0))
def test_shepard_weights_are_convex(seed, n, power):
    X, Q, rng = _layout(seed, n)
    y = rng.normal(size=n)
    shepard = ShepardRegressor(power=power).fit(X, y)
    pred = shepard.predict(Q)
    assert np.all(pred >= y.min() - 1e-12) and np.all(pred <= y.max() + 1e-12)
    np.testing.assert_allclose(shepard.predict(X), y, atol=1e-12)
