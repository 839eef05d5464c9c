"""The step loop of the ray march fused into one loop per ray, for CPUs (numba).

:mod:`swim.rt.march` marches a chunk of rays in lockstep with JAX: every step is ~45 XLA kernels over the
whole chunk, each writing its result to memory for the next, and on a CPU that costs ~0.6 µs of CPU time per
ray and step (~1400 cycles), far more than the step's arithmetic and ~150 table reads
(docs/decisions/0002-per-ray-cpu-kernel.md). This module runs the same steps with every intermediate in registers, one
ray at a time, rays in parallel over the cores, and stops a ray as soon as it meets the ground. The loop and the per-ray
set-up before it (aerosol class, diffuse-source profiles: :func:`prepare_rays`) are duplicated here; the clouds'
composition after it is :mod:`swim.rt.compose_cpu` (the clouds) and :mod:`swim.rt.ground_cpu` (the ground's Eq. 35). The
JAX march remains the kernel on GPUs and for gradients. ``tests/unit/rt/test_rt_march.py`` holds both kernels to the
float64 reference and to each other.

The loop allocates nothing (its work arrays come from :func:`work_arrays`, once per call) and uses scalar ``math``
functions, so that LLVM keeps a ray's state in registers. The geometry and table lookups it shares with the
ground's term are :mod:`swim.rt.march_geometry_cpu`'s, and the step's arithmetic per wavelength (the sky table's
lanes, the accumulators, the hydrometeors' sources) :mod:`swim.rt.march_lanes_cpu`'s; their names are importable
from this module too.

Each function mirrors its JAX counterpart in :mod:`swim.rt.march_jax` (named in its docstring) and follows
the same equations (Albers et al. 2020, doi:10.5194/amt-13-3235-2020: Eq. 3 for the clear-sky source,
Eq. 12 for the hydrometeor integral); it computes in float64 from the float32 tables.
"""

from __future__ import annotations

import math

import numpy as np

from numba import njit

from ..compilation.numba_jit import JIT_KERNEL, helper_jit, vectorising
from ..constants import AFTER_MIN_STEPS, CELL_PROBES, DIFFUSE_SUN_T_MIN, GAS_COLUMN_ROW, GAS_OZONE_ROW
# the kernel's helpers, also importable from here (ground_cpu, compose_cpu, the tests and the benchmarks take them
# from this module)
from .march_geometry_cpu import (  # noqa: F401
    _N_PARAMETERS, _P_BOUNDS, _P_CENTRE, _P_DH, _P_DZ, _P_RADIUS, _P_SCALE, _P_SUN, _P_SURFACE_MARGIN, _P_TERRAIN_TOP,
    _P_TOP, _P_ZBOTTOM, PROBE_BLOCK, ROUNDING_LIMIT, ROUNDING_SHIFT, TERRAIN_TOP_MARGIN, _bilinear, _bilinear_at,
    _bilinear_clamped, _bilinear_index, _clip, _gap_along, _geometry_constants, _height_and_indices, _index_map, _ix,
    _lerp_index, _lower_corner, _point_geometry, _prefetch, _prefetch_corners, _probe_indices, _radius_and_height,
    _round_half_even, _step_geometry, _terrain_crossing, _terrain_gap)
from .march_lanes_cpu import (  # noqa: F401
    LANES, SKY_LANE_COLUMNS, _accumulate_cloud, _accumulate_lanes, _cloud_sources, _corner_lane, _corner_lanes,
    _field_at, _mean_transmittance, _profile_lanes, _ratio_above)
from .march_lanes_cpu import sky_lanes as sky_lanes


def pack_parameters(consts):
    """The scalars of :func:`swim.rt.march_inputs.kernel_constants` as one float64 vector (17,) and the index map's
    cubic coefficients (20,). Entry :data:`_P_TERRAIN_TOP` is the height [m] above which no sample can be under the
    terrain: the terrain's (``consts["terrain"]``) highest point plus :data:`TERRAIN_TOP_MARGIN`, or infinity where
    there is no terrain or it is not finite everywhere (every sample then looks it up); the last, the margin [cells]
    by which the ground's fields extend beyond the grid (``consts["surface_margin"]``)."""
    p = np.zeros(_N_PARAMETERS)
    index_map = consts["index_map"]
    p[_P_RADIUS] = float(consts["radius"])
    p[_P_SUN:_P_SUN + 3] = np.asarray(consts["sun"], dtype=float)
    p[_P_ZBOTTOM] = float(consts["z_bottom"])
    p[_P_DZ] = float(consts["dz"])
    p[_P_CENTRE:_P_CENTRE + 2] = np.asarray(index_map["index_map_centre"], dtype=float)
    p[_P_SCALE] = float(index_map["index_map_scale"])
    if "index_map_bounds" in index_map:
        p[_P_BOUNDS:_P_BOUNDS + 4] = np.asarray(index_map["index_map_bounds"], dtype=float)
    else:  # no box: the cubic everywhere (clipping to an infinite box changes nothing)
        p[_P_BOUNDS:_P_BOUNDS + 4] = (-np.inf, np.inf, -np.inf, np.inf)
    p[_P_DH] = float(consts["dh"])
    p[_P_TOP] = float(consts["top"])
    terrain = consts.get("terrain")
    highest = float(np.max(np.asarray(terrain))) if terrain is not None and np.size(terrain) else math.inf
    p[_P_TERRAIN_TOP] = highest + TERRAIN_TOP_MARGIN if math.isfinite(highest) else math.inf
    # the ground's fields extend this many cells beyond the grid (swim.rt.march_inputs.extended_surface)
    p[_P_SURFACE_MARGIN] = float(np.asarray(consts.get("surface_margin", 0.0)))
    coef = np.asarray(index_map["index_map_coefficients"], dtype=float).reshape(20)
    return p, coef


@helper_jit()
def _segment_cells(st0, st1, st2, d0, d1, d2, s0, length, p, coef, shape, probe_at):
    """:func:`swim.rt.march_jax.segment_cells` for one ray: the length in cells of the grid segment [s0, s0 + length]
    [m], from the grid indices of :data:`swim.constants.CELL_PROBES` points (one block of :func:`_probe_indices`)."""
    n = CELL_PROBES
    _probe_indices(st0, st1, st2, d0, d1, d2, s0, length, n, 0, n, p, coef, shape, probe_at)
    cells = 0.0
    for b in range(1, n):
        cells += max(abs(probe_at[0, b] - probe_at[0, b - 1]),
                     max(abs(probe_at[1, b] - probe_at[1, b - 1]), abs(probe_at[2, b] - probe_at[2, b - 1])))
    return cells * (n / (n - 1.0))


@helper_jit()
def _probe_occupancy(st0, st1, st2, d0, d1, d2, s0, length, p, coef, occupancy, n_probe, cdf, probe_at):
    """Probe the step classes of :func:`swim.rt.march_inputs.step_classes` (or an occupancy grid: 1 occupied, 0
    empty) at n_probe equal intervals of a grid segment: each interval's class into ``cdf[1:n_probe + 1]`` (1.0
    occupied, 0.0 empty, -1.0 sunlit clear air); returns the numbers of occupied and of sunlit probes. The probes'
    indices are computed in blocks of ``probe_at.shape[1]`` (:func:`_probe_indices`), then looked up one by one."""
    nk, ny, nx = occupancy.shape
    cdf[0] = 0.0
    occupied = 0
    sunlit = 0
    block = probe_at.shape[1]
    for first in range(0, n_probe, block):
        count = min(block, n_probe - first)
        _probe_indices(st0, st1, st2, d0, d1, d2, s0, length, n_probe, first, count, p, coef, (nk, ny, nx),
                       probe_at)
        for b in range(count):
            m = first + b
            kind = occupancy[int(probe_at[3, b]), int(probe_at[4, b]), int(probe_at[5, b])]
            if kind > 0:
                occupied += 1
                cdf[m + 1] = 1.0
            elif kind < 0:
                sunlit += 1
                cdf[m + 1] = -1.0
            else:
                cdf[m + 1] = 0.0
    return occupied, sunlit


