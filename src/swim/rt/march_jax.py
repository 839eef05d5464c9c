"""The march's JAX kernel: chunks of rays marched in lockstep, jit-compiled once per batch size (GPUs; gradients).

The same steps, sources and composition as the numba kernel (:mod:`swim.rt.march_cpu`, the CPU's default), written
with ``jax.numpy``: the step placement (:func:`grid_step_edges`, :func:`clear_step_edges`), the segment march
(:func:`_march_segment`, :func:`_march_grid_refined`), the clouds' and the ground's composition (:func:`_compose`)
and the chunk's stages (:func:`_trace_chunk`). :func:`swim.rt.march.trace_rays` calls it for
``MarchSettings(backend="jax")``; only then is JAX imported.
"""

from __future__ import annotations

import functools
import logging
from dataclasses import replace

import jax
import jax.numpy as jnp
import numpy as np

from ..constants import AFTER_MIN_STEPS, CELL_PROBES, GAS_COLUMN_ROW
from ..optics.volume import grid_indices
from ..optics.phase import (
    anisotropic_reflectance_factor_kokhanovsky2004,
    blend_coefficient,
    delta_scaled_path_factor,
    diffuse_transmission_factor,
    effective_phase_function,
    forward_peak_mixture,
    phase_thin_mixture,
)
from ..surface.lighting import surface_radiance
from .clouds import CLOUD_HOST_KEYS, CLOUD_KERNEL_KEYS, three_d
from .clouds_device import cloud_sources, ratio_above_grid
from ..compilation.jax_export import exported_jit
from .solar import transmittance_delta_eddington
from .device_copies import _DEVICE_COPIES, device_copies
from .march_inputs import HOST_CONSTANTS, _ends_on_surface, packed_aerosol_3d
from .surface_margin import surface_fade_cells
from .march_settings import (CELL_SLACK, CLEAR_PROBES, CLEAR_STEP_FLOOR, CLEAR_STEP_POWER, EMPTY_CELLS_PER_STEP,
                             EMPTY_STEP_WEIGHT, FROM_ABOVE_BLEND, GRID_LOOP_UNROLL_ACCELERATOR, MAX_PROBES,
                             MarchSettings, N_OCCUPANCY_PROBES, REFINE_BUDGET, REFINE_DEPTH, REFINE_SLOTS,
                             REFINE_VISIBLE_TAU, SKYLIGHT_SCALAR_FACTOR, SUNLIT_CELLS_PER_STEP, TERRAIN_BISECTIONS,
                             TOP_MIN_MU0, TOP_MIN_SELF_TRANSMITTANCE, TOP_REFLECTANCE_MIN_MU0)

log = logging.getLogger(__name__)


def _materialise(x):
    """Compute x once: without the barrier XLA on a CPU may fuse the gathers into each of x's consumers and repeat
    them (the kernel ~9 % slower). On a GPU the barriers cost more than they save: each ends a fusion, so its
    values go through device memory; without them the kernel is 18 % faster on an H100
    (docs/decisions/0006-gpu-kernels.md), so there x passes unchanged."""
    if jax.default_backend() != "cpu":
        return x
    return jax.lax.optimization_barrier(x)


def lerp_gathers(flat, n_channels, n, f, row=0, stride=None):
    """Linear interpolation of a flattened channel-major table along rows of n values, at fractional indices f,
    clamped: a list of ``n_channels`` arrays shaped like f. Channel c's row starts at ``c * stride + row`` (``stride``
    None: n; ``row`` may be per point, as each ray's own profile in :func:`_profile_at`). ``flat`` is an array or a
    Pallas ref (:mod:`swim.rt.march_pallas`: the same indexing reads it)."""
    stride = n if stride is None else stride
    f = jnp.clip(f, 0.0, n - 1.001)
    i0 = jnp.floor(f).astype(jnp.int32)
    w = f - i0
    at = row + i0
    return [flat[c * stride + at] * (1 - w) + flat[c * stride + at + 1] * w for c in range(n_channels)]


def _lerp_table(table, f):
    """Linear interpolation of a channel-major (C, n) table at fractional indices f (n_pts,), clamped: (n_pts, C)."""
    return _materialise(jnp.stack(lerp_gathers(table.reshape(-1), *table.shape, f), axis=-1))


def bilinear_gathers(flat, shape, fu, fv, prepare=None):
    """Bilinear interpolation of a flattened channel-major (C, nu, nv) table at fractional indices fu, fv, clamped: a
    list of C arrays shaped like fu. ``flat`` is an array or a Pallas ref (:mod:`swim.rt.march_pallas`: the same
    indexing reads it); ``prepare`` is applied to the cell's offset and the weights before the gathers
    (:func:`_materialise` in :func:`_bilinear_table`)."""
    n_c, nu, nv = shape
    fu = jnp.clip(fu, 0.0, nu - 1.001)
    fv = jnp.clip(fv, 0.0, nv - 1.001)
    u0 = jnp.floor(fu).astype(jnp.int32)
    v0 = jnp.floor(fv).astype(jnp.int32)
    a = fu - u0
    b = fv - v0
    r = u0 * nv + v0
    if prepare is not None:
        r, a, b = prepare((r, a, b))
    out = []
    for c in range(n_c):
        t = c * nu * nv + r
        out.append((flat[t] * (1 - b) + flat[t + 1] * b) * (1 - a) + (flat[t + nv] * (1 - b) + flat[t + nv + 1] * b) * a)
    return out


def _bilinear_table(table, fu, fv):
    """Bilinear interpolation of a channel-major (C, nu, nv) table at fractional indices, clamped: (n_pts, C)."""
    return _materialise(jnp.stack(bilinear_gathers(table.reshape(-1), table.shape, fu, fv, _materialise), axis=-1))


def _cell_weights(shape, k, j, i):
    """The lower corner (k0, j0, i0) of the cell around fractional indices k, j, i of a (nk, ny, nx, ...) volume,
    clamped to the volume, the weights (fk, fj, fi) of its far corners and whether the point lies inside."""
    nk, ny, nx = shape[:3]
    inside = (k >= 0) & (k <= nk - 1) & (j >= 0) & (j <= ny - 1) & (i >= 0) & (i <= nx - 1)
    k0 = jnp.clip(jnp.floor(k), 0, nk - 2).astype(jnp.int32)
    j0 = jnp.clip(jnp.floor(j), 0, ny - 2).astype(jnp.int32)
    i0 = jnp.clip(jnp.floor(i), 0, nx - 2).astype(jnp.int32)
    fk = jnp.clip(k - k0, 0.0, 1.0)
    fj = jnp.clip(j - j0, 0.0, 1.0)
    fi = jnp.clip(i - i0, 0.0, 1.0)
    return inside, k0, j0, i0, fk, fj, fi


def trilinear_gathers(flat, shape, k, j, i, outside, prepare=None):
    """Trilinear sample of a flattened (nk, ny, nx, C) volume at fractional indices, one scalar gather per channel and
    corner: a list of C arrays shaped like k, each ``outside[c]`` beyond the volume. ``flat`` is an array or a Pallas
    ref (:mod:`swim.rt.march_pallas`: the same indexing reads it); ``prepare`` is applied to the corner's offset and
    the weights before the gathers (:func:`_materialise` in :func:`trilinear`)."""
    ny, nx, n_c = shape[1:]
    inside, k0, j0, i0, fk, fj, fi = _cell_weights(shape, k, j, i)
    base = ((k0 * ny + j0) * nx + i0) * n_c
    if prepare is not None:
        base, fk, fj, fi, inside = prepare((base, fk, fj, fi, inside))
    row_step, plane_step = nx * n_c, ny * nx * n_c
    channels = []
    for c in range(n_c):
        def row(b):
            return flat[b + c] * (1 - fi) + flat[b + c + n_c] * fi

        def plane(b):
            return row(b) * (1 - fj) + row(b + row_step) * fj

        channels.append(jnp.where(inside, plane(base) * (1 - fk) + plane(base + plane_step) * fk, outside[c]))
    return channels


