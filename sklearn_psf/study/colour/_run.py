"""The colour study: the size residual at the galaxies against their colour, for a model of
position only and a model with a colour dimension, on chromatic fields and their controls."""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from astropy.table import Table
from joblib import Parallel, delayed
from sklearn.base import clone
from threadpoolctl import threadpool_limits

from ...measure import adaptive_moments
from ...model import PSFModel
from ...simulate import SourceSettings, make_psf_field

#: Default sizes: 10 arcmin fields (3000 x 3000 pixels of 0.2 arcsec) of 600 stars at S/N
#: uniform in 50-500 and 2000 galaxies; airmass 1.2; 5 bins of the galaxies' g-i in the figure.
DEFAULTS = {"n_simulations": 3, "n_stars": 600, "n_galaxies": 2000,
            "image_shape": (3000, 3000), "snr": (50.0, 500.0), "airmass": 1.2,
            "colour_bins": (0.0, 0.4, 0.8, 1.2, 1.6, 2.0)}

#: The fits of each simulation: (name, field, extra columns).
FITS = (("position, control", "control", ()), ("colour, control", "control", ("g_i",)),
        ("position, chromatic", "chromatic", ()), ("colour, chromatic", "chromatic", ("g_i",)))


def galaxy_residuals(model, field, columns=()):
    """Fit ``model`` (cloned) on a simulated field's stars with X = (x, y, columns...) and
    return its relative size residual ``(sigma_model - sigma_true) / sigma_true`` and squared
    ellipticity residual at the field's galaxies (adaptive moments of both).

    Parameters
    ----------
    model : PSFModel
    field : PSFField
        From :func:`~sklearn_psf.simulate.make_psf_field`; ``columns`` name columns of its
        ``stars`` and ``galaxies`` tables.
    columns : sequence of str

    Returns
    -------
    ds, de2 : ndarray of shape (n_galaxies,)

    Examples
    --------
    >>> from sklearn_psf.model import PSFModel
    >>> from sklearn_psf.simulate import make_psf_field
    >>> from sklearn_psf.study.colour import galaxy_residuals
    >>> f = make_psf_field(n_stars=80, n_galaxies=20, image_shape=(900, 900), random_state=0)
    >>> ds, de2 = galaxy_residuals(PSFModel(), f)
    >>> ds.shape, bool(abs(ds.mean()) < 0.05)
    ((20,), True)
    """
    def design(table):
        return np.column_stack([table["x"], table["y"]] + [table[c] for c in columns])

    stamps, weights, _ = field.star_stamps(return_weights=True)
    fitted = clone(model).fit(design(field.stars), stamps, weights=weights)
    mom = adaptive_moments(fitted.predict(design(field.galaxies)))
    g = field.galaxies
    ds = (np.asarray(mom["sigma"]) - g["sigma"]) / g["sigma"]
    de2 = (np.asarray(mom["e1"]) - g["e1"]) ** 2 + (np.asarray(mom["e2"]) - g["e2"]) ** 2
    return np.asarray(ds, dtype=float), np.asarray(de2, dtype=float)


