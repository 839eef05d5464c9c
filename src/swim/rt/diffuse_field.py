"""The 3-D diffuse solution of a render: the scene's medium on the solver's grid, solved once per scene, sun and
atmosphere, and its moments on the optical volume's levels for the march (``cloud_scattering="discrete_ordinates"``).

:func:`diffuse_field` builds the delta-M scaled medium (:class:`swim.rt.diffuse_solver.DiffuseMedium`) from

* the hydrometeors' extinction of the optical volume (Eq. 7), scaled by (1 - f) of their phase functions
  (:mod:`swim.optics.cloud_phase`), block means over ``coarsen`` x ``coarsen`` columns;
* the clear air (Rayleigh, background, stratospheric and 3-D aerosol) of the gas tables (Step 2);
* the direct beam: the gas tables' transmittance to the sun (spherical atmosphere) times its scaled transmittance
  through the grid's clouds and 3-D aerosol, swept through the solver's cells along the sun so that each cell takes
  from the beam what its faces let in (:func:`swim.rt.ordinates_cpu.beam_sweep`);
* the ground's albedo (Lambertian) and terrain (cells below it are solid);

on a vertical grid of the volume's levels, each interval split until no cell is optically thicker than
``max_cell_tau``, and clear layers above the grid up to the top of the atmosphere. The grid's surroundings are
the clear atmosphere (the scene's convention: no cloud beyond the grid): light enters through its sides with the
radiance of a one-column clear solve of the same atmosphere (:func:`clear_column`).

The march reads (:class:`DiffuseField`) the moments of the diffuse radiance (solar-relative, L' = 4 pi I) on the
volume's levels, and two ratios that carry the clouds' effect into the clear sky's validated terms: the diffuse
radiance's isotropic moment against the clear column's (the air's multiple-scattering source, Step 2) and the
ground's diffuse irradiance against the clear column's (the ground's skylight). With a 3-D aerosol field the
reference is the grid's clear air with that aerosol over a flat ground of the mean albedo, solved the same way: the
clear sky's terms the ratios scale already hold the aerosol (Step 2's column classes).

References
----------
docs/decisions/0001-cloud-diffuse-solution.md (why discrete ordinates, the grid, the boundary conditions).
Albers et al. (2020), doi:10.5194/amt-13-3235-2020, Eqs. 3-8 (Steps 1a and 2, which this replaces for clouds).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field, replace

import numpy as np

from ..constants import SPECIES
from ..errors import SwimInputError
from .diffuse_solver import DiffuseMedium, solve_diffuse
from .ordinates import make_quadrature

log = logging.getLogger(__name__)

#: Lowest cosine of the sun's zenith angle the 3-D diffuse solution is solved for (0.6 deg elevation); a render with a
#: lower sun scatters its clouds by the albers2020 method (swim.pipeline).
MIN_SUN_COSINE = 0.01
#: Largest relative difference of the sun's cosine from its node's (:func:`solve_sun`) for which a render takes the
#: node's solution, scaled (at sun zenith 75 deg a 0.5 deg step is 3.3 %); beyond it (a sun lower than ~80 deg with
#: the default step) the sun is solved for exactly.
MAX_NODE_COSINE_CHANGE = 0.05

__all__ = ["DiffuseSettings", "DiffuseField", "diffuse_field", "clear_column", "solver_levels", "solve_sun",
           "MIN_SUN_COSINE"]


@dataclass(frozen=True)
class DiffuseSettings:
    """Accuracy settings of the 3-D diffuse solution.

    Attributes
    ----------
    n_polar : int
        Gauss cosines per hemisphere (2: a 4-stream solution in a plane-parallel medium).
    n_azimuth : int
        Azimuths of the directions (a multiple of 4).
    max_degree : int
        Degree L of the scaled phase functions and of the stored moments ((L + 1)^2 per wavelength).
    max_cell_tau : float
        Largest scaled optical thickness of a cell in the vertical [-], in the ``thick_quantile`` of the columns (the
        thickest few cores of a convective scene do not set every level's split); raised where the split would give
        more than ``max_level_factor`` times the volume's levels.
    max_levels_per_interval : int
        Most cells an interval between two of the volume's levels is split into.
    thick_quantile : float
        Quantile of the columns' scaled optical thickness in an interval that its split resolves [-].
    max_level_factor : float
        Most cells in the vertical, as a multiple of the volume's intervals.
    max_cells : int
        Columns are averaged in blocks (coarsened) until the grid has at most this many cells.
    top_layers : int
        Clear layers between the grid's top and the top of the atmosphere.
    tolerance : float
        Relative residual of the solve.
    max_sweeps : int
        Most transport sweeps.
    sun_step_deg : float
        Spacing [deg] of the grid of sun directions the solution is solved for (:func:`solve_sun`): a render solves
        for the grid's sun nearest to its own and scales the solution to its own sun's cosine
        (:meth:`DiffuseField.for_sun`), so that the frames of a time series share a solution while the sun moves
        less than this. 0: every sun is solved for exactly.
    """

    n_polar: int = 2
    n_azimuth: int = 8
    max_degree: int = 2
    max_cell_tau: float = 0.25
    max_levels_per_interval: int = 24
    thick_quantile: float = 0.995
    max_level_factor: float = 3.0
    max_cells: int = 75_000
    top_layers: int = 10
    tolerance: float = 1e-4
    max_sweeps: int = 300
    sun_step_deg: float = 1.0

    def __post_init__(self):
        if not (self.n_polar >= 1 and self.n_azimuth >= 4 and self.n_azimuth % 4 == 0 and 0 <= self.max_degree <= 3
                and self.max_cell_tau > 0 and self.max_levels_per_interval >= 1 and self.max_cells >= 1000
                and 0.5 <= self.thick_quantile <= 1 and self.max_level_factor >= 1
                and self.top_layers >= 1 and 0 < self.tolerance < 1 and self.max_sweeps >= 4
                and 0 <= self.sun_step_deg <= 5):
            raise SwimInputError(f"DiffuseSettings out of range: {self}")


@dataclass
class DiffuseField:
    """The diffuse solution on the optical volume's levels, as the march reads it.

    Attributes
    ----------
    field : numpy.ndarray
        (nk, ny_c, nx_c, 3 + 3 nm) float32 on the volume's levels and the coarsened columns: channels 0-2 the ratio
        of the diffuse radiance's isotropic moment to the clear column's at that height [-] (per wavelength),
        then per wavelength the nm = (L + 1)^2 moments of the diffuse radiance L' [-] (4 pi I_lm, F0 = 1).
    ground : numpy.ndarray
        (ny_c, nx_c, 3) float32: the ground's diffuse irradiance relative to the clear column's [-].
    coarsen : int
        Columns per block along each axis.
    rotation : numpy.ndarray
        (2, 2): scene (x, y) -> the solver's (along i, across) horizontal frame of the moments.
    max_degree : int
        L.
    ground_diffuse : numpy.ndarray
        (ny_c, nx_c, 3) float32: the ground's diffuse irradiance relative to E_TOA [-] (the solve's own).
    above : numpy.ndarray
        (n_above, ny_c, nx_c, 3) float32: the isotropic moment's ratio to the clear column's at the grid's top level
        and in the clear layers above it, at the heights ``above_heights`` (n_above,) [m]: the air above the grid
        sees the light the clouds send up.
    sweeps, residual, cells : int, float, int
        The solve's statistics.
    sun : numpy.ndarray
        (3,) the unit vector towards the sun the medium was solved for, scene frame.
    """

    field: np.ndarray
    ground: np.ndarray
    coarsen: int
    rotation: np.ndarray
    max_degree: int
    ground_diffuse: np.ndarray | None = None
    above: np.ndarray | None = None
    above_heights: np.ndarray | None = None
    sweeps: int = 0
    residual: float = 0.0
    cells: int = 0
    seconds: dict = field(default_factory=dict)
    sun: np.ndarray | None = None

    def for_sun(self, sun_scene) -> DiffuseField:
        """The solution for a sun near the one it was solved for: the diffuse radiance's moments and the ground's
        diffuse irradiance scaled by the ratio of the suns' cosines (the light the medium receives; their ratios to
        the clear column's, which the march scales with its own sun's clear sky, are kept).

        Parameters
        ----------
        sun_scene : array_like
            (3,) unit vector towards the sun, scene frame.

        Returns
        -------
        DiffuseField
            ``self`` where the cosines agree, else a scaled copy.

        References
        ----------
        docs/decisions/0001-cloud-diffuse-solution.md, "Which method is the default" (the sun nodes and their
        measured error against an exact solve).
        """
        if self.sun is None:
            return self
        scale = float(np.asarray(sun_scene, float)[2]) / float(self.sun[2])
        if scale == 1.0:
            return self
        moments = self.field.copy()
        moments[..., 3:] *= np.float32(scale)
        ground_diffuse = None if self.ground_diffuse is None else self.ground_diffuse * np.float32(scale)
        return replace(self, field=moments, ground_diffuse=ground_diffuse)


def solve_sun(sun_scene, step_deg: float) -> np.ndarray:
    """The sun direction a diffuse solution is solved for: the node nearest to ``sun_scene`` of a grid of directions
    spaced ``step_deg`` in zenith angle and, on each ring of zenith angle z, in arc (round(360 sin z / step)
    azimuths), so that the node does not depend on the frames rendered before (a frame alone and in a series
    gets the same solution). A sun whose cosine differs from its node's by more than
    :data:`MAX_NODE_COSINE_CHANGE` (a low sun) is its own node.

    Parameters
    ----------
    sun_scene : array_like
        (3,) unit vector towards the sun, scene frame.
    step_deg : float
        Spacing [deg]; 0 keeps ``sun_scene``.

    Returns
    -------
    numpy.ndarray
        (3,) unit vector.

    References
    ----------
    docs/decisions/0001-cloud-diffuse-solution.md, "Which method is the default".
    """
    sun = np.asarray(sun_scene, float)
    if step_deg <= 0 or sun[2] <= MIN_SUN_COSINE:  # (a sun so low is not solved for: swim.pipeline)
        return sun
    zenith = math.degrees(math.acos(min(1.0, max(-1.0, sun[2]))))
    z = round(zenith / step_deg) * step_deg
    n_azimuth = max(1, round(360.0 * math.sin(math.radians(z)) / step_deg))
    spacing = 360.0 / n_azimuth
    a = round(math.degrees(math.atan2(sun[0], sun[1])) / spacing) * spacing
    zr, ar = math.radians(z), math.radians(a)
    if abs(math.cos(zr) / sun[2] - 1.0) > MAX_NODE_COSINE_CHANGE:
        return sun  # a low sun: the node's light would differ by more than the cosine scaling makes good
    return np.array([math.sin(zr) * math.sin(ar), math.sin(zr) * math.cos(ar), math.cos(zr)])


def _block_mean(a, c):
    """Mean of ``a`` (..., ny, nx) over blocks of c x c columns (the last blocks partial), summed in float64 in one
    compiled pass (:func:`swim.rt.ordinates_cpu.block_sums`)."""
    if c == 1:
        return np.asarray(a, np.float32)
    from .ordinates_cpu import block_sums

    a = np.asarray(a)
    *lead, ny, nx = a.shape
    starts_y, starts_x = np.arange(0, ny, c), np.arange(0, nx, c)
    s = np.zeros((math.prod(lead), starts_y.size, starts_x.size))
    block_sums(np.ascontiguousarray(a).reshape(-1, ny, nx), int(c), s)
    n = np.outer(np.diff(np.append(starts_y, ny)), np.diff(np.append(starts_x, nx)))
    return (s / n).astype(np.float32).reshape(*lead, starts_y.size, starts_x.size)


def solver_levels(levels, scaled_tau_interval, settings: DiffuseSettings, top_m):
    """The solver's cell edges [m] (bottom first) and, per volume interval, its first cell and cell count.

    Parameters
    ----------
    levels : numpy.ndarray
        (nk,) the volume's levels [m].
    scaled_tau_interval : numpy.ndarray
        (nk - 1,) the scaled optical thickness of each interval to resolve (a high quantile over the columns) [-].
    top_m : float
        Top of the atmosphere [m].
    """
    def split(limit):
        return np.clip(np.ceil(scaled_tau_interval / limit), 1, settings.max_levels_per_interval).astype(int)

    limit = settings.max_cell_tau
    budget = max(settings.max_level_factor * (levels.size - 1), levels.size - 1)
    while split(limit).sum() > budget:  # thicker cells rather than more levels than the budget
        limit *= 1.1
    n_split = split(limit)
    edges = [levels[0]]
    first = []
    for k in range(levels.size - 1):
        first.append(len(edges) - 1)
        edges.extend(levels[k] + (levels[k + 1] - levels[k]) * np.arange(1, n_split[k] + 1) / n_split[k])
    z_top = levels[-1]
    if top_m > z_top:
        t = np.arange(1, settings.top_layers + 1) / settings.top_layers
        s = 4.0  # layers thin near the grid's top, thick above
        edges.extend(z_top + (top_m - z_top) * np.expm1(s * t) / math.expm1(s))
    return np.asarray(edges), np.asarray(first), n_split


def _gas_profiles(gas, z):
    """Extinction [m-1] of molecules, background and stratospheric aerosol and ozone's absorption coefficient at
    heights ``z`` (n,), each (n, 3)."""
    h = np.arange(gas.beta_rayleigh.shape[0]) * gas.dh
    ozone = gas.ozone_extinction
    out = []
    for b in (gas.beta_rayleigh, gas.beta_aerosol, gas.beta_stratospheric, ozone):
        b = np.asarray(b, float)
        out.append(np.stack([np.interp(z, h, b[:, c]) for c in range(3)], axis=-1))
    return out


def _sun_transmittance(gas, z, mu0):
    """The gas tables' transmittance towards the sun at heights ``z`` (n,) and sun cosine mu0: (n, 3)."""
    table = np.asarray(gas.sun_transmittance, float)  # (n_u, n_mu, 3)
    n_u, n_mu = table.shape[:2]
    fu = np.clip(np.sqrt(np.clip(np.asarray(z, float) / gas.top_m, 0.0, 1.0)) * (n_u - 1), 0, n_u - 1.000001)
    fm = min(max((mu0 + 1.0) * 0.5 * (n_mu - 1), 0.0), n_mu - 1.000001)
    u0, m0 = fu.astype(int), int(fm)
    a, b = fu - u0, fm - m0
    t = ((1 - a)[:, None] * ((1 - b) * table[u0, m0] + b * table[u0, m0 + 1])
         + a[:, None] * ((1 - b) * table[u0 + 1, m0] + b * table[u0 + 1, m0 + 1]))
    return t


