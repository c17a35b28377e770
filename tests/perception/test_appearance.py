"""Chain ends' colours for merging: the compiled sampling against the plain one."""

import cv2
import numpy as np
import pytest

from service.perception import appearance
from service.perception.appearance import EndColours
from service.perception.merging import ChainEnd
from service.synthetic.families import make_family_scene
from tests.perception.references import appearance as reference


@pytest.mark.parametrize("seed", range(6))
def test_end_colours_equal_the_plain_reference(seed):
    rng = np.random.default_rng(seed)
    image = rng.integers(0, 256, (70, 110, 3), dtype=np.uint8)
    pieces = []
    for _ in range(8):
        count = int(rng.integers(1, 25))
        steps = rng.normal(0, 4, (count, 2))
        if rng.random() < 0.2:
            steps[rng.integers(0, count)] = 0.0  # a repeated joint
        pieces.append(rng.uniform(-5, 115, 2) + np.cumsum(steps, axis=0))
    ends = [
        ChainEnd(k, at_start, np.zeros(2), np.zeros(2))
        for k in range(8)
        for at_start in (True, False)
    ]
    radius = float(rng.uniform(1, 6))
    # Some samples fall where the foreground is too wide to be one cable.
    limit = appearance.WIDE_FACTOR * (radius + 0.5)
    distance = rng.uniform(0, limit, (70, 110)).astype(np.float32)
    distance[rng.random((70, 110)) < 0.01] = 2 * limit
    found = appearance.end_colours(image, pieces, ends, radius, distance)
    colour, spread = reference.end_colours(
        image,
        pieces,
        ends,
        appearance.STRETCH_SKIP_RADII * radius,
        appearance.STRETCH_RADII * radius,
        distance,
        appearance.WIDE_FACTOR * (radius + 0.5),
        appearance.MIN_SAMPLES,
    )
    np.testing.assert_allclose(found.colour, colour, rtol=1e-6, atol=1e-4)
    np.testing.assert_allclose(found.spread, spread, rtol=1e-6, atol=1e-4)
    # With its piece's own width, an end wider than the typical cable is read as the
    # reference reads it at its own limit; the others as before.
    widths = rng.uniform(0, 3 * (radius + 0.5), len(ends))
    own = appearance.end_colours(image, pieces, ends, radius, distance, widths=widths)
    for index, end in enumerate(ends):
        one_colour, one_spread = reference.end_colours(
            image,
            pieces,
            [end],
            appearance.STRETCH_SKIP_RADII * radius,
            appearance.STRETCH_RADII * radius,
            distance,
            appearance.WIDE_FACTOR * max(radius + 0.5, widths[index]),
            appearance.MIN_SAMPLES,
        )
        np.testing.assert_allclose(own.colour[index], one_colour[0], rtol=1e-6, atol=1e-4)
        np.testing.assert_allclose(own.spread[index], one_spread[0], rtol=1e-6, atol=1e-4)


def test_colour_penalty_is_zero_for_one_cable_and_grows_with_the_difference():
    image = np.full((60, 200, 3), 240, np.uint8)
    cv2.line(image, (0, 30), (90, 30), (30, 30, 190), 7)  # red
    cv2.line(image, (100, 30), (199, 30), (40, 35, 185), 7)  # a slightly different red
    cv2.line(image, (0, 10), (199, 10), (190, 60, 30), 7)  # blue
    pieces = [
        np.column_stack([np.linspace(5, 85, 9), np.full(9, 30.0)]),
        np.column_stack([np.linspace(105, 195, 9), np.full(9, 30.0)]),
        np.column_stack([np.linspace(5, 195, 9), np.full(9, 10.0)]),
    ]
    ends = [
        ChainEnd(k, at_start, np.zeros(2), np.zeros(2))
        for k in range(3)
        for at_start in (True, False)
    ]
    colours = appearance.end_colours(image, pieces, ends, 3.5)
    same, different = appearance.colour_penalty(colours, np.array([1, 1]), np.array([2, 4]))
    assert same == 0.0
    assert different == appearance.MAX_COLOUR_STEPS


