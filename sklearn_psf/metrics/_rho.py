"""The rho statistics rho1-rho5 of PSF model residuals (Jarvis et al. 2016), with TreeCorr."""

from __future__ import annotations

import numpy as np

from ._correlation import CorrelationResult, _check_component, _check_positions, \
    ellipticity_correlation

__all__ = ["RHO_NAMES", "rho_statistics"]

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
