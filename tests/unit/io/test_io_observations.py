"""Radiation observations from SURFRAD, BSRN and NREL MIDC files (swim.io.observations) and ``swim ghi --observed``.

The SURFRAD file is real (../shared/data/obs); the BSRN and MIDC files are written here in the formats that
pvlib's readers parse (pvlib.iotools.bsrn: fixed-width LR0100 in two lines per minute, LR0300 in one;
pvlib.iotools.midc: CSV with the time zone as the name of the time column), with clear-sky values from pvlib's
Ineichen-Perez model at a known site (NREL's Solar Radiation Research Laboratory, Golden, Colorado).
"""

import gzip

import numpy as np
import pandas as pd
import pvlib
import pytest
from typer.testing import CliRunner

from swim.errors import SwimInputError
from swim.io import read_observations
from swim.io.observations import (
    clear_periods,
    observations_at,
    observed_albedo,
    observed_precipitable_water,
)
from swim.io.surfrad import read_surfrad

LAT, LON, ELEV = 39.742, -105.18, 1829.0  # NREL SRRL (the MIDC "BMS" station)
START = pd.Timestamp("2019-06-21T18:00Z")  # first BSRN interval start (local noon is ~19:00 UTC)
MINUTES = 40
ALBEDO = 0.20


def _clear_sky(ends):
    """Clear-sky GHI, DNI, DHI [W m-2] (rounded to whole numbers, as BSRN files store them) at interval centres."""
    loc = pvlib.location.Location(LAT, LON, altitude=ELEV)
    cs = loc.get_clearsky(ends - pd.Timedelta(seconds=30), model="ineichen")
    return cs.round().astype(int).set_axis(ends)


@pytest.fixture(scope="module")
def truth():
    """The values written to the synthetic files, indexed by interval *end* (UTC)."""
    ends = pd.date_range(START + pd.Timedelta(minutes=1), periods=MINUTES, freq="1min", name="time")
    cs = _clear_sky(ends)
    cs["uw"] = (ALBEDO * cs["ghi"]).round().astype(int)
    cs["temp_air"] = 25.0 + 0.1 * np.arange(MINUTES)
    cs["rh"] = 30.0
    cs["pressure"] = 812
    return cs


# ---------------------------------------------------------------------------------------------------------------
# synthetic files


def _bsrn_text(truth, *, lr0300=True, missing_dni_at=None, station=23, lat=LAT, lon=LON, elev=ELEV):
    """A BSRN station-to-archive file (pvlib.iotools.bsrn's column specifications, GCOS-174 layout)."""
    lines = ["*U0001", f"{station:3d}{START.month:3d} {START.year:4d}  1", "*U0004", " -1 -1 -1",
             " 11  2", "NREL Solar Radiation Research Laboratory, Golden, CO",
             f"{'+1 303 000 0000':<20}+1 303 000 0001", f"{'127.0.0.1':<15}bsrn@example.org",
             f"{lat + 90:8.3f}{lon + 180:8.3f}{int(elev):5d} 72469", " -1 -1 -1", "  0  2 90  3 180  1 270  2 -1 -1",
             "*U0100"]
    for end, row in truth.iterrows():
        start = end - pd.Timedelta(minutes=1)  # BSRN stamps are interval starts
        day, minute = start.day, start.hour * 60 + start.minute
        ghi, dni, dhi = int(row["ghi"]), int(row["dni"]), int(row["dhi"])
        dni_file = -999 if end == missing_dni_at else dni
        lines.append(f"{day:3d} {minute:5d} {ghi:6d}{1.5:6.1f}{ghi - 2:5d}{ghi + 2:5d}"
                     f"{dni_file:7d}{0.8:6.1f}{dni - 1:5d}{dni + 1:5d}")
        lines.append(f"{'':10}{dhi:6d}{0.5:6.1f}{dhi - 1:5d}{dhi + 1:5d}"
                     f"{330:7d}{0.2:6.1f}{329:5d}{331:5d}{row['temp_air']:9.1f}{row['rh']:6.1f}{int(row['pressure']):5d}")
    if lr0300:
        lines.append("*U0300")
        for end, row in truth.iterrows():
            start = end - pd.Timedelta(minutes=1)
            day, minute, uw = start.day, start.hour * 60 + start.minute, int(row["uw"])
            lines.append(f" {day:2d} {minute:5d} {uw:6d}{0.4:6.1f}{uw - 1:5d}{uw + 1:4d}"
                         f"{420:7d}{0.3:6.1f}{419:5d}{421:5d}{300:7d}{1.0:6.1f}{298:5d}{302:6d}")
    return "\n".join(lines) + "\n"


