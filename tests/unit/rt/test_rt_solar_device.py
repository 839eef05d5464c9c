"""A new sun's Step 1a on the device's copy of the packed volume (swim.rt.solar_device, MarchSettings.step1a_on_device)
against the host's Step 1a (swim.rt.solar.solar_transmittance, both sweeps), and in a render."""

import jax.numpy as jnp
import numpy as np
import pytest

import swim
from swim import pipeline
from swim.errors import SwimInputError
from swim.frames import enu_from_azimuth_zenith
from swim.io.scene import scene_from_arrays
from swim.optics.volume import build_optical_volume
from swim.rt import device_copies, march_jax, solar_device
from swim.rt.march_inputs import KERNEL_STEP1A_VARIABLES, pack_volume, packed_species, share_packed_channels
from swim.rt.march_settings import ExecutionSettings, MarchSettings as _MarchSettings
from swim.rt.solar import solar_transmittance, step1a_levels

from test_rt_solar import RADIUS, _full_and_empty_scenes


def MarchSettings(**kw):  # noqa: N802 - a stand-in for the class in this module's tests
    """The render's settings with the paper's cloud scattering: Step 1a on the device serves
    ``cloud_scattering="albers2020"`` (the 3-D method's scaled beam is made on the host)."""
    return _MarchSettings(**{"cloud_scattering": "albers2020", **kw})


def _shared_volume(scene):
    volume = build_optical_volume(scene, dz=100.0)
    species = packed_species(volume)
    packed = pack_volume(volume, species)  # Step 1a's channels left undefined: every cell must be written
    share_packed_channels(volume, packed, species)
    return volume, packed, species


