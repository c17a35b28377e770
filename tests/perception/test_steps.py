"""Each pipeline step on its own, on hand-made shapes with known answers."""

import cv2
import numpy as np
import pytest

from schemas import Chain, Crossing, Detection, DetectParams, SegmentationMethod
from service.perception import InvalidInputError, render_labels
from service.perception.contours import extract_contours
from service.perception.fitting import fit_chains, junction_zones, split_contour, walk_joints
from service.perception.geometry import end_direction, polyline_length, resample
from service.perception.merging import ChainEnd, join_cost, merge_chains, natural_curve
from service.perception.pruning import prune_overlaps
from service.perception.segmentation import as_bgr, clean_mask, segment, validate_mask
from service.perception.skeleton import branch_counts, estimate_radius, skeletonize_mask


def thick_polyline(shape, points, thickness):
    mask = np.zeros(shape, np.uint8)
    cv2.polylines(mask, [np.array(points, np.int32)], False, 1, thickness)
    return mask > 0


# --- segmentation -------------------------------------------------------------------


def test_auto_segmentation_finds_a_bright_cable_on_a_dark_background():
    image = np.full((100, 160, 3), 30, np.uint8)
    cv2.line(image, (10, 50), (150, 50), (200, 200, 200), 7)
    mask = segment(image, DetectParams())
    truth = np.zeros((100, 160), np.uint8)
    cv2.line(truth, (10, 50), (150, 50), 1, 7)
    dice = 2 * (mask & (truth > 0)).sum() / (mask.sum() + truth.sum())
    assert dice > 0.95


def test_auto_segmentation_uses_colour_when_brightness_does_not_separate():
    # A red cable on a light grey table: as bright as the table, but colourful.
    image = np.full((100, 160, 3), 200, np.uint8)
    cv2.line(image, (10, 50), (150, 50), (40, 40, 210), 9)
    mask = segment(image, DetectParams())
    assert mask[50, 80] and not mask[20, 80]
    assert 0.8 < mask.sum() / (141 * 9) < 1.3


def test_hsv_segmentation_selects_only_the_given_hue():
    image = np.zeros((60, 100, 3), np.uint8)
    cv2.line(image, (5, 20), (95, 20), (0, 0, 255), 5)  # red
    cv2.line(image, (5, 40), (95, 40), (255, 0, 0), 5)  # blue
    params = DetectParams(
        segmentation=SegmentationMethod.hsv, hsv_low=(100, 100, 100), hsv_high=(130, 255, 255)
    )
    mask = segment(image, params)
    assert mask[40, 50] and not mask[20, 50]


def test_clean_mask_removes_specks_and_fills_small_holes():
    mask = np.zeros((60, 60), bool)
    mask[10:40, 10:40] = True
    mask[20:22, 20:22] = False  # small hole
    mask[50:52, 50:52] = True  # speck
    cleaned = clean_mask(mask, min_component_area=20, max_hole_area=10)
    assert cleaned[20:22, 20:22].all()
    assert not cleaned[50:52, 50:52].any()
    assert cleaned[10:40, 10:40].all()


def test_input_validation_gives_clear_errors():
    with pytest.raises(InvalidInputError, match="uint8"):
        as_bgr(np.zeros((20, 20), np.float32))
    with pytest.raises(InvalidInputError, match="too small"):
        as_bgr(np.zeros((2, 2, 3), np.uint8))
    with pytest.raises(InvalidInputError, match="mask is 30x20 px but the image is 40x20 px"):
        validate_mask(np.ones((20, 30), bool), (20, 40))
    with pytest.raises(InvalidInputError, match="empty"):
        validate_mask(np.zeros((20, 40), bool), (20, 40))
    assert as_bgr(np.zeros((20, 20), np.uint8)).shape == (20, 20, 3)
    assert as_bgr(np.zeros((20, 20, 4), np.uint8)).shape == (20, 20, 3)


# --- skeleton -------------------------------------------------------------------------


