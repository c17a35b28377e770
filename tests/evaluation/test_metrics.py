"""The instance DICE metric on hand-made label images with known answers."""

import numpy as np
import pytest

from service.evaluation.metrics import foreground_dice, instance_dice, pairwise_dice


def test_identical_labellings_score_one_whatever_the_ids():
    truth = np.array([[1, 1, 0, 2, 2, 0, 3]])
    assert instance_dice(truth, truth) == 1.0
    assert instance_dice(truth, np.array([[9, 9, 0, 4, 4, 0, 7]])) == 1.0


def test_pairwise_dice_matrix():
    truth = np.array([[1, 1, 1, 1, 0, 2, 2]])
    predicted = np.array([[1, 1, 2, 2, 0, 2, 2]])
    dice, truth_ids, predicted_ids = pairwise_dice(truth, predicted)
    assert list(truth_ids) == [1, 2] and list(predicted_ids) == [1, 2]
    # |T1|=4, |P1|=2, overlap 2 -> 4/6; T1 vs P2: overlap 2, |P2|=4 -> 4/8
    assert dice == pytest.approx(np.array([[4 / 6, 0.5], [0.0, 4 / 6]]))


def test_more_predictions_than_truth_unmatched_predictions_cost_nothing_directly():
    truth = np.array([[1, 1, 1, 1, 0, 0]])
    predicted = np.array([[1, 1, 1, 1, 2, 2]])
    assert instance_dice(truth, predicted) == 1.0
    # A cable split in two: the best match covers half of it.
    split = np.array([[1, 1, 2, 2, 0, 0]])
    assert instance_dice(truth, split) == pytest.approx(2 * 2 / (4 + 2))


def test_fewer_predictions_than_truth_unmatched_truth_scores_zero():
    truth = np.array([[1, 1, 0, 2, 2, 0, 3, 3]])
    predicted = np.array([[5, 5, 0, 5, 5, 0, 0, 0]])
    # One prediction covers T1 and T2 (DICE 2*2/(2+4) each), matched to one of them;
    # T2 or T1 and T3 are unmatched and score 0.
    assert instance_dice(truth, predicted) == pytest.approx((4 / 6) / 3)


def test_empty_cases():
    empty = np.zeros((3, 3), int)
    assert instance_dice(empty, empty) == 1.0
    assert instance_dice(empty, np.ones((3, 3), int)) == 0.0
    assert instance_dice(np.ones((3, 3), int), empty) == 0.0
    with pytest.raises(ValueError, match="shape"):
        instance_dice(np.ones((3, 3), int), np.ones((3, 4), int))


def test_ignored_pixels_are_left_out_of_both_sides():
    # ariadne marks the pixels of two cables at once 255; they count for neither.
    truth = np.array([[1, 1, 255, 2, 2, 0]])
    predicted = np.array([[5, 5, 7, 7, 7, 7]])
    ignore = truth == 255
    # T1 = {0, 1} = P5: 1; T2 = {3, 4}, P7 = {3, 4, 5} without pixel 2: 2*2 / (2 + 3).
    assert instance_dice(truth, predicted, ignore) == pytest.approx((1.0 + 0.8) / 2)
    # Counted, 255 would be a third cable, and pixel 2 would cost P7 as well.
    assert instance_dice(truth, predicted) < 0.7
    dice, truth_ids, _ = pairwise_dice(truth, predicted, ignore)
    assert list(truth_ids) == [1, 2] and dice.shape == (2, 2)
    with pytest.raises(ValueError, match="ignore"):
        instance_dice(truth, predicted, np.zeros((2, 6), bool))


def test_foreground_dice():
    truth = np.array([[1, 1, 1, 0, 0]], bool)
    assert foreground_dice(truth, truth) == 1.0
    assert foreground_dice(truth, np.array([[0, 1, 1, 1, 0]], bool)) == pytest.approx(4 / 6)
    assert foreground_dice(np.zeros(3, bool), np.zeros(3, bool)) == 1.0
    assert foreground_dice(truth, np.zeros_like(truth)) == 0.0
