"""The thin orchestrator: scene -> optics -> geometry -> tracing -> composition -> colour -> outputs.

Each stage is a function between xarray objects or small dataclasses; :func:`render` only wires them.
"""

from __future__ import annotations

import collections
import dataclasses
import functools
import logging
import threading
import weakref
from collections.abc import Mapping
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr
import xxhash

from . import __version__
from .color import DEFAULT_WHITE_LEVEL, SPACE_WHITE_LEVEL, solar_relative_to_srgb8
from .color.display import auto_white_level, exposure_white_level
from .constants import ATMOSPHERE_TOP_M, EARTH_RADIUS_M, SUN_ANGULAR_RADIUS_RAD, WAVELENGTHS_NM
from .optics.cloud_phase import AUREOLE_HALF_ANGLE_RAD
from .digest import update_with_array
from .errors import SwimInputError
from .frames import azimuth_zenith_from_enu, enu_to_scene_rotation, geodetic_to_scene
from .geometry.cameras import check_camera_options, fov_to_fit, look_at_angles, make_camera
from .geometry.level_of_detail import check_coarsening, coarsen_scene, resolve_coarsening
from .geometry.reach import crop_scene_to_view, with_reference_point
from .geometry.sun import SunPosition, sun_from_angles, sun_position
from .io.atomic import atomic_write
from .io.scene import to_utc_datetime64, validate_scene
from .memory import release_compiled_programs, release_free_memory
from .optics.volume import build_optical_volume, grid_indices
from .rt.gas import AerosolBackground, aerosol_column_classes, build_gas_tables, phase_functions
from .rt.image_sampling import AdaptiveSampling, sample_image_adaptive, tile_order
from .rt.device_copies import keep_device_copies, kept_device_copies
from .rt.march import trace_rays
from .rt.march_inputs import (KERNEL_STEP1A_VARIABLES, aerosol_column_optical_depth, atmosphere_constants,
                              grid_geometry, occupancy_grid, pack_volume, packed_species, share_packed_channels,
                              shared_packed_volume, step1a_channel_views, volume_constants)
from .rt.march_settings import MarchSettings
from .workers import threads
from .rt.clouds import MIN_SUN_COSINE, cloud_constants, cloud_ray_inputs, direct_weights, scene_cloud_optics
from .rt.diffuse_field import diffuse_field, solve_sun
from .rt.solar import solar_transmittance, step1a_levels
from .workers import parallel_map

log = logging.getLogger(__name__)

#: Above this height [m] a perspective camera without a look-at point looks straight down.
SPACE_VIEW_HEIGHT_M = ATMOSPHERE_TOP_M
#: Image rows per call of the colour stage in :func:`render` (bounds its float64 temporaries).
COLOUR_BLOCK_ROWS = 128
#: Shortest time between two of :func:`render`'s counts of the process's memory mappings [s]
#: (:func:`swim.memory.release_compiled_programs`; a count costs tens of ms near the limit).
COMPILED_PROGRAMS_CHECK_S = 30.0
#: Images of fewer pixels skip the C heap's trims after the march and at the end of :func:`render`: they free a few
#: MB, and each ``malloc_trim`` walks the whole heap (1-3 ms, a tenth of a 41 x 41 render; swim.memory). So do
#: renders whose march runs on a GPU.
TRIM_MIN_PIXELS = 1 << 16
#: Images of at least this many traced pixels are scattered into their planes on several threads (:func:`render`):
#: below it the pool's overhead (~0.02 ms a task) is not worth it.
PLANES_THREADED_PIXELS = 1 << 16
#: Rows per block of an adaptive render's planes, copied on several threads [-].
PLANE_BLOCK_ROWS = 64
#: Scenes of at least this many bytes are hashed on several threads (:func:`_fingerprint`): below it the pool's
#: overhead (~0.1 ms) is not worth it.
FINGERPRINT_THREADED_BYTES = 64 << 20
#: The outputs of :func:`swim.rt.march.trace_rays` that become images of :func:`render`.
IMAGE_OUTPUTS = ("radiance", "radiance_clear", "radiance_cloud", "radiance_surface", "tau_hydrometeor")


def _fingerprint(scene: xr.Dataset) -> str:
    """Digest of a scene's values, coordinates and attributes (what its optical volume depends on).

    The scene as given to :func:`render` (cropped, not yet validated: the same values validate to the same
    scene, and a warm render then skips the validation's float64 copies). A streaming XXH3-128 digest (``xxhash``)
    of each variable's name, dims, dtype, shape and attributes and of its values (:mod:`swim.digest`); then one of
    those digests, in the variables' sorted order, and of the scene's attributes. The variables of a big scene are
    hashed on up to 8 threads (xxhash releases the GIL): the 12 MB RICO LES takes ~0.4 ms per render (7 ms with
    SHA-256 on the thread pool), the 0.47 GB of the 400 x 400 x 60 benchmark scene ~17 ms on one core here and
    75 ms on one core of the H100 machine's host (docs/decisions/0009-work-around-the-march.md and
    docs/decisions/0006-gpu-kernels.md)."""
    names = sorted(scene.variables)

    def variable_digest(name):
        var = scene.variables[name]
        digest = xxhash.xxh3_128()
        # the attributes too: validation checks the units, and a warm render does not validate again
        digest.update(f"{name}{var.dims}{var.dtype}{var.shape}{_attrs_text(var.attrs)}".encode())
        values = var.values
        if values.dtype.kind not in "biufc":
            digest.update(repr(values.tolist()).encode())
        else:
            update_with_array(digest, values)
        return digest.digest()

    size = sum(scene.variables[name].nbytes for name in names)
    parts = parallel_map(variable_digest, names, min(threads(), 8) if size >= FINGERPRINT_THREADED_BYTES else 1)
    digest = xxhash.xxh3_128(b"".join(parts))
    digest.update(_attrs_text(scene.attrs).encode())
    return digest.hexdigest()


#: Arrays of at least this many bytes are known by their identity in :func:`_scene_identity` (smaller ones by their
#: values' digest, which costs less than a microsecond per kilobyte).
IDENTITY_MIN_BYTES = 1 << 20


def _scene_identity(scene: xr.Dataset):
    """What makes a scene the same one as a render's before, short of hashing its big arrays: each variable's name,
    dims, dtype, shape and attributes; for an array of at least :data:`IDENTITY_MIN_BYTES`, the array that owns its
    memory (its id and a weak reference to it: while that lives, no other array can take its place) with the view's
    address and strides; for a smaller one, its values' digest; and the scene's attributes. None where a big
    variable is not a NumPy array (a lazy one). Values changed in place leave the identity as it was: a render that
    takes a digest by identity checks it (:func:`_fingerprint_by_identity`)."""
    parts = []
    for name in sorted(scene.variables):
        var = scene.variables[name]
        head = f"{name}{var.dims}{var.dtype}{var.shape}{_attrs_text(var.attrs)}"
        data = getattr(var, "_data", None)
        if isinstance(data, np.ndarray) and data.nbytes >= IDENTITY_MIN_BYTES:
            root = data
            while isinstance(root.base, np.ndarray):
                root = root.base
            parts.append((head, id(root), weakref.ref(root), data.__array_interface__["data"][0], data.strides))
        elif var.nbytes >= IDENTITY_MIN_BYTES:
            return None
        else:
            digest = xxhash.xxh3_128()
            values = var.values
            if values.dtype.kind not in "biufc":
                digest.update(repr(values.tolist()).encode())
            else:
                update_with_array(digest, values)
            parts.append((head, digest.digest()))
    return tuple(parts), _attrs_text(scene.attrs)


def _same_identity(a, b) -> bool:
    """Whether two :func:`_scene_identity` values are of the same arrays (weak references compared by their
    referents' identity, never by ``==`` on arrays)."""
    if a is None or b is None or a[1] != b[1] or len(a[0]) != len(b[0]):
        return False
    for x, y in zip(a[0], b[0]):
        if len(x) != len(y) or x[0] != y[0]:
            return False
        if len(x) == 2:
            if x[1] != y[1]:
                return False
        elif x[1] != y[1] or x[2]() is None or x[2]() is not y[2]() or x[3:] != y[3:]:
            return False
    return True


class _LastDigest:
    """The identity (:func:`_scene_identity`) and digest (:func:`_fingerprint`) of the last in-memory scene rendered
    in this process."""

    def __init__(self):
        self._lock = threading.Lock()
        self._entry = None

    def digest_of(self, identity):
        with self._lock:
            entry = self._entry
        return entry[1] if entry is not None and _same_identity(entry[0], identity) else None

    def remember(self, identity, digest):
        with self._lock:
            self._entry = None if identity is None else (identity, digest)

    def forget(self):
        with self._lock:
            self._entry = None


_LAST_DIGEST = _LastDigest()


class _StaleDigest(Exception):
    """A digest taken by identity did not hold (the scene's values changed in place): :func:`render` renders again."""


class _DigestGuess:
    """A render's digest taken by the scene's identity (:func:`_fingerprint_by_identity`) and its check: the scene
    hashed on a thread of its own while the render goes on (one thread per check: renders on several threads hash
    at once, and a forked process starts none of its parent's)."""

    def __init__(self):
        self.guess = None
        self._done = threading.Event()
        self._actual = self._error = None

    def start(self, guess, scene) -> bool:
        """Check ``guess`` against ``scene``'s digest on a new thread; False where no thread can start (the
        interpreter shutting down: the caller hashes the scene itself)."""
        def check():
            try:
                self._actual = _fingerprint(scene)
            except BaseException as err:  # noqa: BLE001 - raised again by held()
                self._error = err
            finally:
                self._done.set()

        try:
            threading.Thread(target=check, name="swim-digest-check", daemon=True).start()
        except RuntimeError:
            return False
        self.guess = guess
        return True

    def held(self) -> bool:
        """Whether the guess was the scene's digest (True where none was taken); waits for the check."""
        if self.guess is None:
            return True
        self._done.wait()
        if self._error is not None:
            raise self._error
        return self._actual == self.guess


def _speculate_digest(settings: MarchSettings) -> bool:
    """Whether a render may take an in-memory scene's digest by its arrays' identity and check it meanwhile: where
    the march runs on a GPU (its host idles while the device marches); on a CPU the march takes the cores."""
    return settings.on_accelerator()


