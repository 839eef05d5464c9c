"""Reader for WRF (ARW) output (``wrfout``) files into the canonical scene.

Formulas (WRF ARW Technical Note, Skamarock et al. 2019, NCAR/TN-556+STR, Sects. 2.1 and 5; the same as
wrf-python's ``getvar('z')``, ``getvar('tk')`` and ``getvar('rho')``):

* geopotential height of the w-levels ``z_w = (PH + PHB) / g``; mass-level height
  ``z = (z_w[k] + z_w[k+1]) / 2`` (destaggered along ``bottom_top_stag``);
* pressure ``p = P + PB`` [Pa]; potential temperature ``theta = T + 300`` [K];
  temperature ``T = theta (p / 1e5) ** 0.2857``; virtual temperature ``T_v = T (1 + 0.608 q_v)``
  (``QVAPOR``; ``T_v = T`` without it);
* air density ``rho = p / (R_d T_v)`` [kg m-3]; mass content = mixing ratio [kg kg-1] x ``rho``.

``P_TOP``, ``ZNU`` and ``ZNW`` are not needed (the Katrina sample file lacks them).
"""

from __future__ import annotations

import logging
import re
from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr

from ..constants import (
    DEFAULT_EFFECTIVE_RADIUS,
    KAPPA_DRY_AIR,
    P0_POTENTIAL_TEMPERATURE,
    R_DRY_AIR,
    STANDARD_GRAVITY,
    WAVELENGTHS_NM,
)
from ..errors import SwimInputError
from .files import open_netcdf
from .quantities import dequantified
from .scene import RADIUS_RANGE_M, domain_centre, require_real_numbers, to_utc_datetime64, validate_scene
from .wrf_postprocessed import WRF_UNITS, is_xwrf_dataset, raw_wrf_layout

logger = logging.getLogger(__name__)

__all__ = ["read_wrf", "wrf_times", "wrf_surface_fields", "WRF_SPECIES", "WRF_RADII", "TIME_TOLERANCE"]

#: WRF mixing-ratio variable [kg kg-1] for each canonical species.
WRF_SPECIES = {
    "cloud_liquid": "QCLOUD",
    "cloud_ice": "QICE",
    "rain": "QRAIN",
    "snow": "QSNOW",
    "graupel": "QGRAUP",
}
#: WRF effective-radius variable for each species that WRF outputs one for.
WRF_RADII = {"cloud_liquid": "RE_CLOUD", "cloud_ice": "RE_ICE", "snow": "RE_SNOW"}
#: Largest allowed distance between the requested time and the nearest time in the file.
TIME_TOLERANCE = pd.Timedelta(hours=1.5)
#: Base-state potential temperature of WRF's perturbation ``T`` [K].
WRF_THETA_BASE = 300.0
#: Virtual-temperature coefficient (1/epsilon - 1) [-].
VIRTUAL_COEFF = 0.608

_REQUIRED = ("PH", "PHB", "P", "PB", "T", "HGT", "XLAT", "XLONG")
_MICRO = {"um", "µm", "μm", "micron", "microns", "micrometer", "micrometers", "micrometre", "micrometres"}


def _decode_time_string(value) -> np.datetime64 | None:
    if isinstance(value, np.ndarray):
        value = b"".join(np.atleast_1d(value).astype("S1").ravel()) if value.dtype.kind == "S" else str(value)
    if isinstance(value, bytes):
        value = value.decode("ascii", "replace")
    s = str(value).strip().replace("_", " ")
    if not s:
        return None
    try:
        return to_utc_datetime64(s)
    except SwimInputError:
        return None


