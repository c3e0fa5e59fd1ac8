"""Multi-exposure simulations, per-exposure and pooled PSF models, focal-plane positions."""

import os
import pickle
import warnings

import joblib
import numpy as np
import pytest
from sklearn.base import clone
from sklearn.model_selection import GridSearchCV, KFold
from sklearn.pipeline import make_pipeline
from sklearn.utils.estimator_checks import parametrize_with_checks
from threadpoolctl import threadpool_limits

from sklearn_psf.interpolate import ExposureKrigingRegressor
from sklearn_psf.measure import adaptive_moments
from sklearn_psf.model import (
    FocalPlaneMapper,
    PerExposurePSFModel,
    PooledPSFModel,
    PSFModel,
    make_default_interpolator,
)
from sklearn_psf.simulate import DetectorSettings, make_exposures, make_psf_field

SMALL = dict(n_stars=60, n_galaxies=40, image_shape=(700, 700), dither=40.0)


@pytest.fixture(scope="module")
def exposures():
    return make_exposures(3, random_state=1, **SMALL)


# ---------------------------------------------------------------- simulations
def test_static_pattern_shared_and_atmosphere_varies():
    ref_kw = dict(n_stars=30, n_galaxies=200, image_shape=(800, 800), random_state=3)
    static = make_exposures(2, atmosphere_ratio=0.0, dither=0.0, **ref_kw)
    w = [np.asarray(f.galaxies["coeffs"]) for f in static.exposures]
    np.testing.assert_allclose(w[0], w[1], rtol=0, atol=1e-12)  # same optics, same place
    a = 1.0
    moving = make_exposures(2, atmosphere_ratio=a, dither=0.0, **ref_kw)
    std = moving.exposures[0].reference.coeff_std
    d = [np.asarray(f.galaxies["coeffs"]) for f in moving.exposures]
    # Var(w0 - w1) / coeff_std^2 = 2 a^2 / (1 + a^2) for independent unit-variance atmospheres
    ratio = np.var(d[0] - d[1], axis=0) / std ** 2
    assert 0.6 < np.median(ratio) < 1.4


def test_dithers_move_galaxies_and_seeds_nest(exposures):
    sky = np.column_stack([exposures.galaxies["x"], exposures.galaxies["y"]])
    for f, d in zip(exposures.exposures, exposures.dithers):
        chip = np.column_stack([f.galaxies["x"], f.galaxies["y"]])
        np.testing.assert_allclose(chip, sky - d)
        assert np.all(np.abs(d) <= SMALL["dither"])
    assert len({tuple(d) for d in exposures.dithers}) == 3
    two = make_exposures(2, random_state=1, **SMALL)
    for a, b in zip(two.exposures, exposures.exposures):
        np.testing.assert_array_equal(a.image, b.image)
    X, stamps, weights = exposures.star_data(return_weights=True)
    assert X.shape == (len(stamps), 3) and weights.shape == stamps.shape
    assert set(np.unique(X[:, 2])) == {0.0, 1.0, 2.0}


def test_make_exposures_bad_input():
    with pytest.raises(ValueError, match="n_exposures"):
        make_exposures(0, **SMALL)
    with pytest.raises(ValueError, match="too small for dithers"):
        make_exposures(2, n_stars=10, image_shape=(300, 300), dither=200.0)
    with pytest.raises(ValueError, match="atmosphere_ratio"):
        make_exposures(2, atmosphere_ratio=-1, **SMALL)


# ---------------------------------------------------------------- models
def test_one_exposure_equals_psf_model(exposures):
    X, stamps = exposures.star_data([0])
    single = PSFModel().fit(X[:, :2], stamps)
    X_gal, _ = exposures.galaxy_data([0])
    for model in (PooledPSFModel(), PerExposurePSFModel()):
        model.fit(X, stamps)
        np.testing.assert_allclose(model.predict(X_gal), single.predict(X_gal[:, :2]),
                                   rtol=0, atol=1e-14)


