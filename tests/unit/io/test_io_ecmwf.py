"""Tests of the ECMWF readers (swim.io.ecmwf, swim.io.ecmwf_levels): ERA5 pressure levels and IFS L137 model
levels, the hypsometric heights, the mixing-ratio-to-content conversion and the cloud-fraction treatments."""

import numpy as np
import pytest
import xarray as xr

from swim.errors import SwimInputError
from swim.io import validate_scene
from swim.io.ecmwf import (
    EFFECTIVE_THICKNESS_FACTOR,
    ecmwf_kind,
    is_ecmwf_grib,
    maximum_random_overlap,
    read_ecmwf,
    read_era5_pressure_levels,
    read_ifs_model_levels,
    subcolumn_contents,
)
from swim.io.ecmwf_levels import (
    L137_A,
    L137_B,
    air_density,
    half_level_pressure,
    hybrid_coefficients_from_pv,
    model_level_heights,
    pressure_level_heights,
)

ERA5_2018 = "era5_columns/era5_reanalysis-2018-08-20T11_00_00.nc"
ERA5_2023 = "era5_columns/era5_reanalysis-2023-05-16T18_00_00.nc"
IFS = "ifs_profiles/S3COM_input_test_NWPSAF_10pt.nc"
SPECIES = ("cloud_liquid", "cloud_ice", "rain", "snow")


@pytest.fixture(scope="module")
def era5(shared_data):
    with xr.open_dataset(shared_data / ERA5_2018) as ds:
        return ds.load()


@pytest.fixture(scope="module")
def ifs(shared_data):
    with xr.open_dataset(shared_data / IFS) as ds:
        return ds.load()


# --- hypsometric heights ---------------------------------------------------------------------------------------


def test_l137_table_reproduces_the_half_level_pressures_of_the_profile_set(ifs):
    """ECMWF's L137 a, b give the file's own half-level pressures (a + b p_s) within 0.1 Pa."""
    assert L137_A.size == L137_B.size == 138 and L137_B[-1] == 1.0 and L137_A[0] == 0.0
    ph = half_level_pressure(ifs["psurf"].values)
    np.testing.assert_allclose(ph, ifs["paph"].values, atol=0.1)


def test_model_level_heights_match_the_profile_set_altitudes(ifs):
    """The IFS hypsometric integration agrees with the NWP SAF geometric altitudes: lowest level within 1 m,
    within 0.3 % of the height above ground plus 10 m below 20 km."""
    z = model_level_heights(ifs["paph"].values.astype(float), ifs["temp"].values, ifs["hum"].values,
                            ifs["z0"].values)
    alt = ifs["altitude"].values.astype(float)
    np.testing.assert_allclose(z[-1], alt[-1], atol=1.0)
    low = alt < 20_000.0
    above_ground = alt - ifs["elevation"].values[None]
    assert np.all(np.abs(z - alt)[low] <= 0.003 * above_ground[low] + 10.0)
    assert np.all(np.diff(z, axis=0) < 0)  # top first: decreasing downwards


def test_pressure_level_heights_follow_the_standard_atmosphere():
    """With the U.S. Standard Atmosphere 1976 temperatures (dry), the heights of 1000, 850, 500, 200 hPa are its
    geometric heights (111, 1457, 5574, 11784 m) within 0.5 % (the trapezoid in ln p)."""
    p = np.array([1000.0, 850.0, 700.0, 500.0, 300.0, 200.0]) * 100.0
    geopotential_height = 44330.8 * (1.0 - (p / 101325.0) ** 0.190263)  # troposphere, lapse rate 6.5 K/km
    t = 288.15 - 0.0065 * geopotential_height
    t[-1] = 216.65  # 200 hPa: just above the tropopause (11.0 km); the 300-200 hPa layer straddles it
    z = pressure_level_heights(p, t[:, None], np.zeros((6, 1)))[:, 0]
    expected = np.array([110.9, 1457.3, 3012.0, 5574.4, 9164.2, 11784.0])
    np.testing.assert_allclose(z[:5], expected[:5], rtol=0.005)
    assert abs(z[5] - expected[5]) < 0.01 * expected[5]