def test_an_end_inside_an_object_segmented_with_the_cables_has_no_colour_of_the_object():
    """End to end, an occluder of a cable-like colour is segmented with the cable: the
    piece runs on into the object, and its colour there is not the cable's."""
    image = np.full((80, 220, 3), 60, np.uint8)
    cv2.line(image, (0, 40), (200, 40), (230, 230, 230), 7)  # a white cable
    cv2.rectangle(image, (90, 15), (150, 65), (40, 40, 200), -1)  # a red box over it
    mask = np.zeros(image.shape[:2], np.uint8)
    cv2.line(mask, (0, 40), (200, 40), 1, 7)
    cv2.rectangle(mask, (90, 15), (150, 65), 1, -1)
    distance = cv2.distanceTransform(mask, cv2.DIST_L2, 5)
    pieces = [
        np.column_stack([np.linspace(5, 120, 24), np.full(24, 40.0)]),  # into the box
        np.column_stack([np.linspace(160, 200, 9), np.full(9, 40.0)]),  # beyond it
    ]
    ends = [
        ChainEnd(k, at_start, np.zeros(2), np.zeros(2))
        for k in range(2)
        for at_start in (True, False)
    ]
    radius = 3.5
    blind = appearance.end_colours(image, pieces, ends, radius)
    seeing = appearance.end_colours(image, pieces, ends, radius, distance)
    # With the widths the samples stop at the box: the end has no colour of its own.
    # Without them the end's red is not its piece's white further in, which two
    # readings agree on: the end takes its cable's white, never the box's red.
    assert list(seeing.known) == [True, False, True, True]
    assert list(blind.known) == [True, True, True, True]
    np.testing.assert_allclose(blind.colour[1], blind.colour[0], atol=3)
    for colours in (blind, seeing):
        assert appearance.colour_penalty(colours, np.array([1]), np.array([2]))[0] == 0.0
    # The cable's own ends keep their colour: white against white.
    np.testing.assert_allclose(seeing.colour[0], seeing.colour[3], atol=3)


def gap_scene(box_colour, box=(82, 178)):
    """A dark cable along y = 50 with a 100 px gap (x 80-180), on light grey paper with
    a little noise, optionally a box of ``box_colour`` over the gap (from x ``box[0]``
    to ``box[1]``)."""
    rng = np.random.default_rng(3)
    image = np.clip(rng.normal(200, 4, (100, 260, 3)), 0, 255).astype(np.uint8)
    mask = np.zeros((100, 260), np.uint8)
    for first, last in ((10, 80), (180, 250)):
        cv2.line(mask, (first, 50), (last, 50), 1, 7)
    image[mask > 0] = (40, 40, 60)
    if box_colour is not None:
        cv2.rectangle(image, (box[0], 30), (box[1], 70), box_colour, -1)
    ends = (
        ChainEnd(0, False, np.array([78.0, 50.0]), np.array([1.0, 0.0])),
        ChainEnd(1, True, np.array([182.0, 50.0]), np.array([-1.0, 0.0])),
    )
    curve = np.column_stack([np.arange(78.0, 183.0), np.full(105, 50.0)])
    return image, mask > 0, curve, ends


def test_a_cable_over_twice_as_thick_as_the_typical_one_has_a_colour_of_its_own():
    """The picture's typical cable is thin (half width 3.7); a cable 17 px wide (half
    width 8.4) is wider than twice that everywhere, so every sample of its ends read
    as a blob's and its ends had no colour, which a turn under an object needs (loops
    400119). Judged by its own width, its ends have its colour; a wide blob on it still
    stops the reading."""
    image = np.full((80, 300, 3), 60, np.uint8)
    cv2.line(image, (0, 40), (280, 40), (200, 205, 210), 17)  # a thick light cable
    mask = np.zeros(image.shape[:2], np.uint8)
    cv2.line(mask, (0, 40), (280, 40), 1, 17)
    cv2.circle(mask, (235, 40), 30, 1, -1)  # a wide blob segmented with it
    distance = cv2.distanceTransform(mask, cv2.DIST_L2, 5)
    pieces = [np.column_stack([np.linspace(10, 260, 51), np.full(51, 40.0)])]
    ends = [ChainEnd(0, at_start, np.zeros(2), np.zeros(2)) for at_start in (True, False)]
    radius = 3.7
    typical = appearance.end_colours(image, pieces, ends, radius, distance)
    own = appearance.end_colours(image, pieces, ends, radius, distance, widths=np.full(2, 8.9))
    assert list(typical.known) == [False, False]
    assert list(own.known) == [True, False]
    lightness = cv2.cvtColor(np.array([[[200, 205, 210]]], np.uint8), cv2.COLOR_BGR2LAB)[0, 0, 0]
    assert abs(own.colour[0, 0] - float(lightness) * 100 / 255) < 2


