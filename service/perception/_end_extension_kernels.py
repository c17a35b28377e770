"""Compiled loop of end extension (:mod:`service.perception.end_extension`).

Plain version: ``tests/perception/references/end_extension.py``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from service.perception._geometry_kernels import outward_fit
from service.perception._shared_kernels import ORTHOGONAL_FIRST_DC, ORTHOGONAL_FIRST_DR


@njit(cache=True, nogil=True)
def farthest_rim_ahead(mask, col, row, tip_x, tip_y, dir_x, dir_y, limit, cos_half_angle, rim):
    """The middle of the mask's farthest rim ahead of the tip: ``(found, x, y)``.

    The rim is the pixels at most ``limit`` px from the tip (``tip_x``, ``tip_y``; its
    pixel ``row``, ``col``), within the cone of ``cos_half_angle`` round the direction and
    connected to the tip through the mask near it, that lie within ``rim`` px of the
    largest such distance. Its middle, not its farthest pixel, so that the corners of a
    square-cut end do not pull the end sideways.

    The 8-connected component of the pixel (``row``, ``col``) is flood-filled within the
    square window of half size ceil(limit) round it, as cv2.connectedComponents on that
    window would label it.
    """
    height, width = mask.shape
    r = int(np.ceil(limit))
    x0 = max(col - r, 0)
    y0 = max(row - r, 0)
    x1 = min(col + r + 1, width)
    y1 = min(row + r + 1, height)
    if not (x0 <= col < x1 and y0 <= row < y1) or not mask[row, col]:
        return False, 0.0, 0.0
    w = x1 - x0
    h = y1 - y0
    seen = np.zeros((h, w), np.uint8)
    queue = np.empty(h * w, np.int64)
    queue[0] = (row - y0) * w + (col - x0)
    seen[row - y0, col - x0] = 1
    count = 1
    head = 0
    far = -1.0
    while head < count:
        qr = queue[head] // w
        qc = queue[head] - qr * w
        head += 1
        for k in range(8):
            rr = qr + ORTHOGONAL_FIRST_DR[k]
            cc = qc + ORTHOGONAL_FIRST_DC[k]
            if 0 <= rr < h and 0 <= cc < w and not seen[rr, cc] and mask[y0 + rr, x0 + cc]:
                seen[rr, cc] = 1
                queue[count] = rr * w + cc
                count += 1
    # Two passes over the component: the farthest distance in the cone, then the rim.
    for i in range(count):
        qr = queue[i] // w
        qc = queue[i] - qr * w
        vx = qc + x0 - tip_x
        vy = qr + y0 - tip_y
        dist = np.hypot(vx, vy)
        if 0 < dist <= limit and vx * dir_x + vy * dir_y >= cos_half_angle * dist:
            far = max(far, dist)
    if far < 0:
        return False, 0.0, 0.0
    sum_x = 0.0
    sum_y = 0.0
    n = 0
    for i in range(count):
        qr = queue[i] // w
        qc = queue[i] - qr * w
        vx = qc + x0 - tip_x
        vy = qr + y0 - tip_y
        dist = np.hypot(vx, vy)
        inside = 0 < dist <= limit and vx * dir_x + vy * dir_y >= cos_half_angle * dist
        if inside and dist >= far - rim:
            sum_x += vx
            sum_y += vy
            n += 1
    return True, tip_x + sum_x / n, tip_y + sum_y / n


@njit(cache=True, nogil=True)
def extended_tip(points, at_start, mask, radius, span, search_limit, cos_half_angle, rim):
    """end_extension.extend_end's new tip: ``(moved, x, y)``, ``moved`` False when the
    end would move by less than a pixel.

    The end's direction is geometry.end_direction's (the fit over ``span``); the walk
    from the tip takes 1 px steps along it while they stay on ``mask`` (``uint8``), each
    rounded as Python's ``round``, as far as the cable runs on straight ahead (a stretch
    thinning left without skeleton, a cable's short end past a crossing whose piece fell
    to spur removal); then, unless the walk left the picture, :func:`farthest_rim_ahead`
    within ``search_limit`` may carry the end further, and the tip comes one radius back
    inside.
    """
    height, width = mask.shape
    backwards = points if at_start else points[::-1]
    _, _, dir_x, dir_y, _ = outward_fit(backwards, 0.0, span)
    tip_x = backwards[0, 0]
    tip_y = backwards[0, 1]
    reach = 0.0
    leaves_image = False
    while True:
        col = int(np.rint(tip_x + (reach + 1.0) * dir_x))
        row = int(np.rint(tip_y + (reach + 1.0) * dir_y))
        if not (0 <= col < width and 0 <= row < height):
            leaves_image = True
            break
        if not mask[row, col]:
            break
        reach += 1.0
    extension = reach if leaves_image else reach - radius
    if not leaves_image:
        # A curving end, or one whose tip fork fell to spur removal, leaves the straight
        # walk through the side of the cap: the farthest pixel of the cable ahead marks
        # the end better.
        found, far_x, far_y = farthest_rim_ahead(
            mask,
            int(np.rint(tip_x)),
            int(np.rint(tip_y)),
            tip_x,
            tip_y,
            dir_x,
            dir_y,
            search_limit,
            cos_half_angle,
            rim,
        )
        if found:
            offset_x = far_x - tip_x
            offset_y = far_y - tip_y
            length = np.hypot(offset_x, offset_y)
            if length - radius > extension:
                dir_x = offset_x / length
                dir_y = offset_y / length
                extension = length - radius
    if extension < 1.0:
        return False, 0.0, 0.0
    return True, tip_x + extension * dir_x, tip_y + extension * dir_y
