"""Night and twilight renders against a day render: the speed of ``light="moon"`` and ``light="sun+moon"``.

Usage::

    python benchmarks/bench_night.py                                  # built-in scene and Katrina, all-sky 255
    python benchmarks/bench_night.py --scenes default --size 127 --repeats 5
    python benchmarks/bench_night.py --profile twilight_sun_moon      # where that case's time goes (cProfile)

For each scene, one all-sky view (the scene's reference point, or the suite's Katrina vantage, 2 m above the
ground) rendered at a few times (UTC), chosen for where the sun and the moon stand there:

========================  =====================  =======================================================
case                      light                  time
========================  =====================  =======================================================
``day``                   sun                    the sun 34-35 deg up
``night_moon``            moon                   the sun below -18 deg (astronomical night), the moon up
``twilight_sun_moon``     sun+moon               the sun 4 deg below the horizon, the moon up
``twilight_sun``          sun                    the same twilight, the sun alone
``night_sun_moon``        sun+moon               the night's time: only the moon is marched
``day_sun_moon``          sun+moon               the day's time: both marched where the moon is up (above -8 deg)
========================  =====================  =======================================================

Each case is timed two ways, in one process after a warm-up render of every case (the kernels compiled, the scene's
optical volume built):

* ``same_frame_s``: the median of ``--repeats`` renders of the same frame, each right after an untimed one of it:
  what a render costs when it repeats its frame (a camera moved, an exposure changed). The stage cache keeps one
  light's Step 1a and tables (swim.pipeline.tables), so a sun+moon render builds both lights' every time.
* ``new_frame_s``: the median of ``--repeats`` renders of new frames (the time moved on by a minute each, the
  cases taking turns): each light's Step 1a and tables built anew, as in a time series.

with the fastest of the runs too (``*_min_s``: on a machine shared with other work the median wanders), the same
frame's CPU time (``same_frame_cpu_s``, every thread's: less swayed by other processes than the wall time), the
volume samples of the case's marches (``march_samples``, the image's attribute: the march's work, which the machine's
load does not change), and the ratio of each to the day render's, against the goals: the moon alone <= 1x a day
render of the same view, sun and moon together <= 2x, twilight (the sun alone) <= 1.5x. Results go to
``results/night-latest.json`` (overwritten) and the ratios to ``results/history.csv`` (kind ``night``, appended;
``history.py``); a Markdown table is printed.
"""

from __future__ import annotations

import argparse
import cProfile
import io
import json
import logging
import pstats
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import history  # noqa: E402  (benchmarks/)
from scenes import katrina_scene  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"
DATA = ROOT.parent / "shared" / "data"

#: The views and times (UTC) of each scene: the place and the moments where the sun and the moon stand as the cases
#: need (checked at the start, :func:`check_times`). The built-in scene: a waxing crescent (14-22 % lit); Katrina:
#: a waning moon (32 % lit). The day's moon is up at both: 2.4 deg (the built-in scene), 77 deg (Katrina).
SCENES = {
    "default": {"view": {"height": 2.0}, "place": (40.0, -105.3),
                "times": {"day": "2023-06-21T14:48Z", "twilight": "2023-06-22T02:54Z", "night": "2023-06-23T05:00Z"}},
    "katrina": {"view": {"lat": 24.7, "lon": -88.6, "height": 2.0}, "place": (24.7, -88.6),
                "times": {"day": "2005-08-28T14:12Z", "twilight": "2005-08-28T11:20Z", "night": "2005-08-28T08:38Z"}},
}
#: (case, light, time's name)
CASES = (("day", "sun", "day"), ("night_moon", "moon", "night"), ("twilight_sun_moon", "sun+moon", "twilight"),
         ("twilight_sun", "sun", "twilight"), ("night_sun_moon", "sun+moon", "night"),
         ("day_sun_moon", "sun+moon", "day"))
