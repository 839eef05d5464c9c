"""The scene's stages of a render: the scene cropped and coarsened to what the camera sees, its digest, its optical
volume through the stage cache, and the observer and camera placed in it."""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from ..constants import EARTH_RADIUS_M
from ..errors import SwimInputError
from ..frames import enu_to_scene_rotation, geodetic_to_scene
from ..geometry.cameras import fov_to_fit, look_at_angles, make_camera
from ..geometry.level_of_detail import coarsen_scene, resolve_coarsening
from ..geometry.reach import crop_scene_to_view, with_reference_point
from ..io.scene import validate_scene
from ..memory import release_free_memory
from ..optics.volume import build_optical_volume, grid_indices
from ..rt.backends import CameraRays
from ..rt.image_sampling import tile_order
from ..rt.march_inputs import grid_geometry
from .arguments import SPACE_VIEW_HEIGHT_M
from .caches import (STATE, StaleDigest, fingerprint_by_identity, is_lazy, lazy_fingerprint,
                     speculate_digest)
from .moonlight import crop_light_direction


def terrain_at(volume, lat, lon, geometry=None):
    """Terrain height [m] under (lat, lon) by bilinear interpolation; beyond the domain the height of its nearest
    edge, as the ray march continues the terrain (clamped). ``geometry``: the volume's :func:`grid_geometry`, if
    the caller has it."""
    geometry = grid_geometry(volume) if geometry is None else geometry
    p = geodetic_to_scene(lat, lon, 0.0, volume.attrs["reference_lat"], volume.attrs["reference_lon"])
    i, j = (float(v) for v in grid_indices(volume.attrs, p[0], p[1]))
    _, ny, nx = geometry.shape
    terrain = volume.variables["terrain_height"].values
    ic, jc = min(max(i, 0.0), nx - 1.0), min(max(j, 0.0), ny - 1.0)
    i0, j0 = min(int(ic), nx - 2), min(int(jc), ny - 2)
    fi, fj = ic - i0, jc - j0
    value = (terrain[j0, i0] * (1 - fi) * (1 - fj) + terrain[j0, i0 + 1] * fi * (1 - fj)
             + terrain[j0 + 1, i0] * (1 - fi) * fj + terrain[j0 + 1, i0 + 1] * fi * fj)
    return float(value), (i, j)



def check_observer_reach(geometry, indices, height_asl):
    """Raise if the model domain (:func:`grid_geometry`) lies wholly below the observer's horizon."""
    _, ny, nx = geometry.shape
    i, j = indices
    outside = np.hypot(max(0.0, -i, i - (nx - 1)), max(0.0, -j, j - (ny - 1)))
    distance = outside * geometry.spacing
    horizon = np.sqrt(2 * EARTH_RADIUS_M * max(height_asl, 0.0)) + np.sqrt(2 * EARTH_RADIUS_M * max(geometry.top, 0.0))
    if distance > horizon:
        raise SwimInputError(
            f"observer is {distance / 1e3:.0f} km outside the model domain, beyond the {horizon / 1e3:.0f} km "
            "at which any of it rises above the horizon: choose lat/lon inside or near the domain"
        )



def default_perspective_view(volume, lat, lon, height_asl, look_at, options):
    """View angles (and a fitting field of view) for a perspective camera without explicit angles."""
    lat0, lon0 = volume.attrs["reference_lat"], volume.attrs["reference_lon"]
    geometry = grid_geometry(volume)
    _, ny, nx = geometry.shape
    half_extent = 0.5 * float(np.hypot(*(geometry.matrix @ [nx - 1, ny - 1])))
    view = {}
    if look_at is not None:
        az, zen = look_at_angles(lat, lon, height_asl, *look_at)
        view.update(view_azimuth_deg=az, view_zenith_deg=zen)
    elif height_asl > SPACE_VIEW_HEIGHT_M:
        az, zen = look_at_angles(lat, lon, height_asl, lat0, lon0, 0.0)
        view.update(view_azimuth_deg=az, view_zenith_deg=zen)
        if "fov_deg" not in options:
            distance = np.linalg.norm(geodetic_to_scene(lat, lon, height_asl, lat0, lon0) - [0, 0, EARTH_RADIUS_M])
            view["fov_deg"] = fov_to_fit(distance, half_extent)
    else:
        view.update(view_azimuth_deg=0.0, view_zenith_deg=90.0)
    return view



