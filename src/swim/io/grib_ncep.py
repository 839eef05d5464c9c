"""Reader for NOAA/NCEP HRRR and RAP output in GRIB2: native hybrid levels (``wrfnat``) or pressure levels
(``wrfprs``), with the explicit hydrometeors of the Thompson microphysics, and the HRRR-Smoke near-surface smoke.

The messages are found by their GRIB2 parameter numbers (discipline, category, number) and level type, read with
ecCodes one at a time: the file is scanned once for the message headers, and only the messages the scene needs are
decoded; of each, only the grid columns of the region around the camera's place are kept.

Grids: any grid ecCodes geolocates (HRRR's 3 km Lambert conformal CONUS grid, RAP's Lambert grid 130, regular
lat-lon), and the NCEP rotated latitude-longitude grid of grid definition template 3.32769 (RAP's 13 km North
American ``wrfnat`` grid), which ecCodes does not geolocate: its latitudes and longitudes are computed here
(:func:`rotated_grid_latlon`).

Formulas:

* geometric height from geopotential height (:func:`swim.io.grib.geometric_height`);
* vapour pressure from specific humidity ``e = q p / (eps + (1 - eps) q)`` or relative humidity
  ``e = RH e_s(T)`` (:func:`swim.io.grib.saturation_vapour_pressure_water`); dry-air density
  ``rho_d = (p - e) / (R_d T)`` (Dalton's law, ideal gas);
* content = mixing ratio x ``rho_d``: the HRRR/RAP hydrometeor mixing ratios (CLMR, CIMIXR, RWMR, SNMR, GRLE)
  are WRF-ARW's, mass per kg of **dry** air. NCEP's post-processor (UPP, ``INITPOST.F``, the WRF-ARW input of
  RAP and HRRR) converts WRF's water-vapour mixing ratio to specific humidity (``q = w / (1 + w)``, the SPFH
  messages) but copies ``QCLOUD``, ``QICE``, ``QRAIN``, ``QSNOW``, ``QGRAUP`` unchanged, and WRF's moisture
  variables are mixing ratios with respect to dry air (Skamarock et al. 2019, NCAR/TN-556+STR, Sect. 2.1,
  doi:10.5065/1dfh-6p97); the difference to moist air is at most a few per cent;
* smoke (HRRR-Smoke MASSDEN at 8 m above ground, kg m-3): uniform from the ground to the top of the mixed
  layer, zero above (:func:`smoke_profile`).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr

from ..constants import EPSILON_WATER_VAPOUR, R_DRY_AIR
from ..errors import SwimInputError
from .grib import (
    MAX_RADIUS_DEG,
    TIME_TOLERANCE_H,
    geometric_height,
    saturation_vapour_pressure_water,
)
from .scene import WIND_SPEED_RANGE_M_S, to_utc_datetime64, validate_scene

logger = logging.getLogger(__name__)

__all__ = [
    "read_ncep_grib",
    "hrrr_smoke_content",
    "smoke_profile",
    "rotated_grid_latlon",
    "region_box",
    "dry_air_density",
    "NCEP_DEFAULT_RADIUS_DEG",
    "DEFAULT_SMOKE_MIXING_DEPTH_M",
    "SMOKE_REFERENCE_HEIGHT_M",
]

#: Default radius [deg of great circle] of the region cut around the camera: a ground camera sees clouds at 15 km
#: height out to about 4 deg (the HRRR's 3 km grid gives some 300 x 300 columns).
NCEP_DEFAULT_RADIUS_DEG = 4.0
#: Most grid columns read without a camera's place (a whole HRRR grid is 1.9 million).
MAX_WHOLE_COLUMNS = 250_000
#: Depth [m] of the layer above the ground through which near-surface smoke is mixed where the file has no
#: boundary-layer height (HPBL): a summer-afternoon mixed layer over the continental United States is 1-2 km deep
#: (Seidel et al. 2012, doi:10.1029/2012JD018143).
DEFAULT_SMOKE_MIXING_DEPTH_M = 1500.0
#: Height [m above ground] of the HRRR-Smoke MASSDEN field.
SMOKE_REFERENCE_HEIGHT_M = 8.0

#: GRIB2 (discipline, parameterCategory, parameterNumber) of the hydrometeor mixing ratios [kg kg-1 of dry air],
#: with their NCEP names and the canonical variables they become.
SPECIES_PARAMETERS = {
    (0, 1, 22): ("CLMR", "cloud_liquid_content"),
    (0, 1, 82): ("CIMIXR", "cloud_ice_content"),
    (0, 1, 24): ("RWMR", "rain_content"),
    (0, 1, 25): ("SNMR", "snow_content"),
    (0, 1, 32): ("GRLE", "graupel_content"),
}
#: The state on the model or pressure levels: geopotential height [gpm], temperature [K], specific humidity
#: [kg kg-1], relative humidity [%], pressure [Pa] (on hybrid levels).
STATE_PARAMETERS = {(0, 3, 5): "HGT", (0, 0, 0): "TMP", (0, 1, 0): "SPFH", (0, 1, 1): "RH", (0, 3, 0): "PRES"}
#: Single-level fields: ((discipline, category, number), typeOfFirstFixedSurface, level) -> NCEP name.
SURFACE_PARAMETERS = {
    ((0, 3, 5), 1, None): "HGT_SFC",     # orography [m]
    ((2, 0, 0), 1, None): "LAND",        # land cover, 1 land 0 water
    ((0, 3, 0), 1, None): "PRES_SFC",    # surface pressure [Pa]
    ((0, 2, 2), 103, 10.0): "UGRD10",    # 10 m wind [m s-1]
    ((0, 2, 3), 103, 10.0): "VGRD10",
    ((0, 3, 196), 1, None): "HPBL",      # planetary boundary-layer height [m] (NCEP local table)
    ((0, 20, 0), 103, 8.0): "MASSDEN",   # HRRR-Smoke mass density at 8 m [kg m-3]
}
#: typeOfFirstFixedSurface of the 3-D fields: 105 hybrid (model) level, 100 isobaric surface [Pa].
HYBRID, ISOBARIC = 105, 100
_HOW_TO = ("swim.io.grib_ncep.read_ncep_grib reads NCEP HRRR/RAP GRIB2 (HGT, TMP, SPFH or RH, PRES on hybrid "
           "levels, and CLMR, CIMIXR, RWMR, SNMR, GRLE mixing ratios on hybrid or isobaric levels; HGT on the "
           "surface); for other model output build a canonical scene with swim.scene_from_arrays "
           "(docs/scene-format.md)")
#: Header keys read from every message.
_HEADER_KEYS = ("discipline", "parameterCategory", "parameterNumber", "typeOfFirstFixedSurface",
                "scaledValueOfFirstFixedSurface", "scaleFactorOfFirstFixedSurface", "validityDate", "validityTime",
                "dataDate", "dataTime", "centre", "generatingProcessIdentifier")


def _eccodes(label: str):
    try:
        import eccodes
    except ImportError as exc:
        raise SwimInputError(f"{label}: reading GRIB needs ecCodes: pip install 'swim-imagery[grib]'") from exc
    return eccodes


def _level_value(header: dict) -> float:
    """The first fixed surface's value (scaled value x 10^-scale factor): Pa, m or a level number."""
    value, factor = header["scaledValueOfFirstFixedSurface"], header["scaleFactorOfFirstFixedSurface"]
    if value is None:
        return float("nan")
    return float(value) * 10.0 ** (-(factor or 0))


