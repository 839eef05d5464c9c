"""swim.io.globe: the global columns resampled onto the orthographic grid about the sub-observer point, the
sub-solar point and the L1 camera."""

import numpy as np
import pytest
import xarray as xr

from swim.constants import EARTH_RADIUS_M
from swim.errors import SwimInputError
from swim.io import globe

R = EARTH_RADIUS_M
LAT_AXIS = np.arange(-90.0, 90.1, 2.5)
LON_AXIS = np.arange(0.0, 360.0, 2.5)


def _columns(content=None, terrain=None):
    """Global columns on the 2.5 deg grid: 10 levels 1-10 km, an optional cloud (z, lat, lon) and terrain."""
    nz = 10
    height = np.broadcast_to(np.linspace(1000.0, 10000.0, nz)[:, None, None], (nz, LAT_AXIS.size, LON_AXIS.size))
    data = {"height": (("z", "lat", "lon"), height.copy())}
    if content is not None:
        data["cloud_liquid_content"] = (("z", "lat", "lon"), content)
    if terrain is not None:
        data["terrain_height"] = (("lat", "lon"), terrain)
    return xr.Dataset(data, coords={"lat": LAT_AXIS, "lon": LON_AXIS})


def _orthographic(lat, lon, lat0, lon0):
    """Orthographic projection about (lat0, lon0) written out (Snyder 1987, USGS PP 1395, Eqs. 20-3, 20-4)."""
    la, lo, la0, lo0 = (np.deg2rad(np.asarray(v, dtype=float)) for v in (lat, lon, lat0, lon0))
    x = R * np.cos(la) * np.sin(lo - lo0)
    y = R * (np.cos(la0) * np.sin(la) - np.sin(la0) * np.cos(la) * np.cos(lo - lo0))
    return x, y


def test_interpolation_reproduces_a_smooth_field_and_is_periodic():
    lat2, lon2 = np.meshgrid(LAT_AXIS, LON_AXIS, indexing="ij")
    field = np.cos(np.deg2rad(lat2)) * np.cos(np.deg2rad(lon2 - 30.0))
    rng = np.random.default_rng(1)
    lat, lon = rng.uniform(-89.0, 89.0, 500), rng.uniform(-180.0, 180.0, 500)
    got = globe.interpolate_lat_lon(field, LAT_AXIS, LON_AXIS, lat, lon)
    want = np.cos(np.deg2rad(lat)) * np.cos(np.deg2rad(lon - 30.0))
    # bilinear error bound h^2/8 max|f''| with h = 2.5 deg: 2.4e-4 per direction
    assert np.max(np.abs(got - want)) < 6e-4
    # across the seam 357.5 -> 0 (360) deg: a field linear in longitude there is interpolated exactly
    ramp = np.where(lon2 >= 357.5, 0.0, 1.0)
    assert globe.interpolate_lat_lon(ramp, LAT_AXIS, LON_AXIS, 10.0, 358.75) == pytest.approx(0.5)
    assert globe.interpolate_lat_lon(ramp, LAT_AXIS, LON_AXIS, 10.0, -1.25) == pytest.approx(0.5)


