"""A new process's render: wall time, and JAX's tracing, lowering and cache reads in it, with the traced programs read
from disk (``swim.compilation.jax_export``) and without, the two taking turns (prints a table, writes JSON).

Usage::

    python benchmarks/bench_cold.py                                   # the README's render with --backend jax, 256²
    python benchmarks/bench_cold.py --rounds 5 -- --size 1024         # on a GPU machine: the README's render itself
    python benchmarks/bench_cold.py --variants export=1 export=0 -- --backend numba --size 512

Each round runs ``swim render <arguments>`` once per variant, each in a new Python process that registers a listener
for JAX's duration events (``jax._src.monitoring``) and then runs the CLI in place. A variant ``export=0`` sets
``SWIM_JAX_EXPORT=0`` (every program traced anew), ``export=1`` leaves the programs' cache on. The
caches must be warm: the first round is a warm-up and is not counted. Reported per variant (medians over the rounds):
the process's wall time, the CLI's time, and the seconds of JAX's tracing (``jaxpr_trace_duration``), lowering
(``jaxpr_to_mlir_module_duration``) and reads of compiled executables (``cache_retrieval_time_sec``). Results go to
``benchmarks/results/cold-latest.json`` (``--out`` to change) and the medians to ``benchmarks/results/history.csv``.
docs/decisions/0008-cold-start.md
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

CHILD = r"""
import collections, json, sys, time
from jax._src import monitoring
totals = collections.defaultdict(float)
monitoring.register_event_duration_secs_listener(lambda event, seconds, **_: totals.__setitem__(
    event.rsplit("/", 1)[-1], totals[event.rsplit("/", 1)[-1]] + seconds))
sys.argv = ["swim", "render", *json.loads(sys.argv[1])]
from swim.cli.main import run
start = time.perf_counter()
try:
    run()
except SystemExit as stop:
    if stop.code:
        raise
print("BENCH_COLD " + json.dumps({"cli_s": time.perf_counter() - start, **totals}))
"""
EVENTS = {"trace_s": "jaxpr_trace_duration", "lower_s": "jaxpr_to_mlir_module_duration",
          "cache_read_s": "cache_retrieval_time_sec"}


def run_once(variant, arguments, folder):
    env = dict(os.environ)
    for item in filter(None, variant.split(",")):
        name, value = item.split("=")
        env[{"export": "SWIM_JAX_EXPORT"}.get(name, name)] = value
    out = Path(folder) / f"cold-{variant.replace('=', '').replace(',', '-')}.png"
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-c", CHILD, json.dumps([*arguments, "--out", str(out)])], env=env,
                          capture_output=True, text=True, check=True)
    wall = time.perf_counter() - start
    line = next(row for row in done.stdout.splitlines() if row.startswith("BENCH_COLD "))
    totals = json.loads(line.split(" ", 1)[1])
    return {"wall_s": wall, "cli_s": totals["cli_s"], **{key: totals.get(event, 0.0) for key, event in EVENTS.items()}}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=4, help="counted rounds (after one warm-up)")
    parser.add_argument("--variants", nargs="+", default=["export=1", "export=0"])
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("arguments", nargs="*", help="swim render's arguments (after --)")
    args = parser.parse_args()
    arguments = args.arguments or ["--backend", "jax", "--size", "256"]
    import tempfile

    runs = {variant: [] for variant in args.variants}
    with tempfile.TemporaryDirectory() as folder:
        for round_ in range(args.rounds + 1):
            for variant in args.variants:
                result = run_once(variant, arguments, folder)
                if round_:
                    runs[variant].append(result)
                print(f"round {round_}{' (warm-up)' if not round_ else ''} {variant}: "
                      + ", ".join(f"{key} {value:.2f}" for key, value in result.items()), flush=True)
    print(f"\nswim render {' '.join(arguments)}: medians of {args.rounds} new processes [s]\n")
    keys = ["wall_s", "cli_s", *EVENTS]
    print("| variant | " + " | ".join(keys) + " |")
    print("|---" * (len(keys) + 1) + "|")
    summary = {}
    for variant, results in runs.items():
        summary[variant] = {key: statistics.median(r[key] for r in results) for key in keys}
        print(f"| {variant} | " + " | ".join(f"{summary[variant][key]:.2f}" for key in keys) + " |")
    out = args.out or ROOT / "benchmarks" / "results" / "cold-latest.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    doc = {"arguments": arguments, "rounds": args.rounds, "runs": runs, "medians": summary}
    out.write_text(json.dumps(doc, indent=1))
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import history

    history.append("cold", history.cold_rows(doc), source="bench_cold.py")
    print(f"\nwritten: {out}, {history.HISTORY}")


if __name__ == "__main__":
    main()
