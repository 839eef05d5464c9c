"""Surface radiation observations from SURFRAD, BSRN and NREL MIDC files, and the helpers that compare them
with swim's irradiance (``swim ghi --observed``; docs/irradiance.md).

:func:`read_observations` recognises the format from the file's content (not its name) and returns one
table for all three networks:

* **SURFRAD** daily files (NOAA; Augustine et al. 2000): :func:`swim.io.surfrad.read_surfrad`, which also
  corrects a longitude given as degrees west against the file's zenith column.
* **BSRN** station-to-archive files (Driemel et al. 2018), plain or gzip-compressed, first line ``*U0001``
  or ``*C0001``: :func:`pvlib.iotools.read_bsrn` with the logical records LR0100 (1-min global, direct,
  diffuse irradiance, air temperature, humidity, pressure) and LR0300 (upwelling short-wave: the albedo).
  The station position comes from LR0004.
* **NREL MIDC** files (Measurement and Instrumentation Data Center): the CSV of the daily/interval
  download (header ``DATE (MM/DD/YYYY),<time zone>,...``) or of the raw-data API (``,Year,DOY,<time zone>,
  ...``), read with :func:`pvlib.iotools.read_midc`; times are converted from the station's standard time
  to UTC. MIDC files carry no station position: the caller gives latitude, longitude and elevation.

Time stamps: the index of the returned table is the **end** of each averaging interval (UTC), the SURFRAD
convention. BSRN documents its stamps as the *start* of the interval (GCOS-174, quoted in
:func:`pvlib.iotools.read_bsrn`), so BSRN stamps are moved forward by one minute. MIDC files do not state
their convention; their stamps are taken as interval ends like SURFRAD's (were they centres or starts, a
value would be half a minute or a minute late: < 1 % of clear-sky GHI at zenith angles below 60 deg, a few per
cent near sunrise and sunset). :func:`observations_at` interpolates to the centres of the intervals.

Quality flags: SURFRAD's own flags are kept (0 = good). BSRN and MIDC files carry none in the parsed
records; their ``<name>_qc`` columns are 0 where the value is finite and 1 where it is missing. No further
quality control (e.g. BSRN physical limits) is applied.

References
----------
Augustine, J. A., DeLuisi, J. J. and Long, C. N. (2000), SURFRAD -- A national surface radiation budget
network for atmospheric research, BAMS 81, 2341-2357, doi:10.1175/1520-0477(2000)081<2341:SAINSR>2.3.CO;2.
Driemel, A. et al. (2018), Baseline Surface Radiation Network (BSRN): structure and data description
(1992-2017), Earth Syst. Sci. Data 10, 1491-1501, doi:10.5194/essd-10-1491-2018.
NREL Measurement and Instrumentation Data Center (MIDC), https://midcdmz.nrel.gov/.
Holmgren, W. F., Hansen, C. W. and Mikofski, M. A. (2018), pvlib python: a python package for modeling solar
energy systems, JOSS 3, 884, doi:10.21105/joss.00884 (``pvlib.iotools``, ``pvlib.solarposition``).
"""

from __future__ import annotations

import gzip
import io
import logging
import re
from pathlib import Path

import numpy as np
import pandas as pd

from ..errors import SwimInputError

log = logging.getLogger(__name__)

__all__ = ["read_observations", "clear_periods", "observed_precipitable_water", "observed_albedo",
           "observations_at"]

#: Columns that get a ``<name>_qc`` flag when the file has none (0: finite value, 1: missing).
_FLAGGED = ("ghi", "dni", "dhi", "uw_solar", "temp_air", "relative_humidity", "pressure_hpa")
#: Units of the main columns of every format.
_UNITS = {"zenith": "degree", "ghi": "W m-2", "dni": "W m-2", "dhi": "W m-2", "uw_solar": "W m-2",
          "temp_air": "degC", "relative_humidity": "%", "pressure_hpa": "hPa"}
_EXPECTED = ("a SURFRAD daily file, a BSRN station-to-archive file (first line *U0001 or *C0001, plain or .gz) "
             "or an NREL MIDC CSV (header 'DATE (MM/DD/YYYY),...' or ',Year,DOY,...')")
#: Missing-value markers of MIDC files.
_MIDC_MISSING = (-7999.0, -9999.0, -99999.0)
#: Extra MIDC field names (beyond pvlib's per-site maps) used when no mapped column gives the quantity.
_MIDC_FALLBACK = {"ghi": ("Global PSP [W/m^2]", "Global Horiz [W/m^2]", "Global Horizontal [W/m^2]"),
                  "pressure_hpa": ("Station Pressure [mBar]", "Station Pressure [hPa]", "Pressure [mBar]")}


