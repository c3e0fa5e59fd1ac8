"""Benchmark: PSFEx against ``sklearn-psf fit --psfex`` through the real pipeline, with the truth.

Usage::

    python benchmarks/bench_psfex.py                  # 3 DECam-like CCDs, 2000 positions each
    python benchmarks/bench_psfex.py --n-ccds 8
    python benchmarks/bench_psfex.py --many           # 16 CCDs: CPU of one command over all
    python benchmarks/bench_psfex.py --quick          # one 1024 x 1024 CCD, 500 positions

Each CCD is rendered with GalSim (:func:`sklearn_psf.simulate.render_galsim_ccd`: 2048 x 2048
pixels of 0.263", 600 stars of S/N 20-1000, 5 saturated, 1000 faint galaxies, Kolmogorov
seeing lensed by a power-spectrum shear field and field-dependent optics), catalogued by
Source Extractor with PSFEx's usual recipe (:func:`sklearn_psf.io.run_sextractor`: 35 x 35
VIGNETs, 5 apertures), then modelled from that one catalogue by

- PSFEx (``PSFVAR_KEYS XWIN_IMAGE,YWIN_IMAGE``, ``PSFVAR_DEGREES`` 2 and 3, its other settings
  its defaults: PIXEL_AUTO basis, PSF_SIZE 25,25, automatic sampling);
- ``sklearn-psf fit --stars CAT --no-plots`` (its defaults), timed, on each of the first
  ``--single`` CCDs alone (a single-CCD command), and again with ``--psfex OURS.psf`` (untimed)
  for the accuracy of the written ``.psf`` (run first: the timed command finds numba's
  cache written; the package's bytecode is compiled beforehand, as ``pip install`` does);
- with ``--many`` (default 16 CCDs): one command ``sklearn-psf fit --stars CAT1 ... CATN
  --no-plots`` over all the catalogues, with ``--n-jobs 1`` and ``--n-jobs 2``: its CPU per
  CCD against PSFEx's, and the CPU an extra worker costs (``--n-jobs 2`` minus ``--n-jobs
  1``); the two runs' models must predict the same stamps.

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
PSFEx and Source Extractor); ratios are ours over PSFEx's in the same run, with issue 32's
targets (16-CCD command within 1.5x PSFEx's CPU per CCD, single-CCD command within 3x, an
extra worker at most 0.5 s of CPU) printed as met / NOT met; the single-CCD figure is split
into the process's start (a process that only imports what a fit imports and makes numba's
first call) and the rest. ``--cache FOLDER`` keeps the
rendered CCDs (images and pickled truth) in FOLDER and reuses them in later runs (Source
Extractor, PSFEx and ours always run).
"""

from __future__ import annotations

import argparse
import os
import pickle
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

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


def ours(catalogs, folder, name="ours", options=(), psf_file=False):
    """``sklearn-psf fit --stars CAT [CAT ...] --no-plots [--psfex]``; its printed PSFEx line.

    One catalogue: the model is ``folder/name.fits``; several: ``folder/name_<catalogue>.fits``.
    """
    env = {**os.environ, **ONE_THREAD}
    catalogs = [os.path.abspath(str(c)) for c in np.atleast_1d(catalogs)]
    folder = os.path.abspath(folder)
    cmd = [sys.executable, "-m", "sklearn_psf", "fit", "--stars", *catalogs, "-o",
           os.path.join(folder, f"{name}.fits"), "--no-plots", "--overwrite", *options]
    if psf_file:
        cmd += ["--psfex", os.path.join(folder, f"{name}.psf")]
    # run in ``folder``: ``python -m`` puts the working directory first on ``sys.path``,
    # where a checkout's own package would hide a baseline's (``PYTHONPATH``)
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, cwd=folder)
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


def compile_bytecode():
    """Compile sklearn_psf's bytecode, as ``pip install`` does: an editable install run with
    ``PYTHONDONTWRITEBYTECODE`` (as on the CI machine) would otherwise compile its ~70
    modules in every command, ~0.15 s of CPU that an installed package does not spend."""
    import compileall

    import sklearn_psf

    compileall.compile_dir(os.path.dirname(sklearn_psf.__file__), quiet=1)


