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
    skeleton = np.asarray(skeleton)
    # A C-contiguous boolean skeleton is read as the 0/1 bytes it is: OpenCV's border
    # following copies its input (it does not change it), so a converted copy of the
    # whole image first would only cost a pass over it.
    if skeleton.dtype == np.bool_ and skeleton.flags.c_contiguous:
        image = skeleton.view(np.uint8)
    else:
        image = skeleton.astype(np.uint8)
    contours, _ = cv2.findContours(image, cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)
    return [contour.reshape(-1, 2) for contour in contours if len(contour) >= 2]
