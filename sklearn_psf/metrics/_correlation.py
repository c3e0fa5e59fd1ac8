"""Ellipticity correlation functions (xi = <e e*>) and Rowe (2010)'s D1 (rho1), with TreeCorr."""

from __future__ import annotations

import warnings
from contextlib import contextmanager
from typing import NamedTuple

import numpy as np

__all__ = ["CorrelationResult", "EmptyBinsWarning", "ellipticity_correlation", "rho1"]


@contextmanager
def _catalog_threads(num_threads):
    """TreeCorr's OpenMP threads held to ``num_threads`` (None: its own choice) while a
    catalogue is built: a ``Catalog`` takes no thread setting and converts ``ra``/``dec`` on
    every core, which costs ~7 ms per catalogue of 60 points under ``OMP_NUM_THREADS=1``
    (0.06 ms on one thread)."""
    import treecorr
    import treecorr.util

    if num_threads is None:
        yield
        return
    previous = treecorr.util.max_omp_threads
    treecorr.set_max_omp_threads(num_threads)
    try:
        yield
    finally:
        treecorr.set_max_omp_threads(previous)


class EmptyBinsWarning(UserWarning):
    """Some separation bins contain no pair of points; their xi is NaN."""


class CorrelationResult(NamedTuple):
    """Binned ellipticity correlation function.

    Attributes
    ----------
    theta : ndarray of shape (nbins,)
        Mean separation of the pairs in each bin (TreeCorr's ``meanr``), in ``sep_units``
        (the units of ``X`` when ``sep_units`` is None). Empty bins get the nominal centre.
    theta_nominal : ndarray of shape (nbins,)
        Logarithmic centre of each bin (TreeCorr's ``rnom``).
    xi : ndarray of shape (nbins,)
        Real part of xi+ = <e(r) e*(r + theta)>: the paper's chi(theta), Rowe's D1 for residuals.
        NaN in empty bins (with an :class:`EmptyBinsWarning`).
    xi_im : ndarray of shape (nbins,)
        Imaginary part of xi+ (zero in expectation for a parity-invariant field).
    sigma_xi : ndarray of shape (nbins,)
        Shape-noise error of ``xi``: ``sqrt(varxip)`` from TreeCorr (ignores sample variance).
    npairs : ndarray of shape (nbins,)
        Number of pairs in each bin (each unordered pair counted once in an auto-correlation).
    """

    theta: np.ndarray
    theta_nominal: np.ndarray
    xi: np.ndarray
    xi_im: np.ndarray
    sigma_xi: np.ndarray
    npairs: np.ndarray

    def to_table(self):
        """Return the result as an :class:`astropy.table.Table` (one row per bin)."""
        from astropy.table import Table

        return Table({name: np.asarray(value) for name, value in self._asdict().items()})


def _check_positions(X, name):
    X = np.asarray(X, dtype=np.float64)
    if X.ndim != 2 or X.shape[1] != 2:
        raise ValueError(f"{name} must have shape (n, 2) (columns x, y), got shape {X.shape}.")
    if X.shape[0] < 2:
        raise ValueError(
            f"{name} has {X.shape[0]} point(s): a correlation function needs at least two points."
        )
    if not np.all(np.isfinite(X)):
        raise ValueError(f"{name} contains NaN or infinite positions; remove those rows first.")
    return X


def _check_component(values, n, name):
    values = np.asarray(values, dtype=np.float64)
    if values.ndim != 1:
        raise ValueError(f"{name} must be one-dimensional, got shape {values.shape}.")
    if values.shape[0] != n:
        raise ValueError(
            f"{name} has {values.shape[0]} values but the positions have {n} rows: "
            "pass one ellipticity per position."
        )
    if not np.all(np.isfinite(values)):
        bad = int(np.sum(~np.isfinite(values)))
        raise ValueError(
            f"{name} contains {bad} NaN or infinite value(s); exclude those objects (e.g. the "
            "rows flagged by adaptive_moments) before computing the correlation."
        )
    return values


def _check_binning(min_sep, max_sep, nbins):
    if not (np.isfinite(min_sep) and np.isfinite(max_sep)) or min_sep <= 0:
        raise ValueError(f"min_sep must be positive and finite, got {min_sep!r}.")
    if min_sep >= max_sep:
        raise ValueError(f"min_sep ({min_sep}) must be smaller than max_sep ({max_sep}).")
    if int(nbins) != nbins or nbins < 1:
        raise ValueError(f"nbins must be a positive integer, got {nbins!r}.")
    return float(min_sep), float(max_sep), int(nbins)


