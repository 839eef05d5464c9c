"""Which columns of a model grid a camera's rays can reach: crop big grids before anything is loaded in full.

A ray from the observer can only meet the model grid inside the shell between the sea-level sphere (radius R,
:data:`swim.constants.EARTH_RADIUS_M`) and the grid's top (the highest model level, R + top). For every pixel
of the camera (and the ray towards the sun that gives the sun's disk) :func:`reachable_index_window` clips the
ray to that shell, samples the clipped segment, maps the samples to fractional grid indices with the columns'
own positions (``lat``/``lon``; the 1-D ``x``/``y`` of a grid that reaches beyond the limb, as the optical volume
does) and takes the bounding box over all rays, widened by

* a margin of cells for the samples, the bilinear lookups and the terrain slope's central differences, and
  the bilinear spread of the Step 1a sweep (one cell per block of levels, :mod:`swim.rt.solar`);
* a sun-ward margin: clouds and mountains outside the view shade it (Step 1a sweeps towards the sun), so the
  window reaches ``top * tan(sun zenith)`` further towards the sun, capped at :data:`SUN_MARGIN_CAP_M`;
* the observer's own column (the terrain under the observer sets its height above sea level).

:func:`crop_scene_to_view` applies the window with ``scene.isel`` (lazy for dask-backed or lazily opened
netCDF scenes) after fixing the reference point of the scene frame to that of the whole grid. Before the crop
it reads only ``lat``, ``lon`` (and ``x``, ``y``), the two highest levels of ``height``, the edges of
``terrain_height`` and a few of its cells under the observer. See ``docs/rendering.md``, "Cropping big grids".

The reach of a camera's rays (most of the window's time) is remembered for the next window with the same camera,
observer and grid, so that a repeated render or a fixed camera's time series redoes only the ray towards the sun
and the sun-ward margin (docs/decisions/0006-gpu-kernels.md).
"""

from __future__ import annotations

import logging
import math

import numpy as np
import xarray as xr
import xxhash

from ..constants import EARTH_RADIUS_M
from ..digest import array_digest, update_with_array
from ..errors import SwimInputError
from ..frames import enu_to_scene_rotation, geodetic_to_scene, orthographic_xy, ray_sphere_intersections
from ..io.scene import domain_centre
from .cameras import Camera, make_camera

log = logging.getLogger(__name__)

__all__ = [
    "DEFAULT_MARGIN_CELLS",
    "SUN_MARGIN_CAP_M",
    "MAX_CROP_FRACTION",
    "CROP_BLOCK_FRACTION",
    "MIN_CROP_BLOCK",
    "SAMPLES_PER_RAY",
    "with_reference_point",
    "reachable_index_window",
    "snap_window_to_blocks",
    "crop_scene_to_view",
]

#: Cells added on every side of the reached box: 3 for the spacing of the samples along a ray, the bilinear
#: lookups and the terrain slope's central differences, plus 11 for the Step 1a sweep, whose bilinear
#: interpolation between blocks of 16 levels (``swim.rt.solar.DIRECT_LEVELS``) widens what a grid point depends
#: on by one cell per block, up to 10 blocks for the 160 levels of an optical volume, and one cell for its
#: sub-steps.
DEFAULT_MARGIN_CELLS = 14
#: Largest sun-ward margin [m] (300 km). The sun-ward margin is ``top * tan(sun zenith)``; it reaches the cap
#: for a sun lower than about 86 deg zenith under a 20 km grid top. Clouds further than this towards a low sun
#: no longer shade the crop (the sweep sees cloud-free air beyond a grid's edge).
SUN_MARGIN_CAP_M = 300e3
#: A window that holds more than this fraction of the grid's columns is not worth a crop: the scene is returned
#: unchanged.
MAX_CROP_FRACTION = 0.9
#: The render's crop widens its window to whole blocks of columns, each block a power of two near this fraction of the
#: window's extent (at least :data:`MIN_CROP_BLOCK` columns): a camera that moves by less than a block keeps the same
#: crop, so the frames of a fly-through reuse its optical volume and Step 1a instead of rebuilding them
#: (docs/decisions/0007-scene-set-up.md). The window then holds up to ~2 / 8 more columns per axis.
CROP_BLOCK_FRACTION = 1.0 / 8.0
#: Smallest block of columns of :data:`CROP_BLOCK_FRACTION`.
MIN_CROP_BLOCK = 8
#: Points sampled along each ray's segment inside the shell (both ends included).
SAMPLES_PER_RAY = 9
#: Smallest sine of the sun's elevation in the sun-ward margin (as the sweep, swim.rt.solar).
_MIN_SUN_ELEVATION_SINE = 0.01
#: Rays processed together (bounds the memory of the samples: rays x samples x 3 float64).
_RAY_CHUNK = 16384
#: Pixels of a camera above which the window is computed from a subset of them (:func:`_representative_pixels`).
_MAX_SAMPLED_PIXELS = 40_000
#: Half-width of the bands about the horizon and the horizon's dip kept in full, as a sine of elevation (3 deg).
_HORIZON_BAND_SINE = 0.0523


# ---------------------------------------------------------------------------------------------------------------
# reading the few fields needed before the crop


