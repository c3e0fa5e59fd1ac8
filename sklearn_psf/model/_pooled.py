"""PSF models across exposures (exposure index as a column of X) and focal-plane positions.

:class:`PerExposurePSFModel` fits one :class:`PSFModel` per exposure (the paper's way);
:class:`PooledPSFModel` fits one model on the stars of every exposure whose interpolation
learns the static pattern they share and each exposure's own (atmospheric) pattern;
:class:`FocalPlaneMapper` maps (x, y, ccd) to focal-plane positions so that the CCDs of one
exposure share one model. Save and load the multi-exposure models with their ``save`` /
``load`` (the package's FITS model format) or ``joblib.dump`` / ``joblib.load``.
"""

from __future__ import annotations

from numbers import Integral

import numpy as np
from joblib import Parallel, delayed
from sklearn.base import BaseEstimator, RegressorMixin, TransformerMixin, _fit_context, clone
from sklearn.metrics import r2_score
from sklearn.utils._param_validation import HasMethods, Interval
from sklearn.utils.validation import check_is_fitted, validate_data

from ..interpolate import ExposureKrigingRegressor
from ..interpolate._exposure_kriging import split_exposure_column
from .._persist import StateMixin
from ..preprocessing import StampNormalizer
from ._file import read_exposure_model, save_exposure_model
from ._psf_model import PSFModel

__all__ = ["FocalPlaneMapper", "PerExposurePSFModel", "PooledPSFModel"]


class _ExposureModel(StateMixin, RegressorMixin, BaseEstimator):
    """Shared parts: the exposure column, stamp targets, routing by exposure, R^2 score."""

    def _split_X(self, X, y=None, reset=True):
        if reset:
            if y is None:
                raise ValueError(f"{type(self).__name__} requires y to be passed, but the "
                                 "target y is None: pass the star stamps.")
            y = np.asarray(y)
            y = y.reshape(y.shape[0], -1) if y.ndim == 3 else y
            X, y = validate_data(self, X, y, multi_output=True, dtype=np.float64,
                                 ensure_all_finite="allow-nan" if np.isnan(y).any() else True)
            if not np.isfinite(X).all():
                raise ValueError("X holds NaN or infinite values: give finite positions and "
                                 "exposure indices.")
        else:
            check_is_fitted(self)
            X = validate_data(self, X, dtype=np.float64, reset=False)
        if reset and X.shape[0] < 3:
            raise ValueError(f"{type(self).__name__} needs at least 3 stars, got "
                             f"n_samples = {X.shape[0]}.")
        pos, exposure = split_exposure_column(X, self.exposure_column)
        return pos, exposure, y

    def _groups(self, exposure, reset=False):
        if not reset:
            unknown = np.setdiff1d(exposure, self.exposures_)
            if len(unknown):
                raise ValueError(f"Exposures {unknown.tolist()} were not in the fit (fitted: "
                                 f"{self.exposures_.tolist()}): a model predicts only the "
                                 "exposures its stars came from.")
        for e in np.unique(exposure):
            yield e, np.flatnonzero(exposure == e)

    def score(self, X, y, sample_weight=None):
        """R^2 of predicted stamps against the normalised true stamps (as
        :meth:`PSFModel.score`).

        Parameters
        ----------
        X : array-like of shape (m, n_features)
        y : array-like of shape (m, s*s) or (m, s, s)
        sample_weight : array-like of shape (m,), optional

        Returns
        -------
        score : float
        """
        y = np.asarray(y, dtype=np.float64)
        y = y.reshape(y.shape[0], -1) if y.ndim == 3 else y
        truth = StampNormalizer().fit_transform(y)
        return float(r2_score(truth, self.predict(X), sample_weight=sample_weight,
                              multioutput="variance_weighted"))

    def save(self, path, *, overwrite: bool = False) -> None:
        """Write the fitted model to a FITS model file (the current format, written atomically).

        The file holds the basis, the stars (positions, exposure, coefficients and their
        noise, inlier flags) and the parameters of every model; see
        :mod:`sklearn_psf.model` (module ``_file``) for the format. :meth:`load` reads it back
        and predicts identically.

        Parameters
        ----------
        path : str or os.PathLike
        overwrite : bool, default=False

        Examples
        --------
        >>> import os, tempfile
        >>> import numpy as np
        >>> from sklearn_psf.model import PooledPSFModel
        >>> from sklearn_psf.simulate import make_exposures
        >>> exp = make_exposures(2, n_stars=30, n_galaxies=5, image_shape=(500, 500),
        ...                      random_state=0)
        >>> X, stamps = exp.star_data()
        >>> model = PooledPSFModel().fit(X, stamps)
        >>> path = os.path.join(tempfile.mkdtemp(), "pooled.fits")
        >>> model.save(path)
        >>> back = PooledPSFModel.load(path)
        >>> bool(np.array_equal(back.predict(X[:5]), model.predict(X[:5])))
        True
        """
        save_exposure_model(self, path, overwrite=overwrite)

    @classmethod
    def load(cls, path):
        """Read a model written by :meth:`save`.

        Parameters
        ----------
        path : str or os.PathLike

        Returns
        -------
        model
            Fitted, of this class; predictions identical to the saved model's.

        Raises
        ------
        ValueError
            For a missing, damaged or newer file, or a file of another kind of model.
        """
        return read_exposure_model(path, cls, PSFModel)

    def __sklearn_tags__(self):
        tags = super().__sklearn_tags__()
        tags.target_tags.multi_output = True
        tags.target_tags.single_output = False
        return tags


