"""The forward operator through the whole chain (Eq. 7, Step 1a, the march, the composition): its radiance against
the render's kernels, its tangent-linear operator against finite differences in float64 with the step placement held
fixed, its adjoint against the tangent-linear operator (<J dx, dy> = <dx, J^T dy>), and a misfit's gradient.

The JAX programs of the chain take 20-50 s each to compile on an empty cache (2 cores): the full tier."""

import sys
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

from swim.assimilation import ForwardOperator, Observer, one_minus_r, rmse
from swim.assimilation.retrieval import CONTENT_FLOOR
from swim.errors import SwimInputError
from swim.rt.march import trace_rays
from swim.rt.march_settings import MarchSettings

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_assimilation_state import _scene  # noqa: E402

pytestmark = pytest.mark.full

#: Few steps: the derivatives hold for any placement, and the tests stay quick once compiled.
SETTINGS = MarchSettings(n_before=4, n_grid=24, n_after=8)
#: A camera on the ground under the cloud and one above it looking down (ground, cloud tops and sides).
OBSERVERS = [Observer(height=20.0, camera_options=dict(width=6, height=6, fov_deg=70.0, view_azimuth_deg=30.0,
                                                        view_zenith_deg=30.0)),
             Observer(height=6000.0, camera_options=dict(width=5, height=5, fov_deg=70.0, view_azimuth_deg=200.0,
                                                         view_zenith_deg=150.0))]
#: Two scenes: the cloud over a hill under two suns.
CASES = {"sun in the south-east": (40.0, 135.0), "low sun in the west": (65.0, 250.0)}


@pytest.fixture(scope="module")
def operator32():
    return ForwardOperator(_scene(), OBSERVERS, sun_zenith=40.0, sun_azimuth=135.0, settings=SETTINGS)


def _dot(a, b):
    return sum(float(np.vdot(np.asarray(x, np.float64), np.asarray(y, np.float64))) for x, y in zip(a, b))


def _tangent_and_difference(op, x, dx, h):
    """The tangent-linear images at x along dx, and their central difference with step h."""
    return op.tangent_linear(x, dx), [(p - m) / (2 * h) for p, m in zip(op(x + h * dx), op(x - h * dx))]


def _relative_error(images, reference):
    """||images - reference|| / ||reference|| over all images, pixels and channels."""
    difference = [a - b for a, b in zip(images, reference)]
    return np.sqrt(_dot(difference, difference) / _dot(reference, reference))


def test_the_operators_radiance_is_the_kernels(operator32):
    """The same rays through the render's JAX and numba kernels (the same settings: no refinement, no stop in opaque
    cloud, the paper's clouds) give the operator's radiance of the reference state."""
    op = operator32
    images = op(op.reference_state)
    s = op.setup
    consts = {key: (np.asarray(v) if not isinstance(v, dict) else {k: np.asarray(w) for k, w in v.items()})
              for key, v in s.consts.items()}
    chunk = s.chunks[0]
    n = s.n_rays
    from swim.rt.march_inputs import grid_geometry
    from swim.assimilation.setup import scene_tables

    _, sun, volume, _, _, _, _ = scene_tables(_scene(), 40.0, 135.0)
    origins = np.asarray(chunk["start"][:n], float) + [0.0, 0.0, float(consts["radius"])]
    directions = np.asarray(chunk["direction"][:n], float)
    phase = {key: np.asarray(value[:n]) for key, value in chunk["rays"].items()}
    mine = np.concatenate([np.asarray(i).reshape(3, -1)[:, f].T for i, f in zip(images, s.pixels)])
    assert mine.max() > 0.3 and np.all(np.isfinite(mine))
    for backend, rtol in (("jax", 1e-4), ("numba", 2e-4)):  # T: the JAX and the numba sweep (float32)
        out = trace_rays(origins, directions, consts, grid_geometry(volume), phase,
                         s.settings.with_execution(backend=backend))
        np.testing.assert_allclose(mine, out["radiance"], rtol=rtol, atol=1e-5, err_msg=backend)


