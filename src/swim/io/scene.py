"""The canonical scene: validation, construction from numpy arrays, and opening files.

The canonical scene is an :class:`xarray.Dataset` on a (possibly terrain-following) grid with dimensions
``z, y, x``; every variable is in SI units. The format, the validation rules and the readers are documented
in ``docs/scene-format.md``; this module and :mod:`swim.io.scene_checks` (the checks of each group of variables)
are the one place that enforces them.

Decisions (see ``docs/scene-format.md``):

* An absent hydrometeor species means zero content everywhere. :func:`validate_scene` never adds all-zero
  species, so downstream code uses ``scene.get(f"{species}_content")`` and skips ``None``.
* ``<species>_effective_radius`` may be 0, NaN or anything else where the content of its species is 0; the
  validated copy holds :data:`swim.constants.DEFAULT_EFFECTIVE_RADIUS` there, so a validated radius is finite
  and positive everywhere. Where the content is positive it must lie in [1e-7, 0.1] m.
* ``height``, ``lat``, ``lon`` and ``terrain_height`` are data variables; ``x``, ``y`` (when the grid is
  regular in the scene frame), ``wavelength`` and the scalar ``time`` are coordinates.
"""

from __future__ import annotations

import inspect
import logging
from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr

from ..constants import EARTH_RADIUS_M, WAVELENGTHS_NM
from ..errors import SwimInputError
from ..frames import scene_to_geodetic
from .formats import LES_SUFFIXES as _LES_SUFFIXES  # noqa: F401 (swim.series reads it here)
from .formats import _is_wrf  # noqa: F401 (swim.series reads it here)
from .formats import file_kind, netcdf_format, unsupported_message
from .quantities import dequantified, is_quantity
from .scene_checks import (
    _2D,
    _3D,
    _LONG_NAMES,
    _UNITS,
    CONTENT_VARIABLES,
    DEFAULT_WIND_SPEED_M_S,
    MAX_AEROSOL_EXTINCTION_M1 as MAX_AEROSOL_EXTINCTION_M1,
    MAX_CONTENT_KG_M3,
    NEGATIVE_NOISE_KG_M3,
    RADIUS_RANGE_M as RADIUS_RANGE_M,
    RADIUS_VARIABLES,
    TERRAIN_RANGE_M as TERRAIN_RANGE_M,
    WIND_SPEED_RANGE_M_S,
    _check_aerosol,
    _check_smoke,
    _check_contents,
    _check_dataset,
    _check_height,
    _check_lat_lon,
    _check_radii,
    _check_surface,
    _check_terrain,
    _check_xy,
    _copied_and_scanned as _copied_and_scanned,
    _finite_or_raise,
    _warn_wet_below_terrain,
    require_real_numbers,
)

logger = logging.getLogger(__name__)

__all__ = [
    "CONTENT_VARIABLES",
    "RADIUS_VARIABLES",
    "MAX_CONTENT_KG_M3",
    "NEGATIVE_NOISE_KG_M3",
    "WIND_SPEED_RANGE_M_S",
    "DEFAULT_WIND_SPEED_M_S",
    "validate_scene",
    "scene_from_arrays",
    "open_scene",
    "layer_thickness",
    "domain_centre",
    "to_utc_datetime64",
]


# ---------------------------------------------------------------------------------------------------------------
# small helpers


def to_utc_datetime64(value, name: str = "time") -> np.datetime64:
    """Convert a time to a timezone-naive ``numpy.datetime64[ns]`` in UTC.

    Parameters
    ----------
    value : str, datetime.datetime, numpy.datetime64 or pandas.Timestamp
        The time. A timezone-aware value is converted to UTC; a naive one is taken as UTC.
    name : str
        Name used in error messages.

    Returns
    -------
    numpy.datetime64

    Raises
    ------
    SwimInputError
        If ``value`` cannot be parsed as a time.
    """
    if isinstance(value, np.ndarray):
        if value.size != 1:
            raise SwimInputError(f"{name} must be a single time; got {value.size} values")
        value = value.reshape(())[()]
    if isinstance(value, bytes):
        value = value.decode("ascii", "replace")
    try:
        ts = pd.Timestamp(value)
    except (ValueError, TypeError) as exc:
        raise SwimInputError(f"{name}={value!r} is not a time; expected e.g. '2023-06-21T18:00Z' (UTC)") from exc
    if ts is pd.NaT:
        raise SwimInputError(f"{name}={value!r} is not a time; expected e.g. '2023-06-21T18:00Z' (UTC)")
    if ts.tzinfo is not None:
        ts = ts.tz_convert("UTC").tz_localize(None)
    return np.datetime64(ts.to_datetime64(), "ns")


