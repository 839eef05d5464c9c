"""Reader for WPS output (``geo_em`` from geogrid, ``met_em`` from metgrid) into a clear-sky canonical scene.

A WPS file describes the WRF grid and its surface but holds no clouds: the scene it gives has terrain,
lat/lon, surface albedo, land mask, snow cover and (``met_em``) the 10 m wind, and no hydrometeors. The
vertical grid is synthetic: :data:`N_LEVELS` terrain-following levels (Gal-Chen and Somerville 1975) from
the surface to :data:`LEVELS_ABOVE_TERRAIN_M` above the highest terrain, so that the scene validates and a
user can add hydrometeors or aerosol on it. Mapping of the variables (``docs/surfaces.md``):

========================  ==================================================================================
canonical                 from WPS
========================  ==================================================================================
``terrain_height``        ``HGT_M`` [m]
``lat``, ``lon``          ``XLAT_M``, ``XLONG_M`` [deg]
``land_mask``             ``LANDMASK`` (1 land, 0 water); without it ``HGT_M > 0`` (logged)
``surface_albedo``        snow-free: ``ALBEDO12M`` [%] of the month, spectrally shaped by ``LANDUSEF``/
                          ``LU_INDEX`` of the ``MMINLU`` scheme; land use alone without ``ALBEDO12M``; absent
                          (the renderer's default) without either
``snow_cover``            ``SNOW`` [kg m-2] with the Noah depletion curve, reduced with ``SNOALB`` [%] to the
                          fraction seen as snow; with ``snow_above_m`` also 1 where ``HGT_M`` exceeds it
``wind_speed_10m``        ``UU``, ``VV`` of the surface level of ``met_em`` (``num_metgrid_levels`` 0 when
                          ``PRES`` there equals ``PSFC``), destaggered
``time``                  ``Times`` (geo_em has none: ``time=`` sets it)
========================  ==================================================================================

References
----------
Gal-Chen, T., Somerville, R. C. J. (1975): On the use of a coordinate transformation for the solution of
the Navier-Stokes equations, J. Comput. Phys. 17, 209-228.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr

from ..constants import WAVELENGTHS_NM
from ..errors import SwimInputError
from .files import open_netcdf
from .scene import domain_centre, to_utc_datetime64, validate_scene
from .wrf import TIME_TOLERANCE, _field, _units, wrf_times

logger = logging.getLogger(__name__)

__all__ = ["read_wps_geogrid", "clear_sky_levels", "N_LEVELS", "LEVELS_ABOVE_TERRAIN_M", "FIRST_LAYER_M"]

#: Number of synthetic vertical levels of a WPS scene.
N_LEVELS = 20
#: Depth of the synthetic grid above the highest terrain [m].
LEVELS_ABOVE_TERRAIN_M = 12_000.0
#: Thickness of the lowest layer over sea-level terrain [m].
FIRST_LAYER_M = 100.0

_REQUIRED = ("HGT_M", "XLAT_M", "XLONG_M")


def clear_sky_levels(terrain, n_levels: int = N_LEVELS, depth_m: float = LEVELS_ABOVE_TERRAIN_M,
                     first_layer_m: float = FIRST_LAYER_M) -> np.ndarray:
    """Terrain-following heights of the mass points of a cloud-free grid.

    Interfaces ``zeta_k = dz0 (r^k - 1) / (r - 1)``, k = 0..n, stretched (ratio r) so that the top interface is
    at ``Z = max(terrain) + depth_m``; mass points midway; ``height = zeta + h (1 - zeta / Z)``
    (Gal-Chen and Somerville 1975), which is strictly increasing in every column because ``h < Z``.

    Parameters
    ----------
    terrain : array_like
        Shape (ny, nx): terrain height [m].
    n_levels : int
        Number of levels (>= 2).
    depth_m : float
        Depth of the grid above the highest terrain [m].
    first_layer_m : float
        Thickness of the lowest layer where the terrain is at sea level [m].

    Returns
    -------
    numpy.ndarray
        Shape (n_levels, ny, nx): heights above sea level [m].
    """
    from scipy.optimize import brentq

    h = np.asarray(terrain, dtype=float)
    if n_levels < 2:
        raise SwimInputError(f"n_levels={n_levels}: need at least 2 levels")
    z_top = max(float(h.max()), 0.0) + depth_m
    if first_layer_m * n_levels >= z_top:
        zeta_i = np.linspace(0.0, z_top, n_levels + 1)
    else:
        ratio = brentq(lambda r: first_layer_m * (r**n_levels - 1.0) / (r - 1.0) - z_top, 1.0 + 1e-9, 10.0)
        zeta_i = first_layer_m * (ratio ** np.arange(n_levels + 1) - 1.0) / (ratio - 1.0)
    zeta = 0.5 * (zeta_i[1:] + zeta_i[:-1])[:, None, None]
    return zeta + h[None] * (1.0 - zeta / z_top)


def _file_time(ds: xr.Dataset) -> np.datetime64 | None:
    times = wrf_times(ds)
    if times:
        return times[0]
    start = ds.attrs.get("SIMULATION_START_DATE")
    if start is not None:
        try:
            return to_utc_datetime64(str(start).replace("_", " "))
        except SwimInputError:
            return None
    return None


def _monthly_albedo(ds: xr.Dataset, month: int | None, label: str) -> tuple[np.ndarray, str]:
    """``ALBEDO12M`` of the month (1-12), or the annual mean when ``month`` is None."""
    da = ds["ALBEDO12M"]
    if "Time" in da.dims:
        da = da.isel(Time=0)
    month_dims = [d for d in da.dims if d not in ("south_north", "west_east")]
    if len(month_dims) != 1 or da.sizes[month_dims[0]] != 12:
        raise SwimInputError(f"{label}: ALBEDO12M has dims {da.dims}; expected 12 months x (south_north, west_east)")
    values = np.asarray(da.transpose(month_dims[0], "south_north", "west_east").values, dtype=float)
    if month is None:
        return values.mean(axis=0), "annual mean"
    return values[month - 1], f"month {month}"


def _surface_wind(ds: xr.Dataset, label: str) -> np.ndarray | None:
    """10 m wind speed from the surface level of met_em UU/VV, when level 0 is the surface."""
    if not {"UU", "VV", "PRES", "PSFC"} <= set(ds.variables):
        return None
    p0 = _field(ds, "PRES", 0)[0]
    psfc = _field(ds, "PSFC", 0)
    if p0.shape != psfc.shape or not np.allclose(p0, psfc, rtol=0.0, atol=1.0):
        logger.info("%s: metgrid level 0 is not the surface (PRES != PSFC): no wind_speed_10m", label)
        return None
    uu = _field(ds, "UU", 0)[0]
    vv = _field(ds, "VV", 0)[0]
    u = 0.5 * (uu[:, 1:] + uu[:, :-1])
    v = 0.5 * (vv[1:, :] + vv[:-1, :])
    if u.shape != psfc.shape or v.shape != psfc.shape:
        raise SwimInputError(f"{label}: UU/VV staggered shapes {uu.shape}/{vv.shape} do not fit the mass grid {psfc.shape}")
    if not (np.all(np.isfinite(u)) and np.all(np.isfinite(v))):
        raise SwimInputError(f"{label}: UU/VV have non-finite values on the surface level [m s-1]")
    return np.hypot(u, v)


def read_wps_geogrid(path_or_dataset, month: int | None = None, time=None, albedo_band: str = "shortwave",
                     snow_above_m: float | None = None, source: str | None = None) -> xr.Dataset:
    """Read a WPS ``geo_em`` or ``met_em`` file into a clear-sky canonical scene on the WRF grid.

    Parameters
    ----------
    path_or_dataset : str, os.PathLike or xarray.Dataset
        The netCDF file or a dataset opened from it. Needs ``HGT_M`` [m], ``XLAT_M``, ``XLONG_M`` [deg]; uses,
        when present, ``LANDMASK``, ``LU_INDEX``, ``LANDUSEF`` and the ``MMINLU`` attribute, ``ALBEDO12M`` [%],
        ``SNOALB`` [%], ``SNOW`` [kg m-2], ``UU``, ``VV``, ``PRES``, ``PSFC`` and ``Times``.
    month : int, optional
        Month (1-12) of ``ALBEDO12M``; default the month of the scene's time (``time=`` or the file's
        ``Times``), else the annual mean (logged).
    time : str, datetime or numpy.datetime64, optional
        Valid time (UTC) of the scene. When the file has a valid time it must lie within 1.5 h of it; a
        ``geo_em`` file has none and takes this one.
    albedo_band : {"shortwave", "visible"}
        ``ALBEDO12M`` is matched as the shortwave albedo of the land-use class (default) or as its visible
        mean (:func:`swim.surface.albedo.surface_from_model_fields`).
    snow_above_m : float, optional
        Terrain height [m] above which the surface is taken as snow covered (``snow_cover`` = 1), e.g. for the
        Greenland ice sheet in a ``geo_em`` file without land use. Default: no such assumption.
    source : str, optional
        Recorded in the ``source`` attribute (default the file path).

    Returns
    -------
    xarray.Dataset
        The validated canonical scene (dims z, y, x = :data:`N_LEVELS`, south_north, west_east): ``height``
        (:func:`clear_sky_levels`), ``lat``, ``lon``, ``terrain_height``, ``land_mask``, and where the file
        allows ``surface_albedo``, ``snow_cover``, ``wind_speed_10m``, ``time``; attrs ``reference_lat``/
        ``reference_lon`` (grid centre), ``title``, ``source``, ``wrf_dx``, ``wrf_dy``, ``wrf_map_proj``,
        ``landuse_scheme`` and ``albedo_source``. No hydrometeor variables (clear sky).

    Raises
    ------
    SwimInputError
        If the file is missing or unreadable, lacks ``HGT_M``/``XLAT_M``/``XLONG_M``, ``month`` is not 1-12,
        ``time`` disagrees with the file's time by more than 1.5 h, a surface field is out of range, or the scene
        fails :func:`swim.io.scene.validate_scene`.
    """
    if isinstance(path_or_dataset, xr.Dataset):
        ds = path_or_dataset
        src = source or str(ds.encoding.get("source", "xarray.Dataset"))
        label = f"WPS file {Path(source).name}" if source else "the WPS dataset"
        return _read_wps_dataset(ds, month, time, albedo_band, snow_above_m, label, src)
    p = Path(path_or_dataset)
    with open_netcdf(p, "WPS file") as ds:
        return _read_wps_dataset(ds, month, time, albedo_band, snow_above_m, f"WPS file {p.name}", source or str(p))


def _read_wps_dataset(ds: xr.Dataset, month, time, albedo_band: str, snow_above_m, label: str, source: str) -> xr.Dataset:
    """Read the WPS dataset ``ds`` into the validated clear-sky canonical scene (:func:`read_wps_geogrid`);
    ``label`` names the file in messages, ``source`` is recorded in the attributes."""
    missing = [v for v in _REQUIRED if v not in ds.variables]
    if missing:
        raise SwimInputError(f"{label} lacks WPS variable(s) {missing}; needs HGT_M [m], XLAT_M, XLONG_M [deg]")
    if month is not None and (isinstance(month, bool) or int(month) != month or not 1 <= int(month) <= 12):
        raise SwimInputError(f"month={month!r}: expected an integer 1-12 (the month of ALBEDO12M)")
    valid_time = _valid_time(ds, time, label)
    if month is None and valid_time is not None:
        month = int(pd.Timestamp(valid_time).month)

    terrain, lat, lon = _wps_grid(ds, label)
    dims2 = ("y", "x")
    data: dict[str, xr.DataArray] = {
        "height": xr.DataArray(clear_sky_levels(terrain), dims=("z", "y", "x"), attrs={"units": "m"}),
        "lat": xr.DataArray(lat, dims=dims2, attrs={"units": "degrees_north"}),
        "lon": xr.DataArray(lon, dims=dims2, attrs={"units": "degrees_east"}),
        "terrain_height": xr.DataArray(terrain, dims=dims2, attrs={"units": "m"}),
        "land_mask": xr.DataArray(_land_mask(ds, terrain, label), dims=dims2),
    }
    albedo, snow, albedo_source, scheme = _albedo_and_snow(ds, month, albedo_band, label)
    coords = {}
    if snow_above_m is not None:
        high = (terrain > float(snow_above_m)).astype(float)
        logger.info("%s: snow_cover = 1 above %g m (%d cells; snow_above_m)", label, float(snow_above_m), int(high.sum()))
        snow = high if snow is None else np.maximum(snow, high)
    if snow is not None:
        data["snow_cover"] = xr.DataArray(snow, dims=dims2)
    if albedo is not None:
        data["surface_albedo"] = xr.DataArray(albedo, dims=("wavelength",) + dims2)
        coords["wavelength"] = xr.DataArray(WAVELENGTHS_NM.copy(), dims=("wavelength",), attrs={"units": "nm"})
    else:
        logger.info("%s has neither ALBEDO12M nor land use: surface_albedo left out (the renderer's default)", label)

    wind = _surface_wind(ds, label)
    if wind is not None:
        data["wind_speed_10m"] = xr.DataArray(wind, dims=dims2)
    if valid_time is not None:
        coords["time"] = xr.DataArray(valid_time)
    attrs = _scene_attrs(ds, lat, lon, valid_time, source, albedo_source, scheme)
    scene = xr.Dataset(data, coords=coords, attrs=attrs)
    try:
        return validate_scene(scene)
    except SwimInputError as exc:
        raise SwimInputError(f"{label}: {exc}") from exc


def _valid_time(ds: xr.Dataset, time, label: str) -> np.datetime64 | None:
    """Valid time of the scene: the file's time, which a requested ``time`` must match within
    :data:`~swim.io.wrf.TIME_TOLERANCE`, else the requested time; None without either."""
    file_time = _file_time(ds)
    valid_time = file_time
    if time is not None:
        want = to_utc_datetime64(time)
        if file_time is not None and abs(want - file_time) > np.timedelta64(int(TIME_TOLERANCE.total_seconds()), "s"):
            raise SwimInputError(
                f"time={pd.Timestamp(want).strftime('%Y-%m-%dT%H:%MZ')} is more than {TIME_TOLERANCE} from {label}'s "
                f"time {pd.Timestamp(file_time).strftime('%Y-%m-%dT%H:%MZ')}"
            )
        valid_time = file_time if file_time is not None else want
    return valid_time


def _wps_grid(ds: xr.Dataset, label: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Terrain height [m], latitude and longitude [deg] of the mass grid (``HGT_M``, ``XLAT_M``, ``XLONG_M``),
    refused unless they are finite and of one (south_north, west_east) shape."""
    terrain = _field(ds, "HGT_M", 0)
    lat = _field(ds, "XLAT_M", 0)
    lon = _field(ds, "XLONG_M", 0)
    if terrain.ndim != 2 or lat.shape != terrain.shape or lon.shape != terrain.shape:
        raise SwimInputError(
            f"{label}: HGT_M {terrain.shape}, XLAT_M {lat.shape}, XLONG_M {lon.shape} must be equal (south_north, "
            "west_east)"
        )
    for name, values in (("HGT_M", terrain), ("XLAT_M", lat), ("XLONG_M", lon)):
        if not np.all(np.isfinite(values)):
            raise SwimInputError(f"{label}: {name} has {int(np.sum(~np.isfinite(values)))} non-finite value(s)")
    return terrain, lat, lon


