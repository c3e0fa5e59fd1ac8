"""Benchmark: the paper's comparison study (run_study) serial, n_jobs=2 and on Dask.

Times ``sklearn_psf.study.compare.run_study`` (every default scheme on the paper's configuration:
1000 stars, 2000 galaxy-PSFs, 10,032 x 7,769 pixels) for a few simulations with

- ``n_jobs=1``,
- ``n_jobs=2`` (joblib processes),
- a Dask ``LocalCluster(n_workers=2, threads_per_worker=1)`` through
  ``joblib.parallel_backend("dask")``,

checks that the three result tables are identical (every column but ``fit_seconds``, which
is a timing), and extrapolates the paper's full study (50 simulations) from the per-
simulation time: an extrapolation, not a run of the 50 simulations (pass ``--n-sims 50`` to
run it). ``--cli-quick`` also times the command ``sklearn-psf compare --quick`` (the
main comparison plus the S/N, density, outlier and tuning studies of the quick preset).

Exits 1 when the tables differ.

Usage::

    python benchmarks/bench_compare.py [--n-sims N] [--quick] [--no-dask] [--cli-quick]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time

import joblib
import numpy as np
from threadpoolctl import threadpool_limits

from sklearn_psf.study.compare import SimulationConfig, run_study

FULL_STUDY = 50


def tables_equal(a, b):
    """Same rows and values (NaN == NaN) in every table, ``fit_seconds`` excepted."""
    problems = []
    for name in ("scores", "correlations", "galaxies"):
        ta, tb = getattr(a, name), getattr(b, name)
        if ta.colnames != tb.colnames or len(ta) != len(tb):
            problems.append(f"{name}: columns or lengths differ")
            continue
        for col in ta.colnames:
            if col == "fit_seconds":
                continue
            x, y = np.asarray(ta[col]), np.asarray(tb[col])
            same = (np.array_equal(x, y, equal_nan=True) if x.dtype.kind == "f"
                    else np.array_equal(x, y))
            if not same:
                problems.append(f"{name}.{col}")
    if not np.array_equal(a.theta, b.theta):
        problems.append("theta")
    return problems


def timed_study(n_sims, config, n_jobs):
    t0 = time.perf_counter()
    result = run_study(config, n_simulations=n_sims, n_jobs=n_jobs, random_state=0)
    return time.perf_counter() - t0, result


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n-sims", type=int, default=4, help="simulations timed [4]")
    parser.add_argument("--quick", action="store_true",
                        help="smoke size: 2 small simulations (150 stars, 2000 x 1500 pixels)")
    parser.add_argument("--no-dask", action="store_true", help="skip the Dask run")
    parser.add_argument("--cli-quick", action="store_true",
                        help="also time 'sklearn-psf compare --quick'")
    args = parser.parse_args(argv)
    if args.quick:
        n_sims = 2
        config = SimulationConfig(n_stars=150, n_galaxies=200, image_shape=(1500, 2000))
    else:
        n_sims = args.n_sims
        config = SimulationConfig()
    status = 0
    # one BLAS thread per process: the parallelism is over simulations
    with threadpool_limits(1):
        run_study(config, n_simulations=1, n_jobs=1)  # warm-up: imports, numba cache
        t1, r1 = timed_study(n_sims, config, 1)
        run_study(config, n_simulations=2, n_jobs=2)  # warm the loky worker processes
        t2, r2 = timed_study(n_sims, config, 2)
        runs = {"n_jobs=2": r2}
        t_dask = None
        if not args.no_dask:
            from dask.distributed import Client, LocalCluster

            with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                              dashboard_address=None) as cluster, Client(cluster):
                with joblib.parallel_backend("dask"):
                    run_study(config, n_simulations=2, n_jobs=-1)  # warm both workers
                    t_dask, runs["dask"] = timed_study(n_sims, config, -1)
    print(f"run_study: {n_sims} simulations x {len(r1.config['schemes'])} schemes, "
          f"{config.n_stars} stars, {config.n_galaxies} galaxy-PSFs, image "
          f"{config.image_shape[1]} x {config.image_shape[0]}")
    print(f"  n_jobs=1                 : {t1:8.1f} s  ({t1 / n_sims:.1f} s per simulation)")
    print(f"  n_jobs=2                 : {t2:8.1f} s  ({t1 / t2:.2f} x)")
    if t_dask is not None:
        print(f"  Dask LocalCluster 2x1    : {t_dask:8.1f} s  ({t1 / t_dask:.2f} x; "
              f"dask / n_jobs=2 = {t_dask / t2:.2f}, target <= 1)")
    for label, res in runs.items():
        problems = tables_equal(r1, res)
        print(f"  tables {label:8s} == n_jobs=1: "
              f"{'identical' if not problems else 'DIFFER: ' + ', '.join(problems)}")
        status |= bool(problems)
    best = min(t for t in (t1, t2, t_dask) if t is not None)
    print(f"  EXTRAPOLATED full study ({FULL_STUDY} simulations, main comparison): "
          f"{best / n_sims * FULL_STUDY / 60:.1f} min with the fastest setting above "
          "(target < 30 min; an extrapolation from the per-simulation time, not a run)")

    if args.cli_quick:
        with tempfile.TemporaryDirectory() as out:
            cmd = [sys.executable, "-m", "sklearn_psf", "compare", "--quick", "--n-jobs", "2",
                   "-o", os.path.join(out, "report")]
            t0 = time.perf_counter()
            proc = subprocess.run(cmd, capture_output=True, text=True)
            t_cli = time.perf_counter() - t0
        print(f"  sklearn-psf compare --quick --n-jobs 2: {t_cli:.1f} s (target < 300 s), "
              f"exit status {proc.returncode}")
        if proc.returncode:
            print(proc.stderr[-2000:])
            status = 1
    return status


if __name__ == "__main__":
    sys.exit(main())
