"""The optical volume and Step 1a (in the grid's kernel constants) are reused between renders only while the
scene and the sun stay the same."""

import logging

import numpy as np
import pytest

import swim
from swim import pipeline
from swim.errors import SwimInputError


#: The stages are tested with the paper's cloud scattering (no diffuse solve for each new sun); the 3-D solution's
#: own stage: test_the_3d_solution_is_kept_for_the_suns_near_its_node
PAPER = swim.MarchSettings(cloud_scattering="albers2020")


def _render(scene, **kw):
    kw.setdefault("settings", PAPER)
    return swim.render(scene, camera="allsky", camera_options={"size": 17}, sun_zenith=kw.pop("sun_zenith", 40.0),
                       sun_azimuth=150.0, **kw)


def test_the_3d_solution_is_kept_for_the_suns_near_its_node(caplog):
    """The diffuse solution is a stage of its own, keyed by the node of the sun (swim.rt.diffuse_field.solve_sun):
    a sun 0.3 deg away reuses it (scaled to its cosine), one 5 deg away solves anew, and a render gets the same image
    whichever render came before."""
    from swim.validation.stratus import stratus_scene

    deck = stratus_scene(10.0, n_columns=5)
    kw = {"settings": swim.MarchSettings()}
    pipeline.STATE.stages.clear()
    first = _render(deck, sun_zenith=40.0, **kw)
    with caplog.at_level(logging.INFO, logger="swim.pipeline"):
        near = _render(deck, sun_zenith=40.3, **kw)
    assert "reusing the diffuse field of an earlier render" in caplog.text
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="swim.pipeline"):
        _render(deck, sun_zenith=45.0, **kw)
    assert "reusing the diffuse field" not in caplog.text
    pipeline.STATE.stages.clear()
    np.testing.assert_array_equal(near["radiance"].values, _render(deck, sun_zenith=40.3, **kw)["radiance"].values)
    assert not np.array_equal(near["radiance"].values, first["radiance"].values)


def test_3d_solutions_are_kept_across_scenes_a_few_at_a_time(caplog):
    """Renders that alternate between two scenes reuse each one's diffuse solution (kept apart from the one-scene
    stages, which hold grids); the oldest of more than SMALL_ENTRIES goes first."""
    from swim.validation.stratus import stratus_scene

    decks = [stratus_scene(tau, n_columns=5) for tau in (5.0, 10.0)]
    kw = {"settings": swim.MarchSettings()}
    pipeline.STATE.stages.clear()
    images = [_render(deck, **kw)["radiance"].values for deck in decks]
    with caplog.at_level(logging.INFO, logger="swim.pipeline"):
        again = _render(decks[0], **kw)["radiance"].values
    assert "reusing the diffuse field of an earlier render" in caplog.text
    np.testing.assert_array_equal(again, images[0])
    for zenith in range(20, 20 + 5 * pipeline.caches.SMALL_ENTRIES, 5):  # other sun nodes push the first deck's out
        _render(decks[1], sun_zenith=float(zenith), **kw)
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="swim.pipeline"):
        _render(decks[0], **kw)
    assert "reusing the diffuse field" not in caplog.text


def test_same_scene_reuses_stages_and_a_changed_scene_does_not(caplog):
    pipeline.STATE.stages.clear()
    scene = swim.default_scene()
    with caplog.at_level(logging.INFO, logger="swim.pipeline"):
        first = _render(scene)
        assert "reusing" not in caplog.text
        second = _render(scene)
        assert all(f"reusing the {kind}" in caplog.text for kind in ("volume", "constants"))
    np.testing.assert_array_equal(first["radiance"].values, second["radiance"].values)

    # a new sun: the volume and its occupancy grid are reused, Step 1a is not; the image is that of a fresh start
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="swim.pipeline"):
        new_sun = _render(scene, sun_zenith=60.0)
    assert "reusing the volume" in caplog.text and "reusing the grid constants" not in caplog.text
    assert "reusing the occupancy" in caplog.text
    pipeline.STATE.stages.clear()
    np.testing.assert_array_equal(new_sun["radiance"].values, _render(scene, sun_zenith=60.0)["radiance"].values)

    # another aerosol: the grid's constants (Step 1a, the packed volume) are reused, the atmosphere's are not
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="swim.pipeline"):
        _render(scene, sun_zenith=60.0, aerosol="maritime")
    assert "reusing the grid constants" in caplog.text and "reusing the constants" not in caplog.text

    # a warm render does not validate again, so the digest must see what validation checks (units)
    bad = scene.copy()
    bad["cloud_liquid_content"] = bad["cloud_liquid_content"].assign_attrs(units="g m-3")
    with pytest.raises(SwimInputError, match="units"):
        _render(bad)

    # the same object changed in place (clouds removed) must not be served from the cache
    for name in [v for v in scene.data_vars if v.endswith("_content")]:
        scene[name].values[...] = 0.0
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="swim.pipeline"):
        clear = _render(scene)
    assert "reusing" not in caplog.text
    assert float(np.nanmax(clear["tau_hydrometeor"].values)) == 0.0
    assert float(np.nanmax(first["tau_hydrometeor"].values)) > 1.0


