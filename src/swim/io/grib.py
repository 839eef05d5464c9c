"""Reader for NCEP GFS output in GRIB (edition 1 or 2) on a regular latitude-longitude grid.

A global file is cut to the region around the camera's place: the smallest box of grid columns that holds every
column within ``radius_deg`` (great-circle distance) of (lat, lon), taken across the 0/360 deg seam where the box
crosses it. The scene keeps the 2-D ``lat``/``lon`` of the columns (like a WRF scene, it has no ``x``/``y``
coordinates); its reference point is (lat, lon). The file's message headers are indexed once (:func:`grib_index`)
for all the groups of messages read; a message's values are decoded when the region is taken from them.
:func:`grib_reader_for` tells a GFS file from NCEP HRRR/RAP output (:mod:`swim.io.grib_ncep`) by its first
message.

Formulas:

* geometric height above sea level from geopotential height, ``z = r0 H / (r0 - H)`` with ``r0`` = 6 356 766 m
  (U.S. Standard Atmosphere 1976, NOAA-S/T 76-1562, Eq. 19 solved for z);
* saturation vapour pressure over liquid water ``e_s = 611.2 exp(17.67 T_c / (T_c + 243.5))`` [Pa]
  (Bolton 1980, Eq. 10, doi:10.1175/1520-0493(1980)108<1046:TCOEPT>2.0.CO;2), vapour pressure
  ``e = RH e_s``; virtual temperature ``T_v = T / (1 - (e / p)(1 - eps))`` (Wallace and Hobbs 2006, Eq. 3.16,
  eps = R_d / R_v); air density ``rho = p / (R_d T_v)``;
* content = ``clwmr`` x rho: GFS's condensate, like its specific humidity, is a mass per kg of moist air;
* liquid fraction of the total condensate ``alpha = ((T - 250.16) / (273.16 - 250.16))^2`` between 250.16 and
  273.16 K, 1 above and 0 below (the mixed phase of the IFS cloud scheme: ECMWF IFS Documentation Cy47r3, Part
  IV: Physical processes, Chap. 7; docs/decisions/0015-gfs-condensate-split.md).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr

from ..constants import EPSILON_WATER_VAPOUR, R_DRY_AIR
from ..errors import SwimInputError
from .scene import WIND_SPEED_RANGE_M_S, to_utc_datetime64, validate_scene

logger = logging.getLogger(__name__)

__all__ = [
    "read_gfs_grib",
    "grib_reader_for",
    "grib_index",
    "is_grib_file",
    "GRIB_SUFFIXES",
    "DEFAULT_RADIUS_DEG",
    "MAX_RADIUS_DEG",
    "geometric_height",
    "saturation_vapour_pressure_water",
    "moist_air_density",
    "liquid_fraction",
    "split_condensate",
    "region_columns",
]

#: File name suffixes of GRIB files (any file that starts with the bytes ``GRIB`` is read as GRIB too).
GRIB_SUFFIXES = {".grib", ".grib2", ".grb", ".grb2"}
#: Default radius [deg of great circle] of the region cut from a global file around the camera. A ground camera
#: sees clouds at 15 km height out to about 4 deg and the sun's rays at 1 deg elevation leave a 15 km high
#: atmosphere within 3.1 deg; the rest is context for views from above. The renderer maps grid indices to the scene
#: frame by a cubic fit: a lat-lon box of 15 deg fits it within 0.1 cell at 45 N (0.4 cell at 20 deg), 0.7 cell
#: at 60 N (3.6 cells at 20 deg), where it warns that cloud positions are approximate.
DEFAULT_RADIUS_DEG = 15.0
#: Largest radius [deg]: beyond it the orthographic scene frame squeezes the edge columns by more than cos(30 deg).
MAX_RADIUS_DEG = 30.0
#: Earth radius of the conversion between geopotential and geometric height [m] (U.S. Standard Atmosphere 1976).
GEOPOTENTIAL_EARTH_RADIUS_M = 6_356_766.0
#: Temperatures [K] below which the condensate is all ice and above which it is all liquid (IFS mixed phase).
ICE_TEMPERATURE_K = 250.16
MELTING_TEMPERATURE_K = 273.16
#: Bolton (1980) Eq. 10: e_s [Pa] = A exp(B T_c / (T_c + C)), T_c [deg C].
_BOLTON_A_PA, _BOLTON_B, _BOLTON_C_K = 611.2, 17.67, 243.5
#: Largest distance [h] between a requested time and the file's valid time.
TIME_TOLERANCE_H = 1.5

#: (typeOfLevel, shortNames) of the messages read, and the units the reader expects of each variable (cfgrib's
#: names: ``10u``/``10v`` become ``u10``/``v10``).
_ISOBARIC = "isobaricInhPa"
_UNITS = {"t": "K", "gh": "gpm", "r": "%", "clwmr": "kg kg**-1", "orog": "m", "sp": "Pa", "u10": "m s**-1",
          "v10": "m s**-1"}
_HOW_TO = ("swim.io.read_gfs_grib reads NCEP GFS pressure-level output (t, gh, clwmr and r on isobaricInhPa, orog "
           "on surface); for other model output build a canonical scene with swim.scene_from_arrays "
           "(docs/scene-format.md)")


def is_grib_file(path) -> bool:
    """True when the file ``path`` starts with the bytes ``GRIB`` (editions 1 and 2 both do), whatever its name,
    or is named as GRIB (:data:`GRIB_SUFFIXES`: a file may start with a bulletin header instead)."""
    if Path(path).suffix.lower() in GRIB_SUFFIXES:
        return True
    try:
        with open(path, "rb") as f:
            return f.read(4) == b"GRIB"
    except OSError:
        return False


_READERS = ("swim reads GRIB2 of NCEP GFS on a regular latitude-longitude grid (swim.io.read_gfs_grib), of NCEP "
            "HRRR/RAP on a Lambert conformal or NCEP rotated lat-lon grid (swim.io.grib_ncep.read_ncep_grib) and of "
            "ECMWF ERA5/IFS (swim.io.read_ecmwf); for other model output build a canonical scene with "
            "swim.scene_from_arrays (docs/scene-format.md)")
#: NCEP generating processes (ON388 Table A) read by :func:`swim.io.grib_ncep.read_ncep_grib`: 83 HRRR, 105 RAP.
NCEP_HRRR_RAP_PROCESSES = {83: "HRRR", 105: "RAP"}
#: Grids (ecCodes ``gridType``) of the NCEP regional models: HRRR/RAP Lambert conformal, RAP's rotated lat-lon.
NCEP_REGIONAL_GRIDS = {"lambert", "ncep_32769"}


def _first_message(path: Path, label: str) -> dict:
    """Centre, generating process, grid type and edition of the first GRIB message of ``path``."""
    try:
        import eccodes
    except ImportError as exc:
        raise SwimInputError(f"{label}: reading GRIB needs cfgrib and ecCodes: "
                             "pip install 'swim-imagery[grib]'") from exc
    try:
        with open(path, "rb") as f:
            h = eccodes.codes_grib_new_from_file(f, headers_only=True)
            if h is None:
                raise SwimInputError(f"{label}: holds no GRIB message; {_READERS}")
            try:
                keys = ("centre", "generatingProcessIdentifier", "gridType", "edition")
                return {k: eccodes.codes_get(h, k) if eccodes.codes_is_defined(h, k) else None for k in keys}
            finally:
                eccodes.codes_release(h)
    except (eccodes.GribInternalError, OSError) as exc:
        raise SwimInputError(f"{label}: not readable as GRIB ({exc}); {_READERS}") from exc


def grib_reader_for(path):
    """The reader of a GRIB file, chosen from its first message.

    Parameters
    ----------
    path : str or os.PathLike
        A GRIB file.

    Returns
    -------
    callable
        :func:`swim.io.grib_ncep.read_ncep_grib` for NCEP HRRR or RAP output (centre ``kwbc`` with generating
        process 83 or 105, or on a Lambert conformal or NCEP rotated lat-lon grid); :func:`swim.io.ecmwf.read_ecmwf`
        for ECMWF output (centre ``ecmf``: ERA5, IFS); :func:`read_gfs_grib` for another regular
        latitude-longitude or Gaussian grid (NCEP GFS). All take ``(path, lat=, lon=, radius_deg=, time=)``.

    Raises
    ------
    SwimInputError
        If the file is missing or not readable as GRIB, or its first message is on a grid neither reader handles
        (the message names the centre, process and grid found, and what is expected).
    """
    p = Path(path)
    label = f"GRIB file {p.name}"
    if not p.is_file():
        raise SwimInputError(f"GRIB file not found: {p}")
    first = _first_message(p, label)
    process = first["generatingProcessIdentifier"]
    if first["centre"] == "kwbc" and (process in NCEP_HRRR_RAP_PROCESSES or first["gridType"] in NCEP_REGIONAL_GRIDS):
        from .grib_ncep import read_ncep_grib

        return read_ncep_grib
    if first["centre"] == "ecmf":
        try:
            from .ecmwf import read_ecmwf
        except ImportError:
            pass
        else:
            return read_ecmwf
    if first["gridType"] in ("regular_ll", "regular_gg"):
        return read_gfs_grib
    raise SwimInputError(
        f"{label}: centre {first['centre']}, generating process {process}, grid {first['gridType']!r} (GRIB"
        f"{first['edition']}): no reader of swim handles it; {_READERS}")


def geometric_height(geopotential_height):
    """Geometric height above sea level [m] from geopotential height [gpm].

    Parameters
    ----------
    geopotential_height : array_like
        Any shape [gpm]: geopotential / 9.80665 m s-2.

    Returns
    -------
    numpy.ndarray
        Same shape [m]: ``z = r0 H / (r0 - H)``, ``r0`` = :data:`GEOPOTENTIAL_EARTH_RADIUS_M` (15.7 m above H at
        10 km).

    References
    ----------
    U.S. Standard Atmosphere, 1976, NOAA-S/T 76-1562, Washington DC, Eq. 19 (``H = r0 Z / (r0 + Z)``).
    """
    h = np.asarray(geopotential_height, dtype=float)
    return GEOPOTENTIAL_EARTH_RADIUS_M * h / (GEOPOTENTIAL_EARTH_RADIUS_M - h)


def saturation_vapour_pressure_water(temperature):
    """Saturation vapour pressure over a plane surface of liquid water [Pa].

    Parameters
    ----------
    temperature : array_like
        Any shape [K].

    Returns
    -------
    numpy.ndarray
        Same shape [Pa]; within 0.1 % of the Wexler values between -35 and 35 deg C (also used, supercooled,
        below 0 deg C).

    References
    ----------
    Bolton, D. (1980), The computation of equivalent potential temperature, Mon. Wea. Rev. 108, 1046-1053,
    Eq. 10, doi:10.1175/1520-0493(1980)108<1046:TCOEPT>2.0.CO;2.
    """
    t_c = np.asarray(temperature, dtype=float) - 273.15
    return _BOLTON_A_PA * np.exp(_BOLTON_B * t_c / (t_c + _BOLTON_C_K))


def moist_air_density(pressure, temperature, relative_humidity=None):
    """Density of moist air [kg m-3] from pressure, temperature and relative humidity (ideal gas).

    Parameters
    ----------
    pressure : array_like
        [Pa].
    temperature : array_like
        [K], broadcastable with ``pressure``.
    relative_humidity : array_like, optional
        [fraction 0-1] over liquid water; negative values are taken as 0. None: dry air (``T_v = T``).

    Returns
    -------
    numpy.ndarray
        ``rho = p / (R_d T_v)`` with ``T_v = T / (1 - (e / p)(1 - eps))``, ``e = RH e_s(T)``
        (:func:`saturation_vapour_pressure_water`), R_d = :data:`swim.constants.R_DRY_AIR`,
        eps = :data:`swim.constants.EPSILON_WATER_VAPOUR`.

    References
    ----------
    Wallace, J. M. and Hobbs, P. V. (2006), Atmospheric Science, 2nd ed., Academic Press, Sect. 3.1.1
    (virtual temperature, Eq. 3.16).
    """
    p = np.asarray(pressure, dtype=float)
    t = np.asarray(temperature, dtype=float)
    if relative_humidity is None:
        return p / (R_DRY_AIR * t)
    e = np.clip(relative_humidity, 0.0, None) * saturation_vapour_pressure_water(t)
    e = np.minimum(e, p)
    t_virtual = t / (1.0 - (e / p) * (1.0 - EPSILON_WATER_VAPOUR))
    return p / (R_DRY_AIR * t_virtual)


def liquid_fraction(temperature):
    """Liquid fraction [0-1] of a total cloud condensate at temperature ``temperature`` [K].

    ``alpha = ((T - T_ice) / (T_0 - T_ice))^2`` for T_ice = 250.16 K < T < T_0 = 273.16 K, 1 above T_0 and 0
    below T_ice.

    Parameters
    ----------
    temperature : array_like
        Any shape [K].

    Returns
    -------
    numpy.ndarray
        Same shape [-], in [0, 1].

    References
    ----------
    ECMWF (2021), IFS Documentation Cy47r3, Part IV: Physical processes, Chap. 7 (Clouds and large-scale
    precipitation), the mixed-phase partition; docs/decisions/0015-gfs-condensate-split.md.
    """
    t = np.asarray(temperature, dtype=float)
    ramp = np.clip((t - ICE_TEMPERATURE_K) / (MELTING_TEMPERATURE_K - ICE_TEMPERATURE_K), 0.0, 1.0)
    return ramp**2


def split_condensate(total, temperature):
    """Split a total cloud condensate into liquid and ice by :func:`liquid_fraction`.

    Parameters
    ----------
    total : array_like
        Total condensate, any unit (e.g. kg m-3).
    temperature : array_like
        [K], broadcastable with ``total``.

    Returns
    -------
    tuple of numpy.ndarray
        ``(liquid, ice)``, the broadcast shape, in the unit of ``total``; ``liquid + ice == total``.

    References
    ----------
    As :func:`liquid_fraction`: ECMWF IFS Documentation Cy47r3, Part IV, Chap. 7 (the mixed-phase partition);
    docs/decisions/0015-gfs-condensate-split.md.
    """
    total = np.asarray(total, dtype=float)
    liquid = total * liquid_fraction(temperature)
    return liquid, total - liquid


def region_columns(lat, lon, lat0, lon0, radius_deg, wrap=True):
    """Rows and columns of a regular lat-lon grid that bound the cap of ``radius_deg`` around (lat0, lon0).

    Parameters
    ----------
    lat : array_like
        Shape (nlat,): the grid's latitudes [deg], any order.
    lon : array_like
        Shape (nlon,): the grid's longitudes [deg], any order and range.
    lat0, lon0 : float
        Centre of the region [deg].
    radius_deg : float
        Great-circle radius of the region [deg].
    wrap : bool
        Whether the grid goes round the globe (columns are then taken across its seam).

    Returns
    -------
    rows, cols : numpy.ndarray of int
        Indices of the rows south to north and of the columns west to east; the box they span holds every
        column within ``radius_deg`` of (lat0, lon0).
    longitudes : numpy.ndarray
        Shape (ncols,): the columns' longitudes [deg] continuous across the seam (``lon0`` +- 180 deg).

    Raises
    ------
    SwimInputError
        When the cap reaches a pole (the box would be a ring of all longitudes) or holds fewer than 2 x 2
        columns.
    """
    lat, lon = np.asarray(lat, dtype=float), np.asarray(lon, dtype=float)
    if abs(lat0) + radius_deg >= 90.0:
        raise SwimInputError(
            f"the region of radius {radius_deg:g} deg around ({lat0:g}, {lon0:g}) reaches the pole, where a lat-lon "
            f"grid gives no scene; use a radius below {max(90.0 - abs(lat0), 0.0):.1f} deg (--region-radius)")
    rows = np.flatnonzero(np.abs(lat - lat0) <= radius_deg + 1e-9)
    rows = rows[np.argsort(lat[rows])]
    half_width = np.rad2deg(np.arcsin(min(1.0, np.sin(np.deg2rad(radius_deg)) / np.cos(np.deg2rad(lat0)))))
    offset = (lon - lon0 + 180.0) % 360.0 - 180.0 if wrap else lon - lon0
    cols = np.flatnonzero(np.abs(offset) <= half_width + 1e-9)
    cols = cols[np.argsort(offset[cols])]
    if rows.size < 2 or cols.size < 2:
        raise SwimInputError(
            f"the region of radius {radius_deg:g} deg around ({lat0:g}, {lon0:g}) holds {rows.size} x {cols.size} "
            "grid columns; it needs at least 2 x 2: a larger radius, or a place inside the file's grid")
    return rows, cols, lon0 + offset[cols]


def _cfgrib(label: str):
    try:
        import cfgrib
    except ImportError as exc:
        raise SwimInputError(f"{label}: reading GRIB needs cfgrib and ecCodes: "
                             "pip install 'swim-imagery[grib]'") from exc
    return cfgrib


def grib_index(path: Path, label: str):
    """One cfgrib index of the headers of every message of ``path``, read once and shared by all the groups of
    messages a reader opens (:func:`_open_messages`); no index file is written. None where this cfgrib's
    internals differ from 0.9.x: each group then indexes the file itself (the same result, slower)."""
    _cfgrib(label)
    try:
        from cfgrib import dataset as cfdataset
        from cfgrib import messages as cfmessages

        keys = cfdataset.compute_index_keys(filter_by_keys=dict.fromkeys(("typeOfLevel", "shortName", "level")))
        stream = cfmessages.FileStream(str(path))
        return cfmessages.FileIndex.from_fieldset(stream, keys, cfdataset.cfmessage.COMPUTED_KEYS)
    except (ImportError, AttributeError, TypeError) as exc:
        logger.debug("cfgrib's index API differs (%s): each group of messages indexes %s", exc, label)
        return None
    except (EOFError, OSError, ValueError, RuntimeError, KeyError) as exc:
        raise SwimInputError(f"{label}: not readable as GRIB ({exc}); {_HOW_TO}") from exc


def _from_index(index, filter_by_keys) -> xr.Dataset:
    """The lazily decoded dataset of the messages of ``index`` that match ``filter_by_keys``, as
    ``xarray.open_dataset(engine="cfgrib")`` builds it (cfgrib 0.9.x: ``open_from_index``, CF decoding)."""
    from cfgrib import dataset as cfdataset
    from cfgrib.xarray_plugin import ECCODES_LOCK, CfGribDataStore
    from xarray.backends.locks import ensure_lock

    class _IndexStore(CfGribDataStore):
        def __init__(self, ds):  # noqa: D401 (the store of an opened cfgrib dataset)
            self.lock, self.ds = ensure_lock(ECCODES_LOCK), ds

    store = _IndexStore(cfdataset.open_from_index(index.subindex(filter_by_keys)))
    variables, attributes = store.load()
    variables, attributes, coord_names = xr.conventions.decode_cf_variables(variables, attributes)
    return xr.Dataset(variables, attrs=attributes).set_coords(coord_names.intersection(variables))


def _open_messages(path: Path, type_of_level: str, short_names, label: str, index=None, **keys) -> xr.Dataset:
    """The messages of ``path`` on ``type_of_level`` with these short names (and other GRIB ``keys``), as cfgrib
    reads them, lazily: a message's values are decoded when the region is taken from them. With ``index``
    (:func:`grib_index`) the file's headers are not read again; no index file is written next to the data."""
    _cfgrib(label)
    filter_by_keys = {"typeOfLevel": type_of_level, **keys}
    if short_names is not None:
        filter_by_keys["shortName"] = list(short_names)
    try:
        if index is not None:
            try:
                return _from_index(index, filter_by_keys)
            except (ImportError, AttributeError, TypeError) as exc:
                logger.debug("cfgrib's index API differs (%s): opening %s by its name", exc, label)
        return xr.open_dataset(path, engine="cfgrib",
                               backend_kwargs={"filter_by_keys": filter_by_keys, "indexpath": ""})
    except (EOFError, OSError, ValueError, RuntimeError) as exc:
        raise SwimInputError(f"{label}: not readable as GRIB ({exc}); {_HOW_TO}") from exc


