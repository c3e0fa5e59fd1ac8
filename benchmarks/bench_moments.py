"""Benchmark: batched adaptive moments (sklearn_psf) vs GalSim HSM called stamp by stamp.

Usage::

    python benchmarks/bench_moments.py            # 10,000 stamps of 32x32
    python benchmarks/bench_moments.py --quick    # 200 stamps (smoke test)

Two cases: plain stamps, and the same stamps with masked pixels (2% at random and a bad
column 2-5 px from the star, holding garbage values), measured with ``weights`` (0 = masked)
against ``FindAdaptiveMom(..., badpix=mask)``. Prints both times and the ratio for each; exits
with status 1 if e1, e2 (or sigma, centroid) differ by more than 1e-4 on any stamp, or if the
two disagree on which stamps failed.
"""

from __future__ import annotations

import argparse
import sys
import time

import galsim
import numpy as np
from threadpoolctl import threadpool_limits

from sklearn_psf.measure import adaptive_moments


def make_stamps(n, size, seed):
    """Sheared Gaussian, Moffat and Kolmogorov profiles with random offsets and mild noise."""
    rng = np.random.default_rng(seed)
    stamps = np.empty((n, size, size))
    kinds = rng.integers(0, 3, n)
    fwhm = rng.uniform(2.5, 4.5, n)
    g = rng.uniform(-0.1, 0.1, (n, 2))
    off = rng.uniform(-0.5, 0.5, (n, 2))
    for i in range(n):
        if kinds[i] == 0:
            prof = galsim.Gaussian(fwhm=fwhm[i])
        elif kinds[i] == 1:
            prof = galsim.Moffat(beta=3.0, fwhm=fwhm[i])
        else:
            prof = galsim.Kolmogorov(fwhm=fwhm[i])
        prof = prof.shear(g1=g[i, 0], g2=g[i, 1]).shift(*off[i])
        stamps[i] = prof.drawImage(nx=size, ny=size, scale=1.0).array
    stamps += rng.normal(0.0, 1e-4, stamps.shape)  # S/N of a few hundred
    return stamps


def make_masks(n, size, seed):
    """2% of the pixels at random and one bad column 2-5 px from the stamp centre."""
    rng = np.random.default_rng(seed)
    masks = rng.random((n, size, size)) < 0.02
    cols = size // 2 + rng.integers(2, 6, n) * rng.choice([-1, 1], n)
    masks[np.arange(n), :, cols] = True
    return masks


def run_galsim(stamps, masks=None):
    out = np.full((len(stamps), 5), np.nan)
    for i, st in enumerate(stamps):
        badpix = None if masks is None else galsim.ImageI(masks[i].astype(np.int32))
        res = galsim.hsm.FindAdaptiveMom(galsim.Image(st, scale=1.0), badpix=badpix,
                                         strict=False)
        if not res.error_message:
            out[i] = (
                res.observed_shape.e1,
                res.observed_shape.e2,
                res.moments_sigma,
                res.moments_centroid.x - 1.0,  # galsim.Image bounds start at 1
                res.moments_centroid.y - 1.0,
            )
    return out


def compare(label, n, ours_fn, galsim_fn, repeat):
    """Time both (best of ``repeat``), print the ratio and the largest differences."""
    t_ours, t_gs = [], []
    for _ in range(repeat):
        t0 = time.perf_counter()
        table = ours_fn()
        t_ours.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        ref = galsim_fn()
        t_gs.append(time.perf_counter() - t0)
    ours = np.column_stack([table[c] for c in ("e1", "e2", "sigma", "x0", "y0")])
    t_ours, t_gs = min(t_ours), min(t_gs)
    print(f"[{label}]")
    print(f"sklearn_psf adaptive_moments : {t_ours:8.3f} s  ({1e6 * t_ours / n:7.1f} us/stamp)")
    print(f"GalSim FindAdaptiveMom loop  : {t_gs:8.3f} s  ({1e6 * t_gs / n:7.1f} us/stamp)")
    print(f"speed-up                     : {t_gs / t_ours:8.2f} x")

    ok_ours = np.asarray(table["flag"]) == 0
    ok_ref = np.all(np.isfinite(ref), axis=1)
    status = 0
    if not np.array_equal(ok_ours, ok_ref):
        print(f"FAIL: failures differ on {np.sum(ok_ours != ok_ref)} stamps")
        status = 1
    both = ok_ours & ok_ref
    diff = np.abs(ours[both] - ref[both]).max(axis=0) if both.any() else np.zeros(5)
    print("max |difference| e1, e2, sigma, x0, y0: " + ", ".join(f"{d:.2e}" for d in diff))
    if np.any(diff > 1e-4):
        print("FAIL: results differ from GalSim by more than 1e-4")
        status = 1
    else:
        print("agreement with GalSim within 1e-4: OK")
    return status


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="200 stamps instead of 10,000")
    parser.add_argument("--n", type=int, default=None, help="number of stamps")
    parser.add_argument("--size", type=int, default=32, help="stamp side in pixels")
    parser.add_argument("--threads", type=int, default=1, help="BLAS threads for both sides")
    parser.add_argument("--repeat", type=int, default=3, help="best of this many runs")
    args = parser.parse_args(argv)
    n = args.n or (200 if args.quick else 10_000)

    stamps = make_stamps(n, args.size, seed=12345)
    masks = make_masks(n, args.size, seed=54321)
    weights = np.where(masks, 0.0, 1e8)  # inverse variance of the 1e-4 noise; 0 = masked
    garbage = np.where(masks, np.random.default_rng(0).choice([np.nan, 1e30], stamps.shape),
                       stamps)
    zeroed = np.where(masks, 0.0, stamps)  # HSM multiplies the image by the mask: no NaN
    print(f"{n} stamps of {args.size}x{args.size}, {args.threads} BLAS thread(s), best of "
          f"{args.repeat}")
    adaptive_moments(stamps[:2], weights=weights[:2])  # compile the kernels before timing
    with threadpool_limits(args.threads):
        status = compare("unmasked", n, lambda: adaptive_moments(stamps),
                         lambda: run_galsim(stamps), args.repeat)
        status |= compare("masked pixels: weights=w vs badpix=mask", n,
                          lambda: adaptive_moments(garbage, weights=weights),
                          lambda: run_galsim(zeroed, masks), args.repeat)
    return status


if __name__ == "__main__":
    sys.exit(main())
