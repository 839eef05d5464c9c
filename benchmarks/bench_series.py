"""Frames per second of a time series (swim.series.render_series): in one process, and on local dask workers.

Usage: ``python benchmarks/bench_series.py [--data ../shared/data] [--scene katrina|default] [--frames 12]
[--size 255] [--workers 2]``

Prints one line per way of running the series: its wall time, the frames per second, and the median time of a
frame after each process's first (which loads the kernels). Each way writes its PNGs to a temporary folder.
"""

from __future__ import annotations

import argparse
import logging
import statistics
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def scene_and_site(name, data):
    import swim

    if name == "default":
        return swim.default_scene(), {}, "2023-06-21T15:00"
    scene = swim.open_scene(Path(data) / "wrf_katrina" / "ci_test_file.nc", time="2005-08-28T18:00")
    return scene, {"lat": 24.7, "lon": -88.6, "height": 2.0}, "2005-08-28T15:00"


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=str(ROOT.parent / "shared" / "data"))
    parser.add_argument("--scene", default="katrina", choices=["katrina", "default"])
    parser.add_argument("--frames", type=int, default=12)
    parser.add_argument("--size", type=int, default=255)
    parser.add_argument("--every", type=float, default=10.0, help="minutes between frames")
    parser.add_argument("--workers", type=int, nargs="*", default=[2])
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING)
    import pandas as pd

    from swim.series import render_series, series_times

    scene, site, start = scene_and_site(args.scene, args.data)
    end = pd.Timestamp(start) + pd.Timedelta(minutes=args.every * (args.frames - 1))
    times = series_times(start, end, args.every)
    print(f"{args.scene}: {len(times)} all-sky frames of {args.size}^2, {start} every {args.every:g} min")
    for workers in [0, *args.workers]:
        with tempfile.TemporaryDirectory() as folder:
            t0 = time.perf_counter()
            table = render_series(scene, times, out=Path(folder) / "{index:03d}.png", workers=workers or None,
                                  camera_options={"size": args.size}, **site)
            wall = time.perf_counter() - t0
        later = table[table["worker"].duplicated()]["seconds"]  # each process's frames after its first
        how = "this process" if not workers else f"{workers} worker processes"
        print(f"  {how:20s} wall {wall:6.1f} s  {len(times) / wall:5.2f} frames/s  "
              f"frame after the first {statistics.median(later):5.2f} s (median)  first {table['seconds'].iloc[0]:5.2f} s")


if __name__ == "__main__":
    main()
