"""A camera's rays kept on the device for the JAX kernel (:attr:`swim.rt.march_settings.MarchSettings.ray_table`).

A GPU frame of the JAX kernel did most of its work on the host (docs/decisions/0006-gpu-kernels.md): for every
batch of rays the host clipped the rays to the grid (:func:`swim.rt.march.ray_segments_compiled`), evaluated the
phase functions on the device and copied them back, padded and converted ten per-ray arrays chunk by chunk and sent
them to the device again. For a camera that does not move, none of that changes between frames except the phase
functions, which follow the sun. A :class:`RayTable` holds, on the device, what every pixel's ray needs that the sun
does not change: its start, direction, segments (before, in and after the grid), whether it ends on the sea-level
sphere and the occupancy probes of its grid segment (:func:`swim.rt.march_jax.probe_counts_and_cells`). A batch of
pixels (every pixel, or a level of adaptive sampling) then sends only its rows' indices: the rows are gathered and
the phase functions computed in one compiled call on the device (:func:`_gather_rows`), and the chunks are marched by
the same compiled program as :func:`swim.rt.march.trace_rays` marches them (:func:`swim.rt.march_jax._trace_chunk`),
queued one after the other without waiting for the host in between.

The phase functions' scattering-angle cosine is computed on the device in float32 (:func:`scattering_cosine`, as
accurate near the sun as the host's float64 value rounded once), so the radiance differs from the host's by a few
1e-6 relative, and within a few degrees of the sun, under thin cloud's forward peak, by up to ~0.2 % where the two
round the cosine to neighbouring float32 values. Everything else is what :func:`swim.rt.march.trace_rays` computes for
the same rays (``tests/unit/rt/test_rt_ray_table.py``).

On an H100 a warm 1024² all-sky with every pixel traced renders in 0.151 s with the table against 0.324 s without
(docs/decisions/0006-gpu-kernels.md), so ``MarchSettings.ray_table`` is on by default where the JAX kernel runs on a GPU
(:meth:`swim.rt.march_settings.MarchSettings.resolved_ray_table`).
"""

from __future__ import annotations

import collections
import logging
import weakref
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import SwimInputError
from . import march_jax
from .march import check_rays, padded_batch_size, ray_segments_parallel, without_empty_segments
from .march_inputs import GridGeometry
from .march_jax import _device_constants, _host_rows, with_probes_for
from .march_settings import MarchSettings
from .march_pallas import with_vector_volume
from ..compilation.jax_export import exported_jit
from .gas import phase_functions

log = logging.getLogger(__name__)

#: Rays per block in which a table's probes are computed on the device (bounds the probes' temporaries).
TABLE_BLOCK = 1 << 18
#: Chunks whose outputs may wait on the device before the oldest is copied to the host.
PENDING_CHUNKS = 3


@dataclass(frozen=True)
class PhaseInputs:
    """What the rays' phase functions depend on besides their directions (:func:`swim.pipeline.render`'s
    ``ray_phase``): the sun's unit direction in the scene frame (3,), the air's depolarization factor [-] and the
    background and stratospheric aerosol types (:class:`swim.optics.aerosol_types.AerosolType`)."""

    sun_scene: tuple
    depolarization: float
    aerosol_type: object
    stratospheric_type: object


@dataclass(eq=False)
class RayTable:
    """A camera's rays on the device (see the module docstring); build with :func:`build_ray_table`.

    Attributes
    ----------
    start, direction, bounds : jax.Array
        Shape (n, 3) float32: the rays' rebased starts [m], unit directions and distances [m] to the grid's entry,
        its exit and the ray's end (:func:`swim.rt.march.ray_segments`).
    ends_on_ground, valid : jax.Array
        Shape (n,) bool.
    probes, cells : jax.Array or None
        Shape (n,): each ray's occupancy probes (int32) and its grid segment's length in cells (float32),
        :func:`swim.rt.march_jax.probe_counts_and_cells` (None where ``settings.probe_spacing`` or ``n_grid`` is 0).
    probes_host : numpy.ndarray or None
        The probes (n,) int32 on the host, for each chunk's ``n_probe`` without a copy from the device.
    segments_host : numpy.ndarray
        Shape (n,) uint8: which of each ray's segments before, in and after the grid have a length (bits 0, 1, 2), one
        byte a ray so that a batch's rows are gathered and or-ed cheaply.
    key : tuple
        What the table was built for (:func:`camera_ray_table`'s cache).
    """

    start: jax.Array
    direction: jax.Array
    bounds: jax.Array
    ends_on_ground: jax.Array
    valid: jax.Array
    probes: jax.Array | None
    cells: jax.Array | None
    probes_host: np.ndarray | None
    segments_host: np.ndarray
    key: tuple = ()

    @property
    def size(self) -> int:
        """Rays in the table."""
        return int(self.segments_host.shape[0])


