"""Step 6, merging: join costs, joins, gap curves and bridges, and their kernels."""

import dataclasses
from collections import Counter
from dataclasses import replace

import cv2
import numpy as np
import pytest

from schemas import DetectParams
from service.evaluation.synthetic_eval import evaluate_scene
from service.perception import _merging_kernels, detect
from service.perception.appearance import EndColours
from service.perception.bridge_ends import (
    bridge_from_the_fits,
    ends_of_short_pieces_from_partners,
)
from service.perception.deadline import Deadline, DeadlineExceeded
from service.perception.euler_spiral import is_large_turn
from service.perception.geometry import resample
from service.perception.merging import (
    ChainEnd,
    chain_ends,
    choose_joins,
    gap_curve,
    join_cost,
    junctions_of_ends,
    merge_chains,
    tips_in_junctions,
)
from service.perception.touching import split_where_leaving_together
from service.synthetic.families import make_family_scene
from tests.perception.references import merging as reference
from tests.perception.test_appearance import gap_scene
from tests.perception.test_merging_touching import strand_error, touching_strands_mask


def test_gap_curves_are_straight_for_aligned_ends():
    for shape in ("natural", "smooth"):
        curve = gap_curve(
            np.array([0.0, 0]),
            np.array([1.0, 0]),
            np.array([50.0, 0]),
            np.array([1.0, 0]),
            shape=shape,
        )
        assert np.allclose(curve[:, 1], 0)
        assert np.allclose(curve[0], [0, 0]) and np.allclose(curve[-1], [50, 0])


def test_natural_curve_follows_the_ends_then_turns_at_a_constant_rate():
    # Leaving east from the origin, arriving heading north at (30, 40): the rays meet
    # at (30, 0); the gentlest arc is tangent 30 px before that corner.
    start, end = np.array([0.0, 0.0]), np.array([30.0, 40.0])
    curve = gap_curve(
        start, np.array([1.0, 0.0]), end, np.array([0.0, 1.0]), step=0.5, shape="natural"
    )
    assert np.allclose(curve[0], start) and np.allclose(curve[-1], end)
    headings = np.diff(curve, axis=0)
    assert np.allclose(headings[0] / np.linalg.norm(headings[0]), [1, 0], atol=0.01)
    assert np.allclose(headings[-1] / np.linalg.norm(headings[-1]), [0, 1], atol=0.01)
    # The arc part (centre (0, 30), radius 30) then a straight stretch north.
    on_arc = curve[(curve[:, 1] < 30) & (curve[:, 1] > 0.5)]
    radii = np.hypot(on_arc[:, 0] - 0.0, on_arc[:, 1] - 30.0)
    assert np.allclose(radii, 30.0, atol=0.05)


def test_smooth_curve_follows_an_arc_between_symmetric_ends_and_is_straight_when_aligned():
    radius = 80.0
    angles = (0.3, 1.4)
    start, end = (np.array([radius * np.cos(a), radius * np.sin(a)]) for a in angles)
    leaving, arriving = (np.array([-np.sin(a), np.cos(a)]) for a in angles)
    curve = gap_curve(start, leaving, end, arriving, step=0.5, shape="smooth")
    # The cubic stays within a small fraction of a pixel of the circle it approximates.
    assert np.abs(np.hypot(curve[:, 0], curve[:, 1]) - radius).max() < 0.05
    np.testing.assert_allclose(curve[[0, -1]], [start, end])
    straight = gap_curve(
        np.array([0.0, 0.0]),
        np.array([1.0, 0.0]),
        np.array([30.0, 0.0]),
        np.array([1.0, 0.0]),
        shape="smooth",
    )
    assert np.abs(straight[:, 1]).max() < 1e-9


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
    # The bridge starts where each end's fit begins, a radius in from the tips (100 and
    # 160): the joints within it (the tips) are left out of the path.
    assert gap_edges[:, 0].min() >= 90 - 1e-9 and gap_edges[:, 0].max() < 170
    assert not np.isin(path.vertices[:, 0], [100.0, 160.0]).any()


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


def test_end_directions_leave_out_a_cut_end_where_the_cable_narrows():
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


def test_a_thin_cable_is_held_to_its_own_width_not_the_pictures():
    # A cable of half width 3 in a picture whose cables are typically 4.5: one joint
    # widened (a bend, a touching strand) must not make the joints before it a cut end.
    piece = np.array([[10.0 + 10 * k, 50.0] for k in range(15)])
    distance = np.zeros((100, 200), np.float32)
    distance[47:54, :] = 3.0
    distance[50, 40] = 4.2
    radius = 4.5
    ends = chain_ends(
        [piece], span=40.0, skip=radius, distance=distance, full_width=0.8 * (radius + 0.5)
    )
    assert [end.skip for end in ends] == [radius, radius]


def test_a_short_pieces_end_fit_stops_short_of_its_other_ends_cut():
    # A 38 px piece along y = 50 whose far end bends into a slanted cut's corner: the
    # near end's fit leaves that hook out and keeps the cable's axis.
    piece = np.array([[x, 50.0] for x in range(20, 51, 5)] + [[55.0, 53.0], [58.0, 57.0]])
    mask = np.zeros((100, 100), np.uint8)
    cv2.line(mask, (0, 50), (53, 50), 1, 13)
    distance = cv2.distanceTransform(mask, cv2.DIST_L2, 5)
    radius = 6.0
    near = chain_ends(
        [piece], span=40.0, skip=radius, distance=distance, full_width=0.8 * (radius + 0.5)
    )[0]
    np.testing.assert_allclose(near.position, [20.0, 50.0], atol=1e-6)
    np.testing.assert_allclose(near.direction, [-1.0, 0.0], atol=1e-6)


