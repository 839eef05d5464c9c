"""The planets (swim.geometry.planets) against PyEphem, an independent implementation of the planetary theory
(VSOP87), apparent place and refraction, and its magnitudes (test dependency only); the planets' phase angles and
magnitudes against their orbits' limits; and the planets drawn by the night-sky stage."""

from __future__ import annotations

import math

import numpy as np
import pytest

from swim.errors import SwimInputError
from swim.geometry.cameras import AllSkyCamera
from swim.geometry.planets import PLANETS, planet_sky
from swim.rt.night_sky import star_irradiance

ephem = pytest.importorskip("ephem")

#: (time, lat, lon, height above sea level [m]): evenings and mornings of three years, both hemispheres.
PLACES = [("2024-01-15T03:00:00Z", 40.0, -105.3, 1600.0), ("2023-12-22T02:21:00Z", 40.0, -105.3, 1650.0),
          ("2025-06-01T22:00:00Z", -30.2, -70.7, 2200.0), ("2023-02-20T02:15:00Z", 40.0, -105.3, 1650.0)]

EPHEM_BODIES = {"Mercury": "Mercury", "Venus": "Venus", "Mars": "Mars", "Jupiter": "Jupiter", "Saturn": "Saturn"}


def _ephem_planet(name, time, lat, lon, height, refraction=True, temperature=10.0):
    obs = ephem.Observer()
    obs.lat, obs.lon, obs.elevation = str(lat), str(lon), height
    obs.date = time.replace("T", " ").rstrip("Z")
    obs.pressure = 1013.25 * (1 - 2.25577e-5 * height) ** 5.25588 if refraction else 0.0  # US Standard Atmosphere
    obs.temp = temperature
    body = getattr(ephem, EPHEM_BODIES[name])()
    body.compute(obs)
    return body


@pytest.mark.parametrize("place", PLACES)
def test_places_match_pyephem_within_a_pixel_of_a_1024_allsky(place):
    # the refracted place within 0.1 deg of PyEphem's, and in its pixel of a 1024^2 all-sky image (0.18 deg)
    time, lat, lon, height = place
    sky = planet_sky(time, lat, lon, height, temperature_c=10.0)
    assert sky.names == tuple(p[0] for p in PLANETS)
    camera = AllSkyCamera(size=1024)
    row, col = camera.pixel_of_direction(sky.directions)
    for k, name in enumerate(sky.names):
        body = _ephem_planet(name, time, lat, lon, height)
        e_alt, e_az = math.degrees(body.alt), math.degrees(body.az)
        assert sky.altitude_deg[k] == pytest.approx(e_alt, abs=0.1 if e_alt > 2 else 0.3), name
        d_az = (sky.azimuth_deg[k] - e_az + 180) % 360 - 180
        assert abs(d_az) * math.cos(math.radians(e_alt)) < 0.1, name
        if e_alt > 2.0:
            a, z = math.radians(e_alt), math.radians(e_az)
            e_row, e_col = camera.pixel_of_direction(np.array([math.cos(a) * math.sin(z), math.cos(a) * math.cos(z),
                                                               math.sin(a)]))
            assert math.hypot(row[k] - e_row, col[k] - e_col) < 1.0, name


@pytest.mark.parametrize("place", PLACES[:3])
def test_venus_and_jupiter_magnitudes_match_pyephem(place):
    # Mallama & Hilton (2018) against PyEphem's magnitudes (its older almanac formulae): within 0.2 mag
    time, lat, lon, height = place
    sky = planet_sky(time, lat, lon, height)
    for name in ("Venus", "Jupiter"):
        k = sky.names.index(name)
        assert sky.v_mag[k] == pytest.approx(_ephem_planet(name, time, lat, lon, height).mag, abs=0.2), name


def test_magnitudes_and_phase_angles_within_the_planets_ranges():
    # over a synodic period of Venus, within the planets' ranges of apparent magnitude (Mallama & Hilton 2018):
    # Venus -4.92 to -2.98, Jupiter -2.94 to -1.66, Saturn -0.55 to 1.47, Mars -2.94 to 1.86; an outer planet's phase
    # angle below asin(1 AU / r): Jupiter's under 12 deg, Saturn's under 6.5 deg; Venus's illuminated fraction as
    # PyEphem's phase
    for time in ("2022-01-01T00:00:00Z", "2022-05-01T00:00:00Z", "2022-09-01T00:00:00Z", "2023-01-01T00:00:00Z",
                 "2023-05-01T00:00:00Z", "2023-08-13T00:00:00Z"):
        sky = planet_sky(time, 0.0, 0.0)
        v = dict(zip(sky.names, sky.v_mag))
        phase = dict(zip(sky.names, sky.phase_angle_deg))
        assert -4.92 <= v["Venus"] <= -2.98 and -2.94 <= v["Jupiter"] <= -1.66
        assert -0.55 <= v["Saturn"] <= 1.47 and -2.94 <= v["Mars"] <= 1.86
        assert phase["Jupiter"] < 12.0 and phase["Saturn"] < 6.5
        fraction = 50.0 * (1 + math.cos(math.radians(phase["Venus"])))
        assert fraction == pytest.approx(_ephem_planet("Venus", time, 0.0, 0.0, 0.0).phase, abs=0.5)


def test_colours_follow_the_planets_b_minus_v():
    # Mars (B-V 1.36) is the reddest, Venus (0.82) and Jupiter (0.83) yellow-white: red/blue of their irradiance
    sky = planet_sky("2024-01-15T03:00:00Z", 40.0, -105.3)
    e = star_irradiance(sky.v_mag, sky.b_minus_v)
    red_blue = dict(zip(sky.names, e[:, 0] / e[:, 2]))
    assert red_blue["Mars"] > red_blue["Saturn"] > red_blue["Venus"]
    sun_like = star_irradiance([0.0], [0.65])[0]
    assert red_blue["Venus"] > sun_like[0] / sun_like[2]  # sunlight reddened by the planet's reflectance
    assert red_blue["Mars"] < 3.0


def test_bad_observer_and_time():
    with pytest.raises(SwimInputError):
        planet_sky("2024-01-15T03:00:00Z", 95.0, 0.0)
    with pytest.raises(SwimInputError, match="DE421"):
        planet_sky("2060-01-01T00:00:00Z", 40.0, 0.0)


def test_the_night_sky_draws_jupiter_where_pyephem_puts_it():
    from swim.pipeline.night_sky import night_sky_radiance

    time = "2024-01-15T03:00:00Z"
    camera = AllSkyCamera(size=95)
    zenith = camera.cached_view_angles()[1]
    night, _, _, planets = night_sky_radiance(camera, zenith, np.zeros(zenith.shape), (40.0, -105.3, 1600.0, 2.0),
                                              time)
    assert "Jupiter" in planets and "Venus" not in planets  # Venus is a morning star then, below the horizon
    body = _ephem_planet("Jupiter", time, 40.0, -105.3, 1600.0)
    a, z = float(body.alt), float(body.az)
    row, col = camera.pixel_of_direction(np.array([math.cos(a) * math.sin(z), math.cos(a) * math.cos(z),
                                                   math.sin(a)]))
    r, c = int(round(float(row))), int(round(float(col)))
    block = night[1, r - 4:r + 5, c - 4:c + 5]
    # Jupiter (V -2.5) is the brightest point of its neighbourhood, by far (Aldebaran, V 0.9, is 25 deg away)
    assert night[1, r, c] == block.max()
    assert night[1, r, c] > 50 * np.median(block)
