"""Reader for NOAA SURFRAD daily radiation files (:func:`swim.io.observations.read_observations` dispatches
SURFRAD, BSRN and MIDC files; the clear-period detector and the other comparison helpers live there).

SURFRAD (Surface Radiation Budget Network, NOAA Global Monitoring Laboratory; Augustine et al. 2000,
BAMS 81, 2341-2357, doi:10.1175/1520-0477(2000)081<2341:SAINSR>2.3.CO;2; Augustine et al. 2005, J. Appl.
Meteorol. 44, 1640-1651) publishes one ASCII file per station and day (e.g. ``slv16001.dat``: Alamosa,
2016, day 1), documented in the README of each station directory of the archive:

* line 1: station name;
* line 2: latitude [deg N], longitude [deg], elevation [m], the letter ``m``, ``version`` and a number;
* then one row per minute (1-min means since 2009; 3-min before), 48 whitespace-separated fields:
  year, jday, month, day, hour, min, dt (decimal hour), zen (solar zenith angle [deg]) and 20 pairs of a
  value and its quality flag, in this order: dw_solar (downwelling global solar, "dw_psp", GHI [W m-2]),
  uw_solar (upwelling global solar [W m-2]), direct_n (direct normal, DNI [W m-2]), diffuse (downwelling
  diffuse, DHI [W m-2]), dw_ir, dw_casetemp, dw_dometemp, uw_ir, uw_casetemp, uw_dometemp (infrared
  [W m-2] and pyrgeometer temperatures [K]), uvb [mW m-2], par [W m-2], netsolar, netir, totalnet
  [W m-2], temp (air temperature [deg C]), rh (relative humidity [%]), windspd [m s-1], winddir [deg from
  north], pressure (station pressure [hPa]).

A flag of 0 means the value passed all quality checks; 1 that it failed the physical-limits check (bad);
2 and above that it failed a later check and is to be used with scrutiny. Missing values are -9999.9.

Two properties of the files, checked against the Alamosa file of 2016-01-01
(tests/unit/diagnostics/test_diagnostics_ghi.py):

* The longitude of line 2 is given as degrees *west* in some files (Alamosa: ``105.92``): the reader
  picks the sign whose solar zenith matches the ``zen`` column and stores east-positive longitude.
* ``zen`` is the refracted solar zenith angle 30 s before the time stamp (to 0.04 deg for zenith < 85 deg,
  NREL SPA via pvlib): a row is the mean over the minute that *ends* at its stamp. The reader keeps the
  stamps (UTC) as the index, as pvlib's ``read_surfrad`` does; :func:`swim.io.observations.observations_at`
  interpolates to the centres of the intervals.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pandas as pd

from ..errors import SwimInputError

log = logging.getLogger(__name__)

__all__ = ["SURFRAD_COLUMNS", "SURFRAD_MISSING", "read_surfrad"]

_PAIRS = ("dw_solar", "uw_solar", "direct_n", "diffuse", "dw_ir", "dw_casetemp", "dw_dometemp", "uw_ir",
          "uw_casetemp", "uw_dometemp", "uvb", "par", "netsolar", "netir", "totalnet", "temp", "rh",
          "windspd", "winddir", "pressure")
#: The 48 fields of a data row, in file order (station README).
SURFRAD_COLUMNS = ("year", "jday", "month", "day", "hour", "min", "dt", "zen") + tuple(
    name for pair in _PAIRS for name in (pair, f"{pair}_qc"))
#: Missing-value marker of the files.
SURFRAD_MISSING = -9999.9
#: Names given to the main columns (the rest keep the file's names; flags end in ``_qc``).
_RENAME = {"zen": "zenith", "dw_solar": "ghi", "dw_solar_qc": "ghi_qc", "direct_n": "dni", "direct_n_qc": "dni_qc",
           "diffuse": "dhi", "diffuse_qc": "dhi_qc", "temp": "temp_air", "temp_qc": "temp_air_qc",
           "rh": "relative_humidity", "rh_qc": "relative_humidity_qc", "pressure": "pressure_hpa",
           "pressure_qc": "pressure_hpa_qc"}
#: Units of the returned columns.
UNITS = {"zenith": "degree", "ghi": "W m-2", "dni": "W m-2", "dhi": "W m-2", "uw_solar": "W m-2",
         "dw_ir": "W m-2", "uw_ir": "W m-2", "uvb": "mW m-2", "par": "W m-2", "netsolar": "W m-2",
         "netir": "W m-2", "totalnet": "W m-2", "temp_air": "degC", "relative_humidity": "%",
         "windspd": "m s-1", "winddir": "degree", "pressure_hpa": "hPa", "dw_casetemp": "K",
         "dw_dometemp": "K", "uw_casetemp": "K", "uw_dometemp": "K"}


def _header(lines, path):
    if len(lines) < 3:
        raise SwimInputError(f"{path}: a SURFRAD file has 2 header lines and data rows; got {len(lines)} lines")
    station = lines[0].strip()
    fields = lines[1].split()
    try:
        lat, lon, elev = (float(v) for v in fields[:3])
    except (ValueError, IndexError):
        raise SwimInputError(f"{path}: line 2 must be 'latitude longitude elevation m version N'; got "
                             f"{lines[1].strip()!r}") from None
    if not (-90 <= lat <= 90 and -360 <= lon <= 360 and -500 <= elev <= 9000):
        raise SwimInputError(f"{path}: implausible station position {lat}, {lon}, {elev} m on line 2")
    version = fields[-1] if len(fields) > 3 else ""
    return station, lat, lon, elev, version


def read_surfrad(path) -> pd.DataFrame:
    """Read a SURFRAD daily file (module docstring) into a DataFrame indexed by UTC time.

    Parameters
    ----------
    path : str or pathlib.Path
        The ``.dat`` file.

    Returns
    -------
    pandas.DataFrame
        Index ``time`` (tz-aware UTC, the file's stamps: ends of the averaging intervals). Columns:
        ``zenith`` [deg], ``ghi``, ``dni``, ``dhi``, ``uw_solar`` [W m-2], ``temp_air`` [deg C],
        ``relative_humidity`` [%], ``pressure_hpa`` [hPa] and the other fields under their file names,
        missing values as NaN; the flags ``<name>_qc`` (int, 0 = good). ``attrs``: ``station``,
        ``latitude``, ``longitude`` (east positive), ``longitude_in_file``, ``elevation_m``, ``version``,
        ``source``, ``units``.

    Raises
    ------
    SwimInputError
        Missing file, a bad header, a row without 48 numbers, dates that disagree with each other or a
        zenith column that no station longitude explains.
    """
    path = Path(path)
    if not path.is_file():
        raise SwimInputError(f"SURFRAD file not found: {path}")
    try:
        lines = path.read_text(encoding="ascii", errors="strict").splitlines()
    except UnicodeDecodeError:
        raise SwimInputError(f"{path}: not a SURFRAD text file (non-ASCII bytes)") from None
    station, lat, lon_file, elev, version = _header(lines, path)
    rows = []
    for number, line in enumerate(lines[2:], start=3):
        if not line.strip():
            continue
        fields = line.split()
        if len(fields) != len(SURFRAD_COLUMNS):
            raise SwimInputError(f"{path}, line {number}: expected {len(SURFRAD_COLUMNS)} fields, got {len(fields)}")
        try:
            rows.append([float(v) for v in fields])
        except ValueError:
            raise SwimInputError(f"{path}, line {number}: non-numeric field in {line.strip()[:60]!r}...") from None
    table = pd.DataFrame(np.array(rows), columns=list(SURFRAD_COLUMNS))
    ints = ["year", "jday", "month", "day", "hour", "min"] + [c for c in SURFRAD_COLUMNS if c.endswith("_qc")]
    table[ints] = table[ints].astype(int)
    try:
        stamp = pd.to_datetime(table["year"].astype(str) + table["jday"].map("{:03d}".format)
                               + table["hour"].map("{:02d}".format) + table["min"].map("{:02d}".format),
                               format="%Y%j%H%M", utc=True)
    except ValueError as exc:
        raise SwimInputError(f"{path}: bad date/time fields ({exc})") from None
    if np.any(stamp.dt.month.values != table["month"].values) or np.any(stamp.dt.day.values != table["day"].values):
        raise SwimInputError(f"{path}: month/day columns disagree with year/jday")
    if not stamp.is_monotonic_increasing or stamp.duplicated().any():
        raise SwimInputError(f"{path}: time stamps must increase")
    values = [c for c in SURFRAD_COLUMNS[7:] if not c.endswith("_qc")]
    table[values] = table[values].where(np.abs(table[values] - SURFRAD_MISSING) > 1e-6)
    table.index = pd.DatetimeIndex(stamp, name="time")
    table = table.rename(columns=_RENAME)
    lon = _station_longitude(table, lat, lon_file, elev, path)
    table.attrs.update(station=station, latitude=lat, longitude=lon, longitude_in_file=lon_file, elevation_m=elev,
                       version=version, source=str(path), units=dict(UNITS),
                       time_stamp="end of the averaging interval (UTC)")
    return table


def _station_longitude(table, lat, lon_file, elev, path):
    """East-positive longitude: the sign of the header's value whose sun matches the zenith column."""
    import pvlib

    day = table["zenith"].notna() & (table["zenith"] < 85.0)
    if day.sum() < 3:
        return float(lon_file)
    sample = table.loc[day].iloc[:: max(1, int(day.sum()) // 20)]
    errors = {}
    for lon in {float(lon_file), -abs(float(lon_file))}:
        wrapped = (lon + 180.0) % 360.0 - 180.0
        sp = pvlib.solarposition.get_solarposition(sample.index - pd.Timedelta(seconds=30), lat, wrapped, altitude=elev)
        errors[wrapped] = float(np.nanmax(np.abs(sp["apparent_zenith"].values - sample["zenith"].values)))
    best = min(errors, key=errors.get)
    if errors[best] > 1.0:
        raise SwimInputError(f"{path}: the zenith column matches no longitude {sorted(errors)} (errors {errors} deg): "
                             "wrong station header or time stamps")
    if best != float(lon_file):
        log.info("%s: header longitude %.2f read as %.2f deg east (zenith column matches to %.3f deg)",
                 path.name, lon_file, best, errors[best])
    return best
