"""Successive orders of scattering (swim.rt.multiple_scattering): analytic limits and conservation."""

from __future__ import annotations

import numpy as np
import pytest

from swim.constants import DIFFUSE_SUN_T_MIN
from swim.errors import SwimInputError
from swim.rt.gas import aerosol_column_classes
from swim.rt.multiple_scattering import (
    _direction_grid,
    _kernel,
    aerosol_layer_albedo,
    diffuse_source_table,
    successive_orders_plane_parallel,
    tabulated_phase_function,
)


def rayleigh(c):
    return 0.75 * (1.0 + np.asarray(c) ** 2)


def henyey_greenstein(g):
    def p(c):
        c = np.asarray(c)
        return (1 - g**2) / (1 + g**2 - 2 * g * c) ** 1.5
    return p


def _fluxes(sol, mu0, tau_total):
    mu, w, rad = sol["mu"], sol["weight"], sol["radiance"]
    up = mu > 0
    reflected = np.einsum("q,qsc->sc", (w * mu / (4 * np.pi))[up], rad[0, up])
    transmitted = np.einsum("q,qsc->sc", (w * -mu / (4 * np.pi))[~up], rad[-1, ~up])
    direct = mu0[:, None] * np.exp(-tau_total / mu0[:, None])
    return reflected, transmitted, direct