def _air_optics(gas, z, max_degree):
    """Scaled extinction (n, 3) and scattering moments beta* omega* chi*_l (n, 3, L + 1) of the clear air at heights
    ``z`` (molecules, background and stratospheric aerosol; delta-M with f = chi_{L+1} for the aerosols; ozone
    absorbs: extinction, no moments)."""
    from ..optics.legendre import phase_function_legendre_moments, rayleigh_legendre_moments

    b_r, b_a, b_s, b_o = _gas_profiles(gas, z)
    n_l = max_degree + 1
    chi_r = rayleigh_legendre_moments(gas.depolarization, n_l)[:n_l]
    beta = b_r.copy()
    sigma = b_r[..., None] * chi_r[None, None, :]
    parts = ((b_a, gas.aerosol.ssa, gas.aerosol.type.phase_function),
             (b_s, gas.aerosol.stratospheric.ssa, gas.aerosol.stratospheric.phase_function))
    for b, ssa, phase_function in parts:
        if not np.any(b > 0):
            continue
        ssa = np.broadcast_to(np.asarray(ssa, float), (3,))
        chi = phase_function_legendre_moments(lambda x, pf=phase_function: np.asarray(pf(x)), n_l)
        chi = np.broadcast_to(np.asarray(chi, float).reshape(n_l + 1, -1), (n_l + 1, 3))
        f = chi[n_l]  # delta-M (3,)
        beta = beta + b * (1.0 - ssa * f)[None, :]
        sigma = sigma + (b * ssa[None, :])[..., None] * (chi[:n_l].T - f[:, None])[None, :, :]
    if np.any(b_o > 0):
        beta = beta + b_o
    return beta, sigma