def _scan(path: Path, label: str) -> list[dict]:
    """The headers of every GRIB2 message of ``path`` (:data:`_HEADER_KEYS`, ``offset`` in the file, the grid
    section's md5), without decoding any values."""
    ec = _eccodes(label)
    headers = []
    try:
        with open(path, "rb") as f:
            while True:
                h = ec.codes_grib_new_from_file(f, headers_only=True)
                if h is None:
                    break
                try:
                    if ec.codes_get(h, "edition") != 2:
                        raise SwimInputError(f"{label}: a GRIB{ec.codes_get(h, 'edition')} message; HRRR and RAP "
                                             f"output is GRIB2; {_HOW_TO}")
                    header = {k: (ec.codes_get_long(h, k) if ec.codes_is_defined(h, k) and not
                                  ec.codes_is_missing(h, k) else None) for k in _HEADER_KEYS}
                    header["offset"] = int(ec.codes_get(h, "offset"))
                    header["centre_name"] = ec.codes_get_string(h, "centre")
                    header["grid"] = ec.codes_get(h, "md5GridSection")
                finally:
                    ec.codes_release(h)
                header["parameter"] = (header["discipline"], header["parameterCategory"], header["parameterNumber"])
                header["level"] = _level_value(header)
                header["valid"] = _timestamp(header["validityDate"], header["validityTime"])
                header["run"] = _timestamp(header["dataDate"], header["dataTime"])
                headers.append(header)
    except (ec.GribInternalError, OSError) as exc:
        raise SwimInputError(f"{label}: not readable as GRIB ({exc}); {_HOW_TO}") from exc
    if not headers:
        raise SwimInputError(f"{label}: holds no GRIB message; {_HOW_TO}")
    return headers


def _timestamp(date, hhmm) -> np.datetime64:
    return np.datetime64(pd.Timestamp(f"{int(date):08d}") + pd.Timedelta(hours=int(hhmm) // 100,
                                                                        minutes=int(hhmm) % 100), "ns")


def _select_time(headers: list[dict], time, label: str) -> list[dict]:
    """The headers at one valid time: the first (``time=None``) or the nearest to ``time`` (within
    :data:`swim.io.grib.TIME_TOLERANCE_H`)."""
    valid = np.array(sorted({h["valid"] for h in headers}))
    if time is None:
        chosen = valid[0]
    else:
        want = to_utc_datetime64(time)
        chosen = valid[int(np.argmin(np.abs(valid - want)))]
        if abs(chosen - want) > np.timedelta64(int(TIME_TOLERANCE_H * 3600), "s"):
            times = ", ".join(pd.Timestamp(t).strftime("%Y-%m-%dT%H:%MZ") for t in valid)
            raise SwimInputError(f"time={time!r} is more than {TIME_TOLERANCE_H:g} h from every valid time of "
                                 f"{label}: {times}")
    return [h for h in headers if h["valid"] == chosen]


def _rotated_grid_section(message: bytes, offset: int):
    """The parameters of grid definition template 3.32769 from the raw section 3 at ``offset`` of ``message``:
    Ni, Nj, La1, Lo1, La2, Lo2, LaC, LoC [deg] and the scanning mode; GRIB2 signed integers carry the sign in
    their top bit."""
    sec = message[offset:offset + 80]

    def signed(octet):  # octets counted from 1, as in the NCEP table of the template
        v = int.from_bytes(sec[octet - 1:octet + 3], "big")
        return -(v & 0x7FFFFFFF) if v & 0x80000000 else v

    degrees = [signed(octet) * 1e-6 for octet in (47, 51, 73, 77, 56, 60)]
    return (signed(31), signed(35), *degrees, sec[71])


