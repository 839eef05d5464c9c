"""The disk caches stay within their budgets: least recently used entries go first, old numba code versions go, JAX's
own eviction works on entries written before it was on, and ``swim cache`` lists and clears them."""

import os
import subprocess
import sys
import time

import pytest
from typer.testing import CliRunner

from swim.cli.main import app
from swim.errors import SwimInputError
from swim.compilation.cache_budget import (KINDS, STALE_TMP_S, cache_usage, clear_caches, max_bytes, prune_code_versions,
                                  prune_least_recently_used)
from swim.compilation.disk_cache import disk_cached


def _file(path, size, age_s):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"x" * size)
    stamp = time.time() - age_s
    os.utime(path, (stamp, stamp))
    return path


def test_least_recently_used_entries_go_first_but_never_the_one_kept(tmp_path):
    entries = [_file(tmp_path / f"{n}.pkl", 1000, age_s=100 * (5 - n)) for n in range(5)]  # 0 oldest ... 4 newest
    removed = prune_least_recently_used(tmp_path, 2500, keep=entries[0])
    assert removed == 3000
    assert sorted(p.name for p in tmp_path.iterdir()) == ["0.pkl", "4.pkl"]
    assert prune_least_recently_used(tmp_path, 3000) == 0, "within the budget nothing goes"


def test_unfinished_writes_go_only_when_stale(tmp_path):
    old = _file(tmp_path / "a.tmp", 10, age_s=STALE_TMP_S + 60)
    fresh = _file(tmp_path / "b.tmp", 10, age_s=1)
    prune_least_recently_used(tmp_path, 10**9)
    assert not old.exists() and fresh.exists()
    assert prune_least_recently_used(tmp_path / "missing", 0) == 0


def test_a_read_keeps_an_entry_and_the_budget_applies_on_writes(tmp_path, monkeypatch):
    monkeypatch.setenv("SWIM_CACHE_DIR", str(tmp_path))
    monkeypatch.delenv("SWIM_JAX_CACHE", raising=False)
    monkeypatch.setenv("SWIM_CACHE_MAX_MB", str(1500 / 2**20))  # two of the ~640-byte entries below, not three
    disk_cached("test", "a", lambda: b"a" * 600)
    disk_cached("test", "b", lambda: b"b" * 600)
    for entry in (tmp_path / "test").glob("*.pkl"):
        os.utime(entry, (time.time() - 600, time.time() - 600))
    assert disk_cached("test", "a", lambda: pytest.fail("a must be a hit")) == b"a" * 600  # now the most recent
    disk_cached("test", "c", lambda: b"c" * 600)
    built = []
    assert disk_cached("test", "a", lambda: built.append(1)) == b"a" * 600 and not built, "a was read: kept"
    assert disk_cached("test", "c", lambda: built.append(1)) == b"c" * 600 and not built, "c was just written: kept"
    assert disk_cached("test", "b", lambda: b"B") == b"B", "b, least recently used, was removed"
    assert sum(entry.stat().st_size for entry in (tmp_path / "test").glob("*.pkl")) <= 1500


@pytest.mark.parametrize("text", ["0", "-5", "lots", "inf", "nan"])
def test_a_bad_budget_names_the_variable_before_any_build(tmp_path, monkeypatch, text):
    monkeypatch.setenv("SWIM_CACHE_DIR", str(tmp_path))
    monkeypatch.delenv("SWIM_JAX_CACHE", raising=False)
    monkeypatch.setenv("SWIM_CACHE_MAX_MB", text)
    with pytest.raises(SwimInputError, match="SWIM_CACHE_MAX_MB must be a number of megabytes > 0"):
        disk_cached("test", "k", lambda: pytest.fail("no build with a bad budget"))


def test_the_budget_defaults_to_a_gigabyte_and_reads_megabytes(monkeypatch):
    monkeypatch.delenv("SWIM_CACHE_MAX_MB", raising=False)
    assert max_bytes() == 1024 * 2**20
    monkeypatch.setenv("SWIM_CACHE_MAX_MB", " 2.5 ")
    assert max_bytes() == int(2.5 * 2**20)


def _version(n):
    """A code version's folder name (16 hex digits, as swim.compilation.numba_jit.numba_sources_digest gives)."""
    return f"{n:016x}"


def _versions(root, count, age_step_s=100):
    for n in range(count):  # version 0 oldest ... count - 1 newest
        _file(root / _version(n) / "index.nbi", 10, age_s=0)
        stamp = time.time() - age_step_s * (count - n)
        os.utime(root / _version(n), (stamp, stamp))


def test_numba_keeps_the_current_code_version_and_the_two_used_last(tmp_path):
    _versions(tmp_path, 5)
    _file(tmp_path / "notes" / "mine.txt", 10, age_s=10**6)  # not a code version: never touched
    removed = prune_code_versions(tmp_path, _version(0))
    assert sorted(removed) == [_version(1), _version(2)]
    assert sorted(p.name for p in tmp_path.iterdir()) == [_version(0), _version(3), _version(4), "notes"]
    assert prune_code_versions(tmp_path, _version(99)) == [_version(3)], "a new version's folder need not exist yet"