def _probe_key(settings: MarchSettings):
    """The settings that a table's probes depend on."""
    return (settings.n_probe, float(settings.probe_spacing), settings.n_grid)


def build_ray_table(origins, directions, geometry: GridGeometry, consts, settings: MarchSettings, key=()) -> RayTable:
    """The rays ``origins``, ``directions`` as a :class:`RayTable` on JAX's default device.

    Parameters
    ----------
    origins, directions : array_like
        Shape (n, 3) or broadcastable to it: scene-frame origins [m] and unit directions, finite.
    geometry : GridGeometry
    consts : dict
        Kernel constants (:func:`swim.rt.march_inputs.kernel_constants`): ``top`` [m] and the grid's index map.
    settings : MarchSettings
        ``n_probe``, ``probe_spacing`` and ``n_grid`` set the probes.
    key : tuple
        Stored as the table's ``key``.

    Returns
    -------
    RayTable

    Raises
    ------
    SwimInputError
        If there are no rays or they are not finite (n, 3) arrays.
    """
    directions = np.asarray(directions, dtype=float)
    origins = np.broadcast_to(np.asarray(origins, dtype=float), directions.shape)
    check_rays("build_ray_table", origins, directions)
    seg = ray_segments_parallel(origins, directions, geometry, top=float(consts["top"]))
    bounds = seg["bounds"]
    lengths = ((bounds[:, 0] > 0).astype(np.uint8) | ((bounds[:, 1] - bounds[:, 0] > 0).astype(np.uint8) << 1)
               | ((bounds[:, 2] - bounds[:, 1] > 0).astype(np.uint8) << 2))
    start = jnp.asarray(seg["start"].astype(np.float32))
    direction = jnp.asarray(directions.astype(np.float32))
    bounds_d = jnp.asarray(bounds.astype(np.float32))
    probes = cells = probes_host = None
    if settings.probe_spacing and settings.n_grid:
        device = _device_constants(consts)
        n = len(directions)
        parts = []
        for lo in range(0, n, TABLE_BLOCK):
            # each block padded to a size of padded_batch_size (its last row repeated): a few compiled shapes serve
            # every camera
            hi = min(lo + TABLE_BLOCK, n)
            take = np.minimum(np.arange(lo, lo + padded_batch_size(hi - lo, TABLE_BLOCK)), hi - 1)
            # the chunks' program (exported: a new process does not trace it)
            p, c = march_jax._probe_counts_chunk(start[take], direction[take], bounds_d[take], device, settings.n_probe,
                                             float(settings.probe_spacing))
            parts.append((p[:hi - lo], c[:hi - lo]))
        probes = jnp.concatenate([p for p, _ in parts])
        cells = jnp.concatenate([c for _, c in parts])
        probes_host = np.asarray(probes)
    return RayTable(start, direction, bounds_d, jnp.asarray(seg["ends_on_ground"]), jnp.asarray(seg["valid"]),
                    probes, cells, probes_host, lengths, key)


#: The last table of :func:`camera_ray_table`: (weak references to the directions and the pixels, table, rows).
_LAST_TABLE = {}


