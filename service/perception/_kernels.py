"""Compiled pixel loops of steps 2 to 6 (numba, one thread, no GIL held).

Every kernel here reproduces, bit for bit, the result of the plain NumPy / OpenCV /
scikit-image code it replaced; ``tests/perception/test_speed_equivalence.py`` keeps
those plain versions as references and checks the kernels against them. The speed
comes from touching only the pixels that matter (the border of the mask while it is
thinned, the skeleton pixels afterwards) instead of whole images, and from walking
contours in one compiled loop instead of one Python step per pixel.

Kernels take ``uint8`` views of boolean images (0 or 1). ``cache=True`` keeps the
machine code in ``__pycache__`` (or numba's user cache when that is not writable), so
only the very first import on a machine compiles; :func:`warm_up` then loads every
kernel so that the first real image pays nothing.
"""

from __future__ import annotations

import numpy as np
from numba import njit

# --------------------------------------------------------------------------- tables

# OpenCV's 5x5 chamfer distance (cv2.DIST_L2, mask 5): steps of 1 (axial), 1.4
# (diagonal) and 2.1969 (knight's move), added in float32 as cv2.distanceTransform
# (OpenCV 5) adds them; the outside of the image is "far" (FLT_MAX).
_HV_DIST = np.float32(1.0)
_DIAG_DIST = np.float32(1.4)
_LONG_DIST = np.float32(2.1969)
_DIST_MAX = np.float32(np.finfo(np.float32).max)

# Offsets (row, col) of the 8 neighbours in the order of the branch-count bits
# (clockwise from east), the same as skeleton.NEIGHBOUR_OFFSETS.
_RING_DR = np.array([0, 1, 1, 1, 0, -1, -1, -1], np.int64)
_RING_DC = np.array([1, 1, 0, -1, -1, -1, 0, 1], np.int64)
# The order in which a spur walk looks for the next pixel: orthogonal ones first.
_WALK_DR = np.array([0, 1, 0, -1, 1, 1, -1, -1], np.int64)
_WALK_DC = np.array([1, 0, -1, 0, 1, -1, -1, 1], np.int64)


# --------------------------------------------------------------------------- helpers


@njit(cache=True, nogil=True)
def _pattern(skeleton, row, col):
    """8-bit pattern of the set neighbours (bit k: ring offset k); outside is unset."""
    height, width = skeleton.shape
    pattern = 0
    for k in range(8):
        r = row + _RING_DR[k]
        c = col + _RING_DC[k]
        if 0 <= r < height and 0 <= c < width and skeleton[r, c]:
            pattern |= 1 << k
    return pattern


_BYTE_ONES = np.uint64(0x0101010101010101)
_TOP_BYTE = np.uint64(56)


@njit(cache=True, nogil=True)
def nonzero_flat(flat):
    """Indices of the set entries of a 1D 0/1 ``uint8`` array, in increasing order.

    Both passes skip 8 zero bytes at a time, so that sparse images (a skeleton, a mask
    of thin cables) cost little more than reading them once: the first counts (the
    bytes of a word are 0 or 1, so multiplying by 0x0101... sums them into the top
    byte), the second gathers without branching on each byte.
    """
    n_words = flat.size // 8
    words = flat[: n_words * 8].view(np.uint64)
    n = 0
    for w in range(n_words):
        x = words[w]
        if x != 0:
            n += np.int64((x * _BYTE_ONES) >> _TOP_BYTE)
    for i in range(n_words * 8, flat.size):
        n += flat[i] != 0
    # Room for 8 more: every byte of a word is written before the count moves on.
    indices = np.empty(n + 8, np.int64)
    k = 0
    for w in range(n_words):
        if words[w] != 0:
            base = w * 8
            for b in range(8):
                indices[k] = base + b
                k += flat[base + b] != 0
    for i in range(n_words * 8, flat.size):
        indices[k] = i
        k += flat[i] != 0
    return indices[:k]


@njit(cache=True, nogil=True)
def skeleton_pixels(skeleton):
    """Rows and columns of the set pixels of a C-contiguous image, in row-major order."""
    width = skeleton.shape[1]
    indices = nonzero_flat(skeleton.reshape(skeleton.size))
    rows = np.empty(indices.size, np.int64)
    cols = np.empty(indices.size, np.int64)
    row = 0
    row_start = 0
    for k in range(indices.size):
        index = indices[k]
        while index >= row_start + width:
            row_start += width
            row += 1
        rows[k] = row
        cols[k] = index - row_start
    return rows, cols


@njit(cache=True, nogil=True)
def branch_counts_at(skeleton, rows, cols, branch_table):
    """Branch count (``branch_table`` of the neighbour pattern) at the given pixels."""
    counts = np.empty(rows.size, np.uint8)
    for k in range(rows.size):
        counts[k] = branch_table[_pattern(skeleton, rows[k], cols[k])]
    return counts


@njit(cache=True, nogil=True)
def branch_count_image(skeleton, branch_table):
    """Branch count of every skeleton pixel, zero elsewhere, as a full image."""
    counts = np.zeros(skeleton.shape, np.uint8)
    rows, cols = skeleton_pixels(skeleton)
    for i in range(rows.size):
        counts[rows[i], cols[i]] = branch_table[_pattern(skeleton, rows[i], cols[i])]
    return counts


# --------------------------------------------------------------------------- thinning

# The ring P2..P9 of Zhang and Suen (1984) as offsets: N, NE, E, SE, S, SW, W, NW;
# bit k of a thinning pattern is P(k+2). (The branch-count patterns use _RING_*.)
_ZS_DR = np.array([-1, -1, 0, 1, 1, 1, 0, -1], np.int64)
_ZS_DC = np.array([0, 1, 1, 1, 0, -1, -1, -1], np.int64)


