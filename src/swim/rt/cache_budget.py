"""Bounded disk caches: what swim keeps in ``$SWIM_CACHE_DIR`` stays below a budget, and can be listed and cleared.

swim keeps four caches on disk (:func:`swim.rt.compilation_cache.cache_directory`):

========  ===========================================================  =============================================
kind      what                                                         bound
========  ===========================================================  =============================================
gas       the successive-orders clear-sky tables (:mod:`swim.rt.gas`),  :func:`max_bytes`, least recently used first
          9-42 MB each, one per aerosol, surface albedo and profile
surface   the BRDF tables (:mod:`swim.surface.brdf`)                   :func:`max_bytes`, least recently used first
jax       JAX's compiled executables                                   :func:`max_bytes`, JAX's own LRU eviction
                                                                       (``jax_compilation_cache_max_size``)
numba     numba's machine code, one folder per version of the code     the :data:`CODE_VERSIONS` most recently used
          (:func:`swim.rt.march_cpu.numba_sources_digest`, ~13 MB)     folders
========  ===========================================================  =============================================

Without bounds they only grow: every new scene aerosol profile or albedo adds a table of up to 42 MB, and every
upgrade of swim adds new tables and a new numba folder (a development machine held 28 GB of tables after two days).
``SWIM_CACHE_MAX_MB`` sets the budget of each of the first three kinds (default :data:`DEFAULT_MAX_MB`); entries are
removed, least recently used first, when a new one is written. ``swim cache`` lists the caches and
``swim cache --clear`` empties them (:func:`cache_usage`, :func:`clear_caches`).
"""

from __future__ import annotations

import logging
import os
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

from ..errors import SwimInputError
from .compilation_cache import cache_directory

log = logging.getLogger(__name__)

#: The caches, in the order ``swim cache`` lists them.
KINDS = ("gas", "surface", "jax", "numba")
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
    """Budget of each of the gas, surface and JAX caches [bytes]: ``SWIM_CACHE_MAX_MB`` [MB], default
    :data:`DEFAULT_MAX_MB`.

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


def prune_least_recently_used(folder: Path, limit_bytes: int, keep: Path | None = None) -> int:
    """Remove the least recently used entries (``*.pkl``, by modification time, which a read refreshes) of ``folder``
    until the rest fit in ``limit_bytes`` [bytes], never ``keep`` (the entry just written); and unfinished writes
    older than :data:`STALE_TMP_S`. Returns the bytes removed. Files that vanish meanwhile (another process pruning)
    are skipped."""
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
        elif item.name.endswith(".pkl"):
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


def prune_code_versions(root: Path, current: str, keep: int = CODE_VERSIONS) -> list[str]:
    """Remove the numba cache folders under ``root`` but the ``keep`` most recently used, ``current`` always among them.

    Each folder holds the machine code of one version of swim's numba modules
    (:func:`swim.rt.march_cpu.numba_sources_digest`); ``current`` is marked used first. Returns the removed folders'
    names."""
    mark_used(root / current)
    try:
        folders = [item for item in os.scandir(root) if item.is_dir(follow_symlinks=False)]
    except OSError:
        return []
    def used(item):
        try:
            return item.stat().st_mtime
        except OSError:
            return 0.0
    ranked = sorted((item for item in folders if item.name != current), key=used, reverse=True)
    removed = []
    for item in ranked[max(keep - 1, 0):]:
        shutil.rmtree(item.path, ignore_errors=True)
        removed.append(item.name)
    if removed:
        log.info("numba cache: removed %d folders of older code versions", len(removed))
    return removed


def _folder_size(folder: Path) -> tuple[int, int]:
    files = size = 0
    for path, _, names in os.walk(folder):
        for name in names:
            try:
                size += os.stat(os.path.join(path, name), follow_symlinks=False).st_size
                files += 1
            except OSError:
                pass
    return files, size


def cache_usage() -> list[CacheUsage]:
    """Each of :data:`KINDS`'s folders, files, size [bytes] and budget (missing folders have 0 files)."""
    limit = max_bytes()
    return [CacheUsage(kind, cache_directory(kind), *_folder_size(cache_directory(kind)),
                       None if kind == "numba" else limit) for kind in KINDS]


def clear_caches(kinds=KINDS) -> int:
    """Empty the caches ``kinds`` (a subset of :data:`KINDS`); returns the bytes removed. A process that is rendering
    meanwhile only loses time: it builds or compiles again what it does not find.

    Raises
    ------
    SwimInputError
        If a kind is not one of :data:`KINDS`.
    """
    unknown = sorted(set(kinds) - set(KINDS))
    if unknown:
        raise SwimInputError(f"unknown cache kind(s) {unknown}; expected some of {list(KINDS)}")
    removed = 0
    for kind in kinds:
        folder = cache_directory(kind)
        removed += _folder_size(folder)[1]
        shutil.rmtree(folder, ignore_errors=True)
    return removed
