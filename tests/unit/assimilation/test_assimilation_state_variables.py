"""A state of several variables (cloud liquid and ice contents, the droplets' effective radius, the 3-D aerosol's
extinction): its map reproduces the render's packed volume, the ground's fields and the aerosol column at the
reference, and the operator's tangent-linear operator matches finite differences in float64 for each variable and
its adjoint is its transpose. The states' kinds (array, dict, Dataset) and the refusals of bad variables and scenes
are checked without building an operator (the quick tier)."""

import sys
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest
import xarray as xr

from swim.assimilation import ForwardOperator
from swim.assimilation.operator import state_like, state_parts
from swim.assimilation.setup import check_scene_for_state, reference_values, scene_tables, state_variables
from swim.assimilation.state import march_inputs
from swim.errors import SwimInputError
from swim.io.scene import scene_from_arrays

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_assimilation_operator import OBSERVERS, SETTINGS  # noqa: E402
from test_assimilation_state import _scene  # noqa: E402

VARIABLES = ("cloud_liquid_content", "cloud_ice_content", "cloud_liquid_effective_radius", "aerosol_extinction")


def _mixed_scene():
    """The small cloud over a hill (:func:`_scene`) with an ice cloud above it, the droplets' effective radius given
    in the liquid cloud only, and a boundary-layer aerosol that thickens towards the east."""
    base = _scene()
    x = (np.arange(10) - 4.5) * 400.0  # the grid of _scene
    y, z = x[:9], np.arange(0.0, 4000.0, 250.0) + 125.0
    zz, yy, xx = np.meshgrid(z, y, x, indexing="ij")
    liquid = base["cloud_liquid_content"].values
    ice = 1e-4 * np.exp(-(((xx + 400) / 1000) ** 2 + ((yy - 100) / 900) ** 2 + ((zz - 3300) / 300) ** 2))
    radius = np.where(liquid > 0, 8e-6 + 6e-6 * liquid / liquid.max(), 0.0)
    aerosol = 1e-4 * (1.0 + 0.5 * (xx + 2000) / 4000) * np.exp(-zz / 1500.0)
    return scene_from_arrays(x=x, y=y, z=z, reference_lat=30.0,
                             reference_lon=10.0, terrain_height=base["terrain_height"].values,
                             cloud_liquid_content=liquid, cloud_ice_content=ice,
                             cloud_liquid_effective_radius=radius, aerosol_extinction=aerosol, land_mask=1.0)


def _dot(a, b):
    return sum(float(np.vdot(np.asarray(x, np.float64), np.asarray(y, np.float64))) for x, y in zip(a, b))


def test_state_variables_must_be_known_and_distinct():
    assert state_variables("cloud_ice_content") == ("cloud_ice_content",)
    assert state_variables(VARIABLES) == VARIABLES
    for bad in ((), ("cloud_liquid_content", "cloud_liquid_content"), ("ice_content",), ("height",)):
        with pytest.raises(SwimInputError, match="state_variables"):
            state_variables(bad)


def test_the_scene_must_give_the_reference_of_the_states_variables():
    scene = _scene()
    check_scene_for_state(scene, ("cloud_liquid_content", "cloud_liquid_effective_radius"))
    with pytest.raises(SwimInputError, match="cloud_ice_content"):
        check_scene_for_state(scene, ("cloud_ice_effective_radius",))
    with pytest.raises(SwimInputError, match="aerosol_extinction"):
        check_scene_for_state(scene, ("aerosol_extinction",))


def test_a_state_is_an_array_a_dict_or_a_dataset_and_its_gradient_comes_back_alike():
    z = np.zeros((2, 3, 4))
    parts, kind = state_parts(z, ("cloud_ice_content",))
    assert kind == "array" and parts["cloud_ice_content"] is z
    assert state_like({"cloud_ice_content": z + 1}, kind, z)[0, 0, 0] == 1.0
    variables = ("cloud_ice_content", "aerosol_extinction")
    parts, kind = state_parts({"aerosol_extinction": z, "cloud_ice_content": z + 1}, variables)
    assert kind == "dict" and list(parts) == list(variables)
    dims = ("z", "y", "x")
    ds = xr.Dataset({"cloud_ice_content": (("y", "z", "x"), np.ones((3, 2, 4))), "aerosol_extinction": (dims, z),
                     "height": (dims, z)}, coords={"x": np.arange(4.0)})
    parts, kind = state_parts(ds, variables)
    assert kind == "dataset" and parts["cloud_ice_content"].shape == (2, 3, 4)
    back = state_like({v: 2.0 * np.asarray(a) for v, a in parts.items()}, kind, ds)
    assert isinstance(back, xr.Dataset) and set(back.data_vars) == set(variables)
    assert back["cloud_ice_content"].dims == dims and float(back["cloud_ice_content"].max()) == 2.0
    np.testing.assert_array_equal(back["x"].values, ds["x"].values)
    with pytest.raises(SwimInputError, match="one-variable"):
        state_parts(z, variables)
    with pytest.raises(SwimInputError, match="missing"):
        state_parts({"cloud_ice_content": z}, variables)
    with pytest.raises(SwimInputError, match="not of the state"):
        state_parts({"cloud_ice_content": z, "aerosol_extinction": z, "rain_content": z}, variables)
    with pytest.raises(SwimInputError, match="missing"):
        state_parts(ds.drop_vars("aerosol_extinction"), variables)


