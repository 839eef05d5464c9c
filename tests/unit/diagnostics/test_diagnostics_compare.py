"""Camera comparison (paper Eq. 37): Pearson r, brightness fit, masks, reprojection and outputs."""

import json

import numpy as np
import pytest
import xarray as xr
from PIL import Image

from swim.errors import SwimInputError
from swim.frames import azimuth_zenith_from_enu
from swim.geometry.cameras import AllSkyCamera
from swim.geometry.fisheye import FisheyeCameraModel
from swim.diagnostics.compare import (
    compare_images,
    difference_rgb8,
    linear_fit,
    linear_to_srgb,
    pearson_r,
    reproject,
    scores_dict,
    srgb_to_linear,
    swim_camera_of,
    write_difference_png,
    write_json,
)

RNG = np.random.default_rng(7)


def eq37(x, y):
    """The paper's Eq. 37, literally."""
    n = x.size
    return (n * np.sum(x * y) - x.sum() * y.sum()) / np.sqrt(
        (n * np.sum(x * x) - x.sum() ** 2) * (n * np.sum(y * y) - y.sum() ** 2))


def test_pearson_r_identical_negative_and_eq37():
    a = RNG.uniform(0, 1, (40, 30))
    b = 0.5 * a + RNG.normal(0, 0.1, a.shape)
    assert pearson_r(a, a) == pytest.approx(1.0, abs=1e-12)
    assert pearson_r(a, 1.0 - a) == pytest.approx(-1.0, abs=1e-12)
    assert pearson_r(a, -3.0 * a + 2.0) == pytest.approx(-1.0, abs=1e-12)
    assert pearson_r(a, b) == pytest.approx(eq37(a.ravel(), b.ravel()), rel=1e-12)
    assert 0.5 < pearson_r(a, b) < 0.99
    # invariant under positive affine maps of either image
    assert pearson_r(3 * a + 1, 0.2 * b - 4) == pytest.approx(pearson_r(a, b), rel=1e-12)


def test_weighted_pearson_equals_replicated_pixels():
    a = RNG.uniform(0, 1, 50)
    b = a**2 + RNG.normal(0, 0.05, 50)
    w = RNG.integers(1, 4, 50)
    rep_a, rep_b = np.repeat(a, w), np.repeat(b, w)
    assert pearson_r(a, b, w) == pytest.approx(eq37(rep_a, rep_b), rel=1e-12)
    assert pearson_r(a, b, w) != pytest.approx(pearson_r(a, b), rel=1e-6)
    # zero weight or NaN drops a pair
    a2, b2 = a.copy(), b.copy()
    a2[0] = np.nan
    w2 = np.ones(50)
    w2[1] = 0
    assert pearson_r(a2, b2, w2) == pytest.approx(eq37(a[2:], b[2:]), rel=1e-12)


def test_pearson_r_degenerate_and_bad_input():
    assert np.isnan(pearson_r([1.0, 1.0, 1.0], [1.0, 2.0, 3.0]))
    assert np.isnan(pearson_r([1.0], [2.0]))
    with pytest.raises(SwimInputError, match="same shape"):
        pearson_r(np.ones(3), np.ones(4))
    with pytest.raises(SwimInputError, match="weights"):
        pearson_r(np.arange(3.0), np.arange(3.0), [1, -1, 1])


def test_linear_fit_recovers_a_known_transform():
    x = RNG.uniform(0, 1, 200)
    w = RNG.uniform(0.1, 2, 200)
    assert linear_fit(x, 0.7 * x + 0.05, w, "gain_offset") == pytest.approx((0.7, 0.05), abs=1e-12)
    assert linear_fit(x, 1.3 * x, w, "gain") == pytest.approx((1.3, 0.0), abs=1e-12)
    assert linear_fit(x, 1.3 * x, w, "none") == (1.0, 0.0)
    with pytest.raises(SwimInputError, match="fit"):
        linear_fit(x, x, w, "quadratic")


def test_srgb_round_trip():
    v = np.linspace(0, 1, 1001)
    np.testing.assert_allclose(linear_to_srgb(srgb_to_linear(v)), v, atol=1e-12)
    assert srgb_to_linear(0.5) == pytest.approx(0.21404114, rel=1e-6)


@pytest.fixture(scope="module")
def camera():
    return FisheyeCameraModel.from_radius(91, 81, 38.0, projection="equisolid", azimuth_up_deg=20.0)


