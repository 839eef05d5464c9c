"""End-to-end renders with the 3-D cloud scattering (``cloud_scattering="discrete_ordinates"``) on the built-in scene
and real model output: physical ranges, energy bookkeeping of the aureole, cloud-ground interreflection, resolution
independence of the GHI, the CLI's options, the JAX kernel against the numba kernel and the backend that refuses it."""

import numpy as np
import pytest
from typer.testing import CliRunner

import swim
import swim.validation.stratus
from swim.cli.main import app
from swim.diagnostics.irradiance import sky_irradiance
from swim.rt.march_settings import ExecutionSettings, MarchSettings

THREE_D = MarchSettings(cloud_scattering="discrete_ordinates")
PAPER = MarchSettings(cloud_scattering="albers2020")


@pytest.fixture(scope="module")
def default_scene():
    from swim.io.default_scene import default_scene

    return default_scene()


@pytest.fixture(scope="module")
def default_3d(default_scene):
    # the solver's columns coarsened to 50 000 cells: a solve of ~3 s instead of the default's ~4 s
    from swim.rt.clouds import CloudScattering
    from swim.rt.diffuse_field import DiffuseSettings

    coarse = CloudScattering("discrete_ordinates", diffuse=DiffuseSettings(max_cells=50_000))
    return swim.render(default_scene, camera="allsky", camera_options={"size": 63}, sun_zenith=40.0,
                       sun_azimuth=150.0, settings=MarchSettings(cloud_scattering=coarse))


@pytest.mark.full  # the built-in scene's 3-D solve; the quick tier renders the method on a small LES field
def test_default_scene_renders_with_3d_clouds(default_3d):
    image = default_3d
    assert image.attrs["cloud_scattering"] == "discrete_ordinates"
    rad = image["radiance"].values
    inside = np.isfinite(image["view_zenith"].values)
    assert np.all(np.isfinite(rad[:, inside])) and np.all(rad[:, inside] >= 0)
    cloudy = inside & (image["tau_hydrometeor"].values > 3)
    assert cloudy.sum() > 20
    # clouds are grey-white: their 615/450 nm ratio near 1, unlike the blue sky's
    cloud, sky = image["radiance_cloud"].values, image["radiance_clear"].values
    assert np.all(cloud[:, cloudy] > 0)
    clear = inside & (image["tau_hydrometeor"].values < 1e-3)
    red_blue_cloud = np.median(image["radiance"].values[0, cloudy] / image["radiance"].values[2, cloudy])
    red_blue_sky = np.median(sky[0, clear] / sky[2, clear])
    assert 0.75 < red_blue_cloud < 1.25 and red_blue_sky < 0.7
    assert np.all(np.asarray(image.attrs["circumsolar_transmittance"]) >= 0)


def test_the_3d_method_is_the_default_and_the_paper_s_stays_selectable():
    assert MarchSettings().cloud_scattering.method == "discrete_ordinates"
    scene = swim.validation.stratus.stratus_scene(5.0, n_columns=5)
    kwargs = dict(camera="allsky", camera_options={"size": 15}, sun_zenith=40.0, sun_azimuth=150.0)
    paper = swim.render(scene, settings=PAPER, **kwargs)
    assert paper.attrs["cloud_scattering"] == "albers2020"
    assert np.all(np.asarray(paper.attrs["circumsolar_transmittance"]) == 0)  # the paper's method has no aureole
    assert swim.render(scene, **kwargs).attrs["cloud_scattering"] == "discrete_ordinates"


