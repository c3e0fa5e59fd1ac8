"""The ``fit`` and ``predict`` commands of ``sklearn-psf``: their parsers and runners.

Errors are raised as :class:`CLIInputError` (a ``ValueError``) with a one-line message naming
the user's path; the entry point prints them and exits with status 2.
"""

from __future__ import annotations

import argparse
import os
import tempfile

import numpy as np


class CLIInputError(ValueError):
    """A problem with the input of ``fit`` or ``predict``, reported in one line."""


def _positive_int(text):
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


FIT_INTERPOLATORS = ("kriging", "polynomial", "delaunay", "shepard", "rbf", "chebyshev")


def _fraction(text):
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a fraction in [0, 1), got {text!r}") from None
    if not 0 <= value < 1:
        raise argparse.ArgumentTypeError(f"expected a fraction in [0, 1), got {value}")
    return value


def _odd_size(text):
    value = _positive_int(text)
    if value < 5 or value % 2 == 0:
        raise argparse.ArgumentTypeError(f"expected an odd stamp size >= 5, got {value}")
    return value


def _add_fit_parsers(sub):
    fit = sub.add_parser(
        "fit", help="build a validated PSF model of a FITS image and save it",
        description="Select stars (or read a catalogue), cut their stamps with the weight map, "
        "reserve a fraction for validation, fit a PSF model (PCA basis, IQR outlier rejection, "
        "interpolation of the coefficients), save it as a FITS model file and write "
        "diagnostic figures next to it (MODEL_stamps.png, MODEL_whiskers.png, MODEL_rho1.png).",
    )
    fit.add_argument("image", help="FITS image (.fits, .fits.fz)")
    fit.add_argument("-o", "--output", required=True, help="model file to write (FITS)")
    fit.add_argument("--hdu", help="image HDU: index or EXTNAME [first 2-D image]")
    fit.add_argument("--weight-hdu", help="weight/mask HDU of the same file (0 = bad pixel)")
    fit.add_argument("--stars", metavar="CATALOG",
                     help="star catalogue (FITS table or CSV with x, y or X_IMAGE, Y_IMAGE); "
                     "default: stars selected on the image (flux-radius locus)")
    fit.add_argument("--one-based", action="store_true",
                     help="the catalogue's x, y are 1-based (FITS convention); X_IMAGE/Y_IMAGE "
                     "columns are always read as 1-based")
    fit.add_argument("--interpolator", default="kriging", choices=FIT_INTERPOLATORS + ("auto",),
                     help="interpolation scheme, or 'auto' to choose it by 5-fold "
                     "cross-validation [kriging]")
    fit.add_argument("--reserve", type=_fraction, default=0.2,
                     help="fraction of stars reserved for validation [0.2]")
    fit.add_argument("--stamp-size", type=_odd_size, default=25, help="stamp side, odd [25]")
    fit.add_argument("--saturation", type=float,
                     help="saturation level [header SATURATE keyword, else none]")
    fit.add_argument("--min-snr", type=float, default=50.0,
                     help="smallest S/N of a star selected on the image [50]")
    fit.add_argument("--seed", type=int, default=0, help="seed of the reserved-star draw [0]")
    fit.add_argument("--no-plots", action="store_true", help="do not write figures")

    pred = sub.add_parser(
        "predict", help="evaluate a saved PSF model at given positions",
        description="Write the model's PSF stamps at the positions of a catalogue, with their "
        "adaptive-moment e1, e2 and size (sigma, pixels), to a FITS table.",
    )
    pred.add_argument("model", help="model file written by 'sklearn-psf fit'")
    pred.add_argument("--positions", required=True, metavar="CATALOG",
                      help="FITS table or CSV with x, y (or X_IMAGE, Y_IMAGE) columns")
    pred.add_argument("--one-based", action="store_true",
                      help="the catalogue's x, y are 1-based (FITS convention)")
    pred.add_argument("-o", "--output", required=True, help="FITS table to write")


def _figure_paths(output):
    stem = output[:-5] if output.lower().endswith(".fits") else output
    return {name: f"{stem}_{name}.png" for name in ("stamps", "whiskers", "rho1")}


