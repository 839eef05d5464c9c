"""Unit tests of swim.io.wps on small synthetic geo_em / met_em-like datasets."""

import logging

import numpy as np
import pytest
import xarray as xr

from swim.errors import SwimInputError
from swim.io import open_scene, read_wps_geogrid, validate_scene
from swim.io.wps import N_LEVELS, clear_sky_levels
from swim.surface.albedo import visible_mean
from swim.surface.landuse import landuse_classes

NY, NX = 4, 5
D2 = ("Time", "south_north", "west_east")


def _geo_em(**extra):
    """geo_em-like: terrain with a sea-level strip, lat/lon, no land use (like the Greenland samples)."""
    terrain = np.tile(np.linspace(0.0, 2000.0, NX), (NY, 1))
    terrain[:, 0] = 0.0
    lat = np.broadcast_to(np.linspace(69.0, 69.3, NY)[:, None], (NY, NX))
    lon = np.broadcast_to(np.linspace(-50.4, -49.6, NX)[None, :], (NY, NX))
    ds = xr.Dataset(
        {
            "Times": ("Time", np.array([b"0000-00-00_00:00:00"])),
            "HGT_M": (D2, terrain[None].copy(), {"units": "meters MSL"}),
            "XLAT_M": (D2, lat[None].copy(), {"units": "degrees latitude"}),
            "XLONG_M": (D2, lon[None].copy(), {"units": "degrees longitude"}),
        },
        attrs={"TITLE": "OUTPUT FROM GEOGRID V3.8.1", "DX": 6000.0, "DY": 6000.0, "MAP_PROJ": 2,
               "SIMULATION_START_DATE": "0000-00-00_00:00:00"},
    )
    for key, value in extra.items():
        ds[key] = value
    return ds


def _met_em():
    """met_em-like: land use fractions, monthly albedo (percent), snow, surface winds, a valid time."""
    ds = _geo_em()
    ds["Times"] = ("Time", np.array([b"2005-08-28_12:00:00"]))
    ds.attrs.update({"TITLE": "OUTPUT FROM METGRID V3.0.1", "MMINLU": "USGS", "NUM_LAND_CAT": 24, "ISWATER": 16})
    land = np.ones((NY, NX))
    land[:, 0] = 0.0
    ds["LANDMASK"] = (D2, land[None])
    f = np.zeros((24, NY, NX))
    f[13] = 1.0  # evergreen needleleaf forest
    f[13, :, 0], f[15, :, 0] = 0.0, 1.0  # water column
    f[13, 0, 4], f[6, 0, 4] = 0.5, 0.5  # half forest, half grassland
    ds["LANDUSEF"] = (("Time", "z-dimension0024", "south_north", "west_east"), f[None])
    lu = np.where(land > 0, 14.0, 16.0)
    ds["LU_INDEX"] = (D2, lu[None])
    months = (np.arange(1, 13, dtype=float) + 10.0)[:, None, None] * np.ones((12, NY, NX))  # 11 ... 22 %
    ds["ALBEDO12M"] = (("Time", "z-dimension0012", "south_north", "west_east"), months[None], {"units": "percent"})
    ds["SNOALB"] = (D2, np.full((1, NY, NX), 50.0), {"units": "percent"})
    swe = np.zeros((1, NY, NX))
    swe[0, 3, 4] = 200.0
    ds["SNOW"] = (D2, swe, {"units": "kg m-2"})
    nlev = 3
    pres = np.broadcast_to(np.array([80000.0, 100000.0, 85000.0])[:, None, None], (nlev, NY, NX)).copy()
    ds["PRES"] = (("Time", "num_metgrid_levels", "south_north", "west_east"), pres[None])
    ds["PSFC"] = (D2, np.full((1, NY, NX), 80000.0), {"units": "Pa"})
    uu = np.zeros((nlev, NY, NX + 1))
    uu[0] = 6.0
    vv = np.zeros((nlev, NY + 1, NX))
    vv[0] = np.linspace(-8.0, 8.0, NY + 1)[:, None]  # destaggered: -6, -2, 2, 6
    ds["UU"] = (("Time", "num_metgrid_levels", "south_north", "west_east_stag"), uu[None])
    ds["VV"] = (("Time", "num_metgrid_levels", "south_north_stag", "west_east"), vv[None])
    return ds


def test_clear_sky_levels_follow_terrain():
    terrain = np.array([[0.0, 1500.0], [3000.0, 8000.0]])
    h = clear_sky_levels(terrain, n_levels=10, depth_m=12_000.0, first_layer_m=100.0)
    assert h.shape == (10, 2, 2)
    assert np.all(np.diff(h, axis=0) > 0)
    assert np.all(h[0] > terrain)
    assert h[0, 0, 0] == pytest.approx(50.0)  # half the first layer over sea level
    # over sea level: geometric layers dz0 r^k, the top interface 12 km above the highest terrain
    m = h[:, 0, 0]
    ratios = np.diff(m)[1:] / np.diff(m)[:-1]
    np.testing.assert_allclose(ratios, ratios[0])
    r = ratios[0]
    assert m[-1] + 0.5 * 100.0 * r**9 == pytest.approx(8000.0 + 12_000.0)
    # Gal-Chen: the levels converge towards the common top
    assert np.ptp(h[-1]) < np.ptp(h[0]) / 5


