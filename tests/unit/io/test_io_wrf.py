"""Unit tests of swim.io.wrf on a small synthetic wrfout-like dataset."""

import logging

import numpy as np
import pytest
import xarray as xr

from swim.constants import DEFAULT_EFFECTIVE_RADIUS, R_DRY_AIR, STANDARD_GRAVITY
from swim.errors import SwimInputError
from swim.io import open_scene, read_wrf
from swim.io.wrf import wrf_times

NT, NZ, NY, NX = 2, 4, 3, 5


def _wrf(**drop_or_set):
    """A tiny wrfout-like dataset: flat terrain at 100 m, w-levels every 500 m, isothermal theta = 300 K."""
    z_w = 100.0 + 500.0 * np.arange(NZ + 1)
    ph_total = np.broadcast_to((z_w * STANDARD_GRAVITY)[None, :, None, None], (NT, NZ + 1, NY, NX))
    p = np.broadcast_to(np.linspace(95000.0, 80000.0, NZ)[None, :, None, None], (NT, NZ, NY, NX)).copy()
    qc = np.zeros((NT, NZ, NY, NX))
    qc[:, 1, 1, 2] = 1e-3
    qc[:, 0, 0, 0] = -1e-15
    lat = np.broadcast_to(np.linspace(39.9, 40.1, NY)[None, :, None], (NT, NY, NX))
    lon = np.broadcast_to(np.linspace(-105.2, -104.8, NX)[None, None, :], (NT, NY, NX))
    d4 = ("Time", "bottom_top", "south_north", "west_east")
    d4w = ("Time", "bottom_top_stag", "south_north", "west_east")
    d3 = ("Time", "south_north", "west_east")
    ds = xr.Dataset(
        {
            "Times": ("Time", np.array([b"2020-07-01_12:00:00", b"2020-07-01_13:00:00"])),
            "PH": (d4w, np.zeros((NT, NZ + 1, NY, NX)), {"units": "m2 s-2"}),
            "PHB": (d4w, ph_total.copy(), {"units": "m2 s-2"}),
            "P": (d4, np.zeros((NT, NZ, NY, NX)), {"units": "Pa"}),
            "PB": (d4, p, {"units": "Pa"}),
            "T": (d4, np.zeros((NT, NZ, NY, NX)), {"units": "K"}),
            "QVAPOR": (d4, np.full((NT, NZ, NY, NX), 0.01), {"units": "kg kg-1"}),
            "QCLOUD": (d4, qc, {"units": "kg kg-1"}),
            "RE_CLOUD": (d4, np.where(qc > 0, 12.0, 0.0), {"units": "um"}),
            "HGT": (d3, np.full((NT, NY, NX), 100.0), {"units": "m"}),
            "XLAT": (d3, lat.copy(), {"units": "degree_north"}),
            "XLONG": (d3, lon.copy(), {"units": "degree_east"}),
            "XLAND": (d3, np.where(np.arange(NX)[None, None, :] < 2, 2.0, 1.0) * np.ones((NT, NY, NX))),
            "ALBEDO": (d3, np.full((NT, NY, NX), 18.0), {"units": "%"}),
        },
        attrs={"TITLE": " OUTPUT FROM WRF V4.5 MODEL", "CEN_LAT": 10.0, "CEN_LON": 10.0, "DX": 1000.0},
    )
    for key, value in drop_or_set.items():
        if value is None:
            ds = ds.drop_vars(key)
        else:
            ds[key] = value
    return ds