def _fingerprint_by_identity(scene: xr.Dataset, guess: _DigestGuess | None) -> str:
    """:func:`_fingerprint` of an in-memory scene, or, with ``guess``, perhaps the last rendered scene's.

    With ``guess``, where the scene has the last rendered scene's identity (:func:`_scene_identity`: the same
    arrays, attributes and small values) and the stage cache still holds that scene's optical volume, the last
    digest is returned at once and ``guess`` checks it on another thread meanwhile (:meth:`_DigestGuess.held`,
    which :func:`render` asks before it returns, and the volume's build before it builds anything under the guessed
    digest). In an H100 frame of the 400 x 400 x 60 scene the hash of its 0.47 GB took ~14 ms of the host's
    0.135 s (docs/decisions/0006-gpu-kernels.md). Otherwise the digest is computed here, and with ``guess``
    remembered with the identity."""
    if guess is None:
        return _fingerprint(scene)
    identity = _scene_identity(scene)
    if identity is not None:
        last = _LAST_DIGEST.digest_of(identity)
        if last is not None and _STAGE_CACHE.peek(("volume", last)) is not None and guess.start(last, scene):
            return last
    fingerprint = _fingerprint(scene)
    _LAST_DIGEST.remember(identity, fingerprint)
    return fingerprint


def _is_lazy(scene: xr.Dataset) -> bool:
    """Whether any variable of ``scene`` is a chunked (dask) array. ``Variable.chunks`` checks its array against a
    runtime protocol (~13 us a variable); an index variable, or a variable whose array is a numpy array (xarray's
    ``_data``, looked up with a fallback to ``chunks``), is answered at once. Not ``Variable.data``: for a lazily
    opened file that reads it."""
    return any(not isinstance(var, xr.IndexVariable) and not isinstance(getattr(var, "_data", None), np.ndarray)
               and var.chunks is not None for var in scene.variables.values())  # an index is held in memory


def _lazy_fingerprint(scene: xr.Dataset) -> str:
    """Digest of a lazy (dask-backed) scene without reading it: its dask token, which covers the graph of every
    variable (the names of the files and their modification times for an opened file, the tokens of the
    operations on them, such as the crop), the in-memory variables' values and all attributes. dask names its
    arrays by the same token and relies on it for its own caching. What it does not see: a file replaced by one
    with the same name and modification time (``cp -p``, ``rsync -t``), a file rewritten while a dataset opened
    from it is still in use (its token was made when it was opened; open it again), and a numpy array wrapped by
    ``dask.array.from_array`` and changed in place afterwards (wrap it again). ``swim.pipeline._STAGE_CACHE.clear()``
    forgets every cached stage."""
    import dask.base

    return "dask-" + dask.base.tokenize(scene)


def _attrs_text(attrs):
    return repr(sorted((k, repr(v)) for k, v in attrs.items()))


def _phase_functions(cos_theta, depolarization, aerosol_type, stratospheric_type):
    """Rayleigh (n,), aerosol and stratospheric aerosol (n, 3) phase functions [-] (mean 1 over the sphere;
    :func:`swim.rt.gas.phase_functions`) at the scattering-angle cosines ``cos_theta`` (n,), float32 numpy arrays."""
    return phase_functions(np.asarray(cos_theta, np.float32), np.float32(depolarization), aerosol_type,
                           stratospheric_type)


def _scene_directions(camera, rotation):
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


class _StageCache:
    """The last render's optical volume, Step 1a and kernel constants, reused while the scene (and the sun and
    the atmosphere) stay the same.

    A time series, several cameras on one scene or a fly-through would otherwise rebuild them every frame,
    which on a big grid takes longer than the ray march (docs/performance.md). Keys are (kind, scene
    fingerprint, ...); one entry of each kind. Before an entry is rebuilt, it and every entry of another
    scene are dropped, so the cache never holds two grids at once. Small values that do not hold a grid (the 3-D
    diffuse solutions) are kept across scenes, a few at a time (:meth:`get_small`)."""

    def __init__(self):
        self._entries = {}
        self._small = collections.OrderedDict()
        self._lock = threading.Lock()

    def get(self, key, build):
        kind, fingerprint = key[:2]
        entry = self._entries.get(kind)
        if entry is not None and entry[0] == key:
            log.info("reusing the %s of the previous render", kind)
            return entry[1]
        self._drop_for(key)  # before the build: the cache never holds two grids at once
        return self.put(key, build())

    def peek(self, key):
        """The value kept under ``key``, or None (nothing is built or dropped)."""
        entry = self._entries.get(key[0])
        return entry[1] if entry is not None and entry[0] == key else None

    def put(self, key, value):
        """Keep ``value`` under ``key`` (replacing its kind's entry; entries of other scenes are dropped) and return
        it."""
        self._drop_for(key)
        self._entries[key[0]] = (key, value)
        return value

    def _drop_for(self, key):
        """Drop the entry of ``key``'s kind and every entry of another scene."""
        kind, fingerprint = key[:2]
        for other, (other_key, _) in list(self._entries.items()):
            if other == kind or other_key[1] != fingerprint:
                self._entries.pop(other, None)  # (another render's thread may have dropped it already)

    def get_small(self, key, build, named=None):
        """The value of ``key`` from a store of :data:`SMALL_ENTRIES` small values kept across scenes (the least
        recently used goes first), else ``build()``'s, kept. ``named``: the object whose ``id`` the key holds (the
        gas tables), referenced weakly: an entry whose object has gone (its id may be another's now) is not used."""
        with self._lock:
            entry = self._small.get(key)
            if entry is not None and (entry[1] is None or entry[1]() is named):
                self._small.move_to_end(key)
                log.info("reusing the %s of an earlier render", key[0])
                return entry[0]
        value = build()
        with self._lock:
            self._small[key] = (value, None if named is None else weakref.ref(named))
            while len(self._small) > SMALL_ENTRIES:
                self._small.popitem(last=False)
        return value

    def clear(self):
        self._entries.clear()
        self._small.clear()


#: Small stage values kept across scenes (:meth:`_StageCache.get_small`): the 3-D diffuse solutions (a few MB each),
#: which renders that alternate between scenes, aerosols or sun nodes would otherwise solve again.
SMALL_ENTRIES = 4

_STAGE_CACHE = _StageCache()


def _atmosphere_inputs(volume):
    """What the clear-atmosphere tables take from the optical volume (:func:`swim.rt.gas.build_gas_tables`): the
    scene-mean surface albedo (3,), which reflects light back into the sky in the multiple-scattering table; the
    mean column of a 3-D aerosol field, (heights [m], extinction [1/m]) or None, which joins the background aerosol
    there; and for a non-uniform field the classes of its column optical depth, one table each (Eqs. 30-31,
    docs/aerosols.md §8), or None. Kept with the volume in the stage cache: a warm render of a small image spent
    ~0.5 ms on these means."""
    albedo = volume["surface_albedo"]
    mean_albedo = np.asarray(albedo.mean(dim=[d for d in albedo.dims if d != "wavelength"]).values, dtype=float)
    aer3d = volume["aerosol_extinction"].values.mean(axis=(1, 2), dtype=float)
    if not np.any(aer3d > 0):
        return mean_albedo, None, None
    levels = float(volume.attrs["z_bottom"]) + float(volume.attrs["dz"]) * np.arange(aer3d.size)
    return mean_albedo, (levels, aer3d), aerosol_column_classes(aerosol_column_optical_depth(volume).values)


def _terrain_at(volume, lat, lon, geometry=None):
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


def _check_observer_reach(geometry, indices, height_asl):
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


def resolve_sun(time, scene, sun_zenith=None, sun_azimuth=None) -> SunPosition:
    """Sun position at the scene's reference point from the time or from explicit angles [deg]."""
    if (sun_zenith is None) != (sun_azimuth is None):
        raise SwimInputError("give both sun_zenith and sun_azimuth [deg] to override the sun, or neither")
    lat0, lon0 = float(scene.attrs["reference_lat"]), float(scene.attrs["reference_lon"])
    if sun_zenith is not None:
        return sun_from_angles(sun_zenith, sun_azimuth)
    if time is None:
        if "time" not in scene.coords:
            raise SwimInputError("no time given and the scene has no 'time' coordinate: pass time (ISO 8601, UTC)")
        time = pd.Timestamp(scene["time"].values)
    return sun_position(time, lat0, lon0)


def _sun_disk(camera, dirs_enu, valid, sun_enu, transmittance, radius=SUN_ANGULAR_RADIUS_RAD):
    """The sun's disk: the flat indices (k,) of its pixels and their solar-relative radiance (3,), which spreads
    4 pi T_direct over the disk's pixels; no pixels where the sun is outside the image or its disk covers none.
    With another ``radius`` [rad] (at least 0.75 pixel), a circumsolar disc of that radius.

    Only its pixels are returned (rather than an image of zeros that a render added to its radiance: two passes
    over 24 MB of float64 for a 1024^2 image, docs/decisions/0009-work-around-the-march.md)."""
    none = np.zeros(0, np.int64), np.zeros(3)
    row, col = camera.pixel_of_direction(np.asarray(sun_enu)[None, :])
    if not (np.isfinite(row[0]) and np.isfinite(col[0])):
        return none
    ny, nx = dirs_enu.shape[:2]
    r = int(np.clip(np.rint(row[0]), 0, ny - 1))
    c = int(np.clip(np.rint(col[0]), 0, nx - 1))
    # the pixel's angular pitch across and along the rows: a panorama's columns close up towards the zenith
    # (cos elevation), and its rows may be further apart than its columns
    across = dirs_enu[r, c + 1] if c + 1 < nx else dirs_enu[r, c - 1]
    along = dirs_enu[r + 1, c] if r + 1 < ny else dirs_enu[r - 1, c]
    pitches = [float(np.arccos(np.clip(np.dot(dirs_enu[r, c], d), -1, 1))) if valid[r, c] else 0.0
               for d in (across, along)]
    if not all(np.isfinite(x) and x > 0 for x in pitches):
        return none
    # at least 0.75 of the larger pitch: a disk that no pixel centre falls into would lose the sun
    radius = max(radius, 0.75 * max(pitches))
    pitch = float(np.sqrt(pitches[0] * pitches[1]))  # the pixel's solid angle is about pitch^2
    # the pixels within the disk's angular radius, looked for in the window that holds them (the whole image only
    # where the disk reaches outside the camera's field): a 1024^2 image's every direction took ~5 ms a frame
    (r0, r1), (c0, c1) = _disk_window(camera, np.asarray(sun_enu, dtype=float), radius, row[0], col[0], ny, nx)
    # NaN outside the camera's pixels, where the comparison below is False
    cos_angle = dirs_enu[r0:r1, c0:c1] @ sun_enu
    rows, cols = np.nonzero(valid[r0:r1, c0:c1] & (cos_angle >= np.cos(radius)))
    if rows.size == 0:
        return none
    pixels = (rows + r0) * nx + (cols + c0)  # ascending, as flatnonzero of the whole image gives them
    return pixels, 4 * np.pi * np.asarray(transmittance, dtype=float) / (pixels.size * pitch**2)


