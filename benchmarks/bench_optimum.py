"""Benchmark: PSFModel() against the optimum of the same simulated field.

The optimum (oracle) is the best linear unbiased predictor of all the reference-basis
coefficients jointly, with the simulation's true signal covariance
(``PSFField.weight_covariance``: independent components of one correlation shape) and each
star's full noise covariance across components. Its measurement is the best the package
makes: each star's raw stamp fitted by weighted least squares on the reference basis with
its pixel weights (``StampPCA.project`` with the reference's mean and components), whose
noise covariance follows from the pixel weights through the flux normalisation (delta
method). Each component's mean is unknown (generalised least squares). The dense system
(n_stars x n_components square) is solved with numpy.

For each simulation of the default field (1000 stars, 2000 galaxy-PSFs, 10,032 x 7,769 px)
at S/N 100 and at the realistic S/N mix (20-1000), ``e_rms`` is the rms over the
galaxy-PSFs of |e_model - e_true| (adaptive moments of the predicted, normalised stamps).
Printed, with the median and the 16th-84th percentiles over the simulations:

- PSFModel() / oracle (target: median <= 1.01);
- previous PSFModel() / PSFModel(), paired on the same simulations (with ``--baseline PATH``,
  a checkout of the previous code run in a subprocess; target: median >= 1.02);
- the oracle of each component on its own (the study's previous oracle, noise variances
  only) / the joint oracle.

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
from scipy.linalg import LinAlgError, cho_factor, cho_solve
from threadpoolctl import threadpool_limits

from sklearn_psf import PSFModel, adaptive_moments, make_psf_field
from sklearn_psf.preprocessing import StampPCA
from sklearn_psf.simulate import realistic_snr

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


def psfmodel_e_rms(f):
    X, stamps, weights, keep = star_data(f)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        t0 = time.perf_counter()
        model = PSFModel().fit(X[keep], stamps[keep], weights=weights[keep])
        seconds = time.perf_counter() - t0
    return e_rms(model.predict(galaxies(f)), f), seconds


def reference_projector(f):
    """StampPCA holding the simulation's reference basis: its ``project`` is the weighted
    least-squares fit of raw stamps on that basis, with the coefficients' covariance."""
    ref = f.reference
    k = ref.n_components
    proj = StampPCA()
    proj.mean_ = np.asarray(ref.mean, float).reshape(-1)
    proj.components_ = np.asarray(ref.components, float).reshape(k, -1)
    proj.n_components_, proj.stamp_size_ = k, f.stamp_size
    proj.n_features_in_ = proj.mean_.size
    proj._n_features_out = k
    return proj


def _factor(K):
    jitter = 1e-10 * float(np.mean(np.diag(K)))
    try:
        return cho_factor(K + jitter * np.eye(len(K)), lower=True)
    except LinAlgError:  # a tabulated covariance of close stars can be slightly indefinite
        w, V = np.linalg.eigh(K)
        return cho_factor((V * np.clip(w, jitter, None)) @ V.T, lower=True)


def oracle_e_rms(f):
    """e_rms of the joint oracle and of the per-component one (noise variances only)."""
    X, stamps, weights, keep = star_data(f)
    proj = reference_projector(f)
    fit = proj.project(stamps[keep], weights[keep])
    good = fit.flag == 0
    X, C, S = X[keep][good], fit.coefficients[good], fit.coefficient_cov[good]
    n, k = C.shape
    signal = f.weight_covariance(X)  # (k, n, n)
    cross = f.weight_covariance(galaxies(f), X)  # (k, m, n)
    out = []
    for joint in (True, False):
        K = np.zeros((n * k, n * k))
        for t in range(k):
            K[t * n:(t + 1) * n, t * n:(t + 1) * n] = signal[t]
        idx = np.arange(k)[None, :] * n + np.arange(n)[:, None]  # (n, k): row of (i, t)
        noise = S if joint else S * np.eye(k)[None]
        K[idx[:, :, None], idx[:, None, :]] += noise
        L = _factor(K)
        F = np.kron(np.eye(k), np.ones((n, 1)))
        y = C.T.reshape(-1)
        KiF, Kiy = cho_solve(L, F), cho_solve(L, y)
        beta = np.linalg.solve(F.T @ KiF, F.T @ Kiy)
        alpha = (Kiy - KiF @ beta).reshape(k, n)
        pred = beta[None, :] + np.einsum("tmn,tn->mt", cross, alpha)
        out.append(e_rms(proj.inverse_transform(pred), f))
    return out


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
                new, seconds = psfmodel_e_rms(f)
                joint, single = oracle_e_rms(f)
                rows.append((seed, new, prev.get(str(seed), np.nan), joint, single, seconds))
                print(f"  S/N {snr:9s} seed {seed:2d}: PSFModel() {new:.5f} ({seconds:.1f} s), "
                      f"previous {rows[-1][2]:.5f}, joint oracle {joint:.5f}, "
                      f"per-component oracle {single:.5f}", flush=True)
        seed, new, old, joint, single, _ = map(np.array, zip(*rows))
        print(f"\nS/N {snr}: e_rms ratios over {len(seeds)} simulations (1000 stars)")
        summary("PSFModel() / joint oracle (target <= 1.01)", new / joint, lambda m: m <= 1.01)
        if args.baseline:
            summary("previous PSFModel() / PSFModel() (target >= 1.02)", old / new,
                    lambda m: m >= 1.02)
            summary("previous PSFModel() / joint oracle", old / joint)
        summary("per-component oracle / joint oracle", single / joint)
        print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