def test_heights_density_contents():
    s = read_wrf(_wrf())
    np.testing.assert_allclose(s["height"].values[:, 0, 0], [350.0, 850.0, 1350.0, 1850.0])
    p = np.linspace(95000.0, 80000.0, NZ)[1]
    t = 300.0 * (p / 1e5) ** 0.2857
    rho = p / (R_DRY_AIR * t * (1 + 0.608 * 0.01))
    assert s["cloud_liquid_content"].values[1, 1, 2] == pytest.approx(1e-3 * rho, rel=1e-12)
    assert s["cloud_liquid_content"].values.min() == 0.0  # the -1e-15 mixing ratio was clipped
    assert s["cloud_liquid_effective_radius"].values[1, 1, 2] == pytest.approx(12e-6)
    assert s["cloud_liquid_effective_radius"].values[0, 0, 0] == DEFAULT_EFFECTIVE_RADIUS["cloud_liquid"]
    assert s.get("rain_content") is None
    np.testing.assert_array_equal(s["land_mask"].values[0], [0, 0, 1, 1, 1])
    np.testing.assert_allclose(s["surface_albedo"].values, 0.18)
    assert s.attrs["reference_lat"] == pytest.approx(40.0, abs=1e-3)  # grid centre, not CEN_LAT
    assert s.attrs["reference_lon"] == pytest.approx(-105.0, abs=1e-3)
    assert s.attrs["wrf_dx"] == 1000.0


def test_no_qvapor_uses_temperature(caplog):
    with caplog.at_level(logging.INFO, logger="swim.io.wrf"):
        s = read_wrf(_wrf(QVAPOR=None))
    p = np.linspace(95000.0, 80000.0, NZ)[1]
    rho = p / (R_DRY_AIR * 300.0 * (p / 1e5) ** 0.2857)
    assert s["cloud_liquid_content"].values[1, 1, 2] == pytest.approx(1e-3 * rho, rel=1e-12)
    assert "QVAPOR" in caplog.text


def test_radius_zero_in_cloud_gets_default():
    ds = _wrf()
    ds["RE_CLOUD"] = ds["RE_CLOUD"] * 0.0
    s = read_wrf(ds)
    assert s["cloud_liquid_effective_radius"].values[1, 1, 2] == DEFAULT_EFFECTIVE_RADIUS["cloud_liquid"]


def test_radius_bad_units():
    ds = _wrf()
    ds["RE_CLOUD"].attrs["units"] = "furlong"
    with pytest.raises(SwimInputError, match="RE_CLOUD"):
        read_wrf(ds)


def test_landmask_preferred_and_xtime_fallback():
    ds = _wrf(Times=None)
    ds["LANDMASK"] = (("Time", "south_north", "west_east"), np.ones((NT, NY, NX)))
    ds["XTIME"] = ("Time", np.array([720.0, 780.0]), {"description": "minutes since 2020-07-01 00:00:00"})
    assert wrf_times(ds) == [np.datetime64("2020-07-01T12:00"), np.datetime64("2020-07-01T13:00")]
    s = read_wrf(ds, time="2020-07-01T13:00")
    assert s["time"].values == np.datetime64("2020-07-01T13:00")
    assert np.all(s["land_mask"].values == 1)


def test_simulation_start_xtime():
    ds = _wrf(Times=None)
    ds["XTIME"] = ("Time", np.array([0.0, 90.0]), {"description": "minutes since simulation start"})
    ds.attrs["SIMULATION_START_DATE"] = "2020-07-01_12:00:00"
    assert wrf_times(ds)[1] == np.datetime64("2020-07-01T13:30")


def test_time_errors():
    with pytest.raises(SwimInputError, match="available times"):
        read_wrf(_wrf(), time="2020-07-01T16:00")
    with pytest.raises(SwimInputError, match="out of range"):
        read_wrf(_wrf(), time=5)
    with pytest.raises(SwimInputError, match="no Times"):
        read_wrf(_wrf(Times=None), time="2020-07-01T12:00")
    assert "time" not in read_wrf(_wrf(Times=None)).coords


def test_missing_and_bad_fields():
    with pytest.raises(SwimInputError, match="XLAT"):
        read_wrf(_wrf(XLAT=None))
    ds = _wrf()
    ds["QCLOUD"][0, 2, 2, 2] = np.nan
    with pytest.raises(SwimInputError, match="QCLOUD.*non-finite"):
        read_wrf(ds)
    ds = _wrf()
    ds["QCLOUD"] = ds["QCLOUD"] * 1000.0  # g/kg given as kg/kg
    with pytest.raises(SwimInputError, match="cloud_liquid_content.*g m-3 or g kg-1"):
        read_wrf(ds)