def clear_column(gas, edges, mu0, albedo, quad, settings: DiffuseSettings, sun):
    """The clear atmosphere's plane-parallel diffuse solution on the solver's levels (the grid's surroundings).

    Returns
    -------
    tuple
        (column radiance (nz, n_dir, 3) [per unit E_TOA, 1/sr], moments (nz, 3, nm), ground diffuse irradiance
        (3,) relative to E_TOA).
    """
    z = 0.5 * (edges[1:] + edges[:-1])
    dz = np.diff(edges)
    beta, sigma = _air_optics(gas, z, quad.max_degree)
    t_top = np.maximum(_sun_transmittance(gas, edges[1:], mu0), 0.0)
    t_bot = np.maximum(_sun_transmittance(gas, edges[:-1], mu0), 0.0)
    # the layer's mean of an exponential between its edges' values (their logarithmic mean); where either is ~0 (a
    # sun so low that the earth shades the layer) or they agree, their plain mean
    log_mean = (t_bot > 1e-12) & (t_top > 1e-12) & (np.abs(t_top - t_bot) > 1e-9)
    ratio = np.divide(t_top, t_bot, out=np.full_like(t_top, np.e), where=log_mean)  # e where unused: log 1
    beam = np.where(log_mean, (t_top - t_bot) / np.log(ratio), 0.5 * (t_top + t_bot))
    nz = z.size
    medium = DiffuseMedium(
        beta=np.ascontiguousarray(beta.reshape(nz, 1, 1, 3), np.float32),
        sigma=np.ascontiguousarray(sigma.reshape(nz, 1, 1, 3, -1), np.float32),
        beam=np.ascontiguousarray(beam.reshape(nz, 1, 1, 3), np.float32),
        dz=dz, dx=1.0, dy=1.0,
        albedo=np.ascontiguousarray(np.reshape(albedo, (1, 1, 3)), np.float32),
        ground_level=np.zeros((1, 1), np.int64),
        ground_beam=np.ascontiguousarray((mu0 * t_bot[0]).reshape(1, 1, 3), np.float32), sun=np.asarray(sun, float))
    sol = solve_diffuse(medium, quad, tolerance=min(settings.tolerance, 1e-5), max_sweeps=settings.max_sweeps,
                        column=True)
    return sol.column_radiance, sol.moments[:, 0, 0], sol.ground_diffuse[0, 0]


