"""Unit tests of swim.io.scene (validation, scene_from_arrays, open_scene) and swim.io.default_scene."""

import logging
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from swim.constants import DEFAULT_EFFECTIVE_RADIUS, EARTH_RADIUS_M, WAVELENGTHS_NM
from swim.errors import SwimInputError
from swim.frames import geodetic_to_scene, orthographic_xy
from swim.io import default_scene, layer_thickness, open_scene, scene_from_arrays, validate_scene
from swim.io.scene import domain_centre, to_utc_datetime64

NZ, NY, NX = 5, 4, 6


def _scene(**overrides):
    """A small valid scene built from arrays; keyword overrides go to scene_from_arrays."""
    x = np.arange(NX) * 1000.0 - 2500.0
    y = np.arange(NY) * 1000.0 - 1500.0
    z = np.linspace(100.0, 4100.0, NZ)
    lwc = np.zeros((NZ, NY, NX))
    lwc[2, 1:3, 2:4] = 5e-4
    kwargs = dict(x=x, y=y, z=z, reference_lat=40.0, reference_lon=-105.0, cloud_liquid_content=lwc)
    kwargs.update(overrides)
    return scene_from_arrays(**kwargs)


# ----------------------------------------------------------------------------------------------- validation errors


@pytest.mark.parametrize("name", ["height", "lat", "lon", "terrain_height"])
def test_missing_required_variable(name):
    ds = _scene().drop_vars(name)
    with pytest.raises(SwimInputError, match=name):
        validate_scene(ds)


def test_not_a_dataset():
    with pytest.raises(SwimInputError, match="xarray.Dataset"):
        validate_scene({"height": 1})


def test_nan_content_names_variable_and_count():
    ds = _scene()
    ds["cloud_liquid_content"][0, 0, :3] = np.nan
    with pytest.raises(SwimInputError, match=r"cloud_liquid_content.*3 non-finite"):
        validate_scene(ds)


def test_nan_height():
    ds = _scene()
    ds["height"][1, 1, 1] = np.nan
    with pytest.raises(SwimInputError, match=r"height.*1 non-finite"):
        validate_scene(ds)


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.int16])
@pytest.mark.parametrize("layout", ["contiguous", "transposed"])
def test_scan_of_a_field_is_numpys(dtype, layout):
    """validate_scene's compiled pass over a 3-D field (swim.io.scan_cpu, blocks of levels on every core): the copy
    is the field in float64 (C order, no memory shared) and the counts of non-finite and negative values and the
    finite values' min and max are NumPy's, with the bad values in different blocks of levels."""
    from swim.io.scene import _copied_and_scanned

    rng = np.random.default_rng(3)
    field = (rng.normal(size=(9, 7, 8)) * 100).astype(dtype)
    if layout == "transposed":
        field = np.ascontiguousarray(field.transpose(2, 1, 0)).transpose(2, 1, 0)
        assert not field.flags.c_contiguous
    if np.issubdtype(dtype, np.floating):
        field[0, 1, 2] = np.nan
        field[8, 6, 7] = np.inf
        field[4, 0, 0] = -np.inf
    copy, stats = _copied_and_scanned(field)
    assert copy.dtype == np.float64 and copy.flags.c_contiguous and not np.shares_memory(copy, field)
    np.testing.assert_array_equal(copy, field.astype(np.float64))
    finite = field[np.isfinite(field)].astype(np.float64)
    assert stats == {"not finite": field.size - finite.size, "negative": int((finite < 0).sum()),
                     "min": finite.min(), "max": finite.max()}
    assert stats["not finite"] == (3 if np.issubdtype(dtype, np.floating) else 0) and stats["negative"] > 100