def test_open_scene_dispatches_wrf(tmp_path):
    path = tmp_path / "wrfout_d01_2020-07-01_12:00:00"
    _wrf().to_netcdf(path)
    s = open_scene(path, time=1)
    assert s["time"].values == np.datetime64("2020-07-01T13:00")
    assert s["height"].shape == (NZ, NY, NX)


# ----------------------------------------------------------------------------------------------------- surface


def _wrf_surface(**extra):
    """The tiny dataset with land use (USGS), a snow-free background albedo, snow cover and 10 m wind."""
    d3 = ("Time", "south_north", "west_east")
    ds = _wrf()
    lu = np.full((NY, NX), 14.0)  # evergreen needleleaf forest
    lu[:, :2] = 16.0  # water where XLAND = 2
    ds["LU_INDEX"] = (("south_north", "west_east"), lu)  # no Time dim, as in the Tibet sample
    ds["ALBBCK"] = (d3, np.full((NT, NY, NX), 0.12), {"units": "-"})
    snowc = np.zeros((NT, NY, NX))
    snowc[:, 2, 4] = 1.0
    snowc[:, 2, 3] = 0.5
    ds["SNOWC"] = (d3, snowc)
    ds["U10"] = (d3, np.full((NT, NY, NX), 3.0), {"units": "m s-1"})
    ds["V10"] = (d3, np.full((NT, NY, NX), -4.0), {"units": "m s-1"})
    ds.attrs["MMINLU"] = "USGS"
    for key, value in extra.items():
        ds[key] = value
    return ds


def test_surface_albedo_spectral_shape_snow_and_wind():
    from swim.surface.albedo import visible_mean
    from swim.surface.landuse import landuse_classes

    s = read_wrf(_wrf_surface())
    a = s["surface_albedo"].values
    forest = landuse_classes("USGS")[14]
    # snow-free ALBBCK (shortwave) with the forest's spectral shape: a = a_forest * 0.12 / A_forest, also under snow
    expect = np.array(forest.albedo) * 0.12 / forest.shortwave_albedo
    for j, i in ((0, 3), (2, 3), (2, 4)):
        np.testing.assert_allclose(a[:, j, i], expect)
    assert a[2, 0, 3] < a[1, 0, 3]  # forest: darker in the blue
    water = landuse_classes("USGS")[16]
    np.testing.assert_allclose(a[:, 0, 0], np.array(water.albedo) * 0.12 / water.shortwave_albedo)
    assert a[2, 0, 0] > a[0, 0, 0]  # water: bluer than red
    np.testing.assert_array_equal(s["snow_cover"].values[2, 3:], [0.5, 1.0])  # SNOWC, no SNOALB
    assert s["snow_cover"].values[0, 0] == 0.0
    np.testing.assert_allclose(s["wind_speed_10m"].values, 5.0)
    assert s["wind_speed_10m"].attrs["units"] == "m s-1"
    # albedo_band="visible": the visible mean of the result equals ALBBCK
    v = read_wrf(_wrf_surface(), albedo_band="visible")
    assert visible_mean(v["surface_albedo"].values)[0, 3] == pytest.approx(0.12)


def test_albedo_with_snow_included_is_taken_out():
    from swim.surface.albedo import DEFAULT_SNOW_SHORTWAVE_ALBEDO
    from swim.surface.landuse import landuse_classes

    ds = _wrf_surface().drop_vars("ALBBCK")
    albedo = np.full((NT, NY, NX), 0.12)
    albedo[:, 2, 3] = 0.5 * 0.12 + 0.5 * DEFAULT_SNOW_SHORTWAVE_ALBEDO  # half snow on a 0.12 background
    albedo[:, 2, 4] = 0.6  # full snow: the background is hidden
    ds["ALBEDO"] = (("Time", "south_north", "west_east"), albedo, {"units": "-"})
    s = read_wrf(ds)
    a = s["surface_albedo"].values
    np.testing.assert_allclose(a[:, 2, 3], a[:, 1, 3])
    np.testing.assert_allclose(a[:, 2, 4], landuse_classes("USGS")[14].albedo)