#: Pixels added to each side of the window of :func:`_disk_window`, and the longest step [pixels] allowed between the
#: images of neighbouring directions sampled on the disk's edge: a point of the edge's image between two samples then
#: lies within the margin of one of them.
DISK_WINDOW_MARGIN = 2
#: Fewest and most directions sampled on the disk's edge (:func:`_disk_window`): about one a pixel of its image.
DISK_EDGE_DIRECTIONS = (64, 4096)


def _disk_edge_pixels(camera, sun_enu, radius, n):
    """Pixel coordinates (rows, cols) of ``n`` directions evenly spaced on the circle at ``radius`` [rad] around
    the unit vector ``sun_enu`` (ENU)."""
    axis = np.zeros(3)  # an orthonormal pair across the sun's direction, from the ENU axis least aligned with it
    axis[int(np.argmin(np.abs(sun_enu)))] = 1.0
    e1 = np.cross(sun_enu, axis)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(sun_enu, e1)
    phi = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    return camera.pixel_of_direction(np.cos(radius) * sun_enu
                                     + np.sin(radius) * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2))


def _disk_window(camera, sun_enu, radius, row, col, ny, nx):
    """Rows [r0, r1) and columns [c0, c1) of the image that hold every pixel whose direction lies within ``radius``
    [rad] of the unit vector ``sun_enu`` (ENU), whose pixel is (``row``, ``col``).

    A camera's projection maps the disk onto the region that its edge's image bounds, so the box of that curve holds
    every such pixel. The curve is sampled at about one direction a pixel (:data:`DISK_EDGE_DIRECTIONS`) and the
    samples' box widened by :data:`DISK_WINDOW_MARGIN` pixels. The whole image where that does not hold: an edge
    direction not imaged (the disk reaches outside the field of view), a step between neighbouring samples longer
    than the margin (a panorama's seam or pole inside the disk, where the curve is not closed in the image; a disk
    too big for the most samples), or a sun that is not a unit vector."""
    whole = (0, ny), (0, nx)
    norm = float(np.linalg.norm(sun_enu))
    if not (np.isfinite(norm) and abs(norm - 1.0) <= 1e-6 and np.isfinite(row) and np.isfinite(col)):
        return whole
    fewest, most = DISK_EDGE_DIRECTIONS
    rows, cols = _disk_edge_pixels(camera, sun_enu, radius, fewest)
    if not (np.all(np.isfinite(rows)) and np.all(np.isfinite(cols))):
        return whole
    # about one sample a pixel of the edge's image: its length from the first samples' mean distance to the centre
    n = int(np.clip(np.ceil(2 * np.pi * np.mean(np.hypot(rows - row, cols - col))), fewest, most))
    if n > fewest:
        rows, cols = _disk_edge_pixels(camera, sun_enu, radius, n)
        if not (np.all(np.isfinite(rows)) and np.all(np.isfinite(cols))):
            return whole
    m = DISK_WINDOW_MARGIN
    if np.max(np.hypot(np.diff(rows, append=rows[0]), np.diff(cols, append=cols[0]))) > m:
        return whole
    r0, r1 = max(int(np.floor(min(rows.min(), row))) - m, 0), min(int(np.ceil(max(rows.max(), row))) + m + 1, ny)
    c0, c1 = max(int(np.floor(min(cols.min(), col))) - m, 0), min(int(np.ceil(max(cols.max(), col))) + m + 1, nx)
    return (r0, max(r1, r0)), (c0, max(c1, c0))


#: Renders running in this process (threads: a dask worker's, a caller's own), with their lock: a new sun refills
#: the shared packed volume in place only where its render is the only one (:func:`render`).
_RENDERS_IN_PROGRESS = [0]
_RENDERS_LOCK = threading.Lock()
#: Renders in this process build their grid constants (the packed volume, Step 1a, the occupancy grid) one at a time:
#: the build reads the cached optical volume and may point its extinctions at a new packed volume
#: (:func:`swim.rt.march_inputs.share_packed_channels`), which deletes and re-adds its ``species`` coordinate. A render beside
#: it (a dask worker's threads, each with its own sun) read the volume in between and found the coordinate gone
#: ("'cloud_liquid' is not in list" in ``pack_volume``, or worse, names and extinctions of two layouts).
_GRID_CONSTANTS_LOCK = threading.RLock()


def _counted_render(fn):
    """``fn`` (:func:`render`) counted in :data:`_RENDERS_IN_PROGRESS` while it runs."""
    @functools.wraps(fn)
    def counted(*args, **kwargs):
        with _RENDERS_LOCK:
            _RENDERS_IN_PROGRESS[0] += 1
        try:
            return fn(*args, **kwargs)
        finally:
            with _RENDERS_LOCK:
                _RENDERS_IN_PROGRESS[0] -= 1
    return counted


def _rendering_alone() -> bool:
    """Whether the calling render is the only one running in this process (:data:`_RENDERS_IN_PROGRESS`)."""
    with _RENDERS_LOCK:
        return _RENDERS_IN_PROGRESS[0] <= 1


@_counted_render
def render(scene: xr.Dataset, *, time=None, lat=None, lon=None, height=2.0, camera="allsky",
           camera_options=None, sun_zenith=None, sun_azimuth=None, look_at=None,
           aerosol: AerosolBackground | None = None, settings: MarchSettings = MarchSettings(),
           white_level=None, exposure: float = 0.0, progress=None, crop: bool = True,
           sampling: AdaptiveSampling | None = None, coarsen=None, check_memory: bool = True) -> xr.Dataset:
    """Render what a camera at a vantage point sees in a scene.

    Parameters
    ----------
    scene : xarray.Dataset
        Canonical scene (docs/scene-format.md), e.g. from :func:`swim.open_scene`.
    time : str, datetime or pandas.Timestamp, optional
        UTC time; default: the scene's ``time`` coordinate. Not needed with ``sun_zenith``/``sun_azimuth``.
    lat, lon : float, optional
        Observer position [deg]; default: the scene's reference point.
    height : float
        Observer height above the ground [m] (above the terrain or sea surface under it).
    camera : {"allsky", "panorama", "perspective"}
        Camera kind (docs/frames.md); ``camera_options`` are passed to its constructor (e.g. ``size``,
        ``width``, ``height``, ``fov_deg``, ``view_azimuth_deg``, ``view_zenith_deg``).
    sun_zenith, sun_azimuth : float, optional
        Override the ephemeris [deg].
    look_at : tuple of float, optional
        (lat [deg], lon [deg], height [m above sea level]) for a perspective camera. Without it (and
        without view angles) a camera above 100 km looks straight down and fits the domain in its field
        of view, and a lower one looks at the horizon towards the north.
    aerosol : AerosolBackground or str, optional
        Background 1-D aerosol and the type of all aerosol (a type name alone keeps the default profile,
        docs/aerosols.md); ``"none"``: no background aerosol; default: type "continental", AOD 0.05 at 550 nm,
        or no background where the scene has a 3-D ``aerosol_extinction`` (which a scene's 3-D aerosol keeps).
    settings : MarchSettings
        Ray-marching step counts.
    white_level : float or "auto", optional
        Exposure: the solar-relative radiance mapped to display white before the tone curve, whose shoulder
        rolls brighter light off to neutral white (docs/colour.md); default 1.5 for observers in the atmosphere
        (a camera's exposure) and 4.0 above 100 km (reflectance 1 is white, as in satellite imagery). ``"auto"``:
        from the image's luminance, its log-average shown at 0.18 of white (a camera's average metering,
        :func:`swim.color.auto_white_level`). The radiance planes do not depend on it.
    exposure : float
        Exposure shift [EV, stops] on top of ``white_level``: +1 shows the image twice as bright.
    progress : callable, optional
        Called with (rays done, rays total).
    crop : bool
        First crop the scene lazily to the columns the camera's rays can reach, widened towards the sun for
        the shadows (:func:`swim.geometry.reach.crop_scene_to_view`; docs/rendering.md, "Cropping big
        grids"), so a big (or dask-backed) grid is never loaded in full. Not done for a perspective camera
        without ``view_azimuth_deg``/``view_zenith_deg`` in ``camera_options`` (its view comes from the whole
        grid), nor when the rays reach more than 90 % of the columns. False renders the whole grid.
    sampling : AdaptiveSampling, optional
        Trace a coarse lattice of pixels and only refine where the image is not smooth, interpolating the
        rest (:func:`swim.rt.image_sampling.sample_image_adaptive`; docs/rendering.md, "Adaptive
        sampling"): 2-5x fewer rays on typical scenes, within the sampling's tolerance where it interpolates.
        Default: every valid pixel is traced.
    coarsen : None, "auto" or int
        Keep one column (the middle one) of each block of N x N of the grid's columns, before anything is read in
        full, for a distant view whose pixels each cover several columns
        (:func:`swim.geometry.level_of_detail.coarsen_scene`, method ``"sample"``; docs/rendering.md, "Distant views
        of big grids"): the volume, Step 1a and the march then hold N^2 times fewer columns. ``"auto"``: the largest
        N whose blocks are no wider than the smallest pixel footprint on the grid (perspective cameras only; 1 for
        the others). Default None: the grid as it is.
    check_memory : bool
        Refuse, before any work, an image whose render would need more memory than the system has available
        (:data:`RENDER_BYTES_PER_PIXEL` per pixel); False renders it anyway.

    Returns
    -------
    xarray.Dataset
        ``radiance`` (wavelength, y, x) [1]: solar-relative spectral radiance L' (Eq. 2) at 615/546/450 nm;
        ``rgb`` (y, x, channel) uint8 sRGB; ``view_azimuth``, ``view_zenith`` (y, x) [deg] in the observer's
        frame; ``tau_hydrometeor`` (y, x) [1], the hydrometeor optical depth along the line of sight (``stop_tau``
        of :class:`MarchSettings`, 50, where a ray that does not look down stops in opaque cloud: a lower bound);
        ``radiance_clear``, ``radiance_cloud``, ``radiance_surface``;
        attributes with the sun, observer, time and camera, ``traced_pixels`` (pixels whose ray was
        marched), ``march_samples`` (the volume samples the march took: per ray as marched by the "numba"
        kernel, the lockstep count of every ray's steps for "jax"; :func:`swim.rt.march.trace_rays`) and
        ``march_backend`` (the kernel that marched them, :class:`MarchSettings`).

    Raises
    ------
    SwimInputError
        Bad scene, observer below the terrain or out of reach, bad camera options, time or ``coarsen``; a march kernel
        (``settings.backend``) that cannot run here (numba missing); an image too big for the
        memory available (``check_memory``).

    Notes
    -----
    The renders of a process share the last scene's stages: the optical volume, the packed grid and Step 1a. A
    render of the same scene and sun reuses them; a new sun (a time series' frame) redoes Step 1a only, into the
    same packed grid where no other render is running, else into a new one. Renders may run on several threads
    at once (a dask worker's); docs/decisions/0006-gpu-kernels.md Where the march runs on a GPU, a scene whose arrays
    were rendered before is recognised by them and hashed while the device marches; if their values were changed in
    place since, the render finds it before it returns and renders the scene again (a warning says so, and
    ``progress`` counts the rays twice; docs/decisions/0006-gpu-kernels.md).
    """
    call = dict(time=time, lat=lat, lon=lon, height=height, camera=camera, camera_options=camera_options,
                sun_zenith=sun_zenith, sun_azimuth=sun_azimuth, look_at=look_at, aerosol=aerosol, settings=settings,
                white_level=white_level, exposure=exposure, progress=progress, crop=crop, sampling=sampling,
                coarsen=coarsen, check_memory=check_memory)
    guess = _DigestGuess()
    try:
        image = _render(scene, **call, guess=guess)
        if guess.held():
            return image
        del image
    except _StaleDigest:
        pass
    except Exception:
        if guess.held():
            raise
    # the scene's values changed in place since its arrays were last rendered: the image (or the error) came from
    # the stages of their old values. Forget both, and render again from the values as they are
    log.warning("the scene's values changed in place since its last render: rendering it again")
    _LAST_DIGEST.forget()
    _STAGE_CACHE.clear()
    # a new guess: with the record forgotten none is taken, the scene is hashed first and remembered for the next
    return _render(scene, **call, guess=_DigestGuess())


