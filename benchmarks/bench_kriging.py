"""Benchmark: KrigingRegressor vs PyKrige OrdinaryKriging vs a bare numpy/scipy solve.

Paper size: 1000 stars, 13 targets (PCA coefficients), 2000 query points (galaxy-PSFs),
exponential variogram, range 0.5, nugget 0, positions in the unit square.

PyKrige fits one target column at a time (``OrdinaryKriging`` + ``execute("points",
backend="vectorized")``); KrigingRegressor factorises the shared normalised system once.
All three compute predictions and Kriging variances; results must agree to 1e-6 relative
or the script exits with status 1.

Usage::

    python benchmarks/bench_kriging.py [--quick] [--threads N] [--repeat R]
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np
from pykrige.ok import OrdinaryKriging
from scipy.linalg import cho_factor, cho_solve, solve_triangular
from scipy.spatial.distance import cdist
from threadpoolctl import threadpool_limits

from sklearn_psf.interpolate import KrigingRegressor

RTOL = 1e-6


def make_data(n_stars, n_targets, n_queries, seed=0):
    rng = np.random.default_rng(seed)
    X = rng.uniform(size=(n_stars, 2))
    Xq = rng.uniform(size=(n_queries, 2))
    k = rng.normal(scale=5.0, size=(n_targets, 8, 2))
    phase = rng.uniform(0, 2 * np.pi, size=(n_targets, 8))
    amp = rng.normal(size=(n_targets, 8)) * np.logspace(0, -2, n_targets)[:, None]
    Y = np.einsum("tk,ntk->nt", amp, np.cos(np.einsum("nd,tkd->ntk", X, k) + phase))
    return X, Y, Xq


def ours(X, Y, Xq, a):
    reg = KrigingRegressor(variogram="exponential", range=a, nugget=0.0).fit(X, Y)
    pred, std = reg.predict(Xq, return_std=True)
    return pred, std**2


def ours_no_std(X, Y, Xq, a):
    return KrigingRegressor(variogram="exponential", range=a).fit(X, Y).predict(Xq), None


def pykrige(X, Y, Xq, a):
    preds, variances = [], []
    for t in range(Y.shape[1]):
        ok = OrdinaryKriging(
            X[:, 0], X[:, 1], Y[:, t], variogram_model="exponential",
            # PyKrige's exponential range is 3x ours; psill = column variance, nugget 0
            variogram_parameters={"psill": Y[:, t].var(), "range": 3.0 * a, "nugget": 0.0},
            exact_values=True, pseudo_inv=False,
        )
        z, ss = ok.execute("points", Xq[:, 0], Xq[:, 1], backend="vectorized")
        preds.append(np.asarray(z))
        variances.append(np.asarray(ss))
    return np.column_stack(preds), np.column_stack(variances)


def bare(X, Y, Xq, a):
    """Plain Cholesky + Schur complement, all targets at once, one block of queries."""
    C = np.exp(-cdist(X, X) / a)
    f = cho_factor(C, lower=True)
    w = cho_solve(f, np.ones(len(X)))
    s = w.sum()
    beta = w @ Y / s
    alpha = cho_solve(f, Y - beta)
    c = np.exp(-cdist(Xq, X) / a)
    pred = beta + c @ alpha
    v = solve_triangular(f[0], c.T, lower=True)  # c^T C^-1 c = |L^-1 c|^2
    var = 1.0 - np.einsum("ij,ij->j", v, v) + (1.0 - c @ w) ** 2 / s
    return pred, np.clip(var, 0, None)[:, None] * Y.var(axis=0)


def best_time(fn, args, repeat):
    best, out = np.inf, None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn(*args)
        best = min(best, time.perf_counter() - t0)
    return best, out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="tiny smoke size")
    parser.add_argument("--threads", type=int, default=1, help="BLAS threads (both sides)")
    parser.add_argument("--repeat", type=int, default=5, help="repeats (best time kept)")
    args = parser.parse_args(argv)
    n_stars, n_targets, n_queries = (60, 3, 100) if args.quick else (1000, 13, 2000)
    a = 0.5
    X, Y, Xq = make_data(n_stars, n_targets, n_queries)
    data = (X, Y, Xq, a)
    with threadpool_limits(limits=args.threads):
        ours(*data)  # warm-up (imports, first BLAS calls)
        t_ours, (p_ours, v_ours) = best_time(ours, data, args.repeat)
        t_nostd, _ = best_time(ours_no_std, data, args.repeat)
        t_bare, (p_bare, v_bare) = best_time(bare, data, args.repeat)
        t_pk, (p_pk, v_pk) = best_time(pykrige, data, max(1, args.repeat // 3))

    print(f"Kriging fit+predict(+variance): {n_stars} stars, {n_targets} targets, "
          f"{n_queries} queries, exponential a={a}, BLAS threads={args.threads}")
    print(f"  KrigingRegressor (with std) : {t_ours * 1e3:9.1f} ms")
    print(f"  KrigingRegressor (no std)   : {t_nostd * 1e3:9.1f} ms")
    print(f"  bare numpy/scipy Cholesky   : {t_bare * 1e3:9.1f} ms")
    print(f"  PyKrige OrdinaryKriging     : {t_pk * 1e3:9.1f} ms  (one column at a time)")
    print(f"  speed-up vs PyKrige         : {t_pk / t_ours:9.1f} x  (both with variances)")
    print(f"  speed-up, ours without std  : {t_pk / t_nostd:9.1f} x  (PyKrige always "
          "computes variances)")
    print(f"  ours / bare numpy-scipy     : {t_ours / t_bare:9.2f} (target <= 1.5)")

    ok = True
    for label, (p_ref, v_ref) in {"PyKrige": (p_pk, v_pk), "bare": (p_bare, v_bare)}.items():
        scale_p = np.abs(Y).max(axis=0)
        dp = np.max(np.abs(p_ours - p_ref) / (np.abs(p_ref) + 1e-3 * scale_p))
        dv = np.max(np.abs(v_ours - v_ref) / (np.abs(v_ref) + 1e-6 * Y.var(axis=0)))
        good = dp < RTOL and dv < RTOL
        ok &= good
        print(f"  max rel. diff vs {label:8s}: predictions {dp:.2e}, variances {dv:.2e}"
              f"  -> {'OK' if good else 'MISMATCH'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
