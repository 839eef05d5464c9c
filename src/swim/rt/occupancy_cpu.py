"""The occupancy grid of the empty-space skipping (:func:`swim.rt.march.occupancy_grid`) written for CPUs (numba).

A new scene's occupancy grid summed the species' extinction as one float32 matrix-vector product per cell (one
thread), compared the sum with :data:`swim.rt.march.OCCUPIED_EXTINCTION` and the levels with the raised terrain in
further whole-grid passes: ~0.22 s of a new 400 x 400 x 60 scene's set-up. :func:`occupied_cells` decides each cell
in one pass over the packed volume's species channels (a cell's channels are one cache line), in blocks of levels
on every core, without the GIL (docs/performance.md, section 71).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .march_cpu import _JIT_EXACT


@njit(**_JIT_EXACT)
def occupied_cells(extinction, threshold, levels, terrain_top, dz, k0, k1, out):  # pragma: no cover - compiled
    """Levels ``k0:k1`` of the cells that rays must step through finely, before the dilation of
    :func:`swim.rt.march.occupancy_grid`: ``out[k, j, i]`` (bool, (level, y, x)) is True where the species'
    ``extinction`` (species, level, y, x) float32 [m-1], any strides, summed in float32 in the species' order,
    exceeds ``threshold`` (float32 [m-1]), or where ``terrain_top`` (y, x) [m] (the highest terrain around the
    column) is above 1 m and ``levels[k]`` [m] lies at most ``dz`` [m] above it; else False.

    The float32 sum is the matrix-vector product's of the code before it, up to the order of its additions (float32
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


@njit(**_JIT_EXACT)
def unlit_nodes(cloud_transmittance, terrain_shadow, aerosol_tau_sun, has_aerosol, threshold, k0, k1,
                out):  # pragma: no cover - compiled
    """Levels ``k0:k1`` of the nodes that the direct sun does not reach unattenuated, before the dilation of
    :func:`swim.rt.march.step_classes`: ``out[k, j, i]`` (bool, (level, y, x)) is True where Step 1a's
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


@njit(**_JIT_EXACT)
def classify_cells(occupancy, unlit, code, k0, k1, out):  # pragma: no cover - compiled
    """Levels ``k0:k1`` of the step classes of :func:`swim.rt.march.step_classes`: ``out`` (int8, (level, y, x)) is 1
    where ``occupancy`` > 0, else 0 where ``unlit`` (dilated), else ``code`` (sunlit clear air)."""
    _, ny, nx = occupancy.shape
    for k in range(k0, k1):
        for j in range(ny):
            for i in range(nx):
                out[k, j, i] = 1 if occupancy[k, j, i] > 0 else (0 if unlit[k, j, i] else code)