def test_pressure_level_heights_start_from_the_surface_pressure():
    """With p_s = 1000 hPa at 500 m, the 1000 hPa level is at 500 m and 900 hPa R_d T_v ln(1000/900) / g higher."""
    z = pressure_level_heights(np.array([1000e2, 900e2]), np.full((2, 1), 280.0), np.zeros((2, 1)),
                               surface_pressure=np.array([1000e2]), surface_geopotential=np.array([500 * 9.80665]))
    assert z[0, 0] == pytest.approx(500.0, abs=0.1)
    assert z[1, 0] - z[0, 0] == pytest.approx(287.05 * 280.0 * np.log(10 / 9) / 9.80665, rel=1e-3)


def test_pv_split_and_its_errors():
    a, b = hybrid_coefficients_from_pv(np.concatenate([L137_A, L137_B]))
    np.testing.assert_array_equal(a, L137_A)
    np.testing.assert_array_equal(b, L137_B)
    with pytest.raises(SwimInputError, match="pv"):
        hybrid_coefficients_from_pv(np.arange(5.0))
    with pytest.raises(SwimInputError, match="Pa"):
        half_level_pressure(1013.0)


# --- mixing ratio to content -----------------------------------------------------------------------------------


def test_air_density_against_a_hand_computation():
    """p = 85000 Pa, T = 280 K, q = 0.008, q_c = 0.0005: T_rho = 280 (1 + 0.6077 0.008 - 0.0005) = 281.221 K,
    rho = 85000 / (287.05 281.221) = 1.05296 kg m-3."""
    rho = air_density(85000.0, 280.0, 0.008, 0.0005)
    assert rho == pytest.approx(85000.0 / (287.05 * 280.0 * (1 + (1 / 0.622 - 1) * 0.008 - 0.0005)), rel=1e-12)
    assert rho == pytest.approx(1.05296, rel=1e-4)


def test_era5_liquid_content_is_mixing_ratio_times_density(era5, shared_data):
    """A cell's cloud liquid content is clwc x p / (R_d T_rho) computed by hand from the file's values."""
    scene = read_era5_pressure_levels(shared_data / ERA5_2018, cloud_fraction="grid_mean")
    cell = era5.isel(time=0, latitude=2, longitude=0)  # south-west column (latitude runs north to south)
    k = int(np.argmax(cell["clwc"].values))
    level = float(cell["level"].values[k])
    z = int(np.flatnonzero(np.sort(era5["level"].values)[::-1] == level)[0])
    qc = sum(float(cell[n].values[k]) for n in ("clwc", "ciwc", "crwc", "cswc"))
    t, q = float(cell["t"].values[k]), float(cell["q"].values[k])
    rho = level * 100.0 / (287.05 * t * (1 + (1 / 0.622 - 1) * q - qc))
    assert float(scene["cloud_liquid_content"][z, 0, 0]) == pytest.approx(float(cell["clwc"].values[k]) * rho,
                                                                           rel=1e-9)
    assert float(scene["lat"][0, 0]) == pytest.approx(37.57, abs=1e-3)


# --- readers ---------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", [ERA5_2018, ERA5_2023])
def test_era5_scene_variables_units_heights(shared_data, name):
    scene = read_era5_pressure_levels(shared_data / name)
    assert scene.attrs["ecmwf_cloud_fraction"] == "grid_mean"  # no cc in these files
    assert scene.sizes["z"] == 37
    for s in SPECIES:
        assert scene[f"{s}_content"].attrs["units"] == "kg m-3"
        assert 0 < float(scene[f"{s}_content"].max()) < 1e-3
    h = scene["height"].values
    assert np.all(np.diff(h, axis=0) > 0)
    # 1000 hPa about 111 m (standard atmosphere); 500 hPa within 5 % of the standard 5574 m (a warm-season
    # Mediterranean 500 hPa surface lies at 5700-5900 m); 1 hPa (standard 47.8 km) between 45 and 50 km
    assert h[0].mean() == pytest.approx(110.9, abs=10.0)
    assert h[list(np.sort([1, 2, 3, 5, 7, 10, 20, 30, 50, 70, 100, 125, 150, 175, 200, 225, 250, 300, 350, 400, 450,
                           500, 550, 600, 650, 700, 750, 775, 800, 825, 850, 875, 900, 925, 950, 975, 1000])[::-1]
               ).index(500)].mean() == pytest.approx(5574.4, rel=0.05)
    assert 45_000 < h[-1].max() < 50_000
    assert "time" in scene.coords and scene.attrs["title"].startswith("ERA5")


