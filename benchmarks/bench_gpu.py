"""Frames per second of the march's GPU kernels (the goal: 60 frames/s at 1024²) and where a GPU render spends its time.

Usage (on a machine where JAX's default device is a GPU; it also runs on a CPU, slowly)::

    python benchmarks/bench_gpu.py --scenes synthetic katrina --chunks 32768 0 --sun-series 6 --out gpu.json

For each scene and kernel chunk size (``ExecutionSettings.chunk``: rays per kernel call) it renders the suite's
1024 x 1024 all-sky view (``bench_suite.CASES``) with the JAX kernel and reports:

* ``render_s``: wall time of a warm render (median of ``--repeats``), and its frames/s;
* ``trace_s``: of that, the time in :func:`swim.rt.march.trace_rays` (ray segments, phase functions, the
  device's march of every chunk, the copies back);
* ``kernel_s``: the device time of one chunk's march and composition (``_trace_chunk`` on the captured
  inputs of a full chunk, ``block_until_ready``, median of 5), and the frames/s that the kernel alone would
  allow at 1024 x 1024 (the rays of the render / rays per second of the kernel);
* with ``--sun-series N``: the time per frame of N renders with a new sun each (a fixed camera's time series:
  Step 1a and the kernel constants are redone every frame);
* with ``--sampling``: an adaptively sampled render (the suite's ``ADAPTIVE`` settings), its time, the pixels it
  traced and its radiance's error against the same device's image with every pixel traced (median and 99th
  percentile of the relative difference); with ``--profile`` too, the main thread's wall clock in a warm adaptive
  frame (``profile_<scene>_adaptive_wall.txt``);
* with ``--grid-kernel``: the march of the grid segment (``ExecutionSettings.grid_kernel``: ``fused``, the Pallas kernel of
  :mod:`swim.rt.march_pallas`; ``fused-march``, the clear-air segments in it too; ``lockstep``, XLA's loops; ``auto`` by
  default); with ``--against lockstep fused-march`` the captured chunk is also marched by those (device time and outputs
  against the render's kernel), and ``--fused-blocks 64x2 256x4 128x4r128`` times the render's fused kernel on it with
  other rays per program and warps, and capped at N registers per thread (``rN``, :mod:`swim.rt.ptx_edits`);
* with ``--ray-table``: warm renders with the camera's rays kept on the device (``ExecutionSettings.ray_table``,
  :mod:`swim.rt.ray_table`) and without, taking turns: every pixel, adaptive (with ``--sampling``) and a new sun
  every frame (with ``--sun-series N``), each one's median and the largest radiance difference between the two;
* with ``--step1a-on-device``: frames with a new sun each, a new sun's Step 1a on the device's copy of the packed
  volume (``ExecutionSettings.step1a_on_device``, :mod:`swim.rt.solar_device`) against the host's, taking turns;
* with ``--device-sampling``: adaptive frames with the sampler's image on the device (``ExecutionSettings.device_sampling``,
  :mod:`swim.rt.image_sampling_device`) against the host's sampler, taking turns, both with the camera's rays on the
  device (the ray table);
* with ``--device-image``: frames with the image's planes and colour made on the device (``ExecutionSettings.device_image``,
  :mod:`swim.rt.image_device`, :mod:`swim.color.srgb_device`) against the host's, taking turns, every pixel and
  adaptive (the sampler on the device), both with the ray table; with ``--out`` also the main thread's wall clock
  in a warm frame of each with it on and of an every-pixel frame with a new sun
  (``profile_<scene>_device_image_<sampling>_wall.txt``); and every-pixel frames
  with the scene's digest taken by its arrays' identity (checked while the device marches) against hashed first;
* with ``--barriers``: the kernel with the optimisation barriers it uses on CPUs forced on (``_materialise``);
* with ``--profile`` (and ``--out``): a host profile of a warm render and of one with a new sun (cProfile) and the
  device's kernels of one chunk (JAX's profiler, time summed per kernel name), as text files beside the JSON;
* the GPU's peak memory (``memory_stats``) and, with ``--compare``, the radiance against a render with the
  numba kernel on the host's cores (median and 99th percentile of the relative difference).

Figures print as a table at the end and go to ``--out`` as JSON (with the images as PNG beside it), the headline
figures of each row to ``benchmarks/results/history.csv``; ``--size`` renders smaller images for a quick check.
The H100's and H200's figures are in docs/decisions/0006-gpu-kernels.md.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import sys
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parent
sys.path.insert(0, str(ROOT))

import bench_suite  # noqa: E402  (the suite's scenes, views and render options)


def _median_time(fn, repeats):
    runs = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        runs.append(time.perf_counter() - t0)
    return statistics.median(runs), runs


class TraceProbe:
    """Wraps ``trace_rays`` (time per render) and ``_trace_chunk`` (keeps the inputs of one full chunk)."""

    def __init__(self):
        import swim.pipeline as pipeline
        import swim.rt.backends.host
        import swim.rt.march_jax as march_jax

        self.pipeline, self.march = pipeline, march_jax
        self.trace_rays, self.trace_chunk = swim.rt.backends.host.trace_rays, march_jax._trace_chunk
        self.trace_s, self.captured = 0.0, None
        swim.rt.backends.host.trace_rays, march_jax._trace_chunk = self._trace_rays, self._trace_chunk

    def _trace_rays(self, *args, **kwargs):
        t0 = time.perf_counter()
        try:
            return self.trace_rays(*args, **kwargs)
        finally:
            self.trace_s += time.perf_counter() - t0

    def _trace_chunk(self, *args, **kwargs):
        if self.captured is None or args[0].shape[0] > self.captured[0][0].shape[0]:
            self.captured = (args, kwargs)
        return self.trace_chunk(*args, **kwargs)

    def kernel_time(self, repeats=5):
        """(seconds, rays) of the device's work on the captured chunk."""
        import jax

        args, kwargs = self.captured
        call = lambda: jax.block_until_ready(self.trace_chunk(*args, **kwargs))  # noqa: E731
        call()
        return _median_time(call, repeats)[0], int(args[0].shape[0])


