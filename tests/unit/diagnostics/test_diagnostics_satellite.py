"""Satellite views: reflectance factor R = L' / (4 mu0) with the local sun, and nadir / geostationary views."""

import numpy as np
import pytest
import xarray as xr

import swim
from swim import frames
from swim.constants import EARTH_RADIUS_M
from swim.diagnostics.satellite import (
    GEOSTATIONARY_HEIGHT_M,
    geostationary_view,
    ground_points,
    nadir_view,
    reflectance_factor,
    reflectance_from_radiance,
)
from swim.errors import SwimInputError
from swim.geometry.cameras import PerspectiveCamera, make_camera

LAT, LON, H = 40.0, -105.3, 700e3
SUN_AZ, SUN_ZEN = 200.0, 50.0
ALBEDO = np.array([0.3, 0.5, 0.9])


def mu0_ecef(dirs_enu, lat, lon, h, sun_az, sun_zen):
    """Independent local cos(sun zenith) in earth-centred coordinates (quadratic for the ray-sphere hit)."""
    basis = frames.enu_basis_ecef(lat, lon)  # rows east, north, up (ECEF)
    origin = basis[2] * (EARTH_RADIUS_M + h)
    d = dirs_enu @ basis
    sun = frames.enu_from_azimuth_zenith(sun_az, sun_zen) @ basis
    b = d @ origin
    c = origin @ origin - EARTH_RADIUS_M**2
    disc = b * b - c
    s = -b - np.sqrt(np.where(disc >= 0, disc, np.nan))
    p = origin + s[..., None] * d
    mu0 = (p / np.linalg.norm(p, axis=-1, keepdims=True)) @ sun
    return np.where(s > 0, mu0, np.nan)


def fake_space_image(fov=40.0, size=41):
    cam = PerspectiveCamera(width=size, height=size, fov_deg=fov, view_azimuth_deg=0.0, view_zenith_deg=180.0)
    dirs, _ = cam.directions()
    mu0 = mu0_ecef(dirs, LAT, LON, H, SUN_AZ, SUN_ZEN)
    radiance = 4.0 * ALBEDO[:, None, None] * mu0  # white-ish Lambertian ground without atmosphere
    attrs = {"observer_lat": LAT, "observer_lon": LON, "observer_height_asl_m": H, "sun_azimuth_deg": SUN_AZ,
             "sun_zenith_deg": SUN_ZEN, "camera": "perspective"}
    attrs.update({f"camera_{k}": v for k, v in cam.to_attrs().items()})
    return xr.Dataset({"radiance": (("wavelength", "y", "x"), radiance)},
                      coords={"wavelength": [615.0, 546.0, 450.0]}, attrs=attrs), mu0


def test_reflectance_from_radiance():
    mu0 = np.array([1.0, 0.5, 0.1, 0.0, -0.2])
    R = reflectance_from_radiance(4 * 0.7 * mu0, mu0)
    np.testing.assert_allclose(R[:3], 0.7)
    assert np.isnan(R[3:]).all()
    assert np.isnan(reflectance_from_radiance(1.0, 0.05, min_mu0=0.1))
    with pytest.raises(SwimInputError, match="min_mu0"):
        reflectance_from_radiance(1.0, 0.5, min_mu0=1.5)


def test_lambertian_surface_gives_its_albedo():
    image, mu0 = fake_space_image()
    out = reflectance_factor(image, min_mu0=0.0)
    R = out["reflectance_factor"].values
    assert np.all(np.isfinite(mu0)) and np.ptp(mu0) > 0.05  # the local sun varies across the view (by 12 %)
    np.testing.assert_allclose(R, np.broadcast_to(ALBEDO[:, None, None], R.shape), rtol=1e-9)
    np.testing.assert_allclose(out["mu0"].values, mu0, rtol=1e-9, atol=1e-12)
    # the nadir pixel sees the point below the observer, where mu0 = cos(sun zenith at the observer)
    assert out["mu0"].values[20, 20] == pytest.approx(np.cos(np.radians(SUN_ZEN)), abs=1e-12)
    assert out["ground_lat"].values[20, 20] == pytest.approx(LAT, abs=1e-9)
    assert out["ground_lon"].values[20, 20] == pytest.approx(LON, abs=1e-9)
    assert out["distance"].values[20, 20] == pytest.approx(H, rel=1e-12)


def test_pixels_beyond_the_limb_are_nan():
    image, mu0 = fake_space_image(fov=150.0, size=31)
    out = reflectance_factor(image, min_mu0=0.0)
    space = ~np.isfinite(mu0)
    assert space[0, 0] and not space[15, 15]
    assert np.isnan(out["reflectance_factor"].values[:, space]).all()
    np.testing.assert_allclose(out["reflectance_factor"].values[:, ~space & (mu0 > 0)][1], 0.5, rtol=1e-9)


