"""Writing files safely and describing file errors in one line (shared by io and model)."""

from __future__ import annotations

import contextlib
import linecache
import os
import tempfile

__all__ = ["InputError", "check_memory", "one_line", "write_atomic", "write_fits_atomic"]


class InputError(ValueError):
    """A problem with the data or the options a user gave: the file, column or option is
    named in the one-line message (with counts where rows are rejected).

    A ``ValueError``, so ``except ValueError`` still catches it. The ``sklearn-psf`` command
    prints it as one line (exit status 2); any other failure is reported as a bug.

    Examples
    --------
    >>> from astropy.table import Table
    >>> from sklearn_psf.io import InputError, read_catalog
    >>> try:
    ...     read_catalog(Table({"a": [1.0]}))
    ... except InputError as exc:
    ...     print(str(exc)[:37])
    The catalogue has no position columns
    """


def is_input_error(exc) -> bool:
    """Whether ``exc`` is about the user's input: an :class:`InputError`, a file that cannot
    be read or written (``OSError``), or a ``ValueError`` raised by a ``raise`` statement of
    this package; not a failure inside numpy, scipy... (a bug of the package)."""
    if isinstance(exc, (InputError, OSError)):
        return True
    if not isinstance(exc, ValueError):
        return False
    tb = exc.__traceback__
    while tb is not None and tb.tb_next is not None:
        tb = tb.tb_next
    if tb is None:
        return True
    filename = os.path.abspath(tb.tb_frame.f_code.co_filename)
    return (filename.startswith(os.path.dirname(os.path.abspath(__file__)) + os.sep)
            and linecache.getline(filename, tb.tb_lineno).lstrip().startswith("raise"))


def _available_memory():
    """Bytes of memory free for new arrays (``MemAvailable`` of Linux, else the free
    physical pages), or None where unknown."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def check_memory(nbytes, what) -> None:
    """Refuse, before allocating them, arrays of ``nbytes`` that the free memory cannot hold:
    an :class:`InputError` naming ``what`` (e.g. ``"80 stamps of 10001 x 10001 pixels
    (--stamp-size)"``) and the size needed."""
    free = _available_memory()
    if free is not None and nbytes > free:
        raise InputError(f"{what} would need {nbytes / 2**30:.3g} GiB of memory, more than "
                         f"the {free / 2**30:.3g} GiB free: choose a smaller size.")


def one_line(exc) -> str:
    """An exception's message on one line (astropy's span several)."""
    return " ".join(str(exc).split())


def write_atomic(path, write, overwrite: bool = True):
    """Write ``path`` through a temporary file in the same folder: ``write(tmp)`` writes the
    file at the temporary path ``tmp`` (which exists, empty).

    The temporary file is renamed over ``path`` (``os.replace``) only once it is complete;
    on any error it is removed, so ``path`` is never left half-written. The file gets the
    permissions the user's umask gives new files (not the temporary file's 0600). Returns
    ``path``.
    """
    folder = os.path.dirname(os.path.abspath(os.fspath(path)))
    if os.path.exists(path) and not overwrite:
        raise FileExistsError(f"{os.fspath(path)!r} already exists: pass overwrite=True to "
                              "replace it.")
    if not os.path.isdir(folder):
        raise FileNotFoundError(f"The folder {folder!r} of {os.fspath(path)!r} does not exist.")
    fd, tmp = tempfile.mkstemp(prefix="." + os.path.basename(path) + ".", suffix=".tmp",
                               dir=folder)
    os.close(fd)
    try:
        write(tmp)
        with open(tmp, "rb+") as f:
            os.fsync(f.fileno())
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    return path


def write_fits_atomic(hdul, path, overwrite: bool = False) -> None:
    """Write an HDU list to ``path`` with :func:`write_atomic`."""
    def write(tmp):
        with open(tmp, "wb") as f:
            hdul.writeto(f)

    write_atomic(os.fspath(path), write, overwrite=overwrite)
