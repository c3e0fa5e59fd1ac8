"""The ``fit`` and ``predict`` commands of ``sklearn-psf``: their parsers and runners.

``fit`` is :func:`sklearn_psf.exposure.fit_exposure` for each input, its report printed and
its model and figures saved; errors are raised as :class:`CLIInputError` (see ``_common``).
"""

from __future__ import annotations

import argparse
import os
import sys
from typing import NamedTuple

from ._common import (CLIInputError, _about, _bits, _check_input, _check_optional,
                      _check_output_file, _fraction, _n_jobs, _non_negative, _positive,
                      _positive_int, _stamp_size, _width)


#: The schemes ``fit --interpolator`` takes (sklearn_psf.model.INTERPOLATORS, listed here so
#: that building the parser imports no library module).
FIT_INTERPOLATORS = ("kriging", "polynomial", "chebyshev", "delaunay", "shepard", "rbf")


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
    fit.add_argument("--band-limit", type=_positive, metavar="CYCLES",
                     help="undersampled stars: the PSF's band limit in cycles per pixel, the "
                     "optics' cutoff D/lambda times the pixel scale in radians (2.4 m, 1.06 "
                     "um, 0.11\" pixels: 1.21); the super-resolved basis is then used, its "
                     "fine grid held to this band [chosen from the stars]")
    fit.add_argument("--stamp-size", type=_stamp_size,
                     help="stamp side [25; a catalogue's VIGNET side]; the star's pixel is at "
                     "index side // 2 (SExtractor's VIGNET convention, even sides too)")
    fit.add_argument("--seed", type=int, default=0, help="seed of the reserved-star draw [0]")
    fit.add_argument("--reserve-out", metavar="RESERVED.fits",
                     help="write the reserved stars' catalogue rows to this FITS catalogue, "
                     "and every other row to RESERVED_train.fits (a FITS or FITS_LDAC "
                     "catalogue input only): run PSFEx on the second, then 'sklearn-psf "
                     "validate --stars RESERVED.fits' judges both models on the same stars")
    fit.add_argument("--no-plots", action="store_true", help="do not write figures")
    fit.add_argument("--psfex", metavar="PATH.psf",
                     help="also write the model as a PSFEx .psf file (for Source Extractor's "
                     "PSF_NAME, GalSim's DES_PSFEx): its variation as a polynomial of "
                     "XWIN_IMAGE, YWIN_IMAGE of the degree, up to 8, that follows the model "
                     "best on a grid; the degree and the approximation error are printed. "
                     "One model only")
    fit.add_argument("--keys", nargs="+", metavar="COL",
                     help="catalogue columns (a colour, a magnitude, a flux) as further "
                     "dimensions of the model after x, y, as PSFEx's PSFVAR_KEYS; stars with "
                     "NaN in one are left out (counted); 'predict' reads the same columns at "
                     "the galaxies")
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
    sel.add_argument("--flag-mask", type=_bits, default=0xFE,
                     help="bits of FLAGS that reject a source [0xfe, PSFEx's: sources flagged "
                     "1, with neighbours, are kept and their neighbours masked]")
    sel.add_argument("--min-snr", type=_non_negative, default=20.0,
                     help="smallest S/N of a selected star [20]")
    sel.add_argument("--saturation", type=_positive,
                     help="saturation level [header SATURATE keyword, else none]")
    sel.add_argument("--isolation", type=_non_negative,
                     help="smallest distance in pixels (along x and y) to another source, "
                     "instead of the default: a star is rejected only when a neighbour's "
                     "light reaches its core, and the pixels of the other neighbours in its "
                     "stamp are masked (0: no crowding cut)")
    sel.add_argument("--locus-width", type=_width, default="auto",
                     help="relative half-width of the size-magnitude locus, or 'auto': 3 times "
                     "its scatter at each star's S/N [auto]")
    sel.add_argument("--max-spread-model", type=_non_negative, default=0.003,
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
    pred.add_argument("--keys", nargs="+", metavar="COL",
                      help="the catalogue's columns of the model's extra dimensions, in the "
                      "order of the fit's --keys [the names the model file stores]")
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
    if args.scheduler is not None:
        _check_optional("distributed", "--scheduler")
    jobs = _fit_jobs(args)
    inputs = [*args.image, *(args.stars or ())]
    for job in jobs:
        path, figures = _outputs(args, job.output)
        _check_output_file(path, args.overwrite, figures, inputs)
    if args.psfex is not None:
        if args.keys:
            raise CLIInputError("--psfex writes a model of x, y only: not with --keys")
        if len(jobs) > 1:
            raise CLIInputError("--psfex writes one .psf file: give one input (one model)")
        _check_output_file(args.psfex, args.overwrite, inputs=inputs)
    if args.reserve_out is not None:
        if len(jobs) > 1 or not args.stars:
            raise CLIInputError("--reserve-out writes the rows of one catalogue: give one "
                                "--stars catalogue (one model)")
        if args.reserve == 0:
            raise CLIInputError("--reserve-out needs reserved stars: --reserve is 0")
        for path in _reserve_paths(args.reserve_out):
            _check_output_file(path, args.overwrite, inputs=inputs)
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

    from ._parallel import dask_backend, map_ordered, prepare_workers

    for job in jobs:  # the workers may run in another folder, or on another machine
        job.shown, job.image, job.stars, job.output = (
            job.output, *(None if p is None else os.path.abspath(p)
                          for p in (job.image, job.stars, job.output)))
    failed, bugs, registry = [], [], {}
    outcomes = None
    if args.scheduler is None:  # the local workers fork before the progress bar's thread
        prepare_workers("sklearn_psf.validation", "treecorr",
                        *(() if args.no_plots else ("matplotlib.figure",
                                                    "matplotlib.backends.backend_agg")))
        outcomes = map_ordered(_fit_of_many, jobs, args.n_jobs)
    with dask_backend(args.scheduler), tqdm(total=len(jobs), desc="fitting",
                                            unit="model") as bar:
        if outcomes is None:
            outcomes = Parallel(n_jobs=args.n_jobs, return_as="generator")(
                delayed(_fit_of_many)(job) for job in jobs)
        for job, outcome in zip(jobs, outcomes):
            with tqdm.external_write_mode():
                print(f"{job.source} -> {job.shown}")
                _show(outcome, registry, shown_output=job.shown)
                if outcome.internal:
                    bugs.append(job.source)
                    print(f"sklearn-psf: internal error: {job.source}: "
                          f"{type(outcome.error).__name__}: {outcome.error}: a bug of "
                          "sklearn-psf, not of this input; fit it alone with --debug for the "
                          "traceback", file=sys.stderr)
                elif outcome.error is not None:
                    failed.append(job.source)
                    print(f"sklearn-psf: error: {job.source}: {outcome.error}", file=sys.stderr)
            bar.update()
    if failed or bugs:
        text = (f"{len(failed) + len(bugs)} of {len(jobs)} fits failed "
                f"({', '.join(failed + bugs)}: errors above); the other models were written")
        raise RuntimeError(text) if bugs else CLIInputError(text)
    return 0


class _FitOutcome(NamedTuple):
    """What a fit prints: its report ``lines``; the ``warnings`` to replay, each
    ``(message, category, filename, lineno)``, and this package's warnings about the fitted
    model (``notes``, plain text: the command prints them, and the process showing them need
    not import the library), in the order of printing; the files written and the error that
    stopped the fit (or None), and whether that error is internal (a bug, not the input's:
    judged where it was raised, since its traceback does not cross processes)."""

    lines: list
    warnings: list
    notes: list
    later_warnings: list
    written: list
    error: Exception | None
    internal: bool = False


def _plain(caught):
    return [(str(w.message), w.category, w.filename, w.lineno) for w in caught]


def _fit_one(args, quiet=False) -> _FitOutcome:
    """Fit the model of one input; print nothing (but the steps' progress bar unless
    ``quiet``): the outcome holds what to print, so that it can run in another process."""
    import warnings

    from .._files import is_input_error

    lines, fit_warnings, written, error = [], [], [], None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            written = _fit_steps(args, lines, fit_warnings, quiet)
        except Exception as exc:  # noqa: BLE001 - reported with the others' outcomes
            error = exc
    ours = [w.category.__module__.startswith("sklearn_psf") for w in fit_warnings]
    notes = [str(w.message) for w, mine in zip(fit_warnings, ours) if mine]
    others = _plain(w for w, mine in zip(fit_warnings, ours) if not mine)
    return _FitOutcome(lines, _plain(caught), notes, others, written, error,
                       error is not None and not is_input_error(error))


def _fit_of_many(args) -> _FitOutcome:
    """One fit of several: no progress bar of its own, one BLAS thread (the same arithmetic
    in any worker and with any --n-jobs, and no more threads than cores)."""
    from threadpoolctl import threadpool_limits

    # the BLAS and OpenMP libraries the fit uses are loaded with these: limited once loaded
    from .. import exposure, io, model, validation  # noqa: F401

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
    """Fit one input with :func:`~sklearn_psf.exposure.fit_exposure`, save the model and
    its figures; ``lines`` gets the report, ``fit_warnings`` the warnings of the fit (those
    of the reading and selection go on to the caller's record). Returns the files written."""
    import warnings

    from tqdm.auto import tqdm

    from ..model import save_model
    from ..exposure import SelectionCuts, StarSelectionError, fit_exposure

    with tqdm(total=5, desc="reading", unit="step", disable=quiet) as bar:
        fitting = []  # where the fit's own warnings start among those caught

        def progress(name):
            if name == "fitting and validating":
                fitting.append(len(caught))
            bar.update()
            bar.set_description(name)

        try:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                cuts = SelectionCuts(
                    flag_mask=args.flag_mask, min_snr=args.min_snr, isolation=args.isolation,
                    locus_width=args.locus_width, max_spread_model=args.max_spread_model,
                    min_class_star=args.min_class_star)
                fit = fit_exposure(
                    args.image, args.stars, hdu=args.hdu, weight_hdu=args.weight_hdu,
                    one_based=True if args.one_based else None, x_col=args.x_col,
                    y_col=args.y_col, select=not args.no_select, cuts=cuts,
                    saturation=args.saturation, stamp_size=args.stamp_size,
                    interpolator=args.interpolator, reserve=args.reserve,
                    random_state=args.seed, keys=args.keys, band_limit=args.band_limit,
                    progress=progress)
        except StarSelectionError as exc:
            hint = ("or use --no-select if the catalogue holds stars only" if args.stars
                    else "or give a star catalogue with --stars")
            lines += exc.lines
            raise CLIInputError(exc.text(CLI_OPTIONS, hint)) from None
        finally:
            start = fitting[0] if fitting else len(caught)
            for w in caught[:start]:  # the reading's and selection's: shown first
                warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
            fit_warnings += caught[start:]
        lines += fit.report()
        bar.update()
        bar.set_description("saving")
        try:
            save_model(fit.model, args.output,
                       residuals=fit.residuals if len(fit.residuals) else None,
                       summary=fit.summary, overwrite=args.overwrite)
        except OSError as exc:
            raise CLIInputError(f"cannot write {args.output!r}: {exc.strerror or exc}") from None
        written = [args.output]
        if getattr(args, "psfex", None):
            written.append(_write_psfex(args, fit, lines))
        if getattr(args, "reserve_out", None):
            written += _write_reserved(args, fit)
        if not args.no_plots:
            bar.set_description("figures")
            written += _save_figures(fit.figures(), _figure_paths(args.output))
        bar.update()
    return written


def _write_psfex(args, fit, lines):
    """The model as a PSFEx .psf over the field; its polynomial's degree and error go to the
    report."""
    import numpy as np

    from ..validation import to_psfex

    chi2 = fit.summary.get("chi2_dof")
    out = to_psfex(fit.model, args.psfex, image_shape=fit.image_shape, overwrite=args.overwrite,
                   chi2=chi2 if chi2 is not None and np.isfinite(chi2) else None)
    why = "within 5% of the best degree's" if out.model_error is None else \
        f"the model's own uncertainty {out.model_error:.2e}"
    lines.append(f"PSFEx file: polynomial of degree {out.degree} (up to 8; cross-validated "
                 f"error on a grid {out.cv_error[out.degree]:.2e} of the peak, {why}); its "
                 f"error against the model: pixel rms {out.pixel_rms:.2e} of the peak, e rms "
                 f"{out.e_rms:.4f}, size rms {out.size_rms:.4f} pixels")
    return args.psfex


def _reserve_paths(path):
    """The reserved stars' catalogue and the others' (``<stem>_train<ext>``)."""
    stem, ext = os.path.splitext(path)
    return path, f"{stem}_train{ext or '.fits'}"


def _write_reserved(args, fit):
    """The catalogue's reserved rows and the other rows, each to its own file."""
    import numpy as np

    from ..io import write_catalog_rows

    reserved = fit.stars.rows[np.asarray(fit.residuals["index"], dtype=int)]
    paths = _reserve_paths(args.reserve_out)
    with _about(args.stars):
        write_catalog_rows(args.stars, paths[0], reserved, overwrite=args.overwrite)
        write_catalog_rows(args.stars, paths[1], reserved, invert=True,
                           overwrite=args.overwrite)
    return list(paths)


def _save_figures(figures, paths):
    """Save each figure at its path, close it; the paths written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    for name, fig in figures.items():
        fig.savefig(paths[name], dpi=100)
        plt.close(fig)
    return [paths[name] for name in figures]


def _predict(args):
    """``predict``: :func:`~sklearn_psf.exposure.predict_catalog` at the catalogue's
    positions, written to a FITS table."""
    _check_input(args.model, "model file")
    _check_input(args.positions, "catalogue")
    _check_output_file(args.output, args.overwrite, inputs=(args.model, args.positions))
    if (args.x_col is None) != (args.y_col is None):
        raise CLIInputError("give both --x-col and --y-col, or neither")
    import numpy as np
    from astropy.io import fits
    from tqdm.auto import tqdm

    from .._files import write_fits_atomic
    from ..exposure import predict_catalog

    bars = []  # the bar starts with the drawing, as its total is known

    def progress(done, total):
        if not bars:
            bars.append(tqdm(total=total, desc="predicting", unit="PSF"))
        bars[0].update(done - bars[0].n)

    try:
        out = predict_catalog(args.model, args.positions,
                              one_based=True if args.one_based else None, x_col=args.x_col,
                              y_col=args.y_col, radec=args.radec, keys=args.keys,
                              centered=args.centered, oversampling=args.oversampling,
                              progress=progress)
    finally:
        for bar in bars:
            bar.close()
    keys, size = out.meta.pop("keys"), out["psf"].shape[1]
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
    n_out = int(np.sum(out["extrapolated"]))
    print(f"PSFs at {len(out)} positions ({size}x{size} stamps, e1/e2/sigma measured"
          + (f"; {flagged} could not be measured" if flagged else "")
          + (f"; model dimensions x, y, {', '.join(keys)}" if keys else "") + ")"
          + (f"; {n_out} extrapolated (flagged in column 'extrapolated'"
             + (": off the stars' positions or beyond their range of a key" if keys else "")
             + ")" if n_out else ""))
    print(f"Wrote {args.output}")
    return 0
