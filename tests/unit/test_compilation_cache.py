"""The persistent caches only ever save time: hits, invalidation by code, switches."""

import pickle

from swim.rt.compilation_cache import cache_directory, disk_cached


def test_disk_cache_hits_across_calls_and_rebuilds_when_the_code_changes(tmp_path, monkeypatch):
    monkeypatch.setenv("SWIM_CACHE_DIR", str(tmp_path))
    monkeypatch.delenv("SWIM_JAX_CACHE", raising=False)
    source = tmp_path / "builder.py"
    source.write_text("v1")
    calls = []

    def build():
        calls.append(1)
        return {"value": len(calls)}

    assert disk_cached("test", ("a", 1), build, sources=[source]) == {"value": 1}
    assert disk_cached("test", ("a", 1), build, sources=[source]) == {"value": 1}, "second call must hit"
    assert len(calls) == 1
    assert disk_cached("test", ("a", 2), build, sources=[source]) == {"value": 2}, "other key, new entry"
    source.write_text("v2")
    assert disk_cached("test", ("a", 1), build, sources=[source]) == {"value": 3}, "changed code must rebuild"
    assert cache_directory("test") == tmp_path / "test"


def test_corrupt_entries_are_rebuilt_and_switch_off_builds_every_time(tmp_path, monkeypatch):
    monkeypatch.setenv("SWIM_CACHE_DIR", str(tmp_path))
    monkeypatch.delenv("SWIM_JAX_CACHE", raising=False)
    disk_cached("test", "k", lambda: 1)
    (entry,) = (tmp_path / "test").glob("*.pkl")
    entry.write_bytes(b"not a pickle")
    assert disk_cached("test", "k", lambda: 2) == 2
    assert pickle.loads(entry.read_bytes()) == 2
    monkeypatch.setenv("SWIM_JAX_CACHE", "0")
    assert disk_cached("test", "k", lambda: 3) == 3


def test_keys_with_object_addresses_are_not_cached(tmp_path, monkeypatch):
    monkeypatch.setenv("SWIM_CACHE_DIR", str(tmp_path))
    key = object()
    assert disk_cached("test", key, lambda: 1) == 1
    assert not (tmp_path / "test").exists()