def wrf_times(ds: xr.Dataset) -> list[np.datetime64] | None:
    """Valid times (UTC) of a WRF dataset, one per ``Time`` index.

    Taken from ``Times`` ('YYYY-MM-DD_HH:MM:SS'); else from ``XTIME`` (decoded datetimes, or minutes since the
    date in its ``description``/``units``, or since the ``SIMULATION_START_DATE`` attribute).

    Parameters
    ----------
    ds : xarray.Dataset
        WRF output.

    Returns
    -------
    list of numpy.datetime64 or None
        None if the file has no usable time information.
    """
    if "Times" in ds.variables:
        t = ds["Times"]
        values = t.values
        if values.dtype.kind == "S" and values.dtype.itemsize == 1 and values.ndim == 2:
            strings = [b"".join(row) for row in values]
        else:
            strings = list(np.atleast_1d(values))
        decoded = [_decode_time_string(s) for s in strings]
        if decoded and all(d is not None for d in decoded):
            return decoded
    if "XTIME" in ds.variables:
        xt = ds["XTIME"]
        values = np.atleast_1d(xt.values)
        if values.dtype.kind == "M":
            return [np.datetime64(v, "ns") for v in values]
        text = f"{xt.attrs.get('units', '')} {xt.attrs.get('description', '')}"
        m = re.search(r"minutes since (\d{4}-\d\d-\d\d[ _T]\d\d:\d\d(:\d\d)?)", text)
        start = _decode_time_string(m.group(1)) if m else None
        if start is None and "simulation start" in text and "SIMULATION_START_DATE" in ds.attrs:
            start = _decode_time_string(ds.attrs["SIMULATION_START_DATE"])
        if start is not None:
            return [start + np.timedelta64(int(round(float(v) * 60.0)), "s") for v in values]
    return None


def _select_time(ds: xr.Dataset, time, label: str) -> tuple[int, np.datetime64 | None]:
    """Index along ``Time`` and its valid time for the requested ``time``."""
    n = ds.sizes.get("Time", 1)
    times = wrf_times(ds)
    if times is not None and len(times) != n:
        times = None
    if time is None:
        return 0, (times[0] if times else None)
    if isinstance(time, (int, np.integer)) and not isinstance(time, bool):
        if not -n <= int(time) < n:
            raise SwimInputError(f"time index {time} is out of range for {label} with {n} time(s)")
        i = int(time) % n
        return i, (times[i] if times else None)
    if times is None:
        raise SwimInputError(f"time={time!r} requested but {label} has no Times/XTIME to select from")
    want = to_utc_datetime64(time)
    diffs = np.array([abs((t - want) / np.timedelta64(1, "s")) for t in times])
    i = int(np.argmin(diffs))
    if diffs[i] > TIME_TOLERANCE.total_seconds():
        available = ", ".join(pd.Timestamp(t).strftime("%Y-%m-%dT%H:%MZ") for t in times)
        raise SwimInputError(
            f"time={pd.Timestamp(want).strftime('%Y-%m-%dT%H:%MZ')} is more than {TIME_TOLERANCE} from every time in "
            f"{label}; available times (UTC): {available}"
        )
    if diffs[i] > 0:
        logger.info("read_wrf: using %s, the nearest time to %s", pd.Timestamp(times[i]), pd.Timestamp(want))
    return i, times[i]


def _field(ds: xr.Dataset, name: str, itime: int) -> np.ndarray:
    da = ds[name]
    require_real_numbers(f"WRF variable {name}", da.dtype)
    if "Time" in da.dims:
        da = da.isel(Time=itime)
    return np.asarray(da.values, dtype=float)


def _radius_to_metres(ds: xr.Dataset, name: str, values: np.ndarray) -> np.ndarray:
    units = str(ds[name].attrs.get("units", "")).strip()
    u = units.lower().replace(" ", "")
    if u in ("m", "meter", "meters", "metre", "metres"):
        return values
    if u in _MICRO:
        return values * 1e-6
    if u == "":
        vmax = float(np.nanmax(values)) if values.size else 0.0
        if vmax > 0.1:
            logger.warning("%s has no units and values up to %.3g: assuming micrometres", name, vmax)
            return values * 1e-6
        logger.warning("%s has no units: assuming metres", name)
        return values
    raise SwimInputError(f"WRF variable {name} has units '{units}'; expected m (or um) for an effective radius")


