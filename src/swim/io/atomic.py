"""Atomic file output: never a half-written file (DEVELOPERS' guide: bad input or a crash leaves no output)."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

__all__ = ["atomic_write"]


def atomic_write(path, writer) -> Path:
    """Write through a temporary file in the target folder, then rename it into place.

    Parameters
    ----------
    path : str or os.PathLike
        Destination; its folder is created if needed.
    writer : callable
        ``writer(tmp_path)`` writes the whole file to ``tmp_path`` (a str).

    Returns
    -------
    pathlib.Path
        ``path``. The file gets the permissions of a normally created file (0666 less the umask), not the
        0600 of :func:`tempfile.mkstemp`; on any error the temporary file is removed and nothing is left.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    os.close(fd)
    try:
        writer(tmp)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise
    return path