def test_hemisphere_grid_is_the_orthographic_projection_and_reproduces_terrain():
    lat2, lon2 = np.meshgrid(LAT_AXIS, LON_AXIS, indexing="ij")
    terrain = 1000.0 + 800.0 * np.sin(np.deg2rad(lat2)) * np.cos(np.deg2rad(lon2))
    scene = globe.hemisphere_scene(_columns(terrain=terrain), -21.0, 2.5, size=65, disc_radius_deg=85.0)
    x, y = np.meshgrid(scene["x"].values, scene["y"].values)
    r = np.hypot(x, y)
    on_sphere = r < R
    ox, oy = _orthographic(scene["lat"].values, scene["lon"].values, -21.0, 2.5)
    assert np.max(np.hypot(ox - x, oy - y)[on_sphere]) < 1.0  # [m]
    # the centre column is the sub-observer point; the middle of an edge lies 85 deg away, the corners beyond the limb
    assert scene["lat"].values[32, 32] == pytest.approx(-21.0, abs=1e-9)
    assert scene["lon"].values[32, 32] == pytest.approx(2.5, abs=1e-9)
    assert np.rad2deg(np.arcsin(x[32, -1] / R)) == pytest.approx(85.0, abs=1e-6)
    assert r[0, 0] == pytest.approx(np.sqrt(2.0) * R * np.sin(np.deg2rad(85.0)))
    assert scene.attrs["globe_disc_radius_deg"] == 85.0
    la, lo = np.deg2rad(scene["lat"].values), np.deg2rad(scene["lon"].values)
    want = 1000.0 + 800.0 * np.sin(la) * np.cos(lo)
    disc = r <= R * np.sin(np.deg2rad(85.0))
    assert np.max(np.abs(scene["terrain_height"].values - want)[disc]) < 5.0  # [m]; 2.5 deg bilinear: <= ~1.3 m
    # beyond the disc: the values (and beyond the limb the lat/lon) of the nearest point of the rim, which lies
    # 85 deg of great circle from the sub-observer point in the column's direction
    j, i = 0, 0
    rim = R * np.sin(np.deg2rad(85.0)) / r[j, i]
    rim_lat, rim_lon = _inverse_orthographic(x[j, i] * rim, y[j, i] * rim, -21.0, 2.5)
    assert scene["lat"].values[j, i] == pytest.approx(rim_lat, abs=1e-9)
    assert scene["lon"].values[j, i] == pytest.approx(rim_lon, abs=1e-9)
    rim_terrain = 1000.0 + 800.0 * np.sin(np.deg2rad(rim_lat)) * np.cos(np.deg2rad(rim_lon))
    assert scene["terrain_height"].values[j, i] == pytest.approx(rim_terrain, abs=5.0)


def _inverse_orthographic(x, y, lat0, lon0):
    """Lat, lon [deg] of the point (x, y) on the sphere (Snyder 1987, USGS PP 1395, Eqs. 20-14, 20-15)."""
    rho = np.hypot(x, y)
    c = np.arcsin(rho / R)
    la0 = np.deg2rad(lat0)
    lat = np.arcsin(np.cos(c) * np.sin(la0) + y * np.sin(c) * np.cos(la0) / rho)
    lon = np.deg2rad(lon0) + np.arctan2(x * np.sin(c), rho * np.cos(la0) * np.cos(c) - y * np.sin(la0) * np.sin(c))
    return float(np.rad2deg(lat)), float((np.rad2deg(lon) + 180.0) % 360.0 - 180.0)


def test_a_grid_beyond_the_limb_validates_and_maps_its_indices_exactly():
    from swim.geometry.reach import _Columns, reachable_index_window
    from swim.geometry.cameras import make_camera
    from swim.io.scene import validate_scene
    from swim.optics.volume import _grid_maps, grid_indices

    content = np.zeros((10, LAT_AXIS.size, LON_AXIS.size))
    content[2:5] = 1e-4
    scene = globe.hemisphere_scene(_columns(content), 30.0, -40.0, size=33, disc_radius_deg=87.0)
    x, y = np.meshgrid(scene["x"].values, scene["y"].values)
    outside = np.hypot(x, y) >= R
    assert outside.sum() > 100  # the corners, whose lat/lon are not those of their x, y
    assert np.all(scene["cloud_liquid_content"].values[:, outside] == 0.0)
    validate_scene(scene)  # again: the columns beyond the limb are not compared with their lat/lon
    gx, gy, attrs = _grid_maps(scene, 30.0, -40.0)
    np.testing.assert_array_equal(gx, x)
    i, j = grid_indices(attrs, x, y)
    jj, ii = np.mgrid[0:33, 0:33]
    assert np.max(np.abs(i - ii)) < 1e-9 and np.max(np.abs(j - jj)) < 1e-9
    assert attrs["index_map_max_residual_cells"] < 1e-9
    # the crop places the columns as the renderer does, by x and y, and sees from L1 the whole grid
    i, j = _Columns(scene).indices(x, y)
    assert np.max(np.abs(i - ii)) < 1e-6 and np.max(np.abs(j - jj)) < 1e-6
    view = globe.l1_view(30.0, -40.0)
    camera = make_camera("perspective", width=41, height=41, **view["camera_options"])
    wy, wx = reachable_index_window(scene, camera, lat=30.0, lon=-40.0, height=view["height"], margin_cells=0)
    assert (wx.start, wx.stop, wy.start, wy.stop) == (0, 33, 0, 33)
    # a column inside the limb is still compared with its lat/lon
    bad = scene.copy(deep=True)
    bad["lat"].values[16, 3] += 0.5
    with pytest.raises(SwimInputError, match="coordinate 'x'|coordinate 'y'"):
        validate_scene(bad)
    # beyond the limb the positions rest on x and y alone: they must increase
    flipped = scene.assign_coords(x=scene["x"].values[::-1].copy())
    flipped["lat"].values[:] = scene["lat"].values[:, ::-1]
    flipped["lon"].values[:] = scene["lon"].values[:, ::-1]
    with pytest.raises(SwimInputError, match="increase strictly"):
        validate_scene(flipped)


