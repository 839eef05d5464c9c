"""Cropping big grids to the columns a camera's rays can reach (swim.geometry.reach) and render(crop=...)."""

import numpy as np
import pytest
import xarray as xr

import swim
from swim.constants import EARTH_RADIUS_M
from swim.errors import SwimInputError
from swim.frames import enu_from_azimuth_zenith
from swim.geometry import reach
from swim.geometry.cameras import make_camera
from swim.geometry.reach import (
    DEFAULT_MARGIN_CELLS,
    MIN_CROP_BLOCK,
    crop_scene_to_view,
    reachable_index_window,
    snap_window_to_blocks,
    with_reference_point,
)

# ---------------------------------------------------------------------------------------------------------------
# geometry of the window (fast)

BIG_DX = 3e3
BIG_LEVELS = np.array([50.0, 500.0, 2000.0, 8000.0, 14000.0, 15000.0])


@pytest.fixture(scope="module")
def big_scene():
    """600 x 600 columns at 3 km (1800 km wide), flat sea-level ground, grid top at 15 km."""
    n = 600
    x = (np.arange(n) - (n - 1) / 2) * BIG_DX
    return swim.scene_from_arrays(x=x, y=x, z=BIG_LEVELS, reference_lat=40.0, reference_lon=-100.0)


def _horizon_cells(top, h_obs=2.0):
    """Distance [cells] at which a ray from h_obs grazing the ground leaves a shell of height top."""
    return (np.sqrt(2 * EARTH_RADIUS_M * top) + np.sqrt(2 * EARTH_RADIUS_M * h_obs)) / BIG_DX


def _reach_cells(top, elevation_deg, h_obs=2.0):
    """Grid distance [cells] at which a ray from h_obs at an elevation leaves a shell of height top."""
    r0, e = EARTH_RADIUS_M + h_obs, np.deg2rad(elevation_deg)
    s = -r0 * np.sin(e) + np.sqrt((r0 * np.sin(e)) ** 2 + (EARTH_RADIUS_M + top) ** 2 - r0**2)
    return EARTH_RADIUS_M * np.sin(np.arctan2(s * np.cos(e), r0 + s * np.sin(e))) / BIG_DX


def test_allsky_window_matches_the_horizon_reach(big_scene):
    camera = make_camera("allsky", size=127)
    wy, wx = reachable_index_window(big_scene, camera, height=2.0, sun_direction=[0.0, 0.0, 1.0])
    centre = (600 - 1) / 2
    assert wx.start < centre < wx.stop - 1 and wy.start < centre < wy.stop - 1  # holds the observer
    assert (wx.stop - wx.start) * (wy.stop - wy.start) < 0.5 * 600 * 600  # much smaller than the domain
    # Half-widths between the reach under the highest level (15 km) along the lowest pixels (0.7 deg above
    # the horizon) and the horizon reach under the optical volume's top (the top interface plus a level
    # spacing, < 16 km), plus the margin.
    lowest = 90.0 - 63 / 63.5 * 90.0
    lo, hi = _reach_cells(15_000.0, lowest), _horizon_cells(16_000.0) + DEFAULT_MARGIN_CELLS + 2
    grazing = -np.rad2deg(np.sqrt(2 * 2.0 / EARTH_RADIUS_M))  # the ray that touches the sea-level sphere
    assert _reach_cells(16_000.0, grazing) == pytest.approx(_horizon_cells(16_000.0), rel=5e-3)
    for s in (wx, wy):
        for half in (centre - s.start, s.stop - 1 - centre):
            assert lo - 2 < half < hi, (half, lo, hi)
    # The same without a margin: the bare reach.
    wy0, wx0 = reachable_index_window(big_scene, camera, height=2.0, sun_direction=[0.0, 0.0, 1.0], margin_cells=0)
    assert lo - 2 < 0.5 * (wx0.stop - wx0.start) < _horizon_cells(16_000.0) + 2


