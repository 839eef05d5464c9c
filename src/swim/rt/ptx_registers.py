"""A cap on the registers per thread of swim's Pallas kernels on NVIDIA GPUs (PTX's ``.maxnreg`` directive).

The fused march (:mod:`swim.rt.march_pallas`) waits on its gathers' latency: on an H200 ptxas gives it 255 registers a
thread, so only two 128-ray programs fit a multiprocessor (12.5 % occupancy) and too few warps hide the wait
(Nsight Compute, docs/performance.md, section 85). Pallas offers no register cap (Triton's ``maxnreg`` is not among
its compiler parameters), and the only other lever, bigger programs, costs lockstep efficiency (section 85: 90.2 % of
the iterations useful at 128 rays a program, 82.2 % at 512). PTX has the cap as a directive of the kernel's entry,
``.maxnreg N``, which ptxas and the driver's JIT both obey.

So the cap travels in the kernel's name: a Pallas kernel of swim's named ``swim_..._rN`` (:func:`capped_name`) gets
``.maxnreg N`` inserted into its PTX (:func:`cap_registers_in_ptx`) by a wrapper around the Triton compilation that
Pallas's lowering calls (:func:`install_register_cap`); other kernels' PTX is left alone. The PTX that goes into the
lowered program (and into an exported one) is the capped one. The name is made while the kernel is traced, so it
cannot tell JAX's caches apart: the setting that asks for the cap
(:attr:`swim.rt.march.MarchSettings.fused_max_registers`) is one of the compiled programs' static arguments and keys
(JAX's and :mod:`swim.rt.export_cache`'s). :func:`capped_entries` lists the entries capped so far in the process.

This reaches into a private module of JAX (``jax._src.pallas.triton.pallas_call_registration``), so it is checked
before use and never required: where the lowering differs (JAX releases whose jaxlib is 0.10.2 or older hand the
Triton module itself to XLA, which compiles it without the cap), :func:`install_register_cap` returns False, logs why
once, and the kernel runs uncapped. ``benchmarks/pallas_registers.py`` counts the registers and spills of any cap on
a CPU.
"""

from __future__ import annotations

import logging
import re
import threading

log = logging.getLogger(__name__)

#: A kernel name's cap suffix: ``_r`` and the registers per thread.
_SUFFIX = re.compile(r"_r(\d+)$")
#: The prefix of swim's kernel names: only their entries are capped.
PREFIX = "swim_"
#: A PTX kernel entry of swim's whose name carries the suffix, up to its parameter list's opening parenthesis.
_ENTRY = re.compile(r"\.entry\s+(" + PREFIX + r"[\w$]*?_r(\d+))\s*\(")
_MAXNREG = re.compile(r"\.maxnreg\s+\d+")

#: ptxas's bounds for ``.maxnreg`` (a thread addresses at most 255 registers; fewer than 16 cannot hold a kernel).
MIN_REGISTERS, MAX_REGISTERS = 16, 255

_LOCK = threading.Lock()
_STATE = {"installed": None}
_CAPPED: dict[str, int] = {}
_COUNT = {"caps": 0}


def capped_entries() -> dict[str, int]:
    """The PTX entries that :func:`cap_registers_in_ptx` capped in this process: name -> registers per thread (a
    benchmark's proof that a cap reached the PTX, not only that the wrapper was installed)."""
    with _LOCK:
        return dict(_CAPPED)


def caps_applied() -> int:
    """How many entries :func:`cap_registers_in_ptx` has capped in this process, each compilation counted (a
    benchmark's proof that its own compilation was capped: the count before and after it)."""
    with _LOCK:
        return _COUNT["caps"]


def capped_name(name: str, max_registers: int | None) -> str:
    """``name`` with the suffix that caps its kernel at ``max_registers`` per thread (``name`` itself for None).

    Raises
    ------
    ValueError
        If ``max_registers`` is outside [16, 255], or ``name`` does not start with :data:`PREFIX` or already ends in
        a cap suffix.
    """
    if max_registers is None:
        return name
    if not name.startswith(PREFIX):
        raise ValueError(f"kernel name {name!r}: only swim's kernels ({PREFIX}...) are capped")
    cap = int(max_registers)
    if not MIN_REGISTERS <= cap <= MAX_REGISTERS:
        raise ValueError(f"max_registers must be in [{MIN_REGISTERS}, {MAX_REGISTERS}] registers per thread, got "
                         f"{max_registers!r}")
    if _SUFFIX.search(name):
        raise ValueError(f"kernel name {name!r} already ends in a register cap suffix")
    return f"{name}_r{cap}"


