"""Readers on the real data in ../shared/data (WRF Katrina and Tibet; WPS geo_em/met_em; RICO and stratocumulus LES).

Reference numbers from ../shared/data/README.md.
"""

import numpy as np
import pytest
import xarray as xr

from swim.errors import SwimInputError
from swim.frames import orthographic_xy
from swim.io import layer_thickness, open_scene, read_shdom_les, read_wps_geogrid, read_wrf, validate_scene
from swim.surface.albedo import visible_mean
from swim.surface.landuse import landuse_classes

pytestmark = pytest.mark.realdata

KATRINA = "wrf_katrina/ci_test_file.nc"
TIBET = "wrf_tibet/wrf_d01_allvars_cropped.nc"
MET_EM = "wrf_geo/met_em.d01.2005-08-28_12_00_00.nc"
GEO_EM = ("wrf_geo/geo_em_d01_polarstereo.nc", "wrf_geo/geo_em_d02_polarstereo.nc")
SPECIES_CONTENTS = ("cloud_liquid_content", "cloud_ice_content", "rain_content", "snow_content", "graupel_content")


def _water_path(scene):
    dz = layer_thickness(scene["height"].values, scene["terrain_height"].values)
    return sum(scene[name].values * dz for name in SPECIES_CONTENTS if name in scene).sum(axis=0)


@pytest.fixture(scope="module")
def katrina(shared_data):
    return read_wrf(shared_data / KATRINA)


@pytest.fixture(scope="module")
def tibet(shared_data):
    return read_wrf(shared_data / TIBET)


# ----------------------------------------------------------------------------------------------------- WRF Katrina


def test_katrina_shapes_variables_units(katrina):
    s = katrina
    assert (s.sizes["z"], s.sizes["y"], s.sizes["x"]) == (14, 48, 48)
    assert s["height"].dims == ("z", "y", "x")
    assert s["lat"].dims == ("y", "x")
    assert "cloud_liquid_content" in s and "rain_content" in s
    # WSM3 (MP_PHYSICS=3) keeps ice in QCLOUD and snow in QRAIN below 0 degC: the reader splits them.
    assert s.attrs.get("wrf_mp_physics", 3) == 3
    frozen = s["height"] > 5500.0  # well above the tropical melting level (~4.9 km)
    assert float(s["snow_content"].where(frozen).max()) > 1e-4
    # (the hurricane's warm core keeps a few cells above 0 degC even there)
    assert int(((s["rain_content"] > 0) & frozen).sum()) < 0.2 * int(((s["snow_content"] > 0) & frozen).sum())
    warm = s["height"] < 3000.0
    assert float(s["snow_content"].where(warm, 0).max()) == 0.0
    for absent in ("graupel_content", "surface_albedo", "land_mask"):
        assert s.get(absent) is None
    assert s["cloud_liquid_content"].attrs["units"] == "kg m-3"
    assert s["height"].attrs["units"] == "m"
    assert s["lat"].attrs["units"] == "degrees_north"
    for name in s.data_vars:
        assert "units" in s[name].attrs and "long_name" in s[name].attrs
    assert s["time"].values == np.datetime64("2005-08-28T12:00")
    # the file's attrs CEN_LAT/CEN_LON (parent-domain centre) are not used: the origin is the grid centre
    assert 21.8 < s.attrs["reference_lat"] < 25.7 and -91.7 < s.attrs["reference_lon"] < -87.4
    x, y = orthographic_xy(s["lat"].values, s["lon"].values, s.attrs["reference_lat"], s.attrs["reference_lon"])
    assert abs(x.mean()) < 20e3 and abs(y.mean()) < 20e3