def test_window_is_the_same_for_fields_in_memory_lazy_or_laid_out_otherwise():
    """The window reads the grid's top, the terrain near the observer and on the grid's edge straight from NumPy
    arrays held in memory, through xarray otherwise: the same window either way, also for (x, y) fields with a
    length-1 time dimension (the other layout reaches the xarray path only where it is lazy)."""
    n = 200
    x = (np.arange(n) - (n - 1) / 2) * 6e3
    yy, xx = np.meshgrid(x, x, indexing="ij")
    # terrain rising to the north-east, highest on the grid's east edge; levels that rise with the ground
    terrain = 900.0 * np.clip((xx + 0.5 * yy) / x.max(), 0.0, None)
    levels = np.array([100.0, 600.0, 2000.0, 5000.0, 7000.0, 8000.0])
    scene = swim.scene_from_arrays(x=x, y=x, z=levels, reference_lat=35.0, reference_lon=-90.0, terrain_height=terrain)
    sun = enu_from_azimuth_zenith(250.0, 75.0)
    camera = make_camera("allsky", size=63)

    def window(s):
        return reachable_index_window(s, camera, height=500.0, lat=35.05, lon=-89.95, sun_direction=sun)

    expected = window(scene)
    assert all(w.stop - w.start < 0.9 * n for w in expected)  # a real window, not the whole grid
    for name, dims in (("height", ("z", "y", "x")), ("terrain_height", ("y", "x")), ("lat", ("y", "x"))):
        assert reach._in_memory(scene, name, dims) is not None, name  # the NumPy path was taken
    laid_out = scene.expand_dims(time=[np.datetime64("2024-05-01T12:00")]).transpose("time", "x", "y", "z")
    assert window(laid_out) == expected
    dask = pytest.importorskip("dask")
    assert dask is not None
    lazy = scene.chunk({"y": 30, "x": 30})
    assert reach._in_memory(lazy, "height", ("z", "y", "x")) is None  # the xarray path
    assert window(lazy) == expected
    assert window(laid_out.chunk({"y": 30, "x": 30})) == expected


@pytest.mark.parametrize("kind, options, height", [
    ("allsky", {"size": 511}, 2.0),
    ("panorama", {"width": 1024, "height": 512}, 2.0),
    ("panorama", {"width": 1024, "height": 512}, 9000.0),
    ("perspective", {"width": 640, "height": 480, "fov_deg": 50.0, "view_azimuth_deg": 60.0, "view_zenith_deg": 95.0},
     12000.0),
])
def test_big_cameras_use_a_subset_of_pixels_with_the_same_window(big_scene, kind, options, height):
    from swim.geometry import reach

    camera = make_camera(kind, **options)
    dirs, valid = camera.directions()
    assert valid.sum() > reach._MAX_SAMPLED_PIXELS  # the subset is used
    subset = reach._representative_pixels(dirs, valid, 0.0)
    assert subset.sum() < 0.5 * valid.sum()
    for sun in ([0.0, 0.0, 1.0], enu_from_azimuth_zenith(250.0, 70.0)):
        kwargs = dict(height=height, sun_direction=sun, margin_cells=0)
        # a camera uses the subset; an array of directions is used in full
        assert reachable_index_window(big_scene, camera, **kwargs) == reachable_index_window(
            big_scene, dirs, valid=valid, **kwargs)


