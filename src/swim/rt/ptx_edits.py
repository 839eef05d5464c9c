"""Edits to the PTX of swim's Pallas kernels on NVIDIA GPUs: a cap on the registers per thread (PTX's ``.maxnreg``)
and fused multiply-adds (float32 multiplies and adds without ``.rn``, which ptxas may then contract).

**The register cap.** The fused march (:mod:`swim.rt.march_pallas`) waits on its gathers' latency: on an H200 ptxas
gives it 255 registers a thread, so only two 128-ray programs fit a multiprocessor (12.5 % occupancy) and too few
warps hide the wait (Nsight Compute, docs/decisions/0006-gpu-kernels.md). Pallas offers no register cap (Triton's
``maxnreg`` is not among its compiler parameters), and the only other lever, bigger programs, costs lockstep
efficiency (docs/decisions/0006-gpu-kernels.md: 90.2 % of the iterations useful at 128 rays a program, 82.2 % at 512).
PTX has the cap as a directive of the kernel's entry, ``.maxnreg N``, which ptxas and the driver's JIT both obey.

**Fused multiply-adds.** Triton's PTX writes every float32 multiply, add and subtract of the kernel with an explicit
rounding mode (``mul.rn.f32``, ``add.rn.f32``, ``sub.rn.f32``), and PTX forbids ptxas to contract an instruction
with a rounding mode into a fused multiply-add (PTX ISA, ``add``/``mul``: "mul/add sequences with no rounding
modifiers may be optimized to use fused-multiply-add instructions"). The fused kernel's grid loop then issues 399
FMUL and 308 FADD and only 56 FFMA on sm_90a. Without the modifiers (``.rn`` is the default rounding, so each
instruction that stays alone rounds as before) ptxas contracts ~180 pairs: the loop falls from 1 617 to 1 440
instructions at the same 255 registers (docs/decisions/0006-gpu-kernels.md). A contracted pair rounds once instead of
twice, as nvcc's default ``--fmad=true`` does, so the results move by float32 rounding (and a decision at a threshold,
such as a terrain crossing or a refinement, may flip for a rare ray); the kernel makes no decision on the exact equality
of values computed apart (its roll-back's adjacency test compares a stored bound with itself). The edit cannot tell
LLVM's protective ``.rn`` from a deliberate one (``__fmul_rn`` in an inlined libdevice function, which nvcc would
keep); the fused kernel's inlined ``expf``/``expm1f`` have no ``mul.rn`` that feeds an add,
and a libdevice call added to the kernel must be checked the same way.

So both travel in the kernel's name: a Pallas kernel of swim's named ``swim_...[_fma][_rN]`` (:func:`kernel_name`)
gets ``.maxnreg N`` inserted among its entry's directives and, with ``_fma``, its body's float32 multiplies, adds and
subtracts without ``.rn`` (:func:`edit_ptx`), by a wrapper around the Triton compilation that Pallas's lowering calls
(:func:`install_ptx_edits`); other kernels' PTX is left alone. The PTX that goes into the lowered program (and into
an exported one) is the edited one. The name is made while the kernel is traced, so it cannot tell JAX's caches
apart: the settings that ask for the edits (:attr:`swim.rt.march_settings.ExecutionSettings.fused_max_registers` and
:attr:`~swim.rt.march_settings.ExecutionSettings.fused_fma`) are among the compiled programs' static arguments and keys (JAX's and
:mod:`swim.compilation.jax_export`'s). :func:`capped_entries` and :func:`contracted_entries` list the entries edited so far
in the process.

This reaches into a private module of JAX (``jax._src.pallas.triton.pallas_call_registration``), so it is checked
before use and never required: where the lowering differs (JAX releases whose jaxlib is 0.10.2 or older hand the
Triton module itself to XLA, which compiles it without the edits), :func:`install_ptx_edits` returns False, logs why
once, and the kernel runs as Triton wrote it. ``benchmarks/pallas_registers.py`` counts the registers, spills and
instructions of any variant on a CPU.
"""

from __future__ import annotations

import logging
import re
import threading

log = logging.getLogger(__name__)

