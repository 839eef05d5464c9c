"""swim.rt: the ray-tracing kernels (JAX) and the tables they use.

Importing the package turns on the persistent compilation cache (:mod:`swim.rt.compilation_cache`).
"""

from .compilation_cache import enable_compilation_cache

enable_compilation_cache()