def _check_exposure(white_level, exposure) -> bool:
    """Check ``render``'s exposure arguments before any work; True for auto exposure."""
    exposure_white_level(1.0, exposure)  # raises SwimInputError for a bad shift
    if isinstance(white_level, str):
        if white_level != "auto":
            raise SwimInputError(f"white_level must be a positive number (solar-relative L' [-]) or 'auto'; got "
                                 f"{white_level!r}")
        return True
    if white_level is not None:
        exposure_white_level(white_level)
    return False


def settings_attributes(settings: MarchSettings) -> dict:
    """The march settings as netCDF attributes ``settings_<field>``: numbers as they are, booleans as 0 or 1, the
    rest (None, methods, nested settings) as text."""
    out = {}
    for field in dataclasses.fields(settings):
        value = getattr(settings, field.name)
        if isinstance(value, (bool, np.bool_)):
            value = int(value)
        elif not isinstance(value, (int, float, np.integer, np.floating)):
            value = str(value)
        out[f"settings_{field.name}"] = value
    return out


def _checked_arguments(scene, camera, camera_options, height, look_at, aerosol, lat, white_level, exposure, coarsen,
                       check_memory):
    """:func:`render`'s arguments checked before the scene is read (a whole CONUS grid: ~40 s and ~11 GB): the scene's
    type, the exposure, the camera's kind and options (a perspective camera's view is filled in from the grid later,
    :func:`_default_perspective_view`), the image's memory, the observer and the coarsening. Returns the observer's
    height [m above the ground] as a float and whether the exposure is automatic.

    Raises
    ------
    SwimInputError
        Naming the argument and what it should be.
    """
    if not isinstance(scene, xr.Dataset):
        raise SwimInputError(f"scene must be an xarray.Dataset; got {type(scene).__name__}")
    auto_exposure = _check_exposure(white_level, exposure)
    if camera_options is not None and not isinstance(camera_options, Mapping):
        raise SwimInputError(f"camera_options must be a mapping of option names to values, got "
                             f"{type(camera_options).__name__}")
    # a number, not text or a flag that float() would take: a misread "2" or True is a mistake, not a height
    height_m = None
    if isinstance(height, (int, float, np.integer, np.floating)) and not isinstance(height, (bool, np.bool_)):
        height_m = float(height)
    if not (aerosol is None or isinstance(aerosol, (str, AerosolBackground))):
        raise SwimInputError(f"aerosol must be None (the default background), an aerosol type name or an "
                             f"AerosolBackground; got {aerosol!r} ({type(aerosol).__name__})")
    filled_later = ()
    if "view_azimuth_deg" not in (camera_options or {}):  # _default_perspective_view: the view, and from space its
        # field of view where no look_at is given (the ground's height, at most 9 km, not yet known)
        space = height_m is not None and height_m + 9000.0 > SPACE_VIEW_HEIGHT_M
        filled_later = ("view_azimuth_deg", "view_zenith_deg") + (("fov_deg",) if space and look_at is None else ())
    preview = check_camera_options(camera, dict(camera_options or {}), filled_later=filled_later)
    if check_memory:
        check_render_memory(int(np.prod(preview.shape)))
    if lat is not None and not (-90 <= float(lat) <= 90):
        raise SwimInputError(f"observer lat must be in [-90, 90] deg, got {lat}")
    if height_m is None or not np.isfinite(height_m) or height_m < 0:
        raise SwimInputError(f"observer height must be a number >= 0 [m above the ground], got {height!r}")
    check_coarsening(coarsen)
    return height_m, auto_exposure


def _background_aerosol(aerosol, scene_vars) -> AerosolBackground:
    """The render's background aerosol (:func:`render`'s ``aerosol``): None gives the default background, or none
    where the scene has a 3-D ``aerosol_extinction`` (``scene_vars``: the scene's variable names); ``"none"`` no
    background (a scene's 3-D aerosol stays); a type name that type with the default profile."""
    if aerosol is None:
        return AerosolBackground(aod_550=0.0) if "aerosol_extinction" in scene_vars else AerosolBackground()
    if isinstance(aerosol, str) and aerosol.strip().lower() == "none":
        return AerosolBackground(aod_550=0.0)
    if isinstance(aerosol, str):
        return AerosolBackground(type_name=aerosol)
    return aerosol


def _settings_for_sun(settings: MarchSettings, sun: SunPosition, sun_scene) -> MarchSettings:
    """``settings``, with the 3-D cloud scattering replaced by the paper's method where the sun (``sun_scene``, its
    unit direction in the scene frame) is too low for the 3-D diffuse solution: twilight and night skies, lit by the
    clear sky's tables (the image's ``cloud_scattering`` attribute says which ran)."""
    clouds = settings.cloud_scattering
    if not (clouds.three_d and sun_scene[2] <= MIN_SUN_COSINE):
        return settings
    log.info("sun elevation %.2f deg: clouds scattered by the albers2020 method (the 3-D diffuse solution needs "
             "the sun above %.1f deg)", 90.0 - sun.zenith_deg, np.degrees(np.arcsin(MIN_SUN_COSINE)))
    return dataclasses.replace(settings, cloud_scattering=dataclasses.replace(clouds, method="albers2020"))


def _with_the_sun(planes, sun_out, cam, dirs_enu, valid, sun_enu_observer, aureole):
    """The image's radiance (3, ny, nx) with the sun's disk added, and with ``aureole`` (the 3-D cloud scattering)
    the circumsolar aureole of the clouds' forward peak, added to ``planes["radiance_cloud"]`` too (in place).
    ``planes``' ``radiance`` is taken out of it; ``sun_out`` holds the sun's ray's outputs. Returns the radiance, the
    flat indices of the pixels that changed, and the direct and circumsolar transmittances (3,) [-]."""
    t_direct = np.exp(-(sun_out["tau_clear"] + sun_out["tau_hydrometeor"]))
    if sun_out["surface"]:
        t_direct = np.zeros(3)
    disk_pixels, disk_radiance = _sun_disk(cam, dirs_enu, valid, sun_enu_observer, t_direct)
    radiance = planes.pop("radiance")  # (3, ny, nx) float32
    t_aureole = np.zeros(3)
    recoloured = disk_pixels
    if aureole and not sun_out["surface"]:
        # the forward peak's narrow part, delivered about the sun (swim.optics.cloud_phase.split_phase_function)
        t_aureole = np.maximum(np.exp(-(sun_out["tau_clear"] + sun_out["tau_narrow"])) - t_direct, 0.0)
        aureole_pixels, aureole_radiance = _sun_disk(cam, dirs_enu, valid, sun_enu_observer, t_aureole,
                                                     radius=AUREOLE_HALF_ANGLE_RAD)
        if aureole_pixels.size:
            for plane in (radiance, planes["radiance_cloud"]):
                flat = plane.reshape(3, -1)
                flat[:, aureole_pixels] = flat[:, aureole_pixels] + aureole_radiance[:, None]
            recoloured = np.union1d(disk_pixels, aureole_pixels)
    if disk_pixels.size:  # the disk added in float64, rounded once to the output's float32
        flat = radiance.reshape(3, -1)
        flat[:, disk_pixels] = flat[:, disk_pixels] + disk_radiance[:, None]
        radiance = flat.reshape(radiance.shape)
    return radiance, recoloured, t_direct, t_aureole