def domain_centre(lat, lon) -> tuple[float, float]:
    """Centre of a set of columns: the direction of the mean of their earth-centred unit vectors.

    Parameters
    ----------
    lat, lon : array_like
        Latitudes and longitudes [deg] of the columns, any (equal) shape.

    Returns
    -------
    tuple of float
        ``(lat0, lon0)`` [deg], ``lon0`` in [-180, 180).
    """
    la = np.deg2rad(np.asarray(lat, dtype=float)).ravel()
    lo = np.deg2rad(np.asarray(lon, dtype=float)).ravel()
    v = np.array([np.mean(np.cos(la) * np.cos(lo)), np.mean(np.cos(la) * np.sin(lo)), np.mean(np.sin(la))])
    norm = np.linalg.norm(v)
    if not norm > 0:
        raise SwimInputError("lat/lon: the columns of the scene have no well-defined centre")
    v /= norm
    lat0 = float(np.rad2deg(np.arcsin(np.clip(v[2], -1.0, 1.0))))
    lon0 = float((np.rad2deg(np.arctan2(v[1], v[0])) + 180.0) % 360.0 - 180.0)
    return lat0, lon0


def layer_thickness(height, terrain_height) -> np.ndarray:
    """Thickness [m] of the layers around the mass points of each column.

    The layer interfaces lie midway between adjacent mass points; the bottom interface is the terrain (or the
    lowest mass point minus half the first spacing where the terrain lies above it) and the top interface lies
    half a spacing above the highest mass point. ``sum(content * layer_thickness, axis=0)`` is the column
    water path [kg m-2].

    Parameters
    ----------
    height : array_like
        Shape (nz, ny, nx): heights of the mass points [m], increasing with z.
    terrain_height : array_like
        Shape (ny, nx) [m].

    Returns
    -------
    numpy.ndarray
        Shape (nz, ny, nx) [m].
    """
    h = np.asarray(height, dtype=float)
    t = np.asarray(terrain_height, dtype=float)
    if h.shape[0] < 2:
        raise SwimInputError("height: layer thickness needs at least 2 levels along z")
    mid = 0.5 * (h[1:] + h[:-1])
    bottom = h[0] - 0.5 * (h[1] - h[0])
    bottom = np.where(t < h[0], np.maximum(t, bottom), bottom)
    top = h[-1] + 0.5 * (h[-1] - h[-2])
    interfaces = np.concatenate([bottom[None], mid, top[None]], axis=0)
    return np.diff(interfaces, axis=0)


#: Least plausible horizontal spacing [m] of a grid whose levels are more than :data:`KM_ASPECT` times further apart:
#: below it the x/y axes are taken for km (a 3 km grid given as 3.0 against levels 100-500 m apart).
LEAST_SPACING_M = 5.0
KM_ASPECT = 20.0


def _check_horizontal_metres(xv, yv, height):
    """Refuse x/y axes [m] that look like km: a spacing below :data:`LEAST_SPACING_M` under levels more than
    :data:`KM_ASPECT` times further apart."""
    spacing = [float(np.median(np.diff(v))) for v in (xv, yv) if v.size > 1]
    if not spacing or height.shape[0] < 2:
        return
    dz = float(np.median(np.diff(height, axis=0)))
    dx = min(spacing)
    if dx < LEAST_SPACING_M and dz > KM_ASPECT * dx:
        raise SwimInputError(f"x/y spacing {dx:g} m under levels {dz:.4g} m apart: expected x and y in metres, not km")


# ---------------------------------------------------------------------------------------------------------------
# validation