def _units(ds: xr.Dataset, name: str):
    units = ds[name].attrs.get("units")
    return None if units is None else str(units)


def wrf_surface_fields(ds: xr.Dataset, itime: int, label: str, albedo_band: str = "shortwave") -> dict[str, np.ndarray]:
    """Surface fields of the canonical scene from WRF output: snow-free spectral albedo, snow cover, 10 m wind.

    * ``surface_albedo`` (3, ny, nx), snow-free: ``ALBBCK`` (the background albedo), else ``ALBEDO`` with the
      snow taken out (``(ALBEDO - f A_snow) / (1 - f)``), given the spectral shape of the ``LU_INDEX`` class of
      the ``MMINLU`` scheme (:func:`swim.surface.albedo.surface_from_model_fields`). Without
      ``LU_INDEX``/``MMINLU`` the broadband albedo is used at all three wavelengths. Left out without
      ``ALBBCK``/``ALBEDO``.
    * ``snow_cover`` [0-1]: ``SNOWC``, else the Noah depletion curve of ``SNOW`` [kg m-2]
      (:func:`swim.surface.albedo.snow_cover_from_swe`); over sea ice the larger of that and ``SEAICE``; with
      ``SNOALB`` reduced to the fraction that appears as snow (:func:`swim.surface.albedo.effective_snow_cover`).
      Left out when the file has neither ``SNOWC`` nor ``SNOW`` nor sea ice.
    * ``wind_speed_10m`` [m s-1]: ``hypot(U10, V10)`` (grid-relative components; the speed does not depend on
      the rotation).

    Parameters
    ----------
    ds : xarray.Dataset
        WRF output.
    itime : int
        Index along ``Time``.
    label : str
        Used in messages.
    albedo_band : {"shortwave", "visible"}
        What the broadband albedo is a mean over (see :func:`swim.surface.albedo.surface_from_model_fields`).

    Returns
    -------
    dict
        Name -> numpy array, for the variables that could be built.

    Raises
    ------
    SwimInputError
        On non-finite or out-of-range albedos, fractions or winds, or bad class numbers.
    """
    from ..surface.albedo import snow_cover_from_swe, surface_from_model_fields
    from ..surface.landuse import scheme_from_attrs

    out: dict[str, np.ndarray] = {}
    snow = None
    if "SNOWC" in ds.variables:
        snow = _field(ds, "SNOWC", itime)
        if not np.all(np.isfinite(snow)):
            raise SwimInputError(f"{label}: SNOWC has non-finite values; expected a snow cover fraction in [0, 1]")
        snow = np.clip(snow, 0.0, 1.0)
    elif "SNOW" in ds.variables:
        snow = snow_cover_from_swe(np.clip(_field(ds, "SNOW", itime), 0.0, None))
    if "SEAICE" in ds.variables:
        ice = np.clip(np.nan_to_num(_field(ds, "SEAICE", itime)), 0.0, 1.0)
        if np.any(ice > 0):
            snow = ice if snow is None else np.maximum(snow, ice)

    scheme = lu = None
    if "LU_INDEX" in ds.variables:
        scheme = scheme_from_attrs(ds.attrs, label)
        lu = _field(ds, "LU_INDEX", itime) if scheme is not None else None
    if "ALBBCK" in ds.variables:
        name, includes_snow = "ALBBCK", False
    elif "ALBEDO" in ds.variables:
        name, includes_snow = "ALBEDO", True
    else:
        name, includes_snow = None, False
    snoalb = _field(ds, "SNOALB", itime) if "SNOALB" in ds.variables else None
    try:
        albedo, snow = surface_from_model_fields(
            None if name is None else _field(ds, name, itime),
            lu_index=lu,
            scheme=scheme,
            snow_cover=snow,
            snow_broadband=snoalb,
            includes_snow=includes_snow,
            band=albedo_band,
            units=None if name is None else _units(ds, name),
            snow_units=None if snoalb is None else _units(ds, "SNOALB"),
        )
    except SwimInputError as exc:
        raise SwimInputError(f"{label}: {exc}") from exc
    if name is not None and albedo is not None:
        out["surface_albedo"] = albedo
        logger.info(
            "%s: snow-free surface albedo from %s%s", label, name,
            f" shaped by LU_INDEX ({scheme})" if lu is not None else " (no land use: flat spectrum)",
        )
    if snow is not None:
        out["snow_cover"] = snow

    if "U10" in ds.variables and "V10" in ds.variables:
        u, v = _field(ds, "U10", itime), _field(ds, "V10", itime)
        if not (np.all(np.isfinite(u)) and np.all(np.isfinite(v))):
            raise SwimInputError(f"{label}: U10/V10 have non-finite values [m s-1]")
        out["wind_speed_10m"] = np.hypot(u, v)
    return out


