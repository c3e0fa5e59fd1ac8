"""PSFModel: basis + outlier rejection + interpolation, predicting PSF stamps anywhere."""

from __future__ import annotations

import warnings
from numbers import Integral

import numpy as np
from sklearn.base import BaseEstimator, RegressorMixin, _fit_context, clone
from sklearn.metrics import r2_score
from sklearn.utils._param_validation import HasMethods, Interval, StrOptions
from sklearn.utils.validation import _is_fitted, check_is_fitted, validate_data

from ..preprocessing import (
    FIT_OK,
    ChiSquareOutlierDetector,
    IQROutlierDetector,
    StampNormalizer,
    SuperResolvedPCA,
    stamp_fwhm,
)
from ..interpolate import FewStarsWarning
from ..interpolate._kriging import _MIN_ML_STARS
from ..preprocessing._superres import UNDERSAMPLED_FWHM
from .._persist import StateMixin
from .._validation import rows_text
from ._defaults import _constant_interpolator, make_default_basis, make_default_interpolator
from ._file import read_model, save_model
from ._galsim import to_galsim
from ._noise import fit_interpolator, kriging_steps
from ._outlier_rounds import _calibrated, _OutlierRounds, _warm

__all__ = ["PSFModel", "UnusableStarsWarning", "load_model"]


class UnusableStarsWarning(UserWarning):
    """Some stars could not be fitted on the basis (no centroid or no positive flux) and
    were left out; ``PSFModel.fit_flag_`` tells which."""



#: Fewest stars an interpolator fitting hyperparameters by maximum likelihood (a Kriging with
#: an "auto" range, nugget, ...) is given: with fewer, PSFModel fits a constant PSF.
MIN_LIKELIHOOD_STARS = _MIN_ML_STARS

#: The Kriging parameters that, left to "auto", are fitted by maximum likelihood.
_LIKELIHOOD_PARAMS = ("range", "nugget", "noise_scale", "anisotropy_scaling",
                      "anisotropy_angle")


def _too_few_for(interpolator, n_stars):
    """Whether ``n_stars`` are too few for the maximum likelihood of ``interpolator``'s
    Kriging steps (any of their hyperparameters left to be fitted)."""
    if n_stars >= MIN_LIKELIHOOD_STARS:
        return False
    return any(isinstance(step.get_params(deep=False).get(name), str)
               for _, step in kriging_steps(interpolator) for name in _LIKELIHOOD_PARAMS)


