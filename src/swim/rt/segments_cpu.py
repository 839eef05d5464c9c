"""The rays' three segments (before, in and after the model grid), one ray at a time on the CPU (numba).

:func:`swim.rt.march.ray_segments` clips the rays to the top of the atmosphere, the sea-level sphere and the model
grid with NumPy: ~40 passes over (n,) and (n, 3) float64 temporaries. A warm 1024^2 adaptive all-sky spent ~34 ms in
it per render, between the batches while the march's threads waited, and the Monte Carlo case's 41^2 view ~0.4 ms
of its ~12-14 ms (docs/decisions/0009-work-around-the-march.md). This kernel does the same arithmetic for each ray in
registers.

The same operations in the same order as the NumPy function, without fast-math: the dot products of
:func:`swim.frames.ray_sphere_intersections` summed as NumPy's ``einsum`` sums three terms, ``(x0 y0 + x2 y2) + x1
y1``, and the grid's inverse affine map written out element by element, as :func:`swim.rt.march.ray_segments` does.
Where NumPy's ``einsum`` sums in another order (another CPU's SIMD code), the results differ by float64 round-off,
which near a sphere's tangent is a few centimetres of a ray's ~10^5 m (``tests/unit/rt/test_rt_segments_cpu.py``).
"""

from __future__ import annotations

import math

from numba import njit

from ..compilation.numba_jit import JIT_EXACT as _JIT


@njit(**_JIT, inline="always")
def _sphere(b, oo, radius):
    """Near and far distances [m] of a ray with ``b`` = o . d and ``oo`` = o . o to a sphere of ``radius`` [m]
    centred on the frame's origin: NaN for both where the ray's line misses it."""
    disc = b * b - (oo - radius ** 2)
    if not disc >= 0:
        return math.nan, math.nan
    root = math.sqrt(disc)
    return -b - root, -b + root


@njit(**_JIT)
def ray_segments_into(origins, directions, affine_origin, inverse, shape_yx, margin, radius, top, grid_top, start,
                      bounds, ends_on_ground, valid):
    """:func:`swim.rt.march.ray_segments` for rays ``origins``, ``directions`` (n, 3) [m, unit vectors], written into
    ``start`` (n, 3) [m], ``bounds`` (n, 3) [m], ``ends_on_ground`` (n,) bool and ``valid`` (n,) bool.

    ``affine_origin`` (2,) [m] and ``inverse`` (2, 2) [cells/m] map a point's (x, y) to grid indices (i, j);
    ``shape_yx`` the grid's (ny, nx); ``margin`` [cells] widens its lateral index bounds; ``radius`` [m] is the
    sea-level sphere's, ``top`` [m] the atmosphere's height above it and ``grid_top`` [m] the grid's top."""
    ny, nx = shape_yx
    r_top, r_grid = radius + top, radius + grid_top
    for r in range(origins.shape[0]):
        o0, o1, o2 = origins[r, 0], origins[r, 1], origins[r, 2]
        d0, d1, d2 = directions[r, 0], directions[r, 1], directions[r, 2]
        b = (o0 * d0 + o2 * d2) + o1 * d1  # numpy.einsum's order for three terms
        oo = (o0 * o0 + o2 * o2) + o1 * o1
        t1, t2 = _sphere(b, oo, r_top)
        is_valid = t2 > 0  # False for NaN
        s_start = max(t1, 0.0) if is_valid else 0.0
        s_end = t2 if is_valid else 0.0
        g1 = _sphere(b, oo, radius)[0]
        hits_sea = g1 > 0 and g1 < s_end
        if hits_sea:
            s_end = g1
        k1, k2 = _sphere(b, oo, r_grid)
        shell_in = max(k1, 0.0) if k1 == k1 else math.inf
        shell_out = k2 if k2 == k2 else -math.inf
        # the grid's lateral index bounds, widened by margin (the NumPy function's loop over the two axes)
        lo, hi = -math.inf, math.inf
        for axis in range(2):
            n = nx if axis == 0 else ny
            at = (o0 - affine_origin[0]) * inverse[axis, 0] + (o1 - affine_origin[1]) * inverse[axis, 1]
            rate = d0 * inverse[axis, 0] + d1 * inverse[axis, 1]
            a, b_hi = -margin, n - 1 + margin
            if abs(rate) < 1e-12:
                inside = at >= a and at <= b_hi
                e_lo = -math.inf if inside else math.inf
                e_hi = math.inf if inside else -math.inf
            else:
                e1 = (a - at) / rate
                e2 = (b_hi - at) / rate
                e_lo, e_hi = min(e1, e2), max(e1, e2)
            lo, hi = max(lo, e_lo), min(hi, e_hi)
        s_a = max(max(s_start, shell_in), lo)
        s_b = min(min(s_end, shell_out), hi)
        if not s_b > s_a:
            s_a = s_b = s_start
        start[r, 0] = o0 + s_start * d0
        start[r, 1] = o1 + s_start * d1
        start[r, 2] = (o2 + s_start * d2) - radius
        if is_valid:
            bounds[r, 0], bounds[r, 1], bounds[r, 2] = s_a - s_start, s_b - s_start, s_end - s_start
        else:
            bounds[r, 0] = bounds[r, 1] = bounds[r, 2] = 0.0
        ends_on_ground[r] = hits_sea and is_valid
        valid[r] = is_valid

