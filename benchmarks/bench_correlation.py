"""Benchmark: sklearn_psf.metrics.ellipticity_correlation vs a direct TreeCorr call.

Usage::

    python benchmarks/bench_correlation.py            # 10^6 points, 20 bins
    python benchmarks/bench_correlation.py --quick    # 2 x 10^4 points (smoke test)

Both sides use the same points, binning, bin_slop and number of OpenMP threads, in the same
run; BLAS is pinned to one thread. Prints the times and their ratio, and exits non-zero if the
results differ.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np
import treecorr
from threadpoolctl import threadpool_limits

from sklearn_psf.metrics import ellipticity_correlation


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small smoke-test size")
    parser.add_argument("--n", type=int, default=None, help="number of points")
    parser.add_argument("--nbins", type=int, default=20)
    parser.add_argument("--threads", type=int, default=os.cpu_count())
    parser.add_argument("--repeat", type=int, default=1)
    args = parser.parse_args(argv)
    n = args.n or (20_000 if args.quick else 1_000_000)

    # A 33' x 26' field (the paper's Subaru image) in arcmin, with a smooth PSF pattern + noise.
    rng = np.random.default_rng(0)
    X = rng.uniform((0.0, 0.0), (33.0, 26.0), size=(n, 2))
    e1 = 0.02 * np.sin(X[:, 0] / 5.0) + 0.01 * rng.standard_normal(n)
    e2 = 0.02 * np.cos(X[:, 1] / 4.0) + 0.01 * rng.standard_normal(n)
    settings = dict(min_sep=0.1, max_sep=20.0, nbins=args.nbins)

    def ours():
        return ellipticity_correlation(X, e1, e2, num_threads=args.threads, **settings)

    def direct():
        cat = treecorr.Catalog(x=X[:, 0], y=X[:, 1], g1=e1, g2=e2)
        gg = treecorr.GGCorrelation(**settings)
        gg.process(cat, num_threads=args.threads)
        return gg

    with threadpool_limits(1):
        # warm-up on a small subset (imports, OpenMP pool)
        ellipticity_correlation(X[:2000], e1[:2000], e2[:2000], num_threads=args.threads,
                                **settings)
        t_ours, t_direct = [], []
        for _ in range(args.repeat):  # alternate to share any drift in machine load
            t0 = time.perf_counter()
            res = ours()
            t_ours.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            gg = direct()
            t_direct.append(time.perf_counter() - t0)

    a, b = min(t_ours), min(t_direct)
    print(f"points={n} bins={args.nbins} threads={args.threads} "
          f"(treecorr {treecorr.__version__})")
    print(f"ellipticity_correlation: {a:8.2f} s")
    print(f"direct TreeCorr        : {b:8.2f} s")
    print(f"ratio ours / TreeCorr  : {a / b:8.3f}")
    ok = (np.array_equal(res.npairs, gg.npairs)
          and np.allclose(res.xi, gg.xip, rtol=1e-10, atol=0)
          and np.allclose(res.sigma_xi, np.sqrt(gg.varxip), rtol=1e-10)
          and np.allclose(res.theta, gg.meanr, rtol=1e-10))
    print("results identical:", ok)
    print("xi(theta) first/last bin:", res.xi[0], res.xi[-1])
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
