"""Inputs the perception tests share: hand-made masks, random masks and generated scenes."""

from pathlib import Path

import cv2
import numpy as np

from service.synthetic import make_scene

MBEST = Path(__file__).resolve().parents[3] / "shared" / "datasets" / "mbest"


def thick_polylines(shape, polylines, thickness) -> np.ndarray:
    """A boolean mask of the polylines (lists of ``(x, y)``) drawn ``thickness`` px wide."""
    mask = np.zeros(shape, np.uint8)
    for points in polylines:
        cv2.polylines(mask, [np.array(points, np.int32)], False, 1, thickness)
    return mask > 0


def random_mask(seed, shape=(150, 200)):
    """Random thick strokes and rings, with pinholes and specks, some off the edges."""
    rng = np.random.default_rng(seed)
    height, width = shape
    mask = np.zeros(shape, np.uint8)
    for _ in range(5):
        points = rng.integers(-15, [width + 15, height + 15], size=(rng.integers(2, 5), 2))
        cv2.polylines(
            mask, [points.astype(np.int32)], bool(rng.integers(0, 2)), 1, int(rng.integers(2, 18))
        )
    centre = tuple(int(v) for v in rng.integers(0, [width, height]))
    cv2.circle(mask, centre, int(rng.integers(8, 40)), 1, int(rng.integers(2, 9)))
    near = cv2.dilate(mask, np.ones((3, 3), np.uint8)) > 0
    return (mask > 0) ^ (near & (rng.random(shape) < 0.02))


def speckled_mask(seed, shape=(90, 120)):
    rng = np.random.default_rng(seed)
    mask = cv2.dilate((rng.random(shape) < 0.02).astype(np.uint8), np.ones((7, 7), np.uint8))
    mask[rng.random(shape) < 0.08] ^= 1  # specks and holes, some on the border
    mask[0, rng.integers(0, shape[1], 5)] = 1
    return mask > 0


def _inputs():
    shape = (120, 160)
    cases = {
        "band": thick_polylines(shape, [[(10, 60), (150, 60)]], 11),
        "cross": thick_polylines(shape, [[(10, 20), (150, 100)], [(10, 100), (150, 20)]], 9),
        "ragged": thick_polylines(shape, [[(5, 30), (155, 35)], [(80, 30), (80, 118)]], 7)
        | thick_polylines(shape, [[(40, 30), (43, 24)], [(120, 35), (122, 42)]], 3),
        "loop": thick_polylines(shape, [[(20, 100), (80, 10), (140, 100), (20, 40)]], 8),
        "edges": thick_polylines(shape, [[(-5, 0), (165, 119)], [(0, 119), (159, 0)]], 6),
        "block": np.pad(np.ones((40, 60), bool), 20),
        "speck": np.pad(np.ones((1, 1), bool), 3),
        "empty": np.zeros((20, 30), bool),
    }
    for seed in range(6):
        cases[f"random{seed}"] = random_mask(seed)
    for seed, (width, height, n) in enumerate([(200, 150, 2), (256, 192, 3), (320, 240, 3)]):
        cases[f"scene{seed}"] = make_scene(width, height, n, seed=seed, radius_range=(3, 6)).mask
    return cases


INPUTS = _inputs()


def assert_same_chains(fast, reference) -> None:
    """The same chains: as many, in the same order, with identical joints and dtype."""
    assert len(fast) == len(reference)
    for a, b in zip(fast, reference, strict=True):
        assert a.dtype == b.dtype and a.shape == b.shape
        np.testing.assert_array_equal(a, b)
