"""Many frames (swim.series): each frame is the image that swim.render gives alone, the sun follows the ephemeris from
frame to frame, files are named per frame, bad series fail before any frame, and a dask cluster gives the same
frames."""

import numpy as np
import pandas as pd
import pytest
import xarray as xr
from PIL import Image
from typer.testing import CliRunner

import swim
from swim.errors import SwimInputError
from swim.series import COLUMNS, render_series, series_times

SIZE = {"size": 47}
#: The series' own behaviour is tested with the paper's cloud scattering, which needs no diffuse solve per sun; the
#: 3-D method's reuse of its solution across frames: test_a_series_shares_the_3d_solution_while_the_sun_moves_little
PAPER = swim.MarchSettings(cloud_scattering="albers2020")
LAT, LON = 40.0, -105.3  # the default scene's reference point, where its observer stands by default


@pytest.fixture(scope="module")
def scene():
    return swim.default_scene()


def _pixels(path):
    return np.asarray(Image.open(path))


def test_series_times_include_both_ends_and_convert_time_zones():
    times = series_times("2023-06-21T12:00-06:00", "2023-06-21T19:00Z", 30)
    assert list(times) == [pd.Timestamp("2023-06-21T18:00"), pd.Timestamp("2023-06-21T18:30"),
                           pd.Timestamp("2023-06-21T19:00")]
    assert len(series_times("2023-06-21T18:00", "2023-06-21T18:25", 10)) == 3, "an end off the step is not passed"
    with pytest.raises(SwimInputError, match="before its start"):
        series_times("2023-06-21T18:00", "2023-06-21T17:00", 10)
    with pytest.raises(SwimInputError, match="every_minutes must be a number of minutes > 0"):
        series_times("2023-06-21T18:00", "2023-06-21T19:00", 0)
    with pytest.raises(SwimInputError, match="ISO 8601"):
        series_times("noon", "2023-06-21T19:00", 10)


def test_frames_are_the_single_renders_and_the_sun_follows_the_ephemeris(scene, tmp_path):
    import pvlib

    times = series_times("2023-06-21T15:00", "2023-06-21T21:00", 180)
    table = render_series(scene, times, out=tmp_path / "f" / "{time:%H%M}.png", netcdf=tmp_path / "f" / "{index}.nc",
                          camera_options=SIZE, settings=PAPER)
    assert list(table.columns) == list(COLUMNS) and list(table.index) == [0, 1, 2]
    assert list(table["time"]) == list(times)
    assert [p.rsplit("/", 1)[1] for p in table["png"]] == ["1500.png", "1800.png", "2100.png"]
    assert all(p.startswith("/") for p in table["png"]), "absolute, so that workers elsewhere write the same files"
    # each frame is what swim.render gives for that time on its own
    for t, png, nc in zip(times, table["png"], table["netcdf"]):
        alone = swim.render(scene, time=t, camera_options=SIZE, settings=PAPER)
        np.testing.assert_array_equal(_pixels(png), alone["rgb"].values)
        with xr.open_dataset(nc) as written:
            np.testing.assert_allclose(written["radiance"].values, alone["radiance"].values, rtol=1e-6)
    # the sun's path through the morning and afternoon, against pvlib's SPA at the observer
    spa = pvlib.solarposition.get_solarposition(times, LAT, LON)  # the observer's height moves it by < 0.001 deg
    np.testing.assert_allclose(table["sun_zenith_deg"], spa["zenith"], atol=0.05)
    np.testing.assert_allclose(table["sun_azimuth_deg"], spa["azimuth"], atol=0.05)
    assert table["sun_zenith_deg"].iloc[1] < table["sun_zenith_deg"].iloc[0], "the sun climbs towards noon"
    assert (table["traced_pixels"] > 1000).all() and (table["seconds"] > 0).all()


