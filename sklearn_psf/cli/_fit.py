"""The ``fit`` and ``predict`` commands of ``sklearn-psf``: their parsers and runners.

Errors are raised as :class:`CLIInputError` (a ``ValueError``) with a one-line message naming
the user's path; the entry point prints them and exits with status 2.
"""

from __future__ import annotations

import argparse
import contextlib
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


#: The schemes ``fit --interpolator`` takes (sklearn_psf.model.INTERPOLATORS, listed here so
#: that building the parser imports no library module).
FIT_INTERPOLATORS = ("kriging", "polynomial", "chebyshev", "delaunay", "shepard", "rbf")


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
        "fit", help="build a validated PSF model of a FITS image or a catalogue and save it",
        description="Select stars (on the image, or in a catalogue: flags, S/N, saturation, "
        "SPREAD_MODEL/CLASS_STAR, size-magnitude locus), cut their stamps with the weight map "
        "(or take the catalogue's VIGNETs: no image needed), reserve a fraction for "
        "validation, fit a PSF model, save it as a FITS model file and write diagnostic "
        "figures next to it (MODEL_stamps.png: reserved stars, model, residuals; "
        "MODEL_whiskers.png: e of stars/model/residuals; MODEL_rho.png: rho1-rho5; "
        "MODEL_maps.png: model e and size across the chip).",
    )
    fit.add_argument("image", nargs="?",
                     help="FITS image (.fits, .fits.fz); optional with a catalogue holding "
                     "VIGNET stamps (SExtractor FITS_LDAC)")
    fit.add_argument("-o", "--output", required=True,
                     help="model file to write (FITS); with --hdu all, one file per HDU "
                     "named OUTPUT_<EXTNAME or index>.fits")
    fit.add_argument("--hdu", help="image HDU: index or EXTNAME, or 'all' for one model per "
                     "CCD of a multi-extension file [first 2-D image]")
    fit.add_argument("--weight-hdu", help="weight/mask HDU of the same file (0 = bad pixel)")
    fit.add_argument("--stars", metavar="CATALOG",
                     help="source catalogue: FITS table, SExtractor FITS_LDAC or ASCII, CSV "
                     "with x, y or X_IMAGE, Y_IMAGE; default: stars selected on the image")
    fit.add_argument("--x-col", help="column of the catalogue's x positions (0-based unless "
                     "--one-based)")
    fit.add_argument("--y-col", help="column of the catalogue's y positions")
    fit.add_argument("--one-based", action="store_true",
                     help="the catalogue's x, y are 1-based (FITS convention); X_IMAGE/Y_IMAGE "
                     "columns are always read as 1-based")
    fit.add_argument("--no-select", action="store_true",
                     help="use every catalogue row as a star (no star/galaxy selection)")
    fit.add_argument("--interpolator", default="kriging", choices=FIT_INTERPOLATORS + ("auto",),
                     help="interpolation scheme (each in the noise-aware PSFModel: "
                     "StampPCA basis, chi^2 outlier rejection), or 'auto' to choose it by "
                     "5-fold cross-validation [kriging: range fitted by maximum likelihood]")
    fit.add_argument("--reserve", type=_fraction, default=0.2,
                     help="fraction of stars reserved for validation [0.2]")
    fit.add_argument("--stamp-size", type=_odd_size,
                     help="stamp side, odd [25; a catalogue's VIGNET side]")
    fit.add_argument("--saturation", type=float,
                     help="saturation level [header SATURATE keyword, else none]")
    fit.add_argument("--min-snr", type=float, default=50.0,
                     help="smallest S/N of a selected star [50]")
    fit.add_argument("--seed", type=int, default=0, help="seed of the reserved-star draw [0]")
    fit.add_argument("--no-plots", action="store_true", help="do not write figures")

    pred = sub.add_parser(
        "predict", help="evaluate a saved PSF model at given positions",
        description="Write the model's PSF stamps at the positions of a catalogue, with their "
        "adaptive-moment e1, e2 and size (sigma, pixels) and an 'extrapolated' flag (outside "
        "the stars' convex hull, or farther from any star than 3 times their median "
        "nearest-neighbour distance), to a FITS table.",
    )
    pred.add_argument("model", help="model file written by 'sklearn-psf fit'")
    pred.add_argument("--positions", required=True, metavar="CATALOG",
                      help="FITS table, SExtractor catalogue or CSV with x, y (or X_IMAGE, "
                      "Y_IMAGE) columns")
    pred.add_argument("--x-col", help="column of the x positions")
    pred.add_argument("--y-col", help="column of the y positions")
    pred.add_argument("--one-based", action="store_true",
                      help="the catalogue's x, y are 1-based (FITS convention)")
    pred.add_argument("--radec", action="store_true",
                      help="positions are (RA, Dec) in degrees (ALPHA_J2000/DELTA_J2000, RA/DEC "
                      "or --x-col/--y-col), converted with the WCS of the fitted image")
    pred.add_argument("--centered", action="store_true",
                      help="shift each PSF by the position's sub-pixel offset from the stamp's "
                      "centre pixel floor(x + 0.5), as PSFEx and PIFF draw it")
    pred.add_argument("--oversampling", type=_positive_int, default=1,
                      help="samples per pixel along each axis [1]")
    pred.add_argument("-o", "--output", required=True, help="FITS table to write")


