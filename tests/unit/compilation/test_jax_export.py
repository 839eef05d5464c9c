"""The traced programs kept on disk (swim.compilation.jax_export): a later process reads them instead of tracing, and gets the
same bits as jax.jit."""

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from swim.compilation import cache_budget
from swim.compilation.jax_export import KIND, SUFFIX, ExportedJit, exported_jit

pytest.importorskip("flatbuffers")  # jax.export's serialization needs it (a dependency of swim)


@dataclass(frozen=True)
class _Options:
    power: int = 2
    scale: float = 1.5


_TRACES = []  # one entry per trace of _kernel's Python body


def _kernel(x, table, options: _Options, offset=None):
    _TRACES.append(options)
    y = jnp.sin(x) ** options.power * options.scale + jnp.take(table["values"], jnp.arange(x.shape[0]) % 3)
    return {"y": y if offset is None else y + offset, "total": jnp.sum(x)}


@pytest.fixture
def cache_dir(tmp_path, monkeypatch):
    monkeypatch.setenv("SWIM_CACHE_DIR", str(tmp_path))
    monkeypatch.delenv("SWIM_JAX_CACHE", raising=False)
    monkeypatch.delenv("SWIM_JAX_EXPORT", raising=False)
    return tmp_path / KIND


def _inputs(n=7):
    x = np.linspace(-2.0, 3.0, n, dtype=np.float32)
    return x, {"values": np.array([0.5, -1.0, 2.0], np.float32)}


def _new_process():
    """What a new process holds: an ExportedJit of the same function, with no programs yet."""
    return exported_jit(_kernel, static_argnames=("options",))


def test_a_new_process_reads_the_program_instead_of_tracing_it_and_gets_the_same_bits(cache_dir):
    x, table = _inputs()
    expected = jax.jit(_kernel, static_argnames=("options",))(x, table, _Options())
    first = _new_process()
    _TRACES.clear()
    out = first(x, table, _Options())
    assert first.exported == 1 and first.loaded == 0
    assert len(list(cache_dir.glob(f"*{SUFFIX}"))) == 1
    traced = len(_TRACES)
    assert traced >= 1
    again = first(x, table, options=_Options())  # the same program in this process: neither read nor traced again
    assert first.exported == 1 and len(_TRACES) == traced

    later = _new_process()
    out_later = later(x, table, _Options())
    assert later.loaded == 1 and later.exported == 0
    assert len(_TRACES) == traced  # the function's Python body did not run: read, not traced
    for result in (out, again, out_later):
        assert set(result) == {"y", "total"}
        np.testing.assert_array_equal(np.asarray(result["y"]), np.asarray(expected["y"]))
        np.testing.assert_array_equal(np.asarray(result["total"]), np.asarray(expected["total"]))


def test_new_static_arguments_shapes_and_input_trees_are_new_programs(cache_dir):
    x, table = _inputs()
    kernel = _new_process()
    kernel(x, table, _Options())
    kernel(x, table, _Options(power=3))  # static argument
    kernel(_inputs(9)[0], table, _Options())  # shape
    kernel(x, table, _Options(), np.float32(0.25))  # the optional input given: another tree
    assert kernel.exported == 4
    assert len(list(cache_dir.glob(f"*{SUFFIX}"))) == 4
    out = _new_process()(x, table, _Options(power=3))
    np.testing.assert_array_equal(np.asarray(out["y"]), np.asarray(jax.jit(
        _kernel, static_argnames=("options",))(x, table, _Options(power=3))["y"]))
    with_offset = _new_process()(x, table, _Options(), np.float32(0.25))
    np.testing.assert_array_equal(np.asarray(with_offset["y"]), np.asarray(jax.jit(
        _kernel, static_argnames=("options",))(x, table, _Options(), np.float32(0.25))["y"]))


def test_gradients_and_batches_through_a_cached_program_are_jax_jits(cache_dir):
    """An exported program has no derivative or batching rule: inside a transformation the function is traced."""
    x, table = _inputs()
    _new_process()(x, table, _Options())  # the program on disk
    kernel = _new_process()
    plain = jax.jit(_kernel, static_argnames=("options",))

    def loss(fun):
        return lambda v: jnp.sum(fun(v, table, _Options())["y"])

    np.testing.assert_array_equal(np.asarray(jax.grad(loss(kernel))(x)), np.asarray(jax.grad(loss(plain))(x)))
    rows = np.stack([x, x[::-1]])
    np.testing.assert_array_equal(np.asarray(jax.vmap(lambda v: kernel(v, table, _Options())["y"])(rows)),
                                  np.asarray(jax.vmap(lambda v: plain(v, table, _Options())["y"])(rows)))
    assert kernel.loaded == 0 and kernel.exported == 0  # never read inside the transformations
    kernel(x, table, _Options())
    assert kernel.loaded == 1  # outside them, it is


