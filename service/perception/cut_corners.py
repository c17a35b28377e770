"""Where a cable passes out of sight at a cut: halfway between the two corners where its
borders meet the object's edge.

An object's straight edge crossing a cable leaves the visible end bounded by three runs of
the mask's border: the cable's one border, the object's edge, the cable's other border. The
cable's middle line crosses the edge halfway between the two corners (the two borders lie a
half width either side of it), at any slant and wherever the cable bends. The corners are
where the image shows them, whatever the direction read at the cut: a middle line carried on
past the cable's last full section along that direction (:func:`.cut_ends.carried_to_the_border`)
leaves the middle by the carry's length times the sine of the direction's error, and on a
tight bend into a hidden turn that error is 15-40 degrees (the fit lags the bend the cable
begins at the cut): the carried point lies up to a quarter width off the middle.

The mask alone does not say which of its border runs is the object's edge: a steep slant's
edge runs within 10-15 degrees of the border it cuts on a bend, and strands touching at the
cut join their masks (split into three straight runs by least squares, the border put the
point 4-8 px off the middle there: loops 480052, 480057). The image does, where the object
is not of the ground's colour: beyond the cable's borders lies the ground seen beside its
full sections, beyond the edge the object (:func:`.appearance.unlike_ground`'s test, as
:func:`.cut_ends.along_the_wedge` reads a wedge's borders).
"""

from __future__ import annotations

import cv2
import numpy as np

from service.perception import _shared_kernels
from service.perception.appearance import ground_beside, unlike_ground_at


def _straight_line_residual(points: np.ndarray) -> float:
    """Sum of squared distances of the (x, y) ``points`` to their best straight line
    (total least squares: the centred scatter matrix's smaller eigenvalue)."""
    centred = points - points.mean(axis=0)
    xx, yy = centred[:, 0] @ centred[:, 0], centred[:, 1] @ centred[:, 1]
    xy = centred[:, 0] @ centred[:, 1]
    return max(0.5 * (xx + yy) - float(np.sqrt((0.5 * (xx - yy)) ** 2 + xy * xy)), 0.0)


def _borders_either_side(
    mask: np.ndarray, origin: np.ndarray, normal: np.ndarray, steps: np.ndarray
) -> tuple[float, float]:
    """How far the mask's border lies from ``origin`` along the unit ``normal`` and
    against it (px, sampled at ``steps``; ``steps[-1]`` where none is read:
    :func:`._shared_kernels.border_distance`, as :func:`.cut_ends._border_distance`
    reads a section, which this module cannot import: cut_ends imports it)."""
    return tuple(
        float(
            _shared_kernels.border_distance(
                mask.view(np.uint8),
                float(origin[0]),
                float(origin[1]),
                float(sign * normal[0]),
                float(sign * normal[1]),
                steps,
                float(steps[-1]),
                0.5 * float(steps[0]),
                False,
            )
        )
        for sign in (1.0, -1.0)
    )


def _edge_seen(
    image: np.ndarray, mask: np.ndarray, arc: np.ndarray, bounds: list[int], beyond: float
) -> tuple[int, int] | None:
    """The first and last points of the border ``arc`` between ``bounds`` (its indices of
    the last full section's two border points) beyond which the BGR ``image`` shows
    something unlike the ground beside the cable (:func:`.appearance.unlike_ground_at`'s
    test, read ``beyond`` px out): the object's edge, its two ends the corners. The ground
    is what lies beyond the arc's stretches outside the bounds (the cable's own borders
    behind its last full section). None where the image does not show the edge: an
    object of the ground's colour, another cable beyond the border, or ground read
    between the edge's ends."""
    ahead = np.roll(arc, -1, axis=0) - np.roll(arc, 1, axis=0)
    ahead[0], ahead[-1] = arc[1] - arc[0], arc[-1] - arc[-2]
    length = np.hypot(*ahead.T)
    if not (length > 0.0).all():
        return None
    normal = np.column_stack([-ahead[:, 1], ahead[:, 0]]) / length[:, None]
    # The side of each border point the mask is not on.
    probe = arc + normal
    rows = np.clip(np.rint(probe[:, 1]).astype(np.int64), 0, mask.shape[0] - 1)
    cols = np.clip(np.rint(probe[:, 0]).astype(np.int64), 0, mask.shape[1] - 1)
    normal[mask[rows, cols]] *= -1.0
    outside = arc + (0.5 + beyond) * normal
    first, last = bounds
    ground = ground_beside(image, mask, outside[np.r_[0:first, last + 1 : len(arc)]])
    if ground is None:
        return None
    readable, unlike = unlike_ground_at(image, mask, outside[first : last + 1], ground)
    if not unlike.any():
        return None
    k = np.flatnonzero(unlike)
    i, j = int(k[0]), int(k[-1])
    if (readable[i : j + 1] & ~unlike[i : j + 1]).any():
        return None  # ground between the ends: no one edge
    return first + i, first + j


