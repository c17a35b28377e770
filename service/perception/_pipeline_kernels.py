"""Compiled loops of :mod:`service.perception.pipeline`: a chain's "inferred" flags and
the mask's width across it.

Plain version: ``tests/perception/references/pipeline.py``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from service.perception._shared_kernels import pairwise_sum


@njit(cache=True, nogil=True)
def inferred_segments(source_edge, edge_lengths, hidden_edge):
    """The per-segment "inferred" flags of a resampled chain (pipeline._finalise_path).

    Segment ``k`` (joints ``k`` to ``k + 1``) spans the polyline edges
    ``source_edge[k]`` to ``source_edge[k + 1]``; it is inferred when more than half of
    their length is hidden (or, if they have no length, when the first one is). The
    sums are added in NumPy's order (:func:`pairwise_sum`), so the comparisons are
    those of the plain code.
    """
    n = max(source_edge.size - 1, 0)
    inferred = np.zeros(n, np.bool_)
    scratch = np.empty(max(edge_lengths.size, 1), np.float64)
    for k in range(n):
        lo = source_edge[k]
        hi = min(source_edge[k + 1] + 1, edge_lengths.size)
        total = pairwise_sum(edge_lengths, lo, hi) if hi > lo else 0.0
        if total > 0:
            for i in range(lo, hi):
                scratch[i - lo] = edge_lengths[i] if hidden_edge[i] else 0.0
            inferred[k] = pairwise_sum(scratch, 0, hi - lo) > 0.5 * total
        else:
            inferred[k] = hidden_edge[source_edge[k]]
    return inferred


@njit(cache=True, nogil=True)
def edge_distance(mask, x, y, dx, dy, limit):
    """How far the ray from ``(x, y)`` along the unit ``(dx, dy)`` runs inside the mask.

    Pixel ``(r, c)`` is the square ``[c - 0.5, c + 0.5) x [r - 0.5, r + 0.5)``; the ray
    walks from square to square (Amanatides and Woo) and the distance is where it
    enters the first background square: the border of the mask as drawn, exact, where
    a distance transform measures to the next background pixel's centre. NaN when the
    start is background, or the ray leaves the image or runs past ``limit`` first.
    """
    height, width = mask.shape
    col = int(np.floor(x + 0.5))
    row = int(np.floor(y + 0.5))
    if col < 0 or row < 0 or col >= width or row >= height or not mask[row, col]:
        return np.nan
    step_col = 1 if dx > 0 else -1
    step_row = 1 if dy > 0 else -1
    # Distance along the ray to the next column (row) boundary, and between two.
    if dx != 0.0:
        to_col = (col + 0.5 * step_col - x) / dx
        col_spacing = abs(1.0 / dx)
    else:
        to_col = col_spacing = np.inf
    if dy != 0.0:
        to_row = (row + 0.5 * step_row - y) / dy
        row_spacing = abs(1.0 / dy)
    else:
        to_row = row_spacing = np.inf
    while True:
        if to_col < to_row:
            travelled = to_col
            col += step_col
            to_col += col_spacing
        else:
            travelled = to_row
            row += step_row
            to_row += row_spacing
        if travelled > limit or col < 0 or row < 0 or col >= width or row >= height:
            return np.nan
        if not mask[row, col]:
            return travelled


@njit(cache=True, nogil=True)
def sides_across(joints, mask, limit):
    """How far the mask reaches on each side of a chain, at each joint and segment middle.

    Across is along the normal of the chord between a joint's neighbours (the one
    segment at an end) and of the segment itself at its middle: ``(2n - 1, 2)`` distances
    (left, right) for ``n`` joints, NaN where a side has no edge (see
    :func:`edge_distance`) or the chord has no length.
    """
    n = joints.shape[0]
    sides = np.full((max(2 * n - 1, 0), 2), np.nan)
    for k in range(2 * n - 1):
        if k < n:
            before, after = max(k - 1, 0), min(k + 1, n - 1)
            x, y = joints[k, 0], joints[k, 1]
        else:
            before, after = k - n, k - n + 1
            x = 0.5 * (joints[before, 0] + joints[after, 0])
            y = 0.5 * (joints[before, 1] + joints[after, 1])
        tx = joints[after, 0] - joints[before, 0]
        ty = joints[after, 1] - joints[before, 1]
        norm = np.hypot(tx, ty)
        if norm == 0.0:
            continue
        nx, ny = -ty / norm, tx / norm
        sides[k, 0] = edge_distance(mask, x, y, nx, ny, limit)
        sides[k, 1] = edge_distance(mask, x, y, -nx, -ny, limit)
    return sides


@njit(cache=True, nogil=True)
def radius_from_sides(sides, radius, centred_share, quantisation):
    """pipeline.chain_radius from :func:`sides_across`: half the mean of the finite
    widths (left + right) the chain runs through the middle ``centred_share`` of that lie
    within ``quantisation`` of their median (the median itself when none does), at least
    0.5; ``radius`` when there is no such width. Medians and means as NumPy's, bit for bit.
    """
    widths = np.empty(sides.shape[0])
    count = 0
    for k in range(sides.shape[0]):
        left = sides[k, 0]
        right = sides[k, 1]
        width = left + right
        if np.isfinite(width) and min(left, right) >= centred_share * width:
            widths[count] = width
            count += 1
    if count == 0:
        return radius
    ordered = np.sort(widths[:count])
    middle = count // 2
    median = ordered[middle] if count % 2 else (ordered[middle - 1] + ordered[middle]) / 2.0
    # The widths near the median, in the chain's order (np.mean sums them pairwise).
    near = np.empty(count)
    near_count = 0
    for k in range(count):
        if abs(widths[k] - median) <= quantisation:
            near[near_count] = widths[k]
            near_count += 1
    if near_count == 0:
        return max(0.5 * median, 0.5)
    return max(0.5 * (pairwise_sum(near, 0, near_count) / near_count), 0.5)
