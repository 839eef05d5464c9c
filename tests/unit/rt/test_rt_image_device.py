"""The image finished on the device (``MarchSettings.device_image``): planes and colour there, one copy to the host."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

import swim
import swim.color.srgb_device
from swim.errors import SwimInputError
from swim.rt import ray_table
from swim.rt.image_device import planes_on_device
from swim.rt.image_sampling import AdaptiveSampling
from swim.rt.march_settings import ExecutionSettings, MarchSettings as _MarchSettings


def MarchSettings(**kw):  # noqa: N802 - a stand-in for the class in this module's tests
    """The render's settings with the paper's cloud scattering: the image made on the device serves
    ``cloud_scattering="albers2020"`` (the 3-D method keeps the camera's rays on the host)."""
    return _MarchSettings(**{"cloud_scattering": "albers2020", **kw})


#: Images made on the device run the JAX kernel, whose programs compile for minutes on an empty cache: the full tier.
pytestmark = pytest.mark.full

OUTPUTS = ("radiance", "radiance_clear", "radiance_cloud", "radiance_surface", "tau_hydrometeor", "rgb",
           "view_zenith", "view_azimuth")


def render_pair(sampling, sun_zenith=40.0, size=48, **extra):
    """The default scene's all-sky with the camera's rays on the device, the image finished on the host and on the
    device."""
    scene = swim.default_scene()
    return [swim.render(scene, camera="allsky", camera_options={"size": size}, sun_zenith=sun_zenith,
                        sun_azimuth=120.0, sampling=sampling,
                        settings=MarchSettings(**extra,
                                               execution=ExecutionSettings(backend="jax", chunk=1024, ray_table=True,
                                                                           device_image=on)))
            for on in (False, True)]


@pytest.mark.parametrize("sampling", [None, AdaptiveSampling()], ids=["every pixel", "adaptive"])
def test_the_image_made_on_the_device_is_the_hosts(sampling):
    """The same rays marched, the same planes bit for bit (a scatter copies values), the same direct transmittance
    and sun's disk, and the same 8-bit codes (the colour stage's float64 arithmetic in the host kernel's order); the
    sun (zenith 40 deg) is in the image, so its disk's pixels are recoloured on the host."""
    ray_table.forget_ray_tables()
    try:
        host, device = render_pair(sampling)
        for key in ("traced_pixels", "march_samples", "direct_transmittance"):
            np.testing.assert_array_equal(device.attrs[key], host.attrs[key], err_msg=key)
        for key in OUTPUTS:
            np.testing.assert_array_equal(device[key].values, host[key].values, err_msg=key)
            assert device[key].values.flags.writeable, key
        # the disk: its pixels are the brightest of the image (4 pi T / solid angle), saturated in the 8-bit image
        radiance = host["radiance"].values
        brightest = np.unravel_index(np.nanargmax(radiance[1]), radiance.shape[1:])
        assert radiance[1][brightest] > 100 and device["rgb"].values[brightest].max() == 255
    finally:
        ray_table.forget_ray_tables()


def test_pixels_left_to_the_host_are_coloured_there(monkeypatch):
    """Where the device flags a pixel (its spectrum may need clipping), the host's colour stage gives its codes: with
    every pixel flagged and the device's codes zeroed, the image is still the host's."""
    real = swim.color.srgb_device.solar_relative_to_srgb8_device

    def flag_all(radiance, white_level, **kwargs):
        codes, _ = real(radiance, white_level, **kwargs)
        return jnp.zeros_like(codes), jnp.ones(codes.shape[:-1], bool)

    ray_table.forget_ray_tables()
    try:
        host, _ = render_pair(None, size=24)
        monkeypatch.setattr(swim.color.srgb_device, "solar_relative_to_srgb8_device", flag_all)
        _, device = render_pair(None, size=24)
        np.testing.assert_array_equal(device["rgb"].values, host["rgb"].values)
        assert host["rgb"].values.max() > 0
    finally:
        ray_table.forget_ray_tables()


def test_device_image_resolves_on_accelerators_beside_the_table(monkeypatch):
    """None (the default) is on where the JAX kernel runs on a GPU beside the ray table, off on a CPU; True needs the
    table; the numba kernel never; not a kernel setting (a compiled kernel serves either); a bad value is named."""
    import jax

    assert MarchSettings().device_image is None
    with pytest.raises(SwimInputError, match="device_image must be True, False or None"):
        MarchSettings(execution=ExecutionSettings(device_image="yes"))
    on = MarchSettings(execution=ExecutionSettings(device_image=True))
    assert on.kernel_settings() == MarchSettings().kernel_settings()
    monkeypatch.setattr(jax, "default_backend", lambda: "cpu")
    assert MarchSettings(execution=ExecutionSettings(backend="jax", ray_table=True)).resolved_device_image() is False
    assert MarchSettings(execution=ExecutionSettings(backend="jax", ray_table=True,
                                                     device_image=True)).resolved_device_image() is True
    assert MarchSettings(execution=ExecutionSettings(backend="jax", device_image=True)).resolved_device_image() is False
    assert MarchSettings(execution=ExecutionSettings(backend="numba", ray_table=True,
                                                     device_image=True)).resolved_device_image() is False
    from swim.rt import precompile

    monkeypatch.setattr(precompile, "jax_may_see_a_gpu", lambda: True)  # JAX is asked only where it may see one
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    assert MarchSettings(execution=ExecutionSettings(backend="jax")).resolved_device_image() is True
    assert MarchSettings(execution=ExecutionSettings(backend="jax",
                                                     device_image=False)).resolved_device_image() is False
    assert MarchSettings(execution=ExecutionSettings(backend="jax", ray_table=False)).resolved_device_image() is False


def test_planes_on_device_scatters_the_pixels_rows():
    """Rows in the pixels' order land at their pixels, NaN elsewhere; 1-D outputs become one-channel planes; the row
    after the pixels is the sun's; too few rows are named."""
    pixels = np.array([5, 0, 7, 2])
    rows = jnp.arange(6 * 3, dtype=jnp.float32).reshape(6, 3)  # 4 pixels, the sun, one padding row
    outputs = {"radiance": rows, "tau_hydrometeor": rows[:, 0], "steps": jnp.full(6, 9, jnp.int32)}
    planes, sun, steps = planes_on_device(outputs, pixels, (3, 3), ("radiance", "tau_hydrometeor"),
                                          sun_keys=("radiance",))
    radiance = np.asarray(planes["radiance"]).reshape(3, -1)
    assert planes["radiance"].shape == (3, 3, 3) and planes["tau_hydrometeor"].shape == (1, 3, 3)
    np.testing.assert_array_equal(radiance[:, pixels], np.asarray(rows[:4]).T)
    others = np.setdiff1d(np.arange(9), pixels)
    assert np.isnan(radiance[:, others]).all()
    np.testing.assert_array_equal(np.asarray(planes["tau_hydrometeor"]).reshape(-1)[pixels], np.asarray(rows[:4, 0]))
    np.testing.assert_array_equal(np.asarray(sun["radiance"]), np.asarray(rows[4]))
    assert int(steps) == 9
    with pytest.raises(ValueError, match="rows of outputs"):
        planes_on_device({key: value[:4] for key, value in outputs.items()}, pixels, (3, 3), ("radiance",),
                         sun_keys=("radiance",))


KW = dict(camera="allsky", camera_options={"size": 24}, sun_zenith=40.0, sun_azimuth=120.0, settings=MarchSettings())


@pytest.fixture
def speculating(monkeypatch):
    """swim.pipeline with digests taken by identity (as on a GPU), empty caches, and a record of the guesses."""
    import swim.pipeline as pipeline

    pipeline.STATE.stages.clear()
    pipeline.STATE.last_digest.forget()
    monkeypatch.setattr(pipeline.scene_stage, "speculate_digest", lambda settings: True)
    guesses = []
    real = pipeline.caches.DigestGuess.start
    monkeypatch.setattr(pipeline.caches.DigestGuess, "start", lambda self, guess, scene: guesses.append(guess) or
                        real(self, guess, scene))
    yield pipeline, guesses
    pipeline.STATE.stages.clear()
    pipeline.STATE.last_digest.forget()


def test_a_digest_taken_by_identity_is_checked(speculating, caplog):
    """Where the march runs on a GPU, a scene rendered before (the same arrays) takes its last digest at once and is
    hashed meanwhile: the image is the one of a render that hashed it first; values changed in place are found by
    that check, and the scene is rendered again from its new values."""
    import logging

    pipeline, guesses = speculating
    scene = swim.default_scene().copy(deep=True)
    first = swim.render(scene, **KW)
    second = swim.render(scene, **KW)
    assert len(guesses) == 1  # the second render's
    np.testing.assert_array_equal(second["radiance"].values, first["radiance"].values)
    cloud = scene["cloud_liquid_content"]
    assert cloud.nbytes >= pipeline.caches.IDENTITY_MIN_BYTES and float(cloud.values.max()) > 0
    cloud.values[...] = 0.0  # no liquid cloud left: the same arrays, new values
    with caplog.at_level(logging.WARNING, logger="swim.pipeline"):
        changed = swim.render(scene, **KW)
    assert len(guesses) == 2 and "changed in place" in caplog.text
    pipeline.STATE.stages.clear()
    pipeline.STATE.last_digest.forget()
    fresh = swim.render(scene, **KW)
    np.testing.assert_array_equal(changed["radiance"].values, fresh["radiance"].values)
    assert not np.array_equal(changed["radiance"].values, first["radiance"].values, equal_nan=True)


def test_an_error_from_stale_stages_renders_again(speculating, monkeypatch):
    """An error raised by a render whose guessed digest did not hold (its stages were of the old values) is not the
    caller's: the scene is rendered again from its values; where the guess held, the error is raised."""
    pipeline, guesses = speculating
    scene = swim.default_scene().copy(deep=True)
    swim.render(scene, **KW)
    real = pipeline.terrain_at
    failures = []

    def fail_once(*args):
        if not failures:
            failures.append(1)
            raise SwimInputError("an error of the stages of the old values")
        return real(*args)

    monkeypatch.setattr(pipeline.scene_stage, "terrain_at", fail_once)
    with pytest.raises(SwimInputError, match="old values"):  # the guess held: the error is the scene's
        swim.render(scene, **KW)
    assert len(guesses) == 1
    failures.clear()
    scene["cloud_liquid_content"].values[...] = 0.0
    image = swim.render(scene, **KW)  # the guess did not hold: rendered again, without the error
    assert len(guesses) == 2 and len(failures) == 1
    pipeline.STATE.stages.clear()
    np.testing.assert_array_equal(image["radiance"].values, swim.render(scene, **KW)["radiance"].values)


def test_nothing_is_built_under_a_guessed_digest_that_does_not_hold(speculating, monkeypatch):
    """The optical volume evicted between the guess and its use (by another scene's render or another thread's): the
    scene's new values are not built under the old digest, where a render of the old values in the meantime (another
    thread's, here one inside this render, after its volume) would take them."""
    pipeline, guesses = speculating
    scene = swim.default_scene().copy(deep=True)
    original = scene.copy(deep=True)
    before = swim.render(scene, **KW)
    scene["cloud_liquid_content"].values[...] = 0.0
    real_get = pipeline.STATE.stages.get
    meanwhile = []

    def evicted(key, build):
        if key[0] == "volume" and not meanwhile:  # the stages gone when the render asks for its volume
            pipeline.STATE.stages.clear()
        if key[0] == "atmosphere inputs" and not meanwhile:  # after this render's volume: a render of the old values
            meanwhile.append(None)
            meanwhile[0] = swim.render(original, **KW)
        return real_get(key, build)

    monkeypatch.setattr(pipeline.STATE.stages, "get", evicted)
    swim.render(scene, **KW)
    assert len(guesses) == 1 and meanwhile
    np.testing.assert_array_equal(meanwhile[0]["radiance"].values, before["radiance"].values)


def test_scene_identity_holds_for_the_same_arrays_only():
    """The same dataset, and a crop-like view of it, keep their identity; a copy, a changed attribute or a changed
    small coordinate do not."""
    import swim.pipeline as pipeline

    scene = swim.default_scene()
    same = pipeline.caches.same_identity
    identity = pipeline.caches.scene_identity(scene)
    assert identity is not None and same(identity, pipeline.caches.scene_identity(scene))
    assert same(identity, pipeline.caches.scene_identity(scene.copy(deep=False)))
    assert not same(identity, pipeline.caches.scene_identity(scene.copy(deep=True)))
    assert not same(identity, pipeline.caches.scene_identity(scene.assign_attrs(title="another")))
    x = scene["x"].values.copy()
    x[0] -= 1.0
    assert not same(identity, pipeline.caches.scene_identity(scene.assign_coords(x=x)))
    lazy = scene.chunk()
    assert pipeline.caches.scene_identity(lazy) is None or not same(identity, pipeline.caches.scene_identity(lazy))


def test_progress_of_an_image_made_on_the_device():
    """With every pixel traced on the device, progress is reported as each chunk's march is done (as on the host's
    path), the last call with every ray (the pixels' and the sun's)."""
    scene = swim.default_scene()
    calls = []
    ray_table.forget_ray_tables()
    try:
        swim.render(scene, camera="allsky", camera_options={"size": 40}, sun_zenith=40.0, sun_azimuth=120.0,
                    settings=MarchSettings(execution=ExecutionSettings(backend="jax", chunk=256, ray_table=True,
                                                                       device_image=True)),
                    progress=lambda done, total: calls.append((done, total)))
    finally:
        ray_table.forget_ray_tables()
    totals = {total for _, total in calls}
    done = [d for d, _ in calls]
    assert len(calls) >= 4 and len(totals) == 1 and done == sorted(done) and done[-1] == totals.pop()