@pytest.mark.parametrize("seed", [400119])
def test_a_thick_cables_turn_under_an_object_is_joined(seed):
    """loops 400119: a cable of half width 8.4 in a picture whose typical cable's is 3.7,
    its loop's turn hidden under a box; its ends had no colour, and the turn pass, which
    needs two ends alike, never joined it (one chain too many)."""
    from service.evaluation.synthetic_eval import evaluate_scene

    score, _ = evaluate_scene(make_family_scene("loops", seed), seed, mask_from_labels=True)
    assert score.frame.correct


def test_a_gap_under_an_object_is_hidden_and_one_over_open_paper_is_not():
    radius = 3.5
    for box, hidden in (((60, 140, 60), True), (None, False), ((200, 200, 200), False)):
        image, mask, curve, ends = gap_scene(box)
        assert appearance.gap_hidden(image, mask, curve, ends, radius) is hidden, box


def test_a_gap_with_too_few_samples_off_the_mask_tells_nothing():
    image, mask, curve, ends = gap_scene((60, 140, 60))
    mask[:] = True  # no background beside the ends, nothing of the gap off the mask
    assert appearance.gap_hidden(image, mask, curve, ends, 3.5) is False


def test_a_gap_whose_ends_lie_on_open_paper_is_not_hidden():
    """An object between two cable ends that both end on open paper (two cables' own
    ends with something lying between them) does not hide a cable: the cable would
    disappear under it right at its ends."""
    image, mask, curve, ends = gap_scene((60, 140, 60), box=(105, 155))
    assert appearance.gap_hidden(image, mask, curve, ends, 3.5) is False


def _cable_end_mask(tip: str, slant_degrees: float = 0.0, half_width: int = 6):
    """A horizontal cable of ``half_width`` from x = 10 ending near x = 80: cut square
    across its width (``tip="cut"``, the cut's line turned by ``slant_degrees``) or
    with a cable's own round tip (``"round"``)."""
    mask = np.zeros((100, 160), np.uint8)
    cv2.rectangle(
        mask, (10, 50 - half_width), (80 if tip == "round" else 100, 50 + half_width), 1, -1
    )
    if tip == "round":
        cv2.circle(mask, (80, 50), half_width, 1, -1)
    else:
        # Cut along a line through (80, 50) turned from the vertical by the slant.
        rows, cols = np.mgrid[0:100, 0:160]
        slope = np.tan(np.radians(slant_degrees))
        mask[cols > 80 + slope * (rows - 50)] = 0
    return mask > 0


@pytest.mark.parametrize(
    ("tip", "slant", "square"),
    [
        ("cut", 0.0, True),
        ("cut", 35.0, True),
        ("cut", -35.0, True),
        ("round", 0.0, False),
    ],
)
def test_a_cut_across_the_width_is_square_and_a_round_tip_is_not(tip, slant, square):
    """A cable's own tip rounds off ahead of its end (:func:`.appearance.own_tip`); an
    object's border cuts it straight across, or at a slant."""
    mask = _cable_end_mask(tip, slant)
    position, direction = np.array([78.0, 50.0]), np.array([1.0, 0.0])
    assert appearance.cut_square(mask, position, direction, 6.5) is square
    front = appearance.end_front(mask, position, direction, 6.5)
    assert appearance.own_tip(front, 6.5) is not square


