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

from .._validation import as_stamps, rows_text

__all__ = [
    "adaptive_moments",
    "fixed_moments",
    "FLAG_OK",
    "FLAG_BAD_PIXELS",
    "FLAG_NO_FLUX",
    "FLAG_DIVERGED",
    "FLAG_MAX_ITER",
    "FLAG_MASKED",
]

#: The measurement converged.
FLAG_OK = 0
#: An unmasked pixel of the stamp is infinite (nothing is measured).
FLAG_BAD_PIXELS = 1
#: The stamp holds no positive flux (all zero, or the weighted flux became non-positive).
FLAG_NO_FLUX = 2
#: The iteration diverged: moments not positive definite, larger than ``max_moment``,
#: centroid moved more than ``max_shift`` pixels, too few pixels under the weight, or NaN.
FLAG_DIVERGED = 4
#: The iteration did not converge within ``max_iter`` steps.
FLAG_MAX_ITER = 8
#: Masked pixels: every pixel of the stamp is masked (nothing is measured), or the iteration
#: converged but more than ``max_masked_fraction`` of the star's core weight ``exp(-2 rho^2)``
#: falls on masked pixels.
FLAG_MASKED = 16

try:  # the compiled kernel is used when numba is installed (much faster, same results)
    from ._moments_numba import iterate_numba as _iterate_numba
    from ._moments_numba import mask_pixels_numba as _mask_pixels_numba
    from ._moments_numba import masked_core_fraction_numba as _masked_fraction_numba
except ImportError:  # pragma: no cover - depends on the environment
    _iterate_numba = _masked_fraction_numba = _mask_pixels_numba = None

#: Use the compiled kernel when available (tests switch it off to check the numpy path).
_USE_NUMBA = _iterate_numba is not None

_BOUND_CORRECT = 0.25  # largest relative change of any parameter in one step (as HSM)
_CHUNK_PIXELS = 1 << 18  # pixels per chunk of stamps iterated together (~2 MB per float array)


def _check_positive(name, value):
    value = float(value)
    if not np.isfinite(value) or value <= 0:
        raise ValueError(f"{name} must be a positive finite number, got {value!r}.")
    return value


def _masked_pixels(cube, weights):
    """Return ``(stamps with masked pixels set to 0, boolean mask or None when none is masked)``.

    A pixel is masked where its weight is 0 or its value is NaN; ``cube`` is not modified.
    """
    if weights is None:
        masked = np.isnan(cube)
    else:
        w = as_stamps(weights, name="weights")
        if w.shape != cube.shape:
            raise ValueError(
                f"weights must have the shape of the stamps ({cube.shape[0]} stamps of "
                f"{cube.shape[1]}x{cube.shape[2]} pixels), got {w.shape[0]} stamps of "
                f"{w.shape[1]}x{w.shape[2]} pixels."
            )
        if _USE_NUMBA:  # one pass instead of five; None when a weight is invalid
            result = _mask_pixels_numba(cube, w)
            valid = result is not None
        else:  # two reductions instead of a per-pixel test (a NaN fails both comparisons)
            valid = w.min(initial=0.0) >= 0 and w.max(initial=0.0) < np.inf
        if not valid:
            rows = np.flatnonzero(~(np.isfinite(w) & (w >= 0)).all(axis=(1, 2)))
            raise ValueError(
                f"weights hold negative, NaN or infinite values in rows {rows_text(rows)}: "
                "pass inverse variances >= 0, with 0 for "
                "masked pixels."
            )
        if _USE_NUMBA:
            return result
        masked = np.isnan(cube) | (w == 0)
    if not masked.any():
        return cube, None
    return np.where(masked, 0.0, cube), masked