def _image_dataset(radiance, rgb, planes, cam, *, camera, settings, sampling, sun, sun_enu_observer, scene, observer,
                   reference, exposure, aerosol, march, transmittances) -> xr.Dataset:
    """:func:`render`'s image: the radiance planes (``radiance`` (3, ny, nx) and the other ``planes``), the sRGB codes
    ``rgb`` (ny, nx, 3) and the view angles of the camera ``cam`` (kind ``camera``) as CF variables, with the render's
    attributes: the sun (``sun``, and ``sun_enu_observer`` its direction at the observer), the ``scene``'s title,
    source and time, the ``observer`` (lat, lon [deg], height above the ground and above sea level [m]), the scene's
    ``reference`` point (lat, lon [deg]), the ``exposure`` (white level, whether automatic, shift [EV]), the
    ``aerosol``, the ``march`` (samples, traced pixels, the scene's coarsening), the sun's direct and circumsolar
    ``transmittances`` (3,) and the ``settings`` and ``sampling``; and the time as a scalar coordinate (CF 4.4)."""
    lat, lon, height, height_asl = observer
    lat0, lon0 = reference
    white_level, auto_exposure, exposure = exposure
    march_samples, traced_pixels, coarsened_by = march
    t_direct, t_aureole = transmittances
    # float32 copies (the output is the caller's; the cached angles are read-only): no second copy below
    view_az, view_zen = (np.array(a, dtype=np.float32) for a in cam.cached_view_angles())
    sun_az_obs, sun_zen_obs = azimuth_zenith_from_enu(sun_enu_observer)

    dims3 = ("wavelength", "y", "x")
    data = {
        "radiance": (dims3, radiance.astype(np.float32, copy=False), {
            "units": "1", "long_name": "solar-relative spectral radiance L' = 4 pi L / E_TOA (Albers et al. 2020, Eq. 2)"}),
        "radiance_clear": (dims3, planes.pop("radiance_clear").astype(np.float32, copy=False), {"units": "1", "long_name": "gas and aerosol part of L'"}),
        "radiance_cloud": (dims3, planes.pop("radiance_cloud").astype(np.float32, copy=False), {"units": "1", "long_name": "hydrometeor part of L'"}),
        "radiance_surface": (dims3, planes.pop("radiance_surface").astype(np.float32, copy=False), {"units": "1", "long_name": "ground part of L'"}),
        "tau_hydrometeor": (("y", "x"), planes.pop("tau_hydrometeor")[0].astype(np.float32, copy=False), {
            "units": "1", "long_name": "hydrometeor optical depth along the line of sight",
            "comment": (f"rays that do not look down stop where it passes {settings.stop_tau:g} (opaque): there it "
                        f"is {settings.stop_tau:g}, a lower bound") if settings.stop_tau
                       else "the whole line of sight"}),
        "rgb": (("y", "x", "channel"), rgb, {"units": "1", "long_name": "true-colour image, 8-bit sRGB codes",
                                             "comment": "display transform: see the display_transform, white_level "
                                                        "and exposure attributes; the radiance does not depend on it"}),
        "view_azimuth": (("y", "x"), view_az, {"units": "degree", "standard_name": "sensor_azimuth_angle",
                                               "long_name": "view azimuth, clockwise from north"}),
        "view_zenith": (("y", "x"), view_zen, {"units": "degree", "standard_name": "sensor_zenith_angle",
                                              "long_name": "view zenith angle"}),
    }
    attrs = {
        "title": f"SWIm {camera} image",
        "institution": "swim-imagery",
        "source": f"swim {__version__}",
        "references": "Albers et al. (2020), Atmos. Meas. Tech. 13, 3235-3261, doi:10.5194/amt-13-3235-2020",
        "history": f"{datetime.now(timezone.utc).isoformat(timespec='seconds')} rendered by swim {__version__}",
        "scene_title": str(scene.attrs.get("title", "")),
        "scene_source": str(scene.attrs.get("source", "")),
        # the model time whose fields were rendered (a series' frame may lie up to 90 min from it)
        "scene_time": pd.Timestamp(scene["time"].values).isoformat() if "time" in scene.coords else "",
        "time": "" if sun.time is None else pd.Timestamp(sun.time).isoformat(),
        "sun_zenith_deg": float(sun_zen_obs),
        "sun_azimuth_deg": float(sun_az_obs),
        "sun_zenith_reference_deg": float(sun.zenith_deg),
        "sun_azimuth_reference_deg": float(sun.azimuth_deg),
        "sun_source": sun.source,
        "earth_sun_distance_au": float(sun.earth_sun_distance_au),
        "direct_transmittance": np.asarray(t_direct, dtype=float),
        "circumsolar_transmittance": np.asarray(t_aureole, dtype=float),
        "cloud_scattering": settings.cloud_scattering.method,
        "observer_lat": lat,
        "observer_lon": lon,
        "observer_height_above_ground_m": float(height),
        "observer_height_asl_m": float(height_asl),
        "reference_lat": lat0,
        "reference_lon": lon0,
        "white_level": float(white_level),
        "exposure": "auto" if auto_exposure else "fixed",
        "exposure_ev": float(exposure),
        "display_transform": "filmic",
        "aerosol_type": aerosol.type_name,
        "aerosol_optical_depth_550": float(aerosol.aod_550),
        "aerosol_scale_height_m": float(aerosol.scale_height_m),
        "aerosol_single_scattering_albedo": np.asarray(aerosol.type.ssa, dtype=float),
        "aerosol_asymmetry_parameter": np.asarray(aerosol.type.asymmetry_parameter(), dtype=float),
        "aerosol_angstrom_exponent": float(aerosol.type.angstrom_exponent),
        "camera": camera,
        "march_samples": march_samples,
        "traced_pixels": traced_pixels,
        "march_backend": settings.resolved_backend(),
        "scene_coarsened_by": coarsened_by,
        "sampling": "every pixel" if sampling is None else (
            f"adaptive (tolerance {sampling.tolerance:g}, coarse spacing {sampling.coarse_spacing}, "
            f"radiance floor {sampling.radiance_floor:g}, tau tolerance {sampling.tau_tolerance:g}, "
            f"tau floor {sampling.tau_floor:g}, clear tolerance {sampling.clear_tolerance:g}, "
            f"edge tests in cells of {sampling.edge_test_size} pixels)"),
        "Conventions": "CF-1.8",
    }
    attrs.update(cam.to_attrs())  # keys start with "camera_"
    attrs.update(settings_attributes(settings))  # keys start with "settings_"
    image = xr.Dataset(data, coords=_image_coordinates(), attrs=attrs)
    when = sun.time if sun.time is not None else (scene["time"].values if "time" in scene.coords else None)
    if when is not None:  # a scalar time coordinate (CF 4.4): the sun's time, else the scene's
        image = image.assign_coords(time=xr.Variable((), to_utc_datetime64(when),
                                                     {"standard_name": "time", "long_name": "time of the image (UTC)"}))
    return image


def _scattered_planes(outputs, pixels, ny, nx):
    """The image's planes (C, ny, nx) of the traced rays' ``outputs`` (name -> (n,) or (n, C)): NaN, then each ray's
    value at its flat pixel index ``pixels`` (n,). Every channel at once on the pools' threads (NumPy's scatter
    without the GIL): the 13 channels' scatters of a 1024^2 all-sky took 77 ms one after the other on a GPU machine's
    host while the device idled (docs/decisions/0006-gpu-kernels.md). Empties ``outputs``."""
    planes = {key: np.empty((value.shape[1] if value.ndim == 2 else 1, ny * nx), value.dtype)
              for key, value in outputs.items()}

    def scatter(row):  # one channel of one output
        key, channel = row
        value, plane = outputs[key], planes[key][channel]
        np.copyto(plane, np.nan)
        plane[pixels] = value[:, channel] if value.ndim == 2 else value

    parallel_map(scatter, [(key, c) for key, plane in planes.items() for c in range(plane.shape[0])],
                 min(threads(), 8) if pixels.size >= PLANES_THREADED_PIXELS else 1)
    outputs.clear()
    return {key: plane.reshape(-1, ny, nx) for key, plane in planes.items()}


def _planes_of_samples(out, ny, nx):
    """The image's planes (C, ny, nx) of the adaptive sampler's image ``out`` (name -> (ny * nx,) or (ny * nx, C)),
    taking the outputs of :data:`IMAGE_OUTPUTS` out of it. One output at a time, its rows in blocks on several threads
    (NumPy's copy without the GIL), each output dropped once copied: with all of them copied at once, every output and
    its copy were alive together, the render's peak for big images (docs/decisions/0010-memory.md). The arrays travel
    in the blocks' items, so that no function outlives the loop holding the last output."""
    planes = {}

    def copy_rows(block):
        source, target, r0 = block
        np.copyto(target[:, r0:r0 + PLANE_BLOCK_ROWS], source[:, r0:r0 + PLANE_BLOCK_ROWS])

    for key in IMAGE_OUTPUTS:
        a = out.pop(key)
        if a.ndim == 1:
            planes[key] = a.reshape(1, ny, nx)
            continue
        source = a.reshape(ny, nx, -1).transpose(2, 0, 1)
        planes[key] = target = np.empty(source.shape, a.dtype)
        del a
        parallel_map(copy_rows, [(source, target, r0) for r0 in range(0, ny, PLANE_BLOCK_ROWS)],
                     min(threads(), 8) if ny * nx >= PLANES_THREADED_PIXELS else 1)
        del source, target
    return planes