def compare_ray_table(name, scene, kw, args):
    """Warm renders with and without ``ExecutionSettings.ray_table``, taking turns (``args.repeats`` each): every pixel,
    adaptive with ``args.sampling``, and a new sun every frame with ``args.sun_series``; each variant's median and
    runs, and the largest relative radiance difference between the two images (docs/decisions/0006-gpu-kernels.md)."""
    variants = [("every pixel", {})]
    if args.sampling:
        from swim.rt.image_sampling import AdaptiveSampling

        variants.append(("adaptive", {"sampling": AdaptiveSampling(**bench_suite.ADAPTIVE)}))
    if args.sun_series:
        variants.append(("new sun", {"new_sun": True}))
    return compare_setting(name, scene, kw, args, "ray_table", variants)


def compare_setting(name, scene, kw, args, field, variants):
    """Warm renders with the boolean ``MarchSettings`` field ``field`` off and on, taking turns (``args.repeats``
    each, after a first round that compiles), for each of ``variants`` ((label, render keywords); ``new_sun``: a sun
    of its own for every render); each variant's median and runs, and the largest relative radiance difference
    between the two images (with a new sun, the last "with" frame's sun rendered again without)."""
    import numpy as np

    import swim

    rows = []
    for label, extra in variants:
        new_sun = extra.pop("new_sun", False)
        runs, images, suns = {False: [], True: []}, {}, {}
        for k in range(1 + args.repeats):  # the first round compiles the table's programs: not counted
            for kept in (False, True):
                # a sun of its own for each render (the other variant's would be reused)
                step = 2 * k + kept
                sun = {"sun_zenith": 30.0 + 0.5 * step, "sun_azimuth": 135.0 + step} if new_sun else {}
                settings = replace(kw["settings"], **{field: kept})
                t0 = time.perf_counter()
                image = swim.render(scene, **{**kw, **extra, **sun, "settings": settings})
                if k:
                    runs[kept].append(time.perf_counter() - t0)
                images[kept], suns[kept] = image, sun
        row = {"scene": name, field: label, "without_s": statistics.median(runs[False]),
               "with_s": statistics.median(runs[True]), "without_runs": runs[False], "with_runs": runs[True],
               "traced_pixels": [int(images[x].attrs["traced_pixels"]) for x in (False, True)]}
        if new_sun:
            # the last "with" frame's sun again without, after another sun (so that its constants are made anew)
            off = replace(kw["settings"], **{field: False})
            swim.render(scene, **{**kw, **extra, "sun_zenith": 20.0, "sun_azimuth": 100.0, "settings": off})
            images[False] = swim.render(scene, **{**kw, **extra, **suns[True], "settings": off})
        a, b = images[False]["radiance"].values, images[True]["radiance"].values
        ok = np.isfinite(a) & np.isfinite(b)
        rel = np.abs(a[ok] - b[ok]) / np.maximum(np.abs(a[ok]), 1e-3)
        row.update(max_rel_diff=float(rel.max()), p99_rel_diff=float(np.percentile(rel, 99)),
                   values_over_1e_4=int(np.sum(rel > 1e-4)))
        codes = np.abs(images[False]["rgb"].values.astype(int) - images[True]["rgb"].values.astype(int))
        row.update(rgb_max_code_diff=int(codes.max()), rgb_pixels_apart=int(np.count_nonzero(codes.max(axis=-1))))
        # where the largest difference lies (docs/decisions/0006-gpu-kernels.md: 3.6e-3 of one pixel with Step 1a on the
        # device, not located)
        full = np.where(ok, np.abs(a - b) / np.maximum(np.abs(a), 1e-3), 0.0)
        at = np.unravel_index(int(np.argmax(full)), full.shape)
        worst = {"index": dict(zip(images[False]["radiance"].dims, (int(i) for i in at))),
                 "without": float(a[at]), "with": float(b[at])}
        pixel = {d: i for d, i in worst["index"].items() if d in images[False]["tau_hydrometeor"].dims}
        for key in ("tau_hydrometeor", "view_zenith", "view_azimuth"):
            if key in images[False]:
                worst[key] = [float(images[x][key].isel(pixel).values) for x in (False, True)]
        row["largest_difference"] = worst
        apart = (f"; radiance apart by p99 {row['p99_rel_diff']:.1e}, max {row['max_rel_diff']:.1e} at {worst}, "
                 f"{row['values_over_1e_4']} values over 1e-4; rgb {row['rgb_pixels_apart']} pixels apart, by at "
                 f"most {row['rgb_max_code_diff']}")
        rows.append(row)
        print(f"{name} {field}, {label}: without {row['without_s']:.3f} s, with {row['with_s']:.3f} s "
              f"({row['without_s'] / row['with_s']:.2f}x){apart}", flush=True)
    return rows