def test_a_short_piece_cut_at_a_slant_at_both_ends_has_its_cables_width():
    # A cable 13 px wide seen for 40 px between two objects that cut it at 50
    # degrees: most of the piece's few joints lie where a cut narrows it, and their
    # median is well below the cable's width. Its widest joint between the ends is not.
    mask = np.zeros((100, 160), np.uint8)
    cv2.rectangle(mask, (20, 44), (120, 56), 1, -1)
    rows, cols = np.mgrid[0:100, 0:160]
    slope = np.tan(np.radians(50.0))
    mask[(cols < 50 + slope * (rows - 50)) | (cols > 90 + slope * (rows - 50))] = 0
    distance = cv2.distanceTransform(mask, cv2.DIST_L2, 5)
    piece = np.array([[44.0, 50.0], [52.0, 50.0], [60.0, 50.0], [70.0, 50.0], [88.0, 50.0]])
    values = distance[50, piece[:, 0].astype(int)]
    (start, end) = chain_ends([piece], 40.0, skip=6.0, distance=distance, full_width=5.2)
    assert start.width == end.width == pytest.approx(float(values[1:-1].max()))
    assert start.width >= 5.5 > float(np.median(values))
    # Where the median is not narrow (a piece seen whole between two crossings), its
    # widest joint (here where something touches it) is only its noise: the median stays.
    whole_mask = np.zeros_like(mask)
    cv2.rectangle(whole_mask, (20, 44), (120, 56), 1, -1)
    cv2.circle(whole_mask, (60, 50), 8, 1, -1)
    uncut = cv2.distanceTransform(whole_mask, cv2.DIST_L2, 5)
    values = uncut[50, piece[:, 0].astype(int)]
    (whole, _) = chain_ends([piece], 40.0, skip=6.0, distance=uncut, full_width=5.2)
    assert whole.width == pytest.approx(float(np.median(values)))
    assert whole.width < float(values[1:-1].max())


# --------------------------------------------------------------------------- kernels


@pytest.mark.parametrize("seed", range(3))
def test_gap_curve_kernels_equal_the_references_in_every_shape(seed):
    rng = np.random.default_rng(seed)
    natural_shapes = Counter()
    for _ in range(400):
        start, end = rng.uniform(0, 300, 2), rng.uniform(0, 300, 2)
        leaving, arriving = (v / np.linalg.norm(v) for v in rng.normal(size=(2, 2)))
        if rng.random() < 0.1:  # aligned ends: the straight case
            leaving = arriving = (end - start) / np.linalg.norm(end - start)
        step = float(rng.choice([0.5, 1.0, 3.0]))
        natural_shapes[reference.natural_curve_shape(start, leaving, end, arriving)] += 1
        fast = gap_curve(start, leaving, end, arriving, step, shape="natural")
        expected = reference.natural_curve(start, leaving, end, arriving, step)
        assert fast.shape == expected.shape
        np.testing.assert_allclose(fast, expected, rtol=0, atol=1e-9)
        # The cubic's kernel (gap_curve's smooth shape for turns under a right angle;
        # larger ones take the Euler spiral, tests/perception/test_euler_spiral.py).
        fast = _merging_kernels.smooth_curve_kernel(start, leaving, end, arriving, step)
        expected = reference.smooth_curve(start, leaving, end, arriving, step)
        assert fast.shape == expected.shape
        np.testing.assert_allclose(fast, expected, rtol=0, atol=1e-9)
        if not is_large_turn(start, leaving, end, arriving):
            smooth = gap_curve(start, leaving, end, arriving, step, shape="smooth")
            np.testing.assert_array_equal(smooth, fast)
    # Each of the natural curve's three shapes was compared many times (about 40
    # straight, 90 arcs and 270 Bezier curves in 400).
    assert natural_shapes["straight"] >= 20
    assert natural_shapes["arc"] >= 50
    assert natural_shapes["bezier"] >= 150


@pytest.mark.parametrize("seed", range(3))
def test_chain_ends_kernel_equals_the_plain_fits_bit_for_bit(seed):
    # Wandering pieces of 2 to 40 joints over a distance map with narrow and wide places,
    # with and without the narrow ends left out, and with most ends fitted over the span
    # their bend allows: every end's fit as geometry.end_fit's.
    rng = np.random.default_rng(seed)
    mask = np.zeros((120, 160), np.uint8)
    for _ in range(6):
        start, stop = rng.integers(0, 160, 2), rng.integers(0, 120, 2)
        cv2.line(mask, (int(start[0]), int(stop[0])), (int(start[1]), int(stop[1])), 1, 9)
    distance = cv2.distanceTransform(mask, cv2.DIST_L2, 5)
    pieces = []
    for _ in range(30):
        steps = rng.normal(size=(int(rng.integers(2, 40)), 2)) * 3.0 + rng.normal(size=2) * 4.0
        pieces.append(rng.uniform(0, 150, 2) + np.cumsum(steps, axis=0))
    flags = rng.random(2 * len(pieces)) < 0.7
    shortened = 0
    for arguments in (
        {"span": 40.0},
        {"span": 20.0, "skip": 4.0},
        {"span": 30.0, "skip": 3.0, "distance": distance, "full_width": 2.8},
        {"span": 40.0, "skip": 4.0, "bend_aware": flags},
        {"span": 30.0, "skip": 3.0, "distance": distance, "full_width": 2.8, "bend_aware": flags},
    ):
        fast, plain = chain_ends(pieces, **arguments), reference.chain_ends(pieces, **arguments)
        assert len(fast) == len(plain) == 2 * len(pieces)
        usual = {key: value for key, value in arguments.items() if key != "bend_aware"}
        for got, expected, before in zip(fast, plain, chain_ends(pieces, **usual), strict=True):
            assert (got.piece, got.at_start) == (expected.piece, expected.at_start)
            assert np.array_equal(got.position, expected.position)
            assert np.array_equal(got.direction, expected.direction)
            assert (got.curvature, got.skip, got.width) == (
                expected.curvature,
                expected.skip,
                expected.width,
            )
            shortened += not np.array_equal(got.direction, before.direction)
    assert shortened > 0  # some flagged ends lay on tight bends