def read_observations(path, *, latitude=None, longitude=None, elevation_m=None) -> pd.DataFrame:
    """Read a SURFRAD, BSRN or NREL MIDC radiation file (recognised by content) into one kind of table.

    Parameters
    ----------
    path : str or pathlib.Path
        The file: a SURFRAD daily ``.dat`` file, a BSRN station-to-archive file (plain or gzip-compressed, any
        name) or an MIDC CSV (download or raw-data API format).
    latitude : float, optional
        Station latitude [deg N]; overrides the file's. Required for MIDC files.
    longitude : float, optional
        Station longitude [deg, east positive]; overrides the file's. Required for MIDC files.
    elevation_m : float, optional
        Station elevation [m above sea level]; overrides the file's. Required for MIDC files.

    Returns
    -------
    pandas.DataFrame
        Index ``time``: tz-aware UTC, the end of each averaging interval (module docstring). Columns:
        ``zenith`` (refracted solar zenith angle at the interval centre [deg]: the file's for SURFRAD,
        pvlib's SPA otherwise), ``ghi``, ``dni``, ``dhi`` [W m-2] (NaN where missing or not measured) and,
        where the file has them, ``uw_solar`` (upwelling short-wave [W m-2]), ``temp_air`` [deg C],
        ``relative_humidity`` [%], ``pressure_hpa`` [hPa]; a ``<name>_qc`` flag (int, 0 = good) for each of
        these; further columns of the file under the reader's names. ``attrs``: ``station``, ``latitude``
        [deg N], ``longitude`` [deg E], ``elevation_m`` [m], ``source`` (the path), ``format`` (``"surfrad"``,
        ``"bsrn"`` or ``"midc"``), ``time_stamp``, ``units``.

    Raises
    ------
    SwimInputError
        Missing file, a format that is none of the three, a file that its reader cannot parse, no data rows
        or no finite GHI, an MIDC file without ``latitude``/``longitude``/``elevation_m``, or a position out
        of range.

    References
    ----------
    Augustine et al. (2000), doi:10.1175/1520-0477(2000)081<2341:SAINSR>2.3.CO;2 (SURFRAD).
    Driemel et al. (2018), doi:10.5194/essd-10-1491-2018 (BSRN).
    NREL Measurement and Instrumentation Data Center, https://midcdmz.nrel.gov/ (MIDC).
    """
    path = Path(path)
    if not path.is_file():
        raise SwimInputError(f"observation file not found: {path} (expected {_EXPECTED})")
    _check_position(path, latitude, longitude, elevation_m)
    text, compressed = _read_text(path)
    lines = text.splitlines()
    kind = _sniff(lines)
    if kind is None:
        if not text.strip():
            raise SwimInputError(f"{path}: empty file (expected {_EXPECTED})")
        raise SwimInputError(f"{path}: unknown observation format (expected {_EXPECTED})")
    log.debug("%s: read as %s%s", path, kind, " (gzip)" if compressed else "")
    if kind == "surfrad":
        if compressed:
            raise SwimInputError(f"{path}: a gzip-compressed SURFRAD file; decompress it first (expected a plain "
                                 "SURFRAD .dat file)")
        from .surfrad import read_surfrad

        table = read_surfrad(path)
        table.attrs["format"] = "surfrad"
        _override_position(table, path, latitude, longitude, elevation_m)
        return _finish(table, path)
    if kind == "bsrn":
        table = _read_bsrn(path, text)
    else:
        if latitude is None or longitude is None or elevation_m is None:
            raise SwimInputError(f"{path}: an NREL MIDC file carries no station position; give --lat, --lon and "
                                 "--elevation (latitude, longitude [deg E], elevation_m [m])")
        table = _read_midc(path, text, raw=(kind == "midc-raw"))
    _override_position(table, path, latitude, longitude, elevation_m)
    return _finish(table, path)


# ---------------------------------------------------------------------------------------------------------------
# format recognition