def _land_mask(ds: xr.Dataset, terrain: np.ndarray, label: str) -> np.ndarray:
    """Land mask (int8, 1 land, 0 water) from ``LANDMASK``; without it, land where the terrain is above 0 m
    (logged)."""
    if "LANDMASK" in ds.variables:
        return (_field(ds, "LANDMASK", 0) > 0.5).astype(np.int8)
    land = (terrain > 0.0).astype(np.int8)
    logger.info("%s has no LANDMASK: land where HGT_M > 0 m (%d of %d cells)", label, int(land.sum()), land.size)
    return land


def _land_use(ds: xr.Dataset, label: str) -> tuple[str | None, np.ndarray | None, np.ndarray | None]:
    """Land-use scheme of the file (``MMINLU``) with its class fractions ``LANDUSEF`` (class, y, x) or, without
    them, the dominant class ``LU_INDEX`` (y, x): ``(scheme, lu_index, landusef)``, all None without land use."""
    from ..surface.landuse import scheme_from_attrs

    scheme = scheme_from_attrs(ds.attrs, label) if ("LU_INDEX" in ds.variables or "LANDUSEF" in ds.variables) else None
    lu = landusef = None
    if scheme is not None:
        if "LANDUSEF" in ds.variables:
            f = ds["LANDUSEF"]
            if "Time" in f.dims:
                f = f.isel(Time=0)
            class_dims = [d for d in f.dims if d not in ("south_north", "west_east")]
            landusef = np.asarray(f.transpose(*class_dims, "south_north", "west_east").values, dtype=float)
        else:
            lu = _field(ds, "LU_INDEX", 0)
    return scheme, lu, landusef


