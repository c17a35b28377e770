"""The Euler spiral across a gap whose ends turn a long way (euler_spiral.py, paths.gap_curve)."""

import numpy as np
import pytest

from service.evaluation.synthetic_eval import distance_to_polyline, evaluate_scene
from service.perception import _merging_kernels
from service.perception.euler_spiral import (
    chord_turn,
    euler_spiral,
    headings_within_bend,
    is_large_turn,
    max_curvature,
    spiral_shape,
)
from service.perception.paths import gap_curve
from service.synthetic.families import make_family_scene
from tests.perception.references import euler_spiral as reference


def _on_circle(radius: float, angle: float) -> tuple[np.ndarray, np.ndarray]:
    """The point at ``angle`` on a circle about the origin and the heading there,
    going round anticlockwise."""
    return (
        np.array([radius * np.cos(angle), radius * np.sin(angle)]),
        np.array([-np.sin(angle), np.cos(angle)]),
    )


def _headings(curve: np.ndarray) -> np.ndarray:
    steps = np.diff(curve, axis=0)
    return np.unwrap(np.arctan2(steps[:, 1], steps[:, 0]))


@pytest.mark.parametrize("turn_degrees", [100.0, 160.0, 202.0, 260.0])
def test_symmetric_ends_are_joined_by_the_circular_arc_even_past_a_half_turn(turn_degrees):
    # A loop's hidden arc turns past a half turn: the headings alone read 202 degrees
    # one way as 158 the other; about the chord they keep the way round.
    radius, turn = 30.0, np.radians(turn_degrees)
    (start, leaving), (end, arriving) = _on_circle(radius, 0.0), _on_circle(radius, turn)
    curve = euler_spiral(start, leaving, end, arriving, step=0.5)
    np.testing.assert_allclose(curve[[0, -1]], [start, end], atol=1e-9)
    assert np.abs(np.hypot(*curve.T) - radius).max() < 0.05
    turned = _headings(curve)
    assert turned[-1] - turned[0] == pytest.approx(turn, abs=0.02)
    # Samples about a step apart.
    assert np.hypot(*np.diff(curve, axis=0).T).max() < 0.55


def test_the_cubic_flattens_a_loops_hidden_arc_that_the_spiral_follows():
    radius, turn = 30.0, np.radians(202.0)
    (start, leaving), (end, arriving) = _on_circle(radius, 0.0), _on_circle(radius, turn)
    angles = np.linspace(0.0, turn, 200)
    hidden = radius * np.column_stack([np.cos(angles), np.sin(angles)])
    cubic = _merging_kernels.smooth_curve_kernel(start, leaving, end, arriving, 1.0)
    assert distance_to_polyline(hidden, cubic).max() > 0.3 * radius
    spiral = gap_curve(start, leaving, end, arriving)
    assert distance_to_polyline(hidden, spiral).max() < 0.5


def test_an_asymmetric_turn_changes_its_curvature_at_a_constant_rate():
    # Leaving east, arriving heading south-west after a turn of 225 degrees about
    # a chord the ends do not share alike.
    start, end = np.array([0.0, 0.0]), np.array([-20.0, 40.0])
    leaving = np.array([1.0, 0.0])
    arriving = np.array([np.cos(np.radians(-135.0)), np.sin(np.radians(-135.0))])
    distance, _, first, last = chord_turn(start, leaving, end, arriving)
    assert distance == pytest.approx(np.hypot(20.0, 40.0))
    shape = spiral_shape(start, leaving, end, arriving)
    assert shape is not None
    curve = euler_spiral(start, leaving, end, arriving, step=0.25)
    np.testing.assert_allclose(curve[[0, -1]], [start, end], atol=1e-9)
    headings = _headings(curve)
    assert headings[0] == pytest.approx(0.0, abs=0.02)
    assert headings[-1] - headings[0] == pytest.approx(last - first, abs=0.02)
    # The heading is quadratic in arc length: its second difference is constant.
    curvature = np.diff(headings) / 0.25
    rate = np.diff(curvature)
    assert np.ptp(rate) < 0.05 * np.abs(curvature).max()
    assert np.abs(curvature).max() == pytest.approx(max_curvature(shape), rel=0.05)


