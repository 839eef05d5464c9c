"""FisheyeCameraModel: projections, orientation, solid angles, masks, TOML files and the sun-based fit."""

import math

import numpy as np
import pytest
from PIL import Image

from swim.errors import SwimInputError
from swim.frames import azimuth_zenith_from_enu, enu_from_azimuth_zenith
from swim.geometry.cameras import AllSkyCamera
from swim.geometry.fisheye import FisheyeCameraModel, detect_sun, fit_orientation_from_sun

PARAMETRIC = ["equidistant", "equisolid", "stereographic", "orthographic"]
POLY = (1.0, 0.05, -0.08)  # shape of a polynomial r(theta), increasing on [0, pi/2]


def analytic_zenith(projection, r, f):
    """Independent inverse projections theta(r) [deg] for the parametric models."""
    return np.degrees({
        "equidistant": lambda: r / f,
        "equisolid": lambda: 2 * np.arcsin(r / (2 * f)),
        "stereographic": lambda: 2 * np.arctan(r / (2 * f)),
        "orthographic": lambda: np.arcsin(r / f),
    }[projection]())


def make(projection, **kw):
    kw.setdefault("width", 101)
    kw.setdefault("height", 101)
    radius = kw.pop("radius", 48.0)
    coeffs = POLY if projection == "polynomial" else ()
    return FisheyeCameraModel.from_radius(kw.pop("width"), kw.pop("height"), radius, projection=projection,
                                          coefficients=coeffs, **kw)


def random_sky(n, seed=1, max_zenith=89.0):
    rng = np.random.default_rng(seed)
    az = rng.uniform(0, 360, n)
    zen = np.degrees(np.arccos(rng.uniform(np.cos(np.radians(max_zenith)), 1, n)))
    return enu_from_azimuth_zenith(az, zen)


def test_centred_equidistant_model_equals_the_allsky_camera():
    for size in (64, 101):
        model = FisheyeCameraModel.from_radius(size, size, size / 2)
        cam = AllSkyCamera(size=size)
        d1, v1 = model.directions()
        d2, v2 = cam.directions()
        assert np.array_equal(v1, v2)
        np.testing.assert_allclose(d1[v1], d2[v2], atol=1e-12)
        np.testing.assert_allclose(model.pixel_solid_angles(), cam.pixel_solid_angles(), atol=1e-14)


@pytest.mark.parametrize("projection", PARAMETRIC + ["polynomial"])
def test_centre_pixel_looks_at_the_zenith(projection):
    model = make(projection, azimuth_up_deg=77.0, mirror=True)
    dirs, valid = model.directions()
    assert valid[50, 50]
    np.testing.assert_allclose(dirs[50, 50], [0, 0, 1], atol=1e-12)
    row, col = model.pixel_of_direction([0.0, 0.0, 1.0])
    assert (row, col) == pytest.approx((50.0, 50.0), abs=1e-12)


@pytest.mark.parametrize("projection", PARAMETRIC)
def test_pixel_at_radius_r_has_the_projection_zenith(projection):
    # integer centre: the pixel k columns left of the centre is at radius k and (north up, east left) looks east
    model = make(projection, width=121, height=101, cx=60.0, cy=50.0, radius=45.0)
    f = model.focal_length_px
    dirs, valid = model.directions()
    left = dirs[50, :60][::-1]  # columns 59 .. 0: radius k = 1 .. 60
    ok = valid[50, :60][::-1]
    az, zen = azimuth_zenith_from_enu(np.where(ok[:, None], left, [0.0, 0.0, 1.0]))
    k = np.arange(1, 61, dtype=float)
    with np.errstate(invalid="ignore"):
        expected = analytic_zenith(projection, k, f)
    assert ok.sum() >= 40
    np.testing.assert_allclose(zen[ok], expected[ok], atol=1e-9)
    np.testing.assert_allclose(az[ok], 90.0, atol=1e-9)
    # and the 90-deg circle has the requested radius 45 px
    assert model.radius_of_angle(90.0) == pytest.approx(45.0, rel=1e-12)


