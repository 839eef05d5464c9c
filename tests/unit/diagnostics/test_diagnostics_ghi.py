"""GHI forward-operator helpers (swim.diagnostics.ghi), the SURFRAD reader (swim.io.surfrad), the comparison helpers
(swim.io.observations) and ``swim ghi``."""

import math

import numpy as np
import pandas as pd
import pvlib
import pytest
import typer
from typer.testing import CliRunner

from swim.cli.ghi import ghi
from swim.diagnostics.ghi import (aerosol_for_site, attach_observations, clear_site_scene, error_statistics,
                                  plot_ghi, pvlib_clear_sky, site_aod_550, time_range)
from swim.errors import SwimInputError
from swim.io.observations import clear_periods, observations_at, observed_albedo, observed_precipitable_water
from swim.io.surfrad import SURFRAD_COLUMNS, read_surfrad

SURFRAD_NAME = "surfrad-slv16001.dat"


@pytest.fixture(scope="module")
def surfrad_path(shared_data):
    path = shared_data / "obs" / SURFRAD_NAME
    if not path.is_file():
        pytest.skip(f"{path} not found")
    return path


@pytest.fixture(scope="module")
def alamosa(surfrad_path):
    return read_surfrad(surfrad_path)


# ---------------------------------------------------------------------------------------------------------------
# SURFRAD reader


@pytest.mark.realdata
def test_surfrad_reader_shape_index_and_header(alamosa):
    assert len(alamosa) == 1440  # one row per minute
    assert isinstance(alamosa.index, pd.DatetimeIndex) and str(alamosa.index.tz) == "UTC"
    assert alamosa.index[0] == pd.Timestamp("2016-01-01T00:00Z")
    assert alamosa.index[-1] == pd.Timestamp("2016-01-01T23:59Z")
    assert ((alamosa.index[1:] - alamosa.index[:-1]) == pd.Timedelta("1min")).all()
    for col in ("zenith", "ghi", "ghi_qc", "dni", "dni_qc", "dhi", "dhi_qc", "uw_solar", "temp_air",
                "relative_humidity", "pressure_hpa"):
        assert col in alamosa
    assert alamosa.shape[1] == len(SURFRAD_COLUMNS)
    assert alamosa["ghi_qc"].dtype.kind == "i"
    assert alamosa.attrs["station"] == "Alamosa"
    assert alamosa.attrs["latitude"] == 37.70 and alamosa.attrs["elevation_m"] == 2317.0
    # The header says 105.92: degrees west; the reader stores east-positive longitude.
    assert alamosa.attrs["longitude_in_file"] == 105.92 and alamosa.attrs["longitude"] == -105.92
    # Missing values (-9999.9: UV-B and PAR are not measured here) become NaN.
    assert alamosa["uvb"].isna().all() and not (alamosa == -9999.9).any().any()


@pytest.mark.realdata
def test_surfrad_values_match_the_file_and_pvlibs_reader(alamosa, surfrad_path):
    row = alamosa.loc["2016-01-01T19:00Z"]  # 19:00 line of the file: zen 60.69, dw_psp 579.1, direct 1075.1
    assert row["zenith"] == 60.69 and row["ghi"] == 579.1 and row["dni"] == 1075.1 and row["dhi"] == 59.1
    assert row["temp_air"] == -6.5 and row["relative_humidity"] == 40.2 and row["pressure_hpa"] == 778.2
    theirs, _ = pvlib.iotools.read_surfrad(surfrad_path)
    np.testing.assert_array_equal(alamosa["ghi"].values, theirs["ghi"].values)
    np.testing.assert_array_equal(alamosa["dni"].values, theirs["dni"].values)
    np.testing.assert_array_equal(alamosa.index, theirs.index)


@pytest.mark.realdata
def test_surfrad_night_and_day_values_are_physical(alamosa):
    night = alamosa["zenith"] > 90.0
    assert night.sum() > 800  # a winter night
    assert alamosa.loc[night, "ghi"].abs().max() < 5.0  # thermal offset of the pyranometer only
    assert alamosa.loc[night, "dni"].abs().max() < 5.0
    day = alamosa["zenith"] < 70.0
    assert (alamosa.loc[day, "ghi"] > 300).all()
    # Closure of the three instruments: GHI = DNI cos(zenith) + DHI within 3 % at noon.
    noon = alamosa.loc["2016-01-01T18:30Z":"2016-01-01T19:30Z"]
    closure = noon["dni"] * np.cos(np.radians(noon["zenith"])) + noon["dhi"]
    assert np.allclose(closure, noon["ghi"], rtol=0.03)