def _at_time(ds: xr.Dataset, time, label: str) -> xr.Dataset:
    """``ds`` at one valid time: the only one, the first (``time=None``) or the nearest to ``time`` (within
    :data:`TIME_TOLERANCE_H`)."""
    if "valid_time" not in ds.coords:
        return ds
    valid = ds["valid_time"]
    flat = np.asarray(valid.values).ravel()
    if time is None:
        i = 0
    else:
        want = to_utc_datetime64(time)
        i = int(np.argmin(np.abs(flat - want)))
        if abs(flat[i] - want) > np.timedelta64(int(TIME_TOLERANCE_H * 3600), "s"):
            times = ", ".join(pd.Timestamp(t).strftime("%Y-%m-%dT%H:%MZ") for t in flat)
            raise SwimInputError(f"time={time!r} is more than {TIME_TOLERANCE_H:g} h from every valid time of {label}: "
                                 f"{times}")
    if valid.ndim:
        ds = ds.isel(dict(zip(valid.dims, np.unravel_index(i, valid.shape))))
    return ds


def _check_units(ds: xr.Dataset, label: str) -> None:
    """Refuse a variable whose GRIB units are not those :data:`_UNITS` expects (a unit converted once, here)."""
    for name, da in ds.data_vars.items():
        units = da.attrs.get("units", da.attrs.get("GRIB_units"))
        if name in _UNITS and units is not None and units != _UNITS[name]:
            raise SwimInputError(f"{label}: {name} has units {units!r}; expected {_UNITS[name]!r}")


