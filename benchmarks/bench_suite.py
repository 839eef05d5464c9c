"""Benchmark suite: wall time cold and warm, compile time, peak memory, rays/s and samples/s per case.

Usage::

    python benchmarks/bench_suite.py --quick                      # smoke run, image sizes / 4 per axis
    python benchmarks/bench_suite.py --cases 'synthetic_*' mc_ratio --repeats 5
    python benchmarks/bench_suite.py --list

Every case runs in a fresh subprocess (so ``cold`` includes JIT compilation and ``peak_rss_mb`` is the case's
own ``ru_maxrss``) under a timeout and a memory limit; a case that fails is reported as "not run: <reason>".
Results go to ``benchmarks/results/latest.json`` (overwritten) and a few figures per case to
``benchmarks/results/history.csv`` (appended, ``history.py``); a Markdown table is printed at the end. See
benchmarks/README.md for the cases and the JSON fields.
"""

from __future__ import annotations

import argparse
import fnmatch
import json
import math
import os
import platform
import resource
import signal
import statistics
import subprocess
import sys
import tempfile
import time
import traceback
from datetime import datetime, timezone
from pathlib import Path

from scenes import CONUS_REFERENCE, SYNTHETIC_REFERENCE  # benchmarks/ is on the path (this script's folder, or its importers')

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
DATA = ROOT.parent / "shared" / "data"
#: A machine probe at most this many times the fastest one (of the suite's reference, taken before its first case, and
#: of the case's own) counts as the machine's fast state (machine_probe.py: its two states are ~1.45x apart on the AMD
#: EPYC, with probes between them too; docs/performance.md, "How to measure").
FAST_STATE = 1.1
#: Seconds of one-pass probes before the first case whose fastest is the suite's reference (machine_probe.reference).
PROBE_REFERENCE_S = 6.0
#: --quick divides every image size, and the procedural grids except CONUS, by this per axis.
QUICK_FACTOR = 4
#: The synthetic scene of the brief: 400 x 400 x 60 at 1 km, all five species and terrain.
SYNTHETIC_GRID = {"nx": 400, "ny": 400, "nz": 60, "spacing": 1000.0}

KATRINA_ALLSKY = {"lat": 24.7, "lon": -88.6, "height": 2.0}
KATRINA_PANORAMA = {"lat": 24.2, "lon": -89.0, "height": 3000.0}  # the README's panorama vantage
RICO_VIEW = {"height": 2.0, "sun_zenith": 30.0, "sun_azimuth": 135.0}  # swim.validation.mitsuba rico_ground_sza30
GROUND = {"height": 2.0}  # at the scene's reference point (the domain centre)
# a satellite 700 km over the scene's reference point: a perspective camera above 100 km without view angles looks
# straight down (swim.pipeline.render); its field of view (30 deg: 375 km across the ground) within the 400 km
# synthetic grid and Katrina's 480 km one, so that every pixel sees the grid (the default would fit the grid's diagonal
# with a margin)
ORBIT = {"height": 700e3}
ORBIT_FOV_DEG = 30.0
# the same satellite 8 deg of latitude south of the synthetic scene's reference point, looking at it (a view zenith of
# 49 deg there) with a 12 deg field of view: the image's upper rows see past the grid's far edge, where rays leave the
# grid sideways on their way down to the ground (docs/performance.md, "How to measure" and
# docs/decisions/0004-step-placement.md)
_LAT0, _LON0, _ = SYNTHETIC_REFERENCE
ORBIT_OBLIQUE = {"lat": _LAT0 - 8.0, "lon": _LON0, "height": 700e3, "look_at": [_LAT0, _LON0, 0.0]}
ORBIT_OBLIQUE_FOV_DEG = 12.0
# the whole CONUS grid from geostationary orbit (GOES-East's longitude), looking at the grid's centre with a 9 deg
# field of view (~5 800 km across at the grid): every column is in view, so nothing is cropped; one column of each
# block as wide as a pixel's footprint (render's coarsen="auto": 3 x 3 at 512^2; docs/performance.md, "Distant views of
# big grids")
GEO = {"lat": 0.0, "lon": -75.2, "height": 35786e3, "look_at": [CONUS_REFERENCE[0], CONUS_REFERENCE[1], 0.0],
       "sun_zenith": 30.0, "sun_azimuth": 180.0}
GEO_FOV_DEG = 9.0
# swim.rt.image_sampling.AdaptiveSampling() defaults (docs/decisions/0005-adaptive-sampling.md)
ADAPTIVE = {"tolerance": 0.0085, "coarse_spacing": 8, "edge_test_size": 8}

CASES = {
    "katrina_allsky": {"kind": "render", "scene": "katrina", "camera": "allsky", "image": (1024, 1024), "view": KATRINA_ALLSKY},
    "katrina_panorama": {"kind": "render", "scene": "katrina", "camera": "panorama", "image": (2048, 1024), "view": KATRINA_PANORAMA},
    "rico_allsky": {"kind": "render", "scene": "rico", "camera": "allsky", "image": (1024, 1024), "view": RICO_VIEW},
    "rico_panorama": {"kind": "render", "scene": "rico", "camera": "panorama", "image": (2048, 1024), "view": RICO_VIEW},
    "synthetic_allsky": {"kind": "render", "scene": "synthetic", "camera": "allsky", "image": (1024, 1024), "view": GROUND},
    "synthetic_panorama": {"kind": "render", "scene": "synthetic", "camera": "panorama", "image": (2048, 1024), "view": GROUND},
    "katrina_orbit": {"kind": "render", "scene": "katrina", "camera": "perspective", "image": (1024, 1024),
                      "view": ORBIT, "fov_deg": ORBIT_FOV_DEG},
    "synthetic_orbit": {"kind": "render", "scene": "synthetic", "camera": "perspective", "image": (1024, 1024),
                        "view": ORBIT, "fov_deg": ORBIT_FOV_DEG},
    "synthetic_orbit_oblique": {"kind": "render", "scene": "synthetic", "camera": "perspective", "image": (1024, 1024),
                                "view": ORBIT_OBLIQUE, "fov_deg": ORBIT_OBLIQUE_FOV_DEG},
    "conus_allsky": {"kind": "render", "scene": "conus", "camera": "allsky", "image": (1024, 1024), "view": GROUND, "crop": True},
    "conus_geo": {"kind": "render", "scene": "conus", "camera": "perspective", "image": (512, 512), "view": GEO,
                  "fov_deg": GEO_FOV_DEG, "coarsen": "auto"},
    "conus_panorama": {"kind": "render", "scene": "conus", "camera": "panorama", "image": (2048, 1024), "view": GROUND,
                       "crop": True},
    # adaptive image sampling (swim.rt.image_sampling): timed like the others, then compared with one render of
    # every pixel (not timed)
    "katrina_allsky_adaptive": {"kind": "render", "scene": "katrina", "camera": "allsky", "image": (1024, 1024),
                                "view": KATRINA_ALLSKY, "sampling": ADAPTIVE},
    "synthetic_allsky_adaptive": {"kind": "render", "scene": "synthetic", "camera": "allsky", "image": (1024, 1024),
                                  "view": GROUND, "sampling": ADAPTIVE},
    "conus_allsky_adaptive": {"kind": "render", "scene": "conus", "camera": "allsky", "image": (1024, 1024), "view": GROUND,
                              "crop": True, "sampling": ADAPTIVE},
    "series": {"kind": "series", "scene": "katrina", "camera": "allsky", "image": (512, 512), "view": KATRINA_ALLSKY,
               "frames": 24, "step_min": 10.0, "start": "2005-08-28T16:00", "wind_m_s": 10.0},
    # the same series as a forecaster's loop would render it: adaptive sampling (swim.rt.image_sampling)
    "series_adaptive": {"kind": "series", "scene": "katrina", "camera": "allsky", "image": (512, 512),
                        "view": KATRINA_ALLSKY, "frames": 24, "step_min": 10.0, "start": "2005-08-28T16:00",
                        "wind_m_s": 10.0, "sampling": ADAPTIVE},
    # a camera moving over a big grid (a drive or a fly-through): one 3 km cell east per frame, the time fixed
    "flythrough": {"kind": "flythrough", "scene": "conus", "camera": "allsky", "image": (512, 512), "view": GROUND,
                   "crop": True, "frames": 12, "step_m": 3000.0},
    "scaling_pixels": {"kind": "scaling_pixels", "scene": "synthetic", "camera": "allsky", "sizes": [128, 256, 512, 1024], "view": GROUND},
    "scaling_grid": {"kind": "scaling_grid", "scene": "synthetic", "camera": "allsky", "image": (256, 256), "grids": [100, 200, 400],
                     "domain_m": 400e3, "view": GROUND},
    "mc_ratio": {"kind": "mc", "scene": "rico", "camera": "allsky", "mc_case": "rico_ground_sza30", "size": 41, "ref_spp": 4096,
                 "noise_target": 0.02},
    # the 3-D cloud scattering (cloud_scattering="discrete_ordinates"): the same cases, warm (the diffuse solution of
    # the scene and sun reused; benchmarks/bench_clouds3d.py times the solve itself); the Monte Carlo case with the
    # reference's phase function (Henyey-Greenstein g 0.85)
    "synthetic_allsky_adaptive_3d": {"kind": "render", "scene": "synthetic", "camera": "allsky", "image": (1024, 1024),
                                     "view": GROUND, "sampling": ADAPTIVE, "cloud_scattering": "discrete_ordinates"},
    "mc_ratio_3d": {"kind": "mc", "scene": "rico", "camera": "allsky", "mc_case": "rico_ground_sza30", "size": 41,
                    "ref_spp": 4096, "noise_target": 0.02,
                    "cloud_scattering": {"method": "discrete_ordinates", "phase_function": {"liquid": ["hg", 0.85]}}},
}