@pytest.mark.realdata
def test_surfrad_zenith_matches_pvlib_solar_position(alamosa):
    """The zen column is the refracted zenith at the middle of the minute ending at the stamp (SPA)."""
    day = alamosa["zenith"] < 85.0
    pos = pvlib.solarposition.get_solarposition(alamosa.index[day] - pd.Timedelta(seconds=30), 37.70, -105.92,
                                                altitude=2317.0)
    assert np.max(np.abs(pos["apparent_zenith"].values - alamosa.loc[day, "zenith"].values)) < 0.1


@pytest.mark.realdata
def test_surfrad_clear_periods_and_site_parameters(alamosa):
    clear = clear_periods(alamosa)
    assert clear.dtype == bool and clear.index.equals(alamosa.index)
    low = alamosa["zenith"] < 85.0
    assert clear[low].mean() > 0.9  # 2016-01-01 at Alamosa was cloud-free
    assert not clear[alamosa["zenith"] >= 85.0].any()
    # Gueymard (1994) by hand at 19:00 (-6.5 degC, 40.2 %): e_s (Gueymard 1993) and H_v give 0.32 cm.
    t = -6.5 + 273.15
    es = math.exp(22.330 - 49.140 * (100 / t) - 10.922 * (100 / t) ** 2 - 0.39015 * t / 100)
    rho_v = 216.7 * 0.402 * es / t
    hv = 0.4976 + 1.5265 * t / 273.15 + math.exp(13.6897 * t / 273.15 - 14.9188 * (t / 273.15) ** 3)
    assert 0.1 * hv * rho_v == pytest.approx(0.32, abs=0.01)
    assert observed_precipitable_water(alamosa) == pytest.approx(0.33, abs=0.05)
    assert 0.1 < observed_albedo(alamosa) < 0.3  # dry winter grass, no snow (uw/dw ~ 0.18 at noon)


@pytest.mark.realdata
def test_observations_at_interval_centres(alamosa):
    times = pd.DatetimeIndex(["2016-01-01T19:00Z", "2016-01-02T01:00Z"]).as_unit("s")  # any time unit
    got = observations_at(alamosa, times)
    # 19:00 is the centre of the minutes ending 19:00 and 19:01: their mean.
    expected = alamosa.loc[["2016-01-01T19:00Z", "2016-01-01T19:01Z"], "ghi"].mean()
    assert got.loc[times[0], "ghi"] == pytest.approx(expected)
    assert np.isnan(got.loc[times[1], "ghi"])  # outside the record


def _write(tmp_path, header, rows):
    path = tmp_path / "x.dat"
    path.write_text("\n".join(header + rows) + "\n")
    return path


_ROW = (" 2016   1  1  1 19  0 19.000  60.69   579.1 0    101.1 0  1075.1 0    59.1 0   200.0 0   270.0 0   270.0 0"
        "   300.0 0   270.0 0   270.0 0 -9999.9 1 -9999.9 1   478.0 0  -100.0 0   378.0 0    -6.5 0    40.2 0     2.0 0"
        "   180.0 0   778.2 0")


def test_surfrad_reader_errors(tmp_path):
    header = [" Alamosa", "   37.70  105.92 2317 m version 1"]
    with pytest.raises(SwimInputError, match="not found"):
        read_surfrad(tmp_path / "missing.dat")
    with pytest.raises(SwimInputError, match="line 2"):
        read_surfrad(_write(tmp_path, [" Alamosa", " north somewhere"], [_ROW]))
    with pytest.raises(SwimInputError, match="line 3: expected 48 fields"):
        read_surfrad(_write(tmp_path, header, [_ROW.rsplit(" ", 2)[0]]))
    with pytest.raises(SwimInputError, match="non-numeric"):
        read_surfrad(_write(tmp_path, header, [_ROW.replace("579.1", "abc")]))
    with pytest.raises(SwimInputError, match="month/day"):
        read_surfrad(_write(tmp_path, header, [_ROW.replace(" 2016   1  1  1 19", " 2016   1  2  1 19")]))
    with pytest.raises(SwimInputError, match="increase"):
        read_surfrad(_write(tmp_path, header, [_ROW, _ROW]))
    ok = read_surfrad(_write(tmp_path, header, [_ROW]))
    assert ok["ghi"].iloc[0] == 579.1 and np.isnan(ok["uvb"].iloc[0])


# ---------------------------------------------------------------------------------------------------------------
# helpers


def test_time_range():
    t = time_range("2016-01-01T15:00Z", "2016-01-01T17:00Z", "30min")
    assert len(t) == 5 and str(t.tz) == "UTC" and t[-1] == pd.Timestamp("2016-01-01T17:00Z")
    assert len(time_range("2016-01-01T15:00", "2016-01-01T15:00", "1h")) == 1
    for bad in [("2016-01-01T17:00Z", "2016-01-01T15:00Z", "30min"), ("2016-01-01", "2016-01-02", "0min"),
                ("2016-01-01", "2016-01-02", "soon"), ("tomorrow", "2016-01-02", "1h"),
                ("2016-01-01", "2017-01-01", "1min")]:
        with pytest.raises(SwimInputError):
            time_range(*bad)


