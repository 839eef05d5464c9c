"""Renders lit by the moon (swim.render(..., light="moon")): the scaling, the attributes, the phase of the disk, and the
moonlit clear sky's brightness against Krisciunas and Schaefer's (1991) model."""

from __future__ import annotations

import math

import numpy as np
import pytest

import swim
from swim import frames
from swim.errors import SwimInputError
from swim.geometry.moon import lunar_irradiance_ratio, moon_from_angles, solar_irradiance_at_channels

#: V = 0 flux density at 550 nm [W m-2 nm-1]: 3.63e-9 erg cm-2 s-1 A-1 (Bessell, Castelli and Plez 1998, A&A 333,
#: 231, Table A2).
V_ZERO_W_M2_NM = 3.63e-11
#: One square arcsecond [sr].
ARCSEC2_SR = (math.pi / 180.0 / 3600.0) ** 2


def _clear_scene(time="2024-03-10T10:00:00Z"):
    """A cloudless sea-level scene 80 km wide (the default background aerosol: continental, AOD 0.05)."""
    x = np.linspace(-40e3, 40e3, 21)
    z = np.linspace(100.0, 15000.0, 20)
    return swim.scene_from_arrays(x=x, y=x.copy(), z=z, reference_lat=19.8, reference_lon=-155.5,
                                  surface_albedo=0.1, time=time)


def _airmass_ks(zenith_deg):
    """Krisciunas and Schaefer (1991), Eq. 3: X(Z) = (1 - 0.96 sin^2 Z)^-1/2."""
    return (1.0 - 0.96 * math.sin(math.radians(zenith_deg)) ** 2) ** -0.5


def ks_moonlight_v(phase_deg, moon_zenith_deg, sky_zenith_deg, separation_deg, k_v):
    """The scattered moonlight's V surface brightness [mag arcsec-2] of Krisciunas and Schaefer (1991), PASP 103,
    1033, Eqs. 15-21: B = f(rho) I* 10^(-0.4 k X(Z_m)) [1 - 10^(-0.4 k X(Z))] [nL], I* = 10^(-0.4 (3.84 + 0.026 |a|
    + 4e-9 a^4)), f(rho) = 10^5.36 (1.06 + cos^2 rho) + 10^(6.15 - rho / 40), converted with their Eq. 1,
    B [nL] = 34.08 exp(20.7233 - 0.92104 V)."""
    illuminance = 10 ** (-0.4 * (3.84 + 0.026 * abs(phase_deg) + 4e-9 * phase_deg**4))
    rho = separation_deg
    f = 10**5.36 * (1.06 + math.cos(math.radians(rho)) ** 2) + 10 ** (6.15 - rho / 40.0)
    b = (f * illuminance * 10 ** (-0.4 * k_v * _airmass_ks(moon_zenith_deg))
         * (1.0 - 10 ** (-0.4 * k_v * _airmass_ks(sky_zenith_deg))))
    return (20.7233 - math.log(b / 34.08)) / 0.92104


def v_surface_brightness(radiance_546):
    """V [mag arcsec-2] of a solar-relative radiance at 546 nm: L = L' E_TOA / (4 pi) per arcsec^2 against the V = 0
    flux density (the 546 nm channel taken as the V band's effective wavelength)."""
    radiance = radiance_546 * solar_irradiance_at_channels()[1] / (4.0 * math.pi)
    return -2.5 * math.log10(radiance * ARCSEC2_SR / V_ZERO_W_M2_NM)


def moonlight(image):
    """The image's radiance (3, ny, nx) less the night sky's (airglow, zodiacal light, stars: docs/rendering.md,
    "Night sky"), which a moonlit render adds: the scattered moonlight alone."""
    if "radiance_night_sky" not in image:
        return image.radiance.values
    return image.radiance.values - np.nan_to_num(image.radiance_night_sky.values)


def _pixel(image, azimuth_deg, zenith_deg):
    d = frames.enu_from_azimuth_zenith(image.view_azimuth.values, image.view_zenith.values)
    target = frames.enu_from_azimuth_zenith(azimuth_deg, zenith_deg)
    return np.unravel_index(np.nanargmax(np.where(np.isfinite(d[..., 0]), d @ target, -2.0)), d.shape[:2])


def test_moonlight_is_the_sunlit_render_scaled():
    scene = _clear_scene()
    moon = moon_from_angles(35.0, 160.0, 20.0)
    lit = swim.render(scene, sun_zenith=35.0, sun_azimuth=160.0, camera_options={"size": 41})
    night = swim.render(scene, light=moon, camera_options={"size": 41}, white_level="auto")
    ratio = lunar_irradiance_ratio(moon)
    assert 1e-6 < ratio[1] < 3e-6
    iy, ix = _pixel(night, 0.0, 40.0)  # far from the moon's disk
    assert np.allclose(moonlight(night)[:, iy, ix], lit.radiance[:, iy, ix].values * ratio, rtol=1e-4)
    assert np.allclose(night.radiance_clear[:, iy, ix], lit.radiance_clear[:, iy, ix] * ratio, rtol=1e-5)
    assert night.attrs["light"] == "moon" and "light" not in lit.attrs
    assert np.allclose(night.attrs["moon_irradiance_ratio"], ratio)
    assert night.attrs["moon_phase_angle_deg"] == pytest.approx(20.0)
    assert night.rgb.values.max() > 50  # the auto exposure shows it