def test_a_damaged_entry_is_exported_again(cache_dir):
    x, table = _inputs()
    _new_process()(x, table, _Options())
    (entry,) = cache_dir.glob(f"*{SUFFIX}")
    entry.write_bytes(b"not a program")
    kernel = _new_process()
    out = kernel(x, table, _Options())
    assert kernel.loaded == 0 and kernel.exported == 1
    assert entry.read_bytes() != b"not a program"
    np.testing.assert_array_equal(np.asarray(out["y"]), np.asarray(jax.jit(
        _kernel, static_argnames=("options",))(x, table, _Options())["y"]))


@pytest.mark.parametrize("switch", ["SWIM_JAX_EXPORT", "SWIM_JAX_CACHE"])
def test_switched_off_it_writes_nothing_and_traces_as_jit_does(cache_dir, monkeypatch, switch):
    monkeypatch.setenv(switch, "0")
    x, table = _inputs()
    kernel = _new_process()
    out = kernel(x, table, _Options())
    assert kernel.exported == 0 and kernel.loaded == 0
    assert not cache_dir.exists()
    assert np.isfinite(np.asarray(out["y"])).all()


class _Opaque:  # hashable, but its repr holds an address that another process would not share
    power, scale = 2, 1.0


@dataclass(frozen=True, eq=False)
class _LongTable:  # hashable (by identity); its repr shortens the array with "...", so it does not name the values
    values: np.ndarray
    power: int = 2
    scale: float = 1.0


@pytest.mark.parametrize("options", [_Opaque(), _LongTable(np.arange(5000.0))], ids=["address", "shortened array"])
def test_a_static_argument_whose_repr_does_not_name_it_is_not_cached(cache_dir, options):
    kernel = ExportedJit(_kernel, static_argnames=("options",))
    x, table = _inputs()
    out = kernel(x, table, options)
    assert kernel.exported == 0 and not cache_dir.exists()
    np.testing.assert_array_equal(np.asarray(out["y"]), np.asarray(jax.jit(
        _kernel, static_argnames=("options",))(x, table, options)["y"]))


def test_the_cache_is_listed_bounded_and_cleared(cache_dir, monkeypatch):
    x, table = _inputs()
    _new_process()(x, table, _Options())
    (usage,) = cache_budget.cache_usage([KIND])
    assert usage.files == 1 and usage.size_bytes > 0 and usage.path == cache_dir
    # a budget smaller than two entries: writing the second removes the least recently used first one
    monkeypatch.setenv("SWIM_CACHE_MAX_MB", str(1.5 * usage.size_bytes / 2**20))
    first = next(cache_dir.glob(f"*{SUFFIX}"))
    _new_process()(_inputs(11)[0], table, _Options())
    assert not first.exists() and len(list(cache_dir.glob(f"*{SUFFIX}"))) == 1
    assert cache_budget.clear_caches([KIND]) > 0
    assert not list(cache_dir.glob(f"*{SUFFIX}"))


@pytest.mark.full  # the JAX kernel's programs compile for tens of seconds on an empty cache: the full tier
def test_the_jax_march_and_step_1a_are_read_by_a_new_process_with_the_same_image(cache_dir, monkeypatch):
    """The real kernels export (an operation that JAX cannot export would fall back to plain jit silently), and a
    render whose programs are read from the cache gives the bits of one traced by jax.jit."""
    from swim.io.default_scene import default_scene
    from swim.pipeline import STATE, render
    from swim.rt import march_jax, solar_device
    from swim.rt.march_settings import ExecutionSettings, MarchSettings

    scene = default_scene()
    kernels = (march_jax._trace_chunk, march_jax._probe_counts_chunk, solar_device._sweep)

    def image():
        STATE.stages.clear()  # Step 1a runs again
        out = render(scene, sun_zenith=35.0, sun_azimuth=120.0, camera_options={"size": 24},
                     settings=MarchSettings(execution=ExecutionSettings(backend="jax", chunk=256)))
        return out["radiance"].values

    monkeypatch.setenv("SWIM_JAX_EXPORT", "0")
    plain = image()
    monkeypatch.setenv("SWIM_JAX_EXPORT", "1")
    for kernel in kernels:
        kernel.forget_programs()
    exported = image()
    assert [k.exported > 0 for k in kernels] == [True] * 3, "the march, its probe counts and Step 1a export"
    for kernel in kernels:
        kernel.forget_programs()
    read = image()
    assert [k.loaded > 0 and k.exported == 0 for k in kernels] == [True] * 3
    assert np.isfinite(plain).mean() > 0.7 and np.nanmax(plain) > 0.05  # NaN outside the fisheye circle
    np.testing.assert_array_equal(exported, plain)
    np.testing.assert_array_equal(read, plain)
