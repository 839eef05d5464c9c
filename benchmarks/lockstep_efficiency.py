"""How much of the fused GPU kernel's lockstep is work: each ray's grid samples against its program's slowest ray.

The fused Pallas kernel (``swim.rt.march_pallas``) marches a program's block of rays in lockstep: its loop over the
grid runs until the block's last ray has taken its last sample, and a ray that has finished runs the loop's body with
its results discarded. Nsight Compute cannot see that waste (those threads are not predicated off:
docs/decisions/0006-gpu-kernels.md). This script counts it on a CPU: it renders the suite's all-sky view with the numba
kernel on one thread (so that its ``march_rays`` calls come in the pixels' order, the order of the GPU's batches with
every pixel traced), replays the calls through ``sample_kinds.py``'s counting copy of the kernel, and takes each ray's
samples in the grid (every kind but the clear air before and after it and the terminal steps). Each sample of the numba
kernel is one iteration of the GPU's grid loop (a predicted halving samples the interval's first half in the same
iteration).

For blocks of B consecutive rays it prints the efficiency, the sum of the rays' grid samples over the sum of B times
each block's largest, and the iterations per ray that a program runs: in the order traced (8 x 8 pixel tiles,
``swim.rt.image_sampling.tile_order``), in other tiles, and sorted by the samples themselves (the bound that no
order can beat).

With ``--adaptive`` it also takes the batches of an adaptive render of the same view (the host's sampler, whose
batches are the device sampler's: each quadtree level's wanted pixels) and gives each ray the samples that the
every-pixel replay counted for its pixel. Per level and block size it prints the efficiency with the batch's rays in
the device sampler's row-major order (``np.flatnonzero``), in 8 x 8 tiles, sorted by a prediction of their samples
(the nearest pixel traced at an earlier level; the view zenith angle on the first) and sorted by the samples
themselves; then the efficiency if each lane of a program marched K of the batch's consecutive rays one after the
other (a finished ray's lane taking the next: "lane refill", one iteration per refill), and the programs that leaves
per batch (docs/decisions/0006-gpu-kernels.md).

Usage::

    python benchmarks/lockstep_efficiency.py --size 1024 --blocks 32 128 256 512 1024
    python benchmarks/lockstep_efficiency.py --size 1024 --blocks 128 512 --adaptive
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


def adaptive_batches(scene_name, size, data):
    """The pixels (flat indices) of each batch of an adaptive render of the suite's all-sky view of ``scene_name`` at
    ``size``² (the host's sampler with the suite's settings, the numba kernel), in the order of the batches."""
    import bench_suite

    import swim
    import swim.pipeline as pipeline
    from swim.rt.image_sampling import AdaptiveSampling
    from swim.rt.march import MarchSettings

    spec = {**bench_suite.CASES[bench_march.SCENE_CASES[scene_name]], "data": str(data)}
    if scene_name == "synthetic":
        spec["scene_kwargs"] = dict(bench_suite.SYNTHETIC_GRID)
    scene = bench_suite.load_scene(spec)
    kw = bench_suite.render_kwargs(spec, image=(size, size))
    kw["settings"] = MarchSettings(backend="numba")
    batches, original = [], pipeline.sample_image_adaptive

    def recording(trace, *args, **kwargs):
        def traced(flat, *more, **named):
            batches.append(np.array(flat))
            return trace(flat, *more, **named)
        return original(traced, *args, **kwargs)

    pipeline.sample_image_adaptive = recording
    try:
        swim.render(scene, **kw, sampling=AdaptiveSampling(**bench_suite.ADAPTIVE))
    finally:
        pipeline.sample_image_adaptive = original
    return batches


def refill_efficiency(samples, block, per_lane):
    """Efficiency if each of a program's ``block`` lanes marched ``per_lane`` of its rays one after the other (lane
    l of program p: rays p * block * per_lane + l + block * k), a refill costing one iteration."""
    n = -(-samples.size // (block * per_lane)) * (block * per_lane)
    padded = np.zeros(n, np.int64)
    padded[:samples.size] = samples + 1
    lanes = padded.reshape(-1, per_lane, block).sum(axis=1)
    return float(samples.sum()) / float(lanes.max(axis=1).sum() * block)


def adaptive_report(samples, pixels, shape, batches, blocks, per_lane=(1, 2, 4, 8)):
    """The levels' efficiencies (see the module docstring) as printed table rows and a dict."""
    from scipy.ndimage import distance_transform_edt

    from swim.geometry.cameras import _view_angles, make_camera
    from swim.rt.image_sampling import tile_order

    ny, nx = shape
    per_pixel = np.zeros(ny * nx, np.int64)
    per_pixel[pixels] = samples
    zenith = _view_angles(make_camera("allsky", size=ny))[0].reshape(-1)
    known = np.zeros(ny * nx, bool)
    result = {"batches": [int(b.size) for b in batches], "levels": [], "refill": {}}
    names = ("row-major", "8 x 8 tiles", "predicted", "sorted by samples (the bound)")
    print("| level | rays | rays per program | " + " | ".join(names) + " |")
    print("|---|---|---|" + "---|" * len(names))
    for level, batch in enumerate(batches):
        if level == 0:
            prediction = zenith[batch]
        else:
            _, (iy, ix) = distance_transform_edt(~known.reshape(ny, nx), return_indices=True)
            prediction = per_pixel[(iy * nx + ix).reshape(-1)[batch]]
        orders = {names[0]: np.sort(batch), names[1]: batch[tile_order(batch, shape)],
                  names[2]: batch[np.argsort(prediction, kind="stable")]}
        for block in blocks:
            shares = {name: efficiency(per_pixel[order], block)[0] for name, order in orders.items()}
            shares[names[3]] = efficiency(np.sort(per_pixel[batch]), block)[0]
            result["levels"].append({"level": level, "rays": int(batch.size), "block": block, **shares})
            print(f"| {level} | {batch.size} | {block} | " + " | ".join(f"{shares[n]:.1%}" for n in names) + " |")
        known[batch] = True
    print("\n| rays per program | rays per lane | efficiency (row-major, all levels) | programs per level |")
    print("|---|---|---|---|")
    for block in blocks:
        for k in per_lane:
            work = sum(float(per_pixel[b].sum()) for b in batches)
            iterations = sum(float(per_pixel[b].sum()) / refill_efficiency(per_pixel[np.sort(b)], block, k)
                             for b in batches)
            programs = [-(-int(b.size) // (block * k)) for b in batches]
            result["refill"][f"{block}x{k}"] = {"efficiency": work / iterations, "programs": programs}
            print(f"| {block} | {k} | {work / iterations:.1%} | {programs} |")
    return result


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scene", default="synthetic", choices=sorted(bench_march.SCENE_CASES))
    parser.add_argument("--size", type=int, default=1024)
    parser.add_argument("--blocks", type=int, nargs="+", default=[32, 64, 128, 256, 512, 1024])
    parser.add_argument("--tiles", nargs="*", default=["16x8", "32x16"],
                        help="also the rays in other tiles, HEIGHTxWIDTH pixels")
    parser.add_argument("--data", default=str(ROOT.parent / "shared" / "data"))
    parser.add_argument("--adaptive", action="store_true",
                        help="also the batches of an adaptive render (the quadtree's levels), see the docstring")
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
    adaptive = None
    if args.adaptive:
        print(f"\nadaptive render of the same view: each level's batch, the rays' samples from the replay above")
        adaptive = adaptive_report(samples, pixels, shape, adaptive_batches(args.scene, args.size, args.data),
                                   args.blocks)
    if args.out:
        Path(args.out).write_text(json.dumps({"scene": args.scene, "size": args.size, "rays": int(samples.size),
                                              "mean_grid_samples": float(samples.mean()), "blocks": rows,
                                              "adaptive": adaptive}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