def test_skeleton_of_a_band_is_one_connected_branch_on_its_centreline():
    mask = thick_polyline((80, 200), [(20, 40), (180, 40)], 11)
    skeleton = skeletonize_mask(mask, spur_length=12)
    counts = branch_counts(skeleton)
    assert (counts == 1).sum() == 2  # two tips
    assert (counts >= 3).sum() == 0  # no junction
    assert np.abs(np.argwhere(skeleton)[:, 0] - 40).max() <= 1
    assert cv2.connectedComponents(skeleton.astype(np.uint8))[0] == 2  # background + 1
    assert estimate_radius(mask, skeleton) == pytest.approx(5.5, abs=1.0)


def test_skeleton_of_a_crossing_has_a_junction_and_four_tips():
    mask = thick_polyline((200, 200), [(20, 20), (180, 180)], 9)
    mask |= thick_polyline((200, 200), [(20, 180), (180, 20)], 9)
    skeleton = skeletonize_mask(mask, spur_length=12)
    counts = branch_counts(skeleton)
    assert (counts == 1).sum() == 4
    assert (counts >= 3).any()


def test_spurs_from_a_ragged_border_are_removed():
    mask = thick_polyline((80, 200), [(20, 40), (180, 40)], 11)
    mask[30:35, 100:103] = True  # a bump on the border grows a spur
    raw = skeletonize_mask(mask, spur_length=0)
    pruned = skeletonize_mask(mask, spur_length=15)
    assert (branch_counts(raw) == 1).sum() >= 2
    assert (branch_counts(pruned) == 1).sum() == 2
    assert (branch_counts(pruned) >= 3).sum() == 0


# --- contours and fitting -------------------------------------------------------------


def test_contours_of_a_skeleton_line_walk_out_and_back():
    skeleton = np.zeros((20, 60), bool)
    skeleton[10, 5:55] = True
    contours = extract_contours(skeleton)
    assert len(contours) == 1
    xs = contours[0][:, 0]
    assert xs.min() == 5 and xs.max() == 54
    assert len(contours[0]) == 2 * 50 - 2  # each pixel twice, the tips once


def test_walk_joints_spaces_joints_by_the_segment_length():
    pixels = np.stack([np.arange(0, 101), np.zeros(101)], axis=1)
    joints = walk_joints(pixels, 10)
    assert np.allclose(np.diff(joints[:, 0]), 10)
    assert joints[0, 0] == 0 and joints[-1, 0] == 100


def test_split_contour_cuts_at_tips_and_skips_junction_zones():
    contour = np.stack([np.arange(10), np.zeros(10, int)], axis=1)
    tips = np.zeros(10, bool)
    tips[[0, 9]] = True
    zones = np.zeros(10, bool)
    zones[4:6] = True
    runs = split_contour(contour, tips, zones)
    assert sorted(len(r) for r in runs) == [4, 4]


def test_fitting_and_pruning_give_one_chain_per_branch():
    mask = thick_polyline((80, 200), [(20, 40), (180, 40)], 9)
    skeleton = skeletonize_mask(mask, spur_length=12)
    zones = junction_zones(skeleton, 4.5)
    pieces = fit_chains(extract_contours(skeleton), skeleton, zones, 10)
    assert len(pieces) == 2  # the contour walks the branch twice
    kept = prune_overlaps(pieces, mask.shape)
    assert len(kept) == 1
    assert polyline_length(kept[0]) == pytest.approx(polyline_length(pieces[0]), rel=0.05)


def test_junction_zones_cover_a_crossing_but_not_the_arms():
    mask = thick_polyline((200, 200), [(20, 20), (180, 180)], 9)
    mask |= thick_polyline((200, 200), [(20, 180), (180, 20)], 9)
    skeleton = skeletonize_mask(mask, spur_length=12)
    zones = junction_zones(skeleton, 4.5)
    assert zones[100, 100]
    assert not zones[40, 40] and not zones[160, 40]


# --- geometry and merging -------------------------------------------------------------