def test_a_new_scene_drops_the_old_scenes_entries_before_building():
    cache = pipeline.caches.StageCache()
    cache.get(("volume", "scene A"), lambda: "volume A")
    cache.get(("grid constants", "scene A", (0, 0, 1)), lambda: "T A")
    cache.get(("constants", "scene A", (0, 0, 1), 7), lambda: "constants A")

    def build_b():
        # nothing of scene A may still be held while scene B's (big) volume is built
        assert cache._entries == {}
        return "volume B"

    assert cache.get(("volume", "scene B"), build_b) == "volume B"
    # same scene, new sun: the volume stays, Step 1a is rebuilt
    cache.get(("grid constants", "scene B", (0, 0, 1)), lambda: "T B")
    assert cache.get(("grid constants", "scene B", (0, 1, 0)), lambda: "T B2") == "T B2"
    assert cache.get(("volume", "scene B"), lambda: "rebuilt") == "volume B"


def test_a_new_sun_holds_one_set_of_grid_constants_at_a_time():
    """render() looks the grid's constants up inside the build of the constants: when the sun changes, the old
    entries (each holding the packed volume) are gone before the new packed volume is built."""
    cache = pipeline.caches.StageCache()
    cache.get(("volume", "B"), lambda: "volume B")
    cache.get(("constants", "B", "sun 1", 7), lambda: cache.get(("grid constants", "B", "sun 1"), lambda: "G1"))

    def build_grid():
        assert set(cache._entries) == {"volume"}, "the old sun's constants must be released first"
        return "G2"

    assert cache.get(("constants", "B", "sun 2", 7), lambda: cache.get(("grid constants", "B", "sun 2"), build_grid)) == "G2"
    assert set(cache._entries) == {"volume", "constants", "grid constants"}


@pytest.mark.parametrize("crop", [True, False])
def test_a_scene_that_is_not_a_dataset_is_a_clear_error(crop):
    with pytest.raises(SwimInputError, match="xarray.Dataset"):
        swim.render({"cloud_liquid_content": 1.0}, crop=crop, sun_zenith=30.0, sun_azimuth=0.0)


def test_a_lazy_scene_is_not_read_again_but_its_changes_are_seen(tmp_path, caplog):
    """A lazily opened scene is identified by its dask graph (file name and modification time, the crop's
    slices, attributes): a warm render reuses the stages without running a single dask task, while changed
    attributes (validated again) and a rewritten file (new values) are not served from the cache."""
    pytest.importorskip("dask")  # the scale extra
    import dask.array
    from dask.callbacks import Callback

    from swim.io.scene import open_scene

    class Tasks(Callback):
        def __init__(self):
            super().__init__()
            self.count = 0

        def _posttask(self, *args):
            self.count += 1

    pipeline.STATE.stages.clear()
    scene = swim.default_scene()
    path = tmp_path / "scene.nc"
    scene.to_netcdf(path)
    time = str(scene["time"].values)
    lazy = open_scene(path, lazy=True, time=time)
    assert isinstance(lazy["cloud_liquid_content"].data, dask.array.Array)
    for crop in (False, True):
        first = _render(lazy, crop=crop)
        with Tasks() as tasks, caplog.at_level(logging.INFO, logger="swim.pipeline"):
            caplog.clear()
            second = _render(lazy, crop=crop)
        assert "reusing the volume" in caplog.text
        if not crop:  # the crop reads a few columns of terrain each time; the scene itself is not read
            assert tasks.count == 0, f"a warm render of a lazy scene ran {tasks.count} dask tasks"
        np.testing.assert_array_equal(first["radiance"].values, second["radiance"].values)

    bad = lazy.copy()
    bad["cloud_liquid_content"] = bad["cloud_liquid_content"].assign_attrs(units="g m-3")
    with pytest.raises(SwimInputError, match="units"):
        _render(bad, crop=False)

    cleared = scene.copy()
    for name in [v for v in scene.data_vars if v.endswith("_content")]:
        cleared[name] = cleared[name] * 0.0
    path.unlink()
    cleared.to_netcdf(path)
    clear = _render(open_scene(path, lazy=True, time=time), crop=False)
    assert float(np.nanmax(first["tau_hydrometeor"].values)) > 1.0
    assert float(np.nanmax(clear["tau_hydrometeor"].values)) == 0.0


