"""The ``validate`` command of ``sklearn-psf``: several PSF models on the same reserved stars.

Building the parser imports nothing heavy; the runner imports the library (and GalSim or PIFF
only for their models) when it runs.
"""

from __future__ import annotations

import os

from ._common import (CLIInputError, _about, _bits, _check_input, _check_not_input,
                      _check_optional, _non_negative, _output_folder, _positive, _stamp_size)

#: Files ``validate`` writes in its output folder (figures only without --no-plots).
OUTPUTS = {"table": "validation.csv", "rho": "validation_rho.png",
           "residuals": "validation_residuals.png", "stamps": "validation_stamps.png",
           "whiskers": "validation_whiskers.png"}
_FIGURES = [name for key, name in OUTPUTS.items() if key != "table"]


def add_validate_parser(sub):
    """Add ``sklearn-psf validate`` to the subcommands."""
    p = sub.add_parser(
        "validate", help="compare PSF models (this package's, PSFEx .psf, PIFF) on the same "
        "reserved stars",
        description="Measure the same residuals of each model on the same stars: e1, e2 and "
        "size (adaptive moments) of star minus model, the chi^2 of each raw star against the "
        "model in the star's noise, and rho1-rho5; print one table and write it "
        f"({OUTPUTS['table']}) with figures ({', '.join(_FIGURES)}) to the output folder. "
        "Give stars none of the models was fitted on. PIFF models need PIFF "
        "(pip install 'sklearn-psf[piff]').",
    )
    p.add_argument("image", nargs="?",
                   help="FITS image to cut the stars' stamps from; optional with a catalogue "
                   "holding VIGNET stamps (SExtractor FITS_LDAC)")
    p.add_argument("--stars", required=True, metavar="CATALOG",
                   help="catalogue of the reserved stars: FITS_LDAC with VIGNETs, or a FITS "
                   "table / ASCII / CSV with x, y (or X_IMAGE, Y_IMAGE) and an image")
    p.add_argument("-m", "--model", action="append", required=True, metavar="FILE",
                   help="model file (repeat for each model): written by 'sklearn-psf fit', a "
                   "PSFEx .psf, or a PIFF file; the kind is read from the file")
    p.add_argument("-o", "--output", required=True, metavar="FOLDER",
                   help="folder for the table and the figures (created if needed)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace the table and figures of an earlier run in the folder")
    p.add_argument("--hdu", help="image HDU: index or EXTNAME [first 2-D image]")
    p.add_argument("--weight-hdu", help="weight/mask HDU of the same file (0 = bad pixel)")
    p.add_argument("--x-col", help="column of the catalogue's x positions")
    p.add_argument("--y-col", help="column of the catalogue's y positions")
    p.add_argument("--one-based", action="store_true",
                   help="the catalogue's x, y are 1-based (FITS convention); X_IMAGE/Y_IMAGE "
                   "columns are always read as 1-based")
    p.add_argument("--select", action="store_true",
                   help="apply the star selection of 'fit' to the catalogue [use every row]")
    p.add_argument("--min-snr", type=_non_negative, default=20.0,
                   help="smallest S/N of a selected star, with --select [20]")
    p.add_argument("--flag-mask", type=_bits, default=0xFE,
                   help="bits of FLAGS that leave a star out [0xfe, PSFEx's and fit's: "
                   "stars flagged 1, with neighbours, are judged]")
    p.add_argument("--stamp-size", type=_stamp_size,
                   help="stamp side, odd or even [25; a catalogue's VIGNET side]")
    p.add_argument("--saturation", type=_positive,
                   help="saturation level [header SATURATE keyword, else none]")
    p.add_argument("--model-origin", type=int, choices=(0, 1), default=1,
                   help="pixel convention of PSFEx and PIFF models: 1 = FITS (X_IMAGE), as "
                   "PSFEx and PIFF on FITS images use [1]")
    p.add_argument("--chipnum", type=int, help="CCD of a multi-chip PIFF model")
    p.add_argument("--keys", nargs="+", metavar="COL",
                   help="the catalogue's columns of the extra dimensions of models fitted "
                   "with 'fit --keys' [the names their model file stores]")
    p.add_argument("--no-plots", action="store_true", help="do not write figures")
    return p


