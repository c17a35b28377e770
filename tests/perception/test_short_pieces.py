"""The ends of stubs, pieces shorter than the cable is wide
(:mod:`service.perception.short_pieces`)."""

import cv2
import numpy as np

from service.perception.merging import chain_ends
from service.perception.short_pieces import ends_of_stubs


def _stub_mask(cable: np.ndarray, half_width: float, cut: np.ndarray, half_length: float):
    """A cable through (100, 100) along unit ``cable`` seen between two straight cuts
    along unit ``cut``, ``2 half_length`` apart along the cable: a parallelogram."""
    across = np.array([-cable[1], cable[0]])
    # The cuts cross the cable's sides where the cut lines meet them.
    centre = np.array([100.0, 100.0])
    corners = []
    for along, side in ((-1, -1), (-1, 1), (1, 1), (1, -1)):
        point_on_side = centre + side * half_width * across
        # Solve point_on_side + s cable = centre + along half_length cable + t cut.
        matrix = np.stack([cable, -cut], axis=1)
        s, _ = np.linalg.solve(matrix, centre + along * half_length * cable - point_on_side)
        corners.append(point_on_side + s * cable)
    mask = np.zeros((200, 200), np.uint8)
    cv2.fillPoly(mask, [np.rint(np.array(corners)).astype(np.int32)], 1)
    return mask.astype(bool)


def test_a_stub_cut_at_a_slant_points_along_its_sides_not_its_skeleton():
    # A cable 16 px wide heading down-right at 52 degrees, seen for 10 px between two
    # cuts at a slant: the blob is about as long as wide and its skeleton runs along
    # the longer diagonal, across the cable.
    cable = np.array([np.cos(0.9), np.sin(0.9)])
    cut = np.array([np.cos(2.6), np.sin(2.6)])
    mask = _stub_mask(cable, 8.0, cut, 5.0)
    skeleton = np.array([[93.0, 103.0], [100.0, 100.0], [107.0, 97.0]])
    ends = chain_ends([skeleton], 40.0)
    assert abs(ends[1].direction @ cable) < 0.6  # the skeleton's reading is far off
    (start, end) = ends_of_stubs([skeleton], ends, mask, 8.0)
    assert abs(float(end.direction @ cable)) > np.cos(np.radians(5.0))
    np.testing.assert_allclose(start.direction, -end.direction)
    # The ends lie on the cable's middle line, where it leaves the blob.
    across = np.array([-cable[1], cable[0]])
    for point in (start.position, end.position):
        assert abs(float((point - 100.0) @ across)) < 1.5
    assert start.curvature == end.curvature == 0.0


def test_a_stub_touching_another_piece_or_a_longer_piece_keeps_its_ends():
    cable = np.array([np.cos(0.9), np.sin(0.9)])
    cut = np.array([np.cos(2.6), np.sin(2.6)])
    mask = _stub_mask(cable, 8.0, cut, 5.0)
    stub = np.array([[93.0, 103.0], [100.0, 100.0], [107.0, 97.0]])
    other = np.array([[104.0, 101.0], [105.0, 102.0], [106.0, 103.0]])  # in the same blob
    ends = chain_ends([stub, other], 40.0)
    assert ends_of_stubs([stub, other], ends, mask, 8.0) == ends
    long_piece = np.array([[60.0, 100.0], [100.0, 100.0], [140.0, 100.0]])
    ends = chain_ends([long_piece], 40.0)
    assert ends_of_stubs([long_piece], ends, mask, 8.0) == ends
