"""Irradiance from all-sky images (swim.diagnostics) and the exact pixel solid angles of the cameras."""

import numpy as np
import pytest
import xarray as xr

from swim.constants import WAVELENGTHS_NM
from swim.diagnostics import irradiance_w_m2, sky_irradiance
from swim.errors import SwimInputError
from swim.geometry.cameras import AllSkyCamera, PanoramaCamera, PerspectiveCamera


@pytest.mark.parametrize("size", [1, 2, 3, 10, 61, 120, 121, 255])
def test_allsky_solid_angles_sum_to_the_hemisphere(size):
    cam = AllSkyCamera(size=size)
    omega = cam.pixel_solid_angles()
    assert omega.shape == (size, size)
    assert np.all(omega >= 0)
    assert omega.sum() == pytest.approx(2 * np.pi, rel=1e-12)
    assert cam.pixel_solid_angles(cosine_weighted=True).sum() == pytest.approx(np.pi, rel=1e-12)


def test_allsky_solid_angles_match_brute_force_integration():
    """Against a 400 x 400 midpoint sub-sampling of pixels at the centre, mid-radius and on the rim."""
    cam = AllSkyCamera(size=21)
    omega = cam.pixel_solid_angles()
    projected = cam.pixel_solid_angles(cosine_weighted=True)
    k, c, rim = cam.radians_per_pixel, cam.centre, cam.size / 2.0
    n = 400
    sub = (np.arange(n) + 0.5) / n - 0.5
    for i, j in [(10, 10), (10, 15), (3, 7), (0, 10), (2, 3), (1, 5)]:
        u, v = np.meshgrid(j - c + sub, i - c + sub)
        r = np.hypot(u, v)
        zen = k * r
        density = np.where(r <= rim, k * k * np.sinc(zen / np.pi), 0.0) / n**2  # sin(z)/r * k per pixel^2
        assert omega[i, j] == pytest.approx(density.sum(), rel=2e-3, abs=1e-7), (i, j)
        assert projected[i, j] == pytest.approx((density * np.cos(zen)).sum(), rel=2e-3, abs=1e-7), (i, j)


def test_allsky_beyond_the_horizon():
    cam = AllSkyCamera(size=41, max_zenith_deg=120.0)
    assert cam.pixel_solid_angles().sum() == pytest.approx(2 * np.pi * 1.5, rel=1e-12)
    assert cam.pixel_solid_angles(upper_hemisphere=True).sum() == pytest.approx(2 * np.pi, rel=1e-12)
    assert cam.pixel_solid_angles(cosine_weighted=True).sum() == pytest.approx(np.pi, rel=1e-12)


def test_panorama_and_perspective_solid_angles():
    pano = PanoramaCamera(width=36, height=18)
    assert pano.pixel_solid_angles().sum() == pytest.approx(4 * np.pi)
    assert pano.pixel_solid_angles(upper_hemisphere=True).sum() == pytest.approx(2 * np.pi)
    assert pano.pixel_solid_angles(cosine_weighted=True).sum() == pytest.approx(np.pi)
    # a 90° square pinhole camera sees one face of a cube: 4 pi / 6
    cube = PerspectiveCamera(width=7, height=7, fov_deg=90.0, view_azimuth_deg=0.0, view_zenith_deg=0.0)
    assert cube.pixel_solid_angles().sum() == pytest.approx(4 * np.pi / 6)


def _isotropic_image(size, value, sun_zenith=40.0, t_direct=(0.7, 0.6, 0.5), components=True):
    cam = AllSkyCamera(size=size)
    dirs, valid = cam.directions()
    zen = np.degrees(np.arccos(np.clip(dirs[..., 2], -1, 1)))
    az = np.degrees(np.arctan2(dirs[..., 0], dirs[..., 1])) % 360
    sky = np.where(valid[None], np.asarray(value, dtype=float)[:, None, None] * np.ones((3, size, size)), np.nan)
    data = {"view_zenith": (("y", "x"), np.where(valid, zen, np.nan)),
            "view_azimuth": (("y", "x"), np.where(valid, az, np.nan))}
    if components:
        data.update(radiance=(("wavelength", "y", "x"), sky + 100.0),  # a "sun disk" that must not count
                    radiance_clear=(("wavelength", "y", "x"), 0.25 * sky),
                    radiance_cloud=(("wavelength", "y", "x"), 0.75 * sky),
                    radiance_surface=(("wavelength", "y", "x"), np.full_like(sky, np.nan)))
    else:
        data.update(radiance=(("wavelength", "y", "x"), sky))
    attrs = {"sun_zenith_deg": sun_zenith, "sun_azimuth_deg": 135.0, "direct_transmittance": np.array(t_direct),
             "earth_sun_distance_au": 1.0}
    attrs.update({f"camera_{k}": v for k, v in cam.to_attrs().items()} | cam.to_attrs())
    return xr.Dataset(data, coords={"wavelength": WAVELENGTHS_NM}, attrs=attrs)


