"""The ``fit`` and ``predict`` commands of ``sklearn-psf``: their parsers and runners.

Errors are raised as :class:`CLIInputError` (a ``ValueError``) with a one-line message naming
the user's path; the entry point prints them and exits with status 2.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
import tempfile
from typing import NamedTuple


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


def _n_jobs(text):
    try:
        value = int(text)
    except ValueError:
        value = None
    if not value:
        raise argparse.ArgumentTypeError(f"expected a number of jobs (1, 2, ..., or -1 for "
                                         f"one per core), got {text!r}")
    return value


def _stamp_size(text):
    value = _positive_int(text)
    if value < 5:
        raise argparse.ArgumentTypeError(f"expected a stamp size >= 5, got {value}")
    return value


def _number(text):
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None


def _bits(text):
    try:
        return int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected an integer (e.g. 254 or 0xfe), got {text!r}") from None


def _width(text):
    return text if text == "auto" else _number(text)


#: ``sklearn-psf fit`` options relaxing each selection cut (the parameters of select_stars).
CLI_OPTIONS = {
    "flag_mask": "--flag-mask",
    "min_snr": "--min-snr",
    "saturation": "--saturation",
    "stamp_size": "--stamp-size",
    "isolation": "--isolation",
    "locus_width": "--locus-width",
    "max_spread_model / min_class_star": "--max-spread-model / --min-class-star",
}


def _add_fit_parsers(sub):
    fit = sub.add_parser(
        "fit", help="build a validated PSF model of a FITS image or a catalogue and save it",
        description="Select stars (on the image, or in a catalogue: flags, S/N, saturation, "
        "isolation, the size-magnitude locus, then SPREAD_MODEL/CLASS_STAR where they agree "
        "with it), cut their stamps with the weight map (or take the catalogue's VIGNETs: no "
        "image needed), reserve a fraction for validation, fit a PSF model, print a verdict on "
        "it (the reserved stars' residuals against their own noise and against a constant PSF, "
        "rho1-rho5; a warning when the model is not trustworthy), save it as a FITS model file "
        "and write diagnostic figures next to it (MODEL_stamps.png: reserved stars, model, "
        "residuals; MODEL_whiskers.png: e of stars/model/residuals; MODEL_rho.png: rho1-rho5; "
        "MODEL_maps.png: model e and size across the chip). Existing files are not replaced "
        "without --overwrite. Several images (or catalogues, or --hdu all) give one model "
        "each, fitted in parallel with --n-jobs or on a Dask cluster with --scheduler; the "
        "models are the same as fitted one by one.",
    )
    fit.add_argument("image", nargs="*", metavar="IMAGE",
                     help="FITS image(s) (.fits, .fits.fz), one model each; none with "
                     "catalogues holding VIGNET stamps (SExtractor FITS_LDAC)")
    fit.add_argument("-o", "--output", required=True,
                     help="model file to write (FITS); with several inputs (images, "
                     "catalogues or the HDUs of --hdu all), one file per input named "
                     "OUTPUT_<name>.fits, <name> the input file's name and/or the HDU's "
                     "EXTNAME or index")
    fit.add_argument("--hdu", help="image HDU: index or EXTNAME, or 'all' for one model per "
                     "CCD of a multi-extension file [first 2-D image]")
    fit.add_argument("--weight-hdu", help="weight/mask HDU of the same file (0 = bad pixel)")
    fit.add_argument("--stars", metavar="CATALOG", nargs="+",
                     help="source catalogue(s): FITS table, SExtractor FITS_LDAC or ASCII, CSV "
                     "with x, y or X_IMAGE, Y_IMAGE; one per image (or per HDU with --hdu "
                     "all), in the same order, given after the images; default: stars "
                     "selected on the image")
    fit.add_argument("--x-col", help="column of the catalogue's x positions (0-based unless "
                     "--one-based)")
    fit.add_argument("--y-col", help="column of the catalogue's y positions")
    fit.add_argument("--one-based", action="store_true",
                     help="the catalogue's x, y are 1-based (FITS convention); X_IMAGE/Y_IMAGE "
                     "columns are always read as 1-based")
    fit.add_argument("--interpolator", default="kriging", choices=FIT_INTERPOLATORS + ("auto",),
                     help="interpolation scheme (each in the noise-aware PSFModel: "
                     "StampPCA basis, chi^2 outlier rejection), or 'auto' to choose it by "
                     "5-fold cross-validation [kriging: range fitted by maximum likelihood]")
    fit.add_argument("--reserve", type=_fraction, default=0.2,
                     help="fraction of stars reserved for validation [0.2]")
    fit.add_argument("--stamp-size", type=_stamp_size,
                     help="stamp side [25; a catalogue's VIGNET side]; the star's pixel is at "
                     "index side // 2 (SExtractor's VIGNET convention, even sides too)")
    fit.add_argument("--seed", type=int, default=0, help="seed of the reserved-star draw [0]")
    fit.add_argument("--no-plots", action="store_true", help="do not write figures")
    fit.add_argument("--overwrite", action="store_true",
                     help="replace an existing model file and its figures")
    fit.add_argument("--n-jobs", type=_n_jobs, default=1,
                     help="models fitted at once, each in its own process (-1: one per core) "
                     "[1]")
    fit.add_argument("--scheduler", metavar="ADDRESS",
                     help="fit on the Dask cluster at ADDRESS (joblib's dask backend; its "
                     "workers must read and write the files at the same paths); --n-jobs is "
                     "then the cluster's")
    sel = fit.add_argument_group(
        "star selection", "cuts of select_stars (and of the finder on the image), in this "
        "order; the size-magnitude locus is the primary point-source test")
    sel.add_argument("--no-select", action="store_true",
                     help="use every catalogue row as a star (no star/galaxy selection)")
    sel.add_argument("--flag-mask", type=_bits,
                     help="bits of FLAGS that reject a source [every bit; PSFEx: 0xfe]")
    sel.add_argument("--min-snr", type=float, default=20.0,
                     help="smallest S/N of a selected star [20]")
    sel.add_argument("--saturation", type=float,
                     help="saturation level [header SATURATE keyword, else none]")
    sel.add_argument("--isolation", type=float,
                     help="smallest distance in pixels (along x and y) to another source "
                     "[half the stamp + 3; 0: no crowding cut]")
    sel.add_argument("--locus-width", type=_width, default="auto",
                     help="relative half-width of the size-magnitude locus, or 'auto': 3 times "
                     "its scatter at each star's S/N [auto]")
    sel.add_argument("--max-spread-model", type=float, default=0.003,
                     help="largest |SPREAD_MODEL| (+ 2 SPREADERR_MODEL) of a point source, "
                     "unless it would reject most of the locus [0.003]")
    sel.add_argument("--min-class-star", type=float, default=0.8,
                     help="smallest CLASS_STAR of a point source (without SPREAD_MODEL), "
                     "unless it would reject most of the locus [0.8]")

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
    pred.add_argument("--overwrite", action="store_true", help="replace an existing output")


def _stem(output):
    """A model file's path without ``.fits``: the start of its figures' paths."""
    return output[:-5] if output.lower().endswith(".fits") else output


def _figure_paths(output):
    return {name: f"{_stem(output)}_{name}.png" for name in ("stamps", "whiskers", "rho", "maps")}


def _check_input(path, what):
    """Fail at once (before importing the library) when an input file is missing."""
    if not os.path.exists(path):
        raise CLIInputError(f"the {what} {path!r} does not exist")
    if os.path.isdir(path):
        raise CLIInputError(f"the {what} {path!r} is a folder: give a file")


def _check_output_file(path, overwrite=False, also=()):
    """Fail before any work when ``path`` cannot be written, or when it (or one of ``also``,
    files written with it) exists and ``overwrite`` is not set."""
    folder = os.path.dirname(os.path.abspath(path)) or "."
    if not os.path.isdir(folder):
        raise CLIInputError(f"the folder of the output file {path!r} does not exist")
    if os.path.isdir(path):
        raise CLIInputError(f"the output {path!r} is a folder: give a file name")
    existing = [p for p in (path, *also) if os.path.exists(p)]
    if existing and not overwrite:
        more = f" (and {len(existing) - 1} more output files)" if len(existing) > 1 else ""
        raise CLIInputError(f"{existing[0]!r} already exists{more}: pass --overwrite to "
                            "replace it")
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
    """Indices and names of the 2-D image HDUs of a FITS file (the CCDs), from its headers
    alone: astropy's notes on them are left to the reading of each CCD, which reports them,
    and the library is not imported here (the fits of several CCDs import it in their own
    processes)."""
    import warnings

    from astropy.io import fits

    try:
        with warnings.catch_warnings(), fits.open(path, memmap=False) as hdul:
            warnings.simplefilter("ignore")
            return [(i, h.name or str(i)) for i, h in enumerate(hdul)
                    if h.is_image and h.header.get("NAXIS", 0) == 2]
    except OSError as exc:
        raise CLIInputError(f"cannot read {path!r}: {exc}") from None


def _outputs(args, output):
    """The model file and the figures written next to it."""
    return output, () if args.no_plots else tuple(_figure_paths(output).values())


def _name(path):
    """A file's name without its folder and its data-file suffixes (``ccd01.fits.fz``:
    ``ccd01``)."""
    name = os.path.basename(path)
    suffixes = (".fz", ".gz", ".fits", ".fit", ".fts", ".ldac", ".cat", ".csv", ".ecsv", ".txt")
    while name.lower().endswith(suffixes) and "." in name[1:]:
        name = name[:name.rindex(".")]
    return name


def _fit_jobs(args):
    """One namespace of ``args`` per model to fit: its ``image`` (with ``hdu``), ``stars`` and
    ``output``, and ``source``, the input as shown on the terminal."""
    images, catalogs = list(args.image), list(args.stars or ())
    if not images and not catalogs:
        raise CLIInputError("give a FITS image, or a catalogue with VIGNET stamps (--stars)")
    for path in images:
        _check_input(path, "image")
    for path in catalogs:
        _check_input(path, "catalogue")
    if (args.x_col is None) != (args.y_col is None):
        raise CLIInputError("give both --x-col and --y-col, or neither")
    every_hdu = args.hdu is not None and args.hdu.strip().lower() == "all"
    if every_hdu:
        if not images:
            raise CLIInputError("--hdu all needs a multi-extension FITS image")
        if args.weight_hdu is not None:
            raise CLIInputError("--hdu all cannot take one --weight-hdu: fit each CCD with "
                                "its own --hdu and --weight-hdu")
        units = []
        for image in images:
            hdus = _image_hdus(image)
            if not hdus:
                raise CLIInputError(f"{image!r} holds no 2-D image HDU")
            units += [(image, str(i), name) for i, name in hdus]
    else:
        units = [(image, args.hdu, None) for image in images]
    if images and catalogs and len(catalogs) != len(units):
        what = (f"{len(units)} image HDUs" if every_hdu else f"{len(units)} images")
        raise CLIInputError(f"{len(catalogs)} catalogues (--stars) for {what}: give one "
                            "catalogue per image" + (" HDU" if every_hdu else "")
                            + ", in the same order, or none")
    if not images:
        units = [(None, args.hdu, None)] * len(catalogs)
    catalogs = catalogs or [None] * len(units)
    named = len(set(images or catalogs)) > 1  # outputs named after the input files
    jobs, seen = [], {}
    for (image, hdu, hdu_name), catalog in zip(units, catalogs):
        output = args.output
        if every_hdu or len(units) > 1:
            label = "_".join(p for p in (_name(image or catalog) if named else None, hdu_name)
                             if p)
            output = f"{_stem(args.output)}_{label}.fits"
        source = image or catalog if hdu_name is None else f"{image}[{hdu_name}]"
        if output in seen:
            raise CLIInputError(f"{seen[output]} and {source} would both be written to "
                                f"{output!r}: give input files distinct names")
        seen[output] = source
        jobs.append(argparse.Namespace(**{**vars(args), "image": image, "stars": catalog,
                                          "hdu": hdu, "output": output, "source": source}))
    return jobs


def _fit(args):
    jobs = _fit_jobs(args)
    for job in jobs:
        path, figures = _outputs(args, job.output)
        _check_output_file(path, args.overwrite, figures)
    if len(jobs) > 1 or args.scheduler is not None:
        return _fit_many(jobs, args)
    outcome = _fit_one(jobs[0])
    _show(outcome, warnings_registry={})
    if outcome.error is not None:
        raise outcome.error
    return 0


def _fit_many(jobs, args):
    """Fit ``jobs`` in parallel (or on the Dask cluster); print each one's report as in a
    single fit, in the order given, under a progress bar. A failed fit does not stop the
    others; the command then ends with an error naming them."""
    from joblib import Parallel, delayed
    from tqdm.auto import tqdm

    from ._parallel import dask_backend, map_ordered

    for job in jobs:  # the workers may run in another folder, or on another machine
        job.shown, job.image, job.stars, job.output = (
            job.output, *(None if p is None else os.path.abspath(p)
                          for p in (job.image, job.stars, job.output)))
    failed, registry = [], {}
    with dask_backend(args.scheduler), tqdm(total=len(jobs), desc="fitting",
                                            unit="model") as bar:
        outcomes = (map_ordered(_fit_of_many, jobs, args.n_jobs) if args.scheduler is None
                    else Parallel(n_jobs=args.n_jobs, return_as="generator")(
                        delayed(_fit_of_many)(job) for job in jobs))
        for job, outcome in zip(jobs, outcomes):
            with tqdm.external_write_mode():
                print(f"{job.source} -> {job.shown}")
                _show(outcome, registry, shown_output=job.shown)
                if outcome.error is not None:
                    failed.append(job.source)
                    print(f"sklearn-psf: error: {job.source}: {outcome.error}", file=sys.stderr)
            bar.update()
    if failed:
        raise CLIInputError(f"{len(failed)} of {len(jobs)} fits failed ({', '.join(failed)}: "
                            "errors above); the other models were written")
    return 0


def _counts_text(counts, keys):
    """``"flags 2, low_snr 28"``: the non-zero counts of ``keys``."""
    return ", ".join(f"{k} {counts[k]}" for k in keys if counts.get(k))


def _too_few(head, counts, hint):
    """The error when fewer than 5 stars are selected: each cut's count and its option."""
    from ..io import SELECTION_OPTIONS, SELECTION_REASONS

    options = {reason: CLI_OPTIONS.get(param, param)
               for reason, param in SELECTION_OPTIONS.items()}
    per_cut = ", ".join(f"{k} {counts[k]} ({options[k]})" for k in SELECTION_REASONS
                        if counts.get(k) and k in options)
    return CLIInputError(
        f"{head}: too few for a PSF model (need 5)"
        + (f"; dropped by cut (option relaxing it): {per_cut}" if per_cut else "")
        + f"; {hint}")


