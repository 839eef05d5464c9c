"""numba's set-up for swim's compiled kernels: the CPU target, the disk cache's folder, and the options and
decorators of the kernels (:data:`JIT_KERNEL`, :data:`JIT_HELPER`, :data:`JIT_EXACT`, :func:`helper_jit`,
:func:`vectorising`).

Importing this module chooses numba's CPU features (:mod:`swim.compilation.numba_target`) and points numba's disk
cache at a folder of swim's cache named by the digest of the kernels' code (:func:`numba_sources_digest`), before any
kernel is decorated: every module with numba kernels (``swim/rt/*_cpu.py``, ``swim.io.scan_cpu``,
``swim.optics.columns_cpu``, ``swim.color.srgb_cpu``) takes its options from here.
"""

from __future__ import annotations

import hashlib
import inspect
from pathlib import Path

import numba
from numba import njit
from numba.core.registry import CPUDispatcher

from .cache_budget import hold_code_version, prune_code_versions
from .disk_cache import _disabled, cache_directory, serialise_numba_cache_writes
from .numba_target import choose_cpu_features


#: The modules (relative to ``swim/rt``, where the numba kernels live) whose module-level constants the compiled functions read: numba freezes
#: such globals into the machine code (e.g. :data:`swim.constants.AFTER_MIN_STEPS`, the phase functions' constants
#: in ``swim.rt.compose_cpu``), so a change to them must start a fresh cache too (:func:`numba_sources_digest`).
CONSTANTS_READ_FROM = ("../constants.py", "../optics/phase.py", "../compilation/numba_jit.py", "march_settings.py",
                       "march_inputs.py", "surface_margin.py", "solar.py")


def numba_sources_digest() -> str:
    """A digest (16 hex digits) of the code of every module with numba-compiled functions (``swim/rt/*_cpu.py``) and
    of those whose constants they read (:data:`CONSTANTS_READ_FROM`).

    numba decides whether a cached compilation is stale from the time stamp of the function's own file only, and bakes
    the compiled functions it calls from other files (``swim.rt.ground_cpu`` calls this module's point geometry and
    lookups, and ``swim.rt.compose_cpu``'s transmittance) into the caller's machine code, and the other modules'
    constants as well: after a change to this file a cached ``ground_radiance`` would keep running the old geometry.
    The cache therefore lives in a folder named by this digest, so that any change to any of these modules starts a
    fresh one (docs/decisions/0009-work-around-the-march.md and docs/decisions/0004-step-placement.md)."""
    digest = hashlib.sha256()
    rt = Path(__file__).resolve().parents[1] / "rt"
    for path in [*sorted(rt.glob("*_cpu.py")), *(rt / name for name in CONSTANTS_READ_FROM)]:
        if path.is_file():
            digest.update(path.name.encode() + path.read_bytes())
    return digest.hexdigest()[:16]


# before numba sets up its CPU target (the first compilation or cache load): AVX-512 left out on Intel CPUs,
# where the replayed march ran ~10 % slower with it (swim.compilation.numba_target)
choose_cpu_features()
CACHE_ON = not _disabled()
if CACHE_ON and not numba.config.CACHE_DIR:
    # numba caches compiled functions beside the source by default, which an installed package may not allow;
    # the setting is read when each function below is decorated (a user's NUMBA_CACHE_DIR is kept, and with it
    # numba's own staleness check by file time stamps)
    _digest, _versions = numba_sources_digest(), cache_directory("numba")
    numba.config.CACHE_DIR = str(_versions / _digest)
    # each code version has its own folder: this process holds its own, and the oldest of the others go, so that
    # upgrades do not pile up machine code
    hold_code_version(_versions, _digest)
    prune_code_versions(_versions, _digest)
if CACHE_ON:
    serialise_numba_cache_writes()  # a helper process may compile beside this one (swim.rt.precompile)