def validate_scene(ds: xr.Dataset) -> xr.Dataset:
    """Check a scene against the canonical format and return a cleaned canonical copy.

    Parameters
    ----------
    ds : xarray.Dataset
        Candidate scene with dims ``z, y, x``: ``height`` (z, y, x) [m above sea level], ``lat``, ``lon``
        (y, x) [deg], ``terrain_height`` (y, x) [m], optional ``<species>_content`` (z, y, x) [kg m-3],
        ``<species>_effective_radius`` (z, y, x) [m], ``aerosol_extinction`` (z, y, x) [m-1 at 550 nm],
        ``surface_albedo`` (wavelength, y, x) or (y, x) [-], ``land_mask`` (y, x) [1 land, 0 water],
        ``snow_cover`` (y, x) [fraction 0-1; absent means 0], ``wind_speed_10m`` (y, x) [m s-1; absent means the
        renderer's default :data:`DEFAULT_WIND_SPEED_M_S`], attrs
        ``reference_lat``/``reference_lon`` [deg], ``title``, ``source`` and a scalar coordinate ``time``.
        See ``docs/scene-format.md``.

    Returns
    -------
    xarray.Dataset
        A new dataset (the input is not modified and shares no memory with it): float64 values (``land_mask``
        int8), dims transposed to canonical order, ``units`` and ``long_name`` on every variable,
        numerical-noise negatives clipped to 0, effective radii filled with
        :data:`swim.constants.DEFAULT_EFFECTIVE_RADIUS` where the content is 0, a 2-D albedo broadcast to the
        three wavelengths [615, 546, 450] nm, ``lon`` wrapped to [-180, 180), ``reference_lat/lon`` set to the
        domain centre when absent, ``title``/``source`` defaulted. Unknown variables are dropped (logged).

    Raises
    ------
    SwimInputError
        When a required variable (``height``, ``lat``, ``lon``, ``terrain_height``) is missing; when dims or
        shapes disagree; on non-finite values (the message gives the variable and the count); when ``height``
        does not increase strictly with z in every column or looks like km; on negative contents below -1e-12
        kg m-3; on a content above 0.05 kg m-3 (50 g m-3: g m-3 or g kg-1 given as kg m-3); on a ``units``
        attribute that is not a spelling of the canonical unit; on an effective radius outside [1e-7, 0.1] m
        (or non-finite) where the content is positive ("expected metres"), or without its content variable;
        on latitudes outside [-90, 90] or longitudes outside [-360, 360]; on albedo outside [0, 1]; on a land
        mask other than 0/1; on ``snow_cover`` outside [0, 1]; on ``wind_speed_10m`` outside [0, 75] m s-1; on
        terrain outside [-500, 9000] m; on aerosol extinction < 0 or > 0.05 m-1; on a ``time`` that is not a
        single time.
    """
    ds = _check_dataset(ds)
    height_da, height = _check_height(ds)
    shape = height.shape
    out: dict[str, xr.DataArray] = {"height": height_da}
    out["lat"], out["lon"] = _check_lat_lon(ds, shape[1:])
    out["terrain_height"] = _check_terrain(ds, shape[1:])
    variables, contents = _check_contents(ds, shape)
    out.update(variables)
    _warn_wet_below_terrain(height, out["terrain_height"].values, contents)
    out.update(_check_radii(ds, shape, contents))
    if "aerosol_extinction" in ds.variables:
        out["aerosol_extinction"] = _check_aerosol(ds, shape)
    if "smoke_mass_content" in ds.variables:
        out["smoke_mass_content"] = _check_smoke(ds, shape)
    variables, coords = _check_surface(ds, shape[1:])
    out.update(variables)
    lat, lon = out["lat"].values, out["lon"].values
    attrs = _check_attributes(ds.attrs, lat, lon)
    coords.update(_check_xy(ds, lat, lon, attrs["reference_lat"], attrs["reference_lon"]))
    if "time" in ds.variables:
        coords["time"] = _validate_time(ds["time"])
    return xr.Dataset(out, attrs=attrs).assign_coords(coords)


def _check_attributes(ds_attrs: dict, lat: np.ndarray, lon: np.ndarray) -> dict:
    """The scene's attributes with a finite reference point in range (the domain centre of ``lat``/``lon`` where
    it is missing; ``reference_lon`` wrapped to [-180, 180)) and a ``title`` and ``source``."""
    attrs = {k: v for k, v in ds_attrs.items()}
    for key in ("reference_lat", "reference_lon"):
        if key in attrs:
            try:
                attrs[key] = float(attrs[key])
            except (TypeError, ValueError) as exc:
                raise SwimInputError(f"scene attribute {key}={attrs[key]!r} is not a number [deg]") from exc
            if not np.isfinite(attrs[key]):
                raise SwimInputError(f"scene attribute {key} is not finite")
    if "reference_lat" not in attrs or "reference_lon" not in attrs:
        lat0, lon0 = domain_centre(lat, lon)
        logger.info("validate_scene: reference point missing; using the domain centre (%.4f, %.4f)", lat0, lon0)
        attrs.setdefault("reference_lat", lat0)
        attrs.setdefault("reference_lon", lon0)
    if not -90.0 <= attrs["reference_lat"] <= 90.0:
        raise SwimInputError(f"reference_lat={attrs['reference_lat']} is outside [-90, 90] degrees_north")
    if not -360.0 <= attrs["reference_lon"] <= 360.0:
        raise SwimInputError(f"reference_lon={attrs['reference_lon']} is outside [-360, 360] degrees_east")
    attrs["reference_lon"] = float((attrs["reference_lon"] + 180.0) % 360.0 - 180.0)
    attrs["title"] = str(attrs.get("title", "swim scene"))
    attrs["source"] = str(attrs.get("source", "unknown"))
    return attrs