def test_a_camera_s_reach_is_remembered_and_only_the_sun_is_redone(big_scene, monkeypatch):
    from swim.geometry import reach

    camera = make_camera("allsky", size=255)
    low_sun = enu_from_azimuth_zenith(250.0, 80.0)  # a sun-ward margin of ~90 km: the window moves with the sun
    calls = []
    as_directions = reach._as_directions
    monkeypatch.setattr(reach, "_as_directions", lambda *a, **k: calls.append(1) or as_directions(*a, **k))
    reach._CAMERA_REACH.clear()
    first = reachable_index_window(big_scene, camera, height=2.0, sun_direction=[0, 0, 1])
    moved = reachable_index_window(big_scene, camera, height=2.0, sun_direction=low_sun)
    assert len(calls) == 1  # the camera's rays were traced once
    assert moved != first
    reach._CAMERA_REACH.clear()
    assert reachable_index_window(big_scene, camera, height=2.0, sun_direction=low_sun) == moved  # as if fresh
    # another observer height, camera or grid is a new entry
    high = reachable_index_window(big_scene, camera, height=5000.0, sun_direction=[0, 0, 1])
    reachable_index_window(big_scene, make_camera("allsky", size=127), height=2.0, sun_direction=[0, 0, 1])
    shifted = big_scene.assign_coords(lat=big_scene["lat"] + 0.5)
    reachable_index_window(shifted, camera, height=2.0, sun_direction=[0, 0, 1])
    assert len(calls) == 5 and high != first and len(reach._CAMERA_REACH) == 1


def test_a_window_is_remembered_per_sun_and_margins(big_scene, monkeypatch):
    """The same camera, observer and sun again: the window is the one remembered, without tracing the sun's ray
    again; another sun or margin is traced afresh and gives the window a fresh computation gives."""
    from swim.geometry import reach

    camera = make_camera("allsky", size=63)
    low_sun = enu_from_azimuth_zenith(250.0, 80.0)
    traced = []
    rays_box = reach._rays_box
    monkeypatch.setattr(reach, "_rays_box", lambda *a, **k: traced.append(len(a[1])) or rays_box(*a, **k))
    reach._CAMERA_REACH.clear()
    first = reachable_index_window(big_scene, camera, height=2.0, sun_direction=low_sun)
    assert len(traced) == 2  # the camera's rays, then the sun's ray
    assert reachable_index_window(big_scene, camera, height=2.0, sun_direction=low_sun) == first
    assert len(traced) == 2  # nothing traced again
    overhead = reachable_index_window(big_scene, camera, height=2.0, sun_direction=[0.0, 0.0, 1.0])
    wider = reachable_index_window(big_scene, camera, height=2.0, sun_direction=low_sun, margin_cells=9)
    assert len(traced) == 4 and traced[2:] == [1, 1]  # only the sun's ray, for each
    assert overhead != first and wider != first
    for window, kwargs in ((overhead, dict(sun_direction=[0.0, 0.0, 1.0])),
                           (wider, dict(sun_direction=low_sun, margin_cells=9))):
        reach._CAMERA_REACH.clear()
        assert reachable_index_window(big_scene, camera, height=2.0, **kwargs) == window  # as computed afresh


def test_a_grid_s_columns_are_projected_once_and_anew_when_they_change(big_scene, monkeypatch):
    """The column geometry of :class:`_Columns` is kept for the next render of the same lat, lon and reference
    point; another grid, a moved reference point or a bad lat are each seen for what they are."""
    from swim.geometry import reach

    calls = []
    projection = reach.orthographic_xy
    monkeypatch.setattr(reach, "orthographic_xy", lambda *a, **k: calls.append(1) or projection(*a, **k))
    camera = make_camera("allsky", size=63)
    kwargs = dict(height=2.0, sun_direction=[0.0, 0.0, 1.0])
    reach._COLUMN_GEOMETRY.clear()
    reach._CAMERA_REACH.clear()
    first = reachable_index_window(big_scene, camera, **kwargs)
    assert reachable_index_window(big_scene.copy(deep=True), camera, **kwargs) == first  # equal values: reused
    assert len(calls) == 1
    columns = reach._Columns(big_scene)
    assert not columns.gx.flags.writeable and not columns.gy.flags.writeable  # shared: read-only
    shifted = big_scene.assign_coords(lat=big_scene["lat"] + 0.5)
    moved_reference = big_scene.assign_attrs(reference_lat=40.5)
    for scene in (shifted, moved_reference):
        window = reachable_index_window(scene, camera, **kwargs)
        reach._COLUMN_GEOMETRY.clear()
        reach._CAMERA_REACH.clear()
        assert reachable_index_window(scene, camera, **kwargs) == window  # as computed afresh
    assert len(calls) == 5
    bad = big_scene.assign_coords(lat=big_scene["lat"] + 60.0)
    with pytest.raises(SwimInputError, match="lat"):
        reachable_index_window(bad, camera, **kwargs)