#: The groups of messages the reader uses: ``t``/``gh``, ``r`` and ``clwmr`` on pressure levels (three groups:
#: their level sets differ), ``orog``/``lsm``/``sp`` on the surface and the 10 m wind.
_GROUPS = {
    "clwmr": (_ISOBARIC, ("clwmr",), {}),
    "t_gh": (_ISOBARIC, ("t", "gh"), {}),
    "r": (_ISOBARIC, ("r",), {}),
    "surface": ("surface", ("orog", "lsm", "sp"), {}),
    "wind": ("heightAboveGround", ("10u", "10v"), {"level": 10}),
}


def _read_messages(path: Path, time, label: str, groups, index=None) -> dict[str, xr.Dataset]:
    """The datasets of the :data:`_GROUPS` named in ``groups``, each at one valid time, lazily decoded."""
    out = {}
    for key in groups:
        level_type, names, keys = _GROUPS[key]
        ds = _at_time(_open_messages(path, level_type, names, label, index=index, **keys), time, label)
        _check_units(ds, label)
        out[key] = ds
    return out


def _require(messages: dict[str, xr.Dataset], label: str) -> np.ndarray:
    """The pressure levels [hPa] of ``clwmr``, high pressure first, after checking that t, gh (and r where present)
    exist on each of them and ``orog`` on the surface; otherwise the error names what is missing."""
    needed = (("t_gh", "t", _ISOBARIC), ("t_gh", "gh", _ISOBARIC), ("clwmr", "clwmr", _ISOBARIC),
              ("surface", "orog", "surface"))
    missing = [f"{name} on {level}" for key, name, level in needed if name not in messages[key].data_vars]
    if missing:
        raise SwimInputError(f"{label} lacks {', '.join(missing)}; {_HOW_TO}")
    levels = np.sort(np.atleast_1d(messages["clwmr"][_ISOBARIC].values).astype(float))[::-1]
    if levels.size < 2:
        raise SwimInputError(f"{label}: clwmr is on {levels.size} pressure level; a scene needs at least 2")
    for key, name in (("t_gh", "t"), ("t_gh", "gh"), ("r", "r")):
        if name not in messages[key].data_vars:
            continue
        have = np.atleast_1d(messages[key][_ISOBARIC].values).astype(float)
        absent = [f"{p:g}" for p in levels if not np.any(np.isclose(have, p))]
        if absent:
            raise SwimInputError(f"{label}: {name} lacks the clwmr levels {', '.join(absent)} hPa; {_HOW_TO}")
    return levels