def _to_rotated(lat, lon, lat_centre, lon_centre):
    """Rotated latitude and longitude [deg] of (lat, lon) in the system whose equator and prime meridian cross at
    (lat_centre, lon_centre)."""
    tilt = np.deg2rad(lat_centre)
    la, lo = np.deg2rad(lat), np.deg2rad(np.asarray(lon) - lon_centre)
    x, y, z = np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)
    xr_, zr = x * np.cos(tilt) + z * np.sin(tilt), -x * np.sin(tilt) + z * np.cos(tilt)
    return np.rad2deg(np.arcsin(np.clip(zr, -1, 1))), np.rad2deg(np.arctan2(y, xr_))


def _from_rotated(phi, lam, lat_centre, lon_centre):
    """Inverse of :func:`_to_rotated`: geographic latitude and longitude [deg], longitude in [-180, 180)."""
    tilt = -np.deg2rad(lat_centre)
    phi, lam = np.deg2rad(phi), np.deg2rad(lam)
    x, y, z = np.cos(phi) * np.cos(lam), np.cos(phi) * np.sin(lam), np.sin(phi)
    xg, zg = x * np.cos(tilt) + z * np.sin(tilt), -x * np.sin(tilt) + z * np.cos(tilt)
    lon = (np.rad2deg(np.arctan2(y, xg)) + lon_centre + 180.0) % 360.0 - 180.0
    return np.rad2deg(np.arcsin(np.clip(zg, -1, 1))), lon


def rotated_grid_latlon(ni, nj, lat_first, lon_first, lat_last, lon_last, lat_centre, lon_centre):
    """Latitudes and longitudes of the NCEP rotated latitude-longitude grid (GRIB2 grid definition template
    3.32769, "Rotate Lat/Lon Non-E Staggered grid": RAP's 13 km North American grid).

    The grid is regular in a rotated latitude-longitude system whose equator and prime meridian cross at the
    centre point (``lat_centre``, ``lon_centre``): the rotated system's south pole lies at
    (``lat_centre`` - 90, ``lon_centre``). The points are spaced evenly in rotated latitude and longitude between
    the first (south-west) and the last (north-east) grid point. (On RAP's grid the two corners lie symmetric
    about the centre, as NCL and grib2io assume; the template's Di/Dj, 0.121813 deg there, is 0.02 % smaller than
    the spacing of its corners, 0.121833 deg.)

    Parameters
    ----------
    ni, nj : int
        Points along a row (west to east) and a column (south to north).
    lat_first, lon_first : float
        The first grid point [deg] (octets 47-54 of section 3).
    lat_last, lon_last : float
        The last grid point [deg] (octets 73-80).
    lat_centre, lon_centre : float
        The centre point [deg] (octets 56-63).

    Returns
    -------
    lat, lon : numpy.ndarray
        Shape (nj, ni) [deg], rows south to north, longitudes in [-180, 180).

    References
    ----------
    NCEP GRIB2 documentation, Grid Definition Template 3.32769
    (https://www.nco.ncep.noaa.gov/pmb/docs/grib2/grib2_doc/grib2_temp3-32769.shtml); the rotation is that of
    NCAR's NCL GRIB2 decoder (NclGRIB2.c) and of NOAA-MDL's grib2io (``utils/arakawa_rotated_grid.py``).
    """
    phi1, lam1 = _to_rotated(float(lat_first), float(lon_first), lat_centre, lon_centre)
    phi2, lam2 = _to_rotated(float(lat_last), float(lon_last), lat_centre, lon_centre)
    if lam2 <= lam1:
        lam2 += 360.0
    phi, lam = np.meshgrid(np.linspace(phi1, phi2, int(nj)), np.linspace(lam1, lam2, int(ni)), indexing="ij")
    return _from_rotated(phi, lam, lat_centre, lon_centre)


