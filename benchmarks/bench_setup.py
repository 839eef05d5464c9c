"""The set-up of a new scene and a new sun, stage by stage (prints a table): what a forecast's next hour costs
before the march.

Usage::

    python benchmarks/bench_setup.py                       # the suite's synthetic 400 x 400 x 60 scene, 5 repeats
    python benchmarks/bench_setup.py --grid 200 --repeats 9
    PYTHONPATH=/tmp/old-worktree/src python benchmarks/bench_setup.py   # another checkout's code, to alternate

Each repeat builds, from the same scene as given, what :func:`swim.render` builds for a scene it has not seen:
the validated scene (:func:`swim.io.scene.validate_scene`, a float64 copy of every field and its checks), the optical
volume (Eq. 7 and the resampling onto regular levels, :func:`swim.optics.volume.build_optical_volume`),
the packed volume that the kernels read (:func:`swim.rt.march_inputs.pack_volume`, its channels then shared with the
optical volume), the occupancy grid of the empty-space skipping (:func:`swim.rt.march_inputs.occupancy_grid`) and Step 1a
for one sun (:func:`swim.rt.solar.solar_transmittance`, the fields the kernels read, in the packed volume's
channels: :func:`swim.rt.march_inputs.volume_constants`; its swept levels, :func:`swim.rt.solar.step1a_levels`, found
before the packing as a render finds them). It prints the best and the
median of each stage over the repeats after a first, warm-up one (numba's kernels loaded, NumPy's pools made). On
this project's shared 2-core machine alternate runs of the two codes: a figure moves by 10-20 % from hour to hour
(docs/decisions/0007-scene-set-up.md).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

STAGES = ("validation", "optical volume", "packing", "occupancy grid", "Step 1a and its channels", "all five")


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--grid", type=int, default=400, help="columns per axis of the synthetic scene (60 levels, 1 km)")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--sun-zenith", type=float, default=21.2, help="[deg]")
    parser.add_argument("--sun-azimuth", type=float, default=56.3, help="[deg] clockwise from north")
    args = parser.parse_args()

    import scenes

    import swim
    from swim.frames import enu_from_azimuth_zenith
    from swim.io.scene import validate_scene
    from swim.optics.volume import build_optical_volume
    from swim.rt import march_inputs, solar

    given = scenes.synthetic_scene(nx=args.grid, ny=args.grid)
    sun = np.asarray(enu_from_azimuth_zenith(args.sun_azimuth, args.sun_zenith), dtype=float)
    times = {stage: [] for stage in STAGES}
    for repeat in range(args.repeats + 1):
        t_valid = time.perf_counter()
        scene = validate_scene(given)
        t0 = time.perf_counter()
        volume = build_optical_volume(scene)
        t1 = time.perf_counter()
        # as a render does it: the levels that Step 1a sweeps found before the packing makes the extinctions strided
        # views (a scan through them took ~5x longer), and counted as Step 1a's
        levels = solar.step1a_levels(volume)
        t_levels = time.perf_counter() - t1
        t1 = time.perf_counter()
        species = march_inputs.packed_species(volume)
        packed = march_inputs.pack_volume(volume, species)
        march_inputs.share_packed_channels(volume, packed, species)
        t2 = time.perf_counter()
        occupancy = march_inputs.occupancy_grid(volume)
        t3 = time.perf_counter()
        # as a render does it: the fields written into the packed channels where this code can
        # (docs/decisions/0007-scene-set-up.md), else made and then copied there by volume_constants
        out = march_inputs.step1a_channel_views(packed, species) if hasattr(march_inputs, "step1a_channel_views") else None
        transmittance = solar.solar_transmittance(volume, sun, variables=march_inputs.KERNEL_STEP1A_VARIABLES,
                                                  nonzero_levels=levels, **({"out": out} if out else {}))
        march_inputs.volume_constants(volume, transmittance, occupancy=occupancy, packed=packed, species=species)
        t4 = time.perf_counter()
        if repeat:
            for stage, seconds in zip(STAGES, (t0 - t_valid, t1 - t0 - t_levels, t2 - t1, t3 - t2, t4 - t3 + t_levels,
                                               t4 - t_valid)):
                times[stage].append(seconds)
        del scene, volume, packed, occupancy, transmittance, out
    print(f"swim from {Path(swim.__file__).parents[1]}: synthetic {args.grid} x {args.grid} x 60, sun at zenith "
          f"{args.sun_zenith:g} deg, {args.repeats} repeats after a warm-up\n")
    print("| stage | best [s] | median [s] |\n|---|---|---|")
    for stage, values in times.items():
        print(f"| {stage} | {min(values):.3f} | {statistics.median(values):.3f} |")


if __name__ == "__main__":
    main()