def test_float32_transposed_scene_is_validated_as_given():
    """A scene of float32 fields with their dims in another order (strided after the transpose): the validated
    copy holds the same values in float64, and bad values in several blocks of levels are all counted."""
    nz = 9
    z = np.linspace(100.0, 8100.0, nz)
    lwc = np.zeros((nz, NY, NX), np.float32)
    lwc[1, 1, 1], lwc[7, 2, 3] = 2e-4, 3e-4
    ds = _scene(z=z, cloud_liquid_content=lwc)
    ds["cloud_liquid_content"] = ds["cloud_liquid_content"].astype(np.float32).transpose("x", "z", "y")
    out = validate_scene(ds)
    np.testing.assert_array_equal(out["cloud_liquid_content"].values, lwc.astype(np.float64))
    assert out["cloud_liquid_content"].dtype == np.float64
    bad = ds.copy(deep=True)
    bad["cloud_liquid_content"][0, 0, 0] = np.nan  # (x, z, y): level 0
    bad["cloud_liquid_content"][1, nz - 1, 2] = np.inf  # the top level
    with pytest.raises(SwimInputError, match=r"cloud_liquid_content.*2 non-finite"):
        validate_scene(bad)
    height = ds["height"].values.copy()
    height[nz - 1, 0, 0] = height[nz - 2, 0, 0]  # not strictly increasing at the top of one column
    height[1, 3, 5] = height[0, 3, 5] - 1.0  # and near the bottom of another
    with pytest.raises(SwimInputError, match=rf"increase strictly.*2 of {NY * NX} column"):
        validate_scene(ds.assign(height=(("z", "y", "x"), height)))


def test_negative_content_raises():
    ds = _scene()
    ds["cloud_liquid_content"][1, 1, 1] = -1e-6
    with pytest.raises(SwimInputError, match=r"cloud_liquid_content.*negative"):
        validate_scene(ds)


def test_negative_noise_is_clipped_and_logged(caplog):
    ds = _scene()
    ds["cloud_liquid_content"][1, 1, 1] = -5e-13
    with caplog.at_level(logging.INFO, logger="swim.io.scene"):
        out = validate_scene(ds)
    assert out["cloud_liquid_content"].values.min() == 0.0
    assert "clipped" in caplog.text


def test_g_per_m3_given_as_kg_is_rejected():
    lwc = np.zeros((NZ, NY, NX))
    lwc[2, 1, 1] = 1.2  # 1.2 g m-3 mistakenly given as kg m-3
    with pytest.raises(SwimInputError, match=r"cloud_liquid_content.*g m-3 or g kg-1"):
        _scene(cloud_liquid_content=lwc)


@pytest.mark.parametrize("units", ["g m-3", "kg kg-1", "g/kg", "kg"])
def test_bad_units_attribute(units):
    ds = _scene()
    ds["cloud_liquid_content"].attrs["units"] = units
    with pytest.raises(SwimInputError, match=r"cloud_liquid_content.*kg m-3"):
        validate_scene(ds)


@pytest.mark.parametrize("units", ["kg m-3", "kg/m3", "kg m**-3", "kg m^-3", "kg.m-3"])
def test_good_units_spellings(units):
    ds = _scene()
    ds["cloud_liquid_content"].attrs["units"] = units
    assert validate_scene(ds)["cloud_liquid_content"].attrs["units"] == "kg m-3"


def test_units_attribute_added_when_missing():
    ds = _scene()
    for name in ds.variables:
        ds[name].attrs.pop("units", None)
        ds[name].attrs.pop("long_name", None)
    out = validate_scene(ds)
    for name in ("height", "lat", "lon", "terrain_height", "cloud_liquid_content"):
        assert out[name].attrs["units"] and out[name].attrs["long_name"]


def test_effective_radius_in_microns_rejected():
    with pytest.raises(SwimInputError, match=r"cloud_liquid_effective_radius.*expected metres"):
        _scene(cloud_liquid_effective_radius=12.0)


def test_effective_radius_filled_where_no_content():
    r = np.full((NZ, NY, NX), np.nan)
    r[2, 1:3, 2:4] = 12e-6
    out = _scene(cloud_liquid_effective_radius=r)
    rv = out["cloud_liquid_effective_radius"].values
    assert np.all(np.isfinite(rv))
    assert np.all(rv[2, 1:3, 2:4] == 12e-6)
    assert rv[0, 0, 0] == DEFAULT_EFFECTIVE_RADIUS["cloud_liquid"]


def test_effective_radius_nan_where_content_rejected():
    r = np.full((NZ, NY, NX), np.nan)
    with pytest.raises(SwimInputError, match="cloud_liquid_effective_radius"):
        _scene(cloud_liquid_effective_radius=r)


def test_radius_without_content_rejected():
    ds = _scene()
    ds["cloud_ice_effective_radius"] = ds["cloud_liquid_content"] * 0 + 30e-6
    with pytest.raises(SwimInputError, match="cloud_ice_content"):
        validate_scene(ds)


