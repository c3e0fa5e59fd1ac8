"""What the commands share: the one-line input error, argument types and file checks.

Errors are raised as :class:`CLIInputError` (a ``ValueError``) with a one-line message naming
the user's path; the entry point prints them and exits with status 2.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import tempfile

from .._files import InputError, is_input_error


class CLIInputError(InputError):
    """A problem with the input of ``fit`` or ``predict``, reported in one line."""


def _positive_int(text):
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


def _fraction(text):
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a fraction in [0, 1), got {text!r}") from None
    if not 0 <= value < 1:
        raise argparse.ArgumentTypeError(f"expected a fraction in [0, 1), got {value}")
    return value


def _n_jobs(text):
    try:
        value = int(text)
    except ValueError:
        value = None
    if not value:
        raise argparse.ArgumentTypeError(f"expected a number of jobs (1, 2, ..., or -1 for "
                                         f"one per core), got {text!r}")
    return value


def _stamp_size(text):
    value = _positive_int(text)
    if value < 5:
        raise argparse.ArgumentTypeError(f"expected a stamp size >= 5, got {value}")
    return value


def _number(text):
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None


def _bits(text):
    try:
        return int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected an integer (e.g. 254 or 0xfe), got {text!r}") from None


def _non_negative(text):
    value = _number(text)
    if not value >= 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}")
    return value


def _positive(text):
    value = _non_negative(text)
    if value == 0:
        raise argparse.ArgumentTypeError(f"expected a number > 0, got {text!r}")
    return value


def _width(text):
    return text if text == "auto" else _positive(text)


def _check_input(path, what):
    """Fail at once (before importing the library) when an input file is missing."""
    if not os.path.exists(path):
        raise CLIInputError(f"the {what} {path!r} does not exist")
    if os.path.isdir(path):
        raise CLIInputError(f"the {what} {path!r} is a folder: give a file")
    if not os.access(path, os.R_OK):
        raise CLIInputError(f"the {what} {path!r} cannot be read: permission denied")


def _check_not_input(outputs, inputs):
    """No command writes over a file it reads, with or without --overwrite."""
    for out in outputs:
        for path in inputs:
            if path is not None and os.path.exists(out) and os.path.exists(path) \
                    and os.path.samefile(out, path):
                raise CLIInputError(f"the output {out!r} is the input {path!r} of this "
                                    "command: an input is never written over, even with "
                                    "--overwrite; give another output name")


def _check_output_file(path, overwrite=False, also=(), inputs=()):
    """Fail before any work when ``path`` cannot be written, when it (or one of ``also``,
    files written with it) is one of the command's ``inputs``, or exists and ``overwrite``
    is not set."""
    folder = os.path.dirname(os.path.abspath(path)) or "."
    if not os.path.isdir(folder):
        raise CLIInputError(f"the folder of the output file {path!r} does not exist")
    if os.path.isdir(path):
        raise CLIInputError(f"the output {path!r} is a folder: give a file name")
    _check_not_input((path, *also), inputs)
    existing = [p for p in (path, *also) if os.path.exists(p)]
    if existing and not overwrite:
        more = f" (and {len(existing) - 1} more output files)" if len(existing) > 1 else ""
        raise CLIInputError(f"{existing[0]!r} already exists{more}: pass --overwrite to "
                            "replace it")
    try:  # the atomic write creates a temporary file there: try one now
        with tempfile.NamedTemporaryFile(dir=folder):
            pass
        if os.path.exists(path) and not os.access(path, os.W_OK):
            raise PermissionError(13, "permission denied")
    except OSError as exc:
        raise CLIInputError(f"cannot write the output file {path!r}: "
                            f"{(exc.strerror or str(exc)).lower()}") from None


@contextlib.contextmanager
def _about(path):
    """Errors of the library about ``path``'s content name the user's path."""
    try:
        yield
    except ValueError as exc:
        if isinstance(exc, CLIInputError) or str(path) in str(exc) \
                or not is_input_error(exc):
            raise
        raise CLIInputError(f"{path}: {exc}") from None


def _remove_empty(folders):
    """Remove each of ``folders`` (deepest first) that is empty."""
    for folder in folders:
        with contextlib.suppress(OSError):
            os.rmdir(folder)


@contextlib.contextmanager
def _output_folder(path):
    """Create the output folder ``path`` (and its missing parents) for a command's run,
    checking it can be written; when the command fails, the folders it created that are
    still empty are removed: a failed command leaves no empty folder behind."""
    created, parent = [], os.path.abspath(path)
    while not os.path.exists(parent):
        created.append(parent)
        parent = os.path.dirname(parent)
    try:
        os.makedirs(path, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path):
            pass
    except OSError as exc:
        _remove_empty(created)
        raise CLIInputError(
            f"cannot write to the output folder {path!r}: {exc.strerror or exc}") from None
    try:
        yield
    except BaseException:
        _remove_empty(created)
        raise


def _check_optional(module, what):
    """An optional package the command's options need, checked before any output is made
    (a one-line error with its ``pip install`` line, exit status 2)."""
    from .._optional import check_installed

    check_installed(module, what)
