"""Rayleigh scattering against Bodhaine et al. (1999) (B99) published numbers and analytic limits."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from numpy.polynomial.legendre import leggauss

from swim.errors import SwimInputError
from swim.optics.rayleigh import (
    DEPOLARIZATION_546NM,
    rayleigh_cross_section_bodhaine1999,
    rayleigh_depolarization_ratio,
    rayleigh_optical_depth_bodhaine1999,
    rayleigh_phase_function,
)

# B99 Table 3: Rayleigh optical depth at 1013.25 hPa, 45°, sea level, 360 ppm CO2 (5 significant digits).
B99_TABLE3 = {400.0: 0.36022, 450.0: 0.22111, 500.0: 0.14336, 550.0: 0.09707, 600.0: 0.06809, 700.0: 0.03642}


def _b99_eq29_sigma_m2(lam_um):
    """B99 Eq. 29, their published fit of σ [1e-28 cm2] for 360 ppm CO2, in m2."""
    return (
        (1.0455996 - 341.29061 * lam_um**-2 - 0.90230850 * lam_um**2)
        / (1.0 + 0.0027059889 * lam_um**-2 - 85.968563 * lam_um**2)
        * 1e-28 * 1e-4
    )


@pytest.mark.parametrize("lam_nm, tau", sorted(B99_TABLE3.items()))
def test_optical_depth_matches_b99_table3(lam_nm, tau):
    # tolerance: the table's last digit (±5e-6 on 0.03642 is 1.4e-4 relative) plus margin
    assert rayleigh_optical_depth_bodhaine1999(lam_nm) == pytest.approx(tau, rel=3e-4)


def test_optical_depth_matches_b99_eq30_in_the_uv():
    lam = 0.25
    # B99 Eq. 30: τ = 0.0021520 × (Eq. 29 numerator / denominator) at 1013.25 hPa, 45°, sea level
    tau_fit = 0.0021520 * _b99_eq29_sigma_m2(lam) / 1e-32
    assert rayleigh_optical_depth_bodhaine1999(250.0) == pytest.approx(tau_fit, rel=1e-3)
    assert tau_fit == pytest.approx(2.71, abs=0.01)


def test_cross_section_matches_b99_eq29_fit():
    lam_nm = np.array([250.0, 350.0, 450.0, 546.0, 615.0, 700.0, 850.0])
    sigma = rayleigh_cross_section_bodhaine1999(lam_nm)
    np.testing.assert_allclose(sigma, _b99_eq29_sigma_m2(lam_nm / 1e3), rtol=2e-4)


def test_pressure_and_latitude_scaling():
    base = rayleigh_optical_depth_bodhaine1999(550.0)
    assert rayleigh_optical_depth_bodhaine1999(550.0, pressure_pa=50_662.5) == pytest.approx(base / 2, rel=1e-12)
    # τ ∝ 1/g: gravity is 0.53 % larger at the poles (9.832 vs 9.780 m s-2)
    ratio = rayleigh_optical_depth_bodhaine1999(550.0, latitude_deg=0.0) / rayleigh_optical_depth_bodhaine1999(
        550.0, latitude_deg=90.0
    )
    assert ratio == pytest.approx(9.8322 / 9.7803, rel=5e-4)


def test_depolarization_ratio():
    rho = rayleigh_depolarization_ratio(np.array([450.0, 546.0, 615.0]))
    # the King factor of air in the visible is 1.048-1.050 (Bates 1984), i.e. ρ ≈ 0.028-0.029
    assert np.all((rho > 0.0275) & (rho < 0.0295))
    assert np.all(np.diff(rho) < 0)  # depolarisation decreases with wavelength
    assert rho[1] == pytest.approx(DEPOLARIZATION_546NM, abs=1e-5)


_phase = jax.jit(rayleigh_phase_function)  # compiled once (eager jax compiles each primitive per shape)


@pytest.mark.parametrize("rho", [0.0, 0.0279, 0.1])
def test_phase_function_mean_is_one(rho):
    x, w = leggauss(64)  # exact for the degree-2 polynomial in cos θ
    with jax.enable_x64(True):
        assert 0.5 * np.sum(np.asarray(_phase(x, rho)) * w) == pytest.approx(1.0, abs=1e-12)


def test_phase_function_classical_limit_and_anisotropy():
    rho = 0.0279
    gamma = rho / (2 - rho)
    p = np.asarray(_phase(np.array([1.0, 0.0, -1.0])[:, None], np.array([0.0, rho])))
    np.testing.assert_allclose(p[:, 0], [1.5, 0.75, 1.5], rtol=1e-6)  # 3/4 (1 + cos²θ)
    # with anisotropy the 90° minimum rises: P(90°)/P(0°) = (1 + 3γ) / (2 (1 + γ)), γ = ρ/(2 - ρ)
    assert p[1, 1] / p[0, 1] == pytest.approx((1 + 3 * gamma) / (2 * (1 + gamma)), rel=1e-6)


def test_phase_function_runs_in_jit_float32():
    out = _phase(jnp.linspace(-1.0, 1.0, 7, dtype=jnp.float32))
    assert out.dtype == jnp.float32 and out.shape == (7,)


@pytest.mark.parametrize(
    "kwargs", [{"wavelength_nm": 100.0}, {"wavelength_nm": 550.0, "pressure_pa": -1.0},
               {"wavelength_nm": 550.0, "latitude_deg": 95.0}, {"wavelength_nm": 550.0, "co2_ppm": -5.0}]
)
def test_bad_input_raises(kwargs):
    with pytest.raises(SwimInputError):
        rayleigh_optical_depth_bodhaine1999(**kwargs)
