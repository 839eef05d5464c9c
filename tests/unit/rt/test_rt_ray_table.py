"""A camera's rays kept on the device (swim.rt.ray_table, MarchSettings.ray_table) against the per-batch rays of
swim.rt.march.trace_rays: the same kernel, so the same outputs but for the float32 rounding of the phase functions'
scattering-angle cosine, which the table computes on the device."""

import numpy as np
import pytest

import swim
from swim.errors import SwimInputError
from swim.frames import enu_from_azimuth_zenith
from swim.rt import ray_table
from swim.rt.gas import AerosolBackground
from swim.rt.image_sampling import AdaptiveSampling
from swim.rt.march_settings import ExecutionSettings, MarchSettings as _MarchSettings
from swim.rt.march_inputs import grid_geometry

from test_rt_march import _random_rays, _tiny_scene, _trace


def MarchSettings(**kw):  # noqa: N802 - a stand-in for the class in this module's tests
    """The render's settings with the paper's cloud scattering: the JAX kernel's fast paths tested here (the fused grid
    kernel, the ray table, Step 1a and the sampler on the device) serve ``cloud_scattering="albers2020"``; the 3-D
    method marches in lockstep on the host's rays (tests/system/test_clouds_3d.py)."""
    return _MarchSettings(**{"cloud_scattering": "albers2020", **kw})

KEYS = ("radiance", "radiance_clear", "radiance_cloud", "radiance_surface", "tau_clear")


@pytest.mark.full  # the JAX kernel's programs compile for tens of seconds on an empty cache: the full tier
def test_table_rows_give_trace_rays_outputs():
    """Rows of a table in a shuffled order, across two chunks, with an extra ray after them (the sun's in a render):
    each output that of trace_rays for the same rays, from the ground, inside the grid and from 20 km through cloud,
    the smoke plume, terrain and the grid's edges."""
    scene = _tiny_scene(True)
    origins, dirs = _random_rays(300, seed=4)
    sun = enu_from_azimuth_zenith(135.0, 40.0)
    aerosol = AerosolBackground(stratospheric_aod_550=0.2)
    settings = MarchSettings(execution=ExecutionSettings(backend="jax", chunk=256))
    rows = np.random.default_rng(5).permutation(len(dirs))[:290]  # not every row, not in order
    extra_index = np.setdiff1d(np.arange(len(dirs)), rows)[0]
    order = np.concatenate([rows, [extra_index]])
    reference, (volume, _, gas, _) = _trace(scene, origins[order], dirs[order], sun, aerosol=aerosol, settings=settings)
    assert reference["surface"].sum() > 40 and (reference["tau_hydrometeor"] > 1.0).sum() > 10, \
        "rays must hit ground and cloud"
    from swim.rt.march_inputs import kernel_constants
    from swim.rt.solar import solar_transmittance

    consts = kernel_constants(volume, solar_transmittance(volume, sun), gas, sun)
    geometry = grid_geometry(volume)
    table = ray_table.build_ray_table(origins, dirs, geometry, consts, settings)
    extra = ray_table.build_ray_table(origins[[extra_index]], dirs[[extra_index]], geometry, consts, settings)
    assert table.size == len(dirs) and extra.size == 1
    phase = ray_table.PhaseInputs(tuple(sun), gas.depolarization, aerosol.type, aerosol.stratospheric)
    seen = []
    out = ray_table.trace_table_rows(table, rows, consts, phase, settings, progress=lambda done, n: seen.append(
        (done, n)), extra=extra)
    assert seen == [(256, 291), (291, 291)]
    np.testing.assert_array_equal(out["surface"], reference["surface"])
    np.testing.assert_array_equal(out["steps"], reference["steps"])
    np.testing.assert_allclose(out["tau_hydrometeor"], reference["tau_hydrometeor"], rtol=1e-6, atol=1e-7)
    for key in KEYS:  # a few 1e-6: the aerosol's forward peak magnifies the cosine's float32 rounding
        np.testing.assert_allclose(out[key], reference[key], rtol=2e-5, atol=1e-7, err_msg=key)
    np.testing.assert_allclose(out["distance"], reference["distance"], rtol=1e-6, atol=1e-3)


