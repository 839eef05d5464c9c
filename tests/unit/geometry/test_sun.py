"""Sun position against published values (NREL SPA example, perihelion/aphelion, equinox, solstice)."""

from __future__ import annotations

import datetime as dt
import math

import numpy as np
import pandas as pd
import pytest

from swim.errors import SwimInputError
from swim.geometry.sun import SunPosition, parse_time_utc, sun_from_angles, sun_position

AU_KM = 149_597_870.7

# Reda & Andreas (2004), Solar Energy 76, 577-589, Table A5.1/A5.2: 2003-10-17 12:30:30 local (UTC-7),
# delta_t 67 s, lat 39.742476, lon -105.1786, elevation 1830.14 m, pressure 820 mbar, temperature 11 C.
SPA_TIME = "2003-10-17T12:30:30-07:00"
SPA_LAT, SPA_LON, SPA_ELEV = 39.742476, -105.1786, 1830.14
SPA_TOPO_ZENITH = 50.11162  # refraction-corrected (pvlib "apparent_zenith")
SPA_TOPO_AZIMUTH = 194.34024
SPA_RADIUS_VECTOR_AU = 0.9965422974


def spa_refraction_deg(elevation_deg, pressure_mbar=820.0, temperature_c=11.0):
    """Atmospheric refraction correction, SPA paper Eq. 42."""
    e = elevation_deg
    return (pressure_mbar / 1010.0) * (283.0 / (273.0 + temperature_c)) * 1.02 / (
        60.0 * math.tan(math.radians(e + 10.3 / (e + 5.11)))
    )


def test_pvlib_reproduces_spa_example():
    """The published example with the paper's own pressure, temperature and delta_t."""
    import pvlib.solarposition as solpos

    t = pd.DatetimeIndex([pd.Timestamp(SPA_TIME)])
    df = solpos.get_solarposition(t, SPA_LAT, SPA_LON, altitude=SPA_ELEV, pressure=82000.0, temperature=11.0,
                                  delta_t=67.0)
    assert df["apparent_zenith"].iloc[0] == pytest.approx(SPA_TOPO_ZENITH, abs=1e-4)
    assert df["azimuth"].iloc[0] == pytest.approx(SPA_TOPO_AZIMUTH, abs=1e-4)


def test_sun_position_spa_example():
    sun = sun_position(SPA_TIME, SPA_LAT, SPA_LON, SPA_ELEV)
    assert sun.source == "pvlib-spa"
    assert sun.time == pd.Timestamp("2003-10-17T19:30:30Z")
    assert sun.azimuth_deg == pytest.approx(SPA_TOPO_AZIMUTH, abs=1e-3)
    # geometric zenith = published refracted zenith + refraction (SPA Eq. 42 at the published elevation)
    refraction = spa_refraction_deg(90.0 - SPA_TOPO_ZENITH)
    assert 0.015 < refraction < 0.018
    assert sun.zenith_deg == pytest.approx(SPA_TOPO_ZENITH + refraction, abs=1e-4)
    assert sun.earth_sun_distance_au == pytest.approx(SPA_RADIUS_VECTOR_AU, abs=1e-7)


@pytest.mark.parametrize(
    "time,distance_km",
    [
        ("2024-01-03T00:39Z", 147_100_632.0),  # perihelion 2024 (USNO / NASA)
        ("2024-07-05T05:06Z", 152_099_968.0),  # aphelion 2024
    ],
)
def test_perihelion_aphelion(time, distance_km):
    r = sun_position(time, 0.0, 0.0).earth_sun_distance_au
    assert r == pytest.approx(distance_km / AU_KM, abs=1e-4)
    # an extremum: ten days either side are both farther (perihelion) or both nearer (aphelion)
    t = pd.Timestamp(time)
    before = sun_position(t - pd.Timedelta(days=10), 0.0, 0.0).earth_sun_distance_au
    after = sun_position(t + pd.Timedelta(days=10), 0.0, 0.0).earth_sun_distance_au
    sign = 1.0 if distance_km < AU_KM else -1.0
    assert sign * (before - r) > 0 and sign * (after - r) > 0
    assert sun_position(time, 0.0, 0.0).irradiance_factor == pytest.approx((AU_KM / distance_km) ** 2, rel=2e-4)


def test_equinox_noon_at_equator():
    """March equinox 2024-03-20 03:06 UTC; solar noon on the Greenwich meridian ~12:07:20 UTC (equation of time
    about -7.4 min): the noon zenith equals |declination| = asin(sin(eps) sin(lambda)) ~ 0.15 deg."""
    times = pd.date_range("2024-03-20T12:03:00Z", "2024-03-20T12:12:00Z", freq="5s")
    zen = np.array([sun_position(t, 0.0, 0.0).zenith_deg for t in times])
    i = int(np.argmin(zen))
    hours_since_equinox = (times[i] - pd.Timestamp("2024-03-20T03:06Z")).total_seconds() / 3600.0
    ecliptic_longitude = 360.0 / 365.2422 * hours_since_equinox / 24.0
    declination = math.degrees(math.asin(math.sin(math.radians(23.4393)) * math.sin(math.radians(ecliptic_longitude))))
    assert zen[i] < 0.5
    assert zen[i] == pytest.approx(declination, abs=0.01)
    assert abs((times[i] - pd.Timestamp("2024-03-20T12:07:20Z")).total_seconds()) < 60.0
    # the sun crosses the meridian north of the zenith (declination > 0): azimuth ~ 0 at noon
    noon = sun_position(times[i], 0.0, 0.0)
    assert min(noon.azimuth_deg, 360.0 - noon.azimuth_deg) < 10.0


