"""Objects lying on the cables: compact blobs far wider than the lines, taken out of the mask."""

import cv2
import numpy as np

from schemas import DetectParams
from service.perception.objects import distance_and_ridges, object_blobs, without_objects
from service.perception.segmentation import segment
from service.synthetic.families import make_family_scene
from service.synthetic.family_occluders import Polygon
from tests.perception.references import segmentation as reference


def _cable(mask, points, radius):
    cv2.polylines(mask, [np.asarray(points, np.int32)], False, 1, 2 * radius + 1)


def test_a_box_on_a_cable_is_taken_out_and_the_cable_cut_at_its_border():
    mask = np.zeros((120, 240), np.uint8)
    _cable(mask, [(0, 60), (239, 60)], 3)
    mask[35:85, 95:145] = 1  # a box 50 px square over the cable
    out = without_objects(mask.astype(bool), 120)
    assert not out[35:85, 95:145].any()
    # The cable keeps its full width to within a few px of the box (the corners' disc
    # bites a shallow cap off its front), on both sides.
    assert out[57:64, :90].all() and out[57:64, 150:].all()
    assert out[60, 92] and out[60, 147]


def test_a_box_whose_corner_a_cable_runs_in_beside_leaves_no_wedge():
    # The cable (rows 45-53) enters 5 px from the box's corner (row 40): the opening's
    # disc misses the corner, which would hang on the cable's side as a wedge (56 px
    # without the corners' disc).
    mask = np.zeros((140, 240), np.uint8)
    _cable(mask, [(0, 49), (239, 49)], 3)
    mask[40:110, 90:160] = 1
    out = without_objects(mask.astype(bool), 120)
    assert not out[40:45].any()
    assert not out[55:110, 90:160].any()
    assert out[45:54, :86].all() and out[45:54, 164:].all()


def test_lines_crossing_touching_and_a_thick_cable_are_not_objects():
    mask = np.zeros((200, 400), np.uint8)
    _cable(mask, [(0, 30), (399, 30)], 4)
    _cable(mask, [(0, 39), (399, 39)], 4)  # touching the first along its length
    _cable(mask, [(0, 100), (399, 125)], 4)  # a shallow crossing (about 7 degrees) ...
    _cable(mask, [(0, 125), (399, 100)], 4)
    _cable(mask, [(60, 199), (340, 150)], 9)  # a cable twice as thick as the rest
    assert not object_blobs(mask.astype(bool)).any()


def test_a_disc_as_wide_as_two_cables_lying_together_is_left():
    # Nothing tells a blob this narrow from two strands side by side: left to merging.
    mask = np.zeros((120, 240), np.uint8)
    _cable(mask, [(0, 60), (239, 60)], 4)
    cv2.circle(mask, (120, 60), 9, 1, -1)
    assert not object_blobs(mask.astype(bool)).any()


def test_objects_on_a_tuning_scene_are_taken_out_of_the_brightness_mask():
    # occluded 330018: a bright box and a disc over a cable on a dark table; the
    # threshold kept both whole with the cable (end to end, two wrong hidden stretches).
    scene = make_family_scene("occluded", 330018)
    mask = segment(scene.image, DetectParams())
    height, width = mask.shape
    rows, cols = np.mgrid[0:height, 0:width]
    pixels = np.column_stack([cols.ravel(), rows.ravel()]).astype(float)
    for occluder in scene.occluders:
        if occluder.like_background:
            continue
        inside = (Polygon(np.asarray(occluder.polygon)).signed_distance(pixels) <= 0).reshape(
            height, width
        )
        assert mask[inside].mean() < 0.02
    assert (mask & scene.mask).sum() > 0.99 * scene.mask.sum()


def test_the_distances_ridges_read_in_the_chamfer_pass_equal_the_plain_reading():
    # Lines of every width (ridges one or two pixels wide, plateaus), noise masks,
    # masks touching the image's border and images of one to three rows or columns.
    rng = np.random.default_rng(5)
    masks = [np.zeros((0, 4), bool), np.zeros((5, 5), bool), np.ones((6, 9), bool)]
    for shape in ((1, 7), (7, 1), (2, 5), (3, 3), (3, 8), (8, 3)):
        masks.append(rng.random(shape) < 0.7)
    for _ in range(40):
        mask = np.zeros(rng.integers(20, 90, 2), np.uint8)
        for _ in range(3):
            x0, y0, x1, y1 = (int(v) for v in rng.integers(-10, 100, 4))
            cv2.line(mask, (x0, y0), (x1, y1), 1, int(rng.integers(1, 16)))
        masks.append(mask > 0)
        masks.append(rng.random(mask.shape) < rng.uniform(0.3, 0.95))
    for mask in masks:
        distance, (values, largest) = distance_and_ridges(mask)
        np.testing.assert_array_equal(
            distance, cv2.distanceTransform(mask.view(np.uint8), cv2.DIST_L2, 5)
        )
        expected, expected_largest = reference.ridges(distance, mask)
        assert values.dtype == np.float32
        np.testing.assert_array_equal(values, expected)
        assert largest == expected_largest