def between_the_corners(
    mask: np.ndarray,
    position: np.ndarray,
    direction: np.ndarray,
    half_width: float,
    reach: float,
    steps: np.ndarray,
    rounding: float,
    image: np.ndarray | None = None,
    beyond: float = 2.0,
) -> np.ndarray | None:
    """The point halfway between the two corners where the cable's borders meet the
    object's edge at the cut ahead of ``position`` (on the cable's middle at its last full
    section, heading out along ``direction``), or None where the BGR ``image`` does not
    show them.

    The mask's border is followed (:func:`cv2.findContours`, the outermost pixels' centres)
    from the cable's two borders, read across a section a half width (``half_width``) behind
    ``position`` (``steps``, px, the samples the sections are read at), round the cut ahead.
    The section at ``position`` (read across the two borders' own direction at the back
    section, not across ``direction``, which may lean off the cable by 30-40 degrees and
    put one of its border points on the edge) bounds the edge: its two border points are
    the cable's. Between them the edge is where the image shows, ``beyond`` px out,
    something unlike the ground beyond the borders behind (:func:`_edge_seen`); its two
    ends are the corners, and their midpoint is where the middle line crosses it.

    None without the image, where a border is not read across either section, the border
    from one side does not come round to the other within ``reach`` px of the back section
    (another strand touching the end, a crossing), the image shows no one edge (an object
    of the ground's colour), the edge is shorter than the cable's width less a pixel's
    ``rounding`` at each corner (a slanted edge is longer: the width over the slant's
    cosine) or further than that rounding from a straight line (root mean square), or the
    midpoint lies behind ``position``.
    """
    if image is None:
        return None  # nothing tells the edge from the borders
    position = np.asarray(position, np.float64)
    direction = np.asarray(direction, np.float64)
    normal = np.array([-direction[1], direction[0]])
    back = position - half_width * direction
    across = float(steps[-1])
    outs = _borders_either_side(mask, back, normal, steps)
    if max(outs) >= across:
        return None  # no border read on a side: the end runs into something else
    sides = [back + sign * out * normal for sign, out in zip((1.0, -1.0), outs, strict=True)]
    # The crop round the section, a pixel of background round it so that each border
    # followed closes within it.
    height, width = mask.shape
    span = reach + half_width + 2.0
    x0, y0 = (max(int(np.floor(value - span)), 0) for value in back)
    x1 = min(int(np.ceil(back[0] + span)) + 1, width)
    y1 = min(int(np.ceil(back[1] + span)) + 1, height)
    if x1 - x0 < 3 or y1 - y0 < 3:
        return None
    crop = np.zeros((y1 - y0 + 2, x1 - x0 + 2), np.uint8)
    crop[1:-1, 1:-1] = mask[y0:y1, x0:x1]
    contours, _ = cv2.findContours(crop, cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)
    offset = np.array([x0 - 1.0, y0 - 1.0])
    for contour in contours:
        border = contour.reshape(-1, 2).astype(np.float64) + offset
        # Each side's border point lies on the first sample off the mask: the outermost
        # pixels' centres within a pixel and a half of it.
        near = [np.hypot(*(border - side).T) for side in sides]
        ends = [int(np.argmin(distance)) for distance in near]
        if all(distance[k] <= 1.5 for distance, k in zip(near, ends, strict=True)):
            break
    else:
        return None
    first, last = ends
    # The border's two ways from one side to the other: the one round the cut runs ahead.
    ways = (
        np.concatenate([border[first:], border[:first]])[: (last - first) % len(border) + 1],
        np.concatenate([border[last:], border[:last]])[: (first - last) % len(border) + 1][::-1],
    )
    arc = max(ways, key=lambda way: float(np.mean((way - back) @ direction)))
    if float(np.hypot(*(arc - back).T).max()) > reach + half_width:
        return None  # the border runs on beyond the cut's reach: not the end of this cable
    # The section at ``position`` is the cable's last full one: its two border points
    # are the cable's borders, and the object's edge lies on the arc between them.
    # Read across the cable as its two borders run at the back section (the arc's two
    # ends, a half width of each), not across the direction given, which may lean off
    # the cable by 30-40 degrees and put a border point of the section on the edge.
    reach_back = np.hypot(*(arc - arc[0]).T) <= half_width
    left = arc[: max(int(np.argmin(reach_back)), 2)]
    reach_back = np.hypot(*(arc - arc[-1]).T) <= half_width
    right = arc[::-1][: max(int(np.argmin(reach_back[::-1])), 2)]
    along = (left[-1] - left[0]) + (right[-1] - right[0])
    if not np.hypot(*along) > 0.0:
        return None
    along = along / np.hypot(*along)
    across_cable = np.array([-along[1], along[0]])
    bounds = []
    outs = _borders_either_side(mask, position, across_cable, steps)
    for sign, out in zip((1.0, -1.0), outs, strict=True):
        distance = np.hypot(*(arc - (position + sign * out * across_cable)).T)
        if out >= across or distance.min() > 1.5:
            return None
        bounds.append(int(np.argmin(distance)))
    corners = _edge_seen(image, mask, arc, bounds, beyond)
    if corners is None:
        return None
    i, j = corners
    if np.hypot(*(arc[j] - arc[i])) < 2.0 * half_width - 2.0 * rounding:
        return None  # shorter than the cable is wide: no edge across it
    if _straight_line_residual(arc[i : j + 1]) > (j - i + 1) * rounding**2:
        return None  # no straight edge: an object's edge lies within a pixel of a line
    middle = 0.5 * (arc[corners[0]] + arc[corners[1]])
    if float((middle - position) @ direction) < 0.0:
        return None  # behind the last full section: no cut ahead read
    return middle