def test_katrina_heights_and_contents(katrina):
    h = katrina["height"].values
    assert 20.0 < h[0].min() and h[0].max() < 60.0  # lowest mass level: some tens of metres
    assert 5000.0 < h[-1].max() < 7000.0  # model top about 6 km (only 14 levels kept)
    assert np.all(np.diff(h, axis=0) > 0)
    assert np.abs(katrina["terrain_height"].values).max() < 1.0  # all ocean
    lwc = katrina["cloud_liquid_content"].values
    rwc = katrina["rain_content"].values
    # QCLOUD max 1.81e-3, QRAIN max 5.28e-3 kg/kg over all times; times air density ~1.1 kg m-3
    assert 5e-4 < lwc.max() < 2.5e-3
    assert 1e-3 < rwc.max() < 6e-3
    assert lwc.min() >= 0 and rwc.min() >= 0


def test_katrina_liquid_water_path(katrina):
    # README: column LWP + RWP max about 15.7 kg m-2
    wp = _water_path(katrina)
    assert wp.max() == pytest.approx(15.7, rel=0.15)


def test_katrina_time_selection(shared_data):
    path = shared_data / KATRINA
    s15 = read_wrf(path, time="2005-08-28T15:00Z")
    assert s15["time"].values == np.datetime64("2005-08-28T15:00")
    nearest = read_wrf(path, time="2005-08-28 19:10")  # nearest is 18 UTC, 70 min away
    assert nearest["time"].values == np.datetime64("2005-08-28T18:00")
    last = read_wrf(path, time=-1)
    assert last["time"].values == np.datetime64("2005-08-28T21:00")
    # a moving nest: the columns of the selected time are used
    first = read_wrf(path)
    assert last["lat"].values.min() > first["lat"].values.min() + 0.5
    with pytest.raises(SwimInputError, match=r"2005-08-28T12:00Z.*2005-08-28T21:00Z"):
        read_wrf(path, time="2005-08-29T06:00Z")
    with pytest.raises(SwimInputError, match="not a time"):
        read_wrf(path, time="yesterday-ish")


def test_katrina_from_open_dataset_and_open_scene(shared_data, katrina):
    with xr.open_dataset(shared_data / KATRINA) as ds:
        from_ds = read_wrf(ds)
    xr.testing.assert_allclose(from_ds, katrina)
    via_open = open_scene(shared_data / KATRINA, time="2005-08-28T12:00")
    xr.testing.assert_allclose(via_open, katrina)
    xr.testing.assert_identical(validate_scene(katrina), katrina)


def test_wrf_missing_variables(shared_data):
    with xr.open_dataset(shared_data / KATRINA) as ds:
        broken = ds.drop_vars(["PHB"])
        with pytest.raises(SwimInputError, match="PHB"):
            read_wrf(broken)
    with pytest.raises(SwimInputError, match="not found"):
        read_wrf(shared_data / "wrf_katrina" / "no_such_file.nc")


# ----------------------------------------------------------------------------------------------------- WRF Tibet


def test_tibet_all_species(tibet):
    s = tibet
    assert (s.sizes["z"], s.sizes["y"], s.sizes["x"]) == (27, 8, 10)
    for name in SPECIES_CONTENTS:
        assert name in s, name
        assert s[name].attrs["units"] == "kg m-3"
        assert s[name].values.min() >= 0
    assert s["cloud_liquid_content"].values.max() > 1e-5
    assert s["snow_content"].values.max() > 0
    assert s["graupel_content"].values.max() > 0


def test_tibet_terrain_surface_time(tibet):
    s = tibet
    t = s["terrain_height"].values
    assert t.min() == pytest.approx(4484.0, abs=2.0)
    assert t.max() == pytest.approx(5499.0, abs=2.0)
    assert np.all(s["height"].values[0] > t)
    assert np.all(s["height"].values[0] - t < 60.0)
    assert s["surface_albedo"].dims == ("wavelength", "y", "x")
    np.testing.assert_array_equal(s["wavelength"].values, [615.0, 546.0, 450.0])
    alb = s["surface_albedo"].values
    assert 0.0 < alb.min() and alb.max() < 0.24
    assert set(np.unique(s["land_mask"].values)) <= {0, 1}
    assert s["time"].values == np.datetime64("2005-09-21T00:00")
    assert 29.0 < s.attrs["reference_lat"] < 31.0 and 85.5 < s.attrs["reference_lon"] < 88.5