def test_resample_gives_exact_chord_lengths():
    t = np.linspace(0, np.pi, 400)
    arc = np.stack([100 + 50 * np.cos(t), 100 + 50 * np.sin(t)], axis=1)
    joints, _ = resample(arc, 10.0)
    steps = np.linalg.norm(np.diff(joints, axis=0), axis=1)
    assert np.allclose(steps[:-1], 10.0, atol=1e-9)
    assert steps[-1] <= 10.0 + 1e-9
    assert np.allclose(joints[-1], arc[-1])


def test_end_direction_points_outwards():
    line = np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0]])
    assert np.allclose(end_direction(line, at_start=False, span=15), [1, 0])
    assert np.allclose(end_direction(line, at_start=True, span=15), [-1, 0])


def test_natural_curve_is_straight_for_aligned_ends():
    curve = natural_curve(
        np.array([0.0, 0]), np.array([1.0, 0]), np.array([50.0, 0]), np.array([1.0, 0])
    )
    assert np.allclose(curve[:, 1], 0)
    assert np.allclose(curve[0], [0, 0]) and np.allclose(curve[-1], [50, 0])


def test_natural_curve_follows_the_ends_then_turns_at_a_constant_rate():
    # Leaving east from the origin, arriving heading north at (30, 40): the rays meet
    # at (30, 0); the gentlest arc is tangent 30 px before that corner.
    start, end = np.array([0.0, 0.0]), np.array([30.0, 40.0])
    curve = natural_curve(start, np.array([1.0, 0.0]), end, np.array([0.0, 1.0]), step=0.5)
    assert np.allclose(curve[0], start) and np.allclose(curve[-1], end)
    headings = np.diff(curve, axis=0)
    assert np.allclose(headings[0] / np.linalg.norm(headings[0]), [1, 0], atol=0.01)
    assert np.allclose(headings[-1] / np.linalg.norm(headings[-1]), [0, 1], atol=0.01)
    # The arc part (centre (0, 30), radius 30) then a straight stretch north.
    on_arc = curve[(curve[:, 1] < 30) & (curve[:, 1] > 0.5)]
    radii = np.hypot(on_arc[:, 0] - 0.0, on_arc[:, 1] - 30.0)
    assert np.allclose(radii, 30.0, atol=0.05)


def test_join_cost_prefers_straight_continuation_over_a_turn():
    params = DetectParams()
    a = ChainEnd(0, False, np.array([100.0, 100.0]), np.array([1.0, 0.0]))
    straight = ChainEnd(1, True, np.array([130.0, 100.0]), np.array([-1.0, 0.0]))
    turned = ChainEnd(2, True, np.array([115.0, 115.0]), np.array([0.0, -1.0]))
    backwards = ChainEnd(3, True, np.array([70.0, 100.0]), np.array([1.0, 0.0]))
    assert join_cost(a, straight, params, 4) < join_cost(a, turned, params, 4)
    assert join_cost(a, turned, params, 4) < join_cost(a, backwards, params, 4)
    assert join_cost(a, straight, params, 4) < params.merge_cost_threshold


def test_merging_bridges_a_gap_and_marks_it_filled():
    left = np.stack([np.arange(0, 101, 10.0), np.full(11, 50.0)], axis=1)
    right = np.stack([np.arange(160, 261, 10.0), np.full(11, 50.0)], axis=1)
    result = merge_chains([left, right], DetectParams(), radius=4)
    assert len(result.paths) == 1 and len(result.joins) == 1
    path = result.paths[0]
    assert path.filled.any() and not path.filled.all()
    gap_edges = path.vertices[:-1][path.filled]
    assert gap_edges[:, 0].min() >= 100 - 1e-9 and gap_edges[:, 0].max() < 160


