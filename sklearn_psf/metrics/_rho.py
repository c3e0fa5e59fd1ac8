"""The rho statistics rho1-rho5 of PSF model residuals (Jarvis et al. 2016), with TreeCorr."""

from __future__ import annotations

import numpy as np

from ._correlation import CorrelationResult, _check_component, _check_positions, \
    ellipticity_correlation

__all__ = ["FOURTH_RHO_NAMES", "RHO_NAMES", "fourth_moment_rho_statistics", "rho_statistics"]

#: The five statistics, in order.
RHO_NAMES = ("rho1", "rho2", "rho3", "rho4", "rho5")


def rho_statistics(X, e1_star, e2_star, T_star, e1_model, e2_model, T_model, *,
                   min_sep: float, max_sep: float, nbins: int, x_units: str | None = None,
                   sep_units: str | None = None, sky: bool = False,
                   bin_slop: float | None = None,
                   num_threads: int | None = None) -> dict[str, CorrelationResult]:
    """rho1 to rho5 of Jarvis et al. (2016, DES SV), as PIFF reports them.

    With e the stars' ellipticity, de = e_star - e_model and dT/T = (T_star - T_model) /
    T_star (T the size, e.g. 2 sigma^2 of adaptive moments; any size whose ratio is meant):

    - rho1 = <de* de>
    - rho2 = <e* de>
    - rho3 = <(e dT/T)* (e dT/T)>
    - rho4 = <de* (e dT/T)>
    - rho5 = <e* (e dT/T)>

    each the real part of TreeCorr's xi+ (:func:`ellipticity_correlation`), a cross-correlation
    over all ordered pairs of distinct objects for rho2, rho4 and rho5. Measure them on
    reserved stars (not used in the fit), as :func:`sklearn_psf.validation.fit_and_validate`
    does.

    Parameters
    ----------
    X : array-like of shape (n, 2)
        Positions: (x, y) pixels, or (RA, Dec) with ``sky=True``.
    e1_star, e2_star, T_star, e1_model, e2_model, T_model : array-like of shape (n,)
        Ellipticities and sizes of the stars and of the model at the stars.
    min_sep, max_sep, nbins, x_units, sep_units, bin_slop, num_threads
        As in :func:`ellipticity_correlation`.
    sky : bool, default=False
        X holds (RA, Dec) in ``x_units`` (default deg): separations are great-circle angles in
        ``sep_units`` (default arcmin). Ellipticities must then be in the sky frame.

    Returns
    -------
    dict
        ``"rho1"`` ... ``"rho5"`` -> :class:`CorrelationResult`.

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.metrics import rho_statistics
    >>> rng = np.random.default_rng(0)
    >>> X = rng.uniform(0, 1000, (300, 2))
    >>> e1, e2 = 0.03 * np.cos(X[:, 0] / 300), 0.03 * np.sin(X[:, 1] / 300)
    >>> T = np.full(300, 8.0)
    >>> rho = rho_statistics(X, e1, e2, T, e1, e2, T, min_sep=20, max_sep=500, nbins=4)
    >>> [float(np.abs(rho[k].xi).max()) for k in ("rho1", "rho3", "rho4")]
    [0.0, 0.0, 0.0]
    >>> bool(rho["rho2"].npairs[0] > 0)
    True
    """
    X = _check_positions(X, "X")
    n = X.shape[0]
    star = [_check_component(v, n, name) for v, name in
            ((e1_star, "e1_star"), (e2_star, "e2_star"), (T_star, "T_star"))]
    model = [_check_component(v, n, name) for v, name in
             ((e1_model, "e1_model"), (e2_model, "e2_model"), (T_model, "T_model"))]
    if np.any(star[2] <= 0):
        raise ValueError("T_star must be positive (a size); remove unmeasured stars first.")
    e = star[0] + 1j * star[1]
    de = e - (model[0] + 1j * model[1])
    edt = e * (star[2] - model[2]) / star[2]
    options = {"min_sep": min_sep, "max_sep": max_sep, "nbins": nbins, "x_units": x_units,
               "sep_units": sep_units, "sky": sky, "bin_slop": bin_slop,
               "num_threads": num_threads}
    pairs = {"rho1": (de, None), "rho2": (e, de), "rho3": (edt, None), "rho4": (de, edt),
             "rho5": (e, edt)}
    out = {}
    for name, (a, b) in pairs.items():
        second = {} if b is None else {"X2": X, "e1_2": b.real, "e2_2": b.imag}
        out[name] = ellipticity_correlation(X, a.real, a.imag, **second, **options)
    return out


#: The fourth-moment correlation functions of :func:`fourth_moment_rho_statistics`, in order.
FOURTH_RHO_NAMES = ("rho_M4", "rho_eM4", "rho_M22", "rho_TM22")