def camera_ray_table(observer, directions, pixels, geometry: GridGeometry, consts, settings: MarchSettings):
    """The :class:`RayTable` of a camera's pixels ``pixels`` seen from ``observer``, and each pixel's row in it;
    the last one is kept and reused while the same arrays ``directions`` and ``pixels`` (a camera's cached ones,
    :func:`swim.pipeline.scene_stage.scene_directions`, which are read-only), observer, grid geometry, atmosphere top and probe
    settings come again. Arrays are recognised by identity, not by their values (hashing a 1024^2 camera's would take
    milliseconds every frame): pass arrays that are not changed in place.

    Parameters
    ----------
    observer : array_like
        Shape (3,) [m], scene frame.
    directions : numpy.ndarray
        Shape (m, 3): the unit directions of the camera's pixels (flat image order), scene frame.
    pixels : numpy.ndarray
        Shape (n,) int: the flat indices of the pixels to put in the table, in the table's order.
    geometry : GridGeometry
    consts : dict
        Kernel constants (:func:`swim.rt.march_inputs.kernel_constants`).
    settings : MarchSettings

    Returns
    -------
    tuple
        (:class:`RayTable` of n rays, ``rows`` (m,) int64, read-only: each pixel's row in the table, -1 where it has
        none).
    """
    observer = np.asarray(observer, dtype=float)
    key = (observer.tobytes(), _geometry_key(geometry), float(consts["top"]), _probe_key(settings),
           jax.default_backend())
    entry = _LAST_TABLE.get("entry")
    if entry is not None and entry[0]() is directions and entry[1]() is pixels and entry[2].key == key:
        return entry[2], entry[3]
    _LAST_TABLE.clear()  # the old table's device arrays go before the new ones are made
    index = np.asarray(pixels)
    table = build_ray_table(observer, np.asarray(directions)[index], geometry, consts, settings, key=key)
    rows = np.full(len(directions), -1, np.int64)
    rows[index] = np.arange(len(index))
    rows.flags.writeable = False
    try:
        _LAST_TABLE["entry"] = (weakref.ref(directions), weakref.ref(pixels), table, rows)
    except TypeError:  # no weak reference to them (not numpy arrays): not kept
        pass
    return table, rows


#: The last table of :func:`single_ray_table`: (key, table).
_LAST_RAY = {}


def single_ray_table(origin, direction, geometry: GridGeometry, consts, settings: MarchSettings) -> RayTable:
    """A one-row :class:`RayTable` of the ray from ``origin`` (3,) [m] along the unit ``direction`` (3,) (the sun's
    ray of a render, for its disk: :func:`trace_table_rows`'s ``extra``); the last one is kept, so that a frame with
    the same sun, observer, grid and settings does not build it again (~15 ms of a warm 1024^2 frame's host work on
    this project's CPU: ``benchmarks/bench_host.py``)."""
    origin, direction = np.asarray(origin, dtype=float), np.asarray(direction, dtype=float)
    key = (origin.tobytes(), direction.tobytes(), _geometry_key(geometry), float(consts["top"]), _probe_key(settings),
           jax.default_backend())
    entry = _LAST_RAY.get("entry")
    if entry is not None and entry[0] == key:
        return entry[1]
    table = build_ray_table(origin, direction[None], geometry, consts, settings, key=key)
    _LAST_RAY["entry"] = (key, table)
    return table


def forget_ray_tables():
    """Drop the kept tables (:func:`camera_ray_table`, :func:`single_ray_table`) and their device memory."""
    _LAST_TABLE.clear()
    _LAST_RAY.clear()


def _geometry_key(geometry: GridGeometry):
    return (np.asarray(geometry.origin, float).tobytes(), np.asarray(geometry.matrix, float).tobytes(),
            float(geometry.z_bottom), float(geometry.dz), tuple(geometry.shape), float(geometry.top),
            float(geometry.affine_residual_cells))


