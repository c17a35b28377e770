"""Compiled loops of :mod:`service.perception.appearance`: colour samples along the end
stretch of every chain end, and their medians.

Plain versions: ``tests/perception/references/appearance.py``.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def _stretch_bounds(total, skip, length):
    """Arc lengths (from the end) of the first and last sample of an end stretch: from
    ``skip`` on, at most ``length`` long, and ``skip`` clear of the piece's other end."""
    start = skip
    stop = min(skip + length, total - skip)
    if stop - start < 1.0:
        start, stop = 0.0, total
    return start, stop


@njit(cache=True, nogil=True)
def end_samples(image, joints, starts, end_piece, end_at_start, skip, length):
    """BGR (0-1) means of the 3x3 pixels round points 1 px apart along each end stretch.

    End ``e`` belongs to piece ``end_piece[e]`` (joints ``joints[starts[k]:starts[k + 1]]``)
    and sits at its first joint when ``end_at_start[e]``, else at its last. Its stretch
    runs from ``skip`` to ``skip + length`` of arc from the end, and stops ``skip``
    before the piece's other end (the whole piece when that leaves under 1 px). Points are
    rounded half to even and the 3x3 neighbourhood is clipped to the image.

    Returns ``(samples, bounds, pixels, lengths)``: end ``e``'s samples are
    ``samples[bounds[e]:bounds[e + 1]]``; ``pixels`` holds each sample's (row, col) and
    ``lengths[e]`` the arc length of the end's piece.
    """
    height, width = image.shape[0], image.shape[1]
    count = end_piece.size
    bounds = np.zeros(count + 1, np.int64)
    # First pass: how many samples each end gets.
    totals = np.empty(count)
    for e in range(count):
        k = end_piece[e]
        total = 0.0
        for i in range(starts[k] + 1, starts[k + 1]):
            total += np.hypot(joints[i, 0] - joints[i - 1, 0], joints[i, 1] - joints[i - 1, 1])
        totals[e] = total
        first, last = _stretch_bounds(total, skip, length)
        bounds[e + 1] = bounds[e] + int(np.floor(last - first + 1e-9)) + 1
    samples = np.empty((bounds[count], 3), np.float32)
    pixels = np.empty((bounds[count], 2), np.int64)
    for e in range(count):
        k = end_piece[e]
        n = starts[k + 1] - starts[k]
        first, last = _stretch_bounds(totals[e], skip, length)
        # Walk the piece from the end, with arc lengths as np.interp sees them.
        segment = 0
        arc_here = 0.0
        arc_next = 0.0
        for s_index in range(bounds[e + 1] - bounds[e]):
            s = first + s_index
            x = 0.0
            y = 0.0
            while True:
                a = starts[k] + segment if end_at_start[e] else starts[k + 1] - 1 - segment
                if segment + 1 >= n:
                    x, y = joints[a, 0], joints[a, 1]
                    break
                b = a + 1 if end_at_start[e] else a - 1
                arc_next = arc_here + np.hypot(
                    joints[b, 0] - joints[a, 0], joints[b, 1] - joints[a, 1]
                )
                if s <= arc_next or segment + 2 >= n:
                    if s >= arc_next:
                        x, y = joints[b, 0], joints[b, 1]
                    elif arc_next > arc_here:
                        t = (s - arc_here) / (arc_next - arc_here)
                        x = joints[a, 0] + t * (joints[b, 0] - joints[a, 0])
                        y = joints[a, 1] + t * (joints[b, 1] - joints[a, 1])
                    else:
                        x, y = joints[b, 0], joints[b, 1]
                    break
                segment += 1
                arc_here = arc_next
            col = min(max(int(np.rint(x)), 0), width - 1)
            row = min(max(int(np.rint(y)), 0), height - 1)
            blue = 0.0
            green = 0.0
            red = 0.0
            for dr in range(-1, 2):
                r = min(max(row + dr, 0), height - 1)
                for dc in range(-1, 2):
                    c = min(max(col + dc, 0), width - 1)
                    blue += image[r, c, 0]
                    green += image[r, c, 1]
                    red += image[r, c, 2]
            out = bounds[e] + s_index
            pixels[out, 0] = row
            pixels[out, 1] = col
            samples[out, 0] = blue / (9.0 * 255.0)
            samples[out, 1] = green / (9.0 * 255.0)
            samples[out, 2] = red / (9.0 * 255.0)
    return samples, bounds, pixels, totals


