"""The forward operator's set-up on the host, from the reference state: what the derivatives hold fixed.

:func:`build_setup` builds, once, everything that does not depend on the state or that is held at its reference
value: the optical volume and its resampling weights (:func:`swim.optics.volume.build_optical_volume`), the clear
air's tables (:func:`swim.rt.gas.build_gas_tables`), Step 1a's sun geometry, the packed volume and the ground's fields
of the reference state, the step classes that place the steps (:func:`swim.rt.march_inputs.step_classes`), the
observers' rays and their segments (:func:`swim.rt.march.ray_segments`), and each chunk's placed steps
(:func:`swim.assimilation.march.step_segments`). None of it is traced.
"""

from __future__ import annotations

import functools
import logging
from dataclasses import dataclass, field, replace

import jax
import jax.numpy as jnp
import numpy as np

from ..constants import SPECIES
from ..errors import SwimInputError
from ..frames import enu_from_azimuth_zenith, enu_to_scene_rotation, geodetic_to_scene
from ..geometry.cameras import make_camera
from ..io.scene import as_scene
from ..optics.hydrometeors import effective_radius
from ..optics.model_aerosol import smoke_extinction
from ..optics.volume import ColumnInterpolation, build_optical_volume
from ..pipeline.scene_stage import terrain_at
from ..pipeline.tables import atmosphere_inputs
from ..rt.gas import AerosolBackground, build_gas_tables
from ..rt.kernel_tables import ray_phase_functions
from ..rt.march import ray_segments, without_empty_segments
from ..rt.march_inputs import (KERNEL_STEP1A_VARIABLES, GridGeometry, atmosphere_constants, grid_geometry,
                               packed_aerosol_3d, packed_species, step1a_channel_names, volume_constants)
from ..rt.march_settings import MarchSettings
from ..rt.solar import (backscatter_weights, column_sweep_geometry, per_column_sun, solar_transmittance,
                        sweep_geometry)
from ..rt.surface_margin import LIGHTING_EDGE_FADE_CELLS
from .march import placed_steps, step_segments
from .state import AEROSOL_VARIABLE, RADIUS_VARIABLES, STATE_VARIABLES, StateLayout, StateMap

log = logging.getLogger(__name__)

#: The march's settings that the derivatives need (:mod:`swim.assimilation.march`): no refinement, no stop in
#: opaque cloud, the paper's cloud composition, the JAX lockstep kernel.
DIFFERENTIABLE = {"tau_refine": 0.0, "stop_tau": 0.0, "cloud_scattering": "albers2020"}
#: Rays per chunk of the march [-]: each chunk's reverse pass holds its rays' states at every step.
DEFAULT_CHUNK = 4096
#: The state's variables unless told otherwise: the cloud liquid water content.
DEFAULT_VARIABLES = ("cloud_liquid_content",)


@dataclass(frozen=True)
class Observer:
    """A camera at a vantage point.

    Attributes
    ----------
    lat, lon : float or None
        Position [deg]; None: the scene's reference point.
    height : float
        Height above the ground under it [m].
    camera : str
        Camera kind, ``"perspective"``, ``"allsky"`` or ``"panorama"`` (:func:`swim.geometry.cameras.make_camera`).
    camera_options : dict
        The camera's options (e.g. ``width``, ``height``, ``fov_deg``, ``view_azimuth_deg``, ``view_zenith_deg``;
        ``size`` for an all-sky camera).
    """

    lat: float | None = None
    lon: float | None = None
    height: float = 2.0
    camera: str = "perspective"
    camera_options: dict = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class Setup:
    """What :func:`build_setup` holds fixed: the state's shape, its map to the march's inputs (``state_map``,
    ``layout``), the march's other constants (``consts``, JAX arrays), its settings, the chunks of rays (each a dict
    of arrays for :func:`swim.assimilation.march.chunk_radiance`) and which segments lie in the grid, the observers'
    images' shapes, valid pixels (flat indices, in the order of the rays) and masks, the reference state (a dict of
    (z, y, x) arrays by variable: :func:`reference_values`) and the optical volume's horizontal and vertical geometry
    (:class:`swim.rt.march_inputs.GridGeometry`)."""

    state_shape: tuple
    state_map: StateMap
    layout: StateLayout
    consts: dict
    settings: MarchSettings
    chunks: list
    n_rays: int
    shapes: list
    pixels: list
    masks: list
    reference_state: dict
    geometry: GridGeometry


