"""The CPU march kernel alone, replayed on one core: its inputs captured from a real render (prints a table).

Usage::

    python benchmarks/bench_march.py --scene synthetic --size 512                  # time per sample and per ray
    python benchmarks/bench_march.py --scene rico --size 512 --experiments         # + cache and fixed-cost splits
    python benchmarks/bench_march.py --scene synthetic --variant /tmp/my_march_cpu.py --repeats 15
    python benchmarks/bench_march.py --scene synthetic --variant /tmp/my_march_cpu.py --repeats 8 --interleave
    python benchmarks/bench_march.py --scene mc --size 41 --flush 64 --repeats 15       # the Monte Carlo case's view

A render's timing moves by 10-20 % on this project's shared 2-core machine, which hides a change of a few per
cent in the kernel. This script renders the suite's all-sky view of a scene once (``benchmarks/bench_suite.py``'s
scenes and vantages), keeps the arguments of every call of :func:`swim.rt.march_cpu.march_rays` (each chunk of
rays with the tables it reads), and replays them on one thread, several times, alternating between kernels:
the minimum over the repeats then moves by ~1-2 %. It reports rays, samples (the medium's samples per ray that
the kernel counts, docs/performance.md, "How to measure"), ns per sample and µs per ray.

``--scene mc`` captures the view of the suite's Monte Carlo case instead (``mc_ratio``: the RICO LES seen from
the ground, :func:`swim.validation.mitsuba.swim_view`, 41² in the suite). ``--flush MB`` writes to a buffer of that
many MB before each kernel's pass, as a render's other work does between its marches, so that the tables start
outside the caches (what a small render sees).

``--variant FILE.py`` replays the same inputs through another implementation of ``march_rays`` (a copy of
``src/swim/rt/march_cpu.py`` with a change; its relative imports are rewritten to ``swim.rt.``) and reports the
largest difference of its outputs from the installed kernel's. ``--interleave`` alternates the kernels chunk by
chunk instead of pass by pass and adds each one's time over the installed kernel's, with its range over the passes:
the machine's load then falls alike on all of them, and two kernels' time ratio moves by ~1-3 % from pass to pass,
where whole passes taken in turn differ by 5-10 % (docs/performance.md, "How to measure"). Use it to judge a change of a
few per cent, against a plain copy of march_cpu.py replayed beside it: a copy compiled in this process runs 0.98-1.01
times the installed kernel's time (loaded from numba's disk cache).

``--experiments`` adds three splits of the time:

* ``one ray per chunk``: every ray of a chunk replaced by the chunk's middle ray, so the tables it reads stay in
  the caches: the kernel's cost without cache misses (its arithmetic, branches and L1 reads);
* ``rays shuffled``: the chunk's rays in random order, so neighbouring rays no longer share cache lines;
* ``one step per segment``: one step before, in and after the grid (no refinement), so what remains is the
  per-ray cost that does not grow with the steps: the occupancy and clear-air probes that place them, the
  set-up and the outputs (``set-up per ray`` = its µs per ray less its few samples at the full run's cost).

Results go to ``benchmarks/results/march-latest.json`` (``--out`` to change) and ns per sample of each kernel to
``benchmarks/results/history.csv``.
"""

from __future__ import annotations

import argparse
import importlib.util
import inspect
import json
import re
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import bench_suite  # noqa: E402  (benchmarks/ on the path first)

#: The suite's all-sky case of each scene (its view and sun).
SCENE_CASES = {"synthetic": "synthetic_allsky", "rico": "rico_allsky", "katrina": "katrina_allsky",
               "conus": "conus_allsky", "mc": "mc_ratio"}
#: march_rays' outputs (written in place), by name: the per-ray results, then the 3-D clouds' radiance (its last
#: argument, after the clouds' inputs).
OUTPUTS = ("tau_clear", "tau_h", "tau_species", "l_clear", "i_nogas", "i_gas", "i_cloud_t", "alive_out", "hit_out",
           "s_hit_out", "samples_out", "l_cloud")