#: The prefix of swim's kernel names: only their entries are edited.
PREFIX = "swim_"
#: The suffixes of a kernel's name that ask for edits: ``_fma`` (fused multiply-adds), then ``_r`` and the registers
#: per thread (the cap).
_SUFFIXES = re.compile(r"(_fma)?(?:_r(\d+))?$")
#: A PTX kernel entry of swim's, up to its parameter list's opening parenthesis.
_ENTRY = re.compile(r"\.entry\s+(" + PREFIX + r"[\w$]*)\s*\(")
_MAXNREG = re.compile(r"\.maxnreg\s+\d+")
#: A float32 multiply, add or subtract with the explicit round-to-nearest-even mode that forbids contraction; its
#: other modifiers (``.ftz``, ``.sat``) kept.
_ROUNDED = re.compile(r"\b(mul|add|sub)\.rn((?:\.ftz)?(?:\.sat)?\.f32)\b")

#: ptxas's bounds for ``.maxnreg`` (a thread addresses at most 255 registers; fewer than 16 cannot hold a kernel).
MIN_REGISTERS, MAX_REGISTERS = 16, 255

_LOCK = threading.Lock()
_STATE = {"installed": None}
_CAPPED: dict[str, int] = {}
_CONTRACTED: dict[str, int] = {}
_COUNT = {"caps": 0, "contractions": 0}


def capped_entries() -> dict[str, int]:
    """The PTX entries that :func:`edit_ptx` capped in this process: name -> registers per thread (a benchmark's
    proof that a cap reached the PTX, not only that the wrapper was installed)."""
    with _LOCK:
        return dict(_CAPPED)


def caps_applied() -> int:
    """How many entries :func:`edit_ptx` has capped in this process, each compilation counted (a benchmark's proof
    that its own compilation was capped: the count before and after it)."""
    with _LOCK:
        return _COUNT["caps"]


def contracted_entries() -> dict[str, int]:
    """The PTX entries whose float32 multiplies, adds and subtracts :func:`edit_ptx` freed for contraction in this
    process: name -> instructions freed in its last compilation."""
    with _LOCK:
        return dict(_CONTRACTED)


def contractions_applied() -> int:
    """How many entries :func:`edit_ptx` has freed for contraction in this process, each compilation counted."""
    with _LOCK:
        return _COUNT["contractions"]


def _edits_of(name: str) -> tuple[bool, int | None]:
    """(fused multiply-adds, register cap or None) that an entry's name asks for."""
    match = _SUFFIXES.search(name)
    return bool(match.group(1)), int(match.group(2)) if match.group(2) else None


def kernel_name(name: str, max_registers: int | None = None, fma: bool = False) -> str:
    """``name`` with the suffixes that ask :func:`edit_ptx` for fused multiply-adds (``_fma``) and a cap of
    ``max_registers`` per thread (``_rN``); ``name`` itself where neither is asked for.

    Raises
    ------
    ValueError
        If ``max_registers`` is outside [16, 255], or an edit is asked for and ``name`` does not start with
        :data:`PREFIX` or already ends in a suffix of an edit.
    """
    if max_registers is None and not fma:
        return name
    if not name.startswith(PREFIX):
        raise ValueError(f"kernel name {name!r}: only swim's kernels ({PREFIX}...) are edited")
    if _SUFFIXES.search(name).group(0):
        raise ValueError(f"kernel name {name!r} already ends in an edit's suffix (_fma or _rN)")
    suffix = "_fma" if fma else ""
    if max_registers is not None:
        cap = int(max_registers)
        if not MIN_REGISTERS <= cap <= MAX_REGISTERS:
            raise ValueError(f"max_registers must be in [{MIN_REGISTERS}, {MAX_REGISTERS}] registers per thread, "
                             f"got {max_registers!r}")
        suffix += f"_r{cap}"
    return name + suffix