def _grid_constants(volume, fingerprint, settings: MarchSettings, sun_scene, cloud_optics) -> dict:
    """The kernel constants of the scene's grid for one sun (:func:`swim.rt.march_inputs.volume_constants`): the
    packed volume with Step 1a's channels for the sun ``sun_scene`` (3,), the step classes, the ground's fields. The
    packing, the species packed, Step 1a's levels and the occupancy depend on the volume alone and are kept in the
    stage cache under ``fingerprint``; a new sun refills the packed volume in place where this render is the only one
    (on the device's copy with ``MarchSettings.step1a_on_device``). ``cloud_optics``: the 3-D cloud scattering's, or
    None."""
    # The grid is packed first and the volume's extinctions become views of the packed channels, so the
    # grid is held once before Step 1a's fields are made (docs/performance.md, "Memory"); species that are zero
    # everywhere are not packed (a march through fewer channels reads fewer cache lines,
    # docs/decisions/0007-scene-set-up.md) the species packed and Step 1a's levels with extinction depend on the
    # volume alone: a new sun (a time series' frame) reuses them (their scans read every species' extinction: ~0.1
    # and ~0.2 s for the 400 x 400 x 60 scene on this project's 2 cores, docs/decisions/0006-gpu-kernels.md)
    species = _STAGE_CACHE.get(("packed species", fingerprint), lambda: packed_species(volume))
    # before the packing, which makes the extinctions strided views: the scan of a new scene's contiguous
    # arrays took 84-90 ms against 440-490 ms through the views (400 x 400 x 60, docs/decisions/0006-gpu-kernels.md)
    nonzero_levels = _STAGE_CACHE.get(("step 1a levels", fingerprint), lambda: step1a_levels(volume))
    # A new sun refills the packed volume's Step 1a channels in place (the grid's channels are the same), where
    # this render is the only one in the process: beside others (a dask worker's threads) one of them may still
    # march through that volume with its own sun, and this one packs the grid anew
    packed = shared_packed_volume(volume, species) if _rendering_alone() else None
    # the step classes (march.step_classes) of a new sun are written over the last sun's where the packed volume
    # is refilled in place too (the same arrays then keep their device copies' places)
    classes = None
    if packed is None:
        packed = pack_volume(volume, species)
        share_packed_channels(volume, packed, species)
    else:
        classes = _STAGE_CACHE.peek(("step classes", fingerprint))
    # the occupancy grid depends on the volume alone: a new sun (a time series' frame) reuses it
    occupancy = _STAGE_CACHE.get(("occupancy", fingerprint), lambda: occupancy_grid(volume))
    if classes is None:
        # kept also beside other renders: the next render alone reuses this render's packed volume, and with its
        # classes it finds the device copies that this render made (only a render alone writes them in place)
        classes = _STAGE_CACHE.put(("step classes", fingerprint), np.zeros(occupancy.shape, np.int8))
    # MarchSettings.step1a_on_device: a new sun on the device's copy of this packed volume, which an earlier
    # sun's render of the JAX kernel left there (swim.rt.solar_device): no sums, sweep input or volume sent
    kept = (kept_device_copies({"volume": packed, "occupancy": classes})
            if settings.resolved_step1a_on_device() else None)
    if kept is not None:
        from .rt.march_pallas import forget_vector_volume
        from .rt.solar_device import solar_transmittance_on_device

        forget_vector_volume()  # the fused kernel's padded copy of the old volume goes before the refill
        transmittance, device_packed = solar_transmittance_on_device(volume, sun_scene, kept["volume"], packed,
                                                                     species, nonzero_levels)
        del kept["volume"]  # (donated to the new copy on a GPU)
    else:
        # Step 1a, only the fields that the kernel constants read, written straight into the packed volume's
        # channels: no field of its own (~100 MB each at 400 x 400 x 160) and no copy
        # (docs/decisions/0007-scene-set-up.md) (the 3-D cloud scattering: the direct beam's delta-M scaled
        # transmittance in place of T)
        transmittance = solar_transmittance(volume, sun_scene, variables=KERNEL_STEP1A_VARIABLES,
                                            backend=settings.backend, nonzero_levels=nonzero_levels,
                                            out=step1a_channel_views(packed, species),
                                            direct_weights=(None if cloud_optics is None
                                                            else direct_weights(volume, cloud_optics)))
    constants = volume_constants(volume, transmittance, occupancy=occupancy, packed=packed, species=species,
                                 classes=classes)
    if kept is not None:  # the device's new copy is the one the JAX kernel takes (swim.rt.device_copies.device_copies);
        # the step classes of this sun are sent (25.6 MB for 400 x 400 x 160)
        import jax

        keep_device_copies({"volume": constants["volume"], "occupancy": constants["occupancy"]},
                           {"volume": device_packed, "occupancy": jax.device_put(constants["occupancy"])})
        del device_packed
    del transmittance
    if not settings.on_accelerator():
        # Step 1a's freed levels, before the ray march; not where the march runs on a GPU, whose host has the
        # memory to spare: there the trim took 0.06 s of a new sun's 0.58 s frame on an H100 machine's 16
        # cores (docs/decisions/0006-gpu-kernels.md)
        release_free_memory()
    return constants


