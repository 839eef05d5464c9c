"""Adaptive sampling's test of its cells, one cell at a time on the CPU (numba).

:func:`swim.rt.image_sampling._smooth_cells` decides which cells of a level are interpolated: their tested pixels
(the centre, and in cells of at least ``edge_test_size`` pixels the midpoints of the four edges) must match the
bilinear interpolation of the cell's corners in every channel of the radiance, the optical depth and the clear-air
radiance. In NumPy that test built per-cell index and weight arrays and gathered every corner and tested pixel of
every output channel, pass after pass: ~0.09 s of the 1024^2 synthetic all-sky's three levels, on the main thread
while the march's threads waited for the next batch. These kernels do the same float64 arithmetic per cell in one
pass (docs/performance.md, section 60).

Bit for bit NumPy's decision: the weights are computed in float64 as ``(yc - y0) / max(y1 - y0, 1)``, the
interpolation is summed corner by corner in the same order without fused multiply-adds (no fast-math), and a NaN
anywhere fails the test as NumPy's comparisons do.
"""

from __future__ import annotations

from numba import njit

from .march_cpu import _JIT_EXACT as _JIT


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
