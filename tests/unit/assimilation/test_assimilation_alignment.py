"""Field alignment: the cloud objects, the warp (its values and its derivative) and the recovery of a known
displacement and amplitude, through a cheap linear stand-in for the forward operator (the cloud's projections), and,
in the full tier, through the forward operator of a small scene."""

import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from swim.assimilation.alignment import align_clouds, cloud_objects, split_objects, warp_state
from swim.errors import SwimInputError

sys.path.insert(0, str(Path(__file__).resolve().parent))


def _blob(shape=(6, 20, 20), centre=(2.5, 8.0, 9.0), peak=1e-3):
    """A smooth cloud (z, y, x) [kg m-3] cut off below 1e-5 kg m-3."""
    z, y, x = np.meshgrid(*(np.arange(s, dtype=float) for s in shape), indexing="ij")
    c = peak * np.exp(-(((z - centre[0]) / 1.5) ** 2 + ((y - centre[1]) / 3.0) ** 2 + ((x - centre[2]) / 2.5) ** 2))
    return np.where(c > 1e-5, c, 0.0)


class _Projections:
    """A linear stand-in for the forward operator: the images are the state's sums along z (a camera looking up)
    and along y (one looking north), three equal channels each."""

    dtype = jnp.float32

    def __init__(self, shape):
        self.setup = type("Setup", (), {"state_shape": shape})()

    def __call__(self, state):
        state = jnp.asarray(state, self.dtype) * 1e3
        return [jnp.stack([state.sum(axis=0)] * 3), jnp.stack([state.sum(axis=1)] * 3)]

    def value_and_grad(self, loss, state):
        return jax.value_and_grad(lambda x: loss(self(x)))(jnp.asarray(state, self.dtype))


def _cost(observed):
    return lambda images: 0.5 * sum(jnp.sum((x - y) ** 2) for x, y in zip(images, observed))


def test_cloud_objects_are_the_components_largest_first_and_fragments_stay_in_the_rest():
    state = _blob()
    state[1:4, 15:19, 15:19] = 2e-3  # 48 cells, heavier than the blob
    state[0, 0, 0] = 1e-3  # one cell
    labels, n = cloud_objects(state, min_cells=20)
    assert n == 2
    assert labels[2, 16, 16] == 1 and labels[2, 8, 9] == 2 and labels[0, 0, 0] == 0
    objects, rest = split_objects(state, labels, n)
    np.testing.assert_allclose(objects.sum(axis=0) + rest, state)
    with pytest.raises(SwimInputError, match="kg m-3"):
        cloud_objects(-state)


def test_an_integer_displacement_moves_an_object_as_np_roll_and_the_amplitude_scales_it():
    state = _blob()
    objects = jnp.asarray(state[None], jnp.float32)
    rest = jnp.zeros(state.shape, jnp.float32)
    params = jnp.asarray([0.0, 3.0, -2.0, np.log(1.5), 0.0], jnp.float32)
    moved = np.asarray(warp_state(objects, rest, params))
    np.testing.assert_allclose(moved, 1.5 * np.roll(state, (3, -2), axis=(1, 2)), rtol=1e-5, atol=1e-10)
    # half a cell: the mean of the two neighbours (trilinear interpolation)
    half = np.asarray(warp_state(objects, rest, jnp.asarray([0.0, 0.0, 0.5, 0.0, 0.0], jnp.float32)))
    np.testing.assert_allclose(half[:, :, 1:], 0.5 * (state[:, :, 1:] + state[:, :, :-1]), rtol=1e-5, atol=1e-10)
    # the rest stays and takes its own amplitude
    still = np.asarray(warp_state(objects[:0], objects[0], jnp.asarray([np.log(0.5)], jnp.float32)))
    np.testing.assert_allclose(still, 0.5 * state, rtol=1e-5)