def march_settings(spec):
    """The case's renderer settings: its backend and cloud scattering (None: the renderer's defaults). A case without
    ``cloud_scattering`` renders with the paper's method ("albers2020"), whose figures the suite's history holds (the
    renderer's default since the 3-D method became it: the "_3d" cases); older code without the setting renders
    with its default, which was that method."""
    import dataclasses

    from swim.rt.march_settings import MarchSettings

    clouds = spec.get("cloud_scattering")
    if clouds is None and "cloud_scattering" in {f.name for f in dataclasses.fields(MarchSettings)}:
        clouds = "albers2020"
    kw = {}
    if spec.get("backend", "auto") != "auto":
        kw["backend"] = spec["backend"]
    if isinstance(clouds, dict):
        from swim.rt.clouds import CloudScattering

        kw["cloud_scattering"] = CloudScattering(clouds["method"], clouds.get("phase_function", "physical"))
    elif clouds:
        kw["cloud_scattering"] = clouds
    if not kw:
        return None
    backend = kw.pop("backend", None)
    return MarchSettings(**kw) if backend is None else settings_with_backend(backend, **kw)


def settings_with_backend(backend, **kw):
    """``MarchSettings(**kw)`` with the march's ``backend``: in its ``ExecutionSettings`` where the code under test has
    them, else as older code's own field (the suite also measures older versions, taking turns)."""
    from swim.rt import march_settings

    if hasattr(march_settings, "ExecutionSettings"):
        return march_settings.MarchSettings(execution=march_settings.ExecutionSettings(backend=backend), **kw)
    return march_settings.MarchSettings(backend=backend, **kw)


# ---------------------------------------------------------------------------------------------------------
# helpers shared by parent and child


