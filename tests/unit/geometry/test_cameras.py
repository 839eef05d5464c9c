"""Cameras: round trips and analytic invariants of the pixel <-> direction maps (conventions: docs/frames.md)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from swim.constants import EARTH_RADIUS_M
from swim.errors import SwimInputError
from swim.geometry.cameras import (
    AllSkyCamera,
    PanoramaCamera,
    PerspectiveCamera,
    check_camera_options,
    fov_to_fit,
    look_at_angles,
    make_camera,
)


def enu(az_deg, zen_deg):
    """Independent (test-side) ENU unit vector: east = sin z sin az, north = sin z cos az, up = cos z."""
    a, z = np.deg2rad(az_deg), np.deg2rad(zen_deg)
    return np.array([np.sin(z) * np.sin(a), np.sin(z) * np.cos(a), np.cos(z)])


CAMERAS = [
    AllSkyCamera(1),
    AllSkyCamera(2),
    AllSkyCamera(7),
    AllSkyCamera(64),
    AllSkyCamera(511),
    AllSkyCamera(101, max_zenith_deg=60.0),
    AllSkyCamera(100, max_zenith_deg=180.0),
    PanoramaCamera(8, 4),
    PanoramaCamera(1024, 512),
    PanoramaCamera(37, 21, azimuth_start_deg=-45.0, elevation_min_deg=-10.0, elevation_max_deg=50.0),
    PanoramaCamera(50, 30, azimuth_start_deg=200.0, azimuth_span_deg=120.0, elevation_min_deg=0.0),
    PerspectiveCamera(101, 51, 60.0, 30.0, 80.0),
    PerspectiveCamera(64, 64, 90.0, 200.0, 120.0, roll_deg=17.0),
    PerspectiveCamera(7, 13, 10.0, 0.0, 0.0),
    PerspectiveCamera(40, 30, 120.0, 90.0, 180.0, roll_deg=-30.0),
    PerspectiveCamera(1, 1, 5.0, 45.0, 45.0),
]


@pytest.mark.parametrize("cam", CAMERAS, ids=lambda c: f"{c.kind}{c.shape}")
def test_round_trip_and_unit_length(cam):
    dirs, valid = cam.directions()
    ny, nx = cam.shape
    assert dirs.shape == (ny, nx, 3) and dirs.dtype == np.float64
    assert valid.shape == (ny, nx) and valid.dtype == bool
    assert valid.any()
    d = dirs[valid]
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0, atol=1e-12)
    row, col = cam.pixel_of_direction(dirs)
    rows, cols = np.meshgrid(np.arange(ny), np.arange(nx), indexing="ij")
    assert np.all(np.isfinite(row[valid])) and np.all(np.isfinite(col[valid]))
    assert np.max(np.abs(row[valid] - rows[valid])) < 1e-6
    assert np.max(np.abs(col[valid] - cols[valid])) < 1e-6
    # NaN directions (outside the fisheye circle) are not imaged
    assert np.all(np.isnan(row[~valid])) and np.all(np.isnan(col[~valid]))


@pytest.mark.parametrize("cam", [CAMERAS[4], CAMERAS[9], CAMERAS[12]], ids=lambda c: f"{c.kind}{c.shape}")
def test_cached_directions_and_view_angles_are_the_camera_s_own_and_read_only(cam):
    dirs, valid = cam.directions()
    cached_dirs, cached_valid = cam.cached_directions()
    np.testing.assert_array_equal(cached_valid, valid)
    np.testing.assert_array_equal(cached_dirs[valid], dirs[valid])
    azimuth, zenith = cam.cached_view_angles()
    # test-side angles of the valid pixels: zenith from the up component, azimuth clockwise from north
    v = dirs[valid]
    np.testing.assert_allclose(zenith[valid], np.degrees(np.arccos(np.clip(v[:, 2], -1, 1))), atol=2e-4)
    ok = np.hypot(v[:, 0], v[:, 1]) > 1e-6  # the zenith and nadir have no azimuth
    difference = (azimuth[valid][ok] - np.degrees(np.arctan2(v[ok, 0], v[ok, 1])) + 180.0) % 360.0 - 180.0
    np.testing.assert_allclose(difference, 0.0, atol=5e-4)
    assert np.all(np.isnan(zenith[~valid])) and azimuth.dtype == np.float32
    for a in (cached_dirs, cached_valid, azimuth, zenith):
        assert not a.flags.writeable
    # an equal camera, made anew, shares them
    again = type(cam)(**{f.name: getattr(cam, f.name) for f in dataclasses.fields(cam)})
    assert again.cached_directions()[0] is cached_dirs and again.cached_view_angles()[1] is zenith


@pytest.mark.parametrize("cam", [CAMERAS[4], CAMERAS[9], CAMERAS[12]], ids=lambda c: f"{c.kind}{c.shape}")
@pytest.mark.parametrize("block", [1, 7, 64, 10**9])
def test_view_angles_in_blocks_are_those_of_the_whole_image(cam, block):
    from swim.frames import azimuth_zenith_from_enu
    from swim.geometry.cameras import _view_angles

    dirs, valid = cam.directions()
    whole_az, whole_zen = azimuth_zenith_from_enu(np.where(valid[..., None], dirs, np.nan))
    azimuth, zenith = _view_angles(cam, block=block)
    assert azimuth.shape == zenith.shape == valid.shape and azimuth.dtype == zenith.dtype == np.float32
    # bit for bit the whole image's angles, rounded to float32 (NaN where not valid)
    np.testing.assert_array_equal(azimuth, whole_az.astype(np.float32))
    np.testing.assert_array_equal(zenith, whole_zen.astype(np.float32))


@pytest.mark.parametrize("cam", CAMERAS, ids=lambda c: f"{c.kind}{c.shape}")
def test_attrs_are_plain(cam):
    attrs = cam.to_attrs()
    assert attrs["camera_kind"] == cam.kind
    assert (attrs["camera_ny"], attrs["camera_nx"]) == cam.shape
    for value in attrs.values():
        assert isinstance(value, (int, float, str)) and not isinstance(value, bool)


def test_pixel_of_direction_broadcasts_and_rejects_bad_shape():
    cam = AllSkyCamera(11)
    row, col = cam.pixel_of_direction(np.zeros((2, 5, 3)) + [0.0, 0.0, 2.0])  # need not be unit length
    assert row.shape == (2, 5)
    np.testing.assert_allclose(row, 5.0)
    row0, col0 = cam.pixel_of_direction([0.0, 0.0, 0.0])
    assert np.isnan(row0) and np.isnan(col0)
    with pytest.raises(SwimInputError, match="dirs_enu"):
        cam.pixel_of_direction(np.zeros((4, 2)))


# ------------------------------------------------------------------------------------------------- all-sky
@pytest.mark.parametrize("size", [5, 511])
def test_allsky_orientation_odd(size):
    cam = AllSkyCamera(size)
    dirs, valid = cam.directions()
    c = (size - 1) // 2
    np.testing.assert_allclose(dirs[c, c], [0.0, 0.0, 1.0], atol=1e-15)  # centre = zenith
    # top centre looks north, bottom south, left east, right west; radius c = zenith 90 (size-1)/size
    z_edge = 90.0 * (size - 1) / size
    np.testing.assert_allclose(dirs[0, c], enu(0.0, z_edge), atol=1e-12)
    np.testing.assert_allclose(dirs[-1, c], enu(180.0, z_edge), atol=1e-12)
    np.testing.assert_allclose(dirs[c, 0], enu(90.0, z_edge), atol=1e-12)
    np.testing.assert_allclose(dirs[c, -1], enu(270.0, z_edge), atol=1e-12)
    assert valid[0, c] and valid[c, 0] and not valid[0, 0]


def test_allsky_rim_is_horizon_and_radius_linear_in_zenith():
    size = 511
    cam = AllSkyCamera(size)
    c = (size - 1) / 2
    az = np.arange(0.0, 360.0, 7.5)
    for zen, radius in [(90.0, size / 2), (45.0, size / 4), (30.0, size / 6), (0.0, 0.0)]:
        row, col = cam.pixel_of_direction(np.stack([enu(a, zen) for a in az]))
        np.testing.assert_allclose(np.hypot(row - c, col - c), radius, atol=1e-9)
    # just below the horizon is not imaged
    row, col = cam.pixel_of_direction(enu(10.0, 90.001))
    assert np.isnan(row) and np.isnan(col)


def test_allsky_sun_pixel():
    # sun at azimuth 135 (south-east), zenith 60 in a 511 image: r = 60/90 * 255.5, south = down, east = left
    cam = AllSkyCamera(511)
    r = 60.0 / 90.0 * 255.5
    expected_row = 255.0 + r * math.sqrt(0.5)
    expected_col = 255.0 - r * math.sqrt(0.5)
    row, col = cam.pixel_of_direction(enu(135.0, 60.0))
    assert row == pytest.approx(expected_row, abs=1e-9)
    assert col == pytest.approx(expected_col, abs=1e-9)
    assert (round(float(row)), round(float(col))) == (375, 135)


def test_allsky_valid_disc_and_even_size():
    size = 200
    dirs, valid = AllSkyCamera(size).directions()
    assert abs(valid.sum() - math.pi * (size / 2) ** 2) < 2 * math.pi * size / 2  # area within a perimeter
    assert np.all(np.isnan(dirs[~valid]))
    # even size: the four central pixels are symmetric about the zenith, half a pixel diagonal away
    k = 90.0 / (size / 2)
    zen = np.degrees(np.arccos(dirs[99:101, 99:101, 2]))
    np.testing.assert_allclose(zen, k * math.sqrt(0.5), atol=1e-12)


def test_allsky_max_zenith():
    cam = AllSkyCamera(301, max_zenith_deg=120.0)
    row, col = cam.pixel_of_direction(enu(0.0, 120.0))
    assert 150.0 - row == pytest.approx(150.5, abs=1e-9) and col == pytest.approx(150.0, abs=1e-9)
    row, col = cam.pixel_of_direction(enu(270.0, 90.0))  # west horizon at 3/4 of the rim radius, right
    assert col - 150.0 == pytest.approx(150.5 * 0.75, abs=1e-9)
    nadir = AllSkyCamera(11, max_zenith_deg=180.0).pixel_of_direction([0.0, 0.0, -1.0])
    assert np.isnan(nadir[0])


# ------------------------------------------------------------------------------------------------ panorama
def test_panorama_axes():
    w, h = 1024, 512
    cam = PanoramaCamera(w, h)
    dirs, valid = cam.directions()
    assert valid.all()
    # top row centre: elevation 90 - half a row; bottom row: -90 + half a row
    np.testing.assert_allclose(dirs[0, :, 2], math.sin(math.radians(90.0 - 0.5 * 180.0 / h)), atol=1e-12)
    np.testing.assert_allclose(dirs[-1, :, 2], -math.sin(math.radians(90.0 - 0.5 * 180.0 / h)), atol=1e-12)
    # azimuth 90 (east) at the boundary between columns w/4 - 1 and w/4; north, south, west likewise
    for az, frac in [(0.0, 0.0), (90.0, 0.25), (180.0, 0.5), (270.0, 0.75)]:
        row, col = cam.pixel_of_direction(enu(az, 90.0))
        assert col == pytest.approx(frac * w - 0.5, abs=1e-9)
        assert row == pytest.approx(h / 2 - 0.5, abs=1e-9)  # horizon midway
    # column w/4 looks east, half a column further right
    az_col = math.degrees(math.atan2(dirs[h // 2, w // 4, 0], dirs[h // 2, w // 4, 1]))
    assert az_col == pytest.approx(90.0 + 0.5 * 360.0 / w, abs=1e-9)


def test_panorama_start_and_ranges():
    cam = PanoramaCamera(360, 60, azimuth_start_deg=-90.0, elevation_min_deg=0.0, elevation_max_deg=30.0)
    assert cam.azimuth_start_deg == 270.0
    # north is a quarter turn right of the left edge (west)
    row, col = cam.pixel_of_direction(enu(0.0, 75.0))
    assert col == pytest.approx(90.0 - 0.5, abs=1e-9)
    assert row == pytest.approx((30.0 - 15.0) / 0.5 - 0.5, abs=1e-9)
    below, _ = cam.pixel_of_direction(enu(0.0, 90.5))
    above, _ = cam.pixel_of_direction(enu(0.0, 59.5))
    assert np.isnan(below) and np.isnan(above)
    part = PanoramaCamera(120, 10, azimuth_start_deg=100.0, azimuth_span_deg=120.0)
    _, col = part.pixel_of_direction(np.stack([enu(160.0, 80.0), enu(300.0, 80.0), enu(99.0, 80.0)]))
    assert col[0] == pytest.approx(59.5, abs=1e-9) and np.isnan(col[1]) and np.isnan(col[2])


# --------------------------------------------------------------------------------------------- perspective
@pytest.mark.parametrize(
    "w,h,fov,az,zen,roll",
    [(101, 51, 60.0, 30.0, 80.0, 0.0), (33, 77, 100.0, 250.0, 135.0, 40.0), (9, 9, 20.0, 0.0, 0.0, 0.0),
     (9, 9, 20.0, 123.0, 180.0, 10.0)],
)
def test_perspective_centre_and_corners(w, h, fov, az, zen, roll):
    cam = PerspectiveCamera(w, h, fov, az, zen, roll_deg=roll)
    dirs, valid = cam.directions()
    axis = enu(az, zen)
    np.testing.assert_allclose(dirs[h // 2, w // 2], axis, atol=1e-14)
    f_px = (w / 2) / math.tan(math.radians(fov) / 2)
    corner = math.degrees(math.atan(math.hypot((w - 1) / 2, (h - 1) / 2) / f_px))
    for i, j in [(0, 0), (0, -1), (-1, 0), (-1, -1)]:
        angle = math.degrees(math.acos(np.clip(dirs[i, j] @ axis, -1, 1)))
        assert angle == pytest.approx(corner, abs=1e-9)
    assert cam.vertical_fov_deg == pytest.approx(math.degrees(2 * math.atan((h / 2) / f_px)), abs=1e-12)


def test_perspective_level_horizon_and_edges():
    w, h = 200, 101
    cam = PerspectiveCamera(w, h, 60.0, 0.0, 90.0)  # looking north, horizontally
    # horizon level: every horizontal direction in view is on the middle row; east is right
    az = np.linspace(-29.0, 29.0, 13)
    row, col = cam.pixel_of_direction(np.stack([enu(a, 90.0) for a in az]))
    np.testing.assert_allclose(row, (h - 1) / 2, atol=1e-9)
    assert np.all(np.diff(col) > 0)
    # left and right image edges at fov/2 from the axis
    row, col = cam.pixel_of_direction(np.stack([enu(30.0, 90.0), enu(-30.0, 90.0)]))
    np.testing.assert_allclose(col, [w - 0.5, -0.5], atol=1e-9)
    # up is up; behind the camera and outside the frame is not imaged
    row, _ = cam.pixel_of_direction(enu(0.0, 80.0))
    assert row < (h - 1) / 2
    behind, _ = cam.pixel_of_direction(enu(180.0, 90.0))
    outside, _ = cam.pixel_of_direction(enu(40.0, 90.0))
    assert np.isnan(behind) and np.isnan(outside)


def test_perspective_vertical_views_and_roll():
    c = 50.0
    up = PerspectiveCamera(101, 101, 40.0, 0.0, 0.0)  # looking up: north up, east left (as the all-sky)
    row, col = up.pixel_of_direction(np.stack([enu(0.0, 5.0), enu(90.0, 5.0)]))
    assert row[0] < c and col[0] == pytest.approx(c, abs=1e-9)
    assert col[1] < c and row[1] == pytest.approx(c, abs=1e-9)
    down = PerspectiveCamera(101, 101, 40.0, 0.0, 180.0)  # looking down: a map, north up, east right
    row, col = down.pixel_of_direction(np.stack([enu(0.0, 175.0), enu(90.0, 175.0)]))
    assert row[0] < c and col[0] == pytest.approx(c, abs=1e-9)
    assert col[1] > c and row[1] == pytest.approx(c, abs=1e-9)
    # roll 90: camera turned clockwise, scene turns counter-clockwise: the sky moves to the left
    rolled = PerspectiveCamera(101, 101, 40.0, 0.0, 90.0, roll_deg=90.0)
    row, col = rolled.pixel_of_direction(enu(0.0, 80.0))
    assert col < c and row == pytest.approx(c, abs=1e-9)
    f_px = 50.5 / math.tan(math.radians(20.0))
    assert c - col == pytest.approx(f_px * math.tan(math.radians(10.0)), abs=1e-9)


# ------------------------------------------------------------------------------------- pointing helpers
def test_scene_frame_invariants_used_by_look_at():
    """swim.frames (docstring): the reference point at height h is (0, 0, R + h); ENU bases are orthonormal."""
    from swim import frames

    np.testing.assert_allclose(frames.geodetic_to_scene(45.0, 10.0, 100.0, 45.0, 10.0), [0, 0, EARTH_RADIUS_M + 100],
                               atol=1e-6)
    basis = frames.enu_basis_ecef(np.array([-60.0, 0.0, 45.0]), np.array([170.0, 0.0, 10.0]))
    np.testing.assert_allclose(basis @ np.swapaxes(basis, -1, -2), np.broadcast_to(np.eye(3), (3, 3, 3)), atol=1e-15)
    np.testing.assert_allclose(np.cross(basis[:, 0], basis[:, 1]), basis[:, 2], atol=1e-15)  # E x N = U


def test_look_at_angles():
    # same height, 1 deg of arc to the north: the chord dips phi/2 below the horizontal
    az, zen = look_at_angles(45.0, 10.0, 100.0, 46.0, 10.0, 100.0)
    assert 0.0 <= az < 360.0
    assert min(az, 360.0 - az) == pytest.approx(0.0, abs=1e-9) and zen == pytest.approx(90.5, abs=1e-9)
    az, zen = look_at_angles(0.0, 0.0, 0.0, 0.0, 2.0, 0.0)  # east along the equator
    assert az == pytest.approx(90.0, abs=1e-9) and zen == pytest.approx(91.0, abs=1e-9)
    az, zen = look_at_angles(10.0, 20.0, 0.0, 10.0, 20.0, 5000.0)
    assert zen == pytest.approx(0.0, abs=1e-9)
    _, zen = look_at_angles(10.0, 20.0, 5000.0, 10.0, 20.0, 0.0)
    assert zen == pytest.approx(180.0, abs=1e-9)
    # a cloud 10 km up, 10 km to the south: elevation atan(h'/d) on the sphere
    phi = 10_000.0 / EARTH_RADIUS_M
    R, H = EARTH_RADIUS_M, EARTH_RADIUS_M + 10_000.0
    horiz, vert = H * math.sin(phi), H * math.cos(phi) - R
    az, zen = look_at_angles(40.0, -105.0, 0.0, 40.0 - math.degrees(phi), -105.0, 10_000.0)
    assert az == pytest.approx(180.0, abs=1e-9)
    assert zen == pytest.approx(90.0 - math.degrees(math.atan2(vert, horiz)), abs=1e-7)
    with pytest.raises(SwimInputError, match="coincide"):
        look_at_angles(1.0, 2.0, 3.0, 1.0, 2.0, 3.0)
    with pytest.raises(SwimInputError, match="observer_lat"):
        look_at_angles(91.0, 0.0, 0.0, 0.0, 0.0, 0.0)


def test_fov_to_fit():
    assert fov_to_fit(1000.0, 1000.0, margin=1.0) == pytest.approx(90.0)
    assert fov_to_fit(1000.0, 500.0) == pytest.approx(2 * math.degrees(math.atan(0.6)))
    for kwargs, name in [({"distance_m": 0.0, "half_extent_m": 1.0}, "distance_m"),
                         ({"distance_m": 1.0, "half_extent_m": -1.0}, "half_extent_m"),
                         ({"distance_m": 1.0, "half_extent_m": 1.0, "margin": float("nan")}, "margin")]:
        with pytest.raises(SwimInputError, match=name):
            fov_to_fit(**kwargs)


# ------------------------------------------------------------------------------------ factory, validation
def test_make_camera():
    assert make_camera("allsky") == AllSkyCamera(511)
    assert make_camera("All-Sky", size=65).shape == (65, 65)
    assert make_camera("panorama", width=10, height=5).shape == (5, 10)
    cam = make_camera("perspective", width=8, height=6, fov_deg=50, view_azimuth_deg=-10, view_zenith_deg=90)
    assert cam.shape == (6, 8) and cam.view_azimuth_deg == 350.0
    with pytest.raises(SwimInputError, match="kind"):
        make_camera("orthographic")
    with pytest.raises(SwimInputError, match="fov_deg"):
        make_camera("perspective", width=8, height=6)
    with pytest.raises(SwimInputError, match="sizee"):
        make_camera("allsky", sizee=3)


LATER = ("view_azimuth_deg", "view_zenith_deg", "fov_deg")


@pytest.mark.parametrize("kind, options, match", [
    ("orthographic", {}, "kind"),
    ("allsky", {"sizee": 3}, "sizee"),
    ("perspective", {"size": 256, "fov_deg": 9.0}, "size"),  # a perspective camera has width and height
    ("perspective", {"width": 64}, "height"),  # required and not filled in later
    ("perspective", {"width": 64, "height": 0}, "height"),  # a value out of range
    ("panorama", {"width": 10, "height": 5, "view_azimuth_deg": 3.0}, "view_azimuth_deg"),  # not a panorama's
], ids=["kind", "unknown", "size for perspective", "missing height", "bad height", "not the kind's option"])
def test_check_camera_options_raises_what_make_camera_would(kind, options, match):
    """Bad kinds, names and values are found without the options filled in later (a perspective camera's view,
    which swim.render takes from the grid); the same options given to make_camera fail alike."""
    with pytest.raises(SwimInputError, match=match):
        check_camera_options(kind, options, filled_later=LATER)
    view = {"view_azimuth_deg": 10.0, "view_zenith_deg": 80.0, "fov_deg": 40.0} if kind == "perspective" else {}
    with pytest.raises(SwimInputError, match=match):
        make_camera(kind, **{**view, **options})


def test_check_camera_options_accepts_options_whose_view_comes_later():
    """A perspective camera with only its size passes where its view is filled in later, and fails where it is not;
    the stand-ins are not offered to cameras that do not have those options."""
    check_camera_options("perspective", {"width": 64, "height": 48}, filled_later=LATER)
    check_camera_options("perspective", {"width": 64, "height": 48, "view_zenith_deg": 180.0}, filled_later=LATER)
    check_camera_options("fisheye", {"size": 65}, filled_later=LATER)
    check_camera_options("panorama", {"width": 10, "height": 5}, filled_later=LATER)
    with pytest.raises(SwimInputError, match="view_azimuth_deg"):
        check_camera_options("perspective", {"width": 64, "height": 48})


@pytest.mark.parametrize(
    "build,name",
    [
        (lambda: AllSkyCamera(0), "size"),
        (lambda: AllSkyCamera(10.5), "size"),
        (lambda: AllSkyCamera(True), "size"),
        (lambda: AllSkyCamera(11, max_zenith_deg=0.0), "max_zenith_deg"),
        (lambda: AllSkyCamera(11, max_zenith_deg=181.0), "max_zenith_deg"),
        (lambda: PanoramaCamera(width=-1), "width"),
        (lambda: PanoramaCamera(elevation_min_deg=-91.0), "elevation_min_deg"),
        (lambda: PanoramaCamera(elevation_min_deg=10.0, elevation_max_deg=10.0), "elevation_max_deg"),
        (lambda: PanoramaCamera(azimuth_span_deg=400.0), "azimuth_span_deg"),
        (lambda: PanoramaCamera(azimuth_start_deg=float("inf")), "azimuth_start_deg"),
        (lambda: PerspectiveCamera(10, 10, 180.0, 0.0, 90.0), "fov_deg"),
        (lambda: PerspectiveCamera(10, 10, 60.0, 0.0, 190.0), "view_zenith_deg"),
        (lambda: PerspectiveCamera(10, 10, 60.0, "north", 90.0), "view_azimuth_deg"),
    ],
)
def test_validation(build, name):
    with pytest.raises(SwimInputError, match=name):
        build()