def test_the_adjoint_is_the_transpose_of_the_tangent_linear_operator(operator32):
    """In float32, with rays that meet no cloud (whose derivatives through Eq. 12's gas ratio and the delta-Eddington
    T must be finite, not 0 / 0) and rays that look down on the cloud and the ground."""
    op = operator32
    x = jnp.asarray(op.reference_state, jnp.float32)
    rng = np.random.default_rng(5)
    dx = x * jnp.asarray(rng.standard_normal(x.shape), jnp.float32)
    dy = [jnp.asarray(rng.standard_normal((3,) + m.shape), jnp.float32) * m for m in op.masks]
    lhs = _dot(op.tangent_linear(x, dx), dy)
    rhs = _dot([dx], [op.adjoint(x, dy)])
    assert abs(lhs) > 1e-2
    assert rhs == pytest.approx(lhs, rel=2e-5)  # float32 rounding (measured 1e-6)


@pytest.mark.parametrize("case", CASES)
def test_the_tangent_linear_operator_matches_finite_differences(case, x64):
    """Central differences in float64 along random directions (relative perturbations of the liquid water) with the
    step placement held fixed: within 1 % (measured ~1e-8 at h = 1e-4: second order)."""
    zenith, azimuth = CASES[case]
    op = ForwardOperator(_scene(), OBSERVERS, sun_zenith=zenith, sun_azimuth=azimuth, settings=SETTINGS,
                         dtype=jnp.float64)
    x = jnp.asarray(op.reference_state)
    rng = np.random.default_rng(6)
    h = 1e-4
    for _ in range(2):
        dx = x * jnp.asarray(rng.standard_normal(x.shape))
        tangent, fd = _tangent_and_difference(op, x, dx, h)
        assert _dot(tangent, tangent) > 1e-4, "the images must change with the liquid water"
        assert _relative_error(fd, tangent) < 0.01


def test_cloud_grown_on_clear_lines_of_sight_has_the_derivative_of_finite_differences(x64):
    """Liquid water added in the clear cells around a cloud with sharp edges, at the retrieval's floor of the content
    (swim.assimilation.retrieval.CONTENT_FLOOR: every line of sight through the grid meets a little cloud, so that
    Eq. 12's means over the cloud are defined): the tangent-linear operator gives the central finite difference to
    1 %. At exactly 0 the composition's cloud radiance is switched off and its derivative there is 0."""
    scene = _scene()
    liquid = scene["cloud_liquid_content"]
    scene["cloud_liquid_content"] = liquid.where(liquid > 2e-4, 0.0)
    op = ForwardOperator(scene, OBSERVERS, sun_zenith=40.0, sun_azimuth=135.0, settings=SETTINGS,
                         dtype=jnp.float64)
    clear = op.reference_state == 0.0
    x = jnp.asarray(np.maximum(op.reference_state, CONTENT_FLOOR))
    dx = jnp.asarray(np.where(clear, np.random.default_rng(8).uniform(0.0, 1.0, clear.shape), 0.0))
    tangent, fd = _tangent_and_difference(op, x, dx, 0.5 * CONTENT_FLOOR)
    assert _dot(fd, fd) > 1e-2, "cloud added on clear lines of sight must change the images"
    error = _relative_error(tangent, fd)
    assert error < 0.01, error


def test_value_and_grad_of_a_misfit_matches_finite_differences(x64):
    """The gradient of RMSE + (1 - r) against images of a thinner cloud, along a random direction."""
    op = ForwardOperator(_scene(), OBSERVERS[:1], sun_zenith=40.0, sun_azimuth=135.0, settings=SETTINGS,
                         dtype=jnp.float64)
    x = jnp.asarray(op.reference_state)
    observed = op(0.5 * x)

    def loss(images):
        return rmse(images, observed, op.masks) + one_minus_r(images, observed, op.masks)

    value, grad = op.value_and_grad(loss, x)
    assert float(value) == pytest.approx(float(loss(op(x))), rel=1e-12)
    direction = x * jnp.asarray(np.random.default_rng(7).standard_normal(x.shape))
    h = 1e-4
    fd = (float(loss(op(x + h * direction))) - float(loss(op(x - h * direction)))) / (2 * h)
    assert float(jnp.vdot(grad, direction)) == pytest.approx(fd, rel=0.01)


def test_bad_states_and_observers_are_refused(operator32):
    with pytest.raises(SwimInputError, match="shape"):
        operator32(np.zeros((2, 2, 2)))
    with pytest.raises(SwimInputError, match="finite"):
        operator32(np.full(operator32.reference_state.shape, np.nan))
    with pytest.raises(SwimInputError, match="Observer"):
        ForwardOperator(_scene(), [], sun_zenith=40.0, sun_azimuth=135.0)
