"""Tests of sklearn_psf.metrics against brute force, analytic cases, TreeCorr and pyccl."""

import pickle
import warnings

import numpy as np
import pytest
from sklearn.base import BaseEstimator, RegressorMixin
from sklearn.decomposition import PCA
from sklearn.model_selection import GridSearchCV, KFold, cross_validate
from sklearn.neighbors import KNeighborsRegressor

from sklearn_psf.metrics import (
    SURVEYS,
    EmptyBinsWarning,
    FlaggedStampsWarning,
    ellipticity_correlation,
    ellipticity_residuals,
    hankel_xi_to_cl,
    make_coefficient_rms_scorer,
    make_ellipticity_rms_scorer,
    make_rho1_scorer,
    make_sigma_sys_scorer,
    requirement_curves,
    rho1,
    shear_bias_bound,
    shear_cl,
    sigma_sys2,
    sigma_sys2_from_cl,
    survey_requirement,
    survey_table,
)

ARCMIN = np.pi / 180 / 60
STAMP = 15


# ------------------------------------------------------------------------------------------
# helpers
# ------------------------------------------------------------------------------------------
def gaussian_stamps(e1, e2, sigma=2.0, size=STAMP):
    """Elliptical Gaussians with distortion (e1, e2): M = sigma^2 [[1+e1, e2], [e2, 1-e1]]."""
    e1, e2 = np.atleast_1d(e1), np.atleast_1d(e2)
    yy, xx = np.mgrid[0:size, 0:size] - (size - 1) / 2
    mxx, myy, mxy = sigma**2 * (1 + e1), sigma**2 * (1 - e1), sigma**2 * e2
    det = mxx * myy - mxy**2
    ixx, iyy, ixy = myy / det, mxx / det, -mxy / det
    q = (ixx[:, None, None] * xx**2 + 2 * ixy[:, None, None] * xx * yy
         + iyy[:, None, None] * yy**2)
    stamps = np.exp(-0.5 * q)
    return (stamps / stamps.sum(axis=(1, 2), keepdims=True)).reshape(len(e1), -1)


def psf_field(X):
    return 0.08 * np.sin(X[:, 0] / 150.0), 0.08 * np.cos(X[:, 1] / 120.0)


def brute_force_xi(X, e, min_sep, max_sep, nbins, X2=None, e2=None):
    """Mean Re(e_i e_j*) over pairs in log bins (i < j for an auto-correlation)."""
    if X2 is None:
        i, j = np.triu_indices(len(X), k=1)
        d = np.hypot(*(X[i] - X[j]).T)
        prod = (e[i] * np.conj(e[j])).real
    else:
        d = np.hypot(X[:, None, 0] - X2[None, :, 0], X[:, None, 1] - X2[None, :, 1]).ravel()
        prod = (e[:, None] * np.conj(e2[None, :])).real.ravel()
    keep = (d >= min_sep) & (d < max_sep)
    idx = np.floor(np.log(d[keep] / min_sep) / (np.log(max_sep / min_sep) / nbins)).astype(int)
    npairs = np.bincount(idx, minlength=nbins)
    xi = np.bincount(idx, weights=prod[keep], minlength=nbins) / npairs
    meanr = np.bincount(idx, weights=d[keep], minlength=nbins) / npairs
    return xi, npairs, meanr


class StandIn(RegressorMixin, BaseEstimator):
    """Minimal PSF model: predicts Gaussian stamps with the true field's e plus a fixed offset."""

    def __init__(self, offset=0.0):
        self.offset = offset

    def fit(self, X, y):
        self.basis_ = PCA(n_components=3).fit(np.asarray(y))
        return self

    def predict(self, X):
        e1, e2 = psf_field(np.asarray(X))
        return gaussian_stamps(e1 + self.offset, e2)

    def predict_coefficients(self, X):
        return self.basis_.transform(self.predict(X)) + self.offset


@pytest.fixture(scope="module")
def psf_data():
    rng = np.random.default_rng(42)
    X = rng.uniform(0, 1000, (400, 2))
    return X, gaussian_stamps(*psf_field(X))


