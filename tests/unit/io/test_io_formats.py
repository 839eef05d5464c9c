"""open_scene recognises each real sample by its content, whatever its name, and names what it expected where no
reader takes a file."""

from __future__ import annotations

import shutil

import pytest

from swim.errors import SwimInputError
from swim.io.formats import NETCDF_FORMATS, file_kind
from swim.io.scene import open_scene, scene_reader

pytestmark = pytest.mark.realdata


@pytest.mark.parametrize("relative, reader", [
    ("era5_columns/era5_reanalysis-2018-08-20T11_00_00.nc", "read_era5_pressure_levels"),
    ("ifs_profiles/S3COM_input_test_NWPSAF_10pt.nc", "read_ifs_model_levels"),
    ("icon_les/S3COM_input_test_ICON_Sc.nc", "read_icon"),
    ("icon_unstructured/icon_test.nc", "read_icon"),
    ("wrf_katrina/ci_test_file.nc", "read_wrf"),
    ("gfs/gfs.t12z.pgrbf120.2p5deg.grib2", "read_gfs_grib"),
    ("rap_native/rap.wrfnat.grib2", "read_ncep_grib"),
    ("hrrr_smoke/hrrr.t00z.wrfprsf00-atmo-chem.grib2", "read_ncep_grib"),
    ("les/rico32x37x26.txt", "read_shdom_les"),
])
def test_each_sample_finds_its_reader_by_content(shared_data, tmp_path, relative, reader):
    found, kind, dataset = scene_reader(shared_data / relative)
    if dataset is not None:
        dataset.close()
    assert found.__name__ == reader
    renamed = tmp_path / "model_output.bin"  # the name says nothing
    shutil.copyfile(shared_data / relative, renamed)
    again, _, dataset = scene_reader(renamed)
    if dataset is not None:
        dataset.close()
    assert again is found


def test_samples_open_through_open_scene(shared_data):
    era5 = open_scene(shared_data / "era5_columns" / "era5_reanalysis-2018-08-20T11_00_00.nc")
    assert era5.sizes["z"] == 37 and float(era5["height"].isel(z=-1).min()) > 15_000.0
    icon = open_scene(shared_data / "icon_les" / "S3COM_input_test_ICON_Sc.nc")
    assert icon.sizes["z"] == 150 and "cloud_liquid_content" in icon


def test_files_no_reader_takes_are_named(shared_data, tmp_path):
    with pytest.raises(SwimInputError, match="no hydrometeor.*HRRR-Smoke.*hrrr_smoke_content"):
        open_scene(shared_data / "hrrr_smoke" / "hrrr.t00z.wrfprsf00-atmo-chem.grib2", lat=35.0, lon=-95.0)
    png = tmp_path / "sky.png"
    png.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(64))
    assert file_kind(png) == "unknown"
    with pytest.raises(SwimInputError, match="neither GRIB, netCDF.*ICON.*MPAS.*scene_from_arrays"):
        open_scene(png)


def test_the_canonical_scene_is_the_last_layout_tried():
    assert NETCDF_FORMATS[-1].name == "canonical scene"
    assert len({f.name for f in NETCDF_FORMATS}) == len(NETCDF_FORMATS)


def test_datasets_in_memory_go_through_the_same_table(shared_data):
    import xarray as xr

    from swim.io.scene import as_scene

    path = shared_data / "era5_columns" / "era5_reanalysis-2018-08-20T11_00_00.nc"
    with xr.open_dataset(path) as ds:
        from_memory = as_scene(ds.load())
    from_file = open_scene(path)
    xr.testing.assert_allclose(from_memory.drop_attrs(), from_file.drop_attrs())
    assert as_scene(from_file) is from_file  # a canonical scene is returned as it is


def test_an_open_file_is_closed_when_an_option_is_refused(shared_data, tmp_path):
    import gc
    import os
    import shutil

    fd_dir = "/proc/self/fd"
    if not os.path.isdir(fd_dir):
        pytest.skip("needs /proc/self/fd to list the open files")
    path = tmp_path / "era5.nc"
    shutil.copyfile(shared_data / "era5_columns" / "era5_reanalysis-2018-08-20T11_00_00.nc", path)

    def held():
        gc.collect()
        return [f for f in os.listdir(fd_dir) if os.path.realpath(os.path.join(fd_dir, f)) == str(path.resolve())]

    with pytest.raises(SwimInputError, match="unknown option"):
        open_scene(path, tme="2018-08-20T11:00")
    assert held() == []