def cached_ccd(seed, quick, cache, folder):
    """(ccd, image path, its folder): the DECam-like CCD of ``seed`` rendered, or read from
    the cache folder when it is there."""
    kw = dict(shape=(1024, 1024), n_stars=150, n_galaxies=250) if quick else {}
    cached = Path(cache or folder) / f"ccd{seed}{'_quick' if quick else ''}"
    cached.mkdir(parents=True, exist_ok=True)
    if (cached / "ccd.pkl").exists():
        with open(cached / "ccd.pkl", "rb") as f:
            return pickle.load(f), cached / "ccd.fits", cached
    ccd = render_galsim_ccd(random_state=seed, **kw)
    image = ccd.write(cached, overwrite=True)
    with open(cached / "ccd.pkl", "wb") as f:
        pickle.dump(ccd, f)
    return ccd, image, cached


def prepare(seed, args, folder):
    """The rendered CCD (from the cache when there), its Source Extractor catalogue and PSFEx's
    models of it; the CPU seconds of Source Extractor and PSFEx."""
    t0 = time.time()
    ccd, image, cached = cached_ccd(seed, args.quick, args.cache, folder)
    t_render = time.time() - t0
    catalog, cpu_sex = timed(run_sextractor, image, os.path.join(folder, f"ccd{seed}.ldac"),
                             weight_path=ccd.weight_path(image), config={"NTHREADS": 1},
                             overwrite=True)
    cpu, files = {"Source Extractor": cpu_sex}, {}
    for degree in (2, 3):
        name = f"PSFEx d{degree}"
        files[name], cpu[name] = timed(
            run_psfex, catalog, os.path.join(folder, f"psfex{degree}"),
            config={"PSFVAR_DEGREES": degree, "NTHREADS": 1,
                    "PSFVAR_KEYS": "XWIN_IMAGE,YWIN_IMAGE"}, overwrite=True)
    h = fits.getheader(files["PSFEx d2"], "PSF_DATA")
    print(f"CCD seed {seed}: {len(ccd.stars)} stars, {len(ccd.galaxies)} galaxies "
          f"({'loaded' if t_render < 5 else 'rendered'} in {t_render:.0f} s); PSFEx accepted "
          f"{h['ACCEPTED']} of {h['LOADED']}, PSF_SAMP {h['PSF_SAMP']:.2f}", flush=True)
    return ccd, catalog, files, cpu


def accuracy(ccd, seed, args, models, psf_files):
    """(e rms, size rms, failed moments) at the truth of each model file and ``.psf``."""
    rng = np.random.default_rng(seed)
    ny, nx = ccd.image.shape
    X = np.column_stack([rng.uniform(20, nx - 21, args.positions),
                         rng.uniform(20, ny - 21, args.positions)])
    loaded = {name: load_model(path) for name, path in models.items()}
    side = next(iter(loaded.values())).stamp_size_  # every model drawn on our model's side
    truth = shapes(ccd.truth_stamps(X[:, 0], X[:, 1], stamp_size=side), side)
    acc = {name: errors(shapes(model.predict(X), side), truth)
           for name, model in loaded.items()}
    for name, path in psf_files.items():
        acc[name] = errors(shapes(PSFExModel(path, side).predict(X), side), truth)
    return acc


def single(seed, ccd, catalog, files, args, folder):
    """Our single-CCD command on ``catalog`` (timed), its ``.psf`` and the variants
    (untimed); the accuracy of all and of PSFEx's models."""
    line = ours(catalog, folder, "ours_psf", psf_file=True)  # (first: numba's cache written)
    _, cpu = timed(ours, catalog, folder)
    variants = {f"ours {v}": ours(catalog, folder, f"ours{k}", v.split(), psf_file=True)
                for k, v in enumerate(args.variant)}
    models = {"ours (full model)": os.path.join(folder, "ours.fits")}
    psf_files = {"ours (.psf, DES_PSFEx)": os.path.join(folder, "ours_psf.psf")}
    for k, name in enumerate(variants):
        models[f"{name} (full model)"] = os.path.join(folder, f"ours{k}.fits")
        psf_files[f"{name} (.psf)"] = os.path.join(folder, f"ours{k}.psf")
    psf_files.update({f"{name} (.psf, DES_PSFEx)": path for name, path in files.items()})
    acc = accuracy(ccd, seed, args, models, psf_files)
    ours_h = fits.getheader(os.path.join(folder, "ours_psf.psf"), "PSF_DATA")
    written = {k: ours_h.get(k) for k in ("POLDEG1", "APXCV", "APXMODEL", "APXPIX", "APXE",
                                          "APXSIZE")}
    print(f"  ours: {line}")
    for name, text in variants.items():
        print(f"  {name}: {text}")
    return acc, cpu, written


