"""Compiled helpers that the kernels of several steps share (numba, one thread, no GIL).

Neighbour tables and patterns, lists of set pixels, OpenCV's chamfer distance transform
and NumPy's order of summation. Every kernel module of the perception core (the
``_<step>_kernels.py`` beside each step) reproduces, bit for bit, the plain NumPy /
OpenCV code it replaced; the plain versions are kept as references in
``tests/perception/references/`` and the kernels are tested against them. The speed
comes from touching only the pixels that matter (the border of the mask while it is
thinned, the skeleton pixels afterwards) instead of whole images, and from walking
contours in one compiled loop instead of one Python step per pixel.

Kernel modules import only numpy, numba and other kernel modules, never a step module.
Kernels take ``uint8`` views of boolean images (0 or 1). ``cache=True`` keeps the machine
code in ``__pycache__`` (or numba's user cache when that is not writable), so only the
first run on a machine compiles; :func:`service.perception.warm_up` then loads every
kernel so that the first real image pays nothing.
"""

from __future__ import annotations

import numpy as np
from numba import njit

# --------------------------------------------------------------------------- neighbours

# Offsets (row, col) of the 8 neighbours in the order of the branch-count bits
# (clockwise from east): bit k of a neighbour pattern is offset k.
RING_DR = np.array([0, 1, 1, 1, 0, -1, -1, -1], np.int64)
RING_DC = np.array([1, 1, 0, -1, -1, -1, 0, 1], np.int64)
# The 8 neighbours, the 4 orthogonal ones first: 4-connected fills use the first four,
# and a spur walk tries them first so that it does not skip the pixel of a staircase.
ORTHOGONAL_FIRST_DR = np.array([0, 1, 0, -1, 1, 1, -1, -1], np.int64)
ORTHOGONAL_FIRST_DC = np.array([1, 0, -1, 0, 1, -1, -1, 1], np.int64)


@njit(cache=True, nogil=True)
def neighbour_pattern(skeleton, row, col):
    """8-bit pattern of the set neighbours (bit k: ring offset k); outside is unset."""
    height, width = skeleton.shape
    pattern = 0
    for k in range(8):
        r = row + RING_DR[k]
        c = col + RING_DC[k]
        if 0 <= r < height and 0 <= c < width and skeleton[r, c]:
            pattern |= 1 << k
    return pattern


# --------------------------------------------------------------------------- pixel lists

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
def set_pixels(image):
    """Rows and columns of the set pixels of a C-contiguous image, in row-major order."""
    width = image.shape[1]
    indices = nonzero_flat(image.reshape(image.size))
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
        counts[k] = branch_table[neighbour_pattern(skeleton, rows[k], cols[k])]
    return counts


# --------------------------------------------------------------------------- distance