@pytest.mark.parametrize("seed", range(4))
def test_junctions_of_ends_group_the_ends_as_the_labelled_grown_zones(seed):
    # Discs and bridges of zones, some close enough to merge once grown, some at the
    # picture's border; ends on them, beside them, just out of reach and far off.
    rng = np.random.default_rng(seed)
    zones = np.zeros((90, 120), np.uint8)
    for _ in range(int(rng.integers(1, 9))):
        centre = (int(rng.integers(-5, 125)), int(rng.integers(-5, 95)))
        cv2.circle(zones, centre, int(rng.integers(1, 9)), 1, -1)
    if seed % 2:
        cv2.line(zones, (10, 10), (60, 40), 1, 1)
    positions = rng.uniform(-3.0, 123.0, (200, 2))
    # And some on half pixels, which round half to even.
    positions = np.concatenate([positions, np.round(rng.uniform(0, 90, (40, 2))) + 0.5])
    ends = [
        ChainEnd(k // 2, k % 2 == 0, position, np.array([1.0, 0.0]))
        for k, position in enumerate(positions)
    ]
    for reach in (0, 3):
        fast = junctions_of_ends(ends, zones.view(np.bool_), reach)
        plain = reference.junctions_of_ends(ends, zones.view(np.bool_), reach)
        # The same ends in no zone, and the same ends together (labels may be numbered
        # otherwise: only which ends share a zone counts).
        assert [label < 0 for label in fast] == [label < 0 for label in plain]
        assert len(set(zip(fast, plain, strict=True))) == len(set(plain)) == len(set(fast))
        # Whether an end is on the zones at all, without labels (tips_in_junctions).
        on_zones = _merging_kernels.on_grown_zones(zones, positions, reach)
        assert on_zones.tolist() == reference.on_grown_zones(zones, positions, reach).tolist()
    assert junctions_of_ends(ends, np.zeros((90, 120), bool)) == [-1] * len(ends)


@pytest.mark.parametrize("seed", range(3))
def test_tips_in_junctions_read_both_tips_of_every_piece_as_junctions_of_ends(seed):
    # The tip check hands the pieces' first and last joints to the kernel directly:
    # the same answer as the ends' own lookup, piece by piece, start then end.
    rng = np.random.default_rng(seed)
    zones = np.zeros((80, 100), np.uint8)
    for _ in range(5):
        centre = (int(rng.integers(0, 100)), int(rng.integers(0, 80)))
        cv2.circle(zones, centre, int(rng.integers(2, 8)), 1, -1)
    pieces = [rng.uniform(-3, 103, (int(rng.integers(1, 12)), 2)) for _ in range(30)]
    tips = [
        ChainEnd(index, at_start, points[0 if at_start else -1], np.zeros(2))
        for index, points in enumerate(pieces)
        for at_start in (True, False)
    ]
    expected = np.array(junctions_of_ends(tips, zones.view(np.bool_))) >= 0
    got = tips_in_junctions(pieces, zones.view(np.bool_))
    assert expected.any() and not expected.all()
    assert got.tolist() == expected.tolist()
    assert not tips_in_junctions(pieces, None).any()


@pytest.mark.parametrize("seed", range(3))
def test_median_distance_per_piece_equals_numpy(seed):
    rng = np.random.default_rng(seed)
    distance = (rng.random((60, 80)) * 9).astype(np.float32)
    pieces = [rng.uniform(-5, 85, (int(rng.integers(1, 30)), 2)) for _ in range(8)]
    starts = np.cumsum([0] + [len(points) for points in pieces]).astype(np.int64)
    medians = _merging_kernels.median_distance_per_piece(distance, np.concatenate(pieces), starts)
    for points, median in zip(pieces, medians, strict=True):
        cols = np.clip(np.rint(points[:, 0]).astype(int), 0, 79)
        rows = np.clip(np.rint(points[:, 1]).astype(int), 0, 59)
        assert float(np.median(distance[rows, cols])) == float(median)


def random_ends(rng, count, extent):
    """``count`` chain ends of about ``count / 2`` pieces, some on top of each other."""
    pieces = rng.integers(0, max(1, count // 2), count)
    ends = []
    for index in range(count):
        direction = rng.normal(size=2)
        direction = direction / np.linalg.norm(direction) if rng.random() > 0.05 else np.zeros(2)
        position = rng.uniform(0, extent, 2)
        if ends and rng.random() < 0.1:  # two ends at the same spot
            position = ends[-1].position.copy()
        curvature = float(rng.normal(0.0, 0.05)) if rng.random() < 0.7 else 0.0
        ends.append(ChainEnd(int(pieces[index]), bool(index % 2), position, direction, curvature))
    return ends, int(pieces.max()) + 1


@pytest.mark.parametrize("seed", range(40))
def test_candidate_grid_makes_the_joins_every_pair_costed_makes(seed):
    """The grid of candidate joins within max_gap gives the very joins (ends, order and
    costs to the last bit) of costing every pair, with and without expected_count,
    junctions and ends at the border."""
    rng = np.random.default_rng(seed)
    ends, piece_count = random_ends(rng, int(rng.integers(2, 160)), float(rng.choice([80, 600])))
    params = DetectParams(
        max_gap=float(rng.choice([0.0, 0.5, 40.0, 250.0, 5000.0])),
        expected_count=None if rng.random() < 0.6 else int(rng.integers(1, 5)),
        merge_cost_threshold=float(rng.choice([0.3, 0.6, 1.2])),
    )
    radius = float(rng.uniform(1, 8))
    junctions = [int(j) for j in rng.integers(-4, 4, len(ends))] if rng.random() < 0.5 else None
    at_border = rng.random(len(ends)) < 0.2 if rng.random() < 0.5 else None
    leaving = rng.random(len(ends)) < 0.2 if rng.random() < 0.5 else None
    colours = None
    if rng.random() < 0.5:
        colours = EndColours(rng.uniform(0, 60, (len(ends), 3)), rng.uniform(0, 8, len(ends)))
    picture = (
        (int(rng.integers(40, 700)), int(rng.integers(40, 700))) if rng.random() < 0.5 else None
    )
    evidence = (colours, leaving, picture)
    expected = reference.choose_joins(
        ends, piece_count, params, radius, junctions, at_border, *evidence
    )
    assert (
        choose_joins(ends, piece_count, params, radius, junctions, at_border, None, *evidence)
        == expected
    )


@pytest.mark.parametrize("seed", range(3))
def test_candidate_join_costs_equal_join_cost_to_the_last_bit(seed):
    rng = np.random.default_rng(seed)
    ends, _ = random_ends(rng, 300, 400.0)
    params = DetectParams(distance_weight=0.7, direction_weight=1.3, curvature_weight=0.4)
    pairs, distances, costs = _merging_kernels.candidate_joins(
        np.array([end.position for end in ends]),
        np.array([end.direction for end in ends]),
        np.array([end.curvature for end in ends]),
        np.array([end.piece for end in ends], np.int64),
        np.arange(len(ends), dtype=np.int64),
        float(params.max_gap),
        float(params.max_gap),
        np.array([params.distance_weight, params.direction_weight, params.curvature_weight]),
        3.5,
    )
    assert len(pairs) > 1000
    for (i, j), distance, cost in zip(pairs, distances, costs, strict=True):
        assert i < j and ends[i].piece != ends[j].piece
        assert cost == join_cost(ends[i], ends[j], params, 3.5)
        assert distance == np.hypot(*(ends[i].position - ends[j].position)) <= params.max_gap


def test_merging_stops_at_its_deadline():
    ends, piece_count = random_ends(np.random.default_rng(0), 400, 300.0)
    ticks = iter(range(1000))
    deadline = Deadline(1.0, clock=lambda: float(next(ticks)))  # one second per look
    with pytest.raises(DeadlineExceeded, match="in merging after its budget of 1 s"):
        choose_joins(ends, piece_count, DetectParams(), 3.0, deadline=deadline)


@pytest.mark.parametrize("seed", range(3))
def test_join_cost_kernel_equals_the_plain_reference(seed):
    rng = np.random.default_rng(seed)
    ends, _ = random_ends(rng, 200, 150.0)
    params = DetectParams(distance_weight=0.7, direction_weight=1.3, curvature_weight=0.4)
    for a, b in zip(ends[::2], ends[1::2], strict=True):
        radius = float(rng.uniform(1, 8))
        expected = reference.join_cost(a, b, params, radius)
        assert join_cost(a, b, params, radius) == pytest.approx(expected, rel=1e-12, abs=1e-12)
        # The ends' bending only ever explains a turn: never dearer than the paper's cost.
        flat = join_cost(replace(a, curvature=0.0), replace(b, curvature=0.0), params, radius)
        assert join_cost(a, b, params, radius) <= flat


def test_join_cost_of_a_hidden_bend_follows_the_ends_curvature():
    """Two ends of one circle of 30 px (a tight loop of a cable of radius 6) with a
    quarter of it hidden: their curvature says the cable goes on bending, so the join
    costs far less than the same ends seen as straight, and no more than a straight gap
    of the same length between straight ends."""
    params, radius, bend = DetectParams(), 6.0, 30.0

    def on_circle(angle, outwards_sign, curvature):
        position = bend * np.array([np.cos(angle), np.sin(angle)])
        tangent = outwards_sign * np.array([-np.sin(angle), np.cos(angle)])
        return position, tangent, curvature

    # Leaving a at angle 0 anticlockwise (turning left, +1/bend), arriving at b at pi/2;
    # b's outward direction is clockwise, along which the circle turns right.
    pa, da, ka = on_circle(0.0, 1.0, 1.0 / bend)
    pb, db, kb = on_circle(np.pi / 2, -1.0, -1.0 / bend)
    curved = join_cost(
        ChainEnd(0, False, pa, da, ka), ChainEnd(1, True, pb, db, kb), params, radius
    )
    seen_straight = join_cost(ChainEnd(0, False, pa, da), ChainEnd(1, True, pb, db), params, radius)
    gap = float(np.hypot(*(pb - pa)))
    straight = join_cost(
        ChainEnd(0, False, np.zeros(2), np.array([1.0, 0.0])),
        ChainEnd(1, True, np.array([gap, 0.0]), np.array([-1.0, 0.0])),
        params,
        radius,
    )
    assert curved < 0.5 * seen_straight
    assert curved <= straight + 1e-9


@pytest.mark.parametrize("seed", range(5))
def test_runs_to_border_equals_the_plain_reference(seed):
    rng = np.random.default_rng(seed)
    mask = np.zeros((60, 90), bool)
    for _ in range(6):
        x, y = rng.integers(0, 90), rng.integers(0, 60)
        cv2.line(mask.view(np.uint8), (int(x), int(y)), (int(x + 40), int(y)), 1, 5)
    positions = rng.uniform(-2, 92, (300, 2))
    angles = rng.uniform(0, 2 * np.pi, 300)
    directions = np.column_stack([np.cos(angles), np.sin(angles)])
    found = _merging_kernels.runs_to_border(mask, positions, directions, 20.0, 2.0)
    expected = reference.runs_to_border(mask, positions, directions, 20.0, 2.0)
    np.testing.assert_array_equal(found, expected)


def test_a_cable_running_out_of_the_picture_is_not_joined_across_a_gap():
    """Two parallel cables cross the picture 20 px apart, leaving it at both edges:
    without the mask one pair of their ends would be joined in a U-turn."""
    mask = np.zeros((100, 200), bool)
    mask[37:44] = True
    mask[57:64] = True
    pieces = [
        np.column_stack([np.linspace(3, 196, 20), np.full(20, 40.0)]),
        np.column_stack([np.linspace(3, 196, 20), np.full(20, 60.0)]),
    ]
    params = DetectParams(merge_cost_threshold=5.0)
    assert len(merge_chains(pieces, params, 3.5).paths) == 1
    assert len(merge_chains(pieces, params, 3.5, mask=mask).paths) == 2


def test_ends_of_clearly_different_colour_are_not_joined():
    """One straight cable with a 30 px gap, drawn in one colour or in two."""
    pieces = [
        np.column_stack([np.linspace(10, 80, 15), np.full(15, 50.0)]),
        np.column_stack([np.linspace(110, 190, 15), np.full(15, 50.0)]),
    ]
    one, two = (np.full((100, 200, 3), 235, np.uint8) for _ in range(2))
    for image, right in ((one, (40, 40, 200)), (two, (200, 60, 30))):
        cv2.line(image, (10, 50), (80, 50), (40, 40, 200), 7)
        cv2.line(image, (110, 50), (190, 50), right, 7)
    params = DetectParams(colour_weight=0.5)
    assert len(merge_chains(pieces, params, 3.5, image=one).paths) == 1
    assert len(merge_chains(pieces, params, 3.5, image=two).paths) == 2
    assert (
        len(
            merge_chains(
                pieces, params.model_copy(update={"colour_weight": 0}), 3.5, image=two
            ).paths
        )
        == 1
    )


def test_ends_are_not_joined_round_a_bend_outside_the_picture():
    """Two cables bend down out of the picture's bottom edge next to each other: their
    ends' curvature makes a U-turn below the picture look plausible, but what a cable
    does outside the picture cannot be told."""

    # One circle of radius 50 round (100, 60): its bottom (y 100-110) is cut off by the
    # picture's edge at y = 100.
    def arc(first, last):
        t = np.linspace(first, last, 40)
        return np.column_stack([100 + 50 * np.cos(t), 60 + 50 * np.sin(t)])

    left, right = arc(np.pi, 0.8 * np.pi), arc(0.0, 0.2 * np.pi)
    pieces = [left, right]
    # (A U-turn joining the two top ends, over the circle's top, costs 0.58.)
    params = DetectParams(merge_cost_threshold=0.5)
    free = merge_chains(pieces, params, 4.0)
    inside = merge_chains(pieces, params, 4.0, zones=np.zeros((100, 240), bool))
    assert len(free.paths) == 1 and len(inside.paths) == 2


def test_two_ends_facing_each_other_across_a_long_gap_join_only_under_an_object():
    """A straight cable with a 100 px gap (28 radii): its ends are each other's only
    partner but a little over the threshold. Across a short gap that is enough; across a
    long one only where the image shows something lying over the gap, not over open
    paper or under an object of the paper's own colour (which looks as open paper)."""
    pieces = [
        np.column_stack([np.linspace(10, 80, 15), np.full(15, 50.0)]),
        np.column_stack([np.linspace(180, 250, 15), np.full(15, 50.0)]),
    ]
    params = DetectParams(merge_cost_threshold=0.35)  # the gap alone costs 0.4
    counts = []
    for box in ((60, 140, 60), None, (200, 200, 200)):
        image, mask, _, _ = gap_scene(box)
        counts.append(len(merge_chains(pieces, params, 3.5, image=image, mask=mask).paths))
    assert counts == [1, 2, 2]


@pytest.mark.parametrize(
    ("box", "second_start", "chains"),
    [
        ((60, 140, 60), 180, 1),  # 100 px (29 radii) under a green box: joined
        (None, 180, 2),  # the same over open paper: longer than anything hides
        ((200, 200, 200), 180, 2),  # a box of the paper's colour shows nothing
        (None, 140, 1),  # 60 px (17 radii): an object of the paper's colour could hide it
        ("foreground", 180, 1),  # the bridge runs along the foreground (touching strands)
    ],
)
def test_a_cheap_join_across_open_paper_needs_a_gap_something_could_hide(box, second_start, chains):
    """Two pieces facing each other, well under the threshold (the gap alone costs 0.4
    at 100 px): over open background a gap is bridged only as far as an object of the
    background's own colour could hide a cable (``OPEN_GAP_RADII``); a longer one only
    where the image shows an object lying over it (ariadne ``simple/00013``: two red
    cables' tips 29 radii apart on plain paper). A bridge along the foreground is not
    over open background."""
    pieces = [
        np.column_stack([np.linspace(10, 80, 15), np.full(15, 50.0)]),
        np.column_stack([np.linspace(second_start, second_start + 70, 15), np.full(15, 50.0)]),
    ]
    image, mask, _, _ = gap_scene(None if box == "foreground" else box)
    if box == "foreground":
        mask[47:54, 80:180] = True
        image[mask] = (40, 40, 60)
    if second_start != 180:  # the second cable seen from second_start on, not from 180
        paper = image[10, 10].copy()
        image[mask & (np.arange(260) >= 180)] = paper
        mask[:, 180:] = False
        cable = np.zeros(mask.shape, np.uint8)
        cv2.line(cable, (second_start, 50), (second_start + 70, 50), 1, 7)
        mask |= cable > 0
        image[cable > 0] = (40, 40, 60)
    result = merge_chains(pieces, DetectParams(), 3.5, image=image, mask=mask)
    assert result.joins == [] or result.joins[0].cost < DetectParams().merge_cost_threshold
    assert len(result.paths) == chains
    # Without the image there is no evidence either way: joined as before.
    assert len(merge_chains(pieces, DetectParams(), 3.5).paths) == 1


@pytest.mark.parametrize(("family", "seed"), [("occluded", 118), ("many", 119)])
def test_cables_under_long_occluders_of_generated_scenes_are_bridged(family, seed):
    """Tuning scenes where a cable bends under an occluder 18-19 radii across: its two
    ends are each other's only partner, a little over the threshold; one chain each."""
    score, _ = evaluate_scene(make_family_scene(family, seed), seed, mask_from_labels=True)
    assert score.frame.correct, score.frame.coverage


def _hairpin_pieces(bend=30.0):
    """A cable running right along y = 60, round a half circle of radius ``bend`` about
    (100, 90) and back left along y = 120; the middle quarter of the bend is hidden and
    each piece's last joint is bent 4 px outwards (the hook thinning leaves at a cut)."""

    def arc(first, last):
        angle = np.linspace(first, last, 200)
        return np.column_stack([100 + bend * np.cos(angle), 90 + bend * np.sin(angle)])

    def line(y, start, stop):
        return np.column_stack([np.linspace(start, stop, 200), np.full(200, float(y))])

    first = resample(np.vstack([line(60, 0, 100), arc(-np.pi / 2, -np.pi / 4)]), 10.0)[0]
    second = resample(np.vstack([arc(np.pi / 4, np.pi / 2), line(120, 100, 0)]), 10.0)[0]
    first[-1] += 4 * (first[-1] - [100, 90]) / bend
    second[0] += 4 * (second[0] - [100, 90]) / bend

    def error(points):
        on_bend = points[:, 0] > 100
        round_bend = np.abs(np.hypot(points[:, 0] - 100, points[:, 1] - 90) - bend)
        straight = np.minimum(np.abs(points[:, 1] - 60), np.abs(points[:, 1] - 120))
        return np.where(on_bend, round_bend, straight)

    return [first, second], error


def test_a_hidden_bend_is_bridged_from_where_the_end_fits_begin():
    """Across a gap on a tight bend, the end fits extrapolated over the cut tips point
    the bridge off the cable (5.9 px from its centreline, over its 5 px radius); from
    where the fits begin, with their own tangents there, it stays on the cable."""
    pieces, error = _hairpin_pieces()
    result = merge_chains(pieces, DetectParams(), 5.0)
    assert len(result.paths) == 1
    assert error(result.paths[0].vertices).max() < 5.0
    ends = chain_ends(pieces, 40.0, skip=5.0)
    inner, trims = bridge_from_the_fits(pieces, ends, [(1, 2, 0.0)], 40.0, [-1] * 4)
    assert trims.tolist() == [0.0, 5.0, 5.0, 0.0]
    extrapolated = error(np.array([ends[1].position, ends[2].position]))
    assert (error(np.array([inner[1].position, inner[2].position])) < extrapolated).all()


def _cut_cable_scene(tips: str, second_half_width: int = 5):
    """A dark red cable along y = 60 on grey paper, seen from x 10 to 90 and from 150 to
    230: a 60 px gap (12 radii of 5 px), its ends cut square or round."""
    rng = np.random.default_rng(4)
    image = np.clip(rng.normal(150, 3, (120, 240, 3)), 0, 255).astype(np.uint8)
    mask = np.zeros((120, 240), np.uint8)
    for (first, last), half in (((10, 90), 5), ((150, 230), second_half_width)):
        cv2.rectangle(mask, (first, 60 - half), (last, 60 + half), 1, -1)
        if tips == "round":
            tip = last if first == 10 else first
            cv2.rectangle(mask, (tip - half, 60 - half), (tip + half, 60 + half), 0, -1)
            cv2.circle(mask, (tip - half if first == 10 else tip + half, 60), half, 1, -1)
    image[mask > 0] = (40, 30, 150)
    distance = cv2.distanceTransform(mask, cv2.DIST_L2, 5)
    pieces = [
        np.column_stack([np.linspace(15, 85, 15), np.full(15, 60.0)]),
        np.column_stack([np.linspace(155, 225, 15), np.full(15, 60.0)]),
    ]
    return image, mask > 0, distance, pieces


@pytest.mark.parametrize(
    ("tips", "second_half_width", "chains"),
    [("cut", 5, 1), ("round", 5, 2), ("cut", 3, 2)],
)
def test_two_ends_cut_square_and_alike_join_across_a_gap_over_open_paper(
    tips, second_half_width, chains
):
    """An object of the paper's own colour hides 12 radii of a cable: nothing shows over
    the gap, but both ends are cut straight across the cable, face each other and agree
    in colour and width, and are each other's only partner a little over the threshold.
    Two cables' own round tips, or two cables of different widths, are not joined."""
    image, mask, distance, pieces = _cut_cable_scene(tips, second_half_width)
    params = DetectParams(merge_cost_threshold=0.2)  # the gap alone costs 0.24
    result = merge_chains(pieces, params, 5.0, distance=distance, image=image, mask=mask)
    assert len(result.paths) == chains


@pytest.mark.parametrize("seed", [280002, 280049, 280074, 280058])
def test_cables_of_one_colour_whose_own_tips_lie_close_come_out_apart(seed):
    """Tuning scenes of `same_colour`: two cables' round tips 40-50 px apart over open
    background, whose join would bend (costs 0.60-0.86), stay two cables' ends; and a
    loop's bend under an object of the background's colour, between a crossing and the
    object a scrap of no colour of its own, is joined as a turn (its chain's colour)."""
    scene = make_family_scene("same_colour", seed)
    score, _ = evaluate_scene(scene, seed, mask_from_labels=True)
    assert score.frame.correct, score.frame.coverage


@pytest.mark.parametrize("seed", [330016, 330052])
def test_a_round_tip_and_an_end_that_shows_no_cut_stay_apart_over_open_background(seed):
    """Tuning scenes of `same_colour`: a cable's round tip 40-60 px from another cable's
    end over open background (in 330052 a tip read wide on its bend, in 330016 a cable
    running along the picture's bottom edge), the join bending sharply (costs 0.74-0.87).
    Nothing shows over the gap and neither end is cut, while an object hiding a stretch
    of cable cuts at least one of its two ends: two cables' ends (one chain for two
    cables before)."""
    scene = make_family_scene("same_colour", seed)
    score, _ = evaluate_scene(scene, seed, mask_from_labels=True)
    assert score.frame.correct, score.frame.coverage


def _ends_by_the_top_edge():
    """A piece of cable lying along the picture's top edge (y = 5, radius 5) from its
    right edge to x = 300, where an object cuts it; the cable comes out again at
    (240, 9), heading on to the left: ends 1 and 2 face each other across 12 radii."""
    return [
        ChainEnd(0, True, np.array([318.0, 5.0]), np.array([1.0, 0.0])),
        ChainEnd(0, False, np.array([300.0, 5.0]), np.array([-1.0, 0.0])),
        ChainEnd(1, True, np.array([240.0, 9.0]), np.array([1.0, -0.06])),
        ChainEnd(1, False, np.array([150.0, 20.0]), np.array([-1.0, 0.1])),
    ]


@pytest.mark.parametrize(
    ("hidden", "runs_out", "joined"),
    [
        (True, [True, False, False, False], True),  # an object at the edge cut it
        (False, [True, False, False, False], False),  # nothing shows over the gap
        (True, [True, True, False, False], False),  # the cable runs on out of the picture
        (True, None, False),  # not told which ends run out: every end by the edge leaves
    ],
)
def test_an_end_by_the_edge_is_joined_only_under_an_object(hidden, runs_out, joined):
    """An end near the picture's edge whose cable stops short of it (not ``runs_out``)
    is not a cable leaving the picture when the image shows an object over the gap."""
    ends = _ends_by_the_top_edge()
    at_border = np.array([True, True, False, False])
    leaving = at_border | (runs_out if runs_out is not None else False)
    joins = choose_joins(
        ends,
        2,
        DetectParams(),
        5.0,
        at_border=at_border,
        leaving=leaving,
        hidden_gap=lambda i, j: hidden,
        runs_out=None if runs_out is None else np.array(runs_out),
    )
    assert [(i, j) for i, j, _ in joins] == ([(1, 2)] if joined else [])


@pytest.mark.parametrize(
    ("family", "seed"), [("edge", 8025), ("occluded", 8011), ("occluded", 8027)]
)
def test_cables_cut_by_objects_at_a_slant_or_at_the_edge_come_out_whole(family, seed):
    """Tuning scenes: a cable cut at a slant by objects of the background's own colour
    (its ends' cut read from where their fits begin), and one lying along the picture's
    top edge into an object there (not a cable leaving the picture). One chain each."""
    score, _ = evaluate_scene(make_family_scene(family, seed), seed, mask_from_labels=True)
    assert score.frame.correct, score.frame.coverage


def test_a_short_piece_joined_at_one_end_arrives_as_its_partners_bend_goes_on():
    """A cable on a circle of radius 80 about (100, 100): a long piece up to 0 degrees,
    hidden from there to 40 degrees, then a piece only 25 px long (shorter than the
    40 px fit span) whose end points 20 degrees off (thinning bent it toward a cut's
    corner). The bridge arrives along the circle's tangent, within a pixel of it all
    the way, where from the short piece's own direction it bulges nearly 3 px off."""
    centre, bend = np.array([100.0, 100.0]), 80.0

    def at(degrees):
        angle = np.radians(degrees)
        return centre + bend * np.array([np.cos(angle), np.sin(angle)])

    def tangent(degrees):  # the direction of travel, counter-clockwise
        angle = np.radians(degrees)
        return np.array([-np.sin(angle), np.cos(angle)])

    long_piece = np.array([at(a) for a in np.linspace(-90.0, 0.0, 40)])
    short_piece = np.array([at(a) for a in np.linspace(40.0, 58.0, 6)])
    turned = np.radians(20.0)
    rotation = np.array([[np.cos(turned), -np.sin(turned)], [np.sin(turned), np.cos(turned)]])
    ends = [
        ChainEnd(0, True, at(-90.0), -tangent(-90.0)),
        ChainEnd(0, False, at(0.0), tangent(0.0)),
        ChainEnd(1, True, at(40.0), rotation @ -tangent(40.0)),
        ChainEnd(1, False, at(58.0), tangent(58.0)),
    ]
    joins = [(1, 2, 0.3)]
    adjusted = ends_of_short_pieces_from_partners(
        [long_piece, short_piece], ends, joins, 40.0, [-1, -1, -1, -1]
    )
    assert adjusted[1] is ends[1]  # the long piece's end is kept
    assert np.degrees(np.arccos(adjusted[2].direction @ -tangent(40.0))) < 0.5

    def worst_off(end_ends):
        curve = gap_curve(
            end_ends[1].position,
            end_ends[1].direction,
            end_ends[2].position,
            -end_ends[2].direction,
        )
        return float(np.abs(np.hypot(*(curve - centre).T) - bend).max())

    assert worst_off(adjusted) < 1.0
    assert worst_off(ends) > 2.5
    # Joined at both ends, or in a junction, the piece is left to the other rules.
    both = [*joins, (3, 0, 0.3)]
    kept = ends_of_short_pieces_from_partners(
        [long_piece, short_piece], ends, both, 40.0, [-1, -1, -1, -1]
    )
    assert kept[2] is ends[2]
    in_junction = ends_of_short_pieces_from_partners(
        [long_piece, short_piece], ends, joins, 40.0, [-1, 0, 0, -1]
    )
    assert in_junction[2] is ends[2]


@pytest.mark.parametrize(("family", "seed"), [("occluded", 5023), ("edge", 5034), ("edge", 8039)])
def test_bridges_to_short_pieces_beside_occluders_follow_the_cable(family, seed):
    """Tuning scenes where a short piece of cable (shorter than the end-fit span) lies
    between an occluder and the picture's edge: the bridge to it came out 1.2-1.4
    tolerances off the hidden stretch from the short piece's poor direction."""
    score, _ = evaluate_scene(make_family_scene(family, seed), seed, mask_from_labels=True)
    assert score.frame.correct, score.frame.coverage


def test_two_cables_touching_as_they_leave_the_picture_come_out_as_two_chains():
    """Two straight cables 9 px wide leave the picture at its left edge at one point, at
    right angles: the mask is a V the border cuts, and thinning draws one line round its
    point with no junction. Each cable must come out as its own chain (ariadne
    simple/00012); a cable bending round close to the border must stay one."""
    first = [(100, 0), (0, 100)]
    second = [(0, 100), (100, 200)]
    detection = detect(None, mask=touching_strands_mask(first, second, shape=(200, 300)))
    chains = [np.asarray(chain.points, np.float64) for chain in detection.chains]
    assert len(chains) == 2
    for cable in (first, second):
        assert min(strand_error(chain, cable) for chain in chains) < 6.0
    # One cable round a wide bend whose outer side the border clips.
    mask = np.zeros((200, 300), np.uint8)
    cv2.ellipse(mask, (60, 100), (62, 70), 0, 90, 270, 1, 9)
    detection = detect(None, mask=mask > 0)
    assert len(detection.chains) == 1


def _crossing_at_the_top_mask(apex_y, half_angle, thickness=9, shape=(200, 300)):
    """Two straight cables ``thickness`` px wide crossing at ``(150, apex_y)``, each
    ``half_angle`` degrees from the vertical, drawn on from beyond the top border; and
    each cable's part in the picture (from the top border down)."""
    apex = np.array([150.0, apex_y])
    mask = np.zeros(shape, np.uint8)
    cables = []
    for side in (-1.0, 1.0):
        heading = np.array([side * np.sin(np.radians(half_angle)), np.cos(np.radians(half_angle))])
        top = apex + (-apex_y / heading[1]) * heading
        far = (shape[0] - 1 - apex_y) / heading[1], (shape[1] - 1 - apex[0]) / abs(heading[0])
        bottom = apex + min(far) * heading
        cables.append([tuple(top), tuple(bottom)])
        drawn = [top - 30.0 * heading, bottom]
        cv2.line(mask, *[tuple(round(16 * v) for v in p) for p in drawn], 1, thickness, 8, 4)
    return mask > 0, cables


@pytest.mark.parametrize(("apex_y", "half_angle"), [(-6, 35), (-4, 45), (-2, 55), (0, 60)])
def test_a_v_whose_turn_thinning_spreads_over_two_joints_is_cut_at_the_border(apex_y, half_angle):
    """Two cables crossing at or just beyond the top border meet it as a V, and thinning
    rounds the V's cut-off point so that its turn falls on two joints, not one
    (tracking video 440004 frames 72-74): each cable must come out as its own chain."""
    mask, cables = _crossing_at_the_top_mask(apex_y, half_angle)
    chains = [np.asarray(chain.points, np.float64) for chain in detect(None, mask=mask).chains]
    assert len(chains) == 2
    for cable in cables:
        assert min(strand_error(chain, cable) for chain in chains) < 6.0


@pytest.mark.parametrize(("apex_y", "half_angle"), [(16, 30), (24, 45), (24, 20)])
def test_a_crossing_near_the_border_is_not_cut_into_a_v(apex_y, half_angle):
    """Two cables crossing a few cable widths inside the top border: each must come out
    as one chain through the crossing, to the border."""
    mask, cables = _crossing_at_the_top_mask(apex_y, half_angle)
    chains = [np.asarray(chain.points, np.float64) for chain in detect(None, mask=mask).chains]
    assert len(chains) == 2
    for cable in cables:
        assert min(strand_error(chain, cable) for chain in chains) < 6.0


def test_a_tight_hairpin_touching_the_border_stays_one_chain():
    """A cable doubled back round a bend of 3 cable radii (the loops family's tightest)
    whose outer side touches the top border: a bend, however tight, is no corner."""
    mask = np.zeros((200, 300), np.uint8)
    cv2.ellipse(mask, (150, 18), (14, 14), 0, 180, 360, 1, 9)
    for x in (136, 164):
        cv2.line(mask, (x, 18), (x, 199), 1, 9)
    assert len(detect(None, mask=mask > 0).chains) == 1


@pytest.mark.slow
def test_two_cables_crossing_through_the_top_border_in_video_440004_stay_apart():
    """Tracking video 440004, frames 72-74: two near-white cables cross just beyond the
    top border, and their V's turn falls on two joints. The detection must keep the
    three cables three chains (it joined two round the V, and the tracker made one
    track of them)."""
    from service.perception import detect_full
    from service.synthetic.videos import make_video

    video = make_video(440004)
    for index in (72, 73, 74):
        frame = video.frame(index)
        assert len(detect_full(frame.image, DetectParams(), None).detection.chains) == 3


def test_a_cable_kinked_slightly_along_the_border_is_not_cut():
    """A cable running along the top border, 4-18 px from it, with a kink of 16 degrees
    at its joint nearest the border (as mbest S2/img4's along the left border, there
    spread over two joints): its line never rises a half width from the border within
    two marks of the kink, so it is no V of two cables leaving the picture."""
    xs = np.arange(0.0, 201.0, 10.0)
    piece = np.column_stack([xs, 4.0 + np.abs(xs - 100.0) * np.tan(np.radians(8.0))])
    mask = np.zeros((100, 300), np.uint8)
    cv2.polylines(mask, [np.rint(piece).astype(np.int32)], False, 1, 9)
    pieces = split_where_leaving_together([piece], mask > 0, 4.5, 6.5, 2.0, 40.0)
    assert len(pieces) == 1 and pieces[0] is piece


def test_chain_ends_are_the_dataclass_s_own_ends():
    # chain_ends makes its ends without the frozen dataclass's __init__ (one setattr per
    # field): each must equal the end that __init__ makes, own its position and
    # direction (writing one end's must not move another's), and stay frozen.
    rng = np.random.default_rng(5)
    pieces = [
        rng.uniform(0, 100, 2) + np.cumsum(rng.normal(0, 4, (n, 2)), axis=0) for n in (2, 5, 17)
    ]
    ends = chain_ends(pieces, 20.0, skip=2.0)
    assert len(ends) == 6
    for index, end in enumerate(ends):
        made = ChainEnd(
            **{field.name: getattr(end, field.name) for field in dataclasses.fields(ChainEnd)}
        )
        assert made == end and vars(made).keys() == vars(end).keys()
        assert (end.piece, end.at_start) == (index // 2, index % 2 == 0)
        assert end.position.dtype == np.float64 and end.position.flags.c_contiguous
        with pytest.raises(dataclasses.FrozenInstanceError):
            end.skip = 1.0
    before = ends[1].position.copy()
    ends[0].position[:] = -1.0
    np.testing.assert_array_equal(ends[1].position, before)
