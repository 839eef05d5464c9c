"""The instruction set that numba compiles swim's CPU kernels for: AVX-512 left out on Intel CPUs that have it.

numba compiles for the host CPU's every feature. On an Intel Xeon with AVX-512 (Emerald Rapids) LLVM then puts
512-bit registers, mask registers and 512-bit-indexed gathers into the march kernel (:mod:`swim.rt.march_cpu`),
whose arithmetic is four float64 lanes, one 256-bit register (docs/decisions/0003-cpu-kernel-code.md). Compiled without
AVX-512 for the same CPU (its tuning kept, AVX2 and FMA kept), the kernel replayed on one core took 7-18 % less time
on the synthetic scene in seven of eight rounds (1 % more in one; median 10.5 % less) and 13-20 % less on Katrina, the
two builds running side by side on the machine's two cores (docs/decisions/0003-cpu-kernel-code.md). Leaving out only
the gathers (LLVM's ``-fast-gather``) did not do it.

So, as numba's CPU target is first set up, :func:`choose_cpu_features` hands numba the host's features with every
AVX-512 feature (and AVX10, which implies it) turned off, where

* the host has AVX-512 (``avx512f``) and LLVM does not name it an AMD core (``znver*``, whose AVX-512 runs at full
  clock: not measured, so left as numba chooses);
* the user has set neither ``NUMBA_CPU_NAME`` nor ``NUMBA_CPU_FEATURES`` (theirs are kept);
* numba has not set up its CPU target yet in this process (a program that compiled its own numba functions before
  importing swim's kernels keeps the target it has: numba sets it up once per process).

``SWIM_NUMBA_AVX512=1`` keeps AVX-512 (numba's own choice); ``SWIM_NUMBA_AVX512=0`` leaves it out on any CPU that has
it. The setting is numba's, for the whole process: a user's numba functions compiled afterwards get the same
instructions. numba's disk cache keys each kernel by the features it was compiled for, so a change of this setting
compiles the kernels anew once (:mod:`swim.rt.precompile` hands the helper process this process's features).
"""

from __future__ import annotations

import logging
import os

log = logging.getLogger(__name__)

#: Environment variable: "1" keeps AVX-512 in swim's numba kernels, "0" leaves it out on every CPU, unset: left out on
#: Intel CPUs (:func:`choose_cpu_features`).
AVX512_ENV = "SWIM_NUMBA_AVX512"
#: LLVM feature names that enable 512-bit vectors or AVX-512 instructions (each AVX10 version implies AVX-512).
_AVX512_PREFIXES = ("avx512", "avx10", "evex512", "amx-avx512")


def is_avx512_feature(name: str) -> bool:
    """Whether the LLVM feature ``name`` (without its sign) enables AVX-512 instructions or 512-bit registers."""
    return name.startswith(_AVX512_PREFIXES)


def features_without_avx512(features: str) -> str:
    """An LLVM feature string (``"+avx2,+avx512f,-sse4a,..."``, as ``llvmlite.binding.get_host_cpu_features()``
    flattens it) with every AVX-512 feature switched off and the others as they were, in the same order.

    Every AVX-512 feature goes, not only ``avx512f``: LLVM applies the features in order, and a later
    ``+avx512vl`` would switch ``avx512f`` back on (it implies it)."""
    out = []
    for item in filter(None, features.split(",")):
        sign, name = item[0], item[1:]
        out.append(f"-{name}" if sign in "+-" and is_avx512_feature(name) else item)
    return ",".join(out)


def has_avx512(features: str) -> bool:
    """Whether an LLVM feature string switches ``avx512f`` on."""
    return "+avx512f" in features.split(",")


def _target_set_up() -> bool:
    """Whether numba has set up its CPU target (code generator and target machine) in this process."""
    from numba.core.registry import cpu_target

    return "_toplevel_target_context" in vars(cpu_target)


def choose_cpu_features() -> str | None:
    """Set ``numba.config.CPU_FEATURES`` to the host's features without AVX-512 where the module docstring says;
    returns the features set, or None where numba's choice stands. Logs its decision (debug level)."""
    import numba
    from llvmlite import binding
    from numba.core.codegen import get_host_cpu_features

    setting = os.environ.get(AVX512_ENV, "").strip()
    if setting not in ("", "0", "1"):
        log.warning("%s=%r is neither 0 nor 1: ignored", AVX512_ENV, setting)
        setting = ""
    if setting == "1" or numba.config.CPU_NAME is not None or numba.config.CPU_FEATURES is not None:
        return None
    if _target_set_up():
        log.debug("numba's CPU target is already set up in this process: its instruction set is kept")
        return None
    features = get_host_cpu_features()
    if not has_avx512(features):
        return None
    if setting == "" and binding.get_host_cpu_name().startswith("znver"):
        return None
    numba.config.CPU_FEATURES = features_without_avx512(features)
    log.debug("numba compiles for %s without AVX-512 (%s=1 keeps it)", binding.get_host_cpu_name(), AVX512_ENV)
    return numba.config.CPU_FEATURES
