"""Reader for NOAA SURFRAD daily radiation files, and a clear-period detector (issue 5, item 1).

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

Two properties of the files, checked against the Alamosa file of 2016-01-01 (tests/unit/test_diagnostics_ghi.py):

* The longitude of line 2 is given as degrees *west* in some files (Alamosa: ``105.92``): the reader
  picks the sign whose solar zenith matches the ``zen`` column and stores east-positive longitude.
* ``zen`` is the refracted solar zenith angle 30 s before the time stamp (to 0.04 deg for zenith < 85 deg,
  NREL SPA via pvlib): a row is the mean over the minute that *ends* at its stamp. The reader keeps the
  stamps (UTC) as the index, as pvlib's ``read_surfrad`` does; :func:`observations_at` interpolates to
  the centres of the intervals.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pandas as pd

from ..errors import SwimInputError

log = logging.getLogger(__name__)

__all__ = ["SURFRAD_COLUMNS", "SURFRAD_MISSING", "read_surfrad", "clear_periods", "surfrad_precipitable_water",
           "surfrad_albedo", "observations_at"]

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


def clear_periods(obs: pd.DataFrame, window_length=10, max_zenith_deg=85.0) -> pd.Series:
    """Clear-sky minutes of a SURFRAD day: pvlib's ``detect_clearsky`` (Reno & Hansen 2016) on GHI.

    The reference clear sky is pvlib's Ineichen-Perez model with the climatological Linke turbidity of the
    station; ``detect_clearsky`` scales it and tests the mean, maximum, line length, variability and slope
    of GHI in sliding windows.

    Parameters
    ----------
    obs : pandas.DataFrame
        From :func:`read_surfrad` (regular 1-min index, ``ghi``, ``ghi_qc``, ``zenith``, station attrs).
    window_length : int
        Window [min].
    max_zenith_deg : float
        Minutes with a larger zenith angle [deg] are not clear (low sun: cosine errors of the pyranometer).

    Returns
    -------
    pandas.Series
        Boolean, index of ``obs``: True where the sky is clear, GHI is valid (qc 0) and the zenith is small
        enough.

    References
    ----------
    Reno, M. J. and Hansen, C. W. (2016), Renewable Energy 90, 520-531, doi:10.1016/j.renene.2015.12.031.
    Ineichen, P. and Perez, R. (2002), Sol. Energy 73, 151-157, doi:10.1016/S0038-092X(02)00045-2.
    """
    import pvlib

    try:
        lat, lon, elev = obs.attrs["latitude"], obs.attrs["longitude"], obs.attrs["elevation_m"]
    except KeyError:
        raise SwimInputError("clear_periods needs a DataFrame from read_surfrad (station attributes)") from None
    ghi = obs["ghi"].fillna(0.0)
    location = pvlib.location.Location(lat, lon, altitude=elev)
    reference = location.get_clearsky(obs.index - pd.Timedelta(seconds=30), model="ineichen")["ghi"]
    reference.index = obs.index
    clear = pvlib.clearsky.detect_clearsky(ghi, reference, window_length=window_length)
    ok = (obs["ghi_qc"] == 0) & obs["ghi"].notna() & (obs["zenith"] < max_zenith_deg)
    return (pd.Series(np.asarray(clear, dtype=bool), index=obs.index) & ok).rename("clear")


def surfrad_precipitable_water(obs: pd.DataFrame, max_zenith_deg=90.0) -> float:
    """Daytime median precipitable water [cm] from the station's air temperature and relative humidity.

    Gueymard (1994), Sol. Energy 53, 57-71, Eqs. 1-4 (pvlib ``gueymard94_pw``): w = 0.1 H_v rho_v with the
    surface water-vapour density rho_v = 216.7 RH e_s / T and the water-vapour scale height H_v(T) [km].

    Parameters
    ----------
    obs : pandas.DataFrame
        From :func:`read_surfrad`.
    max_zenith_deg : float
        Use the minutes with a smaller zenith angle [deg].

    Returns
    -------
    float
        Precipitable water [cm].

    Raises
    ------
    SwimInputError
        If no valid temperature/humidity pair is in the selected minutes.
    """
    import pvlib

    ok = (obs["zenith"] < max_zenith_deg) & obs["temp_air"].notna() & obs["relative_humidity"].notna()
    ok &= (obs.get("temp_air_qc", 0) == 0) & (obs.get("relative_humidity_qc", 0) == 0)
    if not ok.any():
        raise SwimInputError("no valid air temperature / relative humidity in the SURFRAD file")
    pw = pvlib.atmosphere.gueymard94_pw(obs.loc[ok, "temp_air"], obs.loc[ok, "relative_humidity"])
    return float(np.median(pw))


def surfrad_albedo(obs: pd.DataFrame, max_zenith_deg=75.0) -> float:
    """Median broadband surface albedo uw_solar / ghi [-] over the minutes with zenith < ``max_zenith_deg``.

    Raises
    ------
    SwimInputError
        If no minute has valid, positive global and upwelling solar irradiance.
    """
    ok = (obs["zenith"] < max_zenith_deg) & (obs["ghi"] > 50.0) & obs["uw_solar"].notna()
    ok &= (obs["ghi_qc"] == 0) & (obs.get("uw_solar_qc", 0) == 0)
    if not ok.any():
        raise SwimInputError("no valid daytime global / upwelling solar irradiance in the SURFRAD file")
    return float(np.clip(np.median(obs.loc[ok, "uw_solar"] / obs.loc[ok, "ghi"]), 0.0, 1.0))


def observations_at(obs: pd.DataFrame, times, columns=("ghi", "dni", "dhi"), clear=None) -> pd.DataFrame:
    """Observed values at given instants: linear interpolation to the centres of the 1-min intervals.

    A SURFRAD row is the mean over the minute ending at its stamp, so the value for instant t is the
    interpolation at t + 30 s (half an interval). Values with a qc flag other than 0 are dropped first.

    Parameters
    ----------
    obs : pandas.DataFrame
        From :func:`read_surfrad`.
    times : array_like of datetime
        The instants (UTC).
    columns : sequence of str
        Columns to return.
    clear : pandas.Series, optional
        From :func:`clear_periods`; adds a boolean ``clear`` column (both neighbouring minutes clear).

    Returns
    -------
    pandas.DataFrame
        Index ``times`` (UTC); the columns [W m-2]; NaN outside the record or where a neighbour is flagged.
    """
    index = pd.DatetimeIndex(pd.to_datetime(times, utc=True))
    span = pd.Timedelta(seconds=(obs.index[1] - obs.index[0]).total_seconds() / 2.0) if len(obs) > 1 else pd.Timedelta(0)
    target = index + span
    x = pd.DatetimeIndex(obs.index).as_unit("ns").asi8.astype(float)
    xt = target.as_unit("ns").asi8.astype(float)
    out = {}
    for name in columns:
        v = obs[name].astype(float)
        qc = f"{name}_qc"
        if qc in obs:
            v = v.where(obs[qc] == 0)
        vals = v.values
        good = np.isfinite(vals)
        res = np.interp(xt, x[good], vals[good], left=np.nan, right=np.nan) if good.any() else np.full(xt.size, np.nan)
        # NaN where either neighbour is bad
        pos = np.searchsorted(x, xt)
        lo, hi = np.clip(pos - 1, 0, x.size - 1), np.clip(pos, 0, x.size - 1)
        res[~(good[lo] & good[hi])] = np.nan
        out[name] = res
    frame = pd.DataFrame(out, index=index)
    if clear is not None:
        c = np.asarray(clear.reindex(obs.index, fill_value=False), dtype=bool)
        pos = np.searchsorted(x, xt)
        lo, hi = np.clip(pos - 1, 0, x.size - 1), np.clip(pos, 0, x.size - 1)
        inside = (xt >= x[0]) & (xt <= x[-1])
        frame["clear"] = c[lo] & c[hi] & inside
    return frame
