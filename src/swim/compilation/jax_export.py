"""Traced JAX kernels kept on disk (``jax.export``), so that a new process does not trace them again.

JAX's persistent compilation cache (:mod:`swim.compilation.disk_cache`) keeps the compiled executables, but every new
process still traces each jitted function in Python and lowers it to StableHLO before it can look the executable up.
For the lockstep march (:func:`swim.rt.march_jax._trace_chunk`) that is ~1.1 s of a new process's first render on a CPU
(0.8 s of tracing, 0.3 s of lowering: docs/decisions/0008-cold-start.md; ~3 s under cProfile on a GPU host, section
66). :func:`exported_jit` wraps a function like ``jax.jit`` and, the first time a process calls it with given static
arguments and input shapes, loads the function's serialized ``jax.export.Exported`` from
``$SWIM_CACHE_DIR/jax-export`` instead of tracing it; where there is none, it exports the function, writes it there
and calls the export. The export's StableHLO is the traced function's, so the results are the same bit for bit, and
its compilation is then found in JAX's persistent cache by the later processes.

An entry's key holds the whole swim package's code (:func:`swim.compilation.disk_cache.package_sources`), the JAX and
jaxlib versions, the platform, the x64 switch, the function's name, its static arguments' ``repr`` and its inputs'
tree, shapes and dtypes, so a changed code or another platform writes a new entry. ``SWIM_JAX_EXPORT=0`` turns this
off alone, ``SWIM_JAX_CACHE=0`` with the compilation cache. Where an export cannot be made (a JAX without
``jax.export``, no ``flatbuffers``, an operation that JAX does not export) or read, the function is jitted as usual
and the failure logged: the cache only ever saves time. The folder stays within
:func:`swim.compilation.cache_budget.max_bytes` (least recently used entries removed first; ``swim cache`` lists and clears
it).
"""

from __future__ import annotations

import functools
import hashlib
import inspect
import logging
import threading

import jax
import numpy as np

from .disk_cache import (cache_directory, enable_compilation_cache, package_sources, store_entry,
                                switched_off)

log = logging.getLogger(__name__)

# every JAX kernel imports this module: JAX's own persistent cache is set up before their first compilation
enable_compilation_cache()

#: The cache's kind (:func:`swim.compilation.disk_cache.cache_directory`, :mod:`swim.compilation.cache_budget`).
KIND = "jax-export"
#: Ending of the cache's entries.
SUFFIX = ".jaxexport"
#: The custom call of a Pallas kernel on an NVIDIA GPU (Triton), which the cache exports with the rest.
TRITON_CALL = "__gpu$xla.gpu.triton"


@functools.lru_cache(maxsize=1)
def _code_digest() -> str:
    """Digest of every Python file of the package and of the JAX versions (once per process, ~5 ms)."""
    import jaxlib

    digest = hashlib.sha256(f"{jax.__version__} {jaxlib.__version__}".encode())
    for source in package_sources():
        digest.update(source.read_bytes())
    return digest.hexdigest()


def _leaf_key(leaf):
    """What of an input the export depends on: its type (a Python scalar is weakly typed), shape and dtype."""
    return type(leaf).__name__, np.shape(leaf), str(getattr(leaf, "dtype", ""))