def _albedo_and_snow(ds: xr.Dataset, month, albedo_band: str, label: str):
    """Snow-free spectral surface albedo and snow cover from ``ALBEDO12M`` of ``month``, the land use, ``SNOW`` and
    ``SNOALB`` (:func:`swim.surface.albedo.surface_from_model_fields`).

    Returns
    -------
    albedo : numpy.ndarray or None
        Shape (wavelength, y, x); None without ``ALBEDO12M`` and land use.
    snow : numpy.ndarray or None
        Snow cover (y, x) [0-1]; None without ``SNOW``.
    albedo_source : str or None
        What the albedo was made from, for the ``albedo_source`` attribute.
    scheme : str or None
        The land-use scheme.
    """
    from ..surface.albedo import snow_cover_from_swe, surface_from_model_fields

    # the snow_above_m terrain rule is applied to the result, so that SNOALB does not reduce it
    snow = None
    if "SNOW" in ds.variables:
        snow = snow_cover_from_swe(np.clip(_field(ds, "SNOW", 0), 0.0, None))
    scheme, lu, landusef = _land_use(ds, label)
    broadband, albedo_source = None, None
    if "ALBEDO12M" in ds.variables:
        broadband, which = _monthly_albedo(ds, month, label)
        albedo_source = f"ALBEDO12M ({which})"
        if month is None:
            logger.info("%s: no time and no month given: using the annual mean of ALBEDO12M", label)
    snoalb = _field(ds, "SNOALB", 0) if "SNOALB" in ds.variables else None
    try:
        albedo, snow = surface_from_model_fields(
            broadband,
            lu_index=lu,
            landusef=landusef,
            scheme=scheme,
            snow_cover=snow,
            snow_broadband=snoalb,
            includes_snow=False,
            band=albedo_band,
            units=_units(ds, "ALBEDO12M") if broadband is not None else None,
            snow_units=_units(ds, "SNOALB") if snoalb is not None else None,
        )
    except SwimInputError as exc:
        raise SwimInputError(f"{label}: {exc}") from exc
    if albedo is not None:
        if albedo_source is None:
            albedo_source = "land-use class albedo"
        if scheme is not None:
            albedo_source += f", spectral shape of {'LANDUSEF' if landusef is not None else 'LU_INDEX'} ({scheme})"
    return albedo, snow, albedo_source, scheme


def _scene_attrs(ds: xr.Dataset, lat, lon, valid_time, source: str, albedo_source, scheme) -> dict:
    """Attributes of the scene: the grid centre as reference point, a title with the valid time, the source, what
    the albedo was made from, the land-use scheme and the grid spacing and map projection of the file."""
    lat0, lon0 = domain_centre(lat, lon)
    title = str(ds.attrs.get("TITLE", "WPS output")).strip()
    attrs = {
        "reference_lat": lat0,
        "reference_lon": lon0,
        "title": f"{title} (clear sky)"
        + (f", {pd.Timestamp(valid_time).strftime('%Y-%m-%d %H:%M UTC')}" if valid_time is not None else ""),
        "source": f"{source} read by swim.io.wps.read_wps_geogrid",
        "albedo_source": albedo_source or "none (renderer default)",
    }
    if scheme is not None:
        attrs["landuse_scheme"] = scheme
    for key, out in (("DX", "wrf_dx"), ("DY", "wrf_dy"), ("MAP_PROJ", "wrf_map_proj")):
        if key in ds.attrs:
            attrs[out] = ds.attrs[key].item() if hasattr(ds.attrs[key], "item") else ds.attrs[key]
    return attrs
