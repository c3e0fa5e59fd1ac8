"""Benchmark: PSFModel() against the optimum of the same simulated field.

The optimum is the study's oracle (:class:`sklearn_psf.study.compare.FieldOracle`): the best
linear unbiased predictor of all the reference-basis coefficients jointly, with the
simulation's true signal covariance and each star's true k x k noise covariance, on the best
measurement the package makes (weighted least squares of each raw stamp on the reference
basis). :func:`~sklearn_psf.study.compare.oracle_e_rms_ratio` compares the two on the
galaxy-PSFs.

For each simulation of the default field (1000 stars, 2000 galaxy-PSFs, 10,032 x 7,769 px)
at S/N 100 and at the realistic S/N mix (20-1000), ``e_rms`` is the rms over the
galaxy-PSFs of |e_model - e_true| (adaptive moments of the predicted, normalised stamps).
Printed, with the median and the 16th-84th percentiles over the simulations:

- PSFModel() / oracle (target: median <= 1.01);
- previous PSFModel() / PSFModel(), paired on the same simulations (with ``--baseline PATH``,
  a checkout of the previous code run in a subprocess; target: median >= 1.02).

Run ``python benchmarks/bench_optimum.py --baseline /tmp/prev`` (10 simulations per S/N, about
15 minutes on 2 cores) or ``--quick`` (2 simulations). BLAS runs on one thread.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings

import numpy as np
from threadpoolctl import threadpool_limits

from sklearn_psf import PSFModel, adaptive_moments, make_psf_field
from sklearn_psf.simulate import realistic_snr
from sklearn_psf.study.compare import oracle_e_rms_ratio

N_STARS = 1000


def field(seed, snr):
    value = realistic_snr(N_STARS, random_state=seed) if snr == "realistic" else float(snr)
    return make_psf_field(n_stars=N_STARS, snr=value, random_state=seed)


def e_rms(stamps, f):
    mom = adaptive_moments(stamps)
    ok = np.asarray(mom["flag"]) == 0
    de = np.hypot(mom["e1"] - f.galaxies["e1"], mom["e2"] - f.galaxies["e2"])[ok]
    return float(np.sqrt(np.mean(de**2)))


def star_data(f):
    X = np.column_stack([f.stars["x"], f.stars["y"]]).astype(float)
    stamps, weights, flags = f.star_stamps(normalize=False, return_weights=True)
    return X, stamps, weights, flags == 0


def galaxies(f):
    return np.column_stack([f.galaxies["x"], f.galaxies["y"]]).astype(float)


def fit_default(f):
    X, stamps, weights, keep = star_data(f)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        t0 = time.perf_counter()
        model = PSFModel().fit(X[keep], stamps[keep], weights=weights[keep])
        seconds = time.perf_counter() - t0
    return model, seconds


def psfmodel_e_rms(f):
    model, seconds = fit_default(f)
    return e_rms(model.predict(galaxies(f)), f), seconds


def worker(snr, seeds):
    """PSFModel() e_rms per seed with the sklearn_psf on the path (the previous code)."""
    with threadpool_limits(1):
        res = {str(s): psfmodel_e_rms(field(s, snr))[0] for s in seeds}
    print(json.dumps(res))


def summary(name, ratios, target=None):
    r = np.asarray(ratios)
    lo, med, hi = np.percentile(r, [16, 50, 84])
    line = f"   {name:46s} median {med:.4f}  (16-84%: {lo:.4f}-{hi:.4f})"
    if target is not None:
        met = target(med)
        line += "  -> target met" if met else "  -> target NOT met"
    print(line)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="2 simulations per S/N")
    parser.add_argument("--baseline", help="checkout of the previous code (PYTHONPATH)")
    parser.add_argument("--worker", nargs="+", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker:
        return worker(args.worker[0], [int(s) for s in args.worker[1:]])
    seeds = list(range(1, 3 if args.quick else 11))
    prev = {}
    if args.baseline:
        from _baseline import check_version, run_with

        print(f"previous code: {check_version(args.baseline)}")
    for snr in ("100", "realistic"):
        if args.baseline:
            prev = run_with(args.baseline, __file__, [snr, *seeds])
        rows = []
        with threadpool_limits(1):
            for seed in seeds:
                f = field(seed, snr)
                model, seconds = fit_default(f)
                new = e_rms(model.predict(galaxies(f)), f)  # as the previous code's worker
                ratio = oracle_e_rms_ratio(model, f)["ratio"]  # on galaxies measured in both
                rows.append((seed, new, prev.get(str(seed), np.nan), ratio, seconds))
                print(f"  S/N {snr:9s} seed {seed:2d}: PSFModel() {new:.5f} ({seconds:.1f} s), "
                      f"previous {rows[-1][2]:.5f}, PSFModel() / oracle {ratio:.4f}",
                      flush=True)
        seed, new, old, ratio, _ = map(np.array, zip(*rows))
        print(f"\nS/N {snr}: e_rms ratios over {len(seeds)} simulations (1000 stars)")
        summary("PSFModel() / oracle (target <= 1.01)", ratio, lambda m: m <= 1.01)
        if args.baseline:
            summary("previous PSFModel() / PSFModel() (target >= 1.02)", old / new,
                    lambda m: m >= 1.02)
        print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