def trilinear(volume, k, j, i, outside):
    """Trilinear sample of a (nk, ny, nx, C) volume at fractional indices: (n_pts, C); ``outside`` (C,) beyond it.

    The channels of a cell stay adjacent in memory (one cache line for all of them). On a CPU each of the 8
    corners is read as one row of C channels: with JAX 0.10 the kernel marches 1.9x faster so than with one scalar
    gather per channel and corner, the reverse of what an older XLA did (see the note above :func:`_lerp_table`;
    docs/decisions/0006-gpu-kernels.md). On a GPU the scalar gathers from the flattened volume stay
    (:func:`trilinear_gathers`): rows were 6 % slower on an H100."""
    if jax.default_backend() != "cpu":
        return _materialise(jnp.stack(trilinear_gathers(volume.reshape(-1), volume.shape, k, j, i, outside,
                                                        _materialise), axis=-1))
    nk, ny, nx, n_c = volume.shape
    inside, k0, j0, i0, fk, fj, fi = _cell_weights(volume.shape, k, j, i)
    cells = volume.reshape(-1, n_c)
    cell = (k0 * ny + j0) * nx + i0
    fk, fj, fi = fk[:, None], fj[:, None], fi[:, None]

    def corner(dk, dj, di):
        return cells[cell + (dk * ny + dj) * nx + di]

    def plane(dk):
        return ((corner(dk, 0, 0) * (1 - fi) + corner(dk, 0, 1) * fi) * (1 - fj)
                + (corner(dk, 1, 0) * (1 - fi) + corner(dk, 1, 1) * fi) * fj)

    return jnp.where(inside[:, None], plane(0) * (1 - fk) + plane(1) * fk, outside[None, :])


def bilinear_clamped(field, j, i):
    """Bilinear sample of a channel-major (C, ny, nx) field, clamped to its edges: (n_pts, C)."""
    ny, nx = field.shape[1:]
    return _bilinear_table(field, jnp.clip(j, 0, ny - 1), jnp.clip(i, 0, nx - 1))


def _point_geometry(q, consts):
    """Height, grid indices and local solar-zenith cosine of points q (n, 3) relative to (0, 0, R)."""
    radius = consts["radius"]
    pz = q[:, 2] + radius
    r = jnp.sqrt(q[:, 0] ** 2 + q[:, 1] ** 2 + pz**2)
    # Stable form of |p| - R for points near the sea-level sphere.
    h = (q[:, 0] ** 2 + q[:, 1] ** 2 + q[:, 2] ** 2 + 2 * radius * q[:, 2]) / (r + radius)
    sun = consts["sun"]
    mu_s = (q[:, 0] * sun[0] + q[:, 1] * sun[1] + pz * sun[2]) / r
    i, j = grid_indices(consts["index_map"], radius * q[:, 0] / r, radius * q[:, 1] / r, jnp)
    k = (h - consts["z_bottom"]) / consts["dz"]
    return _materialise((h, mu_s, k, j, i))


def _gas_at(h, mu_s, consts):
    """Clear-atmosphere quantities at heights h [m] and local solar-zenith cosines mu_s.

    Returns the Rayleigh, background-aerosol and stratospheric-aerosol extinction (n, 3) [m-1] (one
    lookup in a joint height table of their profiles, times their spectral factors: each is a height profile
    times a spectrum), and the sun transmittance and horizontal diffuse irradiance / E_TOA (n, 3) each (one
    bilinear lookup in the joint (height, mu_s) table).
    """
    profile = _lerp_table(consts["beta_gas"][:GAS_COLUMN_ROW], h / consts["dh"])
    spectra = consts["beta_gas_spectra"]  # (3 components, 3 wavelengths)
    beta = jnp.concatenate([profile[:, c : c + 1] * spectra[c][None, :] for c in range(3)], axis=-1)
    nu, nmu = consts["sky"].shape[1:]
    fu = jnp.sqrt(jnp.clip(h / consts["top"], 0.0, 1.0)) * (nu - 1)
    fm = (mu_s + 1.0) * 0.5 * (nmu - 1)
    sky = _bilinear_table(consts["sky"], fu, fm)
    return beta[:, :3], beta[:, 3:6], beta[:, 6:], sky[:, :3], sky[:, 3:]


def lowest_point(start, direction, bounds, consts, end=None):
    """The point of each ray closest to the earth's centre, clipped to the traced segment (n, 3).

    Rebased like ``start`` (scene frame minus (0, 0, R)): the observer for upward views, the ground for
    downward ones, the tangent point for limb views. Inputs: the chunk's rebased ``start`` (n, 3) [m], unit
    ``direction`` (n, 3) and ``bounds`` (n, 3) [m] of :func:`ray_segments`; ``end`` (n,) [m]: the lowest point up
    to there instead of the segment's end ``bounds[:, 2]``.
    """
    radius = consts["radius"]
    pz = start[:, 2] + radius
    s_low = jnp.clip(-(start[:, 0] * direction[:, 0] + start[:, 1] * direction[:, 1] + pz * direction[:, 2]),
                     0.0, bounds[:, 2] if end is None else end)
    return start + s_low[:, None] * direction


def aerosol_class_weights(point, consts):
    """Class of the 3-D aerosol column at rebased points (n, 3): lower class index (n,) and weight (n, 1).

    Linear in the column optical depth between the classes of :func:`swim.rt.gas.aerosol_column_classes`
    (clamped at both ends); index 0 and weight 0 when the tables have a single class.
    """
    class_aod = consts["class_aod"]
    n_class = class_aod.shape[0]
    if n_class == 1:
        return jnp.zeros(point.shape[0], jnp.int32), jnp.zeros((point.shape[0], 1), jnp.float32)
    _, _, _, j, i = _point_geometry(point, consts)
    column = bilinear_clamped(consts["aerosol_column"], j, i)[:, 0]
    f = jnp.clip(jnp.interp(column, class_aod, jnp.arange(n_class, dtype=jnp.float32)), 0.0, n_class - 1.001)
    c0 = jnp.floor(f).astype(jnp.int32)
    return c0, (f - c0)[:, None]


def diffuse_at(h, mu_s, aerosol_class, consts):
    """Downward diffuse irradiance on a horizontal surface / E_TOA (n, 3) of the ray's aerosol class."""
    table = consts["diffuse_classes"]  # (3, n_class * nu, nmu): the classes stacked along the height axis
    n_class = consts["class_aod"].shape[0]
    nu, nmu = table.shape[1] // n_class, table.shape[2]
    fu = jnp.sqrt(jnp.clip(h / consts["top"], 0.0, 1.0)) * (nu - 1)
    fm = (mu_s + 1.0) * 0.5 * (nmu - 1)
    if n_class == 1:
        return _bilinear_table(table, fu, fm)
    # Rows c nu ... c nu + nu - 1 hold class c; with fu clamped inside a class, the bilinear lookup never mixes
    # two classes.
    c0, wc = aerosol_class
    fu = jnp.clip(fu, 0.0, nu - 1.001)
    lower = _bilinear_table(table, c0 * nu + fu, fm)
    upper = _bilinear_table(table, (c0 + 1) * nu + fu, fm)
    return lower * (1 - wc) + upper * wc


def diffuse_source_profiles(point, direction, aerosol_class, consts):
    """Per-ray height profiles of the diffuse (multiple-scattering) source, (9, n, n_u).

    The table of :mod:`swim.rt.multiple_scattering` depends on the local sun and view cosines and the
    relative azimuth, which change along a ray only through the curvature of the earth. Each ray takes them
    at its lowest point in the atmosphere (:func:`lowest_point`: the observer for upward views, the ground
    for downward ones, the tangent point for limb views), where most of its scattering happens, and keeps
    the height dependence; with a 3-D aerosol field it takes the table of the aerosol column there
    (:func:`aerosol_class_weights`, the project's form of Eqs. 30-31).

    Inputs are the rebased ``point`` (n, 3) [m] of :func:`lowest_point`, the unit ``direction`` (n, 3) and
    the class of :func:`aerosol_class_weights`; the result, channel-major (9, n, n_u), holds J of molecules, aerosol and stratospheric
    aerosol at 615/546/450 nm [-] (solar-relative radiance per unit scattering optical depth) on the table's
    heights.
    """
    q = point + jnp.array([0.0, 0.0, 1.0], jnp.float32) * consts["radius"]
    up = q / jnp.linalg.norm(q, axis=1, keepdims=True)
    sun = consts["sun"]
    mu_v = jnp.sum(up * direction, axis=1)
    mu_s = up @ sun
    cos_phi = (direction @ sun - mu_v * mu_s) / jnp.sqrt(jnp.maximum((1 - mu_v**2) * (1 - mu_s**2), 1e-12))
    table = consts["ms_source"]  # (n_class, n_s, n_v, n_phi, n_u, 9)
    n_s, n_v, n_phi = table.shape[1:4]
    fs = jnp.clip(jnp.sqrt(jnp.clip(mu_s, 0.0, 1.0)) * (n_s - 1), 0.0, n_s - 1.001)
    fv = jnp.clip((mu_v + 1.0) * 0.5 * (n_v - 1), 0.0, n_v - 1.001)
    fp = jnp.clip(jnp.arccos(jnp.clip(cos_phi, -1.0, 1.0)) / jnp.pi * (n_phi - 1), 0.0, n_phi - 1.001)
    s0, v0, p0 = (jnp.floor(f).astype(jnp.int32) for f in (fs, fv, fp))
    ws, wv, wp = ((f - jnp.floor(f))[:, None, None] for f in (fs, fv, fp))
    c0, wc = aerosol_class
    classes = ((0, 1.0),) if table.shape[0] == 1 else ((0, 1 - wc[:, :, None]), (1, wc[:, :, None]))
    profile = 0.0
    for dc, w in classes:
        for ds, a in ((0, 1 - ws), (1, ws)):
            for dv, b in ((0, 1 - wv), (1, wv)):
                for dp, c in ((0, 1 - wp), (1, wp)):
                    profile = profile + table[c0 + dc, s0 + ds, v0 + dv, p0 + dp] * (a * b * c * w)
    return jnp.moveaxis(profile, -1, 0)


