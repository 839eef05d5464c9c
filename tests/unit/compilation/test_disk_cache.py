"""The persistent caches only ever save time: hits, invalidation by code, switches."""

import pickle
from pathlib import Path

import pytest

from swim.compilation.disk_cache import cache_directory, disk_cached


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


@pytest.mark.full  # compiles a kernel in a new process: the full tier
def test_numba_kernel_cache_follows_swim_cache_dir(tmp_path):
    """The numba kernel caches in $SWIM_CACHE_DIR/numba/<digest of the numba modules' code> (not beside the installed
    source), and not at all with SWIM_JAX_CACHE=0; a user's NUMBA_CACHE_DIR is kept. Fresh interpreters: the setting
    is read at import."""
    import os
    import subprocess
    import sys

    from swim.compilation.numba_jit import numba_sources_digest

    probe = ("import numba, swim.rt.march_cpu, swim.compilation.numba_jit as m; "
             "print(repr(numba.config.CACHE_DIR), m.CACHE_ON)")
    base = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "SWIM_JAX_CACHE", "SWIM_CACHE_DIR")}

    def run(**env):
        out = subprocess.run([sys.executable, "-c", probe], env={**base, **env}, capture_output=True, text=True, check=True)
        return out.stdout.strip()

    assert run(SWIM_CACHE_DIR=str(tmp_path)) == f"{str(tmp_path / 'numba' / numba_sources_digest())!r} True"
    assert run(SWIM_CACHE_DIR=str(tmp_path), SWIM_JAX_CACHE="0") == "'' False"
    assert run(SWIM_CACHE_DIR=str(tmp_path), NUMBA_CACHE_DIR=str(tmp_path / "mine")) == f"{str(tmp_path / 'mine')!r} True"


def test_the_numba_cache_folder_changes_with_the_code_of_any_numba_module(tmp_path, monkeypatch):
    """numba checks only a function's own file for staleness, but a ground term compiled from ground_cpu.py bakes in
    march_cpu.py's geometry, and numba freezes the constants that compiled code reads from other modules: the digest
    that names the cache folder must change when any *_cpu.py module or any of those modules changes."""
    import shutil

    import swim.compilation.numba_jit as m

    rt = Path(m.__file__).resolve().parents[1] / "rt"
    copy = tmp_path / "swim" / "rt"
    copy.mkdir(parents=True)
    for path in rt.glob("*_cpu.py"):
        shutil.copy(path, copy / path.name)
    for name in m.CONSTANTS_READ_FROM:  # the modules whose constants numba freezes into the machine code
        (copy / name).resolve().parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(rt / name, (copy / name).resolve())
    monkeypatch.setattr(m, "__file__", str(tmp_path / "swim" / "compilation" / "numba_jit.py"))
    before = m.numba_sources_digest()
    assert before == m.numba_sources_digest() and len(before) == 16
    for name in ("march_cpu.py", "compose_cpu.py", "ground_cpu.py", "solar_cpu.py", *m.CONSTANTS_READ_FROM):
        path = (copy / name).resolve()
        path.write_text(path.read_text() + "\n# changed\n")
        after = m.numba_sources_digest()
        assert after != before, name
        before = after
