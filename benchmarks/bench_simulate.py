"""Benchmark: build time and peak memory of a full-size default simulation.

Full size (the paper's): 10,032 x 7,769 pixels, 1,000 stars + 2,000 galaxy-PSFs, built twice:
the default (clean, sub-pixel positions) and "as real data" (5% of the stars with each kind of
contaminant, 200 cosmic rays and 200 galaxies elsewhere, 1e-4 bad pixels, 3 bad columns,
saturation, Poisson noise: a weight map). Requirements: each well under a minute and under
2 GB. The rendering of the PSFs into the image (at their nearest pixels) is compared with
GalSim (the same stamps added with ``galsim.Image`` bounds arithmetic): same pixels, timing
ratio printed. Exit code 1 if a requirement or the comparison fails.

    python benchmarks/bench_simulate.py            # full size
    python benchmarks/bench_simulate.py --quick    # 2000 x 1500, 300 PSFs
"""

import argparse
import resource
import sys
import time
import tracemalloc

import numpy as np
from threadpoolctl import threadpool_limits


def galsim_render(shape, positions, stamps, flux):
    import galsim

    ny, nx = shape
    image = galsim.ImageF(nx, ny, xmin=0, ymin=0)
    s = int(round(np.sqrt(stamps.shape[1])))
    h = s // 2
    for (x, y), st, f in zip(positions.astype(int), stamps, flux):
        b = galsim.BoundsI(x - h, x + h, y - h, y + h)
        image[b] += galsim.ImageF((st * f).reshape(s, s).astype(np.float32), xmin=x - h,
                                  ymin=y - h)
    return image.array


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--quick", action="store_true")
    args = p.parse_args(argv)
    from sklearn_psf.datasets import load_default_reference
    from sklearn_psf.simulate import ContaminantSettings, DetectorSettings, make_psf_field
    from sklearn_psf.simulate._contaminants import render

    if args.quick:
        kw = dict(n_stars=100, n_galaxies=200, image_shape=(1500, 2000))
    else:
        kw = dict(n_stars=1000, n_galaxies=2000, image_shape=(7769, 10032))
    ref = load_default_reference()
    n_field = 20 if args.quick else 200
    fractions = {k: 0.05 for k in ("cosmic_ray", "neighbour", "galaxy", "binary")}
    real = dict(contaminants=ContaminantSettings(fractions, n_field_cosmic_rays=n_field,
                                                 n_field_galaxies=n_field),
                detector=DetectorSettings(masked_fraction=1e-4, bad_columns=3, saturation=5e4,
                                          gain=2.0))
    ok = True
    fields = {}
    with threadpool_limits(2):
        make_psf_field(ref, n_stars=20, n_galaxies=5, image_shape=(500, 500), random_state=0,
                       contaminants=fractions)  # warm-up: imports, compiled kernels
        for label, extra in (("default", {}), ("as real data", real)):
            t0 = time.perf_counter()
            field = make_psf_field(ref, random_state=0, **kw, **extra)
            build = time.perf_counter() - t0
            del field  # the peak memory of a second build, traced (tracemalloc slows it)
            tracemalloc.start()
            field = make_psf_field(ref, random_state=0, **kw, **extra)
            _, peak = tracemalloc.get_traced_memory()
            tracemalloc.stop()
            n = len(field.stars) + len(field.galaxies)
            print(f"make_psf_field ({label}) {kw['image_shape'][1]} x {kw['image_shape'][0]} "
                  f"px, {n} PSFs: {build:.2f} s, tracemalloc peak {peak / 2**20:.0f} MB")
            if build > 60 or peak > 2 * 2**30:
                print("FAIL: build over a minute or over 2 GB")
                ok = False
            fields[label] = field
        field = fields["default"]
        rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # MB on Linux
        print(f"max RSS of the process (both fields held): {rss:.0f} MB")

        t0 = time.perf_counter()
        m = field.measure_stars()
        print(f"measure_stars ({len(m)} stars): {time.perf_counter() - t0:.2f} s; "
              f"measured S/N / requested: median {np.nanmedian(m['snr'] / field.stars['snr']):.3f}")
        e = np.hypot(np.concatenate([field.stars["e1"], field.galaxies["e1"]]),
                     np.concatenate([field.stars["e2"], field.galaxies["e2"]]))
        print(f"PSF ellipticity |e|: mean {e.mean():.4f}, std {e.std():.4f} (paper 0.05, 0.02)")

        # noiseless rendering: ours vs GalSim
        pos = np.floor(np.vstack([np.column_stack([t["x"], t["y"]])
                                  for t in (field.stars, field.galaxies)]) + 0.5)
        stamps = np.vstack([np.asarray(field.stars["stamp"]), np.asarray(field.galaxies["stamp"])])
        flux = np.concatenate([field.stars["flux"], field.galaxies["flux"]])
        ours = np.zeros(kw["image_shape"], dtype=np.float32)
        t0 = time.perf_counter()
        render(ours, pos, stamps, flux)
        t_ours = time.perf_counter() - t0
        t0 = time.perf_counter()
        theirs = galsim_render(kw["image_shape"], pos, stamps, flux)
        t_gs = time.perf_counter() - t0
        diff = np.abs(ours - theirs).max() / np.abs(theirs).max()
        print(f"render {n} stamps: ours {t_ours:.3f} s, GalSim {t_gs:.3f} s, "
              f"ratio {t_ours / t_gs:.2f}; max relative difference {diff:.2e}")
        if diff > 1e-6:
            print("FAIL: rendering differs from GalSim")
            ok = False
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