def _region(messages: dict[str, xr.Dataset], lat, lon, radius_deg, label: str):
    """Rows, columns and the columns' longitudes of the region (:func:`region_columns`) and its reference point:
    (lat, lon), or the centre of a regional file read whole."""
    grid = messages["clwmr"]
    lats, lons = grid["latitude"], grid["longitude"]
    if lats.ndim != 1 or lons.ndim != 1:
        raise SwimInputError(f"{label}: the grid is not a regular latitude-longitude grid "
                             f"(gridType {grid['clwmr'].attrs.get('GRIB_gridType', '?')}); {_HOW_TO}")
    lats, lons = lats.values.astype(float), lons.values.astype(float)
    spacing = abs(float(np.median(np.diff(lons)))) if lons.size > 1 else 360.0
    is_global = abs(lons.size * spacing - 360.0) < 1e-3 * spacing
    if lat is None or lon is None:
        if is_global:
            raise SwimInputError(f"{label} is global: give the camera's place, --lat/--lon (lat=/lon=), to cut "
                                 f"the region of radius {radius_deg:g} deg around it")
        from .scene import domain_centre

        rows, cols = np.argsort(lats), np.argsort(lons)
        lat0, lon0 = domain_centre(*np.meshgrid(lats, lons, indexing="ij"))
        return rows, cols, lons[cols], (lat0, lon0)
    lat0, lon0 = float(lat), float(lon)
    if not (np.isfinite(lat0) and np.isfinite(lon0) and -90.0 <= lat0 <= 90.0):
        raise SwimInputError(f"lat={lat!r}, lon={lon!r}: expected a latitude in [-90, 90] and a finite longitude [deg]")
    rows, cols, longitudes = region_columns(lats, lons, lat0, lon0, float(radius_deg), wrap=is_global)
    return rows, cols, longitudes, (lat0, (lon0 + 180.0) % 360.0 - 180.0)


