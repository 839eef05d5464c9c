"""How much of the fused GPU kernel's lockstep is work: each ray's grid samples against its program's slowest ray.

The fused Pallas kernel (``swim.rt.march_pallas``) marches a program's block of rays in lockstep: its loop over the
grid runs until the block's last ray has taken its last sample, and a ray that has finished runs the loop's body with
its results discarded. Nsight Compute cannot see that waste (those threads are not predicated off: docs/performance.md,
section 85). This script counts it on a CPU: it renders the suite's all-sky view with the numba kernel on one thread
(so that its ``march_rays`` calls come in the pixels' order, the order of the GPU's batches with every pixel traced),
replays the calls through ``sample_kinds.py``'s counting copy of the kernel, and takes each ray's samples in the grid
(every kind but the clear air before and after it and the terminal steps). Each sample of the numba kernel is one
iteration of the GPU's grid loop (a predicted halving samples the interval's first half in the same iteration).

For blocks of B consecutive rays it prints the efficiency, the sum of the rays' grid samples over the sum of B times
each block's largest, and the iterations per ray that a program runs: in the order traced (8 x 8 pixel tiles,
``swim.rt.image_sampling.tile_order``), in other tiles, and sorted by the samples themselves (the bound that no
order can beat).

Usage::

    python benchmarks/lockstep_efficiency.py --size 1024 --blocks 32 128 256 512 1024
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

os.environ["SWIM_NUM_THREADS"] = "1"  # the march's calls in the pixels' order (before swim is imported)

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import bench_march  # noqa: E402
import sample_kinds  # noqa: E402


def grid_samples(scene, size, data):
    """Each ray's samples in the grid (n_rays,), in the order of the render's march calls."""
    calls = bench_march.capture(scene, size, Path(data))
    with tempfile.TemporaryDirectory() as folder:
        march = bench_march.load_variant(sample_kinds.counting_kernel(Path(folder) / "march_cpu_counting.py", False))
    per_ray = []
    for args in bench_march.with_fresh_outputs(calls):
        march(*args)
        packed = args[-1].astype(np.int64)
        fields = [(packed >> (sample_kinds.BITS * q)) & ((1 << sample_kinds.BITS) - 1)
                  for q in range(len(sample_kinds.KINDS))]
        per_ray.append(sum(fields[1:]))  # kind 0: the clear air and the terminal steps
    return np.concatenate(per_ray)


def efficiency(samples, block):
    """(work / lockstep iterations, iterations per ray) for blocks of ``block`` consecutive rays (the last one
    padded with rays of no samples, as the kernel's batches are padded)."""
    n = -(-samples.size // block) * block
    padded = np.zeros(n, samples.dtype)
    padded[:samples.size] = samples
    longest = padded.reshape(-1, block).max(axis=1)
    lockstep = float(longest.sum()) * block
    return float(samples.sum()) / lockstep, lockstep / samples.size


def pixel_of_each_ray(size):
    """The flat pixel index of each camera ray in the order traced (the suite's all-sky camera at ``size``²: its
    valid pixels in ``tile_order``, as ``swim.pipeline`` traces them), and the image's shape."""
    from swim.geometry.cameras import _view_angles, make_camera
    from swim.rt.image_sampling import tile_order

    zenith, _ = _view_angles(make_camera("allsky", size=size))
    flat = np.flatnonzero(np.isfinite(zenith))
    return flat[tile_order(flat, zenith.shape)], zenith.shape


def tiled(pixels, shape, tile_y, tile_x):
    """The permutation of ``pixels`` (flat indices) that takes them tile by tile, row-major inside a tile."""
    y, x = np.divmod(pixels, shape[1])
    return np.lexsort((x % tile_x, y % tile_y, x // tile_x, y // tile_y))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scene", default="synthetic", choices=sorted(bench_march.SCENE_CASES))
    parser.add_argument("--size", type=int, default=1024)
    parser.add_argument("--blocks", type=int, nargs="+", default=[32, 64, 128, 256, 512, 1024])
    parser.add_argument("--tiles", nargs="*", default=["16x8", "32x16"],
                        help="also the rays in other tiles, HEIGHTxWIDTH pixels")
    parser.add_argument("--data", default=str(ROOT.parent / "shared" / "data"))
    parser.add_argument("--out", default=None, help="JSON file")
    args = parser.parse_args(argv)

    samples = grid_samples(args.scene, args.size, args.data)
    pixels, shape = pixel_of_each_ray(args.size)
    if samples.size != pixels.size + 1:
        raise SystemExit(f"{samples.size} rays marched for {pixels.size} pixels and the sun: not the all-sky's rays")
    samples = samples[:-1]  # the sun's ray, marched last
    print(f"{args.scene}, {args.size}² all-sky, every pixel: {samples.size} rays, grid samples per ray: mean "
          f"{samples.mean():.1f}, median {np.median(samples):.0f}, p90 {np.percentile(samples, 90):.0f}, "
          f"max {samples.max()}\n")
    orders = {"traced (8 x 8 tiles)": None}
    orders.update({f"{t.replace('x', ' x ')} tiles": tiled(pixels, shape, *(int(v) for v in t.split("x")))
                   for t in args.tiles})
    orders["sorted by samples (the bound)"] = np.argsort(samples, kind="stable")
    print("| rays per program | " + " | ".join(orders) + " |")
    print("|---|" + "---|" * len(orders))
    rows = {}
    for block in args.blocks:
        cells = []
        for name, order in orders.items():
            share, iterations = efficiency(samples if order is None else samples[order], block)
            rows.setdefault(str(block), {})[name] = {"efficiency": share, "iterations_per_ray": iterations}
            cells.append(f"{share:.1%} ({iterations:.1f})")
        print(f"| {block} | " + " | ".join(cells) + " |")
    print("\n(efficiency: the rays' grid samples over the programs' lockstep iterations; in brackets the iterations "
          "per ray)")
    if args.out:
        Path(args.out).write_text(json.dumps({"scene": args.scene, "size": args.size, "rays": int(samples.size),
                                              "mean_grid_samples": float(samples.mean()), "blocks": rows}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
