"""The march kernel compiled in a helper process on a cold numba cache (swim.rt.precompile): the types it compiles
for are those a render calls with, the helper's result lands in the cache, and a failing helper only costs time."""

import logging
import os
import subprocess
import sys

import numpy as np
import pytest

import swim
from swim.rt import precompile
from swim.rt.march_settings import ExecutionSettings, MarchSettings


@pytest.fixture(autouse=True)
def _no_helper_left():
    """A real helper that an earlier render in this process started (a cold cache) is waited for first, so that
    the tests below start their own."""
    precompile.wait()
    yield
    precompile.wait()


@pytest.mark.parametrize("name", sorted(precompile.KERNELS))
def test_the_argument_types_name_every_parameter_of_the_kernel(name):
    signature = precompile.kernel_signature(name)  # raises where a parameter was added, removed or renamed
    assert len(signature) == len(precompile._argument_types()[name])


def test_the_signatures_are_those_a_render_calls_the_kernels_with(monkeypatch):
    """Renders whose rays end on the ground call all five kernels (with either cloud scattering), each with exactly
    the types the helper and wait() compile for, or their work would be wasted (the argument types recorded at the
    calls, no helper)."""
    monkeypatch.setenv("SWIM_PRECOMPILE", "0")
    expected = {name: {precompile.kernel_signature(name)} for name in precompile.KERNELS}
    called = {}
    for name, module in precompile.KERNELS.items():
        kernel = precompile._dispatcher(name)

        def recording(*args, _kernel=kernel, _name=name):
            called.setdefault(_name, set()).add(tuple(_kernel.typeof_pyval(a) for a in args))
            return _kernel(*args)

        monkeypatch.setattr(sys.modules[module], name, recording)
    # the 3-D cloud scattering (the default) integrates the clouds along the ray; the paper's method composes them
    # after the march (compose_clouds)
    for method in ("discrete_ordinates", "albers2020"):
        image = swim.render(swim.default_scene(), camera="panorama", camera_options={"width": 32, "height": 16},
                            time="2024-06-21T18:00:00Z",
                            settings=MarchSettings(cloud_scattering=method,
                                                   execution=ExecutionSettings(backend="numba")))
        assert np.isfinite(image["radiance"].values).all()
        assert float(image["radiance_surface"].max()) > 0, "the view must include the ground (ground_radiance)"
        if method == "discrete_ordinates":
            assert "compose_clouds" not in called and len(called) == len(precompile.KERNELS) - 1
    assert sorted(called) == sorted(precompile.KERNELS)
    assert called == expected


def _in_fresh_cache(code, cache, timeout=300):
    env = {**os.environ, "SWIM_CACHE_DIR": str(cache), "SWIM_PRECOMPILE": "1"}
    env.pop("SWIM_JAX_CACHE", None)
    env.pop("NUMBA_CACHE_DIR", None)
    return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=timeout)


@pytest.mark.full  # a cold compile of the whole march in a helper process: the full tier
@pytest.mark.slow
def test_the_helper_compiles_the_march_into_the_disk_cache(tmp_path):
    check = "from swim.rt import precompile; print(precompile.is_cached('_march_ray_range'))"
    before = _in_fresh_cache(check, tmp_path)
    assert before.returncode == 0, before.stderr
    assert before.stdout.strip() == "False", "an empty cache folder must lack the kernel"
    helper = _in_fresh_cache("from swim.rt.precompile import main; main(['_march_ray_range'])", tmp_path)
    assert helper.returncode == 0, helper.stderr
    after = _in_fresh_cache(check, tmp_path)
    assert after.stdout.strip() == "True", after.stderr
    assert list(tmp_path.glob("numba/*/precompile.lock")), "the helpers' lock lives in the cache folder"


def test_no_helper_for_other_kernels_or_when_switched_off(monkeypatch):
    monkeypatch.setattr(precompile, "_helper_needed", lambda: True)
    started = []
    monkeypatch.setattr(precompile, "_helper_command", lambda names: started.append(names) or [sys.executable, "-c", ""])
    assert not precompile.start("jax") and not precompile.start("cuda")
    monkeypatch.setenv("SWIM_PRECOMPILE", "0")
    assert not precompile.start("numba")
    assert started == []


@pytest.mark.parametrize("backend, platforms, plugin, expected", [
    ("numba", "", False, ["numba"]), ("auto", "cpu", False, ["numba"]), ("auto", "", False, ["numba"]),
    ("auto", "cuda", False, []), ("auto", "", True, []), ("jax", "cpu", False, []), ("cuda", "", False, [])])
def test_the_command_starts_the_helper_early_only_for_the_numba_kernel(monkeypatch, backend, platforms, plugin,
                                                                       expected):
    """``swim render`` starts the helper before it imports JAX: "auto" only where JAX can see no GPU (no GPU
    platform named, no JAX plugin installed); otherwise swim.pipeline.render decides once JAX is loaded."""
    from importlib import metadata

    started = []
    monkeypatch.setattr(precompile, "start", lambda kind: started.append(kind) or True)
    monkeypatch.setenv("JAX_PLATFORMS", platforms)
    if plugin:
        monkeypatch.setattr(metadata, "entry_points", lambda group: ["jax_cuda12_plugin"])
    precompile._jax_plugin_installed.cache_clear()  # looked up once per process: here per case
    try:
        precompile.start_early(backend)
    finally:
        precompile._jax_plugin_installed.cache_clear()
    assert started == expected


