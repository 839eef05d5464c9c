"""Pieces of the CPU kernel's step (swim.rt.march_cpu) held to closed forms, and its cache hint.

The whole kernel is held to the float64 reference and to the JAX kernel in test_rt_march.py; these check the
shortcuts of section 29 of docs/performance.md on their own, where a slip would be small enough to hide there.
"""

import math
import platform

import numba
import numpy as np
import pytest

from swim.rt import march_cpu


@pytest.mark.parametrize("x", [0.0, 1e-9, 1e-4, 2e-3, 0.05, 0.0999999, 0.1, 0.3, 2.0, 40.0])
def test_step_accumulates_the_exact_mean_transmittance(x):
    """A step of optical depth x adds source * ds * (1 - e^-x) / x times the transmittance before it (Eq. 3 over a
    step), multiplies the transmittance by e^-x, and adds Eq. 12's integrals with the clear sky's e^-tau_clear: on
    both sides of the polynomial's limit (x = 0.1), to 1e-11 relative (the polynomial's first dropped term, x^7 / 8!,
    is 2.5e-12 there)."""
    beta_clear, beta_h, ds = 0.25 * x, 0.75 * x, 1.0
    tau_clear, t0 = 0.4, 0.3
    t_obs = math.exp(-(tau_clear + t0))
    source, irradiance, weight = 2.0, 3.0, 0.125
    accumulate = march_cpu.callable_from_python(march_cpu._accumulate)
    out = accumulate(tau_clear, t_obs, 0.0, 0.0, 0.0, beta_clear, source, irradiance, beta_h, ds, weight, math.exp(t0))
    mean = -math.expm1(-x) / x if x > 0 else 1.0
    assert out[0] == pytest.approx(tau_clear + beta_clear * ds, rel=1e-15)
    assert out[1] == pytest.approx(t_obs * math.exp(-x), rel=1e-12)
    assert out[2] == pytest.approx(t_obs * source * ds * mean, rel=1e-11)
    assert out[3] == pytest.approx(irradiance * weight, rel=1e-15)
    assert out[4] == pytest.approx(irradiance * math.exp(-tau_clear) * weight, rel=1e-12)


def test_corner_prefetch_reads_nothing_and_compiles_to_cache_hints():
    """Prefetching a block's corners, edges and outside of the grid included, changes nothing and leaves no
    out-of-range address; on x86-64 the hint is a prefetch instruction (else the saving of section 29 is gone)."""
    volume = np.arange(3 * 4 * 5 * 7, dtype=np.float32).reshape(3, 4, 5, 7)
    step_at = np.zeros((6, march_cpu.PROBE_BLOCK))
    step_at[2:5, :6] = np.array([[0.0, 2.0, 1.5, -0.5, 2.0, np.nan],
                                 [0.0, 3.0, 2.2, 1.0, 4.5, 1.0],
                                 [0.0, 4.0, 0.7, 1.0, 1.0, 1.0]])
    before = volume.copy()
    march_cpu.callable_from_python(march_cpu._prefetch_corners)(volume, 6, step_at)
    assert np.array_equal(volume, before)
    if platform.machine().lower() in ("x86_64", "amd64"):
        # compiled here (a function loaded from numba's disk cache keeps no assembly to inspect)
        fresh = numba.njit(cache=False)(march_cpu._prefetch_corners.py_func)
        fresh(volume, 6, step_at)
        assert "prefetcht0" in fresh.inspect_asm(fresh.signatures[0])


def test_only_the_kernels_that_python_calls_have_python_wrappers():
    """Every compiled function of the CPU kernels' modules that Python does not call is compiled without numba's
    CPython and C wrappers (an empty cache compiles the march ~17 % faster, docs/performance.md section 40), and
    the kernels that the render calls keep theirs; a helper stays callable through ``callable_from_python``."""
    from swim.rt import compose_cpu, ground_cpu, solar_cpu

    kernels = {"march_rays", "prepare_rays", "compose_clouds", "ground_radiance", "_direct_rows", "_add_above"}
    seen = set()
    for module in (march_cpu, compose_cpu, ground_cpu, solar_cpu):
        for name, value in vars(module).items():
            if not isinstance(value, numba.core.registry.CPUDispatcher) or value.py_func.__module__ != module.__name__:
                continue
            seen.add(name)
            wrapped = not value.targetoptions.get("no_cpython_wrapper", False)
            assert wrapped == (name in kernels), (module.__name__, name)
    assert kernels <= seen
    assert len(seen) > 40
    assert march_cpu.callable_from_python(march_cpu._clip)(3.0, 0.0, 1.0) == 1.0
    with pytest.raises(TypeError, match="callable_from_python"):  # not a crash of the interpreter
        march_cpu._clip(3.0, 0.0, 1.0)
