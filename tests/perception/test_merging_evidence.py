"""Merging at free ends (issue 13): a partner that could not be joined is no rival for one
that could, and an end by the picture's edge that runs along it (not out of the picture)
is joined like any other."""

import cv2
import numpy as np
import pytest

from schemas import DetectParams
from service.evaluation.synthetic_eval import evaluate_scene
from service.perception.merging import ChainEnd, choose_joins, join_cost, merge_chains
from service.synthetic.families import make_family_scene


def test_a_partner_over_open_background_is_no_rival_for_a_hidden_gap():
    """Ends 1 and 2 face each other across 36 radii that something hides (0.72, over the
    threshold): each other's only partner they could be joined to. End 4, another
    cable's tip, would be cheaper for end 2 (0.66) but lies 20 radii off over open
    background, where nothing could hide a cable: it is no rival (same_colour 79041: a
    cable's two pieces either side of an object left apart for another cable's tip)."""

    def end(piece, at_start, position, direction):
        direction = np.array(direction, float)
        return ChainEnd(
            piece, at_start, np.array(position, float), direction / np.hypot(*direction)
        )

    ends = [
        end(0, True, (-100, 0), (-1, 0)),
        end(0, False, (0, 0), (1, 0)),
        end(1, True, (180, 0), (-1, 0)),
        end(1, False, (300, 0), (1, 0)),
        end(2, True, (100, -60), (0.6, 0.6)),
        end(2, False, (100, -210), (0, -1)),
    ]
    params = DetectParams()
    assert join_cost(ends[2], ends[4], params, 5.0) < join_cost(ends[1], ends[2], params, 5.0)
    joins = choose_joins(
        ends, 3, params, 5.0, hidden_gap=lambda i, j: {i, j} == {1, 2}, at_border=np.zeros(6, bool)
    )
    assert [(i, j) for i, j, _ in joins] == [(1, 2)]


@pytest.mark.parametrize("row", [95, 50])
def test_ends_running_along_the_picture_edge_are_not_cables_leaving_it(row):
    """A cable lying along the picture's bottom edge (y = 95 of 100, radius 3.5), broken
    for 3 radii between two round ends (a stretch the segmentation lost): its two inner
    ends run along the edge, not out of the picture, and are joined as in the middle of
    the picture (edge 79021, 75001: a stub beyond an object by the edge, a cable along
    it). The outer ends at the left and right edges point out: cables leaving it."""
    image = np.full((100, 300, 3), 200, np.uint8)
    mask = np.zeros((100, 300), np.uint8)
    cv2.rectangle(mask, (0, row - 3), (127, row + 3), 1, -1)
    cv2.rectangle(mask, (139, row - 3), (299, row + 3), 1, -1)
    mask[:, 125:142] = 0
    cv2.circle(mask, (124, row), 3, 1, -1)
    cv2.circle(mask, (142, row), 3, 1, -1)
    image[mask > 0] = (40, 40, 60)
    distance = cv2.distanceTransform(mask, cv2.DIST_L2, 5)
    pieces = [
        np.column_stack([np.linspace(4, 122, 13), np.full(13, float(row))]),
        np.column_stack([np.linspace(144, 294, 16), np.full(16, float(row))]),
    ]
    result = merge_chains(
        pieces, DetectParams(), 3.5, distance=distance, image=image, mask=mask > 0
    )
    assert len(result.paths) == 1
    assert len(result.joins) == 1


@pytest.mark.parametrize(("family", "seed"), [("edge", 79021), ("same_colour", 79041)])
def test_stubs_by_the_edge_and_gaps_with_a_tip_nearby_come_out_whole(family, seed):
    """Tuning scenes: a stub of cable left beyond an object by the picture's edge, its
    inner end pointing back into the picture; a cable's two pieces either side of an
    object with another cable's round tip nearby over open background. One chain each."""
    score, _ = evaluate_scene(make_family_scene(family, seed), seed, mask_from_labels=True)
    assert score.frame.correct, score.frame.coverage


@pytest.mark.parametrize("seed", [330008, 330076])
def test_gaps_partly_under_seen_objects_come_out_whole(seed):
    """Tuning scenes (occluded, true mask): a gap under an object of the background's
    colour and a grey box beside it, over 19 radii in all but most of it under the box
    (330008); a bend under a grey box whose turn curves start on the pieces' own tips
    (330076). Each cable one chain."""
    score, _ = evaluate_scene(make_family_scene("occluded", seed), seed, mask_from_labels=True)
    assert score.frame.correct, score.frame.coverage
