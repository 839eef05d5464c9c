"""Renders lit by the sun and the moon together (swim.render(..., light="sun+moon")): the sum of the sunlit and the
moonlit renders, each light marched only where it shows, the night sky added once, and the command line's option.

The built-in scene (Boulder-like, 40.0 N, 105.3 W) on 2023-06-22/23 UTC, a waxing crescent (21-22 % lit); the sun's
and the moon's elevations at the reference point (JPL DE421 via Skyfield, NREL SPA via pvlib):

=================  =====  ======
time (UTC)         sun    moon
=================  =====  ======
2023-06-23 00:00   26.6   62.9     both up: day with the moon
2023-06-23 02:54   -4.1   33.6     civil twilight with the moon up
2023-06-23 05:00   -20.4  10.0     night (below astronomical twilight's -18 deg) with the moon up
2023-06-23 08:00   -25.2  -19.9    night, no moon
2023-06-23 14:00   25.3   -24.0    day, the moon down
=================  =====  ======
"""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr
from typer.testing import CliRunner

import swim
from swim.cli.main import app
from swim.errors import SwimInputError
from swim.geometry.moon import moon_position
from swim.geometry.sun import sun_position
from swim.pipeline.moonlight import (MOON_MARCH_MIN_ELEVATION_DEG, SUN_MARCH_MIN_ELEVATION_DEG, crop_light_direction,
                                     full_moon_ratio, progress_of)

DAY_WITH_MOON = "2023-06-23T00:00Z"
TWILIGHT = "2023-06-23T02:54Z"
NIGHT = "2023-06-23T05:00Z"
MOONLESS_NIGHT = "2023-06-23T08:00Z"
MOON_DOWN = "2023-06-23T14:00Z"
SIZE = {"size": 31}


@pytest.fixture(scope="module")
def scene():
    return swim.default_scene()


def _render(scene, time, light, **kwargs):
    return swim.render(scene, time=time, light=light, camera_options=SIZE, **kwargs)


def _night_sky(image):
    return np.nan_to_num(image.radiance_night_sky.values) if "radiance_night_sky" in image else 0.0


def _elevations(time):
    lat, lon = 40.0, -105.3
    return sun_position(time, lat, lon).elevation_deg, 90.0 - moon_position(time, lat, lon).zenith_deg


def test_the_times_put_the_lights_where_the_tests_need_them():
    sun, moon = _elevations(DAY_WITH_MOON)
    assert sun > 20 and moon > 20
    sun, moon = _elevations(TWILIGHT)
    assert -6 < sun < -3 and moon > 20  # civil twilight: the sun 0-6 deg below the horizon
    sun, moon = _elevations(NIGHT)
    assert sun < SUN_MARCH_MIN_ELEVATION_DEG == -18.0 and moon > 5
    sun, moon = _elevations(MOON_DOWN)
    assert sun > 20 and moon < MOON_MARCH_MIN_ELEVATION_DEG