# ------------------------------------------------------------------------------------------
# correlation functions
# ------------------------------------------------------------------------------------------
def test_xi_matches_brute_force_pair_sum():
    rng = np.random.default_rng(0)
    X = rng.uniform(0, 100, (2000, 2))
    e1 = 0.05 * np.sin(X[:, 0] / 15) + 0.01 * rng.standard_normal(2000)
    e2 = 0.05 * np.cos(X[:, 1] / 20) + 0.01 * rng.standard_normal(2000)
    res = ellipticity_correlation(X, e1, e2, min_sep=1.0, max_sep=50.0, nbins=12, bin_slop=0)
    xi, npairs, meanr = brute_force_xi(X, e1 + 1j * e2, 1.0, 50.0, 12)
    np.testing.assert_array_equal(res.npairs, npairs)
    np.testing.assert_allclose(res.xi, xi, rtol=1e-6, atol=1e-12)
    # meanr comes from cell centres for cell pairs wholly inside one bin: close, not exact
    np.testing.assert_allclose(res.theta, meanr, rtol=2e-3)
    # sign / normalisation: the field is positively correlated at small separations
    assert res.xi[0] > 0
    # shape-noise error: TreeCorr's sqrt(varxip), which scales as 1 / sqrt(npairs)
    np.testing.assert_allclose(res.sigma_xi * np.sqrt(npairs),
                               res.sigma_xi[0] * np.sqrt(npairs[0]), rtol=1e-10)


def test_cross_correlation_matches_brute_force():
    rng = np.random.default_rng(1)
    X, X2 = rng.uniform(0, 60, (600, 2)), rng.uniform(0, 60, (500, 2))
    e = 0.03 * np.exp(1j * X[:, 0] / 10)
    f = 0.03 * np.exp(1j * X2[:, 0] / 10) + 0.01
    res = ellipticity_correlation(X, e.real, e.imag, min_sep=0.5, max_sep=30, nbins=8,
                                  X2=X2, e1_2=f.real, e2_2=f.imag, bin_slop=0)
    xi, npairs, _ = brute_force_xi(X, e, 0.5, 30, 8, X2, f)
    np.testing.assert_array_equal(res.npairs, npairs)
    np.testing.assert_allclose(res.xi, xi, rtol=1e-6, atol=1e-12)


def test_constant_field_and_units():
    rng = np.random.default_rng(2)
    X = rng.uniform(0, 10, (300, 2))  # arcmin
    e1, e2 = np.full(300, 0.03), np.full(300, -0.04)
    res = ellipticity_correlation(X, e1, e2, min_sep=0.2, max_sep=5, nbins=4)
    np.testing.assert_allclose(res.xi, 0.03**2 + 0.04**2, rtol=1e-6)
    np.testing.assert_allclose(res.xi_im, 0.0, atol=1e-12)
    res_arcsec = ellipticity_correlation(X, e1, e2, min_sep=12, max_sep=300, nbins=4,
                                         x_units="arcmin", sep_units="arcsec")
    np.testing.assert_allclose(res_arcsec.theta, 60 * res.theta, rtol=1e-6)
    table = res.to_table()
    assert list(table.colnames) == ["theta", "theta_nominal", "xi", "xi_im", "sigma_xi", "npairs"]


def test_rho1_is_correlation_of_residuals():
    rng = np.random.default_rng(3)
    X = rng.uniform(0, 50, (500, 2))
    t1, t2 = psf_field(X * 20)
    m1, m2 = t1 + 0.01 * rng.standard_normal(500), t2 + 0.01 * rng.standard_normal(500)
    d1 = rho1(X, t1, t2, m1, m2, min_sep=1, max_sep=20, nbins=5, bin_slop=0)
    xi, _, _ = brute_force_xi(X, (t1 - m1) + 1j * (t2 - m2), 1, 20, 5)
    np.testing.assert_allclose(d1.xi, xi, rtol=1e-6, atol=1e-14)


