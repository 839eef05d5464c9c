"""swim.memory: giving the C heap's freed pages back between a render's stages."""

import platform

import numpy as np

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
    kwargs = dict(camera="allsky", camera_options={"size": 16}, sun_zenith=30.0, sun_azimuth=120.0)
    swim.render(scene, **kwargs)  # builds the scene's stages (and trims after them)
    calls = []
    monkeypatch.setattr(pipeline, "release_free_memory", lambda: calls.append(1) or False)
    swim.render(scene, **kwargs)
    assert calls == []
    monkeypatch.setattr(pipeline, "TRIM_MIN_PIXELS", 16 * 16)
    image = swim.render(scene, **kwargs)
    assert len(calls) == 2 and image["rgb"].shape == (16, 16, 3)
