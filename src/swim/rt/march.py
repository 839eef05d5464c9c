"""Steps 1b, 2 and 3: rays from the observer through the atmosphere, the model grid and onto the ground.

Each pixel's ray is marched once, from where it enters the atmosphere (or the observer) to where it
leaves the atmosphere (100 km) or meets the ground, in three segments with fixed step counts: clear air
before the model grid, the grid (its steps concentrated where there are hydrometeors, raised terrain or
aerosol gradients, and few where there is nothing: :func:`grid_step_edges`), and clear air after it (the clear
air's steps dense where the air is: :func:`clear_step_edges`). Along the way the kernel accumulates

* the clear-sky radiance of the gas and the aerosol: single scattering (Step 2, Eq. 3), lit by the sun
  through the spherical atmosphere (tabulated, :mod:`swim.rt.gas`) and through the clouds (T of Step 1a,
  so cloud shadows fall on the air as well), plus the higher orders from the precomputed directional
  diffuse source (:mod:`swim.rt.multiple_scattering`), attenuated towards the observer by gas, aerosol
  *and* hydrometeors;
* for the hydrometeors (Step 1b): the optical depth tau_o per species and the integral of Eq. 12,
  ``int_0^l (E/E_TOA) e^{-tau_o} dtau_o`` with l = min(2, tau_o), both with and without the gas
  attenuation between the observer and the cloud;
* the first intersection with the terrain (bilinear height field, refined linearly between steps; beyond
  the grid the terrain continues at its edge heights) or the sea-level sphere.

After the march the cloud radiance follows Eq. 12 with the effective phase function of Eq. 13
(:func:`swim.optics.phase.effective_phase_function`), blended with the cloud-top reflection of Eqs. 24-26
for rays that look down on clouds; the ground reflects direct and diffuse light on its tilted terrain facet
(Eq. 35; BRDFs, sun glint and slopes in :mod:`swim.surface.lighting`). Step 3 (Eqs. 32-34) is realised by the
compositing itself: gas in front of a cloud adds unattenuated, the cloud is seen through the gas in front of it (the e^{-tau_1} of Eq. 33), and the sky
and ground behind it are attenuated by its optical depth. docs/rendering.md states the interpretation.

This module is the march's dispatcher: :func:`trace_rays` cuts the rays' segments, splits the rays into chunks and
hands each chunk to a kernel (:attr:`swim.rt.march_settings.ExecutionSettings.backend`). On a CPU that is the numba
kernel (:mod:`swim.rt.march_cpu`: one loop per ray, ~5x faster there than the JAX kernel), with its per-ray set-up
(:func:`swim.rt.march_cpu.prepare_rays`) and the clouds' and the ground's composition (:mod:`swim.rt.compose_cpu`,
:mod:`swim.rt.ground_cpu`) in numba too; on a GPU the JAX kernel (:mod:`swim.rt.march_jax`: float32, jit-compiled
once per batch size, chunks marched in lockstep), imported only then (docs/decisions/0002-per-ray-cpu-kernel.md,
docs/decisions/0009-work-around-the-march.md, docs/decisions/0011-jax-only-where-it-runs.md). The kernels' inputs
come from :mod:`swim.rt.march_inputs`, their settings and constants from :mod:`swim.rt.march_settings`.
"""

from __future__ import annotations

import collections
import functools
import logging
import weakref
from dataclasses import replace

import numpy as np

from ..constants import EARTH_RADIUS_M
from ..errors import SwimInputError
from ..frames import ray_sphere_intersections
from ..workers import in_worker_thread, parallel_map, threads, worker_pool
from .clouds import CLOUD_KERNEL_KEYS
from .march_inputs import GridGeometry, _ends_on_surface
from .march_settings import (CELL_SLACK, CLEAR_PROBES, CLEAR_STEP_FLOOR, CLEAR_STEP_POWER, EMPTY_CELLS_PER_STEP,
                             EMPTY_STEP_WEIGHT, MAX_PROBES, MarchSettings, REFINE_BUDGET, REFINE_DEPTH, REFINE_SLOTS,
                             REFINE_VISIBLE_TAU, SUNLIT_CELLS_PER_STEP, TERRAIN_BISECTIONS)
from .solar import PER_COLUMN_SUN_TILT_DEG

log = logging.getLogger(__name__)