def _validate_time(t: xr.DataArray) -> xr.DataArray:
    """The scalar ``time`` coordinate as UTC ``datetime64[ns]``; refused unless it is a single time."""
    values = np.asarray(t.values)
    if values.size != 1:
        raise SwimInputError(f"scene 'time' must be a single (scalar) time; got {values.size} values: select one")
    dt = to_utc_datetime64(values, "time")
    return xr.DataArray(dt, attrs={"long_name": _LONG_NAMES["time"]})


# ---------------------------------------------------------------------------------------------------------------
# construction from arrays


def _regular_axis(name: str, values) -> np.ndarray:
    """Grid coordinates [m] along ``name``: 1-D, finite, strictly increasing, regularly spaced, within reach."""
    require_real_numbers(name, np.asarray(values).dtype)
    v = np.asarray(values, dtype=float)
    if v.ndim != 1 or v.size < 1:
        raise SwimInputError(f"{name} must be a 1-D array of grid coordinates [m]; got shape {v.shape}")
    _finite_or_raise(name, v)
    if v.size > 1:
        d = np.diff(v)
        if np.any(d <= 0):
            raise SwimInputError(f"{name} [m] must increase strictly")
        if np.max(np.abs(d - d.mean())) > 1e-6 * max(abs(d.mean()), 1.0) + 1e-6:
            raise SwimInputError(f"{name} [m] must be regularly spaced; spacing ranges {d.min():.6g} to {d.max():.6g} m")
    if np.max(np.abs(v)) > 0.5 * EARTH_RADIUS_M:
        raise SwimInputError(f"{name}: |{name}| up to {np.max(np.abs(v)):.4g} m is too far from the reference point; expected metres")
    return v


def _heights(z, ny: int, nx: int) -> np.ndarray:
    """Heights [m] of the mass points, shape (nz, ny, nx), from ``z`` of shape (nz,) or (nz, ny, nx)."""
    require_real_numbers("z", np.asarray(z).dtype)
    zv = np.asarray(z, dtype=float)
    if zv.ndim == 1:
        return np.broadcast_to(zv[:, None, None], (zv.size, ny, nx)).copy()
    if zv.ndim == 3 and zv.shape[1:] == (ny, nx):
        return zv.copy()
    raise SwimInputError(
        f"z must have shape (nz,) or (nz, ny, nx) = (nz, {ny}, {nx}) [m above sea level]; got {zv.shape}"
    )


def _columns_lat_lon(xv: np.ndarray, yv: np.ndarray, reference_lat: float, reference_lon: float):
    """Latitude and longitude [deg], shape (ny, nx), of the columns at grid ``x``, ``y`` [m]: the inverse of
    :func:`swim.frames.orthographic_xy` about the reference point."""
    gx, gy = np.meshgrid(xv, yv)
    r2 = gx**2 + gy**2
    if np.any(r2 >= EARTH_RADIUS_M**2):
        raise SwimInputError("x, y reach beyond the earth's limb seen from the reference point; expected metres")
    p = np.stack([gx, gy, np.sqrt(EARTH_RADIUS_M**2 - r2)], axis=-1)
    lat, lon, _ = scene_to_geodetic(p, reference_lat, reference_lon)
    return lat, lon


def _array_field(name: str, value, shape: tuple[int, ...], dims: tuple[str, ...]) -> xr.DataArray:
    """``value`` broadcast to ``shape`` as a float64 variable on ``dims`` with the units and long name of ``name``."""
    raw = np.asarray(value)
    require_real_numbers(f"scene_from_arrays: {name}", raw.dtype)  # then the cast to float cannot fail
    a = raw.astype(float)
    try:
        a = np.broadcast_to(a, shape).copy()
    except ValueError as exc:
        raise SwimInputError(f"{name} must have shape {shape} {dims}; got {np.shape(value)}") from exc
    return xr.DataArray(a, dims=dims, attrs={"units": _UNITS[name], "long_name": _LONG_NAMES[name]})