@pytest.mark.parametrize("size", [15, 61, 121])
@pytest.mark.parametrize("components", [True, False])
def test_isotropic_sky_gives_a_quarter_of_the_radiance(size, components):
    value = np.array([1.0, 2.0, 0.4])
    t_direct = np.array([0.7, 0.6, 0.5])
    out = sky_irradiance(_isotropic_image(size, value, t_direct=t_direct, components=components))
    np.testing.assert_allclose(out["dhi"].values, value / 4.0, rtol=1e-12)
    mu0 = np.cos(np.radians(40.0))
    np.testing.assert_allclose(out["direct_horizontal"].values, mu0 * t_direct)
    np.testing.assert_allclose(out["dni"].values, t_direct)
    np.testing.assert_allclose(out["ghi"].values, value / 4.0 + mu0 * t_direct, rtol=1e-12)


def test_linear_sky_gradient():
    """L' = a + b cos(z): E/E_TOA = (1/4pi) 2pi (a/2 + b/3) = a/4 + b/6."""
    ds = _isotropic_image(121, np.ones(3))
    mu = np.cos(np.radians(ds["view_zenith"].values))
    sky = (2.0 + 3.0 * mu)[None] * np.ones((3, 1, 1))
    ds["radiance_clear"] = (("wavelength", "y", "x"), sky)
    ds["radiance_cloud"] = (("wavelength", "y", "x"), np.zeros_like(sky))
    out = sky_irradiance(ds)
    np.testing.assert_allclose(out["dhi"].values, 2.0 / 4 + 3.0 / 6, rtol=2e-4)  # pixel-centre mu: O(pixel^2)


def test_conversion_and_errors():
    out = sky_irradiance(_isotropic_image(31, np.full(3, 2.0)))
    watts = irradiance_w_m2(out)
    assert float(watts["dhi"]) == pytest.approx(0.5 * 1362.0)
    assert watts["ghi"].attrs["units"] == "W m-2"
    assert irradiance_w_m2(0.5, earth_sun_distance_au=2.0) == pytest.approx(0.5 * 1362.0 / 4)
    bad = _isotropic_image(31, np.ones(3))
    bad.attrs["camera_kind"] = "panorama"
    with pytest.raises(SwimInputError):
        sky_irradiance(bad)


def test_render_of_a_clear_sky_is_consistent_with_its_components():
    """End to end on a tiny render: GHI = DHI + mu0 DNI and DHI > 0 (cloud-free sea scene)."""
    from swim import render
    from swim.validation.disort import clear_scene

    ds = render(clear_scene(), camera="allsky", camera_options={"size": 21}, sun_zenith=30.0, sun_azimuth=135.0,
                height=0.0)
    out = sky_irradiance(ds)
    assert np.all(out["dhi"].values > 0.02) and np.all(out["dhi"].values < 0.3)
    np.testing.assert_allclose(out["dni"].values, ds.attrs["direct_transmittance"])
    np.testing.assert_allclose(out["ghi"].values, out["dhi"].values + np.cos(np.radians(30.0)) * out["dni"].values)


@pytest.mark.parametrize("shape", [(1, 1), (5, 7), (41, 41)])
def test_radiance_without_sun_disk_sums_the_components_with_nan_as_zero(shape):
    """The sum of the clear, cloud and surface components of an image (NaN outside the camera's circle counts as 0),
    as xarray's ``fillna(0)`` and ``+`` give it, in float64; an image without a component is a KeyError."""
    from swim.diagnostics.irradiance import radiance_without_sun_disk

    rng = np.random.default_rng(3)
    dims = ("wavelength", "y", "x")
    parts = {}
    for key in ("radiance_clear", "radiance_cloud", "radiance_surface"):
        values = rng.random((3,) + shape).astype(np.float32)
        values[rng.random(values.shape) < 0.3] = np.nan
        parts[key] = (dims, values)
    image = xr.Dataset(parts)
    expected = sum(image[key].fillna(0) for key in parts).values.astype(float)
    got = radiance_without_sun_disk(image)
    assert got.dtype == np.float64 and got.shape == (3,) + shape
    np.testing.assert_array_equal(got, expected)
    assert np.all(np.isfinite(got))
    with pytest.raises(KeyError):
        radiance_without_sun_disk(image.drop_vars("radiance_cloud"))
