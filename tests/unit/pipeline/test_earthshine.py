"""Earthshine on the moon's dark part (swim.pipeline.moonlight: earthshine_ratio, moon_disk with earthshine) against
outside numbers: the Lambert sphere's phase function (Russell 1916), the earth's apparent albedo 0.297 of Qiu et al.
(2003, JGR 108, 4709) recovered from the drawn disk through their equation written out here, and the earthshine's
order of magnitude relative to the crescent."""

from __future__ import annotations

import math

import numpy as np
import pytest

from swim.errors import SwimInputError
from swim.geometry.cameras import PerspectiveCamera
from swim.geometry.moon import lunar_irradiance, moon_from_angles
from swim.pipeline.moonlight import (EARTH_APPARENT_ALBEDO, earth_irradiance_at_moon, earthshine_ratio,
                                     full_moon_ratio, lambert_phase_function, moon_disk)


def test_lambert_phase_function():
    # Russell (1916): 1 at full phase, 1/pi at quadrature, 0 at new; its integral 2 int f sin a da = 4/3 (the phase
    # integral q of a Lambert sphere: Bond albedo = 3/2 geometric albedo)
    assert lambert_phase_function([0.0, 90.0, 180.0]) == pytest.approx([1.0, 1.0 / math.pi, 0.0], abs=1e-12)
    a = np.linspace(0.0, 180.0, 20001)
    q = 2.0 * np.trapezoid(lambert_phase_function(a) * np.sin(np.radians(a)), np.radians(a))
    assert q == pytest.approx(1.5, rel=1e-4)


def test_full_earth_at_the_moon():
    # at new moon the whole sunlit earth faces the moon: (2/3) 0.297 (6371 / 384400)^2 = 5.4e-5 of the sun's
    # irradiance, V = -26.74 + 10.7 = -16.1 seen from the moon, 20-25 full moons (Miller & Turner: 2.5e-6)
    e = earth_irradiance_at_moon(180.0)
    assert e == pytest.approx(2.0 / 3.0 * 0.297 * (6371.0 / 384400.0) ** 2, rel=1e-9)
    assert -26.74 - 2.5 * math.log10(e) == pytest.approx(-16.1, abs=0.1)
    assert 15 < e / full_moon_ratio() < 30
    assert earth_irradiance_at_moon(0.0) == pytest.approx(0.0, abs=1e-15)  # full moon: the earth's night side
    with pytest.raises(SwimInputError):
        earth_irradiance_at_moon(90.0, apparent_albedo=1.5)


@pytest.mark.parametrize("phase", [120.0, 140.0])
def test_the_drawn_dark_side_gives_back_qius_apparent_albedo(phase):
    # Qiu et al. (2003): p* = (3/2) (I_dark / I_lit) f_L(g) / f_L(~1 deg) / f_e(180 - g) (d / R_E)^2, f_L the moon's
    # surface brightness at phase angle g relative to opposition, here from the Miller & Turner irradiance over the lit
    # fraction; the dark and lit pixels of a resolved disk (1 deg perspective view, 255 pixels) give p* = 0.297
    moon = moon_from_angles(60.0, 180.0, phase, bright_limb_angle_deg=90.0)
    cam = PerspectiveCamera(width=255, height=255, fov_deg=1.0, view_azimuth_deg=180.0, view_zenith_deg=60.0)
    dirs, valid = cam.cached_directions()
    m = moon.direction_enu
    t = np.array([0.8, 0.7, 0.6])
    pixels, radiance = moon_disk(cam, dirs, valid, m, moon.sun_from_moon_enu(), t, moon.angular_radius_rad,
                                 earthshine=moon)
    lit_pixels, bright = moon_disk(cam, dirs, valid, m, moon.sun_from_moon_enu(), t, moon.angular_radius_rad)
    assert radiance.shape == (3, pixels.size) and np.isin(lit_pixels, pixels).all()
    lit = np.isin(pixels, lit_pixels)
    assert np.allclose(radiance[:, lit], bright[:, None])  # the lit part as without earthshine
    dark = radiance[:, ~lit]
    assert dark.shape[1] > 0.5 * lit.size * (1 - moon.illuminated_fraction)
    ratio = dark[:, 0] / bright
    k = lit.sum() / lit.size
    f_lunar = lunar_irradiance(phase) / k / lunar_irradiance(1.0)  # surface brightness relative to opposition
    earth_phase = math.radians(180.0 - phase)
    f_e = (math.sin(earth_phase) + (math.pi - earth_phase) * math.cos(earth_phase)) / math.pi
    p_star = 1.5 * ratio * f_lunar / f_e * (moon.distance_m / 6_371_000.0) ** 2
    assert p_star == pytest.approx(np.full(3, 0.297), rel=0.01)


def test_earthshine_is_a_thousandth_to_a_ten_thousandth_of_the_crescent():
    # the dark side of a crescent or quarter moon is 1e-4 to 1e-3 of the lit part (about 10 magnitudes per
    # square arcsecond fainter), brighter the thinner the crescent (the fuller the earth seen from the moon)
    ratios = [float(earthshine_ratio(g)[1]) for g in (90.0, 120.0, 150.0)]
    assert 5e-5 < ratios[0] < 2e-4 and 1e-4 < ratios[1] < 1e-3 and 3e-4 < ratios[2] < 2e-3
    assert ratios[0] < ratios[1] < ratios[2]
    assert earthshine_ratio(60.0, apparent_albedo=2 * EARTH_APPARENT_ALBEDO)[1] == pytest.approx(
        2 * earthshine_ratio(60.0)[1])


def test_an_unresolved_disk_with_earthshine_keeps_its_pixels():
    moon = moon_from_angles(60.0, 180.0, 120.0)
    cam = PerspectiveCamera(width=64, height=48, fov_deg=60.0, view_azimuth_deg=180.0, view_zenith_deg=60.0)
    dirs, valid = cam.cached_directions()
    t = np.ones(3)
    pixels, radiance = moon_disk(cam, dirs, valid, moon.direction_enu, moon.sun_from_moon_enu(), t,
                                 moon.angular_radius_rad, earthshine=moon)
    plain, value = moon_disk(cam, dirs, valid, moon.direction_enu, moon.sun_from_moon_enu(), t,
                             moon.angular_radius_rad)
    assert np.array_equal(pixels, plain) and np.allclose(radiance, value[:, None])