def test_geo_em_terrain_only(caplog):
    with caplog.at_level(logging.INFO, logger="swim.io.wps"):
        s = read_wps_geogrid(_geo_em())
    assert (s.sizes["z"], s.sizes["y"], s.sizes["x"]) == (N_LEVELS, NY, NX)
    np.testing.assert_array_equal(s["terrain_height"].values, _geo_em()["HGT_M"].values[0])
    np.testing.assert_array_equal(s["land_mask"].values[:, 0], 0)  # HGT_M == 0: water
    np.testing.assert_array_equal(s["land_mask"].values[:, 1:], 1)
    assert "LANDMASK" in caplog.text
    for absent in ("surface_albedo", "snow_cover", "wind_speed_10m", "cloud_liquid_content"):
        assert s.get(absent) is None
    assert "time" not in s.coords  # 0000-00-00: no valid time
    assert s.attrs["wrf_dx"] == 6000.0
    xr.testing.assert_identical(validate_scene(s), s)


def test_geo_em_time_and_snow_above():
    s = read_wps_geogrid(_geo_em(), time="2021-03-01T14:00Z", snow_above_m=1200.0)
    assert s["time"].values == np.datetime64("2021-03-01T14:00")
    high = s["terrain_height"].values > 1200.0
    assert high.any() and not high.all()
    np.testing.assert_array_equal(s["snow_cover"].values, high.astype(float))
    assert s.get("surface_albedo") is None  # still no albedo information: the renderer's default


def test_met_em_albedo_month_landuse_snow_wind():
    s = read_wps_geogrid(_met_em())
    assert s["time"].values == np.datetime64("2005-08-28T12:00")
    assert "month 8" in s.attrs["albedo_source"] and "LANDUSEF" in s.attrs["albedo_source"]
    assert s.attrs["landuse_scheme"] == "USGS"
    forest = landuse_classes("USGS")[14]
    grass = landuse_classes("USGS")[7]
    a = s["surface_albedo"].values
    # August ALBEDO12M = 18 %: a = a_forest * 0.18 / A_forest (shortwave matching)
    np.testing.assert_allclose(a[:, 1, 2], np.array(forest.albedo) * 0.18 / forest.shortwave_albedo)
    # half forest, half grass: the shape of the 50/50 mix, scaled by 0.18 / its shortwave albedo
    mix = 0.5 * np.array(forest.albedo) + 0.5 * np.array(grass.albedo)
    mix_sw = 0.5 * forest.shortwave_albedo + 0.5 * grass.shortwave_albedo
    np.testing.assert_allclose(a[:, 0, 4], mix * 0.18 / mix_sw)
    # deep snow (full cover) on the forest, whose snow-covered albedo SNOALB is 50 %: the albedo stays the
    # snow-free one, the snow cover is the fraction that makes the visible mean that of the 50 % snow
    from swim.surface.albedo import DEFAULT_SNOW_ALBEDO, DEFAULT_SNOW_SHORTWAVE_ALBEDO

    np.testing.assert_allclose(a[:, 3, 4], a[:, 1, 2])
    f = s["snow_cover"].values
    assert f[1, 2] == 0.0
    target = visible_mean(DEFAULT_SNOW_ALBEDO * 0.5 / DEFAULT_SNOW_SHORTWAVE_ALBEDO)
    assert visible_mean((1 - f[3, 4]) * a[:, 3, 4] + f[3, 4] * DEFAULT_SNOW_ALBEDO) == pytest.approx(target)
    assert 0.5 < f[3, 4] < 0.7
    np.testing.assert_array_equal(s["land_mask"].values[:, 0], 0)
    np.testing.assert_allclose(s["wind_speed_10m"].values[:, 0], np.hypot(6.0, [-6.0, -2.0, 2.0, 6.0]))


def test_met_em_month_options():
    visible = read_wps_geogrid(_met_em(), month=1, albedo_band="visible")
    assert visible_mean(visible["surface_albedo"].values)[1, 2] == pytest.approx(0.11)
    no_time = _met_em().drop_vars("Times")
    no_time.attrs["SIMULATION_START_DATE"] = "0000-00-00_00:00:00"
    annual = read_wps_geogrid(no_time, albedo_band="visible")
    assert "annual mean" in annual.attrs["albedo_source"]
    assert visible_mean(annual["surface_albedo"].values)[1, 2] == pytest.approx(0.165)
    for bad in (0, 13, 2.5):
        with pytest.raises(SwimInputError, match="month"):
            read_wps_geogrid(_met_em(), month=bad)
    with pytest.raises(SwimInputError, match="1.5|01:30"):
        read_wps_geogrid(_met_em(), time="2005-08-29T12:00Z")


def test_landuse_index_without_fractions():
    ds = _met_em().drop_vars("LANDUSEF")
    s = read_wps_geogrid(ds)
    assert "LU_INDEX" in s.attrs["albedo_source"]
    water = landuse_classes("USGS")[16]
    np.testing.assert_allclose(s["surface_albedo"].values[:, 2, 0], np.array(water.albedo) * 0.18 / water.shortwave_albedo)


def test_wps_errors_and_open_scene(tmp_path):
    with pytest.raises(SwimInputError, match="HGT_M"):
        read_wps_geogrid(_geo_em().drop_vars("HGT_M"))
    with pytest.raises(SwimInputError, match="not found"):
        read_wps_geogrid(tmp_path / "geo_em.d01.nc")
    bad = _met_em()
    bad["ALBEDO12M"] = bad["ALBEDO12M"] * 10.0  # 110-220 %
    with pytest.raises(SwimInputError, match=r"albedo.*outside \[0, 1\]"):
        read_wps_geogrid(bad)
    path = tmp_path / "met_em.d01.2005-08-28_12:00:00"  # WPS names have no .nc suffix
    _met_em().to_netcdf(path)
    s = open_scene(path, month=8)
    assert s.attrs["source"].startswith(str(path))
    xr.testing.assert_allclose(s.drop_attrs(), read_wps_geogrid(_met_em()).drop_attrs())
