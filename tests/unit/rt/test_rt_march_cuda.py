"""The CUDA march (swim.rt.march_cuda): the CPU kernel's code compiled for a GPU, held to the CPU kernel.

A GPU is never needed: numba's CUDA simulator (NUMBA_ENABLE_CUDASIM=1, set before numba loads, hence a
subprocess) runs the kernel's Python code thread by thread, and libNVVM, where the machine has it, compiles
the kernel to PTX for a Hopper GPU without one.
"""

import inspect
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from swim.errors import SwimInputError
from swim.rt import march_cpu, march_cuda
from swim.rt.march import MarchSettings

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[2]


def _run(code, tmp_path, env=None, timeout=600):
    """Run ``code`` in a fresh interpreter (``tests/unit/rt`` importable) and return its completed process."""
    script = tmp_path / "job.py"
    script.write_text(textwrap.dedent(code))
    environ = {**os.environ, "PYTHONPATH": os.pathsep.join([str(HERE), str(ROOT / "src"),
                                                             os.environ.get("PYTHONPATH", "")]), **(env or {})}
    return subprocess.run([sys.executable, str(script)], capture_output=True, text=True, env=environ, timeout=timeout,
                          cwd=tmp_path)


def test_kernel_takes_the_cpu_kernels_arguments():
    """One argument list: the CUDA kernel's is read off march_rays, and the loop over the rays takes it between the
    range of rays and the work arrays that each caller allocates (a change to one must reach the others)."""
    cpu = tuple(inspect.signature(march_cpu.march_rays).parameters)
    body = tuple(inspect.signature(march_cpu._march_ray_range.py_func).parameters)
    assert march_cuda.kernel_arguments() == cpu
    assert body[:3] == ("first", "stop", "stride") and body[3:3 + len(cpu)] == cpu
    work = body[3 + len(cpu):]
    assert work == ("edges", "cdf", "stack_lo", "stack_hi", "stack_depth", "saved", "tsp", "ms_lanes", "vol", "vol32",
                    "probe_at")
    # every function the kernel reaches is compiled for the device (none is left to call a CPU dispatcher); the
    # per-ray set-up stays on the host (the CUDA path's is the JAX one, swim.rt.march._prepare_chunk)
    names = {name for name, value in vars(march_cpu).items() if hasattr(value, "py_func")} - {"prepare_rays"}
    assert names == set(march_cuda.DEVICE_FUNCTIONS)


def test_work_sizes_are_the_cpu_kernels():
    sizes = march_cuda.work_sizes(12, 128, 24, 64, 256, 16, 32, 5, 9, 41)
    assert sizes == (129, 257, 32, 27, 5, 9, 41)
    assert march_cuda.work_sizes(300, 128, 24, 8, 8, 16, 4, 3, 7, 2)[:2] == (301, 17)
    # a cloudless scene packs no species: the species work array keeps one element (CUDA has no empty local arrays)
    assert march_cuda.work_sizes(12, 128, 24, 64, 256, 16, 32, 0, 2, 2)[3:] == (22, 1, 2, 2)


def test_numba_cuda_that_cannot_compile_with_this_numpy_says_so(monkeypatch):
    """numba-cuda 0.30.4 with NumPy 2.5 fails at its first compilation (numpy.row_stack is gone, seen on an H100
    machine): the cuda backend says so before any work, naming both packages, instead of a traceback from numba."""
    def lowering_fails():
        raise AttributeError("module 'numpy' has no attribute 'row_stack'")

    monkeypatch.setattr(march_cuda, "cuda_available", lambda: True)
    monkeypatch.setattr(march_cuda, "_load_cuda_lowering", lowering_fails)
    with pytest.raises(SwimInputError, match=r"numba-cuda cannot compile with NumPy .*row_stack.*NumPy < 2\.5"):
        march_cuda.require_cuda()
    monkeypatch.setattr(march_cuda, "_load_cuda_lowering", lambda: None)
    march_cuda.require_cuda()  # a working pair: no error


