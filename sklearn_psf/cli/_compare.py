"""``sklearn-psf compare``: its parser and its runner (the study of :mod:`sklearn_psf.study`)."""

from __future__ import annotations

import argparse
from dataclasses import replace
from functools import partial

from ._common import (CLIInputError, _check_optional, _n_jobs, _output_folder, _positive,
                      _positive_int)
from ._parallel import dask_backend, local_pool, prepare_workers

#: Sizes of ``sklearn-psf compare``: ``"paper"`` (the default) and ``"quick"`` (``--quick``);
#: explicit options override them.
PRESETS = {
    # The paper: 50 simulations of 1000 stars and 2000 galaxy-PSFs on a Subaru-sized image.
    "paper": {"n_simulations": 50, "study_simulations": 10, "n_stars": 1000, "n_galaxies": 2000,
              "image_shape": (7769, 10032)},
    # A few minutes on 2 cores: the same image and densities, fewer simulations (underpowered:
    # the report says so next to each verdict).
    "quick": {"n_simulations": 4, "study_simulations": 2, "n_stars": 1000, "n_galaxies": 2000,
              "image_shape": (7769, 10032)},
}
#: Side studies of ``sklearn-psf compare`` (``--studies``).
STUDIES = ("maps", "snr", "density", "outliers", "tuning", "scale", "exposures", "colour")
#: Studies run only when named in ``--studies``.
OPT_IN_STUDIES = ("colour",)
#: Schemes of the side studies: the paper's figures of the discussion show these three.
STUDY_SCHEMES = ("polynomial", "delaunay", "kriging")
# Embedded reference bases: the default (5 components, 90% of the variance) and one the size of
# the paper's Subaru basis (13 components).
REFERENCES = {"default": 5, "paper13": 13}
# The smallest scale of the simulated PSF variation (arcsec) tried by the "scale" study.
SCALE_STUDY = (4.0, 8.0, 16.0)
# The "exposures" study under --quick: the three variance ratios at one dither (otherwise
# run_exposure_study's defaults: 9 regimes x 3 simulations, 1-8 exposures of 120 and 240 stars).
EXPOSURES_QUICK = {"n_exposures": (1, 2, 4), "n_stars": (120,), "n_simulations": 1,
                   "dithers": (300.0,)}


def _snr(text):
    if text == "realistic":
        return text
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number or 'realistic', got {text!r}") from None
    if not value > 0:
        raise argparse.ArgumentTypeError(f"S/N must be positive, got {value}")
    return value