def _figure_paths(output):
    stem = output[:-5] if output.lower().endswith(".fits") else output
    return {name: f"{stem}_{name}.png" for name in ("stamps", "whiskers", "rho", "maps")}


def _check_output_file(path):
    """Fail before any work when ``path`` cannot be written (the user's path in the message)."""
    folder = os.path.dirname(os.path.abspath(path)) or "."
    if not os.path.isdir(folder):
        raise CLIInputError(f"the folder of the output file {path!r} does not exist")
    if os.path.isdir(path):
        raise CLIInputError(f"the output {path!r} is a folder: give a file name")
    try:  # the atomic write creates a temporary file there: try one now
        with tempfile.NamedTemporaryFile(dir=folder):
            pass
        if os.path.exists(path) and not os.access(path, os.W_OK):
            raise PermissionError(13, "permission denied")
    except OSError as exc:
        raise CLIInputError(f"cannot write the output file {path!r}: "
                            f"{(exc.strerror or str(exc)).lower()}") from None


@contextlib.contextmanager
def _about(path):
    """Errors of the library about ``path``'s content name the user's path."""
    try:
        yield
    except ValueError as exc:
        if isinstance(exc, CLIInputError) or str(path) in str(exc):
            raise
        raise CLIInputError(f"{path}: {exc}") from None


def _image_hdus(path):
    """Indices and names of the 2-D image HDUs of a FITS file (the CCDs)."""
    from astropy.io import fits

    from ..io._image import _tolerant_fits

    try:
        with _tolerant_fits(path), fits.open(path, memmap=False) as hdul:
            return [(i, h.name or str(i)) for i, h in enumerate(hdul)
                    if h.is_image and h.header.get("NAXIS", 0) == 2]
    except OSError as exc:
        raise CLIInputError(f"cannot read {path!r}: {exc}") from None


def _fit(args):
    if args.image is None and not args.stars:
        raise CLIInputError("give a FITS image, or a catalogue with VIGNET stamps (--stars)")
    if (args.x_col is None) != (args.y_col is None):
        raise CLIInputError("give both --x-col and --y-col, or neither")
    if args.hdu is not None and args.hdu.strip().lower() == "all":
        if args.image is None:
            raise CLIInputError("--hdu all needs a multi-extension FITS image")
        if args.weight_hdu is not None:
            raise CLIInputError("--hdu all cannot take one --weight-hdu: fit each CCD with "
                                "its own --hdu and --weight-hdu")
        stem = args.output[:-5] if args.output.lower().endswith(".fits") else args.output
        hdus = _image_hdus(args.image)
        if not hdus:
            raise CLIInputError(f"{args.image!r} holds no 2-D image HDU")
        jobs = [(i, f"{stem}_{name}.fits") for i, name in hdus]
        for _, out in jobs:
            _check_output_file(out)
        for index, out in jobs:
            print(f"HDU {index} -> {out}")
            _fit_one(argparse.Namespace(**{**vars(args), "hdu": str(index), "output": out}))
        return 0
    _check_output_file(args.output)
    return _fit_one(args)


def _select(args, catalog, saturation, image_shape, lines):
    """The star/galaxy selection of a catalogue given with --stars."""
    from ..io import select_stars

    lines.append(f"sources in the catalogue: {len(catalog)}"
                 f" ({'1' if catalog.meta['one_based'] else '0'}-based "
                 f"{catalog.meta['x_column']}, {catalog.meta['y_column']})")
    if image_shape is not None:
        x, y = np.asarray(catalog["x"]), np.asarray(catalog["y"])
        ny, nx = image_shape
        if not ((x > -0.5) & (x < nx - 0.5) & (y > -0.5) & (y < ny - 0.5)).any():
            raise CLIInputError(
                f"All {len(catalog)} catalogue positions fall outside the image {args.image} "
                f"(ny, nx = {ny}, {nx}): check the HDU, or whether the positions are 1-based "
                "(--one-based)")
    if args.no_select:
        return catalog
    # positions off the image or at its edge are counted when the stamps are cut
    keep, counts = select_stars(catalog, min_snr=args.min_snr, saturation=saturation,
                                stamp_size=args.stamp_size or 25)
    rejected = {k: v for k, v in counts.items() if not k.startswith("locus") and v}
    lines.append(f"selected as stars: {int(keep.sum())}" + (" (rejected: " + ", ".join(
        f"{k} {v}" for k, v in rejected.items()) + ")" if rejected else ""))
    if keep.sum() < 5:
        raise CLIInputError(f"{int(keep.sum())} stars of {args.stars} pass the selection: too "
                            "few for a PSF model; lower --min-snr or use --no-select")
    return catalog[keep]