def _selection_lines(counts, n_kept, lines, head, args):
    import numpy as np

    from ..io import SELECTION_REASONS

    rejected = _counts_text(counts, SELECTION_REASONS)
    lines.append(f"{head}{n_kept}" + (f" (rejected: {rejected})" if rejected else ""))
    size = {"flux_radius": "FLUX_RADIUS", "adaptive_sigma": "adaptive-moment sigma of the "
            "VIGNETs"}.get(counts.get("locus_size"))
    if size and np.isfinite(counts["locus_radius"]):
        lines.append(f"  size-magnitude locus: {size} {counts['locus_radius']:.3g} pixels "
                     f"(median over the selected stars), accepted within +-"
                     f"{counts['locus_width']:.1%} (median; wider at low S/N)")
    cuts = {"class_star": f"CLASS_STAR >= {args.min_class_star:g} (--min-class-star)",
            "spread_model": f"|SPREAD_MODEL| <= {args.max_spread_model:g} "
                            "(--max-spread-model)"}
    for name, fraction in counts.get("not_applied", {}).items():
        lines.append(f"  not applied: {cuts[name]}, which would reject {fraction:.0%} of the "
                     "sources on the size-magnitude locus"
                     + (" (SExtractor's CLASS_STAR depends on the SEEING_FWHM it was given)"
                        if name == "class_star" else ""))


