"""Touching strands told apart (service/perception/touching.py), issue 13."""

import cv2
import numpy as np
import pytest

from service.evaluation.synthetic_eval import evaluate_scene
from service.perception.pipeline import detect
from service.perception.touching import split_touching_strands
from service.synthetic.families import make_family_scene
from tests.perception.test_merging_touching import strand_error, touching_strands_mask


@pytest.mark.parametrize("stretch", [20, 30])
def test_a_touching_stretch_the_junction_takes_whole_keeps_each_strands_side(stretch):
    """Two cables 9 px wide touch for only 20-30 px and part again: the junction zone
    takes the whole stretch, leaving one junction of four ends. The cheapest matching
    of a crossing paired each strand with the other's far arm (every cable then ran
    105 px off); the stretch keeps both widths, so each strand keeps its side."""
    upper = [(20, 30), (100, 96), (100 + stretch, 96), (180 + stretch, 30)]
    lower = [(20, 170), (100, 104), (100 + stretch, 104), (180 + stretch, 170)]
    detection = detect(None, mask=touching_strands_mask(upper, lower, shape=(200, 400)))
    chains = [np.asarray(chain.points, np.float64) for chain in detection.chains]
    assert len(chains) == 2
    for cable in (upper, lower):
        assert min(strand_error(chain, cable) for chain in chains) < 6.0


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
    mask = touching_strands_mask(upper, lower, shape=(200, 240))
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


