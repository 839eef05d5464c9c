"""The fused per-ray march on NVIDIA GPUs: :mod:`swim.rt.march_cpu`'s step loop compiled by numba-cuda.

The lockstep JAX march passes every ray's state through device memory ~20 times per step, which caps it at
~5 frames/s at 1024² on an H100 (docs/decisions/0006-gpu-kernels.md). Here each CUDA thread marches one ray with
its state in registers and local memory, as :func:`swim.rt.march_cpu.march_rays` does on a CPU core.

There is one source: the functions of :mod:`swim.rt.march_cpu` (written for numba's CPU target) are compiled a
second time as CUDA device functions, from their Python code, with their calls to each other resolved to the
device versions (:func:`_device_functions`). The kernel (:func:`cuda_march_kernel`) only allocates a thread's
work arrays and calls :func:`swim.rt.march_cpu._march_ray_range`, the CPU's loop over the rays, for the
thread's ray. The JAX set-up before the march (which the CPU kernel has in numba,
:func:`swim.rt.march_cpu.prepare_rays`) and the composition after it are shared with the JAX kernel
(:func:`swim.rt.march.trace_rays`).

It computes in float64, like the CPU kernel: an H100 or H200 does float64 at half its float32 rate, consumer
GPUs at 1/32-1/64 of it. Without a GPU, numba's CUDA simulator (``NUMBA_ENABLE_CUDASIM=1``) runs the same
kernel in Python, which is how the tests hold it to the CPU kernel on machines without one.
"""

from __future__ import annotations

import functools
import inspect
import logging
import types

import numpy as np

from ..errors import SwimInputError
from . import march_cpu

logger = logging.getLogger(__name__)

#: The functions of :mod:`swim.rt.march_cpu` that the kernel calls, directly or through each other.
DEVICE_FUNCTIONS = ("_index_map", "_round_half_even", "_ix", "_clip", "_radius_and_height",
                    "_height_and_indices", "_point_geometry", "_geometry_constants", "_probe_indices", "_step_geometry",
                    "_bilinear", "_bilinear_index", "_lerp_index", "_bilinear_at", "_bilinear_clamped", "_terrain_gap",
                    "_gap_along", "_terrain_crossing", "_lower_corner", "_prefetch_corners", "_segment_cells",
                    "_probe_occupancy", "_adaptive_edges", "_clear_edges", "_descending_at", "_lowest_along",
                    "_column_above", "_after_steps", "_invert_cdf", "_predicted_halving", "_corner_lane",
                    "_corner_lanes", "_profile_lanes", "_mean_transmittance", "_accumulate_lanes", "_field_at",
                    "_cloud_sources", "_ratio_above", "_accumulate_cloud", "_march_ray_range")
#: CUDA threads per block: ray marches diverge (a ray stops at the ground, refines cloud faces), so small blocks.
THREADS_PER_BLOCK = 128


def cuda_available() -> bool:
    """Whether numba-cuda sees a GPU (or runs its simulator, ``NUMBA_ENABLE_CUDASIM=1``)."""
    try:
        from numba import cuda
    except ImportError:  # pragma: no cover - numba without its CUDA target
        return False
    try:
        return bool(cuda.is_available())
    except Exception:  # noqa: BLE001 - a broken driver is "no GPU" here, with the reason in the log
        logger.debug("numba-cuda finds no usable GPU", exc_info=True)
        return False


def require_cuda():
    """Raise :class:`~swim.errors.SwimInputError` unless numba-cuda sees a GPU (or runs its simulator) and can
    compile for it with the installed NumPy."""
    if not cuda_available():
        raise SwimInputError("MarchSettings.backend='cuda' needs an NVIDIA GPU that numba-cuda can use "
                             "(pip install 'swim-imagery[cuda]', i.e. numba-cuda; NUMBA_ENABLE_CUDASIM=1 runs its "
                             "simulator instead)")
    try:
        _load_cuda_lowering()
    except AttributeError as exc:
        raise SwimInputError(
            f"MarchSettings.backend='cuda': the installed numba-cuda cannot compile with NumPy {np.__version__} "
            f"({exc}). numba-cuda 0.30 registers numpy.row_stack, which NumPy 2.5 removed: install NumPy < 2.5 or a "
            "numba-cuda release that supports your NumPy") from exc


