"""Chain ends' colours for merging: the compiled sampling against the plain one."""

import cv2
import numpy as np
import pytest

from service.perception import appearance
from service.perception.merging import ChainEnd
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


def test_an_end_inside_an_object_segmented_with_the_cables_has_no_colour():
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
    # With the widths the samples stop at the box; without them the end's red is not
    # its piece's white further in. Either way the end has no colour of its own.
    for colours in (blind, seeing):
        assert list(colours.known) == [True, False, True, True]
        assert appearance.colour_penalty(colours, np.array([1]), np.array([2]))[0] == 0.0
    # The cable's own ends keep their colour: white against white.
    np.testing.assert_allclose(seeing.colour[0], seeing.colour[3], atol=3)
