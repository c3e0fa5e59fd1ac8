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

Where the extra CPU goes: each command runs through this script (``--child``), which times
every task where it runs (``process_time`` around a fit of one catalogue, a simulation task
or a group of figures, in the command's process or a worker) and so splits a run's CPU into
the tasks' and the rest (imports, starting and feeding the workers, collecting results). A
pair's extra CPU outside the tasks is what the workers themselves cost; the tasks' own CPU
may differ too, from running two at once on the machine's cores. ``--contention`` measures
that directly: the CPU of one ``fit --stars`` command alone, and of two identical ones at
once (each; alternated, ``--pairs`` times).
"""

from __future__ import annotations

import argparse
import functools
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

#: the tasks timed in each process (module, name): a fit of one catalogue, a simulation task
#: of ``compare``, a group of its figures
TASKS = (("sklearn_psf.cli._fit", "_fit_of_many"), ("sklearn_psf.study.compare._run", "_tagged"),
         ("sklearn_psf.study.report._write", "_draw_figures"))


def child(log, args):
    """Run ``sklearn-psf ARGS`` here, appending each task's CPU seconds to ``log``."""
    import importlib

    from sklearn_psf import cli

    # as the command does, before the tasks' modules import scikit-learn (a baseline
    # checkout may predate these)
    for name in ("_tune_malloc", "_import_sklearn_without_pandas"):
        getattr(cli, name, lambda: None)()

    def timed(func):
        @functools.wraps(func)
        def wrapper(*a, **k):
            start = time.process_time()
            try:
                return func(*a, **k)
            finally:
                with open(log, "a") as f:
                    f.write(f"{time.process_time() - start:.4f}\n")
        return wrapper

    for module, name in TASKS:
        mod = importlib.import_module(module)
        setattr(mod, name, timed(getattr(mod, name)))

    sys.argv = ["sklearn-psf", *args]
    sys.exit(cli._console_script())


def _env(pythonpath):
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    if pythonpath:
        env["PYTHONPATH"] = pythonpath
    return env


def run(args, folder, pythonpath=None):
    """CPU seconds (user + system, this command and its reaped workers) of one command, run
    in ``folder`` (``python -m`` would put the working directory first on ``sys.path``, before
    ``pythonpath``), and the CPU seconds of its tasks."""
    log = os.path.join(folder, "tasks.log")
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    proc = subprocess.run([sys.executable, os.path.abspath(__file__), "--child", log, "--",
                           *args], capture_output=True, text=True, env=_env(pythonpath),
                          cwd=folder)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode:
        raise SystemExit(f"sklearn-psf {' '.join(args[:3])} ... failed:\n{proc.stderr[-2000:]}")
    with open(log) as f:
        tasks = sum(float(line) for line in f)
    os.remove(log)
    return sum(getattr(after, k) - getattr(before, k) for k in ("ru_utime", "ru_stime")), tasks


def pairs(label, make_args, n_pairs, codes):
    """Alternate ``--n-jobs 1`` and ``2`` for each code, ``n_pairs`` times; print each pair."""
    extra = {code: [] for code in codes}
    outside = {code: [] for code in codes}
    for k in range(n_pairs):
        for code, path in codes.items():
            with tempfile.TemporaryDirectory() as tmp:
                one, tasks_one = run(make_args(tmp, 1), tmp, path)
                two, tasks_two = run(make_args(tmp, 2), tmp, path)
            extra[code].append(two - one)
            outside[code].append((two - tasks_two) - (one - tasks_one))
            print(f"  {label} [{code}] pair {k + 1}: --n-jobs 1 {one:.1f} s (tasks {tasks_one:.1f}"
                  f" s), --n-jobs 2 {two:.1f} s (tasks {tasks_two:.1f} s) of CPU: extra worker "
                  f"{two - one:+.1f} s, of which outside the tasks {outside[code][-1]:+.2f} s",
                  flush=True)
    for code, values in extra.items():
        median = statistics.median(values)
        print(f"{label} [{code}]: extra worker's CPU median {median:+.1f} s (from "
              f"{min(values):+.1f} to {max(values):+.1f} s over {len(values)} pairs; target "
              f"<= 0.5 s: {'met' if median <= 0.5 else 'NOT met'}); outside the tasks median "
              f"{statistics.median(outside[code]):+.2f} s (from {min(outside[code]):+.2f} to "
              f"{max(outside[code]):+.2f} s)")
    return extra


def contention(catalogue, n_pairs, folder):
    """CPU of one ``fit --stars catalogue`` alone and of each of two identical ones at once
    (alternated): how much running two processes at once costs on this machine."""
    args = [sys.executable, "-m", "sklearn_psf", "fit", "--stars", catalogue, "--no-plots",
            "--seed", "0"]
    alone, paired = [], []
    for k in range(n_pairs):
        for n in (1, 2):
            procs = [subprocess.Popen(args + ["-o", os.path.join(folder, f"c{k}_{n}_{j}.fits")],
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                      env=_env(None), cwd=folder) for j in range(n)]
            for proc in procs:
                _, status, usage = os.wait4(proc.pid, 0)
                if status:
                    raise SystemExit(f"{' '.join(args)} failed (status {status})")
                (alone if n == 1 else paired).append(usage.ru_utime + usage.ru_stime)
        print(f"  contention pair {k + 1}: alone {alone[-1]:.2f} s, two at once "
              f"{paired[-2]:.2f} and {paired[-1]:.2f} s of CPU each", flush=True)
    ratio = statistics.median(paired) / statistics.median(alone)
    print(f"contention: one fit alone median {statistics.median(alone):.2f} s of CPU, two at "
          f"once {statistics.median(paired):.2f} s each: x{ratio:.3f} ({ratio - 1:+.1%}) for "
          "running two processes at once")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=3)
    parser.add_argument("--n-catalogues", type=int, default=8)
    parser.add_argument("--catalogues", nargs="+", help="catalogues for fit (default: simulated)")
    parser.add_argument("--only", choices=("fit", "compare"))
    parser.add_argument("--baseline", metavar="CHECKOUT",
                        help="a checkout of another commit, timed in the same series")
    parser.add_argument("--quick", action="store_true", help="one pair, two catalogues")
    parser.add_argument("--contention", action="store_true",
                        help="also time one fit alone and two at once (the machine's share)")
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--child"]:  # one command, its tasks timed (see run)
        return child(argv[1], argv[3:])
    args = parser.parse_args(argv)
    if args.quick:
        args.pairs, args.n_catalogues = 1, 2
    codes = {"this": None}
    if args.baseline:
        codes["baseline"] = str(Path(args.baseline).resolve())
    with tempfile.TemporaryDirectory() as folder:
        catalogues = [os.path.abspath(c) for c in args.catalogues or []]
        if not catalogues and (args.only != "compare" or args.contention):
            from sklearn_psf.simulate import write_example_ldac

            for k in range(args.n_catalogues):
                sub = Path(folder, str(k))
                sub.mkdir()
                made = write_example_ldac(sub, n_stars=600, n_galaxies=600,
                                          image_shape=(2048, 4096), random_state=k)
                catalogues.append(str(Path(folder, f"ccd{k}.ldac")))
                os.rename(made["catalog"], catalogues[-1])
        if args.only in (None, "fit"):
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
        if args.contention:
            contention(catalogues[0], args.pairs, folder)


if __name__ == "__main__":
    main()