def edit_ptx(ptx: str) -> str:
    """``ptx`` with the edits that its swim entries' names ask for (:func:`kernel_name`); ``ptx`` itself (the same
    object) where none asks for any.

    * ``_rN``: ``.maxnreg N`` among the entry's directives, between its parameter list and its body, where PTX puts
      the performance-tuning directives (``.maxnreg``, ``.maxntid``, ``.reqntid``; PTX ISA, "Performance-Tuning
      Directives"), replacing a cap that is there.
    * ``_fma``: in the entry's body (up to the brace that closes it), ``mul.rn.f32``, ``add.rn.f32`` and
      ``sub.rn.f32`` (with ``.ftz`` or ``.sat`` kept) without their ``.rn``. Round-to-nearest-even is PTX's default
      mode, so an instruction that ptxas leaves alone rounds as before; a multiply and an add that it contracts
      into a fused multiply-add round once (PTX ISA, ``add``, ``mul``).

    Raises
    ------
    ValueError
        If an entry that asks for an edit has no body (no ``{`` after its parameter list before a ``;`` or the next
        entry, or none that closes), or its cap is outside [16, 255].
    """
    pieces, at = [], 0
    for entry in _ENTRY.finditer(ptx):
        name = entry.group(1)
        fma, cap = _edits_of(name)
        if not fma and cap is None:
            continue
        if cap is not None and not MIN_REGISTERS <= cap <= MAX_REGISTERS:
            raise ValueError(f"PTX entry {name}: register cap {cap} outside [{MIN_REGISTERS}, {MAX_REGISTERS}]")
        close = _closing(ptx, entry.end() - 1, "(", ")")
        body = ptx.find("{", close) if close >= 0 else -1
        end = _closing(ptx, body, "{", "}") if body >= 0 else -1
        # a declaration without a body ends in ";" before the next function: never edit that one's body instead
        if end < 0 or ";" in ptx[close + 1:body] or ".entry" in ptx[close + 1:body]:
            raise ValueError(f"PTX entry {name} has no body")
        directives = ptx[close + 1:body]
        if cap is not None:
            if _MAXNREG.search(directives):
                directives = _MAXNREG.sub(f".maxnreg {cap}", directives)
            else:
                directives = directives.rstrip("\n") + f"\n.maxnreg {cap}\n"
        code = ptx[body:end + 1]
        if fma:
            code, freed = _ROUNDED.subn(r"\1\2", code)
        pieces += [ptx[at:close + 1], directives, code]
        at = end + 1
        with _LOCK:
            if cap is not None:
                _CAPPED[name] = cap
                _COUNT["caps"] += 1
            if fma:
                _CONTRACTED[name] = freed
                _COUNT["contractions"] += 1
    if not pieces:
        return ptx
    return "".join(pieces) + ptx[at:]


def _closing(text: str, opening: int, left: str, right: str) -> int:
    """Index of the ``right`` that closes the ``left`` at ``opening`` (-1 if none)."""
    depth = 0
    for i in range(opening, len(text)):
        if text[i] == left:
            depth += 1
        elif text[i] == right:
            depth -= 1
            if depth == 0:
                return i
    return -1


class _EditedCompilation:
    """A Triton compilation's result with its PTX (``asm``) edited; its other attributes (``smem_bytes``, ...) the
    original's."""

    def __init__(self, result, asm):
        self._result, self.asm = result, asm

    def __getattr__(self, name):
        return getattr(self._result, name)


class _EditingTriton:
    """JAX's Triton module (``jax._src.lib.triton``) with :func:`compile` returning edited PTX; every other attribute
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
        try:
            edited = edit_ptx(asm)
        except ValueError as err:  # PTX of a shape the edits do not know: run the kernel as Triton wrote it
            log.warning("PTX edits (register cap, fused multiply-adds) not applied to this kernel: %s", err)
            return result
        return result if edited is asm else _EditedCompilation(result, edited)


def install_ptx_edits() -> bool:
    """Make Pallas's Triton lowering edit the PTX of kernels named ``swim_...[_fma][_rN]`` (:func:`kernel_name`).

    Idempotent and thread-safe. Returns whether the edits will apply: False (logged once) where this JAX's lowering
    is not the one it wraps, a Triton compilation in Python whose PTX goes into the lowered program.
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
                       "without them (jaxlib > 0.10.2 needed)")
        if why is None:
            if not isinstance(registration.triton, _EditingTriton):
                registration.triton = _EditingTriton(registration.triton)
            _STATE["installed"] = True
        else:
            log.warning("PTX edits of the fused kernel (register cap, fused multiply-adds) not applied: %s", why)
            _STATE["installed"] = False
        return _STATE["installed"]
