"""The benchmarks' history: a few headline figures of each run, one CSV row each, in ``benchmarks/results/history.csv``.

A script writes its whole output to its ``*-latest.json`` (overwritten by the next run) and appends its headline
figures here with :func:`append`; the ``*_rows`` functions pick them from the script's JSON document. Columns:

* ``date``: UTC, ``YYYY-MM-DDTHH:MM:SSZ`` (``YYYY-MM-DD`` where only the day is known);
* ``kind``: the script (``suite``, ``suite-quick``, ``gpu``, ``cold``, ``march``, ``instructions``, ``profile``,
  ``settings``, ``host``, ``frame-parts``, ...);
* ``case``: the case, scene or variant measured; ``figure``, ``value``, ``unit``: the figure (the JSON's key);
* ``machine``: the CPU model and its usable cores (``AMD EPYC x2``) or the GPU;
* ``commit``: the measured commit's first 12 hex digits, ``+dirty`` where tracked files had local changes;
* ``source``: the script, or for runs from before this file the per-run JSON file (in git history), relative to
  ``benchmarks/``.
"""

from __future__ import annotations

import csv
import math
import numbers
import os
import platform
import statistics
import subprocess
from datetime import datetime, timezone
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
HISTORY = RESULTS / "history.csv"
COLUMNS = ("date", "kind", "case", "figure", "value", "unit", "machine", "commit", "source")


def now():
    return datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


def machine_label(machine=None):
    """``"AMD EPYC x2"`` (CPU model, usable cores) or the GPU's name, from a results file's ``machine`` record (the
    suite's ``machine_info`` or ``bench_gpu.py``'s) or, without one, from this machine."""
    if machine is None:
        machine = {"cpu_model": _cpu_model(), "cpu_affinity": len(os.sched_getaffinity(0))
                   if hasattr(os, "sched_getaffinity") else os.cpu_count()}
        gpu = _gpu_name()
        if gpu:
            machine["device_kind"] = gpu
    if machine.get("device_kind") and str(machine["device_kind"]).lower() != "cpu":
        return str(machine["device_kind"])
    if machine.get("jax_backend") == "gpu" or machine.get("backend") == "gpu":
        return _gpu_name() or "GPU"  # a record without the GPU's name (the suite's): this machine's
    cores = machine.get("cpu_affinity") or machine.get("cpu_count") or machine.get("host_cores")
    return f"{machine.get('cpu_model') or 'CPU'} x{cores or '?'}"


def _cpu_model():
    info = Path("/proc/cpuinfo")
    if info.exists():
        for line in info.read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    return platform.processor()


def _gpu_name():
    try:
        done = subprocess.run(["nvidia-smi", "--query-gpu=name", "--format=csv,noheader"], capture_output=True,
                              text=True, timeout=20)
    except (OSError, subprocess.SubprocessError):
        return None
    name = done.stdout.split("\n")[0].strip() if done.returncode == 0 else ""
    return name or None


def commit_label(git=None):
    """The commit's first 12 hex digits, ``+dirty`` where tracked files had local changes, from a results file's
    ``git`` record (``bench_suite.git_info()``) or, without one, from the checkout."""
    if git is None:
        def run(*a):
            done = subprocess.run(["git", "-C", str(ROOT), *a], capture_output=True, text=True)
            return done.stdout.strip() if done.returncode == 0 else ""

        git = {"commit": run("rev-parse", "HEAD"), "dirty_files": run("status", "--porcelain", "--untracked-files=no")}
    commit = (git.get("commit") or "")[:12]
    return commit + ("+dirty" if commit and git.get("dirty_files") else "")


def _value(value):
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(value):
        return None
    return str(int(value)) if isinstance(value, numbers.Integral) else f"{float(value):.6g}"


