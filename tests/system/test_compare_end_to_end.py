"""End to end: render the default scene, fake a camera image from it, and score it with `swim compare`.

The "camera" sees the simulation through a different projection (equisolid), rotation, handedness and
centre, with an unknown brightness (gain/offset on linear RGB) and sRGB encoding; the CLI must recover the
gain and find r close to 1. A small geostationary render checks the reflectance factor's local sun.
"""

import json

import numpy as np
import pytest
import typer
from PIL import Image
from typer.testing import CliRunner

import swim
from swim.cli.compare import compare
from swim.diagnostics.compare import linear_to_srgb, reproject
from swim.diagnostics.satellite import geostationary_view, reflectance_factor
from swim.geometry.fisheye import FisheyeCameraModel

GAIN = np.array([0.85, 0.8, 0.7])
OFFSET = np.array([0.02, 0.03, 0.04])


@pytest.fixture(scope="module")
def scene():
    return swim.default_scene()


@pytest.fixture(scope="module")
def simulated(scene, tmp_path_factory):
    image = swim.render(scene, camera="allsky", camera_options={"size": 129},
                        settings=swim.MarchSettings(cloud_scattering="albers2020"))  # the comparison is tested
    path = tmp_path_factory.mktemp("sim") / "sim.nc"
    swim.write_netcdf(image, path)
    return image, path


def cli():
    app = typer.Typer()
    app.command()(compare)
    return app


def test_cli_compare_recovers_gain_and_high_correlation(simulated, tmp_path):
    image, nc = simulated
    model = FisheyeCameraModel.from_radius(180, 140, 62.0, projection="equisolid", cx=91.3, cy=68.6,
                                           azimuth_up_deg=-35.0, mirror=True,
                                           horizon_azimuth_deg=(0.0, 120.0, 240.0),
                                           horizon_elevation_deg=(5.0, 12.0, 2.0))
    model_path = tmp_path / "camera.toml"
    model.to_toml(model_path)
    linear = reproject(image, model)["rgb_linear"].values
    observed = np.clip(GAIN * np.nan_to_num(linear) + OFFSET, 0.0, 1.0)
    png = tmp_path / "camera.png"
    Image.fromarray(np.rint(linear_to_srgb(observed) * 255).astype(np.uint8)).save(png)

    result = CliRunner().invoke(cli(), [str(nc), str(png), "--camera-model", str(model_path), "--fit", "gain_offset",
                                        "--sun-exclusion", "12", "--min-elevation", "10",
                                        "--diff", str(tmp_path / "diff.png"), "--json", str(tmp_path / "s.json")])
    assert result.exit_code == 0, result.output
    assert "r-bar" in result.output
    scores = json.loads((tmp_path / "s.json").read_text())
    assert min(scores["r"]) >= 0.99 and scores["r_mean"] >= 0.99
    np.testing.assert_allclose(scores["gain"], GAIN, rtol=0.02)
    np.testing.assert_allclose(scores["offset"], OFFSET, atol=0.005)
    assert max(scores["rmse"]) < 0.01 < min(scores["rmse_raw"])
    assert scores["sun_exclusion_deg"] == 12.0 and scores["min_elevation_deg"] == 10.0
    # the compared sky: above 10 deg elevation (and the horizon profile), minus the 12-deg sun cap
    cap = 2 * np.pi * (1 - np.cos(np.radians(12.0)))
    assert 2 * np.pi * (1 - np.sin(np.radians(12.0))) - cap - 0.2 < scores["solid_angle_sr"] \
        < 2 * np.pi * (1 - np.sin(np.radians(10.0))) - cap + 0.05
    assert 0.0 <= scores["clouds"]["accuracy"] <= 1.0
    with Image.open(tmp_path / "diff.png") as diff:
        assert diff.size == (180, 140)


