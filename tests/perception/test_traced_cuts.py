"""A turn under an object whose cut lies on the turn's own bend: the cuts read where the
middle line traced from the end's fit leaves the mask (service/perception/traced_cuts.py)."""

import cv2
import numpy as np
import pytest

from service.evaluation.synthetic_eval import evaluate_scene
from service.perception.appearance import cut_square
from service.perception.merging import ChainEnd
from service.perception.traced_cuts import ends_at_the_cuts
from service.synthetic.families import make_family_scene


def _bent_strand() -> tuple[np.ndarray, ChainEnd]:
    """A strand of half width 4 running right along row 40, then bending down on a
    circle of radius 20 about (60, 60) and cut straight across, 60 degrees into the
    bend, along the circle's radius (an object's border); its end fitted over the
    straight stretch, the tip's hook (10 px) left out."""
    height, width = 100, 120
    ys, xs = np.mgrid[:height, :width].astype(np.float64)
    straight = (np.abs(ys - 40.0) <= 4.0) & (xs <= 60.0) & (xs >= 5.0)
    angle = np.arctan2(xs - 60.0, 60.0 - ys)  # 0 straight up from the centre, clockwise
    ring = np.abs(np.hypot(xs - 60.0, ys - 60.0) - 20.0) <= 4.0
    mask = straight | (ring & (xs >= 60.0) & (angle <= np.radians(60.0)))
    end = ChainEnd(
        piece=0,
        at_start=False,
        position=np.array([68.0, 41.0]),
        direction=np.array([1.0, 0.0]),
        skip=10.0,
        width=4.0,
    )
    return mask, end


def test_an_end_on_a_bend_is_read_where_the_traced_middle_line_leaves_the_mask():
    """The end read at its traced cut lies on the cut (60 degrees round the bend, within a
    half width of the middle) and points into the bend, not straight on as the fit."""
    mask, end = _bent_strand()
    moved = ends_at_the_cuts([end], mask, 4.0)(0)
    assert moved is not end
    assert moved.skip == 0.0
    # At the cut (the radius at 60 degrees), within a half width of it and of the middle.
    radial = np.array([np.sin(np.radians(60.0)), -np.cos(np.radians(60.0))])
    offset = moved.position - np.array([60.0, 60.0])
    assert abs(float(offset[0] * radial[1] - offset[1] * radial[0])) <= 4.0
    assert abs(float(offset @ radial) - 20.0) <= 4.0
    # Turned into the bend (the fit points straight on, 60 degrees off the tangent there).
    turned = np.degrees(np.arctan2(moved.direction[1], moved.direction[0]))
    assert 20.0 <= turned <= 70.0
    # An end whose fit left out no tip is read as it is.
    unhooked = ChainEnd(0, False, end.position, end.direction, width=4.0)
    assert ends_at_the_cuts([unhooked], mask, 4.0)(0) is unhooked


@pytest.mark.parametrize(
    ("family", "seed"),
    [("doubled_back", 330036), ("doubled_back", 330185), ("loops", 330063), ("occluded", 350022)],
)
def test_a_turn_cut_on_its_own_bend_is_joined(family, seed):
    """Tuning scenes (true mask): a doubled-back cable's turn under an object whose
    border cuts one strand on its bend into the turn (330036: the fit lags the bend by
    36 degrees), a thick strand cut at a slant (330185), a loop's turn (330063), a bend
    under a box (occluded 350022). One chain per cable (where the bridge runs is the
    bridging's business: 330036 and 330185 are bridged inside the true turn)."""
    score, _ = evaluate_scene(make_family_scene(family, seed), seed, mask_from_labels=True)
    assert score.frame.n_chains == score.frame.n_cables
    assert min(score.frame.coverage) >= 0.95, score.frame.coverage


def test_an_end_whose_line_back_leaves_the_cable_is_traced_from_its_own_piece():
    """A straight strand of half width 4 along row 40, cut square at x = 60; its end left
    at the tip in the cut's corner with a chord 50 degrees off the cable (a piece too
    short to fit, bent into a corner's wedge): the line back to where the fit begins
    (12 px: a hook left out) leaves the mask, so the trace from there reads nothing. Traced from the
    piece's own point where the cable is whole, the cut is found at x = 60, square
    across the cable, heading along it."""
    height, width = 80, 100
    ys, xs = np.mgrid[:height, :width].astype(np.float64)
    mask = (np.abs(ys - 40.0) <= 4.0) & (xs >= 5.0) & (xs <= 60.0)
    distance = cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, 5)
    piece = np.array(
        [[10.0, 40.0], [20.0, 40.0], [30.0, 40.0], [40.0, 40.0], [50.0, 40.0], [59.0, 43.0]]
    )
    tilted = np.array([np.cos(np.radians(50.0)), np.sin(np.radians(50.0))])
    end = ChainEnd(0, False, piece[-1], tilted, skip=12.0, width=4.5)
    assert not mask[
        int(np.rint(piece[-1][1] - 12.0 * tilted[1])), int(np.rint(piece[-1][0] - 12.0 * tilted[0]))
    ]
    assert ends_at_the_cuts([end], mask, 4.0)(0) is end
    moved = ends_at_the_cuts([end], mask, 4.0, [piece], distance)(0)
    assert moved is not end
    assert abs(float(moved.position[0]) - 60.0) <= 1.5
    assert abs(float(moved.position[1]) - 40.0) <= 1.5
    assert float(moved.direction[0]) >= np.cos(np.radians(10.0))
    assert cut_square(mask, moved.position, moved.direction, end.width, moved.skip)


@pytest.mark.parametrize(("family", "seed"), [("loops", 410220), ("loops", 420298)])
def test_a_loops_turn_cut_in_an_objects_corner_is_joined(family, seed):
    """Tuning scenes (true mask): a loop's strand runs into an object's corner (410220) or
    into a short, steep cut on a disc's rim (420298); its piece's end, left in the
    corner's wedge, points along a chord of the bend. Traced from the piece, its cut reads
    square and the turn is joined: one chain per cable, the frame right."""
    score, _ = evaluate_scene(make_family_scene(family, seed), seed, mask_from_labels=True)
    assert score.frame.n_chains == score.frame.n_cables
    assert score.frame.correct