def _render(scene, *, time, lat, lon, height, camera, camera_options, sun_zenith, sun_azimuth, look_at, aerosol,
            settings, white_level, exposure, progress, crop, sampling, coarsen, check_memory,
            guess: _DigestGuess | None) -> xr.Dataset:
    """:func:`render`'s work. ``guess``: where the scene's digest may be taken by its arrays' identity
    (:func:`_fingerprint_by_identity`; None: hashed first)."""
    height, auto_exposure = _checked_arguments(scene, camera, camera_options, height, look_at, aerosol, lat,
                                               white_level, exposure, coarsen, check_memory)
    if crop or coarsen is not None:
        # Before anything is loaded in full; the scene frame stays that of the whole grid.
        scene = with_reference_point(scene)
    if coarsen is not None:
        # one column per block of the whole grid's columns, lazily, before the crop: the columns kept are then the
        # same whatever window the crop takes (a camera or a sun that moves keeps them)
        scene = coarsen_scene(scene, resolve_coarsening(coarsen, scene, camera, camera_options, lat, lon, height,
                                                        look_at))
    coarsened_by = int(scene.attrs.get("coarsened_by", 1))
    if crop:
        try:
            sun_for_crop = resolve_sun(time, scene, sun_zenith, sun_azimuth).direction_enu
        except (SwimInputError, TypeError, ValueError, KeyError):
            sun_for_crop = None  # unknown here: a margin on every side; a real error is raised below
        scene = crop_scene_to_view(scene, camera, camera_options=camera_options, lat=lat, lon=lon, height=height,
                                   sun_direction=sun_for_crop)
    # a kernel that cannot run (no numba) fails before any work
    backend = settings.resolved_backend()
    from .rt import precompile

    precompile.start(backend)  # on a cold numba cache, the march compiles in a helper process meanwhile
    given = scene

    def validated_volume():
        # never built from the scene's values under a digest guessed by identity that does not hold (the stage cache
        # would hand it to a render of a scene with the old values)
        if guess is not None and not guess.held():
            raise _StaleDigest
        # a lazy (cropped) scene is read here, once: compute(), not load(), so the caller's dataset stays lazy
        valid = validate_scene(given.compute() if lazy else given)
        # From here on only the scene's attributes, coordinates and variable names are needed: dropping its
        # values frees the float64 copy of validate_scene before Step 1a and the kernel constants.
        volume = build_optical_volume(valid)
        names = frozenset(valid.data_vars)
        valid = valid.drop_vars(list(valid.data_vars))
        release_free_memory()  # the build's freed blocks of rows, before Step 1a (swim.memory)
        return volume, valid, names

    # The digest of the scene as given: a warm render (same values) neither validates nor builds anything. A lazy
    # scene is identified by its dask graph (for files their names and modification times), not read again.
    lazy = _is_lazy(scene)
    if lazy:
        fingerprint = _lazy_fingerprint(scene)
    else:  # on a GPU perhaps the last scene's, checked while the device marches (render asks before it returns)
        fingerprint = _fingerprint_by_identity(scene, guess if guess is not None and _speculate_digest(settings)
                                               else None)
    volume, scene, scene_vars = _STAGE_CACHE.get(("volume", fingerprint), validated_volume)
    lat0, lon0 = float(scene.attrs["reference_lat"]), float(scene.attrs["reference_lon"])
    lat = lat0 if lat is None else float(lat)
    lon = lon0 if lon is None else float(lon)
    geometry = grid_geometry(volume)
    terrain, indices = _terrain_at(volume, lat, lon, geometry)
    height_asl = terrain + float(height)
    _check_observer_reach(geometry, indices, height_asl)

    sun = resolve_sun(time, scene, sun_zenith, sun_azimuth)
    if sun.zenith_deg > 90:
        log.warning("sun is %.1f deg below the horizon: twilight/night sky (no moon, stars or city lights)",
                    sun.zenith_deg - 90)
    sun_scene = np.asarray(sun.direction_enu, dtype=float)

    options = dict(camera_options or {})
    if camera == "perspective" and "view_azimuth_deg" not in options:
        options.update(_default_perspective_view(volume, lat, lon, height_asl, look_at, options))
    cam = make_camera(camera, **options)
    dirs_enu, valid = cam.cached_directions()
    rotation = enu_to_scene_rotation(lat, lon, lat0, lon0)
    dirs_scene, valid_pixels = _scene_directions(cam, rotation)
    observer = geodetic_to_scene(lat, lon, height_asl, lat0, lon0)
    sun_enu_observer = sun_scene @ rotation.T

    sun_key = tuple(np.round(sun_scene, 12))
    aerosol = _background_aerosol(aerosol, scene_vars)
    mean_albedo, aerosol_profile, classes = _STAGE_CACHE.get(("atmosphere inputs", fingerprint),
                                                              lambda: _atmosphere_inputs(volume))
    gas = build_gas_tables(aerosol, surface_albedo=mean_albedo, scene_aerosol_profile=aerosol_profile,
                           aerosol_class_aod=classes)
    settings = _settings_for_sun(settings, sun, sun_scene)
    clouds = settings.cloud_scattering
    cloud_optics = cloud_key = None
    if clouds.three_d:
        cloud_optics = _STAGE_CACHE.get(("cloud optics", fingerprint, clouds),
                                        lambda: scene_cloud_optics(volume, clouds))
        cloud_key = clouds


    # The entry holds the gas tables, so their id cannot be reused by other tables while it lives. The grid's
    # constants are looked up inside its build, after the old entry has gone: a new sun never holds two volumes.
    with _GRID_CONSTANTS_LOCK:
        def with_clouds(grid):  # the 3-D cloud scattering's diffuse solution (swim.rt.clouds), once per sun node
            if cloud_optics is None:
                return {}
            species = tuple(_STAGE_CACHE.peek(("packed species", fingerprint)))
            # solved for the node of the grid of suns nearest this sun and kept while the sun stays near it: the
            # frames of a series share it (swim.rt.diffuse_field.solve_sun)
            node = solve_sun(sun_scene, clouds.diffuse.sun_step_deg)
            key = ("diffuse field", fingerprint, tuple(np.round(node, 12)), id(gas), clouds)
            solved = _STAGE_CACHE.get_small(key, lambda: diffuse_field(volume, species, gas, node, cloud_optics,
                                                                       clouds.diffuse), named=gas)
            return cloud_constants(grid, species, sun_scene, cloud_optics, solved)

        def build_constants():
            grid = _STAGE_CACHE.get(("grid constants", fingerprint, sun_key, cloud_key),
                                    lambda: _grid_constants(volume, fingerprint, settings, sun_scene, cloud_optics))
            return {**grid, **atmosphere_constants(gas, sun_scene), **with_clouds(grid)}, gas

        consts, _ = _STAGE_CACHE.get(("constants", fingerprint, sun_key, id(gas), cloud_key), build_constants)

    def ray_phase(dirs):
        cos_theta = dirs @ sun_scene
        p_rayleigh, p_aerosol, p_stratospheric = _phase_functions(cos_theta, gas.depolarization, aerosol.type,
                                                                   aerosol.stratospheric)
        out = {"cos_theta": cos_theta, "cos_view_zenith": dirs[:, 2], "p_rayleigh": p_rayleigh,
               "p_aerosol": p_aerosol, "p_stratospheric": p_stratospheric}
        if cloud_optics is not None:
            out.update(cloud_ray_inputs(dirs, sun_scene, consts["cloud_species"], consts))
        return out

    def trace_directions(dirs, progress_rays):
        # the phase functions block by block (trace_rays), not held for every pixel of a big image at once
        return trace_rays(np.broadcast_to(observer, dirs.shape), dirs, consts, geometry, ray_phase, settings,
                          progress_rays)

    # MarchSettings.ray_table (the JAX kernel): the camera's rays kept on the device, computed once per camera,
    # observer and grid; a batch sends its rows' indices, and the phase functions are computed there too
    table = table_rows = phase_inputs = None
    if backend == "jax" and settings.resolved_ray_table():
        from .rt.ray_table import PhaseInputs, camera_ray_table, single_ray_table, trace_table_rows

        table, table_rows = camera_ray_table(observer, dirs_scene, valid_pixels, geometry, consts, settings)
        phase_inputs = PhaseInputs(tuple(float(x) for x in sun_scene), float(gas.depolarization), aerosol.type,
                                   aerosol.stratospheric)

    # Only the camera's valid pixels are traced (an all-sky image's corners are 21 % of its pixels), plus one
    # extra ray towards the sun for the direct-beam transmittance of the sun's disk (with the first batch).
    sun_out = {}

    def trace_tiled(flat, progress_rays=None, tiled=False):
        """Trace the pixels ``flat`` in tile order (neighbouring pixels one after the other: they cross the same
        cells): that order (indices into ``flat``) and the rays' outputs in it. With ``tiled``, ``flat`` is already
        in tile order (:func:`_scene_directions`) and traced as it is (the order: None)."""
        order = None if tiled else tile_order(flat, cam.shape)
        pixels = flat if tiled else flat[order]
        with_sun = not sun_out  # the sun's ray, last, with the first batch
        if table is not None:
            # (not the camera's ray, so not in its table: a one-row table of its own)
            extra = single_ray_table(observer, sun_scene, geometry, consts, settings) if with_sun else None
            result = trace_table_rows(table, table_rows[pixels], consts, phase_inputs, settings, progress_rays,
                                      extra=extra)
        else:
            dirs = np.empty((len(pixels) + with_sun, 3))
            np.take(dirs_scene, pixels, axis=0, out=dirs[:len(pixels)])
            if with_sun:
                dirs[-1] = sun_scene
            result = trace_directions(dirs, progress_rays)
        if with_sun:
            sun_out.update({key: value[-1] for key, value in result.items()})
            result = {key: value[:-1] for key, value in result.items()}
        return order, result

    def trace_pixels(flat, progress_rays=None):
        # the adaptive sampler's: the outputs in tile order with that order (the sampler scatters each into its
        # image once; put back into the order of flat first, each was copied twice: ~0.01 s of a 1024^2 all-sky
        # while the cores idled), only those that the image and the sampler's test read (the sampler keeps and
        # interpolates every array it is given)
        order, result = trace_tiled(flat, progress_rays)
        kept = (*IMAGE_OUTPUTS, "surface", "steps")
        return order, {key: value for key, value in result.items() if key in kept}

    ny, nx = cam.shape
    planes = {}  # image outputs (channel, y, x), NaN outside the camera's pixels
    if auto_exposure:  # from the image's radiance, on the host, before the colour stage
        white_level = None
    else:
        if white_level is None:
            white_level = SPACE_WHITE_LEVEL if height_asl > SPACE_VIEW_HEIGHT_M else DEFAULT_WHITE_LEVEL
        white_level = exposure_white_level(white_level, exposure)
    # MarchSettings.device_image: the image's planes and colour made on the device, then one copy of them to the host
    # (the colour there needs the white level before the image exists: not with auto exposure)
    device_image = table is not None and settings.resolved_device_image()
    device_colour = device_image and not auto_exposure
    device_rgb = None  # with it: the colour stage's codes (y, x, 3) and the pixels it left to the host (y, x)

    def planes_to_host(device_planes, *extra, colour):
        """The planes (on the device), with ``colour`` coloured there first, copied to the host at once with
        ``extra``: the planes as writable host arrays (a CPU device's may be read-only views), the codes and flags of
        the colour stage (None without ``colour``) and ``extra``."""
        codes = None
        if colour:
            from .color.srgb_device import solar_relative_to_srgb8_device

            codes = solar_relative_to_srgb8_device(device_planes["radiance"], white_level)
        import jax

        device_planes, codes, extra = jax.device_get((device_planes, codes, extra))
        return ({key: value if value.flags.writeable else value.copy() for key, value in device_planes.items()},
                codes, extra)

    if sampling is None and device_image and valid_pixels.size:
        log.info("tracing %d rays (%s camera %s), the image made on the device", int(valid.sum()) + 1, camera,
                 cam.shape)
        from .rt.image_device import planes_on_device

        traced = valid.reshape(-1)
        sun_table = single_ray_table(observer, sun_scene, geometry, consts, settings)
        # every valid pixel in tile order (the table's rows in order: it was built from valid_pixels), then the sun's
        # ray; their outputs and the planes stay on the device
        result = trace_table_rows(table, range(table.size), consts, phase_inputs, settings, progress,
                                  extra=sun_table, on_device=True)
        device_planes, sun_row, first_steps = planes_on_device(
            result, valid_pixels, (ny, nx), IMAGE_OUTPUTS, sun_keys=("tau_clear", "tau_hydrometeor", "surface", "steps"))
        del result
        planes, device_rgb, (sun_row, first_steps) = planes_to_host(device_planes, sun_row, first_steps,
                                                                    colour=device_colour)
        del device_planes
        sun_out.update(sun_row)
        march_samples = int(valid_pixels.size) * int(first_steps)  # the lockstep's steps, the same for every ray
    elif sampling is None:
        log.info("tracing %d rays (%s camera %s)", int(valid.sum()) + 1, camera, cam.shape)
        traced = valid.reshape(-1)
        pixels = valid_pixels  # every valid pixel, in tile order
        _, rays = trace_tiled(pixels, progress, tiled=True)
        planes = _scattered_planes({key: rays.pop(key) for key in IMAGE_OUTPUTS}, pixels, ny, nx)
        march_samples = int(rays["steps"].sum())
        del rays
    else:
        log.info("tracing adaptively (%s camera %s, %d valid pixels, tolerance %g, tau tolerance %g, clear tolerance "
                 "%g, coarse spacing %d, edge tests in cells of %d pixels)", camera, cam.shape, int(valid.sum()),
                 sampling.tolerance, sampling.tau_tolerance, sampling.clear_tolerance, sampling.coarse_spacing,
                 sampling.edge_test_size)
        # NaN outside the camera's pixels from the start: the planes are then copies in channel order, not masked
        # (np.where over a transposed view took ~30 ms of a 1024^2 image while the cores idled)
        if table is not None and settings.resolved_device_sampling():
            # MarchSettings.device_sampling: the sampler's image on the device, beside the camera's ray table
            from .rt.image_device import device_plane
            from .rt.image_sampling_device import sample_image_adaptive_device

            kept = (*IMAGE_OUTPUTS, "surface", "steps")
            sun_rows = {}

            def march_sun():
                # the sun's ray in a one-row batch of its own (with a full bucket's rows it would double the batch's
                # padded size; so march_samples counts no step that only the sun's ray needs, which the host's first
                # batch counts for all its rays where the sun's ray has a segment that none of the camera's has),
                # its outputs left on the device: queued without a wait, its row copied with the image's planes
                sun_table = single_ray_table(observer, sun_scene, geometry, consts, settings)
                sun_rows.update(trace_table_rows(sun_table, np.zeros(1, np.int64), consts, phase_inputs, settings,
                                                 on_device=True))

            def trace_on_device(pixels):
                # a bucketed batch (its last pixel repeated), the outputs left on the device; the sampler asks for
                # one batch at least (an empty one where nothing is traced), so the sun's ray is always marched here
                if not sun_rows:
                    march_sun()
                if len(pixels) == 0:  # no valid pixel in the image: its outputs' keys and types, without rows
                    return {key: value[:0] for key, value in sun_rows.items() if key in kept}
                # the batch's own pixels, then its last one repeated up to its bucket: the repeats marched as padding
                # (rays that start stopped, sample_image_adaptive_device drops their rows)
                own = int(np.argmax(pixels == pixels[-1])) + 1
                result = trace_table_rows(table, table_rows[pixels], consts, phase_inputs, settings, on_device=True,
                                          padding_from=own)
                return {key: value for key, value in result.items() if key in kept}

            out, traced = sample_image_adaptive_device(trace_on_device, valid, sampling, progress, outside=np.nan,
                                                       chunk=settings.resolved_chunk())
            # the image's planes (C, ny, nx) made on the device, then one copy of all the arrays to the host
            # (writable: a CPU device's may be read-only views) with the sun's row; with device_image coloured there
            # first
            device_planes = {key: device_plane(out.pop(key), ny, nx) for key in IMAGE_OUTPUTS}
            device_planes, device_rgb, (out, traced, sun_padded) = planes_to_host(device_planes, out, traced, sun_rows,
                                                                                  colour=device_colour)
            sun_out.update({key: value[0] for key, value in sun_padded.items()})  # the rest is the chunk's padding
            planes.update(device_planes)
            traced = np.asarray(traced)
        else:
            out, traced = sample_image_adaptive(trace_pixels, valid, sampling, progress,
                                                max_threads=min(threads(), 8), outside=np.nan)
            planes.update(_planes_of_samples(out, ny, nx))
        log.info("traced %d of %d valid pixels (%.1f %%)", int(traced.sum()), int(valid.sum()),
                 100.0 * traced.sum() / max(int(valid.sum()), 1))
        march_samples = int(out["steps"].sum())
        del out

    # Not where the march ran on a GPU: its chunks lived on the device, and on an H100 machine's host (16 cores, JAX's
    # runtime threads and their heaps) the two trims took 30-40 ms of a 0.4 s frame for ~0.2 GB of a 7 GB peak
    # (docs/decisions/0006-gpu-kernels.md)
    trim = ny * nx >= TRIM_MIN_PIXELS and not settings.on_accelerator()
    if trim:
        release_free_memory()  # the march's freed chunks, before the image is assembled
    radiance, recoloured, t_direct, t_aureole = _with_the_sun(planes, sun_out, cam, dirs_enu, valid, sun_enu_observer,
                                                              aureole=cloud_optics is not None)
    if auto_exposure:
        white_level = exposure_white_level(auto_white_level(radiance), exposure)
    # the colour stage is per pixel: in blocks of rows (float64 copies of a block) on up to 8 cores, its compiled
    # pass without the GIL (swim.color.srgb_cpu: ~0.05 s for a 1024^2 image on one core here, 0.26-0.39 s in NumPy)
    if device_rgb is not None:
        # the device's codes, but for the pixels whose spectrum needs clipping and those of the sun's disk (its
        # radiance added above): the host's colour stage for those few
        codes, need = device_rgb
        rgb = codes if codes.flags.writeable else codes.copy()
        redo = np.union1d(np.flatnonzero(need), recoloured)
        if redo.size:
            rgb.reshape(-1, 3)[redo] = solar_relative_to_srgb8(radiance.reshape(3, -1)[:, redo],
                                                               white_level=white_level)
    else:
        starts = range(0, ny, COLOUR_BLOCK_ROWS)

        def colour(r0):
            return solar_relative_to_srgb8(radiance[:, r0:r0 + COLOUR_BLOCK_ROWS], white_level=white_level)

        rgb = np.concatenate(parallel_map(colour, starts, min(threads(), 8)), axis=0)
    image = _image_dataset(
        radiance, rgb, planes, cam, camera=camera, settings=settings, sampling=sampling, sun=sun,
        sun_enu_observer=sun_enu_observer, scene=scene, observer=(lat, lon, height, height_asl), reference=(lat0, lon0),
        exposure=(white_level, auto_exposure, exposure), aerosol=aerosol,
        march=(march_samples + int(sun_out["steps"]), int(np.count_nonzero(traced)), coarsened_by),
        transmittances=(t_direct, t_aureole))
    del radiance, rgb
    if trim:
        release_free_memory()  # what the image's assembly freed, so the next render starts from the live arrays
    # A long-lived process that renders many grids keeps every program JAX compiled; near the process's limit of
    # memory mappings XLA's next executable would fail to map and leave the process to crash (swim.memory).
    release_compiled_programs(min_interval_s=COMPILED_PROGRAMS_CHECK_S)
    return image


