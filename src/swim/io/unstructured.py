"""Unstructured global and regional meshes (ICON triangles, MPAS Voronoi cells): regridding their columns to the
canonical scene, and the MPAS reader (the ICON reader is :mod:`swim.io.icon`).

A mesh scene is a regular grid in the scene frame around the camera (docs/frames.md): columns at
``x, y = i dx, j dx`` for ``|i|, |j| <= n`` about the reference point, with ``dx`` about the mesh's cell size and
``n dx`` about the requested radius; the ``lat``/``lon`` of a column are those of the point whose orthographic
projection is (x, y) (:func:`swim.frames.orthographic_xy`). Each column is filled from the mesh by one of:

* ``"conservative"`` (default): the mean over ``s x s`` sub-points of the target column of the mesh cell that
  holds each sub-point (the cell's polygon from its vertex bounds where the file has them, else the nearest cell
  centre, which for an MPAS Voronoi mesh is the cell itself). Layer masses (content x layer thickness) and heights
  are averaged level by level (terrain-following levels), and the content is the mean mass over the canonical layer
  thickness of the mean heights: the column water path equals the area mean of the mesh's water paths over the
  target column, up to the ``1/s^2`` sampling of the overlap areas;
* ``"nearest"``: the whole column of the cell holding the target column's centre (no averaging).

Sub-points of the edge columns of a regional mesh that fall beyond its last cells take the nearest cell.

Cell lookups use a k-d tree of earth-centred unit vectors (:class:`scipy.spatial.cKDTree`): chord distance is
monotonic in great-circle distance, so there is no seam at the date line and no pole problem.
docs/decisions/0018-unstructured-regridding.md gives the choice and its measured errors.

MPAS formulas (Skamarock et al. 2012, doi:10.1175/MWR-D-11-00215.1): mixing ratios are per kg of dry air, so
content = q x rho_d with the dry-air density ``rho`` of the output, else ``rho_d = p / (R_d T (1 + q_v / eps))``
with ``T = theta (p / p0)^kappa``; mass-point heights are the midpoints of the interface heights ``zgrid``.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr

from ..constants import (
    EARTH_RADIUS_M,
    EPSILON_WATER_VAPOUR,
    KAPPA_DRY_AIR,
    P0_POTENTIAL_TEMPERATURE,
    R_DRY_AIR,
)
from ..errors import SwimInputError
from ..frames import scene_to_geodetic
from .scene import WIND_SPEED_RANGE_M_S, domain_centre, layer_thickness, scene_from_arrays, to_utc_datetime64

logger = logging.getLogger(__name__)

__all__ = [
    "read_mpas",
    "is_mpas",
    "is_mesh_file",
    "regrid_columns",
    "mesh_scene",
    "mesh_spacing",
    "cells_containing",
    "unit_vectors",
    "select_time",
    "DEFAULT_RADIUS_DEG",
    "MAX_RADIUS_DEG",
    "MAX_COLUMNS_ACROSS",
    "SUPERSAMPLING",
    "REGRID_METHODS",
]

#: Default radius [deg of great circle] of the scene cut around the camera, that of the GFS reader
#: (:data:`swim.io.grib.DEFAULT_RADIUS_DEG`): context enough for a ground camera and views from above.
DEFAULT_RADIUS_DEG = 15.0
#: Largest radius [deg]: beyond it the orthographic scene frame squeezes the edges by more than cos(30 deg).
MAX_RADIUS_DEG = 30.0
#: Most columns along one side of a mesh scene; the default radius shrinks to fit fine meshes, a larger explicit
#: radius is refused.
MAX_COLUMNS_ACROSS = 401
#: Sub-points per side of a target column for the conservative regridding (``s``; ``s^2`` lookups per column). On a
#: broken cloud field on R2B3 the rms error of the column water paths against the exact overlap areas is 22 % for
#: s = 2, 10 % for 4, 4.6 % for 6 and 2.7 % for 8 (docs/decisions/0018-unstructured-regridding.md).
SUPERSAMPLING = 8
REGRID_METHODS = ("conservative", "nearest")
#: Largest distance between a requested time and the nearest time of the file [h].
TIME_TOLERANCE_H = 1.5
#: Cells whose centres are used to estimate the cell size around a point.
_DENSITY_NEIGHBOURS = 48
#: Cell centres searched for the cell holding a point (a triangle's holder is among its 3 nearest centres in a
#: near-uniform ICON mesh; 8 leaves room for stretched cells).
_CANDIDATES = 8
#: Without vertex bounds a point lies outside a regional mesh when its nearest cell centre is further than this
#: many cell sizes (a hexagon's corner lies 0.62 cell sizes, a triangle's 0.88, from its centre).
_OUTSIDE_DISTANCE = 1.0
#: Points looked up at once against the cell polygons (bounds the memory of the corner arrays).
_BLOCK = 65536


# ---------------------------------------------------------------------------------------------------------------
# mesh geometry


def unit_vectors(lat, lon) -> np.ndarray:
    """Earth-centred unit vectors of points given by latitude and longitude [deg].

    Parameters
    ----------
    lat, lon : array_like
        Broadcastable arrays [deg].

    Returns
    -------
    numpy.ndarray
        Shape ``broadcast.shape + (3,)`` [-].
    """
    la, lo = np.deg2rad(np.asarray(lat, dtype=float)), np.deg2rad(np.asarray(lon, dtype=float))
    return np.stack(np.broadcast_arrays(np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)), axis=-1)


def _tree(cell_lat, cell_lon):
    from scipy.spatial import cKDTree

    return cKDTree(unit_vectors(cell_lat, cell_lon))


def _arc_m(chord) -> np.ndarray:
    """Great-circle distance [m] of a chord of the unit sphere."""
    return 2.0 * EARTH_RADIUS_M * np.arcsin(np.clip(np.asarray(chord) / 2.0, 0.0, 1.0))


def mesh_spacing(cell_lat, cell_lon, lat0, lon0, tree=None) -> float:
    """Cell size [m] of a mesh around a point: the square root of the mean cell area there.

    The area is estimated from the density of cell centres: the ``k`` = 48 nearest centres of (lat0, lon0) lie in a
    disc of radius ``r_k`` (the distance of the k-th), so a cell covers ``pi r_k^2 / (k - 1/2)``. The estimate does
    not depend on the cells' shape: for ICON's R2B3 triangles it gives about 316 km, ``sqrt(4 pi R^2 / 5120)``.

    Parameters
    ----------
    cell_lat, cell_lon : array_like
        Shape (ncells,): cell centres [deg].
    lat0, lon0 : float
        The point [deg].
    tree : scipy.spatial.cKDTree, optional
        Tree of the cells' unit vectors (:func:`unit_vectors`), when already built.

    Returns
    -------
    float
        Cell size [m].
    """
    tree = tree if tree is not None else _tree(cell_lat, cell_lon)
    k = min(_DENSITY_NEIGHBOURS, tree.n)
    if k < 4:
        raise SwimInputError(f"mesh: {tree.n} cells; a mesh scene needs at least 4")
    dist, _ = tree.query(unit_vectors(lat0, lon0), k=k)
    radius = _arc_m(dist[-1])
    return float(np.sqrt(np.pi * radius ** 2 / (k - 0.5)))


def cells_containing(points, tree, vertices=None, spacing_m=None):
    """The mesh cell holding each point, and whether the point lies on the mesh at all.

    Parameters
    ----------
    points : numpy.ndarray
        Shape (..., 3): earth-centred unit vectors of the points.
    tree : scipy.spatial.cKDTree
        Tree of the cell centres' unit vectors.
    vertices : numpy.ndarray, optional
        Shape (ncells, nv, 3): unit vectors of the corners of each (convex) cell, in order round the cell (either
        way round). With them, a point belongs to the cell whose polygon holds it (among its 8 nearest centres),
        falling back to the nearest centre; without them, to the nearest centre (exact for a Voronoi mesh).
    spacing_m : float, optional
        Cell size [m] (:func:`mesh_spacing`): without vertices, a point further than one cell size from every
        centre lies outside the mesh. None: every point is on the mesh.

    Returns
    -------
    tuple of numpy.ndarray
        ``(index, inside)``, both of shape ``points.shape[:-1]``: cell index (int) and bool.
    """
    p = np.asarray(points, dtype=float)
    flat = p.reshape(-1, 3)
    if vertices is None:
        dist, index = tree.query(flat, k=1)
        inside = np.ones(index.shape, bool) if spacing_m is None else _arc_m(dist) <= _OUTSIDE_DISTANCE * spacing_m
        return index.reshape(p.shape[:-1]), inside.reshape(p.shape[:-1])
    if flat.shape[0] > _BLOCK:
        parts = [cells_containing(flat[i:i + _BLOCK], tree, vertices) for i in range(0, flat.shape[0], _BLOCK)]
        return (np.concatenate([a for a, _ in parts]).reshape(p.shape[:-1]),
                np.concatenate([b for _, b in parts]).reshape(p.shape[:-1]))
    k = min(_CANDIDATES, tree.n)
    _, cand = tree.query(flat, k=k)
    cand = cand.reshape(-1, k)
    corners = vertices[cand]  # (m, k, nv, 3)
    edges = np.cross(corners, np.roll(corners, -1, axis=-2))  # normals of the great circles of the edges
    side = np.einsum("mkvc,mc->mkv", edges, flat)
    centre_side = np.einsum("mkvc,mkc->mkv", edges, tree.data[cand])
    tol = 1e-12
    holds = np.all(side * np.sign(centre_side) >= -tol, axis=-1)
    first = np.argmax(holds, axis=1)
    inside = holds[np.arange(cand.shape[0]), first]
    index = np.where(inside, cand[np.arange(cand.shape[0]), first], cand[:, 0])
    return index.reshape(p.shape[:-1]), inside.reshape(p.shape[:-1])


def _target_axis(radius_m, spacing_m):
    """Axis (2 n + 1,) [m] of the square target grid: ``i dx`` for ``|i| <= n = floor(radius / dx)``."""
    half = int(np.floor(radius_m / spacing_m + 1e-9))
    if half < 1:
        raise SwimInputError(f"radius {radius_m / 1000:g} km is less than one cell ({spacing_m / 1000:.4g} km) of the "
                             "mesh: expected a radius of at least one cell size")
    return np.arange(-half, half + 1) * spacing_m


def _column_points(axis_x, axis_y, lat0, lon0, offsets=(0.0,)):
    """Unit vectors (ny, nx, len(offsets)^2, 3) of the sea-level points at grid coordinates ``(x + ox, y + oy)``."""
    ox, oy = np.meshgrid(offsets, offsets, indexing="xy")
    x = axis_x[None, :, None] + ox.ravel()[None, None, :]
    y = axis_y[:, None, None] + oy.ravel()[None, None, :]
    x, y = np.broadcast_arrays(x, y)
    z = np.sqrt(np.clip(EARTH_RADIUS_M ** 2 - x ** 2 - y ** 2, 0.0, None))
    lat, lon, _ = scene_to_geodetic(np.stack([x, y, z], axis=-1), lat0, lon0)
    return unit_vectors(lat, lon)


# ---------------------------------------------------------------------------------------------------------------
# regridding


def _average(fields: dict, index: np.ndarray) -> dict:
    """Mean over the sub-points (last axis of ``index``, shape (ny, nx, s2)) of each field (cells on the last axis);
    contents as layer masses over the canonical thickness of the mean heights (the water path is kept)."""
    height = fields["height"]
    thickness = layer_thickness(height[:, None, :], fields["terrain_height"][None, :])[:, 0, :]
    out, mass = {}, {}
    nsub = index.shape[-1]
    for name, values in fields.items():
        if name.endswith("_effective_radius"):
            continue
        src = values * thickness if name.endswith("_content") else values
        acc = sum(src[..., index[..., j]] for j in range(nsub)) / nsub
        (mass if name.endswith("_content") else out)[name] = acc
    target_thickness = layer_thickness(out["height"], out["terrain_height"])
    for name, acc in mass.items():
        out[name] = acc / target_thickness
        radius = fields.get(name.replace("_content", "_effective_radius"))
        if radius is not None:  # the mass-weighted mean radius; NaN where there is no content
            src = fields[name] * thickness * np.nan_to_num(radius)
            weighted = sum(src[..., index[..., j]] for j in range(nsub)) / nsub
            ratio = weighted / np.where(acc > 0, acc, 1.0)
            out[name.replace("_content", "_effective_radius")] = np.where(acc > 0, ratio, np.nan)
    if "land_mask" in out:
        out["land_mask"] = (out["land_mask"] >= 0.5).astype(np.int8)
    return out


def regrid_columns(cell_lat, cell_lon, fields: dict, reference_lat: float, reference_lon: float, radius_m: float,
                   spacing_m: float | None = None, method: str = "conservative", vertices=None,
                   supersampling: int | None = None, label: str = "mesh"):
    """Regrid the columns of an unstructured mesh to a square regular grid in the scene frame.

    Parameters
    ----------
    cell_lat, cell_lon : array_like
        Shape (ncells,): cell centres [deg].
    fields : dict of str to numpy.ndarray
        Canonical fields with the cells on the last axis: ``height`` (nz, ncells) [m], increasing with the first
        axis, and ``terrain_height`` (ncells,) [m] are required; ``<species>_content`` (nz, ncells) [kg m-3],
        ``<species>_effective_radius`` (nz, ncells) [m], ``land_mask`` (ncells,) [0/1], ``wind_speed_10m``
        (ncells,) [m s-1] are optional.
    reference_lat, reference_lon : float
        Centre of the grid and reference point of the scene frame [deg].
    radius_m : float
        Half-width [m] of the square grid (rounded down to whole cells).
    spacing_m : float, optional
        Grid spacing [m]; default the mesh's cell size there (:func:`mesh_spacing`).
    method : {"conservative", "nearest"}
        See the module docstring.
    vertices : numpy.ndarray, optional
        Shape (ncells, nv, 3): the cells' corners as unit vectors (:func:`cells_containing`).
    supersampling : int, optional
        Sub-points per side of a target column for ``"conservative"``; default :data:`SUPERSAMPLING` where the
        columns are as large as the mesh's cells, fewer where they are finer (``ceil(8 dx / cell size)``).
    label : str
        Name of the input in messages.

    Returns
    -------
    tuple
        ``(x, y, out)``: the axes (nx,), (ny,) [m] and the fields on the grid, (nz, ny, nx) and (ny, nx). A regional
        mesh that does not cover the whole square gives the largest centred square it covers (logged).

    Raises
    ------
    SwimInputError
        On an unknown method, a radius under one cell, more than :data:`MAX_COLUMNS_ACROSS` columns, or a reference
        point outside the mesh.
    """
    if method not in REGRID_METHODS:
        raise SwimInputError(f"method={method!r}: expected one of {', '.join(REGRID_METHODS)}")
    cell_lat, cell_lon = np.asarray(cell_lat, dtype=float), np.asarray(cell_lon, dtype=float)
    tree = _tree(cell_lat, cell_lon)
    camera = unit_vectors(reference_lat, reference_lon)
    nearest = int(tree.query(camera)[1])
    cell_size = mesh_spacing(cell_lat, cell_lon, cell_lat[nearest], cell_lon[nearest], tree)
    if not cells_containing(camera[None], tree, vertices, cell_size)[1][0]:
        raise SwimInputError(f"{label}: the camera's place ({reference_lat:g}, {reference_lon:g}) lies outside the "
                             "mesh's coverage: expected a place on the mesh (a regional mesh covers only its domain)")
    spacing = float(spacing_m) if spacing_m is not None else cell_size
    axis = _target_axis(float(radius_m), spacing)
    if axis.size > MAX_COLUMNS_ACROSS:
        raise SwimInputError(f"{label}: a radius of {radius_m / 1000:g} km at {spacing / 1000:.4g} km spacing gives "
                             f"{axis.size} columns across (at most {MAX_COLUMNS_ACROSS}): expected a smaller radius")
    centre = _column_points(axis, axis, reference_lat, reference_lon)[..., 0, :]
    index, inside = cells_containing(centre, tree, vertices, cell_size)
    axis, keep = _covered_square(axis, inside, reference_lat, reference_lon, label)
    index = index[keep][:, keep]
    if method == "nearest":
        sub = index[..., None]
    else:
        # the overlaps are sampled at about an eighth of a mesh cell: fewer sub-points where the columns are finer
        s = int(supersampling or min(SUPERSAMPLING, max(1, int(np.ceil(SUPERSAMPLING * spacing / cell_size - 1e-9)))))
        offsets = ((np.arange(s) + 0.5) / s - 0.5) * spacing
        points = _column_points(axis, axis, reference_lat, reference_lon, offsets)
        sub, _ = cells_containing(points, tree, vertices, None)
    return axis, axis, _average(fields, sub)


def _covered_square(axis, inside, lat0, lon0, label):
    """The largest centred sub-square of the grid whose columns all lie on the mesh: its axis and index range."""
    half = axis.size // 2
    n = half
    while n > 0 and not np.all(inside[half - n:half + n + 1, half - n:half + n + 1]):
        n -= 1
    if n < 1:
        raise SwimInputError(f"{label}: the mesh covers less than 3 x 3 columns around ({lat0:g}, {lon0:g})")
    if n < half:
        logger.warning("%s: the mesh covers only %d of the %d columns around the camera: the scene is %d x %d "
                       "columns", label, 2 * n + 1, axis.size, 2 * n + 1, 2 * n + 1)
    keep = slice(half - n, half + n + 1)
    return axis[keep], keep


def mesh_scene(cell_lat, cell_lon, fields: dict, *, lat=None, lon=None, radius_deg=None, spacing_km=None,
               method: str = "conservative", vertices=None, time=None, attrs=None, label: str = "mesh"):
    """Canonical scene around the camera from the columns of a mesh (:func:`regrid_columns`).

    Parameters
    ----------
    cell_lat, cell_lon, fields, method, vertices, label
        As :func:`regrid_columns`.
    lat, lon : float, optional
        The camera's place [deg]: centre and reference point of the scene; default the centre of the cells
        (:func:`swim.io.scene.domain_centre`).
    radius_deg : float, optional
        Half-width of the scene [deg of great circle] in (0, :data:`MAX_RADIUS_DEG`]; default
        :data:`DEFAULT_RADIUS_DEG`, reduced to ``MAX_COLUMNS_ACROSS // 2`` cells on fine meshes.
    spacing_km : float, optional
        Column spacing [km]; default the mesh's cell size around the camera.
    time : numpy.datetime64, optional
        Valid time of the fields.
    attrs : dict, optional
        Scene attributes (``title``, ``source`` and reader-specific ones).

    Returns
    -------
    xarray.Dataset
        The validated canonical scene with ``x``/``y`` coordinates and the attributes ``mesh_spacing_m``,
        ``mesh_radius_m`` and ``mesh_regridding``.

    Raises
    ------
    SwimInputError
        On a bad place, radius or spacing, and as :func:`regrid_columns`.
    """
    if lat is None or lon is None:
        lat0, lon0 = domain_centre(cell_lat, cell_lon)
    else:
        lat0, lon0 = float(lat), float(lon)
        if not (np.isfinite(lat0) and np.isfinite(lon0) and -90.0 <= lat0 <= 90.0):
            raise SwimInputError(f"lat={lat!r}, lon={lon!r}: expected a latitude in [-90, 90] and a finite "
                                 "longitude [deg]")
        lon0 = (lon0 + 180.0) % 360.0 - 180.0
    if spacing_km is not None and not float(spacing_km) > 0:
        raise SwimInputError(f"spacing_km={spacing_km!r}: expected a positive spacing [km]")
    spacing_m = None if spacing_km is None else float(spacing_km) * 1000.0
    metres_per_deg = np.deg2rad(1.0) * EARTH_RADIUS_M
    if radius_deg is None:
        size = spacing_m or mesh_spacing(cell_lat, cell_lon, lat0, lon0)
        radius_m = min(DEFAULT_RADIUS_DEG * metres_per_deg, (MAX_COLUMNS_ACROSS // 2) * size)
    elif not 0.0 < float(radius_deg) <= MAX_RADIUS_DEG:
        raise SwimInputError(f"radius_deg={radius_deg!r} (--region-radius): expected (0, {MAX_RADIUS_DEG:g}] deg; "
                             "beyond it the orthographic scene frame squeezes the scene's edges")
    else:
        radius_m = float(radius_deg) * metres_per_deg
    x, y, out = regrid_columns(cell_lat, cell_lon, fields, lat0, lon0, radius_m, spacing_m, method, vertices,
                               label=label)
    spacing = float(x[1] - x[0])
    height = out.pop("height")
    scene_attrs = dict(attrs or {})
    scene_attrs.update(mesh_spacing_m=spacing, mesh_radius_m=float(x[-1]), mesh_regridding=method)
    logger.info("%s: %d x %d columns at %.4g km around (%g, %g), %d levels, %s", label, y.size, x.size,
                spacing / 1000, lat0, lon0, height.shape[0], method)
    return _scene(x, y, height, lat0, lon0, out, time, scene_attrs)


def _scene(x, y, height, lat0, lon0, out: dict, time, attrs: dict) -> xr.Dataset:
    """``scene_from_arrays`` with the regridded fields and the attributes kept."""
    kwargs = {name: values for name, values in out.items() if name != "terrain_height"}
    for name in [n for n in kwargs if n.endswith("_content")]:
        if not np.any(kwargs[name] > 0):  # absent species stay absent
            kwargs.pop(name)
            kwargs.pop(name.replace("_content", "_effective_radius"), None)
    scene = scene_from_arrays(x=x, y=y, z=height, reference_lat=lat0, reference_lon=lon0,
                              terrain_height=out["terrain_height"], time=time,
                              title=attrs.pop("title", "swim scene from a mesh"),
                              source=attrs.pop("source", "swim.io.unstructured"), **kwargs)
    scene.attrs.update(attrs)
    return scene


# ---------------------------------------------------------------------------------------------------------------
# shared reader pieces


def select_time(times, time, label: str) -> int:
    """Index of the time to read: 0 for ``time=None``, an int as given, else the nearest within 1.5 h.

    Parameters
    ----------
    times : numpy.ndarray or None
        Shape (nt,) ``datetime64`` times of the file (None: the file has none).
    time : None, int, str, datetime or numpy.datetime64
        The requested time (UTC).
    label : str
        Name of the file in messages.

    Returns
    -------
    int

    Raises
    ------
    SwimInputError
        If an index is out of range, or ``time`` is more than 1.5 h from every time of the file.
    """
    n = 1 if times is None else len(times)
    if time is None:
        return 0
    if isinstance(time, (int, np.integer)) and not isinstance(time, bool):
        if not -n <= int(time) < n:
            raise SwimInputError(f"time={time}: {label} holds {n} time(s)")
        return int(time) % n
    want = to_utc_datetime64(time)
    if times is None:
        logger.warning("%s has no time: time=%s is taken as the time of its fields", label, time)
        return 0
    i = int(np.argmin(np.abs(times - want)))
    if abs(times[i] - want) > np.timedelta64(int(TIME_TOLERANCE_H * 3600), "s"):
        listed = ", ".join(pd.Timestamp(t).strftime("%Y-%m-%dT%H:%MZ") for t in times)
        raise SwimInputError(f"time={time!r} is more than {TIME_TOLERANCE_H:g} h from every time of {label}: {listed}")
    return i


def _open(path_or_dataset, kind: str):
    """(dataset, label, source) of a path or an open dataset."""
    if isinstance(path_or_dataset, xr.Dataset):
        return path_or_dataset, kind, str(path_or_dataset.encoding.get("source", "dataset"))
    from .files import open_netcdf

    p = Path(path_or_dataset)
    with open_netcdf(p, kind) as ds:
        return ds.load(), f"{kind} {p.name}", str(p)


def _require(ds: xr.Dataset, names, label: str, what: str):
    missing = [n for n in names if n not in ds.variables]
    if missing:
        raise SwimInputError(f"{label} lacks {', '.join(missing)} ({what}); see docs/scene-format.md")


def _clip_negative(name: str, values: np.ndarray, label: str) -> np.ndarray:
    if np.any(values < 0):
        logger.info("%s: clipped %d negative %s value(s) (min %.3g) to 0", label, int(np.sum(values < 0)), name,
                    float(values.min()))
        return np.clip(values, 0.0, None)
    return values


def _check_range(name: str, values: np.ndarray, low: float, high: float, units: str, label: str) -> None:
    finite = values[np.isfinite(values)]
    if finite.size != values.size:
        raise SwimInputError(f"{label}: {name} has {values.size - finite.size} non-finite value(s)")
    if finite.size and (finite.min() < low or finite.max() > high):
        raise SwimInputError(f"{label}: {name} spans {finite.min():.4g}..{finite.max():.4g}; expected {units} in "
                             f"[{low:g}, {high:g}]")


def _wind(u, v) -> np.ndarray:
    return np.clip(np.hypot(u, v), *WIND_SPEED_RANGE_M_S)


# ---------------------------------------------------------------------------------------------------------------
# MPAS

_MPAS_SPECIES = {"qc": "cloud_liquid", "qi": "cloud_ice", "qr": "rain", "qs": "snow", "qg": "graupel"}


def is_mpas(ds: xr.Dataset) -> bool:
    """MPAS-Atmosphere output: cell centres ``latCell``/``lonCell`` and interface heights ``zgrid``."""
    return {"latCell", "lonCell", "zgrid"} <= set(ds.variables)


def is_mesh_file(path) -> bool:
    """Whether ``path`` is a netCDF file of ICON output (:func:`swim.io.icon.is_icon`, on its mesh or a lat-lon
    grid) or MPAS output (:func:`is_mpas`): the readers that take the camera's place (``lat=``, ``lon=``) and
    ``radius_deg=``. Only the header is read; anything unreadable is not a mesh file."""
    from .icon import is_icon

    p = Path(path)
    if not p.is_file():
        return False
    try:
        with xr.open_dataset(p, decode_times=False) as ds:
            return is_icon(ds) or is_mpas(ds)
    except Exception:  # noqa: BLE001 - not netCDF, or not readable: not a mesh file
        return False


def _mpas_times(ds: xr.Dataset):
    if "xtime" not in ds.variables:
        return None
    raw = np.atleast_1d(ds["xtime"].values)
    if raw.dtype.kind == "S" and raw.ndim == 2:  # (Time, StrLen) characters
        raw = np.array([b"".join(row).decode("ascii", "replace") for row in raw])
    text = [(r.decode() if isinstance(r, bytes) else str(r)).strip().replace("_", "T") for r in raw]
    return np.array([to_utc_datetime64(t, "xtime") for t in text])


def _mpas_density(ds, sel, label):
    """Dry-air density [kg m-3] (nz, ncells): ``rho`` of the output, else from pressure, theta and qv."""
    if "rho" in ds.variables:
        return np.asarray(ds["rho"].isel(sel).values, dtype=float).T
    if "pressure" in ds.variables:
        p = np.asarray(ds["pressure"].isel(sel).values, dtype=float).T
    elif {"pressure_p", "pressure_base"} <= set(ds.variables):
        p = np.asarray((ds["pressure_p"] + ds["pressure_base"]).isel(sel).values, dtype=float).T
    else:
        raise SwimInputError(f"{label} lacks rho, and pressure (or pressure_p and pressure_base) to compute it")
    _require(ds, ["theta"], label, "potential temperature [K], for the air density")
    theta = np.asarray(ds["theta"].isel(sel).values, dtype=float).T
    _check_range("pressure", p, 1.0, 1.2e5, "Pa", label)
    _check_range("theta", theta, 150.0, 2000.0, "K", label)
    t = theta * (p / P0_POTENTIAL_TEMPERATURE) ** KAPPA_DRY_AIR
    qv = np.asarray(ds["qv"].isel(sel).values, dtype=float).T if "qv" in ds.variables else 0.0
    return p / (R_DRY_AIR * t * (1.0 + np.clip(qv, 0.0, None) / EPSILON_WATER_VAPOUR))


def _mpas_fields(ds: xr.Dataset, it: int, label: str) -> dict:
    """Canonical fields (cells last) of MPAS output at time index ``it``."""
    _require(ds, ["zgrid"], label, "interface heights [m]")
    sel = {"Time": it} if "Time" in ds.dims else {}
    zgrid = np.asarray(ds["zgrid"].isel({k: v for k, v in sel.items() if k in ds["zgrid"].dims}).values,
                       dtype=float).T  # (nz + 1, ncells)
    _check_range("zgrid", zgrid, -1000.0, 100_000.0, "m", label)
    fields = {"height": 0.5 * (zgrid[1:] + zgrid[:-1]), "terrain_height": zgrid[0]}
    species = [name for name in _MPAS_SPECIES if name in ds.variables]
    if not species:
        raise SwimInputError(f"{label} has none of {', '.join(_MPAS_SPECIES)} (mixing ratios [kg kg-1])")
    rho = _mpas_density(ds, sel, label)
    for name in species:
        q = _clip_negative(name, np.asarray(ds[name].isel(sel).values, dtype=float).T, label)
        _check_range(name, q, 0.0, 0.05, "kg kg-1", label)
        fields[f"{_MPAS_SPECIES[name]}_content"] = q * rho
    if "landmask" in ds.variables:
        fields["land_mask"] = (np.asarray(ds["landmask"].values, dtype=float).ravel() > 0.5).astype(float)
    elif "xland" in ds.variables:
        fields["land_mask"] = (np.asarray(ds["xland"].isel(sel).values, dtype=float).ravel() < 1.5).astype(float)
    if {"u10", "v10"} <= set(ds.variables):
        fields["wind_speed_10m"] = _wind(np.asarray(ds["u10"].isel(sel).values, dtype=float),
                                         np.asarray(ds["v10"].isel(sel).values, dtype=float))
    return fields


def _mpas_vertices(ds: xr.Dataset):
    """Corners (ncells, maxEdges, 3) of each MPAS cell, the last repeated up to ``maxEdges``; None if absent."""
    if not {"verticesOnCell", "nEdgesOnCell", "latVertex", "lonVertex"} <= set(ds.variables):
        return None
    von = np.asarray(ds["verticesOnCell"].values, dtype=np.int64) - 1
    n = np.asarray(ds["nEdgesOnCell"].values, dtype=np.int64)
    col = np.minimum(np.arange(von.shape[1])[None, :], (n - 1)[:, None])
    von = np.take_along_axis(von, col, axis=1)
    corners = unit_vectors(np.rad2deg(ds["latVertex"].values), np.rad2deg(ds["lonVertex"].values))
    return corners[von]


def read_mpas(path_or_dataset, lat=None, lon=None, radius_deg=None, time=None, method: str = "conservative",
              spacing_km=None) -> xr.Dataset:
    """Read MPAS-Atmosphere output (history or diagnostic netCDF on the native Voronoi mesh) into a canonical scene.

    Parameters
    ----------
    path_or_dataset : str, os.PathLike or xarray.Dataset
        The file. Variables used: ``latCell``, ``lonCell`` [rad] (ncells); ``zgrid`` (nCells, nVertLevelsP1)
        interface heights [m], the lowest the terrain; ``qc``, ``qi``, ``qr``, ``qs``, ``qg`` (Time, nCells,
        nVertLevels) mixing ratios [kg per kg of dry air], any present, at least one; ``rho`` dry-air density
        [kg m-3], else ``pressure`` (or ``pressure_p`` + ``pressure_base``) [Pa], ``theta`` [K] and ``qv``
        [kg kg-1]; optional ``landmask`` (1 land) or ``xland`` (1 land, 2 water), ``u10``/``v10`` [m s-1],
        ``xtime`` ("YYYY-MM-DD_hh:mm:ss"), and ``verticesOnCell``/``nEdgesOnCell``/``latVertex``/``lonVertex``
        (cell polygons, for the coverage of a regional mesh).
    lat, lon : float, optional
        The camera's place [deg], centre of the scene; default the mesh's centre (give it for a global mesh).
    radius_deg, spacing_km, method
        As :func:`mesh_scene`.
    time : None, int, str or datetime, optional
        Time to read: None the first, an int an index along ``Time``, else the nearest within 1.5 h.

    Returns
    -------
    xarray.Dataset
        The validated canonical scene (:func:`mesh_scene`): heights the midpoints of ``zgrid``, contents
        ``q x rho_d`` [kg m-3], terrain ``zgrid[:, 0]``.

    Raises
    ------
    SwimInputError
        If a needed variable is missing, a value is out of range (the message names it and its units), the camera
        lies outside a regional mesh, or as :func:`mesh_scene`.

    References
    ----------
    Skamarock et al. (2012), doi:10.1175/MWR-D-11-00215.1 (MPAS-Atmosphere; mixing ratios per dry air).
    """
    ds, label, source = _open(path_or_dataset, "MPAS file")
    _require(ds, ["latCell", "lonCell", "zgrid"], label, "cell centres [rad] and interface heights [m]")
    times = _mpas_times(ds)
    it = select_time(times, time, label)
    cell_lat = np.rad2deg(np.asarray(ds["latCell"].values, dtype=float))
    cell_lon = np.rad2deg(np.asarray(ds["lonCell"].values, dtype=float))
    fields = _mpas_fields(ds, it, label)
    attrs = {"title": f"MPAS-Atmosphere {ds.attrs.get('config_start_time', '')}".strip(),
             "source": f"{source} read by swim.io.unstructured.read_mpas"}
    return mesh_scene(cell_lat, cell_lon, fields, lat=lat, lon=lon, radius_deg=radius_deg, spacing_km=spacing_km,
                      method=method, vertices=_mpas_vertices(ds), time=None if times is None else times[it],
                      attrs=attrs, label=label)