def compare_digest_by_identity(name, scene, kw, args):
    """Warm every-pixel frames with the scene's digest taken by its arrays' identity and checked while the device
    marches (``swim.pipeline.caches.fingerprint_by_identity``,
             on by default on GPUs) against hashing it before the march,
    taking turns (``args.repeats`` each, after a first round)."""
    import swim
    import swim.pipeline as pipeline

    default = pipeline.scene_stage.speculate_digest
    runs = {False: [], True: []}
    try:
        for k in range(1 + args.repeats):
            for on in (False, True):
                pipeline.scene_stage.speculate_digest = default if on else (lambda settings: False)
                t0 = time.perf_counter()
                swim.render(scene, **kw)
                if k:
                    runs[on].append(time.perf_counter() - t0)
    finally:
        pipeline.scene_stage.speculate_digest = default
    row = {"scene": name, "digest_by_identity": "every pixel", "without_s": statistics.median(runs[False]),
           "with_s": statistics.median(runs[True]), "without_runs": runs[False], "with_runs": runs[True]}
    print(f"{name} digest by identity, every pixel: without {row['without_s']:.3f} s, with {row['with_s']:.3f} s "
          f"({row['without_s'] / row['with_s']:.2f}x)", flush=True)
    return row


def gpu_memory():
    import jax

    stats = jax.devices()[0].memory_stats() or {}
    return {key: stats[key] / 2**20 for key in ("peak_bytes_in_use", "bytes_in_use", "bytes_limit") if key in stats}