def test_polynomial_radius():
    model = FisheyeCameraModel(201, 151, projection="polynomial", coefficients=(60.0, 2.0, -4.0))
    theta = np.radians([10.0, 45.0, 80.0])
    r = 60 * theta + 2 * theta**2 - 4 * theta**3
    np.testing.assert_allclose(model.radius_of_angle(np.degrees(theta)), r, rtol=1e-14)
    np.testing.assert_allclose(model.angle_of_radius(r), np.degrees(theta), atol=1e-10)
    # pixel straight above the centre (azimuth_up 0: north) at radius r(45 deg)
    row, col = model.pixel_of_direction(enu_from_azimuth_zenith(0.0, 45.0))
    assert row == pytest.approx(75.0 - r[1], abs=1e-9) and col == pytest.approx(100.0, abs=1e-12)


@pytest.mark.parametrize("projection", PARAMETRIC + ["polynomial"])
@pytest.mark.parametrize("mirror", [False, True])
def test_round_trip_direction_pixel_direction(projection, mirror):
    model = make(projection, width=140, height=110, cx=71.3, cy=52.6, azimuth_up_deg=23.0, mirror=mirror,
                 tilt_deg=4.0, tilt_azimuth_deg=200.0, max_zenith_deg=90.0 if projection == "orthographic" else 95.0)
    dirs = random_sky(500)
    row, col = model.pixel_of_direction(dirs)
    ok = np.isfinite(row)
    assert ok.mean() > 0.9
    # back through the pixel grid: directions() at integer pixels, so compare with an independent evaluation
    # by building a model whose centre shifts the continuous coordinate onto a pixel centre
    for i in np.flatnonzero(ok)[:40]:
        shifted = make(projection, width=140, height=110, cx=71.3 - col[i] + 70, cy=52.6 - row[i] + 55,
                       azimuth_up_deg=23.0, mirror=mirror, tilt_deg=4.0, tilt_azimuth_deg=200.0,
                       max_zenith_deg=90.0 if projection == "orthographic" else 95.0)
        d, v = shifted.directions()
        assert v[55, 70]
        np.testing.assert_allclose(d[55, 70], dirs[i], atol=1e-9)
    # and pixel -> direction -> pixel on the whole grid
    d, v = model.directions()
    r2, c2 = model.pixel_of_direction(d)
    rows, cols = np.mgrid[0:110, 0:140]
    np.testing.assert_allclose(r2[v], rows[v], atol=1e-8)
    np.testing.assert_allclose(c2[v], cols[v], atol=1e-8)


@pytest.mark.parametrize("projection", PARAMETRIC + ["polynomial"])
def test_solid_angles_sum_to_the_hemisphere(projection):
    model = make(projection, width=120, height=104, cx=58.7, cy=51.2, azimuth_up_deg=40.0, mirror=True)
    omega = model.pixel_solid_angles()
    assert omega.shape == (104, 120) and np.all(omega >= 0)
    assert omega.sum() == pytest.approx(2 * np.pi, rel=1e-10)


def test_solid_angles_of_a_partial_cap_and_a_cut_circle():
    model = make("equisolid", max_zenith_deg=60.0)
    assert model.pixel_solid_angles().sum() == pytest.approx(2 * np.pi * (1 - np.cos(np.radians(60))), rel=1e-10)
    # image circle larger than the sensor: only the part on the sensor (a full-frame fisheye)
    big = make("equidistant", width=61, height=41, radius=40.0)
    omega = big.pixel_solid_angles()
    # brute force: midpoint sub-sampling of the density dOmega/dA = sin(theta) / (r dr/dtheta) = sin(k r)/(r) k
    k = (np.pi / 2) / 40.0
    n = 8
    sub = (np.arange(n) + 0.5) / n - 0.5
    rows, cols = np.mgrid[0:41, 0:61]
    total = 0.0
    for a in sub:
        for b in sub:
            r = np.hypot(cols + b - 30.0, rows + a - 20.0)
            total += np.sum(np.where(r <= 40.0, k * np.sinc(k * r / np.pi) * k, 0.0)) / n**2
    assert omega.sum() == pytest.approx(total, rel=1e-4)
    assert omega.sum() < 2 * np.pi * 0.9