def scene_directions(camera, rotation):
    """The camera's pixels' unit view directions in the scene frame, (ny * nx, 3) float64 (zeros where not valid), and
    the flat indices of its valid pixels (n,) in tile order (:func:`swim.rt.image_sampling.tile_order`): read-only,
    computed once for the last two cameras and rotations (a time series' frames and the renders of one view share
    them; ~0.1 s per 1024^2 frame on the H100 machine's host, docs/decisions/0006-gpu-kernels.md).
    ``rotation``: :func:`swim.frames.enu_to_scene_rotation` (3, 3)."""
    try:
        return _scene_directions_of(camera, np.asarray(rotation, dtype=float).tobytes())
    except TypeError:  # a camera with unhashable options is computed every time
        return _compute_scene_directions(camera, np.asarray(rotation, dtype=float))



@functools.lru_cache(maxsize=2)
def _scene_directions_of(camera, rotation_bytes):
    out = _compute_scene_directions(camera, np.frombuffer(rotation_bytes).reshape(3, 3))
    for a in out:
        a.flags.writeable = False
    return out



def _compute_scene_directions(camera, rotation):
    dirs_enu, valid = camera.cached_directions()
    dirs = np.nan_to_num(dirs_enu.reshape(-1, 3)) @ rotation
    dirs /= np.maximum(np.linalg.norm(dirs, axis=1, keepdims=True), 1e-12)
    flat = np.flatnonzero(valid.reshape(-1))
    return dirs, flat[tile_order(flat, camera.shape)]



def prepared_scene(scene, request, height):
    """The scene that ``request`` (:class:`swim.pipeline.chain.RenderRequest`) renders, before anything is read in
    full: with ``coarsen``, one column per block of the whole grid's columns (lazily, before the crop: the columns
    kept are then the same whatever window the crop takes, so a camera or a sun that moves keeps them); with ``crop``,
    the columns the camera's rays can reach, widened towards the sun for the shadows. The scene frame stays that of
    the whole grid. Returns the scene and the coarsening factor [-]. ``height``: the observer's [m above the
    ground]."""
    if request.crop or request.coarsen is not None:
        scene = with_reference_point(scene)
    if request.coarsen is not None:
        scene = coarsen_scene(scene, resolve_coarsening(request.coarsen, scene, request.camera, request.camera_options,
                                                        request.lat, request.lon, height, request.look_at))
    coarsened_by = int(scene.attrs.get("coarsened_by", 1))
    if request.crop:
        try:
            sun = crop_light_direction(request, scene)  # the light marched; None (every side) for two
        except (SwimInputError, TypeError, ValueError, KeyError):
            sun = None  # unknown here: a margin on every side; a real error is raised later
        scene = crop_scene_to_view(scene, request.camera, camera_options=request.camera_options, lat=request.lat,
                                   lon=request.lon, height=height, sun_direction=sun)
    return scene, coarsened_by


def scene_fingerprint(scene, settings, guess) -> str:
    """The digest of the scene as given, which keys its stages: a warm render (same values) neither validates nor
    builds anything. A lazy scene is identified by its dask graph (for files their names and modification times),
    not read again; an in-memory one on a GPU perhaps by its arrays' identity, checked while the device marches
    (``guess``: a :class:`swim.pipeline.caches.DigestGuess`, or None: hashed first)."""
    if is_lazy(scene):
        return lazy_fingerprint(scene)
    return fingerprint_by_identity(scene, guess if guess is not None and speculate_digest(settings) else None)


