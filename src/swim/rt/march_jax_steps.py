"""The JAX kernel's step placement: where each ray's midpoint steps lie in the grid and in the clear air around it.

Every ray of a chunk takes the same number of steps (lockstep), placed from the geometry and the scene alone before
the march: through the grid dense where the occupancy probes find something and few where they find nothing
(:func:`grid_step_edges`, docs/decisions/0004-step-placement.md), through the clear air before and after the grid
dense where the air is (:func:`clear_step_edges`, :func:`after_step_counts`). :mod:`swim.rt.march_jax` marches them
and imports these functions back; the numba kernel places the same steps per ray (:mod:`swim.rt.march_cpu`).

The lookups of the scene's tables (:func:`swim.rt.march_jax._point_geometry`, ``_gas_at``, ``_lerp_table``) stay in
:mod:`swim.rt.march_jax` with the optimisation barriers they share (``_materialise``), and are imported where they are
called: that module imports this one.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ..constants import AFTER_MIN_STEPS, CELL_PROBES, GAS_COLUMN_ROW
from .march_settings import (CELL_SLACK, CLEAR_PROBES, CLEAR_STEP_FLOOR, CLEAR_STEP_POWER, EMPTY_CELLS_PER_STEP,
                             EMPTY_STEP_WEIGHT, MAX_PROBES, MarchSettings, N_OCCUPANCY_PROBES, SUNLIT_CELLS_PER_STEP)


def _probe_indices(start, direction, s0, length, consts, n_probe, count=None):
    """Grid indices (k, j, i), each (n_probe, n), of the probes at the middles of equal intervals of each ray's
    grid segment: ``n_probe`` of them, or the first ``count`` (n,) <= n_probe of each ray's own count (the others
    then repeat the last)."""
    from .march_jax import _point_geometry

    m = jnp.arange(n_probe, dtype=jnp.float32)[:, None]
    count = jnp.float32(n_probe) if count is None else count.astype(jnp.float32)[None, :]
    f = (jnp.minimum(m, count - 1) + 0.5) / count
    s = s0[None, :] + f * length[None, :]
    q = (start[None] + s[..., None] * direction[None]).reshape(-1, 3)
    _, _, k, j, i = _point_geometry(q, consts)
    return tuple(x.reshape(n_probe, -1) for x in (k, j, i))


def probe_counts(start, direction, s0, length, consts, n_probe=N_OCCUPANCY_PROBES,
                 probe_spacing=MarchSettings.probe_spacing):
    """Occupancy probes per ray (n,) int32 for :func:`adaptive_step_edges`: ``n_probe``, or for a ray whose grid
    segment crosses more than ``n_probe * probe_spacing`` cells one per ``probe_spacing`` cells, at most
    :data:`MAX_PROBES`.

    A segment's length in cells is the Chebyshev length of its path in grid indices (:func:`segment_cells`): the
    number of cells the ray passes along its dominant axis. ``probe_spacing`` 0 gives ``n_probe`` for every ray.
    """
    if not probe_spacing:
        return jnp.full(start.shape[:1], n_probe, jnp.int32)
    return probe_counts_and_cells(start, direction, s0, length, consts, n_probe, probe_spacing)[0]


def probe_counts_and_cells(start, direction, s0, length, consts, n_probe=N_OCCUPANCY_PROBES,
                           probe_spacing=MarchSettings.probe_spacing):
    """:func:`probe_counts` (n,) int32 and the grid segments' lengths in cells (n,) [-] that they come from
    (:func:`segment_cells`; ``probe_spacing`` 0 gives ``n_probe`` probes for every ray)."""
    cells = segment_cells(start, direction, s0, length, consts)
    if not probe_spacing:
        return jnp.full(start.shape[:1], n_probe, jnp.int32), cells
    # CELL_SLACK: a ray along a grid axis crosses a whole number of cells, which must not round up in float32
    # here and not in float64 in the numba kernel (or the other way round)
    need = jnp.ceil(cells / probe_spacing - CELL_SLACK)
    return jnp.clip(need, n_probe, max(MAX_PROBES, n_probe)).astype(jnp.int32), cells


def segment_cells(start, direction, s0, length, consts):
    """Length in cells (n,) [-] of each ray's grid segment [s0, s0 + length] [m]: the Chebyshev length of its path
    in grid indices, measured at :data:`CELL_PROBES` points (the middles of equal intervals; the largest index change
    between neighbouring points, summed and extended by the half intervals at the ends), the cells the ray passes
    along its dominant axis.

    Measured apart from the occupancy probes, at fewer points: the march probed every ray's occupancy at ``n_probe``
    points for its length alone before probing it again at the count that length asks for (every ray of a 1024^2
    all-sky of the 400 x 400 x 60 scene, whose 160 levels make even the zenith's ray cross more than ``n_probe``
    times ``probe_spacing`` cells): 64 of a ray's ~147 probes there (docs/decisions/0003-cpu-kernel-code.md)."""
    k, j, i = _probe_indices(start, direction, s0, length, consts, CELL_PROBES)
    return _segment_cells(k, j, i, CELL_PROBES)