def test_empty_bins_are_nan_with_warning():
    X = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    with pytest.warns(EmptyBinsWarning):
        res = ellipticity_correlation(X, [0.1, 0.1, 0.1], [0, 0, 0], min_sep=0.5, max_sep=5,
                                      nbins=4)
    assert np.isnan(res.xi).sum() == (res.npairs == 0).sum() > 0


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(X=[[0.0, 0.0]], e1=[0.1], e2=[0.0]), "at least two points"),
        (dict(e1=[0.1, np.nan, 0.0]), "NaN"),
        (dict(e2=[0.1, 0.0]), "3 rows"),
        (dict(min_sep=5.0, max_sep=5.0), "smaller than max_sep"),
        (dict(min_sep=10.0, max_sep=20.0), "No pair"),
        (dict(X=[[0, 0], [1, 0], [0, np.inf]]), "infinite"),
        (dict(X2=[[0, 0], [1, 1]]), "all of X2"),
        (dict(sep_units="arcmin"), "both x_units and sep_units"),
    ],
)
def test_bad_input(kwargs, message):
    args = dict(X=[[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]], e1=[0.1, 0.0, 0.0], e2=[0.0, 0.1, 0.0],
                min_sep=0.5, max_sep=3.0, nbins=2)
    args.update(kwargs)
    with pytest.raises(ValueError, match=message):
        ellipticity_correlation(**args)


# ------------------------------------------------------------------------------------------
# weak-lensing systematics
# ------------------------------------------------------------------------------------------
def test_survey_table_matches_paper():
    table = survey_table()
    assert list(table["survey"]) == list(SURVEYS)
    values = dict(zip(table["survey"], table["sigma_sys2"]))
    assert round(values["CFHTLS"], 7) == pytest.approx(2.0e-6)
    assert round(values["COSMOS"], 7) == pytest.approx(8.4e-6)
    assert round(values["COSMOS"], 6) == pytest.approx(8e-6)
    assert round(values["Stage IV"], 8) == pytest.approx(1.2e-7)
    assert survey_requirement(2e4, 35, 0.9) == pytest.approx(1e-7)
    with pytest.raises(ValueError):
        survey_requirement(-1, 10, 0.5)


def test_shear_bias_bound_analytic():
    assert shear_bias_bound(1e-6) == pytest.approx(1e-6 * (1 / 1.5) ** 4 / 1.84**2)
    np.testing.assert_allclose(shear_bias_bound([-2e-6, 2e-6], p_gamma=2.0, size_ratio=0.5),
                               [2e-6 / 64, 2e-6 / 64])
    with pytest.raises(ValueError):
        shear_bias_bound(1e-6, p_gamma=0)


@pytest.mark.parametrize("extrapolation", ["smooth", "zero"])
def test_hankel_transform_gaussian_pair(extrapolation):
    s = 3.0  # arcmin
    theta = np.geomspace(0.005, 30, 200)
    ell = np.geomspace(10, 20000, 40)
    cl = hankel_xi_to_cl(theta, 2e-5 * np.exp(-theta**2 / (2 * s**2)), ell,
                         extrapolation=extrapolation)
    s_rad = s * ARCMIN
    expected = 2 * np.pi * 2e-5 * s_rad**2 * np.exp(-(ell**2) * s_rad**2 / 2)
    np.testing.assert_allclose(cl, expected, rtol=1e-3, atol=1e-5 * expected.max())


def test_sigma_sys2_from_cl_analytic():
    ell = np.geomspace(10, 20000, 512)
    assert sigma_sys2_from_cl(ell, -3e-9 / (ell * (ell + 1))) == pytest.approx(
        3e-9 * np.log(2000) / (2 * np.pi), rel=1e-6)
    # Gaussian xi: sigma_sys^2 = (1/2pi) Int C_l l(l+1) dl/l, with the analytic Gaussian C_l
    s_rad = 3.0 * ARCMIN
    theta = np.geomspace(0.005, 30, 200)
    fine = np.geomspace(10, 20000, 20001)
    exact = np.trapezoid(2 * np.pi * s_rad**2 * np.exp(-(fine**2) * s_rad**2 / 2)
                         * (fine + 1), fine) / (2 * np.pi)
    assert sigma_sys2(theta, np.exp(-theta**2 / 18)) == pytest.approx(exact, rel=1e-3)


@pytest.fixture(scope="module")
def wide_theta():
    return np.geomspace(0.01, 3000, 400)


