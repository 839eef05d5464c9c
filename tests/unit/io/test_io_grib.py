"""Tests of swim.io.grib on the NCEP GFS sample files of ../shared/data/gfs (skipped where absent)."""

import numpy as np
import pytest

from swim.errors import SwimInputError
from swim.io import layer_thickness, open_scene, validate_scene
from swim.io.grib import (
    DEFAULT_RADIUS_DEG,
    MAX_RADIUS_DEG,
    geometric_height,
    liquid_fraction,
    moist_air_density,
    read_gfs_grib,
    region_columns,
    split_condensate,
)

pytest.importorskip("cfgrib")

GRIB2 = "gfs/gfs.t12z.pgrbf120.2p5deg.grib2"
GRB = "gfs/gfs.grb"


def _path(shared_data, name):
    path = shared_data / name
    if not path.is_file():
        pytest.skip(f"{path} not found")
    return path


@pytest.fixture(scope="module")
def scene(shared_data):
    """The GRIB2 sample around 45 N, 10 E (read once for the module)."""
    return read_gfs_grib(_path(shared_data, GRIB2), lat=45.0, lon=10.0)


@pytest.fixture(scope="module")
def dateline_scene(shared_data):
    return open_scene(_path(shared_data, GRIB2), lat=-20.0, lon=180.0, radius_deg=10.0)


def test_variables_units_and_attributes(scene):
    for name, units in (("height", "m"), ("terrain_height", "m"), ("cloud_liquid_content", "kg m-3"),
                        ("cloud_ice_content", "kg m-3"), ("wind_speed_10m", "m s-1"), ("lat", "degrees_north"),
                        ("lon", "degrees_east")):
        assert scene[name].attrs["units"] == units
    assert scene["land_mask"].dtype == np.int8
    assert "surface_albedo" not in scene
    assert scene.sizes["z"] == 21  # the clwmr levels, 1000-100 hPa
    assert str(scene["time"].values)[:16] == "2011-01-15T12:00"
    assert scene.attrs["forecast_reference_time"] == "2011-01-10T12:00:00Z"
    assert scene.attrs["grib_edition"] == 2 and scene.attrs["grib_centre"] == "kwbc"
    assert 0.0 < scene["cloud_liquid_content"].max() < 5e-3
    assert 0.0 < scene["cloud_ice_content"].max() < 5e-3


def test_heights_increase_in_every_column_and_reach_the_tropopause(scene):
    h = scene["height"].values
    assert np.all(np.diff(h, axis=0) > 0)
    assert 14e3 < h[-1].mean() < 18e3  # 100 hPa


def test_validate_round_trip(scene):
    again = validate_scene(scene)
    assert again.identical(scene)


def test_region_centred_where_asked(scene):
    assert (scene.attrs["reference_lat"], scene.attrs["reference_lon"]) == (45.0, 10.0)
    lat, lon = scene["lat"].values, scene["lon"].values
    assert np.all(np.diff(lat[:, 0]) > 0) and np.all(np.diff(lon[0]) > 0)  # south to north, west to east
    assert lat.min() == pytest.approx(45.0 - DEFAULT_RADIUS_DEG)
    assert lat.max() == pytest.approx(45.0 + DEFAULT_RADIUS_DEG)
    assert lon[0].mean() == pytest.approx(10.0)


def test_region_across_the_dateline(dateline_scene):
    lon = dateline_scene["lon"].values[0]
    assert dateline_scene.attrs["reference_lon"] == -180.0
    assert np.any(lon > 170.0) and np.any(lon < -170.0)
    assert np.all(np.abs(((lon - 180.0) + 180.0) % 360.0 - 180.0) <= 12.0)
    assert dateline_scene["lat"].values.mean() == pytest.approx(-20.0)