@functools.lru_cache(maxsize=1)
def _image_coordinates() -> xr.Coordinates:
    """The coordinates of every image of :func:`render` (wavelength [nm], channel), with their indexes made once:
    making them took half of the output Dataset's ~0.3 ms. A Dataset copies the variables' attributes, and the
    indexes' values are read-only, so images that share them cannot change one another's."""
    return xr.Coordinates({"wavelength": xr.Variable("wavelength", np.asarray(WAVELENGTHS_NM, dtype=float),
                                                     {"units": "nm", "standard_name": "radiation_wavelength",
                                                      "long_name": "wavelength"}),
                           "channel": ["R", "G", "B"]})


def _default_perspective_view(volume, lat, lon, height_asl, look_at, options):
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


#: Image files by suffix: Pillow's format name and its options.
IMAGE_FORMATS = {".png": ("PNG", {}), ".jpg": ("JPEG", {"quality": 95}), ".jpeg": ("JPEG", {"quality": 95}),
                 ".tif": ("TIFF", {"compression": "tiff_deflate"}), ".tiff": ("TIFF", {"compression": "tiff_deflate"})}


def image_format(path, what="image file"):
    """Pillow's format name and options for an image file ``path`` by its suffix (:data:`IMAGE_FORMATS`).

    Raises
    ------
    SwimInputError
        If the suffix is not that of a format swim writes.
    """
    suffix = Path(path).suffix.lower()
    if suffix not in IMAGE_FORMATS:
        raise SwimInputError(f"{what} {path}: unknown image format {suffix or '(no suffix)'!r}; use "
                             f"{', '.join(sorted(IMAGE_FORMATS))}")
    return IMAGE_FORMATS[suffix]


def _image_text(image: xr.Dataset) -> dict:
    """What an image file says about itself: software, time, place, camera and sun (PNG text chunks)."""
    a = image.attrs
    where = (f"observer {a.get('observer_lat', float('nan')):.4f} N {a.get('observer_lon', float('nan')):.4f} E, "
             f"{a.get('observer_height_above_ground_m', float('nan')):g} m above ground")
    text = {"Software": str(a.get("source", "swim")), "Title": str(a.get("title", "SWIm image")),
            "Description": f"{a.get('camera', '')} camera; {where}; sun zenith {a.get('sun_zenith_deg', float('nan')):.2f} "
                           f"deg, azimuth {a.get('sun_azimuth_deg', float('nan')):.2f} deg; cloud scattering "
                           f"{a.get('cloud_scattering', '')}; scene: {a.get('scene_title', '')}",
            "Source": str(a.get("scene_source", "")), "Comment": str(a.get("references", ""))}
    if a.get("time"):
        text["Creation Time"] = str(a["time"])
    return text


def _rgb(image, caller):
    rgb = image.get("rgb") if isinstance(image, xr.Dataset) else None
    if rgb is None or rgb.ndim != 3 or rgb.shape[-1] != 3 or rgb.dtype != np.uint8:
        raise SwimInputError(f"{caller}: image must be a rendered image (swim.render) with an 'rgb' variable of "
                             "(rows, columns, 3) 8-bit sRGB values")
    return np.asarray(rgb.values, dtype=np.uint8)


#: Peak memory of a render per image pixel [bytes]: ~216 measured for all-sky images of the built-in scene between
#: 512^2 and 1024^2 pixels (its planes, the rays' outputs and the colour stage), with a margin; the scene's volume
#: comes on top.
RENDER_BYTES_PER_PIXEL = 250


def check_render_memory(n_pixels: int) -> None:
    """Refuse an image of ``n_pixels`` whose render would need more memory than the system has available.

    Raises
    ------
    SwimInputError
        If ``n_pixels`` x :data:`RENDER_BYTES_PER_PIXEL` exceeds :func:`swim.memory.available_memory_bytes`.
    """
    from .memory import available_memory_bytes

    need, have = n_pixels * RENDER_BYTES_PER_PIXEL, available_memory_bytes()
    if have is not None and need > have:
        raise SwimInputError(f"an image of {n_pixels:,} pixels needs about {need / 2**30:.1f} GiB to render, more than "
                             f"the {have / 2**30:.1f} GiB available: a smaller image, or check_memory=False "
                             f"(CLI --no-memory-check) to try anyway")


def write_image(image: xr.Dataset, path) -> Path:
    """Write the ``rgb`` of a rendered image as an 8-bit sRGB image file (atomically), in the format of the path's
    suffix: PNG (with text chunks: software, time, place, camera, sun), JPEG (quality 95) or TIFF (deflate).

    Raises
    ------
    SwimInputError
        If ``image`` is not a rendered image (no ``rgb`` of (rows, columns, 3) 8-bit values), the suffix is not one
        of :data:`IMAGE_FORMATS`, or the file cannot be written there (:func:`swim.io.atomic.check_output_path`).
    """
    from PIL import Image
    from PIL.PngImagePlugin import PngInfo

    rgb = _rgb(image, "write_image")
    kind, options = image_format(path)
    options = dict(options)
    if kind == "PNG":
        info = PngInfo()
        for key, value in _image_text(image).items():
            info.add_itxt(key, value)
        options["pnginfo"] = info
    atomic_write(Path(path), lambda tmp: Image.fromarray(rgb, "RGB").save(tmp, format=kind, **options))
    return Path(path)


def write_png(image: xr.Dataset, path) -> Path:
    """Write the ``rgb`` of a rendered image as an 8-bit sRGB PNG (atomically; :func:`write_image`).

    Raises
    ------
    SwimInputError
        If ``image`` is not a rendered image (no ``rgb`` of (rows, columns, 3) 8-bit values), or ``path`` names
        another format than PNG (:func:`write_image` writes JPEG and TIFF).
    """
    _rgb(image, "write_png")
    if Path(path).suffix.lower() != ".png":
        raise SwimInputError(f"write_png: {path} is not a .png file (write_image writes JPEG and TIFF by suffix)")
    return write_image(image, path)


def write_netcdf(image: xr.Dataset, path) -> Path:
    """Write a rendered image as CF-style netCDF-4 (atomically); radiance is compressed float32."""
    atomic_write(Path(path), lambda tmp: _netcdf_to(image, tmp))
    return Path(path)


def cf_dataset(image: xr.Dataset) -> xr.Dataset:
    """A rendered image as written to netCDF (CF-1.8): the ``channel`` labels as a character variable
    ``channel_name`` (CF 6.1.1 labels; CF 2.2 allows no variable-length strings) instead of a string coordinate."""
    if "channel" in image.coords and image["channel"].dtype.kind in "OUS":
        names = np.asarray(image["channel"].values).astype("S1")
        image = image.drop_vars("channel").assign_coords(
            channel_name=xr.Variable("channel", names, {"long_name": "colour channel of rgb (R, G, B)"}))
    return image


def _netcdf_to(image, tmp):
    image = cf_dataset(image)
    encoding = {name: {"zlib": True, "complevel": 4} for name in image.data_vars}
    if "channel_name" in image.coords:
        encoding["channel_name"] = {"dtype": "S1"}
    image.to_netcdf(tmp, format="NETCDF4", encoding=encoding)


def write_outputs(image: xr.Dataset, image_path=None, netcdf_path=None):
    """Write a rendered image's image file (:func:`write_image`) and netCDF file (:func:`write_netcdf`), each where
    given, both or neither: the netCDF file is written to a temporary file, the image put in place, and only then
    the netCDF file, so that an error leaves neither new file (and an image is never left without its netCDF)."""
    if netcdf_path is None:
        if image_path is not None:
            write_image(image, image_path)
        return
    if image_path is not None:
        image_format(image_path)

    def both(tmp):
        _netcdf_to(image, tmp)
        if image_path is not None:
            write_image(image, image_path)

    atomic_write(Path(netcdf_path), both)
