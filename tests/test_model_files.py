"""Model files written by earlier versions of sklearn_psf load and predict as they did.

The files of ``tests/data/models`` (see ``make_models.py`` there) were written before the
estimators wrote their own state; their predictions at a few positions, computed by the
models that wrote them, are in ``predictions.npz``.
"""

import os
import warnings

import numpy as np
import pytest
from numpy.testing import assert_allclose

from sklearn_psf.model import PerExposurePSFModel, PooledPSFModel, PSFModel

HERE = os.path.join(os.path.dirname(__file__), "data", "models")
EXPECTED = dict(np.load(os.path.join(HERE, "predictions.npz")))
NAMES = sorted(k for k in EXPECTED if "__" not in k)
LOADERS = {"pooled": PooledPSFModel.load, "per_exposure": PerExposurePSFModel.load}


def test_every_file_has_its_predictions():
    files = sorted(f[:-len(".fits.gz")] for f in os.listdir(HERE) if f.endswith(".fits.gz"))
    assert files == NAMES and len(NAMES) >= 17


@pytest.mark.parametrize("name", NAMES)
def test_old_model_files_predict_as_when_written(name):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # (a few were fitted on too few stars on purpose)
        model = LOADERS.get(name, PSFModel.load)(os.path.join(HERE, f"{name}.fits.gz"))
    assert_allclose(model.predict(EXPECTED[f"{name}__queries"]), EXPECTED[name],
                    rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("name", NAMES)
def test_saved_again_they_predict_the_same(name, tmp_path):
    # written in the current format (each part's own state) and read back
    load = LOADERS.get(name, PSFModel.load)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = load(os.path.join(HERE, f"{name}.fits.gz"))
    model.save(tmp_path / "again.fits")
    back = load(tmp_path / "again.fits")
    queries = EXPECTED[f"{name}__queries"]
    assert_allclose(back.predict(queries), EXPECTED[name], rtol=1e-12, atol=1e-15)
    assert_allclose(back.predict(queries), model.predict(queries), rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("name", ["default", "kriging_local", "pooled", "polynomial"])
def test_loading_runs_no_likelihood_and_no_search(name, tmp_path, monkeypatch):
    load = LOADERS.get(name, PSFModel.load)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = load(os.path.join(HERE, f"{name}.fits.gz"))
    model.save(tmp_path / "again.fits")

    def refuse(*args, **kwargs):
        raise AssertionError("the likelihood ran on loading")

    from sklearn_psf.interpolate import _exposure_kriging, _kriging_hyper, _polynomial

    monkeypatch.setattr(_kriging_hyper, "fit_hyperparameters", refuse)
    monkeypatch.setattr(_exposure_kriging, "fit_joint_hyperparameters", refuse)
    solves, lstsq = [], _polynomial._weighted_lstsq
    monkeypatch.setattr(_polynomial, "_weighted_lstsq",
                        lambda *a: solves.append(1) or lstsq(*a))
    back = load(tmp_path / "again.fits")
    queries = EXPECTED[f"{name}__queries"]
    assert_allclose(back.predict(queries), EXPECTED[name], rtol=1e-12, atol=1e-15)
    # degree="auto" solved at the stored degree only, not at every candidate's
    assert len(solves) == (name == "polynomial")
