"""Where a ray's samples go: the numba march's samples counted by kind, on a real render's rays (prints a table).

Usage::

    python benchmarks/sample_kinds.py                          # synthetic 512² all-sky, every pixel
    python benchmarks/sample_kinds.py --scene katrina --size 256

The script renders the suite's all-sky view of a scene once with the numba kernel, keeps the arguments of every
``march_rays`` call (``bench_march.capture``), and replays them through a copy of ``src/swim/rt/march_cpu.py`` in which
each ray's sample counter (``samples_out``) is replaced by counts packed in 10-bit fields of its 64 bits: in one
copy the samples of each kind, in another the halvings after a sample (whose sample is discarded), the predicted
halvings and the roll-backs. The kinds:

* the clear air before and after the grid, and the terminal steps up to the ground;
* in the grid, cells occupied by hydrometeors (the sample's hydrometeor extinction > 0), while the ray's own optical
  depth is below 8 (``REFINE_VISIBLE_TAU``: refinement and Eq. 12's weight) or beyond it;
* occupied cells without hydrometeors at the sample: below the terrain's highest point (the cells next to the
  terrain), or elsewhere (the occupancy's one-cell shell around clouds, a 3-D aerosol);
* empty cells (``step_classes`` 0 or -1: shadowed or sunlit clear air).

The copy is made by replacing lines of the kernel's source; the script stops with an error naming the line if the
kernel has changed so that one is no longer found. The copy's other outputs are the kernel's (its samples agree with
the installed kernel's count, which the table checks). What its counts decided: docs/decisions/0004-step-placement.md.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import bench_march  # noqa: E402  (benchmarks/ on the path first)

#: The kinds of sample, in the order of their 10-bit fields.
KINDS = ("clear air before/after the grid, terminal steps", "cloud, optical depth along the ray < 8",
         "cloud beyond an optical depth of 8", "occupied, no hydrometeors: below the terrain's top",
         "occupied, no hydrometeors: elsewhere (shell, aerosol)", "empty cells (shadowed or sunlit)")
#: Events counted after the kinds.
EVENTS = ("halvings after a sample (sample discarded)", "predicted halvings (no sample)", "roll-backs")
BITS = 10


def _replace(source, old, new):
    if source.count(old) != 1:
        raise SystemExit(f"sample_kinds.py: the kernel's line {old.strip().splitlines()[0]!r} was not found once; "
                         "update this script to the kernel")
    return source.replace(old, new)


def counting_kernel(path, events):
    """A copy of march_cpu.py at ``path`` whose ``samples_out`` holds the packed counts: of the kinds, or with
    ``events`` of the events."""
    src = (ROOT / "src/swim/rt/march_cpu.py").read_text()
    samples = "        samples = 0  # the medium's samples along this ray: every step evaluated, refined halves included\n"
    src = _replace(src, samples, samples + "        packed = 0\n")
    beta = "                beta_h = 0.0\n                if in_grid:\n                    for c in range(n_species):\n" \
           "                        beta_h += vol[c]\n"
    src = _replace(src, beta, beta + f"""                if (not in_grid) or terminal:
                    kind = 0
                else:
                    cls = occupancy[min(max(int(k), 0), occupancy.shape[0] - 1),
                                    min(max(int(j), 0), occupancy.shape[1] - 1),
                                    min(max(int(i), 0), occupancy.shape[2] - 1)]
                    if cls <= 0:
                        kind = 5
                    elif beta_h > 0:
                        kind = 1 if th < refine_visible else 2
                    else:
                        kind = 3 if h <= terrain_top else 4
                if not {events}:
                    packed += 1 << ({BITS} * kind)
""")
    split = "                        pending += 2\n                        budget -= 1\n"
    src = _replace(src, split, split + f"                        packed += {int(events)} << ({BITS} * 0)\n")
    rollback = "                        pending += 3\n                        budget -= 1\n"
    src = _replace(src, rollback, rollback + f"                        packed += {int(events)} << ({BITS} * 2)\n")
    predicted = "                    pending += 1\n                    budget -= 1\n"
    src = _replace(src, predicted, predicted + f"                    packed += {int(events)} << ({BITS} * 1)\n")
    src = _replace(src, "        samples_out[r] = samples\n", "        samples_out[r] = packed\n")
    Path(path).write_text(src)
    return path


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scene", default="synthetic", choices=sorted(bench_march.SCENE_CASES))
    parser.add_argument("--size", type=int, default=512)
    parser.add_argument("--data", default=str(ROOT.parent / "shared" / "data"))
    args = parser.parse_args(argv)

    calls = bench_march.capture(args.scene, args.size, Path(args.data))
    totals = []
    for events, names in ((False, KINDS), (True, EVENTS)):
        with tempfile.TemporaryDirectory() as folder:
            march = bench_march.load_variant(counting_kernel(Path(folder) / f"march_cpu_counting_{events}.py", events))
        total = np.zeros(len(names), np.int64)
        rays = installed = 0
        for args_, original in zip(bench_march.with_fresh_outputs(calls), calls):
            march(*args_)
            packed = args_[-1].astype(np.int64)
            for q in range(len(names)):
                total[q] += ((packed >> (BITS * q)) & ((1 << BITS) - 1)).sum()
            rays += packed.size
            installed += int(original[-1].sum())
        totals.extend(total)
    counted = sum(totals[:len(KINDS)])
    print(f"{args.scene}, {args.size}² all-sky: {rays} rays, {counted / rays:.1f} samples per ray "
          f"(the installed kernel's count: {installed / rays:.1f})\n")
    print("| kind | samples per ray | share |\n|---|---|---|")
    for name, total in zip(KINDS, totals):
        print(f"| {name} | {total / rays:.1f} | {100 * total / counted:.1f} % |")
    print("\n| event | per ray |\n|---|---|")
    for name, total in zip(EVENTS, totals[len(KINDS):]):
        print(f"| {name} | {total / rays:.2f} |")
    if counted != installed:
        raise SystemExit("the counting copy's samples differ from the installed kernel's: the copy is wrong")
    return 0


if __name__ == "__main__":
    sys.exit(main())