def startup_cpu(repeats=3):
    """CPU seconds of a process that only starts as `fit` does: the imports of a fit and
    numba's first call (``prepare_workers``), median of ``repeats``: the part of a single-CCD
    command that does not depend on the catalogue."""
    code = ("import gc; gc.set_threshold(10_000, 10, 10); "  # as the command's process
            "from sklearn_psf.cli import _import_sklearn_without_pandas, _tune_malloc; "
            "_tune_malloc(); _import_sklearn_without_pandas(); "
            "from sklearn_psf.cli._parallel import prepare_workers; "
            "prepare_workers('sklearn_psf.validation', 'treecorr', 'sklearn_psf.io', "
            "'sklearn_psf.model', 'tqdm.auto'); gc.freeze()")
    env = {**os.environ, **ONE_THREAD}
    return float(np.median([timed(subprocess.run, [sys.executable, "-c", code], env=env,
                                  check=True)[1] for _ in range(repeats)]))


def degree_text(w):
    """The written .psf's degree and its approximation error (from its header)."""
    model = "" if w["APXMODEL"] is None else f" (model's own {w['APXMODEL']:.2e})"
    return (f"degree {w['POLDEG1']}, approximation error {w['APXCV']:.2e} of the peak"
            f"{model}, e {w['APXE']:.4f}, size {w['APXSIZE']:.4f} px against the full model")


def print_accuracy(acc, indent="  "):
    for name, (e, s, nf) in acc.items():
        print(f"{indent}{name:40s} e rms {e:.4f}  size rms {s:.4f} px"
              + (f"  ({nf} moments failed)" if nf else ""))


def mean_accuracy(accs, positions):
    n = len(accs)
    print(f"\nMean over {n} CCD(s), {positions} positions each (e rms, size rms in pixels; "
          "per-CCD rms averaged):")
    ref = {k: np.mean([a[k][:2] for a in accs], axis=0) for k in accs[0]}
    for name, (e, s) in ref.items():
        print(f"  {name:40s} e rms {e:.4f}  size rms {s:.4f}")
    return ref


def target(ratio, limit):
    return f"x{ratio:.2f} (target <= {limit}: {'met' if ratio <= limit else 'NOT met'})"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n-ccds", type=int, help="CCDs [3; 16 with --many]")
    parser.add_argument("--single", type=int, default=3,
                        help="CCDs (the first ones) also fitted by single-CCD commands [3]")
    parser.add_argument("--many", action="store_true",
                        help="one command over all the catalogues, --n-jobs 1 and 2")
    parser.add_argument("--positions", type=int, default=2000)
    parser.add_argument("--seed", type=int, default=100)
    parser.add_argument("--quick", action="store_true", help="one 1024 x 1024 CCD")
    parser.add_argument("--keep", metavar="FOLDER", help="keep the files in FOLDER")
    parser.add_argument("--cache", metavar="FOLDER",
                        help="keep the rendered CCDs in FOLDER and reuse them")
    parser.add_argument("--variant", action="append", default=[], metavar="OPTIONS",
                        help="also fit ours with these fit options (e.g. '--reserve 0 "
                        "--isolation 12'), accuracy only; repeatable")
    args = parser.parse_args(argv)
    if args.n_ccds is None:
        args.n_ccds = 16 if args.many else 3
    if args.quick:
        args.n_ccds, args.positions = (2 if args.many else 1), min(args.positions, 500)
    args.single = min(args.single, args.n_ccds)
    for program in ("source-extractor", "psfex"):
        if find_program(program) is None:
            sys.exit(f"{program} is not installed (apt-get install source-extractor psfex)")
    print(f"load average at start {os.getloadavg()[0]:.2f}")
    compile_bytecode()
    status = 0
    accs, cpus, prepared, degrees = [], [], [], []
    with tempfile.TemporaryDirectory(prefix="bench_psfex_") as tmp:
        root = args.keep or tmp
        for i in range(args.n_ccds):
            seed = args.seed + i
            folder = os.path.join(root, f"ccd{i}")
            os.makedirs(folder, exist_ok=True)
            ccd, catalog, files, cpu = prepare(seed, args, folder)
            prepared.append((seed, ccd, catalog, files))
            if i < args.single:
                acc, cpu["ours"], written = single(seed, ccd, catalog, files, args, folder)
                accs.append(acc)
                degrees.append((seed, written))
                print(f"  written .psf: {degree_text(written)}")
                print_accuracy(acc)
            cpus.append(cpu)
            print("  CPU s: " + ", ".join(f"{k} {v:.2f}" for k, v in cpu.items()), flush=True)
        if accs:
            ref = mean_accuracy(accs, args.positions)
            for d in (2, 3):
                p = ref[f"PSFEx d{d} (.psf, DES_PSFEx)"]
                print(f"  ours .psf / PSFEx d{d}: e rms x{ref['ours (.psf, DES_PSFEx)'][0] / p[0]:.2f}"
                      f", size rms x{ref['ours (.psf, DES_PSFEx)'][1] / p[1]:.2f}; full model / "
                      f"PSFEx d{d}: e rms x{ref['ours (full model)'][0] / p[0]:.2f}, size rms "
                      f"x{ref['ours (full model)'][1] / p[1]:.2f}")
            for seed, written in degrees:
                print(f"  CCD seed {seed}: written .psf {degree_text(written)}")
            first = cpus[:args.single]
            mean_cpu = {k: np.mean([c[k] for c in first]) for k in first[0]}
            print(f"CPU seconds per CCD over the {len(first)} single-CCD command(s) (one thread "
                  "each): " + ", ".join(f"{k} {v:.2f}" for k, v in mean_cpu.items()))
            for d in (2, 3):
                print(f"  single-CCD command: ours / PSFEx d{d} "
                      + target(mean_cpu["ours"] / mean_cpu[f"PSFEx d{d}"], 3))
            start = startup_cpu()
            print(f"  of which the process's start (imports and numba's first call, median of "
                  f"3): {start:.2f} s = x{start / mean_cpu['PSFEx d2']:.2f} PSFEx d2's whole "
                  f"run; the rest {mean_cpu['ours'] - start:.2f} s = "
                  f"x{(mean_cpu['ours'] - start) / mean_cpu['PSFEx d2']:.2f}")
        if args.many:
            status = many(prepared, cpus, args, root)
    return status


