"""Run ``sklearn-psf`` in this process with the CPU time of its stages accumulated.

Usage: ``python benchmarks/_stages.py OUT.json fit --stars CAT --no-plots -o m.fits``.

The functions of :data:`STAGES` are wrapped (where the code looks them up) by a timer of the
process's CPU time, inclusive of what they call (a stage inside another counts in both;
a recursive call counts once). ``OUT.json`` gets, per stage, its CPU seconds and calls, and
``start``: the CPU spent before the command's runner (the interpreter, the imports of the
parser), and ``imports of the library``: the modules the stages live in, imported before the
command's runner (which would otherwise import them). Used by ``bench_speed.py`` for the stage profile of one command; the command runs
as the console script runs it (``_console_script``), so its CPU is that of a plain run plus
the timers' (a few microseconds per call).
"""

from __future__ import annotations

import functools
import importlib
import inspect
import json
import os
import sys
import time

#: (name, "module:attribute path"): what each stage times, in the order printed; names
#: starting with spaces are parts of the stage above.
STAGES = [
    ("command (after its start)", "sklearn_psf.cli._fit:_fit"),
    ("read, select stars, cut stamps", "sklearn_psf.exposure._fit:fit_exposure"),
    ("  select stars", "sklearn_psf.exposure:select_stars"),
    ("  celestial WCS", "sklearn_psf.io:celestial_wcs"),
    ("fit and validate", "sklearn_psf.validation._fit:fit_and_validate"),
    ("  PSFModel.fit", "sklearn_psf.model._psf_model:PSFModel.fit"),
    ("    basis fit (each outlier round)", "sklearn_psf.model._psf_model:PSFModel._fit_basis"),
    ("      StampPCA: stars on the basis", "sklearn_psf.preprocessing._pca:StampPCA._fit_stamps"),
    ("      SuperResolvedPCA: fine images", "sklearn_psf.preprocessing._superres:"
     "SuperResolvedPCA._fit_fine"),
    ("      SuperResolvedPCA: stars' fits", "sklearn_psf.preprocessing._superres:"
     "SuperResolvedPCA._fit_stars"),
    ("      SuperResolvedPCA: band, support (half fits)", "sklearn_psf.preprocessing._superres:"
     "SuperResolvedPCA._held_out_choice"),
    ("      SuperResolvedPCA: spatial refinement", "sklearn_psf.preprocessing._superres:"
     "SuperResolvedPCA._refine"),
    ("    projection of the other stars", "sklearn_psf.model._psf_model:PSFModel._project"),
    ("    outlier test", "sklearn_psf.model._psf_model:PSFModel._reject"),
    ("      noise calibration", "sklearn_psf.model._noise:calibrate_pixel_noise"),
    ("      cross-predictions", "sklearn_psf.model._noise:leave_out_predict"),
    ("      companions", "sklearn_psf.model._companions:companion_log_p"),
    ("    interpolator fits (Kriging, maximum likelihood)",
     "sklearn_psf.model._noise:fit_interpolator"),
    ("  verdict: reserved stars' residuals", "sklearn_psf.validation._fit:measure_residuals"),
    ("  verdict: noise and rho statistics", "sklearn_psf.validation._fit:model_verdict"),
    ("save the model file", "sklearn_psf.model:save_model"),
    ("adaptive moments (all calls)", "sklearn_psf.measure._moments:adaptive_moments"),
]


def _timed(fn, totals, name):
    """``fn`` with its CPU time added to ``totals[name]`` (not again inside itself)."""
    active = [0]

    # (functools.wraps: code that reads the signature, such as which fit parameters
    # ``PSFModel.fit`` takes, sees the wrapped function's)
    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        if active[0]:
            return fn(*args, **kwargs)
        active[0] += 1
        start = time.process_time()
        try:
            return fn(*args, **kwargs)
        finally:
            active[0] -= 1
            entry = totals.setdefault(name, [0.0, 0])
            entry[0] += time.process_time() - start
            entry[1] += 1

    return wrapper


def _patch(target, totals, name):
    module, path = target.split(":")
    owner = importlib.import_module(module)
    *parents, attr = path.split(".")
    for part in parents:
        owner = getattr(owner, part)
    raw = inspect.getattr_static(owner, attr)
    fn = raw.__func__ if isinstance(raw, (staticmethod, classmethod)) else raw
    wrapped = _timed(fn, totals, name)
    setattr(owner, attr, type(raw)(wrapped) if isinstance(raw, (staticmethod, classmethod))
            else wrapped)
    if not parents:  # a module's function: also where other modules imported it by name
        for other in list(sys.modules.values()):
            if (getattr(other, "__name__", "").startswith("sklearn_psf")
                    and getattr(other, attr, None) is fn):
                setattr(other, attr, wrapped)


def main():
    out, argv = sys.argv[1], sys.argv[2:]
    start = time.process_time()
    from sklearn_psf import cli

    sys.argv = ["sklearn-psf", *argv]
    totals = {}
    runner = cli._fit

    def run(args):
        totals["start"] = [time.process_time(), 1]
        for name, target in STAGES:  # (imports the modules: their cost is the command's)
            _patch(target, totals, name)
        totals["imports of the library"] = [time.process_time() - totals["start"][0], 1]
        return _timed(runner, totals, STAGES[0][0])(args)

    cli._fit = run
    try:
        code = cli._console_script()
    finally:
        totals["process"] = [time.process_time(), 1]
        totals["imports of the parser"] = [start, 1]
        with open(out, "w") as fh:
            json.dump({"stages": [name for name, _ in STAGES], "totals": totals}, fh)
    return code


if __name__ == "__main__":
    sys.exit(main())