#: The speed goals: the case's time at most this many times the day render's.
GOALS = {"night_moon": 1.0, "twilight_sun_moon": 2.0, "twilight_sun": 1.5, "night_sun_moon": 1.0, "day_sun_moon": 2.0}


def check_times(place, times):
    """The sun's and the moon's elevations [deg] at each time; raises if a time does not fit its case."""
    from swim.geometry.moon import moon_position
    from swim.geometry.sun import sun_position

    out = {}
    for name, when in times.items():
        sun = sun_position(when, *place).elevation_deg
        moon = 90.0 - moon_position(when, *place).zenith_deg
        out[name] = {"sun_elevation_deg": round(sun, 2), "moon_elevation_deg": round(moon, 2)}
    assert 30 <= out["day"]["sun_elevation_deg"] <= 40, out
    assert -4.5 <= out["twilight"]["sun_elevation_deg"] <= -3.5 and out["twilight"]["moon_elevation_deg"] > 10, out
    assert out["night"]["sun_elevation_deg"] < -18 and out["night"]["moon_elevation_deg"] > 5, out
    return out


def render_once(scene, view, size, light, when):
    """One render's wall time [s], the lights it marched, the volume samples of its marches (``march_samples``: the
    work, whatever else the machine does) and its CPU time [s] (every thread of this process's)."""
    import swim

    t0, c0 = time.perf_counter(), time.process_time()
    image = swim.render(scene, time=when, light=light, camera="allsky", camera_options={"size": size},
                        white_level="auto", **view)
    return (time.perf_counter() - t0, image.attrs.get("lights", "moon" if light == "moon" else "sun"),
            int(image.attrs["march_samples"]), time.process_time() - c0)


def bench_scene(name, scene, size, repeats):
    """The cases of one scene: their times the two ways (module docstring) and the ratios to the day's."""
    spec = SCENES[name]
    lights, samples = {}, {}
    for case, light, when in CASES:  # warm-up: compiled kernels, the optical volume, the diffuse solutions
        _, lights[case], samples[case], _ = render_once(scene, spec["view"], size, light, spec["times"][when])
    same, new, same_cpu = ({case: [] for case, _, _ in CASES} for _ in range(3))
    for k in range(1, repeats + 1):  # the cases take turns, so that the machine's load falls on each alike
        for case, light, when in CASES:
            render_once(scene, spec["view"], size, light, spec["times"][when])  # its frame's stages into the cache
            wall, _, _, cpu = render_once(scene, spec["view"], size, light, spec["times"][when])
            same[case].append(wall)
            same_cpu[case].append(cpu)
        for case, light, when in CASES:
            moved = (pd.Timestamp(spec["times"][when]) + pd.Timedelta(minutes=k)).isoformat()
            new[case].append(render_once(scene, spec["view"], size, light, moved)[0])
    rows = {}
    for case, light, when in CASES:
        same_s, new_s = statistics.median(same[case]), statistics.median(new[case])
        rows[case] = {"light": light, "time": spec["times"][when], "lights_marched": lights[case],
                      "march_samples": samples[case],
                      "same_frame_s": same_s, "same_frame_min_s": min(same[case]), "same_frame_runs": same[case],
                      "same_frame_cpu_s": statistics.median(same_cpu[case]), "same_frame_cpu_runs": same_cpu[case],
                      "new_frame_s": new_s, "new_frame_min_s": min(new[case]), "new_frame_runs": new[case]}
    for case, row in rows.items():
        row["march_samples_ratio"] = row["march_samples"] / rows["day"]["march_samples"]
        row["same_frame_cpu_ratio"] = row["same_frame_cpu_s"] / rows["day"]["same_frame_cpu_s"]
        for way in ("same_frame", "new_frame"):
            row[f"{way}_ratio"] = row[f"{way}_s"] / rows["day"][f"{way}_s"]
            row[f"{way}_min_ratio"] = row[f"{way}_min_s"] / rows["day"][f"{way}_min_s"]
        row["goal_ratio"] = GOALS.get(case)
    return rows


