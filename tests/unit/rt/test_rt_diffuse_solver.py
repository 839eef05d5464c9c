"""The 3-D diffuse solution's solver (swim.rt.diffuse_solver, swim.rt.ordinates_cpu) against analytic limits,
energy conservation and DISORT for plane-parallel layers."""

import math

import numpy as np
import pytest

from swim.errors import SwimInputError
from swim.rt.diffuse_solver import DiffuseMedium, solve_diffuse
from swim.rt.ordinates import make_quadrature

H = 500.0  # slab thickness [m]


def _slab(tau_scaled, sz, albedo, chi, ssa=1.0, n=None, columns=1, dx=1.0):
    """A uniform slab of scaled optical thickness ``tau_scaled`` with scaled moments ``chi`` (L + 1,), single-
    scattering albedo ``ssa``, over a Lambertian ground, and a transparent cell above it (whose radiance is what
    leaves the slab's top); the direct beam's cell means exact."""
    n = n or max(10, int(math.ceil(tau_scaled / 0.25)))
    mu0 = math.cos(math.radians(sz))
    dz = H / n
    beta = tau_scaled / H
    k = np.arange(n)
    top = (n - 1 - k) * dz * beta
    beam = np.ones(n + 1)
    if beta > 0:
        beam[:n] = (np.exp(-top / mu0) - np.exp(-(top + dz * beta) / mu0)) * mu0 / (dz * beta)
    shape = (n + 1, columns, columns)
    inside = (np.arange(n + 1) < n)[:, None, None, None]
    return DiffuseMedium(
        beta=np.where(inside, beta, 0.0).astype(np.float32) * np.ones(shape + (3,), np.float32),
        sigma=(np.where(inside[..., None], beta * ssa * np.asarray(chi), 0.0)
               * np.ones(shape + (3, len(chi)))).astype(np.float32),
        beam=np.broadcast_to(beam[:, None, None, None], shape + (3,)).astype(np.float32).copy(),
        dz=np.full(n + 1, dz), dx=dx, dy=dx, albedo=np.full((columns, columns, 3), albedo, np.float32),
        ground_level=np.zeros((columns, columns), np.int64),
        ground_beam=np.full((columns, columns, 3), mu0 * math.exp(-tau_scaled / mu0), np.float32),
        sun=np.array([math.sin(math.radians(sz)), 0.0, mu0]))


def _fluxes(sol, medium, quad):
    """Downward diffuse flux on the ground and upward flux out of the top, per unit E_TOA (3,)."""
    top_up = None
    if sol.column_radiance is not None:
        up = quad.directions[:, 2] > 0
        top_up = (quad.weights[up] * quad.directions[up, 2]) @ sol.column_radiance[-1, up]
    return sol.ground_diffuse[0, 0], top_up


def test_a_transparent_medium_has_no_diffuse_light():
    quad = make_quadrature(2, 8, 2)
    m = _slab(0.0, 30, 0.0, [1.0, 0.0, 0.0], n=4)
    sol = solve_diffuse(m, quad, column=True)
    assert np.all(sol.moments == 0) and np.all(sol.ground_diffuse == 0)


def test_single_scattering_limit_of_a_thin_isotropic_slab():
    """A thin isotropic, conservative slab over a black ground: the diffuse flux reaching the ground is the single-
    scattering value tau / 2 (mu0-independent to first order in tau: half the scattered beam goes down)."""
    quad = make_quadrature(4, 8, 0)
    tau = 1e-3
    for sz in (0.0, 60.0):
        m = _slab(tau, sz, 0.0, [1.0], n=8)
        sol = solve_diffuse(m, quad, column=True, tolerance=1e-8)
        np.testing.assert_allclose(sol.ground_diffuse[0, 0], 0.5 * tau, rtol=0.02)