def test_snoalb_reduces_the_visible_snow_cover():
    snoalb = np.full((NT, NY, NX), 0.4)  # snow under a conifer canopy
    s = read_wrf(_wrf_surface(SNOALB=(("Time", "south_north", "west_east"), snoalb)))
    f = s["snow_cover"].values
    assert 0.0 < f[2, 4] < 0.6 and 0.0 < f[2, 3] < f[2, 4]
    assert f[0, 0] == 0.0


def test_unknown_landuse_scheme_gives_flat_albedo(caplog):
    ds = _wrf_surface().drop_vars(["SNOWC"])
    ds.attrs["MMINLU"] = "NLCD40"
    with caplog.at_level(logging.WARNING, logger="swim.surface.landuse"):
        s = read_wrf(ds)
    assert "NLCD40" in caplog.text
    np.testing.assert_allclose(s["surface_albedo"].values, 0.12)


def test_bad_landuse_index_names_variable():
    lu = np.full((NY, NX), 99.0)
    with pytest.raises(SwimInputError, match="LU_INDEX"):
        read_wrf(_wrf_surface(LU_INDEX=(("south_north", "west_east"), lu)))


def test_snow_from_swe_and_sea_ice():
    d3 = ("Time", "south_north", "west_east")
    swe = np.zeros((NT, NY, NX))
    swe[:, 1, 4] = 100.0  # deep snow: full cover
    ice = np.zeros((NT, NY, NX))
    ice[:, 0, 0] = 0.7
    ds = _wrf_surface().drop_vars("SNOWC")
    ds["SNOW"] = (d3, swe, {"units": "kg m-2"})
    ds["SEAICE"] = (d3, ice)
    s = read_wrf(ds)
    assert s["snow_cover"].values[1, 4] == 1.0
    assert s["snow_cover"].values[0, 0] == pytest.approx(0.7)
    assert s["snow_cover"].values[1, 3] == 0.0


def test_a_wrfout_without_cloud_water_says_so(caplog):
    with caplog.at_level(logging.WARNING, logger="swim.io.wrf"):
        read_wrf(_wrf().drop_vars(["QCLOUD", "RE_CLOUD"]), time="2020-07-01T12:00")
    assert "none of QCLOUD" in caplog.text and "clear sky" in caplog.text
    caplog.clear()
    ds = _wrf()
    ds["QICE"] = ds["QCLOUD"]
    with caplog.at_level(logging.WARNING, logger="swim.io.wrf"):
        read_wrf(ds.drop_vars(["QCLOUD", "RE_CLOUD"]), time="2020-07-01T12:00")
    assert "no QCLOUD" in caplog.text and "QICE" in caplog.text
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="swim.io.wrf"):
        read_wrf(_wrf(), time="2020-07-01T12:00")
    assert "QCLOUD" not in caplog.text


def test_complex_wrf_fields_are_refused():
    ds = _wrf()
    ds["QCLOUD"] = ds["QCLOUD"].astype(complex)
    with pytest.raises(SwimInputError, match="QCLOUD holds complex128 values; expected real numbers"):
        read_wrf(ds, time="2020-07-01T12:00")


def test_a_truncated_netcdf3_wrfout_is_named_truncated(tmp_path):
    """WRF writes netCDF-3 by default; a copy cut short reads back zeros for its tail in netCDF-C."""
    path = tmp_path / "wrfout_d01_2020-07-01_12:00:00"
    _wrf().to_netcdf(path, format="NETCDF3_64BIT")
    assert open_scene(path, time="2020-07-01T12:00")["height"].shape == (NZ, NY, NX)
    data = path.read_bytes()
    cut = tmp_path / "wrfout_d01_cut"
    cut.write_bytes(data[: int(0.7 * len(data))])
    with pytest.raises(SwimInputError, match="is truncated or damaged: its netCDF-3 header describes more data"):
        open_scene(cut, time="2020-07-01T12:00")
