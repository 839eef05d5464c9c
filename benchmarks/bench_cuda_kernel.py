"""The CUDA march kernel on one captured chunk: compile options, launch shapes and ray order (issue 6, goal 3).

Usage (on a machine with an NVIDIA GPU and numba-cuda; ``NUMBA_ENABLE_CUDASIM=1 --size 9`` runs it in
numba's simulator, to check the script)::

    python benchmarks/bench_cuda_kernel.py --scene synthetic --variants --orders --out cuda-kernel.json
    python benchmarks/bench_cuda_kernel.py --scene synthetic --save /tmp/chunk.npz
    ncu --kernel-name regex:march --launch-count 1 --section WarpStateStats --section Occupancy \\
        python benchmarks/bench_cuda_kernel.py --launch /tmp/chunk.npz

It renders the suite's 1024 x 1024 all-sky view of ``--scene`` with ``MarchSettings(backend="cuda")``, keeps the
arguments of its largest kernel call (a full chunk of ``GPU_CHUNK`` rays) and launches the kernel again on them,
with the inputs already on the device (median of ``--repeats`` synchronised launches):

* ``--variants``: the kernel compiled with ``max_registers`` capped (None, 168, 128, 96) and launched in blocks of
  64, 128 and 256 threads; registers and local memory per thread as numba-cuda reports them;
* ``--orders``: the chunk's rays in image (tile) order, sorted by their sample counts (every warp's rays equally
  long), by the direction's third component, and shuffled; the outputs are checked to be the same rays' outputs,
  and ``warp max/mean`` is the mean over warps of the longest ray's samples over the warp's mean (1: no ray of a
  warp waits for another);
* ``--save``/``--launch``: the captured chunk to an ``.npz`` file and one launch of it in a new process (no render),
  for Nsight Compute (``ncu``).

What an H100's results decided: docs/decisions/0006-gpu-kernels.md.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

import bench_gpu  # noqa: E402  (CudaProbe: the kernel's calls captured)
import bench_suite  # noqa: E402  (the suite's scenes, views and render options)

OUTPUTS = ("i_gas", "l_clear", "tau_h", "samples_out")


def capture(scene_name, data, size=None):
    """Host copies of the arguments of the largest kernel call of a warm render (name -> value)."""
    import swim
    from swim.rt import march_cuda
    from swim.rt.march import MarchSettings

    probe = bench_gpu.CudaProbe()
    spec = json.loads(json.dumps(bench_suite.CASES[f"{scene_name}_allsky"]))
    spec.update(data=str(data), backend="cuda")
    if scene_name == "synthetic":
        spec["scene_kwargs"] = dict(bench_suite.SYNTHETIC_GRID)
    if size:
        spec["image"] = [size, size]
    kw = bench_suite.render_kwargs(spec)
    kw["settings"] = MarchSettings(backend="cuda")
    swim.render(bench_suite.load_scene(spec), **kw)
    values = {}
    for name, value in zip(march_cuda.kernel_arguments(), probe.captured):
        if hasattr(value, "copy_to_host"):  # numba's device arrays (the volume, the occupancy grid)
            value = value.copy_to_host()
        elif hasattr(value, "__cuda_array_interface__") and not isinstance(value, np.ndarray):  # JAX's
            value = np.asarray(value)
        values[name] = value
    return values


def launcher(values, kernel, threads=None):
    """A function that launches ``kernel`` on ``values`` (copied to the device once) and returns (the median
    time of ``repeats`` synchronised launches [s], the outputs of :data:`OUTPUTS` as host arrays)."""
    from numba import cuda

    from swim.rt import march_cuda

    names = march_cuda.kernel_arguments()
    device = [cuda.to_device(np.ascontiguousarray(v)) if isinstance(v, np.ndarray) else v
              for v in (values[k] for k in names)]
    n = values["start"].shape[0]
    threads = threads or march_cuda.THREADS_PER_BLOCK
    launch = kernel[-(-n // threads), threads]

    def run(repeats):
        launch(*device)
        cuda.synchronize()
        runs = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            launch(*device)
            cuda.synchronize()
            runs.append(time.perf_counter() - t0)
        return (statistics.median(runs) if runs else None), {k: device[names.index(k)].copy_to_host() for k in OUTPUTS}

    return run


def variants(values, repeats):
    from numba import cuda

    from swim.rt import march_cuda

    base = march_cuda.cuda_march_kernel(*march_cuda.kernel_work_sizes(values))
    rows = []
    for regs in (None, 168, 128, 96):
        kernel = base if regs is None else cuda.jit(max_registers=regs)(base.py_func)
        for threads in (64, 128, 256):
            seconds, _ = launcher(values, kernel, threads)(repeats)
            row = {"max_registers": regs, "threads_per_block": threads, **bench_gpu.kernel_resources(kernel),
                   "kernel_ms": 1e3 * seconds}
            print(row, flush=True)
            rows.append(row)
    return rows


def warp_ratio(samples):
    w = samples[: samples.size // 32 * 32].reshape(-1, 32)
    return float(np.mean(w.max(1)) / np.mean(w.mean(1)))


def orders(values, repeats):
    from swim.rt import march_cuda

    kernel = march_cuda.cuda_march_kernel(*march_cuda.kernel_work_sizes(values))
    n = values["start"].shape[0]

    def permuted(order):
        out = {}
        for k, v in values.items():
            if isinstance(v, np.ndarray) and k == "ms_profile" and v.ndim == 3 and v.shape[1] >= n:
                v = v.copy()  # JAX's padded chunk: its first n rows are the rays'
                v[:, :n] = v[:, order]
            elif isinstance(v, np.ndarray) and v.ndim >= 1 and v.shape[0] == n and k in march_cuda.kernel_arguments():
                v = v[order]
            out[k] = v
        return out

    seconds, base = launcher(values, kernel)(repeats)
    samples = base["samples_out"]
    rows = [{"order": "image (tiles)", "kernel_ms": 1e3 * seconds, "warp_max_over_mean": warp_ratio(samples),
             "samples_mean": float(samples.mean()), "samples_p99": float(np.percentile(samples, 99))}]
    print(rows[0], flush=True)
    for label, order in (("sorted by samples", np.argsort(samples, kind="stable")),
                         ("sorted by direction[:, 2]", np.argsort(values["direction"][:, 2], kind="stable")),
                         ("shuffled", np.random.default_rng(1).permutation(n))):
        seconds, out = launcher(permuted(order), kernel)(repeats)
        inverse = np.empty_like(order)
        inverse[order] = np.arange(n)
        differ = max(float(np.max(np.abs(out[k][inverse] - base[k]))) for k in OUTPUTS)
        row = {"order": label, "kernel_ms": 1e3 * seconds, "warp_max_over_mean": warp_ratio(samples[order]),
               "outputs_differ_by": differ}
        print(row, flush=True)
        rows.append(row)
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="synthetic", choices=("synthetic", "katrina", "rico"))
    ap.add_argument("--data", type=Path, default=bench_suite.DATA)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--variants", action="store_true", help="register caps and block sizes")
    ap.add_argument("--orders", action="store_true", help="the chunk's rays in other orders")
    ap.add_argument("--save", type=Path, default=None, help="write the captured chunk to this .npz file")
    ap.add_argument("--launch", type=Path, default=None, help="launch a saved chunk once (for ncu) and stop")
    ap.add_argument("--size", type=int, default=None, help="image width and height (default: the suite's 1024)")
    ap.add_argument("--out", type=Path, default=None, help="JSON file of the figures")
    args = ap.parse_args(argv)
    from swim.rt import march_cuda

    if args.launch:
        with np.load(args.launch) as saved:
            values = {k: (saved[k].item() if saved[k].ndim == 0 else saved[k]) for k in saved.files}
        kernel = march_cuda.cuda_march_kernel(*march_cuda.kernel_work_sizes(values))
        launcher(values, kernel)(0)
        print(f"launched {values['start'].shape[0]} rays", flush=True)
        return
    values = capture(args.scene, args.data, args.size)
    doc = {"scene": args.scene, "rays": int(values["start"].shape[0])}
    if args.save:
        np.savez(args.save, **{k: np.asarray(v) for k, v in values.items()})
    if args.variants:
        doc["variants"] = variants(values, args.repeats)
    if args.orders:
        doc["orders"] = orders(values, args.repeats)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(doc, indent=1))


if __name__ == "__main__":
    main()
