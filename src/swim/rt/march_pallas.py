"""The ray march's segments as one fused GPU kernel (Pallas on Triton): the grid's refined march, and the clear air.

The lockstep JAX march (:func:`swim.rt.march_jax._march_grid_refined`) runs one iteration of every ray's march as ~20
XLA kernels that pass the rays' state (~90 values a ray: the accumulators, their snapshot for roll-backs, the pending
intervals) through device memory; on an H100 that iteration's traffic, not its arithmetic, sets the time (~270 us
per 262 144 rays, 173 iterations a chunk: docs/decisions/0006-gpu-kernels.md). A per-ray GPU kernel (numba's CPU
code compiled with numba-cuda, measured and removed) keeps the state in registers but its threads diverge between the
march's phases (5.4 of a warp's 32 threads active, docs/decisions/0006-gpu-kernels.md).

This kernel keeps both virtues: the same lockstep iteration, written branch-free over a block of rays as
:func:`~swim.rt.march_jax._march_grid_refined` is, but inside one Triton program per block of :data:`BLOCK_RAYS` rays,
so that the state stays in registers for the whole segment and a warp's threads always run the same instructions.
The tables (packed volume, terrain, gas and sky tables, the rays' step edges and diffuse-source profiles) are read
by gathers from device memory (their caches); where a point has several channels, the kernel gets them with their
channels last and reads them up to four at a time (``vector_loads``, :func:`_load_groups`).

:func:`march_grid_fused` marches the grid segment with refinement (``ExecutionSettings.grid_kernel="fused"``, the
default on GPUs: 1.9-2.1x faster per chunk than the lockstep loop on an H200, docs/decisions/0006-gpu-kernels.md);
:func:`march_segments_fused` marches consecutive segments in one kernel, the clear air before and after the grid too
(``"fused-march"``: the ~10 ms per chunk of XLA loops and copies left around the grid kernel; 0.85x "fused"'s chunk
time on an H100, docs/decisions/0006-gpu-kernels.md).
Each computes what :func:`swim.rt.march_jax._march_segment` computes for its segments, the same equations in the same
order (Eqs. 3, 8 and 12 of Albers et al. 2020, doi:10.5194/amt-13-3235-2020; see that function), so its state agrees
with the XLA kernel's to float32 rounding; ``tests/unit/rt/test_rt_march_pallas.py`` holds it to that in Pallas's
interpreter on CPUs. Each 3-vector of the XLA kernel (a quantity at the three wavelengths, a point) is three (B,)
vectors here: Triton's blocks must be powers of two in every dimension.
"""

from __future__ import annotations

import functools
import logging
import threading
import weakref
from dataclasses import dataclass

import jax
import jax.numpy as jnp

from ..constants import GAS_COLUMN_ROW
from ..optics.volume import _cubic, _cubic_du, _cubic_dv

log = logging.getLogger(__name__)

#: Rays per Triton program (a block of the lockstep march) and the program's warps: one ray per thread. At 128 x 4
#: ptxas gives the kernel 255 registers (two programs per Hopper SM, 12.5 % occupancy); 512 x 16 caps it at 128 with
#: 88 bytes of spills (12 with scalar gathers; 25 %), to be timed on a GPU (``benchmarks/pallas_registers.py``,
#: docs/decisions/0006-gpu-kernels.md).
BLOCK_RAYS = 128
NUM_WARPS = 4

#: The state of :func:`swim.rt.march_jax._march_segment` that the kernel carries, one (n,) column each: the quantities at
#: the three wavelengths (three columns each), the per-ray numbers, then (:func:`_state_columns`) the packed species'
#: optical depths and the flags, which travel as int32.
_VECTORS = ("tau_clear", "l_clear", "i_nogas", "i_gas")
_SCALARS = ("tau_h", "i_cloud_t", "hit_s", "hit_lo", "hit_hi", "hit_from", "gap", "s_last")
_FLAGS = ("alive", "hit")


@functools.lru_cache(maxsize=1)
def pallas_triton_available() -> bool:
    """Whether JAX's default device is a GPU and Pallas can lower to Triton there (the CUDA plugin's Triton calls)."""
    if jax.default_backend() != "gpu":
        return False
    try:
        from jax.experimental import pallas  # noqa: F401
        from jax.experimental.pallas import triton
    except Exception as err:  # noqa: BLE001 - an old JAX, or one without Pallas: the lockstep kernel serves
        log.info("no Pallas Triton backend (%s): the grid is marched by the lockstep XLA kernel", err)
        return False
    if not hasattr(triton, "CompilerParams"):  # older releases named it otherwise (TritonCompilerParams)
        log.info("this JAX's Pallas has no triton.CompilerParams: the grid is marched by the lockstep XLA kernel")
        return False
    return True


#: Values per vector load: a thread reads 4 adjacent float32 (16 bytes, one ``LDG.E.128`` on NVIDIA GPUs) where a
#: table's channels are adjacent and padded to a multiple of 4 (:func:`_channels_padded`, :func:`_trilinear_vec4`).
VECTOR = 4