@helper_jit()
def _adaptive_edges(st0, st1, st2, d0, d1, d2, s0, length, n_steps, p, coef, occupancy, n_probe, empty_weight,
                    probe_spacing, cell_slack, empty_steps, empty_cells_per_step, sunlit_steps, sunlit_cells_per_step,
                    cdf, edges, probe_at):
    """:func:`swim.rt.march_jax.grid_step_edges` for one ray, written into ``edges`` (steps + 1,); returns its number
    of steps. With the probe count of :func:`swim.rt.march_jax.probe_counts`: a ray that crosses more than ``n_probe *
    probe_spacing`` cells (:func:`_segment_cells`) is probed once per ``probe_spacing`` cells instead (at most
    ``cdf.size - 1`` probes)."""
    cells = _segment_cells(st0, st1, st2, d0, d1, d2, s0, length, p, coef, occupancy.shape, probe_at)
    # clamped before the conversion to an integer (a tiny spacing would overflow it)
    need = min(math.ceil(cells / probe_spacing - cell_slack), cdf.shape[0] - 1.0) if probe_spacing > 0 else 0.0
    if need > n_probe:
        n_probe = int(need)
    occupied, sunlit = _probe_occupancy(st0, st1, st2, d0, d1, d2, s0, length, p, coef, occupancy, n_probe, cdf,
                                        probe_at)
    # empty-space skipping: the empty intervals get at most max(empty_steps, empty cells / empty_cells_per_step)
    # steps, the sunlit clear ones at most max(sunlit_steps, sunlit cells / sunlit_cells_per_step), the occupied ones
    # keep their density (and the ray takes fewer steps in all)
    if sunlit_steps <= 0:  # no class of its own: sunlit clear air is empty air
        sunlit = 0
    empty = n_probe - occupied - sunlit
    weight_empty = weight_sunlit = empty_weight
    if empty_steps > 0 and empty + sunlit > 0:
        total = occupied + empty_weight * (empty + sunlit)
        # less cell_slack: whole numbers of cells (rays along a grid axis) must not round the count up in float64
        # here and not in float32 in the JAX kernel
        steps_empty = n_steps * empty_weight * empty / total
        steps_sunlit = n_steps * empty_weight * sunlit / total
        capped = False
        if empty > 0:
            budget = max(float(empty_steps), cells * empty / (n_probe * empty_cells_per_step) - cell_slack)
            if steps_empty > budget:
                steps_empty, capped = budget, True
        if sunlit > 0:
            budget = max(float(sunlit_steps), cells * sunlit / (n_probe * sunlit_cells_per_step) - cell_slack)
            if steps_sunlit > budget:
                steps_sunlit, capped = budget, True
        if capped:
            fewer = min(math.ceil(n_steps * occupied / total + steps_empty + steps_sunlit), float(n_steps))
            # the weight left to the unoccupied intervals at the occupied ones' steps per unit weight, n_steps /
            # total, shared in proportion to their capped steps
            rest = fewer * total / n_steps - occupied
            share = steps_empty / (steps_empty + steps_sunlit)
            weight_empty = rest / max(empty, 1) * share
            weight_sunlit = rest / max(sunlit, 1) * (1.0 - share)
            n_steps = int(fewer)
    if sunlit_steps <= 0:
        weight_sunlit = weight_empty
    for m in range(n_probe):  # the cumulative step density
        kind = cdf[m + 1]
        cdf[m + 1] = cdf[m] + (1.0 if kind > 0.5 else (weight_sunlit if kind < -0.5 else weight_empty))
    _invert_cdf(s0, length, n_steps, n_probe, cdf, edges)
    return n_steps


@helper_jit(inline="always")
def _predicted_halving(have_prev, prev_hi, prev_beta, s_lo, ds, depth, max_depth, th, refine_visible, pending,
                       refine_slots, tau_refine):
    """Whether the interval [s_lo, s_lo + ds] [m] at refinement ``depth`` is halved before it is sampled (one level),
    :func:`swim.rt.march_jax._predicted_halving`: the accumulated interval just before it (ending at ``prev_hi``) had an
    extinction ``prev_beta`` [1/m] that makes it thicker than ``tau_refine``, so its own sample would most likely
    find it too thick and be discarded for its halves. The caller checks the ray's refinement budget."""
    return (have_prev and prev_hi == s_lo and depth < max_depth and th < refine_visible
            and pending + 2 <= refine_slots and prev_beta * ds > tau_refine)


@helper_jit()
def _clear_edges(st0, st1, st2, d0, d1, d2, s0, length, n_steps, p, beta_gas, spectra, n_probe, power, floor,
                 cdf, edges):
    """:func:`swim.rt.march_jax.clear_step_edges` for one ray, written into ``edges`` (n_steps + 1,)."""
    n_gas = beta_gas.shape[1]
    cdf[0] = 0.0
    largest = 0.0
    for m in range(n_probe):  # the density at the probes first (in cdf[1:]), then its running sum
        s = s0 + (m + 0.5) / n_probe * length
        _, h = _radius_and_height(st0 + s * d0, st1 + s * d1, st2 + s * d2, p[_P_RADIUS])
        g0, w = _lerp_index(h / p[_P_DH], n_gas)
        beta = 0.0
        # the scattering components' (the clear-sky source's) extinction at 546 nm: not ozone's, which scatters
        # nothing (with it the steps crowd into the ozone layer, away from the source: from space 0.1-0.2 % worse)
        for q in range(GAS_OZONE_ROW):
            beta += (beta_gas[q, g0] * (1 - w) + beta_gas[q, g0 + 1] * w) * spectra[q, 1]
        cdf[m + 1] = max(beta, 0.0) ** power
        largest = max(largest, cdf[m + 1])
    for m in range(n_probe):
        cdf[m + 1] = cdf[m] + cdf[m + 1] + floor * largest + 1e-30
    _invert_cdf(s0, length, n_steps, n_probe, cdf, edges)


@helper_jit(inline="always")
def _descending_at(st0, st1, st2, d0, d1, d2, s, radius):
    """Whether a ray comes closer to the earth's centre at distance s [m] along it."""
    return (st0 + s * d0) * d0 + (st1 + s * d1) * d1 + (st2 + s * d2 + radius) * d2 < 0


@helper_jit()
def _lowest_along(st0, st1, st2, d0, d1, d2, radius, end):
    """:func:`swim.rt.march_jax.lowest_point` for one ray: the distance [m] along it, within [0, end], of its point
    closest to the earth's centre (the ray's height is convex along it)."""
    return _clip(-(st0 * d0 + st1 * d1 + (st2 + radius) * d2), 0.0, end)


@helper_jit(inline="always")
def _column_above(beta_gas, f):
    """The fraction of the vertical optical depth above fractional height index ``f`` of the clear-air height table
    (its row :data:`swim.constants.GAS_COLUMN_ROW`, clamped linear lookup)."""
    g0, w = _lerp_index(f, beta_gas.shape[1])
    return beta_gas[GAS_COLUMN_ROW, g0] * (1 - w) + beta_gas[GAS_COLUMN_ROW, g0 + 1] * w


@helper_jit()
def _after_steps(st0, st1, st2, d0, d1, d2, s_exit, n_after, p, beta_gas):
    """:func:`swim.rt.march_jax.after_step_counts` for one ray: its clear-air steps after the grid, which it leaves at
    ``s_exit`` [m]; ``n_after`` where ``beta_gas`` has no column row (:data:`swim.constants.GAS_COLUMN_ROW`)."""
    if beta_gas.shape[0] <= GAS_COLUMN_ROW:
        return n_after
    radius = p[_P_RADIUS]
    if _descending_at(st0, st1, st2, d0, d1, d2, s_exit, radius):  # where it leaves: it may end on the ground
        return n_after
    e0, e1, e2 = st0 + s_exit * d0, st1 + s_exit * d1, st2 + s_exit * d2
    s_low = _lowest_along(st0, st1, st2, d0, d1, d2, radius, s_exit)
    above_exit = _column_above(beta_gas, _radius_and_height(e0, e1, e2, radius)[1] / p[_P_DH])
    above_low = _column_above(beta_gas, _radius_and_height(st0 + s_low * d0, st1 + s_low * d1, st2 + s_low * d2,
                                                           radius)[1] / p[_P_DH])
    q = _clip(above_exit / max(above_low, 1e-30), 0.0, 1.0)
    return min(max(int(math.ceil(n_after * math.sqrt(q))), min(AFTER_MIN_STEPS, n_after)), n_after)


