"""Bounded disk caches: what swim keeps in ``$SWIM_CACHE_DIR`` stays below a budget, and can be listed and cleared.

swim keeps five caches on disk (:func:`swim.compilation.disk_cache.cache_directory`):

========  ===========================================================  =============================================
kind      what                                                         bound
========  ===========================================================  =============================================
gas       the successive-orders clear-sky tables (:mod:`swim.rt.gas`),  :func:`max_bytes`, least recently used first
          9-42 MB each, one per aerosol, surface albedo and profile
surface   the BRDF tables (:mod:`swim.surface.brdf`)                   :func:`max_bytes`, least recently used first
jax       JAX's compiled executables                                   :func:`max_bytes`, JAX's own LRU eviction
                                                                       (``jax_compilation_cache_max_size``)
jax-      the JAX kernels' traced programs                             :func:`max_bytes`, least recently used first
export    (:mod:`swim.compilation.jax_export`, ~0.3 MB each)
numba     numba's machine code, one folder per version of the code     the :data:`CODE_VERSIONS` most recently used
          (:func:`swim.compilation.numba_jit.numba_sources_digest`, ~13 MB)     folders
========  ===========================================================  =============================================

Without bounds they only grow: every new scene aerosol profile or albedo adds a table of up to 42 MB, and every
upgrade of swim adds new tables and a new numba folder (a development machine held 28 GB of tables after two days).
``SWIM_CACHE_MAX_MB`` sets the budget of each of the first four kinds (default :data:`DEFAULT_MAX_MB`); entries are
removed, least recently used first, when a new one is written. ``swim cache`` lists the caches and
``swim cache --clear`` empties them (:func:`cache_usage`, :func:`clear_caches`).
"""

from __future__ import annotations

import logging
import os
import re
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

from ..errors import SwimInputError
from .disk_cache import cache_directory

log = logging.getLogger(__name__)

#: The caches, in the order ``swim cache`` lists them.
KINDS = ("gas", "surface", "jax", "jax-export", "numba")
#: Budget of each of the table and JAX caches [MB] (``SWIM_CACHE_MAX_MB`` overrides it): ~24 of the largest gas tables.
DEFAULT_MAX_MB = 1024
#: numba code versions kept (each a folder named by its code's digest): the current one and the two used before it,
#: so that two installations of swim side by side do not evict each other's machine code.
CODE_VERSIONS = 3
#: Unfinished writes (``*.tmp``, left by a killed process) older than this are removed [s].
STALE_TMP_S = 3600.0


@dataclass(frozen=True)
class CacheUsage:
    """One cache's folder, its number of files, their size [bytes] and its bound (None: :data:`CODE_VERSIONS`)."""

    kind: str
    path: Path
    files: int
    size_bytes: int
    max_bytes: int | None


def max_bytes() -> int:
    """Budget of each of the gas, surface, colour, JAX and JAX export caches [bytes]: ``SWIM_CACHE_MAX_MB`` [MB],
    default :data:`DEFAULT_MAX_MB`.

    Raises
    ------
    SwimInputError
        If ``SWIM_CACHE_MAX_MB`` is not a number of megabytes > 0.
    """
    text = os.environ.get("SWIM_CACHE_MAX_MB", "").strip()
    if not text:
        return DEFAULT_MAX_MB * 2**20
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not value > 0 or value == float("inf"):
        raise SwimInputError(f"SWIM_CACHE_MAX_MB must be a number of megabytes > 0; got {text!r}")
    return int(value * 2**20)


def _remove(path: Path) -> int:
    """Remove one file; its size [bytes], or 0 when another process removed it first."""
    try:
        size = path.stat().st_size
        path.unlink()
        return size
    except OSError:
        return 0


