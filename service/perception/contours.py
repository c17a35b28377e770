"""Step 3: contour extraction by Suzuki-Abe border following (OpenCV).

On a one-pixel-wide skeleton, the outer border of each component walks from a branch
tip along one side of every branch, turns back at each tip, and returns: every
skeleton pixel is visited, most of them twice. Closed loops of the skeleton also
produce a hole border. The later steps split and de-duplicate these walks.
"""

from __future__ import annotations

import cv2
import numpy as np


def extract_contours(skeleton: np.ndarray) -> list[np.ndarray]:
    """Step 3 of the pipeline: ordered pixel sequences along the skeleton.

    Parameters
    ----------
    skeleton : ndarray of bool
        One-pixel-wide skeleton.

    Returns
    -------
    list of ndarray
        One ``(N, 2)`` ``int32`` array of ``[x, y]`` pixels per border, outer borders
        and hole borders alike, in the order OpenCV follows them.
    """
    contours, _ = cv2.findContours(skeleton.astype(np.uint8), cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)
    return [contour.reshape(-1, 2) for contour in contours if len(contour) >= 2]
