"""Command line: ``sklearn-psf compare`` runs the paper's comparison and writes a report;
``sklearn-psf fit`` builds a validated PSF model of a FITS image and ``sklearn-psf predict``
evaluates a saved model at given positions.

Run ``sklearn-psf <command> --help`` for the options. Errors in the arguments or the data end with
a one-line message and exit status 2 (set ``SKLEARN_PSF_DEBUG=1`` for the traceback); the
library itself never prints.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
from dataclasses import replace

import numpy as np

from ._cli_fit import _add_fit_parsers, _check_output, _fit, _predict

PRESETS = {
    # The paper: 50 simulations of 1000 stars and 2000 galaxy-PSFs on a Subaru-sized image.
    "paper": {"n_simulations": 50, "study_simulations": 10, "n_stars": 1000, "n_galaxies": 2000,
              "image_shape": (7769, 10032)},
    # A few minutes on 2 cores: the same image and densities, fewer simulations.
    "quick": {"n_simulations": 4, "study_simulations": 2, "n_stars": 1000, "n_galaxies": 2000,
              "image_shape": (7769, 10032)},
}
STUDIES = ("maps", "snr", "density", "outliers", "tuning")
# The paper's figures of the discussion show these three schemes.
STUDY_SCHEMES = ("polynomial", "delaunay", "kriging")


class CLIError(Exception):
    """A problem with the command line's input, reported in one line."""


def _positive_int(text):
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


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


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="sklearn-psf", description="PSF modelling and interpolation (Berge et al. 2012)."
    )
    sub = parser.add_subparsers(dest="command", required=True)
    cmp = sub.add_parser(
        "compare",
        help="run the paper's comparison of interpolation schemes on simulated PSF fields",
        description="Simulate PSF fields from the embedded reference, fit a PSF model per "
        "interpolation scheme on the stars, evaluate it at the galaxy-PSFs, and write tables, "
        "figures and a Markdown report.",
    )
    cmp.add_argument("-o", "--output", default="sklearn_psf_results", help="output folder")
    cmp.add_argument("--quick", action="store_true",
                     help="a few simulations only: minutes instead of the paper's 50 simulations")
    cmp.add_argument("--n-simulations", type=_positive_int, help="simulations of the main comparison")
    cmp.add_argument("--study-simulations", type=_positive_int,
                     help="simulations per configuration of the S/N, density and outlier studies")
    cmp.add_argument("--n-stars", type=_positive_int, help="stars per simulation [1000]")
    cmp.add_argument("--n-galaxies", type=_positive_int, help="galaxy-PSFs per simulation [2000]")
    cmp.add_argument("--image-shape", type=_shape, metavar="NY,NX",
                     help="simulated image size in pixels [7769,10032: Subaru SuprimeCam]")
    cmp.add_argument("--snr", type=_snr, default=100.0, help="star S/N, or 'realistic' [100]")
    cmp.add_argument("--schemes", type=_csv_list,
                     help="comma-separated schemes of the main comparison (default: all)")
    cmp.add_argument("--studies", type=_csv_list, default=list(STUDIES),
                     help=f"comma-separated studies among {','.join(STUDIES)}, or 'none'")
    cmp.add_argument("--seed", type=int, default=0, help="seed of the whole study [0]")
    cmp.add_argument("--n-jobs", type=int, default=1, help="parallel simulations (joblib)")
    cmp.add_argument("--scheduler", metavar="ADDRESS",
                     help="run on the Dask cluster at ADDRESS (joblib's dask backend)")
    _add_fit_parsers(sub)
    return parser