def ray_images(setup: Setup, values, fill):
    """Per-ray values (n_rays, ...) (in the rays' order: observer after observer) as one image (..., ny, nx) per
    observer, ``fill`` at the pixels without a ray (numpy)."""
    out, first = [], 0
    for shape, flat in zip(setup.shapes, setup.pixels):
        rows = np.asarray(values[first:first + flat.size], float)
        first += flat.size
        image = np.full(rows.shape[1:] + (shape[0] * shape[1],), fill, dtype=float)
        image[..., flat] = np.moveaxis(rows, 0, -1)
        out.append(image.reshape(rows.shape[1:] + tuple(shape)))
    return out


def _as_jax(value, dtype):
    """A kernel constant as a JAX array: floating arrays in ``dtype``, the others as they are (dicts entry by entry)."""
    if isinstance(value, dict):
        return {key: _as_jax(v, dtype) for key, v in value.items()}
    a = np.asarray(value)
    return jnp.asarray(a, dtype) if np.issubdtype(a.dtype, np.floating) else jnp.asarray(a)


def _observer_rays(volume, observer: Observer, sun):
    """One observer's rays: origins (n, 3) [m] and unit directions (n, 3) in the scene frame of its valid pixels,
    their flat indices (n,), the image's shape and its mask (ny, nx) bool."""
    lat0, lon0 = float(volume.attrs["reference_lat"]), float(volume.attrs["reference_lon"])
    lat = lat0 if observer.lat is None else float(observer.lat)
    lon = lon0 if observer.lon is None else float(observer.lon)
    terrain, _ = terrain_at(volume, lat, lon)
    camera = make_camera(observer.camera, **dict(observer.camera_options))
    dirs_enu, valid = camera.cached_directions()
    dirs = np.nan_to_num(dirs_enu.reshape(-1, 3)) @ enu_to_scene_rotation(lat, lon, lat0, lon0)
    dirs /= np.maximum(np.linalg.norm(dirs, axis=1, keepdims=True), 1e-12)
    flat = np.flatnonzero(valid.reshape(-1))
    origin = geodetic_to_scene(lat, lon, terrain + float(observer.height), lat0, lon0)
    return np.repeat(np.asarray(origin, float)[None], flat.size, axis=0), dirs[flat], flat, valid.shape, valid


def _sun_sweep(volume, sun):
    """Step 1a's sun geometry (di, dj, path_per_level, mu0) and sub-steps per level, as
    :func:`swim.rt.solar_device.refill_step1a_channels` takes it."""
    if per_column_sun(volume):
        di, dj, n_sub, path, mu0, _ = column_sweep_geometry(volume, sun, "forward_operator")
    else:
        di, dj, n_sub, path, mu0 = sweep_geometry(volume, sun, "forward_operator")
    return (di, dj, path, mu0), n_sub


def state_variables(variables) -> tuple:
    """The state's variables as a tuple of names of :data:`swim.assimilation.state.STATE_VARIABLES`.

    Raises
    ------
    SwimInputError
        If ``variables`` is empty, repeats a name or names one that a state cannot hold.
    """
    names = (variables,) if isinstance(variables, str) else tuple(variables)
    unknown = [name for name in names if name not in STATE_VARIABLES]
    if not names or unknown or len(set(names)) != len(names):
        raise SwimInputError(f"forward_operator: state_variables must be distinct names of {STATE_VARIABLES}; got "
                             f"{variables!r}")
    return names


