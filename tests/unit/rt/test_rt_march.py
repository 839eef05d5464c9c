"""The JAX ray march against the slow NumPy reference and against analytic clear-sky limits."""

import threading
from dataclasses import replace

import numpy as np
import pytest

from swim.compilation import numba_jit
from swim.errors import SwimInputError
from swim.constants import EARTH_RADIUS_M
from swim.frames import enu_from_azimuth_zenith
from swim.io.scene import scene_from_arrays
from swim.optics.rayleigh import rayleigh_phase_function
from swim.optics.volume import build_optical_volume
from swim.rt.gas import AerosolBackground, aerosol_column_classes, build_gas_tables
from swim.rt.march import ray_segments, ray_segments_compiled, trace_rays
from swim.rt.march_inputs import aerosol_column_optical_depth, grid_geometry, kernel_constants
from swim.rt.march_settings import ExecutionSettings, MarchSettings
from swim.rt.reference import reference_trace_ray
from swim.rt.solar import solar_transmittance


def _tiny_scene(aerosol_plume=False):
    rng = np.random.default_rng(3)
    n, spacing = 12, 400.0
    x = (np.arange(n) - n / 2 + 0.5) * spacing
    z = np.arange(0.0, 5000.0, 250.0) + 125.0
    zz, yy, xx = np.meshgrid(z, x, x, indexing="ij")
    blob = np.exp(-(((xx - 300) / 900) ** 2 + ((yy + 200) / 700) ** 2 + ((zz - 2500) / 600) ** 2))
    liquid = 6e-4 * blob * (1 + 0.3 * rng.random(blob.shape))
    ice = 2e-5 * np.exp(-((zz - 4200) / 300) ** 2) * (xx > 0)
    terrain = 600.0 * np.exp(-(((xx[0] + 1500) / 800) ** 2 + ((yy[0] - 1000) / 800) ** 2))
    # A smoke plume (column AOD ~1.5) over the western half: several column classes of the tables.
    aerosol = 6e-4 * np.exp(-zz / 1500.0) * np.clip((600.0 - xx) / 1200.0, 0.0, 1.0) if aerosol_plume else None
    return scene_from_arrays(x=x, y=x, z=z, reference_lat=30.0, reference_lon=10.0, terrain_height=terrain,
                             cloud_liquid_content=liquid, cloud_ice_content=ice, land_mask=1.0,
                             aerosol_extinction=aerosol)


#: Both kernels, the JAX one in the full tier: compiling its programs on an empty cache was two thirds of this
#: file's time in the quick tier.
BACKENDS_JAX_FULL = pytest.mark.parametrize("backend", [pytest.param("jax", marks=pytest.mark.full), "numba"])


def _trace(scene, origins, directions, sun, aerosol=AerosolBackground(), settings=MarchSettings(n_grid=400, n_after=200),
           rayleigh_scattering=True):
    volume = build_optical_volume(scene)
    transmittance = solar_transmittance(volume, sun)
    aer3d = volume["aerosol_extinction"].mean(dim=("y", "x")).values.astype(float)
    profile, classes = None, None
    if np.any(aer3d > 0):
        levels = float(volume.attrs["z_bottom"]) + float(volume.attrs["dz"]) * np.arange(aer3d.size)
        profile = (levels, aer3d)
        classes = aerosol_column_classes(aerosol_column_optical_depth(volume).values)
    gas = build_gas_tables(aerosol, scene_aerosol_profile=profile, aerosol_class_aod=classes)
    consts = kernel_constants(volume, transmittance, gas, sun)
    cos_theta = directions @ sun
    phase = {"cos_theta": cos_theta, "cos_view_zenith": directions[:, 2],
             "p_rayleigh": np.asarray(rayleigh_phase_function(cos_theta, gas.depolarization)) * rayleigh_scattering,
             "p_aerosol": np.asarray(aerosol.type.phase_function(cos_theta)),
             "p_stratospheric": np.asarray(aerosol.stratospheric.phase_function(cos_theta))}
    out = trace_rays(origins, directions, consts, grid_geometry(volume), phase, settings)
    return out, (volume, transmittance, gas, phase)


@BACKENDS_JAX_FULL
@pytest.mark.parametrize("settings", [MarchSettings(n_grid=400, n_after=200), MarchSettings()],
                         ids=["fine steps", "default adaptive steps"])
@pytest.mark.parametrize("aerosol_plume", [False, True], ids=["no 3-D aerosol", "smoke plume"])
def test_kernel_matches_numpy_reference_on_a_tiny_grid(aerosol_plume, settings, backend):
    settings = settings.with_execution(backend=backend)
    scene = _tiny_scene(aerosol_plume)
    sun = enu_from_azimuth_zenith(135.0, 40.0)
    ground = np.array([0.0, 0.0, EARTH_RADIUS_M + 20.0])  # terrain here is ~6 m
    aircraft = np.array([-2000.0, 1500.0, EARTH_RADIUS_M + 6000.0])
    origins, dirs = [], []
    for origin, az, zen in [(ground, 0, 0), (ground, 60, 30), (ground, 300, 60), (ground, 200, 85),
                            (aircraft, 120, 120), (aircraft, 150, 150), (aircraft, 90, 100), (aircraft, 315, 170)]:
        origins.append(origin)
        dirs.append(enu_from_azimuth_zenith(az, zen))
    origins, dirs = np.array(origins), np.array(dirs)
    # with a stratospheric aerosol layer, so that its extinction, source and diffuse source are compared too
    aerosol = AerosolBackground(stratospheric_aod_550=0.2)
    out, (volume, transmittance, gas, phase) = _trace(scene, origins, dirs, sun, aerosol=aerosol, settings=settings)
    if aerosol_plume:
        assert gas.aerosol_class_aod.size >= 3, "the plume must give several column classes"
    assert out["tau_hydrometeor"].max() > 1.0, "the test rays must cross cloud"
    assert out["surface"].sum() >= 3, "some rays must reach the ground"
    opaque_rays = 0
    for n in range(len(dirs)):
        ref = reference_trace_ray(origins[n], dirs[n], volume, transmittance, gas, sun,
                                  phase["p_rayleigh"][n], phase["p_aerosol"][n], step_m=20.0,
                                  p_stratospheric=phase["p_stratospheric"][n])
        # the reference marches the whole line of sight; a ray that does not look down stops where its optical
        # depth passes stop_tau (MarchSettings.stop_tau), with the same radiance and no ground seen behind
        if dirs[n, 2] >= 0 and ref["tau_hydrometeor"] > 1.1 * settings.stop_tau:
            opaque_rays += 1
            assert out["tau_hydrometeor"][n] == settings.stop_tau, f"ray {n}"
            assert not out["surface"][n], f"ray {n}"
            np.testing.assert_allclose(out["radiance"][n], ref["radiance"], rtol=0.04, atol=2e-4)
            continue
        assert out["surface"][n] == ref["surface"], f"ray {n}"
        assert out["tau_hydrometeor"][n] == pytest.approx(ref["tau_hydrometeor"], rel=0.03, abs=1e-3)
        np.testing.assert_allclose(out["tau_clear"][n], ref["tau_clear"], rtol=0.03)
        np.testing.assert_allclose(out["radiance"][n], ref["radiance"], rtol=0.04, atol=2e-4)
    assert opaque_rays >= 1, "a ray must stop in opaque cloud"


@pytest.mark.parametrize("backend", [pytest.param("jax", marks=pytest.mark.full), "numba"])
@pytest.mark.full  # a sweep of step counts through the whole kernel: the full tier
def test_the_air_in_front_of_the_ground_does_not_depend_on_the_step_count(backend):
    """Rays from 14 m above the ground, just above the horizon, that meet the rising ground 280-480 m away: the
    gas and aerosol light in front of it (``radiance_clear``) and the whole radiance against the NumPy reference's
    2 m steps, with 1 to 400 grid steps. Were the step in which a ray meets the ground to count up to where its
    middle sample has gone below the ground, that light would be 10-410 % too bright with 1-32 grid steps (the whole
    radiance up to 2.6 %). It ends at the refined crossing, and where the crossing lies in the far half of
    the step before, that step is taken back and taken again up to it (swim.rt.march_jax._terminal_step;
    docs/decisions/0004-step-placement.md)."""
    scene = _tiny_scene().copy()
    for name in ("cloud_liquid_content", "cloud_ice_content"):
        scene[name] = scene[name] * 0.0
    sun = enu_from_azimuth_zenith(135.0, 40.0)
    origin = np.array([0.0, 0.0, EARTH_RADIUS_M + 20.0])  # terrain here is ~6 m
    dirs = np.array([enu_from_azimuth_zenith(az, zen) for az, zen in
                     [(304.0, 88.0), (300.0, 89.5), (310.0, 87.0), (296.0, 88.5), (304.0, 90.5)]])
    origins = np.repeat(origin[None], len(dirs), axis=0)
    refs = None
    for n_grid in (1, 2, 3, 5, 8, 32, 400):
        settings = MarchSettings(n_grid=n_grid, n_after=200, execution=ExecutionSettings(backend=backend))
        out, (volume, transmittance, gas, phase) = _trace(scene, origins, dirs, sun, settings=settings)
        if refs is None:
            refs = [reference_trace_ray(origins[n], dirs[n], volume, transmittance, gas, sun, phase["p_rayleigh"][n],
                                        phase["p_aerosol"][n], step_m=2.0, p_stratospheric=phase["p_stratospheric"][n])
                    for n in range(len(dirs))]
            assert all(ref["surface"] for ref in refs), "every test ray must meet the ground"
        for n, ref in enumerate(refs):
            assert out["surface"][n], f"ray {n}, {n_grid} grid steps"
            np.testing.assert_allclose(out["radiance_clear"][n], ref["radiance_clear"], rtol=0.015,
                                       err_msg=f"ray {n}, {n_grid} grid steps")
            np.testing.assert_allclose(out["radiance"][n], ref["radiance"], rtol=0.002,
                                       err_msg=f"ray {n}, {n_grid} grid steps")


def _plane_parallel_single_scattering(tau, mu0, mu, phase):
    """Downwelling single-scattering L' at the bottom of a homogeneous plane-parallel layer (omega = 1)."""
    return phase * mu0 / (mu0 - mu) * (np.exp(-tau / mu0) - np.exp(-tau / mu))


@pytest.mark.parametrize("n_grid", [400, 128], ids=["fine", "default grid steps"])
@pytest.mark.parametrize("sun_zenith", [30.0, 60.0])
def test_clear_sky_matches_plane_parallel_single_scattering(sun_zenith, n_grid):
    """Pure Rayleigh sky: zenith radiance against the analytic single-scattering solution.

    An exponential atmosphere and a homogeneous layer give the same single-scattering radiance at the
    bottom for a view and sun not too far from the zenith (the integrand depends on the optical depth
    above the scattering point only); the spherical earth changes it by < 0.5 % at these angles. The grid is
    empty along these rays, so they take only MarchSettings.empty_steps grid steps (100 and 32).
    """
    scene = _tiny_scene().copy()
    for name in ("cloud_liquid_content", "cloud_ice_content"):
        scene[name] = scene[name] * 0.0
    sun = enu_from_azimuth_zenith(180.0, sun_zenith)
    view = np.array([[0.0, 0.0, 1.0], enu_from_azimuth_zenith(0.0, 20.0)])
    origins = np.array([[1500.0, -1500.0, EARTH_RADIUS_M + 1.0]] * 2)  # 1 m above sea level, away from the hill
    out, (_, _, gas, phase) = _trace(scene, origins, view, sun, aerosol=AerosolBackground(aod_550=0.0, ozone_du=0.0),
                                     settings=MarchSettings(n_grid=n_grid, n_after=200, multiple_scattering=False))
    tau = np.trapezoid(gas.beta_rayleigh, dx=gas.dh, axis=0)  # column optical depth per wavelength
    for n in range(2):
        mu = view[n, 2]
        expected = _plane_parallel_single_scattering(tau, np.cos(np.deg2rad(sun_zenith)), mu, phase["p_rayleigh"][n])
        np.testing.assert_allclose(out["radiance"][n], expected, rtol=0.01)


@pytest.mark.parametrize("segments", [ray_segments, ray_segments_compiled], ids=["numpy", "compiled"])
def test_ray_segments_for_ground_and_space_observers(segments):
    scene = _tiny_scene()
    geometry = grid_geometry(build_optical_volume(scene))
    up = np.array([0.0, 0.0, 1.0])
    ground = np.array([0.0, 0.0, EARTH_RADIUS_M + 2.0])
    space = np.array([0.0, 0.0, EARTH_RADIUS_M + 36_000e3])
    seg = segments(np.array([ground, space, space]), np.array([up, -up, up]), geometry)
    # Ground looking up: starts at the observer inside the grid, leaves the grid at its top, ends at 100 km.
    assert seg["valid"][0] and not seg["ends_on_ground"][0]
    assert seg["bounds"][0, 0] == 0.0
    assert seg["bounds"][0, 1] == pytest.approx(geometry.top - 2.0, abs=1.0)
    assert seg["bounds"][0, 2] == pytest.approx(100e3 - 2.0, abs=1.0)
    # Space looking down: enters the atmosphere at 100 km, the grid at its top, ends on the sea.
    assert seg["valid"][1] and seg["ends_on_ground"][1]
    assert seg["bounds"][1, 0] == pytest.approx(100e3 - geometry.top, abs=1.0)
    assert seg["bounds"][1, 2] == pytest.approx(100e3, abs=1.0)
    assert seg["start"][1, 2] == pytest.approx(100e3, abs=1e-3)
    # Space looking away from the earth misses the atmosphere.
    assert not seg["valid"][2]