def diffuse_field(volume, species, gas, sun_scene, optics,
                  settings: DiffuseSettings = DiffuseSettings()) -> DiffuseField:
    """Solve the render's medium (module docstring) and put its diffuse moments on the volume's levels.

    Parameters
    ----------
    volume : xarray.Dataset
        The optical volume (:func:`swim.optics.volume.build_optical_volume`).
    species : tuple of int
        The packed species (indices into :data:`swim.constants.SPECIES`) whose extinction is not zero.
    gas : swim.rt.gas.GasTables
        The clear atmosphere.
    sun_scene : array_like
        (3,) unit vector towards the sun in the scene frame.
    optics : swim.optics.cloud_phase.CloudOptics
        The hydrometeors' phase functions and truncation (its ``max_degree`` must be ``settings.max_degree``).
    settings : DiffuseSettings

    Returns
    -------
    DiffuseField

    Raises
    ------
    SwimInputError
        If the sun is below the horizon, or the optics' degree differs from the settings'.
    """
    import time

    t0 = time.perf_counter()
    sun = np.asarray(sun_scene, float)
    mu0 = float(sun[2])
    if mu0 <= MIN_SUN_COSINE:
        raise SwimInputError(f"cloud_scattering='discrete_ordinates' needs the sun above the horizon (sun elevation "
                             f"> 0.6 deg); got a sun cosine of {mu0:.3f}")
    if optics.max_degree != settings.max_degree:
        raise SwimInputError("diffuse_field: the cloud optics' max_degree differs from the settings'")
    quad = make_quadrature(settings.n_polar, settings.n_azimuth, settings.max_degree)
    rotation, dx_m, dy_m = _solver_frame(volume)
    sun_solver = np.array([*(rotation @ sun[:2]), sun[2]])
    names = [str(s) for s in volume["extinction"]["species"].values]
    beta_species = {SPECIES[s]: volume["extinction"].sel(species=SPECIES[s]).values for s in species
                    if SPECIES[s] in names}
    grid = _solver_grid(volume, beta_species, optics, settings, gas.top_m)
    clear_beta, clear_sigma, air_beta, has_aerosol3d = _clear_optics(grid, volume, gas, settings.max_degree)
    beta, sigma = _with_hydrometeors(grid, clear_beta, clear_sigma, beta_species, optics)
    terrain = _block_mean(volume["terrain_height"].values, grid.coarsen)
    ground_level = np.clip(np.searchsorted(grid.edges, terrain - 0.5 * grid.dz[0], side="left"), 0,
                           grid.n_grid - 1).astype(np.int64)
    albedo = np.moveaxis(_block_mean(volume["surface_albedo"].transpose("wavelength", "y", "x").values,
                                     grid.coarsen), 0, -1)
    beam, ground_beam = _medium_beam(grid, beta, air_beta, gas, sun_solver, dx_m, dy_m, ground_level)
    t_build = time.perf_counter()

    mean_albedo = albedo.reshape(-1, 3).mean(axis=0)
    side, clear_moments, clear_ground = clear_column(gas, grid.edges, mu0, mean_albedo, quad, settings, sun_solver)
    # (nz, 1, 1, 3, nm) and (1, 1, 3): the clear column's, the same for every column
    clear_moments, clear_ground = clear_moments[:, None, None], clear_ground[None, None]

    def solve(beta, sigma, beam, albedo, ground_level, ground_beam, tolerance):
        return solve_diffuse(DiffuseMedium(
            beta=np.ascontiguousarray(beta), sigma=np.ascontiguousarray(sigma), beam=beam, dz=grid.dz,
            dx=dx_m * grid.coarsen, dy=dy_m * grid.coarsen, albedo=np.ascontiguousarray(albedo, np.float32),
            ground_level=ground_level, ground_beam=ground_beam, sun=sun_solver, side_radiance=side), quad,
            tolerance=tolerance, max_sweeps=settings.max_sweeps)

    if has_aerosol3d:
        # The ratios' reference is the grid's clear air with its 3-D aerosol over a flat ground of the mean albedo:
        # the march scales the clear sky's terms, which already hold the 3-D aerosol (Step 2's tables of the
        # field's column classes), so the ratios carry the clouds' and the terrain's effect alone (against the
        # clear column they would count the aerosol's diffuse light twice: +57 % GHI under a smoke layer of AOD 1)
        flat = np.zeros_like(ground_level)
        ref_beam, ref_ground_beam = _medium_beam(grid, clear_beta, air_beta, gas, sun_solver, dx_m, dy_m, flat)
        uniform = np.broadcast_to(mean_albedo.astype(np.float32), albedo.shape)
        ref = solve(clear_beta, clear_sigma, ref_beam, uniform, flat, ref_ground_beam, min(settings.tolerance, 1e-5))
        clear_moments, clear_ground = ref.moments, ref.ground_diffuse
    t_clear = time.perf_counter()
    sol = solve(beta, sigma, beam, albedo, ground_level, ground_beam, settings.tolerance)
    t_solve = time.perf_counter()

    field_out, ratio = _on_levels(grid, sol.moments, clear_moments, terrain)
    above_ratio = sol.moments[grid.n_grid:, ..., 0] / np.maximum(clear_moments[grid.n_grid:, ..., 0], 1e-30)
    seconds = {"build": t_build - t0, "clear": t_clear - t_build, "solve": t_solve - t_clear,
               "total": time.perf_counter() - t0}
    nz, nyc, nxc = beta.shape[:3]
    log.info("diffuse field: %d x %d x %d cells (columns coarsened %d x), %d sweeps, %.2f s (solve %.2f s)", nz, nyc,
             nxc, grid.coarsen, sol.sweeps, seconds["total"], seconds["solve"])
    return DiffuseField(
        field=field_out, ground=(sol.ground_diffuse / np.maximum(clear_ground, 1e-30)).astype(np.float32),
        coarsen=grid.coarsen, rotation=rotation, max_degree=settings.max_degree,
        ground_diffuse=sol.ground_diffuse.astype(np.float32),
        above=np.concatenate([ratio[-1:], above_ratio]).astype(np.float32),  # the top level, then the clear layers
        above_heights=np.concatenate([[grid.levels[-1]], grid.z[grid.n_grid:]]), sweeps=sol.sweeps,
        residual=sol.residual, cells=nz * nyc * nxc, seconds=seconds, sun=sun.copy())


