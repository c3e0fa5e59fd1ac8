"""The commands' local worker pool (``cli/_parallel.py``): joblib's ``Parallel`` on workers
forked after the command's imports (Linux), with the serial results."""

import math
import os
import sys

import numpy as np
import pytest
from joblib import Parallel, delayed

from sklearn_psf.cli import _parallel
from sklearn_psf.cli._parallel import local_pool, map_ordered


def _state():
    """What a worker sees: its pid, the marker set in the parent, its BLAS threads."""
    from threadpoolctl import threadpool_info

    threads = [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]
    return os.getpid(), getattr(_parallel, "_TEST_MARK", None), max(threads, default=1)


def _pid_threads(_):
    return _state()[0], _state()[2]


def _nested(n):
    """A task running its own ``Parallel``: joblib's nested backend, not the pool."""
    return sum(Parallel(n_jobs=2)(delayed(math.sqrt)(i * i) for i in range(n)))


def _fails(i):
    if i == 3:
        raise ValueError("task 3 fails")
    return i


@pytest.mark.skipif(sys.platform != "linux", reason="workers are forked on Linux only")
def test_workers_are_forked_after_the_parent_state(monkeypatch):
    """A value the parent set at run time (not at import) reaches the workers: they are forks
    of the command's process, which import nothing; BLAS runs on cores / workers threads."""
    monkeypatch.setattr(_parallel, "_TEST_MARK", 1234, raising=False)
    with local_pool(2):
        states = Parallel(n_jobs=2)(delayed(_state)() for _ in range(8))
    assert {pid for pid, _, _ in states} - {os.getpid()}, "no task ran in a worker"
    assert all(pid != os.getpid() for pid, _, _ in states)
    assert all(mark == 1234 for _, mark, _ in states)
    expected = max(os.cpu_count() // 2, 1)
    assert all(threads <= expected for _, _, threads in states), states


def test_pool_gives_the_serial_results_in_order_and_generators():
    values = np.arange(40.0)
    serial = [math.sqrt(v) for v in values]
    with local_pool(2):
        assert Parallel(n_jobs=2)(delayed(math.sqrt)(v) for v in values) == serial
        got = sorted(Parallel(n_jobs=-1, return_as="generator_unordered")(
            delayed(math.sqrt)(v) for v in values))
        assert got == sorted(serial)
        # a task's own Parallel runs inside the worker (threads), with the serial sum
        assert Parallel(n_jobs=2)(delayed(_nested)(n) for n in (5, 10)) == [10.0, 45.0]


def test_pool_raises_a_task_error_and_stops_its_workers():
    with pytest.raises(ValueError, match="task 3 fails"):
        with local_pool(2):
            Parallel(n_jobs=2)(delayed(_fails)(i) for i in range(8))
    with local_pool(2):  # a new pool after the failed one
        assert Parallel(n_jobs=2)(delayed(_fails)(i) for i in range(3)) == [0, 1, 2]


def test_one_job_runs_in_this_process():
    with local_pool(1):
        pids = Parallel(n_jobs=1)(delayed(os.getpid)() for _ in range(3))
    assert pids == [os.getpid()] * 3
    with local_pool(None):  # no pool (the Dask scheduler's case): joblib's own backend
        assert Parallel(n_jobs=1)(delayed(math.sqrt)(4.0) for _ in range(2)) == [2.0, 2.0]


@pytest.mark.skipif(sys.platform != "linux", reason="workers are forked on Linux only")
def test_map_ordered_worker_shares_the_cores_with_this_process():
    """fit's pool: this process computes beside the worker, so each has half the cores for
    BLAS (a forked worker once kept all of them: 1.6-1.8x the CPU per fit), and never more
    threads than this process had."""
    from threadpoolctl import threadpool_limits

    for limit in (None, 1):
        with threadpool_limits(limit):
            inherited = _state()[2]
            out = list(map_ordered(_pid_threads, range(12), n_jobs=2))
        workers = [threads for pid, threads in out if pid != os.getpid()]
        assert workers, "no item ran in the worker"
        assert max(workers) <= min(max(os.cpu_count() // 2, 1), inherited), (limit, out)