@pytest.mark.parametrize("threaded", [False, True])
def test_scene_digest_sees_every_value_and_attribute(monkeypatch, threaded):
    """The stage cache's key of an in-memory scene (a streaming digest per variable, on several threads for a big
    scene; a non-contiguous array copied in blocks of rows): equal scenes give equal digests, also when an array is
    laid out otherwise, and the same on threads as on one; one changed value (in a contiguous array, or in the last
    block of a non-contiguous one) or one changed attribute gives another."""
    import swim.digest

    monkeypatch.setattr(swim.digest, "BLOCK_BYTES", 256)  # a non-contiguous 3-D field spans many blocks
    scene = swim.default_scene()
    serial = pipeline.caches.fingerprint(scene)
    if threaded:  # every scene counts as big, on 3 threads
        monkeypatch.setattr(pipeline.caches, "FINGERPRINT_THREADED_BYTES", 0)
        monkeypatch.setenv("SWIM_NUM_THREADS", "3")
    digest = pipeline.caches.fingerprint(scene)
    assert digest == serial
    assert pipeline.caches.fingerprint(scene.copy(deep=True)) == digest
    name = next(n for n in scene.data_vars if scene[n].ndim == 3)
    changed = scene.copy(deep=True)
    changed[name].values.reshape(-1)[-1] += 1e-6  # the last value
    assert pipeline.caches.fingerprint(changed) != digest
    strided = scene.copy(deep=True)
    strided[name] = strided[name].copy(data=np.asfortranarray(strided[name].values))
    assert not strided[name].values.flags.c_contiguous
    assert pipeline.caches.fingerprint(strided) == digest  # the same values, laid out otherwise
    for index in ((0, 0, 0), (-1, -1, -1)):  # the first block, and the last
        changed = strided.copy(deep=True)
        changed[name] = changed[name].copy(data=np.asfortranarray(changed[name].values))
        changed[name].values[index] += 1e-6
        assert not changed[name].values.flags.c_contiguous
        assert pipeline.caches.fingerprint(changed) != digest
    attrs = scene.copy(deep=True)
    attrs[name].attrs["units"] = "g m-3"
    assert pipeline.caches.fingerprint(attrs) != digest


def test_scene_directions_are_the_camera_s_rotated_and_shared_by_equal_views():
    """The rays' directions in the scene frame (cached per camera and rotation): unit vectors, the camera's ENU
    directions times the rotation, zero outside its pixels; its valid pixels once each, in tile order; equal cameras
    and rotations share them (read-only), another rotation gets its own."""
    from swim.frames import enu_to_scene_rotation
    from swim.geometry.cameras import make_camera
    from swim.rt.image_sampling import tile_order

    camera = make_camera("allsky", size=33)
    dirs_enu, valid = camera.cached_directions()
    flat = np.flatnonzero(valid.reshape(-1))
    for lat, lon in ((40.0, -105.0), (41.0, -104.0)):
        rotation = enu_to_scene_rotation(lat, lon, 40.0, -105.0)
        dirs, pixels = pipeline.scene_stage.scene_directions(camera, rotation)
        assert dirs.shape == (33 * 33, 3) and not dirs.flags.writeable and not pixels.flags.writeable
        np.testing.assert_allclose(dirs[flat], dirs_enu.reshape(-1, 3)[flat] @ rotation, atol=1e-12)
        np.testing.assert_allclose(np.linalg.norm(dirs[flat], axis=1), 1.0, atol=1e-12)
        assert not dirs[~valid.reshape(-1)].any()
        np.testing.assert_array_equal(pixels, flat[tile_order(flat, camera.shape)])
        again = pipeline.scene_stage.scene_directions(make_camera("allsky", size=33), rotation.copy())
        assert again[0] is dirs and again[1] is pixels
    other = pipeline.scene_stage.scene_directions(camera, enu_to_scene_rotation(40.0, -105.0, 40.0, -105.0))
    assert not np.allclose(other[0][flat], dirs[flat])


