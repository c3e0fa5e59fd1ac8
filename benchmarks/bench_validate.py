"""Benchmark: this package's PSF model and PSFEx validated on the same 200 reserved stars.

Usage::

    python benchmarks/bench_validate.py                 # 200 reserved + 400 fitted stars
    python benchmarks/bench_validate.py --piff          # also a PIFF PixelGrid model (slow fit)
    python benchmarks/bench_validate.py --out figs      # also write the comparison figures
    python benchmarks/bench_validate.py --quick         # 60 reserved + 120 fitted (smoke)

A field is simulated with the truth known (:func:`sklearn_psf.simulate.make_psf_field`,
sub-pixel positions, S/N 100) and written as a FITS image and weight map. When the Debian
``source-extractor`` and ``psfex`` programs are on the PATH (``apt-get install
source-extractor psfex``), SExtractor detects the stars and cuts their VIGNETs, and PSFEx
itself (PIXEL_AUTO basis, PSFVAR_DEGREES 2, PSF_SAMPLING 1, PSF_SIZE 25) models the fitted
stars: a real ``.psf`` file made by another program. Without them, the PSFEx-format model is
a per-pixel polynomial of degree 2 fitted by least squares (PSFEx's model with a pixel basis)
and written with :func:`sklearn_psf.validation.write_psfex`. This package's default
``PSFModel()`` is fitted on the same stars' stamps and saved to a model file.

Measured:

1. the time of :func:`sklearn_psf.validation.validate_models` on the reserved stars with the
   two model files (reading them included; target < 10 s for 200 stars);
2. the models' true errors at the reserved stars (model - truth: pixel rms of the unit-flux
   stamps and ellipticity rms), and whether the table ranks the models as these do (by
   ``chi2_dof`` and by ``e_rms``). Exits with status 1 when a ranking disagrees with the
   truth.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time

import numpy as np
from astropy.io import fits
from scipy.spatial import cKDTree
from threadpoolctl import threadpool_limits

from sklearn_psf.io import read_catalog
from sklearn_psf.exposure import extract_vignettes
from sklearn_psf.measure import adaptive_moments
from sklearn_psf.model import PSFModel, save_model
from sklearn_psf.preprocessing import StampNormalizer
from sklearn_psf.simulate import make_psf_field
from sklearn_psf.validation import (load_psf_model, measure_residuals, plot_model_comparison,
                                    psfex_terms, validate_models, write_psfex)

PARAMS = ["NUMBER", "X_IMAGE", "Y_IMAGE", "XWIN_IMAGE", "YWIN_IMAGE", "FLUX_APER(1)",
          "FLUXERR_APER(1)", "FLUX_RADIUS", "SNR_WIN", "ELONGATION", "FLAGS", "FLUX_MAX",
          "FLUX_AUTO", "FLUXERR_AUTO"]


def _run(cmd, folder):
    subprocess.run(cmd, cwd=folder, check=True, stdout=subprocess.DEVNULL,
                   stderr=subprocess.DEVNULL)


def sextractor_catalog(folder, field, s):
    """SExtractor LDAC catalogue with VIGNETs of the image; its rows matched to the truth."""
    fits.PrimaryHDU(field.image.astype(np.float32)).writeto(f"{folder}/image.fits")
    fits.PrimaryHDU(field.weight.astype(np.float32)).writeto(f"{folder}/weight.fits")
    with open(f"{folder}/default.sex", "w") as f:
        subprocess.run(["source-extractor", "-d"], stdout=f, check=True)
    with open(f"{folder}/psf.param", "w") as f:
        f.write("\n".join(PARAMS + [f"VIGNET({s},{s})"]) + "\n")
    _run(["source-extractor", "image.fits", "-c", "default.sex", "-CATALOG_NAME", "cat.ldac",
          "-CATALOG_TYPE", "FITS_LDAC", "-PARAMETERS_NAME", "psf.param", "-FILTER", "N",
          "-WEIGHT_TYPE", "MAP_WEIGHT", "-WEIGHT_IMAGE", "weight.fits", "-PHOT_APERTURES",
          "10", "-DETECT_THRESH", "5", "-VERBOSE_TYPE", "QUIET"], folder)
    catalog = read_catalog(f"{folder}/cat.ldac")
    truth_xy = np.column_stack([field.stars["x"], field.stars["y"]])
    dist, idx = cKDTree(truth_xy).query(np.column_stack([catalog["x"], catalog["y"]]))
    return catalog, np.where(dist < 1.0, idx, -1)


def run_psfex(folder, rows):
    """PSFEx on the catalogue rows given (the fitted stars); returns the .psf path."""
    with fits.open(f"{folder}/cat.ldac") as hdul:
        hdul["LDAC_OBJECTS"].data = hdul["LDAC_OBJECTS"].data[rows]
        hdul.writeto(f"{folder}/fit.ldac")
    with open(f"{folder}/default.psfex", "w") as f:
        subprocess.run(["psfex", "-d"], stdout=f, check=True)
    _run(["psfex", "fit.ldac", "-c", "default.psfex", "-PSF_SIZE", "25,25", "-PSF_SAMPLING",
          "1.0", "-PSFVAR_DEGREES", "2", "-SAMPLE_MINSN", "20", "-CHECKPLOT_TYPE", "NONE",
          "-CHECKIMAGE_TYPE", "NONE", "-WRITE_XML", "N", "-VERBOSE_TYPE", "QUIET"], folder)
    return f"{folder}/fit.psf"


def polynomial_psfex(path, X, stamps, shape, degree=2):
    """PSFEx's pixel-basis model (each pixel a polynomial of the 1-based position), fitted by
    least squares on the normalised stamps and written in PSFEx's format."""
    s = int(round(np.sqrt(stamps.shape[1])))
    zero = ((shape[1] + 1) / 2.0, (shape[0] + 1) / 2.0)
    scale = (float(shape[1]), float(shape[0]))
    terms = psfex_terms(X + 1.0, degree, zero, scale)
    planes = np.linalg.lstsq(terms, StampNormalizer().fit_transform(stamps), rcond=None)[0]
    write_psfex(path, planes.reshape(-1, s, s), zero, scale)
    return path


