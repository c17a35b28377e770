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
)

# --------------------------------------------------------------------------- thinning

# The ring P2..P9 of Zhang and Suen (1984): N, NE, E, SE, S, SW, W, NW; bit k of a
# thinning pattern is P(k+2). (The branch-count patterns use RING_*.)


@njit(cache=True, nogil=True)
def _zs_pattern(flat, index, width):
    """Thinning pattern of the pixel ``index`` of a flattened padded image ``width`` wide.

    The image's values are 0 or 1 whenever a pattern is read (:func:`thin_padded` clears
    its queued marks before the next sub-iteration reads any), so no bit is masked off.
    The eight offsets are written out, not read from an array: the compiler keeps them
    in registers, where an array of them was reloaded after every store to the image.
    The bits are shifted in without a branch: a border pixel's neighbours are as often
    set as not, and a mispredicted branch per neighbour cost more than the loads.
    """
    return (
        np.int64(flat[index - width])
        | (np.int64(flat[index - width + 1]) << 1)
        | (np.int64(flat[index + 1]) << 2)
        | (np.int64(flat[index + width + 1]) << 3)
        | (np.int64(flat[index + width]) << 4)
        | (np.int64(flat[index + width - 1]) << 5)
        | (np.int64(flat[index - 1]) << 6)
        | (np.int64(flat[index - width - 1]) << 7)
    )


@njit(cache=True, nogil=True)
def _queue(flat, index, wanted, queue, n_queued):
    """Append pixel ``index`` to ``queue`` when ``wanted`` (0 or 1) and it is set and not
    queued already (bit 1 of its value); returns the new length. Without a branch:
    whether a neighbour of a removed pixel is set is as good as a coin toss."""
    value = flat[index]
    fresh = wanted & np.uint8(value == 1)
    flat[index] = value | (fresh << 1)
    queue[n_queued] = index
    return n_queued + fresh


@njit(cache=True, nogil=True)
def thin_padded(padded, first_table, second_table, staircase_table):
    """Thin, in place, a 0/1 image whose outermost rows and columns are 0; returns the
    flat indices of the skeleton's pixels (into ``padded``), in raster order.

    See skeleton.skeletonize for the rule. Each sub-iteration marks, from the image as it
    was, the pixels its table removes, then removes them. Only pixels whose
    neighbourhood changed can change their answer, so the work follows the shrinking
    border of the mask, not the whole image: a pixel is looked at in a sub-iteration
    only when a neighbour was removed in the one before, or when it was looked at then,
    kept, and the other table removes its pattern (unchanged, if no neighbour went). A
    pixel left out of a sub-iteration is thus one whose present pattern that
    sub-iteration's table keeps, and the image after each sub-iteration is that of the
    plain sweep over every pixel (``tests/perception/references/skeleton.py``). While
    a sub-iteration's list is made, bit 1 of a pixel's value marks it listed (cleared
    before the next); interior pixels (all eight neighbours set) are never listed until
    a neighbour goes, as both tables keep them.
    """
    width = padded.shape[1]
    flat = padded.ravel()
    foreground = nonzero_flat(flat)
    total = foreground.size
    listed = np.empty(total, np.int64)
    n_listed = 0
    for j in range(total):
        # Written always, kept (counted) when not inside the mask: all eight neighbours
        # set is the and of their 0/1 bytes (no pattern to shift together).
        index = foreground[j]
        listed[n_listed] = index
        inside = (
            flat[index - width - 1]
            & flat[index - width]
            & flat[index - width + 1]
            & flat[index - 1]
            & flat[index + 1]
            & flat[index + width - 1]
            & flat[index + width]
            & flat[index + width + 1]
        )
        n_listed += 1 - np.int64(inside)
    again = np.empty(total, np.uint8)
    removing = np.empty(total, np.int64)
    next_listed = np.empty(total, np.int64)
    quiet = 0
    first = True
    while quiet < 2 and n_listed > 0:
        table = first_table if first else second_table
        other = second_table if first else first_table
        first = not first
        removed = 0
        for j in range(n_listed):
            pattern = _zs_pattern(flat, listed[j], width)
            # Looked at again next time, if kept, only when the next table removes it.
            again[j] = other[pattern]
            removing[removed] = listed[j]
            removed += table[pattern]
        quiet = quiet + 1 if removed == 0 else 0
        for j in range(removed):
            flat[removing[j]] = 0
        n_next = 0
        for j in range(removed):
            here = removing[j]
            n_next = _queue(flat, here - width, 1, next_listed, n_next)
            n_next = _queue(flat, here - width + 1, 1, next_listed, n_next)
            n_next = _queue(flat, here + 1, 1, next_listed, n_next)
            n_next = _queue(flat, here + width + 1, 1, next_listed, n_next)
            n_next = _queue(flat, here + width, 1, next_listed, n_next)
            n_next = _queue(flat, here + width - 1, 1, next_listed, n_next)
            n_next = _queue(flat, here - 1, 1, next_listed, n_next)
            n_next = _queue(flat, here - width - 1, 1, next_listed, n_next)
        for j in range(n_listed):
            # A removed pixel is 0 by now, so it is never queued again.
            n_next = _queue(flat, listed[j], again[j], next_listed, n_next)
        for j in range(n_next):
            flat[next_listed[j]] = 1
        listed, next_listed = next_listed, listed
        n_listed = n_next
    # The staircase pass: the survivors in raster order (the foreground's list, its
    # pixels still set), each judged on the image as it is. A pixel it keeps is never
    # looked at again, so the kept ones, listed in place as they are judged, are the
    # skeleton's pixels in raster order.
    n_kept = 0
    for j in range(total):
        index = foreground[j]
        if flat[index]:
            if staircase_table[_zs_pattern(flat, index, width)]:
                flat[index] = 0
            else:
                foreground[n_kept] = index
                n_kept += 1
    return foreground[:n_kept]