def run_scene(name, args, probe, out_dir):
    import numpy as np

    import swim
    from swim.rt.march_settings import ExecutionSettings, MarchSettings

    spec = json.loads(json.dumps(bench_suite.CASES[f"{name}_allsky"]))
    spec.update(data=str(args.data), backend="jax")
    if args.size:
        spec["image"] = [args.size, args.size]
    if name == "synthetic":
        spec["scene_kwargs"] = dict(bench_suite.SYNTHETIC_GRID)
    t0 = time.perf_counter()
    scene = bench_suite.load_scene(spec)
    scene_s = time.perf_counter() - t0
    kw = bench_suite.render_kwargs(spec)
    rows = []
    first = None
    for chunk in args.chunks:
        # 0: the default (MarchSettings.resolved_chunk: GPU_CHUNK on a GPU)
        kw["settings"] = MarchSettings(execution=ExecutionSettings(
            backend="jax", grid_kernel=args.grid_kernel, fused_vector_loads=not args.scalar_loads, chunk=chunk or None))
        chunk = kw["settings"].resolved_chunk()
        t0 = time.perf_counter()
        image = swim.render(scene, **kw)  # cold for this chunk size: compiles its kernel shapes
        cold = time.perf_counter() - t0
        probe.trace_s = 0.0
        probe.captured = None
        warm, runs = _median_time(lambda: swim.render(scene, **kw), args.repeats)
        trace_s = probe.trace_s / args.repeats  # the time in trace_rays
        kernel_s, kernel_rays = probe.kernel_time()
        rays = int(image.attrs["traced_pixels"]) + 1
        kernel_rays_per_s = kernel_rays / kernel_s
        row = {"scene": name, "backend": "jax", "grid_kernel": kw["settings"].resolved_grid_kernel(), "chunk": chunk,
               "rays": rays, "cold_s": cold, "render_s": warm, "render_runs": runs,
               "render_fps": 1 / warm, "trace_s": trace_s, "kernel_chunk_s": kernel_s, "kernel_chunk_rays": kernel_rays,
               "kernel_rays_per_s": kernel_rays_per_s, "kernel_fps": kernel_rays_per_s / rays,
               "march_samples": float(image.attrs.get("march_samples", float("nan"))), "gpu_memory_mb": gpu_memory()}
        rows.append(row)
        print(f"{name} chunk {chunk}: cold {cold:.2f} s, warm {warm:.3f} s ({1 / warm:.2f} frames/s), trace "
              f"{trace_s:.3f} s, kernel {kernel_s * 1e3:.2f} ms per {kernel_rays} rays -> {row['kernel_fps']:.1f} "
              f"frames/s of the kernel alone", flush=True)
        first = first or image
        if args.out:
            from PIL import Image

            Image.fromarray(image["rgb"].values).save(Path(args.out).parent / f"gpu_{name}_allsky_{chunk}.png")
    for kernel in args.against:
        rows.append(compare_kernels(name, probe, kernel))
    if args.ray_table:
        rows.extend(compare_ray_table(name, scene, kw, args))
    if args.step1a_on_device:  # a new sun every frame: Step 1a on the device or the host
        rows.extend(compare_setting(name, scene, kw, args, "step1a_on_device", [("new sun", {"new_sun": True})]))
    if args.device_sampling:  # adaptive frames: the sampler on the device or the host
        from swim.rt.image_sampling import AdaptiveSampling

        table_kw = {**kw, "settings": kw["settings"].with_execution(ray_table=True)}
        rows.extend(compare_setting(name, scene, table_kw, args, "device_sampling",
                                    [("adaptive", {"sampling": AdaptiveSampling(**bench_suite.ADAPTIVE)})]))
    if args.device_image:  # the image's planes and colour on the device or the host
        from swim.rt.image_sampling import AdaptiveSampling

        table_kw = {**kw, "settings": kw["settings"].with_execution(ray_table=True)}
        variants = [("every pixel", {}), ("adaptive", {"sampling": AdaptiveSampling(**bench_suite.ADAPTIVE)})]
        rows.extend(compare_setting(name, scene, table_kw, args, "device_image", [(a, dict(b)) for a, b in variants]))
        rows.append(compare_digest_by_identity(name, scene, table_kw, args))
        if out_dir:
            on = {**table_kw, "settings": table_kw["settings"].with_execution(device_image=True)}
            # with a new sun too (Step 1a on the device, the step classes and the constants: a time series' frame)
            for label, extra in variants + [("new sun", {"sun_zenith": 43.0, "sun_azimuth": 190.0})]:
                wall_profile_render(name, f"device_image_{label.replace(' ', '_')}_wall", scene, {**on, **extra},
                                    Path(out_dir))
    if args.barriers:
        rows.append(compare_barriers(name, scene, kw, probe, args.repeats))
    if args.profile and out_dir:
        profile_render(name, scene, kw, probe, Path(out_dir))
    if args.sampling:
        from swim.rt.image_sampling import AdaptiveSampling

        kw_a = {**kw, "sampling": AdaptiveSampling(**bench_suite.ADAPTIVE)}
        adaptive = swim.render(scene, **kw_a)
        warm, runs = _median_time(lambda: swim.render(scene, **kw_a), args.repeats)
        # its error against the same device's image with every pixel traced (what the interpolation costs there)
        a, b = adaptive["radiance"].values, first["radiance"].values
        ok = np.isfinite(a) & np.isfinite(b)
        rel = np.abs(a[ok] - b[ok]) / np.maximum(np.abs(b[ok]), 1e-3)
        rows.append({"scene": name, "chunk": kw["settings"].resolved_chunk(), "sampling": bench_suite.ADAPTIVE,
                     "render_s": warm, "render_runs": runs, "render_fps": 1 / warm,
                     "traced_pixels": int(adaptive.attrs["traced_pixels"]),
                     "vs_every_pixel_median": float(np.median(rel)),
                     "vs_every_pixel_p99": float(np.percentile(rel, 99))})
        print(f"{name} adaptive, chunk {kw['settings'].resolved_chunk()}: warm {warm:.3f} s ({1 / warm:.2f} frames/s), "
              f"{int(adaptive.attrs['traced_pixels'])} pixels traced, against every pixel: median "
              f"{rows[-1]['vs_every_pixel_median']:.2e}, p99 {rows[-1]['vs_every_pixel_p99']:.2e}", flush=True)
        if args.profile and out_dir:  # the main thread's wall clock in a warm adaptive frame
            wall_profile_render(name, "adaptive_wall", scene, kw_a, Path(out_dir))
    if args.sun_series:
        # a time series seen by a fixed camera: every frame has a new sun (Step 1a and the kernel constants anew)
        runs = []
        for k in range(args.sun_series):
            t0 = time.perf_counter()
            swim.render(scene, **{**kw, "sun_zenith": 30.0 + 0.5 * k, "sun_azimuth": 135.0 + k})
            runs.append(time.perf_counter() - t0)
        warm = statistics.median(runs[1:]) if len(runs) > 1 else runs[0]
        rows.append({"scene": name, "chunk": kw["settings"].resolved_chunk(), "sun_series": args.sun_series,
                     "frame_s": warm, "frame_runs": runs, "frames_per_s": 1 / warm})
        print(f"{name} time series (a new sun every frame): {warm:.3f} s per frame ({1 / warm:.2f} frames/s)",
              flush=True)
    if args.compare:
        try:
            rows.append(compare_numba(name, scene, kw, first))
        except Exception as exc:  # a host without a working numba must not lose the GPU figures
            rows.append({"scene": name, "compare": "numba", "error": repr(exc)})
            print(f"{name}: no comparison with numba: {exc!r}", flush=True)
    if args.fused_blocks:  # last: it clears JAX's caches, so a later render would reload
        rows.extend(sweep_fused_blocks(name, probe, args.fused_blocks))
    if out_dir:
        from PIL import Image

        Image.fromarray(first["rgb"].values).save(Path(out_dir) / f"gpu_{name}_allsky.png")
    return {"scene_s": scene_s, "rows": rows}