def varied_species(variables) -> tuple:
    """The species (names, in the order of :data:`swim.constants.SPECIES`) whose content or effective radius the
    state holds."""
    return tuple(s for s in SPECIES if f"{s}_content" in variables or f"{s}_effective_radius" in variables)


def _scene_field(scene, name):
    return np.asarray(scene[name].transpose("z", "y", "x").values, dtype=float)


def check_scene_for_state(scene, variables):
    """Refuse a scene that does not give what the state's variables need: the contents of the varied species (the
    reference state; zeros for a clear start) and, for the 3-D aerosol, its ``aerosol_extinction``.

    Raises
    ------
    SwimInputError
        If one is missing.
    """
    for species in varied_species(variables):
        if f"{species}_content" not in scene:
            raise SwimInputError(f"forward_operator: the scene needs {species}_content [kg m-3] for the state's "
                                 f"{species} (the reference state; zeros for a clear start)")
    if AEROSOL_VARIABLE in variables and AEROSOL_VARIABLE not in scene:
        raise SwimInputError("forward_operator: the scene needs aerosol_extinction [m-1] (the reference 3-D aerosol "
                             "at 550 nm) for the state's aerosol_extinction")


def reference_values(scene, variables) -> dict:
    """The state's variables in the scene (z, y, x) each, float64: the contents and the 3-D aerosol's extinction as
    given, the effective radii as the render's Eq. 7 takes them (the scene's where positive, else the default
    relation: :func:`swim.optics.hydrometeors.effective_radius`)."""
    out = {}
    for name in variables:
        if name in RADIUS_VARIABLES:
            species = name[:-len("_effective_radius")]
            given = _scene_field(scene, name) if name in scene else None
            out[name] = effective_radius(species, _scene_field(scene, f"{species}_content"), given)
        else:
            out[name] = _scene_field(scene, name)
    return out


def _fixed_fields(scene, variables, dtype):
    """What the varied species and aerosol need that the state does not hold (:attr:`StateMap.fixed`)."""
    fixed = {}
    for species in varied_species(variables):
        for name in (f"{species}_content", f"{species}_effective_radius"):
            if name not in variables and name in scene:
                fixed[name] = _as_jax(_scene_field(scene, name), dtype)
    if AEROSOL_VARIABLE in variables and "smoke_mass_content" in scene:
        fixed["smoke_extinction"] = _as_jax(smoke_extinction(_scene_field(scene, "smoke_mass_content")), dtype)
    return fixed


def _state_map(scene, volume, consts, species, sun, variables, dtype):
    """The fixed parts of the map from the state to the packed volume (:class:`StateMap`, :class:`StateLayout`)."""
    levels = volume["level"].values
    terrain = volume["terrain_height"].values
    interpolation = ColumnInterpolation(scene["height"].values, terrain, levels)
    packed = consts["volume"]
    aerosol_3d = packed_aerosol_3d(packed.shape[-1], len(species))
    if AEROSOL_VARIABLE in variables and not aerosol_3d:
        raise SwimInputError("forward_operator: the state's aerosol_extinction needs a scene whose 3-D aerosol is not "
                             "zero everywhere (the reference)")
    names = step1a_channel_names(aerosol_3d)
    t_channel = packed.shape[-1] - len(names) + names.index("cloud_transmittance")
    sweep, n_sub = _sun_sweep(volume, sun)
    ground = np.clip(np.searchsorted(levels, terrain - 1e-6 * float(volume.attrs["dz"])), 0, levels.size - 1)
    surface = np.asarray(consts["surface"])
    margin = int(np.asarray(consts["surface_margin"]))
    ny, nx = terrain.shape
    jj, ii = np.indices(surface.shape[1:], dtype=float)
    d = np.hypot(np.maximum(np.maximum(margin - jj, jj - (ny - 1 + margin)), 0.0),
                 np.maximum(np.maximum(margin - ii, ii - (nx - 1 + margin)), 0.0))
    f = _as_jax
    state_map = StateMap(jnp.asarray(interpolation.k0), f(interpolation.w, dtype), jnp.asarray(interpolation.zero),
                         _fixed_fields(scene, variables, dtype), f(packed, dtype),
                         f(backscatter_weights(volume.sel(species=[SPECIES[s] for s in species])), dtype),
                         tuple(f(a, dtype) for a in sweep), jnp.asarray(ground), f(surface, dtype),
                         f(np.exp(-d / LIGHTING_EDGE_FADE_CELLS), dtype), f(float(volume.attrs["dz"]), dtype))
    channels = tuple((name, species.index(SPECIES.index(name))) for name in varied_species(variables))
    layout = StateLayout(variables, channels, t_channel, len(species) if AEROSOL_VARIABLE in variables else -1,
                         len(species), int(n_sub), margin)
    return state_map, layout