def sky_field(camera, seed=3):
    """A smooth random sky (height, width, 3) in [0.05, 0.95] and the camera's validity."""
    dirs, valid = camera.directions()
    d = np.nan_to_num(dirs)
    rng = np.random.default_rng(seed)
    coef = rng.uniform(-0.3, 0.3, (3, 3))
    img = 0.5 + np.einsum("yxk,ck->yxc", d, coef) + 0.1 * np.sin(5 * d[..., :1])
    return np.clip(img, 0.05, 0.95), valid


def test_identical_and_negative_images(camera):
    img, _ = sky_field(camera)
    res = compare_images(img, img, camera, sun_azimuth_deg=120.0, sun_zenith_deg=40.0)
    np.testing.assert_allclose(res["r"].values, 1.0, atol=1e-12)
    assert float(res["r_mean"]) == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(res["rmse"].values, 0.0, atol=1e-15)
    neg = compare_images(img, 1.0 - img, camera, sun_azimuth_deg=120.0, sun_zenith_deg=40.0)
    np.testing.assert_allclose(neg["r"].values, -1.0, atol=1e-12)
    assert float(neg["r_mean"]) == pytest.approx(-1.0, abs=1e-12)


def test_r_mean_is_the_mean_of_the_channel_correlations(camera):
    img, _ = sky_field(camera)
    obs = img + RNG.normal(0, [0.02, 0.05, 0.1], img.shape)
    res = compare_images(img, obs, camera, sun_exclusion_deg=0.0, weighting="pixel")
    mask = res["mask"].values
    r = [eq37(img[..., c][mask], obs[..., c][mask]) for c in range(3)]
    np.testing.assert_allclose(res["r"].values, r, rtol=1e-10)
    assert float(res["r_mean"]) == pytest.approx(np.mean(r), rel=1e-12)
    assert r[0] > r[1] > r[2]


@pytest.mark.parametrize("fit", ["gain", "gain_offset"])
def test_brightness_fit_recovers_a_linear_transform(camera, fit):
    img, _ = sky_field(camera)
    gain = np.array([0.6, 0.75, 0.9])
    offset = np.array([0.05, 0.02, 0.0]) if fit == "gain_offset" else np.zeros(3)
    obs = img * gain + offset
    res = compare_images(img, obs, camera, sun_azimuth_deg=200.0, sun_zenith_deg=30.0, fit=fit)
    np.testing.assert_allclose(res["gain"].values, gain, rtol=1e-10)
    np.testing.assert_allclose(res["offset"].values, offset, atol=1e-10)
    np.testing.assert_allclose(res["rmse"].values, 0.0, atol=1e-12)
    np.testing.assert_allclose(res["bias"].values, 0.0, atol=1e-12)
    assert np.all(res["rmse_raw"].values > 0.01)
    assert np.nanmax(np.abs(res["difference"].values)) < 1e-10
    # no fit: RMSE is that of the raw difference, and r is unaffected
    raw = compare_images(img, obs, camera, sun_azimuth_deg=200.0, sun_zenith_deg=30.0, fit="none")
    np.testing.assert_allclose(raw["rmse"].values, res["rmse_raw"].values, rtol=1e-12)
    np.testing.assert_allclose(raw["r"].values, res["r"].values, rtol=1e-12)


def test_sun_exclusion_removes_exactly_the_pixels_within_the_radius():
    cam = FisheyeCameraModel.from_radius(201, 201, 100.0, azimuth_up_deg=10.0)
    img = np.full((201, 201, 3), 0.5)
    img[..., 0] += np.linspace(0, 0.1, 201)  # not constant
    sun_az, sun_zen, radius = 150.0, 35.0, 5.0
    base = compare_images(img, img, cam, sun_exclusion_deg=0.0)["mask"].values
    masked = compare_images(img, img, cam, sun_azimuth_deg=sun_az, sun_zenith_deg=sun_zen,
                            sun_exclusion_deg=radius)["mask"].values
    excluded = base & ~masked
    # independently, pixel by pixel: the spherical law of cosines on the camera's directions
    dirs, valid = cam.directions()
    az, zen = azimuth_zenith_from_enu(dirs)
    cos = (np.cos(np.radians(zen)) * np.cos(np.radians(sun_zen)) + np.sin(np.radians(zen))
           * np.sin(np.radians(sun_zen)) * np.cos(np.radians(az - sun_az)))
    expected = valid & (np.degrees(np.arccos(np.clip(cos, -1, 1))) <= radius)
    assert np.array_equal(excluded, expected)
    # and the excluded solid angle is the spherical cap 2 pi (1 - cos 5 deg) to pixelisation accuracy
    omega = cam.pixel_solid_angles()
    cap = 2 * np.pi * (1 - np.cos(np.radians(radius)))
    assert omega[excluded].sum() == pytest.approx(cap, rel=0.03)
    assert 75 < excluded.sum() < 140


