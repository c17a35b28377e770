"""Compiled loop of :mod:`service.perception.bridge_ends`: where a crossing's bridge starts
from one of its ends (``bridge_ends.ends_clear_of_crossing``).

Plain version: ``tests/perception/references/bridge_ends.py``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from service.perception._geometry_kernels import END_FIT_MAX_TURNING, end_fit
from service.perception._shared_kernels import pairwise_sum

# What clear_of_crossing found for an end.
KEPT = 0
"""The end stays as it is."""
MOVED = 1
"""The bridge starts where the fit it returns begins."""
UNDECIDED = 2
"""The turning over a span lies within a hair (``TURNING_TIE``) of
``END_FIT_MAX_TURNING``: call again with NumPy's turns (``turns``)."""

# The C library's arctan2 (numba's) and NumPy's differ by an ulp (4.4e-16 at most) now
# and then. Over m joints, added in the same order, the two sums differ by at most m such
# ulps and m roundings of partial sums below m pi: under TURNING_TIE (m + 1)^2. Nearer the
# limit than that (as on pixel steps, whose 45-degree turns add up to 90 exactly), the
# kernel's own sum cannot tell on which side of it NumPy's lies.
TURNING_TIE = 1e-12


@njit(cache=True, nogil=True)
def clear_of_crossing(
    backwards, at_start, distance, width, narrow_at_most, end_skip, far_skip, span, turns
):
    """The loop of ``bridge_ends.ends_clear_of_crossing`` for one end, bit for bit.

    ``backwards`` is the piece from the end's tip inwards (``at_start``: the piece's own
    order); ``distance`` the mask's distance transform, widened at a joint whose value
    exceeds ``narrow_at_most``; ``width``, ``end_skip`` the end's half width and fitted
    tip, ``far_skip`` the other end's; ``span`` the fit's. ``turns``: the signed turn at
    each inner joint as NumPy computes them, or an empty array for the kernel's own.
    The arc lengths are summed in NumPy's order (``pairwise_sum``), as
    ``geometry.polyline_length`` sums them.

    Returns ``(outcome, skip, x0, y0, dx, dy, ddx, ddy)``: :data:`KEPT`, :data:`MOVED` or
    :data:`UNDECIDED`; for a moved end, the arc length to trim (where the bridge starts)
    and the end fit over the stretch beyond (``_geometry_kernels.end_fit``'s position
    and first and second derivatives), to evaluate at ``skip``.
    """
    n = backwards.shape[0]
    steps = max(n - 1, 0)
    # Step lengths from the tip inwards (sqrt of the squares, as polyline_length).
    lengths = np.empty(steps, np.float64)
    for i in range(steps):
        dx = backwards[i + 1, 0] - backwards[i, 0]
        dy = backwards[i + 1, 1] - backwards[i, 1]
        lengths[i] = np.sqrt(dx * dx + dy * dy)
    if at_start:
        length = pairwise_sum(lengths, 0, steps)
    else:
        # The piece's own length adds its steps in its order, the reverse of these.
        forward = lengths[::-1].copy()
        length = pairwise_sum(forward, 0, steps)
    if width <= 0.0 or length < span:
        return KEPT, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    # The widened tip: up to the first joint where the mask is the piece's own width.
    height, columns = distance.shape
    last = n - 1
    for i in range(n):
        row = min(max(int(np.rint(backwards[i, 1])), 0), height - 1)
        col = min(max(int(np.rint(backwards[i, 0])), 0), columns - 1)
        if distance[row, col] <= narrow_at_most:
            last = i
            break
    widened = pairwise_sum(lengths, 0, last) if last >= 1 else 0.0
    skip = end_skip
    if widened > skip:
        skip = widened
    # Like the end's own fit, the fit stops short of the other end's tip where that was
    # left out for being narrow (more than this end's usual tip), if half a span is left.
    reach = length - skip - far_skip
    if far_skip > end_skip and reach >= 0.5 * span and reach < span:
        span = reach
    if skip <= 0.0:
        return KEPT, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    # The span bend_aware_fit fits over: halved while the turns at the joints between
    # skip and skip + span of arc length add up to more than END_FIT_MAX_TURNING.
    joints = max(n - 2, 0)
    own = turns.shape[0] == 0
    turn = turns
    if own:
        turn = np.empty(joints, np.float64)
        for i in range(joints):
            ax = backwards[i + 1, 0] - backwards[i, 0]
            ay = backwards[i + 1, 1] - backwards[i, 1]
            bx = backwards[i + 2, 0] - backwards[i + 1, 0]
            by = backwards[i + 2, 1] - backwards[i + 1, 1]
            turn[i] = np.arctan2(ax * by - ay * bx, ax * bx + ay * by)
    inner = np.empty(joints, np.float64)  # arc length at joints 1 to n - 2
    arc = 0.0
    for i in range(joints):
        arc += np.hypot(
            backwards[i + 1, 0] - backwards[i, 0], backwards[i + 1, 1] - backwards[i, 1]
        )
        inner[i] = arc
    within = np.empty(joints, np.float64)
    while span > 1.0:
        count = 0
        for i in range(joints):
            if inner[i] >= skip and inner[i] <= skip + span:
                within[count] = turn[i]
                count += 1
        turning = abs(pairwise_sum(within, 0, count))
        if own and abs(turning - END_FIT_MAX_TURNING) <= TURNING_TIE * (count + 1) ** 2:
            return UNDECIDED, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
        if turning <= END_FIT_MAX_TURNING:
            break
        span *= 0.5
    fitted, x0, y0, dx, dy, _, ddx, ddy = end_fit(backwards, skip, span)
    if not fitted or pairwise_sum(lengths, 0, steps) < 2.0 * skip + 1.0:
        return KEPT, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    return MOVED, skip, x0, y0, dx, dy, ddx, ddy
