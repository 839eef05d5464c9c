"""Where the CPU march kernel's time goes, instruction by instruction: a ``perf`` profile of its replay (prints a table).

Usage::

    python benchmarks/profile_march.py                         # synthetic 512² all-sky, 5 s of samples
    python benchmarks/profile_march.py --scene katrina --seconds 10 --top 25

Timings say how long the kernel takes, not where inside it. numba's compiled code is anonymous memory to ``perf``
(a kernel loaded from numba's disk cache has no symbols), so this script renders the suite's all-sky view of a scene
once (``bench_march.capture``), replays the captured chunks on one thread while ``perf record`` samples this very
process, and then reads the hot addresses' machine code from its own memory and disassembles it with ``objdump``
(code regions more than 4 KB apart are counted as different functions). It reports

* the share of the samples in compiled code, in NumPy, in libm (exp, expm1, pow) and in the rest;
* each hot code region (a kernel or a helper that numba did not inline) and its share;
* numba's reference counting (``NRT_incref``/``NRT_decref``: a ``lock inc``/``lock dec`` on the array's count),
  found by its instructions: each array view that the kernel makes in a loop (``volume[k, j, i]``) costs one of
  each, atomic, on a count that all threads share. This is how docs/decisions/0003-cpu-kernel-code.md found that they
  took ~1/4 of the march's cycles;
* the hottest instructions with the few before them (a cost lands on the instruction after a slow one).

Needs ``perf`` (Linux) with user-space sampling allowed (``/proc/sys/kernel/perf_event_paranoid`` ≤ 2) and
``objdump``. On a virtual machine without hardware counters ``perf`` samples the CPU clock instead of cycles.
Results go to ``benchmarks/results/profile-latest.json`` (``--out`` to change) and ns per sample and the shares to
``benchmarks/results/history.csv``.
"""

from __future__ import annotations

import argparse
import ctypes
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import bench_march  # noqa: E402  (benchmarks/ on the path first)
import bench_suite  # noqa: E402

#: Code regions closer than this [bytes] are one region (one compiled function and its inlined helpers).
REGION_GAP = 4096
#: Instructions shown before each hot address.
CONTEXT = 4


