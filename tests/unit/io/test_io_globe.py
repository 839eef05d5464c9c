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
    scene = globe.hemisphere_scene(_columns(terrain=terrain), -21.0, 2.5, size=65, corner_radius_deg=85.0)
    x, y = np.meshgrid(scene["x"].values, scene["y"].values)
    ox, oy = _orthographic(scene["lat"].values, scene["lon"].values, -21.0, 2.5)
    assert np.max(np.hypot(ox - x, oy - y)) < 1.0  # [m]
    # the centre column is the sub-observer point; a corner lies 85 deg away, the middle of an edge 44.6 deg
    assert scene["lat"].values[32, 32] == pytest.approx(-21.0, abs=1e-9)
    assert scene["lon"].values[32, 32] == pytest.approx(2.5, abs=1e-9)
    corner = np.hypot(x[0, 0], y[0, 0])
    assert np.rad2deg(np.arcsin(corner / R)) == pytest.approx(85.0, abs=1e-6)
    assert globe.axis_radius_deg(85.0) == pytest.approx(np.rad2deg(np.arcsin(np.sin(np.deg2rad(85.0)) / 2**0.5)))
    la, lo = np.deg2rad(scene["lat"].values), np.deg2rad(scene["lon"].values)
    want = 1000.0 + 800.0 * np.sin(la) * np.cos(lo)
    assert np.max(np.abs(scene["terrain_height"].values - want)) < 5.0  # [m]; 2.5 deg bilinear: <= ~1.3 m


def test_hemisphere_scene_puts_a_cloud_blob_where_the_condensate_is():
    content = np.zeros((10, LAT_AXIS.size, LON_AXIS.size))
    j, i = int(np.flatnonzero(LAT_AXIS == 10.0)[0]), int(np.flatnonzero(LON_AXIS == 20.0)[0])
    content[2:5, j, i] = 1e-3  # kg m-3 at (10 N, 20 E), 2-4 km
    scene = globe.hemisphere_scene(_columns(content), 0.0, -10.0, size=129, corner_radius_deg=88.0)
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
    with pytest.raises(SwimInputError, match="corner_radius_deg"):
        globe.hemisphere_scene(cols, 0.0, 0.0, size=9, corner_radius_deg=90.0)
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
