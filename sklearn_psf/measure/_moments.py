"""Batched adaptive (Gaussian-weighted) second moments of postage stamps.

The iteration follows the one described by Bernstein & Jarvis (2002) and Hirata & Seljak (2003)
as implemented in GalSim's HSM module (``find_ellipmom_2``): the weight is an elliptical Gaussian
``w = exp(-rho^2 / 2)`` with ``rho^2 = (r - r0)^T M^-1 (r - r0)``; at convergence the weighted
second moments equal ``M / 2`` and ``M`` is the covariance of the best-fitting elliptical
Gaussian. This is a fresh, vectorised implementation: all stamps of a batch are iterated together
and only the not-yet-converged ones are carried to the next step.
"""

from __future__ import annotations

import numpy as np
from astropy.table import Table

from .._validation import as_stamps

__all__ = [
    "adaptive_moments",
    "FLAG_OK",
    "FLAG_BAD_PIXELS",
    "FLAG_NO_FLUX",
    "FLAG_DIVERGED",
    "FLAG_MAX_ITER",
]

#: The measurement converged.
FLAG_OK = 0
#: The stamp holds NaN or infinite pixels (nothing is measured).
FLAG_BAD_PIXELS = 1
#: The stamp holds no positive flux (all zero, or the weighted flux became non-positive).
FLAG_NO_FLUX = 2
#: The iteration diverged: moments not positive definite, larger than ``max_moment``,
#: centroid moved more than ``max_shift`` pixels, too few pixels under the weight, or NaN.
FLAG_DIVERGED = 4
#: The iteration did not converge within ``max_iter`` steps.
FLAG_MAX_ITER = 8

_BOUND_CORRECT = 0.25  # largest relative change of any parameter in one step (as HSM)


def _check_positive(name, value):
    value = float(value)
    if not np.isfinite(value) or value <= 0:
        raise ValueError(f"{name} must be a positive finite number, got {value!r}.")
    return value