def append(kind, rows, *, date=None, machine=None, commit=None, source="", path=HISTORY):
    """Append ``rows`` ((case, figure, value, unit) each; values that are not finite numbers are left out) to the
    history; ``machine`` and ``commit`` are labels (:func:`machine_label`, :func:`commit_label`; this machine and
    checkout by default). Returns the number of rows written."""
    date = date or now()
    machine = machine_label() if machine is None else machine
    commit = commit_label() if commit is None else commit
    lines = [(date, kind, case, figure, text, unit, machine, commit, source) for case, figure, value, unit in rows
             if (text := _value(value)) is not None]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    new = not path.exists() or path.stat().st_size == 0
    with path.open("a", newline="") as f:
        writer = csv.writer(f, lineterminator="\n")
        if new:
            writer.writerow(COLUMNS)
        writer.writerows(lines)
    return len(lines)


# ---------------------------------------------------------------------------------------------------------------------
# headline figures of each script's JSON document: (case, figure, value, unit)

def suite_rows(doc):
    """``bench_suite.py``: per case run, its cold and warm seconds (the warm median in the machine's fast state too),
    the probe's median, the peak memory and the renders' peak above the scene, the traced pixels; the series' frames,
    the scaling exponents and the Monte Carlo ratios."""
    gpu = (doc.get("machine") or {}).get("jax_backend") == "gpu"
    for c in doc.get("cases", []):
        if c.get("status") != "ok":
            continue
        case = c["case"]
        backend = c.get("march_backend")
        if backend and backend != ("jax" if gpu else "numba"):
            case += f" ({backend})"
        for key, unit in (("cold_s", "s"), ("warm_s", "s"), ("warm_fast_state_s", "s"), ("full_warm_s", "s"),
                          ("mean_frame_s", "s"), ("rebuilds", "1"), ("peak_rss_mb", "MB"),
                          ("render_peak_above_scene_mb", "MB"), ("traced_pixels", "pixels"), ("exponent", "1")):
            yield case, key, c.get(key), unit
        if c.get("machine_probe_ns"):
            yield case, "machine_probe_ns", statistics.median(c["machine_probe_ns"]), "ns/sample"
        if isinstance(c.get("adaptive_error"), dict):
            yield case, "adaptive_error_p99", c["adaptive_error"].get("p99"), "1"
        for key in ("equal_error", "equal_noise"):
            if isinstance(c.get(key), dict):
                yield case, f"{key}_ratio", c[key].get("ratio"), "x"


def _gpu_case(scene, r):
    """A label for a row of ``bench_gpu.py``: the scene and what sets the row apart."""
    parts = [scene]
    for key in ("backend", "grid_kernel", "fused_block"):
        if r.get(key):
            parts.append(str(r[key]))
    if r.get("sampling"):
        parts.append("adaptive")
    for key in ("ray_table", "step1a_on_device", "device_sampling", "device_image"):
        if r.get(key):
            parts.append(f"{key} ({r[key]})")
    if r.get("chunk"):
        parts.append(f"chunk {r['chunk']}")
    if r.get("sun_series"):
        parts.append("new sun each frame")
    if r.get("compare"):
        parts.append(f"against {r['compare']}")
    return " ".join(parts)


def gpu_rows(doc):
    """``bench_gpu.py``: per row, the warm frame, the kernel's chunk, the frame with a new sun, the frames with and
    without a setting, the fused blocks' chunk, the first render and the device's memory."""
    for scene, result in (doc.get("scenes") or {}).items():
        for r in result.get("rows", []):
            case = _gpu_case(scene, r)
            for key, unit in (("render_s", "s"), ("kernel_chunk_s", "s"), ("frame_s", "s"), ("with_s", "s"),
                              ("without_s", "s"), ("block_chunk_s", "s"), ("cold_s", "s"), ("gpu_memory_mb", "MB"),
                              ("traced_pixels", "pixels")):
                yield case, key, r.get(key), unit


def cold_rows(doc):
    """``bench_cold.py``: per variant the medians of a new process's wall time, the CLI's and JAX's tracing."""
    arguments = " ".join(doc.get("arguments") or [])
    for variant, medians in (doc.get("medians") or {}).items():
        for key in ("wall_s", "cli_s", "trace_s"):
            yield f"swim render {arguments}, {variant}".replace("  ", " "), key, medians.get(key), "s"