@pytest.mark.full  # two and three renders each: the quick tier keeps the cheaper checks of the lights marched
@pytest.mark.parametrize("time", [DAY_WITH_MOON, TWILIGHT])
def test_sun_and_moon_is_the_sum_of_the_sunlit_and_moonlit_renders(scene, time):
    both = _render(scene, time, "sun+moon", white_level="auto")
    sun = _render(scene, time, "sun", white_level="auto")
    moon = _render(scene, time, "moon", white_level="auto")
    assert both.attrs["light"] == "sun+moon" and both.attrs["lights"] == "sun moon"
    # the moonlit render adds the night sky always; the sunlit one, and the sum, once where the sun is down
    moonlight = np.nan_to_num(moon.radiance.values) - _night_sky(moon)
    expected = np.nan_to_num(sun.radiance.values) + moonlight
    assert np.allclose(np.nan_to_num(both.radiance.values), expected, rtol=1e-6, atol=0)
    for plane in ("radiance_clear", "radiance_cloud", "radiance_surface"):
        assert np.allclose(np.nan_to_num(both[plane].values),
                           np.nan_to_num(sun[plane].values) + np.nan_to_num(moon[plane].values), rtol=1e-6, atol=0)
    assert ("radiance_night_sky" in both) == (time == TWILIGHT)
    if time == TWILIGHT:
        assert np.array_equal(_night_sky(both), _night_sky(sun))
    # the sun's angles and transmittances are the sun's; the moon's are kept apart
    for key in ("sun_zenith_deg", "sun_azimuth_deg"):
        assert both.attrs[key] == sun.attrs[key]
    assert np.array_equal(both.attrs["direct_transmittance"], sun.attrs["direct_transmittance"])
    assert np.array_equal(both.attrs["moon_direct_transmittance"], moon.attrs["direct_transmittance"])
    assert both.attrs["moon_zenith_deg"] == pytest.approx(moon.attrs["moon_zenith_deg"])
    assert both.attrs["march_samples"] == sun.attrs["march_samples"] + moon.attrs["march_samples"]


@pytest.mark.full
def test_moonlight_is_a_millionth_of_the_sunlit_day(scene):
    both = _render(scene, DAY_WITH_MOON, "sun+moon", white_level="auto")
    sun = _render(scene, DAY_WITH_MOON, "sun", white_level="auto")
    extra = np.nanmedian(both.radiance.values[1] / sun.radiance.values[1]) - 1.0
    # a 21 % crescent's irradiance is a few percent of the full moon's 2.4e-6 of the sun's (Miller and Turner 2009)
    assert 0 < extra < full_moon_ratio()


@pytest.mark.full  # renders by both lights: the quick tier renders them in the series test
def test_below_astronomical_twilight_only_the_moon_is_marched(scene):
    both = _render(scene, NIGHT, "sun+moon")
    moon = _render(scene, NIGHT, "moon")
    assert both.attrs["lights"] == "moon"
    assert both.attrs["march_samples"] == moon.attrs["march_samples"]
    # the night sky's solar-relative units take the earth-sun distance of the image's sun: here the sun's (NREL SPA),
    # in the moonlit render the moon's (DE421), 1.4e-5 apart: 2.8e-5 in L'
    assert np.allclose(np.nan_to_num(both.radiance.values), np.nan_to_num(moon.radiance.values), rtol=1e-4, atol=0)
    # the default fixed exposure is then the full moon's, as the moonlit render's: the same picture
    assert both.attrs["white_level"] == pytest.approx(moon.attrs["white_level"])
    assert np.abs(both.rgb.values.astype(int) - moon.rgb.values.astype(int)).max() <= 1
    assert both.attrs["night_sky_stars"] == moon.attrs["night_sky_stars"] > 0


@pytest.mark.full  # renders by both lights: the quick tier renders them in the series test
def test_with_the_moon_down_only_the_sun_is_marched(scene):
    both = _render(scene, MOON_DOWN, "sun+moon")
    sun = _render(scene, MOON_DOWN, "sun")
    assert both.attrs["lights"] == "sun"
    assert both.attrs["march_samples"] == sun.attrs["march_samples"]
    assert np.array_equal(both.radiance.values, sun.radiance.values, equal_nan=True)
    assert both.attrs["white_level"] == sun.attrs["white_level"] == pytest.approx(1.5)
    assert np.array_equal(both.rgb.values, sun.rgb.values)
    assert np.array_equal(both.attrs["moon_direct_transmittance"], np.zeros(3))
    assert "radiance_night_sky" not in both


def test_a_moonless_night_marches_the_moon_for_the_clouds_in_front_of_the_stars(scene):
    both = _render(scene, MOONLESS_NIGHT, "sun+moon")
    assert both.attrs["lights"] == "moon"
    assert "radiance_night_sky" in both and both.attrs["night_sky_stars"] > 0
    # the moon 20 deg below the horizon adds nothing: the radiance is the night sky's
    assert np.allclose(np.nan_to_num(both.radiance.values), _night_sky(both), rtol=1e-6, atol=1e-12)


