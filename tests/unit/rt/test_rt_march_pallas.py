"""The fused grid march (swim.rt.march_pallas) against the lockstep XLA loop it replaces on GPUs.

No GPU is needed: on a CPU the Pallas kernel runs in Pallas's interpreter, the same program that Triton compiles
on a GPU (its lowering is checked on the H100/H200 machines, docs/decisions/0006-gpu-kernels.md).
"""


import jax
import numpy as np
import pytest

from swim.errors import SwimInputError
from swim.frames import enu_from_azimuth_zenith
from swim.rt import march_pallas
from swim.rt.gas import AerosolBackground
from swim.rt.march_settings import ExecutionSettings, MarchSettings as _MarchSettings

from test_rt_march import _random_rays, _tiny_scene, _trace


def MarchSettings(**kw):  # noqa: N802 - a stand-in for the class in this module's tests
    """The render's settings with the paper's cloud scattering: the JAX kernel's fast paths tested here (the fused grid
    kernel, the ray table, Step 1a and the sampler on the device) serve ``cloud_scattering="albers2020"``; the 3-D
    method marches in lockstep on the host's rays (tests/system/test_clouds_3d.py)."""
    return _MarchSettings(**{"cloud_scattering": "albers2020", **kw})


@pytest.mark.slow
@pytest.mark.parametrize("case", ["plume, multiple scattering, 5 aerosol classes",
                                  "no plume, single scattering, at most 4 empty steps",
                                  "plume, deep refinement (tau_refine 0.02)"])
@pytest.mark.full
def test_fused_kernels_give_the_lockstep_march_s_pixels(case):
    """Rays from the ground, inside the grid and from 20 km (looking down) through cloud, the smoke plume (aerosol
    classes, the 3-D aerosol channels), terrain and the grid's edges: every output of the render's kernel within
    float32 rounding of the lockstep loops', with refinement, opaque stops and (second case) each ray's own step count;
    the grid segment alone in the Pallas kernel ("fused") and the clear air before and after it too ("fused-march",
    whose rays from 20 km take the steps before the grid and whose rays from the ground the steps after it; the second
    case checks "fused-march" alone, whose grid segment is "fused"'s kernel code; the third refines far more often,
    so that the kernel's stack of pending intervals, kept compactly, fills deeper). The tables are read both ways:
    their channels up to four a load (``MarchSettings.fused_vector_loads``, the default) and one scalar gather each
    ("scalar"), in the first case both with the volume's five species, the 3-D aerosol, the aerosol classes' diffuse
    tables and the multiple-scattering profiles (the switch is a setting, so each way is traced: a module constant
    read at tracing would let the first program serve both, as a review found)."""
    plume = case.startswith("plume")
    kernels = ("fused", "fused-march", "fused scalar", "fused-march scalar") if plume else ("fused-march",)
    extra = {} if plume else {"multiple_scattering": False, "empty_steps": 4, "n_probe": 16}
    # many splits and roll-backs: the pending intervals' compact stack (docs/decisions/0006-gpu-kernels.md) filled deep
    if "deep" in case:
        kernels, extra = ("fused",), {"tau_refine": 0.02}
    scene = _tiny_scene(plume)
    origins, dirs = _random_rays(256, seed=1)
    sun = enu_from_azimuth_zenith(135.0, 40.0)
    aerosol = AerosolBackground(stratospheric_aod_550=0.2)
    out = {}
    for kernel in ("lockstep",) + kernels:
        out[kernel] = _trace(scene, origins, dirs, sun, aerosol=aerosol,
                             settings=MarchSettings(**extra,
                                                    execution=ExecutionSettings(backend="jax",
                                                                                grid_kernel=kernel.split()[0], chunk=256, fused_vector_loads=not kernel.endswith("scalar"))))[0]
    lockstep = out["lockstep"]
    assert lockstep["surface"].sum() > 40 and (lockstep["tau_hydrometeor"] > 1.0).sum() > 10, \
        "rays must hit ground and cloud"
    for kernel in kernels:
        fused = out[kernel]
        np.testing.assert_array_equal(fused["surface"], lockstep["surface"], err_msg=kernel)
        for key in ("radiance", "radiance_clear", "radiance_cloud", "radiance_surface", "tau_clear", "tau_hydrometeor"):
            np.testing.assert_allclose(fused[key], lockstep[key], rtol=1e-5, atol=1e-7, err_msg=f"{kernel}: {key}")
        # NaN where no ground
        np.testing.assert_allclose(fused["distance"], lockstep["distance"], rtol=1e-6, atol=1e-3, err_msg=kernel)