def _select(args, catalog, saturation, image_shape, stamp_size, lines):
    """The star/galaxy selection of a catalogue given with --stars."""
    import numpy as np

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
    keep, counts = select_stars(
        catalog, min_snr=args.min_snr, saturation=saturation, flag_mask=args.flag_mask,
        stamp_size=stamp_size, isolation=args.isolation, locus_width=args.locus_width,
        max_spread_model=args.max_spread_model, min_class_star=args.min_class_star,
        min_stars=0)
    _selection_lines(counts, int(keep.sum()), lines, "selected as stars: ", args)
    if keep.sum() < 5:
        raise _too_few(f"{int(keep.sum())} of the {len(catalog)} sources of {args.stars} pass "
                       "the star selection", counts,
                       "or use --no-select if the catalogue holds stars only")
    catalog = catalog[keep]
    if args.flag_mask is not None and "flags" in catalog.colnames:
        # flags outside the mask were accepted: the stamp cutters must not skip them again
        catalog["flags"] = np.asarray(catalog["flags"]).astype(np.int64) & int(args.flag_mask)
    return catalog


def _gain(header):
    """Detector gain (e-/ADU): GAIN, else the gain SExtractor used (SEXGAIN); None."""
    for key in ("GAIN", "SEXGAIN"):
        value = header.get(key)
        if isinstance(value, (int, float)) and value > 0:
            return float(value)
    return None