@njit(cache=True, nogil=True)
def _select(values, low, high, k):
    """Partition ``values[low:high + 1]`` in place (Hoare, median-of-three pivots) until
    ``values[k]`` is its k-th smallest, with none greater before it; return that value."""
    while high > low:
        middle = (low + high) >> 1
        if values[middle] < values[low]:
            values[middle], values[low] = values[low], values[middle]
        if values[high] < values[low]:
            values[high], values[low] = values[low], values[high]
        if values[high] < values[middle]:
            values[high], values[middle] = values[middle], values[high]
        pivot = values[middle]
        i = low
        j = high
        while i <= j:
            while values[i] < pivot:
                i += 1
            while values[j] > pivot:
                j -= 1
            if i <= j:
                values[i], values[j] = values[j], values[i]
                i += 1
                j -= 1
        if k <= j:
            high = j
        elif k >= i:
            low = i
        else:
            break
    return values[k]


@njit(cache=True, nogil=True)
def _median(values, n):
    """The median of ``values[:n]`` (reordered in place), as ``np.median`` of numba: the
    middle value, or the mean of the two middle ones."""
    half = n >> 1
    upper = _select(values, 0, n - 1, half)
    if n & 1:
        return upper
    # The lower middle value is the largest of those partitioned before the upper.
    lower = values[0]
    for i in range(1, half):
        if values[i] > lower:
            lower = values[i]
    return (lower + upper) / 2


@njit(cache=True, nogil=True)
def colour_medians(lab, bounds, wide, min_samples, margin):
    """Per end: the median of each channel of its samples before the first ``wide`` one
    (in order from the end) less ``margin`` more, and the median distance of those from
    that colour (as ``np.median``); NaN for an end with fewer than ``min_samples``.

    The medians are selected in one buffer reused by every end (a median of a few dozen
    samples cost less than the copies and allocations of ``np.median``).
    """
    count = bounds.size - 1
    colour = np.full((count, 3), np.nan)
    spread = np.full(count, np.nan)
    longest = 0
    for e in range(count):
        longest = max(longest, bounds[e + 1] - bounds[e])
    buffer = np.empty(longest)
    for e in range(count):
        stop = bounds[e]
        while stop < bounds[e + 1] and not wide[stop]:
            stop += 1
        if stop < bounds[e + 1]:
            stop = max(stop - margin, bounds[e])
        size = stop - bounds[e]
        if size == 0 or size < min_samples:
            continue
        for channel in range(3):
            for i in range(size):
                buffer[i] = lab[bounds[e] + i, channel]
            colour[e, channel] = _median(buffer, size)
        for i in range(size):
            sample = bounds[e] + i
            buffer[i] = np.sqrt(
                (lab[sample, 0] - colour[e, 0]) ** 2
                + (lab[sample, 1] - colour[e, 1]) ** 2
                + (lab[sample, 2] - colour[e, 2]) ** 2
            )
        spread[e] = _median(buffer, size)
    return colour, spread


@njit(cache=True, nogil=True)
def colour_steps(colour, spread, first, second, tolerance, max_steps, lightness_share):
    """appearance.colour_penalty for the pairs ``first[k]``, ``second[k]``: the Lab
    distance (lightness weighted by ``lightness_share``) beyond ``tolerance`` and both
    ends' ``spread``, in steps of ``tolerance``, clipped to ``[0, max_steps]``; 0 where
    either colour is unknown (NaN)."""
    steps = np.empty(first.size)
    for k in range(first.size):
        i = first[k]
        j = second[k]
        lightness = lightness_share * (colour[i, 0] - colour[j, 0])
        a = colour[i, 1] - colour[j, 1]
        b = colour[i, 2] - colour[j, 2]
        distance = np.sqrt(lightness**2 + a**2 + b**2)
        allowed = tolerance + spread[i] + spread[j]
        step = (distance - allowed) / tolerance
        steps[k] = 0.0 if np.isnan(step) else min(max(step, 0.0), max_steps)
    return steps


