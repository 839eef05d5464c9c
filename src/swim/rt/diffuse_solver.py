"""The 3-D diffuse (multiply scattered) radiance field: discrete ordinates with spherical-harmonic moments.

A medium on a Cartesian grid of cells (:class:`DiffuseMedium`: delta-M scaled extinction, scattering moments and
the direct beam of each cell, a Lambertian ground, clear surroundings) is solved for the moments I_lm of its
diffuse radiance (:func:`solve_diffuse`). The transport is swept direction by direction
(:func:`swim.rt.ordinates_cpu.octant_sweep`); the scattering couples the directions through the moments. The
fixed point x = K x + b (K: one sweep of the scattering source, b: one sweep of the beam, the ground's reflection
of it and the light entering from the surroundings) is found by BiCGStab (van der Vorst 1992) on (I - K) x = b,
which needs tens of sweeps where plain source iteration needs hundreds to thousands for optically thick clouds.

The ground's reflection is part of every sweep (downward octants first, then the ground's Lambertian emission,
then upward octants), so the sweep is linear in the moments and the interreflection between cloud and ground is
solved with the rest.

References
----------
van der Vorst, H. A. (1992): Bi-CGSTAB: a fast and smoothly converging variant of Bi-CG for the solution of
nonsymmetric linear systems, SIAM J. Sci. Stat. Comput. 13, 631-644, doi:10.1137/0913035.
Evans, K. F. (1998), doi:10.1175/1520-0469(1998)055<0429:TSHDOM>2.0.CO;2 (the SHDOM idea: moments for the source,
ordinates for the transport).
Wiscombe, W. J. (1977), doi:10.1175/1520-0469(1977)034<1408:TDMRYA>2.0.CO;2 (delta-M scaling).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from ..errors import SwimInputError
from ..workers import threads, worker_pool
from .ordinates import Quadrature, harmonic_degrees, real_spherical_harmonics

log = logging.getLogger(__name__)

__all__ = ["DiffuseMedium", "DiffuseSolution", "solve_diffuse"]


@dataclass
class DiffuseMedium:
    """A scaled (delta-M) medium on the solver's grid, for three wavelengths.

    Attributes
    ----------
    beta : numpy.ndarray
        (nz, ny, nx, 3) float32: extinction beta* [m-1].
    sigma : numpy.ndarray
        (nz, ny, nx, 3, L + 1) float32: beta* omega* chi*_l [m-1] (the scattering coefficient times the Legendre
        moments of the scaled phase function).
    beam : numpy.ndarray
        (nz, ny, nx, 3) float32: the direct beam's irradiance normal to it, relative to E_TOA [-], the cell's
        mean (scaled transmittance from the top of the atmosphere).
    dz : numpy.ndarray
        (nz,) float64: cell thicknesses [m], bottom first.
    dx, dy : float
        Cell widths [m].
    albedo : numpy.ndarray
        (ny, nx, 3) float32: Lambertian albedo of the ground [-].
    ground_level : numpy.ndarray
        (ny, nx) int64: the first cell above the ground in each column.
    ground_beam : numpy.ndarray
        (ny, nx, 3) float32: direct irradiance on the (horizontal) ground relative to E_TOA [-], mu0 times the
        beam there.
    sun : numpy.ndarray
        (3,) unit vector towards the sun in the solver's frame.
    side_radiance : numpy.ndarray or None
        (nz, n_dir, 3) float32: radiance entering through the grid's sides per level and direction (the clear
        surroundings); None: nothing enters (or a one-column medium, whose sides are not swept).
    """

    beta: np.ndarray
    sigma: np.ndarray
    beam: np.ndarray
    dz: np.ndarray
    dx: float
    dy: float
    albedo: np.ndarray
    ground_level: np.ndarray
    ground_beam: np.ndarray
    sun: np.ndarray
    side_radiance: np.ndarray | None = None

    @property
    def shape(self):
        return self.beta.shape[:3]


@dataclass
class DiffuseSolution:
    """The diffuse radiance's moments and the ground's irradiance.

    Attributes
    ----------
    moments : numpy.ndarray
        (nz, ny, nx, 3, (L + 1)^2) float32: I_lm = int I Y_lm dOmega of the diffuse radiance, per unit E_TOA
        (F0 = 1; the solar-relative radiance of Eq. 2 is 4 pi I).
    ground_diffuse : numpy.ndarray
        (ny, nx, 3) float64: diffuse irradiance on the ground relative to E_TOA [-].
    column_radiance : numpy.ndarray or None
        (nz, n_dir, 3) float32: the radiance of every direction in a one-column medium's cells.
    sweeps : int
        Transport sweeps taken.
    residual : float
        Relative residual |b - (I - K) x| / |b| at the end.
    """

    moments: np.ndarray
    ground_diffuse: np.ndarray
    column_radiance: np.ndarray | None
    sweeps: int
    residual: float


class _Sweeper:
    """One transport sweep of all octants: x -> K x (+ b with the sources), on the process's worker threads."""

    def __init__(self, medium: DiffuseMedium, quad: Quadrature, column: bool):
        from .ordinates_cpu import octant_sweep

        self.medium, self.quad, self.column = medium, quad, column
        nz, ny, nx = medium.shape
        nq = quad.per_octant
        self.nm = quad.harmonics.shape[1]
        self.degree = harmonic_degrees(quad.max_degree).astype(np.int64)
        self.kernel = octant_sweep(nq, self.nm, quad.max_degree + 1, tuple(self.degree))
        # the beam propagates away from the sun: its moments are those of a delta in the direction -sun
        sun_harm = real_spherical_harmonics(-np.asarray(medium.sun, float), quad.max_degree)
        self.beam_phase = np.zeros((quad.n_directions, quad.max_degree + 1))
        for m, l in enumerate(self.degree):
            self.beam_phase[:, l] += quad.harmonics[:, m] * sun_harm[m]
        d = quad.directions
        self.ax = np.zeros(quad.n_directions) if column else np.abs(d[:, 0]) / float(medium.dx)
        self.ay = np.zeros(quad.n_directions) if column else np.abs(d[:, 1]) / float(medium.dy)
        self.az = np.abs(d[:, 2])
        self.inv_dz = 1.0 / np.asarray(medium.dz, float)
        side = medium.side_radiance
        side = np.zeros((nz, quad.n_directions, 3), np.float32) if side is None else np.asarray(side, np.float32)
        # per octant, contiguous: (nz, 3 nq), direction q and wavelength c at 3 q + c
        self.side = [np.ascontiguousarray(side[:, o * nq:(o + 1) * nq].reshape(nz, 3 * nq)) for o in range(8)]
        self.zero_side = np.zeros((nz, 3 * nq), np.float32)
        # the kernel's flat arrays: a row per cell, its wavelengths (and degrees or moments) along it
        self.flat = {"beta": medium.beta.reshape(-1, 3), "sigma": medium.sigma.reshape(nz * ny * nx, -1),
                     "beam": medium.beam.reshape(-1, 3),
                     "ground_level": np.ascontiguousarray(medium.ground_level.reshape(-1))}
        # each octant pair (down o, up o + 4, o = 0..3) adds into its own buffer (o = 0: the output), summed in a
        # fixed order: the moments' float32 round-off, and so the image, do not depend on the process's thread count
        # (a dask worker process with one thread renders a frame to the bit as the main process with two)
        self.n_workers = min(threads(), 4)
        self.buffers = [np.zeros((nz, ny, nx, 3, self.nm), np.float32) for _ in range(3)]
        self.flux = [np.zeros((ny * nx, 3)) for _ in range(4)]
        self.work = [(np.zeros((ny * nx, 3 * nq), np.float32), np.zeros((nx, 3 * nq), np.float32)) for _ in range(4)]
        self.column_radiance = [np.zeros((nz if column else 0, 3 * nq), np.float32) for _ in range(8)]
        self.ground_flux = np.zeros((ny, nx, 3))
        self.sweeps = 0

    def _octant(self, o, phi_in, phi_out, flux, emission, sources, work):
        q, f = self.quad, self.flat
        nz, ny, nx = self.medium.shape
        s = slice(o * q.per_octant, (o + 1) * q.per_octant)
        sx, sy, sz = (int(v) for v in q.octants[o])
        side = self.side[o] if sources else self.zero_side
        self.kernel(sx, sy, sz, nz, ny, nx, f["beta"], f["sigma"], f["beam"], phi_in.reshape(nz * ny * nx, -1),
                    phi_out.reshape(nz * ny * nx, -1), q.harmonics[s], self.beam_phase[s], q.weights[s], self.ax[s],
                    self.ay[s], self.az[s], self.inv_dz, side, side, f["ground_level"], emission.reshape(ny * nx, 3),
                    flux, bool(sources), work[0], work[1], self.column_radiance[o])

    def column_radiances(self):
        """The one-column solve's radiance per level, direction and wavelength (nz, n_dir, 3)."""
        nq = self.quad.per_octant
        return np.concatenate([c.reshape(c.shape[0], nq, 3) for c in self.column_radiance], axis=1)

    def __call__(self, phi_in, out, sources):
        """``out`` = the moments of one sweep of ``phi_in`` (plus the sources' when ``sources``)."""
        out[...] = 0.0
        for b in self.buffers:
            b[...] = 0.0
        outs = [out] + self.buffers
        emission = np.zeros(self.medium.albedo.shape, np.float32)
        for flux in self.flux:
            flux[...] = 0.0

        def run(down):
            def octant(o):
                self._octant(o + (0 if down else 4), phi_in, outs[o], self.flux[o], emission, sources, self.work[o])
            if self.n_workers == 1:
                for o in range(4):
                    octant(o)
            else:
                for f in [worker_pool(self.n_workers).submit(octant, o) for o in range(4)]:
                    f.result()

        run(True)
        self.ground_flux = sum(self.flux).reshape(self.medium.albedo.shape)
        incident = self.ground_flux + (self.medium.ground_beam if sources else 0.0)
        emission[...] = self.medium.albedo * incident / math.pi
        run(False)
        for b in self.buffers:
            out += b
        self.sweeps += 1
        return out