def _midc_text(truth, *, missing_ghi_at=None, humidity=True):
    """An MIDC download CSV in Mountain Standard Time (UTC-7), BMS field names, stamps as interval ends."""
    local = truth.index.tz_convert("Etc/GMT+7")
    names = ["Global CMP22 (vent/cor) [W/m^2]", "Direct CHP1-1 [W/m^2]", "Diffuse CM22-1 (vent/cor) [W/m^2]",
             "Global PSP [W/m^2]"] + (["Tower Dry Bulb Temp [deg C]", "Tower RH [%]"] if humidity else [])
    lines = ["DATE (MM/DD/YYYY),MST," + ",".join(names)]
    for t, (end, row) in zip(local, truth.iterrows(), strict=True):
        ghi = -7999 if end == missing_ghi_at else int(row["ghi"])
        fields = [t.strftime("%m/%d/%Y"), t.strftime("%H:%M"), str(ghi), str(int(row["dni"])), str(int(row["dhi"])),
                  str(int(row["ghi"]) + 5)] + ([f"{row['temp_air']:.1f}", f"{row['rh']:.1f}"] if humidity else [])
        lines.append(",".join(fields))
    return "\n".join(lines) + "\n"


def _midc_raw_text(truth):
    """An MIDC raw-data API CSV in Central Standard Time (UTC-6): unnamed first column, Year, DOY, HHMM and more
    fields per row than header names (as the API writes them)."""
    local = truth.index.tz_convert("Etc/GMT+6")
    lines = [",Year,DOY,CST,Global Horizontal [W/m^2],Direct Normal [W/m^2],Diffuse Horizontal [W/m^2]"]
    for t, (_, row) in zip(local, truth.iterrows(), strict=True):
        lines.append(f"0,{t.year},{t.day_of_year},{t.hour * 100 + t.minute},{int(row['ghi'])},{int(row['dni'])},"
                     f"{int(row['dhi'])},"
                     "-7999,-7999")
    return "\n".join(lines) + "\n"


def _write(path, text, compress=False):
    path.write_bytes(gzip.compress(text.encode("latin-1")) if compress else text.encode("latin-1"))
    return path


# ---------------------------------------------------------------------------------------------------------------
# SURFRAD (real file)


@pytest.mark.realdata
def test_surfrad_file_reads_as_before(shared_data):
    path = shared_data / "obs" / "surfrad-slv16001.dat"
    if not path.is_file():
        pytest.skip(f"{path} not found")
    obs = read_observations(path)
    ref = read_surfrad(path)
    assert obs.attrs["format"] == "surfrad" and obs.attrs["station"] == "Alamosa"
    assert obs.attrs["longitude"] == -105.92 and obs.attrs["latitude"] == 37.70 and obs.attrs["elevation_m"] == 2317.0
    assert obs.index.equals(ref.index) and str(obs.index.tz) == "UTC" and obs.index.name == "time"
    np.testing.assert_array_equal(obs["zenith"].values, ref["zenith"].values)  # the file's own zenith
    assert obs.loc["2016-01-01T19:00Z", "ghi"] == 579.1 and obs["ghi_qc"].dtype.kind == "i"
    assert observed_albedo(obs) == pytest.approx(observed_albedo(ref))
    moved = read_observations(path, latitude=37.5, longitude=254.0, elevation_m=2300.0)
    assert (moved.attrs["latitude"], moved.attrs["longitude"], moved.attrs["elevation_m"]) == (37.5, -106.0, 2300.0)