def _horizontal(scene: xr.Dataset, name: str) -> xr.DataArray:
    """A (y, x) variable, a length-1 ``time`` dimension dropped, without loading it."""
    if name not in scene.variables:
        raise SwimInputError(
            f"scene lacks required variable '{name}': needs height(z,y,x) [m above sea level], lat(y,x) "
            "[degrees_north], lon(y,x) [degrees_east] and terrain_height(y,x) [m]"
        )
    da = scene[name]
    if "time" in da.dims and da.sizes["time"] == 1:
        da = da.isel(time=0)
    if set(da.dims) != {"y", "x"} or da.ndim != 2:
        raise SwimInputError(f"scene variable '{name}' has dims {tuple(da.dims)}; expected ('y', 'x')")
    return da.transpose("y", "x")


def _in_memory(scene: xr.Dataset, name: str, dims: tuple) -> np.ndarray | None:
    """The values of ``name`` as a NumPy array with axes ``dims`` (a length-1 ``time`` dropped), without an
    xarray object on the way, where they are held in memory; None where they are lazy (dask, a file) or shaped
    otherwise (the xarray path then reads them, and reports what is wrong). A repeated render of a small image
    spent ~3 ms of its ~25 ms making DataArrays for the few values the window needs
    (docs/decisions/0009-work-around-the-march.md)."""
    var = scene.variables.get(name)
    if var is None or type(var._data) is not np.ndarray:  # noqa: SLF001 - only a plain in-memory array, not read
        return None
    data, var_dims = var._data, var.dims  # noqa: SLF001
    if "time" in var_dims and var.sizes["time"] == 1:
        data = data[(slice(None),) * var_dims.index("time") + (0,)]
        var_dims = tuple(d for d in var_dims if d != "time")
    if set(var_dims) != set(dims) or len(var_dims) != len(dims):
        return None
    return np.transpose(data, [var_dims.index(d) for d in dims])


def _horizontal_values(scene: xr.Dataset, name: str, j=slice(None), i=slice(None)) -> np.ndarray:
    """Values [float] of the (y, x) variable ``name`` at rows ``j`` and columns ``i`` (slices or index lists; see
    :func:`_horizontal`), only those read from a lazy variable."""
    values = _in_memory(scene, name, ("y", "x"))
    if values is None:
        return np.asarray(_horizontal(scene, name).isel(y=j, x=i).values, dtype=float)
    return np.asarray(values[j][:, i], dtype=float)


def _finite(name: str, values: np.ndarray) -> np.ndarray:
    bad = ~np.isfinite(values)
    if bad.any():
        raise SwimInputError(
            f"scene variable '{name}' has {int(bad.sum())} non-finite value(s) (NaN or inf) out of {values.size}; "
            "every value must be finite"
        )
    return values


def _lat_lon(scene: xr.Dataset) -> tuple[np.ndarray, np.ndarray]:
    """Latitude and longitude [deg] of the columns, shape (ny, nx) each (2-D: cheap to load)."""
    lat = _finite("lat", _horizontal_values(scene, "lat"))
    lon = _finite("lon", _horizontal_values(scene, "lon"))
    if lat.shape != lon.shape:
        raise SwimInputError(f"scene variables 'lat' {lat.shape} and 'lon' {lon.shape} differ in shape")
    return lat, lon


def _xy_axes(scene: xr.Dataset, shape: tuple):
    """The scene's 1-D coordinates ``x`` (nx,) and ``y`` (ny,) [m] where its grid reaches beyond the limb (some column
    with ``x^2 + y^2 >= R^2``, whose lat/lon cannot give its place), else None (the columns are then placed by their
    lat/lon): the columns' positions of the optical volume (``swim.optics.volume``)."""
    axes = []
    for axis, n in (("x", shape[1]), ("y", shape[0])):
        if axis not in scene.coords:  # (coords.get would give a bare dimension's 0, 1, 2, ...)
            return None
        c = scene.coords[axis]
        if c.dims != (axis,) or c.size != n:
            return None
        axes.append(_finite(axis, np.asarray(c.values, dtype=float)))
    x, y = axes
    if not np.any(x[None, :] ** 2 + y[:, None] ** 2 >= EARTH_RADIUS_M**2):
        return None
    return x, y


def _given_reference(scene: xr.Dataset):
    """(lat0, lon0) [deg] from the scene's attributes, or None where they are absent.

    Raises
    ------
    SwimInputError
        Where they are present but not finite numbers (as :func:`swim.io.scene.validate_scene`).
    """
    if "reference_lat" not in scene.attrs or "reference_lon" not in scene.attrs:
        return None
    ref = []
    for key in ("reference_lat", "reference_lon"):
        try:
            value = float(scene.attrs[key])
        except (TypeError, ValueError) as exc:
            raise SwimInputError(f"scene attribute {key}={scene.attrs[key]!r} is not a number [deg]") from exc
        if not np.isfinite(value):
            raise SwimInputError(f"scene attribute {key} is not finite")
        ref.append(value)
    return tuple(ref)


def with_reference_point(scene: xr.Dataset) -> xr.Dataset:
    """The scene with its frame's reference point set explicitly, so that a crop does not move the frame.

    Parameters
    ----------
    scene : xarray.Dataset
        Scene with ``lat``, ``lon`` (y, x) [deg]; any backing (numpy, dask, lazy netCDF): only ``lat`` and
        ``lon`` are read, and only when the reference point is absent.

    Returns
    -------
    xarray.Dataset
        ``scene`` itself when it has ``reference_lat``/``reference_lon`` attributes (or cannot give a centre:
        then :func:`swim.io.scene.validate_scene` reports the problem); else a shallow copy (no data copied or
        loaded) with both set to the centre of the whole grid, the point that
        :func:`~swim.io.scene.validate_scene` would choose (:func:`~swim.io.scene.domain_centre`).
    """
    if not isinstance(scene, xr.Dataset) or {"reference_lat", "reference_lon"} <= set(scene.attrs):
        return scene
    try:
        lat0, lon0 = domain_centre(*_lat_lon(scene))
    except SwimInputError:
        return scene
    return scene.assign_attrs(reference_lat=lat0, reference_lon=lon0)


