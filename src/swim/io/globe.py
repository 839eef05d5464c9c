"""Whole-earth views: a global model's columns resampled onto a regular grid in the orthographic plane about the
sub-observer point, and the place and camera of an observer at the sun-earth L1 point (DSCOVR EPIC).

The scene frame of :mod:`swim.frames` is the orthographic projection about the scene's reference point. A grid that
is regular in that plane (1-D ``x``, ``y`` coordinates, ``docs/scene-format.md``) is placed by those coordinates
(the renderer's index map and its crop, an affine map here), however far it reaches from the reference point,
beyond the limb included. The square grid of :func:`hemisphere_scene` holds the disc of ``disc_radius_deg`` of great
circle about the sub-observer point (half-width ``R sin(disc_radius_deg)``); its corners lie beyond the limb
(``x^2 + y^2 >= R^2``), where no point of the sphere is, and no ray looks them up (the renderer finds the column of a
point by its radial projection onto the sphere, ``x^2 + y^2 <= R^2``). They and the columns between the disc and the
limb carry the ground of the nearest point of the disc's rim and no condensate
(docs/decisions/0019-whole-earth-views.md).

Formulas:

* the columns of the grid: the sea-level points ``(x, y, sqrt(R^2 - x^2 - y^2))`` of the scene frame
  (:func:`swim.frames.scene_to_geodetic`, the inverse of :func:`swim.frames.orthographic_xy`); a column beyond the
  disc, ``r = sqrt(x^2 + y^2) > R sin(disc_radius_deg)``, takes its values at ``(x, y) R sin(disc_radius_deg) / r``
  (the nearest point of the disc), and, beyond the limb, that point's lat/lon too;
* values at a column: bilinear interpolation on the regular latitude-longitude grid, periodic in longitude, of every
  field, the heights of the levels included (a weighted mean of strictly increasing columns with weights >= 0 is
  strictly increasing);
* the sub-solar point: the direction of the sun at (0 N, 0 E) from the NREL SPA (pvlib, geometric zenith and
  azimuth) turned into an earth-centred unit vector; an observer at L1, ~1.5e9 m sunward on the sun-earth line,
  stands above the sub-solar point.

The renderer lights the clouds of any grid with the sun of its reference point (Step 1a sweeps one sun direction
through the grid as if it were flat): on a whole-earth grid clouds far from the sub-observer point are lit as if the
sun stood as high as there (docs/decisions/0019-whole-earth-views.md, "Limits").
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr

from ..constants import EARTH_RADIUS_M
from ..errors import SwimInputError
from ..frames import scene_to_geodetic
from .scene import to_utc_datetime64, validate_scene

logger = logging.getLogger(__name__)

__all__ = [
    "L1_DISTANCE_M",
    "DEFAULT_DISC_RADIUS_DEG",
    "read_gfs_global_columns",
    "interpolate_lat_lon",
    "hemisphere_scene",
    "sub_solar_point",
    "l1_view",
]

#: Distance [m] of the sun-earth L1 point from the earth's centre (DSCOVR orbits it at ~1.5e9 m).
L1_DISTANCE_M = 1.5e9
#: Default great-circle radius [deg] about the sub-observer point of the disc that :func:`hemisphere_scene` fills
#: with the model's fields (its grid's half-width is ``R sin`` of it). From L1 the 87-90 deg ring beyond it is the
#: outer 0.14 % of the disc's radius in the image, a sixth of a pixel at 255 x 255.
DEFAULT_DISC_RADIUS_DEG = 87.0
#: Height [m] above sea level that the default field of view of :func:`l1_view` keeps in the picture.
LIMB_HEIGHT_M = 100_000.0
#: Global fields read from the columns dataset, with their dims.
_FIELDS_3D = ("height", "cloud_liquid_content", "cloud_ice_content", "rain_content", "snow_content",
              "graupel_content")
_FIELDS_2D = ("terrain_height", "land_mask", "wind_speed_10m")


def read_gfs_global_columns(path, time=None) -> xr.Dataset:
    """The whole grid of an NCEP GFS GRIB file as columns on its regular latitude-longitude grid.

    The fields are those of :func:`swim.io.grib.read_gfs_grib` (same messages, units, condensate split and
    underground levels dropped) on every row and column, without the region cut and without the scene frame.

    Parameters
    ----------
    path : str or os.PathLike
        The GRIB file (a global or regional regular lat-lon grid).
    time : str, datetime or numpy.datetime64, optional
        Valid time (UTC): the nearest in the file within 1.5 h; None: the file's first.

    Returns
    -------
    xarray.Dataset
        Dims (z, lat, lon) with 1-D coordinates ``lat`` (south to north) [deg] and ``lon`` (west to east, as in the
        file) [deg]: ``height`` [m above sea level], ``cloud_liquid_content``, ``cloud_ice_content`` [kg m-3],
        ``terrain_height`` [m], ``land_mask`` [1 land, 0 water] and ``wind_speed_10m`` [m s-1] where the file has
        them; the scalar coordinate ``time`` (the valid time) where the file has one; the attributes ``title`` and
        ``source``.

    Raises
    ------
    SwimInputError
        As :func:`swim.io.grib.read_gfs_grib` for an unreadable file, missing variables or units.
    """
    from . import grib

    p = Path(path)
    label = f"GRIB file {p.name}"
    if not p.is_file():
        raise SwimInputError(f"GRIB file not found: {p}")
    messages = grib._read_messages(p, time, label, ("clwmr", "t_gh", "r", "surface", "wind"))
    levels = grib._require(messages, label)
    grid = messages["clwmr"]
    lats = np.asarray(grid["latitude"].values, dtype=float)
    lons = np.asarray(grid["longitude"].values, dtype=float)
    rows, cols = np.argsort(lats), np.argsort(lons)
    fields = grib._volume(messages, levels, rows, cols, label)
    fields.update(grib._surface(messages, rows, cols))
    data = {name: (("z", "lat", "lon") if np.ndim(v) == 3 else ("lat", "lon"), v) for name, v in fields.items()}
    coords = {"lat": lats[rows], "lon": lons[cols]}
    if "valid_time" in grid.coords:
        coords["time"] = xr.DataArray(to_utc_datetime64(grid["valid_time"].values))
    logger.info("read_gfs_global_columns: %s: %d levels, %d x %d columns", label, levels.size, rows.size, cols.size)
    return xr.Dataset(data, coords=coords, attrs={"title": f"NCEP GFS {p.name}, whole grid",
                                                  "source": f"{p} read by swim.io.globe.read_gfs_global_columns"})


def _bilinear_weights(lat_axis, lon_axis, lat, lon):
    """Corner indices and weights of bilinear interpolation on a regular lat-lon grid, periodic in longitude where
    the grid goes round the globe: ``(j0, j1, i0, i1, wj, wi)``, each the shape of ``lat``."""
    lat_axis, lon_axis = np.asarray(lat_axis, dtype=float), np.asarray(lon_axis, dtype=float)
    if lat_axis.ndim != 1 or lon_axis.ndim != 1 or lat_axis.size < 2 or lon_axis.size < 2:
        raise SwimInputError("the columns' lat and lon must be 1-D axes of >= 2 values [deg]")
    dlat, dlon = np.diff(lat_axis), np.diff(lon_axis)
    if np.any(dlat <= 0) or np.any(dlon <= 0):
        raise SwimInputError("the columns' lat and lon [deg] must increase strictly (south to north, west to east)")
    if np.ptp(dlon) > 1e-6 * dlon.mean() or np.ptp(dlat) > 1e-6 * dlat.mean():
        raise SwimInputError("the columns' lat and lon [deg] must be regularly spaced")
    step_lat, step_lon = dlat.mean(), dlon.mean()
    nlon = lon_axis.size
    periodic = abs(nlon * step_lon - 360.0) < 1e-3 * step_lon
    fj = np.clip((np.asarray(lat, dtype=float) - lat_axis[0]) / step_lat, 0.0, lat_axis.size - 1.0)
    j0 = np.minimum(np.floor(fj).astype(int), lat_axis.size - 2)
    if periodic:
        fi = ((np.asarray(lon, dtype=float) - lon_axis[0]) % 360.0) / step_lon
        i0 = np.floor(fi).astype(int) % nlon
        return j0, j0 + 1, i0, (i0 + 1) % nlon, fj - j0, fi - np.floor(fi)
    offset = (np.asarray(lon, dtype=float) - lon_axis[0] + 180.0) % 360.0 - 180.0
    fi = np.clip(offset / step_lon, 0.0, nlon - 1.0)
    i0 = np.minimum(np.floor(fi).astype(int), nlon - 2)
    return j0, j0 + 1, i0, i0 + 1, fj - j0, fi - i0


def interpolate_lat_lon(values, lat_axis, lon_axis, lat, lon):
    """Bilinear interpolation of fields on a regular latitude-longitude grid at points (lat, lon).

    Parameters
    ----------
    values : array_like
        Shape (..., nlat, nlon): the fields on the grid (any leading dims, e.g. levels).
    lat_axis, lon_axis : array_like
        Shape (nlat,), (nlon,): the grid's latitudes (south to north) and longitudes (west to east) [deg],
        regularly spaced. A grid whose longitudes go round the globe is periodic (across its seam); points
        beyond the grid otherwise take its edge values.
    lat, lon : array_like
        The points [deg], broadcastable to one shape S.

    Returns
    -------
    numpy.ndarray
        Shape (..., *S): the interpolated fields (float64).

    Raises
    ------
    SwimInputError
        If the axes are not 1-D, increasing and regular, or ``values`` does not end in (nlat, nlon).
    """
    v = np.asarray(values, dtype=float)
    lat, lon = np.broadcast_arrays(np.asarray(lat, dtype=float), np.asarray(lon, dtype=float))
    if v.ndim < 2 or v.shape[-2:] != (np.size(lat_axis), np.size(lon_axis)):
        raise SwimInputError(f"values must end in (nlat, nlon) = ({np.size(lat_axis)}, {np.size(lon_axis)}); "
                             f"got {v.shape}")
    j0, j1, i0, i1, wj, wi = _bilinear_weights(lat_axis, lon_axis, lat, lon)
    return ((1 - wj) * ((1 - wi) * v[..., j0, i0] + wi * v[..., j0, i1])
            + wj * ((1 - wi) * v[..., j1, i0] + wi * v[..., j1, i1]))


def _hemisphere_grid(sub_lat, sub_lon, size, disc_radius_deg):
    """The grid of :func:`hemisphere_scene`: axes x, y (size,) [m]; lat, lon (size, size) [deg] of the columns (of
    the nearest point of the disc's rim beyond the limb); lat, lon (size, size) [deg] where the fields are taken (the
    nearest point of the disc); mask (size, size) of the columns beyond the disc."""
    if not (np.isfinite(sub_lat) and -90.0 <= sub_lat <= 90.0 and np.isfinite(sub_lon)):
        raise SwimInputError(f"sub_lat={sub_lat!r}, sub_lon={sub_lon!r}: expected a latitude in [-90, 90] and a "
                             "finite longitude [deg]")
    if not 0.0 < disc_radius_deg <= 90.0:
        raise SwimInputError(f"disc_radius_deg={disc_radius_deg!r}: expected (0, 90] deg of great circle (the disc "
                             "must lie on the visible hemisphere)")
    if int(size) != size or size < 2:
        raise SwimInputError(f"size={size!r}: expected an integer >= 2 [columns along each axis]")
    rim = EARTH_RADIUS_M * np.sin(np.deg2rad(disc_radius_deg))
    axis = np.linspace(-rim, rim, int(size))
    gx, gy = np.meshgrid(axis, axis)
    r = np.hypot(gx, gy)
    beyond = r > rim
    shrink = np.where(beyond, rim / np.maximum(r, 1.0), 1.0)
    fx, fy = gx * shrink, gy * shrink  # the nearest point of the disc

    def geodetic(x, y):
        p = np.stack([x, y, np.sqrt(np.maximum(EARTH_RADIUS_M**2 - x**2 - y**2, 0.0))], axis=-1)
        lat, lon, _ = scene_to_geodetic(p, sub_lat, sub_lon)
        return lat, lon

    field_lat, field_lon = geodetic(fx, fy)
    on_sphere = r < EARTH_RADIUS_M
    own_lat, own_lon = geodetic(np.where(on_sphere, gx, fx), np.where(on_sphere, gy, fy))
    return axis, axis.copy(), own_lat, own_lon, field_lat, field_lon, beyond


def hemisphere_scene(columns: xr.Dataset, sub_lat: float, sub_lon: float, size: int = 256,
                     disc_radius_deg: float = DEFAULT_DISC_RADIUS_DEG) -> xr.Dataset:
    """Resample global lat-lon columns onto a regular grid in the orthographic plane about the sub-observer point
    that holds the disc of ``disc_radius_deg`` about it.

    Parameters
    ----------
    columns : xarray.Dataset
        Dims (z, lat, lon) with 1-D increasing, regular coordinates ``lat``, ``lon`` [deg]
        (:func:`read_gfs_global_columns`): ``height`` (z, lat, lon) [m above sea level], strictly increasing in
        z; optional ``<species>_content`` (z, lat, lon) [kg m-3]; ``terrain_height`` [m] (default 0),
        ``land_mask`` [0/1] and ``wind_speed_10m`` [m s-1] (lat, lon) where present; an optional scalar ``time``.
    sub_lat, sub_lon : float
        The sub-observer point [deg]: the scene's reference point and the centre of the grid.
    size : int
        Columns along each axis, >= 2 (the spacing is ``2 R sin(disc_radius_deg) / (size - 1)``).
    disc_radius_deg : float
        Great-circle radius [deg] of the disc about the sub-observer point that holds the model's fields, in
        (0, 90]: the middles of the grid's edges lie on its rim (:data:`DEFAULT_DISC_RADIUS_DEG`).

    Returns
    -------
    xarray.Dataset
        The validated canonical scene (``docs/scene-format.md``) with 1-D ``x``, ``y`` [m] (the orthographic
        coordinates of the columns), ``lat``/``lon`` of the columns, the interpolated fields (a land mask is
        rounded to 0/1) and the attributes ``reference_lat``/``reference_lon`` (the sub-observer point) and
        ``globe_disc_radius_deg``. A column beyond the disc (``x^2 + y^2 > R^2 sin^2(disc_radius_deg)``) holds the
        fields of the nearest point of the disc's rim without condensate; beyond the limb (``x^2 + y^2 >= R^2``,
        the grid's corners) its ``lat``/``lon`` are that point's too.

    Raises
    ------
    SwimInputError
        For a dataset without ``height``, ``lat`` and ``lon``, axes that are not regular, a point or radius out
        of range, or a scene that fails :func:`swim.io.scene.validate_scene`.

    Notes
    -----
    No ray of the renderer looks up a column beyond the limb (it finds a point's column by the point's radial
    projection onto the sphere); their values only keep the grid's interpolation free of anything odd next to the
    limb. The ring between the disc and the limb is clear air over the rim's ground (so are the grid's corners for a
    disc well inside the limb: the model's fields fill the disc, a circle, not the square). The clouds are lit with
    the sun of the sub-observer point (module docstring).

    References
    ----------
    Snyder, J. P. (1987), Map Projections: A Working Manual, USGS Professional Paper 1395, Chap. 20 (orthographic
    projection, Eqs. 20-3, 20-4 and their inverse), doi:10.3133/pp1395.
    """
    missing = [name for name in ("height", "lat", "lon") if name not in columns.variables]
    if missing:
        raise SwimInputError(f"hemisphere_scene: the columns lack {', '.join(missing)} (dims z, lat, lon; "
                             "swim.io.globe.read_gfs_global_columns)")
    x, y, lat, lon, field_lat, field_lon, beyond = _hemisphere_grid(float(sub_lat), float(sub_lon), size,
                                                                     float(disc_radius_deg))
    lat_axis, lon_axis = columns["lat"].values, columns["lon"].values
    data = {"lat": (("y", "x"), lat, {"units": "degrees_north"}), "lon": (("y", "x"), lon, {"units": "degrees_east"})}
    for name in _FIELDS_3D + _FIELDS_2D:
        if name not in columns.data_vars:
            continue
        da = columns[name].transpose(..., "lat", "lon")
        values = interpolate_lat_lon(da.values, lat_axis, lon_axis, field_lat, field_lon)
        if name == "land_mask":
            values = (values > 0.5).astype(np.int8)
        data[name] = (("z", "y", "x") if name in _FIELDS_3D else ("y", "x"), values)
    if "terrain_height" not in data:
        data["terrain_height"] = (("y", "x"), np.zeros_like(lat))
    # a level that interpolation puts under the interpolated ground holds its neighbours' cloud: hidden, dropped;
    # beyond the disc there is none
    underground = (data["height"][1] < data["terrain_height"][1][None]) | beyond[None]
    for name in _FIELDS_3D[1:]:
        if name in data:
            data[name] = (data[name][0], np.where(underground, 0.0, data[name][1]))
    coords = {"x": ("x", x, {"units": "m"}), "y": ("y", y, {"units": "m"})}
    if "time" in columns.coords and columns["time"].ndim == 0:
        coords["time"] = columns["time"]
    attrs = {"reference_lat": float(sub_lat), "reference_lon": (float(sub_lon) + 180.0) % 360.0 - 180.0,
             "title": f"{columns.attrs.get('title', 'global columns')} seen from above ({float(sub_lat):.2f}, "
                      f"{float(sub_lon):.2f})",
             "source": f"{columns.attrs.get('source', 'unknown')}; swim.io.globe.hemisphere_scene",
             "globe_disc_radius_deg": float(disc_radius_deg)}
    logger.info("hemisphere_scene: %d x %d columns about (%.2f, %.2f), spacing %.0f m, the disc of %.1f deg filled "
                "(%d columns beyond it)", size, size, sub_lat, sub_lon, x[1] - x[0], disc_radius_deg, beyond.sum())
    return validate_scene(xr.Dataset(data, coords=coords, attrs=attrs))


def sub_solar_point(time) -> tuple[float, float]:
    """The sub-solar point [deg] at an instant: where the sun is in the zenith (and the place below an observer at
    the sun-earth L1 point).

    Parameters
    ----------
    time : str, datetime, numpy.datetime64 or pandas.Timestamp
        The instant (UTC; naive times are UTC).

    Returns
    -------
    tuple of float
        (lat, lon) [deg], lon in [-180, 180).

    References
    ----------
    Reda and Andreas (2004), Solar position algorithm for solar radiation applications, Solar Energy 76, 577-589,
    doi:10.1016/j.solener.2003.12.003 (pvlib ``get_solarposition``, method ``nrel_numpy``, geometric zenith).
    """
    import pvlib.solarposition as solpos

    when = pd.DatetimeIndex([pd.Timestamp(to_utc_datetime64(time))]).tz_localize("UTC")
    df = solpos.get_solarposition(when, 0.0, 0.0, altitude=0.0, method="nrel_numpy", delta_t=67.0)
    zenith, azimuth = np.deg2rad(float(df["zenith"].iloc[0])), np.deg2rad(float(df["azimuth"].iloc[0]))
    # ENU at (0 N, 0 E): east = +y, north = +z, up = +x of the earth-centred frame
    up, east, north = np.cos(zenith), np.sin(zenith) * np.sin(azimuth), np.sin(zenith) * np.cos(azimuth)
    lat = float(np.rad2deg(np.arcsin(np.clip(north, -1.0, 1.0))))
    lon = float(np.rad2deg(np.arctan2(east, up)))
    return lat, (lon + 180.0) % 360.0 - 180.0


def l1_view(sub_lat: float, sub_lon: float, distance_m: float = L1_DISTANCE_M, margin: float = 1.05) -> dict:
    """Keyword arguments of :func:`swim.render` for a perspective camera above (sub_lat, sub_lon) at ``distance_m``
    from the earth's centre, looking straight down at it (north up, east right) with a field of view that fits the
    earth's disc and its atmosphere.

    Parameters
    ----------
    sub_lat, sub_lon : float
        The sub-observer point [deg].
    distance_m : float
        Distance of the camera from the earth's centre [m], > R + 100 km (default :data:`L1_DISTANCE_M`).
    margin : float
        Ratio [-] of the half field of view to the angular radius of the sphere ``R`` + :data:`LIMB_HEIGHT_M`, >= 1.

    Returns
    -------
    dict
        ``lat``, ``lon`` [deg], ``height`` [m above the ground: ``distance_m - R``, the ground's own height
        neglected], ``camera="perspective"`` and
        ``camera_options`` (``fov_deg``, ``view_azimuth_deg=0``, ``view_zenith_deg=180``). The image width is up to
        the caller (``camera_options["width"]``/``["height"]``).

    Raises
    ------
    SwimInputError
        For a distance inside the atmosphere or a margin below 1.
    """
    top = EARTH_RADIUS_M + LIMB_HEIGHT_M
    if not (np.isfinite(distance_m) and distance_m > top):
        raise SwimInputError(f"distance_m={distance_m!r}: expected > {top:.4g} m (above the atmosphere)")
    if not (np.isfinite(margin) and margin >= 1.0):
        raise SwimInputError(f"margin={margin!r}: expected >= 1 [-]")
    fov = 2.0 * margin * np.rad2deg(np.arcsin(top / distance_m))
    return {"lat": float(sub_lat), "lon": float(sub_lon), "height": float(distance_m - EARTH_RADIUS_M),
            "camera": "perspective",
            "camera_options": {"fov_deg": float(fov), "view_azimuth_deg": 0.0, "view_zenith_deg": 180.0}}

