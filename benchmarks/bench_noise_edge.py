"""Benchmark: StampPCA's noise edge on pure noise and on the default field.

1. Pure noise: 1000 stars of one PSF (the default reference's mean at random sub-pixel
   offsets, unit background noise) at the realistic S/N mix (20-1000) and at S/N 100, seeds
   0-9: the largest eigenvalue over the noise edge must lie in 0.95-1.0.
2. The default simulated field (1000 stars on 10,032 x 7,769 pixels) at the realistic S/N
   mix, seeds 1-10 (raw stamps with their weight map): the basis must keep exactly the
   reference's 5 components; printed with the 5th and 6th eigenvalues over the edge and the
   smallest principal cosine between the kept and the reference's components. Also S/N 100
   and 1e4 (where the noiseless stamps' two shift modes are above the noise: 7 expected).

Usage::

    python benchmarks/bench_noise_edge.py [--quick]
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np
from threadpoolctl import threadpool_limits

from sklearn_psf.datasets import load_default_reference
from sklearn_psf.preprocessing import StampPCA, fourier_shift
from sklearn_psf.simulate import core_mask, make_psf_field, realistic_snr


def one_psf_stars(snr, seed):
    rng = np.random.default_rng(seed)
    mean = load_default_reference().mean
    s = mean.shape[0]
    flux = snr / mean.ravel()[core_mask(mean.reshape(1, -1))[0]].mean()
    off = rng.uniform(-0.5, 0.5, (len(snr), 2))
    stars = fourier_shift(np.broadcast_to(mean, (len(snr), s, s)), off[:, 0], off[:, 1])
    return stars.reshape(len(snr), -1) * flux[:, None] + rng.standard_normal((len(snr), s * s))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="2 seeds")
    args = parser.parse_args(argv)
    n_seeds = 2 if args.quick else 10
    failed = []
    with threadpool_limits(1):
        print("1. one PSF (pure noise), 1000 stars: largest eigenvalue / noise edge")
        for mix in ("realistic", "100"):
            tops = []
            for seed in range(n_seeds):
                snr = (realistic_snr(1000, random_state=seed) if mix == "realistic"
                       else np.full(1000, 100.0))
                stamps = one_psf_stars(snr, seed)
                basis = StampPCA().fit(stamps, weights=np.ones_like(stamps))
                tops.append(basis.explained_variance_[0] / basis.noise_edge_)
            tops = np.array(tops)
            ok = bool(np.all((tops >= 0.95) & (tops <= 1.0)))
            failed += [] if ok else [f"pure noise {mix}"]
            print(f"   S/N {mix:>9}: median {np.median(tops):.3f}, range {tops.min():.3f}-"
                  f"{tops.max():.3f}  {'met' if ok else 'NOT met'} (0.95-1.0)")
        print("2. default field, 1000 stars: components kept")
        for mix, expected in (("realistic", 5), ("100", 5), ("10000", 7)):
            print(f"   S/N {mix}")
            for seed in range(1, n_seeds + 1):
                start = time.perf_counter()
                snr = (realistic_snr(1000, random_state=seed) if mix == "realistic"
                       else float(mix))
                f = make_psf_field(n_galaxies=0, snr=snr, random_state=seed)
                raw, w, _ = f.star_stamps(normalize=False, return_weights=True)
                basis = StampPCA().fit(raw, weights=w)
                lam = basis.explained_variance_ / basis.noise_edge_
                k = basis.n_components_
                cos = np.linalg.svd(basis.components_[:5] @ f.reference.components.reshape(
                    5, -1).T, compute_uv=False).min()
                ok = k == expected
                failed += [] if ok else [f"seed {seed} at S/N {mix}: {k} components"]
                print(f"     seed {seed:2d}: {k} components (expected {expected}); eigenvalue /"
                      f" edge 5th {lam[4]:.3f}, 6th {lam[5]:.3f}, 8th {lam[7]:.3f}; smallest "
                      f"principal cosine with the reference {cos:.3f} "
                      f"({time.perf_counter() - start:.1f} s)")
    if failed:
        print(f"NOT met: {failed}")
        return 1
    print("met")
    return 0


if __name__ == "__main__":
    sys.exit(main())
