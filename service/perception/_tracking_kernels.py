"""Compiled loops of the tracker (:mod:`service.perception.tracking` and its helpers).

Plain versions: ``tests/perception/references/tracking.py``.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def _nearest_on_segment(px, py, ax, ay, bx, by):
    """Squared distance from ``p`` to segment ``ab`` and the parameter (0-1) of the foot."""
    dx = bx - ax
    dy = by - ay
    length_sq = dx * dx + dy * dy
    t = 0.0
    if length_sq > 0.0:
        t = ((px - ax) * dx + (py - ay) * dy) / length_sq
        t = min(max(t, 0.0), 1.0)
    fx = ax + t * dx - px
    fy = ay + t * dy - py
    return fx * fx + fy * fy, t


@njit(cache=True, nogil=True)
def nearest_on_polylines(points, directions, joints, starts, counts, gate):
    """For every point and every polyline: distance, arc of the foot, direction cosine.

    Parameters
    ----------
    points, directions : (P, 2) float64
        Query points and their unit directions.
    joints : (M, 2) float64
        The polylines' vertices one after another; polyline ``t`` is
        ``joints[starts[t] : starts[t] + counts[t]]``.
    gate : (T,) float64
        Per polyline, the largest distance reported; beyond it the distance is ``inf``.

    Returns
    -------
    distance, arc, cosine : (P, T) float64
        ``arc`` is the foot's place along the polyline in vertex units (``k + t`` on
        the segment from vertex ``k`` to ``k + 1``: a track's joint numbers, whatever its
        spacing as predicted); ``cosine`` is
        the cosine between the point's direction and the segment's (signed). A point
        whose nearest point is an end of the polyline, and which lies beyond that end
        (not beside it), is not near: its distance is ``inf``.
    """
    n_points = points.shape[0]
    n_lines = starts.shape[0]
    distance = np.full((n_points, n_lines), np.inf)
    arc = np.zeros((n_points, n_lines))
    cosine = np.zeros((n_points, n_lines))
    for line in range(n_lines):
        first = starts[line]
        count = counts[line]
        gate_sq = gate[line] * gate[line]
        lengths = np.empty(max(count - 1, 0))
        for k in range(count - 1):
            dx = joints[first + k + 1, 0] - joints[first + k, 0]
            dy = joints[first + k + 1, 1] - joints[first + k, 1]
            lengths[k] = np.sqrt(dx * dx + dy * dy)
        for p in range(n_points):
            px = points[p, 0]
            py = points[p, 1]
            best = np.inf
            best_arc = 0.0
            best_segment = -1
            best_t = 0.0
            for k in range(count - 1):
                a = first + k
                d_sq, t = _nearest_on_segment(
                    px, py, joints[a, 0], joints[a, 1], joints[a + 1, 0], joints[a + 1, 1]
                )
                if d_sq < best:
                    best = d_sq
                    best_arc = k + t
                    best_segment = k
                    best_t = t
            beyond = (best_segment == 0 and best_t <= 0.0) or (
                best_segment == count - 2 and best_t >= 1.0
            )
            if best_segment >= 0 and best <= gate_sq and not beyond:
                distance[p, line] = np.sqrt(best)
                arc[p, line] = best_arc
                a = first + best_segment
                length = lengths[best_segment]
                if length > 0.0:
                    cosine[p, line] = (
                        directions[p, 0] * (joints[a + 1, 0] - joints[a, 0])
                        + directions[p, 1] * (joints[a + 1, 1] - joints[a, 1])
                    ) / length
    return distance, arc, cosine


@njit(cache=True, nogil=True)
def _segment_distance_sq(ax, ay, bx, by, cx, cy, ex, ey):
    """Squared distance between segments ``ab`` and ``ce`` (0 when they cross)."""
    # Proper intersection: the two segments straddle each other.
    d1 = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
    d2 = (bx - ax) * (ey - ay) - (by - ay) * (ex - ax)
    d3 = (ex - cx) * (ay - cy) - (ey - cy) * (ax - cx)
    d4 = (ex - cx) * (by - cy) - (ey - cy) * (bx - cx)
    if d1 * d2 < 0.0 and d3 * d4 < 0.0:
        return 0.0
    best, _ = _nearest_on_segment(ax, ay, cx, cy, ex, ey)
    value, _ = _nearest_on_segment(bx, by, cx, cy, ex, ey)
    best = min(best, value)
    value, _ = _nearest_on_segment(cx, cy, ax, ay, bx, by)
    best = min(best, value)
    value, _ = _nearest_on_segment(ex, ey, ax, ay, bx, by)
    return min(best, value)


@njit(cache=True, nogil=True)
def crowded_segments(joints, starts, counts, reach, self_gap):
    """Which segments of a set of chains come near another chain, or near their own.

    Segment ``k`` of chain ``c`` (joints ``k`` and ``k + 1`` of it) is crowded when a
    segment of another chain ``c'`` lies within ``reach[c] + reach[c']`` of it, or a
    segment of the same chain at least ``self_gap[c]`` segments away lies within
    ``2 * reach[c]``.

    Returns
    -------
    (S,) bool
        Per segment, chains one after another (chain ``c`` has ``counts[c] - 1``).
    """
    n_chains = starts.shape[0]
    total = 0
    for c in range(n_chains):
        total += max(counts[c] - 1, 0)
    chain_of = np.empty(total, np.int64)
    index_of = np.empty(total, np.int64)
    first_of = np.empty(total, np.int64)
    low_x = np.empty(total)
    high_x = np.empty(total)
    s = 0
    for c in range(n_chains):
        for k in range(counts[c] - 1):
            a = starts[c] + k
            chain_of[s] = c
            index_of[s] = k
            first_of[s] = a
            low_x[s] = min(joints[a, 0], joints[a + 1, 0])
            high_x[s] = max(joints[a, 0], joints[a + 1, 0])
            s += 1
    crowded = np.zeros(total, np.bool_)
    largest = 0.0
    for c in range(n_chains):
        largest = max(largest, reach[c])
    order = np.argsort(low_x)
    for i in range(total):
        si = order[i]
        ci = chain_of[si]
        for j in range(i + 1, total):
            sj = order[j]
            if low_x[sj] > high_x[si] + reach[ci] + largest:
                break
            cj = chain_of[sj]
            if ci == cj and abs(index_of[si] - index_of[sj]) < self_gap[ci]:
                continue
            limit = reach[ci] + reach[cj]
            a = first_of[si]
            b = first_of[sj]
            d_sq = _segment_distance_sq(
                joints[a, 0],
                joints[a, 1],
                joints[a + 1, 0],
                joints[a + 1, 1],
                joints[b, 0],
                joints[b, 1],
                joints[b + 1, 0],
                joints[b + 1, 1],
            )
            if d_sq <= limit * limit:
                crowded[si] = True
                crowded[sj] = True
    return crowded


@njit(cache=True, nogil=True)
def near_any_segment(points, reach, seg_starts, seg_ends):
    """Whether each point lies within ``reach[p]`` of one of the segments."""
    n_points = points.shape[0]
    near = np.zeros(n_points, np.bool_)
    for p in range(n_points):
        limit = reach[p] * reach[p]
        for s in range(seg_starts.shape[0]):
            d_sq, _ = _nearest_on_segment(
                points[p, 0],
                points[p, 1],
                seg_starts[s, 0],
                seg_starts[s, 1],
                seg_ends[s, 0],
                seg_ends[s, 1],
            )
            if d_sq <= limit:
                near[p] = True
                break
    return near


@njit(cache=True, nogil=True)
def constrain_chain(joints, inverse_mass, length, min_span, iterations, anchor):
    """Make consecutive joints exactly ``length`` apart, moving the light joints most.

    Position-based projection (Gauss-Seidel sweeps, alternating direction): each
    segment is brought to ``length`` by moving its two joints in proportion to their
    inverse masses; where ``min_span[k] > 0`` the joints either side of joint ``k`` are
    kept at least that far apart (a bending limit). Then one exact pass outwards from
    joint ``anchor`` puts every joint at exactly ``length`` from its neighbour, along the
    direction the sweeps left (the sweeps leave only a tiny residual to remove).

    Returns a new ``(N, 2)`` array.
    """
    x = joints.copy()
    n = x.shape[0]
    for iteration in range(iterations):
        for step in range(n - 1):
            k = step if iteration % 2 == 0 else n - 2 - step
            dx = x[k + 1, 0] - x[k, 0]
            dy = x[k + 1, 1] - x[k, 1]
            d = np.sqrt(dx * dx + dy * dy)
            w = inverse_mass[k] + inverse_mass[k + 1]
            if d > 1e-12 and w > 0.0:
                move = (d - length) / (d * w)
                x[k, 0] += inverse_mass[k] * move * dx
                x[k, 1] += inverse_mass[k] * move * dy
                x[k + 1, 0] -= inverse_mass[k + 1] * move * dx
                x[k + 1, 1] -= inverse_mass[k + 1] * move * dy
        for k in range(1, n - 1):
            if min_span[k] <= 0.0:
                continue
            dx = x[k + 1, 0] - x[k - 1, 0]
            dy = x[k + 1, 1] - x[k - 1, 1]
            d = np.sqrt(dx * dx + dy * dy)
            w = inverse_mass[k - 1] + inverse_mass[k + 1]
            if d < min_span[k] and d > 1e-12 and w > 0.0:
                move = (d - min_span[k]) / (d * w)
                x[k - 1, 0] += inverse_mass[k - 1] * move * dx
                x[k - 1, 1] += inverse_mass[k - 1] * move * dy
                x[k + 1, 0] -= inverse_mass[k + 1] * move * dx
                x[k + 1, 1] -= inverse_mass[k + 1] * move * dy
    for k in range(anchor, n - 1):
        _place_next(x, k, k + 1, length)
    for k in range(anchor, 0, -1):
        _place_next(x, k, k - 1, length)
    return x


@njit(cache=True, nogil=True)
def _place_next(x, fixed, moved, length):
    """Put joint ``moved`` exactly ``length`` from joint ``fixed``, keeping its direction."""
    dx = x[moved, 0] - x[fixed, 0]
    dy = x[moved, 1] - x[fixed, 1]
    d = np.sqrt(dx * dx + dy * dy)
    if d > 1e-12:
        x[moved, 0] = x[fixed, 0] + dx * (length / d)
        x[moved, 1] = x[fixed, 1] + dy * (length / d)
    else:  # coincident: continue straight along the chain
        x[moved, 0] = x[fixed, 0] + length
        x[moved, 1] = x[fixed, 1]