def test_the_helper_process_does_not_import_jax(tmp_path):
    """It compiles numba kernels only: importing swim.rt and the numba kernel must not load JAX (~0.4 s of its
    start, docs/decisions/0011-jax-only-where-it-runs.md)."""
    probe = "import sys, swim.rt.march_cpu, swim.rt.precompile, swim.rt.march; print('jax' in sys.modules)"
    env = {**os.environ, "SWIM_CACHE_DIR": str(tmp_path)}
    helper = subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True, text=True, check=True)
    assert helper.stdout.strip() == "False"


def test_a_failing_helper_is_logged_and_leaves_the_march_to_the_render(monkeypatch, caplog):
    monkeypatch.delenv("SWIM_PRECOMPILE", raising=False)
    monkeypatch.setattr(precompile, "WAITING_KERNELS", ())
    monkeypatch.setattr(precompile, "_helper_needed", lambda: True)
    monkeypatch.setattr(precompile, "_helper_command",
                        lambda names: [sys.executable, "-c", "import sys; sys.stderr.write('no luck'); sys.exit(3)"])
    with caplog.at_level(logging.INFO, logger="swim.rt.precompile"):
        assert precompile.start("numba")
        assert precompile.start("numba"), "a second render while the helper runs starts no other"
        precompile.wait()
    assert precompile._helper is None
    assert "exit code 3" in caplog.text and "compiling it here" in caplog.text and "no luck" in caplog.text
    precompile.wait()  # nothing left to wait for: returns at once


def test_the_wait_does_the_renders_other_work_meanwhile_only_while_a_helper_runs(monkeypatch, caplog):
    """wait(meanwhile=...) calls its functions while the helper compiles (a failing one is logged, not raised), and
    calls nothing where no helper runs (a warm cache)."""
    monkeypatch.delenv("SWIM_PRECOMPILE", raising=False)
    monkeypatch.setattr(precompile, "WAITING_KERNELS", ())
    monkeypatch.setattr(precompile, "_helper_needed", lambda: True)
    monkeypatch.setattr(precompile, "_helper_command", lambda names: [sys.executable, "-c", "pass"])
    called = []

    def failing():
        raise ValueError("no table")

    with caplog.at_level(logging.INFO, logger="swim.rt.precompile"):
        assert precompile.start("numba")
        precompile.wait(meanwhile=(lambda: called.append("table"), failing))
    assert called == ["table"]
    assert "failing ahead of its first use failed: no table" in caplog.text
    precompile.wait(meanwhile=(lambda: called.append("again"),))
    assert called == ["table"], "no helper: nothing to do meanwhile"


def test_a_helper_that_outlives_the_wait_is_stopped(monkeypatch, caplog):
    monkeypatch.delenv("SWIM_PRECOMPILE", raising=False)
    monkeypatch.setattr(precompile, "WAITING_KERNELS", ())
    monkeypatch.setattr(precompile, "_helper_needed", lambda: True)
    monkeypatch.setattr(precompile, "WAIT_S", 1.0)
    monkeypatch.setattr(precompile, "_helper_command", lambda names: [sys.executable, "-c", "import time; time.sleep(60)"])
    with caplog.at_level(logging.INFO, logger="swim.rt.precompile"):
        assert precompile.start("numba")
        process = precompile._helper[0]
        precompile.wait()
    assert process.poll() is not None, "the helper must be stopped"
    assert "took more than" in caplog.text


def test_numba_cache_saves_wait_for_another_process_lock(tmp_path):
    """Two processes saving entries of one function at once could number both data files alike; the saves are
    serialised by a lock in the cache folder (swim.compilation.disk_cache.serialise_numba_cache_writes)."""
    fcntl = pytest.importorskip("fcntl")
    import threading

    from numba.core import caching

    import swim.rt.march_cpu  # noqa: F401  (installs the lock where numba's cache is on)
    from swim.compilation.disk_cache import serialise_numba_cache_writes

    serialise_numba_cache_writes()
    assert getattr(caching.IndexDataCacheFile.save, "_swim_locked", False)
    index = caching.IndexDataCacheFile(str(tmp_path), "f-1.py311", source_stamp=(1.0, 1))
    other = open(tmp_path / "swim-index.lock", "a")  # another process's lock: a separate open file
    fcntl.flock(other, fcntl.LOCK_EX)
    saver = threading.Thread(target=index.save, args=(("sig", "target"), b"code"))
    saver.start()
    saver.join(0.5)
    assert saver.is_alive(), "the save must wait for the lock"
    assert index.load(("sig", "target")) is None
    other.close()
    saver.join(10)
    assert not saver.is_alive()
    assert index.load(("sig", "target")) == b"code"
