"""Adaptive sampling's interpolation of its smooth cells, one pixel at a time on the CPU (numba).

Interpolating each output in NumPy (per cell size, index and weight arrays for every target pixel, then four
gathers and three products per pixel and output array, each a pass with temporaries) took 0.17 s of a warm 1024^2
adaptive all-sky on 2 cores (~810 000 target pixels, 13 float channels), at the end of the render while the march's
threads were idle. This kernel walks the cells and their pixels and does the same float32 arithmetic in one pass over
all the float outputs, the pixels' weights computed once, on bands of rows in parallel
(docs/decisions/0009-work-around-the-march.md).

Bit for bit NumPy's result: the weights are computed in float64 as ``dy / h`` and ``dx / w`` and rounded once to
float32, and the four corners' products are summed in the same order, without fused multiply-adds.

A cell whose centre is traced and strictly inside it (the centre test's pixel) is interpolated through that centre
too: the corners' bilinear value plus the centre's residual times a bump that is 1 at the centre,
0 on the cell's edges and bilinear on each quarter the centre makes (:func:`_centre_bump`). The edges stay the
corners' lines, so neighbouring cells still agree along them (docs/decisions/0005-adaptive-sampling.md).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..compilation.numba_jit import JIT_EXACT as _JIT


@njit(**_JIT)
def fill_cells(arrays, cells, traced, valid, nx, y_lo, y_hi):
    """Bilinear interpolation of the untraced, valid pixels of cells from their corners, in place, in the pixel rows
    ``y_lo <= y < y_hi``: every array of ``arrays`` with the weights computed once per pixel. Where a cell's centre
    ``(y0 + h // 2, x0 + w // 2)`` is traced and strictly inside it (h, w >= 2), its inner pixels add the centre's
    residual (its value less the corners' value there, in the values' precision) times :func:`_centre_bump`, rounded
    once to that precision; not where the residual is not finite.

    Parameters
    ----------
    arrays : tuple of numpy.ndarray
        Each of shape (ny * nx, C) (C may differ), all float32 or all float64: outputs of the sampler, their traced
        pixels set; the cells' other pixels are written. Cells later in ``cells`` overwrite the pixels they share
        with earlier ones (a pixel on the edge of a coarse and a fine cell takes the fine cell's value when the
        levels come coarse to fine).
    cells : numpy.ndarray
        Shape (m, 4) int64: the cells' first and last rows and columns (y0, y1, x0, x1) [pixels], y1 > y0 and
        x1 > x0, within the image.
    traced, valid : numpy.ndarray
        Shape (ny * nx,) bool: the pixels that were traced (kept) and those that have a ray (the others are not
        written).
    nx : int
        Image width [pixels].
    y_lo, y_hi : int
        The rows [pixels] written: threads that take disjoint bands of rows write disjoint pixels, each in the
        cells' order, so together they give what one pass over all rows gives.
    """
    weights = np.empty(4, arrays[0].dtype)  # assigned in float64, each rounded once to the values' precision
    centre_weights = np.empty(4, arrays[0].dtype)
    bump = np.empty(1, arrays[0].dtype)
    channels = 0
    for values in arrays:
        channels = max(channels, values.shape[1])
    residuals = np.empty((len(arrays), channels), arrays[0].dtype)  # a centred cell's, per array and channel
    for q in range(cells.shape[0]):
        y0, y1, x0, x1 = cells[q, 0], cells[q, 1], cells[q, 2], cells[q, 3]
        if y1 < y_lo or y0 >= y_hi:
            continue
        h, w = y1 - y0, x1 - x0
        c00 = y0 * nx + x0
        c01, c10, c11 = c00 + w, c00 + h * nx, c00 + h * nx + w
        # a traced centre strictly inside the cell (the centre test's pixel): the bump through it (_centre_bump)
        yc, xc = y0 + h // 2, x0 + w // 2
        centred = h >= 2 and w >= 2 and traced[yc * nx + xc]
        if centred:
            wy, wx = (yc - y0) / h, (xc - x0) / w
            centre_weights[0] = (1 - wx) * (1 - wy)
            centre_weights[1] = wx * (1 - wy)
            centre_weights[2] = (1 - wx) * wy
            centre_weights[3] = wx * wy
            k = 0
            for values in arrays:  # the centre's value less the corners' value there
                for c in range(values.shape[1]):
                    at_centre = values[c00, c] * centre_weights[0]
                    at_centre += values[c01, c] * centre_weights[1]
                    at_centre += values[c10, c] * centre_weights[2]
                    at_centre += values[c11, c] * centre_weights[3]
                    residuals[k, c] = values[yc * nx + xc, c] - at_centre
                k += 1
        for dy in range(max(y0, y_lo) - y0, min(y1, y_hi - 1) - y0 + 1):
            wy = dy / h
            for dx in range(w + 1):
                pix = c00 + dy * nx + dx
                if traced[pix] or not valid[pix]:
                    continue
                wx = dx / w
                weights[0] = (1 - wx) * (1 - wy)
                weights[1] = wx * (1 - wy)
                weights[2] = (1 - wx) * wy
                weights[3] = wx * wy
                w00, w01, w10, w11 = weights[0], weights[1], weights[2], weights[3]
                inside = centred and 0 < dy < h and 0 < dx < w
                if inside:
                    bump[0] = _centre_bump(dy, dx, h // 2, w // 2, h, w)
                k = 0
                for values in arrays:
                    for c in range(values.shape[1]):
                        acc = values[c00, c] * w00
                        acc += values[c01, c] * w01
                        acc += values[c10, c] * w10
                        acc += values[c11, c] * w11
                        if inside and np.isfinite(residuals[k, c]):
                            acc += residuals[k, c] * bump[0]
                        values[pix, c] = acc
                    k += 1


@njit(**_JIT)
def _centre_bump(dy, dx, cy, cx, h, w):
    """The bump [-] at the pixel (dy, dx) of a cell h x w pixels whose centre is (cy, cx), all relative to its first
    corner: 1 at the centre, 0 on the cell's edges, bilinear on each of the four quarters that the centre makes
    (float64)."""
    ty = dy / cy if dy <= cy else (h - dy) / (h - cy)
    tx = dx / cx if dx <= cx else (w - dx) / (w - cx)
    return ty * tx


@njit(**_JIT)
def fill_cells_from_corner(values, cells, traced, valid, nx, zero):
    """The untraced, valid pixels of cells set to 0 (``zero``) or to the value at the cell's first corner, in place:
    :func:`fill_cells` for outputs that are not interpolated (booleans, on which a smooth cell's corners agree;
    integer counts of work done, 0 where none was done).

    Parameters
    ----------
    values : numpy.ndarray
        Shape (ny * nx,) bool or integer.
    cells, traced, valid, nx
        As :func:`fill_cells`.
    zero : bool
        Set 0 rather than the first corner's value.
    """
    for q in range(cells.shape[0]):
        y0, y1, x0, x1 = cells[q, 0], cells[q, 1], cells[q, 2], cells[q, 3]
        corner = values[y0 * nx + x0]
        for y in range(y0, y1 + 1):
            for pix in range(y * nx + x0, y * nx + x1 + 1):
                if not traced[pix] and valid[pix]:
                    if zero:
                        values[pix] = 0
                    else:
                        values[pix] = corner


@njit(**_JIT)
def scatter_rows(image, pixels, rows):
    """``image[pixels] = rows``, in place: a batch's traced outputs written into the sampler's image array.

    NumPy's fancy assignment of a 1024^2 all-sky's ~200 000 traced rows into its 7 image arrays took ~26 ms of the
    render, on the main thread while the march's threads waited; this loop, one array per thread, ~5 ms
    (docs/decisions/0009-work-around-the-march.md).

    Parameters
    ----------
    image : numpy.ndarray
        Shape (ny * nx, C): one output of the sampler (a 1-D output as (ny * nx, 1)).
    pixels : numpy.ndarray
        Shape (m,) int64: flat pixel indices, each within the image.
    rows : numpy.ndarray
        Shape (m, C), of the image's dtype: the values of those pixels.
    """
    for q in range(pixels.shape[0]):
        pix = pixels[q]
        for c in range(rows.shape[1]):
            image[pix, c] = rows[q, c]
