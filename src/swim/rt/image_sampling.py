"""Adaptive image sampling: trace a coarse lattice of pixels and refine only where the image is not smooth.

An NWP field is resolved at its grid spacing (kilometres), which covers several pixels of a typical image:
a 3 km cell 100 km away spans 1.7 deg, ten pixels of a 1024 x 1024 all-sky image. Most of an image is
therefore smooth at the pixel scale, and tracing every pixel repeats work. This module traces pixels in
the order of a quadtree (the refinement of Whitted 1980, "An improved illumination model for shaded
display", Commun. ACM 23, 343-349, doi:10.1145/358876.358882, with an explicit error test):

1. the lattice of every ``coarse_spacing``-th row and column (and the last ones) is traced;
2. each cell of the lattice traces its centre pixel and compares it with the bilinear interpolation of
   its four corners; a cell at least ``edge_test_size`` pixels high or wide also traces the midpoints of
   its four edges and compares each with the linear interpolation of its edge's two corners. Where the
   radiance, the hydrometeor optical depth and the radiance of the air in front of the clouds agree within
   ``tolerance``, ``tau_tolerance`` and ``clear_tolerance`` (relative, above absolute floors) and all these
   pixels see the same thing (all ground or all sky, all inside the camera's field), the cell's other pixels
   are interpolated through every pixel that the test traced: in a cell that tested its edges, quarter by quarter
   from each quarter's four traced corners (the cell's corners, edge midpoints and centre), else bilinearly from
   its corners plus a bump through its traced centre (:func:`swim.rt.fill_cpu.fill_cells`);
3. the other cells trace the midpoints of their edges (where not yet traced) and split into four, down to
   single pixels.

With the defaults (a spacing of 8 and edge tests in cells of 8 pixels) a smooth image is traced on the lattice of
every 4th row and column, 1/16 of its pixels, and each 8 x 8 cell is tested at 5 of them. A feature smaller
than a cell that touches none of its tested pixels can be missed; docs/decisions/0005-adaptive-sampling.md
gives the measured errors on real scenes.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from ..errors import SwimInputError
from ..workers import parallel_map


@dataclass(frozen=True)
class AdaptiveSampling:
    """Settings of :func:`sample_image_adaptive`.

    Attributes
    ----------
    tolerance : float
        Largest relative difference [-] between a cell's traced centre (and edge midpoints') radiance, in each
        channel, and the interpolation of its corners for the cell to be interpolated. Default 0.0085: with the edge
        tests, 0.0085 gives a smaller interpolation error than 0.01 without them, on every scene measured, for
        fewer rays (docs/decisions/0005-adaptive-sampling.md).
    coarse_spacing : int
        Pixels between the rows and columns of the first lattice (>= 2). Larger spacings trace fewer rays in
        smooth regions and risk missing smaller features. Default 8 (with the edge tests; see ``edge_test_size``).
    radiance_floor : float
        Absolute solar-relative radiance [-] added to the tolerance, so that dark pixels (night side, deep
        shadow) do not refine on differences far below what any output resolves.
    tau_tolerance : float
        The same for the hydrometeor optical depth along the line of sight [-]. Default 0.05: the test is
        there to catch clouds whose radiance happens to match the sky's; at 1 % it refined smooth thick
        cloud for the optical-depth image alone (~14 % of an all-sky render's rays, 17 % of its time,
        docs/decisions/0005-adaptive-sampling.md).
    tau_floor : float
        Absolute hydrometeor optical depth [-] added to the tolerance of the optical-depth test.
    edge_test_size : int
        Cells at least this many pixels high or wide [pixels] test the midpoints of their four edges too, each
        against the linear interpolation of its edge's corners (0: centres only). A cell
        that splits traces those midpoints anyway, so the tests cost rays only where cells are smooth, and there
        they are interpolated from too (:func:`quarters_of_edged_cells`); with the
        default coarse spacing and tolerance they trace 10-28 % fewer rays than a spacing of 4 with centre tests
        alone at a 1 % tolerance, with a smaller 99.9th percentile of the interpolation's error
        (docs/decisions/0005-adaptive-sampling.md). Default 8.
    clear_tolerance : float
        The same as ``tolerance`` for the gas and aerosol part of the radiance (``radiance_clear``, with the floor
        ``radiance_floor``), where the trace returns it; 0: no such test. Seen from below, the air between the
        camera and a cloud shines more the farther the cloud, so this finds where the visible face of opaque cloud
        jumps from a near cloud to a far one: there the optical depth along the line of sight, capped where rays stop
        (``MarchSettings.stop_tau``), does not change, and the total radiance may happen to. Default 0.05: on the
        CONUS all-sky it takes the interpolation's largest error from 53 % to 21 % (pixels more than 10 % off: 14 →
        2) for 0.7 % more traced pixels, and changes nothing on Katrina (docs/decisions/0005-adaptive-sampling.md).
    """

    tolerance: float = 0.0085
    coarse_spacing: int = 8
    radiance_floor: float = 1e-4
    tau_tolerance: float = 0.05
    tau_floor: float = 0.01
    edge_test_size: int = 8
    clear_tolerance: float = 0.05

    def __post_init__(self):
        for name in ("tolerance", "tau_tolerance", "radiance_floor", "tau_floor", "clear_tolerance"):
            value = getattr(self, name)
            if not isinstance(value, (int, float, np.floating, np.integer)) or not np.isfinite(value) or value < 0:
                raise SwimInputError(f"AdaptiveSampling.{name} must be a finite number >= 0, got {value!r}")
        for name in ("tolerance", "tau_tolerance"):
            if getattr(self, name) <= 0:
                raise SwimInputError(f"AdaptiveSampling.{name} must be > 0, got {getattr(self, name)!r}")
        if not isinstance(self.coarse_spacing, (int, np.integer)) or self.coarse_spacing < 2:
            raise SwimInputError(f"AdaptiveSampling.coarse_spacing must be an integer >= 2, got {self.coarse_spacing!r}")
        if not isinstance(self.edge_test_size, (int, np.integer)) or self.edge_test_size < 0:
            raise SwimInputError(f"AdaptiveSampling.edge_test_size must be an integer >= 0 [pixels], "
                                 f"got {self.edge_test_size!r}")


#: Fewest cells [-] per thread of :func:`_smooth_cells` (a 1024^2 image's levels have 16 000-110 000).
SMOOTH_BLOCK_CELLS = 4096
#: Side of the square tiles in which :func:`tile_order` puts the pixels [pixels].
TRACE_TILE = 8


def tile_order(flat, shape, tile=TRACE_TILE):
    """The order in which to trace pixels: tile by tile, row by row inside a tile.

    Rays of neighbouring pixels cross the same grid cells, so traced one after the other they find them in the
    CPU's caches; in image rows they revisit a cell only a row (hundreds of rays) later. On the 400 x 400 x 60
    scene (0.9 GB volume) a 511^2 all-sky renders ~5 % faster in 8 x 8 tiles than in rows; on small grids,
    which stay in the caches, the order makes no difference (docs/decisions/0003-cpu-kernel-code.md).

    Parameters
    ----------
    flat : numpy.ndarray
        Shape (n,) int: flat pixel indices into an image of ``shape``.
    shape : tuple of int
        (ny, nx) of the image [pixels].
    tile : int
        Side of the tiles [pixels], >= 1.

    Returns
    -------
    numpy.ndarray
        Shape (n,) int: the permutation of ``flat`` (``flat[order]`` is in tile order; pixels of one tile keep
        their row-major order).
    """
    y, x = np.divmod(np.asarray(flat, dtype=np.int64), shape[1])
    tiles_per_row = -(-shape[1] // tile)
    key = ((y // tile) * tiles_per_row + x // tile) * (tile * tile) + (y % tile) * tile + x % tile
    return np.argsort(key, kind="stable")


def _lattice(n, spacing):
    """Every spacing-th index of range(n) and the last one."""
    idx = np.arange(0, n, spacing)
    return idx if idx[-1] == n - 1 else np.append(idx, n - 1)


class _Batches:
    """The image's outputs as batches of pixels are traced into it, and the progress reported.

    ``traced`` and ``filled`` (ny * nx,) bool: the pixels traced, and those that the fill will interpolate (only kept
    with ``progress``); ``values``: the outputs by key, (ny * nx, ...), made at the first batch that returns them.
    """

    def __init__(self, trace, valid_flat, progress, max_threads, outside):
        self.trace, self.valid_flat, self.progress = trace, valid_flat, progress
        self.max_threads, self.outside = max_threads, outside
        self.traced = np.zeros(valid_flat.size, bool)
        self.filled = np.zeros(valid_flat.size, bool)
        self.values: dict[str, np.ndarray] = {}
        self.total = int(valid_flat.sum())

    def report(self):
        """Call ``progress`` with the valid pixels traced or to be interpolated."""
        if self.progress is not None and self.total:
            self.progress(int(np.count_nonzero((self.traced | self.filled) & self.valid_flat)), self.total)

    def run(self, wanted):
        """Trace the valid pixels not yet traced among those ``wanted`` (a mask over the image) into the image."""
        values, n = self.values, self.valid_flat.size
        # the new valid pixels among those ``wanted`` (a mask over the image), in increasing order: not np.unique's
        # sort of a list with duplicates, which took 135-154 ms of the synthetic 1024^2 all-sky's three batches
        # (131 000-347 000 pixels) on the main thread while the cores idled
        # (docs/decisions/0009-work-around-the-march.md)
        flat = np.flatnonzero(wanted & self.valid_flat & ~self.traced)
        if flat.size == 0:
            return
        pixels, result = _rows_of(self.trace(flat), flat)
        pixels = np.ascontiguousarray(pixels, dtype=np.int64)
        result = {key: np.asarray(value) for key, value in result.items()}
        new = [key for key in result if key not in values]
        for key in new:  # made in the trace's order; their pages first written (blanked) by the threads below
            values[key] = _image_array(n, result[key])
        from .fill_cpu import scatter_rows

        def scatter(key):
            image = values[key]
            if key in new:
                _blank(image, self.outside)
            scatter_rows(image.reshape(n, -1), pixels,
                         np.ascontiguousarray(result[key].reshape(len(pixels), -1), dtype=image.dtype))

        parallel_map(scatter, list(result), self.max_threads)
        self.traced[flat] = True
        self.report()


def _coarse_cells(ny, nx, spacing):
    """The coarse lattice's rows and columns, and its cells (m, 4) of (y0, y1, x0, x1) with a pixel inside."""
    rows, cols = _lattice(ny, spacing), _lattice(nx, spacing)
    y0, x0 = np.meshgrid(rows[:-1], cols[:-1], indexing="ij")
    y1, x1 = np.meshgrid(rows[1:], cols[1:], indexing="ij")
    cells = np.stack([y0.ravel(), y1.ravel(), x0.ravel(), x1.ravel()], axis=1)
    # the cells with a pixel between their corners (one of at most 2 x 2 pixels has only corners)
    return rows, cols, np.ascontiguousarray(cells[(cells[:, 1] - cells[:, 0] > 1) | (cells[:, 3] - cells[:, 2] > 1)])