class _Reader:
    """Decodes chosen messages of one GRIB2 file, each cut to the region's rows and columns."""

    def __init__(self, path: Path, label: str):
        self.path, self.label, self.ec = path, label, _eccodes(label)
        self.rows = self.cols = None
        self.flip = False

    def _handle(self, header):
        with open(self.path, "rb") as f:
            f.seek(header["offset"])
            return self.ec.codes_grib_new_from_file(f)

    def grid(self, header):
        """The 2-D (lat, lon) [deg] of the message's grid, rows south to north, and the grid's description."""
        ec = self.ec
        h = self._handle(header)
        try:
            template = ec.codes_get(h, "gridDefinitionTemplateNumber")
            grid_type = ec.codes_get(h, "gridType")
            if template == 32769:
                ni, nj, la1, lo1, la2, lo2, la0, lo0, scan = _rotated_grid_section(
                    ec.codes_get_message(h), ec.codes_get(h, "offsetSection3"))
                if scan & 0b11100000 != 0b01000000:
                    raise SwimInputError(f"{self.label}: rotated grid 3.32769 with scanning mode {scan:08b}; only "
                                         "01000000 (west to east, south to north, rows consecutive) is read")
                lat, lon = rotated_grid_latlon(ni, nj, la1, lo1, la2, lo2, la0, lo0)
                description = f"NCEP rotated lat-lon (template 3.32769, centre {la0:g} N {lo0:g} E), {ni} x {nj}"
                return lat, lon, description
            if ec.codes_is_defined(h, "jPointsAreConsecutive") and ec.codes_get(h, "jPointsAreConsecutive"):
                raise SwimInputError(f"{self.label}: its grid's points run along columns (jPointsAreConsecutive); "
                                     "expected rows (NCEP's order)")
            try:
                ni, nj = ec.codes_get(h, "Ni"), ec.codes_get(h, "Nj")
                lat = np.asarray(ec.codes_get_array(h, "latitudes"), dtype=float).reshape(nj, ni)
                lon = np.asarray(ec.codes_get_array(h, "longitudes"), dtype=float).reshape(nj, ni)
            except (ec.GribInternalError, ValueError) as exc:
                raise SwimInputError(f"{self.label}: ecCodes gives no latitudes/longitudes for its grid "
                                     f"(gridType {grid_type!r}, template 3.{template}): {exc}; expected Lambert "
                                     f"conformal (3.30), lat-lon (3.0) or NCEP rotated lat-lon (3.32769)") from exc
        finally:
            ec.codes_release(h)
        self.flip = bool(np.mean(lat[0]) > np.mean(lat[-1]))
        if self.flip:
            lat, lon = lat[::-1], lon[::-1]
        return lat, (lon + 180.0) % 360.0 - 180.0, f"{grid_type} (template 3.{template}), {ni} x {nj}"

    def values(self, header) -> np.ndarray:
        """The message's values on the region, float64 (ny, nx)."""
        ec = self.ec
        h = self._handle(header)
        try:
            ni, nj = (ec.codes_get(h, "Ni"), ec.codes_get(h, "Nj"))
            values = np.asarray(ec.codes_get_values(h), dtype=float).reshape(nj, ni)
            missing = ec.codes_get(h, "missingValue") if ec.codes_get(h, "bitmapPresent") else None
        finally:
            ec.codes_release(h)
        if self.flip:
            values = values[::-1]
        values = values[self.rows, self.cols]
        if missing is not None:
            values = np.where(values == missing, np.nan, values)
        if not np.all(np.isfinite(values)):
            name = _name(header)
            raise SwimInputError(f"{self.label}: {name} has {int(np.sum(~np.isfinite(values)))} missing value(s) in "
                                 "the region")
        return values


def _name(header) -> str:
    p = header["parameter"]
    name = SPECIES_PARAMETERS.get(p, (STATE_PARAMETERS.get(p, f"parameter {p[0]}.{p[1]}.{p[2]}"),))[0]
    return f"{name} at level {header['level']:g}"


def region_box(lat, lon, lat0, lon0, radius_deg):
    """The rows and columns (slices) of the smallest index box of a 2-D grid that holds every column within
    ``radius_deg`` (great circle) of (lat0, lon0).

    Parameters
    ----------
    lat, lon : numpy.ndarray
        Shape (ny, nx): the grid's columns [deg].
    lat0, lon0 : float
        The centre [deg].
    radius_deg : float
        Great-circle radius [deg].

    Returns
    -------
    rows, cols : slice

    Raises
    ------
    SwimInputError
        When fewer than 2 x 2 columns lie within the radius (the place is outside the grid, or the radius is
        below the grid spacing).
    """
    la, la0 = np.deg2rad(lat), np.deg2rad(lat0)
    cos_d = np.sin(la) * np.sin(la0) + np.cos(la) * np.cos(la0) * np.cos(np.deg2rad(lon - lon0))
    inside = cos_d >= np.cos(np.deg2rad(radius_deg + 1e-9))
    rows, cols = np.flatnonzero(inside.any(axis=1)), np.flatnonzero(inside.any(axis=0))
    if rows.size < 2 or cols.size < 2:
        nearest = np.rad2deg(np.arccos(np.clip(cos_d.max(), -1, 1)))
        raise SwimInputError(
            f"the region of radius {radius_deg:g} deg around ({lat0:g}, {lon0:g}) holds {rows.size} x {cols.size} "
            f"grid columns (the nearest is {nearest:.2f} deg away); it needs at least 2 x 2: a place inside the "
            "file's grid, or a larger radius")
    return slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1)


def dry_air_density(pressure, temperature, specific_humidity=None, relative_humidity=None):
    """Density of the dry air [kg m-3] in moist air, ``rho_d = (p - e) / (R_d T)``.

    Parameters
    ----------
    pressure : array_like
        [Pa].
    temperature : array_like
        [K], broadcastable with ``pressure``.
    specific_humidity : array_like, optional
        [kg kg-1]: ``e = q p / (eps + (1 - eps) q)``.
    relative_humidity : array_like, optional
        [fraction 0-1] over liquid water, used without ``specific_humidity``: ``e = RH e_s(T)``
        (:func:`swim.io.grib.saturation_vapour_pressure_water`). Neither: dry air (``e = 0``).

    Returns
    -------
    numpy.ndarray
        The broadcast shape [kg m-3]; R_d = :data:`swim.constants.R_DRY_AIR`, eps =
        :data:`swim.constants.EPSILON_WATER_VAPOUR`.

    References
    ----------
    Wallace, J. M. and Hobbs, P. V. (2006), Atmospheric Science, 2nd ed., Academic Press, Sect. 3.1 (Dalton's
    law of partial pressures, Eq. 3.14 for the specific humidity).
    """
    p = np.asarray(pressure, dtype=float)
    t = np.asarray(temperature, dtype=float)
    if specific_humidity is not None:
        q = np.clip(np.asarray(specific_humidity, dtype=float), 0.0, 0.1)
        e = q * p / (EPSILON_WATER_VAPOUR + (1.0 - EPSILON_WATER_VAPOUR) * q)
    elif relative_humidity is not None:
        e = np.clip(relative_humidity, 0.0, None) * saturation_vapour_pressure_water(t)
    else:
        e = np.zeros_like(p)
    return (p - np.minimum(e, 0.5 * p)) / (R_DRY_AIR * t)


