"""The numba march kernel compiled in a helper process on a cold cache, while the render gets on with its own work.

A process whose numba disk cache (:mod:`swim.rt.march_cpu`, ``$SWIM_CACHE_DIR/numba``) lacks the kernels compiles them
at their first calls, one after the other: numba holds one compiler lock per process, so two threads cannot compile
at once. The README's ``swim render`` on a new installation spent 24.7 s of its 27.5 s compiling, 14.3 s of it the
march (:func:`swim.rt.march_cpu._march_ray_range`, which :func:`~swim.rt.march_cpu.march_rays` calls: numba's type
inference of its step loop and ~50 helpers, then LLVM).

A second process can compile at the same time. :func:`start`, called by :func:`swim.pipeline.render` before any
work (and, through :func:`start_early`, by ``swim render`` before its other imports and the scene), finds the march
missing from the disk cache and starts ``python -m swim.rt.precompile _march_ray_range``, which
compiles it into that cache with the argument types that the render will pass (:func:`kernel_signature`). The
render meanwhile reads the scene, builds the optics and runs Step 1a. Its first chunk (:func:`wait`, from
:func:`swim.rt.march._trace_chunk_numba`) compiles the per-ray set-up, which it calls first, and the composition
kernels, which it would compile after the march, then waits for the helper and loads the march from the cache.
Measured with the README's render and an empty cache: 15.1-15.4 s, with the march's loop over the rays compiled as
the kernel itself and the ground's tables built while the render waits (docs/decisions/0003-cpu-kernel-code.md).
Compiling the march in the render instead, after Step 1a, costs ~7 s more (23.9-24.0 s against 16.1-17.5 s where the
helper was measured first, docs/decisions/0008-cold-start.md).

The helper is only an optimisation. A kernel whose types differ from :func:`kernel_signature`'s is compiled by the
render itself; a helper that fails, cannot start or takes longer than :data:`WAIT_S` leaves the march to the
render (logged as a warning). Where ``fcntl`` exists, a file lock in the cache folder lets one helper compile while
the others wait and then load its result (two pytest-xdist workers, or several renders starting at once), and
:func:`swim.compilation.disk_cache.serialise_numba_cache_writes` keeps two processes from writing a function's cache
index at once. ``SWIM_PRECOMPILE=0`` turns the helper off; so does turning the disk caches off (``SWIM_JAX_CACHE=0``),
since the helper hands its result over through them. ``tests/unit/rt/test_precompile.py`` holds
:func:`kernel_signature` to the types of a real render's calls.
"""

from __future__ import annotations

import functools
import importlib
import inspect
import logging
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from ..compilation import numba_jit
from ..compilation.disk_cache import switched_off

log = logging.getLogger(__name__)

#: The kernels whose types :func:`kernel_signature` knows, and their modules.
KERNELS = {"_march_ray_range": "swim.rt.march_cpu", "prepare_rays": "swim.rt.march_cpu",
           "compose_clouds": "swim.rt.compose_cpu", "ground_radiance": "swim.rt.ground_cpu",
           "srgb8_pixels": "swim.color.srgb_cpu"}
#: Compiled by the helper process (the longest compilation by far).
HELPER_KERNELS = ("_march_ray_range",)
#: Compiled by the render's first chunk while it waits for the helper (in the order the chunk calls them; the colour
#: stage's kernel, ~0.9 s on an empty cache, last: the render calls it after the march).
WAITING_KERNELS = ("prepare_rays", "compose_clouds", "ground_radiance", "srgb8_pixels")
#: Longest wait for the helper [s] (it compiles the march in ~12 s on 2 cores); then it is stopped and the render
#: compiles the march itself.
WAIT_S = 180.0
#: Longest wait of a helper for another one's lock [s]; then it compiles anyway.
LOCK_WAIT_S = 150.0

_lock = threading.Lock()
_helper = None  # (subprocess.Popen, start time, stderr file) while a helper runs for this process