def sample_image_adaptive(trace, valid, sampling: AdaptiveSampling = AdaptiveSampling(), progress=None, max_threads=1,
                          outside=0.0):
    """Sample an image by tracing a quadtree of its pixels and interpolating its smooth cells.

    Parameters
    ----------
    trace : callable
        ``trace(pixels)`` with flat pixel indices (n,) into the (ny, nx) image returns a dict of arrays
        (n, ...): at least ``radiance`` (n, C) [-], ``tau_hydrometeor`` (n,) [-] and ``surface`` (n,) bool;
        ``radiance_clear`` (n, C) [-], where given, enters the test of ``sampling.clear_tolerance``. Float arrays
        are interpolated, boolean ones copied from the corners (which agree), integer ones (e.g. step counts) are 0
        where interpolated. It may also return ``(order, arrays)``: the arrays' rows are then those of the pixels
        ``pixels[order]`` (a tracer that traces them in another order need not put them back: each is scattered
        into the image once).
    valid : numpy.ndarray
        Shape (ny, nx) bool: the camera's pixels that have a ray; the others are never traced and keep ``outside``
        (float outputs) or 0.
    sampling : AdaptiveSampling
    progress : callable, optional
        Called with (pixels done, valid pixels) after each batch of rays.
    max_threads : int
        Threads [-] that test a level's cells (blocks of cells) and interpolate the smooth cells' pixels (bands of
        rows; the compiled kernels release the GIL). The cells of every level are interpolated at the end, coarse to
        fine, which gives what filling them level by level gives (only traced pixels enter the test of a cell, and a
        pixel traced later keeps its traced value).
    outside : float
        Value of the float outputs at the pixels without a ray (``valid`` False): NaN lets an image's planes be
        made without a masking pass (:func:`swim.pipeline.render`).

    Returns
    -------
    values : dict of numpy.ndarray
        Shape (ny * nx, ...) per key of ``trace``'s result; ``outside`` (float) or 0 at invalid pixels.
    traced : numpy.ndarray
        Shape (ny, nx) bool: the pixels that were traced (the others are interpolated or invalid).

    Raises
    ------
    SwimInputError
        If ``valid`` is not a 2-D boolean array.
    """
    valid = np.asarray(valid)
    if valid.ndim != 2 or valid.dtype != bool:
        raise SwimInputError(f"valid must be a 2-D boolean pixel mask, got dtype {valid.dtype} and shape {valid.shape}")
    ny, nx = valid.shape
    valid_flat = valid.reshape(-1)
    batches = _Batches(trace, valid_flat, progress, max_threads, outside)
    traced, filled, values = batches.traced, batches.filled, batches.values
    run, report = batches.run, batches.report

    if sampling.coarse_spacing >= min(ny, nx) or min(ny, nx) < 3:
        run(valid_flat)
        return _finish(values, traced, ny, nx, trace, outside), traced.reshape(ny, nx)

    from .smooth_cpu import mark_tested, split_cells

    size = int(sampling.edge_test_size)
    rows, cols, cells = _coarse_cells(ny, nx, sampling.coarse_spacing)
    # The lattice and its cells' tested pixels in one batch, and below the split cells' edge midpoints with their
    # children's tested pixels (swim.rt.smooth_cpu): each cell's are traced whatever its test finds, so the batches
    # trace what one batch per step traced (the same pixels, tests and image) with fewer waits for a batch's last rays.
    wanted = np.zeros((ny, nx), bool)
    wanted[np.ix_(rows, cols)] = True
    wanted = wanted.reshape(-1)
    mark_tested(cells, nx, size, wanted)
    run(wanted)
    smooth_levels = []  # the smooth cells (m, 4) of each level, coarse to fine: interpolated at the end
    while cells.size:
        smooth = _smooth_cells(values, valid_flat, traced, cells, nx, sampling, max_threads)
        # a cell that tested its edges is interpolated quarter by quarter: its edge midpoints and centre are traced
        smooth_levels.append(quarters_of_edged_cells(cells[smooth], size))
        if progress is not None:  # the pixels that the fill will interpolate count as done
            from .fill_cpu import fill_cells_from_corner

            # the cells' untraced valid pixels take the value of their first corner, which is traced: True
            filled |= traced
            fill_cells_from_corner(filled, np.ascontiguousarray(smooth_levels[-1], dtype=np.int64), traced,
                                   valid_flat, nx, False)
            report()
        wanted = np.zeros(ny * nx, bool)
        cells = split_cells(cells, smooth, nx, size, wanted)
        run(wanted)
    _fill(values, traced, valid_flat, smooth_levels, nx, max_threads)
    return _finish(values, traced, ny, nx, trace, outside), traced.reshape(ny, nx)


