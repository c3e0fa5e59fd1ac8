"""Running the commands' tasks on a Dask cluster (``--scheduler ADDRESS``), shared by
``compare`` and ``fit``.

Dask's nannies start their workers with ``MALLOC_TRIM_THRESHOLD_=65536`` (the default of
``distributed.nanny.pre-spawn-environ``). Setting it also fixes glibc's mmap threshold at
128 KiB, so that every array above that size is mapped afresh and page-faulted in: a fit of
one 200-star CCD then faults three times as many pages and takes 1.3x the CPU time of the same
fit in a local process. The command says so when the workers it joins run that way, with the
setting that starts them as fast as local processes (:data:`FAST_WORKERS`).
"""

from __future__ import annotations

import contextlib
import os
import sys

from ._fit import CLIInputError

#: How to start Dask workers as fast per task as local processes: without Dask's
#: ``MALLOC_TRIM_THRESHOLD_`` (its other settings, one BLAS thread per worker, are kept), one
#: thread per worker process.
FAST_WORKERS = ("DASK_DISTRIBUTED__NANNY__PRE_SPAWN_ENVIRON=\"{'MALLOC_TRIM_THRESHOLD_': None}\" "
                "dask worker ADDRESS --nworkers N --nthreads 1")


def _trim_threshold():
    return os.environ.get("MALLOC_TRIM_THRESHOLD_")


def slow_workers(client) -> list:
    """The workers of ``client``'s cluster running with ``MALLOC_TRIM_THRESHOLD_`` set."""
    return sorted(w for w, value in client.run(_trim_threshold).items() if value is not None)


@contextlib.contextmanager
def dask_backend(scheduler):
    """Run joblib's ``Parallel`` on the Dask cluster at ``scheduler`` (nothing when None)."""
    if scheduler is None:
        yield
        return
    try:
        from distributed import Client
    except ImportError:
        raise CLIInputError("--scheduler needs Dask: pip install 'sklearn-psf[dask]'") from None
    import joblib

    try:
        client = Client(scheduler, timeout="10s")
    except OSError as exc:
        raise CLIInputError(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from None
    with client:
        slow = slow_workers(client)
        if slow:
            print(f"sklearn-psf: note: {len(slow)} of the cluster's {len(client.ncores())} Dask "
                  "workers run with MALLOC_TRIM_THRESHOLD_ set (Dask's default), which makes "
                  "each fit about 1.3x slower than in a local process; start them with "
                  f"{FAST_WORKERS}", file=sys.stderr)
        with joblib.parallel_backend("dask"):
            yield
