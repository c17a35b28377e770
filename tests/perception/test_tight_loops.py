"""Tight loops: the end fits at a loop's own crossing follow the cable, not the loop."""

import numpy as np
import pytest

from service.evaluation.synthetic_eval import evaluate_scene
from service.perception.merging import chain_ends
from service.synthetic.families import make_family_scene


def loop_piece(bend_radius: float, step: float = 10.0, straight: float = 0.0) -> np.ndarray:
    """Joints ``step`` apart round most of a circle of ``bend_radius`` px, starting (the
    piece's first joint, its end at the crossing) at ``(bend_radius, -straight)`` after
    ``straight`` px of straight cable heading in -y (outwards) from the circle's top."""
    arc = np.arange(0.0, 1.6 * np.pi * bend_radius, step)
    circle = np.column_stack(
        [bend_radius * np.cos(arc / bend_radius), bend_radius * np.sin(arc / bend_radius)]
    )
    lead = np.column_stack(
        [np.full(int(straight // step), bend_radius), -np.arange(straight, 0.0, -step)]
    ).reshape(-1, 2)
    return np.concatenate([lead, circle])


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b), -1.0, 1.0))))


@pytest.mark.parametrize("bend_radius", [13.0, 16.0, 20.0])
def test_an_end_on_a_tight_loop_is_fitted_near_its_tip(bend_radius):
    """A cable radius of 4.4 px, loops down to 3 radii: the usual fit (a quadratic over
    40 px past a 4.4 px skip) spans more than half the loop and puts the end far off the
    cable; fitted over a span the bend allows, it stays at the tip, heading along the
    cable (within one joint step's turn, 10 px on the circle: the chord of the last two
    steps)."""
    piece = loop_piece(bend_radius)
    tip, outward = piece[0], np.array([0.0, -1.0])
    usual = chain_ends([piece], 40.0, skip=4.4)[0]
    aware = chain_ends([piece], 40.0, skip=4.4, bend_aware=np.array([True, False]))[0]
    assert np.hypot(*(usual.position - tip)) > 3.0 or angle_deg(usual.direction, outward) > 30
    assert np.hypot(*(aware.position - tip)) < 1.0
    step_turn = np.degrees(10.0 / bend_radius)
    assert angle_deg(aware.direction, outward) <= step_turn + 1.0


def test_an_end_on_a_gentle_bend_keeps_the_usual_fit_bit_for_bit():
    piece = loop_piece(200.0, straight=30.0)
    usual = chain_ends([piece], 40.0, skip=4.4)
    aware = chain_ends([piece], 40.0, skip=4.4, bend_aware=np.array([True, True]))
    for got, expected in zip(aware, usual, strict=True):
        assert np.array_equal(got.position, expected.position)
        assert np.array_equal(got.direction, expected.direction)
        assert got.curvature == expected.curvature


def test_the_loops_straight_neck_keeps_the_usual_fit():
    # 60 px of straight cable before the loop: the usual stretch never reaches the bend.
    piece = loop_piece(15.0, straight=60.0)
    usual = chain_ends([piece], 40.0, skip=4.4)[0]
    aware = chain_ends([piece], 40.0, skip=4.4, bend_aware=np.array([True, False]))[0]
    assert np.array_equal(usual.position, aware.position)
    assert np.array_equal(usual.direction, aware.direction)


@pytest.mark.parametrize("seed", [77000, 77003, 77032, 77038])
def test_loops_crossing_themselves_tightly_come_out_whole(seed):
    """Loops scenes (tuning seeds) whose chain cut across a tight loop's own crossing:
    the fits of the loop's ends there spanned half the loop, the bridges across the
    crossing swung off the cable, and a few px of cable were left uncovered."""
    score, _ = evaluate_scene(make_family_scene("loops", seed), seed, mask_from_labels=True)
    assert score.frame.correct, score.frame.coverage