def _rays(volume, observers, sun, gas, aerosol, top):
    """All observers' rays (one after the other): their segments (:func:`swim.rt.march.ray_segments`), phase
    arrays, and per observer the image's shape, valid pixels and mask."""
    origins, directions, pixels, shapes, masks = [], [], [], [], []
    for observer in observers:
        o, d, flat, shape, valid = _observer_rays(volume, observer, sun)
        origins.append(o)
        directions.append(d)
        pixels.append(flat)
        shapes.append(shape)
        masks.append(valid)
    origins, directions = np.concatenate(origins), np.concatenate(directions)
    if origins.shape[0] == 0:
        raise SwimInputError("forward_operator: the observers' cameras have no valid pixels")
    seg = ray_segments(origins, directions, grid_geometry(volume), top=top)
    cos_theta = directions @ sun
    p_rayleigh, p_aerosol, p_stratospheric = ray_phase_functions(cos_theta, gas.depolarization, aerosol.type,
                                                                 aerosol.stratospheric)
    phase = {"cos_theta": cos_theta, "cos_view_zenith": directions[:, 2], "p_rayleigh": p_rayleigh,
             "p_aerosol": p_aerosol, "p_stratospheric": p_stratospheric}
    return seg, directions, phase, shapes, pixels, masks


@functools.partial(jax.jit, static_argnames=("settings",))
def _placed(start, direction, bounds, consts, settings, probes):
    """A chunk's steps placed (:func:`swim.assimilation.march.step_segments`) in marching order
    (:func:`swim.assimilation.march.placed_steps`)."""
    return placed_steps(step_segments(start, direction, bounds, consts, settings, probes))


def _chunks(seg, directions, phase, consts, settings, chunk, dtype):
    """The rays in chunks of ``chunk`` (the last padded by repeating its last ray, not valid), each a dict of JAX
    arrays with its placed steps (``lo``, ``ds``, ``taken``: :func:`swim.assimilation.march.placed_steps`)."""
    from ..rt.march_jax import _chunk_probes

    n = directions.shape[0]
    chunks = []
    for lo in range(0, n, chunk):
        hi = min(lo + chunk, n)
        pad = chunk - (hi - lo) if n > chunk else 0

        def take(a, kind=dtype, lo=lo, hi=hi, pad=pad):
            a = np.asarray(a[lo:hi])
            a = np.concatenate([a, np.repeat(a[-1:], pad, axis=0)]) if pad else a
            return jnp.asarray(a, kind)

        arrays = {"start": take(seg["start"]), "direction": take(directions), "bounds": take(seg["bounds"]),
                  "ends_on_ground": take(seg["ends_on_ground"], bool),
                  "valid": take(seg["valid"], bool).at[hi - lo:].set(False),
                  "rays": {key: take(value) for key, value in phase.items()}}
        chunk_settings, probes = _chunk_probes(arrays["start"], arrays["direction"], arrays["bounds"], consts,
                                               settings)
        arrays["lo"], arrays["ds"], arrays["taken"] = _placed(arrays["start"], arrays["direction"],
                                                              arrays["bounds"], consts, chunk_settings, probes)
        chunks.append(arrays)
    return chunks