def _grid_fields(xv, yv, height, reference_lat, reference_lon, terrain_height) -> tuple[dict, dict]:
    """The geometry of a scene on the regular grid ``xv``, ``yv`` [m]: the variables ``height``, ``lat``, ``lon``
    and ``terrain_height`` (default 0, sea level), and the coordinates ``x`` and ``y``."""
    ny, nx = yv.size, xv.size
    lat, lon = _columns_lat_lon(xv, yv, reference_lat, reference_lon)
    data = {
        "height": xr.DataArray(height, dims=_3D, attrs={"units": "m", "long_name": _LONG_NAMES["height"]}),
        "lat": xr.DataArray(lat, dims=_2D, attrs={"units": "degrees_north", "long_name": "latitude"}),
        "lon": xr.DataArray(lon, dims=_2D, attrs={"units": "degrees_east", "long_name": "longitude"}),
        "terrain_height": _array_field("terrain_height", 0.0 if terrain_height is None else terrain_height, (ny, nx),
                                       _2D),
    }
    coords = {
        "x": xr.DataArray(xv, dims=("x",), attrs={"units": "m", "long_name": _LONG_NAMES["x"]}),
        "y": xr.DataArray(yv, dims=("y",), attrs={"units": "m", "long_name": _LONG_NAMES["y"]}),
    }
    return data, coords


def _volume_fields(shape: tuple[int, int, int], given: dict) -> dict:
    """The (z, y, x) variables of ``given`` (name: value) that are not None, broadcast to ``shape``: contents and
    aerosol extinction must be 3-D, effective radii may also be scalars."""
    data = {}
    for name, value in given.items():
        if value is not None:
            if name in CONTENT_VARIABLES + ("aerosol_extinction", "smoke_mass_content") and np.ndim(value) != 3:
                raise SwimInputError(f"{name} must have shape (nz, ny, nx) = {shape}; got {np.shape(value)}")
            data[name] = _array_field(name, value, shape, _3D)
    return data


def _albedo_field(surface_albedo, ny: int, nx: int) -> tuple[xr.DataArray, xr.DataArray]:
    """``surface_albedo`` of shape (3, ny, nx), (ny, nx), (3,) or scalar broadcast to (wavelength, y, x), and the
    ``wavelength`` coordinate."""
    a = np.asarray(surface_albedo, dtype=float)
    if a.ndim == 1:
        a = a[:, None, None]
    return (_array_field("surface_albedo", a, (WAVELENGTHS_NM.size, ny, nx), ("wavelength",) + _2D),
            xr.DataArray(WAVELENGTHS_NM.copy(), dims=("wavelength",), attrs={"units": "nm"}))


