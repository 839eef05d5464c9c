"""The bright-star catalogue and the stars' apparent places (swim.geometry.stars) against outside sources: the
catalogue's own documented counts and entries, PyEphem's apparent places (an independent implementation of
precession, nutation and aberration, test dependency only), Bennett's refraction formula and the pole's altitude."""

from __future__ import annotations

import math

import numpy as np
import pytest

from swim.errors import SwimInputError
from swim.geometry.cameras import AllSkyCamera
from swim.geometry.stars import (BSC5_STARS, apparent_altaz, read_bsc5, refraction_saemundsson_deg,
                                 star_catalogue, star_directions_enu)

ephem = pytest.importorskip("ephem")

#: Bright stars (HR number, name) spread over the sky.
BRIGHT = [(2491, "Sirius"), (7001, "Vega"), (5340, "Arcturus"), (2061, "Betelgeuse"), (1708, "Capella"),
          (424, "Polaris"), (7924, "Deneb"), (3982, "Regulus")]

#: (time, lat, lon, height above sea level [m])
PLACES = [("2024-01-15T03:00:00Z", 40.0, -105.3, 1600.0), ("2023-12-22T02:21:00Z", 40.0, -105.3, 1650.0),
          ("2025-06-01T22:00:00Z", -30.2, -70.7, 2200.0)]


@pytest.fixture(scope="module")
def catalogue(shared_data):
    return read_bsc5(shared_data / "stars" / "bsc5.dat")


def test_catalogue_counts_and_entries_match_its_readme(catalogue):
    # the data folder's README: 9096 records, 8786 with B-V, 5080 with V <= 6.0, 8404 with V <= 6.5
    assert len(catalogue) == BSC5_STARS
    assert np.count_nonzero(np.isfinite(catalogue.b_minus_v)) == 8786
    assert np.count_nonzero(catalogue.v_mag <= 6.0) == 5080
    assert np.count_nonzero(catalogue.v_mag <= 6.5) == 8404
    i = int(np.flatnonzero(catalogue.hr == 2491)[0])  # Sirius: RA 06 45 08.9, Dec -16 42 58, V -1.46
    assert catalogue.v_mag[i] == pytest.approx(-1.46)
    assert catalogue.ra_deg[i] == pytest.approx(15 * (6 + 45 / 60 + 8.9 / 3600), abs=1e-6)
    assert catalogue.dec_deg[i] == pytest.approx(-(16 + 42 / 60 + 58 / 3600), abs=1e-6)
    assert catalogue.b_minus_v[i] == pytest.approx(0.0, abs=0.01)


def test_catalogue_from_the_environment_and_missing_file(shared_data, monkeypatch, tmp_path):
    monkeypatch.setenv("SWIM_STAR_CATALOGUE", str(shared_data / "stars" / "bsc5.dat"))
    assert len(star_catalogue()) == BSC5_STARS
    monkeypatch.delenv("SWIM_STAR_CATALOGUE")
    assert len(star_catalogue()) == BSC5_STARS  # the packaged table
    with pytest.raises(SwimInputError, match="not found"):
        read_bsc5(tmp_path / "none.dat")


def _ephem_altaz(catalogue, hr, time, lat, lon, height, refraction):
    i = int(np.flatnonzero(catalogue.hr == hr)[0])
    obs = ephem.Observer()
    obs.lat, obs.lon, obs.elevation = str(lat), str(lon), height
    obs.date = time.replace("T", " ").rstrip("Z")
    obs.pressure = 1010.0 * math.exp(-height / 8434.0) if refraction else 0.0
    obs.temp = 10.0
    star = ephem.FixedBody()
    star._ra, star._dec, star._epoch = math.radians(catalogue.ra_deg[i]), math.radians(catalogue.dec_deg[i]), \
        ephem.J2000
    star.compute(obs)
    return math.degrees(star.alt), math.degrees(star.az), obs.pressure


@pytest.mark.parametrize("place", PLACES)
def test_apparent_places_match_pyephem(catalogue, place):
    time, lat, lon, height = place
    for hr, name in BRIGHT:
        i = int(np.flatnonzero(catalogue.hr == hr)[0])
        alt, az = apparent_altaz(catalogue.ra_deg[[i]], catalogue.dec_deg[[i]], time, lat, lon, height)
        e_alt, e_az, _ = _ephem_altaz(catalogue, hr, time, lat, lon, height, refraction=False)
        assert alt[0] == pytest.approx(e_alt, abs=0.01), name  # 36 arcsec
        d_az = (az[0] - e_az + 180) % 360 - 180
        assert abs(d_az) * math.cos(math.radians(e_alt)) < 0.01, name