def test_the_bridge_across_a_touching_stretch_follows_each_strands_own_side():
    """The same four arms, their tips bent toward the stretch's middle as thinning bends
    them where strands meet (1 px off it instead of 4): a curve between the tips ran down
    the middle, a strand's half width off both cables (a doubled-back cable's outer
    strand left uncovered). Each bridge keeps to its strand's side, away from the other."""
    upper = [(20, 40), (100, 96), (130, 96), (210, 40)]
    lower = [(20, 160), (100, 104), (130, 104), (210, 160)]
    mask = touching_strands_mask(upper, lower, shape=(200, 240))
    arms = [
        [(20, 40), (60, 68), (94, 92), (99, 99)],
        [(20, 160), (60, 132), (94, 108), (99, 101)],
        [(210, 40), (170, 68), (136, 92), (131, 99)],
        [(210, 160), (170, 132), (136, 108), (131, 101)],
    ]
    split = split_touching_strands(*_four_arms(mask, arms))
    assert sorted(tuple(sorted(pair)) for pair in split.pairs) == [(1, 5), (3, 7)]
    for pair, strand_y in (((1, 5), 96.0), ((3, 7), 104.0)):
        bridge = split.bridges.get(pair)
        if bridge is None:
            bridge = split.bridges[pair[::-1]][::-1]
        assert np.allclose(bridge[[0, -1]], [arms[pair[0] // 2][-1], arms[pair[1] // 2][-1]])
        middle = bridge[(bridge[:, 0] >= 105) & (bridge[:, 0] <= 125)]
        assert len(middle) >= 15
        assert np.abs(middle[:, 1] - strand_y).max() <= 1.0


def test_four_ends_in_the_notches_of_strands_parting_at_a_shallow_angle_pair_by_side():
    """Two strands touching for 40 px part at 18 degrees at both ends, and the junction's
    four ends lie where they have just parted: the line between the two pairs starts and
    ends in the notches between the strands, where the mask narrows to nothing, whether
    the strands touch or cross (doubled_back 86057, 86068, 86073, 280060, 280114: the
    cable ran across its own stretch). The stretch is judged along the line's middle
    third, where a crossing would narrow it: each strand keeps its side."""
    upper = [(20, 70), (100, 96), (140, 96), (220, 70)]
    lower = [(20, 130), (100, 104), (140, 104), (220, 130)]
    mask = touching_strands_mask(upper, lower, shape=(200, 240))
    arms = [
        [(20, 70), (50, 80), (80, 89)],
        [(20, 130), (50, 120), (80, 111)],
        [(220, 70), (190, 80), (160, 89)],
        [(220, 130), (190, 120), (160, 111)],
    ]
    pieces, positions, directions, labels, distance = _four_arms(mask, arms)
    assert distance[100, 89] == 0  # the notch, a strand's width in from the line's end
    split = split_touching_strands(pieces, positions, directions, labels, distance)
    assert sorted(tuple(sorted(pair)) for pair in split.pairs) == [(1, 5), (3, 7)]


def test_four_ends_where_strands_part_slowly_past_the_middle_pair_by_side():
    """Two strands touching for 30 px part at 4 degrees on the right, and the junction's
    right ends lie 45 px on, where they have just parted: the notch between the strands
    narrows the mask from there inwards over more than the ends' clearance, into the
    middle the stretch is judged on. The mask narrows on towards the notch and never
    widens again, as a crossing's does past its middle, so it is the parting's
    narrowing (doubled_back 400158, 400267: a bulb opening slowly from its neck): each
    strand keeps its side."""
    upper = [(20, 40), (100, 96), (130, 96), (250, 88)]
    lower = [(20, 160), (100, 104), (130, 104), (250, 112)]
    mask = touching_strands_mask(upper, lower, shape=(200, 280))
    arms = [
        [(20, 40), (60, 68), (94, 92)],
        [(20, 160), (60, 132), (94, 108)],
        [(250, 88), (210, 91), (175, 94)],
        [(250, 112), (210, 109), (175, 106)],
    ]
    pieces, positions, directions, labels, distance = _four_arms(mask, arms)
    profile = distance[100, 94:176]
    narrowest = int(np.argmin(profile[27:55])) + 27  # the middle third
    assert profile[narrowest] < 0.75 * profile.max()  # narrower than touching strands
    assert profile[narrowest:].max() <= profile[narrowest] + 1.0  # and never wider past it
    split = split_touching_strands(pieces, positions, directions, labels, distance)
    assert sorted(tuple(sorted(pair)) for pair in split.pairs) == [(1, 5), (3, 7)]


@pytest.mark.parametrize("seed", [400158, 400267])
def test_a_doubled_back_bulb_opening_slowly_from_its_neck_keeps_each_strands_side(seed):
    """A doubled-back cable's two strands touch just below its bulb and part slowly into
    it: the junction zone takes the stretch whole, and its four ends were paired straight
    across, the chain crossing its own stretch a pixel outside tolerance."""
    score, _ = evaluate_scene(make_family_scene("doubled_back", seed), seed, mask_from_labels=True)
    assert score.frame.correct


@pytest.mark.parametrize(("family", "seed"), [("many", 86102), ("loops", 94112)])
def test_a_thin_cables_wide_crossing_is_no_parting_touching_stretch(family, seed):
    """A loop of a thin cable (radius 3.2, 4.4 px) crossing itself at a wide angle: pixel
    rounding puts the X's middle near 0.9 of the two strands, and the mask narrows from
    there into the notches between its arms as a slow parting's does. It keeps 3/4 of the
    two for 0-2 px, not over a cable's width as touching strands do: a crossing still
    (read as a parting, the loop turned back at it, a visible stretch off tolerance)."""
    score, _ = evaluate_scene(make_family_scene(family, seed), seed, mask_from_labels=True)
    assert score.frame.correct


def test_four_ends_of_a_shallow_crossing_are_left_to_the_crossing():
    """Two cables crossing at 23 degrees: the same four arms, but the mask narrows to
    one cable's width where they cross, so the junction is left as it is."""
    first, second = [(20, 80), (220, 120)], [(20, 120), (220, 80)]
    mask = touching_strands_mask(first, second, shape=(200, 240))
    arms = [
        [(20, 80), (55, 87), (90, 94)],
        [(20, 120), (55, 113), (90, 106)],
        [(220, 80), (185, 87), (150, 94)],
        [(220, 120), (185, 113), (150, 106)],
    ]
    split = split_touching_strands(*_four_arms(mask, arms))
    assert split.pairs == []
    assert split.junction_of_end == [-1, 0] * 4


@pytest.mark.parametrize(("crossing", "split_pieces"), [(False, [0]), (True, [])])
def test_a_shared_piece_shorter_than_its_width_is_judged_at_its_middle(crossing, split_pieces):
    """A line thinning leaves between two three-way junctions only 12 px long, shorter
    than the stretch is wide (18 px): before, nothing of it was measured and two strands
    touching there were taken for a crossing (a doubled-back cable's bridges cut across
    the stretch). At its middle the mask keeps both strands' widths, and the strands
    keep their sides; where two cables cross at 44 degrees the middle is where they
    cross, one cable wide, and the junctions are left a crossing."""
    if crossing:
        first, second = [(20, 60), (220, 140)], [(20, 140), (220, 60)]
        middle = 120.0
    else:
        first = [(20, 40), (100, 95.5), (112, 95.5), (192, 40)]
        second = [(20, 160), (100, 104.5), (112, 104.5), (192, 160)]
        middle = 106.0
    mask = touching_strands_mask(first, second, shape=(200, 240))
    shared = np.column_stack([np.linspace(middle - 6, middle + 6, 4), np.full(4, 100.0)])
    arms = [
        np.array([first[0], (middle - 30, 100 - 14), (middle - 8, 99)], np.float64),
        np.array([second[0], (middle - 30, 100 + 14), (middle - 8, 101)], np.float64),
        np.array([(middle + 8, 99), (middle + 30, 100 - 14), first[-1]], np.float64),
        np.array([(middle + 8, 101), (middle + 30, 100 + 14), second[-1]], np.float64),
    ]
    split = _split_stretch_between_arms(mask, shared, arms)
    assert split.split == split_pieces
    if not crossing:
        partner = {end: other for pair in split.pairs for end, other in (pair, pair[::-1])}
        # Upper left (end 3) runs on through one copy of the line to upper right (end 6).
        copy = partner[3] // 2
        assert split.pieces[copy][:, 1].mean() < 100.0
        assert partner[2 * copy + 1] == 6


@pytest.mark.parametrize(("stub_thickness", "split_pieces"), [(9, [0]), (4, [])])
def test_a_strand_cut_short_past_the_stretch_is_a_strand_when_as_wide_as_its_partner(
    stub_thickness, split_pieces
):
    """Two strands touch for 200 px; past the stretch's right end one runs on and the
    other stops after 15 px (an object cuts a doubled-back cable's strand short of its
    bulb), shorter than the stretch is wide (20 px). As wide as the strand beside it
    (9 px) it is a strand, and the stretch is split, its two strands' far ends a
    parting to turn round between; a narrow stub (4 px, as the scraps thinning leaves
    where a cable's shadow, segmented with it, ends) is a scrap, and nothing is split."""
    upper = [(20, 40), (100, 95.5), (300, 95.5), (380, 40)]
    lower = [(20, 160), (100, 104.5), (300, 104.5)]
    mask = touching_strands_mask(upper, lower, shape=(200, 400))
    stub = np.zeros(mask.shape, np.uint8)
    cv2.polylines(stub, [np.array([(300, 104), (326, 112)], np.int32)], False, 1, stub_thickness)
    mask |= stub > 0
    shared = np.column_stack([np.linspace(108, 292, 24), np.full(24, 100.0)])
    arms = [
        np.array([upper[0], (70, 75), (92, 99)], np.float64),
        np.array([lower[0], (70, 125), (92, 101)], np.float64),
        np.array([(308, 99), (330, 74.7), upper[-1]], np.float64),
        np.array([(308, 104), (322, 110.5)], np.float64),
    ]
    split = _split_stretch_between_arms(mask, shared, arms)
    assert split.split == split_pieces
    if split_pieces:
        # The far ends of the two strands parting at the right end: upper right's (7)
        # and the stub's (9).
        assert sorted(sorted(pair) for pair in split.partings)[-1] == [7, 9]
        assert split.strand_widths[4] >= 4.0


def _split_stretch_between_arms(mask, shared, arms):
    """:func:`split_touching_strands` of a ``shared`` piece between two three-way
    junctions (0 at its start, 1 at its end), ``arms`` upper left, lower left (their
    last point at junction 0), upper right and lower right (their first at junction 1)."""
    pieces = [shared, *arms]
    positions = np.array([points[index] for points in pieces for index in (0, -1)])
    directions = np.array(
        [points[index] - points[inner] for points in pieces for index, inner in ((0, 1), (-1, -2))]
    )
    directions /= np.hypot(directions[:, 0], directions[:, 1])[:, None]
    distance = cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, 5)
    labels = [0, 1, -1, 0, -1, 0, 1, -1, 1, -1]
    return split_touching_strands(pieces, positions, directions, labels, distance)


def test_a_cable_crossing_where_touching_strands_part_is_taken_out_of_their_junction():
    """Five ends in one junction zone: a stretch two strands wide (piece 2, half width
    9) parting into two strands (pieces 3 and 4), and a cable (pieces 0 and 1) crossing
    right there. The crossing cable runs straight through and agrees in width with
    itself; the upper strand runs straight on into the stretch too, but the stretch is
    both strands wide (doubled_back 310129)."""
    from service.perception.touching import _straight_through

    positions = np.array(
        [
            (0, 0),
            (100, 80),
            (130, 120),
            (200, 200),
            (0, 0),
            (95, 100),
            (0, 0),
            (110, 96),
            (0, 0),
            (112, 108),
        ],
        np.float64,
    )
    directions = np.zeros_like(positions)
    directions[1] = (0.6, 0.8)  # the crossing cable's upper end, pointing down across
    directions[2] = (-0.6, -0.8)  # its lower end, pointing up
    directions[5] = (1.0, 0.0)  # the stretch's end, pointing right along it
    directions[7] = (-1.0, 0.0)  # the upper strand, straight on from the stretch
    directions[9] = (-0.96, -0.28)  # the lower strand, bending away
    widths = np.array([4.5, 4.5, 9.0, 4.5, 4.5])
    ends = [1, 2, 5, 7, 9]
    assert _straight_through(ends, positions, directions, widths) == (1, 2)
    widths[2] = 4.5  # a strand of one width: two straight pairs, none taken
    assert _straight_through(ends, positions, directions, widths) is None


def test_four_ends_of_a_wide_crossing_are_left_to_the_crossing():
    """Two cables 8 px wide crossing at 85 degrees, the four ends 13 px from the middle:
    the middle of the X lies about sqrt(2) half widths from the background, over the
    3/4 of two strands a shallow crossing's narrowing is held to once the distance's
    pixel rounding is counted, and the junction was paired as a touching stretch (a
    loop's own crossing read so, its cable turned back at it: loops 20020, 20174, 20192,
    290195). No touching stretch is that narrow: the junction is left to the crossing."""
    centre, pieces = np.array([120.0, 120.0]), []
    for angle in np.radians([-42.5, 42.5, 137.5, 222.5]):
        way = np.array([np.cos(angle), np.sin(angle)])
        pieces.append(centre + np.linspace(100.0, 13.0, 88)[:, None] * way)
    first, second = [pieces[0][0], pieces[2][0]], [pieces[1][0], pieces[3][0]]
    mask = touching_strands_mask(first, second, thickness=8, shape=(240, 240))
    positions = np.array([points[index] for points in pieces for index in (0, -1)])
    directions = np.array(
        [points[index] - points[inner] for points in pieces for index, inner in ((0, 1), (-1, -2))]
    )
    directions /= np.hypot(directions[:, 0], directions[:, 1])[:, None]
    distance = cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, 5)
    middle = distance[120, 120]
    assert (
        0.75
        * 2
        * np.median(
            distance[np.rint(pieces[0][:, 1]).astype(int), np.rint(pieces[0][:, 0]).astype(int)]
        )
        <= middle
    )
    split = split_touching_strands(pieces, positions, directions, [-1, 0] * 4, distance)
    assert split.pairs == []
    assert split.junction_of_end == [-1, 0] * 4


@pytest.mark.parametrize("seed", [20020, 20174, 20192, 290195])
def test_a_loops_own_crossing_at_a_wide_angle_is_crossed_not_turned_back(seed):
    """A loop crossing itself at 70-95 degrees: the junction's four ends were paired as a
    touching stretch's, each strand turning back into the other's arm, and the chain
    cut the crossing's corners, two visible stretches a pixel or two beyond tolerance."""
    score, _ = evaluate_scene(make_family_scene("loops", seed), seed, mask_from_labels=True)
    assert score.frame.correct


@pytest.mark.parametrize("seed", [400162])
def test_a_loops_crossing_beside_the_object_that_cuts_one_strand_short_is_crossed(seed):
    """A loop's own crossing with an object right beside it: one strand runs 11 px from
    the crossing into the object, and its median width (2.7 against its cable's 4.4) fell
    where the object cuts it. Counted so, the two strands' widths held the crossing's
    middle (7.0) to less than a crossing's, and the junction was paired as a touching
    stretch, the cable turned back at its crossing (one chain too many). A short strand
    is as wide as the widest its mask gets, as a shared piece's short strand is read."""
    score, _ = evaluate_scene(make_family_scene("loops", seed), seed, mask_from_labels=True)
    assert score.frame.correct
