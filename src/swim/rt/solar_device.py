"""Step 1a for a new sun on the device: the packed volume's Step 1a channels refilled where the JAX kernel marches.

On a GPU, a new sun (a time series seen by a fixed camera) made on the host costs ~1.3 GB of transfers between the host
and the device for the 400 x 400 x 60 scene's 160 levels: the sweep's input (the species' sums, made on the host's
cores) to the device, the swept optical depths back, and then the whole packed volume (0.7 GB) to the device again,
because its Step 1a channels have changed on the host (docs/decisions/0006-gpu-kernels.md: 0.29-0.36 s of Step 1a and
0.08-0.12 s of the volume's copy in a 0.58 s frame on an H100). The packed volume's grid channels (the extinctions) do
not depend on the sun, and the previous sun's device copy holds them. :func:`refill_step1a_channels` makes the sweep's
input from them on the device, sweeps it there (:func:`swim.rt.solar._sweep`, the same program as the host's JAX path),
computes T, the terrain's shadow and the 3-D aerosol's optical depth there (as :func:`swim.rt.solar_cpu.step1a_channels`
does on the host, in float32) and writes them into the device copy's channels. Only the new channels come back, for the
host's packed volume (the numba kernel, the ground's fields and a later render read them): ~0.2 GB, once.

The same equations and the same sweep as :func:`swim.rt.solar.solar_transmittance`; the species' sums may round
differently in float32 (the order of a reduction), so the channels agree to float32 round-off
(``tests/unit/rt/test_rt_solar_device.py``).

References
----------
Albers et al. (2020), doi:10.5194/amt-13-3235-2020, Sect. 3.4, Eqs. 4-8 (Step 1a); Joseph et al. (1976),
doi:10.1175/1520-0469(1976)033<2452:TDEAFR>2.0.CO;2 (T, :func:`swim.rt.solar.transmittance_delta_eddington`).
"""

from __future__ import annotations

import functools
import logging

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import SwimInputError
from ..compilation.jax_export import exported_jit
from .march_inputs import KERNEL_STEP1A_VARIABLES, packed_aerosol_3d, step1a_channel_names, step1a_channel_views
from .solar import (ABOVE_SWEPT, DIRECT_LEVELS, STEP1A_ATTRS, TERRAIN_OPACITY_PER_CELL, backscatter_weights,
                    column_sweep_geometry, per_column_sun, sweep_geometry, swept_levels,
                    transmittance_delta_eddington)

log = logging.getLogger(__name__)


def _bilinear_zero_outside(field, jj, ii):
    """Bilinear sample of (C, ny, nx) fields at fractional (jj, ii) of shape (ny, nx); zero outside."""
    ny, nx = field.shape[-2:]
    inside = (jj >= 0) & (jj <= ny - 1) & (ii >= 0) & (ii <= nx - 1)
    j0 = jnp.clip(jnp.floor(jj), 0, ny - 2).astype(jnp.int32)
    i0 = jnp.clip(jnp.floor(ii), 0, nx - 2).astype(jnp.int32)
    fj = jnp.clip(jj - j0, 0.0, 1.0)
    fi = jnp.clip(ii - i0, 0.0, 1.0)
    v = (field[..., j0, i0] * (1 - fj) * (1 - fi) + field[..., j0, i0 + 1] * (1 - fj) * fi
         + field[..., j0 + 1, i0] * fj * (1 - fi) + field[..., j0 + 1, i0 + 1] * fj * fi)
    return jnp.where(inside, v, 0.0)


@exported_jit(static_argnames=("n_sub", "block"))
def _sweep(fields, di, dj, path_per_level, n_sub, block=DIRECT_LEVELS):
    """Sweep (C, nk, ny, nx) extinction fields along the sun; returns optical depths (nk, C, ny, nx) (the
    order the sweep builds them in: a transpose would copy them).

    tau(k) = integral of the extinction from level k up to level min(k + block, top) along the sun ray
    (sampled directly, n_sub points per level) + tau of that level, bilinearly interpolated where the
    ray crosses it.
    """
    c, nk, ny, nx = fields.shape
    jj, ii = jnp.meshgrid(jnp.arange(ny, dtype=jnp.float32), jnp.arange(nx, dtype=jnp.float32), indexing="ij")
    ts = (jnp.arange(n_sub, dtype=jnp.float32) + 0.5) / n_sub

    def level(k, taus):
        def one_level(m, acc):
            lo = jnp.minimum(k + m, nk - 2)
            lower = jax.lax.dynamic_index_in_dim(fields, lo, axis=1, keepdims=False)
            upper = jax.lax.dynamic_index_in_dim(fields, lo + 1, axis=1, keepdims=False)
            active = (k + m + 1) <= (nk - 1)

            def sub(a, t):
                shift = m + t
                lo_v = _bilinear_zero_outside(lower, jj + shift * dj, ii + shift * di)
                up_v = _bilinear_zero_outside(upper, jj + shift * dj, ii + shift * di)
                return a + (1 - t) * lo_v + t * up_v, None

            seg, _ = jax.lax.scan(sub, jnp.zeros_like(acc), ts)
            return acc + jnp.where(active, seg, 0.0)

        direct = jax.lax.fori_loop(0, block, one_level, jnp.zeros((c, ny, nx), fields.dtype))
        top = jnp.minimum(k + block, nk - 1)
        above = jax.lax.dynamic_index_in_dim(taus, top, axis=0, keepdims=False)
        n_levels = (top - k).astype(jnp.float32)
        tau = _bilinear_zero_outside(above, jj + n_levels * dj, ii + n_levels * di) + direct * (path_per_level / n_sub)
        return jax.lax.dynamic_update_index_in_dim(taus, tau, k, axis=0)

    taus = jnp.zeros((nk, c, ny, nx), fields.dtype)
    taus = jax.lax.fori_loop(0, nk - 1, lambda n, t: level(nk - 2 - n, t), taus)
    return taus