def _segment_cells(k, j, i, n_probe):
    """Length in cells (n,) of each ray's grid segment from the grid indices (n_probe, n) of its equally spaced
    probes: the largest index change between neighbouring probes, summed and extended by the half intervals at
    the segment's ends."""
    step = jnp.maximum(jnp.maximum(jnp.abs(jnp.diff(k, axis=0)), jnp.abs(jnp.diff(j, axis=0))),
                       jnp.abs(jnp.diff(i, axis=0)))
    return jnp.sum(step, axis=0) * (n_probe / max(n_probe - 1, 1))


def adaptive_step_edges(start, direction, s0, length, n_steps, consts, n_probe=N_OCCUPANCY_PROBES,
                        empty_weight=EMPTY_STEP_WEIGHT, probes=None):
    """Edges (n_steps + 1, n) [m] of n_steps steps through the grid, concentrated where something happens
    (:func:`grid_step_edges` without a limit on the steps in empty space: every ray takes n_steps).

    Empty-space skipping for rays marched in lockstep: each ray probes the (dilated) occupancy grid of
    :func:`occupancy_grid` (hydrometeors, the terrain, gradients of the 3-D aerosol) at ``n_probe`` equal
    intervals of its grid segment (or at its own count ``probes`` (n,) <= n_probe, from :func:`probe_counts`)
    and spreads its steps with density 1 in occupied and ``empty_weight`` in empty intervals (inverse of the
    piecewise-linear cumulative density). Every ray takes the same number of steps, so no ray waits for
    another, and clear air still gets steps (a cloud missed by the probes is sampled as by a uniform march of
    n_steps empty_weight / (occupied + empty_weight (n_probe - occupied)) steps per interval).
    """
    return grid_step_edges(start, direction, s0, length, n_steps, consts, n_probe, empty_weight, probes)[0]


