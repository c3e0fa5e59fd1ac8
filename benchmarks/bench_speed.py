"""Benchmark: CPU of ``sklearn-psf fit`` against PSFEx on every kind of image (issue 48).

Usage::

    python benchmarks/bench_speed.py [--cache DIR] [--cases decam decam16 euclid sdss spitzer]
                                     [--repeats 2] [--baseline CHECKOUT] [--quick]

The cases, each catalogued once by Source Extractor (``run_sextractor``: PSFEx's recipe,
``NTHREADS 1``) and modelled from that catalogue by ``sklearn-psf fit --stars CAT --no-plots``
(its defaults) and by PSFEx 3.21 (one thread, ``-CHECKPLOT_TYPE NONE``), in the same run:

- ``decam``: a GalSim DECam-like CCD (:func:`sklearn_psf.simulate.render_galsim_ccd`, seed
  100, rendered as ``bench_psfex.py`` does: 2048 x 2048 pixels, 605 stars, 1000 galaxies; 35 x
  35 VIGNETs); PSFEx with ``PSFVAR_DEGREES 2``, ``PSFVAR_KEYS XWIN_IMAGE,YWIN_IMAGE``. One
  single-CCD command (its start included).
- ``decam16``: 16 such CCDs (seeds 100-115) in one command ``fit --stars CAT1 ... CAT16``
  (``--n-jobs 1``), against PSFEx's 16 runs.
- ``euclid``: the Euclid-like undersampled CCD of ``bench_undersampled.py`` (seed 3, FWHM
  ~1.5 px, 25 x 25 VIGNETs); PSFEx as there with ``PSF_SAMPLING 0`` (automatic).
- ``sdss``: the real SDSS frame of ``../shared/realdata`` (resampled, undersampled, no gain);
  PSFEx with ``SAMPLE_FWHMRANGE 1,10`` (its default 2-10 keeps 21 stars), ``PSF_SAMPLING 0``.
- ``spitzer``: a crowded Spitzer/IRAC 4.5 um GLIMPSE mosaic (``--spitzer FILE``, or
  ``spitzer*.fits`` in the real-data folder; e.g. ``spitzer_example_image.fits`` of the
  astropy/photutils-datasets repository, ``data/``); PSFEx with its defaults. Skipped, with
  the reason, when absent.

CPU seconds are those of the child processes (``RUSAGE_CHILDREN``), one thread each
(``OMP_NUM_THREADS=1`` and the BLAS libraries' equivalents); each tool runs ``--repeats``
times, alternating, and the median is kept. Printed: ours, PSFEx, their ratio against the
issue's target (met / NOT met), the stage profile of one more run of ours
(``benchmarks/_stages.py``: inclusive CPU of each stage; a stage inside another counts in
both), and for the simulated CCDs the accuracy at the truth of both: e rms and size rms at
``--positions`` random positions of each DECam-like CCD (``bench_psfex.py``'s adaptive
moments) and at ``bench_undersampled.py``'s 2000 of the Euclid-like one (its fixed-weight
moments at phase 0).
With ``--baseline CHECKOUT``, ours also runs once with that code (first on ``PYTHONPATH``;
after one untimed run of the first case, which fills a fresh checkout's numba cache), and
the ratio new / previous and the previous model's accuracy are printed. ``--scaling``
prints the cost of a fit per star and per CCD and how it grows with the number of stars and
the stamp size (the DECam-like CCD's catalogue thinned, its VIGNETs cropped).
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import bench_psfex as bp  # noqa: E402  (the DECam-like CCDs, PSFEx, accuracy, CPU timing)
import bench_undersampled as bu  # noqa: E402  (the Euclid-like CCD and its truth)

#: The issue's targets: ours / PSFEx CPU.
TARGETS = {"decam": 3.0, "decam16": 1.0, "euclid": 2.0, "sdss": 2.0, "spitzer": 2.0}


def realdata():
    """The real-data folder ``shared/realdata`` next to the repository (or next to the folder
    holding it, for a git worktree), or ``$SKLEARN_PSF_REALDATA``, as the tests find it."""
    candidates = [os.environ.get("SKLEARN_PSF_REALDATA")]
    candidates += [base / "shared" / "realdata" for base in (HERE.parents[1], HERE.parents[2])]
    found = [Path(c) for c in candidates if c and Path(c).is_dir()]
    return found[0] if found else HERE.parents[1] / "shared" / "realdata"


def run_ours(catalogs, folder, name, code=None, options=()):
    """``sklearn-psf fit --stars CAT... --no-plots`` with ``code`` (a checkout) first on
    ``PYTHONPATH``; the CPU seconds of the process."""
    saved = os.environ.get("PYTHONPATH")
    if code is not None:
        os.environ["PYTHONPATH"] = os.pathsep.join([os.path.abspath(code)]
                                                   + ([saved] if saved else []))
    try:
        return bp.timed(bp.ours, catalogs, folder, name, options)[1]
    finally:
        if code is not None:
            if saved is None:
                del os.environ["PYTHONPATH"]
            else:
                os.environ["PYTHONPATH"] = saved


def stages(catalogs, folder):
    """The stage profile of one more run of ours: {stage: CPU seconds}, in order."""
    out = os.path.join(folder, "stages.json")
    cmd = [sys.executable, str(HERE / "_stages.py"), out, "fit", "--stars",
           *map(str, np.atleast_1d(catalogs)), "-o", os.path.join(folder, "stages.fits"),
           "--no-plots", "--overwrite"]
    subprocess.run(cmd, env={**os.environ, **bp.ONE_THREAD}, check=True, capture_output=True)
    with open(out) as fh:
        got = json.load(fh)
    totals = got["totals"]
    rows = [("process (all)", totals["process"][0]),
            ("start (interpreter, imports of the parser)", totals["start"][0]),
            ("imports of the library", totals["imports of the library"][0])]
    inner = totals.get("fit and validate", [0.0])[0]
    for name in got["stages"]:
        if name in totals:  # (fit_exposure's own part: less the fit and its validation)
            own = name.startswith("read, select") and inner
            rows.append((name + " (without the fit)" * bool(own), totals[name][0] - own))
    return rows


def psfex(catalog, folder, config):
    """PSFEx on ``catalog`` (one thread); (its .psf, CPU seconds)."""
    from sklearn_psf.io import run_psfex

    return bp.timed(run_psfex, catalog, folder, config={"NTHREADS": 1, **config},
                    overwrite=True)


_WARMED = []  # whether the baseline checkout has run once


def measure(case, catalogs, folder, psfex_runs, args):
    """CPU of ours (and of the baseline code) and of PSFEx, alternating, ``--repeats``
    times; the medians and the stage profile."""
    cpu = {"ours": [], "PSFEx": []}
    if args.baseline:
        cpu["previous"] = []
    if args.baseline and not _WARMED:
        # untimed, once: a fresh checkout's first run compiles numba's kernels into its cache
        # (4-5 s), which an installed package's users pay once, not per command
        run_ours(catalogs, folder, "previous", args.baseline)
        _WARMED.append(True)
    for k in range(args.repeats):
        cpu["ours"].append(run_ours(catalogs, folder, "ours"))
        if args.baseline and k == 0:  # (once: the previous code is the slow one)
            cpu["previous"].append(run_ours(catalogs, folder, "previous", args.baseline))
        cpu["PSFEx"].append(sum(psfex(*run)[1] for run in psfex_runs))
    med = {k: statistics.median(v) for k, v in cpu.items()}
    line = (f"{case}: CPU s ours {med['ours']:.2f} ({', '.join(f'{v:.2f}' for v in cpu['ours'])})"
            f", PSFEx {med['PSFEx']:.2f} ({', '.join(f'{v:.2f}' for v in cpu['PSFEx'])})")
    if args.baseline:
        line += (f", previous code {med['previous']:.2f} "
                 f"({', '.join(f'{v:.2f}' for v in cpu['previous'])}): new / previous "
                 f"x{med['ours'] / med['previous']:.2f}")
    ratio = med["ours"] / med["PSFEx"]
    limit = TARGETS[case]
    print(line + f"\n  ours / PSFEx x{ratio:.2f} (target <= {limit}: "
          f"{'met' if ratio <= limit else 'NOT met'})", flush=True)
    profile = stages(catalogs, folder)
    print("  stage profile of ours (CPU s, inclusive):")
    for name, value in profile:
        print(f"    {name:52s} {value:8.2f}")
    return {"cpu": cpu, "median": med, "ratio": ratio, "stages": profile}


def decam_case(args, root, n_ccds):
    """The DECam-like CCDs (``bench_psfex.prepare``: rendered or read from the cache,
    catalogued), ours and PSFEx d2, accuracy of both at the truth."""
    ns = argparse.Namespace(quick=args.quick, cache=args.cache, positions=args.positions)
    prepared = []
    for i in range(n_ccds):
        folder = os.path.join(root, f"decam{i}")
        os.makedirs(folder, exist_ok=True)
        prepared.append(prepare_decam(args.seed + i, ns, folder))
    case = "decam" if n_ccds == 1 else "decam16"
    catalogs = [p[1] for p in prepared]
    runs = [(p[1], os.path.join(root, f"psfex{i}"),
             {"PSFVAR_DEGREES": 2, "PSFVAR_KEYS": "XWIN_IMAGE,YWIN_IMAGE"})
            for i, p in enumerate(prepared)]
    out = measure(case, catalogs if n_ccds > 1 else catalogs[0], root, runs, args)
    accs = []
    names = ("ours", "previous") if args.baseline else ("ours",)
    for i, (ccd, catalog) in enumerate(prepared):
        stem = "" if n_ccds == 1 else f"_{Path(catalog).stem}"
        psf = psfex(*runs[i])[0]
        accs.append(bp.accuracy(ccd, args.seed + i, ns,
                                {name: os.path.join(root, f"{name}{stem}.fits")
                                 for name in names}, {"PSFEx d2": psf}))
    for name in (*names, "PSFEx d2"):
        e, s = np.mean([a[name][:2] for a in accs], axis=0)
        print(f"  accuracy at the truth ({n_ccds} CCD(s), {args.positions} positions each): "
              f"{name} e rms {e:.4f}, size rms {s:.4f} px")
    return out


def prepare_decam(seed, ns, folder):
    """A DECam-like CCD and its catalogue (PSFEx's models are made by ``measure``)."""
    from sklearn_psf.io import run_sextractor

    ccd, image, cached = bp.cached_ccd(seed, ns.quick, ns.cache, folder)
    catalog = cached / f"ccd{seed}.ldac"  # (distinct names: one model file each)
    if not catalog.exists():
        run_sextractor(image, catalog, weight_path=ccd.weight_path(image),
                       config={"NTHREADS": 1}, overwrite=True)
    return ccd, str(catalog)


def euclid_case(args, root):
    """The Euclid-like undersampled CCD of ``bench_undersampled.py`` (rendered once into the
    cache), ours and PSFEx with ``PSF_SAMPLING 0``, accuracy of both at the truth."""
    import galsim.des  # noqa: F401
    from astropy.io import fits

    from sklearn_psf.io import run_sextractor
    from sklearn_psf.model import load_model
    from sklearn_psf.simulate import render_galsim_ccd

    n = 1024 if args.quick else 2048
    n_stars = 150 if args.quick else 600
    scale = bu.FIELDS["euclid"][0]
    psf = bu._psf_factory(n, "euclid")
    cached = Path(args.cache or root) / f"euclid{args.euclid_seed}_{n}"
    cached.mkdir(parents=True, exist_ok=True)
    catalog = cached / "cat.ldac"
    if not catalog.exists():
        ccd = render_galsim_ccd(shape=(n, n), pixel_scale=scale, n_stars=n_stars,
                                n_galaxies=n_stars, psf=psf, snr_range=(30.0, 1000.0),
                                random_state=args.euclid_seed)
        image = ccd.write(cached, overwrite=True)
        run_sextractor(image, catalog, weight_path=ccd.weight_path(image), vignet=(25, 25),
                       config={"NTHREADS": 1}, overwrite=True)
    config = {"PSF_SAMPLING": 0.0, "PSF_SIZE": "41,41", "PSFVAR_DEGREES": 2,
              "SAMPLE_FWHMRANGE": "0.5,10.0"}
    runs = [(str(catalog), os.path.join(root, "psfex_euclid"), config)]
    out = measure("euclid", str(catalog), root, runs, args)
    positions = 500 if args.quick else 2000  # bench_undersampled.py's truth positions
    truth_file = cached / f"truth{positions}.npz"
    if truth_file.exists():
        z = np.load(truth_file)
        P, truth = z["P"], z["truth"]
    else:
        P = np.random.default_rng(args.euclid_seed + 1).uniform(0, n - 1, (positions, 2))
        truth = bu._truth(psf, P, 25, scale)
        np.savez(truth_file, P=P, truth=truth)
    for name in ("ours", "previous") if args.baseline else ("ours",):
        model = load_model(os.path.join(root, f"{name}.fits"))
        e, s, b = bu._scores(model.predict(P), truth)
        print(f"  accuracy at the truth ({positions} positions): {name} e rms {e:.4f}, size "
              f"rms {s:.4f}, size bias {b:+.4f}")
    path = psfex(*runs[0])[0]
    with fits.open(path) as hdul:
        sampling = float(hdul[1].header.get("PSF_SAMP", 0.0))
    drawn = galsim.des.DES_PSFEx(str(path))
    pred = np.array([bu._phase_zero(drawn.getPSF(galsim.PositionD(x + 1.0, y + 1.0)), 25, 1.0)
                     for x, y in P])
    e, s, b = bu._scores(pred, truth)
    print(f"  accuracy at the truth: PSFEx (PSF_SAMP {sampling:.2f}) e rms {e:.4f}, size rms "
          f"{s:.4f}, size bias {b:+.4f}")
    return out


def real_case(args, root, case, image, config):
    """A real image catalogued by Source Extractor (PSFEx's recipe), ours and PSFEx; no
    truth: the verdict on the reserved stars of ours (and of the previous code's)."""
    from sklearn_psf.io import run_sextractor
    from sklearn_psf.model import read_model_validation

    catalog = os.path.join(root, f"{case}.ldac")
    run_sextractor(image, catalog, config={"NTHREADS": 1}, overwrite=True)
    out = measure(case, catalog, root, [(catalog, os.path.join(root, f"psfex_{case}"),
                                         config)], args)
    for name in ("ours", "previous") if args.baseline else ("ours",):
        v = read_model_validation(os.path.join(root, f"{name}.fits"))[1]
        print(f"  verdict of {name} on its reserved stars: {v['n_inliers']} of {v['n_fit']} "
              f"stars kept, {v['n_components']} components, median chi^2/dof "
              f"{v['chi2_dof_median']:.3f} (a constant PSF: "
              f"{v['chi2_dof_median_constant']:.3f}), e residual / e noise "
              f"{v['e_resid_over_noise']:.2f}")
    return out


def scaling(args, root):
    """CPU of the model's fit and verdict (``fit_and_validate``, 20% reserved: what grows
    with the stars; reading and selection excluded, the process warm) on subsets of a
    catalogue's selected stars and on their stamps cropped about the centre, for the
    DECam-like CCD (35-pixel VIGNETs, well sampled) and the Euclid-like one (25-pixel,
    undersampled): a table of CPU seconds and milliseconds per star."""
    import time
    import warnings

    from sklearn_psf.validation import fit_and_validate
    from sklearn_psf.exposure import fit_exposure

    ns = argparse.Namespace(quick=args.quick, cache=args.cache, positions=args.positions)
    folder = os.path.join(root, "decam")
    os.makedirs(folder, exist_ok=True)
    cases = {"DECam-like (well sampled)": (prepare_decam(args.seed, ns, folder)[1],
                                           (15, 25, 35))}
    euclid = Path(args.cache or root) / f"euclid{args.euclid_seed}_{1024 if args.quick else 2048}"
    if (euclid / "cat.ldac").exists():  # (made by the euclid case)
        cases["Euclid-like (undersampled)"] = (str(euclid / "cat.ldac"), (15, 19, 25))
    rng = np.random.default_rng(0)
    for name, (catalog, sides) in cases.items():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            stars = fit_exposure(catalog=catalog).stars
        X, d, w = stars.positions, stars.stamps, stars.weights
        full = int(round(np.sqrt(d.shape[1])))
        counts = [c for c in (50, 100, 200, 400) if c < len(X)] + [len(X)]
        print(f"\n{name}: fit_and_validate CPU s (ms per star) on n stars' stamps of side s")
        print("  n \\ s " + "".join(f"{side:>16d}" for side in sides))
        for n in counts:
            sub = np.sort(rng.choice(len(X), n, replace=False))
            cells = []
            for side in sides:
                lo = (full - side) // 2
                cut = np.s_[lo:lo + side, lo:lo + side]
                dd = d[sub].reshape(n, full, full)[:, cut[0], cut[1]].reshape(n, -1)
                ww = w[sub].reshape(n, full, full)[:, cut[0], cut[1]].reshape(n, -1)
                start = time.process_time()
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    fit_and_validate(X[sub], dd, weights=ww, random_state=0)
                cpu = time.process_time() - start
                cells.append(f"{cpu:7.2f} ({1e3 * cpu / n:5.1f})")
            print(f"  {n:5d} " + "".join(f"{c:>16s}" for c in cells), flush=True)


def spitzer_image(args):
    if args.spitzer:
        return args.spitzer
    found = sorted(glob.glob(str(realdata() / "*[Ss]pitzer*.fits")))
    return found[0] if found else None


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", default=list(TARGETS), choices=list(TARGETS))
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--positions", type=int, default=500,
                        help="truth positions per simulated CCD [500]")
    parser.add_argument("--seed", type=int, default=100, help="first DECam-like CCD [100]")
    parser.add_argument("--euclid-seed", type=int, default=3)
    parser.add_argument("--cache", metavar="FOLDER", help="keep the rendered CCDs here")
    parser.add_argument("--spitzer", metavar="FITS", help="a Spitzer/IRAC mosaic")
    parser.add_argument("--baseline", metavar="CHECKOUT",
                        help="also run ours with this checkout of the previous code")
    parser.add_argument("--quick", action="store_true", help="small CCDs (a smoke test)")
    parser.add_argument("--keep", metavar="FOLDER", help="keep the files in FOLDER")
    parser.add_argument("--scaling", action="store_true",
                        help="also the fit's CPU against the number of stars and the stamp "
                        "size (DECam-like and, when cached, Euclid-like stars)")
    args = parser.parse_args(argv)
    for program in ("source-extractor", "psfex"):
        if bp.find_program(program) is None:
            sys.exit(f"{program} is not installed (apt-get install source-extractor psfex)")
    print(f"load average at start {os.getloadavg()[0]:.2f}")
    bp.compile_bytecode()
    results = {}
    with tempfile.TemporaryDirectory(prefix="bench_speed_") as tmp:
        root = Path(args.keep or tmp)
        for case in args.cases:
            folder = root / case
            folder.mkdir(parents=True, exist_ok=True)
            if case in ("decam", "decam16"):
                results[case] = decam_case(args, str(folder), 1 if case == "decam" else
                                           (2 if args.quick else 16))
            elif case == "euclid":
                results[case] = euclid_case(args, str(folder))
            elif case == "sdss":
                image = realdata() / "SDSS_2p5m_reprojected.fits"
                if not image.exists():
                    print(f"sdss: skipped ({image} is absent)")
                    continue
                results[case] = real_case(args, str(folder), case, image,
                                          {"SAMPLE_FWHMRANGE": "1,10", "PSF_SAMPLING": 0.0})
            else:
                image = spitzer_image(args)
                if image is None:
                    print(f"spitzer: skipped (no --spitzer FILE and no spitzer*.fits in "
                          f"{realdata()}; e.g. data/spitzer_example_image.fits of the "
                          "astropy/photutils-datasets repository, a GLIMPSE 4.5 um mosaic)")
                    continue
                results[case] = real_case(args, str(folder), case, image, {})
        if args.scaling:
            from threadpoolctl import threadpool_limits

            with threadpool_limits(limits=1):
                scaling(args, str(root / "scaling"))
    print("\nsummary (CPU s, medians): case, ours, PSFEx, ratio, target")
    for case, r in results.items():
        m = r["median"]
        print(f"  {case:8s} {m['ours']:8.2f} {m['PSFEx']:8.2f}   x{r['ratio']:.2f}   <= "
              f"{TARGETS[case]} {'met' if r['ratio'] <= TARGETS[case] else 'NOT met'}"
              + (f"   (previous code {m['previous']:.2f}: x{m['ours'] / m['previous']:.2f})"
                 if "previous" in m else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
