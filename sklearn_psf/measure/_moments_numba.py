"""Compiled (numba) adaptive-moment iteration, one stamp at a time (private).

The same iteration as the numpy path of :mod:`._moments` (GalSim HSM's ``find_ellipmom_2``
update rule, step bounds and convergence test) on the same region: the smallest box holding
the ellipse ``rho^2 <= max_rho2`` (box corners have weight below ``precision / 10``). The
Gaussian weight is not evaluated with one ``exp`` per pixel: ``-rho^2/2`` is a quadratic in
the column and row indices, so consecutive weights along a row follow ``w_{j+1} = w_j r_j``,
``r_{j+1} = r_j q`` (two interleaved chains, even and odd columns), and the first weight and
ratio of each row follow the same kind of recurrence down the rows: five ``exp`` per
iteration in all. The relative rounding over a 32-pixel stamp is ~1e-14.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

_BOUND_CORRECT = 0.25
FLAG_BAD_PIXELS = 1
FLAG_NO_FLUX = 2
FLAG_DIVERGED = 4
FLAG_MAX_ITER = 8


def _clip(v, bc):
    return min(max(v, -bc), bc)


_clip = njit(cache=True, inline="always")(_clip)


# reassociation only: NaN/inf checks must stay exact (no 'nnan'/'ninf')
@njit(cache=True, nogil=True, fastmath={"reassoc", "contract"})
def _moments_loop(cube, todo, x0, y0, mxx, mxy, myy, amp, n_iter, flag, max_rho2,
                  precision, max_iter, max_moment, max_shift):  # pragma: no cover - compiled
    s = cube.shape[1]
    bc = _BOUND_CORRECT
    for t in range(todo.shape[0]):
        n = todo[t]
        img = cube[n]
        # the numpy path's input checks, stamp by stamp: NaN/inf pixels, no flux at all
        finite = True
        nonzero = False
        for i in range(s):
            for j in range(s):
                v = img[i, j]
                if not math.isfinite(v):
                    finite = False
                elif v != 0.0:
                    nonzero = True
        if not finite:
            flag[n] |= FLAG_BAD_PIXELS
            continue
        if not nonzero:
            flag[n] |= FLAG_NO_FLUX
            continue
        ax0, ay0 = x0[n], y0[n]
        x00, y00 = ax0, ay0
        axx, axy, ayy = mxx[n], mxy[n], myy[n]
        shift0 = 0.0
        it = 0
        while True:
            det = axx * ayy - axy * axy
            bad = not (det > 0.0 and axx > 0.0 and ayy > 0.0)
            a = 0.0
            bx = 0.0
            by = 0.0
            cxx = 0.0
            cxy = 0.0
            cyy = 0.0
            if not bad:
                ixx = ayy / det
                ixy = -axy / det
                iyy = axx / det
                half_h = math.sqrt(max_rho2 * ayy)
                half_w = math.sqrt(max_rho2 * axx)
                ylo = max(0, int(math.ceil(ay0 - half_h)))
                yhi = min(s - 1, int(math.floor(ay0 + half_h)))
                xlo = max(0, int(math.ceil(ax0 - half_w)))
                xhi = min(s - 1, int(math.floor(ax0 + half_w)))
                q1 = math.exp(-ixx)
                q2 = q1 * q1
                q4 = q2 * q2
                # Along rows: w(dx + 1) = w(dx) step, step(dx + 1) = step(dx) q1. Down the
                # first column: e0(dy + 1) - e0(dy) = -iyy (dy + 1/2) - ixy dx0 (a ratio g
                # with g(dy + 1) = g(dy) exp(-iyy)), and step(dy + 1) = step(dy) exp(-ixy):
                # five exp per iteration, none per row or pixel.
                dx0 = xlo - ax0
                dy = ylo - ay0
                wrow = math.exp(-0.5 * (ixx * dx0 * dx0 + 2.0 * ixy * dx0 * dy
                                        + iyy * dy * dy))
                g = math.exp(-iyy * (dy + 0.5) - ixy * dx0)
                gq = math.exp(-iyy)
                step = math.exp(-0.5 * ixx * (2.0 * dx0 + 1.0) - ixy * dy)
                sq = math.exp(-ixy)
                for i in range(ylo, yhi + 1):
                    dy = i - ay0
                    dx = dx0
                    w0 = wrow
                    w1 = w0 * step
                    r0 = step * step * q1
                    r1 = r0 * q2
                    wrow *= g
                    g *= gq
                    step *= sq
                    ra = 0.0
                    rx = 0.0
                    rxx = 0.0
                    ra1 = 0.0
                    rx1 = 0.0
                    rxx1 = 0.0
                    j = xlo
                    while j < xhi:
                        v0 = w0 * img[i, j]
                        v1 = w1 * img[i, j + 1]
                        ra += v0
                        rx += v0 * dx
                        rxx += v0 * dx * dx
                        d1 = dx + 1.0
                        ra1 += v1
                        rx1 += v1 * d1
                        rxx1 += v1 * d1 * d1
                        w0 *= r0
                        w1 *= r1
                        r0 *= q4
                        r1 *= q4
                        dx += 2.0
                        j += 2
                    if j == xhi:
                        v0 = w0 * img[i, j]
                        ra += v0
                        rx += v0 * dx
                        rxx += v0 * dx * dx
                    ra += ra1
                    rx += rx1
                    rxx += rxx1
                    a += ra
                    bx += rx
                    cxx += rxx
                    by += ra * dy
                    cxy += rx * dy
                    cyy += ra * dy * dy
            half_trace = 0.5 * (axx + ayy)
            semi_b2 = half_trace - math.sqrt((0.5 * (axx - ayy)) ** 2 + axy * axy)
            bad = bad or not (semi_b2 > 0.0)
            shiftscale = math.sqrt(semi_b2) if semi_b2 > 0.0 else math.nan
            no_flux = (not (a * shiftscale > 0.0)) and not bad  # also a flux that underflows
            if bad or no_flux:
                conv = math.nan
                nx0 = ny0 = nxx = nxy = nyy = math.nan
            else:
                ddx = _clip(2.0 * bx / (a * shiftscale), bc)
                ddy = _clip(2.0 * by / (a * shiftscale), bc)
                dxx = _clip(4.0 * (cxx / a - 0.5 * axx) / semi_b2, bc)
                dxy = _clip(4.0 * (cxy / a - 0.5 * axy) / semi_b2, bc)
                dyy = _clip(4.0 * (cyy / a - 0.5 * ayy) / semi_b2, bc)
                conv = max(abs(ddx), abs(ddy), abs(dxx), abs(dxy), abs(dyy))
                if it == 0:
                    shift0 = shiftscale
                if shiftscale < shift0:
                    conv = conv * shift0 / shiftscale
                nx0 = ax0 + ddx * shiftscale
                ny0 = ay0 + ddy * shiftscale
                nxx = axx + dxx * semi_b2
                nxy = axy + dxy * semi_b2
                nyy = ayy + dyy * semi_b2
            it += 1
            ax0, ay0, axx, axy, ayy = nx0, ny0, nxx, nxy, nyy
            amp[n] = a
            diverged = (
                bad
                or abs(nxx) > max_moment
                or abs(nxy) > max_moment
                or abs(nyy) > max_moment
                or abs(nx0 - x00) > max_shift
                or abs(ny0 - y00) > max_shift
                or not math.isfinite(conv)
                or not math.isfinite(nxx + nxy + nyy + nx0 + ny0)
            )
            if no_flux:
                flag[n] |= FLAG_NO_FLUX
                break
            if diverged:
                flag[n] |= FLAG_DIVERGED
                break
            if it > max_iter:
                flag[n] |= FLAG_MAX_ITER
                break
            if not conv > precision:
                break
        x0[n], y0[n], mxx[n], mxy[n], myy[n] = ax0, ay0, axx, axy, ayy
        n_iter[n] = it


def iterate_numba(cube, todo, state, max_rho2, precision, max_iter, max_moment, max_shift):
    """Run the compiled iteration on ``cube[todo]``, updating ``state`` arrays in place."""
    _moments_loop(
        np.ascontiguousarray(cube, dtype=np.float64), np.ascontiguousarray(todo, np.int64),
        state["x0"], state["y0"], state["mxx"], state["mxy"], state["myy"], state["amp"],
        state["n_iter"], state["flag"], float(max_rho2), float(precision), int(max_iter),
        float(max_moment), float(max_shift),
    )


@njit(cache=True, nogil=True)
def _masked_fraction_loop(masked, idx, x0, y0, mxx, mxy, myy, max_rho2, out):  # pragma: no cover
    s = masked.shape[1]
    for t in range(idx.shape[0]):
        n = idx[t]
        det = mxx[n] * myy[n] - mxy[n] * mxy[n]
        if not det > 0.0:
            out[t] = math.nan
            continue
        ixx, ixy, iyy = myy[n] / det, -mxy[n] / det, mxx[n] / det
        half_h = 0.5 * math.sqrt(max_rho2 * myy[n])  # 4 rho^2 < max_rho2
        half_w = 0.5 * math.sqrt(max_rho2 * mxx[n])
        total = 0.0
        lost = 0.0
        for i in range(max(0, int(math.ceil(y0[n] - half_h))),
                       min(s - 1, int(math.floor(y0[n] + half_h))) + 1):
            dy = i - y0[n]
            for j in range(max(0, int(math.ceil(x0[n] - half_w))),
                           min(s - 1, int(math.floor(x0[n] + half_w))) + 1):
                dx = j - x0[n]
                rho2 = 4.0 * (ixx * dx * dx + 2.0 * ixy * dx * dy + iyy * dy * dy)
                if rho2 < max_rho2:
                    w = math.exp(-0.5 * rho2)
                    total += w
                    if masked[n, i, j]:
                        lost += w
        out[t] = lost / total if total > 0.0 else math.nan


def masked_core_fraction_numba(masked, idx, x0, y0, mxx, mxy, myy, max_rho2):
    """Fraction of the core weight ``exp(-2 rho^2)`` (where ``4 rho^2 < max_rho2``) on masked
    pixels, for stamps ``idx`` (as ``_moments._masked_core_fraction``)."""
    out = np.empty(idx.shape[0])
    _masked_fraction_loop(masked, np.ascontiguousarray(idx, np.int64), x0, y0, mxx, mxy, myy,
                          float(max_rho2), out)
    return out


@njit(cache=True, nogil=True)
def _mask_loop(cube, weights, clean, masked):  # pragma: no cover - compiled
    n_masked = 0
    valid = True
    for k in range(cube.shape[0]):
        for i in range(cube.shape[1]):
            for j in range(cube.shape[2]):  # branch-free: vectorised by the compiler
                v = cube[k, i, j]
                w = weights[k, i, j]
                valid &= (w >= 0.0) & (w < math.inf)  # False for NaN
                m = (w == 0.0) | (v != v)
                masked[k, i, j] = m
                clean[k, i, j] = 0.0 if m else v
                n_masked += m
    return n_masked if valid else -1


def mask_pixels_numba(cube, weights):
    """As ``_moments._masked_pixels`` with weights, in one pass: ``(clean, masked)``, ``(cube,
    None)`` when no pixel is masked, ``None`` when a weight is negative or not finite."""
    cube = np.ascontiguousarray(cube, dtype=np.float64)
    clean = np.empty_like(cube)
    masked = np.empty(cube.shape, dtype=np.bool_)
    n_masked = _mask_loop(cube, np.ascontiguousarray(weights, dtype=np.float64), clean, masked)
    if n_masked < 0:
        return None
    return (clean, masked) if n_masked else (cube, None)
