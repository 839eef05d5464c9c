"""How fast this machine is right now: a fixed workload like the march's, timed on every core (prints a line).

Usage::

    python benchmarks/machine_probe.py                  # one probe: ns per sample, best of 3 passes
    python benchmarks/machine_probe.py --watch 20       # 20 probes, one every few seconds (the machine's drift)

This project's shared 2-core machines run the same code at (at least) two speeds, switching between them within a
second to tens of seconds: on an AMD EPYC the march's replay takes 0.62 s in one state and 0.85-0.95 s in the other
(docs/performance.md, "How to measure"). A "fast hour" is an hour spent mostly in the first state. So a figure means
little without the state it was taken in. The probe measures that state, independently of swim's code: the benchmark
suite (``bench_suite.py``) takes a reference before its first case (:func:`reference`), then one probe before every warm
render of a render case and one after the last, and stores them beside the render times (``machine_probe_ns``).

The workload imitates the march's step loop without being it, so that a change to swim does not change the probe:
rays of 96 steps through a (24, 48, 48, 8) float32 volume of 1.8 MB, each step a trilinear sample of 8 channels (eight
corner loads of 32 bytes) and four wavelength lanes of multiply-adds and a Taylor polynomial. Rays leave in bundles of
64 from one point in nearby directions, as a tile of pixels' rays do. The volume stays in the caches: like the march
(docs/performance.md, "How to measure"), the probe is bound by the instructions it issues, which is what the machine's
slow state slows. A version with a 201 MB volume and libm's exponentials, bound by memory and calls, saw the slow state
as 1.17× its fast one where the march saw 1.4× (docs/performance.md, "How to measure"). Each core marches its own rays,
in a compiled loop without the GIL, all cores at once. The result is the best of the passes (the least disturbed), as ns
per sample per core: ~36 ns in that AMD EPYC's fast state, ~53 ns in its slow one.
"""

from __future__ import annotations

import argparse
import functools
import math
import os
import sys
import threading
import time

import numpy as np
from numba import njit

#: The probe's volume: levels, rows, columns, channels (float32, 1.8 MB).
SHAPE = (24, 48, 48, 8)
#: Rays per core (a multiple of 64) and steps per ray of one pass (~20 ms in the AMD EPYC's fast state, ~30 ms in its
#: slow one).
RAYS = 6016
STEPS = 96


@njit(nogil=True, fastmath=True, cache=False)
def _march(volume, origin, direction, out):
    nk, ny, nx, nc = volume.shape
    for r in range(origin.shape[0]):
        k, j, i = origin[r, 0], origin[r, 1], origin[r, 2]
        dk, dj, di = direction[r, 0], direction[r, 1], direction[r, 2]
        tau = 0.0
        light = 0.0
        for _ in range(STEPS):
            # reflected at the volume's faces, so that every step samples inside it
            if k < 0.0 or k > nk - 1.001:
                dk = -dk
                k = min(max(k, 0.0), nk - 1.001)
            if j < 0.0 or j > ny - 1.001:
                dj = -dj
                j = min(max(j, 0.0), ny - 1.001)
            if i < 0.0 or i > nx - 1.001:
                di = -di
                i = min(max(i, 0.0), nx - 1.001)
            k0, j0, i0 = int(k), int(j), int(i)
            fk, fj, fi = k - k0, j - j0, i - i0
            w00, w01, w10, w11 = (1 - fk) * (1 - fj), (1 - fk) * fj, fk * (1 - fj), fk * fj
            beta = 0.0
            source = 0.0
            for c in range(nc):
                v = ((1 - fi) * (w00 * volume[k0, j0, i0, c] + w01 * volume[k0, j0 + 1, i0, c]
                                 + w10 * volume[k0 + 1, j0, i0, c] + w11 * volume[k0 + 1, j0 + 1, i0, c])
                     + fi * (w00 * volume[k0, j0, i0 + 1, c] + w01 * volume[k0, j0 + 1, i0 + 1, c]
                             + w10 * volume[k0 + 1, j0, i0 + 1, c] + w11 * volume[k0 + 1, j0 + 1, i0 + 1, c]))
                if c < nc - 2:
                    beta += v
                else:
                    source += v
            for lane in range(4):  # four wavelength lanes, as the march's step: (1 - e^-x) / x by its polynomial
                x = beta * (1.0 + 0.1 * lane)
                m = 1.0 - x * (0.5 - x * (1.0 / 6 - x * (1.0 / 24 - x * (1.0 / 120 - x * (1.0 / 720 - x / 5040)))))
                light += source * (1.0 + 0.05 * lane) * m * x / (1.0 + tau * (1.0 + 0.1 * lane))
            tau += beta * 0.01
            k += dk
            j += dj
            i += di
        out[r] = light + tau