@pytest.mark.parametrize("projection", PARAMETRIC + ["polynomial"])
def test_solid_angle_of_a_pixel_matches_the_jacobian(projection):
    model = make(projection, radius=48.0)
    omega = model.pixel_solid_angles()
    # near the centre the density is about 1 / (dr/dtheta at 0)^2 (a polynomial's k2 adds a term ~ 3 k2 theta / k1)
    k1 = float(model.radius_of_angle(1e-6) / np.radians(1e-6))
    assert omega[50, 50] == pytest.approx(1.0 / k1**2, rel=3e-3)

    # brute force: midpoint sub-sampling of the Jacobian density sin(theta) / (r dr/dtheta)
    def density(r):
        theta = np.radians(model.angle_of_radius(r))
        h = 1e-6
        drdt = (model.radius_of_angle(np.degrees(theta + h)) - model.radius_of_angle(np.degrees(theta - h))) / (2 * h)
        return np.sin(theta) / (r * drdt)

    n = 40
    sub = (np.arange(n) + 0.5) / n - 0.5
    for i, j, tol in [(50, 20, 1e-5), (30, 62, 1e-5), (80, 75, 1e-5), (50, 50, 2e-4)]:
        u, v = np.meshgrid(j - 50.0 + sub, i - 50.0 + sub)
        assert omega[i, j] == pytest.approx(density(np.hypot(u, v)).mean(), rel=tol), (i, j)


def test_rotation_moves_the_sun_as_predicted():
    base = make("equisolid", width=151, height=151, radius=70.0)
    sun = enu_from_azimuth_zenith(130.0, 40.0)
    r0, c0 = base.pixel_of_direction(sun)
    for delta in (15.0, 90.0, 250.0):
        rot = make("equisolid", width=151, height=151, radius=70.0, azimuth_up_deg=delta)
        r1, c1 = rot.pixel_of_direction(sun)
        # increasing azimuth_up by delta turns the sky clockwise in the image by delta (u right, v up)
        u0, v0 = c0 - 75.0, 75.0 - r0
        a = np.radians(delta)
        u1, v1 = u0 * np.cos(a) + v0 * np.sin(a), -u0 * np.sin(a) + v0 * np.cos(a)
        assert (c1 - 75.0, 75.0 - r1) == pytest.approx((u1, v1), abs=1e-9)
    # azimuth_up = sun azimuth puts the sun straight above the centre
    up = make("equisolid", width=151, height=151, radius=70.0, azimuth_up_deg=130.0)
    r2, c2 = up.pixel_of_direction(sun)
    assert c2 == pytest.approx(75.0, abs=1e-9) and r2 < 75.0
    # handedness: north up, east left (from below) or right (mirrored)
    east = enu_from_azimuth_zenith(90.0, 60.0)
    assert base.pixel_of_direction(east)[1] < 75.0
    assert make("equisolid", width=151, height=151, radius=70.0, mirror=True).pixel_of_direction(east)[1] > 75.0


def test_tilt_puts_the_optical_axis_at_the_centre():
    model = make("equidistant", tilt_deg=10.0, tilt_azimuth_deg=300.0, max_zenith_deg=100.0)
    axis = enu_from_azimuth_zenith(300.0, 10.0)
    np.testing.assert_allclose(model.optical_axis, axis, atol=1e-12)
    dirs, _ = model.directions()
    np.testing.assert_allclose(dirs[50, 50], axis, atol=1e-12)
    # directions 90 deg from the axis are on the 90-deg circle
    row, col = model.pixel_of_direction(enu_from_azimuth_zenith(120.0, 80.0))  # opposite side, 90 deg away
    assert math.hypot(row - 50.0, col - 50.0) == pytest.approx(model.radius_of_angle(90.0), rel=1e-9)