def _dispatcher(name):
    return getattr(importlib.import_module(KERNELS[name]), name)


def _argument_types():
    """The numba type of each argument of each kernel in :data:`KERNELS`, by parameter name, as
    :func:`swim.rt.march._trace_chunk_numba`, :func:`swim.rt.march._compose_numba` and the colour stage
    (:func:`swim.color.display.solar_relative_to_srgb8`) call them: per-chunk arrays
    are fresh C-contiguous numpy arrays, the render's tables C-contiguous and marked read-only
    (:func:`swim.rt.march._numba_tables`), Python ints int64."""
    from numba import types

    f8, f4, i8, i4, i1, b1 = types.float64, types.float32, types.int64, types.int32, types.int8, types.boolean

    def a(dtype, ndim):
        return types.Array(dtype, ndim, "C")

    def ro(dtype, ndim):
        return types.Array(dtype, ndim, "C", readonly=True)

    rays = {"start": a(f8, 2), "direction": a(f8, 2)}
    march = {
        **rays, "bounds": a(f8, 2), "valid": a(b1, 1), "p_rayleigh": a(f8, 1), "p_aerosol": a(f8, 2),
        "p_stratospheric": a(f8, 2), "class_lower": a(i4, 1), "class_weight": a(f8, 1), "ms_profile": a(f4, 3),
        "use_ms": b1, "n_before": i8, "n_grid": i8, "n_after": i8, "p": a(f8, 1), "coef": a(f8, 1),
        "beta_gas": ro(f4, 2), "spectra": ro(f4, 2), "sky_lanes": ro(f8, 3), "diffuse_classes": ro(f4, 3),
        "n_class": i8,
        "volume": ro(f4, 4), "terrain": ro(f4, 3), "occupancy": ro(i1, 3), "angstrom": ro(f4, 1),
        "aerosol_ssa": ro(f4, 1), "stratospheric_ssa": ro(f4, 1), "n_probe": i8, "empty_weight": f8,
        "probe_spacing": f8, "n_probe_max": i8, "cell_slack": f8, "empty_steps": i8, "empty_cells_per_step": f8,
        "sunlit_steps": i8, "sunlit_cells_per_step": f8,
        "n_clear_probe": i8, "clear_power": f8, "clear_floor": f8, "tau_refine": f8, "max_depth": i8,
        "refine_budget": i8, "refine_visible": f8, "refine_slots": i8, "n_bisections": i8, "stop_tau": f8,
        # outputs
        "tau_clear": a(f8, 2), "tau_h": a(f8, 1), "tau_species": a(f8, 2), "l_clear": a(f8, 2), "i_nogas": a(f8, 2),
        "i_gas": a(f8, 2), "i_cloud_t": a(f8, 1), "alive_out": a(b1, 1), "hit_out": a(b1, 1), "s_hit_out": a(f8, 1),
        "samples_out": a(i8, 1),
        # the 3-D cloud scattering's inputs (swim.rt.clouds; placeholders without it) and its output
        "cloud_mode": b1, "p_hydro": a(f4, 3), "ray_ms": a(f4, 3), "hydro_scale": ro(f8, 1),
        "hydro_narrow": ro(f8, 1), "ms_field": ro(f4, 4), "ms_coarsen": f8,
        "ms_above": ro(f4, 4), "above_heights": ro(f8, 1), "l_cloud": a(f8, 2)}
    prepare = {
        **rays, "bounds": a(f8, 2), "p": a(f8, 1), "coef": a(f8, 1), "aerosol_column": ro(f4, 3),
        "class_aod": ro(f4, 1), "ms_source": ro(f4, 5), "use_ms": b1, "class_lower": a(i4, 1),
        "class_weight": a(f8, 1), "ms_profile": a(f4, 3)}
    compose = {
        "tau_h": a(f8, 1), "tau_packed": a(f8, 2), "species": a(i8, 1), "i_nogas": a(f8, 2), "i_gas": a(f8, 2),
        "i_cloud_t": a(f8, 1), "l_clear": a(f8, 2), "l_surface": a(f4, 2), "valid": a(b1, 1), "cos_theta": a(f4, 1),
        "cos_view_zenith": a(f4, 1), "mu0": f8, "g_liquid": a(f8, 1), "backscatter": a(f8, 1),
        "coefficients": a(f8, 1), "lobes": a(f8, 2), "radiance_out": a(f4, 2), "cloud_out": a(f4, 2)}
    ground = {
        **rays, "s_hit": a(f8, 1), "surface": a(b1, 1), "cos_view_zenith": a(f4, 1), "tau_h": a(f8, 1),
        "tau_clear": a(f8, 2), "tau_packed": a(f8, 2), "species": a(i8, 1), "class_lower": a(i4, 1),
        "class_weight": a(f8, 1), "p": a(f8, 1), "coef": a(f8, 1), "sky": ro(f4, 3), "diffuse_classes": ro(f4, 3),
        "n_class": i8, "fields": ro(f4, 3), "fields_outside": ro(f4, 1), "angstrom": ro(f4, 1),
        "backscatter": ro(f4, 1), "lambertian": b1, "compose_coefficients": a(f8, 1), "k": ro(f8, 1),
        "rpv_q": ro(f8, 1), "snow_table": ro(f8, 2), "snow_albedo": ro(f8, 1), "subsurface": ro(f8, 1),
        "fade_cells": ro(f8, 1), "cloud_mode": b1, "out": a(f4, 2)}
    colour = {"radiance": a(f8, 2), "to_xyz": ro(f8, 2), "monomial": ro(f8, 2), "to_rgb": a(f8, 2),
              "luminance": ro(f8, 1), "mode": i8, "knee": f8, "steps": ro(f8, 1), "start": ro(i8, 1),
              "out": a(types.uint8, 2), "need": a(b1, 1)}
    work = {"edges": a(f8, 1), "cdf": a(f8, 1), "stack_lo": a(f8, 1), "stack_hi": a(f8, 1), "stack_depth": a(i8, 1),
            "saved": a(f8, 1), "tsp": a(f8, 1), "ms_lanes": a(f8, 2), "vol": a(f8, 1), "vol32": a(f4, 1),
            "probe_at": a(f8, 2)}
    ray_range = {"first": i8, "stop": i8, "stride": i8, **march, **work}
    return {"_march_ray_range": ray_range, "prepare_rays": prepare, "compose_clouds": compose,
            "ground_radiance": ground, "srgb8_pixels": colour}