def _channel_values(packed, weights, terrain, levels, dz, di, dj, path_per_level, mu0, n_species, aerosol_3d,
                    n_levels, n_sub, lit=None):
    """Step 1a's channels (levels, y, x, 2 or 3: [the 3-D aerosol's optical depth,] T, the terrain's shadow) of the
    device's packed volume (level, y, x, channel), all levels: swept up to ``n_levels``, above it T = 1, shadow 1 and
    the aerosol's optical depth 0 (what the sweep gives where every field is zero above). With each column's own sun
    (``di``, ``dj``, ``path_per_level``, ``mu0`` (y, x)), ``lit`` (y, x) float32 is 0 where a column gets no direct
    sun: its terrain shadow is 0 there (:func:`swim.rt.solar.column_sweep_geometry`)."""
    nk, ny, nx, _ = packed.shape
    names = step1a_channel_names(aerosol_3d)
    above = jnp.asarray([ABOVE_SWEPT[name] for name in names], jnp.float32)
    if lit is not None:  # the terrain shadow's channel (the last) times lit, on every level
        unlit = jnp.ones(above.shape, jnp.float32).at[-1].set(0.0)
        darken = unlit + (1.0 - unlit) * lit[..., None]  # (y, x, channels)
        values = _channel_values(packed, weights, terrain, levels, dz, di, dj, path_per_level, mu0, n_species,
                                 aerosol_3d, n_levels, n_sub)
        return values * darken
    if n_levels == 0:  # nothing to sweep (no cloud, no terrain above the lowest level, no 3-D aerosol)
        return jnp.broadcast_to(above, (nk, ny, nx, above.size))
    grid = packed[:n_levels]
    extinction = grid[..., :n_species]
    # the species one after the other, as swim.rt.solar_cpu.species_sums adds them
    total = jnp.zeros(grid.shape[:-1], jnp.float32)
    weighted = jnp.zeros(grid.shape[:-1], jnp.float32)
    for s in range(n_species):
        total = total + extinction[..., s]
        weighted = weighted + weights[s] * extinction[..., s]
    shade = jnp.clip((terrain[None] - levels[:n_levels, None, None]) / dz, 0.0, 1.0) * (TERRAIN_OPACITY_PER_CELL / dz)
    fields = [total, weighted, shade.astype(jnp.float32)] + ([grid[..., n_species]] if aerosol_3d else [])
    taus = _sweep(jnp.stack(fields), di, dj, path_per_level, n_sub, DIRECT_LEVELS)  # (n_levels, C, ny, nx)
    cloud_t = transmittance_delta_eddington(taus[:, 0], taus[:, 1], mu0).astype(jnp.float32)
    shadow = jnp.exp(-taus[:, 2])
    by_name = {"cloud_transmittance": cloud_t, "terrain_shadow": shadow}
    if aerosol_3d:
        by_name["aerosol_tau_sun"] = taus[:, 3]
    swept = jnp.stack([by_name[name] for name in names], axis=-1)
    rest = jnp.broadcast_to(above, (nk - n_levels, ny, nx, above.size))
    return jnp.concatenate([swept, rest], axis=0)


def _refill(packed, weights, terrain, levels, dz, di, dj, path_per_level, mu0, n_species, aerosol_3d, n_levels,
            n_sub, lit=None):
    values = _channel_values(packed, weights, terrain, levels, dz, di, dj, path_per_level, mu0, n_species,
                             aerosol_3d, n_levels, n_sub, lit)
    first = packed.shape[-1] - values.shape[-1]
    return packed.at[..., first:].set(values), values[:n_levels]