@helper_jit()
def _invert_cdf(s0, length, n_steps, n_probe, cdf, edges):
    """Edges (n_steps + 1,) [m] that cut the cumulative step density ``cdf[:n_probe + 1]`` (unnormalised, over
    n_probe equal intervals of [s0, s0 + length]) into n_steps equal parts (``_edges_from_density`` of
    :mod:`swim.rt.march`)."""
    total = cdf[n_probe]
    for m in range(n_probe + 1):
        cdf[m] /= total
    idx = 0  # searchsorted(cdf, t, "right") - 1, walked forward since t increases
    for m in range(n_steps + 1):
        t = m / n_steps
        while idx + 1 <= n_probe and cdf[idx + 1] <= t:
            idx += 1
        ic = min(idx, n_probe - 1)
        c0, c1 = cdf[ic], cdf[ic + 1]
        frac = _clip((ic + (t - c0) / max(c1 - c0, 1e-12)) / n_probe, 0.0, 1.0)
        edges[m] = s0 + frac * length


#: Depth [m] under the terrain below which a ray's end on the sea-level sphere takes the zero-length end step
#: (:func:`_march_ray_range`): far above float64 round-off at the earth's radius, far below any height that matters.
END_STEP_GAP = 1e-3


@vectorising
@njit(**JIT_KERNEL, nogil=True)
def _march_ray_range(first, stop, stride, start, direction, bounds, valid, p_rayleigh, p_aerosol, p_stratospheric,
                     class_lower, class_weight, ms_profile, use_ms, n_before, n_grid, n_after, p, coef, beta_gas,
                     spectra, sky_lanes, diffuse_classes, n_class, volume, terrain, occupancy, angstrom, aerosol_ssa,
                     stratospheric_ssa, n_probe, empty_weight, probe_spacing, n_probe_max, cell_slack, empty_steps,
                     empty_cells_per_step, sunlit_steps, sunlit_cells_per_step, n_clear_probe, clear_power,
                     clear_floor, tau_refine, max_depth,
                     refine_budget, refine_visible, refine_slots, n_bisections, stop_tau, tau_clear, tau_h, tau_species,
                     l_clear, i_nogas, i_gas, i_cloud_t, alive_out, hit_out, s_hit_out, samples_out, cloud_mode,
                     p_hydro, ray_ms, hydro_scale, hydro_narrow, ms_field, ms_coarsen, ms_above,
                     above_heights, l_cloud, edges, cdf,
                     stack_lo, stack_hi, stack_depth, saved, tsp, ms_lanes, vol, vol32, probe_at):
    """Rays ``range(first, stop, stride)`` of :func:`march_rays`, with the work arrays that its caller allocates
    once (:func:`work_arrays`), in one call. A call per ray made the CPU kernel 4 % slower (its ~70
    arguments were passed anew every time), and numba's inlining of it failed.

    This is the compiled kernel that :func:`march_rays` calls from Python, without the GIL, with LLVM's SLP
    vectoriser on (:func:`vectorising`). A compiled ``march_rays`` that allocated the work arrays and called this
    took 1.5-2 s longer to compile on an empty cache (numba optimised and emitted the whole loop a second time
    for it), for no gain at run time (docs/decisions/0003-cpu-kernel-code.md).

    A ray's accumulators (per wavelength: the clear-sky optical depth, the transmittance to the observer, the
    clear-sky radiance and the two Eq. 12 integrals) are scalars, which LLVM keeps in registers; as elements of
    work arrays (which may alias the tables, as far as LLVM knows) they were loaded and stored at every step, and
    the kernel was ~7 % slower (docs/decisions/0002-per-ray-cpu-kernel.md)."""
    nk, ny, nx, n_c = volume.shape
    n_species = tau_species.shape[1]
    aerosol_3d = n_c > n_species + 2  # the 3-D aerosol's two channels (packed only where it is not zero)
    n_gas = beta_gas.shape[1]
    nu_sky, nmu_sky = sky_lanes.shape[0], sky_lanes.shape[1]
    nu_class = diffuse_classes.shape[1] // n_class
    n_rows, nmu_class = diffuse_classes.shape[1], diffuse_classes.shape[2]
    n_u = ms_profile.shape[2]
    top = p[_P_TOP]
    dh = p[_P_DH]
    terrain_top = p[_P_TERRAIN_TOP]
    # the wavelengths' constants (and each ray's phase functions, below) as tuples of scalars, read once: read from
    # their arrays, they were read again at every step (the loop's stores may alias them, as far as LLVM knows);
    # 3-4 % faster (docs/decisions/0003-cpu-kernel-code.md). One per lane (LANES): the padding lane's is the sky table's
    # zero column, a value that the compiler cannot fold away, so that the four lanes' arithmetic stays alike
    # (docs/decisions/0003-cpu-kernel-code.md)
    pad = sky_lanes[0, 0, 3]
    spec_r = (float(spectra[0, 0]), float(spectra[0, 1]), float(spectra[0, 2]), pad)
    spec_a = (float(spectra[1, 0]), float(spectra[1, 1]), float(spectra[1, 2]), pad)
    spec_s = (float(spectra[2, 0]), float(spectra[2, 1]), float(spectra[2, 2]), pad)
    spec_o = (float(spectra[3, 0]), float(spectra[3, 1]), float(spectra[3, 2]), pad)
    ang = (float(angstrom[0]), float(angstrom[1]), float(angstrom[2]), pad)
    ssa_a = (float(aerosol_ssa[0]), float(aerosol_ssa[1]), float(aerosol_ssa[2]), pad)
    ssa_s = (float(stratospheric_ssa[0]), float(stratospheric_ssa[1]), float(stratospheric_ssa[2]), pad)
    for r in range(first, stop, stride):
        st0, st1, st2 = start[r, 0], start[r, 1], start[r, 2]
        row = _ix(r)
        phase_r = p_rayleigh[row]
        phase_a = (p_aerosol[row, 0], p_aerosol[row, 1], p_aerosol[row, 2], p_aerosol[row, 2])
        phase_s = (p_stratospheric[row, 0], p_stratospheric[row, 1], p_stratospheric[row, 2], p_stratospheric[row, 2])
        d0, d1, d2 = direction[r, 0], direction[r, 1], direction[r, 2]
        # per lane (the wavelengths 0, 1, 2 and the padding): tau_clear, e^-(tau_clear + tau_h) to the observer
        # (carried as a product), l_clear, i_nogas and i_gas
        tc = lc = i_ng = i_g = (0.0, 0.0, 0.0, 0.0)
        lcl = (0.0, 0.0, 0.0, 0.0)  # the hydrometeors' radiance (cloud_mode: single and diffuse scattering)
        to = (1.0, 1.0, 1.0, 1.0)
        if use_ms:  # the ray's multiple-scattering profiles (9, n_u) as rows of lanes: ms_lanes[u, 4 * k + c]
            for u in range(n_u):
                for c in range(3):
                    ms_lanes[u, c] = ms_profile[c, row, u]
                    ms_lanes[u, LANES + c] = ms_profile[3 + c, row, u]
                    ms_lanes[u, 2 * LANES + c] = ms_profile[6 + c, row, u]
        for c in range(n_species):
            tsp[c] = 0.0
        th = 0.0
        e_th = 1.0
        ict = 0.0
        samples = 0  # the medium's samples along this ray: every step evaluated, refined halves included
        alive = valid[r]
        hit = False
        hit_s = 0.0
        hit_lo = 0.0
        hit_hi = 0.0
        gap_prev = 1e9
        s_last = 0.0
        c0 = class_lower[r]
        wc = class_weight[r]
        hit_from = 0.0  # where the step in which the ray met the ground began
        s_hit = bounds[r, 2]
        for segment in range(4):
            terminal = segment == 3
            end_step = False
            if terminal:
                # swim.rt.march_jax._terminal_step: from the start of the step in which the ray met the ground (whose
                # sample may lie far inside the terrain, and which added nothing) to the refined crossing, or
                # back to it where it lies in the far half of the step before
                if not hit:
                    break
                s_hit = _terrain_crossing(hit_s, hit_lo, hit_hi, n_bisections, st0, st1, st2, d0, d1, d2, p, coef,
                                          terrain)
                length = s_hit - hit_from
                # where the step before it began: its sample hit_lo is its middle (< 0 where there was none)
                back_to = 2.0 * hit_lo - hit_from
                if not (length > 0 or (length < 0 and back_to >= 0)):
                    break
                n_steps, s0, in_grid = 0, hit_from, True
                alive = True
            elif not alive:
                continue
            elif segment == 0:
                n_steps, s0, length, in_grid = n_before, 0.0, bounds[r, 0], False
            elif segment == 1:
                n_steps, s0, length, in_grid = n_grid, bounds[r, 0], bounds[r, 1] - bounds[r, 0], True
            else:
                n_steps, s0, length, in_grid = n_after, bounds[r, 1], bounds[r, 2] - bounds[r, 1], False
                n_steps = _after_steps(st0, st1, st2, d0, d1, d2, s0, n_after, p, beta_gas)
                # a ray still alive that ends on the sea-level sphere under the terrain (which beyond the grid keeps
                # its edge's heights) takes one more step, of zero length at that end: its sample detects a crossing
                # in the far half of the ray's last step, which no later step would
                # (docs/decisions/0004-step-placement.md); not where the terrain is at sea level, whose crossing is that
                # end (a gap of ~1e-9 m either way)
                end_step = (_descending_at(st0, st1, st2, d0, d1, d2, bounds[r, 2], p[_P_RADIUS])
                            and _gap_along(bounds[r, 2], st0, st1, st2, d0, d1, d2, p, coef, terrain) < -END_STEP_GAP)
            if terminal:
                pass  # no placed steps: one or two pending intervals (below), sampled as refined halves are
            elif n_steps == 0 and not end_step:
                continue
            elif in_grid:
                n_steps = _adaptive_edges(st0, st1, st2, d0, d1, d2, s0, length, n_steps, p, coef, occupancy, n_probe,
                                          empty_weight, probe_spacing, cell_slack, empty_steps, empty_cells_per_step,
                                          sunlit_steps, sunlit_cells_per_step,
                                          cdf, edges, probe_at)
            elif n_steps > 0:
                _clear_edges(st0, st1, st2, d0, d1, d2, s0, length, n_steps, p, beta_gas, spectra,
                             n_clear_probe, clear_power, clear_floor, cdf, edges)
            # a segment of zero length takes one step there (after the grid: the zero-length end step)
            taken = n_steps if length > 0 or terminal else 1
            if end_step:
                if n_steps > 0 and length > 0:
                    edges[_ix(n_steps + 1)] = edges[_ix(n_steps)]
                    taken = n_steps + 1
                else:
                    edges[0] = edges[1] = s0 + max(length, 0.0)
                    taken = 1
            m = 0
            block_first = block_stop = 0  # the steps whose geometry is in probe_at (_step_geometry)
            b = _ix(0)  # a placed step's column there (unsigned, as _ix gives it: an int would unify to float)
            pending = 0
            if terminal:  # pending intervals, the last one on top
                if length > 0:
                    stack_lo[0], stack_hi[0], stack_depth[0] = hit_from, s_hit, max_depth
                    pending = 1
                else:  # the crossing lies in the far half of the step before: that step taken back, then again
                    stack_lo[0], stack_hi[0], stack_depth[0] = back_to, s_hit, max_depth
                    stack_lo[1], stack_hi[1], stack_depth[1] = hit_from, back_to, max_depth
                    pending = 2
            budget = refine_budget if in_grid and tau_refine > 0 and not terminal else 0
            have_prev = False  # an accumulated grid interval that may still be rolled back
            prev_lo = prev_hi = prev_beta = 0.0
            prev_depth = 0
            while True:
                if pending == 0:
                    if m >= taken:
                        break
                    if m >= block_stop:  # the next block of steps' geometry, in one vectorised loop
                        block_first, block_stop = m, min(m + probe_at.shape[1], taken)
                        _step_geometry(st0, st1, st2, d0, d1, d2, edges, m, block_stop - m, p, coef, probe_at)
                        if in_grid:
                            _prefetch_corners(volume, block_stop - m, probe_at)
                    s_lo, s_hi = edges[_ix(m)], edges[_ix(m + 1)]
                    b = _ix(m - block_first)
                    m += 1
                    depth = 0
                    from_block = True  # its midpoint's geometry is in probe_at
                else:  # a refined half
                    pending -= 1
                    s_lo, s_hi, depth = stack_lo[pending], stack_hi[pending], stack_depth[pending]
                    from_block = False
                ds = s_hi - s_lo
                # an interval that the one before it predicts too thick is halved before it is sampled
                # (_predicted_halving): its second half pending, its first half sampled here
                if budget > 0 and alive and _predicted_halving(have_prev, prev_hi, prev_beta, s_lo, ds, depth,
                                                                max_depth, th, refine_visible, pending, refine_slots,
                                                                tau_refine):
                    half = s_lo + 0.5 * ds
                    stack_lo[pending], stack_hi[pending], stack_depth[pending] = half, s_hi, depth + 1
                    s_hi = half
                    pending += 1
                    budget -= 1
                    depth += 1
                    ds = s_hi - s_lo
                    from_block = False
                s = s_lo + 0.5 * ds
                if from_block:
                    h, mu_s, k = probe_at[0, b], probe_at[1, b], probe_at[2, b]
                    j, i = probe_at[3, b], probe_at[4, b]
                    fu = probe_at[5, b]
                else:
                    if terminal and ds < 0:  # the step back takes back what the step before added: at its sample
                        s = hit_lo
                    h, mu_s, k, j, i = _point_geometry(st0 + s * d0, st1 + s * d1, st2 + s * d2, p, coef)
                    fu = math.sqrt(_clip(h / top, 0.0, 1.0))
                samples += 1
                # clear atmosphere (_gas_at): four height profiles times their spectra (ozone's, row GAS_OZONE_ROW,
                # absorbs only), and the sky table
                g0, w = _lerp_index(h / dh, n_gas)
                prof_r = beta_gas[0, _ix(g0)] * (1 - w) + beta_gas[0, _ix(g0 + 1)] * w
                prof_a = beta_gas[1, _ix(g0)] * (1 - w) + beta_gas[1, _ix(g0 + 1)] * w
                prof_s = beta_gas[2, _ix(g0)] * (1 - w) + beta_gas[2, _ix(g0 + 1)] * w
                prof_o = beta_gas[3, _ix(g0)] * (1 - w) + beta_gas[3, _ix(g0 + 1)] * w
                fm = (mu_s + 1.0) * 0.5
                su0, sv0, sa, sb = _bilinear_index(nu_sky, nmu_sky, fu * (nu_sky - 1), fm * (nmu_sky - 1))
                # the terrain looked up only below its highest point (pack_parameters): ~4 % of the march's time
                # (docs/decisions/0003-cpu-kernel-code.md); above it, the gap is unknown (infinite) until it is needed,
                # which is when the next sample meets the ground: then it is looked up at that earlier sample
                gap = _terrain_gap(h, j, i, terrain) if h <= terrain_top else math.inf
                hit_now = alive and gap < 0 and not terminal
                if hit_now and gap_prev == math.inf:
                    gap_prev = _gap_along(s_last, st0, st1, st2, d0, d1, d2, p, coef, terrain)
                frac = _clip(gap_prev / max(gap_prev - gap, 1e-6), 0.0, 1.0) if hit_now else 1.0
                ds_eff = ds if alive and not hit_now else 0.0
                # the corners of the skylight of the ray's aerosol column class, where there are classes (a flag
                # per step rather than n_class itself in the wavelength loop: the kernel was ~4 % faster so)
                classes = False
                cu0 = cv0 = cu1 = cv1 = 0
                ca = cb = ca1 = cb1 = 0.0
                if in_grid:
                    # trilinear sample of the packed volume, its "outside" values beyond it
                    inside, k0, j0, i0 = _lower_corner(k, j, i, nk, ny, nx)
                    if inside:
                        fk = _clip(k - k0, 0.0, 1.0)
                        fj = _clip(j - j0, 0.0, 1.0)
                        fi = _clip(i - i0, 0.0, 1.0)
                        # in float32 with the corners' weights, channel by channel
                        # (docs/decisions/0003-cpu-kernel-code.md; the JAX kernel interpolates in float32 too): LLVM
                        # gathers a channel's eight corners into one vector (a flat view whose channels it loaded 8 at a
                        # time was not faster, docs/decisions/0003-cpu-kernel-code.md)
                        w00 = np.float32((1 - fk) * (1 - fj))
                        w01 = np.float32((1 - fk) * fj)
                        w10 = np.float32(fk * (1 - fj))
                        w11 = np.float32(fk * fj)
                        w_i1 = np.float32(fi)
                        w_i0 = np.float32(1 - fi)
                        ka, ja, ia = _ix(k0), _ix(j0), _ix(i0)
                        kb, jb, ib = _ix(k0 + 1), _ix(j0 + 1), _ix(i0 + 1)
                        # element by element, not through views of the corners' channels (volume[ka, ja, ia]):
                        # each view's reference count is raised and lowered with atomic instructions, on a count
                        # that every thread shares (docs/decisions/0003-cpu-kernel-code.md)
                        for c in range(n_c):
                            vol32[c] = (w_i0 * (w00 * volume[ka, ja, ia, c] + w01 * volume[ka, jb, ia, c]
                                                + w10 * volume[kb, ja, ia, c] + w11 * volume[kb, jb, ia, c])
                                        + w_i1 * (w00 * volume[ka, ja, ib, c] + w01 * volume[ka, jb, ib, c]
                                                  + w10 * volume[kb, ja, ib, c] + w11 * volume[kb, jb, ib, c]))
                        for c in range(n_c):
                            vol[c] = vol32[c]
                    else:
                        for c in range(n_c):
                            vol[c] = 1.0 if c >= n_c - 2 else 0.0
                    beta_a3 = vol[n_species] if aerosol_3d else 0.0
                    tau_a3_sun = vol[n_species + 1] if aerosol_3d else 0.0
                    t_cloud = vol[n_c - 2]
                    shadow = vol[n_c - 1]
                    if n_class > 1:  # diffuse_at
                        classes = True
                        fcu = _clip(fu * (nu_class - 1), 0.0, nu_class - 1.001)
                        cu0, cv0, ca, cb = _bilinear_index(n_rows, nmu_class, c0 * nu_class + fcu, fm * (nmu_class - 1))
                        cu1, cv1, ca1, cb1 = _bilinear_index(n_rows, nmu_class, (c0 + 1) * nu_class + fcu,
                                                             fm * (nmu_class - 1))
                else:
                    beta_a3 = 0.0
                    tau_a3_sun = 0.0
                    t_cloud = 1.0
                    shadow = 1.0
                above_grid = cloud_mode and not in_grid and k > nk - 1 and 0.0 <= j <= ny - 1 and 0.0 <= i <= nx - 1
                beta_h = 0.0
                if in_grid:
                    for c in range(n_species):
                        beta_h += vol[c]
                if budget > 0 and alive:
                    adjacent = have_prev and prev_hi == s_lo
                    change = abs(beta_h - prev_beta) if adjacent else 0.0
                    if (adjacent and prev_depth < max_depth and change * (prev_hi - prev_lo) > tau_refine
                            and pending + 3 <= refine_slots and saved[7] < refine_visible):
                        # the previous interval held a cloud face that its midpoint missed: back to the state
                        # before it, and its two halves, then this interval again
                        # (the padding lane takes the last wavelength's state: its values are never read)
                        tc = (saved[0], saved[1], saved[2], saved[2])
                        to = (saved[3], saved[4], saved[5], saved[5])
                        lc = (saved[8], saved[9], saved[10], saved[10])
                        i_ng = (saved[11], saved[12], saved[13], saved[13])
                        i_g = (saved[14], saved[15], saved[16], saved[16])
                        th, ict, gap_prev, s_last = saved[7], saved[6], saved[17], saved[18]
                        lcl = (saved[19], saved[20], saved[21], saved[21])
                        e_th = math.exp(-th)
                        for c in range(n_species):
                            tsp[c] = saved[22 + c]
                        mid = prev_lo + 0.5 * (prev_hi - prev_lo)
                        stack_lo[pending], stack_hi[pending], stack_depth[pending] = s_lo, s_hi, depth
                        stack_lo[pending + 1], stack_hi[pending + 1] = mid, prev_hi
                        stack_depth[pending + 1] = prev_depth + 1
                        stack_lo[pending + 2], stack_hi[pending + 2] = prev_lo, mid
                        stack_depth[pending + 2] = prev_depth + 1
                        pending += 3
                        budget -= 1
                        have_prev = False
                        continue
                    if (depth < max_depth and th < refine_visible and pending + 2 <= refine_slots
                            and max(beta_h, change) * ds > tau_refine):
                        # too thick a step, or one whose extinction differs too much from the previous one's,
                        # while the observer still sees it: its two halves instead, the first first
                        stack_lo[pending], stack_hi[pending], stack_depth[pending] = s, s_hi, depth + 1
                        stack_lo[pending + 1], stack_hi[pending + 1], stack_depth[pending + 1] = s_lo, s, depth + 1
                        pending += 2
                        budget -= 1
                        continue
                    saved[0], saved[1], saved[2] = tc[0], tc[1], tc[2]
                    saved[3], saved[4], saved[5] = to[0], to[1], to[2]
                    saved[8], saved[9], saved[10] = lc[0], lc[1], lc[2]
                    saved[11], saved[12], saved[13] = i_ng[0], i_ng[1], i_ng[2]
                    saved[14], saved[15], saved[16] = i_g[0], i_g[1], i_g[2]
                    saved[6], saved[7], saved[17], saved[18] = ict, th, gap_prev, s_last
                    saved[19], saved[20], saved[21] = lcl[0], lcl[1], lcl[2]
                    for c in range(n_species):
                        saved[22 + c] = tsp[c]
                    have_prev = True
                    prev_lo, prev_hi, prev_beta, prev_depth = s_lo, s_hi, beta_h, depth
                t0 = th
                t1 = t0 + beta_h * ds_eff
                # Eq. 12's weight e^-t0 - e^-min(t1, 2) is exactly 0 without hydrometeors or beyond tau 2
                # (e^-t0 is carried from the step before, e_th, and restored with the state)
                weight = 0.0
                e_t1 = e_th
                gas_ratio = 0.0
                if t1 > t0 and t0 < 2.0 and not cloud_mode:
                    e_t1 = math.exp(-min(t1, 2.0))
                    weight = max(e_th - e_t1, 0.0)
                    gas_ratio = 1.0 / e_th
                elif t1 < t0 and t1 < 2.0 and not cloud_mode:  # a step back (the terminal step): a negative weight
                    e_t1 = math.exp(-t1)
                    weight = e_th - e_t1
                u0 = 0
                wu = 0.0
                if use_ms:
                    u0, wu = _lerp_index(fu * (n_u - 1), n_u)
                ua, ub = _ix(u0), _ix(u0 + 1)  # the multiple-scattering profiles' two heights
                sun = t_cloud * shadow
                # what each lane (wavelength) adds at this step, lane by lane in one block of arithmetic, the
                # corners' lanes each one contiguous load: LLVM vectorises it across the lanes
                # (docs/decisions/0003-cpu-kernel-code.md)
                su0u, sv0u, su1u, sv1u = _ix(su0), _ix(sv0), _ix(su0 + 1), _ix(sv0 + 1)
                e0, e1, e2, e3 = _corner_lanes(sky_lanes, su0u, sv0u, su1u, sv1u, 0, sa, sb)
                e0, e1, e2, e3 = e0 * sun, e1 * sun, e2 * sun, e3 * sun
                if tau_a3_sun != 0.0:
                    e0 *= math.exp(-tau_a3_sun * ang[0])
                    e1 *= math.exp(-tau_a3_sun * ang[1])
                    e2 *= math.exp(-tau_a3_sun * ang[2])
                    e3 *= math.exp(-tau_a3_sun * ang[3])
                br0, br1, br2, br3 = prof_r * spec_r[0], prof_r * spec_r[1], prof_r * spec_r[2], prof_r * spec_r[3]
                ba0, ba1 = prof_a * spec_a[0] + beta_a3 * ang[0], prof_a * spec_a[1] + beta_a3 * ang[1]
                ba2, ba3 = prof_a * spec_a[2] + beta_a3 * ang[2], prof_a * spec_a[3] + beta_a3 * ang[3]
                bs0, bs1, bs2, bs3 = prof_s * spec_s[0], prof_s * spec_s[1], prof_s * spec_s[2], prof_s * spec_s[3]
                bo0, bo1, bo2, bo3 = prof_o * spec_o[0], prof_o * spec_o[1], prof_o * spec_o[2], prof_o * spec_o[3]
                sa0, sa1, sa2, sa3 = ba0 * ssa_a[0], ba1 * ssa_a[1], ba2 * ssa_a[2], ba3 * ssa_a[3]
                ss0, ss1, ss2, ss3 = bs0 * ssa_s[0], bs1 * ssa_s[1], bs2 * ssa_s[2], bs3 * ssa_s[3]
                # the clear-sky source: single scattering (Eq. 3) and, where use_ms, the diffuse source's profiles
                src0 = (br0 * phase_r + sa0 * phase_a[0] + ss0 * phase_s[0]) * e0
                src1 = (br1 * phase_r + sa1 * phase_a[1] + ss1 * phase_s[1]) * e1
                src2 = (br2 * phase_r + sa2 * phase_a[2] + ss2 * phase_s[2]) * e2
                src3 = (br3 * phase_r + sa3 * phase_a[3] + ss3 * phase_s[3]) * e3
                # cloud_mode: the hydrometeors' single scattering of the direct beam (full phase function, the
                # beam's scaled transmittance in t_cloud) and the diffuse solution's source, and the diffuse
                # solution's ratio for the air's diffuse source (in place of T)
                dr0 = dr1 = dr2 = t_cloud
                cs0 = cs1 = cs2 = 0.0
                beta_eff = beta_h
                if above_grid:  # the clear air over the grid: the light its clouds send up
                    dr0, dr1, dr2 = _ratio_above(h, j, i, ms_above, above_heights, ms_coarsen)
                if cloud_mode and in_grid:
                    dr0, dr1, dr2, cs0, cs1, cs2, beta_eff = _cloud_sources(
                        row, k, j, i, nk, vol, n_species, p_hydro, ray_ms, hydro_scale, hydro_narrow, ms_field,
                        ms_coarsen, beta_h, t_cloud, e0, e1, e2)
                if use_ms:
                    jr0, jr1, jr2, jr3 = _profile_lanes(ms_lanes, ua, ub, 0, wu)
                    ja0, ja1, ja2, ja3 = _profile_lanes(ms_lanes, ua, ub, LANES, wu)
                    js0, js1, js2, js3 = _profile_lanes(ms_lanes, ua, ub, 2 * LANES, wu)
                    src0 += (br0 * jr0 + sa0 * ja0 + ss0 * js0) * dr0
                    src1 += (br1 * jr1 + sa1 * ja1 + ss1 * js1) * dr1
                    src2 += (br2 * jr2 + sa2 * ja2 + ss2 * js2) * dr2
                    src3 += (br3 * jr3 + sa3 * ja3 + ss3 * js3) * dr2
                irr = (e0, e1, e2, e3)
                if weight != 0.0 and in_grid:  # the skylight only where Eq. 12's weight needs it (< 0: a step back)
                    if classes:
                        df0, df1, df2 = (_bilinear_at(diffuse_classes, 0, cu0, cv0, ca, cb) * (1 - wc)
                                       + _bilinear_at(diffuse_classes, 0, cu1, cv1, ca1, cb1) * wc,
                                       _bilinear_at(diffuse_classes, 1, cu0, cv0, ca, cb) * (1 - wc)
                                       + _bilinear_at(diffuse_classes, 1, cu1, cv1, ca1, cb1) * wc,
                                       _bilinear_at(diffuse_classes, 2, cu0, cv0, ca, cb) * (1 - wc)
                                       + _bilinear_at(diffuse_classes, 2, cu1, cv1, ca1, cb1) * wc)
                        df3 = df2
                    else:
                        df0, df1, df2, df3 = _corner_lanes(sky_lanes, su0u, sv0u, su1u, sv1u, LANES, sa, sb)
                    irr = (e0 + 2.0 * df0 * t_cloud, e1 + 2.0 * df1 * t_cloud, e2 + 2.0 * df2 * t_cloud,
                           e3 + 2.0 * df3 * t_cloud)
                if cloud_mode and beta_h > 0.0:
                    lcl = _accumulate_cloud(lcl, to, (cs0, cs1, cs2), (br0 + ba0 + bs0 + bo0, br1 + ba1 + bs1 + bo1,
                                                                       br2 + ba2 + bs2 + bo2), beta_eff, ds_eff)
                # the clear air's extinction: its scattering components' and ozone's absorption
                tc, to, lc, i_ng, i_g = _accumulate_lanes(tc, to, lc, i_ng, i_g,
                                                          (br0 + ba0 + bs0 + bo0, br1 + ba1 + bs1 + bo1,
                                                           br2 + ba2 + bs2 + bo2, br3 + ba3 + bs3 + bo3),
                                                          (src0, src1, src2, src3), irr, beta_eff, ds_eff, weight,
                                                          gas_ratio)
                ict += sun * weight
                th = t1
                e_th = e_t1
                if in_grid:
                    for c in range(n_species):
                        tsp[c] += vol[c] * ds_eff
                if hit_now:
                    hit_s = s - 0.5 * ds + frac * ds
                    hit_lo = s_last
                    hit_hi = s
                    hit_from = s_lo
                    alive = False
                    hit = True
                if terminal and pending == 0:
                    alive = False
                if stop_tau > 0 and th > stop_tau and t0 >= refine_visible and d2 >= 0 and alive and not terminal:
                    # opaque (MarchSettings.stop_tau): the ray stops at stop_tau, its species in the proportions
                    # they had there; past refine_visible before the step, so that no roll-back can undo it
                    for c in range(n_species):
                        tsp[c] *= stop_tau / th
                    th = stop_tau
                    alive = False
                gap_prev = gap
                s_last = s
                if not alive:
                    break
        tau_clear[r, 0], tau_clear[r, 1], tau_clear[r, 2] = tc[0], tc[1], tc[2]
        l_clear[r, 0], l_clear[r, 1], l_clear[r, 2] = lc[0], lc[1], lc[2]
        i_nogas[r, 0], i_nogas[r, 1], i_nogas[r, 2] = i_ng[0], i_ng[1], i_ng[2]
        i_gas[r, 0], i_gas[r, 1], i_gas[r, 2] = i_g[0], i_g[1], i_g[2]
        for c in range(n_species):
            tau_species[r, c] = tsp[c]
        tau_h[r] = th
        i_cloud_t[r] = ict
        if cloud_mode:
            l_cloud[r, 0], l_cloud[r, 1], l_cloud[r, 2] = lcl[0], lcl[1], lcl[2]
        alive_out[r] = alive
        hit_out[r] = hit
        s_hit_out[r] = s_hit
        samples_out[r] = samples