def colour_simulation(seed: int, *, n_stars: int = DEFAULTS["n_stars"],
                      n_galaxies: int = DEFAULTS["n_galaxies"],
                      image_shape=DEFAULTS["image_shape"], snr=DEFAULTS["snr"],
                      airmass: float = DEFAULTS["airmass"], model=None) -> dict:
    """One simulation of the colour study: a chromatic field and its control (the same stars,
    PSF pattern and noise, the PSF of the position only; the galaxies and stars keep their
    colours), each fitted by ``model`` on (x, y) and on (x, y, g-i).

    Returns
    -------
    dict
        ``colour`` (the galaxies' g-i), ``true_change`` (the relative change of the
        galaxies' true PSF size from the control field to the chromatic one) and, for each
        entry of :data:`FITS`, ``ds`` and
        ``de2`` at the galaxies (see :func:`galaxy_residuals`), keyed ``"<name>"`` ->
        ``(ds, de2)``.

    Examples
    --------
    >>> from sklearn_psf.study.colour import colour_simulation
    >>> out = colour_simulation(0, n_stars=80, n_galaxies=30, image_shape=(900, 900))
    >>> sorted(out)[:2], out["colour"].shape
    (['colour', 'colour, chromatic'], (30,))
    """
    model = PSFModel() if model is None else model
    rng = np.random.default_rng(seed)
    lo, hi = snr
    kw = dict(n_stars=n_stars, n_galaxies=n_galaxies, image_shape=tuple(image_shape),
              snr=rng.uniform(lo, hi, n_stars), random_state=seed)
    fields = {"control": make_psf_field(**kw),
              "chromatic": make_psf_field(
                  sources=SourceSettings(chromatic=True, airmass=airmass), **kw)}
    for name in ("stars", "galaxies"):  # the colours, doing nothing on the control
        getattr(fields["control"], name)["g_i"] = getattr(fields["chromatic"], name)["g_i"]
    sigma = [np.asarray(fields[k].galaxies["sigma"], dtype=float)
             for k in ("control", "chromatic")]
    out = {"colour": np.asarray(fields["chromatic"].galaxies["g_i"], dtype=float),
           "true_change": (sigma[1] - sigma[0]) / sigma[0]}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for name, which, columns in FITS:
            out[name] = galaxy_residuals(model, fields[which], columns)
    return out


def _scores(seed, sim):
    """One row of the study's table: slopes, rms and e rms of one simulation."""
    colour = sim["colour"]
    ds = {name: sim[name][0] for name, _, _ in FITS}
    pos0, col0 = ds["position, control"], ds["colour, control"]
    pos, col = ds["position, chromatic"], ds["colour, chromatic"]

    def slope(d):
        return float(np.polyfit(colour, d, 1)[0])

    def e_rms(name):
        return float(np.sqrt(np.mean(sim[name][1])))

    return {"simulation": seed, "slope_truth": slope(sim["true_change"]),
            "slope_position": slope(pos), "slope_colour": slope(col),
            "slope_position_paired": slope(pos - pos0), "slope_colour_paired": slope(col - pos0),
            "colour_rms_position": float(np.sqrt(np.mean((pos - pos0) ** 2))),
            "colour_rms_colour": float(np.sqrt(np.mean((col - col0) ** 2))),
            "size_rms_position": float(np.sqrt(np.mean(pos**2))),
            "size_rms_colour": float(np.sqrt(np.mean(col**2))),
            "e_rms_position_control": e_rms("position, control"),
            "e_rms_colour_control": e_rms("colour, control")}


def _binned(sim, edges):
    """Mean paired size residual (minus the position-only model's on the control) per bin of
    the galaxies' colour, for both models on the chromatic field."""
    colour, base = sim["colour"], sim["position, control"][0]
    k = np.digitize(colour, edges) - 1
    rows = []
    for name in ("position, chromatic", "colour, chromatic"):
        d = sim[name][0] - base
        rows.append([float(np.mean(d[k == b])) if np.any(k == b) else np.nan
                     for b in range(len(edges) - 1)])
    return np.array(rows)


@dataclass
class ColourStudyResult:
    """Results of :func:`run_colour_study`.

    Attributes
    ----------
    scores : astropy.table.Table
        One row per simulation: ``slope_truth`` (slope of the relative change of the
        galaxies' true PSF size from the control field to the chromatic one against their
        g-i, per magnitude: what a model must follow), ``slope_position``, ``slope_colour``
        (slope of the relative size residual at the galaxies against their g-i, per
        magnitude, on the chromatic field), the same ``_paired`` (minus the position-only
        model's residual on the control field: the interpolation error both models share
        removed), ``colour_rms_position``,
        ``colour_rms_colour`` (rms of the relative size residual's change from the control
        field to the chromatic one, each model against itself: what colour adds),
        ``size_rms_position``, ``size_rms_colour`` (rms of the relative size residual on the
        chromatic field), ``e_rms_position_control``, ``e_rms_colour_control`` (ellipticity
        residual rms on the control field: what a colour dimension that does nothing costs).
    binned : ndarray of shape (n_simulations, 2, n_bins)
        Mean paired relative size residual per bin of the galaxies' g-i (position-only model,
        colour model).
    config : dict
        The settings.
    """

    scores: Table
    binned: np.ndarray
    config: dict = field(default_factory=dict)