def test_tibet_time_selection(shared_data):
    s = read_wrf(shared_data / TIBET, time=np.datetime64("2005-09-21T09:00"))
    assert s["time"].values == np.datetime64("2005-09-21T09:00")
    with pytest.raises(SwimInputError, match="available times"):
        read_wrf(shared_data / TIBET, time="2005-09-20T12:00")


def test_tibet_snow_wind_and_spectral_albedo(shared_data, tibet):
    s = tibet
    with xr.open_dataset(shared_data / TIBET) as ds:
        snowc = ds["SNOWC"].values[0]
        u10, v10 = ds["U10"].values[0], ds["V10"].values[0]
        albbck = ds["ALBBCK"].values[0]
        lu = ds["LU_INDEX"].values
        assert ds.attrs["MMINLU"] == "USGS"
    snow = s["snow_cover"].values
    assert snow.min() >= 0.0 and snow.max() <= 1.0
    np.testing.assert_allclose(snow, snowc)  # SNOWC max 0.007 (README)
    np.testing.assert_allclose(s["wind_speed_10m"].values, np.hypot(u10, v10), rtol=1e-6)
    assert s["wind_speed_10m"].attrs["units"] == "m s-1"
    # snow-free cells: ALBBCK with the spectral shape of the USGS class, a = a_c ALBBCK / A_c
    alb = s["surface_albedo"].values
    free = snowc == 0
    assert free.sum() > 20
    classes = landuse_classes("USGS")
    table = np.array([classes[int(c)].albedo for c in lu[free]]).T
    sw = np.array([classes[int(c)].shortwave_albedo for c in lu[free]])
    np.testing.assert_allclose(alb[:, free], table * albbck[free] / sw, rtol=1e-6)
    # the lake cell (LU 16, LANDMASK 0): water is bluer than it is red; grassland (LU 7) the opposite
    assert lu[7, 0] == 16 and s["land_mask"].values[7, 0] == 0
    assert alb[2, 7, 0] > alb[0, 7, 0]
    grass = free & (lu == 7)
    assert np.all(alb[0, grass] > alb[2, grass])


def test_katrina_wind(shared_data, katrina):
    with xr.open_dataset(shared_data / KATRINA) as ds:
        speed = np.hypot(ds["U10"].values[0], ds["V10"].values[0])
    np.testing.assert_allclose(katrina["wind_speed_10m"].values, speed, rtol=1e-6)
    assert katrina["wind_speed_10m"].values.max() > 30.0  # a category-5 hurricane's eyewall
    assert katrina.get("snow_cover") is None


# ----------------------------------------------------------------------------------------------------- WPS


@pytest.fixture(scope="module")
def met_em(shared_data):
    return read_wps_geogrid(shared_data / MET_EM)


def test_met_em_grid_terrain_and_mask(shared_data, met_em):
    s = met_em
    assert (s.sizes["z"], s.sizes["y"], s.sizes["x"]) == (20, 42, 42)
    with xr.open_dataset(shared_data / MET_EM) as ds:
        hgt = ds["HGT_M"].values[0]
        landmask = ds["LANDMASK"].values[0]
        lat = ds["XLAT_M"].values[0]
    np.testing.assert_array_equal(s["terrain_height"].values, hgt)
    assert s["terrain_height"].values.min() == pytest.approx(2995.0, abs=1.0)  # README: HGT_M 2995-3267 m
    assert s["terrain_height"].values.max() == pytest.approx(3267.0, abs=1.0)
    np.testing.assert_array_equal(s["land_mask"].values, landmask)
    assert np.all(s["land_mask"].values == 1)
    np.testing.assert_array_equal(s["lat"].values, lat)
    assert np.all(s["height"].values[0] > s["terrain_height"].values)
    assert s["time"].values == np.datetime64("2005-08-28T12:00")
    assert 39.69 < s.attrs["reference_lat"] < 39.72 and -107.32 < s.attrs["reference_lon"] < -107.26
    for name in ("cloud_liquid_content", "cloud_ice_content", "rain_content"):
        assert s.get(name) is None  # clear sky
    xr.testing.assert_identical(validate_scene(s), s)