def _profile_at(profile, h, consts):
    """Linear interpolation of channel-major per-ray profiles (C, n, n_u) on u = sqrt(h / H_top) at the rays'
    heights h (n,): (n, C)."""
    n_c, n, n_u = profile.shape
    u = jnp.sqrt(jnp.clip(h / consts["top"], 0.0, 1.0)) * (n_u - 1)
    return _materialise(jnp.stack(lerp_gathers(profile.reshape(-1), n_c, n_u, u, row=jnp.arange(n) * n_u,
                                               stride=n * n_u), axis=-1))


def _probe_indices(start, direction, s0, length, consts, n_probe, count=None):
    """Grid indices (k, j, i), each (n_probe, n), of the probes at the middles of equal intervals of each ray's
    grid segment: ``n_probe`` of them, or the first ``count`` (n,) <= n_probe of each ray's own count (the others
    then repeat the last)."""
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
    step = jnp.maximum(jnp.maximum(jnp.abs(jnp.diff(k, axis=0)), jnp.abs(jnp.diff(j, axis=0))), jnp.abs(jnp.diff(i, axis=0)))
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
    Sect. 3.3). Each ray
    probes the extinction at 546 nm (Rayleigh, background and stratospheric aerosol: the clear-sky source's
    coefficients) at ``n_probe`` equal intervals and spreads its steps with density extinction^(1/3) plus
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
    n = start.shape[0]
    f = (jnp.arange(n_probe, dtype=jnp.float32)[:, None] + 0.5) / n_probe
    s = s0[None, :] + f * length[None, :]
    q = (start[None] + s[..., None] * direction[None]).reshape(-1, 3)
    h, mu_s, *_ = _point_geometry(q, consts)
    beta_r, beta_a, beta_s, _, _ = _gas_at(h, mu_s, consts)  # (the sky lookup unused: XLA drops it)
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


def _march_segment(state, start, direction, edges, n_steps, in_grid, rays, consts, ms_profile, aerosol_class,
                   tau_refine=0.0, steps=None, terminal=False, stop_tau=0.0):
    """Accumulate one ray segment with n_steps midpoint steps between ``edges`` (n_steps + 1, n) [m] (see the
    module docstring), or each ray its own ``steps`` (n,) <= n_steps of them (:func:`grid_step_edges`); in the
    grid, thick steps and cloud faces are refined down to ``tau_refine`` (:func:`_march_grid_refined`), and a ray
    that does not look down stops where its hydrometeor optical depth passes ``stop_tau`` (> 0; 0: never), once
    past :data:`REFINE_VISIBLE_TAU` before the step (:attr:`MarchSettings.stop_tau`).

    ``ms_profile`` is :func:`diffuse_source_profiles` of the rays, or None for single scattering only;
    ``aerosol_class`` that of :func:`aerosol_class_weights` (the skylight of the hydrometeors).
    """
    multiple_scattering = ms_profile is not None
    clouds_3d = three_d(consts)  # cloud_scattering="discrete_ordinates" (swim.rt.clouds_device)
    n_c = consts["volume"].shape[-1]
    n_sp = consts["species_matrix"].shape[0]  # the packed species (packed_species)
    aerosol_3d = packed_aerosol_3d(n_c, n_sp)  # packed only where it is not zero
    outside = jnp.concatenate([jnp.zeros(n_c - 2), jnp.ones(2)]).astype(jnp.float32)

    def sample(st, s_lo, ds):
        """The state after a step of length ``ds`` from ``s_lo`` [m], and the step's hydrometeor extinction."""
        s = s_lo + 0.5 * ds
        if terminal:  # the step back takes back what the step before added: at that step's sample
            s = jnp.where(ds < 0, st["hit_lo"], s)
        q = start + s[:, None] * direction
        h, mu_s, k, j, i = _point_geometry(q, consts)
        beta_r, beta_a, beta_s, t_sun, diffuse = _gas_at(h, mu_s, consts)
        if in_grid:
            v = trilinear(consts["volume"], k, j, i, outside)
            beta_sp = v[:, :n_sp]
            t_cloud = v[:, -2]
            shadow = v[:, -1]
            if aerosol_3d:
                beta_a3 = v[:, n_sp : n_sp + 1] * consts["angstrom"][None, :]
                # Direct beam through the 3-D aerosol towards the sun (Angstrom-scaled from 550 nm).
                t_aerosol = jnp.exp(-v[:, n_sp + 1 : n_sp + 2] * consts["angstrom"][None, :])
            else:
                beta_a3 = jnp.zeros((q.shape[0], 3), jnp.float32)
                t_aerosol = jnp.ones((q.shape[0], 3), jnp.float32)
            gap = h - bilinear_clamped(consts["terrain"], j, i)[:, 0]
            hit_now = st["alive"] & (gap < 0) & (not terminal)
            frac = jnp.where(hit_now, jnp.clip(st["gap"] / jnp.maximum(st["gap"] - gap, 1e-6), 0.0, 1.0), 1.0)
        else:
            beta_sp = jnp.zeros((q.shape[0], n_sp), jnp.float32)
            beta_a3 = jnp.zeros((q.shape[0], 3), jnp.float32)
            t_cloud = jnp.ones(q.shape[0], jnp.float32)
            shadow = jnp.ones(q.shape[0], jnp.float32)
            t_aerosol = jnp.ones((q.shape[0], 3), jnp.float32)
            # Beyond the grid the terrain continues at its edge heights (clamped), so that mountains at the
            # domain's edge do not end in a cliff down to the sea-level sphere and a plateau's horizon is flat.
            gap = h - bilinear_clamped(consts["terrain"], j, i)[:, 0]
            hit_now = st["alive"] & (gap < 0)
            frac = jnp.where(hit_now, jnp.clip(st["gap"] / jnp.maximum(st["gap"] - gap, 1e-6), 0.0, 1.0), 1.0)
        # the step in which the ray meets the ground adds nothing here: its sample may lie deep inside the
        # terrain; the terminal step (_terminal_step) covers it up to the refined crossing
        ds_eff = jnp.where(st["alive"] & ~hit_now, ds, 0.0)
        # direct beam / E_TOA, lights the gas and aerosol (Eq. 3): gas, hydrometeors (T), 3-D aerosol
        irradiance = t_sun * (t_cloud * shadow)[:, None] * t_aerosol
        if in_grid:
            # Clear-sky diffuse scalar irradiance / E_TOA, through the clouds above (T of Step 1a); with
            # aerosol column classes, that of the ray's class.
            if consts["class_aod"].shape[0] > 1:
                diffuse = diffuse_at(h, mu_s, aerosol_class, consts)
            skylight = SKYLIGHT_SCALAR_FACTOR * diffuse * t_cloud[:, None]
        # Scalar irradiance of Eq. 8 ("direct + scattered") lighting the hydrometeors.
        irradiance_h = irradiance + skylight if in_grid else irradiance
        beta_clear = beta_r + beta_a + beta_a3 + beta_s
        beta_h = beta_sp.sum(axis=1)
        # the extinction that dims the light on its way to the observer: with the 3-D cloud scattering the
        # hydrometeors' delta-M scaled one (the forward peak's light stays in the view), whose sources are
        # integrated along the ray; the diffuse solution's ratio to the clear sky dims the air's diffuse source
        beta_view, dims_diffuse = beta_h, t_cloud[:, None]
        if clouds_3d and in_grid:
            dims_diffuse, cloud_source, beta_view = cloud_sources(beta_sp, k, j, i, t_cloud, irradiance, rays, consts)
        elif clouds_3d:
            dims_diffuse = ratio_above_grid(h, k, j, i, consts, consts["volume"].shape[:3])
        x = (beta_clear + beta_view[:, None]) * ds_eff[:, None]
        # (1 - e^-x) / x, also for the terminal step's negative x (a step back)
        big = jnp.abs(x) > 1e-4
        step_mean = jnp.where(big, -jnp.expm1(-x) / jnp.where(big, x, 1.0), 1.0 - 0.5 * x)
        t_obs = jnp.exp(-(st["tau_clear"] + (st["tau_view"] if clouds_3d else st["tau_h"])[:, None]))
        scat_a = (beta_a + beta_a3) * consts["aerosol_ssa"]
        scat_s = beta_s * consts["stratospheric_ssa"]
        source = (beta_r * rays["p_rayleigh"][:, None] + scat_a * rays["p_aerosol"]
                  + scat_s * rays["p_stratospheric"]) * irradiance
        if multiple_scattering:
            # Orders >= 2: the diffuse source of the successive-orders table (molecules, aerosol,
            # stratospheric aerosol), dimmed under clouds by their transmittance like the skylight.
            j = _profile_at(ms_profile, h, consts)
            source = source + (beta_r * j[:, :3] + scat_a * j[:, 3:6] + scat_s * j[:, 6:]) * dims_diffuse
        l_clear = st["l_clear"] + t_obs * source * (ds_eff[:, None] * step_mean)
        # Eq. 12 integrand over the first two optical depths of hydrometeors.
        t0 = st["tau_h"]
        t1 = t0 + beta_h * ds_eff
        if clouds_3d:  # the clouds' light is integrated along the ray (swim.rt.clouds), not composed by Eq. 12
            i_nogas, i_gas, i_cloud_t = st["i_nogas"], st["i_gas"], st["i_cloud_t"]
            extra = {"tau_view": st["tau_view"] + beta_view * ds_eff, "l_cloud": st["l_cloud"]}
            if in_grid:
                extra["l_cloud"] = st["l_cloud"] + t_obs * cloud_source * (ds_eff[:, None] * step_mean)
        else:
            weight = jnp.exp(-jnp.minimum(t0, 2.0)) - jnp.exp(-jnp.minimum(t1, 2.0))
            weight = jnp.where(t1 >= t0, jnp.maximum(weight, 0.0), weight)  # negative for a step back
            i_nogas = st["i_nogas"] + irradiance_h * weight[:, None]
            i_gas = st["i_gas"] + irradiance_h * jnp.exp(-st["tau_clear"]) * weight[:, None]
            i_cloud_t = st["i_cloud_t"] + t_cloud * shadow * weight
            extra = {}
        hit_s = jnp.where(hit_now, s - 0.5 * ds + frac * ds, st["hit_s"])
        # bracket of the crossing for the bisection after the march: the previous sample (above) and this one
        hit_lo = jnp.where(hit_now, st["s_last"], st["hit_lo"])
        hit_hi = jnp.where(hit_now, s, st["hit_hi"])
        hit_from = jnp.where(hit_now, s_lo, st["hit_from"])
        tau_species = st["tau_species"] + beta_sp * ds_eff[:, None]
        alive = st["alive"] & ~hit_now
        if in_grid and stop_tau > 0:
            # opaque (MarchSettings.stop_tau): the ray stops at stop_tau, its species in the proportions they had
            # there; past REFINE_VISIBLE_TAU before the step, so that no roll-back can undo it
            stopped = alive & (t1 > stop_tau) & (t0 >= REFINE_VISIBLE_TAU) & (direction[:, 2] >= 0)
            tau_species = jnp.where(stopped[:, None], tau_species * (stop_tau / jnp.maximum(t1, stop_tau))[:, None],
                                    tau_species)
            t1 = jnp.where(stopped, jnp.asarray(stop_tau, t1.dtype), t1)
            alive = alive & ~stopped
        return {
            "tau_clear": st["tau_clear"] + beta_clear * ds_eff[:, None],
            "tau_h": t1,
            "tau_species": tau_species,
            "l_clear": l_clear,
            "i_nogas": i_nogas,
            "i_gas": i_gas,
            "i_cloud_t": i_cloud_t,
            "alive": alive,
            "hit": st["hit"] | hit_now,
            "hit_s": hit_s,
            "hit_lo": hit_lo,
            "hit_hi": hit_hi,
            "hit_from": hit_from,
            "gap": gap,
            "s_last": s,
            **extra,
        }, beta_h

    def body(m, st):
        s_lo = jax.lax.dynamic_index_in_dim(edges, m, keepdims=False)
        ds = jax.lax.dynamic_index_in_dim(edges, m + 1, keepdims=False) - s_lo
        new = sample(st, s_lo, ds)[0]
        if steps is None:
            return new
        taken = m < steps  # a ray's steps beyond its own count leave it as it is
        return {key: jnp.where(taken.reshape((-1,) + (1,) * (value.ndim - 1)), value, st[key])
                for key, value in new.items()}

    if in_grid and tau_refine > 0:
        return _march_grid_refined(state, sample, edges, n_steps, tau_refine, steps)
    return jax.lax.fori_loop(0, n_steps, body, state)