def ray_segments(origins, directions, geometry: GridGeometry, top=100_000.0, radius=EARTH_RADIUS_M):
    """Clip rays to the atmosphere, the sea-level sphere and the model grid (host side, float64), with NumPy: the
    reference of :func:`ray_segments_compiled`, which :func:`trace_rays` calls.

    Parameters
    ----------
    origins, directions : numpy.ndarray
        Shape (n, 3): ray origins [m] and unit directions in the scene frame.
    geometry : GridGeometry
    top : float
        Top of the atmosphere [m].

    Returns
    -------
    dict
        ``start`` (n, 3) [m]: rebased origins (first point inside the atmosphere) relative to the
        reference sea-level point (0, 0, R); ``bounds`` (n, 3) [m]: distances from ``start`` to the grid
        entry, grid exit and end of the ray; ``ends_on_ground`` (n,) bool; ``valid`` (n,) bool (False
        where the ray misses the atmosphere).
    """
    o = np.asarray(origins, dtype=float)
    d = np.asarray(directions, dtype=float)
    t1, t2 = ray_sphere_intersections(o, d, radius + top)
    valid = np.isfinite(t2) & (t2 > 0)
    s_start = np.where(valid, np.maximum(np.nan_to_num(t1), 0.0), 0.0)
    s_end = np.where(valid, t2, 0.0)
    g1, _ = ray_sphere_intersections(o, d, radius)
    hits_sea = np.isfinite(g1) & (g1 > 0) & (g1 < s_end)
    s_end = np.where(hits_sea, g1, s_end)

    # Model grid: below its top shell and inside its (slightly widened) lateral index bounds.
    k1, k2 = ray_sphere_intersections(o, d, radius + geometry.top)
    shell_in = np.where(np.isfinite(k1), np.maximum(k1, 0.0), np.inf)
    shell_out = np.where(np.isfinite(k2), k2, -np.inf)
    _, ny, nx = geometry.shape
    margin = _lateral_margin(geometry, radius)
    rel_x, rel_y = o[:, 0] - geometry.origin[0], o[:, 1] - geometry.origin[1]
    lo = np.full(len(o), -np.inf)
    hi = np.full(len(o), np.inf)
    for axis, n in ((0, nx), (1, ny)):
        a, b = -margin, n - 1 + margin
        # the inverse affine map element by element, not a matrix product: BLAS's fused multiply-adds differ from
        # one CPU to another, and the compiled twin (swim.rt.segments_cpu) takes these operations in this order
        row = geometry.inverse[axis]
        at = rel_x * row[0] + rel_y * row[1]
        rate = d[:, 0] * row[0] + d[:, 1] * row[1]
        with np.errstate(divide="ignore", invalid="ignore"):
            e1 = (a - at) / rate
            e2 = (b - at) / rate
        still = np.abs(rate) < 1e-12
        inside = (at >= a) & (at <= b)
        e_lo = np.where(still, np.where(inside, -np.inf, np.inf), np.minimum(e1, e2))
        e_hi = np.where(still, np.where(inside, np.inf, -np.inf), np.maximum(e1, e2))
        lo = np.maximum(lo, e_lo)
        hi = np.minimum(hi, e_hi)
    s_a = np.maximum.reduce([s_start, shell_in, lo])
    s_b = np.minimum.reduce([s_end, shell_out, hi])
    empty = ~(s_b > s_a)
    s_a = np.where(empty, s_start, s_a)
    s_b = np.where(empty, s_start, s_b)

    start = o + s_start[:, None] * d
    start[:, 2] -= radius
    bounds = np.stack([s_a - s_start, s_b - s_start, s_end - s_start], axis=1)
    bounds = np.where(valid[:, None], bounds, 0.0)
    return {"start": start, "bounds": bounds, "ends_on_ground": hits_sea & valid, "valid": valid}


def _lateral_margin(geometry: GridGeometry, radius):
    """Cells [-] by which :func:`ray_segments` widens the grid's lateral index bounds: the affine fit's error and
    the height-dependent scale of (x, y)."""
    _, ny, nx = geometry.shape
    return 1.0 + geometry.top / radius * max(nx, ny) + geometry.affine_residual_cells


def grid_tilt_deg(geometry: GridGeometry, radius=EARTH_RADIUS_M) -> float:
    """The largest angle [deg] between the vertical at a corner column of the grid's affine frame and the vertical at
    the scene's reference point: :func:`swim.rt.solar.column_tilt_deg` from the affine fit (exact for a grid regular
    in orthographic (x, y), such as :func:`swim.io.globe.hemisphere_scene`'s; within the fit's residual, 0.02 deg for
    the WRF Katrina grid, for others), which is what the march has of the volume. Above
    :data:`swim.rt.solar.PER_COLUMN_SUN_TILT_DEG` the numba march composes each ray's clouds at its own vertical
    (:func:`swim.rt.compose_cpu.local_view_geometry`)."""
    _, ny, nx = geometry.shape
    corners = np.array([[0.0, 0.0], [nx - 1.0, 0.0], [0.0, ny - 1.0], [nx - 1.0, ny - 1.0]])
    xy = np.asarray(geometry.origin, dtype=float)[None] + corners @ np.asarray(geometry.matrix, dtype=float).T
    return float(np.degrees(np.arcsin(min(float(np.max(np.hypot(xy[:, 0], xy[:, 1]))) / radius, 1.0))))