@njit(cache=True, nogil=True)
def patches_beside(image, mask, points):
    """Per (x, y) point, the mean BGR colour (``float32``, scaled to 0-1) of the pixels
    off ``mask`` (``uint8``) in the 3x3 patch round its nearest pixel, and whether it can
    be read: the patch inside the picture and the point's own pixel off the mask.

    In NumPy's order and types (``float32`` sums, ``max(count, 1)``, then ``/ 255``),
    so that the colours equal the plain reading's bit for bit; a point whose patch
    leaves the picture (or is not finite) reads the patch at pixel (1, 1), as it does.
    """
    height, width = mask.shape
    n = points.shape[0]
    patches = np.empty((n, 3), np.float32)
    readable = np.empty(n, np.bool_)
    one = np.float32(1.0)
    scale = np.float32(255.0)
    for i in range(n):
        fx = np.rint(points[i, 0])
        fy = np.rint(points[i, 1])
        # Tested on the rounded floats: a NaN or a value past int64 is outside as well.
        inside = fx >= 1.0 and fy >= 1.0 and fx <= width - 2 and fy <= height - 2
        col = int(fx) if inside else 1
        row = int(fy) if inside else 1
        readable[i] = inside and mask[row, col] == 0
        blue = np.float32(0.0)
        green = np.float32(0.0)
        red = np.float32(0.0)
        count = np.float32(0.0)
        for dy in range(-1, 2):
            for dx in range(-1, 2):
                if mask[row + dy, col + dx] == 0:
                    blue += np.float32(image[row + dy, col + dx, 0])
                    green += np.float32(image[row + dy, col + dx, 1])
                    red += np.float32(image[row + dy, col + dx, 2])
                    count += one
        if count < one:
            count = one
        patches[i, 0] = blue / count / scale
        patches[i, 1] = green / count / scale
        patches[i, 2] = red / count / scale
    return patches, readable


@njit(cache=True, nogil=True)
def _step_off(mask, step, fx, fy):
    """1 where the sample at pixel ``(fx, fy)`` (rounded floats) is the march's first off
    ``mask``, 2 where the march's first sample is off it or off the picture (no front), 0
    where it goes on (on the mask, or off the picture past the first sample)."""
    height, width = mask.shape
    inside = 0.0 <= fx < width and 0.0 <= fy < height
    if step == 0 and not (inside and mask[int(fy), int(fx)] != 0):
        return 2
    if inside and mask[int(fy), int(fx)] == 0:
        return 1
    return 0


@njit(cache=True, nogil=True)
def first_off(mask, points):
    """``appearance._first_off``: the arc (px, ``points`` 0.5 px apart) to the first point
    whose pixel (rounded half to even) is on the picture and off ``mask`` (``uint8``);
    NaN when the first point is off the mask or the picture, or no point is off. Points
    off the picture past the first read as on the mask, as NumPy's reading leaves them."""
    for i in range(points.shape[0]):
        state = _step_off(mask, i, np.rint(points[i, 0]), np.rint(points[i, 1]))
        if state == 2:
            return np.nan
        if state == 1:
            return 0.5 * i
    return np.nan


@njit(cache=True, nogil=True)
def front(mask, x, y, dx, dy, count):
    """``appearance._front``: :func:`first_off` along the ``count`` points ``(x, y) +
    (0.5 i) (dx, dy)``, each made as NumPy makes it (the step times the direction, then
    the start added)."""
    for i in range(count):
        step = 0.5 * i
        state = _step_off(mask, i, np.rint(x + step * dx), np.rint(y + step * dy))
        if state == 2:
            return np.nan
        if state == 1:
            return 0.5 * i
    return np.nan
