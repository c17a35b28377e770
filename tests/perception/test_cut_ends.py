"""Bridges drawn from the cut: the stretch between where an end's fit begins and where
the cable passes out of sight, traced on the mask (:mod:`service.perception.cut_ends`)."""

import numpy as np
import pytest

from service.evaluation.synthetic_eval import evaluate_scene
from service.perception.appearance import _first_off, _front, _lab_beside
from service.perception.cut_ends import (
    SECTION_STEP_PX,
    _border_distance,
    _carried,
    _far_border,
    along_the_wedge,
    bridges_from_the_cuts,
    carried_to_the_border,
    end_at_the_cut,
    middle_line,
    read_together,
    short_piece_cut,
    unfitted_end_cut,
)
from service.perception.merging import ChainEnd
from service.synthetic.families import make_family_scene
from tests.perception.references.appearance import first_off, front
from tests.perception.references.appearance import lab_beside as plain_lab_beside
from tests.perception.references.cut_ends import middle_line as plain_middle_line

CENTRE = np.array([100.0, 100.0])
BEND = 30.0  # px: a loop's bend of 6 radii for a cable of half width 5
HALF_WIDTH = 5.0


def arc_mask(cut_angle: float, slant: float = 0.0) -> np.ndarray:
    """A cable of ``HALF_WIDTH`` bending round ``CENTRE`` at ``BEND`` px, from angle
    -pi/2 counter-clockwise (in x, y) to where an object's straight border cuts it: the
    line through the middle line's point at ``cut_angle``, across the cable turned by
    ``slant`` radians."""
    ys, xs = np.mgrid[0:200, 0:200].astype(np.float64)
    offset = np.column_stack([xs.ravel(), ys.ravel()]) - CENTRE
    radial = np.hypot(*offset.T)
    angle = np.arctan2(offset[:, 1], offset[:, 0])
    on_cable = (np.abs(radial - BEND) <= HALF_WIDTH) & (angle >= -np.pi / 2) & (angle <= 2.5)
    cut_point = CENTRE + BEND * np.array([np.cos(cut_angle), np.sin(cut_angle)])
    tangent = np.array([-np.sin(cut_angle), np.cos(cut_angle)])
    along = np.array(
        [
            np.cos(slant) * tangent[0] - np.sin(slant) * tangent[1],
            np.sin(slant) * tangent[0] + np.cos(slant) * tangent[1],
        ]
    )
    # The object's border runs across the cable at ``slant`` from square: what lies
    # ahead of it, along the cable's tangent there, is hidden.
    border_normal = along
    hidden = (offset + CENTRE - cut_point) @ border_normal > 0
    return (on_cable & ~hidden).reshape(200, 200)


def end_before(angle: float, skip: float) -> ChainEnd:
    """An end where a fit leaving out ``skip`` px would begin: on the middle line at
    ``angle``, heading along the cable (counter-clockwise), bending as it does."""
    position = CENTRE + BEND * np.array([np.cos(angle), np.sin(angle)])
    direction = np.array([-np.sin(angle), np.cos(angle)])
    return ChainEnd(0, False, position, direction, 1.0 / BEND, skip, HALF_WIDTH - 0.5)


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b), -1.0, 1.0))))


def test_a_square_cut_on_a_tight_bend_is_found_where_the_cable_disappears():
    """The fit begins 12 px (23 degrees of bend) before the cut: traced on, the bridge
    starts within a pixel and a half of the cut, heading along the cable there."""
    cut_angle = 0.6
    end = end_before(cut_angle - 12.0 / BEND, skip=8.0)
    found = end_at_the_cut(arc_mask(cut_angle), end, HALF_WIDTH, 8.0 + 2 * HALF_WIDTH + 2.0)
    assert found is not None
    traced, position, direction = found
    cut = CENTRE + BEND * np.array([np.cos(cut_angle), np.sin(cut_angle)])
    tangent = np.array([-np.sin(cut_angle), np.cos(cut_angle)])
    assert np.hypot(*(position - cut)) <= 1.5
    assert angle_deg(direction, tangent) <= 6.0
    # The traced stretch keeps to the middle line, half a width in from both borders.
    radial = np.hypot(*(traced - CENTRE).T)
    assert np.abs(radial - BEND).max() <= 1.0


def test_a_slanted_cut_stops_the_trace_where_it_begins_and_the_bridge_at_the_middle():
    """Cut at 50 degrees from square: past where the border first reaches the cable,
    what is left of it is a wedge whose middle is not the cable's; the trace stops
    about there, near the middle line, and the middle line is carried on as it ran to
    where the border crosses it (half the slant, 6 px, further on): the bridge starts
    there, within 3 px of the cut, not 6 px before it."""
    cut_angle = 0.6
    end = end_before(cut_angle - 14.0 / BEND, skip=10.0)
    found = end_at_the_cut(
        arc_mask(cut_angle, np.radians(50.0)), end, HALF_WIDTH, 10.0 + 2 * HALF_WIDTH + 2.0
    )
    assert found is not None
    traced, position, direction = found
    # Within the narrowing the trace allows (CUT_NARROWING_PX) of the middle line.
    assert np.abs(np.hypot(*(traced - CENTRE).T) - BEND).max() <= 1.5
    stopped = float(np.arctan2(*(traced[-1] - CENTRE)[::-1]))
    assert (cut_angle - stopped) * BEND >= 3.0
    angle = float(np.arctan2(*(position - CENTRE)[::-1]))
    assert abs(angle - cut_angle) * BEND <= 3.0
    assert abs(np.hypot(*(position - CENTRE)) - BEND) <= 1.5
    # The last points, a pixel off where the cut begins, tilt the short fit (over
    # three radii, to follow tight bends) by up to 15 degrees.
    tangent = np.array([-np.sin(angle), np.cos(angle)])
    assert angle_deg(direction, tangent) <= 15.0