def test_an_end_whose_foreground_runs_on_is_not_cut():
    mask = _cable_end_mask("cut")
    mask[30:70, 70:130] = True  # the piece runs into a blob of the foreground
    assert not appearance.cut_square(mask, np.array([60.0, 50.0]), np.array([1.0, 0.0]), 6.5)


def test_an_end_whose_foreground_runs_on_is_no_tip():
    mask = _cable_end_mask("round")
    mask[30:70, 70:130] = True  # the piece runs into a blob of the foreground
    front = appearance.end_front(mask, np.array([60.0, 50.0]), np.array([1.0, 0.0]), 6.5)
    assert not appearance.own_tip(front, 6.5)


def test_ends_alike_need_known_agreeing_colours_and_one_width():
    colours = EndColours(
        np.array([[50.0, 60.0, 40.0], [52.0, 58.0, 41.0], [50.0, -40.0, 30.0], [np.nan] * 3]),
        np.array([1.0, 1.0, 1.0, np.nan]),
    )
    assert appearance.ends_alike(colours, 0, 1, (6.0, 5.5))
    assert not appearance.ends_alike(colours, 0, 1, (6.0, 4.0))  # a thinner cable
    assert not appearance.ends_alike(colours, 0, 2, (6.0, 6.0))  # another colour
    assert not appearance.ends_alike(colours, 0, 3, (6.0, 6.0))  # colour unknown
    assert not appearance.ends_alike(colours, 0, 1, (6.0, 0.0))  # width unknown


@pytest.mark.parametrize(
    ("seed", "position", "direction", "half_width", "skip"),
    [
        (8011, [365.01, 546.08], [0.999, -0.037], 7.99, 22.48),
        (8027, [294.0, 614.0], [0.196, 0.981], 7.0, 20.4),
    ],
)
def test_a_cut_is_read_from_behind_the_tip_its_end_fit_left_out(
    seed, position, direction, half_width, skip
):
    """Ends of `occluded` tuning scenes cut by an object of the background's colour at
    a slant: the end's fit left out a hooked tip of ``skip`` px, and its position is
    extrapolated past the cut, where one side of the cable is already gone 1.5 half
    widths behind it. Read from where the fit begins, the cut is square."""
    mask = make_family_scene("occluded", seed).mask
    position, direction = np.array(position), np.array(direction)
    # Read along the fitted direction only (cut_square also reads turned directions).
    assert not appearance._straight(appearance.end_front(mask, position, direction, half_width))
    assert appearance.cut_square(mask, position, direction, half_width, skip)


@pytest.mark.parametrize("slant", [0.0, 35.0, 55.0, -55.0])
def test_reading_further_back_keeps_a_round_tip_round_and_a_cut_cut(slant):
    """Reading further back (a long skipped tip, or a cross-section narrowed by a slanted
    cut) does not make a cable's own round tip look cut."""
    mask = _cable_end_mask("round")
    for skip in (0.0, 10.0, 20.0):
        assert not appearance.cut_square(
            mask, np.array([78.0, 50.0]), np.array([1.0, 0.0]), 6.5, skip
        )
    cut = _cable_end_mask("cut", slant)
    assert appearance.cut_square(cut, np.array([78.0, 50.0]), np.array([1.0, 0.0]), 6.5, 10.0)


def _bent_end_mask(tip: str) -> np.ndarray:
    """A cable of half width 6 along y = 50 up to x = 70, then bent by 30 degrees
    (downwards) for 20 px to its end, cut square across the bent stretch or ending in
    a round tip."""
    mask = np.zeros((120, 160), np.uint8)
    bend = np.radians(30.0)
    corner = np.array([70.0, 50.0])
    tip_point = corner + 20.0 * np.array([np.cos(bend), np.sin(bend)])
    cv2.line(mask, (10, 50), (70, 50), 1, 13)
    cv2.line(mask, (70, 50), tuple(np.rint(tip_point).astype(int).tolist()), 1, 13)
    rows, cols = np.mgrid[0:120, 0:160]
    along = (cols - tip_point[0]) * np.cos(bend) + (rows - tip_point[1]) * np.sin(bend)
    mask[along > 0] = 0
    if tip == "round":
        mask[along > -6.0] = 0
        centre = tip_point - 6.0 * np.array([np.cos(bend), np.sin(bend)])
        cv2.circle(mask, tuple(np.rint(centre).astype(int).tolist()), 6, 1, -1)
    return mask > 0