def grid_loop_unroll() -> int:
    """Iterations of the lockstep grid loop per test of its condition (:func:`_march_grid_refined`):
    :data:`GRID_LOOP_UNROLL_ACCELERATOR` where JAX's default device is a GPU (or another accelerator), 1 on a CPU."""
    return 1 if jax.default_backend() == "cpu" else GRID_LOOP_UNROLL_ACCELERATOR


def _predicted_halving(adjacent, prev_beta, ds, depth, tau_h, pending, slots, tau_refine):
    """Whether a ray's next interval (length ``ds`` [m], refinement ``depth``) is halved before it is sampled, its
    second half left pending (:func:`_march_grid_refined`): the accumulated interval just before it (``adjacent``) had
    an extinction ``prev_beta`` [1/m] that makes this one thicker than ``tau_refine`` in hydrometeor optical depth, so
    its midpoint's sample would most likely find it too thick and be discarded for its halves. Only where that
    refinement could happen (``depth`` < :data:`REFINE_DEPTH`, the ray's optical depth ``tau_h`` <
    :data:`REFINE_VISIBLE_TAU`, two of ``slots`` free above ``pending``); the caller checks the ray's budget. One level
    each time an interval is taken: the first half is sampled even if the prediction would halve it again (its own
    sample finds it too thick then); the pending second half is predicted anew when it is taken, from the interval
    accumulated just before it. Elementwise: JAX arrays of one shape, or scalars (:mod:`swim.rt.march_pallas`;
    :func:`swim.rt.march_cpu._predicted_halving` is the numba kernel's)."""
    return (adjacent & (depth < REFINE_DEPTH) & (tau_h < REFINE_VISIBLE_TAU) & (pending + 2 <= slots)
            & (prev_beta * ds > tau_refine))