@exported_jit(static_argnames=("aerosol_type", "stratospheric_type"))  # a new process reads the traced program
def _gather_rows(table_arrays, extra_arrays, rows, n_real, sun, depolarization, aerosol_type, stratospheric_type):
    """A chunk's per-ray inputs of :func:`swim.rt.march_jax._trace_chunk` from the table's rows ``rows`` (n,) (rows past
    the table's end: the rows of ``extra_arrays``, a second table's), with the phase functions of
    :func:`swim.rt.kernel_tables.ray_phase_functions` at their scattering angles (the sun ``sun`` (3,)). The rays from position
    ``n_real`` (an int32 scalar: a traced value, so one program serves every count) on are padding: not valid."""
    size = table_arrays[0].shape[0]

    def take(a, e):
        if a is None:
            return None
        taken = jnp.take(a, jnp.minimum(rows, size - 1), axis=0)
        if e is None:
            return taken
        other = jnp.take(e, jnp.clip(rows - size, 0, e.shape[0] - 1), axis=0)
        return jnp.where((rows >= size).reshape((-1,) + (1,) * (a.ndim - 1)), other, taken)

    extra_arrays = (None,) * len(table_arrays) if extra_arrays is None else extra_arrays
    start, direction, bounds, ends_on_ground, valid, probes, cells = (
        take(a, e) for a, e in zip(table_arrays, extra_arrays))
    # padding marched as a ray outside the camera: it starts stopped, so the fused kernel's programs of padding end
    # at once (a copy of the last row's ray cost as much as that ray)
    valid = valid & (jnp.arange(rows.shape[0], dtype=jnp.int32) < n_real)
    cos_theta = scattering_cosine(direction, sun)
    p_rayleigh, p_aerosol, p_stratospheric = phase_functions(cos_theta, depolarization, aerosol_type,
                                                             stratospheric_type)
    rays = {"cos_theta": cos_theta, "cos_view_zenith": direction[:, 2], "p_rayleigh": p_rayleigh,
            "p_aerosol": p_aerosol, "p_stratospheric": p_stratospheric}
    return (start, direction, bounds, ends_on_ground, valid), rays, (probes, cells)


def scattering_cosine(direction, sun):
    """The cosine [-] (n,) float32 of the scattering angle between unit directions ``direction`` (n, 3) and ``sun``
    (3,), accurate near the sun.

    The phase functions of thin cloud peak within a degree of the sun (Eq. 13's ``g = 0.99^tau``: ``d ln p / d cos``
    ~ 3e4 there, ~0.2 % per unit in the last place of a float32 cosine near 1), so the cosine should be the float32
    rounding of its exact value, as the host's float64 dot product rounded once gives it. A float32 dot product of
    float32 directions is off by up to 2 units in the last place there, and differs from the host's rounding for 38 %
    of directions within 3 degrees of the sun; ``1 - |d - s|^2 / 2`` is off by at most 0.54 units and differs for 0.7
    % (the difference of two close vectors loses nothing, and their float32 norms do not enter). So the cosine is that
    below 60 degrees, and the dot product (whose error no phase function magnifies there) beyond. Written out, not a
    matrix product: XLA may take a float32 dot on a GPU's tensor cores at reduced precision."""
    d0, d1, d2 = direction[:, 0], direction[:, 1], direction[:, 2]
    half_chord = 0.5 * ((d0 - sun[0]) ** 2 + (d1 - sun[1]) ** 2 + (d2 - sun[2]) ** 2)
    dot = d0 * sun[0] + d1 * sun[1] + d2 * sun[2]
    return jnp.where(half_chord < 0.5, 1.0 - half_chord, dot)


def _arrays(table: RayTable):
    return (table.start, table.direction, table.bounds, table.ends_on_ground, table.valid, table.probes, table.cells)