def test_a_higher_observer_sees_further_below_the_horizon(big_scene):
    # A panorama of the horizon: from h the rays that graze the ground leave the shell sqrt(2 R h) further out.
    camera = make_camera("panorama", width=64, height=61, elevation_min_deg=-3.0, elevation_max_deg=3.0)
    low = reachable_index_window(big_scene, camera, height=2.0, sun_direction=[0, 0, 1], margin_cells=0)
    high = reachable_index_window(big_scene, camera, height=3000.0, sun_direction=[0, 0, 1], margin_cells=0)
    gain = (np.sqrt(2 * EARTH_RADIUS_M * 3000.0) - np.sqrt(2 * EARTH_RADIUS_M * 2.0)) / BIG_DX
    assert (high[1].stop - high[1].start) - (low[1].stop - low[1].start) == pytest.approx(2 * gain, rel=0.1)


def test_sunward_margin_extends_towards_a_low_sun_and_is_capped(big_scene):
    camera = make_camera("allsky", size=63)
    base = reachable_index_window(big_scene, camera, sun_direction=[0, 0, 1])
    east = enu_from_azimuth_zenith(90.0, 80.0)  # low sun in the east: shadows come from the east
    wy, wx = reachable_index_window(big_scene, camera, sun_direction=east)
    shift = 16_000.0 * np.tan(np.deg2rad(80.0)) / BIG_DX  # < top * tan(zenith), ~30 cells
    assert wx.stop - base[1].stop == pytest.approx(1.05 * shift, abs=3)
    assert wx.start == base[1].start and wy == base[0]
    # Sun on the horizon: the cap (300 km = 100 cells) instead of the unbounded top * tan(zenith).
    west = enu_from_azimuth_zenith(270.0, 90.0)
    wy, wx = reachable_index_window(big_scene, camera, sun_direction=west)
    # (the ray towards the sun itself reaches a little further than the fisheye's lowest pixels)
    ray_only = reachable_index_window(big_scene, camera, sun_direction=west, sun_margin_cap_m=0.0)
    assert ray_only[1].start < base[1].start
    assert ray_only[1].start - wx.start == pytest.approx(1.05 * 100, abs=3)
    # An unknown sun: the cap on every side.
    wy, wx = reachable_index_window(big_scene, camera, sun_direction=None)
    assert base[1].start - wx.start == pytest.approx(100, abs=3) and wy.stop - base[0].stop == pytest.approx(100, abs=3)


def test_crop_keeps_the_frame_and_is_unchanged_when_the_view_covers_everything(big_scene, caplog):
    scene = big_scene.copy()
    del scene.attrs["reference_lat"], scene.attrs["reference_lon"]  # the frame is then the grid's centre
    with caplog.at_level("INFO", logger="swim.geometry.reach"):
        cropped = crop_scene_to_view(scene, "allsky", camera_options={"size": 63}, lat=40.5, lon=-99.0,
                                     sun_direction=[0, 0, 1])
    assert "crop: x" in caplog.text
    assert cropped.sizes["x"] < 400 and cropped.sizes["y"] < 400
    assert cropped.attrs["reference_lat"] == pytest.approx(40.0, abs=1e-9)
    assert cropped.attrs["reference_lon"] == pytest.approx(-100.0, abs=1e-9)
    assert float(cropped["x"][0]) > float(scene["x"][0])  # the columns keep their coordinates
    swim.io.scene.validate_scene(cropped)  # x/y still agree with lat/lon in the (unmoved) frame
    # A fisheye looking down from 3000 km sees the whole grid: the scene itself comes back.
    assert crop_scene_to_view(big_scene, "allsky", camera_options={"size": 63, "max_zenith_deg": 180.0}, height=3_000e3,
                              sun_direction=[0, 0, 1]) is big_scene
    # A perspective camera pointed by the renderer from the whole grid is not cropped.
    assert crop_scene_to_view(big_scene, "perspective", camera_options={"width": 8, "height": 8}) is big_scene
    # The default scene (40 km wide) is in reach everywhere.
    small = swim.default_scene()
    assert crop_scene_to_view(small, "allsky", camera_options={"size": 63}, sun_direction=[0, 0, 1]) is small