@pytest.mark.skipif(march_cuda.cuda_available(), reason="this machine has a GPU: the error is for those without one")
def test_cuda_backend_without_a_gpu_says_so(tmp_path):
    """Before any work: the settings, a render, and the CLI (exit code 2, no image written)."""
    import swim
    from typer.testing import CliRunner

    from swim.cli.main import app

    with pytest.raises(SwimInputError, match="needs an NVIDIA GPU"):
        MarchSettings(backend="cuda").resolved_backend()
    with pytest.raises(SwimInputError, match="needs an NVIDIA GPU"):
        swim.render(swim.default_scene(), camera_options={"size": 9}, settings=MarchSettings(backend="cuda"))
    out = tmp_path / "cuda.png"
    result = CliRunner().invoke(app, ["render", "--size", "9", "--backend", "cuda", "--out", str(out)])
    assert result.exit_code == 2 and "needs an NVIDIA GPU" in result.output and not out.exists()


_SIMULATED = """
    import json, sys
    import numpy as np
    import test_rt_march as t
    from numba import cuda
    from swim.frames import enu_from_azimuth_zenith
    from swim.rt.gas import AerosolBackground
    from swim.rt.march import MarchSettings

    assert cuda.is_available()  # the simulator
    origins, dirs = t._random_rays(96, seed=5)
    sun = enu_from_azimuth_zenith(135.0, 40.0)
    out = {}
    for backend in ("numba", "cuda"):
        # the paper's cloud scattering: the CUDA kernel has no other
        settings = MarchSettings(backend=backend, chunk=64, cloud_scattering="albers2020")  # two chunks, padding
        out[backend] = t._trace(t._tiny_scene(True), origins, dirs, sun, settings=settings,
                                aerosol=AerosolBackground(stratospheric_aod_550=0.2))[0]
    # and a whole render through the pipeline (the kernel's name in its attributes)
    import swim
    for backend in ("numba", "cuda"):
        image = swim.render(t._tiny_scene(), camera="allsky", camera_options={"size": 9}, sun_zenith=40.0,
                            sun_azimuth=135.0, settings=MarchSettings(backend=backend, cloud_scattering="albers2020"))
        out[backend]["render"] = image["radiance"].values
        out[backend]["render_backend"] = np.array(image.attrs["march_backend"])
    np.savez("out.npz", **{f"{b}_{k}": v for b, o in out.items() for k, v in o.items()})
"""


@pytest.mark.slow
@pytest.mark.full
def test_cuda_march_matches_the_cpu_march_in_the_simulator(tmp_path):
    """The same rays (ground, aircraft and 20 km views through cloud, a smoke plume, terrain and a stratospheric
    layer) marched by the CPU kernel and, in numba's CUDA simulator, by the CUDA kernel built from the same code
    through trace_rays: the same pixels, to float32 round-off of the composition."""
    run = _run(_SIMULATED, tmp_path, env={"NUMBA_ENABLE_CUDASIM": "1", "JAX_PLATFORMS": "cpu"})
    assert run.returncode == 0, run.stderr[-3000:]
    data = np.load(tmp_path / "out.npz")
    cpu = {k[6:]: data[k] for k in data.files if k.startswith("numba_")}
    gpu = {k[5:]: data[k] for k in data.files if k.startswith("cuda_")}
    assert cpu["surface"].sum() > 20 and (cpu["tau_hydrometeor"] > 1.0).sum() >= 3, "rays must hit ground and cloud"
    np.testing.assert_array_equal(gpu["surface"], cpu["surface"])
    for key in ("radiance", "radiance_clear", "radiance_cloud", "radiance_surface", "tau_clear", "tau_hydrometeor"):
        np.testing.assert_allclose(gpu[key], cpu[key], rtol=1e-5, atol=1e-7, err_msg=key)
    np.testing.assert_allclose(gpu["distance"], cpu["distance"], rtol=1e-6)  # NaN where no ground, in both
    np.testing.assert_array_equal(gpu["steps"], cpu["steps"])  # each ray's samples, counted by the same code
    assert str(gpu["render_backend"]) == "cuda" and str(cpu["render_backend"]) == "numba"
    assert np.isfinite(cpu["render"]).sum() > 100  # the all-sky circle of a 9 x 9 image, 3 wavelengths
    np.testing.assert_allclose(gpu["render"], cpu["render"], rtol=1e-5, atol=1e-7)


