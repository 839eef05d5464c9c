"""Atomic file output: never a half-written file (DEVELOPERS' guide: bad input or a crash leaves no output)."""

from __future__ import annotations

import os
import stat
import tempfile
from pathlib import Path

from ..errors import SwimInputError

__all__ = ["atomic_write", "check_output_path"]


def check_output_path(path, what="output") -> Path:
    """Check, before any work, that a file can be written at ``path``: the path a symlink points to (the link is
    written through, not replaced), not an existing directory, device, pipe or other file that is not a regular
    file, under folders that exist or can be made and can be written.

    Parameters
    ----------
    path : str or os.PathLike
        Destination.
    what : str
        What is written, for the messages (e.g. "--out").

    Returns
    -------
    pathlib.Path
        The path that will be written (the symlink's target for a symlink).

    Raises
    ------
    SwimInputError
        If the file could not be written there.
    """
    target = Path(os.path.realpath(path)) if os.path.islink(path) else Path(path)
    if target.exists() and not stat.S_ISREG(target.stat().st_mode):
        kind = "a directory" if target.is_dir() else "not a regular file"
        raise SwimInputError(f"{what} {path}: exists and is {kind}; give a file name")
    parent = target.parent
    while not parent.exists():  # the first folder that exists: the rest are made
        parent = parent.parent
    if not parent.is_dir():
        raise SwimInputError(f"{what} {path}: {parent} is not a folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise SwimInputError(f"{what} {path}: the folder {parent} cannot be written")
    return target


def atomic_write(path, writer) -> Path:
    """Write through a temporary file in the target folder, then rename it into place.

    Parameters
    ----------
    path : str or os.PathLike
        Destination; its folder is created if needed. A symlink is written through (its target is replaced, the
        link stays); an existing directory, device or other file that is not a regular file is refused.
    writer : callable
        ``writer(tmp_path)`` writes the whole file to ``tmp_path`` (a str).

    Returns
    -------
    pathlib.Path
        ``path``. The file gets the permissions of a normally created file (0666 less the umask), not the
        0600 of :func:`tempfile.mkstemp`; on any error the temporary file is removed and nothing is left.

    Raises
    ------
    SwimInputError
        If the file cannot be written there (:func:`check_output_path`).
    """
    target = check_output_path(path)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", dir=target.parent)
    except OSError as exc:
        raise SwimInputError(f"output {path}: cannot be written ({exc.strerror or exc})") from None
    os.close(fd)
    try:
        writer(tmp)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, target)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise
    return Path(path)