def _march_grid_refined(state, sample, edges, n_steps, tau_refine, steps=None, unroll=None):
    """The grid segment of :func:`_march_segment` with steps refined where a cloud face may lie, while the ray's
    own hydrometeor optical depth is below :data:`REFINE_VISIBLE_TAU` (at most :data:`REFINE_DEPTH` levels of
    halving and :data:`REFINE_BUDGET` refinements per ray):

    * a step whose hydrometeor optical depth ``beta_h ds`` exceeds ``tau_refine`` is replaced by its two halves,
      first half first, recursively (a face inside the step, or a thick step whose midpoint sunlight stands for
      all of it);
    * so is a step whose extinction differs from that of the interval before it by more than ``tau_refine / ds``
      (the face where a cloud ends lies in its first half, or the cloud goes on unseen by its midpoint);
    * where that difference over the previous interval's length exceeds ``tau_refine``, the previous interval
      held the face where a cloud begins, but its midpoint lay in clear air: the ray goes back to its state
      before that interval and takes its two halves, then this interval again;
    * an interval whose length times the extinction of the accumulated interval just before it exceeds
      ``tau_refine`` is halved before it is sampled (:func:`_predicted_halving`, one level): inside a cloud its
      own sample would find it too thick and be discarded for its halves. On the synthetic 400 x 400 x 60 all-sky
      that saves ~5 % of the samples, at a slightly smaller error (docs/decisions/0004-step-placement.md).

    So a cloud face is resolved where the light comes from, and neighbouring pixels whose step midpoints fall on
    either side of the face agree (the stripes of docs/decisions/0004-step-placement.md).

    Rays in lockstep, each with its own pending intervals (:data:`REFINE_SLOTS`, a refinement only where they
    fit): every iteration each ray takes its next interval (the last pending one, or its next step; its first half,
    the second pending, where the halving is predicted), samples it and either accumulates it, pushes its halves, or
    rolls back, until it has taken its n_steps (or its own ``steps`` (n,)) steps or has stopped (``alive`` False: the
    ground, or opaque cloud; its later samples would add nothing). :mod:`swim.rt.march_cpu` does the same per ray.

    ``unroll``: iterations per test of the loop's condition (None: :func:`grid_loop_unroll`); an iteration leaves
    a finished ray unchanged, so any value gives the same state.
    """
    n = edges.shape[1]
    slots = REFINE_SLOTS
    col = jnp.arange(slots)[None, :]
    last = jnp.full((n,), n_steps, jnp.int32) if steps is None else steps

    def finished(carry):
        # a ray that has stopped (the ground, opaque cloud) is finished: its later samples would add nothing (their
        # length counts as 0 in every sum), so its steps and pending intervals are left
        # (docs/decisions/0006-gpu-kernels.md)
        st, m, pending, *_ = carry
        return ((pending == 0) & (m >= last)) | ~st["alive"]

    def rows(mask, value):
        return mask.reshape((n,) + (1,) * (value.ndim - 1))

    def body(carry):
        st, m, pending, stack_lo, stack_hi, stack_depth, budget, saved, prev = carry
        stacked = pending > 0
        top = jnp.maximum(pending - 1, 0)[:, None]
        next_step = jnp.minimum(m, last - 1)[None, :]
        done = (~stacked & (m >= last)) | ~st["alive"]
        lo = jnp.where(stacked, jnp.take_along_axis(stack_lo, top, 1)[:, 0], jnp.take_along_axis(edges, next_step, 0)[0])
        hi = jnp.where(stacked, jnp.take_along_axis(stack_hi, top, 1)[:, 0], jnp.take_along_axis(edges, next_step + 1, 0)[0])
        depth = jnp.where(stacked, jnp.take_along_axis(stack_depth, top, 1)[:, 0], 0)
        ds = jnp.where(done, 0.0, hi - lo)
        base = pending - stacked
        adjacent = prev["valid"] & (prev["hi"] == lo)
        # an interval that the one before it predicts too thick: its second half pending, its first half sampled
        halve = (~done & (budget > 0) & st["alive"]
                 & _predicted_halving(adjacent, prev["beta_h"], ds, depth, st["tau_h"], base, slots, tau_refine))
        half = lo + 0.5 * ds
        at = halve[:, None] & (col == base[:, None])
        stack_lo = jnp.where(at, half[:, None], stack_lo)
        stack_hi = jnp.where(at, hi[:, None], stack_hi)
        stack_depth = jnp.where(at, depth[:, None] + 1, stack_depth)
        hi = jnp.where(halve, half, hi)
        depth = depth + halve
        ds = jnp.where(halve, hi - lo, ds)
        base = base + halve
        budget = budget - halve
        new, beta_h = sample(st, lo, ds)
        live = ~done & (budget > 0) & st["alive"]
        change = jnp.where(adjacent, jnp.abs(beta_h - prev["beta_h"]), 0.0)
        rollback = (live & adjacent & (prev["depth"] < REFINE_DEPTH) & (change * (prev["hi"] - prev["lo"]) > tau_refine)
                    & (base + 3 <= slots) & (saved["tau_h"] < REFINE_VISIBLE_TAU))
        refine = (live & ~rollback & (depth < REFINE_DEPTH) & (st["tau_h"] < REFINE_VISIBLE_TAU) & (base + 2 <= slots)
                  & (jnp.maximum(beta_h, change) * ds > tau_refine))
        keep = ~done & ~refine & ~rollback
        save = keep & live
        saved = {key: jnp.where(rows(save, value), st[key], value) for key, value in saved.items()}
        # a rolled-back ray's snapshot is not overwritten above (save needs keep)
        st = {key: jnp.where(rows(keep, value), value, jnp.where(rows(rollback, value), saved[key], st[key]))
              for key, value in new.items()}
        mid = (lo + 0.5 * ds)[:, None]
        prev_mid = (prev["lo"] + 0.5 * (prev["hi"] - prev["lo"]))[:, None]
        b = base[:, None]
        # split: the second half below the first, which is taken next; rollback: this interval, then the
        # previous one's second half, then its first half on top
        first, second = refine[:, None] & (col == b), refine[:, None] & (col == b + 1)
        again, p_second, p_first = (rollback[:, None] & (col == b + i) for i in range(3))
        stack_lo = jnp.where(first | p_second, jnp.where(first, mid, prev_mid),
                             jnp.where(second | again, lo[:, None], jnp.where(p_first, prev["lo"][:, None], stack_lo)))
        stack_hi = jnp.where(first | again, hi[:, None],
                             jnp.where(second, mid, jnp.where(p_second, prev["hi"][:, None],
                                                              jnp.where(p_first, prev_mid, stack_hi))))
        stack_depth = jnp.where(first | second, depth[:, None] + 1,
                                jnp.where(again, depth[:, None],
                                          jnp.where(p_second | p_first, prev["depth"][:, None] + 1, stack_depth)))
        prev = {"valid": jnp.where(save, True, prev["valid"] & ~rollback), "lo": jnp.where(save, lo, prev["lo"]),
                "hi": jnp.where(save, hi, prev["hi"]), "beta_h": jnp.where(save, beta_h, prev["beta_h"]),
                "depth": jnp.where(save, depth, prev["depth"])}
        pending = base + 2 * refine + 3 * rollback
        return (st, m + (~stacked & ~done), pending, stack_lo, stack_hi, stack_depth, budget - refine - rollback,
                saved, prev)

    zero = jnp.zeros(n, jnp.float32)
    prev = {"valid": jnp.zeros(n, bool), "lo": zero, "hi": zero, "beta_h": zero, "depth": jnp.zeros(n, jnp.int32)}
    carry = (state, jnp.zeros(n, jnp.int32), jnp.zeros(n, jnp.int32), jnp.zeros((n, slots), jnp.float32),
             jnp.zeros((n, slots), jnp.float32), jnp.zeros((n, slots), jnp.int32), jnp.full(n, REFINE_BUDGET, jnp.int32),
             dict(state), prev)
    unroll = grid_loop_unroll() if unroll is None else int(unroll)

    def bodies(c):  # a finished ray's iteration leaves it as it is, so the loop may run past its last one
        for _ in range(unroll):
            c = body(c)
        return c

    return jax.lax.while_loop(lambda c: ~jnp.all(finished(c)), bodies, carry)[0]


def refine_terrain_hit(start, direction, state, consts):
    """Distance [m] to the terrain crossing of each ray, by bisection between the samples that bracket it.

    The march finds the crossing between a sample above and one below the (clamped bilinear) terrain and
    interpolates the gap linearly, which is exact for a flat surface but, with the long steps beyond the grid
    or along grazing rays, can put the hit kilometres off over curved terrain; bisection on the same gap
    function fixes that. Rays without a terrain hit keep ``state["hit_s"]``.
    """
    def gap(s):
        h, _, _, j, i = _point_geometry(start + s[:, None] * direction, consts)
        return h - bilinear_clamped(consts["terrain"], j, i)[:, 0]

    def step(_, bracket):
        lo, hi = bracket
        mid = 0.5 * (lo + hi)
        below = gap(mid) < 0
        return jnp.where(below, lo, mid), jnp.where(below, mid, hi)

    lo, hi = state["hit_lo"], state["hit_hi"]
    valid = (gap(lo) >= 0) & (gap(hi) < 0)
    lo, hi = jax.lax.fori_loop(0, TERRAIN_BISECTIONS, step, (lo, hi))
    return jnp.where(valid, 0.5 * (lo + hi), state["hit_s"])


