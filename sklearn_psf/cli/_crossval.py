"""The ``crossval`` command of ``sklearn-psf``: this package's model and PSFEx (or the user's
models) judged star by star by K-fold cross-validation on the same catalogue."""

from __future__ import annotations

import os

from ._common import (CLIInputError, _about, _check_input, _check_optional, _non_negative,
                      _output_folder, _positive_int)

#: Files ``crossval`` writes in its output folder (the figure only without --no-plots).
OUTPUTS = {"table": "crossval.csv", "figure": "crossval.png"}


def _setting(text):
    key, sep, value = text.partition("=")
    if not sep or not key.strip() or not value.strip():
        import argparse

        raise argparse.ArgumentTypeError(f"expected a PSFEx setting KEY=VALUE (e.g. "
                                         f"PSF_SIZE=31,31), got {text!r}")
    return key.strip().upper(), value.strip()


def add_crossval_parser(sub):
    """Add ``sklearn-psf crossval`` to the subcommands."""
    p = sub.add_parser(
        "crossval", help="judge this package's model against PSFEx (or your models) by "
        "K-fold cross-validation on one catalogue",
        description="Split the stars this package selects from a Source Extractor FITS_LDAC "
        "catalogue (with VIGNETs: PSFEx's input) into K folds; for each fold, fit this "
        "package's model and PSFEx on the catalogue without that fold (each with its own "
        "selection and outlier rejection) and judge both on the fold's stars: every star "
        "is judged once, out of sample, by every model, in the same pixels and noise (chi^2 "
        "of the raw star against the model moved to it by a fitted sub-pixel shift, flux "
        "and background fitted). Prints the paired comparison on the stars both tools "
        "accept (the fraction of stars where each is closer, a sign test, the summed chi^2 "
        "ratio, a bootstrap interval of the mean difference) and writes the per-star table "
        f"({OUTPUTS['table']}) and a figure ({OUTPUTS['figure']}).")
    p.add_argument("--stars", required=True, metavar="CATALOG",
                   help="SExtractor FITS_LDAC catalogue with VIGNET stamps")
    p.add_argument("-o", "--output", required=True, metavar="FOLDER",
                   help="folder for the table and the figure (created if needed)")
    p.add_argument("--folds", type=_positive_int, default=5, help="number of folds [5]")
    p.add_argument("--seed", type=int, default=0, help="seed of the folds [0]")
    p.add_argument("--no-psfex", action="store_true",
                   help="do not run PSFEx [run it when installed]")
    p.add_argument("--psfex-degrees", type=int, nargs="+", metavar="D",
                   help="one PSFEx model per PSFVAR_DEGREES value [2]")
    p.add_argument("--psfex-config", type=_setting, nargs="+", default=[], metavar="KEY=VALUE",
                   help="PSFEx settings for every PSFEx model, e.g. SAMPLE_FWHMRANGE=1,10 for "
                   "undersampled stars [PSFEx's defaults, one thread]")
    p.add_argument("-m", "--model", action="append", default=[], metavar="PATTERN",
                   help="your own model of each fold: a file name with {fold} (1 to K) "
                   "standing for the fold, fitted on fold{fold}_train.ldac (write them with "
                   "--write-folds); a PSFEx .psf, a PIFF file or this package's")
    p.add_argument("--write-folds", action="store_true",
                   help="keep each fold's training catalogue in the output folder "
                   "(fold<k>_train.ldac) to fit other tools on")
    p.add_argument("--interpolator", default="kriging",
                   choices=["kriging", "polynomial", "chebyshev", "delaunay", "shepard", "rbf"],
                   help="this package's interpolation scheme [kriging]")
    p.add_argument("--min-snr", type=_non_negative, default=20.0,
                   help="smallest S/N of a selected star [20]")
    p.add_argument("--overwrite", action="store_true",
                   help="replace the table and figure of an earlier run in the folder")
    p.add_argument("--no-plots", action="store_true", help="do not write the figure")
    return p


