"""Plain search for the cable's farthest rim ahead of a chain end (end extension)."""

import cv2
import numpy as np


def farthest_ahead(tip, direction, mask, limit, cos_half_angle, rim):
    """The middle of the mask's farthest rim from ``tip``: the pixels at most ``limit``
    px away, within the cone of ``cos_half_angle`` round ``direction`` and connected to
    the tip through the mask near it, that lie within FAR_RIM_PX of the largest
    distance. None when there is none."""
    height, width = mask.shape
    r = int(np.ceil(limit))
    col, row = round(float(tip[0])), round(float(tip[1]))
    x0, y0 = max(col - r, 0), max(row - r, 0)
    x1, y1 = min(col + r + 1, width), min(row + r + 1, height)
    window = mask[y0:y1, x0:x1].astype(np.uint8)
    ty, tx = row - y0, col - x0
    if not (0 <= ty < window.shape[0] and 0 <= tx < window.shape[1]) or not window[ty, tx]:
        return None
    _, labels = cv2.connectedComponents(window, connectivity=8)
    ys, xs = np.nonzero(labels == labels[ty, tx])
    vx = xs + x0 - tip[0]
    vy = ys + y0 - tip[1]
    dist = np.hypot(vx, vy)
    ahead = vx * direction[0] + vy * direction[1] >= cos_half_angle * dist
    ok = (dist <= limit) & (dist > 0) & ahead
    if not ok.any():
        return None
    # The middle of the farthest rim, not one pixel of it: the corners of a square-cut
    # end are equally far and would pull the end sideways.
    far = ok & (dist >= dist[ok].max() - rim)
    return np.array([tip[0] + vx[far].mean(), tip[1] + vy[far].mean()])