def _terminal_step(state, start, direction, rays, consts, ms_profile, aerosol_class):
    """The last step of each ray that met the ground: from the start of the step in which it did (``hit_from``) to
    the refined crossing ``s_hit`` [m] (:func:`refine_terrain_hit`), one sample at its middle; rays that did not
    meet the ground are left as they are.

    The march finds the ground by a sample below it, in the middle of a step that may be kilometres long (the
    empty space of a ray grazing a big grid); that sample's light and extinction come from inside the terrain,
    and the step adds nothing. Where the crossing lies before ``hit_from``, in the far half of the step before
    (which was taken whole; its sample ``hit_lo`` is its middle, so it began at 2 ``hit_lo`` - ``hit_from``), that
    step is taken back (a step of negative length at its own sample, which undoes it) and taken again up to the
    crossing. The step back inverts Eq. 3's exponential step exactly ((T, L) -> (T e^-x, L + T S (1 - e^-x) / x)
    with -x) and Eq. 12's weight e^-min(tau0, 2) - e^-min(tau1, 2) changes sign (Albers et al. 2020,
    doi:10.5194/amt-13-3235-2020). So the light of the air in front of the ground no longer depends on the step
    count (docs/decisions/0004-step-placement.md). :mod:`swim.rt.march_cpu` takes the same steps.

    ``state``: the march's per-ray arrays (n,) or (n, 3) of :func:`_march_rays` with ``s_hit`` (n,) [m]; ``start``
    (n, 3) [m], unit ``direction`` (n, 3); the rest as :func:`_march_segment` takes them. Returns the state
    after the terminal steps, ``alive`` and ``s_hit`` as they were."""
    state = dict(state)
    s_hit, alive = state.pop("s_hit"), state["alive"]
    hit_from = state["hit_from"]
    back_to = 2.0 * state["hit_lo"] - hit_from  # < 0 where no step came before
    back = state["hit"] & (s_hit < hit_from) & (back_to >= 0)
    # two steps: back to where the step before began (zero length unless ``back``), then on to the crossing (zero
    # length where it lies before the ray's first step)
    mid = jnp.where(back, back_to, hit_from)
    end = jnp.where(back | (s_hit > hit_from), s_hit, hit_from)
    state["alive"] = state["hit"]
    state = _march_segment(state, start, direction, jnp.stack([hit_from, mid, end]), 2, True, rays, consts,
                           ms_profile, aerosol_class, terminal=True)
    return dict(state, alive=alive, s_hit=s_hit)


def fused_fits(n) -> bool:
    """Whether a batch of n rays fills whole blocks of the fused grid kernel (:data:`swim.rt.march_pallas.BLOCK_RAYS`);
    the batches of :func:`padded_batch_size` do (powers of two of at least :data:`MIN_BATCH`, or the chunk)."""
    from .march_pallas import BLOCK_RAYS

    return n % BLOCK_RAYS == 0


def _prepare_rays(start, direction, bounds, consts, settings: MarchSettings):
    """Per-ray set-up before the march: the aerosol column class and the diffuse-source height profiles (or
    None) at each ray's lowest point."""
    low = lowest_point(start, direction, bounds, consts)
    aerosol_class = aerosol_class_weights(low, consts)
    ms = diffuse_source_profiles(low, direction, aerosol_class, consts) if settings.multiple_scattering else None
    return aerosol_class, ms


def _march_rays(start, direction, bounds, valid, rays, consts, settings: MarchSettings, aerosol_class, ms, probes=None):
    """The lockstep march of the three segments; the state of :func:`_march_segment` plus ``s_hit`` (n,) [m],
    the refined terrain crossing or the end of the ray (:mod:`swim.rt.march_cpu` computes the same per ray).
    ``probes``: each ray's occupancy probes (n,) (:func:`probe_counts`, at most ``settings.n_probe``) and its grid
    segment's length in cells (n,), from :func:`probe_counts_and_cells`."""
    n = start.shape[0]
    zeros3 = jnp.zeros((n, 3), jnp.float32)
    state = {
        "tau_clear": zeros3, "tau_h": jnp.zeros(n, jnp.float32),
        "tau_species": jnp.zeros((n, consts["species_matrix"].shape[0]), jnp.float32),  # the packed species'
        "l_clear": zeros3, "i_nogas": zeros3, "i_gas": zeros3, "i_cloud_t": jnp.zeros(n, jnp.float32),
        "alive": valid, "hit": jnp.zeros(n, bool), "hit_s": jnp.zeros(n, jnp.float32),
        "hit_lo": jnp.zeros(n, jnp.float32), "hit_hi": jnp.zeros(n, jnp.float32),
        "hit_from": jnp.zeros(n, jnp.float32),
        "gap": jnp.full(n, 1e9, jnp.float32), "s_last": jnp.zeros(n, jnp.float32),
    }
    if three_d(consts):  # the hydrometeors' scaled optical depth to the observer and their radiance
        state.update(tau_view=jnp.zeros(n, jnp.float32), l_cloud=zeros3)
    from .march_pallas import Segment, march_grid_fused, march_segments_fused

    zero = jnp.zeros(n, jnp.float32)
    args = (rays, consts, ms, aerosol_class)
    tau_refine, stop_tau = float(settings.tau_refine), float(settings.stop_tau)
    segments = []  # the ray's segments in order, each's step edges placed from the geometry alone
    if settings.n_before:
        segments.append(Segment(clear_step_edges(start, direction, zero, bounds[:, 0], settings.n_before, consts),
                                settings.n_before))
    if settings.n_grid:
        count, cells = (None, None) if probes is None else probes
        empty_steps = settings.resolved_empty_steps()
        edges, steps = grid_step_edges(start, direction, bounds[:, 0], bounds[:, 1] - bounds[:, 0], settings.n_grid,
                                       consts, n_probe=settings.n_probe, probes=count, cells=cells,
                                       empty_steps=empty_steps, sunlit_steps=settings.sunlit_steps)
        segments.append(Segment(edges, settings.n_grid, steps if empty_steps else None, in_grid=True,
                                refined=tau_refine > 0))
    if settings.n_after:
        steps = after_step_counts(start, direction, bounds, settings.n_after, consts)
        segments.append(Segment(clear_step_edges(start, direction, bounds[:, 1], bounds[:, 2] - bounds[:, 1],
                                                 settings.n_after, consts, steps=steps), settings.n_after, steps))
    # one more step, of zero length at each ray's end: where that end lies on the sea-level sphere, below the terrain
    # (which beyond the grid keeps its edge's heights), its sample detects a crossing in the far half of the ray's
    # last step, which no later step would (docs/decisions/0004-step-placement.md); elsewhere it adds nothing
    segments.append(Segment(jnp.stack([bounds[:, 2], bounds[:, 2]]), 1))
    # the fused kernel marches whole blocks of rays: a batch of another size (a chunk set by hand) is marched by the
    # lockstep loops
    kernel = settings.resolved_grid_kernel()
    fused = kernel in ("fused", "fused-march") and fused_fits(n)
    interpret = jax.default_backend() == "cpu"
    # the fused kernel's register cap, loads and fused multiply-adds: settings, so that programs built with other
    # ones are kept apart
    fused_options = {"max_registers": settings.fused_max_registers, "vector_loads": settings.fused_vector_loads,
                     "fma": settings.fused_fma}
    if fused and kernel == "fused-march":
        state = march_segments_fused(state, start, direction, tuple(segments), rays, consts, ms, aerosol_class,
                                     tau_refine, stop_tau, interpret=interpret, **fused_options)
    else:
        for seg in segments:
            if fused and seg.refined:
                state = march_grid_fused(state, start, direction, seg.edges, seg.n_steps, rays, consts, ms,
                                         aerosol_class, tau_refine, steps=seg.steps, stop_tau=stop_tau,
                                         interpret=interpret, **fused_options)
            else:
                state = _march_segment(state, start, direction, seg.edges, seg.n_steps, seg.in_grid, *args,
                                       tau_refine=tau_refine if seg.refined else 0.0, steps=seg.steps,
                                       stop_tau=stop_tau if seg.in_grid else 0.0)
    state["s_hit"] = jnp.where(state["hit"], refine_terrain_hit(start, direction, state, consts), bounds[:, 2])
    state = _terminal_step(state, start, direction, *args)
    state["tau_species"] = state["tau_species"] @ consts["species_matrix"]  # all of SPECIES, 0 where not packed
    return state


def _compose(start, direction, bounds, ends_on_ground, valid, rays, consts, settings: MarchSettings, state,
             aerosol_class, ground=True):
    """The pixel radiance from the march's state: ground (Eq. 35), clouds (Eqs. 12-26), clear sky.

    ``ground`` (static): False where no ray of the batch ends on the ground, whose term is then 0 without being
    evaluated (as it is for such rays anyway). The chunks of an all-sky camera on the ground and the upper rows of a
    panorama see no ground, and the ground's BRDF is about half of the composition's cost
    (docs/decisions/0009-work-around-the-march.md)."""
    surface = _ends_on_surface(state, ends_on_ground)
    s_hit = state["s_hit"]
    if ground:
        l_surface = _ground_radiance(start, direction, rays, consts, settings, state, aerosol_class, surface, s_hit)
    else:
        l_surface = jnp.zeros_like(state["l_clear"])
    if three_d(consts):
        return _compose_three_d(consts, state, valid, surface, s_hit, l_surface)
    return _compose_clouds(rays, consts, state, valid, surface, s_hit, l_surface)