@pytest.mark.parametrize(("tip", "square"), [("cut", True), ("round", False)])
def test_a_cut_just_past_a_bend_is_read_along_the_cable(tip, square):
    """The end's fitted direction still runs along the stretch before the bend (30
    degrees off the cable at the cut): read along it, the lines across the cut leave
    through the cable's side. Read along the cable's own axis, the cut is square and a
    round tip stays round."""
    mask = _bent_end_mask(tip)
    position, direction = np.array([84.0, 56.0]), np.array([1.0, 0.0])
    assert appearance.cut_square(mask, position, direction, 6.0) is square


@pytest.mark.parametrize(
    ("seed", "position", "direction", "half_width", "skip"),
    [
        (76043, [294.2, 446.7], [-0.69, -0.72], 7.8, 10.0),
        (76044, [300.5, 236.3], [-1.0, 0.01], 4.39, 10.4),
        (76004, [373.0, 470.7], [-0.26, 0.96], 4.0, 10.0),
    ],
)
def test_a_cable_entering_a_disc_at_a_shallow_angle_is_cut(
    seed, position, direction, half_width, skip
):
    """Ends of `occluded` tuning scenes where a cable (bending, or a little off its
    fitted direction) enters the rim of a disc of the background's colour at a shallow
    angle: the line on the cut's far side, which runs furthest, leaves through the
    cable's side before it reaches the rim, and the middle seemed to bulge as a round
    tip's does. The cut is that far from square across the cable, and is read as cut."""
    mask = make_family_scene("occluded", seed).mask
    direction = np.array(direction) / np.hypot(*direction)
    assert appearance.cut_square(mask, np.array(position), direction, half_width, skip)


@pytest.mark.parametrize("tilt", [-15.0, -8.0, 0.0, 8.0, 15.0])
def test_a_round_tip_read_off_its_axis_stays_round(tilt):
    """The bulge allowed grows with how far one side's front reaches past the other's;
    a cable's own round tip read along a direction up to 15 degrees off its axis is
    nearly symmetric, and still not cut."""
    mask = _cable_end_mask("round")
    angle = np.radians(tilt)
    direction = np.array([np.cos(angle), np.sin(angle)])
    for skip in (0.0, 10.0):
        assert not appearance.cut_square(mask, np.array([78.0, 50.0]), direction, 6.5, skip)


def test_a_short_piece_between_two_objects_keeps_its_colour_when_its_tips_are_free():
    """A stretch of cable seen between two objects thins to a piece shorter than three
    radii: a scrap has no colour, but one whose tips lie in no junction (``free``) is
    the cable's, all along."""
    image = np.full((60, 120, 3), 60, np.uint8)
    cv2.line(image, (50, 30), (62, 30), (40, 200, 40), 9)  # a green stretch of cable
    pieces = [np.column_stack([np.linspace(52, 60, 3), np.full(3, 30.0)])]
    ends = [ChainEnd(0, at_start, np.zeros(2), np.zeros(2)) for at_start in (True, False)]
    radius = 4.0
    scrap = appearance.end_colours(image, pieces, ends, radius)
    free = appearance.end_colours(image, pieces, ends, radius, free=np.array([True]))
    assert not scrap.known.any()
    assert free.known.all()
    green = cv2.cvtColor(np.array([[[40, 200, 40]]], np.float32) / 255.0, cv2.COLOR_BGR2LAB)
    np.testing.assert_allclose(free.colour, np.repeat(green.reshape(1, 3), 2, axis=0), atol=1)


