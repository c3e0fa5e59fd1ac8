"""The report directory: tables, figures and report.md."""

from __future__ import annotations

import io
import json
from collections.abc import Iterable
from pathlib import Path

import numpy as np
from joblib import Parallel, delayed, effective_n_jobs

from ..plotting import MissingDataError
from ..plotting._common import _unique_in_order
from ._figures import _figure_specs
from ._files import _atomic, _jsonable, _write_correlations, _write_table
from ._markdown import _markdown
from ._summary import _PAPER_TRIO


# Relative time to draw and save each figure (measured on the quick study; 1 for the others):
# figures are spread over the workers of write_report(n_jobs=...) by these, the longest first.
_DRAW_COST = {"fig_cor": 5.0, "fig_ell1comp": 4.0, "fig_coeff34": 4.0, "fig_coeff0": 3.5,
              "fig_coeffscomp": 3.0, "fig_ell": 2.3}


def _draw_figures(result, specs_args, names, dpi):
    """Draw the named figures: ``[(name, caption, PNG bytes or None, note)]`` in spec order."""
    drawn = []
    for name, caption, draw in _figure_specs(result, *specs_args):
        if name not in names:
            continue
        try:
            fig = draw()
        except MissingDataError as exc:
            drawn.append((name, caption, None, f"{name}.png skipped: {exc}"))
            continue
        buffer = io.BytesIO()
        fig.savefig(buffer, dpi=dpi, format="png")
        drawn.append((name, caption, buffer.getvalue(), None))
    return drawn


def _spread(names, n_groups):
    """Names in at most ``n_groups`` groups of about equal drawing time (longest first)."""
    groups = [[] for _ in range(max(1, min(n_groups, len(names))))]
    load = [0.0] * len(groups)
    for name in sorted(names, key=lambda n: -_DRAW_COST.get(n, 1.0)):
        k = int(np.argmin(load))
        groups[k].append(name)
        load[k] += _DRAW_COST.get(name, 1.0)
    return groups


def write_report(result, outdir, figures: bool | Iterable[str] = True, stamps=None, positions=None,
                 schemes=None, config: str = "default", dpi: int = 110,
                 n_jobs: int | None = None) -> list[Path]:
    """Write the tables, figures and a Markdown report of a study into a directory.

    Parameters
    ----------
    result : StudyResult
        Needs ``scores``; ``correlations``, ``theta``, ``galaxies``, ``config``,
        ``requirements``, ``surveys`` and ``tuning`` are used when present. Figures whose data
        are missing are skipped and listed in the report.
    outdir : str or path-like
        Created if needed; existing files of the same names are replaced.
    figures : bool or iterable of str
        Draw all figures (True), none (False) or only the named ones (e.g.
        ``{"fig_cor", "fig_densell"}``); drawing all takes a few seconds per figure.
    stamps, positions : array-like, optional
        Example PSF stamps and their positions for ``fig_sim.png`` (default: the result's
        ``example_stamps`` / ``example_positions`` attributes when present).
    schemes : sequence of str, optional
        Schemes of the correlation figure (default: all). The map, pair and density figures
        use the paper's polynomial / Delaunay / Kriging when present, else these schemes.
    config : str
        The baseline configuration.
    dpi : int
        Resolution of the PNG files.
    n_jobs : int, optional
        Figures drawn at once, in joblib's worker processes (None: one after the other, or
        joblib's ``parallel_backend`` setting); the files are the same.

    Returns
    -------
    paths : list of pathlib.Path
        Every file written: ``scores.csv``, ``scores.fits``, ``galaxies.fits``,
        ``correlations.fits`` (HDUs CORRELATIONS and THETA), ``config.json``, the figures and
        ``report.md`` (last). Tables are written to a temporary file and renamed.

    Examples
    --------
    >>> import tempfile
    >>> from sklearn_psf.study.report import synthetic_study_result, write_report
    >>> result = synthetic_study_result(n_simulations=2)
    >>> with tempfile.TemporaryDirectory() as d:
    ...     paths = write_report(result, d, figures=False)
    ...     sorted(p.name for p in paths)
    ['config.json', 'correlations.fits', 'galaxies.fits', 'report.md', 'scores.csv', 'scores.fits']
    """
    scores = getattr(result, "scores", None)
    if scores is None or len(scores) == 0:
        raise ValueError("result.scores is missing or empty: nothing to report.")
    for name in ("config", "scheme", "e_rms"):
        if name not in scores.colnames:
            raise ValueError(f"result.scores lacks the column {name!r}; it has {scores.colnames}.")
    in_config = np.asarray(scores["config"]).astype(str) == config
    all_schemes = _unique_in_order(scores["scheme"][in_config] if in_config.any()
                                   else scores["scheme"])
    schemes = all_schemes if schemes is None else [str(s) for s in schemes]
    map_schemes = [s for s in _PAPER_TRIO if s in all_schemes] or schemes

    specs_args = (config, schemes, map_schemes, stamps, positions)
    specs = _figure_specs(result, *specs_args)
    if figures is True or figures is False:
        wanted = {name for name, _, _ in specs} if figures else set()
    else:
        wanted = {str(f).removesuffix(".png") for f in figures}
        unknown = wanted - {name for name, _, _ in specs}
        if unknown:
            raise ValueError(f"unknown figure name(s) {sorted(unknown)}; choose from "
                             f"{[name for name, _, _ in specs]}.")
    groups = _spread(sorted(wanted), effective_n_jobs(n_jobs)) if wanted else []
    drawing = None
    if len(groups) > 1:  # each worker draws a group (the result is sent once per worker),
        # while this process writes the tables
        drawing = Parallel(n_jobs=len(groups), return_as="generator")(
            delayed(_draw_figures)(result, specs_args, set(g), dpi) for g in groups)

    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    written, notes = [], []
    written.append(_write_table(scores, outdir / "scores.csv", "ascii.csv"))
    written.append(_write_table(scores, outdir / "scores.fits", "fits"))
    galaxies = getattr(result, "galaxies", None)
    if galaxies is not None:
        written.append(_write_table(galaxies, outdir / "galaxies.fits", "fits"))
    else:
        notes.append("galaxies.fits not written: the result has no galaxies table.")
    correlations = getattr(result, "correlations", None)
    if correlations is not None:
        written.append(_write_correlations(correlations, getattr(result, "theta", None),
                                           outdir / "correlations.fits"))
    else:
        notes.append("correlations.fits not written: the result has no correlations table.")
    study_config = getattr(result, "config", None) or {}
    written.append(_atomic(outdir / "config.json", lambda tmp: Path(tmp).write_text(
        json.dumps(_jsonable(study_config), indent=2, sort_keys=True))))

    drawn = ([d for group in drawing for d in group] if drawing is not None
             else _draw_figures(result, specs_args, wanted, dpi) if wanted else [])
    order = {name: k for k, (name, _, _) in enumerate(specs)}
    figure_entries = []
    for name, caption, png, note in sorted(drawn, key=lambda d: order[d[0]]):
        if png is None:
            notes.append(note)
            continue
        path = outdir / f"{name}.png"
        path.write_bytes(png)
        written.append(path)
        figure_entries.append((path.name, caption))
    if len(wanted) < len(specs):
        notes.append("Figures not requested: " + ", ".join(
            f"{name}.png" for name, _, _ in specs if name not in wanted) + ".")

    text = _markdown(result, config, schemes, figure_entries, notes, written)
    written.append(_atomic(outdir / "report.md", lambda tmp: Path(tmp).write_text(text)))
    return written
