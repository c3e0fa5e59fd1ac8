"""Benchmark: PSFEx against ``sklearn-psf fit --psfex`` through the real pipeline, with the truth.

Usage::

    python benchmarks/bench_psfex.py                  # 3 DECam-like CCDs, 2000 positions each
    python benchmarks/bench_psfex.py --n-ccds 8
    python benchmarks/bench_psfex.py --quick          # one 1024 x 1024 CCD, 500 positions

Each CCD is rendered with GalSim (:func:`sklearn_psf.simulate.render_galsim_ccd`: 2048 x 2048
pixels of 0.263", 600 stars of S/N 20-1000, 5 saturated, 1000 faint galaxies, Kolmogorov
seeing lensed by a power-spectrum shear field and field-dependent optics), catalogued by
Source Extractor with PSFEx's usual recipe (:func:`sklearn_psf.io.run_sextractor`: 35 x 35
VIGNETs, 5 apertures), then modelled from that one catalogue by

- PSFEx (``PSFVAR_KEYS XWIN_IMAGE,YWIN_IMAGE``, ``PSFVAR_DEGREES`` 2 and 3, its other settings
  its defaults: PIXEL_AUTO basis, PSF_SIZE 25,25, automatic sampling);
- ``sklearn-psf fit --stars CAT --no-plots --psfex OURS.psf`` (its defaults).

At ``--positions`` random positions of each CCD (20 pixels or more from the edges), the true
pixel-convolved PSF (``GalSimCCD.truth_stamps``, centred on the centre pixel, of our model's
side: the VIGNET's, 35 pixels) is
compared with: our full model (``PSFModel.predict``), our written ``.psf`` and PSFEx's, both
drawn by GalSim's ``DES_PSFEx`` (:class:`sklearn_psf.validation.PSFExModel`: ``no_pixel``,
unit sum, centred). Shapes are the package's adaptive moments
(:func:`sklearn_psf.measure.adaptive_moments`, GalSim HSM's algorithm, equal to
``FindAdaptiveMom`` to ~1e-8): ``e rms`` = rms of ``|e_model - e_true|`` (e = distortion),
``size rms`` = rms of ``sigma_model - sigma_true`` (pixels). The CPU seconds of each command
are those of the child processes (``resource.getrusage(RUSAGE_CHILDREN)``), one thread each
(``OMP_NUM_THREADS=1`` and the BLAS libraries' equivalents for ours, ``NTHREADS 1`` for
PSFEx and Source Extractor); ratios are ours over PSFEx's in the same run. For each CCD and
at the end, the written ``.psf``'s degree and its approximation error (its header's
``APXCV``, against the model's own uncertainty ``APXMODEL``, and ``APXE``, ``APXSIZE``).
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time

import numpy as np
from astropy.io import fits

from sklearn_psf.io import find_program, run_psfex, run_sextractor
from sklearn_psf.measure import adaptive_moments
from sklearn_psf.model import load_model
from sklearn_psf.simulate import render_galsim_ccd
from sklearn_psf.validation import PSFExModel

ONE_THREAD = {k: "1" for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
                               "NUMBA_NUM_THREADS", "VECLIB_MAXIMUM_THREADS")}


def _children_cpu():
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def timed(fn, *args, **kwargs):
    """Call ``fn`` and return (its result, CPU seconds of the processes it ran)."""
    start = _children_cpu()
    out = fn(*args, **kwargs)
    return out, _children_cpu() - start


def ours(catalog, folder, name="ours", options=()):
    """``sklearn-psf fit --stars CAT --no-plots --psfex``; its printed PSFEx line."""
    env = {**os.environ, **ONE_THREAD}
    cmd = [sys.executable, "-m", "sklearn_psf", "fit", "--stars", str(catalog), "-o",
           os.path.join(folder, f"{name}.fits"), "--no-plots", "--psfex",
           os.path.join(folder, f"{name}.psf"), *options]
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{proc.stderr[-2000:]}")
    line = [s for s in proc.stdout.splitlines() if s.startswith("PSFEx file:")]
    return line[0] if line else ""


def shapes(stamps, side):
    m = adaptive_moments(np.asarray(stamps).reshape(-1, side, side), guess_sigma=2.0)
    return np.column_stack([m["e1"], m["e2"], m["sigma"]]), np.asarray(m["flag"]) == 0


def errors(model_shapes, truth_shapes):
    (a, oka), (b, okb) = model_shapes, truth_shapes
    ok = oka & okb
    de = np.hypot(a[ok, 0] - b[ok, 0], a[ok, 1] - b[ok, 1])
    ds = a[ok, 2] - b[ok, 2]
    return float(np.sqrt(np.mean(de**2))), float(np.sqrt(np.mean(ds**2))), int((~ok).sum())


def one_ccd(seed, args, folder):
    t0 = time.time()
    kw = dict(shape=(1024, 1024), n_stars=150, n_galaxies=250) if args.quick else {}
    ccd = render_galsim_ccd(random_state=seed, **kw)
    image = ccd.write(folder)
    t_render = time.time() - t0
    catalog, cpu_sex = timed(run_sextractor, image, os.path.join(folder, "ccd.ldac"),
                             weight_path=ccd.weight_path(image), config={"NTHREADS": 1})
    cpu, files = {"Source Extractor": cpu_sex}, {}
    for degree in (2, 3):
        name = f"PSFEx d{degree}"
        files[name], cpu[name] = timed(
            run_psfex, catalog, os.path.join(folder, f"psfex{degree}"),
            config={"PSFVAR_DEGREES": degree, "NTHREADS": 1,
                    "PSFVAR_KEYS": "XWIN_IMAGE,YWIN_IMAGE"})
    line, cpu["ours"] = timed(ours, catalog, folder)
    variants = {f"ours {v}": ours(catalog, folder, f"ours{k}", v.split())
                for k, v in enumerate(args.variant)}

    rng = np.random.default_rng(seed)
    ny, nx = ccd.image.shape
    X = np.column_stack([rng.uniform(20, nx - 21, args.positions),
                         rng.uniform(20, ny - 21, args.positions)])
    model = load_model(os.path.join(folder, "ours.fits"))
    side = model.stamp_size_      # every model drawn on stamps of our model's side
    t1 = time.time()
    truth = shapes(ccd.truth_stamps(X[:, 0], X[:, 1], stamp_size=side), side)
    t_truth = time.time() - t1
    acc = {"ours (full model)": errors(shapes(model.predict(X), side), truth),
           "ours (.psf, DES_PSFEx)": errors(shapes(
               PSFExModel(os.path.join(folder, "ours.psf"), side).predict(X), side), truth)}
    for k, name in enumerate(variants):
        variant = load_model(os.path.join(folder, f"ours{k}.fits"))
        acc[f"{name} (full model)"] = errors(shapes(variant.predict(X), side), truth)
        acc[f"{name} (.psf)"] = errors(shapes(
            PSFExModel(os.path.join(folder, f"ours{k}.psf"), side).predict(X), side), truth)
    for name, path in files.items():
        acc[f"{name} (.psf, DES_PSFEx)"] = errors(
            shapes(PSFExModel(path, side).predict(X), side), truth)
    ours_h = fits.getheader(os.path.join(folder, "ours.psf"), "PSF_DATA")
    written = {k: ours_h.get(k) for k in ("POLDEG1", "APXCV", "APXMODEL", "APXPIX", "APXE",
                                          "APXSIZE")}
    h = fits.getheader(files["PSFEx d2"], "PSF_DATA")
    print(f"CCD seed {seed}: {len(ccd.stars)} stars, {len(ccd.galaxies)} galaxies "
          f"(rendered in {t_render:.0f} s, truth at {len(X)} positions in {t_truth:.0f} s); "
          f"PSFEx accepted {h['ACCEPTED']} of {h['LOADED']}, PSF_SAMP {h['PSF_SAMP']:.2f}")
    print(f"  ours: {line}")
    for name, text in variants.items():
        print(f"  {name}: {text}")
    return acc, cpu, written


def degree_text(w):
    """The written .psf's degree and its approximation error (from its header)."""
    model = "" if w["APXMODEL"] is None else f" (model's own {w['APXMODEL']:.2e})"
    return (f"degree {w['POLDEG1']}, approximation error {w['APXCV']:.2e} of the peak"
            f"{model}, e {w['APXE']:.4f}, size {w['APXSIZE']:.4f} px against the full model")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n-ccds", type=int, default=3)
    parser.add_argument("--positions", type=int, default=2000)
    parser.add_argument("--seed", type=int, default=100)
    parser.add_argument("--quick", action="store_true", help="one 1024 x 1024 CCD")
    parser.add_argument("--keep", metavar="FOLDER", help="keep the files in FOLDER")
    parser.add_argument("--variant", action="append", default=[], metavar="OPTIONS",
                        help="also fit ours with these fit options (e.g. '--reserve 0 "
                        "--isolation 12'), accuracy only; repeatable")
    args = parser.parse_args(argv)
    if args.quick:
        args.n_ccds, args.positions = 1, min(args.positions, 500)
    for program in ("source-extractor", "psfex"):
        if find_program(program) is None:
            sys.exit(f"{program} is not installed (apt-get install source-extractor psfex)")
    accs, cpus, degrees = [], [], []
    with tempfile.TemporaryDirectory(prefix="bench_psfex_") as tmp:
        for i in range(args.n_ccds):
            folder = os.path.join(args.keep or tmp, f"ccd{i}")
            os.makedirs(folder, exist_ok=True)
            acc, cpu, written = one_ccd(args.seed + i, args, folder)
            accs.append(acc)
            cpus.append(cpu)
            degrees.append(written)
            print(f"  written .psf: {degree_text(written)}")
            for name, (e, s, nf) in acc.items():
                print(f"  {name:40s} e rms {e:.4f}  size rms {s:.4f} px"
                      + (f"  ({nf} moments failed)" if nf else ""))
            print("  CPU s: " + ", ".join(f"{k} {v:.2f}" for k, v in cpu.items()))
    n = len(accs)
    print(f"\nMean over {n} CCD(s), {args.positions} positions each (e rms, size rms in pixels; "
          "per-CCD rms averaged):")
    for name in accs[0]:
        e = np.mean([a[name][0] for a in accs])
        s = np.mean([a[name][1] for a in accs])
        print(f"  {name:40s} e rms {e:.4f}  size rms {s:.4f}")
    for i, w in enumerate(degrees):
        print(f"  CCD seed {args.seed + i}: written .psf {degree_text(w)}")
    ref = {k: np.mean([a[k][:2] for a in accs], axis=0) for k in accs[0]}
    for d in (2, 3):
        p = ref[f"PSFEx d{d} (.psf, DES_PSFEx)"]
        print(f"  ours .psf / PSFEx d{d}: e rms x{ref['ours (.psf, DES_PSFEx)'][0] / p[0]:.2f}, "
              f"size rms x{ref['ours (.psf, DES_PSFEx)'][1] / p[1]:.2f}; full model / PSFEx "
              f"d{d}: e rms x{ref['ours (full model)'][0] / p[0]:.2f}, size rms "
              f"x{ref['ours (full model)'][1] / p[1]:.2f}")
    mean_cpu = {k: np.mean([c[k] for c in cpus]) for k in cpus[0]}
    print("CPU seconds per CCD (one thread each): " + ", ".join(
        f"{k} {v:.2f}" for k, v in mean_cpu.items()))
    for d in (2, 3):
        print(f"  ours / PSFEx d{d}: x{mean_cpu['ours'] / mean_cpu[f'PSFEx d{d}']:.2f}")


if __name__ == "__main__":
    main()
