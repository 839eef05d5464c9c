"""The night sky in whole renders (swim.pipeline.night_sky through swim.render): a clear dark site's zenith of
V = 21.6-22.0 mag arcsec-2 (Benn & Ellison 1998; Leinert et al. 1998), the bright stars where PyEphem puts them,
clouds that hide them, and day renders left alone."""

from __future__ import annotations

import math

import numpy as np
import pytest

import swim
from swim.diagnostics.ghi import clear_site_scene
from swim.geometry.cameras import AllSkyCamera
from swim.io.default_scene import default_scene
from swim.rt.night_sky import solar_irradiance_channels, v_surface_brightness

#: The sun 30 deg below the horizon at the default scene's site (40 N, 105.3 W).
NIGHT = "2023-12-22T02:21:00Z"


@pytest.fixture
def stars_file(shared_data, monkeypatch):
    monkeypatch.setenv("SWIM_STAR_CATALOGUE", str(shared_data / "stars" / "bsc5.dat"))
    return shared_data / "stars" / "bsc5.dat"


@pytest.fixture(scope="module")
def clear_night(shared_data):
    mp = pytest.MonkeyPatch()
    mp.setenv("SWIM_STAR_CATALOGUE", str(shared_data / "stars" / "bsc5.dat"))
    try:
        scene = clear_site_scene(40.0, -105.3, 1650.0, time=NIGHT)
        yield swim.render(scene, time=NIGHT, camera_options={"size": 95}, white_level="auto")
    finally:
        mp.undo()


def _v_mag(image, rows, cols):
    """V mag arcsec-2 of the median 546 nm radiance of a block of pixels."""
    l_prime = float(np.median(image["radiance"].values[1, rows, cols]))
    e_toa = solar_irradiance_channels()[1] / image.attrs["earth_sun_distance_au"] ** 2
    return v_surface_brightness(l_prime * e_toa / (4 * math.pi))


def test_clear_dark_site_zenith_brightness(clear_night):
    image = clear_night
    assert image.attrs["sun_zenith_deg"] == pytest.approx(120.0, abs=0.5)
    c = 47
    v = _v_mag(image, slice(c - 3, c + 4), slice(c - 3, c + 4))
    assert 21.6 <= v <= 22.0
    # the sun's twilight is gone 30 deg below the horizon: the night sky is nearly all of it
    night = image["radiance_night_sky"].values[1, c, c]
    assert night / image["radiance"].values[1, c, c] > 0.95
    # the horizon brighter than the zenith (van Rhijn): the ring at 80 deg zenith angle
    zen = image["view_zenith"].values
    ring = (zen > 78) & (zen < 82)
    assert np.median(image["radiance_night_sky"].values[1][ring]) > 1.3 * np.median(
        image["radiance_night_sky"].values[1][zen < 10])
    for key in ("night_sky_stars", "night_sky_components", "night_sky_airglow", "night_sky_vertical_optical_depth"):
        assert key in image.attrs
    assert image.attrs["night_sky_stars"] > 3000  # about half the 8404 stars to V = 6.5 are up


def test_bright_stars_stand_where_pyephem_puts_them(clear_night):
    ephem = pytest.importorskip("ephem")
    image = clear_night
    camera = AllSkyCamera(size=95)
    obs = ephem.Observer()
    obs.lat, obs.lon, obs.elevation, obs.date = "40.0", "-105.3", 1652.0, NIGHT.replace("T", " ").rstrip("Z")
    night = image["radiance_night_sky"].values[1]
    seen = 0
    for name in ("Vega", "Capella", "Deneb", "Altair", "Aldebaran"):
        star = ephem.star(name)
        star.compute(obs)
        alt, az = float(star.alt), float(star.az)
        if math.degrees(alt) < 15:
            continue
        row, col = camera.pixel_of_direction(np.array([math.cos(alt) * math.sin(az), math.cos(alt) * math.cos(az),
                                                       math.sin(alt)]))
        r, c = int(round(float(row))), int(round(float(col)))
        block = night[r - 3:r + 4, c - 3:c + 4]
        assert night[r, c] == block.max(), name  # the star's pixel is its neighbourhood's brightest
        assert night[r, c] > 2 * np.median(block), name
        seen += 1
    assert seen >= 3


@pytest.mark.full
def test_clouds_hide_the_stars(stars_file):
    image = swim.render(default_scene(), time=NIGHT, camera_options={"size": 127}, white_level="auto")
    night = image["radiance_night_sky"].values[1]
    tau = image["tau_hydrometeor"].values
    valid = np.isfinite(image["view_zenith"].values) & (image["view_zenith"].values < 80)
    cloudy, clear = valid & (tau > 10), valid & (tau < 0.01)
    assert cloudy.sum() > 100 and clear.sum() > 100
    # bright stars shine through the clear sky; behind thick cloud only its dim diffuse glow is left
    assert night[clear].max() > 5 * np.median(night[clear])
    assert night[cloudy].max() < 1.0 * np.median(night[clear])


def test_a_day_render_has_no_night_sky(stars_file):
    scene = clear_site_scene(40.0, -105.3, 1650.0, time="2023-06-21T18:00:00Z")
    image = swim.render(scene, time="2023-06-21T18:00:00Z", camera_options={"size": 31})
    assert "radiance_night_sky" not in image
    assert not any(k.startswith("night_sky") for k in image.attrs)


def test_star_pixel_solid_angles_match_the_cameras_exact_ones():
    # the stars' E / Omega uses the cross product of neighbouring directions; the cameras' Stokes-exact solid angles
    # (swim.geometry.cameras) agree to 0.1-0.5 % wherever a star can fall, 2 % on a small perspective image's border
    # (one-sided differences)
    from swim.geometry.cameras import make_camera
    from swim.pipeline.night_sky import pixel_solid_angle_at

    for camera, tol in ((AllSkyCamera(size=63), 1e-3), (make_camera("panorama", width=64, height=32), 5e-3),
                        (make_camera("perspective", width=48, height=36, fov_deg=60, view_azimuth_deg=30,
                                     view_zenith_deg=60), 2e-2)):
        exact = camera.pixel_solid_angles()
        dirs = camera.cached_directions()[0]
        rows, cols = np.nonzero(np.isfinite(dirs[..., 0]) & (np.degrees(np.arccos(np.clip(dirs[..., 2], -1, 1))) < 88))
        estimate = pixel_solid_angle_at(dirs, rows, cols)
        assert estimate == pytest.approx(exact[rows, cols], rel=tol), camera.kind