def ellipticity_correlation(
    X,
    e1,
    e2,
    *,
    min_sep: float,
    max_sep: float,
    nbins: int,
    X2=None,
    e1_2=None,
    e2_2=None,
    x_units: str | None = None,
    sep_units: str | None = None,
    sky: bool = False,
    bin_slop: float | None = None,
    num_threads: int | None = None,
) -> CorrelationResult:
    """Ellipticity correlation function xi(theta) = <e(r) e*(r + theta)> in logarithmic bins.

    Computed with TreeCorr's :class:`treecorr.GGCorrelation` on flat (Euclidean) coordinates:
    ``xi`` is the real part of TreeCorr's xi+ = sum w_i w_j e_i e_j* / sum w_i w_j over the
    pairs in the bin (unit weights). xi+ does not depend on the orientation of the pair, so
    ellipticities may be distortions e (as here) or reduced shears g alike.

    Parameters
    ----------
    X : array-like of shape (n, 2)
        Positions (x, y).
    e1, e2 : array-like of shape (n,)
        Ellipticity components at ``X``.
    min_sep, max_sep : float
        Range of separations, in ``sep_units`` (the units of ``X`` if None).
    nbins : int
        Number of logarithmic bins between ``min_sep`` and ``max_sep``.
    X2, e1_2, e2_2 : array-like, optional
        Second field for a cross-correlation <e(r) e2*(r + theta)>; give all three or none.
    x_units, sep_units : str, optional
        Angular units of ``X`` and of the separations ("arcsec", "arcmin", "deg", "rad"), passed
        to TreeCorr; give both or neither. With neither, separations are in the units of ``X``.
    sky : bool, default=False
        ``X`` (and ``X2``) hold (RA, Dec) in ``x_units`` (default "deg"): TreeCorr's spherical
        catalogues, separations are great-circle angles in ``sep_units`` (default "arcmin").
        The ellipticities must then be in the sky frame (e1 along RA).
    bin_slop : float, optional
        TreeCorr's binning accuracy (0 = exact pair binning, slow for large n). None uses
        TreeCorr's default, which is fast and accurate to a fraction of the bin width.
    num_threads : int, optional
        OpenMP threads used by TreeCorr (None: all cores).

    Returns
    -------
    result : CorrelationResult
        ``theta`` (mean pair separation per bin), ``theta_nominal``, ``xi``, ``xi_im``,
        ``sigma_xi`` (sqrt of TreeCorr's varxip), ``npairs``.

    Raises
    ------
    ValueError
        Fewer than two points, NaN values, mismatched lengths, ``min_sep >= max_sep``, or no pair
        of points separated by between ``min_sep`` and ``max_sep``.

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.metrics import ellipticity_correlation
    >>> rng = np.random.default_rng(0)
    >>> X = rng.uniform(0, 100, size=(500, 2))
    >>> e1 = 0.02 * np.cos(X[:, 0] / 30)
    >>> e2 = 0.02 * np.sin(X[:, 1] / 30)
    >>> res = ellipticity_correlation(X, e1, e2, min_sep=1, max_sep=50, nbins=5)
    >>> res.xi.shape, bool(res.xi[0] > 0)
    ((5,), True)
    """
    import treecorr

    min_sep, max_sep, nbins = _check_binning(min_sep, max_sep, nbins)
    X = _check_positions(X, "X")
    e1 = _check_component(e1, X.shape[0], "e1")
    e2 = _check_component(e2, X.shape[0], "e2")
    second = [v is not None for v in (X2, e1_2, e2_2)]
    if any(second) and not all(second):
        raise ValueError("For a cross-correlation give all of X2, e1_2 and e2_2 (or none).")
    if sky:
        x_units, sep_units = x_units or "deg", sep_units or "arcmin"
    if (x_units is None) != (sep_units is None):
        raise ValueError(
            "Give both x_units and sep_units (angular positions) or neither (separations in the "
            "units of X)."
        )
    units = {} if x_units is None else {"x_units": x_units, "y_units": x_units}

    def catalog(P, g1, g2):
        if sky:
            with _catalog_threads(num_threads):
                return treecorr.Catalog(ra=P[:, 0], dec=P[:, 1], ra_units=x_units,
                                        dec_units=x_units, g1=g1, g2=g2)
        return treecorr.Catalog(x=P[:, 0], y=P[:, 1], g1=g1, g2=g2, **units)

    config = {"min_sep": min_sep, "max_sep": max_sep, "nbins": nbins}
    if sep_units is not None:
        config["sep_units"] = sep_units
    if bin_slop is not None:
        config["bin_slop"] = float(bin_slop)

    cat1 = catalog(X, e1, e2)
    gg = treecorr.GGCorrelation(**config)
    if all(second):
        X2 = _check_positions(X2, "X2")
        e1_2 = _check_component(e1_2, X2.shape[0], "e1_2")
        e2_2 = _check_component(e2_2, X2.shape[0], "e2_2")
        cat2 = catalog(X2, e1_2, e2_2)
        gg.process(cat1, cat2, num_threads=num_threads)
    else:
        gg.process(cat1, num_threads=num_threads)

    npairs = np.asarray(gg.npairs, dtype=np.float64).copy()
    if not np.any(npairs > 0):
        raise ValueError(
            f"No pair of points is separated by between min_sep={min_sep} and max_sep={max_sep}"
            f"{'' if sep_units is None else ' ' + sep_units}: widen the range or check the units."
        )
    empty = npairs == 0
    xi = np.asarray(gg.xip, dtype=np.float64).copy()
    xi_im = np.asarray(gg.xip_im, dtype=np.float64).copy()
    sigma = np.sqrt(np.asarray(gg.varxip, dtype=np.float64))
    theta = np.asarray(gg.meanr, dtype=np.float64).copy()
    theta_nominal = np.asarray(gg.rnom, dtype=np.float64).copy()
    if np.any(empty):
        warnings.warn(
            f"{int(empty.sum())} of {nbins} separation bins contain no pair; their xi is NaN. "
            "Use fewer bins or a range covered by the data.",
            EmptyBinsWarning,
            stacklevel=2,
        )
        xi[empty] = np.nan
        xi_im[empty] = np.nan
        sigma[empty] = np.nan
        theta[empty] = theta_nominal[empty]
    return CorrelationResult(theta, theta_nominal, xi, xi_im, sigma, npairs)