_STATIC = ("n_species", "aerosol_3d", "n_levels", "n_sub")
#: The refill compiled; on a GPU the old copy's memory is reused for the new one (donated), so a new sun never holds
#: two packed volumes on the device. Not on a CPU, where the kernel's "device copy" may share the host volume's
#: memory (JAX can take a NumPy array without copying it): the refill copies there.
_refill_donating = jax.jit(_refill, static_argnames=_STATIC, donate_argnums=(0,))
_refill_copying = jax.jit(_refill, static_argnames=_STATIC)


def refill_step1a_channels(device_packed, volume, sun_direction_scene, n_species, aerosol_3d, nonzero_levels):
    """A new sun's Step 1a channels written into the device's copy of a packed volume.

    Parameters
    ----------
    device_packed : jax.Array
        Shape (level, y, x, channel) float32: the device's copy of the packed volume
        (:func:`swim.rt.march_inputs.pack_volume`) with an earlier sun's Step 1a channels; its grid channels (the
        extinctions of ``n_species`` species, then with a 3-D aerosol its extinction) are read. On a GPU its memory is
        reused for the result: do not use it afterwards.
    volume : xarray.Dataset
        The optical volume (:func:`swim.optics.volume.build_optical_volume`, its extinctions shared with the packed
        volume: :func:`swim.rt.march_inputs.share_packed_channels`): its ``species`` coordinate (the packed species),
        ``level`` [m], ``terrain_height`` (y, x) [m] and the attributes ``dz`` [m] and ``affine_matrix``.
    sun_direction_scene : array_like
        Shape (3,): unit vector towards the sun in the scene frame; on a grid of :func:`swim.rt.solar.per_column_sun`
        each column takes it in its own local frame, as on the host (:func:`swim.rt.solar.column_sweep_geometry`).
    n_species : int
        Species channels at the front of the packed volume.
    aerosol_3d : bool
        Whether the packed volume holds the 3-D aerosol (its extinction and ``aerosol_tau_sun`` channels).
    nonzero_levels : tuple of numpy.ndarray
        The volume's :func:`swim.rt.solar.step1a_levels`: the fields are swept up to the highest level that any of them
        needs, as the host's JAX path sweeps them (:func:`swim.rt.solar.solar_transmittance`).

    Returns
    -------
    device_packed : jax.Array
        The packed volume with the new sun's Step 1a channels (:data:`swim.rt.march_inputs.KERNEL_STEP1A_VARIABLES`,
        without the aerosol's where it is not packed).
    swept : jax.Array
        Shape (n_levels, y, x, 2 or 3): those channels on the swept levels (above them T and the shadow are 1 and the
        aerosol's optical depth 0), for the host's copy.
    n_levels : int
        The swept levels.

    Raises
    ------
    SwimInputError
        If the sun's shift per level is not finite (as :func:`swim.rt.solar.solar_transmittance`), or the packed volume
        does not have the channels of ``n_species`` and ``aerosol_3d`` or the volume's shape.

    References
    ----------
    Albers et al. (2020), doi:10.5194/amt-13-3235-2020, Sect. 3.4, Eqs. 4-8.
    """
    sun = np.asarray(sun_direction_scene, dtype=float)
    nk = volume["level"].size
    shape = tuple(volume["terrain_height"].shape)
    channels = n_species + (4 if aerosol_3d else 2)
    if tuple(device_packed.shape) != (nk,) + shape + (channels,) or device_packed.dtype != jnp.float32:
        raise SwimInputError(f"refill_step1a_channels: the device's packed volume {tuple(device_packed.shape)} "
                             f"{device_packed.dtype} is not float32 of shape {(nk,) + shape + (channels,)}")
    lit = None
    if per_column_sun(volume):  # each column's own sun (a grid over a noticeable part of the sphere), as the host's
        di, dj, n_sub, path_per_level, mu0, lit = column_sweep_geometry(volume, sun, "refill_step1a_channels")
        lit = None if lit.all() else jnp.asarray(lit, jnp.float32)
        log.info("Step 1a on the device: each column's own sun (%d columns without direct sun)",
                 0 if lit is None else int(lit.size - np.asarray(lit).sum()))
    else:
        di, dj, n_sub, path_per_level, mu0 = sweep_geometry(volume, sun, "refill_step1a_channels")
    dz = float(volume.attrs["dz"])
    levels = volume["level"].values
    terrain = volume["terrain_height"].values
    hydro_levels, aerosol_levels = (np.asarray(a, bool) for a in nonzero_levels)
    tops = [hydro_levels, levels < terrain.max()] + ([aerosol_levels] if aerosol_3d else [])
    # as solar_transmittance's JAX path: every field to the highest field's top
    n_levels = max([swept_levels(t) for t in tops if t.any()], default=0)
    weights = backscatter_weights(volume)
    if weights.size != n_species:
        raise SwimInputError(f"refill_step1a_channels: the volume names {weights.size} species, the packed volume "
                             f"holds {n_species}")
    refill = _refill_copying if jax.default_backend() == "cpu" else _refill_donating
    f32 = functools.partial(jnp.asarray, dtype=jnp.float32)
    new, swept = refill(device_packed, f32(weights), f32(terrain), f32(levels), f32(dz), f32(di), f32(dj),
                        f32(path_per_level), f32(mu0), n_species=int(n_species), aerosol_3d=bool(aerosol_3d),
                        n_levels=int(n_levels), n_sub=n_sub, lit=lit)
    return new, swept, n_levels