def _load_cuda_lowering():
    """Import numba-cuda's lowering registry, which its first compilation would import anyway: numba-cuda 0.30.4
    fails there with NumPy 2.5 (an AttributeError for ``numpy.row_stack``; seen on an H100 machine).
    Nothing to check in numba's simulator or where the module does not exist."""
    from numba.core import config

    if config.ENABLE_CUDASIM:
        return
    try:
        import numba.cuda.cudaimpl  # noqa: F401
    except ImportError:  # pragma: no cover - a numba-cuda layout without it
        return


def _max2(a, b):
    return b if b > a else a


def _min2(a, b):
    return b if b < a else a


def _no_prefetch(array, k, j, i):
    """:func:`swim.rt.march_cpu._prefetch` on a GPU: nothing (a CPU's cache hint; a GPU hides memory latency with
    its other threads)."""
    return


@functools.lru_cache(maxsize=1)
def _device_functions():
    """The functions of :data:`DEVICE_FUNCTIONS` as CUDA device functions (name -> function).

    Each is a copy of the CPU function's Python code whose globals are a copy of :mod:`swim.rt.march_cpu`'s
    namespace in which those names are the device versions: numba resolves a function's calls from its globals
    when it compiles it, so the device functions call each other, never the CPU dispatchers."""
    from numba import cuda

    namespace = dict(vars(march_cpu))
    # Python's two-argument max and min as device functions (the same result: the first argument unless the
    # second is larger, or smaller): numba's own overloads of them do not compile for its deprecated built-in
    # CUDA target, which is what a machine without numba-cuda has for the compile check of the tests
    namespace["max"] = cuda.jit(device=True)(_max2)
    namespace["min"] = cuda.jit(device=True)(_min2)
    namespace["_prefetch"] = cuda.jit(device=True)(_no_prefetch)
    for name in DEVICE_FUNCTIONS:
        python = getattr(march_cpu, name).py_func
        clone = types.FunctionType(python.__code__, namespace, name, python.__defaults__, python.__closure__)
        namespace[name] = cuda.jit(device=True)(clone)  # compiled when the kernel that calls it is
    return {name: namespace[name] for name in DEVICE_FUNCTIONS}


def kernel_arguments() -> tuple:
    """The argument names of :func:`swim.rt.march_cpu.march_rays`, which the CUDA kernel takes too."""
    return tuple(inspect.signature(march_cpu.march_rays).parameters)


#: Sizes of one ray's work arrays: the CPU kernel's (one definition for both).
work_sizes = march_cpu.work_sizes


def kernel_work_sizes(values) -> tuple:
    """:func:`work_sizes` for a call's arguments (``values``: a mapping from :func:`kernel_arguments` to values)."""
    return work_sizes(values["n_before"], values["n_grid"], values["n_after"], values["n_probe"],
                      values["n_probe_max"], values["n_clear_probe"], values["refine_slots"],
                      values["tau_species"].shape[1], values["volume"].shape[3], values["ms_profile"].shape[2])