# ---------------------------------------------------------------------------------------------------------------
# BSRN


def test_bsrn_values_index_location_zenith_and_flags(tmp_path, truth):
    gap = truth.index[10]
    obs = read_observations(_write(tmp_path / "srl0619.dat", _bsrn_text(truth, missing_dni_at=gap)))
    assert obs.attrs["format"] == "bsrn" and obs.attrs["station"] == "SRL" and obs.attrs["station_number"] == 23
    assert obs.attrs["latitude"] == pytest.approx(LAT) and obs.attrs["longitude"] == pytest.approx(LON)
    assert obs.attrs["elevation_m"] == ELEV and obs.attrs["source"].endswith("srl0619.dat")
    # The file's first stamp is 18:00 (an interval start); the table's is 18:01, the interval's end.
    assert str(obs.index.tz) == "UTC" and obs.index.name == "time"
    assert obs.index.equals(truth.index) and obs.index[0] == pd.Timestamp("2019-06-21T18:01Z")
    for col in ("ghi", "dhi"):
        np.testing.assert_array_equal(obs[col].values, truth[col].values)
    np.testing.assert_array_equal(obs["dni"].drop(gap).values, truth["dni"].drop(gap).values)
    np.testing.assert_array_equal(obs["uw_solar"].values, truth["uw"].values)  # LR0300 "gri"
    np.testing.assert_allclose(obs["temp_air"].values, truth["temp_air"].values, atol=0.051)
    assert (obs["relative_humidity"] == 30.0).all() and (obs["pressure_hpa"] == 812.0).all()
    # Zenith: pvlib's SPA at the interval centres; the sun moves ~0.1 deg per minute, so a wrong stamp shows.
    spa = pvlib.solarposition.get_solarposition(truth.index - pd.Timedelta(seconds=30), LAT, LON, altitude=ELEV)
    np.testing.assert_allclose(obs["zenith"].values, spa["apparent_zenith"].values, atol=1e-6)
    assert 15.0 < obs["zenith"].min() < 20.0  # midsummer noon at 39.7 deg N
    # Flags: the file has none; 0 where finite, 1 where missing (-999 in the file).
    assert np.isnan(obs.loc[gap, "dni"]) and obs.loc[gap, "dni_qc"] == 1
    assert (obs["dni_qc"].drop(gap) == 0).all()
    for col in ("ghi", "dhi", "uw_solar", "temp_air", "relative_humidity", "pressure_hpa"):
        assert obs[f"{col}_qc"].dtype.kind == "i" and (obs[f"{col}_qc"] == 0).all(), col


def test_bsrn_is_recognised_by_content_plain_or_gzip(tmp_path, truth):
    text = _bsrn_text(truth)
    reference = read_observations(_write(tmp_path / "srl0619.dat", text))
    for name, compress in (("station.txt", False), ("srl0619.dat.gz", True), ("download.dat", True)):
        obs = read_observations(_write(tmp_path / name, text, compress=compress))
        assert obs.attrs["format"] == "bsrn", name
        pd.testing.assert_frame_equal(obs, reference, check_like=True)