def wall_profile_render(name, label, scene, kw, out_dir):
    """The main thread's wall clock in one render (``wall_profile.WallSampler``), to ``profile_<name>_<label>.txt``."""
    import swim

    from wall_profile import WallSampler

    with WallSampler() as sampler:
        swim.render(scene, **kw)
    (out_dir / f"profile_{name}_{label}.txt").write_text(sampler.report())
    print(f"{name} {label}: " + "\n".join(sampler.report(12).splitlines()[:30]), flush=True)


def profile_render(name, scene, kw, probe, out_dir):
    """Where a warm render spends its time: the main thread's wall clock (``wall_profile.WallSampler``, to
    ``profile_<scene>_wall.txt`` and, with a new sun, ``profile_<scene>_newsun_wall.txt``), the host's Python
    functions (cProfile, top 40 by cumulative and by own time, to ``profile_<scene>_host.txt``; a render with a new
    sun to ``profile_<scene>_newsun_host.txt``) and the device's kernels for one captured chunk (JAX's profiler, time
    summed per kernel name, to ``profile_<scene>_device.txt``)."""
    import cProfile
    import glob
    import gzip
    import io
    import pstats
    import tempfile

    import jax

    import swim

    # wall-clock samples of the main thread first (no cProfile overhead): a warm render, then one with a new sun
    for label, extra in (("wall", {}), ("newsun_wall", {"sun_zenith": 43.0, "sun_azimuth": 190.0})):
        wall_profile_render(name, label, scene, {**kw, **extra}, out_dir)
    # a warm render, and one with a new sun (Step 1a and the kernel constants anew: a time series' frame)
    for label, extra in (("host", {}), ("newsun_host", {"sun_zenith": 41.0, "sun_azimuth": 200.0})):
        prof = cProfile.Profile()
        prof.enable()
        swim.render(scene, **{**kw, **extra})
        prof.disable()
        text = io.StringIO()
        for key in ("cumulative", "tottime"):
            pstats.Stats(prof, stream=text).sort_stats(key).print_stats(40)
        (out_dir / f"profile_{name}_{label}.txt").write_text(text.getvalue())
    with tempfile.TemporaryDirectory() as tmp:
        with jax.profiler.trace(tmp, create_perfetto_trace=True):
            seconds, rays = probe.kernel_time(repeats=1)
        files = glob.glob(f"{tmp}/**/*.json.gz", recursive=True)
        totals = {}
        for f in files:
            with gzip.open(f) as fh:
                events = json.load(fh)
            events = events.get("traceEvents", events) if isinstance(events, dict) else events
            for e in events:
                if e.get("ph") == "X" and "dur" in e:
                    t = totals.setdefault((e.get("pid"), e["name"]), [0.0, 0])
                    t[0] += e["dur"] * 1e-3
                    t[1] += 1
    lines = [f"{name}: one chunk of {rays} rays, {seconds * 1e3:.2f} ms under the profiler; {len(files)} trace files",
             "pid | name | total [ms] | calls"]
    lines += [f"{pid} | {n[:150]} | {t:.3f} | {c}" for (pid, n), (t, c) in
              sorted(totals.items(), key=lambda kv: -kv[1][0])[:60]]
    (out_dir / f"profile_{name}_device.txt").write_text("\n".join(lines))
    print("\n".join(lines[:25]), flush=True)


def compare_barriers(name, scene, kw, probe, repeats):
    """The kernel with the optimisation barriers that it uses on CPUs (``swim.rt.march_jax._materialise``) forced on,
    against the default of the device: warm render, device time per chunk, largest difference of the outputs."""
    import jax
    import numpy as np

    import swim
    import swim.rt.march_jax as march_jax

    def measure():
        swim.render(scene, **kw)  # compiles
        probe.captured = None
        warm, _ = _median_time(lambda: swim.render(scene, **kw), repeats)
        args, kwargs = probe.captured
        out = jax.block_until_ready(probe.trace_chunk(*args, **kwargs))
        return warm, probe.kernel_time()[0], {key: np.asarray(value) for key, value in out.items()}

    default = measure()
    plain = march_jax._materialise
    march_jax._materialise = jax.lax.optimization_barrier
    jax.clear_caches()
    try:
        forced = measure()
    finally:
        march_jax._materialise = plain
        jax.clear_caches()
    diff = max(float(np.nanmax(np.abs(forced[2][key].astype(float) - default[2][key].astype(float)), initial=0.0))
               for key in default[2])
    row = {"scene": name, "compare": "optimisation barriers", "default_render_s": default[0],
           "default_kernel_chunk_s": default[1], "barriers_render_s": forced[0], "barriers_kernel_chunk_s": forced[1],
           "max_abs_difference": diff}
    print(f"{name}: kernel per chunk {default[1] * 1e3:.2f} ms (default) against {forced[1] * 1e3:.2f} ms with the "
          f"barriers forced; warm render {default[0]:.3f} against {forced[0]:.3f} s; outputs within {diff:.2e}",
          flush=True)
    return row