@pytest.mark.parametrize("shape", [(10, 12), (150, 150), (1059, 1799)])
@pytest.mark.parametrize("fraction", [1.0 / 8.0, 0.25])
def test_snapped_windows_hold_the_window_in_whole_blocks(shape, fraction):
    """snap_window_to_blocks: the result holds the window, stays in the grid, its edges lie on multiples of a
    power-of-two block (at least MIN_CROP_BLOCK, at most fraction x extent unless that is smaller) except at the
    grid's edges, and a window moved by one column gets the same blocks unless an edge crosses a block's edge."""
    rng = np.random.default_rng(sum(shape))
    for _ in range(200):
        window = []
        for n in shape:
            lo = int(rng.integers(0, n - 1))
            window.append(slice(lo, int(rng.integers(lo + 2, n + 1))))
        snapped = snap_window_to_blocks(tuple(window), shape, fraction)
        for s, w, n in zip(snapped, window, shape):
            assert 0 <= s.start <= w.start and w.stop <= s.stop <= n
            extent = w.stop - w.start
            block = max(MIN_CROP_BLOCK, 2 ** int(np.floor(np.log2(max(extent * fraction, 1.0)))))
            assert block <= max(MIN_CROP_BLOCK, extent * fraction)
            assert s.start % block == 0 and (s.stop % block == 0 or s.stop == n)
            assert s.start > w.start - block and (s.stop < w.stop + block)
        moved = tuple(slice(w.start + 1, w.stop + 1) if w.stop < n else w for w, n in zip(window, shape))
        again = snap_window_to_blocks(moved, shape, fraction)
        for s, a, w, m, n in zip(snapped, again, window, moved, shape):
            extent = w.stop - w.start
            block = max(MIN_CROP_BLOCK, 2 ** int(np.floor(np.log2(max(extent * fraction, 1.0)))))
            if m.start // block == w.start // block and -(-m.stop // block) == -(-w.stop // block):
                assert a == s
    assert snap_window_to_blocks((slice(3, 9), slice(2, 5)), (10, 10), 0.0) == (slice(3, 9), slice(2, 5))
    with pytest.raises(SwimInputError, match="block_fraction"):
        snap_window_to_blocks((slice(0, 2), slice(0, 2)), (10, 10), -0.1)


def test_with_reference_point_sets_the_centre_without_copying(big_scene):
    assert with_reference_point(big_scene) is big_scene
    scene = big_scene.copy()
    del scene.attrs["reference_lat"], scene.attrs["reference_lon"]
    out = with_reference_point(scene)
    assert out.attrs["reference_lat"] == pytest.approx(40.0) and out.attrs["reference_lon"] == pytest.approx(-100.0)
    assert "reference_lat" not in scene.attrs
    assert np.shares_memory(out["height"].values, scene["height"].values)


def test_bad_input_is_reported(big_scene):
    camera = make_camera("allsky", size=15)
    with pytest.raises(SwimInputError, match="observer height"):
        reachable_index_window(big_scene, camera, height=-1.0)
    with pytest.raises(SwimInputError, match="observer lat"):
        reachable_index_window(big_scene, camera, lat=91.0)
    with pytest.raises(SwimInputError, match=r"\(\.\.\., 3\)"):
        reachable_index_window(big_scene, np.zeros((4, 2)))
    with pytest.raises(SwimInputError, match="terrain_height"):
        reachable_index_window(big_scene.drop_vars("terrain_height"), camera)
    with pytest.raises(SwimInputError, match="camera kind"):
        crop_scene_to_view(big_scene, "pinhole")
    with pytest.raises(SwimInputError, match="reference_lat"):
        crop_scene_to_view(big_scene.assign_attrs(reference_lat="north"), "allsky")


