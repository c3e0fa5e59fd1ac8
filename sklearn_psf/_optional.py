"""Optional dependencies: imported where a feature needs them, or an input error saying how
to install them (the command line exits with status 2 and that line, not as a bug)."""

from __future__ import annotations

import importlib
import importlib.util
import sys

from ._files import InputError

#: How to install each optional package (the extras of ``pyproject.toml``).
INSTALL = {
    "galsim": "pip install 'sklearn-psf[galsim]' (or: pip install galsim)",
    "piff": "pip install 'sklearn-psf[piff]' (or: pip install piff)",
    "distributed": "pip install 'sklearn-psf[dask]' (or: pip install dask distributed)",
}


class OptionalDependencyError(ImportError, InputError):
    """An optional package a feature needs is not installed: an ``ImportError`` (as Python
    raises) and an :class:`~sklearn_psf.io.InputError` (the command line reports it in one
    line, exit status 2)."""


def _message(module, what):
    return (f"{what} needs the optional package {module!r}, which is not installed: "
            f"{INSTALL[module]}")


def require(module: str, what: str):
    """Import the optional ``module`` for ``what`` (e.g. "Reading a PIFF model"), or raise
    :class:`OptionalDependencyError` with the ``pip install`` line."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise OptionalDependencyError(_message(module, what) + ".", name=module) from exc


def check_installed(module: str, what: str) -> None:
    """Like :func:`require`, without importing ``module`` (the command line checks its
    options' packages before it makes any output)."""
    try:
        found = sys.modules.get(module, True) is not None and \
            importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):
        found = False
    if not found:
        raise OptionalDependencyError(_message(module, what) + ".", name=module)