def _ground_radiance(start, direction, rays, consts, settings, state, aerosol_class, surface, s_hit):
    """The ground's part of the pixel radiance (n, 3), 0 where a ray does not end on the ground (``surface``):
    Eq. 35 on the terrain facet at ``s_hit`` [m], direct (BRDF) + diffuse (ARF = 1), seen through the clear sky and
    the hydrometeors on the way. The numba kernel's twin: :func:`swim.rt.ground_cpu.ground_radiance`."""
    q = start + s_hit[:, None] * direction
    h, mu_s, k, j, i = _point_geometry(q, consts)
    _, _, _, t_sun, diffuse = _gas_at(h, mu_s, consts)
    if consts["class_aod"].shape[0] > 1:
        diffuse = diffuse_at(h, mu_s, aerosol_class, consts)
    # albedo (3), land, snow, wind, slope (2), and Step 1a at the ground: cloud T, terrain shadow, 3-D aerosol
    # tau to the sun (2-D fields, so a steep slope does not sample its neighbours' underground values);
    # beyond the grid they continue over a margin (swim.rt.march_inputs.extended_surface), and beyond that they fade
    # from its edge to the far ground, flat and unshaded
    jm, im = j + consts["surface_margin"], i + consts["surface_margin"]
    fields = surface_beyond_edge(bilinear_clamped(consts["surface"], jm, im), consts["surface_outside"],
                                 *consts["surface"].shape[1:], jm, im)
    slope = fields[:, 6:8]
    t_cloud = fields[:, 8]
    shadow = fields[:, 9]
    t_aerosol = jnp.exp(-fields[:, 10:11] * consts["angstrom"][None, :])
    # with the 3-D cloud scattering the diffuse light at the ground is the diffuse solution's (its ratio to the
    # clear sky's, channels 11-13), which includes the light between the ground and the cloud base
    clouds_3d = three_d(consts)
    diffuse = diffuse * (fields[:, 11:14] if clouds_3d else t_cloud[:, None])
    up = q + jnp.array([0.0, 0.0, 1.0], jnp.float32) * consts["radius"]
    up = up / jnp.linalg.norm(up, axis=1, keepdims=True)
    l_ground = surface_radiance(up, -direction, consts["sun"], slope, fields[:, :3], fields[:, 3], fields[:, 4],
                                fields[:, 5], t_sun * t_aerosol * (t_cloud * shadow)[:, None], diffuse,
                                model=settings.surface)
    if clouds_3d:  # seen through the delta-M scaled optical depth: the forward peak's light stays in the view
        t_hydro = jnp.exp(-(state["tau_species"] @ consts["backscatter_scaled"]))
        return jnp.where(surface[:, None], l_ground * (jnp.exp(-state["tau_clear"]) * t_hydro[:, None]), 0.0)
    # Seen from above, the ground under a cloud layer shines through the layer's total (direct + diffuse)
    # transmittance at the view angle (reciprocity), the same delta-Eddington T as in Step 1a; rays that do
    # not look down (blend as for the clouds) keep the direct e^{-tau} (docs/rendering.md, "Overcast accuracy").
    mu_down_ground = -rays["cos_view_zenith"]
    w_above_ground = jnp.clip(mu_down_ground / FROM_ABOVE_BLEND, 0.0, 1.0)
    tau_hydro = state["tau_h"]
    t_hydro = (1 - w_above_ground) * jnp.exp(-tau_hydro) + w_above_ground * transmittance_delta_eddington(
        tau_hydro, state["tau_species"] @ consts["backscatter"], jnp.maximum(mu_down_ground, FROM_ABOVE_BLEND))
    transmit = jnp.exp(-state["tau_clear"]) * t_hydro[:, None]
    return jnp.where(surface[:, None], l_ground * transmit, 0.0)


def _compose_three_d(consts, state, valid, surface, s_hit, l_surface):
    """The outputs of :func:`_compose` with the 3-D cloud scattering, whose hydrometeors' radiance was integrated
    along the rays (:mod:`swim.rt.clouds_device`), given the ground's part ``l_surface`` (n, 3); ``tau_narrow``
    (n,) is the optical depth that dims the beam but for the forward peak's narrow part (the circumsolar aureole,
    :func:`swim.optics.cloud_phase.split_phase_function`). The numba kernel's twin: :func:`_compose_numba`."""
    aureole = consts["species_matrix"].T @ consts["hydro_aureole"].astype(jnp.float32)  # (SPECIES,)
    radiance = jnp.where(valid[:, None], state["l_clear"] + state["l_cloud"] + l_surface, 0.0)
    return {
        "radiance": radiance,
        "radiance_clear": state["l_clear"],
        "radiance_cloud": state["l_cloud"],
        "radiance_surface": l_surface,
        "tau_hydrometeor": state["tau_h"],
        "tau_clear": state["tau_clear"],
        "surface": surface,
        "distance": jnp.where(surface, s_hit, jnp.nan),
        "tau_narrow": state["tau_species"] @ aureole,
    }


def _compose_clouds(rays, consts, state, valid, surface, s_hit, l_surface):
    """The clouds' part of the pixel radiance (Eq. 12 with the effective phase function of Eq. 13, seen from below,
    blended with the cloud-top reflection of Eqs. 24-26 seen from above; Albers et al. 2020,
    doi:10.5194/amt-13-3235-2020) and the outputs of :func:`_compose`, given the ground's part ``l_surface``
    (n, 3)."""
    # ---- clouds: Eq. 12 with the effective phase function of Eq. 13, blended with Eqs. 24-26 ----
    tau = state["tau_h"]
    norm = -jnp.expm1(-jnp.minimum(tau, 2.0))
    safe = jnp.maximum(norm, 1e-12)
    e_mean = state["i_nogas"] / safe[:, None]
    # How directly the visible cloud is lit, for c1 and c3 (Eqs. 14, 22): the cloud transmittance T of
    # Step 1a, not E/E_TOA with the gas extinction (docs/rendering.md).
    t_mean = jnp.clip(state["i_cloud_t"] / safe, 0.0, 1.0)
    weights = state["tau_species"] / jnp.maximum(tau, 1e-12)[:, None]
    cos_theta = rays["cos_theta"]
    cos_view_zenith = rays["cos_view_zenith"]
    mu_view_down = -cos_view_zenith
    mu0 = consts["mu0"]
    w_above = jnp.clip(mu_view_down / FROM_ABOVE_BLEND, 0.0, 1.0)[:, None]
    # Seen from below, the indirectly lit (c4) term of Eq. 21 is the diffusely transmitted light: 4 x the
    # transmitted flux mu0 T x the escape function, i.e. the factor (9/7) mu0 (docs/rendering.md, "Overcast
    # accuracy"); rays looking down keep Eq. 21 as printed.
    low_factor = (1 - w_above) * diffuse_transmission_factor(mu0) + w_above
    phase = effective_phase_function(cos_theta[:, None], cos_view_zenith[:, None], tau[:, None], t_mean[:, None],
                                     weights[:, None, :], consts["g_liquid"][None, :], low_factor)
    eq12 = (-jnp.expm1(-tau) / safe)[:, None] * state["i_gas"]
    # Thin-cloud term (c1 P_thin) with the forward (diffraction) peak kept in the beam: Eq. 12's 1 - e^{-tau}
    # delta-scaled to (1 - e^{-(1 - f) tau}) / (1 - f) (docs/rendering.md, "Overcast accuracy").
    eq12_thin = (delta_scaled_path_factor(tau) / safe)[:, None] * state["i_gas"]
    c1 = blend_coefficient(tau, t_mean)
    p_thin = phase_thin_mixture(cos_theta[:, None], tau[:, None], weights[:, None, :], consts["g_liquid"][None, :])
    p_rest = p_thin - forward_peak_mixture(cos_theta[:, None], tau[:, None], weights[:, None, :], consts["g_liquid"][None, :])
    l_12 = phase * eq12 + c1[:, None] * p_rest * (eq12_thin - eq12)
    # Seen from above (docs/rendering.md, "Overcast accuracy"): the thin part of Eq. 13 (c1 P_thin, Eq. 12)
    # plus, in place of its thick part (Eqs. 19-21, cloud sides and bases), the cloud-top reflection of
    # Eqs. 24-26, (1 - c1) a 4 mu0 ARF E_top: the albedo a = 1 - T of the layer seen (delta-Eddington, as in
    # Step 1a, along the sun path tau_s = tau mu_view / mu0) and the irradiance incident on the cloud top,
    # E_top = E / T_self (Eq. 12's mean E over the top two optical depths already carries the cloud's own
    # extinction, which the reflection function ARF includes).
    b_eff = weights @ consts["backscatter"]
    mu_down = jnp.maximum(mu_view_down, FROM_ABOVE_BLEND)
    mu0_top = jnp.maximum(mu0, TOP_MIN_MU0)
    tau_s = tau * mu_down / mu0_top
    albedo_cloud = 1.0 - transmittance_delta_eddington(tau_s, b_eff * tau_s, mu0_top)
    lim = jnp.minimum(tau, 2.0)
    depth = (1.0 - (1.0 + lim) * jnp.exp(-lim)) / safe  # Eq. 12's e^{-tau_o}-weighted mean tau_o
    depth_s = depth * mu_down / mu0_top
    t_self = jnp.maximum(transmittance_delta_eddington(depth_s, b_eff * depth_s, mu0_top), TOP_MIN_SELF_TRANSMITTANCE)
    arf = anisotropic_reflectance_factor_kokhanovsky2004(mu_down, jnp.maximum(mu0, TOP_REFLECTANCE_MIN_MU0), cos_theta)
    gas_to_cloud = state["i_gas"] / jnp.maximum(state["i_nogas"], 1e-30)
    l_top = 4.0 * jnp.maximum(mu0, 0.0) * arf[:, None] * (e_mean / t_self[:, None]) * gas_to_cloud
    l_above = c1[:, None] * p_thin * eq12 + ((1 - c1) * albedo_cloud)[:, None] * l_top
    l_cloud = jnp.where(tau[:, None] > 1e-6, (1 - w_above) * l_12 + w_above * l_above, 0.0)

    radiance = state["l_clear"] + l_cloud + l_surface
    radiance = jnp.where(valid[:, None], radiance, 0.0)
    return {
        "radiance": radiance,
        "radiance_clear": state["l_clear"],
        "radiance_cloud": l_cloud,
        "radiance_surface": l_surface,
        "tau_hydrometeor": tau,
        "tau_clear": state["tau_clear"],
        "surface": surface,
        "distance": jnp.where(surface, s_hit, jnp.nan),
    }


