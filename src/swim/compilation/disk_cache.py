"""Persistent caches, so that a new process neither compiles the JAX kernels nor builds the tables again.

The ray-march and Step 1a kernels take several seconds to compile on a CPU (more than the README's default
render itself once warm); JAX can store the compiled executables on disk and reload them in later processes.
The cache lives in ``$SWIM_CACHE_DIR/jax`` (default ``$XDG_CACHE_HOME/swim/jax`` or ``~/.cache/swim/jax``);
``SWIM_JAX_CACHE=0`` turns it off. A cache that cannot be created is skipped with a log message: it only
ever saves time. :func:`disk_cached` keeps other slow, deterministic results (the successive-orders tables of
:mod:`swim.rt.gas`) in ``$SWIM_CACHE_DIR/<kind>``, keyed by their arguments and the code that builds them.
Every cache stays within a budget (``SWIM_CACHE_MAX_MB``, least recently used entries removed first;
:mod:`swim.compilation.cache_budget`), and ``swim cache`` lists or clears them.
"""

from __future__ import annotations

import hashlib
import logging
import os
import pickle
import tempfile
from pathlib import Path

log = logging.getLogger(__name__)

_DONE = False


def switched_off(variable: str) -> bool:
    """Whether the environment variable ``variable`` turns its switch off ("0", "false", "no" or "off"; on when unset):
    ``SWIM_JAX_CACHE`` here, ``SWIM_PRECOMPILE`` in :mod:`swim.rt.precompile`."""
    return os.environ.get(variable, "1").strip().lower() in ("0", "false", "no", "off")


def _disabled() -> bool:
    return switched_off("SWIM_JAX_CACHE")


def cache_directory(kind: str = "jax") -> Path:
    """Directory of one persistent cache, e.g. ``"jax"`` for the compiled kernels (see the module docstring)."""
    root = os.environ.get("SWIM_CACHE_DIR")
    if root:
        return Path(root) / kind
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "swim" / kind


def package_sources() -> list[Path]:
    """Every Python file of the swim package: a result keyed by all of them is rebuilt after any code change
    (the tables depend on the optics modules as well as on the module that builds them)."""
    return sorted(Path(__file__).resolve().parents[1].rglob("*.py"))


def disk_cached(kind: str, key, build, sources=()):
    """``build()``, or its pickled result from an earlier process with the same ``key`` and code.

    ``key`` must have a repr that identifies the result (no object addresses); ``sources`` are the files
    whose code the result depends on (a changed file gives a new entry). Unreadable entries are rebuilt and
    unwritable caches skipped: the cache only ever saves time.
    """
    text = repr(key)
    if _disabled() or " at 0x" in text:
        return build()
    digest = hashlib.sha256(text.encode())
    for source in sources:
        digest.update(Path(source).read_bytes())
    path = cache_directory(kind) / f"{digest.hexdigest()[:40]}.pkl"
    from .cache_budget import mark_used, max_bytes

    try:
        with open(path, "rb") as f:
            result = pickle.load(f)
        mark_used(path)  # least recently used entries go first when the cache is over its budget
        return result
    except (OSError, pickle.UnpicklingError, EOFError, AttributeError, ImportError):
        pass
    limit = max_bytes()  # a bad SWIM_CACHE_MAX_MB is reported before the build, not after it
    result = build()
    try:
        store_entry(path, lambda f: pickle.dump(result, f, protocol=pickle.HIGHEST_PROTOCOL), limit)
    except OSError as err:
        log.info("could not cache %s (%s)", kind, err)
    return result


def store_entry(path: Path, write, limit_bytes: int, suffix: str = ".pkl") -> None:
    """Write one entry of a disk cache: ``write(f)`` fills an open binary ``*.tmp`` file beside ``path``, which is then
    renamed to ``path`` (so that a concurrent reader never sees half a file; a killed writer's ``*.tmp`` is removed
    later), and the folder's least recently used entries (ending in ``suffix``) go until it fits in ``limit_bytes``
    (:func:`swim.compilation.cache_budget.prune_least_recently_used`). Raises OSError where the folder cannot be written."""
    from .cache_budget import prune_least_recently_used

    path.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.NamedTemporaryFile(dir=path.parent, suffix=".tmp", delete=False) as f:
        write(f)
    os.replace(f.name, path)
    prune_least_recently_used(path.parent, limit_bytes, keep=path, suffix=suffix)