def march_rows(doc):
    """``bench_march.py``: per kernel (the installed one, each ``--variant``, the experiments) ns per sample and the
    median pass; the per-ray set-up."""
    where = f"{doc.get('scene')} {doc.get('size')}" + (f" flush {doc['flush_mb']:g} MB" if doc.get("flush_mb") else "")
    for name, r in (doc.get("results") or {}).items():
        if isinstance(r, dict):
            yield f"{where}: {name}", "ns_per_sample", r.get("ns_per_sample"), "ns"
            yield f"{where}: {name}", "median_s", r.get("median_s"), "s"
    yield f"{where}: kernel", "setup_per_ray_us", (doc.get("results") or {}).get("setup_per_ray_us"), "us"


def instructions_rows(doc):
    """``bench_instructions.py``: instructions, branches and mispredicted branches per sample."""
    case = f"{doc.get('scene')} {doc.get('size')} chunk {doc.get('chunk')}"
    for key, value in (doc.get("per_sample") or {}).items():
        yield case, f"{key}_per_sample", value, "1"
    yield case, "samples_per_ray", doc.get("samples_per_ray"), "1"


def profile_rows(doc):
    """``profile_march.py``: ns per sample under ``perf``; the compiled code's, libm's, reference counting's shares."""
    case = f"{doc.get('scene')} {doc.get('size')}"
    yield case, "ns_per_sample", doc.get("ns_per_sample"), "ns"
    yield case, "compiled_share", doc.get("compiled_share"), "%"
    yield case, "libm_share", (doc.get("libraries") or {}).get("libm"), "%"
    yield case, "reference_counting_share", doc.get("reference_counting_share"), "%"


def settings_rows(doc):
    """``bench_settings.py``: per variant its warm time, traced pixels, samples per ray and the radiance's and optical
    depth's 99th percentile error over the image."""
    for variant, r in (doc.get("variants") or {}).items():
        case = f"{doc.get('case')}: {variant or 'defaults'}"
        yield case, "warm_s", r.get("warm_s"), "s"
        yield case, "traced_pixels", r.get("traced_pixels"), "pixels"
        yield case, "samples_per_ray", r.get("samples_per_ray"), "1"
        for key in ("error_pct", "tau_error_pct"):
            yield case, f"{key}_p99", ((r.get(key) or {}).get("all") or {}).get("p99"), "%"


def host_rows(doc):
    """``bench_host.py``: a GPU frame's host work with the ray table (and the image on the device) and without."""
    setting = "ray_table, device_image" if doc.get("device_image") else "ray_table"
    for r in doc.get("rows", []):
        case = f"{doc.get('scene')} {doc.get('size')} {r.get('sampling')}, {setting}"
        yield case, "without_s", r.get("without_s"), "s"
        yield case, "with_s", r.get("with_s"), "s"


def frame_parts_rows(doc):
    """``frame_parts.py``: a frame's time, each program's, and the rest (the host's)."""
    stand_in = ", stand-in" if doc.get("stand_in") else ""
    for r in doc.get("rows", []):
        case = f"{doc.get('scene')} {doc.get('size')} {r.get('sampling')}{stand_in}"
        yield case, "frame_s", r.get("frame_s"), "s"
        yield case, "rest_s", r.get("rest_s"), "s"
        for name, part in (r.get("parts") or {}).items():
            yield case, f"{name} s", part.get("s"), "s"


def assimilation_rows(doc):
    """``bench_assimilation.py``: per scene and case the cold and warm seconds and the peak memory (renders: the
    render of a new state too); the gradient's ratios to the forward run and the renders."""
    size = doc.get("size")
    for scene, result in (doc.get("results") or {}).items():
        for case, r in (result.get("cases") or {}).items():
            if r.get("status") != "ok":
                continue
            for key, unit in (("cold_s", "s"), ("warm_s", "s"), ("new_state_s", "s"), ("peak_rss_mb", "MB")):
                yield f"{scene} {size} {case}", key, r.get(key), unit
        for key, value in (result.get("ratios") or {}).items():
            if key.startswith("gradient_per_"):
                yield f"{scene} {size}", key, value, "x"
