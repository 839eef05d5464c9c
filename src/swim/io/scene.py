"""The canonical scene: validation, construction from numpy arrays, and opening files.

The canonical scene is an :class:`xarray.Dataset` on a (possibly terrain-following) grid with dimensions
``z, y, x``; every variable is in SI units. The format, the validation rules and the readers are documented
in ``docs/scene-format.md``; this module is the one place that enforces them.

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

import logging
from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr

from ..constants import DEFAULT_EFFECTIVE_RADIUS, EARTH_RADIUS_M, SPECIES, WAVELENGTHS_NM
from ..errors import SwimInputError
from ..frames import orthographic_xy, scene_to_geodetic
from ..workers import in_blocks

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

#: Names of the mass-content variables [kg m-3], in the order of :data:`swim.constants.SPECIES`.
CONTENT_VARIABLES = tuple(f"{s}_content" for s in SPECIES)
#: Names of the optional effective-radius variables [m].
RADIUS_VARIABLES = tuple(f"{s}_effective_radius" for s in SPECIES)
#: Largest plausible hydrometeor mass content [kg m-3] (50 g m-3); larger values mean wrong units.
MAX_CONTENT_KG_M3 = 0.05
#: Negative contents down to minus this value [kg m-3] are numerical noise and are clipped to 0.
NEGATIVE_NOISE_KG_M3 = 1e-12
#: Plausible range of an effective radius where there is content [m].
RADIUS_RANGE_M = (1e-7, 0.1)
#: Largest plausible aerosol extinction at 550 nm [m-1] (visibility ~ 80 m); larger values mean wrong units.
MAX_AEROSOL_EXTINCTION_M1 = 0.05
#: Plausible range of terrain height [m].
TERRAIN_RANGE_M = (-500.0, 9000.0)
#: Plausible range of the 10 m wind speed [m s-1] (the strongest measured gusts are about 113 m s-1, but a
#: grid-cell mean 10 m wind above 75 m s-1 means wrong units).
WIND_SPEED_RANGE_M_S = (0.0, 75.0)
#: 10 m wind speed [m s-1] the renderer assumes where the scene has no ``wind_speed_10m``.
DEFAULT_WIND_SPEED_M_S = 5.0

_LONG_NAMES = {
    "height": "height above sea level of the mass points",
    "lat": "latitude",
    "lon": "longitude",
    "terrain_height": "terrain height above sea level",
    "cloud_liquid_content": "cloud liquid water mass content",
    "cloud_ice_content": "cloud ice mass content",
    "rain_content": "rain mass content",
    "snow_content": "snow mass content",
    "graupel_content": "graupel mass content",
    "cloud_liquid_effective_radius": "cloud liquid effective radius",
    "cloud_ice_effective_radius": "cloud ice effective radius",
    "rain_effective_radius": "rain effective radius",
    "snow_effective_radius": "snow effective radius",
    "graupel_effective_radius": "graupel effective radius",
    "aerosol_extinction": "aerosol extinction coefficient at 550 nm",
    "surface_albedo": "surface spectral albedo",
    "land_mask": "land mask (1 land, 0 water)",
    "snow_cover": "fraction of the surface covered by snow or ice",
    "wind_speed_10m": "wind speed at 10 m above the surface",
    "x": "grid x (east) of the column in the scene frame",
    "y": "grid y (north) of the column in the scene frame",
    "wavelength": "wavelength",
    "time": "valid time (UTC)",
}

_UNITS = {
    "height": "m",
    "lat": "degrees_north",
    "lon": "degrees_east",
    "terrain_height": "m",
    "aerosol_extinction": "m-1",
    "surface_albedo": "1",
    "land_mask": "1",
    "snow_cover": "1",
    "wind_speed_10m": "m s-1",
    "x": "m",
    "y": "m",
    "wavelength": "nm",
    **{name: "kg m-3" for name in CONTENT_VARIABLES},
    **{name: "m" for name in RADIUS_VARIABLES},
}

_3D = ("z", "y", "x")
_2D = ("y", "x")
_CANONICAL_VARIABLES = (
    ("height", "lat", "lon", "terrain_height")
    + CONTENT_VARIABLES
    + RADIUS_VARIABLES
    + ("aerosol_extinction", "surface_albedo", "land_mask", "snow_cover", "wind_speed_10m")
)

# ---------------------------------------------------------------------------------------------------------------
# units


def _normalise_units(units) -> str:
    s = str(units).strip().lower()
    for old, new in (("**", ""), ("^", ""), (" ", ""), (".", ""), ("·", ""), ("*", ""), ("μ", "u"), ("µ", "u")):
        s = s.replace(old, new)
    return s


_ACCEPTED_UNITS = {
    "kg m-3": {"kgm-3", "kg/m3"},
    "m": {"m", "meter", "meters", "metre", "metres"},
    "m-1": {"m-1", "1/m", "/m"},
    "degrees_north": {"degrees_north", "degree_north", "degrees_n", "degree_n", "degreesnorth", "degrees", "degree", "deg", "°n", "°"},
    "degrees_east": {"degrees_east", "degree_east", "degrees_e", "degree_e", "degreeseast", "degrees", "degree", "deg", "°e", "°"},
    "1": {"1", "", "-", "fraction", "dimensionless", "none", "0-1"},
    "nm": {"nm", "nanometer", "nanometers", "nanometre", "nanometres"},
    "m s-1": {"ms-1", "m/s", "mps"},
}

_UNIT_HINTS = {
    "gm-3": "g m-3: multiply by 1e-3",
    "g/m3": "g m-3: multiply by 1e-3",
    "kgkg-1": "a mixing ratio: multiply by the air density",
    "kg/kg": "a mixing ratio: multiply by the air density",
    "gkg-1": "a mixing ratio in g kg-1: multiply by 1e-3 and by the air density",
    "g/kg": "a mixing ratio in g kg-1: multiply by 1e-3 and by the air density",
    "um": "micrometres: multiply by 1e-6",
    "micron": "micrometres: multiply by 1e-6",
    "microns": "micrometres: multiply by 1e-6",
    "micrometer": "micrometres: multiply by 1e-6",
    "micrometre": "micrometres: multiply by 1e-6",
    "km": "kilometres: multiply by 1e3",
    "km-1": "per kilometre: multiply by 1e-3",
    "1/km": "per kilometre: multiply by 1e-3",
    "%": "percent: divide by 100",
    "percent": "percent: divide by 100",
    "kmh-1": "km h-1: divide by 3.6",
    "km/h": "km h-1: divide by 3.6",
    "kt": "knots: multiply by 0.514444",
    "kts": "knots: multiply by 0.514444",
    "knot": "knots: multiply by 0.514444",
    "knots": "knots: multiply by 0.514444",
}


def _check_units(name: str, da: xr.DataArray) -> None:
    """Raise if ``da.attrs['units']`` is present and not a spelling of the canonical unit of ``name``."""
    expected = _UNITS[name]
    if "units" not in da.attrs:
        return
    got = _normalise_units(da.attrs["units"])
    if got in _ACCEPTED_UNITS[expected]:
        return
    hint = _UNIT_HINTS.get(got)
    hint = f" ('{da.attrs['units']}' looks like {hint})" if hint else ""
    raise SwimInputError(
        f"scene variable '{name}' has units '{da.attrs['units']}' but must be in {expected}{hint}; convert it and set "
        f"units='{expected}'"
    )


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


def require_real_numbers(label: str, dtype) -> None:
    """Refuse a field ``label`` of values that are not real numbers (float, integer or bool ``dtype``): a complex
    field would lose its imaginary part, text or objects would fail deep inside.

    Raises
    ------
    SwimInputError
        Naming ``label`` and the dtype.
    """
    if not (np.issubdtype(dtype, np.floating) or np.issubdtype(dtype, np.integer) or np.issubdtype(dtype, np.bool_)):
        raise SwimInputError(f"{label} holds {dtype} values; expected real numbers")


def _as_dataarray(name: str, ds: xr.Dataset) -> xr.DataArray:
    da = ds[name].reset_coords(drop=True)
    require_real_numbers(f"scene variable '{name}'", da.dtype)
    return da


def _check_dims(name: str, da: xr.DataArray, dims: tuple[str, ...]) -> xr.DataArray:
    if set(da.dims) != set(dims) or len(da.dims) != len(dims):
        raise SwimInputError(f"scene variable '{name}' has dims {tuple(da.dims)}; expected {dims}")
    return da.transpose(*dims)


def _finite_or_raise(name: str, values: np.ndarray, not_finite: int | None = None) -> None:
    """Raise if ``values`` holds NaN or inf (``not_finite``: their count, where a scan has counted them)."""
    if not_finite is None:
        not_finite = int(np.count_nonzero(~np.isfinite(values)))
    if not_finite:
        raise SwimInputError(
            f"scene variable '{name}' has {int(not_finite)} non-finite value(s) (NaN or inf) out of {values.size}; "
            f"every value must be finite ({_UNITS.get(name, '')})"
        )


def _copied_and_scanned(values) -> tuple[np.ndarray, dict]:
    """A float64 copy of a 3-D array (level, y, x) and its statistics: ``not finite`` and ``negative`` (counts),
    ``min`` and ``max`` (of the finite values), from one compiled pass in blocks of levels on every core
    (:func:`swim.io.scan_cpu.copy_and_scan`; numba is imported at the first scan, not with :mod:`swim`)."""
    from .scan_cpu import STATS, copy_and_scan

    source = np.asarray(values)
    if source.dtype not in (np.float32, np.float64):  # one compiled version per dtype: the others converted first
        source = source.astype(np.float64)
    copy = np.empty(source.shape, np.float64)
    blocks = []

    def scan(k0, k1):
        stats = np.zeros(len(STATS))
        copy_and_scan(source, copy, k0, k1, stats)
        blocks.append(stats)

    in_blocks(scan, source.shape[0])
    stats = np.array(blocks).reshape(-1, len(STATS))
    return copy, {"not finite": int(stats[:, 0].sum()), "negative": int(stats[:, 1].sum()),
                  "min": float(stats[:, 2].min(initial=np.inf)), "max": float(stats[:, 3].max(initial=-np.inf))}


def _new_attrs(name: str, old: dict) -> dict:
    attrs = {k: v for k, v in old.items() if k not in ("units", "long_name", "_FillValue", "missing_value", "coordinates")}
    attrs["units"] = _UNITS[name]
    attrs["long_name"] = str(old.get("long_name", _LONG_NAMES[name]))
    return attrs


def _clip_noise(name: str, values: np.ndarray, negative: int | None = None) -> np.ndarray:
    """Raise on negative values below -1e-12, clip the numerical noise in [-1e-12, 0) to 0 (logged). ``negative``:
    the count of negative values, where a scan has counted them."""
    if negative == 0:
        return values
    neg = values < 0
    if not neg.any():
        return values
    vmin = float(values.min())
    if vmin < -NEGATIVE_NOISE_KG_M3:
        raise SwimInputError(
            f"scene variable '{name}' has {int((values < -NEGATIVE_NOISE_KG_M3).sum())} negative value(s) (min "
            f"{vmin:.3g}); it must be >= 0 ({_UNITS[name]}); values down to -{NEGATIVE_NOISE_KG_M3:g} are clipped as "
            "numerical noise"
        )
    logger.info("%s: clipped %d negative value(s) >= %.1e (min %.3g) to 0", name, int(neg.sum()), -NEGATIVE_NOISE_KG_M3, vmin)
    return np.where(neg, 0.0, values)


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
    if not isinstance(ds, xr.Dataset):
        raise SwimInputError(f"scene must be an xarray.Dataset; got {type(ds).__name__}")
    if "time" in ds.dims and ds.sizes["time"] == 1:
        ds = ds.squeeze("time")
    missing = [name for name in ("height", "lat", "lon", "terrain_height") if name not in ds.variables]
    if missing:
        raise SwimInputError(
            f"scene lacks required variable(s) {missing}: needs height(z,y,x) [m above sea level], lat(y,x) "
            "[degrees_north], lon(y,x) [degrees_east] and terrain_height(y,x) [m]"
        )
    unknown = [str(n) for n in ds.data_vars if n not in _CANONICAL_VARIABLES]
    unknown += [str(n) for n in ds.coords if n not in _CANONICAL_VARIABLES + ("x", "y", "z", "wavelength", "time")]
    if unknown:
        logger.warning("validate_scene: dropping variable(s) that are not part of the canonical scene: %s", unknown)

    out: dict[str, xr.DataArray] = {}

    # ---- geometry
    height_da = _check_dims("height", _as_dataarray("height", ds), _3D)
    _check_units("height", height_da)
    nz, ny, nx = height_da.shape
    if min(nz, ny, nx) < 1:
        raise SwimInputError(f"scene grid is empty: (z, y, x) = {(nz, ny, nx)}")
    height, stats = _copied_and_scanned(height_da.values)
    _finite_or_raise("height", height, stats["not finite"])
    if stats["max"] > 100_000.0:
        raise SwimInputError(f"height: max {stats['max']:.4g} m is above 100 km; expected metres above sea level")
    if stats["max"] <= 25.0:
        raise SwimInputError(
            f"height: max {stats['max']:.4g} m; a scene only 25 m deep is implausible: expected metres above sea "
            "level, not km"
        )
    if nz > 1:
        from .scan_cpu import flag_non_increasing

        bad_cols = np.zeros((ny, nx), bool)
        in_blocks(lambda j0, j1: flag_non_increasing(height, j0, j1, bad_cols), ny)
        if bad_cols.any():
            raise SwimInputError(
                f"height must increase strictly with z in every column; {int(bad_cols.sum())} of {ny * nx} column(s) "
                "do not (is the z axis upside down, or is it pressure?)"
            )
    out["height"] = xr.DataArray(height, dims=_3D, attrs=_new_attrs("height", height_da.attrs))

    def _horizontal(name):
        da = _check_dims(name, _as_dataarray(name, ds), _2D)
        if da.shape != (ny, nx):
            raise SwimInputError(f"scene variable '{name}' has shape {da.shape}; expected (y, x) = {(ny, nx)}")
        _check_units(name, da)
        values = np.array(da.values, dtype=float)
        _finite_or_raise(name, values)
        return da, values

    lat_da, lat = _horizontal("lat")
    lon_da, lon = _horizontal("lon")
    if lat.min() < -90.0 or lat.max() > 90.0:
        raise SwimInputError(f"lat: range [{lat.min():.4g}, {lat.max():.4g}] is outside [-90, 90] degrees_north")
    if lon.min() < -360.0 or lon.max() > 360.0:
        raise SwimInputError(f"lon: range [{lon.min():.4g}, {lon.max():.4g}] is outside [-360, 360] degrees_east")
    lon = (lon + 180.0) % 360.0 - 180.0
    out["lat"] = xr.DataArray(lat, dims=_2D, attrs=_new_attrs("lat", lat_da.attrs))
    out["lon"] = xr.DataArray(lon, dims=_2D, attrs=_new_attrs("lon", lon_da.attrs))

    terrain_da, terrain = _horizontal("terrain_height")
    if terrain.min() < TERRAIN_RANGE_M[0] or terrain.max() > TERRAIN_RANGE_M[1]:
        raise SwimInputError(
            f"terrain_height: range [{terrain.min():.4g}, {terrain.max():.4g}] m is outside "
            f"[{TERRAIN_RANGE_M[0]:g}, {TERRAIN_RANGE_M[1]:g}] m above sea level"
        )
    out["terrain_height"] = xr.DataArray(terrain, dims=_2D, attrs=_new_attrs("terrain_height", terrain_da.attrs))

    def _volume(name):
        da = _check_dims(name, _as_dataarray(name, ds), _3D)
        if da.shape != (nz, ny, nx):
            raise SwimInputError(f"scene variable '{name}' has shape {da.shape}; expected (z, y, x) = {(nz, ny, nx)}")
        _check_units(name, da)
        return (da,) + _copied_and_scanned(da.values)

    # ---- hydrometeor contents
    contents: dict[str, np.ndarray] = {}
    for species, name in zip(SPECIES, CONTENT_VARIABLES):
        if name not in ds.variables:
            continue
        da, values, stats = _volume(name)
        _finite_or_raise(name, values, stats["not finite"])
        values = _clip_noise(name, values, stats["negative"])
        vmax = max(stats["max"], 0.0) if stats["negative"] else stats["max"]  # the noise clipped to 0
        if vmax > MAX_CONTENT_KG_M3:
            raise SwimInputError(
                f"{name}: max {vmax:.4g} kg m-3 exceeds {MAX_CONTENT_KG_M3:g} kg m-3 ({MAX_CONTENT_KG_M3 * 1e3:g} g m-3), "
                "which is impossible for a cloud; the values are most likely in g m-3 or g kg-1 (or a mixing ratio) "
                "given as kg m-3. Expected kg m-3"
            )
        contents[species] = values
        out[name] = xr.DataArray(values, dims=_3D, attrs=_new_attrs(name, da.attrs))

    below = height < terrain[None]
    if below.any():
        wet_below = sum(int(np.count_nonzero(c[below] > 0)) for c in contents.values())
        if wet_below:
            logger.warning("validate_scene: %d cell(s) below the terrain hold hydrometeors (they are hidden)", wet_below)

    # ---- effective radii
    for species, name in zip(SPECIES, RADIUS_VARIABLES):
        if name not in ds.variables:
            continue
        if species not in contents:
            raise SwimInputError(f"scene has '{name}' but no '{species}_content'; give both or drop the radius")
        da, values, _ = _volume(name)
        cloudy = contents[species] > 0
        r = values[cloudy]
        bad = ~np.isfinite(r) | (r < RADIUS_RANGE_M[0]) | (r > RADIUS_RANGE_M[1])
        if bad.any():
            finite = r[np.isfinite(r)]
            rng = f"[{finite.min():.3g}, {finite.max():.3g}]" if finite.size else "[no finite value]"
            raise SwimInputError(
                f"{name}: {int(bad.sum())} value(s) where {species}_content > 0 are non-finite or outside "
                f"[{RADIUS_RANGE_M[0]:g}, {RADIUS_RANGE_M[1]:g}] m (range {rng}); expected metres (micrometres "
                "must be multiplied by 1e-6)"
            )
        values = np.where(cloudy, values, DEFAULT_EFFECTIVE_RADIUS[species])
        out[name] = xr.DataArray(values, dims=_3D, attrs=_new_attrs(name, da.attrs))

    # ---- aerosol
    if "aerosol_extinction" in ds.variables:
        name = "aerosol_extinction"
        da, values, stats = _volume(name)
        _finite_or_raise(name, values, stats["not finite"])
        values = _clip_noise(name, values, stats["negative"])
        if stats["max"] > MAX_AEROSOL_EXTINCTION_M1:
            raise SwimInputError(
                f"{name}: max {stats['max']:.4g} m-1 exceeds {MAX_AEROSOL_EXTINCTION_M1:g} m-1 (visibility < 80 m); "
                "expected m-1 at 550 nm (km-1 must be multiplied by 1e-3)"
            )
        out[name] = xr.DataArray(values, dims=_3D, attrs=_new_attrs(name, da.attrs))

    # ---- surface
    coords: dict[str, xr.DataArray] = {}
    if "surface_albedo" in ds.variables:
        out["surface_albedo"], coords["wavelength"] = _validate_albedo(_as_dataarray("surface_albedo", ds), ds, ny, nx)
    if "land_mask" in ds.variables:
        da, values = _horizontal("land_mask")
        if not np.all((values == 0) | (values == 1)):
            raise SwimInputError(
                f"land_mask: values must be 1 (land) or 0 (water); got values in [{values.min():.3g}, {values.max():.3g}]"
            )
        out["land_mask"] = xr.DataArray(values.astype(np.int8), dims=_2D, attrs=_new_attrs("land_mask", da.attrs))
    if "snow_cover" in ds.variables:
        da, values = _horizontal("snow_cover")
        if values.min() < 0.0 or values.max() > 1.0:
            hint = " (percent must be divided by 100)" if values.max() <= 100.0 and values.min() >= 0.0 else ""
            raise SwimInputError(
                f"snow_cover: range [{values.min():.4g}, {values.max():.4g}] is outside [0, 1]; expected the fraction "
                f"of the surface covered by snow or ice (units 1){hint}"
            )
        out["snow_cover"] = xr.DataArray(values, dims=_2D, attrs=_new_attrs("snow_cover", da.attrs))
    if "wind_speed_10m" in ds.variables:
        da, values = _horizontal("wind_speed_10m")
        lo, hi = WIND_SPEED_RANGE_M_S
        if values.min() < lo:
            raise SwimInputError(
                f"wind_speed_10m: {int((values < lo).sum())} negative value(s) (min {values.min():.4g}); expected the "
                f"10 m wind speed in [{lo:g}, {hi:g}] m s-1 (a speed sqrt(u10^2 + v10^2), not a wind component)"
            )
        if values.max() > hi:
            raise SwimInputError(
                f"wind_speed_10m: max {values.max():.4g} exceeds {hi:g} m s-1; expected m s-1 in [{lo:g}, {hi:g}] "
                "(km h-1 must be divided by 3.6, knots multiplied by 0.514444)"
            )
        out["wind_speed_10m"] = xr.DataArray(values, dims=_2D, attrs=_new_attrs("wind_speed_10m", da.attrs))

    # ---- attributes
    attrs = {k: v for k, v in ds.attrs.items()}
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

    # ---- coordinates x, y (optional; must agree with lat/lon) and time
    gx = gy = None
    for axis in ("x", "y"):
        if axis in ds.coords:
            c = ds.coords[axis]
            if c.dims != (axis,):
                logger.warning("validate_scene: dropping coordinate '%s' with dims %s (expected (%s,))", axis, c.dims, axis)
                continue
            _check_units(axis, c)
            if gx is None:
                gx, gy = orthographic_xy(lat, lon, attrs["reference_lat"], attrs["reference_lon"])
            values = np.array(c.values, dtype=float)
            spacing = float(np.median(np.abs(np.diff(values)))) if values.size > 1 else 1000.0
            tol = max(1.0, 0.01 * spacing)
            grid = gx if axis == "x" else gy
            along = values[None, :] if axis == "x" else values[:, None]
            err = float(np.max(np.abs(grid - along)))
            if err > tol:
                raise SwimInputError(
                    f"coordinate '{axis}' [m] disagrees with lat/lon by up to {err:.4g} m (orthographic projection about "
                    f"reference_lat/lon = {attrs['reference_lat']:.4f}, {attrs['reference_lon']:.4f}); expected "
                    f"{axis} = orthographic_xy(lat, lon) within {tol:.3g} m"
                )
            coords[axis] = xr.DataArray(values, dims=(axis,), attrs=_new_attrs(axis, c.attrs))
    if "time" in ds.variables:
        coords["time"] = _validate_time(ds["time"])

    return xr.Dataset(out, attrs=attrs).assign_coords(coords)


def _validate_albedo(da: xr.DataArray, ds: xr.Dataset, ny: int, nx: int):
    name = "surface_albedo"
    _check_units(name, da)
    wl = xr.DataArray(WAVELENGTHS_NM.copy(), dims=("wavelength",), attrs=_new_attrs("wavelength", {}))
    if set(da.dims) == set(_2D) and da.ndim == 2:
        da = da.transpose(*_2D)
        values = np.broadcast_to(np.array(da.values, dtype=float), (WAVELENGTHS_NM.size, ny, nx)).copy()
        logger.debug("surface_albedo: broadcast a (y, x) albedo to the %d wavelengths", WAVELENGTHS_NM.size)
    else:
        da = _check_dims(name, da, ("wavelength",) + _2D)
        if "wavelength" in da.coords:
            given = np.asarray(da["wavelength"].values, dtype=float)
            if "wavelength" in ds.coords and "units" in ds["wavelength"].attrs:
                _check_units("wavelength", ds["wavelength"])
            try:
                da = da.sel(wavelength=WAVELENGTHS_NM, method="nearest", tolerance=0.5)
            except KeyError as exc:
                raise SwimInputError(
                    f"surface_albedo: wavelength coordinate {given.tolist()} must hold {WAVELENGTHS_NM.tolist()} nm"
                ) from exc
        elif da.sizes["wavelength"] != WAVELENGTHS_NM.size:
            raise SwimInputError(
                f"surface_albedo: {da.sizes['wavelength']} wavelengths without a coordinate; expected "
                f"{WAVELENGTHS_NM.size} in the order {WAVELENGTHS_NM.tolist()} nm"
            )
        values = np.array(da.values, dtype=float)
    if values.shape[1:] != (ny, nx):
        raise SwimInputError(f"surface_albedo has (y, x) shape {values.shape[1:]}; expected {(ny, nx)}")
    _finite_or_raise(name, values)
    if values.min() < 0.0 or values.max() > 1.0:
        raise SwimInputError(
            f"surface_albedo: range [{values.min():.4g}, {values.max():.4g}] is outside [0, 1] (a fraction; percent "
            "must be divided by 100)"
        )
    return xr.DataArray(values, dims=("wavelength",) + _2D, attrs=_new_attrs(name, da.attrs)), wl


def _validate_time(t: xr.DataArray) -> xr.DataArray:
    values = np.asarray(t.values)
    if values.size != 1:
        raise SwimInputError(f"scene 'time' must be a single (scalar) time; got {values.size} values: select one")
    dt = to_utc_datetime64(values, "time")
    return xr.DataArray(dt, attrs={"long_name": _LONG_NAMES["time"]})


# ---------------------------------------------------------------------------------------------------------------
# construction from arrays


def _regular_axis(name: str, values) -> np.ndarray:
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
    nx, ny = xv.size, yv.size
    require_real_numbers("z", np.asarray(z).dtype)
    zv = np.asarray(z, dtype=float)
    if zv.ndim == 1:
        height = np.broadcast_to(zv[:, None, None], (zv.size, ny, nx)).copy()
    elif zv.ndim == 3 and zv.shape[1:] == (ny, nx):
        height = zv.copy()
    else:
        raise SwimInputError(f"z must have shape (nz,) or (nz, ny, nx) = (nz, {ny}, {nx}) [m above sea level]; got {zv.shape}")
    nz = height.shape[0]
    _check_horizontal_metres(xv, yv, height)

    gx, gy = np.meshgrid(xv, yv)
    r2 = gx**2 + gy**2
    if np.any(r2 >= EARTH_RADIUS_M**2):
        raise SwimInputError("x, y reach beyond the earth's limb seen from the reference point; expected metres")
    p = np.stack([gx, gy, np.sqrt(EARTH_RADIUS_M**2 - r2)], axis=-1)
    lat, lon, _ = scene_to_geodetic(p, reference_lat, reference_lon)

    def _field(name, value, shape, dims):
        raw = np.asarray(value)
        require_real_numbers(f"scene_from_arrays: {name}", raw.dtype)  # then the cast to float cannot fail
        a = raw.astype(float)
        try:
            a = np.broadcast_to(a, shape).copy()
        except ValueError as exc:
            raise SwimInputError(f"{name} must have shape {shape} {dims}; got {np.shape(value)}") from exc
        return xr.DataArray(a, dims=dims, attrs={"units": _UNITS[name], "long_name": _LONG_NAMES[name]})

    data = {
        "height": xr.DataArray(height, dims=_3D, attrs={"units": "m", "long_name": _LONG_NAMES["height"]}),
        "lat": xr.DataArray(lat, dims=_2D, attrs={"units": "degrees_north", "long_name": "latitude"}),
        "lon": xr.DataArray(lon, dims=_2D, attrs={"units": "degrees_east", "long_name": "longitude"}),
        "terrain_height": _field("terrain_height", 0.0 if terrain_height is None else terrain_height, (ny, nx), _2D),
    }
    given = {
        "cloud_liquid_content": cloud_liquid_content,
        "cloud_ice_content": cloud_ice_content,
        "rain_content": rain_content,
        "snow_content": snow_content,
        "graupel_content": graupel_content,
        "cloud_liquid_effective_radius": cloud_liquid_effective_radius,
        "cloud_ice_effective_radius": cloud_ice_effective_radius,
        "rain_effective_radius": rain_effective_radius,
        "snow_effective_radius": snow_effective_radius,
        "graupel_effective_radius": graupel_effective_radius,
        "aerosol_extinction": aerosol_extinction,
    }
    for name, value in given.items():
        if value is not None:
            if name in CONTENT_VARIABLES + ("aerosol_extinction",) and np.ndim(value) != 3:
                raise SwimInputError(f"{name} must have shape (nz, ny, nx) = {(nz, ny, nx)}; got {np.shape(value)}")
            data[name] = _field(name, value, (nz, ny, nx), _3D)
    coords = {
        "x": xr.DataArray(xv, dims=("x",), attrs={"units": "m", "long_name": _LONG_NAMES["x"]}),
        "y": xr.DataArray(yv, dims=("y",), attrs={"units": "m", "long_name": _LONG_NAMES["y"]}),
    }
    if surface_albedo is not None:
        a = np.asarray(surface_albedo, dtype=float)
        if a.ndim == 1:
            a = a[:, None, None]
        data["surface_albedo"] = _field("surface_albedo", a, (WAVELENGTHS_NM.size, ny, nx), ("wavelength",) + _2D)
        coords["wavelength"] = xr.DataArray(WAVELENGTHS_NM.copy(), dims=("wavelength",), attrs={"units": "nm"})
    if land_mask is not None:
        data["land_mask"] = _field("land_mask", land_mask, (ny, nx), _2D)
    if snow_cover is not None:
        data["snow_cover"] = _field("snow_cover", snow_cover, (ny, nx), _2D)
    if wind_speed_10m is not None:
        data["wind_speed_10m"] = _field("wind_speed_10m", wind_speed_10m, (ny, nx), _2D)
    if time is not None:
        coords["time"] = xr.DataArray(to_utc_datetime64(time))
    attrs = {"reference_lat": float(reference_lat), "reference_lon": float(reference_lon), "title": title, "source": source}
    return validate_scene(xr.Dataset(data, coords=coords, attrs=attrs))


# ---------------------------------------------------------------------------------------------------------------
# files

_NETCDF_SUFFIXES = {".nc", ".nc4", ".netcdf", ".cdf", ".h5", ".hdf5"}
_LES_SUFFIXES = {".txt", ".lwc", ".dat"}


def _is_wrf(ds: xr.Dataset) -> bool:
    title = str(ds.attrs.get("TITLE", ""))
    return ("WRF" in title.upper() and "PH" in ds.variables) or {"PH", "PHB", "Times"} <= set(ds.variables)


def _is_wps(ds: xr.Dataset) -> bool:
    """WPS geogrid (``geo_em``) or metgrid (``met_em``) output: terrain and lat/lon on the mass grid."""
    return {"HGT_M", "XLAT_M", "XLONG_M"} <= set(ds.variables)


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
    import inspect

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


def open_scene(path, lazy: bool = False, **kwargs) -> xr.Dataset:
    """Open a scene file of any supported kind and return the validated canonical scene.

    Dispatch: a netCDF file with WRF variables/attributes (``PH``, ``PHB``, ``Times`` or a WRF ``TITLE``) goes to
    :func:`swim.io.wrf.read_wrf`; a WPS ``geo_em``/``met_em`` file (``HGT_M``, ``XLAT_M``, ``XLONG_M``) to
    :func:`swim.io.wps.read_wps_geogrid` (a clear-sky scene); a netCDF file that already holds ``height``/``lat``/``lon`` is validated with
    :func:`validate_scene`; a ``.txt`` (or ``.lwc``, ``.dat``) SHDOM-style LES file goes to
    :func:`swim.io.les.read_shdom_les`. A file without a suffix (e.g. ``wrfout_d01_2005-08-28_00:00:00``), and
    a name containing "wrf" or starting with "geo_em"/"met_em", is tried as netCDF.

    Parameters
    ----------
    path : str or os.PathLike
        File to open.
    lazy : bool
        Canonical scene files only: open the fields as dask arrays and return the scene unvalidated, so that
        :func:`swim.render` crops it to what the camera can see before anything is read in full (the way to
        render CONUS-size grids in a few GB; docs/rendering.md, "Cropping big grids"). Only the names, the
        dimensions and the time are checked here; :func:`swim.render` validates the cropped scene.
    **kwargs
        Passed to the reader (``time=`` for WRF; ``time=``, ``month=``, ``albedo_band=``, ``snow_above_m=`` for
        WPS files; ``reference_lat=``, ``reference_lon=``, ``time=`` for LES).
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
    if lazy:
        return _open_scene_lazily(p, **kwargs)
    suffix = p.suffix.lower()
    if suffix in _LES_SUFFIXES:
        from .les import read_shdom_les

        _reader_options(read_shdom_les, "an SHDOM-style LES file", kwargs)
        return read_shdom_les(p, **kwargs)
    wrf_like = "wrf" in p.name.lower() or p.name.lower().startswith(("geo_em", "met_em"))
    if suffix and suffix not in _NETCDF_SUFFIXES and not suffix[1:].isdigit() and not wrf_like:
        raise SwimInputError(
            f"scene file {p.name}: unknown kind '{suffix}'; expected netCDF (.nc: WRF output or a canonical scene) or "
            "an SHDOM-style LES text file (.txt)"
        )
    from .files import open_netcdf

    with open_netcdf(p, "scene file") as ds:
        if _is_wrf(ds):
            from .wrf import read_wrf

            _reader_options(read_wrf, "a WRF file", kwargs)
            ds.load()
            return read_wrf(ds, **kwargs)
        if _is_wps(ds) and not {"height", "lat", "lon"} <= set(ds.variables):
            from .wps import read_wps_geogrid

            _reader_options(read_wps_geogrid, "a WPS file", kwargs)
            ds.load()
            return read_wps_geogrid(ds, source=str(p), **kwargs)
        if {"height", "lat", "lon"} <= set(ds.variables):
            time = _canonical_time(kwargs)
            return _canonical_scene(validate_scene(ds.load()), p, time)
    raise SwimInputError(
        f"scene file {p.name} is netCDF but neither WRF output (PH, PHB, Times), WPS geo_em/met_em output (HGT_M, "
        "XLAT_M, XLONG_M) nor a canonical scene (height, lat, lon)"
    )