def kernel_signature(name: str) -> tuple:
    """The numba signature (a tuple of argument types) with which a render calls the kernel ``name`` of
    :data:`KERNELS`.

    Raises
    ------
    KeyError
        If ``name`` is not in :data:`KERNELS`.
    RuntimeError
        If the kernel's parameters are not those that :func:`_argument_types` names (its code changed).
    """
    dispatcher = _dispatcher(name)
    types = _argument_types()[name]
    parameters = list(inspect.signature(dispatcher.py_func).parameters)
    if parameters != list(types):
        raise RuntimeError(f"swim.rt.precompile names the arguments of {name} as {list(types)}, but the kernel takes "
                           f"{parameters}: update _argument_types")
    return tuple(types[p] for p in parameters)


def is_cached(name: str) -> bool:
    """Whether the kernel ``name`` is compiled for :func:`kernel_signature` in this process or in numba's disk
    cache. True where numba's cache is off or its internals (private API) are not what this module expects: then
    nothing is compiled ahead."""
    dispatcher = _dispatcher(name)
    signature = kernel_signature(name)
    if signature in dispatcher.overloads:
        return True
    try:
        cache = dispatcher._cache
        key = cache._index_key(signature, dispatcher.targetctx.codegen())
        return key in cache._cache_file._load_index()
    except Exception:  # a NullCache (caching off) or another numba version's internals
        return True