def captured_kernel_call(kernel="fused", values=False, plume=False, **settings):
    """The fused kernel's arguments (``march_grid_fused``'s, or ``march_segments_fused``'s for "fused-march") in a JAX
    march of 128 rays through the tests' tiny scene (on the CPU; ``plume``: with the smoke plume and terrain), with
    these MarchSettings, as (args, kwargs): traced values, or with ``values`` the arrays themselves (the chunk then
    runs without jit up to the kernel's call)."""
    from swim.rt import march_jax

    got = {}

    class Captured(Exception):
        pass

    def grab(*args, **kwargs):
        got.update(args=args, kwargs=kwargs)
        raise Captured

    def eager_chunk(*args, **kwargs):
        with jax.disable_jit():
            return chunk.function(*args, **kwargs)

    name = "march_grid_fused" if kernel == "fused" else "march_segments_fused"
    real, chunk = getattr(march_pallas, name), march_jax._trace_chunk
    setattr(march_pallas, name, grab)
    if values:
        march_jax._trace_chunk = eager_chunk
    try:
        origins, dirs = _random_rays(128, seed=1)
        _trace(_tiny_scene(plume), origins, dirs, enu_from_azimuth_zenith(135.0, 40.0),
               settings=MarchSettings(**settings,
                                      execution=ExecutionSettings(backend="jax", grid_kernel=kernel, chunk=128)))
    except Captured:
        pass
    finally:
        setattr(march_pallas, name, real)
        march_jax._trace_chunk = chunk
    assert got, "the march did not call the fused grid kernel"
    return got["args"], got["kwargs"]


@pytest.mark.full
def test_a_block_whose_rays_have_stopped_takes_no_steps():
    """"fused-march": a block of rays that have all stopped (or are padding: not valid) leaves every loop of the
    kernel at once, its state as it came (``gap`` and ``s_last`` are not moved by samples that add nothing), while the
    other block of the batch is marched as when alone (the same bits); with its rays alive the first block's loops
    do run (docs/decisions/0006-gpu-kernels.md)."""
    args, kwargs = captured_kernel_call("fused-march", values=True, plume=True)
    state, *rest = args
    kwargs = {**kwargs, "interpret": True, "block_rays": 64, "num_warps": 2}  # two blocks of 64 rays
    marched = march_pallas.march_segments_fused(state, *rest, **kwargs)
    stopped = dict(state, alive=state["alive"].at[:64].set(False))
    idle = march_pallas.march_segments_fused(stopped, *rest, **kwargs)
    assert bool(np.asarray(state["alive"])[:64].all())
    for key in ("gap", "s_last", "tau_h", "tau_clear", "l_clear", "i_nogas", "tau_species", "hit"):
        np.testing.assert_array_equal(np.asarray(idle[key])[:64], np.asarray(stopped[key])[:64], err_msg=key)
        np.testing.assert_array_equal(np.asarray(idle[key])[64:], np.asarray(marched[key])[64:], err_msg=key)
    assert not np.array_equal(np.asarray(marched["s_last"])[:64], np.asarray(state["s_last"])[:64])


