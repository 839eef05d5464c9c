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
