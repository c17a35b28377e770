"""Plain end extension: one end's new tip (the code ``_end_extension_kernels.extended_tip``
replaced, with the compiled rim search it called) and the search for the cable's farthest
rim ahead of a chain end."""

import cv2
import numpy as np

from service.perception import _end_extension_kernels, end_extension
from service.perception.geometry import end_direction


def extend_end(points, at_start, mask, radius, span):
    """:func:`service.perception.end_extension.extend_end` step by step in Python."""
    direction = end_direction(points, at_start, span)
    tip = points[0] if at_start else points[-1]
    height, width = mask.shape
    reach = 0.0
    leaves_image = False
    while True:
        probe = tip + (reach + 1.0) * direction
        col, row = round(probe[0]), round(probe[1])
        if not (0 <= col < width and 0 <= row < height):
            leaves_image = True
            break
        if not mask[row, col]:
            break
        reach += 1.0
    extension = reach if leaves_image else reach - radius
    if not leaves_image:
        far = compiled_farthest_ahead(
            tip, direction, mask, end_extension.TIP_SEARCH_RADII * radius + 2.0
        )
        if far is not None:
            offset = far - tip
            length = float(np.hypot(*offset))
            if length - radius > extension:
                direction = offset / length
                extension = length - radius
    if extension < 1.0:
        return points
    new_tip = tip + extension * direction
    return np.vstack([new_tip, points]) if at_start else np.vstack([points, new_tip])


def compiled_farthest_ahead(tip, direction, mask, limit):
    """``_end_extension_kernels.farthest_rim_ahead`` as extend_end called it: the middle of
    the farthest rim, or None (its mean is summed otherwise than :func:`farthest_ahead`'s,
    so the two agree to about 1e-12 px, not bit for bit)."""
    found, x, y = _end_extension_kernels.farthest_rim_ahead(
        np.ascontiguousarray(mask).view(np.uint8),
        round(float(tip[0])),
        round(float(tip[1])),
        float(tip[0]),
        float(tip[1]),
        float(direction[0]),
        float(direction[1]),
        float(limit),
        end_extension.TIP_SEARCH_COS,
        end_extension.FAR_RIM_PX,
    )
    return np.array([x, y]) if found else None


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