BACKGROUND_BGR = (60, 60, 60)
OBJECT_BGR = (40, 150, 220)  # orange: far from the grey ground


def wedge_scene(slant: float, object_bgr, beside_bgr=BACKGROUND_BGR):
    """The arc cut at ``slant`` (:func:`arc_mask`), drawn: a grey ground, an object of
    ``object_bgr`` beyond its border, and ``beside_bgr`` beyond the cable's outer border
    where the wedge runs on (the ground, or the object lying alongside). Returns the
    mask, the BGR image and the middle line traced up to where the cut's border first
    reaches the cable (1 px steps)."""
    cut_angle = 0.6
    mask = arc_mask(cut_angle, slant)
    ys, xs = np.mgrid[0:200, 0:200].astype(np.float64)
    offset = np.stack([xs, ys], -1)
    cut_point = CENTRE + BEND * np.array([np.cos(cut_angle), np.sin(cut_angle)])
    tangent = np.array([-np.sin(cut_angle), np.cos(cut_angle)])
    along = np.array(
        [
            np.cos(slant) * tangent[0] - np.sin(slant) * tangent[1],
            np.sin(slant) * tangent[0] + np.cos(slant) * tangent[1],
        ]
    )
    image = np.empty((200, 200, 3), np.uint8)
    image[:] = BACKGROUND_BGR
    image[np.hypot(*(offset - CENTRE).transpose(2, 0, 1)) > BEND + HALF_WIDTH] = beside_bgr
    image[(offset - cut_point) @ along > 0] = object_bgr
    image[mask] = (30, 30, 160)
    # The first border reaches the cable a half width times the slant's tangent before
    # the cut's middle.
    first = cut_angle - (HALF_WIDTH * np.tan(abs(slant)) + 1.0) / BEND
    angles = np.arange(first - 20.0 / BEND, first, 1.0 / BEND)
    points = CENTRE + BEND * np.column_stack([np.cos(angles), np.sin(angles)])
    return mask, image, points


def test_a_wedges_border_is_followed_where_the_image_shows_an_object_beyond_the_other():
    """Cut at 30 degrees from square, the object orange on a grey ground: beyond the
    border that reads short lies the object, beyond the one still at the cable's
    distance the ground seen beside the cable, so the line is carried on into the
    wedge half a width in from that border, on the cable's middle (within 1.5 px)."""
    mask, image, points = wedge_scene(np.radians(-30.0), OBJECT_BGR)
    added = along_the_wedge(mask, points, HALF_WIDTH, 15.0, image)
    assert len(added) >= 2
    assert np.abs(np.hypot(*(added - CENTRE).T) - BEND).max() <= 1.5


@pytest.mark.parametrize(
    ("object_bgr", "beside_bgr"),
    [(BACKGROUND_BGR, BACKGROUND_BGR), (OBJECT_BGR, OBJECT_BGR)],
    ids=["object-of-the-grounds-colour", "object-beyond-both-borders"],
)
def test_a_wedge_the_image_does_not_tell_apart_is_left_alone(object_bgr, beside_bgr):
    """The same wedge where the image does not say which border is the cable's: an
    object of the ground's own colour (the mask alone cannot tell the cable's border
    from the object's edge: wedge15, docs/BENCHMARKS.md), or the object beyond both
    borders (the one followed would be its edge). Nothing is added; nor without an
    image."""
    mask, image, points = wedge_scene(np.radians(-30.0), object_bgr, beside_bgr)
    assert len(along_the_wedge(mask, points, HALF_WIDTH, 15.0, image)) == 0
    assert len(along_the_wedge(mask, points, HALF_WIDTH, 15.0)) == 0


@pytest.mark.parametrize(
    "seed",
    [
        420132,
        # Wrong until depth23 (read_together, dback17: its two cuts open 34 degrees as the
        # bulb does, and their mean drew the turn 21 px off): the turn pass now takes the
        # curve the object hides whole nearest the middle of its depth, 6.5 px off.
        420263,
        420265,
    ],
)
def test_a_doubled_back_turn_cut_at_a_coloured_objects_wedge_is_covered(seed):
    """Tuning scenes, true mask, each turn hidden by an object of a colour unlike the
    ground: one cut's direction is read along the wedge's border the image shows is
    the cable's (main read it 15-30 degrees off; wedge15's class)."""
    scene = make_family_scene("doubled_back", seed)
    score, _ = evaluate_scene(scene, seed, mask_from_labels=True)
    assert score.frame.correct, score.frame.coverage


def test_a_short_pieces_cut_is_traced_from_its_middle():
    """A short piece (bridged along its partners' line) whose tip thinning bent 3 px
    toward the corner of a square cut: its bridge starts on the middle line at the
    cut, in the partners' direction, not at the tip."""
    mask = np.zeros((60, 120), bool)
    mask[25:36, 10:71] = True  # a cable of half width 5.5 along y = 30, cut at x = 70.5
    points = np.array([[35.0, 30.0], [50.0, 30.0], [62.0, 31.0], [68.0, 33.0]])
    end = ChainEnd(0, False, points[-1], np.array([1.0, 0.0]))
    found = short_piece_cut(mask, points, end, HALF_WIDTH + 0.5)
    assert found is not None
    position, direction = found
    assert abs(position[1] - 30.0) <= 0.5
    assert 68.0 <= position[0] <= 71.0
    assert np.allclose(direction, [1.0, 0.0], atol=0.02)


