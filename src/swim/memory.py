"""Returning the C heap's freed memory to the operating system between the stages of a render.

NumPy arrays smaller than glibc's mmap threshold (which glibc raises up to 32 MB after the first such array is
freed) live on the C heap, and the heaps of threads (the kernel's, the thread pools') keep what is freed in the
middle of them. A render of a big grid frees hundreds of MB of such blocks in each stage (the optical volume's
blocks of rows, Step 1a's levels, the ray march's chunks), which the process then holds as resident memory: the
peak of a 1024^2 render of the 400 x 400 x 60 scene with three warm renders fell from 2 144 to 1 852 MB above the
scene when :func:`swim.pipeline.render` called this between its stages (docs/performance.md, section 19).
``malloc_trim(0)`` gives those pages back (it walks every arena), at a cost of 3-12 ms.

The process's count of memory mappings is watched as well (:func:`release_compiled_programs`). Every XLA:CPU
executable that JAX keeps in its in-memory caches holds ~3 mappings for its machine code, and a process that compiles
thousands of programs (a pytest worker; a service rendering many different grids) reaches Linux's limit
(``vm.max_map_count``, 65 530 by default). LLVM's linker inside XLA then fails to map the next executable's code and,
on that path, leaves the unwinder's record of the freed code's exception-handling frames behind: the next C++
exception anywhere in the process crashes it with a segmentation fault in ``libgcc_s`` (docs/performance.md,
section 90).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import gc
import logging
import sys
import threading
import time

log = logging.getLogger(__name__)

#: Default share of ``vm.max_map_count`` above which :func:`release_compiled_programs` drops JAX's compiled programs.
MAPPING_FRACTION = 0.5


@functools.lru_cache(maxsize=1)
def _malloc_trim():
    if not sys.platform.startswith("linux"):
        return None
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        trim = libc.malloc_trim  # glibc only (musl has none)
    except (OSError, AttributeError):
        return None
    trim.argtypes = [ctypes.c_size_t]
    trim.restype = ctypes.c_int
    return trim


def release_free_memory() -> bool:
    """Give the C heap's free pages back to the operating system.

    Calls glibc's ``malloc_trim(0)``; elsewhere (macOS, Windows, musl) it does nothing. Live arrays are not
    touched: only memory that the process has already freed and the allocator kept is released.

    Returns
    -------
    bool
        True if memory was released (glibc reports whether it gave any back).
    """
    trim = _malloc_trim()
    return bool(trim(0)) if trim is not None else False


def memory_mapping_count() -> int | None:
    """Number of memory mappings of this process (the lines of ``/proc/self/maps``), or None without ``/proc``.

    Reading it costs ~1 ms per 3 000 mappings (the kernel writes one line for each)."""
    try:
        with open("/proc/self/maps", "rb") as f:
            return f.read().count(b"\n")
    except OSError:
        return None


@functools.lru_cache(maxsize=1)
def memory_mapping_limit() -> int | None:
    """Most memory mappings a process may hold (Linux's ``vm.max_map_count``), or None where it is not known."""
    try:
        with open("/proc/sys/vm/max_map_count") as f:
            return int(f.read().strip())
    except (OSError, ValueError):
        return None


_last_check = [float("-inf")]
_check_lock = threading.Lock()


def release_compiled_programs(fraction: float = MAPPING_FRACTION, min_interval_s: float = 0.0) -> bool:
    """Drop JAX's in-memory caches of compiled programs when the process holds more than ``fraction`` of the memory
    mappings it may hold (see the module docstring).

    The programs are compiled again, or loaded from JAX's persistent cache, when next called. Does nothing where
    JAX is not imported or the count or the limit is not known (not Linux).

    Parameters
    ----------
    fraction : float
        Share of ``vm.max_map_count`` (:func:`memory_mapping_limit`) above which the caches are dropped, in (0, 1].
    min_interval_s : float
        Shortest time between two checks [s]: a call sooner after the last check returns False without counting
        (the count costs ~10-20 ms near the limit).

    Returns
    -------
    bool
        Whether the caches were dropped.

    Raises
    ------
    ValueError
        If ``fraction`` is not in (0, 1] or ``min_interval_s`` is negative.
    """
    if not 0.0 < fraction <= 1.0:
        raise ValueError(f"release_compiled_programs: fraction must be in (0, 1], got {fraction!r}")
    if not min_interval_s >= 0.0:
        raise ValueError(f"release_compiled_programs: min_interval_s must be >= 0 s, got {min_interval_s!r}")
    jax = sys.modules.get("jax")
    if jax is None:
        return False
    with _check_lock:
        now = time.monotonic()
        if now - _last_check[0] < min_interval_s:
            return False
        _last_check[0] = now
    limit, count = memory_mapping_limit(), memory_mapping_count()
    if limit is None or count is None or count <= fraction * limit:
        return False
    jax.clear_caches()
    gc.collect()  # the executables go with their last references
    log.info("%d memory mappings of at most %d: JAX's compiled programs dropped (%s left)", count, limit,
             memory_mapping_count())
    return True