@pytest.mark.parametrize("tau, sz, albedo", [(2.0, 30.0, 0.0), (8.0, 60.0, 0.3), (20.0, 45.0, 0.9)])
def test_energy_is_conserved_in_a_conservative_slab(tau, sz, albedo):
    """Reflected + absorbed by the ground = incident: mu0 = F_up(top) + (1 - albedo) (F_down + direct)(ground)."""
    quad = make_quadrature(2, 8, 2)
    m = _slab(tau, sz, albedo, [1.0, 0.5, 0.2])
    sol = solve_diffuse(m, quad, column=True, tolerance=1e-7, max_sweeps=800)
    down, up = _fluxes(sol, m, quad)
    mu0 = math.cos(math.radians(sz))
    direct = mu0 * math.exp(-tau / mu0)
    np.testing.assert_allclose(up + (1 - albedo) * (down + direct), mu0, rtol=5e-3)


def test_a_horizontally_uniform_grid_is_its_column():
    """With the column's radiance entering through its sides, a 3-D grid of a uniform slab has the column's
    solution to within 1-2 % (the cells' closure lets a cell's sides out with its exit value, the column's sides take
    its cell means: a small difference in cells of optical thickness ~0.25)."""
    quad = make_quadrature(2, 8, 2)
    column = _slab(5.0, 50.0, 0.2, [1.0, 0.4, 0.1])
    one = solve_diffuse(column, quad, column=True, tolerance=1e-7)
    grid = _slab(5.0, 50.0, 0.2, [1.0, 0.4, 0.1], columns=4, dx=300.0)
    grid.side_radiance = one.column_radiance
    three = solve_diffuse(grid, quad, tolerance=1e-7)
    np.testing.assert_allclose(three.ground_diffuse, np.broadcast_to(one.ground_diffuse, (4, 4, 3)), rtol=1e-2)
    np.testing.assert_allclose(three.moments[:, 2, 1, :, 0], one.moments[:, 0, 0, :, 0], rtol=2e-2, atol=1e-6)


def test_the_grounds_reflection_brightens_the_light_under_a_cloud():
    """Cloud-ground interreflection: over a bright ground more light reaches the ground than the ground's albedo
    alone explains (the cloud base sends part of it back), so F(a) / F(0) > 1 + a R, R the cloud's reflectance."""
    quad = make_quadrature(2, 8, 2)
    chi = [1.0, 0.45, 0.15]
    fluxes = {}
    for a in (0.0, 0.9):
        m = _slab(10.0, 30.0, a, chi)
        sol = solve_diffuse(m, quad, column=True, tolerance=1e-7, max_sweeps=800)
        fluxes[a] = sol.ground_diffuse[0, 0, 1]
    assert fluxes[0.9] / fluxes[0.0] > 1.5


@pytest.mark.parametrize("tau, sz", [(5.0, 30.0), (20.0, 60.0), (50.0, 75.0)])
def test_ground_flux_matches_disort(tau, sz):
    """A conservative Henyey-Greenstein (g 0.85) slab, delta-M scaled with f = g^3 (degree 2): the global
    irradiance on a ground of albedo 0.1 within 3 % of DISORT (64 streams, all moments)."""
    pytest.importorskip("disortpp")
    from swim.validation.disort import _solve

    g, n_mom = 0.85, 256
    f = g**3
    chi = [(g**l - f) / (1 - f) for l in range(3)]
    quad = make_quadrature(2, 8, 2)
    m = _slab(tau * (1 - f), sz, 0.1, chi)
    sol = solve_diffuse(m, quad, column=True, tolerance=1e-6, max_sweeps=800)
    mu0 = math.cos(math.radians(sz))
    ours = sol.ground_diffuse[0, 0, 1] + mu0 * math.exp(-tau * (1 - f) / mu0)
    layers = {"dtau": np.full((10, 3), tau / 10), "ssa": np.full((10, 3), 1 - 1e-9),
              "moments": np.tile((g ** np.arange(n_mom + 1))[None, :, None], (10, 1, 3))}
    ref = _solve(layers, 1, mu0, np.full(3, 0.1), 64, fluxes_only=True)
    reference = np.asarray(ref.flux_direct_beam)[-1] + np.asarray(ref.flux_down)[-1]
    np.testing.assert_allclose(ours, reference, rtol=0.03)