def test_grid_kernel_setting_is_checked_and_resolved(monkeypatch):
    with pytest.raises(SwimInputError, match="grid_kernel must be one of"):
        MarchSettings(execution=ExecutionSettings(grid_kernel="triton"))
    assert MarchSettings(execution=ExecutionSettings(grid_kernel="fused")).resolved_grid_kernel() == "fused"
    assert MarchSettings(execution=ExecutionSettings(grid_kernel="lockstep")).resolved_grid_kernel() == "lockstep"
    assert MarchSettings(execution=ExecutionSettings(grid_kernel="fused-march")).resolved_grid_kernel() == "fused-march"
    march_pallas.pallas_triton_available.cache_clear()
    try:
        assert MarchSettings().resolved_grid_kernel() == "lockstep"  # this CPU: the XLA loop
        monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
        march_pallas.pallas_triton_available.cache_clear()
        assert MarchSettings().resolved_grid_kernel() == "fused"  # Pallas's Triton backend imports without a GPU
    finally:
        monkeypatch.undo()
        march_pallas.pallas_triton_available.cache_clear()


def test_rays_that_fill_no_whole_block_are_refused():
    """The kernel refuses them; the JAX march then takes the lockstep loop (a chunk set by hand to such a size)."""
    from swim.rt.march import padded_batch_size
    from swim.rt.march_jax import fused_fits

    assert not fused_fits(100) and fused_fits(256)
    assert all(fused_fits(padded_batch_size(n, 262144)) for n in (1, 200, 5000, 262144, 10**6))
    with pytest.raises(ValueError, match="not a multiple of block_rays=128"):
        march_pallas.march_grid_fused({}, np.zeros((100, 3), np.float32), np.zeros((100, 3), np.float32), None, 8,
                                      {}, {}, None, None, 0.25)


def test_cli_refuses_an_unknown_grid_kernel_before_any_work(tmp_path):
    from typer.testing import CliRunner

    from swim.cli.main import app

    out = tmp_path / "sky.png"
    result = CliRunner().invoke(app, ["render", "--grid-kernel", "triton", "--size", "9", "--out", str(out)])
    assert result.exit_code == 2 and "grid_kernel must be one of" in result.output
    assert not out.exists()


def test_fused_kernel_settings_are_checked_and_keep_programs_apart(tmp_path):
    """MarchSettings.fused_max_registers (None or 16-255), fused_vector_loads and fused_fma (bools) are named when
    wrong, also from the CLI before any work; all are kernel settings, the compiled programs' keys."""
    from typer.testing import CliRunner

    from swim.cli.main import app

    for bad in (8, 256, 12.5, True, "128"):
        with pytest.raises(SwimInputError, match=r"fused_max_registers must be None or an integer in \[16, 255\]"):
            MarchSettings(execution=ExecutionSettings(fused_max_registers=bad))
    with pytest.raises(SwimInputError, match="fused_vector_loads must be True or False"):
        MarchSettings(execution=ExecutionSettings(fused_vector_loads=None))
    for bad in (None, 1, "yes"):
        with pytest.raises(SwimInputError, match="fused_fma must be True or False"):
            MarchSettings(execution=ExecutionSettings(fused_fma=bad))
    base = MarchSettings().kernel_settings()
    assert MarchSettings(execution=ExecutionSettings(fused_max_registers=128)).kernel_settings() != base
    assert MarchSettings(execution=ExecutionSettings(fused_vector_loads=False)).kernel_settings() != base
    assert MarchSettings(execution=ExecutionSettings(fused_fma=True)).kernel_settings() != base
    out = tmp_path / "sky.png"
    result = CliRunner().invoke(app, ["render", "--fused-max-registers", "300", "--size", "9", "--out", str(out)])
    assert result.exit_code == 2 and "fused_max_registers must be None or an integer" in result.output
    assert not out.exists()