def ray_segments_compiled(origins, directions, geometry: GridGeometry, top=100_000.0, radius=EARTH_RADIUS_M):
    """:func:`ray_segments` one ray at a time in compiled code (:mod:`swim.rt.segments_cpu`): the same arguments
    and dict, ~10x faster on a CPU (no float64 temporaries: 47 -> 4.7 ms for 200 000 rays on one thread here);
    what :func:`trace_rays` calls. The same operations in the same order, so the same results where NumPy's
    ``einsum`` sums three terms as this machine's does, else within float64 round-off
    (docs/decisions/0009-work-around-the-march.md)."""
    from .segments_cpu import ray_segments_into

    o = np.ascontiguousarray(origins, dtype=np.float64)
    d = np.ascontiguousarray(directions, dtype=np.float64)
    n = len(o)
    out = {"start": np.empty((n, 3)), "bounds": np.empty((n, 3)), "ends_on_ground": np.empty(n, np.bool_),
           "valid": np.empty(n, np.bool_)}
    _, ny, nx = geometry.shape
    ray_segments_into(o, d, np.ascontiguousarray(geometry.origin, dtype=np.float64),
                      np.ascontiguousarray(geometry.inverse, dtype=np.float64), (ny, nx),
                      float(_lateral_margin(geometry, radius)), float(radius), float(top), float(geometry.top),
                      out["start"], out["bounds"], out["ends_on_ground"], out["valid"])
    return out


def check_rays(caller, origins, directions):
    """Raise :class:`SwimInputError` naming ``caller`` unless ``origins`` and ``directions`` are finite (n, 3) arrays
    [m, unit vectors] with n >= 1 (what :func:`trace_rays` and :func:`swim.rt.ray_table.build_ray_table` take)."""
    for name, value in (("origins", origins), ("directions", directions)):
        value = np.asarray(value, dtype=float)
        if value.ndim != 2 or value.shape[-1] != 3 or not np.all(np.isfinite(value)):
            raise SwimInputError(f"{caller}: {name} must be a finite (n, 3) array [m for origins, unit vectors "
                                 f"for directions], got shape {value.shape} with non-finite values or the wrong shape")
    if len(origins) == 0:
        raise SwimInputError(f"{caller} needs at least one ray, got none")


def without_empty_segments(settings: MarchSettings, has) -> MarchSettings:
    """``settings`` with no steps for the segments (before, in, after the grid) that ``has`` (3 bools) says no ray
    of a batch has: a batch of observers inside the grid marches nothing before it."""
    return replace(settings, **{name: 0 for name, there in zip(("n_before", "n_grid", "n_after"), has) if not there})