def test_the_beam_sweep_conserves_the_beams_energy():
    """A wide, thick cell that the sun enters through its top and side takes from the beam exactly what its faces
    let in minus what they let out (e^-x of it), not a beam that lights it through and through."""
    from swim.rt.ordinates_cpu import beam_sweep

    nz, ny, nx = 3, 1, 4
    beta = np.zeros((nz, ny, nx, 3), np.float32)
    beta[1, 0, 2] = 1e-2  # one cell 100 km wide and 500 m thick: optical depth 1000 across, 5 up
    mean = np.empty_like(beta)
    ground = np.zeros((ny, nx, 3), np.float32)
    dx, dz = 1e5, 500.0
    sun = np.array([math.sin(math.radians(60)), 0.0, 0.5])
    p = -sun
    a_x, a_z = abs(p[0]) / dx, abs(p[2]) / dz
    beam_sweep(beta, a_x, 0.0, abs(p[2]), np.full(nz, 1 / dz), -1, 1, np.zeros((ny, nx), np.int64), mean, ground)
    x = 1e-2 / (a_x + a_z)
    taken = 1e-2 * mean[1, 0, 2, 0]
    np.testing.assert_allclose(taken, (a_x + a_z) * (1 - math.exp(-x)), rtol=1e-4)
    assert mean[1, 0, 2, 0] < 0.15
    np.testing.assert_allclose(ground[0, 3, 0], 1.0, rtol=1e-6)  # up-sun of the cell the beam is whole
    assert ground[0, 2, 0] < 0.01  # under it, it is not
    np.testing.assert_allclose(mean[2], 1.0)  # above it too


def test_bad_media_are_refused():
    quad = make_quadrature(2, 8, 2)
    m = _slab(1.0, 30.0, 0.1, [1.0, 0.5, 0.2])
    m.beta = -m.beta
    with pytest.raises(SwimInputError, match="beta"):
        solve_diffuse(m, quad)
    m = _slab(1.0, 30.0, 0.1, [1.0, 0.5])
    with pytest.raises(SwimInputError, match="sigma"):
        solve_diffuse(m, quad)
    m = _slab(1.0, 30.0, 0.1, [1.0, 0.5, 0.2], columns=2)
    with pytest.raises(SwimInputError, match="one-column"):
        solve_diffuse(m, quad, column=True)


def test_the_solution_does_not_depend_on_the_thread_count(monkeypatch):
    """The octants add into buffers of their own, summed in a fixed order, and the Krylov scalars are float64 sums in
    a fixed order: one thread and several give the same bits (a dask worker process with one thread renders a
    series' frame as the main process does)."""
    import swim.rt.diffuse_solver as solver

    quad = make_quadrature(2, 8, 2)
    rng = np.random.default_rng(7)
    grid = _slab(8.0, 40.0, 0.3, [1.0, 0.5, 0.2], columns=5, dx=400.0)
    factor = rng.uniform(0.2, 1.8, grid.beta.shape[:3] + (1,)).astype(np.float32)  # a 3-D field of cells
    grid.beta = np.ascontiguousarray(grid.beta * factor)
    grid.sigma = np.ascontiguousarray(grid.sigma * factor[..., None])
    solutions = []
    for n in (1, 2, 4):
        monkeypatch.setattr(solver, "threads", lambda n=n: n)
        solutions.append(solve_diffuse(grid, quad, tolerance=1e-6))
    for other in solutions[1:]:
        np.testing.assert_array_equal(other.moments, solutions[0].moments)
        np.testing.assert_array_equal(other.ground_diffuse, solutions[0].ground_diffuse)
    assert solutions[0].sweeps > 4


def test_the_float64_dot_product_is_numpy_s():
    from swim.rt.ordinates_cpu import dot64

    a, b = np.random.default_rng(1).normal(size=(2, 100_003)).astype(np.float32)
    assert dot64(a, b) == pytest.approx(float(np.dot(a.astype(np.float64), b.astype(np.float64))), rel=1e-12)
