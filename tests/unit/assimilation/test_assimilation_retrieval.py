"""The retrieval's parts: colour-ratio cloud masks, the lines of sight's cells, the paper's clearing and insertion
(Sect. 4.3), the noise-weighted misfit, synthetic observations, and the variational retrieval of a thinned cloud.

The tests that build a forward operator compile its JAX programs (20-50 s each on an empty cache): the full tier."""

import sys
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

from swim.assimilation import ForwardOperator, Observer
from swim.assimilation.colour_ratio import _ray_cells, cloudy_pixels, colour_ratio_update
from swim.assimilation.observe import synthetic_observations
from swim.assimilation.retrieval import (CONTENT_FLOOR, background_cost, image_cost, mean_r, placement_scene,
                                         retrieve_liquid_water)
from swim.errors import SwimInputError
from swim.rt.march_settings import MarchSettings

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_assimilation_state import _scene  # noqa: E402

SETTINGS = MarchSettings(n_before=4, n_grid=32, n_after=8)
#: A camera on the ground under the cloud and one 8 km up looking down on it.
OBSERVERS = [Observer(height=2.0, camera_options=dict(width=8, height=8, fov_deg=90.0, view_azimuth_deg=0.0,
                                                       view_zenith_deg=0.0)),
             Observer(height=8000.0, camera_options=dict(width=8, height=8, fov_deg=60.0, view_azimuth_deg=0.0,
                                                         view_zenith_deg=180.0))]


def test_cloudy_pixels_are_those_with_a_red_to_blue_ratio_at_the_threshold():
    image = np.zeros((3, 2, 3))
    image[0] = [[0.3, 0.6, 0.9], [0.2, 0.0, 0.5]]  # 615 nm
    image[2] = [[0.8, 1.0, 1.0], [0.2, 0.0, 1.0]]  # 450 nm
    valid = np.array([[True, True, True], [True, True, False]])
    np.testing.assert_array_equal(cloudy_pixels(image, valid, 0.6),
                                  [[False, True, True], [True, False, False]])


def test_the_image_cost_is_the_noise_weighted_mean_square():
    observed = [np.full((3, 2, 2), 0.5)]
    images = [jnp.asarray(np.full((3, 2, 2), 0.51))]
    masks = [np.array([[1.0, 1.0], [0.0, 1.0]])]
    sigma2 = (0.01 * 0.5) ** 2 + 1e-3 ** 2
    expected = 0.5 * 3 * 3 * 0.01 ** 2 / sigma2 / 3
    assert float(image_cost(observed, masks)(images)) == pytest.approx(expected, rel=1e-5)


def test_the_background_term_is_the_weighted_square_and_its_gradient():
    """J_b = 1/2 sum ((x - x_b) / sigma_b)^2 / total, its gradient against central differences; bad errors refused."""
    rng = np.random.default_rng(2)
    xb = rng.uniform(0, 1e-3, (2, 3, 4))
    sigma = rng.uniform(1e-4, 2e-4, xb.shape)
    x = xb + rng.normal(0, 1e-4, xb.shape)
    value, grad = background_cost(xb, sigma, 7.0)(x)
    assert value == pytest.approx(0.5 * np.sum(((x - xb) / sigma) ** 2) / 7.0, rel=1e-12)
    d = rng.normal(0, 1e-5, xb.shape)
    cost = background_cost(xb, sigma, 7.0)
    fd = (cost(x + d)[0] - cost(x - d)[0]) / 2
    assert np.vdot(grad, d) == pytest.approx(fd, rel=1e-9)
    assert background_cost(xb, 1e-4, 1.0)(xb)[0] == 0.0
    for bad in (0.0, -1e-4, np.nan, np.ones((2, 2))):
        with pytest.raises(SwimInputError, match="background_error"):
            background_cost(xb, bad, 1.0)
    with pytest.raises(SwimInputError, match="background must be finite"):
        background_cost(np.full(xb.shape, np.inf), 1e-4, 1.0)


def test_bad_retrieval_and_observation_inputs_are_refused():
    scene = _scene()
    with pytest.raises(SwimInputError, match="first_guess"):
        retrieve_liquid_water(scene, OBSERVERS, [], sun_zenith=30.0, sun_azimuth=0.0,
                              first_guess=-np.ones((16, 9, 10)))
    with pytest.raises(SwimInputError, match="go together"):
        retrieve_liquid_water(scene, OBSERVERS, [], sun_zenith=30.0, sun_azimuth=0.0,
                              first_guess=np.zeros((16, 9, 10)), background=np.zeros((16, 9, 10)))
    with pytest.raises(SwimInputError, match="outer_loops"):
        retrieve_liquid_water(scene, OBSERVERS, [], sun_zenith=30.0, sun_azimuth=0.0,
                              first_guess=np.zeros((16, 9, 10)), outer_loops=0)
    with pytest.raises(SwimInputError, match="no cloud"):
        placement_scene(scene, np.zeros((16, 9, 10)))
    with pytest.raises(SwimInputError, match="not both 0"):
        image_cost([np.ones((3, 2, 2))], [np.ones((2, 2))], relative_noise=0.0, absolute_noise=0.0)
    with pytest.raises(SwimInputError, match="no pixel"):
        image_cost([np.ones((3, 2, 2))], [np.zeros((2, 2))])
    with pytest.raises(SwimInputError, match="shape"):
        retrieve_liquid_water(scene, OBSERVERS, [], sun_zenith=30.0, sun_azimuth=0.0, first_guess=np.zeros((2, 2, 2)))
    with pytest.raises(SwimInputError, match="relative_noise"):
        synthetic_observations(scene, OBSERVERS, sun_zenith=30.0, sun_azimuth=0.0, relative_noise=-0.1)