def test_a_set_sun_falls_back_to_the_paper_s_method_and_a_low_one_renders_in_3d(caplog):
    """The 3-D solution needs the sun above 0.6 deg elevation: a twilight or night render says so in the log and its
    cloud_scattering attribute, and renders (dark at night) instead of failing."""
    scene = swim.validation.stratus.stratus_scene(5.0, n_columns=5)
    with caplog.at_level("INFO", logger="swim.pipeline"):
        night = swim.render(scene, camera="allsky", camera_options={"size": 15}, sun_zenith=120.0, sun_azimuth=0.0)
    assert night.attrs["cloud_scattering"] == "albers2020" and "the 3-D diffuse solution needs" in caplog.text
    assert np.nanmax(night["radiance"].values) < 1e-3
    # a low sun (4 deg high) under a stratospheric layer: the 3-D method runs where the lowest layers hardly see the
    # sun (the clear column's beam was once made negative there, by the logarithmic mean of two near-zero values)
    low = swim.render(swim.default_scene(), camera="allsky", camera_options={"size": 9}, sun_zenith=86.0,
                      sun_azimuth=270.0, aerosol=swim.AerosolBackground(stratospheric_aod_550=0.15))
    assert low.attrs["cloud_scattering"] == "discrete_ordinates"
    rad = low["radiance"].values
    assert np.all(rad[np.isfinite(rad)] >= 0) and np.isfinite(rad).sum() > 100


@pytest.mark.full  # two 3-D renders of an ice deck (~20 s): a goal figure of the validation tier
def test_ghi_does_not_depend_on_the_image_resolution(default_scene):
    """The forward peaks' narrow part is delivered as an energy-conserving aureole: the GHI integrated from all-sky
    images of 121^2 and 511^2 pixels agrees within 1 % (a thin ice deck with a diffraction peak ~0.1 deg wide)."""
    from swim.validation.stratus import stratus_scene

    scene = stratus_scene(1.0, species="cloud_ice", cloud_base_m=8000.0, cloud_top_m=10000.0, dz_m=100.0,
                          effective_radius_m=34e-6)
    ghi = []
    for size in (121, 511):
        image = swim.render(scene, camera="allsky", camera_options={"size": size}, sun_zenith=35.0,
                            sun_azimuth=160.0, height=0.0, settings=THREE_D)
        ghi.append(sky_irradiance(image)["ghi"].values)
    np.testing.assert_allclose(ghi[0], ghi[1], rtol=0.01)


def test_a_cloudless_scene_keeps_the_clear_sky():
    """Without hydrometeors the diffuse solution's ratios to the clear column are ~1: the sky and the ground are the
    clear sky's (validated against DISORT) within the solution's discretisation, and no aureole is delivered."""
    from swim.validation.disort import clear_scene

    images = [swim.render(clear_scene(), camera="allsky", camera_options={"size": 31}, sun_zenith=50.0,
                          sun_azimuth=135.0, height=0.0, settings=settings) for settings in (THREE_D, PAPER)]
    inside = np.isfinite(images[1]["view_zenith"].values) & (images[1]["view_zenith"].values < 85)
    ratio = images[0]["radiance_clear"].values[:, inside] / images[1]["radiance_clear"].values[:, inside]
    assert np.all(np.abs(np.median(ratio, axis=1) - 1) < 0.01) and np.all(np.abs(ratio - 1) < 0.03)
    assert np.all(np.asarray(images[0].attrs["circumsolar_transmittance"]) == 0)
    assert np.all(images[0]["tau_hydrometeor"].values[inside] == 0)


def test_a_smoke_layer_without_clouds_matches_disort():
    """A scene's 3-D aerosol (smoke, AOD 1) without clouds: the diffuse solution's ratios are taken against the grid's
    own clear air with that aerosol, so the sky is Step 2's validated one (against the clear column alone the smoke's
    diffuse light counted twice: median +72 to +134 %, GHI +51 to +64 %). DISORT with the same aerosol, 16 streams."""
    from swim.rt.gas import AerosolBackground
    from swim.validation.disort import aerosol_layer_scene, compare_ground_sky

    smoke = AerosolBackground(aod_550=1.0, type_name="smoke")
    r = compare_ground_sky(45.0, smoke, scene=aerosol_layer_scene(smoke), settings=THREE_D,
                           render_aerosol=AerosolBackground(aod_550=0.0, type_name="smoke"), n_streams=16,
                           camera_size=31)
    assert np.all(r["median_abs"] < 0.015), r["median_abs"]
    assert np.all(np.abs(r["ghi_swim"] / r["ghi_disort"] - 1) < 0.01)