def trace_table_rows(table: RayTable, rows, consts, phase: PhaseInputs, settings: MarchSettings = MarchSettings(),
                     progress=None, extra: RayTable | None = None, on_device: bool = False,
                     padding_from: int | None = None):
    """March the rays of a :class:`RayTable`'s rows with the JAX kernel; the outputs of
    :func:`swim.rt.march.trace_rays` for those rays.

    Parameters
    ----------
    table : RayTable
    rows : array_like or range
        Shape (m,) int: rows of the table, in the order of the outputs. A ``range`` of step 1 (a frame's whole table)
        is read as slices of the table's host arrays, without gathering them.
    consts : dict
        Kernel constants (:func:`swim.rt.march_inputs.kernel_constants`) of the render.
    phase : PhaseInputs
        The sun and the types whose phase functions the rays take.
    settings : MarchSettings
        As for :func:`swim.rt.march.trace_rays` (its ``backend`` must resolve to "jax"; its ``probe_spacing``,
        ``n_probe`` and ``n_grid`` those the tables were built with).
    progress : callable, optional
        Called with (rays done, rays total) after each chunk (with ``on_device``, as each chunk's march is done: the
        host then waits for it, a chunk behind the device's queue).
    extra : RayTable, optional
        Rays that are not the camera's (the sun's, for its disk), marched after ``rows`` (in the last chunk): their
        outputs follow those of ``rows``.
    on_device : bool
        Return the chunks' outputs as they are on the device (JAX arrays), their padding rows included (each chunk
        padded to :func:`swim.rt.march.padded_batch_size`), instead of the first m rows on the host: for
        :func:`swim.rt.image_sampling_device.sample_image_adaptive_device`, whose batches are already of such sizes.
        No copy to the host, and no slice whose shape would be compiled anew for every batch.
    padding_from : int, optional
        Rows from this position of ``rows`` on are the caller's padding (a batch filled up to a compiled size, as
        :func:`swim.rt.image_sampling_device.sample_image_adaptive_device` fills its batches): they are marched as
        rays outside the camera (not valid), as the chunks' own padding always is, so that the fused GPU kernel's
        programs of padding end at once; their outputs are those of such a ray (zero radiance), not their rows'. Not
        with ``extra``. None: every row is the caller's own.

    Returns
    -------
    dict of numpy.ndarray or of jax.Array
        As :func:`swim.rt.march.trace_rays`'s, each (m + extra rays, ...); with ``on_device``, (the padded rows, ...)
        on the device.

    Raises
    ------
    SwimInputError
        If there are no rows, a row is outside the table, ``settings`` does not resolve to the JAX kernel, or
        ``padding_from`` is given with ``extra`` or outside [1, len(rows)].
    """
    positions = _Positions(table, rows, extra)
    m = positions.m
    real = m if padding_from is None else int(padding_from)
    if padding_from is not None and (extra is not None or not 1 <= real <= m):
        raise SwimInputError(f"trace_table_rows: padding_from must be in [1, {m}] and not given with extra, "
                             f"got {padding_from!r}{' with extra' if extra is not None else ''}")
    if settings.resolved_backend() != "jax":
        raise SwimInputError(f"trace_table_rows marches with the JAX kernel; MarchSettings.backend="
                             f"{settings.execution.backend!r} resolves to {settings.resolved_backend()!r}")
    n = positions.n
    if extra is not None:
        real = n
    settings = _batch_settings(positions, settings)
    steps = settings.n_before + settings.n_grid + settings.n_after + 1
    outputs, kept = _march_chunks(positions, real, consts, phase, settings, progress, on_device)
    if on_device:
        outputs = {key: kept[0][key] if len(kept) == 1 else jnp.concatenate([out[key] for out in kept])
                   for key in kept[0]}
        outputs["steps"] = jnp.full(next(iter(outputs.values())).shape[0], steps, jnp.int32)
        return outputs
    outputs["steps"] = np.full(n, steps, np.int32)
    return outputs


class _Positions:
    """The rays of a batch by position: the table's ``rows``, then the ``extra`` rays' (rows past the table's end).

    The host's arrays are read in place, not joined (a 1024^2 frame's ~5 MB copied and gathered again every frame).

    Raises
    ------
    SwimInputError
        If there are no rows or a row is outside the table.
    """

    def __init__(self, table: RayTable, rows, extra: RayTable | None):
        if isinstance(rows, range) and rows.step == 1:  # consecutive rows: slices of the host's arrays, no gathers
            if len(rows) == 0 or rows.start < 0 or rows.stop > table.size:
                raise SwimInputError(f"trace_table_rows: rows must be a non-empty range in [0, {table.size}), "
                                     f"got {rows}")
        else:
            rows = np.asarray(rows)
            if rows.ndim != 1 or rows.size == 0 or not np.issubdtype(rows.dtype, np.integer):
                raise SwimInputError(f"trace_table_rows: rows must be a non-empty (m,) integer array, got shape "
                                     f"{rows.shape} of {rows.dtype}")
            if rows.min() < 0 or rows.max() >= table.size:
                raise SwimInputError(f"trace_table_rows: rows must be in [0, {table.size}), got "
                                     f"{rows.min()}..{rows.max()}")
        self.table, self.rows, self.extra = table, rows, extra
        self.m = len(rows)
        self.n = self.m + (0 if extra is None else extra.size)

    def own_rows(self, lo, hi):
        """The table's rows of positions lo..hi (< m): a slice for a range, else an array."""
        if isinstance(self.rows, range):
            return slice(self.rows.start + lo, self.rows.start + hi)
        return self.rows[lo:hi]

    def chunk_rows(self, lo, hi):
        """The rows of positions lo..hi: the table's, then the extra rays' (table.size on)."""
        m = self.m
        own = self.own_rows(lo, min(hi, m))
        own = np.arange(own.start, own.stop) if isinstance(own, slice) else own
        return own if hi <= m else np.concatenate([own, self.table.size + np.arange(max(lo, m) - m, hi - m)])

    def chunk_probes(self, lo, hi):
        """The largest probe count of positions lo..hi (the extra rays' where they have probes)."""
        m = self.m
        largest = int(self.table.probes_host[self.own_rows(lo, min(hi, m))].max()) if lo < m else 0
        if hi > m and self.extra.probes_host is not None:
            largest = max(largest, int(self.extra.probes_host[max(lo, m) - m:hi - m].max()))
        return largest