class _Inputs(NamedTuple):
    """What ``fit`` and ``validate`` read: the image (None without one), its weight and
    header (else the catalogue's image header), the catalogue (None without --stars), the
    saturation level (--saturation, else the header's SATURATE) and the gain."""

    image: object
    weight: object
    header: dict
    catalog: object
    saturation: float | None
    gain: float | None


def _read_inputs(args) -> _Inputs:
    """Read ``args.image`` (``--hdu``, ``--weight-hdu``) and the catalogue ``args.stars``."""
    from ..io import read_catalog, read_image

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
    return _Inputs(image, weight, header, catalog, saturation, _gain(header))


def _cut_stamps(inputs, catalog, args):
    """The stamps of ``catalog``'s stars: the VIGNETs without an image (at ``--stamp-size``,
    default their side), else cut from the image (default side 25)."""
    from ..io import extract_star_stamps, extract_vignettes

    if inputs.image is None:
        with _about(args.stars):
            return extract_vignettes(catalog, args.stamp_size, saturation=inputs.saturation,
                                     gain=inputs.gain)
    with _about(args.stars or args.image):
        return extract_star_stamps(inputs.image, catalog, args.stamp_size or 25,
                                   weight=inputs.weight, saturation=inputs.saturation)


def _skipped_text(counts):
    """`` (skipped: masked 2, saturated 1)`` from the counts of a stamp cut, or ""."""
    skipped = {k: v for k, v in counts.items() if k not in ("input", "used") and v}
    return (" (skipped: " + ", ".join(f"{k} {v}" for k, v in skipped.items()) + ")"
            if skipped else "")