def test_cli_compare_bad_input_exits_2(simulated, tmp_path):
    _, nc = simulated
    model = FisheyeCameraModel.from_radius(60, 50, 20.0)
    model.to_toml(tmp_path / "camera.toml")
    Image.fromarray(np.zeros((40, 60, 3), np.uint8)).save(tmp_path / "small.png")
    runner = CliRunner()
    result = runner.invoke(cli(), [str(nc), str(tmp_path / "small.png"), "--camera-model",
                                   str(tmp_path / "camera.toml")])
    assert result.exit_code == 2 and "expects" in result.output
    Image.fromarray(np.zeros((50, 60, 3), np.uint8)).save(tmp_path / "ok.png")
    result = runner.invoke(cli(), [str(nc), str(tmp_path / "ok.png"), "--camera-model",
                                   str(tmp_path / "camera.toml"), "--sun-exclusion", "-3"])
    assert result.exit_code == 2 and "sun_exclusion_deg" in result.output
    assert not (tmp_path / "s.json").exists()


def test_geostationary_reflectance_factor(scene):
    kwargs = geostationary_view(-75.2, scene, size=21)
    image = swim.render(scene, **kwargs)
    refl = reflectance_factor(image)
    # the centre pixel sees the reference point, where the local sun is the ephemeris' sun there
    assert refl["mu0"].values[10, 10] == pytest.approx(np.cos(np.radians(image.attrs["sun_zenith_reference_deg"])),
                                                       abs=1e-4)
    R = refl["reflectance_factor"].values
    assert np.all(np.isfinite(R))
    # dark vegetated ground / lake plus Rayleigh path radiance, up to bright cumulus
    assert 0.02 < np.min(R) and np.max(R) < 1.5
    assert np.median(R[2]) > np.median(R[0])  # blue path radiance


def test_cli_compare_downsampled(simulated, tmp_path):
    """--downsample 2: the same fake camera compared on pixels twice as large (a quarter of the work) recovers the
    same gain and correlation, and the difference image has the coarser grid; a camera mask image applies to it."""
    image, nc = simulated
    model = FisheyeCameraModel.from_radius(180, 140, 62.0, projection="equisolid", cx=91.3, cy=68.6,
                                           azimuth_up_deg=-35.0, mirror=True)
    mask = np.full((140, 180), 255, np.uint8)
    mask[:, :40] = 0  # a building on the left
    Image.fromarray(mask).save(tmp_path / "mask.png")
    model = FisheyeCameraModel(**{**{k: getattr(model, k) for k in ("width", "height", "focal_length_px", "projection",
                                                                     "cx", "cy", "azimuth_up_deg", "mirror")},
                                  "mask_path": str(tmp_path / "mask.png")})
    model.to_toml(tmp_path / "camera.toml")
    linear = reproject(image, model)["rgb_linear"].values
    observed = np.clip(GAIN * np.nan_to_num(linear) + OFFSET, 0.0, 1.0)
    png = tmp_path / "camera.png"
    Image.fromarray(np.rint(linear_to_srgb(observed) * 255).astype(np.uint8)).save(png)
    result = CliRunner().invoke(cli(), [str(nc), str(png), "--camera-model", str(tmp_path / "camera.toml"), "--fit",
                                        "gain_offset", "--sun-exclusion", "12", "--min-elevation", "10",
                                        "--downsample", "2", "--diff", str(tmp_path / "diff.png"), "--json",
                                        str(tmp_path / "s.json")])
    assert result.exit_code == 0, result.output
    scores = json.loads((tmp_path / "s.json").read_text())
    assert scores["r_mean"] >= 0.98 and scores["downsample"] == 2
    np.testing.assert_allclose(scores["gain"], GAIN, rtol=0.03)
    with Image.open(tmp_path / "diff.png") as diff:
        assert diff.size == (90, 70)
    small = model.downsampled(2)
    assert small.mask_image()[:, :20].sum() == 0 and small.mask_image()[:, 20:].any()