def _scalar_correlation(X, a, b, options):
    """<a b>(theta) of two real fields on the same points (TreeCorr's KKCorrelation), as a
    :class:`CorrelationResult` (``xi_im`` zero)."""
    import treecorr

    from ._correlation import _catalog_threads, _check_binning

    min_sep, max_sep, nbins = _check_binning(options["min_sep"], options["max_sep"],
                                             options["nbins"])
    config = {"min_sep": min_sep, "max_sep": max_sep, "nbins": nbins}
    if options["bin_slop"] is not None:
        config["bin_slop"] = float(options["bin_slop"])
    sky, x_units, sep_units = options["sky"], options["x_units"], options["sep_units"]
    if sky:
        x_units, sep_units = x_units or "deg", sep_units or "arcmin"
    if sep_units is not None:
        config["sep_units"] = sep_units

    def catalog(k):
        if sky:
            with _catalog_threads(options["num_threads"]):
                return treecorr.Catalog(ra=X[:, 0], dec=X[:, 1], ra_units=x_units,
                                        dec_units=x_units, k=k)
        units = {} if x_units is None else {"x_units": x_units, "y_units": x_units}
        return treecorr.Catalog(x=X[:, 0], y=X[:, 1], k=k, **units)

    kk = treecorr.KKCorrelation(**config)
    if b is None:
        kk.process(catalog(a), num_threads=options["num_threads"])
    else:
        kk.process(catalog(a), catalog(b), num_threads=options["num_threads"])
    npairs = np.asarray(kk.npairs, dtype=np.float64).copy()
    if not np.any(npairs > 0):
        raise ValueError(f"No pair of points is separated by between min_sep={min_sep} and "
                         f"max_sep={max_sep}: widen the range or check the units.")
    empty = npairs == 0
    xi = np.where(empty, np.nan, np.asarray(kk.xi, dtype=np.float64))
    sigma = np.where(empty, np.nan, np.sqrt(np.asarray(kk.varxi, dtype=np.float64)))
    nominal = np.asarray(kk.rnom, dtype=np.float64).copy()
    theta = np.where(empty, nominal, np.asarray(kk.meanr, dtype=np.float64))
    return CorrelationResult(theta, nominal, xi, np.zeros_like(xi), sigma, npairs)


def fourth_moment_rho_statistics(X, dM31, dM13, dM22, de1, de2, dT_over_T, *, min_sep: float,
                                 max_sep: float, nbins: int, x_units: str | None = None,
                                 sep_units: str | None = None, sky: bool = False,
                                 bin_slop: float | None = None,
                                 num_threads: int | None = None
                                 ) -> dict[str, CorrelationResult]:
    """rho-like correlation functions of the fourth-moment residuals of PSF models.

    The Dark Energy Survey's Year 6 PSF diagnostics (Schutt et al. 2025, arXiv 2501.05781)
    add the fourth moments to the rho statistics, since errors in them bias shear as much as
    second-moment errors do. With the residuals (star - model) of the spin-2 fourth moment
    ``dM4 = dM31 + i dM13``, of the spin-0 one ``dM22`` (:func:`sklearn_psf.measure.fourth_moments`,
    best made dimensionless, e.g. divided by the star's sigma^4 as
    :func:`sklearn_psf.validation.measure_residuals` does), of the ellipticity ``de`` and of
    the size ``dT/T``:

    - ``rho_M4`` = <dM4* dM4>: spin 2, the real part of xi+ (as rho1 for e);
    - ``rho_eM4`` = <de* dM4>: spin 2, second against fourth moments;
    - ``rho_M22`` = <dM22 dM22>: spin 0 (TreeCorr's KKCorrelation);
    - ``rho_TM22`` = <(dT/T) dM22>: spin 0, size against the fourth moment.

    Parameters
    ----------
    X : array-like of shape (n, 2)
        Positions: (x, y), or (RA, Dec) with ``sky=True``.
    dM31, dM13, dM22, de1, de2, dT_over_T : array-like of shape (n,)
        The residuals, star - model.
    min_sep, max_sep, nbins, x_units, sep_units, sky, bin_slop, num_threads
        As in :func:`rho_statistics`.

    Returns
    -------
    dict
        ``"rho_M4"``, ``"rho_eM4"``, ``"rho_M22"``, ``"rho_TM22"`` ->
        :class:`CorrelationResult` (``sigma_xi``: TreeCorr's shape-noise error).

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.metrics import fourth_moment_rho_statistics
    >>> rng = np.random.default_rng(0)
    >>> X = rng.uniform(0, 1000, (300, 2))
    >>> dM22 = 0.01 * np.cos(X[:, 0] / 400)               # a smooth spin-0 residual
    >>> zero = np.zeros(300)
    >>> rho = fourth_moment_rho_statistics(X, zero, zero, dM22, zero, zero, zero,
    ...                                    min_sep=20, max_sep=300, nbins=3)
    >>> bool(rho["rho_M22"].xi[0] > 0), float(np.abs(rho["rho_M4"].xi).max())
    (True, 0.0)
    """
    X = _check_positions(X, "X")
    n = X.shape[0]
    values = {name: _check_component(v, n, name) for v, name in (
        (dM31, "dM31"), (dM13, "dM13"), (dM22, "dM22"), (de1, "de1"), (de2, "de2"),
        (dT_over_T, "dT_over_T"))}
    options = {"min_sep": min_sep, "max_sep": max_sep, "nbins": nbins, "x_units": x_units,
               "sep_units": sep_units, "sky": sky, "bin_slop": bin_slop,
               "num_threads": num_threads}
    m4 = (values["dM31"], values["dM13"])
    return {
        "rho_M4": ellipticity_correlation(X, *m4, **options),
        "rho_eM4": ellipticity_correlation(X, values["de1"], values["de2"], X2=X,
                                           e1_2=m4[0], e2_2=m4[1], **options),
        "rho_M22": _scalar_correlation(X, values["dM22"], None, options),
        "rho_TM22": _scalar_correlation(X, values["dT_over_T"], values["dM22"], options),
    }
