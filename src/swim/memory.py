"""Returning the C heap's freed memory to the operating system between the stages of a render.

NumPy arrays smaller than glibc's mmap threshold (which glibc raises up to 32 MB after the first such array is
freed) live on the C heap, and the heaps of threads (the kernel's, the thread pools') keep what is freed in the
middle of them. A render of a big grid frees hundreds of MB of such blocks in each stage (the optical volume's
blocks of rows, Step 1a's levels, the ray march's chunks), which the process then holds as resident memory: the
peak of a 1024^2 render of the 400 x 400 x 60 scene with three warm renders fell from 2 144 to 1 852 MB above the
scene when :func:`swim.pipeline.render` called this between its stages (docs/performance.md, section 19).
``malloc_trim(0)`` gives those pages back (it walks every arena), at a cost of 3-12 ms.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import sys


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
