"""Adaptive sampling's cells, one cell at a time on the CPU (numba): their test and their split.

:func:`swim.rt.image_sampling._smooth_cells` decides which cells of a level are interpolated: their tested pixels
(the centre, and in cells of at least ``edge_test_size`` pixels the midpoints of the four edges) must match the
bilinear interpolation of the cell's corners in every channel of the radiance, the optical depth and the clear-air
radiance. In NumPy that test built per-cell index and weight arrays and gathered every corner and tested pixel of
every output channel, pass after pass: ~0.09 s of the 1024^2 synthetic all-sky's three levels, on the main thread
while the march's threads waited for the next batch. These kernels do the same float64 arithmetic per cell in one
pass (docs/decisions/0003-cpu-kernel-code.md).

Bit for bit NumPy's decision: the weights are computed in float64 as ``(yc - y0) / max(y1 - y0, 1)``, the
interpolation is summed corner by corner in the same order without fused multiply-adds (no fast-math), and a NaN
anywhere fails the test as NumPy's comparisons do.

:func:`split_cells` and :func:`mark_tested` then give the next level's cells and mark the pixels to trace for them in
one pass each: NumPy's column views, stacks and index arrays for that took ~30 ms of the same render's levels, again
while the march's threads waited (docs/decisions/0009-work-around-the-march.md).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..compilation.numba_jit import JIT_EXACT as _JIT


@njit(**_JIT)
def _tested_pixels(y0, y1, x0, x1, nx, edge_size):
    """The cell's centre (yc, xc), its corners' flat indices, whether it has edge tests, and its edges' midpoints
    (top, bottom, left, right) as flat indices."""
    yc, xc = (y0 + y1) // 2, (x0 + x1) // 2
    edged = edge_size > 0 and max(y1 - y0, x1 - x0) >= edge_size
    corners = (y0 * nx + x0, y0 * nx + x1, y1 * nx + x0, y1 * nx + x1)
    edges = (y0 * nx + xc, y1 * nx + xc, yc * nx + x0, yc * nx + x1)
    return yc, xc, corners, edged, edges


@njit(**_JIT)
def cells_traced_alike(ok, cells, nx, edge_size, valid, traced, surface):
    """Clear ``ok`` for cells whose corners or tested pixels lack a ray or were not traced, or whose corners or edge
    midpoints do not see what the centre sees (all the ground or all the sky), in place.

    Parameters
    ----------
    ok : numpy.ndarray
        Shape (m,) bool: the cells still interpolable; set to False where this test fails.
    cells : numpy.ndarray
        Shape (m, 4) int64: the cells' first and last rows and columns (y0, y1, x0, x1) [pixels].
    nx : int
        Image width [pixels].
    edge_size : int
        Cells at least this many pixels high or wide test their edges' midpoints too (0: none does).
    valid, traced, surface : numpy.ndarray
        Shape (ny * nx,) bool: the pixels that have a ray, those traced, and those that see the ground.
    """
    for q in range(cells.shape[0]):
        y0, y1, x0, x1 = cells[q, 0], cells[q, 1], cells[q, 2], cells[q, 3]
        yc, xc, corners, edged, edges = _tested_pixels(y0, y1, x0, x1, nx, edge_size)
        centre = yc * nx + xc
        good = valid[centre] and traced[centre]
        for p in corners:
            good = good and valid[p] and traced[p] and surface[p] == surface[centre]
        if edged:
            for p in edges:
                good = good and valid[p] and traced[p] and surface[p] == surface[centre]
        if not good:
            ok[q] = False


@njit(**_JIT)
def _matches(values, pixel, corners, w00, w01, w10, w11, tolerance, floor):
    """Whether every channel of ``values`` at ``pixel`` lies within ``tolerance`` (relative to the larger of it and
    the prediction) plus ``floor`` of the corners' interpolation with these weights."""
    c00, c01, c10, c11 = corners
    for c in range(values.shape[1]):
        predicted = 0.0
        predicted += w00 * values[c00, c]  # the sum of NumPy's sum(): (((0 + w00 c00) + w01 c01) + w10 c10) + w11 c11
        predicted += w01 * values[c01, c]
        predicted += w10 * values[c10, c]
        predicted += w11 * values[c11, c]
        actual = values[pixel, c] + 0.0  # in float64, as NumPy's mixed float32 and float64 arithmetic
        scale = max(abs(actual), abs(predicted))
        if not abs(actual - predicted) <= tolerance * scale + floor:  # a NaN fails
            return False
    return True