@pytest.mark.parametrize("backend", ["numba", pytest.param("jax", marks=pytest.mark.full)])
def test_a_new_sun_refills_the_packed_volume_in_place(backend):
    """A new sun reuses the packed grid (its Step 1a channels filled again, no second copy of the grid) and the
    kernel's device copies of it are made again: every image equals a render from an empty cache."""
    pipeline.STATE.stages.clear()
    scene = swim.default_scene()
    settings = swim.MarchSettings(cloud_scattering="albers2020", execution=swim.ExecutionSettings(backend=backend))
    packed = []
    suns = (40.0, 65.0, 40.0)
    images = []
    for zenith in suns:
        images.append(_render(scene, sun_zenith=zenith, settings=settings)["radiance"].values)
        packed.append(pipeline.STATE.stages._entries["grid constants"][1]["volume"])
    assert packed[1] is packed[0] and packed[2] is packed[0]
    assert not packed[0].flags.writeable
    assert not np.array_equal(images[0], images[1])  # the suns differ enough to tell a stale Step 1a apart
    for zenith, image in zip(suns, images):
        pipeline.STATE.stages.clear()
        np.testing.assert_array_equal(image, _render(scene, sun_zenith=zenith, settings=settings)["radiance"].values)


def test_a_new_sun_beside_another_render_packs_the_grid_anew():
    """Where another render runs in the process (a dask worker's threads), it may still march through the shared
    packed volume with its own sun: a new sun then packs the grid anew instead of refilling that volume."""
    pipeline.STATE.stages.clear()
    scene = swim.default_scene()
    first = _render(scene, sun_zenith=40.0)
    packed = pipeline.STATE.stages._entries["grid constants"][1]["volume"]
    before = packed.copy()
    with pipeline.STATE.rendering():  # another render, still marching with the first sun
        _render(scene, sun_zenith=65.0)
    assert pipeline.STATE.stages._entries["grid constants"][1]["volume"] is not packed
    np.testing.assert_array_equal(packed, before)  # the first sun's volume untouched
    assert pipeline.STATE.running() == 0
    pipeline.STATE.stages.clear()
    np.testing.assert_array_equal(first["radiance"].values, _render(scene, sun_zenith=40.0)["radiance"].values)


def test_the_heap_is_trimmed_after_big_renders_on_the_host_only(monkeypatch):
    """The C heap's trims (swim.memory) follow a big image's march and a new sun's Step 1a on the host's cores, not
    those on a GPU (docs/decisions/0006-gpu-kernels.md)."""
    from swim.rt.march_settings import MarchSettings

    calls = []
    for stage in (pipeline.chain, pipeline.scene_stage, pipeline.tables):  # every stage's trims
        monkeypatch.setattr(stage, "release_free_memory", lambda: calls.append(1) or True)
    scene = swim.default_scene()
    size = {"size": 257}  # 51 900 valid pixels of 66 049: past TRIM_MIN_PIXELS
    assert 257 * 257 >= pipeline.chain.TRIM_MIN_PIXELS
    swim.render(scene, camera_options=size, sun_zenith=40.0, sun_azimuth=150.0, settings=PAPER)
    assert len(calls) >= 2
    calls.clear()
    # a new sun: Step 1a's trim too
    swim.render(scene, camera_options=size, sun_zenith=41.0, sun_azimuth=150.0, settings=PAPER)
    assert len(calls) == 3
    calls.clear()
    monkeypatch.setattr(MarchSettings, "on_accelerator", lambda self: True)
    swim.render(scene, camera_options=size, sun_zenith=40.0, sun_azimuth=150.0, settings=PAPER)
    swim.render(scene, camera_options=size, sun_zenith=42.0, sun_azimuth=150.0, settings=PAPER)  # a new sun
    assert calls == []


