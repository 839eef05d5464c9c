"""swim.rt: the ray-tracing kernels (JAX) and the tables they use.

Importing the package turns on the persistent compilation cache (:mod:`swim.rt.compilation_cache`), except in the
helper process of :mod:`swim.rt.precompile`, which compiles numba kernels only and so need not import JAX.
"""

import os

from .compilation_cache import enable_compilation_cache

if not os.environ.get("SWIM_PRECOMPILE_HELPER"):
    enable_compilation_cache()