def _read_text(path):
    """The file's text (latin-1: BSRN station addresses are not ASCII) and whether it was gzip-compressed."""
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise SwimInputError(f"{path}: cannot read the observation file ({exc.strerror or exc})") from None
    compressed = raw[:2] == b"\x1f\x8b"
    if compressed:
        try:
            raw = gzip.decompress(raw)
        except (OSError, EOFError, ValueError) as exc:
            raise SwimInputError(f"{path}: a damaged gzip file ({_one_line(exc)}; expected {_EXPECTED})") from None
    if b"\x00" in raw[:4096]:
        raise SwimInputError(f"{path}: a binary file, not a text observation file (expected {_EXPECTED})")
    return raw.decode("latin-1"), compressed


def _sniff(lines):
    """``"surfrad"``, ``"bsrn"``, ``"midc"``, ``"midc-raw"`` or None from the first lines of the text."""
    if not lines:
        return None
    first = lines[0].strip()
    if first.startswith(("*U0001", "*C0001")):
        return "bsrn"
    if first.startswith("DATE (MM/DD/YYYY)"):
        return "midc"
    fields = [f.strip() for f in first.split(",")]
    if len(fields) > 3 and "Year" in fields[:2] and "DOY" in fields[1:3]:
        return "midc-raw"
    if len(lines) >= 3:
        header = lines[1].split()
        try:
            [float(v) for v in header[:3]]
        except ValueError:
            return None
        if len(header) >= 3 and ("version" in lines[1].lower() or len(lines[2].split()) == 48):
            return "surfrad"
    return None


# ---------------------------------------------------------------------------------------------------------------
# BSRN


def _read_bsrn(path, text):
    """BSRN LR0100 + LR0300 through pvlib; stamps moved from interval starts to interval ends."""
    import pvlib

    try:
        # A buffer, not the path: pvlib chooses gzip by the name's suffix and decodes with the locale's encoding.
        data, meta = pvlib.iotools.read_bsrn(io.StringIO(text), logical_records=("0100", "0300"))
    except (ValueError, KeyError, IndexError, TypeError, NameError) as exc:
        raise SwimInputError(f"{path}: not a readable BSRN station-to-archive file ({_one_line(exc)})") from None
    if data is None or len(data) == 0 or "ghi" not in data:
        raise SwimInputError(f"{path}: no LR0100 data records (1-min global/direct/diffuse irradiance) in the BSRN "
                             "file")
    try:
        data = data.astype(float)
    except (TypeError, ValueError) as exc:
        raise SwimInputError(f"{path}: non-numeric BSRN data ({_one_line(exc)})") from None
    data = data.rename(columns=lambda c: "uw_solar" + c[3:] if c.startswith("gri") else c)
    data = data.rename(columns={"pressure": "pressure_hpa"})
    data.index = pd.DatetimeIndex(data.index).tz_convert("UTC") + pd.Timedelta(minutes=1)
    number = meta.get("station identification number")
    match = re.fullmatch(r"([a-z]{3})\d{4}", path.name.split(".")[0].lower())
    station = match.group(1).upper() if match else f"BSRN station {number}"
    data.attrs.update(station=station, station_number=number, latitude=round(float(meta["latitude"]), 6),
                      longitude=round(float(meta["longitude"]), 6), elevation_m=float(meta["altitude"]),
                      version=meta.get("version of data"), format="bsrn",
                      time_stamp="end of the averaging interval (UTC; the file's interval starts + 1 min)")
    return data


# ---------------------------------------------------------------------------------------------------------------
# MIDC


def _midc_variable_map():
    """pvlib's per-site MIDC maps merged (field name -> pvlib name); all sites share their field names."""
    from pvlib.iotools.midc import MIDC_VARIABLE_MAP

    merged = {}
    for site_map in MIDC_VARIABLE_MAP.values():
        merged.update(site_map)
    return merged