def test_height_not_increasing():
    ds = _scene()
    ds["height"].values[:] = ds["height"].values[::-1]
    with pytest.raises(SwimInputError, match="height must increase"):
        validate_scene(ds)


def test_height_in_km_rejected():
    with pytest.raises(SwimInputError, match="km"):
        _scene(z=np.linspace(0.1, 4.1, NZ))


def test_lat_out_of_range():
    ds = _scene()
    ds["lat"][0, 0] = 95.0
    with pytest.raises(SwimInputError, match="lat"):
        validate_scene(ds)


def test_albedo_out_of_range_and_percent():
    with pytest.raises(SwimInputError, match="surface_albedo"):
        _scene(surface_albedo=15.0)


def test_albedo_broadcast_from_2d():
    ds = _scene()
    ds["surface_albedo"] = xr.DataArray(np.full((NY, NX), 0.2), dims=("y", "x"))
    out = validate_scene(ds)
    assert out["surface_albedo"].dims == ("wavelength", "y", "x")
    np.testing.assert_array_equal(out["wavelength"].values, WAVELENGTHS_NM)
    assert np.all(out["surface_albedo"].values == 0.2)


def test_land_mask_must_be_binary():
    with pytest.raises(SwimInputError, match="land_mask"):
        _scene(land_mask=0.5)


def test_content_too_large_for_aerosol():
    with pytest.raises(SwimInputError, match="aerosol_extinction"):
        _scene(aerosol_extinction=np.full((NZ, NY, NX), 0.2))


def test_wrong_dims():
    ds = _scene()
    ds["rain_content"] = xr.DataArray(np.zeros((NY, NX)), dims=("y", "x"))
    with pytest.raises(SwimInputError, match="rain_content"):
        validate_scene(ds)


def test_time_must_be_single():
    ds = _scene().assign_coords(time=("ntime", [np.datetime64("2020-01-01"), np.datetime64("2020-01-02")]))
    with pytest.raises(SwimInputError, match="single"):
        validate_scene(ds)


def test_xy_coordinates_must_match_latlon():
    ds = _scene()
    ds = ds.assign_coords(x=ds["x"] + 5000.0)
    with pytest.raises(SwimInputError, match="coordinate 'x'"):
        validate_scene(ds)


def test_transposed_input_is_reordered_and_unknown_dropped(caplog):
    ds = _scene()
    ds["temperature"] = ds["height"] * 0 + 280.0
    ds = ds.transpose("x", "y", "z", ...)
    with caplog.at_level(logging.WARNING, logger="swim.io.scene"):
        out = validate_scene(ds)
    assert out["cloud_liquid_content"].dims == ("z", "y", "x")
    assert "temperature" not in out
    assert "temperature" in caplog.text


def test_validate_does_not_modify_input():
    ds = _scene()
    ds["cloud_liquid_content"][1, 1, 1] = -5e-13
    before = ds["cloud_liquid_content"].values.copy()
    out = validate_scene(ds)
    np.testing.assert_array_equal(ds["cloud_liquid_content"].values, before)
    for name in out.data_vars:
        assert not np.shares_memory(out[name].values, ds[name].values), name


def test_reference_point_defaults_to_centre():
    ds = _scene()
    del ds.attrs["reference_lat"], ds.attrs["reference_lon"]
    ds = ds.drop_vars(["x", "y"])
    out = validate_scene(ds)
    assert out.attrs["reference_lat"] == pytest.approx(40.0, abs=1e-6)
    assert out.attrs["reference_lon"] == pytest.approx(-105.0, abs=1e-6)


def test_absent_species_stay_absent():
    out = _scene()
    assert out.get("rain_content") is None
    assert "cloud_liquid_content" in out


# ----------------------------------------------------------------------------------------------- scene_from_arrays