def quarters_of_edged_cells(cells, edge_test_size):
    """The cells (m, 4) with each cell that tests its edges (at least ``edge_test_size`` pixels high or wide, as
    :func:`swim.rt.smooth_cpu.mark_tested` decides) replaced by its quarters, split at its centre as
    :func:`swim.rt.smooth_cpu.split_cells` splits a cell (a quarter without area, or without a pixel between its
    corners, dropped). A smooth cell's corners, edge midpoints and centre are all traced, so each quarter is
    interpolated from four traced corners: the fill then meets every traced pixel of the cell, where the four corners
    alone missed the five tested ones (on the 1024^2 all-sky of the 400 x 400 x 60 scene, the same traced pixels,
    the radiance's median error against the converged reference 0.079 -> 0.066 % below a view zenith of 72 deg, the
    hydrometeor optical depth's 0.055 -> 0.020 %; docs/decisions/0005-adaptive-sampling.md).

    Parameters
    ----------
    cells : numpy.ndarray
        Shape (m, 4) int: cells (y0, y1, x0, x1) [pixels], corners included.
    edge_test_size : int
        :attr:`AdaptiveSampling.edge_test_size` [pixels]; 0: no cell tests its edges (``cells`` returned).

    Returns
    -------
    numpy.ndarray
        Shape (k, 4) int64: the cells without edge tests, then the quarters of those with them.
    """
    cells = np.asarray(cells, dtype=np.int64).reshape(-1, 4)
    if edge_test_size <= 0 or len(cells) == 0:
        return np.ascontiguousarray(cells)
    y0, y1, x0, x1 = cells.T
    edged = np.maximum(y1 - y0, x1 - x0) >= edge_test_size
    if not edged.any():
        return np.ascontiguousarray(cells)
    y0, y1, x0, x1 = cells[edged].T
    yc, xc = (y0 + y1) // 2, (x0 + x1) // 2
    quarters = np.concatenate([np.stack(corners, axis=1) for corners in
                               ((y0, yc, x0, xc), (y0, yc, xc, x1), (yc, y1, x0, xc), (yc, y1, xc, x1))])
    h, w = quarters[:, 1] - quarters[:, 0], quarters[:, 3] - quarters[:, 2]
    quarters = quarters[(h > 0) & (w > 0) & ((h > 1) | (w > 1))]
    return np.ascontiguousarray(np.concatenate([cells[~edged], quarters]))


