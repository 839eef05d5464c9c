"""swim.rt: the radiative transfer: the clear atmosphere's tables, Step 1a, the diffuse fields and the ray march.

The march has one dispatcher (:func:`swim.rt.march.trace_rays`) and two kernels: numba's per-ray kernel on the CPU
(:mod:`swim.rt.march_cpu`) and JAX's lockstep kernel (:mod:`swim.rt.march_jax`; GPUs, gradients). JAX is imported only
by the modules of its kernels, which turn on its persistent compilation cache (:mod:`swim.compilation.disk_cache`,
through :mod:`swim.compilation.jax_export`), so a numba render never loads it (docs/decisions/0011-jax-only-where-it-runs.md).
"""