def test_an_end_left_at_its_tip_in_the_cuts_corner_reads_its_cut_from_the_middle():
    """A piece too short for its end's fit (five joints, the fit's skip half of it) on a
    loop's bend: the end is left at its tip, which thinning bent 4 px toward the cut's
    outer corner, heading along the chord through it, 43 degrees off the cable. Traced
    from there the section is already narrowed: no cut. Read from the piece's middle,
    along the joints either side of it, the cut lies on the middle line, within 3 px
    before the true cut, heading within 8 degrees of the cable."""
    cut_angle = 0.6
    mask = arc_mask(cut_angle)
    angles = cut_angle - np.array([36.0, 26.0, 16.0, 6.0]) / BEND
    points = CENTRE + BEND * np.column_stack([np.cos(angles), np.sin(angles)])
    corner = cut_angle - 1.0 / BEND
    tip = CENTRE + (BEND + 0.8 * HALF_WIDTH) * np.array([np.cos(corner), np.sin(corner)])
    points = np.vstack([points, tip])
    chord = (points[-1] - points[-2]) / np.hypot(*(points[-1] - points[-2]))
    end = ChainEnd(0, False, tip, chord, 0.0, 20.0, HALF_WIDTH - 0.5)
    tangent = np.array([-np.sin(cut_angle), np.cos(cut_angle)])
    assert angle_deg(chord, tangent) > 40.0
    assert end_at_the_cut(mask, end, HALF_WIDTH, 20.0 + 2 * HALF_WIDTH + 2.0) is None
    found = unfitted_end_cut(mask, points, end, HALF_WIDTH)
    assert found is not None
    position, direction = found
    cut = CENTRE + BEND * np.array([np.cos(cut_angle), np.sin(cut_angle)])
    assert abs(np.hypot(*(position - CENTRE)) - BEND) <= 1.0
    assert np.hypot(*(position - cut)) <= 3.0
    assert angle_deg(direction, tangent) <= 8.0


@pytest.mark.parametrize("seed", [400233, 410254])
def test_a_loops_turn_from_an_end_left_at_its_tip_is_bridged_from_its_pieces_middle(seed):
    """Loops 400233 and 410254 (tuning blocks): a five-joint piece between the loop's
    crossing and the object, its end left at its tip 4-5 px off the middle and 24-27
    degrees off; bridged from the cut read from its middle, the hidden turn is covered."""
    score, _ = evaluate_scene(make_family_scene("loops", seed), seed, mask_from_labels=True)
    assert score.frame.correct