def default_cores():
    """The cores this process may use [-]."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


@functools.lru_cache(maxsize=4)
def _inputs(cores, seed=0):
    """The volume, each core's ray origins and directions, and its outputs; the kernel compiled."""
    rng = np.random.default_rng(seed)
    volume = rng.random(SHAPE, dtype=np.float32) * np.float32(0.05)
    origins, directions = [], []
    for _ in range(cores):
        bundles = RAYS // 64
        centre = rng.random((bundles, 1, 3)) * (np.array(SHAPE[:3]) - 1.001)
        axis = rng.normal(size=(bundles, 1, 3))
        axis /= np.linalg.norm(axis, axis=2, keepdims=True)
        direction = axis + 0.05 * rng.normal(size=(bundles, 64, 3))
        direction *= 1.3 / np.linalg.norm(direction, axis=2, keepdims=True)  # steps of 1.3 cells
        origins.append(np.repeat(centre, 64, axis=1).reshape(-1, 3))
        directions.append(direction.reshape(-1, 3))
    outs = [np.zeros(RAYS) for _ in range(cores)]
    _march(volume, origins[0][:1], directions[0][:1], outs[0][:1])  # compiled here, not in a timed pass
    return volume, origins, directions, outs


def ready(cores=None):
    """Compile the probe and make its inputs (~1 s once per process), so that :func:`probe` times the work alone.
    The benchmark suite calls it before it loads a case's scene, so that the compiler's memory counts as the
    scene's and not as the render's."""
    _inputs(cores or default_cores())


def probe(cores=None, passes=3):
    """Time the probe's workload on ``cores`` threads at once.

    Parameters
    ----------
    cores : int, optional
        Threads, each marching its own :data:`RAYS` rays of :data:`STEPS` steps [-]; default: every core this
        process may use.
    passes : int
        Timed passes after an untimed one [-]; the best counts.

    Returns
    -------
    dict
        ``ns_per_sample``: the best pass's wall time over one core's samples [ns]; ``passes_ms``: each pass's wall
        time [ms]; ``cores``.
    """
    if passes < 1:
        raise ValueError(f"machine_probe.probe: passes must be >= 1, got {passes!r}")
    cores = cores or default_cores()
    volume, origins, directions, outs = _inputs(cores)

    def one_pass():
        threads = [threading.Thread(target=_march, args=(volume, o, d, out))
                   for o, d, out in zip(origins, directions, outs)]
        t0 = time.perf_counter()
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        return time.perf_counter() - t0

    one_pass()
    seconds = [one_pass() for _ in range(passes)]
    return {"ns_per_sample": min(seconds) / (RAYS * STEPS) * 1e9, "passes_ms": [1e3 * s for s in seconds],
            "cores": cores}


def reference(seconds=6.0, cores=None):
    """The fastest of one-pass probes taken one after the other for ``seconds`` [s]: the machine's fast state, if
    it visited it meanwhile (it switches within a second to tens of seconds, docs/performance.md, "How to measure").
    ``bench_suite.py`` takes it once before its first case, so that a case that never sees the fast state is not judged
    against its own fastest probe alone. Returns ns per sample [ns]."""
    ready(cores)
    best, end = math.inf, time.monotonic() + seconds
    while time.monotonic() < end:
        best = min(best, probe(cores, passes=1)["ns_per_sample"])
    return best


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--cores", type=int, default=None, help="threads at once (default: every core)")
    parser.add_argument("--watch", type=int, default=1, help="probes to take, one after the other")
    parser.add_argument("--every", type=float, default=5.0, help="seconds between probes with --watch")
    args = parser.parse_args(argv)
    if args.cores is not None and args.cores < 1:
        parser.error(f"--cores must be >= 1, got {args.cores}")
    for n in range(args.watch):
        if n:
            time.sleep(args.every)
        r = probe(args.cores)
        print(f"{time.strftime('%H:%M:%S')} machine probe: {r['ns_per_sample']:.1f} ns per sample on each of "
              f"{r['cores']} cores (passes {', '.join(f'{p:.0f}' for p in r['passes_ms'])} ms)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
