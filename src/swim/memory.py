"""Returning the C heap's freed memory to the operating system between the stages of a render.

NumPy arrays smaller than glibc's mmap threshold (which glibc raises up to 32 MB after the first such array is
freed) live on the C heap, and the heaps of threads (the kernel's, the thread pools') keep what is freed in the
middle of them. A render of a big grid frees hundreds of MB of such blocks in each stage (the optical volume's
blocks of rows, Step 1a's levels, the ray march's chunks), which the process then holds as resident memory: the
peak of a 1024^2 render of the 400 x 400 x 60 scene with three warm renders fell from 2 144 to 1 852 MB above the
scene when :func:`swim.pipeline.render` called this between its stages (docs/decisions/0010-memory.md).
``malloc_trim(0)`` gives those pages back (it walks every arena), at a cost of 3-12 ms.

The process's count of memory mappings is watched as well (:func:`release_compiled_programs`). Every XLA:CPU
executable that JAX keeps in its in-memory caches holds ~3 mappings for its machine code, and a process that compiles
thousands of programs (a pytest worker; a service rendering many different grids) reaches Linux's limit
(``vm.max_map_count``, 65 530 by default). LLVM's linker inside XLA then fails to finish the next executable's code
(setting its pages' protections needs new mappings) and, on that error path, frees the code but leaves the unwinder's
record of its exception-handling frames behind: the next C++ exception anywhere in the process crashes it with a
segmentation fault in ``libgcc_s`` (docs/decisions/0010-memory.md).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import gc
import logging
import os
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

    Reading it costs ~1 ms per 1 000 mappings (15 ms for 15 400; the kernel writes one line for each)."""
    try:
        with open("/proc/self/maps", "rb") as f:
            return f.read().count(b"\n")
    except OSError:
        return None


@functools.lru_cache(maxsize=1)
def memory_mapping_limit() -> int | None:
    """Most memory mappings a process may hold (Linux's ``vm.max_map_count``), or None where it is not known.

    Read once per process: a later change of the setting is not seen."""
    try:
        with open("/proc/sys/vm/max_map_count") as f:
            return int(f.read().strip())
    except (OSError, ValueError):
        return None


_last_check = [float("-inf")]
#: Mappings left after the last drop that did not bring the count under the share (the rest are not JAX's), else 0.
_floor = [0]
_check_lock = threading.Lock()
#: Growth over :data:`_floor` [share of the limit] that a count needs before the programs are dropped again.
REDROP_MARGIN = 0.1


def release_compiled_programs(fraction: float = MAPPING_FRACTION, min_interval_s: float = 0.0) -> bool:
    """Drop JAX's in-memory caches of compiled programs when the process holds more than ``fraction`` of the memory
    mappings it may hold (see the module docstring).

    The programs are compiled again, or loaded from JAX's persistent cache, when next called. Does nothing where
    JAX is not imported or the count or the limit is not known (not Linux). Where a drop leaves the process above
    the share (the mappings are not JAX's: numba's code, threads, mapped files), a warning is logged and the next
    drop waits until the count has grown by :data:`REDROP_MARGIN` of the limit, rather than recompiling every
    program at every check.

    Parameters
    ----------
    fraction : float
        Share of ``vm.max_map_count`` (:func:`memory_mapping_limit`) above which the caches are dropped, in (0, 1].
    min_interval_s : float
        Shortest time between two checks [s]: a call sooner after the last check returns False without counting
        (the count costs tens of ms near the limit).

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
    if limit is None or count is None:
        return False
    threshold = fraction * limit
    if _floor[0]:  # the last drop did not get under the share: wait for growth
        threshold = max(threshold, _floor[0] + REDROP_MARGIN * limit)
    if count <= threshold:
        return False
    jax.clear_caches()
    gc.collect()  # the executables go with their last references
    left = memory_mapping_count()
    if left is not None and left > fraction * limit:
        _floor[0] = left
        log.warning("%d memory mappings of at most %d; %d left after JAX's compiled programs were dropped: the rest "
                    "are not JAX's", count, limit, left)
    else:
        _floor[0] = 0
        log.info("%d memory mappings of at most %d: JAX's compiled programs dropped (%s left)", count, limit, left)
    return True


def available_memory_bytes() -> int | None:
    """The memory the system can give a process now without swapping [bytes]: ``MemAvailable`` of /proc/meminfo
    (Linux), else the free physical pages; None where neither is known."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return None