def read_wrf(path_or_dataset, time=None, albedo_band: str = "shortwave") -> xr.Dataset:
    """Read one time of a WRF output file into the canonical scene.

    Parameters
    ----------
    path_or_dataset : str, os.PathLike or xarray.Dataset
        A ``wrfout`` netCDF file or a dataset opened from one. Needs ``PH``, ``PHB`` (bottom_top_stag)
        [m2 s-2], ``P``, ``PB`` [Pa], ``T`` (perturbation potential temperature) [K], ``HGT`` [m], ``XLAT``,
        ``XLONG`` [deg]; uses, when present, ``QVAPOR``, ``QCLOUD``, ``QICE``, ``QRAIN``, ``QSNOW``, ``QGRAUP``
        [kg kg-1], ``RE_CLOUD``, ``RE_ICE``, ``RE_SNOW`` [m], ``LANDMASK`` (or ``XLAND``), ``ALBBCK`` or
        ``ALBEDO`` [-], ``LU_INDEX`` with the ``MMINLU`` attribute, ``SNOWC`` (or ``SNOW`` [kg m-2]),
        ``SEAICE``, ``SNOALB``, ``U10``/``V10`` [m s-1], ``Times``/``XTIME``.
    time : None, int, str, datetime or numpy.datetime64, optional
        None: the first time in the file; an int: that index along ``Time``; otherwise the nearest time in
        ``Times``/``XTIME``, which must lie within 1.5 h.
    albedo_band : {"shortwave", "visible"}
        How the broadband ``ALBBCK``/``ALBEDO`` is given a spectral shape: as the class's shortwave broadband
        albedo (default; WRF's albedos are shortwave) or as its visible mean (:func:`wrf_surface_fields`).

    Returns
    -------
    xarray.Dataset
        The validated canonical scene (``docs/scene-format.md``) with dims (z, y, x) = (bottom_top,
        south_north, west_east): ``height`` [m] of the mass levels, ``lat``/``lon`` [deg] (of the selected time),
        ``terrain_height`` [m], ``<species>_content`` [kg m-3] for the species whose mixing ratio is in the file
        (absent species are zero and left out), effective radii [m] from ``RE_*``, ``land_mask``,
        ``surface_albedo`` (wavelength, y, x; snow-free), ``snow_cover``, ``wind_speed_10m``
        (:func:`wrf_surface_fields`; each left out when the file lacks its fields), the scalar coordinate ``time`` and attrs
        ``reference_lat``/``reference_lon`` (the centre of the grid, see below), ``title``, ``source``,
        ``wrf_dx``/``wrf_dy`` [m] and ``wrf_map_proj`` where the file has them.

    Raises
    ------
    SwimInputError
        If the file does not exist or cannot be opened, lacks a required variable, the requested time is more
        than 1.5 h from every time in the file (the message lists the available times), an effective radius has
        unknown units, or the scene fails :func:`swim.io.scene.validate_scene`.

    Notes
    -----
    ``reference_lat``/``reference_lon`` are the centre of the grid (:func:`swim.io.scene.domain_centre`), not
    ``CEN_LAT``/``CEN_LON``: in cropped files (both sample files) those attributes give the centre of the
    parent domain, which can lie at the edge of or outside the cropped grid. Negative mixing ratios (numerical
    noise of WRF's advection) are clipped to 0 and logged. Where a mixing ratio is positive but ``RE_*`` is not
    a radius in [1e-7, 0.1] m (WRF leaves 0 in tiny-content cells), the species default radius
    (:data:`swim.constants.DEFAULT_EFFECTIVE_RADIUS`) is used and logged.
    """
    if isinstance(path_or_dataset, xr.Dataset):
        label = "the WRF dataset"
        ds = dequantified(path_or_dataset, WRF_UNITS, label)
        if is_xwrf_dataset(ds):
            ds = raw_wrf_layout(ds)
        source = str(ds.encoding.get("source", path_or_dataset.encoding.get("source", "xarray.Dataset")))
        return _read_wrf_dataset(ds, time, label, source, albedo_band)
    p = Path(path_or_dataset)
    with open_netcdf(p, "WRF file") as ds:
        return _read_wrf_dataset(ds, time, f"WRF file {p.name}", str(p), albedo_band)


