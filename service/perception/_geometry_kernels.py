"""Compiled loops of :mod:`service.perception.geometry`: resampling, end fits and arc
lengths.

Plain version of the resampling and the arc lengths: ``tests/perception/references/geometry.py``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from service.perception._shared_kernels import pairwise_sum, solve_small

# The most a fitted stretch may turn (radians) in bend_aware_fit. Over half a turn of a
# tight loop, a quadratic in arc length puts the end several px off the cable and its
# direction tens of degrees off.
END_FIT_MAX_TURNING = np.pi / 2.0


@njit(cache=True, nogil=True)
def circle_exit(ax, ay, bx, by, cx, cy, step_sq):
    """Where, as a fraction of segment a-b in [0, 1], the circle of squared radius
    ``step_sq`` round (cx, cy) is left by a walk along the segment (the far root of the
    quadratic; 1 for a segment of no length)."""
    dx = bx - ax
    dy = by - ay
    fx = ax - cx
    fy = ay - cy
    qa = dx * dx + dy * dy
    qb = 2.0 * (fx * dx + fy * dy)
    qc = fx * fx + fy * fy - step_sq
    disc = max(qb * qb - 4.0 * qa * qc, 0.0)
    t = (-qb + np.sqrt(disc)) / (2.0 * qa) if qa > 0.0 else 1.0
    return min(max(t, 0.0), 1.0)


@njit(cache=True, nogil=True)
def resample_kernel(points, step):
    """The loop of geometry.resample in float64 (a correctly rounded square root)."""
    n = points.shape[0]
    step_sq = step * step
    capacity = 16
    joints = np.empty((capacity, 2), np.float64)
    edges = np.empty(capacity, np.int64)
    cx = points[0, 0]
    cy = points[0, 1]
    joints[0, 0] = cx
    joints[0, 1] = cy
    edges[0] = 0
    count = 1
    edge = 0
    while edge < n - 1:
        ax = points[edge, 0]
        ay = points[edge, 1]
        bx = points[edge + 1, 0]
        by = points[edge + 1, 1]
        if (bx - cx) ** 2 + (by - cy) ** 2 < step_sq:
            edge += 1
            continue
        t = circle_exit(ax, ay, bx, by, cx, cy, step_sq)
        cx = ax + t * (bx - ax)
        cy = ay + t * (by - ay)
        if count + 2 > capacity:
            capacity *= 2
            grown = np.empty((capacity, 2), np.float64)
            grown[:count] = joints[:count]
            joints = grown
            grown_edges = np.empty(capacity, np.int64)
            grown_edges[:count] = edges[:count]
            edges = grown_edges
        joints[count, 0] = cx
        joints[count, 1] = cy
        edges[count] = edge
        count += 1
    return joints[:count], edges[:count]


@njit(cache=True, nogil=True)
def end_fit(backwards, skip, span):
    """Quadratic least-squares fit of a polyline's last stretch (see geometry.end_tangent).

    ``backwards`` starts at the end. Returns ``(fitted, x0, y0, dx, dy, last, ddx,
    ddy)``: whether at least four points lie between ``skip`` and ``skip + span`` of arc
    length; the end position (the fit's value at arc length 0 when a stretch was
    skipped, else the first point); the fit's first-order coefficient; the index of the
    last point within ``span`` (for the chord fallback); and the fit's second derivative
    (per px squared).
    """
    n = backwards.shape[0]
    total = 0.0
    for i in range(1, n):
        total += np.hypot(
            backwards[i, 0] - backwards[i - 1, 0], backwards[i, 1] - backwards[i - 1, 1]
        )
    if total < 2.0 * skip + 1.0:
        skip = 0.0
    reach = skip + span
    # Normal equations in t = s / reach, which keeps them well conditioned.
    sums = np.zeros(5)
    rhs = np.zeros((3, 2))
    used = 0
    last = 0
    arc = 0.0
    for i in range(n):
        if i > 0:
            arc += np.hypot(
                backwards[i, 0] - backwards[i - 1, 0], backwards[i, 1] - backwards[i - 1, 1]
            )
        if arc <= span:
            last = i
        if arc > reach:
            break
        if arc >= skip:
            t = arc / reach if reach > 0 else 0.0
            power = 1.0
            for k in range(5):
                sums[k] += power
                if k < 3:
                    rhs[k, 0] += power * backwards[i, 0]
                    rhs[k, 1] += power * backwards[i, 1]
                power *= t
            used += 1
    last = max(last, 1)
    if used < 4:
        return False, backwards[0, 0], backwards[0, 1], 0.0, 0.0, last, 0.0, 0.0
    normal = np.empty((3, 3))
    for r in range(3):
        for c in range(3):
            normal[r, c] = sums[r + c]
    determinant, coefficients = solve_small(normal, rhs)
    if abs(determinant) < 1e-12:
        return False, backwards[0, 0], backwards[0, 1], 0.0, 0.0, last, 0.0, 0.0
    x0, y0 = backwards[0, 0], backwards[0, 1]
    if skip > 0:
        x0, y0 = coefficients[0, 0], coefficients[0, 1]
    return (
        True,
        x0,
        y0,
        coefficients[1, 0] / reach,
        coefficients[1, 1] / reach,
        last,
        2.0 * coefficients[2, 0] / (reach * reach),
        2.0 * coefficients[2, 1] / (reach * reach),
    )


@njit(cache=True, nogil=True)
def outward_fit(backwards, skip, span):
    """geometry.end_fit on a polyline that starts at the end (``backwards``): the end's
    position ``(x, y)``, its outward unit tangent ``(dx, dy)`` (zero for a polyline of
    no length) and the signed curvature of the fit (0 when the stretch was too short),
    bit for bit as the Python code finishes :func:`end_fit`'s coefficients."""
    fitted, x0, y0, dx, dy, last, ddx, ddy = end_fit(backwards, skip, span)
    # The linear term points inwards; outwards is its opposite.
    speed = np.hypot(dx, dy)
    curvature = 0.0
    if fitted and speed > 1e-9:
        curvature = -(dx * ddy - dy * ddx) / speed**3.0
        x = x0
        y = y0
        tangent_x = -dx
        tangent_y = -dy
    else:
        last = min(last, backwards.shape[0] - 1)  # a lone point has no direction
        x = backwards[0, 0]
        y = backwards[0, 1]
        tangent_x = backwards[0, 0] - backwards[last, 0]
        tangent_y = backwards[0, 1] - backwards[last, 1]
    norm = np.hypot(tangent_x, tangent_y)
    if norm > 1e-12:
        return x, y, tangent_x / norm, tangent_y / norm, curvature
    return x, y, 0.0, 0.0, curvature