#: LLVM fast-math flags that keep NaN and infinity semantics (the index map's box may be infinite): contraction
#: into FMAs, reassociation, reciprocals and approximate functions; 14 % faster, differences ~1e-7 relative.
FASTMATH = {"contract", "arcp", "nsz", "reassoc", "afn"}
#: The kernels that Python calls (march_rays, prepare_rays, compose_clouds, ground_radiance, Step 1a's sweep).
JIT_KERNEL = {"cache": CACHE_ON, "fastmath": FASTMATH, "error_model": "numpy"}
#: The functions that only compiled code calls (:func:`helper_jit`): without the CPython and C wrappers that numba
#: would otherwise compile (and cache) for each of them, an empty cache compiles the march and its set-up ~2.5 s
#: (17 %) faster (docs/decisions/0008-cold-start.md).
JIT_HELPER = {**JIT_KERNEL, "no_cpython_wrapper": True, "no_cfunc_wrapper": True}
#: Kernels that must give the bits of the NumPy code they replace (the colour stage, adaptive sampling's fill and
#: cells' test): no fast-math (no contraction into FMAs, no reassociation), without the GIL.
JIT_EXACT = {"cache": CACHE_ON, "error_model": "numpy", "nogil": True}


class CompiledOnlyDispatcher(CPUDispatcher):
    """A function compiled without numba's Python wrapper (:func:`helper_jit`). Called from Python, numba would
    enter the wrapper that was never compiled and crash the interpreter; this raises instead."""

    def __call__(self, *args, **kwargs):
        raise TypeError(f"swim.rt: {self.py_func.__name__} is compiled for compiled callers only (no Python wrapper); "
                        "call it through swim.compilation.numba_jit.callable_from_python")


def helper_jit(**options):
    """``numba.njit`` for the kernels' helpers, which only compiled code calls.

    Parameters
    ----------
    **options
        numba options beside :data:`JIT_HELPER`'s (disk cache, fast-math, no Python or C wrapper), e.g.
        ``inline="always"``, or in place of one of them (``fastmath=False``).

    Returns
    -------
    callable
        A decorator: the function's numba dispatcher, which raises TypeError when called from Python (use
        :func:`callable_from_python`); under ``NUMBA_DISABLE_JIT=1`` the plain function.
    """

    def decorate(function):
        dispatcher = njit(**{**JIT_HELPER, **options})(function)
        if isinstance(dispatcher, CPUDispatcher):  # not so under NUMBA_DISABLE_JIT=1: the plain function
            dispatcher.__class__ = CompiledOnlyDispatcher
        return dispatcher

    return decorate


class VectorisingDispatcher(CPUDispatcher):
    """The march kernel's dispatcher: compiles with LLVM's SLP (straight-line code) vectoriser on, which numba leaves
    off by default (``NUMBA_SLP_VECTORIZE``). It vectorises the step's four wavelength lanes (:data:`LANES`): the
    replayed march ~4-6 % faster (docs/decisions/0003-cpu-kernel-code.md). The setting is numba's global one, switched
    on
    for this compilation (and the helpers it compiles and links) only."""

    def compile(self, sig):
        previous = numba.config.SLP_VECTORIZE
        numba.config.SLP_VECTORIZE = 1
        try:
            return super().compile(sig)
        finally:
            numba.config.SLP_VECTORIZE = previous


def vectorising(dispatcher):
    """``dispatcher`` compiling as :class:`VectorisingDispatcher` (under ``NUMBA_DISABLE_JIT=1`` the plain
    function, as it is)."""
    if isinstance(dispatcher, CPUDispatcher):
        dispatcher.__class__ = VectorisingDispatcher
    return dispatcher


def callable_from_python(function):
    """A helper of the kernels compiled without a Python wrapper (:func:`helper_jit`), made callable from Python
    (tests, debugging): a jitted shim that calls it (each call of this function makes and compiles a new shim: keep
    the shim for repeated calls).

    Parameters
    ----------
    function : numba dispatcher
        E.g. ``march_cpu._adaptive_edges``.

    Returns
    -------
    callable
        Takes ``function``'s arguments, returns its result.
    """
    if not isinstance(function, CPUDispatcher):  # NUMBA_DISABLE_JIT=1: a plain function
        return function
    # parameters by name: numba inlines ``inline="always"`` functions into the shim and refuses ``*args`` there
    names = ", ".join(inspect.signature(function.py_func).parameters)
    namespace = {"__swim_helper": function}  # a name that no helper's parameter shadows
    exec(f"def call({names}):\n    return __swim_helper({names})\n", namespace)
    return njit(cache=False)(namespace["call"])