class ExportedJit:
    """``jax.jit(function, static_argnames=...)`` whose traced programs persist between processes.

    Call it as the function itself. See the module docstring; :func:`exported_jit` makes one. Inside a JAX
    transformation (``jax.grad``, ``jax.vmap``, an enclosing ``jax.jit``) it is ``jax.jit`` itself: an exported
    program has no derivative or batching rule."""

    def __init__(self, function, static_argnames=()):
        self.function = function
        self.static_argnames = tuple(static_argnames)
        self.jitted = jax.jit(function, static_argnames=self.static_argnames)
        self._signature = inspect.signature(function)
        self._calls = {}  # (statics, input tree, leaves' keys) -> the callable of that program in this process
        self._lock = threading.Lock()
        self.loaded = self.exported = 0  # programs read from the cache and written to it by this process
        functools.update_wrapper(self, function)

    def __call__(self, *args, **kwargs):
        if switched_off("SWIM_JAX_CACHE") or switched_off("SWIM_JAX_EXPORT"):
            return self.jitted(*args, **kwargs)
        bound = self._signature.bind(*args, **kwargs)
        bound.apply_defaults()
        statics = tuple((name, bound.arguments[name]) for name in self.static_argnames)
        names = tuple(name for name in bound.arguments if name not in self.static_argnames)
        dynamic = tuple(bound.arguments[name] for name in names)
        leaves, tree = jax.tree_util.tree_flatten(dynamic)
        if any(isinstance(leaf, jax.core.Tracer) for leaf in leaves):
            # inside a transformation (grad, vmap, an outer jit): an export has no derivative or batching rule
            return self.jitted(*args, **kwargs)
        key = (statics, tree, tuple(_leaf_key(leaf) for leaf in leaves))
        call = self._calls.get(key)
        if call is None:
            with self._lock:  # renders on several threads: one export per program
                call = self._calls.get(key)
                if call is None:
                    call = self._calls[key] = self._program(statics, names, dynamic, tree, key[2])
        return call(*dynamic)

    def forget_programs(self):
        """Drop this process's programs, as a new process starts without them: the next call reads or exports."""
        with self._lock:
            self._calls.clear()
            self.loaded = self.exported = 0

    def _program(self, statics, names, dynamic, tree, leaf_keys):
        """The callable that runs this program: the cached export, a new one, or (failing both) plain ``jit``."""
        static_text = repr(statics)
        # an argument without a stable repr (an address) or with a shortened one (a long array's "..."): no key that
        # names the program
        if " at 0x" in static_text or "..." in static_text:
            return self._plain(statics, names)
        text = repr((_code_digest(), jax.default_backend(), bool(jax.config.jax_enable_x64),
                     f"{self.function.__module__}.{self.function.__qualname__}", static_text, str(tree), leaf_keys))
        path = cache_directory(KIND) / f"{hashlib.sha256(text.encode()).hexdigest()[:40]}{SUFFIX}"
        try:
            from jax import export
        except ImportError as err:  # JAX < 0.4.30
            log.info("no jax.export (%s): %s is traced in every process", err, self.function.__qualname__)
            return self._plain(statics, names)
        from .cache_budget import mark_used, max_bytes

        try:
            program = export.deserialize(bytearray(path.read_bytes()))
            mark_used(path)
            self.loaded += 1
            log.debug("%s: traced program read from %s", self.function.__qualname__, path)
            return jax.jit(program.call)
        except FileNotFoundError:
            pass
        except Exception as err:  # noqa: BLE001  (a damaged or foreign entry: export it again)
            log.info("could not read %s (%s); exporting it again", path, err)
        limit = max_bytes()
        fixed = dict(statics)

        def with_statics(*values):
            return self.function(**dict(zip(names, values)), **fixed)

        try:
            # the fused grid march's Triton call (swim.rt.march_pallas): XLA promises no compatibility of its
            # custom call across versions, which the key's JAX and jaxlib versions already pin
            checks = [export.DisabledSafetyCheck.custom_call(TRITON_CALL)]
            program = export.export(jax.jit(with_statics), disabled_checks=checks)(*dynamic)
            data = program.serialize()
        except Exception as err:  # noqa: BLE001  (no flatbuffers, or an operation that JAX does not export)
            log.info("%s is traced in every process: it could not be exported (%s)", self.function.__qualname__, err)
            return self._plain(statics, names)
        try:
            store_entry(path, lambda f: f.write(data), limit, suffix=SUFFIX)
            self.exported += 1
        except OSError as err:
            log.info("could not cache %s's traced program (%s)", self.function.__qualname__, err)
        return jax.jit(program.call)

    def _plain(self, statics, names):
        fixed = dict(statics)
        return lambda *values: self.jitted(**dict(zip(names, values)), **fixed)


def exported_jit(function=None, *, static_argnames=()):
    """Decorator: :class:`ExportedJit` of ``function`` (like ``functools.partial(jax.jit, static_argnames=...)``).

    Parameters
    ----------
    function : callable
        A function that ``jax.jit`` can trace, without positional-only parameters.
    static_argnames : sequence of str
        Its static (hashable, compile-time) parameters, as for ``jax.jit``; their ``repr`` goes into the cache's key,
        so it must describe the value (a dataclass's does).

    Returns
    -------
    ExportedJit
        Called as ``function``; on the first call with new static arguments or input shapes the program is read
        from the cache, or exported and written to it.
    """
    if function is None:
        return functools.partial(exported_jit, static_argnames=static_argnames)
    return ExportedJit(function, static_argnames)
