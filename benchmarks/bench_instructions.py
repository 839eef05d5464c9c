"""Instructions and branches per sample of the CPU march kernel, counted by valgrind's callgrind (prints a table).

Usage::

    python benchmarks/bench_instructions.py                          # synthetic 512², its first chunk of rays
    python benchmarks/bench_instructions.py --scene katrina --chunk 10

Timings on this project's shared 2-core machine move by 10-20 %; an instruction count does not: callgrind counts
what the CPU would execute, whatever else the machine is doing, the same for the same code and inputs. This script
renders the suite's all-sky view of a scene once (as ``benchmarks/bench_march.py`` does), keeps the arguments of one
call of :func:`swim.rt.march_cpu.march_rays` (a chunk of rays with its tables), and runs that call under callgrind
in fresh interpreters: once to compile (numba compiles anew for the CPU that valgrind presents, and caches it), then
with one and with two passes over the chunk. The difference between the last two is one pass: its instructions,
conditional branches and (with callgrind's simple branch predictor, not the real CPU's) mispredicted branches, per
sample and per ray.

The counts are of the kernel compiled for valgrind's CPU, which has AVX2 but not AVX-512: on this project's AMD
Zen 4 CPU numba compiles with AVX-512's 32 vector registers, so its own count is somewhat lower (fewer spills).
Compare counts with counts from this script only. The first run compiles under valgrind (~10 minutes on this
machine), the others take ~1-2 minutes each. Needs ``valgrind`` on the PATH.

Results go to ``benchmarks/results/instructions-latest.json`` (``--out`` to change) and the counts per sample to
``benchmarks/results/history.csv``.
"""

from __future__ import annotations

import argparse
import json
import pickle
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import bench_march  # noqa: E402  (benchmarks/ on the path first)
import bench_suite  # noqa: E402
import history  # noqa: E402

CHILD = r"""
import pickle, sys
sys.path.insert(0, sys.argv[3])
import bench_march
from swim.rt import march_cpu
args = bench_march.with_fresh_outputs([pickle.load(open(sys.argv[1], "rb"))])[0]
for _ in range(int(sys.argv[2])):
    march_cpu.march_rays(*args)
print("samples", int(args[-1].sum()), "rays", args[0].shape[0])
"""

#: callgrind's totals: "I refs", then "Branches" and "Mispredicts" as (all, conditional, indirect).
_TOTALS = {"instructions": r"I\s+refs:\s+([\d,]+)",
           "branches": r"Branches:\s+[\d,]+\s+\(\s*([\d,]+) cond",
           "mispredicts": r"Mispredicts:\s+[\d,]+\s+\(\s*([\d,]+) cond"}


def callgrind(chunk_file, passes):
    """Run ``passes`` (at least one) passes of the kernel over the pickled chunk under callgrind; returns its totals
    and the chunk's samples and rays (from the child's own count)."""
    child = [sys.executable, "-c", CHILD, str(chunk_file), str(passes), str(ROOT / "benchmarks")]
    done = subprocess.run(["valgrind", "--tool=callgrind", "--branch-sim=yes", "--callgrind-out-file=/dev/null",
                           *child], capture_output=True, text=True, check=True)
    text = done.stdout + done.stderr
    totals = {key: int(re.search(pattern, text).group(1).replace(",", "")) for key, pattern in _TOTALS.items()}
    found = re.search(r"samples (\d+) rays (\d+)", text)
    totals["samples"], totals["rays"] = int(found.group(1)), int(found.group(2))
    return totals


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", choices=sorted(bench_march.SCENE_CASES), default="synthetic")
    parser.add_argument("--size", type=int, default=512, help="all-sky image size [pixels] of the captured render")
    parser.add_argument("--chunk", type=int, default=0,
                        help="which of the render's march calls to count (sorted by their first ray's direction)")
    parser.add_argument("--data", type=Path, default=bench_suite.DATA)
    parser.add_argument("--out", type=Path, default=None)
    opts = parser.parse_args(argv)
    if shutil.which("valgrind") is None:
        raise SystemExit("valgrind is not on the PATH")

    # the render's threads append their calls in no fixed order: sorted by their first ray's direction, a chunk's
    # number names the same rays in every run
    calls = sorted(bench_march.capture(opts.scene, opts.size, opts.data), key=lambda args: tuple(args[1][0]))
    if not 0 <= opts.chunk < len(calls):
        raise SystemExit(f"--chunk must lie in [0, {len(calls) - 1}]: the render made {len(calls)} march calls")
    with tempfile.TemporaryDirectory(prefix="swim-instructions-") as folder:
        chunk_file = Path(folder) / "chunk.pkl"
        with open(chunk_file, "wb") as f:
            pickle.dump(calls[opts.chunk], f, protocol=5)
        del calls
        t0 = time.perf_counter()
        # numba compiles for valgrind's CPU at the first call (and caches it): a pass outside the counts
        callgrind(chunk_file, 1)
        compile_s = time.perf_counter() - t0
        one, two = callgrind(chunk_file, 1), callgrind(chunk_file, 2)
    samples, rays = two["samples"], two["rays"]
    per_pass = {key: two[key] - one[key] for key in _TOTALS}
    result = {"scene": opts.scene, "size": opts.size, "chunk": opts.chunk, "rays": rays, "samples": samples,
              "samples_per_ray": samples / rays, "per_pass": per_pass,
              "per_sample": {key: value / samples for key, value in per_pass.items()},
              "per_ray": {key: value / rays for key, value in per_pass.items()},
              "first_run_s": compile_s, "git": bench_suite.git_info(), "machine": bench_suite.machine_info()}

    print(f"\n{opts.scene}, {opts.size}² all-sky, march call {opts.chunk}: {rays} rays, "
          f"{samples / rays:.1f} samples per ray (callgrind, one pass)\n")
    print("| count | per pass | per sample | per ray |")
    print("|---|---|---|---|")
    for key, label in (("instructions", "instructions"), ("branches", "conditional branches"),
                       ("mispredicts", "mispredicted (simulated)")):
        print(f"| {label} | {per_pass[key]:,} | {result['per_sample'][key]:.1f} | {result['per_ray'][key]:,.0f} |")
    out = opts.out or ROOT / "benchmarks" / "results" / "instructions-latest.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1))
    history.append("instructions", history.instructions_rows(result), machine=history.machine_label(result["machine"]),
                   commit=history.commit_label(result["git"]), source="bench_instructions.py")
    print(f"\nwritten: {out}, {history.HISTORY}")


if __name__ == "__main__":
    main()