def record(calls, seconds, data_file):
    """Replay ``calls`` on this thread for about ``seconds`` while ``perf record`` samples this process; returns
    (samples replayed, seconds)."""
    from swim.rt import march_cpu

    for args in calls:  # warm: compiled, caches filled
        march_cpu.march_rays(*args)
    events = ["-e", "cycles:u"]
    probe = subprocess.run(["perf", "record", "-q", *events, "-o", os.devnull, "true"], capture_output=True)
    if probe.returncode != 0:
        events = ["-e", "cpu-clock:u"]
    perf = subprocess.Popen(["perf", "record", "-q", *events, "-p", str(os.getpid()), "-o", str(data_file)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    time.sleep(0.5)  # perf attached
    samples, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        for args in calls:
            march_cpu.march_rays(*args)
            samples += int(args[-1].sum())
    elapsed = time.perf_counter() - t0
    perf.send_signal(signal.SIGINT)
    perf.wait()
    return samples, elapsed


def hot_addresses(data_file):
    """(share in %, address) of the compiled code's sampled instructions, and the shares of the named libraries."""
    report = subprocess.run(["perf", "report", "-i", str(data_file), "--stdio", "--sort=dso,sym"],
                            capture_output=True, text=True, check=True).stdout
    addresses, libraries = [], {}
    for line in report.splitlines():
        match = re.match(r"\s+([\d.]+)%\s+(\S+)\s+.*\[\.\]\s+(\S+)", line)
        if not match:
            continue
        share, dso, symbol = float(match.group(1)), match.group(2), match.group(3)
        if dso.startswith("[JIT") or symbol.startswith("0x"):  # numba's code: anonymous memory, no symbols
            addresses.append((share, int(symbol, 16)))
        else:
            library = "libm" if "libm" in dso else "numpy" if "multiarray" in dso else "other"
            libraries[library] = libraries.get(library, 0.0) + share
    return addresses, libraries


def regions(addresses):
    """The hot addresses grouped into code regions (sorted by share): dicts of first, last address, share, points."""
    groups = []
    for share, address in sorted(addresses, key=lambda x: x[1]):
        if groups and address - groups[-1]["last"] < REGION_GAP:
            groups[-1]["last"] = address
            groups[-1]["share"] += share
            groups[-1]["points"].append((share, address))
        else:
            groups.append({"first": address, "last": address, "share": share, "points": [(share, address)]})
    return sorted(groups, key=lambda g: -g["share"])


def disassemble(region):
    """The region's machine code, read from this process's memory: a list of (address, instruction text)."""
    start, size = region["first"] - 256, region["last"] - region["first"] + 512
    with tempfile.NamedTemporaryFile(suffix=".bin") as blob:
        blob.write(ctypes.string_at(start, size))
        blob.flush()
        text = subprocess.run(["objdump", "-D", "-b", "binary", "-mi386:x86-64", f"--adjust-vma={start}", blob.name],
                              capture_output=True, text=True, check=True).stdout
    lines = []
    for line in text.splitlines():
        match = re.match(r"\s*([0-9a-f]+):\t(?:[0-9a-f]{2} )+\s*\t(.*)", line)
        if match:
            lines.append((int(match.group(1), 16), match.group(2).strip()))
    return lines


def is_reference_count(code):
    """Whether a region is numba's NRT_incref/NRT_decref: a tiny function of ``lock inc``/``lock dec``."""
    text = " ".join(instruction for _, instruction in code)
    return len(code) < 40 and ("lock incq" in text or "lock decq" in text)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", choices=sorted(bench_march.SCENE_CASES), default="synthetic")
    parser.add_argument("--size", type=int, default=512, help="all-sky image size [pixels] of the captured render")
    parser.add_argument("--seconds", type=float, default=5.0, help="replay time under perf [s]")
    parser.add_argument("--top", type=int, default=15, help="hottest instructions shown")
    parser.add_argument("--data", type=Path, default=bench_suite.DATA)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    for tool in ("perf", "objdump"):
        if shutil.which(tool) is None:
            raise SystemExit(f"profile_march.py needs {tool} on the PATH")

    calls = bench_march.with_fresh_outputs(bench_march.capture(args.scene, args.size, args.data))
    with tempfile.TemporaryDirectory() as folder:
        data_file = Path(folder) / "perf.data"
        samples, elapsed = record(calls, args.seconds, data_file)
        addresses, libraries = hot_addresses(data_file)
    if not addresses:
        raise SystemExit("perf recorded no samples in compiled code (is user-space sampling allowed?)")
    groups = regions(addresses)
    compiled = sum(share for share, _ in addresses)
    print(f"{args.scene} {args.size}²: {samples / elapsed / 1e6:.2f} million samples/s on one thread "
          f"({elapsed / samples * 1e9:.0f} ns per sample, perf attached)")
    print(f"compiled code {compiled:.1f} %, " + ", ".join(f"{k} {v:.1f} %" for k, v in sorted(libraries.items())))
    print("\ncode regions (a kernel with its inlined helpers, or a helper called from it):")
    reference_counting = 0.0
    found = []
    for group in groups[:8]:
        code = disassemble(group)
        counting = is_reference_count(code)
        reference_counting += group["share"] if counting else 0.0
        size = group["last"] - group["first"]
        label = "numba's reference counting (NRT_incref/NRT_decref)" if counting else f"{size} bytes of hot code"
        print(f"  {group['share']:6.2f} %  {hex(group['first'])}  {label}")
        found.append({"first": group["first"], "share": group["share"], "bytes": size, "reference_counting": counting,
                      "code": code})
    print(f"\nreference counting: {reference_counting:.1f} % of the samples")
    print(f"\nhottest instructions (the {CONTEXT} before each):")
    top = []
    for share, address in sorted(addresses, key=lambda x: -x[0])[:args.top]:
        region = next((g for g in found if g["first"] <= address <= g["first"] + g["bytes"]), None)
        lines = []
        if region is not None:
            index = next((q for q, (a, _) in enumerate(region["code"]) if a == address), None)
            if index is not None:
                lines = [text for _, text in region["code"][max(0, index - CONTEXT):index + 1]]
        print(f"  {share:5.2f} %  {hex(address)}")
        for text in lines:
            print(f"            {text}")
        top.append({"share": share, "address": address, "code": lines})

    out = args.out or ROOT / "benchmarks" / "results" / "profile-latest.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    summary = {"scene": args.scene, "size": args.size, "samples": samples, "seconds": elapsed,
               "ns_per_sample": elapsed / samples * 1e9, "compiled_share": compiled, "libraries": libraries,
               "reference_counting_share": reference_counting,
               "regions": [{k: v for k, v in g.items() if k != "code"} for g in found], "top": top,
               "machine": bench_suite.machine_info() if hasattr(bench_suite, "machine_info") else None}
    out.write_text(json.dumps(summary, indent=1))
    import history  # benchmarks/ is on the path

    history.append("profile", history.profile_rows(summary), source="profile_march.py")
    print(f"\nwritten {out}, {history.HISTORY}")


if __name__ == "__main__":
    main()
