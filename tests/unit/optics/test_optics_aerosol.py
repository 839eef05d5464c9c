"""Background aerosol profile and Ångström scaling against analytic results."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import quad

from swim.errors import SwimInputError
from swim.optics.aerosol import angstrom_extinction, exponential_aerosol_extinction


@pytest.mark.parametrize("aod, h", [(0.05, 1500.0), (0.3, 2500.0)])
def test_column_integral_equals_aod(aod, h):
    column, _ = quad(lambda z: float(exponential_aerosol_extinction(z, aod, h)), 0.0, np.inf)
    assert column == pytest.approx(aod, rel=1e-8)


def test_profile_shape_and_defaults():
    beta = exponential_aerosol_extinction(np.array([[0.0, 1500.0], [3000.0, 100_000.0]]))
    assert beta.shape == (2, 2)
    assert beta[0, 0] == pytest.approx(0.05 / 1500.0)  # defaults: AOD 0.05, H = 1500 m
    assert beta[0, 1] == pytest.approx(beta[0, 0] / np.e)
    assert beta[1, 1] < 1e-30


def test_angstrom_law():
    lam = np.array([450.0, 546.0, 550.0, 615.0])
    beta = angstrom_extinction(1.0, lam)
    np.testing.assert_allclose(beta, (lam / 550.0) ** -1.3)
    assert beta[2] == 1.0
    np.testing.assert_allclose(angstrom_extinction(2.0, lam, 0.0), 2.0)  # coarse dust: neutral
    assert beta[0] == pytest.approx(1.2981, abs=1e-4)  # (450/550)^-1.3


def test_jit_paths():
    z = jnp.array([0.0, 1500.0], jnp.float32)
    out = jax.jit(lambda h: angstrom_extinction(exponential_aerosol_extinction(h), 450.0))(z)
    assert out.dtype == jnp.float32
    np.testing.assert_allclose(np.asarray(out), 0.05 / 1500 * np.exp([0.0, -1.0]) * (450 / 550) ** -1.3, rtol=1e-5)


@pytest.mark.parametrize(
    "call",
    [
        lambda: exponential_aerosol_extinction(0.0, -0.1),
        lambda: exponential_aerosol_extinction(0.0, 0.1, 0.0),
        lambda: exponential_aerosol_extinction(np.nan),
        lambda: angstrom_extinction(1.0, 0.0),
        lambda: angstrom_extinction(-1.0, 500.0),
    ],
)
def test_bad_input_raises(call):
    with pytest.raises(SwimInputError):
        call()