#: WRF microphysics schemes whose QCLOUD/QRAIN hold ice/snow below freezing (WSM3 "simple ice", Hong et al.
#: 2004, doi:10.1175/1520-0493(2004)132<0103:ARATIM>2.0.CO;2): the phase follows the temperature.
SIMPLE_ICE_SCHEMES = {3: "WSM3"}
FREEZING_K = 273.15


def _split_simple_ice(ds: xr.Dataset, contents: dict, temperature: np.ndarray, label: str) -> None:
    """For simple-ice schemes, move QCLOUD/QRAIN below 0 degC into cloud ice/snow (in place)."""
    scheme = SIMPLE_ICE_SCHEMES.get(int(ds.attrs.get("MP_PHYSICS", -1)))
    if scheme is None:
        return
    frozen = temperature < FREEZING_K
    for liquid, ice in (("cloud_liquid", "cloud_ice"), ("rain", "snow")):
        if liquid in contents and ice not in contents:
            contents[ice] = np.where(frozen, contents[liquid], 0.0)
            contents[liquid] = np.where(frozen, 0.0, contents[liquid])
    logger.info("read_wrf: %s uses %s simple ice: QCLOUD/QRAIN below 0 degC read as cloud ice/snow (%d cells)",
                label, scheme, int(frozen.sum()))


def _read_wrf_dataset(ds: xr.Dataset, time, label: str, source: str, albedo_band: str = "shortwave") -> xr.Dataset:
    """Read one time of the WRF dataset ``ds`` into the validated canonical scene (:func:`read_wrf`); ``label``
    names the file in messages, ``source`` is recorded in the attributes."""
    missing = [v for v in _REQUIRED if v not in ds.variables]
    if missing:
        raise SwimInputError(
            f"{label} lacks WRF variable(s) {missing}; needs PH, PHB [m2 s-2], P, PB [Pa], T [K, perturbation theta], "
            "HGT [m], XLAT, XLONG [deg]"
        )
    itime, valid_time = _select_time(ds, time, label)
    height, temperature, rho = _air_state(ds, itime, label)
    dims3 = ("z", "y", "x")
    data: dict[str, xr.DataArray] = {"height": xr.DataArray(height, dims=dims3, attrs={"units": "m"})}
    contents = _mass_contents(ds, itime, rho, height.shape, label)
    _split_simple_ice(ds, contents, temperature, label)
    # the species read from the file, then the ice a simple-ice scheme split off from them
    for species, values in contents.items():
        data[f"{species}_content"] = xr.DataArray(values, dims=dims3, attrs={"units": "kg m-3"})
    data.update(_effective_radii(ds, itime, contents))

    lat = _field(ds, "XLAT", itime)
    lon = _field(ds, "XLONG", itime)
    data["lat"] = xr.DataArray(lat, dims=("y", "x"), attrs={"units": "degrees_north"})
    data["lon"] = xr.DataArray(lon, dims=("y", "x"), attrs={"units": "degrees_east"})
    data["terrain_height"] = xr.DataArray(_field(ds, "HGT", itime), dims=("y", "x"), attrs={"units": "m"})
    surface, coords = _surface_variables(ds, itime, label, albedo_band)
    data.update(surface)
    if valid_time is not None:
        coords["time"] = xr.DataArray(valid_time)
    scene = xr.Dataset(data, coords=coords, attrs=_scene_attrs(ds, lat, lon, valid_time, itime, source))
    try:
        return validate_scene(scene)
    except SwimInputError as exc:
        raise SwimInputError(f"{label}: {exc}") from exc