@pytest.mark.parametrize("n_c", range(1, 13))
def test_vector_loads_cover_each_channel_once_and_stay_aligned(n_c):
    """The loads of a point's channels (march_pallas._load_groups): every channel in exactly one load, widths 4, 2
    and 1, each load's first channel a multiple of its width (so that a 16- or 8-byte load is aligned where rows are
    padded to 4 channels), and no wider load left unused where it would fit."""
    groups = march_pallas._load_groups(n_c)
    covered = [c for first, width in groups for c in range(first, first + width)]
    assert covered == list(range(n_c))
    assert all(width in (1, 2, 4) and first % width == 0 for first, width in groups)
    assert sum(width == 4 for _, width in groups) == n_c // 4
    assert sum(width < 4 for _, width in groups) == bin(n_c % 4).count("1")
    _, n_cp = march_pallas._channels_padded(np.zeros((2, 3, n_c), np.float32))
    assert n_cp % 4 == 0 and n_c <= n_cp < n_c + 4


def test_the_padded_volume_is_made_once_per_device_volume_and_dropped_with_it():
    """with_vector_volume: for the fused kernel's vector loads the packed volume's channels padded to 4 (zeros) once
    per device volume, the same copy for every chunk; a new volume (a new sun's Step 1a on the device) replaces it,
    and it goes with its volume; nothing is added for other kernels, scalar gathers or 4k channels."""
    import gc

    import jax.numpy as jnp

    fused = MarchSettings(execution=ExecutionSettings(backend="jax", grid_kernel="fused"))
    volume = jnp.asarray(np.arange(2 * 3 * 4 * 7, dtype=np.float32).reshape(2, 3, 4, 7))
    first = march_pallas.with_vector_volume({"volume": volume}, fused)
    padded = np.asarray(first["volume_vector"]).reshape(2, 3, 4, 8)
    np.testing.assert_array_equal(padded[..., :7], np.asarray(volume))
    assert not padded[..., 7].any()
    again = march_pallas.with_vector_volume({"volume": volume}, fused.with_execution(grid_kernel="fused-march"))
    assert again["volume_vector"] is first["volume_vector"]
    for settings in (fused.with_execution(grid_kernel="lockstep"), fused.with_execution(fused_vector_loads=False)):
        assert "volume_vector" not in march_pallas.with_vector_volume({"volume": volume}, settings)
    four = jnp.zeros((2, 3, 4, 8), jnp.float32)
    assert "volume_vector" not in march_pallas.with_vector_volume({"volume": four}, fused)
    new = volume + 1.0
    second = march_pallas.with_vector_volume({"volume": new}, fused)["volume_vector"]
    assert second is not first["volume_vector"] and float(second[0]) == 1.0
    del first, again, second, new
    gc.collect()
    assert march_pallas._VECTOR_VOLUME == {}


def test_the_padded_volume_s_weak_reference_cannot_deadlock_and_can_be_dropped():
    """The padded copy's callback runs in whichever thread frees its volume, also one that holds the cache's lock
    (a review found a thread that freed the last volume inside with_vector_volume blocked on its own lock);
    forget_vector_volume drops the copy (before a new sun's Step 1a refills the volume on the device)."""
    import gc
    import threading

    import jax.numpy as jnp

    fused = MarchSettings(execution=ExecutionSettings(backend="jax", grid_kernel="fused"))
    held = [jnp.ones((2, 3, 4, 5), jnp.float32)]
    march_pallas.with_vector_volume({"volume": held[0]}, fused)
    assert march_pallas._VECTOR_VOLUME
    done = threading.Event()

    def free_under_the_lock():
        with march_pallas._VECTOR_VOLUME_LOCK:
            held.clear()
            gc.collect()
        done.set()

    worker = threading.Thread(target=free_under_the_lock, daemon=True)
    worker.start()
    worker.join(10)
    assert done.is_set() and march_pallas._VECTOR_VOLUME == {}
    volume = jnp.ones((2, 3, 4, 5), jnp.float32)
    march_pallas.with_vector_volume({"volume": volume}, fused)
    march_pallas.forget_vector_volume()
    assert march_pallas._VECTOR_VOLUME == {}
