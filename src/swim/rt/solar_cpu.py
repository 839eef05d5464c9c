"""The Step 1a sweep of :mod:`swim.rt.solar` written for CPUs (numba).

:func:`swim.rt.solar._sweep` integrates the extinction along the sun ray from every grid point: 16 levels
directly (one bilinear lookup per level and sub-step) plus the optical depth 16 levels up, interpolated. In JAX
on a CPU that costs ~7 ns per lookup (a loop over levels of whole-field operations, each written to memory),
~10 s for a 400 x 400 x 60 grid (docs/decisions/0007-scene-set-up.md). Every point of a level shares the same
sun-ward shift, so the lookups of a grid row are a stencil with four constant weights over contiguous memory,
which a compiled loop vectorises: this module computes the same sums ~5x faster (Step 1a as a whole ~3x), the
measurement the project's rule asks for before numba is used ("numba only where a measurement shows JAX cannot
serve").

The work is split in two: the direct integrals of every level (rows independent, one block of rows per core,
without the GIL), then, level by level from the top, the optical depth interpolated from the level ``block`` above
(a sequential dependency, one lookup per point; one swept field per core). Both follow
Albers et al. (2020), doi:10.5194/amt-13-3235-2020, Sect. 3.4 (Step 1a), as :func:`swim.rt.solar._sweep` does;
``tests/unit/rt/test_rt_solar.py`` holds the two to each other.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..workers import in_blocks
from .solar import ONE_MINUS_G_PER_BACKSCATTER
from ..compilation.numba_jit import JIT_EXACT, JIT_KERNEL, helper_jit


@helper_jit()
def _span(shift, n):
    """Points q of range(n) whose shifted position q + shift lies in [0, n - 1], as (first, end), and the
    position's integer offset and fraction."""
    floor = math.floor(shift)
    first = max(0, int(math.ceil(-shift)))
    end = min(n - 1, int(math.floor(n - 1 - shift))) + 1
    return first, end, int(floor), shift - floor


@njit(**JIT_KERNEL, nogil=True)
def _direct_rows(fields, taus, ny, nx, di, dj, scale, n_sub, block, midpoints, row_first, row_end):
    """``taus[k, :, j, :nx]`` = ``scale`` x the extinction ``fields`` (C, nk, ny + 1, nx + 1; zero last row and
    column) summed along the sun ray over the ``block`` levels above level k (``n_sub`` points per level, linear
    between the levels, bilinear across), for the rows j in [row_first, row_end) of every level k.

    With ``midpoints`` (one point per level), ``fields[:, k]`` already holds the mean of levels k and k + 1
    (:func:`sweep`): each point is then 4 reads instead of 8.

    The sums are taken in float32, the fields' type, as the JAX sweep takes them: in float64 every term would be a
    conversion and the vectorised loop half as wide (the sweep 0.31-0.37 s against 0.47-0.59 s for the
    400 x 400 x 60 scene, the optical depths within 8e-7 relative; docs/decisions/0007-scene-set-up.md)."""
    c, nk = fields.shape[0], fields.shape[1]
    scale32 = np.float32(scale)
    acc = np.empty(nx, np.float32)
    for k in range(nk - 1):
        for j in range(row_first, row_end):
            for ch in range(c):
                acc[:] = 0.0
                for m in range(block):
                    if k + m + 1 > nk - 1:
                        break
                    lower = fields[ch, k + m]
                    upper = fields[ch, k + m + 1]
                    for q in range(n_sub):
                        t = (q + 0.5) / n_sub
                        jj = j + (m + t) * dj
                        if jj < 0 or jj > ny - 1:
                            continue  # zero outside the grid
                        j0 = int(math.floor(jj))
                        fj = jj - j0
                        first, end, offset, fi = _span((m + t) * di, nx)
                        w00, w01, w10, w11 = (np.float32((1 - fj) * (1 - fi)), np.float32((1 - fj) * fi),
                                              np.float32(fj * (1 - fi)), np.float32(fj * fi))
                        t32 = np.float32(t)
                        # the stencil's four rows as 1-D slices indexed from 0: LLVM then vectorises the loop
                        # (indexed by i + offset, it stayed scalar: ~4x slower; docs/decisions/0007-scene-set-up.md)
                        n, x0 = end - first, first + offset
                        out = acc[first:end]
                        a0, a1 = lower[j0, x0:x0 + n], lower[j0, x0 + 1:x0 + 1 + n]
                        b0, b1 = lower[j0 + 1, x0:x0 + n], lower[j0 + 1, x0 + 1:x0 + 1 + n]
                        if midpoints:
                            for i in range(n):
                                out[i] += w00 * a0[i] + w01 * a1[i] + w10 * b0[i] + w11 * b1[i]
                            continue
                        c0, c1 = upper[j0, x0:x0 + n], upper[j0, x0 + 1:x0 + 1 + n]
                        d0, d1 = upper[j0 + 1, x0:x0 + n], upper[j0 + 1, x0 + 1:x0 + 1 + n]
                        for i in range(n):
                            out[i] += (w00 * (a0[i] + t32 * (c0[i] - a0[i])) + w01 * (a1[i] + t32 * (c1[i] - a1[i]))
                                       + w10 * (b0[i] + t32 * (d0[i] - b0[i])) + w11 * (b1[i] + t32 * (d1[i] - b1[i])))
                for i in range(nx):
                    taus[k, ch, j, i] = acc[i] * scale32


