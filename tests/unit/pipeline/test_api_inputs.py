"""Bad arguments to the public API end in a SwimInputError that names the argument, before any work: not a TypeError
or AttributeError from deep inside."""

import numpy as np
import pytest
import xarray as xr

import swim
from swim.errors import SwimInputError
from swim.pipeline import write_png


@pytest.fixture(scope="module")
def scene():
    from swim.io.default_scene import default_scene

    return default_scene()


def _render(scene, **kwargs):  # the inputs' checks, with the paper's cloud scattering (no 3-D solve per aerosol)
    kwargs.setdefault("settings", swim.MarchSettings(cloud_scattering="albers2020"))
    kwargs.setdefault("camera_options", {"size": 9})
    return swim.render(scene, camera="allsky", sun_zenith=40.0, sun_azimuth=150.0, **kwargs)


@pytest.mark.parametrize("height", ["2", True, None, -1.0, np.nan, 1j])
def test_a_height_that_is_not_a_number_is_refused(scene, height):
    with pytest.raises(SwimInputError, match="observer height must be a number"):
        _render(scene, height=height)


def test_numpy_heights_are_numbers(scene):
    assert _render(scene, height=np.float32(2.0))["radiance"].shape == (3, 9, 9)


@pytest.mark.parametrize("aerosol", [0, 0.1, {"aod_550": 0.1}])
def test_an_aerosol_that_is_not_a_type_or_background_is_refused(scene, aerosol):
    with pytest.raises(SwimInputError, match="^aerosol must be"):
        _render(scene, aerosol=aerosol)


def test_a_misspelt_reader_option_is_named(shared_data):
    with pytest.raises(SwimInputError, match="unknown option.*'tme'.*WRF wrfout file.*time"):
        swim.open_scene(shared_data / "wrf_katrina" / "ci_test_file.nc", tme="2005-08-28T18:00")
    with pytest.raises(SwimInputError, match="unknown option.*'lat'.*LES file.*reference_lat"):
        swim.open_scene(shared_data / "les" / "rico122x106x39.txt", lat=10.0)


@pytest.mark.parametrize("image", [xr.Dataset(), xr.Dataset({"rgb": (("y", "x"), np.zeros((2, 2), np.uint8))}),
                                   "image.png"])
def test_write_png_wants_a_rendered_image(tmp_path, image):
    with pytest.raises(SwimInputError, match="write_png: image must be a rendered image"):
        write_png(image, tmp_path / "out.png")
    assert not (tmp_path / "out.png").exists()


def test_aerosol_none_switches_the_background_off(scene):
    none = _render(scene, aerosol="none")
    assert none.attrs["aerosol_optical_depth_550"] == 0.0
    clean = _render(scene, aerosol=swim.AerosolBackground(aod_550=0.0))
    np.testing.assert_array_equal(none["radiance"].values, clean["radiance"].values)


def test_an_image_too_big_for_the_memory_is_refused_before_any_work(scene, monkeypatch):
    import swim.memory

    monkeypatch.setattr(swim.memory, "available_memory_bytes", lambda: 1_000_000)
    with pytest.raises(SwimInputError, match=r"an image of 10,201 pixels needs about .* GiB to render, more than"):
        _render(scene, camera_options={"size": 101})
    image = _render(scene, camera_options={"size": 101}, check_memory=False)
    assert image["rgb"].shape == (101, 101, 3)
