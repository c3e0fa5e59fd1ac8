"""Write the model files of ``tests/data/models`` and their predictions.

These files were written by sklearn_psf before the estimators wrote their own state
(commit 6fd1d3e, model-file format 7), and by that version's writer restamped as older
formats (the readers of formats 1-6 refit what those formats stored). ``test_model_files.py``
loads each with the current code and asserts that it predicts what ``predictions.npz``
holds (computed, when the files were written, by the model that wrote them) to 1e-12.

Run from the repository root (small simulations, gzipped files: ~0.3 MB in all)::

    PYTHONPATH=$PWD OMP_NUM_THREADS=1 python tests/data/models/make_models.py

Do not run it again to "refresh" the files: they stand for the files users hold. A new
format gets new files next to these.
"""

import gzip
import os
import warnings

import numpy as np
from astropy.io import fits

from sklearn_psf.interpolate import KrigingRegressor
from sklearn_psf.model import (PerExposurePSFModel, PooledPSFModel, PSFModel,
                               make_interpolator, make_paper_basis)
from sklearn_psf.preprocessing import (FixedBasis, IQROutlierDetector, StampNormalizer,
                                       SuperResolvedPCA)
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import MinMaxScaler

HERE = os.path.dirname(os.path.abspath(__file__))


def save(model, name):
    """Write the model file ``name.fits.gz`` (gzipped: astropy reads it as it is)."""
    path = os.path.join(HERE, f"{name}.fits")
    model.save(path, overwrite=True)
    with open(path, "rb") as raw, open(path + ".gz", "wb") as out:
        out.write(gzip.compress(raw.read(), mtime=0))
    os.remove(path)
    return path + ".gz"
S = 9  # stamp side (pixels)
FIELD = 1000.0


def stars(n, seed, sigma=1.6, extra=False, exposures=0):
    """Noisy Gaussian stars whose size and shape vary over the field; positions (n, 2)."""
    rng = np.random.default_rng(seed)
    X = rng.uniform(0, FIELD, (n, 2))
    yy, xx = np.mgrid[0:S, 0:S] - (S - 1) / 2.0
    off = rng.uniform(-0.4, 0.4, (n, 2, 1, 1)) if sigma < 1 else np.zeros((n, 2, 1, 1))
    sx = (sigma * (1 + 0.15 * X[:, 0] / FIELD))[:, None, None]
    sy = (sigma * (1 + 0.1 * X[:, 1] / FIELD))[:, None, None]
    img = np.exp(-0.5 * ((xx - off[:, 0]) ** 2 / sx**2 + (yy - off[:, 1]) ** 2 / sy**2))
    img = 3e4 * img / img.sum(axis=(1, 2), keepdims=True)
    stamps = (img + rng.normal(0, 8.0, img.shape)).reshape(n, -1)
    if extra:
        X = np.column_stack([X, rng.uniform(0.2, 1.5, n)])
    if exposures:
        X = np.column_stack([X, rng.integers(0, exposures, n).astype(float)])
    return X, stamps


def main():
    queries = np.random.default_rng(99).uniform(50, FIELD - 50, (5, 2))
    X, stamps = stars(70, 1)
    Xo, so = X.copy(), stamps.copy()
    so[:3, (S // 2) * S + S // 2 + 2] += 4000.0  # cosmic rays: outliers
    models = {
        "default": (PSFModel(), Xo, so),
        "polynomial": (PSFModel(interpolator=make_interpolator("polynomial")), X, stamps),
        "chebyshev": (PSFModel(interpolator=make_interpolator("chebyshev"), outliers="iqr"),
                      X, stamps),
        "delaunay": (PSFModel(interpolator=make_interpolator("delaunay")), X, stamps),
        "shepard": (PSFModel(interpolator=make_interpolator("shepard")), X, stamps),
        "rbf": (PSFModel(interpolator=make_interpolator("rbf")), X, stamps),
        "kriging_fixed": (PSFModel(interpolator=make_pipeline(MinMaxScaler(), KrigingRegressor(
            range=0.5, nugget=0.0)), basis=make_paper_basis(),
            outliers=IQROutlierDetector(alpha=3.5)), X, stamps / stamps.sum(1, keepdims=True)),
        "kriging_local": (PSFModel(interpolator=make_pipeline(MinMaxScaler(), KrigingRegressor(
            range="auto", nugget="auto", n_neighbors=20))), X, stamps),
    }
    mean = np.exp(-0.5 * ((np.arange(S) - S // 2) ** 2)[:, None] / 2.6 - 0.5 * (
        (np.arange(S) - S // 2) ** 2)[None, :] / 2.6).ravel()
    comp = np.random.default_rng(3).normal(size=(2, S * S))
    models["fixed_basis"] = (PSFModel(basis=make_pipeline(StampNormalizer(), FixedBasis(
        comp, mean / mean.sum())), interpolator=make_interpolator("polynomial"),
        outliers=None), X, stamps)
    Xe, se = stars(70, 2, extra=True)
    models["extra_column"] = (PSFModel(), Xe, se)
    Xu, su = stars(80, 4, sigma=0.6)
    models["superres"] = (PSFModel(basis=SuperResolvedPCA(n_components=2)), Xu, su)
    Xf, sf = stars(12, 5)
    models["constant"] = (PSFModel(), Xf, sf)
    predictions = {}
    for name, (model, Xm, sm) in models.items():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            model.fit(Xm, sm)
        path = save(model, name)
        q = queries if Xm.shape[1] == 2 else np.column_stack([queries, np.full(5, 0.7)])
        predictions[name] = model.predict(q)
        predictions[f"{name}__queries"] = q
        print(name, type(model.basis_).__name__, model.n_components_, os.path.getsize(path))
    # the readers of older formats: this version's default model file restamped (formats
    # 1-3 refit the default Kriging on positions scaled by MinMaxScaler, 1-4 with a
    # constant mean, 1-5 without the warm starts of format 6; 1 and 2 read as 3)
    from sklearn_psf.model import load_model

    for version in (3, 4, 5):
        path = os.path.join(HERE, f"default_v{version}.fits.gz")
        with fits.open(os.path.join(HERE, "default.fits.gz")) as hdul:
            hdul[0].header["FORMAT"] = version
            hdul.writeto(path, overwrite=True)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            predictions[f"default_v{version}"] = load_model(path).predict(queries)
        predictions[f"default_v{version}__queries"] = queries
    # multi-exposure models: pooled (ExposureKrigingRegressor) and per-exposure
    Xp, sp = stars(90, 6, exposures=3)
    q3 = np.column_stack([queries, np.arange(5) % 3])
    for name, model in (("pooled", PooledPSFModel()), ("per_exposure", PerExposurePSFModel())):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            model.fit(Xp, sp)
        path = save(model, name)
        predictions[name] = model.predict(q3)
        predictions[f"{name}__queries"] = q3
        print(name, os.path.getsize(path))
    np.savez_compressed(os.path.join(HERE, "predictions.npz"), **predictions)


if __name__ == "__main__":
    main()