def test_horizon_profile_and_mask_image(tmp_path):
    model = make("equidistant", horizon_azimuth_deg=(0.0, 180.0), horizon_elevation_deg=(20.0, 0.0))
    dirs, valid = model.directions()
    _, circle = model.directions(apply_masks=False)
    az, zen = azimuth_zenith_from_enu(np.where(circle[..., None], dirs, [0, 0, 1]))
    el = 90 - zen
    obstacle = np.interp(az, [0, 180, 360], [20, 0, 20])
    expected = circle & (el > obstacle)
    assert np.array_equal(valid, expected)
    assert (circle & ~valid).sum() > 100
    # mask image: left half dark
    mask = np.full((101, 101), 255, np.uint8)
    mask[:, :40] = 0
    Image.fromarray(mask).save(tmp_path / "mask.png")
    masked = make("equidistant", mask_path=str(tmp_path / "mask.png"))
    _, v = masked.directions()
    assert not v[:, :40].any() and np.array_equal(v[:, 40:], circle[:, 40:])
    bad = make("equidistant", mask_path=str(tmp_path / "missing.png"))
    with pytest.raises(SwimInputError, match="mask_path"):
        bad.directions()


def test_toml_round_trip(tmp_path):
    Image.fromarray(np.full((90, 120), 255, np.uint8)).save(tmp_path / "mask.png")
    for model in [
        make("equisolid", width=120, height=90, cx=59.25, cy=44.5, azimuth_up_deg=12.5, mirror=True, tilt_deg=2.0,
             tilt_azimuth_deg=45.0, horizon_azimuth_deg=(0, 90, 180, 270), horizon_elevation_deg=(3, 8, 5, 2)),
        make("polynomial", width=120, height=90, max_zenith_deg=85.0),
        make("stereographic", width=120, height=90, mask_path=str(tmp_path / "mask.png")),
    ]:
        path = tmp_path / "cam.toml"
        text = model.to_toml(path)
        assert path.read_text() == text
        assert FisheyeCameraModel.from_toml(path) == model
        assert FisheyeCameraModel.from_toml(text) == model


def test_toml_radius_form_and_relative_mask(tmp_path):
    Image.fromarray(np.full((80, 100), 255, np.uint8)).save(tmp_path / "m.png")
    (tmp_path / "cam.toml").write_text(
        '[camera]\nwidth = 100\nheight = 80\nprojection = "equisolid"\nradius_px = 38.0\n'
        'radius_zenith_deg = 90.0\n[horizon]\nmask_image = "m.png"\n')
    model = FisheyeCameraModel.from_toml(tmp_path / "cam.toml")
    assert model.radius_of_angle(90.0) == pytest.approx(38.0, rel=1e-12)
    assert model.focal_length_px == pytest.approx(38.0 / (2 * np.sin(np.pi / 4)), rel=1e-12)
    assert model.mask_path == str(tmp_path / "m.png")
    assert (model.cx, model.cy) == (49.5, 39.5)


@pytest.mark.parametrize("text, match", [
    ('[camera]\nwidth = 10\nheight = 10\nfocal_length_px = 3.0\nfoo = 1\n', "unknown key"),
    ('[camera]\nwidth = 10\nheight = 10\nfocal_length_px = 3.0\nradius_px = 3.0\n', "not both"),
    ('[camera]\nwidth = 10\nheight = 10\nfocal_length_px = 3.0\nprojection = "fish"\n', "projection"),
    ('[camera]\nwidth = 10\nheight = 10\n', "focal_length_px"),
    ('[camera]\nwidth = 10\nheight = 10\nfocal_length_px = -3.0\n', "focal_length_px"),
    ('[camera]\nwidth = 0\nheight = 10\nfocal_length_px = 3.0\n', "width"),
    ('[camera]\nwidth = 10\nheight = 10\nprojection = "polynomial"\ncoefficients = [10.0, 0.0, -10.0]\n',
     "increase"),
    ('[camera]\nwidth = 10\nheight = 10\nfocal_length_px = 3.0\nprojection = "orthographic"\n'
     'max_zenith_deg = 100.0\n', "max_zenith_deg"),
    ('[camera]\nwidth = 10\nheight = 10\nfocal_length_px = 3.0\ntilt_deg = 95.0\n', "tilt_deg"),
    ('[camera\nwidth = 10\n', "TOML"),
    ('[lens]\nwidth = 10\n', "camera"),
])
def test_toml_errors(text, match):
    with pytest.raises(SwimInputError, match=match):
        FisheyeCameraModel.from_toml(text)


