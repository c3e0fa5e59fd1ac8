"""Writing files safely and describing file errors in one line (shared by io and model)."""

from __future__ import annotations

import contextlib
import os
import tempfile

__all__ = ["one_line", "write_fits_atomic"]


def one_line(exc) -> str:
    """An exception's message on one line (astropy's span several)."""
    return " ".join(str(exc).split())


def write_fits_atomic(hdul, path, overwrite: bool = False) -> None:
    """Write an HDU list to ``path`` through a temporary file in the same folder.

    The temporary file is renamed over ``path`` (``os.replace``) only once it is complete;
    on any error it is removed, so ``path`` is never left half-written. The file gets the
    permissions the user's umask gives new files (not the temporary file's 0600).
    """
    path = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(path))
    if os.path.exists(path) and not overwrite:
        raise FileExistsError(f"{path!r} already exists: pass overwrite=True to replace it.")
    if not os.path.isdir(folder):
        raise FileNotFoundError(f"The folder {folder!r} of {path!r} does not exist.")
    fd, tmp = tempfile.mkstemp(prefix="." + os.path.basename(path) + ".", suffix=".tmp",
                               dir=folder)
    try:
        with os.fdopen(fd, "wb") as f:
            hdul.writeto(f)
            f.flush()
            os.fsync(f.fileno())
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
