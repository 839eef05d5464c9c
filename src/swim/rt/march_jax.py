"""The march's JAX kernel: chunks of rays marched in lockstep, jit-compiled once per batch size (GPUs; gradients).

The same steps, sources and composition as the numba kernel (:mod:`swim.rt.march_cpu`, the CPU's default), written
with ``jax.numpy``: the lookups of the scene's tables, the segment march (:func:`_march_segment`,
:func:`_march_grid_refined`) and the chunk's stages (:func:`_trace_chunk`) here, the step placement
(:func:`grid_step_edges`, :func:`clear_step_edges`) in :mod:`swim.rt.march_jax_steps` and the clouds' and the ground's
composition (:func:`_compose`) in :mod:`swim.rt.march_jax_compose`. :func:`swim.rt.march.trace_rays` calls it for
``ExecutionSettings(backend="jax")``; only then is JAX imported.
"""

from __future__ import annotations

import functools
import logging
from dataclasses import replace
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..constants import DIFFUSE_SUN_T_MIN, GAS_COLUMN_ROW
from ..optics.volume import grid_indices
from .clouds import CLOUD_HOST_KEYS, CLOUD_KERNEL_KEYS, three_d
from .clouds_device import cloud_sources, ratio_above_grid
from ..compilation.jax_export import exported_jit
from .device_copies import _DEVICE_COPIES, device_copies
from .march_inputs import HOST_CONSTANTS, packed_aerosol_3d
# the step placement and the composition, imported back for the march and for the modules and tests that take them
# from here
from .march_jax_compose import (_compose, _compose_clouds, _compose_three_d, _ground_radiance,  # noqa: F401
                                surface_beyond_edge)
from .march_jax_steps import (adaptive_step_edges, after_step_counts, clear_step_edges,  # noqa: F401
                              grid_step_edges, probe_counts, probe_counts_and_cells, segment_cells)