def _read_midc(path, text, raw):
    """MIDC CSV through pvlib (standard time -> UTC), mapped to ghi/dni/dhi/temp_air/relative_humidity."""
    import pvlib

    if raw and text.lstrip().startswith("Year"):
        # the raw-data API puts an unnamed column first; pvlib reads the time from the fourth column
        text = "\n".join("," + line if line.strip() else line for line in text.splitlines())
    try:
        ncols = len(pd.read_csv(io.StringIO(text), nrows=0).columns)
        # raw-data rows can have more fields than the header names: read only the named ones
        data = pvlib.iotools.read_midc(io.StringIO(text), variable_map=_midc_variable_map(), raw_data=raw,
                                       usecols=range(ncols))
    except (ValueError, KeyError, IndexError, TypeError, AttributeError) as exc:
        raise SwimInputError(f"{path}: not a readable NREL MIDC file ({_one_line(exc)}; expected a time-zone "
                             "column such as MST after the date columns)") from None
    if len(data) == 0:
        raise SwimInputError(f"{path}: no data rows in the MIDC file")
    time_zone = str(data.index.tz)
    data = data.iloc[:, 4 if raw else 2:]  # the date and time columns, now the index
    data = data.loc[:, ~data.columns.duplicated()]
    for name, candidates in _MIDC_FALLBACK.items():
        found = [c for c in candidates if c in data]
        if name not in data and found:
            data = data.rename(columns={found[0]: name})
    if "dni" not in data:
        for alt in ("dni_chp1", "dni_nip"):
            if alt in data:
                data = data.rename(columns={alt: "dni"})
                break
    if "ghi" not in data:
        raise SwimInputError(f"{path}: no global horizontal irradiance column in the MIDC file (expected one of "
                             f"{sorted(k for k, v in _midc_variable_map().items() if v == 'ghi')})")
    data = data.apply(pd.to_numeric, errors="coerce").astype(float)
    data = data.mask(data.isin(_MIDC_MISSING))
    data.index = pd.DatetimeIndex(data.index).tz_convert("UTC")
    data.attrs.update(station=path.stem, format="midc", time_zone_in_file=time_zone,
                      time_stamp="end of the averaging interval (UTC; the file's convention is not stated)")
    return data


# ---------------------------------------------------------------------------------------------------------------
# common


def _one_line(exc):
    text = str(exc).strip().splitlines()
    return (text[0] if text else type(exc).__name__)[:200]


def _check_position(path, latitude, longitude, elevation_m):
    if latitude is not None and not -90.0 <= float(latitude) <= 90.0:
        raise SwimInputError(f"{path}: latitude must be within -90..90 deg; got {latitude}")
    if longitude is not None and not -360.0 <= float(longitude) <= 360.0:
        raise SwimInputError(f"{path}: longitude must be within -180..360 deg; got {longitude}")
    if elevation_m is not None and not -500.0 <= float(elevation_m) <= 9000.0:
        raise SwimInputError(f"{path}: elevation must be within -500..9000 m; got {elevation_m}")


def _override_position(table, path, latitude, longitude, elevation_m):
    if longitude is not None:
        longitude = (float(longitude) + 180.0) % 360.0 - 180.0
    given = {"latitude": latitude, "longitude": longitude, "elevation_m": elevation_m}
    for key, value in given.items():
        if value is None:
            continue
        old = table.attrs.get(key)
        if old is not None and abs(float(old) - float(value)) > 0.01:
            log.info("%s: %s %s from the caller replaces the file's %s", path.name, key, value, old)
        table.attrs[key] = float(value)


def _finish(table, path):
    """Shared checks and columns: sorted unique UTC index, ghi/dni/dhi, zenith, qc flags, attrs."""
    if len(table) == 0:
        raise SwimInputError(f"{path}: no data rows")
    table.index.name = "time"
    if table.index.has_duplicates:
        raise SwimInputError(f"{path}: repeated time stamps (e.g. {table.index[table.index.duplicated()][0]})")
    if not table.index.is_monotonic_increasing:
        table = table.sort_index()
    for name in ("ghi", "dni", "dhi"):
        if name not in table:
            log.warning("%s: no %s column; it is left missing", path.name, name.upper())
            table[name] = np.nan
    if not np.isfinite(table["ghi"].to_numpy(dtype=float)).any():
        raise SwimInputError(f"{path}: no finite global horizontal irradiance (GHI) value in the file")
    lat, lon, elev = table.attrs["latitude"], table.attrs["longitude"], table.attrs["elevation_m"]
    if not (-90.0 <= lat <= 90.0 and -360.0 <= lon <= 360.0):
        raise SwimInputError(f"{path}: implausible station position {lat}, {lon} in the file")
    if not -180.0 <= lon <= 180.0:
        lon = table.attrs["longitude"] = (lon + 180.0) % 360.0 - 180.0
    if "zenith" not in table:
        import pvlib

        half = _step(table.index) / 2
        position = pvlib.solarposition.get_solarposition(table.index - half, lat, lon, altitude=elev)
        table["zenith"] = position["apparent_zenith"].to_numpy()
    for name in _FLAGGED:
        if name in table and f"{name}_qc" not in table:
            table[f"{name}_qc"] = np.where(np.isfinite(table[name].to_numpy(dtype=float)), 0, 1).astype(int)
    units = dict(table.attrs.get("units") or {})
    units.update({k: v for k, v in _UNITS.items() if k in table and k not in units})
    table.attrs.update(source=str(path), units=units)
    table.attrs.setdefault("time_stamp", "end of the averaging interval (UTC)")
    return table