@pytest.mark.parametrize("type_name", ["colorado_dust", "smoke"])
def test_aerosol_sky_radiance_follows_its_phase_function(type_name):
    """Views at equal zenith angle share the path geometry in a horizontally uniform atmosphere, so the
    single-scattering radiance of the aerosol (Rayleigh scattering switched off, its extinction kept)
    differs only through P_A(theta): the ratio is exact."""
    scene = _tiny_scene().copy()
    for name in ("cloud_liquid_content", "cloud_ice_content"):
        scene[name] = scene[name] * 0.0
    sun = enu_from_azimuth_zenith(180.0, 40.0)
    view = np.array([enu_from_azimuth_zenith(180.0, 50.0), enu_from_azimuth_zenith(0.0, 50.0)])  # theta 10, 90 deg
    origins = np.array([[1500.0, -1500.0, EARTH_RADIUS_M + 1.0]] * 2)
    out, (_, _, _, phase) = _trace(scene, origins, view, sun, aerosol=AerosolBackground(0.1, type_name=type_name),
                                   rayleigh_scattering=False,
                                   settings=MarchSettings(n_grid=400, n_after=200, multiple_scattering=False))
    radiance = out["radiance"]
    assert np.all(radiance > 0)
    np.testing.assert_allclose(radiance[0] / radiance[1], phase["p_aerosol"][0] / phase["p_aerosol"][1], rtol=0.01)
    # Forward scattering dominates for aerosol: the view 10 deg from the sun is far brighter.
    assert np.all(radiance[0] > 3 * radiance[1])


def test_stratospheric_layer_adds_its_optical_depth_and_light():
    """A zenith ray through a stratospheric layer of AOD 0.2 gains exactly 0.2 x (lambda / 550)^-alpha of
    optical depth (Gaussian profile normalised to the column), and the sky gets brighter."""
    scene = _tiny_scene()
    ground = np.array([[0.0, -3000.0, EARTH_RADIUS_M + 1.0]])
    up = np.array([[0.0, 0.0, 1.0]])
    sun = enu_from_azimuth_zenith(135.0, 40.0)
    base, _ = _trace(scene, ground, up, sun, aerosol=AerosolBackground())
    strat = AerosolBackground(stratospheric_aod_550=0.2)
    layer, _ = _trace(scene, ground, up, sun, aerosol=strat)
    expected = 0.2 * strat.stratospheric.extinction_factor(np.array([615.0, 546.0, 450.0]))
    np.testing.assert_allclose(layer["tau_clear"][0] - base["tau_clear"][0], expected, rtol=0.01)
    assert np.all(layer["radiance_clear"][0] > base["radiance_clear"][0] * 1.1)


@pytest.mark.parametrize("field, value", [("n_grid", -1), ("chunk", 0), ("chunk", True), ("chunk", 4096.0),
                                          ("n_before", -3), ("n_after", 2.5), ("n_probe", 0), ("empty_steps", -1),
                                          ("empty_steps", 2.5),
                                          ("probe_spacing", -1.0), ("probe_spacing", float("nan")), ("probe_spacing", "2"),
                                          ("probe_spacing", 1e-20), ("tau_refine", -0.5), ("tau_refine", float("inf")),
                                          ("stop_tau", 10.0), ("stop_tau", -50.0), ("stop_tau", float("inf")),
                                          ("stop_tau", True), ("stop_tau", "50")])
def test_march_settings_reject_bad_counts(field, value):
    kind = ExecutionSettings if field == "chunk" else MarchSettings
    with pytest.raises(SwimInputError, match=f"{kind.__name__}.{field}"):
        kind(**{field: value})


def _random_rays(n, seed=0):
    """Rays in every direction from the ground, an aircraft inside the grid and 20 km up (half looking down)."""
    rng = np.random.default_rng(seed)
    azimuth = rng.uniform(0.0, 360.0, n)
    zenith = np.degrees(np.arccos(rng.uniform(-1.0, 1.0, n)))
    dirs = np.array([enu_from_azimuth_zenith(a, z) for a, z in zip(azimuth, zenith)])
    vantage = np.array([[0.0, 0.0, EARTH_RADIUS_M + 20.0], [-2000.0, 1500.0, EARTH_RADIUS_M + 6000.0],
                        [500.0, -800.0, EARTH_RADIUS_M + 20_000.0]])
    which = np.arange(n) % 3
    dirs[which == 2] = -np.abs(dirs[which == 2]) * [[-1.0, -1.0, 1.0]]  # from 20 km: downward views
    return vantage[which], dirs


@pytest.mark.parametrize("case", ["plume, multiple scattering", "no plume, single scattering, lambertian",
                                  "plume, 8 probes", "plume, 4 probes, one per cell crossed",
                                  "plume, at most 4 empty steps", "plume, at most 4 empty steps, no refinement",
                                  "fog on the ground, 8 grid steps"])
@pytest.mark.full
def test_numba_march_matches_the_jax_march(case):
    """The fused per-ray CPU march (swim.rt.march_cpu) is the JAX kernel's step loop written again: both
    must give the same pixels, to float32 round-off, for rays that cross cloud, the plume, the terrain (hits
    refined by bisection), the grid's edges and the clear air beyond it. With fog on the ground and few steps, rays
    take their terminal steps back through the fog, beyond the first two optical depths (_terminal_step)."""
    plume = case.startswith("plume")
    extra = {} if plume else {"multiple_scattering": False, "surface": "lambertian"}
    if case.endswith("8 probes"):
        extra = {"n_probe": 8}  # MarchSettings.n_probe reaches both kernels (test_probe_count_places_the_steps)
    if case.endswith("cell crossed"):
        # rays across more than 4 cells take their own probe counts: per ray (numba), by a per-chunk maximum of
        # padded probes (JAX); both must place the same steps (test_probe_spacing_follows_the_cells_crossed)
        extra = {"n_probe": 4, "probe_spacing": 1.0}
    if "empty steps" in case:
        # few steps in empty space, more for rays across many empty cells: per ray in both kernels
        # (test_empty_steps_thin_out_the_steps_in_empty_space); without refinement the JAX kernel masks the steps
        # beyond each ray's count in its plain step loop (_march_segment) instead of its refined one
        extra = {"empty_steps": 4, "n_probe": 16, **({"tau_refine": 0.0} if case.endswith("no refinement") else {})}
    scene = _tiny_scene(plume)
    if case.startswith("fog"):
        extra = {"n_grid": 8}
        fog = 4e-4 * np.exp(-((scene["height"] - scene["terrain_height"]) / 150.0) ** 2)  # tau ~10 per 100 m
        scene["cloud_liquid_content"] = scene["cloud_liquid_content"] + fog.transpose(*scene["cloud_liquid_content"].dims)
    origins, dirs = _random_rays(600)
    sun = enu_from_azimuth_zenith(135.0, 40.0)
    aerosol = AerosolBackground(stratospheric_aod_550=0.2)
    out = {backend: _trace(scene, origins, dirs, sun, aerosol=aerosol,
                           settings=MarchSettings(**extra, execution=ExecutionSettings(backend=backend)))[0]
           for backend in ("jax", "numba")}
    jax_out, numba_out = out["jax"], out["numba"]
    assert jax_out["surface"].sum() > 100 and (jax_out["tau_hydrometeor"] > 1.0).sum() > 30, "rays must hit ground and cloud"
    np.testing.assert_array_equal(numba_out["surface"], jax_out["surface"])
    for key in ("radiance", "radiance_clear", "radiance_cloud", "radiance_surface", "tau_clear", "tau_hydrometeor"):
        # in the fog the refined crossing, which both kernels find to ~1 m (float32 and float64 positions 20-30 km
        # from the vantage), moves the fog's optical depth by up to ~0.1 m-1 x its difference
        rtol = 1e-3 if key == "tau_hydrometeor" and case.startswith("fog") else 2e-4
        np.testing.assert_allclose(numba_out[key], jax_out[key], rtol=rtol, atol=1e-6, err_msg=key)
    np.testing.assert_allclose(numba_out["distance"], jax_out["distance"], rtol=1e-4, atol=0.5)  # NaN where no ground


@pytest.mark.full  # numba against the JAX kernel: the JAX programs' compilation, the full tier
def test_chunks_without_ground_compose_without_its_term():
    """The numba path composes a chunk in which no ray ends on the ground without the ground's term (a second
    compiled version of the composition); the JAX kernel always evaluates it. Rays that look up from 1 km above the
    cloud's centre (chunks of them alone) and random rays (chunks with ground) must agree in both."""
    rng = np.random.default_rng(5)
    n_up = 320
    up = np.array([enu_from_azimuth_zenith(a, z) for a, z in zip(rng.uniform(0, 360, n_up), rng.uniform(0, 60, n_up))])
    below_cloud = np.array([300.0, -200.0, EARTH_RADIUS_M + 1000.0])
    others = _random_rays(600)
    origins = np.concatenate([np.repeat(below_cloud[None], n_up, axis=0), others[0]])
    dirs = np.concatenate([up, others[1]])
    sun = enu_from_azimuth_zenith(135.0, 40.0)
    out = {backend: _trace(_tiny_scene(), origins, dirs, sun,
                           settings=MarchSettings(execution=ExecutionSettings(backend=backend, chunk=64)))[0]
           for backend in ("jax", "numba")}
    assert not out["numba"]["surface"][:n_up].any() and out["numba"]["surface"][n_up:].sum() > 100
    assert (out["numba"]["tau_hydrometeor"][:n_up] > 1.0).sum() > 10, "upward rays must cross cloud"
    np.testing.assert_array_equal(out["numba"]["radiance_surface"][:n_up], 0.0)
    for key in ("radiance", "radiance_cloud", "radiance_surface"):
        np.testing.assert_allclose(out["numba"][key], out["jax"][key], rtol=2e-4, atol=1e-6, err_msg=key)


@pytest.mark.full  # numba against the JAX kernel: the JAX programs' compilation, the full tier
@pytest.mark.parametrize("looking_down", [40, 700], ids=["few rays on the ground", "most rays on the ground"])
def test_the_grounds_term_of_a_chunk_with_ground_rays_matches_the_jax_kernel(monkeypatch, looking_down):
    """The numba path composes the clouds and, for chunks that have rays on the ground, the ground's term in numba:
    few or most of a chunk's rays, spread over it, must give the JAX kernel's pixels (the ground's term only where a
    ray ends on the ground)."""
    monkeypatch.setenv("SWIM_NUM_THREADS", "1")  # one chunk
    rng = np.random.default_rng(11)
    n = 900
    zenith = np.where(np.arange(n) < looking_down, rng.uniform(100.0, 170.0, n), rng.uniform(0.0, 70.0, n))
    dirs = np.array([enu_from_azimuth_zenith(a, z) for a, z in zip(rng.uniform(0, 360, n), zenith)])
    order = rng.permutation(n)  # the rays on the ground spread over the chunk
    dirs = dirs[order]
    origins = np.repeat(np.array([[0.0, 0.0, EARTH_RADIUS_M + 3000.0]]), n, axis=0)
    sun = enu_from_azimuth_zenith(135.0, 40.0)
    out = {backend: _trace(_tiny_scene(), origins, dirs, sun,
                           settings=MarchSettings(execution=ExecutionSettings(backend=backend)))[0]
           for backend in ("jax", "numba")}
    on_ground = out["numba"]["surface"]
    assert looking_down * 0.9 <= on_ground.sum() <= looking_down
    np.testing.assert_array_equal(on_ground, out["jax"]["surface"])
    assert np.all(out["numba"]["radiance_surface"][on_ground] > 0) and np.all(out["numba"]["radiance_surface"][~on_ground] == 0)
    for key in ("radiance", "radiance_surface"):
        np.testing.assert_allclose(out["numba"][key], out["jax"][key], rtol=2e-4, atol=1e-6, err_msg=key)