def serialise_numba_cache_writes() -> None:
    """Make numba's saves of disk-cache entries exclusive between processes (a file lock per cache folder).

    numba saves an entry by reading the function's index, adding its key and writing the index back, without a
    lock. Two processes that save entries of the same function at once (different argument types: the helpers of
    :mod:`swim.rt.march_cpu` are compiled for arrays and for tuples) can lose one, or number both data files alike,
    so that one signature's key points at the other's machine code. A helper process compiling beside the render
    (:mod:`swim.rt.precompile`), or two pytest-xdist workers, make that likely; the lock is held for the save
    only (~1 ms). Without ``fcntl`` (Windows) numba's own behaviour is kept."""
    try:
        import fcntl

        from numba.core import caching

        original = caching.IndexDataCacheFile.save
    except (ImportError, AttributeError):
        return
    if getattr(original, "_swim_locked", False):
        return

    def save(self, key, data):
        try:
            handle = open(os.path.join(self._cache_path, "swim-index.lock"), "a")
        except OSError:
            return original(self, key, data)
        with handle:  # closing the file releases the lock
            fcntl.flock(handle, fcntl.LOCK_EX)
            return original(self, key, data)

    save._swim_locked = True
    caching.IndexDataCacheFile.save = save


def enable_compilation_cache() -> Path | None:
    """Point JAX's persistent compilation cache at :func:`cache_directory` (once per process).

    Returns the directory, or None when the cache is disabled (``SWIM_JAX_CACHE=0``), when the user has
    already configured a JAX cache directory (theirs is kept), or when the directory cannot be created.
    """
    global _DONE
    if _DONE:
        return None
    _DONE = True
    if _disabled():
        return None
    import jax

    if jax.config.jax_compilation_cache_dir:
        return None
    path = cache_directory()
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        log.info("no persistent JAX compilation cache (%s)", err)
        return None
    jax.config.update("jax_compilation_cache_dir", str(path))
    _bound_jax_cache(jax)
    # Cache every compiled function: a render compiles ~60 small ones (0.05-0.3 s each) beside the two big
    # kernels, and loading them is faster.
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    return path


def _bound_jax_cache(jax) -> None:
    """JAX's own least-recently-used eviction at :func:`swim.compilation.cache_budget.max_bytes` (it needs ``filelock``).

    A size the user has set (``JAX_COMPILATION_CACHE_MAX_SIZE`` or the config) is kept, and a bad
    ``SWIM_CACHE_MAX_MB`` leaves the cache unbounded with a warning (this runs at import, where an exception would
    stop every command). The cache also stays unbounded where this JAX's eviction is not the one
    :func:`_backfill_before_eviction` knows."""
    from ..errors import SwimInputError
    from .cache_budget import max_bytes

    if "JAX_COMPILATION_CACHE_MAX_SIZE" in os.environ or jax.config.jax_compilation_cache_max_size != -1:
        return
    try:
        import filelock  # noqa: F401  (JAX's LRU cache locks its folder with it)
        from jax._src import lru_cache

        limit = max_bytes()
    except ImportError as err:
        log.info("JAX's compilation cache is unbounded (%s)", err)
        return
    except SwimInputError as err:
        log.warning("%s: JAX's compilation cache is left unbounded", err)
        return
    if _backfill_before_eviction(lru_cache):
        jax.config.update("jax_compilation_cache_max_size", limit)
    else:
        log.info("JAX's compilation cache is unbounded: this JAX's eviction is not the one swim knows")


def _backfill_before_eviction(lru_cache) -> bool:
    """Make JAX's eviction (``LRUCache._evict_if_needed``, run under its folder lock at every new entry) first give
    each entry the access-time file it reads (``<key>-atime``); returns whether it could.

    JAX writes that file only while eviction is on. Entries written without it (before eviction was on, by an older
    swim, or by a process with another setting) made the eviction fail with FileNotFoundError at every new
    compilation, so that nothing new was cached. A missing time is taken from the entry's modification time."""
    cls = getattr(lru_cache, "LRUCache", None)
    original = getattr(cls, "_evict_if_needed", None)
    if original is None:
        return False
    if getattr(original, "_swim_backfills", False):
        return True

    def evict_if_needed(self, *args, **kwargs):
        _backfill_access_times(Path(str(self.path)))
        return original(self, *args, **kwargs)

    evict_if_needed._swim_backfills = True
    cls._evict_if_needed = evict_if_needed
    return True


def _backfill_access_times(folder: Path) -> None:
    """The ``<key>-atime`` file of every ``<key>-cache`` entry in ``folder`` that lacks one (see
    :func:`_backfill_before_eviction`); entries that vanish meanwhile are skipped."""
    try:
        names = set(os.listdir(folder))
    except OSError:
        return
    for name in names:
        if name.endswith("-cache") and name[:-len("-cache")] + "-atime" not in names:
            try:
                stamp = os.stat(folder / name).st_mtime_ns
                (folder / (name[:-len("-cache")] + "-atime")).write_bytes(stamp.to_bytes(8, "little"))
            except OSError:
                pass
