"""Wall time and peak memory of typical renders (prints a table; not a test).

Usage: ``python benchmarks/bench_render.py [--data ../shared/data] [--cases NAME ...]``

Each case runs in a fresh subprocess so that its peak resident memory (``ru_maxrss``) is its own. Times:
``cold`` includes JIT compilation (first render in the process), ``warm`` is a second identical render.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

CASES = {
    "default_allsky_511": ("default", "allsky", {"size": 511}),
    "default_panorama_1024x512": ("default", "panorama", {"width": 1024, "height": 512}),
    "katrina_allsky_511": ("katrina", "allsky", {"size": 511}),
    "katrina_panorama_1024x512": ("katrina", "panorama", {"width": 1024, "height": 512}),
}

CHILD = r"""
import json, resource, sys, time
import swim
spec = json.loads(sys.argv[1])
if spec["scene"] == "default":
    scene, kw = swim.default_scene(), {}
else:
    scene = swim.open_scene(spec["data"] + "/wrf_katrina/ci_test_file.nc", time="2005-08-28T18:00")
    kw = {"lat": 24.7, "lon": -88.6, "height": 2.0}
times = []
for _ in range(2):
    t0 = time.perf_counter()
    image = swim.render(scene, camera=spec["camera"], camera_options=spec["options"], **kw)
    times.append(time.perf_counter() - t0)
ny, nx = image["rgb"].shape[:2]
print(json.dumps({"cold_s": times[0], "warm_s": times[1], "pixels": ny * nx,
                  "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=str(ROOT.parent / "shared" / "data"))
    parser.add_argument("--cases", nargs="*", default=list(CASES))
    args = parser.parse_args(argv)
    print(f"{'case':32s} {'cold [s]':>9s} {'warm [s]':>9s} {'Mray/s':>8s} {'peak RSS [MB]':>14s}")
    results = {}
    for name in args.cases:
        scene, camera, options = CASES[name]
        spec = json.dumps({"scene": scene, "camera": camera, "options": options, "data": args.data})
        proc = subprocess.run([sys.executable, "-c", CHILD, spec], capture_output=True, text=True, check=True)
        r = json.loads(proc.stdout.strip().splitlines()[-1])
        results[name] = r
        print(f"{name:32s} {r['cold_s']:9.2f} {r['warm_s']:9.2f} {r['pixels'] / r['warm_s'] / 1e6:8.3f} {r['peak_rss_mb']:14.0f}")
    # Cases not run this time keep their previous figures.
    path = ROOT / "benchmarks" / "results.json"
    previous = json.loads(path.read_text()) if path.is_file() else {}
    path.write_text(json.dumps({**previous, **results}, indent=2))


if __name__ == "__main__":
    main()