@exported_jit(static_argnames=("settings",))  # a new process reads the traced program (~1.1 s on a CPU)
def _trace_chunk(start, direction, bounds, ends_on_ground, valid, rays, consts, settings: MarchSettings, probes=None):
    """One chunk of rays through the JAX kernel: set-up, lockstep march and composition in one program
    (``probes``: see :func:`_march_rays`)."""
    aerosol_class, ms = _prepare_rays(start, direction, bounds, consts, settings)
    state = _march_rays(start, direction, bounds, valid, rays, consts, settings, aerosol_class, ms, probes)
    return _compose(start, direction, bounds, ends_on_ground, valid, rays, consts, settings, state, aerosol_class)


_prepare_chunk = exported_jit(_prepare_rays, static_argnames=("settings",))


@exported_jit(static_argnames=("n_probe", "probe_spacing"))
def _probe_counts_chunk(start, direction, bounds, consts, n_probe, probe_spacing):
    return probe_counts_and_cells(start, direction, bounds[:, 0], bounds[:, 1] - bounds[:, 0], consts, n_probe,
                                  probe_spacing)


def _chunk_probes(start, direction, bounds, consts, settings: MarchSettings):
    """Settings and per-ray probes for one chunk of the lockstep kernel: each ray's count of :func:`probe_counts`
    and its grid segment's length in cells (:func:`probe_counts_and_cells`), and ``n_probe`` raised to the next
    power of two above the chunk's largest count (so that a few compiled versions serve every chunk)."""
    if not settings.probe_spacing or not settings.n_grid:
        return settings, None
    probes, cells = _probe_counts_chunk(start, direction, bounds, consts, settings.n_probe,
                                        float(settings.probe_spacing))
    return with_probes_for(settings, int(jnp.max(probes))), (probes, cells)


def with_probes_for(settings: MarchSettings, most: int) -> MarchSettings:
    """``settings`` whose ``n_probe`` holds a chunk whose rays take at most ``most`` probes: raised to the next power
    of two above it (at most :data:`MAX_PROBES`), so that a few compiled versions serve every chunk."""
    if most > settings.n_probe:
        settings = replace(settings, n_probe=int(min(MAX_PROBES, 1 << int(np.ceil(np.log2(most))))))
    return settings


_compose_chunk = exported_jit(_compose, static_argnames=("settings", "ground"))


def surface_beyond_edge(clamped, outside, ny, nx, j, i):
    """The ground's fields at indices (j, i) (n,) of the extended fields (the grid with its margin,
    :func:`swim.rt.march_inputs.extended_surface`, ny x nx), anywhere: inside them ``clamped`` (n, C), their bilinear
    lookup; beyond them a fade, with the distance d [cells] from their edge, from the nearest edge cell's values
    (``clamped``, the lookup at the clamped indices) to ``outside`` (C,) (:func:`surface_fields_outside`), weight
    e^(-d / L) with L of :func:`surface_fade_cells`. The margin has already faded most of the way to ``outside``
    (smoothed along the grid's edge, so that no edge feature runs on as a streak); the fade keeps the ground
    continuous at the margin's edge."""
    dj = jnp.maximum(jnp.maximum(-j, j - (ny - 1)), 0.0)
    di = jnp.maximum(jnp.maximum(-i, i - (nx - 1)), 0.0)
    w = jnp.exp(-jnp.sqrt(dj * dj + di * di)[:, None] / surface_fade_cells(clamped.shape[-1])[None, :])
    return outside[None, :] + (clamped - outside[None, :]) * w


def _jax_cloud_constants(consts):
    """``consts`` without the 3-D cloud scattering's host-only entries (:data:`swim.rt.clouds.CLOUD_HOST_KEYS`)
    and with its arrays on the device, once per render (a jitted call would copy a numpy array every time)."""
    if not three_d(consts):
        return consts
    out = {key: value for key, value in consts.items() if key not in CLOUD_HOST_KEYS}
    for key in (*CLOUD_KERNEL_KEYS, "ms_coarsen"):
        out[key] = jnp.asarray(np.asarray(out[key], np.float32))
    return out


#: Device copies of the last kernel constants' small arrays (those not in :data:`HOST_CONSTANTS`).
_SMALL_COPIES = {}


def _device_constants(consts):
    """``consts`` with its arrays as JAX device arrays, for the JAX kernel: those of :data:`HOST_CONSTANTS` and the
    small ones each in their own :func:`swim.rt.device_copies.device_copies` cache (on a GPU the volume's one
    transfer; the renders of one scene and sun share the copies), the ``index_map`` entries converted each time."""
    host = {key: consts[key] for key in HOST_CONSTANTS}
    small = {key: value for key, value in consts.items()
             if key not in HOST_CONSTANTS and isinstance(value, np.ndarray)}
    out = {**consts, **device_copies(host, jnp.asarray, _DEVICE_COPIES)}
    if small:
        out.update(device_copies(small, jnp.asarray, _SMALL_COPIES))
    if isinstance(consts.get("index_map"), dict):
        out["index_map"] = {key: jnp.asarray(value) for key, value in consts["index_map"].items()}
    return out


def chunk_marcher(consts, settings):
    """The JAX kernel's march of chunks for :func:`swim.rt.march.trace_rays`, with the constants on the device once.

    Returns a function of a chunk's padded inputs (``args``: start, direction, bounds, ends_on_ground, valid, numpy),
    its rays' phase arrays (``rays``: name -> numpy) and its number ``n`` of real rays. It computes the chunk's probes
    at once (on the caller's thread) and returns the march as a function of no arguments, which returns the first
    ``n`` rays' outputs as numpy arrays (:func:`_trace_chunk`)."""
    from .march_pallas import with_vector_volume

    # the probes' program takes the constants as the ray table's build gives them (one compiled program for both),
    # the march those and the fused kernel's padded volume
    probe_consts = _device_constants(_jax_cloud_constants(consts))
    march_consts = with_vector_volume(probe_consts, settings)

    def prepare(args, rays, n):
        args = list(map(jnp.asarray, args))
        rays = {key: jnp.asarray(value) for key, value in rays.items()}
        return functools.partial(_trace_chunk_jax, args, rays, march_consts,
                                 *_chunk_probes(*args[:3], probe_consts, settings), n)

    return prepare


def _host_rows(out, n):
    """The first n rows of a chunk's device outputs as host arrays (waits for the device)."""
    # one device_get starts every output's copy before waiting for any: on an H100 a warm 1024^2 adaptive frame took
    # 10-25 ms less than with one blocking copy per output (docs/decisions/0006-gpu-kernels.md)
    return {key: value[:n] for key, value in jax.device_get(out).items()}


def _trace_chunk_jax(args, rays, consts, settings, probes, n):
    """One chunk through the JAX kernel (:func:`_trace_chunk`), its first ``n`` rows' outputs as host arrays."""
    return _host_rows(_trace_chunk(*args, rays, consts, settings, probes), n)