def test_min_elevation_and_masks(camera):
    img, valid = sky_field(camera)
    res = compare_images(img, img, camera, sun_exclusion_deg=0.0, min_elevation_deg=30.0)
    dirs, _ = camera.directions()
    _, zen = azimuth_zenith_from_enu(np.where(valid[..., None], dirs, [0, 0, 1]))
    assert np.array_equal(res["mask"].values, valid & (90 - zen >= 30.0))
    assert int(res["n_pixels"]) == int((valid & (90 - zen >= 30.0)).sum())
    omega = camera.pixel_solid_angles()
    assert float(res["solid_angle_sr"]) == pytest.approx(omega[res["mask"].values].sum(), rel=1e-12)
    # NaN in either image drops the pixel
    obs = img.copy()
    obs[40, 45, 1] = np.nan
    assert not compare_images(img, obs, camera, sun_exclusion_deg=0.0)["mask"].values[40, 45]


def test_uint8_observations_are_linearised(camera):
    img, _ = sky_field(camera)
    obs8 = np.rint(linear_to_srgb(img) * 255).astype(np.uint8)
    res = compare_images(img, obs8, camera, sun_exclusion_deg=0.0, fit="gain_offset")
    np.testing.assert_allclose(res["gain"].values, 1.0, atol=0.01)
    assert np.all(res["r"].values > 0.999)
    enc = compare_images(linear_to_srgb(img), obs8, camera, sun_exclusion_deg=0.0, quantity="srgb")
    assert np.all(enc["rmse"].values < 0.5 / 255 * 1.01)


def test_bad_options(camera):
    img, _ = sky_field(camera)
    with pytest.raises(SwimInputError, match="quantity"):
        compare_images(img, img, camera, quantity="luminance", sun_exclusion_deg=0)
    with pytest.raises(SwimInputError, match="fit"):
        compare_images(img, img, camera, fit="affine", sun_exclusion_deg=0)
    with pytest.raises(SwimInputError, match="weighting"):
        compare_images(img, img, camera, weighting="area", sun_exclusion_deg=0)
    with pytest.raises(SwimInputError, match="sun_exclusion_deg"):
        compare_images(img, img, camera, sun_exclusion_deg=-1)
    with pytest.raises(SwimInputError, match="min_elevation_deg"):
        compare_images(img, img, camera, min_elevation_deg=95, sun_exclusion_deg=0)
    with pytest.raises(SwimInputError, match="sun_azimuth_deg"):
        compare_images(img, img, camera)
    with pytest.raises(SwimInputError, match="shape"):
        compare_images(img[:-1], img, camera, sun_exclusion_deg=0)
    with pytest.raises(SwimInputError, match="observed"):
        compare_images(img, img[:, :-1], camera, sun_exclusion_deg=0)


# ------------------------------------------------------------------ reprojection of swim images
def field(d):
    """Smooth analytic fields of a direction (..., 3): three channels."""
    return np.stack([1 + 0.5 * d[..., 0] + 0.3 * d[..., 1] + 0.2 * d[..., 2],
                     2 - 0.4 * d[..., 0] + 0.1 * d[..., 2] ** 2,
                     0.5 + 0.2 * d[..., 1] * d[..., 2]], axis=0)


def fake_render(size=201):
    """A dataset shaped like swim.render output of an all-sky camera, with analytic radiance."""
    cam = AllSkyCamera(size=size)
    dirs, valid = cam.directions()
    rad = np.where(valid, field(np.nan_to_num(dirs)), np.nan)
    az, zen = azimuth_zenith_from_enu(np.where(valid[..., None], dirs, [0, 0, 1]))
    lin = np.clip(np.moveaxis(rad, 0, -1) / 3.0, 0, 1)
    rgb = np.rint(linear_to_srgb(np.nan_to_num(lin)) * 255).astype(np.uint8)
    attrs = {"sun_azimuth_deg": 135.0, "sun_zenith_deg": 30.0, "camera": "allsky"}
    attrs.update({f"camera_{k}": v for k, v in cam.to_attrs().items()})
    return xr.Dataset(
        {"radiance": (("wavelength", "y", "x"), rad.astype(np.float32)),
         "rgb": (("y", "x", "channel"), rgb),
         "view_azimuth": (("y", "x"), np.where(valid, az, np.nan).astype(np.float32)),
         "view_zenith": (("y", "x"), np.where(valid, zen, np.nan).astype(np.float32))},
        coords={"wavelength": [615.0, 546.0, 450.0], "channel": ["R", "G", "B"]}, attrs=attrs)


