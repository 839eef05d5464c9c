"""The optical volume's passes over whole grids, compiled (numba): the column weights, the content's scan and the
resampling of a block of columns onto the regular levels.

:func:`swim.optics.volume.build_optical_volume` reads every species' content once per new scene. In NumPy each of its
steps was a pass of its own over a block of rows (the content's minimum and maximum, the mask of cloudy cells, their
values, a zeroed extinction array, the scatter into it, one ``take`` per target level), and the weights of the
resampling were found by one ``searchsorted`` per model level: 1.0-1.4 s for the 400 x 400 x 60 scene with all five
species on this project's 2 cores. These kernels do each in one pass (0.39-0.50 s) and give the same bits: the weights
and the interpolation in float32, operation by operation as NumPy rounds them (no fast-math, so no contraction into
FMAs), and the physics of Eq. 7 stays in :mod:`swim.optics.hydrometeors`, on the cloudy cells only
(docs/decisions/0007-scene-set-up.md).

They release the GIL, so :func:`swim.workers.in_blocks` and :func:`swim.workers.parallel_map` run them on every core,
a block of columns each.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..compilation.numba_jit import JIT_EXACT  # also puts numba's disk cache where swim keeps it


@njit(**JIT_EXACT)
def column_weights(height, levels, top, terrain, k0, w, zero):  # pragma: no cover - compiled
    """The weights of :class:`swim.optics.volume.ColumnInterpolation` for a block of columns.

    Parameters
    ----------
    height : numpy.ndarray
        Shape (nz, n) float64: the model levels' heights [m] in each column, strictly increasing along the first axis.
    levels : numpy.ndarray
        Shape (nk,) float64: the regular levels [m], increasing.
    top, terrain : numpy.ndarray
        Shape (n,) float64 [m]: the height above which a column is empty (half a layer over its top level) and the
        terrain's height.
    k0 : numpy.ndarray
        Shape (nk, n) int32, written: the last model level below each regular level, within [0, nz - 2].
    w : numpy.ndarray
        Shape (nk, n) float32, written: the weight of level ``k0 + 1``, within [0, 1].
    zero : numpy.ndarray
        Shape (nk, n) bool, written: regular levels above ``top`` or below the terrain.
    """
    nz, n = height.shape
    below = np.zeros(n, np.int64)  # per column: the model levels strictly below the current regular level
    for k in range(levels.shape[0]):
        level = levels[k]
        level32 = np.float32(level)
        for c in range(n):
            z = below[c]
            while z < nz and height[z, c] < level:  # the levels increase along both axes: a merge
                z += 1
            below[c] = z
            lo = min(max(z, 1), nz - 1) - 1
            k0[k, c] = lo
            h0 = np.float32(height[lo, c])
            x = (level32 - h0) / (np.float32(height[lo + 1, c]) - h0)
            if x < 0:  # np.clip's result, NaN kept
                x = np.float32(0.0)
            elif x > 1:
                x = np.float32(1.0)
            w[k, c] = x
            zero[k, c] = level > top[c] or level < terrain[c]


@njit(**JIT_EXACT)
def scan_content(content, where, values):  # pragma: no cover - compiled
    """The cloudy cells of a block of a species' content, in one pass.

    Parameters
    ----------
    content : numpy.ndarray
        Shape (nz, ny, nx) float64 [kg m-3] (any strides).
    where : numpy.ndarray
        Shape (>= nz ny nx,) int64, written: the flat positions (C order of ``content``'s shape) of the cells with
        content > 0, in increasing order, in its first ``present`` elements.
    values : numpy.ndarray
        Shape like ``where``, float64, written: their contents [kg m-3].

    Returns
    -------
    bad : int
        Cells that are negative or not finite (NaN, infinite).
    present : int
        Cells with content > 0 (and finite).
    """
    nz, ny, nx = content.shape
    bad = 0
    present = 0
    flat = 0
    for z in range(nz):
        for j in range(ny):
            for i in range(nx):
                v = content[z, j, i]
                if v > 0.0:
                    if v == np.inf:
                        bad += 1
                    else:
                        where[present] = flat
                        values[present] = v
                        present += 1
                elif not v == 0.0:  # negative or NaN
                    bad += 1
                flat += 1
    return bad, present


@njit(**JIT_EXACT)
def gather_cells(field, where, out):  # pragma: no cover - compiled
    """``out[m] = field.ravel()[where[m]]`` for a field (nz, ny, nx) of any strides (no copy of the field)."""
    _, ny, nx = field.shape
    for m in range(out.shape[0]):
        p = where[m]
        z, rest = divmod(p, ny * nx)
        j, i = divmod(rest, nx)
        out[m] = field[z, j, i]


@njit(**JIT_EXACT)
def resample_cells(where, beta, nz, k0, w, zero, first, stop, out):  # pragma: no cover - compiled
    """A block of columns of a sparse field on the regular levels, as :meth:`ColumnInterpolation.columns` gives it.

    Parameters
    ----------
    where : numpy.ndarray
        Shape (m,) int64: the flat positions (z, column) of the field's non-zero cells in the block, increasing
        (:func:`scan_content`).
    beta : numpy.ndarray
        Shape (m,) float32: their values.
    nz : int
        Model levels.
    k0, w, zero : numpy.ndarray
        Shape (nk, n): the block's columns of :class:`~swim.optics.volume.ColumnInterpolation`'s weights.
    first, stop : int
        The regular levels that may read a non-zero cell: the others stay 0.
    out : numpy.ndarray
        Shape (nk, n) float32, zeros, written: the field on the regular levels.
    """
    n = k0.shape[1]
    dense = np.zeros((nz, n), np.float32)
    lowest = np.full(n, nz, np.int64)  # per column: its lowest and highest non-zero model level
    highest = np.full(n, -1, np.int64)
    for m in range(where.shape[0]):
        z, c = divmod(where[m], n)
        dense[z, c] = beta[m]
        lowest[c] = min(lowest[c], z)
        highest[c] = max(highest[c], z)
    for k in range(first, stop):
        for c in range(n):
            lo = k0[k, c]
            if lo + 1 < lowest[c] or lo > highest[c] or zero[k, c]:
                continue  # reads two zeros (or lies outside the column): stays 0
            lower = dense[lo, c]
            out[k, c] = (dense[lo + 1, c] - lower) * w[k, c] + lower  # NumPy's order: difference, product, sum