class _FitOutcome(NamedTuple):
    """What a fit prints: its report ``lines``; the ``warnings`` to replay, each
    ``(message, category, filename, lineno)``, and this package's warnings about the fitted
    model (``notes``, plain text: the command prints them, and the process showing them need
    not import the library), in the order of printing; the files written and the error that
    stopped the fit (or None)."""

    lines: list
    warnings: list
    notes: list
    later_warnings: list
    written: list
    error: Exception | None


def _plain(caught):
    return [(str(w.message), w.category, w.filename, w.lineno) for w in caught]


def _fit_one(args, quiet=False) -> _FitOutcome:
    """Fit the model of one input; print nothing (but the steps' progress bar unless
    ``quiet``): the outcome holds what to print, so that it can run in another process."""
    import warnings

    lines, fit_warnings, written, error = [], [], [], None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            written = _fit_steps(args, lines, fit_warnings, quiet)
        except (CLIInputError, ValueError, OSError) as exc:
            error = exc
    ours = [w.category.__module__.startswith("sklearn_psf") for w in fit_warnings]
    notes = [str(w.message) for w, mine in zip(fit_warnings, ours) if mine]
    others = _plain(w for w, mine in zip(fit_warnings, ours) if not mine)
    return _FitOutcome(lines, _plain(caught), notes, others, written, error)


def _fit_of_many(args) -> _FitOutcome:
    """One fit of several: no progress bar of its own, one BLAS thread (the same arithmetic
    in any worker and with any --n-jobs, and no more threads than cores)."""
    from threadpoolctl import threadpool_limits

    # the BLAS and OpenMP libraries the fit uses are loaded with these: limited once loaded
    from .. import io, model, validation  # noqa: F401

    with threadpool_limits(limits=1):
        return _fit_one(args, quiet=True)


