"""Benchmark: PSFModel() at survey scale, against the previous code, the exact model and PIFF.

For each size (1000, 4000, 16,000 and 64,000 stars of 25x25 pixels at S/N 100, on the default
10,032 x 7,769 px image; at random positions up to 16,000, on a jittered grid at 64,000, where
random non-overlapping stamps no longer fit), in a fresh process: the time of
``PSFModel().fit`` (raw stamps and their weights, one BLAS thread; best and median of 3 fits up
to 4000 stars, one beyond) and its peak memory above the process's memory before the fit
(resident set size sampled every 5 ms from ``/proc/self/statm``, so that BLAS and LAPACK
buffers count). Targets (on a quiet machine): <= 2 s at 1000 stars, <= 30 s and <= 2 GB at
16,000, <= 3 min at 64,000.

With ``--baseline PATH`` (a checkout of the previous code, e.g. ``git archive <rev> | tar -x
-C /tmp/prev``) the same fits run with that code, in the same run, and their ratios are
printed (the previous code refused 16,000 stars).

Accuracy: at 4000 stars, the e_rms at 2000 galaxy-PSFs (rms of |e_model - e_true|, adaptive
moments) of ``PSFModel()`` (local Kriging beyond 2000 stars) against the same model with exact
Kriging (``KrigingRegressor(range="auto", n_neighbors=None)``), paired on 3 simulations
(target: ratio <= 1.01).

``--piff``: PIFF's ``SimplePSF(PixelGrid(scale=1, size=25), BasisPolynomial(order=2))`` fitted
on the same stars (``piff.Star`` building excluded from the time), at 1000 stars; PIFF's model
is another one (pixel grid, polynomial interpolation): the ratio is one of cost only.

Run ``python benchmarks/bench_scale.py --baseline /tmp/prev [--piff]`` (about 20 minutes on a
quiet 2-core machine, most of it the 64,000-star simulation and fit) or ``--quick`` (500 and
2000 stars).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import threading
import time
import warnings

import numpy as np
from threadpoolctl import threadpool_limits

from sklearn_psf import PSFModel, adaptive_moments, make_psf_field

_PAGE = os.sysconf("SC_PAGE_SIZE")


class PeakMemory:
    """Peak resident set size above the value at entry, sampled in a thread (bytes)."""

    def __enter__(self):
        self.start = self.peak = self._rss()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()
        return self

    @staticmethod
    def _rss():
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[1]) * _PAGE

    def _run(self):
        while not self._stop.wait(0.005):
            self.peak = max(self.peak, self._rss())

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()
        self.peak = max(self.peak, self._rss())
        self.above = self.peak - self.start


#: stars at random positions up to this many; beyond, on a jittered grid (random
#: non-overlapping 25x25 stamps no longer fit on the image)
_RANDOM_UP_TO = 16000


def field(n_stars, seed, n_galaxies=10):
    positions = None
    if n_stars > _RANDOM_UP_TO:
        shape = (7769, 10032)
        rows = int(np.floor(np.sqrt(n_stars * shape[0] / shape[1])))
        cols = int(np.ceil(n_stars / rows))
        step_y, step_x = (shape[0] - 40) / rows, (shape[1] - 40) / cols
        gy, gx = np.mgrid[0:rows, 0:cols]
        rng = np.random.default_rng(seed)
        jitter = rng.uniform(-0.15, 0.15, size=(2, rows, cols))
        x = 20 + (gx + 0.5 + jitter[0] * (step_x - 26) / step_x) * step_x
        y = 20 + (gy + 0.5 + jitter[1] * (step_y - 26) / step_y) * step_y
        positions = np.column_stack([x.ravel(), y.ravel()])[:n_stars]
    return make_psf_field(n_stars=n_stars, n_galaxies=n_galaxies, snr=100.0, random_state=seed,
                          star_positions=positions)


def star_data(f):
    X = np.column_stack([f.stars["x"], f.stars["y"]]).astype(float)
    stamps, weights, flags = f.star_stamps(normalize=False, return_weights=True)
    keep = flags == 0
    return X[keep], stamps[keep], weights[keep]


def fit_worker(n_stars, seed):
    """Time and peak memory of PSFModel().fit with the sklearn_psf on the path."""
    X, stamps, weights = star_data(field(n_stars, seed))
    out = {"n": int(len(X))}
    with threadpool_limits(1), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        PSFModel().fit(X[:200], stamps[:200], weights=weights[:200])  # imports, compilation
        times = []
        try:
            for _ in range(3 if n_stars <= 4000 else 1):
                with PeakMemory() as mem:
                    t0 = time.perf_counter()
                    PSFModel().fit(X, stamps, weights=weights)
                    times.append(time.perf_counter() - t0)
                out["memory"] = max(out.get("memory", 0), mem.above)
            out["seconds"], out["median"] = min(times), float(np.median(times))
        except (ValueError, MemoryError) as exc:
            out["error"] = f"{type(exc).__name__}: {str(exc)[:120]}"
    return out


def accuracy_worker(n_stars, seed):
    """e_rms at the galaxies of PSFModel() and of the same model with exact Kriging."""
    from sklearn_psf.model import make_default_interpolator

    f = field(n_stars, seed, n_galaxies=2000)
    X, stamps, weights = star_data(f)
    Xg = np.column_stack([f.galaxies["x"], f.galaxies["y"]]).astype(float)
    out = {}
    with threadpool_limits(1), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        exact = make_default_interpolator().set_params(krigingregressor__n_neighbors=None)
        for name, interp in (("default", None), ("exact", exact)):
            model = PSFModel(interpolator=interp).fit(X, stamps, weights=weights)
            mom = adaptive_moments(model.predict(Xg))
            ok = np.asarray(mom["flag"]) == 0
            de = np.hypot(mom["e1"] - f.galaxies["e1"], mom["e2"] - f.galaxies["e2"])[ok]
            out[name] = float(np.sqrt(np.mean(de**2)))
    return out


def piff_worker(n_stars, seed):
    import galsim
    import piff

    X, stamps, weights = star_data(field(n_stars, seed))
    s = int(round(np.sqrt(stamps.shape[1])))
    wcs = galsim.PixelScale(1.0)
    stars = []
    for (x, y), st, w in zip(X, stamps, weights):
        im = galsim.Image(st.reshape(s, s).copy(), wcs=wcs)
        wt = galsim.Image(w.reshape(s, s).copy(), wcs=wcs)
        for image in (im, wt):
            image.setCenter(int(round(x)), int(round(y)))
        stars.append(piff.Star(piff.StarData(im, galsim.PositionD(x, y), weight=wt), None))
    psf = piff.SimplePSF(piff.PixelGrid(scale=1.0, size=s), piff.BasisPolynomial(order=2))
    with threadpool_limits(1):
        t0 = time.perf_counter()
        psf.fit(stars, wcs={0: wcs}, pointing=None)
        return {"seconds": time.perf_counter() - t0}


def worker(kind, n_stars, seed):
    fn = {"fit": fit_worker, "accuracy": accuracy_worker, "piff": piff_worker}[kind]
    print(json.dumps(fn(int(n_stars), int(seed))))


def run(args, path=None):
    """A worker in a fresh process, with ``path`` (previous code) first on the path."""
    from _baseline import run_with

    return run_with(path or os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                    __file__, args)


def target(label, met):
    print(f"   -> target {label}: {'met' if met else 'NOT met'}")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="500 and 2000 stars")
    parser.add_argument("--baseline", help="checkout of the previous code (PYTHONPATH)")
    parser.add_argument("--piff", action="store_true", help="PIFF's fit at 1000 stars")
    parser.add_argument("--worker", nargs=3, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker:
        return worker(*args.worker)
    sizes = (500, 2000) if args.quick else (1000, 4000, 16000, 64000)
    previous_sizes = sizes[:2] if args.quick else (1000, 4000, 16000)
    if args.baseline:
        from _baseline import check_version

        print(f"previous code: {check_version(args.baseline)}")
    print("\nPSFModel().fit, S/N 100, 25x25 stamps, one BLAS thread (fresh process per size)")
    results = {}
    for n in sizes:
        new = run(["fit", n, 1])
        line = (f"  {new['n']:6d} stars: {new['seconds']:7.2f} s (median {new['median']:.2f}), "
                f"peak memory {new['memory'] / 2**30:5.2f} GB above the pre-fit process")
        if args.baseline and n in previous_sizes:
            old = run(["fit", n, 1], args.baseline)
            if "error" in old:
                line += f"; previous code: {old['error']}"
            else:
                line += (f"; previous {old['seconds']:6.2f} s (median {old['median']:.2f}), "
                         f"{old['memory'] / 2**30:4.2f} GB (time ratio new/previous "
                         f"{new['seconds'] / old['seconds']:.2f})")
        print(line, flush=True)
        results[n] = new
    if not args.quick:
        target("<= 2 s at 1000 stars", results[1000]["seconds"] <= 2.0)
        target("<= 30 s and <= 2 GB at 16,000 stars",
               results[16000]["seconds"] <= 30.0 and results[16000]["memory"] <= 2 * 2**30)
        target("<= 3 min at 64,000 stars", results[64000]["seconds"] <= 180.0)
        sizes_arr = np.array([results[n]["n"] for n in sizes], float)
        times = np.array([results[n]["seconds"] for n in sizes])
        slope = np.polyfit(np.log(sizes_arr[1:]), np.log(times[1:]), 1)[0]
        print(f"  time grows as n^{slope:.2f} from 4000 to 64,000 stars")
    n_acc = 2000 if args.quick else 4000
    ratios = []
    for seed in (1, 2, 3):
        acc = run(["accuracy", n_acc, seed])
        ratios.append(acc["default"] / acc["exact"])
        print(f"  accuracy, {n_acc} stars, seed {seed}: e_rms PSFModel() {acc['default']:.5f}, "
              f"exact Kriging {acc['exact']:.5f} (ratio {ratios[-1]:.4f})", flush=True)
    print(f"  median ratio {np.median(ratios):.4f}, largest {max(ratios):.4f}")
    target("e_rms within 1% of the exact model at 4000 stars", max(ratios) <= 1.01)
    if args.piff:
        n = 500 if args.quick else 1000
        p = run(["piff", n, 1])
        print(f"  PIFF SimplePSF(PixelGrid 25x25, BasisPolynomial order 2).fit, {n} stars: "
              f"{p['seconds']:.1f} s (ratio PSFModel()/PIFF "
              f"{results[n]['seconds'] / p['seconds']:.3f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