def _fit(args):
    from tqdm.auto import tqdm

    from .compare import default_schemes, make_psf_model
    from .io import extract_star_stamps, find_stars, read_catalog, read_image, save_model
    from .validation import fit_and_validate

    folder = os.path.dirname(os.path.abspath(args.output))
    if not os.path.isdir(folder):
        raise CLIInputError(f"the folder of the output file {args.output!r} does not exist")
    schemes = default_schemes()
    lines = []
    with tqdm(total=6, desc="reading image", unit="step") as bar:
        image, weight, header = read_image(args.image, hdu=args.hdu, weight_hdu=args.weight_hdu)
        saturation = args.saturation
        if saturation is None and "SATURATE" in header:
            saturation = float(header["SATURATE"])
        bar.update()
        bar.set_description("selecting stars")
        if args.stars:
            catalog = read_catalog(args.stars, one_based=True if args.one_based else None)
            lines.append(f"stars in the catalogue: {len(catalog)}"
                         f" ({'1' if catalog.meta['one_based'] else '0'}-based "
                         f"{catalog.meta['x_column']}, {catalog.meta['y_column']})")
        else:
            catalog = find_stars(image, weight=weight, stamp_size=args.stamp_size,
                                 min_snr=args.min_snr, saturation=saturation)
            rejected = {k: v for k, v in catalog.meta["rejected"].items() if v}
            lines.append(f"sources detected: {catalog.meta['n_detections']}, selected as stars: "
                         f"{len(catalog)}" + (" (rejected: " + ", ".join(
                             f"{k} {v}" for k, v in rejected.items()) + ")" if rejected else ""))
            if len(catalog) < 5:
                raise CLIInputError(
                    f"found {len(catalog)} usable stars in {args.image} "
                    f"({catalog.meta['n_detections']} detections): too few for a PSF model; "
                    "give a star catalogue with --stars or lower --min-snr"
                )
        bar.update()
        bar.set_description("cutting stamps")
        cut = extract_star_stamps(image, catalog, args.stamp_size, weight=weight,
                                  saturation=saturation)
        skipped = {k: v for k, v in cut.counts.items() if k not in ("input", "used") and v}
        lines.append(f"stars used: {cut.counts['used']} of {cut.counts['input']}"
                     + (" (skipped: " + ", ".join(f"{k} {v}" for k, v in skipped.items()) + ")"
                        if skipped else ""))
        bar.update()
        bar.set_description("fitting and validating")
        if args.interpolator == "auto":
            candidates = {n: make_psf_model(schemes[n]) for n in FIT_INTERPOLATORS}
            model, residuals, summary = fit_and_validate(
                cut.positions, cut.stamps, reserve=args.reserve, random_state=args.seed,
                candidates=candidates)
        else:
            model, residuals, summary = fit_and_validate(
                cut.positions, cut.stamps, make_psf_model(schemes[args.interpolator]),
                reserve=args.reserve, random_state=args.seed)
        summary["selection"] = dict(cut.counts)
        summary["image"] = os.path.abspath(args.image)
        summary["interpolator"] = summary.get("scheme", args.interpolator)
        bar.update()
        bar.set_description("saving")
        save_model(model, args.output, residuals=residuals if len(residuals) else None,
                   summary=summary, overwrite=True)
        bar.update()
        written = [args.output]
        if not args.no_plots and len(residuals):
            bar.set_description("figures")
            written += _fit_figures(residuals, summary, args.output)
        bar.update()
    if "cv" in summary:
        lines.append("cross-validation (e rms): " + ", ".join(
            f"{r['scheme']} {r['e_rms']:.4f}" for r in summary["cv"])
            + f" -> {summary['scheme']}")
    lines.append(f"interpolator: {summary['interpolator']}; fitted stars: {summary['n_fit']}, "
                 f"outliers rejected: {summary['n_outliers']}, reserved: "
                 f"{summary['n_reserved']}")
    if summary["n_measured"]:
        lines.append(
            f"reserved stars (star - model, {summary['n_measured']} measured): "
            f"e rms {summary['e_rms']:.4f} (e1 mean {summary['de1_mean']:+.4f} rms "
            f"{summary['de1_rms']:.4f}, e2 mean {summary['de2_mean']:+.4f} rms "
            f"{summary['de2_rms']:.4f}), size mean {summary['dsigma_mean']:+.4f} rms "
            f"{summary['dsigma_rms']:.4f} pixels, |rho1| mean {summary['rho1_mean_abs']:.2e}")
    print("\n".join(lines))
    print(f"Wrote {', '.join(written)}")
    return 0