@pytest.mark.full
def test_a_range_of_rows_is_marched_as_the_same_rows_listed(monkeypatch):
    """A frame's whole table passed as a range (read as slices of the host's arrays, no gathers) with the sun's ray
    after it: the same outputs, bit for bit, as the rows listed, where the extra ray shares the last chunk and where it
    has a chunk of its own; the range's bounds are checked."""
    scene = _tiny_scene(True)
    origins, dirs = _random_rays(300, seed=7)
    sun = enu_from_azimuth_zenith(135.0, 40.0)
    aerosol = AerosolBackground()
    settings = MarchSettings(n_probe=8, probe_spacing=0.5,
                             execution=ExecutionSettings(backend="jax", chunk=256))  # probe counts that vary
    _, (volume, _, gas, _) = _trace(scene, origins[:1], dirs[:1], sun, aerosol=aerosol, settings=settings)
    from swim.rt.march_inputs import kernel_constants
    from swim.rt.solar import solar_transmittance

    consts = kernel_constants(volume, solar_transmittance(volume, sun), gas, sun)
    geometry = grid_geometry(volume)
    table = ray_table.build_ray_table(origins, dirs, geometry, consts, settings)
    extra = ray_table.build_ray_table(origins[:1], -dirs[:1], geometry, consts, settings)
    probes = table.probes_host
    assert probes.max() > settings.n_probe, "some chunk must take more probes than n_probe"
    phase = ray_table.PhaseInputs(tuple(sun), gas.depolarization, aerosol.type, aerosol.stratospheric)
    chunks = []  # each chunk's kernel settings (its n_probe: the largest probe count of its rays)
    march_chunk = ray_table.march_jax._trace_chunk
    monkeypatch.setattr(ray_table.march_jax, "_trace_chunk", lambda *args, **kwargs: chunks.append(args[7]) or
                        march_chunk(*args, **kwargs))
    for rows in (range(5, 295), range(44, 300)):  # the extra ray in the second chunk with others, then alone
        seen = []
        listed = ray_table.trace_table_rows(table, np.arange(rows.start, rows.stop), consts, phase, settings,
                                            extra=extra)
        listed_chunks, chunks[:] = chunks[:], []
        ranged = ray_table.trace_table_rows(table, rows, consts, phase, settings, extra=extra,
                                            progress=lambda done, n: seen.append((done, n)))
        assert seen == [(256, len(rows) + 1), (len(rows) + 1, len(rows) + 1)]
        assert chunks == listed_chunks and len(chunks) == 2, "the same chunks with the same settings"
        # raised to the power of two above the chunk's largest count (swim.rt.march_jax.with_probes_for)
        assert chunks[0].n_probe == 1 << int(np.ceil(np.log2(probes[rows.start:rows.start + 256].max())))
        chunks[:] = []
        assert set(ranged) == set(listed)
        for key, value in listed.items():
            np.testing.assert_array_equal(ranged[key], value, err_msg=key)
        assert ranged["radiance"].shape[0] == len(rows) + 1 and np.all(ranged["radiance"] > 0)
    with pytest.raises(SwimInputError, match=r"non-empty range in \[0, 300\)"):
        ray_table.trace_table_rows(table, range(1, 301), consts, phase, settings)
    with pytest.raises(SwimInputError, match="non-empty range"):
        ray_table.trace_table_rows(table, range(3, 3), consts, phase, settings)