def _values(ds: xr.Dataset, name: str, rows, cols, levels=None) -> np.ndarray:
    """Variable ``name`` of ``ds`` as float64 on the region's (rows, cols), at ``levels`` [hPa] (high pressure
    first) when given: shape (nz, ny, nx) or (ny, nx)."""
    da = ds[name]
    if levels is not None:
        have = np.atleast_1d(da[_ISOBARIC].values).astype(float)
        da = da.isel({_ISOBARIC: [int(np.flatnonzero(np.isclose(have, p))[0]) for p in levels]})
    # the region is taken from each message as it is decoded: a level's whole field is never kept
    values = np.asarray(da.isel({da.dims[-2]: rows, da.dims[-1]: cols}).values, dtype=float)
    if not np.all(np.isfinite(values)):
        raise SwimInputError(f"GRIB variable {name} has {int(np.sum(~np.isfinite(values)))} missing or non-finite "
                             "value(s) in the region")
    return values


def _volume(messages: dict[str, xr.Dataset], levels, rows, cols, label: str) -> dict[str, np.ndarray]:
    """Height [m] and liquid and ice content [kg m-3] (nz, ny, nx) on the clwmr levels, lowest level first."""
    t = _values(messages["t_gh"], "t", rows, cols, levels)
    height = geometric_height(_values(messages["t_gh"], "gh", rows, cols, levels))
    pressure = np.broadcast_to((levels * 100.0)[:, None, None], t.shape)
    if "r" in messages["r"].data_vars:
        humidity = _values(messages["r"], "r", rows, cols, levels) / 100.0
    else:
        humidity = None
        logger.warning("read_gfs_grib: %s has no r on pressure levels: dry air density (up to ~1.5 %% too high)",
                       label)
    rho = moist_air_density(pressure, t, humidity)
    clwmr = _values(messages["clwmr"], "clwmr", rows, cols, levels)
    if np.any(clwmr < 0):
        logger.info("read_gfs_grib: clipped %d negative clwmr value(s) (min %.3g kg kg-1) to 0",
                    int(np.sum(clwmr < 0)), clwmr.min())
        clwmr = np.clip(clwmr, 0.0, None)
    # pressure levels under the model's ground hold values extrapolated by the post-processing, not cloud
    if "sp" in messages["surface"].data_vars:
        underground = pressure > _values(messages["surface"], "sp", rows, cols)[None]
    else:
        underground = height < _values(messages["surface"], "orog", rows, cols)[None]
    liquid, ice = split_condensate(np.where(underground, 0.0, clwmr * rho), t)
    return {"height": height, "cloud_liquid_content": liquid, "cloud_ice_content": ice}