def _solver_frame(volume):
    """The solver's horizontal frame: the rotation (2, 2) from scene (x, y) to the solver's (x along the grid's i
    axis), and the grid's spacings along i and j [m]."""
    matrix = np.asarray(volume.attrs["affine_matrix"], float).reshape(2, 2)
    ex, ey = matrix[:, 0], matrix[:, 1]
    dx_m, dy_m = float(np.hypot(*ex)), float(np.hypot(*ey))
    e1 = ex / dx_m
    rotation = np.array([e1, [-e1[1], e1[0]]])
    if float(np.dot(rotation[1], ey)) < 0:
        rotation[1] *= -1.0
    return rotation, dx_m, dy_m


@dataclass
class _Grid:
    """The solver's grid: columns averaged in blocks of ``coarsen``, the volume's ``levels`` split into cells with
    ``edges`` (bottom first; ``first``/``n_split`` per interval), the first ``n_grid`` cells inside the volume and clear
    layers above; ``below_k``/``weight`` place each of those cells between two volume levels."""

    coarsen: int
    levels: np.ndarray
    edges: np.ndarray
    first: np.ndarray
    n_split: np.ndarray
    n_grid: int
    shape: tuple
    below_k: np.ndarray
    weight: np.ndarray

    @property
    def z(self):
        return 0.5 * (self.edges[1:] + self.edges[:-1])

    @property
    def dz(self):
        return np.diff(self.edges)

    def on_cells(self, node_field):
        """A field on the volume's levels (nk, ny_c, nx_c[, ...]) at the cells' centres (n_grid, ny_c, nx_c[, ...])."""
        w = self.weight.reshape((-1,) + (1,) * (node_field.ndim - 1))
        return (1 - w) * node_field[self.below_k] + w * node_field[self.below_k + 1]