def test_merging_stops_at_the_expected_count():
    pieces = [
        np.stack([np.arange(0, 101, 10.0) + 200 * k, np.full(11, 50.0)], axis=1) for k in range(3)
    ]
    assert len(merge_chains(pieces, DetectParams(), 4).paths) == 1
    assert len(merge_chains(pieces, DetectParams(expected_count=2), 4).paths) == 2
    # Far apart and implausible: with no expected count they stay apart ...
    far = [pieces[0], pieces[0] + [0, 400]]
    assert len(merge_chains(far, DetectParams(), 4).paths) == 2
    # ... and an expected count of one forces the join.
    assert len(merge_chains(far, DetectParams(expected_count=1), 4).paths) == 1


def _crossing_bars():
    """A red horizontal bar (half width 5) over a green vertical one, as image and mask."""
    image = np.zeros((80, 80, 3), np.uint8)
    image[:, 35:46] = (40, 190, 40)  # green, underneath
    image[35:46, :] = (40, 40, 200)  # red, on top
    mask = image.any(axis=2)
    detection = Detection(
        width=80,
        height=80,
        segment_length=10,
        chains=[
            # Radii a pixel short of the bars' half width, as a median often is.
            Chain(
                id=0,
                points=[(x, 40.0) for x in range(0, 80, 10)] + [(79.0, 40.0)],
                radius=4.0,
                inferred=[False] * 8,
            ),
            Chain(
                id=1,
                points=[(40.0, y) for y in range(0, 80, 10)] + [(40.0, 79.0)],
                radius=4.0,
                inferred=[False] * 8,
            ),
        ],
        crossings=[
            Crossing(x=40, y=40, over=0, under=1, over_segment=4, under_segment=4, confidence=1.0)
        ],
    )
    return image, mask, detection


def test_labels_near_a_crossing_follow_the_cables_colours():
    image, mask, detection = _crossing_bars()
    geometric = render_labels(detection, mask)
    by_colour = render_labels(detection, mask, image)
    red = (image[:, :, 2] == 200) & mask
    green = (image[:, :, 1] == 190) & mask
    # The red bar's rim above the green bar goes to the green strand by geometry alone...
    assert (geometric[red] == 2).any()
    # ...and to the red strand by colour; no pixel changes away from the crossing.
    assert (by_colour[red] == 1).all()
    assert (by_colour[green] == 2).all()
    far = np.ones_like(mask)
    cv2.circle(far.view(np.uint8), (40, 40), 14, 0, -1)
    np.testing.assert_array_equal(by_colour[far], geometric[far])


def test_labels_keep_the_geometry_for_cables_of_one_colour_or_a_grey_image():
    image, mask, detection = _crossing_bars()
    grey = cv2.cvtColor(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY), cv2.COLOR_GRAY2BGR)
    np.testing.assert_array_equal(
        render_labels(detection, mask, grey), render_labels(detection, mask)
    )
    np.testing.assert_array_equal(
        render_labels(detection, mask, image[:, :, 0]), render_labels(detection, mask)
    )


def test_end_directions_leave_out_a_cut_end_where_the_cable_narrows():
    from service.perception.merging import chain_ends

    # A straight cable along y = 50 whose last joints bend toward a slanted cut's corner.
    piece = np.array([[x, 50.0] for x in range(0, 100, 10)] + [[100.0, 53.0], [108.0, 58.0]])
    mask = np.zeros((100, 140), np.uint8)
    cv2.line(mask, (0, 50), (96, 50), 1, 13)  # half width 6, ends before the hook
    distance = cv2.distanceTransform(mask, cv2.DIST_L2, 5)
    radius = 6.0
    plain = chain_ends([piece], span=40.0, skip=radius)[1]
    adaptive = chain_ends(
        [piece], span=40.0, skip=radius, distance=distance, full_width=0.8 * (radius + 0.5)
    )[1]
    # The hook tilts the plain fit; leaving out the narrow joints keeps the cable's axis.
    assert abs(plain.direction[1]) > 0.1
    assert abs(adaptive.direction[1]) < 0.02 and adaptive.direction[0] > 0.99


