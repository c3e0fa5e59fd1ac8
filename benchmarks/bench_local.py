"""Benchmark: local (moving-neighbourhood) Kriging for large numbers of stars.

- N = 10^4 stars, 13 targets, 2000 queries: ``KrigingRegressor(n_neighbors=k)`` vs exact
  Kriging (``n_neighbors=None``, itself checked against PyKrige and a bare solve in
  bench_kriging.py): the RMS difference must stay below 2% of each target's field RMS.
- PyKrige's own moving window (``execute(..., backend="loop", n_closest_points=k)``), one
  target, a few hundred queries: the same local ordinary Kriging, so predictions and
  variances must agree to 1e-6; the time per (query, target) is compared.
- N = 10^5 stars, 10^5 queries, 13 targets: time of fit + predict (target < 60 s), with
  and without the standard deviation, and the local Shepard and RBF for reference.

Exits 1 when a result differs from its reference beyond tolerance.

Usage::

    python benchmarks/bench_local.py [--quick] [--threads N] [-k K]
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np
from pykrige.ok import OrdinaryKriging
from threadpoolctl import threadpool_limits

from sklearn_psf.interpolate import KrigingRegressor, RBFRegressor, ShepardRegressor

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_kriging import make_data  # noqa: E402  (the same smooth multi-target field)



def clock(fn):
    t0 = time.perf_counter()
    out = fn()
    return time.perf_counter() - t0, out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="tiny smoke size")
    parser.add_argument("--threads", type=int, default=1, help="BLAS threads")
    parser.add_argument("-k", type=int, default=30, help="neighbours per query")
    args = parser.parse_args(argv)
    k, a, ok = args.k, 0.5, True
    n_mid, n_big, n_pk = (1000, 5000, 50) if args.quick else (10_000, 100_000, 300)
    with threadpool_limits(args.threads):
        print(f"BLAS threads = {args.threads}, k = {k} neighbours, exponential a = {a}")
        # 1. accuracy against exact Kriging at n_mid stars
        X, Y, Xq = make_data(n_mid, 13, 2000)
        t_exact, p_exact = clock(lambda: KrigingRegressor(range=a).fit(X, Y).predict(Xq))
        t_local, p_local = clock(
            lambda: KrigingRegressor(range=a, n_neighbors=k).fit(X, Y).predict(Xq))
        rms = Y.std(axis=0)
        rel = np.sqrt(np.mean((p_local - p_exact) ** 2, axis=0)) / rms
        relmax = np.max(np.abs(p_local - p_exact), axis=0) / rms
        print(f"\n{n_mid} stars, 13 targets, 2000 queries")
        print(f"  exact Kriging : {t_exact:8.2f} s   local (k={k}) : {t_local:8.2f} s  "
              f"({t_exact / t_local:.0f} x)")
        print(f"  RMS(local - exact) / field RMS: max over targets {rel.max():.2%} "
              f"(max abs difference {relmax.max():.2%} of the field RMS)")
        good = bool(np.all(rel < 0.02))
        ok &= good
        print(f"    -> within 2% of the field RMS: {'OK' if good else 'MISMATCH'}")

        # 2. PyKrige's moving window, one target
        q = Xq[:n_pk]
        t_ours, (p1, s1) = clock(lambda: KrigingRegressor(range=a, n_neighbors=k).fit(
            X, Y[:, :1]).predict(q, return_std=True))
        ok_pk = OrdinaryKriging(X[:, 0], X[:, 1], Y[:, 0], variogram_model="exponential",
                                variogram_parameters={"psill": Y[:, 0].var(),
                                                      "range": 3.0 * a, "nugget": 0.0})
        t_pk, (z, ss) = clock(lambda: ok_pk.execute("points", q[:, 0], q[:, 1],
                                                    backend="loop", n_closest_points=k))
        dp = np.max(np.abs(p1[:, 0] - z)) / rms[0]
        dv = np.max(np.abs(s1[:, 0] ** 2 - ss) / (ss + 1e-12))
        print(f"  PyKrige moving window ({n_pk} queries, 1 target, with variances): "
              f"{t_pk:.2f} s, ours {t_ours:.3f} s ({t_pk / t_ours:.0f} x; PyKrige fit time "
              "excluded)")
        print(f"  max difference vs PyKrige: predictions {dp:.1e} (of field RMS), variances "
              f"{dv:.1e} (relative)")
        good = dp < 1e-6 and dv < 1e-6
        ok &= good
        print(f"    -> agreement with PyKrige: {'OK' if good else 'MISMATCH'}")

        # 3. scale
        X, Y, Xq = make_data(n_big, 13, n_big, seed=1)
        print(f"\n{n_big} stars, 13 targets, {n_big} queries (fit + predict)")
        for label, est, kw in [
            ("Kriging, predictions", KrigingRegressor(range=a, n_neighbors=k), {}),
            ("Kriging, with std", KrigingRegressor(range=a, n_neighbors=k),
             {"return_std": True}),
            ("Shepard", ShepardRegressor(n_neighbors=k), {}),
            ("RBF thin-plate", RBFRegressor(kernel="thin_plate_spline", n_neighbors=k), {}),
        ]:
            t, out = clock(lambda: est.fit(X, Y).predict(Xq, **kw))
            pred = out[0] if isinstance(out, tuple) else out
            finite = bool(np.all(np.isfinite(pred)))
            ok &= finite
            flag = "" if label[:7] != "Kriging" else (
                "  (target < 60 s: " + ("met" if t < 60 else "NOT met") + ")")
            print(f"  {label:22s}: {t:8.2f} s{flag}{'' if finite else '  NON-FINITE'}")
        # on-star sanity at scale: local Kriging interpolates exactly
        p_on = KrigingRegressor(range=a, n_neighbors=k).fit(X, Y).predict(X[:100])
        good = np.allclose(p_on, Y[:100], atol=1e-10)
        ok &= good
        print(f"    -> exact at the stars: {'OK' if good else 'MISMATCH'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
