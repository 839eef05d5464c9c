"""The night sky's radiances (swim.rt.night_sky) against outside numbers: the sun as a star of V = -26.76 and
B-V = 0.65 (Willmer 2018, ApJS 236, 47) against the extraterrestrial spectrum; the sun's and Vega's temperatures;
the van Rhijn factor against the chord through a thin shell; Kasten & Young's (1989) table; the dark-site zenith of
V = 21.6-22.0 mag arcsec-2 (Benn & Ellison 1998; Leinert et al. 1998) and the sky's colour in B and R."""

from __future__ import annotations

import math

import numpy as np
import pytest

from swim.constants import EARTH_RADIUS_M, WAVELENGTHS_NM
from swim.errors import SwimInputError
from swim.rt.night_sky import (AIRGLOW, ARCSEC2_SR, CHANNEL_BANDS_NM, LIGHT_C, PLANCK_H, RAYLEIGH_PHOTON_RADIANCE,
                               AirglowEmission, background_radiance, bv_temperature, emission_channel_radiance,
                               kasten_young_airmass, solar_irradiance_channels, solar_relative, star_irradiance,
                               v_surface_brightness, van_rhijn, vertical_optical_depth)


def test_the_sun_as_a_star_matches_the_extraterrestrial_spectrum():
    # V = -26.76, B-V = 0.65 (Willmer 2018): within 5 % of ASTM G173 at 615 and 546 nm; at 450 nm the black body of
    # the B-V temperature is 11 % below the sun's spectrum (the sun is not a black body)
    e = star_irradiance([-26.76], [0.65])[0]
    assert e[:2] == pytest.approx(solar_irradiance_channels()[:2], rel=0.05)
    assert e[2] == pytest.approx(solar_irradiance_channels()[2], rel=0.13)


def test_ballesteros_temperatures_of_the_sun_and_vega():
    t_sun, t_vega = bv_temperature([0.65, 0.0])
    assert t_sun == pytest.approx(5772.0, abs=150.0)    # IAU 2015 nominal solar effective temperature
    assert t_vega == pytest.approx(9600.0, abs=700.0)   # Vega's effective temperature (Kinman & Castelli 2002)


def test_star_colours_and_magnitudes():
    e = star_irradiance([0.0, 0.0, 5.0], [-0.3, 1.5, np.nan])
    assert e[0, 2] > e[0, 0]  # a hot star is bluer than red, a cool one redder
    assert e[1, 0] > e[1, 2]
    assert e[2, 1] == pytest.approx(3.63e-11 * 1e-2, rel=0.03)  # 5 magnitudes: a factor 100 at 546 nm
    with pytest.raises(SwimInputError):
        star_irradiance([np.nan], [0.0])


def test_van_rhijn_is_the_chord_through_a_thin_shell():
    # the path length through the shell [h, h + dh] seen at zenith angle z, relative to dh
    h, dh = 97_000.0, 10.0
    for z in (0.0, 30.0, 60.0, 80.0, 90.0):
        mu = math.cos(math.radians(z))
        r0 = EARTH_RADIUS_M

        def distance(r):
            return -r0 * mu + math.sqrt((r0 * mu) ** 2 + r**2 - r0**2)

        chord = (distance(r0 + h + dh) - distance(r0 + h)) / dh
        assert van_rhijn(z, h) == pytest.approx(chord, rel=2e-3)
    assert van_rhijn(0.0, h) == pytest.approx(1.0)
    assert van_rhijn(np.array([10.0]), h, observer_height_m=120_000.0)[0] == 0.0


def test_kasten_young_table():
    # Kasten & Young (1989), Table: 1.0 at the zenith, 1.995 at 60 deg, 5.60 at 80 deg, 38.09 at 90 deg
    x = kasten_young_airmass([0.0, 60.0, 80.0, 90.0])
    assert x == pytest.approx([1.0, 1.995, 5.60, 38.09], rel=5e-3)


