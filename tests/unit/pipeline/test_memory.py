"""swim.memory: giving the C heap's freed pages back between a render's stages, and JAX's compiled programs before the
process runs out of memory mappings."""

import platform
import sys

import numpy as np
import pytest

import swim.memory as memory


def test_release_free_memory_keeps_live_arrays_and_reports_a_bool():
    live = np.arange(3_000_000, dtype=np.float64)  # 24 MB: a live array must survive the trim unchanged
    garbage = [np.ones(100_000) for _ in range(50)]  # 800 kB blocks, freed below
    del garbage
    released = memory.release_free_memory()
    assert isinstance(released, bool)
    assert live[-1] == 2_999_999.0 and live.sum() == 2_999_999 * 3_000_000 / 2
    if platform.libc_ver()[0] == "glibc":
        assert memory._malloc_trim() is not None, "glibc has malloc_trim"


def test_release_free_memory_is_a_no_op_without_malloc_trim(monkeypatch):
    monkeypatch.setattr(memory, "_malloc_trim", lambda: None)
    assert memory.release_free_memory() is False


def test_a_render_trims_the_heap_only_for_images_of_many_pixels(monkeypatch):
    """render trims the heap after the march and at its end for images of TRIM_MIN_PIXELS pixels and more; a small
    image skips both trims (each walks the whole heap, a tenth of a 41 x 41 render), its set-up's trims stay."""
    import swim
    import swim.pipeline as pipeline

    scene = swim.default_scene()
    kwargs = dict(camera="allsky", camera_options={"size": 16}, sun_zenith=30.0, sun_azimuth=120.0,
                  settings=swim.MarchSettings(cloud_scattering="albers2020"))
    swim.render(scene, **kwargs)  # builds the scene's stages (and trims after them)
    calls = []
    for stage in (pipeline.chain, pipeline.scene_stage, pipeline.tables):  # every stage's trims
        monkeypatch.setattr(stage, "release_free_memory", lambda: calls.append(1) or False)
    swim.render(scene, **kwargs)
    assert calls == []
    monkeypatch.setattr(pipeline.chain, "TRIM_MIN_PIXELS", 16 * 16)
    image = swim.render(scene, **kwargs)
    assert len(calls) == 2 and image["rgb"].shape == (16, 16, 3)


@pytest.mark.full  # the JAX kernel's programs compile for tens of seconds on an empty cache: the full tier
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc/self/maps and vm.max_map_count are Linux's")
def test_compiled_programs_are_dropped_above_the_share_of_the_mapping_limit(monkeypatch):
    """Each XLA:CPU executable that JAX keeps holds memory mappings of its own; above the given share of
    vm.max_map_count they are dropped (and their mappings with them), below it nothing happens."""
    import gc

    import jax
    import jax.numpy as jnp

    monkeypatch.setattr(memory, "_floor", [0])  # no earlier drop of this worker's that waits for growth

    limit = memory.memory_mapping_limit()
    assert limit is not None and limit > 1000
    with open("/proc/self/maps", "rb") as f:
        assert memory.memory_mapping_count() == pytest.approx(f.read().count(b"\n"), abs=5)
    cpu = jax.devices("cpu")[0]  # XLA:CPU executables hold host mappings (a GPU's would not)
    programs = [jax.jit(lambda x, i=i: jnp.sin(x * (i + 1.5)) + i) for i in range(120)]  # alive until the end
    x = jax.device_put(np.ones(5, np.float32), cpu)
    for program in programs:
        program(x).block_until_ready()
    gc.collect()  # an earlier test's programs freed now, not between the counts below
    held = memory.memory_mapping_count()
    assert memory.release_compiled_programs(fraction=(held + 100) / limit) is False  # below the share: kept
    assert memory.memory_mapping_count() >= held - 5
    assert memory.release_compiled_programs(fraction=(held - 100) / limit) is True
    assert memory.memory_mapping_count() < held - 120  # ~3 mappings per executable went
    assert float(programs[7](jax.device_put(np.zeros(5, np.float32), cpu))[0]) == 7.0  # compiled again when called


def test_release_compiled_programs_checks_its_arguments_and_its_interval(monkeypatch):
    import jax

    with pytest.raises(ValueError, match="fraction"):
        memory.release_compiled_programs(fraction=0.0)
    with pytest.raises(ValueError, match="min_interval_s"):
        memory.release_compiled_programs(min_interval_s=-1.0)
    counted = []
    monkeypatch.setattr(memory, "memory_mapping_count", lambda: counted.append(1) or 10**9)
    monkeypatch.setattr(memory, "memory_mapping_limit", lambda: 100)
    monkeypatch.setattr(jax, "clear_caches", lambda: counted.append("cleared"))
    monkeypatch.setattr(memory, "_last_check", [float("-inf")])
    monkeypatch.setattr(memory, "_floor", [0])
    assert memory.release_compiled_programs(min_interval_s=3600.0) is True
    assert memory.release_compiled_programs(min_interval_s=3600.0) is False  # within the interval: not counted
    assert counted.count("cleared") == 1 and counted.count(1) == 2  # the count before and after the one drop


def test_programs_are_not_dropped_again_while_the_mappings_are_not_jax_s(monkeypatch, caplog):
    """A drop that leaves the process above the share (the mappings are someone else's) is logged as a warning, and
    the next drop waits for REDROP_MARGIN of the limit's growth, rather than recompiling everything at every check."""
    import logging

    import jax

    counts = iter([800, 700,  # above the share of 1000 · 0.5, and still after the drop
                   760,  # grown by less than REDROP_MARGIN · 1000 = 100 over 700: no drop
                   820, 300])  # grown by more: dropped again, and now under the share
    cleared = []
    monkeypatch.setattr(memory, "memory_mapping_count", lambda: next(counts))
    monkeypatch.setattr(memory, "memory_mapping_limit", lambda: 1000)
    monkeypatch.setattr(jax, "clear_caches", lambda: cleared.append(1))
    monkeypatch.setattr(memory, "_last_check", [float("-inf")])
    monkeypatch.setattr(memory, "_floor", [0])
    with caplog.at_level(logging.INFO, logger="swim.memory"):
        assert memory.release_compiled_programs() is True
        assert "not JAX's" in caplog.text and memory._floor[0] == 700
        assert memory.release_compiled_programs() is False
        assert memory.release_compiled_programs() is True
    assert len(cleared) == 2 and memory._floor[0] == 0


def test_a_render_checks_the_process_s_memory_mappings(monkeypatch):
    """render asks swim.memory to drop JAX's programs near the mapping limit, at most every COMPILED_PROGRAMS_CHECK_S."""
    import swim
    import swim.pipeline as pipeline

    calls = []
    monkeypatch.setattr(pipeline.chain, "release_compiled_programs", lambda **kw: calls.append(kw) or False)
    swim.render(swim.default_scene(), camera="allsky", camera_options={"size": 16}, sun_zenith=30.0,
                sun_azimuth=120.0)
    assert calls == [{"min_interval_s": pipeline.chain.COMPILED_PROGRAMS_CHECK_S}]