def _fit_one(args):
    from tqdm.auto import tqdm

    from ..io import (celestial_wcs, extract_star_stamps, extract_vignettes, find_stars,
                     read_catalog, read_image, save_model)
    from ..model import PSFModel, make_interpolator
    from ..validation import fit_and_validate

    lines = []
    with tqdm(total=6, desc="reading", unit="step") as bar:
        header, image, weight, catalog = {}, None, None, None
        if args.image is not None:
            image, weight, header = read_image(args.image, hdu=args.hdu,
                                               weight_hdu=args.weight_hdu)
        if args.stars:
            with _about(args.stars):
                catalog = read_catalog(args.stars, one_based=True if args.one_based else None,
                                       x_col=args.x_col, y_col=args.y_col)
            if image is None:
                header = catalog.meta.get("image_header") or {}
        saturation = args.saturation
        if saturation is None and "SATURATE" in header:
            saturation = float(header["SATURATE"])
        bar.update()
        bar.set_description("selecting stars")
        if catalog is not None:
            catalog = _select(args, catalog, saturation,
                              None if image is None else image.shape, lines)
        else:
            catalog = find_stars(image, weight=weight, stamp_size=args.stamp_size or 25,
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
        if args.image is None:
            with _about(args.stars):
                cut = extract_vignettes(catalog, args.stamp_size, saturation=saturation,
                                        gain=header.get("GAIN"))
        else:
            with _about(args.stars or args.image):
                cut = extract_star_stamps(image, catalog, args.stamp_size or 25,
                                          weight=weight, saturation=saturation)
        skipped = {k: v for k, v in cut.counts.items() if k not in ("input", "used") and v}
        lines.append(f"stars used: {cut.counts['used']} of {cut.counts['input']}"
                     + (" (skipped: " + ", ".join(f"{k} {v}" for k, v in skipped.items()) + ")"
                        if skipped else ""))
        bar.update()
        bar.set_description("fitting and validating")
        wcs = celestial_wcs(header)
        options = {"reserve": args.reserve, "random_state": args.seed, "weights": cut.weights,
                   "wcs": wcs}
        if args.interpolator == "auto":
            candidates = {n: PSFModel(interpolator=make_interpolator(n))
                          for n in FIT_INTERPOLATORS}
            model, residuals, summary = fit_and_validate(
                cut.positions, cut.stamps, candidates=candidates, **options)
        else:
            model, residuals, summary = fit_and_validate(
                cut.positions, cut.stamps,
                PSFModel(interpolator=make_interpolator(args.interpolator)), **options)
        summary["selection"] = dict(cut.counts)
        summary["image"] = os.path.abspath(args.image or args.stars)
        summary["interpolator"] = summary.get("scheme", args.interpolator)
        if wcs is not None:  # predict can then take and return (RA, Dec)
            summary["wcs"] = wcs.to_header_string()
        bar.update()
        bar.set_description("saving")
        try:
            save_model(model, args.output, residuals=residuals if len(residuals) else None,
                       summary=summary, overwrite=True)
        except OSError as exc:
            raise CLIInputError(f"cannot write {args.output!r}: {exc.strerror or exc}") from None
        bar.update()
        written = [args.output]
        if not args.no_plots and len(residuals):
            bar.set_description("figures")
            if image is not None:
                shape = image.shape
            elif "NAXIS2" in header and "NAXIS1" in header:
                shape = (int(header["NAXIS2"]), int(header["NAXIS1"]))
            else:  # catalogue without image header: the stars' extent
                shape = tuple(int(v) + 1 for v in cut.positions.max(axis=0)[::-1])
            written += _fit_figures(residuals, summary, args.output, model, shape)
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
            f"{summary['dsigma_rms']:.4f} pixels, |rho1| mean {summary['rho1_mean_abs']:.2e}"
            + (" (rho statistics on the sky, arcmin)" if wcs is not None else ""))
    print("\n".join(lines))
    print(f"Wrote {', '.join(written)}")
    return 0


