"""Star selection on crowded images against PSFEx's, through the real pipeline.

GalSim renders DECam-like CCDs (``render_galsim_ccd``: Kolmogorov seeing lensed by a shear
field, field-dependent optics, stars at S/N 20-1000, saturated stars, galaxies and dead
columns) with galaxies at a natural density (default 2000 per 2048x2048 CCD, about 25 per
arcmin^2), Source Extractor catalogues each with PSFEx's recipe, and on that one catalogue:

- PSFEx 3.21 (its defaults: ``SAMPLE_FLAGMASK 0xfe``, ``SAMPLE_MINSN 20``,
  ``SAMPLE_MAXELLIP 0.3``, ``PSFVAR_DEGREES 2``): the stars it accepts (its output catalogue);
- ``fit_exposure`` with its defaults (flag mask 0xfe, neighbours masked, a star rejected only
  when a neighbour's light reaches its core);
- ``fit_exposure`` with the fixed isolation cut of earlier versions (no source within half a
  VIGNET + 3 pixels, every flag rejected).

Printed per CCD and summed: the catalogue's true stars (unsaturated, matched within 1 pixel),
the true stars and the non-stars each keeps, and the model's e rms and size rms at the truth
at 2000 random positions (adaptive moments of the model's and of the true pixel-convolved PSF
drawn at the same sub-pixel phase; size = sigma in pixels).

    python benchmarks/bench_selection.py            # 3 CCDs
    python benchmarks/bench_selection.py --quick    # 1 CCD, 1000 galaxies
"""

from __future__ import annotations

import argparse
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
from astropy.io import fits
from scipy.spatial import cKDTree
from threadpoolctl import threadpool_limits

from sklearn_psf.io import find_program, read_catalog, run_psfex, run_sextractor
from sklearn_psf.measure import adaptive_moments
from sklearn_psf.simulate import render_galsim_ccd
from sklearn_psf.exposure import SelectionCuts, fit_exposure


def _match(xy, truth_xy, radius=1.0):
    d, i = cKDTree(truth_xy).query(xy)
    return np.where(d <= radius, i, -1)


def _accuracy(model, ccd, n, rng):
    ny, nx = ccd.image.shape
    x, y = rng.uniform(20, nx - 20, n), rng.uniform(20, ny - 20, n)
    side = model.stamp_size_
    truth = adaptive_moments(ccd.truth_stamps(x, y, stamp_size=side))
    pred = adaptive_moments(model.predict(np.column_stack([x, y])).reshape(n, side, side))
    de = np.hypot(np.asarray(pred["e1"]) - truth["e1"], np.asarray(pred["e2"]) - truth["e2"])
    ds = np.asarray(pred["sigma"]) - np.asarray(truth["sigma"])
    return float(np.sqrt(np.nanmean(de**2))), float(np.sqrt(np.nanmean(ds**2)))


def run(seed, n_galaxies, folder, n_truth):
    ccd = render_galsim_ccd(n_galaxies=n_galaxies, random_state=seed)
    image = ccd.write(folder, name=f"ccd{seed}")
    cat_path = run_sextractor(image, folder / f"ccd{seed}.ldac", weight_path=ccd.weight_path(image))
    cat = read_catalog(cat_path)
    stars = ccd.stars[~ccd.stars["saturated"]]
    truth_xy = np.column_stack([stars["x"], stars["y"]])
    in_cat = _match(np.column_stack([cat["x"], cat["y"]]), truth_xy)
    row = {"seed": seed, "catalogue": len(cat), "true stars in catalogue": int(np.sum(in_cat >= 0))}
    out = run_psfex(cat_path, folder, config={"NTHREADS": 1, "OUTCAT_TYPE": "FITS_LDAC",
                                              "OUTCAT_NAME": str(folder / f"ccd{seed}_out.cat")},
                    overwrite=True)
    used = fits.getdata(folder / f"ccd{seed}_out.cat", 2)
    if "FLAGS_PSF" in used.names:
        used = used[used["FLAGS_PSF"] == 0]
    got = _match(np.column_stack([used["X_IMAGE"] - 1, used["Y_IMAGE"] - 1]), truth_xy)
    row["PSFEx true"], row["PSFEx other"] = int(np.sum(got >= 0)), int(np.sum(got < 0))
    row["PSFEx ACCEPTED"] = int(fits.getheader(out, 1).get("ACCEPTED", -1))
    side = int(np.shape(cat["VIGNET"])[1])
    for name, options in (("ours", {}), ("isolation", {"cuts": SelectionCuts(
            isolation=side // 2 + 3, flag_mask=None)})):
        start = time.process_time()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            fit = fit_exposure(catalog=cat_path, **options)
        got = _match(fit.stars.positions, truth_xy)
        row[f"{name} true"], row[f"{name} other"] = int(np.sum(got >= 0)), int(np.sum(got < 0))
        row[f"{name} e rms"], row[f"{name} size rms"] = _accuracy(
            fit.model, ccd, n_truth, np.random.default_rng(seed))
        row[f"{name} cpu"] = time.process_time() - start
    return row


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--n-ccds", type=int, default=3)
    parser.add_argument("--n-galaxies", type=int, default=2000)
    parser.add_argument("--n-truth", type=int, default=2000)
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args(argv)
    if args.quick:
        args.n_ccds, args.n_galaxies, args.n_truth = 1, 1000, 500
    for program in ("source-extractor", "psfex"):
        if find_program(program) is None:
            raise SystemExit(f"{program} is not installed: apt-get install source-extractor psfex")
    rows = []
    with tempfile.TemporaryDirectory() as tmp, threadpool_limits(1):
        for seed in range(args.n_ccds):
            rows.append(run(seed, args.n_galaxies, Path(tmp), args.n_truth))
            print(rows[-1], flush=True)
    total = {k: sum(r[k] for r in rows) for k in rows[0] if k.endswith(("true", "other"))}
    cat = sum(r["true stars in catalogue"] for r in rows)
    print(f"\n{len(rows)} CCDs, {args.n_galaxies} galaxies each; unsaturated true stars in the "
          f"catalogues: {cat}")
    for name in ("PSFEx", "ours", "isolation"):
        kept, other = total[f"{name} true"], total[f"{name} other"]
        line = (f"{name:>9}: true stars kept {kept} ({kept / cat:.1%} of the catalogue's), "
                f"non-stars {other} ({other / max(kept + other, 1):.2%} of those kept)")
        if name != "PSFEx":
            e = np.mean([r[f"{name} e rms"] for r in rows])
            s = np.mean([r[f"{name} size rms"] for r in rows])
            cpu = np.mean([r[f"{name} cpu"] for r in rows])
            line += f"; e rms at the truth {e:.4f}, size rms {s:.4f} px; {cpu:.1f} s CPU"
        print(line)
    print(f"ours / PSFEx true stars: {total['ours true'] / total['PSFEx true']:.3f}; "
          f"ours / isolation e rms: "
          f"{np.mean([r['ours e rms'] for r in rows]) / np.mean([r['isolation e rms'] for r in rows]):.3f}")


if __name__ == "__main__":
    main()
