"""The process's worker threads: one long-lived pool per size, shared by every parallel stage of swim.

swim runs whole-grid copies, the Step 1a sweep, the rays' segments and the chunks of the ray march on threads
(NumPy and the numba kernels release the GIL). Each new thread gets one of glibc's
malloc arenas, and arenas keep pages that :func:`swim.memory.release_free_memory` cannot give back. With new
threads for every stage of every render, the resident memory after each warm 1024² render of the 400 x 400 x 60
scene (image freed, heap trimmed) grew from 1 315 to 1 462 MB above the scene over six renders; with these
long-lived threads it stays at 1 286-1 301 MB (docs/decisions/0010-memory.md).

Tasks given to a pool must not wait on tasks of the same pool (a pool's threads could all be waiting); swim's
tasks are leaves (NumPy and numba calls), and :func:`worker_pool` refuses to be called from one of its own
threads. A forked child process gets new pools (the parent's threads do not exist in it).
"""

from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor

from .errors import SwimInputError

_POOLS: dict[int, ThreadPoolExecutor] = {}
_POOLS_PID = [os.getpid()]
_LOCK = threading.Lock()
_PREFIX = "swim-worker"


def worker_pool(n: int) -> ThreadPoolExecutor:
    """The shared pool of ``n`` worker threads (made on first use, kept for the life of the process).

    Parameters
    ----------
    n : int
        Threads of the pool, >= 1 (callers pass at most :func:`threads`).

    Returns
    -------
    concurrent.futures.ThreadPoolExecutor
        Do not shut it down; cancel the futures you no longer need instead.

    Raises
    ------
    RuntimeError
        If called from a worker thread of swim's pools: a task that waited on the pools could deadlock them.
    """
    n = int(n)
    if n < 1:
        raise ValueError(f"worker_pool: n must be >= 1, got {n}")
    if in_worker_thread():
        raise RuntimeError("swim's worker pools must not be used from their own worker threads (deadlock)")
    with _LOCK:
        if _POOLS_PID[0] != os.getpid():  # a forked child: the parent's threads are not here
            _POOLS.clear()
            _POOLS_PID[0] = os.getpid()
        pool = _POOLS.get(n)
        if pool is None:
            pool = _POOLS[n] = ThreadPoolExecutor(n, thread_name_prefix=f"{_PREFIX}-{n}")
        return pool


def in_worker_thread() -> bool:
    """Whether the calling thread is one of swim's pool threads (which must not wait on the pools)."""
    return threading.current_thread().name.startswith(_PREFIX)


def parallel_map(fn, items, max_threads: int) -> list:
    """``[fn(item) for item in items]`` on up to ``max_threads`` threads of the shared pools, results in order.

    With one thread (or one item) the calls run on the calling thread. Otherwise they run on the pool of
    ``max_threads`` threads, even for fewer items: one pool per size that callers ask for, not one per number of
    items (each pool's threads and their malloc arenas live as long as the process). An exception in a call is raised
    here, and the calls not yet started are cancelled (those running finish).

    Parameters
    ----------
    fn : callable
        Called once per item; a leaf task (it must not wait on swim's pools).
    items : iterable
    max_threads : int
        Threads to use at most (callers pass at most :func:`threads`).

    Returns
    -------
    list
        The results, in the order of ``items``.
    """
    items = list(items)
    if min(int(max_threads), len(items)) <= 1:
        return [fn(item) for item in items]
    # Executor.map cancels what has not started after an exception
    return list(worker_pool(int(max_threads)).map(fn, items))


def threads() -> int:
    """Threads for work over the cores (chunks of rays marched at once, blocks of the scene's digest):
    ``SWIM_NUM_THREADS``, or the cores this process may run on.

    Raises
    ------
    SwimInputError
        If ``SWIM_NUM_THREADS`` is set to anything but a positive integer.
    """
    value = os.environ.get("SWIM_NUM_THREADS", "").strip()
    if value:
        if not value.isdigit() or int(value) < 1:
            raise SwimInputError(f"SWIM_NUM_THREADS must be a positive integer, got {value!r}")
        return int(value)
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def in_blocks(fill, n):
    """Call ``fill(i0, i1)`` over consecutive blocks of ``range(n)`` (levels, columns), one block per thread
    (:func:`threads`): copies and sums of whole grids, which NumPy runs without the GIL, on every core. An exception
    in a block is raised here."""
    workers = max(1, min(threads(), n))
    bounds = [i * n // workers for i in range(workers + 1)]
    blocks = [(i0, i1) for i0, i1 in zip(bounds[:-1], bounds[1:]) if i1 > i0]
    parallel_map(lambda block: fill(*block), blocks, len(blocks))