def _helper_command(names) -> list[str]:
    return [sys.executable, "-m", "swim.rt.precompile", *names]


def _helper_environment() -> dict:
    """This process's environment with numba's cache folder and the folder that holds this swim package named
    explicitly, so that the helper compiles this code into the cache this process reads."""
    import numba

    from . import march_cpu

    env = dict(os.environ)
    env["NUMBA_CACHE_DIR"] = str(numba.config.CACHE_DIR)
    # the CPU and the features this process compiles for (swim.compilation.numba_target): numba's cache keys its
    # entries by them, and the helper, a fresh process, could choose others (this one's target may have been set up
    # before swim's choice)
    _, cpu_name, features = march_cpu._march_ray_range.targetctx.codegen().magic_tuple()
    env["NUMBA_CPU_NAME"], env["NUMBA_CPU_FEATURES"] = cpu_name, features
    root = str(Path(__file__).resolve().parents[2])
    env["PYTHONPATH"] = os.pathsep.join([root, *filter(None, [env.get("PYTHONPATH")])])
    return env


def _helper_needed() -> bool:
    """Whether numba's disk cache is on and lacks a kernel of :data:`HELPER_KERNELS` that this process has not
    compiled either."""
    from . import march_cpu

    try:
        return (numba_jit.CACHE_ON and not march_cpu._march_ray_range.signatures
                and not all(map(is_cached, HELPER_KERNELS)))
    except Exception:  # e.g. NUMBA_DISABLE_JIT=1: plain Python functions, nothing to compile
        return False


def start(backend: str) -> bool:
    """Start the helper process that compiles the march kernel into numba's disk cache, where ``backend`` is
    "numba" and that cache lacks it (see the module docstring); returns whether a helper has been started and not
    yet waited for (:func:`wait`).

    Called by :func:`swim.pipeline.render` before any work; cheap once the kernel is compiled in this process. Never
    raises: without a helper the render compiles the kernel itself."""
    global _helper
    if backend != "numba" or switched_off("SWIM_PRECOMPILE"):
        return False
    with _lock:
        if _helper is not None:
            return True
        # an interpreter that cannot start "python -m" (embedded, frozen): the render compiles the march itself
        if not sys.executable or getattr(sys, "frozen", False) or not _helper_needed():
            return False
        errors = None
        try:
            errors = tempfile.TemporaryFile()
            process = subprocess.Popen(_helper_command(HELPER_KERNELS), stdin=subprocess.DEVNULL,
                                       stdout=subprocess.DEVNULL, stderr=errors, env=_helper_environment())
        except Exception as error:  # only ever a head start
            if errors is not None:
                errors.close()
            log.warning("numba's cache lacks the march kernel and no helper process could start (%s)", error)
            return False
        _helper = (process, time.perf_counter(), errors)
        log.info("numba's cache lacks the march kernel: compiling it in a helper process (pid %d)", process.pid)
        return True


def start_early(backend: str) -> bool:
    """:func:`start` for a command that has not yet loaded the rest of swim or its scene (``swim render``): on a cold
    cache the march kernel's helper starts ~2 s sooner. ``backend`` is the command's option; "auto" counts as
    "numba" only where JAX can see no GPU (no GPU platform in ``JAX_PLATFORMS``, no JAX plugin installed), since
    telling for sure would mean initialising JAX's backends first. :func:`swim.pipeline.render` starts the helper in
    any case where it was not started here. Never raises."""
    try:
        if backend == "auto" and jax_may_see_a_gpu():
            return False
        return start("numba") if backend in ("auto", "numba") else False
    except Exception as error:  # only ever a head start
        log.info("no early start of the helper process (%s)", error)
        return False


def jax_may_see_a_gpu() -> bool:
    """Whether JAX may see a GPU or another accelerator: a GPU platform named in ``JAX_PLATFORMS``, or (without it)
    a JAX plugin installed. Tells without importing JAX; False means its default device is the CPU."""
    platforms = os.environ.get("JAX_PLATFORMS", "").strip().lower()
    if platforms:
        return any(name in platforms for name in ("cuda", "gpu", "rocm", "tpu", "metal"))
    return _jax_plugin_installed()