def test_a_curve_out_of_view_all_the_way_lies_under_the_object_at_every_sample():
    """The gap's straight line lies under the box all along; a curve swinging 24 px up
    from it leaves the box (y 30-70) for open paper round its middle, where a cable
    would be seen, though most of it, and of its edges, is still under the box
    (gap_hidden's test). Over open paper nothing is out of view."""
    image, mask, curve, ends = gap_scene((60, 140, 60))
    assert appearance.out_of_view(image, mask, curve, ends, 3.5)
    swing = curve.copy()
    swing[:, 1] -= 24.0 * np.sin(np.pi * (swing[:, 0] - 78.0) / 104.0)
    assert appearance.gap_hidden(image, mask, swing, ends, 3.5)
    assert not appearance.out_of_view(image, mask, swing, ends, 3.5)
    open_image, open_mask, _, _ = gap_scene(None)
    assert not appearance.out_of_view(open_image, open_mask, curve, ends, 3.5)


def test_a_curve_whose_middle_keeps_under_the_object_but_whose_tube_reaches_past_it_shows():
    """A cable is a tube: a curve swinging 20 px up from the gap's line has its middle
    on the box's top row (y 30) and out of view, but a cable 3 px to either side of it
    would reach up onto open paper, and be seen there; swinging 10 px, the whole tube
    keeps under the box."""
    image, mask, curve, ends = gap_scene((60, 140, 60))
    for height, tube_hidden in ((10.0, True), (20.0, False)):
        swing = curve.copy()
        swing[:, 1] -= height * np.sin(np.pi * (swing[:, 0] - 78.0) / 104.0)
        assert appearance.out_of_view(image, mask, swing, ends, 3.5)
        assert appearance.out_of_view(image, mask, swing, ends, 3.5, half_width=3.0) == tube_hidden


@pytest.mark.parametrize(
    ("seed", "position", "direction", "half_width", "skip"),
    [
        (280104, [583.1, 507.5], [0.988, 0.154], 8.0, 20.4),
        (280146, [245.0, 220.0], [-0.904, -0.428], 5.0, 10.3),
    ],
)
def test_a_steep_cut_read_into_its_sharp_corner_is_cut(seed, position, direction, half_width, skip):
    """Ends of `occluded` tuning scenes where an object of the background's colour cuts
    the cable at a steep slant: the end's fitted direction points into the sharp corner,
    and read along it the wedge bulges as a round tip does. Read along a direction
    turned by up to 20 degrees, the cut is straight."""
    mask = make_family_scene("occluded", seed).mask
    position, direction = np.array(position), np.array(direction) / np.hypot(*direction)
    front = appearance.end_front(mask, position, direction, half_width, skip)
    assert not appearance._straight(front)
    assert appearance.cut_square(mask, position, direction, half_width, skip)


@pytest.mark.parametrize("tilt", [-25.0, -20.0, 20.0, 25.0])
@pytest.mark.parametrize("half_width", [4, 6, 8])
def test_a_round_tip_read_well_off_its_axis_is_not_cut(tilt, half_width):
    """Read again along turned directions (:data:`.appearance.CUT_READ_TURNS`), a cable's
    own round tip still bulges along every one: it is not cut."""
    mask = _cable_end_mask("round", half_width=half_width)
    angle = np.radians(tilt)
    direction = np.array([np.cos(angle), np.sin(angle)])
    for skip in (0.0, 10.0):
        assert not appearance.cut_square(
            mask, np.array([78.0, 50.0]), direction, half_width + 0.5, skip
        )


@pytest.mark.parametrize(
    ("seed", "position", "direction", "half_width", "skip"),
    [
        (290020, [794.8033, 248.4157], [-0.47668, 0.87908], 7.9907, 21.0147),
        (290099, [569.3788, 422.2561], [-0.74576, 0.66621], 5.3938, 4.8938),
    ],
)
def test_a_cut_across_a_bent_cable_is_read_along_its_bend(
    seed, position, direction, half_width, skip
):
    """Ends of `loops` tuning scenes where an object of the background's colour cuts the
    cable where it bends (4 to 6 radii): along straight lines the outer line leaves
    through the cable's side, and the front reads as bulging (290020) or as a cable's
    own round tip (290099). Read along the bend the cable's centre shows behind it, it
    is flat: cut, no own tip."""
    mask = make_family_scene("loops", seed).mask
    position, direction = np.array(position), np.array(direction)
    front, bent = appearance.end_fronts(mask, position, direction, half_width, skip)
    assert not appearance._straight(front)
    assert appearance._flat(bent)
    assert appearance.cut_square(mask, position, direction, half_width, skip)
    assert not appearance.own_tip_both_ways((front, bent), half_width)