def _show(outcome, warnings_registry, shown_output=None):
    """Print a fit's report as it happened: the warnings of the reading, the report, the
    fit's own warnings (this package's as ``sklearn-psf: warning:`` lines), the files
    written (named after ``shown_output``, the model file as the user gave it)."""
    import warnings

    def replay(message, category, filename, lineno):
        warnings.warn_explicit(message, category, filename, lineno,
                               registry=warnings_registry)

    for w in outcome.warnings:
        replay(*w)
    if outcome.lines:
        print("\n".join(outcome.lines))
    for note in outcome.notes:
        print(f"sklearn-psf: warning: {note}", file=sys.stderr)
    for w in outcome.later_warnings:
        replay(*w)
    if outcome.written:
        written = outcome.written
        if shown_output is not None:  # the model file first, its figures named after it
            start, shown = _stem(written[0]), _stem(shown_output)
            written = [shown + p[len(start):] for p in written]
        print(f"Wrote {', '.join(written)}")


def _fit_steps(args, lines, fit_warnings, quiet=False):
    import warnings

    import numpy as np
    from tqdm.auto import tqdm

    from ..io import celestial_wcs, find_stars, save_model
    from ..model import PSFModel, make_interpolator
    from ..validation import fit_and_validate

    with tqdm(total=6, desc="reading", unit="step", disable=quiet) as bar:
        inputs = _read_inputs(args)
        image, header, catalog, saturation = (inputs.image, inputs.header, inputs.catalog,
                                              inputs.saturation)
        n_nan = 0
        if image is not None:
            n_nan = int(np.isnan(image).sum())
            weight = inputs.weight
            n_zero = 0 if weight is None else int(np.sum(~(np.asarray(weight) > 0)))
            lines.append(f"image: {image.shape[1]} x {image.shape[0]} pixels; NaN pixels: "
                         f"{n_nan}" + ("" if weight is None else
                                       f"; zero-weight pixels: {n_zero}")
                         + " (masked: a star with one in its core is skipped)")
        vignettes = image is None and catalog is not None and "VIGNET" in [
            c.upper() for c in catalog.colnames]
        stamp_size = args.stamp_size
        if stamp_size is None:
            stamp_size = (int(np.shape(catalog[[c for c in catalog.colnames
                                                if c.upper() == "VIGNET"][0]])[1])
                          if vignettes else 25)
        bar.update()
        bar.set_description("selecting stars")
        if catalog is not None:
            catalog = _select(args, catalog, saturation,
                              None if image is None else image.shape, stamp_size, lines)
        else:
            catalog = find_stars(image, weight=inputs.weight, stamp_size=stamp_size,
                                 min_snr=args.min_snr, saturation=saturation,
                                 isolation=args.isolation, locus_width=args.locus_width)
            counts = {**catalog.meta["rejected"], "locus_size": None}
            _selection_lines(counts, len(catalog), lines, f"sources detected: "
                             f"{catalog.meta['n_detections']}, selected as stars: ", args)
            if len(catalog) < 5:
                raise _too_few(f"found {len(catalog)} usable stars in {args.image} "
                               f"({catalog.meta['n_detections']} detections)", counts,
                               "or give a star catalogue with --stars")
        bar.update()
        bar.set_description("cutting stamps")
        cut = _cut_stamps(inputs, catalog, args)
        lines.append(f"stars used: {cut.counts['used']} of {cut.counts['input']}"
                     + _skipped_text(cut.counts))
        bar.update()
        bar.set_description("fitting and validating")
        wcs = celestial_wcs(header)
        options = {"reserve": args.reserve, "random_state": args.seed, "weights": cut.weights,
                   "wcs": wcs}
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            if args.interpolator == "auto":
                candidates = {n: PSFModel(interpolator=make_interpolator(n))
                              for n in FIT_INTERPOLATORS}
                model, residuals, summary = fit_and_validate(
                    cut.positions, cut.stamps, candidates=candidates, **options)
            else:
                model, residuals, summary = fit_and_validate(
                    cut.positions, cut.stamps,
                    PSFModel(interpolator=make_interpolator(args.interpolator)), **options)
        fit_warnings += caught
        summary["selection"] = dict(cut.counts)
        summary["image"] = os.path.abspath(args.image or args.stars)
        summary["interpolator"] = summary.get("scheme", args.interpolator)
        summary["nan_pixels"] = n_nan
        summary["saturation"] = saturation
        summary["gain"] = inputs.gain
        if wcs is not None:  # predict can then take and return (RA, Dec)
            summary["wcs"] = wcs.to_header_string()
        bar.update()
        bar.set_description("saving")
        try:
            save_model(model, args.output, residuals=residuals if len(residuals) else None,
                       summary=summary, overwrite=args.overwrite)
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
    lines += _report(summary, wcs is not None)
    return written