def test_gentle_gaps_keep_the_cubic_and_large_turns_take_the_spiral():
    rng = np.random.default_rng(5)
    large = gentle = 0
    for _ in range(300):
        start, end = rng.uniform(0, 200, 2), rng.uniform(0, 200, 2)
        leaving, arriving = (v / np.linalg.norm(v) for v in rng.normal(size=(2, 2)))
        curve = gap_curve(start, leaving, end, arriving)
        cubic = _merging_kernels.smooth_curve_kernel(start, leaving, end, arriving, 1.0)
        if is_large_turn(start, leaving, end, arriving):
            large += 1
            spiral = euler_spiral(start, leaving, end, arriving)
            np.testing.assert_array_equal(curve, cubic if spiral is None else spiral)
        else:
            gentle += 1
            np.testing.assert_array_equal(curve, cubic)
        # The paper's natural curve is never changed.
        natural = gap_curve(start, leaving, end, arriving, shape="natural")
        expected = _merging_kernels.natural_curve_kernel(start, leaving, end, arriving, 1.0)
        np.testing.assert_array_equal(natural, expected)
    assert large > 50 and gentle > 50


def test_ends_that_coincide_have_no_spiral():
    point = np.array([3.0, 4.0])
    assert euler_spiral(point, np.array([1.0, 0.0]), point, np.array([0.0, 1.0])) is None


@pytest.mark.parametrize(
    ("family", "seed"),
    [
        pytest.param(
            "doubled_back",
            350023,
            marks=pytest.mark.xfail(
                strict=True,
                reason="a turn of 186 degrees, past a half turn: its two cuts' readings open "
                "away from each other as the cable itself does there, and read together "
                "(cut_ends.read_together, their mean) the hidden curve is drawn inside the "
                "turn, 14.9 px off against 8.4 (a loss of that rule, which nothing measured "
                "tells apart from its gains: docs/BENCHMARKS.md, dback17 and the thirty-first "
                "session's code together)",
            ),
        ),
        ("doubled_back", 94045),
        ("doubled_back", 330036),
    ],
)
def test_long_hidden_turns_of_tuning_scenes_are_followed(family, seed):
    """Tuning scenes (true mask): a doubled-back cable turns under an object by 186
    degrees (350023: about the chord its ends' headings turn the long way round, which
    the cubic took the short way, 9.7 px off from the true cuts) or 140 degrees with
    one end nearly along the chord (94045), or 139 (330036); each cable one chain,
    every hidden stretch covered."""
    score, _ = evaluate_scene(make_family_scene(family, seed), seed, mask_from_labels=True)
    assert score.frame.n_chains == score.frame.n_cables
    assert score.frame.correct, score.frame.coverage


def _large_turns(count: int, seed: int):
    """Random gaps up to 60 px long whose ends turn by a right angle or more."""
    rng = np.random.default_rng(seed)
    while count:
        start = rng.uniform(0, 200, 2)
        end = start + rng.uniform(-60, 60, 2)
        leaving, arriving = (
            np.array([np.cos(a), np.sin(a)]) for a in rng.uniform(-np.pi, np.pi, 2)
        )
        if is_large_turn(start, leaving, end, arriving):
            count -= 1
            yield start, leaving, end, arriving


def _chord_offset(shape) -> float:
    """``integral sin(heading) dt`` of ``shape``: 0 where the spiral ends on the chord."""
    first, turn, rate, _, _ = shape
    t, weights = np.polynomial.legendre.leggauss(200)
    t = 0.5 * (t + 1.0)
    return float(np.sin(first + (turn - rate) * t + rate * t**2) @ (0.5 * weights))


def test_the_compiled_spiral_is_the_plain_one():
    # The kernels sum the quadrature one node at a time where NumPy's matrix products
    # sum in another order: the same roots to the last few bits, and the same samples
    # bit for bit for the same shape.
    for start, leaving, end, arriving in _large_turns(400, seed=7):
        shape = spiral_shape(start, leaving, end, arriving)
        expected = reference.spiral_shape(start, leaving, end, arriving)
        assert (shape is None) == (expected is None)
        if shape is None:
            continue
        curve = euler_spiral(start, leaving, end, arriving)
        np.testing.assert_array_equal(curve, reference.spiral_samples(shape, start, end))
        np.testing.assert_allclose(
            curve, reference.euler_spiral(start, leaving, end, arriving), rtol=0, atol=1e-9
        )


def test_the_root_search_keeps_the_root_it_converged_on():
    # Once Newton's steps reach the root, the next lands on the bracket's end just moved
    # there and used to be refused for a bisection, which walked away from the root: at
    # about a fifth of large turns the spiral then ended up to 1e-4 of its length off
    # the chord (the closing error spread along the curve hid it).
    old_offsets, offsets = [], []
    for start, leaving, end, arriving in _large_turns(200, seed=11):
        shape = spiral_shape(start, leaving, end, arriving)
        if shape is None:
            continue
        offsets.append(abs(_chord_offset(shape)))
        old = reference.spiral_shape(start, leaving, end, arriving, converged=False)
        old_offsets.append(abs(_chord_offset(old)))
    assert max(offsets) < 1e-12
    assert np.mean(np.array(old_offsets) > 1e-6) > 0.1


