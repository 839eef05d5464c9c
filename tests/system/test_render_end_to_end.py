"""End-to-end renders on real and built-in scenes: geometry invariants, colour, outputs, bad input."""


import numpy as np
import pytest
import xarray as xr
from typer.testing import CliRunner

import swim
from swim.cli.main import app
from swim.errors import SwimInputError
from swim.frames import enu_from_azimuth_zenith
from swim.geometry.cameras import AllSkyCamera
from swim.rt.march_settings import ExecutionSettings, MarchSettings, REFINE_BUDGET

SMALL = {"size": 95}


@pytest.fixture(scope="module")
def katrina(shared_data):
    return swim.open_scene(shared_data / "wrf_katrina" / "ci_test_file.nc", time="2005-08-28T18:00")


@pytest.fixture(scope="module")
def katrina_allsky(katrina):
    return swim.render(katrina, time="2005-08-28T18:00", lat=24.7, lon=-88.6, height=2.0, camera="allsky",
                       camera_options=SMALL)


def test_katrina_allsky_sun_where_the_ephemeris_puts_it(katrina_allsky):
    image = katrina_allsky
    zen, az = image.attrs["sun_zenith_deg"], image.attrs["sun_azimuth_deg"]
    # pvlib: 2005-08-28 18 UTC at 24.7 N 88.6 W is ~1 h before local solar noon, sun high in the south-east.
    assert 10 < zen < 35 and 90 < az < 200
    camera = AllSkyCamera(**SMALL)
    row, col = camera.pixel_of_direction(enu_from_azimuth_zenith(az, zen)[None])
    green = image["radiance"].sel(wavelength=546).values
    brightest = np.unravel_index(np.nanargmax(green), green.shape)
    assert abs(brightest[0] - row[0]) <= 1 and abs(brightest[1] - col[0]) <= 1


def test_katrina_allsky_has_no_crease_through_the_zenith(katrina_allsky):
    """The rows and columns through the zenith are as smooth as the rest of the sky in the 8-bit image: no line or
    step where the view azimuth turns over (a one-level line along a row would lift its mean |second difference|
    from ~0.15 to ~1)."""
    rgb = katrina_allsky["rgb"].values.astype(float).mean(axis=-1)
    n = rgb.shape[0]
    centre, inner = n // 2, slice(n // 8, n - n // 8)
    for image in (rgb, rgb.T):  # across rows, then across columns
        curvature = np.abs(image[1:-1] - 0.5 * (image[:-2] + image[2:]))[:, inner].mean(axis=1)  # row i + 1
        typical = float(np.median(curvature[inner]))
        through_zenith = curvature[centre - 2:centre + 1]
        assert np.all(through_zenith < max(2.0 * typical, 0.5)), (through_zenith, typical)


def test_katrina_allsky_physical_ranges(katrina_allsky):
    radiance = katrina_allsky["radiance"].values
    valid = np.isfinite(radiance[1])
    assert valid.sum() > 0.7 * valid.size
    assert np.all(radiance[:, valid] >= 0)
    # Outside the sun's disk L' stays below a white Lambertian surface facing the sun (4, Eq. 2) x ARF.
    sky = radiance[:, valid & (katrina_allsky["view_zenith"].values < 80)]
    assert np.percentile(sky, 99) < 6.0
    # Hurricane clouds: a large part of the sky has optical depth > 1.
    assert np.mean(katrina_allsky["tau_hydrometeor"].values[valid] > 1) > 0.2