def _padded_channels(n_c):
    """``n_c`` channels rounded up to a multiple of :data:`VECTOR` (a padded row's length)."""
    return -(-n_c // VECTOR) * VECTOR


def _channels_padded(table):
    """A channel-last table flattened with its last axis padded with zeros to a multiple of :data:`VECTOR`, and that
    padded channel count."""
    n_c = table.shape[-1]
    n_cp = _padded_channels(n_c)
    if n_cp != n_c:
        table = jnp.pad(table, [(0, 0)] * (table.ndim - 1) + [(0, n_cp - n_c)])
    return table.reshape(-1), n_cp


#: The last padded volume (:func:`with_vector_volume`): {"source": weak reference to the device volume it was made
#: from, "padded": its flattened, padded copy}; dropped with that volume.
_VECTOR_VOLUME: dict = {}
# re-entrant: the weak reference's callback may run in a thread that holds the lock
_VECTOR_VOLUME_LOCK = threading.RLock()

#: Most values (cells x padded channels) that the fused kernel's int32 offsets address.
MAX_VOLUME_VALUES = 2**31 - 1


def with_vector_volume(consts, settings):
    """``consts`` (the JAX kernel's, on the device) with ``"volume_vector"``: the packed volume with its channels
    padded to a multiple of :data:`VECTOR`, flattened (:func:`_channels_padded`), where ``settings`` march the grid
    with the fused kernel's vector loads; ``consts`` itself otherwise (also for a volume beyond the kernel's int32
    offsets, which :func:`march_segments_fused` refuses).

    The copy is made once per device volume and kept while that volume lives (a new sun's Step 1a on the device makes
    a new volume, and so a new copy; :func:`forget_vector_volume` drops it before): without it each chunk's program
    padded the volume again (for the 400 x 400 x 60 scene's 160 x 400 x 400 x 7 packed volume, 0.82 GB written a
    chunk, ~0.3 ms on an H200; docs/decisions/0006-gpu-kernels.md). Only the last volume's copy is kept."""
    kernel = settings.resolved_grid_kernel()
    volume = consts.get("volume")
    if kernel not in ("fused", "fused-march") or not settings.execution.fused_vector_loads or volume is None \
            or not isinstance(volume, jax.Array) or volume.shape[-1] % VECTOR == 0 \
            or volume.size // volume.shape[-1] * _padded_channels(volume.shape[-1]) > MAX_VOLUME_VALUES:
        return consts
    last = None  # the last volume, held here until the lock is released: its end (and callback) comes after
    with _VECTOR_VOLUME_LOCK:
        source = _VECTOR_VOLUME.get("source")
        last = None if source is None else source()
        if last is not volume:
            _VECTOR_VOLUME.clear()  # the last volume's copy goes before the new one is made
            padded, _ = _channels_padded(volume)

            def forget(ref):
                with _VECTOR_VOLUME_LOCK:
                    if _VECTOR_VOLUME.get("source") is ref:
                        _VECTOR_VOLUME.clear()

            _VECTOR_VOLUME.update(source=weakref.ref(volume, forget), padded=padded)
        padded = _VECTOR_VOLUME["padded"]
    del last
    return {**consts, "volume_vector": padded}


def forget_vector_volume():
    """Drop the padded copy of :func:`with_vector_volume`: before a new sun's Step 1a on the device refills the
    volume it was made from (that volume lives on through the refill, and the old copy with it: 0.82 GB for the
    400 x 400 x 60 scene)."""
    with _VECTOR_VOLUME_LOCK:
        _VECTOR_VOLUME.clear()


def _load_groups(n_c):
    """(first channel, width) of the loads that read a point's ``n_c`` adjacent channels: widths 4, then 2 and 1 for
    the rest (16-, 8- and 4-byte loads, each aligned to its width where rows are padded to :data:`VECTOR`), so that no
    padding is loaded into registers."""
    groups, c = [], 0
    for width in (VECTOR, 2, 1):
        while n_c - c >= width:
            groups.append((c, width))
            c += width
    return groups


class _Gather:
    """Reads ``flat[at + c]`` for channels c of each point (``at``: (B,) int32 offsets of the points' channel 0) by
    :func:`_load_groups`'s loads: ``offsets(at, group)`` indexes a group's (B, width) block (width 1: (B,)),
    ``weight(w, group)`` shapes a (B,) weight for it, and ``split(values, group)`` takes the block's channels out as
    (B,) arrays (a select and a sum within each thread: the block's layout keeps a row in one thread, as its vector
    load put it, so no shuffles)."""

    def __init__(self, like, n_c):
        self.groups = _load_groups(n_c)
        self.lanes = {w: jax.lax.broadcasted_iota(jnp.int32, (like.shape[0], w), 1) for _, w in self.groups if w > 1}

    def offsets(self, at, group):
        c, width = group
        return at + c if width == 1 else at[:, None] + c + self.lanes[width]

    def weight(self, w, group):
        return w if group[1] == 1 else w[:, None]

    def split(self, values, group):
        if group[1] == 1:
            return [values]
        lane = self.lanes[group[1]]
        return [jnp.sum(jnp.where(lane == c, values, 0.0), axis=1) for c in range(group[1])]


def _trilinear_vec4(flat, shape, n_c, k, j, i, outside):
    """:func:`swim.rt.march_jax.trilinear_gathers` from a (nk, ny, nx, n_cp) volume whose channels are padded to a multiple
    of :data:`VECTOR` (:func:`_channels_padded`): each corner's channels read by :func:`_load_groups`'s loads (for 7
    channels three a corner instead of seven), the same products and sums per channel in the same order. Returns the
    ``n_c`` channels, each ``outside[c]`` beyond the volume."""
    from .march_jax import _cell_weights

    ny, nx, n_cp = shape[1:]
    inside, k0, j0, i0, fk, fj, fi = _cell_weights(shape, k, j, i)
    base = ((k0 * ny + j0) * nx + i0) * n_cp
    gather = _Gather(k, n_c)
    row_step, plane_step = nx * n_cp, ny * nx * n_cp
    channels = []
    for group in gather.groups:
        at = gather.offsets(base, group)
        wi, wj, wk = (gather.weight(w, group) for w in (fi, fj, fk))

        def row(b):
            return flat[b] * (1 - wi) + flat[b + n_cp] * wi

        def plane(b):
            return row(b) * (1 - wj) + row(b + row_step) * wj

        values = plane(at) * (1 - wk) + plane(at + plane_step) * wk
        channels += gather.split(values, group)
    return [jnp.where(inside, value, outside[c]) for c, value in enumerate(channels)]


def _bilinear_vec4(flat, nu, nv, n_cp, n_c, fu, fv):
    """:func:`swim.rt.march_jax.bilinear_gathers` from a (nu, nv, n_cp) table whose channels are padded to a multiple of
    :data:`VECTOR` (:func:`_channels_padded`), each corner's channels read by :func:`_load_groups`'s loads; the same
    products and sums per channel in the same order. Returns the ``n_c`` channels."""
    fu = jnp.clip(fu, 0.0, nu - 1.001)
    fv = jnp.clip(fv, 0.0, nv - 1.001)
    u0 = jnp.floor(fu).astype(jnp.int32)
    v0 = jnp.floor(fv).astype(jnp.int32)
    gather = _Gather(fu, n_c)
    r = (u0 * nv + v0) * n_cp
    row = nv * n_cp
    out = []
    for group in gather.groups:
        t = gather.offsets(r, group)
        a, b = gather.weight(fu - u0, group), gather.weight(fv - v0, group)
        values = ((flat[t] * (1 - b) + flat[t + n_cp] * b) * (1 - a)
                  + (flat[t + row] * (1 - b) + flat[t + row + n_cp] * b) * a)
        out += gather.split(values, group)
    return out


def _lerp_vec4(flat, n, n_cp, n_c, f, row=0):
    """:func:`swim.rt.march_jax.lerp_gathers` from a (rows, n, n_cp) table whose channels are padded to a multiple of
    :data:`VECTOR`: row ``row`` (may be per point) at fractional indices f, clamped, both ends' channels read by
    :func:`_load_groups`'s loads. Returns the ``n_c`` channels."""
    f = jnp.clip(f, 0.0, n - 1.001)
    i0 = jnp.floor(f).astype(jnp.int32)
    gather = _Gather(f, n_c)
    at = (row + i0) * n_cp
    out = []
    for group in gather.groups:
        t = gather.offsets(at, group)
        w = gather.weight(f - i0, group)
        out += gather.split(flat[t] * (1 - w) + flat[t + n_cp] * w, group)
    return out


def _state_columns(n_sp):
    """Names of the kernel's state columns, in order."""
    names = [f"{key}{c}" for key in _VECTORS for c in range(3)] + list(_SCALARS)
    names += [f"tau_species{c}" for c in range(n_sp)]
    return names + list(_FLAGS)


def _params(consts, has_bounds):
    """The kernel's scalar constants as one float32 vector, and each one's position in it (name -> index)."""
    index_map = consts["index_map"]
    parts = {
        "radius": consts["radius"], "sun": consts["sun"], "z_bottom": consts["z_bottom"], "dz": consts["dz"],
        "dh": consts["dh"], "top": consts["top"], "centre": index_map["index_map_centre"],
        "scale": index_map["index_map_scale"], "coef": index_map["index_map_coefficients"],
        "spectra": consts["beta_gas_spectra"], "angstrom": consts["angstrom"], "aerosol_ssa": consts["aerosol_ssa"],
        "stratospheric_ssa": consts["stratospheric_ssa"],
    }
    if has_bounds:
        parts["bounds"] = index_map["index_map_bounds"]
    position, values, at = {}, [], 0
    for name, value in parts.items():
        flat = jnp.ravel(jnp.asarray(value, jnp.float32))
        position[name] = (at, flat.shape[0])
        values.append(flat)
        at += flat.shape[0]
    return jnp.concatenate(values), position


def march_grid_fused(state, start, direction, edges, n_steps, rays, consts, ms_profile, aerosol_class, tau_refine,
                     steps=None, stop_tau=0.0, interpret=False, block_rays=None, num_warps=None,
                     max_registers=None, vector_loads=True, fma=False):
    """The grid segment of :func:`swim.rt.march_jax._march_segment` with refinement (``in_grid``, ``tau_refine`` > 0), as
    one Pallas kernel (:func:`march_segments_fused` with that one segment).

    Parameters
    ----------
    state : dict
        The march's state before the grid (:func:`swim.rt.march_jax._march_rays`): (n,) and (n, 3) float32 arrays,
        ``alive`` and ``hit`` (n,) bool, ``tau_species`` (n, n_species).
    start, direction : jax.Array
        Shape (n, 3): rebased ray origins [m] and unit directions.
    edges : jax.Array
        Shape (n_steps + 1, n): the grid steps' edges along each ray [m] (:func:`swim.rt.march_jax.grid_step_edges`).
    n_steps : int
        Grid steps per ray (static).
    rays : dict
        ``p_rayleigh`` (n,), ``p_aerosol`` and ``p_stratospheric`` (n, 3): phase functions [-].
    consts : dict
        The kernel constants (:func:`swim.rt.march_inputs.kernel_constants`, the volume on the device).
    ms_profile : jax.Array or None
        (9, n, n_u) diffuse-source profiles (:func:`swim.rt.march_jax.diffuse_source_profiles`), or None.
    aerosol_class : tuple
        (n,) int32 lower class and (n, 1) weight (:func:`swim.rt.march_jax.aerosol_class_weights`).
    tau_refine : float
        Refinement threshold [-] (> 0, static).
    steps : jax.Array, optional
        (n,) int32 steps of each ray (<= n_steps); None: n_steps each.
    stop_tau : float
        Hydrometeor optical depth [-] at which a ray that does not look down stops (0: never; static).
    interpret : bool
        Run in Pallas's interpreter (CPUs; the tests) instead of compiling for a GPU.
    block_rays, num_warps : int, optional
        Rays per Triton program (a power of two that divides n) and its warps (None: :data:`BLOCK_RAYS`,
        :data:`NUM_WARPS`).
    max_registers : int, optional
        Registers per thread that ptxas may give the kernel on NVIDIA GPUs, in [16, 255] (None: ptxas's choice;
        :attr:`swim.rt.march_settings.ExecutionSettings.fused_max_registers`, :mod:`swim.rt.ptx_edits`).
    vector_loads : bool
        Read the tables' channels up to four a load, the tables channels last (:func:`_load_groups`), or by a scalar
        gather each (:attr:`swim.rt.march_settings.ExecutionSettings.fused_vector_loads`).
    fma : bool
        Let ptxas contract the kernel's float32 multiplies and adds into fused multiply-adds on NVIDIA GPUs
        (:attr:`swim.rt.march_settings.ExecutionSettings.fused_fma`, :mod:`swim.rt.ptx_edits`; no effect in the
        interpreter).

    Returns
    -------
    dict
        The state after the grid segment, as :func:`swim.rt.march_jax._march_segment` returns it.

    Raises
    ------
    ValueError
        If n is not a multiple of ``block_rays``.
    """
    segment = Segment(edges, n_steps, steps, in_grid=True, refined=True)
    return march_segments_fused(state, start, direction, (segment,), rays, consts, ms_profile, aerosol_class,
                                tau_refine, stop_tau, interpret, block_rays, num_warps, max_registers, vector_loads,
                                fma)


@dataclass(frozen=True)
class Segment:
    """One segment of a ray's march for :func:`march_segments_fused`: its step ``edges`` (n_steps + 1, n) [m], the
    step count ``n_steps`` (static), each ray's own count ``steps`` (n,) <= n_steps or None, whether it lies in the
    grid (``in_grid``: the volume is sampled) and whether its steps are refined at cloud faces (``refined``: the grid
    segment with ``tau_refine`` > 0, :func:`swim.rt.march_jax._march_grid_refined`)."""

    edges: object
    n_steps: int
    steps: object = None
    in_grid: bool = False
    refined: bool = False


def march_segments_fused(state, start, direction, segments, rays, consts, ms_profile, aerosol_class, tau_refine=0.0,
                         stop_tau=0.0, interpret=False, block_rays=None, num_warps=None, max_registers=None,
                         vector_loads=True, fma=False):
    """Consecutive segments of :func:`swim.rt.march_jax._march_segment` (not its terminal step) in one Pallas kernel, the
    rays' state in registers from the first segment's first step to the last segment's last.

    ``segments``: :class:`Segment` each, in the order in which the rays cross them (e.g. the clear air before the
    grid, the grid, the clear air after it and the zero-length step at each ray's end); the other arguments as
    :func:`march_grid_fused` takes them. Returns the state after the last segment.

    Raises
    ------
    ValueError
        If n is not a multiple of ``block_rays``, or ``max_registers`` is outside [16, 255].
    """
    from jax.experimental import pallas as pl

    from .ptx_edits import install_ptx_edits, kernel_name

    from .march_inputs import packed_aerosol_3d
    from .march_settings import REFINE_SLOTS

    block_rays = BLOCK_RAYS if block_rays is None else int(block_rays)
    num_warps = NUM_WARPS if num_warps is None else int(num_warps)
    # the cap and the fused multiply-adds travel to the PTX in the kernel's name (swim.rt.ptx_edits); the caches keep
    # programs with other edits apart by the settings that ask for them (ExecutionSettings.fused_max_registers,
    # fused_fma)
    name = kernel_name("swim_fused_march", max_registers, bool(fma))
    if name != "swim_fused_march" and not interpret:
        install_ptx_edits()
    n = start.shape[0]
    if n % block_rays:
        raise ValueError(f"march_segments_fused: {n} rays are not a multiple of block_rays={block_rays}")
    volume = consts["volume"]
    nk, ny, nx, n_c = volume.shape
    padded = _padded_channels(n_c) if vector_loads else n_c
    if nk * ny * nx * padded > MAX_VOLUME_VALUES:  # the kernel's offsets are int32: fail here rather than wrap
        raise ValueError(f"march_segments_fused: a volume of {nk} x {ny} x {nx} cells x {padded} channels has more "
                         f"than 2**31 - 1 values, beyond the kernel's int32 offsets: render a smaller grid (the "
                         f"scene cropped to the camera's view, or coarser)")
    n_sp = consts["species_matrix"].shape[0]
    has_bounds = "index_map_bounds" in consts["index_map"]
    params, position = _params(consts, has_bounds)
    n_sky, nu_sky, nmu_sky = consts["sky"].shape
    n_class = consts["class_aod"].shape[0]
    multiple_scattering = ms_profile is not None
    columns = _state_columns(n_sp)
    f32 = jnp.float32

    ray_columns = _ray_columns(start, direction, rays, aerosol_class, segments)
    state_columns = _state_in(state, n_sp)
    vector = bool(vector_loads)
    tables, channels = _kernel_tables(consts, ms_profile, params, padded, vector)
    tables += [seg.edges.astype(f32).reshape(-1) for seg in segments]
    layout = _Layout(
        n=n, block_rays=block_rays, n_sp=n_sp, n_c=n_c, volume_shape=(nk, ny, nx), n_gas=consts["beta_gas"].shape[1],
        sky_shape=(n_sky, nu_sky, nmu_sky), n_class=n_class,
        diffuse_shape=(consts["diffuse_classes"].shape[1] // n_class, consts["diffuse_classes"].shape[2]),
        n_u=ms_profile.shape[2] if multiple_scattering else 1, channels=channels, vector=vector,
        aerosol_3d=packed_aerosol_3d(n_c, n_sp), multiple_scattering=multiple_scattering, has_bounds=has_bounds,
        position=position, outside=[0.0] * (n_c - 2) + [1.0, 1.0],  # the volume's channels beyond it: no cloud, sunlit
        slots=REFINE_SLOTS, tau_refine=tau_refine, stop_tau=stop_tau, columns=columns, segments=tuple(segments),
        counts=(len(ray_columns), len(state_columns), len(tables)))

    def kernel(*refs):
        """The Pallas kernel: a function of the refs alone, the layout fixed here."""
        _march_block(layout, refs)

    n_rays_in, n_state = layout.counts[:2]
    block = pl.BlockSpec((block_rays,), lambda b: (b,))
    whole = [pl.BlockSpec(t.shape, lambda b: (0,)) for t in tables]
    out_shape = [jax.ShapeDtypeStruct((n,), jnp.int32 if name in _FLAGS else f32) for name in columns]
    compiler_params = None
    if not interpret:
        from jax.experimental.pallas import triton as pl_triton

        compiler_params = pl_triton.CompilerParams(num_warps=num_warps, num_stages=1)
    outs = pl.pallas_call(
        kernel, out_shape=out_shape, grid=(n // block_rays,),
        in_specs=[block] * (n_rays_in + n_state) + whole, out_specs=[block] * len(columns),
        compiler_params=compiler_params, interpret=interpret, name=name,
    )(*ray_columns, *state_columns, *tables)
    return _state_out(state, dict(zip(columns, outs)), n_sp)


def _ray_columns(start, direction, rays, aerosol_class, segments):
    """The fused kernel's per-ray inputs, one (n,) column each: the rays' starts and directions, phase functions and
    aerosol class, and each segment's own step counts."""
    f32 = jnp.float32
    n = start.shape[0]
    ray_columns = [start[:, c] for c in range(3)] + [direction[:, c] for c in range(3)]
    ray_columns += [rays["p_rayleigh"]] + [rays["p_aerosol"][:, c] for c in range(3)]
    ray_columns += [rays["p_stratospheric"][:, c] for c in range(3)]
    ray_columns = [a.astype(f32) for a in ray_columns]
    ray_columns += [aerosol_class[0].astype(jnp.int32), aerosol_class[1][:, 0].astype(f32)]
    # each segment's own step counts: where a segment has none, its n_steps
    ray_columns += [(jnp.full(n, seg.n_steps) if seg.steps is None else seg.steps).astype(jnp.int32) for seg in segments]
    return ray_columns


def _state_in(state, n_sp):
    """The march's state as the fused kernel's columns (:func:`_state_columns`), one (n,) array each."""
    state_columns = []
    for key in _VECTORS:
        state_columns += [state[key][:, c] for c in range(3)]
    state_columns += [state[key] for key in _SCALARS]
    state_columns += [state["tau_species"][:, c] for c in range(n_sp)]
    state_columns += [state[key].astype(jnp.int32) for key in _FLAGS]
    return state_columns


def _state_out(state, out, n_sp):
    """The march's state from the fused kernel's output columns ``out`` (name -> (n,) array), the other entries of
    ``state`` as they were."""
    result = dict(state)
    for key in _VECTORS:
        result[key] = jnp.stack([out[f"{key}{c}"] for c in range(3)], axis=1)
    for key in _SCALARS:
        result[key] = out[key]
    result["tau_species"] = (jnp.stack([out[f"tau_species{c}"] for c in range(n_sp)], axis=1) if n_sp
                             else state["tau_species"])
    for key in _FLAGS:
        result[key] = out[key] != 0
    return result


def _kernel_tables(consts, ms_profile, params, padded, vector):
    """The fused kernel's tables, flattened: the parameter vector ``params`` (:func:`_params`), then gas, sky,
    volume, terrain, diffuse classes and diffuse-source profiles (the segments' edges follow them); and with
    ``vector`` loads the padded channel counts of the tables read by them (name -> count; empty without)."""
    f32 = jnp.float32
    volume = consts["volume"]
    nk, ny, nx, _ = volume.shape
    n_class = consts["class_aod"].shape[0]
    diffuse_table = consts["diffuse_classes"]
    multiple_scattering = ms_profile is not None
    gas_table = consts["beta_gas"][:GAS_COLUMN_ROW]
    channels = {}
    if vector:  # the tables with their channels last, padded to whole vector loads: a point's channels in adjacent
        # 16-byte words (the small tables here; the volume once per device volume, with_vector_volume)
        if "volume_vector" in consts:  # padded once per volume (with_vector_volume)
            volume_flat, n_cp = consts["volume_vector"], padded
            if volume_flat.shape != (nk * ny * nx * n_cp,):
                raise ValueError(f"march_segments_fused: volume_vector has shape {volume_flat.shape}, not the "
                                 f"volume's {nk} x {ny} x {nx} cells x {n_cp} padded channels")
        else:
            volume_flat, n_cp = _channels_padded(volume)
        gas_flat, n_gas_p = _channels_padded(gas_table.T)
        sky_flat, n_sky_p = _channels_padded(jnp.moveaxis(consts["sky"], 0, -1))
        diffuse_flat, n_diffuse_p = (_channels_padded(jnp.moveaxis(diffuse_table, 0, -1)) if n_class > 1
                                     else (jnp.zeros(1, f32), VECTOR))
        ms_flat, n_ms_p = (_channels_padded(jnp.moveaxis(ms_profile, 0, -1)) if multiple_scattering
                           else (jnp.zeros(1, f32), VECTOR))
        channels = {"volume": n_cp, "gas": n_gas_p, "sky": n_sky_p, "diffuse": n_diffuse_p, "ms": n_ms_p}
    else:  # channel-major, as the lockstep march reads them (the volume's cells keep their channels adjacent)
        volume_flat, gas_flat, sky_flat = volume.reshape(-1), gas_table.reshape(-1), consts["sky"].reshape(-1)
        diffuse_flat = diffuse_table.reshape(-1) if n_class > 1 else jnp.zeros(1, f32)
        ms_flat = ms_profile.reshape(-1) if multiple_scattering else jnp.zeros(1, f32)
    return [params, gas_flat, sky_flat, volume_flat, consts["terrain"].reshape(-1), diffuse_flat, ms_flat], channels


@dataclass(frozen=True)
class _Layout:
    """What the fused kernel knows when it is traced (Python values): ``n`` rays in all, ``block_rays`` a program, the
    tables' shapes (``volume_shape`` (nk, ny, nx) with ``n_c`` channels, ``n_gas`` heights, ``sky_shape``, the
    ``diffuse_shape`` (nu, nmu) of each of ``n_class`` classes, ``n_u`` heights of the diffuse-source profiles) and
    with ``vector`` loads their padded channel counts (``channels``, :func:`_kernel_tables`), the switches, the scalar
    constants' ``position`` in the parameter vector (:func:`_params`), the state's ``columns`` (:func:`_state_columns`),
    the ``segments`` and ``counts``: the ray inputs, state columns and tables that the kernel's refs begin with."""

    n: int
    block_rays: int
    n_sp: int
    n_c: int
    volume_shape: tuple
    n_gas: int
    sky_shape: tuple
    n_class: int
    diffuse_shape: tuple
    n_u: int
    channels: dict
    vector: bool
    aerosol_3d: bool
    multiple_scattering: bool
    has_bounds: bool
    position: dict
    outside: list
    slots: int
    tau_refine: float
    stop_tau: float
    columns: list
    segments: tuple
    counts: tuple


@dataclass(frozen=True)
class _Block:
    """One Triton program's block of rays in the fused kernel: the ``layout``, the tables' refs (``tables``: name ->
    ref), the rays' indices ``ray`` (B,), the kernel's scalar constants (``const``, :func:`_read_constants`) and the
    rays' inputs (``inputs``, :func:`_read_inputs`)."""

    layout: _Layout
    tables: dict
    ray: object
    const: dict
    inputs: dict


#: Bits of a pending slot's refinement depth in the one int32 that holds the slots' depths (:func:`_depth_at`).
_DEPTH_BITS = 3


def _march_block(layout, refs):
    """The fused kernel's body: one program's block of rays through every segment (``refs``: the ray inputs, state
    columns, tables and segments' edges, then the outputs, as :func:`march_segments_fused` passes them)."""
    from jax.experimental import pallas as pl

    from .march_settings import REFINE_DEPTH

    n_rays_in, n_state, n_tables = layout.counts
    ray_refs = refs[:n_rays_in]
    state_refs = refs[n_rays_in:n_rays_in + n_state]
    p_ref, gas_ref, sky_ref, vol_ref, terrain_ref, diffuse_ref, ms_ref, *edges_refs = \
        refs[n_rays_in + n_state:n_rays_in + n_state + n_tables]
    out_refs = refs[n_rays_in + n_state + n_tables:]
    block_rays = layout.block_rays
    ray = pl.program_id(0) * block_rays + jnp.arange(block_rays, dtype=jnp.int32)
    const = _read_constants(p_ref, layout.position, layout.has_bounds)
    inputs = _read_inputs(ray_refs)
    tables = {"gas": gas_ref, "sky": sky_ref, "volume": vol_ref, "terrain": terrain_ref, "diffuse": diffuse_ref,
              "ms": ms_ref}
    blk = _Block(layout, tables, ray, const, inputs)
    # The pending intervals, stored compactly (fewer registers: docs/decisions/0006-gpu-kernels.md): the slots'
    # depths are 3-bit fields of one int32 (_depth_at)
    slots = layout.slots
    if REFINE_DEPTH >= 1 << _DEPTH_BITS or _DEPTH_BITS * slots > 31:
        raise ValueError(f"march_segments_fused: REFINE_DEPTH {REFINE_DEPTH} and REFINE_SLOTS {slots} do not fit "
                         f"{_DEPTH_BITS}-bit fields of one int32")
    columns = layout.columns
    values = [r[...] for r in state_refs]
    st = dict(zip(columns, values))
    st["alive"], st["hit"] = st["alive"] != 0, st["hit"] != 0
    for seg, edges_ref, last in zip(layout.segments, edges_refs, inputs["step_counts"]):
        if seg.refined:
            st = _block_refined(blk, st, edges_ref, last)
        else:
            st = _block_plain(blk, st, edges_ref, last, seg.n_steps, seg.in_grid)
    for name, ref in zip(columns, out_refs):
        value = st[name]
        ref[...] = value.astype(jnp.int32) if name in _FLAGS else value


def _read_constants(p_ref, position, has_bounds):
    """The kernel's scalar constants, read from the parameter vector's ref (:func:`_params`): name -> scalar, or a
    list of them."""
    def scalar(name, k=0):
        return p_ref[position[name][0] + k]

    radius = scalar("radius")
    sun = [scalar("sun", c) for c in range(3)]
    z_bottom, dz, dh, top = scalar("z_bottom"), scalar("dz"), scalar("dh"), scalar("top")
    cx, cy, scale = scalar("centre", 0), scalar("centre", 1), scalar("scale")
    coef = [[scalar("coef", 10 * a + b) for b in range(10)] for a in range(2)]
    bounds = [scalar("bounds", b) for b in range(4)] if has_bounds else None
    spectra = [[scalar("spectra", 3 * a + b) for b in range(3)] for a in range(GAS_COLUMN_ROW)]
    angstrom = [scalar("angstrom", c) for c in range(3)]
    aerosol_ssa = [scalar("aerosol_ssa", c) for c in range(3)]
    strat_ssa = [scalar("stratospheric_ssa", c) for c in range(3)]
    return {"radius": radius, "sun": sun, "z_bottom": z_bottom, "dz": dz, "dh": dh, "top": top, "cx": cx, "cy": cy,
            "scale": scale, "coef": coef, "bounds": bounds, "spectra": spectra, "angstrom": angstrom,
            "aerosol_ssa": aerosol_ssa, "strat_ssa": strat_ssa}


def _read_inputs(ray_refs):
    """The block's per-ray inputs (:func:`_ray_columns`): name -> (B,) array, or a list of them."""
    inputs = [r[...] for r in ray_refs]
    return {"q0": inputs[0:3], "direction3": inputs[3:6], "p_r": inputs[6], "p_a": inputs[7:10],
            "p_s": inputs[10:13], "c0": inputs[13], "wc": inputs[14], "step_counts": inputs[15:]}


def _block_point(blk, s):
    """:func:`swim.rt.march_jax._point_geometry` of the block's samples at ``s`` (B,) [m]: the height h, the local
    solar-zenith cosine mu_s and the grid indices k, j, i."""
    cst = blk.const
    radius, sun, q0, direction3 = cst["radius"], cst["sun"], blk.inputs["q0"], blk.inputs["direction3"]
    bounds = cst["bounds"]
    q = [q0[c] + s * direction3[c] for c in range(3)]
    pz = q[2] + radius
    r = jnp.sqrt(q[0] ** 2 + q[1] ** 2 + pz ** 2)
    h = (q[0] ** 2 + q[1] ** 2 + q[2] ** 2 + 2 * radius * q[2]) / (r + radius)
    mu_s = (q[0] * sun[0] + q[1] * sun[1] + pz * sun[2]) / r
    u = (radius * q[0] / r - cst["cx"]) / cst["scale"]
    v = (radius * q[1] / r - cst["cy"]) / cst["scale"]
    if blk.layout.has_bounds:
        uc, vc = jnp.clip(u, bounds[0], bounds[1]), jnp.clip(v, bounds[2], bounds[3])
        du, dv = u - uc, v - vc
        i, j = (_cubic(uc, vc, c) + _cubic_du(uc, vc, c) * du + _cubic_dv(uc, vc, c) * dv for c in cst["coef"])
    else:
        i, j = (_cubic(u, v, c) for c in cst["coef"])
    k = (h - cst["z_bottom"]) / cst["dz"]
    return h, mu_s, k, j, i


def _block_lookups(blk, h, mu_s, k, j, i, in_grid):
    """The tables at the block's samples (:func:`_block_point`): :func:`swim.rt.march_jax._gas_at`'s extinction
    profiles, sun transmittance and diffuse irradiance, the volume's channels (in the grid) and the terrain's height
    (name -> (B,) array, or a list of three: one per wavelength)."""
    from .march_jax import bilinear_gathers, lerp_gathers, trilinear_gathers

    lay, t, c = blk.layout, blk.tables, blk.const
    vector, n_sp = lay.vector, lay.n_sp
    n_sky, nu_sky, nmu_sky = lay.sky_shape
    nk, ny, nx = lay.volume_shape
    # _gas_at: the four extinction profiles (ozone's absorbs only), then sky's sun transmittance and diffuse
    # irradiance
    profile = (_lerp_vec4(t["gas"], lay.n_gas, lay.channels.get("gas"), GAS_COLUMN_ROW, h / c["dh"]) if vector
               else lerp_gathers(t["gas"], GAS_COLUMN_ROW, lay.n_gas, h / c["dh"]))
    beta_r, beta_a, beta_s, beta_o = ([profile[a] * c["spectra"][a][b] for b in range(3)]
                                      for a in range(GAS_COLUMN_ROW))
    height_u = jnp.sqrt(jnp.clip(h / c["top"], 0.0, 1.0))
    fm = (mu_s + 1.0) * 0.5 * (nmu_sky - 1)
    sky = (_bilinear_vec4(t["sky"], nu_sky, nmu_sky, lay.channels.get("sky"), n_sky, height_u * (nu_sky - 1), fm)
           if vector else bilinear_gathers(t["sky"], (n_sky, nu_sky, nmu_sky), height_u * (nu_sky - 1), fm))
    t_sun, diffuse = sky[:3], sky[3:]
    if in_grid:  # trilinear: each corner's channels four at a time, or a scalar gather per channel and corner
        vol = (_trilinear_vec4(t["volume"], (nk, ny, nx, lay.channels.get("volume")), lay.n_c, k, j, i, lay.outside)
               if vector else trilinear_gathers(t["volume"], (nk, ny, nx, lay.n_c), k, j, i, lay.outside))
        beta_sp = vol[:n_sp]
        t_cloud, shadow = vol[-2], vol[-1]
    else:
        beta_sp, t_cloud, shadow = [], jnp.ones_like(h), jnp.ones_like(h)
    if in_grid and lay.aerosol_3d:
        beta_a3 = [vol[n_sp] * c["angstrom"][b] for b in range(3)]
        t_aerosol = [jnp.exp(-vol[n_sp + 1] * c["angstrom"][b]) for b in range(3)]
    else:
        beta_a3 = [jnp.zeros_like(h)] * 3
        t_aerosol = [jnp.ones_like(h)] * 3
    ground = bilinear_gathers(t["terrain"], (1, ny, nx), jnp.clip(j, 0, ny - 1), jnp.clip(i, 0, nx - 1))[0]
    return {"beta_r": beta_r, "beta_a": beta_a, "beta_s": beta_s, "beta_o": beta_o, "height_u": height_u,
            "t_sun": t_sun, "diffuse": diffuse, "beta_sp": beta_sp, "t_cloud": t_cloud, "shadow": shadow,
            "beta_a3": beta_a3, "t_aerosol": t_aerosol, "ground": ground}


def _block_diffuse_classes(blk, height_u, mu_s):
    """:func:`swim.rt.march_jax.diffuse_at` for the block's samples: the diffuse irradiance of the ray's aerosol class,
    between two stacked tables (a list of three (B,) arrays)."""
    from .march_jax import bilinear_gathers

    lay, diffuse_ref = blk.layout, blk.tables["diffuse"]
    n_class, (nu_d, nmu_d) = lay.n_class, lay.diffuse_shape
    c0, wc = blk.inputs["c0"], blk.inputs["wc"]
    fu = jnp.clip(height_u * (nu_d - 1), 0.0, nu_d - 1.001)
    fm_d = (mu_s + 1.0) * 0.5 * (nmu_d - 1)
    if lay.vector:
        lower, upper = (_bilinear_vec4(diffuse_ref, n_class * nu_d, nmu_d, lay.channels["diffuse"], 3,
                                       (c0 + d) * nu_d + fu, fm_d) for d in (0, 1))
    else:
        lower, upper = (bilinear_gathers(diffuse_ref, (3, n_class * nu_d, nmu_d), (c0 + d) * nu_d + fu,
                                         fm_d) for d in (0, 1))
    return [lower[b] * (1 - wc) + upper[b] * wc for b in range(3)]


def _block_bands(blk, st, at, light, ds_eff, t0, weight, j9):
    """The block's per-wavelength sums after a sample (:func:`_block_sample`): the clear sky's radiance (Eq. 3), Eq.
    12's integrands and the clear optical depth, from the sample's lookups ``at`` (:func:`_block_lookups`) and
    ``light`` (irradiance, irradiance_h, beta_clear, beta_h)."""
    c, p_r, p_a, p_s = blk.const, blk.inputs["p_r"], blk.inputs["p_a"], blk.inputs["p_s"]
    beta_r, beta_a, beta_s, beta_a3 = at["beta_r"], at["beta_a"], at["beta_s"], at["beta_a3"]
    irradiance, irradiance_h, beta_clear, beta_h = light
    new = {}
    for b in range(3):
        x = (beta_clear[b] + beta_h) * ds_eff
        big = jnp.abs(x) > 1e-4
        step_mean = jnp.where(big, -jnp.expm1(-x) / jnp.where(big, x, 1.0), 1.0 - 0.5 * x)
        t_obs = jnp.exp(-(st[f"tau_clear{b}"] + t0))
        scat_a = (beta_a[b] + beta_a3[b]) * c["aerosol_ssa"][b]
        scat_s = beta_s[b] * c["strat_ssa"][b]
        source = (beta_r[b] * p_r + scat_a * p_a[b] + scat_s * p_s[b]) * irradiance[b]
        if blk.layout.multiple_scattering:
            source = source + (beta_r[b] * j9[b] + scat_a * j9[3 + b] + scat_s * j9[6 + b]) * at["t_cloud"]
        new[f"l_clear{b}"] = st[f"l_clear{b}"] + t_obs * source * (ds_eff * step_mean)
        new[f"i_nogas{b}"] = st[f"i_nogas{b}"] + irradiance_h[b] * weight
        new[f"i_gas{b}"] = st[f"i_gas{b}"] + irradiance_h[b] * jnp.exp(-st[f"tau_clear{b}"]) * weight
        new[f"tau_clear{b}"] = st[f"tau_clear{b}"] + beta_clear[b] * ds_eff
    return new


def _block_sample(blk, st, s_lo, ds, in_grid):
    """:func:`swim.rt.march_jax._march_segment`'s ``sample`` (not the terminal step's) for the block: the state after
    a step of length ``ds`` (B,) from ``s_lo`` (B,) [m], and the step's hydrometeor extinction (B,)."""
    from .march_jax import lerp_gathers
    from .march_settings import REFINE_VISIBLE_TAU, SKYLIGHT_SCALAR_FACTOR

    lay, n_sp, stop_tau = blk.layout, blk.layout.n_sp, blk.layout.stop_tau
    s = s_lo + 0.5 * ds
    h, mu_s, k, j, i = _block_point(blk, s)
    at = _block_lookups(blk, h, mu_s, k, j, i, in_grid)
    beta_sp, t_cloud, height_u, diffuse = at["beta_sp"], at["t_cloud"], at["height_u"], at["diffuse"]
    gap = h - at["ground"]
    alive = st["alive"]
    hit_now = alive & (gap < 0)
    frac = jnp.where(hit_now, jnp.clip(st["gap"] / jnp.maximum(st["gap"] - gap, 1e-6), 0.0, 1.0), 1.0)
    ds_eff = jnp.where(alive & ~hit_now, ds, 0.0)
    cloud_sun = t_cloud * at["shadow"]
    irradiance = [at["t_sun"][b] * cloud_sun * at["t_aerosol"][b] for b in range(3)]
    if in_grid and lay.n_class > 1:  # diffuse_at: the ray's aerosol class, between two stacked tables
        diffuse = _block_diffuse_classes(blk, height_u, mu_s)
    irradiance_h = ([irradiance[b] + SKYLIGHT_SCALAR_FACTOR * diffuse[b] * t_cloud for b in range(3)] if in_grid
                    else irradiance)
    # the clear air's extinction: its scattering components' and ozone's absorption (which adds no source)
    beta_clear = [at["beta_r"][b] + at["beta_a"][b] + at["beta_a3"][b] + at["beta_s"][b] + at["beta_o"][b]
                  for b in range(3)]
    beta_h = functools.reduce(lambda a, b: a + b, beta_sp) if beta_sp else jnp.zeros_like(h)
    j9 = None
    if lay.multiple_scattering:  # _profile_at: the ray's own profile
        n_u, ray, ms_ref = lay.n_u, blk.ray, blk.tables["ms"]
        j9 = (_lerp_vec4(ms_ref, n_u, lay.channels.get("ms"), 9, height_u * (n_u - 1), row=ray * n_u) if lay.vector
              else lerp_gathers(ms_ref, 9, n_u, height_u * (n_u - 1), row=ray * n_u, stride=lay.n * n_u))
    t0 = st["tau_h"]
    t1 = t0 + beta_h * ds_eff
    weight = jnp.exp(-jnp.minimum(t0, 2.0)) - jnp.exp(-jnp.minimum(t1, 2.0))
    weight = jnp.where(t1 >= t0, jnp.maximum(weight, 0.0), weight)
    new = _block_bands(blk, st, at, (irradiance, irradiance_h, beta_clear, beta_h), ds_eff, t0, weight, j9)
    new["i_cloud_t"] = st["i_cloud_t"] + cloud_sun * weight
    new["hit_s"] = jnp.where(hit_now, s - 0.5 * ds + frac * ds, st["hit_s"])
    new["hit_lo"] = jnp.where(hit_now, st["s_last"], st["hit_lo"])
    new["hit_hi"] = jnp.where(hit_now, s, st["hit_hi"])
    new["hit_from"] = jnp.where(hit_now, s_lo, st["hit_from"])
    tau_species = [st[f"tau_species{c}"] + beta_sp[c] * ds_eff if beta_sp else st[f"tau_species{c}"]
                   for c in range(n_sp)]
    alive = alive & ~hit_now
    if in_grid and stop_tau > 0:
        stopped = alive & (t1 > stop_tau) & (t0 >= REFINE_VISIBLE_TAU) & (blk.inputs["direction3"][2] >= 0)
        scale_sp = stop_tau / jnp.maximum(t1, stop_tau)
        tau_species = [jnp.where(stopped, t * scale_sp, t) for t in tau_species]
        t1 = jnp.where(stopped, jnp.asarray(stop_tau, jnp.float32), t1)
        alive = alive & ~stopped
    new["tau_h"] = t1
    for c in range(n_sp):
        new[f"tau_species{c}"] = tau_species[c]
    new["alive"] = alive
    new["hit"] = st["hit"] | hit_now
    new["gap"] = gap
    new["s_last"] = s
    return new, beta_h


def _pick(stack, index):
    """stack[index] of a list of (B,) slots."""
    out = stack[0]
    for slot in range(1, len(stack)):
        out = jnp.where(index == slot, stack[slot], out)
    return out


# The pending intervals, stored compactly (fewer registers: docs/decisions/0006-gpu-kernels.md). The stack of
# _march_grid_refined is a contiguous partition of the ray's path: each interval pushed above another ends
# where that one begins (a split's halves share their midpoint; a roll-back's three intervals are the
# previous interval's halves and the current one, adjacent to it by definition), so slot s > 0 ends at slot
# s - 1's start, and only the bottom slot's end is kept (``hi0``). The slots' depths (at most REFINE_DEPTH)
# are 3-bit fields of one int32.
def _depth_at(packed, slot, slots):
    """The refinement depth of pending slot ``slot`` (B,) in the packed depths ``packed`` (B,) int32."""
    return (packed >> (_DEPTH_BITS * jnp.clip(slot, 0, slots - 1))) & ((1 << _DEPTH_BITS) - 1)


def _with_depth(packed, where, slot, value, slots):
    """The packed depths ``packed`` with slot ``slot``'s set to ``value`` where ``where``."""
    shift = _DEPTH_BITS * jnp.clip(slot, 0, slots - 1)
    cleared = packed & ~(((1 << _DEPTH_BITS) - 1) << shift)
    return jnp.where(where, cleared | (value << shift), packed)


def _block_refined_iteration(blk, carry, edges_ref, last):
    """One iteration of :func:`_block_refined` (of :func:`swim.rt.march_jax._refined_iteration`) for the block: take
    each ray's next interval, sample it and accumulate it, push its halves or roll back."""
    from .march_jax import _predicted_halving
    from .march_settings import REFINE_DEPTH, REFINE_VISIBLE_TAU

    slots, tau_refine, n, ray = blk.layout.slots, blk.layout.tau_refine, blk.layout.n, blk.ray
    st, m, pending, stack_lo, hi0, depths, budget, saved, prev = carry
    stacked = pending > 0
    top_slot = jnp.maximum(pending - 1, 0)
    next_step = jnp.maximum(jnp.minimum(m, last - 1), 0)
    # a ray that has stopped (the ground, opaque cloud) samples nothing more: done, its pending intervals
    # dropped (_march_grid_refined's, docs/decisions/0006-gpu-kernels.md)
    done = (~stacked & (m >= last)) | ~st["alive"]
    lo = jnp.where(stacked, _pick(stack_lo, top_slot), edges_ref[next_step * n + ray])
    top_hi = jnp.where(top_slot == 0, hi0, _pick(stack_lo, top_slot - 1))
    hi = jnp.where(stacked, top_hi, edges_ref[(next_step + 1) * n + ray])
    depth = jnp.where(stacked, _depth_at(depths, top_slot, slots), 0)
    ds = jnp.where(done, 0.0, hi - lo)
    base = pending - stacked.astype(jnp.int32)
    adjacent = prev["valid"] & (prev["hi"] == lo)
    # _march_grid_refined's predicted halving: the second half pending, the first half sampled
    halve = (~done & (budget > 0) & st["alive"]
             & _predicted_halving(adjacent, prev["beta_h"], ds, depth, st["tau_h"], base, slots, tau_refine))
    half = lo + 0.5 * ds
    stack_lo = [jnp.where(halve & (base == slot), half, stack_lo[slot]) for slot in range(slots)]
    hi0 = jnp.where(halve & (base == 0), hi, hi0)
    depths = _with_depth(depths, halve, base, depth + 1, slots)
    hi = jnp.where(halve, half, hi)
    depth = depth + halve.astype(jnp.int32)
    ds = jnp.where(halve, hi - lo, ds)
    base = base + halve.astype(jnp.int32)
    budget = budget - halve.astype(jnp.int32)
    new, beta_h = _block_sample(blk, st, lo, ds, True)
    live = ~done & (budget > 0) & st["alive"]
    change = jnp.where(adjacent, jnp.abs(beta_h - prev["beta_h"]), 0.0)
    rollback = (live & adjacent & (prev["depth"] < REFINE_DEPTH)
                & (change * (prev["hi"] - prev["lo"]) > tau_refine) & (base + 3 <= slots)
                & (saved["tau_h"] < REFINE_VISIBLE_TAU))
    refine = (live & ~rollback & (depth < REFINE_DEPTH) & (st["tau_h"] < REFINE_VISIBLE_TAU)
              & (base + 2 <= slots) & (jnp.maximum(beta_h, change) * ds > tau_refine))
    keep = ~done & ~refine & ~rollback
    save = keep & live
    saved = {key: jnp.where(save, st[key], value) for key, value in saved.items()}
    st = {key: jnp.where(keep, value, jnp.where(rollback, saved[key], st[key])) for key, value in new.items()}
    mid = lo + 0.5 * ds
    prev_mid = prev["lo"] + 0.5 * (prev["hi"] - prev["lo"])
    # a split: (mid, hi) at base, (lo, mid) above it; a roll-back: (lo, hi) at base, then the previous
    # interval's halves (prev_mid, prev hi = lo) and (prev lo, prev_mid) above it
    new_lo = []
    for slot in range(slots):
        first, second = refine & (base == slot), refine & (base + 1 == slot)
        again, p_second, p_first = (rollback & (base + d == slot) for d in range(3))
        new_lo.append(jnp.where(first | p_second, jnp.where(first, mid, prev_mid),
                                jnp.where(second | again, lo, jnp.where(p_first, prev["lo"], stack_lo[slot]))))
    hi0 = jnp.where((refine | rollback) & (base == 0), hi, hi0)
    depths = _with_depth(depths, refine | rollback, base, jnp.where(refine, depth + 1, depth), slots)
    depths = _with_depth(depths, refine | rollback, base + 1, jnp.where(refine, depth, prev["depth"]) + 1, slots)
    depths = _with_depth(depths, rollback, base + 2, prev["depth"] + 1, slots)
    prev = {"valid": save | (prev["valid"] & ~rollback), "lo": jnp.where(save, lo, prev["lo"]),
            "hi": jnp.where(save, hi, prev["hi"]), "beta_h": jnp.where(save, beta_h, prev["beta_h"]),
            "depth": jnp.where(save, depth, prev["depth"])}
    pending = base + 2 * refine.astype(jnp.int32) + 3 * rollback.astype(jnp.int32)
    m = m + (~stacked & ~done).astype(jnp.int32)
    budget = budget - refine.astype(jnp.int32) - rollback.astype(jnp.int32)
    return st, m, pending, new_lo, hi0, depths, budget, saved, prev


def _block_refined(blk, st, edges_ref, last):
    """:func:`swim.rt.march_jax._march_grid_refined` of the block: until each ray has taken its steps."""
    from .march_settings import REFINE_BUDGET

    block_rays, slots, f32 = blk.layout.block_rays, blk.layout.slots, jnp.float32

    def unfinished(carry):
        st, m, pending, *_ = carry
        return jnp.max((((pending != 0) | (m < last)) & st["alive"]).astype(jnp.int32)) > 0

    zero_f = jnp.zeros((block_rays,), f32)
    zero_i = jnp.zeros((block_rays,), jnp.int32)
    prev = {"valid": zero_i != 0, "lo": zero_f, "hi": zero_f, "beta_h": zero_f, "depth": zero_i}
    carry = (st, zero_i, zero_i, [zero_f] * slots, zero_f, zero_i,
             jnp.full((block_rays,), REFINE_BUDGET, jnp.int32), dict(st), prev)
    return jax.lax.while_loop(unfinished, lambda c: _block_refined_iteration(blk, c, edges_ref, last), carry)[0]


def _block_plain(blk, st, edges_ref, last, n_steps, in_grid):
    """:func:`swim.rt.march_jax._march_segment`'s loop of ``n_steps`` midpoint steps; a ray's steps beyond its
    own count ``last`` leave it as it is. The block's loop ends when no ray that has not stopped has steps
    left: a stopped ray's samples add nothing (docs/decisions/0006-gpu-kernels.md), so a block of padding or of
    rays stopped in the grid takes none of the steps after it."""
    n, ray = blk.layout.n, blk.ray

    def body(carry):
        m, st = carry
        s_lo = edges_ref[m * n + ray]
        ds = edges_ref[(m + 1) * n + ray] - s_lo
        new = _block_sample(blk, st, s_lo, ds, in_grid)[0]
        taken = m < last
        return m + 1, {key: jnp.where(taken, value, st[key]) for key, value in new.items()}

    def more(carry):
        m, st = carry
        return (m < n_steps) & (jnp.max(((m < last) & st["alive"]).astype(jnp.int32)) > 0)

    return jax.lax.while_loop(more, body, (jnp.int32(0), st))[1]