def _air_state(ds: xr.Dataset, itime: int, label: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Height of the mass levels [m], temperature [K] and air density [kg m-3] at time index ``itime``, each of
    shape (bottom_top, south_north, west_east), from PH, PHB, P, PB, T and (if present) QVAPOR."""
    ph = _field(ds, "PH", itime) + _field(ds, "PHB", itime)
    z_w = ph / STANDARD_GRAVITY
    if z_w.ndim != 3:
        raise SwimInputError(
            f"{label}: PH must be (Time, bottom_top_stag, south_north, west_east); got dims {ds['PH'].dims}"
        )
    height = 0.5 * (z_w[1:] + z_w[:-1])

    p = _field(ds, "P", itime) + _field(ds, "PB", itime)
    theta = _field(ds, "T", itime) + WRF_THETA_BASE
    if p.shape != height.shape or theta.shape != height.shape:
        raise SwimInputError(
            f"{label}: P/PB/T have shape {p.shape}, destaggered PH has {height.shape}; expected equal (bottom_top, "
            "south_north, west_east)"
        )
    if np.any(p <= 0):
        raise SwimInputError(f"{label}: pressure P+PB has {int(np.sum(p <= 0))} value(s) <= 0 Pa")
    temperature = theta * (p / P0_POTENTIAL_TEMPERATURE) ** KAPPA_DRY_AIR
    if "QVAPOR" in ds.variables:
        qv = np.clip(_field(ds, "QVAPOR", itime), 0.0, None)
        t_virtual = temperature * (1.0 + VIRTUAL_COEFF * qv)
    else:
        logger.info("read_wrf: %s has no QVAPOR; using T for the virtual temperature", label)
        t_virtual = temperature
    return height, temperature, p / (R_DRY_AIR * t_virtual)


def _mass_contents(ds: xr.Dataset, itime: int, rho: np.ndarray, shape: tuple, label: str) -> dict[str, np.ndarray]:
    """Mass content [kg m-3] of each species whose mixing ratio is in ``ds``: the mixing ratio [kg kg-1], its
    negative numerical noise clipped to 0 (logged), times the air density ``rho``; ``shape`` is that of the
    mass grid."""
    contents: dict[str, np.ndarray] = {}
    missing = [var for var in WRF_SPECIES.values() if var not in ds.variables]
    if len(missing) == len(WRF_SPECIES):
        logger.warning("read_wrf: %s has none of %s: it renders as a clear sky", label, ", ".join(missing))
    elif "QCLOUD" in missing:
        logger.warning("read_wrf: %s has no QCLOUD: no cloud water (only %s)", label,
                       ", ".join(v for v in WRF_SPECIES.values() if v not in missing))
    for species, var in WRF_SPECIES.items():
        if var not in ds.variables:
            logger.debug("read_wrf: %s has no %s: %s content is zero", label, var, species)
            continue
        q = _field(ds, var, itime)
        if q.shape != shape:
            raise SwimInputError(f"{label}: {var} has shape {q.shape}; expected {shape}")
        if not np.all(np.isfinite(q)):
            raise SwimInputError(f"{label}: {var} has {int(np.sum(~np.isfinite(q)))} non-finite value(s) [kg kg-1]")
        neg = q < 0
        if neg.any():
            logger.info("read_wrf: clipped %d negative %s value(s) (min %.3g kg kg-1) to 0", int(neg.sum()), var,
                        q.min())
            q = np.where(neg, 0.0, q)
        contents[species] = q * rho
    return contents


def _effective_radii(ds: xr.Dataset, itime: int, contents: dict[str, np.ndarray]) -> dict[str, xr.DataArray]:
    """The ``<species>_effective_radius`` variables [m] from the ``RE_*`` of the species in ``contents``; where the
    content is positive and the radius is not in :data:`~swim.io.scene.RADIUS_RANGE_M`, the species default
    (logged)."""
    radii: dict[str, xr.DataArray] = {}
    for species, var in WRF_RADII.items():
        if var not in ds.variables or species not in contents:
            continue
        r = _radius_to_metres(ds, var, _field(ds, var, itime))
        cloudy = contents[species] > 0
        bad = cloudy & ~((r >= RADIUS_RANGE_M[0]) & (r <= RADIUS_RANGE_M[1]))
        if bad.any():
            logger.info(
                "read_wrf: %s outside [%g, %g] m in %d cell(s) with %s > 0: using the default %g m there",
                var, RADIUS_RANGE_M[0], RADIUS_RANGE_M[1], int(bad.sum()), WRF_SPECIES[species],
                DEFAULT_EFFECTIVE_RADIUS[species],
            )
            r = np.where(bad, DEFAULT_EFFECTIVE_RADIUS[species], r)
        radii[f"{species}_effective_radius"] = xr.DataArray(r, dims=("z", "y", "x"), attrs={"units": "m"})
    return radii


def _surface_variables(ds: xr.Dataset, itime: int, label: str, albedo_band: str) -> tuple[dict, dict]:
    """The land mask (``LANDMASK``, else ``XLAND``) and the fields of :func:`wrf_surface_fields` as scene variables,
    and the ``wavelength`` coordinate where there is an albedo."""
    dims2 = ("y", "x")
    data: dict[str, xr.DataArray] = {}
    if "LANDMASK" in ds.variables:
        data["land_mask"] = xr.DataArray((_field(ds, "LANDMASK", itime) > 0.5).astype(np.int8), dims=dims2)
    elif "XLAND" in ds.variables:
        data["land_mask"] = xr.DataArray((np.rint(_field(ds, "XLAND", itime)) == 1).astype(np.int8), dims=dims2)
    coords = {}
    surface = wrf_surface_fields(ds, itime, label, albedo_band=albedo_band)
    for name, values in surface.items():
        data[name] = xr.DataArray(values, dims=(("wavelength",) + dims2) if values.ndim == 3 else dims2)
    if "surface_albedo" in surface:
        coords["wavelength"] = xr.DataArray(WAVELENGTHS_NM.copy(), dims=("wavelength",), attrs={"units": "nm"})
    return data, coords


def _scene_attrs(ds: xr.Dataset, lat: np.ndarray, lon: np.ndarray, valid_time, itime: int, source: str) -> dict:
    """Attributes of the scene: the grid centre as reference point, a title with the valid time, the source and
    the grid spacing, map projection and microphysics scheme of the file."""
    lat0, lon0 = domain_centre(lat, lon)
    title = str(ds.attrs.get("TITLE", "WRF output")).strip()
    when = f", {pd.Timestamp(valid_time).strftime('%Y-%m-%d %H:%M UTC')}" if valid_time is not None else ""
    attrs = {
        "reference_lat": lat0,
        "reference_lon": lon0,
        "title": f"{title}" + when,
        "source": f"{source} read by swim.io.wrf.read_wrf (Time index {itime})",
    }
    for key, out in (("DX", "wrf_dx"), ("DY", "wrf_dy"), ("MAP_PROJ", "wrf_map_proj"),
                     ("MP_PHYSICS", "wrf_mp_physics")):
        if key in ds.attrs:
            attrs[out] = ds.attrs[key].item() if hasattr(ds.attrs[key], "item") else ds.attrs[key]
    return attrs