def smoke_profile(surface_mass_density, height, terrain_height, mixing_depth=DEFAULT_SMOKE_MIXING_DEPTH_M):
    """Smoke mass content on the scene's levels from its near-surface value: well mixed from the ground to the
    top of the mixed layer, zero above.

    Parameters
    ----------
    surface_mass_density : array_like
        Shape (ny, nx) [kg m-3]: HRRR-Smoke MASSDEN at 8 m above ground.
    height : array_like
        Shape (nz, ny, nx) [m above sea level]: the scene's levels.
    terrain_height : array_like
        Shape (ny, nx) [m].
    mixing_depth : float or array_like
        Depth of the mixed layer above the ground [m], scalar or (ny, nx) (the model's HPBL); at least 8 m is
        used. Default :data:`DEFAULT_SMOKE_MIXING_DEPTH_M`.

    Returns
    -------
    numpy.ndarray
        Shape (nz, ny, nx) [kg m-3]: ``MASSDEN`` where ``0 <= z - terrain <= depth``, else 0.

    Notes
    -----
    Most smoke from North American fires stays in the boundary layer: 4-12 % of the plumes seen by MISR rose
    above it (Val Martin et al. 2010, doi:10.5194/acp-10-1491-2010; Kahn et al. 2008,
    doi:10.1029/2007GL032165), and the daytime mixed layer spreads it evenly in height. The column mass is
    ``MASSDEN x depth``; lofted plumes are missed.

    References
    ----------
    Seidel, D. J. et al. (2012), Climatology of the planetary boundary layer over the continental United States
    and Europe, J. Geophys. Res. 117, D17106, doi:10.1029/2012JD018143 (the default depth).
    """
    surface = np.clip(np.asarray(surface_mass_density, dtype=float), 0.0, None)
    above = np.asarray(height, dtype=float) - np.asarray(terrain_height, dtype=float)[None]
    depth = np.maximum(np.asarray(mixing_depth, dtype=float), SMOKE_REFERENCE_HEIGHT_M)
    inside = (above >= -1.0) & (above <= depth)
    return np.where(inside, surface[None], 0.0)


def _index(headers: list[dict]):
    """The 3-D fields as {name: {type of level: {level: header}}} and the single-level ones as {name: header}."""
    volume, single = {}, {}
    for h in headers:
        p, surface = h["parameter"], h["typeOfFirstFixedSurface"]
        if surface in (HYBRID, ISOBARIC) and (p in SPECIES_PARAMETERS or p in STATE_PARAMETERS):
            name = SPECIES_PARAMETERS[p][0] if p in SPECIES_PARAMETERS else STATE_PARAMETERS[p]
            volume.setdefault(name, {}).setdefault(surface, {}).setdefault(h["level"], h)
            continue
        for (parameter, level_type, level), name in SURFACE_PARAMETERS.items():
            if p == parameter and surface == level_type and (level is None or np.isclose(h["level"], level)):
                single.setdefault(name, h)
    return volume, single


def _levels(volume: dict, label: str):
    """The level type (hybrid, else isobaric) and its levels that hold a hydrometeor, after checking that HGT, TMP
    (and PRES on hybrid levels) exist on each of them."""
    species = [s for s, _ in SPECIES_PARAMETERS.values()]
    for level_type in (HYBRID, ISOBARIC):
        levels = sorted({lev for s in species for lev in volume.get(s, {}).get(level_type, {})})
        if levels:
            break
    else:
        raise SwimInputError(f"{label} holds no hydrometeor mixing ratio (CLMR, CIMIXR, RWMR, SNMR, GRLE) on hybrid or "
                             f"isobaric levels; {_HOW_TO} (a near-surface HRRR-Smoke file is added to a scene with "
                             "swim.io.grib_ncep.hrrr_smoke_content)")
    needed = ("HGT", "TMP", "PRES") if level_type == HYBRID else ("HGT", "TMP")
    kind = "hybrid" if level_type == HYBRID else "isobaric"
    for name in needed:
        have = volume.get(name, {}).get(level_type, {})
        absent = [f"{lev:g}" for lev in levels if lev not in have]
        if absent:
            raise SwimInputError(f"{label} lacks {name} on the {kind} levels {', '.join(absent[:10])}"
                                 f"{' ...' if len(absent) > 10 else ''} (the levels of its hydrometeors); {_HOW_TO}")
    if len(levels) < 2:
        raise SwimInputError(f"{label}: hydrometeors on {len(levels)} {kind} level; a scene needs at least 2")
    return level_type, levels


def _stack(reader: _Reader, volume: dict, name: str, level_type: int, levels) -> np.ndarray | None:
    """Field ``name`` on ``levels`` (nz, ny, nx); None where the file lacks it; zeros on a level it lacks
    (hydrometeors only: :func:`_levels` has checked the state)."""
    by_level = volume.get(name, {}).get(level_type)
    if not by_level:
        return None
    layers = {lev: reader.values(by_level[lev]) for lev in levels if lev in by_level}
    shape = next(iter(layers.values())).shape
    for lev in levels:
        if lev not in layers:
            logger.info("read_ncep_grib: %s lacks %s on level %g: taken as 0", reader.label, name, lev)
    return np.stack([layers.get(lev, np.zeros(shape)) for lev in levels])