# --------------------------------------------------------------------------- spurs


# Marks of remove_spurs_inplace in a skeleton pixel's own byte (bit 0 is the pixel).
_VISITED = np.uint8(2)
_TIP = np.uint8(4)
_JUNCTION = np.uint8(8)
_PIXEL_ONLY = np.uint8(1)
_NOT_VISITED = np.uint8(255 - 2)


@njit(cache=True, nogil=True)
def remove_spurs_inplace(skeleton, pixels, spur_length, branch_table):
    """One pass of cutting tip-to-junction branches shorter than ``spur_length``.

    ``skeleton``: a 0/1 image. ``pixels``: the flat indices of its set pixels in raster
    order (the thinning's list, or ``nonzero_flat`` of it), so that the image is not
    scanned for them.

    See skeleton.remove_spurs: branch counts are taken once per pass, the next pixel is
    the first unvisited set neighbour in the order E, S, W, N, SE, SW, NW, NE, and a
    staircase step marks the diagonal it skipped as visited. Returns whether anything
    was removed (the caller then thins the skeleton again).

    What the walks need of a pixel besides whether it is set, whether it is a tip
    (branch count 1), a junction (3 or more) and visited, is marked in bits 2, 3 and 1
    of its own byte, not in image-sized arrays (two fewer images written per pass); the
    marks are cleared before it returns.
    """
    height, width = skeleton.shape
    rows = pixels // width
    cols = pixels - rows * width
    # A walk takes at most one step per unit of length, and never revisits a pixel.
    max_steps = min(max(int(min(spur_length, 1e9)), 0), rows.size) + 2
    path_r = np.empty(max_steps + 1, np.int64)
    path_c = np.empty(max_steps + 1, np.int64)
    marked_r = np.empty(8 * (max_steps + 1), np.int64)
    marked_c = np.empty(8 * (max_steps + 1), np.int64)
    cand_r = np.empty(8, np.int64)
    cand_c = np.empty(8, np.int64)
    # Every count read from the skeleton as it is, before any mark is written.
    kinds = np.empty(rows.size, np.uint8)
    for i in range(rows.size):
        count = branch_table[neighbour_pattern(skeleton, rows[i], cols[i])]
        kinds[i] = (_TIP if count == 1 else 0) | (_JUNCTION if count >= 3 else 0)
    for i in range(rows.size):
        skeleton[rows[i], cols[i]] |= kinds[i]
    removed_any = False
    for i in range(rows.size):
        row = rows[i]
        col = cols[i]
        # A removed pixel is 0: no longer a tip.
        if not skeleton[row, col] & _TIP:
            continue
        n_path = 1
        path_r[0] = row
        path_c[0] = col
        n_marked = 1
        marked_r[0] = row
        marked_c[0] = col
        skeleton[row, col] |= _VISITED
        length = 0.0
        reached_junction = False
        while length <= spur_length:
            rc = path_r[n_path - 1]
            cc = path_c[n_path - 1]
            n_cand = 0
            for k in range(8):
                r = rc + ORTHOGONAL_FIRST_DR[k]
                c = cc + ORTHOGONAL_FIRST_DC[k]
                # Set and not visited.
                if 0 <= r < height and 0 <= c < width and skeleton[r, c] & 3 == 1:
                    cand_r[n_cand] = r
                    cand_c[n_cand] = c
                    n_cand += 1
            if n_cand == 0:
                break
            nr = cand_r[0]
            nc = cand_c[0]
            if skeleton[nr, nc] & _JUNCTION or n_cand > 2:
                reached_junction = True
                break
            length += 1.0 if (nr == rc or nc == cc) else 1.4142
            path_r[n_path] = nr
            path_c[n_path] = nc
            n_path += 1
            skeleton[nr, nc] |= _VISITED
            marked_r[n_marked] = nr
            marked_c[n_marked] = nc
            n_marked += 1
            for k in range(1, n_cand):
                if (
                    abs(cand_r[k] - nr) <= 1
                    and abs(cand_c[k] - nc) <= 1
                    and not skeleton[cand_r[k], cand_c[k]] & _VISITED
                ):
                    skeleton[cand_r[k], cand_c[k]] |= _VISITED
                    marked_r[n_marked] = cand_r[k]
                    marked_c[n_marked] = cand_c[k]
                    n_marked += 1
        if reached_junction and length < spur_length:
            for k in range(n_path):
                skeleton[path_r[k], path_c[k]] = 0
            removed_any = True
        for k in range(n_marked):
            skeleton[marked_r[k], marked_c[k]] &= _NOT_VISITED
    for i in range(rows.size):
        skeleton[rows[i], cols[i]] &= _PIXEL_ONLY
    return removed_any