@njit(cache=True, nogil=True)
def _zs_pattern(flat, index, offsets):
    """Thinning pattern of the pixel ``index`` of a flattened padded image."""
    pattern = 0
    for k in range(8):
        if flat[index + offsets[k]]:
            pattern |= 1 << k
    return pattern


@njit(cache=True, nogil=True)
def thin_padded(padded, first_table, second_table, staircase_table):
    """Thin, in place, a 0/1 image whose outermost rows and columns are 0.

    See skeleton.thin for the rule. Each sub-iteration marks, from the image as it
    was, the pixels its table removes, then removes them. Only pixels whose
    neighbourhood changed can change their answer, so a pixel is looked at again only
    until it has met both tables since a neighbour was last removed; the work follows
    the shrinking border of the mask, not the whole image.
    """
    width = padded.shape[1]
    flat = padded.ravel()
    offsets = np.empty(8, np.int64)
    for k in range(8):
        offsets[k] = _ZS_DR[k] * width + _ZS_DC[k]
    foreground = nonzero_flat(flat)
    total = foreground.size
    listed = np.empty(total, np.int64)
    age = np.empty(total, np.uint8)
    n_listed = 0
    for j in range(total):
        if _zs_pattern(flat, foreground[j], offsets) != 255:
            listed[n_listed] = foreground[j]
            age[n_listed] = 0
            n_listed += 1
    queued = np.zeros(flat.size, np.uint8)
    remove = np.empty(total, np.uint8)
    next_listed = np.empty(total, np.int64)
    next_age = np.empty(total, np.uint8)
    quiet = 0
    first = True
    while quiet < 2 and n_listed > 0:
        table = first_table if first else second_table
        first = not first
        removed = 0
        for j in range(n_listed):
            remove[j] = table[_zs_pattern(flat, listed[j], offsets)]
            removed += remove[j]
        quiet = quiet + 1 if removed == 0 else 0
        for j in range(n_listed):
            if remove[j]:
                flat[listed[j]] = 0
        n_next = 0
        for j in range(n_listed):
            if remove[j]:
                for k in range(8):
                    neighbour = listed[j] + offsets[k]
                    if flat[neighbour] and not queued[neighbour]:
                        queued[neighbour] = 1
                        next_listed[n_next] = neighbour
                        next_age[n_next] = 0
                        n_next += 1
        for j in range(n_listed):
            index = listed[j]
            if not remove[j] and not queued[index] and age[j] == 0:
                queued[index] = 1
                next_listed[n_next] = index
                next_age[n_next] = 1
                n_next += 1
        for j in range(n_next):
            queued[next_listed[j]] = 0
        listed, next_listed = next_listed, listed
        age, next_age = next_age, age
        n_listed = n_next
    # The staircase pass: the survivors in raster order, each judged on the image as
    # it is (a removal only ever clears pixels, so the list stays valid).
    survivors = nonzero_flat(flat)
    for j in range(survivors.size):
        index = survivors[j]
        if flat[index] and staircase_table[_zs_pattern(flat, index, offsets)]:
            flat[index] = 0


@njit(cache=True, nogil=True)
def remove_spurs_inplace(skeleton, spur_length, branch_table):
    """One pass of cutting tip-to-junction branches shorter than ``spur_length``.

    See skeleton.remove_spurs: branch counts are taken once per pass, the next pixel is
    the first unvisited set neighbour in the order E, S, W, N, SE, SW, NW, NE, and a
    staircase step marks the diagonal it skipped as visited. Returns whether anything
    was removed (the caller then thins the skeleton again).
    """
    height, width = skeleton.shape
    counts = np.zeros((height, width), np.uint8)
    visited = np.zeros((height, width), np.uint8)
    rows, cols = skeleton_pixels(skeleton)
    # A walk takes at most one step per unit of length, and never revisits a pixel.
    max_steps = min(max(int(min(spur_length, 1e9)), 0), rows.size) + 2
    path_r = np.empty(max_steps + 1, np.int64)
    path_c = np.empty(max_steps + 1, np.int64)
    marked_r = np.empty(8 * (max_steps + 1), np.int64)
    marked_c = np.empty(8 * (max_steps + 1), np.int64)
    cand_r = np.empty(8, np.int64)
    cand_c = np.empty(8, np.int64)
    for i in range(rows.size):
        counts[rows[i], cols[i]] = branch_table[_pattern(skeleton, rows[i], cols[i])]
    removed_any = False
    for i in range(rows.size):
        row = rows[i]
        col = cols[i]
        if counts[row, col] != 1 or not skeleton[row, col]:
            continue
        n_path = 1
        path_r[0] = row
        path_c[0] = col
        n_marked = 1
        marked_r[0] = row
        marked_c[0] = col
        visited[row, col] = 1
        length = 0.0
        reached_junction = False
        while length <= spur_length:
            rc = path_r[n_path - 1]
            cc = path_c[n_path - 1]
            n_cand = 0
            for k in range(8):
                r = rc + _WALK_DR[k]
                c = cc + _WALK_DC[k]
                if 0 <= r < height and 0 <= c < width and skeleton[r, c] and not visited[r, c]:
                    cand_r[n_cand] = r
                    cand_c[n_cand] = c
                    n_cand += 1
            if n_cand == 0:
                break
            nr = cand_r[0]
            nc = cand_c[0]
            if counts[nr, nc] >= 3 or n_cand > 2:
                reached_junction = True
                break
            length += 1.0 if (nr == rc or nc == cc) else 1.4142
            path_r[n_path] = nr
            path_c[n_path] = nc
            n_path += 1
            visited[nr, nc] = 1
            marked_r[n_marked] = nr
            marked_c[n_marked] = nc
            n_marked += 1
            for k in range(1, n_cand):
                if (
                    abs(cand_r[k] - nr) <= 1
                    and abs(cand_c[k] - nc) <= 1
                    and not visited[cand_r[k], cand_c[k]]
                ):
                    visited[cand_r[k], cand_c[k]] = 1
                    marked_r[n_marked] = cand_r[k]
                    marked_c[n_marked] = cand_c[k]
                    n_marked += 1
        if reached_junction and length < spur_length:
            for k in range(n_path):
                skeleton[path_r[k], path_c[k]] = 0
            removed_any = True
        for k in range(n_marked):
            visited[marked_r[k], marked_c[k]] = 0
    return removed_any