def test_scene_from_arrays_latlon_roundtrip():
    x = np.linspace(-20000.0, 20000.0, 9)
    y = np.linspace(-30000.0, 10000.0, 5)
    out = scene_from_arrays(x=x, y=y, z=[500.0, 1000.0, 2000.0], reference_lat=-33.0, reference_lon=151.0)
    gx, gy = orthographic_xy(out["lat"].values, out["lon"].values, -33.0, 151.0)
    np.testing.assert_allclose(gx, np.broadcast_to(x, gx.shape), atol=1e-6)
    np.testing.assert_allclose(gy, np.broadcast_to(y[:, None], gy.shape), atol=1e-6)
    # the sea-level point of the column sits at (x, y, sqrt(R^2 - x^2 - y^2)) in the scene frame
    p = geodetic_to_scene(out["lat"].values, out["lon"].values, 0.0, -33.0, 151.0)
    np.testing.assert_allclose(np.linalg.norm(p, axis=-1), EARTH_RADIUS_M, rtol=1e-12)
    # the reference point itself
    out0 = scene_from_arrays(x=[-10.0, 0.0, 10.0], y=[0.0, 10.0], z=[100.0, 200.0], reference_lat=-33.0,
                             reference_lon=151.0)
    assert out0["lat"].values[0, 1] == pytest.approx(-33.0, abs=1e-12)
    assert out0["lon"].values[0, 1] == pytest.approx(151.0, abs=1e-12)
    # y north => latitude increases with y; x east => longitude increases with x
    assert np.all(np.diff(out["lat"].values, axis=0) > 0)
    assert np.all(np.diff(out["lon"].values, axis=1) > 0)


def test_scene_from_arrays_3d_heights_and_time():
    x = np.arange(3) * 500.0
    y = np.arange(2) * 500.0
    terrain = np.array([[0.0, 100.0, 200.0], [50.0, 150.0, 250.0]])
    z = terrain[None] + np.array([20.0, 200.0, 900.0])[:, None, None]
    out = scene_from_arrays(x=x, y=y, z=z, reference_lat=0.0, reference_lon=0.0, terrain_height=terrain,
                            time="2023-06-21T12:00:00+02:00", surface_albedo=[0.1, 0.2, 0.3], land_mask=1)
    assert out["height"].shape == (3, 2, 3)
    assert out["time"].values == np.datetime64("2023-06-21T10:00:00")
    np.testing.assert_allclose(out["surface_albedo"].values[:, 1, 2], [0.1, 0.2, 0.3])
    assert out["land_mask"].dtype == np.int8


def test_scene_from_arrays_rejects_irregular_x_and_bad_shapes():
    with pytest.raises(SwimInputError, match="x"):
        scene_from_arrays(x=[0.0, 10.0, 30.0], y=[0.0, 10.0], z=[100.0, 200.0], reference_lat=0, reference_lon=0)
    with pytest.raises(SwimInputError, match="cloud_liquid_content"):
        scene_from_arrays(x=[0.0, 10.0], y=[0.0, 10.0], z=[100.0, 200.0], reference_lat=0, reference_lon=0,
                          cloud_liquid_content=np.zeros((2, 3, 2)))


def test_to_utc_and_bad_time():
    assert to_utc_datetime64("2005-08-28 12:00Z") == np.datetime64("2005-08-28T12:00")
    with pytest.raises(SwimInputError, match="time"):
        to_utc_datetime64("not a time")


def test_domain_centre_across_dateline():
    lat0, lon0 = domain_centre([10.0, 10.0], [179.0, -179.0])
    assert lon0 == pytest.approx(-180.0, abs=1e-9) or lon0 == pytest.approx(180.0, abs=1e-9)
    assert lat0 == pytest.approx(10.0, abs=0.01)


def test_layer_thickness_sums_to_column_depth():
    h = np.array([50.0, 150.0, 300.0])[:, None, None] * np.ones((1, 2, 2))
    dz = layer_thickness(h, np.zeros((2, 2)))
    np.testing.assert_allclose(dz[:, 0, 0], [100.0, 125.0, 150.0])


# ----------------------------------------------------------------------------------------------- snow, wind


def test_snow_cover_and_wind_from_arrays():
    snow = np.zeros((NY, NX))
    snow[0, :2] = [0.25, 1.0]
    out = _scene(snow_cover=snow, wind_speed_10m=7.5)
    np.testing.assert_array_equal(out["snow_cover"].values, snow)
    np.testing.assert_array_equal(out["wind_speed_10m"].values, np.full((NY, NX), 7.5))
    assert out["snow_cover"].dims == ("y", "x") and out["wind_speed_10m"].dims == ("y", "x")
    assert out["snow_cover"].attrs["units"] == "1"
    assert out["wind_speed_10m"].attrs["units"] == "m s-1"
    assert "snow" in out["snow_cover"].attrs["long_name"]
    xr.testing.assert_identical(validate_scene(out), out)
    # absent by default (snow cover 0, the renderer's default wind)
    plain = _scene()
    assert plain.get("snow_cover") is None and plain.get("wind_speed_10m") is None


