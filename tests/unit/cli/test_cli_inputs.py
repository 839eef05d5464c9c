"""The command line's small promises: its version, options that only work together, an LES scene placed without a
word of where, and no noise from JAX's search for accelerators in ``-v``."""

import logging

import numpy as np
from typer.testing import CliRunner

from swim import __version__
from swim.cli.main import app


def test_version():
    result = CliRunner().invoke(app, ["--version"])
    assert result.exit_code == 0 and result.output.strip() == f"swim {__version__}"


def test_view_zenith_needs_view_azimuth(tmp_path):
    out = tmp_path / "x.png"
    result = CliRunner().invoke(app, ["render", "--camera", "perspective", "--view-zenith", "30", "--size", "9",
                                      "--out", str(out)])
    assert result.exit_code == 2 and "--view-zenith needs --view-azimuth" in result.output
    assert len(result.output.strip().splitlines()) == 1 and "Traceback" not in result.output
    assert not out.exists()


def test_an_les_scene_without_a_place_is_placed_with_a_warning(shared_data, caplog):
    from swim.io.les import read_shdom_les

    with caplog.at_level(logging.WARNING, logger="swim.io.les"):
        scene = read_shdom_les(shared_data / "les" / "rico32x37x26.txt")
    assert "no geolocation" in caplog.text and "--scene-lat" in caplog.text
    assert float(scene.attrs["reference_lat"]) == 0.0 and float(scene.attrs["reference_lon"]) == 0.0
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="swim.io.les"):
        read_shdom_les(shared_data / "les" / "rico32x37x26.txt", reference_lat=15.0, reference_lon=-60.0)
    assert "no geolocation" not in caplog.text


def test_the_verbose_log_leaves_out_jax_s_accelerator_search():
    search = logging.getLogger("jax._src.xla_bridge")
    search.setLevel(logging.NOTSET)
    result = CliRunner().invoke(app, ["-v", "render", "--help"])  # the group's callback configures the log
    assert result.exit_code == 0
    assert search.level == logging.WARNING


def test_aerosol_none(tmp_path):
    out = tmp_path / "clean.png"
    result = CliRunner().invoke(app, ["render", "--aerosol", "none", "--size", "9", "--sun-zenith", "40",
                                      "--sun-azimuth", "150", "--cloud-scattering", "albers2020", "--out", str(out)])
    assert result.exit_code == 0 and out.is_file(), result.output
    result = CliRunner().invoke(app, ["render", "--aerosol", "none", "--aod", "0.2", "--size", "9", "--out",
                                      str(tmp_path / "x.png")])
    assert result.exit_code == 2 and "--aerosol none has no optical depth" in result.output


def test_a_size_beyond_the_memory_is_refused_at_once(tmp_path):
    out = tmp_path / "big.png"
    result = CliRunner().invoke(app, ["render", "--size", "100000", "--out", str(out)])
    assert result.exit_code == 2 and "needs about" in result.output and "--no-memory-check" in result.output
    assert len(result.output.strip().splitlines()) == 1 and not out.exists()


def test_quiet_reports_nothing_but_errors(tmp_path):
    out = tmp_path / "q.png"
    try:
        result = CliRunner().invoke(app, ["-q", "render", "--size", "9", "--sun-zenith", "40", "--sun-azimuth",
                                          "150", "--cloud-scattering", "albers2020", "--out", str(out)])
        assert result.exit_code == 0 and out.is_file() and result.output.strip() == ""
        bad = CliRunner().invoke(app, ["-q", "render", "--size", "9", "--out", str(tmp_path / "q.bmp")])
        assert bad.exit_code == 2 and "unknown image format" in bad.output
    finally:
        CliRunner().invoke(app, ["render", "--help"])  # the next command in this process is not quiet
    loud = CliRunner().invoke(app, ["render", "--size", "9", "--sun-zenith", "40", "--sun-azimuth", "150",
                                    "--cloud-scattering", "albers2020", "--out", str(out)])
    assert "wrote" in loud.output


def test_exposure_options(tmp_path):
    """--white-level auto meters the image, --exposure shifts it in stops; a bad value of either is one line, exit
    code 2 and no file."""
    import xarray as xr

    base = ["render", "--size", "9", "--sun-zenith", "40", "--sun-azimuth", "150", "--cloud-scattering", "albers2020"]
    nc = tmp_path / "auto.nc"
    result = CliRunner().invoke(app, [*base, "--white-level", "auto", "--exposure", "1", "--out",
                                      str(tmp_path / "auto.png"), "--netcdf", str(nc)])
    assert result.exit_code == 0, result.output
    with xr.open_dataset(nc) as image:
        assert image.attrs["exposure"] == "auto" and image.attrs["exposure_ev"] == 1.0
        assert 0.0 < image.attrs["white_level"] < 10.0
    for option, value, message in (("--white-level", "bright", "--white-level"), ("--white-level", "-1", "white_level"),
                                   ("--exposure", "40", "exposure")):
        out = tmp_path / "x.png"
        result = CliRunner().invoke(app, [*base, option, value, "--out", str(out)])
        assert result.exit_code == 2 and message in result.output, result.output
        assert len(result.output.strip().splitlines()) == 1 and "Traceback" not in result.output
        assert not out.exists()