def test_era5_scene_is_validated(shared_data):
    scene = read_era5_pressure_levels(shared_data / ERA5_2023)
    again = validate_scene(scene)
    xr.testing.assert_identical(again, scene)


def test_era5_cds_naming_variants(era5):
    """The new CDS netCDF names (pressure_level, valid_time) and a level axis in Pa read the same."""
    base = read_era5_pressure_levels(era5, cloud_fraction="grid_mean")
    renamed = era5.rename({"level": "pressure_level", "time": "valid_time"})
    other = read_era5_pressure_levels(renamed, cloud_fraction="grid_mean")
    np.testing.assert_allclose(other["cloud_liquid_content"].values, base["cloud_liquid_content"].values)
    in_pa = era5.assign_coords(level=era5["level"].values * 100.0)
    np.testing.assert_allclose(read_era5_pressure_levels(in_pa)["height"].values, base["height"].values)


def test_era5_uses_geopotential_where_present(era5):
    """With z on the levels, the height is z / g made geometric (500 hPa: 5600 gpm -> 5604.9 m)."""
    ds = era5.copy()
    ds["z"] = xr.full_like(ds["t"], 0.0) + (np.arange(37.0)[::-1] * 150.0 + 10.0)[None, :, None, None] * 9.80665
    scene = read_era5_pressure_levels(ds)
    assert float(scene["height"][0, 0, 0]) == pytest.approx(10.0, abs=0.01)
    h = 36 * 150.0 + 10.0
    assert float(scene["height"][-1, 0, 0]) == pytest.approx(6356766.0 * h / (6356766.0 - h), rel=1e-9)


def test_era5_surface_pressure_drops_underground_levels(era5):
    ds = era5.copy()
    ds["sp"] = xr.full_like(ds["t"].isel(level=0), 95000.0)
    scene = read_era5_pressure_levels(ds)
    assert float(scene["rain_content"][:2].max()) == 0.0  # 1000 and 975 hPa under the 950 hPa surface
    assert float(scene["rain_content"][2:].max()) > 0.0


def test_era5_missing_variables_and_bad_units(era5):
    with pytest.raises(SwimInputError, match="lacks q"):
        read_era5_pressure_levels(era5.drop_vars("q"))
    with pytest.raises(SwimInputError, match="clwc, ciwc"):
        read_era5_pressure_levels(era5.drop_vars(["clwc", "ciwc", "crwc", "cswc"]))
    grams = era5.copy()
    grams["clwc"] = grams["clwc"] * 1000.0
    grams["clwc"].attrs["units"] = "g kg**-1"
    with pytest.raises(SwimInputError, match="clwc.*kg kg-1"):
        read_era5_pressure_levels(grams)
    with pytest.raises(SwimInputError, match="1.5 h"):
        read_era5_pressure_levels(era5, time="2018-08-21T11:00")
    with pytest.raises(SwimInputError, match="needs the cloud cover cc"):
        read_era5_pressure_levels(era5, cloud_fraction="subcolumns")


def test_ifs_profile_scene(shared_data, ifs):
    scene = read_ifs_model_levels(shared_data / IFS, column=3, cloud_fraction="grid_mean")
    assert scene.sizes["z"] == 137 and scene.sizes["x"] == scene.sizes["y"] == 8
    assert float(scene["lat"].mean()) == pytest.approx(float(ifs["lat"][3]), abs=0.1)
    np.testing.assert_allclose(scene["height"].values[:, 0, 0], ifs["altitude"].values[::-1, 3],
                               rtol=0.003, atol=10.0)
    assert np.all(np.diff(scene["height"].values, axis=0) > 0)
    # liquid water path: the file's derived lwc [g m-3] over the layers, within 3 %
    lwp = float((scene["cloud_liquid_content"][:, 0, 0] * np.diff(ifs["altitudeh"].values[::-1, 3])).sum())
    assert lwp * 1000.0 == pytest.approx(float(ifs["lwp"][3]), rel=0.03)
    assert scene["time"].values == np.datetime64("2013-09-02T12:00")
    xr.testing.assert_identical(validate_scene(scene), scene)