def _fit_figures(residuals, summary, output):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .validation import plot_rho1, plot_stamp_residuals, plot_whiskers

    paths = _figure_paths(output)
    written = []
    makers = {"stamps": lambda: plot_stamp_residuals(residuals),
              "whiskers": lambda: plot_whiskers(residuals)}
    if summary.get("rho1"):
        makers["rho1"] = lambda: plot_rho1(summary)
    for name, make in makers.items():
        fig = make()
        fig.savefig(paths[name], dpi=100)
        plt.close(fig)
        written.append(paths[name])
    return written


def _predict(args):
    from astropy.io import fits
    from astropy.table import Table
    from tqdm.auto import tqdm

    from .io import load_model, read_catalog
    from .io._model_io import write_fits_atomic
    from .measure import adaptive_moments

    folder = os.path.dirname(os.path.abspath(args.output))
    if not os.path.isdir(folder):
        raise CLIInputError(f"the folder of the output file {args.output!r} does not exist")
    model = load_model(args.model)
    catalog = read_catalog(args.positions, one_based=True if args.one_based else None)
    X = np.column_stack([np.asarray(catalog["x"]), np.asarray(catalog["y"])])
    if len(X) == 0:
        raise CLIInputError(f"the catalogue {args.positions} has no rows")
    bad = ~np.isfinite(X).all(axis=1)
    if bad.any():
        raise CLIInputError(f"{int(bad.sum())} positions of {args.positions} are NaN or infinite "
                       f"(first at row {int(np.flatnonzero(bad)[0])})")
    s = model.stamp_size_
    stamps = np.empty((len(X), s * s))
    chunk = 5000
    with tqdm(total=len(X), desc="predicting", unit="PSF") as bar:
        for start in range(0, len(X), chunk):
            stop = min(start + chunk, len(X))
            stamps[start:stop] = model.predict(X[start:stop])
            bar.update(stop - start)
    mom = adaptive_moments(stamps)
    out = Table({"x": X[:, 0], "y": X[:, 1]})
    for name in catalog.colnames:
        if name not in ("x", "y"):
            out[name] = catalog[name]
    out["psf"] = stamps.reshape(len(X), s, s)
    for name in ("e1", "e2", "sigma"):
        out[name] = np.asarray(mom[name], dtype=np.float64)
    out["moments_flag"] = np.asarray(mom["flag"], dtype=np.int64)
    lo, hi = model.X_fit_.min(axis=0), model.X_fit_.max(axis=0)
    outside = ((X < lo) | (X > hi)).any(axis=1)
    hdu = fits.table_to_hdu(out)
    hdu.name = "PSF"
    hdu.header["MODEL"] = (os.path.basename(args.model), "PSF model file")
    hdu.header["STAMPSZ"] = (s, "stamp side in pixels")
    hdu.header["COMMENT"] = "x, y: 0-based pixel positions (x = column); psf: unit-sum stamps"
    write_fits_atomic(fits.HDUList([fits.PrimaryHDU(), hdu]), args.output, overwrite=True)
    flagged = int(np.sum(out["moments_flag"] != 0))
    print(f"PSFs at {len(X)} positions ({s}x{s} stamps, e1/e2/sigma measured"
          + (f"; {flagged} could not be measured" if flagged else "") + ")"
          + (f"; {int(outside.sum())} positions outside the stars' area are extrapolated"
             if outside.any() else ""))
    print(f"Wrote {args.output}")
    return 0


def _check_output(path):
    try:
        os.makedirs(path, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path):
            pass
    except OSError as exc:
        raise CLIInputError(f"cannot write to the output folder {path!r}: {exc.strerror or exc}") from None