def _volume(reader: _Reader, volume: dict, single: dict, level_type: int, levels) -> dict[str, np.ndarray]:
    """Height [m] and the hydrometeor contents [kg m-3] (nz, ny, nx), lowest level first."""
    height = geometric_height(_stack(reader, volume, "HGT", level_type, levels))
    t = _stack(reader, volume, "TMP", level_type, levels)
    if level_type == HYBRID:
        pressure = _stack(reader, volume, "PRES", level_type, levels)
    else:
        pressure = np.broadcast_to(np.asarray(levels, dtype=float)[:, None, None], t.shape)
    q = _stack(reader, volume, "SPFH", level_type, levels)
    rh = _stack(reader, volume, "RH", level_type, levels) if q is None else None
    if q is None and rh is None:
        logger.warning("read_ncep_grib: %s has neither SPFH nor RH: dry air density (up to ~2 %% too high)",
                       reader.label)
    rho_dry = dry_air_density(pressure, t, q, None if rh is None else rh / 100.0)
    order = np.argsort(np.mean(height, axis=(1, 2)))
    out = {"height": height[order]}
    underground = np.zeros(t.shape, dtype=bool)
    if level_type == ISOBARIC:
        if "PRES_SFC" in single:
            underground = pressure > reader.values(single["PRES_SFC"])[None]
        else:
            underground = height < reader.values(single["HGT_SFC"])[None]
    for code, (name, canonical) in SPECIES_PARAMETERS.items():
        ratio = _stack(reader, volume, name, level_type, levels)
        if ratio is None:
            continue
        if np.any(ratio < 0):
            logger.info("read_ncep_grib: clipped %d negative %s value(s) to 0", int(np.sum(ratio < 0)), name)
        content = np.where(underground, 0.0, np.clip(ratio, 0.0, None) * rho_dry)[order]
        if np.any(content > 0):
            out[canonical] = content
    return out


def _surface(reader: _Reader, single: dict, label: str) -> dict[str, np.ndarray]:
    """Terrain height [m] and, where present, the land mask and the 10 m wind speed [m s-1]."""
    if "HGT_SFC" not in single:
        raise SwimInputError(f"{label} lacks HGT on the surface (the orography); {_HOW_TO}")
    out = {"terrain_height": reader.values(single["HGT_SFC"])}
    if "LAND" in single:
        out["land_mask"] = (reader.values(single["LAND"]) > 0.5).astype(np.int8)
    if "UGRD10" in single and "VGRD10" in single:
        speed = np.hypot(reader.values(single["UGRD10"]), reader.values(single["VGRD10"]))
        out["wind_speed_10m"] = np.clip(speed, *WIND_SPEED_RANGE_M_S)
    return out


def _region(reader: _Reader, header: dict, lat, lon, radius_deg, label: str):
    """Set the reader's rows and columns to the region (or the whole grid); return its (lat, lon) (ny, nx), the
    reference point and the grid's description."""
    grid_lat, grid_lon, description = reader.grid(header)
    if lat is None or lon is None:
        if grid_lat.size > MAX_WHOLE_COLUMNS:
            raise SwimInputError(f"{label}: its grid has {grid_lat.size} columns; give the camera's place, --lat/--lon "
                                 f"(lat=/lon=), to cut the region of radius {radius_deg:g} deg around it")
        from .scene import domain_centre

        reader.rows, reader.cols = slice(None), slice(None)
        return grid_lat, grid_lon, domain_centre(grid_lat, grid_lon), description
    lat0, lon0 = float(lat), float(lon)
    if not (np.isfinite(lat0) and np.isfinite(lon0) and -90.0 <= lat0 <= 90.0):
        raise SwimInputError(f"lat={lat!r}, lon={lon!r}: expected a latitude in [-90, 90] and a finite longitude [deg]")
    reader.rows, reader.cols = region_box(grid_lat, grid_lon, lat0, lon0, float(radius_deg))
    return (grid_lat[reader.rows, reader.cols], grid_lon[reader.rows, reader.cols],
            (lat0, (lon0 + 180.0) % 360.0 - 180.0), description)


def _model(header: dict) -> str:
    """The model's name from the generating process (NCEP ON388 Table A: 83 HRRR, 105 RAP)."""
    process = header.get("generatingProcessIdentifier")
    return {83: "NCEP HRRR", 105: "NCEP RAP"}.get(process, f"{header.get('centre')} process {process}")


def _smoke(reader: _Reader, single: dict, height, terrain, mixing_depth):
    """smoke_mass_content (nz, ny, nx) [kg m-3] from MASSDEN at 8 m (:func:`smoke_profile`), the mixed layer's
    depth from ``mixing_depth``, else the file's HPBL, else :data:`DEFAULT_SMOKE_MIXING_DEPTH_M`."""
    if mixing_depth is None:
        mixing_depth = reader.values(single["HPBL"]) if "HPBL" in single else DEFAULT_SMOKE_MIXING_DEPTH_M
    return smoke_profile(reader.values(single["MASSDEN"]), height, terrain, mixing_depth)


def _attrs(header: dict, path: Path, reference, radius_deg, whole: bool, grid: str, kind: str) -> dict:
    """Reference point, title (model, run, lead time, valid time, level type, region), provenance."""
    run, valid = pd.Timestamp(header["run"]), pd.Timestamp(header["valid"])
    lead = (valid - run) / pd.Timedelta(hours=1)
    region = "whole grid" if whole else f"{radius_deg:g} deg around ({reference[0]:g}, {reference[1]:g})"
    attrs = {
        "reference_lat": float(reference[0]),
        "reference_lon": float(reference[1]),
        "title": f"{_model(header)} GRIB2 {run:%Y-%m-%d %H}Z +{lead:g} h, valid {valid:%Y-%m-%d %H:%M} UTC, "
                 f"{kind} levels, {region}",
        "source": f"{path} read by swim.io.grib_ncep.read_ncep_grib",
        "grib_centre": str(header.get("centre_name", "unknown")),
        "grib_edition": 2,
        "grib_grid": grid,
        "forecast_reference_time": run.strftime("%Y-%m-%dT%H:%M:%SZ"),
    }
    if not whole:
        attrs["grib_region_radius_deg"] = float(radius_deg)
    return attrs


