"""Registers, spills and occupancy of the fused GPU march (``swim.rt.march_pallas``) for an H100/H200, on a CPU.

Nsight Compute on an H200 (docs/decisions/0006-gpu-kernels.md) found the fused kernel at 255 registers per thread: two
programs of 128 rays per multiprocessor, 12.5 % occupancy, and its warps waiting on their gathers 59 % of the time.
How many registers a variant of the kernel needs can be known without a GPU: this script captures the kernel's
arguments from a small render of the synthetic scene (JAX's CPU backend), lowers it for CUDA
(``lowering_platforms=("cuda",)``), compiles the Triton module to PTX with the CUDA plugin's own Triton pipeline (the
one that a GPU run uses), assembles the PTX for sm_90a with ``ptxas -v`` and disassembles it (``cuobjdump -sass``).
It prints, for each kernel and block shape (rays per program x warps), the registers per thread, the spills, the
SASS instructions and the theoretical occupancy on a Hopper multiprocessor (65 536 registers, 64 warps, 32 programs).

ptxas caps the registers at 65 536 / (threads per program), at most 255: 128 rays x 4 warps may take 255, 512 x 16
only 128 (four programs of 4 warps' worth per multiprocessor, at the price of spills), 1024 x 32 only 64.
Pallas offers no other cap (no ``maxnreg``); swim's kernels take one through their name (``--blocks 128x4r128``:
128 registers per thread, PTX's ``.maxnreg``, :mod:`swim.rt.ptx_edits`); ``128x4s``: the tables read by a scalar
gather per channel (``ExecutionSettings.fused_vector_loads`` off: one load per channel, not four); ``128x4f``: the float32
multiplies and adds free to be contracted into fused multiply-adds (``ExecutionSettings.fused_fma``,
docs/decisions/0006-gpu-kernels.md). The grid loop's instructions are also counted by kind (``loop_ops``: FFMA, FMUL,
FADD, FSEL, LDG, ...).

Needs, beside swim's own environment (nothing that the tests or a render need):

* the CUDA plugin of this jaxlib's version (its Triton pipeline), e.g. ``pip install --no-deps --target
  /tmp/cuda-site jax-cuda12-plugin==X jax-cuda12-pjrt==X`` with X = ``jaxlib.__version__``; it needs no GPU and no
  CUDA libraries here (the script sets ``JAX_SKIP_CUDA_CONSTRAINTS_CHECK``);
* a ``ptxas`` (and ``cuobjdump``) new enough for that PTX: ``--ptxas``, or Triton's wheel in the same folder
  (``pip install --no-deps --target /tmp/cuda-site triton``; its ``ptxas-blackwell`` is CUDA 12.9's).

Usage::

    PYTHONPATH=/tmp/cuda-site python benchmarks/pallas_registers.py --kernels fused fused-march \
        --blocks 128x4 512x16 1024x32 --out /tmp/registers.json

On this project's 2-core machine each kernel and shape takes ~15-25 s (the lowering and ptxas).
"""

from __future__ import annotations

import argparse
import collections
import io
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

os.environ.setdefault("JAX_SKIP_CUDA_CONSTRAINTS_CHECK", "1")  # the plugin's CUDA libraries are not needed here
# the march traced anew, not read from the export cache: the kernel's call is captured while it is traced
os.environ["SWIM_JAX_EXPORT"] = "0"

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

#: A Hopper multiprocessor (H100, H200): registers, warps and resident programs, and the register allocation's
#: granularity per thread.
SM_REGISTERS, SM_WARPS, SM_PROGRAMS, REGISTER_UNIT = 65536, 64, 32, 8


class _Captured(Exception):
    pass


_SCENE = []


def _scene():
    """The suite's synthetic 400 x 400 x 60 scene, built once."""
    import scenes

    if not _SCENE:
        _SCENE.append(scenes.synthetic_scene())
    return _SCENE[0]