def _shrink(n, quick):
    return max(8, n // QUICK_FACTOR) if quick else n


def camera_options(camera, image, fov_deg=None):
    width, height = image
    options = {"size": width} if camera == "allsky" else {"width": width, "height": height}
    return options if fov_deg is None else {**options, "fov_deg": fov_deg}


def case_spec(name, args):
    """The case with sizes adjusted for --quick and the run options the child needs."""
    spec = json.loads(json.dumps(CASES[name]))
    q = args.quick
    if "image" in spec:
        spec["image"] = [_shrink(n, q) for n in spec["image"]]
    if spec["scene"] == "synthetic" or (spec["kind"] == "series" and args.series_scene == "synthetic"):
        # render() rebuilds the optical volume and the solar transmittance of the whole grid every call (~100 s
        # for 400 x 400 x 60 on 2 cores), so a smoke run also needs a smaller grid; same 400 km domain
        g = dict(SYNTHETIC_GRID)
        if q:
            g.update(nx=g["nx"] // QUICK_FACTOR, ny=g["ny"] // QUICK_FACTOR, spacing=g["spacing"] * QUICK_FACTOR)
        spec["scene_kwargs"] = g
    if "grids" in spec and q:
        spec["grids"] = [n // QUICK_FACTOR for n in spec["grids"]]
    if "sizes" in spec:
        spec["sizes"] = [_shrink(n, q) for n in spec["sizes"]]
    if spec["kind"] == "mc":
        spec["size"] = (spec["size"] // QUICK_FACTOR) | 1 if q else spec["size"]  # odd: a pixel on the zenith
        spec["ref_spp"] = args.mc_ref_spp or (1024 if q else spec["ref_spp"])
        spec["max_spp"] = args.mc_max_spp or spec["ref_spp"] // 4
    if spec["kind"] == "series":
        spec["scene"] = args.series_scene
        if args.series_scene == "synthetic":
            spec["view"] = GROUND
        spec["workers"] = args.series_workers
    spec.update(name=name, quick=q, data=str(args.data), results=str(args.results), repeats=args.repeats,
                mem_limit_gb=args.mem_limit_gb, disk_caches=args.disk_caches, backend=args.backend)
    return spec


# ---------------------------------------------------------------------------------------------------------
# child: one case in a fresh process


class CompileProbe:
    """Seconds JAX spends compiling (jaxpr tracing, MLIR lowering, XLA backend compile) and the number of
    backend compiles, from ``jax.monitoring`` duration events."""

    def __init__(self, disk_caches=False):
        import jax

        if not disk_caches:
            # A persistent cache would make "cold" a cache load instead of a compile (swim turns JAX's on
            # at import; this master switch wins over it).
            jax.config.update("jax_enable_compilation_cache", False)
        self.seconds, self.count = 0.0, 0
        jax.monitoring.register_event_duration_secs_listener(self._on_event)

    def _on_event(self, event, duration, **_):
        if event.startswith("/jax/core/compile/"):
            self.seconds += duration
            self.count += event.endswith("backend_compile_duration")


def timed(probe, fn, *args, **kwargs):
    """(result, wall seconds, JAX compile seconds, backend compiles) of one call."""
    s0, n0 = probe.seconds, probe.count
    t0 = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - t0, probe.seconds - s0, probe.count - n0


def warm_time(probe, fn, repeats, max_warmups=3):
    """Median of ``repeats`` calls during which JAX compiled nothing; calls that compiled are warm-ups
    (a new image size below the kernel's chunk size compiles a new kernel shape)."""
    runs, warmups = [], 0
    while len(runs) < repeats:
        _, dt, _, n = timed(probe, fn)
        if n and warmups < max_warmups:
            warmups += 1
            continue
        runs.append(dt)
    return statistics.median(runs), runs, warmups


def machine_info():
    import jax
    import numpy

    import swim

    cpu = next((line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                if line.startswith("model name")), platform.processor()) if Path("/proc/cpuinfo").exists() else platform.processor()
    return {"hostname": platform.node(), "platform": platform.platform(), "python": platform.python_version(),
            "cpu_model": cpu, "cpu_count": os.cpu_count(),
            "cpu_affinity": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),
            "mem_total_gb": round(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30, 1),
            "jax": jax.__version__, "jax_backend": jax.default_backend(), "jax_devices": [str(d) for d in jax.devices()],
            "numpy": numpy.__version__, "swim": swim.__version__}


def march_backend(choice="auto"):
    """The step-loop kernel a case's renders use (swim.rt.march_settings.ExecutionSettings.backend, resolved)."""
    from swim.rt.march_settings import MarchSettings

    if not hasattr(MarchSettings(), "resolved_backend"):
        return "jax"  # versions before the numba kernel
    return settings_with_backend(choice).resolved_backend()


def march_chunk(choice="auto"):
    """Rays per kernel call of a case's renders (swim.rt.march_settings.ExecutionSettings.chunk, resolved), or None."""
    settings = settings_with_backend(choice)
    return settings.resolved_chunk() if hasattr(settings, "resolved_chunk") else settings.chunk


def limit_address_space(gb):
    """RLIMIT_AS for CPU runs: an allocation beyond it raises MemoryError instead of swapping the machine.
    Not on GPUs, whose drivers reserve far more virtual address space than they use."""
    import jax

    if gb and jax.default_backend() == "cpu":
        limit = int(gb * 2**30)
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))


def load_scene(spec, **kwargs):
    import scenes

    name = spec["scene"]
    if name == "katrina":
        return scenes.katrina_scene(spec["data"])
    if name == "rico":
        return scenes.rico_scene(spec["data"])
    if name == "synthetic":
        return scenes.synthetic_scene(**{**spec.get("scene_kwargs", {}), **kwargs})
    if name == "conus":
        return scenes.conus_scene(**kwargs)
    raise KeyError(name)


def _grid(scene):
    return [scene.sizes["x"], scene.sizes["y"], scene.sizes["z"]]


def render_kwargs(spec, image=None):
    import inspect

    import swim

    options = camera_options(spec["camera"], image or spec["image"], spec.get("fov_deg"))
    kw = dict(spec["view"], camera=spec["camera"], camera_options=options)
    if spec.get("crop") and "crop" in inspect.signature(swim.render).parameters:
        kw["crop"] = True
    settings = march_settings(spec)
    if settings is not None:
        kw["settings"] = settings
    if spec.get("coarsen") is not None:
        kw["coarsen"] = spec["coarsen"]
    if spec.get("sampling"):
        from swim.rt.image_sampling import AdaptiveSampling

        kw["sampling"] = AdaptiveSampling(**spec["sampling"])
    return kw


def adaptive_errors(image, full):
    """Relative radiance error of an adaptively sampled image against every pixel traced, and 8-bit RGB
    differences."""
    import numpy as np

    a, f = image["radiance"].values, full["radiance"].values
    ok = np.isfinite(f)
    rel = np.abs(a[ok] - f[ok]) / np.maximum(np.abs(f[ok]), 1e-3)
    d8 = np.abs(image["rgb"].values.astype(int) - full["rgb"].values.astype(int))
    return {"median": float(np.median(rel)), "p99": float(np.percentile(rel, 99)), "max": float(rel.max()),
            "rgb_max": int(d8.max()), "rgb_frac_over_2": float(np.mean(d8 > 2))}


def crop_used(kw):
    """The crop setting a render ran with: passed, render's default, or None where render has no crop."""
    import inspect

    import swim

    p = inspect.signature(swim.render).parameters.get("crop")
    return kw.get("crop", p.default) if p is not None else None


def throughput(image, rays, seconds):
    """rays/s and samples/s; samples are the kernel's count (``march_samples``) where the output has it."""
    from swim.rt.march_settings import MarchSettings

    if "march_samples" in image.attrs:
        backend = image.attrs.get("march_backend", "?")
        # the per-ray kernels count the samples each ray took, the JAX kernel every step of its chunk (lockstep count;
        # docs/performance.md, "How to measure")
        counted = "lockstep count" if backend == "jax" else "per-ray count"
        samples, how = (float(image.attrs["march_samples"]),
                        f"march_samples attribute of the render output ({counted}, {backend} kernel)")
    else:
        s = MarchSettings()
        per_ray = s.n_before + s.n_grid + s.n_after
        samples, how = rays * per_ray, f"upper bound: rays x (n_before + n_grid + n_after) = rays x {per_ray}"
    return {"rays_per_s": rays / seconds, "samples_per_s": samples / seconds, "samples": samples, "samples_how": how}


def run_render(spec, probe):
    import machine_probe  # benchmarks/ is on the path

    import swim

    machine_probe.ready()  # compiled before the scene, so that its memory counts as the scene's
    t0 = time.perf_counter()
    scene = load_scene(spec)
    scene_s = time.perf_counter() - t0
    scene_rss = _self_rss_mb()  # what the scene (and building it) left: the renders' own memory is above it
    kw = render_kwargs(spec)
    image, cold, cold_compile, _ = timed(probe, swim.render, scene, **kw)
    runs, warm_compile, speed = [], 0.0, []
    for _ in range(spec["repeats"]):
        # the machine's state before each warm render and after the last (machine_probe.py; ~60 ms each)
        speed.append(machine_probe.probe(passes=1)["ns_per_sample"])
        image, dt, c, _ = timed(probe, swim.render, scene, **kw)
        runs.append(dt)
        warm_compile += c
    speed.append(machine_probe.probe(passes=1)["ns_per_sample"])
    warm = statistics.median(runs)
    # the runs between two probes of the machine's fast state (within FAST_STATE of the fastest probe: the suite's
    # reference or the case's own)
    best = min(speed + [spec.get("probe_reference_ns") or math.inf])
    fast = [t for t, a, b in zip(runs, speed, speed[1:]) if max(a, b) <= FAST_STATE * best]
    ny, nx = image["rgb"].shape[:2]
    rays = ny * nx + 1  # every pixel (all-sky corners too) plus the ray towards the sun
    out = {"image": [nx, ny], "rays": rays, "grid": _grid(scene), "scene_s": scene_s, "cold_s": cold, "warm_s": warm, "warm_runs": runs,
           "machine_probe_ns": speed, "warm_fast_state_s": statistics.median(fast) if fast else None,
           "warm_fast_state_runs": len(fast), "compile_est_s": cold - warm, "jax_compile_s": cold_compile, "jax_compile_warm_s": warm_compile,
           "crop": crop_used(kw), **throughput(image, rays, warm),
           "scene_rss_mb": scene_rss, "render_peak_above_scene_mb": _self_peak_rss_mb() - scene_rss}
    if "traced_pixels" in image.attrs:
        out["traced_pixels"] = int(image.attrs["traced_pixels"])
    if "sampling" in kw:
        every = {key: value for key, value in kw.items() if key != "sampling"}
        swim.render(scene, **every)  # warm: compiled for this image's batches as the adaptive render was
        full, full_s, _, _ = timed(probe, swim.render, scene, **every)
        out.update(sampling=spec["sampling"], full_warm_s=full_s, full_traced_pixels=int(full.attrs["traced_pixels"]),
                   adaptive_error=adaptive_errors(image, full))
    return out


def _self_rss_mb():
    """Resident memory of this process now [MB] (after a garbage collection)."""
    import gc

    gc.collect()
    return _tree_rss_mb(os.getpid())


def _self_peak_rss_mb():
    """This process's high-water mark of resident memory [MB] (Linux reports KB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _distributed_frames(scene, kw, times, workers):
    """The series' frames on a local dask cluster of ``workers`` processes (swim.series.render_series), the PNGs
    written to a temporary folder; the wall time includes the cluster's start and each worker's first frame."""
    import tempfile

    from swim.series import render_series

    with tempfile.TemporaryDirectory() as folder:
        t0 = time.perf_counter()
        table = render_series(scene, times, out=Path(folder) / "{index:03d}.png", workers=workers, **kw)
        wall = time.perf_counter() - t0
    return {"workers": workers, "wall_s": wall, "s_per_frame": wall / len(times), "frames_per_s": len(times) / wall,
            "worker_frame_s": [float(x) for x in table["seconds"]]}


def run_series(spec, probe):
    import pandas as pd

    import swim

    times = [pd.Timestamp(spec["start"]) + pd.Timedelta(minutes=spec["step_min"] * i) for i in range(spec["frames"])]
    kw = render_kwargs(spec)
    frames, builds, compile_s = [], [], []
    scene = None if spec["scene"] == "synthetic" else load_scene(spec)
    for i, t in enumerate(times):
        if spec["scene"] == "synthetic":
            # clouds advected by a uniform wind; the scene build is timed apart from the frame
            t0 = time.perf_counter()
            shift = (spec["wind_m_s"] * 60.0 * spec["step_min"] * i, 0.0)
            scene = load_scene(spec, shift=shift, time=str(t))
            builds.append(time.perf_counter() - t0)
            image, dt, c, _ = timed(probe, swim.render, scene, **kw)
        else:
            # the sun moves: same scene, a new time per frame
            image, dt, c, _ = timed(probe, swim.render, scene, time=t, **kw)
        frames.append(dt)
        compile_s.append(c)
    nx, ny = spec["image"]
    rays = nx * ny + 1
    warm = statistics.median(frames[1:])
    out = {"image": [nx, ny], "rays": rays, "grid": _grid(scene), "frames": len(frames), "frame_s": frames, "frame_jax_compile_s": compile_s,
           "cold_s": frames[0], "warm_s": warm, "warm_runs": frames[1:], "mean_frame_s": statistics.fmean(frames),
           "total_s": sum(frames), "compile_est_s": frames[0] - warm, "jax_compile_s": compile_s[0],
           "jax_compile_warm_s": sum(compile_s[1:]), "frame_times_utc": [str(t) for t in times],
           **throughput(image, rays, warm)}
    if builds:
        out["scene_build_s"] = builds
    if "sampling" in kw:  # adaptive: the last frame against every pixel traced (not timed)
        every = {key: value for key, value in kw.items() if key != "sampling"}
        full = swim.render(scene, **({"time": times[-1]} if spec["scene"] != "synthetic" else {}), **every)
        out.update(sampling=spec["sampling"], traced_pixels=int(image.attrs["traced_pixels"]),
                   full_traced_pixels=int(full.attrs["traced_pixels"]), adaptive_error=adaptive_errors(image, full))
    if spec.get("workers"):
        # frame cost only: one scene (the last) at every frame time, scattered once to all workers
        out["distributed"] = _distributed_frames(scene, kw, [str(t) for t in times], spec["workers"])
    return out


class _ReuseCounter:
    """Counts the stage cache's "reusing the volume" log records (swim.pipeline.caches.StageCache.get)."""

    def __init__(self):
        import logging

        self.count = 0
        self.handler = logging.Handler(logging.INFO)
        self.handler.emit = self._emit
        self.logger = logging.getLogger("swim.pipeline")
        self.previous_level = self.logger.level

    def _emit(self, record):
        if record.getMessage() == "reusing the volume of the previous render":
            self.count += 1

    def __enter__(self):
        import logging

        self.logger.addHandler(self.handler)
        self.logger.setLevel(logging.INFO)
        return self

    def __exit__(self, *exc):
        self.logger.removeHandler(self.handler)
        self.logger.setLevel(self.previous_level)


def run_flythrough(spec, probe):
    """A camera moving ``step_m`` east per frame over a big grid, the time (and so the sun) fixed: per-frame times,
    and the frames that reused the previous frame's optical volume (the same crop) rather than rebuilding it."""
    import math

    import swim

    scene = load_scene(spec)
    kw = render_kwargs(spec)
    lat0, lon0 = float(scene.attrs["reference_lat"]), float(scene.attrs["reference_lon"])
    dlon = math.degrees(spec["step_m"] / (6371008.8 * math.cos(math.radians(lat0))))
    frames, reused = [], []
    for i in range(spec["frames"]):
        with _ReuseCounter() as counter:
            image, dt, _, _ = timed(probe, swim.render, scene, **{**kw, "lat": lat0, "lon": lon0 + i * dlon})
        frames.append(dt)
        reused.append(counter.count > 0)
    nx, ny = spec["image"]
    rays = nx * ny + 1
    warm = statistics.median(frames[1:])
    return {"image": [nx, ny], "rays": rays, "grid": _grid(scene), "frames": len(frames), "frame_s": frames,
            "frame_reused_volume": reused, "rebuilds": len(frames) - sum(reused), "cold_s": frames[0], "warm_s": warm,
            "warm_runs": frames[1:], "total_s": sum(frames), "mean_frame_s": statistics.fmean(frames),
            "step_m": spec["step_m"], **throughput(image, rays, warm)}


def fit_exponent(x, y):
    """Log-log slope of y against x (least squares)."""
    import numpy as np

    return float(np.polyfit(np.log(x), np.log(y), 1)[0])


def run_scaling_pixels(spec, probe):
    import swim

    scene = load_scene(spec)
    points = []
    for size in spec["sizes"]:
        kw = render_kwargs(spec, (size, size))
        warm, runs, warmups = warm_time(probe, lambda: swim.render(scene, **kw), spec["repeats"])
        rays = size * size + 1
        points.append({"size": size, "pixels": size * size, "rays": rays, "warm_s": warm, "warm_runs": runs,
                       "warmups": warmups, "rays_per_s": rays / warm})
    return {"curve": "warm time vs pixels (all-sky)", "grid": _grid(scene), "points": points,
            "exponent": fit_exponent([p["pixels"] for p in points], [p["warm_s"] for p in points])}


def run_scaling_grid(spec, probe):
    import swim

    kw = render_kwargs(spec)
    points = []
    for n in spec["grids"]:
        # a fixed 400 km domain at finer spacing: the view stays the same, only the cell count changes
        t0 = time.perf_counter()
        scene = load_scene(spec, nx=n, ny=n, spacing=spec["domain_m"] / n)
        build = time.perf_counter() - t0
        nz = scene.sizes["z"]
        warm, runs, warmups = warm_time(probe, lambda: swim.render(scene, **kw), spec["repeats"])
        points.append({"grid": [n, n, nz], "cells": n * n * nz, "spacing_m": spec["domain_m"] / n, "scene_s": build,
                       "warm_s": warm, "warm_runs": runs, "warmups": warmups})
        scene = None  # free it before the next, bigger grid is built
    nx, ny = spec["image"]
    return {"curve": f"warm time vs grid cells ({nx}x{ny} all-sky)", "image": [nx, ny], "rays": nx * ny + 1, "points": points,
            "exponent": fit_exponent([p["cells"] for p in points], [p["warm_s"] for p in points])}


def image_errors(test, ref, ref_sigma):
    """Errors of ``test`` against a Monte Carlo reference of per-pixel standard error ``ref_sigma``, pooled
    over pixels and the 3 wavelengths: mean absolute relative error and RMSE / mean(reference), raw and
    corrected for the reference's own noise (``*_corrected``; exact for the mean square error, a Gaussian
    quadrature estimate for the mean absolute error)."""
    import numpy as np

    a, b, s = (np.asarray(v, float) for v in (test, ref, ref_sigma))
    ok = np.isfinite(a) & np.isfinite(b) & (b > 0)
    a, b, s = a[ok], b[ok], s[ok]
    mare, mare_noise = float(np.mean(np.abs(a / b - 1.0))), math.sqrt(2 / math.pi) * float(np.mean(s / b))
    mse, mean = float(np.mean((a - b) ** 2)), float(np.mean(b))
    return {"mean_abs_rel": mare, "mean_abs_rel_corrected": math.sqrt(max(mare**2 - mare_noise**2, 0.0)),
            "rel_rmse": math.sqrt(mse) / mean, "rel_rmse_corrected": math.sqrt(max(mse - float(np.mean(s**2)), 0.0)) / mean}


def crossing(spps, errors, target):
    """spp at which the Monte Carlo error falls to ``target``: log-log interpolation between the sweep points
    that bracket it; below the first point: the first spp; beyond the sweep: extrapolated along the fitted
    slope of the last points (noise ~ spp^-1/2)."""
    import numpy as np

    ls, le, lt = np.log(spps), np.log(np.maximum(errors, 1e-9)), math.log(max(target, 1e-9))
    for i, e in enumerate(errors):
        if e <= target:
            if i == 0:
                return float(spps[0]), "reached at the first spp"
            f = (lt - le[i - 1]) / (le[i] - le[i - 1])
            return float(np.exp(ls[i - 1] + f * (ls[i] - ls[i - 1]))), "interpolated"
    slope = np.polyfit(ls[-3:], le[-3:], 1)[0] if len(ls) >= 3 else -0.5
    slope = slope if slope < -0.1 else -0.5
    return float(np.exp(ls[-1] + (lt - le[-1]) / slope)), "extrapolated"


#: Fewest warm renders whose median is swim's time in the Monte Carlo case.
SWIM_MC_REPEATS = 15
#: swim renders after each of Monte Carlo's calls in its sweep: both renderers are then timed under the same load (the
#: shared machine's speed moves by +-30 % over minutes, which a ratio of times taken minutes apart inherits).
SWIM_MC_INTERLEAVED = 3


def run_mc(spec, probe):
    import numpy as np

    from swim.optics.volume import build_optical_volume
    from swim.validation.mitsuba import RICO_CASES, RICO_SETTINGS, mitsuba_radiance, swim_view

    case = RICO_CASES[spec["mc_case"]]
    scene = load_scene(spec)
    settings = {"allsky_size": spec["size"]}
    ms = march_settings(spec)
    sv, cold, cold_compile, _ = timed(probe, swim_view, scene, case["view"], case["sun_zenith"], settings=settings,
                                      march_settings=ms)
    # swim's ~20 ms render moves by +-30 % from call to call on a shared machine: a median of at least
    # SWIM_MC_REPEATS calls (Mitsuba's sweep keeps the suite's repeats: its calls take seconds)
    def swim_runs(count):
        return [timed(probe, swim_view, scene, case["view"], case["sun_zenith"], settings=settings,
                      march_settings=ms)[1] for _ in range(count)]

    runs = swim_runs(max(spec["repeats"], SWIM_MC_REPEATS))
    swim_px = sv["image"][:, sv["mask"]].T  # (n, 3) the compared pixels (view zenith <= 75 deg, sun excluded)
    n = swim_px.shape[0]

    volume = build_optical_volume(scene)
    args = (volume, case["sun_zenith"], RICO_SETTINGS["sun_azimuth"], sv["observer"], sv["directions"])
    cache = Path(spec["results"]) / f"mc_ref_{spec['mc_case']}_allsky{spec['size']}_spp{spec['ref_spp']}.npy"
    ref = np.load(cache) if cache.is_file() else None
    ref_s = None
    if ref is None or ref.shape != (2, n, 3):
        out = mitsuba_radiance(*args, spp=spec["ref_spp"], aerosol=sv["aerosol"], seed=1)
        ref, ref_s = np.stack([out["radiance"], out["stderr"]]), out["seconds"]
        cache.parent.mkdir(parents=True, exist_ok=True)
        np.save(cache, ref)
    reference, sigma = ref
    # "MC noise" as in docs/validation.md: the median relative standard error; it falls as spp^-1/2
    ref_noise = float(np.median(sigma / np.maximum(reference, 1e-12)))
    swim_err = image_errors(swim_px, reference, sigma)

    mitsuba_radiance(*args, spp=1, aerosol=sv["aerosol"], seed=99)  # warm-up: Dr.Jit compiles its kernels once
    sweep, spp = [], 1
    while spp <= spec["max_spp"]:
        times = []
        for k in range(spec["repeats"]):  # errors of the first run, median time of all
            t0 = time.perf_counter()
            # seeds unlike the reference's (1); Mitsuba's _trace needs seed * 1000003 < 2**32, i.e. seed < 4294
            run = mitsuba_radiance(*args, spp=spp, aerosol=sv["aerosol"], seed=100 + 20 * len(sweep) + k)
            times.append(time.perf_counter() - t0)
            runs += swim_runs(SWIM_MC_INTERLEAVED)
            out = run if k == 0 else out
        sweep.append({"spp": spp, "mc_s": statistics.median(times), "mc_runs": times,
                      **image_errors(out["radiance"], reference, sigma)})
        if sweep[-1]["mean_abs_rel_corrected"] < 0.7 * swim_err["mean_abs_rel_corrected"]:  # crossing bracketed
            break
        spp *= 2
    # swim's time: the median of its renders before the sweep and between Monte Carlo's calls
    swim_s = statistics.median(runs)
    spps = np.array([p["spp"] for p in sweep], float)
    # MC time = overhead (scene build) + cost per path: a least-squares line through the sweep
    b, a = np.polyfit(spps, [p["mc_s"] for p in sweep], 1) if len(sweep) > 1 else (sweep[0]["mc_s"] / spps[0], 0.0)

    def at(spp_star, how, **extra):
        t = max(a, 0.0) + max(b, 0.0) * spp_star
        # "ratio_paths_only": without Mitsuba's per-call overhead (it builds its scene every call, where swim's warm
        # render reuses its optical volume), the conservative figure
        return {**extra, "spp": spp_star, "how": how, "mc_s": t, "ratio": t / swim_s,
                "ratio_paths_only": max(b, 0.0) * spp_star / swim_s}

    def equal(metric):
        target = swim_err[metric]
        return at(*crossing(spps, [p[metric] for p in sweep], target), metric=metric, target=target)

    noise_spp = spec["ref_spp"] * (ref_noise / spec["noise_target"]) ** 2
    rays = spec["size"] ** 2 + 1  # swim traces the whole image; n of its pixels are compared
    return {"image": [spec["size"], spec["size"]], "grid": _grid(scene), "pixels": n, "rays": rays, "cold_s": cold,
            "warm_s": swim_s, "warm_runs": runs, "compile_est_s": cold - swim_s, "jax_compile_s": cold_compile,
            **throughput(sv["dataset"], rays, swim_s),
            "reference": {"spp": spec["ref_spp"], "seed": 1, "computed_s": ref_s, "median_rel_stderr": ref_noise,
                          "cache": str(cache.relative_to(ROOT)) if cache.is_relative_to(ROOT) else str(cache)},
            "swim_error": swim_err, "sweep": sweep, "mc_time_fit": {"overhead_s": float(a), "s_per_spp": float(b)},
            "equal_error": equal("mean_abs_rel_corrected"), "equal_error_rmse": equal("rel_rmse_corrected"),
            "equal_noise": at(noise_spp, "median rel. standard error of the reference x sqrt(ref spp / spp)",
                              metric="median_rel_stderr", target=spec["noise_target"])}


RUNNERS = {"render": run_render, "series": run_series, "flythrough": run_flythrough, "scaling_pixels": run_scaling_pixels,
           "scaling_grid": run_scaling_grid, "mc": run_mc}


def child(spec_path, out_path):
    spec = json.loads(Path(spec_path).read_text())
    result = {}
    try:
        probe = CompileProbe(spec["disk_caches"])
        result["machine"] = machine_info()
        result["march_backend"] = march_backend(spec.get("backend", "auto"))
        result["march_chunk"] = march_chunk(spec.get("backend", "auto"))
        limit_address_space(spec["mem_limit_gb"])
        result.update(RUNNERS[spec["kind"]](spec, probe))
        result["status"] = "ok"
    except BaseException as exc:  # MemoryError, missing data, API errors: the reason goes into the table
        result.update(status="not run", reason=f"{type(exc).__name__}: {exc}"[:400], traceback=traceback.format_exc()[-3000:])
    result["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    Path(out_path).write_text(json.dumps(result, default=float))


# ---------------------------------------------------------------------------------------------------------
# parent


def _tree_rss_mb(pid):
    """Resident memory [MB] of a process and its descendants (dask workers), 0 once it is gone."""
    try:
        import psutil

        p = psutil.Process(pid)
        return sum(q.memory_info().rss for q in [p, *p.children(recursive=True)]) / 2**20
    except ImportError:
        try:
            status = Path(f"/proc/{pid}/status").read_text()
            return next(int(line.split()[1]) for line in status.splitlines() if line.startswith("VmRSS")) / 1024
        except (OSError, StopIteration):
            return 0.0
    except Exception:  # psutil.NoSuchProcess and races with exiting children
        return 0.0


def run_case(spec, timeout, mem_limit_gb):
    """Run one case in a fresh process group; kill it at the timeout or when its memory passes the limit
    (a watchdog on resident memory: it also covers GPU runs, where RLIMIT_AS cannot be used)."""
    with tempfile.TemporaryDirectory(prefix="swim-bench-") as tmp:
        spec_path, out_path, log_path = (Path(tmp) / n for n in ("spec.json", "result.json", "log.txt"))
        spec_path.write_text(json.dumps(spec))
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT / "src"), os.environ.get("PYTHONPATH")])))
        if not spec["disk_caches"]:
            env["SWIM_JAX_CACHE"] = "0"  # swim's on-disk caches (compiled kernels, gas tables): a first-ever run
        with open(log_path, "w") as log:
            proc = subprocess.Popen([sys.executable, str(Path(__file__).resolve()), "--child", str(spec_path), str(out_path)],
                                    stdout=log, stderr=subprocess.STDOUT, cwd=Path(__file__).parent, env=env,
                                    start_new_session=True)
            t0, killed, peak = time.monotonic(), None, 0.0
            while proc.poll() is None:
                rss = _tree_rss_mb(proc.pid)
                peak = max(peak, rss)
                if time.monotonic() - t0 > timeout:
                    killed = f"timeout after {timeout:.0f} s"
                elif mem_limit_gb and rss > 1.05 * mem_limit_gb * 1024:  # RLIMIT_AS normally acts first (CPU)
                    killed = f"memory: resident {rss / 1024:.1f} GB passed the {mem_limit_gb:g} GB limit"
                if killed:
                    os.killpg(proc.pid, signal.SIGKILL)  # the group this call created: the child and its workers
                    proc.wait()
                    break
                time.sleep(0.2)
        wall = time.monotonic() - t0
        if out_path.is_file() and not killed:
            result = json.loads(out_path.read_text())
        else:
            tail = log_path.read_text(errors="replace").strip().splitlines()[-15:]
            if killed:
                reason = killed
            elif proc.returncode < 0:
                reason = f"killed by signal {-proc.returncode} ({signal.Signals(-proc.returncode).name})"
            else:
                reason = f"child exited with code {proc.returncode} without a result"
            result = {"status": "not run", "reason": reason, "log_tail": tail}
    result.update(case=spec["name"], kind=spec["kind"], scene=spec["scene"], wall_s=wall, peak_rss_tree_mb=peak,
                  camera={"kind": spec["camera"], **({"image": spec["image"]} if "image" in spec else {}),
                          "view": spec.get("view")},
                  spec={k: v for k, v in spec.items() if k not in ("data", "results")})
    if result.get("warm_s"):
        result["frames_per_s"] = 1.0 / result["warm_s"]
    return result