def read_ncep_grib(path, lat=None, lon=None, radius_deg=NCEP_DEFAULT_RADIUS_DEG, time=None,
                   smoke_mixing_depth=None) -> xr.Dataset:
    """Read NOAA/NCEP HRRR or RAP GRIB2 output, native (``wrfnat``) or pressure levels (``wrfprs``), into the
    canonical scene.

    Parameters
    ----------
    path : str or os.PathLike
        The GRIB2 file. Messages used (NCEP names; GRIB2 discipline.category.number; only these are decoded):

        * on hybrid levels (typeOfFirstFixedSurface 105), else on isobaric surfaces (100), on the levels that
          hold a hydrometeor: HGT (0.3.5) geopotential height [gpm], TMP (0.0.0) temperature [K], on hybrid
          levels PRES (0.3.0) pressure [Pa], and SPFH (0.1.0) specific humidity [kg kg-1] or else RH (0.1.1)
          relative humidity [%] (neither: dry air); the mixing ratios [kg kg-1 of dry air] CLMR (0.1.22) cloud
          water, CIMIXR (0.1.82) cloud ice, RWMR (0.1.24) rain, SNMR (0.1.25) snow, GRLE (0.1.32) graupel;
        * on the surface (1): HGT orography [m]; when present LAND (2.0.0) land cover [0/1], PRES (0.3.0)
          surface pressure [Pa] (isobaric levels at a higher pressure lie under the ground: no condensate there),
          HPBL (0.3.196) boundary-layer height [m];
        * at 10 m above ground: UGRD/VGRD (0.2.2/0.2.3) [m s-1]; at 8 m: MASSDEN (0.20.0) smoke [kg m-3].
    lat, lon : float, optional
        The camera's place [deg]: centre of the region and the scene's reference point. Without them a grid of
        at most 250 000 columns is read whole (reference point: its centre).
    radius_deg : float
        Great-circle radius [deg] of the region, in (0, 30]; default :data:`NCEP_DEFAULT_RADIUS_DEG`. The scene
        holds the smallest box of grid rows and columns that contains every column within it.
    time : str, datetime or numpy.datetime64, optional
        Valid time (UTC): the nearest in the file within 1.5 h. None: the file's first valid time.
    smoke_mixing_depth : float, optional
        Depth [m] of the layer that holds the smoke (:func:`smoke_profile`); None: the file's HPBL, else
        :data:`DEFAULT_SMOKE_MIXING_DEPTH_M`.

    Returns
    -------
    xarray.Dataset
        The validated canonical scene, (z, y, x) = (levels, lowest first; grid rows south to north; grid
        columns west to east): ``height`` [m above sea level] (:func:`swim.io.grib.geometric_height` of HGT),
        ``lat``/``lon`` (y, x) [deg], ``terrain_height`` [m], ``cloud_liquid_content``, ``cloud_ice_content``,
        ``rain_content``, ``snow_content``, ``graupel_content`` [kg m-3] (mixing ratio x
        :func:`dry_air_density`; a species that is zero everywhere is left out), ``smoke_mass_content``
        [kg m-3] where the file has MASSDEN (:func:`smoke_profile`), ``land_mask``, ``wind_speed_10m``
        [m s-1], the scalar coordinate ``time`` (valid time) and the attributes ``reference_lat``/
        ``reference_lon``, ``title``, ``source``, ``grib_centre``, ``grib_edition``, ``grib_grid``,
        ``forecast_reference_time``, ``grib_region_radius_deg``.

    Raises
    ------
    SwimInputError
        If ecCodes is missing; the file is not GRIB2; it holds no hydrometeor on hybrid or isobaric levels, or
        lacks HGT, TMP (PRES on hybrid levels) on their levels or the surface HGT (the message names them); the
        grid cannot be geolocated; ``lat``/``lon`` are missing for a big grid, out of range, or the region holds
        fewer than 2 x 2 columns; the radius is outside (0, 30] deg; ``time`` is more than 1.5 h from every
        valid time; a field has missing values in the region; or the scene fails
        :func:`swim.io.scene.validate_scene`.

    References
    ----------
    NCEP UPP ``INITPOST.F`` (WRF-ARW input: hydrometeor mixing ratios per kg of dry air); Skamarock et al.
    (2019), doi:10.5065/1dfh-6p97; NCEP GRIB2 Grid Definition Template 3.32769.
    """
    p = Path(path)
    label = f"GRIB file {p.name}"
    if not p.is_file():
        raise SwimInputError(f"GRIB file not found: {p}")
    if not 0.0 < float(radius_deg) <= MAX_RADIUS_DEG:
        raise SwimInputError(f"radius_deg={radius_deg!r} (--region-radius): expected (0, {MAX_RADIUS_DEG:g}] deg")
    headers = _select_time(_scan(p, label), time, label)
    volume, single = _index(headers)
    level_type, levels = _levels(volume, label)
    first = next(iter(volume["HGT"][level_type].values()))
    reader = _Reader(p, label)
    lats, lons, reference, grid = _region(reader, first, lat, lon, radius_deg, label)
    if any(h["grid"] != first["grid"] for h in headers):
        raise SwimInputError(f"{label}: its messages are on more than one grid; expected one grid")
    fields = _volume(reader, volume, single, level_type, levels)
    data = {name: xr.DataArray(values, dims=("z", "y", "x")) for name, values in fields.items()}
    surface = _surface(reader, single, label)
    data.update({name: xr.DataArray(values, dims=("y", "x")) for name, values in surface.items()})
    if "MASSDEN" in single:
        smoke = _smoke(reader, single, fields["height"], surface["terrain_height"], smoke_mixing_depth)
        data["smoke_mass_content"] = xr.DataArray(smoke, dims=("z", "y", "x"), attrs={"units": "kg m-3"})
    data["lat"] = xr.DataArray(lats, dims=("y", "x"), attrs={"units": "degrees_north"})
    data["lon"] = xr.DataArray(lons, dims=("y", "x"), attrs={"units": "degrees_east"})
    kind = "hybrid" if level_type == HYBRID else "isobaric"
    attrs = _attrs(first, p, reference, radius_deg, lat is None or lon is None, grid, kind)
    logger.info("read_ncep_grib: %s: %d %s levels, %d x %d columns of %s", label, len(levels), kind,
                lats.shape[0], lats.shape[1], grid)
    try:
        return validate_scene(xr.Dataset(data, coords={"time": xr.DataArray(first["valid"])}, attrs=attrs))
    except SwimInputError as exc:
        raise SwimInputError(f"{label}: {exc}") from exc