def cap_registers_in_ptx(ptx: str) -> str:
    """``ptx`` with ``.maxnreg N`` among the directives of each kernel entry named ``swim_..._rN`` (replacing a cap
    that is there); ``ptx`` itself (the same object) where no entry of swim's carries the suffix.

    The directive goes between the entry's parameter list and its body, where PTX puts the performance-tuning
    directives (``.maxnreg``, ``.maxntid``, ``.reqntid``; PTX ISA, "Performance-Tuning Directives").

    Raises
    ------
    ValueError
        If an entry named with the suffix has no body (no ``{`` after its parameter list), or its cap is outside
        [16, 255].
    """
    pieces, at = [], 0
    for entry in _ENTRY.finditer(ptx):
        cap = int(entry.group(2))
        if not MIN_REGISTERS <= cap <= MAX_REGISTERS:
            raise ValueError(f"PTX entry {entry.group(1)}: register cap {cap} outside [{MIN_REGISTERS}, "
                             f"{MAX_REGISTERS}]")
        close = _closing_parenthesis(ptx, entry.end() - 1)
        body = ptx.find("{", close) if close >= 0 else -1
        if body < 0:
            raise ValueError(f"PTX entry {entry.group(1)} has no body")
        directives = ptx[close + 1:body]
        if _MAXNREG.search(directives):
            directives = _MAXNREG.sub(f".maxnreg {cap}", directives)
        else:
            directives = directives.rstrip("\n") + f"\n.maxnreg {cap}\n"
        pieces += [ptx[at:close + 1], directives]
        at = body
        with _LOCK:
            _CAPPED[entry.group(1)] = cap
            _COUNT["caps"] += 1
    if not pieces:
        return ptx
    return "".join(pieces) + ptx[at:]


def _closing_parenthesis(text: str, opening: int) -> int:
    """Index of the parenthesis that closes the one at ``opening`` (-1 if none)."""
    depth = 0
    for i in range(opening, len(text)):
        if text[i] == "(":
            depth += 1
        elif text[i] == ")":
            depth -= 1
            if depth == 0:
                return i
    return -1


class _CappedCompilation:
    """A Triton compilation's result with its PTX (``asm``) capped; its other attributes (``smem_bytes``, ...) the
    original's."""

    def __init__(self, result, asm):
        self._result, self.asm = result, asm

    def __getattr__(self, name):
        return getattr(self._result, name)


class _CappingTriton:
    """JAX's Triton module (``jax._src.lib.triton``) with :func:`compile` returning capped PTX; every other attribute
    the module's own."""

    def __init__(self, triton):
        self._triton = triton

    def __getattr__(self, name):
        return getattr(self._triton, name)

    def compile(self, *args, **kwargs):  # noqa: A003 - the wrapped module's name
        result = self._triton.compile(*args, **kwargs)
        asm = getattr(result, "asm", None)
        if not isinstance(asm, str):  # ROCm's result (a code object's path), or a release that returns bytes
            return result
        capped = cap_registers_in_ptx(asm)
        return result if capped is asm else _CappedCompilation(result, capped)


def install_register_cap() -> bool:
    """Make Pallas's Triton lowering cap kernels named ``swim_..._rN`` (:func:`capped_name`) at N registers per
    thread.

    Idempotent and thread-safe. Returns whether the cap will apply: False (logged once) where this JAX's lowering is
    not the one it wraps, a Triton compilation in Python whose PTX goes into the lowered program.
    """
    with _LOCK:
        if _STATE["installed"] is not None:
            return _STATE["installed"]
        why = None
        try:
            from jax._src.pallas.triton import pallas_call_registration as registration
        except Exception as err:  # noqa: BLE001 - no Pallas Triton lowering at all
            registration, why = None, f"no Pallas Triton lowering ({err})"
        if registration is not None:
            triton = getattr(registration, "triton", None)
            version = getattr(registration, "jaxlib_version", None)
            if triton is None or not callable(getattr(triton, "compile", None)):
                why = "Pallas's Triton lowering has no Triton compilation to wrap"
            elif version is not None and tuple(version) <= (0, 10, 2):
                why = (f"jaxlib {'.'.join(map(str, version))} hands the Triton module to XLA, which compiles it "
                       "without the cap (jaxlib > 0.10.2 needed)")
        if why is None:
            if not isinstance(registration.triton, _CappingTriton):
                registration.triton = _CappingTriton(registration.triton)
            _STATE["installed"] = True
        else:
            log.warning("register cap of the fused kernel not applied: %s", why)
            _STATE["installed"] = False
        return _STATE["installed"]