def test_a_clear_site_from_the_command_line(tmp_path):
    """--site renders swim ghi's cloud-free site scene at --lat/--lon and --elevation: no cloud on the line of sight
    and the observer on the site's ground; without its place or time, or beside a scene file, it is refused."""
    import xarray as xr

    nc = tmp_path / "site.nc"
    result = CliRunner().invoke(app, ["render", "--site", "--lat", "37.70", "--lon", "-105.92", "--elevation", "2317",
                                      "--time", "2016-06-01T18:00", "--aod", "0.1", "--size", "15", "--out",
                                      str(tmp_path / "site.png"), "--netcdf", str(nc)])
    assert result.exit_code == 0, result.output
    with xr.open_dataset(nc) as image:
        assert image.attrs["observer_height_asl_m"] == 2317.0 + 2.0
        assert abs(image.attrs["observer_lat"] - 37.70) < 1e-9 and image.attrs["aerosol_optical_depth_550"] == 0.1
        assert float(np.nanmax(image["tau_hydrometeor"].values)) == 0.0
    for args, message in ((["--lat", "37.7"], "--lat and --lon"),
                          (["--lat", "37.7", "--lon", "-105.9"], "--time"),
                          (["scene.nc", "--lat", "37.7", "--lon", "-105.9", "--time", "2016-06-01T18:00"], "one or the other")):
        result = CliRunner().invoke(app, ["render", "--site", *args, "--size", "9", "--out", str(tmp_path / "x.png")])
        assert result.exit_code == 2 and message in result.output, result.output
        assert len(result.output.strip().splitlines()) == 1


def test_model_aerosol_options_go_together(tmp_path):
    out = tmp_path / "x.png"
    for args, message in ((["--aerosol-file", str(tmp_path / "cams.nc")], "needs --aerosol-table"),
                          (["--aerosol-table", str(tmp_path / "t.nc")], "--aerosol-file, which is not given")):
        result = CliRunner().invoke(app, ["render", "--size", "9", "--out", str(out), *args])
        assert result.exit_code == 2 and message in result.output and "Traceback" not in result.output
    assert not out.exists()


def test_default_aerosol_type_follows_the_scene():
    from swim.cli.main import _aerosol_background

    smoke = {"smoke_mass_content": None}
    assert _aerosol_background(smoke, None, None, 0.0, 20.0, None, None, None, None, None).type_name == "smoke"
    assert _aerosol_background(smoke, None, None, 0.0, 20.0, None, None, None, None, None).aod_550 == 0.0
    assert _aerosol_background({}, None, None, 0.0, 20.0, None, None, None, None, None).type_name == "continental"
    named = _aerosol_background(smoke, "sea_salt", None, 0.0, 20.0, None, None, None, None, None)
    assert named.type_name == "sea_salt"


def test_globe_options_are_checked_before_reading(tmp_path, shared_data):
    out = tmp_path / "x.png"
    gfs = str(shared_data / "gfs" / "gfs.t12z.pgrbf120.2p5deg.grib2")
    for args, message in ((["--globe"], "--globe needs a global GRIB file"),
                          ([gfs, "--globe", "--lat", "10"], "give both --lat and --lon")):
        result = CliRunner().invoke(app, ["render", "--size", "9", "--out", str(out), *args])
        assert result.exit_code == 2 and message in result.output and "Traceback" not in result.output
    assert not out.exists()


def test_towns_add_their_city_lights_to_the_scene():
    """--town 'LAT,LON,POPULATION' adds a town's upward light to the scene's emission (the town's flux:
    population x 1000 lm x the upward share, Garstang 1986) with the --lamps spectrum; bad towns and lamps are
    refused."""
    import pytest

    from swim.cli.main import _with_towns
    from swim.errors import SwimInputError
    from swim.io.default_scene import default_scene
    from swim.surface.city_lights import LUMENS_PER_PERSON, cell_areas, upward_fraction

    scene = default_scene()
    assert _with_towns(scene, None, "sodium") is scene
    lat, lon = float(scene["lat"].values.mean()), float(scene["lon"].values.mean())
    lit = _with_towns(scene, [f"{lat},{lon},20000", f"{lat + 0.1},{lon},5000"], "led")
    emission = lit["upward_light_emission"]
    assert emission.attrs["lamp_spectrum"] == "led" and emission.dims == ("y", "x")
    flux = float((emission.values * cell_areas(scene["lat"].values, scene["lon"].values)).sum())
    assert flux == pytest.approx(25000 * LUMENS_PER_PERSON * upward_fraction(), rel=1e-6)
    # --lamps alone relabels the scene's own emission; without it a new town keeps the scene's lamps
    assert _with_towns(lit, None, "sodium")["upward_light_emission"].attrs["lamp_spectrum"] == "sodium"
    assert _with_towns(lit, [f"{lat},{lon},100"], None)["upward_light_emission"].attrs["lamp_spectrum"] == "led"
    for towns, lamps in ((["24.7,-88.6"], "sodium"), (["a,b,c"], "sodium"), ([f"{lat},{lon},100"], "neon")):
        with pytest.raises(SwimInputError, match="--town|--lamps"):
            _with_towns(scene, towns, lamps)
    for bad, message in (("nan,-105.3,1000", "latitude"), (f"{lat},{lon},0", "population"),
                         ("24.7,-88.6,1000", "outside its grid")):
        with pytest.raises(SwimInputError, match=message):
            _with_towns(scene, [bad], None)
