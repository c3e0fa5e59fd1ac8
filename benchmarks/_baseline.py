"""Run a benchmark's measurement with another version of the package (private helper).

``run_with(path, script, args)`` runs ``python script --worker args...`` with ``path`` (a
checkout of the previous code, e.g. ``git archive main | tar -x -C /tmp/prev``) first on
``PYTHONPATH``, so that ``import sklearn_psf`` there is the previous code, and returns the
JSON the worker printed on its last line. The benchmarks use it to print ratios against
the previous code measured in the same run.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys


def run_with(path, script, args):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [os.path.abspath(path)] + [p for p in [os.environ.get("PYTHONPATH")] if p])}
    # run from the checkout's parent: the current directory (a checkout of the new code,
    # perhaps) must not come first on sys.path
    out = subprocess.run([sys.executable, os.path.abspath(script), "--worker", *map(str, args)],
                         env=env, capture_output=True, text=True,
                         cwd=os.path.dirname(os.path.abspath(path)))
    if out.returncode != 0:
        raise RuntimeError(f"worker {args} failed:\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def check_version(path):
    """The sklearn_psf that ``path`` provides (its file), to print which code ran."""
    env = {**os.environ, "PYTHONPATH": os.path.abspath(path)}
    out = subprocess.run([sys.executable, "-c", "import sklearn_psf; print(sklearn_psf.__file__)"],
                         env=env, check=True, capture_output=True, text=True,
                         cwd=os.path.dirname(os.path.abspath(path)))
    return out.stdout.strip()