def _fit_figures(residuals, summary, output, model, shape):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..validation import plot_psf_maps, plot_rho_statistics, plot_stamp_residuals, \
        plot_whiskers

    paths = _figure_paths(output)
    written = []
    makers = {"stamps": lambda: plot_stamp_residuals(residuals),
              "whiskers": lambda: plot_whiskers(residuals),
              "maps": lambda: plot_psf_maps(model, shape)}
    if summary.get("rho1"):
        makers["rho"] = lambda: plot_rho_statistics(summary)
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

    from ..io import (celestial_wcs, draw_psf, extrapolation_flags, load_model, pixel_to_sky,
                     read_catalog, read_model_validation, sky_to_pixel)
    from .._files import write_fits_atomic
    from ..measure import adaptive_moments

    _check_output_file(args.output)
    if (args.x_col is None) != (args.y_col is None):
        raise CLIInputError("give both --x-col and --y-col, or neither")
    model = load_model(args.model)
    wcs = celestial_wcs((read_model_validation(args.model)[1] or {}).get("wcs"))
    if args.radec and wcs is None:
        raise CLIInputError(f"--radec: the model {args.model!r} has no WCS (its image had none)")
    with _about(args.positions):
        catalog = read_catalog(args.positions, one_based=True if args.one_based else None,
                               x_col=args.x_col, y_col=args.y_col, sky=args.radec)
    X = np.column_stack([np.asarray(catalog["x"]), np.asarray(catalog["y"])])
    if len(X) == 0:
        raise CLIInputError(f"the catalogue {args.positions} has no rows")
    bad = ~np.isfinite(X).all(axis=1)
    if bad.any():
        raise CLIInputError(f"{int(bad.sum())} positions of {args.positions} are NaN or "
                            f"infinite (first at row {int(np.flatnonzero(bad)[0])})")
    radec = X if args.radec else None
    if args.radec:
        X = sky_to_pixel(wcs, radec)
    elif wcs is not None:
        radec = pixel_to_sky(wcs, X)
    size = model.stamp_size_ * args.oversampling
    stamps = np.empty((len(X), size, size))
    chunk = 5000
    with tqdm(total=len(X), desc="predicting", unit="PSF") as bar:
        for start in range(0, len(X), chunk):
            stop = min(start + chunk, len(X))
            stamps[start:stop] = draw_psf(model, X[start:stop], centered=args.centered,
                                          oversampling=args.oversampling)
            bar.update(stop - start)
    mom = adaptive_moments(stamps)
    out = Table({"x": X[:, 0], "y": X[:, 1]})
    if radec is not None:
        out["ra"], out["dec"] = radec[:, 0], radec[:, 1]
    for name in catalog.colnames:
        if name not in out.colnames:
            out[name] = catalog[name]
    out["psf"] = stamps
    for name in ("e1", "e2", "sigma"):
        out[name] = np.asarray(mom[name], dtype=np.float64)
    if args.oversampling > 1:
        out["sigma"] /= args.oversampling  # in image pixels
    out["moments_flag"] = np.asarray(mom["flag"], dtype=np.int64)
    out["extrapolated"] = extrapolation_flags(model.X_fit_, X)
    hdu = fits.table_to_hdu(out)
    hdu.name = "PSF"
    hdu.header["MODEL"] = (os.path.basename(args.model), "PSF model file")
    hdu.header["STAMPSZ"] = (size, "stamp side in samples")
    hdu.header["OVERSAMP"] = (args.oversampling, "samples per pixel along each axis")
    hdu.header["CENTERED"] = (bool(args.centered), "PSF shifted to the sub-pixel position")
    hdu.header["COMMENT"] = ("x, y: 0-based pixel positions (x = column); psf: unit-sum "
                             "stamps centred on pixel floor(x + 0.5), floor(y + 0.5)")
    try:
        write_fits_atomic(fits.HDUList([fits.PrimaryHDU(), hdu]), args.output, overwrite=True)
    except OSError as exc:
        raise CLIInputError(f"cannot write {args.output!r}: {exc.strerror or exc}") from None
    flagged = int(np.sum(out["moments_flag"] != 0))
    n_extra = int(np.sum(out["extrapolated"]))
    print(f"PSFs at {len(X)} positions ({size}x{size} stamps, e1/e2/sigma measured"
          + (f"; {flagged} could not be measured" if flagged else "") + ")"
          + (f"; {n_extra} extrapolated (flagged in column 'extrapolated')" if n_extra else ""))
    print(f"Wrote {args.output}")
    return 0


def _check_output(path):
    try:
        os.makedirs(path, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path):
            pass
    except OSError as exc:
        raise CLIInputError(
            f"cannot write to the output folder {path!r}: {exc.strerror or exc}") from None