@pytest.mark.full  # parity with the JAX kernel's set-up: the full tier, as the kernels' parity
@pytest.mark.parametrize("plume", [True, False], ids=["five aerosol classes", "one class"])
@pytest.mark.parametrize("sun_zenith", [40.0, 93.0], ids=["day", "twilight"])
def test_numba_set_up_matches_the_jax_set_up(plume, sun_zenith):
    """The per-ray set-up of the CPU kernel (swim.rt.march_cpu.prepare_rays) is swim.rt.march_jax._prepare_rays written
    again: the same aerosol column class and the same diffuse-source profiles at each ray's lowest point, to
    float32 round-off (the JAX function computes in float32), for rays from the ground, inside the grid and above,
    by day and with the sun below the horizon (the tables' twilight rows)."""
    import jax

    from swim.rt import march_cpu
    from swim.rt.march import _numba_tables
    from swim.rt.march_jax import _prepare_rays

    scene = _tiny_scene(plume)
    sun = enu_from_azimuth_zenith(135.0, sun_zenith)
    volume = build_optical_volume(scene)
    aer3d = volume["aerosol_extinction"].mean(dim=("y", "x")).values.astype(float)
    levels = float(volume.attrs["z_bottom"]) + float(volume.attrs["dz"]) * np.arange(aer3d.size)
    classes = aerosol_column_classes(aerosol_column_optical_depth(volume).values) if plume else None
    gas = build_gas_tables(AerosolBackground(stratospheric_aod_550=0.2),
                           scene_aerosol_profile=(levels, aer3d) if plume else None, aerosol_class_aod=classes)
    consts = kernel_constants(volume, solar_transmittance(volume, sun), gas, sun)
    origins, dirs = _random_rays(900, seed=4)
    seg = ray_segments(origins, dirs, grid_geometry(volume), top=float(consts["top"]))
    f32 = [np.asarray(a, np.float32) for a in (seg["start"], dirs, seg["bounds"])]
    (lower_jax, weight_jax), ms_jax = jax.device_get(
        jax.jit(_prepare_rays, static_argnames="settings")(*f32, consts, MarchSettings()))
    tables = _numba_tables(consts)
    n = len(dirs)
    lower, weight = np.empty(n, np.int32), np.empty(n)
    ms = np.full((9, n, tables["n_u"]), np.nan, np.float32)
    march_cpu.prepare_rays(seg["start"], dirs, seg["bounds"], tables["p"], tables["coef"], tables["aerosol_column"],
                           tables["class_aod"], tables["ms_source"], True, lower, weight, ms)
    if plume:
        assert len(tables["class_aod"]) == 5 and len(np.unique(lower)) >= 3, "the rays must see several classes"
    else:
        assert not lower.any() and not weight.any()
    same = lower == lower_jax  # float32 and float64 may put a column on either side of a class boundary
    assert same.mean() > 0.99
    np.testing.assert_allclose(weight[same], weight_jax[same, 0], atol=1e-5)
    assert np.all(np.isfinite(ms)) and ms.max() > (0.1 if sun_zenith < 90 else 1e-3)
    np.testing.assert_allclose(ms[:, same], ms_jax[:, same], rtol=1e-4, atol=1e-6 * ms_jax.max())
    # without the multiple-scattering source only the classes are written
    untouched = np.full((9, 1, 2), -1.0, np.float32)
    march_cpu.prepare_rays(seg["start"], dirs, seg["bounds"], tables["p"], tables["coef"], tables["aerosol_column"],
                           tables["class_aod"], tables["ms_source"], False, lower, weight, untouched)
    assert np.all(untouched == -1.0) and np.array_equal(lower[same], lower_jax[same])


@pytest.mark.parametrize("backend", [pytest.param("jax", marks=pytest.mark.full), "numba"])
def test_rays_that_do_not_look_down_stop_in_opaque_cloud_with_the_same_radiance(backend):
    """MarchSettings.stop_tau: a ray that does not look down stops where its hydrometeor optical depth passes 50.
    Against the same rays marched to their ends (``stop_tau=0``): every radiance the same (what lies behind
    reaches the observer through e^-50, and Eq. 14's c1 = e^-(tau/10)^2 leaves the cloud radiance seen from below
    independent of tau), the optical depth 50 where it was larger, no ground seen behind it, fewer samples; rays
    that look down unchanged (their cloud-top reflection, Eqs. 24-26, needs the whole optical depth)."""
    origins, dirs = _random_rays(600, seed=3)
    sun = enu_from_azimuth_zenith(135.0, 40.0)
    scene = _tiny_scene()
    scene["cloud_liquid_content"] = scene["cloud_liquid_content"] * 8.0  # more rays through opaque cloud
    stop, full = (_trace(scene, origins, dirs, sun,
                         settings=MarchSettings(stop_tau=tau, execution=ExecutionSettings(backend=backend)))[0]
                  for tau in (50.0, 0.0))
    up = dirs[:, 2] >= 0
    opaque = up & (full["tau_hydrometeor"] > 50.0 * 1.05)
    assert opaque.sum() >= 10 and (up & ~opaque).sum() >= 50, "rays must cross opaque cloud and miss it"
    for key in ("radiance", "radiance_clear", "radiance_cloud", "radiance_surface"):
        np.testing.assert_allclose(stop[key], full[key], rtol=1e-5, atol=1e-9, err_msg=key)
    np.testing.assert_array_equal(stop["tau_hydrometeor"][opaque], 50.0)
    assert np.all(stop["tau_hydrometeor"][up] <= 50.0)
    assert not stop["surface"][opaque].any()
    for key in ("tau_hydrometeor", "surface"):
        np.testing.assert_array_equal(stop[key][~up], full[key][~up], err_msg=key)
    if backend == "numba":  # the lockstep kernel takes every step of every ray
        assert np.all(stop["steps"][opaque] < full["steps"][opaque])
        calm = ~up | (full["tau_hydrometeor"] <= 50.0)  # rays that cannot have stopped
        np.testing.assert_array_equal(stop["steps"][calm], full["steps"][calm])


@pytest.mark.full  # numba against the JAX kernel: the JAX programs' compilation, the full tier
def test_per_ray_kernel_counts_the_samples_each_ray_takes():
    """``steps``: the numba kernel counts the samples each ray takes, the lockstep JAX kernel every step of every
    ray. Without refinement and without the empty-space limit a ray that never meets the ground takes every step
    of its segments (one for a segment of zero length); one that meets it stops there (and takes its terminal
    steps), and one that ends on the sea-level sphere takes one more, of zero length there (the end step). Refined
    halves add samples, and the empty-space limit takes samples off rays through clear air. A ray that rises out of
    the grid takes its own count of clear-air steps after it (after_step_counts). Rays do not stop in opaque cloud
    here (``stop_tau=0``)."""
    import jax.numpy as jnp

    from swim.rt.march_jax import after_step_counts

    origins, dirs = _random_rays(300)
    sun = enu_from_azimuth_zenith(135.0, 40.0)
    scene = _tiny_scene()
    plain = MarchSettings(tau_refine=0.0, empty_steps=0, stop_tau=0)
    out = {backend: _trace(scene, origins, dirs, sun, settings=plain.with_execution(backend=backend))
           for backend in ("jax", "numba")}
    (jax_out, _), (numba_out, (volume, transmittance, gas, _)) = out["jax"], out["numba"]
    nominal = plain.n_before + plain.n_grid + plain.n_after + 1  # the end step
    np.testing.assert_array_equal(jax_out["steps"], nominal)
    consts = kernel_constants(volume, transmittance, gas, sun)
    seg = ray_segments(origins, dirs, grid_geometry(volume), top=float(consts["top"]))
    bounds = np.asarray(seg["bounds"])
    lengths = np.stack([bounds[:, 0], bounds[:, 1] - bounds[:, 0], bounds[:, 2] - bounds[:, 1]], axis=1)
    after = np.asarray(after_step_counts(jnp.asarray(seg["start"], jnp.float32), jnp.asarray(dirs, jnp.float32),
                                         jnp.asarray(bounds, jnp.float32), plain.n_after, consts))
    rises = lengths[:, 2] > 0
    assert (after[rises] < plain.n_after).sum() > 30 and (after[rises] == plain.n_after).sum() > 30
    per_segment = np.stack([np.full(len(dirs), plain.n_before), np.full(len(dirs), plain.n_grid), after], axis=1)
    full = np.where(lengths > 0, per_segment, 1).sum(axis=1)
    ground = numba_out["surface"]
    assert 30 < ground.sum() < 270, "rays must both meet the ground and miss it"
    np.testing.assert_array_equal(numba_out["steps"][~ground], full[~ground])
    # a ray whose segments end at the ground meets it in its last step or its end step; one that meets the terrain
    # stops early; both then take one or two terminal steps, up to the crossing (swim.rt.march_jax._terminal_step)
    assert np.all((numba_out["steps"][ground] >= 1) & (numba_out["steps"][ground] <= full[ground] + 3))
    assert (numba_out["steps"][ground] < full[ground]).sum() > 10

    refined, _ = _trace(scene, origins, dirs, sun, settings=replace(plain, backend="numba", tau_refine=0.1))
    both = ~ground & ~refined["surface"]
    more = refined["steps"][both] - numba_out["steps"][both]
    assert np.all(more >= 0) and (more > 0).sum() >= 5, "refined halves are samples too"
    skipping, _ = _trace(scene, origins, dirs, sun, settings=replace(plain, backend="numba", empty_steps=8))
    both = ~ground & ~skipping["surface"]
    fewer = numba_out["steps"][both] - skipping["steps"][both]
    assert np.all(fewer >= 0) and (fewer > 0).sum() >= 5, "empty space costs fewer samples"


def test_backend_setting_is_checked_and_resolved(monkeypatch):
    import jax

    from swim.rt import march_settings

    with pytest.raises(SwimInputError, match="ExecutionSettings.backend"):
        MarchSettings(execution=ExecutionSettings(backend="opencl"))
    assert MarchSettings(execution=ExecutionSettings(backend="jax")).resolved_backend() == "jax"
    expected = "numba" if jax.default_backend() == "cpu" else "jax"
    assert MarchSettings().resolved_backend() == expected
    monkeypatch.setattr(march_settings, "_numba_available", lambda: False)
    assert MarchSettings().resolved_backend() == "jax"
    origins, dirs = _random_rays(3)
    with pytest.raises(SwimInputError, match="needs the numba package"):
        _trace(_tiny_scene(), origins, dirs, enu_from_azimuth_zenith(135.0, 40.0),
               settings=MarchSettings(execution=ExecutionSettings(backend="numba")))


def test_chunk_follows_the_device_unless_given(monkeypatch):
    import jax

    from swim.rt import march_settings

    assert MarchSettings(execution=ExecutionSettings(chunk=1000)).resolved_chunk() == 1000
    on_cpu = jax.default_backend() == "cpu"
    assert MarchSettings().resolved_chunk() == (march_settings.CPU_CHUNK if on_cpu else march_settings.GPU_CHUNK)
    from swim.rt import precompile

    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    # JAX is asked for its device only where it may see one (a GPU plugin installed)
    monkeypatch.setattr(precompile, "jax_may_see_a_gpu", lambda: False)
    assert MarchSettings().resolved_chunk() == march_settings.CPU_CHUNK
    monkeypatch.setattr(precompile, "jax_may_see_a_gpu", lambda: True)
    assert MarchSettings().resolved_chunk() == march_settings.GPU_CHUNK  # the JAX kernel on a GPU: big chunks
    assert MarchSettings().on_accelerator()
    assert MarchSettings(execution=ExecutionSettings(backend="jax")).on_accelerator()
    # numba runs on the host's cores
    assert MarchSettings(execution=ExecutionSettings(backend="numba")).resolved_chunk() == march_settings.CPU_CHUNK
    assert not MarchSettings(execution=ExecutionSettings(backend="numba")).on_accelerator()
    assert MarchSettings(execution=ExecutionSettings(chunk=8192)).resolved_chunk() == 8192
    monkeypatch.setattr(jax, "default_backend", lambda: "cpu")
    assert MarchSettings(execution=ExecutionSettings(backend="jax")).resolved_chunk() == march_settings.CPU_CHUNK
    assert not MarchSettings(execution=ExecutionSettings(backend="jax")).on_accelerator()


