"""The Milky Way (swim.rt.night_sky.integrated_starlight_s10 and swim.geometry.stars.galactic_coordinates) against
outside numbers: PyEphem's galactic coordinates of bright stars (test dependency only), the integrated starlight of
20-60 S10 at galactic latitudes above 30 deg (Leinert et al. 1998, Sect. 10), the dark-site zenith of V 21.6-22.0
mag arcsec-2 (Benn & Ellison 1998) with the galactic pole or the Milky Way overhead, and the band's place in a
night sky."""

from __future__ import annotations

import math

import numpy as np
import pytest

from swim.geometry.stars import galactic_coordinates
from swim.rt.night_sky import (MILKY_WAY_POLE_S10, STARLIGHT_BACKGROUND_S10, background_radiance,
                               integrated_starlight_s10, v_surface_brightness, vertical_optical_depth)


def _enu(alt_deg, az_deg):
    a, z = math.radians(alt_deg), math.radians(az_deg)
    return np.array([math.cos(a) * math.sin(z), math.cos(a) * math.cos(z), math.sin(a)])


def test_galactic_coordinates_match_pyephem():
    ephem = pytest.importorskip("ephem")
    from swim.geometry.stars import apparent_altaz

    time, lat, lon = "2024-01-15T03:00:00Z", 40.0, -105.3
    for name in ("Deneb", "Vega", "Sirius", "Polaris", "Antares", "Rigel", "Arcturus"):
        star = ephem.star(name)
        star.compute(ephem.J2000)
        gal = ephem.Galactic(star, epoch=ephem.J2000)
        alt, az = apparent_altaz([math.degrees(star.a_ra)], [math.degrees(star.a_dec)], time, lat, lon)
        b, lon_gal = galactic_coordinates(_enu(alt[0], az[0]), time, lat, lon)
        assert b == pytest.approx(math.degrees(gal.lat), abs=0.02), name
        assert (lon_gal - math.degrees(gal.lon) + 180) % 360 - 180 == pytest.approx(0.0, abs=0.02 / math.cos(
            math.radians(math.degrees(gal.lat)))), name


def test_high_galactic_latitudes_keep_leinerts_20_to_60_s10():
    # Leinert et al. (1998), Sect. 10: the integrated starlight is 20-60 S10 at |b| > 30 deg; its sky-area mean there
    # is the uniform background it replaces (STARLIGHT_BACKGROUND_S10 = 30) within a quarter
    b = np.linspace(30.0, 90.0, 121)
    lon = np.linspace(0.0, 360.0, 145)
    bb, ll = np.meshgrid(b, lon, indexing="ij")
    s = integrated_starlight_s10(np.concatenate([bb, -bb]), np.concatenate([ll, ll]))
    assert s.min() >= 20.0 and s.max() <= 60.0
    weight = np.cos(np.radians(np.concatenate([bb, -bb])))
    assert np.sum(s * weight) / np.sum(weight) == pytest.approx(STARLIGHT_BACKGROUND_S10, rel=0.25)
    assert integrated_starlight_s10(90.0, 0.0) == pytest.approx(MILKY_WAY_POLE_S10, rel=1e-3)


def test_the_band_is_brightest_towards_the_centre_and_falls_off_with_latitude():
    # the galactic plane many times the poles' light, most towards the centre (Sagittarius), least towards the
    # anticentre (Auriga), symmetric about the plane; NaN (no direction) gives the uniform background
    centre, anticentre, pole = integrated_starlight_s10(np.array([0.0, 0.0, 90.0]), np.array([0.0, 180.0, 0.0]))
    assert centre / pole > 20 and 4 < anticentre / pole < 10
    b = np.array([0.0, 5.0, 10.0, 20.0, 40.0])
    profile = integrated_starlight_s10(b, 60.0)
    assert np.all(np.diff(profile) < 0)
    assert integrated_starlight_s10(-b, 60.0) == pytest.approx(profile)
    assert integrated_starlight_s10(np.nan, np.nan) == STARLIGHT_BACKGROUND_S10


@pytest.mark.parametrize("b,low,high", [(90.0, 21.6, 22.0), (0.0, 20.8, 21.5)])
def test_dark_site_zenith_with_the_pole_or_the_cygnus_milky_way_overhead(b, low, high):
    # the galactic pole overhead keeps the dark-site zenith in Benn & Ellison's V 21.6-22.0; the Milky Way's plane
    # overhead (Cygnus, l = 80 deg) brightens it by 0.3-1 mag, the band plain to the eye at a dark site
    tau = vertical_optical_depth(2400.0, 0.05 * math.exp(-2400.0 / 1500.0))
    radiance = background_radiance(np.array(0.0), tau, 2400.0, starlight_s10=integrated_starlight_s10(b, 80.0))
    assert low <= v_surface_brightness(radiance[1]) <= high


def test_the_band_crosses_the_night_sky_where_the_galactic_plane_stands():
    # an August night at 40 N: the Milky Way runs from Sagittarius in the south through Cygnus near the zenith; the
    # pixels within 5 deg of the galactic plane are brighter than those beyond 40 deg of it
    from swim.geometry.cameras import AllSkyCamera
    from swim.pipeline.night_sky import milky_way_s10, night_sky_radiance

    camera = AllSkyCamera(size=63)
    time, observer = "2023-08-15T04:30:00Z", (40.0, -105.3, 1650.0)
    s10 = milky_way_s10(camera, time, observer)
    dirs = camera.cached_directions()[0]
    b, _ = galactic_coordinates(dirs, time, *observer)
    zenith = camera.cached_view_angles()[1]
    up = np.isfinite(zenith) & (zenith < 70)
    assert np.median(s10[up & (np.abs(b) < 5)]) > 4 * np.median(s10[up & (np.abs(b) > 40)])
    night = night_sky_radiance(camera, zenith, np.zeros(zenith.shape), observer + (2.0,), time)[0][1]
    assert np.median(night[up & (np.abs(b) < 5)]) > 1.3 * np.median(night[up & (np.abs(b) > 40)])