@njit(**JIT_KERNEL, nogil=True)
def _add_above(taus, ny, nx, di, dj, block, ch_first, ch_end):
    """Level by level from the top: add to ``taus[k]`` the optical depth of level min(k + block, top), bilinearly
    interpolated where the sun ray from level k crosses it (zero outside the grid), for the fields (channels)
    ``ch_first:ch_end``: the fields are independent, so each may be a thread's."""
    nk = taus.shape[0]
    for n in range(nk - 1):
        k = nk - 2 - n
        top = min(k + block, nk - 1)
        levels = top - k
        first, end, offset, fi = _span(levels * di, nx)
        for j in range(ny):
            jj = j + levels * dj
            if jj < 0 or jj > ny - 1:
                continue
            j0 = int(math.floor(jj))
            fj = jj - j0
            n, x0 = end - first, first + offset
            for ch in range(ch_first, ch_end):
                above = taus[top, ch]
                out = taus[k, ch, j, first:end]  # 1-D slices indexed from 0, as in _direct_rows
                a0, a1 = above[j0, x0:x0 + n], above[j0, x0 + 1:x0 + 1 + n]
                b0, b1 = above[j0 + 1, x0:x0 + n], above[j0 + 1, x0 + 1:x0 + 1 + n]
                for i in range(n):
                    out[i] += (a0[i] * (1 - fi) + a1[i] * fi) * (1 - fj) + (b0[i] * (1 - fi) + b1[i] * fi) * fj


@helper_jit()
def _bilinear(field, a, b, ny, nx, jj, ii):
    """Bilinear sample of ``field[a, b]`` (a 4-D array whose last two axes are ny + 1, nx + 1 with a zero last row and
    column) at the fractional (jj, ii); zero outside the grid's (ny, nx) points. Scalar reads only (no views, so no
    reference counts inside the callers' loops)."""
    if jj < 0 or jj > ny - 1 or ii < 0 or ii > nx - 1:
        return np.float32(0.0)
    j0 = int(math.floor(jj))
    i0 = int(math.floor(ii))
    fj = np.float32(jj - j0)
    fi = np.float32(ii - i0)
    one = np.float32(1.0)
    return ((field[a, b, j0, i0] * (one - fi) + field[a, b, j0, i0 + 1] * fi) * (one - fj)
            + (field[a, b, j0 + 1, i0] * (one - fi) + field[a, b, j0 + 1, i0 + 1] * fi) * fj)


@njit(**JIT_KERNEL, nogil=True)
def _direct_columns(fields, taus, ny, nx, di, dj, scale, n_sub, block, midpoints, row_first, row_end):
    """:func:`_direct_rows` with each column's own shift ``di``, ``dj`` (ny, nx) [grid indices per level] and scale
    ``scale`` (ny, nx) [m per point]: the sun ray of a grid that spans a noticeable part of the sphere
    (:func:`swim.rt.solar.column_sweep_geometry`). One column at a time, scalar reads, the bilinear weights of a point
    shared by the fields (the stencil's weights differ from column to column, so the rows are no longer a vectorised
    stencil): slower than :func:`_direct_rows`, and taken only for such grids."""
    c, nk = fields.shape[0], fields.shape[1]
    acc = np.zeros(c, np.float32)  # made once, outside the loops
    one = np.float32(1.0)
    for k in range(nk - 1):
        for j in range(row_first, row_end):
            for i in range(nx):
                sdi = di[j, i]
                sdj = dj[j, i]
                for ch in range(c):
                    acc[ch] = 0.0
                for m in range(block):
                    if k + m + 1 > nk - 1:
                        break
                    for q in range(n_sub):
                        t = (q + 0.5) / n_sub
                        jj = j + (m + t) * sdj
                        ii = i + (m + t) * sdi
                        if jj < 0 or jj > ny - 1 or ii < 0 or ii > nx - 1:
                            continue  # zero outside the grid
                        j0 = int(math.floor(jj))
                        i0 = int(math.floor(ii))
                        fj = np.float32(jj - j0)
                        fi = np.float32(ii - i0)
                        w00, w01, w10, w11 = (one - fj) * (one - fi), (one - fj) * fi, fj * (one - fi), fj * fi
                        t32 = np.float32(t)
                        for ch in range(c):
                            low = (w00 * fields[ch, k + m, j0, i0] + w01 * fields[ch, k + m, j0, i0 + 1]
                                   + w10 * fields[ch, k + m, j0 + 1, i0] + w11 * fields[ch, k + m, j0 + 1, i0 + 1])
                            if midpoints:
                                acc[ch] += low
                            else:
                                up = (w00 * fields[ch, k + m + 1, j0, i0] + w01 * fields[ch, k + m + 1, j0, i0 + 1]
                                      + w10 * fields[ch, k + m + 1, j0 + 1, i0]
                                      + w11 * fields[ch, k + m + 1, j0 + 1, i0 + 1])
                                acc[ch] += low + t32 * (up - low)
                s32 = np.float32(scale[j, i])
                for ch in range(c):
                    taus[k, ch, j, i] = acc[ch] * s32