def scene_from_arrays(
    *,
    x,
    y,
    z,
    reference_lat: float,
    reference_lon: float,
    terrain_height=None,
    cloud_liquid_content=None,
    cloud_ice_content=None,
    rain_content=None,
    snow_content=None,
    graupel_content=None,
    cloud_liquid_effective_radius=None,
    cloud_ice_effective_radius=None,
    rain_effective_radius=None,
    snow_effective_radius=None,
    graupel_effective_radius=None,
    aerosol_extinction=None,
    smoke_mass_content=None,
    surface_albedo=None,
    land_mask=None,
    snow_cover=None,
    wind_speed_10m=None,
    time=None,
    title: str = "swim scene from arrays",
    source: str = "swim.io.scene.scene_from_arrays",
) -> xr.Dataset:
    """Build and validate a canonical scene from numpy arrays on a regular horizontal grid.

    Parameters
    ----------
    x, y : array_like
        Shape (nx,) and (ny,): regular, strictly increasing grid coordinates [m] east and north of the reference
        point (the grid horizontal coordinates of :mod:`swim.frames`; (0, 0) is the reference point).
    z : array_like
        Heights of the mass points [m above sea level]: shape (nz,) (the same in every column) or (nz, ny, nx)
        (e.g. terrain-following); strictly increasing along z.
    reference_lat, reference_lon : float
        Reference point of the scene frame [deg].
    terrain_height : array_like, optional
        Shape (ny, nx) or scalar [m]; default 0 (sea level).
    cloud_liquid_content, cloud_ice_content, rain_content, snow_content, graupel_content : array_like, optional
        Shape (nz, ny, nx) [kg m-3]; an omitted species is absent (zero).
    cloud_liquid_effective_radius, cloud_ice_effective_radius, rain_effective_radius, snow_effective_radius, \
graupel_effective_radius : array_like, optional
        Shape (nz, ny, nx) or scalar [m].
    aerosol_extinction : array_like, optional
        Shape (nz, ny, nx) [m-1 at 550 nm].
    smoke_mass_content : array_like, optional
        (z, y, x) smoke mass concentration [kg m-3]; the renderer adds its extinction to the aerosol's (4.5 m2 g-1 at
        550 nm, :func:`swim.optics.model_aerosol.smoke_extinction`).
    surface_albedo : array_like, optional
        Shape (3, ny, nx) for [615, 546, 450] nm, (ny, nx), (3,) or scalar [-], broadcast to (3, ny, nx):
        the snow-free albedo.
    land_mask : array_like, optional
        Shape (ny, nx) or scalar: 1 land, 0 water.
    snow_cover : array_like, optional
        Shape (ny, nx) or scalar: fraction [0-1] of the surface covered by snow or ice; absent means 0.
        ``surface_albedo`` stays the snow-free albedo; the renderer blends the snow in
        (``docs/surfaces.md``).
    wind_speed_10m : array_like, optional
        Shape (ny, nx) or scalar: 10 m wind speed [m s-1] in [0, 75]; absent: the renderer's default
        (:data:`DEFAULT_WIND_SPEED_M_S`).
    time : str, datetime or numpy.datetime64, optional
        Valid time (UTC); stored as the scalar coordinate ``time``.
    title, source : str
        Dataset attributes.

    Returns
    -------
    xarray.Dataset
        The validated canonical scene (:func:`validate_scene`), with 1-D coordinates ``x`` and ``y`` [m] and
        ``lat``/``lon`` of the columns: the inverse of :func:`swim.frames.orthographic_xy`, so that
        ``orthographic_xy(lat, lon, reference_lat, reference_lon) == (x, y)``.

    Raises
    ------
    SwimInputError
        On a bad shape, irregular or non-increasing x/y, and anything :func:`validate_scene` rejects.
    """
    xv = _regular_axis("x", x)
    yv = _regular_axis("y", y)
    ny, nx = yv.size, xv.size
    height = _heights(z, ny, nx)
    _check_horizontal_metres(xv, yv, height)
    data, coords = _grid_fields(xv, yv, height, reference_lat, reference_lon, terrain_height)
    data.update(_volume_fields(height.shape, {
        "cloud_liquid_content": cloud_liquid_content, "cloud_ice_content": cloud_ice_content,
        "rain_content": rain_content, "snow_content": snow_content, "graupel_content": graupel_content,
        "cloud_liquid_effective_radius": cloud_liquid_effective_radius,
        "cloud_ice_effective_radius": cloud_ice_effective_radius, "rain_effective_radius": rain_effective_radius,
        "snow_effective_radius": snow_effective_radius, "graupel_effective_radius": graupel_effective_radius,
        "aerosol_extinction": aerosol_extinction,
        "smoke_mass_content": smoke_mass_content,
    }))
    if surface_albedo is not None:
        data["surface_albedo"], coords["wavelength"] = _albedo_field(surface_albedo, ny, nx)
    for name, value in (("land_mask", land_mask), ("snow_cover", snow_cover), ("wind_speed_10m", wind_speed_10m)):
        if value is not None:
            data[name] = _array_field(name, value, (ny, nx), _2D)
    if time is not None:
        coords["time"] = xr.DataArray(to_utc_datetime64(time))
    attrs = {"reference_lat": float(reference_lat), "reference_lon": float(reference_lon), "title": title, "source": source}
    return validate_scene(xr.Dataset(data, coords=coords, attrs=attrs))


# ---------------------------------------------------------------------------------------------------------------
# files



def _canonical_time(kwargs):
    """The ``time=`` option of a canonical scene file; no other reader option applies to one."""
    options = dict(kwargs)
    time = options.pop("time", None)
    if options:
        raise SwimInputError(f"open_scene: options {sorted(options)} do not apply to a canonical scene file")
    return time


def _reader_options(reader, kind, kwargs, internal=("source",)):
    """Refuse ``open_scene`` options that ``reader`` (the reader of a file of ``kind``) does not take, naming them
    and the ones it takes: a misspelt option (``tme=``) would otherwise end in a TypeError from deep inside."""
    params = list(inspect.signature(reader).parameters.items())[1:]  # after the path or dataset
    names = [name for name, par in params if par.kind in (par.POSITIONAL_OR_KEYWORD, par.KEYWORD_ONLY)
             and name not in internal]
    unknown = sorted(set(kwargs) - set(names))
    if unknown:
        raise SwimInputError(f"open_scene: unknown option(s) {', '.join(map(repr, unknown))} for {kind}; it takes "
                             f"{', '.join(names) or 'no options'}")