def fit_piff(path, X, stamps, weights, s):
    """PIFF PixelGrid + BasisPolynomial(2) on the fitted stars, written to path."""
    import galsim
    import piff

    stars = []
    for (x, y), d, w in zip(X, stamps, weights):
        cx, cy = int(np.floor(x + 0.5)) + 1, int(np.floor(y + 0.5)) + 1  # 1-based pixels
        b = galsim.BoundsI(cx - s // 2, cx + s // 2, cy - s // 2, cy + s // 2)
        image = galsim.Image(d.reshape(s, s).copy(), bounds=b, scale=1.0)
        weight = galsim.Image(w.reshape(s, s).copy(), bounds=b, scale=1.0)
        stars.append(piff.Star(piff.StarData(image, galsim.PositionD(x + 1, y + 1),
                                             weight=weight), None))
    psf = piff.SimplePSF(piff.PixelGrid(scale=1.0, size=s), piff.BasisPolynomial(order=2))
    psf.fit(stars, {0: galsim.PixelScale(1.0)}, pointing=None)
    psf.write(path)
    return path


def truth_errors(model, X, truth):
    """Model - truth at X: pixel rms of the unit-flux stamps as they are, the same after the
    flux, background and centroid fit of the chi^2 (the table's measure on noiseless stars:
    ``measure_residuals`` with unit weights), and the ellipticity rms."""
    pred = model.predict(X)
    mp, mt = adaptive_moments(pred), adaptive_moments(truth)
    de = np.hypot(np.asarray(mp["e1"]) - mt["e1"], np.asarray(mp["e2"]) - mt["e2"])
    table, _ = measure_residuals(X, truth, pred, weights=np.ones_like(truth))
    fitted = np.sqrt(np.nansum(table["chi2"]) / np.sum(table["dof"]))
    return (float(np.sqrt(np.mean((pred - truth) ** 2))), float(fitted),
            float(np.sqrt(np.nanmean(de**2))))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--piff", action="store_true", help="also fit and validate a PIFF model")
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--out", help="folder for the comparison figures")
    args = ap.parse_args(argv)
    n_res, n_fit = (60, 120) if args.quick else (200, 400)
    shape = (1500, 1500) if args.quick else (3000, 3000)
    field = make_psf_field(n_stars=n_res + n_fit, n_galaxies=0, image_shape=shape,
                           snr=100.0, random_state=args.seed)
    s = field.stamp_size
    folder = tempfile.mkdtemp(prefix="bench_validate_")
    real = shutil.which("source-extractor") and shutil.which("psfex")
    rng = np.random.default_rng(args.seed)
    if real:
        catalog, truth_row = sextractor_catalog(folder, field, s)
        good = np.flatnonzero(truth_row >= 0)
        order = rng.permutation(good)
        res_rows, fit_rows = np.sort(order[:n_res]), np.sort(order[n_res:])
        res = extract_vignettes(catalog[res_rows])
        fit = extract_vignettes(catalog[fit_rows])
        psfex_path, psfex_label = run_psfex(folder, fit_rows), "PSFEx 3.21 (real)"
        X_res, stamps_res, w_res = res.positions, res.stamps, res.weights
        truth = np.asarray(field.stars["stamp"])[truth_row[res_rows][res.catalog["used"]]]
        X_fit, stamps_fit, w_fit = fit.positions, fit.stamps, fit.weights
        print(f"SExtractor: {len(catalog)} detections, {len(good)} matched to true stars; "
              f"PSFEx fitted on {len(fit_rows)}, reserved {res.counts['used']}")
    else:
        stamps, w, _ = field.star_stamps(return_weights=True)
        X = np.column_stack([field.stars["x"], field.stars["y"]])
        order = rng.permutation(len(X))
        r, f = np.sort(order[:n_res]), np.sort(order[n_res:])
        X_res, stamps_res, w_res, truth = X[r], stamps[r], w[r], np.asarray(field.stars["stamp"])[r]
        X_fit, stamps_fit, w_fit = X[f], stamps[f], w[f]
        psfex_path = polynomial_psfex(f"{folder}/poly.psf", X_fit, stamps_fit, shape)
        psfex_label = "PSFEx-format polynomial (psfex not installed)"
        print("source-extractor/psfex not found: PSFEx-format model fitted by least squares")
    with threadpool_limits(1):
        ours = PSFModel().fit(X_fit, stamps_fit, weights=w_fit)
        save_model(ours, f"{folder}/ours.fits")
        files = {"sklearn_psf PSFModel()": f"{folder}/ours.fits", psfex_label: psfex_path}
        if args.piff:
            t0 = time.perf_counter()
            files["PIFF PixelGrid"] = fit_piff(f"{folder}/model.piff", X_fit, stamps_fit,
                                               w_fit, s)
            print(f"PIFF fit: {time.perf_counter() - t0:.1f} s")
        timed = {k: files[k] for k in list(files)[:2]}
        t0 = time.perf_counter()
        table, _ = validate_models(X_res, stamps_res, timed, weights=w_res)
        seconds = time.perf_counter() - t0
        table, results = validate_models(X_res, stamps_res, files, weights=w_res)
    print(f"\nvalidate_models, {len(X_res)} reserved stars, 2 model files (reading included): "
          f"{seconds:.2f} s (target < 10 s: {'met' if seconds < 10 else 'NOT met'})\n")
    errors = {name: truth_errors(load_psf_model(path, s), X_res, truth)
              for name, path in files.items()}
    print(f"{'model':<46} {'rank':>4} {'chi2/dof':>9} {'e rms':>8} {'|rho1|':>9} | truth: "
          f"{'pixel rms':>9} {'fitted':>9} {'e rms':>8}")
    for row in table:
        pix, fitted, e = errors[row["model"]]
        print(f"{row['model']:<46} {row['rank']:>4} {row['chi2_dof']:>9.4f} "
              f"{row['e_rms']:>8.5f} {row['rho1_mean_abs']:>9.2e} |        {pix:>9.3e} "
              f"{fitted:>9.3e} {e:>8.5f}")
    names = list(table["model"])

    def same_order(a, b):
        return bool(np.array_equal(np.argsort(a), np.argsort(b)))

    checks = {
        "chi2/dof vs true pixel error after the chi^2's fit": same_order(
            table["chi2_dof"], [errors[n][1] for n in names]),
        "e rms vs true e error": same_order(table["e_rms"], [errors[n][2] for n in names]),
    }
    raw = same_order(table["chi2_dof"], [errors[n][0] for n in names])
    print("\nthe table ranks the models as the truth does:")
    for what, ok in checks.items():
        print(f"  {what}: {ok}")
    print(f"  (chi2/dof vs true pixel error as stamps are, not fitted: {raw})")
    if args.out:
        import matplotlib

        matplotlib.use("Agg")
        os.makedirs(args.out, exist_ok=True)
        for key, fig in plot_model_comparison(results).items():
            fig.savefig(os.path.join(args.out, f"validation_{key}.png"), dpi=100)
        print(f"figures in {args.out}")
    shutil.rmtree(folder, ignore_errors=True)
    return 0 if all(checks.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
