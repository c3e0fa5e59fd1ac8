"""Benchmark: the CPU an extra worker costs, for ``sklearn-psf fit`` and ``sklearn-psf compare``
(issue 32: at most 0.5 s).

Each command runs as a user runs it (a fresh process, one BLAS thread), alternately with
``--n-jobs 1`` and ``--n-jobs 2``, ``--pairs`` times; the CPU of a run is the user + system
time of the command and its workers (reaped). The extra worker's cost is the difference of a
pair (two jobs: one worker more). The machine's speed drifts by 10-20% between runs, several
seconds on these ~25-30 s commands, so every pair is printed with the median and spread;
alternating the runs keeps a drift from falling on one side only.

- ``fit``: ``fit --stars CAT1 ... CATn --no-plots`` over ``--n-catalogues`` simulated VIGNET
  catalogues (``write_example_ldac``: 600 stars, 600 galaxies, 4096 x 2048 pixels each, about
  the DECam-like CCDs of ``bench_psfex.py``), or the catalogues given with ``--catalogues``;
- ``compare``: ``compare --quick --n-simulations 2 --study-simulations 1 --studies none``.

``--baseline PATH`` runs the same pairs with the package at ``PATH`` (a checkout of another
commit, put first on ``PYTHONPATH``) in the same series, for the ratio against it. The CPU
of a worker counts only once the command has reaped it: loky's workers, killed at the end of
``fit`` (the code before the forked workers), may be left unreaped, so a baseline with them
can read low, even below ``--n-jobs 1``.

Usage::

    python benchmarks/bench_workers.py [--pairs 3] [--n-catalogues 8] [--catalogues F ...]
                                       [--only fit|compare] [--baseline CHECKOUT] [--quick]

``--quick``: one pair, two catalogues (a smoke run: its figures mean nothing).
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path


def run(args, folder, pythonpath=None):
    """CPU seconds (user + system, this command and its reaped workers) of one command, run
    in ``folder``: ``python -m`` puts its working directory first on ``sys.path``, which
    would put a checkout there before ``pythonpath``."""
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    if pythonpath:
        env["PYTHONPATH"] = pythonpath
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    proc = subprocess.run([sys.executable, "-m", "sklearn_psf", *args], capture_output=True,
                          text=True, env=env, cwd=folder)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode:
        raise SystemExit(f"sklearn-psf {' '.join(args[:3])} ... failed:\n{proc.stderr[-2000:]}")
    return sum(getattr(after, k) - getattr(before, k) for k in ("ru_utime", "ru_stime"))


def pairs(label, make_args, n_pairs, codes):
    """Alternate ``--n-jobs 1`` and ``2`` for each code, ``n_pairs`` times; print each pair."""
    extra = {code: [] for code in codes}
    for k in range(n_pairs):
        for code, path in codes.items():
            with tempfile.TemporaryDirectory() as tmp:
                one = run(make_args(tmp, 1), tmp, path)
                two = run(make_args(tmp, 2), tmp, path)
            extra[code].append(two - one)
            print(f"  {label} [{code}] pair {k + 1}: --n-jobs 1 {one:.1f} s, --n-jobs 2 {two:.1f} s"
                  f" of CPU: extra worker {two - one:+.1f} s", flush=True)
    for code, values in extra.items():
        median = statistics.median(values)
        print(f"{label} [{code}]: extra worker's CPU median {median:+.1f} s (from "
              f"{min(values):+.1f} to {max(values):+.1f} s over {len(values)} pairs; target "
              f"<= 0.5 s: {'met' if median <= 0.5 else 'NOT met'})")
    return extra


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=3)
    parser.add_argument("--n-catalogues", type=int, default=8)
    parser.add_argument("--catalogues", nargs="+", help="catalogues for fit (default: simulated)")
    parser.add_argument("--only", choices=("fit", "compare"))
    parser.add_argument("--baseline", metavar="CHECKOUT",
                        help="a checkout of another commit, timed in the same series")
    parser.add_argument("--quick", action="store_true", help="one pair, two catalogues")
    args = parser.parse_args(argv)
    if args.quick:
        args.pairs, args.n_catalogues = 1, 2
    codes = {"this": None}
    if args.baseline:
        codes["baseline"] = str(Path(args.baseline).resolve())
    with tempfile.TemporaryDirectory() as folder:
        if args.only in (None, "fit"):
            catalogues = [os.path.abspath(c) for c in args.catalogues or []]
            if not catalogues:
                from sklearn_psf.simulate import write_example_ldac

                catalogues = []
                for k in range(args.n_catalogues):
                    sub = Path(folder, str(k))
                    sub.mkdir()
                    made = write_example_ldac(sub, n_stars=600, n_galaxies=600,
                                              image_shape=(2048, 4096), random_state=k)
                    catalogues.append(str(Path(folder, f"ccd{k}.ldac")))
                    os.rename(made["catalog"], catalogues[-1])
            pairs(f"fit over {len(catalogues)} catalogues",
                  lambda tmp, n: ["fit", "--stars", *catalogues, "--no-plots", "--n-jobs", str(n),
                                  "-o", os.path.join(tmp, f"psf{n}.fits")],
                  args.pairs, codes)
        if args.only in (None, "compare"):
            pairs("compare (2 simulations, no side study)",
                  lambda tmp, n: ["compare", "--quick", "--n-simulations", "2",
                                  "--study-simulations", "1", "--studies", "none", "--n-jobs",
                                  str(n), "-o", os.path.join(tmp, f"out{n}")],
                  args.pairs, codes)


if __name__ == "__main__":
    main()