def _surface(messages: dict[str, xr.Dataset], rows, cols) -> dict[str, np.ndarray]:
    """Terrain height [m] and, where the file has them, the land mask (``lsm > 0.5``) and the 10 m wind speed
    [m s-1], clipped to the canonical range."""
    surface, wind = messages["surface"], messages["wind"]
    out = {"terrain_height": _values(surface, "orog", rows, cols)}
    if "lsm" in surface.data_vars:
        out["land_mask"] = (_values(surface, "lsm", rows, cols) > 0.5).astype(np.int8)
    if {"u10", "v10"} <= set(wind.data_vars):
        speed = np.hypot(_values(wind, "u10", rows, cols), _values(wind, "v10", rows, cols))
        out["wind_speed_10m"] = np.clip(speed, *WIND_SPEED_RANGE_M_S)
    return out


def _scene_attrs(grid: xr.Dataset, path: Path, reference, radius_deg, whole: bool) -> dict:
    """Reference point, title (model, run, lead time, valid time, region) and the GRIB provenance."""
    run = pd.Timestamp(grid["time"].values) if "time" in grid.coords else None
    valid = pd.Timestamp(grid["valid_time"].values) if "valid_time" in grid.coords else None
    edition = grid.attrs.get("GRIB_edition", "?")
    when = ""
    if run is not None and valid is not None:
        lead = (valid - run) / pd.Timedelta(hours=1)
        when = f" {run:%Y-%m-%d %H}Z +{lead:g} h, valid {valid:%Y-%m-%d %H:%M} UTC"
    region = "whole grid" if whole else f"{radius_deg:g} deg around ({reference[0]:g}, {reference[1]:g})"
    attrs = {
        "reference_lat": float(reference[0]),
        "reference_lon": float(reference[1]),
        "title": f"NCEP GFS GRIB{edition}{when}, {region}",
        "source": f"{path} read by swim.io.grib.read_gfs_grib",
        "grib_centre": str(grid.attrs.get("GRIB_centre", "unknown")),
        "grib_edition": int(edition) if str(edition).isdigit() else str(edition),
    }
    if run is not None:
        attrs["forecast_reference_time"] = run.strftime("%Y-%m-%dT%H:%M:%SZ")
    if not whole:
        attrs["grib_region_radius_deg"] = float(radius_deg)
    return attrs