def hrrr_smoke_content(path, lat, lon, height, terrain_height, mixing_depth=DEFAULT_SMOKE_MIXING_DEPTH_M,
                       time=None) -> np.ndarray:
    """Smoke mass content [kg m-3] on a scene's columns from an HRRR-Smoke GRIB2 file (MASSDEN at 8 m above
    ground), spread over the mixed layer (:func:`smoke_profile`).

    Parameters
    ----------
    path : str or os.PathLike
        GRIB2 file with MASSDEN (0.20.0) at 8 m above ground [kg m-3] (e.g. HRRR ``wrfprs``/``wrfsfc``).
    lat, lon : array_like
        Shape (ny, nx): the scene's columns [deg]; each takes the value of the nearest grid point.
    height : array_like
        Shape (nz, ny, nx) [m above sea level].
    terrain_height : array_like
        Shape (ny, nx) [m].
    mixing_depth : float or array_like
        Depth of the mixed layer [m], scalar or (ny, nx); default :data:`DEFAULT_SMOKE_MIXING_DEPTH_M`.
    time : optional
        Valid time (UTC), as in :func:`read_ncep_grib`.

    Returns
    -------
    numpy.ndarray
        Shape (nz, ny, nx) [kg m-3], for ``smoke_mass_content``.

    Raises
    ------
    SwimInputError
        If the file lacks MASSDEN at 8 m, its grid cannot be geolocated, or a column lies more than two grid
        spacings outside it.
    """
    p = Path(path)
    label = f"GRIB file {p.name}"
    headers = _select_time(_scan(p, label), time, label)
    _, single = _index(headers)
    if "MASSDEN" not in single:
        raise SwimInputError(f"{label} lacks MASSDEN (0.20.0, smoke mass density [kg m-3]) at 8 m above ground")
    lat, lon = np.asarray(lat, dtype=float), np.asarray(lon, dtype=float)
    reader = _Reader(p, label)
    grid_lat, grid_lon, _ = reader.grid(single["MASSDEN"])
    from .scene import domain_centre

    centre = domain_centre(lat, lon)
    cos_reach = np.min(_unit_vectors(lat, lon) @ _unit_vectors(*centre))
    reach = float(np.rad2deg(np.arccos(np.clip(cos_reach, -1.0, 1.0))))
    reader.rows, reader.cols = region_box(grid_lat, grid_lon, *centre, min(MAX_RADIUS_DEG, reach + 0.5))
    sub_lat, sub_lon = grid_lat[reader.rows, reader.cols], grid_lon[reader.rows, reader.cols]
    index, distance = _nearest(sub_lat, sub_lon, lat, lon)
    spacing = _spacing_deg(sub_lat, sub_lon)
    if np.max(distance) > 2.0 * spacing:
        raise SwimInputError(f"{label}: {int(np.sum(distance > 2.0 * spacing))} scene column(s) lie outside its grid")
    surface = reader.values(single["MASSDEN"]).ravel()[index]
    return smoke_profile(surface, height, terrain_height, mixing_depth)


def _unit_vectors(lat, lon):
    la, lo = np.deg2rad(lat), np.deg2rad(lon)
    return np.stack([np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)], axis=-1)


def _nearest(grid_lat, grid_lon, lat, lon):
    """Index into the flattened grid of the point nearest to each (lat, lon), and its distance [deg]."""
    from scipy.spatial import cKDTree

    tree = cKDTree(_unit_vectors(grid_lat, grid_lon).reshape(-1, 3))
    chord, index = tree.query(_unit_vectors(lat, lon))
    return index, np.rad2deg(2.0 * np.arcsin(np.clip(chord / 2.0, 0.0, 1.0)))


def _spacing_deg(lat, lon) -> float:
    """The grid spacing [deg of great circle] between the first two points of the middle row."""
    row = lat.shape[0] // 2
    v = _unit_vectors(lat[row, :2], lon[row, :2])
    return float(np.rad2deg(np.arccos(np.clip(np.dot(v[0], v[1]), -1, 1))))