@contextlib.contextmanager
def _backend(scheduler):
    if scheduler is None:
        yield
        return
    try:
        from distributed import Client
    except ImportError:
        raise CLIError("--scheduler needs Dask: pip install 'sklearn-psf[dask]'") from None
    import joblib

    try:
        client = Client(scheduler, timeout="10s")
    except OSError as exc:
        raise CLIError(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from None
    with client, joblib.parallel_backend("dask"):
        yield


def _compare(args):
    from tqdm.auto import tqdm

    from . import compare
    from .metrics import requirement_curves, survey_table
    from .report import summarize, survey_verdicts, write_report

    preset = dict(PRESETS["quick" if args.quick else "paper"])
    n_sims = args.n_simulations or preset["n_simulations"]
    study_sims = args.study_simulations or preset["study_simulations"]
    studies = [] if args.studies == ["none"] else args.studies
    unknown = sorted(set(studies) - set(STUDIES))
    if unknown:
        raise CLIError(f"unknown study {unknown[0]!r}; choose among {', '.join(STUDIES)} or 'none'")
    all_schemes = compare.default_schemes()
    names = args.schemes or list(all_schemes)
    unknown = [n for n in names if n not in all_schemes]
    if unknown:
        raise CLIError(f"unknown scheme {unknown[0]!r}; choose among {', '.join(all_schemes)}")
    schemes = {n: all_schemes[n] for n in names}
    study_schemes = {n: all_schemes[n] for n in STUDY_SCHEMES}
    _check_output(args.output)

    base = compare.SimulationConfig(
        n_stars=args.n_stars or preset["n_stars"],
        n_galaxies=args.n_galaxies or preset["n_galaxies"],
        snr=args.snr,
        image_shape=args.image_shape or preset["image_shape"],
    ).validate()
    runs = [("comparison", [base], schemes, n_sims)]
    if "maps" in studies:
        runs.append(("maps", [replace(base, label="grid", galaxy_layout="grid")], schemes, 1))
    if "snr" in studies:
        runs.append(("S/N study", compare.snr_study_configs(base), study_schemes, study_sims))
    if "density" in studies:
        runs.append(("density study", compare.density_study_configs(base), study_schemes, study_sims))
    if "outliers" in studies:
        runs.append(("outlier study", compare.outlier_study_configs(base), study_schemes, study_sims))

    results = []
    with _backend(args.scheduler):
        for title, configs, run_schemes, sims in runs:
            with tqdm(total=len(configs) * sims, desc=title, unit="sim") as bar:
                results.append(compare.run_study(
                    configs, run_schemes, n_simulations=sims, random_state=args.seed,
                    n_jobs=args.n_jobs, progress=bar.update,
                ))
    result = compare.combine_results(results)
    curves = requirement_curves(result.theta)
    result.requirements = dict(zip(curves.levels, curves.d1_limit))
    result.surveys = survey_table()
    if "snr" in studies:
        result.wiener = compare.wiener_bands(base, result.config["theta_bins"], random_state=args.seed)
    if "tuning" in studies:
        with tqdm(total=len(compare.PARAM_GRIDS), desc="tuning", unit="scheme") as bar:
            result.tuning = compare.tune_schemes(
                base, random_state=args.seed, n_jobs=args.n_jobs, progress=bar.update
            )
    stamps, positions = _example_stars(base, result.config["seeds"][0])
    paths = write_report(result, args.output, stamps=stamps, positions=positions)
    print(_summary_text(result, summarize, survey_verdicts))
    print(f"\nWrote {len(paths)} files to {args.output}/ (report: {args.output}/report.md)")
    return 0


def _example_stars(config, seed, n=4):
    """Stamps of a few stars cut from the first simulation's image (the paper's fig_sim)."""
    from .simulate import make_psf_field

    sim = make_psf_field(n_stars=config.n_stars, n_galaxies=2, snr=config.snr
                         if config.snr != "realistic" else 100.0,
                         image_shape=config.image_shape, pixel_scale=config.pixel_scale,
                         random_state=seed)
    stamps, flags = sim.star_stamps()
    good = np.flatnonzero(np.asarray(flags) == 0)[:n]
    positions = np.column_stack([sim.stars["x"], sim.stars["y"]])[good]
    return stamps[good], positions


def _summary_text(result, summarize, survey_verdicts):
    """A few lines for the terminal: each scheme's median residuals and survey verdicts."""
    summary = summarize(result.scores[result.scores["config"] == "default"])
    verdicts = survey_verdicts(result.scores, result.surveys)
    lines = [f"{'scheme':<18}{'e_rms':>10}{'coeff_rms':>11}{'|rho1|':>10}{'sigma_sys2':>12}  meets"]
    for row in summary[np.argsort(summary["e_rms_median"])]:
        met = [str(v["survey"]) for v in verdicts if v["scheme"] == row["scheme"] and v["meets"]]
        lines.append(
            f"{row['scheme']:<18}{row['e_rms_median']:>10.2e}{row['coeff_rms_median']:>11.2e}"
            f"{row['rho1_mean_abs_median']:>10.1e}{row['sigma_sys2_median']:>12.1e}  "
            + (", ".join(met) or "none")
        )
    return "\n".join(lines)


def main(argv=None) -> int:
    """Entry point of the ``sklearn-psf`` command."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        if args.command == "compare":
            return _compare(args)
        if args.command == "fit":
            return _fit(args)
        if args.command == "predict":
            return _predict(args)
    except (CLIError, ValueError, OSError) as exc:
        if os.environ.get("SKLEARN_PSF_DEBUG"):
            raise
        print(f"sklearn-psf: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("sklearn-psf: interrupted", file=sys.stderr)
        return 130
    parser.error(f"unknown command {args.command!r}")
    return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
