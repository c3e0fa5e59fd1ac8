"""Running the commands' tasks in parallel, shared by ``compare`` and ``fit``: on local
worker processes (forked from the command's process on Linux: :func:`process_pool`,
:func:`local_pool`, :func:`map_ordered`) or on a Dask cluster (``--scheduler ADDRESS``).

Dask's nannies start their workers with ``MALLOC_TRIM_THRESHOLD_=65536`` (the default of
``distributed.nanny.pre-spawn-environ``). Setting it also fixes glibc's mmap threshold at
128 KiB, so that every array above that size is mapped afresh and page-faulted in: a fit of
one 200-star CCD then faults three times as many pages and takes 1.3x the CPU time of the same
fit in a local process. The command says so when the workers it joins run that way, with the
setting that starts them as fast as local processes (:data:`FAST_WORKERS`). That setting also
imports the library when each worker starts (Dask's ``--preload``), so that a fresh cluster's
first fits do not wait for it.
"""

from __future__ import annotations

import contextlib
import os
import sys

from ._common import CLIInputError

#: The module a Dask worker imports when it starts (``--preload``): the fitting, measuring and
#: reading code (about 2 s of imports, mostly scikit-learn, SciPy and Astropy).
PRELOAD = "sklearn_psf.validation"
#: How to start Dask workers as fast per task as local processes: without Dask's
#: ``MALLOC_TRIM_THRESHOLD_`` (its other settings, one BLAS thread per worker, are kept), one
#: thread per worker process, the library imported at the start.
FAST_WORKERS = ("DASK_DISTRIBUTED__NANNY__PRE_SPAWN_ENVIRON=\"{'MALLOC_TRIM_THRESHOLD_': None}\" "
                f"dask worker ADDRESS --nworkers N --nthreads 1 --preload {PRELOAD}")


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
    from .._optional import require

    Client = require("distributed", "--scheduler").Client
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


def _worker_start(blas_threads):
    """Start of a worker process of :func:`process_pool`: tqdm's lock a thread lock, BLAS on
    ``blas_threads`` threads at most (the cores over the processes computing at once, as
    joblib's loky shares them).

    A worker draws no progress bar, but tqdm creates its lock with each bar (even disabled):
    by default a multiprocessing lock, a named semaphore that the worker, stopped once the
    results are in, would leave to Python's resource tracker ("leaked semaphore objects").
    """
    import threading

    from threadpoolctl import threadpool_info, threadpool_limits
    from tqdm import tqdm

    tqdm.set_lock(threading.RLock())
    inherited = max((p["num_threads"] for p in threadpool_info()), default=1)
    threadpool_limits(min(blas_threads, inherited))  # never more than the user allowed


def prepare_workers(*modules):
    """Import ``modules`` and make numba's first call (its compiler and the adaptive-moment
    kernels, ~0.4 s in each process) here, once, before :func:`process_pool` forks workers
    that would each repeat them on their first task."""
    import importlib

    import numpy as np

    from ..measure import adaptive_moments

    for name in modules:
        importlib.import_module(name)
    adaptive_moments(np.ones((1, 9, 9)))