def adaptive_moments(
    stamps,
    *,
    guess_sigma: float = 5.0,
    guess_centroid=None,
    precision: float = 1e-6,
    max_iter: int = 400,
    max_moment: float = 8000.0,
    max_shift: float = 15.0,
) -> Table:
    """Adaptive Gaussian-weighted moments of a batch of stamps.

    For each stamp, iterate an elliptical Gaussian weight ``exp(-rho^2/2)`` (centre ``r0``,
    covariance ``M``) until the weighted first moments vanish and the weighted second moments
    equal ``M/2``; ``M`` is then the covariance of the best-fitting elliptical Gaussian. The
    update rule, step bounds, convergence test, weight truncation (pixels with
    ``exp(-rho^2/2) < precision/10`` ignored) and the initial guess (round Gaussian of width
    ``guess_sigma`` at the stamp centre) are those of GalSim's ``FindAdaptiveMom``, so results
    agree with ``galsim.hsm.FindAdaptiveMom(galsim.Image(stamp, scale=1))``.

    Parameters
    ----------
    stamps : array-like of shape (n, s, s) or (n, s*s)
        Square stamps, background-subtracted. Not modified.
    guess_sigma : float, default=5.0
        Initial width (pixels) of the round weight.
    guess_centroid : array-like of shape (2,) or (n, 2), optional
        Initial centre (x0, y0) in stamp pixel coordinates; default the stamp centre
        ((s-1)/2, (s-1)/2).
    precision : float, default=1e-6
        Convergence threshold on the largest relative step of centroid and moments.
    max_iter : int, default=400
        Largest number of iterations before a stamp is flagged ``FLAG_MAX_ITER``.
    max_moment : float, default=8000.0
        Largest allowed |M_ij| (pixels^2) before a stamp is flagged ``FLAG_DIVERGED``.
    max_shift : float, default=15.0
        Largest allowed move of the centroid from its initial guess (pixels).

    Returns
    -------
    table : astropy.table.Table
        One row per stamp, columns

        - ``e1``, ``e2``: distortion ``(Mxx - Myy + 2i Mxy) / (Mxx + Myy)`` (GalSim's
          ``observed_shape.e1/e2``), x along columns;
        - ``sigma``: ``det(M)^(1/4)`` in pixels (GalSim's ``moments_sigma``);
        - ``x0``, ``y0``: centroid in stamp pixel coordinates, 0-based, pixel centres at
          integers, x = column (GalSim's ``moments_centroid`` minus ``(xmin, ymin)`` of the
          image, i.e. minus 1 for a default ``galsim.Image``);
        - ``Mxx``, ``Mxy``, ``Myy``: adaptive covariance (pixels^2);
        - ``amplitude``: flux of the best-fitting Gaussian (GalSim's ``moments_amp``);
        - ``n_iter``: number of iterations;
        - ``flag``: 0 when the measurement converged, otherwise a bit mask of ``FLAG_*``
          values. Flagged rows hold NaN in every float column: check ``flag`` (no exception is
          raised for bad stamps in a batch).

    Raises
    ------
    ValueError
        When stamps are not square or a parameter is out of range.

    Examples
    --------
    >>> import numpy as np
    >>> from sklearn_psf.measure import adaptive_moments
    >>> y, x = np.mgrid[0:25, 0:25] - 12.0
    >>> cov = np.array([[4.0, 1.0], [1.0, 3.0]])          # [[Mxx, Mxy], [Mxy, Myy]]
    >>> icov = np.linalg.inv(cov)
    >>> img = np.exp(-0.5 * (icov[0, 0] * x**2 + 2 * icov[0, 1] * x * y + icov[1, 1] * y**2))
    >>> t = adaptive_moments(img[None])
    >>> print(round(t["e1"][0], 4), round(t["e2"][0], 4), t["flag"][0])
    0.1429 0.2857 0
    """
    cube = as_stamps(stamps)
    n, s, _ = cube.shape
    guess_sigma = _check_positive("guess_sigma", guess_sigma)
    precision = _check_positive("precision", precision)
    max_moment = _check_positive("max_moment", max_moment)
    max_shift = _check_positive("max_shift", max_shift)
    if int(max_iter) != max_iter or max_iter < 1:
        raise ValueError(f"max_iter must be a positive integer, got {max_iter!r}.")
    max_iter = int(max_iter)

    x0 = np.full(n, (s - 1) / 2.0)
    y0 = np.full(n, (s - 1) / 2.0)
    if guess_centroid is not None:
        gc = np.asarray(guess_centroid, dtype=np.float64)
        if gc.shape == (2,):
            gc = np.broadcast_to(gc, (n, 2))
        if gc.shape != (n, 2) or not np.all(np.isfinite(gc)):
            raise ValueError(
                "guess_centroid must be finite with shape (2,) or (n_stamps, 2), "
                f"got shape {gc.shape}."
            )
        x0 = gc[:, 0].copy()
        y0 = gc[:, 1].copy()
    x00, y00 = x0.copy(), y0.copy()
    mxx = np.full(n, guess_sigma**2)
    myy = np.full(n, guess_sigma**2)
    mxy = np.zeros(n)
    amp = np.full(n, np.nan)
    n_iter = np.zeros(n, dtype=np.int64)
    flag = np.zeros(n, dtype=np.int64)
    shiftscale0 = np.full(n, np.nan)

    finite = np.isfinite(cube).all(axis=(1, 2))
    flag[~finite] |= FLAG_BAD_PIXELS
    nonzero = np.zeros(n, dtype=bool)
    nonzero[finite] = (cube[finite] != 0).any(axis=(1, 2))
    flag[finite & ~nonzero] |= FLAG_NO_FLUX

    # Pixels whose weight is below precision / 10 are ignored (as HSM does).
    max_rho2 = -2.0 * np.log(precision / 10.0)
    coords = np.arange(s, dtype=np.float64)

    active = np.flatnonzero(flag == 0)
    while active.size:
        img = cube[active]
        ax0, ay0 = x0[active], y0[active]
        axx, axy, ayy = mxx[active], mxy[active], myy[active]
        det = axx * ayy - axy * axy
        bad = ~((det > 0) & (axx > 0) & (ayy > 0))
        with np.errstate(divide="ignore", invalid="ignore"):
            ixx, ixy, iyy = ayy / det, -axy / det, axx / det
        dx = coords[None, :] - ax0[:, None]  # (m, s) along columns
        dy = coords[None, :] - ay0[:, None]  # (m, s) along rows
        rho2 = (ixx[:, None] * dx * dx)[:, None, :] + (iyy[:, None] * dy * dy)[:, :, None]
        rho2 += (2.0 * ixy[:, None, None]) * dy[:, :, None] * dx[:, None, :]
        inside = rho2 <= max_rho2
        np.multiply(rho2, -0.5, out=rho2)
        np.exp(rho2, out=rho2)
        np.multiply(rho2, inside, out=rho2)
        np.multiply(rho2, img, out=rho2)  # weighted intensity, (m, s, s) [row, col]
        a = rho2.sum(axis=(1, 2))
        col = rho2.sum(axis=1)  # (m, s): sum over rows, per column x
        row = rho2.sum(axis=2)  # per row y
        bx = np.einsum("mj,mj->m", col, dx)
        by = np.einsum("mi,mi->m", row, dy)
        cxx = np.einsum("mj,mj->m", col, dx * dx)
        cyy = np.einsum("mi,mi->m", row, dy * dy)
        cxy = np.einsum("mi,mi->m", np.matmul(rho2, dx[:, :, None])[:, :, 0], dy)
        npix = inside.sum(axis=(1, 2))

        half_trace = 0.5 * (axx + ayy)
        semi_b2 = half_trace - np.sqrt((0.5 * (axx - ayy)) ** 2 + axy * axy)
        no_flux = ~(a > 0)
        bad |= ~(semi_b2 > 0) | (npix < 3)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            shiftscale = np.sqrt(semi_b2)
            ddx = np.clip(2.0 * bx / (a * shiftscale), -_BOUND_CORRECT, _BOUND_CORRECT)
            ddy = np.clip(2.0 * by / (a * shiftscale), -_BOUND_CORRECT, _BOUND_CORRECT)
            dxx = np.clip(4.0 * (cxx / a - 0.5 * axx) / semi_b2, -_BOUND_CORRECT, _BOUND_CORRECT)
            dxy = np.clip(4.0 * (cxy / a - 0.5 * axy) / semi_b2, -_BOUND_CORRECT, _BOUND_CORRECT)
            dyy = np.clip(4.0 * (cyy / a - 0.5 * ayy) / semi_b2, -_BOUND_CORRECT, _BOUND_CORRECT)
            conv = np.max(np.abs(np.stack([ddx, ddy, dxx, dxy, dyy])), axis=0)
            first = n_iter[active] == 0
            shift0 = np.where(first, shiftscale, shiftscale0[active])
            shiftscale0[active] = shift0
            conv = np.where(shiftscale < shift0, conv * shift0 / shiftscale, conv)
            nx0 = ax0 + ddx * shiftscale
            ny0 = ay0 + ddy * shiftscale
            nxx = axx + dxx * semi_b2
            nxy = axy + dxy * semi_b2
            nyy = ayy + dyy * semi_b2
        n_iter[active] += 1
        x0[active], y0[active] = nx0, ny0
        mxx[active], mxy[active], myy[active] = nxx, nxy, nyy
        amp[active] = a

        diverged = (
            bad
            | (np.abs(nxx) > max_moment)
            | (np.abs(nxy) > max_moment)
            | (np.abs(nyy) > max_moment)
            | (np.abs(nx0 - x00[active]) > max_shift)
            | (np.abs(ny0 - y00[active]) > max_shift)
            | ~np.isfinite(conv)
            | ~np.isfinite(nxx + nxy + nyy + nx0 + ny0)
        )
        flag[active[no_flux]] |= FLAG_NO_FLUX
        flag[active[diverged & ~no_flux]] |= FLAG_DIVERGED
        failed = diverged | no_flux
        too_many = ~failed & (n_iter[active] > max_iter)
        flag[active[too_many]] |= FLAG_MAX_ITER
        keep = ~failed & ~too_many & (conv > precision)
        active = active[keep]

    good = flag == 0
    with np.errstate(divide="ignore", invalid="ignore"):
        trace = mxx + myy
        e1 = (mxx - myy) / trace
        e2 = 2.0 * mxy / trace
        sigma = np.abs(mxx * myy - mxy * mxy) ** 0.25
    columns = {
        "e1": e1,
        "e2": e2,
        "sigma": sigma,
        "x0": x0,
        "y0": y0,
        "Mxx": mxx,
        "Mxy": mxy,
        "Myy": myy,
        "amplitude": 2.0 * amp,
    }
    table = Table()
    for name, values in columns.items():
        table[name] = np.where(good, values, np.nan)
    table["n_iter"] = n_iter
    table["flag"] = flag
    return table