def test_pole_at_june_solstice():
    """At the north pole the sun circles at elevation = declination = obliquity (~23.44 deg) all day."""
    for hour in range(0, 24, 4):
        sun = sun_position(pd.Timestamp("2024-06-20T20:51Z") + pd.Timedelta(hours=hour - 12), 90.0, 0.0)
        assert sun.zenith_deg == pytest.approx(90.0 - 23.4393, abs=0.01)


def test_morning_east_afternoon_west():
    am = sun_position("2024-06-21T08:00:00-06:00", 40.0, -105.0)
    pm = sun_position("2024-06-21T16:00:00-06:00", 40.0, -105.0)
    assert 0.0 < am.azimuth_deg < 180.0 and 180.0 < pm.azimuth_deg < 360.0
    assert am.direction_enu[0] > 0.0 and pm.direction_enu[0] < 0.0


def test_time_parsing():
    ref = sun_position("2024-06-21T12:00:00Z", 10.0, 20.0)
    for t in ["2024-06-21T12:00:00", "2024-06-21 14:00:00+02:00", dt.datetime(2024, 6, 21, 12),
              np.datetime64("2024-06-21T12:00:00"), pd.Timestamp("2024-06-21 07:00", tz="America/Chicago")]:
        sun = sun_position(t, 10.0, 20.0)
        assert sun.time == ref.time and str(sun.time.tz) == "UTC"
        assert sun.zenith_deg == ref.zenith_deg and sun.azimuth_deg == ref.azimuth_deg
    assert parse_time_utc("2024-06-21").hour == 0
    for bad in ["yesterday noon", "2024-13-45T99:00", None, 1.5e9, ["2024-06-21"], pd.NaT]:
        with pytest.raises(SwimInputError, match=r"time.*ISO 8601"):
            sun_position(bad, 0.0, 0.0)


def test_coordinate_validation():
    with pytest.raises(SwimInputError, match="lat"):
        sun_position("2024-06-21T12:00Z", 91.0, 0.0)
    with pytest.raises(SwimInputError, match="altitude_m"):
        sun_position("2024-06-21T12:00Z", 0.0, 0.0, altitude_m=float("nan"))
    # longitude wraps: 360 east is Greenwich
    a = sun_position("2024-06-21T12:00Z", 10.0, 0.0)
    b = sun_position("2024-06-21T12:00Z", 10.0, 360.0)
    assert a.zenith_deg == pytest.approx(b.zenith_deg, abs=1e-9)


def test_sun_from_angles_and_direction():
    sun = sun_from_angles(90.0, -90.0)  # west horizon
    assert sun.source == "override" and sun.time is None
    assert sun.azimuth_deg == 270.0 and sun.elevation_deg == 0.0
    np.testing.assert_allclose(sun.direction_enu, [-1.0, 0.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(sun_from_angles(0.0, 123.0).direction_enu, [0.0, 0.0, 1.0], atol=1e-15)
    d = sun_from_angles(60.0, 135.0).direction_enu
    np.testing.assert_allclose(d, [math.sqrt(3) / 2 * math.sqrt(0.5), -math.sqrt(3) / 2 * math.sqrt(0.5), 0.5],
                               atol=1e-15)
    assert np.linalg.norm(d) == pytest.approx(1.0, abs=1e-15)
    assert sun_from_angles(30.0, 0.0, earth_sun_distance_au=0.5).irradiance_factor == pytest.approx(4.0)
    assert sun_from_angles(30.0, 720.5).azimuth_deg == pytest.approx(0.5)
    for kwargs, name in [({"zenith_deg": -1.0, "azimuth_deg": 0.0}, "zenith_deg"),
                         ({"zenith_deg": 180.5, "azimuth_deg": 0.0}, "zenith_deg"),
                         ({"zenith_deg": 10.0, "azimuth_deg": float("nan")}, "azimuth_deg"),
                         ({"zenith_deg": 10.0, "azimuth_deg": 0.0, "earth_sun_distance_au": 0.0},
                          "earth_sun_distance_au")]:
        with pytest.raises(SwimInputError, match=name):
            sun_from_angles(**kwargs)
    with pytest.raises(SwimInputError, match="source"):
        SunPosition(10.0, 0.0, 1.0, None, "guess")
    attrs = sun_from_angles(10.0, 20.0).to_attrs()
    assert attrs["sun_source"] == "override" and all(isinstance(v, (str, float)) for v in attrs.values())
