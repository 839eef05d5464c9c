"""The geometry and table lookups of the CPU march kernel (:mod:`swim.rt.march_cpu`, numba): the layout of its
packed parameters, a point's height and grid indices along a ray, the clamped bilinear lookups, the terrain's gap and
crossing, and the blocks of points whose geometry is computed in one vectorised loop, with the prefetch of their
volume cells (docs/decisions/0003-cpu-kernel-code.md).

Each function mirrors its JAX counterpart in :mod:`swim.rt.march_jax` (named in its docstring); it computes in float64
from the float32 tables.
"""

from __future__ import annotations

import math

import numpy as np

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

from ..compilation.numba_jit import helper_jit

#: Layout of the float64 parameter vector of :func:`march_rays` (see :func:`pack_parameters`).
_P_RADIUS, _P_SUN, _P_ZBOTTOM, _P_DZ, _P_CENTRE, _P_SCALE, _P_BOUNDS, _P_DH, _P_TOP = 0, 1, 4, 5, 6, 8, 9, 13, 14
_P_TERRAIN_TOP = 15
_P_SURFACE_MARGIN = 16
_N_PARAMETERS = 17
#: Height above the terrain's highest point [m] from which the step loop looks the terrain up no more: a bilinear
#: lookup of the terrain (a weighted mean of four of its heights) never exceeds that point, so a sample higher up
#: is above the ground (:func:`pack_parameters`); the metre covers the lookup's round-off many times over.
TERRAIN_TOP_MARGIN = 1.0
#: Occupancy probes, or steps, whose geometry is computed together in one vectorised loop (:func:`_probe_indices`,
#: :func:`_step_geometry`): four vectors of float64 with AVX-512, eight without; a GPU thread's local array of 6 x this.
PROBE_BLOCK = 32

@helper_jit()
def _index_map(u, v, du, dv, c, o):
    """One index of :func:`swim.optics.volume.grid_indices`: the cubic of :func:`swim.optics.volume._cubic` (its
    coefficients c[o:o + 10]) at the point (u, v), clipped to the fit's box, plus its tangent plane over the distance
    (du, dv) beyond the box. One function rather than three (the cubic and its two derivatives): each compiled
    function costs numba ~0.05 s on an empty cache, four times over for the literal offsets and types of ``c``."""
    cubic = (c[o] + u * (c[o + 1] + u * (c[o + 3] + u * c[o + 6]) + v * (c[o + 4] + v * c[o + 8]))
             + v * (c[o + 2] + v * (c[o + 5] + v * c[o + 9])) + u * u * v * c[o + 7])
    cubic_du = c[o + 1] + u * (2 * c[o + 3] + 3 * c[o + 6] * u + 2 * c[o + 7] * v) + v * (c[o + 4] + c[o + 8] * v)
    cubic_dv = c[o + 2] + v * (2 * c[o + 5] + 3 * c[o + 9] * v + 2 * c[o + 8] * u) + u * (c[o + 4] + c[o + 7] * u)
    return cubic + cubic_du * du + cubic_dv * dv


@intrinsic
def _prefetch(typingctx, array, k, j, i):
    """Ask the CPU to bring the cell ``array[k, j, i]`` (its first channel; integer indices, in range) into its
    caches ahead of a read (LLVM's ``llvm.prefetch``: a hint, which never faults and changes no result)."""
    sig = types.void(array, k, j, i)

    def codegen(context, builder, signature, args):
        array_type = signature.args[0]
        data = context.make_array(array_type)(context, builder, args[0])
        intp = context.get_value_type(types.intp)
        index = [context.cast(builder, value, kind, types.intp) for value, kind in zip(args[1:], signature.args[1:])]
        index += [ir.Constant(intp, 0)] * (array_type.ndim - 3)
        pointer = cgutils.get_item_pointer(context, builder, array_type, data, index, wraparound=False)
        byte_pointer = ir.IntType(8).as_pointer()
        i32 = ir.IntType(32)
        signature_ir = ir.FunctionType(ir.VoidType(), [byte_pointer, i32, i32, i32])
        hint = cgutils.get_or_insert_function(builder.module, signature_ir, "llvm.prefetch.p0")
        # a read (0), to be kept in every cache level (locality 3), of data (1)
        builder.call(hint, [builder.bitcast(pointer, byte_pointer), ir.Constant(i32, 0), ir.Constant(i32, 3),
                            ir.Constant(i32, 1)])
        return context.get_dummy_value()

    return sig, codegen


#: 1.5 * 2^52: added to a float64 of magnitude below :data:`ROUNDING_LIMIT`, it leaves no fraction bits, so the sum is
#: that number rounded to the nearest whole one, halves to the even one (IEEE 754's default rounding); subtracting it
#: again is exact (:func:`_round_half_even`).
ROUNDING_SHIFT = 6755399441055744.0
#: 2^51: the magnitude below which :data:`ROUNDING_SHIFT` rounds; from 2^52 on, every float64 is a whole number.
ROUNDING_LIMIT = 2251799813685248.0


