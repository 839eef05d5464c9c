"""The host's work in a JAX-kernel frame, measured without a GPU: the march replaced by a stand-in of negligible cost.

Usage::

    python benchmarks/bench_host.py                              # synthetic 1024² all-sky, every pixel and adaptive
    python benchmarks/bench_host.py --size 512 --repeats 7 --profile

On a GPU, a warm frame of the JAX kernel is mostly host work (docs/decisions/0006-gpu-kernels.md): the rays'
segments, the phase functions, the chunks' inputs and outputs, adaptive sampling between its batches, the image's
planes and the colour stage, while the device's march of a 1024² all-sky takes tens of milliseconds. On a CPU that host
work hides behind the JAX kernel's march (seconds). This script measures it on any machine: it replaces the compiled
chunk (:func:`swim.rt.march_jax._trace_chunk`) by a stand-in that returns outputs of the right shapes, with some structure
so that adaptive sampling refines (a smooth sky with sharp-edged "clouds" by direction), at a cost of a few
milliseconds per chunk, and times warm renders of the suite's all-sky view with the JAX kernel in the GPU's chunks
(``GPU_CHUNK`` rays; ``--chunk`` to change), taking turns between
``ExecutionSettings.ray_table`` off and on (the camera's rays kept on the device, docs/decisions/0006-gpu-kernels.md). What
it reports is the frame without its march: the host's share that a GPU frame pays, on this machine's cores (a GPU
machine's host has more and faster ones). ``--profile`` adds a wall-clock profile of one frame of each variant
(:mod:`wall_profile`).

A GPU frame also finishes its image on the device (``ExecutionSettings.device_image``: the planes and the
colour stage there) and takes a known scene's digest by identity (docs/decisions/0006-gpu-kernels.md); on a CPU both are
off by default, so the "with the table" variant measures the host's planes and colour stage. ``--device-image`` turns
both on in that variant, as on a GPU: the device's part (the stand-in, the scatters, the colour stage) then runs on
this machine's cores too and counts in the figure, which is then an upper bound of the host's share.

The images are not physical: only the times mean something. Results go to ``benchmarks/results/host-latest.json``
(``--out`` to change) and the times with and without to ``benchmarks/results/history.csv``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent
sys.path.insert(0, str(ROOT))

import bench_suite  # noqa: E402  (the suite's scenes, views and render options)


def stand_in_chunk():
    """A compiled stand-in for ``_trace_chunk``: the same arguments and output keys, values from the directions."""
    import jax
    import jax.numpy as jnp

    @jax.jit
    def chunk(start, direction, bounds, ends_on_ground, valid, rays, consts):
        d = direction
        # a bluish sky and white clouds: spectra that the colour stage takes on its fast path, as a real sky's
        # (independent channels would send many pixels through its slow path for spectra out of gamut)
        sky = (0.4 + 0.2 * jnp.sin(3.0 * d[:, 2:3]) + 0.1 * rays["p_rayleigh"][:, None]) * jnp.array([0.7, 0.85, 1.0])
        cloud = jnp.where((jnp.sin(40.0 * d[:, 0]) * jnp.sin(40.0 * d[:, 1]) > 0.3)[:, None], 0.5, 0.0) * jnp.ones(3)
        radiance = jnp.where(valid[:, None], sky + cloud, 0.0)
        tau = 20.0 * (cloud[:, 0] > 0)
        zeros = jnp.zeros_like(radiance)
        surface = ends_on_ground & (d[:, 2] < 0)
        return {"radiance": radiance, "radiance_clear": sky, "radiance_cloud": cloud, "radiance_surface": zeros,
                "tau_hydrometeor": tau, "tau_clear": 0.1 + zeros, "surface": surface,
                "distance": jnp.where(surface, bounds[:, 2], jnp.nan)}

    def trace_chunk(start, direction, bounds, ends_on_ground, valid, rays, consts, settings, probes=None):
        return chunk(start, direction, bounds, ends_on_ground, valid, rays, consts)

    return trace_chunk


def allsky_case(scene_name, size, data):
    """The suite's all-sky view of ``scene_name`` ("synthetic", "katrina", "rico") at ``size``² pixels: the scene and
    the render's keyword arguments (:mod:`bench_suite`)."""
    spec = json.loads(json.dumps(bench_suite.CASES[f"{scene_name}_allsky"]))
    spec.update(data=str(data), image=[size, size])
    if scene_name == "synthetic":
        spec["scene_kwargs"] = dict(bench_suite.SYNTHETIC_GRID)
    return bench_suite.load_scene(spec), bench_suite.render_kwargs(spec)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="synthetic", choices=("synthetic", "katrina", "rico"))
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--chunk", type=int, default=None,
                    help="rays per chunk (default: swim.rt.march_settings.GPU_CHUNK, the GPU's: a CPU's 4096 would make the "
                         "per-chunk work of ~200 chunks weigh as it never does on a GPU)")
    ap.add_argument("--profile", action="store_true", help="a wall-clock profile of one frame of each variant")
    ap.add_argument("--device-image", action="store_true",
                    help="with the table, also the image finished on the device and the digest by identity, as on a "
                         "GPU (see the docstring)")
    ap.add_argument("--data", type=Path, default=bench_suite.DATA)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)

    import jax

    import swim
    import swim.rt.march_jax as march_jax
    import swim.rt.march_settings as march_settings
    from swim.rt.image_sampling import AdaptiveSampling
    from swim.rt.march_settings import ExecutionSettings, MarchSettings

    scene, kw = allsky_case(args.scene, args.size, args.data)
    base = kw.get("settings", MarchSettings()).with_execution(backend="jax")
    base = base.with_execution(chunk=args.chunk or march_settings.GPU_CHUNK)
    march_jax._trace_chunk = stand_in_chunk()
    # as on a GPU (docs/decisions/0006-gpu-kernels.md): the digest by identity in every variant, the image with the
    # table
    if args.device_image:
        import swim.pipeline as pipeline

        pipeline.scene_stage.speculate_digest = lambda settings: True
        base = base.with_execution(device_image=True)  # (resolved off without the table)
    samplings = {"every pixel": None, "adaptive": AdaptiveSampling(**bench_suite.ADAPTIVE)}
    rows = []
    for label, sampling in samplings.items():
        runs = {False: [], True: []}
        traced = {}
        for k in range(1 + args.repeats):  # the first round compiles (and builds the table): not counted
            for kept in (False, True):
                t0 = time.perf_counter()
                image = swim.render(scene, **{**kw, "settings": base.with_execution(ray_table=kept),
                                    "sampling": sampling})
                if k:
                    runs[kept].append(time.perf_counter() - t0)
                traced[kept] = int(image.attrs["traced_pixels"])
        row = {"sampling": label, "without_s": statistics.median(runs[False]), "with_s": statistics.median(runs[True]),
               "without_runs": runs[False], "with_runs": runs[True], "traced_pixels": traced[False]}
        if traced[False] != traced[True]:
            row["traced_pixels_with_table"] = traced[True]
        rows.append(row)
        print(f"{args.scene} {args.size}² {label}: host work without the table {row['without_s']:.3f} s, with it "
              f"{row['with_s']:.3f} s ({traced[False]} pixels traced)", flush=True)
        if args.profile:
            from wall_profile import WallSampler

            for kept in (False, True):
                with WallSampler() as sampler:
                    swim.render(scene, **{**kw, "settings": base.with_execution(ray_table=kept), "sampling": sampling})
                text = sampler.report()
                row[f"profile_{'with' if kept else 'without'}"] = text
                print(f"\n### {label}, ray table {'on' if kept else 'off'}\n{text[:3000]}", flush=True)
    out = args.out or ROOT / "results" / "host-latest.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    doc = {"scene": args.scene, "size": args.size, "repeats": args.repeats, "chunk": base.execution.chunk,
           "device_image": bool(args.device_image), "machine": bench_suite.machine_info(),
           "jax_backend": jax.default_backend(), "rows": rows}
    out.write_text(json.dumps(doc, indent=1))
    import history

    history.append("host", history.host_rows(doc), machine=history.machine_label(doc["machine"]),
                   source="bench_host.py")
    print(f"written: {out}, {history.HISTORY}")


if __name__ == "__main__":
    main()