@functools.lru_cache(maxsize=8)
def cuda_march_kernel(n_edges, n_cdf, n_slots, n_saved, n_species, n_channels, n_u, fastmath=False):
    """The CUDA kernel of :func:`swim.rt.march_cpu.march_rays`: one thread per ray, the work arrays of
    :func:`work_sizes` in the thread's local memory (their sizes are compile-time constants, hence one kernel
    per combination). It takes ``march_rays``' arguments (:func:`kernel_arguments`), the outputs as device
    arrays, and is launched over ``ceil(n / THREADS_PER_BLOCK)`` blocks of :data:`THREADS_PER_BLOCK`."""
    import numba
    from numba import cuda

    march_ray_range = _device_functions()["_march_ray_range"]
    names = ", ".join(kernel_arguments())
    # the argument list is the CPU kernel's, written once there; the body allocates and calls
    source = (
        f"def march_rays_cuda({names}):\n"
        "    r = cuda.grid(1)\n"
        "    if r < start.shape[0]:\n"
        "        edges = cuda.local.array(N_EDGES, float64)\n"
        "        cdf = cuda.local.array(N_CDF, float64)\n"
        "        stack_lo = cuda.local.array(N_SLOTS, float64)\n"
        "        stack_hi = cuda.local.array(N_SLOTS, float64)\n"
        "        stack_depth = cuda.local.array(N_SLOTS, int64)\n"
        "        saved = cuda.local.array(N_SAVED, float64)\n"
        "        tsp = cuda.local.array(N_SPECIES, float64)\n"
        "        ms_lanes = cuda.local.array((N_U, MS_LANE_COLUMNS), float64)\n"
        "        for u in range(N_U):\n"
        "            for c in range(MS_LANE_COLUMNS):\n"
        "                ms_lanes[u, c] = 0.0\n"
        "        vol = cuda.local.array(N_CHANNELS, float64)\n"
        "        vol32 = cuda.local.array(N_CHANNELS, float32)\n"
        "        probe_at = cuda.local.array((6, PROBE_BLOCK), float64)\n"
        f"        march_ray_range(r, r + 1, 1, {names}, edges, cdf, stack_lo, stack_hi, stack_depth, saved, tsp,\n"
        "                        ms_lanes, vol, vol32, probe_at)\n"
    )
    namespace = {"cuda": cuda, "float64": numba.float64, "float32": numba.float32, "int64": numba.int64,
                 "march_ray_range": march_ray_range, "N_EDGES": n_edges, "N_CDF": n_cdf, "N_SLOTS": n_slots,
                 "N_SAVED": n_saved, "N_SPECIES": n_species, "N_CHANNELS": n_channels, "N_U": n_u,
                 "MS_LANE_COLUMNS": 3 * march_cpu.LANES,
                 "PROBE_BLOCK": march_cpu.PROBE_BLOCK}
    name = f"<swim.rt.march_cuda kernel {n_edges}/{n_cdf}/{n_slots}/{n_channels}/{n_u}>"
    exec(compile(source, name, "exec"), namespace)
    return cuda.jit(fastmath=fastmath)(namespace["march_rays_cuda"])


#: Device copies of the last tables' big arrays (:func:`device_tables`, :func:`swim.rt.march.device_copies`).
_TABLE_COPIES = {}
#: The same for the last sky table's lanes, kept apart: a new sun's sky does not copy the volume again.
_SKY_LANE_COPIES = {}


def device_tables(tables):
    """``tables`` (:func:`swim.rt.march._numba_tables`) with the arrays of :data:`swim.rt.march.HOST_CONSTANTS`
    (the packed volume and the step classes, :func:`swim.rt.march.step_classes`) and the sky table's lanes (3 MB) on
    the GPU, copied once per host array (:func:`swim.rt.march.device_copies`); the kernel's launches copy the small
    tables with the rays."""
    from numba import cuda

    from .march import HOST_CONSTANTS, device_copies

    def transfer(a):
        return cuda.to_device(np.ascontiguousarray(a))

    return {**tables, **device_copies({key: tables[key] for key in HOST_CONSTANTS}, transfer, _TABLE_COPIES),
            **device_copies({"sky_lanes": tables["sky_lanes"]}, transfer, _SKY_LANE_COPIES)}


def march_rays(*args):
    """:func:`swim.rt.march_cpu.march_rays` on the GPU: the same arguments (numpy arrays, or device arrays for
    the tables), the outputs written into the host arrays given, as there (on the default stream: the copies
    back wait for the kernel).

    Raises
    ------
    SwimInputError
        If numba-cuda finds no GPU.
    """
    from numba import cuda

    require_cuda()
    names = kernel_arguments()
    values = dict(zip(names, args))
    n = values["start"].shape[0]
    if n == 0:
        return
    kernel = cuda_march_kernel(*kernel_work_sizes(values))
    outputs = ("tau_clear", "tau_h", "tau_species", "l_clear", "i_nogas", "i_gas", "i_cloud_t", "alive_out", "hit_out",
               "s_hit_out", "samples_out", "l_cloud")
    device = {}
    for name in names:
        value = values[name]
        if isinstance(value, np.ndarray):
            value = cuda.to_device(np.ascontiguousarray(value)) if name not in outputs else \
                cuda.device_array(value.shape, value.dtype)
        elif hasattr(value, "__cuda_array_interface__") and not hasattr(value, "copy_to_host"):
            # another library's GPU array (JAX's multiple-scattering profiles), read in place; it must be ready
            # (block_until_ready). Wrapped here: numba-cuda 0.30 types such an argument through DLPack on a stream
            # that JAX refuses (CUDA_ERROR_INVALID_HANDLE)
            value = cuda.as_cuda_array(value, sync=False)
        device[name] = value
    blocks = -(-n // THREADS_PER_BLOCK)
    kernel[blocks, THREADS_PER_BLOCK](*(device[name] for name in names))
    for name in outputs:
        device[name].copy_to_host(values[name])
