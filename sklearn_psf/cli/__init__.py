"""Command line: ``sklearn-psf compare`` runs the paper's comparison and writes a report;
``sklearn-psf fit`` builds a validated PSF model of a FITS image (or of each of many CCDs, in
parallel or on a Dask cluster) and ``sklearn-psf predict`` evaluates a saved model at given
positions; ``sklearn-psf validate`` compares PSF models
(this package's, PSFEx, PIFF) on the same reserved stars, and ``sklearn-psf crossval`` this
package's model and PSFEx by K-fold cross-validation, every star judged once by both.

Run ``sklearn-psf <command> --help`` for the options. Errors in the arguments or the data end with
a one-line message and exit status 2; any other failure is a bug of the package: it says so,
with exit status 3 (``--debug``, or ``SKLEARN_PSF_DEBUG=1``, shows the traceback of either); the
library itself never prints. The parsers import nothing heavy: each command imports the
library when it runs, so ``sklearn-psf --help`` answers at once.
"""

from __future__ import annotations

import argparse
import os
import sys

from .._files import is_input_error
from ._fit import _add_fit_parsers, _fit, _predict
from ._compare import PRESETS, STUDIES, STUDY_SCHEMES, add_compare_parser, run_compare
from ._validate import add_validate_parser, run_validate
from ._crossval import add_crossval_parser, run_crossval

__all__ = ["PRESETS", "STUDIES", "STUDY_SCHEMES", "build_parser", "main"]


def build_parser() -> argparse.ArgumentParser:
    """The ``sklearn-psf`` argument parser (commands ``compare``, ``fit``, ``predict``,
    ``validate``, ``crossval``)."""
    parser = argparse.ArgumentParser(
        prog="sklearn-psf", description="PSF modelling and interpolation (Berge et al. 2012)."
    )
    debug = "show the traceback of an error (also: SKLEARN_PSF_DEBUG=1)"
    parser.add_argument("--debug", action="store_true", help=debug)
    sub = parser.add_subparsers(dest="command", required=True)
    add_compare_parser(sub)
    _add_fit_parsers(sub)
    add_validate_parser(sub)
    add_crossval_parser(sub)
    for command in sub.choices.values():  # --debug after the command name too
        command.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                             help=debug)
    return parser


def main(argv=None) -> int:
    """Entry point of the ``sklearn-psf`` command.

    Returns the exit status: 0, 2 for an error in the arguments or the data (one line on
    stderr), 3 for an internal error (a bug; ``--debug`` or ``SKLEARN_PSF_DEBUG=1`` shows
    its traceback), 130 when interrupted.
    """
    return _run(build_parser().parse_args(argv))


def _run(args) -> int:
    """Run the command of the parsed ``args``; the exit status of :func:`main`."""
    runners = {"compare": run_compare, "fit": _fit, "predict": _predict,
               "validate": run_validate, "crossval": run_crossval}
    debug = args.debug or os.environ.get("SKLEARN_PSF_DEBUG", "") not in ("", "0")
    try:
        return runners[args.command](args)
    except KeyboardInterrupt:
        print("sklearn-psf: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:
        if debug:
            raise
        if is_input_error(exc):
            print(f"sklearn-psf: error: {exc}", file=sys.stderr)
            return 2
        print(f"sklearn-psf: internal error ({type(exc).__name__}: "
              f"{' '.join(str(exc).split())}): this is a bug of sklearn-psf, not a problem "
              "with your input; run the command again with --debug (or SKLEARN_PSF_DEBUG=1) "
              "for the traceback and report it with the command line", file=sys.stderr)
        return 3


def _console_script() -> int:
    """The ``sklearn-psf`` console script (and ``python -m sklearn_psf``): :func:`main`, then
    the objects it leaves are frozen (:func:`gc.freeze`), so that the interpreter's final
    garbage collections skip every imported module's objects: about 0.5 s of each command.

    The youngest generation is collected every 10,000 allocations instead of 700: the
    imports and numba's first call make ~10^6 long-lived objects, and with Python's default
    the full collections they trigger (4 in a single-CCD ``fit``) cost ~0.15 s of CPU.

    scikit-learn is imported without pandas (:func:`_import_sklearn_without_pandas`), and
    the C allocator keeps the memory it frees for the next arrays (:func:`_tune_malloc`)."""
    import gc

    gc.set_threshold(10_000, *gc.get_threshold()[1:])
    _tune_malloc()
    args = build_parser().parse_args()  # --help and argument errors exit here, at once
    _import_sklearn_without_pandas()
    code = _run(args)
    gc.freeze()
    return code


def _tune_malloc():
    """Let glibc's allocator reuse freed memory in a command's own process (and the workers
    it forks), instead of returning it to the system and faulting it in again.

    By default glibc returns every block over 128 kB to the system when it is freed (raising
    that limit only as it sees larger blocks freed) and trims its heap when 2x that limit is
    free: each of the thousands of stamp-sized arrays a fit makes and frees is then faulted
    in again page by page. Blocks up to 32 MB (glibc's own upper limit) now come from the
    heap, which is trimmed only above 256 MB free and grows by 64 MB at a time, so a process
    keeps at most ~320 MB it does not use. A 16-CCD ``fit`` then takes ~65,000 page faults
    instead of ~400,000 (0.9 s of system CPU instead of 1.7 s; with 64 / 16 MB, 220,000 to
    370,000), ``compare --quick`` ~95,000 instead of ~270,000 (1.1 s instead of 2.3 s); the
    results are identical. The three parameters are set together: any one alone switches
    the dynamic limits off at their defaults and multiplies the faults. Nothing is done
    where the C library is not glibc."""
    import ctypes
    import platform

    if platform.libc_ver()[0] != "glibc":
        return
    mallopt = ctypes.CDLL(None).mallopt
    m_trim_threshold, m_top_pad, m_mmap_threshold = -1, -2, -3  # glibc's <malloc.h>
    for param, value in ((m_mmap_threshold, 32 << 20), (m_trim_threshold, 256 << 20),
                         (m_top_pad, 64 << 20)):
        mallopt(param, value)


def _import_sklearn_without_pandas():
    """Import scikit-learn as if pandas were not installed, in a command's own process.

    scikit-learn imports pandas when it is installed (``sklearn.utils.fixes``), only to
    recognise DataFrames, which no command gives it; the import costs ~0.3 s of CPU, a
    tenth of a single-CCD ``fit``. pandas is hidden during scikit-learn's import only:
    anything importing it later (TreeCorr's readers, Dask) imports it as usual, and from
    then on scikit-learn recognises its DataFrames (it looks pandas up in ``sys.modules``).
    """
    if "sklearn" in sys.modules or "pandas" in sys.modules:
        return
    sys.modules["pandas"] = None  # `import pandas` raises ImportError
    try:
        import sklearn.base  # noqa: F401
    finally:
        del sys.modules["pandas"]


if __name__ == "__main__":  # pragma: no cover
    sys.exit(_console_script())
