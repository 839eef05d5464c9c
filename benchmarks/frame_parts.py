"""Where a JAX-kernel frame's device time goes, program by program: each of the frame's compiled programs waited for
as it is called.

Usage::

    python benchmarks/frame_parts.py                             # synthetic 1024² all-sky, every pixel and adaptive
    python benchmarks/frame_parts.py --stand-in --repeats 3      # without a GPU: the march replaced (bench_host.py's)
    python benchmarks/frame_parts.py --scene katrina --data .devdata --size 512

A GPU frame queues its programs on the device and waits for them only where the host needs a result (an adaptive
level's wanted pixels, the final copy), so a wall-clock profile (``wall_profile.py``) shows the waits but not which
program they wait for. Here the frame's programs are wrapped so that each call waits for its result
(``jax.block_until_ready``): the march's chunks (:func:`swim.rt.march_jax._trace_chunk`), the ray table's gathers
(:func:`swim.rt.ray_table._gather_rows`), the device sampler's programs (:mod:`swim.rt.image_sampling_device`: the
first lattice, each level's test and split, each batch's scatter, the final fill), the planes
(:mod:`swim.rt.image_device`) and the colour stage (:mod:`swim.color.srgb_device`). Each part's time is then the
device's (plus a call's dispatch), and "the rest" is the frame's Python and host work with the device idle, and
the device's few small programs that are not wrapped (eager operations, allocations, the final copy). The
waits serialise the frame, so its total here is larger than an unwaited frame's, which is timed first (``frame_s``)
for comparison.

The ray table, the device sampler and the image on the device are switched on (on a GPU they are the defaults). On a
CPU the "device" is the host's cores: XLA's CPU code is slower than a GPU's for these programs, so use ``--stand-in``
there to leave the march out (the images are then not physical) and read the figures as an upper bound. Results go to
``benchmarks/results/frame-parts-latest.json`` (``--out`` to change) and each program's seconds to
``benchmarks/results/history.csv``; docs/decisions/0005-adaptive-sampling.md
"""

from __future__ import annotations

import argparse
import collections
import json
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent
sys.path.insert(0, str(ROOT))

import bench_suite  # noqa: E402  (the suite's scenes, views and render options)

#: The frame's programs: (module, function name, label). Each is looked up in its module at every call, so that a
#: wrapper put there is what the frame calls.
PARTS = (
    ("swim.rt.march_jax", "_trace_chunk", "march (a chunk)"),
    ("swim.rt.ray_table", "_gather_rows", "table rows and phase functions"),
    ("swim.rt.image_sampling_device", "_first_wanted", "sampler: first lattice"),
    ("swim.rt.image_sampling_device", "_test_level", "sampler: a level's test"),
    ("swim.rt.image_sampling_device", "_wanted_after_split", "sampler: a level's split"),
    ("swim.rt.image_sampling_device", "_scatter", "sampler: a batch's outputs scattered"),
    ("swim.rt.image_sampling_device", "_fill", "sampler: fill"),
    ("swim.rt.image_device", "planes_on_device", "planes (every pixel)"),
    ("swim.rt.image_device", "device_plane", "planes (adaptive)"),
    ("swim.color.srgb_device", "_srgb8_planes", "colour stage"),
)