def run_colour_study(*, n_simulations: int = DEFAULTS["n_simulations"],
                     n_stars: int = DEFAULTS["n_stars"], n_galaxies: int = DEFAULTS["n_galaxies"],
                     image_shape=DEFAULTS["image_shape"], airmass: float = DEFAULTS["airmass"],
                     colour_bins=DEFAULTS["colour_bins"], model=None, random_state: int = 0,
                     n_jobs: int = 1, progress=None) -> ColourStudyResult:
    """Run the colour study: :func:`colour_simulation` for each simulation, in parallel.

    Parameters
    ----------
    n_simulations, n_stars, n_galaxies, image_shape, airmass :
        The simulations (S/N uniform in 50-500; stars g-i 0.3-3.0, galaxies 0-2).
    colour_bins : sequence of float
        Bin edges of the galaxies' g-i in :attr:`ColourStudyResult.binned`.
    model : PSFModel, optional
        Default ``PSFModel()`` (its Kriging fits one correlation length per extra dimension
        and a linear trend in it).
    random_state : int
        Seed of simulation 0 (simulation i uses ``random_state + i``).
    n_jobs : int
        joblib workers (one BLAS thread each).
    progress : callable, optional
        Called once per finished simulation.

    Returns
    -------
    ColourStudyResult

    Examples
    --------
    >>> from sklearn_psf.study.colour import run_colour_study
    >>> res = run_colour_study(n_simulations=1, n_stars=80, n_galaxies=30,
    ...                        image_shape=(900, 900))
    >>> len(res.scores), res.binned.shape
    (1, (1, 2, 5))
    """
    edges = np.asarray(colour_bins, dtype=float)
    seeds = [int(random_state) + i for i in range(int(n_simulations))]
    options = dict(n_stars=n_stars, n_galaxies=n_galaxies, image_shape=image_shape,
                   airmass=airmass, model=model)

    def one(seed):
        with threadpool_limits(limits=1):
            sim = colour_simulation(seed, **options)
        return _scores(seed, sim), _binned(sim, edges)

    rows, binned = [], []
    for row, b in Parallel(n_jobs=n_jobs, return_as="generator")(
            delayed(one)(s) for s in seeds):
        rows.append(row)
        binned.append(b)
        if progress is not None:
            progress()
    config = {"n_simulations": len(seeds), "n_stars": n_stars, "n_galaxies": n_galaxies,
              "image_shape": list(image_shape), "airmass": airmass,
              "colour_bins": edges.tolist(), "random_state": int(random_state)}
    return ColourStudyResult(Table(rows=rows), np.array(binned), config)


def plot_colour_study(result):
    """The paired relative size residual at the galaxies against their g-i (mean over the
    simulations, with their spread), for the model of position only and the model with
    colour.

    Returns
    -------
    fig : matplotlib.figure.Figure

    Examples
    --------
    >>> import numpy as np
    >>> from astropy.table import Table
    >>> from sklearn_psf.study.colour import ColourStudyResult, plot_colour_study
    >>> res = ColourStudyResult(Table(), np.zeros((2, 2, 3)), {"colour_bins": [0, 1, 2, 3]})
    >>> len(plot_colour_study(res).axes)
    1
    """
    import matplotlib.pyplot as plt

    edges = np.asarray(result.config["colour_bins"], dtype=float)
    centres = (edges[1:] + edges[:-1]) / 2
    fig, ax = plt.subplots(figsize=(6, 4))
    for j, (label, marker) in enumerate((("position only (x, y)", "o"),
                                         ("with colour (x, y, g-i)", "s"))):
        values = result.binned[:, j, :]
        mean = np.nanmean(values, axis=0)
        err = np.nanstd(values, axis=0) / np.sqrt(max(len(values), 1))
        ax.errorbar(centres, mean, yerr=err, marker=marker, capsize=3, label=label)
    ax.axhline(0.0, color="0.5", lw=0.8)
    ax.set_xlabel("galaxy colour g - i [mag]")
    ax.set_ylabel("relative size residual ds at the galaxies\n(chromatic field - control field)")
    ax.set_title("PSF size at the galaxies: what colour costs")
    ax.legend()
    fig.tight_layout()
    return fig