def test_missing_toml_file(tmp_path):
    with pytest.raises(SwimInputError, match="cannot be read"):
        FisheyeCameraModel.from_toml(tmp_path / "nope.toml")


def test_detect_sun_centroid_of_the_largest_saturated_blob():
    img = np.full((80, 100, 3), 90, np.uint8)
    rows, cols = np.mgrid[0:80, 0:100]
    disk = (rows - 30.3) ** 2 + (cols - 61.7) ** 2 <= 16
    img[disk] = 255
    img[5:7, 5:7] = 255  # small spurious blob
    img[50:60, 10:20, 0] = 255  # saturated red only: not white
    row, col = detect_sun(img)
    assert (row, col) == pytest.approx((rows[disk].mean(), cols[disk].mean()), abs=1e-12)
    with pytest.raises(SwimInputError, match="no saturated"):
        detect_sun(np.zeros((10, 10, 3), np.uint8))


def _truth():
    return make("equisolid", width=161, height=121, radius=58.0, cx=83.4, cy=58.1, azimuth_up_deg=37.5)


def test_fit_orientation_recovers_rotation_and_centre():
    truth = _truth()
    az = np.array([100.0, 150.0, 200.0, 240.0])
    zen = np.array([60.0, 35.0, 30.0, 55.0])
    row, col = truth.pixel_of_direction(enu_from_azimuth_zenith(az, zen))
    guess = make("equisolid", width=161, height=121, radius=58.0)  # centre at the image centre, no rotation
    fit = fit_orientation_from_sun(guess, az, zen, np.stack([row, col], axis=-1), fit_centre=True)
    assert fit.parameters["azimuth_up_deg"] == pytest.approx(37.5, abs=1e-6)
    assert (fit.model.cx, fit.model.cy) == pytest.approx((83.4, 58.1), abs=1e-6)
    assert fit.rms_px < 1e-6
    # rotation only, from a single sun, with a rotation far from the start
    truth2 = make("equisolid", width=161, height=121, radius=58.0, azimuth_up_deg=250.0)
    r2, c2 = truth2.pixel_of_direction(enu_from_azimuth_zenith(az[:1], zen[:1]))
    fit2 = fit_orientation_from_sun(guess, az[:1], zen[:1], [[r2[0], c2[0]]])
    assert fit2.parameters["azimuth_up_deg"] == pytest.approx(250.0, abs=1e-6)


def test_fit_orientation_with_scale_and_from_images():
    truth = _truth()
    az = np.array([95.0, 140.0, 185.0, 230.0, 260.0])
    zen = np.array([65.0, 40.0, 28.0, 45.0, 70.0])
    row, col = truth.pixel_of_direction(enu_from_azimuth_zenith(az, zen))
    rows, cols = np.mgrid[0:121, 0:161]
    images = []
    for r, c in zip(row, col):
        img = np.full((121, 161, 3), 60, np.uint8)
        img[(rows - r) ** 2 + (cols - c) ** 2 <= 6.0] = 255
        images.append(img)
    guess = make("equisolid", width=161, height=121, radius=52.0, cx=80.0, cy=60.0)
    fit = fit_orientation_from_sun(guess, az, zen, images=images, fit_centre=True, fit_scale=True)
    # detected centroids of pixelated disks are within ~0.1 px of the truth
    assert fit.parameters["azimuth_up_deg"] == pytest.approx(37.5, abs=0.3)
    assert (fit.model.cx, fit.model.cy) == pytest.approx((83.4, 58.1), abs=0.3)
    assert fit.model.radius_of_angle(90.0) == pytest.approx(58.0, rel=0.01)
    assert fit.rms_px < 0.3