# ---------------------------------------------------------------------------------------------------------------
# rendering with and without the crop (each new grid shape compiles the ray-march kernel: slow)

# The crop gives the whole grid's image with the paper's cloud scattering; the 3-D method's diffuse solution is
# solved on the crop's columns, coarsened less than the whole grid's (docs/rendering.md, "Cropping big grids")
RENDER = {"camera": "allsky", "camera_options": {"size": 33}, "sun_zenith": 40.0, "sun_azimuth": 200.0,
          "lat": 40.1, "lon": -100.2, "settings": swim.MarchSettings(cloud_scattering="albers2020")}
N_WIDE, DX_WIDE = 150, 10e3
LEVELS_WIDE = np.array([250.0, 750.0, 1500.0, 2500.0, 4000.0, 6000.0, 8000.0])


def _wide_fields():
    """Cloud liquid (z, y, x) [kg m-3] of a 1500 km wide scene: clouds near the observer, near its horizon
    and in a corner far beyond it."""
    lwc = np.zeros((LEVELS_WIDE.size, N_WIDE, N_WIDE))
    lwc[2:4, 74:77, 76:80] = 4e-4  # overhead, a little east
    lwc[1:5, 60:64, 95:99] = 6e-4  # ~250 km south-east, low in the sky
    lwc[2:4, 5:12, 5:12] = 5e-4  # the south-west corner: out of reach
    return lwc


@pytest.fixture(scope="module")
def wide_scene():
    x = (np.arange(N_WIDE) - (N_WIDE - 1) / 2) * DX_WIDE
    return swim.scene_from_arrays(x=x, y=x, z=LEVELS_WIDE, reference_lat=40.0, reference_lon=-100.0,
                                  cloud_liquid_content=_wide_fields(), time="2023-06-21T18:00")


@pytest.fixture(scope="module")
def wide_cropped_image(wide_scene):
    return swim.render(wide_scene, **RENDER)


@pytest.mark.slow
def test_crop_does_not_change_the_image(wide_scene, wide_cropped_image, caplog):
    window = reachable_index_window(wide_scene, make_camera("allsky", size=33), lat=RENDER["lat"],
                                    lon=RENDER["lon"], sun_direction=enu_from_azimuth_zenith(200.0, 40.0))
    cells = (window[0].stop - window[0].start) * (window[1].stop - window[1].start)
    assert cells < 0.6 * N_WIDE**2  # the crop does cut the grid
    full = swim.render(wide_scene, crop=False, **RENDER)
    cropped = wide_cropped_image
    assert np.nanmax(cropped["tau_hydrometeor"].values) > 1  # the clouds in reach are seen
    np.testing.assert_allclose(cropped["radiance"].values, full["radiance"].values, rtol=1e-5, atol=1e-7)
    # The components too, up to the float32 round-off of the kernel's grid indices, which are computed from
    # a different origin and scale on the crop (~1e-5 cells: a few 1e-5 of tau at the edges of blocky clouds).
    for key in ("radiance_cloud", "radiance_clear", "radiance_surface", "tau_hydrometeor"):
        np.testing.assert_allclose(cropped[key].values, full[key].values, rtol=1e-4, atol=2e-5, err_msg=key)
    assert cropped.attrs["reference_lat"] == full.attrs["reference_lat"]
    assert cropped.attrs["direct_transmittance"] == pytest.approx(full.attrs["direct_transmittance"])