def test_the_grid_loop_unrolled_gives_the_same_state(monkeypatch):
    """The lockstep grid loop with 2 or 3 iterations per test of its condition (as on a GPU) leaves every ray as one
    iteration per test does: an iteration leaves a finished ray unchanged. A toy medium whose slab faces fall inside
    steps makes the rays split steps and roll back; its optical depth is then closer to the slab's than the midpoint
    rule's without refinement."""
    import jax
    import jax.numpy as jnp

    from swim.rt import march_jax, march_settings

    n, n_steps, length, beta = 64, 16, 16.0, 0.6
    rng = np.random.default_rng(4)
    a = rng.uniform(0.3, 8.0, n).astype(np.float32)  # each ray's slab [a, b] [m], faces off the steps' edges
    b = (a + rng.uniform(1.5, 6.0, n)).astype(np.float32)
    edges = jnp.asarray(np.linspace(0.0, length, n_steps + 1, dtype=np.float32)[:, None].repeat(n, 1))
    steps = jnp.asarray(rng.integers(n_steps // 2, n_steps + 1, n).astype(np.int32))  # rays' own step counts

    def sample(st, s_lo, ds):
        s = s_lo + 0.5 * ds
        beta_h = jnp.where((s >= a) & (s <= b), beta, 0.0).astype(jnp.float32)
        return {"tau_h": st["tau_h"] + beta_h * ds, "alive": st["alive"], "calls": st["calls"] + 1}, beta_h

    state = {"tau_h": jnp.zeros(n, jnp.float32), "alive": jnp.ones(n, bool), "calls": jnp.zeros(n, jnp.int32)}

    def march_with(unroll):
        run = jax.jit(lambda st, e, k: march_jax._march_grid_refined(st, sample, e, n_steps, 0.25, k, unroll=unroll))
        return {key: np.asarray(value) for key, value in run(state, edges, steps).items()}

    one, two, three = march_with(1), march_with(2), march_with(3)
    for key in one:
        np.testing.assert_array_equal(two[key], one[key], err_msg=key)
        np.testing.assert_array_equal(three[key], one[key], err_msg=key)
    # against the slab's optical depth: closer than the midpoint rule's without refinement
    ends = np.asarray(edges)[np.asarray(steps), 0]
    exact = beta * np.clip(np.minimum(b, ends) - a, 0.0, None)
    mid = (np.arange(n_steps) + 0.5) * (length / n_steps)
    inside = (mid[:, None] >= a) & (mid[:, None] <= b) & (np.arange(n_steps)[:, None] < np.asarray(steps))
    plain = beta * (length / n_steps) * inside.sum(axis=0)
    assert one["calls"].max() > n_steps and np.all(one["calls"] >= np.asarray(steps))  # refinements were taken
    assert np.abs(one["tau_h"] - exact).mean() < 0.5 * np.abs(plain - exact).mean()
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    assert march_jax.grid_loop_unroll() == march_settings.GRID_LOOP_UNROLL_ACCELERATOR
    monkeypatch.setattr(jax, "default_backend", lambda: "cpu")
    assert march_jax.grid_loop_unroll() == 1


@pytest.mark.parametrize("thickness", [0.3, 0.4, 0.45])
def test_a_step_after_a_thick_one_is_halved_before_it_is_sampled(monkeypatch, thickness):
    """Predicted halving (``march_jax._predicted_halving``): inside a uniform cloud whose grid steps are each ``thickness``
    (> tau_refine 0.25, < twice it) thick, the first step is sampled, found too thick and halved (3 samples: the
    discarded one and its two halves); every later step follows an accumulated interval whose extinction predicts it
    too thick, so it is halved before any sample (2 samples), where without the prediction it takes 3. Where a ray
    enters the cloud from clear air, nothing predicts: the clear interval before the face is rolled back and halved,
    and the first cloud step halved after its sample, as before. At the far face the clear step is halved before its
    sample, where the change of extinction would have halved it after. The same intervals are accumulated either
    way, so the optical depth and the sum of the samples' distances times lengths agree."""
    import jax
    import jax.numpy as jnp

    from swim.rt import march_jax

    n_steps, ds = 8, 10.0
    beta = thickness / ds
    edges = jnp.asarray(np.arange(n_steps + 1, dtype=np.float32)[:, None].repeat(3, 1) * ds)
    # ray 0: cloud everywhere; ray 1: clear for 3 steps, then cloud; ray 2: cloud for 4 steps, then clear
    lo = jnp.asarray([0.0, 3 * ds, 0.0], jnp.float32)
    hi = jnp.asarray([1e9, 1e9, 4 * ds], jnp.float32)

    samples = np.zeros(3, int)  # every sample, the discarded ones too (the state keeps only the accumulated ones)

    def count(ds_):
        samples[:] += np.asarray(ds_) > 0  # a finished ray's iterations sample nothing (ds 0)

    def sample(st, s_lo, ds_):
        jax.debug.callback(count, ds_, ordered=True)
        s = s_lo + 0.5 * ds_
        beta_h = jnp.where((s >= lo) & (s <= hi), beta, 0.0).astype(jnp.float32)
        return {"tau_h": st["tau_h"] + beta_h * ds_, "alive": st["alive"], "moment": st["moment"] + s * ds_}, beta_h

    state = {"tau_h": jnp.zeros(3, jnp.float32), "alive": jnp.ones(3, bool), "moment": jnp.zeros(3, jnp.float32)}

    def run():
        samples[:] = 0
        out = march_jax._march_grid_refined(state, sample, edges, n_steps, 0.25, unroll=1)
        jax.effects_barrier()
        return {key: np.asarray(value) for key, value in out.items()}, samples.copy()

    predicted, with_prediction = run()
    monkeypatch.setattr(march_jax, "_predicted_halving", lambda adjacent, *args: jnp.zeros_like(adjacent))
    tested, without = run()
    # ray 1: 3 clear steps, the roll-back (1 discarded, 2 clear halves), the first cloud step (1 + 2), 4 cloud steps;
    # ray 2: 4 cloud steps, the clear step after them halved (1 + 2 or 2), 3 clear steps
    np.testing.assert_array_equal(without, [3 * n_steps, 3 + 3 + 3 + 3 * 4, 3 * 4 + 3 + 3])
    np.testing.assert_array_equal(with_prediction, [3 + 2 * (n_steps - 1), 3 + 3 + 3 + 2 * 4, 3 + 2 * 3 + 2 + 3])
    np.testing.assert_allclose(predicted["tau_h"], [thickness * n_steps, thickness * 5, thickness * 4], rtol=1e-6)
    np.testing.assert_allclose(predicted["tau_h"], tested["tau_h"], rtol=1e-6)
    # the same intervals in the cloud; the far face's clear step halved (its two halves' sum equals the step's)
    np.testing.assert_allclose(predicted["moment"], tested["moment"], rtol=1e-6)


def _grid_samples_of_both_kernels(monkeypatch, scene, largest_zenith, **settings):
    """240 rays up from the ground and from inside the cloud (view zenith up to ``largest_zenith``) through ``scene``,
    without clear air before or after the grid: the lockstep JAX kernel's grid samples per ray (of nonzero length,
    counted through a callback around the grid march's sample function, its uncached program), and the outputs of
    both kernels (numba's ``steps`` is then its grid's count, with a terminal step at the ground)."""
    import jax

    from swim.rt import march_jax

    rng = np.random.default_rng(11)
    n = 240
    azimuth, zenith = rng.uniform(0.0, 360.0, n), rng.uniform(0.0, largest_zenith, n)
    dirs = np.array([enu_from_azimuth_zenith(a, z) for a, z in zip(azimuth, zenith)])
    origins = np.where((np.arange(n) % 2 == 0)[:, None], [[0.0, 0.0, EARTH_RADIUS_M + 20.0]],
                       [[200.0, -300.0, EARTH_RADIUS_M + 1800.0]])
    sun = enu_from_azimuth_zenith(135.0, 40.0)
    settings = dict(n_before=0, n_after=0, chunk=256, **settings)
    counts = np.zeros(256, int)

    def count(ds):
        counts[:ds.shape[0]] += np.asarray(ds) > 0

    refined = march_jax._march_grid_refined

    def counting(state, sample, *args, **kwargs):
        def counted(st, lo, ds):
            jax.debug.callback(count, ds, ordered=True)
            return sample(st, lo, ds)
        return refined(state, counted, *args, **kwargs)

    monkeypatch.setattr(march_jax, "_march_grid_refined", counting)
    monkeypatch.setattr(march_jax, "_trace_chunk", jax.jit(march_jax._trace_chunk.function, static_argnames=("settings",)))
    jax_out = _trace(scene, origins, dirs, sun, settings=MarchSettings(**settings,
                                                                       execution=ExecutionSettings(backend="jax")))[0]
    jax.effects_barrier()
    numba_out = _trace(scene, origins, dirs, sun,
                       settings=MarchSettings(**settings, execution=ExecutionSettings(backend="numba")))[0]
    return counts[:n].copy(), jax_out, numba_out


@pytest.mark.full
def test_numba_and_jax_refine_alike_sample_by_sample(monkeypatch):
    """The numba kernel and the lockstep JAX kernel take the same samples per ray in the grid: the same halvings,
    predicted halvings and roll-backs (equal results do not show that: where a prediction is right, the accumulated
    intervals are the same as without it). No stop in opaque cloud here."""
    jax_steps, jax_out, numba_out = _grid_samples_of_both_kernels(monkeypatch, _tiny_scene(), 70.0, stop_tau=0.0)
    numba_steps = np.asarray(numba_out["steps"])
    assert numba_steps.min() > 0 and numba_steps.max() > 128  # the rays refined in the cloud
    same = jax_steps == numba_steps
    assert same.mean() >= 0.95, (same.mean(), np.flatnonzero(~same)[:10])
    assert abs(int(jax_steps.sum()) - int(numba_steps.sum())) <= 0.005 * numba_steps.sum()
    np.testing.assert_allclose(jax_out["tau_hydrometeor"], numba_out["tau_hydrometeor"], rtol=2e-3, atol=1e-3)


@pytest.mark.full
def test_a_stopped_ray_samples_no_more_in_jax_than_in_numba(monkeypatch):
    """A ray that stops (in opaque cloud, or at the ground) leaves the JAX kernel's grid loop, as it leaves numba's:
    the rays stopped in opaque cloud take the same grid samples in both kernels, and those at the ground as many
    but numba's terminal steps (up to 3), instead of going on to their last grid step (50-105 samples more here),
    where their later samples would add nothing (docs/decisions/0006-gpu-kernels.md)."""
    jax_steps, jax_out, numba_out = _grid_samples_of_both_kernels(monkeypatch, _tiny_scene(True), 150.0,
                                                                  stop_tau=40.0)
    numba_steps = np.asarray(numba_out["steps"])
    surface = np.asarray(numba_out["surface"])
    stopped = (np.asarray(numba_out["tau_hydrometeor"]) >= 40.0 - 1e-3) & ~surface
    assert stopped.sum() >= 20 and surface.sum() >= 10, (stopped.sum(), surface.sum())
    np.testing.assert_array_equal(np.asarray(jax_out["surface"]), surface)
    np.testing.assert_array_equal(jax_steps[stopped], numba_steps[stopped])
    extra = numba_steps[surface] - jax_steps[surface]
    assert extra.min() >= 0 and extra.max() <= 3, np.unique(extra)
    np.testing.assert_allclose(jax_out["tau_hydrometeor"], numba_out["tau_hydrometeor"], rtol=2e-3, atol=1e-3)


@pytest.mark.full  # numba against the JAX kernel: the JAX programs' compilation, the full tier
@pytest.mark.parametrize("chunk", [64, 256])
def test_jax_chunks_dispatched_ahead_give_the_rays_of_one_call(chunk):
    """The JAX kernel marches a chunk on a worker thread while the next is prepared (outputs collected one chunk
    behind): several chunks, a short last one among them, give the same rays in the same order as one big call."""
    origins, dirs = _random_rays(600, seed=3)
    sun = enu_from_azimuth_zenith(135.0, 40.0)
    one = _trace(_tiny_scene(), origins, dirs, sun, settings=MarchSettings(execution=ExecutionSettings(backend="jax",
                                                                                                       chunk=1024)))[0]
    many = _trace(_tiny_scene(), origins, dirs, sun, settings=MarchSettings(execution=ExecutionSettings(backend="jax",
                                                                                                        chunk=chunk)))[0]
    for key in ("radiance", "tau_hydrometeor", "surface"):
        np.testing.assert_allclose(many[key], one[key], rtol=1e-5, atol=1e-7, err_msg=key)


@pytest.mark.full  # the JAX kernel's programs compile for tens of seconds on an empty cache: the full tier
def test_a_jax_chunk_s_error_reaches_the_caller_and_the_next_call_works(monkeypatch):
    """The JAX kernel's chunks run on a worker thread: an error in one of them is raised by trace_rays itself (not
    lost in the thread, no partial output), and the next call, on the same worker, traces every ray."""
    from swim.rt import march_jax

    origins, dirs = _random_rays(300, seed=5)
    sun = enu_from_azimuth_zenith(135.0, 40.0)
    settings = MarchSettings(execution=ExecutionSettings(backend="jax", chunk=64))
    plain, calls = march_jax._trace_chunk, []

    def failing(*args, **kwargs):
        calls.append(threading.current_thread().name)
        if len(calls) == 2:
            raise FloatingPointError("chunk 2 failed")
        return plain(*args, **kwargs)

    monkeypatch.setattr(march_jax, "_trace_chunk", failing)
    with pytest.raises(FloatingPointError, match="chunk 2 failed"):
        _trace(_tiny_scene(), origins, dirs, sun, settings=settings)
    assert all(name.startswith("swim-worker") for name in calls)
    monkeypatch.setattr(march_jax, "_trace_chunk", plain)
    out = _trace(_tiny_scene(), origins, dirs, sun, settings=settings)[0]
    assert out["radiance"].shape == (300, 3) and np.all(np.isfinite(out["radiance"]))


@pytest.mark.parametrize("threads, n_levels", [(1, 5), (3, 7), (4, 2), (8, 160)])
def test_level_blocks_cover_every_level_once_and_raise_a_block_s_error(monkeypatch, threads, n_levels):
    from swim.workers import in_blocks

    monkeypatch.setenv("SWIM_NUM_THREADS", str(threads))
    seen = np.zeros(n_levels, int)

    def fill(k0, k1):
        seen[k0:k1] += 1

    in_blocks(fill, n_levels)
    np.testing.assert_array_equal(seen, 1)

    def broken(k0, k1):
        if k0 > 0 or threads == 1:
            raise ValueError("block failed")

    with pytest.raises(ValueError, match="block failed"):
        in_blocks(broken, n_levels)


def test_optimisation_barriers_only_on_cpus(monkeypatch):
    """The kernel's optimisation barriers (``_materialise``) keep XLA on a CPU from repeating gathers; on a GPU
    they are left out (18 % faster on an H100): the values are the same either way."""
    import jax
    import jax.numpy as jnp

    from swim.rt import march_jax

    x = (jnp.arange(4.0), jnp.ones(3))
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    assert march_jax._materialise(x) is x
    monkeypatch.setattr(jax, "default_backend", lambda: "cpu")
    barrier = jax.make_jaxpr(march_jax._materialise)(x)
    assert "optimization_barrier" in str(barrier)
    for a, b in zip(march_jax._materialise(x), x):
        np.testing.assert_array_equal(a, b)


@pytest.mark.full  # the JAX kernel's helper, its numba twin held to it here: the full tier (its JAX programs)
@pytest.mark.parametrize("shape", [(5, 6, 7, 9), (2, 2, 2, 7), (3, 40, 2, 1)])
def test_trilinear_reads_rows_on_cpus_and_scalars_elsewhere_with_the_same_values(monkeypatch, shape):
    import jax
    import jax.numpy as jnp

    from swim.rt.march_jax import trilinear

    rng = np.random.default_rng(sum(shape))
    volume = rng.random(shape).astype(np.float32)
    k, j, i = (rng.uniform(-0.7, n - 0.3, 500) for n in shape[:3])  # some points beyond the volume
    outside = rng.random(shape[3]).astype(np.float32)
    # test-side trilinear interpolation, clamped to the edge cells, ``outside`` beyond the volume
    expected = np.empty((500, shape[3]))
    for p in range(500):
        idx = [min(max(int(np.floor(x)), 0), n - 2) for x, n in zip((k[p], j[p], i[p]), shape)]
        w = [min(max(x - i0, 0.0), 1.0) for x, i0 in zip((k[p], j[p], i[p]), idx)]
        corners = volume[idx[0]:idx[0] + 2, idx[1]:idx[1] + 2, idx[2]:idx[2] + 2]
        expected[p] = np.einsum("a,b,c,abcn->n", [1 - w[0], w[0]], [1 - w[1], w[1]], [1 - w[2], w[2]], corners)
        if not all(0 <= x <= n - 1 for x, n in zip((k[p], j[p], i[p]), shape)):
            expected[p] = outside
    args = [jnp.asarray(volume)] + [jnp.asarray(x, jnp.float32) for x in (k, j, i)] + [jnp.asarray(outside)]
    for backend in ("cpu", "gpu"):
        monkeypatch.setattr(jax, "default_backend", lambda: backend)
        np.testing.assert_allclose(np.asarray(trilinear(*args)), expected, rtol=2e-5, atol=2e-6, err_msg=backend)


def test_no_rays_is_a_clear_error():
    with pytest.raises(SwimInputError, match="at least one ray"):
        _trace(_tiny_scene(), np.zeros((0, 3)), np.zeros((0, 3)), enu_from_azimuth_zenith(135.0, 40.0))


@pytest.mark.parametrize("backend", ["jax", "numba"])
def test_non_finite_rays_are_rejected_before_the_kernel(backend):
    origins, dirs = _random_rays(4)
    dirs[2, 0] = np.nan
    with pytest.raises(SwimInputError, match="directions must be a finite"):
        _trace(_tiny_scene(), origins, dirs, enu_from_azimuth_zenith(135.0, 40.0),
               settings=MarchSettings(execution=ExecutionSettings(backend=backend)))
    origins = origins.copy()
    origins[0, 2] = np.inf
    with pytest.raises(SwimInputError, match="origins must be a finite"):
        _trace(_tiny_scene(), origins, np.nan_to_num(dirs), enu_from_azimuth_zenith(135.0, 40.0),
               settings=MarchSettings(execution=ExecutionSettings(backend=backend)))


@pytest.mark.parametrize("aerosol_plume", [False, True], ids=["no 3-D aerosol", "smoke plume"])
def test_packed_volume_is_one_host_array_without_empty_channels(aerosol_plume):
    """The packed volume is held once, as a read-only numpy array (the numba kernel reads it in place), and
    without a 3-D aerosol its two all-zero channels are left out (docs/performance.md, "Memory"), as are the species
    that are zero everywhere (the tiny scene has cloud liquid and ice only; docs/decisions/0007-scene-set-up.md)."""
    from swim.rt.march_inputs import HOST_CONSTANTS, packed_species
    from swim.rt.march_jax import _device_constants

    scene = _tiny_scene(aerosol_plume)
    volume = build_optical_volume(scene)
    sun = enu_from_azimuth_zenith(135.0, 40.0)
    transmittance = solar_transmittance(volume, sun)
    consts = kernel_constants(volume, transmittance, build_gas_tables(AerosolBackground()), sun)
    packed = consts["volume"]
    assert isinstance(packed, np.ndarray) and not packed.flags.writeable
    extinction = volume["extinction"].values
    assert packed_species(volume) == (0, 1) and not np.any(extinction[2:]), "liquid and ice only"
    assert packed.shape == volume["extinction"].shape[1:] + (6 if aerosol_plume else 4,)
    np.testing.assert_array_equal(packed[..., :2], np.moveaxis(extinction[:2], 0, -1))
    np.testing.assert_array_equal(packed[..., -2], transmittance["cloud_transmittance"].values)
    np.testing.assert_array_equal(packed[..., -1], transmittance["terrain_shadow"].values)
    if aerosol_plume:
        np.testing.assert_array_equal(packed[..., 2], volume["aerosol_extinction"].values)
    # the kernels' per-species optical depths of the packed channels go back to their species' columns
    np.testing.assert_array_equal(np.asarray(consts["species_matrix"]), np.eye(5, dtype=np.float32)[:2])
    from swim.rt import device_copies

    device = _device_constants(consts)
    assert _device_constants(consts)["volume"] is device["volume"], "the device copy is made once per host array"
    for key in HOST_CONSTANTS:
        np.testing.assert_array_equal(np.asarray(device[key]), consts[key])
    # a new host array (another sun) gets its own copy; a freed one takes its copy with it
    replaced = dict(consts, volume=consts["volume"].copy())
    assert _device_constants(replaced)["volume"] is not device["volume"]
    del replaced, device
    import gc

    gc.collect()
    assert device_copies._DEVICE_COPIES == {}, "the device copies must go with their host volume"


def test_volume_shares_the_packed_channels_and_still_serves_a_new_sun():
    """render() points the optical volume's extinctions at the packed channels (one copy of the grid); the
    constants built again from that volume (another sun) must be those built from the original volume."""
    from swim.rt.march_inputs import share_packed_channels

    volume = build_optical_volume(_tiny_scene(aerosol_plume=True))
    original = {name: volume[name].values.copy() for name in ("extinction", "aerosol_extinction")}
    gas = build_gas_tables(AerosolBackground())
    sun_1, sun_2 = enu_from_azimuth_zenith(135.0, 40.0), enu_from_azimuth_zenith(250.0, 65.0)
    expected = kernel_constants(volume, solar_transmittance(volume, sun_2), gas, sun_2)["volume"].copy()
    consts = kernel_constants(volume, solar_transmittance(volume, sun_1), gas, sun_1)
    share_packed_channels(volume, consts["volume"])
    # the species that are zero everywhere (rain, snow, graupel) are not packed: the volume names the others
    assert list(volume["species"].values) == ["cloud_liquid", "cloud_ice"] and not np.any(original["extinction"][2:])
    original["extinction"] = original["extinction"][:2]
    for name, values in original.items():
        assert np.shares_memory(volume[name].values, consts["volume"]), name
        np.testing.assert_array_equal(volume[name].values, values, err_msg=name)
    again = kernel_constants(volume, solar_transmittance(volume, sun_2), gas, sun_2)["volume"]
    # Step 1a sums the species in float32 (swim.rt.solar_cpu.species_sums), here of the packed channels and there of
    # the volume's own (species, level, y, x) array: the same to float32 round-off
    np.testing.assert_allclose(again, expected, rtol=1e-6, atol=1e-7)
    assert np.array_equal(again[..., -1], expected[..., -1]), "the terrain shadow does not depend on the species"


@pytest.mark.parametrize("aerosol_plume", [False, True], ids=["no 3-D aerosol", "smoke plume"])
def test_packing_before_step_1a_gives_the_same_constants(aerosol_plume):
    """render() packs the grid and shares its channels before Step 1a (memory): Step 1a on the shared volume and
    the constants filled into that packed volume must equal those of the volume as built, packed after Step 1a."""
    from swim.rt.march_inputs import occupancy_grid, pack_volume, share_packed_channels, volume_constants

    sun = enu_from_azimuth_zenith(135.0, 40.0)
    volume = build_optical_volume(_tiny_scene(aerosol_plume))
    transmittance = solar_transmittance(volume, sun)
    expected = volume_constants(volume, transmittance)
    occupancy = occupancy_grid(volume)

    shared = build_optical_volume(_tiny_scene(aerosol_plume))
    packed = pack_volume(shared)
    assert packed.shape[-1] == (6 if aerosol_plume else 4)  # liquid, ice (+ 3-D aerosol, its tau to the sun), T, shadow
    share_packed_channels(shared, packed)
    assert np.shares_memory(shared["extinction"].values, packed)
    assert not shared["extinction"].values.flags.writeable, "the shared channels must be read-only views"
    again = solar_transmittance(shared, sun)
    # the species summed in float32 (swim.rt.solar_cpu.species_sums) over the packed channels and over the volume's
    # own array: the same to float32 round-off
    for name in transmittance.data_vars:
        np.testing.assert_allclose(again[name].values, transmittance[name].values, rtol=1e-6, atol=1e-7, err_msg=name)
    np.testing.assert_array_equal(again["terrain_shadow"].values, transmittance["terrain_shadow"].values)
    got = volume_constants(shared, again, occupancy=occupancy_grid(shared), packed=packed)
    assert got["volume"] is packed and not packed.flags.writeable
    np.testing.assert_allclose(got["volume"], expected["volume"], rtol=1e-6, atol=1e-7)
    # the step classes of this sun (march_inputs.step_classes): occupied where the occupancy grid is, the same sunlit air
    np.testing.assert_array_equal(got["occupancy"] > 0, occupancy > 0)
    np.testing.assert_array_equal(got["occupancy"], expected["occupancy"])


@pytest.mark.parametrize("aerosol_plume", [False, True], ids=["no 3-D aerosol", "smoke plume"])
def test_step_1a_written_into_the_packed_channels_gives_the_same_constants(aerosol_plume, monkeypatch):
    """A render has Step 1a write its fields straight into the packed volume's channels (step1a_channel_views, the
    ``out`` of solar_transmittance): every cell of those channels is written (also above the swept levels, where a
    refilled volume holds an earlier sun's values), volume_constants copies nothing, the JAX kernel's device copy of
    the earlier values is dropped, and the constants equal those of fields made and then copied (T to float32
    round-off: numba's float32 arithmetic against XLA's)."""
    from swim.rt import march_inputs, march_jax
    from swim.rt.march_inputs import (KERNEL_STEP1A_VARIABLES, pack_volume, packed_species, share_packed_channels,
                                      step1a_channel_views, volume_constants)

    sun_1, sun_2 = enu_from_azimuth_zenith(135.0, 40.0), enu_from_azimuth_zenith(250.0, 70.0)
    fresh_volume = build_optical_volume(_tiny_scene(aerosol_plume))
    expected = volume_constants(fresh_volume, solar_transmittance(fresh_volume, sun_2))

    volume = build_optical_volume(_tiny_scene(aerosol_plume))
    species = packed_species(volume)
    packed = pack_volume(volume, species)
    share_packed_channels(volume, packed, species)
    first = volume_constants(volume, solar_transmittance(volume, sun_1), packed=packed, species=species)
    on_device = march_jax._device_constants(first)["volume"]
    views = step1a_channel_views(packed, species)
    assert set(views) == set(KERNEL_STEP1A_VARIABLES if aerosol_plume else KERNEL_STEP1A_VARIABLES[1:])
    assert march_jax._device_constants(first)["volume"] is not on_device, "the old device copy must be dropped"
    for view in views.values():
        assert np.shares_memory(view, packed) and view.flags.writeable
        view[...] = np.nan  # whatever an earlier sun left there: every cell must be written again

    copies = []
    monkeypatch.setattr(march_inputs, "_fill_channels", lambda *args: copies.append(args))
    transmittance = solar_transmittance(volume, sun_2, variables=KERNEL_STEP1A_VARIABLES, out=views)
    for name, view in views.items():
        assert transmittance[name].values is view, name
    got = volume_constants(volume, transmittance, packed=packed, species=species)
    assert copies == [], "the fields are in place: nothing to copy"
    assert got["volume"] is packed and not packed.flags.writeable
    assert np.isfinite(packed).all()
    np.testing.assert_allclose(packed, expected["volume"], rtol=1e-6, atol=1e-7)
    np.testing.assert_array_equal(packed[..., :len(species)], expected["volume"][..., :len(species)])


@pytest.mark.parametrize("aerosol_plume", [False, True], ids=["no 3-D aerosol", "smoke plume"])
def test_a_new_sun_refills_the_shared_packed_volume(aerosol_plume):
    """shared_packed_volume finds the packed volume that a shared volume's extinctions view (None before sharing or
    for another layout); refilled with a second sun's Step 1a, it equals a volume packed anew for that sun, and the
    JAX kernel's device copy of the first sun's channels is dropped."""
    from swim.rt import march_jax
    from swim.rt.march_inputs import (pack_volume, packed_species, share_packed_channels, shared_packed_volume,
                                      volume_constants)
    from swim.rt.solar import step1a_levels

    sun_1, sun_2 = enu_from_azimuth_zenith(135.0, 40.0), enu_from_azimuth_zenith(250.0, 70.0)
    volume = build_optical_volume(_tiny_scene(aerosol_plume))
    species = packed_species(volume)
    assert shared_packed_volume(volume, species) is None  # the volume's own arrays
    packed = pack_volume(volume, species)
    share_packed_channels(volume, packed, species)
    assert shared_packed_volume(volume, species) is packed
    assert shared_packed_volume(volume, species[:-1]) is None  # not the layout of these species
    first = volume_constants(volume, solar_transmittance(volume, sun_1), packed=packed, species=species)
    on_device = march_jax._device_constants(first)["volume"]
    np.testing.assert_array_equal(np.asarray(on_device), packed)

    levels = step1a_levels(volume)
    assert levels[0].any() and levels[1].any() == aerosol_plume
    again = volume_constants(volume, solar_transmittance(volume, sun_2, nonzero_levels=levels),
                             packed=shared_packed_volume(volume, species), species=species)
    assert again["volume"] is packed and not packed.flags.writeable
    fresh_volume = build_optical_volume(_tiny_scene(aerosol_plume))
    fresh = volume_constants(fresh_volume, solar_transmittance(fresh_volume, sun_2), species=species)
    np.testing.assert_allclose(again["volume"], fresh["volume"], rtol=1e-6, atol=1e-7)
    # the second sun's T and terrain shadow differ from the first's device copy, which must not be served again
    assert not np.array_equal(np.asarray(on_device)[..., -2:], packed[..., -2:])
    np.testing.assert_array_equal(np.asarray(march_jax._device_constants(again)["volume"]), packed)
    with pytest.raises(SwimInputError, match="nonzero_levels"):
        solar_transmittance(volume, sun_2, nonzero_levels=(levels[0][:-1], levels[1]))


@pytest.mark.parametrize("backend", [pytest.param("jax", marks=pytest.mark.full), "numba"])
def test_species_that_are_zero_everywhere_are_left_out_of_the_packed_volume(backend):
    """Packing the species that are zero everywhere (rain, snow and graupel in the tiny scene) changes no output of
    either kernel: their channels only add zeros, and the per-species optical depths of the packed ones are put
    back in their species' columns (the composition's phase-function mixture reads them). The same to float32
    round-off: the numba march's vectorised code sums a volume of 9 channels in another order than one of 6 (its
    step counts exactly the same)."""
    from swim.rt.march_inputs import atmosphere_constants, volume_constants

    origins, dirs = _random_rays(400)
    sun = enu_from_azimuth_zenith(135.0, 40.0)
    settings = MarchSettings(execution=ExecutionSettings(backend=backend))
    out, (volume, transmittance, gas, phase) = _trace(_tiny_scene(aerosol_plume=True), origins, dirs, sun,
                                                      settings=settings)
    every = {**volume_constants(volume, transmittance, species=tuple(range(5))), **atmosphere_constants(gas, sun)}
    assert every["volume"].shape[-1] == 9
    again = trace_rays(origins, dirs, every, grid_geometry(volume), phase, settings)
    assert (out["tau_hydrometeor"] > 1.0).sum() > 20 and out["surface"].sum() > 20, "rays must cross cloud and ground"
    np.testing.assert_array_equal(out["steps"], again["steps"])
    for key in ("radiance", "radiance_cloud", "radiance_surface", "tau_hydrometeor", "distance"):
        np.testing.assert_allclose(out[key], again[key], rtol=1e-6, atol=1e-12, err_msg=key)


def test_a_cloudless_volume_packs_no_species():
    """A scene without hydrometeors packs Step 1a's two channels alone, and the volume that shares them (no species
    left) is packed again the same way (a second sun of a clear sky)."""
    from swim.rt.march_inputs import pack_volume, packed_species, share_packed_channels

    scene = _tiny_scene()
    for name in ("cloud_liquid_content", "cloud_ice_content"):
        scene[name] = scene[name] * 0.0
    volume = build_optical_volume(scene)
    assert packed_species(volume) == ()
    packed = pack_volume(volume)
    assert packed.shape == volume["extinction"].shape[1:] + (2,)
    share_packed_channels(volume, packed)
    assert volume.sizes["species"] == 0 and packed_species(volume) == ()
    assert pack_volume(volume).shape == packed.shape


def test_probe_count_places_the_steps():
    """MarchSettings.n_probe changes where the grid steps go (both kernels take it: the parity test above)."""
    origins, dirs = _random_rays(300)
    sun = enu_from_azimuth_zenith(135.0, 40.0)
    out = {n: _trace(_tiny_scene(), origins, dirs, sun, settings=MarchSettings(n_probe=n))[0] for n in (4, 64)}
    changed = ~np.isclose(out[4]["tau_hydrometeor"], out[64]["tau_hydrometeor"], rtol=1e-4, atol=1e-6)
    assert changed.sum() > 10, "4 probes must place the steps differently from 64"


def _kernel_constants(scene, sun):
    volume = build_optical_volume(scene)
    return volume, kernel_constants(volume, solar_transmittance(volume, sun), build_gas_tables(AerosolBackground()), sun)


@pytest.mark.full  # the JAX kernel's helper, its numba twin held to it here: the full tier (its JAX programs)
def test_probe_counts_are_the_cells_crossed():
    """probe_counts: a ray along the grid's x axis crosses (length / spacing) cells; with 4 probes and one per
    cell it takes that many (rounded up), a short ray keeps 4, and probe_spacing 0 always gives n_probe."""
    import jax.numpy as jnp

    from swim.rt.march_jax import probe_counts
    from swim.rt.march_settings import MAX_PROBES

    sun = enu_from_azimuth_zenith(135.0, 40.0)
    volume, consts = _kernel_constants(_tiny_scene(), sun)
    origins = np.array([[-2300.0, 100.0, EARTH_RADIUS_M + 2000.0]] * 3)
    dirs = np.array([[1.0, 0.0, 0.0]] * 3)
    seg = ray_segments(origins, dirs, grid_geometry(volume), top=float(consts["top"]))
    s0 = seg["bounds"][:, 0]
    length = np.array([4400.0, 800.0, 2200.0])  # 11 cells of 400 m, 2 cells, 5.5 cells
    args = [jnp.asarray(a, jnp.float32) for a in (seg["start"], dirs, s0, length)]
    counts = {spacing: np.asarray(probe_counts(*args, consts, n_probe=4, probe_spacing=spacing))
              for spacing in (0.0, 0.5, 1.0)}
    np.testing.assert_array_equal(counts[0.0], [4, 4, 4])
    assert counts[1.0][0] == 11 and counts[1.0][1] == 4 and counts[1.0][2] == 6, counts
    assert counts[0.5][0] == 22 and counts[0.5][1] == 4 and counts[0.5][2] == 11, counts
    # capped at MAX_PROBES: a spacing of a tenth of a cell over 11 cells wants 110
    capped = np.asarray(probe_counts(*args, consts, n_probe=4, probe_spacing=0.1))
    assert 110 <= capped[0] <= 111, capped
    assert np.asarray(probe_counts(*args[:3], jnp.asarray([1e9, 800.0, 2200.0], jnp.float32), consts, n_probe=4,
                                   probe_spacing=0.1))[0] == MAX_PROBES


def _cloud_wall(thick, count=120, liquid_content=4e-4):
    """A wall of cloud ``thick`` cells (400 m) thick across a 12 x 12 grid, 1-4 km high, and ``count``
    near-horizontal rays from the grid's west edge towards it."""
    n, spacing = 12, 400.0
    x = (np.arange(n) - n / 2 + 0.5) * spacing
    z = np.arange(0.0, 5000.0, 250.0) + 125.0
    zz, yy, xx = np.meshgrid(z, x, x, indexing="ij")
    liquid = np.where((xx > x[7] - 1.0) & (xx < x[7 + thick - 1] + 1.0) & (zz > 1000) & (zz < 4000), liquid_content, 0.0)
    scene = scene_from_arrays(x=x, y=x, z=z, reference_lat=30.0, reference_lon=10.0, cloud_liquid_content=liquid)
    rng = np.random.default_rng(5)
    origins = np.column_stack([np.full(count, -2380.0), rng.uniform(-1500.0, 1500.0, count),
                               EARTH_RADIUS_M + rng.uniform(2000, 3000, count)])
    dirs = np.array([enu_from_azimuth_zenith(a, z) for a, z in zip(rng.uniform(85.0, 95.0, count),
                                                                    rng.uniform(88.0, 92.0, count))])
    return scene, origins, dirs


@BACKENDS_JAX_FULL
def test_probe_spacing_follows_the_cells_crossed(backend):
    """A cloud wall one cell thick, crossed by near-horizontal rays along 12 cells: 3 probes miss it for most
    rays, whose 12 steps then sample it at one place each; one probe per cell crossed (probe_spacing=1) finds
    it and puts the steps there, so the hydrometeor optical depth must come much closer to a fine march, in
    both kernels."""
    scene, origins, dirs = _cloud_wall(thick=1)
    sun = enu_from_azimuth_zenith(135.0, 40.0)
    fine = _trace(scene, origins, dirs, sun, settings=MarchSettings(n_grid=2000, n_probe=1000, probe_spacing=0.0))[0]
    through = fine["tau_hydrometeor"] > 0.5
    assert through.sum() > 60, "the rays must cross the wall"
    err = {}
    for probe_spacing in (0.0, 1.0):
        out = _trace(scene, origins, dirs, sun, settings=MarchSettings(n_grid=12, n_probe=3,
                                                                       probe_spacing=probe_spacing,
                                                                       execution=ExecutionSettings(backend=backend)))[0]
        err[probe_spacing] = np.median(np.abs(out["tau_hydrometeor"] / fine["tau_hydrometeor"] - 1)[through])
    assert err[1.0] < 0.3 * err[0.0] and err[1.0] < 0.1, (backend, err)


@BACKENDS_JAX_FULL
def test_thick_steps_are_refined(backend):
    """A thick cloud wall (optical depth ~240 across) seen edge-on with few steps: the step that reaches its face
    samples the sunlight somewhere inside (one cell deep, the sun's transmittance there is far lower) unless
    thick steps are halved down to tau_refine, in both kernels; the cloud's radiance must then come much closer
    to a fine march's."""
    scene, origins, dirs = _cloud_wall(thick=4)
    sun = enu_from_azimuth_zenith(270.0, 40.0)  # behind the observer: the rays see the wall's sunlit face
    fine = _trace(scene, origins, dirs, sun, settings=MarchSettings(n_grid=4000, tau_refine=0.0))[0]
    through = fine["tau_hydrometeor"] > 20.0
    assert through.sum() > 60, "the rays must cross the wall"
    err = {}
    for tau_refine in (0.0, 0.5):
        out = _trace(scene, origins, dirs, sun, settings=MarchSettings(n_grid=12, tau_refine=tau_refine,
                                                                       execution=ExecutionSettings(backend=backend)))[0]
        err[tau_refine] = np.median(np.abs(out["radiance"] / fine["radiance"] - 1)[through])
    assert err[0.5] < 0.3 * err[0.0] and err[0.5] < 0.02, (backend, err)


@pytest.mark.full  # numba against the JAX kernel: the JAX programs' compilation, the full tier
@pytest.mark.parametrize("sun_azimuth", [270.0, 90.0])
def test_cloud_face_inside_a_clear_step_is_found(sun_azimuth):
    """A wall of cloud one cell thick, seen edge-on with 12 steps: where the face lies in a step whose midpoint is
    in clear air, that step adds no cloud and the next one starts inside it, so splitting only the thick step
    puts the face up to half a step too deep (0.5-0.8 % radiance error here, pixel-scale stripes in images).
    Refinement on the change of extinction goes back and halves the clear step, in both kernels, which must
    agree with each other and come within 0.3 % of a fine march, lit from the front and from behind."""
    scene, origins, dirs = _cloud_wall(thick=1)
    sun = enu_from_azimuth_zenith(sun_azimuth, 40.0)
    fine = _trace(scene, origins, dirs, sun, settings=MarchSettings(n_grid=4000, tau_refine=0.0))[0]
    through = fine["tau_hydrometeor"] > 0.5
    assert through.sum() > 60, "the rays must cross the wall"
    out = {backend: _trace(scene, origins, dirs, sun,
                           settings=MarchSettings(n_grid=12, execution=ExecutionSettings(backend=backend)))[0]
           for backend in ("jax", "numba")}
    for backend, result in out.items():
        err = np.abs(result["radiance"] / fine["radiance"] - 1)[through]
        assert np.median(err) < 0.003 and np.percentile(err, 90) < 0.006, (backend, np.median(err))
    np.testing.assert_allclose(out["numba"]["radiance"], out["jax"]["radiance"], rtol=2e-4)
    np.testing.assert_allclose(out["numba"]["tau_hydrometeor"], out["jax"]["tau_hydrometeor"], rtol=2e-4, atol=1e-6)


def test_any_cut_of_the_rays_into_chunks_gives_the_same_pixels(monkeypatch):
    """The numba kernel's rays are cut into equal chunks, as many as a multiple of the threads (a small batch runs
    on every core): one thread, three threads, and chunks smaller than the batch must give the same pixels in the
    same order."""
    origins, dirs = _random_rays(700)
    sun = enu_from_azimuth_zenith(135.0, 40.0)
    monkeypatch.setenv("SWIM_NUM_THREADS", "1")
    ref = _trace(_tiny_scene(), origins, dirs, sun,
                 settings=MarchSettings(execution=ExecutionSettings(backend="numba")))[0]
    assert np.isfinite(ref["radiance"]).all() and np.ptp(ref["radiance"][:, 0]) > 0.01
    for threads, chunk in ((3, 4096), (2, 128), (1, 300)):
        monkeypatch.setenv("SWIM_NUM_THREADS", str(threads))
        out = _trace(_tiny_scene(), origins, dirs, sun,
                     settings=MarchSettings(execution=ExecutionSettings(backend="numba", chunk=chunk)))[0]
        for key in ("radiance", "tau_hydrometeor", "surface"):
            np.testing.assert_allclose(out[key], ref[key], rtol=1e-5, atol=1e-7, err_msg=f"{key}, {threads} threads, chunk {chunk}")


@BACKENDS_JAX_FULL
def test_ground_beyond_the_grid_continues_its_edge_and_fades_to_the_edge_mean(backend):
    """Beyond the grid the ground continues from its edge over a margin, smoothed along the edge and fading to the
    mean of the edge cells (swim.rt.surface_margin.extend_beyond_grid, swim.rt.march_jax.surface_beyond_edge): seen
    from above it must be continuous across the edge (a ground that jumped to the mean drew the domain's outline in
    views from space), and some cells away the same along the edge (no streaks of edge values)."""
    n, spacing = 12, 400.0
    x = (np.arange(n) - n / 2 + 0.5) * spacing
    z = np.arange(0.0, 5000.0, 250.0) + 125.0
    albedo = np.full((n, n), 0.05)
    albedo[n // 2:, -2:] = 0.5  # a bright patch on the northern half of the east edge
    scene = scene_from_arrays(x=x, y=x, z=z, reference_lat=30.0, reference_lon=10.0, surface_albedo=albedo,
                              cloud_liquid_content=np.zeros((z.size, n, n)), land_mask=1.0)
    edge = x[-1]
    ground = np.array([[edge - 20.0, 1000.0], [edge + 20.0, 1000.0], [edge + 20.0, -1000.0],
                       [edge + 80 * spacing, 1000.0], [edge + 80 * spacing, -1000.0],
                       [edge + 15 * spacing, 1000.0], [edge + 15 * spacing, -1000.0]])
    origins = np.column_stack([ground, np.full(len(ground), EARTH_RADIUS_M + 3000.0)])
    down = np.tile([0.0, 0.0, -1.0], (len(ground), 1))
    sun = enu_from_azimuth_zenith(200.0, 30.0)
    out = _trace(scene, origins, down, sun, settings=MarchSettings(surface="lambertian",
                                                                   execution=ExecutionSettings(backend=backend)))[0]
    surface = out["radiance_surface"][:, 1]
    assert out["surface"].all()
    assert abs(surface[1] / surface[0] - 1) < 0.02, (backend, surface)  # across the edge: continuous
    assert surface[1] > 3 * surface[2], (backend, surface)  # near the edge: the edge cells' own ground
    assert abs(surface[3] / surface[4] - 1) < 1e-3, (backend, surface)  # far beyond: the edge mean
    # 15 cells out the patch has faded (with a 6-cell fade a hurricane's edge winds drew a streak this far
    # beyond Katrina's grid in views from space)
    assert abs(surface[5] / surface[6] - 1) < 0.01, (backend, surface)
    assert surface[2] < surface[3] < surface[1], (backend, surface)


@pytest.mark.parametrize("backend", [pytest.param("jax", marks=pytest.mark.full), "numba"])
def test_a_ray_leaving_the_grid_downwards_meets_the_terrain_beyond_it(backend):
    """Beyond the grid the terrain keeps its edge heights, so a ray that leaves the grid sideways on its way down meets
    the ground before its segment after the grid ends (on the sea-level sphere). No later step finds a crossing in
    the far half of that segment's last step: the ray's zero-length end step does
    (docs/decisions/0004-step-placement.md). Without it all 57 of these rays ended on the sea-level sphere, up to 1.2 km
    too far, with the air under the terrain in their path (a view from orbit 8 deg off nadir had 2 % errors and stripes
    beyond the grid's far edge). Against the analytic crossing (the sphere of radius R + the terrain's height) and the
    NumPy reference."""
    n, spacing, terrain = 12, 400.0, 20.0
    x = (np.arange(n) - n / 2 + 0.5) * spacing
    z = np.arange(0.0, 5000.0, 250.0) + 125.0
    scene = scene_from_arrays(x=x, y=x, z=z, reference_lat=30.0, reference_lon=10.0,
                              terrain_height=np.full((n, n), terrain), cloud_liquid_content=np.zeros((z.size, n, n)),
                              land_mask=1.0)
    dirs = np.array([enu_from_azimuth_zenith(90.0, zenith) for zenith in np.linspace(92.0, 120.0, 57)])
    origins = np.tile([0.0, 0.0, EARTH_RADIUS_M + 3000.0], (len(dirs), 1))
    sun = enu_from_azimuth_zenith(200.0, 40.0)
    settings = MarchSettings(execution=ExecutionSettings(backend=backend))
    out, (volume, transmittance, gas, phase) = _trace(scene, origins, dirs, sun, settings=settings)
    b = np.sum(origins * dirs, axis=1)
    crossing = -b - np.sqrt(b * b - np.sum(origins ** 2, axis=1) + (EARTH_RADIUS_M + terrain) ** 2)
    seg = ray_segments(origins, dirs, grid_geometry(volume))
    assert np.all(seg["bounds"][:, 2] > seg["bounds"][:, 1]) and seg["ends_on_ground"].all(), \
        "every ray must leave the grid and end on the sea-level sphere"
    assert out["surface"].all()
    np.testing.assert_allclose(out["distance"], crossing, atol=2.0)  # 0.7 m: the bisection's 2^-10 of a step
    for k in range(0, len(dirs), 3):
        ref = reference_trace_ray(origins[k], dirs[k], volume, transmittance, gas, sun, phase["p_rayleigh"][k],
                                  phase["p_aerosol"][k], step_m=20.0, p_stratospheric=phase["p_stratospheric"][k])
        assert ref["surface"]
        np.testing.assert_allclose(out["tau_clear"][k], ref["tau_clear"], rtol=0.005)  # 0.16 %; 2.6 % without
        np.testing.assert_allclose(out["radiance"][k], ref["radiance"], rtol=0.005)


def test_samples_above_the_terrains_top_skip_its_lookup_and_meet_the_ground_alike(monkeypatch):
    """The numba kernel looks the terrain up only below its highest point (march_cpu.pack_parameters'
    TERRAIN_TOP_MARGIN; docs/decisions/0003-cpu-kernel-code.md). Rays from 6 km down and from 300 m up and down onto the
    tiny scene's 600 m hill, its flanks and the plain around it, and rays that graze it sideways: where they meet the
    ground, with what radiance and optical depths, the same as when every sample looks it up (to round-off: the sample
    before the crossing is then looked up when the crossing is found, not when it is taken)."""
    from swim.rt import march_cpu

    scene = _tiny_scene()
    sun = enu_from_azimuth_zenith(135.0, 40.0)
    dirs, origins = [], []
    for height, zeniths in ((6000.0, np.linspace(95.0, 175.0, 17)), (300.0, np.linspace(80.0, 100.0, 11))):
        for az in (0.0, 70.0, 160.0, 290.0, 315.0):
            for zen in zeniths:
                dirs.append(enu_from_azimuth_zenith(az, zen))
                origins.append([1500.0, -1500.0, EARTH_RADIUS_M + height])
    dirs, origins = np.array(dirs), np.array(origins)
    settings = MarchSettings(execution=ExecutionSettings(backend="numba"))
    skipping = _trace(scene, origins, dirs, sun, settings=settings)[0]
    monkeypatch.setattr(march_cpu, "TERRAIN_TOP_MARGIN", np.inf)
    looking_up = _trace(scene, origins, dirs, sun, settings=settings)[0]
    assert skipping["surface"].sum() > 100 and (~skipping["surface"]).sum() > 10
    np.testing.assert_array_equal(skipping["surface"], looking_up["surface"])
    for key in ("distance", "radiance", "tau_clear", "tau_hydrometeor", "radiance_clear"):
        np.testing.assert_allclose(skipping[key], looking_up[key], rtol=1e-9, atol=1e-9, err_msg=key)


def test_the_terrains_top_is_packed_for_the_step_loop():
    """pack_parameters' last entry: the terrain's highest point plus the margin; infinite (every sample looks the
    terrain up) without terrain or where it is not finite."""
    from swim.rt import march_cpu

    sun = enu_from_azimuth_zenith(135.0, 40.0)
    consts = _kernel_constants(_tiny_scene(), sun)[1]
    p, _ = march_cpu.pack_parameters(consts)
    highest = float(np.max(np.asarray(consts["terrain"])))
    assert 590.0 < highest < 610.0
    assert p[march_cpu._P_TERRAIN_TOP] == highest + march_cpu.TERRAIN_TOP_MARGIN
    for terrain in (None, np.full((1, 3, 3), np.nan, np.float32)):
        assert march_cpu.pack_parameters({**consts, "terrain": terrain})[0][march_cpu._P_TERRAIN_TOP] == np.inf


def _clear_segments():
    """Rays from the tiny grid's top straight up (after the grid) and from 800 km straight down (before it)."""
    sun = enu_from_azimuth_zenith(135.0, 40.0)
    volume, consts = _kernel_constants(_tiny_scene(), sun)
    up, down = np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, -1.0])
    origins = np.array([[0.0, 0.0, EARTH_RADIUS_M + 2.0], [0.0, 0.0, EARTH_RADIUS_M + 800e3],
                        [-3000.0, 500.0, EARTH_RADIUS_M + 2.0]])
    dirs = np.array([up, down, [0.6, 0.0, 0.8]])
    seg = ray_segments(origins, dirs, grid_geometry(volume), top=float(consts["top"]))
    return consts, seg, dirs


@pytest.mark.full  # the JAX kernel's helper, its numba twin held to it here: the full tier (its JAX programs)
@pytest.mark.parametrize("n_steps", [8, 24])
def test_clear_air_steps_follow_the_air_and_integrate_it_better(n_steps):
    """clear_step_edges: the steps span the segment, lengthen upwards (the air thins) and integrate an
    exponential atmosphere (scale height 8 km) by the midpoint rule better than equal steps."""
    import jax.numpy as jnp

    from swim.rt.march_jax import clear_step_edges

    consts, seg, dirs = _clear_segments()
    start, bounds = (jnp.asarray(seg[k], jnp.float32) for k in ("start", "bounds"))
    dirs_j = jnp.asarray(dirs, jnp.float32)
    after = np.asarray(clear_step_edges(start, dirs_j, bounds[:, 1], bounds[:, 2] - bounds[:, 1], n_steps, consts),
                       dtype=float)
    before = np.asarray(clear_step_edges(start, dirs_j, jnp.zeros(3), bounds[:, 0], n_steps, consts), dtype=float)
    b = np.asarray(seg["bounds"], dtype=float)
    np.testing.assert_allclose(after[0], b[:, 1], rtol=1e-6)
    np.testing.assert_allclose(after[-1], b[:, 2], rtol=1e-6)
    np.testing.assert_allclose(before[-1, 1], b[1, 0], rtol=1e-6)
    assert np.all(np.diff(after[:, [0, 2]], axis=0) > 0) and np.all(np.diff(before[:, 1]) > 0)
    up_steps, down_steps = np.diff(after[:, 0]), np.diff(before[:, 1])
    assert np.all(np.diff(up_steps) >= -1e-3 * up_steps[:-1]), "steps must lengthen as the ray climbs"
    assert np.all(np.diff(down_steps) <= 1e-3 * down_steps[:-1]), "steps must shorten as the ray descends"
    assert up_steps[0] < 0.5 * up_steps.mean() and down_steps[-1] < 0.5 * down_steps.mean()

    # the vertical ray up: heights above the grid top h0 = start height + s
    h0 = 2.0 + b[0, 1]
    top = 2.0 + b[0, 2]
    exact = 8e3 * (np.exp(-h0 / 8e3) - np.exp(-top / 8e3))
    mid = 0.5 * (after[1:, 0] + after[:-1, 0]) + 2.0
    placed = np.sum(np.exp(-mid / 8e3) * up_steps)
    equal_edges = np.linspace(b[0, 1], b[0, 2], n_steps + 1)
    equal = np.sum(np.exp(-(0.5 * (equal_edges[1:] + equal_edges[:-1]) + 2.0) / 8e3) * np.diff(equal_edges))
    assert abs(placed - exact) < 0.5 * abs(equal - exact), (placed, equal, exact)


@pytest.mark.full  # the JAX kernel's programs compile for tens of seconds on an empty cache: the full tier
def test_numba_clear_air_steps_match_the_jax_ones():
    import jax.numpy as jnp

    from swim.rt import march_cpu
    from swim.rt.march_jax import clear_step_edges
    from swim.rt.march_settings import CLEAR_PROBES, CLEAR_STEP_FLOOR, CLEAR_STEP_POWER

    consts, seg, dirs = _clear_segments()
    start, bounds = np.asarray(seg["start"], float), np.asarray(seg["bounds"], float)
    expected = np.asarray(clear_step_edges(jnp.asarray(start, jnp.float32), jnp.asarray(dirs, jnp.float32),
                                           jnp.asarray(bounds[:, 1], jnp.float32),
                                           jnp.asarray(bounds[:, 2] - bounds[:, 1], jnp.float32), 24, consts))
    p, _ = march_cpu.pack_parameters(consts)
    clear_edges = numba_jit.callable_from_python(march_cpu._clear_edges)
    for r in range(len(dirs)):
        cdf, edges = np.empty(CLEAR_PROBES + 1), np.empty(25)
        clear_edges(*start[r], *dirs[r], bounds[r, 1], bounds[r, 2] - bounds[r, 1], 24, p,
                    np.asarray(consts["beta_gas"]), np.asarray(consts["beta_gas_spectra"]), CLEAR_PROBES,
                    CLEAR_STEP_POWER, CLEAR_STEP_FLOOR, cdf, edges)
        np.testing.assert_allclose(edges, expected[:, r], rtol=0, atol=1e-4 * (bounds[r, 2] - bounds[r, 1]))


@pytest.mark.parametrize("dh", [100.0, 250.0])
def test_gas_column_above_is_the_exponential_atmospheres_column(dh):
    """gas_column_above: for an exponential atmosphere (scale height 8 km, to 100 km) the fraction of the vertical
    optical depth above height h is (e^(-h/H) - e^(-top/H)) / (1 - e^(-top/H)), to the trapezoidal rule's
    accuracy; the components count with their 546-nm spectral factors; an empty atmosphere gives ones."""
    from swim.rt.march_inputs import gas_column_above

    heights = np.arange(0.0, 100e3 + dh / 2, dh)
    scale, top = 8e3, heights[-1]
    profiles = np.zeros((3, heights.size))
    profiles[0] = 1e-5 * np.exp(-heights / scale)
    column = gas_column_above(profiles, np.ones((3, 3)), dh)
    exact = (np.exp(-heights / scale) - np.exp(-top / scale)) / (1 - np.exp(-top / scale))
    np.testing.assert_allclose(column, exact, atol=2e-4 * (dh / 100.0) ** 2)
    assert column[0] == 1.0 and column[-1] == 0.0 and np.all(np.diff(column) <= 0)
    # a second component (an aerosol layer, up to 2 km) weighted by its spectral factor at 546 nm (column 1)
    profiles[1] = np.where(heights < 2e3, 1e-4, 0.0)
    spectra = np.ones((3, 3))
    spectra[1] = (1.0, 0.0, 5.0)  # no aerosol at 546 nm: the column as before
    np.testing.assert_allclose(gas_column_above(profiles, spectra, dh), column, atol=1e-12)
    spectra[1, 1] = 1.0
    assert gas_column_above(profiles, spectra, dh)[int(2e3 / dh)] < 0.5 * column[int(2e3 / dh)]
    np.testing.assert_array_equal(gas_column_above(np.zeros((3, 11)), spectra, dh), 1.0)


@pytest.mark.full  # the JAX kernel's helper, its numba twin held to it here: the full tier (its JAX programs)
def test_after_step_counts_follow_the_air_left_above_the_grid():
    """after_step_counts: a ray straight up from the ground takes ceil(n_after sqrt(q)) steps after the grid, q the
    column fraction above its exit (the height table's column row); the count falls as the grid top rises, never
    below AFTER_MIN_STEPS. A ray from 6 km counts its air from there (q relative to its own lowest point), a ray
    that dips to a tangent point below its start from that point, and a ray that descends where it leaves the
    grid takes n_after. The numba kernel's helper (swim.rt.march_cpu._after_steps) gives the same counts, and
    n_after without the column row."""
    import jax.numpy as jnp

    from swim.constants import AFTER_MIN_STEPS, GAS_COLUMN_ROW
    from swim.rt import march_cpu
    from swim.rt.march_jax import after_step_counts

    sun = enu_from_azimuth_zenith(135.0, 40.0)
    _, consts = _kernel_constants(_tiny_scene(), sun)
    column = np.asarray(consts["beta_gas"][GAS_COLUMN_ROW], dtype=float)
    dh = float(consts["dh"])

    def q_at(h):
        return np.interp(h, np.arange(column.size) * dh, column)

    tops = np.array([500.0, 2e3, 5e3, 10e3, 20e3, 40e3])
    n = tops.size
    up = np.tile([0.0, 0.0, 1.0], (n, 1))
    start = np.tile([0.0, 0.0, 2.0], (n, 1))
    bounds = np.stack([np.zeros(n), tops - 2.0, np.full(n, 100e3 - 2.0)], axis=1)
    n_after = 28
    counts = np.asarray(after_step_counts(jnp.asarray(start, jnp.float32), jnp.asarray(up, jnp.float32),
                                          jnp.asarray(bounds, jnp.float32), n_after, consts))
    expected = np.clip(np.ceil(n_after * np.sqrt(q_at(tops) / q_at(2.0))), AFTER_MIN_STEPS, n_after)
    np.testing.assert_array_equal(counts, expected)
    assert counts[0] > counts[3] > counts[4] and counts[-1] == AFTER_MIN_STEPS
    # horizontal from 6 km: the lowest point is the start; straight down from 30 km into the grid's top: descends
    radius = float(consts["radius"])
    flat_start = np.array([[0.0, 0.0, 6e3], [0.0, 0.0, 30e3]])
    dirs = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    exit_height = np.hypot(200e3, radius + 6e3) - radius
    flat_bounds = np.array([[0.0, 200e3, 600e3], [0.0, 25e3, 29e3]])
    got = np.asarray(after_step_counts(jnp.asarray(flat_start, jnp.float32), jnp.asarray(dirs, jnp.float32),
                                       jnp.asarray(flat_bounds, jnp.float32), n_after, consts))
    assert exit_height > 9e3  # a 6 km horizontal ray leaves a grid 200 km along it
    assert got[0] == np.clip(np.ceil(n_after * np.sqrt(q_at(exit_height) / q_at(6e3))), AFTER_MIN_STEPS, n_after)
    assert got[1] == n_after
    # a ray from 6 km looking 2 deg down, leaving the grid 400 km on, beyond its tangent point (~220 km on)
    down = np.array([[np.cos(np.radians(2.0)), 0.0, -np.sin(np.radians(2.0))]])
    s_tangent = (radius + 6e3) * np.sin(np.radians(2.0))
    tangent_height = (radius + 6e3) * np.cos(np.radians(2.0)) - radius
    exit_point = np.array([0.0, 0.0, 6e3]) + 400e3 * down[0]
    exit_h = np.hypot(exit_point[0], radius + exit_point[2]) - radius
    dip = np.asarray(after_step_counts(jnp.asarray([[0.0, 0.0, 6e3]], jnp.float32), jnp.asarray(down, jnp.float32),
                                       jnp.asarray([[0.0, 400e3, 900e3]], jnp.float32), n_after, consts))
    assert 0 < s_tangent < 400e3 and 1e3 < tangent_height < exit_h < 6e3
    assert dip[0] == np.clip(np.ceil(n_after * np.sqrt(q_at(exit_h) / q_at(tangent_height))), AFTER_MIN_STEPS,
                             n_after)
    # the numba helper, per ray
    p, _ = march_cpu.pack_parameters(consts)
    after_steps = numba_jit.callable_from_python(march_cpu._after_steps)
    table = np.asarray(consts["beta_gas"])
    rays = [(start[r], up[r], bounds[r, 1], counts[r]) for r in range(n)]
    rays += [(flat_start[r], dirs[r], flat_bounds[r, 1], got[r]) for r in range(2)]
    rays += [(np.array([0.0, 0.0, 6e3]), down[0], 400e3, dip[0])]
    for origin, direction, s_exit, count in rays:
        assert after_steps(*origin, *direction, s_exit, n_after, p, table) == count
        assert after_steps(*origin, *direction, s_exit, n_after, p, table[:GAS_COLUMN_ROW]) == n_after


@pytest.mark.full  # the JAX kernel's helper, its numba twin held to it here: the full tier (its JAX programs)
def test_after_step_counts_keep_the_clear_airs_error_relative_to_the_ray():
    """The rule of after_step_counts: the midpoint rule's error over the segment above a grid top, with that ray's
    own step count placed by clear_step_edges, relative to the whole column's optical depth at 546 nm, is no larger
    than the error of n_after steps through the whole column (the rule's promise), for grid tops from 0.5 to 20 km,
    while the counts fall from n_after to a third of it or less."""
    import jax.numpy as jnp

    from swim.constants import GAS_COLUMN_ROW
    from swim.rt.march_jax import after_step_counts, clear_step_edges

    sun = enu_from_azimuth_zenith(135.0, 40.0)
    _, consts = _kernel_constants(_tiny_scene(), sun)
    dh = float(consts["dh"])
    table = np.asarray(consts["beta_gas"], dtype=float)
    spectra = np.asarray(consts["beta_gas_spectra"], dtype=float)
    beta = (table[:GAS_COLUMN_ROW] * spectra[:, 1:2]).sum(axis=0)
    grid = np.arange(beta.size) * dh

    def beta_at(h):
        return np.interp(h, grid, beta)

    def exact(lo, hi):
        h = np.linspace(lo, hi, 200_001)
        return np.trapezoid(beta_at(h), h)

    top, n_after = 100e3 - 1.0, 28
    tops = np.array([1.0, 500.0, 2e3, 5e3, 10e3, 20e3])  # the first: the whole column
    n = tops.size
    start = jnp.zeros((n, 3), jnp.float32)
    up = jnp.asarray(np.tile([0.0, 0.0, 1.0], (n, 1)), jnp.float32)
    bounds = jnp.asarray(np.stack([np.zeros(n), tops, np.full(n, top)], axis=1), jnp.float32)
    steps = after_step_counts(start, up, bounds, n_after, consts)
    edges = np.asarray(clear_step_edges(start, up, bounds[:, 1], bounds[:, 2] - bounds[:, 1], n_after, consts,
                                        steps=steps), dtype=float)
    whole = exact(0.0, top)
    errors = []
    for r in range(n):
        e = edges[:, r]
        midpoint = np.sum(beta_at(0.5 * (e[1:] + e[:-1])) * np.diff(e))
        errors.append(abs(midpoint - exact(tops[r], top)) / whole)
    steps = np.asarray(steps)
    assert steps[0] == n_after and steps[-1] <= n_after // 3, steps
    assert errors[0] > 1e-5, errors  # the whole column's error is not negligible at 28 steps
    assert max(errors[1:]) <= errors[0], (errors, steps)  # 0.43-0.11 % against 0.53 % of the column