@helper_jit(fastmath=False)  # fast-math's reassociation would fold (x + shift) - shift into x
def _round_half_even(x):
    """``jnp.round``: to the nearest integer, halves to the even one (a probe on a grid-aligned ray lands on
    exact halves, and rounding them otherwise would place the steps differently from the JAX kernel).

    By adding and subtracting :data:`ROUNDING_SHIFT`: float arithmetic alone, which LLVM vectorises in
    :func:`_probe_indices`' loop. ``math.floor`` returns an integer in numba, and without AVX-512 (the kernels'
    target on Intel CPUs, :mod:`swim.compilation.numba_target`) x86 has no vector conversion of float64 to int64: a
    round's two floors became four scalar conversions, and the probes' loop took 8.2 % of the march's time instead
    of 4.0 % (docs/decisions/0003-cpu-kernel-code.md). Magnitudes from 2^51 on (whole numbers from 2^52 on; a probe
    far beyond the grid, clipped to it after) and NaN are returned as they are."""
    if not abs(x) < ROUNDING_LIMIT:
        return x
    return (x + ROUNDING_SHIFT) - ROUNDING_SHIFT


@helper_jit(inline="always")
def _ix(i):
    """An array index that is never negative, as an unsigned integer: numba then emits no wraparound of negative
    indices for it (a compare, a select and often a reload of the axis' length per index). The step loop's lookups
    take their computed indices through this: 7.6 % fewer instructions, 3-6 % faster
    (docs/decisions/0003-cpu-kernel-code.md). Like any index here (bounds are not checked), it must lie within the
    axis."""
    return np.uint64(i)


@helper_jit()
def _clip(x, lo, hi):
    return min(max(x, lo), hi)


@helper_jit(inline="always")
def _radius_and_height(q0, q1, q2, radius):
    """Distance from the Earth's centre [m] and height [m] of the point q (scene frame, rebased): for the callers
    that need the height alone (the clear-air steps), without the grid indices of :func:`_point_geometry`, which
    numba would inline and type for nothing (~0.5 s of a new installation's compilation)."""
    pz = q2 + radius
    r = math.sqrt(q0 * q0 + q1 * q1 + pz * pz)
    return r, (q0 * q0 + q1 * q1 + q2 * q2 + 2 * radius * q2) / (r + radius)


@helper_jit(inline="always")
def _height_and_indices(q0, q1, q2, radius, centre_u, centre_v, scale, u_lo, u_hi, v_lo, v_hi, z_bottom, dz, c):
    """Distance from the Earth's centre [m], height [m] and grid indices (k, j, i) of the point q (scene frame,
    rebased) with the index map's cubic coefficients ``c`` (an array, or a tuple where a loop over points keeps them
    in registers): :func:`swim.rt.march_jax._point_geometry` without the sun."""
    r, h = _radius_and_height(q0, q1, q2, radius)
    # swim.optics.volume.grid_indices: the cubic inside the box, its tangent plane beyond
    u = (radius * q0 / r - centre_u) / scale
    v = (radius * q1 / r - centre_v) / scale
    uc = _clip(u, u_lo, u_hi)
    vc = _clip(v, v_lo, v_hi)
    du, dv = u - uc, v - vc
    i = _index_map(uc, vc, du, dv, c, 0)
    j = _index_map(uc, vc, du, dv, c, 10)
    return r, h, (h - z_bottom) / dz, j, i


# numba-level inlining: LLVM left this call in the step loop (docs/decisions/0003-cpu-kernel-code.md)
@helper_jit(inline="always")
def _point_geometry(q0, q1, q2, p, coef):
    """:func:`swim.rt.march_jax._point_geometry`: height [m], local solar-zenith cosine, grid indices (k, j, i)."""
    radius = p[_P_RADIUS]
    r, h, k, j, i = _height_and_indices(q0, q1, q2, radius, p[_P_CENTRE], p[_P_CENTRE + 1], p[_P_SCALE], p[_P_BOUNDS],
                                        p[_P_BOUNDS + 1], p[_P_BOUNDS + 2], p[_P_BOUNDS + 3], p[_P_ZBOTTOM], p[_P_DZ],
                                        coef)
    mu_s = (q0 * p[_P_SUN] + q1 * p[_P_SUN + 1] + (q2 + radius) * p[_P_SUN + 2]) / r
    return h, mu_s, k, j, i


