"""A series from a scene file of several model times renders each frame from its nearest model time, within the
readers' 90 min; frames beyond that are refused unless the fields are frozen on purpose."""

import numpy as np
import pandas as pd
import pytest
import xarray as xr
from typer.testing import CliRunner

from swim.cli.main import app
from swim.constants import STANDARD_GRAVITY
from swim.errors import SwimInputError
from swim.series import model_time_frames, scene_file_times

NZ, NY, NX = 4, 6, 6
TIMES = ("2020-07-01_12:00:00", "2020-07-01_15:00:00", "2020-07-01_18:00:00")


@pytest.fixture(scope="module")
def wrfout(tmp_path_factory):
    """A small wrfout-like file with three times 3 h apart, its cloud growing from one time to the next."""
    nt = len(TIMES)
    z_w = 100.0 + 500.0 * np.arange(NZ + 1)
    ph = np.broadcast_to((z_w * STANDARD_GRAVITY)[None, :, None, None], (nt, NZ + 1, NY, NX)).copy()
    p = np.broadcast_to(np.linspace(95000.0, 80000.0, NZ)[None, :, None, None], (nt, NZ, NY, NX)).copy()
    qc = np.zeros((nt, NZ, NY, NX))
    for t in range(nt):
        qc[t, 1, 2:4, 2:4] = 2e-4 * (t + 1)
    lat = np.broadcast_to(np.linspace(39.98, 40.02, NY)[None, :, None], (nt, NY, NX)).copy()
    lon = np.broadcast_to(np.linspace(-105.03, -104.97, NX)[None, None, :], (nt, NY, NX)).copy()
    d4, d4w, d3 = (("Time", "bottom_top", "south_north", "west_east"),
                   ("Time", "bottom_top_stag", "south_north", "west_east"), ("Time", "south_north", "west_east"))
    ds = xr.Dataset({
        "Times": ("Time", np.array([t.encode() for t in TIMES])),
        "PH": (d4w, np.zeros_like(ph)), "PHB": (d4w, ph), "P": (d4, np.zeros_like(p)), "PB": (d4, p),
        "T": (d4, np.zeros_like(p)), "QVAPOR": (d4, np.full_like(p, 0.01)), "QCLOUD": (d4, qc),
        "HGT": (d3, np.full((nt, NY, NX), 100.0)), "XLAT": (d3, lat), "XLONG": (d3, lon),
        "XLAND": (d3, np.ones((nt, NY, NX))),
    }, attrs={"TITLE": " OUTPUT FROM WRF V4.4 MODEL", "DX": 1000.0, "DY": 1000.0, "MAP_PROJ": 1})
    path = tmp_path_factory.mktemp("wrf") / "wrfout_d01_2020-07-01_12:00:00"
    ds.to_netcdf(path, format="NETCDF3_64BIT")
    return path


def test_each_frame_takes_its_nearest_model_time(wrfout):
    assert [str(t) for t in scene_file_times(wrfout)] == ["2020-07-01 12:00:00", "2020-07-01 15:00:00",
                                                          "2020-07-01 18:00:00"]
    frames = model_time_frames(wrfout, ["2020-07-01T12:30", "2020-07-01T14:00", "2020-07-01T16:20",
                                        "2020-07-01T19:30"])
    assert [f["open_options"]["time"][11:16] for f in frames] == ["12:00", "15:00", "15:00", "18:00"]
    assert [f["time"] for f in frames][0] == pd.Timestamp("2020-07-01T12:30")


def test_frames_beyond_90_min_are_refused_unless_frozen(wrfout):
    with pytest.raises(SwimInputError, match="frame 1 at 2020-07-01 20:00 UTC is 0 days 02:00:00 from the nearest "
                                             "model time.*--freeze-fields"):
        model_time_frames(wrfout, ["2020-07-01T18:00", "2020-07-01T20:00"])
    frozen = model_time_frames(wrfout, ["2020-07-01T12:00", "2020-07-03T12:00"], freeze_fields=True)
    assert {f["open_options"]["time"][11:16] for f in frozen} == {"12:00"}


def test_the_cli_series_steps_through_the_model_times(wrfout, tmp_path):
    pattern = str(tmp_path / "{time:%H%M}.nc")
    result = CliRunner().invoke(app, [
        "render", str(wrfout), "--time", "2020-07-01T13:00", "--end", "2020-07-01T17:00", "--every", "120",
        "--size", "9", "--netcdf", pattern])
    assert result.exit_code == 0, result.output
    scene_times = {}
    for name in ("1300", "1500", "1700"):
        with xr.open_dataset(tmp_path / f"{name}.nc") as ds:
            scene_times[name] = ds.attrs["scene_time"][11:16]
    assert scene_times == {"1300": "12:00", "1500": "15:00", "1700": "18:00"}
    late = CliRunner().invoke(app, ["render", str(wrfout), "--time", "2020-07-01T17:00", "--end",
                                    "2020-07-01T21:00", "--every", "60", "--size", "9", "--netcdf", pattern])
    assert late.exit_code == 2 and "--freeze-fields" in late.output