# --------------------------------------------------------------------------- distance


@njit(cache=True, nogil=True)
def _row_starts(rows, height):
    """Index of the first pixel of each row in a row-major pixel list (``height + 1``)."""
    starts = np.empty(height + 1, np.int64)
    k = 0
    for r in range(height + 1):
        while k < rows.size and rows[k] < r:
            k += 1
        starts[r] = k
    return starts


@njit(cache=True, nogil=True)
def chamfer_values(rows, cols, height, width):
    """OpenCV's two-pass 5x5 chamfer distance at the foreground pixels only.

    ``rows, cols`` list the foreground in row-major order; the distances come back in
    the same order. No image-sized array is made: the two rows above (below, going
    back) live in three small row buffers, background 0 and the outside of the image
    OpenCV's "far" value. The additions and minima are OpenCV's (float32), so the
    values are identical to ``cv2.distanceTransform(mask, cv2.DIST_L2, 5)``.
    """
    n = rows.size
    values = np.empty(n, np.float32)
    if n == 0:
        return values
    starts = _row_starts(rows, height)
    first = rows[0]
    last = rows[n - 1]
    # Buffer index = column + 2: two "far" columns pad each side.
    buffers = np.zeros((3, width + 4), np.float32)
    far = np.full(width + 4, _DIST_MAX, np.float32)
    for b in range(3):
        buffers[b, 0] = buffers[b, 1] = _DIST_MAX
        buffers[b, width + 2] = buffers[b, width + 3] = _DIST_MAX
    for r in range(first, last + 1):
        here = buffers[r % 3]
        if r >= 3:
            for k in range(starts[r - 3], starts[r - 2]):
                here[cols[k] + 2] = 0.0
        up1 = buffers[(r - 1) % 3] if r >= 1 else far
        up2 = buffers[(r - 2) % 3] if r >= 2 else far
        for k in range(starts[r], starts[r + 1]):
            c = cols[k] + 2
            # Minima taken as a tree (exact, so the order does not matter) to keep
            # the dependency chain short.
            t0 = min(
                min(
                    min(up2[c - 1] + _LONG_DIST, up2[c + 1] + _LONG_DIST),
                    min(up1[c - 2] + _LONG_DIST, up1[c + 2] + _LONG_DIST),
                ),
                min(
                    min(up1[c - 1] + _DIAG_DIST, up1[c + 1] + _DIAG_DIST),
                    min(up1[c] + _HV_DIST, _DIST_MAX),
                ),
            )
            t0 = min(t0, here[c - 1] + _HV_DIST)
            here[c] = t0
            values[k] = t0
    buffers[:, 2 : width + 2] = 0.0
    for r in range(last, first - 1, -1):
        here = buffers[r % 3]
        if r + 3 <= last:
            for k in range(starts[r + 3], starts[r + 4]):
                here[cols[k] + 2] = 0.0
        for k in range(starts[r], starts[r + 1]):
            here[cols[k] + 2] = values[k]
        down1 = buffers[(r + 1) % 3] if r + 1 < height else far
        down2 = buffers[(r + 2) % 3] if r + 2 < height else far
        for k in range(starts[r + 1] - 1, starts[r] - 1, -1):
            c = cols[k] + 2
            t0 = here[c]
            if t0 > _HV_DIST:
                t0 = min(
                    min(
                        min(down2[c + 1] + _LONG_DIST, down2[c - 1] + _LONG_DIST),
                        min(down1[c + 2] + _LONG_DIST, down1[c - 2] + _LONG_DIST),
                    ),
                    min(
                        min(down1[c + 1] + _DIAG_DIST, down1[c - 1] + _DIAG_DIST),
                        min(down1[c] + _HV_DIST, t0),
                    ),
                )
                t0 = min(t0, here[c + 1] + _HV_DIST)
                here[c] = t0
                values[k] = t0
    return values


@njit(cache=True, nogil=True)
def distance_transform(mask):
    """``cv2.distanceTransform(mask, cv2.DIST_L2, 5)``, bit for bit, in O(foreground)."""
    height, width = mask.shape
    distance = np.zeros((height, width), np.float32)
    rows, cols = skeleton_pixels(mask)
    values = chamfer_values(rows, cols, height, width)
    for k in range(rows.size):
        distance[rows[k], cols[k]] = values[k]
    return distance


@njit(cache=True, nogil=True)
def distances_on_skeleton(mask, skeleton):
    """The distance of :func:`distance_transform` at the skeleton pixels (row-major).

    Skeleton pixels off the mask get 0, as they would in the distance image.
    """
    height, width = mask.shape
    rows, cols = skeleton_pixels(mask)
    values = chamfer_values(rows, cols, height, width)
    skel_rows, skel_cols = skeleton_pixels(skeleton)
    found = np.zeros(skel_rows.size, np.float32)
    k = 0
    for i in range(skel_rows.size):
        r = skel_rows[i]
        c = skel_cols[i]
        while k < rows.size and (rows[k] < r or (rows[k] == r and cols[k] < c)):
            k += 1
        if k < rows.size and rows[k] == r and cols[k] == c:
            found[i] = values[k]
    return found


# --------------------------------------------------------------------------- zones


