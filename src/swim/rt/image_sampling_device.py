"""Adaptive image sampling with the image on the device (JAX): the quadtree of
:func:`swim.rt.image_sampling.sample_image_adaptive` as whole-image array operations.

On a GPU the host's sampler is most of an adaptive frame (docs/decisions/0006-gpu-kernels.md: 68 % of a 1024^2 all-sky's
0.135 s on an H100): after each batch of rays the march's outputs come back to the host, are scattered into the
image's arrays, its cells are tested there and the next batch's pixels listed, and at the end the smooth cells are
interpolated, while the device waits. Here the image's arrays stay on the device. The cells of a level are not a list
but a dense grid: the first level's rows and columns are the lattice of every ``coarse_spacing``-th pixel, and each
next level's are the last one's with every interval of two or more pixels split at its middle (``(y0 + y1) // 2``,
as :func:`swim.rt.smooth_cpu.split_cells` splits a cell). A cell of a level exists where its parent split (or, on the
first level, everywhere) and it has a pixel between its corners. So a level's test, its split, the pixels it wants
traced and the final interpolation are a few gathers and comparisons over fixed shapes, compiled once per image size
(and kept on disk for new processes, :mod:`swim.compilation.jax_export`). Per batch only the wanted pixels' mask comes to
the host, which lists them for the march (the ray table keeps the rays' segment flags and probe counts there,
:func:`swim.rt.ray_table.trace_table_rows`); the march's outputs are scattered on the device.

The decisions are those of the host's sampler (Whitted 1980, doi:10.1145/358876.358882, with the tests of
:class:`swim.rt.image_sampling.AdaptiveSampling`): the same cells, the same tested pixels, the same tolerances, the
tests in float64 as the host's (JAX's 64-bit types on for them alone; a device may fuse a product and a sum, which
moves a prediction by ~1e-16 relative). The interpolation runs in the outputs' precision (float32), its weights
rounded to ~1 unit in the last place of the host's.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import SwimInputError
from ..compilation.jax_export import exported_jit
from .image_sampling import AdaptiveSampling, _lattice


@dataclass(frozen=True)
class Level:
    """One level of the dense quadtree: its cells' boundaries and their parents on the level before.

    Attributes
    ----------
    ys, xs : numpy.ndarray
        Shape (n_rows + 1,) and (n_cols + 1,) int: the rows and columns [pixels] between which the level's cells
        lie; cell (a, b) spans rows ``ys[a]``..``ys[a + 1]`` and columns ``xs[b]``..``xs[b + 1]``, corners included.
    parent_rows, parent_cols : numpy.ndarray or None
        Shape (n_rows,) and (n_cols,) int: the interval of the level before that each interval lies in (None on the
        first level).
    """

    ys: np.ndarray
    xs: np.ndarray
    parent_rows: np.ndarray | None
    parent_cols: np.ndarray | None


def _split_intervals(bounds):
    """Each interval of ``bounds`` of two or more pixels split at its middle (``(lo + hi) // 2``); intervals of one
    pixel kept (their "top" child has no height, :func:`swim.rt.smooth_cpu.split_cells`). Returns the new bounds and
    each new interval's parent."""
    new, parents = [int(bounds[0])], []
    for a, (lo, hi) in enumerate(zip(bounds[:-1], bounds[1:])):
        mid = (int(lo) + int(hi)) // 2
        if mid > lo:
            new.append(mid)
            parents.append(a)
        new.append(int(hi))
        parents.append(a)
    return np.asarray(new, np.int64), np.asarray(parents, np.int64)


@functools.lru_cache(maxsize=16)
def quadtree_levels(ny: int, nx: int, coarse_spacing: int) -> tuple[Level, ...]:
    """The levels of the dense quadtree of an (ny, nx) image, coarse to fine, down to the last one whose cells can
    have a pixel between their corners.

    Parameters
    ----------
    ny, nx : int
        Image size [pixels], each >= 3.
    coarse_spacing : int
        Pixels between the first lattice's rows and columns (:attr:`AdaptiveSampling.coarse_spacing`).

    Returns
    -------
    tuple of Level
    """
    ys, xs = _lattice(ny, coarse_spacing), _lattice(nx, coarse_spacing)
    levels = [Level(ys, xs, None, None)]
    while np.diff(levels[-1].ys).max() > 1 or np.diff(levels[-1].xs).max() > 1:
        last = levels[-1]
        ys, rows = _split_intervals(last.ys)
        xs, cols = _split_intervals(last.xs)
        levels.append(Level(ys, xs, rows, cols))
    return tuple(levels)


def _cell_geometry(level: Level, nx: int, edge_test_size: int):
    """Per cell of a level (n_rows, n_cols): the flat indices of its corners (4, ...), centre, edge midpoints
    (top, bottom, left, right: 4, ...), whether it tests its edges, whether it has a pixel between its corners, and
    the centre's bilinear weights (wy, wx) as :func:`swim.rt.smooth_cpu.cells_match` computes them."""
    # from the 1-D boundaries, broadcast in the compiled program: (n_rows, n_cols) arrays of indices as constants
    # would be compiled into it (megabytes for a 1024^2 image's finer levels)
    ys, xs = jnp.asarray(level.ys, jnp.int32), jnp.asarray(level.xs, jnp.int32)
    y0, y1 = ys[:-1, None], ys[1:, None]
    x0, x1 = xs[None, :-1], xs[None, 1:]
    shape = (len(level.ys) - 1, len(level.xs) - 1)
    y0, y1, x0, x1 = (jnp.broadcast_to(a, shape) for a in (y0, y1, x0, x1))
    yc, xc = (y0 + y1) // 2, (x0 + x1) // 2
    corners = (y0 * nx + x0, y0 * nx + x1, y1 * nx + x0, y1 * nx + x1)
    edges = (y0 * nx + xc, y1 * nx + xc, yc * nx + x0, yc * nx + x1)
    edged = (edge_test_size > 0) & (jnp.maximum(y1 - y0, x1 - x0) >= edge_test_size)
    inner = (y1 - y0 > 1) | (x1 - x0 > 1)
    wy = (yc - y0) / jnp.maximum(y1 - y0, 1)
    wx = (xc - x0) / jnp.maximum(x1 - x0, 1)
    return corners, yc * nx + xc, edges, edged, inner, wy, wx


def _matches(values, pixel, corners, weights, tolerance, floor):
    """Whether every channel of ``values`` (N, C) at ``pixel`` (...) lies within ``tolerance`` (relative to the larger
    of it and the prediction) plus ``floor`` of the weighted corners (4 weights, each broadcast to ``pixel``'s shape):
    :func:`swim.rt.smooth_cpu._matches`, summed corner by corner in its order; a NaN fails."""
    predicted = 0.0
    for corner, weight in zip(corners, weights):
        predicted = predicted + weight[..., None] * values[corner]
    actual = values[pixel]
    scale = jnp.maximum(jnp.abs(actual), jnp.abs(predicted))
    return jnp.all(jnp.abs(actual - predicted) <= tolerance * scale + floor, axis=-1)


@exported_jit(static_argnames=("nx", "edge_test_size", "level_index", "levels_key", "checks"))
def _test_level(exists, values, valid, traced, surface, *, nx, edge_test_size, level_index, levels_key, checks):
    """The smooth cells (n_rows, n_cols) of a level among those that ``exists``: :func:`swim.rt.image_sampling.
    _smooth_cells` on the dense grid. ``values`` holds the tested outputs in the order of ``checks`` ((tolerance,
    floor) each)."""
    level = quadtree_levels(*levels_key)[level_index]
    corners, centre, edges, edged, _, wy, wx = _cell_geometry(level, nx, edge_test_size)
    ok = exists & valid[centre] & traced[centre]
    for p in corners:
        ok &= valid[p] & traced[p] & (surface[p] == surface[centre])
    for p in edges:
        ok &= ~edged | (valid[p] & traced[p] & (surface[p] == surface[centre]))
    # in float64, as the host's test (called with 64-bit types on: sample_image_adaptive_device): a tested pixel
    # within a float32 rounding of its tolerance then decides as there
    wy, wx = jnp.asarray(wy, jnp.float64), jnp.asarray(wx, jnp.float64)
    zero = jnp.zeros_like(wy)
    top, bottom, left, right = edges
    for array, (tolerance, floor) in zip(values, checks):
        array = array.astype(jnp.float64)
        good = _matches(array, centre, corners, ((1 - wx) * (1 - wy), wx * (1 - wy), (1 - wx) * wy, wx * wy),
                        tolerance, floor)
        edge_good = (_matches(array, top, corners, (1 - wx, wx, zero, zero), tolerance, floor)
                     & _matches(array, bottom, corners, (zero, zero, 1 - wx, wx), tolerance, floor)
                     & _matches(array, left, corners, (1 - wy, zero, wy, zero), tolerance, floor)
                     & _matches(array, right, corners, (zero, 1 - wy, zero, wy), tolerance, floor))
        ok &= good & (~edged | edge_good)
    return ok


def _children_exist(split, level: Level, nx, edge_test_size):
    """Which cells of ``level`` exist: those whose parent (a cell of the level before) split and that have a pixel
    between their corners."""
    _, _, _, _, inner, _, _ = _cell_geometry(level, nx, edge_test_size)
    parents = split[jnp.asarray(level.parent_rows, jnp.int32)][:, jnp.asarray(level.parent_cols, jnp.int32)]
    return parents & inner


@exported_jit(static_argnames=("nx", "edge_test_size", "level_index", "levels_key"))
def _wanted_after_split(split, *, nx, edge_test_size, level_index, levels_key):
    """The next level's existing cells and the pixels (N,) bool that they and the split cells need: the split cells'
    edge midpoints (the children's corners) and the children's tested pixels (:func:`swim.rt.smooth_cpu.split_cells`).
    """
    levels = quadtree_levels(*levels_key)
    n = (levels[0].ys[-1] + 1) * nx
    _, _, edges, _, _, _, _ = _cell_geometry(levels[level_index], nx, edge_test_size)
    wanted = jnp.zeros(n, bool)
    for p in edges:
        wanted = wanted.at[jnp.where(split, p, n)].set(True, mode="drop")
    exists = _children_exist(split, levels[level_index + 1], nx, edge_test_size)
    return exists, _mark_tested(wanted, exists, levels[level_index + 1], nx, edge_test_size)


def _mark_tested(wanted, exists, level, nx, edge_test_size):
    """``wanted`` with the tested pixels of the existing cells of ``level`` set: their centres, and the edge midpoints
    of those that test edges (:func:`swim.rt.smooth_cpu.mark_tested`)."""
    n = wanted.shape[0]
    _, centre, edges, edged, _, _, _ = _cell_geometry(level, nx, edge_test_size)
    wanted = wanted.at[jnp.where(exists, centre, n)].set(True, mode="drop")
    for p in edges:
        wanted = wanted.at[jnp.where(exists & edged, p, n)].set(True, mode="drop")
    return wanted


@exported_jit(static_argnames=("nx", "edge_test_size", "levels_key"))
def _first_wanted(*, nx, edge_test_size, levels_key):
    """The first level's existing cells and its batch's pixels: the lattice and the cells' tested pixels."""
    level = quadtree_levels(*levels_key)[0]
    n = (level.ys[-1] + 1) * nx
    lattice = (jnp.asarray(level.ys, jnp.int32)[:, None] * nx + jnp.asarray(level.xs, jnp.int32)[None, :]).ravel()
    wanted = jnp.zeros(n, bool).at[lattice].set(True)
    _, _, _, _, exists, _, _ = _cell_geometry(level, nx, edge_test_size)
    return exists, _mark_tested(wanted, exists, level, nx, edge_test_size)


def _candidates(bounds, n):
    """Per pixel coordinate in range(n): the interval of ``bounds`` that starts at or before it (the last for the
    last bound) and the one that ends at it where it is a bound, else the same (the two cells that share an edge)."""
    q = np.arange(n)
    first = np.clip(np.searchsorted(bounds, q, side="right") - 1, 0, len(bounds) - 2)
    second = np.where((q == bounds[first]) & (first > 0), first - 1, first)
    return first, second


@exported_jit(static_argnames=("nx", "edge_test_size", "levels_key"))
def _fill(arrays, smooth_levels, traced, valid, *, nx, edge_test_size, levels_key):
    """Every array (N, C) with the untraced valid pixels of the smooth cells interpolated from their corners, level
    by level coarse to fine (a pixel of a finer smooth cell takes its value): :func:`swim.rt.image_sampling._fill`.
    Each pixel is interpolated once, in the finest smooth cell that holds it (8.5x less time on a CPU for a 1024^2
    frame than every level in turn; docs/decisions/0005-adaptive-sampling.md).
    A smooth cell that tested its edges is interpolated by its children on the next level, its quarters, whose
    corners are its traced corners, edge midpoints and centre
    (:func:`swim.rt.image_sampling.quarters_of_edged_cells`); a cell whose centre is traced and strictly inside it
    adds the bump through that centre (:func:`swim.rt.fill_cpu.fill_cells`).
    Float arrays are interpolated bilinearly with weights ``dy / h`` and ``dx / w`` rounded to their precision;
    boolean arrays take the cell's first corner; integer arrays 0. A pixel on the edge between two smooth cells of a
    level takes the first one's value where the host's takes the last written: the same for the tested outputs (finite,
    their corners alike), not for an untested output that is not finite or boolean at a corner off that edge."""
    levels = quadtree_levels(*levels_key)
    ny = levels[0].ys[-1] + 1
    y = jnp.arange(ny, dtype=jnp.int32)[:, None]
    x = jnp.arange(nx, dtype=jnp.int32)[None, :]
    target = (valid & ~traced).reshape(ny, nx)
    arrays = list(arrays)
    tested = smooth_levels  # the cells each level's test found smooth
    smooth_levels = list(smooth_levels)
    for index in range(len(levels) - 1):  # the quarters of the tested smooth cells that tested their edges
        # from the tested cells only, as the host quarters them (once): a quarter's own quarters would have corners
        # at its edge midpoints and centre, which no level traced
        _, _, _, edged, _, _, _ = _cell_geometry(levels[index], nx, edge_test_size)
        quarters = _children_exist(tested[index] & edged, levels[index + 1], nx, edge_test_size)
        smooth_levels[index + 1] = smooth_levels[index + 1] | quarters
    # The cell that interpolates each pixel: a finer level's smooth cell overrides a coarser one's (the host writes
    # level by level, coarse to fine). The interpolation reads only traced pixels (a smooth cell's corners, and its
    # centre where traced), which no level writes, so one interpolation per pixel in the finest smooth cell that holds
    # it gives what writing every level in turn gives, at one level's gathers instead of every level's.
    cell = None  # its rows y0, y1 and columns x0, x1 (ny, nx) int32, and whether any level's smooth cell holds it
    for level, smooth in zip(levels, smooth_levels):
        rows = [jnp.asarray(r, jnp.int32) for r in _candidates(level.ys, ny)]
        cols = [jnp.asarray(c, jnp.int32) for c in _candidates(level.xs, nx)]
        # the pixel's cell: the first of the (up to four) cells around it that is smooth; all of them interpolate a
        # shared edge or corner alike
        chosen_a = jnp.broadcast_to(rows[0][:, None], (ny, nx))
        chosen_b = jnp.broadcast_to(cols[0][None, :], (ny, nx))
        found = smooth[chosen_a, chosen_b]
        for a_options, b_options in ((rows[1], cols[0]), (rows[0], cols[1]), (rows[1], cols[1])):
            a = jnp.broadcast_to(a_options[:, None], (ny, nx))
            b = jnp.broadcast_to(b_options[None, :], (ny, nx))
            take = ~found & smooth[a, b]
            chosen_a, chosen_b, found = jnp.where(take, a, chosen_a), jnp.where(take, b, chosen_b), found | take
        ys, xs = jnp.asarray(level.ys, jnp.int32), jnp.asarray(level.xs, jnp.int32)
        here = (ys[chosen_a], ys[chosen_a + 1], xs[chosen_b], xs[chosen_b + 1])
        if cell is None:
            cell = (*here, found)
        else:
            cell = (*(jnp.where(found, new, old) for new, old in zip(here, cell[:4])), cell[4] | found)
    y0, y1, x0, x1, found = cell
    write = (target & found).reshape(-1)
    # a pixel in no smooth cell is not written: its cell made one pixel high and wide (no division by zero there)
    y1, x1 = jnp.where(found, y1, y0 + 1), jnp.where(found, x1, x0 + 1)
    corners = [(y0 * nx + x0).reshape(-1), (y0 * nx + x1).reshape(-1), (y1 * nx + x0).reshape(-1),
               (y1 * nx + x1).reshape(-1)]
    corners = [jnp.where(write, corner, 0) for corner in corners]  # in range where not written
    wy = ((y - y0) / (y1 - y0)).reshape(-1)  # float64 where x64 is on, as the host's; else float32
    wx = ((x - x0) / (x1 - x0)).reshape(-1)
    weights = ((1 - wx) * (1 - wy), wx * (1 - wy), (1 - wx) * wy, wx * wy)
    # the bump through a traced centre strictly inside the cell (swim.rt.fill_cpu.fill_cells)
    height, width = y1 - y0, x1 - x0
    yc, xc = y0 + height // 2, x0 + width // 2
    centre = jnp.where(write, (yc * nx + xc).reshape(-1), 0)
    inside = ((height >= 2) & (width >= 2) & (y > y0) & (y < y1) & (x > x0) & (x < x1)).reshape(-1) & traced[centre]
    ty = jnp.where(y <= yc, (y - y0) / jnp.maximum(yc - y0, 1), (y1 - y) / jnp.maximum(y1 - yc, 1))
    tx = jnp.where(x <= xc, (x - x0) / jnp.maximum(xc - x0, 1), (x1 - x) / jnp.maximum(x1 - xc, 1))
    bump = (ty * tx).reshape(-1)
    wcy = ((yc - y0) / jnp.maximum(height, 1)).reshape(-1)
    wcx = ((xc - x0) / jnp.maximum(width, 1)).reshape(-1)
    centre_weights = ((1 - wcx) * (1 - wcy), wcx * (1 - wcy), (1 - wcx) * wcy, wcx * wcy)
    for i, array in enumerate(arrays):
        if jnp.issubdtype(array.dtype, jnp.floating):
            at_corners = [array[corner] for corner in corners]  # gathered once for both sums
            w = [wt.astype(array.dtype)[:, None] for wt in weights]
            value = at_corners[0] * w[0]
            for corner_value, wt in zip(at_corners[1:], w[1:]):
                value = value + corner_value * wt
            wc = [wt.astype(array.dtype)[:, None] for wt in centre_weights]
            at_centre = at_corners[0] * wc[0]
            for corner_value, wt in zip(at_corners[1:], wc[1:]):
                at_centre = at_centre + corner_value * wt
            residual = array[centre] - at_centre
            value = jnp.where(inside[:, None] & jnp.isfinite(residual),
                              value + residual * bump.astype(array.dtype)[:, None], value)
        elif array.dtype == jnp.bool_:
            value = array[corners[0]]
        else:
            value = jnp.zeros_like(array)
        arrays[i] = jnp.where(write[:, None], value, array)
    return tuple(arrays)


@exported_jit
def _scatter(images, traced, pixels, rows):
    """Each of ``images`` (N, C) with its ``rows`` (m, C) written at ``pixels`` (m,), and ``traced`` (N,) bool set
    there, those at N or beyond (a batch's padding) dropped: one program per batch, not one per output. Not donating
    the images' buffers: a 1024^2 image's arrays are a few megabytes, and an exported program (read from disk by a new
    process) cannot donate."""
    images = tuple(image.at[pixels].set(row.astype(image.dtype), mode="drop") for image, row in zip(images, rows))
    return images, traced.at[pixels].set(True, mode="drop")


def bucket_size(m: int, chunk: int) -> int:
    """Rows [-] of a batch of ``m`` pixels as the device sampler hands it to its ``trace``: the march's own padding
    (:func:`swim.rt.march.padded_batch_size`) of ``chunk``-ray chunks, so that the padding costs the march nothing,
    and the compiled scatters and traces see a bounded set of shapes however many pixels a batch has (an exact
    shape per batch compiled them anew for every batch of every frame)."""
    from .march import padded_batch_size

    full, rest = divmod(int(m), int(chunk))
    return full * int(chunk) + (padded_batch_size(rest, int(chunk)) if rest else 0)


def _as_columns(value):
    value = jnp.asarray(value)
    return value.reshape(value.shape[0], int(np.prod(value.shape[1:], dtype=np.int64)))


def _finish(values, trace, n, outside):
    """``values``, or where nothing was traced, each output of an empty batch as an image of ``outside`` (float) or
    0 (:func:`swim.rt.image_sampling._finish`)."""
    if values:
        return values
    empty = trace(np.zeros(0, np.int64))
    images = {}
    for name, value in empty.items():
        rows = _as_columns(value)
        images[name] = jnp.full((n, rows.shape[1]), outside if jnp.issubdtype(rows.dtype, jnp.floating) else 0,
                                rows.dtype)
    return images


class _DeviceBatches:
    """The image's outputs on the device as batches of pixels are traced into it.

    ``traced`` (n,) bool and ``values`` (the outputs by name, (n, C), made at the first batch that returns them)
    are the device's; ``done`` counts the pixels traced so far (each batch's are new ones, so the host counts them).
    """

    def __init__(self, trace, valid_dev, total, n, chunk, progress, outside):
        self.trace, self.valid_dev, self.total, self.n = trace, valid_dev, total, n
        self.chunk, self.progress, self.outside = chunk, progress, outside
        self.traced = jnp.zeros(n, bool)
        self.values: dict[str, jax.Array] = {}
        self.done = 0

    def run(self, wanted):
        """Trace the valid pixels not yet traced among those ``wanted`` (a mask over the image) into the image.

        Raises
        ------
        SwimInputError
            If ``trace`` returns no ``radiance``, ``tau_hydrometeor`` or ``surface``, or not a row per pixel.
        """
        n, values = self.n, self.values
        new = np.flatnonzero(np.asarray(wanted & self.valid_dev & ~self.traced))
        if new.size == 0:
            return
        # the last pixel repeated up to the batch's bucket; the repeats' rows are dropped (index n), so that trace may
        # march them as padding (the pipeline's rays that start stopped) and return anything there
        pad = bucket_size(new.size, self.chunk) - new.size
        padded = np.concatenate([new, np.repeat(new[-1:], pad)])
        result = self.trace(padded)
        missing = {"radiance", "tau_hydrometeor", "surface"} - set(result)
        if missing:
            raise SwimInputError(f"sample_image_adaptive_device: trace returned no {sorted(missing)}")
        pixels = jnp.asarray(np.concatenate([new, np.full(pad, n)]).astype(np.int32))
        names, batch = list(result), []
        for name in names:
            rows = _as_columns(result[name])
            if rows.shape[0] != padded.size:
                raise SwimInputError(f"sample_image_adaptive_device: trace returned {rows.shape[0]} rows of "
                                     f"{name!r} for {padded.size} pixels")
            if name not in values:
                fill = self.outside if jnp.issubdtype(rows.dtype, jnp.floating) else 0
                values[name] = jnp.full((n, rows.shape[1]), fill, rows.dtype)
            batch.append(rows)
        images, self.traced = _scatter(tuple(values[name] for name in names), self.traced, pixels, tuple(batch))
        values.update(zip(names, images))
        self.done += new.size
        if self.progress is not None and self.total:  # counted here, not by the device: no wait for the batch's march
            self.progress(self.done, self.total)


def _smooth_of_level(exists, values, valid_dev, traced, sampling: AdaptiveSampling, *, nx, level_index, levels_key):
    """The cells of level ``level_index`` that are smooth (the device's :func:`_test_level` over the traced values)."""
    if not values:  # nothing traced yet (no valid pixel so far): no cell is smooth, all split (as the host's sampler)
        return jnp.zeros_like(exists)
    checks = [("radiance", sampling.tolerance, sampling.radiance_floor),
              ("tau_hydrometeor", sampling.tau_tolerance, sampling.tau_floor)]
    if sampling.clear_tolerance > 0 and "radiance_clear" in values:
        checks.append(("radiance_clear", sampling.clear_tolerance, sampling.radiance_floor))
    with jax.enable_x64(True):  # the test in float64, as the host's (_test_level)
        return _test_level(exists, tuple(values[name] for name, _, _ in checks), valid_dev, traced,
                           values["surface"][:, 0], nx=nx, edge_test_size=int(sampling.edge_test_size),
                           level_index=level_index, levels_key=levels_key,
                           checks=tuple((float(t), float(f)) for _, t, f in checks))


def sample_image_adaptive_device(trace, valid, sampling: AdaptiveSampling = AdaptiveSampling(), progress=None,
                                 outside=0.0, chunk=None):
    """Sample an image as :func:`swim.rt.image_sampling.sample_image_adaptive` does, with the image on the device.

    Parameters
    ----------
    trace : callable
        ``trace(pixels)`` with flat pixel indices (m,) int64 (a NumPy array: a batch's pixels in increasing order,
        then its last pixel repeated up to :func:`bucket_size`) into the (ny, nx) image returns a dict of arrays
        (m, ...), JAX device arrays or NumPy ones (the repeats' rows are not used: they may be padding's): at least
        ``radiance`` (m, C) [-], ``tau_hydrometeor`` (m,) [-] and ``surface`` (m,) bool; ``radiance_clear`` (m, C)
        [-], where given, enters the test of ``sampling.clear_tolerance``. Float arrays are interpolated, boolean ones
        copied from a smooth cell's first corner, integer ones 0 where interpolated.
    valid : numpy.ndarray
        Shape (ny, nx) bool: the camera's pixels that have a ray; the others are never traced and keep ``outside``
        (float outputs) or 0.
    sampling : AdaptiveSampling
    progress : callable, optional
        Called with (pixels traced, valid pixels) after each batch of rays.
    outside : float
        Value of the float outputs at the pixels without a ray.
    chunk : int, optional
        Rays of the march's chunks, whose padding the batches take (:func:`bucket_size`); None: the GPU's,
        :data:`swim.rt.march_settings.GPU_CHUNK`.

    Returns
    -------
    values : dict of jax.Array
        Shape (ny * nx, C) per key of ``trace``'s result (a 1-D output as (ny * nx, 1)), on the device.
    traced : jax.Array
        Shape (ny, nx) bool: the pixels that were traced.

    Raises
    ------
    SwimInputError
        If ``valid`` is not a 2-D boolean array of at least 3 x 3 pixels, or ``trace`` returns no ``radiance``,
        ``tau_hydrometeor`` or ``surface``.

    References
    ----------
    Whitted, T. (1980), "An improved illumination model for shaded display", Commun. ACM 23, 343-349,
    doi:10.1145/358876.358882 (the refinement); docs/decisions/0005-adaptive-sampling.md (this module).
    """
    valid = np.asarray(valid)
    if valid.ndim != 2 or valid.dtype != bool or min(valid.shape) < 3:
        raise SwimInputError(f"valid must be a 2-D boolean pixel mask of at least 3 x 3 pixels, got dtype "
                             f"{valid.dtype} and shape {valid.shape}")
    ny, nx = valid.shape
    n = ny * nx
    size = int(sampling.edge_test_size)
    if chunk is None:
        from .march_settings import GPU_CHUNK as chunk
    valid_flat = valid.reshape(-1)
    valid_dev = jnp.asarray(valid_flat)
    batches = _DeviceBatches(trace, valid_dev, int(valid_flat.sum()), n, chunk, progress, outside)
    values, run = batches.values, batches.run

    if sampling.coarse_spacing >= min(ny, nx):  # no lattice inside the image: every pixel (as the host's sampler)
        run(jnp.ones(n, bool))
        return _finish(values, trace, n, outside), batches.traced.reshape(ny, nx)
    key = (ny, nx, int(sampling.coarse_spacing))  # quadtree_levels's arguments: the programs' static one
    levels = quadtree_levels(*key)
    exists, wanted = _first_wanted(nx=nx, edge_test_size=size, levels_key=key)
    run(wanted)
    smooth_levels = []
    for index in range(len(levels)):
        smooth = _smooth_of_level(exists, values, valid_dev, batches.traced, sampling, nx=nx, level_index=index,
                                  levels_key=key)
        smooth_levels.append(smooth)
        if index + 1 == len(levels):
            break
        exists, wanted = _wanted_after_split(exists & ~smooth, nx=nx, edge_test_size=size, level_index=index,
                                             levels_key=key)
        run(wanted)
    traced = batches.traced
    if not values:  # no valid pixel at all
        return _finish(values, trace, n, outside), traced.reshape(ny, nx)
    names = list(values)
    filled = _fill(tuple(values[name] for name in names), tuple(smooth_levels), traced, valid_dev, nx=nx,
                   edge_test_size=size, levels_key=key)
    return dict(zip(names, filled)), traced.reshape(ny, nx)