@pytest.mark.parametrize("kernel", ["lockstep", "fused"])
@pytest.mark.full
def test_padding_rows_are_marched_as_rays_outside_the_camera(kernel):
    """A batch filled up to its bucket (its last row repeated, ``padding_from``) and a chunk's own padding: the
    padding marched as rays that start stopped (zero radiance, no ground), the batch's own rows as without it, bit for
    bit, with the lockstep loops and with the fused kernel (in Pallas's interpreter), on the device."""
    scene = _tiny_scene(True)
    origins, dirs = _random_rays(200, seed=7)
    sun = enu_from_azimuth_zenith(135.0, 40.0)
    aerosol = AerosolBackground()
    settings = MarchSettings(execution=ExecutionSettings(backend="jax", chunk=256, grid_kernel=kernel))
    _, (volume, _, gas, _) = _trace(scene, origins[:1], dirs[:1], sun, aerosol=aerosol, settings=settings)
    from swim.rt.march_inputs import kernel_constants
    from swim.rt.solar import solar_transmittance

    consts = kernel_constants(volume, solar_transmittance(volume, sun), gas, sun)
    table = ray_table.build_ray_table(origins, dirs, grid_geometry(volume), consts, settings)
    phase = ray_table.PhaseInputs(tuple(sun), gas.depolarization, aerosol.type, aerosol.stratospheric)
    from swim.rt.march import padded_batch_size

    own = np.arange(0, 200, 2)  # 100 rows: the chunk pads them itself (to 256)
    alone = ray_table.trace_table_rows(table, own, consts, phase, settings, on_device=True)
    filled = np.concatenate([own, np.repeat(own[-1:], 156)])  # a caller's bucket of 256: no padding of the chunk's
    padded = ray_table.trace_table_rows(table, filled, consts, phase, settings, on_device=True, padding_from=100)
    as_duplicates = ray_table.trace_table_rows(table, filled, consts, phase, settings, on_device=True)
    assert np.asarray(alone["radiance"]).shape[0] == padded_batch_size(100, 256) == 256
    assert np.asarray(padded["radiance"]).shape[0] == 256
    assert np.asarray(alone["tau_hydrometeor"])[:100].max() > 1.0 and np.asarray(alone["surface"])[:100].any()
    for key in ("radiance", "radiance_clear", "radiance_cloud", "radiance_surface", "tau_clear", "tau_hydrometeor",
                "surface", "distance"):
        a, b = np.asarray(alone[key]), np.asarray(padded[key])
        np.testing.assert_array_equal(b[:100], a[:100], err_msg=key)
        np.testing.assert_array_equal(np.asarray(as_duplicates[key])[:100], a[:100], err_msg=key)
    for out, first in ((alone, 100), (padded, 100)):
        assert not np.asarray(out["radiance"])[first:].any() and not np.asarray(out["surface"])[first:].any()
    # without padding_from the caller's repeats are its own rays: the last row's values
    np.testing.assert_array_equal(np.asarray(as_duplicates["radiance"])[100:],
                                  np.repeat(np.asarray(alone["radiance"])[99:100], 156, axis=0))


def test_scattering_cosine_is_accurate_near_the_sun():
    """Within 3 degrees of the sun the float32 cosine is within 0.6 units in the last place of the exact one (the
    host's float64 value rounded: 0.5), where a float32 dot product is off by up to 2; elsewhere within 3e-7."""
    rng = np.random.default_rng(0)
    sun = np.array([0.3, 0.5, 0.8]) / np.linalg.norm([0.3, 0.5, 0.8])
    a = np.cross(sun, [0.0, 0.0, 1.0])
    a /= np.linalg.norm(a)
    b = np.cross(sun, a)
    for largest, tolerance in ((3.0, 0.6 * np.spacing(np.float32(1)) / 2), (180.0, 3e-7)):
        angle = np.radians(rng.uniform(0.0, largest, 50_000))
        phi = rng.uniform(0.0, 2 * np.pi, angle.size)
        d = (np.cos(angle)[:, None] * sun
             + np.sin(angle)[:, None] * (np.cos(phi)[:, None] * a + np.sin(phi)[:, None] * b))
        got = np.asarray(ray_table.scattering_cosine(d.astype(np.float32), sun.astype(np.float32)), dtype=float)
        assert np.abs(got - d @ sun).max() <= tolerance, largest


def _volume_and_constants():
    from swim.optics.volume import build_optical_volume
    from swim.rt.gas import build_gas_tables
    from swim.rt.march_inputs import kernel_constants
    from swim.rt.solar import solar_transmittance

    sun = enu_from_azimuth_zenith(135.0, 40.0)
    volume = build_optical_volume(_tiny_scene())
    return volume, kernel_constants(volume, solar_transmittance(volume, sun), build_gas_tables(AerosolBackground()),
                                    sun)


