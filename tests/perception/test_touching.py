"""Touching strands told apart (service/perception/touching.py), issue 13."""

import cv2
import numpy as np
import pytest

from service.perception.pipeline import detect
from service.perception.touching import split_touching_strands
from tests.perception.test_merging import _strand_error, _touching_strands_mask


@pytest.mark.parametrize("stretch", [20, 30])
def test_a_touching_stretch_the_junction_takes_whole_keeps_each_strands_side(stretch):
    """Two cables 9 px wide touch for only 20-30 px and part again: the junction zone
    takes the whole stretch, leaving one junction of four ends. The cheapest matching
    of a crossing paired each strand with the other's far arm (every cable then ran
    105 px off); the stretch keeps both widths, so each strand keeps its side."""
    upper = [(20, 30), (100, 96), (100 + stretch, 96), (180 + stretch, 30)]
    lower = [(20, 170), (100, 104), (100 + stretch, 104), (180 + stretch, 170)]
    detection = detect(None, mask=_touching_strands_mask(upper, lower, shape=(200, 400)))
    chains = [np.asarray(chain.points, np.float64) for chain in detection.chains]
    assert len(chains) == 2
    for cable in (upper, lower):
        assert min(_strand_error(chain, cable) for chain in chains) < 6.0


def _four_arms(mask, arms):
    """The arms' pieces, ends, outward directions and one junction (label 0) for the
    four inner ends (each arm's last point)."""
    pieces = [np.array(arm, np.float64) for arm in arms]
    positions = np.array([points[index] for points in pieces for index in (0, -1)])
    directions = np.array(
        [points[index] - points[inner] for points in pieces for index, inner in ((0, 1), (-1, -2))]
    )
    directions /= np.hypot(directions[:, 0], directions[:, 1])[:, None]
    labels = [-1, 0] * len(pieces)
    distance = cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, 5)
    return pieces, positions, directions, labels, distance


def test_four_ends_meeting_where_the_mask_keeps_both_widths_pair_by_side():
    """The four arms of a short touching stretch: upper left (piece 0) continues upper
    right (piece 2), lower left (piece 1) lower right (piece 3), not straight across."""
    upper = [(20, 40), (100, 96), (130, 96), (210, 40)]
    lower = [(20, 160), (100, 104), (130, 104), (210, 160)]
    mask = _touching_strands_mask(upper, lower, shape=(200, 240))
    arms = [
        [(20, 40), (60, 68), (96, 93)],
        [(20, 160), (60, 132), (96, 107)],
        [(210, 40), (170, 68), (134, 93)],
        [(210, 160), (170, 132), (134, 107)],
    ]
    split = split_touching_strands(*_four_arms(mask, arms))
    assert split.split == []
    assert sorted(tuple(sorted(pair)) for pair in split.pairs) == [(1, 5), (3, 7)]
    assert split.junction_of_end == [-1] * 8


def test_four_ends_of_a_shallow_crossing_are_left_to_the_crossing():
    """Two cables crossing at 23 degrees: the same four arms, but the mask narrows to
    one cable's width where they cross, so the junction is left as it is."""
    first, second = [(20, 80), (220, 120)], [(20, 120), (220, 80)]
    mask = _touching_strands_mask(first, second, shape=(200, 240))
    arms = [
        [(20, 80), (55, 87), (90, 94)],
        [(20, 120), (55, 113), (90, 106)],
        [(220, 80), (185, 87), (150, 94)],
        [(220, 120), (185, 113), (150, 106)],
    ]
    split = split_touching_strands(*_four_arms(mask, arms))
    assert split.pairs == []
    assert split.junction_of_end == [-1, 0] * 4
