"""Hydrometeor extinction (paper Eq. 7, Stephens 1978) and effective radius (Martin et al. 1994)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from swim.constants import DEFAULT_EFFECTIVE_RADIUS, HYDROMETEOR_DENSITY
from swim.errors import SwimInputError
from swim.optics.hydrometeors import (
    effective_radius,
    effective_radius_liquid_martin1994,
    extinction_coefficient_stephens1978,
)


def test_eq7_liquid_cloud_case():
    # LWC 0.3 g m-3, r_e = 10 µm: β = 1.5 × 3e-4 / (1e-5 × 1000) = 0.045 m-1 = 45 km-1
    beta = extinction_coefficient_stephens1978(0.3e-3, 10e-6, HYDROMETEOR_DENSITY["cloud_liquid"])
    assert beta == pytest.approx(0.045, rel=1e-12)


def test_column_optical_depth_matches_stephens_relation():
    # Stephens (1978): τ = 3 LWP / (2 ρ_w r_e); LWP = 100 g m-2, r_e = 10 µm gives τ = 15
    z = np.linspace(0.0, 1000.0, 11)
    beta = extinction_coefficient_stephens1978(np.full_like(z, 0.1e-3), 10e-6, 1000.0)
    assert np.trapezoid(beta, z) == pytest.approx(15.0, rel=1e-12)


def test_eq7_broadcasts_and_runs_in_jit():
    beta = extinction_coefficient_stephens1978(np.array([[0.1e-3], [0.2e-3]]), np.array([5e-6, 10e-6]), 1000.0)
    assert beta.shape == (2, 2)
    out = jax.jit(extinction_coefficient_stephens1978)(jnp.array([0.3e-3], jnp.float32), 10e-6, 1000.0)
    assert out.dtype == jnp.float32 and float(out[0]) == pytest.approx(0.045, rel=1e-6)


@pytest.mark.parametrize(
    "args", [(-1e-4, 1e-5, 1000.0), (1e-4, 0.0, 1000.0), (1e-4, 1e-5, -1.0), (np.nan, 1e-5, 1000.0)]
)
def test_eq7_bad_input_raises(args):
    with pytest.raises(SwimInputError):
        extinction_coefficient_stephens1978(*args)


def test_martin_hand_calculation():
    # r_e = (3 LWC / (4 π ρ_w k N))^(1/3), LWC = 0.3 g m-3, k = 0.8, N = 100 cm-3
    expected = (3 * 0.3e-3 / (4 * np.pi * 1000.0 * 0.8 * 1e8)) ** (1 / 3)
    assert effective_radius_liquid_martin1994(0.3e-3) == pytest.approx(expected, rel=1e-12)
    assert expected == pytest.approx(9.64e-6, rel=1e-3)


def test_martin_typical_clouds_7_to_10_um_rising_with_content():
    lwc = np.linspace(0.1e-3, 0.3e-3, 9)
    r = effective_radius_liquid_martin1994(lwc)
    assert np.all(np.diff(r) > 0)
    assert 6.5e-6 < r[0] < 7.0e-6 and 9.5e-6 < r[-1] < 10.0e-6


def test_martin_clipped_to_4_20_um():
    r = effective_radius_liquid_martin1994(np.array([0.0, 1e-9, 10e-3]))
    np.testing.assert_allclose(r, [4e-6, 4e-6, 20e-6])
    # more droplets for the same water: smaller drops (the Twomey effect)
    assert effective_radius_liquid_martin1994(0.3e-3, 3e8) < effective_radius_liquid_martin1994(0.3e-3, 1e8)


def test_effective_radius_prefers_positive_scene_values():
    content = np.array([0.1e-3, 0.3e-3, 0.3e-3, 0.0])
    scene = np.array([np.nan, 12e-6, 0.0, -1.0])
    r = effective_radius("cloud_liquid", content, scene)
    np.testing.assert_allclose(r, [effective_radius_liquid_martin1994(0.1e-3), 12e-6,
                                   effective_radius_liquid_martin1994(0.3e-3), 4e-6])
    r = effective_radius("snow", content, scene)
    np.testing.assert_allclose(r, [4e-3, 12e-6, 4e-3, 4e-3])
    for species, default in DEFAULT_EFFECTIVE_RADIUS.items():
        if species != "cloud_liquid":
            assert np.all(effective_radius(species, content) == default)


def test_effective_radius_jit():
    f = jax.jit(lambda c, s: effective_radius("cloud_ice", c, s))
    out = f(jnp.array([1e-4, 2e-4]), jnp.array([jnp.nan, 50e-6]))
    np.testing.assert_allclose(np.asarray(out), [34e-6, 50e-6], rtol=1e-6)


def test_effective_radius_bad_input():
    with pytest.raises(SwimInputError, match="species"):
        effective_radius("hail", 1e-4)
    with pytest.raises(SwimInputError, match="content"):
        effective_radius("rain", -1e-4)