class PSFModel(StateMixin, _OutlierRounds, RegressorMixin, BaseEstimator):
    """A PSF model: a stamp basis, outlier rejection and an interpolator of coefficients.

    What :class:`sklearn.compose.TransformedTargetRegressor` is to scikit-learn: ``fit(X, y,
    weights=None)`` with star positions ``X``, raw star stamps ``y`` and optionally their pixel
    weights (inverse variance, 0 = masked; NaN pixels are masked too)

    1. fits ``basis`` on the stamps and fits each star on it: coefficients (n, k) and, for a
       noise-aware basis such as the default :class:`~sklearn_psf.preprocessing.StampPCA`,
       their noise variance from the pixel weights (weighted least squares on the unmasked
       pixels: masked pixels are left out, not zero-filled);
    2. rejects outlying stars (fit time only; the kept stars are ``inlier_mask_``); with
       ``outliers="chi2"`` (the default), a star is rejected when its pixels differ from its
       own fit on the basis, or its coefficients from their interpolation from the other
       stars (5-fold cross-prediction), by more than its noise and the model's own error
       allow, judged against the other stars where they all depart from the noise law
       (:class:`~sklearn_psf.preprocessing.ChiSquareOutlierDetector`; the pixel noise is
       first learnt from the stars' residuals, ``pixel_noise_``), or when that departure
       and the star's pixel residual have the shape an unresolved companion gives them (a
       larger size, an ellipticity along the separation; see the user guide); at most the
       detector's ``max_remove`` of the stars. Pixels outside a star's core that hold light
       its model does not (an uncatalogued neighbour, a cosmic-ray hit) are masked
       (``contaminated_pixels_``) and the star judged again; the basis is then fitted
       again without the rejected stars;
    3. fits ``interpolator`` on (positions, coefficients) of the kept stars, passing each
       star's coefficient noise when the interpolator takes it: the full covariance across
       components as ``noise_cov`` to co-Kriging (the default; the components' noise is
       correlated through the common flux normalisation), the variances as ``noise_var``
       otherwise (Kriging with a measurement-error term, weighted least squares for
       polynomials, smoothing for RBF).

    ``predict(X)`` interpolates coefficients at X and rebuilds normalised (unit-sum), centred
    stamps with ``basis_.inverse_transform``.

    The paper's noise-blind model is ``PSFModel(basis=make_paper_basis(),
    interpolator=make_paper_interpolator(), outliers="iqr")`` (PCA keeping 90% of the
    variance, exponential Kriging with range 0.5 and nugget 0, IQR cut with alpha 3.5).

    Parameters
    ----------
    interpolator : regressor, optional
        A multi-output scikit-learn regressor from positions (n, d) to coefficients (n, k).
        Default :func:`make_default_interpolator` (IsotropicScaler + Kriging with its range
        and sills fitted by maximum likelihood).
    basis : transformer, optional
        Transformer from stamps to coefficients with ``inverse_transform``. Default
        :func:`make_default_basis` (:class:`~sklearn_psf.preprocessing.StampPCA`), or, when
        the stars are undersampled (median FWHM under 2 pixels, see
        :func:`~sklearn_psf.preprocessing.stamp_fwhm`),
        :class:`~sklearn_psf.preprocessing.SuperResolvedPCA` (the PSF on a finer grid than
        the pixels, each star fitted at its own sub-pixel phase). Bases
        without a ``project`` method (e.g. :func:`make_paper_basis`, or
        ``make_pipeline(StampNormalizer(), FixedBasis(components, mean))``) know no noise:
        they take clean, unmasked stamps and no weights. A basis whose ``fit`` takes
        ``positions`` is given the stars' positions (``SuperResolvedPCA``: its joint
        refinement of the PSF's variation over the field).
    outliers : "chi2", "iqr", outlier detector or None, default="chi2"
        "chi2": :class:`~sklearn_psf.preprocessing.ChiSquareOutlierDetector` on standardised
        residuals (see above; with a basis that knows no noise, on the coefficients'
        cross-prediction residuals only, in units of their robust scatter). A
        ``ChiSquareOutlierDetector`` instance works the same way with its own ``p_value``.
        "iqr": the paper's ``IQROutlierDetector(alpha=3.5)`` on the coefficients; any
        scikit-learn outlier detector with ``fit_predict`` returning +1/-1 also works on the
        coefficients. None keeps every star.
    cv : int, default=5
        Folds of the cross-prediction used by the chi^2 test.
    random_state : int, RandomState or None, default=0
        Seeds the folds of the cross-prediction (and nothing else).

    Attributes
    ----------
    basis_ : transformer
        Fitted basis.
    outliers_ : outlier detector or None
        Fitted detector.
    interpolator_ : regressor
        Interpolator fitted on the kept stars.
    inlier_mask_ : ndarray of shape (n_stars,), bool
        Stars kept for the interpolation (usable and not rejected).
    fit_flag_ : ndarray of shape (n_stars,), int
        The basis fit's flag of each star (``FIT_OK`` = 0 for bases that know no noise).
    n_components_ : int
        Number of coefficients per stamp.
    stamp_size_ : int
        Side s of the stamps.
    n_features_in_ : int
        Number of position columns (2 for (x, y)).
    X_fit_ : ndarray of shape (n_stars, n_features)
        Positions of the stars given to ``fit``.
    coefficients_ : ndarray of shape (n_stars, n_components_)
        Basis coefficients of those stars (NaN where ``fit_flag_`` is not 0).
    coefficient_var_ : ndarray of shape (n_stars, n_components_) or None
        Their noise variance (None for a basis that knows no noise).
    coefficient_cov_ : ndarray of shape (n_stars, n_components_, n_components_) or None
        Their noise covariance (None for a basis that does not give it).
    outlier_score_ : ndarray of shape (n_stars,)
        The detector's ``score_samples`` (larger = more normal; log10 p-value for "chi2");
        NaN for unusable stars; None without outlier rejection.
    pixel_noise_ : PixelNoise or None
        With ``outliers="chi2"`` and a noise-aware basis, the stars' pixel noise learnt from
        their residuals (``sky``: scale of the weights' variances, ``poisson``: a Poisson
        term per unit of the model missing from them, ``1 / gain``; ``eps2``: the model's
        relative error squared); real images rarely carry the right noise model (no gain,
        other units, resampling). None otherwise.
    contaminated_pixels_ : ndarray of shape (n_stars,), int
        Pixels of each star's stamp masked after the first fit as holding light its model
        does not (a neighbour missing from the catalogue, a cosmic-ray hit, a bad pixel;
        outside the star's core), so that the star is cleaned rather than rejected.
    spatial_model_ : str
        The spatial freedom the fit gave the PSF, which follows the number of stars (as
        PSFEx lowers its polynomial's degree): ``"interpolator"``, the interpolator as
        given; ``"constant"`` when the stars kept were fewer than its maximum likelihood
        needs (10 for a Kriging with hyperparameters to fit, as the default's): the
        PSF is then the same over the field, the noise-weighted mean of the stars'
        coefficients (a polynomial of degree 0), with a
        :class:`~sklearn_psf.interpolate.FewStarsWarning` saying so.

    See Also
    --------
    sklearn_psf.validation.fit_and_validate : fit with reserved stars and report residuals.
    sklearn_psf.model.save_model : the model file format.

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.model import PSFModel
    >>> rng = np.random.default_rng(0)
    >>> X = rng.uniform(0, 1000, (80, 2))
    >>> yy, xx = np.mgrid[0:15, 0:15] - 7.0
    >>> sig = (1.8 + X[:, 0] / 2000.0)[:, None, None]   # size varies along x: 2 components
    >>> stars = 5e4 * np.exp(-0.5 * (xx**2 + yy**2) / sig**2) / (2 * np.pi * sig**2)
    >>> stamps = stars + rng.normal(0.0, 10.0, stars.shape)   # S/N about 200
    >>> weights = np.full((80, 15 * 15), 1 / 10.0**2)           # inverse variance
    >>> model = PSFModel().fit(X, stamps.reshape(80, -1), weights=weights)
    >>> model.n_components_, bool(model.inlier_mask_.mean() > 0.95)
    (2, True)
    >>> model.predict([[500.0, 500.0]]).shape
    (1, 225)
    """

    _parameter_constraints: dict = {
        "interpolator": [HasMethods(["fit", "predict"]), None],
        "basis": [HasMethods(["fit", "transform", "inverse_transform"]), None],
        "outliers": [StrOptions({"chi2", "iqr"}), HasMethods(["fit_predict"]), None],
        "cv": [Interval(Integral, 2, None, closed="left")],
        "random_state": ["random_state"],
    }

    def __init__(self, interpolator=None, basis=None, outliers="chi2", cv=5, random_state=0):
        self.interpolator = interpolator
        self.basis = basis
        self.outliers = outliers
        self.cv = cv
        self.random_state = random_state

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
            if self.outliers == "chi2":
                return ChiSquareOutlierDetector()
            if self.outliers == "iqr":
                return IQROutlierDetector(alpha=3.5)
            raise ValueError(f"outliers must be 'chi2', 'iqr', None or an outlier detector, "
                             f"got {self.outliers!r}.")
        if not hasattr(self.outliers, "fit_predict"):
            raise TypeError(
                "outliers must be 'chi2', 'iqr', None or an estimator with fit_predict "
                f"returning +1/-1, got {type(self.outliers).__name__}."
            )
        return clone(self.outliers)

    # -- persisted state (see sklearn_psf._persist) ------------------------------------------
    _state_attributes = ("basis_", "outliers_", "interpolator_", "inlier_mask_", "fit_flag_",
                         "outlier_score_", "n_components_", "stamp_size_", "n_features_in_",
                         "X_fit_", "coefficients_", "coefficient_var_", "coefficient_cov_",
                         "spatial_model_")

    def _set_state(self, state):
        """Restore the fitted model: the basis and the outlier detector as given (fitted by
        their own states), the interpolator fitted on the stored stars (the inliers of
        ``X_fit_``, their ``coefficients_`` and noise), which solves with the choices its
        state holds (Kriging's hyperparameters: no likelihood). A detector that is not fitted
        (a scikit-learn one, which stores no state) is fitted on the stored coefficients, as
        is the model's own detector (``outliers``) when ``state`` has no ``outliers_``
        (files written before the detectors stored their state)."""
        state = {"fit_flag_": np.zeros(len(state["X_fit_"]), dtype=np.int64),
                 "outlier_score_": None, "coefficient_var_": None, "coefficient_cov_": None,
                 "spatial_model_": "interpolator", **state}
        if "outliers_" not in state:
            state["outliers_"] = self._make_outliers()
        super()._set_state(state)
        coef, mask = self.coefficients_, self.inlier_mask_
        detector = self.outliers_
        if detector is not None and not _is_fitted(detector):
            detector.fit(coef[np.isfinite(coef).all(axis=1)])
        var, cov = self.coefficient_var_, self.coefficient_cov_
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # they were shown when the model was fitted
            fit_interpolator(self.interpolator_, self.X_fit_[mask], coef[mask],
                             None if var is None else var[mask],
                             None if cov is None else cov[mask])
        return self

    def _check_fit_data(self, X, y, weights):
        if y is None:
            raise ValueError(f"{type(self).__name__} requires y to be passed, but the target y "
                             "is None: pass the star stamps.")
        y = np.asarray(y)
        if y.ndim == 3:
            y = y.reshape(y.shape[0], -1)
        X, y = validate_data(self, X, y, multi_output=True, y_numeric=True, dtype=np.float64,
                             ensure_all_finite=True)
        if y.ndim != 2:
            raise ValueError("y must hold flattened stamps of shape (n_stars, s*s).")
        if X.shape[1] < 2:
            raise ValueError(f"X has n_features = {X.shape[1]}: PSFModel needs the stars' "
                             "positions (x, y), X of shape (n_stars, 2) (or more columns for "
                             f"further dimensions); got X {X.shape} for stamps {y.shape}.")
        s = int(round(np.sqrt(y.shape[1])))
        if s * s != y.shape[1]:
            raise ValueError(
                f"y has {y.shape[1]} pixels per star: pass flattened square stamps "
                "(n_stars, s*s)."
            )
        n = X.shape[0]
        if n < 3:
            raise ValueError(f"PSFModel needs at least 3 stars, got n_samples = {n}.")
        if weights is not None:
            weights = np.asarray(weights, dtype=np.float64)
            if weights.ndim == 3:
                weights = weights.reshape(weights.shape[0], -1)
            if weights.shape != y.shape:
                raise ValueError(f"weights must have the shape of the stamps {y.shape}, got "
                                 f"{weights.shape}.")
        return X, y, s, weights

    @_fit_context(prefer_skip_nested_validation=False)  # its parameters are estimators
    def fit(self, X, y, weights=None):
        """Fit the basis on the stamps, reject outliers, fit the interpolator.

        Parameters
        ----------
        X : array-like of shape (n_stars, n_features)
            Star positions, usually (x, y) in pixels; further columns (e.g. an exposure
            index for a multi-exposure model) are passed to the interpolator as they are.
        y : array-like of shape (n_stars, s*s) or (n_stars, s, s)
            Star stamps (raw, any flux units), NaN for masked pixels. Not modified. The PSF's
            centre is the stamp's centre, pixel ``((s - 1) / 2, (s - 1) / 2)`` (0-based):
            the central pixel for odd s, the corner shared by the four central pixels for
            even s (GalSim's ``true_center``).
        weights : array-like of the shape of y, optional
            Inverse variance of each pixel, 0 for masked ones. Default: estimated from each
            stamp's border (see :func:`~sklearn_psf.preprocessing.estimate_pixel_weights`).
            A fit parameter that ``cross_validate``/``GridSearchCV`` split with the stars
            (with metadata routing: ``PSFModel().set_fit_request(weights=True)``).

        Returns
        -------
        self : PSFModel

        Raises
        ------
        ValueError
            For NaN positions, non-square stamps, too few stars for the basis,
            or when outlier rejection leaves too few stars; rows are named in the caller's
            numbering.
        """
        y_in = np.asarray(y) if y is not None else None
        X, y, s, weights = self._check_fit_data(
            X, None if y_in is None else np.where(np.isnan(y_in), 0.0, y_in), weights)
        if np.isnan(y_in).any():  # NaN pixels are masked pixels
            y = np.where(np.isnan(y_in.reshape(y.shape)), np.nan, y)
        basis = self._default_basis(y, weights) if self.basis is None else clone(self.basis)
        # (unfitted: each fit clones it or warm-starts the previous round's)
        template = make_default_interpolator() if self.interpolator is None else clone(
            self.interpolator)
        spatial = "interpolator"
        detector = self._make_outliers()
        noise_aware = hasattr(basis, "project")
        n = X.shape[0]
        if not noise_aware:
            self._check_noise_blind(basis, y, weights)

        keep = np.ones(n, dtype=bool)
        fitted, fit_warnings = None, []  # the chi^2 test's interpolator and its warnings
        contaminated = np.zeros(y.shape, dtype=bool)
        held = {}  # what the first round's basis chose from the stars, held in the second
        for round_ in range(2):
            fresh = clone(basis)
            if held:
                fresh.set_params(**held)
            basis, fitted_stars = self._fit_basis(fresh, y, weights, keep, X)
            coef, var, cov, flag, stamp_fit = self._project(basis, y, weights, keep,
                                                            fitted_stars)
            usable = flag == FIT_OK
            k = coef.shape[1]
            if usable.sum() < k + 2:
                raise ValueError(f"{int(usable.sum())} usable stars are too few for a basis of "
                                 f"{k} components: need at least {k + 2}.")
            trusted = usable & keep
            if spatial == "interpolator" and _too_few_for(template, int(trusted.sum())):
                template, spatial, fitted = _constant_interpolator(), "constant", None
            # (the second round's fit starts from the first's: it is refitted in place)
            inliers, score, fitted, fit_warnings, hit, noise = self._reject(
                detector, X, y, coef, var, cov, trusted, usable, template, stamp_fit, basis,
                previous=fitted)
            mask = usable & inliers
            new = None if hit is None or round_ == 1 else hit & ~contaminated
            if round_ == 1 or not noise_aware or ((mask == trusted).all()
                                                   and (new is None or not new.any())):
                break
            if new is not None and new.any():  # the neighbours' light masked, not the star
                contaminated |= new
                y = np.where(contaminated, np.nan, y)
            weights = _calibrated(weights, stamp_fit, noise, usable)
            keep = inliers  # fit the basis again without the rejected stars
            held = getattr(basis, "_refit_params", dict)()
            # (this round's per-star arrays go before the next round's)
            coef = var = cov = stamp_fit = None
        if (~usable).any():
            warnings.warn(
                f"{int((~usable).sum())} stars could not be fitted on the basis (no centroid "
                f"or no positive flux) and were left out: rows "
                f"{rows_text(np.flatnonzero(~usable))}.", UnusableStarsWarning, stacklevel=2)
        kept = int(mask.sum())
        if kept < 2:
            raise ValueError(
                f"Outlier rejection kept {kept} of {n} stars: too few to interpolate. Use a "
                "milder detector (e.g. a larger p_value or alpha) or outliers=None."
            )
        if spatial == "interpolator" and _too_few_for(template, kept):
            template, spatial, fitted = _constant_interpolator(), "constant", None
        if spatial == "constant":
            warnings.warn(
                f"{kept} stars are fewer than the {MIN_LIKELIHOOD_STARS} that the "
                "interpolator's maximum likelihood needs: the PSF is modelled as constant "
                "over the field (the noise-weighted mean of the stars' coefficients), as "
                "PSFEx lowers its polynomial's degree with few stars.", FewStarsWarning,
                stacklevel=2)
        if fitted is not None and (mask == trusted).all():
            # the chi^2 test's fit is on exactly these stars: it is the model, with its
            # warnings (those of fits on other stars are not the model's)
            interp = fitted
            for w in fit_warnings:
                warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
        else:
            interp = fit_interpolator(_warm(template, fitted), X[mask], coef[mask],
                                      None if var is None else var[mask],
                                      None if cov is None else cov[mask])
        interp = _warm(template, interp, on=False)

        self.basis_ = basis
        self.outliers_ = detector
        self.interpolator_ = interp
        self.inlier_mask_ = mask
        self.fit_flag_ = flag
        self.outlier_score_ = score
        self.contaminated_pixels_ = contaminated.sum(axis=1)
        self.pixel_noise_ = noise
        self.n_components_ = k
        self.stamp_size_ = s
        self.X_fit_ = np.array(X, copy=True)
        self.coefficients_ = coef
        self.coefficient_var_ = var
        self.coefficient_cov_ = cov
        self.spatial_model_ = spatial
        return self

    @staticmethod
    def _default_basis(y, weights):
        """:func:`make_default_basis`, or a super-resolved basis for undersampled stars."""
        fwhm = stamp_fwhm(np.where(np.isnan(y), 0.0, y),
                          np.where(np.isnan(y), 0.0, 1.0 if weights is None else weights))
        if np.isfinite(fwhm).any() and np.nanmedian(fwhm) < UNDERSAMPLED_FWHM:
            return SuperResolvedPCA()
        return make_default_basis()

    @staticmethod
    def _check_noise_blind(basis, y, weights):
        if weights is not None:
            raise TypeError(
                f"This model's basis ({type(basis).__name__}) cannot use pixel weights: use a "
                "noise-aware basis such as StampPCA (the default), or give no weights."
            )
        bad = np.isnan(y).any(axis=1)
        if bad.any():
            raise ValueError(
                f"Stamps with NaN (masked) pixels at rows {rows_text(np.flatnonzero(bad))}: "
                f"this model's basis ({type(basis).__name__}) cannot mask pixels; use a "
                "noise-aware basis such as StampPCA (the default) or drop those stars."
            )
        nonpos = ~(y.sum(axis=1) > 0)
        if nonpos.any():
            raise ValueError(
                f"Stamps with non-positive total flux at rows "
                f"{rows_text(np.flatnonzero(nonpos))}: they are not star stamps."
            )

    def save(self, path, *, residuals=None, summary=None, overwrite: bool = False) -> None:
        """Write the fitted model to a self-describing FITS file (atomically).

        See :func:`sklearn_psf.model.save_model` for the format; joblib/pickle work too.

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
        save_model(self, path, residuals=residuals, summary=summary, overwrite=overwrite)

    @classmethod
    def load(cls, path) -> "PSFModel":
        """Read a model written by :meth:`save`: :func:`load_model` as a class method.

        Parameters
        ----------
        path : str or os.PathLike

        Returns
        -------
        model : PSFModel
            Fitted (errors as :func:`load_model`'s).
        """
        return read_model(path, cls)

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

    def predict(self, X, offsets=None, fine=False):
        """Normalised PSF stamps at positions X.

        Parameters
        ----------
        X : array-like of shape (m, 2)
        offsets : array-like of shape (m, 2), optional
            (dx, dy) of each star from the stamp's centre pixel, in pixels: the stamps as a
            star at that sub-pixel position shows the PSF (drawn from the fine grid for a
            :class:`~sklearn_psf.preprocessing.SuperResolvedPCA` basis; a Fourier shift of
            the centred stamp for a basis with ``render``). Default: centred.
        fine : bool, default=False
            The PSF on the fine grid of a super-resolved basis (``(m, S*S)``, unit sum,
            ``basis_.oversampling_`` samples per pixel) instead of the pixels.

        Returns
        -------
        stamps : ndarray of shape (m, s*s), or (m, S*S) with ``fine``
        """
        coef = self.predict_coefficients(X)
        if fine:
            if not hasattr(self.basis_, "render_fine"):
                raise ValueError(f"fine=True needs a super-resolved basis (SuperResolvedPCA); "
                                 f"this model's basis is {type(self.basis_).__name__}.")
            return self.basis_.render_fine(coef)
        if offsets is None:
            return np.asarray(self.basis_.inverse_transform(coef), dtype=np.float64)
        if not hasattr(self.basis_, "render"):
            raise ValueError(f"offsets need a basis with render (StampPCA, SuperResolvedPCA); "
                             f"this model's basis is {type(self.basis_).__name__}.")
        stamps = self.basis_.render(coef, offsets=np.asarray(offsets, dtype=np.float64))
        return stamps / stamps.sum(axis=1, keepdims=True)

    def to_galsim(self, x: float, y: float, *, wcs=None, **kwargs):
        """The PSF at 0-based pixel (x, y) as a ``galsim.InterpolatedImage`` (needs GalSim).

        See :func:`sklearn_psf.model.to_galsim` (parameters, centring, ``method='no_pixel'``).
        """
        return to_galsim(self, x, y, wcs=wcs, **kwargs)

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


def load_model(path) -> PSFModel:
    """Read a PSF model file written by :func:`save_model` / :meth:`PSFModel.save`.

    Files of every known format version (``FORMAT`` keyword, see
    :data:`MODEL_FORMAT_VERSION`) load; a newer or unknown version fails with a message
    naming the version and what to do.

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
        For a missing, corrupt or truncated file, a FITS file that is not a model file, or an
        unknown/newer format version.

    Examples
    --------
    >>> import os, tempfile
    >>> import numpy as np
    >>> from sklearn_psf.model import PSFModel, load_model, save_model
    >>> rng = np.random.default_rng(0)
    >>> X = rng.uniform(0, 1000, (40, 2))
    >>> yy, xx = np.mgrid[0:11, 0:11] - 5.0
    >>> y = np.exp(-0.5 * (xx.ravel() ** 2 + yy.ravel() ** 2) / (1.5 + X[:, :1] / 1e3) ** 2)
    >>> model = PSFModel(outliers=None).fit(X, y + rng.normal(0, 1e-3, y.shape))
    >>> path = os.path.join(tempfile.mkdtemp(), "psf.fits")
    >>> save_model(model, path)
    >>> bool(np.array_equal(load_model(path).predict(X), model.predict(X)))
    True
    """
    return read_model(path, PSFModel)