def test_per_exposure_is_one_model_each(exposures):
    X, stamps = exposures.star_data()
    model = PerExposurePSFModel().fit(X, stamps)
    X_gal, truth = exposures.galaxy_data()
    pred = model.predict(X_gal)
    for e in range(3):
        own = PSFModel().fit(X[X[:, 2] == e, :2], stamps[X[:, 2] == e])
        sel = X_gal[:, 2] == e
        np.testing.assert_allclose(pred[sel], own.predict(X_gal[sel, :2]), rtol=0, atol=1e-14)


def _e_residual(model, exp):
    X_gal, truth = exp.galaxy_data()
    mom = adaptive_moments(model.predict(X_gal))
    return np.sqrt(np.mean((np.asarray(mom["e1"]) - truth["e1"]) ** 2
                           + (np.asarray(mom["e2"]) - truth["e2"]) ** 2))


def test_pooled_beats_per_exposure_on_a_static_pattern():
    # strong static optics (atmosphere 0.2 of its rms), 4 exposures, paired over 3 seeds
    wins = []
    for seed in range(3):
        exp = make_exposures(4, n_stars=40, n_galaxies=60, image_shape=(800, 800), dither=60.0,
                             atmosphere_ratio=0.2, random_state=seed)
        X, stamps = exp.star_data()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            pooled = _e_residual(PooledPSFModel().fit(X, stamps), exp)
            per = _e_residual(PerExposurePSFModel().fit(X, stamps), exp)
        wins.append(pooled < per)
    assert all(wins)