def capture_kernel_call(kernel, size=32):
    """(function, positional arguments, keyword arguments) of the Pallas kernel's call in a small JAX render of the
    synthetic scene with ``MarchSettings(grid_kernel=kernel)``: arrays as ``jax.ShapeDtypeStruct``."""
    import jax

    import swim
    from swim.rt import march_pallas
    from swim.rt.march_settings import ExecutionSettings, MarchSettings

    real = {"fused": march_pallas.march_grid_fused, "fused-march": march_pallas.march_segments_fused}
    captured = {}

    def grab(*args, **kwargs):
        captured.update(args=args, kwargs=kwargs)
        raise _Captured

    def spec(tree):
        return jax.tree_util.tree_map(
            lambda a: jax.ShapeDtypeStruct(a.shape, a.dtype) if hasattr(a, "shape") else a, tree)

    name = {"fused": "march_grid_fused", "fused-march": "march_segments_fused"}[kernel]
    setattr(march_pallas, name, grab)
    try:
        swim.render(_scene(), camera_options={"size": size}, sun_zenith=35.0, sun_azimuth=140.0,
                    settings=MarchSettings(execution=ExecutionSettings(backend="jax", grid_kernel=kernel, chunk=1024)))
    except _Captured:
        pass
    finally:
        setattr(march_pallas, name, real[kernel])
    if not captured:
        raise RuntimeError(f"the render did not call the {kernel!r} kernel")
    args = []
    for a in captured["args"]:
        if isinstance(a, tuple) and a and isinstance(a[0], march_pallas.Segment):
            a = tuple(replace(seg, edges=spec(seg.edges), steps=spec(seg.steps)) for seg in a)
        elif hasattr(a, "shape") or isinstance(a, dict):
            a = spec(a)
        args.append(a)
    return real[kernel], args, {k: spec(v) for k, v in captured["kwargs"].items()}


def triton_module(fn, args, kwargs, block_rays, num_warps, max_registers=None, vector_loads=True, fma=False):
    """The Triton module (MLIR bytecode) of the kernel's CUDA lowering with this block shape (and register cap and
    fused multiply-adds: the kernel's name carries them, :mod:`swim.rt.ptx_edits`)."""
    import jax
    from jax._src.pallas.triton import pallas_call_registration as registration

    from swim.rt.march_pallas import Segment

    arrays, slots = [], []
    for a in args:  # the arrays travel as the jitted function's arguments, everything else is closed over
        if isinstance(a, tuple) and a and isinstance(a[0], Segment):
            arrays.append([(seg.edges, seg.steps) for seg in a])
            slots.append(("segments", a))
        elif hasattr(a, "shape") or isinstance(a, dict):
            arrays.append(a)
            slots.append(("array", None))
        else:
            slots.append(("static", a))
    array_kw = {k: v for k, v in kwargs.items() if hasattr(v, "shape")}
    static_kw = {k: v for k, v in kwargs.items() if not hasattr(v, "shape")}
    static_kw.update(interpret=False, block_rays=block_rays, num_warps=num_warps, max_registers=max_registers,
                     vector_loads=vector_loads, fma=fma)

    def call(arrays, array_kw):
        it, full = iter(arrays), []
        for kind, value in slots:
            if kind == "static":
                full.append(value)
            elif kind == "array":
                full.append(next(it))
            else:
                full.append(tuple(replace(seg, edges=e, steps=s) for seg, (e, s) in zip(value, next(it))))
        return fn(*full, **static_kw, **array_kw)

    modules = []
    real = registration.lowering.lower_jaxpr_to_triton_module

    def keep(*a, **k):
        result = real(*a, **k)
        buf = io.BytesIO()
        result.module.operation.write_bytecode(buf)
        modules.append(buf.getvalue())
        return result

    registration.lowering.lower_jaxpr_to_triton_module = keep
    try:
        jax.jit(call).trace(arrays, array_kw).lower(lowering_platforms=("cuda",))
    finally:
        registration.lowering.lower_jaxpr_to_triton_module = real
    if not modules:
        raise RuntimeError("no Triton module in the CUDA lowering")
    return modules[-1]