@pytest.mark.parametrize("n_half, n_phi", [(6, 8), (10, 12)])
def test_quadrature_weights_cover_the_sphere(n_half, n_phi):
    mu, phi, w = _direction_grid(n_half, n_phi)
    assert mu.size == 2 * n_half * n_phi
    np.testing.assert_allclose(w.sum(), 4 * np.pi, rtol=1e-12)
    # second moment of mu over the sphere: 4 pi / 3
    np.testing.assert_allclose((w * mu**2).sum(), 4 * np.pi / 3, rtol=1e-12)
    assert np.all(mu[: mu.size // 2] < 0) and np.all(mu[mu.size // 2:] > 0)


@pytest.mark.parametrize("g", [0.0, 0.7, 0.9])
def test_kernel_rows_conserve_energy(g):
    mu, phi, w = _direction_grid(8, 12)
    k = _kernel(henyey_greenstein(g), mu, phi, mu, phi, w)
    np.testing.assert_allclose(k.sum(axis=1), 1.0, rtol=1e-12)
    assert np.all(k >= 0)


@pytest.mark.parametrize("g", [0.0, 0.85])
@pytest.mark.parametrize("tau", [0.1, 1.0, 5.0])
def test_conservative_slab_conserves_flux(tau, g):
    """omega = 1, black ground: reflected + transmitted diffuse + direct = mu0 (the incident flux)."""
    n_l = 20
    d_tau = np.full((n_l, 1), tau / n_l)
    mu0 = np.array([1.0, 0.5, 0.2])
    ones = np.ones((n_l, 1))
    sol = successive_orders_plane_parallel(d_tau, ones, ones[None], mu0, [0.0], [henyey_greenstein(g)],
                                           tolerance=1e-7, max_orders=400)
    r, t, direct = _fluxes(sol, mu0, tau)
    np.testing.assert_allclose(r + t + direct, mu0[:, None], rtol=2e-3)
    # the slab reflects more the thicker it is, and a forward-peaked phase function reflects less
    assert np.all(r > 0) and np.all(t > 0)


def test_white_ground_under_conservative_layer_returns_everything():
    """omega = 1 over a white Lambertian ground: all incident flux leaves the top again."""
    n_l = 10
    d_tau = np.full((n_l, 1), 0.05)
    mu0 = np.array([0.7])
    ones = np.ones((n_l, 1))
    sol = successive_orders_plane_parallel(d_tau, ones, ones[None], mu0, [1.0], [rayleigh], tolerance=1e-8,
                                           max_orders=2000)
    mu, w, rad = sol["mu"], sol["weight"], sol["radiance"]
    up = mu > 0
    reflected = (w * mu / (4 * np.pi))[up] @ rad[0, up, 0, 0]
    np.testing.assert_allclose(reflected, 0.7, rtol=5e-3)


def test_absorbing_slab_loses_energy():
    n_l = 10
    d_tau = np.full((n_l, 1), 0.1)
    mu0 = np.array([0.8])
    sol = successive_orders_plane_parallel(d_tau, np.full((n_l, 1), 0.8), np.ones((1, n_l, 1)), mu0, [0.0],
                                           [rayleigh])
    r, t, direct = _fluxes(sol, mu0, 1.0)
    assert float((r + t + direct)[0, 0]) < 0.8 - 0.05


@pytest.mark.parametrize("mu_view", [0.3, 0.6, 1.0])
def test_thin_layer_matches_single_scattering_formula(mu_view):
    """tau = 1e-3: the diffuse radiance is single scattering, L' = omega P mu0 / (mu0 - mu)(e^-tau/mu0 - e^-tau/mu)
    below (looking up) and P mu0 / (mu0 + mu)(1 - e^(-tau/mu0 - tau/mu)) above (paper Eq. 3 in a slab)."""
    tau, mu0 = 1e-3, 0.6
    n_l = 4
    # two components (molecules and an isotropic scatterer) sharing the scattering
    sol = successive_orders_plane_parallel(np.full((n_l, 1), tau / n_l), np.ones((n_l, 1)),
                                           np.full((2, n_l, 1), 0.5), np.array([mu0]), [0.0],
                                           [rayleigh, lambda c: np.ones_like(np.asarray(c, float))])
    mu, phi, rad = sol["mu"], sol["phi"], sol["radiance"]
    # grid direction closest to the requested view cosine
    down = np.flatnonzero(mu < 0)
    q = down[np.argmin(np.abs(-mu[down] - mu_view))]
    m = -mu[q]
    cos_theta = mu[q] * -mu0 + np.sqrt(1 - mu[q] ** 2) * np.sqrt(1 - mu0**2) * np.cos(phi[q])
    p = 0.5 * rayleigh(cos_theta) + 0.5
    expected = p * mu0 / (mu0 - m) * (np.exp(-tau / mu0) - np.exp(-tau / m)) if abs(mu0 - m) > 1e-6 else \
        p * tau / mu0 * np.exp(-tau / mu0)
    # the column normalisation of the direct-beam phase function is within 1e-3 of 1 on this grid
    np.testing.assert_allclose(rad[-1, q, 0, 0], expected, rtol=3e-3)


def test_pseudo_spherical_beam_of_the_plane_parallel_transmittance_is_the_plane_parallel_solution():
    """Given the beam exp(-tau / mu0) at the layer edges, the pseudo-spherical path (layer means of the edges'
    exponential) reproduces the plane-parallel solution."""
    n_l, mu0 = 12, np.array([0.2, 0.7])
    d_tau = np.full((n_l, 1), 0.05)
    tau_edges = np.concatenate([[0.0], np.cumsum(d_tau[:, 0])])
    beam = np.exp(-tau_edges[:, None, None] / mu0[None, :, None])
    args = (d_tau, np.full((n_l, 1), 0.95), np.ones((1, n_l, 1)), mu0, [0.2], [henyey_greenstein(0.6)])
    plane = successive_orders_plane_parallel(*args)["radiance"]
    pseudo = successive_orders_plane_parallel(*args, beam_edges=beam)["radiance"]
    np.testing.assert_allclose(pseudo, plane, rtol=1e-9, atol=1e-15)


@pytest.mark.parametrize("mu_view", [0.3, 0.6, 1.0])
def test_upward_beam_of_a_sun_below_the_horizon_in_a_thin_layer(mu_view):
    """A sun 17.5 deg below the horizon (mu0 = -0.3) lighting a thin layer from below its horizontal: the light
    scattered down is single scattering, L' = omega P(theta) tau / mu (the thin limit of paper Eq. 3 in a slab),
    with theta the angle between the upward beam and the downward light."""
    tau, mu0, n_l = 1e-3, -0.3, 4
    beam = np.ones((n_l + 1, 1, 1))  # thin: the beam crosses the layer undimmed
    sol = successive_orders_plane_parallel(np.full((n_l, 1), tau / n_l), np.ones((n_l, 1)), np.ones((1, n_l, 1)),
                                           np.array([mu0]), [0.0], [rayleigh], beam_edges=beam)
    mu, phi, rad = sol["mu"], sol["phi"], sol["radiance"]
    down = np.flatnonzero(mu < 0)
    q = down[np.argmin(np.abs(-mu[down] - mu_view))]
    cos_theta = mu[q] * -mu0 + np.sqrt(1 - mu[q] ** 2) * np.sqrt(1 - mu0**2) * np.cos(phi[q])
    np.testing.assert_allclose(rad[-1, q, 0, 0], rayleigh(cos_theta) * tau / -mu[q], rtol=3e-3)
    with pytest.raises(ValueError, match="beam_edges"):
        successive_orders_plane_parallel(np.full((n_l, 1), tau / n_l), np.ones((n_l, 1)), np.ones((1, n_l, 1)),
                                         np.array([mu0]), [0.0], [rayleigh])


def test_tabulated_phase_function_is_accurate():
    hg = henyey_greenstein(0.9)
    tab = tabulated_phase_function(lambda c: hg(c))
    c = np.cos(np.radians(np.linspace(0, 180, 997)))
    np.testing.assert_allclose(tab(c), hg(c), rtol=2e-3)


def test_diffuse_source_table_shapes_and_limits():
    heights = np.linspace(0, 100e3, 1001)
    beta_r = 1.2e-5 * np.exp(-heights / 8000.0)[:, None] * np.array([0.6, 1.0, 2.2])
    beta_a = np.zeros_like(beta_r)
    tab = diffuse_source_table(heights, [beta_r, beta_a], [[1.0] * 3, [0.9] * 3],
                               [rayleigh, lambda c: henyey_greenstein(0.7)(c)[..., None] * np.ones(3)], [0.1] * 3,
                               100e3, n_u=11, n_s=5, n_v=9, n_phi=7, n_half=6, n_phi_quad=8)
    assert tab.source.shape == (5, 9, 7, 11, 6)
    # the sun axis t = sign(mu_s) sqrt(|mu_s|) from DIFFUSE_SUN_T_MIN to 1; a plane-parallel sun at or below the
    # horizon lights nothing
    np.testing.assert_allclose(tab.t_s, np.linspace(DIFFUSE_SUN_T_MIN, 1.0, 5))
    below = tab.t_s <= 0
    assert below.sum() == 2 and np.all(tab.source[below] == 0)
    assert np.all(tab.source[~below][..., :3] > 0)
    assert np.all(tab.source[..., 3:] == 0)  # no aerosol extinction: that component is skipped
    # more Rayleigh scattering at shorter wavelengths: bluer diffuse light at the ground
    d = tab.diffuse_down[0, -1]
    assert d[2] > d[1] > d[0] > 0
    # the diffuse light dims with height (less air above to scatter downwards)
    assert np.all(np.diff(tab.diffuse_down[:, -1, 1]) < 0)


def test_symmetric_kernel_conserves_energy_both_ways():
    mu, phi, w = _direction_grid(8, 12)
    k = _kernel(henyey_greenstein(0.9), mu, phi, mu, phi, w, symmetric=True)
    np.testing.assert_allclose(k.sum(axis=1), 1.0, rtol=1e-9)
    np.testing.assert_allclose(w @ k, w, rtol=1e-6)


def test_aerosol_layer_albedo_limits_of_eqs_30_31():
    """omega' (Eq. 31) tends to omega for a thin layer (Eq. 30), is 1 without absorption, and falls with tau
    while the albedo a rises towards its semi-infinite value."""
    hg = henyey_greenstein(0.7)
    ssa = np.array([0.8, 0.9, 1.0])
    thin = aerosol_layer_albedo(0.001, ssa, hg, 0.6)
    np.testing.assert_allclose(thin["omega_prime"], ssa, rtol=0.003)
    assert thin["omega_prime"][2] == pytest.approx(1.0, abs=1e-9)
    # single scattering: a = omega tau / mu0 x (backscattered share of the beam), small
    assert np.all(thin["albedo"] < 0.001 / 0.6)
    # the second order (absorption on the way out) grows with tau: omega' departs from omega
    assert np.all(aerosol_layer_albedo(0.01, ssa[:2], hg, 0.6)["omega_prime"] < thin["omega_prime"][:2])
    taus = [0.3, 1.0, 3.0, 8.0]
    rows = [aerosol_layer_albedo(t, ssa[:2], hg, 0.6) for t in taus]
    omega_prime = np.array([r["omega_prime"] for r in rows])
    albedo = np.array([r["albedo"] for r in rows])
    assert np.all(np.diff(omega_prime, axis=0) < 0)
    assert np.all(np.diff(albedo, axis=0) > 0)
    assert np.all(albedo[:, 0] < albedo[:, 1])  # more absorption, darker
    with pytest.raises(ValueError, match="single-scattering albedo"):
        aerosol_layer_albedo(1.0, 1.2, hg, 0.6)
    with pytest.raises(ValueError, match="mu0"):
        aerosol_layer_albedo(1.0, 0.9, hg, 0.0)


@pytest.mark.parametrize("shape", [(7,), (4, 5)])
def test_aerosol_column_classes(shape):
    rng = np.random.default_rng(1)
    column = rng.uniform(0.2, 2.0, shape)
    classes = aerosol_column_classes(column)
    assert classes[0] == pytest.approx(column.min(), rel=2e-3)
    assert classes[-1] == pytest.approx(column.max(), rel=2e-3)
    assert np.all(np.diff(classes) > 0) and len(classes) == 5
    assert aerosol_column_classes(np.full(shape, 0.7)) is None  # uniform: the mean column serves
    assert aerosol_column_classes(np.zeros(shape)) is None
    with pytest.raises(SwimInputError, match="column aerosol optical depth"):
        aerosol_column_classes(-column)


def test_twilight_rows_of_the_gas_tables_fill_the_earths_shadow():
    """The pseudo-spherical beam lights the upper air of a sun below the horizon: the ground's zenith diffuse source
    is nonzero down to civil twilight's end, falls steadily as the sun sinks, and passes the horizon continuously."""
    from swim.rt.gas import build_gas_tables

    tab = build_gas_tables().diffuse_source
    mu_s = np.sign(tab.t_s) * tab.t_s**2
    zenith = tab.source[:, np.argmin(np.abs(tab.mu_v - 1.0)), 0, 0, 1]  # molecules, 546 nm, at the ground
    twilight = (mu_s > np.sin(np.radians(-7.0))) & (mu_s < 0.1)
    assert np.all(zenith[twilight] > 0)
    lit = zenith > 0
    assert np.all(np.diff(zenith[lit]) > 0) and np.all(mu_s[lit] > np.sin(np.radians(-18.0)))
    horizon = int(np.argmin(np.abs(mu_s)))
    # on the horizon the source lies between its neighbours' and near their mean (no step at mu_s = 0)
    assert zenith[horizon - 1] < zenith[horizon] < zenith[horizon + 1]
    assert zenith[horizon] == pytest.approx(0.5 * (zenith[horizon - 1] + zenith[horizon + 1]), rel=0.3)
    # the ground's diffuse irradiance at twilight: lit, and far below the day's
    assert 0 < tab.diffuse_down[0, horizon - 1, 1] < 0.1 * tab.diffuse_down[0, -1, 1]