def git_info():
    def git(*a):
        r = subprocess.run(["git", "-C", str(ROOT), *a], capture_output=True, text=True)
        return r.stdout.rstrip() if r.returncode == 0 else None

    status = git("status", "--porcelain", "--untracked-files=no")
    return {"commit": git("rev-parse", "HEAD"), "branch": git("rev-parse", "--abbrev-ref", "HEAD"),
            "dirty_files": status.splitlines() if status else []}


# ---------------------------------------------------------------------------------------------------------
# table


def _f(v, fmt="{:.2f}"):
    return "–" if v is None or (isinstance(v, float) and not math.isfinite(v)) else fmt.format(v)


def _notes(r):
    if r["status"] != "ok":
        reason = " ".join(str(r["reason"]).split()).replace("|", "/")  # one table cell
        return f"not run: {reason[:160]}"
    if r["kind"] == "series":
        s = (f"{r['frames']} frames: first {r['cold_s']:.1f} s, median {r['warm_s']:.2f} s/frame, "
             f"total {r['total_s']:.0f} s")
        if "adaptive_error" in r:
            e = r["adaptive_error"]
            s += (f"; adaptive, last frame: {r['traced_pixels']:,} of {r['full_traced_pixels']:,} pixels traced, "
                  f"error against every pixel median {100 * e['median']:.2f} %, p99 {100 * e['p99']:.2f} %")
        if "distributed" in r:
            d = r["distributed"]
            s += f"; dask {d['workers']} workers: {d['s_per_frame']:.2f} s/frame"
        return s
    if r["kind"] == "flythrough":
        return (f"{r['frames']} frames {r['step_m'] / 1e3:g} km apart: first {r['cold_s']:.1f} s, median "
                f"{r['warm_s']:.2f} s/frame, mean {r['mean_frame_s']:.2f}, total {r['total_s']:.0f} s; "
                f"{r['rebuilds']} optical volumes built (new crops)")
    if r["kind"].startswith("scaling"):
        what = "pixels" if r["kind"] == "scaling_pixels" else "grid cells"
        return f"warm time ∝ {what}^{r['exponent']:.2f}"
    if r["kind"] == "mc":
        e, n = r["equal_error"], r["equal_noise"]
        return (f"MC/swim time: {e['ratio']:.3g} at equal error ({100 * e['target']:.1f} %, {e['spp']:.3g} spp; "
                f"{e.get('ratio_paths_only', float('nan')):.3g} without MC's per-call overhead), "
                f"{n['ratio']:.3g} at equal noise ({100 * n['target']:.0f} %, {n['spp']:.3g} spp)")
    adaptive = ""
    if "adaptive_error" in r:
        e = r["adaptive_error"]
        adaptive = (f"adaptive: {r['traced_pixels']:,} of {r['full_traced_pixels']:,} pixels traced, every pixel "
                    f"{r['full_warm_s']:.1f} s; error median {100 * e['median']:.2f} %, p99 {100 * e['p99']:.2f} %, "
                    f"max {100 * e['max']:.1f} %, RGB max {e['rgb_max']}")
    chunks = f" ({r['march_chunk']:,}-ray chunks)" if r.get("march_chunk") else ""
    return "; ".join(filter(None, [f"{r['march_backend']} kernel{chunks}" if r.get("march_backend") else "",
                                   f"grid {'x'.join(map(str, r['grid']))}" if r.get("grid") else "",
                                   f"scene load {r['scene_s']:.1f} s" if "scene_s" in r else "",
                                   f"render peak {r['render_peak_above_scene_mb']:,.0f} MB above the scene's "
                                   f"{r['scene_rss_mb']:,.0f}" if "render_peak_above_scene_mb" in r else "",
                                   "crop" if r.get("crop") else "",
                                   adaptive,
                                   _probe_note(r)]))