@njit(**JIT_KERNEL, nogil=True)
def prepare_rays(start, direction, bounds, p, coef, aerosol_column, class_aod, ms_source, use_ms, class_lower,
                 class_weight, ms_profile):
    """:func:`swim.rt.march_jax._prepare_rays`, the per-ray set-up before the march, for the rays of :func:`march_rays`:
    each ray's lowest point (:func:`swim.rt.march_jax.lowest_point`), the class of the 3-D aerosol column there
    (:func:`swim.rt.march_jax.aerosol_class_weights`) and the diffuse (multiple-scattering) source's height profiles
    (:func:`swim.rt.march_jax.diffuse_source_profiles`).

    Inputs: rebased ``start`` (n, 3) [m], unit ``direction`` (n, 3), ``bounds`` (n, 3) [m] of
    :func:`swim.rt.march.ray_segments`; ``p``, ``coef`` of :func:`pack_parameters`; the column optical depth field
    ``aerosol_column`` (1, ny, nx) and its classes ``class_aod`` (n_class,); the source table ``ms_source``
    (n_class, n_s, n_v, n_phi, n_u * 9) (:mod:`swim.rt.multiple_scattering`, its last two axes flattened). Written:
    ``class_lower`` (n,) int32 and ``class_weight`` (n,) [-], and where ``use_ms`` ``ms_profile`` (9, n, n_u) [-].

    The same arithmetic as the JAX functions: the geometry and weights in float64, the corners' sum in float32 as
    there. The aerosol classes are the project's form of Eqs. 30-31 (Albers et al. 2020,
    doi:10.5194/amt-13-3235-2020; docs/aerosols.md, section 8). In a render 0.5-0.6 us a ray (the table's rows read
    from the caches): 0.32-0.41 ms for a chunk of 657 rays, where the JAX call, with its dispatch and its wait on
    XLA's threads beside the other chunk's march, took 1.1-2 ms (docs/decisions/0009-work-around-the-march.md)."""
    radius = p[_P_RADIUS]
    sun0, sun1, sun2 = p[_P_SUN], p[_P_SUN + 1], p[_P_SUN + 2]
    n_class = class_aod.shape[0]
    n_s, n_v, n_phi, n_row = ms_source.shape[1], ms_source.shape[2], ms_source.shape[3], ms_source.shape[4]
    n_u = ms_profile.shape[2]
    acc = np.empty(n_row, np.float32)  # in float32 as the JAX function: twice the lanes of a vector
    for r in range(start.shape[0]):
        st0, st1, st2 = start[r, 0], start[r, 1], start[r, 2]
        d0, d1, d2 = direction[r, 0], direction[r, 1], direction[r, 2]
        s_low = _lowest_along(st0, st1, st2, d0, d1, d2, radius, bounds[r, 2])  # lowest_point
        q0, q1, q2 = st0 + s_low * d0, st1 + s_low * d1, st2 + s_low * d2
        c0 = 0
        wc = 0.0
        if n_class > 1:  # aerosol_class_weights: the column optical depth there, linear between the classes
            _, _, _, j, i = _point_geometry(q0, q1, q2, p, coef)
            column = _bilinear_clamped(aerosol_column, j, i)
            f = 0.0  # jnp.interp on the class index: clamped to the first and last class
            if column >= class_aod[n_class - 1]:
                f = n_class - 1.0
            elif column > class_aod[0]:
                for c in range(n_class - 1):
                    if column <= class_aod[c + 1]:
                        f = c + (column - class_aod[c]) / (class_aod[c + 1] - class_aod[c])
                        break
            f = _clip(f, 0.0, n_class - 1.001)
            c0 = int(math.floor(f))
            wc = f - c0
        class_lower[r] = c0
        class_weight[r] = wc
        if not use_ms:
            continue
        # diffuse_source_profiles: the table at the local sun and view cosines and relative azimuth there
        qz = q2 + radius
        norm = math.sqrt(q0 * q0 + q1 * q1 + qz * qz)
        up0, up1, up2 = q0 / norm, q1 / norm, qz / norm
        mu_v = up0 * d0 + up1 * d1 + up2 * d2
        mu_s = up0 * sun0 + up1 * sun1 + up2 * sun2
        cos_phi = ((d0 * sun0 + d1 * sun1 + d2 * sun2 - mu_v * mu_s)
                   / math.sqrt(max((1 - mu_v * mu_v) * (1 - mu_s * mu_s), 1e-12)))
        t_s = math.copysign(math.sqrt(min(abs(mu_s), 1.0)), mu_s)  # the table's sun axis, down to the night
        fs = _clip((t_s - DIFFUSE_SUN_T_MIN) / (1.0 - DIFFUSE_SUN_T_MIN) * (n_s - 1), 0.0, n_s - 1.001)
        fv = _clip((mu_v + 1.0) * 0.5 * (n_v - 1), 0.0, n_v - 1.001)
        fp = _clip(math.acos(_clip(cos_phi, -1.0, 1.0)) / math.pi * (n_phi - 1), 0.0, n_phi - 1.001)
        s0, v0, p0 = int(math.floor(fs)), int(math.floor(fv)), int(math.floor(fp))
        ws, wv, wp = fs - s0, fv - v0, fp - p0
        for dc in range(2 if n_class > 1 else 1):
            w_c = (1 - wc if dc == 0 else wc) if n_class > 1 else 1.0
            # the eight corners of the class in one pass over their (n_u, 9) profiles, each contiguous: vectorised,
            # eight streams read once and the sum written once
            a0 = ms_source[c0 + dc, s0, v0, p0]
            a1 = ms_source[c0 + dc, s0, v0, p0 + 1]
            a2 = ms_source[c0 + dc, s0, v0 + 1, p0]
            a3 = ms_source[c0 + dc, s0, v0 + 1, p0 + 1]
            b0 = ms_source[c0 + dc, s0 + 1, v0, p0]
            b1 = ms_source[c0 + dc, s0 + 1, v0, p0 + 1]
            b2 = ms_source[c0 + dc, s0 + 1, v0 + 1, p0]
            b3 = ms_source[c0 + dc, s0 + 1, v0 + 1, p0 + 1]
            wa, wb = w_c * (1 - ws), w_c * ws
            w00, w01, w10, w11 = (1 - wv) * (1 - wp), (1 - wv) * wp, wv * (1 - wp), wv * wp
            wa0, wa1, wa2, wa3 = (np.float32(wa * w00), np.float32(wa * w01), np.float32(wa * w10),
                                  np.float32(wa * w11))
            wb0, wb1, wb2, wb3 = (np.float32(wb * w00), np.float32(wb * w01), np.float32(wb * w10),
                                  np.float32(wb * w11))
            if dc == 0:
                for x in range(n_row):
                    acc[x] = (a0[x] * wa0 + a1[x] * wa1 + a2[x] * wa2 + a3[x] * wa3
                              + b0[x] * wb0 + b1[x] * wb1 + b2[x] * wb2 + b3[x] * wb3)
            else:
                for x in range(n_row):
                    acc[x] += (a0[x] * wa0 + a1[x] * wa1 + a2[x] * wa2 + a3[x] * wa3
                               + b0[x] * wb0 + b1[x] * wb1 + b2[x] * wb2 + b3[x] * wb3)
        for c in range(9):
            for u in range(n_u):
                ms_profile[c, r, u] = acc[u * 9 + c]


