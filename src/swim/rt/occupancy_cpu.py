"""The occupancy grid of the empty-space skipping (:func:`swim.rt.march_inputs.occupancy_grid`) written for CPUs (numba).

A new scene's occupancy grid summed the species' extinction as one float32 matrix-vector product per cell (one
thread), compared the sum with :data:`swim.rt.march_inputs.OCCUPIED_EXTINCTION` and the levels with the raised terrain in
further whole-grid passes: ~0.22 s of a new 400 x 400 x 60 scene's set-up. :func:`occupied_cells` decides each cell
in one pass over the packed volume's species channels (a cell's channels are one cache line), in blocks of levels
on every core, without the GIL (docs/decisions/0007-scene-set-up.md).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..compilation.numba_jit import JIT_EXACT


@njit(**JIT_EXACT)
def occupied_cells(extinction, threshold, levels, terrain_top, dz, k0, k1, out):  # pragma: no cover - compiled
    """Levels ``k0:k1`` of the cells that rays must step through finely, before the dilation of
    :func:`swim.rt.march_inputs.occupancy_grid`: ``out[k, j, i]`` (bool, (level, y, x)) is True where the species'
    ``extinction`` (species, level, y, x) float32 [m-1], any strides, summed in float32 in the species' order,
    exceeds ``threshold`` (float32 [m-1]), or where ``terrain_top`` (y, x) [m] (the highest terrain around the
    column) is above 1 m and ``levels[k]`` [m] lies at most ``dz`` [m] above it; else False.

    The float32 sum is a species-by-extinction matrix-vector product's, up to the order of its additions (float32
    round-off, which can move a cell only where its sum is within ~1e-7 relative of the threshold)."""
    n, _, ny, nx = extinction.shape
    for k in range(k0, k1):
        level = levels[k]
        for j in range(ny):
            for i in range(nx):
                total = np.float32(0.0)
                for c in range(n):
                    total += extinction[c, k, j, i]
                top = terrain_top[j, i]
                out[k, j, i] = total > threshold or (top > 1.0 and level <= top + dz)


@njit(**JIT_EXACT)
def unlit_nodes(cloud_transmittance, terrain_shadow, aerosol_tau_sun, has_aerosol, threshold, k0, k1,
                out):  # pragma: no cover - compiled
    """Levels ``k0:k1`` of the nodes that the direct sun does not reach unattenuated, before the dilation of
    :func:`swim.rt.march_inputs.step_classes`: ``out[k, j, i]`` (bool, (level, y, x)) is True where Step 1a's
    ``cloud_transmittance`` times ``terrain_shadow`` times, where ``has_aerosol``, exp(-``aerosol_tau_sun``) (each
    (level, y, x) float32, any strides) is below ``threshold`` (a NaN counts as below)."""
    _, ny, nx = cloud_transmittance.shape
    for k in range(k0, k1):
        for j in range(ny):
            for i in range(nx):
                t = np.float64(cloud_transmittance[k, j, i]) * terrain_shadow[k, j, i]
                if has_aerosol:
                    t *= np.exp(-np.float64(aerosol_tau_sun[k, j, i]))
                out[k, j, i] = not t >= threshold


@njit(**JIT_EXACT)
def classify_cells(occupancy, unlit, code, k0, k1, out):  # pragma: no cover - compiled
    """Levels ``k0:k1`` of the step classes of :func:`swim.rt.march_inputs.step_classes`: ``out`` (int8, (level, y, x)) is 1
    where ``occupancy`` > 0, else 0 where ``unlit`` (dilated), else ``code`` (sunlit clear air)."""
    _, ny, nx = occupancy.shape
    for k in range(k0, k1):
        for j in range(ny):
            for i in range(nx):
                out[k, j, i] = 1 if occupancy[k, j, i] > 0 else (0 if unlit[k, j, i] else code)


@njit(**JIT_EXACT)
def dilate_levels_across(mask, k0, k1, out):  # pragma: no cover - compiled
    """Levels ``k0:k1`` of a (level, y, x) ``mask`` of 0 and 1 (uint8) dilated by one cell across each level:
    ``out[k, j, i]`` is 1 where ``mask[k]`` is 1 in the 3 x 3 square around (j, i) (clipped at the edges). The
    first half of :func:`dilate_cells`, whose levels are independent; bytewise ors without branches, which LLVM
    vectorises."""
    _, ny, nx = mask.shape
    row = np.empty(nx, np.uint8)
    for k in range(k0, k1):
        for j in range(ny):
            j_lo, j_hi = max(j - 1, 0), min(j + 1, ny - 1)
            for i in range(nx):  # the column's three rows or-ed
                row[i] = mask[k, j_lo, i] | mask[k, j, i] | mask[k, j_hi, i]
            if nx == 1:
                out[k, j, 0] = row[0]
                continue
            out[k, j, 0] = row[0] | row[1]
            for i in range(1, nx - 1):
                out[k, j, i] = row[i - 1] | row[i] | row[i + 1]
            out[k, j, nx - 1] = row[nx - 2] | row[nx - 1]


@njit(**JIT_EXACT)
def dilate_levels_along(across, k0, k1, out):  # pragma: no cover - compiled
    """Levels ``k0:k1`` of ``across`` (:func:`dilate_levels_across`'s result) or-ed with the levels below and above
    it: the second half of :func:`dilate_cells`."""
    nk, ny, nx = across.shape
    for k in range(k0, k1):
        k_lo, k_hi = max(k - 1, 0), min(k + 1, nk - 1)
        for j in range(ny):
            for i in range(nx):
                out[k, j, i] = across[k_lo, j, i] | across[k, j, i] | across[k_hi, j, i]


def dilate_cells(mask):
    """A (level, y, x) boolean array dilated by one cell: every cell next to a True cell (the 3 x 3 x 3 cube around
    it, clipped at the grid's edges) set, as :func:`swim.rt.march_inputs.dilated_by_one_cell` gives it, in two compiled
    passes over blocks of levels on every core (the 3 x 3 square of each level, then the levels below and above).

    Parameters
    ----------
    mask : numpy.ndarray
        Shape (level, y, x) bool.

    Returns
    -------
    numpy.ndarray
        Shape (level, y, x) bool, a new array.
    """
    from ..workers import in_blocks

    mask = np.ascontiguousarray(mask, dtype=bool).view(np.uint8)  # bytes of 0 and 1
    if mask.size == 0:  # an axis of no cells: nothing to dilate (the kernels index a row's first and last cells)
        return np.zeros(mask.shape, bool)
    across = np.empty_like(mask)
    in_blocks(lambda k0, k1: dilate_levels_across(mask, k0, k1, across), mask.shape[0])
    out = np.empty_like(mask)
    in_blocks(lambda k0, k1: dilate_levels_along(across, k0, k1, out), mask.shape[0])
    return out.view(bool)
