"""Compiled loops of the tracker (:mod:`service.perception.tracking` and its helpers).

Plain versions: ``tests/perception/references/tracking.py``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from service.perception._geometry_kernels import circle_exit
from service.perception._shared_kernels import pairwise_sum


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


@njit(cache=True, nogil=True)
def fit_statistics(
    distance, arc, cosine, sample_arc, starts, counts, gates, min_cosine, track_lengths
):
    """How each piece lies along each track, from its samples' projections.

    Piece ``p`` owns samples ``starts[p] : starts[p] + counts[p]`` (rows of the ``(S, T)``
    projection arrays of :func:`nearest_on_polylines`, ``arc`` in px); ``sample_arc`` is
    each sample's arc along its piece. A sample is near a track when its distance is
    finite and the directions agree (``|cosine| >= min_cosine``). ``track_lengths``: per
    track, its length (px). Per piece and track:

    ok
        At least 3 samples are near, and half of as many as the shorter of the piece and
        the track can hold (a piece longer than its track, at an end coming into view,
        overlaps it by the track's length at most), and their offsets agree (median
        spread at most half the piece's length).
    sign
        +1 when the piece runs along the track's direction, -1 against it.
    offset
        Median over the near samples of ``arc - sign * sample_arc``.
    cost
        Mean distance of the near samples + (1 - near share) * gate + spread / 4.
    share
        The near share.
    """
    n_pieces = starts.shape[0]
    n_tracks = gates.shape[0]
    ok = np.zeros((n_pieces, n_tracks), np.bool_)
    sign = np.ones((n_pieces, n_tracks), np.int64)
    offset = np.zeros((n_pieces, n_tracks))
    cost = np.full((n_pieces, n_tracks), np.inf)
    share = np.zeros((n_pieces, n_tracks))
    for p in range(n_pieces):
        first = starts[p]
        count = counts[p]
        length = sample_arc[first + count - 1]
        values = np.empty(count)
        for t in range(n_tracks):
            near = 0
            cos_sum = 0.0
            distance_sum = 0.0
            for i in range(first, first + count):
                if np.isfinite(distance[i, t]) and abs(cosine[i, t]) >= min_cosine:
                    near += 1
                    cos_sum += cosine[i, t]
                    distance_sum += distance[i, t]
            # Samples of the piece a stretch of the track's length holds.
            along_track = (count - 1) * track_lengths[t] / max(length, 1e-9) + 1.0
            if near < 3 or near < 0.5 * min(count, along_track):
                continue
            direction = 1 if cos_sum >= 0.0 else -1
            k = 0
            for i in range(first, first + count):
                if np.isfinite(distance[i, t]) and abs(cosine[i, t]) >= min_cosine:
                    values[k] = arc[i, t] - direction * sample_arc[i]
                    k += 1
            middle = np.median(values[:near])
            for i in range(near):
                values[i] = abs(values[i] - middle)
            spread = np.median(values[:near])
            if spread > 0.5 * max(length, 1.0):
                continue
            ok[p, t] = True
            sign[p, t] = direction
            offset[p, t] = middle
            share[p, t] = near / count
            cost[p, t] = distance_sum / near + (1.0 - near / count) * gates[t] + 0.25 * spread
    return ok, sign, offset, cost, share


@njit(cache=True, nogil=True)
def _locate(arcs, at):
    """The segment of a polyline (vertices at ``arcs``) holding arc ``at``, and the
    fraction along it (clamped to the polyline)."""
    n = arcs.shape[0]
    if at <= arcs[0]:
        return 0, 0.0
    if at >= arcs[n - 1]:
        return n - 2, 1.0
    lo = 0
    hi = n - 1
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if arcs[mid] <= at:
            lo = mid
        else:
            hi = mid
    span = arcs[lo + 1] - arcs[lo]
    return lo, (at - arcs[lo]) / span if span > 0.0 else 0.0


@njit(cache=True, nogil=True)
def refine_offset(joints, points, arcs, sign, offset, step, iterations):
    """Least-squares offset laying a piece's arc along a track's joints (Gauss-Newton).

    Joint ``k`` sits at piece arc ``sign * (k * step - offset)``; each iteration moves the
    offset by the mean, over the joints that fall on the piece, of their residual along
    the piece (so that the residuals along it balance).
    """
    n = joints.shape[0]
    length = arcs[arcs.shape[0] - 1]
    for _ in range(iterations):
        total = 0.0
        count = 0
        for k in range(n):
            u = sign * (k * step - offset)
            if u < 0.0 or u > length:
                continue
            s, f = _locate(arcs, u)
            dx = points[s + 1, 0] - points[s, 0]
            dy = points[s + 1, 1] - points[s, 1]
            norm = np.sqrt(dx * dx + dy * dy)
            if norm <= 0.0:
                continue
            px = points[s, 0] + f * dx
            py = points[s, 1] + f * dy
            total += ((joints[k, 0] - px) * dx + (joints[k, 1] - py) * dy) / norm
            count += 1
        if count < 2:
            break
        offset -= sign * total / count
    return offset


@njit(cache=True, nogil=True)
def chord_walk(points, arcs, start, sign, step, limit):
    """Up to ``limit`` points along a polyline from arc ``start``, forwards (``sign`` 1)
    or backwards, each exactly ``step`` in a straight line from the one before (a
    track's spacing), the first at ``start`` itself."""
    n = points.shape[0]
    out = np.empty((max(limit, 1), 2))
    s, f = _locate(arcs, start)
    cx = points[s, 0] + f * (points[s + 1, 0] - points[s, 0])
    cy = points[s, 1] + f * (points[s + 1, 1] - points[s, 1])
    out[0, 0] = cx
    out[0, 1] = cy
    count = 1
    # The vertex to walk towards next.
    vertex = s + 1 if sign > 0 else (s if f > 0.0 else s - 1)
    ax = cx
    ay = cy
    step_sq = step * step
    while count < limit and 0 <= vertex < n:
        bx = points[vertex, 0]
        by = points[vertex, 1]
        if (bx - cx) ** 2 + (by - cy) ** 2 < step_sq:
            ax = bx
            ay = by
            vertex += 1 if sign > 0 else -1
            continue
        # Where the circle of radius step round the last point leaves segment a-b.
        t = circle_exit(ax, ay, bx, by, cx, cy, step_sq)
        cx = ax + t * (bx - ax)
        cy = ay + t * (by - ay)
        ax = cx
        ay = cy
        out[count, 0] = cx
        out[count, 1] = cy
        count += 1
    return out[:count]


@njit(cache=True, nogil=True)
def window_medians(values, width):
    """Per window of ``width`` consecutive rows of ``values`` (N, C) float64, the median
    of each column over the rows that are not NaN (NaN where none is): ``np.nanmedian``
    over each window, the mean of the two middle values of an even count."""
    n_rows, n_columns = values.shape
    n_windows = max(n_rows - width + 1, 0)
    out = np.empty((n_windows, n_columns))
    ordered = np.empty(width)
    for window in range(n_windows):
        for column in range(n_columns):
            count = 0
            for row in range(window, window + width):
                value = values[row, column]
                if value != value:
                    continue  # NaN
                # Insertion into the sorted values so far.
                at = count
                while at > 0 and ordered[at - 1] > value:
                    ordered[at] = ordered[at - 1]
                    at -= 1
                ordered[at] = value
                count += 1
            if count == 0:
                out[window, column] = np.nan
            else:
                out[window, column] = 0.5 * (ordered[(count - 1) // 2] + ordered[count // 2])
    return out


@njit(cache=True, nogil=True)
def rigid_sums(source, target):
    """What the least-squares rotation taking ``source`` onto ``target`` (paired (N, 2)
    float64 points, N >= 1) is made of: ``[source mean x, y, target mean x, y, sum of
    the centred pairs' cross products, sum of their dot products]``, each as NumPy
    computes it in :func:`service.perception.geometry.rigid_fit` (the same bits)."""
    n = len(source)
    sx = sy = tx = ty = 0.0
    for i in range(n):
        sx += source[i, 0]
        sy += source[i, 1]
        tx += target[i, 0]
        ty += target[i, 1]
    sx /= n
    sy /= n
    tx /= n
    ty /= n
    cross = np.empty(n)
    dots = np.empty(2 * n)
    for i in range(n):
        a0 = source[i, 0] - sx
        a1 = source[i, 1] - sy
        b0 = target[i, 0] - tx
        b1 = target[i, 1] - ty
        cross[i] = a0 * b1 - a1 * b0
        dots[2 * i] = a0 * b0
        dots[2 * i + 1] = a1 * b1
    out = np.empty(6)
    out[0] = sx
    out[1] = sy
    out[2] = tx
    out[3] = ty
    out[4] = 0.0 + pairwise_sum(cross, 0, n)
    out[5] = 0.0 + pairwise_sum(dots, 0, 2 * n)
    return out


@njit(cache=True, nogil=True)
def motion_design(previous, current, use, tangent):
    """The cross-cable least-squares problem of
    :func:`service.perception.track_motion.motion`, as it computes it with NumPy (the
    same bits): per joint the normal, the displacement across the cable and the arm
    turned a right angle about the used joints' centre; the used joints' design rows
    ``[normal x, normal y, turned . normal]`` and values; and the arms' RMS (at least 1).
    """
    n = len(previous)
    normal = np.empty((n, 2))
    across = np.empty(n)
    count = 0
    cx = cy = 0.0
    for i in range(n):
        normal[i, 0] = -tangent[i, 1]
        normal[i, 1] = tangent[i, 0]
        across[i] = (current[i, 0] - previous[i, 0]) * normal[i, 0] + (
            current[i, 1] - previous[i, 1]
        ) * normal[i, 1]
        if use[i]:
            cx += previous[i, 0]
            cy += previous[i, 1]
            count += 1
    cx /= count
    cy /= count
    turned = np.empty((n, 2))
    rows = np.empty((count, 3))
    values = np.empty(count)
    arm_sq = np.empty(count)
    k = 0
    for i in range(n):
        ax = previous[i, 0] - cx
        ay = previous[i, 1] - cy
        turned[i, 0] = -ay
        turned[i, 1] = ax
        if use[i]:
            rows[k, 0] = normal[i, 0]
            rows[k, 1] = normal[i, 1]
            rows[k, 2] = turned[i, 0] * normal[i, 0] + turned[i, 1] * normal[i, 1]
            values[k] = across[i]
            arm_sq[k] = ax * ax + ay * ay
            k += 1
    scale = max(np.sqrt((0.0 + pairwise_sum(arm_sq, 0, count)) / count), 1.0)
    return normal, across, turned, rows, values, scale


@njit(cache=True, nogil=True)
def motion_result(fitted, turned, across, normal, rigid_only, weights):
    """Each joint's displacement from the rigid motion ``fitted`` (``tx, ty, rotation``)
    and the cross-cable remainder smoothed along the cable with ``weights`` (five, two
    neighbours each side, the ends repeated); the joints in ``rigid_only`` get the rigid
    motion alone: the end of :func:`service.perception.track_motion.motion`, the same
    bits as its NumPy."""
    n = len(turned)
    rigid = np.empty((n, 2))
    remainder = np.empty(n)
    for i in range(n):
        rigid[i, 0] = fitted[0] + fitted[2] * turned[i, 0]
        rigid[i, 1] = fitted[1] + fitted[2] * turned[i, 1]
        remainder[i] = across[i] - (rigid[i, 0] * normal[i, 0] + rigid[i, 1] * normal[i, 1])
    smoothed = remainder.copy()
    if n >= 3:
        for i in range(n):
            total = 0.0
            for j in range(5):
                at = min(max(i + j - 2, 0), n - 1)
                total = total + weights[j] * remainder[at]
            smoothed[i] = total
    result = np.empty((n, 2))
    for i in range(n):
        if rigid_only[i]:
            result[i, 0] = rigid[i, 0]
            result[i, 1] = rigid[i, 1]
        else:
            result[i, 0] = rigid[i, 0] + smoothed[i] * normal[i, 0]
            result[i, 1] = rigid[i, 1] + smoothed[i] * normal[i, 1]
    return result


@njit(cache=True, nogil=True)
def piece_samples(joints):
    """A piece's joints (N >= 2, float64) and segment midpoints in order, their unit
    directions (a joint's: the mean of its segments', normalised; an end's: its
    segment's), and their arcs in joint units: what
    :func:`service.perception.track_matching._samples` computed with NumPy, the same
    bits."""
    n = len(joints)
    points = np.empty((2 * n - 1, 2))
    directions = np.empty((2 * n - 1, 2))
    arc = np.empty(2 * n - 1)
    arc[0] = 0.0
    total = 0.0
    for k in range(n):
        points[2 * k, 0] = joints[k, 0]
        points[2 * k, 1] = joints[k, 1]
    for k in range(n - 1):
        points[2 * k + 1, 0] = 0.5 * (joints[k, 0] + joints[k + 1, 0])
        points[2 * k + 1, 1] = 0.5 * (joints[k, 1] + joints[k + 1, 1])
        dx = joints[k + 1, 0] - joints[k, 0]
        dy = joints[k + 1, 1] - joints[k, 1]
        length = np.sqrt(dx * dx + dy * dy)
        size = max(length, 1e-12)
        directions[2 * k + 1, 0] = dx / size
        directions[2 * k + 1, 1] = dy / size
        half = length / 2.0
        total += half
        arc[2 * k + 1] = total
        total += half
        arc[2 * k + 2] = total
    directions[0, 0] = directions[1, 0]
    directions[0, 1] = directions[1, 1]
    directions[2 * n - 2, 0] = directions[2 * n - 3, 0]
    directions[2 * n - 2, 1] = directions[2 * n - 3, 1]
    for k in range(1, n - 1):
        ix = directions[2 * k - 1, 0] + directions[2 * k + 1, 0]
        iy = directions[2 * k - 1, 1] + directions[2 * k + 1, 1]
        size = max(np.sqrt(ix * ix + iy * iy), 1e-12)
        directions[2 * k, 0] = ix / size
        directions[2 * k, 1] = iy / size
    return points, directions, arc


@njit(cache=True, nogil=True)
def farthest_from_polyline(points, polyline):
    """The largest of the points' distances (px) from a polyline of two vertices or more
    (each point's nearest segment): ``geometry.distances_to_polyline(points,
    polyline).max()``, the same bits, without its (points, segments) arrays."""
    farthest = -np.inf
    for i in range(len(points)):
        nearest = np.inf
        for k in range(len(polyline) - 1):
            ax = polyline[k, 0]
            ay = polyline[k, 1]
            abx = polyline[k + 1, 0] - ax
            aby = polyline[k + 1, 1] - ay
            apx = points[i, 0] - ax
            apy = points[i, 1] - ay
            t = (apx * abx + apy * aby) / max(abx * abx + aby * aby, 1e-12)
            t = min(max(t, 0.0), 1.0)
            gx = apx - t * abx
            gy = apy - t * aby
            nearest = min(nearest, np.sqrt(gx * gx + gy * gy))
        farthest = max(farthest, nearest)
    return farthest


@njit(cache=True, nogil=True)
def unit_tangents(joints):
    """Unit tangents at the joints (N >= 2, float64): central differences, one-sided at
    the ends; :func:`service.perception.track_motion.tangents`, the same bits."""
    n = len(joints)
    tangent = np.empty((n, 2))
    for i in range(n):
        if i == 0:
            tx = joints[1, 0] - joints[0, 0]
            ty = joints[1, 1] - joints[0, 1]
        elif i == n - 1:
            tx = joints[n - 1, 0] - joints[n - 2, 0]
            ty = joints[n - 1, 1] - joints[n - 2, 1]
        else:
            tx = (joints[i + 1, 0] - joints[i - 1, 0]) / 2.0
            ty = (joints[i + 1, 1] - joints[i - 1, 1]) / 2.0
        size = max(np.sqrt(tx * tx + ty * ty), 1e-12)
        tangent[i, 0] = tx / size
        tangent[i, 1] = ty / size
    return tangent