def march_settings(settings: MarchSettings | None) -> MarchSettings:
    """``settings`` (default :class:`MarchSettings`'s step counts) with what the derivatives need
    (:data:`DIFFERENTIABLE`) and the JAX lockstep kernel."""
    settings = MarchSettings() if settings is None else settings
    settings = replace(settings, **DIFFERENTIABLE)
    return settings.with_execution(backend="jax", grid_kernel="lockstep").kernel_settings()


def scene_tables(scene, sun_zenith, sun_azimuth, aerosol=None, dtype=jnp.float32, variables=DEFAULT_VARIABLES):
    """The scene's fixed tables for the reference state: the sun's direction (3,) in the scene frame, the optical
    volume, the clear air's tables, the kernel constants (numpy, the packed volume with the channels of the varied
    species always), and the map from the state of ``variables`` to the march's inputs (:class:`StateMap`,
    :class:`StateLayout`).

    Raises
    ------
    SwimInputError
        If ``variables`` are not names a state can hold, or the scene does not give what they need
        (:func:`check_scene_for_state`).
    """
    scene = as_scene(scene)
    variables = state_variables(variables)
    check_scene_for_state(scene, variables)
    aerosol = AerosolBackground() if aerosol is None else aerosol
    sun = np.asarray(enu_from_azimuth_zenith(float(sun_azimuth), float(sun_zenith)), dtype=float)
    volume = build_optical_volume(scene)
    species = tuple(sorted(set(packed_species(volume)) | {SPECIES.index(s) for s in varied_species(variables)}))
    transmittance = solar_transmittance(volume, sun, variables=KERNEL_STEP1A_VARIABLES)
    mean_albedo, profile, classes = atmosphere_inputs(volume)
    gas = build_gas_tables(aerosol, surface_albedo=mean_albedo, scene_aerosol_profile=profile,
                           aerosol_class_aod=classes)
    host = {**volume_constants(volume, transmittance, species=species), **atmosphere_constants(gas, sun)}
    state_map, layout = _state_map(scene, volume, host, species, sun, variables, dtype)
    return scene, sun, volume, gas, host, state_map, layout


def build_setup(scene, observers, sun_zenith, sun_azimuth, aerosol=None, settings=None, chunk=DEFAULT_CHUNK,
                dtype=jnp.float32, variables=DEFAULT_VARIABLES) -> Setup:
    """The forward operator's fixed set-up (:class:`Setup`) from a canonical ``scene`` whose values of the state's
    ``variables`` are the reference state; the arguments as :class:`swim.assimilation.ForwardOperator` takes them.

    Raises
    ------
    SwimInputError
        If the scene does not give what the state's variables need (:func:`scene_tables`), or the observers are not
        a non-empty list of :class:`Observer` or their cameras have no pixels.
    """
    observers = list(observers)
    if not observers or not all(isinstance(o, Observer) for o in observers):
        raise SwimInputError(f"forward_operator: observers must be a non-empty list of Observer, got {observers!r}")
    aerosol = AerosolBackground() if aerosol is None else aerosol
    scene, sun, volume, gas, host, state_map, layout = scene_tables(scene, sun_zenith, sun_azimuth, aerosol, dtype,
                                                                    variables)
    consts = _as_jax(host, dtype)
    seg, directions, phase, shapes, pixels, masks = _rays(volume, observers, sun, gas, aerosol, float(host["top"]))
    bounds = seg["bounds"]
    settings = without_empty_segments(march_settings(settings), [np.any(length > 0) for length in (
        bounds[:, 0], bounds[:, 1] - bounds[:, 0], bounds[:, 2] - bounds[:, 1])])
    chunks = _chunks(seg, directions, phase, consts, settings, int(chunk), dtype)
    reference = reference_values(scene, layout.variables)
    shape = next(iter(reference.values())).shape
    log.info("forward operator: %d observers, %d rays in %d chunks, state %s on %s", len(observers),
             directions.shape[0], len(chunks), ", ".join(layout.variables), shape)
    return Setup(shape, state_map, layout, consts, settings, chunks, directions.shape[0], shapes, pixels, masks,
                 reference, grid_geometry(volume))