@pytest.fixture(scope="module")
def case():
    """The truth: the small cloud over a hill, thinned to a tenth (optical depths up to ~10: seen through) with sharp
    edges, over the sea (whose red/blue ratio, unlike land's, is a clear sky's); its images by the render's numba
    kernel with noise, and an operator whose steps are placed for the whole cloud layer."""
    scene = _scene()
    liquid = scene["cloud_liquid_content"]
    scene["cloud_liquid_content"] = 0.1 * liquid.where(liquid > 1e-4, 0.0)
    scene["land_mask"] = 0 * scene["land_mask"]
    truth = np.asarray(scene["cloud_liquid_content"].transpose("z", "y", "x").values)
    observed, _ = synthetic_observations(scene, OBSERVERS, sun_zenith=30.0, sun_azimuth=150.0, seed=3,
                                         settings=MarchSettings(n_grid=128, cloud_scattering="albers2020"))
    op = ForwardOperator(placement_scene(scene, truth), OBSERVERS, sun_zenith=30.0, sun_azimuth=150.0,
                         settings=SETTINGS)
    return scene, truth, observed, op


@pytest.mark.full
def test_an_upward_line_of_sight_crosses_the_cells_of_its_column(case):
    """A pixel next to the zenith of the ground camera (looking up, at the reference point between columns 4 and 5
    of both axes) crosses every level, its lowest cells within a cell of the camera and its highest no farther than
    its slant carries it."""
    scene, _, _, op = case
    heights = np.asarray(scene["height"].transpose("z", "y", "x").values)
    cells, ray = _ray_cells(op.setup, heights, np.asarray(scene["terrain_height"].values))
    k, j, i = np.unravel_index(cells, heights.shape)
    centre = op.setup.pixels[0].tolist().index(3 * 8 + 3)  # pixel (3, 3) of 8 x 8, just off the zenith
    mine = ray == centre
    assert set(k[mine]) == set(range(heights.shape[0]))
    low = mine & (k <= 2)
    assert np.all(np.abs(j[low] - 4.5) <= 1.0) and np.all(np.abs(i[low] - 4.5) <= 1.0)
    direction = np.asarray(op.setup.chunks[0]["direction"][centre], float)
    reach = heights[-1].max() * np.hypot(direction[0], direction[1]) / direction[2] / 400.0  # [cells]
    assert np.all(np.hypot(j[mine] - 4.5, i[mine] - 4.5) <= reach + 1.5)


@pytest.mark.full
def test_the_colour_ratio_update_clears_and_inserts_along_the_lines_of_sight(case):
    """A first guess with the cloud moved four columns (1.6 km) east, wrapping round the grid's edge: cells are cleared
    only where the first guess had cloud, inserted only where it had none, and the images' r-bar rises (the paper's
    Fig. 14: 0.41 to 0.71)."""
    scene, truth, observed, op = case
    guess = np.roll(truth, 4, axis=2)
    masks = op.masks_without_sun(5.0)
    update = colour_ratio_update(op, scene, guess, observed, masks)
    assert update.cleared.any() and update.inserted.any()
    assert np.all(guess[update.cleared] > 1e-5)
    assert np.all(guess[update.inserted] <= 1e-5)
    before = np.mean(mean_r(op(guess), observed, masks))
    after = np.mean(mean_r(op(update.state), observed, masks))
    assert after > before + 0.2  # measured 0.27 -> 0.77


@pytest.mark.full
def test_the_retrieval_fits_the_images_of_a_thinned_cloud(case):
    """From the cloud thinned to 40 %, 15 iterations of the variational retrieval (the render's kernel's noisy images,
    the operator's own march) bring r-bar from 0.87 to above 0.97 and cut the cost tenfold (measured 834 -> 69);
    the liquid water's L2 error falls (0.60 -> 0.56: two 8 x 8 views of 1440 cells leave most of the field
    undetermined)."""
    scene, truth, observed, _ = case
    guess = 0.4 * truth
    result = retrieve_liquid_water(scene, OBSERVERS, observed, sun_zenith=30.0, sun_azimuth=150.0,
                                   first_guess=guess, outer_loops=1, iterations=15, settings=SETTINGS)
    error = np.linalg.norm(result.state - truth) / np.linalg.norm(truth)
    before = np.linalg.norm(guess - truth) / np.linalg.norm(truth)
    assert np.all(result.state >= CONTENT_FLOOR * (1 - 1e-6))
    assert error < 0.97 * before
    assert np.mean(result.history[-1]["r_after"]) > 0.97
    assert result.history[-1]["cost_after"] < 0.1 * result.history[-1]["cost_before"]
    with pytest.raises(SwimInputError, match="observed image"):
        retrieve_liquid_water(scene, OBSERVERS, [o[:, :4] for o in observed], sun_zenith=30.0, sun_azimuth=150.0,
                              first_guess=guess, outer_loops=1, iterations=1, settings=SETTINGS)


@pytest.mark.full
def test_a_tight_background_holds_the_retrieval_at_the_background(case):
    """With background errors 1e-5 of the cloud's largest content, J_b outweighs the images' misfit: the retrieval
    from the thinned cloud stays at it (the background) instead of thickening towards the observed cloud (with errors
    of 1e-3 of it, the images move it by 7 %)."""
    scene, truth, observed, _ = case
    guess = 0.4 * truth
    result = retrieve_liquid_water(scene, OBSERVERS, observed, sun_zenith=30.0, sun_azimuth=150.0,
                                   first_guess=guess, outer_loops=1, iterations=5, settings=SETTINGS,
                                   background=guess, background_error=1e-5 * truth.max())
    change = np.linalg.norm(result.state - np.maximum(guess, CONTENT_FLOOR)) / np.linalg.norm(guess)
    assert change < 0.01, change