@njit(cache=True, nogil=True)
def junction_zones_kernel(skeleton, disc, bridge_length, branch_table):
    """Junction zones of fitting.junction_zones: discs round junctions plus short bridges.

    ``disc`` is the (odd, square) structuring element of the dilation; it is stamped
    mirrored at every junction pixel, which is what ``cv2.dilate`` computes. Returns
    the zones as ``uint8`` and whether there was any junction at all.
    """
    height, width = skeleton.shape
    zones = np.zeros((height, width), np.uint8)
    rows, cols = skeleton_pixels(skeleton)
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
                rr = r + _RING_DR[k]
                cc = c + _RING_DC[k]
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


# --------------------------------------------------------------------------- fitting


@njit(cache=True, nogil=True)
def _emit_run(points, idx, n_idx, segment_length_sq, joints, n_joints, ends, n_chains):
    """walk_joints on the run ``points[idx[:n_idx]]``; appends one chain."""
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
    """split_contour + walk_joints over every contour in one pass; see fitting.fit_chains.

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
        is_tip[i] = branch_table[_pattern(skeleton, y, x)] == 1 and skeleton[y, x] != 0
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


# --------------------------------------------------------------------------- pruning


@njit(cache=True, nogil=True)
def _block_sum(values, start, stop):
    """NumPy's sum of at most 128 contiguous float64 values (eight running sums)."""
    n = stop - start
    if n < 8:
        total = 0.0
        for i in range(start, stop):
            total += values[i]
        return total
    r0 = values[start]
    r1 = values[start + 1]
    r2 = values[start + 2]
    r3 = values[start + 3]
    r4 = values[start + 4]
    r5 = values[start + 5]
    r6 = values[start + 6]
    r7 = values[start + 7]
    body = start + n - n % 8
    for i in range(start + 8, body, 8):
        r0 += values[i]
        r1 += values[i + 1]
        r2 += values[i + 2]
        r3 += values[i + 3]
        r4 += values[i + 4]
        r5 += values[i + 5]
        r6 += values[i + 6]
        r7 += values[i + 7]
    total = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    for i in range(body, stop):
        total += values[i]
    return total


@njit(cache=True, nogil=True)
def _pairwise_sum(values, start, stop):
    """``values[start:stop].sum()`` added in NumPy's order, bit for bit.

    NumPy sums blocks of up to 128 values with eight running sums and splits longer
    arrays in two (the first part a multiple of 8 long), recursively; the recursion is
    unrolled here on a small stack. Summing in the same order keeps the chain lengths,
    and so the order of the chains, exactly those of ``chain_length``.
    """
    if stop - start <= 128:
        return _block_sum(values, start, stop)
    lo = np.empty(64, np.int64)
    hi = np.empty(64, np.int64)
    phase = np.empty(64, np.int64)  # 0: not split yet, 1: left part pending, 2: right
    left = np.empty(64, np.float64)
    lo[0] = start
    hi[0] = stop
    phase[0] = 0
    depth = 1
    result = 0.0
    have_result = False
    while depth > 0:
        t = depth - 1
        if have_result:
            if phase[t] == 1:
                left[t] = result
                phase[t] = 2
                have_result = False
                half = (hi[t] - lo[t]) // 2
                half -= half % 8
                lo[depth] = lo[t] + half
                hi[depth] = hi[t]
                phase[depth] = 0
                depth += 1
            else:
                result = left[t] + result
                depth -= 1
            continue
        n = hi[t] - lo[t]
        if n <= 128:
            result = _block_sum(values, lo[t], hi[t])
            have_result = True
            depth -= 1
            continue
        half = n // 2
        half -= half % 8
        phase[t] = 1
        lo[depth] = lo[t]
        hi[depth] = lo[t] + half
        phase[depth] = 0
        depth += 1
    return result


@njit(cache=True, nogil=True)
def _polyline_length(joints, start, stop, scratch):
    """``pruning.chain_length(joints[start:stop])`` with the same rounding."""
    if stop - start < 2:
        return 0.0
    for i in range(start, stop - 1):
        dx = joints[i + 1, 0] - joints[i, 0]
        dy = joints[i + 1, 1] - joints[i, 1]
        scratch[i - start] = np.sqrt(dx * dx + dy * dy)
    return 0.0 + _pairwise_sum(scratch, 0, stop - start - 1)


@njit(cache=True, nogil=True)
def chain_lengths(joints, ends):
    """Arc length of each chain of ``joints`` (chain ``i`` ends at ``ends[i]``)."""
    lengths = np.empty(ends.size, np.float64)
    scratch = np.empty(max(joints.shape[0], 1), np.float64)
    start = 0
    for i in range(ends.size):
        lengths[i] = _polyline_length(joints, start, ends[i], scratch)
        start = ends[i]
    return lengths


@njit(cache=True, nogil=True)
def uncovered_runs(joints, coverage):
    """Runs of a chain whose segments are not already covered; see pruning.prune_overlaps.

    A segment is covered when at least two of its points at 1/4, 1/2 and 3/4 of its
    length (rounded to the nearest pixel, half to even, and clipped to the image)
    are set in ``coverage``. Returns ``(start, stop)`` joint index pairs of the
    maximal runs of uncovered segments at least 1 px long.
    """
    height, width = coverage.shape
    n = joints.shape[0]
    runs = np.empty((n, 2), np.int64)
    scratch = np.empty(max(n, 1), np.float64)
    n_runs = 0
    start = -1
    for k in range(n):
        covered = False
        if k < n - 1:
            sx = joints[k, 0]
            sy = joints[k, 1]
            dx = joints[k + 1, 0] - sx
            dy = joints[k + 1, 1] - sy
            hits = 0
            for f in (0.25, 0.5, 0.75):
                col = min(max(np.int64(np.rint(sx + f * dx)), 0), width - 1)
                row = min(max(np.int64(np.rint(sy + f * dy)), 0), height - 1)
                hits += coverage[row, col]
            covered = hits >= 2
        if k < n - 1 and not covered:
            if start < 0:
                start = k
        elif start >= 0:
            # Segments start .. k-1 are uncovered: joints start .. k.
            if _polyline_length(joints, start, k + 1, scratch) >= 1.0:
                runs[n_runs, 0] = start
                runs[n_runs, 1] = k + 1
                n_runs += 1
            start = -1
    return runs[:n_runs]


