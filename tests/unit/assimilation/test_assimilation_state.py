"""The map from the state (cloud liquid water content) to the march's inputs: its values against the render's own
optical volume and Step 1a, the effective radius against Martin et al. (1994), and its derivatives."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from swim.assimilation.setup import scene_tables
from swim.assimilation.state import (MARTIN_LOWER_LWC, effective_radius_liquid, march_inputs, species_extinction,
                                     transmittance)
from swim.io.scene import scene_from_arrays
from swim.rt.solar import solar_transmittance, transmittance_delta_eddington


def _scene():
    """A small cloud over a hill: 10 x 9 columns, 16 levels of 250 m."""
    n, spacing = 10, 400.0
    x = (np.arange(n) - n / 2 + 0.5) * spacing
    y = x[:9]
    z = np.arange(0.0, 4000.0, 250.0) + 125.0
    zz, yy, xx = np.meshgrid(z, y, x, indexing="ij")
    liquid = 6e-4 * np.exp(-(((xx - 300) / 900) ** 2 + ((yy + 200) / 700) ** 2 + ((zz - 2000) / 500) ** 2))
    terrain = 400.0 * np.exp(-(((xx[0] + 1200) / 800) ** 2 + ((yy[0] - 600) / 800) ** 2))
    return scene_from_arrays(x=x, y=y, z=z, reference_lat=30.0, reference_lon=10.0, terrain_height=terrain,
                             cloud_liquid_content=liquid, land_mask=1.0)


def test_effective_radius_is_martins_with_a_finite_derivative():
    # Martin et al. (1994) with k = 0.8, N = 100 cm-3: 6.7, 9.6 and 11.4 um at 0.1, 0.3 and 0.5 g m-3
    r = np.asarray(effective_radius_liquid(jnp.asarray([1e-4, 3e-4, 5e-4])))
    np.testing.assert_allclose(r, [6.7e-6, 9.6e-6, 11.4e-6], rtol=0.01)
    assert float(effective_radius_liquid(jnp.asarray(0.0))) == pytest.approx(4e-6, rel=1e-5)
    slope = jax.vmap(jax.grad(effective_radius_liquid))(jnp.asarray([0.0, 0.5 * MARTIN_LOWER_LWC, 3e-4]))
    assert np.all(np.isfinite(slope)) and float(slope[0]) == 0.0 and float(slope[2]) > 0.0


def test_transmittance_is_delta_eddingtons_with_a_finite_derivative_above_the_clouds():
    tau = jnp.asarray([0.0, 0.1, 3.0, 40.0], jnp.float32)
    b_tau = 0.063 * tau
    np.testing.assert_allclose(transmittance(tau, b_tau, 0.6), transmittance_delta_eddington(tau, b_tau, 0.6),
                               rtol=1e-6)
    slope = jax.vmap(jax.grad(lambda t: transmittance(t, 0.063 * t, 0.6)))(tau)
    assert np.all(np.isfinite(np.asarray(slope))) and float(slope[0]) < 0.0


@pytest.mark.full  # JAX's compilation of the map: seconds on a cold cache
def test_the_state_gives_the_renders_extinction_and_step_1a():
    scene = _scene()
    _, sun, volume, _, _, state_map, layout = scene_tables(scene, 50.0, 120.0)
    lwc = jnp.asarray(scene["cloud_liquid_content"].values, jnp.float32)
    beta = np.asarray(species_extinction("cloud_liquid", {"cloud_liquid_content": lwc}, state_map))
    expected = volume["extinction"].sel(species="cloud_liquid").values
    np.testing.assert_allclose(beta, expected, rtol=2e-5, atol=1e-9)
    packed = march_inputs({"cloud_liquid_content": lwc}, state_map, layout)["volume"]
    t_host = solar_transmittance(volume, sun, variables=["cloud_transmittance"])["cloud_transmittance"].values
    t = np.asarray(packed[..., layout.t_channel])
    assert t.min() < 0.7, "the cloud must shade the levels below it"
    np.testing.assert_allclose(t, t_host, atol=2e-5)


@pytest.mark.full  # as above; the quick tier keeps the derivatives of its pieces and the misfits'
def test_the_state_maps_derivative_matches_finite_differences():
    old = jax.config.jax_enable_x64
    jax.config.update("jax_enable_x64", True)
    try:
        _, _, _, _, _, state_map, layout = scene_tables(_scene(), 50.0, 120.0, dtype=jnp.float64)
        lwc = jnp.asarray(_scene()["cloud_liquid_content"].values, jnp.float64)
        direction = lwc * jnp.asarray(np.random.default_rng(0).standard_normal(lwc.shape))

        def f(a):
            inputs = march_inputs({"cloud_liquid_content": a}, state_map, layout)
            return inputs["volume"][..., layout.t_channel], inputs["surface"][layout.surface_t_channel]

        _, tangent = jax.jvp(f, (lwc,), (direction,))
        h = 1e-4
        plus, minus = f(lwc + h * direction), f(lwc - h * direction)
        for t, p, m in zip(tangent, plus, minus):
            fd = (p - m) / (2 * h)
            assert float(jnp.abs(t).max()) > 1e-3, "T must change with the liquid water"
            assert float(jnp.linalg.norm(fd - t) / jnp.linalg.norm(t)) < 1e-6
    finally:
        jax.config.update("jax_enable_x64", old)


@pytest.mark.full  # with the map's derivative and the operator's adjoint test
def test_the_state_maps_adjoint_is_its_transpose():
    """<J dx, dy> = <dx, J^T dy> to float32 rounding for the map to the packed volume and the ground's fields
    (Eq. 7, the resampling, Step 1a's sweep and T)."""
    scene = _scene()
    _, _, _, _, _, state_map, layout = scene_tables(scene, 50.0, 120.0)
    lwc = jnp.asarray(scene["cloud_liquid_content"].values, jnp.float32)
    rng = np.random.default_rng(4)
    dx = jnp.asarray(rng.standard_normal(lwc.shape) * 1e-4, jnp.float32)
    def f(a):
        inputs = march_inputs({"cloud_liquid_content": a}, state_map, layout)
        return inputs["volume"], inputs["surface"]

    outputs, tangent = jax.jvp(f, (lwc,), (dx,))
    dy = tuple(jnp.asarray(rng.standard_normal(o.shape), jnp.float32) for o in outputs)
    _, pull = jax.vjp(f, lwc)
    lhs = sum(float(np.vdot(np.asarray(t, np.float64), np.asarray(d, np.float64))) for t, d in zip(tangent, dy))
    rhs = float(np.vdot(np.asarray(dx, np.float64), np.asarray(pull(dy)[0], np.float64)))
    assert abs(lhs) > 1e-3
    assert rhs == pytest.approx(lhs, rel=1e-5)
