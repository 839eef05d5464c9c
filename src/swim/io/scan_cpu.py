"""The passes of :func:`swim.io.scene.validate_scene` over a scene's 3-D fields, compiled (numba).

Validation copied each 3-D field to float64 and then tested the copy in separate NumPy passes (finite, negative,
maximum; the heights' differences along z): ~0.35 s of a new 400 x 400 x 60 scene with five species. Here one pass
per field copies it and gathers what the checks need, in blocks of levels (or of rows) on every core, without the
GIL (docs/decisions/0007-scene-set-up.md). The checks and their messages stay in :mod:`swim.io.scene_checks`.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..compilation.numba_jit import JIT_EXACT  # also puts numba's disk cache where swim keeps it

#: Columns of :func:`copy_and_scan`'s statistics: the count of values that are not finite (NaN, inf), the count of
#: negative values, the least and the greatest finite value.
STATS = ("not finite", "negative", "min", "max")


@njit(**JIT_EXACT)
def copy_and_scan(source, copy, k0, k1, stats):  # pragma: no cover - compiled
    """Levels ``k0:k1`` of a 3-D field (level, y, x), any real dtype and strides, copied into ``copy`` (float64, of
    its shape), and their statistics (:data:`STATS`) written into ``stats`` (4,) float64: min and max over the
    finite values (+inf and -inf where there is none)."""
    _, ny, nx = source.shape
    not_finite = 0
    negative = 0
    least = np.inf
    greatest = -np.inf
    for k in range(k0, k1):
        for j in range(ny):
            for i in range(nx):
                value = np.float64(source[k, j, i])
                copy[k, j, i] = value
                if np.isfinite(value):
                    negative += value < 0.0
                    least = min(least, value)
                    greatest = max(greatest, value)
                else:
                    not_finite += 1
    stats[0] = not_finite
    stats[1] = negative
    stats[2] = least
    stats[3] = greatest


@njit(**JIT_EXACT)
def flag_non_increasing(height, j0, j1, flags):  # pragma: no cover - compiled
    """Rows ``j0:j1`` of ``flags`` (y, x) bool set where the column of ``height`` (z, y, x) does not increase
    strictly with z (a level at or below the one under it); the other flags are left as they are."""
    nz, _, nx = height.shape
    for k in range(1, nz):
        for j in range(j0, j1):
            for i in range(nx):
                if not height[k, j, i] > height[k - 1, j, i]:
                    flags[j, i] = True