def test_clear_sky_is_blue_and_clouds_are_grey(katrina):
    # A cloud-free column north-west of the hurricane (column tau < 0.2 within 20 km), its thick
    # clouds ~50 km to the east, low on the horizon.
    image = swim.render(katrina, lat=26.0, lon=-90.66, height=2.0, camera="allsky", camera_options=SMALL)
    radiance = image["radiance"].values
    tau = image["tau_hydrometeor"].values
    zenith = image["view_zenith"].values
    sun = enu_from_azimuth_zenith(image.attrs["sun_azimuth_deg"], image.attrs["sun_zenith_deg"])
    view = enu_from_azimuth_zenith(image["view_azimuth"].values, zenith)
    far_from_sun = np.einsum("yxc,c->yx", view, sun) < np.cos(np.deg2rad(10.0))
    clear = (tau < 0.01) & (zenith < 70) & far_from_sun
    cloudy = (tau > 20) & (zenith < 88)
    assert clear.sum() > 0.5 * (zenith < 70).sum()
    # Rayleigh blue: tau_R(450)/tau_R(615) = 3.6; the background aerosol (AOD 0.05, Angstrom 1.4) is
    # spectrally flatter and dilutes it, but the sky stays Rayleigh-dominated.
    assert np.median(radiance[2][clear] / radiance[0][clear]) > 1.6
    rgb = image["rgb"].values[clear].astype(int)
    assert np.all(rgb[:, 2] > rgb[:, 0])
    assert cloudy.sum() > 5
    ratio = radiance[2][cloudy] / radiance[0][cloudy]
    # Thick cloud is near neutral; seen ~50 km away through near-surface air it is reddened by Rayleigh
    # extinction (tau_R over that path ~1.3 at 450 nm, ~0.3 at 615 nm) and blued by in-scattering.
    assert 0.5 < np.median(ratio) < 1.6


def test_netcdf_and_png_outputs(katrina_allsky, tmp_path):
    nc = swim.write_netcdf(katrina_allsky, tmp_path / "a.nc")
    png = swim.write_png(katrina_allsky, tmp_path / "a.png")
    with xr.open_dataset(nc) as back:
        assert back["radiance"].attrs["units"] == "1"
        assert list(back["wavelength"].values) == [615.0, 546.0, 450.0]
        assert back.attrs["sun_source"] == "pvlib-spa"
        np.testing.assert_allclose(back["radiance"].values, katrina_allsky["radiance"].values)
    from PIL import Image

    assert Image.open(png).size == (SMALL["size"], SMALL["size"])
    assert not list(tmp_path.glob(".*"))  # no temporary files left behind


def test_space_view_sees_the_hurricane(katrina):
    image = swim.render(katrina, time="2005-08-28T18:00", height=36_000e3, camera="perspective",
                        camera_options={"width": 64, "height": 64})
    radiance = image["radiance"].sel(wavelength=615).values
    tau = image["tau_hydrometeor"].values
    assert np.isfinite(radiance).all()
    # Thick cloud tops are far brighter than the open sea.
    assert np.median(radiance[tau > 20]) > 4 * np.median(radiance[tau < 0.1])


def test_default_scene_renders_with_no_file():
    image = swim.render(swim.default_scene(), camera="allsky", camera_options={"size": 63})
    rgb = image["rgb"].values
    assert rgb.dtype == np.uint8 and rgb.shape == (63, 63, 3)
    assert rgb.max() > 100
    # Only the fisheye circle (and one ray to the sun) is traced: the corners cost nothing and stay empty.
    inside = np.isfinite(image["radiance"].values[0])
    assert not inside[0, 0] and inside[31, 31]
    n_traced = int(inside.sum()) + 1
    assert 0.7 * 63 * 63 < n_traced < 0.85 * 63 * 63
    # the samples of the traced rays alone: every step of every ray in the lockstep JAX kernel, each ray's own count
    # (at least one, at most its steps plus three per refinement) in the per-ray kernels; the end step included
    samples = image.attrs["march_samples"]
    settings = MarchSettings()
    nominal = settings.n_before + settings.n_grid + settings.n_after + 1
    if image.attrs["march_backend"] == "jax":
        assert samples == n_traced * nominal
    else:
        assert n_traced <= samples <= n_traced * (nominal + 3 * REFINE_BUDGET)


def test_observer_under_terrain_or_out_of_reach_is_rejected():
    scene = swim.default_scene()
    with pytest.raises(SwimInputError, match="height"):
        swim.render(scene, height=-5.0, camera_options=SMALL)
    with pytest.raises(SwimInputError, match="outside the model domain"):
        swim.render(scene, lat=10.0, lon=20.0, camera_options=SMALL)


