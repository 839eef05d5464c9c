"""Output files: written through symlinks, never over something that is not a regular file, checked before the
render, in the format of their suffix, with what they show written into them, and an image and its netCDF file
both or neither."""

import os
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

import swim
import swim.io.outputs
from swim.cli.main import app
from swim.errors import SwimInputError
from swim.io.atomic import atomic_write, check_output_path
from swim.pipeline import write_image, write_outputs


@pytest.fixture(scope="module")
def image():
    from swim.io.default_scene import default_scene

    return swim.render(default_scene(), camera="allsky", camera_options={"size": 9}, sun_zenith=40.0,
                       sun_azimuth=150.0, settings=swim.MarchSettings(cloud_scattering="albers2020"))


def test_a_symlink_is_written_through(tmp_path, image):
    target = tmp_path / "real.png"
    target.write_bytes(b"old")
    link = tmp_path / "link.png"
    link.symlink_to(target)
    write_image(image, link)
    assert link.is_symlink() and Image.open(target).format == "PNG"


@pytest.mark.parametrize("kind", ["directory", "fifo", "parent is a file"])
def test_what_is_not_a_regular_file_is_refused(tmp_path, kind):
    if kind == "directory":
        path = tmp_path / "d.png"
        path.mkdir()
    elif kind == "fifo":
        path = tmp_path / "f.png"
        os.mkfifo(path)
    else:
        (tmp_path / "file").write_text("x")
        path = tmp_path / "file" / "x.png"
    before = sorted(tmp_path.iterdir())
    with pytest.raises(SwimInputError, match="is a directory|not a regular file|is not a folder"):
        atomic_write(path, lambda tmp: Path(tmp).write_text("new"))
    with pytest.raises(SwimInputError):
        check_output_path(path, "--out")
    assert sorted(tmp_path.iterdir()) == before  # nothing replaced, no temporary file left


@pytest.mark.parametrize("suffix, fmt", [(".png", "PNG"), (".jpg", "JPEG"), (".JPEG", "JPEG"), (".tif", "TIFF")])
def test_the_suffix_chooses_the_format(tmp_path, image, suffix, fmt):
    path = write_image(image, tmp_path / f"sky{suffix}")
    with Image.open(path) as im:
        assert im.format == fmt and im.size == (9, 9)
        if fmt == "PNG":
            assert im.text["Software"].startswith("swim") and "sun zenith 40.00 deg" in im.text["Description"]


def test_an_unknown_suffix_is_refused_before_the_render(tmp_path):
    out = tmp_path / "sky.bmp"
    result = CliRunner().invoke(app, ["render", "--size", "9", "--out", str(out)])
    assert result.exit_code == 2 and "unknown image format '.bmp'" in result.output
    assert len(result.output.strip().splitlines()) == 1 and not out.exists()


def test_a_netcdf_that_cannot_be_written_stops_the_render_before_the_image(tmp_path):
    (tmp_path / "file").write_text("x")
    out = tmp_path / "sky.png"
    result = CliRunner().invoke(app, ["render", "--size", "9", "--out", str(out), "--netcdf",
                                      str(tmp_path / "file" / "sky.nc")])
    assert result.exit_code == 2 and "--netcdf" in result.output and "Traceback" not in result.output
    assert not out.exists()


def test_an_image_and_its_netcdf_are_written_both_or_neither(tmp_path, image, monkeypatch):
    write_outputs(image, tmp_path / "a.png", tmp_path / "a.nc")
    assert (tmp_path / "a.png").is_file() and (tmp_path / "a.nc").is_file()
    with pytest.raises(SwimInputError, match="unknown image format"):
        write_outputs(image, tmp_path / "b.bmp", tmp_path / "b.nc")

    def broken(image, tmp):
        raise OSError("disk full")

    monkeypatch.setattr(swim.io.outputs, "_netcdf_to", broken)
    with pytest.raises(OSError):
        write_outputs(image, tmp_path / "c.png", tmp_path / "c.nc")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.nc", "a.png"]
    np.testing.assert_array_equal(np.asarray(Image.open(tmp_path / "a.png")), image["rgb"].values)


def test_the_netcdf_follows_cf(tmp_path, image):
    """What cfchecker (CF-1.8) checks in the image's file: no variable-length strings (CF 2.2: the channel labels are
    a character variable), units on every data variable, standard names where CF has them, a time coordinate even
    with the sun set by angles (the scene's time then), and the march settings and exposure as attributes."""
    import netCDF4
    import xarray as xr

    path = swim.write_netcdf(image, tmp_path / "a.nc")
    with netCDF4.Dataset(path) as nc:
        for name, var in nc.variables.items():
            assert not isinstance(var.datatype, netCDF4.VLType) and var.dtype is not str, name
        assert nc.getncattr("Conventions") == "CF-1.8"
        for name in ("radiance", "radiance_clear", "rgb", "view_zenith", "view_azimuth", "tau_hydrometeor"):
            assert "units" in nc.variables[name].ncattrs(), name
        assert nc.variables["view_zenith"].standard_name == "sensor_zenith_angle"
        assert nc.variables["view_azimuth"].standard_name == "sensor_azimuth_angle"
        assert nc.variables["wavelength"].standard_name == "radiation_wavelength"
        assert nc.variables["time"].standard_name == "time" and "since" in nc.variables["time"].units
        assert "channel_name" in nc.variables["rgb"].coordinates
        assert nc.getncattr("settings_n_grid") == image.attrs["settings_n_grid"] > 0
        assert nc.getncattr("display_transform") == "filmic" and nc.getncattr("exposure") == "fixed"
    with xr.open_dataset(path) as back:
        assert [c.decode() for c in back["channel_name"].values] == ["R", "G", "B"]
        assert back["time"].values == np.datetime64(swim.default_scene()["time"].values)
        np.testing.assert_array_equal(back["rgb"].values, image["rgb"].values)
    assert list(image["channel"].values) == ["R", "G", "B"]  # the image in memory keeps its labels