@pytest.mark.full  # JAX's compilation of the warp's derivative and of L-BFGS-B's loop: ~15 s on a cold cache
def test_the_warps_derivative_matches_finite_differences():
    state = _blob()
    objects = jnp.asarray(state[None], jnp.float32)
    rest = jnp.asarray(0.3 * _blob(centre=(3.0, 15.0, 15.0)), jnp.float32)
    weights = jnp.asarray(np.random.default_rng(0).standard_normal(state.shape), jnp.float32)

    def f(p):
        return jnp.sum(weights * warp_state(objects, rest, p)) * 1e3

    p = np.array([0.3, 1.3, -0.6, 0.2, -0.1])  # away from whole cells: the interpolation is linear in between
    grad = np.asarray(jax.grad(f)(jnp.asarray(p, jnp.float32)))
    for m in range(p.size):
        e = np.zeros_like(p)
        e[m] = 1e-2
        fd = (float(f(jnp.asarray(p + e, jnp.float32))) - float(f(jnp.asarray(p - e, jnp.float32)))) / 2e-2
        assert grad[m] == pytest.approx(fd, rel=2e-2, abs=1e-3 * float(np.abs(grad).max()))


@pytest.mark.full  # as above
def test_alignment_recovers_a_known_displacement_and_amplitude():
    truth = _blob(centre=(2.5, 11.0, 12.0))
    guess = 0.6 * np.roll(truth, (-5, 4), axis=(1, 2))
    op = _Projections(truth.shape)
    result = align_clouds(op, _cost(op(truth)), guess, radius=6.0, step=2.0, iterations=40, min_cells=10)
    np.testing.assert_allclose(result.displacements[0], [0.0, 5.0, -4.0], atol=0.05)
    assert result.amplitudes[0] == pytest.approx(1.0 / 0.6, rel=0.02)
    assert np.linalg.norm(result.state - truth) < 0.05 * np.linalg.norm(truth)
    assert result.history["cost_after"] < 1e-2 * result.history["cost_before"]


def test_bad_alignment_inputs_are_refused():
    op = _Projections((6, 20, 20))
    cost = _cost(op(_blob()))
    with pytest.raises(SwimInputError, match="shape"):
        align_clouds(op, cost, np.zeros((2, 2, 2)))
    with pytest.raises(SwimInputError, match="no cloud object"):
        align_clouds(op, cost, np.zeros((6, 20, 20)))
    with pytest.raises(SwimInputError, match="step"):
        align_clouds(op, cost, _blob(), step=0.0)


@pytest.mark.full
def test_alignment_through_the_forward_operator_recovers_a_moved_and_thinned_cloud():
    """The small cloud of the retrieval's tests (a tenth of its content, sharp edges), its images by the operator
    itself; the first guess moved two columns (800 m) west and thinned to 60 %: the coarse search and L-BFGS-B bring
    it back."""
    from test_assimilation_state import _scene

    from swim.assimilation import ForwardOperator, Observer
    from swim.assimilation.retrieval import image_cost, placement_scene
    from swim.rt.march_settings import MarchSettings

    observers = [Observer(height=2.0, camera_options=dict(width=8, height=8, fov_deg=90.0, view_azimuth_deg=0.0,
                                                          view_zenith_deg=0.0)),
                 Observer(height=8000.0, camera_options=dict(width=8, height=8, fov_deg=60.0, view_azimuth_deg=0.0,
                                                             view_zenith_deg=180.0))]
    scene = _scene()
    liquid = scene["cloud_liquid_content"]
    scene["cloud_liquid_content"] = 0.1 * liquid.where(liquid > 1e-4, 0.0)
    scene["land_mask"] = 0 * scene["land_mask"]
    truth = np.asarray(scene["cloud_liquid_content"].transpose("z", "y", "x").values)
    guess = 0.6 * np.roll(truth, -2, axis=2)
    op = ForwardOperator(placement_scene(scene, truth), observers, sun_zenith=30.0, sun_azimuth=150.0,
                         settings=MarchSettings(n_before=4, n_grid=32, n_after=8))
    observed = [np.asarray(image) for image in op(truth)]
    cost = image_cost(observed, op.masks_without_sun(5.0))
    result = align_clouds(op, cost, guess, radius=2.0, step=1.0, iterations=30, threshold=1e-6, min_cells=5)
    np.testing.assert_allclose(result.displacements[0], [0.0, 0.0, 2.0], atol=0.25)
    assert result.amplitudes[0] == pytest.approx(1.0 / 0.6, rel=0.1)
    assert result.history["cost_after"] < 0.05 * result.history["cost_before"]