class PerExposurePSFModel(_ExposureModel):
    """One PSF model per exposure, the exposure given as a column of X (the paper's way).

    Parameters
    ----------
    model : PSFModel, optional
        Template cloned and fitted on the stars of each exposure; default ``PSFModel()``.
    exposure_column : int, default=-1
        Column of X holding the integer exposure index; the other columns (e.g. x, y) are the
        positions given to each exposure's model.
    n_jobs : int or None, default=None
        Exposures fitted in parallel through joblib (``-1``: all cores; a Dask cluster inside
        ``joblib.parallel_backend("dask")``). The fitted models do not depend on it.

    Attributes
    ----------
    exposures_ : ndarray of int
        Exposure indices seen in ``fit``.
    models_ : list of PSFModel
        The fitted model of each of ``exposures_``.
    inlier_mask_ : ndarray of shape (n_stars,), bool
        Stars kept by their exposure's model.
    n_features_in_ : int

    Examples
    --------
    >>> from sklearn_psf.model import PerExposurePSFModel
    >>> from sklearn_psf.simulate import make_exposures
    >>> exp = make_exposures(2, n_stars=40, n_galaxies=5, image_shape=(600, 600),
    ...                      random_state=0)
    >>> X, stamps = exp.star_data()
    >>> model = PerExposurePSFModel().fit(X, stamps)
    >>> model.exposures_.tolist(), model.predict(X[:3]).shape
    ([0, 1], (3, 625))
    >>> [int(m.inlier_mask_.sum()) for m in model.models_]    # the stars each model keeps
    [40, 40]
    """

    _parameter_constraints: dict = {
        "model": [HasMethods(["fit", "predict"]), None],
        "exposure_column": [Interval(Integral, None, None, closed="neither")],
        "n_jobs": [Integral, None],
    }

    _state_attributes = ("models_", "exposures_", "inlier_mask_", "n_features_in_")

    def __init__(self, model=None, exposure_column=-1, n_jobs=None):
        self.model = model
        self.exposure_column = exposure_column
        self.n_jobs = n_jobs

    @_fit_context(prefer_skip_nested_validation=False)  # model is an estimator
    def fit(self, X, y, weights=None):
        """Fit one model per exposure.

        Parameters
        ----------
        X : array-like of shape (n_stars, n_features)
            Positions and the exposure column (``exposure_column``): each exposure's
            stars are fitted by their own clone of ``model``, in parallel (``n_jobs``).
        y : array-like of shape (n_stars, s*s) or (n_stars, s, s)
            Raw star stamps.
        weights : array-like of the shape of y, optional
            Pixel weights (inverse variance, 0 = masked), split with the stars.

        Returns
        -------
        self : PerExposurePSFModel
        """
        pos, exposure, y = self._split_X(X, y)
        w = None if weights is None else np.asarray(weights, dtype=np.float64).reshape(y.shape)
        template = PSFModel() if self.model is None else self.model
        groups = list(self._groups(exposure, reset=True))
        self.exposures_ = np.unique(exposure)
        self.models_ = Parallel(n_jobs=self.n_jobs)(
            delayed(clone(template).fit)(pos[idx], y[idx], None if w is None else w[idx])
            for _, idx in groups)
        self.inlier_mask_ = np.zeros(len(pos), dtype=bool)
        for (_, idx), model in zip(groups, self.models_):
            self.inlier_mask_[idx] = model.inlier_mask_
        return self

    def predict(self, X):
        """Normalised PSF stamps, each from its exposure's model.

        Parameters
        ----------
        X : array-like of shape (m, n_features)

        Returns
        -------
        stamps : ndarray of shape (m, s*s)
        """
        pos, exposure, _ = self._split_X(X, reset=False)
        out = None
        for e, idx in self._groups(exposure):
            pred = self.models_[int(np.searchsorted(self.exposures_, e))].predict(pos[idx])
            out = np.empty((len(pos), pred.shape[1])) if out is None else out
            out[idx] = pred
        return out


