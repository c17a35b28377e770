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


def test_contours_read_the_boolean_skeleton_as_its_bytes_as_a_copy_would():
    # A C-contiguous boolean skeleton is handed to OpenCV as its 0/1 bytes, without a
    # converted copy: the same contours as from the copy, and the skeleton unchanged
    # (also read-only, Fortran-ordered, sliced and integer skeletons).
    import cv2

    from service.perception.skeleton import skeletonize

    rng = np.random.default_rng(5)
    for trial in range(40):
        mask = np.zeros((60, 90), np.uint8)
        for _ in range(1 + trial % 5):
            points = rng.integers(-5, 95, size=(2, 2)).tolist()
            cv2.line(mask, tuple(points[0]), tuple(points[1]), 1, int(rng.integers(1, 9)))
        skeleton = skeletonize(mask)
        frozen = skeleton.copy()
        frozen.flags.writeable = False
        for image in (
            skeleton,
            frozen,
            np.asfortranarray(skeleton),
            skeleton[3:-2, 1:],
            skeleton * 3,
        ):
            before = np.array(image, copy=True)
            expected, _ = cv2.findContours(
                np.asarray(image).astype(np.uint8), cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE
            )
            expected = [c.reshape(-1, 2) for c in expected if len(c) >= 2]
            found = extract_contours(image)
            assert len(found) == len(expected)
            for a, b in zip(found, expected, strict=True):
                assert a.dtype == b.dtype
                np.testing.assert_array_equal(a, b)
            np.testing.assert_array_equal(image, before)