def prune_least_recently_used(folder: Path, limit_bytes: int, keep: Path | None = None, suffix: str = ".pkl") -> int:
    """Remove the least recently used entries (files ending in ``suffix``, by modification time, which a read refreshes)
    of ``folder`` until the rest fit in ``limit_bytes`` [bytes], never ``keep`` (the entry just written); and
    unfinished writes older than :data:`STALE_TMP_S`. Returns the bytes removed. Files that vanish meanwhile (another
    process pruning) are skipped."""
    entries = []
    removed = 0
    now = time.time()
    try:
        listing = list(os.scandir(folder))
    except OSError:
        return 0
    for item in listing:
        try:
            stat = item.stat()
        except OSError:
            continue
        if item.name.endswith(".tmp"):
            if now - stat.st_mtime > STALE_TMP_S:
                removed += _remove(Path(item.path))
        elif item.name.endswith(suffix):
            entries.append((stat.st_mtime, stat.st_size, Path(item.path)))
    total = sum(size for _, size, _ in entries)
    for _, size, path in sorted(entries, key=lambda e: e[0]):
        if total <= limit_bytes:
            break
        if keep is not None and path == keep:
            continue
        removed += _remove(path)
        total -= size
    if removed:
        log.info("cache %s: removed %.1f MB of least recently used entries (budget %.0f MB)", folder, removed / 2**20,
                 limit_bytes / 2**20)
    return removed


def mark_used(path: Path) -> None:
    """Refresh ``path``'s modification time, so that :func:`prune_least_recently_used` and
    :func:`prune_code_versions` see it as just used (missing or read-only files are skipped)."""
    try:
        os.utime(path)
    except OSError:
        pass


#: Names of the numba cache's code-version folders (:func:`swim.compilation.numba_jit.numba_sources_digest`): nothing else in
#: that folder is ever removed.
_CODE_VERSION = re.compile(r"[0-9a-f]{16}")
#: Endings of the files that swim's (and JAX's) caches write: nothing else in their folders is ever removed.
_OWN_FILES = {"gas": (".pkl", ".tmp"), "surface": (".pkl", ".tmp"),
              "jax": ("-cache", "-atime", ".lockfile"), "jax-export": (".jaxexport", ".tmp")}
#: Name of the lock file by which live processes hold their code version's numba folder (:func:`hold_code_version`).
IN_USE = ".in-use"
_held = None  # this process's shared lock on its code version's folder (an open file), kept for its lifetime


def hold_code_version(root: Path, current: str) -> bool:
    """Create the numba cache folder ``root/current`` and hold a shared lock on it for the life of this process, so
    that no other process prunes or clears it while this one may still write machine code there (a long-running
    process: a dask worker, a notebook, a test run). Returns whether the lock is held (never where ``fcntl`` is
    missing, e.g. Windows: there only recency protects the folder)."""
    global _held
    try:
        import fcntl
    except ImportError:
        return False
    for _ in range(3):  # a pruner may remove the folder between our mkdir and our lock: then again
        try:
            (root / current).mkdir(parents=True, exist_ok=True)
            handle = open(root / current / IN_USE, "a")
        except OSError:
            continue
        fcntl.flock(handle, fcntl.LOCK_SH)
        if os.fstat(handle.fileno()).st_nlink > 0:  # not removed while we waited for the lock
            _held = handle
            return True
        handle.close()
    return False


def _remove_code_version(folder: str) -> int | None:
    """Remove one code version's folder unless a live process holds it (:func:`hold_code_version`); its size
    [bytes], or None when it is in use."""
    try:
        import fcntl
    except ImportError:
        fcntl = None
    handle = None
    if fcntl is not None:
        try:
            handle = open(os.path.join(folder, IN_USE), "a")
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            handle.close()
            return None
        except OSError:
            handle = None
    try:
        size = _folder_size(folder)[1]
        shutil.rmtree(folder, ignore_errors=True)
        return size if not os.path.exists(folder) else 0
    finally:
        if handle is not None:
            handle.close()


