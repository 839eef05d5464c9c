"""The image misfits: RMSE and 1 - r (Eq. 37 of Albers et al. 2020) with masks, against numpy's own statistics, and
their gradients against finite differences."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from swim.assimilation.misfit import one_minus_r, rmse
from swim.errors import SwimInputError


def _images(seed=0, shape=(3, 5, 7)):
    rng = np.random.default_rng(seed)
    x = rng.random(shape)
    y = 0.7 * x + 0.3 * rng.random(shape)
    mask = rng.random(shape[1:]) > 0.3
    return x, y, mask


def test_rmse_is_numpys_over_the_masked_pixels_of_all_images():
    x, y, mask = _images()
    x2, y2, _ = _images(1, (3, 4, 4))
    mask2 = np.ones((4, 4), bool)
    expected = np.sqrt(np.mean(np.concatenate([(x - y)[:, mask].ravel(), (x2 - y2).ravel()]) ** 2))
    assert float(rmse([x, x2], [y, y2], [mask, mask2])) == pytest.approx(expected, rel=1e-6)
    assert float(rmse(x, x)) == 0.0


def test_one_minus_r_is_one_minus_the_channels_mean_pearson_r():
    x, y, mask = _images()
    r = [np.corrcoef(x[c][mask], y[c][mask])[0, 1] for c in range(3)]
    assert float(one_minus_r(x, y, mask)) == pytest.approx(1.0 - np.mean(r), rel=1e-6)
    # Eq. 37 as printed (sums of products), on the same pixels
    n = mask.sum()
    eq37 = [(n * np.sum(a * b) - a.sum() * b.sum()) / np.sqrt((n * np.sum(a * a) - a.sum() ** 2)
                                                               * (n * np.sum(b * b) - b.sum() ** 2))
            for a, b in ((x[c][mask], y[c][mask]) for c in range(3))]
    assert float(one_minus_r(x, y, mask)) == pytest.approx(1.0 - np.mean(eq37), rel=1e-6)
    # an increasing linear function of the reference correlates perfectly; a decreasing one anti-correlates
    assert float(one_minus_r(2.0 * y + 1.0, y)) == pytest.approx(0.0, abs=1e-6)
    assert float(one_minus_r(-y, y)) == pytest.approx(2.0, abs=1e-6)


@pytest.mark.parametrize("misfit", [rmse, one_minus_r])
def test_misfit_gradients_match_finite_differences(misfit):
    x, y, mask = _images(2)
    grad = np.asarray(jax.grad(lambda a: misfit(a, y, mask))(jnp.asarray(x, jnp.float32)), float)
    direction = np.random.default_rng(3).standard_normal(x.shape)
    h = 1e-3
    fd = (float(misfit(x + h * direction, y, mask)) - float(misfit(x - h * direction, y, mask))) / (2 * h)
    assert np.sum(grad * direction) == pytest.approx(fd, rel=1e-2)
    assert np.all(grad[:, ~mask] == 0.0), "masked pixels have no gradient"


def test_misfit_rejects_mismatched_images_and_empty_masks():
    x, y, mask = _images()
    with pytest.raises(SwimInputError, match="match its reference"):
        rmse(x, y[:, :3])
    with pytest.raises(SwimInputError, match="mask 0"):
        one_minus_r(x, y, mask[:3])
    with pytest.raises(SwimInputError, match="no pixel"):
        rmse(x, y, np.zeros_like(mask))