@njit(**JIT_KERNEL, nogil=True)
def _add_above_columns(taus, ny, nx, di, dj, block, ch_first, ch_end):
    """:func:`_add_above` with each column's own shift ``di``, ``dj`` (ny, nx) [grid indices per level]."""
    nk = taus.shape[0]
    for n in range(nk - 1):
        k = nk - 2 - n
        top = min(k + block, nk - 1)
        levels = top - k
        for j in range(ny):
            for i in range(nx):
                jj = j + levels * dj[j, i]
                ii = i + levels * di[j, i]
                for ch in range(ch_first, ch_end):
                    taus[k, ch, j, i] += _bilinear(taus, top, ch, ny, nx, jj, ii)


@njit(**JIT_EXACT)
def species_sums(extinction, weights, k0, k1, total, weighted):  # pragma: no cover - compiled
    """The sweep's first two fields for levels ``k0:k1``, in one pass over the species: ``total`` = the sum over the
    species of ``extinction`` (species, level, y, x) [m-1] and ``weighted`` = its sum weighted by ``weights``
    (species,) float32 (the backscatter fractions), each (k1 - k0, y, x) float32 (any strides), in float32.

    Where the species are channels of the packed volume (adjacent in memory,
    :func:`swim.rt.march_inputs.share_packed_channels`), each cell's species are one cache line's read for both sums:
    two sums over the species (one a weighted sum) would read the volume twice (the fill of a new sun's Step 1a for the
    400 x 400 x 60 scene 0.12-0.14 s against 0.17-0.18 s; docs/decisions/0007-scene-set-up.md)."""
    n, _, ny, nx = extinction.shape
    for k in range(k0, k1):
        for j in range(ny):
            for i in range(nx):
                a = np.float32(0.0)
                b = np.float32(0.0)
                for c in range(n):
                    value = extinction[c, k, j, i]
                    a += value
                    b += weights[c] * value
                total[k - k0, j, i] = a
                weighted[k - k0, j, i] = b


@njit(**JIT_EXACT)
def step1a_channels(k0, k1, mu0, n_hydro, tau, b_tau, n_terrain, terrain_tau, n_aerosol, aerosol_tau, cloud_t,
                    shadow, aerosol, write_cloud, write_shadow, write_aerosol,
                    direct_beam):  # pragma: no cover - compiled
    """Levels ``k0:k1`` of the render's three Step 1a fields from the swept optical depths, written in one pass:
    ``cloud_t`` = T (:func:`swim.rt.solar.transmittance_delta_eddington`, in float32 as the JAX function), ``shadow``
    = e^-(the terrain's optical depth) and ``aerosol`` = the 3-D aerosol's optical depth towards the sun, each
    (nk, ny, nx) float32 of any strides (the packed volume's channels: a cell's channels one cache line's write).

    The swept fields (``tau``, ``b_tau``, ``terrain_tau``, ``aerosol_tau``: (levels, ny, nx) float32, any strides)
    hold their first ``n_hydro``, ``n_terrain`` and ``n_aerosol`` levels; above them T and the shadow are 1 and the
    aerosol's optical depth 0 (0 levels: a field that nothing makes). An output whose ``write_*`` flag is False is
    not written. In NumPy, each field was made whole and then copied into the packed volume's channel: three
    strided passes over it (docs/decisions/0007-scene-set-up.md). With ``direct_beam``, ``cloud_t`` is the direct beam's
    e^-b_tau instead (``b_tau`` then the delta-M scaled optical depth, :func:`swim.rt.solar.solar_transmittance`)."""
    ny, nx = cloud_t.shape[1], cloud_t.shape[2]
    c73 = np.float32(ONE_MINUS_G_PER_BACKSCATTER)
    k_mu = np.float32(0.5) + np.float32(0.75) * mu0
    one_minus_k = np.float32(1.0) - k_mu
    three_mu = np.float32(0.75) * mu0
    one = np.float32(1.0)
    tiny = np.float32(1e-30)
    for k in range(k0, k1):
        for j in range(ny):
            if write_cloud:
                if k < n_hydro and direct_beam:
                    for i in range(nx):
                        cloud_t[k, j, i] = np.exp(-b_tau[k, j, i])
                elif k < n_hydro:
                    for i in range(nx):
                        x = c73 * b_tau[k, j, i]  # (1 - g) tau_s
                        one_minus_g = min(max(x / max(tau[k, j, i], tiny), np.float32(0.0)), one)
                        tau_prime = x * (np.float32(2.0) - one_minus_g)
                        cloud_t[k, j, i] = (k_mu + one_minus_k * np.exp(-tau_prime)) / (one + three_mu * x)
                else:
                    for i in range(nx):
                        cloud_t[k, j, i] = one
            if write_shadow:
                if k < n_terrain:
                    for i in range(nx):
                        shadow[k, j, i] = np.exp(-terrain_tau[k, j, i])
                else:
                    for i in range(nx):
                        shadow[k, j, i] = one
            if write_aerosol:
                if k < n_aerosol:
                    for i in range(nx):
                        aerosol[k, j, i] = aerosol_tau[k, j, i]
                else:
                    for i in range(nx):
                        aerosol[k, j, i] = np.float32(0.0)