def work_sizes(n_before, n_grid, n_after, n_probe, n_probe_max, n_clear_probe, refine_slots, n_species, n_channels,
               n_u):
    """Sizes of one ray's work arrays (:func:`work_arrays`): step edges (one more after the grid, for the zero-length step at
    the end of a ray that ends on the sea-level sphere), probe densities, refinement slots, the saved state, species
    and volume channels, and the heights of the multiple-scattering profiles (``n_u``: ``ms_profile.shape[2]``).
    ``n_species``: the packed species (:func:`swim.rt.march_inputs.packed_species`), none in a cloudless scene, whose species
    array keeps one element."""
    return (max(n_before, n_grid, n_after + 1) + 1, max(n_probe, n_probe_max, n_clear_probe) + 1, refine_slots,
            22 + n_species, max(n_species, 1), n_channels, n_u)


#: Bytes of a CPU cache line (:func:`work_arrays`).
CACHE_LINE = 64


def work_arrays(n_edges, n_cdf, n_slots, n_saved, n_species, n_channels, n_u):
    """The work arrays of :func:`_march_ray_range` for the sizes of :func:`work_sizes`, which every ray of a call
    uses in turn: step edges, the probes' cumulative density, the pending halves of refined steps (lower and upper
    ends, depth), the state before the last accumulated grid interval (restored when the next one shows that a cloud
    face lay inside it: tau_clear 0-2, t_obs 3-5, i_cloud_t 6, tau_h 7, l_clear 8-10, i_nogas 11-13, i_gas 14-16,
    gap 17, s_last 18, l_cloud 19-21, the species' optical depths 22-), the species' optical depths along the ray, the ray's
    multiple-scattering profiles as rows of lanes (zeros: their padding lanes stay 0), a volume sample in float64 and
    float32, and the geometry of a block of occupancy probes or steps (:func:`_probe_indices`,
    :func:`_step_geometry`).

    They are views of one zeroed buffer, each starting on a cache line of its own, with a spare line before and after
    the buffer. Allocated one by one with numpy, the 1024² render of the synthetic scene (two threads, each marching
    its chunks with its own work arrays) took 3.03-3.05 s instead of 2.82-2.87 s
    (docs/decisions/0003-cpu-kernel-code.md)."""
    specs = (((n_edges,), np.float64), ((n_cdf,), np.float64), ((n_slots,), np.float64), ((n_slots,), np.float64),
             ((n_slots,), np.int64), ((n_saved,), np.float64), ((n_species,), np.float64),
             ((n_u, 3 * LANES), np.float64), ((n_channels,), np.float64), ((n_channels,), np.float32),
             ((6, PROBE_BLOCK), np.float64))
    nbytes = [math.prod(shape) * np.dtype(dtype).itemsize for shape, dtype in specs]
    spans = [-(-n // CACHE_LINE) * CACHE_LINE for n in nbytes]
    buffer = np.zeros(sum(spans) + 3 * CACHE_LINE, np.uint8)
    offset = CACHE_LINE + (-buffer.ctypes.data) % CACHE_LINE
    arrays = []
    for (shape, dtype), n, span in zip(specs, nbytes, spans):
        arrays.append(buffer[offset:offset + n].view(dtype).reshape(shape))
        offset += span
    return tuple(arrays)


def march_rays(start, direction, bounds, valid, p_rayleigh, p_aerosol, p_stratospheric, class_lower, class_weight,
               ms_profile, use_ms, n_before, n_grid, n_after, p, coef, beta_gas, spectra, sky_lanes, diffuse_classes,
               n_class, volume, terrain, occupancy, angstrom, aerosol_ssa, stratospheric_ssa, n_probe, empty_weight,
               probe_spacing, n_probe_max, cell_slack, empty_steps, empty_cells_per_step, sunlit_steps,
               sunlit_cells_per_step, n_clear_probe, clear_power,
               clear_floor, tau_refine, max_depth, refine_budget, refine_visible, refine_slots, n_bisections, stop_tau,
               tau_clear, tau_h, tau_species, l_clear, i_nogas, i_gas, i_cloud_t, alive_out, hit_out, s_hit_out,
               samples_out, cloud_mode, p_hydro, ray_ms, hydro_scale, hydro_narrow, ms_field, ms_coarsen, ms_above,
               above_heights, l_cloud):
    """March rays through the three segments of :func:`swim.rt.march.ray_segments`, one after the other.

    The compiled loop over the rays, :func:`_march_ray_range`, runs without the GIL, so that
    :func:`swim.rt.march.trace_rays` runs chunks of rays on all cores from a thread pool (a ``parallel=True`` loop
    was as fast and took 29 s to compile instead of 7); this function allocates its work arrays
    (:func:`work_arrays`) and calls it.

    The loop of :func:`swim.rt.march_jax._march_segment` over the clear air before the grid (``n_before`` steps placed
    by :func:`_clear_edges` from ``n_clear_probe`` extinction probes, with density extinction^``clear_power`` plus
    ``clear_floor`` times its largest value), the grid (``n_grid`` steps placed by :func:`_adaptive_edges` from
    ``n_probe`` occupancy probes, or one per ``probe_spacing`` cells up to ``n_probe_max`` for rays that cross more,
    less ``cell_slack``; at most max(``empty_steps``, empty cells / ``empty_cells_per_step``) of them in its empty
    intervals, ``empty_steps`` 0: no limit; and at most max(``sunlit_steps``, sunlit cells / ``sunlit_cells_per_step``)
    in its sunlit clear ones, where ``occupancy`` holds the step classes of :func:`swim.rt.march_inputs.step_classes`,
    ``sunlit_steps`` 0: they count as empty; :func:`swim.rt.march_jax.grid_step_edges`) and the clear air after it
    (``n_after`` steps placed as ``n_before``'s), then :func:`swim.rt.march_jax.refine_terrain_hit` and, for a ray that met
    the ground,
    the terminal steps of :func:`swim.rt.march_jax._terminal_step` up to that crossing. While the ray's hydrometeor optical
    depth is below ``refine_visible``, a grid step whose own (or whose change of extinction from the interval before
    it, times its length) exceeds ``tau_refine`` is replaced by its two halves, and a step whose change times the
    previous interval's length exceeds it sends the ray back to its state before that interval, which is halved,
    and an interval whose length times the extinction of the accumulated interval before it exceeds it is halved
    before its sample (:func:`_predicted_halving`); recursively to ``max_depth`` levels, at most ``refine_budget``
    times per ray, with at most ``refine_slots`` pending intervals (:func:`swim.rt.march_jax._march_grid_refined`). A ray
    that does not look down (``direction``'s vertical component >= 0) stops where its hydrometeor optical depth
    passes ``stop_tau`` > 0, once it was past ``refine_visible`` before the step: its optical depth is then
    ``stop_tau`` and its species' keep their proportions (:attr:`swim.rt.march_settings.MarchSettings.stop_tau`). A ray stops
    at the ground (the lockstep kernel goes on with zero-length steps that add nothing), and a segment of zero length
    takes one step (to see whether it starts under the terrain) instead of all of them.

    Inputs per ray (n = rays): rebased ``start`` (n, 3) [m], unit ``direction`` (n, 3), ``bounds`` (n, 3)
    [m], ``valid`` (n,) bool, the phase functions ``p_rayleigh`` (n,), ``p_aerosol`` and ``p_stratospheric``
    (n, 3), the aerosol class ``class_lower`` (n,) int and ``class_weight`` (n,), and ``ms_profile`` (9, n, n_u)
    [-] (used where ``use_ms``). Tables as in :func:`swim.rt.march_inputs.kernel_constants` (float32), but for the sky
    table, which the step loop reads as :func:`sky_lanes` (nu, nmu, 8) float64; scalars packed by
    :func:`pack_parameters`. The results are written into the preallocated outputs: the optical depths
    ``tau_clear`` (n, 3), ``tau_h`` (n,), ``tau_species`` (n, p) of the volume's p packed species
    (:func:`swim.rt.march_inputs.packed_species`), the clear-sky radiance ``l_clear`` (n, 3),
    the Eq. 12 integrals ``i_nogas``, ``i_gas`` (n, 3) and ``i_cloud_t`` (n,), ``alive_out`` and ``hit_out``
    (n,) bool, ``s_hit_out`` (n,) [m], the refined terrain crossing or the segment's end, and ``samples_out``
    (n,) int, the medium's samples the ray took (its steps, refined halves and steps undone by a refinement
    included; none after the ground; the terrain bisection's lookups not counted).
    """
    work = work_arrays(*work_sizes(n_before, n_grid, n_after, n_probe, n_probe_max, n_clear_probe, refine_slots,
                                   tau_species.shape[1], volume.shape[3], ms_profile.shape[2]))
    _march_ray_range(0, start.shape[0], 1, start, direction, bounds, valid, p_rayleigh, p_aerosol, p_stratospheric,
                     class_lower, class_weight, ms_profile, use_ms, n_before, n_grid, n_after, p, coef, beta_gas,
                     spectra, sky_lanes, diffuse_classes, n_class, volume, terrain, occupancy, angstrom, aerosol_ssa,
                     stratospheric_ssa, n_probe, empty_weight, probe_spacing, n_probe_max, cell_slack, empty_steps,
                     empty_cells_per_step, sunlit_steps, sunlit_cells_per_step, n_clear_probe, clear_power,
                     clear_floor, tau_refine, max_depth,
                     refine_budget, refine_visible, refine_slots, n_bisections, stop_tau, tau_clear, tau_h, tau_species,
                     l_clear, i_nogas, i_gas, i_cloud_t, alive_out, hit_out, s_hit_out, samples_out, cloud_mode,
                     p_hydro, ray_ms, hydro_scale, hydro_narrow, ms_field, ms_coarsen, ms_above, above_heights,
                     l_cloud, *work)
