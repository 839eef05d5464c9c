"""From the state (hydrometeor contents, effective radii, 3-D aerosol on the scene's grid) to the march's packed
volume, differentiably.

A state is a dict of (z, y, x) arrays, some of :data:`STATE_VARIABLES`: ``<species>_content`` [kg m-3] and
``<species>_effective_radius`` [m] of the species of :data:`swim.constants.SPECIES`, and ``aerosol_extinction``
[m-1] (550 nm). The chain, each link in ``jax.numpy`` and so differentiable by ``jax.jvp`` and ``jax.vjp``:

1. each varied species' effective radius r_e: the state's; else the scene's held fixed where it gives one, else the
   default relation of the content (Martin et al. 1994 for cloud liquid, :func:`effective_radius_liquid`; a
   constant for the others), as the render's optical volume takes it;
2. the extinction coefficient of Eq. 7 on the scene's levels, beta = 1.5 q / (rho r_e)
   (:func:`swim.optics.hydrometeors.extinction_coefficient_stephens1978`), with the content q the state's or the
   scene's held fixed;
3. its linear interpolation onto the optical volume's regular levels, with the weights of
   :class:`swim.optics.volume.ColumnInterpolation` (zero below the terrain), written into the species' channel of the
   packed volume; the 3-D aerosol's extinction likewise into its channel, and its column optical depth (which picks
   the diffuse source's aerosol class) from it;
4. Step 1a: the hydrometeors' optical depth and its backscatter-weighted sum swept towards the sun
   (:func:`swim.rt.solar_device._sweep`) and the cloud transmittance T (:func:`transmittance`, the values of
   :func:`swim.rt.solar.transmittance_delta_eddington`) written into the packed volume's T channel, and T at the
   ground into the ground's fields (the cloud shadows on the ground), continued beyond the grid as
   :func:`swim.rt.surface_margin.extend_beyond_grid` continues it; with a varied 3-D aerosol its optical depth
   towards the sun likewise.

Held fixed at the reference: the species and the aerosol the state does not hold, the terrain's shadow, and the
backscatter fractions b of Step 1a and the phase functions (the species' tables, which do not depend on r_e in the
paper's composition).

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

from ..constants import DEFAULT_EFFECTIVE_RADIUS, HYDROMETEOR_DENSITY, SPECIES
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


#: The variables a state may hold, each (z, y, x) on the scene's grid: the hydrometeors' contents [kg m-3] and
#: effective radii [m] (docs/scene-format.md's names) and the 3-D aerosol's extinction at 550 nm [m-1].
CONTENT_VARIABLES = tuple(f"{species}_content" for species in SPECIES)
RADIUS_VARIABLES = tuple(f"{species}_effective_radius" for species in SPECIES)
AEROSOL_VARIABLE = "aerosol_extinction"
STATE_VARIABLES = CONTENT_VARIABLES + RADIUS_VARIABLES + (AEROSOL_VARIABLE,)
#: Units of each state variable.
STATE_UNITS = {**{name: "kg m-3" for name in CONTENT_VARIABLES}, **{name: "m" for name in RADIUS_VARIABLES},
               AEROSOL_VARIABLE: "m-1"}


class StateMap(NamedTuple):
    """The fixed parts of the map from the state to the march's differentiable inputs (all arrays; built by
    :func:`swim.assimilation.setup.build_setup`).

    Attributes
    ----------
    k0, w, zero : array
        (level, column) the resampling weights of :class:`swim.optics.volume.ColumnInterpolation`: the scene level
        at or below each regular level, the weight of the one above it, and the regular levels below the terrain.
    fixed : dict of str to array
        (z, y, x) each: the scene's values of what the varied species' extinction (and the 3-D aerosol's) needs and
        the state does not hold, held fixed: ``<species>_content`` [kg m-3], ``<species>_effective_radius`` [m]
        where the scene gives one (absent: the default relation), ``smoke_extinction`` [m-1] (the smoke's part of
        the 3-D aerosol, added to the state's ``aerosol_extinction``).
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
    dz : array
        The regular levels' spacing [m] (the 3-D aerosol's column optical depth).
    """

    k0: object
    w: object
    zero: object
    fixed: dict
    packed: object
    species_weights: object
    sweep: tuple
    ground_level: object
    surface: object
    fade: object
    dz: object


class StateLayout(NamedTuple):
    """The static parts of the map: the state's variables, the varied species and their channels in the packed
    volume ((name, channel) pairs: those whose content or effective radius the state holds), T's channel, the 3-D
    aerosol's extinction channel (its optical depth towards the sun in the next; -1: not varied), the packed species,
    the sweep's sub-steps per level, the margin of the ground's fields [cells] and the channels of T and the 3-D
    aerosol's optical depth there."""

    variables: tuple
    species_channels: tuple
    t_channel: int
    aerosol_channel: int
    n_species: int
    n_sub: int
    margin: int
    surface_t_channel: int = 8
    surface_aerosol_channel: int = 10


def resample_levels(values, state_map: StateMap):
    """``values`` (z, y, x) on the scene's levels, linearly interpolated onto the optical volume's regular levels
    (level, y, x) (:class:`swim.optics.volume.ColumnInterpolation`'s weights; 0 below the terrain)."""
    nz = values.shape[0]
    flat = values.reshape(nz, -1)
    columns = jnp.arange(flat.shape[1])[None, :]
    lower = flat[state_map.k0, columns]
    upper = flat[state_map.k0 + 1, columns]
    levels = jnp.where(state_map.zero, 0.0, lower + (upper - lower) * state_map.w)
    return levels.reshape((state_map.k0.shape[0],) + values.shape[1:])


def species_radius(species, content, given):
    """The effective radius [m] of ``species`` for Eq. 7: ``given`` (z, y, x) where positive (the scene's, as the
    render's optical volume takes it: :func:`swim.optics.hydrometeors.effective_radius`) or the default relation of
    ``content`` (Martin et al. 1994 for cloud liquid, :func:`effective_radius_liquid`; a constant for the others)."""
    if species == "cloud_liquid":
        default = effective_radius_liquid(content)
    else:
        default = jnp.full(content.shape, DEFAULT_EFFECTIVE_RADIUS[species], content.dtype)
    return default if given is None else jnp.where(given > 0.0, given, default)


def species_extinction(species, state, state_map: StateMap):
    """Eq. 7 for one species of a state (a dict of (z, y, x) arrays; what it does not hold from ``state_map.fixed``),
    on the optical volume's regular levels: (level, y, x) [m-1]."""
    content_name, radius_name = f"{species}_content", f"{species}_effective_radius"
    content = state[content_name] if content_name in state else state_map.fixed[content_name]
    if radius_name in state:
        radius = state[radius_name]
    else:
        radius = species_radius(species, content, state_map.fixed.get(radius_name))
    beta = extinction_coefficient_stephens1978(content, radius, HYDROMETEOR_DENSITY[species])
    return resample_levels(beta, state_map)


def aerosol_extinction(state, state_map: StateMap):
    """The 3-D aerosol's extinction at 550 nm (level, y, x) [m-1] on the regular levels: the state's
    ``aerosol_extinction`` and the scene's smoke held fixed."""
    values = state[AEROSOL_VARIABLE]
    if "smoke_extinction" in state_map.fixed:
        values = values + state_map.fixed["smoke_extinction"]
    return resample_levels(values, state_map)


def step1a_fields(packed, state_map: StateMap, layout: StateLayout):
    """Step 1a's fields (level, y, x) of a packed volume, all levels swept towards the sun: the cloud transmittance T
    [-] of its species (above the clouds T = 1), and with a varied 3-D aerosol its optical depth towards the sun
    [-] (else None)."""
    extinction = packed[..., :layout.n_species]
    fields = [jnp.sum(extinction, axis=-1), extinction @ state_map.species_weights.astype(extinction.dtype)]
    if layout.aerosol_channel >= 0:
        fields.append(packed[..., layout.aerosol_channel])
    di, dj, path_per_level, mu0 = state_map.sweep
    taus = _sweep(jnp.stack(fields), di, dj, path_per_level, layout.n_sub)  # (level, fields, y, x)
    return transmittance(taus[:, 0], taus[:, 1], mu0), (taus[:, 2] if layout.aerosol_channel >= 0 else None)


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


def at_ground(field, state_map: StateMap, layout: StateLayout, outside):
    """A Step 1a field (level, y, x) at the first level at or above the terrain, continued beyond the grid as the
    ground's fields (y + 2 m, x + 2 m): its edge value fading to ``outside`` (the unobstructed sun far away)."""
    ny, nx = field.shape[1:]
    jj, ii = jnp.meshgrid(jnp.arange(ny), jnp.arange(nx), indexing="ij")
    m = layout.margin
    extruded = jnp.pad(field[state_map.ground_level, jj, ii], ((m, m), (m, m)), mode="edge")
    return outside + (extruded - outside) * state_map.fade


def march_inputs(state, state_map: StateMap, layout: StateLayout):
    """The march's differentiable inputs from a state (a dict of (z, y, x) arrays, the variables of
    ``layout.variables``: :data:`STATE_VARIABLES`): a dict with the packed volume ``volume`` (level, y, x, channel)
    with the varied species' extinction, Step 1a's T and with a varied 3-D aerosol its extinction and optical depth
    towards the sun; the ground's fields ``surface`` (channel, y + 2 m, x + 2 m) with T (and the aerosol's optical
    depth) at the ground; and with a varied 3-D aerosol its column optical depth ``aerosol_column`` (1, y, x) [-]
    (which picks the diffuse source's aerosol class, :func:`swim.rt.march_jax.aerosol_class_weights`)."""
    dtype = state_map.packed.dtype
    state = {name: jnp.asarray(state[name], dtype) for name in layout.variables}
    packed = state_map.packed
    for species, channel in layout.species_channels:
        packed = packed.at[..., channel].set(species_extinction(species, state, state_map))
    out = {}
    if layout.aerosol_channel >= 0:
        aerosol = aerosol_extinction(state, state_map)
        packed = packed.at[..., layout.aerosol_channel].set(aerosol)
        out["aerosol_column"] = (jnp.sum(aerosol, axis=0) * state_map.dz)[None].astype(dtype)
    t, aerosol_tau = step1a_fields(packed, state_map, layout)
    packed = packed.at[..., layout.t_channel].set(t.astype(dtype))
    surface = state_map.surface.at[layout.surface_t_channel].set(at_ground(t, state_map, layout, 1.0).astype(dtype))
    if aerosol_tau is not None:
        packed = packed.at[..., layout.aerosol_channel + 1].set(aerosol_tau.astype(dtype))
        surface = surface.at[layout.surface_aerosol_channel].set(at_ground(aerosol_tau, state_map, layout, 0.0)
                                                                 .astype(dtype))
    return {"volume": packed, "surface": surface, **out}