def profile_case(scene, name, case, size):
    """cProfile of one warm render of ``case`` (its frame rendered once before): the top functions by cumulative
    time, as text."""
    spec = SCENES[name]
    light, when = {c: (lt, w) for c, lt, w in CASES}[case]
    render_once(scene, spec["view"], size, light, spec["times"][when])
    profiler = cProfile.Profile()
    profiler.enable()
    render_once(scene, spec["view"], size, light, spec["times"][when])
    profiler.disable()
    text = io.StringIO()
    pstats.Stats(profiler, stream=text).sort_stats("cumulative").print_stats(30)
    return text.getvalue()


def table(results):
    lines = ["| scene | case | light | lights marched | same frame [s] | ratio | ratio of fastest | CPU ratio | "
             "new frame [s] | ratio | ratio of fastest | samples ratio | goal |", "| --- " * 13 + "|"]
    for scene, rows in results.items():
        for case, r in rows.items():
            goal = "" if r["goal_ratio"] is None else f"<= {r['goal_ratio']:g}"
            lines.append(f"| {scene} | {case} | {r['light']} | {r['lights_marched']} | {r['same_frame_s']:.3f} | "
                         f"{r['same_frame_ratio']:.2f} | {r['same_frame_min_ratio']:.2f} | "
                         f"{r['same_frame_cpu_ratio']:.2f} | {r['new_frame_s']:.3f} | "
                         f"{r['new_frame_ratio']:.2f} | {r['new_frame_min_ratio']:.2f} | "
                         f"{r['march_samples_ratio']:.2f} | {goal} |")
    return "\n".join(lines)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", nargs="+", default=list(SCENES), choices=list(SCENES))
    parser.add_argument("--size", type=int, default=255, help="all-sky image size [pixels] (default 255)")
    parser.add_argument("--repeats", type=int, default=3, help="timed renders per case and way (default 3)")
    parser.add_argument("--data", type=Path, default=DATA, help="the shared data (wrf_katrina/)")
    parser.add_argument("--out", type=Path, default=RESULTS / "night-latest.json")
    parser.add_argument("--no-history", action="store_true", help="do not append to results/history.csv")
    parser.add_argument("--profile", metavar="CASE", choices=[c for c, _, _ in CASES],
                        help="print a cProfile of one warm render of CASE per scene instead of timing")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)
    import swim

    results, elevations, profiles = {}, {}, {}
    for name in args.scenes:
        scene = swim.default_scene() if name == "default" else katrina_scene(args.data)
        elevations[name] = check_times(SCENES[name]["place"], SCENES[name]["times"])
        if args.profile:
            profiles[name] = profile_case(scene, name, args.profile, args.size)
            print(f"## {name}: {args.profile}\n{profiles[name]}")
            continue
        results[name] = bench_scene(name, scene, args.size, args.repeats)
        print(table({name: results[name]}), flush=True)
    if args.profile:
        return 0
    doc = {"created": history.now(), "argv": sys.argv[1:], "size": args.size, "repeats": args.repeats,
           "machine": history.machine_label(), "commit": history.commit_label(), "elevations": elevations,
           "results": results}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(doc, indent=1, default=float))
    print(f"\n{table(results)}\n\nwrote {args.out}")
    if not args.no_history:
        rows = [(f"{scene}_{case}", figure, r[figure], unit) for scene, rs in results.items() for case, r in rs.items()
                for figure, unit in (("same_frame_s", "s"), ("new_frame_s", "s"), ("same_frame_ratio", "1"),
                                     ("new_frame_ratio", "1"), ("same_frame_min_ratio", "1"),
                                     ("new_frame_min_ratio", "1"), ("march_samples_ratio", "1"),
                                     ("same_frame_cpu_ratio", "1"))]
        history.append("night", rows, date=doc["created"], source="bench_night.py")
    return 0 if np.isfinite([r["same_frame_s"] for rs in results.values() for r in rs.values()]).all() else 1


if __name__ == "__main__":
    sys.exit(main())
