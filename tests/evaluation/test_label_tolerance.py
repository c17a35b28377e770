import numpy as np
import pytest

from service.evaluation.label_tolerance import (
    tolerant_foreground_dice,
    tolerant_instance_dice,
    tolerant_pairwise_dice,
)
from service.evaluation.metrics import foreground_dice, instance_dice, pairwise_dice


def random_labels(rng, shape, n):
    labels = np.zeros(shape, np.int64)
    for label in range(1, n + 1):
        y, x = rng.integers(0, shape[0] - 6), rng.integers(0, shape[1] - 20)
        labels[y : y + rng.integers(2, 6), x : x + rng.integers(5, 20)] = label * 7
    return labels


@pytest.mark.parametrize("seed", range(4))
def test_at_tolerance_zero_it_is_exact_dice(seed):
    rng = np.random.default_rng(seed)
    truth = random_labels(rng, (40, 60), 4)
    predicted = random_labels(rng, (40, 60), 5)
    ignore = rng.random((40, 60)) < 0.05
    expected, _, _ = pairwise_dice(truth, predicted, ignore)
    np.testing.assert_allclose(tolerant_pairwise_dice(truth, predicted, 0, ignore), expected)
    assert tolerant_instance_dice(truth, predicted, 0, ignore) == pytest.approx(
        instance_dice(truth, predicted, ignore)
    )
    assert tolerant_foreground_dice(truth > 0, predicted > 0, 0) == pytest.approx(
        foreground_dice(truth > 0, predicted > 0)
    )


def test_a_label_two_pixels_off_is_forgiven_at_two_pixels_only():
    truth = np.zeros((30, 40), np.int64)
    truth[10:14, 5:35] = 3  # a band 4 px wide
    truth[20:24, 5:35] = 9
    shifted = np.roll(truth, 2, axis=0)  # both two rows lower
    assert instance_dice(truth, shifted) == pytest.approx(0.5)
    assert tolerant_instance_dice(truth, shifted, 1) < 1.0
    assert tolerant_instance_dice(truth, shifted, 2) == pytest.approx(1.0)
    assert tolerant_foreground_dice(truth > 0, shifted > 0, 2) == pytest.approx(1.0)
    # The band does not join two cables into one: one predicted instance over both
    # true bands still matches only one of them.
    merged = np.where(shifted > 0, 1, 0)
    assert tolerant_instance_dice(truth, merged, 2) < 0.7


def test_a_missing_prediction_scores_zero_and_an_empty_pair_one():
    truth = np.zeros((10, 10), np.int64)
    truth[2:4, 2:8] = 1
    assert tolerant_instance_dice(truth, np.zeros_like(truth), 2) == 0.0
    assert tolerant_instance_dice(np.zeros_like(truth), np.zeros_like(truth), 2) == 1.0
    with pytest.raises(ValueError, match="tolerance"):
        tolerant_pairwise_dice(truth, truth, -1)