# --------------------------------------------------------------------------- merging


@njit(cache=True, nogil=True)
def segment_intersections(starts, ends, chain_ids, indices, order, stops):
    """The sweep of crossings.find_intersections over all segments, in its order.

    ``order`` sorts the segments by their smallest x and ``stops[k]`` is where the
    segments of ``order`` that may overlap ``order[k]`` along x end. Returns the
    pairs ``(a, b)`` of proper intersections (``a`` the segment of the sweep) and
    the parameter ``t`` of the point along ``a``, with the same float64 arithmetic.
    """
    n = order.size
    capacity = 16
    pairs = np.empty((capacity, 2), np.int64)
    params = np.empty(capacity, np.float64)
    count = 0
    for position in range(n):
        a = order[position]
        ax0 = starts[a, 0]
        ay0 = starts[a, 1]
        rx = ends[a, 0] - ax0
        ry = ends[a, 1] - ay0
        a_lo_y = min(ay0, ends[a, 1])
        a_hi_y = max(ay0, ends[a, 1])
        for k in range(position + 1, stops[position]):
            b = order[k]
            bx0 = starts[b, 0]
            by0 = starts[b, 1]
            bx1 = ends[b, 0]
            by1 = ends[b, 1]
            if not (min(by0, by1) <= a_hi_y and max(by0, by1) >= a_lo_y):
                continue
            if chain_ids[b] == chain_ids[a] and abs(indices[b] - indices[a]) <= 2:
                continue
            sx = bx1 - bx0
            sy = by1 - by0
            denom = rx * sy - ry * sx
            if not abs(denom) > 1e-12:
                continue
            qpx = bx0 - ax0
            qpy = by0 - ay0
            t = (qpx * sy - qpy * sx) / denom
            u = (qpx * ry - qpy * rx) / denom
            if t >= 0 and t < 1 and u >= 0 and u < 1:
                if count == capacity:
                    capacity *= 2
                    grown = np.empty((capacity, 2), np.int64)
                    grown[:count] = pairs[:count]
                    pairs = grown
                    grown_params = np.empty(capacity, np.float64)
                    grown_params[:count] = params[:count]
                    params = grown_params
                pairs[count, 0] = a
                pairs[count, 1] = b
                params[count] = t
                count += 1
    return pairs[:count], params[:count]


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
        dx = bx - ax
        dy = by - ay
        fx = ax - cx
        fy = ay - cy
        qa = dx * dx + dy * dy
        qb = 2.0 * (fx * dx + fy * dy)
        qc = fx * fx + fy * fy - step_sq
        disc = max(qb * qb - 4.0 * qa * qc, 0.0)
        t = (-qb + np.sqrt(disc)) / (2.0 * qa) if qa > 0 else 1.0
        t = min(max(t, 0.0), 1.0)
        cx = ax + t * dx
        cy = ay + t * dy
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
def inferred_segments(source_edge, edge_lengths, hidden_edge):
    """The per-segment "inferred" flags of pipeline._finalise_path.

    Segment ``k`` (joints ``k`` to ``k + 1``) spans the polyline edges
    ``source_edge[k]`` to ``source_edge[k + 1]``; it is inferred when more than half of
    their length is hidden (or, if they have no length, when the first one is). The
    sums are added in NumPy's order (:func:`_pairwise_sum`), so the comparisons are
    those of the plain code.
    """
    n = max(source_edge.size - 1, 0)
    inferred = np.zeros(n, np.bool_)
    scratch = np.empty(max(edge_lengths.size, 1), np.float64)
    for k in range(n):
        lo = source_edge[k]
        hi = min(source_edge[k + 1] + 1, edge_lengths.size)
        total = _pairwise_sum(edge_lengths, lo, hi) if hi > lo else 0.0
        if total > 0:
            for i in range(lo, hi):
                scratch[i - lo] = edge_lengths[i] if hidden_edge[i] else 0.0
            inferred[k] = _pairwise_sum(scratch, 0, hi - lo) > 0.5 * total
        else:
            inferred[k] = hidden_edge[source_edge[k]]
    return inferred