def test_swim_camera_of_reads_both_attribute_prefixes():
    ds = fake_render(51)
    assert swim_camera_of(ds) == AllSkyCamera(size=51)
    plain = ds.copy()
    plain.attrs = {"camera_kind": "allsky", "camera_size": 51, "camera_max_zenith_deg": 90.0}
    assert swim_camera_of(plain) == AllSkyCamera(size=51)
    bad = ds.copy()
    bad.attrs = dict(ds.attrs, camera_camera_max_zenith_deg=80.0)
    with pytest.raises(SwimInputError, match="disagree"):
        swim_camera_of(bad)


@pytest.mark.parametrize("by_attrs", [True, False])
def test_reproject_samples_the_simulation_at_the_camera_directions(by_attrs):
    sim = fake_render()
    if not by_attrs:
        sim.attrs = {k: v for k, v in sim.attrs.items() if not k.startswith("camera")}
    cam = FisheyeCameraModel.from_radius(121, 101, 45.0, projection="equisolid", azimuth_up_deg=70.0, mirror=True,
                                         cx=61.3, cy=49.8, max_zenith_deg=85.0)
    out = reproject(sim, cam)
    dirs, valid = cam.directions()
    assert out["radiance"].shape == (3, 101, 121)
    assert np.array_equal(out["valid"].values, valid)
    expected = field(np.nan_to_num(dirs))
    err = np.abs(out["radiance"].values - expected)[:, valid]
    # bilinear on a 201-px equidistant image (0.9 deg pixels) of a smooth field; float32 storage
    assert err.max() < (2e-3 if by_attrs else 1.5e-2)
    assert np.isnan(out["radiance"].values[:, ~valid]).all()
    np.testing.assert_allclose(out["solid_angle"].values, cam.pixel_solid_angles())
    assert out.attrs["swim_reprojected"] == "fisheye" and out.attrs["sun_azimuth_deg"] == 135.0
    # rgb is decoded to linear before interpolation
    lin = np.clip(np.moveaxis(expected, 0, -1) / 3.0, 0, 1)
    assert np.abs(out["rgb_linear"].values[valid] - lin[valid]).max() < 0.02


def test_compare_a_reprojected_simulation_with_a_transformed_copy(tmp_path):
    sim = fake_render()
    cam = FisheyeCameraModel.from_radius(121, 101, 45.0, projection="stereographic", azimuth_up_deg=-30.0)
    lin = reproject(sim, cam)["rgb_linear"].values
    obs = np.rint(linear_to_srgb(np.nan_to_num(0.8 * lin + 0.05)) * 255).astype(np.uint8)
    Image.fromarray(obs).save(tmp_path / "cam.png")
    res = compare_images(sim, tmp_path / "cam.png", cam, fit="gain_offset")
    assert np.all(res["r"].values > 0.995)
    np.testing.assert_allclose(res["gain"].values, 0.8, atol=0.02)
    np.testing.assert_allclose(res["offset"].values, 0.05, atol=0.01)
    assert res.attrs["sun_azimuth_deg"] == 135.0  # from the simulation's attributes
    scores = scores_dict(res)
    path = write_json(scores, tmp_path / "s.json")
    assert json.loads(path.read_text())["r_mean"] == pytest.approx(float(res["r_mean"]))
    png = write_difference_png(res, tmp_path / "d.png")
    with Image.open(png) as im:
        assert im.size == (121, 101) and im.mode == "RGB"


def test_difference_image_colours(camera):
    img, valid = sky_field(camera)
    obs = img.copy()
    obs[:40] -= 0.1  # simulation brighter in the top rows -> red
    obs[40:] += 0.1  # darker below -> blue
    res = compare_images(img, obs, camera, sun_exclusion_deg=0.0)
    rgb = difference_rgb8(res, scale=0.1)
    mask = res["mask"].values
    top = mask.copy()
    top[40:] = False
    bottom = mask.copy()
    bottom[:40] = False
    assert np.all(rgb[top] == [255, 0, 0])
    assert np.all(rgb[bottom] == [0, 0, 255])
    assert np.all(rgb[~mask] == 0)
    with pytest.raises(SwimInputError, match="scale"):
        difference_rgb8(res, scale=0.0)