@pytest.mark.parametrize(
    ("seed", "position", "direction", "half_width", "skip"),
    [
        (290088, [707.0, 395.0], [-0.486, 0.874], 5.79, 5.29),
        (290129, [726.15, 20.46], [-0.953, -0.302], 7.0, 6.5),
    ],
)
def test_a_cables_own_tip_on_a_bend_stays_a_tip(seed, position, direction, half_width, skip):
    """Cables' own tips in `loops` tuning scenes whose centre bends behind them (radii of
    43 and 54 px read): read along that bend they are a little lopsided in their pixel
    steps, but neither flat nor lopsided past a cut's share, so they stay own tips."""
    mask = make_family_scene("loops", seed).mask
    position, direction = np.array(position), np.array(direction)
    fronts = appearance.end_fronts(mask, position, direction, half_width, skip)
    assert fronts[1] is not None
    assert appearance.own_tip_both_ways(fronts, half_width)
    assert not appearance.cut_square(mask, position, direction, half_width, skip)


def test_only_the_open_stretch_of_a_gap_counts_as_what_the_ground_must_hide():
    """Of a gap's curve, what an object of the background's own colour would have to
    hide is the stretch off the mask that looks like the open background: not the
    pieces' own tips the curve starts on, nor the part under an object seen over it."""
    from service.perception.gap_evidence import open_length

    image, mask, curve, ends = gap_scene((60, 140, 60), box=(130, 178))
    # 91 px off the mask (the pieces' round caps reach x 83 and 177); the box shows
    # over x 130-178.
    assert open_length(curve, mask, None, ends, 3.5) == 91.0
    assert 40.0 <= open_length(curve, mask, image, ends, 3.5) <= 48.0
    open_image, _, _, _ = gap_scene(None)
    assert open_length(curve, mask, open_image, ends, 3.5) == 91.0
    # The curve started 20 px back on the first piece: no more open.
    longer = np.vstack([np.column_stack([np.arange(58.0, 78.0), np.full(20, 50.0)]), curve])
    assert open_length(longer, mask, None, ends, 3.5) == 91.0


def stripped_tip_scene(body_end=110, object_from=None):
    """White paper with a light-blue cable along y = 40 from x 10 to ``body_end``, its
    copper tip 25 px on, and a black cable from x 175 to 250; optionally a dark-blue
    object over the light-blue cable from x ``object_from`` to the tip. Returns the
    image, the two pieces and their four ends."""
    image = np.full((80, 260, 3), 235, np.uint8)  # white paper
    cv2.line(image, (10, 40), (body_end, 40), (200, 160, 110), 7)  # light blue (BGR)
    if object_from is not None:
        cv2.line(image, (object_from, 40), (body_end, 40), (110, 40, 20), 7)  # dark blue
    tip = body_end + 25
    cv2.line(image, (body_end, 40), (tip, 40), (60, 120, 200), 5)  # copper
    cv2.line(image, (175, 40), (250, 40), (30, 30, 30), 7)  # a black cable
    pieces = [
        np.column_stack([np.linspace(12, tip - 1, 25), np.full(25, 40.0)]),
        np.column_stack([np.linspace(176, 248, 15), np.full(15, 40.0)]),
    ]
    ends = [
        ChainEnd(k, at_start, np.zeros(2), np.zeros(2))
        for k in range(2)
        for at_start in (True, False)
    ]
    return image, pieces, ends