def _chunk_outputs(probe, settings):
    """(device time of one call, outputs as numpy arrays) of the captured chunk with other ``settings``."""
    import jax
    import numpy as np

    args, kwargs = probe.captured
    kwargs = {**kwargs}
    if "settings" in kwargs:
        kwargs["settings"] = settings
    else:  # positional: start, direction, bounds, ends_on_ground, valid, rays, consts, settings[, probes]
        args = list(args)
        args[7] = settings
    call = lambda: jax.block_until_ready(probe.trace_chunk(*args, **kwargs))  # noqa: E731
    t0 = time.perf_counter()
    out = call()
    first = time.perf_counter() - t0
    seconds, _ = _median_time(call, 5)
    return seconds, first, {key: np.asarray(value) for key, value in out.items()}


def _captured_settings(probe):
    args, kwargs = probe.captured
    return kwargs["settings"] if "settings" in kwargs else args[7]


def compare_kernels(name, probe, kernel):
    """The captured chunk marched with ``kernel`` (``ExecutionSettings.grid_kernel``): its device time and outputs against
    the render's."""
    import numpy as np

    settings = _captured_settings(probe)
    base_s, _, base = _chunk_outputs(probe, settings)
    other_s, compile_s, other = _chunk_outputs(probe, settings.with_execution(grid_kernel=kernel))
    valid = np.asarray(probe.captured[0][4]).astype(bool)
    a, b = base["radiance"][valid].astype(float), other["radiance"][valid].astype(float)
    ok = np.isfinite(a) & np.isfinite(b)
    rel = np.abs(a[ok] - b[ok]) / np.maximum(np.abs(b[ok]), 1e-3)
    row = {"scene": name, "compare": kernel, "grid_kernel": settings.resolved_grid_kernel(),
           "grid_kernel_chunk_s": base_s, "other_kernel_chunk_s": other_s, "other_first_call_s": compile_s,
           "speed_up": other_s / base_s, "radiance_median": float(np.median(rel)),
           "radiance_p99": float(np.percentile(rel, 99)), "radiance_max": float(rel.max()),
           "rays_off_by_1pct": int(np.sum(rel.reshape(-1, 3).max(axis=1) > 0.01) if rel.size % 3 == 0 else -1),
           "nonfinite": int(np.sum(~ok)), "tau_h_max_diff": float(np.nanmax(np.abs(
               base["tau_hydrometeor"][valid].astype(float) - other["tau_hydrometeor"][valid].astype(float))))}
    print(f"{name}: chunk of {valid.size} rays: {settings.resolved_grid_kernel()} {base_s * 1e3:.2f} ms, {kernel} "
          f"{other_s * 1e3:.2f} ms (first call {compile_s:.1f} s): x{row['speed_up']:.2f}; radiance against {kernel} "
          f"median {row['radiance_median']:.2e}, p99 {row['radiance_p99']:.2e}, max {row['radiance_max']:.2e}, "
          f"{row['rays_off_by_1pct']} rays > 1 %", flush=True)
    return row