def read_gfs_grib(path, lat=None, lon=None, radius_deg=DEFAULT_RADIUS_DEG, time=None) -> xr.Dataset:
    """Read NCEP GFS pressure-level output (GRIB2 on a regular lat-lon grid; GRIB1 goes through the same ecCodes
    decoding, untested) into the canonical scene.

    Parameters
    ----------
    path : str or os.PathLike
        The GRIB file. Messages used (cfgrib names; only these are read):

        * on ``isobaricInhPa``: ``t`` temperature [K], ``gh`` geopotential height [gpm], ``clwmr`` cloud mixing
          ratio [kg kg-1] (GFS's total cloud condensate, liquid and ice, per kg of moist air) and, when present,
          ``r`` relative humidity [%] (without it the air is taken as dry), on the levels of ``clwmr``;
        * on ``surface``: ``orog`` orography [m]; when present ``lsm`` land-sea mask [0-1] and ``sp`` surface
          pressure [Pa] (levels with a higher pressure lie under the model's ground: their condensate is dropped);
        * on ``heightAboveGround`` 10 m, when present: ``10u``/``10v`` (cfgrib ``u10``/``v10``) wind [m s-1].
    lat, lon : float, optional
        The camera's place [deg]: centre of the region cut from a global file and the scene's reference point.
        Needed for a global file; a regional file without them is read whole.
    radius_deg : float
        Great-circle radius [deg] of the region, in (0, :data:`MAX_RADIUS_DEG`]; default
        :data:`DEFAULT_RADIUS_DEG`. The scene holds the smallest box of grid columns that contains every column
        within it.
    time : str, datetime or numpy.datetime64, optional
        Valid time (UTC) to read: the nearest in the file within 1.5 h. None: the file's (first) valid time.

    Returns
    -------
    xarray.Dataset
        The validated canonical scene (``docs/scene-format.md``), (z, y, x) = (the ``clwmr`` levels, lowest
        first; latitude south to north; longitude west to east): ``height`` [m above sea level] from ``gh``
        (:func:`geometric_height`), ``lat``/``lon`` (y, x) [deg], ``terrain_height`` [m], ``cloud_liquid_content``
        and ``cloud_ice_content`` [kg m-3] (``clwmr`` x moist air density, :func:`moist_air_density`, split by
        :func:`liquid_fraction`; a species that is zero everywhere is left out), ``land_mask``,
        ``wind_speed_10m`` [m s-1] (clipped to [0, 75]), the scalar coordinate ``time`` (the valid time) and the
        attributes ``reference_lat``/``reference_lon``, ``title``, ``source``, ``grib_centre``, ``grib_edition``,
        ``forecast_reference_time`` and ``grib_region_radius_deg``. No surface albedo: the renderer's default
        from the land mask applies.

    Raises
    ------
    SwimInputError
        If cfgrib is not installed; the file is not readable as GRIB; ``t``, ``gh``, ``clwmr`` or ``orog`` is
        missing, or ``t``/``gh``/``r`` lacks a ``clwmr`` level (the message names them and how to build a
        canonical scene instead, :func:`swim.io.scene.scene_from_arrays`); a unit differs from the above; the
        grid is not a regular lat-lon grid; the file is global and ``lat``/``lon`` are not given; the radius is
        outside (0, 30] deg, the region reaches a pole or holds fewer than 2 x 2 columns; ``time`` is more than
        1.5 h from every valid time; or the scene fails :func:`swim.io.scene.validate_scene`.

    References
    ----------
    U.S. Standard Atmosphere, 1976, NOAA-S/T 76-1562 (geopotential height); Bolton (1980),
    doi:10.1175/1520-0493(1980)108<1046:TCOEPT>2.0.CO;2 (saturation vapour pressure); ECMWF IFS Documentation
    Cy47r3, Part IV, Chap. 7 (mixed phase); docs/decisions/0015-gfs-condensate-split.md.
    """
    p = Path(path)
    label = f"GRIB file {p.name}"
    if not p.is_file():
        raise SwimInputError(f"GRIB file not found: {p}")
    if not 0.0 < float(radius_deg) <= MAX_RADIUS_DEG:
        raise SwimInputError(f"radius_deg={radius_deg!r} (--region-radius): expected (0, {MAX_RADIUS_DEG:g}] deg; "
                             "beyond it the orthographic scene frame squeezes the region's edges")
    # the condensate first: its grid tells whether the file is global before the rest is read
    index = grib_index(p, label)
    messages = _read_messages(p, time, label, ("clwmr",), index)
    if "clwmr" not in messages["clwmr"].data_vars:
        raise SwimInputError(f"{label} lacks clwmr on {_ISOBARIC}; {_HOW_TO}")
    rows, cols, longitudes, reference = _region(messages, lat, lon, radius_deg, label)
    messages.update(_read_messages(p, time, label, ("t_gh", "r", "surface", "wind"), index))
    levels = _require(messages, label)
    lats = messages["clwmr"]["latitude"].values.astype(float)[rows]
    dims3, dims2 = ("z", "y", "x"), ("y", "x")
    fields = _volume(messages, levels, rows, cols, label)
    data = {name: xr.DataArray(values, dims=dims3) for name, values in fields.items()
            if name == "height" or np.any(values > 0)}
    data.update({name: xr.DataArray(values, dims=dims2) for name, values in _surface(messages, rows, cols).items()})
    lat2, lon2 = np.meshgrid(lats, longitudes, indexing="ij")
    data["lat"] = xr.DataArray(lat2, dims=dims2, attrs={"units": "degrees_north"})
    data["lon"] = xr.DataArray(lon2, dims=dims2, attrs={"units": "degrees_east"})
    grid = messages["clwmr"]
    coords = {"time": xr.DataArray(to_utc_datetime64(grid["valid_time"].values))} if "valid_time" in grid.coords else {}
    attrs = _scene_attrs(grid, p, reference, radius_deg, whole=lat is None or lon is None)
    logger.info("read_gfs_grib: %s: %d levels %g-%g hPa, %d x %d columns", label, levels.size, levels[0], levels[-1],
                rows.size, cols.size)
    try:
        return validate_scene(xr.Dataset(data, coords=coords, attrs=attrs))
    except SwimInputError as exc:
        raise SwimInputError(f"{label}: {exc}") from exc
