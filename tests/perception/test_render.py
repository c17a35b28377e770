"""Label and overlay images made from a detection."""

import cv2
import numpy as np

from schemas import Chain, Crossing, Detection
from service.perception import render_labels


def _crossing_bars():
    """A red horizontal bar (half width 5) over a green vertical one, as image and mask."""
    image = np.zeros((80, 80, 3), np.uint8)
    image[:, 35:46] = (40, 190, 40)  # green, underneath
    image[35:46, :] = (40, 40, 200)  # red, on top
    mask = image.any(axis=2)
    detection = Detection(
        width=80,
        height=80,
        segment_length=10,
        chains=[
            # Radii a pixel short of the bars' half width, as a median often is.
            Chain(
                id=0,
                points=[(x, 40.0) for x in range(0, 80, 10)] + [(79.0, 40.0)],
                radius=4.0,
                inferred=[False] * 8,
            ),
            Chain(
                id=1,
                points=[(40.0, y) for y in range(0, 80, 10)] + [(40.0, 79.0)],
                radius=4.0,
                inferred=[False] * 8,
            ),
        ],
        crossings=[
            Crossing(x=40, y=40, over=0, under=1, over_segment=4, under_segment=4, confidence=1.0)
        ],
    )
    return image, mask, detection


def test_labels_near_a_crossing_follow_the_cables_colours():
    image, mask, detection = _crossing_bars()
    geometric = render_labels(detection, mask)
    by_colour = render_labels(detection, mask, image)
    red = (image[:, :, 2] == 200) & mask
    green = (image[:, :, 1] == 190) & mask
    # The red bar's rim above the green bar goes to the green strand by geometry alone...
    assert (geometric[red] == 2).any()
    # ...and to the red strand by colour; no pixel changes away from the crossing.
    assert (by_colour[red] == 1).all()
    assert (by_colour[green] == 2).all()
    far = np.ones_like(mask)
    cv2.circle(far.view(np.uint8), (40, 40), 14, 0, -1)
    np.testing.assert_array_equal(by_colour[far], geometric[far])


def test_labels_keep_the_geometry_for_cables_of_one_colour_or_a_grey_image():
    image, mask, detection = _crossing_bars()
    grey = cv2.cvtColor(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY), cv2.COLOR_GRAY2BGR)
    np.testing.assert_array_equal(
        render_labels(detection, mask, grey), render_labels(detection, mask)
    )
    np.testing.assert_array_equal(
        render_labels(detection, mask, image[:, :, 0]), render_labels(detection, mask)
    )