def test_a_camera_that_moves_a_little_keeps_its_crop_and_the_built_volume(wide_scene, wide_cropped_image, caplog):
    """A move of the observer that changes the bare reachable window but not its blocks keeps the crop: the next
    frame reuses the optical volume (the same cropped scene, the same digest), and its image is still that of the
    whole grid. The render's crop does cut the grid."""
    sun = enu_from_azimuth_zenith(RENDER["sun_azimuth"], RENDER["sun_zenith"])
    camera = make_camera("allsky", size=33)
    lat = RENDER["lat"]

    def windows(lon):
        bare = reachable_index_window(wide_scene, camera, lat=lat, lon=lon, sun_direction=sun)
        cropped = crop_scene_to_view(wide_scene, camera, lat=lat, lon=lon, sun_direction=sun)
        return bare, (int(cropped["x"][0]), int(cropped["x"][-1]), int(cropped["y"][0]), int(cropped["y"][-1]))

    first_bare, first_crop = windows(RENDER["lon"])
    assert (first_crop[1] - first_crop[0]) * (first_crop[3] - first_crop[2]) < 0.8 * ((N_WIDE - 1) * DX_WIDE) ** 2
    step = np.degrees(DX_WIDE / (EARTH_RADIUS_M * np.cos(np.radians(lat))))
    moved = next((RENDER["lon"] + k * step for k in (1, -1, 2, -2, 3, -3)
                  if windows(RENDER["lon"] + k * step)[0] != first_bare and windows(RENDER["lon"] + k * step)[1] == first_crop),
                 None)
    assert moved is not None, "no move of 1-3 cells changes the bare window and keeps the crop's blocks"
    swim.render(wide_scene, **RENDER)  # the stage cache holds this crop's volume (the fixture's may be older)
    with caplog.at_level("INFO", logger="swim.pipeline"):
        image = swim.render(wide_scene, **{**RENDER, "lon": moved})
    assert "reusing the volume of the previous render" in caplog.text
    full = swim.render(wide_scene, crop=False, **{**RENDER, "lon": moved})
    np.testing.assert_allclose(image["radiance"].values, full["radiance"].values, rtol=1e-5, atol=1e-7)


@pytest.mark.slow
def test_dask_scene_renders_computing_only_the_crop(wide_scene, wide_cropped_image):
    dask_array = pytest.importorskip("dask.array")
    window = reachable_index_window(wide_scene, make_camera("allsky", size=33), lat=RENDER["lat"],
                                    lon=RENDER["lon"], sun_direction=enu_from_azimuth_zenith(200.0, 40.0))
    window = snap_window_to_blocks(window, (N_WIDE, N_WIDE))  # the render's crop: whole blocks of columns
    lwc = _wide_fields()
    chunk = 10  # the crop (24:128 on both axes) leaves out the two outer rings of chunks
    computed = []

    def block(block_info=None):
        (z0, z1), (y0, y1), (x0, x1) = block_info[None]["array-location"]
        outside = y1 <= window[0].start or y0 >= window[0].stop or x1 <= window[1].start or x0 >= window[1].stop
        if outside:
            raise AssertionError(f"computed a block outside the crop: y {y0}:{y1}, x {x0}:{x1}")
        computed.append((y0, x0))
        return lwc[z0:z1, y0:y1, x0:x1]

    chunks = ((LEVELS_WIDE.size,), (chunk,) * (N_WIDE // chunk), (chunk,) * (N_WIDE // chunk))
    lazy = dask_array.map_blocks(block, chunks=chunks, dtype=float)
    height = dask_array.broadcast_to(dask_array.from_array(LEVELS_WIDE)[:, None, None],
                                     (LEVELS_WIDE.size, N_WIDE, N_WIDE), chunks=chunks[0] + chunks[1:])
    raw = xr.Dataset(
        {"height": (("z", "y", "x"), height), "lat": wide_scene["lat"], "lon": wide_scene["lon"],
         "terrain_height": wide_scene["terrain_height"], "cloud_liquid_content": (("z", "y", "x"), lazy)},
        coords={"time": wide_scene["time"]},
        attrs={"reference_lat": 40.0, "reference_lon": -100.0},
    )
    image = swim.render(raw, **RENDER)
    n_blocks = (N_WIDE // chunk) ** 2
    assert 0 < len(set(computed)) < n_blocks
    np.testing.assert_allclose(image["radiance"].values, wide_cropped_image["radiance"].values, rtol=1e-5, atol=1e-7)