def process_pool(n_workers, n_processes=None):
    """An executor of ``n_workers`` worker processes, forked from this one where the system
    allows it (Linux), else fresh interpreters (loky's). Each runs BLAS on the cores divided
    by ``n_processes`` (the processes computing at once; ``n_workers`` when None).

    A forked worker starts with this process's imports, which a fresh one pays again (about
    3.5 s of CPU: scikit-learn, SciPy, Astropy, matplotlib); make them first
    (:func:`prepare_workers`), and call this before starting threads (a thread holding a
    lock at the fork would leave it held in the workers).
    """
    import gc
    import multiprocessing
    import warnings

    from joblib import cpu_count

    args = dict(max_workers=n_workers, initializer=_worker_start,
                initargs=(max(cpu_count() // (n_processes or n_workers), 1),))
    if sys.platform == "linux":
        from concurrent.futures import ProcessPoolExecutor

        executor = ProcessPoolExecutor(mp_context=multiprocessing.get_context("fork"), **args)
        # the workers' garbage collector leaves the objects they inherit alone (else it
        # touches, and so copies, every page holding one); fork them all now, before the
        # caller starts threads
        gc.freeze()
        try:
            with warnings.catch_warnings():
                # Python 3.12+ warns of any thread at a fork; here only the BLAS and OpenMP
                # pools' idle threads run (none of ours yet), which hold no lock of Python's
                warnings.filterwarnings("ignore", r".*multi-threaded.*fork",
                                        DeprecationWarning)
                executor.submit(int).result()
        finally:
            gc.unfreeze()
        return executor
    from joblib.externals.loky import ProcessPoolExecutor

    return ProcessPoolExecutor(**args)


def _stop(executor):
    """Stop ``executor``'s workers now, not at the interpreter's exit (which would wait for
    each to finish its task and tear itself down)."""
    executor.shutdown(wait=False, cancel_futures=True)
    if hasattr(executor, "_processes"):  # the standard library's (loky's kills them itself)
        for process in list((executor._processes or {}).values()):
            process.terminate()


@contextlib.contextmanager
def local_pool(n_jobs, prepare=None):
    """Run joblib's ``Parallel`` on :func:`process_pool`'s ``n_jobs`` workers (nothing when
    ``n_jobs`` is None or 1), started here and kept until the end of the block.

    ``prepare()``, when given, runs first: the imports and first calls (numba's kernels,
    matplotlib's fonts) that every worker would otherwise repeat on its first task.
    """
    import joblib
    from joblib import cpu_count
    from joblib._parallel_backends import (AutoBatchingMixin, FallbackToBackend,
                                           ParallelBackendBase, SequentialBackend)

    n_workers = 1 if n_jobs is None else joblib.effective_n_jobs(n_jobs)
    if n_workers < 2:
        yield
        return
    if prepare is not None:
        prepare()

    class PoolBackend(AutoBatchingMixin, ParallelBackendBase):  # joblib's backend interface
        supports_retrieve_callback = True

        def effective_n_jobs(self, n_jobs):
            if n_jobs is None:
                return 1
            return min(n_jobs if n_jobs > 0 else max(cpu_count() + 1 + n_jobs, 1), n_workers)

        def configure(self, n_jobs=1, parallel=None, **kwargs):
            n_jobs = self.effective_n_jobs(n_jobs)
            if n_jobs == 1:
                raise FallbackToBackend(SequentialBackend(nesting_level=self.nesting_level))
            self.parallel = parallel
            return n_jobs

        def submit(self, func, callback=None):
            future = executor.submit(func)
            if callback is not None:
                future.add_done_callback(callback)
            return future

        def retrieve_result_callback(self, future):
            return future.result()

    executor = process_pool(n_workers)
    try:
        with joblib.parallel_config(backend=PoolBackend()):
            yield
    finally:
        _stop(executor)


def map_ordered(func, items, n_jobs):
    """``func(item)`` for each of ``items`` in their order (an iterator), computed by this
    process and ``n_jobs - 1`` worker processes, each taking the next item when it is free.

    The workers are started (forked) by this call, before the caller starts threads such as
    its progress bar's. This process computes too, so that it is not idle beside them. An
    exception of ``func`` is raised at its item's turn; the items a dead worker did not take
    are left to this process.
    """
    from joblib import effective_n_jobs

    items = list(items)
    n_workers = min(effective_n_jobs(n_jobs), len(items)) - 1
    if n_workers < 1:
        return map(func, items)
    return _map_on(process_pool(n_workers, n_workers + 1), n_workers, func, items)


def _map_on(executor, n_workers, func, items):
    import threading
    from collections import deque
    from concurrent.futures import Future

    pending, done, ready = deque(range(len(items))), {}, threading.Condition()

    def take():
        with ready:
            return pending.popleft() if pending else None

    def finish(i, future):
        with ready:
            done[i] = future
            ready.notify_all()

    def feed():  # one thread per worker, handing it the next item when it is free
        while (i := take()) is not None:
            try:
                future = executor.submit(func, items[i])
            except Exception:  # a broken pool: this process computes the rest
                with ready:
                    pending.appendleft(i)
                return
            failed = future.exception() is not None  # waits for the result
            finish(i, future)
            if failed:
                return

    for _ in range(n_workers):
        threading.Thread(target=feed, daemon=True).start()
    try:
        for i in range(len(items)):
            while i not in done and (j := take()) is not None:
                future = Future()
                try:
                    future.set_result(func(items[j]))
                except Exception as exc:
                    future.set_exception(exc)
                finish(j, future)
            with ready:
                ready.wait_for(lambda: i in done)
                future = done.pop(i)
            yield future.result()
    finally:
        with ready:
            pending.clear()  # the workers take nothing more
        # their results are in (or no longer wanted): stop them now, not at the interpreter's
        # exit, which would wait for each to tear its own down
        _stop(executor)