def ray_segments_parallel(origins, directions, geometry: GridGeometry, top=100_000.0):
    """:func:`ray_segments_compiled` in blocks on up to 8 cores (the kernel runs without the GIL), a block per thread
    at least where there are :data:`SEGMENT_MIN_BLOCK` rays per thread: what :func:`trace_rays` and
    :func:`swim.rt.ray_table.build_ray_table` call. Compiled, ~45 -> ~7 ms of a warm 1024^2 adaptive all-sky
    (docs/decisions/0009-work-around-the-march.md); an adaptive render's batches of 20 000-70 000 rays were one block,
    on one thread while the others waited. The same arguments and dict as :func:`ray_segments`."""
    workers = min(threads(), 8)
    block = min(SEGMENT_BLOCK, max(SEGMENT_MIN_BLOCK, -(-len(origins) // workers)))

    def segments(lo):
        return ray_segments_compiled(origins[lo:lo + block], directions[lo:lo + block], geometry, top=top)

    blocks = parallel_map(segments, range(0, len(origins), block), workers)
    return {key: np.concatenate([b[key] for b in blocks]) for key in blocks[0]} if len(blocks) > 1 else blocks[0]


#: Rays per call of :func:`ray_segments_compiled` and of a ``ray_phase`` function in :func:`trace_rays` (bounds the
#: phase functions' temporaries).
SEGMENT_BLOCK = 65536
#: Fewest rays per block of :func:`ray_segments_compiled` in :func:`trace_rays` when a batch is split between threads:
#: a smaller block's hand-over to a thread costs more than its rays' segments (~0.02-0.03 us a ray).
SEGMENT_MIN_BLOCK = 8192
#: Smallest batch of rays the kernel is compiled for (:func:`padded_batch_size`).
MIN_BATCH = 256


def padded_batch_size(n, chunk):
    """Rays a kernel call of n rays marches: ``chunk``, or for a last, smaller batch the next power of two
    (at least :data:`MIN_BATCH`). The kernel is compiled once per batch size, so a few sizes serve any number
    of rays (renders of every image size, the batches of adaptive sampling) with at most half of a batch
    wasted on padding."""
    if n >= chunk:
        return chunk
    return int(min(chunk, max(MIN_BATCH, 1 << int(np.ceil(np.log2(max(n, 1)))))))


#: Fewest rays of a chunk before the last round of :func:`chunk_spans` (each chunk has fixed costs of its own: its
#: job's Python calls and arrays).
TAIL_CHUNK = 512


def chunk_spans(n, chunk, cores, least=TAIL_CHUNK):
    """The chunks [lo, hi) of a batch of n rays that ``cores`` workers march on the CPU, in order: each round of
    ``cores`` chunks takes half of the rays left, split evenly (at most ``chunk`` rays per chunk), until such chunks
    would be smaller than ``least``: the last round takes what is left, split evenly. Chunks thus shrink towards the
    batch's end.

    This is "factoring" (Hummel, Schonberg and Flynn 1992, "Factoring: a method for scheduling parallel loops",
    Commun. ACM 35(8), 90-101, doi:10.1145/135226.135232). A ray's cost varies ~10-fold across an image (the horizon's
    rays cross far more cells than the zenith's), so chunks of equal size left one core marching the batch's last
    chunk alone for 0.04-0.15 s of a 1024^2 all-sky's three batches while the other waited
    (docs/decisions/0002-per-ray-cpu-kernel.md); with chunks this small at the end, it waits for a small one. A small
    batch (a small image, a level of adaptive sampling) still runs on every core from the start.

    Parameters
    ----------
    n : int
        Rays in the batch, >= 0.
    chunk : int
        Most rays per chunk, >= 1.
    cores : int
        Workers, >= 1.
    least : int
        Fewest rays per chunk but in the last round (whose chunks are < 2 ``least``), >= 1.

    Returns
    -------
    list of tuple of int
        (lo, hi) per chunk: consecutive, covering range(n).
    """
    spans, lo = [], 0
    while lo < n:
        left = n - lo
        size = min(-(-left // (2 * cores)), chunk)
        if size < least and -(-left // cores) <= chunk:  # the last round: what is left, split evenly
            k = min(cores, left)
            ends = lo + np.cumsum([left // k + (q < left % k) for q in range(k)])  # the bigger chunks first
            return spans + [(int(a), int(b)) for a, b in zip([lo, *ends[:-1]], ends)]
        for _ in range(cores):
            if lo < n:
                spans.append((lo, min(lo + size, n)))
                lo = spans[-1][1]
    return spans


def trace_rays(origins, directions, consts, geometry: GridGeometry, ray_phase, settings: MarchSettings = MarchSettings(),
               progress=None):
    """March rays and return per-ray radiance components (numpy arrays).

    Parameters
    ----------
    origins, directions : numpy.ndarray
        Shape (n, 3): scene-frame origins [m] and unit directions.
    consts : dict
        From :func:`kernel_constants`.
    geometry : GridGeometry
    ray_phase : dict or callable
        Per-ray arrays (n,): ``cos_theta`` (cosine of the scattering angle), ``cos_view_zenith`` (view
        direction dotted with the local up at the reference point), ``p_rayleigh`` (phase function,
        mean 1 over the sphere); ``p_aerosol`` and ``p_stratospheric`` (n, 3), the phase functions of the
        background and the stratospheric aerosol per wavelength. Or a function that returns that dict for a
        (m, 3) block of ``directions``, called block by block (:data:`SEGMENT_BLOCK` rays) so that a big image
        never holds them all.
    settings : MarchSettings
    progress : callable, optional
        Called with (rays done, rays total) after each chunk.

    Returns
    -------
    dict of numpy.ndarray
        ``radiance`` (n, 3) [-] solar-relative L' (Eq. 2) at 615/546/450 nm and its components
        ``radiance_clear``, ``radiance_cloud``, ``radiance_surface``; ``tau_hydrometeor`` (n,);
        ``tau_clear`` (n, 3); ``surface`` (n,) bool; ``distance`` (n,) [m] to the ground or NaN; ``steps`` (n,)
        the volume samples each ray took: as marched by the per-ray kernel ("numba": refined halves
        included, none after the ground, :func:`swim.rt.march_cpu.march_rays`), the lockstep count
        ``n_before + n_grid + n_after + 1`` for the JAX kernel, whose rays all take every step of their chunk.

    Raises
    ------
    SwimInputError
        If there are no rays, if ``origins`` or ``directions`` are not finite (n, 3) arrays, or if
        ``settings.execution.backend`` is "numba" and numba is not installed.
    """
    # the numba kernel reads its tables unchecked: a NaN ray must not get that far
    check_rays("trace_rays", origins, directions)
    seg = ray_segments_parallel(origins, directions, geometry, top=float(consts["top"]))
    # Segments of zero length for every ray need no steps (e.g. observers inside the grid).
    bounds = seg["bounds"]
    settings = without_empty_segments(settings.kernel_settings(), [np.any(length > 0) for length in (
        bounds[:, 0], bounds[:, 1] - bounds[:, 0], bounds[:, 2] - bounds[:, 1])])
    n = len(origins)
    chunk = batch = settings.resolved_chunk()
    steps = settings.n_before + settings.n_grid + settings.n_after + 1  # the end step (_march_rays)
    backend = settings.resolved_backend()
    if backend == "numba":
        # chunks that shrink towards the batch's end, so that all cores finish together (chunk_spans)
        cores = threads()
        spans = chunk_spans(n, chunk, cores)
        tables = {**_numba_tables(consts), "local_vertical": grid_tilt_deg(geometry) > PER_COLUMN_SUN_TILT_DEG}
    else:
        spans = [(lo, min(lo + chunk, n)) for lo in range(0, n, chunk)]
        from . import march_jax  # JAX is imported only for its kernel

        jax_chunk = march_jax.chunk_marcher(consts, settings)
    outputs = {}  # written chunk by chunk into arrays for all rays (a list and a concatenate would hold two)
    # [first ray, end, phase arrays of those rays]: all rays for a dict, blocks of SEGMENT_BLOCK for a function
    # (one call per chunk would pay the phase functions' calls ~200 times for a 1024^2 image)
    phase_block = [] if callable(ray_phase) else [0, n, ray_phase]
    pool, pending = None, collections.deque()  # (collect the outputs, end of the chunk, cancel it or None)
    held = []  # the first chunks' jobs, one per worker, submitted together (below)
    if backend == "numba":
        # chunks marched at once, one per core (the numba kernel runs without the GIL)
        workers = min(cores, len(spans))
        pool = worker_pool(workers) if workers > 1 else None
    # the JAX kernel's chunks are marched one after the other, on one worker thread when there are several chunks
    jax_pool = worker_pool(1) if backend == "jax" and n > chunk and not in_worker_thread() else None

    def finished(out, hi):
        for key, value in out.items():
            if key not in outputs:
                outputs[key] = np.empty((n,) + value.shape[1:], value.dtype)
            outputs[key][hi - len(value):hi] = value
        if progress is not None:
            progress(hi, n)

    try:
        for lo, hi in spans:
            pad = padded_batch_size(hi - lo, batch) - (hi - lo)

            def take(a, dtype=np.float32, first=0):
                return _pad_rows(np.asarray(a[lo - first:hi - first]), pad).astype(dtype)

            if not phase_block or hi > phase_block[1]:
                block_hi = min(n, lo + max(SEGMENT_BLOCK, hi - lo))
                phase_block[:] = [lo, block_hi, ray_phase(np.asarray(directions[lo:block_hi]))]
            rays = {key: take(value, first=phase_block[0]) for key, value in phase_block[2].items()}
            args = [take(seg["start"]), take(directions), take(seg["bounds"]), take(seg["ends_on_ground"], bool),
                    take(seg["valid"], bool)]
            if backend == "jax":
                job = jax_chunk(args, rays, hi - lo)
                if jax_pool is None:
                    finished(job(), hi)
                    continue
                # On a GPU the call returns only when the march is done (XLA reads its while loop's condition on
                # the host every step): a worker thread waits for it while this one prepares the next chunk
                # (docs/decisions/0006-gpu-kernels.md); the one before is collected now (two chunks at most are held)
                future = jax_pool.submit(job)
                pending.append((future.result, hi, future.cancel))
                if len(pending) > 1:
                    collect, done_hi, _ = pending.popleft()
                    finished(collect(), done_hi)
                continue
            job = functools.partial(_trace_chunk_numba, *args, rays, settings, tables,
                                    [take(a, float) for a in (seg["start"], directions, seg["bounds"])], hi - lo)
            if pool is None:
                finished(job(), hi)
                continue
            held.append((job, hi))
            if not pending and len(held) < workers and hi < n:
                # the first round's jobs are made before any is submitted: a worker's Python calls (the kernels'
                # dispatch) do not compete for the GIL with the making of the next job, and the chunks of a small
                # image start together (the second chunk of the Monte Carlo case's 41^2 view started ~0.8 ms after
                # the first; the view -0.1 ms in median, docs/decisions/0005-adaptive-sampling.md)
                continue
            for ready, ready_hi in held:
                future = pool.submit(ready)
                pending.append((future.result, ready_hi, future.cancel))
            held.clear()
            if len(pending) >= 2 * workers:  # bound the chunks held in memory; collect in order
                collect, done_hi, _ = pending.popleft()
                finished(collect(), done_hi)
        while pending:
            collect, hi, _ = pending.popleft()
            finished(collect(), hi)
    finally:  # after an error (or an interrupt): the chunks not yet started are dropped
        for _, _, cancel in pending:
            if cancel is not None:
                cancel()
    if "steps" not in outputs:  # the lockstep kernel: every ray of a chunk takes every step
        outputs["steps"] = np.full(n, steps, np.int32)
    return outputs


def _pad_rows(a, pad):
    """``a`` with its last row repeated ``pad`` times: a batch filled up to a size the kernels are compiled for."""
    return np.concatenate([a, np.repeat(a[-1:], pad, axis=0)], axis=0) if pad else a


def _numba_tables(consts, prepare=True):
    """The kernel constants as the numpy arrays and packed scalars of :func:`swim.rt.march_cpu.march_rays` (read-only
    views, so the volume is not copied), and with ``prepare`` those of :func:`swim.rt.march_cpu.prepare_rays`."""
    from . import march_cpu

    p, coef = march_cpu.pack_parameters(consts)

    def arr(a):
        a = np.asarray(a).view()  # a view: marking it read-only leaves the caller's array as it was
        a.flags.writeable = False  # like JAX's host views, so that every render calls the same compiled kernel
        return a

    tables = {"p": p, "coef": coef, "beta_gas": arr(consts["beta_gas"]), "spectra": arr(consts["beta_gas_spectra"]),
              "sky": arr(consts["sky"]), "sky_lanes": _sky_lanes(consts["sky"]),
              "diffuse_classes": arr(consts["diffuse_classes"]),
              "n_class": int(consts["class_aod"].shape[0]), "volume": arr(consts["volume"]),
              "terrain": arr(consts["terrain"]), "occupancy": arr(consts["occupancy"]),
              "angstrom": arr(consts["angstrom"]), "aerosol_ssa": arr(consts["aerosol_ssa"]),
              "stratospheric_ssa": arr(consts["stratospheric_ssa"]), "species_matrix": arr(consts["species_matrix"]),
              "surface": arr(consts["surface"]), "surface_outside": arr(consts["surface_outside"]),
              "backscatter": arr(consts["backscatter"])}
    # each packed species' index into SPECIES, for the numba composition
    tables["species_index"] = np.argmax(tables["species_matrix"], axis=1).astype(np.int64)
    # the 3-D cloud scattering's tables (swim.rt.clouds.cloud_constants), or placeholders the kernel does not read
    tables["cloud_mode"] = "ms_field" in consts
    if tables["cloud_mode"]:
        tables.update({key: consts[key] for key in CLOUD_KERNEL_KEYS}, ms_coarsen=float(consts["ms_coarsen"]))
    else:
        tables.update(hydro_scale=arr(np.zeros(1)), hydro_narrow=arr(np.zeros(1)),
                      ms_field=arr(np.zeros((1, 1, 1, 4), np.float32)),
                      ms_above=arr(np.ones((2, 1, 1, 3), np.float32)), above_heights=arr(np.array([0.0, 1.0])),
                      ms_coarsen=1.0)
    if prepare:  # the source table with each corner's (n_u, 9) profiles as one row
        source = consts["ms_source"]
        tables.update(ms_source=arr(np.asarray(source).reshape(source.shape[:4] + (-1,))), n_u=int(source.shape[4]),
                      aerosol_column=arr(consts["aerosol_column"]), class_aod=arr(consts["class_aod"]))
    return tables


#: The last sky table's :func:`swim.rt.march_cpu.sky_lanes` (:func:`_sky_lanes`).
_SKY_LANES = {}


def _sky_lanes(sky):
    """:func:`swim.rt.march_cpu.sky_lanes` of the sky table ``sky`` (6, nu, nmu), read-only, made once per table
    and kept while the table lives: a render calls the kernels ~3 times (adaptive sampling's batches), a time series
    or the Monte Carlo case's repeated view many more, and the copy (3 MB for 96 x 512 entries) took ~1 ms. Kept by
    the table itself, a JAX array, not by :func:`device_copies`, which identifies the owner of a numpy array's memory:
    each host view of a JAX array has a new one."""
    from . import march_cpu

    entry = _SKY_LANES.get("entry")
    if entry is None or entry[0]() is not sky:
        _SKY_LANES.clear()
        lanes = march_cpu.sky_lanes(sky)
        lanes.flags.writeable = False
        _SKY_LANES["entry"] = entry = (weakref.ref(sky), lanes)
    return entry[1]


def _trace_chunk_numba(start, direction, bounds, ends_on_ground, valid, rays, settings, tables, exact, n):
    """One chunk of rays through the numba kernel: the per-ray set-up (:func:`swim.rt.march_cpu.prepare_rays`), the
    step loop (:func:`swim.rt.march_cpu.march_rays`; ``exact``: start, direction and bounds in float64) and the
    composition (:func:`_compose_numba`). Returns numpy arrays of the first ``n`` (real) rays: no JAX call, no GIL
    held in the kernels (docs/decisions/0009-work-around-the-march.md)."""
    from . import ground_cpu, march_cpu, precompile

    # a helper process compiling the march on a cold cache: its result loaded, not redone; the ground's tables built
    # while it compiles
    precompile.wait(meanwhile=(ground_cpu.ground_tables,))
    # The batch is padded (repeats of its last ray) to a size the kernels are compiled for; numba marches only the
    # real rays, and the padding rows of the state repeat the last one as the inputs do.
    padded = start.shape[0]
    class_lower, class_weight = np.empty(padded, np.int32), np.empty(padded)
    ms = np.empty((9, n, tables["n_u"]) if settings.multiple_scattering else (9, 1, 2), np.float32)
    march_cpu.prepare_rays(*(a[:n] for a in exact), tables["p"], tables["coef"], tables["aerosol_column"],
                           tables["class_aod"], tables["ms_source"], settings.multiple_scattering,
                           class_lower[:n], class_weight[:n], ms)
    # with settings.multiple_scattering off, ms is a (9, 1, 2) placeholder that the march never reads
    # in the order of march_rays' outputs (its last arguments but the sample counts, which go to the caller alone)
    state = {"tau_clear": np.empty((padded, 3)), "tau_h": np.empty(padded),
             "tau_species": np.empty((padded, tables["species_matrix"].shape[0])), "l_clear": np.empty((padded, 3)),
             "i_nogas": np.empty((padded, 3)), "i_gas": np.empty((padded, 3)), "i_cloud_t": np.empty(padded),
             "alive": np.empty(padded, bool), "hit": np.empty(padded, bool), "s_hit": np.empty(padded)}
    # Per-chunk arrays are fresh (writable) copies and the tables read-only views of the kernel constants, in
    # every call: numba compiles (and caches on disk) one version of the kernel per combination of types.
    phase = {key: rays[key][:n].astype(float) for key in ("p_rayleigh", "p_aerosol", "p_stratospheric")}
    if tables["cloud_mode"]:  # float32 as built (swim.rt.clouds.cloud_ray_inputs); the kernel sums in float64
        p_hydro = np.ascontiguousarray(rays["p_hydro"][:n], np.float32)
        ray_ms = np.ascontiguousarray(rays["ray_ms"][:n], np.float32)
    else:
        p_hydro, ray_ms = np.zeros((1, 1, 6), np.float32), np.zeros((1, 1, 3), np.float32)
    state["l_cloud"] = np.zeros((padded, 3))
    samples = np.empty(n, np.int64)
    # the aerosol column class and its weight (rounded to float32, as the JAX set-up gives it), for the march and the
    # ground
    ray_class = (class_lower[:n], class_weight[:n].astype(np.float32).astype(float))
    t, out = tables, [state[key][:n] for key in state if key != "l_cloud"] + [samples]
    march_cpu.march_rays(
        *(a[:n] for a in exact), np.array(valid[:n]), phase["p_rayleigh"], phase["p_aerosol"], phase["p_stratospheric"],
        *ray_class, ms, settings.multiple_scattering,
        settings.n_before, settings.n_grid, settings.n_after, t["p"], t["coef"], t["beta_gas"], t["spectra"],
        t["sky_lanes"], t["diffuse_classes"], t["n_class"], t["volume"], t["terrain"], t["occupancy"], t["angstrom"],
        t["aerosol_ssa"], t["stratospheric_ssa"], settings.n_probe, EMPTY_STEP_WEIGHT, float(settings.probe_spacing),
        MAX_PROBES, CELL_SLACK, settings.resolved_empty_steps(), EMPTY_CELLS_PER_STEP, settings.sunlit_steps,
        SUNLIT_CELLS_PER_STEP, CLEAR_PROBES, CLEAR_STEP_POWER,
        CLEAR_STEP_FLOOR, float(settings.tau_refine), REFINE_DEPTH, REFINE_BUDGET, REFINE_VISIBLE_TAU, REFINE_SLOTS,
        TERRAIN_BISECTIONS, float(settings.stop_tau), *out, bool(t["cloud_mode"]), p_hydro, ray_ms, t["hydro_scale"],
        t["hydro_narrow"], t["ms_field"], t["ms_coarsen"], t["ms_above"], t["above_heights"], state["l_cloud"][:n])
    # the clouds and the ground composed in numba too (docs/decisions/0009-work-around-the-march.md)
    return {**_compose_numba(exact, ends_on_ground, valid, rays, settings, tables, state, ray_class, n),
            "steps": samples.astype(np.int32)}


def _compose_numba(exact, ends_on_ground, valid, rays, settings, tables, state, ray_class, n):
    """The outputs of :func:`_compose` for the first ``n`` rays of a chunk marched by the numba kernel: the ground's
    term (Eq. 35) in :func:`swim.rt.ground_cpu.ground_radiance` for chunks that have rays on the ground, the clouds'
    part and the sum in :func:`swim.rt.compose_cpu.compose_clouds` (no JAX call, no GIL). ``exact`` holds the rays'
    float64 start, direction and bounds as the march took them, ``ray_class`` the real rays' aerosol column class and
    float64 weight as the march took them, ``state`` the kernel's float64 outputs (its packed species, padding rows not
    yet written); numpy arrays."""
    from . import compose_cpu

    st = {key: value[:n] for key, value in state.items()}  # the real rays' float64 rows (views)
    surface = _ends_on_surface(st, ends_on_ground[:n])
    # the view's and the sun's zenith cosines: at the reference point, or on a grid whose columns take their own sun
    # at each ray's local vertical (docs/decisions/0020-per-column-sun.md)
    view_sun = (rays["cos_view_zenith"][:n], tables["p"][compose_cpu.P_MU0])
    if tables.get("local_vertical", False):
        view_sun = compose_cpu.local_view_geometry(exact[0][:n], exact[1][:n], tables["p"][compose_cpu.P_RADIUS],
                                                   tables["p"][compose_cpu.P_SUN:compose_cpu.P_SUN + 3])
    l_surface = np.zeros((n, 3), np.float32)
    if np.any(surface):
        from . import ground_cpu

        g = ground_cpu.ground_tables()
        cloud_mode = bool(tables["cloud_mode"])
        ground_cpu.ground_radiance(
            exact[0][:n], exact[1][:n], st["s_hit"], surface, view_sun[0], st["tau_h"],
            st["tau_clear"], st["tau_species"], tables["species_index"], *ray_class, tables["p"], tables["coef"],
            tables["sky"],
            tables["diffuse_classes"], tables["n_class"], tables["surface"], tables["surface_outside"],
            tables["angstrom"], tables["backscatter_scaled"] if cloud_mode else tables["backscatter"],
            settings.surface == "lambertian", compose_cpu.COEFFICIENTS,
            g["coefficients"], g["rpv_q"], g["snow_table"], g["snow_albedo"], g["subsurface"], g["fade_cells"],
            cloud_mode, l_surface)
    if tables["cloud_mode"]:  # the hydrometeors' radiance was integrated along the ray (swim.rt.clouds)
        l_cloud = st["l_cloud"].astype(np.float32)
        radiance = (st["l_clear"] + st["l_cloud"] + l_surface).astype(np.float32)
        radiance[~np.asarray(valid[:n], bool)] = 0.0
        # the optical depth that dims the beam but for the forward peak's narrow part (the circumsolar aureole)
        tau_narrow = st["tau_species"] @ np.asarray(tables["hydro_aureole"], float)
        return {"radiance": radiance, "radiance_clear": st["l_clear"].astype(np.float32), "radiance_cloud": l_cloud,
                "radiance_surface": l_surface, "tau_hydrometeor": st["tau_h"].astype(np.float32),
                "tau_clear": st["tau_clear"].astype(np.float32), "surface": surface,
                "distance": np.where(surface, st["s_hit"], np.nan).astype(np.float32),
                "tau_narrow": tau_narrow.astype(np.float32)}
    radiance, l_cloud = np.empty((n, 3), np.float32), np.empty((n, 3), np.float32)
    compose_cpu.compose_clouds(st["tau_h"], st["tau_species"], tables["species_index"], st["i_nogas"], st["i_gas"],
                               st["i_cloud_t"], st["l_clear"], l_surface, np.array(valid[:n]), rays["cos_theta"][:n],
                               *view_sun, compose_cpu.G_LIQUID_ARRAY,
                               compose_cpu.BACKSCATTER_ARRAY, compose_cpu.COEFFICIENTS, compose_cpu.LOBES, radiance,
                               l_cloud)
    return {"radiance": radiance, "radiance_clear": st["l_clear"].astype(np.float32), "radiance_cloud": l_cloud,
            "radiance_surface": l_surface, "tau_hydrometeor": st["tau_h"].astype(np.float32),
            "tau_clear": st["tau_clear"].astype(np.float32), "surface": surface,
            "distance": np.where(surface, st["s_hit"], np.nan).astype(np.float32)}