def test_hemisphere_scene_puts_a_cloud_blob_where_the_condensate_is():
    content = np.zeros((10, LAT_AXIS.size, LON_AXIS.size))
    j, i = int(np.flatnonzero(LAT_AXIS == 10.0)[0]), int(np.flatnonzero(LON_AXIS == 20.0)[0])
    content[2:5, j, i] = 1e-3  # kg m-3 at (10 N, 20 E), 2-4 km
    scene = globe.hemisphere_scene(_columns(content), 0.0, -10.0, size=129)
    path = scene["cloud_liquid_content"].sum("z").values
    row, col = np.unravel_index(np.argmax(path), path.shape)
    x0, y0 = _orthographic(10.0, 20.0, 0.0, -10.0)
    spacing = float(scene["x"][1] - scene["x"][0])
    assert abs(scene["x"].values[col] - x0) <= 0.5 * spacing
    assert abs(scene["y"].values[row] - y0) <= 0.5 * spacing
    # the blob keeps its height: the cloud is on levels 2-4 only, and the peak content is the cell's
    assert np.all(scene["cloud_liquid_content"].values[[0, 1, 5, 6, 7, 8, 9]] == 0.0)
    assert scene["cloud_liquid_content"].values[3, row, col] == pytest.approx(1e-3, rel=0.35)


def test_hemisphere_scene_refuses_bad_input():
    cols = _columns()
    for radius in (0.0, 90.5):
        with pytest.raises(SwimInputError, match="disc_radius_deg"):
            globe.hemisphere_scene(cols, 0.0, 0.0, size=9, disc_radius_deg=radius)
    with pytest.raises(SwimInputError, match="height"):
        globe.hemisphere_scene(cols.drop_vars("height"), 0.0, 0.0, size=9)
    with pytest.raises(SwimInputError, match="sub_lat"):
        globe.hemisphere_scene(cols, 95.0, 0.0, size=9)


def test_sub_solar_point_at_the_june_solstice():
    # 2024 June solstice 20:51 UTC: declination +23.44 deg (obliquity); the equation of time -1.6 min puts the sun
    # over 15 deg/h x (12 h - 20.85 h + 0.027 h) = -132.4 deg (Astronomical Almanac 2024)
    lat, lon = globe.sub_solar_point("2024-06-20T20:51:00Z")
    assert lat == pytest.approx(23.44, abs=0.01)
    assert lon == pytest.approx(-132.4, abs=0.15)


def test_l1_view_fits_the_earth_in_the_field_of_view():
    from swim.geometry.cameras import make_camera

    view = globe.l1_view(10.0, -30.0)
    assert view["height"] == pytest.approx(1.5e9 - R)
    # the earth's angular radius from 1.5e9 m is 0.2434 deg; 100 km of atmosphere and 5 % margin: 0.2597 deg
    assert view["camera_options"]["fov_deg"] / 2 == pytest.approx(0.2597, abs=5e-4)
    camera = make_camera("perspective", width=31, height=31, **view["camera_options"])
    directions, _ = camera.directions()
    assert directions[15, 15] == pytest.approx([0.0, 0.0, -1.0], abs=1e-12)
    with pytest.raises(SwimInputError, match="distance_m"):
        globe.l1_view(0.0, 0.0, distance_m=6.4e6)