def _solver_grid(volume, beta_species, optics, settings, top_m) -> _Grid:
    """The smallest column blocks whose grid, split to ``max_cell_tau``, holds at most ``max_cells`` cells."""
    levels = volume["level"].values.astype(float)
    nk = levels.size
    ny, nx = volume["terrain_height"].shape
    hydro = np.zeros((nk, ny, nx), np.float32)
    for s, b in beta_species.items():
        hydro += np.float32(1.0 - optics.truncation[SPECIES.index(s)]) * b
    dz_levels = np.diff(levels)
    # every interval between the volume's levels is at least one cell: fewer blocks than that never fit the budget
    # (nor beyond the first blocks that leave at most 8 x 8 columns, where the search stops)
    coarsen = max(1, min(math.ceil(math.sqrt(max(nk - 1, 1) * ny * nx / settings.max_cells)) - 1,
                         -(-max(ny, nx) // 8)))

    def trial(c):  # the grid of c x c column blocks, and whether it fits the budget
        hydro_c = _block_mean(hydro, c)
        interval_tau = np.quantile(0.5 * (hydro_c[1:] + hydro_c[:-1]).reshape(nk - 1, -1), settings.thick_quantile,
                                   axis=1) * dz_levels
        levels_c = solver_levels(levels, interval_tau, settings, top_m)
        nyc, nxc = hydro_c.shape[1:]
        return (levels_c[0].size - 1) * nyc * nxc <= settings.max_cells or max(nyc, nxc) <= 8, (levels_c, nyc, nxc)

    # the smallest blocks that fit: larger blocks mean fewer columns and thinner block means, so the cells fall with
    # the block size; steps that double until one fits, then bisection (a few passes over a big volume, not one
    # per block size)
    fits, found = trial(coarsen)
    failed, step = coarsen, 1
    while not fits:
        coarsen = failed + step
        fits, found = trial(coarsen)
        if not fits:
            failed, step = coarsen, 2 * step
    while coarsen - failed > 1:
        middle = (failed + coarsen) // 2
        fits_middle, found_middle = trial(middle)
        if fits_middle:
            coarsen, found = middle, found_middle
        else:
            failed = middle
    (edges, first, n_split), nyc, nxc = found
    n_grid = int(first[-1] + n_split[-1]) if nk > 1 else 0
    z = 0.5 * (edges[1:n_grid + 1] + edges[:n_grid])
    below = np.clip(np.searchsorted(levels, z, side="right") - 1, 0, nk - 2)
    weight = ((z - levels[below]) / dz_levels[below]).astype(np.float32)
    return _Grid(coarsen, levels, edges, first, n_split, n_grid, (edges.size - 1, nyc, nxc), below, weight)


def _clear_optics(grid, volume, gas, max_degree):
    """The scaled extinction beta* (nz, ny_c, nx_c, 3) and scattering moments beta* omega* chi*_l
    (nz, ny_c, nx_c, 3, L + 1) of the solver's cells without hydrometeors (the clear air and the scene's 3-D aerosol),
    the clear air's beta* (nz, 3), and whether the scene has a 3-D aerosol field."""
    nz, nyc, nxc = grid.shape
    n_l = max_degree + 1
    n_grid = grid.n_grid
    air_beta, air_sigma = _air_optics(gas, grid.z, max_degree)  # (nz, 3), (nz, 3, L + 1)
    beta = np.broadcast_to(air_beta[:, None, None, :], (nz, nyc, nxc, 3)).astype(np.float32)
    sigma = np.broadcast_to(air_sigma[:, None, None, :, :], (nz, nyc, nxc, 3, n_l)).astype(np.float32)
    aerosol3d = np.asarray(volume["aerosol_extinction"].values, np.float32)
    has_aerosol3d = bool(np.any(aerosol3d > 0))
    if has_aerosol3d:
        from ..optics.legendre import phase_function_legendre_moments

        kind = gas.aerosol
        ssa = np.asarray(kind.ssa, float)
        chi = np.asarray(phase_function_legendre_moments(lambda x: np.asarray(kind.type.phase_function(x)), n_l),
                         float).reshape(n_l + 1, -1)
        chi = np.broadcast_to(chi, (n_l + 1, 3))
        fa = chi[n_l]
        ang = np.asarray(gas.angstrom_factor, float)
        a_cells = grid.on_cells(_block_mean(aerosol3d, grid.coarsen))[..., None] * ang  # (n_grid, nyc, nxc, 3)
        beta[:n_grid] += (a_cells * (1 - ssa * fa)).astype(np.float32)
        sigma[:n_grid] += ((a_cells * ssa)[..., None] * (chi[:n_l].T - fa[:, None])).astype(np.float32)
    return beta, sigma, air_beta, has_aerosol3d


def _with_hydrometeors(grid, beta, sigma, beta_species, optics):
    """Copies of the clear cells' ``beta`` and ``sigma`` (:func:`_clear_optics`) with the species' scaled extinction
    and scattering moments added (``beta_species``: species name -> extinction (nk, ny, nx) [m-1])."""
    beta, sigma = beta.copy(), sigma.copy()
    n_l, n_grid = sigma.shape[-1], grid.n_grid
    for s, b in beta_species.items():
        n = SPECIES.index(s)
        f = float(optics.truncation[n])
        b_cells = grid.on_cells(_block_mean(b, grid.coarsen))  # (n_grid, nyc, nxc)
        beta[:n_grid] += (np.float32(1.0 - f) * b_cells)[..., None]
        chi = optics.moments[n, :n_l, :] - f  # (L + 1, 3): beta (chi_l - f) = beta* omega* chi*_l
        sigma[:n_grid] += b_cells[..., None, None] * chi.T[None, None, None].astype(np.float32)
    return beta, sigma


def _medium_beam(grid, beta, air_beta, gas, sun_solver, dx_m, dy_m, ground_level):
    """The direct beam's cell means (nz, ny_c, nx_c, 3) and its irradiance on the ground (ny_c, nx_c, 3): swept
    through the grid's clouds and 3-D aerosol along the sun (energy-conserving cells,
    :func:`swim.rt.ordinates_cpu.beam_sweep`), times the gas tables' transmittance (spherical atmosphere) at each
    height."""
    n_grid = grid.n_grid
    mu0 = float(sun_solver[2])
    inside, ground_t = _beam(beta[:n_grid] - air_beta[:n_grid, None, None, :].astype(np.float32), sun_solver,
                             dx_m * grid.coarsen, dy_m * grid.coarsen, grid.dz[:n_grid], ground_level)
    t_gas = _sun_transmittance(gas, grid.z, mu0)  # (nz, 3)
    beam = np.empty(beta.shape, np.float32)
    beam[:n_grid] = inside * t_gas[:n_grid, None, None, :]
    beam[n_grid:] = t_gas[n_grid:, None, None, :]
    t_ground = _sun_transmittance(gas, grid.edges[ground_level].ravel(), mu0).reshape(ground_level.shape + (3,))
    return beam, np.ascontiguousarray((mu0 * ground_t * t_ground).astype(np.float32))


def _on_levels(grid, moments, clear_moments, terrain):
    """The march's field on the volume's levels (nk, ny_c, nx_c, 3 + 3 nm) and the isotropic ratio (nk, ny_c,
    nx_c, 3) to the reference ``clear_moments`` (nz, 1 or ny_c, 1 or nx_c, 3, nm): a level is the boundary of two
    cells (the mean of their moments); solid cells (below the terrain) take the first open level's values, so that
    the march's interpolation next to the ground mixes in no zeros."""
    levels, first, n_split = grid.levels, grid.first, grid.n_split
    nk = levels.size
    nz, nyc, nxc = grid.shape
    below = np.array([first[k - 1] + n_split[k - 1] - 1 if k > 0 else 0 for k in range(nk)])
    above = np.clip(np.array([first[k] if k < nk - 1 else grid.n_grid for k in range(nk)]), 0, nz - 1)
    node = 0.5 * (moments[below] + moments[above])  # (nk, nyc, nxc, 3, nm)
    open_node = np.clip(np.searchsorted(levels, terrain, side="left"), 0, nk - 1)
    solid = np.arange(nk)[:, None, None] < open_node[None]
    if solid.any():
        jj, ii = np.indices(open_node.shape)
        node = np.where(solid[..., None, None], node[open_node, jj, ii][None], node)
    clear_node = 0.5 * (clear_moments[below] + clear_moments[above])  # (nk, 1 or ny_c, 1 or nx_c, 3, nm)
    ratio = node[..., 0] / np.maximum(clear_node[..., 0], 1e-30)
    nm = moments.shape[-1]
    out = np.empty((nk, nyc, nxc, 3 + 3 * nm), np.float32)
    out[..., :3] = ratio
    out[..., 3:] = (4.0 * math.pi * node).reshape(nk, nyc, nxc, 3 * nm)
    return out, ratio


def _beam(beta, sun, dx, dy, dz, ground_level):
    """The direct beam's cell means (nz, ny, nx, 3) and what reaches the ground (ny, nx, 3), relative to its value
    outside the grid, through the scaled extinction ``beta`` (:func:`swim.rt.ordinates_cpu.beam_sweep`)."""
    from .ordinates_cpu import beam_sweep

    p = -np.asarray(sun, float)
    mean = np.empty(beta.shape, np.float32)
    ground = np.zeros(beta.shape[1:3] + (3,), np.float32)
    beam_sweep(np.ascontiguousarray(beta, np.float32), abs(p[0]) / dx, abs(p[1]) / dy, abs(p[2]),
               1.0 / np.asarray(dz, float), 1 if p[0] >= 0 else -1, 1 if p[1] >= 0 else -1, ground_level, mean,
               ground)
    return mean, ground