def straight_cable_mask(
    heading_deg: float, radius: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A straight cable drawn as the renderer draws one (a pixel is the cable's where its
    centre lies within ``radius`` of the middle line), at ``heading_deg`` to the x axis,
    from ``origin`` 60 px on to a square cut. Returns the mask, the origin and the
    cable's unit direction."""
    ys, xs = np.mgrid[0:120, 0:160].astype(np.float64)
    angle = np.radians(heading_deg)
    along_unit = np.array([np.cos(angle), np.sin(angle)])
    origin = np.array([20.0, 40.0])
    offset = np.stack([xs - origin[0], ys - origin[1]], -1)
    along = offset @ along_unit
    across = offset @ np.array([-along_unit[1], along_unit[0]])
    return (np.abs(across) <= radius) & (along >= 0.0) & (along <= 60.0), origin, along_unit


@pytest.mark.parametrize(("heading_deg", "radius"), [(27.0, 4.8), (40.0, 4.6)])
def test_a_section_narrowed_by_the_borders_rounding_alone_is_no_cut(heading_deg, radius):
    """A straight cable of radius 4.6-4.8 at a slant, traced with the half width 5.5 a
    piece's skeleton gives (its width 5.0, and half a pixel): each border read across
    the slant falls up to 0.7 px short, so single sections read narrower than the cable
    by more than :data:`CUT_NARROWING_PX`, though the next one is full again. Such a
    section stopped the trace 6 px before the cut (27 degrees), or behind the end
    (40 degrees: the end's own fit, 8 degrees off, bent on). A cut's narrowing runs on:
    the trace goes on past it to the cut, and the direction is fitted behind the end."""
    mask, origin, along_unit = straight_cable_mask(heading_deg, radius)
    lean = np.radians(8.0)  # the end's fit, bent by the cut's hook
    heading = np.array(
        [
            np.cos(lean) * along_unit[0] - np.sin(lean) * along_unit[1],
            np.sin(lean) * along_unit[0] + np.cos(lean) * along_unit[1],
        ]
    )
    end = ChainEnd(0, False, origin + 40.0 * along_unit, heading, 0.0, 8.0, 5.0)
    found = end_at_the_cut(mask, end, 5.5, 8.0 + 2 * 5.5 + 2.0)
    assert found is not None
    _, position, direction = found
    assert abs(float((position - origin) @ along_unit) - 60.0) <= 1.5
    assert angle_deg(direction, along_unit) <= 4.0


@pytest.mark.parametrize(
    ("family", "seed"),
    [("loops", 400201), ("loops", 410161), ("doubled_back", 400149), ("doubled_back", 410105)],
)
def test_hidden_stretches_bridged_from_cuts_no_rounding_stopped_short_are_covered(family, seed):
    """Tuning scenes (true mask) whose traces stopped at a section its borders' rounding
    alone narrowed: ahead of the end, 9-16 px of arc short of the cut, the direction
    fitted up to there (loops 400201, 410161); behind it, the end's own fit bent on,
    25-26 degrees off (doubled_back 400149, 410105). Traced on, every cable is covered."""
    score, _ = evaluate_scene(make_family_scene(family, seed), seed, mask_from_labels=True)
    assert score.frame.correct


def slanted_cut_mask() -> np.ndarray:
    """A straight cable of half width 5.5 along y = 30, cut at 45 degrees from square by
    the border x = 80 + (y - 30): its middle line leaves the mask at x = 80, its side
    at y = 25 at x = 75, and the wedge on the side y = 35 runs on to x = 85."""
    mask = np.zeros((60, 140), bool)
    ys, xs = np.mgrid[0:60, 0:140]
    mask[(np.abs(ys - 30) <= 5) & (xs <= 80 + (ys - 30))] = True
    return mask


def test_the_middle_line_is_carried_towards_the_border_while_both_sides_are_seen():
    """From where the section begins to narrow (its near side, x = 75), carried on as it
    ran until the line a quarter width to the near side leaves the mask, 2.75 px short
    of where the border crosses the middle (x = 80), and not along the wedge the far side
    leaves, 10 px on."""
    start = np.array([75.0, 30.0])
    position, direction = carried_to_the_border(
        slanted_cut_mask(), start, np.array([1.0, 0.0]), 0.0, 5.5
    )
    assert abs(position[0] - 77.25) <= 1.0
    assert abs(position[1] - 30.0) <= 1e-9
    assert np.allclose(direction, [1.0, 0.0])


@pytest.mark.parametrize("lean_deg", [20.0, -20.0])
def test_a_direction_leaning_off_is_not_carried_off_the_cable(lean_deg):
    """The direction read at a short traced cut on a tight bend can be 10-35 degrees
    off. Leaning 20 degrees either way, the carry stops where the cable stops being
    seen on both sides of the carried line: its start stays within 1.1 px of the
    middle line (carried on to halfway between where the two side lines leave, the
    start fell 2.0 and 1.4 px off, leaning into the wedge and away from it)."""
    lean = np.radians(lean_deg)
    position, _ = carried_to_the_border(
        slanted_cut_mask(),
        np.array([75.0, 30.0]),
        np.array([np.cos(lean), np.sin(lean)]),
        0.0,
        5.5,
    )
    assert abs(position[1] - 30.0) <= 1.1
    assert 75.0 < position[0] <= 80.0


def painted_slanted_cut(object_bgr) -> np.ndarray:
    """:func:`slanted_cut_mask` drawn: a grey ground, an object of ``object_bgr`` beyond
    the cut's border (x > 80 + (y - 30)), the cable red."""
    ys, xs = np.mgrid[0:60, 0:140]
    image = np.empty((60, 140, 3), np.uint8)
    image[:] = BACKGROUND_BGR
    image[xs > 80 + (ys - 30)] = object_bgr
    image[slanted_cut_mask()] = (30, 30, 160)
    return image


@pytest.mark.parametrize("lean_deg", [35.0, -35.0])
def test_a_cut_read_along_a_direction_off_the_cable_is_put_between_the_corners(lean_deg):
    """The 45-degree cut of a straight cable read from its last full section (x = 73, 2
    px before its near side is cut) with a direction 35 degrees off (what a short fit
    reads on a tight bend): carried on along it, the start fell 2.9-3.4 px off the
    middle line; put halfway between the two corners where the cable's borders meet the
    object's edge, (75, 25) and (85, 35), the ends of the border beyond which the image
    shows the object (each read within a pixel), it is within a pixel of where the border
    crosses the middle, whatever the direction.
    Under an object of the ground's colour nothing tells the edge from the borders: the
    carried point is kept."""
    lean = np.radians(lean_deg)
    heading = np.array([np.cos(lean), np.sin(lean)])
    start = np.array([73.0, 30.0])
    mask = slanted_cut_mask()
    position, _ = _carried(mask, start, heading, 0.0, 5.5, False, painted_slanted_cut(OBJECT_BGR))
    assert np.hypot(*(position - [80.0, 30.0])) <= 1.0
    unseen, _ = _carried(mask, start, heading, 0.0, 5.5, False, painted_slanted_cut(BACKGROUND_BGR))
    carried, _ = carried_to_the_border(mask, start, heading, 0.0, 5.5)
    assert np.allclose(unseen, carried)


@pytest.mark.parametrize("slant_deg", [-40.0, 0.0, 40.0])
@pytest.mark.parametrize("lag_deg", [30.0, -30.0])
def test_a_cut_on_a_tight_bend_read_with_a_lagging_direction_stays_on_the_middle(
    slant_deg, lag_deg
):
    """The arc of bend 30 px (half width 5) cut at -40 to 40 degrees by an orange object,
    its cut read 8 px before the cut with a direction 30 degrees off the cable's either
    way (a fit lagging the bend, or leaning into a wedge): carried along it the bridge
    started 2.0-3.1 px off the middle line; between the corners the image shows, within
    a pixel of the middle (the corners are the border pixels' centres) and 2 px of the
    cut."""
    start_angle = 0.6 - 8.0 / BEND
    start = CENTRE + BEND * np.array([np.cos(start_angle), np.sin(start_angle)])
    tangent = np.array([-np.sin(start_angle), np.cos(start_angle)])
    lag = np.radians(lag_deg)
    heading = np.array(
        [
            np.cos(lag) * tangent[0] - np.sin(lag) * tangent[1],
            np.sin(lag) * tangent[0] + np.cos(lag) * tangent[1],
        ]
    )
    mask, image, _ = wedge_scene(np.radians(slant_deg), OBJECT_BGR)
    position, _ = _carried(mask, start, heading, 0.0, HALF_WIDTH, False, image)
    cut = CENTRE + BEND * np.array([np.cos(0.6), np.sin(0.6)])
    assert abs(np.hypot(*(position - CENTRE)) - BEND) <= 1.0
    assert np.hypot(*(position - cut)) <= 2.0


@pytest.mark.parametrize("seed", [480040, 480240])
def test_doubled_back_cuts_carried_off_the_middle_are_read_between_the_corners(seed):
    """Tuning scenes (true mask) whose strands bend into their hidden turn at a coloured
    object's edge: the directions read at the cuts lag the bend (480240: 41 degrees), and
    carried along them the bridges started 1.3-3.9 px off the middle and missed the turn
    (480040 4.6 px against 4.3, 480240 9.5 against 7.0); from the midpoints of the
    corners the image shows, both turns are covered."""
    score, _ = evaluate_scene(make_family_scene("doubled_back", seed), seed, mask_from_labels=True)
    assert score.frame.correct


def test_a_start_off_the_middle_is_put_on_it_at_once():
    """A fit's start 2 px off the middle of a straight cable: the trace starts on the
    middle (not a pixel a step towards it, leaning its first points across the cable),
    and reads each section's shortfall from the cable's width, none before the cut."""
    mask = np.zeros((60, 120), bool)
    mask[25:36, 10:71] = True  # half width 5.5 about y = 30, cut square at x = 70.5
    points, cut, shortfall = middle_line(
        mask, np.array([40.0, 32.0]), np.array([1.0, 0.0]), 0.0, 5.5, 40.0
    )
    assert cut
    assert np.abs(points[:, 1] - 30.0).max() <= 0.25
    assert 69.0 <= points[-1, 0] <= 71.0
    assert len(shortfall) == len(points)
    assert shortfall.max() <= 0.5


def test_no_cut_within_reach_is_no_cut():
    """The cable runs on well past the stretch the fit left out: the end is not at a
    cut (its bridge starts where its fit begins, as before)."""
    end = end_before(-1.0, skip=4.0)
    assert end_at_the_cut(arc_mask(2.4), end, HALF_WIDTH, 4.0 + 2 * HALF_WIDTH + 2.0) is None


@pytest.mark.parametrize(
    ("family", "seed"),
    [
        pytest.param(
            "doubled_back",
            330063,
            marks=pytest.mark.xfail(
                strict=True,
                reason="the directions read at its two traced cuts lean 21 and 27 degrees "
                "outwards; the Euler spiral (a turn of 107 degrees, about 155 on those directions) "
                "follows them about 1.5 px further out than the cubic did, past the "
                "tolerance (euler_spiral.py; the direction at a cut is cut_ends.py's)",
            ),
        ),
        ("doubled_back", 330100),
        ("loops", 330066),
        ("loops", 330149),
        ("loops", 330181),
    ],
)
def test_hidden_turns_bridged_from_their_cuts_are_covered(family, seed):
    """Tuning scenes (true mask) whose hidden turn was bridged from where the ends'
    fits begin, 6-17 px before the cuts, and fell inside the true bend by more than the
    tolerance: bridged from the cuts, every cable is covered."""
    score, _ = evaluate_scene(make_family_scene(family, seed), seed, mask_from_labels=True)
    assert score.frame.correct


LAGGING_CUTS = pytest.mark.xfail(
    strict=True,
    reason="the directions read at both cuts lag the loop's bend by 10-23 degrees (it tightens "
    "at the cut, on the wedge the slanted cut leaves, which the trace stops before); the hidden "
    "half turn is bridged as one of about 200 degrees and bulges out by 6-18 px. From the same "
    "cut points with the true tangents the curve covers (0.3-3.1 px). Reading the cut along the "
    "side the object has not reached was tried (docs/BENCHMARKS.md, branch loops10), not kept",
)


@pytest.mark.parametrize(
    ("family", "seed"),
    [pytest.param("loops", 330001, marks=LAGGING_CUTS), ("loops", 350104)],
)
def test_a_loops_hidden_half_turn_is_bridged_from_directions_that_follow_its_bend(family, seed):
    """Tuning scenes (true mask) whose loop passes out of sight where it bends tightest:
    the bridge between the right cut points leaves each along a direction that lags
    the bend, and the hidden stretch is not covered (330001). 350104 comes right once
    a section narrowed by its borders' rounding alone no longer stops the trace short of
    the cut (``cut_ends._full_beyond``)."""
    score, _ = evaluate_scene(make_family_scene(family, seed), seed, mask_from_labels=True)
    assert score.frame.correct


@pytest.mark.parametrize(
    ("family", "seed"),
    [
        ("loops", 330047),
        ("loops", 330090),
        ("loops", 330096),
        ("doubled_back", 330138),
        ("occluded", 330027),
    ],
)
def test_bridges_from_where_the_middle_line_leaves_the_cable_cover_hidden_stretches(family, seed):
    """Tuning scenes (true mask) whose bridge started before the cut: where a slanted
    border begins to narrow the section (doubled_back 330138), or at a short piece's
    tip, which thinning bent off the middle toward the cut's corner (loops 330047,
    330090; 330096, a turn whose one end is such a piece). Started where the middle
    line meets the cut, every cable is covered."""
    score, _ = evaluate_scene(make_family_scene(family, seed), seed, mask_from_labels=True)
    assert score.frame.correct


@pytest.mark.parametrize(
    ("family", "seed"),
    [
        ("baseline", 86040),
        ("loops", 330056),
        ("same_colour", 330111),
    ],
)
def test_cuts_read_over_few_traced_points_are_not_carried_off_the_cable(family, seed):
    """Tuning scenes (true mask) whose cut directions, read over 3-9 traced points of a
    thin cable or a tight bend, lean 5-24 degrees: carried on to halfway between where
    the two side lines leave the mask, the bridges started 1.7-2.7 px off the middle and
    missed the hidden stretch; carried only while the cable is seen on both sides of
    the carried line, every cable is covered."""
    score, _ = evaluate_scene(make_family_scene(family, seed), seed, mask_from_labels=True)
    assert score.frame.correct


@pytest.mark.parametrize(("half_width", "traced"), [(1.5, False), (5.0, True)])
def test_a_cable_thinner_than_twice_the_cuts_narrowing_is_not_traced(half_width, traced):
    """Two ends across a square gap of a straight cable, each fit leaving a 4 px tip out:
    a cable of half width 5 is traced to its cuts (a bridge drawn from them); one of
    half width 1.5 (a 3 px strip, where the 2 px narrowing that marks a cut is most of
    its section) is not: its bridges start where the fits begin, as before."""
    mask = np.zeros((40, 160), bool)
    rows = slice(round(20 - half_width + 0.5), round(20 + half_width - 0.5) + 1)
    mask[rows, 10:61] = True
    mask[rows, 100:151] = True
    ends = [
        ChainEnd(
            0, False, np.array([56.0, 20.0]), np.array([1.0, 0.0]), 0.0, 4.0, half_width - 0.5
        ),
        ChainEnd(
            1, True, np.array([104.0, 20.0]), np.array([-1.0, 0.0]), 0.0, 4.0, half_width - 0.5
        ),
    ]
    bridges = bridges_from_the_cuts(
        ends, [(0, 1, 1.0)], [-1, -1], mask, half_width - 0.5, frozenset()
    )
    assert bool(bridges) == traced
    if traced:
        curve = bridges[0, 1]
        assert np.abs(curve[:, 1] - 20.0).max() <= 0.5


def _sliver_scene(sliver_width: float):
    """A straight cable of half width 8 along y = 40, cut at a slant near x = 80 and seen
    again from x = 120: its strand's skeleton ends at the fork thinning makes in the
    cut's wedge (x = 70), a sliver of ``sliver_width`` runs from there into the cut's
    upper corner (7 px off the middle), joined to the strand through the fork's junction
    and across the gap to the far piece."""
    ys, xs = np.mgrid[0:80, 0:170].astype(np.float64)
    band = np.abs(ys - 40.0) <= 7.5
    mask = band & (xs >= 10.0) & (xs <= 80.0 + 0.8 * (ys - 40.0))
    mask |= band & (xs >= 120.0) & (xs <= 160.0)
    sliver = np.array([[70.0, 40.0], [78.0, 33.0]])
    slant = (sliver[1] - sliver[0]) / np.hypot(*(sliver[1] - sliver[0]))
    ends = [
        ChainEnd(0, True, np.array([14.0, 40.0]), np.array([-1.0, 0.0]), 0.0, 4.0, 7.5),
        ChainEnd(0, False, np.array([66.0, 40.0]), np.array([1.0, 0.0]), 0.0, 4.0, 7.5),
        ChainEnd(1, True, sliver[0], -slant, 0.0, 0.0, sliver_width),
        ChainEnd(1, False, sliver[1], slant, 0.0, 0.0, sliver_width),
        ChainEnd(2, True, np.array([124.0, 40.0]), np.array([-1.0, 0.0]), 0.0, 4.0, 7.5),
        ChainEnd(2, False, np.array([156.0, 40.0]), np.array([1.0, 0.0]), 0.0, 4.0, 7.5),
    ]
    joins = [(1, 2, 0.1), (3, 4, 0.5)]
    junction_of_end = [-1, 0, 0, -1, -1, -1]
    return mask, ends, joins, junction_of_end, sliver


@pytest.mark.parametrize(("junction", "from_the_strand"), [(0, True), (-1, False)])
def test_a_sliver_in_the_cuts_corner_is_bridged_from_its_strands_cut(junction, from_the_strand):
    """A sliver (half width 2 against the strand's 7.5) joined to its strand through the
    fork's junction is no section of the cable: the gap's bridge leaves from where the
    strand's middle line, traced across the fork, reaches the cut, on the cable's
    middle. Read from the sliver itself (joined to nothing through a junction), the cut
    is its corner's, off the middle."""
    mask, ends, joins, junction_of_end, sliver = _sliver_scene(2.0)
    junction_of_end[1] = junction_of_end[2] = junction
    bridges = bridges_from_the_cuts(
        ends, joins, junction_of_end, mask, 7.5, frozenset(), short_pieces={3: (sliver, 2.0)}
    )
    curve = bridges[3, 4]
    # The curve's first point is the sliver's tip; the bridge proper follows.
    off_middle = np.abs(curve[1:, 1] - 40.0).max()
    assert (off_middle <= 1.0) == from_the_strand
    if from_the_strand:
        assert 72.0 <= curve[1, 0] <= 80.0  # at the cut, not at the fork


def _stub_scene():
    """A cable of half width 5 along y = 40, crossed at x = 60-70 by another running down
    (the crossing's junction), seen on as a stub to an object's square border at x = 80,
    and again from x = 120 (the other border) to 160. The strand's piece ends in the
    crossing's junction with its fit's direction 12 degrees off the cable (the crossing
    bends a fit there); the far piece's end is fitted where its fit begins, 4 px before its
    tip, its direction 12 degrees off the other way (a fit over a cut's hook)."""
    ys, xs = np.mgrid[0:80, 0:170].astype(np.float64)
    band = np.abs(ys - 40.0) <= 4.5
    mask = band & (xs >= 10.0) & (xs <= 80.0)
    mask |= band & (xs >= 120.0) & (xs <= 160.0)
    mask |= np.abs(xs - 65.0) <= 4.5
    tilt = np.radians(12.0)
    ends = [
        ChainEnd(0, True, np.array([14.0, 40.0]), np.array([-1.0, 0.0]), 0.0, 4.0, 4.5),
        ChainEnd(
            0, False, np.array([62.0, 40.0]), np.array([np.cos(tilt), np.sin(tilt)]), 0.0, 0.0, 4.5
        ),
        ChainEnd(
            1, True, np.array([124.0, 40.0]), np.array([-np.cos(tilt), np.sin(tilt)]), 0.0, 4.0, 4.5
        ),
        ChainEnd(1, False, np.array([156.0, 40.0]), np.array([1.0, 0.0]), 0.0, 4.0, 4.5),
    ]
    # Where the foreground along the end's line stops: at the border, 3.7 px off the middle.
    front_at = ends[1].position + (17.5 / np.cos(tilt)) * ends[1].direction
    front = ChainEnd(0, False, front_at, ends[1].direction, 0.0, 0.0, 4.5)
    return mask, ends, [(1, 2, 0.5)], [-1, 0, -1, -1], front


@pytest.mark.parametrize("stub", [True, False])
def test_a_gap_from_a_crossings_stub_is_bridged_from_the_stubs_front(stub):
    """A gap joined from an end in a crossing's junction, its strand seen on past the
    crossing as a stub to the object (:func:`.crossing_stubs.ends_past_crossings`): the
    bridge leaves from the stub's cut, traced onto the middle line from inside the stub
    (the front on the end's line lies 3.7 px off it), heading along the chord from the
    end, and arrives at the far end's traced cut (its direction read along the cable),
    where the plain gap curve from the end in the crossing and the far fit's start (both
    12 degrees off) would leave the middle line.
    With no stub's front given, the join is left to that curve (no bridge from the
    cuts), as before."""
    mask, ends, joins, junction_of_end, front = _stub_scene()
    bridges = bridges_from_the_cuts(
        ends,
        joins,
        junction_of_end,
        mask,
        4.5,
        frozenset(),
        stub_fronts={1: front} if stub else None,
    )
    assert bool(bridges) == stub
    if stub:
        curve = bridges[1, 2]
        across = curve[(curve[:, 0] >= 79.5) & (curve[:, 0] <= 120.0)]
        assert len(across)
        # The plain gap curve from the end in the crossing to the far fit's start
        # leaves the middle line by 3.3 px; from the front as given, along the end's
        # direction, by 3.7 px at the border itself.
        assert np.abs(across[:, 1] - 40.0).max() <= 1.0


@pytest.mark.parametrize("seed", [410046, 420024])
def test_a_loops_gap_from_a_crossings_stub_beside_the_object_is_bridged_from_the_cuts(seed):
    """Tuning scenes (true mask): a loop's crossing lies right beside the object, the
    crossing's strand seen on as a stub to it; the gap's other end is the loop's round,
    its end in the cut's corner, 25-40 degrees off. Bridged on the plain gap curve from
    the end in the crossing and that end, the hidden stretch was missed by 9.3 and 8.5 px
    (tolerances 4.2 and 5.4); from the stub's front and the far end's traced cut it is
    covered."""
    score, _ = evaluate_scene(make_family_scene("loops", seed), seed, mask_from_labels=True)
    assert score.frame.correct


def _degrees(vector: np.ndarray) -> float:
    return float(np.degrees(np.arctan2(vector[1], vector[0])))


def test_a_doubled_back_turns_two_cuts_opening_apart_take_their_common_direction():
    """Two strands side by side going into an object along +x (cuts at y = 40 and 60):
    readings that swing apart (the upper one 25 degrees up, the lower one 10 degrees
    down, both against their strands) are the fits lagging the turn: both take their
    mean, 7.5 degrees up, whichever cut comes first."""
    a, b = np.array([100.0, 40.0]), np.array([104.0, 60.0])
    up = np.array([np.cos(np.radians(-25.0)), np.sin(np.radians(-25.0))])
    down = np.array([np.cos(np.radians(10.0)), np.sin(np.radians(10.0))])
    for (p, first), (q, second) in (((a, up), (b, down)), ((b, down), (a, up))):
        leaving, arriving = read_together(p, first, q, second)
        assert np.allclose(leaving, arriving)
        assert abs(_degrees(leaving) + 7.5) < 1e-6


def test_cuts_closing_in_or_heading_apart_are_read_each_on_its_own():
    """Readings that turn towards each other (the cable's turn begun before the cuts),
    and a gap's two ends heading apart (the cable running on through the object), keep
    their own directions."""
    a, b = np.array([100.0, 40.0]), np.array([100.0, 60.0])
    closing = (
        np.array([np.cos(np.radians(30.0)), np.sin(np.radians(30.0))]),
        np.array([np.cos(np.radians(-20.0)), np.sin(np.radians(-20.0))]),
    )
    assert all(
        np.array_equal(x, y)
        for x, y in zip(read_together(a, closing[0], b, closing[1]), closing, strict=True)
    )
    gap = (np.array([1.0, 0.0]), np.array([-0.98, 0.2]))
    assert all(
        np.array_equal(x, y)
        for x, y in zip(read_together(a, gap[0], np.array([140.0, 40.0]), gap[1]), gap, strict=True)
    )


@pytest.mark.parametrize(
    ("family", "seed"),
    [
        ("doubled_back", 440044),
        ("doubled_back", 440217),
        ("doubled_back", 450082),
        ("doubled_back", 450227),
        ("loops", 440033),
    ],
)
def test_a_doubled_back_turns_cuts_read_together_cover_the_hidden_turn(family, seed):
    """Tuning scenes (true mask). doubled_back: a cable's hidden turn bridged from its two
    strands' cuts, read 20-45 degrees off and swinging apart (main missed the turn by
    7.9, 11.6, 20.7, 7.7 px against 5.7, 8.4, 8.0, 5.1; the common direction: 1.4-3.8
    px). loops 440033: a loop's turn hidden past a half turn, its two cuts swinging
    apart as its circle does, both pieces running back to the loop's crossing: read each
    on its own, as on main."""
    score, _ = evaluate_scene(make_family_scene(family, seed), seed, mask_from_labels=True)
    assert score.frame.correct, score.frame.coverage


def test_the_compiled_section_samples_equal_the_plain_loop():
    """``_border_distance`` and ``_far_border`` (compiled) against the plain Python loop
    they replaced: each sample's pixel rounded half to even, half-pixel positions and
    samples off the image included."""

    def plain(mask, x, y, dx, dy, steps, reach, far):
        height, width = mask.shape
        entered = False
        for step in steps:
            column, row = round(x + step * dx), round(y + step * dy)
            on = 0 <= column < width and 0 <= row < height and bool(mask[row, column])
            if on:
                entered = True
            elif entered or not far:
                return step - 0.5 * SECTION_STEP_PX
        return reach if entered or not far else None

    rng = np.random.default_rng(7)
    for _ in range(40):
        mask = rng.random((30, 40)) < rng.uniform(0.3, 0.95)
        reach = float(rng.uniform(1.0, 25.0))
        steps = np.arange(SECTION_STEP_PX, reach + 1e-9, SECTION_STEP_PX)
        for _ in range(50):
            x = float(rng.integers(-4, 44)) + float(rng.choice([0.0, 0.5, rng.random()]))
            y = float(rng.integers(-4, 34)) + float(rng.choice([0.0, 0.5, rng.random()]))
            angle = rng.uniform(0.0, 2.0 * np.pi)
            dx, dy = float(np.cos(angle)), float(np.sin(angle))
            assert _border_distance(mask, x, y, dx, dy, steps, reach) == plain(
                mask, x, y, dx, dy, steps.tolist(), reach, False
            )
            assert _far_border(mask, x, y, dx, dy, steps, reach) == plain(
                mask, x, y, dx, dy, steps.tolist(), reach, True
            )


def test_the_compiled_middle_line_equals_the_plain_trace():
    """``middle_line`` (its steps compiled) against the step-by-step Python trace it
    replaced (``references/cut_ends.py``), point for point and bit for bit: drawn cuts
    at many angles and slants, noisy masks, starts on and off the mask, bending
    headings, both readings of a narrowing, half widths as the passes give them."""
    rng = np.random.default_rng(31)
    masks = [arc_mask(angle, slant) for angle in (0.3, 1.2, 2.0) for slant in (-0.6, 0.0, 0.7)]
    masks += [rng.random((60, 70)) < rng.uniform(0.5, 0.97) for _ in range(12)]
    for mask in masks:
        height, width = mask.shape
        for _ in range(120):
            start = np.array([rng.uniform(-3, width + 3), rng.uniform(-3, height + 3)])
            angle = rng.uniform(0.0, 2.0 * np.pi)
            heading = np.array([np.cos(angle), np.sin(angle)]) * rng.uniform(0.5, 2.0)
            curvature = float(rng.choice([0.0, rng.normal(0.0, 0.05)]))
            if height == 200 and rng.random() < 0.7:
                # On the drawn cable, a pixel or two off its middle, along it either way.
                at = rng.uniform(-np.pi / 2, 2.5)
                start = CENTRE + (BEND + rng.normal(0.0, 1.5)) * np.array([np.cos(at), np.sin(at)])
                sign = float(rng.choice([-1.0, 1.0]))
                heading = sign * np.array([-np.sin(at + rng.normal(0.0, 0.1)), np.cos(at)])
                curvature = sign / BEND + float(rng.normal(0.0, 0.005))
            if rng.random() < 0.3:
                start = np.round(start * 2.0) / 2.0  # half pixels: the rounding's ties
            half_width = float(rng.choice([HALF_WIDTH, rng.uniform(1.0, 8.0)]))
            limit = float(rng.uniform(0.0, 60.0))
            first = bool(rng.random() < 0.3)
            got = middle_line(mask, start, heading, curvature, half_width, limit, first)
            want = plain_middle_line(mask, start, heading, curvature, half_width, limit, first)
            assert got[1] == want[1]
            assert got[0].shape == want[0].shape and got[2].shape == want[2].shape
            assert np.array_equal(got[0], want[0]) and np.array_equal(got[2], want[2])


def test_the_compiled_patches_beside_equal_the_numpy_reading():
    """``appearance._lab_beside`` (its 3x3 patches compiled) against the NumPy reading
    it replaced, bit for bit: points on and off the mask, at the picture's edge, off it,
    half pixels, and not finite."""
    rng = np.random.default_rng(32)
    for _ in range(60):
        height, width = rng.integers(3, 40, 2)
        mask = rng.random((height, width)) < rng.uniform(0.0, 0.9)
        image = rng.integers(0, 256, (height, width, 3), dtype=np.uint8)
        points = np.column_stack([rng.uniform(-3, width + 3, 40), rng.uniform(-3, height + 3, 40)])
        points[:10] = np.round(points[:10] * 2.0) / 2.0
        points[10, 0], points[11, 1], points[12] = np.nan, np.inf, -1e30
        for count in (1, 3, 40):
            got = _lab_beside(image, mask, points[:count])
            want = plain_lab_beside(image, mask, points[:count])
            assert got.dtype == want.dtype and np.array_equal(got, want, equal_nan=True)


def test_the_compiled_fronts_equal_the_numpy_reading():
    """``appearance._front`` and ``_first_off`` (compiled) against the NumPy readings they
    replaced, bit for bit: marches starting on and off the mask and the picture, leaving
    the picture and coming back, along bends, at half pixels, and not finite."""
    rng = np.random.default_rng(33)
    masks = [arc_mask(angle, slant) for angle in (0.3, 2.0) for slant in (-0.6, 0.7)]
    masks += [rng.random((30, 40)) < rng.uniform(0.3, 0.97) for _ in range(20)]
    for mask in masks:
        height, width = mask.shape
        for _ in range(150):
            start = np.array([rng.uniform(-3, width + 3), rng.uniform(-3, height + 3)])
            if rng.random() < 0.3:
                start = np.round(start * 2.0) / 2.0  # the rounding's ties
            angle = rng.uniform(0.0, 2.0 * np.pi)
            direction = np.array([np.cos(angle), np.sin(angle)])
            count = int(rng.integers(1, 120))
            assert_same(_front(mask, start, direction, count), front(mask, start, direction, count))
            points = start + rng.normal(0.0, 3.0, (count, 2)).cumsum(axis=0)
            if rng.random() < 0.1:
                points[rng.integers(0, count)] = rng.choice([np.nan, np.inf, -1e30])
            assert_same(_first_off(mask, points), first_off(mask, points))


def assert_same(got: float, want: float) -> None:
    assert type(got) is type(want) and (got == want or (got != got and want != want))