def sweep_fused_blocks(name, probe, blocks):
    """The fused grid kernel on the captured chunk with other rays per Triton program and warps ("RAYSxWARPS"), capped
    at N registers per thread ("RAYSxWARPSrN": ``ExecutionSettings.fused_max_registers``), with a scalar gather per table
    channel ("s": ``ExecutionSettings.fused_vector_loads`` off), with fused multiply-adds ("f":
    ``ExecutionSettings.fused_fma``), and with an "m" last, the "fused-march" kernel
    (docs/decisions/0006-gpu-kernels.md)."""
    import jax

    from swim.rt import march_pallas
    from swim.rt.ptx_edits import capped_entries, caps_applied, contracted_entries, contractions_applied, kernel_name

    import numpy as np

    captured = _captured_settings(probe)
    base_s, _, base = _chunk_outputs(probe, captured)
    valid = np.asarray(probe.captured[0][4]).astype(bool)
    rows = []
    saved = march_pallas.BLOCK_RAYS, march_pallas.NUM_WARPS
    # the module's constants are read when the kernel is traced: no programs from the export cache, whose key is the
    # code
    export = os.environ.get("SWIM_JAX_EXPORT")
    os.environ["SWIM_JAX_EXPORT"] = "0"
    try:
        for text in blocks:
            # "RAYSxWARPS" marches the grid segment in the kernel ("fused"); "RAYSxWARPSm" the clear air too
            # ("fused-march")
            spec = re.fullmatch(r"(\d+)x(\d+)(?:r(\d+))?(s?)(f?)(m?)", text)
            if spec is None:
                raise SystemExit(f"--fused-blocks: {text!r} is not RAYSxWARPS[rN][s][f][m]")
            kernel = "fused-march" if spec.group(6) else "fused"
            rays, warps = int(spec.group(1)), int(spec.group(2))
            cap = int(spec.group(3)) if spec.group(3) else None
            vector, fma = not spec.group(4), bool(spec.group(5))
            settings = captured.with_execution(grid_kernel=kernel, fused_max_registers=cap, fused_vector_loads=vector,
                                               fused_fma=fma)
            entry = kernel_name("swim_fused_march", cap, fma)
            march_pallas.BLOCK_RAYS, march_pallas.NUM_WARPS = rays, warps
            jax.clear_caches()
            probe.trace_chunk.forget_programs()
            caps_before, contractions_before = caps_applied(), contractions_applied()
            try:
                seconds, first, out = _chunk_outputs(probe, settings)
            except Exception as exc:  # noqa: BLE001 - one configuration's failure must not lose the others
                rows.append({"scene": name, "fused_block": text, "error": repr(exc)[:500]})
                print(f"{name}: fused {text}: {exc!r}"[:400], flush=True)
                continue
            a, b = out["radiance"][valid].astype(float), base["radiance"][valid].astype(float)
            ok = np.isfinite(a) & np.isfinite(b)
            rel = np.abs(a[ok] - b[ok]) / np.maximum(np.abs(b[ok]), 1e-3)
            worst = float(rel.max()) if rel.size else float("nan")
            # a rounding difference moves every value a little; a decision flipped at a threshold (a terrain
            # crossing, a refinement) moves a rare ray more: the median, the 99th percentile and that count
            spread = {"radiance_median_rel_diff": float(np.median(rel)) if rel.size else float("nan"),
                      "radiance_p99_rel_diff": float(np.percentile(rel, 99)) if rel.size else float("nan"),
                      "radiance_values_off_by_1e-4": int(np.sum(rel > 1e-4))}
            # the edits seen in this row's PTX (not only the wrapper installed): the capped entry, and the contracted
            # one with the instructions freed there
            cap_applied = bool(cap) and caps_applied() > caps_before and capped_entries().get(entry) == cap
            fma_applied = (fma and contractions_applied() > contractions_before
                           and contracted_entries().get(entry, 0) > 0)
            rows.append({"scene": name, "fused_block": text, "grid_kernel": kernel, "block_chunk_s": seconds,
                         "max_registers": cap, "cap_applied": cap_applied, "vector_gathers": vector, "fma": fma,
                         "fma_applied": fma_applied, "fma_freed": contracted_entries()[entry] if fma_applied else None,
                         "first_call_s": first, "render_kernel_chunk_s": base_s, "radiance_max_rel_diff": worst,
                         **spread, "nonfinite": int(np.sum(~ok))})
            capped = "" if cap is None else f", at most {cap} registers ({'' if cap_applied else 'NOT '}applied)"
            capped += "" if vector else ", scalar gathers"
            capped += f", fused multiply-adds ({'' if fma_applied else 'NOT '}applied)" if fma else ""
            print(f"{name}: {kernel} kernel, {rays} rays x {warps} warps per program{capped}: "
                  f"{seconds * 1e3:.2f} ms per chunk (first call {first:.1f} s; the render's kernel "
                  f"{base_s * 1e3:.2f} ms), radiance within {worst:.1e} "
                  f"(median {spread['radiance_median_rel_diff']:.1e}, p99 "
                  f"{spread['radiance_p99_rel_diff']:.1e}, {spread['radiance_values_off_by_1e-4']} values off by "
                  f"> 1e-4), {int(np.sum(~ok))} values not finite", flush=True)
    finally:
        march_pallas.BLOCK_RAYS, march_pallas.NUM_WARPS = saved
        if export is None:
            os.environ.pop("SWIM_JAX_EXPORT")
        else:
            os.environ["SWIM_JAX_EXPORT"] = export
        jax.clear_caches()
        probe.trace_chunk.forget_programs()
    return rows