def _angle(first: np.ndarray, second: np.ndarray) -> float:
    """The unsigned angle (radians) between two unit headings."""
    return float(np.arccos(np.clip(first @ second, -1.0, 1.0)))


def test_a_spiral_bending_tighter_than_a_cable_is_given_the_nearest_headings_that_bend_as_one():
    """A turn 36 px across whose headings disagree: one end square to the chord, the
    other 60 degrees short of it (a turn of 120 degrees, not the half turn). The spiral
    crowds the turn at the second end, to a radius of 8.9 px, tighter than a cable of
    half width 6 bends (12 px); within 30 degrees of each reading the headings turned
    least whose spiral bends no tighter than 12 px are found."""
    start, end = np.array([0.0, 0.0]), np.array([0.0, 36.0])
    leaving = np.array([-1.0, 0.0])  # square to the chord
    arriving = np.array([np.cos(np.radians(60.0)), np.sin(np.radians(60.0))])
    before = spiral_shape(start, leaving, end, arriving)
    assert 1.0 / max_curvature(before) < 12.0
    slack = np.radians(30.0)
    found = headings_within_bend(start, leaving, end, arriving, 12.0, slack)
    assert found is not None
    turned_leaving, turned_arriving = found
    assert 1.0 / max_curvature(spiral_shape(start, turned_leaving, end, turned_arriving)) >= 12.0
    assert _angle(leaving, turned_leaving) <= slack + 1e-9
    assert _angle(arriving, turned_arriving) <= slack + 1e-9
    # Turned, but less than the slack allows both ends together.
    assert 0.0 < _angle(leaving, turned_leaving) + _angle(arriving, turned_arriving) < slack


def test_headings_whose_spiral_bends_as_a_cable_are_kept():
    """The semicircle of radius 18 px: a cable of half width 6 (tightest bend 12 px)
    takes it as it is."""
    start, end = np.array([0.0, 0.0]), np.array([0.0, 36.0])
    leaving, arriving = np.array([-1.0, 0.0]), np.array([1.0, 0.0])
    found = headings_within_bend(start, leaving, end, arriving, 12.0, np.radians(30.0))
    assert found is not None
    np.testing.assert_allclose(found[0], leaving, atol=1e-12)
    np.testing.assert_allclose(found[1], arriving, atol=1e-12)


def test_no_headings_within_the_slack_bend_as_a_cable():
    """A half turn across 6 px: no spiral within 30 degrees of the readings bends no
    tighter than 12 px."""
    start, end = np.array([0.0, 0.0]), np.array([0.0, 6.0])
    leaving, arriving = np.array([-1.0, 0.0]), np.array([1.0, 0.0])
    assert headings_within_bend(start, leaving, end, arriving, 12.0, np.radians(30.0)) is None


@pytest.mark.parametrize(
    ("family", "seed"),
    [
        pytest.param(
            "doubled_back",
            86048,
            marks=pytest.mark.xfail(
                strict=True,
                reason="a near miss both ways: the strand's bridge now starts on the strand "
                "(its fit's start lay 2.6 px beside it, bridge_ends.bridge_from_the_fits), "
                "along its own segment (+1 degree), and its cut is read nearer the truth "
                "(+22 -> +10 degrees, 2.7 -> 0.5 px off the middle), which had offset the "
                "other cut's +18: 5.74 -> 7.01 px against 5.81 (docs/BENCHMARKS.md, dbk17c, "
                "dbk18q; the direction at a cut)",
            ),
        ),
        ("doubled_back", 94009),
    ],
)
def test_hidden_turns_whose_spiral_bent_tighter_than_a_cable_are_covered(family, seed):
    """Tuning scenes (true mask): a doubled-back cable's turn under an object bridged
    from its two traced cuts, whose readings disagree (one leaning outwards on the bend
    at the cut): the spiral between them bent to 1.6 and 1.5 cable radii, tighter than
    a cable does, and fell inside the true round turn (2.8-3.3 radii) by 1.4 and 1.3
    tolerances. With the nearest headings whose spiral bends as a cable does, each
    cable is covered."""
    score, _ = evaluate_scene(make_family_scene(family, seed), seed, mask_from_labels=True)
    assert score.frame.n_chains == score.frame.n_cables
    assert score.frame.correct, score.frame.coverage