def test_camera_table_is_kept_for_the_same_arrays_only():
    """The kept table serves the same directions and pixels arrays (identity: a camera's cached, read-only ones) and
    observer again, and is rebuilt for a copy of the directions; each pixel's row is its place in ``pixels``."""
    volume, consts = _volume_and_constants()
    geometry = grid_geometry(volume)
    settings = MarchSettings(execution=ExecutionSettings(backend="jax", chunk=256))
    _, dirs = _random_rays(30, seed=2)
    pixels = np.array([4, 0, 9, 17, 3])
    observer = np.array([0.0, 0.0, 6_371_008.8 + 20.0])
    ray_table.forget_ray_tables()
    table, rows = ray_table.camera_ray_table(observer, dirs, pixels, geometry, consts, settings)
    assert table.size == 5 and rows[9] == 2 and rows[1] == -1 and not rows.flags.writeable
    again, _ = ray_table.camera_ray_table(observer.copy(), dirs, pixels, geometry, consts, settings)
    assert again is table
    other, _ = ray_table.camera_ray_table(observer, dirs.copy(), pixels, geometry, consts, settings)
    assert other is not table
    np.testing.assert_array_equal(np.asarray(other.direction), np.asarray(table.direction))
    # the sun's one-row table: kept for the same sun, made anew for another
    sun = ray_table.single_ray_table(observer, dirs[0], geometry, consts, settings)
    assert sun.size == 1 and ray_table.single_ray_table(observer, dirs[0].copy(), geometry, consts, settings) is sun
    assert ray_table.single_ray_table(observer, dirs[1], geometry, consts, settings) is not sun
    ray_table.forget_ray_tables()
    assert not ray_table._LAST_TABLE and not ray_table._LAST_RAY


def test_table_rows_are_checked():
    origins, dirs = _random_rays(8)
    sun = enu_from_azimuth_zenith(135.0, 40.0)
    settings = MarchSettings(execution=ExecutionSettings(backend="jax", chunk=256))
    volume, consts = _volume_and_constants()
    table = ray_table.build_ray_table(origins, dirs, grid_geometry(volume), consts, settings)
    aerosol = AerosolBackground()
    phase = ray_table.PhaseInputs(tuple(sun), 0.03, aerosol.type, aerosol.stratospheric)
    with pytest.raises(SwimInputError, match=r"rows must be in \[0, 8\)"):
        ray_table.trace_table_rows(table, [0, 8], consts, phase, settings)
    with pytest.raises(SwimInputError, match="non-empty"):
        ray_table.trace_table_rows(table, np.array([], int), consts, phase, settings)
    with pytest.raises(SwimInputError, match="JAX kernel"):
        ray_table.trace_table_rows(table, [0], consts, phase,
                                   MarchSettings(execution=ExecutionSettings(backend="numba")))
    for bad in (0, 3):
        with pytest.raises(SwimInputError, match=r"padding_from must be in \[1, 2\]"):
            ray_table.trace_table_rows(table, [0, 1], consts, phase, settings, padding_from=bad)
    with pytest.raises(SwimInputError, match="not given with extra, got 1 with extra"):
        ray_table.trace_table_rows(table, [0, 1], consts, phase, settings, padding_from=1, extra=table)
    with pytest.raises(SwimInputError, match="directions must be a finite"):
        ray_table.build_ray_table(origins, dirs * np.nan, grid_geometry(volume), consts, settings)
    with pytest.raises(SwimInputError, match="ray_table must be True, False or None"):
        MarchSettings(execution=ExecutionSettings(ray_table="yes"))


def test_ray_table_default_is_on_only_for_the_jax_kernel_on_an_accelerator(monkeypatch):
    """None (the default) resolves to the table where the JAX kernel runs on a GPU, not on a CPU; the numba kernel
    never uses it, even when asked."""
    import jax

    assert MarchSettings().execution.ray_table is None
    assert MarchSettings(execution=ExecutionSettings(backend="numba", ray_table=True)).resolved_ray_table() is False
    assert MarchSettings(execution=ExecutionSettings(backend="jax", ray_table=True)).resolved_ray_table() is True
    assert MarchSettings(execution=ExecutionSettings(backend="jax", ray_table=False)).resolved_ray_table() is False
    on_gpu = jax.default_backend() != "cpu"
    assert MarchSettings(execution=ExecutionSettings(backend="jax")).resolved_ray_table() is on_gpu
    from swim.rt import precompile

    monkeypatch.setattr(precompile, "jax_may_see_a_gpu", lambda: True)  # JAX is asked only where it may see one
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    assert MarchSettings(execution=ExecutionSettings(backend="jax")).resolved_ray_table() is True
    assert MarchSettings(execution=ExecutionSettings(backend="jax", ray_table=False)).resolved_ray_table() is False


