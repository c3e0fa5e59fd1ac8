"""The optimal (Wiener-filter) interpolation baseline of Berge et al. (2012), sect. 5.2.

For a Gaussian random PSF ellipticity field with known power spectrum, the posterior mean of
the field given noisy values at the stars (Gaussian-process regression with the true
covariance, i.e. the Wiener filter; Amara et al. 2010) has the smallest possible residuals.
Its residual correlation function is the lowest any interpolation can reach with the same
stars, noise and field.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.linalg import LinAlgError, cho_factor, cho_solve

from ._correlation import ellipticity_correlation

__all__ = ["WienerBaseline", "wiener_filter_baseline"]


def _field_covariance(shape, slope, padding=2.0):
    """Covariance, as a function of the (periodic) lag, of ``gaussian_random_field(...,
    normalize=False)`` on its padded grid of (ceil(ny * padding), ceil(nx * padding)) cells,
    with C(0) = 1."""
    from ..simulate import random_field_power

    py, px = int(np.ceil(shape[0] * padding)), int(np.ceil(shape[1] * padding))
    return np.fft.ifft2(random_field_power((py, px), slope)).real


def _lag_covariance(cov, rows_a, cols_a, rows_b, cols_b):
    py, px = cov.shape
    return cov[(rows_a[:, None] - rows_b[None, :]) % py, (cols_a[:, None] - cols_b[None, :]) % px]


class WienerBaseline(NamedTuple):
    """Correlation functions of the optimal (Wiener-filter) residuals over realisations.

    Attributes
    ----------
    theta : ndarray of shape (nbins,)
        Mean pair separation per bin (averaged over realisations), in the units of
        ``field_size`` (arcmin by default).
    xi_input : ndarray of shape (n_realisations, nbins)
        Ellipticity correlation of the true field at the galaxy positions.
    xi_residual : ndarray of shape (n_realisations, nbins)
        Correlation of the Wiener-filter residuals (true - posterior mean) at the galaxies.
    input_variance, residual_variance : ndarray of shape (n_realisations,)
        <e1^2 + e2^2> of the true field and of the residuals at the galaxies.
    xi_interpolator : ndarray of shape (n_realisations, nbins) or None
        Residual correlation of ``interpolator`` fitted on the same noisy stars, if given.
    interpolator_residual_variance : ndarray of shape (n_realisations,) or None
    """

    theta: np.ndarray
    xi_input: np.ndarray
    xi_residual: np.ndarray
    input_variance: np.ndarray
    residual_variance: np.ndarray
    xi_interpolator: np.ndarray | None
    interpolator_residual_variance: np.ndarray | None

    @property
    def residual_band(self):
        """(mean, min, max) over realisations of ``xi_residual``: the lower shaded band."""
        return (self.xi_residual.mean(0), self.xi_residual.min(0), self.xi_residual.max(0))

    @property
    def input_band(self):
        """(mean, min, max) over realisations of ``xi_input``: the upper shaded band."""
        return (self.xi_input.mean(0), self.xi_input.min(0), self.xi_input.max(0))


def wiener_filter_baseline(
    *,
    n_stars: int = 1000,
    n_galaxies: int = 2000,
    field_size=(33.0, 26.0),
    grid_spacing: float = 0.25,
    e_rms: float = 0.02,
    noise_sigma: float = 0.01,
    slope: float = 11 / 4,
    n_realisations: int = 12,
    min_sep: float = 0.5,
    max_sep: float = 20.0,
    nbins: int = 10,
    interpolator=None,
    random_state=None,
) -> WienerBaseline:
    """Residual correlation of the optimal (Wiener-filter) PSF interpolation (paper's fig_corhsn).

    Each realisation draws two independent Gaussian random fields (e1 and e2, standard
    deviation ``e_rms`` each, power spectrum P(k) ~ k^-slope) with
    :func:`sklearn_psf.simulate.gaussian_random_field` on a grid of ``grid_spacing`` covering
    ``field_size``; places ``n_stars`` stars and ``n_galaxies`` galaxies on distinct random grid
    nodes; adds Gaussian noise ``noise_sigma`` (per component) to the star values; and predicts
    the field at the galaxies with the Gaussian-process posterior mean
    K_gs (K_ss + noise_sigma^2 I)^-1 e_s, where K is the exact covariance of the generated field
    (inverse FFT of its power spectrum on the padded generation grid). The residuals are taken
    against the noise-free field at the galaxies.

    Parameters
    ----------
    n_stars, n_galaxies : int, default=1000, 2000
        Number of stars (interpolation nodes) and of galaxies (scoring points), as in the paper.
    field_size : tuple of two floats, default=(33.0, 26.0)
        (width along x, height along y), in arcmin for the paper's Subaru field.
    grid_spacing : float, default=0.25
        Grid step of the field, same units as ``field_size``.
    e_rms : float, default=0.02
        Standard deviation of each ellipticity component (the paper's PSF: 0.02).
    noise_sigma : float, default=0.01
        Measurement noise of each star's ellipticity component (about 1/(S/N) for S/N ~ 100).
    slope : float, default=11/4
        Minus the power-spectrum slope.
    n_realisations : int, default=12
        Number of independent fields (the paper uses 12).
    min_sep, max_sep, nbins
        Binning of the correlation functions (units of ``field_size``).
    interpolator : scikit-learn regressor, optional
        A regressor of (n, 2) positions -> (n, 2) ellipticities, cloned and fitted on the same
        noisy stars for comparison (e.g. ``KNeighborsRegressor(1)``).
    random_state : None, int or numpy Generator
        Seed for reproducibility.

    Returns
    -------
    baseline : WienerBaseline
        ``theta``, per-realisation ``xi_input`` and ``xi_residual`` (``input_band`` and
        ``residual_band`` give mean, min, max), variances, and the ``interpolator``'s residuals.

    Examples
    --------
    >>> from sklearn_psf.metrics import wiener_filter_baseline
    >>> base = wiener_filter_baseline(n_stars=200, n_galaxies=300, field_size=(10.0, 10.0),
    ...                               n_realisations=2, min_sep=0.5, max_sep=5.0, nbins=4,
    ...                               random_state=0)
    >>> base.xi_residual.shape
    (2, 4)
    >>> bool(base.residual_variance.mean() < base.input_variance.mean())
    True
    """
    from ..simulate import as_generator, gaussian_random_field

    width, height = (float(v) for v in field_size)
    if not (width > 0 and height > 0 and grid_spacing > 0):
        raise ValueError("field_size and grid_spacing must be positive.")
    if e_rms <= 0 or noise_sigma < 0:
        raise ValueError("e_rms must be positive and noise_sigma non-negative.")
    for name, value in (("n_stars", n_stars), ("n_galaxies", n_galaxies),
                        ("n_realisations", n_realisations)):
        if int(value) != value or value < 1:
            raise ValueError(f"{name} must be a positive integer, got {value!r}.")
    if n_galaxies < 2:
        raise ValueError("n_galaxies must be at least 2 to measure a correlation function.")
    nx = int(round(width / grid_spacing)) + 1
    ny = int(round(height / grid_spacing)) + 1
    if n_stars + n_galaxies > nx * ny:
        raise ValueError(
            f"{n_stars + n_galaxies} objects do not fit on the {ny} x {nx} grid: decrease "
            "grid_spacing."
        )
    rng = as_generator(random_state)
    cov = _field_covariance((ny, nx), slope)
    if interpolator is not None:
        from sklearn.base import clone

    corr = dict(min_sep=min_sep, max_sep=max_sep, nbins=nbins, num_threads=1)
    thetas, xi_in, xi_res, var_in, var_res, xi_int, var_int = [], [], [], [], [], [], []
    for _ in range(int(n_realisations)):
        nodes = rng.choice(nx * ny, size=n_stars + n_galaxies, replace=False)
        rows, cols = np.divmod(nodes, nx)
        fields = e_rms * np.stack([gaussian_random_field((ny, nx), slope, rng, normalize=False)
                                   for _ in range(2)])
        values = fields[:, rows, cols].T  # (n, 2)
        s, g = slice(0, n_stars), slice(n_stars, None)
        noisy = values[s] + noise_sigma * rng.standard_normal((n_stars, 2))
        k_ss = e_rms**2 * _lag_covariance(cov, rows[s], cols[s], rows[s], cols[s])
        k_ss[np.diag_indices_from(k_ss)] += noise_sigma**2
        k_gs = e_rms**2 * _lag_covariance(cov, rows[g], cols[g], rows[s], cols[s])
        try:
            factor = cho_factor(k_ss, lower=True)
        except LinAlgError:  # noise-free and (numerically) degenerate: add a tiny nugget
            k_ss[np.diag_indices_from(k_ss)] += 1e-10 * e_rms**2
            factor = cho_factor(k_ss, lower=True)
        predicted = k_gs @ cho_solve(factor, noisy)
        X_gal = np.column_stack([cols[g], rows[g]]) * grid_spacing
        truth = values[g]
        residual = truth - predicted
        r_in = ellipticity_correlation(X_gal, truth[:, 0], truth[:, 1], **corr)
        r_res = ellipticity_correlation(X_gal, residual[:, 0], residual[:, 1], **corr)
        thetas.append(r_in.theta)
        xi_in.append(r_in.xi)
        xi_res.append(r_res.xi)
        var_in.append(np.mean(np.sum(truth**2, axis=1)))
        var_res.append(np.mean(np.sum(residual**2, axis=1)))
        if interpolator is not None:
            X_star = np.column_stack([cols[s], rows[s]]) * grid_spacing
            pred = np.asarray(clone(interpolator).fit(X_star, noisy).predict(X_gal))
            other = truth - pred.reshape(truth.shape)
            xi_int.append(ellipticity_correlation(X_gal, other[:, 0], other[:, 1], **corr).xi)
            var_int.append(np.mean(np.sum(other**2, axis=1)))
    return WienerBaseline(
        theta=np.mean(thetas, axis=0),
        xi_input=np.array(xi_in),
        xi_residual=np.array(xi_res),
        input_variance=np.array(var_in),
        residual_variance=np.array(var_res),
        xi_interpolator=np.array(xi_int) if interpolator is not None else None,
        interpolator_residual_variance=np.array(var_int) if interpolator is not None else None,
    )
