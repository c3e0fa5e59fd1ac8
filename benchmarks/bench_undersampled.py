"""Undersampled stars: `sklearn-psf fit` against PSFEx on a Euclid-VIS-like GalSim CCD.

The CCD (:func:`sklearn_psf.simulate.render_galsim_ccd`): 2048 x 2048 pixels of 0.1",
``galsim.OpticalPSF`` at 700 nm through 1.2 m (obscuration 0.3) with defocus, astigmatism,
coma and trefoil varying over the chip (constant on a 6 x 6 grid of cells), 0.025" jitter:
pixel-convolved FWHM ~1.5 px; stars at random sub-pixel positions, S/N 30-1000, galaxies,
saturated stars. Source Extractor catalogues it (25 x 25 VIGNETs); each tool fits the same
catalogue: ``sklearn-psf fit --stars cat.ldac --no-plots`` (its defaults: the super-resolved
basis for these stars) and PSFEx 3.21 with ``PSF_SAMPLING`` automatic and 0.5 (degree 2).

Accuracy at the truth: 2000 random positions, each model's stamp and the true PSF at native
sampling, phase 0 (the true PSF's adaptive centroid, measured on its pixel-convolved profile
sampled every half pixel, on the centre pixel; each model at its own centre), measured with
fixed-weight moments (:func:`sklearn_psf.measure.fixed_moments`, sigma 1.5 px): e rms
(sqrt <de1^2 + de2^2>), size rms and size bias (relative, of det(M)^(1/4)). CPU: user + system
time of each command (child processes), one thread each.

Run: ``python benchmarks/bench_undersampled.py [--seed 3] [--n-stars 600]`` (~5 min).
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def _cpu():
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _psf_factory(n):
    import galsim

    cache = {}

    def psf(x, y):
        i, j = min(int(6 * x / n), 5), min(int(6 * y / n), 5)
        if (i, j) not in cache:
            u, v = (i + 0.5) / 6 - 0.5, (j + 0.5) / 6 - 0.5
            ab = [0, 0, 0, 0, 0.03 + 0.04 * (u * u + v * v), 0.04 * u, 0.04 * v, 0.03 * u,
                  -0.03 * v, 0.01, 0, 0.02]
            cache[i, j] = galsim.Convolve(
                galsim.OpticalPSF(lam=700.0, diam=1.2, obscuration=0.3, aberrations=ab,
                                  scale_unit=galsim.arcsec), galsim.Gaussian(sigma=0.025))
        return cache[i, j]
    return psf


def _truth(psf, P, side, scale):
    import galsim

    out = np.empty((len(P), side, side))
    for k, (x, y) in enumerate(P):
        prof = psf(x, y)
        fine = galsim.Convolve(prof, galsim.Pixel(scale)).drawImage(
            nx=51, ny=51, scale=scale / 2, method="no_pixel")
        c = (galsim.hsm.FindAdaptiveMom(fine).moments_centroid - fine.true_center) / 2
        out[k] = prof.drawImage(nx=side, ny=side, scale=scale, offset=(-c.x, -c.y)).array
    return out


def _scores(stamps, truth):
    from sklearn_psf.measure import fixed_moments

    side = truth.shape[-1]
    mt = fixed_moments(truth, 1.5)
    mp = fixed_moments(np.asarray(stamps).reshape(-1, side, side), 1.5)
    ok = (np.asarray(mt["flag"]) == 0) & (np.asarray(mp["flag"]) == 0)
    de = np.hypot(np.asarray(mp["e1"]) - mt["e1"], np.asarray(mp["e2"]) - mt["e2"])[ok]
    ds = ((np.asarray(mp["sigma"]) - mt["sigma"]) / np.asarray(mt["sigma"]))[ok]
    return float(np.sqrt(np.mean(de**2))), float(np.sqrt(np.mean(ds**2))), float(ds.mean())


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--n-stars", type=int, default=600)
    parser.add_argument("--size", type=int, default=2048)
    parser.add_argument("--n-truth", type=int, default=2000)
    args = parser.parse_args(argv)
    from astropy.io import fits

    from sklearn_psf.io import run_psfex, run_sextractor
    from sklearn_psf.model import load_model
    from sklearn_psf.simulate import render_galsim_ccd
    from sklearn_psf.validation import PSFExModel

    n, side, scale = args.size, 25, 0.1
    psf = _psf_factory(n)
    work = Path(tempfile.mkdtemp(prefix="bench_undersampled_"))
    t = time.time()
    ccd = render_galsim_ccd(shape=(n, n), pixel_scale=scale, n_stars=args.n_stars,
                            n_galaxies=args.n_stars, psf=psf, snr_range=(30.0, 1000.0),
                            random_state=args.seed)
    image = ccd.write(work, overwrite=True)
    cat = run_sextractor(image, work / "cat.ldac", weight_path=ccd.weight_path(image),
                         vignet=(side, side), overwrite=True)
    print(f"CCD {n}x{n} at {scale}\"/px, {len(ccd.stars)} stars: rendered and catalogued in "
          f"{time.time() - t:.0f} s ({work})")
    rng = np.random.default_rng(args.seed + 1)
    P = rng.uniform(0, n - 1, (args.n_truth, 2))
    truth = _truth(psf, P, side, scale)
    rows = []

    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1",
           "MKL_NUM_THREADS": "1"}
    cpu = _cpu()
    out = subprocess.run([sys.executable, "-m", "sklearn_psf", "fit", "--stars", str(cat),
                          "-o", str(work / "ours.fits"), "--no-plots", "--overwrite"],
                         capture_output=True, text=True, env=env, check=True)
    cpu = _cpu() - cpu
    model = load_model(work / "ours.fits")
    used = int(model.inlier_mask_.sum())
    report = [line for line in out.stdout.splitlines() if "reserved stars" in line]
    rows.append(("sklearn-psf fit", *_scores(model.predict(P), truth), used, cpu))
    for sampling in (0.0, 0.5):
        cpu = _cpu()
        folder = work / f"psfex_{sampling}"
        path = run_psfex(cat, folder, config={"PSF_SAMPLING": sampling, "PSF_SIZE": "41,41",
                                              "PSFVAR_DEGREES": 2, "NTHREADS": 1},
                         overwrite=True)
        cpu = _cpu() - cpu
        with fits.open(path) as hdul:
            head = hdul[1].header
            used = int(head.get("ACCEPTED", -1))
            actual = float(head.get("PSF_SAMP", sampling))
        pred = PSFExModel(path, stamp_size=side).predict(P)
        name = f"PSFEx PSF_SAMPLING {'auto' if not sampling else sampling} ({actual:.2f})"
        rows.append((name, *_scores(pred, truth), used, cpu))
    print(f"\naccuracy at the truth ({args.n_truth} positions, fixed-weight moments sigma "
          "1.5 px, native sampling, phase 0)")
    print(f"{'model':<38} {'e rms':>8} {'size rms':>9} {'size bias':>10} {'stars':>6} "
          f"{'CPU s':>6}")
    for name, e, s, b, used, c in rows:
        print(f"{name:<38} {e:8.4f} {s:9.4f} {b:+10.4f} {used:6d} {c:6.1f}")
    best = min(rows[1:], key=lambda r: r[1])
    print(f"\nours / best PSFEx ({best[0]}): e rms {rows[0][1] / best[1]:.2f}x, size rms "
          f"{rows[0][2] / min(r[2] for r in rows[1:]):.2f}x")
    print("our verdict lines:\n  " + "\n  ".join(report))


if __name__ == "__main__":
    main()