def test_moonlight_at_the_time_and_errors():
    scene = _clear_scene("2024-10-17T11:26:00Z")  # the full moon high over Hawaii the night before (UTC 01:26 HST)
    image = swim.render(scene, light="moon", camera_options={"size": 21}, white_level="auto")
    assert image.attrs["moon_source"] == "skyfield-de421"
    assert image.attrs["moon_illuminated_fraction"] > 0.98
    assert image.attrs["sun_zenith_reference_deg"] == pytest.approx(image.attrs["moon_zenith_deg"], abs=1e-9)
    with pytest.raises(SwimInputError, match="light"):
        swim.render(scene, light="stars")
    with pytest.raises(SwimInputError, match="sun_zenith"):
        swim.render(scene, light="moon", sun_zenith=30.0, sun_azimuth=0.0)


#: (phase angle, moon zenith, sky point's azimuth and zenith) [deg]: the moon in the south (azimuth 180).
KS_GEOMETRIES = [(10.0, 30.0, 0.0, 0.0), (60.0, 50.0, 90.0, 60.0), (90.0, 20.0, 0.0, 45.0)]


@pytest.mark.full
@pytest.mark.parametrize("phase,moon_zenith,sky_azimuth,sky_zenith", KS_GEOMETRIES)
def test_moonlit_sky_against_krisciunas_schaefer(phase, moon_zenith, sky_azimuth, sky_zenith):
    """Within 0.3 mag of K&S with the extinction k_V of the rendered atmosphere (from the moon's direct
    transmittance) and with their Mauna Kea k_V = 0.172 mag per airmass."""
    moon = moon_from_angles(moon_zenith, 180.0, phase)
    image = swim.render(_clear_scene(), light=moon, camera_options={"size": 121}, white_level="auto")
    k_v = -2.5 * math.log10(image.attrs["direct_transmittance"][1]) / _airmass_ks(moon_zenith)
    assert 0.12 < k_v < 0.20
    iy, ix = _pixel(image, sky_azimuth, sky_zenith)
    zenith = float(image.view_zenith[iy, ix])
    d = frames.enu_from_azimuth_zenith(float(image.view_azimuth[iy, ix]), zenith)
    separation = math.degrees(math.acos(float(np.clip(d @ moon.direction_enu, -1, 1))))
    ours = v_surface_brightness(float(moonlight(image)[1, iy, ix]))
    for k in (k_v, 0.172):
        assert ours == pytest.approx(ks_moonlight_v(phase, moon_zenith, zenith, separation, k), abs=0.3)


@pytest.mark.full
def test_crescent_disk_in_a_perspective_view():
    """A 1-degree view of a crescent (phase angle 120 deg, lit on the right): the lit pixels are a quarter of the
    disk, on its right, and carry the moon's direct irradiance; the dark part shows by earthshine, at
    :func:`swim.pipeline.moonlight.earthshine_ratio` of the lit part's radiance."""
    moon = moon_from_angles(50.0, 240.0, 120.0, bright_limb_angle_deg=90.0)
    image = swim.render(_clear_scene(), light=moon, camera="perspective", white_level="auto",
                        camera_options={"width": 121, "height": 121, "fov_deg": 1.0, "view_azimuth_deg": 240.0,
                                        "view_zenith_deg": 50.0})
    from swim.pipeline.moonlight import earthshine_ratio

    g = moonlight(image)[1]
    sky = float(np.median(g))
    disk = g > 0.1 * g.max()  # the lit part; the earthshine is ~3e-4 of it
    assert disk.sum() == pytest.approx(moon.illuminated_fraction * math.pi * (0.259 * 121) ** 2, rel=0.1)
    ashen = (g > 3 * sky) & ~disk  # the dark part by earthshine, brighter than the sky about the moon
    assert ashen.sum() == pytest.approx((1 - moon.illuminated_fraction) * math.pi * (0.259 * 121) ** 2, rel=0.15)
    ratio = float(np.median(g[ashen]) / np.median(g[disk]))
    expected = earthshine_ratio(moon.phase_angle_deg, moon.distance_m, moon.illuminated_fraction)[1]
    assert ratio == pytest.approx(expected, rel=0.3)
    cols = np.nonzero(disk)[1]
    assert cols.mean() > 60 + 0.3 * 0.259 * 121  # right of the centre by more than a third of the radius
    pixel_sr = (math.radians(1.0) / 121) ** 2
    e_moon = lunar_irradiance_ratio(moon)[1] * image.attrs["direct_transmittance"][1]
    assert float(((g[disk] - sky) * pixel_sr).sum()) == pytest.approx(4 * math.pi * e_moon, rel=0.05)