def test_met_em_albedo_from_albedo12m_august(shared_data, met_em):
    with xr.open_dataset(shared_data / MET_EM) as ds:
        august = ds["ALBEDO12M"].values[0, 7] / 100.0  # percent
        assert ds["LU_INDEX"].values.min() == ds["LU_INDEX"].values.max() == 14  # all evergreen needleleaf
    assert 0.13 < august.mean() < 0.14
    forest = landuse_classes("USGS")[14]
    alb = met_em["surface_albedo"].values
    # the forest's spectral shape, scaled so that its shortwave albedo is ALBEDO12M of August
    np.testing.assert_allclose(alb, np.array(forest.albedo)[:, None, None] * august / forest.shortwave_albedo)
    vis = visible_mean(alb)
    assert 0.05 < vis.min() and vis.max() < 0.07  # a conifer forest is dark in the visible
    assert "month 8" in met_em.attrs["albedo_source"]
    # matched as the visible mean instead: the visible broadband mean is ALBEDO12M itself
    visible = read_wps_geogrid(shared_data / MET_EM, albedo_band="visible")
    v = visible_mean(visible["surface_albedo"].values)
    np.testing.assert_allclose(v, august)
    assert 0.11 < v.min() and v.max() < 0.17
    # snow: SNOW = 0 everywhere
    assert np.all(met_em["snow_cover"].values == 0.0)


def test_met_em_surface_wind(shared_data, met_em):
    with xr.open_dataset(shared_data / MET_EM) as ds:
        assert float(ds["PRES"].values[0, 0, 0, 0]) == pytest.approx(float(ds["PSFC"].values[0, 0, 0]))
        uu = ds["UU"].values[0, 0]
        vv = ds["VV"].values[0, 0]
    speed = np.hypot(0.5 * (uu[:, 1:] + uu[:, :-1]), 0.5 * (vv[1:] + vv[:-1]))
    np.testing.assert_allclose(met_em["wind_speed_10m"].values, speed)
    assert met_em["wind_speed_10m"].values.max() < 5.0


@pytest.mark.parametrize("name, shape, hmax", [(GEO_EM[0], (199, 199), 3217.4), (GEO_EM[1], (350, 250), 3232.1)])
def test_geo_em_greenland(shared_data, name, shape, hmax):
    s = open_scene(shared_data / name)  # dispatch by HGT_M / XLAT_M / XLONG_M
    assert (s.sizes["y"], s.sizes["x"]) == shape and s.sizes["z"] == 20
    with xr.open_dataset(shared_data / name) as ds:
        hgt = ds["HGT_M"].values[0]
    np.testing.assert_array_equal(s["terrain_height"].values, hgt)
    assert s["terrain_height"].values.min() == 0.0
    assert s["terrain_height"].values.max() == pytest.approx(hmax, abs=0.1)
    np.testing.assert_array_equal(s["land_mask"].values, (hgt > 0).astype(np.int8))
    assert 0.45 < s["land_mask"].values.mean() < 0.75  # README: half the d01 domain is ocean
    assert s.get("surface_albedo") is None  # no albedo information: the renderer's default
    assert "time" not in s.coords
    assert s["lon"].values.min() >= -180.0 and s["lon"].values.max() < 180.0
    assert np.all(np.diff(s["height"].values, axis=0) > 0)


# ----------------------------------------------------------------------------------------------------- LES