def _shape(text):
    try:
        ny, nx = (int(v) for v in text.lower().replace("x", ",").split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected NY,NX in pixels, got {text!r}") from None
    if ny <= 0 or nx <= 0:
        raise argparse.ArgumentTypeError(f"image sides must be positive, got {text!r}")
    return ny, nx


def _csv_list(text):
    return [item.strip() for item in text.split(",") if item.strip()]


def add_compare_parser(sub):
    """Add the ``compare`` command to the sub-parsers ``sub``."""
    cmp = sub.add_parser(
        "compare",
        help="run the paper's comparison of interpolation schemes on simulated PSF fields",
        description="Simulate PSF fields from the embedded reference, fit a PSF model per "
        "interpolation scheme on the stars, evaluate it at the galaxy-PSFs against the optimal "
        "predictor of the same field, and write tables, figures and a Markdown report.",
    )
    cmp.add_argument("-o", "--output", default="sklearn_psf_results", help="output folder")
    cmp.add_argument("--overwrite", action="store_true",
                     help="replace the outputs of an earlier run in the output folder (the "
                     "files its report.md lists, and the tables, are removed first)")
    cmp.add_argument("--quick", action="store_true",
                     help="a few simulations only: minutes instead of the paper's 50 simulations "
                          "(too few to decide most verdicts; the report says so)")
    cmp.add_argument("--n-simulations", type=_positive_int, help="simulations of the main comparison")
    cmp.add_argument("--study-simulations", type=_positive_int,
                     help="simulations per configuration of the side studies")
    cmp.add_argument("--n-stars", type=_positive_int, help="stars per simulation [1000]")
    cmp.add_argument("--n-galaxies", type=_positive_int, help="galaxy-PSFs per simulation [2000]")
    cmp.add_argument("--image-shape", type=_shape, metavar="NY,NX",
                     help="simulated image size in pixels [7769,10032: Subaru SuprimeCam]")
    cmp.add_argument("--snr", type=_snr, default=100.0, help="star S/N, or 'realistic' [100]")
    cmp.add_argument("--smallest-scale", type=_positive, metavar="ARCSEC",
                     help="smallest scale of the simulated PSF variation, arcsec [8: the "
                          "cell of the simulations' random fields]")
    cmp.add_argument("--reference", default="default", metavar="NAME|PATH",
                     help="reference basis of the simulations: 'default' (5 components), "
                          "'paper13' (13 components, the size of the paper's basis) or a "
                          "ReferenceBasis FITS file")
    cmp.add_argument("--schemes", type=_csv_list,
                     help="comma-separated schemes of the main comparison (default: all)")
    cmp.add_argument("--studies", type=_csv_list,
                     default=[n for n in STUDIES if n not in OPT_IN_STUDIES],
                     help=f"comma-separated studies among {','.join(STUDIES)}, or 'none' "
                     f"[all but {', '.join(OPT_IN_STUDIES)}: the colour study (a chromatic "
                     "PSF, models with and without a g-i dimension) runs only when named]")
    cmp.add_argument("--seed", type=int, default=0, help="seed of the whole study [0]")
    cmp.add_argument("--n-jobs", type=_n_jobs,
                     help="simulations and figures at once, each in its own process (-1: one "
                          "per core) [the cores this process may use, fewer if the free memory "
                          "cannot give each 2 GB; with --scheduler, the cluster's]; the tables "
                          "are the same with any number")
    cmp.add_argument("--scheduler", metavar="ADDRESS",
                     help="run on the Dask cluster at ADDRESS (joblib's dask backend)")
    return cmp


def _load_reference(name):
    from .. import datasets

    if name in REFERENCES:
        return datasets.load_default_reference(n_components=REFERENCES[name])
    try:
        return datasets.ReferenceBasis.load(name)
    except (OSError, ValueError) as exc:
        raise CLIInputError(f"--reference {name!r} is neither an embedded basis "
                            f"({', '.join(REFERENCES)}) nor a readable ReferenceBasis FITS "
                            f"file ({exc})") from None


#: Files of a run whose names do not depend on the study (the figures are listed in report.md).
OWN_FILES = ("report.md", "scores.csv", "scores.fits", "galaxies.fits", "correlations.fits",
             "config.json", "exposures.md", "sigma_sys_vs_exposures.png", "exposure_scores.csv",
             "colour.md", "size_vs_colour.png", "colour_scores.csv")


def _earlier_outputs(folder):
    """The files of an earlier run in ``folder``: the fixed names and the files listed under
    "## Files" in its report.md (plain names of that folder only)."""
    from pathlib import Path

    folder = Path(folder)
    names = set(OWN_FILES)
    report = folder / "report.md"
    if report.is_file():
        listed = False
        for line in report.read_text(encoding="utf-8", errors="replace").splitlines():
            if line.startswith("## "):
                listed = line.strip() == "## Files"
            elif listed and line.startswith("- `") and line.rstrip().endswith("`"):
                name = line.strip()[3:-1]
                if name and Path(name).name == name and name.endswith(
                        (".png", ".csv", ".fits", ".json", ".md")):
                    names.add(name)
    return sorted(p for p in (folder / n for n in names) if p.is_file())


def _check_earlier_run(folder, overwrite):
    """Refuse a folder holding an earlier run's outputs unless ``overwrite``."""
    earlier = _earlier_outputs(folder)
    if earlier and not overwrite:
        shown = ", ".join(p.name for p in earlier[:4]) + (", ..." if len(earlier) > 4 else "")
        raise CLIInputError(
            f"the output folder {folder!r} holds the outputs of an earlier run ({len(earlier)} "
            f"files: {shown}): pass --overwrite to replace them, or choose another folder "
            "with -o")
    return earlier


# Peak memory of one simulation task: 2.0 GB measured with 4000 stars on the paper's image (the
# density study's largest), 0.8 GB with 1000 stars and every scheme.
TASK_MEMORY = 2 * 2**30


#: What the tasks import beyond this command's imports (once, before the workers fork).
TASK_MODULES = ("sklearn_psf.datasets", "sklearn_psf.simulate", "sklearn_psf.study.colour",
                "treecorr", "matplotlib.font_manager")


def _default_n_jobs():
    """The cores this process may run on (CPU affinity, container quota), fewer when the free
    memory cannot hold one simulation task per core."""
    import os

    from joblib import cpu_count

    cores = cpu_count()
    try:
        free = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, ValueError, OSError):  # not on every system
        return cores
    return max(1, min(cores, free // TASK_MEMORY))


def _selected(names, available, what):
    unknown = [n for n in names if n not in available]
    if unknown:
        raise CLIInputError(f"unknown {what} {unknown[0]!r}; choose among {', '.join(available)}")
    return names


def run_compare(args) -> int:
    """Run ``sklearn-psf compare``: the study, its report, a summary on the terminal; a run
    that fails leaves no empty output folder."""
    if args.scheduler is not None:
        _check_optional("distributed", "--scheduler")
    with _output_folder(args.output):
        return _compare(args)


def _compare(args) -> int:
    import numpy as np
    from joblib import delayed
    from tqdm.auto import tqdm

    from ..metrics import requirement_curves, survey_table
    from ..study import compare
    from ..study.exposures import run_exposure_study
    from ..study.report import write_report

    preset = dict(PRESETS["quick" if args.quick else "paper"])
    n_sims = args.n_simulations or preset["n_simulations"]
    study_sims = args.study_simulations or preset["study_simulations"]
    studies = [] if args.studies == ["none"] else _selected(args.studies, STUDIES, "study")
    all_schemes = compare.default_schemes()
    names = _selected(args.schemes or list(all_schemes), list(all_schemes), "scheme")
    schemes = {n: all_schemes[n] for n in names}
    study_schemes = {n: all_schemes[n] for n in STUDY_SCHEMES}
    n_jobs = args.n_jobs or (-1 if args.scheduler else _default_n_jobs())
    earlier = _check_earlier_run(args.output, args.overwrite)
    reference = _load_reference(args.reference)

    base = compare.SimulationConfig(
        n_stars=args.n_stars or preset["n_stars"],
        n_galaxies=args.n_galaxies or preset["n_galaxies"],
        snr=args.snr,
        image_shape=args.image_shape or preset["image_shape"],
        smallest_scale=args.smallest_scale,
    ).validate()
    # the side studies (their schemes are the paper's, not the tuned ones)
    side = []
    if "maps" in studies:
        side.append(dict(configs=[replace(base, label="grid", galaxy_layout="grid")],
                         schemes=dict(schemes), n_simulations=1, oracle=False))
    # the oracle everywhere but in the grid maps and with planted outliers it does not model
    if "snr" in studies:
        side.append(dict(configs=compare.snr_study_configs(base), schemes=study_schemes,
                         n_simulations=study_sims, oracle=True))
    if "density" in studies:
        side.append(dict(configs=compare.density_study_configs(base), schemes=study_schemes,
                         n_simulations=study_sims, oracle=True))
    if "outliers" in studies:
        side.append(dict(configs=compare.outlier_study_configs(base), schemes=study_schemes,
                         n_simulations=study_sims, oracle=False))
    if "scale" in studies:
        side.append(dict(configs=compare.scale_study_configs(base, SCALE_STUDY),
                         schemes=study_schemes, n_simulations=study_sims, oracle=True))
    # other tasks of the same pool: the tuning, the example stars of fig_sim and, under
    # --quick, the small exposures study
    seed = int(np.random.SeedSequence(args.seed).spawn(1)[0].generate_state(1, np.uint32)[0])
    others = [delayed(compare.example_stars)(base, seed, reference)]
    if "exposures" in studies and args.quick:
        others.append(delayed(run_exposure_study)(random_state=args.seed, n_jobs=1,
                                                  **EXPOSURES_QUICK))
    tune = "tuning" in studies
    if tune:
        others.insert(0, delayed(compare.tune_schemes)(base, random_state=args.seed,
                                                       reference=reference, n_jobs=1))
    main_run = dict(configs=[base], schemes=schemes, n_simulations=n_sims, oracle=True)
    total = n_sims + sum(len(r["configs"]) * r["n_simulations"] for r in side) + len(others)
    # the workers (forked on Linux) start with the tasks' imports, before the progress bars
    with local_pool(None if args.scheduler else n_jobs,
                    prepare=partial(prepare_workers, *TASK_MODULES)):
        with dask_backend(args.scheduler), \
                tqdm(total=total, desc="simulations", unit="task") as bar:
            run = partial(compare.run_studies, random_state=args.seed, reference=reference,
                          n_jobs=n_jobs, progress=bar.update)
            if tune:
                # the main comparison needs the tuned schemes: the side studies run with the
                # tuning
                results = run(side, other_tasks=others)
                tuning, (stamps, positions), *exposures = results[len(side):]
                schemes.update(compare.tuned_schemes(tuning))
                _add_default_model(schemes, args)
                results = [*run([main_run]), *results[:len(side)]]
            else:
                tuning = None
                _add_default_model(schemes, args)
                results = run([main_run, *side], other_tasks=others)
                (stamps, positions), *exposures = results[len(side) + 1:]
                results = results[:len(side) + 1]
        result = compare.combine_results(results)
        curves = requirement_curves(result.theta)
        result.requirements = dict(zip(curves.levels, curves.d1_limit))
        result.surveys = survey_table()
        result.tuning = tuning
        result.config["quick"] = bool(args.quick)
        result.config["studies"] = list(studies)  # (the report's summary names them)
        result.config["reference"] = args.reference
        for path in earlier:  # no figure of the earlier run stays next to the new report
            path.unlink(missing_ok=True)
        paths = write_report(result, args.output, stamps=stamps, positions=positions,
                             n_jobs=-1 if args.scheduler else n_jobs)  # figures drawn locally
        if "exposures" in studies:
            paths = [*paths, *_run_exposures(args, n_jobs, *exposures)]
        if "colour" in studies:
            paths = [*paths, *_run_colour(args, n_jobs)]
    print(_summary_text(result))
    print(f"\nWrote {len(paths)} files to {args.output}/ (report: {args.output}/report.md)")
    return 0


def _add_default_model(schemes, args):
    """The library's own defaults (basis, outlier rejection, interpolator) next to the paper's
    settings, after the tuned schemes, unless the user chose the schemes."""
    from ..model import PSFModel
    from ..study.compare import DEFAULT_MODEL

    if not args.schemes:
        schemes[DEFAULT_MODEL] = PSFModel()


def _run_exposures(args, n_jobs, result=None):
    """The multi-exposure study (unless its ``result`` is given): its table, figure and
    exposures.md, its section in report.md."""
    from pathlib import Path

    from tqdm.auto import tqdm

    from ..study.exposures import (
        exposure_report_section,
        run_exposure_study,
        write_exposure_report,
    )

    if result is None:
        with dask_backend(args.scheduler), tqdm(desc="exposures study", unit="sim") as bar:
            result = run_exposure_study(random_state=args.seed, n_jobs=n_jobs,
                                        progress=bar.update,
                                        **(EXPOSURES_QUICK if args.quick else {}))
    md = write_exposure_report(result, args.output)
    with open(Path(args.output) / "report.md", "a", encoding="utf-8") as fh:
        fh.write("\n" + exposure_report_section(result))
    return [md, md.with_name("sigma_sys_vs_exposures.png"), md.with_name("exposure_scores.csv")]


def _run_colour(args, n_jobs):
    """The colour study (fewer simulations under --quick): colour_scores.csv, its figure and
    colour.md, its section in report.md."""
    from pathlib import Path

    from tqdm.auto import tqdm

    from ..study.colour import colour_report_section, run_colour_study, write_colour_report

    with dask_backend(args.scheduler), tqdm(desc="colour study", unit="sim") as bar:
        result = run_colour_study(random_state=args.seed, n_jobs=n_jobs, progress=bar.update,
                                  **({"n_simulations": 1} if args.quick else {}))
    md = write_colour_report(result, args.output)
    with open(Path(args.output) / "report.md", "a", encoding="utf-8") as fh:
        fh.write("\n" + colour_report_section(result))
    return [md, md.with_name("size_vs_colour.png"), md.with_name("colour_scores.csv")]


def _summary_text(result):
    """A few lines for the terminal: each scheme's median residuals and survey verdicts."""
    import numpy as np

    from ..study.report import summarize, survey_verdicts

    summary = summarize(result.scores[result.scores["config"] == "default"])
    verdicts = survey_verdicts(result.scores, result.surveys)
    lines = [f"{'scheme':<18}{'e_rms':>10}{'/oracle':>9}{'|rho1|':>10}{'sigma_sys2':>12}  meets"]
    for row in summary[np.argsort(summary["e_rms_median"])]:
        met = [str(v["survey"]) for v in verdicts if v["scheme"] == row["scheme"] and v["meets"]]
        ratio = row["e_rms_ratio_median"] if "e_rms_ratio_median" in summary.colnames else np.nan
        lines.append(
            f"{row['scheme']:<18}{row['e_rms_median']:>10.2e}{ratio:>9.3f}"
            f"{row['rho1_mean_abs_median']:>10.1e}{row['sigma_sys2_median']:>12.1e}  "
            + (", ".join(met) or "none")
        )
    if result.config.get("quick"):
        lines.append("--quick: too few simulations to decide most verdicts (see report.md).")
    return "\n".join(lines)