def solve_diffuse(medium: DiffuseMedium, quad: Quadrature, tolerance: float = 1e-4, max_sweeps: int = 400,
                  column: bool = False) -> DiffuseSolution:
    """Solve a medium for the moments of its diffuse radiance.

    Parameters
    ----------
    medium : DiffuseMedium
        The scaled medium; ``sigma``'s last axis must have ``quad.max_degree + 1`` entries.
    quad : Quadrature
        Directions and harmonics (:func:`swim.rt.ordinates.make_quadrature`).
    tolerance : float
        Relative residual of (I - K) x = b at which BiCGStab stops, > 0.
    max_sweeps : int
        Most transport sweeps; a solve that has not converged by then logs a warning and returns its iterate.
    column : bool
        A one-column medium (nx = ny = 1) without horizontal transport: a plane-parallel solve, whose radiance per
        direction is returned (``column_radiance``).

    Returns
    -------
    DiffuseSolution

    Raises
    ------
    SwimInputError
        If the arrays' shapes do not agree, or a value is negative or not finite.
    """
    from .ordinates_cpu import dot64

    def dot(a, b):  # in float64, in one order whatever the threads (not BLAS's): see _Sweeper
        return dot64(a.reshape(-1), b.reshape(-1))

    def norm(a):
        return math.sqrt(dot(a, a))

    _check_medium(medium, quad, column)
    sweep = _Sweeper(medium, quad, column)
    shape = medium.beta.shape[:3] + (3, sweep.nm)
    b = np.zeros(shape, np.float32)
    sweep(np.zeros(shape, np.float32), b, True)
    x = b.copy()  # the first iterate of source iteration
    r = np.empty_like(b)

    def residual(x, out):  # b - (x - K x)
        sweep(x, out, False)
        out += b
        out -= x
        return out

    b_norm = norm(b) or 1.0
    residual(x, r)
    r0 = r.copy()
    rho = alpha = omega = 1.0
    v = np.zeros_like(b)
    p = np.zeros_like(b)
    s = np.empty_like(b)
    t = np.empty_like(b)
    rel = norm(r) / b_norm
    # BiCGStab (van der Vorst 1992), unpreconditioned: a diffusion correction of each column's isotropic moment
    # helps plane-parallel decks but slows 3-D fields, whose light leaks sideways (docs/decisions/0001-...)
    while rel > tolerance and sweep.sweeps + 2 <= max_sweeps:
        rho_new = dot(r0, r)
        if rho_new == 0.0:
            break
        beta_k = (rho_new / rho) * (alpha / omega)
        rho = rho_new
        p -= np.float32(omega) * v
        p *= np.float32(beta_k)
        p += r
        sweep(p, v, False)
        np.subtract(p, v, out=v)  # (I - K) p
        alpha = rho / dot(r0, v)
        np.subtract(r, np.float32(alpha) * v, out=s)
        if norm(s) / b_norm <= tolerance:
            x += np.float32(alpha) * p
            r[...] = s
            rel = norm(r) / b_norm
            break
        sweep(s, t, False)
        np.subtract(s, t, out=t)  # (I - K) s
        tt = dot(t, t)
        omega = dot(t, s) / tt if tt > 0 else 0.0
        x += np.float32(alpha) * p
        x += np.float32(omega) * s
        np.subtract(s, np.float32(omega) * t, out=r)
        rel = norm(r) / b_norm
        if omega == 0.0:
            break
    if rel > tolerance:
        log.warning("diffuse solution: relative residual %.2g after %d sweeps (tolerance %.2g)", rel, sweep.sweeps,
                    tolerance)
    # one last sweep of the solution: the ground's flux and the column's radiance of the final iterate
    final = np.empty_like(b)
    sweep(x, final, True)
    log.info("diffuse solution: %d sweeps, residual %.2g, grid %s x %d directions", sweep.sweeps, rel,
             medium.shape, quad.n_directions)
    return DiffuseSolution(moments=final, ground_diffuse=sweep.ground_flux.copy(),
                           column_radiance=sweep.column_radiances() if column else None,
                           sweeps=sweep.sweeps, residual=rel)