@njit(cache=True, nogil=True)
def turning_within(backwards, skip, reach):
    """The signed turning (radians) of a polyline that starts at its end, summed over the
    vertices whose arc length from the end lies between ``skip`` and ``reach``."""
    arc = 0.0
    total = 0.0
    for i in range(1, backwards.shape[0] - 1):
        arc += np.hypot(
            backwards[i, 0] - backwards[i - 1, 0], backwards[i, 1] - backwards[i - 1, 1]
        )
        if arc > reach:
            break
        if arc < skip:
            continue
        ax = backwards[i, 0] - backwards[i - 1, 0]
        ay = backwards[i, 1] - backwards[i - 1, 1]
        bx = backwards[i + 1, 0] - backwards[i, 0]
        by = backwards[i + 1, 1] - backwards[i, 1]
        total += np.arctan2(ax * by - ay * bx, ax * bx + ay * by)
    return total


@njit(cache=True, nogil=True)
def bend_aware_fit(backwards, skip, span):
    """:func:`outward_fit` over a span short enough for the bend it lies on.

    While the polyline (starting at the end) turns by more than ``END_FIT_MAX_TURNING``
    between ``skip`` and ``skip + span`` the span is halved. On a tight loop that leaves
    too few joints for the quadratic, and the end is its tip, pointing along the chord
    to the last joint within the span: the stretch of cable nearest the end, which at a
    loop's own crossing runs nearly straight into it.
    """
    while span > 1.0 and abs(turning_within(backwards, skip, skip + span)) > END_FIT_MAX_TURNING:
        span *= 0.5
    return outward_fit(backwards, skip, span)


@njit(cache=True, nogil=True)
def step_lengths(points):
    """The length of each step of a float64 polyline, as NumPy computes it for
    geometry.polyline_length (the square root of the sum of the squares)."""
    count = max(points.shape[0] - 1, 0)
    lengths = np.empty(count, np.float64)
    for i in range(count):
        dx = points[i + 1, 0] - points[i, 0]
        dy = points[i + 1, 1] - points[i, 1]
        lengths[i] = np.sqrt(dx * dx + dy * dy)
    return lengths


@njit(cache=True, nogil=True)
def polyline_length(points):
    """geometry.polyline_length of an ``(N, 2)`` float64 polyline, bit for bit: the steps'
    lengths added in NumPy's order (:func:`pairwise_sum`)."""
    lengths = step_lengths(points)
    return pairwise_sum(lengths, 0, lengths.shape[0])


@njit(cache=True, nogil=True)
def arc_lengths(points):
    """geometry.arc_lengths of an ``(N, 2)`` float64 polyline, bit for bit (NumPy's
    cumulative sum adds one step after the other)."""
    lengths = step_lengths(points)
    arcs = np.empty(lengths.shape[0] + 1, np.float64)
    arcs[0] = 0.0
    total = 0.0
    for i in range(lengths.shape[0]):
        total += lengths[i]
        arcs[i + 1] = total
    return arcs
