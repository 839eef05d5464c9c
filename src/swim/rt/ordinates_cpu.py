"""The transport sweep of the 3-D diffuse solution (:mod:`swim.rt.diffuse_field`) for CPUs (numba).

One call sweeps the directions of one octant through the solver's grid in upwind order, for all three
wavelengths at once, and adds each direction's cell radiance, times its weight and spherical harmonics, to the
moments of the next iterate. The spatial scheme is the finite-volume "step" scheme: the balance of a cell

    sum_d a_d (I_out,d - I_in,d) + beta I = S,    a_d = |Omega_d| / Delta_d,

closed by I_out,d = I (the cell's radiance leaves through its downwind faces), so that

    I = (S + sum_d a_d I_in,d) / (beta + sum_d a_d),

positive for any cell thickness and exact in the limits of a transparent cell (pure advection) and an opaque one
(I = S / beta). Its numerical diffusion is first order in the cell size; the solver's vertical grid is refined
until no cell is optically thicker than ``max_cell_tau`` (:class:`swim.rt.diffuse_field.DiffuseSettings`),
where the scheme's error in thick layers is small (docs/decisions/0001-cloud-diffuse-solution.md).

The source S of a direction is the scattering of the current moments and of the direct beam,
S = sum_l sigma_l (sum_m Y_lm(Omega) I_lm + B p_l), with sigma_l = beta* omega* chi*_l of the cell, B the
direct beam's irradiance normal to it and p_l = sum_m Y_lm(Omega) Y_lm(Omega_sun).

References
----------
Lewis, E. E. and Miller, W. F. (1984): Computational Methods of Neutron Transport, Wiley, Ch. 4 (step and
diamond differencing on Cartesian meshes, sweeps by octant).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .march_cpu import _JIT_KERNEL


@njit(**_JIT_KERNEL, nogil=True)
def sweep_octant(sx, sy, sz, nz, ny, nx, beta, sigma, beam, phi_in, phi_out, harmonics, beam_phase, degree, weights,
                 ax, ay, az, inv_dz, side_x, side_y, ground_level, ground_emission, ground_flux, with_beam,
                 plane, row, column_radiance):  # pragma: no cover - compiled
    """Sweep the ``nq`` directions of one octant (signs ``sx``, ``sy``, ``sz`` of their x, y, z components) through a
    grid of ``nz`` x ``ny`` x ``nx`` cells, cell n = (k ny + j) nx + i of the flat arrays (one row per cell: its
    values per wavelength c, or per wavelength and moment, c nm + m).

    Parameters
    ----------
    beta : (n_cells, 3) float32
        Scaled extinction beta* [m-1] per wavelength.
    sigma : (n_cells, 3 (L + 1)) float32
        beta* omega* chi*_l [m-1].
    beam : (n_cells, 3) float32
        Direct-beam irradiance normal to the beam, relative to E_TOA [-] (the cell's mean).
    phi_in : (n_cells, 3 nm) float32
        Moments I_lm (per unit E_TOA) of the current diffuse radiance.
    phi_out : (n_cells, 3 nm) float32
        Moments of this sweep's radiance, added to.
    harmonics : (nq, nm) float64
        Y_lm of the octant's directions; ``degree`` (nm,) int64: l of each moment.
    beam_phase : (nq, L + 1) float64
        p_l of each direction.
    weights : (nq,) float64
        Solid angles [sr].
    ax, ay, az : (nq,) float64
        |Omega_x| / dx, |Omega_y| / dy [m-1] and |Omega_z| [-] (divided by the level's thickness, ``inv_dz``
        (nz,) [m-1]).
    side_x, side_y : (nz, 3 nq) float32
        Radiance entering through the grid's x and y sides (the clear surroundings), direction q, wavelength c at
        3 q + c.
    ground_level : (ny nx,) int64
        First cell above the ground of each column (cells below are solid and absorb what reaches their sides).
    ground_emission : (ny nx, 3) float32
        Radiance the ground emits upwards (Lambertian reflection), read by upward octants.
    ground_flux : (ny nx, 3) float64
        Downward diffuse flux onto the ground, added to by downward octants.
    with_beam : bool
        Include the direct beam's source.
    plane : (ny nx, 3 nq) float32, row : (nx, 3 nq) float32
        Work arrays: the radiance leaving the previous level and row.
    column_radiance : (nz, 3 nq) float32 or (0, 3 nq)
        Where it has nz rows, the radiance of each direction in the cells of column (0, 0) is written into it
        (the clear surroundings' radiance, from a one-column solve).
    """
    nq = harmonics.shape[0]
    nm = harmonics.shape[1]
    n_l = beam_phase.shape[1]
    nqc = 3 * nq
    # per cell: the moments weighted by their degree's scattering coefficient, and the beam's per degree
    psi = np.empty(3 * nm)
    beam_l = np.zeros(3 * n_l)
    value = np.empty(nqc)
    weighted = np.empty((nq, nm))  # w_q Y_lm(q): a direction's weight in each moment
    for q in range(nq):
        for m in range(nm):
            weighted[q, m] = weights[q] * harmonics[q, m]
    a_x = np.empty(nq)
    a_y = np.empty(nq)
    a_z = np.empty(nq)
    inv_a = np.empty(nq)
    cx = np.empty(nqc)
    acc = np.empty(nm)
    write_column = column_radiance.shape[0] == nz
    for col in range(ny * nx):
        for qc in range(nqc):
            plane[col, qc] = ground_emission[col, qc % 3] if sz > 0 else np.float32(0.0)
    for kk in range(nz):
        k = kk if sz > 0 else nz - 1 - kk
        for q in range(nq):
            a_x[q], a_y[q], a_z[q] = ax[q], ay[q], az[q] * inv_dz[k]
            inv_a[q] = 1.0 / (a_x[q] + a_y[q] + a_z[q])
        for i in range(nx):
            for qc in range(nqc):
                row[i, qc] = side_y[k, qc]
        for jj in range(ny):
            j = jj if sy > 0 else ny - 1 - jj
            for qc in range(nqc):
                cx[qc] = side_x[k, qc]
            for ii in range(nx):
                i = ii if sx > 0 else nx - 1 - ii
                col = j * nx + i
                cell = k * ny * nx + col
                kg = ground_level[col]
                if k < kg:  # solid: absorbs what reaches its sides; below, the ground's emission is carried up
                    for qc in range(nqc):
                        cx[qc] = 0.0
                        row[i, qc] = 0.0
                        plane[col, qc] = ground_emission[col, qc % 3] if sz > 0 else np.float32(0.0)
                    continue
                for c in range(3):
                    for m in range(nm):
                        psi[c * nm + m] = sigma[cell, c * n_l + degree[m]] * phi_in[cell, c * nm + m]
                    if with_beam:
                        b = beam[cell, c]
                        for l in range(n_l):
                            beam_l[c * n_l + l] = b * sigma[cell, c * n_l + l]
                for q in range(nq):
                    for c in range(3):
                        qc = 3 * q + c
                        s = 0.0
                        for m in range(nm):
                            s += harmonics[q, m] * psi[c * nm + m]
                        if with_beam:
                            for l in range(n_l):
                                s += beam_phase[q, l] * beam_l[c * n_l + l]
                        inflow = (a_x[q] * cx[qc] + a_y[q] * row[i, qc] + a_z[q] * plane[col, qc]) * inv_a[q]
                        x = beta[cell, c] * inv_a[q]  # the optical path across the cell along the direction
                        src = s * inv_a[q]  # the source over the path, S / a = (S / beta) x
                        if x > 0.05:
                            e = math.exp(-x)
                            one_minus = 1.0 - e
                            mean = one_minus / x
                            v = src / x * (1.0 - mean) + inflow * mean
                            out = src / x * one_minus + inflow * e
                        else:  # the same to ~1e-8 without the division: e^-x and (1 - e^-x) / x by their series
                            mean = 1.0 - x * (0.5 - x * (1.0 / 6.0 - x * (1.0 / 24.0 - x / 120.0)))
                            e = 1.0 - x * mean
                            half = 0.5 - x * (1.0 / 6.0 - x * (1.0 / 24.0 - x * (1.0 / 120.0 - x / 720.0)))
                            v = src * half + inflow * mean
                            out = src * mean + inflow * e
                        cx[qc] = out
                        row[i, qc] = out
                        plane[col, qc] = out
                        value[qc] = v
                        if sz < 0 and k == kg:
                            ground_flux[col, c] += weights[q] * az[q] * out
                if write_column and col == 0:
                    for qc in range(nqc):
                        column_radiance[k, qc] = value[qc]
                for c in range(3):
                    for m in range(nm):
                        acc[m] = 0.0
                    for q in range(nq):
                        v = value[3 * q + c]
                        for m in range(nm):  # contiguous in m: one vector of moments per direction
                            acc[m] += weighted[q, m] * v
                    for m in range(nm):
                        phi_out[cell, c * nm + m] += acc[m]


@njit(**_JIT_KERNEL, nogil=True)
def beam_sweep(beta, ax, ay, az, inv_dz, sx, sy, ground_level, mean, ground):  # pragma: no cover - compiled
    """The direct beam through the solver's grid along its propagation direction (downwards, signs ``sx``, ``sy``
    of its x and y components), with the cell scheme of :func:`sweep_octant` and no scattering: energy-conserving
    (each cell takes from the beam exactly what its faces let in minus what they let out), so that a wide cell
    that the sun enters through its side is not lit through and through.

    Parameters
    ----------
    beta : (nz, ny, nx, 3) float32
        Scaled extinction [m-1] that dims the beam.
    ax, ay, az : float
        |Omega_x| / dx, |Omega_y| / dy [m-1] and |Omega_z| [-] of the beam's direction.
    inv_dz : (nz,) float64
        1 / the levels' thickness [m-1].
    ground_level : (ny, nx) int64
        First open cell of each column (cells below are solid and stop the beam).
    mean : (nz, ny, nx, 3) float32
        Written: each cell's mean beam, relative to its value outside the grid [-].
    ground : (ny, nx, 3) float32
        Written: the beam leaving each column's lowest open cell downwards [-] (times mu0: the direct irradiance on
        the ground relative to the beam's outside).
    """
    nz, ny, nx = beta.shape[0], beta.shape[1], beta.shape[2]
    plane = np.ones((ny, nx, 3), np.float32)
    row = np.empty((nx, 3), np.float32)
    for kk in range(nz):
        k = nz - 1 - kk
        a_z = az * inv_dz[k]
        a_sum = ax + ay + a_z
        row[:, :] = 1.0
        for jj in range(ny):
            j = jj if sy > 0 else ny - 1 - jj
            c0 = c1 = c2 = np.float32(1.0)
            for ii in range(nx):
                i = ii if sx > 0 else nx - 1 - ii
                if k < ground_level[j, i]:
                    c0 = c1 = c2 = np.float32(0.0)
                    for c in range(3):
                        row[i, c] = 0.0
                        plane[j, i, c] = 0.0
                        mean[k, j, i, c] = 0.0
                    continue
                for c in range(3):
                    cin = c0 if c == 0 else (c1 if c == 1 else c2)
                    inflow = (ax * cin + ay * row[i, c] + a_z * plane[j, i, c]) / a_sum
                    x = beta[k, j, i, c] / a_sum
                    if x > 1e-4:
                        e = math.exp(-x)
                        value = inflow * ((1.0 - e) / x)
                        out = inflow * e
                    else:
                        value = inflow * (1.0 - 0.5 * x)
                        out = inflow * (1.0 - x)
                    mean[k, j, i, c] = value
                    row[i, c] = out
                    plane[j, i, c] = out
                    if c == 0:
                        c0 = out
                    elif c == 1:
                        c1 = out
                    else:
                        c2 = out
                    if k == ground_level[j, i]:
                        ground[j, i, c] = out