@helper_jit(inline="always")
def _geometry_constants(p, coef):
    """The scalars that :func:`_height_and_indices` takes after the point (from :func:`pack_parameters`'s ``p``) and
    the index map's 20 cubic coefficients as a tuple: a loop over points then keeps them in registers, sees no table
    reads to order against its stores, and LLVM vectorises it (:func:`_probe_indices`, :func:`_step_geometry`)."""
    scalars = (p[_P_RADIUS], p[_P_CENTRE], p[_P_CENTRE + 1], p[_P_SCALE], p[_P_BOUNDS], p[_P_BOUNDS + 1],
               p[_P_BOUNDS + 2], p[_P_BOUNDS + 3], p[_P_ZBOTTOM], p[_P_DZ])
    c = (coef[0], coef[1], coef[2], coef[3], coef[4], coef[5], coef[6], coef[7], coef[8], coef[9], coef[10], coef[11],
         coef[12], coef[13], coef[14], coef[15], coef[16], coef[17], coef[18], coef[19])
    return scalars, c


@helper_jit()
def _probe_indices(st0, st1, st2, d0, d1, d2, s0, length, n_probe, first, count, p, coef, shape, probe_at):
    """Grid indices of probes ``first`` ... ``first + count - 1`` of ``n_probe`` at the middles of equal intervals
    of the segment [s0, s0 + length] [m] of a ray, into ``probe_at[0:3, :count]`` (k, j, i), and the nearest
    cell's within the grid of ``shape`` (nk, ny, nx) into ``probe_at[3:6, :count]`` (as floats).

    The geometry of :func:`_point_geometry` in a loop of its own, without table reads or branches and with the
    constants in registers, which LLVM vectorises: ~5 ns per probe instead of ~23 ns inside the loop of lookups
    (docs/decisions/0003-cpu-kernel-code.md)."""
    (radius, centre_u, centre_v, scale, u_lo, u_hi, v_lo, v_hi, z_bottom, dz), c = _geometry_constants(p, coef)
    for b in range(count):
        s = s0 + (first + b + 0.5) / n_probe * length
        _, _, k, j, i = _height_and_indices(st0 + s * d0, st1 + s * d1, st2 + s * d2, radius, centre_u, centre_v,
                                            scale, u_lo, u_hi, v_lo, v_hi, z_bottom, dz, c)
        probe_at[0, b] = k
        probe_at[1, b] = j
        probe_at[2, b] = i
        probe_at[3, b] = _clip(_round_half_even(k), 0.0, shape[0] - 1.0)
        probe_at[4, b] = _clip(_round_half_even(j), 0.0, shape[1] - 1.0)
        probe_at[5, b] = _clip(_round_half_even(i), 0.0, shape[2] - 1.0)


@helper_jit()
def _bilinear(table, c, fu, fv):
    """One channel c of :func:`swim.rt.march_jax._bilinear_table` on a (C, nu, nv) table, clamped."""
    u0, v0, a, b = _bilinear_index(table.shape[1], table.shape[2], fu, fv)
    return _bilinear_at(table, c, u0, v0, a, b)


@helper_jit()
def _bilinear_index(nu, nv, fu, fv):
    """Corner (u0, v0) and weights (a, b) of a clamped bilinear lookup, shared by all channels of a table."""
    u0, a = _lerp_index(fu, nu)
    v0, b = _lerp_index(fv, nv)
    return u0, v0, a, b


@helper_jit()
def _lerp_index(f, n):
    """Lower index and weight of a clamped linear lookup at fractional index f in a table axis of n entries."""
    f = _clip(f, 0.0, n - 1.001)
    i0 = int(f)  # f >= 0: truncation is the floor, without math.floor's rounding first
    return i0, f - i0


@helper_jit()
def _bilinear_at(table, c, u0, v0, a, b):
    return ((table[_ix(c), _ix(u0), _ix(v0)] * (1 - b) + table[_ix(c), _ix(u0), _ix(v0 + 1)] * b) * (1 - a)
            + (table[_ix(c), _ix(u0 + 1), _ix(v0)] * (1 - b) + table[_ix(c), _ix(u0 + 1), _ix(v0 + 1)] * b) * a)


@helper_jit()
def _bilinear_clamped(field, j, i):
    """:func:`swim.rt.march_jax.bilinear_clamped` of the first channel of a (C, ny, nx) field at grid indices (j, i),
    clamped to its edges."""
    return _bilinear(field, 0, _clip(j, 0.0, field.shape[1] - 1.0), _clip(i, 0.0, field.shape[2] - 1.0))


@helper_jit()
def _terrain_gap(h, j, i, terrain):
    """Height above the terrain (the (1, ny, nx) field, :func:`_bilinear_clamped`) [m]."""
    return h - _bilinear_clamped(terrain, j, i)