#: :meth:`_Columns.grid_top` of lazy height fields, by dask token (8 at most, the oldest dropped first).
_LAZY_GRID_TOPS = {}
#: The last grid's column geometry (:class:`_Columns`), by a digest of its ``lat``, ``lon`` and reference point: a
#: repeated render or a time series of one grid does not project and fit its columns again (~3 ms for the RICO
#: LES's 122 x 106 columns, ~60 ms for 400 x 400).
_COLUMN_GEOMETRY = {}


class _Columns:
    """The grid's columns in the scene frame and a robust map from horizontal coordinates to grid indices."""

    def __init__(self, scene: xr.Dataset):
        if not isinstance(scene, xr.Dataset):
            raise SwimInputError(f"scene must be an xarray.Dataset; got {type(scene).__name__}")
        lat, lon = _lat_lon(scene)
        ref = _given_reference(scene)
        axes = _xy_axes(scene, lat.shape)
        key = (array_digest(lat), array_digest(lon), ref) + tuple(array_digest(a) for a in axes or ())
        cached = _COLUMN_GEOMETRY.get(key)
        if cached is None:
            if np.abs(lat).max() > 90.0:
                raise SwimInputError(f"lat: range [{lat.min():.4g}, {lat.max():.4g}] is outside [-90, 90] degrees_north")
            self.lat0, self.lon0 = ref if ref is not None else domain_centre(lat, lon)
            self.shape = lat.shape
            # as the optical volume places them (swim.optics.volume): a grid beyond the limb by its own x, y (those
            # columns have no lat/lon of their own), any other by its lat/lon
            self.gx, self.gy = np.meshgrid(*axes) if axes else orthographic_xy(lat, lon, self.lat0, self.lon0)
            self._fit_affine()
            for a in (self.gx, self.gy):
                a.flags.writeable = False  # shared by the later _Columns of this grid
            self._digest = self._positions_digest()
            _COLUMN_GEOMETRY.clear()
            _COLUMN_GEOMETRY[key] = {name: getattr(self, name) for name in
                                     ("lat0", "lon0", "shape", "gx", "gy", "origin", "matrix", "_digest")}
        else:
            self.__dict__.update(cached)
        self.scene = scene

    def digest(self) -> str:
        """Digest of the columns' positions and the reference point (what the index map depends on)."""
        return self._digest

    def _positions_digest(self) -> str:
        h = xxhash.xxh3_128()
        update_with_array(h, self.gx)
        update_with_array(h, self.gy)
        h.update(f"{self.lat0!r} {self.lon0!r} {self.shape}".encode())
        return h.hexdigest()

    # ---- index map

    def _fit_affine(self) -> None:
        """Least-squares affine (i, j) -> (x, y) on a subsample of the columns: the first guess of the map."""
        ny, nx = self.shape
        jj, ii = np.meshgrid(np.arange(0, ny, max(1, ny // 64)), np.arange(0, nx, max(1, nx // 64)), indexing="ij")
        design = np.stack([np.ones(ii.size), ii.ravel(), jj.ravel()], axis=1)
        target = np.stack([self.gx[jj, ii].ravel(), self.gy[jj, ii].ravel()], axis=1)
        coef, *_ = np.linalg.lstsq(design, target, rcond=None)
        self.origin = coef[0]
        self.matrix = coef[1:].T  # columns d(x, y)/di and d(x, y)/dj [m per cell]
        if ny < 2 or nx < 2 or not abs(np.linalg.det(self.matrix)) > 0:
            raise SwimInputError(
                f"scene grid must have at least 2 distinct columns along y and x; got (y, x) = {self.shape}"
            )

    def indices(self, x, y, iterations: int = 8):
        """Fractional grid indices (i, j) of horizontal coordinates (x, y) [m], any (equal) shape.

        Newton's method on the bilinear interpolation of the columns' positions, from the affine guess: exact
        for any smooth grid (map projections included) to well below a cell. Beyond the grid the result
        extends the edge cell's bilinear patch linearly.
        """
        ny, nx = self.shape
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        i, j = np.linalg.solve(self.matrix, np.stack([x - self.origin[0], y - self.origin[1]]).reshape(2, -1))
        i, j = i.reshape(x.shape), j.reshape(x.shape)
        gx, gy = self.gx, self.gy
        for _ in range(iterations):
            ic, jc = np.clip(i, 0.0, nx - 1.0), np.clip(j, 0.0, ny - 1.0)
            i0 = np.minimum(ic.astype(np.intp), nx - 2)
            j0 = np.minimum(jc.astype(np.intp), ny - 2)
            fi, fj = ic - i0, jc - j0
            corners = []
            for g in (gx, gy):
                g00, g10, g01, g11 = g[j0, i0], g[j0, i0 + 1], g[j0 + 1, i0], g[j0 + 1, i0 + 1]
                value = g00 * (1 - fi) * (1 - fj) + g10 * fi * (1 - fj) + g01 * (1 - fi) * fj + g11 * fi * fj
                d_di = (g10 - g00) * (1 - fj) + (g11 - g01) * fj
                d_dj = (g01 - g00) * (1 - fi) + (g11 - g10) * fi
                corners.append((value, d_di, d_dj))
            (vx, a, b), (vy, c, d) = corners
            det = a * d - b * c
            det = np.where(np.abs(det) > 0, det, np.inf)
            rx, ry = x - vx, y - vy
            step_i = (d * rx - b * ry) / det
            step_j = (a * ry - c * rx) / det
            i_new, j_new = ic + step_i, jc + step_j
            converged = np.all(np.abs(i_new - i) < 1e-3) and np.all(np.abs(j_new - j) < 1e-3)
            i, j = i_new, j_new
            if converged:
                break
        return i, j

    def cells_per_metre(self, i, j) -> np.ndarray:
        """Inverse local Jacobian (2, 2) [cells per m] of the grid at index (i, j)."""
        ny, nx = self.shape
        i0 = int(np.clip(i, 0, nx - 2))
        j0 = int(np.clip(j, 0, ny - 2))
        jac = np.array([[self.gx[j0, i0 + 1] - self.gx[j0, i0], self.gx[j0 + 1, i0] - self.gx[j0, i0]],
                        [self.gy[j0, i0 + 1] - self.gy[j0, i0], self.gy[j0 + 1, i0] - self.gy[j0, i0]]])
        if not abs(np.linalg.det(jac)) > 0:
            jac = self.matrix
        return np.linalg.inv(jac)

    # ---- the few fields read before the crop

    def grid_top(self) -> float:
        """An upper bound [m above sea level] of the optical volume's top: the highest model level, plus half
        the top layer (the volume's top interface) and a spacing of its regular levels.

        Of a lazy (dask) ``height`` the result is remembered by the field's dask token (its graph: for a file,
        its name and modification time), so that the renders of one lazily opened big grid read its four
        levels once (0.8 s for the CONUS-size benchmark grid)."""
        values = _in_memory(self.scene, "height", ("z", "y", "x"))
        if values is not None:
            return self._grid_top_of(lambda z: values[z], values.shape[0])
        height = self.scene["height"]
        if height.chunks is None:
            return self._grid_top(height)
        import dask.base

        token = dask.base.tokenize(height)
        if token not in _LAZY_GRID_TOPS:
            top = self._grid_top(height)
            if len(_LAZY_GRID_TOPS) >= 8:
                _LAZY_GRID_TOPS.pop(next(iter(_LAZY_GRID_TOPS), None), None)
            _LAZY_GRID_TOPS[token] = top
            return top
        return _LAZY_GRID_TOPS[token]

    @staticmethod
    def _grid_top(height) -> float:
        if "time" in height.dims and height.sizes["time"] == 1:
            height = height.isel(time=0)
        if set(height.dims) != {"z", "y", "x"} or height.ndim != 3:
            raise SwimInputError(f"scene variable 'height' has dims {tuple(height.dims)}; expected ('z', 'y', 'x')")
        height = height.transpose("z", "y", "x")
        return _Columns._grid_top_of(lambda z: height.isel(z=z).values, height.sizes["z"])

    @staticmethod
    def _grid_top_of(levels_at, nz: int) -> float:
        """:meth:`grid_top` from ``levels_at(z)``, the heights (len(z), ny, nx) of the levels in the list z."""
        if nz < 2:
            return float(_finite("height", np.asarray(levels_at([nz - 1]), dtype=float)).max())
        levels = _finite("height", np.asarray(levels_at(sorted({0, 1, nz - 2, nz - 1})), dtype=float))
        top, below = levels[-1], levels[-2]
        interface = float(np.max(top + 0.5 * np.abs(top - below)))
        # The optical volume's regular levels run from its bottom (>= -500 m) to at least the top interface, at
        # most max(finest median layer, depth / 159) apart (swim.optics.volume); its top lies less than one
        # spacing above the interface. The finest median layer is at most the lowest one's median.
        finest = float(np.median(np.abs(levels[1] - levels[0])))
        return interface + max(finest, (interface + 500.0) / 159.0)

    def terrain(self, j: slice, i: slice) -> np.ndarray:
        """A piece of ``terrain_height`` [m] (the only part of it read before the crop)."""
        return _finite("terrain_height", _horizontal_values(self.scene, "terrain_height", j, i))

    def edge_terrain_max(self) -> float:
        """Highest terrain [m] on the grid's edge: beyond the grid the ray march continues the terrain at its
        edge heights (clamped), so only points below this height beyond the grid can touch edge cells."""
        rows = _finite("terrain_height", _horizontal_values(self.scene, "terrain_height", j=[0, -1]))
        cols = _finite("terrain_height", _horizontal_values(self.scene, "terrain_height", i=[0, -1]))
        return float(max(rows.max(), cols.max()))


# ---------------------------------------------------------------------------------------------------------------
# the window


def _as_directions(directions, valid, dip_sine=0.0):
    """Unit ENU directions (n, 3) of the valid pixels of a camera or of an array of directions.

    Of a camera with more than :data:`_MAX_SAMPLED_PIXELS` valid pixels only a subset is used
    (:func:`_representative_pixels`)."""
    if isinstance(directions, Camera):
        dirs, mask = directions.cached_directions()
        valid = mask if valid is None else np.asarray(valid, dtype=bool) & mask
        if valid.shape == dirs.shape[:-1]:
            valid = valid & _representative_pixels(dirs, valid, dip_sine)
    else:
        dirs = np.asarray(directions, dtype=float)
    if dirs.ndim < 1 or dirs.shape[-1] != 3:
        raise SwimInputError(f"directions must be ENU unit vectors of shape (..., 3); got shape {dirs.shape}")
    dirs = dirs.reshape(-1, 3)
    keep = np.all(np.isfinite(dirs), axis=1)
    if valid is not None:
        valid = np.asarray(valid, dtype=bool).reshape(-1)
        if valid.size != len(dirs):
            raise SwimInputError(f"valid has {valid.size} entries for {len(dirs)} directions")
        keep &= valid
    dirs = dirs[keep]
    norm = np.linalg.norm(dirs, axis=1, keepdims=True)
    ok = norm[:, 0] > 0
    return dirs[ok] / norm[ok]


def _representative_pixels(dirs, valid, dip_sine):
    """The pixels (ny, nx) bool of a camera image whose rays bound the reach as all its pixels do.

    The farthest points of the reach come from the lowest rays above the horizon (and, for an observer
    above the ground, from the rays that graze the earth below the horizon's dip): every pixel within
    :data:`_HORIZON_BAND_SINE` of the horizon and of the dip is kept, and so is every pixel on the edge of the
    valid field (the field of view's borders). Elsewhere every k-th row and column is enough: those rays
    reach less far than the horizon's at the same azimuth, and neighbouring rays end within a small fraction
    of a cell of each other. At 1024 x 1024 pixels this takes the window's time from ~5 s to ~1 s.
    """
    n = int(valid.sum())
    stride = int(math.ceil(math.sqrt(n / _MAX_SAMPLED_PIXELS)))
    if stride <= 1:
        return valid
    ny, nx = valid.shape
    lattice = np.zeros_like(valid)
    lattice[::stride, ::stride] = True
    padded = np.pad(valid, 1, constant_values=False)
    interior = padded[:-2, 1:-1] & padded[2:, 1:-1] & padded[1:-1, :-2] & padded[1:-1, 2:] & valid
    with np.errstate(invalid="ignore"):
        up = np.nan_to_num(dirs[..., 2], nan=2.0)
        near = (np.abs(up) < _HORIZON_BAND_SINE) | (np.abs(up + dip_sine) < _HORIZON_BAND_SINE)
    return valid & (lattice | ~interior | near)


def _observer(lat, lon, height, lat0, lon0):
    lat = lat0 if lat is None else float(lat)
    lon = lon0 if lon is None else float(lon)
    if not (-90 <= lat <= 90):
        raise SwimInputError(f"observer lat must be in [-90, 90] deg, got {lat}")
    if not np.isfinite(lon):
        raise SwimInputError(f"observer lon must be finite [deg], got {lon}")
    if height is None or not np.isfinite(height) or height < 0:
        raise SwimInputError(f"observer height must be >= 0 m above the ground, got {height}")
    return lat, lon, float(height)


#: The reach of the last camera's rays (:func:`_window`): key -> (index box or None, rays that reach the shell,
#: {(sun, margin_cells, sun_margin_cap_m): the window and its description}).
_CAMERA_REACH = {}
#: Windows remembered per camera entry of :data:`_CAMERA_REACH` (one per sun and margins).
_WINDOWS_PER_CAMERA = 16


def _merge(box, other):
    """The index box [i_min, i_max, j_min, j_max] grown to hold ``other`` (None: nothing to add)."""
    if other is None:
        return box
    return [min(box[0], other[0]), max(box[1], other[1]), min(box[2], other[2]), max(box[3], other[3])]


def _rays_box(columns, dirs, grounds, lat, lon, height, top, edge_max, samples):
    """(index box or None, rays) of rays (n, 3) in the scene frame from the observer: the bounding box of the
    grid indices of their samples inside the shell [R, R + top], and the most rays that reach it from any of the
    observer's ``grounds`` [m] (terrain heights under the observer)."""
    ny, nx = columns.shape
    lat0, lon0 = columns.lat0, columns.lon0
    radius, outer = EARTH_RADIUS_M, EARTH_RADIUS_M + top
    fractions = np.linspace(0.0, 1.0, samples)
    box, n_rays = None, []
    # The terrain under the observer lies between the patch's extremes; the reach changes monotonically with
    # the observer's height, so the two extremes bound it.
    for ground in grounds:
        origin = geodetic_to_scene(lat, lon, ground + height, lat0, lon0)
        n_rays.append(0)
        for lo in range(0, len(dirs), _RAY_CHUNK):
            d = dirs[lo:lo + _RAY_CHUNK]
            # The part of each ray inside the shell [R, R + top], as the ray march clips it (ray_segments).
            k1, k2 = ray_sphere_intersections(origin, d, outer)
            s0 = np.maximum(np.nan_to_num(k1, nan=0.0), 0.0)
            s1 = np.where(np.isfinite(k2), k2, -np.inf)
            g1, _ = ray_sphere_intersections(origin, d, radius)
            sea = np.isfinite(g1) & (g1 > 0) & (g1 < s1)
            s1 = np.where(sea, g1, s1)
            ok = s1 > s0
            if not ok.any():
                continue
            n_rays[-1] += int(ok.sum())
            s = s0[ok, None] + (s1[ok] - s0[ok])[:, None] * fractions[None, :]
            p = origin + s[..., None] * d[ok][:, None, :]
            r = np.linalg.norm(p, axis=-1)
            # Only the front hemisphere about the reference point has unique grid coordinates.
            front = p[..., 2] > 0
            x, y, h = radius * p[..., 0] / r, radius * p[..., 1] / r, r - radius
            i, j = columns.indices(x[front], y[front])
            inside = (i >= -1) & (i <= nx) & (j >= -1) & (j <= ny)
            # Beyond the grid only the terrain (continued at the clamped edge heights) is looked up.
            keep = inside | (h[front] <= edge_max + 1.0)
            if np.any(keep):
                i, j = np.clip(i[keep], 0, nx - 1), np.clip(j[keep], 0, ny - 1)
                box = _merge([float(i.min()), float(i.max()), float(j.min()), float(j.max())], box)
    return box, max(n_rays)


def _window(columns: _Columns, directions, *, lat, lon, height, valid, sun_direction, margin_cells, sun_margin_cap_m,
            samples_per_ray):
    """The window of :func:`reachable_index_window` and a short description for the log."""
    ny, nx = columns.shape
    lat0, lon0 = columns.lat0, columns.lon0
    lat, lon, height = _observer(lat, lon, height, lat0, lon0)
    if not (margin_cells >= 0 and sun_margin_cap_m >= 0):
        raise SwimInputError(f"margin_cells ({margin_cells}) and sun_margin_cap_m ({sun_margin_cap_m}) must be >= 0")
    margin_cells = int(math.ceil(margin_cells))
    samples = max(int(samples_per_ray), 2)
    top = columns.grid_top()

    # The observer's column, found as the renderer finds it (swim.pipeline.scene_stage.terrain_at: clamped to the grid).
    p_ground = geodetic_to_scene(lat, lon, 0.0, lat0, lon0)
    io, jo = (float(v) for v in columns.indices(p_ground[0], p_ground[1]))
    ic, jc = min(max(io, 0.0), nx - 1.0), min(max(jo, 0.0), ny - 1.0)
    i0, j0 = min(int(ic), nx - 2), min(int(jc), ny - 2)
    patch = columns.terrain(slice(max(j0 - 1, 0), j0 + 3), slice(max(i0 - 1, 0), i0 + 3))
    box = [float(i0 - 1), float(i0 + 2), float(j0 - 1), float(j0 + 2)]

    grounds = sorted({float(patch.min()), float(patch.max())})
    edge_max = columns.edge_terrain_max()
    sun = None
    if sun_direction is not None:
        sun = np.asarray(sun_direction, dtype=float).reshape(3)
        if not (np.all(np.isfinite(sun)) and np.linalg.norm(sun) > 0):
            raise SwimInputError(f"sun_direction must be a finite, non-zero vector (3,); got {sun}")
        sun = sun / np.linalg.norm(sun)

    # The camera's rays (most of the window's time, ~0.4 s at 1024 x 1024) are remembered for the renders that
    # follow with the same camera, observer and grid: a time series or a repeated render redoes only the sun. The
    # windows made with them are remembered too, per sun and margins: a render repeated under the same sun (an
    # assimilation's calls of the operator on one grid) does not trace the sun's ray again (~0.5 ms, a 30th of a
    # 41 x 41 render; docs/decisions/0009-work-around-the-march.md).
    key = None
    if isinstance(directions, Camera) and valid is None:
        key = (directions, columns.digest(), lat, lon, height, top, edge_max, tuple(grounds), samples)
    cached = _CAMERA_REACH.get(key) if key is not None else None
    window_key = (None if sun is None else tuple(sun), margin_cells, sun_margin_cap_m)
    if cached is not None and window_key in cached[2]:
        return cached[2][window_key]
    rotation = enu_to_scene_rotation(lat, lon, lat0, lon0)
    # sine of the depression of the apparent horizon (the rays grazing the sea-level sphere) below the level
    dip_sine = math.sqrt(max(1.0 - (EARTH_RADIUS_M / (EARTH_RADIUS_M + max(float(patch.max()) + height, 0.0))) ** 2, 0.0))

    def reach(dirs_enu):
        return _rays_box(columns, dirs_enu @ rotation, grounds, lat, lon, height, top, edge_max, samples)

    if cached is None:
        cached = (*reach(_as_directions(directions, valid, dip_sine)), {})
        if key is not None:
            _CAMERA_REACH.clear()  # one camera's entry: a fly-through's frames never pile up
            _CAMERA_REACH[key] = cached
    camera_box, n_rays, windows = cached
    box = _merge(box, camera_box)
    if sun is not None:
        # the ray towards the sun gives the sun disk's transmittance (already in the scene frame)
        sun_box, sun_rays = _rays_box(columns, sun[None], grounds, lat, lon, height, top, edge_max, samples)
        box = _merge(box, sun_box)
        n_rays += sun_rays

    i_min, i_max, j_min, j_max = box
    i_lo, i_hi = math.floor(i_min) - margin_cells, math.floor(i_max) + 1 + margin_cells
    j_lo, j_hi = math.floor(j_min) - margin_cells, math.floor(j_max) + 1 + margin_cells

    # Sun-ward margin: the Step 1a sweep climbs towards the sun; top * tan(zenith) horizontally, capped.
    to_cells = columns.cells_per_metre(0.5 * (i_min + i_max), 0.5 * (j_min + j_max))
    if sun_direction is None:
        # Unknown sun: the capped margin on every side.
        reach = np.abs(to_cells) @ np.array([sun_margin_cap_m, sun_margin_cap_m])
        sun_cells = (-reach, reach)
        sun_margin_m = sun_margin_cap_m
    else:
        horizontal = float(np.hypot(sun[0], sun[1]))
        sun_margin_m = min(top * horizontal / max(sun[2], _MIN_SUN_ELEVATION_SINE), sun_margin_cap_m)
        shift = to_cells @ (sun[:2] / max(horizontal, 1e-12) * sun_margin_m) * 1.05 if horizontal > 0 else np.zeros(2)
        sun_cells = (np.minimum(shift, 0.0), np.maximum(shift, 0.0))
    # (round-off of a zero component must not add a cell)
    i_lo += math.floor(sun_cells[0][0] + 1e-6)
    j_lo += math.floor(sun_cells[0][1] + 1e-6)
    i_hi += math.ceil(sun_cells[1][0] - 1e-6)
    j_hi += math.ceil(sun_cells[1][1] - 1e-6)

    i_lo, i_hi = max(i_lo, 0), min(i_hi, nx - 1)
    j_lo, j_hi = max(j_lo, 0), min(j_hi, ny - 1)
    # At least 2 x 2 columns (the optical volume needs them).
    if i_hi - i_lo < 1:
        i_lo, i_hi = max(min(i_lo, nx - 2), 0), min(max(i_lo, 0) + 1, nx - 1)
    if j_hi - j_lo < 1:
        j_lo, j_hi = max(min(j_lo, ny - 2), 0), min(max(j_lo, 0) + 1, ny - 1)
    half_width_km = 0.5 * np.hypot(*(columns.matrix @ [i_max - i_min, 0])) / 1e3
    info = (f"{n_rays} rays reach the grid below its top of {top / 1e3:.1f} km (box {half_width_km:.0f} km half-width "
            f"along x), sun-ward margin {sun_margin_m / 1e3:.0f} km, margin {margin_cells} cells")
    result = (slice(j_lo, j_hi + 1), slice(i_lo, i_hi + 1)), info
    if len(windows) >= _WINDOWS_PER_CAMERA:  # a time series' suns: a new one each frame, never piled up
        windows.clear()
    windows[window_key] = result
    return result


def reachable_index_window(scene: xr.Dataset, directions, *, lat=None, lon=None, height=2.0, valid=None,
                           sun_direction=None, margin_cells: int = DEFAULT_MARGIN_CELLS,
                           sun_margin_cap_m: float = SUN_MARGIN_CAP_M,
                           samples_per_ray: int = SAMPLES_PER_RAY) -> tuple[slice, slice]:
    """Index window of the scene's columns that the rays of a camera can reach (and what shades them).

    Parameters
    ----------
    scene : xarray.Dataset
        Scene with ``lat``, ``lon``, ``terrain_height`` (y, x) [deg, deg, m] and ``height`` (z, y, x) [m above
        sea level]; numpy-, dask- or lazily netCDF-backed. Only ``lat``, ``lon``, the two highest levels of
        ``height``, the edges of ``terrain_height`` and its cells under the observer are read. The scene frame
        is that of ``reference_lat``/``reference_lon`` (attributes, [deg]), else the grid's centre.
    directions : Camera or array_like
        A camera (:func:`swim.geometry.cameras.make_camera`; its pixel directions and valid mask), or view
        directions of shape (..., 3): unit (east, north, up) vectors [-] in the observer's ENU frame.
    lat, lon : float, optional
        Observer position [deg]; default: the reference point.
    height : float
        Observer height above the ground [m] (as in :func:`swim.render`).
    valid : array_like of bool, optional
        Shape ``directions.shape[:-1]``: the directions to use (default: all finite ones).
    sun_direction : array_like, optional
        Shape (3,): unit vector towards the sun in the scene frame (ENU at the reference point,
        :attr:`swim.geometry.sun.SunPosition.direction_enu`). Adds the ray towards the sun and the sun-ward
        margin. None: the sun is unknown, and the window grows by ``sun_margin_cap_m`` on every side.
    margin_cells : int
        Cells [-] added on every side (:data:`DEFAULT_MARGIN_CELLS`).
    sun_margin_cap_m : float
        Cap [m] of the sun-ward margin ``top * tan(sun zenith)`` (:data:`SUN_MARGIN_CAP_M`).
    samples_per_ray : int
        Points sampled along each ray's segment in the shell between the sea-level sphere and the grid top.

    Returns
    -------
    tuple of slice
        ``(y, x)``: index slices of the window, for ``scene.isel(y=..., x=...)``; at least 2 x 2 columns.

    Raises
    ------
    SwimInputError
        On a scene without ``lat``/``lon``/``height``/``terrain_height`` of the right dims or with non-finite
        values, a grid of fewer than 2 x 2 columns, an observer with lat outside [-90, 90] or a negative height,
        directions that are not of shape (..., 3), or a bad ``sun_direction``.
    """
    window, _ = _window(_Columns(scene), directions, lat=lat, lon=lon, height=height, valid=valid,
                        sun_direction=sun_direction, margin_cells=margin_cells, sun_margin_cap_m=sun_margin_cap_m,
                        samples_per_ray=samples_per_ray)
    return window


def snap_window_to_blocks(window, shape, block_fraction: float = CROP_BLOCK_FRACTION,
                          min_block: int = MIN_CROP_BLOCK) -> tuple[slice, slice]:
    """Widen an index window to whole blocks of columns, so that nearby views get the same window.

    Along each axis the block is the power of two nearest below ``block_fraction`` times the window's extent (at
    least ``min_block``); the window's start is moved down and its stop up to multiples of it, within the grid.
    The result depends on the window alone, not on earlier renders, so an image never depends on what was rendered
    before it (the crop changes an image only at float32 round-off, docs/rendering.md).

    Parameters
    ----------
    window : tuple of slice
        ``(y, x)`` index slices with steps of 1 (:func:`reachable_index_window`).
    shape : tuple of int
        ``(ny, nx)`` columns of the grid.
    block_fraction : float
        Block size as a fraction [-] of the window's extent; 0 returns ``window`` unchanged.
    min_block : int
        Smallest block [columns].

    Returns
    -------
    tuple of slice
        ``(y, x)``: the widened window, holding ``window``.

    Raises
    ------
    SwimInputError
        If ``block_fraction`` is negative or not finite, or ``min_block`` is below 1.
    """
    if not (np.isfinite(block_fraction) and block_fraction >= 0) or min_block < 1:
        raise SwimInputError(f"block_fraction ({block_fraction}) must be finite and >= 0, min_block ({min_block}) >= 1")
    if block_fraction == 0:
        return tuple(window)
    snapped = []
    for s, n in zip(window, shape):
        extent = s.stop - s.start
        block = max(int(min_block), 1 << max(int(math.floor(math.log2(max(extent * block_fraction, 1.0)))), 0))
        snapped.append(slice(max((s.start // block) * block, 0), min(-(-s.stop // block) * block, n)))
    return tuple(snapped)


def crop_scene_to_view(scene: xr.Dataset, camera="allsky", *, camera_options=None, lat=None, lon=None, height=2.0,
                       sun_direction=None, margin_cells: int = DEFAULT_MARGIN_CELLS,
                       sun_margin_cap_m: float = SUN_MARGIN_CAP_M,
                       max_fraction: float = MAX_CROP_FRACTION,
                       block_fraction: float = CROP_BLOCK_FRACTION) -> xr.Dataset:
    """Crop a scene lazily to the columns a camera's rays can reach (:func:`reachable_index_window`), widened to
    whole blocks of columns (:func:`snap_window_to_blocks`), so that a camera that moves a little keeps its crop.

    Parameters
    ----------
    scene : xarray.Dataset
        Scene (validated or not; numpy-, dask- or lazily netCDF-backed); see :func:`reachable_index_window`
        for what is read. No 3-D variable is loaded: the crop is ``scene.isel(y=..., x=...)``.
    camera : str or Camera
        Camera kind (``"allsky"``, ``"panorama"``, ``"perspective"``) built with ``camera_options`` as
        :func:`swim.render` builds it, or a camera. A perspective camera without ``view_azimuth_deg`` and
        ``view_zenith_deg`` is pointed by :func:`swim.render` from the optical volume, which does not exist
        yet: the scene is returned unchanged.
    camera_options : dict, optional
        Options of the camera kind (e.g. ``size``).
    lat, lon : float, optional
        Observer position [deg]; default: the reference point.
    height : float
        Observer height above the ground [m].
    sun_direction : array_like, optional
        Shape (3,): unit vector towards the sun in the scene frame (ENU at the reference point); None: unknown
        (the capped sun-ward margin on every side).
    margin_cells : int
        Cells [-] added on every side (:data:`DEFAULT_MARGIN_CELLS`).
    sun_margin_cap_m : float
        Cap [m] of the sun-ward margin (:data:`SUN_MARGIN_CAP_M`).
    max_fraction : float
        Return the scene unchanged when the window holds more than this fraction [-] of the columns
        (:data:`MAX_CROP_FRACTION`).
    block_fraction : float
        Size of the blocks that the window is widened to, as a fraction [-] of its extent
        (:data:`CROP_BLOCK_FRACTION`; 0: the bare window).

    Returns
    -------
    xarray.Dataset
        The cropped scene (lazy where the input is) with ``reference_lat``/``reference_lon`` [deg] set to the
        reference point of the whole grid, so the scene frame does not move; or ``scene`` itself.

    Raises
    ------
    SwimInputError
        As :func:`reachable_index_window`, and for a bad camera kind or options.
    """
    if not isinstance(scene, xr.Dataset):
        raise SwimInputError(f"scene must be an xarray.Dataset; got {type(scene).__name__}")
    options = dict(camera_options or {})
    if isinstance(camera, Camera):
        if options:
            raise SwimInputError("camera_options apply to a camera kind, not to a Camera instance")
        cam = camera
    else:
        kind = str(camera).strip().lower()
        if kind == "perspective" and not {"view_azimuth_deg", "view_zenith_deg"} <= set(options):
            log.info("crop: not cropping for a perspective camera without view_azimuth_deg/view_zenith_deg (its "
                     "view is chosen from the whole grid)")
            return scene
        cam = make_camera(camera, **options)
    columns = _Columns(scene)
    (wy, wx), info = _window(columns, cam, lat=lat, lon=lon, height=height, valid=None, sun_direction=sun_direction,
                             margin_cells=margin_cells, sun_margin_cap_m=sun_margin_cap_m,
                             samples_per_ray=SAMPLES_PER_RAY)
    ny, nx = columns.shape
    wy, wx = snap_window_to_blocks((wy, wx), (ny, nx), block_fraction)
    cy, cx = wy.stop - wy.start, wx.stop - wx.start
    fraction = cy * cx / (ny * nx)
    if fraction > max_fraction:
        log.info("crop: not cropping: the rays reach %d x %d of %d x %d columns (%.0f %%); %s",
                 cx, cy, nx, ny, 100 * fraction, info)
        return scene
    log.info("crop: x %d:%d, y %d:%d, %d x %d of %d x %d columns (%.1f %%); %s",
             wx.start, wx.stop, wy.start, wy.stop, cx, cy, nx, ny, 100 * fraction, info)
    cropped = scene.isel(y=wy, x=wx)
    return cropped.assign_attrs(reference_lat=float(columns.lat0), reference_lon=float(columns.lon0))
