"""Red/blue cloud masks and categorical scores on hand-computed contingency tables."""

import numpy as np
import pytest

from swim.errors import SwimInputError
from swim.diagnostics.cloud_mask import (
    BR_DIFFERENCE_THRESHOLD,
    RB_RATIO_THRESHOLD,
    categorical_scores,
    cloud_mask,
    compare_cloud_masks,
    contingency_table,
    red_blue_ratio,
)

# blue sky, white cloud, grey cloud, hazy sky, black (no data), pure red
PIXELS = np.array([[[80, 130, 210], [250, 250, 250], [120, 124, 130], [170, 185, 200], [0, 0, 0], [200, 0, 0]]],
                  dtype=np.uint8)


def test_red_blue_ratio():
    ratio = red_blue_ratio(PIXELS)[0]
    np.testing.assert_allclose(ratio[:4], [80 / 210, 1.0, 120 / 130, 170 / 200])
    assert np.isnan(ratio[4]) and np.isinf(ratio[5])
    # float images in [0, 1] give the same ratio
    np.testing.assert_allclose(red_blue_ratio(PIXELS / 255.0)[0, :4], ratio[:4])


def test_ratio_mask_and_threshold():
    assert RB_RATIO_THRESHOLD == 0.8
    np.testing.assert_array_equal(cloud_mask(PIXELS)[0], [False, True, True, True, False, True])
    np.testing.assert_array_equal(cloud_mask(PIXELS, threshold=0.9)[0], [False, True, True, False, False, True])
    valid = np.array([[True, False, True, True, True, True]])
    np.testing.assert_array_equal(cloud_mask(PIXELS, valid=valid)[0], [False, False, True, True, False, True])


def test_difference_mask():
    assert BR_DIFFERENCE_THRESHOLD == 30
    # B - R: 130, 0, 10, 30, (black), -200
    np.testing.assert_array_equal(cloud_mask(PIXELS, method="difference")[0], [False, True, True, False, False, True])
    np.testing.assert_array_equal(cloud_mask(PIXELS / 255.0, method="difference", threshold=31)[0],
                                  [False, True, True, True, False, True])


def test_mask_errors():
    with pytest.raises(SwimInputError, match="method"):
        cloud_mask(PIXELS, method="otsu")
    with pytest.raises(SwimInputError, match="threshold"):
        cloud_mask(PIXELS, threshold=-1)
    with pytest.raises(SwimInputError, match="threshold"):
        cloud_mask(PIXELS, method="difference", threshold=float("nan"))
    with pytest.raises(SwimInputError, match="valid"):
        cloud_mask(PIXELS, valid=np.ones((2, 2), bool))
    with pytest.raises(SwimInputError, match="channels"):
        cloud_mask(np.zeros((4, 4, 2)))


def test_contingency_table_and_scores_by_hand():
    # a = 3 hits, b = 2 false alarms, c = 1 miss, d = 4 correct negatives
    forecast = np.array([1, 1, 1, 1, 1, 0, 0, 0, 0, 0], bool)
    observed = np.array([1, 1, 1, 0, 0, 1, 0, 0, 0, 0], bool)
    table = contingency_table(forecast, observed)
    assert table == {"hits": 3, "false_alarms": 2, "misses": 1, "correct_negatives": 4, "total": 10}
    scores = categorical_scores(table)
    assert scores["pod"] == pytest.approx(3 / 4)
    assert scores["far"] == pytest.approx(2 / 5)
    assert scores["csi"] == pytest.approx(3 / 6)
    assert scores["frequency_bias"] == pytest.approx(5 / 4)
    assert scores["accuracy"] == pytest.approx(7 / 10)


def test_weighted_and_masked_table():
    forecast = np.array([1, 1, 0, 0, 1], bool)
    observed = np.array([1, 0, 1, 0, 1], bool)
    weights = np.array([0.5, 2.0, 1.0, 3.0, 9.0])
    valid = np.array([1, 1, 1, 1, 0], bool)
    table = contingency_table(forecast, observed, valid=valid, weights=weights)
    assert table == {"hits": 0.5, "false_alarms": 2.0, "misses": 1.0, "correct_negatives": 3.0, "total": 6.5}
    scores = categorical_scores(table)
    assert scores["pod"] == pytest.approx(0.5 / 1.5)
    assert scores["accuracy"] == pytest.approx(3.5 / 6.5)


def test_scores_with_zero_denominators_are_nan():
    scores = categorical_scores({"hits": 0, "false_alarms": 0, "misses": 0, "correct_negatives": 5})
    assert np.isnan(scores["pod"]) and np.isnan(scores["far"]) and np.isnan(scores["csi"])
    assert np.isnan(scores["frequency_bias"]) and scores["accuracy"] == 1.0
    with pytest.raises(SwimInputError, match="hits"):
        categorical_scores({"hits": 1})
    with pytest.raises(SwimInputError, match=">= 0"):
        categorical_scores({"hits": -1, "false_alarms": 0, "misses": 0, "correct_negatives": 0})
    with pytest.raises(SwimInputError, match="same shape"):
        contingency_table(np.ones(3, bool), np.ones(4, bool))


def test_compare_cloud_masks_of_identical_and_shifted_images():
    rng = np.random.default_rng(0)
    sky = np.tile(np.array([70, 120, 200], np.uint8), (20, 30, 1))
    cloudy = rng.uniform(size=(20, 30)) < 0.4
    obs = sky.copy()
    obs[cloudy] = [200, 205, 210]
    same = compare_cloud_masks(obs, obs)
    assert same["scores"]["pod"] == 1.0 and same["scores"]["far"] == 0.0 and same["scores"]["accuracy"] == 1.0
    assert same["observed_cloud_fraction"] == pytest.approx(cloudy.mean())
    sim = sky.copy()
    sim[:, :15] = [200, 205, 210]  # left half cloudy
    res = compare_cloud_masks(sim, obs)
    a = (cloudy[:, :15]).sum()
    b = (~cloudy[:, :15]).sum()
    c = (cloudy[:, 15:]).sum()
    d = (~cloudy[:, 15:]).sum()
    assert res["table"] == {"hits": a, "false_alarms": b, "misses": c, "correct_negatives": d, "total": 600}
    assert res["scores"]["csi"] == pytest.approx(a / (a + b + c))
    assert res["simulated_cloud_fraction"] == pytest.approx(0.5)