def find_tools(ptxas=None):
    """(ptxas, cuobjdump): ``ptxas`` or Triton's bundled CUDA 12.9 ptxas, and the cuobjdump beside it or on PATH."""
    if ptxas is None:
        try:
            import triton

            folder = Path(triton.__file__).parent / "backends" / "nvidia" / "bin"
        except ImportError:
            folder = None
        for name in ("ptxas-blackwell", "ptxas"):
            if folder is not None and (folder / name).exists():
                ptxas = str(folder / name)
                break
        ptxas = ptxas or shutil.which("ptxas")
    if ptxas is None:
        raise SystemExit("no ptxas: install Triton's wheel beside the CUDA plugin or pass --ptxas")
    cuobjdump = Path(ptxas).parent / "cuobjdump"
    return ptxas, str(cuobjdump) if cuobjdump.exists() else shutil.which("cuobjdump")


def assemble(ptx, ptxas, cuobjdump):
    """ptxas -v's registers, spills and stack frame, and the SASS instructions (all, local loads and stores)."""
    with tempfile.TemporaryDirectory() as folder:
        source, cubin = Path(folder) / "kernel.ptx", Path(folder) / "kernel.cubin"
        source.write_text(ptx)
        out = subprocess.run([ptxas, "-arch=sm_90a", "-v", str(source), "-o", str(cubin)], capture_output=True,
                             text=True)
        if out.returncode:
            raise RuntimeError(f"ptxas failed: {out.stderr[-800:]}")
        text = out.stderr
        numbers = {"registers": r"Used (\d+) registers", "stack_frame_bytes": r"(\d+) bytes stack frame",
                   "spill_store_bytes": r"(\d+) bytes spill stores", "spill_load_bytes": r"(\d+) bytes spill loads"}
        row = {key: int(re.search(pattern, text).group(1)) for key, pattern in numbers.items()}
        if cuobjdump:
            sass = subprocess.run([cuobjdump, "-sass", str(cubin)], capture_output=True, text=True).stdout
            lines = [line for line in sass.splitlines() if re.match(r"\s+/\*[0-9a-f]{4,}\*/", line)]
            row["sass_instructions"] = len(lines)
            row["sass_local_loads"] = sum(" LDL" in line for line in lines)
            row["sass_local_stores"] = sum(" STL" in line for line in lines)
            row.update(longest_loop(lines))
    return row


def longest_loop(lines):
    """The longest loop of a SASS listing (the march's grid loop): its instructions, its global loads (``LDG``, any
    width; and the 16-byte ones) and its local loads and stores (spills), from the widest backward branch."""
    code = []
    for line in lines:
        match = re.match(r"\s+/\*([0-9a-f]{4,})\*/\s+(.*?);", line)
        if match:
            code.append((int(match.group(1), 16), match.group(2)))
    loops = [(int(target.group(1), 16), at) for at, text in code
             if (target := re.search(r"BRA\b.*?0x([0-9a-f]+)", text)) and int(target.group(1), 16) < at]
    if not loops:
        return {}
    first, last = max(loops, key=lambda loop: loop[1] - loop[0])
    body = [text for at, text in code if first <= at <= last]
    # by kind: the opcode without its predicate and modifiers (FFMA, FMUL, LDG, ...), most frequent first
    kinds = collections.Counter(re.sub(r"^@!?U?P\w+\s+", "", text).split()[0].split(".")[0] for text in body)
    return {"loop_instructions": len(body), "loop_ops": dict(kinds.most_common()),
            "loop_global_loads": sum(" LDG" in f" {t}" for t in body),
            "loop_global_loads_128": sum("LDG.E.128" in t for t in body),
            "loop_local_loads": sum(" LDL" in f" {t}" for t in body),
            "loop_local_stores": sum(" STL" in f" {t}" for t in body)}