def _stars(args):
    """Positions, stamps, weights, WCS and a line on the stars used."""
    import numpy as np

    from ..io import celestial_wcs
    from ..exposure import select_stars
    from ..exposure import read_exposure

    with _about(args.stars):
        inputs = read_exposure(args.image, args.stars, hdu=args.hdu,
                               weight_hdu=args.weight_hdu,
                               one_based=True if args.one_based else None, x_col=args.x_col,
                               y_col=args.y_col, saturation=args.saturation)
    catalog = inputs.catalog
    n_rows = len(catalog)
    if args.select:
        keep, counts = select_stars(catalog, min_snr=args.min_snr, saturation=inputs.saturation,
                                    flag_mask=args.flag_mask,
                                    stamp_size=args.stamp_size or 25)
        if keep.sum() < 1:
            reasons = ", ".join(f"{k} {v}" for k, v in counts.items()
                                if v and not k.startswith("locus"))
            raise CLIInputError(f"no star of {args.stars} passes the selection ({reasons}); "
                                "leave out --select or lower --min-snr")
        catalog = catalog[keep]
    if "flags" in catalog.colnames:  # judged as fit and PSFEx accept them: flag 1 is fine
        catalog = catalog.copy(copy_data=False)
        catalog["flags"] = np.asarray(catalog["flags"]).astype(np.int64) & args.flag_mask
    cut = inputs.cut_stamps(catalog, args.stamp_size)
    skipped = ", ".join(f"{k} {v}" for k, v in cut.counts.items()
                        if k not in ("input", "used") and v)
    line = (f"stars: {cut.counts['used']} used of {n_rows} rows"
            + (f" ({len(catalog)} selected)" if args.select else "")
            + (f" (skipped: {skipped})" if skipped else ""))
    return cut, celestial_wcs(inputs.header), line


def _print_table(table):
    cols = (("model", "model", "{}"), ("kind", "kind", "{}"), ("rank", "rank", "{}"),
            ("n_measured", "stars", "{}"), ("chi2_dof", "chi2/dof", "{:.3f}"),
            ("e_rms", "e rms", "{:.4f}"), ("dsigma_rms", "size rms [px]", "{:.4f}"),
            ("rho1_mean_abs", "|rho1|", "{:.2e}"), ("rho2_mean_abs", "|rho2|", "{:.2e}"),
            ("dM22_rel_rms", "dM22/s^4 rms", "{:.2e}"), ("dM4_rel_rms", "dM4/s^4 rms", "{:.2e}"))
    rows = [[fmt.format(r[key]) for key, _, fmt in cols] for r in table]
    widths = [max(len(title), *(len(row[j]) for row in rows)) for j, (_, title, _) in
              enumerate(cols)]
    print("  ".join(title.ljust(w) for (_, title, _), w in zip(cols, widths)))
    for row in sorted(rows, key=lambda r: int(r[2])):
        print("  ".join(v.ljust(w) for v, w in zip(row, widths)))


def _model_keys(path):
    """The catalogue keys a model file of this package names (None for other files)."""
    from ..model import read_model_validation
    from ..validation import model_kind

    if model_kind(path) != "sklearn_psf":
        return None
    return (read_model_validation(path)[1] or {}).get("keys")


