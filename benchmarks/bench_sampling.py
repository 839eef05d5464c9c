"""Adaptive sampling's settings replayed on fully traced images: rays, samples and interpolation error per variant
(prints a table, writes JSON).

Usage::

    python benchmarks/bench_sampling.py                                   # synthetic, Katrina and RICO all-sky, 1024²
    python benchmarks/bench_sampling.py --case rico_allsky --size 256 --variant coarse_spacing=4,edge_test_size=0

Each case is rendered once with every pixel traced (the defaults of :class:`swim.rt.march.MarchSettings`; cached in
``--cache`` as ``.npz``, keyed by case and size). Each variant of :class:`swim.rt.image_sampling.AdaptiveSampling`
(``name=value`` overrides, comma-separated; ``""`` is the defaults) then runs :func:`sample_image_adaptive` with a
trace function that looks the traced pixels up in that image instead of marching them. So a variant costs seconds, and
what it reports is the sampler's alone: the pixels it traces, the march samples those pixels took (the render's
``steps``, a proxy of its time), and the interpolation's error against every pixel traced (the largest over the
three wavelengths of |L' - L'_full| / max(L'_full, 1e-3), over all valid pixels, the sky below ``--rim`` degrees of
view zenith and the rim above it), the line-of-sight hydrometeor optical depth's (floor 0.1), and the cloud pixels it
lost (optical depth > 0.3 in the full image, < a tenth of it interpolated). The march's own error, and the time, are
``bench_settings.py``'s (docs/decisions/0004-step-placement.md and docs/decisions/0005-adaptive-sampling.md).

``--device`` also replays each variant with :func:`swim.rt.image_sampling_device.sample_image_adaptive_device` (the
image's arrays, tests and interpolation on the JAX device) and compares it with the host's sampler on the same image:
the pixels that only one of them traced, each output's largest difference, and each sampler's time, taking turns
(docs/decisions/0005-adaptive-sampling.md). On a CPU that times the device sampler's JAX programs on the CPU; on a GPU
machine it is what an adaptive frame's sampling costs there.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from dataclasses import asdict
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import bench_suite  # noqa: E402  (benchmarks/ on the path first)
import bench_settings  # noqa: E402

DEFAULT_CASES = ("synthetic_allsky", "katrina_allsky", "rico_allsky")
#: The variants run when none is given: the defaults and the sampling before session 44.
DEFAULT_VARIANTS = ("", "coarse_spacing=4,edge_test_size=0,tolerance=0.01")
#: Relative error's floor of |L'_full| [-], as in bench_settings.py.
RADIANCE_FLOOR = 1e-3
#: Relative error's floor of the full image's hydrometeor optical depth along the line of sight [-].
TAU_FLOOR = 0.1
#: Optical depth [-] above which a fully traced pixel counts as cloud, for the lost cloud pixels.
CLOUD_TAU = 0.3


def parse_variant(text):
    """``"coarse_spacing=8,tolerance=0.01"`` -> AdaptiveSampling overrides (dict): ``bench_settings.parse_variant``
    with every item taken as an ``adaptive.`` one.

    Raises
    ------
    SystemExit
        If an item is not ``name=value`` or names no field of AdaptiveSampling.
    """
    items = filter(None, (part.strip() for part in text.split(",")))
    _, sampling = bench_settings.parse_variant(",".join(f"adaptive.{item}" for item in items))
    return sampling or {}


def full_image(case, size, data, cache: Path):
    """Every pixel of ``case`` traced at ``size``: dict of valid (ny, nx), radiance (n, 3), radiance_clear (n, 3), tau
    (n,), surface (n,), steps (n,) and view_zenith (ny, nx), n = ny * nx; read from ``cache`` if there (a cached
    image from before session 46, without radiance_clear, is traced again)."""
    path = cache / f"sampling-full-{case}-{size}.npz"
    if path.exists():
        with np.load(path) as f:
            if "radiance_clear" in f.files:
                return dict(f)
    import swim
    import swim.pipeline as pipeline
    from swim.rt.image_sampling import AdaptiveSampling, sample_image_adaptive

    spec = dict(bench_suite.CASES[case], data=str(data))
    if spec["scene"] == "synthetic":
        spec["scene_kwargs"] = dict(bench_suite.SYNTHETIC_GRID)
    image = (size, size // 2) if spec["camera"] == "panorama" else (size, size)
    kw = bench_suite.render_kwargs(spec, image=image)
    kw.pop("sampling", None)
    kept = {}

    def keep(trace, valid, sampling, *args, **kwargs):  # the sampler's own arrays, before the image's assembly
        values, traced = sample_image_adaptive(trace, valid, sampling, *args, **kwargs)
        kept.update(valid=valid.copy(), **{key: np.array(values[key]) for key in
                                           ("radiance", "radiance_clear", "tau_hydrometeor", "surface", "steps")})
        return values, traced

    original = pipeline.sample_image_adaptive
    pipeline.sample_image_adaptive = keep
    try:  # a coarse spacing beyond the image traces every valid pixel through the same path
        out = swim.render(bench_suite.load_scene(spec), sampling=AdaptiveSampling(coarse_spacing=10**6), **kw)
    finally:
        pipeline.sample_image_adaptive = original
    result = {"valid": kept["valid"], "radiance": kept["radiance"], "radiance_clear": kept["radiance_clear"],
              "tau": kept["tau_hydrometeor"],
              "surface": kept["surface"], "steps": kept["steps"], "view_zenith": out["view_zenith"].values}
    cache.mkdir(parents=True, exist_ok=True)
    np.savez(path, **result)
    return result


def replay(full, overrides, rim_deg):
    """Adaptive sampling with ``overrides`` on the fully traced image ``full``: its figures (dict)."""
    from swim.rt.image_sampling import AdaptiveSampling, sample_image_adaptive

    radiance, tau, surface, steps = full["radiance"], full["tau"], full["surface"], full["steps"]

    def trace(flat):
        return {"radiance": radiance[flat], "radiance_clear": full["radiance_clear"][flat],
                "tau_hydrometeor": tau[flat], "surface": surface[flat], "steps": steps[flat]}

    sampling = AdaptiveSampling(**overrides)
    values, traced = sample_image_adaptive(trace, full["valid"], sampling)
    traced = traced.reshape(-1)
    valid = full["valid"].reshape(-1)
    zenith = full["view_zenith"].reshape(-1)
    rel = np.max(np.abs(values["radiance"] - radiance) / np.maximum(np.abs(radiance), RADIANCE_FLOOR), axis=1)
    tau_rel = np.abs(values["tau_hydrometeor"] - tau) / np.maximum(tau, TAU_FLOOR)

    def zone(values, mask):
        v = values[mask]
        return {"pixels": int(v.size), "p99": float(100 * np.percentile(v, 99)),
                "p999": float(100 * np.percentile(v, 99.9)), "max": float(100 * v.max())} if v.size else {"pixels": 0}

    return {"sampling": asdict(sampling), "traced_pixels": int(traced.sum()),
            "march_samples": int(steps[traced].sum()),
            "error_pct": {"all": zone(rel, valid), "sky": zone(rel, valid & (zenith < rim_deg)),
                          "rim": zone(rel, valid & (zenith >= rim_deg))},
            "tau_error_pct": zone(tau_rel, valid),
            "lost_cloud_pixels": int(np.count_nonzero(valid & (tau > CLOUD_TAU)
                                                      & (values["tau_hydrometeor"] < 0.1 * tau)))}


def compare_device(full, overrides, repeats=5):
    """The host's sampler and :func:`swim.rt.image_sampling_device.sample_image_adaptive_device` replayed on the
    fully traced image ``full`` with ``overrides``, taking turns: each one's best and median time [s] (after one
    warm-up; the device's outputs waited for), the pixels each traced, the pixels traced by one only, and the largest
    difference of each output between the two (dict)."""
    import time

    import jax

    from swim.rt.image_sampling import AdaptiveSampling, sample_image_adaptive
    from swim.rt.image_sampling_device import sample_image_adaptive_device

    arrays = {"radiance": full["radiance"], "radiance_clear": full["radiance_clear"],
              "tau_hydrometeor": full["tau"], "surface": full["surface"], "steps": full["steps"]}
    on_device = {key: jax.device_put(value) for key, value in arrays.items()}

    def host_trace(flat):
        return {key: value[flat] for key, value in arrays.items()}

    def device_trace(flat):  # as the ray table's march returns them: on the device
        index = jax.device_put(flat)
        return {key: value[index] for key, value in on_device.items()}

    sampling = AdaptiveSampling(**overrides)

    def host():
        return sample_image_adaptive(host_trace, full["valid"], sampling, max_threads=8, outside=np.nan)

    def device():
        values, traced = sample_image_adaptive_device(device_trace, full["valid"], sampling, outside=np.nan)
        jax.block_until_ready((values, traced))
        return values, traced

    times = {"host": [], "device": []}
    results = {}
    for repeat in range(repeats + 1):
        for name, run in (("host", host), ("device", device)):
            t0 = time.perf_counter()
            results[name] = run()
            if repeat:
                times[name].append(time.perf_counter() - t0)
    (hv, ht), (dv, dt) = results["host"], results["device"]
    ht, dt = np.asarray(ht).reshape(-1), np.asarray(dt).reshape(-1)
    differences = {}
    for key, value in hv.items():
        a = np.asarray(value).reshape(value.shape[0], -1)
        b = np.asarray(dv[key])
        if a.dtype.kind == "f":
            same_nan = bool(np.array_equal(np.isnan(a), np.isnan(b)))
            differences[key] = float(np.nanmax(np.abs(a - b) / np.maximum(np.abs(a), 1e-3))) if same_nan else "NaNs differ"
        else:
            differences[key] = int(np.count_nonzero(a != b))
    return {"sampling": asdict(sampling), "host_s": [min(times["host"]), float(np.median(times["host"]))],
            "device_s": [min(times["device"]), float(np.median(times["device"]))], "backend": jax.default_backend(),
            "traced_host": int(ht.sum()), "traced_device": int(dt.sum()), "traced_by_one": int(np.count_nonzero(ht != dt)),
            "largest_difference": differences}


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--case", action="append", default=None,
                        choices=sorted(k for k, v in bench_suite.CASES.items() if v["kind"] == "render"))
    parser.add_argument("--size", type=int, default=1024,
                        help="image width [pixels] (panoramas: height = width / 2; other cameras: square)")
    parser.add_argument("--variant", action="append", default=None,
                        help="AdaptiveSampling overrides (repeatable; see above)")
    parser.add_argument("--rim", type=float, default=72.0, help="view zenith [deg] between the sky and the rim zones")
    parser.add_argument("--data", type=Path, default=bench_suite.DATA)
    parser.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "swim-bench-sampling",
                        help="folder of the fully traced images (.npz, ~30 MB each at 1024²)")
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--device", action="store_true",
                        help="also replay each variant with the sampler on the device (JAX) and compare it with the "
                             "host's: traced pixels, outputs and time (compare_device)")
    parser.add_argument("--repeats", type=int, default=5, help="timed replays of each sampler with --device")
    args = parser.parse_args()

    variants = {text: parse_variant(text) for text in (args.variant if args.variant is not None else DEFAULT_VARIANTS)}
    results = {}

    def cell(e):
        return f"{e['p99']:.2f} / {e['p999']:.2f} / {e['max']:.1f}" if e.get("pixels") else "-"

    print("interpolation error [%] against every pixel traced: 99th / 99.9th percentile / max\n")
    print("| case | variant | traced pixels | samples [10^6] | all | sky | rim | tau_hydrometeor | lost cloud px |")
    print("|---|---|---|---|---|---|---|---|---|")
    for case in args.case or DEFAULT_CASES:
        full = full_image(case, args.size, args.data, args.cache)
        for text, overrides in variants.items():
            r = replay(full, overrides, args.rim)
            results.setdefault(case, {})[text] = r
            e = r["error_pct"]
            print(f"| {case} | {text or 'defaults'} | {r['traced_pixels']} | {r['march_samples'] / 1e6:.2f} | "
                  f"{cell(e['all'])} | {cell(e['sky'])} | {cell(e['rim'])} | {cell(r['tau_error_pct'])} | "
                  f"{r['lost_cloud_pixels']} |", flush=True)
            if args.device:
                c = compare_device(full, overrides, args.repeats)
                r["device"] = c
                print(f"|  | device sampler ({c['backend']}) | {c['traced_device']} ({c['traced_by_one']} traced by "
                      f"one sampler only) | host {c['host_s'][1]:.3f} s, device {c['device_s'][1]:.3f} s (medians) | "
                      f"largest difference: {c['largest_difference']} |||||", flush=True)

    stamp = datetime.now(timezone.utc).strftime("%Y-%m-%dT%H%M%SZ")
    path = args.out or ROOT / "benchmarks" / "results" / f"sampling-{args.size}-{stamp}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"size": args.size, "rim_deg": args.rim, "cases": results}, indent=1))
    print(f"\nwritten: {path}")


if __name__ == "__main__":
    main()