@njit(cache=True, nogil=True)
def end_fit(backwards, skip, span):
    """Quadratic least-squares fit of a polyline's last stretch (see geometry.end_tangent).

    ``backwards`` starts at the end. Returns ``(fitted, x0, y0, dx, dy, last)``:
    whether at least four points lie between ``skip`` and ``skip + span`` of arc
    length; the end position (the fit's value at arc length 0 when a stretch was
    skipped, else the first point); the fit's first-order coefficient; and the index
    of the last point within ``span`` (for the chord fallback).
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
        return False, backwards[0, 0], backwards[0, 1], 0.0, 0.0, last
    normal = np.empty((3, 3))
    for r in range(3):
        for c in range(3):
            normal[r, c] = sums[r + c]
    if abs(np.linalg.det(normal)) < 1e-12:
        return False, backwards[0, 0], backwards[0, 1], 0.0, 0.0, last
    coefficients = np.linalg.solve(normal, rhs)
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
    )


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
    """Samples of the natural curve between two chain ends (see merging.natural_curve)."""
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
        rhs = np.empty(2)
        rhs[0] = gap_x
        rhs[1] = gap_y
        solution = np.linalg.solve(matrix, rhs)
        t_a = solution[0]
        t_b = solution[1]
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
def farthest_rim_ahead(mask, col, row, tip_x, tip_y, dir_x, dir_y, limit, cos_half_angle, rim):
    """See pipeline._farthest_ahead: ``(found, x, y)`` of the middle of the farthest rim.

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
            rr = qr + _FILL_DR[k]
            cc = qc + _FILL_DC[k]
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
def smooth_curve_kernel(start, leaving, end, arriving, step):
    """Samples of the smooth gap curve (see merging.natural_curve, shape "smooth").

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


# --------------------------------------------------------------------------- segmentation

# The 8 neighbours and, first, the 4 orthogonal ones (for 4-connected fills).
_FILL_DR = np.array([0, 1, 0, -1, 1, 1, -1, -1], np.int64)
_FILL_DC = np.array([1, 0, -1, 0, 1, -1, -1, 1], np.int64)


@njit(cache=True, nogil=True)
def otsu_kernel(hist):
    """Otsu's threshold of a 256-level histogram and its separability (0..1).

    Between-class variance at every level; with an empty stretch of the histogram
    between the classes every threshold in it is equally good, and the middle one
    (within a relative 1e-12 of the best) keeps the most margin to both classes. A
    histogram of one level gives ``(255.0, 0.0)``.
    """
    total = 0.0
    level_sum = 0.0
    for level in range(256):
        total += hist[level]
        level_sum += hist[level] * level
    mean_all = level_sum / total
    var_sum = 0.0
    for level in range(256):
        offset = level - mean_all
        var_sum += hist[level] * (offset * offset)
    var_all = var_sum / total
    if var_all <= 1e-9:
        return 255.0, 0.0
    between = np.zeros(256)
    count_low = 0.0
    sum_low = 0.0
    peak = 0.0
    for level in range(256):
        count_low += hist[level]
        sum_low += hist[level] * level
        weight_low = count_low / total
        weight_high = 1.0 - weight_low
        if weight_low > 0 and weight_high > 0:
            gap = mean_all * weight_low - sum_low / total
            between[level] = gap * gap / (weight_low * weight_high)
            peak = max(peak, between[level])
    best_levels = np.empty(256, np.int64)
    n_best = 0
    for level in range(256):
        if between[level] >= peak * (1.0 - 1e-12):
            best_levels[n_best] = level
            n_best += 1
    return float(best_levels[n_best // 2]), peak / var_all


@njit(cache=True, nogil=True)
def brightness_histogram(image_bgr):
    """Brightness (largest channel) of a BGR ``uint8`` image and its 256-level histogram.

    Two loops, not one: the channel maximum over flat memory vectorizes, and four
    interleaved histograms keep consecutive pixels of one level from waiting on each
    other's increment.
    """
    height, width = image_bgr.shape[:2]
    flat = image_bgr.reshape(-1)
    count = height * width
    brightness = np.empty(count, np.uint8)
    for i in range(count):
        blue = flat[3 * i]
        green = flat[3 * i + 1]
        red = flat[3 * i + 2]
        larger = blue if blue > green else green
        brightness[i] = larger if larger > red else red
    partial = np.zeros((4, 256), np.int64)
    whole = count - count % 4
    for i in range(0, whole, 4):
        partial[0, brightness[i]] += 1
        partial[1, brightness[i + 1]] += 1
        partial[2, brightness[i + 2]] += 1
        partial[3, brightness[i + 3]] += 1
    for i in range(whole, count):
        partial[0, brightness[i]] += 1
    return brightness.reshape(height, width), partial.sum(axis=0)


@njit(cache=True, nogil=True)
def remove_small_components(mask, min_area):
    """Clear, in place, the 8-connected foreground components of fewer than ``min_area`` px."""
    height, width = mask.shape
    seen = np.zeros((height, width), np.uint8)
    # Room for the largest possible component up front: growing an array inside the
    # loop makes numba count references on every step, which costs more than the fill.
    members = np.empty(max(np.count_nonzero(mask), 1), np.int64)
    for r0 in range(height):
        for c0 in range(width):
            if not mask[r0, c0] or seen[r0, c0]:
                continue
            # Breadth-first over ``members``: the filled pixels are the component.
            seen[r0, c0] = 1
            members[0] = r0 * width + c0
            count = 1
            head = 0
            while head < count:
                r = members[head] // width
                c = members[head] - r * width
                head += 1
                for k in range(8):
                    rr = r + _FILL_DR[k]
                    cc = c + _FILL_DC[k]
                    if 0 <= rr < height and 0 <= cc < width and mask[rr, cc] and not seen[rr, cc]:
                        seen[rr, cc] = 1
                        members[count] = rr * width + cc
                        count += 1
            if count < min_area:
                for i in range(count):
                    r = members[i] // width
                    c = members[i] - r * width
                    mask[r, c] = 0


_UNSEEN, _SMALL_HOLE, _OPEN = 0, 1, 2


@njit(cache=True, nogil=True)
def _fill_holes_next_to(mask, foreground, n_foreground, max_hole_area):
    """Fill, in place, the small holes next to the listed foreground pixels.

    A hole is a 4-connected background component of at most ``max_hole_area`` pixels
    that does not touch the image border; ``foreground[:n_foreground]`` (flat indices)
    must include every foreground pixel that borders one, and holes are whole
    components, so the order of the fills does not matter.

    Every hole borders the foreground, so fills start only from background pixels next
    to it. A fill stops as soon as its component is known not to be a hole: more than
    ``max_hole_area`` pixels, the image border, or a pixel an earlier stopped fill
    reached (the same component). Its pixels are then marked open, so no background
    pixel is filled twice and the cost stays near the length of the mask's border.
    """
    height, width = mask.shape
    state = np.zeros((height, width), np.uint8)
    # A fill stops before it holds more than ``max_hole_area`` pixels.
    members = np.empty(max_hole_area + 1, np.int64)
    for i0 in range(n_foreground):
        r0 = foreground[i0] // width
        c0 = foreground[i0] - r0 * width
        for k0 in range(4):
            rs = r0 + _FILL_DR[k0]
            cs = c0 + _FILL_DC[k0]
            if not (0 <= rs < height and 0 <= cs < width):
                continue
            if mask[rs, cs] or state[rs, cs] != _UNSEEN:
                continue
            state[rs, cs] = _SMALL_HOLE
            members[0] = rs * width + cs
            count = 1
            head = 0
            is_hole = True
            while head < count and is_hole:
                r = members[head] // width
                c = members[head] - r * width
                head += 1
                if r == 0 or c == 0 or r == height - 1 or c == width - 1:
                    is_hole = False
                    break
                for k in range(4):
                    rr = r + _FILL_DR[k]
                    cc = c + _FILL_DC[k]
                    if mask[rr, cc]:
                        continue
                    if state[rr, cc] == _OPEN:
                        is_hole = False
                        break
                    if state[rr, cc] == _UNSEEN:
                        if count >= max_hole_area:
                            is_hole = False
                            break
                        state[rr, cc] = _SMALL_HOLE
                        members[count] = rr * width + cc
                        count += 1
            for i in range(count):
                r = members[i] // width
                c = members[i] - r * width
                if is_hole:
                    mask[r, c] = 1
                else:
                    state[r, c] = _OPEN


@njit(cache=True, nogil=True)
def fill_small_holes(mask, max_hole_area):
    """Fill, in place, the 4-connected background components of at most ``max_hole_area``
    pixels that do not touch the image border (see _fill_holes_next_to)."""
    flat = mask.ravel()
    foreground = np.empty(np.count_nonzero(flat), np.int64)
    n = 0
    for i in range(flat.size):
        if flat[i]:
            foreground[n] = i
            n += 1
    _fill_holes_next_to(mask, foreground, n, max_hole_area)


@njit(cache=True, nogil=True)
def threshold_and_clean(cue, low, high, weak_count, min_area, max_hole_area):
    """Hysteresis threshold, speck removal and hole filling in one pass over the result.

    The same mask as ``clean_mask(hysteresis_threshold(cue, low, high), min_area,
    max_hole_area)``: each flood fill of the hysteresis is a whole 8-connected
    component of the result (two floods never touch, or they would be one), so a flood
    of fewer than ``min_area`` pixels is exactly a speck; the kept floods list every
    foreground pixel, so the holes are found next to them without a scan.
    ``weak_count`` is the number of pixels above ``low`` (from the histogram).
    """
    height, width = cue.shape
    result = np.zeros((height, width), np.uint8)
    # Kept components fill ``members`` from the front, removed ones from the back.
    members = np.empty(max(weak_count, 1), np.int64)
    speck = np.empty(max(min_area, 1), np.int64)
    kept = 0
    removed = 0
    for r0 in range(height):
        for c0 in range(width):
            if result[r0, c0] or not (cue[r0, c0] > high and cue[r0, c0] > low):
                continue
            result[r0, c0] = 1
            members[kept] = r0 * width + c0
            count = 1
            head = 0
            while head < count:
                r = members[kept + head] // width
                c = members[kept + head] - r * width
                head += 1
                for k in range(8):
                    rr = r + _FILL_DR[k]
                    cc = c + _FILL_DC[k]
                    inside = 0 <= rr < height and 0 <= cc < width
                    if inside and not result[rr, cc] and cue[rr, cc] > low:
                        result[rr, cc] = 1
                        members[kept + count] = rr * width + cc
                        count += 1
            if count >= min_area:
                kept += count
            else:
                # Still marked in ``result`` so no pixel of it seeds again; cleared below.
                # Through a buffer: the two stretches of ``members`` may overlap.
                speck[:count] = members[kept : kept + count]
                for i in range(count):
                    members[members.size - 1 - removed - i] = speck[i]
                removed += count
    for i in range(removed):
        index = members[members.size - 1 - i]
        result[index // width, index - (index // width) * width] = 0
    if max_hole_area > 0:
        _fill_holes_next_to(result, members, kept, max_hole_area)
    return result


# --------------------------------------------------------------------------- own thresholds


@njit(cache=True, nogil=True)
def _clear_of(x, y, avoid_xy, avoid_reach):
    """Is ``(x, y)`` outside every disc ``avoid_reach[k]`` round ``avoid_xy[k]``?"""
    for k in range(avoid_xy.shape[0]):
        ex, ey = x - avoid_xy[k, 0], y - avoid_xy[k, 1]
        if ex * ex + ey * ey < avoid_reach[k] * avoid_reach[k]:
            return False
    return True


@njit(cache=True, nogil=True)
def profile_histogram(cue, points, seen, avoid_xy, avoid_reach, span, stride):
    """Histogram of ``cue`` across a polyline: profiles ``foot + t * normal``, ``|t| <= span``.

    Each segment has ``ceil(length)`` feet, evenly spread from its start, so feet are
    at most one pixel apart. Every ``stride``-th foot (counted over the whole polyline)
    on a ``seen`` segment and outside every disc ``avoid_reach[k]`` round
    ``avoid_xy[k]`` is used. Profile points go to the nearest pixel (halves up); those
    off the image are left out. Returns the ``float64`` counts of the 256 levels and
    the number of feet used.
    """
    height, width = cue.shape
    hist = np.zeros(256, np.float64)
    used = 0
    foot = 0
    for segment in range(points.shape[0] - 1):
        x0, y0 = points[segment, 0], points[segment, 1]
        dx, dy = points[segment + 1, 0] - x0, points[segment + 1, 1] - y0
        length = np.sqrt(dx * dx + dy * dy)
        count = max(int(np.ceil(length)), 1)
        if not seen[segment] or length <= 1e-9:
            foot += count
            continue
        nx, ny = -dy / length, dx / length
        for step in range(count):
            foot += 1
            if (foot - 1) % stride:
                continue
            x, y = x0 + dx * (step / count), y0 + dy * (step / count)
            if not _clear_of(x, y, avoid_xy, avoid_reach):
                continue
            used += 1
            for t in range(-span, span + 1):
                col = int(np.floor(x + t * nx + 0.5))
                row = int(np.floor(y + t * ny + 0.5))
                if 0 <= col < width and 0 <= row < height:
                    hist[cue[row, col]] += 1.0
    return hist, used


@njit(cache=True, nogil=True)
def grow_along_profiles(cue, before, grown, points, seen, avoid_xy, avoid_reach, start, reach, low):
    """Walk out, both ways, from feet at most half a pixel apart along the ``seen`` segments.

    The feet are those of :func:`profile_histogram`, twice as dense (``ceil(2 *
    length)`` a segment): a slanted rim is a staircase with up to 1.4 pixels per pixel
    of length, and walks one pixel apart miss about one rim pixel in 80 (half a pixel
    apart, about one in 5,000, on straight cables at every angle). A walk begins
    ``start`` pixels out when that pixel is in ``before`` (the cable's inside need not
    be walked), else at the foot. It sets ``grown`` while its pixel is in ``before``
    or its cue is above ``low``, for at most ``reach`` pixels beyond the foot, and
    stops at the image's edge. ``before`` and ``grown`` are ``uint8`` masks; only
    ``grown`` changes.
    """
    height, width = cue.shape
    for segment in range(points.shape[0] - 1):
        x0, y0 = points[segment, 0], points[segment, 1]
        dx, dy = points[segment + 1, 0] - x0, points[segment + 1, 1] - y0
        length = np.sqrt(dx * dx + dy * dy)
        if not seen[segment] or length <= 1e-9:
            continue
        nx, ny = -dy / length, dx / length
        count = max(int(np.ceil(2.0 * length)), 1)
        for step in range(count):
            x, y = x0 + dx * (step / count), y0 + dy * (step / count)
            if not _clear_of(x, y, avoid_xy, avoid_reach):
                continue
            for sign in (1.0, -1.0):
                first = 0
                col = int(np.floor(x + sign * start * nx + 0.5))
                row = int(np.floor(y + sign * start * ny + 0.5))
                if 0 <= col < width and 0 <= row < height and before[row, col]:
                    first = start
                for t in range(first, reach + 1):
                    col = int(np.floor(x + sign * t * nx + 0.5))
                    row = int(np.floor(y + sign * t * ny + 0.5))
                    if not (0 <= col < width and 0 <= row < height):
                        break
                    if before[row, col] == 0 and not cue[row, col] > low:
                        break
                    grown[row, col] = 1


# --------------------------------------------------------------------------- warm-up


def warm_up() -> None:
    """Load (or, on a machine's very first run, compile) every kernel.

    Runs steps 2 to 5 on a tiny mask through the same wrappers, and so with the same
    argument types, as the pipeline uses. Call it once at start-up so that the first
    image pays nothing; calling it again costs well under a millisecond.
    """
    from schemas import DetectParams
    from service.perception.contours import extract_contours
    from service.perception.crossings import find_intersections
    from service.perception.fitting import fit_chains, junction_zones
    from service.perception.geometry import end_tangent, resample
    from service.perception.merging import natural_curve
    from service.perception.pruning import prune_overlaps
    from service.perception.segmentation import clean_mask, grow_by_own_thresholds, segment
    from service.perception.skeleton import (
        as_uint8,
        branch_counts,
        distance_transform,
        estimate_radius,
        remove_spurs,
        skeletonize,
    )

    mask = np.zeros((40, 48), bool)
    mask[17:23, 2:46] = True  # a cross: one junction, four arms
    mask[2:38, 21:27] = True
    mask[8, 4] = True  # a speck
    # Segmentation: the cues, the hysteresis and the clean-up of the same cross.
    image = np.repeat((mask * 200 + 20).astype(np.uint8)[:, :, None], 3, axis=2)
    segment(image, DetectParams())
    clean_mask(mask, 2, 2)
    line = np.array([[2.0, 20.0], [45.0, 20.0]])
    grow_by_own_thresholds(image[:, :, 0], mask, [line], [3.0], [np.array([False])], [])
    skeleton = skeletonize(mask)
    distance = distance_transform(mask)
    radius = max(estimate_radius(mask, skeleton), 1.0)
    estimate_radius(mask, skeleton, distance)
    skeleton = remove_spurs(skeleton, 2.5 * radius)
    branch_counts(skeleton)
    zones = junction_zones(skeleton, radius)
    chains = fit_chains(extract_contours(skeleton), skeleton, zones, 5.0)
    prune_overlaps(chains, mask.shape)
    # Merging: resampling and the crossing search (two chains that cross).
    strands = [
        np.array([[0.0, 5.0], [4.0, 5.0], [8.0, 5.0], [12.0, 5.0]]),
        np.array([[6.0, 0.0], [6.0, 4.0], [6.0, 8.0], [6.0, 12.0]]),
    ]
    resample(strands[0], 2.0)
    end_tangent(strands[0], True, 10.0, 1.0)
    median_distance_per_piece(distance, np.concatenate(strands), np.array([0, 4, 8]))
    farthest_rim_ahead(as_uint8(mask), 24, 20, 24.0, 20.0, 1.0, 0.0, 10.0, 0.8, 2.0)
    # The three shapes of the natural curve: straight, arc, Bezier.
    east, north = np.array([1.0, 0.0]), np.array([0.0, 1.0])
    natural_curve(strands[0][0], east, strands[0][-1], east)
    natural_curve(strands[0][0], east, np.array([20.0, 20.0]), north)
    natural_curve(strands[0][0], east, np.array([-9.0, 9.0]), north)
    natural_curve(strands[0][0], east, np.array([20.0, 20.0]), north, shape="smooth")
    find_intersections(strands)
    inferred_segments(np.array([0, 1, 2]), np.array([1.0, 0.0, 2.0]), np.array([True, False, True]))