def test_constant_fraction_of_shear_gives_f_times_shear_sigma_sys2(wide_theta):
    curves = requirement_curves(wide_theta)
    ell = np.geomspace(10, 20000, 512)
    s_direct = sigma_sys2_from_cl(ell, shear_cl(ell))  # pyccl C_l, no Hankel transform
    assert curves.sigma_sys2_shear == pytest.approx(s_direct, rel=1e-12)
    assert 1e-4 < s_direct < 1e-3  # order of magnitude of xi+(0) for z_m = 0.9
    f = 3e-3
    assert sigma_sys2(wide_theta, f * curves.xi_plus_shear) == pytest.approx(f * s_direct,
                                                                            rel=0.02)


def test_requirement_curves_consistent_with_levels(wide_theta):
    curves = requirement_curves(wide_theta, (1e-5, 1e-6, 1e-7))
    factor = (1 / 1.5) ** 4 / 1.84**2
    for level, d1 in zip(curves.levels, curves.d1_limit):
        assert sigma_sys2(wide_theta, d1 * factor) == pytest.approx(level, rel=0.03)
    np.testing.assert_allclose(curves.d1_limit[0] / curves.d1_limit[1], 10.0)
    # cached: a second call with the same arguments does not call pyccl again
    from sklearn_psf.metrics._systematics import _shear_xi_plus_cached

    hits = _shear_xi_plus_cached.cache_info().hits
    requirement_curves(wide_theta, (1e-6,))
    assert _shear_xi_plus_cached.cache_info().hits == hits + 1
    # a higher sigma_8 raises the shear signal, hence lowers the allowed fraction
    other = requirement_curves(wide_theta[::40], cosmology={"sigma8": 0.9})
    assert other.sigma_sys2_shear > curves.sigma_sys2_shear
    with pytest.raises(TypeError, match="cosmology"):
        requirement_curves(wide_theta, cosmology="Planck")


def test_sigma_sys2_bad_input():
    with pytest.raises(ValueError, match="NaN"):
        sigma_sys2([1.0, 2.0, 3.0], [1e-7, np.nan, 1e-8])
    with pytest.raises(ValueError, match="same length"):
        sigma_sys2([1.0, 2.0, 3.0], [1e-7, 1e-8])
    with pytest.raises(ValueError, match="increasing"):
        sigma_sys2([2.0, 1.0], [1e-7, 1e-8])
    with pytest.raises(ValueError, match="extrapolation"):
        sigma_sys2([1.0, 2.0], [1e-7, 1e-8], extrapolation="linear")
    with pytest.raises(ValueError, match="ell_min"):
        sigma_sys2([1.0, 2.0], [1e-7, 1e-8], ell_min=100, ell_max=10)


# ------------------------------------------------------------------------------------------
# scorers
# ------------------------------------------------------------------------------------------
def test_ellipticity_residuals_and_flags():
    X = np.random.default_rng(5).uniform(0, 1000, (20, 2))
    e1, e2 = psf_field(X)
    true, model = gaussian_stamps(e1, e2), gaussian_stamps(e1 + 0.02, e2)
    de1, de2, mask = ellipticity_residuals(true, model)
    assert mask.all()
    np.testing.assert_allclose(de1, -0.02, atol=2e-4)
    np.testing.assert_allclose(de2, 0.0, atol=2e-4)
    model[:3] = 0.0  # no flux: flagged by adaptive_moments
    with pytest.warns(FlaggedStampsWarning, match="3 of 20"):
        de1, _, mask = ellipticity_residuals(true, model)
    assert mask.sum() == 17 and de1.shape == (17,)
    with pytest.raises(ValueError, match="flagged 3 of 20"):
        ellipticity_residuals(true, model, max_flagged_fraction=0.1)
    with pytest.raises(ValueError, match="same shape"):
        ellipticity_residuals(true, model[:5])


