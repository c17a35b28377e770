"""End extension: free chain ends taken to the cable's ends, and its kernel."""

import cv2
import numpy as np
import pytest

from service.evaluation.synthetic_eval import evaluate_scene
from service.perception.end_extension import FAR_RIM_PX, TIP_SEARCH_COS, extend_end, extend_ends
from service.synthetic import make_family_scene
from tests.perception.references import end_extension as reference


def test_a_chain_far_short_of_a_thin_cables_end_is_taken_to_it_and_to_the_picture_edge():
    # A thin cable (radius 3) from x = 0 (the picture's edge) to x = 99 whose chain runs
    # from x = 5 to x = 70, ten radii short of the cable's end: one extension reaches
    # only a few radii, so the end is pushed on from where it stops.
    mask = np.zeros((40, 140), bool)
    mask[17:24, 0:100] = True
    vertices, filled = extend_ends(
        np.array([[5.0, 20.0], [70.0, 20.0]]), np.array([False]), mask, radius=3.0, span=20.0
    )
    assert 94.0 <= vertices[-1][0] <= 97.5  # one radius inside the cable's end
    assert abs(vertices[-1][1] - 20.0) < 1.0
    # The cable leaves the picture at x = 0: its chain goes to the edge, not a radius short.
    np.testing.assert_allclose(vertices[0], [0.0, 20.0])
    assert len(filled) == len(vertices) - 1 and not filled.any()  # seen cable, not a gap


def test_an_end_at_a_crossing_runs_on_along_its_own_short_stretch_not_the_other_strand():
    # Cable A (half width 4) runs along y = 60 to its tip at x = 130; cable B crosses it at
    # x = 100, 20 degrees off, and runs on out of the picture. A's chain stops at the
    # crossing (its last short stretch lost to spur removal). The straight walk goes on
    # along A to its tip; the cone's farthest rim, which B's strand reaches, is no
    # farther, so the end is not drawn sideways onto B and along it.
    mask = np.zeros((120, 220), np.uint8)
    cv2.line(mask, (0, 60), (130, 60), 1, 9)
    slope = np.tan(np.radians(20.0))
    cv2.line(mask, (0, int(60 + 100 * slope)), (219, int(60 - 119 * slope)), 1, 9)
    vertices, _ = extend_ends(
        np.array([[10.0, 60.0], [96.0, 60.0]]), np.array([False]), mask > 0, 4.0, 20.0
    )
    assert 129.0 <= vertices[-1][0] <= 131.5  # one radius inside A's round tip at x = 134
    assert abs(vertices[-1][1] - 60.0) < 1.0


def test_a_diagonal_tip_the_thinning_ate_is_walked_to_its_end():
    # A 45-degree cable, half width 4: Zhang-Suen thinning removes a diagonal line two
    # pixels thick, so the skeleton of such a tip can stop 80 px short of it (bright
    # 330012). Its chain ends 127 px short here (90 on each axis); the straight walk along
    # the end's direction stays on the cable to its tip (three rounds of a short walk and
    # a rim search reached about 50 px).
    mask = np.zeros((200, 200), np.uint8)
    cv2.line(mask, (10, 10), (180, 180), 1, 9)
    points = np.array([[10.0, 10.0], [60.0, 60.0], [90.0, 90.0]])
    vertices, _ = extend_ends(points, np.array([False, False]), mask > 0, 4.0, 20.0)
    # One radius inside the round tip (its cap reaches 180 + 4 / sqrt(2) on each axis).
    assert np.hypot(*(vertices[-1] - [180.0, 180.0])) < 1.5


@pytest.mark.parametrize(
    ("family", "seed"),
    [
        ("textured", 330013),  # a crossing near the picture's edge: the stretch to it
        ("many", 330067),  # a cable's tip a few radii past where it crosses itself
        ("edge", 330141),  # a tip past a ring: the rim ahead lay across the ring's hole
        ("bright", 330012),  # a diagonal tip without skeleton, 80 px past a crossing
    ],
)
def test_tuning_scenes_whose_visible_ends_the_chain_left_uncovered(family, seed):
    """Tuning scenes, true mask: as many chains as cables and every hidden stretch
    bridged, but a visible stretch at a cable's end uncovered: the end at a crossing drawn
    onto the other strand by the rim search (three), or stopping short of a diagonal tip
    the thinning ate."""
    score, _ = evaluate_scene(make_family_scene(family, seed), seed, mask_from_labels=True)
    assert score.frame.correct, score.frame.coverage


# --------------------------------------------------------------------------- kernel


@pytest.mark.parametrize("seed", range(3))
def test_extended_tip_kernel_equals_the_plain_extension_bit_for_bit(seed):
    # Bent polylines ending inside, short of, at the edge of and outside thick and thin
    # strokes, some running out of the picture: every end moved exactly as before.
    rng = np.random.default_rng(seed)
    moved = 0
    for _ in range(150):
        mask = np.zeros((80, 110), np.uint8)
        stroke = rng.uniform(-10, 120, (2, 2)).astype(int)
        width = int(rng.integers(3, 16))
        cv2.line(mask, tuple(map(int, stroke[0])), tuple(map(int, stroke[1])), 1, width)
        steps = rng.normal(size=(int(rng.integers(2, 12)), 2)) * 2.0 + (stroke[1] - stroke[0]) / 12
        points = stroke[0] + 5.0 * rng.normal(size=2) + np.cumsum(steps, axis=0)
        for at_start in (True, False):
            arguments = (points, at_start, mask > 0, 0.5 * width, float(rng.choice([8.0, 20.0])))
            fast, plain = extend_end(*arguments), reference.extend_end(*arguments)
            assert fast.shape == plain.shape and np.array_equal(fast, plain)
            moved += len(fast) > len(points)
    assert moved > 50  # both the walk and the rim search moved many ends


@pytest.mark.parametrize("seed", range(3))
def test_farthest_rim_ahead_equals_the_reference(seed):
    rng = np.random.default_rng(seed)
    found = 0
    for _ in range(100):
        mask = np.zeros((90, 120), np.uint8)
        for _ in range(3):
            start = tuple(int(v) for v in rng.integers(0, 120, 2))
            end = tuple(int(v) for v in rng.integers(0, 90, 2))
            cv2.line(mask, start, end, 1, int(rng.integers(5, 15)))
        rows, cols = np.nonzero(mask)
        pick = rng.integers(rows.size)
        tip = np.array([cols[pick], rows[pick]]) + rng.uniform(-0.4, 0.4, 2)
        direction = rng.normal(size=2)
        direction /= np.linalg.norm(direction)
        limit = float(rng.uniform(5, 40))
        fast = reference.compiled_farthest_ahead(tip, direction, mask > 0, limit)
        expected = reference.farthest_ahead(
            tip, direction, mask > 0, limit, TIP_SEARCH_COS, FAR_RIM_PX
        )
        assert (fast is None) == (expected is None)
        if fast is not None:
            np.testing.assert_allclose(fast, expected, rtol=0, atol=1e-9)
            found += 1
    assert found > 50