def _rows_of(result, flat):
    """A tracer's result for the pixels ``flat``, as (the pixels of its rows, its arrays): its arrays and ``flat``, or
    for ``(order, arrays)`` the arrays and ``flat[order]`` (:func:`sample_image_adaptive`'s ``trace``)."""
    if not isinstance(result, tuple):
        return flat, result
    order, arrays = result
    return (flat if order is None else flat[order]), arrays


def _image_array(n, value):
    """An output's array (unwritten) for all ``n`` pixels of the image, shaped and typed as a batch's ``value``
    (m, ...)."""
    value = np.asarray(value)
    return np.empty((n,) + value.shape[1:], value.dtype)


def _blank(image, outside):
    """``image`` set, in place, to what its pixels hold until they are traced or interpolated: ``outside`` where it
    is float, else 0; returns it."""
    image.fill(outside if image.dtype.kind == "f" else 0)
    return image


def _finish(values, traced, ny, nx, trace, outside):
    if not values:  # nothing valid: ask for the keys with an empty batch
        empty = np.zeros(0, np.int64)
        values = {key: _blank(_image_array(ny * nx, v), outside)
                  for key, v in _rows_of(trace(empty), empty)[1].items()}
    return values


def _smooth_cells(values, valid_flat, traced, cells, nx, sampling, max_threads=1):
    """Cells (m,) whose traced centre matches the bilinear interpolation of their corners and, in cells of at least
    ``sampling.edge_test_size`` pixels, whose edges' traced midpoints match the linear interpolation of their edges'
    corners, in the radiance, the hydrometeor optical depth and (``sampling.clear_tolerance`` > 0) the clear-air
    radiance; their corners and tested pixels all traced and all seeing the ground or all the sky.

    One compiled pass per output over the cells (:mod:`swim.rt.smooth_cpu`): the NumPy gathers it replaces took ~0.09
    s of a 1024^2 all-sky's three levels while the march's threads waited, for the same decisions
    (docs/decisions/0003-cpu-kernel-code.md). Each cell is tested on its own, so the cells are split into up to
    ``max_threads`` blocks tested at once (the kernels release the GIL;
    docs/decisions/0009-work-around-the-march.md)."""
    from .smooth_cpu import cells_match, cells_traced_alike

    ok = np.ones(len(cells), bool)
    if not values:  # nothing traced yet (no valid pixel so far): no cell can be interpolated
        return ~ok
    cells = np.ascontiguousarray(cells, dtype=np.int64)
    size = int(sampling.edge_test_size)
    checks = [("radiance", sampling.tolerance, sampling.radiance_floor),
              ("tau_hydrometeor", sampling.tau_tolerance, sampling.tau_floor)]
    if sampling.clear_tolerance > 0 and "radiance_clear" in values:
        checks.append(("radiance_clear", sampling.clear_tolerance, sampling.radiance_floor))

    def test(block):
        lo, hi = block
        cells_traced_alike(ok[lo:hi], cells[lo:hi], nx, size, valid_flat, traced, values["surface"])
        for key, tolerance, floor in checks:
            cells_match(ok[lo:hi], values[key].reshape(values[key].shape[0], -1), cells[lo:hi], nx, size,
                        float(tolerance), float(floor))

    # blocks of at least SMOOTH_BLOCK_CELLS cells: below, a thread's hand-over costs more than the cells' tests
    blocks = max(1, min(int(max_threads), len(cells) // SMOOTH_BLOCK_CELLS))
    parallel_map(test, [(q * len(cells) // blocks, (q + 1) * len(cells) // blocks) for q in range(blocks)], blocks)
    return ok


def _fill(values, traced, valid_flat, levels, nx, max_threads=1):
    """Bilinear interpolation of the untraced pixels of the smooth cells of every level (a list of (m, 4) arrays,
    coarse to fine: a pixel on the edge of cells of two levels takes the finer cell's value, as when each level
    was filled before the next was traced), from their corners (the quarters of the cells that tested their edges,
    :func:`quarters_of_edged_cells`, from theirs), and through a traced centre strictly inside a cell
    (:func:`swim.rt.fill_cpu.fill_cells`'s bump).

    Float arrays go through the compiled :func:`swim.rt.fill_cpu.fill_cells`, all of one precision in one pass over
    the cells' pixels (the weights computed once per pixel and rounded once to the arrays' precision), on bands of
    image rows, one per thread: 0.17 s of a 1024^2 all-sky's end in NumPy, ~0.03 s compiled one output at a time, the
    NumPy gathers giving the same bits (docs/decisions/0009-work-around-the-march.md). Booleans are copied from a corner
    (the corners of a smooth cell agree), integers (step counts) are 0, one array per thread."""
    if not any(len(cells) for cells in levels):
        return
    from .fill_cpu import fill_cells, fill_cells_from_corner

    cells = np.ascontiguousarray(np.concatenate([c for c in levels if len(c)]), dtype=np.int64)
    ny = traced.size // nx
    tasks = []
    for dtype in sorted({a.dtype.str for a in values.values() if a.dtype.kind == "f"}):
        arrays = tuple(a.reshape(a.shape[0], -1) for a in values.values() if a.dtype.str == dtype)
        bands = max(1, min(int(max_threads), ny))
        tasks += [functools.partial(fill_cells, arrays, cells, traced, valid_flat, nx, q * ny // bands,
                                    (q + 1) * ny // bands) for q in range(bands)]
    tasks += [functools.partial(fill_cells_from_corner, a.reshape(-1), cells, traced, valid_flat, nx, a.dtype != bool)
              for a in values.values() if a.dtype.kind in "biu"]
    parallel_map(lambda task: task(), tasks, max_threads)