def _batch_settings(positions: _Positions, settings: MarchSettings) -> MarchSettings:
    """The kernel's settings for the batch: trace_rays's chunk program, without segments empty for every ray."""
    # the same program as trace_rays's chunks: the table's switch is not the kernel's
    settings = settings.kernel_settings()
    # segments of zero length for every ray of the batch need no steps (trace_rays)
    bits = int(np.bitwise_or.reduce(positions.table.segments_host[positions.own_rows(0, positions.m)]))
    if positions.extra is not None:
        bits |= int(np.bitwise_or.reduce(positions.extra.segments_host))
    return without_empty_segments(settings, [bits >> c & 1 for c in range(3)])


def _march_chunks(positions: _Positions, real, consts, phase: PhaseInputs, settings: MarchSettings, progress,
                  on_device):
    """March the batch chunk by chunk, queued on the device; (host outputs by key, each chunk's device outputs).

    Positions from ``real`` on are marched as padding (rays outside the camera). Without ``on_device`` the outputs
    are copied into the host's (n, ...) arrays as the chunks finish, at most :data:`PENDING_CHUNKS` behind.
    """
    table, extra, m, n = positions.table, positions.extra, positions.m, positions.n
    chunk = settings.resolved_chunk()
    device = with_vector_volume(_device_constants(consts), settings)
    table_arrays = _arrays(table)
    extra_arrays = None if extra is None else _arrays(extra)
    sun = jnp.asarray(np.asarray(phase.sun_scene, dtype=np.float32))
    depolarization = np.float32(phase.depolarization)
    with_probes = bool(settings.probe_spacing and settings.n_grid and table.probes is not None)
    outputs = {}
    pending = collections.deque()
    kept = []  # with on_device: each chunk's device outputs

    def collect():
        out, lo, hi = pending.popleft()
        if on_device:
            kept.append(out)
            if progress is not None:  # the chunks behind it stay queued on the device
                jax.block_until_ready(out)
                progress(hi, n)
            return
        for key, value in _host_rows(out, hi - lo).items():
            if key not in outputs:
                outputs[key] = np.empty((n,) + value.shape[1:], value.dtype)
            outputs[key][lo:hi] = value
        if progress is not None:
            progress(hi, n)

    for lo in range(0, n, chunk):
        hi = min(lo + chunk, n)
        part = positions.chunk_rows(lo, hi)
        pad = padded_batch_size(hi - lo, chunk) - (hi - lo)
        if pad:
            part = np.concatenate([part, np.repeat(part[-1:], pad)])
        # n_probe as swim.rt.march_jax._chunk_probes raises it, from the probes kept on the host
        chunk_settings = with_probes_for(settings, positions.chunk_probes(lo, hi)) if with_probes else settings
        chunk_extra = extra_arrays if hi > m else None
        n_real = np.int32(min(max(real - lo, 0), hi - lo))  # the chunk's own rays: the rest padding (not valid)
        args, rays, probes = _gather_rows(table_arrays, chunk_extra, jnp.asarray(part.astype(np.int32)), n_real, sun,
                                          depolarization, phase.aerosol_type, phase.stratospheric_type)
        # queued on the device behind the chunk before: no copy to the host in between
        # (looked up in its module each time: benchmarks/bench_gpu.py wraps it)
        pending.append((march_jax._trace_chunk(*args, rays, device, chunk_settings, probes if with_probes else None),
                        lo, hi))
        if len(pending) > PENDING_CHUNKS:
            collect()
    while pending:
        collect()
    return outputs, kept
