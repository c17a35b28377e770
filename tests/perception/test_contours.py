"""Step 3, contours: Suzuki-Abe border following of the skeleton."""

import numpy as np

from service.perception.contours import extract_contours


def test_contours_of_a_skeleton_line_walk_out_and_back():
    skeleton = np.zeros((20, 60), bool)
    skeleton[10, 5:55] = True
    contours = extract_contours(skeleton)
    assert len(contours) == 1
    xs = contours[0][:, 0]
    assert xs.min() == 5 and xs.max() == 54
    assert len(contours[0]) == 2 * 50 - 2  # each pixel twice, the tips once