def test_vertical_optical_depth_is_rayleigh_aerosol_and_ozone():
    tau = vertical_optical_depth(0.0, 0.0)
    # Bodhaine et al. (1999), Table 3 at sea level: 0.0961 at 546 nm (their 550 nm: 0.0973); ozone's ~0.025
    assert tau[1] == pytest.approx(0.098 + 0.025, abs=0.01)
    assert np.all(np.diff(vertical_optical_depth(0.0, 0.0)[[0, 2]]) > 0)  # blue above red
    assert vertical_optical_depth(3000.0, 0.1)[1] < vertical_optical_depth(0.0, 0.1)[1]
    with pytest.raises(SwimInputError):
        vertical_optical_depth(0.0, -0.1)


def test_a_line_keeps_its_energy():
    line = AirglowEmission("test", (557.7, 557.7), 100.0, 97_000.0)
    lc = emission_channel_radiance(line)
    widths = np.array([b1 - b0 for b0, b1 in CHANNEL_BANDS_NM])
    assert np.count_nonzero(lc) == 1 and lc[1] > 0
    assert np.sum(lc * widths) == pytest.approx(100.0 * RAYLEIGH_PHOTON_RADIANCE * PLANCK_H * LIGHT_C / 557.7e-9)
    band = emission_channel_radiance(AirglowEmission("c", (400.0, 700.0), 300.0, 90_000.0))
    assert np.sum(band * widths) == pytest.approx(sum(100.0 * RAYLEIGH_PHOTON_RADIANCE * PLANCK_H * LIGHT_C
                                                      / (0.5 * (b0 + b1) * 1e-9) * (b1 - b0) / 100.0
                                                      for b0, b1 in CHANNEL_BANDS_NM), rel=1e-9)


@pytest.mark.parametrize("height", [0.0, 2400.0])
def test_dark_site_zenith_is_21_6_to_22_0_v_mag_per_square_arcsec(height):
    # a moonless, clear, dark site at solar minimum to moderate activity: V 21.6-22.0 (Benn & Ellison 1998: 21.9 at
    # La Palma; Leinert et al. 1998, Table 2); B about 22.7, R about 20.9: bluer in B than V, redder in R
    tau = vertical_optical_depth(height, 0.05 * math.exp(-height / 1500.0))
    radiance = background_radiance(np.array(0.0), tau, height)
    v = v_surface_brightness(radiance[1])
    assert 21.6 <= v <= 22.0
    b = -2.5 * math.log10(radiance[2] * ARCSEC2_SR / 6.32e-11)  # Bessell et al. 1998: B = 0 is 6.32e-11 W m-2 nm-1
    r = -2.5 * math.log10(radiance[0] * ARCSEC2_SR / 2.18e-11)  # and R = 0 is 2.18e-11 at 640 nm
    assert 22.2 <= b <= 23.2
    assert 20.5 <= r <= 21.4


def test_the_sky_brightens_towards_the_horizon_as_krisciunas_and_schaefer():
    # Krisciunas & Schaefer (1991), Eq. 2: B(z) = B_zenith X 10^(-0.4 k (X - 1)), X = (1 - 0.96 sin^2 z)^-1/2,
    # k = 0.172 mag per air mass in V (Mauna Kea): 2.6 times the zenith at 85 deg. Their model is of a sky that
    # airglow dominates: the airglow alone follows it within 25 %; with the zodiacal light and starlight, which do
    # not brighten, the sky still brightens to the horizon
    tau = vertical_optical_depth(0.0)
    zen = np.array([0.0, 45.0, 75.0, 85.0, 89.9])
    airglow = background_radiance(zen, tau, zodiacal_s10=0.0, starlight_s10=0.0)[1]
    x = 1.0 / np.sqrt(1.0 - 0.96 * np.sin(np.radians(zen)) ** 2)
    model = x * 10.0 ** (-0.4 * 0.172 * (x - 1.0))
    assert airglow / airglow[0] == pytest.approx(model, rel=0.25)
    radiance = background_radiance(zen, tau)[1]
    assert np.all(np.diff(radiance[:4]) > 0) and radiance[4] > 1.3 * radiance[0]


def test_solar_relative_units():
    flat = solar_irradiance_channels() / (4 * np.pi)
    assert solar_relative(flat) == pytest.approx(np.ones(3))
    assert solar_relative(flat[:, None, None] * np.ones((3, 2, 2)), 1.0167)[0, 0, 0] == pytest.approx(1.0167**2)
    assert len(AIRGLOW) == 5 and WAVELENGTHS_NM[1] == 546.0