def test_a_bright_ground_brightens_the_cloud_base():
    """Cloud-ground interreflection: under a deck, the zenith radiance over snow (albedo 0.9) exceeds that over the
    sea (0.06) by far more than the albers2020 method's, which has no light bouncing between them."""
    from swim.validation.stratus import stratus_scene

    def zenith(albedo, settings):
        scene = stratus_scene(20.0, surface_albedo=albedo, n_columns=5)
        image = swim.render(scene, camera="allsky", camera_options={"size": 21}, sun_zenith=50.0,
                            sun_azimuth=180.0, height=0.0, settings=settings)
        return image["radiance"].values[1, 10, 10]

    gain_3d = zenith(0.9, THREE_D) / zenith(0.06, THREE_D)
    gain_paper = zenith(0.9, PAPER) / zenith(0.06, PAPER)
    assert gain_3d > 1.8 and gain_3d > gain_paper + 0.5


@pytest.mark.full
def test_katrina_from_space_and_below(shared_data):
    scene = swim.open_scene(shared_data / "wrf_katrina" / "ci_test_file.nc", time="2005-08-28T18:00")
    below = swim.render(scene, time="2005-08-28T18:00", lat=24.7, lon=-88.6, height=2.0, camera="allsky",
                        camera_options={"size": 47}, settings=THREE_D)
    space = swim.render(scene, time="2005-08-28T18:00", height=36e6, camera="perspective",
                        camera_options={"width": 32, "height": 32}, settings=THREE_D)
    for image in (below, space):
        rad = image["radiance"].values
        assert np.all(np.isfinite(rad[np.isfinite(rad)])) and np.nanmin(rad) >= 0
    # from space the eyewall's thick cloud (a few per cent of the view) is brighter than the sea, but no brighter
    # than a white Lambertian reflector at the sun's cosine (L' = 4 mu0 is an albedo of 1)
    green = space["radiance"].values[1]
    mu0 = np.cos(np.radians(space.attrs["sun_zenith_reference_deg"]))
    assert np.nanmax(green) < 4 * mu0 * 1.2
    assert np.nanpercentile(green, 99) > 2 * np.nanmedian(green)


@pytest.mark.full
def test_the_eyewall_deck_from_space(shared_data):
    """Katrina's eyewall (vertical optical depths up to 480, median 150; the deep field without a Monte Carlo
    reference): a thick, conservative deck's nadir reflectance factor at sun zenith 30 deg is R_inf - t K(1) K(mu0)
    ~ 1.0 - 0.055 * 1.29 * 1.17 ~ 0.92 by the asymptotic thick-layer relations (t ~ 1 / (0.75 (1 - g) tau + 1.4),
    van de Hulst 1980, Multiple Light Scattering, ch. 14); no block brighter than 1.2 (the 99th percentile)."""
    from swim.validation import clouds3d as C

    out = C.render_case(C.case_scene("eyewall", shared_data), "nadir", 30.0, C.settings_3d())
    factor = out["image"][:, out["mask"]] / (4.0 * np.cos(np.radians(30.0)))
    assert np.all(np.isfinite(factor))
    median = np.median(factor, axis=1)
    assert np.all((median > 0.85) & (median < 1.1)), median
    assert np.percentile(factor, 99) < 1.2


def _agree(ours, theirs):
    """Images agree to float32 round-off (1e-3 of each pixel, or of 1e-3 of the brightest where dark) in 99 % of their
    pixels and within 2 % in all: a chunk of the JAX kernel places a ray's steps with the chunk's most probes, where a
    step through a cloud's edge moves that ray's integral by up to ~1 % (the march's own step error there)."""
    ours, theirs = np.nan_to_num(ours), np.nan_to_num(theirs)
    error = np.abs(ours - theirs) / np.maximum(np.abs(theirs), 1e-3 * np.abs(theirs).max())
    assert np.percentile(error, 99) < 1e-3 and error.max() < 0.02, (np.percentile(error, 99), error.max())