@pytest.mark.parametrize(
    "name, shape, lwc_max, reff_range, z_range",
    [
        ("rico122x106x39.txt", (39, 106, 122), 1.38, (11.7, 20.8), (440.0, 1960.0)),
        ("rico32x37x26.txt", (26, 37, 32), 1.52, (11.6, 18.7), (440.0, 1440.0)),
        ("les_stcu.txt", (16, 64, 64), 4.26, (4.0, 24.2), (438.0, 812.0)),
    ],
)
def test_les_files(shared_data, name, shape, lwc_max, reff_range, z_range):
    s = read_shdom_les(shared_data / "les" / name, reference_lat=15.0, reference_lon=-60.0, time="2005-01-10T14:00Z")
    assert s["height"].shape == shape
    lwc = s["cloud_liquid_content"].values
    assert lwc.max() * 1e3 == pytest.approx(lwc_max, abs=0.01)  # README table, g m-3
    assert s["cloud_liquid_content"].attrs["units"] == "kg m-3"
    r = s["cloud_liquid_effective_radius"].values[lwc > 0] * 1e6
    assert r.min() == pytest.approx(reff_range[0], abs=0.1)
    assert r.max() == pytest.approx(reff_range[1], abs=0.1)
    h = s["height"].values
    assert h[0, 0, 0] == pytest.approx(z_range[0]) and h[-1, 0, 0] == pytest.approx(z_range[1])
    assert np.all(s["terrain_height"].values == 0.0)
    assert np.all(s["land_mask"].values == 0)
    assert s["time"].values == np.datetime64("2005-01-10T14:00")
    assert abs(s.attrs["reference_lat"] - 15.0) < 1e-12
    # the domain is centred on the reference point
    assert s["x"].values[0] == pytest.approx(-s["x"].values[-1])
    assert abs(s["lat"].values.mean() - 15.0) < 1e-3


def test_les_grid_spacing_and_cells(shared_data):
    s = read_shdom_les(shared_data / "les" / "les_stcu.txt")
    assert np.diff(s["x"].values) == pytest.approx(55.0)
    assert np.diff(s["y"].values) == pytest.approx(55.0)
    # stcu lists every cell, 24,789 of them cloudy
    assert int(np.count_nonzero(s["cloud_liquid_content"].values)) == 65536 - 40747
    r = read_shdom_les(shared_data / "les" / "rico122x106x39.txt")
    assert int(np.count_nonzero(r["cloud_liquid_content"].values)) == 15905
    assert np.diff(r["x"].values) == pytest.approx(20.0)
    assert "time" not in r.coords
    via_open = open_scene(shared_data / "les" / "rico32x37x26.txt")
    assert via_open["height"].shape == (26, 37, 32)


def test_les_bad_files(tmp_path):
    bad = tmp_path / "bad.txt"
    bad.write_text("# cloud\n2,2,2\n0.02,0.02\n0.5,0.6\ni,j,k,lwc,reff\n0,0,5,0.1,10.0\n")
    with pytest.raises(SwimInputError, match="index k"):
        read_shdom_les(bad)
    short = tmp_path / "short.txt"
    short.write_text("# cloud\n2,2,3\n0.02,0.02\n0.5,0.6\n")
    with pytest.raises(SwimInputError, match="incomplete header"):
        read_shdom_les(short)
    micro = tmp_path / "micro.txt"
    micro.write_text("2 2 2\n0.02 0.02 0.5 0.6\n0 0 0 0.1 0.00001\n")
    with pytest.raises(SwimInputError, match="micrometres"):
        read_shdom_les(micro)
    ok = tmp_path / "ok.txt"
    ok.write_text("2 2 2\n0.02 0.02 0.5 0.6\n0 1 1 0.1 10.0\n")
    s = read_shdom_les(ok)
    assert s["cloud_liquid_content"].values[1, 1, 0] == pytest.approx(1e-4)