def _check_medium(m: DiffuseMedium, quad: Quadrature, column: bool):
    nz, ny, nx = m.beta.shape[:3]
    n_l = quad.max_degree + 1
    expect = {"beta": (nz, ny, nx, 3), "sigma": (nz, ny, nx, 3, n_l), "beam": (nz, ny, nx, 3), "dz": (nz,),
              "albedo": (ny, nx, 3), "ground_level": (ny, nx), "ground_beam": (ny, nx, 3), "sun": (3,)}
    for name, shape in expect.items():
        a = np.asarray(getattr(m, name))
        if a.shape != shape:
            raise SwimInputError(f"DiffuseMedium.{name} must have shape {shape}, got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise SwimInputError(f"DiffuseMedium.{name} holds values that are not finite")
    for name in ("beta", "sigma", "beam", "dz", "albedo", "ground_beam"):
        if np.any(np.asarray(getattr(m, name)) < 0):
            raise SwimInputError(f"DiffuseMedium.{name} must not be negative")
    if np.any(np.asarray(m.dz) <= 0) or not (m.dx > 0 and m.dy > 0):
        raise SwimInputError("DiffuseMedium: cell sizes dz, dx and dy must be > 0 [m]")
    if column and (ny, nx) != (1, 1):
        raise SwimInputError(f"solve_diffuse(column=True) needs a one-column medium, got {(ny, nx)} columns")
    if m.side_radiance is not None and np.asarray(m.side_radiance).shape != (nz, quad.n_directions, 3):
        raise SwimInputError(f"DiffuseMedium.side_radiance must have shape {(nz, quad.n_directions, 3)}")
    for name, a in (("beta", m.beta), ("sigma", m.sigma), ("beam", m.beam), ("albedo", m.albedo),
                    ("ground_beam", m.ground_beam)):
        if a.dtype != np.float32 or not a.flags.c_contiguous:
            raise SwimInputError(f"DiffuseMedium.{name} must be a C-contiguous float32 array")
    if m.ground_level.dtype != np.int64:
        raise SwimInputError("DiffuseMedium.ground_level must be int64")