def test_smooth_curve_follows_an_arc_between_symmetric_ends_and_is_straight_when_aligned():
    radius = 80.0
    angles = (0.3, 1.4)
    start, end = (np.array([radius * np.cos(a), radius * np.sin(a)]) for a in angles)
    leaving, arriving = (np.array([-np.sin(a), np.cos(a)]) for a in angles)
    curve = natural_curve(start, leaving, end, arriving, step=0.5, shape="smooth")
    # The cubic stays within a small fraction of a pixel of the circle it approximates.
    assert np.abs(np.hypot(curve[:, 0], curve[:, 1]) - radius).max() < 0.05
    np.testing.assert_allclose(curve[[0, -1]], [start, end])
    straight = natural_curve(
        np.array([0.0, 0.0]),
        np.array([1.0, 0.0]),
        np.array([30.0, 0.0]),
        np.array([1.0, 0.0]),
        shape="smooth",
    )
    assert np.abs(straight[:, 1]).max() < 1e-9


def _dim_and_bright_cables():
    """Two horizontal cables on black: a bright one, and a dim one with shaded rims."""
    cue = np.zeros((80, 120), np.uint8)
    cue[16:25, :] = 200  # bright cable, hard edges
    cue[52:65, :] = 60  # dim cable's shaded rims, two pixels each side ...
    cue[54:63, :] = 120  # ... round its lit core
    lines = [np.array([[0.0, 20.0], [119.0, 20.0]]), np.array([[0.0, 58.0], [119.0, 58.0]])]
    return cue, lines


def test_own_thresholds_give_a_dim_cable_its_shaded_rims():
    from service.perception.segmentation import grow_by_own_thresholds

    cue, lines = _dim_and_bright_cables()
    # A threshold for the whole image sits between the background and both cables.
    mask = cue >= 100
    grown = grow_by_own_thresholds(cue, mask, lines, [4.5, 4.5], image_low=90.0)
    assert np.array_equal(grown[:40], mask[:40])  # the bright cable keeps its mask
    assert grown[52:65, 5:115].all()  # the dim cable gains its rims ...
    assert not grown[66:, :].any() and not grown[40:51, :].any()  # ... and no background
    assert (grown >= mask).all()  # only ever adds
    # A cable whose own weak threshold is not below the image's gains nothing.
    assert np.array_equal(
        grow_by_own_thresholds(cue, mask, lines, [4.5, 4.5], image_low=10.0), mask
    )


def test_own_thresholds_leave_out_hidden_segments_and_crossings():
    from service.perception.segmentation import grow_by_own_thresholds

    cue, _ = _dim_and_bright_cables()
    mask = cue >= 100
    dim = [np.array([[0.0, 58.0], [60.0, 58.0], [119.0, 58.0]])]
    # With its only seen half next to a crossing, the cable is not judged at all ...
    hidden = [np.array([True, False])]
    crossing = [(90.0, 58.0, 0, 0)]
    same = grow_by_own_thresholds(cue, mask, dim, [4.5], hidden, crossing, image_low=90.0)
    assert np.array_equal(same, mask)
    # ... while with the seen half in the open, only that half grows.
    grown = grow_by_own_thresholds(cue, mask, dim, [4.5], hidden, image_low=90.0)
    assert grown[52:65, 62:118].all() and np.array_equal(grown[:, :58], mask[:, :58])


def test_a_callers_mask_is_not_grown():
    from service.perception import detect_full

    image = np.zeros((80, 120, 3), np.uint8)
    image[16:25, :] = 200
    image[52:65, :] = 60
    image[54:63, :] = 120
    mask = image[:, :, 0] >= 100
    assert np.array_equal(detect_full(image, mask=mask).mask, mask)
    # From the image alone, the dim cable's rims are part of the mask.
    assert detect_full(image).mask[52:65, 10:110].all()