def test_ground_points_with_view_angles_only():
    image, mu0 = fake_space_image(size=21)
    cam = make_camera("perspective", width=21, height=21, fov_deg=40.0, view_azimuth_deg=0.0, view_zenith_deg=180.0)
    dirs, _ = cam.directions()
    az, zen = frames.azimuth_zenith_from_enu(dirs)
    plain = image.copy()
    plain.attrs = {k: v for k, v in image.attrs.items() if not k.startswith("camera")}
    plain["view_azimuth"] = (("y", "x"), az)
    plain["view_zenith"] = (("y", "x"), zen)
    np.testing.assert_allclose(ground_points(plain)["mu0"].values, mu0, rtol=1e-9)
    with pytest.raises(SwimInputError, match="observer_lat"):
        ground_points(xr.Dataset(attrs={}))


@pytest.fixture(scope="module")
def scene():
    return swim.default_scene()


def hit_latlon(kw):
    """(lat, lon) of the ground point seen by each pixel of the view kwargs' camera (ray-sphere in ECEF)."""
    cam = make_camera(kw["camera"], **kw["camera_options"])
    dirs, _ = cam.directions()
    basis = frames.enu_basis_ecef(kw["lat"], kw["lon"])
    origin = basis[2] * (EARTH_RADIUS_M + kw["height"])
    d = dirs @ basis
    b = d @ origin
    s = -b - np.sqrt(b * b - (origin @ origin - EARTH_RADIUS_M**2))
    p = origin + s[..., None] * d
    return np.degrees(np.arcsin(p[..., 2] / np.linalg.norm(p, axis=-1))), np.degrees(np.arctan2(p[..., 1], p[..., 0]))


@pytest.mark.parametrize("sub_lon", [-75.2, -137.2])
def test_geostationary_view_centre_pixel_looks_at_the_target(scene, sub_lon):
    kw = geostationary_view(sub_lon, scene, size=33)
    assert kw["lat"] == 0.0 and kw["lon"] == sub_lon and kw["height"] == GEOSTATIONARY_HEIGHT_M
    assert kw["camera"] == "perspective"
    lat, lon = hit_latlon(kw)
    # 1e-6 deg ~ 0.1 m on the ground
    assert lat[16, 16] == pytest.approx(scene.attrs["reference_lat"], abs=1e-6)
    assert lon[16, 16] == pytest.approx(scene.attrs["reference_lon"], abs=1e-6)
    # every scene column is inside the image
    cam = make_camera(kw["camera"], **kw["camera_options"])
    p_sat = frames.geodetic_to_scene(0.0, sub_lon, kw["height"], 0.0, sub_lon)
    p_cols = frames.geodetic_to_scene(scene["lat"].values, scene["lon"].values, 0.0, 0.0, sub_lon)
    row, col = cam.pixel_of_direction(p_cols - p_sat)
    assert np.all(np.isfinite(row)) and np.all(np.isfinite(col))


def test_geostationary_view_rejects_targets_beyond_the_limb(scene):
    with pytest.raises(SwimInputError, match="limb"):
        geostationary_view(100.0, scene)
    with pytest.raises(SwimInputError, match="target_lat"):
        geostationary_view(-75.0)
    kw = geostationary_view(-75.0, target_lat=10.0, target_lon=-80.0, half_extent_m=50e3, size=11)
    lat, lon = hit_latlon(kw)
    assert (lat[5, 5], lon[5, 5]) == pytest.approx((10.0, -80.0), abs=1e-6)


def test_nadir_view(scene):
    kw = nadir_view(scene, size=33)
    assert kw["camera_options"]["view_zenith_deg"] == 180.0
    lat, lon = hit_latlon(kw)
    assert (lat[16, 16], lon[16, 16]) == pytest.approx((40.0, -105.3), abs=1e-9)
    # corners of the 40 km domain inside the image, with the 20 % margin about the half-diagonal
    cam = make_camera(kw["camera"], **kw["camera_options"])
    p_cols = frames.geodetic_to_scene(scene["lat"].values, scene["lon"].values, 0.0, 40.0, -105.3)
    row, col = cam.pixel_of_direction(p_cols - [0.0, 0.0, EARTH_RADIUS_M + kw["height"]])
    assert np.all(np.isfinite(row)) and np.all(np.isfinite(col))
    assert np.nanmin(col) > 0.0 and np.nanmax(col) < 32.0