def sweep(fields, di, dj, path_per_level, n_sub, block):
    """:func:`swim.rt.solar._sweep` on the CPU.

    Parameters
    ----------
    fields : numpy.ndarray
        Shape (C, nk, ny + 1, nx + 1), float32: the extinctions [m-1] of the grid's (ny, nx) columns with a zero
        last row and column (so that a lookup on the grid's far edge reads a zero weight's neighbour in bounds).
        Overwritten with one point per level (``n_sub`` 1).
    di, dj : float or numpy.ndarray
        Shift [grid indices] of the sun ray per level climbed: one for the grid, or (ny, nx) arrays, each column's
        own (:func:`swim.rt.solar.column_sweep_geometry`; :func:`_direct_columns`, :func:`_add_above_columns`).
    path_per_level : float or numpy.ndarray
        Path length [m] along the sun ray per level: one, or (ny, nx) with the per-column shifts.
    n_sub : int
        Points per level of the direct integral.
    block : int
        Levels integrated directly (:data:`swim.rt.solar.DIRECT_LEVELS`).

    Returns
    -------
    numpy.ndarray
        Optical depths towards the sun [-], (nk, C, ny + 1, nx + 1) float32; the last row and column are padding.
    """
    c, nk, ny1, nx1 = fields.shape
    ny, nx = ny1 - 1, nx1 - 1
    taus = np.zeros((nk, c, ny1, nx1), np.float32)
    scale = float(path_per_level) / n_sub if np.ndim(path_per_level) == 0 else None
    midpoints = int(n_sub) == 1
    if midpoints:
        # One point per level, half-way between two levels: the mean of the two levels is taken once per level
        # here, in place from the bottom up (level k + 1 is still the input when level k is replaced), rather than
        # by each of the 16 rays through it (the direct integrals 1.4x faster: docs/decisions/0007-scene-set-up.md);
        # blocks of rows on every core (NumPy releases the GIL)
        def mean_of_levels(j0, j1):
            for k in range(nk - 1):
                fields[:, k, j0:j1] += fields[:, k + 1, j0:j1]
                fields[:, k, j0:j1] *= np.float32(0.5)

        in_blocks(mean_of_levels, ny1)
    if np.ndim(di) or np.ndim(dj) or np.ndim(path_per_level):  # each column's own sun
        di, dj = (np.ascontiguousarray(np.broadcast_to(a, (ny, nx)), np.float64) for a in (di, dj))
        scale = np.ascontiguousarray(np.broadcast_to(np.asarray(path_per_level, np.float64) / n_sub, (ny, nx)))
        args = (fields, taus, ny, nx, di, dj, scale, int(n_sub), int(block), midpoints)
        in_blocks(lambda j0, j1: _direct_columns(*args, j0, j1), ny)
        in_blocks(lambda c0, c1: _add_above_columns(taus, ny, nx, di, dj, int(block), c0, c1), c)
        return taus
    args = (fields, taus, ny, nx, float(di), float(dj), scale, int(n_sub), int(block), midpoints)
    in_blocks(lambda j0, j1: _direct_rows(*args, j0, j1), ny)  # blocks of rows on every core
    # the fields one per thread (levels must be added from the top down, one after the other)
    in_blocks(lambda c0, c1: _add_above(taus, ny, nx, float(di), float(dj), int(block), c0, c1), c)
    return taus