def many(prepared, cpus, args, root):
    """One command over every catalogue, --n-jobs 1 and 2: CPU per CCD, the extra worker's
    CPU, the same models from both, their accuracy at the truth beside PSFEx's."""
    n = len(prepared)
    catalogs = [c for _, _, c, _ in prepared]
    cpu_run = {}
    for jobs in (1, 2):
        out = os.path.join(root, f"many_jobs{jobs}")
        os.makedirs(out, exist_ok=True)
        _, cpu_run[jobs] = timed(ours, catalogs, out, "psf", ["--n-jobs", str(jobs)])
    status, accs = 0, []
    for seed, ccd, catalog, files in prepared:
        stem = Path(catalog).stem
        paths = [os.path.join(root, f"many_jobs{j}", f"psf_{stem}.fits") for j in (1, 2)]
        a, b = (load_model(p) for p in paths)
        grid = np.column_stack([np.linspace(30, 2000, 40), np.linspace(2000, 30, 40)])
        if not np.array_equal(a.predict(grid), b.predict(grid)):
            print(f"  CCD {seed}: the --n-jobs 2 model DIFFERS from --n-jobs 1's")
            status = 1
        accs.append(accuracy(ccd, seed, args, {"ours (full model)": paths[0]},
                             {f"{k} (.psf, DES_PSFEx)": v for k, v in files.items()}))
    ref = mean_accuracy(accs, args.positions)
    for d in (2, 3):
        p = ref[f"PSFEx d{d} (.psf, DES_PSFEx)"]
        print(f"  ours (full model) / PSFEx d{d}: e rms x{ref['ours (full model)'][0] / p[0]:.2f}"
              f", size rms x{ref['ours (full model)'][1] / p[1]:.2f}")
    psfex = {d: np.mean([c[f"PSFEx d{d}"] for c in cpus]) for d in (2, 3)}
    sex = np.mean([c["Source Extractor"] for c in cpus])
    print(f"CPU seconds per CCD over {n} CCDs (one thread each): Source Extractor {sex:.2f}, "
          f"PSFEx d2 {psfex[2]:.2f}, d3 {psfex[3]:.2f}; one command `fit --stars` over the "
          f"{n} catalogues: --n-jobs 1 {cpu_run[1] / n:.2f} ({cpu_run[1]:.1f} s in all), "
          f"--n-jobs 2 {cpu_run[2] / n:.2f} ({cpu_run[2]:.1f} s)")
    for d in (2, 3):
        print(f"  {n}-CCD command (--n-jobs 1): ours / PSFEx d{d} "
              + target(cpu_run[1] / n / psfex[d], 1.5))
    extra = cpu_run[2] - cpu_run[1]
    print(f"  extra CPU of the second worker: {extra:.2f} s over {n} catalogues "
          f"(target <= 0.5 s: {'met' if extra <= 0.5 else 'NOT met'})")
    return status


if __name__ == "__main__":
    sys.exit(main())