def optical_volume(scene, fingerprint, guess):
    """The scene's optical volume (:func:`swim.optics.volume.build_optical_volume`) through the stage cache, with the
    validated scene stripped of its values (its attributes, coordinates and variable names are what the later stages
    read) and the set of its variable names.

    Raises
    ------
    StaleDigest
        If ``guess``'s digest, taken by the scene's identity, did not hold: a volume is never built from the scene's
        values under a digest that is not theirs (the stage cache would hand it to a render of a scene with the old
        values).
    """
    def build():
        if guess is not None and not guess.held():
            raise StaleDigest
        # a lazy (cropped) scene is read here, once: compute(), not load(), so the caller's dataset stays lazy
        valid = validate_scene(scene.compute() if is_lazy(scene) else scene)
        volume = build_optical_volume(valid)
        names = frozenset(valid.data_vars)
        # dropping the values frees the float64 copy of validate_scene before Step 1a and the kernel tables
        valid = valid.drop_vars(list(valid.data_vars))
        release_free_memory()  # the build's freed blocks of rows, before Step 1a (swim.memory)
        return volume, valid, names

    return STATE.stages.get(("volume", fingerprint), build)


@dataclass(frozen=True, eq=False)
class View:
    """The observer and camera placed in the scene.

    Attributes
    ----------
    lat, lon : float
        The observer [deg].
    height, height_asl : float
        The observer's height above the ground and above sea level [m].
    reference : tuple of float
        The scene's reference point (lat, lon) [deg], the origin of its frame.
    camera : swim.geometry.cameras.Camera
        The camera.
    directions_enu : numpy.ndarray
        Shape (ny, nx, 3): the pixels' unit view directions in the observer's ENU frame (NaN where not valid).
    rays : swim.rt.backends.CameraRays
        The camera's rays in the scene frame.
    sun_enu : numpy.ndarray
        Shape (3,): the sun's unit direction in the observer's ENU frame.
    """

    lat: float
    lon: float
    height: float
    height_asl: float
    reference: tuple
    camera: object
    directions_enu: np.ndarray
    rays: CameraRays
    sun_enu: np.ndarray


def camera_view(volume, scene, request, height, sun_scene) -> View:
    """Place ``request``'s observer and camera in the scene (``volume``: its optical volume, ``scene`` its validated
    attributes and coordinates) at ``height`` [m above the ground]; ``sun_scene`` (3,): the sun's unit direction in
    the scene frame.

    Raises
    ------
    SwimInputError
        If the model domain lies wholly below the observer's horizon, or the camera's options are bad.
    """
    lat0, lon0 = float(scene.attrs["reference_lat"]), float(scene.attrs["reference_lon"])
    lat = lat0 if request.lat is None else float(request.lat)
    lon = lon0 if request.lon is None else float(request.lon)
    geometry = grid_geometry(volume)
    terrain, indices = terrain_at(volume, lat, lon, geometry)
    height_asl = terrain + float(height)
    check_observer_reach(geometry, indices, height_asl)
    options = dict(request.camera_options or {})
    if request.camera == "perspective" and "view_azimuth_deg" not in options:
        options.update(default_perspective_view(volume, lat, lon, height_asl, request.look_at, options))
    cam = make_camera(request.camera, **options)
    dirs_enu, valid = cam.cached_directions()
    rotation = enu_to_scene_rotation(lat, lon, lat0, lon0)
    dirs_scene, valid_pixels = scene_directions(cam, rotation)
    rays = CameraRays(geodetic_to_scene(lat, lon, height_asl, lat0, lon0), dirs_scene, valid_pixels, valid,
                      request.sampling, f"{request.camera} camera {cam.shape}")
    return View(lat, lon, float(height), height_asl, (lat0, lon0), cam, dirs_enu, rays, sun_scene @ rotation.T)