def rho1(
    X,
    e1_true,
    e2_true,
    e1_model,
    e2_model,
    *,
    min_sep: float,
    max_sep: float,
    nbins: int,
    x_units: str | None = None,
    sep_units: str | None = None,
    sky: bool = False,
    bin_slop: float | None = None,
    num_threads: int | None = None,
) -> CorrelationResult:
    """Correlation function of the ellipticity residuals, Rowe (2010)'s D1 (rho1).

    D1(theta) = <de*(r) de(r + theta)> with de = e_true - e_model, i.e.
    :func:`ellipticity_correlation` of the residuals (its real part does not depend on the order
    of the conjugation).

    Parameters
    ----------
    X : array-like of shape (n, 2)
        Positions where both ellipticities are measured (galaxy-PSFs, not the fitted stars).
    e1_true, e2_true, e1_model, e2_model : array-like of shape (n,)
        Measured and modelled ellipticity components.
    min_sep, max_sep, nbins, x_units, sep_units, sky, bin_slop, num_threads
        As in :func:`ellipticity_correlation`.

    Returns
    -------
    result : CorrelationResult

    See Also
    --------
    rho_statistics : rho1 to rho5.

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.metrics import rho1
    >>> rng = np.random.default_rng(1)
    >>> X = rng.uniform(0, 100, size=(400, 2))
    >>> e1, e2 = 0.02 * np.cos(X[:, 0] / 20), 0.02 * np.sin(X[:, 1] / 20)
    >>> d1 = rho1(X, e1, e2, e1, e2, min_sep=1, max_sep=50, nbins=4)
    >>> np.allclose(d1.xi, 0.0)
    True
    """
    X = _check_positions(X, "X")
    n = X.shape[0]
    de1 = _check_component(e1_true, n, "e1_true") - _check_component(e1_model, n, "e1_model")
    de2 = _check_component(e2_true, n, "e2_true") - _check_component(e2_model, n, "e2_model")
    return ellipticity_correlation(
        X,
        de1,
        de2,
        min_sep=min_sep,
        max_sep=max_sep,
        nbins=nbins,
        x_units=x_units,
        sep_units=sep_units,
        sky=sky,
        bin_slop=bin_slop,
        num_threads=num_threads,
    )