_TABLES = """
    import numpy as np
    from swim.rt import march_cuda

    volume = np.arange(24, dtype=np.float32).reshape(2, 3, 4)
    occupancy = np.ones((2, 3, 4), np.uint8)
    sky_lanes = np.arange(40, dtype=np.float64).reshape(1, 5, 8)
    def tables(v):
        views = {"volume": v.view(), "occupancy": occupancy.view(), "sky_lanes": sky_lanes.view()}
        for view in views.values():
            view.flags.writeable = False  # as swim.rt.march._numba_tables makes them, anew for every render
        return {**views, "n_class": 3}
    first, again = march_cuda.device_tables(tables(volume)), march_cuda.device_tables(tables(volume))
    assert again["volume"] is first["volume"] and again["n_class"] == 3  # one transfer per host buffer
    np.testing.assert_array_equal(again["volume"].copy_to_host(), volume)
    other = volume + 1  # a new volume (a new sun or scene): copied, and the old copy dropped
    new = march_cuda.device_tables(tables(other))
    assert new["volume"] is not first["volume"]
    np.testing.assert_array_equal(new["volume"].copy_to_host(), other)
    # the sky table's lanes: copied once too, and not again for a new volume
    assert again["sky_lanes"] is first["sky_lanes"] and new["sky_lanes"] is first["sky_lanes"]
    np.testing.assert_array_equal(new["sky_lanes"].copy_to_host(), sky_lanes)
    print("ok")
"""


@pytest.mark.slow
def test_tables_go_to_the_device_once_per_host_buffer(tmp_path):
    run = _run(_TABLES, tmp_path, env={"NUMBA_ENABLE_CUDASIM": "1", "JAX_PLATFORMS": "cpu"})
    assert run.returncode == 0 and run.stdout.strip() == "ok", run.stderr[-3000:]


_PTX = """
    import re, types
    import numba
    import numba.cuda.dispatcher as dispatcher
    from numba import cuda
    import test_rt_march as t
    from swim.frames import enu_from_azimuth_zenith
    from swim.rt import march_cpu, march_cuda
    from swim.rt.march import MarchSettings

    # the argument types of a real call: those trace_rays gives the CPU kernel, which the CUDA kernel takes too
    captured, names = [], march_cuda.kernel_arguments()
    cpu_march = march_cpu.march_rays
    def capture(*args):
        captured.append(args)
        return cpu_march(*args)
    march_cpu.march_rays = capture
    origins, dirs = t._random_rays(6)
    t._trace(t._tiny_scene(True), origins, dirs, enu_from_azimuth_zenith(135.0, 40.0), settings=MarchSettings(backend="numba"))
    march_cpu.march_rays = cpu_march
    args = dict(zip(names, captured[0]))
    signature = tuple(numba.typeof(v) for v in captured[0])
    sizes = march_cuda.kernel_work_sizes(args)
    # device functions ask the current GPU for its compute capability when they compile; there is none here
    dispatcher.get_current_device = lambda: types.SimpleNamespace(compute_capability=(9, 0))
    kernel = march_cuda.cuda_march_kernel(*sizes)
    ptx, _ = cuda.compile_ptx(kernel.py_func, signature, cc=(9, 0))
    open("kernel.ptx", "w").write(ptx)
"""


def _nvvm_available():
    try:
        from numba.cuda.cudadrv import nvvm

        nvvm.NVVM()
        return True
    except Exception:  # noqa: BLE001 - no CUDA toolkit (libNVVM) on this machine
        return False


@pytest.mark.slow
@pytest.mark.skipif(not _nvvm_available(), reason="needs libNVVM (the CUDA toolkit) to compile PTX")
@pytest.mark.full
def test_cuda_kernel_compiles_for_hopper_in_one_function(tmp_path):
    """The kernel compiles for an H100/H200 (sm_90) with the argument types of a real render, every device
    function inlined into one entry (no calls in the step loop), and a thread's work arrays in local memory of
    ~10 KB (the probe densities of up to MAX_PROBES probes, 8 KB, take most; 2.6 GB for the 270 000 threads that
    an H100 holds at once)."""
    run = _run(_PTX, tmp_path, env={"JAX_PLATFORMS": "cpu"})
    assert run.returncode == 0, run.stderr[-3000:]
    ptx = (tmp_path / "kernel.ptx").read_text()
    assert ".target sm_90" in ptx
    assert len([line for line in ptx.splitlines() if line.startswith(".visible .entry")]) == 1
    import re

    calls = set(re.findall(r"call\.uni[^,]*,\s*\n?\s*(\w+)", ptx))
    assert calls <= {"__internal_accurate_pow"}, calls  # only libdevice's pow (the clear-air step density)
    depots = [int(n) for n in re.findall(r"__local_depot\d+\[(\d+)\]", ptx)]
    assert depots and max(depots) < 16384, depots
