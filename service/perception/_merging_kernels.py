"""Compiled loops of step 6 (:mod:`service.perception.merging`): end widths, candidate
joins, gap curves.

Plain versions: ``tests/perception/references/merging.py``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from service.perception._geometry_kernels import bend_aware_fit, outward_fit
from service.perception._shared_kernels import solve_small

# --------------------------------------------------------------------------- end widths


@njit(cache=True, nogil=True)
def median_distance_per_piece(distance, points, starts):
    """Median of ``distance`` at the rounded joints of each piece (as ``np.median``).

    ``points`` holds every piece's joints one after another; piece ``k`` is
    ``points[starts[k]:starts[k + 1]]``. Joints are rounded half to even and clipped to
    the image, as ``np.rint`` and ``np.clip`` would.
    """
    height, width = distance.shape
    medians = np.empty(starts.size - 1)
    for k in range(starts.size - 1):
        count = starts[k + 1] - starts[k]
        values = np.empty(count, np.float32)
        for i in range(count):
            col = min(max(int(np.rint(points[starts[k] + i, 0])), 0), width - 1)
            row = min(max(int(np.rint(points[starts[k] + i, 1])), 0), height - 1)
            values[i] = distance[row, col]
        values.sort()
        middle = count // 2
        if count % 2:
            medians[k] = values[middle]
        else:
            medians[k] = (values[middle - 1] + values[middle]) / np.float32(2.0)
    return medians


@njit(cache=True, nogil=True)
def narrow_end_length(points, start, stop, at_start, distance, full_width, limit):
    """merging._narrow_end_length on piece ``points[start:stop]``: the arc length from
    the end to the first of its ``limit + 1`` joints nearest the end where ``distance``
    (float32) reaches ``full_width`` (compared in float32, as NumPy compares a float32
    with a Python float), else 0."""
    height, width = distance.shape
    threshold = np.float32(full_width)
    length = 0.0
    previous = start if at_start else stop - 1
    for k in range(min(stop - start, limit + 1)):
        index = start + k if at_start else stop - 1 - k
        if k:
            length += np.hypot(
                points[index, 0] - points[previous, 0], points[index, 1] - points[previous, 1]
            )
        col = min(max(int(np.rint(points[index, 0])), 0), width - 1)
        row = min(max(int(np.rint(points[index, 1])), 0), height - 1)
        if distance[row, col] >= threshold:
            return length
        previous = index
    return 0.0


@njit(cache=True, nogil=True)
def fit_chain_ends(
    points, starts, lengths, distance, full_widths, skip, span, narrow_limit, bend_aware
):
    """merging.chain_ends' fits of both ends of every piece, as geometry.end_fit gives them.

    Piece ``k`` is ``points[starts[k]:starts[k + 1]]`` (two joints or more); its ends are
    ``2 k`` (at its first joint) and ``2 k + 1``. Each end's fit leaves out ``skip`` of
    arc length, or more where the cable is narrow (:func:`narrow_end_length` below
    ``full_widths[k]``, looked at only when ``distance`` is not empty). A fit spans
    ``span`` of arc length, or less on a piece (of length ``lengths[k]``) whose other end
    was left out for being narrow: then it stops short of that end's skip, if at least
    half of ``span`` is left. An end flagged in ``bend_aware`` (an array of one flag per
    end, or empty for none) is fitted by ``_geometry_kernels.bend_aware_fit``: over a
    shorter span where the piece bends tightly.

    Returns
    -------
    positions, directions : ndarray
        ``(2 K, 2)`` fitted end points and outward unit tangents.
    curvatures, skips : ndarray
        ``(2 K,)`` the fits' signed curvatures (0 where too short to fit) and the arc
        lengths their fits left out.
    """
    count = starts.size - 1
    positions = np.empty((2 * count, 2))
    directions = np.empty((2 * count, 2))
    curvatures = np.empty(2 * count)
    skips = np.empty(2 * count)
    for k in range(count):
        start, stop = starts[k], starts[k + 1]
        for side in range(2):
            end_skip = skip
            if distance.shape[0] > 0:
                narrow = narrow_end_length(
                    points, start, stop, side == 0, distance, full_widths[k], narrow_limit
                )
                end_skip = max(skip, narrow)
            skips[2 * k + side] = end_skip
        for side in range(2):
            end = 2 * k + side
            end_skip, far_skip = skips[end], skips[2 * k + 1 - side]
            reach = lengths[k] - end_skip - far_skip
            end_span = span
            if far_skip > skip and reach >= 0.5 * span:
                end_span = min(span, reach)
            backwards = points[start:stop] if side == 0 else points[start:stop][::-1]
            if bend_aware.size and bend_aware[end]:
                x, y, dx, dy, curvature = bend_aware_fit(backwards, end_skip, end_span)
            else:
                x, y, dx, dy, curvature = outward_fit(backwards, end_skip, end_span)
            positions[end, 0] = x
            positions[end, 1] = y
            directions[end, 0] = dx
            directions[end, 1] = dy
            curvatures[end] = curvature
    return positions, directions, curvatures, skips


@njit(cache=True, nogil=True)
def pair_join_costs(positions, directions, curvatures, first, second, weights, max_gap, radius):
    """:func:`join_cost` of ends ``first[k]`` and ``second[k]`` for every ``k``."""
    costs = np.empty(first.size)
    for k in range(first.size):
        i = first[k]
        j = second[k]
        costs[k] = join_cost(
            positions[i, 0],
            positions[i, 1],
            directions[i, 0],
            directions[i, 1],
            curvatures[i],
            positions[j, 0],
            positions[j, 1],
            directions[j, 0],
            directions[j, 1],
            curvatures[j],
            weights,
            max_gap,
            radius,
        )
    return costs


# --------------------------------------------------------------------------- junctions of ends


@njit(cache=True, nogil=True)
def _in_grown_zones(zones, row, col, reach):
    """Whether pixel (row, col) lies within ``reach`` (a square's half side) of a zone
    pixel: on the zones grown by ``cv2.dilate`` with a ``2 reach + 1`` square."""
    if zones[row, col]:
        return True
    height, width = zones.shape
    for r in range(max(row - reach, 0), min(row + reach + 1, height)):
        for c in range(max(col - reach, 0), min(col + reach + 1, width)):
            if zones[r, c]:
                return True
    return False


@njit(cache=True, nogil=True)
def on_grown_zones(zones, positions, reach):
    """merging.tips_in_junctions: whether each position's pixel lies on the grown zones
    (see :func:`_in_grown_zones`), as :func:`grown_zone_labels` rounds and clips it.

    One look at the square round each position: the pieces need no labels for this, so
    none is filled.
    """
    height, width = zones.shape
    inside = np.zeros(positions.shape[0], np.bool_)
    for index in range(positions.shape[0]):
        col = min(max(int(np.rint(positions[index, 0])), 0), width - 1)
        row = min(max(int(np.rint(positions[index, 1])), 0), height - 1)
        inside[index] = _in_grown_zones(zones, row, col, reach)
    return inside


@njit(cache=True, nogil=True)
def grown_zone_labels(zones, positions, reach):
    """merging.junctions_of_ends: the 8-connected piece of the grown zones (see
    :func:`_in_grown_zones`) each position's pixel lies in, or -1.

    Positions ``(x, y)`` are rounded half to even and clipped to the image. Pieces are
    numbered from 0 in the order the positions first reach them; only the pieces the
    positions lie in are filled, one pixel test of the grown zones at a time, never
    the whole picture.
    """
    height, width = zones.shape
    count = positions.shape[0]
    rows = np.empty(count, np.int64)
    cols = np.empty(count, np.int64)
    for index in range(count):
        cols[index] = min(max(int(np.rint(positions[index, 0])), 0), width - 1)
        rows[index] = min(max(int(np.rint(positions[index, 1])), 0), height - 1)
    # Per pixel: 0 not looked at, 1 off the grown zones, 2 on a piece already filled.
    state = np.zeros((height, width), np.uint8)
    labels = np.full(count, -1, np.int64)
    stack = np.empty(1024, np.int64)
    pieces = 0
    for index in range(count):
        row, col = rows[index], cols[index]
        if state[row, col] or not _in_grown_zones(zones, row, col, reach):
            continue  # off the zones, or on a piece filled (and labelled) before
        state[row, col] = 2
        stack[0] = row * width + col
        size = 1
        while size:
            size -= 1
            r = stack[size] // width
            c = stack[size] - r * width
            for nr in range(max(r - 1, 0), min(r + 2, height)):
                for nc in range(max(c - 1, 0), min(c + 2, width)):
                    if state[nr, nc]:
                        continue
                    if not _in_grown_zones(zones, nr, nc, reach):
                        state[nr, nc] = 1
                        continue
                    state[nr, nc] = 2
                    if size == stack.size:
                        grown = np.empty(2 * size, np.int64)
                        grown[:size] = stack
                        stack = grown
                    stack[size] = nr * width + nc
                    size += 1
        # Every position on this piece not labelled yet is on it (earlier pieces'
        # positions were labelled when those were filled).
        for other in range(index, count):
            if labels[other] < 0 and state[rows[other], cols[other]] == 2:
                labels[other] = pieces
        pieces += 1
    return labels


# --------------------------------------------------------------------------- candidate joins


# A cable bends no tighter than this many radii: the most of an end's curvature that
# is carried on across a gap.
MIN_BEND_RADII = 3.0


@njit(cache=True, nogil=True)
def _signed_angle(ux, uy, wx, wy):
    """Signed angle (-pi..pi) from unit vector u to unit vector w."""
    return np.arctan2(ux * wy - uy * wx, ux * wx + uy * wy)


@njit(cache=True, nogil=True)
def _wrap(angle):
    while angle > np.pi:
        angle -= 2.0 * np.pi
    while angle < -np.pi:
        angle += 2.0 * np.pi
    return angle


@njit(cache=True, nogil=True)
def _bending(turn, first, second, distance, length, kappa_a, kappa_b, weights, radius):
    """The direction and turning parts of the join cost, less what curvatures explain."""
    expected = 0.5 * (kappa_a + kappa_b) * length
    cost = weights[1] * abs(_wrap(turn - expected)) / np.pi
    if distance > 1e-9:
        expected_first = length * (2.0 * kappa_a + kappa_b) / 6.0
        expected_second = expected - expected_first
        turning = abs(_wrap(first - expected_first)) + abs(_wrap(second - expected_second))
        fade = min(1.0, distance / max(3.0 * radius, 1e-9))
        cost += weights[2] * fade * turning / (2.0 * np.pi)
    return cost


@njit(cache=True, nogil=True)
def join_cost(ax, ay, adx, ady, ak, bx, by, bdx, bdy, bk, weights, max_gap, radius):
    """merging.join_cost: the paper's three parts, its direction and turning parts less
    the turn the ends' curvature explains when that is cheaper."""
    gap_x = bx - ax
    gap_y = by - ay
    distance = np.hypot(gap_x, gap_y)
    arriving_x = -bdx
    arriving_y = -bdy
    turn = _signed_angle(adx, ady, arriving_x, arriving_y)
    limit = 1.0 / max(MIN_BEND_RADII * radius, 1e-9)
    kappa_a = min(max(ak, -limit), limit)
    # b's curvature is for travel out of b; the cable arrives travelling into b.
    kappa_b = min(max(-bk, -limit), limit)
    half = 0.5 * abs(turn)
    length = distance * half / np.sin(half) if half > 1e-6 else distance
    first = 0.0
    second = 0.0
    if distance > 1e-9:
        heading_x = gap_x / distance
        heading_y = gap_y / distance
        first = _signed_angle(adx, ady, heading_x, heading_y)
        second = _signed_angle(heading_x, heading_y, arriving_x, arriving_y)
    bent = _bending(turn, first, second, distance, length, kappa_a, kappa_b, weights, radius)
    straight = _bending(turn, first, second, distance, length, 0.0, 0.0, weights, radius)
    return weights[0] * distance / max(max_gap, 1e-9) + min(bent, straight)


@njit(cache=True, nogil=True)
def _cells(positions, free, cell):
    """Grid cell key of each free end (row-major over cells ``cell`` px wide), the free ends
    sorted by key, their sorted keys, and the number of cells per row."""
    count = free.size
    min_x = np.inf
    min_y = np.inf
    for k in range(count):
        min_x = min(min_x, positions[free[k], 0])
        min_y = min(min_y, positions[free[k], 1])
    column = np.empty(count, np.int64)
    row = np.empty(count, np.int64)
    columns = 1
    for k in range(count):
        column[k] = int(np.floor((positions[free[k], 0] - min_x) / cell))
        row[k] = int(np.floor((positions[free[k], 1] - min_y) / cell))
        columns = max(columns, column[k] + 3)
    keys = (row + 1) * columns + column + 1  # a free cell around the grid on every side
    order = np.argsort(keys, kind="mergesort")
    return keys, free[order], keys[order], columns


@njit(cache=True, nogil=True)
def _walk_candidates(positions, piece_of_end, free, max_distance, cell, fill, out):
    """Count (``fill`` False) or write into ``out`` the candidate pairs; returns the count."""
    if free.size == 0:
        return 0
    keys, members, sorted_keys, columns = _cells(positions, free, cell)
    found = 0
    for k in range(free.size):
        i = free[k]
        for dy in range(-1, 2):
            for dx in range(-1, 2):
                key = keys[k] + dy * columns + dx
                first = np.searchsorted(sorted_keys, key, side="left")
                last = np.searchsorted(sorted_keys, key, side="right")
                for m in range(first, last):
                    j = members[m]
                    if j <= i or piece_of_end[i] == piece_of_end[j]:
                        continue
                    distance = np.hypot(
                        positions[i, 0] - positions[j, 0], positions[i, 1] - positions[j, 1]
                    )
                    if not distance <= max_distance:
                        continue
                    if fill:
                        out[found, 0] = i
                        out[found, 1] = j
                    found += 1
    return found


@njit(cache=True, nogil=True)
def candidate_joins(
    positions, directions, curvatures, piece_of_end, free, max_distance, max_gap, weights, radius
):
    """Every pair of free ends of different pieces at most ``max_distance`` apart.

    Ends are bucketed in a grid of ``max_distance`` cells, so only the nine cells around
    an end are searched: the work grows with the number of pairs found, not with the
    square of the number of ends (``max_distance`` infinite: every pair, one cell).

    Parameters
    ----------
    positions, directions : ndarray
        ``(N, 2)`` end positions and outward unit directions.
    piece_of_end : ndarray of int64
        The piece each end belongs to; two ends of one piece are never a candidate.
    free : ndarray of int64
        The ends to pair, ascending.
    max_distance : float
        Largest distance between the two ends (``np.hypot`` of their difference).
    max_gap : float
        ``DetectParams.max_gap``, and ``weights`` the three weights (distance, direction,
        curvature) and ``radius`` the cable half width, for the cost.

    Returns
    -------
    pairs : ndarray of int64
        ``(M, 2)`` end indices ``i < j``.
    distances, costs : ndarray
        ``(M,)``: each pair's distance and :func:`merging.join_cost` of ends ``i``, ``j``.
    """
    if max_distance == np.inf:  # every pair: one cell
        cell = 1e300
    elif max_distance >= 1.0:
        cell = max_distance
    else:  # tiny (or NaN) limits: cells of a pixel
        cell = 1.0
    count = _walk_candidates(
        positions, piece_of_end, free, max_distance, cell, False, np.empty((0, 2), np.int64)
    )
    pairs = np.empty((count, 2), np.int64)
    _walk_candidates(positions, piece_of_end, free, max_distance, cell, True, pairs)
    distances = np.empty(count)
    for k in range(count):
        i = pairs[k, 0]
        j = pairs[k, 1]
        distances[k] = np.hypot(
            positions[i, 0] - positions[j, 0], positions[i, 1] - positions[j, 1]
        )
    costs = pair_join_costs(
        positions, directions, curvatures, pairs[:, 0], pairs[:, 1], weights, max_gap, radius
    )
    return pairs, distances, costs


# --------------------------------------------------------------------------- gap curves


@njit(cache=True, nogil=True)
def _put_segment(out, n, ax, ay, bx, by, step, skip_first):
    """Append the samples of the segment a-b (``step`` apart at most) to ``out[n:]``."""
    count = max(2, int(np.ceil(np.hypot(bx - ax, by - ay) / step)) + 1)
    fractions = np.linspace(0.0, 1.0, count)
    for k in range(1 if skip_first else 0, count):
        out[n, 0] = ax + fractions[k] * (bx - ax)
        out[n, 1] = ay + fractions[k] * (by - ay)
        n += 1
    return n


@njit(cache=True, nogil=True)
def _gap_geometry(start, leaving, end, arriving):
    """The gap between two chain ends: its vector, its length, and the cross and dot
    products of the two end headings."""
    gap_x = end[0] - start[0]
    gap_y = end[1] - start[1]
    cross = leaving[0] * arriving[1] - leaving[1] * arriving[0]
    dot = leaving[0] * arriving[0] + leaving[1] * arriving[1]
    return gap_x, gap_y, np.hypot(gap_x, gap_y), cross, dot


@njit(cache=True, nogil=True)
def _ends_only(start, end):
    """The curve across a gap of no length: its two ends."""
    out = np.empty((2, 2))
    out[0] = start
    out[1] = end
    return out


@njit(cache=True, nogil=True)
def _bezier_samples(start, leaving, end, arriving, handle, distance, step):
    """Samples of the cubic Bezier from ``start`` along ``leaving`` to ``end`` along
    ``arriving`` with both handles ``handle`` long (1.3 samples per ``step`` of gap)."""
    count = max(4, int(np.ceil(1.3 * distance / step)) + 1)
    t = np.linspace(0.0, 1.0, count)
    out = np.empty((count, 2))
    for axis in range(2):
        p0 = start[axis]
        p1 = start[axis] + handle * leaving[axis]
        p2 = end[axis] - handle * arriving[axis]
        p3 = end[axis]
        for k in range(count):
            u = t[k]
            out[k, axis] = (
                (1 - u) ** 3 * p0 + 3 * (1 - u) ** 2 * u * p1 + 3 * (1 - u) * u**2 * p2 + u**3 * p3
            )
    return out


@njit(cache=True, nogil=True)
def natural_curve_kernel(start, leaving, end, arriving, step):
    """Samples of the natural curve between two chain ends (merging.gap_curve, "natural")."""
    gap_x, gap_y, distance, cross, dot = _gap_geometry(start, leaving, end, arriving)
    if distance < 1e-9:
        return _ends_only(start, end)
    turn = np.arctan2(cross, dot)
    heading_x = gap_x / distance
    heading_y = gap_y / distance
    if abs(cross) < 1e-6:
        cosine = min(max(leaving[0] * heading_x + leaving[1] * heading_y, -1.0), 1.0)
        if dot > 0 and np.arccos(cosine) < 1e-3:
            out = np.empty((max(2, int(np.ceil(distance / step)) + 1), 2))
            n = _put_segment(out, 0, start[0], start[1], end[0], end[1], step, False)
            return out[:n]
    else:
        # start + t_a * leaving = end - t_b * arriving
        matrix = np.empty((2, 2))
        matrix[0, 0] = leaving[0]
        matrix[0, 1] = arriving[0]
        matrix[1, 0] = leaving[1]
        matrix[1, 1] = arriving[1]
        rhs = np.empty((2, 1))
        rhs[0, 0] = gap_x
        rhs[1, 0] = gap_y
        _, solution = solve_small(matrix, rhs)
        t_a = solution[0, 0]
        t_b = solution[1, 0]
        if t_a > 0 and t_b > 0:
            tangent = min(t_a, t_b)
            corner_x = start[0] + t_a * leaving[0]
            corner_y = start[1] + t_a * leaving[1]
            arc_start_x = corner_x - tangent * leaving[0]
            arc_start_y = corner_y - tangent * leaving[1]
            arc_radius = tangent / np.tan(abs(turn) / 2.0)
            sign = 1.0 if turn >= 0 else -1.0
            centre_x = arc_start_x + arc_radius * sign * -leaving[1]
            centre_y = arc_start_y + arc_radius * sign * leaving[0]
            offset_x = arc_start_x - centre_x
            offset_y = arc_start_y - centre_y
            arc_count = max(2, int(np.ceil(abs(turn) * arc_radius / step)) + 1)
            angles = np.linspace(0.0, turn, arc_count)
            arc_x = centre_x + (np.cos(angles) * offset_x - np.sin(angles) * offset_y)
            arc_y = centre_y + (np.sin(angles) * offset_x + np.cos(angles) * offset_y)
            first = max(
                2, int(np.ceil(np.hypot(arc_start_x - start[0], arc_start_y - start[1]) / step)) + 1
            )
            last = max(2, int(np.ceil(np.hypot(end[0] - arc_x[-1], end[1] - arc_y[-1]) / step)) + 1)
            curve = np.empty((first + arc_count + last, 2))
            n = _put_segment(curve, 0, start[0], start[1], arc_start_x, arc_start_y, step, False)
            for k in range(1, arc_count):
                curve[n, 0] = arc_x[k]
                curve[n, 1] = arc_y[k]
                n += 1
            n = _put_segment(curve, n, arc_x[-1], arc_y[-1], end[0], end[1], step, True)
            curve[n - 1, 0] = end[0]
            curve[n - 1, 1] = end[1]
            # Drop points that repeat their predecessor (a straight part of zero length).
            kept = 1
            for k in range(1, n):
                if np.hypot(curve[k, 0] - curve[k - 1, 0], curve[k, 1] - curve[k - 1, 1]) > 1e-9:
                    curve[kept] = curve[k]
                    kept += 1
            return curve[:kept]
    handle = 0.4 * distance
    return _bezier_samples(start, leaving, end, arriving, handle, distance, step)


@njit(cache=True, nogil=True)
def smooth_curve_kernel(start, leaving, end, arriving, step):
    """Samples of the smooth gap curve (see merging.gap_curve, shape "smooth").

    A cubic Bezier from ``start`` along ``leaving`` to ``end`` along ``arriving`` whose
    handle length, for a total turn theta between the end directions, is
    (2/3) d tan(theta / 4) / sin(theta / 2) with d the gap: the cubic that best follows
    a circular arc when the ends are symmetric, d / 3 (a straight line) when they are
    aligned. theta is capped at 0.95 pi so a reversing gap gets finite handles.
    """
    _, _, distance, cross, dot = _gap_geometry(start, leaving, end, arriving)
    if distance < 1e-9:
        return _ends_only(start, end)
    theta = min(abs(np.arctan2(cross, dot)), 0.95 * np.pi)
    if theta < 1e-6:
        handle = distance / 3.0
    else:
        handle = (2.0 / 3.0) * distance * np.tan(theta / 4.0) / np.sin(theta / 2.0)
    return _bezier_samples(start, leaving, end, arriving, handle, distance, step)


# --------------------------------------------------------------------------- ends at the border


@njit(cache=True, nogil=True)
def runs_to_border(mask, positions, directions, reach, margin):
    """Ends whose cable runs on along their direction to the picture's border.

    From each end, 1 px steps along its direction while they stay on the mask, up to
    ``reach`` px: the end runs to the border when a step leaves the picture, or when
    the first step off the mask is within ``margin`` px of leaving it (thinning stops
    about a radius short of the border). Steps are rounded as Python's ``round``.
    """
    height, width = mask.shape
    result = np.zeros(positions.shape[0], np.bool_)
    for index in range(positions.shape[0]):
        x, y = positions[index, 0], positions[index, 1]
        dx, dy = directions[index, 0], directions[index, 1]
        step = 0.0
        while step <= reach:
            col = int(np.rint(x + step * dx))
            row = int(np.rint(y + step * dy))
            if not (0 <= col < width and 0 <= row < height):
                result[index] = True
                break
            if not mask[row, col]:
                col = int(np.rint(x + (step + margin) * dx))
                row = int(np.rint(y + (step + margin) * dy))
                result[index] = not (0 <= col < width and 0 <= row < height)
                break
            step += 1.0
    return result