def _canonical_scene(scene, p, time):
    """Finish a canonical scene read from file p: a requested time must be within 1.5 h of the scene's, and an
    unknown source becomes the file's path."""
    if time is not None:
        if "time" not in scene.coords:
            raise SwimInputError(f"time={time!r} requested but scene file {p.name} has no time")
        want = to_utc_datetime64(time)
        have = scene["time"].values
        if abs(have - want) > np.timedelta64(90, "m"):
            raise SwimInputError(f"time={time!r}: scene file {p.name} holds only {pd.Timestamp(have)} UTC")
    if scene.attrs.get("source", "unknown") == "unknown":
        scene.attrs["source"] = str(p)
    return scene


def _open_scene_lazily(p, **kwargs):
    """A canonical scene file opened with dask arrays, checked for names and dimensions only (see open_scene)."""
    from .files import open_netcdf

    time = _canonical_time(kwargs)
    ds = open_netcdf(p, "scene file", chunks={})
    if not {"height", "lat", "lon"} <= set(ds.variables):
        ds.close()
        raise SwimInputError(
            f"open_scene(lazy=True): scene file {p.name} is not a canonical scene (height, lat, lon); WRF, WPS and "
            "LES files are read eagerly: open them with lazy=False, or write the scene with Dataset.to_netcdf first")
    missing = [d for d in ("z", "y", "x") if d not in ds.dims]
    if missing:
        ds.close()
        raise SwimInputError(f"scene file {p.name}: dimensions {missing} missing; a scene has (z, y, x) "
                             "(docs/scene-format.md)")
    return _canonical_scene(ds, p, time)


def as_scene(ds: xr.Dataset, time=None, lat=None, lon=None) -> xr.Dataset:
    """A dataset in any layout swim reads, as a scene :func:`swim.render` takes: the first layout of
    :data:`swim.io.formats.NETCDF_FORMATS` it matches (WRF raw or post-processed by xwrf,
    :mod:`swim.io.wrf_postprocessed`; WPS; ERA5/IFS; ICON; MPAS) through its reader at ``time`` (and, for readers
    that cut a region, about ``lat``/``lon``); a canonical scene is returned as it is (the render validates it), with
    unit-aware (pint, MetPy) values converted to the canonical units first (:mod:`swim.io.quantities`). WRF
    datasets take quantities too; the other layouts refuse them by name.

    Parameters
    ----------
    ds : xarray.Dataset
        The dataset.
    time : None, str, datetime or numpy.datetime64, optional
        The time to read from a dataset with several (its reader's rule); ignored for a scene.
    lat, lon : float, optional
        The camera's place [deg], passed to readers that cut a region around it (ERA5/IFS, ICON, MPAS).

    Returns
    -------
    xarray.Dataset
        A canonical scene (validated, for WRF and WPS input) or the scene given.

    Raises
    ------
    SwimInputError
        When ``ds`` is not a Dataset, or its readers reject it.
    """
    if not isinstance(ds, xr.Dataset):
        raise SwimInputError(f"scene must be an xarray.Dataset; got {type(ds).__name__}")
    from .wrf_postprocessed import is_xwrf_dataset

    fmt = None if is_xwrf_dataset(ds) else netcdf_format(ds)
    if fmt is None and not is_xwrf_dataset(ds):
        return ds  # not a known layout: validate_scene names what is missing
    if fmt is not None and fmt.reader.endswith(":validate_scene"):
        return dequantified(ds, _UNITS, "scene")
    reader = fmt.load_reader() if fmt is not None else _read_wrf()
    if any(is_quantity(v.data) for v in ds.variables.values()) and reader is not _read_wrf():
        raise SwimInputError(f"a {fmt.name} dataset of pint quantities: call .pint.dequantify() (or "
                             ".metpy.dequantify()) first; WRF datasets and canonical scenes take quantities")
    params = inspect.signature(reader).parameters
    place = {k: v for k, v in (("lat", lat), ("lon", lon)) if v is not None and k in params}
    return reader(ds, time=time, **place)


def _read_wrf():
    from .wrf import read_wrf

    return read_wrf