def _figure(cv):
    """Per-star chi^2 of this package's model relative to each other model's, against the
    star's S/N, and their histogram."""
    import matplotlib.pyplot as plt
    import numpy as np

    t = cv.table[np.asarray(cv.table["judged"], dtype=bool)]
    ours = np.asarray(t[f"chi2_{cv.models[0]}"], float)
    snr = np.asarray(t["snr"], float)
    fig, axes = plt.subplots(1, 2, figsize=(10.5, 4.2), layout="constrained")
    rel = []
    for k, name in enumerate(cv.models[1:]):
        pct = 100.0 * (ours / np.asarray(t[f"chi2_{name}"], float) - 1.0)
        ok = np.isfinite(pct)
        r = cv.compare(cv.models[0], name)
        lo, hi = r["mean_diff_ci"]
        label = (f"{name}: ours lower on {r['a_lower']:.0%} (p = {r['sign_p']:.1g}); summed "
                 f"{100 * (r['sum_ratio'] - 1):+.2f}%")
        x = snr[ok] if np.isfinite(snr).any() else np.flatnonzero(ok)
        axes[0].scatter(x, pct[ok], s=12, alpha=0.7, color=f"C{k}", label=label)
        rel.append((name, pct[ok]))
    axes[0].axhline(0, color="0.4", lw=1, ls="--")
    axes[0].set_yscale("symlog", linthresh=1.0)
    axes[0].set(xscale="log" if np.isfinite(snr).any() else "linear",
                xlabel="star's S/N (catalogue)" if np.isfinite(snr).any() else "star",
                ylabel="chi^2 ours / other - 1 [%] (< 0: ours closer)",
                title="each star, judged out of sample by both")
    axes[0].legend(fontsize=7, loc="lower left")
    every = np.concatenate([d for _, d in rel]) if rel else np.zeros(1)
    lim = max(float(np.nanpercentile(np.abs(every), 90)), 0.1)
    bins = np.linspace(-lim, lim, 31)
    for k, (name, d) in enumerate(rel):
        axes[1].hist(np.clip(d, -lim, lim), bins=bins, histtype="step", color=f"C{k}",
                     lw=1.5, label=f"{name}: median {np.median(d):+.3f}%")
    axes[1].axvline(0, color="0.4", lw=1, ls="--")
    axes[1].set(xlabel="chi^2 ours / other - 1 [%] (the outer 10% piled at the edges)",
                ylabel="stars", title="their distribution")
    axes[1].legend(fontsize=8)
    return fig


def run_crossval(args) -> int:
    """Run ``sklearn-psf crossval``."""
    _check_input(args.stars, "catalogue")
    out = args.output
    if os.path.exists(out) and not os.path.isdir(out):
        raise CLIInputError(f"the output {out!r} is a file: give a folder")
    names = [OUTPUTS["table"]] + ([] if args.no_plots else [OUTPUTS["figure"]])
    if args.write_folds:
        names += [f"fold{k + 1}_train.ldac" for k in range(args.folds)]
    existing = [n for n in names if os.path.exists(os.path.join(out, n))]
    if existing and not args.overwrite:
        raise CLIInputError(f"{out!r} already holds {', '.join(existing[:3])} (an earlier "
                            "run): give another folder or --overwrite")
    for pattern in args.model:
        if "{fold}" not in pattern:
            raise CLIInputError(f"-m {pattern!r}: a model per fold needs {{fold}} in its name "
                                "(e.g. piff_fold{fold}.piff)")
        for k in range(args.folds):
            _check_input(pattern.format(fold=k + 1), "model file")
    from ..io import find_program

    run_psfex = not args.no_psfex and find_program("psfex") is not None
    if not run_psfex and not args.model:
        raise CLIInputError("nothing to compare with: PSFEx is not installed (or --no-psfex) "
                            "and no -m model is given")
    config = {"NTHREADS": 1, **dict(args.psfex_config)}
    degrees = args.psfex_degrees or [2]
    psfex = {f"psfex_d{d}": {**config, "PSFVAR_DEGREES": d} for d in degrees} \
        if run_psfex else None
    for path in args.model:
        with _about(path):
            from ..validation import model_kind

            if model_kind(path.format(fold=1)) == "piff":
                _check_optional("piff", f"Reading the PIFF model {path!r}")
    with _output_folder(out):
        return _crossval(args, out, psfex)


def _crossval(args, out, psfex) -> int:
    """The run of ``crossval`` once its inputs are checked and its folder made."""
    from tqdm.auto import tqdm

    from ..exposure import SelectionCuts, cross_validate_catalog

    models = {os.path.basename(p).replace("{fold}", "K"):
              (lambda k, train, p=p: p.format(fold=k + 1)) for p in args.model}
    with tqdm(total=args.folds, desc="cross-validating", unit="fold") as bar, \
            _about(args.stars):
        def progress(text):
            if text.startswith("fold") and bar.n < int(text.split()[1]) - 1:
                bar.update()

        cv = cross_validate_catalog(
            args.stars, n_folds=args.folds, psfex=psfex, random_state=args.seed,
            fit_options={"interpolator": args.interpolator,
                         "cuts": SelectionCuts(min_snr=args.min_snr)},
            models=models, progress=progress, work_dir=out if args.write_folds else None)
        bar.update(bar.total - bar.n)
    written = [os.path.join(out, OUTPUTS["table"])]
    cv.table.write(written[0], format="ascii.csv", overwrite=True)
    if not args.no_plots:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig = _figure(cv)
        written.append(os.path.join(out, OUTPUTS["figure"]))
        fig.savefig(written[-1], dpi=100)
        plt.close(fig)
    c = cv.counts
    print(f"catalogue: {c['n_rows']} rows; selected by sklearn-psf: {c['n_selected']}"
          + "".join(f"; accepted by {name}: {n}" for name, n in zip(cv.models[1:], c["n_psfex"]))
          + f"; sklearn-psf's models rest on {min(c['n_fit'])}-{max(c['n_fit'])} stars")
    print("\n".join(cv.lines()))
    print(f"Wrote {', '.join(written)}")
    return 0
