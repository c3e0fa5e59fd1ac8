"""Benchmark: build time and peak memory of a full-size default simulation.

Full size (the paper's): 10,032 x 7,769 pixels, 1,000 stars + 2,000 galaxy-PSFs. Requirements:
well under a minute and under 2 GB. The rendering of the PSFs into the image is compared with
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
    from sklearn_psf.simulate import make_psf_field
    from sklearn_psf.simulate._field import _render

    if args.quick:
        kw = dict(n_stars=100, n_galaxies=200, image_shape=(1500, 2000))
    else:
        kw = dict(n_stars=1000, n_galaxies=2000, image_shape=(7769, 10032))
    ref = load_default_reference()
    ok = True
    with threadpool_limits(2):
        tracemalloc.start()
        t0 = time.perf_counter()
        field = make_psf_field(ref, random_state=0, **kw)
        build = time.perf_counter() - t0
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # MB on Linux
        n = len(field.stars) + len(field.galaxies)
        print(f"make_psf_field {kw['image_shape'][1]} x {kw['image_shape'][0]} px, {n} PSFs: "
              f"{build:.2f} s, tracemalloc peak {peak / 2**20:.0f} MB, max RSS {rss:.0f} MB")
        if build > 60 or peak > 2 * 2**30:
            print("FAIL: build over a minute or over 2 GB")
            ok = False

        t0 = time.perf_counter()
        m = field.measure_stars()
        print(f"measure_stars ({len(m)} stars): {time.perf_counter() - t0:.2f} s; "
              f"measured S/N / requested: median {np.nanmedian(m['snr'] / field.stars['snr']):.3f}")
        e = np.hypot(np.concatenate([field.stars["e1"], field.galaxies["e1"]]),
                     np.concatenate([field.stars["e2"], field.galaxies["e2"]]))
        print(f"PSF ellipticity |e|: mean {e.mean():.4f}, std {e.std():.4f} (paper 0.05, 0.02)")

        # noiseless rendering: ours vs GalSim
        pos = np.vstack([np.column_stack([t["x"], t["y"]]) for t in (field.stars, field.galaxies)])
        stamps = np.vstack([np.asarray(field.stars["stamp"]), np.asarray(field.galaxies["stamp"])])
        flux = np.concatenate([field.stars["flux"], field.galaxies["flux"]])
        ours = np.zeros(kw["image_shape"], dtype=np.float32)
        t0 = time.perf_counter()
        _render(ours, pos, stamps, flux)
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