def test_a_series_shares_the_3d_solution_while_the_sun_moves_little(tmp_path, caplog):
    """The 3-D cloud scattering (the default) solves for the node of a grid of suns nearest each frame's sun
    (swim.rt.diffuse_field.solve_sun): frames two minutes apart (the sun moves ~0.5 deg) share a solution, and every
    frame is the image that swim.render gives for that time on its own."""
    from swim.validation.stratus import stratus_scene

    deck = stratus_scene(10.0, n_columns=5).assign_coords(time=np.datetime64("2023-06-21T18:00"))
    times = series_times("2023-06-21T18:00", "2023-06-21T18:06", 2)
    with caplog.at_level("INFO"):
        table = render_series(deck, times, out=tmp_path / "{index}.png", camera_options={"size": 15})
    solves = caplog.text.count("diffuse field: ")
    assert 1 <= solves < len(times) and caplog.text.count("reusing the diffuse field") == len(times) - solves
    for t, png in zip(times, table["png"]):
        alone = swim.render(deck, time=t, camera_options={"size": 15})
        assert alone.attrs["cloud_scattering"] == "discrete_ordinates"
        np.testing.assert_array_equal(_pixels(png), alone["rgb"].values)


def test_frames_as_sites_and_a_scene_file_per_frame(scene, tmp_path):
    path = tmp_path / "scene.nc"
    scene.to_netcdf(path)
    frames = [{"lat": LAT, "lon": LON, "time": "2023-06-21T18:00"},
              {"lat": LAT + 0.02, "lon": LON, "time": "2023-06-21T18:00", "scene": path}]
    table = render_series(scene, frames, out=tmp_path / "{lat:.2f}_{lon:.2f}.png", camera_options=SIZE)
    assert [p.rsplit("/", 1)[1] for p in table["png"]] == ["40.00_-105.30.png", "40.02_-105.30.png"]
    # a time common to all frames names the files as a frame's own does (converted to UTC)
    common = render_series(scene, [{"lat": LAT}, {"lat": LAT + 0.02}], time="2023-06-21T12:00-06:00",
                           out=tmp_path / "c" / "{time:%H%M}_{index}.png", camera_options=SIZE)
    assert [p.rsplit("/", 1)[1] for p in common["png"]] == ["1800_0.png", "1800_1.png"]
    np.testing.assert_array_equal(_pixels(common["png"][0]), _pixels(table["png"][0]))
    np.testing.assert_array_equal(_pixels(table["png"][0]),
                                  swim.render(scene, time="2023-06-21T18:00", camera_options=SIZE)["rgb"].values)
    moved = swim.render(swim.open_scene(path), time="2023-06-21T18:00", lat=LAT + 0.02, lon=LON, camera_options=SIZE)
    np.testing.assert_array_equal(_pixels(table["png"][1]), moved["rgb"].values)
    assert not np.array_equal(_pixels(table["png"][0]), _pixels(table["png"][1])), "another site, another sky"


def test_a_worker_opens_a_rewritten_scene_file_again(scene, tmp_path):
    """Workers keep scene files open between frames; a file rewritten under its name (an hourly "latest" forecast)
    must not be served from that cache."""
    import os

    from swim.series import _opened

    path = tmp_path / "latest.nc"
    scene.to_netcdf(path)
    first = _opened(str(path), (False, ()))
    assert _opened(str(path), (False, ())) is first, "the same file is opened once"
    scene.assign_attrs(title="the next hour").to_netcdf(path)
    later = os.stat(path).st_mtime_ns + 10**9
    os.utime(path, ns=(later, later))
    assert _opened(str(path), (False, ())).attrs["title"] == "the next hour"
    with pytest.raises(SwimInputError, match="scene file not found"):
        _opened(str(tmp_path / "missing.nc"), (False, ()))