@pytest.mark.parametrize("angle", [0.0, 17.0, 30.0, 45.0, 60.0, 90.0, 135.0])
def test_own_thresholds_grow_whole_rims_at_any_angle(angle):
    from service.perception.segmentation import grow_by_own_thresholds

    cue = np.zeros((160, 160), np.uint8)
    direction = np.array([np.cos(np.radians(angle)), np.sin(np.radians(angle))])
    ends = np.rint([[80.0, 80.0] - 70 * direction, [80.0, 80.0] + 70 * direction])
    line = [ends.astype(np.int32).reshape(-1, 1, 2)]
    cv2.polylines(cue, line, False, 60, 13)  # shaded rims ...
    cv2.polylines(cue, line, False, 120, 9)  # ... round a lit core
    mask = cue >= 100
    grown = grow_by_own_thresholds(cue, mask, [ends], [4.5], image_low=90.0)
    # Away from the ends, every rim pixel joins and nothing else does.
    x, y = np.meshgrid(np.arange(160), np.arange(160))
    along = np.abs((x - 80) * direction[0] + (y - 80) * direction[1])
    middle = along < 55
    assert np.array_equal(grown[middle], (cue > 0)[middle])


def test_an_hsv_mask_is_not_grown():
    from service.perception import detect_full

    image = np.zeros((80, 120, 3), np.uint8)
    image[16:25, :] = (0, 0, 200)  # a red cable
    image[52:65, :] = (0, 0, 60)  # a dim red one with shaded rims
    image[54:63, :] = (0, 0, 120)
    params = DetectParams(
        segmentation=SegmentationMethod.hsv, hsv_low=(0, 100, 100), hsv_high=(10, 255, 255)
    )
    assert np.array_equal(detect_full(image, params).mask, segment(image, params))


def test_a_short_piece_joined_on_both_sides_is_bridged_along_its_partners_line():
    from service.perception.merging import (
        assemble_paths,
        chain_ends,
        ends_through_short_pieces,
    )

    # A straight cable along y = 50 seen in three pieces: the middle one, between two
    # occluders, is short and its thinned line is tilted (cut at a slant at both ends).
    pieces = [
        np.array([[0.0, 50.0], [10.0, 50.0], [20.0, 50.0], [30.0, 50.0], [40.0, 50.0]]),
        np.array([[60.0, 48.0], [66.0, 52.0]]),
        np.array([[90.0, 50.0], [100.0, 50.0], [110.0, 50.0], [120.0, 50.0], [130.0, 50.0]]),
    ]
    ends = chain_ends(pieces, 40.0)
    joins = [(1, 2, 0.1), (3, 4, 0.1)]  # end of piece 0 to piece 1, piece 1 to piece 2
    adjusted = ends_through_short_pieces(pieces, ends, joins, 40.0)
    np.testing.assert_allclose(adjusted[2].direction, [-1.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(adjusted[3].direction, [1.0, 0.0], atol=1e-9)
    assert adjusted[0] is ends[0] and adjusted[5] is ends[5]  # long pieces keep theirs

    def worst_offset(which):
        (path,) = assemble_paths(pieces, which, joins, "smooth")
        return float(np.abs(path.vertices[:, 1] - 50.0).max())

    # The piece's own tilted directions throw the bridges well off the line.
    assert worst_offset(adjusted) <= 2.5 < worst_offset(ends)


def test_a_chain_far_short_of_a_thin_cables_end_is_taken_to_it():
    from service.perception.merging import MergedPath
    from service.perception.pipeline import _finalise_path
    from service.perception.skeleton import distance_transform

    # A thin cable (radius 3) from x = 0 to x = 99 whose chain stops at x = 70, ten
    # radii short: one extension reaches only a few radii, so the end is pushed on from
    # where it stops.
    mask = np.zeros((40, 140), bool)
    mask[17:24, 0:100] = True
    path = MergedPath(np.array([[5.0, 20.0], [70.0, 20.0]]), np.array([False]))
    joints, inferred, _ = _finalise_path(
        path, mask, distance_transform(mask), DetectParams(), radius=3.0
    )
    assert 94.0 <= joints[-1][0] <= 97.5  # one radius inside the cable's end
    assert abs(joints[-1][1] - 20.0) < 1.0 and not inferred.any()