def prune_code_versions(root: Path, current: str, keep: int = CODE_VERSIONS) -> list[str]:
    """Remove the numba cache folders under ``root`` but the ``keep`` most recently used, ``current`` always among
    them, and any folder that a live process holds (:func:`hold_code_version`).

    Each folder holds the machine code of one version of swim's numba modules
    (:func:`swim.compilation.numba_jit.numba_sources_digest`, 16 hex digits; other folders are left alone); ``current`` is
    marked used first. Returns the removed folders' names."""
    mark_used(root / current)
    folders = _own_entries("numba", root)

    def used(item):
        try:
            return item.stat().st_mtime
        except OSError:
            return 0.0

    ranked = sorted((item for item in folders if item.name != current), key=used, reverse=True)
    removed = [item.name for item in ranked[max(keep - 1, 0):] if _remove_code_version(item.path) is not None]
    if removed:
        log.info("numba cache: removed %d folders of older code versions", len(removed))
    return removed


def _own_entries(kind: str, folder: Path) -> list[os.DirEntry]:
    """The entries of ``folder`` that the cache ``kind`` wrote: its files by their endings, or numba's code-version
    folders by their names; never links."""
    try:
        items = list(os.scandir(folder))
    except OSError:
        return []
    if kind == "numba":
        return [item for item in items if _CODE_VERSION.fullmatch(item.name) and item.is_dir(follow_symlinks=False)]
    return [item for item in items if item.name.endswith(_OWN_FILES[kind]) and item.is_file(follow_symlinks=False)]


def _folder_size(folder) -> tuple[int, int]:
    files = size = 0
    for path, _, names in os.walk(folder):
        for name in names:
            try:
                size += os.stat(os.path.join(path, name), follow_symlinks=False).st_size
                files += 1
            except OSError:
                pass
    return files, size


def _entry_size(kind: str, item: os.DirEntry) -> tuple[int, int]:
    if kind == "numba":
        return _folder_size(item.path)
    try:
        return 1, item.stat(follow_symlinks=False).st_size
    except OSError:
        return 0, 0


def _known(kinds) -> tuple:
    unknown = sorted(set(kinds) - set(KINDS))
    if unknown:
        raise SwimInputError(f"unknown cache kind(s) {unknown}; expected some of {list(KINDS)}")
    return tuple(kind for kind in KINDS if kind in kinds)


def cache_usage(kinds=KINDS) -> list[CacheUsage]:
    """Each of the caches ``kinds``' (a subset of :data:`KINDS`, listed in its order) folder, the number of files
    swim wrote there, their size [bytes] and the cache's budget (missing folders: 0 files).

    Raises
    ------
    SwimInputError
        If a kind is not one of :data:`KINDS`, or ``SWIM_CACHE_MAX_MB`` is bad (:func:`max_bytes`).
    """
    kinds = _known(kinds)
    limit = max_bytes()
    usage = []
    for kind in kinds:
        folder = cache_directory(kind)
        sizes = [_entry_size(kind, item) for item in _own_entries(kind, folder)]
        usage.append(CacheUsage(kind, folder, sum(n for n, _ in sizes), sum(b for _, b in sizes),
                                None if kind == "numba" else limit))
    return usage


def clear_caches(kinds=KINDS) -> int:
    """Remove what the caches ``kinds`` (a subset of :data:`KINDS`) wrote: their entries' files, and numba's
    code-version folders except those that a live process holds (:func:`hold_code_version`). Other files in the
    folders are left alone. Returns the bytes removed. A process that is rendering meanwhile only loses time: it
    builds or compiles again what it does not find.

    Raises
    ------
    SwimInputError
        If a kind is not one of :data:`KINDS`.
    """
    removed = 0
    for kind in _known(kinds):
        for item in _own_entries(kind, cache_directory(kind)):
            if kind == "numba":
                removed += _remove_code_version(item.path) or 0
            else:
                removed += _remove(Path(item.path))
    return removed