def _scenes(which):
    """Cloud, terrain and a 3-D aerosol; a low cloud under a ridge that rises above it (the terrain the highest
    field swept), no aerosol; nothing to sweep at all."""
    if which == "ridge above a low cloud":
        n, spacing = 21, 500.0
        x = (np.arange(n) - n // 2) * spacing
        z = np.arange(0.0, 3000.0, 100.0) + 50.0
        zz, yy, xx = np.meshgrid(z, x, x, indexing="ij")
        cloud = 4e-4 * (np.abs(zz - 600) < 200) * (np.abs(xx - 2000) < 1500) * (np.abs(yy) < 2000)
        terrain = np.broadcast_to(2200.0 * np.exp(-((x + 1500) / 1200.0) ** 2)[None, :], (n, n)).copy()
        return scene_from_arrays(x=x, y=x, z=z, reference_lat=45.0, reference_lon=7.0, terrain_height=terrain,
                                 cloud_liquid_content=cloud, cloud_liquid_effective_radius=RADIUS)
    return _full_and_empty_scenes()[0 if which.startswith("cloud") else 1]


@pytest.mark.parametrize("backend", [pytest.param("jax", marks=pytest.mark.full), "numba"])
@pytest.mark.parametrize("zenith, azimuth", [(20.0, 135.0), (87.0, 250.0), (95.0, 60.0)],
                         ids=["high sun", "low sun (4 sub-steps per level)", "sun below the horizon"])
@pytest.mark.parametrize("which", ["cloud, terrain and 3-D aerosol", "ridge above a low cloud", "nothing to sweep"])
def test_device_channels_are_the_hosts_step_1a(which, zenith, azimuth, backend):
    """Every level of T, the terrain's shadow and the 3-D aerosol's optical depth towards the sun as the host's Step
    1a makes them (JAX's sweep and numba's; float32 round-off: the species' sums and the terrain's field are made in
    another order there), under a high sun, a low one (several sub-steps per level) and one below the horizon (the
    sweep's and T's clamped elevations); the device's copy and the host's channels the same values; the grid's
    channels untouched."""
    scene = _scenes(which)
    sun = enu_from_azimuth_zenith(azimuth, zenith)
    volume, packed, species = _shared_volume(scene)
    expected = solar_transmittance(volume, sun, variables=KERNEL_STEP1A_VARIABLES, backend=backend)
    grid_channels = packed[..., :len(species)].copy()
    device = jnp.asarray(np.where(np.isfinite(packed), packed, 0.0))  # an "earlier sun's" copy: its channels junk
    got, device_packed = solar_device.solar_transmittance_on_device(volume, sun, device, packed, species,
                                                                    step1a_levels(volume))
    for name in KERNEL_STEP1A_VARIABLES:
        np.testing.assert_allclose(got[name].values, expected[name].values, rtol=2e-5, atol=2e-6, err_msg=name)
    if which != "nothing to sweep":
        assert got["cloud_transmittance"].values.min() < 0.5 and got["terrain_shadow"].values.min() < 0.05
    if which.startswith("cloud"):
        assert got["aerosol_tau_sun"].values.max() > 0.1
    np.testing.assert_array_equal(np.asarray(device_packed), packed)
    np.testing.assert_array_equal(packed[..., :len(species)], grid_channels)


def test_the_donating_refill_gives_the_same_channels_and_frees_the_old_copy(monkeypatch):
    """The GPU's program, which reuses the old copy's memory (donated), forced on this device: the same channels as
    the host's Step 1a, and the old copy deleted."""
    monkeypatch.setattr(solar_device, "_refill_copying", solar_device._refill_donating)
    volume, packed, species = _shared_volume(_scenes("cloud, terrain and 3-D aerosol"))
    sun = enu_from_azimuth_zenith(300.0, 60.0)
    expected = solar_transmittance(volume, sun, variables=KERNEL_STEP1A_VARIABLES)
    old = jnp.array(np.where(np.isfinite(packed), packed, 0.0))  # an array of JAX's own
    got, new = solar_device.solar_transmittance_on_device(volume, sun, old, packed, species, step1a_levels(volume))
    assert old.is_deleted()
    for name in KERNEL_STEP1A_VARIABLES:
        np.testing.assert_allclose(got[name].values, expected[name].values, rtol=2e-5, atol=2e-6, err_msg=name)
    np.testing.assert_array_equal(np.asarray(new), packed)


@pytest.mark.full  # the JAX kernel's programs compile for tens of seconds on an empty cache: the full tier
def test_the_kernel_is_compiled_once_whatever_the_switches_it_does_not_read():
    """MarchSettings.ray_table (None or False) and step1a_on_device are not the march kernel's settings: a render with
    other values of them runs the same compiled program (a recompilation takes tens of seconds on a GPU)."""
    scene = swim.default_scene()
    kwargs = dict(camera_options={"size": 24}, sun_zenith=35.0, sun_azimuth=140.0)

    def programs():
        return len(march_jax._trace_chunk._calls) + march_jax._trace_chunk.jitted._cache_size()

    swim.render(scene, settings=MarchSettings(execution=ExecutionSettings(backend="jax")), **kwargs)
    before = programs()
    for settings in (MarchSettings(execution=ExecutionSettings(backend="jax", ray_table=False)),
                     MarchSettings(execution=ExecutionSettings(backend="jax", ray_table=False, step1a_on_device=True))):
        swim.render(scene, settings=settings, **kwargs)
    assert programs() == before


def test_refill_checks_its_inputs():
    scene = _full_and_empty_scenes()[0]
    volume, packed, species = _shared_volume(scene)
    levels = step1a_levels(volume)
    sun = enu_from_azimuth_zenith(135.0, 40.0)
    with pytest.raises(SwimInputError, match="is not float32 of shape"):
        solar_device.refill_step1a_channels(jnp.asarray(packed[..., :-1]), volume, sun, len(species), True, levels)
    with pytest.raises(SwimInputError, match="species"):
        solar_device.refill_step1a_channels(jnp.asarray(packed[..., 1:]), volume, sun, len(species) - 1, True,
                                            levels)
    with pytest.raises(SwimInputError, match="step1a_on_device must be True, False or None"):
        MarchSettings(execution=ExecutionSettings(step1a_on_device="yes"))


@pytest.mark.full
def test_a_new_sun_in_a_render_refills_the_device_copy(monkeypatch):
    """With MarchSettings.step1a_on_device, a render's new sun takes the device's path where the JAX kernel left a
    copy of the packed volume (not the first sun: no copy yet), gives the host path's image, and leaves the device's
    copy as the JAX kernel's (no copy sent again) with the host's values."""
    scene = swim.default_scene()
    calls = []
    real = solar_device.solar_transmittance_on_device
    monkeypatch.setattr(solar_device, "solar_transmittance_on_device",
                        lambda *args: calls.append(1) or real(*args))
    images = {}
    for on_device in (False, True):
        pipeline.STATE.stages.clear()
        settings = MarchSettings(execution=ExecutionSettings(backend="jax", step1a_on_device=on_device))
        kwargs = dict(camera_options={"size": 40}, settings=settings, sun_azimuth=200.0)
        swim.render(scene, sun_zenith=30.0, **kwargs)
        assert calls == []  # the first sun: no device copy to refill
        images[on_device] = swim.render(scene, sun_zenith=55.0, **kwargs)["radiance"].values
        assert len(calls) == (1 if on_device else 0)
        packed = pipeline.STATE.stages._entries["grid constants"][1]["volume"]
        # the step classes of this sun (march_inputs.step_classes), written over the last sun's in place
        classes = pipeline.STATE.stages._entries["grid constants"][1]["occupancy"]
        assert classes is pipeline.STATE.stages._entries["step classes"][1]
        copies = device_copies.kept_device_copies({"volume": packed, "occupancy": classes})
        assert copies is not None, "the kernel's device copy of this sun's volume"
        np.testing.assert_array_equal(np.asarray(copies["volume"]), packed)
        # the kernel's constants take that copy: nothing is sent again
        assert march_jax._device_constants(pipeline.STATE.stages._entries["grid constants"][1])["volume"] is \
            copies["volume"]
    np.testing.assert_allclose(images[True], images[False], rtol=1e-4, atol=1e-6)


def test_a_render_alone_after_one_beside_others_reuses_its_step_classes(monkeypatch):
    """A render beside others packs its own volume and step classes (march_inputs.step_classes); the next render alone
    refills that packed volume in place, and must refill those classes too (not an older render's), so that the
    device copies the render beside others made still match them (kept_device_copies)."""
    scene = swim.default_scene()
    kwargs = dict(camera_options={"size": 24}, sun_azimuth=140.0, settings=MarchSettings())
    pipeline.STATE.stages.clear()
    swim.render(scene, sun_zenith=30.0, **kwargs)
    first = pipeline.STATE.stages._entries["step classes"][1]
    monkeypatch.setattr(pipeline.STATE, "rendering_alone", lambda: False)
    swim.render(scene, sun_zenith=40.0, **kwargs)
    beside = pipeline.STATE.stages._entries["grid constants"][1]
    assert beside["occupancy"] is not first
    monkeypatch.undo()
    swim.render(scene, sun_zenith=50.0, **kwargs)
    alone = pipeline.STATE.stages._entries["grid constants"][1]
    assert alone["volume"] is beside["volume"] and alone["occupancy"] is beside["occupancy"]