def test_ifs_errors(shared_data, ifs):
    with pytest.raises(SwimInputError, match="column"):
        read_ifs_model_levels(ifs, column=10)
    with pytest.raises(SwimInputError, match="lacks clw"):
        read_ifs_model_levels(ifs.drop_vars("clw"))
    with pytest.raises(SwimInputError, match="cloud_fraction"):
        read_ifs_model_levels(ifs, cloud_fraction="homogeneous")
    with pytest.raises(SwimInputError, match="subcolumns"):
        read_ifs_model_levels(ifs, subcolumns=0)


def test_ifs_gridded_model_levels_from_lnsp(ifs):
    """ECMWF model-level fields (t, q, clwc, lnsp, z) on a 2 x 2 grid built from one profile give that profile's
    heights (the L137 table from 137 levels)."""
    col = ifs.isel(point=3)

    def grid(v):
        return xr.DataArray(np.broadcast_to(np.asarray(v, dtype=float)[:, None, None], (137, 2, 2)),
                            dims=("hybrid", "latitude", "longitude"))

    ds = xr.Dataset({"t": grid(col["temp"]), "q": grid(col["hum"]), "clwc": grid(col["clw"]),
                     "ciwc": grid(col["ciw"]), "cc": grid(col["cc"]),
                     "lnsp": (("latitude", "longitude"), np.full((2, 2), np.log(float(col["psurf"])))),
                     "z": (("latitude", "longitude"), np.full((2, 2), float(col["z0"])))},
                    coords={"hybrid": np.arange(1, 138), "latitude": [43.0, 42.9], "longitude": [143.0, 143.1]})
    scene = read_ifs_model_levels(ds, cloud_fraction="grid_mean")
    np.testing.assert_allclose(scene["height"].values[:, 1, 0], col["altitude"].values[::-1], rtol=0.003, atol=10.0)
    sub = read_ifs_model_levels(ds, subcolumns=4)
    assert sub.sizes["y"] == sub.sizes["x"] == 8
    with pytest.raises(SwimInputError, match="surface pressure"):
        read_ifs_model_levels(ds.drop_vars("lnsp"))


# --- cloud fraction --------------------------------------------------------------------------------------------


def test_maximum_random_overlap_statistics():
    """Each level is cloudy in a share C_k of the sub-columns; two adjacent levels of 0.4 and 0.6 overlap
    maximally (total cover 0.6); two layers of 0.5 separated by clear air overlap randomly (cover 0.75)."""
    c = np.array([[0.4], [0.6], [0.0], [0.5], [0.0], [0.5]])
    _, cloudy = maximum_random_overlap(c, 200_000, np.random.default_rng(1))
    share = cloudy[:, :, 0].mean(axis=1)
    np.testing.assert_allclose(share, c[:, 0], atol=0.005)
    assert cloudy[:2, :, 0].any(axis=0).mean() == pytest.approx(0.6, abs=0.005)
    assert cloudy[3:, :, 0].any(axis=0).mean() == pytest.approx(0.75, abs=0.005)


def test_subcolumns_conserve_the_grid_mean_and_put_content_in_cloud():
    rng = np.random.default_rng(3)
    cc = rng.uniform(0, 1, (5, 2, 3))
    cc[2] = 0.0  # content without cloud: goes to the sub-columns of largest rank
    q = {"cloud_liquid": rng.uniform(0, 1e-4, (5, 2, 3)), "rain": rng.uniform(0, 1e-5, (5, 2, 3))}
    out = subcolumn_contents(q, cc, 4, seed=0)
    assert out["cloud_liquid"].shape == (5, 8, 12)
    for name in q:
        mean = out[name].reshape(5, 2, 4, 3, 4).mean(axis=(2, 4))
        np.testing.assert_allclose(mean, q[name], rtol=1e-12)
    cloudy = (out["cloud_liquid"] > 0).reshape(5, 2, 4, 3, 4).mean(axis=(2, 4))
    assert np.all(np.abs(cloudy[[0, 1, 3, 4]] - cc[[0, 1, 3, 4]]) <= 0.5)
    assert np.all(cloudy[2] == 1 / 16)
    np.testing.assert_array_equal(out["rain"], np.repeat(np.repeat(q["rain"], 4, axis=1), 4, axis=2))


