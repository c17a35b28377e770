"""Compiled loops of step 4 (:mod:`service.perception.fitting`): junction zones, the walk.

Plain versions: ``tests/perception/references/fitting.py``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from service.perception._shared_kernels import (
    RING_DC,
    RING_DR,
    branch_counts_at,
    neighbour_pattern,
)

# --------------------------------------------------------------------------- zones


@njit(cache=True, nogil=True)
def junction_zones_kernel(skeleton, pixels, disc, bridge_length, branch_table):
    """Junction zones of fitting.junction_zones: discs round junctions plus short bridges.

    ``pixels``: the flat indices of the skeleton's pixels in raster order (the skeleton
    step's list, or ``nonzero_flat`` of it), so that the image is not scanned for them.

    ``disc`` is the (odd, square) structuring element of the dilation; it is stamped
    mirrored at every junction pixel, which is what ``cv2.dilate`` computes. Returns
    the zones as ``uint8`` and whether there was any junction at all.
    """
    height, width = skeleton.shape
    zones = np.zeros((height, width), np.uint8)
    rows = pixels // width
    cols = pixels - rows * width
    counts = branch_counts_at(skeleton, rows, cols, branch_table)
    size = disc.shape[0]
    half = size // 2
    any_junction = False
    for i in range(rows.size):
        if counts[i] < 3:
            continue
        any_junction = True
        for a in range(size):
            r = rows[i] + a - half
            if r < 0 or r >= height:
                continue
            for b in range(size):
                c = cols[i] + b - half
                if 0 <= c < width and disc[size - 1 - a, size - 1 - b]:
                    zones[r, c] = 1
    if not any_junction:
        return zones, False
    # 8-connected pieces of the skeleton outside the zones; a piece with no tip and
    # fewer than bridge_length pixels is the bridge of a crossing and joins the zones
    # (after all pieces are found: the zones must not grow while they are).
    # Seen pixels are marked 2 in ``zones`` itself and cleared at the end.
    stack_r = np.empty(rows.size, np.int64)
    stack_c = np.empty(rows.size, np.int64)
    members_r = np.empty(rows.size, np.int64)
    members_c = np.empty(rows.size, np.int64)
    n_bridge = 0
    for i in range(rows.size):
        r0 = rows[i]
        c0 = cols[i]
        if zones[r0, c0]:
            continue
        zones[r0, c0] = 2
        n_stack = 1
        stack_r[0] = r0
        stack_c[0] = c0
        start = n_bridge
        n_members = 0
        has_tip = False
        while n_stack:
            n_stack -= 1
            r = stack_r[n_stack]
            c = stack_c[n_stack]
            members_r[start + n_members] = r
            members_c[start + n_members] = c
            n_members += 1
            pattern = 0
            for k in range(8):
                rr = r + RING_DR[k]
                cc = c + RING_DC[k]
                if 0 <= rr < height and 0 <= cc < width and skeleton[rr, cc]:
                    pattern |= 1 << k
                    if not zones[rr, cc]:
                        zones[rr, cc] = 2
                        stack_r[n_stack] = rr
                        stack_c[n_stack] = cc
                        n_stack += 1
            if branch_table[pattern] == 1:
                has_tip = True
        if n_members < bridge_length and not has_tip:
            n_bridge += n_members
    for i in range(rows.size):
        if zones[rows[i], cols[i]] == 2:
            zones[rows[i], cols[i]] = 0
    for k in range(n_bridge):
        zones[members_r[k], members_c[k]] = 1
    return zones, True


# --------------------------------------------------------------------------- walk


@njit(cache=True, nogil=True)
def _emit_run(points, idx, n_idx, segment_length_sq, joints, n_joints, ends, n_chains):
    """Appends one chain: joints along the run ``points[idx[:n_idx]]``, each one
    ``sqrt(segment_length_sq)`` or more from the previous one, first and last pixel included."""
    x0 = np.float64(points[idx[0], 0])
    y0 = np.float64(points[idx[0], 1])
    joints[n_joints, 0] = x0
    joints[n_joints, 1] = y0
    n_joints += 1
    for i in range(1, n_idx):
        x = np.float64(points[idx[i], 0])
        y = np.float64(points[idx[i], 1])
        dx = x - x0
        dy = y - y0
        if dx * dx + dy * dy >= segment_length_sq:
            joints[n_joints, 0] = x
            joints[n_joints, 1] = y
            n_joints += 1
            x0 = x
            y0 = y
    if n_idx > 1:
        xl = np.float64(points[idx[n_idx - 1], 0])
        yl = np.float64(points[idx[n_idx - 1], 1])
        if joints[n_joints - 1, 0] != xl or joints[n_joints - 1, 1] != yl:
            joints[n_joints, 0] = xl
            joints[n_joints, 1] = yl
            n_joints += 1
    ends[n_chains] = n_joints
    return n_joints, n_chains + 1


@njit(cache=True, nogil=True)
def fit_kernel(points, starts, skeleton, zones, segment_length, branch_table):
    """Every contour cut into runs and walked, in one pass; see fitting.fit_chains.

    ``points`` holds all contours' ``[x, y]`` pixels back to back, contour ``i`` being
    ``points[starts[i]:starts[i + 1]]``. Returns the joints of all chains back to back
    and the end index of each chain in them.
    """
    n_points = points.shape[0]
    n_contours = starts.size - 1
    # Each pixel gives at most one joint per run and a run adds at most two more.
    joints = np.empty((2 * n_points + 4 * n_contours + 4, 2), np.float64)
    ends = np.empty(n_points + n_contours + 1, np.int64)
    n_joints = 0
    n_chains = 0
    is_tip = np.empty(n_points, np.bool_)
    in_zone = np.empty(n_points, np.bool_)
    for i in range(n_points):
        x = points[i, 0]
        y = points[i, 1]
        in_zone[i] = zones[y, x] != 0
        is_tip[i] = branch_table[neighbour_pattern(skeleton, y, x)] == 1 and skeleton[y, x] != 0
    current = np.empty(n_points + 1, np.int64)
    limit_sq = segment_length * segment_length
    for ci in range(n_contours):
        s = starts[ci]
        n = starts[ci + 1] - s
        if n == 0:
            continue
        first = -1
        for i in range(n):
            if is_tip[s + i] or in_zone[s + i]:
                first = i
                break
        if first < 0:
            # A closed loop with no tip or junction: one run around it.
            for i in range(n):
                current[i] = s + i
            n_joints, n_chains = _emit_run(
                points, current, n, limit_sq, joints, n_joints, ends, n_chains
            )
            continue
        n_current = 0
        for step in range(n):
            index = s + (first + step) % n
            if in_zone[index]:
                if n_current > 1:
                    n_joints, n_chains = _emit_run(
                        points, current, n_current, limit_sq, joints, n_joints, ends, n_chains
                    )
                n_current = 0
            elif is_tip[index]:
                current[n_current] = index
                n_current += 1
                if n_current > 1:
                    n_joints, n_chains = _emit_run(
                        points, current, n_current, limit_sq, joints, n_joints, ends, n_chains
                    )
                current[0] = index
                n_current = 1
            else:
                current[n_current] = index
                n_current += 1
        if n_current > 1:
            first_break = s + first
            if is_tip[first_break] and not in_zone[first_break]:
                current[n_current] = first_break
                n_current += 1
            n_joints, n_chains = _emit_run(
                points, current, n_current, limit_sq, joints, n_joints, ends, n_chains
            )
    return joints[:n_joints], ends[:n_chains]