def _report(summary, sky):
    """The lines of the fit's report after the selection: basis, residuals, verdict."""
    import numpy as np

    lines = []
    if "cv" in summary:
        lines.append("cross-validation (e rms): " + ", ".join(
            f"{r['scheme']} {r['e_rms']:.4f}" for r in summary["cv"])
            + f" -> {summary['scheme']}")
    lines.append(f"interpolator: {summary['interpolator']}; fitted stars: {summary['n_fit']}, "
                 f"outliers rejected: {summary['n_outliers']}, reserved: "
                 f"{summary['n_reserved']}")
    if "n_components" in summary:
        lines.append(f"basis: {summary['n_components']} components: "
                     f"{summary['components_reason']}")
    if summary.get("kriging_range") is not None:
        lines.append(f"Kriging range (maximum likelihood): {summary['kriging_range']:.3g}; "
                     f"stars' typical spacing: {summary['star_spacing']:.3g} (median distance "
                     "to the nearest star; both in the interpolator's coordinates, the field "
                     "scaled to the unit square)")
    if summary["n_measured"]:
        lines.append(
            f"reserved stars (star - model, {summary['n_measured']} measured): "
            f"e rms {summary['e_rms']:.4f} (e1 mean {summary['de1_mean']:+.4f} rms "
            f"{summary['de1_rms']:.4f}, e2 mean {summary['de2_mean']:+.4f} rms "
            f"{summary['de2_rms']:.4f}), size mean {summary['dsigma_mean']:+.4f} rms "
            f"{summary['dsigma_rms']:.4f} pixels; {summary.get('moments', 'adaptive')} moments")
    if summary.get("n_verdict"):
        lines.append(
            f"reserved stars against their own noise ({summary['n_verdict']} stars; a constant "
            f"PSF fitted on the same stars in brackets): median chi^2 per degree of freedom "
            f"{summary['chi2_dof_median']:.3f} ({summary['chi2_dof_median_constant']:.3f}); "
            f"e residual rms "
            f"over e noise rms {summary['e_resid_over_noise']:.2f} "
            f"({summary['e_resid_over_noise_constant']:.2f}; e noise per component "
            f"{summary['e_noise']:.4f}); 1 is pure noise")
    if summary.get("rho1"):
        unit = "arcmin" if sky else "pixel"
        means = []
        for k in range(1, 6):
            xi = np.asarray((summary.get(f"rho{k}") or {}).get("xi", []), dtype=float)
            means.append(f"rho{k} {np.nanmean(np.abs(xi)):.2e}" if np.isfinite(xi).any()
                         else f"rho{k} -")
        theta = summary["rho1"]["theta"]
        lines.append(f"rho statistics of the reserved stars (mean |rho| over {len(theta)} bins, "
                     f"{theta[0]:.3g}-{theta[-1]:.3g} {unit}): " + ", ".join(means))
    return lines


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
    _check_input(args.model, "model file")
    _check_input(args.positions, "catalogue")
    _check_output_file(args.output, args.overwrite)
    import numpy as np
    from astropy.io import fits
    from astropy.table import Table
    from tqdm.auto import tqdm

    from ..io import (celestial_wcs, draw_psf, extrapolation_flags, load_model, pixel_to_sky,
                     read_catalog, read_model_validation, sky_to_pixel)
    from .._files import write_fits_atomic
    from ..measure import adaptive_moments

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
        write_fits_atomic(fits.HDUList([fits.PrimaryHDU(), hdu]), args.output,
                          overwrite=args.overwrite)
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