def output_positions():
    """The positions of :data:`OUTPUTS` among march_rays' arguments (those of the kernel under test: older ones had
    fewer outputs, all last)."""
    import inspect

    from swim.rt import march_cpu

    names = list(inspect.signature(march_cpu.march_rays).parameters)
    return [names.index(name) for name in OUTPUTS if name in names]


def capture(scene_name, size, data):
    """Render the suite's all-sky view of ``scene_name`` at ``size``² with the numba kernel and return the
    arguments of every ``march_rays`` call (a list of lists; the tables are shared, not copied)."""
    import swim
    from swim.rt import march_cpu
    from swim.rt.march_settings import ExecutionSettings, MarchSettings

    spec = {**bench_suite.CASES[SCENE_CASES[scene_name]], "data": str(data)}
    scene = bench_suite.load_scene(spec)
    calls, original = [], march_cpu.march_rays

    def recording(*args):
        calls.append(list(args))  # list.append is atomic: the render's threads may call at once
        return original(*args)

    march_cpu.march_rays = recording
    try:
        if spec.get("kind") == "mc":
            from swim.validation.mitsuba import RICO_CASES, swim_view

            case = RICO_CASES[spec["mc_case"]]
            swim_view(scene, case["view"], case["sun_zenith"], settings={"allsky_size": size},
                      march_settings=MarchSettings(execution=ExecutionSettings(backend="numba")))
        else:
            kw = bench_suite.render_kwargs(spec, image=(size, size))
            kw["settings"] = MarchSettings(execution=ExecutionSettings(backend="numba"))
            swim.render(scene, **kw)
    finally:
        march_cpu.march_rays = original
    if not calls:
        raise SystemExit(f"the render of {scene_name} called no numba march (is the numba kernel in use?)")
    return calls


def load_variant(path):
    """``march_rays`` of a copy of march_cpu.py at ``path`` (relative imports made absolute, no disk cache)."""
    source = re.sub(r"^from \.\.([\w.]+) import", r"from swim.\1 import", Path(path).read_text(), flags=re.MULTILINE)
    source = re.sub(r"^from \.(\w+) import", r"from swim.rt.\1 import", source, flags=re.MULTILINE)
    # the kernels' and the helpers' options without the disk cache
    source = source.replace("@helper_jit(", "@helper_jit(cache=False, ").replace(
        "**JIT_KERNEL", '**{**JIT_KERNEL, "cache": False}')
    folder = Path(tempfile.mkdtemp(prefix="swim-march-variant-"))
    copy = folder / f"variant_{Path(path).stem}.py"
    copy.write_text(source)
    spec = importlib.util.spec_from_file_location(copy.stem, copy)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.march_rays


def with_fresh_outputs(calls):
    """Copies of the calls' argument lists with new zeroed outputs (the inputs shared)."""
    fresh, positions = [], output_positions()
    for args in calls:
        args = list(args)
        for q in positions:
            args[q] = np.zeros_like(args[q])
        fresh.append(args)
    return fresh