def _masked_core_fraction(masked, idx, x0, y0, mxx, mxy, myy, max_rho2):
    """Fraction of the core weight ``exp(-2 rho^2)`` (where ``4 rho^2 < max_rho2``) on masked
    pixels, for stamps ``idx``."""
    s = masked.shape[1]
    coords = np.arange(s, dtype=np.float64)
    out = np.empty(idx.size)
    chunk = max(1, _CHUNK_PIXELS // (s * s))
    for start in range(0, idx.size, chunk):
        j = idx[start:start + chunk]
        det = (mxx[j] * myy[j] - mxy[j] ** 2)[:, None, None]
        dx = coords[None, None, :] - x0[j, None, None]
        dy = coords[None, :, None] - y0[j, None, None]
        rho2 = 4.0 * (myy[j, None, None] * dx * dx - 2.0 * mxy[j, None, None] * dx * dy
                      + mxx[j, None, None] * dy * dy) / det
        w = np.where(rho2 < max_rho2, np.exp(-0.5 * rho2), 0.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            out[start:start + j.size] = (w * masked[j]).sum(axis=(1, 2)) / w.sum(axis=(1, 2))
    return out


def adaptive_moments(
    stamps,
    *,
    weights=None,
    guess_sigma: float = 5.0,
    guess_centroid=None,
    precision: float = 1e-6,
    max_iter: int = 400,
    max_moment: float = 8000.0,
    max_shift: float = 15.0,
    max_masked_fraction: float = 0.5,
) -> Table:
    """Adaptive Gaussian-weighted moments of a batch of stamps.

    An elliptical Gaussian weight (centre, covariance ``M``) is iterated until the weighted
    first moments vanish and the second moments equal ``M/2``, as GalSim's
    ``FindAdaptiveMom(galsim.Image(stamp, scale=1), badpix=mask)``, which it matches. Masked
    pixels (weight 0 or NaN) are left out of every sum; positive weights do not re-weight
    them. How it differs from HSM, and the masks: :ref:`moments-details`.

    Parameters
    ----------
    stamps : array-like of shape (n, s, s) or (n, s*s)
        Square stamps, background-subtracted. Not modified. NaN pixels are masked.
    weights : array-like of the shape of ``stamps`` (either layout), optional
        Inverse variance of each pixel, 0 for a masked pixel; must be finite and >= 0. Only
        the mask (weight 0) is used. Default: no pixel masked except NaN ones.
    guess_sigma : float, default=5.0
        Initial width (pixels) of the round weight.
    guess_centroid : array-like of shape (2,) or (n, 2), optional
        Initial centre (x0, y0) in stamp pixel coordinates; default ((s-1)/2, (s-1)/2).
    precision : float, default=1e-6
        Convergence threshold on the largest relative step of centroid and moments.
    max_iter : int, default=400
        Iterations before a stamp is flagged ``FLAG_MAX_ITER``.
    max_moment : float, default=8000.0
        Largest |M_ij| (pixels^2) before a stamp is flagged ``FLAG_DIVERGED``.
    max_shift : float, default=15.0
        Largest allowed move of the centroid from its initial guess (pixels).
    max_masked_fraction : float, default=0.5
        Largest fraction, in (0, 1], of the core weight ``exp(-2 rho^2)`` (the Gaussian of
        half the adaptive width) that may fall on masked pixels before a stamp is flagged
        ``FLAG_MASKED``; 1 gives HSM's moments whatever the mask.

    Returns
    -------
    table : astropy.table.Table
        One row per stamp, columns

        - ``e1``, ``e2``: distortion ``(Mxx - Myy + 2i Mxy) / (Mxx + Myy)`` (GalSim's
          ``observed_shape.e1/e2``), x along columns;
        - ``sigma``: ``det(M)^(1/4)`` in pixels (GalSim's ``moments_sigma``);
        - ``x0``, ``y0``: centroid in stamp pixel coordinates, 0-based, x = column;
        - ``Mxx``, ``Mxy``, ``Myy``: adaptive covariance (pixels^2);
        - ``amplitude``: the best-fitting Gaussian's flux; ``n_iter``: iterations;
        - ``flag``: 0 when converged, else a bit mask of ``FLAG_BAD_PIXELS`` 1,
          ``FLAG_NO_FLUX`` 2, ``FLAG_DIVERGED`` 4, ``FLAG_MAX_ITER`` 8, ``FLAG_MASKED`` 16;
          flagged rows hold NaN in every float column (no exception for bad stamps).

    Raises
    ------
    ValueError
        For stamps not square, ``weights`` not of their shape, negative or non-finite, or a
        parameter out of range.

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

    A bad column is left out whatever its values; a mask over the core is flagged:

    >>> w = np.ones_like(img)
    >>> w[:, 14] = 0.0
    >>> img_bad = img.copy()
    >>> img_bad[:, 14] = 1e30                              # e.g. a saturated column
    >>> t = adaptive_moments(img_bad[None], weights=w[None])
    >>> img_bad[:, 14] = np.nan
    >>> t_nan = adaptive_moments(img_bad[None])
    >>> print(t["flag"][0], t_nan["flag"][0], t["e1"][0] == t_nan["e1"][0])
    0 0 True
    >>> w[9:16, 9:16] = 0.0
    >>> print(adaptive_moments(img[None], weights=w[None])["flag"][0])
    16
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
    max_masked_fraction = _check_positive("max_masked_fraction", max_masked_fraction)
    if max_masked_fraction > 1:
        raise ValueError(f"max_masked_fraction must be in (0, 1], got {max_masked_fraction!r}.")
    cube, masked = _masked_pixels(cube, weights)

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

    if masked is not None:
        flag[masked.all(axis=(1, 2))] = FLAG_MASKED
    if not _USE_NUMBA:  # the compiled kernel makes these checks stamp by stamp
        finite = np.isfinite(cube).all(axis=(1, 2))
        flag[~finite & (flag == 0)] |= FLAG_BAD_PIXELS
        nonzero = np.zeros(n, dtype=bool)
        nonzero[finite] = (cube[finite] != 0).any(axis=(1, 2))
        flag[finite & ~nonzero & (flag == 0)] |= FLAG_NO_FLUX

    # Pixels whose weight is below precision / 10 are ignored (as HSM does).
    max_rho2 = -2.0 * np.log(precision / 10.0)

    state = dict(x0=x0, y0=y0, mxx=mxx, mxy=mxy, myy=myy, amp=amp, n_iter=n_iter, flag=flag)
    todo = np.flatnonzero(flag == 0)
    if _USE_NUMBA and todo.size:
        _iterate_numba(cube, todo, state, max_rho2, precision, max_iter, max_moment, max_shift)
        todo = todo[:0]
    # Chunks keep the temporaries in cache: much faster than one pass over a large batch.
    chunk = max(1, _CHUNK_PIXELS // (s * s))
    for start in range(0, todo.size, chunk):
        idx = todo[start:start + chunk]
        sub = {key: val[idx] for key, val in state.items()}
        with np.errstate(all="ignore"):  # failures are detected and flagged explicitly
            _iterate(cube[idx], np.arange(idx.size), sub, x00[idx], y00[idx], max_rho2,
                     precision, max_iter, max_moment, max_shift)
        for key, val in sub.items():
            state[key][idx] = val
    if masked is not None:  # converged stamps with masked pixels: how much of the star is left
        idx = np.flatnonzero((flag == 0) & masked.any(axis=(1, 2)))
        fraction = (_masked_fraction_numba if _USE_NUMBA else _masked_core_fraction)(
            masked, idx, x0, y0, mxx, mxy, myy, max_rho2)
        flag[idx[~(fraction <= max_masked_fraction)]] |= FLAG_MASKED

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


def _iterate(cube, active, state, x00, y00, max_rho2, precision, max_iter, max_moment, max_shift):
    """Run the adaptive-moment iteration on stamps ``cube[active]``, updating ``state`` in place.

    Each step crops all active stamps to the smallest common window holding the ellipse
    ``rho^2 <= max_rho2`` of every stamp (pixels outside it have weight < precision / 10),
    computes the weighted moments with batched matrix products, and applies HSM's bounded
    update. ``cube`` is compacted to the active stamps as they converge.
    """
    s = cube.shape[1]
    x0, y0 = state["x0"], state["y0"]
    mxx, mxy, myy = state["mxx"], state["mxy"], state["myy"]
    amp, n_iter, flag = state["amp"], state["n_iter"], state["flag"]
    shiftscale0 = np.full(active.size, np.nan)
    local = np.arange(active.size)  # position of each active stamp in shiftscale0
    coords = np.arange(s, dtype=np.float64)
    while active.size:
        ax0, ay0 = x0[active], y0[active]
        axx, axy, ayy = mxx[active], mxy[active], myy[active]
        det = axx * ayy - axy * axy
        bad = ~((det > 0) & (axx > 0) & (ayy > 0))
        with np.errstate(divide="ignore", invalid="ignore"):
            ixx, ixy, iyy = ayy / det, -axy / det, axx / det
            # rho^2 <= max_rho2 implies |x - x0| <= sqrt(max_rho2 * Mxx) (same for y).
            wx = np.sqrt(max_rho2 * np.where(bad, 0.0, axx))
            wy = np.sqrt(max_rho2 * np.where(bad, 0.0, ayy))
            xlo = int(np.clip(np.floor(np.nanmin(ax0 - wx)), 0, s - 1)) if not bad.all() else 0
            xhi = int(np.clip(np.ceil(np.nanmax(ax0 + wx)), 0, s - 1)) if not bad.all() else 0
            ylo = int(np.clip(np.floor(np.nanmin(ay0 - wy)), 0, s - 1)) if not bad.all() else 0
            yhi = int(np.clip(np.ceil(np.nanmax(ay0 + wy)), 0, s - 1)) if not bad.all() else 0
        img = cube[:, ylo:yhi + 1, xlo:xhi + 1]  # cube holds the active stamps only
        dx = coords[None, xlo:xhi + 1] - ax0[:, None]  # (m, wx) along columns
        dy = coords[None, ylo:yhi + 1] - ay0[:, None]  # (m, wy) along rows
        # -rho^2/2 as a batched product: [1, qy_i, cy_i] . [qx_j, 1, dx_j] with
        # qx = -Minv_xx dx^2 / 2, qy = -Minv_yy dy^2 / 2, cy = -Minv_xy dy.
        left = np.stack([np.ones_like(dy), -0.5 * iyy[:, None] * dy * dy,
                         -ixy[:, None] * dy], axis=2)
        right = np.stack([-0.5 * ixx[:, None] * dx * dx, np.ones_like(dx), dx], axis=1)
        wimg = np.matmul(left, right)  # (m, rows, cols): -rho^2 / 2
        np.exp(wimg, out=wimg)
        np.multiply(wimg, img, out=wimg)  # weighted intensity
        # Per row: sums of I, I c, I c^2 (c = column index) in one matrix product for all
        # stamps, then shifted to dx = c - x0 per stamp.
        m, nrow, ncol = wimg.shape
        col = coords[xlo:xhi + 1]
        powers = np.stack([np.ones_like(col), col, col * col], axis=1)  # (cols, 3)
        per_row = (wimg.reshape(m * nrow, ncol) @ powers).reshape(m, nrow, 3)
        r0 = per_row[:, :, 0]
        r1 = per_row[:, :, 1] - ax0[:, None] * r0  # sum_j I dx
        r2 = per_row[:, :, 2] - 2.0 * ax0[:, None] * per_row[:, :, 1] + (ax0**2)[:, None] * r0
        a = r0.sum(axis=1)
        bx = r1.sum(axis=1)
        cxx = r2.sum(axis=1)
        by = np.einsum("mi,mi->m", r0, dy)
        cyy = np.einsum("mi,mi->m", r0, dy * dy)
        cxy = np.einsum("mi,mi->m", r1, dy)

        half_trace = 0.5 * (axx + ayy)
        semi_b2 = half_trace - np.sqrt((0.5 * (axx - ayy)) ** 2 + axy * axy)
        no_flux = ~(a > 0) & ~bad
        bad |= ~(semi_b2 > 0)
        bc = _BOUND_CORRECT
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            shiftscale = np.sqrt(semi_b2)
            ddx = np.clip(2.0 * bx / (a * shiftscale), -bc, bc)
            ddy = np.clip(2.0 * by / (a * shiftscale), -bc, bc)
            dxx = np.clip(4.0 * (cxx / a - 0.5 * axx) / semi_b2, -bc, bc)
            dxy = np.clip(4.0 * (cxy / a - 0.5 * axy) / semi_b2, -bc, bc)
            dyy = np.clip(4.0 * (cyy / a - 0.5 * ayy) / semi_b2, -bc, bc)
            conv = np.maximum.reduce([np.abs(ddx), np.abs(ddy), np.abs(dxx), np.abs(dxy),
                                      np.abs(dyy)])
            first = n_iter[active] == 0
            shift0 = np.where(first, shiftscale, shiftscale0[local])
            shiftscale0[local] = shift0
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
        if not keep.all():
            active = active[keep]
            local = local[keep]
            cube = cube[keep]


def fixed_moments(stamps, sigma: float = 1.5, *, weights=None, centroid=None,
                  n_iter: int = 20, tol: float = 1e-6) -> Table:
    """Moments with a fixed, round Gaussian weight: defined for undersampled stamps.

    Adaptive moments (:func:`adaptive_moments`, GalSim's HSM) fail on stamps of a PSF
    sampled at under about two pixels per FWHM ("object is too small": the adaptive weight
    shrinks below a pixel). Here the weight is ``exp(-r^2 / (2 sigma^2))``, of a ``sigma``
    the caller states and which never changes, centred at ``centroid`` or, by default, at
    the point where the weighted first moments vanish (iterated from the stamp centre, at
    most ``n_iter`` times, until the centre moves by less than ``tol`` pixels). The second
    moments are the weighted ones, ``M_ij = sum w I (x_i - x0)(x_j - y0) / sum w I``, and
    ``e1, e2 = (Mxx - Myy, 2 Mxy) / (Mxx + Myy)``: those of the star seen through the
    weight, rounder and smaller than the star itself (for a Gaussian star of covariance C,
    ``M = (C^-1 + I / sigma^2)^-1``), so compare stars and models measured with the same
    ``sigma`` and centre (e.g. a PSF model drawn at the star's sub-pixel phase, see
    :meth:`~sklearn_psf.model.PSFModel.predict`). Pixels are taken as points at their
    centres, as in :func:`adaptive_moments`.

    Parameters
    ----------
    stamps : array-like of shape (n, s, s) or (n, s*s)
        Square, background-subtracted stamps. Not modified. NaN pixels are masked.
    sigma : float, default=1.5
        Width of the weight in pixels.
    weights : array-like of the stamps' shape, optional
        Inverse variance per pixel, 0 = masked; only the mask is used (as in
        :func:`adaptive_moments`).
    centroid : array-like of shape (2,) or (n, 2), optional
        Fixed centre (x0, y0) of the weight in stamp pixel coordinates (0-based, x = column);
        default: iterated as above.
    n_iter : int, default=20
        Largest number of centroid iterations.
    tol : float, default=1e-6
        Convergence of the centroid (pixels).

    Returns
    -------
    table : astropy.table.Table
        Columns ``e1``, ``e2``, ``sigma`` (``det(M)^(1/4)``, pixels), ``x0``, ``y0``,
        ``Mxx``, ``Mxy``, ``Myy``, ``n_iter`` and ``flag`` (``FLAG_OK``; ``FLAG_NO_FLUX``
        when the weighted flux is not positive or M not positive definite;
        ``FLAG_DIVERGED`` when the centre leaves the stamp; ``FLAG_MAX_ITER``;
        ``FLAG_MASKED`` when every pixel is masked; ``FLAG_BAD_PIXELS`` for infinite
        pixels). Flagged rows hold NaN.

    Raises
    ------
    ValueError
        For a ``sigma`` that is not positive and finite, or stamps that are not square.

    Examples
    --------
    A Gaussian star of sigma 0.6 px (FWHM 1.4 px) at a sub-pixel position, where adaptive
    moments fail:

    >>> import numpy as np
    >>> from sklearn_psf.measure import adaptive_moments, fixed_moments
    >>> y, x = np.mgrid[0:15, 0:15] - 7.0
    >>> star = np.exp(-0.5 * ((x - 0.3) ** 2 + (y + 0.2) ** 2) / 0.6**2)
    >>> int(adaptive_moments(star[None])["flag"][0]) != 0
    True
    >>> t = fixed_moments(star[None], sigma=1.5)
    >>> print(t["flag"][0], round(float(t["x0"][0]), 2), round(float(t["y0"][0]), 2))
    0 7.3 6.8
    """
    cube = as_stamps(stamps)
    n, s, _ = cube.shape
    sigma = _check_positive("sigma", sigma)
    if int(n_iter) != n_iter or n_iter < 1:
        raise ValueError(f"n_iter must be a positive integer, got {n_iter!r}.")
    cube, masked = _masked_pixels(cube, weights)
    flag = np.zeros(n, dtype=np.int64)
    if masked is not None:
        flag[masked.all(axis=(1, 2))] = FLAG_MASKED
        cube = np.where(masked, 0.0, cube)
    finite = np.isfinite(cube).all(axis=(1, 2))
    flag[~finite & (flag == 0)] |= FLAG_BAD_PIXELS
    cube = np.where(finite[:, None, None], cube, 0.0)
    coords = np.arange(s, dtype=np.float64)
    if centroid is None:
        x0 = np.full(n, (s - 1) / 2.0)
        y0 = x0.copy()
        steps = int(n_iter)
    else:
        c = np.broadcast_to(np.asarray(centroid, dtype=np.float64), (n, 2))
        x0, y0 = c[:, 0].copy(), c[:, 1].copy()
        steps = 0
    count = np.zeros(n, dtype=np.int64)
    active = np.ones(n, dtype=bool)

    def weighted(x0, y0):
        gx = np.exp(-0.5 * (coords[None, :] - x0[:, None]) ** 2 / sigma**2)
        gy = np.exp(-0.5 * (coords[None, :] - y0[:, None]) ** 2 / sigma**2)
        return cube * gy[:, :, None] * gx[:, None, :]

    with np.errstate(divide="ignore", invalid="ignore"):
        for _ in range(steps):
            wi = weighted(x0, y0)
            a = wi.sum(axis=(1, 2))
            nx = (wi.sum(axis=1) @ coords) / a
            ny = (wi.sum(axis=2) @ coords) / a
            move = np.hypot(nx - x0, ny - y0)
            upd = active & np.isfinite(move)
            count[upd] += 1
            x0, y0 = np.where(upd, nx, x0), np.where(upd, ny, y0)
            active &= np.isfinite(move) & (move > tol)
            if not active.any():
                break
        flag[active & (count >= steps) & (steps > 0)] |= FLAG_MAX_ITER
        wi = weighted(x0, y0)
        a = wi.sum(axis=(1, 2))
        dx = coords[None, None, :] - x0[:, None, None]
        dy = coords[None, :, None] - y0[:, None, None]
        mxx = (wi * dx * dx).sum(axis=(1, 2)) / a
        myy = (wi * dy * dy).sum(axis=(1, 2)) / a
        mxy = (wi * dx * dy).sum(axis=(1, 2)) / a
        det = mxx * myy - mxy**2
    outside = ~((x0 >= -0.5) & (x0 <= s - 0.5) & (y0 >= -0.5) & (y0 <= s - 0.5))
    flag[(flag == 0) & outside] |= FLAG_DIVERGED
    flag[(flag == 0) & ~((a > 0) & (det > 0) & (mxx > 0))] |= FLAG_NO_FLUX
    good = flag == 0
    with np.errstate(divide="ignore", invalid="ignore"):
        columns = {"e1": (mxx - myy) / (mxx + myy), "e2": 2.0 * mxy / (mxx + myy),
                   "sigma": np.abs(det) ** 0.25, "x0": x0, "y0": y0, "Mxx": mxx, "Mxy": mxy,
                   "Myy": myy}
    table = Table()
    for name, values in columns.items():
        table[name] = np.where(good, values, np.nan)
    table["n_iter"] = count
    table["flag"] = flag
    return table