def run_validate(args) -> int:
    """Run ``sklearn-psf validate``."""
    for path in args.model:
        if not os.path.isfile(path):
            raise CLIInputError(f"model file {path!r} does not exist")
    _check_input(args.stars, "catalogue")
    if args.image is not None:
        _check_input(args.image, "image")
    if (args.x_col is None) != (args.y_col is None):
        raise CLIInputError("give both --x-col and --y-col, or neither")
    out = args.output
    if os.path.exists(out) and not os.path.isdir(out):
        raise CLIInputError(f"the output {out!r} is a file: give a folder")
    names = [v for k, v in OUTPUTS.items() if k == "table" or not args.no_plots]
    _check_not_input([os.path.join(out, n) for n in names],
                     [*args.model, args.stars, args.image])
    existing = [n for n in names if os.path.exists(os.path.join(out, n))]
    if existing and not args.overwrite:
        raise CLIInputError(f"{out!r} already holds {', '.join(existing)} (an earlier run): "
                            "give another folder or --overwrite")
    from ..validation import model_kind

    for path in args.model:
        with _about(path):
            if model_kind(path) == "piff":
                _check_optional("piff", f"Reading the PIFF model {path!r}")
    with _output_folder(out):
        return _validate(args, out)


def _validate(args, out) -> int:
    """The run of ``validate`` once its inputs are checked and its folder made."""
    from ..validation import validate_models

    cut, wcs, line = _stars(args)
    print(line)
    X = cut.positions
    keys = args.keys or next((k for k in map(_model_keys, args.model) if k), None)
    if keys:  # the extra dimensions, from the stars' own columns
        import numpy as np

        from ..exposure import key_columns

        used = np.flatnonzero(np.asarray(cut.catalog["used"], dtype=bool))
        extra = key_columns(cut.catalog[used], keys, f"the catalogue {args.stars!r}")
        bad = ~np.isfinite(extra).all(axis=1)
        if bad.any():
            raise CLIInputError(f"{int(bad.sum())} stars of {args.stars} have NaN or infinite "
                                f"values in {', '.join(keys)}: the models need them")
        X = np.column_stack([X, extra])
        print(f"model dimensions after x, y: {', '.join(keys)}")
    with _about(", ".join(args.model)):
        table, results = validate_models(X, cut.stamps, list(args.model),
                                         weights=cut.weights, wcs=wcs,
                                         origin=args.model_origin, chipnum=args.chipnum)
    written = [os.path.join(out, OUTPUTS["table"])]
    table.write(written[0], format="ascii.csv", overwrite=True)
    if not args.no_plots:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        from ..validation import plot_model_comparison

        for name, fig in plot_model_comparison(results).items():
            path = os.path.join(out, OUTPUTS[name])
            fig.savefig(path, dpi=100)
            plt.close(fig)
            written.append(path)
    units = table.meta.get("rho_theta_units", "pixel")
    left_out = ", ".join(f"{k} {v}" for k, v in table.meta["left_out"].items() if v)
    if left_out:
        print(f"stars left out of the comparison: {left_out}")
    print(f"star - model on the same stars (rank 1: lowest chi2/dof, each model moved to "
          f"each star by a fitted sub-pixel shift; e and size from "
          f"{table.meta['moments']} moments, size in pixels; |rho| mean over separations in "
          f"{units}):")
    _print_table(table)
    if len(table) > 1:  # how sure the ranking is: the best model against each other, star by star
        import numpy as np

        from ..validation import paired_comparison

        order = [str(m) for m in table["model"][np.argsort(table["rank"])]]
        best = results[order[0]][0]
        for other in order[1:]:
            r = paired_comparison(best["chi2"], results[other][0]["chi2"], best["dof"])
            if r["n"]:
                print(f"{order[0]} against {other}, star by star: lower chi^2 on "
                      f"{r['a_lower']:.0%} of {r['n']} stars (sign test p = {r['sign_p']:.2g}; "
                      f"mean chi^2/dof difference {r['mean_diff']:+.4f}, 95% interval "
                      f"{r['mean_diff_ci'][0]:+.4f} to {r['mean_diff_ci'][1]:+.4f})")
    print(f"Wrote {', '.join(written)}")
    return 0