def test_a_stripped_tip_takes_its_cable_s_colour_where_two_readings_agree():
    """A light-blue cable whose last few millimetres are stripped to copper (ariadne
    simple 00006 end to end) reads copper at its end. Its body, read twice further in,
    is light blue both times: the end takes the light blue, so a black cable's end
    across the paper is clearly another cable's, not a free match."""
    image, pieces, ends = stripped_tip_scene()
    colours = appearance.end_colours(image, pieces, ends, 3.5)
    assert colours.known[1]
    np.testing.assert_allclose(colours.colour[1], colours.colour[0], atol=3)
    assert appearance.colour_penalty(colours, np.array([1]), np.array([2]))[0] > 0


def test_a_body_the_two_readings_disagree_on_is_not_trusted():
    """The piece's body runs onto a dark-blue object segmented with the cable (edge
    330015 end to end): the first reading further in is the object's, the second the
    cable's. The body's colour is not the cable's, and the end stays unknown."""
    image, pieces, ends = stripped_tip_scene(object_from=85)
    colours = appearance.end_colours(image, pieces, ends, 3.5)
    assert not colours.known[1]
    assert appearance.colour_penalty(colours, np.array([1]), np.array([2]))[0] == 0.0


def test_a_piece_too_short_to_read_twice_leaves_a_changed_end_unknown():
    """Too short for a second reading further in (its stretch would run to the piece's
    other end): the body is not trusted."""
    image, pieces, ends = stripped_tip_scene(body_end=70)
    colours = appearance.end_colours(image, pieces, ends, 3.5)
    assert colours.known[0]
    assert not colours.known[1]


def test_the_turn_tests_read_once_per_pair_and_answer_as_read_per_curve():
    """The turn pass's tests (:func:`.gap_evidence.turn_evidence`) read the background
    beside a pair and each end's cut once, not once per curve: their answers are those
    of :func:`.appearance.gap_hidden` and :func:`.gap_evidence.cut_ends_alike` called
    afresh on each curve, for a gap under an object, over open paper between round tips
    and between square cuts, and on a curve bowed off the gap's line."""
    from service.perception.gap_evidence import TURN_CUT_ENDS, cut_ends_alike, turn_evidence

    radius = 3.5
    colours = EndColours(np.zeros((2, 3)), np.ones(2, bool))
    for box, square in (((60, 140, 60), False), (None, False), (None, True)):
        image, mask, curve, ends = gap_scene(box)
        if square:  # the pieces cut straight across: the cut tests pass
            mask[:] = False
            mask[47:54, 10:81] = mask[47:54, 180:251] = True
        ends = tuple(
            ChainEnd(end.piece, end.at_start, end.position, end.direction, width=3.5)
            for end in ends
        )
        bowed = curve + np.column_stack(
            [np.zeros(len(curve)), 8 * np.sin(np.linspace(0, np.pi, len(curve)))]
        )
        hidden, both_cut, one_cut, _ = turn_evidence(image, mask, list(ends), colours, radius)
        for path in (curve, bowed, curve):
            assert hidden(0, 1, path) == appearance.gap_hidden(image, mask, path, ends, radius)
            for test, needed in ((both_cut, 2), (one_cut, TURN_CUT_ENDS)):
                fresh = cut_ends_alike(*ends, 0, 1, path, mask, colours, radius, needed, image)
                assert test(0, 1, path) == fresh


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_first_wide_samples_of_all_ends_at_once_equal_the_end_by_end_reference(dtype):
    # Every end's samples read in one pass must mark what the per-end loop marked,
    # bit for bit: limits a hair either side of the samples' float32 values, ends with
    # no samples, none past, all past.
    rng = np.random.default_rng(7)
    for _ in range(3000):
        counts = rng.integers(0, 12, int(rng.integers(0, 8)))
        bounds = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        at = (rng.integers(0, 40, bounds[-1]) / 4.0).astype(dtype)
        at += rng.choice([0.0, 1e-8, -1e-8], bounds[-1]).astype(dtype)
        limits = rng.integers(0, 40, len(counts)) / 4.0 + rng.choice(
            [0.0, 1e-8, -1e-8, 0.1], len(counts)
        )
        np.testing.assert_array_equal(
            appearance._first_wide_less_margin(at, bounds, limits),
            reference.first_wide_less_margin(at, bounds, limits),
        )