@njit(**_JIT)
def cells_match(ok, values, cells, nx, edge_size, tolerance, floor):
    """Clear ``ok`` for cells whose tested pixels do not match the bilinear interpolation of their corners in
    ``values``, in place: the centre from all four corners, and in cells with edge tests each edge's midpoint from
    that edge's two corners.

    Parameters
    ----------
    ok : numpy.ndarray
        Shape (m,) bool: the cells still interpolable (only these are tested); set to False where the test fails.
    values : numpy.ndarray
        Shape (ny * nx, C) float32 or float64: one output of the sampler (e.g. the radiance (C = 3) [-]), its
        corners and tested pixels traced.
    cells, nx, edge_size
        As :func:`cells_traced_alike`.
    tolerance : float
        Largest difference [-] relative to the larger of the traced and the interpolated value.
    floor : float
        Absolute allowance [units of ``values``] added to it.
    """
    for q in range(cells.shape[0]):
        if not ok[q]:
            continue
        y0, y1, x0, x1 = cells[q, 0], cells[q, 1], cells[q, 2], cells[q, 3]
        yc, xc, corners, edged, edges = _tested_pixels(y0, y1, x0, x1, nx, edge_size)
        wy = (yc - y0) / max(y1 - y0, 1)
        wx = (xc - x0) / max(x1 - x0, 1)
        good = _matches(values, yc * nx + xc, corners, (1 - wx) * (1 - wy), wx * (1 - wy), (1 - wx) * wy, wx * wy,
                        tolerance, floor)
        if good and edged:
            top, bottom, left, right = edges
            good = (_matches(values, top, corners, 1 - wx, wx, 0.0, 0.0, tolerance, floor)
                    and _matches(values, bottom, corners, 0.0, 0.0, 1 - wx, wx, tolerance, floor)
                    and _matches(values, left, corners, 1 - wy, 0.0, wy, 0.0, tolerance, floor)
                    and _matches(values, right, corners, 0.0, 1 - wy, 0.0, wy, tolerance, floor))
        if not good:
            ok[q] = False


@njit(**_JIT)
def mark_tested(cells, nx, edge_size, wanted):
    """Set ``wanted`` at the pixels that the cells' tests read besides their corners, in place: each cell's centre,
    and in cells at least ``edge_size`` pixels high or wide the midpoints of its four edges.

    Parameters
    ----------
    cells : numpy.ndarray
        Shape (m, 4) int64: the cells' first and last rows and columns (y0, y1, x0, x1) [pixels].
    nx : int
        Image width [pixels].
    edge_size : int
        As :func:`cells_traced_alike`.
    wanted : numpy.ndarray
        Shape (ny * nx,) bool: the pixels to trace; set to True at the tested pixels.
    """
    for q in range(cells.shape[0]):
        yc, xc, _, edged, edges = _tested_pixels(cells[q, 0], cells[q, 1], cells[q, 2], cells[q, 3], nx, edge_size)
        wanted[yc * nx + xc] = True
        if edged:
            for p in edges:
                wanted[p] = True


@njit(**_JIT)
def split_cells(cells, smooth, nx, edge_size, wanted):
    """The next level of the quadtree: the four children of each cell that is not smooth, and the pixels they need.

    A cell splits at its centre (``yc = (y0 + y1) // 2``, ``xc`` alike) into its top-left, top-right, bottom-left
    and bottom-right quarters; the children are ordered by quarter first, then by their parent's order in
    ``cells`` (as :func:`swim.rt.image_sampling.sample_image_adaptive` stacked them). A child without area (a parent
    one pixel high or wide splits only across) or without a pixel between its corners (at most 2 x 2 pixels) is
    dropped. ``wanted`` is set at the midpoints of the split cells' four edges and at the children's tested pixels
    (:func:`mark_tested`).

    Parameters
    ----------
    cells : numpy.ndarray
        Shape (m, 4) int64: the level's cells (y0, y1, x0, x1) [pixels].
    smooth : numpy.ndarray
        Shape (m,) bool: the cells that are interpolated (not split).
    nx, edge_size
        As :func:`mark_tested`.
    wanted : numpy.ndarray
        Shape (ny * nx,) bool: the pixels to trace, set in place.

    Returns
    -------
    numpy.ndarray
        Shape (k, 4) int64: the children, k <= 4 (m - smooth.sum()).
    """
    n_split = 0
    for q in range(cells.shape[0]):
        if not smooth[q]:
            n_split += 1
    children = np.empty((4 * n_split, 4), np.int64)
    k = 0
    for quarter in range(4):
        for q in range(cells.shape[0]):
            if smooth[q]:
                continue
            y0, y1, x0, x1 = cells[q, 0], cells[q, 1], cells[q, 2], cells[q, 3]
            yc, xc = (y0 + y1) // 2, (x0 + x1) // 2
            if quarter == 0:  # the split cell's edge midpoints, once
                wanted[y0 * nx + xc] = True
                wanted[y1 * nx + xc] = True
                wanted[yc * nx + x0] = True
                wanted[yc * nx + x1] = True
            top, bottom = (y0, yc) if quarter < 2 else (yc, y1)
            left, right = (x0, xc) if quarter % 2 == 0 else (xc, x1)
            if bottom > top and right > left and (bottom - top > 1 or right - left > 1):
                children[k, 0], children[k, 1], children[k, 2], children[k, 3] = top, bottom, left, right
                k += 1
    children = children[:k]
    mark_tested(children, nx, edge_size, wanted)
    return children