@functools.lru_cache(maxsize=1)
def _jax_plugin_installed() -> bool:
    """Whether a JAX plugin is installed: looked up once per process (the scan of the installed distributions' entry
    points took ~4 ms, and a render resolves its backend a dozen times)."""
    from importlib import metadata, util

    return bool(metadata.entry_points(group="jax_plugins")) or util.find_spec("jax_plugins") is not None


def wait(meanwhile=()) -> None:
    """Before a render's first march: compile :data:`WAITING_KERNELS` here (the per-ray set-up, which the chunk calls
    next, and the composition kernels, which it would compile after the march), call ``meanwhile``'s functions
    (work that the render would do after the march, e.g. tables that a new installation builds once:
    :func:`swim.rt.ground_cpu.ground_tables`), then wait for the helper that :func:`start` began, so that the march
    is loaded from the disk cache rather than compiled a second time. Returns at once where no helper was started
    (and calls nothing)."""
    global _helper
    if _helper is None:
        return
    with _lock:
        if _helper is None:
            return
        process, started, errors = _helper
        here = time.perf_counter()
        for name in WAITING_KERNELS:
            try:
                _dispatcher(name).compile(kernel_signature(name))  # loads it where the disk cache has it
            except Exception as error:  # only ever a head start: the render compiles it at its first call
                log.warning("compiling %s ahead of its first call failed: %s", name, error)
        for function in meanwhile:
            try:
                function()
            except Exception as error:  # only ever a head start: the render calls it again where it needs it
                log.warning("%s ahead of its first use failed: %s", getattr(function, "__name__", function), error)
        log.info("%s ready in %.1f s; waiting for the helper process", ", ".join(WAITING_KERNELS),
                 time.perf_counter() - here)
        try:
            code = process.wait(timeout=max(WAIT_S - (time.perf_counter() - started), 1.0))
        except subprocess.TimeoutExpired:
            process.kill()
            code = process.wait()
            log.warning("the helper process compiling the march kernel took more than %.0f s: stopped", WAIT_S)
        if code == 0 and all(map(is_cached, HELPER_KERNELS)):
            log.info("the helper process compiled the march kernel in %.1f s", time.perf_counter() - started)
        elif code == 0:
            import numba

            log.warning("the helper process finished, but the march kernel is not in this process's numba cache "
                        "(%s); compiling it here", numba.config.CACHE_DIR)
        else:
            errors.seek(0)
            tail = errors.read().decode(errors="replace")[-2000:]
            log.warning("the helper process compiling the march kernel failed (exit code %s); compiling it here:\n%s",
                        code, tail)
        errors.close()
        _helper = None


def main(argv=None) -> int:
    """``python -m swim.rt.precompile KERNEL ...``: compile the named kernels of :data:`KERNELS` for
    :func:`kernel_signature` into numba's disk cache, one helper at a time per cache folder."""
    names = list(sys.argv[1:] if argv is None else argv)
    import numba  # its disk cache points at swim's folder (swim.compilation.numba_jit, imported above)

    folder = numba.config.CACHE_DIR
    lock = None
    if folder:
        os.makedirs(folder, exist_ok=True)
        lock = open(os.path.join(folder, "precompile.lock"), "w")
        try:  # another helper compiling: wait, then load its result
            import fcntl

            deadline = time.monotonic() + LOCK_WAIT_S
            while True:
                try:
                    fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
                    break
                except BlockingIOError:
                    if time.monotonic() > deadline:
                        break  # a stuck helper elsewhere: compile anyway
                    time.sleep(0.2)
        except (ImportError, OSError):
            pass
    try:
        for name in names:
            _dispatcher(name).compile(kernel_signature(name))
    finally:
        if lock is not None:
            lock.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