def test_clone_pickle_joblib_and_grid_search(exposures, tmp_path):
    X, stamps = exposures.star_data()
    model = PooledPSFModel().fit(X, stamps)
    assert clone(model).get_params()["exposure_column"] == -1
    again = pickle.loads(pickle.dumps(model))
    np.testing.assert_array_equal(again.predict(X[:5]), model.predict(X[:5]))
    joblib.dump(model, tmp_path / "pooled.joblib")
    np.testing.assert_array_equal(joblib.load(tmp_path / "pooled.joblib").predict(X[:5]),
                                  model.predict(X[:5]))
    fixed = ExposureKrigingRegressor(range=0.3, atmosphere_range=0.1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        search = GridSearchCV(PooledPSFModel(model=PSFModel(outliers=None)),
                              {"interpolator": [fixed, ExposureKrigingRegressor()]},
                              cv=KFold(2, shuffle=True, random_state=0),
                              error_score="raise").fit(X, stamps)
    assert len(search.cv_results_["mean_test_score"]) == 2
    assert np.all(np.isfinite(search.cv_results_["mean_test_score"]))
    assert search.best_estimator_.predict(X[:2]).shape == (2, stamps.shape[1])


def test_bad_input(exposures):
    X, stamps = exposures.star_data()
    model = PooledPSFModel().fit(X, stamps)
    with pytest.raises(ValueError, match=r"Exposures \[7\] were not in the fit"):
        model.predict(np.array([[100.0, 100.0, 7.0]]))
    bad = X.copy()
    bad[0, 2] = 0.5
    with pytest.raises(ValueError, match="integer exposure indices"):
        PerExposurePSFModel().fit(bad, stamps)
    with pytest.raises(ValueError, match="requires y"):
        PooledPSFModel().fit(X, None)
    # an exposure with 2 stars: the pooled model still predicts it (from the static part and
    # its own two stars), where a per-exposure model cannot
    few = X[:, 2] == 0
    X_few = np.vstack([X[few], X[X[:, 2] == 1][:2]])
    y_few = np.vstack([stamps[few], stamps[X[:, 2] == 1][:2]])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        pooled = PooledPSFModel(model=PSFModel(outliers=None)).fit(X_few, y_few)
    assert np.all(np.isfinite(pooled.predict(np.array([[300.0, 300.0, 1.0]]))))
    with pytest.raises(ValueError, match="at least 3"):
        PerExposurePSFModel(model=PSFModel(outliers=None)).fit(X_few, y_few)
    before = X.copy()
    PerExposurePSFModel().fit(X, stamps)
    np.testing.assert_array_equal(X, before)


# ---------------------------------------------------------------- focal plane
def test_focal_plane_one_model_over_ccds():
    # one exposure over a 2 x 1 mosaic of 500 x 900 pixel CCDs with a 40 pixel gap
    field = make_psf_field(n_stars=120, n_galaxies=30, image_shape=(900, 1040), random_state=4)
    origins = np.array([[0.0, 0.0], [540.0, 0.0]])
    X = np.column_stack([field.stars["x"], field.stars["y"]])
    stamps, _ = field.star_stamps()
    ccd = (X[:, 0] >= 520).astype(float)
    keep = (X[:, 0] < 480) | (X[:, 0] >= 560)  # stars in the gap fall off both CCDs
    local = np.column_stack([X[:, 0] - origins[ccd.astype(int), 0], X[:, 1], ccd])[keep]
    mapper = FocalPlaneMapper(origins)
    np.testing.assert_array_equal(mapper.fit_transform(local), X[keep])
    steps = [step for _, step in make_default_interpolator().steps]
    interp = make_pipeline(FocalPlaneMapper(origins), *steps)
    focal = PSFModel(interpolator=interp).fit(local, stamps[keep])
    plain = PSFModel().fit(X[keep], stamps[keep])
    G = np.column_stack([field.galaxies["x"], field.galaxies["y"]])
    G_local = np.column_stack([G[:, 0] - origins[(G[:, 0] >= 520).astype(int), 0], G[:, 1],
                               (G[:, 0] >= 520).astype(float)])
    np.testing.assert_allclose(focal.predict(G_local), plain.predict(G), rtol=0, atol=1e-12)


def test_focal_plane_rotation_and_errors():
    m = FocalPlaneMapper([[100.0, 50.0]], ccd_angles=[90.0]).fit(np.zeros((1, 3)))
    np.testing.assert_allclose(m.transform([[10.0, 0.0, 0.0]]), [[100.0, 60.0]], atol=1e-12)
    with pytest.raises(ValueError, match="CCD indices"):
        m.transform([[1.0, 2.0, 3.0]])
    with pytest.raises(ValueError, match="ccd_origins"):
        FocalPlaneMapper([1.0, 2.0]).fit(np.zeros((2, 3)))


# ---------------------------------------------------------------- estimator checks
_RANDOM_X = ("the check's X has no integer exposure column: the exposure index is data, "
             "and a random float column is no index")
_CCD = "the check's X has no CCD index column"
_MODEL_FAILS = [
    "check_fit_score_takes_y", "check_estimators_overwrite_params",
    "check_dont_overwrite_parameters", "check_estimators_fit_returns_self",
    "check_readonly_memmap_input", "check_n_features_in_after_fitting",
    "check_positive_only_tag_during_fit", "check_estimators_dtypes", "check_dtype_object",
    "check_pipeline_consistency", "check_estimators_nan_inf", "check_estimators_pickle",
    "check_f_contiguous_array_estimator", "check_regressors_train",
    "check_regressor_data_not_an_array", "check_regressor_multioutput",
    "check_regressors_no_decision_function", "check_regressors_int",
    "check_methods_sample_order_invariance", "check_methods_subset_invariance",
    "check_dict_unchanged", "check_fit_idempotent", "check_fit_check_is_fitted",
    "check_n_features_in", "check_fit2d_predict1d",
]
_MAPPER_FAILS = [
    "check_fit_score_takes_y", "check_estimators_overwrite_params",
    "check_estimators_fit_returns_self", "check_readonly_memmap_input",
    "check_estimators_dtypes", "check_dtype_object", "check_pipeline_consistency",
    "check_estimators_pickle", "check_f_contiguous_array_estimator",
    "check_transformer_data_not_an_array", "check_transformer_general",
    "check_transformer_preserve_dtypes", "check_methods_sample_order_invariance",
    "check_methods_subset_invariance", "check_dict_unchanged", "check_fit_idempotent",
    "check_fit_check_is_fitted", "check_n_features_in",
]


def _expected(estimator):
    if isinstance(estimator, FocalPlaneMapper):
        return dict.fromkeys(_MAPPER_FAILS, _CCD)
    return dict.fromkeys(_MODEL_FAILS, _RANDOM_X)


@parametrize_with_checks(
    [PooledPSFModel(), PerExposurePSFModel(), FocalPlaneMapper([[0.0, 0.0], [100.0, 0.0]])],
    expected_failed_checks=_expected,
)
def test_sklearn_compatible(estimator, check):
    check(estimator)


def test_pooled_on_realistic_exposures_rejects_contaminants():
    # masked pixels and cosmic rays on 10% of the stars of each exposure, weights given
    exp = make_exposures(2, n_stars=80, n_galaxies=20, image_shape=(900, 900), dither=40.0,
                         contaminants={"cosmic_ray": 0.1},
                         detector=DetectorSettings(masked_fraction=0.002),
                         random_state=7)
    X, stamps, weights = exp.star_data(return_weights=True)
    assert np.any(weights == 0)
    kinds = np.concatenate([np.asarray(f.stars["contaminant"])[f.star_stamps()[1] == 0]
                            for f in exp.exposures])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = PooledPSFModel().fit(X, stamps, weights)
    hit = kinds == "cosmic_ray"
    assert hit.sum() >= 10
    assert np.mean(~model.inlier_mask_[hit]) > 0.7  # most cosmic rays rejected
    assert np.mean(model.inlier_mask_[~hit]) > 0.9  # clean stars kept


# ---------------------------------------------------------------- saving, parallel fits
@pytest.mark.parametrize("cls", [PooledPSFModel, PerExposurePSFModel])
def test_save_and_load_predict_identically(cls, exposures, tmp_path):
    X, stamps = exposures.star_data()
    X_gal, _ = exposures.galaxy_data()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = cls().fit(X, stamps)
    path = tmp_path / "model.fits"
    model.save(path)
    back = cls.load(path)
    if cls is PooledPSFModel:  # the coefficients co-Kriged with their noise covariance
        assert back.model_.interpolator_.n_cg_iter_ == model.model_.interpolator_.n_cg_iter_ > 0
    # the same model: equal up to rounding (a conjugate-gradient solve's last bits differ
    # between CPUs, e.g. by 3e-20 on AMD EPYC, between a fit and a reload)
    np.testing.assert_allclose(back.predict(X_gal), model.predict(X_gal), rtol=1e-12,
                               atol=1e-18)
    np.testing.assert_array_equal(back.inlier_mask_, model.inlier_mask_)
    np.testing.assert_array_equal(back.exposures_, model.exposures_)
    with pytest.raises(FileExistsError):
        model.save(path)
    other = PerExposurePSFModel if cls is PooledPSFModel else PooledPSFModel
    with pytest.raises(ValueError, match="not a .* model: load it with"):
        other.load(path)
    from sklearn_psf.model import load_model
    with pytest.raises(ValueError, match="multi-exposure model"):
        load_model(path)


def test_pooled_files_before_format_4_keep_their_scaling(exposures, tmp_path, monkeypatch):
    # formats 1-3 scaled each axis to [0, 1]: on a rectangular field such a file still
    # predicts as the model it was written from, not as today's isotropic scaling
    from astropy.io import fits

    from sklearn_psf.interpolate import ExposureKrigingRegressor

    X, stamps = exposures.star_data()
    X_gal, _ = exposures.galaxy_data()
    X, X_gal = X * [2.5, 1.0, 1.0], X_gal * [2.5, 1.0, 1.0]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        new = PooledPSFModel().fit(X, stamps)
        monkeypatch.setattr(ExposureKrigingRegressor, "_per_axis_scaling", True)
        old = PooledPSFModel().fit(X, stamps)
        old.save(tmp_path / "old.fits")  # (its interpolator's state says so)
    monkeypatch.undo()
    np.testing.assert_allclose(PooledPSFModel.load(tmp_path / "old.fits").predict(X_gal),
                               old.predict(X_gal), rtol=0, atol=1e-10)
    assert np.abs(old.predict(X_gal) - new.predict(X_gal)).max() > 1e-6
    # a file of format 3 (the committed format-7 file of tests/data/models restamped) is
    # read with that scaling, the format-7 file without
    v7 = os.path.join(os.path.dirname(__file__), "data", "models", "pooled.fits.gz")
    with fits.open(v7) as hdul:
        hdul[0].header["FORMAT"] = 3
        hdul.writeto(tmp_path / "v3.fits")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        v3 = PooledPSFModel.load(tmp_path / "v3.fits").model_.interpolator_
        v7 = PooledPSFModel.load(v7).model_.interpolator_
    assert v3._per_axis_scaling and not v7._per_axis_scaling


def test_per_exposure_n_jobs_identical_to_serial(exposures):
    X, stamps = exposures.star_data()
    X_gal, _ = exposures.galaxy_data()
    # one BLAS thread: a multi-threaded BLAS may sum in another order from one call to the
    # next (differences of 1e-17 seen), which is not what the test is about
    with threadpool_limits(limits=1):
        serial = PerExposurePSFModel().fit(X, stamps)
        with joblib.parallel_config(backend="threading"):  # no process start-up in a unit test
            parallel = PerExposurePSFModel(n_jobs=2).fit(X, stamps)
    np.testing.assert_array_equal(parallel.predict(X_gal), serial.predict(X_gal))
    np.testing.assert_array_equal(parallel.inlier_mask_, serial.inlier_mask_)


# ---------------------------------------------------------------- the exposures' truth
def test_weight_covariance_matches_the_simulated_truth():
    # dither 0: galaxies at the same chip position in every exposure; the difference of their
    # true weights between two exposures is the atmosphere alone. Its mean square over the
    # galaxies against the covariance's prediction, averaged over 4 simulations (single
    # draws scatter by about 25%; measured mean 0.88 over 6, 0.90 over 12)
    ratios = []
    for seed in range(4):
        exp = make_exposures(2, n_stars=5, n_galaxies=150, image_shape=(600, 600), dither=0.0,
                             atmosphere_ratio=1.0, random_state=seed)
        X_gal, truth = exp.galaxy_data()
        w = np.asarray(truth["coeffs"]).reshape(2, -1, exp.reference.n_components)
        n = w.shape[1]
        cov = exp.weight_covariance(X_gal)
        within = np.array([np.diagonal(c)[:n] + np.diagonal(c)[n:] for c in cov])
        across = np.array([np.diagonal(c[:n, n:]) for c in cov])
        ratios.append(np.sum(np.mean((w[0] - w[1]) ** 2, axis=0))
                      / np.sum(np.mean(within - 2 * across, axis=1)))
    assert 0.6 < np.mean(ratios) < 1.4
    # no atmosphere: the exposures' weights are the same, and so is their covariance
    static = make_exposures(2, n_stars=10, n_galaxies=5, image_shape=(900, 900), dither=0.0,
                            atmosphere_ratio=0.0, random_state=5)
    X = np.array([[300.0, 400.0, 0], [300.0, 400.0, 1]])
    c = static.weight_covariance(X)
    np.testing.assert_allclose(c[:, 0, 1], c[:, 0, 0], rtol=1e-12)
    noise = static.coefficient_noise_cov()
    k = static.reference.n_components
    assert noise.shape == (len(static.star_data()[0]), k, k)
    with pytest.raises(ValueError, match=r"shape \(n, 3\)"):
        static.weight_covariance(X[:, :2])