# OpenCV's 5x5 chamfer distance (cv2.DIST_L2, mask 5): steps of 1 (axial), 1.4
# (diagonal) and 2.1969 (knight's move), added in float32 as cv2.distanceTransform
# (OpenCV 5) adds them; the outside of the image is "far" (FLT_MAX).
_HV_DIST = np.float32(1.0)
_DIAG_DIST = np.float32(1.4)
_LONG_DIST = np.float32(2.1969)
_DIST_MAX = np.float32(np.finfo(np.float32).max)


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
def chamfer_values(rows, cols, height, width, ridges):
    """OpenCV's two-pass 5x5 chamfer distance at the foreground pixels only.

    ``rows, cols`` list the foreground in row-major order; the distances come back in
    the same order. No image-sized array is made: the two rows above (below, going
    back) live in three small row buffers, background 0 and the outside of the image
    OpenCV's "far" value. The additions and minima are OpenCV's (float32), so the
    values are identical to ``cv2.distanceTransform(mask, cv2.DIST_L2, 5)``.

    ``ridges``: empty, or one byte per pixel, zeros, set to 1 at each pixel away from the
    image's border no farther from the border than any of its eight neighbours (see
    :func:`_mark_ridges`), while the backward pass has the three rows round it final
    in its buffers.
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
        if ridges.size > 0 and r + 1 <= last:
            # Rows r to r + 2 are final now (r + 2 holds 0s past the last row).
            _mark_ridges(ridges, starts, cols, r + 1, height, width, here, down1, down2)
    if ridges.size > 0:
        # Nothing lies above the first row: its row above is all background.
        below = buffers[(first + 1) % 3] if first + 1 < height else far
        above = np.zeros(width + 4, np.float32)
        _mark_ridges(ridges, starts, cols, first, height, width, above, buffers[first % 3], below)
    return values


@njit(cache=True, nogil=True)
def _mark_ridges(ridges, starts, cols, row, height, width, above, middle, below):
    """Set ``ridges`` to 1 at the pixels of ``row`` (away from the image's border) whose
    distance is no smaller than any of their eight neighbours', to 0 at its others (the
    first and last rows are left as they are), the rows' distances given in chamfer
    buffers (index = column + 2, background 0)."""
    if row == 0 or row == height - 1:
        return
    for k in range(starts[row], starts[row + 1]):
        col = cols[k]
        c = col + 2
        # No smaller than each neighbour is no smaller than their largest (distances are
        # never NaN): seven maxima and no branch, where the eight comparisons in turn,
        # each a branch taken as often as not, cost 0.04 ms more a photograph.
        largest = max(
            max(max(above[c - 1], above[c]), max(above[c + 1], middle[c - 1])),
            max(max(middle[c + 1], below[c - 1]), max(below[c], below[c + 1])),
        )
        ridges[k] = (middle[c] >= largest) & (col != 0) & (col != width - 1)


@njit(cache=True, nogil=True)
def distance_transform(mask):
    """``cv2.distanceTransform(mask, cv2.DIST_L2, 5)``, bit for bit, in O(foreground)."""
    height, width = mask.shape
    distance = np.zeros((height, width), np.float32)
    rows, cols = set_pixels(mask)
    values = chamfer_values(rows, cols, height, width, np.empty(0, np.uint8))
    for k in range(rows.size):
        distance[rows[k], cols[k]] = values[k]
    return distance


@njit(cache=True, nogil=True)
def distance_and_ridges(mask):
    """:func:`distance_transform`, and the distances at its ridge pixels and its largest.

    The ridge pixels are those away from the image's border whose distance is no
    smaller than any of their eight neighbours' (in raster order; background is 0),
    the largest distance is over every foreground pixel (0 when none). Read in the
    backward pass, from the rows' distances in its buffers while they are final: no
    second scan of the image for the mask's pixels, no second read of the distances
    (``tests/perception/references/segmentation.py``, ``ridges``).
    """
    height, width = mask.shape
    distance = np.zeros((height, width), np.float32)
    rows, cols = set_pixels(mask)
    marks = np.zeros(max(rows.size, 1), np.uint8)
    values = chamfer_values(rows, cols, height, width, marks)
    ridge = np.empty(rows.size, np.float32)
    n = 0
    largest = 0.0
    for k in range(rows.size):
        value = values[k]
        distance[rows[k], cols[k]] = value
        if value > largest:
            largest = value
        ridge[n] = value
        n += marks[k]
    return distance, ridge[:n], largest


# --------------------------------------------------------------------------- borders


@njit(cache=True, nogil=True)
def border_distance(mask, x, y, dx, dy, steps, reach, half_step, past_first_on):
    """Distance (px) from ``(x, y)`` along ``(dx, dy)`` to the first of the sample
    ``steps`` (px, increasing) whose pixel (rounded half to even, as Python's ``round``)
    is off ``mask`` (``uint8``) or the image, less ``half_step``; ``reach`` when none is.
    With ``past_first_on`` the first off the mask past the first on it, and NaN where no
    sample is on the mask."""
    height, width = mask.shape
    entered = not past_first_on
    for k in range(steps.size):
        step = steps[k]
        column = int(np.rint(x + step * dx))
        row = int(np.rint(y + step * dy))
        if 0 <= column < width and 0 <= row < height and mask[row, column] != 0:
            entered = True
        elif entered:
            return step - half_step
    return reach if entered else np.nan


@njit(cache=True, nogil=True)
def _on_mask(mask, x, y):
    """Whether the pixel nearest ``(x, y)`` (half to even, as Python's ``round``) is on
    ``mask``; False outside the picture (tested on the rounded floats)."""
    height, width = mask.shape
    column = np.rint(x)
    row = np.rint(y)
    return 0.0 <= column < width and 0.0 <= row < height and mask[int(row), int(column)] != 0


@njit(cache=True, nogil=True)
def _recentred(plus, minus, half_width, agrees):
    """``cut_ends._recentred``: the shift along the normal's plus side that puts a point
    half the width in from its borders ``plus`` and ``minus`` px away."""
    full = 2.0 * half_width
    if abs(plus + minus - full) <= agrees * full:
        return 0.5 * (plus - minus)
    near = agrees * full
    plus_own = abs(plus - half_width) <= near
    minus_own = abs(minus - half_width) <= near
    if plus_own and not minus_own:
        return plus - half_width
    if minus_own and not plus_own:
        return half_width - minus
    return 0.0


@njit(cache=True, nogil=True)
def _section(mask, x, y, hx, hy, steps, reach, half_step):
    """The distances (plus, minus) from ``(x, y)`` to the mask's borders across the
    heading ``(hx, hy)``: along its normal ``(-hy, hx)`` and the opposite way
    (:func:`border_distance`)."""
    plus = border_distance(mask, x, y, -hy, hx, steps, reach, half_step, False)
    minus = border_distance(mask, x, y, hy, -hx, steps, reach, half_step, False)
    return plus, minus


@njit(cache=True, nogil=True)
def middle_line(
    mask,
    x,
    y,
    hx,
    hy,
    cos,
    sin,
    half_width,
    n_steps,
    steps,
    reach,
    half_step,
    trace_step,
    narrowing,
    agrees,
    first_narrowing,
):
    """``cut_ends.middle_line``'s trace from ``(x, y)`` (on ``mask``) along ``(hx, hy)``,
    turning by the rotation ``(cos, sin)`` per step: at most ``n_steps`` steps of
    ``trace_step`` px, each put back on the middle from its borders read across it
    (:func:`border_distance` over ``steps``, ``reach``, ``half_step``), stopping at a
    section narrower than ``2 * half_width - narrowing`` that the next one confirms
    (or the first, with ``first_narrowing``), or off the mask.

    The same operations in the same order as the Python loop it replaced, and Python's
    ``min``/``max`` (the first of equals), so the points are the same bit for bit.

    Returns the points ``(K, 2)``, whether it stopped at a cut, and each point's
    shortfall ``(K,)``."""
    points = np.empty((n_steps + 1, 2))
    shortfall = np.zeros(n_steps + 1)
    points[0, 0] = x
    points[0, 1] = y
    nx = -hy
    ny = hx
    full = 2.0 * half_width - narrowing
    plus, minus = _section(mask, x, y, hx, hy, steps, reach, half_step)
    if plus + minus >= full:
        shift = _recentred(plus, minus, half_width, agrees)
        if _on_mask(mask, x + shift * nx, y + shift * ny):
            x = x + shift * nx
            y = y + shift * ny
            points[0, 0] = x
            points[0, 1] = y
    k = 1
    cut = False
    for _ in range(n_steps):
        x = x + trace_step * hx
        y = y + trace_step * hy
        nx = -hy
        ny = hx
        if _on_mask(mask, x, y):
            plus, minus = _section(mask, x, y, hx, hy, steps, reach, half_step)
            if plus + minus < full:
                confirmed = first_narrowing
                if not confirmed:
                    # The next section narrower too (else this one was the rounding).
                    ax = x + trace_step * hx
                    ay = y + trace_step * hy
                    confirmed = True
                    if _on_mask(mask, ax, ay):
                        ahead_plus, ahead_minus = _section(
                            mask, ax, ay, hx, hy, steps, reach, half_step
                        )
                        confirmed = not ahead_plus + ahead_minus >= full
                if confirmed:
                    cut = True
                    break
            narrower = 2.0 * half_width - plus - minus
            if narrower < 0.0:
                narrower = 0.0
            shift = _recentred(plus, minus, half_width, agrees)
            if -trace_step > shift:
                shift = -trace_step
            if trace_step < shift:
                shift = trace_step
            x = x + shift * nx
            y = y + shift * ny
        else:
            narrower = 0.0
        if not _on_mask(mask, x, y):
            cut = True
            break
        points[k, 0] = x
        points[k, 1] = y
        shortfall[k] = narrower
        k += 1
        hx, hy = cos * hx - sin * hy, sin * hx + cos * hy
    return points[:k].copy(), cut, shortfall[:k].copy()


# --------------------------------------------------------------------------- sums


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
def pairwise_sum(values, start, stop):
    """``values[start:stop].sum()`` added in NumPy's order, bit for bit.

    NumPy sums blocks of up to 128 values with eight running sums and splits longer
    arrays in two (the first part a multiple of 8 long), recursively; the recursion is
    unrolled here on a small stack. Summing in the same order keeps the chain lengths,
    and so the order of the chains, exactly those NumPy's ``sum`` gives.
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
def solve_small(matrix, rhs):
    """Solve ``matrix @ x = rhs`` for a tiny square system by Gaussian elimination.

    Partial pivoting, as LAPACK's ``gesv``; ``rhs`` has one column per right-hand side.
    Returns ``(determinant, x)``; ``x`` is meaningless when the determinant is 0. Used
    instead of ``np.linalg`` so that no kernel needs LAPACK: numba would otherwise load
    SciPy's linear algebra (about 0.2 s) in every process that runs a detection.
    """
    n = matrix.shape[0]
    a = matrix.copy()
    x = rhs.copy()
    determinant = 1.0
    for column in range(n):
        pivot = column
        for row in range(column + 1, n):
            if abs(a[row, column]) > abs(a[pivot, column]):
                pivot = row
        if a[pivot, column] == 0.0:
            return 0.0, x
        if pivot != column:
            determinant = -determinant
            for k in range(n):
                a[column, k], a[pivot, k] = a[pivot, k], a[column, k]
            for k in range(x.shape[1]):
                x[column, k], x[pivot, k] = x[pivot, k], x[column, k]
        determinant *= a[column, column]
        for row in range(column + 1, n):
            factor = a[row, column] / a[column, column]
            for k in range(column, n):
                a[row, k] -= factor * a[column, k]
            for k in range(x.shape[1]):
                x[row, k] -= factor * x[column, k]
    for column in range(n - 1, -1, -1):
        for k in range(x.shape[1]):
            total = x[column, k]
            for j in range(column + 1, n):
                total -= a[column, j] * x[j, k]
            x[column, k] = total / a[column, column]
    return determinant, x