def test_cloud_fraction_treatments_change_the_column(shared_data):
    """Column 4 (cc up to 0.45): sub-columns keep the patch-mean liquid water path and make most sub-columns
    clear; effective_thickness scales it by 0.7; grid_mean fills every column."""
    path = shared_data / IFS
    mean = read_ifs_model_levels(path, column=4, cloud_fraction="grid_mean")
    sub = read_ifs_model_levels(path, column=4, cloud_fraction="subcolumns", subcolumns=8)
    eff = read_ifs_model_levels(path, column=4, cloud_fraction="effective_thickness")
    assert sub.attrs["ecmwf_cloud_fraction"] == "subcolumns"
    assert read_ifs_model_levels(path, column=4).attrs["ecmwf_cloud_fraction"] == "subcolumns"  # auto with cc
    lwc = {k: s["cloud_liquid_content"].values for k, s in (("mean", mean), ("sub", sub), ("eff", eff))}
    np.testing.assert_allclose(lwc["sub"].mean(axis=(1, 2)), lwc["mean"].mean(axis=(1, 2)), rtol=1e-10)
    np.testing.assert_allclose(lwc["eff"], EFFECTIVE_THICKNESS_FACTOR * lwc["mean"], rtol=1e-12)
    clear = (lwc["sub"].sum(axis=0) + sub["cloud_ice_content"].values.sum(axis=0)) == 0
    assert 0.3 < clear.mean() < 0.95
    assert np.all(lwc["mean"].sum(axis=0) > 0)
    again = read_ifs_model_levels(path, column=4, cloud_fraction="subcolumns", subcolumns=8)
    np.testing.assert_array_equal(again["cloud_liquid_content"].values, lwc["sub"])  # seeded


# --- GRIB (messages written with ecCodes from the file's values) and recognition -------------------------------

_PARAM_ID = {"t": 130, "q": 133, "clwc": 246, "ciwc": 247, "crwc": 75, "cswc": 76, "cc": 248, "lnsp": 152, "z": 129}


def _write_grib(path, messages, lats, lons, type_of_level=None, pv=None):
    """GRIB2 messages (name, level, values (ny, nx)) on a regular lat-lon grid, from ecCodes' ECMWF sample."""
    eccodes = pytest.importorskip("eccodes")
    with open(path, "wb") as f:
        for name, level, values in messages:
            gid = eccodes.codes_grib_new_from_samples("regular_ll_pl_grib2")
            for key, value in (("Ni", lons.size), ("Nj", lats.size), ("dataDate", 20180820), ("dataTime", 1100)):
                eccodes.codes_set_long(gid, key, value)
            for key, value in (("latitudeOfFirstGridPointInDegrees", lats[0]), ("latitudeOfLastGridPointInDegrees",
                               lats[-1]), ("longitudeOfFirstGridPointInDegrees", lons[0]),
                               ("longitudeOfLastGridPointInDegrees", lons[-1]),
                               ("iDirectionIncrementInDegrees", abs(lons[1] - lons[0])),
                               ("jDirectionIncrementInDegrees", abs(lats[1] - lats[0]))):
                eccodes.codes_set_double(gid, key, float(value))
            if type_of_level:
                eccodes.codes_set_string(gid, "typeOfLevel", type_of_level)
            if pv is not None:
                eccodes.codes_set_long(gid, "PVPresent", 1)
                eccodes.codes_set_array(gid, "pv", pv)
            eccodes.codes_set_long(gid, "level", int(level))
            eccodes.codes_set_long(gid, "paramId", _PARAM_ID[name])
            eccodes.codes_set_long(gid, "bitsPerValue", 24)
            eccodes.codes_set_values(gid, np.asarray(values, dtype=float).ravel())
            eccodes.codes_write(gid, f)
            eccodes.codes_release(gid)


def test_era5_grib_reads_as_the_netcdf(era5, tmp_path):
    pytest.importorskip("cfgrib")
    era5 = era5.sel(level=era5["level"] >= 500)  # 16 levels keep the test quick
    one = era5.isel(time=0)
    path = tmp_path / "era5.grib2"
    _write_grib(path, [(n, lev, one[n].values[i]) for n in ("t", "q", "clwc", "ciwc", "crwc", "cswc")
                       for i, lev in enumerate(one["level"].values)], one["latitude"].values, one["longitude"].values)
    assert is_ecmwf_grib(path)
    scene = read_ecmwf(path)
    reference = read_era5_pressure_levels(era5)
    assert scene["time"].values == reference["time"].values
    np.testing.assert_allclose(scene["height"].values, reference["height"].values, atol=0.01)
    for s in SPECIES:
        np.testing.assert_allclose(scene[f"{s}_content"].values, reference[f"{s}_content"].values, rtol=1e-4,
                                   atol=1e-10)