def test_aerosol_for_site_puts_the_aod_above_the_site():
    from scipy.integrate import quad

    from swim.optics.aerosol import exponential_aerosol_extinction

    aer = aerosol_for_site(0.03, 2319.0, "continental")
    above, _ = quad(lambda h: float(exponential_aerosol_extinction(h, aer.aod_550, aer.scale_height_m)), 2319.0, 60_000.0)
    assert above == pytest.approx(0.03, rel=1e-6)
    assert site_aod_550(aer, 2319.0) == pytest.approx(0.03)
    assert aer.aod_550 == pytest.approx(0.03 * math.exp(2319.0 / 1500.0))
    with pytest.raises(SwimInputError):
        aerosol_for_site(-0.1, 0.0)


def test_clear_site_scene():
    scene = clear_site_scene(37.7, -105.92, 2317.0, surface_albedo=0.18)
    assert float(scene["terrain_height"].min()) == float(scene["terrain_height"].max()) == 2317.0
    assert float(scene["cloud_liquid_content"].max()) == 0.0
    assert float(scene["height"].min()) > 2317.0
    assert scene.attrs["reference_lat"] == 37.7
    with pytest.raises(SwimInputError):
        clear_site_scene(95.0, 0.0)
    with pytest.raises(SwimInputError):
        clear_site_scene(0.0, 0.0, elevation_m=12_000.0)


def test_pvlib_clear_sky_is_pvlibs_models():
    zen = pd.Series([0.0, 45.0, 80.0, 95.0], index=pd.Index([1, 2, 3, 4], name="k"))
    ref = pvlib_clear_sky(zen, elevation_m=1000.0, aod_550=0.1, angstrom_exponent=1.3, precipitable_water_cm=1.2,
                          ozone_atm_cm=0.31, pressure_pa=90_000.0, earth_sun_distance_au=0.99, surface_albedo=0.25)
    assert ref.index.equals(zen.index)
    am = pvlib.atmosphere.get_relative_airmass(45.0, "kastenyoung1989")
    bird = pvlib.clearsky.bird(45.0, am, 0.1 * (380 / 550) ** -1.3, 0.1 * (500 / 550) ** -1.3, 1.2, 0.31, 90_000.0,
                               dni_extra=1362.0 / 0.99**2, asymmetry=0.85, albedo=0.25)
    assert ref.loc[2, "bird_ghi"] == pytest.approx(float(bird["ghi"]))
    assert ref.loc[2, "bird_dni"] == pytest.approx(float(bird["dni"]))
    assert (ref.loc[4] == 0).all()  # night
    # All four models agree on a clear noon sky to 10 %.
    noon = ref.loc[1, ["bird_ghi", "ineichen_ghi", "solis_ghi", "spectrl2_ghi"]].values
    assert noon.max() / noon.min() < 1.1 and 900 < noon.min()


def test_error_statistics():
    s = error_statistics([110.0, 190.0, np.nan, 500.0], [100.0, 200.0, 50.0, 300.0], mask=[True, True, True, False])
    assert s["n"] == 2
    assert s["mbe"] == pytest.approx(0.0) and s["rmse"] == pytest.approx(10.0) and s["mae"] == pytest.approx(10.0)
    assert s["rmse_pct"] == pytest.approx(10.0 / 150.0 * 100)
    assert error_statistics([1.0], [np.nan])["n"] == 0
    with pytest.raises(SwimInputError):
        error_statistics([1.0, 2.0], [1.0])


def _fake_series():
    idx = pd.date_range("2016-01-01T15:00Z", periods=4, freq="1h", name="time")
    sim = pd.DataFrame({"ghi": [100.0, 300, 400, 200], "dni": [500.0, 900, 950, 700], "dhi": [30.0, 50, 55, 40],
                        "sun_zenith_deg": [80.0, 70, 62, 75], "rendered": True}, index=idx)
    obs = pd.DataFrame({"ghi": [110.0, 310, 390, np.nan], "dni": [520.0, 950, 1000, 720], "dhi": [28.0, 48, 60, 41],
                        "clear": [True, True, True, False]}, index=idx)
    return sim, obs


def test_attach_observations():
    sim, obs = _fake_series()
    both = attach_observations(sim, obs)
    assert list(both["ghi_obs"].iloc[:3]) == [110.0, 310.0, 390.0] and both["clear"].dtype == bool
    with pytest.raises(SwimInputError):
        attach_observations(sim, obs.iloc[:2])


def _has_matplotlib():
    from swim.diagnostics.ghi import matplotlib_pyplot

    try:
        matplotlib_pyplot()
    except ImportError:
        return False
    return True