def wrap_parts(times):
    """Wrap each of :data:`PARTS` in its module so that its calls wait for their results and add their wall time [s]
    to ``times[label]``; returns a function that puts the originals back."""
    import importlib

    import jax

    originals = []

    def restore():
        for module, name, original in originals:
            setattr(module, name, original)

    try:
        for module_name, name, label in PARTS:
            module = importlib.import_module(module_name)
            original = getattr(module, name)

            def waited(*args, _original=original, _label=label, **kwargs):
                t0 = time.perf_counter()
                result = _original(*args, **kwargs)
                jax.block_until_ready(result)
                times[_label].append(time.perf_counter() - t0)
                return result

            setattr(module, name, waited)
            originals.append((module, name, original))
    except BaseException:  # a part not found: the ones wrapped so far put back
        restore()
        raise
    return restore


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="synthetic", choices=("synthetic", "katrina", "rico"))
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--repeats", type=int, default=3, help="waited frames per sampling (after an unwaited warm-up)")
    ap.add_argument("--stand-in", action="store_true",
                    help="the march replaced by bench_host.py's stand-in (for a machine without a GPU)")
    ap.add_argument("--profile", action="store_true",
                    help="one more waited frame of each sampling under a wall-clock profile (wall_profile.py): "
                         "what the rest is")
    ap.add_argument("--data", type=Path, default=bench_suite.DATA)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)

    import jax

    import swim
    import swim.rt.march_jax as march_jax
    import swim.rt.march_settings as march_settings
    from swim.rt.image_sampling import AdaptiveSampling
    from swim.rt.march_settings import MarchSettings

    import bench_host

    scene, kw = bench_host.allsky_case(args.scene, args.size, args.data)
    base = kw.get("settings", MarchSettings())
    settings = base.with_execution(backend="jax", chunk=base.execution.chunk or march_settings.GPU_CHUNK, ray_table=True,
                                   device_sampling=True, device_image=True)
    if args.stand_in:
        march_jax._trace_chunk = bench_host.stand_in_chunk()
        # a known scene's digest taken by identity and checked beside the march, as on a GPU
        # (docs/decisions/0006-gpu-kernels.md); on a CPU the render hashes the scene first, which would count in the
        # rest
        import swim.pipeline as pipeline

        pipeline.scene_stage.speculate_digest = lambda settings: True
    samplings = {"every pixel": None, "adaptive": AdaptiveSampling(**bench_suite.ADAPTIVE)}
    rows = []
    for label, sampling in samplings.items():
        options = {**kw, "settings": settings, "sampling": sampling}
        swim.render(scene, **options)  # compiles (first sampling) and builds the ray table
        frames = []
        for _ in range(max(args.repeats, 1)):  # unwaited warm frames: the reference
            t0 = time.perf_counter()
            image = swim.render(scene, **options)
            frames.append(time.perf_counter() - t0)
        waited, parts = [], []
        for _ in range(max(args.repeats, 1)):
            times = collections.defaultdict(list)
            restore = wrap_parts(times)
            try:
                t0 = time.perf_counter()
                swim.render(scene, **options)
                waited.append(time.perf_counter() - t0)
            finally:
                restore()
            parts.append(times)
        k = sorted(range(len(waited)), key=waited.__getitem__)[len(waited) // 2]  # the median frame's parts
        times = parts[k]
        summed = sum(sum(v) for v in times.values())
        row = {"sampling": label, "traced_pixels": int(image.attrs["traced_pixels"]),
               "frame_s": statistics.median(frames), "frame_runs": frames, "waited_s": waited[k], "waited_runs": waited,
               "parts": {name: {"calls": len(v), "s": sum(v), "max_s": max(v)} for name, v in times.items()},
               "rest_s": waited[k] - summed}
        rows.append(row)
        print(f"\n{args.scene} {args.size}² {label} ({row['traced_pixels']} pixels traced): "
              f"frame {row['frame_s']:.4f} s unwaited, {row['waited_s']:.4f} s with each program waited for",
              flush=True)
        print(f"{'part':40s} {'calls':>5s} {'ms':>9s} {'share':>6s}")
        for name, part in sorted(row["parts"].items(), key=lambda item: -item[1]["s"]):
            print(f"{name:40s} {part['calls']:5d} {1e3 * part['s']:9.2f} {100 * part['s'] / row['waited_s']:5.1f}%")
        print(f"{'the rest (mostly the host)':40s} {'':5s} {1e3 * row['rest_s']:9.2f} "
              f"{100 * row['rest_s'] / row['waited_s']:5.1f}%", flush=True)
        if args.profile:
            from wall_profile import WallSampler

            restore = wrap_parts(collections.defaultdict(list))
            try:
                with WallSampler() as sampler:
                    swim.render(scene, **options)
            finally:
                restore()
            row["profile"] = text = sampler.report()
            print(f"\n### {label}, each program waited for\n{text[:4000]}", flush=True)
    out = args.out or ROOT / "results" / "frame-parts-latest.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    doc = {"scene": args.scene, "size": args.size, "repeats": args.repeats, "stand_in": bool(args.stand_in),
           "chunk": settings.execution.chunk, "machine": bench_suite.machine_info(), "jax_backend": jax.default_backend(),
           "rows": rows}
    out.write_text(json.dumps(doc, indent=1))
    import history

    history.append("frame-parts", history.frame_parts_rows(doc), machine=history.machine_label(doc["machine"]),
                   source="frame_parts.py")
    print(f"written: {out}, {history.HISTORY}")


if __name__ == "__main__":
    main()