@pytest.mark.parametrize("bad, match", [(1.5, r"snow_cover.*\[0, 1\]"), (-0.1, r"snow_cover.*\[0, 1\]"),
                                        (40.0, r"snow_cover.*percent")])
def test_snow_cover_out_of_range(bad, match):
    ds = _scene(snow_cover=0.5)
    ds["snow_cover"][0, 0] = bad
    with pytest.raises(SwimInputError, match=match):
        validate_scene(ds)


def test_wind_speed_errors():
    ds = _scene(wind_speed_10m=3.0)
    ds["wind_speed_10m"][1, 1] = -2.0
    with pytest.raises(SwimInputError, match=r"wind_speed_10m.*negative.*m s-1"):
        validate_scene(ds)
    ds = _scene(wind_speed_10m=3.0)
    ds["wind_speed_10m"][1, 1] = 120.0
    with pytest.raises(SwimInputError, match=r"wind_speed_10m.*75 m s-1"):
        validate_scene(ds)
    ds = _scene(wind_speed_10m=3.0)
    ds["wind_speed_10m"].attrs["units"] = "km/h"
    with pytest.raises(SwimInputError, match=r"wind_speed_10m.*divide by 3.6"):
        validate_scene(ds)
    ds["wind_speed_10m"].attrs["units"] = "m/s"
    assert validate_scene(ds)["wind_speed_10m"].attrs["units"] == "m s-1"
    ds = _scene(snow_cover=0.5)
    ds["snow_cover"][0, 0] = np.nan
    with pytest.raises(SwimInputError, match="snow_cover.*1 non-finite"):
        validate_scene(ds)
    with pytest.raises(SwimInputError, match="wind_speed_10m"):
        _scene(wind_speed_10m=np.zeros((NY + 1, NX)))


# ----------------------------------------------------------------------------------------------- open_scene


def test_open_scene_canonical_netcdf_roundtrip(tmp_path):
    ds = _scene(time="2020-05-01T06:00Z", surface_albedo=0.1, land_mask=1)
    path = tmp_path / "scene.nc"
    ds.to_netcdf(path)
    out = open_scene(path)
    xr.testing.assert_allclose(out, ds)
    assert out.attrs["reference_lat"] == ds.attrs["reference_lat"]
    assert out["time"].values == np.datetime64("2020-05-01T06:00")
    with pytest.raises(SwimInputError, match="time"):
        open_scene(path, time="2020-05-02T06:00Z")


def test_open_scene_errors(tmp_path):
    with pytest.raises(SwimInputError, match="not found"):
        open_scene(tmp_path / "nope.nc")
    bad = tmp_path / "image.png"
    bad.write_bytes(b"\x89PNG")
    with pytest.raises(SwimInputError, match="neither GRIB, netCDF nor an SHDOM-style LES.*scene_from_arrays"):
        open_scene(bad)
    junk = tmp_path / "junk.nc"
    junk.write_text("this is not netcdf")
    with pytest.raises(SwimInputError, match="netCDF"):
        open_scene(junk)
    other = tmp_path / "other.nc"
    xr.Dataset({"foo": ("a", [1.0, 2.0])}).to_netcdf(other)
    with pytest.raises(SwimInputError, match="a netCDF file of no layout swim knows.*WRF wrfout.*canonical scene"):
        open_scene(other)


# ----------------------------------------------------------------------------------------------- default scene


