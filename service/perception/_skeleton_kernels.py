"""Compiled loops of step 2 (:mod:`service.perception.skeleton`): thinning, spur removal.

Plain versions: ``tests/perception/references/skeleton.py``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from service.perception._shared_kernels import (
    ORTHOGONAL_FIRST_DC,
    ORTHOGONAL_FIRST_DR,
    neighbour_pattern,
    nonzero_flat,
    set_pixels,
)

# --------------------------------------------------------------------------- thinning

# The ring P2..P9 of Zhang and Suen (1984) as offsets: N, NE, E, SE, S, SW, W, NW;
# bit k of a thinning pattern is P(k+2). (The branch-count patterns use RING_*.)
_ZS_DR = np.array([-1, -1, 0, 1, 1, 1, 0, -1], np.int64)
_ZS_DC = np.array([0, 1, 1, 1, 0, -1, -1, -1], np.int64)


@njit(cache=True, nogil=True)
def _zs_pattern(flat, index, offsets):
    """Thinning pattern of the pixel ``index`` of a flattened padded 0/1 image.

    The bits are shifted in without a branch: a border pixel's neighbours are as often
    set as not, and a mispredicted branch per neighbour cost more than the loads.
    """
    pattern = 0
    for k in range(8):
        pattern |= np.int64(flat[index + offsets[k]]) << k
    return pattern


@njit(cache=True, nogil=True)
def thin_padded(padded, first_table, second_table, staircase_table):
    """Thin, in place, a 0/1 image whose outermost rows and columns are 0.

    See skeleton.skeletonize for the rule. Each sub-iteration marks, from the image as it
    was, the pixels its table removes, then removes them. Only pixels whose
    neighbourhood changed can change their answer, so a pixel is looked at again only
    until it has met both tables since a neighbour was last removed; the work follows
    the shrinking border of the mask, not the whole image. The pixels a sub-iteration
    removes are listed as they are marked, so that clearing them and queueing their
    neighbours walks those alone, in the same order.
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
        # Written always, kept (counted) when not inside the mask.
        listed[n_listed] = foreground[j]
        age[n_listed] = 0
        n_listed += _zs_pattern(flat, foreground[j], offsets) != 255
    queued = np.zeros(flat.size, np.uint8)
    remove = np.empty(total, np.uint8)
    removing = np.empty(total, np.int64)
    next_listed = np.empty(total, np.int64)
    next_age = np.empty(total, np.uint8)
    quiet = 0
    first = True
    while quiet < 2 and n_listed > 0:
        table = first_table if first else second_table
        first = not first
        removed = 0
        for j in range(n_listed):
            verdict = table[_zs_pattern(flat, listed[j], offsets)]
            remove[j] = verdict
            removing[removed] = listed[j]
            removed += verdict
        quiet = quiet + 1 if removed == 0 else 0
        for j in range(removed):
            flat[removing[j]] = 0
        n_next = 0
        for j in range(removed):
            for k in range(8):
                neighbour = removing[j] + offsets[k]
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


# --------------------------------------------------------------------------- spurs


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
    rows, cols = set_pixels(skeleton)
    # A walk takes at most one step per unit of length, and never revisits a pixel.
    max_steps = min(max(int(min(spur_length, 1e9)), 0), rows.size) + 2
    path_r = np.empty(max_steps + 1, np.int64)
    path_c = np.empty(max_steps + 1, np.int64)
    marked_r = np.empty(8 * (max_steps + 1), np.int64)
    marked_c = np.empty(8 * (max_steps + 1), np.int64)
    cand_r = np.empty(8, np.int64)
    cand_c = np.empty(8, np.int64)
    for i in range(rows.size):
        counts[rows[i], cols[i]] = branch_table[neighbour_pattern(skeleton, rows[i], cols[i])]
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
                r = rc + ORTHOGONAL_FIRST_DR[k]
                c = cc + ORTHOGONAL_FIRST_DC[k]
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