def test_step1a_and_sampler_on_the_device_by_default_only_on_an_accelerator(monkeypatch):
    """step1a_on_device and device_sampling (None by default) resolve like the ray table: on where the JAX kernel
    runs on a GPU (measured faster there, docs/decisions/0006-gpu-kernels.md), off on a CPU and for the numba kernel
    even when asked; the sampler on the device also needs the ray table."""
    import jax

    settings = MarchSettings()
    assert settings.execution.step1a_on_device is None and settings.execution.device_sampling is None
    for name in ("step1a_on_device", "device_sampling"):
        with pytest.raises(SwimInputError, match=f"{name} must be True, False or None"):
            ExecutionSettings(**{name: "yes"})
    monkeypatch.setattr(jax, "default_backend", lambda: "cpu")
    assert MarchSettings(execution=ExecutionSettings(backend="jax")).resolved_step1a_on_device() is False
    assert MarchSettings(execution=ExecutionSettings(backend="jax")).resolved_device_sampling() is False
    assert MarchSettings(execution=ExecutionSettings(backend="jax",
                                                     step1a_on_device=True)).resolved_step1a_on_device() is True
    # the sampler on the device only beside the ray table
    assert MarchSettings(execution=ExecutionSettings(backend="jax",
                                                     device_sampling=True)).resolved_device_sampling() is False
    assert MarchSettings(execution=ExecutionSettings(backend="jax", ray_table=True)).resolved_device_sampling() is True
    assert MarchSettings(execution=ExecutionSettings(backend="jax", ray_table=True,
                                                     device_sampling=False)).resolved_device_sampling() is False
    assert MarchSettings(execution=ExecutionSettings(backend="numba",
                                                     step1a_on_device=True)).resolved_step1a_on_device() is False
    assert MarchSettings(execution=ExecutionSettings(backend="numba", ray_table=True,
                                                     device_sampling=True)).resolved_device_sampling() is False
    from swim.rt import precompile

    monkeypatch.setattr(precompile, "jax_may_see_a_gpu", lambda: True)  # JAX is asked only where it may see one
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    assert MarchSettings(execution=ExecutionSettings(backend="jax")).resolved_step1a_on_device() is True
    assert MarchSettings(execution=ExecutionSettings(backend="jax")).resolved_device_sampling() is True
    assert MarchSettings(execution=ExecutionSettings(backend="jax",
                                                     step1a_on_device=False)).resolved_step1a_on_device() is False
    assert MarchSettings(execution=ExecutionSettings(backend="jax",
                                                     ray_table=False)).resolved_device_sampling() is False
    assert MarchSettings(execution=ExecutionSettings(backend="jax",
                                                     device_sampling=False)).resolved_device_sampling() is False