def compare_numba(name, scene, kw, first):
    """Radiance of the JAX render ``first`` against the numba kernel's render of the same view."""
    import numpy as np

    import swim
    from swim.rt.march_settings import ExecutionSettings, MarchSettings

    kw_n = {**kw, "settings": MarchSettings(execution=ExecutionSettings(backend="numba"))}
    t0 = time.perf_counter()
    swim.render(scene, **kw_n)
    ref = swim.render(scene, **kw_n)
    numba_s = time.perf_counter() - t0
    a, b = first["radiance"].values, ref["radiance"].values
    ok = np.isfinite(b) & np.isfinite(a)
    rel = np.abs(a[ok] - b[ok]) / np.maximum(np.abs(b[ok]), 1e-3)
    d8 = np.abs(first["rgb"].values.astype(int) - ref["rgb"].values.astype(int))
    cmp = {"scene": name, "compare": "numba", "numba_two_renders_s": numba_s, "median": float(np.median(rel)),
           "p99": float(np.percentile(rel, 99)), "max": float(rel.max()), "rgb_max": int(d8.max()),
           "nonfinite_gpu": int(np.sum(~np.isfinite(a)))}
    print(f"{name} GPU vs numba: median {cmp['median']:.2e}, p99 {cmp['p99']:.2e}, max {cmp['max']:.2e}, "
          f"8-bit RGB max {cmp['rgb_max']}", flush=True)
    return cmp


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=["synthetic"], choices=("synthetic", "katrina", "rico", "conus"))
    ap.add_argument("--chunks", nargs="+", type=int, default=[0],
                    help="rays per kernel call to compare (0: the default, MarchSettings.resolved_chunk)")
    kernels = ("auto", "lockstep", "fused", "fused-march")
    ap.add_argument("--grid-kernel", choices=kernels, default="auto",
                    help="the JAX kernel's march of the grid segment (ExecutionSettings.grid_kernel)")
    ap.add_argument("--against", nargs="*", choices=kernels[1:], default=[],
                    help="also march the captured chunk with these grid kernels: time and outputs against the render's")
    ap.add_argument("--fused-blocks", nargs="*", default=[],
                    help="also time the fused grid kernel on the captured chunk with RAYSxWARPS per program "
                         "(RAYSxWARPS[rN][s][f][m]: at most N registers per thread; s: a scalar gather per table "
                         "channel; f: fused multiply-adds; m: the fused-march kernel), its radiance against the "
                         "render's kernel")
    ap.add_argument("--scalar-loads", action="store_true",
                    help="the render's fused kernel with a scalar gather per table channel "
                         "(ExecutionSettings.fused_vector_loads=False: one load per channel, not four)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--size", type=int, default=None, help="image width and height (default: the suite's 1024)")
    ap.add_argument("--sampling", action="store_true",
                    help="also an adaptively sampled render (last chunk size) and its error against every pixel traced")
    ap.add_argument("--sun-series", type=int, default=0,
                    help="also N frames with a new sun each (a fixed camera's time series; median of frames 2..N)")
    ap.add_argument("--profile", action="store_true", help="also profile a warm render (host) and a chunk (device)")
    ap.add_argument("--ray-table", action="store_true",
                    help="also time warm renders with ExecutionSettings.ray_table against without, taking turns")
    ap.add_argument("--step1a-on-device", action="store_true",
                    help="also time frames with a new sun each, ExecutionSettings.step1a_on_device on against off, taking "
                         "turns (docs/decisions/0006-gpu-kernels.md)")
    ap.add_argument("--device-sampling", action="store_true",
                    help="also time adaptive frames with the sampler on the device (ExecutionSettings.device_sampling) "
                         "against the host's, taking turns, the ray table on")
    ap.add_argument("--device-image", action="store_true",
                    help="also time frames with the image's planes and colour made on the device "
                         "(ExecutionSettings.device_image) against the host's, taking turns, every pixel and adaptive, "
                         "the ray table on (docs/decisions/0006-gpu-kernels.md)")
    ap.add_argument("--barriers", action="store_true",
                    help="also the kernel with its CPU optimisation barriers forced on "
                         "(docs/decisions/0006-gpu-kernels.md)")
    ap.add_argument("--compare", action="store_true", help="also render with numba on the host and compare")
    ap.add_argument("--data", type=Path, default=bench_suite.DATA)
    ap.add_argument("--out", type=Path, default=None, help="JSON file (its folder also gets the PNGs)")
    args = ap.parse_args(argv)
    import jax

    machine = {"jax": jax.__version__, "backend": jax.default_backend(), "devices": [str(d) for d in jax.devices()],
               "device_kind": jax.devices()[0].device_kind, "host_cores": len(os.sched_getaffinity(0))}
    print(machine, flush=True)
    probe = TraceProbe()
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
    doc = {"machine": machine, "argv": sys.argv[1:], "scenes": {}}
    for name in args.scenes:
        doc["scenes"][name] = run_scene(name, args, probe, args.out.parent if args.out else None)
        if args.out:
            args.out.write_text(json.dumps(doc, indent=1, default=float))
    import history

    history.append("gpu", history.gpu_rows(doc), machine=history.machine_label(machine), source="bench_gpu.py")
    print("\n| scene | chunk | rays | warm render [s] | frames/s | in trace_rays [s] | kernel per chunk [ms] | "
          "kernel Mrays/s | kernel frames/s |\n|---|---|---|---|---|---|---|---|---|")
    for name, res in doc["scenes"].items():
        for r in res["rows"]:
            if "kernel_chunk_s" in r:
                print(f"| {name} | {r['chunk']} | {r['rays']:,} | {r['render_s']:.3f} | {r['render_fps']:.2f} | "
                      f"{r['trace_s']:.3f} | {1e3 * r['kernel_chunk_s']:.2f} | {r['kernel_rays_per_s'] / 1e6:.2f} | "
                      f"{r['kernel_fps']:.1f} |")


if __name__ == "__main__":
    main()