def test_bad_series_fail_before_any_frame(scene, tmp_path):
    times = ["2023-06-21T18:00", "2023-06-21T18:10"]
    with pytest.raises(SwimInputError, match="names frames 0 and 1 alike"):
        render_series(scene, times, out=tmp_path / "same.png")
    with pytest.raises(SwimInputError, match="cannot name frame 0"):
        render_series(scene, [{"lat": LAT}], out=tmp_path / "{time:%H%M}.png")
    with pytest.raises(SwimInputError, match="cannot name frame 0"):
        render_series(scene, times, out=tmp_path / "{station}.png")
    with pytest.raises(SwimInputError, match="frames is empty"):
        render_series(scene, [], out=tmp_path / "{index}.png")
    with pytest.raises(SwimInputError, match="frame 1: 'soon' is neither a time"):
        render_series(scene, ["2023-06-21T18:00", "soon"], out=tmp_path / "{index}.png")
    with pytest.raises(SwimInputError, match="needs out"):
        render_series(scene, times)
    with pytest.raises(SwimInputError, match="workers must be"):
        render_series(scene, times, out=tmp_path / "{index}.png", workers=-1)
    with pytest.raises(SwimInputError, match="frame 0: the scene must be"):
        render_series(np.zeros(3), times, out=tmp_path / "{index}.png")
    with pytest.raises(SwimInputError, match="frame 1: time 'later' is not an ISO 8601 UTC time"):
        render_series(scene, [{"time": times[0]}, {"time": "later"}], out=tmp_path / "{index}.png")
    with pytest.raises(SwimInputError, match="frame 0: 1700000000 is neither a time"):
        render_series(scene, [1700000000], out=tmp_path / "{index}.png")
    with pytest.raises(SwimInputError, match="out and netcdf name the same file"):
        render_series(scene, times, out=tmp_path / "{index}.png", netcdf=tmp_path / "{index}.png")
    with pytest.raises(SwimInputError, match="out .*: unknown image format '.gif'"):
        render_series(scene, times, out=tmp_path / "{index}.gif")
    (tmp_path / "1.nc").mkdir()
    with pytest.raises(SwimInputError, match="netcdf .*1.nc: exists and is a directory"):
        render_series(scene, times, netcdf=tmp_path / "{index}.nc")
    (tmp_path / "1.nc").rmdir()
    with pytest.raises(SwimInputError, match="either client .* or workers"):
        render_series(scene, times, out=tmp_path / "{index}.png", workers=2, client=object())
    assert not list(tmp_path.iterdir()), "nothing written"


def test_a_failing_frame_is_named_and_the_frames_before_it_are_whole(scene, tmp_path):
    frames = [{"time": "2023-06-21T18:00"}, {"time": "2023-06-21T18:10", "lat": 95.0}, {"time": "2023-06-21T18:20"}]
    with pytest.raises(SwimInputError, match=r"frame 1 at 2023-06-21 18:10:00 UTC: observer lat must be in"):
        render_series(scene, frames, out=tmp_path / "{index}.png", camera_options=SIZE)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["0.png"]
    assert _pixels(tmp_path / "0.png").shape == (47, 47, 3)


def test_a_frame_that_fails_on_a_cluster_is_named(scene, tmp_path):
    distributed = pytest.importorskip("dask.distributed")
    frames = [{"time": "2023-06-21T18:00"}, {"time": "2023-06-21T18:10", "lat": 95.0}]
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        with pytest.raises(SwimInputError, match=r"frame 1 at 2023-06-21 18:10:00 UTC: observer lat must be in"):
            render_series(scene, frames, out=tmp_path / "{index}.png", client=client, camera_options=SIZE)


def test_a_dask_cluster_renders_the_same_frames(scene, tmp_path):
    distributed = pytest.importorskip("dask.distributed")
    times = series_times("2023-06-21T17:00", "2023-06-21T19:00", 60)
    alone = render_series(scene, times, out=tmp_path / "a" / "{index}.png", camera_options=SIZE, settings=PAPER)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        done = []
        table = render_series(scene, times, out=tmp_path / "b" / "{index}.png", client=client, camera_options=SIZE,
                              progress=lambda n, total: done.append((n, total)), settings=PAPER)
        path = tmp_path / "scene.nc"
        scene.to_netcdf(path)
        from_file = render_series(path, times, out=tmp_path / "c" / "{index}.png", client=client, camera_options=SIZE,
                                  open_options={"time": "2023-06-21T18:00"}, settings=PAPER)  # the workers open it
    assert done[-1] == (3, 3)
    assert list(table["time"]) == list(times)
    for a, b, c in zip(alone["png"], table["png"], from_file["png"]):
        np.testing.assert_array_equal(_pixels(a), _pixels(b))
        np.testing.assert_array_equal(_pixels(a), _pixels(c))
    with pytest.raises(SwimInputError, match="open_options must be a dict"):
        render_series(path, times, out=tmp_path / "d" / "{index}.png", open_options={"time": ["not", "hashable"]})