def test_sun_angles_and_unknown_lights_are_refused(scene):
    with pytest.raises(SwimInputError, match="sun_zenith"):
        swim.render(scene, light="sun+moon", sun_zenith=30.0, sun_azimuth=180.0, camera_options={"size": 9})
    with pytest.raises(SwimInputError, match="sun\\+moon"):
        swim.render(scene, light="moon+sun", camera_options={"size": 9})


def test_the_crop_widens_towards_the_one_light_marched_or_every_way(scene):
    from types import SimpleNamespace

    def request(time, light):
        return SimpleNamespace(time=time, light=light, sun_zenith=None, sun_azimuth=None)

    assert crop_light_direction(request(TWILIGHT, "sun+moon"), scene) is None  # both marched: a margin on every side
    sun = sun_position(MOON_DOWN, 40.0, -105.3)
    assert np.allclose(crop_light_direction(request(MOON_DOWN, "sun+moon"), scene), sun.direction_enu)
    moon = moon_position(NIGHT, 40.0, -105.3)
    assert np.allclose(crop_light_direction(request(NIGHT, "sun+moon"), scene), moon.direction_enu)
    assert np.allclose(crop_light_direction(request(NIGHT, "moon"), scene), moon.direction_enu)


def test_progress_counts_both_marches():
    calls = []
    first = progress_of(lambda done, total: calls.append((done, total)), 0, 2)
    second = progress_of(lambda done, total: calls.append((done, total)), 1, 2)
    first(50, 100)
    second(100, 100)
    assert calls == [(50, 200), (200, 200)]
    alone = print
    assert progress_of(alone, 0, 1) is alone and progress_of(None, 1, 2) is None


@pytest.mark.full  # renders by both lights: the quick tier renders them in the series test
def test_progress_of_a_render_by_both_lights_reaches_its_total(scene):
    calls = []
    _render(scene, TWILIGHT, "sun+moon", progress=lambda done, total: calls.append((done, total)))
    done = [d for d, _ in calls]
    assert calls[-1][0] == calls[-1][1] and done == sorted(done)


def test_the_command_line_renders_sun_and_moon(tmp_path):
    out, netcdf = tmp_path / "twilight.png", tmp_path / "twilight.nc"
    result = CliRunner().invoke(app, ["render", "--light", "sun+moon", "--time", TWILIGHT, "--size", "9", "--out",
                                      str(out), "--netcdf", str(netcdf)])
    assert result.exit_code == 0, result.output
    assert out.exists()
    with xr.open_dataset(netcdf) as image:
        assert image.attrs["light"] == "sun+moon" and image.attrs["lights"] == "sun moon"
        assert "radiance_night_sky" in image


def test_one_setting_serves_a_series_from_day_into_a_moonlit_night(scene, tmp_path):
    frames = [MOON_DOWN, DAY_WITH_MOON, TWILIGHT, NIGHT, MOONLESS_NIGHT]
    # the paper's cloud scattering: no 3-D diffuse solution to solve for each frame's lights (a quick test)
    table = swim.render_series(scene, frames, netcdf=str(tmp_path / "{index}.nc"), light="sun+moon",
                               white_level="auto", camera_options={"size": 15},
                               settings=swim.MarchSettings(cloud_scattering="albers2020"))
    lights, night_sky, brightest = [], [], []
    for path in table["netcdf"]:
        with xr.open_dataset(path) as image:
            lights.append(image.attrs["lights"])
            night_sky.append("radiance_night_sky" in image)
            brightest.append(float(np.nanmax(image.radiance.values[1])))
    assert lights == ["sun", "sun moon", "sun moon", "moon", "moon"]
    assert night_sky == [False, False, True, True, True]
    # the brightest pixel falls from day (the sun's disk) through twilight into the night
    assert brightest[1] > brightest[2] > brightest[3] > 0