def test_region_columns_and_its_limits():
    lat = np.arange(90.0, -90.1, -2.5)
    lon = np.arange(0.0, 360.0, 2.5)
    rows, cols, longitudes = region_columns(lat, lon, 0.0, 0.0, 5.0)
    assert lat[rows].tolist() == [-5.0, -2.5, 0.0, 2.5, 5.0]
    assert longitudes.tolist() == [-5.0, -2.5, 0.0, 2.5, 5.0]
    assert lon[cols].tolist() == [355.0, 357.5, 0.0, 2.5, 5.0]
    with pytest.raises(SwimInputError, match="pole"):
        region_columns(lat, lon, 80.0, 0.0, 15.0)


def test_global_file_needs_a_place_and_a_sane_radius(shared_data):
    path = _path(shared_data, GRIB2)
    with pytest.raises(SwimInputError, match="--lat/--lon"):
        open_scene(path)
    with pytest.raises(SwimInputError, match="radius"):
        read_gfs_grib(path, lat=45.0, lon=10.0, radius_deg=MAX_RADIUS_DEG + 5.0)


def test_grb_file_opens_too(shared_data):
    # gfs.grb is named as GRIB1 but its messages are GRIB edition 2; the reader takes either edition
    scene = open_scene(_path(shared_data, GRB), lat=30.0, lon=-90.0, radius_deg=10.0)
    assert str(scene["time"].values)[:16] == "2011-10-11T00:00"
    assert scene.attrs["grib_edition"] in (1, 2)
    assert np.all(np.diff(scene["height"].values, axis=0) > 0)


def test_not_a_gfs_grib(tmp_path):
    fake = tmp_path / "model.grib2"
    fake.write_bytes(b"GRIB" + b"\0" * 60)
    with pytest.raises(SwimInputError, match="scene_from_arrays"):
        open_scene(fake, lat=0.0, lon=0.0)


def test_liquid_ice_split():
    t = np.array([300.0, 275.0, 273.16, 261.66, 250.16, 240.0])
    alpha = liquid_fraction(t)
    assert alpha[:3].tolist() == [1.0, 1.0, 1.0]  # above 0 deg C: all liquid
    assert alpha[-2:].tolist() == [0.0, 0.0]  # below -23 deg C: all ice
    assert alpha[3] == pytest.approx(0.25)  # half way in temperature: a quarter liquid
    total = np.array([1e-4, 2e-4, 3e-4, 4e-4, 5e-4, 6e-4])
    liquid, ice = split_condensate(total, t)
    np.testing.assert_allclose(liquid + ice, total, rtol=0, atol=1e-18)
    assert ice[0] == 0.0 and liquid[-1] == 0.0


def test_density_against_the_ideal_gas_law():
    p, t, rh = 85000.0, 280.0, 0.8
    e = rh * 611.2 * np.exp(17.67 * 6.85 / (6.85 + 243.5))  # Bolton (1980) over water, 6.85 deg C
    q = 0.622 * e / (p - 0.378 * e)  # specific humidity
    rho = p / (287.05 * t * (1.0 + 0.6078 * q))
    assert moist_air_density(p, t, rh) == pytest.approx(rho, rel=2e-4)
    assert moist_air_density(p, t) == pytest.approx(p / (287.05 * t))


def test_geometric_height():
    assert geometric_height(10_000.0) == pytest.approx(10_015.7, abs=0.1)
    assert geometric_height(0.0) == 0.0


def test_condensate_conserved_by_the_split(scene):
    """liquid + ice = total condensate x moist air density: the column water paths hold the file's clwmr."""
    total = scene["cloud_liquid_content"].values + scene["cloud_ice_content"].values
    dz = layer_thickness(scene["height"].values, scene["terrain_height"].values)
    path = (total * dz).sum(axis=0)
    assert 0.0 < path.max() < 5.0  # kg m-2
    cold = scene["cloud_liquid_content"].values[-1]  # 100 hPa: below -23 deg C everywhere
    assert np.all(cold == 0.0)


def test_small_render_is_finite(scene):
    import swim

    image = swim.render(scene, lat=45.0, lon=10.0, camera_options={"size": 33})
    inside = np.isfinite(image["view_zenith"].values)  # the all-sky circle
    radiance = image["radiance"].values[:, inside]
    assert inside.sum() > 500 and np.isfinite(radiance).all() and radiance.min() > 0


