"""swim.compilation: compiled code and its caches: numba's set-up and options (:mod:`~swim.compilation.numba_jit`,
:mod:`~swim.compilation.numba_target`), JAX's traced programs kept on disk (:mod:`~swim.compilation.jax_export`),
the disk caches (:mod:`~swim.compilation.disk_cache`) and their size budget (:mod:`~swim.compilation.cache_budget`).

The lowest layer but the constants (docs/architecture.md): it imports nothing of swim's physics, so every package
with compiled kernels can use it.
"""