@pytest.mark.parametrize("variant", ["clear sky", "3-D aerosol"])
def test_a_new_sun_refills_the_packed_volume_of_a_clear_or_smoky_scene(variant):
    """The in-place refill with no hydrometeor channel at all (a clear sky) and with the 3-D aerosol's two
    channels: the same packed array for both suns, and the second sun's image that of an empty cache."""
    scene = swim.default_scene().copy(deep=True)
    if variant == "clear sky":
        for name in [v for v in scene.data_vars if v.endswith("_content")]:
            scene[name].values[...] = 0.0
    else:
        extinction = np.zeros(scene["cloud_liquid_content"].shape)
        extinction[: extinction.shape[0] // 3, 20:50, 20:50] = 2e-4
        scene["aerosol_extinction"] = (scene["cloud_liquid_content"].dims, extinction, {"units": "m-1"})
    pipeline.STATE.stages.clear()
    first = _render(scene, sun_zenith=30.0)["radiance"].values
    packed = pipeline.STATE.stages._entries["grid constants"][1]["volume"]
    species = pipeline.STATE.stages._entries["packed species"][1]
    assert (len(species) == 0) == (variant == "clear sky")
    assert packed.shape[-1] == len(species) + (2 if variant == "clear sky" else 4)  # + the aerosol's two channels
    second = _render(scene, sun_zenith=60.0)["radiance"].values
    assert pipeline.STATE.stages._entries["grid constants"][1]["volume"] is packed
    assert not np.array_equal(first, second)
    pipeline.STATE.stages.clear()
    np.testing.assert_array_equal(second, _render(scene, sun_zenith=60.0)["radiance"].values)


def test_renders_beside_each_other_build_their_grid_constants_one_at_a_time(monkeypatch):
    """Two renders in one process (a dask worker's threads), each with its own sun: while one points the shared
    optical volume's extinctions at its new packed volume (share_packed_channels deletes and re-adds the volume's
    species coordinate), the other must not read the volume (pack_volume found the coordinate gone: "'cloud_liquid'
    is not in list"). The sharing render waits inside share_packed_channels for the other to start packing; the
    other must only start after it has left."""
    import threading

    pipeline.STATE.stages.clear()
    scene = swim.default_scene()
    _render(scene, sun_zenith=40.0)  # the volume cached and shared
    inside, a_inside, b_packing = [None], threading.Event(), threading.Event()
    overlaps, errors, images = [], [], {}
    share, pack = pipeline.tables.share_packed_channels, pipeline.tables.pack_volume

    def sharing(volume, packed, species=None):
        if threading.current_thread().name == "render-a":
            inside[0] = "render-a"
            a_inside.set()
            b_packing.wait(1.0)  # without the lock the other render packs now
        try:
            return share(volume, packed, species)
        finally:
            inside[0] = None

    def packing(volume, species=None):
        if threading.current_thread().name == "render-b":
            overlaps.append(inside[0])
            b_packing.set()
        return pack(volume, species)

    monkeypatch.setattr(pipeline.tables, "share_packed_channels", sharing)
    monkeypatch.setattr(pipeline.tables, "pack_volume", packing)

    def run(name, zenith, wait=None):
        try:
            if wait is not None:
                wait.wait(10.0)
            images[name] = _render(scene, sun_zenith=zenith)["radiance"].values
        except Exception as error:  # noqa: BLE001 (reported below)
            errors.append(error)

    threads = [threading.Thread(target=run, args=("a", 50.0), name="render-a"),
               threading.Thread(target=run, args=("b", 60.0, a_inside), name="render-b")]
    with pipeline.STATE.rendering():  # a third render: neither refills the volume in place, both pack anew
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join(60.0)
    assert not errors, errors
    assert a_inside.is_set() and overlaps == [None]  # the other render packed, and not while the volume changed
    monkeypatch.undo()
    pipeline.STATE.stages.clear()
    for name, zenith in (("a", 50.0), ("b", 60.0)):
        np.testing.assert_array_equal(images[name], _render(scene, sun_zenith=zenith)["radiance"].values)