def test_plot_ghi_writes_a_png(tmp_path):
    if not _has_matplotlib():
        pytest.skip("matplotlib is not installed")
    sim, obs = _fake_series()
    both = attach_observations(sim, obs)
    path = plot_ghi(both, obs, tmp_path / "ghi.png", clear=obs["clear"], title="test")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary file left


# ---------------------------------------------------------------------------------------------------------------
# CLI (errors and a night-only run that renders nothing)


@pytest.fixture(scope="module")
def app():
    application = typer.Typer()
    application.command()(ghi)
    return application


def test_cli_errors_exit_2_without_output(app, tmp_path):
    runner = CliRunner()
    out = tmp_path / "t.csv"
    for args in (["--lat", "37.7", "--lon", "-105.9", "--start", "2016-01-01T15:00Z", "--end", "2016-01-01T14:00Z"],
                 ["--lat", "37.7", "--lon", "-105.9", "--start", "2016-01-01T15:00Z", "--end", "2016-01-01T16:00Z",
                  "--step", "-5min"],
                 ["--start", "2016-01-01T15:00Z", "--end", "2016-01-01T16:00Z"],
                 ["--lat", "37.7", "--lon", "-105.9", "--start", "2016-01-01T15:00Z", "--end", "2016-01-01T16:00Z",
                  "--observed", str(tmp_path / "nope.dat")],
                 ["--lat", "37.7", "--lon", "-105.9", "--start", "2016-01-01T15:00Z", "--end", "2016-01-01T16:00Z",
                  "--band", "300"],
                 ["--lat", "97.7", "--lon", "-105.9", "--start", "2016-01-01T15:00Z", "--end", "2016-01-01T16:00Z"]):
        res = runner.invoke(app, args + ["--out", str(out)])
        assert res.exit_code == 2, (args, res.output)
        assert "error" in res.output
        assert not out.exists()


def test_cli_plot_without_matplotlib_is_a_clear_error(app, tmp_path):
    """Also where colour-science has put its MagicMock stand-ins into sys.modules (matplotlib missing)."""
    import colour.plotting  # noqa: F401  (installs the stand-ins when matplotlib is missing)

    if _has_matplotlib():
        pytest.skip("matplotlib is installed")
    res = CliRunner().invoke(app, ["--lat", "37.7", "--lon", "-105.92", "--start", "2016-01-01T06:00Z", "--end",
                                   "2016-01-01T07:00Z", "--out", str(tmp_path / "x.csv"), "--plot", str(tmp_path / "x.png")])
    assert res.exit_code == 2 and "matplotlib" in res.output
    assert not (tmp_path / "x.csv").exists() and not (tmp_path / "x.png").exists()
    sim, obs = _fake_series()
    with pytest.raises(ImportError, match="matplotlib"):
        plot_ghi(sim, obs, tmp_path / "y.png")
    assert not (tmp_path / "y.png").exists()


def test_cli_night_run_writes_a_csv(app, tmp_path):
    """Alamosa 06:00-08:00 UTC is night: nothing is rendered, the table holds zeros."""
    out = tmp_path / "night.csv"
    res = CliRunner().invoke(app, ["--lat", "37.7", "--lon", "-105.92", "--elevation", "2317", "--start",
                                   "2016-01-01T06:00Z", "--end", "2016-01-01T08:00Z", "--step", "1h", "--pw", "0.3",
                                   "--out", str(out)])
    assert res.exit_code == 0, res.output
    table = pd.read_csv(out, index_col=0)
    assert len(table) == 3 and (table["ghi"] == 0).all() and (~table["rendered"]).all()
    assert {"ghi", "dni", "dhi", "ghi_rel_546", "sun_zenith_deg", "bird_ghi"} <= set(table.columns)
    assert (table["sun_zenith_deg"] > 90).all()


def test_cli_quiet_reports_nothing_but_the_file_is_written(tmp_path, monkeypatch):
    """``swim -q ghi``: no progress bar and no report lines, the CSV written all the same."""
    from swim.cli import main as cli_main

    monkeypatch.setitem(cli_main.QUIET, "on", False)  # restored after the test: -q sets it for the process
    out = tmp_path / "night.csv"
    args = ["ghi", "--lat", "37.7", "--lon", "-105.92", "--elevation", "2317", "--start", "2016-01-01T06:00Z",
            "--end", "2016-01-01T07:00Z", "--step", "1h", "--pw", "0.3", "--out", str(out)]
    loud = CliRunner().invoke(cli_main.app, args)
    assert loud.exit_code == 0 and "wrote" in loud.output and "rendering" in loud.output, loud.output
    out.unlink()
    quiet = CliRunner().invoke(cli_main.app, ["-q", *args])
    assert quiet.exit_code == 0 and quiet.output.strip() == "", quiet.output
    assert out.is_file()
