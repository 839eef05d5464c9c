"""Pieces of the CPU kernel's step (swim.rt.march_cpu) held to closed forms, and its cache hint.

The whole kernel is held to the float64 reference and to the JAX kernel in test_rt_march.py; these check the
shortcuts of docs/decisions/0003-cpu-kernel-code.md on their own, where a slip would be small enough to hide there.
"""

import math
import platform

import numba
import numpy as np
import pytest

from swim.compilation import numba_jit
from swim.rt import march_cpu, precompile


@pytest.mark.parametrize("lanes", [(0.0, 1e-9, 1e-4, 2e-3), (0.05, 0.0999999, 1e-6, 0.02), (0.1, 0.3, 2.0, 40.0),
                                   (0.0999999, 0.1, 1e-4, 0.0), (-0.05, -0.2, 0.3, 1e-3)])
@pytest.mark.parametrize("weight", [0.125, -0.0625, 0.0])
def test_step_accumulates_the_exact_mean_transmittance(lanes, weight):
    """A step of optical depth x adds source * ds * (1 - e^-x) / x times the transmittance before it (Eq. 3 over a
    step), multiplies the transmittance by e^-x, and adds Eq. 12's integrals with the clear sky's e^-tau_clear (its
    weight > 0), or takes it back (< 0: the terminal step back, x < 0 too): in each of the four lanes, on both sides
    of the polynomial's limit (x = 0.1) and with lanes on either side of it in one step (then every lane takes the
    expm1), to 1e-11 relative (the polynomial's first dropped term, x^7 / 8!, is 2.5e-12 there)."""
    beta_h, ds = 0.75 * lanes[0], 1.0
    beta_clear = tuple(x - beta_h for x in lanes)  # each lane's whole optical depth is x
    tau_clear = (0.4, 0.1, 0.7, 0.2)
    t0 = 0.3
    t_obs = tuple(math.exp(-(tau + t0)) for tau in tau_clear)
    source, irradiance = (2.0, 1.0, 0.5, 3.0), (3.0, 2.0, 1.5, 0.5)
    zeros = (0.0, 0.0, 0.0, 0.0)
    accumulate = numba_jit.callable_from_python(march_cpu._accumulate_lanes)
    out = accumulate(tau_clear, t_obs, zeros, zeros, zeros, beta_clear, source, irradiance, beta_h, ds, weight,
                     math.exp(t0))
    for c, x in enumerate(lanes):
        mean = -math.expm1(-x) / x if x != 0 else 1.0
        assert out[0][c] == pytest.approx(tau_clear[c] + beta_clear[c] * ds, rel=1e-15, abs=1e-300)
        assert out[1][c] == pytest.approx(t_obs[c] * math.exp(-x), rel=1e-12)
        assert out[2][c] == pytest.approx(t_obs[c] * source[c] * ds * mean, rel=1e-11)
        assert out[3][c] == pytest.approx(irradiance[c] * weight, rel=1e-15)
        assert out[4][c] == pytest.approx(irradiance[c] * math.exp(-tau_clear[c]) * weight, rel=1e-12)