def test_fit_orientation_needs_enough_suns():
    with pytest.raises(SwimInputError, match="at least"):
        fit_orientation_from_sun(_truth(), [100.0], [40.0], [[10.0, 10.0]], fit_centre=True)
    with pytest.raises(SwimInputError, match="sun_pixels"):
        fit_orientation_from_sun(_truth(), [100.0, 120.0], [40.0, 30.0], [[10.0, 10.0]])


def test_fit_orientation_recovers_tilt_of_a_mirrored_camera():
    truth = FisheyeCameraModel.from_radius(200, 160, 70.0, mirror=True, azimuth_up_deg=123.0, tilt_deg=3.0,
                                           tilt_azimuth_deg=40.0, cx=101.2, cy=78.9)
    az = np.array([80.0, 110.0, 140.0, 170.0, 200.0, 230.0, 260.0])
    zen = np.array([70.0, 50.0, 35.0, 28.0, 33.0, 48.0, 68.0])
    row, col = truth.pixel_of_direction(enu_from_azimuth_zenith(az, zen))
    guess = FisheyeCameraModel.from_radius(200, 160, 70.0, mirror=True)
    fit = fit_orientation_from_sun(guess, az, zen, np.stack([row, col], axis=-1), fit_centre=True, fit_tilt=True)
    p = fit.parameters
    assert (p["azimuth_up_deg"], p["tilt_deg"], p["tilt_azimuth_deg"]) == pytest.approx((123.0, 3.0, 40.0), abs=1e-5)
    assert (p["cx"], p["cy"]) == pytest.approx((101.2, 78.9), abs=1e-5)


def test_detect_sun_passes_over_a_bigger_saturated_cloud_and_says_so(caplog):
    """A ragged saturated cloud edge bigger than the sun's disc (what took a real 2048^2 JPEG's sun 350 px away) is
    not round: the disc is taken and the cloud is logged; with only the cloud the detection fails loudly."""
    import logging

    rows, cols = np.mgrid[0:200, 0:200]
    img = np.full((200, 200, 3), 90, np.uint8)
    disk = (rows - 60.2) ** 2 + (cols - 140.7) ** 2 <= 25
    img[disk] = 255
    rng = np.random.default_rng(1)
    cloud = ((rows - 140) ** 2 / 900 + (cols - 60) ** 2 / 100 <= 1) & (rng.random((200, 200)) < 0.7)
    cloud |= (np.abs(rows - 120) < 2) & (np.abs(cols - 80) < 60)  # a thin saturated rim joined to it
    img[cloud] = 255
    with caplog.at_level(logging.WARNING, logger="swim.geometry.fisheye"):
        row, col = detect_sun(img)
    assert (row, col) == pytest.approx((rows[disk].mean(), cols[disk].mean()), abs=1e-9)
    assert "larger saturated blob" in caplog.text
    img[disk] = 90
    with pytest.raises(SwimInputError, match="not round|can be the sun"):
        detect_sun(img)


def test_detect_sun_takes_the_blob_at_the_sun_s_zenith_angle():
    """Two round saturated blobs (the sun and a reflection): the camera model and the sun's zenith angle pick the
    one at the right distance from the image centre, whichever is larger."""
    model = make("equidistant", width=201, height=201, radius=90.0)
    zen = 40.0
    expected_r = 90.0 * zen / 90.0
    rows, cols = np.mgrid[0:201, 0:201]
    img = np.zeros((201, 201, 3), np.uint8)
    sun = (rows - (model.cy - expected_r)) ** 2 + (cols - model.cx) ** 2 <= 9
    flare = (rows - (model.cy + 60)) ** 2 + (cols - (model.cx + 50)) ** 2 <= 25
    img[sun | flare] = 255
    assert detect_sun(img)[0] == pytest.approx(rows[flare].mean())  # without the model: the larger blob
    row, col = detect_sun(img, model=model, sun_zenith_deg=zen)
    assert (row, col) == pytest.approx((rows[sun].mean(), cols[sun].mean()), abs=1e-9)
    with pytest.raises(SwimInputError, match="from the image centre"):
        detect_sun(img, model=model, sun_zenith_deg=60.0)