@pytest.mark.parametrize("camera, options, match", [
    ("perspective", {"size": 256, "fov_deg": 9.0}, "unknown option"),
    ("allsky", {"size": -3}, "size"),
    ("orthographic", {}, "camera kind"),
    ("allsky", [("size", 9)], "camera_options must be a mapping"),
], ids=["unknown option", "bad value", "unknown kind", "not a mapping"])
def test_bad_camera_options_are_rejected_before_the_scene_is_read(monkeypatch, camera, options, match):
    """A camera's bad kind or options are found before the scene is cropped, read or validated (a whole CONUS grid
    took ~40 s and 11 GB before the camera's error); the scene's reading is made to fail, so a late check fails the
    test with another error."""
    from swim import pipeline

    def read(*args, **kwargs):
        raise AssertionError("the scene was read before the camera's options were checked")

    monkeypatch.setattr(pipeline.scene_stage, "crop_scene_to_view", read)
    monkeypatch.setattr(pipeline.scene_stage, "validate_scene", read)
    with pytest.raises(SwimInputError, match=match):
        swim.render(swim.default_scene(), camera=camera, camera_options=options, crop=True)
    with pytest.raises(SwimInputError, match=match):
        swim.render(swim.default_scene(), camera=camera, camera_options=options, crop=False)


def test_night_renders_dark_instead_of_failing():
    image = swim.render(swim.default_scene(), sun_zenith=120.0, sun_azimuth=0.0, camera_options={"size": 63})
    assert np.nanmax(image["radiance"].values) < 1e-3


def test_cli_renders_and_leaves_no_partial_file_on_error(tmp_path):
    runner = CliRunner()
    out = tmp_path / "sky.png"
    result = runner.invoke(app, ["render", "--size", "63", "--out", str(out), "--netcdf", str(tmp_path / "sky.nc")])
    assert result.exit_code == 0, result.output
    assert out.exists() and (tmp_path / "sky.nc").exists()
    bad = tmp_path / "bad.png"
    result = runner.invoke(app, ["render", "--size", "63", "--height", "-3", "--out", str(bad)])
    assert result.exit_code == 2
    assert "height" in result.output
    assert not bad.exists()
    missing = runner.invoke(app, ["render", str(tmp_path / "nope.nc"), "--out", str(bad)])
    assert missing.exit_code == 2 and not bad.exists()


def test_aerosol_type_and_optical_depth_change_the_sky():
    scene = swim.default_scene()
    from swim.rt.gas import AerosolBackground

    # the paper's cloud scattering: each aerosol would otherwise cost a 3-D solve of the scene
    kwargs = dict(camera="allsky", camera_options={"size": 63}, sun_zenith=40.0, sun_azimuth=180.0,
                  settings=swim.MarchSettings(cloud_scattering="albers2020"))
    clean = swim.render(scene, aerosol=AerosolBackground(0.02, type_name="sea_salt"), **kwargs)
    smoky = swim.render(scene, aerosol=AerosolBackground(0.8, type_name="smoke"), **kwargs)
    assert smoky.attrs["aerosol_type"] == "smoke" and smoky.attrs["aerosol_optical_depth_550"] == 0.8
    clear = (clean["tau_hydrometeor"].values < 0.01) & (smoky["tau_hydrometeor"].values < 0.01)
    blue_red = lambda img: np.nanmedian(img["radiance"].values[2][clear] / img["radiance"].values[0][clear])  # noqa: E731
    assert blue_red(smoky) < 0.8 * blue_red(clean)


def test_cli_rejects_an_unknown_aerosol_type(tmp_path):
    out = tmp_path / "x.png"
    result = CliRunner().invoke(app, ["render", "--size", "31", "--aerosol", "volcanic_ash", "--out", str(out)])
    assert result.exit_code == 2 and "continental" in result.output and not out.exists()