from .march_settings import (GRID_LOOP_UNROLL_ACCELERATOR, MAX_PROBES, MarchSettings, REFINE_BUDGET, REFINE_DEPTH,
                             REFINE_SLOTS, REFINE_VISIBLE_TAU, SKYLIGHT_SCALAR_FACTOR, TERRAIN_BISECTIONS)

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

    Returns the Rayleigh, background-aerosol and stratospheric-aerosol extinction and ozone's absorption
    coefficient (n, 3) [m-1] (one lookup in a joint height table of their profiles, times their spectral factors:
    each is a height profile times a spectrum; ozone absorbs only, :mod:`swim.optics.ozone`), and the sun
    transmittance and horizontal diffuse irradiance / E_TOA (n, 3) each (one bilinear lookup in the joint
    (height, mu_s) table).
    """
    profile = _lerp_table(consts["beta_gas"][:GAS_COLUMN_ROW], h / consts["dh"])
    spectra = consts["beta_gas_spectra"]  # (4 components, 3 wavelengths)
    beta = jnp.concatenate([profile[:, c : c + 1] * spectra[c][None, :] for c in range(GAS_COLUMN_ROW)], axis=-1)
    nu, nmu = consts["sky"].shape[1:]
    fu = jnp.sqrt(jnp.clip(h / consts["top"], 0.0, 1.0)) * (nu - 1)
    fm = (mu_s + 1.0) * 0.5 * (nmu - 1)
    sky = _bilinear_table(consts["sky"], fu, fm)
    return beta[:, :3], beta[:, 3:6], beta[:, 6:9], beta[:, 9:], sky[:, :3], sky[:, 3:]


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
    t_s = jnp.sign(mu_s) * jnp.sqrt(jnp.clip(jnp.abs(mu_s), 0.0, 1.0))  # the table's sun axis, down to the night
    fs = jnp.clip((t_s - DIFFUSE_SUN_T_MIN) / (1.0 - DIFFUSE_SUN_T_MIN) * (n_s - 1), 0.0, n_s - 1.001)
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


class _SegmentInputs(NamedTuple):
    """What each sample of one segment of :func:`_march_segment` reads besides the state: the rays (rebased ``start``
    (n, 3) [m], unit ``direction`` (n, 3), their phase functions ``rays``), the kernel constants, the diffuse-source
    profiles ``ms_profile`` (or None) and ``aerosol_class``, the segment's static switches (``in_grid``: the volume
    is sampled; ``terminal``: the steps of :func:`_terminal_step`; ``stop_tau``) and ``outside``, the volume's
    channels beyond it (made once, outside the segment's loop)."""

    start: object
    direction: object
    rays: dict
    consts: dict
    ms_profile: object
    aerosol_class: tuple
    in_grid: bool
    terminal: bool
    stop_tau: float
    outside: object


def _sample_medium(seg, st, s):
    """The medium at each ray's sample at ``s`` (n,) [m] of :func:`_sample_step`: the point's geometry, the gas's and
    the volume's lookups and whether the ray meets the ground in this step (``hit_now``, the crossing's fraction
    ``frac`` of the step), as a dict of arrays."""
    consts = seg.consts
    n_c = consts["volume"].shape[-1]
    n_sp = consts["species_matrix"].shape[0]  # the packed species (packed_species)
    aerosol_3d = packed_aerosol_3d(n_c, n_sp)  # packed only where it is not zero
    q = seg.start + s[:, None] * seg.direction
    h, mu_s, k, j, i = _point_geometry(q, consts)
    beta_r, beta_a, beta_s, beta_o, t_sun, diffuse = _gas_at(h, mu_s, consts)
    if seg.in_grid:
        v = trilinear(consts["volume"], k, j, i, seg.outside)
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
        hit_now = st["alive"] & (gap < 0) & (not seg.terminal)
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
    return {"h": h, "mu_s": mu_s, "k": k, "j": j, "i": i, "beta_r": beta_r, "beta_a": beta_a, "beta_s": beta_s,
            "beta_o": beta_o, "t_sun": t_sun, "diffuse": diffuse, "beta_sp": beta_sp, "t_cloud": t_cloud,
            "shadow": shadow, "beta_a3": beta_a3, "t_aerosol": t_aerosol, "gap": gap, "hit_now": hit_now, "frac": frac}


def _sample_light(seg, st, at, ds):
    """The light and extinction of a sample of :func:`_sample_step` from its medium ``at`` (:func:`_sample_medium`):
    the step's effective length ``ds_eff``, the irradiance that lights the gas and the hydrometeors, the extinctions
    and, with the 3-D cloud scattering, the hydrometeors' sources (a dict of arrays)."""
    consts = seg.consts
    clouds_3d = three_d(consts)  # cloud_scattering="discrete_ordinates" (swim.rt.clouds_device)
    h, mu_s, k, j, i, t_cloud = at["h"], at["mu_s"], at["k"], at["j"], at["i"], at["t_cloud"]
    beta_sp, diffuse = at["beta_sp"], at["diffuse"]
    # the step in which the ray meets the ground adds nothing here: its sample may lie deep inside the
    # terrain; the terminal step (_terminal_step) covers it up to the refined crossing
    ds_eff = jnp.where(st["alive"] & ~at["hit_now"], ds, 0.0)
    # direct beam / E_TOA, lights the gas and aerosol (Eq. 3): gas, hydrometeors (T), 3-D aerosol
    irradiance = at["t_sun"] * (t_cloud * at["shadow"])[:, None] * at["t_aerosol"]
    if seg.in_grid:
        # Clear-sky diffuse scalar irradiance / E_TOA, through the clouds above (T of Step 1a); with
        # aerosol column classes, that of the ray's class.
        if consts["class_aod"].shape[0] > 1:
            diffuse = diffuse_at(h, mu_s, seg.aerosol_class, consts)
        skylight = SKYLIGHT_SCALAR_FACTOR * diffuse * t_cloud[:, None]
    # Scalar irradiance of Eq. 8 ("direct + scattered") lighting the hydrometeors.
    irradiance_h = irradiance + skylight if seg.in_grid else irradiance
    # the clear air's extinction: its scattering components' and ozone's absorption (which adds no source)
    beta_clear = at["beta_r"] + at["beta_a"] + at["beta_a3"] + at["beta_s"] + at["beta_o"]
    beta_h = beta_sp.sum(axis=1)
    # the extinction that dims the light on its way to the observer: with the 3-D cloud scattering the
    # hydrometeors' delta-M scaled one (the forward peak's light stays in the view), whose sources are
    # integrated along the ray; the diffuse solution's ratio to the clear sky dims the air's diffuse source
    beta_view, dims_diffuse, cloud_source = beta_h, t_cloud[:, None], None
    if clouds_3d and seg.in_grid:
        dims_diffuse, cloud_source, beta_view = cloud_sources(beta_sp, k, j, i, t_cloud, irradiance, seg.rays, consts)
    elif clouds_3d:
        dims_diffuse = ratio_above_grid(h, k, j, i, consts, consts["volume"].shape[:3])
    return {"ds_eff": ds_eff, "irradiance": irradiance, "irradiance_h": irradiance_h, "beta_clear": beta_clear,
            "beta_h": beta_h, "beta_view": beta_view, "dims_diffuse": dims_diffuse, "cloud_source": cloud_source}


def _sample_clear_sky(seg, st, at, light):
    """The clear sky's radiance ``l_clear`` (n, 3) after a sample of :func:`_sample_step` (Eq. 3: single scattering
    and, with ``ms_profile``, the diffuse source), the step's mean attenuation ``step_mean`` and the transmittance
    ``t_obs`` to the observer."""
    consts, rays = seg.consts, seg.rays
    clouds_3d = three_d(consts)
    beta_r, beta_a, beta_s, beta_a3 = at["beta_r"], at["beta_a"], at["beta_s"], at["beta_a3"]
    ds_eff = light["ds_eff"]
    x = (light["beta_clear"] + light["beta_view"][:, None]) * ds_eff[:, None]
    # (1 - e^-x) / x, also for the terminal step's negative x (a step back)
    big = jnp.abs(x) > 1e-4
    step_mean = jnp.where(big, -jnp.expm1(-x) / jnp.where(big, x, 1.0), 1.0 - 0.5 * x)
    t_obs = jnp.exp(-(st["tau_clear"] + (st["tau_view"] if clouds_3d else st["tau_h"])[:, None]))
    scat_a = (beta_a + beta_a3) * consts["aerosol_ssa"]
    scat_s = beta_s * consts["stratospheric_ssa"]
    source = (beta_r * rays["p_rayleigh"][:, None] + scat_a * rays["p_aerosol"]
              + scat_s * rays["p_stratospheric"]) * light["irradiance"]
    if seg.ms_profile is not None:
        # Orders >= 2: the diffuse source of the successive-orders table (molecules, aerosol,
        # stratospheric aerosol), dimmed under clouds by their transmittance like the skylight.
        j = _profile_at(seg.ms_profile, at["h"], consts)
        source = source + (beta_r * j[:, :3] + scat_a * j[:, 3:6] + scat_s * j[:, 6:]) * light["dims_diffuse"]
    l_clear = st["l_clear"] + t_obs * source * (ds_eff[:, None] * step_mean)
    return l_clear, step_mean, t_obs


def _sample_hydrometeors(seg, st, at, light, step_mean, t_obs):
    """The hydrometeors' sums after a sample of :func:`_sample_step`: their optical depth ``t1`` (n,) and Eq. 12's
    integrands over their first two optical depths (``i_nogas``, ``i_gas``, ``i_cloud_t``), or with the 3-D cloud
    scattering their radiance integrated along the ray (``extra``: ``tau_view``, ``l_cloud``)."""
    ds_eff, t_cloud = light["ds_eff"], at["t_cloud"]
    # Eq. 12 integrand over the first two optical depths of hydrometeors.
    t0 = st["tau_h"]
    t1 = t0 + light["beta_h"] * ds_eff
    if three_d(seg.consts):  # the clouds' light is integrated along the ray (swim.rt.clouds), not composed by Eq. 12
        i_nogas, i_gas, i_cloud_t = st["i_nogas"], st["i_gas"], st["i_cloud_t"]
        extra = {"tau_view": st["tau_view"] + light["beta_view"] * ds_eff, "l_cloud": st["l_cloud"]}
        if seg.in_grid:
            extra["l_cloud"] = st["l_cloud"] + t_obs * light["cloud_source"] * (ds_eff[:, None] * step_mean)
    else:
        irradiance_h = light["irradiance_h"]
        weight = jnp.exp(-jnp.minimum(t0, 2.0)) - jnp.exp(-jnp.minimum(t1, 2.0))
        # negative for a step back; where(w >= 0), not maximum(w, 0): the same values, and the derivative of w where it
        # is 0 (a step through no cloud), not half of it
        weight = jnp.where(t1 >= t0, jnp.where(weight >= 0.0, weight, 0.0), weight)
        i_nogas = st["i_nogas"] + irradiance_h * weight[:, None]
        i_gas = st["i_gas"] + irradiance_h * jnp.exp(-st["tau_clear"]) * weight[:, None]
        i_cloud_t = st["i_cloud_t"] + t_cloud * at["shadow"] * weight
        extra = {}
    return t1, i_nogas, i_gas, i_cloud_t, extra


def _sample_step(seg, st, s_lo, ds):
    """:func:`_march_segment`'s sample: the state after a step of length ``ds`` (n,) from ``s_lo`` (n,) [m] of the
    segment ``seg`` (:class:`_SegmentInputs`), and the step's hydrometeor extinction (n,) [1/m]."""
    s = s_lo + 0.5 * ds
    if seg.terminal:  # the step back takes back what the step before added: at that step's sample
        s = jnp.where(ds < 0, st["hit_lo"], s)
    at = _sample_medium(seg, st, s)
    light = _sample_light(seg, st, at, ds)
    l_clear, step_mean, t_obs = _sample_clear_sky(seg, st, at, light)
    t1, i_nogas, i_gas, i_cloud_t, extra = _sample_hydrometeors(seg, st, at, light, step_mean, t_obs)
    hit_now, frac, ds_eff, stop_tau = at["hit_now"], at["frac"], light["ds_eff"], seg.stop_tau
    hit_s = jnp.where(hit_now, s - 0.5 * ds + frac * ds, st["hit_s"])
    # bracket of the crossing for the bisection after the march: the previous sample (above) and this one
    hit_lo = jnp.where(hit_now, st["s_last"], st["hit_lo"])
    hit_hi = jnp.where(hit_now, s, st["hit_hi"])
    hit_from = jnp.where(hit_now, s_lo, st["hit_from"])
    tau_species = st["tau_species"] + at["beta_sp"] * ds_eff[:, None]
    alive = st["alive"] & ~hit_now
    if seg.in_grid and stop_tau > 0:
        # opaque (MarchSettings.stop_tau): the ray stops at stop_tau, its species in the proportions they had
        # there; past REFINE_VISIBLE_TAU before the step, so that no roll-back can undo it
        t0 = st["tau_h"]
        stopped = alive & (t1 > stop_tau) & (t0 >= REFINE_VISIBLE_TAU) & (seg.direction[:, 2] >= 0)
        tau_species = jnp.where(stopped[:, None], tau_species * (stop_tau / jnp.maximum(t1, stop_tau))[:, None],
                                tau_species)
        t1 = jnp.where(stopped, jnp.asarray(stop_tau, t1.dtype), t1)
        alive = alive & ~stopped
    return {
        "tau_clear": st["tau_clear"] + light["beta_clear"] * ds_eff[:, None],
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
        "gap": at["gap"],
        "s_last": s,
        **extra,
    }, light["beta_h"]


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
    n_c = consts["volume"].shape[-1]
    outside = jnp.concatenate([jnp.zeros(n_c - 2), jnp.ones(2)]).astype(jnp.float32)
    seg = _SegmentInputs(start, direction, rays, consts, ms_profile, aerosol_class, in_grid, terminal, stop_tau,
                         outside)

    def sample(st, s_lo, ds):
        """The state after a step of length ``ds`` from ``s_lo`` [m], and the step's hydrometeor extinction."""
        return _sample_step(seg, st, s_lo, ds)

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


def _rows(mask, value):
    """A per-ray ``mask`` (n,) shaped to select rows of ``value`` (n, ...)."""
    return mask.reshape(mask.shape[:1] + (1,) * (value.ndim - 1))


def _next_interval(carry, edges, last, col, tau_refine):
    """The interval that each ray of :func:`_march_grid_refined` takes next: the last pending one, or its next step,
    halved before it is sampled where the interval before it predicts it too thick (:func:`_predicted_halving`: its
    second half pushed, pending). Returns (lo, hi, ds, depth, base, adjacent, done, stacked) and the pending stack
    and budget after the halving."""
    st, m, pending, stack_lo, stack_hi, stack_depth, budget, _, prev = carry
    slots = stack_lo.shape[1]
    stacked = pending > 0
    top = jnp.maximum(pending - 1, 0)[:, None]
    next_step = jnp.minimum(m, last - 1)[None, :]
    done = (~stacked & (m >= last)) | ~st["alive"]
    lo = jnp.where(stacked, jnp.take_along_axis(stack_lo, top, 1)[:, 0], jnp.take_along_axis(edges, next_step, 0)[0])
    hi = jnp.where(stacked, jnp.take_along_axis(stack_hi, top, 1)[:, 0],
                   jnp.take_along_axis(edges, next_step + 1, 0)[0])
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
    return (lo, hi, ds, depth, base, adjacent, done, stacked), (stack_lo, stack_hi, stack_depth, budget)


def _push_pending(stacks, col, interval, prev, refine, rollback):
    """The pending stacks (lo, hi, depth; each (n, slots)) of :func:`_march_grid_refined` after a ray's interval
    (lo, hi, ds, depth, base) was split (``refine``) or rolled back (``rollback``)."""
    stack_lo, stack_hi, stack_depth = stacks
    lo, hi, ds, depth, base = interval
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
    return stack_lo, stack_hi, stack_depth


def _refined_iteration(carry, sample, edges, last, col, tau_refine):
    """One iteration of :func:`_march_grid_refined` for every ray: take the next interval, sample it and accumulate
    it, push its halves or roll back. ``carry``: (state, steps taken, pending count, the pending stack's lo, hi and
    depth, refinement budget, the state's snapshot, the accumulated interval before)."""
    st, m, pending, stack_lo, stack_hi, stack_depth, budget, saved, prev = carry
    slots = stack_lo.shape[1]
    interval, stacks = _next_interval(carry, edges, last, col, tau_refine)
    lo, hi, ds, depth, base, adjacent, done, stacked = interval
    stack_lo, stack_hi, stack_depth, budget = stacks
    new, beta_h = sample(st, lo, ds)
    live = ~done & (budget > 0) & st["alive"]
    change = jnp.where(adjacent, jnp.abs(beta_h - prev["beta_h"]), 0.0)
    rollback = (live & adjacent & (prev["depth"] < REFINE_DEPTH) & (change * (prev["hi"] - prev["lo"]) > tau_refine)
                & (base + 3 <= slots) & (saved["tau_h"] < REFINE_VISIBLE_TAU))
    refine = (live & ~rollback & (depth < REFINE_DEPTH) & (st["tau_h"] < REFINE_VISIBLE_TAU) & (base + 2 <= slots)
              & (jnp.maximum(beta_h, change) * ds > tau_refine))
    keep = ~done & ~refine & ~rollback
    save = keep & live
    saved = {key: jnp.where(_rows(save, value), st[key], value) for key, value in saved.items()}
    # a rolled-back ray's snapshot is not overwritten above (save needs keep)
    st = {key: jnp.where(_rows(keep, value), value, jnp.where(_rows(rollback, value), saved[key], st[key]))
          for key, value in new.items()}
    stack_lo, stack_hi, stack_depth = _push_pending((stack_lo, stack_hi, stack_depth), col,
                                                    (lo, hi, ds, depth, base), prev, refine, rollback)
    prev = {"valid": jnp.where(save, True, prev["valid"] & ~rollback), "lo": jnp.where(save, lo, prev["lo"]),
            "hi": jnp.where(save, hi, prev["hi"]), "beta_h": jnp.where(save, beta_h, prev["beta_h"]),
            "depth": jnp.where(save, depth, prev["depth"])}
    pending = base + 2 * refine + 3 * rollback
    return (st, m + (~stacked & ~done), pending, stack_lo, stack_hi, stack_depth, budget - refine - rollback,
            saved, prev)


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

    def body(carry):
        return _refined_iteration(carry, sample, edges, last, col, tau_refine)

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
    fused_options = {"max_registers": settings.execution.fused_max_registers,
                     "vector_loads": settings.execution.fused_vector_loads,
                     "fma": settings.execution.fused_fma}
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
