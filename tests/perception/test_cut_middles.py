"""A short piece's bridge leaves the cable's middle at the cut, not the skeleton's tip in
the cut's corner (:mod:`service.perception.cut_middles`)."""

import numpy as np
import pytest

from service.evaluation.synthetic_eval import evaluate_scene
from service.perception.cut_middles import cut_middle, section_middle
from service.synthetic.families import make_family_scene

HALF_WIDTH = 5.0
MIDDLE_Y = 50.0


def slanted_cut_mask(cut_x: float, slant_deg: float, half_width: float = HALF_WIDTH) -> np.ndarray:
    """A straight cable along y = MIDDLE_Y, ``half_width`` to either side (pixel centres
    within it), from x = 10 on to where an object's straight border cuts it: the line
    through (``cut_x``, MIDDLE_Y) turned ``slant_deg`` from square."""
    ys, xs = np.mgrid[0:100, 0:100].astype(np.float64)
    slope = np.tan(np.radians(slant_deg))
    border_x = cut_x + (ys - MIDDLE_Y) * slope
    return (np.abs(ys - MIDDLE_Y) <= half_width) & (xs >= 10) & (xs <= border_x)


def test_a_tip_in_a_slanted_cuts_corner_is_taken_to_the_middle_of_the_cut():
    """Cut at 45 degrees: the mask's far corner lies 5 px beyond the middle line's cut
    and 5 px off it, where thinning ends the skeleton. The bridge starts on the middle
    line instead, where the cut begins to narrow the cable."""
    mask = slanted_cut_mask(60.0, 45.0)
    points = np.array([[40.0, 51.0], [50.0, 52.0], [59.0, 54.0]])  # tip in the corner
    middle = cut_middle(mask, points, False, points[-1], np.array([1.0, 0.0]), HALF_WIDTH + 0.5)
    assert middle is not None
    # Within half the narrowing the trace allows before it stops (CUT_NARROWING_PX):
    # the cut takes the near side first, and the section's middle moves off by half.
    assert abs(middle[1] - MIDDLE_Y) <= 1.0
    # The cut begins where the border reaches the cable's near side (x = 55), and
    # reaches the middle line at x = 60.
    assert 52.0 <= middle[0] <= 60.0


def test_a_tip_reached_at_the_start_end_is_traced_the_other_way():
    """The same cut seen from the piece's start: the joints run inwards from it."""
    mask = slanted_cut_mask(60.0, 45.0)
    points = np.array([[59.0, 54.0], [50.0, 52.0], [40.0, 51.0]])
    middle = cut_middle(mask, points, True, points[0], np.array([1.0, 0.0]), HALF_WIDTH + 0.5)
    assert middle is not None
    assert abs(middle[1] - MIDDLE_Y) <= 1.0


def test_a_piece_with_no_section_of_the_cables_width_stays_where_it_is():
    """A stretch narrower than the cable all along (a wedge between two cuts): no
    section shows both of the cable's borders, so nothing says where its middle is."""
    mask = slanted_cut_mask(60.0, 45.0, half_width=2.0)
    points = np.array([[40.0, 51.0], [50.0, 51.0], [59.0, 51.0]])
    assert cut_middle(mask, points, False, points[-1], np.array([1.0, 0.0]), 5.5) is None


def test_a_section_wider_than_the_cable_is_not_its_own():
    """Two cables touching: the section spans both, its middle is neither's."""
    mask = np.zeros((100, 100), bool)
    mask[40:61, :] = True
    assert section_middle(mask, np.array([50.0, 45.0]), np.array([1.0, 0.0]), 5.5) is None


@pytest.mark.parametrize("seed", [330036, 350112, 86104, 94094, 94106])
def test_short_pieces_between_objects_are_bridged_from_their_cut_middles(seed):
    """Tuning scenes (true mask) where a piece shorter than the end fit's span, seen
    between two objects or between an object and a crossing, was bridged from its
    skeleton's tip in the cut's corner, 5-8 px off the middle line, and the bridge ran
    outside the tolerance along the hidden stretch: bridged from the cut's middle,
    every cable is covered."""
    scene = make_family_scene("occluded", seed)
    score, _ = evaluate_scene(scene, seed, mask_from_labels=True)
    assert score.frame.correct
