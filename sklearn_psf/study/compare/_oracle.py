"""The optimum on the same field: the best linear unbiased predictor with the true covariance.

The PCA weights of a simulated PSF field are ``coeff_mean_k + coeff_std_k * g_k(r)`` where the
``g_k`` are Gaussian random fields of known power spectrum, drawn on a grid whose cell is the
field's smallest scale and spline-interpolated (:mod:`sklearn_psf.simulate`). Their true
covariance between positions (:meth:`~sklearn_psf.simulate.PSFField.weight_covariance`) and
each star's true coefficient noise (:meth:`~sklearn_psf.simulate.PSFField.
coefficient_noise_var`) are known. :class:`FieldOracle` is ordinary Kriging of every
coefficient with them: the best linear unbiased predictor of the coefficients at the
galaxy-PSFs given the stars. No interpolation scheme can beat it on average; its residuals
are the floor of the field.

Approximations (stated in the report): the true coefficients are the weights up to the flux
normalisation and centring of the stamps (a second-order change), and the noise of the
centring is not in the noise variance (10-30% of it at S/N 100).
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import LinAlgError, cho_factor, cho_solve, eigh

__all__ = ["FieldOracle"]


def _nearest_psd(matrix):
    """The matrix with its negative eigenvalues set to zero."""
    values, vectors = eigh(matrix)
    return (vectors * np.clip(values, 0.0, None)) @ vectors.T


class FieldOracle:
    """Ordinary Kriging with a simulation's true covariance and each star's true noise.

    Used by :func:`~sklearn_psf.study.compare.run_study` as the scheme ``oracle``: it has the
    ``fit`` / ``predict`` / ``predict_coefficients`` / ``inlier_mask_`` of a fitted
    :class:`~sklearn_psf.model.PSFModel` whose basis is the simulation's reference.

    Parameters
    ----------
    field : PSFField
        The simulation (its reference basis, true covariance and noise).
    noise_var : array-like of shape (n_stars, n_components)
        True coefficient noise variance of the stars passed to ``fit``, in their order
        (rows of ``field.coefficient_noise_var()``).

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.simulate import make_psf_field
    >>> from sklearn_psf.study.compare import FieldOracle
    >>> field = make_psf_field(n_stars=60, n_galaxies=20, image_shape=(600, 800),
    ...                        random_state=0)
    >>> X = np.column_stack([field.stars["x"], field.stars["y"]])
    >>> stamps, flags = field.star_stamps()
    >>> oracle = FieldOracle(field, field.coefficient_noise_var()).fit(X, stamps)
    >>> oracle.predict_coefficients(X[:2]).shape
    (2, 5)
    """

    def __init__(self, field, noise_var):
        self.field = field
        self.noise_var = noise_var

    def fit(self, X, y):
        X = np.asarray(X, float)
        self.basis_ = self.field.reference.as_transformer()
        coef = np.asarray(self.basis_.transform(y), float)
        noise = np.asarray(self.noise_var, float)
        cov = self.field.weight_covariance(X)
        self.X_fit_, self.mean_, self.alpha_, self.projected_ = X, [], [], False
        for k in range(coef.shape[1]):
            # a relative jitter of 1e-10 keeps the factorisation of close stars stable
            jitter = 1e-10 * float(np.mean(np.diag(cov[k]))) * np.eye(len(X))
            try:
                factor = cho_factor(cov[k] + np.diag(noise[:, k]) + jitter)
            except LinAlgError:
                # the tabulated true covariance of many close stars can be slightly indefinite:
                # use its nearest positive semi-definite matrix (same for every component)
                cov = cov if self.projected_ else self._projected(cov)
                factor = cho_factor(cov[k] + np.diag(noise[:, k]) + jitter)
            ones = cho_solve(factor, np.ones(len(X)))
            mean = float(ones @ coef[:, k] / ones.sum())  # generalised least-squares mean
            self.mean_.append(mean)
            self.alpha_.append(cho_solve(factor, coef[:, k] - mean))
        self.inlier_mask_ = np.ones(len(X), dtype=bool)
        return self

    def _projected(self, cov):
        std2 = np.asarray(self.field.reference.coeff_std, float) ** 2
        ref = int(np.argmax(std2))
        self.projected_ = True
        return std2[:, None, None] * _nearest_psd(cov[ref] / std2[ref])[None]

    def predict_coefficients(self, X):
        cov = self.field.weight_covariance(np.asarray(X, float), self.X_fit_)
        return np.column_stack([m + c @ a for m, c, a in zip(self.mean_, cov, self.alpha_)])

    def predict(self, X):
        return np.asarray(self.basis_.inverse_transform(self.predict_coefficients(X)), float)