def test_sky_lanes_hold_the_sky_table_wavelengths_innermost():
    """The step loop's lane table (sky_lanes) is the sky table with the wavelengths innermost, the direct lanes
    0-2 and the diffuse 4-6, its padding 0; and a bilinear lookup of its lanes is the table's own per wavelength."""
    rng = np.random.default_rng(7)
    sky = rng.random((6, 5, 9)).astype(np.float32)
    lanes = march_cpu.sky_lanes(sky)
    assert lanes.shape == (5, 9, 8) and lanes.dtype == np.float64 and lanes.flags.c_contiguous
    for c in range(3):
        assert np.array_equal(lanes[..., c], sky[c]) and np.array_equal(lanes[..., 4 + c], sky[3 + c])
    assert not lanes[..., 3].any() and not lanes[..., 7].any()
    corner = numba_jit.callable_from_python(march_cpu._corner_lanes)
    at = numba_jit.callable_from_python(march_cpu._bilinear_at)
    u0, v0, a, b = 2, 6, 0.3, 0.8
    for o in (0, 4):
        got = corner(lanes, u0, v0, u0 + 1, v0 + 1, o, a, b)
        for c in range(3):
            assert got[c] == pytest.approx(at(sky, o // 4 * 3 + c, u0, v0, a, b), rel=1e-6)
        assert got[3] == 0.0
    with pytest.raises(ValueError, match="6, nu, nmu"):
        march_cpu.sky_lanes(sky[:3])


@pytest.mark.perf  # its assembly
def test_corner_prefetch_reads_nothing_and_compiles_to_cache_hints():
    """Prefetching a block's corners, edges and outside of the grid included, changes nothing and leaves no
    out-of-range address; on x86-64 the hint is a prefetch instruction (else the prefetch's saving,
    docs/decisions/0003-cpu-kernel-code.md, is gone)."""
    volume = np.arange(3 * 4 * 5 * 7, dtype=np.float32).reshape(3, 4, 5, 7)
    step_at = np.zeros((6, march_cpu.PROBE_BLOCK))
    step_at[2:5, :6] = np.array([[0.0, 2.0, 1.5, -0.5, 2.0, np.nan],
                                 [0.0, 3.0, 2.2, 1.0, 4.5, 1.0],
                                 [0.0, 4.0, 0.7, 1.0, 1.0, 1.0]])
    before = volume.copy()
    numba_jit.callable_from_python(march_cpu._prefetch_corners)(volume, 6, step_at)
    assert np.array_equal(volume, before)
    if platform.machine().lower() in ("x86_64", "amd64"):
        # compiled here (a function loaded from numba's disk cache keeps no assembly to inspect)
        fresh = numba.njit(cache=False)(march_cpu._prefetch_corners.py_func)
        fresh(volume, 6, step_at)
        assert "prefetcht0" in fresh.inspect_asm(fresh.signatures[0])


def test_only_the_kernels_that_python_calls_have_python_wrappers():
    """Every compiled function of the CPU kernels' modules that Python does not call is compiled without numba's
    CPython and C wrappers (an empty cache compiles the march ~17 % faster, docs/decisions/0008-cold-start.md), and
    the kernels that the render calls keep theirs; a helper stays callable through ``callable_from_python``."""
    from swim.optics import columns_cpu
    from swim.rt import compose_cpu, ground_cpu, occupancy_cpu, solar_cpu

    kernels = {"_march_ray_range", "prepare_rays", "compose_clouds", "ground_radiance", "_direct_rows", "_add_above",
               "_direct_columns", "_add_above_columns",
               "species_sums", "step1a_channels", "column_weights", "scan_content", "gather_cells", "resample_cells",
               "occupied_cells", "unlit_nodes", "classify_cells", "dilate_levels_across", "dilate_levels_along"}
    seen = set()
    for module in (march_cpu, compose_cpu, ground_cpu, solar_cpu, columns_cpu, occupancy_cpu):
        for name, value in vars(module).items():
            if not isinstance(value, numba.core.registry.CPUDispatcher) or value.py_func.__module__ != module.__name__:
                continue
            seen.add(name)
            wrapped = not value.targetoptions.get("no_cpython_wrapper", False)
            assert wrapped == (name in kernels), (module.__name__, name)
    assert kernels <= seen
    assert len(seen) > 40
    assert numba_jit.callable_from_python(march_cpu._clip)(3.0, 0.0, 1.0) == 1.0
    with pytest.raises(TypeError, match="callable_from_python"):  # not a crash of the interpreter
        march_cpu._clip(3.0, 0.0, 1.0)


def test_the_march_compiles_with_the_slp_vectoriser_and_leaves_numbas_setting_as_it_was():
    """The march (_march_ray_range) compiles with LLVM's SLP vectoriser on (docs/decisions/0003-cpu-kernel-code.md) and
    restores numba's global setting afterwards, also when the compilation fails."""
    assert isinstance(march_cpu._march_ray_range, numba_jit.VectorisingDispatcher)
    seen = []

    def probe(x):
        return x + 1.0

    dispatcher = numba_jit.vectorising(numba.njit(cache=False)(probe))
    original = numba.core.registry.CPUDispatcher.compile

    def spy(self, sig):
        seen.append(numba.config.SLP_VECTORIZE)
        return original(self, sig)

    before = numba.config.SLP_VECTORIZE
    numba.core.registry.CPUDispatcher.compile = spy
    try:
        assert dispatcher(1.0) == 2.0
        with pytest.raises(Exception):
            dispatcher("text")  # a typing error inside the compilation
    finally:
        numba.core.registry.CPUDispatcher.compile = original
    assert seen and all(flag == 1 for flag in seen)
    assert numba.config.SLP_VECTORIZE == before


@pytest.mark.parametrize("sizes", [(12, 128, 28, 64, 256, 16, 32, 5, 9, 41), (300, 128, 24, 8, 8, 16, 0, 0, 2, 2)])
def test_work_arrays_have_their_sizes_and_share_no_cache_line(sizes):
    """march_rays' work arrays: the sizes of work_sizes (which the CUDA kernel's local arrays take too), the types
    that _march_ray_range is compiled for, the multiple-scattering lanes zeroed, and each array on cache lines of its
    own (docs/decisions/0003-cpu-kernel-code.md)."""
    n_before, n_grid, n_after, n_probe, n_probe_max, n_clear, slots, n_species, n_channels, n_u = sizes
    work = march_cpu.work_arrays(*march_cpu.work_sizes(*sizes))
    names = list(precompile._argument_types()["_march_ray_range"])[-len(work):]
    assert names == ["edges", "cdf", "stack_lo", "stack_hi", "stack_depth", "saved", "tsp", "ms_lanes", "vol", "vol32",
                     "probe_at"]
    shapes = [(max(n_before, n_grid, n_after) + 1,), (max(n_probe, n_probe_max, n_clear) + 1,), (slots,), (slots,),
              (slots,), (22 + n_species,), (max(n_species, 1),), (n_u, 3 * march_cpu.LANES), (n_channels,),
              (n_channels,), (6, march_cpu.PROBE_BLOCK)]
    assert [a.shape for a in work] == shapes
    types = precompile._argument_types()["_march_ray_range"]
    assert [numba.typeof(a) for a in work] == [types[name] for name in names]
    assert not work[7].any()
    spans = []
    for a in work:
        if a.nbytes:
            assert a.ctypes.data % march_cpu.CACHE_LINE == 0
            first = a.ctypes.data // march_cpu.CACHE_LINE
            spans.append((first, (a.ctypes.data + a.nbytes - 1) // march_cpu.CACHE_LINE))
    spans.sort()
    assert all(hi < lo for (_, hi), (lo, _) in zip(spans, spans[1:])), "two arrays share a cache line"


def _blocks_in_loops(body):
    """The basic blocks of an LLVM IR function body that lie on a cycle of its control flow (inside a loop): name ->
    the block's text, for the blocks whose strongly connected component has more than one block or a self-edge."""
    import re

    blocks, name = {}, "entry"
    for line in body.splitlines():
        label = re.match(r"^([\w.]+):", line)
        if label:
            name = label.group(1)
        blocks.setdefault(name, []).append(line)
    edges = {b: set(re.findall(r"label %([\w.]+)", "\n".join(lines))) & blocks.keys() for b, lines in blocks.items()}
    # Tarjan's strongly connected components, iteratively (a kernel has thousands of blocks)
    index, low, on_stack, stack, looped, counter = {}, {}, set(), [], set(), [0]
    for root in blocks:
        if root in index:
            continue
        work = [(root, iter(sorted(edges[root])))]
        index[root] = low[root] = counter[0]
        counter[0] += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, successors = work[-1]
            for nxt in successors:
                if nxt not in index:
                    index[nxt] = low[nxt] = counter[0]
                    counter[0] += 1
                    stack.append(nxt)
                    on_stack.add(nxt)
                    work.append((nxt, iter(sorted(edges[nxt]))))
                    break
                if nxt in on_stack:
                    low[node] = min(low[node], index[nxt])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    component = []
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        component.append(member)
                        if member == node:
                            break
                    if len(component) > 1 or node in edges[node]:
                        looped.update(component)
    return {b: "\n".join(blocks[b]) for b in looped}


@pytest.mark.perf  # an inspection of the compiled code
@pytest.mark.slow
def test_the_kernel_changes_no_reference_count_inside_its_loops():
    """The march kernel's loops take no array views (``volume[k, j, i]``, a table's row): numba raises and lowers a
    view's reference count with atomic instructions on a count that every thread shares, which took ~1/4 of the
    march's cycles (docs/decisions/0003-cpu-kernel-code.md). In the compiled kernel (its helpers inlined) no reference
    count changes inside a loop: only its arguments' and a view made once per call, before the loop over rays."""
    import re

    # compiled here, the render's signature, with the kernel's options but the disk cache (which keeps no IR)
    fresh = numba.njit(**{**numba_jit.JIT_KERNEL, "cache": False}, nogil=True)(march_cpu._march_ray_range.py_func)
    signature = precompile.kernel_signature("_march_ray_range")
    fresh.compile(signature)
    ir = fresh.inspect_llvm(signature)
    body = re.search(r"^define [^\n]*@_ZN4swim2rt9march_cpu16_march_ray_range[^\n]*\n(.*?)^}", ir, re.S | re.M)
    assert body is not None
    counted = re.compile(r"call void @NRT_(?:incref|decref)\(")
    assert counted.search(body.group(1)), "no reference counts at all: the IR's form changed, so this test sees nothing"
    looped = _blocks_in_loops(body.group(1))
    assert len(looped) > 100  # the loops over rays, segments, steps and channels
    in_loops = sorted(name for name, text in looped.items() if counted.search(text))
    assert not in_loops, in_loops


def test_probes_round_to_the_nearest_cell_as_numpy_does_halves_to_even():
    """The probes' nearest cell (_round_half_even) is NumPy's (and jnp.round's) rounding: halves to the even
    integer, negative values, magnitudes at and beyond 2^51 and NaN included; compiled as the kernel compiles it
    (fast-math's reassociation must not fold its shift away)."""
    rounded = numba_jit.callable_from_python(march_cpu._round_half_even)
    rng = np.random.default_rng(3)
    halves = np.arange(-8.5, 8.6, 0.5)
    edges = [0.49999999999999994, -0.49999999999999994, 1e-300, -0.0]
    large = [2.0 ** 51 - 0.5, 2.0 ** 51 + 1, 2.0 ** 52 + 2, -2.0 ** 60, 1e300, np.inf, -np.inf]
    values = np.concatenate([halves, edges, rng.uniform(-500.0, 500.0, 200), large])
    for x in values:
        assert rounded(float(x)) == np.round(x), x
    assert np.isnan(rounded(float("nan")))


@pytest.mark.perf  # its assembly
@pytest.mark.skipif(platform.machine().lower() not in ("x86_64", "amd64"), reason="x86 instructions")
def test_the_probes_loop_converts_no_float_to_an_integer():
    """_probe_indices' loop rounds in floating point: x86 converts float64 to int64 in vectors only with AVX-512,
    which the kernels leave out on Intel CPUs (swim.compilation.numba_target), and scalar conversions there made the loop
    take 8.2 % of the march's time instead of 4.0 % (docs/decisions/0003-cpu-kernel-code.md)."""
    fresh = numba.njit(cache=False, fastmath=numba_jit.FASTMATH, error_model="numpy")(
        march_cpu._probe_indices.py_func)
    probe_at = np.zeros((6, march_cpu.PROBE_BLOCK))
    p = np.zeros(32)
    coef = np.zeros(20)
    fresh(0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 10.0, 8, 0, 8, p, coef, (3, 4, 5), probe_at)
    asm = fresh.inspect_asm(fresh.signatures[0])
    assert "cvttsd2si" not in asm and "cvttpd2qq" not in asm