def occupancy(registers, threads):
    """Programs per multiprocessor and theoretical occupancy (warps resident / 64) for a Hopper SM."""
    per_thread = -(-registers // REGISTER_UNIT) * REGISTER_UNIT
    warps = threads // 32
    programs = min(SM_REGISTERS // (per_thread * threads), SM_WARPS // warps, SM_PROGRAMS)
    return programs, programs * warps / SM_WARPS


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kernels", nargs="+", default=["fused"], choices=("fused", "fused-march"))
    ap.add_argument("--blocks", nargs="+", default=["128x4", "512x16"],
                    help="RAYSxWARPS per Triton program, then rN: capped at N registers per thread, then s: a scalar "
                         "gather per table channel (ExecutionSettings.fused_vector_loads off), then f: fused "
                         "multiply-adds (ExecutionSettings.fused_fma)")
    ap.add_argument("--ptxas", default=None, help="ptxas to assemble with (default: Triton's, else PATH's)")
    ap.add_argument("--out", default=None, help="JSON file")
    args = ap.parse_args(argv)

    import jax
    import jaxlib
    from jax._src.lib import triton

    from swim.rt.ptx_edits import edit_ptx

    if not triton.has_compilation_handler("CUDA"):
        jax.devices()  # the plugin registers its Triton pipeline as it initialises
    if not triton.has_compilation_handler("CUDA"):
        raise SystemExit(f"no CUDA Triton pipeline: install jax-cuda12-plugin=={jaxlib.__version__} and "
                         f"jax-cuda12-pjrt=={jaxlib.__version__} (see this script's docstring)")
    ptxas, cuobjdump = find_tools(args.ptxas)
    rows = []
    print("| kernel | rays x warps | registers | spill stores / loads [B] | SASS instructions | local ld / st "
          "| grid loop: instructions, global loads (16-byte), local ld / st | programs per SM | occupancy |")
    print("|---|---|---|---|---|---|---|---|---|")
    for kernel in args.kernels:
        fn, call_args, call_kwargs = capture_kernel_call(kernel)
        for text in args.blocks:
            spec = re.fullmatch(r"(\d+)x(\d+)(?:r(\d+))?(s?)(f?)", text)
            if spec is None:
                raise SystemExit(f"--blocks: {text!r} is not RAYSxWARPS[rN][s][f]")
            rays, warps = int(spec.group(1)), int(spec.group(2))
            cap = int(spec.group(3)) if spec.group(3) else None
            t0 = time.perf_counter()
            module = triton_module(fn, call_args, call_kwargs, rays, warps, cap, vector_loads=not spec.group(4),
                                   fma=bool(spec.group(5)))
            compiled = triton.compile("CUDA", module, "9.0", num_warps=warps, num_ctas=1, num_stages=1)
            ptx = edit_ptx(compiled.asm)  # what the render's lowering does (swim.rt.ptx_edits)
            row = {"kernel": kernel, "block": text, "ptx_chars": len(ptx), **assemble(ptx, ptxas, cuobjdump)}
            row["programs_per_sm"], row["occupancy"] = occupancy(row["registers"], warps * 32)
            row["seconds"] = time.perf_counter() - t0
            rows.append(row)
            print(f"| {kernel} | {text} | {row['registers']} | {row['spill_store_bytes']} / "
                  f"{row['spill_load_bytes']} | {row.get('sass_instructions', '-')} | "
                  f"{row.get('sass_local_loads', '-')} / {row.get('sass_local_stores', '-')} | "
                  f"{row.get('loop_instructions', '-')}, {row.get('loop_global_loads', '-')} "
                  f"({row.get('loop_global_loads_128', '-')}), {row.get('loop_local_loads', '-')} / "
                  f"{row.get('loop_local_stores', '-')} | {row['programs_per_sm']} | {row['occupancy']:.1%} |",
                  flush=True)
            kinds = row.get("loop_ops", {})
            print("    grid loop by kind: " + ", ".join(f"{op} {count}" for op, count in list(kinds.items())[:10]),
                  flush=True)
    if args.out:
        Path(args.out).write_text(json.dumps({"jax": jax.__version__, "ptxas": ptxas, "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