def _probe_note(r):
    """The machine probes around a case's warm renders (machine_probe.py), with the warm runs between them."""
    speed = r.get("machine_probe_ns")
    if not speed:
        return ""
    runs = ", ".join(f"{t:.2f} s" for t in r["warm_runs"])
    n = r.get("warm_fast_state_runs", 0)
    fast = (f"; {'the run' if n == 1 else f'median of the {n} runs'} between fast-state probes "
            f"{r['warm_fast_state_s']:.3f} s" if r.get("warm_fast_state_s") else "; no run between fast-state probes")
    return (f"machine probe {', '.join(f'{p:.0f}' for p in speed)} ns around the warm runs {runs} "
            f"(machine_probe.py: lower is faster){fast}")


def markdown(doc):
    m, g = doc["machine"] or {}, doc["git"]
    gpu = m.get("jax_backend") not in (None, "cpu")
    lines = [f"Benchmark suite {doc['created']}{' (--quick)' if doc['quick'] else ''}: swim {m.get('swim', '?')}, "
             f"commit {str(g['commit'])[:10]}{' + local changes' if g['dirty_files'] else ''}; "
             f"{m.get('cpu_model', '?')}, {m.get('cpu_affinity', '?')} cores, jax {m.get('jax', '?')} on "
             f"{', '.join(m.get('jax_devices', ['?']))}; persistent compilation caches "
             f"{'on' if doc.get('disk_caches') else 'off'}; total {doc['total_s']:.0f} s.", ""]
    head = ["case", "image", "rays", "cold [s]", "warm [s]", "compile est. [s]", "JAX compile [s]", "rays/s",
            "Msamples/s*", "peak RSS [MB]"] + (["frames/s"] if gpu else []) + ["notes"]
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in doc["cases"]:
        ok = r["status"] == "ok"
        img = r.get("image") or (r["camera"].get("image") if r.get("camera") else None)
        img = "–" if r["kind"] == "scaling_pixels" else f"{img[0]}x{img[1]}" if img else "–"
        cells = [r["case"], img, _f(r.get("rays"), "{:,}"), _f(r.get("cold_s")), _f(r.get("warm_s"), "{:.3f}"),
                 _f(r.get("compile_est_s")), _f(r.get("jax_compile_s")),
                 _f(r["rays_per_s"] if ok and r.get("rays_per_s") else None, "{:,.0f}"),
                 _f(r["samples_per_s"] / 1e6 if ok and r.get("samples_per_s") else None, "{:.2f}")
                 + ("†" if ok and r.get("samples_how", "").startswith("upper") else ""),
                 _f(r.get("peak_rss_mb"), "{:.0f}")] + ([_f(r.get("frames_per_s"))] if gpu else []) + [_notes(r)]
        lines.append("| " + " | ".join(cells) + " |")
    bound = next((r["samples_how"] for r in doc["cases"] if r.get("samples_how", "").startswith("upper")), None)
    lines += ["", "\\* samples = ray-march steps, the kernel's count (`march_samples` of the render output)"
              + (f"; † {bound}, where the output has no count" if bound else "") + "."]
    for r in doc["cases"]:
        if r["status"] == "ok" and r["kind"].startswith("scaling"):
            x = "pixels" if r["kind"] == "scaling_pixels" else "grid cells"
            lines += ["", f"Scaling, {r['curve']}: exponent {r['exponent']:.2f}", "",
                      f"| {x} | warm [s] | warm runs [s] | warm-ups |", "|---|---|---|---|"]
            for p in r["points"]:
                xv = f"{p['size']}x{p['size']}" if "size" in p else "x".join(map(str, p["grid"]))
                lines.append(f"| {xv} | {p['warm_s']:.3f} | {', '.join(f'{t:.3f}' for t in p['warm_runs'])} | {p['warmups']} |")
        if r["status"] == "ok" and r["kind"] == "mc":
            e, n, rm, ref, se = r["equal_error"], r["equal_noise"], r["equal_error_rmse"], r["reference"], r["swim_error"]
            lines += ["", f"Monte Carlo (Mitsuba 3) against swim, {r['spec']['mc_case']}, {r['image'][0]}x{r['image'][1]} "
                      f"all-sky, {r['pixels']} compared pixels x 3 wavelengths; reference {ref['spp']} spp (median rel. "
                      f"std. error {100 * ref['median_rel_stderr']:.2f} %); swim warm {r['warm_s']:.3f} s. Errors against "
                      "the reference, raw / corrected for the reference's own noise:", "",
                      "| renderer | spp | time [s] | mean abs. rel. error [%] | rel. RMSE [%] |", "|---|---|---|---|---|",
                      f"| swim | – | {r['warm_s']:.3f} | {100 * se['mean_abs_rel']:.2f} / {100 * se['mean_abs_rel_corrected']:.2f} | "
                      f"{100 * se['rel_rmse']:.2f} / {100 * se['rel_rmse_corrected']:.2f} |"]
            lines += [f"| MC | {p['spp']} | {p['mc_s']:.2f} | {100 * p['mean_abs_rel']:.2f} / {100 * p['mean_abs_rel_corrected']:.2f} | "
                      f"{100 * p['rel_rmse']:.2f} / {100 * p['rel_rmse_corrected']:.2f} |" for p in r["sweep"]]
            lines += ["", f"* **Equal error** (MC's corrected mean abs. rel. error = swim's {100 * e['target']:.2f} %): "
                      f"{e['spp']:.3g} spp ({e['how']}), MC {e['mc_s']:.2f} s → MC/swim time ratio **{e['ratio']:.3g}** "
                      f"({e.get('ratio_paths_only', float('nan')):.3g} without MC's per-call overhead below). "
                      f"By corrected rel. RMSE ({100 * rm['target']:.1f} %): {rm['spp']:.3g} spp ({rm['how']}), ratio "
                      f"{rm['ratio']:.3g}. swim's error is deterministic model bias, MC's is noise.",
                      f"* **Equal noise** (MC's median rel. standard error = {100 * n['target']:.0f} %): {n['spp']:.3g} spp "
                      f"(from the reference's noise, ∝ spp^-1/2), MC {n['mc_s']:.1f} s → ratio **{n['ratio']:.3g}**.",
                      f"* MC time = {r['mc_time_fit']['overhead_s']:.2f} s + {1e3 * r['mc_time_fit']['s_per_spp']:.2f} ms x spp "
                      "(least squares over the sweep; median of the repeats, after a warm-up call)."]
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="+", default=["*"], help="case names or glob patterns (default: all; see --list)")
    ap.add_argument("--quick", action="store_true",
                    help=f"smoke run: image sizes and synthetic grids / {QUICK_FACTOR} per axis, 1 warm repeat, MC reference 1024 spp")
    ap.add_argument("--repeats", type=int, default=None, help="warm renders per case (median; default 3, quick 1)")
    ap.add_argument("--timeout", type=float, default=None, help="seconds per case (default 3600, quick 900)")
    ap.add_argument("--mem-limit-gb", type=float, default=10.0, help="memory limit per case [GB] (0: none)")
    ap.add_argument("--disk-caches", action="store_true",
                    help="keep swim's and JAX's persistent caches on (cold = a new process on a used machine)")
    ap.add_argument("--data", type=Path, default=DATA, help="folder of the real data (wrf_katrina/, les/)")
    ap.add_argument("--results", type=Path, default=RESULTS,
                    help="output folder (latest.json, history.csv, MC reference cache)")
    ap.add_argument("--series-scene", choices=("katrina", "synthetic"), default="katrina",
                    help="series: Katrina with the sun moving, or the synthetic scene with advected clouds")
    ap.add_argument("--series-workers", type=int, default=0, help="series: also spread the frames over a dask LocalCluster")
    ap.add_argument("--mc-ref-spp", type=int, default=None, help="MC reference paths per pixel (default 4096, quick 1024)")
    ap.add_argument("--mc-max-spp", type=int, default=None, help="largest spp of the MC sweep (default reference spp / 4)")
    ap.add_argument("--backend", choices=("auto", "jax", "numba"), default="auto",
                    help="step-loop kernel (ExecutionSettings.backend; default: numba on CPUs, JAX on GPUs)")
    ap.add_argument("--list", action="store_true", help="list the cases and exit")
    ap.add_argument("--child", nargs=2, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        return child(*args.child)
    if args.list:
        for name, c in CASES.items():
            print(f"{name:20s} {c['kind']:15s} {c['scene']:10s} {c['camera']:10s} {c.get('image') or c.get('sizes') or c.get('size')}")
        return
    names = [n for n in CASES if any(fnmatch.fnmatch(n, p) for p in args.cases)]
    unknown = [p for p in args.cases if not any(fnmatch.fnmatch(n, p) for n in CASES)]
    if unknown or not names:
        ap.error(f"unknown cases {unknown}; choose from {list(CASES)}")
    args.repeats = args.repeats or (1 if args.quick else 3)
    timeout = args.timeout or (900.0 if args.quick else 3600.0)
    args.data, args.results = args.data.resolve(), args.results.resolve()

    t0, created = time.monotonic(), datetime.now(timezone.utc)
    import machine_probe  # benchmarks/ is on the path

    probe_reference = machine_probe.reference(PROBE_REFERENCE_S)
    print(f"machine probe: fastest {probe_reference:.1f} ns per sample in {PROBE_REFERENCE_S:g} s", file=sys.stderr,
          flush=True)
    results = []
    for name in names:
        r = run_case({**case_spec(name, args), "probe_reference_ns": probe_reference}, timeout, args.mem_limit_gb)
        results.append(r)
        state = f"warm {r['warm_s']:.3f} s" if r["status"] == "ok" and r.get("warm_s") else r["status"]
        print(f"[{time.monotonic() - t0:6.0f} s] {name}: {state} ({r['wall_s']:.0f} s)", file=sys.stderr, flush=True)
    machine = next((r.pop("machine") for r in results if r.get("machine")), None)
    for r in results:
        r.pop("machine", None)  # the same machine: stored once
    doc = {"suite": "benchmarks/bench_suite.py", "created": created.isoformat(timespec="seconds"), "quick": args.quick,
           "argv": sys.argv[1:], "repeats": args.repeats, "timeout_s": timeout, "mem_limit_gb": args.mem_limit_gb,
           "disk_caches": args.disk_caches, "machine_probe_reference_ns": probe_reference,
           "machine": machine, "git": git_info(), "total_s": time.monotonic() - t0, "cases": results}
    args.results.mkdir(parents=True, exist_ok=True)
    (args.results / "latest.json").write_text(json.dumps(doc, indent=1, default=float))
    import history  # benchmarks/ is on the path

    history.append("suite-quick" if args.quick else "suite", history.suite_rows(doc),
                   date=created.strftime("%Y-%m-%dT%H:%M:%SZ"), machine=history.machine_label(machine),
                   commit=history.commit_label(doc["git"]), source="bench_suite.py",
                   path=args.results / history.HISTORY.name)
    print(markdown(doc))


if __name__ == "__main__":
    main()