@pytest.mark.parametrize("sampling", [None, AdaptiveSampling()], ids=["every pixel", "adaptive"])
@pytest.mark.full
def test_render_with_the_table_gives_the_same_image(sampling):
    """The default scene's all-sky with the camera's rays on the device: the same pixels traced, the same samples,
    the same 8-bit image and radiance to float32 rounding; the second frame (another sun) reuses the table."""
    scene = swim.default_scene()
    ray_table.forget_ray_tables()
    images = {}
    for kept in (False, True):
        for sun_zenith in (40.0, 60.0):
            images[kept, sun_zenith] = swim.render(
                scene, camera="allsky", camera_options={"size": 48}, sun_zenith=sun_zenith, sun_azimuth=120.0,
                # the host's sampler beside the table (with the table, device_sampling None means on; the sampler on
                # the device is held to the host's in test_rt_image_sampling_device.py)
                settings=MarchSettings(execution=ExecutionSettings(backend="jax", chunk=1024, ray_table=kept,
                                                                   device_sampling=False)),
                sampling=sampling)
            if kept:
                entry = ray_table._LAST_TABLE["entry"]
                if sun_zenith == 40.0:
                    first = entry[2]
                else:
                    assert entry[2] is first, "a new sun must reuse the camera's table"
    for sun_zenith in (40.0, 60.0):
        a, b = images[False, sun_zenith], images[True, sun_zenith]
        assert a.attrs["traced_pixels"] == b.attrs["traced_pixels"]
        assert a.attrs["march_samples"] == b.attrs["march_samples"]
        np.testing.assert_array_equal(a["rgb"].values, b["rgb"].values)
        np.testing.assert_allclose(a.attrs["direct_transmittance"], b.attrs["direct_transmittance"], rtol=1e-6)
        # within 5 degrees of the sun thin cloud's forward peak moves by ~0.2 % per unit in the last place of the
        # float32 cosine, which the two paths may round apart (test_scattering_cosine_is_accurate_near_the_sun)
        sun = enu_from_azimuth_zenith(a.attrs["sun_azimuth_deg"], a.attrs["sun_zenith_deg"])
        view = np.stack([np.asarray(enu_from_azimuth_zenith(az, zen)) for az, zen in zip(
            a["view_azimuth"].values.ravel(), a["view_zenith"].values.ravel())]).reshape(a["view_zenith"].shape + (3,))
        near = np.degrees(np.arccos(np.clip(np.nan_to_num(view) @ sun, -1, 1))) < 5.0
        for key in ("radiance", "radiance_clear", "radiance_cloud", "tau_hydrometeor"):
            x, y = a[key].values, b[key].values
            np.testing.assert_array_equal(np.isnan(x), np.isnan(y), err_msg=key)
            far = ~near if x.ndim == 2 else np.broadcast_to(~near, x.shape)
            np.testing.assert_allclose(y[far], x[far], rtol=2e-5, atol=1e-7, err_msg=key)
            np.testing.assert_allclose(y[~far], x[~far], rtol=3e-3, err_msg=key)
    assert (images[True, 40.0]["radiance"] != images[True, 60.0]["radiance"]).any()
    ray_table.forget_ray_tables()
    assert not ray_table._LAST_TABLE


@pytest.mark.full  # the JAX kernel's programs compile for tens of seconds on an empty cache: the full tier
def test_camera_table_is_rebuilt_for_another_observer():
    scene = swim.default_scene()
    ray_table.forget_ray_tables()
    settings = MarchSettings(execution=ExecutionSettings(backend="jax", chunk=1024, ray_table=True))
    swim.render(scene, camera="allsky", camera_options={"size": 16}, sun_zenith=40.0, sun_azimuth=120.0,
                settings=settings)
    first = ray_table._LAST_TABLE["entry"][2]
    swim.render(scene, camera="allsky", camera_options={"size": 16}, sun_zenith=40.0, sun_azimuth=120.0,
                settings=settings, height=50.0)
    second = ray_table._LAST_TABLE["entry"][2]
    assert second is not first and second.key != first.key
    ray_table.forget_ray_tables()


def test_cli_passes_the_ray_table_to_the_render(tmp_path, monkeypatch):
    """``swim render --ray-table`` / ``--no-ray-table`` set ExecutionSettings.ray_table; without either it stays None
    (the device decides: MarchSettings.resolved_ray_table); ``--step1a-on-device/--no-step1a-on-device`` and
    ``--device-sampling/--no-device-sampling`` and ``--device-image/--no-device-image`` likewise, None without
    them."""
    from typer.testing import CliRunner

    import swim.pipeline
    from swim.cli.main import app

    seen = []
    real = swim.pipeline.render

    def spy(*args, **kwargs):
        execution = kwargs["settings"].execution
        seen.append((execution.ray_table, execution.step1a_on_device, execution.device_sampling,
                     execution.device_image))
        return real(*args, **kwargs)

    monkeypatch.setattr(swim.pipeline, "render", spy)
    for k, flag in enumerate((["--ray-table"], ["--no-ray-table", "--step1a-on-device"], [],
                              ["--ray-table", "--adaptive", "--device-sampling", "--no-device-image"],
                              ["--no-step1a-on-device", "--adaptive", "--no-device-sampling", "--device-image"])):
        out = tmp_path / f"sky{k}.png"
        result = CliRunner().invoke(app, ["render", *flag, "--size", "9", "--sun-zenith", "40", "--sun-azimuth",
                                          "100", "--out", str(out)])
        assert result.exit_code == 0, result.output
        assert out.exists()
    assert seen == [(True, None, None, None), (False, True, None, None), (None, None, None, None),
                    (True, None, True, False), (None, False, False, True)]
