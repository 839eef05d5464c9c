"""Speed against accuracy of march and sampling settings: each variant's warm time, samples per ray and error
against a fine reference, by zone of view zenith (prints a table, writes JSON).

Usage::

    python benchmarks/bench_settings.py                                             # synthetic 512², a few variants
    python benchmarks/bench_settings.py --case rico_allsky --size 255 --variant n_grid=96 --variant tau_refine=0.5
    python benchmarks/bench_settings.py --size 1024 --adaptive --variant "" --variant n_grid=96,tau_refine=0.5
    python benchmarks/bench_settings.py --variant adaptive.tolerance=0.02 --variant adaptive.tau_floor=1e9

A variant is a comma-separated list of ``name=value`` overrides of :class:`swim.rt.march_settings.MarchSettings` (``n_grid=96``)
or, prefixed with ``adaptive.``, of :class:`swim.rt.image_sampling.AdaptiveSampling` (``adaptive.tolerance=0.02``;
such a variant renders adaptively); ``""`` is the defaults. ``--adaptive`` renders every variant adaptively.

The scene and view are the suite's (``bench_suite.CASES``: ``synthetic_allsky`` is the 400 x 400 x 60 grid with all
five species and terrain, seen from 2 m). The reference is one render of every pixel with ``--reference`` settings
(default ``n_grid=1024,tau_refine=0.25``: the march converged to ~0.1 % in the median,
docs/decisions/0002-per-ray-cpu-kernel.md and docs/decisions/0004-step-placement.md). Each variant is rendered once to
warm up, then ``--repeats`` times, the variants taking turns so that the machine's drift (±15-25 % on this project's
shared 2-core machine) falls on all of them alike; its time is the median. The error of a pixel is the largest over the
three wavelengths of |L' - L'_ref| / max(|L'_ref|, 1e-3), reported as median / 99th / 99.9th percentile over all valid
pixels, over those below a view zenith of ``--rim`` degrees (the sky overhead) and over those above it (the horizon's
ring, where an all-sky image's rays are longest and most of the error lies). The hydrometeor optical depth along the
line of sight (``tau_hydrometeor``, which adaptive sampling interpolates too) is compared the same way, with a floor of
0.1. Results go to ``benchmarks/results/settings-latest.json`` (``--out`` to change) and each variant's time, pixels,
samples and 99th percentile errors to ``benchmarks/results/history.csv``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from dataclasses import asdict, fields
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import bench_suite  # noqa: E402  (benchmarks/ on the path first)

#: Variants run when none is given: the defaults, fewer grid steps, and coarser cloud-face refinement.
DEFAULT_VARIANTS = ("", "n_grid=96", "n_grid=64", "tau_refine=0.5", "n_grid=96,tau_refine=0.5")
#: Settings of the reference render.
DEFAULT_REFERENCE = "n_grid=1024,tau_refine=0.25"
#: Relative error's floor of |L'_ref| [-], as in the suite's adaptive cases.
RADIANCE_FLOOR = 1e-3
#: Relative error's floor of the reference's hydrometeor optical depth along the line of sight [-]: a cloud's edge
#: where it starts to show.
TAU_FLOOR = 0.1


def _value(text):
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return {"true": True, "false": False, "none": None}.get(text.lower(), text)


def parse_variant(text):
    """``"n_grid=96,adaptive.tolerance=0.02"`` -> (MarchSettings overrides, AdaptiveSampling overrides or None).

    Raises
    ------
    SystemExit
        If an item is not ``name=value`` or names no field of either settings class.
    """
    from swim.rt.image_sampling import AdaptiveSampling
    from swim.rt.march_settings import MarchSettings

    march_names = {f.name for f in fields(MarchSettings)}
    sampling_names = {f.name for f in fields(AdaptiveSampling)}
    march, sampling = {}, None
    for item in filter(None, (part.strip() for part in text.split(","))):
        name, sep, value = item.partition("=")
        if not sep:
            raise SystemExit(f"variant item {item!r} is not name=value")
        if name.startswith("adaptive."):
            if name[9:] not in sampling_names:
                raise SystemExit(f"{name!r}: AdaptiveSampling has no field {name[9:]!r} ({sorted(sampling_names)})")
            sampling = {**(sampling or {}), name[9:]: _value(value)}
        elif name in march_names:
            march[name] = _value(value)
        else:
            raise SystemExit(f"{name!r}: MarchSettings has no field {name!r} ({sorted(march_names)})")
    return march, sampling


def zone_errors(image, reference, view_zenith, rim_deg, floor=RADIANCE_FLOOR):
    """Median, 99th and 99.9th percentile [%] of the relative error (the largest over the channels) over all valid
    pixels, below and above the view zenith ``rim_deg`` [deg]; ``image`` and ``reference`` (c, ny, nx) or (ny, nx),
    ``view_zenith`` (ny, nx); the reference's absolute values below ``floor`` count as ``floor``."""
    if image.ndim == 2:  # one channel
        image, reference = image[None], reference[None]
    rel = np.max(np.abs(image - reference) / np.maximum(np.abs(reference), floor), axis=0)
    ok = np.isfinite(rel) & np.isfinite(view_zenith)
    out = {}
    for zone, mask in (("all", ok), ("sky", ok & (view_zenith < rim_deg)), ("rim", ok & (view_zenith >= rim_deg))):
        values = rel[mask]
        out[zone] = ({"pixels": int(values.size), "median": float(100 * np.median(values)),
                      "p99": float(100 * np.percentile(values, 99)), "p999": float(100 * np.percentile(values, 99.9))}
                     if values.size else {"pixels": 0})
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--case", default="synthetic_allsky",
                        choices=sorted(k for k, v in bench_suite.CASES.items() if v["kind"] == "render"))
    parser.add_argument("--size", type=int, default=512,
                        help="image width [pixels] (panoramas: height = width / 2; other cameras: square)")
    parser.add_argument("--variant", action="append", default=None, help="settings overrides (repeatable; see above)")
    parser.add_argument("--reference", default=DEFAULT_REFERENCE, help="settings overrides of the reference render")
    parser.add_argument("--adaptive", action="store_true", help="render every variant with adaptive sampling")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--rim", type=float, default=72.0, help="view zenith [deg] between the sky and the rim zones")
    parser.add_argument("--data", type=Path, default=bench_suite.DATA)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()

    import swim
    from swim.rt.image_sampling import AdaptiveSampling
    from swim.rt.march_settings import MarchSettings

    spec = dict(bench_suite.CASES[args.case], data=str(args.data))
    if spec["scene"] == "synthetic":
        spec["scene_kwargs"] = dict(bench_suite.SYNTHETIC_GRID)
    image = (args.size, args.size // 2) if spec["camera"] == "panorama" else (args.size, args.size)
    kw = bench_suite.render_kwargs(spec, image=image)
    kw.pop("settings", None)  # each variant's own
    kw.pop("sampling", None)
    variants = {text: parse_variant(text) for text in (args.variant if args.variant is not None else DEFAULT_VARIANTS)}
    ref_march, _ = parse_variant(args.reference)

    scene = bench_suite.load_scene(spec)
    t0 = time.perf_counter()
    reference = swim.render(scene, settings=MarchSettings(**ref_march), **kw)
    ref_s = time.perf_counter() - t0
    ref_radiance, view_zenith = reference["radiance"].values, reference["view_zenith"].values
    ref_tau = reference["tau_hydrometeor"].values
    print(f"{args.case} {image[0]} x {image[1]}: reference ({args.reference}) {ref_s:.1f} s, "
          f"{reference.attrs['march_samples'] / max(reference.attrs['traced_pixels'], 1):.1f} samples per ray", flush=True)

    def settings_of(text):
        march, sampling = variants[text]
        if sampling is None and args.adaptive:
            sampling = {}
        return MarchSettings(**march), (None if sampling is None else AdaptiveSampling(**sampling))

    results = {}
    for text in variants:  # warm-up and the error (the render is deterministic: one suffices)
        settings, sampling = settings_of(text)
        out = swim.render(scene, settings=settings, sampling=sampling, **kw)
        results[text] = {"march_settings": asdict(settings), "sampling": None if sampling is None else asdict(sampling),
                         "traced_pixels": int(out.attrs["traced_pixels"]),
                         "samples_per_ray": float(out.attrs["march_samples"] / max(out.attrs["traced_pixels"], 1)),
                         "error_pct": zone_errors(out["radiance"].values, ref_radiance, view_zenith, args.rim),
                         "tau_error_pct": zone_errors(out["tau_hydrometeor"].values, ref_tau, view_zenith, args.rim,
                                                      TAU_FLOOR),
                         "times_s": []}
    for _ in range(args.repeats):  # the variants take turns
        for text in variants:
            settings, sampling = settings_of(text)
            t0 = time.perf_counter()
            swim.render(scene, settings=settings, sampling=sampling, **kw)
            results[text]["times_s"].append(time.perf_counter() - t0)
    for r in results.values():
        r["warm_s"] = statistics.median(r["times_s"])

    def cell(e):
        return f"{e['median']:.3f} / {e['p99']:.2f} / {e['p999']:.1f}" if e.get("pixels") else "-"

    print(f"\nerror [%]: median / 99th / 99.9th percentile against the reference; sky: view zenith < {args.rim:g} deg\n")
    print("| variant | warm [s] | traced pixels | samples/ray | all | sky | rim | tau_hydrometeor, all |")
    print("|---|---|---|---|---|---|---|---|")
    for text, r in results.items():
        e = r["error_pct"]
        print(f"| {text or 'defaults'}{' (adaptive)' if r['sampling'] is not None else ''} | {r['warm_s']:.2f} | "
              f"{r['traced_pixels']} | {r['samples_per_ray']:.1f} | {cell(e['all'])} | {cell(e['sky'])} | {cell(e['rim'])} "
              f"| {cell(r['tau_error_pct']['all'])} |")

    path = args.out or ROOT / "benchmarks" / "results" / "settings-latest.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    doc = {"case": args.case, "image": list(image), "reference": args.reference, "reference_s": ref_s,
           "rim_deg": args.rim, "repeats": args.repeats, "variants": results}
    path.write_text(json.dumps(doc, indent=1))
    import history  # benchmarks/ is on the path

    history.append("settings", history.settings_rows(doc), source="bench_settings.py")
    print(f"\nwritten: {path}, {history.HISTORY}")


if __name__ == "__main__":
    main()