def test_a_code_version_that_a_live_process_holds_is_neither_pruned_nor_cleared(tmp_path, monkeypatch):
    """A long-running process (a dask worker, a notebook) keeps its machine code while newer versions come and go."""
    _versions(tmp_path / "numba", 5)
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys; from pathlib import Path; from swim.compilation.cache_budget import "
         f"hold_code_version as h; print(h(Path(sys.argv[1]), '{_version(0)}'), flush=True); sys.stdin.read()",
         str(tmp_path / "numba")], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "True"
        old = time.time() - 10**4  # held, yet the least recently marked: only its lock keeps it
        os.utime(tmp_path / "numba" / _version(0), (old, old))
        removed = prune_code_versions(tmp_path / "numba", _version(9))
        assert sorted(removed) == [_version(1), _version(2)], "the oldest, version 0, is held"
        monkeypatch.setenv("SWIM_CACHE_DIR", str(tmp_path))
        clear_caches(["numba"])
        assert sorted(p.name for p in (tmp_path / "numba").iterdir()) == [_version(0)]
    finally:
        holder.communicate("")
    clear_caches(["numba"])
    assert not list((tmp_path / "numba").iterdir()), "released: cleared"


def test_importing_the_numba_kernels_holds_its_version_and_prunes_old_ones(tmp_path):
    """In a fresh interpreter, as a new installation's first render would."""
    from swim.compilation.numba_jit import numba_sources_digest

    _versions(tmp_path / "numba", 4)
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "SWIM_JAX_CACHE")}
    subprocess.run([sys.executable, "-c", "import swim.rt.march_cpu"], env={**env, "SWIM_CACHE_DIR": str(tmp_path)},
                   check=True, capture_output=True)
    left = sorted(p.name for p in (tmp_path / "numba").iterdir())
    assert left == sorted([_version(2), _version(3), numba_sources_digest()])
    assert (tmp_path / "numba" / numba_sources_digest() / ".in-use").exists()


def test_jax_evicts_entries_written_without_access_times(tmp_path):
    """An entry without JAX's access-time file (written while eviction was off, e.g. by an older swim beside this
    one) made JAX's eviction raise FileNotFoundError at every new compilation; swim's eviction gives it one first."""
    legacy = _file(tmp_path / "jax" / "jit_old-0123-cache", 4000, age_s=3600)
    code = ("import jax, swim.compilation.jax_export; from jax._src.lru_cache import LRUCache\n"
            "print(jax.config.jax_compilation_cache_max_size)\n"
            "cache = LRUCache(jax.config.jax_compilation_cache_dir, max_size=5000)\n"
            "cache.put('jit_new-4567', b'y' * 1000)\n"
            "open(jax.config.jax_compilation_cache_dir + '/jit_later-89-cache', 'wb').write(b'z' * 500)\n"
            "cache.put('jit_last-1011', b'w' * 3000)\n")
    env = {k: v for k, v in os.environ.items() if k not in ("SWIM_JAX_CACHE", "JAX_COMPILATION_CACHE_DIR",
                                                            "JAX_COMPILATION_CACHE_MAX_SIZE")}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env={**env, "SWIM_CACHE_DIR": str(tmp_path), "SWIM_CACHE_MAX_MB": "3"})
    assert out.returncode == 0, out.stderr
    assert int(out.stdout.split()[0]) == 3 * 2**20
    assert not legacy.exists(), "the oldest entry is evicted for the new ones"
    assert sorted(p.name for p in (tmp_path / "jax").glob("*-cache")) == [
        "jit_last-1011-cache", "jit_later-89-cache", "jit_new-4567-cache"]
    assert (tmp_path / "jax" / "jit_later-89-atime").exists(), "an entry that came later got its access time too"


def test_cache_command_lists_and_clears(tmp_path, monkeypatch):
    monkeypatch.setenv("SWIM_CACHE_DIR", str(tmp_path))
    _file(tmp_path / "gas" / "a.pkl", 3 * 2**20, age_s=0)
    _file(tmp_path / "gas" / "notes.txt", 2**20, age_s=0)  # not the cache's: neither counted nor removed
    _file(tmp_path / "numba" / _version(1) / "f.nbc", 2**20, age_s=0)
    usage = {u.kind: u for u in cache_usage()}
    assert list(usage) == list(KINDS)
    assert (usage["gas"].files, usage["gas"].size_bytes) == (1, 3 * 2**20)
    assert (usage["numba"].files, usage["numba"].max_bytes) == (1, None)
    assert usage["jax"].files == 0
    runner = CliRunner()
    listing = runner.invoke(app, ["cache"], env={"COLUMNS": "200"})
    assert listing.exit_code == 0
    assert "gas" in listing.output and "3.0" in listing.output
    cleared = runner.invoke(app, ["cache", "--clear", "--kind", "gas"])
    assert cleared.exit_code == 0 and "removed 3.0 MB" in cleared.output
    assert sorted(p.name for p in (tmp_path / "gas").iterdir()) == ["notes.txt"]
    assert (tmp_path / "numba" / _version(1) / "f.nbc").exists()
    bad = runner.invoke(app, ["cache", "--kind", "gass"])
    assert bad.exit_code == 2 and "unknown cache kind" in bad.output
    with pytest.raises(SwimInputError, match="unknown cache kind"):
        clear_caches(["tables"])