def test_cli_renders_the_region_around_lat_lon(shared_data, tmp_path):
    from typer.testing import CliRunner

    from swim.cli.main import app

    path, out = _path(shared_data, GRIB2), tmp_path / "gfs.png"
    result = CliRunner().invoke(app, ["render", str(path), "--lat", "45", "--lon", "10", "--region-radius", "8",
                                      "--size", "33", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert out.is_file() and "sun zenith 66." in result.output  # 45 N, 10 E on 2011-01-15 at 12 UTC
    result = CliRunner().invoke(app, ["render", "--region-radius", "8", "--size", "9", "--out", str(out)])
    assert result.exit_code == 2 and "--region-radius cuts the region of a GRIB" in result.output
    assert "scene only" in result.output


def test_the_cli_help_quotes_the_readers_radii():
    import typer

    from swim.cli.main import app

    command = typer.main.get_command(app).commands["render"]
    text = " ".join(next(p.help for p in command.params if p.name == "region_radius").split())
    assert f"{DEFAULT_RADIUS_DEG:g} for GFS" in text and f"at most {MAX_RADIUS_DEG:g}" in text


# --- choosing the reader of a GRIB file ---------------------------------------------------------------------------

@pytest.mark.parametrize("name, reader", [(GRIB2, "read_gfs_grib"), (GRB, "read_gfs_grib"),
                                          ("rap_native/rap.wrfnat.grib2", "read_ncep_grib"),
                                          ("hrrr_smoke/hrrr.t00z.wrfprsf00-atmo-chem.grib2", "read_ncep_grib")])
def test_grib_reader_for_the_sample_files(shared_data, name, reader):
    """GFS (regular lat-lon), RAP (generating process 105, rotated lat-lon 3.32769) and HRRR (process 83,
    Lambert conformal)."""
    from swim.io.grib import grib_reader_for

    assert grib_reader_for(_path(shared_data, name)).__name__ == reader


def test_grib_reader_for_refuses_other_grids_and_non_grib(shared_data, tmp_path):
    """A Lambert conformal grid of another centre than NCEP (here the HRRR message relabelled as the Canadian
    Meteorological Centre's) is no model swim reads; a file named .grib2 that is not GRIB is refused too."""
    import eccodes

    from swim.io.grib import grib_reader_for

    with open(_path(shared_data, "hrrr_smoke/hrrr.t00z.wrfprsf00-atmo-chem.grib2"), "rb") as f:
        h = eccodes.codes_grib_new_from_file(f)
    try:
        eccodes.codes_set(h, "centre", 54)
        (tmp_path / "cwao.grib2").write_bytes(eccodes.codes_get_message(h))
    finally:
        eccodes.codes_release(h)
    with pytest.raises(SwimInputError, match="centre cwao, generating process 83, grid 'lambert'.*GRIB2 of NCEP GFS"):
        grib_reader_for(tmp_path / "cwao.grib2")
    (tmp_path / "junk.grib2").write_bytes(b"no GRIB here")
    with pytest.raises(SwimInputError, match="junk.grib2: not readable as GRIB"):
        grib_reader_for(tmp_path / "junk.grib2")


def test_the_groups_share_one_index_and_decode_lazily(shared_data, monkeypatch):
    """The file's headers are indexed once for all five groups of messages (cfgrib re-indexing the file per group
    took 3-4 times longer), and no group is loaded whole before its region is cut."""
    from swim.io import grib

    calls, groups = [], []
    index, open_messages = grib.grib_index, grib._open_messages
    monkeypatch.setattr(grib, "grib_index", lambda *a: calls.append(a) or index(*a))
    monkeypatch.setattr(grib, "_open_messages", lambda *a, **k: groups.append(open_messages(*a, **k)) or groups[-1])
    scene = grib.read_gfs_grib(_path(shared_data, GRIB2), lat=45.0, lon=10.0, radius_deg=5.0)
    assert len(calls) == 1 and len(groups) == 5 and scene.sizes["z"] == 21
    assert not any(ds[name].variable._in_memory for ds in groups for name in ds.data_vars)