def grid_step_edges(start, direction, s0, length, n_steps, consts, n_probe=N_OCCUPANCY_PROBES,
                    empty_weight=EMPTY_STEP_WEIGHT, probes=None, cells=None, empty_steps=0, sunlit_steps=0):
    """Edges (n_steps + 1, n) [m] and counts (n,) int32 of each ray's steps through the grid: dense where something
    happens, few where nothing does.

    The steps of :func:`adaptive_step_edges` (density 1 in occupied and ``empty_weight`` in empty probe intervals),
    with the steps in empty space limited (empty-space skipping; docs/decisions/0004-step-placement.md): where the
    empty intervals would get more than ``max(empty_steps, empty cells / EMPTY_CELLS_PER_STEP)`` steps (the empty
    cells are the segment's ``cells`` (n,) times its share of empty probes), they get that many, and the ray
    takes fewer steps in all, ``ceil(occupied steps + that)``, so that its occupied intervals keep their step
    density. A ray through clear air alone takes ``empty_steps`` equal steps instead of n_steps. A ray's edges
    beyond its count repeat the segment's end; its march stops there. ``empty_steps`` 0: every ray takes
    n_steps, as in :func:`adaptive_step_edges`.

    Where ``consts["occupancy"]`` holds the step classes of :func:`step_classes` and ``sunlit_steps`` > 0, the
    sunlit clear intervals (code :data:`SUNLIT_CLEAR`) are limited in the same way on their own, to
    ``max(sunlit_steps, sunlit cells / SUNLIT_CELLS_PER_STEP)`` steps, and the weight left to the unoccupied
    intervals is shared in proportion to the two kinds' limited steps (docs/decisions/0004-step-placement.md); with
    ``sunlit_steps`` 0 they count as empty.

    ``probes`` (n,): each ray's probe count (:func:`probe_counts`, at most ``n_probe``), or None for ``n_probe``
    each; ``cells``: the segments' lengths in cells of :func:`segment_cells` (needed with ``probes`` and
    ``empty_steps``; without ``probes`` they are measured here).
    """
    n = start.shape[0]
    count = jnp.full((n,), n_probe, jnp.int32) if probes is None else jnp.minimum(probes.astype(jnp.int32), n_probe)
    k, j, i = _probe_indices(start, direction, s0, length, consts, n_probe, None if probes is None else count)
    occupancy = jnp.asarray(consts["occupancy"])
    nk, ny, nx = occupancy.shape
    kk, jj, ii = (jnp.clip(jnp.round(x), 0, size - 1).astype(jnp.int32) for x, size in ((k, nk), (j, ny), (i, nx)))
    kind = occupancy.reshape(-1)[(kk * ny + jj) * nx + ii].reshape(n_probe, n)
    occupied = kind > 0
    own = jnp.arange(n_probe)[:, None] < count[None, :]  # a ray's own probes only
    sunlit = (kind < 0) & own if sunlit_steps else jnp.zeros_like(own)
    steps = jnp.full((n,), n_steps, jnp.int32)
    weight_empty = weight_sunlit = jnp.float32(empty_weight)
    if empty_steps:
        if cells is None:
            if probes is not None:
                raise ValueError("grid_step_edges: cells are needed with probes (probe_counts_and_cells)")
            cells = segment_cells(start, direction, s0, length, consts)
        n_occupied = jnp.sum(occupied & own, axis=0).astype(jnp.float32)
        n_sunlit = jnp.sum(sunlit, axis=0).astype(jnp.float32)
        n_empty = count.astype(jnp.float32) - n_occupied - n_sunlit
        total = n_occupied + empty_weight * (n_empty + n_sunlit)
        # CELL_SLACK: a ray along a grid axis crosses a whole number of cells, which must not round the step count
        # up in float32 here and not in float64 in the numba kernel (as in probe_counts_and_cells)
        steps_empty = n_steps * empty_weight * n_empty / total
        budget = jnp.maximum(jnp.float32(empty_steps),
                             cells * n_empty / (count.astype(jnp.float32) * EMPTY_CELLS_PER_STEP) - CELL_SLACK)
        capped = (n_empty > 0) & (steps_empty > budget)
        steps_empty = jnp.where(capped, budget, steps_empty)
        steps_sunlit = n_steps * empty_weight * n_sunlit / total
        if sunlit_steps:
            budget = jnp.maximum(jnp.float32(sunlit_steps),
                                 cells * n_sunlit / (count.astype(jnp.float32) * SUNLIT_CELLS_PER_STEP) - CELL_SLACK)
            capped_sunlit = (n_sunlit > 0) & (steps_sunlit > budget)
            steps_sunlit = jnp.where(capped_sunlit, budget, steps_sunlit)
            capped = capped | capped_sunlit
        fewer = jnp.minimum(jnp.ceil(n_steps * n_occupied / total + steps_empty + steps_sunlit), n_steps)
        # the weight left to the unoccupied intervals at the occupied ones' steps per unit weight, n_steps / total,
        # shared in proportion to their capped steps
        rest = fewer * total / n_steps - n_occupied
        share = steps_empty / jnp.maximum(steps_empty + steps_sunlit, jnp.float32(1e-30))
        weight_empty = jnp.where(capped, rest / jnp.maximum(n_empty, 1.0) * share, weight_empty)[None, :]
        weight_sunlit = jnp.where(capped, rest / jnp.maximum(n_sunlit, 1.0) * (1.0 - share), weight_sunlit)[None, :]
        steps = jnp.where(capped, fewer, n_steps).astype(jnp.int32)
    weight = jnp.where(own, jnp.where(occupied, 1.0, jnp.where(sunlit, weight_sunlit, weight_empty)), 0.0)
    return _edges_from_density(weight, count, s0, length, n_steps, steps), steps


