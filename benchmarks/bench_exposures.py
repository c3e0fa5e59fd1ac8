"""Benchmark: the multi-exposure study (run_exposure_study) at its default size.

Target: the default study (N = 1, 2, 5, 10, 20 exposures; 120 and 240 stars per exposure;
6 simulations of 10 x 10 arcmin chips) in under 15 minutes on a 2-core machine
(``n_jobs=2``, BLAS pinned to one thread per worker). There is no peer library running this
study: the script prints our time against the target, the pooled / per-exposure gain at the
largest N, the verdict against Stage IV, and writes the figure and report section to
``--out``.

Usage::

    python benchmarks/bench_exposures.py [--quick] [--n-jobs 2] [--out DIR]
"""

from __future__ import annotations

import argparse
import tempfile
import time

import numpy as np
from threadpoolctl import threadpool_limits

from sklearn_psf.study.exposures import (
    cheapest_configuration,
    run_exposure_study,
    write_exposure_report,
)

TARGET_SECONDS = 15 * 60
QUICK = dict(n_exposures=(1, 2, 5), n_stars=(40,), n_simulations=2, n_galaxies=150,
             image_shape=(1200, 1200), dither=80.0, theta_bins=(0.3, 3.0, 5))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="tiny size (smoke run)")
    parser.add_argument("--n-jobs", type=int, default=2)
    parser.add_argument("--out", default=None, help="directory of the figure and report")
    args = parser.parse_args(argv)
    kwargs = QUICK if args.quick else {}
    with threadpool_limits(1):
        start = time.perf_counter()
        result = run_exposure_study(n_jobs=args.n_jobs, **kwargs)
        seconds = time.perf_counter() - start
    s = result.scores
    cfg = result.config
    print(f"multi-exposure study: {cfg['n_simulations']} simulations x n_stars "
          f"{cfg['n_stars']} x N {cfg['n_exposures']}, n_jobs={args.n_jobs}: {seconds:.1f} s")
    if not args.quick:
        print(f"target < {TARGET_SECONDS} s: {'met' if seconds < TARGET_SECONDS else 'NOT met'}")
    n_max = max(cfg["n_exposures"])
    for m in cfg["n_stars"]:
        sel = (s["n_stars"] == m) & (s["n_exposures"] == n_max)
        pooled = s[sel & (s["scheme"] == "pooled")]
        per = s[sel & (s["scheme"] == "per-exposure")]
        pooled.sort("simulation")
        per.sort("simulation")
        ratio = np.asarray(pooled["sigma_sys2"]) / np.asarray(per["sigma_sys2"])
        print(f"{m} stars/exposure, N = {n_max}: sigma_sys^2 median pooled "
              f"{np.median(pooled['sigma_sys2']):.2e}, per-exposure "
              f"{np.median(per['sigma_sys2']):.2e}; pooled lower in "
              f"{np.sum(ratio < 1)}/{len(ratio)} simulations (median ratio {np.median(ratio):.2f})")
        for scheme in ("per-exposure", "pooled"):
            meds = [np.median(s["sigma_sys2"][(s["n_stars"] == m) & (s["scheme"] == scheme)
                                              & (s["n_exposures"] == n)])
                    for n in cfg["n_exposures"]]
            print(f"  {scheme:>12}: " + ", ".join(f"N={n}: {v:.2e}"
                                                  for n, v in zip(cfg["n_exposures"], meds)))
    verdict = cheapest_configuration(result)
    if verdict["met"]:
        print(f"cheapest configuration meeting Stage IV: {verdict['best']}")
    else:
        for f in verdict["shortfalls"]:
            print(f"Stage IV not met: {f['scheme']}, {f['n_stars']} stars, N = {f['n_exposures']}:"
                  f" {f['sigma_sys2_median']:.2e} ({f['factor']:.2f}x), power-law N needed "
                  f"{f['n_needed']:.0f}")
    out = args.out or tempfile.mkdtemp(prefix="bench_exposures_")
    print(f"report: {write_exposure_report(result, out)}")


if __name__ == "__main__":
    main()