def _step(index):
    """Median spacing of a time index (1 min for a single row)."""
    if len(index) < 2:
        return pd.Timedelta(minutes=1)
    return pd.Timedelta(int(np.median(np.diff(pd.DatetimeIndex(index).as_unit("ns").asi8))), unit="ns")


# ---------------------------------------------------------------------------------------------------------------
# helpers for the comparison


def clear_periods(obs: pd.DataFrame, window_length=10, max_zenith_deg=85.0) -> pd.Series:
    """Clear-sky intervals of an observed record: pvlib's ``detect_clearsky`` (Reno & Hansen 2016) on GHI.

    The reference clear sky is pvlib's Ineichen-Perez model with the climatological Linke turbidity of the
    station, evaluated at the interval centres; ``detect_clearsky`` scales it and tests the mean, maximum, line
    length, variability and slope of GHI in sliding windows. A record with gaps is put on its regular grid
    first (the gaps count as not clear).

    Parameters
    ----------
    obs : pandas.DataFrame
        From :func:`read_observations` (``ghi``, ``ghi_qc``, ``zenith``, station attrs).
    window_length : int
        Window [min].
    max_zenith_deg : float
        Intervals with a larger zenith angle [deg] are not clear (low sun: cosine errors of the pyranometer).

    Returns
    -------
    pandas.Series
        Boolean, index of ``obs``: True where the sky is clear, GHI is valid (qc 0) and the zenith is small
        enough. All False where the record is shorter than one window.

    Raises
    ------
    SwimInputError
        If ``obs`` lacks the station attributes.

    References
    ----------
    Reno, M. J. and Hansen, C. W. (2016), Renewable Energy 90, 520-531, doi:10.1016/j.renene.2015.12.031.
    Ineichen, P. and Perez, R. (2002), Sol. Energy 73, 151-157, doi:10.1016/S0038-092X(02)00045-2.
    """
    import pvlib

    try:
        lat, lon, elev = obs.attrs["latitude"], obs.attrs["longitude"], obs.attrs["elevation_m"]
    except KeyError:
        raise SwimInputError("clear_periods needs a DataFrame from read_observations (station attributes)") from None
    ok = (obs["ghi_qc"] == 0) & obs["ghi"].notna() & (obs["zenith"] < max_zenith_deg)
    step = _step(obs.index)
    grid = pd.date_range(obs.index[0], obs.index[-1], freq=step) if len(obs) > 1 else obs.index
    if not grid.equals(obs.index):
        log.info("clear_periods: %d of %d intervals missing; detecting on the regular %s grid",
                 len(grid) - len(obs.index.intersection(grid)), len(grid), step)
    if len(grid) < 3 or len(grid) * step < pd.Timedelta(minutes=window_length):
        log.warning("clear_periods: the record (%d intervals) is shorter than the %d-min window: nothing is clear",
                    len(obs), window_length)
        return pd.Series(False, index=obs.index, name="clear")
    ghi = obs["ghi"].reindex(grid).fillna(0.0)
    location = pvlib.location.Location(lat, lon, altitude=elev)
    reference = location.get_clearsky(grid - step / 2, model="ineichen")["ghi"]
    reference.index = grid
    clear = pd.Series(np.asarray(pvlib.clearsky.detect_clearsky(ghi, reference, window_length=window_length),
                                 dtype=bool), index=grid)
    clear = clear.reindex(obs.index, fill_value=False).to_numpy(dtype=bool)
    return (pd.Series(clear, index=obs.index) & ok).rename("clear")


def observed_precipitable_water(obs: pd.DataFrame, max_zenith_deg=90.0) -> float | None:
    """Daytime median precipitable water [cm] from the station's air temperature and relative humidity.

    Gueymard (1994), Sol. Energy 53, 57-71, Eqs. 1-4 (pvlib ``gueymard94_pw``): w = 0.1 H_v rho_v with the
    surface water-vapour density rho_v = 216.7 RH e_s / T and the water-vapour scale height H_v(T) [km].

    Parameters
    ----------
    obs : pandas.DataFrame
        From :func:`read_observations`.
    max_zenith_deg : float
        Use the intervals with a smaller zenith angle [deg].

    Returns
    -------
    float or None
        Precipitable water [cm]; None (logged) where the file has no temperature/humidity columns or no valid
        pair in the selected intervals: the caller then uses its default.
    """
    import pvlib

    if "temp_air" not in obs or "relative_humidity" not in obs:
        log.info("no air temperature / relative humidity in the observations: no precipitable water from them")
        return None
    ok = (obs["zenith"] < max_zenith_deg) & obs["temp_air"].notna() & obs["relative_humidity"].notna()
    ok &= (obs.get("temp_air_qc", 0) == 0) & (obs.get("relative_humidity_qc", 0) == 0)
    if not ok.any():
        log.warning("no valid daytime air temperature / relative humidity in the observations")
        return None
    pw = pvlib.atmosphere.gueymard94_pw(obs.loc[ok, "temp_air"], obs.loc[ok, "relative_humidity"])
    return float(np.median(pw))