def _edges_from_density(weight, count, s0, length, n_steps, steps=None):
    """Edges (n_steps + 1, n) [m] that cut the piecewise-constant step density ``weight`` (n_probe, n) over each
    ray's ``count`` (n,) equal probe intervals of [s0, s0 + length] into n_steps equal parts (the inverse of the
    piecewise-linear cumulative density), or into ``steps`` (n,) <= n_steps parts each (the edges beyond them
    repeating the end)."""
    n = weight.shape[1]
    cdf = jnp.concatenate([jnp.zeros((1, n), jnp.float32), jnp.cumsum(weight, axis=0)], axis=0)
    cdf = cdf / cdf[-1:]
    m = jnp.arange(n_steps + 1, dtype=jnp.float32)
    if steps is None:
        targets = jnp.broadcast_to((m / n_steps)[:, None], (n_steps + 1, n))
    else:
        parts = steps.astype(jnp.float32)[None, :]
        targets = jnp.minimum(m[:, None], parts) / parts
    idx = jnp.clip(jax.vmap(lambda c, t: jnp.searchsorted(c, t, side="right") - 1, in_axes=1, out_axes=1)(cdf, targets),
                   0, count[None, :] - 1)
    c0 = jnp.take_along_axis(cdf, idx, axis=0)
    c1 = jnp.take_along_axis(cdf, idx + 1, axis=0)
    frac = jnp.clip((idx + (targets - c0) / jnp.maximum(c1 - c0, 1e-12)) / count[None, :].astype(jnp.float32),
                    0.0, 1.0)
    return s0[None, :] + frac * length[None, :]


def clear_step_edges(start, direction, s0, length, n_steps, consts, n_probe=CLEAR_PROBES, steps=None):
    """Edges (n_steps + 1, n) [m] of n_steps steps through the clear air before or after the grid, dense where
    the air is.

    The steps integrate the clear-sky source of Step 2 (single scattering and the diffuse source, Albers et al.
    2020, Eq. 3, doi:10.5194/amt-13-3235-2020) by the midpoint rule, whose error over a step of length ds is
    ~ f'' ds^3 / 24; for an integrand that falls exponentially with height (f'' ~ f / H^2) the error is spread
    evenly by a step density ~ f^(1/3) (the placement is ours, not the paper's: it marches Step 2 separately,
    Sect. 3.3). Each ray probes the extinction at 546 nm (Rayleigh, background and stratospheric aerosol: the
    clear-sky source's coefficients; not ozone's absorption, which scatters nothing: with it the steps crowd into
    the ozone layer, and the views from space of ``tests/validation/test_clear_sky_disort.py`` were 0.1-0.2 % further
    from DISORT) at ``n_probe`` equal intervals and spreads its steps with density extinction^(1/3) plus
    :data:`CLEAR_STEP_FLOOR` times its largest value (so that the thin air far up still gets steps). Against a
    march of 384 + 256 equal steps, the default 24 steps after and 12 before the grid so placed are as accurate
    as the 48 and 32 equal steps they replace, or more (median error of ground views 0.013 % against 0.022 %, of
    a view from 800 km 0.25 % against 0.26 %; docs/decisions/0004-step-placement.md). A ray that rises out of
    the grid takes fewer steps after it where little of its air lies there (:func:`after_step_counts`,
    docs/decisions/0004-step-placement.md).

    Inputs per ray (n = rays): rebased ``start`` (n, 3) [m], unit ``direction`` (n, 3), the segment's start ``s0``
    and ``length`` (n,) [m]; ``steps`` (n,) <= n_steps: each ray's own step count (:func:`after_step_counts`), the
    edges beyond it repeating the segment's end (None: n_steps each).
    """
    from .march_jax import _gas_at, _point_geometry

    n = start.shape[0]
    f = (jnp.arange(n_probe, dtype=jnp.float32)[:, None] + 0.5) / n_probe
    s = s0[None, :] + f * length[None, :]
    q = (start[None] + s[..., None] * direction[None]).reshape(-1, 3)
    h, mu_s, *_ = _point_geometry(q, consts)
    beta_r, beta_a, beta_s, _, _, _ = _gas_at(h, mu_s, consts)  # (ozone and the sky lookup unused: XLA drops them)
    beta = beta_r[:, 1] + beta_a[:, 1] + beta_s[:, 1]
    density = jnp.maximum(beta, 0.0).reshape(n_probe, n) ** CLEAR_STEP_POWER
    density = density + CLEAR_STEP_FLOOR * jnp.max(density, axis=0, keepdims=True) + 1e-30
    return _edges_from_density(density, jnp.full((n,), n_probe, jnp.int32), s0, length, n_steps, steps)