def open_scene(path, lazy: bool = False, **kwargs) -> xr.Dataset:
    """Open a scene file of any supported kind and return the validated canonical scene.

    Dispatch is on content (:mod:`swim.io.formats`, :func:`scene_reader`): a file that starts with ``GRIB`` goes to
    :func:`swim.io.grib.grib_reader_for`'s reader (NCEP GFS, HRRR/RAP, ECMWF); a netCDF/HDF5 file to the first
    layout of :data:`swim.io.formats.NETCDF_FORMATS` it matches (WRF, WPS ``geo_em``/``met_em``, ERA5 pressure
    levels, IFS model levels, ICON, MPAS, the canonical scene); a text file whose header parses as an SHDOM-style LES
    header (or named ``.txt``, ``.lwc``, ``.dat``) to :func:`swim.io.les.read_shdom_les`. Names and suffixes do not
    matter otherwise.

    Parameters
    ----------
    path : str or os.PathLike
        File to open.
    lazy : bool
        Canonical scene files only: open the fields as dask arrays and return the scene unvalidated, so that
        :func:`swim.render` crops it to what the camera can see before anything is read in full (the way to
        render CONUS-size grids in a few GB; docs/rendering.md, "Cropping big grids"). Only the names, the
        dimensions and the time are checked here; :func:`swim.render` validates the cropped scene. A GRIB
        file's region is small and is read at once, lazy or not.
    **kwargs
        Passed to the reader (``time=`` for WRF; ``time=``, ``month=``, ``albedo_band=``, ``snow_above_m=`` for
        WPS files; ``reference_lat=``, ``reference_lon=``, ``time=`` for LES; ``lat=``, ``lon=`` (the camera's
        place, needed for a global file), ``radius_deg=``, ``time=`` for GRIB, ERA5/IFS, ICON and MPAS files, and
        each reader's own options, e.g. ``cloud_fraction=`` for ECMWF files; see their docstrings).
        A canonical netCDF scene takes ``time=`` only to check it against the file's time (1.5 h tolerance).

    Returns
    -------
    xarray.Dataset
        The canonical scene.

    Raises
    ------
    SwimInputError
        If the file does not exist, is of an unknown kind, or its content is invalid.
    """
    p = Path(path)
    if not p.is_file():
        raise SwimInputError(f"scene file not found: {p}")
    if lazy and file_kind(p) != "grib":
        return _open_scene_lazily(p, **kwargs)
    reader, kind, dataset = scene_reader(p)
    if dataset is None:
        _reader_options(reader, kind, kwargs)
        return reader(p, **kwargs)
    with dataset:  # closed whatever the reader raises
        if reader is validate_scene:
            return _canonical_scene(validate_scene(dataset.load()), p, _canonical_time(kwargs))
        _reader_options(reader, kind, kwargs)
        dataset.load()
        if "source" in inspect.signature(reader).parameters:
            kwargs = {"source": str(p), **kwargs}
        return reader(dataset, **kwargs)


def scene_reader(path):
    """The reader of a scene file, from its content (:mod:`swim.io.formats`), without reading its fields.

    Parameters
    ----------
    path : pathlib.Path
        An existing file.

    Returns
    -------
    reader : callable
        The reader; :func:`validate_scene` for a canonical scene file.
    kind : str
        What the file is ("a WRF wrfout file"), for messages.
    dataset : xarray.Dataset or None
        The netCDF file opened (not loaded) where the reader takes a dataset; the caller closes it. None where the
        reader takes the path (GRIB, LES text).

    Raises
    ------
    SwimInputError
        For a file no reader takes: the message lists the formats and how to build a canonical scene.
    """
    kind = file_kind(path)
    if kind == "grib":
        from .grib import grib_reader_for

        return grib_reader_for(path), "a GRIB file", None
    if kind == "les":
        from .les import read_shdom_les

        return read_shdom_les, "an SHDOM-style LES file", None
    if kind == "unknown":
        raise SwimInputError(unsupported_message(path.name, "neither GRIB, netCDF nor an SHDOM-style LES text file"))
    from .files import open_netcdf

    ds = open_netcdf(path, "scene file")
    try:
        fmt = netcdf_format(ds)
        if fmt is None:
            raise SwimInputError(unsupported_message(path.name, "a netCDF file of no layout swim knows"))
        reader = fmt.load_reader()
    except BaseException:
        ds.close()
        raise
    if fmt.takes_path:  # the reader opens the file itself and reads only what it needs
        ds.close()
        return reader, f"a {fmt.name} file", None
    return reader, f"a {fmt.name} file", ds