def reorder(calls, mode, seed=0):
    """The calls with each chunk's per-ray inputs replaced: ``"one ray"`` (the middle ray everywhere) or
    ``"shuffled"`` (a random permutation)."""
    from swim.rt import march_cpu

    names = list(inspect.signature(march_cpu.march_rays).parameters)
    per_ray = names[:names.index("ms_profile")]  # start ... class_weight: (n, ...) arrays
    i_ms = names.index("ms_profile")
    out = []
    for args in calls:
        args = list(args)
        n = args[0].shape[0]
        idx = np.full(n, n // 2) if mode == "one ray" else np.random.default_rng(seed).permutation(n)
        for q in range(len(per_ray)):
            args[q] = np.ascontiguousarray(args[q][idx])
        if args[i_ms].shape[1] >= n:  # (9, padded rays, n_u): the rows of the rays (the padding is not read)
            args[i_ms] = np.ascontiguousarray(args[i_ms][:, idx])
        out.append(args)
    return with_fresh_outputs(out)


def with_setting(calls, **values):
    from swim.rt import march_cpu

    names = list(inspect.signature(march_cpu.march_rays).parameters)
    out = []
    for args in with_fresh_outputs(calls):
        for key, value in values.items():
            args[names.index(key)] = value
        out.append(args)
    return out


def replay(runs, repeats, flush_mb=0):
    """Time each (label, march, calls) of ``runs``, alternating between them ``repeats`` times after one warm-up
    pass each (a buffer of ``flush_mb`` MB written before each pass); returns {label: {"seconds": [...], "rays",
    "samples"}}."""
    for _, march, calls in runs:
        for args in calls:
            march(*args)
    seconds = {label: [] for label, _, _ in runs}
    buffer = np.zeros(int(flush_mb * 2**20) // 8)
    for _ in range(repeats):
        for label, march, calls in runs:
            buffer += 1.0  # the caches filled with other data, as between a render's marches
            t0 = time.perf_counter()
            for args in calls:
                march(*args)
            seconds[label].append(time.perf_counter() - t0)
    return {label: _summary(seconds[label], calls) for label, _, calls in runs}


def _summary(seconds, calls):
    """A run's passes ``seconds`` [s] over the replay ``calls``: best and median pass, rays, samples, ns a sample and
    µs a ray (of the best pass)."""
    rays = sum(args[0].shape[0] for args in calls)
    samples = sum(int(args[-1].sum()) for args in calls)
    best = min(seconds)
    return {"seconds": seconds, "min_s": best, "median_s": statistics.median(seconds), "rays": rays,
            "samples": samples, "samples_per_ray": samples / rays, "ns_per_sample": best / samples * 1e9,
            "us_per_ray": best / rays * 1e6}


def replay_interleaved(runs, repeats):
    """Time each (label, march, calls) of ``runs`` chunk by chunk: every chunk is replayed by each run in turn (the
    order reversed from one chunk to the next), ``repeats`` passes after one warm-up pass. Load that changes over
    more than a chunk's time (tens of ms) then falls alike on every run: the runs' time ratios to the first run
    move by ~1 % from pass to pass, where whole passes taken in turn (:func:`replay`) move by 5-10 % on this
    project's shared machine. Returns :func:`replay`'s dict, each entry with ``ratio`` (its total time over the first
    run's) and ``pass_ratios`` added."""
    for _, march, calls in runs:
        for args in calls:
            march(*args)
    seconds = {label: [0.0] * repeats for label, _, _ in runs}
    n_chunks = len(runs[0][2])
    for rep in range(repeats):
        for c in range(n_chunks):
            order = runs if (rep + c) % 2 == 0 else runs[::-1]
            for label, march, calls in order:
                t0 = time.perf_counter()
                march(*calls[c])
                seconds[label][rep] += time.perf_counter() - t0
    first = seconds[runs[0][0]]
    return {label: {**_summary(seconds[label], calls), "ratio": sum(seconds[label]) / sum(first),
                    "pass_ratios": [a / b for a, b in zip(seconds[label], first)]} for label, _, calls in runs}


def max_difference(a_calls, b_calls):
    """Largest absolute difference between the outputs of two replays of the same inputs."""
    worst, positions = 0.0, output_positions()
    for a, b in zip(a_calls, b_calls):
        for q in positions:
            worst = max(worst, float(np.max(np.abs(np.asarray(a[q], float) - np.asarray(b[q], float)), initial=0.0)))
    return worst


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", choices=sorted(SCENE_CASES), default="synthetic")
    parser.add_argument("--size", type=int, default=512, help="all-sky image size [pixels] of the captured render")
    parser.add_argument("--chunks", type=int, default=0, help="replay only the first N chunks (0: all)")
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--variant", action="append", default=[], help="another march_cpu.py to replay (repeatable)")
    parser.add_argument("--flush", type=float, default=0.0, help="MB written before each pass (caches cold)")
    parser.add_argument("--experiments", action="store_true", help="cache and fixed-cost splits (see the docstring)")
    parser.add_argument("--interleave", action="store_true",
                        help="alternate the runs chunk by chunk instead of pass by pass (see the docstring)")
    parser.add_argument("--data", type=Path, default=bench_suite.DATA)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)


    from swim.rt import march_cpu

    calls = capture(args.scene, args.size, args.data)
    calls = calls[:args.chunks] if args.chunks else calls
    names = list(inspect.signature(march_cpu.march_rays).parameters)
    base = with_fresh_outputs(calls)
    runs = [("kernel", march_cpu.march_rays, base)]
    for path in args.variant:
        runs.append((f"variant {Path(path).name}", load_variant(path), with_fresh_outputs(calls)))
    if args.experiments:
        one_step = with_setting(calls, n_before=min(int(calls[0][names.index("n_before")]), 1), n_grid=1,
                                n_after=min(int(calls[0][names.index("n_after")]), 1), tau_refine=0.0)
        runs += [("one ray per chunk", march_cpu.march_rays, reorder(calls, "one ray")),
                 ("rays shuffled", march_cpu.march_rays, reorder(calls, "shuffled")),
                 ("one step per segment", march_cpu.march_rays, one_step)]
    if args.interleave and args.flush:
        parser.error("--interleave replays chunk by chunk: --flush (before each whole pass) does not apply")
    result = replay_interleaved(runs, args.repeats) if args.interleave else replay(runs, args.repeats, args.flush)
    for label, _, replayed in runs[1:1 + len(args.variant)]:
        result[label]["max_output_difference"] = max_difference(base, replayed)
    if args.experiments:
        full, few = result["kernel"], result["one step per segment"]
        result["setup_per_ray_us"] = few["us_per_ray"] - few["samples_per_ray"] * full["ns_per_sample"] * 1e-3
        result["setup_share"] = result["setup_per_ray_us"] / full["us_per_ray"]

    flushed = f", {args.flush:g} MB written before each pass" if args.flush else ""
    mode = "runs alternating chunk by chunk" if args.interleave else "runs alternating pass by pass"
    print(f"\n{args.scene}, {args.size}² all-sky: {len(calls)} chunks of rays (the first {calls[0][0].shape[0]}); "
          f"one thread, {mode}, best of {args.repeats}{flushed}\n")
    ratio_head = " time / kernel's (passes) |" if args.interleave else ""
    print(f"| run | rays | samples/ray | min [s] | median [s] | ns/sample | µs/ray | max output difference |"
          f"{ratio_head}")
    print("|---|---|---|---|---|---|---|---|" + ("---|" if args.interleave else ""))
    for label, _, _ in runs:
        r = result[label]
        diff = f"{r['max_output_difference']:.3g}" if "max_output_difference" in r else ""
        ratio = (f" {r['ratio']:.3f} ({min(r['pass_ratios']):.3f}-{max(r['pass_ratios']):.3f}) |"
                 if args.interleave else "")
        print(f"| {label} | {r['rays']} | {r['samples_per_ray']:.1f} | {r['min_s']:.3f} | {r['median_s']:.3f} | "
              f"{r['ns_per_sample']:.1f} | {r['us_per_ray']:.2f} | {diff} |{ratio}")
    if args.experiments:
        print(f"\nset-up per ray (probes, step placement, outputs): {result['setup_per_ray_us']:.2f} µs, "
              f"{100 * result['setup_share']:.0f} % of the kernel's time")

    out = args.out or bench_suite.RESULTS / "march-latest.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    doc = {"scene": args.scene, "size": args.size, "chunks": len(calls), "repeats": args.repeats,
           "flush_mb": args.flush, "interleaved": args.interleave,
           "machine": bench_suite.machine_info(), "git": bench_suite.git_info(), "results": result}
    out.write_text(json.dumps(doc, indent=1, default=float))
    import history  # benchmarks/ is on the path

    history.append("march", history.march_rows(doc), machine=history.machine_label(doc["machine"]),
                   commit=history.commit_label(doc["git"]), source="bench_march.py")
    print(f"\nwritten: {out}, {history.HISTORY}")


if __name__ == "__main__":
    main()