def after_step_counts(start, direction, bounds, n_after, consts):
    """Clear-air steps (n,) of each ray's segment after the grid: ``n_after`` times the square root of the fraction
    q of the vertical optical depth above the ray's lowest point (up to its grid exit) that lies above its exit, at
    least :data:`swim.constants.AFTER_MIN_STEPS`; ``n_after`` for a ray that descends where it leaves the grid (its
    segment may end on the ground beyond the domain).

    Why: the midpoint rule's error over a segment placed by :func:`clear_step_edges` falls as 1 / n² of the segment's
    own clear-sky radiance, roughly q times the ray's (the air above a 20 km grid top holds ~4 % of the vertical optical
    depth at 546 nm, above a 2 km LES top ~60 %). With n ∝ √q the error relative to the ray's
    clear sky is the same for every ray: that of ``n_after`` steps through the whole column
    (docs/decisions/0004-step-placement.md; our choice, not the paper's, which marches Step 2 separately).

    Inputs per ray (n = rays): rebased ``start`` (n, 3) [m], unit ``direction`` (n, 3) and ``bounds`` (n, 3) [m] of
    :func:`ray_segments`; ``consts`` with the column row :data:`swim.constants.GAS_COLUMN_ROW` of ``beta_gas``
    (:func:`gas_column_above`). :func:`swim.rt.march_cpu._after_steps` is the same per ray.
    """
    from .march_jax import _lerp_table, _point_geometry, lowest_point

    radius = consts["radius"]
    s_exit = bounds[:, 1]
    exit_point = start + s_exit[:, None] * direction
    rising = (exit_point[:, 0] * direction[:, 0] + exit_point[:, 1] * direction[:, 1]
              + (exit_point[:, 2] + radius) * direction[:, 2]) >= 0
    low_point = lowest_point(start, direction, bounds, consts, end=s_exit)  # the height is convex along a ray
    column = consts["beta_gas"][GAS_COLUMN_ROW:GAS_COLUMN_ROW + 1]
    above_exit = _lerp_table(column, _point_geometry(exit_point, consts)[0] / consts["dh"])[:, 0]
    above_low = _lerp_table(column, _point_geometry(low_point, consts)[0] / consts["dh"])[:, 0]
    q = jnp.clip(above_exit / jnp.maximum(above_low, 1e-30), 0.0, 1.0)
    steps = jnp.clip(jnp.ceil(n_after * jnp.sqrt(q)), min(AFTER_MIN_STEPS, n_after), n_after).astype(jnp.int32)
    return jnp.where(rising, steps, n_after)