def test_scorer_values_on_stand_in(psf_data):
    X, y = psf_data
    offset = 0.03
    est = StandIn(offset=offset).fit(X, y)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        e_rms = make_ellipticity_rms_scorer()(est, X, y)
        rho = make_rho1_scorer(20, 400, nbins=5)(est, X, y)
        coef = make_coefficient_rms_scorer()(est, X, y)
    # model e = true e + (offset, 0): |de| = offset everywhere, so D1 = offset^2 at all scales
    assert e_rms == pytest.approx(-offset, rel=1e-2)
    assert rho == pytest.approx(-(offset**2), rel=2e-2)
    # predict_coefficients = transform(predicted stamps) + offset
    expected = np.sqrt(np.mean((est.basis_.transform(est.predict(X)) + offset
                                - est.basis_.transform(y)) ** 2))
    assert coef == pytest.approx(-expected, rel=1e-10)
    # sigma_sys^2 scorer == the chain rho1 -> shear_bias_bound -> sigma_sys2, units in arcmin
    scorer = make_sigma_sys_scorer(1.0, 20.0, nbins=6, arcmin_per_unit=0.05)
    de1, de2, _ = ellipticity_residuals(y, est.predict(X))
    r = ellipticity_correlation(X * 0.05, de1, de2, min_sep=1.0, max_sep=20.0, nbins=6,
                                num_threads=1)
    assert scorer(est, X, y) == pytest.approx(-sigma_sys2(r.theta, shear_bias_bound(r.xi)))
    # perfect model: all scores ~ 0, the best possible
    perfect = StandIn().fit(X, y)
    assert make_ellipticity_rms_scorer()(perfect, X, y) > e_rms
    assert make_rho1_scorer(20, 400, nbins=5)(perfect, X, y) > rho


def test_scorers_pickle_and_validate():
    scorers = [make_rho1_scorer(1, 10), make_ellipticity_rms_scorer(),
               make_coefficient_rms_scorer(n_components=2),
               make_sigma_sys_scorer(0.5, 10, arcmin_per_unit=0.2 / 60)]
    for scorer in scorers:
        clone = pickle.loads(pickle.dumps(scorer))
        assert repr(clone) == repr(scorer)
    with pytest.raises(ValueError, match="smaller than max_sep"):
        make_rho1_scorer(10, 1)
    with pytest.raises(ValueError, match="statistic"):
        make_rho1_scorer(1, 10, statistic="median")
    with pytest.raises(ValueError, match="arcmin_per_unit"):
        make_sigma_sys_scorer(1, 10, arcmin_per_unit=0)
    with pytest.raises(ValueError, match="one stamp per position"):
        make_ellipticity_rms_scorer()(StandIn(), np.zeros((3, 2)), np.zeros((2, STAMP**2)))


def test_scorers_in_cross_validate_and_grid_search(psf_data):
    from sklearn_psf.model import PSFModel

    X, y = psf_data
    scoring = {
        "rho1": make_rho1_scorer(30, 300, nbins=4),
        "e_rms": make_ellipticity_rms_scorer(),
        "coef_rms": make_coefficient_rms_scorer(),
        "sigma_sys2": make_sigma_sys_scorer(0.5, 8.0, nbins=4, arcmin_per_unit=1 / 60),
    }
    cv = KFold(3, shuffle=True, random_state=0)
    good = PSFModel(interpolator=KNeighborsRegressor(4, weights="distance"), outliers=None)
    bad = PSFModel(interpolator=KNeighborsRegressor(200), outliers=None)  # ~ field mean
    res_good = cross_validate(good, X, y, cv=cv, scoring=scoring, n_jobs=2,
                              error_score="raise")
    res_bad = cross_validate(bad, X, y, cv=cv, scoring=scoring, error_score="raise")
    for name in scoring:
        assert np.all(np.isfinite(res_good[f"test_{name}"]))
        assert res_good[f"test_{name}"].mean() > res_bad[f"test_{name}"].mean(), name
        assert np.all(res_good[f"test_{name}"] <= 0)
    search = GridSearchCV(good, {"interpolator__n_neighbors": [200, 4, 50]},
                          scoring=scoring["rho1"], cv=cv, error_score="raise").fit(X, y)
    assert search.best_params_ == {"interpolator__n_neighbors": 4}
    ranks = dict(zip(search.cv_results_["param_interpolator__n_neighbors"],
                     search.cv_results_["rank_test_score"]))
    assert ranks[4] < ranks[50] < ranks[200]
