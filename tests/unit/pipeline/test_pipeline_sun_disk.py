"""The sun's disk of :func:`swim.pipeline.render`: its pixels found in a window around the sun must be exactly those
that a search over the whole image finds (every camera kind, suns near the zenith, the horizon, a panorama's seam and
edges, a perspective view's border), and the window must be small where the disk lies inside the field of view."""

import numpy as np
import pytest

from swim import pipeline
from swim.constants import SUN_ANGULAR_RADIUS_RAD
from swim.frames import enu_from_azimuth_zenith
from swim.geometry.cameras import make_camera
from swim.pipeline.sun_disk import _disk_window, sun_disk as _sun_disk


def whole_image_disk(camera, dirs_enu, valid, sun_enu, transmittance, monkeypatch):
    """The disk searched over every pixel (_sun_disk without its window): the reference."""
    with monkeypatch.context() as patch:
        patch.setattr(pipeline.sun_disk, "_disk_window", lambda camera, sun, radius, row, col, ny, nx: ((0, ny), (0,
                                                                                                                  nx)))
        return _sun_disk(camera, dirs_enu, valid, sun_enu, transmittance)


CAMERAS = {
    "allsky-1024": ("allsky", {"size": 1024}),
    "allsky-255": ("allsky", {"size": 255}),
    "allsky-16": ("allsky", {"size": 16}),
    "panorama": ("panorama", {"width": 1024, "height": 512}),
    "panorama-sky": ("panorama", {"width": 720, "height": 90, "elevation_min_deg": 0.0, "elevation_max_deg": 45.0,
                                  "azimuth_start_deg": 100.0}),
    "panorama-part": ("panorama", {"width": 300, "height": 200, "azimuth_start_deg": 80.0, "azimuth_span_deg": 60.0,
                                   "elevation_min_deg": -10.0, "elevation_max_deg": 50.0}),
    "perspective": ("perspective", {"width": 640, "height": 480, "fov_deg": 60.0, "view_azimuth_deg": 120.0,
                                    "view_zenith_deg": 50.0}),
    # a narrow field: the disk ~50 pixels across, its edge sampled at more directions
    "perspective-zoom": ("perspective", {"width": 400, "height": 300, "fov_deg": 4.0, "view_azimuth_deg": 120.0,
                                         "view_zenith_deg": 50.0}),
}
#: Suns (azimuth, zenith) [deg]: inside, at the zenith and the horizon, on a panorama's seam and near its edges.
SUNS = [(136.5, 21.2), (0.0, 0.0), (250.0, 89.9), (10.0, 90.0), (0.05, 60.0), (359.97, 30.0), (100.02, 45.05),
        (80.1, 40.0), (139.9, 89.5), (120.0, 50.0), (149.0, 69.0), (91.0, 26.0), (300.0, 75.0)]


@pytest.mark.parametrize("name", sorted(CAMERAS))
def test_the_disk_in_its_window_is_the_disk_of_the_whole_image(name, monkeypatch):
    kind, options = CAMERAS[name]
    camera = make_camera(kind, **options)
    dirs_enu, valid = camera.cached_directions()
    rng = np.random.default_rng(7)
    suns = SUNS + [(float(a), float(z)) for a, z in zip(rng.uniform(0, 360, 40), rng.uniform(0, 95, 40))]
    found = 0
    for azimuth, zenith in suns:
        sun = np.asarray(enu_from_azimuth_zenith(azimuth, zenith), float)
        pixels, radiance = _sun_disk(camera, dirs_enu, valid, sun, np.array([0.5, 0.4, 0.3]))
        expected, expected_radiance = whole_image_disk(camera, dirs_enu, valid, sun, np.array([0.5, 0.4, 0.3]),
                                                        monkeypatch)
        np.testing.assert_array_equal(pixels, expected, err_msg=f"{name}, sun at {azimuth}, {zenith}")
        np.testing.assert_array_equal(radiance, expected_radiance)
        found += pixels.size > 0
    assert found >= 1  # the suns do fall on these images


@pytest.mark.parametrize("kind, options, sun", [
    ("allsky", {"size": 1024}, (136.5, 21.2)),
    ("allsky", {"size": 1024}, (200.0, 85.0)),
    ("panorama", {"width": 2048, "height": 1024}, (40.0, 60.0)),
    ("perspective", {"width": 640, "height": 480, "fov_deg": 60.0, "view_azimuth_deg": 120.0,
                     "view_zenith_deg": 50.0}, (130.0, 45.0)),
])
def test_the_window_is_a_few_pixels_across_where_the_disk_is_in_view(kind, options, sun):
    camera = make_camera(kind, **options)
    ny, nx = camera.shape
    sun_enu = np.asarray(enu_from_azimuth_zenith(*sun), float)
    row, col = camera.pixel_of_direction(sun_enu[None, :])
    (r0, r1), (c0, c1) = _disk_window(camera, sun_enu, 2 * SUN_ANGULAR_RADIUS_RAD, row[0], col[0], ny, nx)
    assert r0 <= row[0] < r1 and c0 <= col[0] < c1
    assert (r1 - r0) * (c1 - c0) <= 400  # not the whole image


def test_a_disk_that_reaches_outside_the_field_takes_the_whole_image():
    camera = make_camera("allsky", size=255)
    ny, nx = camera.shape
    sun_enu = np.asarray(enu_from_azimuth_zenith(30.0, 89.95), float)  # its edge below the horizon
    row, col = camera.pixel_of_direction(sun_enu[None, :])
    assert _disk_window(camera, sun_enu, SUN_ANGULAR_RADIUS_RAD, row[0], col[0], ny, nx) == ((0, ny), (0, nx))


@pytest.mark.parametrize("options, sun", [
    ({"width": 1024, "height": 64}, (150.0, 30.0)),   # rows 2.8 deg apart, columns 0.35 deg
    ({"width": 720, "height": 256}, (150.0, 12.0)),    # near the zenith the columns close up
    ({"width": 128, "height": 64}, (33.0, 61.0)),     # 2.8 deg pixels
])
def test_a_coarse_panorama_keeps_the_sun_and_its_energy(options, sun):
    """At any pitch the disk covers at least one pixel and delivers 4 pi T: the sum of its radiance times the pixels'
    solid angles (a panorama's pixel: d_azimuth d_elevation cos elevation)."""
    camera = make_camera("panorama", **options)
    dirs, valid = camera.cached_directions()
    pixels, radiance = _sun_disk(camera, dirs, valid, enu_from_azimuth_zenith(*sun), np.array([0.5, 0.4, 0.3]))
    assert pixels.size >= 1
    elevation = np.arcsin(np.clip(dirs.reshape(-1, 3)[pixels, 2], -1, 1))
    d_az = np.radians(camera.azimuth_span_deg) / camera.width
    d_el = np.radians(camera.elevation_max_deg - camera.elevation_min_deg) / camera.height
    energy = radiance[:, None] * (d_az * d_el * np.cos(elevation))[None, :]
    np.testing.assert_allclose(energy.sum(axis=1), 4 * np.pi * np.array([0.5, 0.4, 0.3]), rtol=0.05)
