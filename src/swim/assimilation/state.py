"""From the state (cloud liquid water content on the scene's grid) to the march's packed volume, differentiably.

The chain, each link in ``jax.numpy`` and so differentiable by ``jax.jvp`` and ``jax.vjp``:

1. the effective radius r_e of the droplets (Martin et al. 1994, :func:`effective_radius_liquid`), or the scene's
   own r_e held fixed;
2. the extinction coefficient of Eq. 7 on the scene's levels, beta = 1.5 LWC / (rho_w r_e)
   (:func:`swim.optics.hydrometeors.extinction_coefficient_stephens1978`);
3. its linear interpolation onto the optical volume's regular levels, with the weights of
   :class:`swim.optics.volume.ColumnInterpolation` (zero below the terrain), written into the packed volume's
   cloud-liquid channel;
4. Step 1a: the hydrometeors' optical depth and its backscatter-weighted sum swept towards the sun
   (:func:`swim.rt.solar_device._sweep`) and the cloud transmittance T (:func:`transmittance`, the values of
   :func:`swim.rt.solar.transmittance_delta_eddington`) written into the packed volume's T channel, and T at the
   ground into the ground's fields (the cloud shadows on the ground), continued beyond the grid as
   :func:`swim.rt.surface_margin.extend_beyond_grid` continues it.

Held fixed at the reference: the other species' extinction, the 3-D aerosol, the terrain's shadow and the 3-D
aerosol's optical depth towards the sun (they do not depend on the liquid water).

References
----------
Albers et al. (2020), doi:10.5194/amt-13-3235-2020, Eq. 7 and Sect. 3.4 (Step 1a); Martin, Johnson and Spice (1994),
doi:10.1175/1520-0469(1994)051<1823:TMAPOE>2.0.CO;2; Joseph et al. (1976),
doi:10.1175/1520-0469(1976)033<2452:TDEAFR>2.0.CO;2 (T).
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from ..optics.hydrometeors import (DEFAULT_DROPLET_NUMBER_M3, LIQUID_EFFECTIVE_RADIUS_RANGE_M, MARTIN_K_MARITIME,
                                   WATER_DENSITY, extinction_coefficient_stephens1978)
from ..rt.solar import ONE_MINUS_G_PER_BACKSCATTER
from ..rt.solar_device import _sweep

#: Liquid water content [kg m-3] below which the Martin et al. (1994) effective radius is clipped to its lower bound
#: (4 um): there r_e is held constant, and its derivative is 0 (the cube root's is unbounded at 0, and a clip after
#: it would give 0 x inf = NaN in reverse mode).
MARTIN_LOWER_LWC = (4.0 * np.pi * WATER_DENSITY * MARTIN_K_MARITIME * DEFAULT_DROPLET_NUMBER_M3 / 3.0
                    * LIQUID_EFFECTIVE_RADIUS_RANGE_M[0] ** 3)


def effective_radius_liquid(lwc):
    """Cloud-droplet effective radius [m] (Martin et al. 1994, N = 100 cm-3, clipped to 4-20 um) of liquid water
    contents ``lwc`` [kg m-3] (any shape), written so that its derivative is finite everywhere: the values of
    :func:`swim.optics.hydrometeors.effective_radius_liquid_martin1994`, with the content floored at
    :data:`MARTIN_LOWER_LWC` before the cube root (derivative 0 below it)."""
    lo, hi = LIQUID_EFFECTIVE_RADIUS_RANGE_M
    floored = jnp.maximum(lwc, MARTIN_LOWER_LWC)
    r = jnp.cbrt(3.0 * floored / (4.0 * jnp.pi * WATER_DENSITY * MARTIN_K_MARITIME * DEFAULT_DROPLET_NUMBER_M3))
    return jnp.clip(r, lo, hi)


class StateMap(NamedTuple):
    """The fixed parts of the map from the state to the march's differentiable inputs (all arrays; built by
    :func:`swim.assimilation.setup.build_setup`).

    Attributes
    ----------
    k0, w, zero : array
        (level, column) the resampling weights of :class:`swim.optics.volume.ColumnInterpolation`: the scene level
        at or below each regular level, the weight of the one above it, and the regular levels below the terrain.
    radius : array or None
        (z, y, x) the scene's effective radius [m] held fixed, or None for :func:`effective_radius_liquid`.
    packed : array
        (level, y, x, channel) the reference packed volume (:func:`swim.rt.march_inputs.pack_volume`).
    species_weights : array
        (packed species,) backscatter fractions b [-] of the packed species (Step 1a's b tau).
    sweep : tuple
        (di, dj, path_per_level, mu0): the sun's shift per level [grid indices], path per level [m] and the cosine
        of its zenith angle (scalars, or (y, x) each for a grid whose columns take their own sun).
    ground_level : array
        (y, x) int: the first regular level at or above the terrain (:func:`swim.rt.march_inputs.surface_fields`).
    surface : array
        (channel, y + 2 m, x + 2 m) the reference ground's fields with their margin m.
    fade : array
        (y + 2 m, x + 2 m) the weight e^(-d / L) of the grid's edge value of T at a distance d beyond the grid
        (1 inside it; :func:`swim.rt.surface_margin.extend_beyond_grid`).
    """

    k0: object
    w: object
    zero: object
    radius: object
    packed: object
    species_weights: object
    sweep: tuple
    ground_level: object
    surface: object
    fade: object


class StateLayout(NamedTuple):
    """The static parts of the map: the liquid's and T's channels in the packed volume, the packed species, the
    sweep's sub-steps per level, the margin of the ground's fields [cells] and T's channel there."""

    liquid_channel: int
    t_channel: int
    n_species: int
    n_sub: int
    margin: int
    surface_t_channel: int = 8


def liquid_extinction(lwc, state_map: StateMap):
    """Eq. 7 for the cloud liquid of a state ``lwc`` (z, y, x) [kg m-3] on the scene's levels, resampled onto the
    optical volume's regular levels: (level, y, x) [m-1]."""
    radius = effective_radius_liquid(lwc) if state_map.radius is None else state_map.radius
    beta = extinction_coefficient_stephens1978(lwc, radius, WATER_DENSITY)
    nz = lwc.shape[0]
    flat = beta.reshape(nz, -1)
    columns = jnp.arange(flat.shape[1])[None, :]
    lower = flat[state_map.k0, columns]
    upper = flat[state_map.k0 + 1, columns]
    levels = jnp.where(state_map.zero, 0.0, lower + (upper - lower) * state_map.w)
    return levels.reshape((state_map.k0.shape[0],) + lwc.shape[1:])


def cloud_transmittance(packed, state_map: StateMap, layout: StateLayout):
    """Step 1a's cloud transmittance T (level, y, x) [-] of a packed volume's species (all levels swept; above the
    clouds T = 1)."""
    extinction = packed[..., :layout.n_species]
    total = jnp.sum(extinction, axis=-1)
    weighted = extinction @ state_map.species_weights.astype(extinction.dtype)
    di, dj, path_per_level, mu0 = state_map.sweep
    taus = _sweep(jnp.stack([total, weighted]), di, dj, path_per_level, layout.n_sub)  # (level, 2, y, x)
    return transmittance(taus[:, 0], taus[:, 1], mu0)


def transmittance(tau_s, b_tau_s, mu0):
    """:func:`swim.rt.solar.transmittance_delta_eddington`'s T [-], the same values to the last bit, with a
    derivative that is finite where tau_s = 0 (above the clouds). The mean 1 - g = (7/3) b tau_s / tau_s is taken by
    a division guarded on both branches; ``jnp.maximum(tau_s, 1e-30)`` in the divisor gave the derivative
    -x / (1e-30)^2, which is 0 / 0 in float32 (NaN)."""
    x = ONE_MINUS_G_PER_BACKSCATTER * b_tau_s
    thick = tau_s > 1e-30
    one_minus_g = jnp.clip(jnp.where(thick, x / jnp.where(thick, tau_s, 1.0), x / 1e-30), 0.0, 1.0)
    tau_prime = x * (2.0 - one_minus_g)
    k = 0.5 + 0.75 * mu0
    return (k + (1.0 - k) * jnp.exp(-tau_prime)) / (1.0 + 0.75 * mu0 * x)


def ground_transmittance(t, state_map: StateMap, layout: StateLayout):
    """The ground's T channel (y + 2 m, x + 2 m) from T (level, y, x): T at the first level at or above the terrain,
    continued beyond the grid by its edge value fading to 1 (the unobstructed sun far away)."""
    ny, nx = t.shape[1:]
    jj, ii = jnp.meshgrid(jnp.arange(ny), jnp.arange(nx), indexing="ij")
    at_ground = t[state_map.ground_level, jj, ii]
    m = layout.margin
    extruded = jnp.pad(at_ground, ((m, m), (m, m)), mode="edge")
    return 1.0 + (extruded - 1.0) * state_map.fade


def march_inputs(lwc, state_map: StateMap, layout: StateLayout):
    """The march's differentiable inputs from a state ``lwc`` (z, y, x) [kg m-3]: the packed volume (level, y, x,
    channel) with the liquid's extinction and Step 1a's T, and the ground's fields (channel, y + 2 m, x + 2 m) with T
    at the ground."""
    dtype = state_map.packed.dtype
    lwc = jnp.asarray(lwc, dtype)
    packed = state_map.packed.at[..., layout.liquid_channel].set(liquid_extinction(lwc, state_map))
    t = cloud_transmittance(packed, state_map, layout)
    packed = packed.at[..., layout.t_channel].set(t.astype(dtype))
    surface = state_map.surface.at[layout.surface_t_channel].set(ground_transmittance(t, state_map, layout)
                                                                  .astype(dtype))
    return packed, surface
