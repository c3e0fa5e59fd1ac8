"""PSFModel: basis + outlier rejection + interpolation, predicting PSF stamps anywhere."""

from __future__ import annotations

import numpy as np
from sklearn.base import BaseEstimator, RegressorMixin, clone
from sklearn.decomposition import PCA
from sklearn.metrics import r2_score
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import MinMaxScaler
from sklearn.utils.validation import check_is_fitted, validate_data

from .preprocessing import IQROutlierDetector, StampNormalizer

__all__ = ["PSFModel", "make_default_basis", "make_default_interpolator"]


def make_default_basis():
    """The default stamp basis: ``make_pipeline(StampNormalizer(), PCA(n_components=0.9))``.

    PCA keeps 90% of the variance (the paper's setting) with ``svd_solver="full"``, which is
    deterministic.

    Returns
    -------
    basis : sklearn.pipeline.Pipeline

    Examples
    --------
    >>> from sklearn_psf.model import make_default_basis
    >>> list(make_default_basis().named_steps)
    ['stampnormalizer', 'pca']
    """
    return make_pipeline(StampNormalizer(), PCA(n_components=0.9, svd_solver="full"))


def make_default_interpolator():
    """The default interpolator: positions scaled to the unit square, then ordinary Kriging.

    ``make_pipeline(MinMaxScaler(), KrigingRegressor(variogram="exponential", range=0.5,
    nugget=0.0))``, as in the paper. Pass it explicitly to ``PSFModel(interpolator=...)`` to
    tune its nested parameters (e.g. ``interpolator__krigingregressor__range``).

    Returns
    -------
    interpolator : sklearn.pipeline.Pipeline

    Examples
    --------
    >>> from sklearn_psf.model import make_default_interpolator
    >>> list(make_default_interpolator().named_steps)
    ['minmaxscaler', 'krigingregressor']
    """
    from .interpolate import KrigingRegressor

    return make_pipeline(
        MinMaxScaler(), KrigingRegressor(variogram="exponential", range=0.5, nugget=0.0)
    )