def colour_report_section(result, figure: str | None = "size_vs_colour.png") -> str:
    """Markdown section of the colour study, with its definitions and units.

    Examples
    --------
    >>> import numpy as np
    >>> from astropy.table import Table
    >>> from sklearn_psf.study.colour import ColourStudyResult, colour_report_section
    >>> keys = ["slope_truth", "slope_position", "slope_colour", "slope_position_paired",
    ...         "slope_colour_paired", "colour_rms_position", "colour_rms_colour",
    ...         "size_rms_position", "size_rms_colour", "e_rms_position_control",
    ...         "e_rms_colour_control"]
    >>> scores = Table({k: [1e-3 if k.endswith("position") else 1e-4] for k in keys})
    >>> text = colour_report_section(ColourStudyResult(scores, np.zeros((1, 2, 5)), {}))
    >>> "## Colour" in text
    True
    """
    s, cfg = result.scores, result.config or {}
    mean = {k: float(np.mean(np.asarray(s[k]))) for k in s.colnames if k != "simulation"}
    lines = ["## Colour: the PSF of each galaxy, not of the average star", ""]
    lines.append(
        f"Simulations: {cfg.get('n_simulations', len(s))}, each of {cfg.get('n_stars', '?')} stars "
        f"(S/N 50-500, blackbody g-i 0.3-3.0) and {cfg.get('n_galaxies', '?')} galaxies "
        f"(g-i 0-2) on a chromatic PSF (seeing proportional to the effective wavelength^-0.2, "
        f"the optics to it, differential chromatic refraction at airmass "
        f"{cfg.get('airmass', 1.2)}), each with a control field of the same stars, PSF "
        "pattern and noise whose PSF depends on position only. The default `PSFModel` is "
        "fitted on (x, y) and on (x, y, g-i). `ds` is the relative size residual at the "
        "galaxies, (sigma_model - sigma_true) / sigma_true (dimensionless, adaptive "
        "moments); the slopes are per magnitude of g-i; \"paired\" subtracts the "
        "position-only model's `ds` on the control field, which removes the interpolation "
        "error both models share.")
    lines.append("")
    lines.append(f"The galaxies' true PSF size changes by {mean['slope_truth']:+.2e} per magnitude "
                 "of g-i (relative, from the control field to the chromatic one): what a model "
                 "must follow. Means over the simulations; ratio = with colour / position only.")
    lines.append("")
    lines.append("| | position only | with colour | ratio |")
    lines.append("| --- | --- | --- | --- |")
    for label, a, b, fmt in (
            ("slope of ds against g-i [1/mag]", "slope_position", "slope_colour", "+.2e"),
            ("the same, paired", "slope_position_paired", "slope_colour_paired", "+.2e"),
            ("rms of ds, chromatic field", "size_rms_position", "size_rms_colour", ".2e"),
            ("rms of ds's change from the control (what colour adds)",
             "colour_rms_position", "colour_rms_colour", ".2e"),
            ("e rms at the galaxies, control field (colour doing nothing)",
             "e_rms_position_control", "e_rms_colour_control", ".2e")):
        a, b = mean[a], mean[b]
        lines.append(f"| {label} | {a:{fmt}} | {b:{fmt}} | {abs(b / a) if a else np.nan:.3f} |")
    lines.append("")
    if figure:
        lines += [f"![size residual against colour]({figure})", ""]
    return "\n".join(lines) + "\n"


def write_colour_report(result, directory) -> Path:
    """Write ``colour_scores.csv``, the figure ``size_vs_colour.png`` and ``colour.md`` into
    ``directory``; return the Markdown file's path."""
    import matplotlib.pyplot as plt

    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    result.scores.write(out / "colour_scores.csv", overwrite=True)
    fig = plot_colour_study(result)
    fig.savefig(out / "size_vs_colour.png", dpi=110)
    plt.close(fig)
    path = out / "colour.md"
    path.write_text(colour_report_section(result), encoding="utf-8")
    return path