def solar_transmittance_on_device(volume, sun_direction_scene, device_packed, packed, species, nonzero_levels):
    """Step 1a of a new sun from the device's copy of the packed volume (:func:`refill_step1a_channels`), with the
    host's packed volume refilled from the device's channels: what :func:`swim.rt.solar.solar_transmittance` with
    ``out=step1a_channel_views(packed, species)`` gives (to float32 round-off), and the device's new copy.

    Parameters
    ----------
    volume : xarray.Dataset
        The optical volume whose extinctions are views of ``packed``'s channels
        (:func:`swim.rt.march_inputs.share_packed_channels`).
    sun_direction_scene : array_like
        Shape (3,): unit vector towards the sun in the scene frame.
    device_packed : jax.Array
        The device's copy of ``packed`` with an earlier sun's channels
        (:func:`swim.rt.device_copies.kept_device_copies`); on a GPU its memory is reused: do not use it afterwards.
    packed : numpy.ndarray
        Shape (level, y, x, channel) float32: the host's packed volume
        (:func:`swim.rt.march_inputs.shared_packed_volume`); its Step 1a channels are overwritten, and its device
        copies dropped (:func:`swim.rt.march_inputs.step1a_channel_views`), and so is the fused kernel's padded copy
        of it (:func:`swim.rt.march_pallas.forget_vector_volume`).
    species : tuple of int
        The species packed (:func:`swim.rt.march_inputs.packed_species`).
    nonzero_levels : tuple of numpy.ndarray
        The volume's :func:`swim.rt.solar.step1a_levels`.

    Returns
    -------
    transmittance : xarray.Dataset
        :data:`swim.rt.march_inputs.KERNEL_STEP1A_VARIABLES`, (level, y, x) float32 each: views of ``packed``'s
        channels, as :func:`swim.rt.march_inputs.volume_constants` takes them (the aerosol's, where it is not packed, a
        read-only broadcast of 0).
    device_packed : jax.Array
        The device's packed volume with the new sun's channels: the same values as the host's.

    Raises
    ------
    SwimInputError
        As :func:`refill_step1a_channels`.

    References
    ----------
    Albers et al. (2020), doi:10.5194/amt-13-3235-2020, Sect. 3.4, Eqs. 4-8 (Step 1a; T as
    :func:`swim.rt.solar.transmittance_delta_eddington`).
    """
    import xarray as xr

    from ..workers import in_blocks
    from .march_pallas import forget_vector_volume

    forget_vector_volume()  # the fused kernel's padded copy of the old volume goes before the refill
    n_species = len(species)
    aerosol_3d = packed_aerosol_3d(packed.shape[-1], n_species)
    views = step1a_channel_views(packed, species)  # the old device copies dropped; the host's channels writeable
    new, swept, n_levels = refill_step1a_channels(device_packed, volume, sun_direction_scene, n_species, aerosol_3d,
                                                  nonzero_levels)
    host = np.asarray(swept)  # (n_levels, y, x, channels): the device's values, once
    names = step1a_channel_names(aerosol_3d)
    first = packed.shape[-1] - len(names)
    above = np.array([ABOVE_SWEPT[name] for name in names], np.float32)

    def write(k0, k1):  # a cell's channels one cache line's write
        swept_to = min(k1, n_levels)
        if swept_to > k0:
            packed[k0:swept_to, ..., first:] = host[k0:swept_to]
        if k1 > max(k0, n_levels):
            packed[max(k0, n_levels):k1, ..., first:] = above

    in_blocks(write, packed.shape[0])
    # a variable that is not packed (no 3-D aerosol) is a read-only broadcast of its value, as solar_transmittance
    # gives it: the ground's fields read it too (swim.rt.march_inputs.surface_fields)
    data = {name: (("level", "y", "x"), views[name] if name in views
                   else np.broadcast_to(np.float32(ABOVE_SWEPT[name]), packed.shape[:-1]), STEP1A_ATTRS[name])
            for name in KERNEL_STEP1A_VARIABLES}
    return xr.Dataset(data, coords={"level": volume["level"]}), new
