"""A wall-clock sampling profile of one thread: where a render's seconds go, without cProfile's overhead.

cProfile charges its own bookkeeping to every Python call and sees nothing of the time that threads, JAX and numba
spend outside the interpreter. This sampler instead records the stack of the profiled thread every ``interval``
seconds from a background thread (``sys._current_frames``), so each function's share of the samples is its share of
the wall-clock time, waiting included. Used by ``bench_gpu.py --profile`` and usable on its own::

    with WallSampler() as sampler:
        swim.render(scene, **kw)
    print(sampler.report())
"""
from __future__ import annotations

import collections
import sys
import threading
import time


class WallSampler:
    """Sample the stack of the thread that enters the context, every ``interval`` [s]."""

    def __init__(self, interval: float = 0.002, prefixes: tuple[str, ...] = ("swim", "bench")):
        self.interval = interval
        self.prefixes = prefixes  # file path parts that mark the project's own frames
        self.inclusive = collections.Counter()
        self.exclusive = collections.Counter()
        self.own_leaf = collections.Counter()  # the innermost project frame of each sample
        self.own_line = collections.Counter()  # ... and its line
        self.samples = 0
        self.seconds = 0.0
        self._stop = threading.Event()

    def _key(self, frame):
        code = frame.f_code
        parts = code.co_filename.replace("\\", "/").split("/")
        short = "/".join(parts[-2:])
        return f"{short}:{code.co_firstlineno}({code.co_name})"

    def _own(self, frame):
        path = frame.f_code.co_filename.replace("\\", "/")
        return any(f"/{p}" in path for p in self.prefixes)

    def _run(self, ident):
        while not self._stop.wait(self.interval):
            frame = sys._current_frames().get(ident)
            if frame is None:
                continue
            self.samples += 1
            seen = set()
            leaf = True
            own_leaf = own_line = None
            while frame is not None:
                key = self._key(frame)
                if leaf:
                    self.exclusive[key] += 1
                    leaf = False
                if own_leaf is None and self._own(frame):
                    own_leaf = key
                    own_line = f"{key} line {frame.f_lineno}"
                if key not in seen:  # recursion counts once per sample
                    self.inclusive[key] += 1
                    seen.add(key)
                frame = frame.f_back
            self.own_leaf[own_leaf or "(no project frame)"] += 1
            self.own_line[own_line or "(no project frame)"] += 1

    def __enter__(self):
        self._thread = threading.Thread(target=self._run, args=(threading.get_ident(),), daemon=True)
        self._t0 = time.perf_counter()
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()
        self.seconds = time.perf_counter() - self._t0
        return False

    def report(self, top: int = 40) -> str:
        """Four tables, each row with its share of the wall-clock time [s]: the functions by inclusive samples, the
        innermost project frame, that frame's line, and the innermost frame of any code (own samples)."""
        per = self.seconds / max(self.samples, 1)
        lines = [f"{self.samples} samples over {self.seconds:.3f} s (one per {per * 1e3:.2f} ms)"]
        for title, counter in (("inclusive (the function or anything it called)", self.inclusive),
                               ("innermost project frame (swim or the benchmark)", self.own_leaf),
                               ("the line of the innermost project frame", self.own_line),
                               ("own (the innermost frame of any code)", self.exclusive)):
            lines += ["", f"## {title}", "seconds | share | function"]
            lines += [f"{n * per:7.3f} | {100 * n / max(self.samples, 1):5.1f} % | {key}"
                      for key, n in counter.most_common(top)]
        return "\n".join(lines)