@pytest.mark.full  # JAX's compilation of the map: seconds on a cold cache
def test_the_map_of_a_mixed_state_gives_the_renders_packed_volume_and_ground():
    """At the reference, the map writes the render's own values (:func:`swim.rt.march_inputs.volume_constants`):
    the liquid's and the ice's extinction (Eq. 7 with the scene's radius where it gives one, Martin's elsewhere), the
    aerosol's extinction and optical depth towards the sun, Step 1a's T, the ground's T and aerosol optical depth and
    the aerosol column."""
    scene = _mixed_scene()
    _, _, volume, _, host, state_map, layout = scene_tables(scene, 50.0, 120.0, variables=VARIABLES)
    assert [name for name, _ in layout.species_channels] == ["cloud_liquid", "cloud_ice"]
    assert layout.aerosol_channel == 2
    reference = reference_values(scene, VARIABLES)
    radius = scene["cloud_liquid_effective_radius"].values
    np.testing.assert_array_equal(reference["cloud_liquid_effective_radius"][radius > 0], radius[radius > 0])
    given = march_inputs({v: jnp.asarray(a, jnp.float32) for v, a in reference.items()}, state_map, layout)
    packed = np.asarray(host["volume"])
    out = np.asarray(given["volume"])
    assert out.shape == packed.shape
    for channel, atol in ((0, 1e-9), (1, 1e-9), (2, 1e-9), (3, 2e-5), (4, 2e-5)):
        assert np.abs(packed[..., channel]).max() > 1e-5
        np.testing.assert_allclose(out[..., channel], packed[..., channel], rtol=2e-5, atol=atol, err_msg=channel)
    np.testing.assert_allclose(np.asarray(given["surface"]), np.asarray(host["surface"]), rtol=2e-5, atol=2e-5)
    np.testing.assert_allclose(np.asarray(given["aerosol_column"]), np.asarray(host["aerosol_column"]), rtol=1e-5)


@pytest.mark.full  # the operator's JAX programs: 20-50 s each to compile on an empty cache
def test_each_variables_derivative_matches_finite_differences(x64):
    """Central differences in float64 along a random relative perturbation of one variable at a time, the step
    placement held fixed: within 1 %."""
    op = ForwardOperator(_mixed_scene(), OBSERVERS, sun_zenith=40.0, sun_azimuth=135.0, state_variables=VARIABLES,
                         settings=SETTINGS, dtype=jnp.float64)
    x = {v: jnp.asarray(a) for v, a in op.reference_state.items()}
    rng = np.random.default_rng(11)
    for variable in VARIABLES:
        d = {v: jnp.zeros_like(a) for v, a in x.items()}
        d[variable] = x[variable] * jnp.asarray(rng.standard_normal(x[variable].shape))
        h = 1e-4
        tangent = op.tangent_linear(x, d)
        plus = op({v: a + h * d[v] for v, a in x.items()})
        minus = op({v: a - h * d[v] for v, a in x.items()})
        fd = [(p - m) / (2 * h) for p, m in zip(plus, minus)]
        assert _dot(tangent, tangent) > 1e-6, f"the images must change with {variable}"
        error = np.sqrt(_dot([a - b for a, b in zip(fd, tangent)], [a - b for a, b in zip(fd, tangent)])
                        / _dot(tangent, tangent))
        assert error < 0.01, (variable, error)


@pytest.mark.full  # as above
def test_the_adjoint_of_a_mixed_state_is_the_transpose_and_keeps_the_states_kind():
    """<J dx, dy> = <dx, J^T dy> in float32 over all variables together; a Dataset's gradient is a Dataset."""
    scene = _mixed_scene()
    op = ForwardOperator(scene, OBSERVERS, sun_zenith=40.0, sun_azimuth=135.0, state_variables=VARIABLES,
                         settings=SETTINGS)
    x = op.reference_state
    rng = np.random.default_rng(12)
    dx = {v: a * rng.standard_normal(a.shape) for v, a in x.items()}
    dy = [rng.standard_normal((3,) + m.shape) * m for m in op.masks]
    lhs = _dot(op.tangent_linear(x, dx), dy)
    grad = op.adjoint(x, dy)
    rhs = _dot([dx[v] for v in VARIABLES], [grad[v] for v in VARIABLES])
    assert abs(lhs) > 1e-3
    assert rhs == pytest.approx(lhs, rel=2e-5)
    dataset = scene[list(VARIABLES)].copy()
    dataset["cloud_liquid_effective_radius"] = (("z", "y", "x"), x["cloud_liquid_effective_radius"])
    value, grad_ds = op.value_and_grad(lambda images: sum(jnp.sum(i ** 2) for i in images), dataset)
    assert isinstance(grad_ds, xr.Dataset) and float(value) > 0
    assert float(jnp.abs(grad_ds["aerosol_extinction"].values).max()) > 0
    with pytest.raises(SwimInputError, match="> 0"):
        op({**x, "cloud_liquid_effective_radius": np.zeros_like(x["cloud_liquid_effective_radius"])})