@pytest.mark.parametrize("place", PLACES)
def test_refracted_places_fall_in_ephems_pixel_of_a_1024_allsky(catalogue, place):
    # the whole chain (apparent place, refraction, camera) within one pixel (0.18 deg) of PyEphem's refracted place
    time, lat, lon, height = place
    camera = AllSkyCamera(size=1024)
    idx = [int(np.flatnonzero(catalogue.hr == hr)[0]) for hr, _ in BRIGHT]
    sub = catalogue.brighter_than(99.0)
    sub = type(sub)(*(getattr(sub, f)[idx] for f in ("hr", "ra_deg", "dec_deg", "v_mag", "b_minus_v")))
    dirs, alt = star_directions_enu(sub, time, lat, lon, height, temperature_c=10.0)
    row, col = camera.pixel_of_direction(dirs)
    for k, (hr, name) in enumerate(BRIGHT):
        e_alt, e_az, _ = _ephem_altaz(catalogue, hr, time, lat, lon, height, refraction=True)
        if e_alt < 2.0:
            continue
        a, z = math.radians(e_alt), math.radians(e_az)
        e_row, e_col = camera.pixel_of_direction(np.array([math.cos(a) * math.sin(z), math.cos(a) * math.cos(z),
                                                           math.sin(a)]))
        assert math.hypot(row[k] - e_row, col[k] - e_col) < 1.0, name
        assert alt[k] == pytest.approx(e_alt, abs=0.03), name


def test_polaris_circles_the_pole_at_the_latitude(catalogue):
    # 11 h 58 min (half a sidereal day) apart Polaris stands on opposite sides of the pole: the mean of its two
    # altitudes is the latitude (plus the refraction, 1.2 arcmin at 40 deg), its half-difference at most its polar
    # distance (0.66 deg in 2024)
    i = int(np.flatnonzero(catalogue.hr == 424)[0])
    sub = type(catalogue)(*(getattr(catalogue, f)[[i]] for f in ("hr", "ra_deg", "dec_deg", "v_mag", "b_minus_v")))
    for lat in (40.0, 65.0):
        _, a1 = star_directions_enu(sub, "2024-03-01T00:00:00Z", lat, 10.0, 0.0)
        _, a2 = star_directions_enu(sub, "2024-03-01T11:58:02Z", lat, 10.0, 0.0)
        assert 0.5 * (a1[0] + a2[0]) == pytest.approx(lat, abs=0.1)
        assert 0.5 * abs(a1[0] - a2[0]) <= 0.7


def test_saemundsson_refraction_against_bennett_and_the_almanac():
    # Bennett (1982): R = 1' / tan(h0 + 7.31 / (h0 + 4.4)) of the apparent altitude h0, 1010 hPa, 10 degC
    for true_alt in (0.5, 2.0, 5.0, 10.0, 20.0, 45.0, 70.0):
        r = refraction_saemundsson_deg(true_alt)
        h0 = true_alt + r
        bennett = 1.0 / math.tan(math.radians(h0 + 7.31 / (h0 + 4.4))) / 60.0
        assert r == pytest.approx(bennett, abs=0.3 / 60)  # 0.3 arcmin
    # the almanac's standard refraction: about 34' at the apparent horizon, 58" at 45 deg
    true_at_horizon = -34.5 / 60
    assert true_at_horizon + refraction_saemundsson_deg(true_at_horizon) == pytest.approx(0.0, abs=0.05)
    assert refraction_saemundsson_deg(45.0) * 3600 == pytest.approx(58.0, abs=4.0)
    # scaled with the air's density; none far below the horizon
    assert refraction_saemundsson_deg(10.0, pressure_hpa=505.0) == pytest.approx(0.5 * refraction_saemundsson_deg(10.0))
    assert refraction_saemundsson_deg(-5.0) == 0.0


def test_directions_are_unit_vectors_and_the_catalogue_read_once(catalogue, shared_data):
    assert read_bsc5(shared_data / "stars" / "bsc5.dat") is catalogue
    dirs, alt = star_directions_enu(catalogue.brighter_than(3.0), "2024-01-15T03:00:00Z", 40.0, -105.3, 1600.0)
    assert np.allclose(np.linalg.norm(dirs, axis=1), 1.0)
    assert np.allclose(np.degrees(np.arcsin(dirs[:, 2])), alt)
    with pytest.raises(SwimInputError):
        apparent_altaz([0.0], [0.0], "2024-01-15T03:00:00Z", 95.0, 0.0)


def test_the_packaged_table_is_the_catalogue(shared_data):
    from swim.geometry.stars import packaged_catalogue, read_bsc5

    packaged, parsed = packaged_catalogue(), read_bsc5(str(shared_data / "stars" / "bsc5.dat"))
    assert len(packaged) == len(parsed) == 9096
    np.testing.assert_array_equal(packaged.hr, parsed.hr)
    np.testing.assert_array_equal(packaged.ra_deg, parsed.ra_deg)
    np.testing.assert_allclose(packaged.v_mag, parsed.v_mag, atol=1e-6)
    np.testing.assert_allclose(packaged.b_minus_v, parsed.b_minus_v, atol=1e-6, equal_nan=True)