def test_bsrn_comparison_helpers(tmp_path, truth):
    obs = read_observations(_write(tmp_path / "srl0619.dat", _bsrn_text(truth)))
    assert observed_albedo(obs) == pytest.approx(ALBEDO, abs=0.01)
    expected_pw = float(np.median(pvlib.atmosphere.gueymard94_pw(truth["temp_air"], truth["rh"])))
    assert observed_precipitable_water(obs) == pytest.approx(expected_pw, rel=1e-3)
    clear = clear_periods(obs)
    assert clear.index.equals(obs.index) and clear.mean() > 0.8  # the values are the clear-sky model's
    # 18:20 is the centre of the minutes ending 18:20 and 18:21: their mean.
    t = pd.Timestamp("2019-06-21T18:20Z")
    got = observations_at(obs, [t], clear=clear)
    assert got.loc[t, "ghi"] == pytest.approx(truth.loc[[t, t + pd.Timedelta("1min")], "ghi"].mean())
    # A record with a gap is detected on its regular grid; one shorter than the window has no clear interval.
    holed = obs.drop(obs.index[20:23])
    assert clear_periods(holed).index.equals(holed.index) and clear_periods(holed).iloc[:10].all()
    assert not clear_periods(obs.iloc[:5]).any()
    # Without LR0300 there is no upwelling short-wave: the albedo falls back to the caller's default (None).
    bare = read_observations(_write(tmp_path / "bare.dat", _bsrn_text(truth, lr0300=False)))
    assert "uw_solar" not in bare and observed_albedo(bare) is None


# ---------------------------------------------------------------------------------------------------------------
# MIDC


def test_midc_download_format(tmp_path, truth):
    gap = truth.index[5]
    path = _write(tmp_path / "bms.csv", _midc_text(truth, missing_ghi_at=gap))
    obs = read_observations(path, latitude=LAT, longitude=LON, elevation_m=ELEV)
    assert obs.attrs["format"] == "midc" and obs.attrs["station"] == "bms"
    assert (obs.attrs["latitude"], obs.attrs["longitude"], obs.attrs["elevation_m"]) == (LAT, LON, ELEV)
    # 11:01 MST is 18:01 UTC; stamps are interval ends.
    assert str(obs.index.tz) == "UTC" and obs.index.equals(truth.index)
    np.testing.assert_array_equal(obs["ghi"].drop(gap).values, truth["ghi"].drop(gap).values)  # CMP22, not PSP
    np.testing.assert_array_equal(obs["dni"].values, truth["dni"].values)  # CHP1
    np.testing.assert_array_equal(obs["dhi"].values, truth["dhi"].values)
    assert np.isnan(obs.loc[gap, "ghi"]) and obs.loc[gap, "ghi_qc"] == 1 and (obs["ghi_qc"].drop(gap) == 0).all()
    spa = pvlib.solarposition.get_solarposition(truth.index - pd.Timedelta(seconds=30), LAT, LON, altitude=ELEV)
    np.testing.assert_allclose(obs["zenith"].values, spa["apparent_zenith"].values, atol=1e-6)
    assert observed_albedo(obs) is None  # no upwelling short-wave in the file
    assert observed_precipitable_water(obs) == pytest.approx(
        float(np.median(pvlib.atmosphere.gueymard94_pw(truth["temp_air"], truth["rh"]))), rel=1e-3)
    dry = read_observations(_write(tmp_path / "dry.csv", _midc_text(truth, humidity=False)), latitude=LAT,
                            longitude=LON, elevation_m=ELEV)
    assert "relative_humidity" not in dry and observed_precipitable_water(dry) is None


def test_midc_raw_api_format(tmp_path, truth):
    obs = read_observations(_write(tmp_path / "midc_raw.txt", _midc_raw_text(truth)), latitude=LAT,
                            longitude=LON + 360.0, elevation_m=ELEV)
    assert obs.attrs["format"] == "midc" and obs.attrs["longitude"] == pytest.approx(LON)
    assert obs.index.equals(truth.index)  # 12:01 CST is 18:01 UTC
    for col in ("ghi", "dni", "dhi"):
        np.testing.assert_array_equal(obs[col].values, truth[col].values)
        assert (obs[f"{col}_qc"] == 0).all()


# ---------------------------------------------------------------------------------------------------------------
# bad input