@pytest.mark.full
def test_the_jax_kernel_matches_the_numba_kernel(default_scene):
    """The JAX kernel (float32, rays in lockstep) against the numba kernel (float64, per ray) on the built-in scene:
    the clouds' integrated sources, the air's diffuse source scaled by the diffuse solution and the ground lit by it
    agree to float32 precision."""
    images = [swim.render(default_scene, camera="allsky", camera_options={"size": 31}, sun_zenith=40.0,
                          sun_azimuth=150.0, settings=MarchSettings(cloud_scattering="discrete_ordinates",
                                                                    execution=ExecutionSettings(backend=b)))
              for b in ("jax", "numba")]
    for key in ("radiance", "radiance_cloud", "radiance_clear", "radiance_surface"):
        _agree(images[0][key].values, images[1][key].values)
    assert (images[0]["radiance_cloud"].values > 0).sum() > 100


@pytest.mark.full
def test_the_jax_kernel_delivers_the_aureole():
    """Through a thin ice deck the sun's narrow forward peak (the aureole's transmittance) and the sky agree between
    the kernels."""
    from swim.validation.stratus import stratus_scene

    scene = stratus_scene(1.0, species="cloud_ice", cloud_base_m=8000.0, cloud_top_m=10000.0, dz_m=250.0,
                          effective_radius_m=34e-6, n_columns=5)
    images = [swim.render(scene, camera="allsky", camera_options={"size": 21}, sun_zenith=35.0, sun_azimuth=160.0,
                          height=0.0, settings=MarchSettings(cloud_scattering="discrete_ordinates",
                                                             execution=ExecutionSettings(backend=b)))
              for b in ("jax", "numba")]
    aureole = [np.asarray(image.attrs["circumsolar_transmittance"]) for image in images]
    assert np.all(aureole[1] > 0.1)
    np.testing.assert_allclose(aureole[0], aureole[1], rtol=1e-4)
    _agree(images[0]["radiance"].values, images[1]["radiance"].values)


@pytest.mark.full
@pytest.mark.parametrize("view, sun_zenith", [("nadir", 60.0), ("ground", 30.0)])
def test_the_jax_kernel_on_the_rico_field(shared_data, view, sun_zenith):
    """The Monte Carlo comparison's views of the RICO cumulus (swim.validation.clouds3d) in both kernels: their 8 x 8
    block means agree within 1e-3."""

    from swim.validation import clouds3d as C

    scene = C.case_scene("rico", shared_data)
    out = [C.render_case(scene, view, sun_zenith, C.settings_3d().with_execution(backend=b))
           for b in ("jax", "numba")]
    blocks = [C.block_means(o["image"], o["mask"]) for o in out]
    np.testing.assert_allclose(blocks[0], blocks[1], rtol=1e-3)


def test_cli_cloud_scattering_options(tmp_path, shared_data):
    out = tmp_path / "sky.png"
    les = shared_data / "les" / "rico32x37x26.txt"  # 32 x 37 columns of RICO: a solve of about a second
    result = CliRunner().invoke(app, ["render", str(les), "--scene-lat", "18", "--scene-lon", "-62",
                                      "--cloud-scattering", "discrete_ordinates", "--cloud-phase",
                                      "liquid=0.85,ice=0.75", "--size", "31", "--sun-zenith", "40", "--sun-azimuth",
                                      "150", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert out.stat().st_size > 0
    bad = CliRunner().invoke(app, ["render", "--cloud-scattering", "monte_carlo", "--size", "15", "--out",
                                   str(tmp_path / "x.png")])
    assert bad.exit_code != 0 and "cloud_scattering" in bad.output
    bad = CliRunner().invoke(app, ["render", "--cloud-scattering", "discrete_ordinates", "--cloud-phase", "liquid",
                                   "--size", "15", "--out", str(tmp_path / "y.png")])
    assert bad.exit_code != 0 and "--cloud-phase" in bad.output