class PooledPSFModel(_ExposureModel):
    """One PSF model on the stars of every exposure: a static pattern plus each exposure's own.

    A :class:`PSFModel` (``model``: basis, outlier rejection) fitted on all the stars at once,
    whose interpolator is an :class:`~sklearn_psf.interpolate.ExposureKrigingRegressor` on
    (position, exposure): the covariance of two stars' coefficients is a static part (chip
    or focal-plane frame, shared by every exposure) plus, for stars of the same exposure, an
    atmospheric part, plus each star's coefficient noise covariance across the components
    (the components are co-Kriged, as in :class:`PSFModel`'s default). The variance and
    correlation length of each part are fitted by maximum likelihood from the stars of all
    exposures, so
    the model reduces to one model per exposure when the atmosphere dominates and to one
    static model when it does not. The outlier test's leave-one-out is the regressor's
    closed form. With one exposure the two parts cannot be told apart: the model is then
    ``model`` fitted on that exposure, identical to a single :class:`PSFModel`.

    Parameters
    ----------
    model : PSFModel, optional
        Template of the model (its basis, outliers, cv, random_state); default ``PSFModel()``.
        With several exposures its interpolator is replaced by ``interpolator``.
    interpolator : regressor, optional
        Regressor of coefficients on (positions, exposure) with the exposure as last column;
        default ``ExposureKrigingRegressor()``.
    exposure_column : int, default=-1
        Column of X holding the integer exposure index.

    Attributes
    ----------
    model_ : PSFModel
        The fitted model (on positions and exposure, the exposure last, with several
        exposures; on positions with one).
    exposures_ : ndarray of int
    inlier_mask_ : ndarray of shape (n_stars,), bool
    n_components_ : int
    n_features_in_ : int

    See Also
    --------
    PerExposurePSFModel : one model per exposure.
    sklearn_psf.interpolate.ExposureKrigingRegressor : the default interpolator.

    Examples
    --------
    >>> from sklearn_psf.model import PooledPSFModel
    >>> from sklearn_psf.simulate import make_exposures
    >>> exp = make_exposures(2, n_stars=40, n_galaxies=5, image_shape=(600, 600),
    ...                      random_state=0)
    >>> X, stamps = exp.star_data()
    >>> model = PooledPSFModel().fit(X, stamps)
    >>> interp = model.model_.interpolator_
    >>> type(interp).__name__, model.predict(X[:3]).shape
    ('ExposureKrigingRegressor', (3, 625))
    """

    _parameter_constraints: dict = {
        "model": [HasMethods(["fit", "predict", "set_params"]), None],
        "interpolator": [HasMethods(["fit", "predict"]), None],
        "exposure_column": [Interval(Integral, None, None, closed="neither")],
    }

    _state_attributes = ("model_", "exposures_", "inlier_mask_", "n_components_",
                         "n_features_in_")

    def __init__(self, model=None, interpolator=None, exposure_column=-1):
        self.model = model
        self.interpolator = interpolator
        self.exposure_column = exposure_column

    def _positions(self, pos, exposure):
        if len(self.exposures_) < 2:
            return pos
        return np.column_stack([pos, exposure.astype(np.float64)])

    @_fit_context(prefer_skip_nested_validation=False)  # model is an estimator
    def fit(self, X, y, weights=None):
        """Fit the basis, the outlier test and the joint interpolation on all the stars.

        Parameters
        ----------
        X : array-like of shape (n_stars, n_features)
            Positions and the exposure column (``exposure_column``), which becomes a
            feature of the joint interpolation when there are two exposures or more.
        y : array-like of shape (n_stars, s*s) or (n_stars, s, s)
            Raw star stamps of every exposure, for one basis.
        weights : array-like of the shape of y, optional
            Pixel weights (inverse variance, 0 = masked).

        Returns
        -------
        self : PooledPSFModel
        """
        pos, exposure, y = self._split_X(X, y)
        self.exposures_ = np.unique(exposure)
        model = clone(PSFModel() if self.model is None else self.model)
        if len(self.exposures_) > 1:
            model.set_params(interpolator=ExposureKrigingRegressor() if self.interpolator is None
                             else clone(self.interpolator))
        self.model_ = model.fit(self._positions(pos, exposure), y, weights)
        self.inlier_mask_ = model.inlier_mask_
        self.n_components_ = model.n_components_
        return self

    def predict_coefficients(self, X):
        """Interpolated coefficients in ``model_``'s basis.

        Parameters
        ----------
        X : array-like of shape (m, n_features)

        Returns
        -------
        coefficients : ndarray of shape (m, n_components_)
        """
        pos, exposure, _ = self._split_X(X, reset=False)
        list(self._groups(exposure))  # unknown exposures fail with a clear message
        return self.model_.predict_coefficients(self._positions(pos, exposure))

    def predict(self, X):
        """Normalised PSF stamps at X.

        Parameters
        ----------
        X : array-like of shape (m, n_features)

        Returns
        -------
        stamps : ndarray of shape (m, s*s)
        """
        coef = self.predict_coefficients(X)
        return np.asarray(self.model_.basis_.inverse_transform(coef), dtype=np.float64)