@pytest.mark.full  # dask worker processes, each importing and compiling anew: the full tier
@pytest.mark.slow
def test_worker_processes_render_the_same_frames(scene, tmp_path):
    pytest.importorskip("dask.distributed")
    times = series_times("2023-06-21T17:00", "2023-06-21T18:00", 20)
    alone = render_series(scene, times, out=tmp_path / "a" / "{index}.png", camera_options=SIZE)
    table = render_series(scene, times, out=tmp_path / "b" / "{index}.png", workers=2, camera_options=SIZE)
    assert table["worker"].nunique() == 2, "both workers rendered"
    for a, b in zip(alone["png"], table["png"]):
        np.testing.assert_array_equal(_pixels(a), _pixels(b))


def test_the_render_command_renders_a_series(tmp_path, monkeypatch):
    from swim.cli.main import app

    monkeypatch.chdir(tmp_path)
    runner = CliRunner()
    result = runner.invoke(app, ["render", "--time", "2023-06-21T18:00", "--end", "2023-06-21T18:20", "--every", "10",
                                 "--size", "31", "--cloud-scattering", "albers2020", "--out", "frames/{time:%H%M}.png"])
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in (tmp_path / "frames").iterdir()) == ["1800.png", "1810.png", "1820.png"]
    same = runner.invoke(app, ["render", "--end", "2023-06-21T18:20", "--size", "31", "--out", "one.png"])
    assert same.exit_code == 2 and "names frames 0 and 1 alike" in same.output
    alone = runner.invoke(app, ["render", "--workers", "2", "--size", "31"])
    assert alone.exit_code == 2 and "--end" in alone.output
    fixed = runner.invoke(app, ["render", "--end", "2023-06-21T18:20", "--sun-zenith", "30", "--out", "{index}.png"])
    assert fixed.exit_code == 2 and "fix the sun" in fixed.output
    nowhere = runner.invoke(app, ["render", "--end", "2023-06-21T18:20", "--size", "31", "--out", "{index}.png",
                                  "--scheduler", "nonsense://x"])
    assert nowhere.exit_code == 2 and "no dask scheduler answered" in nowhere.output
    netcdf_only = runner.invoke(app, ["render", "--time", "2023-06-21T18:00", "--end", "2023-06-21T18:10",
                                      "--size", "31", "--cloud-scattering", "albers2020", "--netcdf", "nc/{index}.nc"])
    assert netcdf_only.exit_code == 0, netcdf_only.output
    assert sorted(p.name for p in (tmp_path / "nc").iterdir()) == ["0.nc", "1.nc"]
    assert not list(tmp_path.glob("*.png")), "no PNG unless --out is given"


@pytest.mark.full  # dask worker processes, each importing and compiling anew: the full tier
@pytest.mark.slow
def test_the_render_command_on_worker_processes_opens_the_file_there(scene, tmp_path, monkeypatch):
    from swim.cli.main import app

    monkeypatch.chdir(tmp_path)
    scene.to_netcdf("scene.nc")
    args = ["render", "scene.nc", "--time", "2023-06-21T18:00", "--end", "2023-06-21T18:20", "--size", "31"]
    runner = CliRunner()
    alone = runner.invoke(app, [*args, "--out", "a/{index}.png"])
    spread = runner.invoke(app, [*args, "--out", "b/{index}.png", "--workers", "2"])
    assert alone.exit_code == 0 and spread.exit_code == 0, spread.output
    for i in range(3):
        np.testing.assert_array_equal(_pixels(tmp_path / "a" / f"{i}.png"), _pixels(tmp_path / "b" / f"{i}.png"))