@helper_jit()
def _gap_along(s, st0, st1, st2, d0, d1, d2, p, coef, terrain):
    """Height above the terrain [m] at distance s [m] along a ray (``gap`` of
    :func:`swim.rt.march_jax.refine_terrain_hit`)."""
    h, _, _, j, i = _point_geometry(st0 + s * d0, st1 + s * d1, st2 + s * d2, p, coef)
    return _terrain_gap(h, j, i, terrain)


@helper_jit()
def _terrain_crossing(hit_s, lo, hi, n_bisections, st0, st1, st2, d0, d1, d2, p, coef, terrain):
    """:func:`swim.rt.march_jax.refine_terrain_hit`: the ground's crossing [m] by bisection between the samples ``lo``
    (above the ground) and ``hi`` (below it) that bracket it; ``hit_s`` where they do not."""
    if (_gap_along(lo, st0, st1, st2, d0, d1, d2, p, coef, terrain) >= 0
            and _gap_along(hi, st0, st1, st2, d0, d1, d2, p, coef, terrain) < 0):
        for _ in range(n_bisections):
            mid = 0.5 * (lo + hi)
            if _gap_along(mid, st0, st1, st2, d0, d1, d2, p, coef, terrain) < 0:
                hi = mid
            else:
                lo = mid
        return 0.5 * (lo + hi)
    return hit_s


@helper_jit()
def _step_geometry(st0, st1, st2, d0, d1, d2, edges, first, count, p, coef, step_at):
    """:func:`_point_geometry` at the middles of steps ``first`` ... ``first + count - 1`` of a ray (between its
    ``edges`` [m]) into ``step_at[0:6, :count]`` (height [m], local solar-zenith cosine, k, j, i, and the sky
    table's height coordinate sqrt(height / top)): a loop that LLVM vectorises, as :func:`_probe_indices`
    (docs/decisions/0003-cpu-kernel-code.md)."""
    (radius, centre_u, centre_v, scale, u_lo, u_hi, v_lo, v_hi, z_bottom, dz), c = _geometry_constants(p, coef)
    sun0, sun1, sun2 = p[_P_SUN], p[_P_SUN + 1], p[_P_SUN + 2]
    top = p[_P_TOP]
    for b in range(count):
        s_lo = edges[first + b]
        s = s_lo + 0.5 * (edges[first + b + 1] - s_lo)  # as the step loop computes it
        q0, q1, q2 = st0 + s * d0, st1 + s * d1, st2 + s * d2
        r, h, k, j, i = _height_and_indices(q0, q1, q2, radius, centre_u, centre_v, scale, u_lo, u_hi, v_lo, v_hi,
                                            z_bottom, dz, c)
        step_at[0, b] = h
        step_at[1, b] = (q0 * sun0 + q1 * sun1 + (q2 + radius) * sun2) / r
        step_at[2, b] = k
        step_at[3, b] = j
        step_at[4, b] = i
        step_at[5, b] = math.sqrt(_clip(h / top, 0.0, 1.0))  # the sky table's height coordinate


@helper_jit(inline="always")
def _lower_corner(k, j, i, nk, ny, nx):
    """Whether the fractional grid indices (k, j, i) lie within a grid of nk x ny x nx cells, and if so the lower
    corner (k0, j0, i0) of the cell whose eight corners a trilinear sample there reads (clamped so that k0 + 1 etc.
    are cells too): the step loop's volume sample and :func:`_prefetch_corners`."""
    if 0 <= k <= nk - 1 and 0 <= j <= ny - 1 and 0 <= i <= nx - 1:
        # >= 0 here, so truncation is the floor: numba's math.floor returns an integer, which the clip turned back
        # into a float and int() into an integer again (docs/decisions/0003-cpu-kernel-code.md)
        return True, int(min(k, nk - 2.0)), int(min(j, ny - 2.0)), int(min(i, nx - 2.0))
    return False, 0, 0, 0


@helper_jit()
def _prefetch_corners(volume, count, step_at):
    """Prefetch the eight corner cells of the trilinear volume samples of steps 0 ... count - 1 of a block (their
    grid indices (k, j, i) in ``step_at[2:5]``, from :func:`_step_geometry`), before the step loop reads them.

    The corners' reads waited on memory for ~30 % of the kernel's time where rays fan out from an observer through a
    volume bigger than the caches (docs/decisions/0003-cpu-kernel-code.md); a block of 32 steps' corners (at most 256
    cells of 36 bytes or fewer) fits in the first-level cache."""
    nk, ny, nx, _ = volume.shape
    for b in range(count):
        inside, k0, j0, i0 = _lower_corner(step_at[2, b], step_at[3, b], step_at[4, b], nk, ny, nx)
        if inside:
            for dk in range(2):
                for dj in range(2):
                    _prefetch(volume, k0 + dk, j0 + dj, i0)
                    _prefetch(volume, k0 + dk, j0 + dj, i0 + 1)  # the cell after, often on the next cache line

