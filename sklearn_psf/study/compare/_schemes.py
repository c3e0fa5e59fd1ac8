"""The interpolation schemes of the paper, its PSF model and its predefined split."""

from __future__ import annotations

import numpy as np
from sklearn.base import clone
from sklearn.model_selection import PredefinedSplit
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import MinMaxScaler

from ...interpolate import (
    ChebyshevRegressor,
    DelaunayRegressor,
    KrigingRegressor,
    PolynomialRegressor,
    RBFRegressor,
    ShepardRegressor,
)
from ...model import PSFModel
from ...preprocessing import IQROutlierDetector, StampNormalizer


ARCMIN = 60.0  # arcsec per arcmin


def default_schemes() -> dict:
    """The interpolation schemes compared by the paper, with its settings.

    Every scheme works on positions scaled to the unit square (``MinMaxScaler``), as the paper
    normalises the image to 0 < x, y < 1.

    Returns
    -------
    schemes : dict
        Scheme name -> unfitted scikit-learn pipeline ``MinMaxScaler() + regressor``:
        ``polynomial`` (degree 5, the paper's best), ``polynomial-auto`` (degree chosen from the
        data), ``chebyshev`` (degree 5), ``shepard`` (p = 3), ``rbf`` (Gaussian kernel, expected
        to be unstable), ``delaunay``, ``kriging`` (exponential variogram, range 0.5, nugget 0)
        and ``kriging-spherical``.

    Examples
    --------
    >>> from sklearn_psf.study.compare import default_schemes
    >>> sorted(default_schemes())[:3]
    ['chebyshev', 'delaunay', 'kriging']
    """
    regressors = {
        "polynomial": PolynomialRegressor(degree=5),
        "polynomial-auto": PolynomialRegressor(degree="auto"),
        "chebyshev": ChebyshevRegressor(degree=5),
        "shepard": ShepardRegressor(power=3.0),
        # epsilon in units of 1 / (unit-square length): the kernel width is ~ 1/10 of the field.
        "rbf": RBFRegressor(kernel="gaussian", epsilon=10.0),
        "delaunay": DelaunayRegressor(),
        "kriging": KrigingRegressor(variogram="exponential", range=0.5, nugget=0.0),
        "kriging-spherical": KrigingRegressor(variogram="spherical", range=0.5, nugget=0.0),
    }
    return {name: make_pipeline(MinMaxScaler(), reg) for name, reg in regressors.items()}


def make_psf_model(interpolator, reference=None, iqr: bool = True, alpha: float = 3.5) -> PSFModel:
    """The paper's PSF model: normalised stamps, a PCA basis, the IQR cut and an interpolator.

    Parameters
    ----------
    interpolator : regressor
        Maps positions to PCA coefficients (e.g. an entry of :func:`default_schemes`).
    reference : ReferenceBasis, optional
        When given, the basis is the reference's fixed basis (the paper forces the
        simulation's basis so that coefficients can be compared with the truth); otherwise
        the library's default basis (:class:`~sklearn_psf.preprocessing.StampPCA`) is fitted
        on the stars.
    iqr : bool
        Reject outlying stars with the interquartile-range test.
    alpha : float
        The IQR test's parameter (3.5 in the paper).

    Returns
    -------
    model : PSFModel

    Examples
    --------
    >>> from sklearn_psf.study.compare import default_schemes, make_psf_model
    >>> model = make_psf_model(default_schemes()["kriging"])
    >>> type(model).__name__
    'PSFModel'
    """
    basis = None
    if reference is not None:
        basis = make_pipeline(StampNormalizer(), reference.as_transformer())
    outliers = IQROutlierDetector(alpha=alpha) if iqr else None
    return PSFModel(interpolator=interpolator, basis=basis, outliers=outliers)


def paper_split(X_stars, y_stars, X_galaxies, y_galaxies):
    """Stack stars and galaxy-PSFs with the paper's predefined split.

    Parameters
    ----------
    X_stars, y_stars : array-like
        Star positions (n, 2) and their measured stamps (n, s*s): the training set.
    X_galaxies, y_galaxies : array-like
        Galaxy-PSF positions (m, 2) and their true stamps (m, s*s): the test set.

    Returns
    -------
    X, y : ndarray
        Stars then galaxy-PSFs.
    cv : PredefinedSplit
        One split, train = stars and test = galaxy-PSFs, for ``cross_validate`` or
        ``GridSearchCV``.

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.study.compare import paper_split
    >>> X, y, cv = paper_split(np.zeros((3, 2)), np.zeros((3, 9)), np.ones((2, 2)), np.ones((2, 9)))
    >>> [(tr.tolist(), te.tolist()) for tr, te in cv.split(X, y)]
    [([0, 1, 2], [3, 4])]
    """
    X_stars, X_galaxies = np.asarray(X_stars, float), np.asarray(X_galaxies, float)
    y_stars, y_galaxies = np.asarray(y_stars, float), np.asarray(y_galaxies, float)
    if y_stars.shape[1:] != y_galaxies.shape[1:]:
        raise ValueError(
            f"stars and galaxy-PSFs must have stamps of the same size, got {y_stars.shape[1:]} "
            f"and {y_galaxies.shape[1:]}."
        )
    X = np.vstack([X_stars, X_galaxies])
    y = np.vstack([y_stars, y_galaxies])
    test_fold = np.r_[np.full(len(X_stars), -1), np.zeros(len(X_galaxies), dtype=int)]
    return X, y, PredefinedSplit(test_fold)


def tuned_schemes(tuning) -> dict:
    """Each tuned scheme at its cross-validated best, named ``<scheme>-cv``.

    Parameters
    ----------
    tuning : astropy.table.Table
        The table of :func:`tune_schemes` (``scheme``, ``best_params``).

    Returns
    -------
    schemes : dict
        Only the schemes whose best setting differs from the paper's.

    Examples
    --------
    >>> from astropy.table import Table
    >>> t = Table({"scheme": ["rbf", "shepard"], "best_params": ["epsilon=30.0", "power=3.0"]})
    >>> s = tuned_schemes(t)
    >>> list(s), s["rbf-cv"][-1].epsilon
    (['rbf-cv'], 30.0)
    """
    schemes = default_schemes()
    out = {}
    for row in tuning:
        name = str(row["scheme"])
        pipe = clone(schemes[name])
        reg = pipe.steps[-1][1]
        params = {}
        for item in str(row["best_params"]).split(", "):
            key, value = item.split("=")
            params[key] = type(getattr(reg, key))(value) if getattr(reg, key) is not None \
                else float(value)
        if any(getattr(reg, k) != v for k, v in params.items()):
            reg.set_params(**params)
            out[f"{name}-cv"] = pipe
    return out