def test_default_scene_recipe():
    s = default_scene()
    assert s.sizes["z"] == 40 and s.sizes["y"] == 80 and s.sizes["x"] == 80
    assert s.attrs["reference_lat"] == 40.0 and s.attrs["reference_lon"] == -105.3
    assert s["time"].values == np.datetime64("2023-06-21T18:00")
    lwc = s["cloud_liquid_content"].values
    ice = s["cloud_ice_content"].values
    h = s["height"].values
    assert 0.7e-3 < lwc.max() <= 1.0e-3
    assert 1400.0 < h[lwc > 0].min() and h[lwc > 0].max() < 4000.0
    assert 4e-5 < ice.max() <= 5e-5
    assert 8600.0 < h[ice > 0].min() and h[ice > 0].max() < 10400.0
    assert 790.0 < s["terrain_height"].values.max() <= 800.0
    assert s["land_mask"].values.min() == 0 and s["land_mask"].values.max() == 1
    assert h.max() < 12000.0
    r = s["cloud_liquid_effective_radius"].values[lwc > 0]
    assert 2e-6 < r.min() and r.max() < 15e-6
    # validated and idempotent under validation
    xr.testing.assert_identical(validate_scene(s), s)


def test_default_scene_is_deterministic():
    a, b = default_scene(), default_scene()
    xr.testing.assert_identical(a, b)


def test_lazy_open_reads_nothing_until_render_and_renders_the_same(tmp_path):
    pytest.importorskip("dask")  # the scale extra
    import dask.array

    import swim

    path = tmp_path / "scene.nc"
    default_scene().to_netcdf(path)
    lazy = open_scene(path, lazy=True, time=str(default_scene()["time"].values))
    assert isinstance(lazy["cloud_liquid_content"].data, dask.array.Array)
    assert lazy.attrs["source"] != "unknown"
    # the paper's cloud scattering: the lazy and the eager scene, crop or not, each a new 3-D solve otherwise
    options = dict(camera="allsky", camera_options={"size": 31},
                   settings=swim.MarchSettings(cloud_scattering="albers2020"))
    eager_image = swim.render(open_scene(path), **options)
    lazy_image = swim.render(lazy, **options)
    np.testing.assert_allclose(lazy_image["radiance"].values, eager_image["radiance"].values, rtol=1e-6, atol=1e-9)
    # rendering (cropped or not) reads what it needs without loading the caller's dataset in place
    swim.render(lazy, crop=False, **options)
    assert isinstance(lazy["cloud_liquid_content"].data, dask.array.Array), "render must leave the scene lazy"


def test_lazy_open_rejects_what_it_cannot_open_lazily(tmp_path):
    katrina = Path(__file__).resolve().parents[3].parent / "shared" / "data" / "wrf_katrina" / "ci_test_file.nc"
    if katrina.is_file():
        with pytest.raises(SwimInputError, match="lazy=True.*not a canonical scene"):
            open_scene(katrina, lazy=True)
    path = tmp_path / "scene.nc"
    default_scene().to_netcdf(path)
    with pytest.raises(SwimInputError, match="month"):
        open_scene(path, lazy=True, month=7)
    with pytest.raises(SwimInputError, match="holds only"):
        open_scene(path, lazy=True, time="2001-01-01T00:00")


@pytest.mark.parametrize("dtype", [complex, object])
def test_variables_that_are_not_real_numbers_are_refused(dtype):
    ds = _scene()
    ds["cloud_liquid_content"] = ds["cloud_liquid_content"].astype(dtype)
    with pytest.raises(SwimInputError, match="'cloud_liquid_content' holds .* values; expected real numbers"):
        validate_scene(ds)


def test_complex_arrays_are_refused_by_scene_from_arrays():
    """A complex field or axis would lose its imaginary part (numpy's cast only warns): each is named."""
    lwc = np.full((NZ, NY, NX), 1e-4) * (1 + 1j)
    with pytest.raises(SwimInputError, match="scene_from_arrays: cloud_liquid_content holds complex128 values"):
        _scene(cloud_liquid_content=lwc)
    with pytest.raises(SwimInputError, match="x holds complex128 values"):
        _scene(x=(np.arange(NX) * 1000.0 - 2500.0).astype(complex))
    with pytest.raises(SwimInputError, match="z holds complex128 values"):
        _scene(z=np.linspace(100.0, 4100.0, NZ).astype(complex))


def test_horizontal_axes_in_km_are_refused():
    with pytest.raises(SwimInputError, match="x/y spacing 1 m under levels 1000 m apart: expected x and y in metres"):
        _scene(x=np.arange(NX) * 1.0 - 2.5, y=np.arange(NY) * 1.0 - 1.5)
    fine = _scene(x=np.arange(NX) * 20.0, y=np.arange(NY) * 20.0, z=np.linspace(0.0, 400.0, NZ))  # an LES grid
    assert fine.sizes["x"] == NX