def test_cli_renders_a_scene_file_lazily(tmp_path):
    scene_file = tmp_path / "scene.nc"
    swim.default_scene().to_netcdf(scene_file)
    runner = CliRunner()
    out = tmp_path / "lazy.png"
    result = runner.invoke(app, ["render", str(scene_file), "--lazy", "--size", "31", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert out.exists()
    bad = tmp_path / "bad.png"
    result = runner.invoke(app, ["render", "--lazy", "--size", "31", "--out", str(bad)])
    assert result.exit_code == 2 and "--lazy needs a scene file" in result.output
    assert not bad.exists()


def test_adaptive_sampling_matches_every_pixel_with_fewer_rays(katrina, katrina_allsky):
    from swim.rt.image_sampling import AdaptiveSampling

    image = swim.render(katrina, time="2005-08-28T18:00", lat=24.7, lon=-88.6, height=2.0, camera="allsky",
                        camera_options=SMALL, sampling=AdaptiveSampling(tolerance=0.01))
    full = katrina_allsky["radiance"].values
    adaptive = image["radiance"].values
    # the same pixels are valid (the fisheye circle), and the sun's disk is drawn the same way
    np.testing.assert_array_equal(np.isfinite(adaptive), np.isfinite(full))
    valid = np.isfinite(full)
    assert np.argmax(np.where(valid, adaptive, 0)[1]) == np.argmax(np.where(valid, full, 0)[1])
    rel = np.abs(adaptive[valid] - full[valid]) / np.maximum(full[valid], 1e-3)
    assert np.median(rel) < 0.002 and np.percentile(rel, 99) < 0.03
    assert image.attrs["traced_pixels"] < 0.8 * valid[0].sum()
    assert katrina_allsky.attrs["traced_pixels"] == valid[0].sum()
    assert image.attrs["sampling"].startswith("adaptive") and katrina_allsky.attrs["sampling"] == "every pixel"


def test_cli_renders_adaptively(tmp_path):
    out = tmp_path / "adaptive.png"
    result = CliRunner().invoke(app, ["render", "--size", "63", "--adaptive", "--tolerance", "0.02", "--tau-tolerance",
                                      "0.03", "--out", str(out), "--netcdf", str(tmp_path / "adaptive.nc")])
    assert result.exit_code == 0, result.output
    assert out.exists()
    with xr.open_dataset(tmp_path / "adaptive.nc") as ds:
        assert "tolerance 0.02," in ds.attrs["sampling"] and "tau tolerance 0.03," in ds.attrs["sampling"]
    bad = tmp_path / "bad.png"
    result = CliRunner().invoke(app, ["render", "--size", "63", "--adaptive", "--tolerance", "0", "--out", str(bad)])
    assert result.exit_code == 2 and "tolerance" in result.output and not bad.exists()


def test_cli_coarsens_a_distant_view(tmp_path):
    """--coarsen N renders the scene with one column per N x N block (the output says so); a bad value is refused
    before any file is written."""
    out = tmp_path / "coarse.png"
    view = ["render", "--camera", "perspective", "--width", "24", "--image-height", "24", "--fov", "4",
            "--height", "700000", "--sun-zenith", "40", "--sun-azimuth", "150"]
    result = CliRunner().invoke(app, view + ["--coarsen", "2", "--out", str(out), "--netcdf", str(tmp_path / "c.nc")])
    assert result.exit_code == 0, result.output
    with xr.open_dataset(tmp_path / "c.nc") as ds:
        assert int(ds.attrs["scene_coarsened_by"]) == 2
    bad = tmp_path / "bad.png"
    result = CliRunner().invoke(app, view + ["--coarsen", "fine", "--out", str(bad)])
    assert result.exit_code == 2 and "--coarsen" in result.output and not bad.exists()


@pytest.mark.full  # JAX compiles its march for ~20 s; the quick tier holds the numba kernel to the reference
@pytest.mark.parametrize("scene_name", ["default", "katrina"])
def test_numba_and_jax_kernels_render_the_same_image(scene_name, request):
    """The CPU kernel (swim.rt.march_cpu) against the JAX kernel on whole images: terrain, cumulus and
    cirrus of the default scene, the hurricane's decks, the sun's disk."""
    from swim.rt.march_settings import MarchSettings

    if scene_name == "default":
        scene, view = swim.default_scene(), {}
    else:
        scene, view = request.getfixturevalue("katrina"), {"time": "2005-08-28T18:00", "lat": 24.7, "lon": -88.6}
    images = {backend: swim.render(scene, height=2.0, camera="allsky", camera_options={"size": 63},
                                   settings=MarchSettings(execution=ExecutionSettings(backend=backend)),
                                                                                      **view) for backend in ("jax",
                                                                                                              "numba")}
    a, b = images["jax"]["radiance"].values, images["numba"]["radiance"].values
    np.testing.assert_array_equal(np.isfinite(a), np.isfinite(b))
    valid = np.isfinite(a)
    rel = np.abs(a[valid] - b[valid]) / np.maximum(a[valid], 1e-3)
    # float32 JAX against float64 numba: round-off, and a rare pixel whose cloud-edge step falls otherwise
    assert np.median(rel) < 1e-5 and np.percentile(rel, 99) < 1e-4 and rel.max() < 5e-3
    assert np.abs(images["jax"]["rgb"].values.astype(int) - images["numba"]["rgb"].values.astype(int)).max() <= 1
    assert images["numba"].attrs["march_backend"] == "numba" and images["jax"].attrs["march_backend"] == "jax"


@pytest.mark.full  # the JAX kernel's programs compile for tens of seconds on an empty cache: the full tier
def test_cli_backend_option(tmp_path):
    out = tmp_path / "jax.png"
    result = CliRunner().invoke(app, ["render", "--size", "31", "--backend", "jax", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert out.exists()
    bad = tmp_path / "bad.png"
    result = CliRunner().invoke(app, ["render", "--size", "31", "--backend", "opencl", "--out", str(bad)])
    assert result.exit_code == 2 and "ExecutionSettings.backend" in result.output and not bad.exists()


def test_cli_probes_option(tmp_path):
    out = tmp_path / "probes.png"
    result = CliRunner().invoke(app, ["render", "--size", "31", "--probes", "16", "--steps", "64", "--probe-spacing", "1",
                                      "--tau-refine", "0.25", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert out.exists()
    bad = tmp_path / "bad.png"
    result = CliRunner().invoke(app, ["render", "--size", "31", "--probes", "0", "--out", str(bad)])
    assert result.exit_code == 2 and "MarchSettings.n_probe" in result.output and not bad.exists()
    result = CliRunner().invoke(app, ["render", "--size", "31", "--probe-spacing", "-1", "--out", str(bad)])
    assert result.exit_code == 2 and "MarchSettings.probe_spacing" in result.output and not bad.exists()
    result = CliRunner().invoke(app, ["render", "--size", "31", "--tau-refine", "-1", "--out", str(bad)])
    assert result.exit_code == 2 and "MarchSettings.tau_refine" in result.output and not bad.exists()


def test_a_cpu_render_does_not_import_jax(tmp_path):
    """On the CPU the numba kernel marches and the host computes the rest (the phase functions, the tables, the 3-D
    diffuse solution): ``swim render --backend numba`` renders the built-in scene without loading JAX
    (docs/decisions/0011-jax-only-where-it-runs.md)."""
    import subprocess
    import sys

    out = tmp_path / "sky.png"
    probe = ("import sys\nfrom swim.cli.main import run\n"
             "sys.argv = ['swim', 'render', '--size', '17', '--backend', 'numba', '--out', sys.argv[1]]\n"
             "try:\n    run()\nexcept SystemExit as exit:\n    assert not exit.code, exit.code\n"
             "print('jax loaded:', 'jax' in sys.modules)\n")
    result = subprocess.run([sys.executable, "-c", probe, str(out)], capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip().splitlines()[-1] == "jax loaded: False"
    assert out.stat().st_size > 0