class FocalPlaneMapper(TransformerMixin, BaseEstimator):
    """Map chip positions (x, y, ccd) to focal-plane positions, for one model over many CCDs.

    Focal-plane position = ``ccd_origins[ccd] + R(ccd_angles[ccd]) @ (x, y)`` (pixels, angle
    in degrees counter-clockwise). Put it first in a PSF model's interpolator, e.g.
    ``PSFModel(interpolator=make_pipeline(FocalPlaneMapper(origins), IsotropicScaler(),
    KrigingRegressor(...)))`` fitted on X = (x, y, ccd).

    Parameters
    ----------
    ccd_origins : array-like of shape (n_ccds, 2)
        Focal-plane position of each CCD's pixel (0, 0).
    ccd_angles : array-like of shape (n_ccds,), optional
        Rotation of each CCD, degrees; default 0.
    ccd_column : int, default=2
        Column of X holding the integer CCD index; columns 0 and 1 are x and y.

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.model import FocalPlaneMapper
    >>> m = FocalPlaneMapper([[0, 0], [2100, 0]])
    >>> m.fit_transform(np.array([[10.0, 20.0, 0], [10.0, 20.0, 1]]))
    array([[  10.,   20.],
           [2110.,   20.]])
    """

    _parameter_constraints: dict = {
        "ccd_origins": ["array-like"],
        "ccd_angles": ["array-like", None],
        "ccd_column": [Interval(Integral, None, None, closed="neither")],
    }

    def __init__(self, ccd_origins, ccd_angles=None, ccd_column=2):
        self.ccd_origins = ccd_origins
        self.ccd_angles = ccd_angles
        self.ccd_column = ccd_column

    @_fit_context(prefer_skip_nested_validation=True)
    def fit(self, X, y=None):
        """Check X and the layout.

        Returns
        -------
        self
        """
        X = validate_data(self, X, dtype=np.float64)
        self._layout()
        if X.shape[1] < 3:
            raise ValueError(f"X must hold x, y and a CCD column, got n_features = {X.shape[1]}.")
        return self

    def _layout(self):
        origins = np.asarray(self.ccd_origins, dtype=np.float64)
        if origins.ndim != 2 or origins.shape[1] != 2:
            raise ValueError(f"ccd_origins must have shape (n_ccds, 2), got {origins.shape}.")
        angles = (np.zeros(len(origins)) if self.ccd_angles is None
                  else np.asarray(self.ccd_angles, dtype=np.float64))
        if angles.shape != (len(origins),):
            raise ValueError(f"ccd_angles must hold {len(origins)} angles, got {angles.shape}.")
        return origins, np.deg2rad(angles)

    def transform(self, X):
        """Focal-plane (x, y), then the columns of X other than x, y and the CCD.

        Returns
        -------
        X_focal : ndarray of shape (n, n_features - 1)
        """
        check_is_fitted(self)
        X = validate_data(self, X, dtype=np.float64, reset=False)
        origins, angles = self._layout()
        ccd = X[:, self.ccd_column]
        if not (np.array_equal(ccd, np.round(ccd)) and ccd.min() >= 0
                and ccd.max() < len(origins)):
            raise ValueError(f"Column {self.ccd_column} of X must hold CCD indices in "
                             f"0..{len(origins) - 1}.")
        i = ccd.astype(np.int64)
        c, s = np.cos(angles[i]), np.sin(angles[i])
        fx = origins[i, 0] + c * X[:, 0] - s * X[:, 1]
        fy = origins[i, 1] + s * X[:, 0] + c * X[:, 1]
        rest = np.delete(X, [0, 1, self.ccd_column], axis=1)
        return np.column_stack([fx, fy, rest])