def test_ifs_model_level_grib_takes_pv_lnsp_and_surface_z(ifs, tmp_path):
    """Model-level GRIB: the hybrid coefficients come from pv (L137), p_s from lnsp and the surface from z on
    hybrid level 1; the lowest 30 levels (108-137, up to about 3 km) keep the test quick."""
    pytest.importorskip("cfgrib")
    col = ifs.isel(point=3)
    lats, lons = np.array([43.0, 42.75]), np.array([143.0, 143.25])
    messages = [(n, k + 1, np.full((2, 2), float(col[src].values[k])))
                for n, src in (("t", "temp"), ("q", "hum"), ("clwc", "clw"), ("ciwc", "ciw"), ("cc", "cc"))
                for k in range(107, 137)]
    messages += [("lnsp", 1, np.full((2, 2), np.log(float(col["psurf"])))), ("z", 1, np.full((2, 2), float(col["z0"])))]
    path = tmp_path / "ifs_ml.grib2"
    _write_grib(path, messages, lats, lons, "hybrid", np.concatenate([L137_A, L137_B]))
    scene = read_ecmwf(path)
    assert scene.sizes["z"] == 30 and scene.sizes["x"] == 2 * 8  # auto: sub-columns, the file has cc
    assert scene.attrs["ecmwf_cloud_fraction"] == "subcolumns"
    np.testing.assert_allclose(scene["height"].values[:, 0, 0], col["altitude"].values[::-1][:30], rtol=0.003,
                               atol=10.0)
    assert float(scene["terrain_height"][0, 0]) == pytest.approx(float(col["elevation"]), abs=1.0)


def test_ecmwf_kind_recognises_the_layouts(era5, ifs):
    assert ecmwf_kind(era5) == "era5_pressure_levels"
    assert ecmwf_kind(era5.rename({"level": "pressure_level"})) == "era5_pressure_levels"
    assert ecmwf_kind(ifs) == "ifs_model_levels"
    assert ecmwf_kind(era5.drop_vars(["clwc", "ciwc", "crwc", "cswc"])) is None
    assert ecmwf_kind(xr.Dataset({"height": ("z", [1.0, 2.0])})) is None


def test_region_and_nearest_profile(shared_data, ifs):
    """lat/lon/radius_deg cut a region of the grid (here 3 x 3 of the 4 x 4 box); on a profile set they pick the
    nearest profile (3.4 N 38.1 W is point 9)."""
    scene = read_era5_pressure_levels(shared_data / ERA5_2023, lat=39.29, lon=15.89, radius_deg=0.3, source="x")
    assert (scene.sizes["y"], scene.sizes["x"]) == (3, 3) and scene.attrs["source"].startswith("x read by")
    np.testing.assert_allclose(scene["lat"].values[:, 0], [39.04, 39.29, 39.54], atol=1e-3)
    with pytest.raises(SwimInputError, match="2 x 2"):
        read_era5_pressure_levels(shared_data / ERA5_2023, lat=39.29, lon=15.89, radius_deg=0.1)
    profile = read_ifs_model_levels(ifs, lat=3.0, lon=-38.0, cloud_fraction="grid_mean")
    assert profile.attrs["ecmwf_column"] == 9
    assert float(profile.attrs["reference_lat"]) == pytest.approx(float(ifs["lat"][9]))


def test_read_ecmwf_dispatches_and_refuses(shared_data, era5):
    scene = read_ecmwf(shared_data / IFS, column=4, cloud_fraction="grid_mean")
    assert scene.attrs["ecmwf_column"] == 4 and scene.attrs["source"].startswith(str(shared_data / IFS))
    assert read_ecmwf(era5).sizes["z"] == 37
    with pytest.raises(SwimInputError, match="column"):
        read_ecmwf(era5, column=1)
    with pytest.raises(SwimInputError, match="neither"):
        read_ecmwf(era5.drop_vars("t"))
    reduced = era5.stack(values=("latitude", "longitude")).reset_index("values")
    with pytest.raises(SwimInputError, match="regular latitude-longitude"):
        read_era5_pressure_levels(reduced)