def observed_albedo(obs: pd.DataFrame, max_zenith_deg=75.0) -> float | None:
    """Median broadband surface albedo uw_solar / ghi [-] over the intervals with zenith < ``max_zenith_deg``.

    Parameters
    ----------
    obs : pandas.DataFrame
        From :func:`read_observations` (``uw_solar``: SURFRAD's upwelling solar, BSRN's LR0300 reflected
        short-wave).
    max_zenith_deg : float
        Use the intervals with a smaller zenith angle [deg] and GHI > 50 W m-2.

    Returns
    -------
    float or None
        Albedo in [0, 1]; None (logged) where the file has no upwelling short-wave or no valid daytime pair:
        the caller then uses its default.
    """
    if "uw_solar" not in obs:
        log.info("no upwelling short-wave irradiance in the observations: no albedo from them")
        return None
    ok = (obs["zenith"] < max_zenith_deg) & (obs["ghi"] > 50.0) & obs["uw_solar"].notna()
    ok &= (obs["ghi_qc"] == 0) & (obs.get("uw_solar_qc", 0) == 0)
    if not ok.any():
        log.warning("no valid daytime global / upwelling solar irradiance in the observations")
        return None
    return float(np.clip(np.median(obs.loc[ok, "uw_solar"] / obs.loc[ok, "ghi"]), 0.0, 1.0))


def observations_at(obs: pd.DataFrame, times, columns=("ghi", "dni", "dhi"), clear=None) -> pd.DataFrame:
    """Observed values at given instants: linear interpolation to the centres of the averaging intervals.

    A row is the mean over the interval ending at its stamp (:func:`read_observations`), so the value for
    instant t is the interpolation at t + half an interval (30 s for 1-min data). Values with a qc flag other
    than 0 are dropped first.

    Parameters
    ----------
    obs : pandas.DataFrame
        From :func:`read_observations`.
    times : array_like of datetime
        The instants (UTC).
    columns : sequence of str
        Columns to return.
    clear : pandas.Series, optional
        From :func:`clear_periods`; adds a boolean ``clear`` column (both neighbouring intervals clear).

    Returns
    -------
    pandas.DataFrame
        Index ``times`` (UTC); the columns [W m-2]; NaN outside the record, where a neighbour is flagged or
        where the file lacks the column.
    """
    index = pd.DatetimeIndex(pd.to_datetime(times, utc=True))
    span = pd.Timedelta(seconds=(obs.index[1] - obs.index[0]).total_seconds() / 2.0) if len(obs) > 1 else pd.Timedelta(0)
    target = index + span
    x = pd.DatetimeIndex(obs.index).as_unit("ns").asi8.astype(float)
    xt = target.as_unit("ns").asi8.astype(float)
    pos = np.searchsorted(x, xt)
    lo, hi = np.clip(pos - 1, 0, x.size - 1), np.clip(pos, 0, x.size - 1)
    out = {}
    for name in columns:
        if name not in obs:
            out[name] = np.full(xt.size, np.nan)
            continue
        v = obs[name].astype(float)
        qc = f"{name}_qc"
        if qc in obs:
            v = v.where(obs[qc] == 0)
        vals = v.values
        good = np.isfinite(vals)
        res = np.interp(xt, x[good], vals[good], left=np.nan, right=np.nan) if good.any() else np.full(xt.size, np.nan)
        res[~(good[lo] & good[hi])] = np.nan  # NaN where either neighbour is bad
        out[name] = res
    frame = pd.DataFrame(out, index=index)
    if clear is not None:
        c = np.asarray(clear.reindex(obs.index, fill_value=False), dtype=bool)
        inside = (xt >= x[0]) & (xt <= x[-1])
        frame["clear"] = c[lo] & c[hi] & inside
    return frame
