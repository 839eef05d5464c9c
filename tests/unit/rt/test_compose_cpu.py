"""The numba composition of the clouds' radiance (:mod:`swim.rt.compose_cpu`) against the JAX one
(:func:`swim.rt.march_jax._compose_clouds`), which the physics tests hold to the paper's equations.

Both are evaluated in float64 (JAX with ``jax.enable_x64``) on random ray states that cover every branch: no cloud,
thin and thick clouds, each packed set of species, views from below, across the horizon and from above, a low, a
high and a set sun, the forward and backward scattering directions, rays outside the camera."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from swim.constants import BACKSCATTER_FRACTION, SPECIES
from swim.optics.phase import G_LIQUID
from swim.rt import compose_cpu
from swim.rt.march_jax import _compose_clouds
from swim.rt.march_settings import FROM_ABOVE_BLEND


def random_states(rng, n, species):
    """Per-ray inputs of the composition for n rays whose clouds hold the packed ``species`` (indices into SPECIES)."""
    tau = np.exp(rng.uniform(np.log(1e-5), np.log(300.0), n))
    tau[rng.random(n) < 0.2] = 0.0
    tau[:4] = (0.0, 1e-7, 2e-6, 1.0)  # below, around and above the 1e-6 threshold of "sees a cloud"
    fractions = rng.dirichlet(np.ones(len(species)), n)
    norm = -np.expm1(-np.minimum(tau, 2.0))
    i_nogas = norm[:, None] * rng.uniform(0.01, 3.0, (n, 3))
    i_gas = i_nogas * rng.uniform(0.2, 1.0, (n, 3))
    i_nogas[5] = 0.0  # a ray whose integrals vanish (the 1e-30 guard)
    i_gas[5] = 0.0
    cos_theta = rng.uniform(-1.0, 1.0, n)
    cos_theta[6:9] = (1.0, -1.0, 0.9999999)
    cos_view_zenith = rng.uniform(-1.0, 1.0, n)
    cos_view_zenith[9:13] = (-FROM_ABOVE_BLEND, -0.5 * FROM_ABOVE_BLEND, 0.0, -1.0)
    return {
        "tau_h": tau, "tau_packed": tau[:, None] * fractions, "i_nogas": i_nogas, "i_gas": i_gas,
        "i_cloud_t": norm * rng.uniform(0.0, 1.2, n),  # T above 1 is clipped
        "l_clear": rng.uniform(0.0, 0.5, (n, 3)), "l_surface": rng.uniform(0.0, 0.3, (n, 3)) * (rng.random((n, 1)) < 0.5),
        "valid": rng.random(n) < 0.9, "cos_theta": cos_theta, "cos_view_zenith": cos_view_zenith,
    }


def jax_composition(st, species, mu0):
    """:func:`swim.rt.march_jax._compose_clouds` in float64: (radiance, clouds' radiance), (n, 3) each."""
    n = st["tau_h"].size
    tau_species = np.zeros((n, len(SPECIES)))
    tau_species[:, species] = st["tau_packed"]
    with jax.enable_x64(True):
        out = _compose_clouds(
            {"cos_theta": st["cos_theta"], "cos_view_zenith": st["cos_view_zenith"]},
            {"mu0": np.float64(mu0), "g_liquid": np.array(G_LIQUID),
             "backscatter": np.array([BACKSCATTER_FRACTION[s] for s in SPECIES])},
            {"tau_h": st["tau_h"], "tau_species": tau_species, "i_nogas": st["i_nogas"], "i_gas": st["i_gas"],
             "i_cloud_t": st["i_cloud_t"], "l_clear": st["l_clear"], "tau_clear": np.zeros((n, 3))},
            st["valid"], np.zeros(n, bool), np.zeros(n), st["l_surface"])
        return np.asarray(out["radiance"]), np.asarray(out["radiance_cloud"])


def numba_composition(st, species, mu0, dtype=np.float64):
    n = st["tau_h"].size
    radiance, cloud = np.empty((n, 3), dtype), np.empty((n, 3), dtype)
    compose_cpu.compose_clouds(st["tau_h"], st["tau_packed"], np.asarray(species, np.int64), st["i_nogas"],
                               st["i_gas"], st["i_cloud_t"], st["l_clear"], st["l_surface"], st["valid"],
                               st["cos_theta"], st["cos_view_zenith"], float(mu0), compose_cpu.G_LIQUID_ARRAY,
                               compose_cpu.BACKSCATTER_ARRAY, compose_cpu.COEFFICIENTS, compose_cpu.LOBES, radiance,
                               cloud)
    return radiance, cloud


SPECIES_SETS = {
    "liquid": [0],
    "liquid and rain": [0, 2],
    "all five": [0, 1, 2, 3, 4],
    "ice and snow": [1, 3],
    "graupel": [4],
}


@pytest.mark.parametrize("mu0", [0.97, 0.5, 0.03, -0.05])
@pytest.mark.parametrize("packed", list(SPECIES_SETS))
def test_numba_composition_matches_jax(packed, mu0):
    species = SPECIES_SETS[packed]
    st = random_states(np.random.default_rng([len(species), int(100 * mu0) + 10]), 400, species)
    want_radiance, want_cloud = jax_composition(st, species, mu0)
    radiance, cloud = numba_composition(st, species, mu0)
    assert np.all(np.isfinite(radiance)) and np.all(np.isfinite(cloud))
    # the same equations in float64 (fast-math reassociation: ~1e-12)
    np.testing.assert_allclose(cloud, want_cloud, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(radiance, want_radiance, rtol=1e-9, atol=1e-12)
    assert np.all(radiance[~st["valid"]] == 0.0)
    assert np.all(cloud[st["tau_h"] <= 1e-6] == 0.0)
    seen = st["valid"] & (st["tau_h"] > 1e-3) & (mu0 > 0) & (st["i_gas"][:, 0] > 0)
    assert np.all(cloud[seen] > 0.0)  # lit clouds are seen: the comparison is not of zeros


def test_numba_composition_writes_float32_outputs():
    """The render's outputs are float32: the same values as the float64 call, rounded."""
    species = SPECIES_SETS["all five"]
    st = random_states(np.random.default_rng(3), 200, species)
    r64, c64 = numba_composition(st, species, 0.6)
    r32, c32 = numba_composition(st, species, 0.6, np.float32)
    assert r32.dtype == np.float32 and c32.dtype == np.float32
    np.testing.assert_allclose(r32, r64, rtol=1e-6)
    np.testing.assert_allclose(c32, c64, rtol=1e-6, atol=1e-30)