class PSFModel(RegressorMixin, BaseEstimator):
    """A PSF model: a stamp basis, outlier rejection and an interpolator of coefficients.

    What :class:`sklearn.compose.TransformedTargetRegressor` is to scikit-learn: ``fit(X, y)``
    with star positions ``X`` and flattened star stamps ``y``

    1. fits ``basis`` on the stamps and projects them (coefficients, shape (n, k));
    2. rejects outlying stars in coefficient space with ``outliers`` (fit time only; the kept
       stars are ``inlier_mask_``). No warning is emitted for dropped stars: the IQR cut
       with alpha=3.5 is expected to remove about 1% of them; inspect ``inlier_mask_``;
    3. fits ``interpolator`` on (positions, coefficients) of the kept stars.

    ``predict(X)`` interpolates coefficients at X and rebuilds normalised stamps with
    ``basis_.inverse_transform``.

    Parameters
    ----------
    interpolator : regressor, optional
        A multi-output scikit-learn regressor from positions (n, d) to coefficients (n, k).
        Default :func:`make_default_interpolator` (MinMaxScaler + exponential Kriging,
        range 0.5).
    basis : transformer, optional
        Transformer from stamps to coefficients with ``inverse_transform``, e.g.
        ``make_pipeline(StampNormalizer(), FixedBasis(components, mean))``. Default
        :func:`make_default_basis` (StampNormalizer + PCA keeping 90% of the variance).
    outliers : "iqr", outlier detector or None, default="iqr"
        "iqr" means ``IQROutlierDetector(alpha=3.5)``; any scikit-learn outlier detector with
        ``fit_predict`` returning +1/-1 works; None keeps every star.

    Attributes
    ----------
    basis_ : transformer
        Fitted basis.
    outliers_ : outlier detector or None
        Fitted detector.
    interpolator_ : regressor
        Interpolator fitted on the kept stars.
    inlier_mask_ : ndarray of shape (n_stars,), bool
        Stars kept for the interpolation.
    n_components_ : int
        Number of coefficients per stamp.
    stamp_size_ : int
        Side s of the stamps.
    n_features_in_ : int
        Number of position columns (2 for (x, y)).
    X_fit_ : ndarray of shape (n_stars, n_features)
        Positions of the stars given to ``fit``.
    coefficients_ : ndarray of shape (n_stars, n_components_)
        Basis coefficients of those stars (the interpolator is fitted on
        ``X_fit_[inlier_mask_]``, ``coefficients_[inlier_mask_]``). :meth:`save` stores them
        and :meth:`load` refits the interpolator on them.

    See Also
    --------
    sklearn_psf.validation.fit_and_validate : fit with reserved stars and report residuals.
    sklearn_psf.io.save_model : the model file format.

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn.neighbors import KNeighborsRegressor
    >>> from sklearn_psf.model import PSFModel
    >>> rng = np.random.default_rng(0)
    >>> X = rng.uniform(0, 1000, (60, 2))
    >>> yy, xx = np.mgrid[0:11, 0:11] - 5.0
    >>> sig = 1.5 + X[:, :1] / 1000.0                       # size varies along x
    >>> y = np.exp(-0.5 * (xx.ravel() ** 2 + yy.ravel() ** 2) / sig**2)
    >>> model = PSFModel(interpolator=KNeighborsRegressor(3), outliers=None).fit(X, y)
    >>> model.predict([[500.0, 500.0]]).shape
    (1, 121)
    """

    def __init__(self, interpolator=None, basis=None, outliers="iqr"):
        self.interpolator = interpolator
        self.basis = basis
        self.outliers = outliers

    def set_params(self, **params):
        """Set parameters, including nested ones of the default basis and interpolator.

        ``interpolator__krigingregressor__range`` works on ``PSFModel()`` (whose
        ``interpolator`` is None): a nested key first replaces None by the default pipeline,
        as ``GridSearchCV(PSFModel(), {"interpolator__krigingregressor__range": [...]})``
        expects.

        Returns
        -------
        self : PSFModel
        """
        defaults = {"interpolator": make_default_interpolator, "basis": make_default_basis}
        for name, make in defaults.items():
            nested = any(key.startswith(f"{name}__") for key in params)
            if nested and params.get(name, getattr(self, name)) is None:
                params = {name: make(), **{k: v for k, v in params.items() if k != name}}
        return super().set_params(**params)

    def _make_outliers(self):
        if self.outliers is None:
            return None
        if isinstance(self.outliers, str):
            if self.outliers != "iqr":
                raise ValueError(
                    f"outliers must be 'iqr', None or an outlier detector, got {self.outliers!r}."
                )
            return IQROutlierDetector(alpha=3.5)
        if not hasattr(self.outliers, "fit_predict"):
            raise TypeError(
                "outliers must be 'iqr', None or an estimator with fit_predict returning +1/-1, "
                f"got {type(self.outliers).__name__}."
            )
        return clone(self.outliers)

    def fit(self, X, y):
        """Fit the basis on the stamps, reject outliers, fit the interpolator.

        Parameters
        ----------
        X : array-like of shape (n_stars, n_features)
            Star positions, usually (x, y) in pixels; further columns (e.g. an exposure
            index for a multi-exposure model) are passed to the interpolator as they are.
        y : array-like of shape (n_stars, s*s) or (n_stars, s, s)
            Star stamps. Not modified.

        Returns
        -------
        self : PSFModel

        Raises
        ------
        ValueError
            For NaN positions or pixels, non-square stamps, too few stars for the basis, or
            when outlier rejection leaves too few stars.
        """
        if y is None:
            raise ValueError(f"{type(self).__name__} requires y to be passed, but the target y "
                             "is None: pass the star stamps.")
        y = np.asarray(y)
        if y.ndim == 3:
            y = y.reshape(y.shape[0], -1)
        X, y = validate_data(self, X, y, multi_output=True, y_numeric=True, dtype=np.float64)
        if y.ndim != 2:
            raise ValueError("y must hold flattened stamps of shape (n_stars, s*s).")
        s = int(round(np.sqrt(y.shape[1])))
        if s * s != y.shape[1]:
            raise ValueError(
                f"y has {y.shape[1]} pixels per star, not a square number: pass flattened "
                "square stamps (n_stars, s*s)."
            )
        n = X.shape[0]
        if n < 3:
            raise ValueError(f"PSFModel needs at least 3 stars, got n_samples = {n}.")

        basis = make_default_basis() if self.basis is None else clone(self.basis)
        coef = np.asarray(basis.fit_transform(y), dtype=np.float64)
        if coef.ndim == 1:
            coef = coef[:, None]
        k = coef.shape[1]
        if n < k + 2:
            raise ValueError(
                f"{n} stars are too few for a basis of {k} components: need at least {k + 2}."
            )

        detector = self._make_outliers()
        if detector is None:
            mask = np.ones(n, dtype=bool)
        else:
            mask = np.asarray(detector.fit_predict(coef)) == 1
        kept = int(mask.sum())
        if kept < 2:
            raise ValueError(
                f"Outlier rejection kept {kept} of {n} stars: too few to interpolate. Use a "
                "milder detector (e.g. a larger alpha) or outliers=None."
            )

        interp = make_default_interpolator() if self.interpolator is None else clone(
            self.interpolator
        )
        target = coef[mask]
        interp.fit(X[mask], target)

        self.basis_ = basis
        self.outliers_ = detector
        self.interpolator_ = interp
        self.inlier_mask_ = mask
        self.n_components_ = k
        self.stamp_size_ = s
        self.X_fit_ = np.array(X, copy=True)
        self.coefficients_ = coef
        return self

    def save(self, path, *, residuals=None, summary=None, overwrite: bool = False) -> None:
        """Write the fitted model to a self-describing FITS file (atomically).

        See :func:`sklearn_psf.io.save_model` for the format; joblib/pickle work too.

        Parameters
        ----------
        path : str or os.PathLike
        residuals : astropy.table.Table, optional
            Reserved-star residuals (from :func:`sklearn_psf.validation.fit_and_validate`).
        summary : dict, optional
            Validation summary stored with them.
        overwrite : bool, default=False

        Examples
        --------
        >>> import os, tempfile
        >>> import numpy as np
        >>> from sklearn.neighbors import KNeighborsRegressor
        >>> from sklearn_psf.model import PSFModel
        >>> rng = np.random.default_rng(0)
        >>> X = rng.uniform(0, 1000, (40, 2))
        >>> yy, xx = np.mgrid[0:11, 0:11] - 5.0
        >>> y = np.exp(-0.5 * (xx.ravel() ** 2 + yy.ravel() ** 2) / (1.5 + X[:, :1] / 1e3) ** 2)
        >>> model = PSFModel(interpolator=KNeighborsRegressor(3), outliers=None).fit(X, y)
        >>> path = os.path.join(tempfile.mkdtemp(), "psf.fits")
        >>> model.save(path)
        >>> back = PSFModel.load(path)
        >>> bool(np.array_equal(back.predict(X[:5]), model.predict(X[:5])))
        True
        """
        from .io import save_model

        save_model(self, path, residuals=residuals, summary=summary, overwrite=overwrite)

    @classmethod
    def load(cls, path) -> "PSFModel":
        """Read a model written by :meth:`save` (see :func:`sklearn_psf.io.load_model`).

        Parameters
        ----------
        path : str or os.PathLike

        Returns
        -------
        model : PSFModel
            Fitted; predictions are identical to the saved model's.

        Raises
        ------
        ValueError
            For a missing, corrupt or truncated file, a file that is not a model, or a model
            file of an unknown (e.g. newer) format version.
        """
        from .io import load_model

        return load_model(path)

    def _check_X(self, X):
        check_is_fitted(self)
        X = validate_data(self, X, dtype=np.float64, reset=False)
        return X

    def predict_coefficients(self, X):
        """Interpolated basis coefficients at positions X.

        Parameters
        ----------
        X : array-like of shape (m, 2)

        Returns
        -------
        coefficients : ndarray of shape (m, n_components_)
        """
        X = self._check_X(X)
        coef = np.asarray(self.interpolator_.predict(X), dtype=np.float64)
        return coef.reshape(X.shape[0], self.n_components_)

    def predict(self, X):
        """Normalised PSF stamps at positions X.

        Parameters
        ----------
        X : array-like of shape (m, 2)

        Returns
        -------
        stamps : ndarray of shape (m, s*s)
        """
        coef = self.predict_coefficients(X)
        return np.asarray(self.basis_.inverse_transform(coef), dtype=np.float64)

    def transform_stamps(self, y):
        """Coefficients of given stamps through the fitted basis (e.g. for scorers).

        Parameters
        ----------
        y : array-like of shape (m, s*s) or (m, s, s)

        Returns
        -------
        coefficients : ndarray of shape (m, n_components_)
        """
        check_is_fitted(self)
        y = np.asarray(y, dtype=np.float64)
        if y.ndim == 3:
            y = y.reshape(y.shape[0], -1)
        return np.asarray(self.basis_.transform(y), dtype=np.float64)

    def score(self, X, y, sample_weight=None):
        """R^2 of predicted stamps against the normalised true stamps.

        The true stamps are normalised with ``StampNormalizer()`` (the package's convention:
        unit flux, adaptive centroid at the stamp centre; idempotent on stamps already
        normalised), and R^2 is computed over all pixels together
        (``r2_score(..., multioutput="variance_weighted")``), so that faint wing pixels do not
        weigh as much as the core.

        Parameters
        ----------
        X : array-like of shape (m, 2)
        y : array-like of shape (m, s*s) or (m, s, s)
        sample_weight : array-like of shape (m,), optional

        Returns
        -------
        score : float
        """
        y = np.asarray(y, dtype=np.float64)
        if y.ndim == 3:
            y = y.reshape(y.shape[0], -1)
        truth = StampNormalizer().fit_transform(y)
        pred = self.predict(X)
        return float(
            r2_score(truth, pred, sample_weight=sample_weight, multioutput="variance_weighted")
        )

    def __sklearn_tags__(self):
        tags = super().__sklearn_tags__()
        tags.target_tags.multi_output = True
        tags.target_tags.single_output = False
        return tags