def _error(path, **kwargs):
    with pytest.raises(SwimInputError) as info:
        read_observations(path, **kwargs)
    message = str(info.value)
    assert "\n" not in message and str(path) in message
    return message


def test_bad_input_raises_one_line_input_errors(tmp_path, truth):
    assert "not found" in _error(tmp_path / "nope.dat")
    assert "unknown observation format" in _error(_write(tmp_path / "notes.txt", "hello\nworld\nthird line\n"))
    assert "BSRN" in _error(_write(tmp_path / "notes.txt", "a,b,c\n1,2,3\n"))  # names what is expected
    assert "empty" in _error(_write(tmp_path / "empty.dat", ""))
    # MIDC without a position: the message names the options.
    message = _error(_write(tmp_path / "bms.csv", _midc_text(truth)), latitude=LAT, longitude=LON)
    assert "--lat" in message and "--lon" in message and "--elevation" in message
    assert "no data rows" in _error(_write(tmp_path / "head.csv", _midc_text(truth).splitlines()[0] + "\n"),
                                    latitude=LAT, longitude=LON, elevation_m=ELEV)
    bad_zone = _midc_text(truth).replace(",MST,", ",Mountain,", 1)
    assert "MIDC" in _error(_write(tmp_path / "zone.csv", bad_zone), latitude=LAT, longitude=LON, elevation_m=ELEV)
    # BSRN: no LR0100 records; a file cut before the station description (LR0004).
    header_only = _bsrn_text(truth).split("*U0100")[0]
    assert "LR0100" in _error(_write(tmp_path / "head.dat", header_only))
    assert "BSRN" in _error(_write(tmp_path / "cut.dat", "*U0001\n 23  6 2019  1\n"))
    broken = tmp_path / "broken.gz"
    broken.write_bytes(gzip.compress(b"*U0001\n")[:12])  # a truncated download
    assert "gzip" in _error(broken)
    assert "latitude" in _error(_write(tmp_path / "srl0619.dat", _bsrn_text(truth)), latitude=95.0)


# ---------------------------------------------------------------------------------------------------------------
# swim ghi --observed


def test_cli_ghi_with_a_bsrn_file(tmp_path, truth):
    """Two 10-min instants at local noon, 9 px renders; the observed column is the file's interval-centre value."""
    from swim.cli.main import app

    obs_path = _write(tmp_path / "srl0619.txt", _bsrn_text(truth))
    out = tmp_path / "ghi.csv"
    res = CliRunner().invoke(app, ["ghi", "--observed", str(obs_path), "--start", "2019-06-21T18:15Z", "--end",
                                   "2019-06-21T18:25Z", "--step", "10min", "--size", "9", "--aod", "0.05",
                                   "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert "BSRN" in res.output
    table = pd.read_csv(out, index_col=0)
    assert len(table) == 2 and {"ghi_obs", "dni_obs", "dhi_obs", "clear"} <= set(table.columns)
    for k, t in enumerate(pd.to_datetime(["2019-06-21T18:15Z", "2019-06-21T18:25Z"], utc=True)):
        expected = truth.loc[[t, t + pd.Timedelta("1min")], "ghi"].mean()
        assert table["ghi_obs"].iloc[k] == pytest.approx(expected)
    # The clear-sky simulation and the clear-sky "observations" agree to ~10 %.
    assert np.allclose(table["ghi"], table["ghi_obs"], rtol=0.1)


def test_cli_ghi_midc_without_position_is_a_clear_error(tmp_path, truth):
    from swim.cli.main import app

    out = tmp_path / "ghi.csv"
    res = CliRunner().invoke(app, ["ghi", "--observed", str(_write(tmp_path / "bms.csv", _midc_text(truth))),
                                   "--start", "2019-06-21T18:15Z", "--end", "2019-06-21T18:25Z", "--out", str(out)])
    assert res.exit_code == 2 and "error" in res.output and "--elevation" in res.output
    assert "Traceback" not in res.output and not out.exists()
