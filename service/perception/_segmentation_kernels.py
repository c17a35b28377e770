"""Compiled loops of step 1 (:mod:`service.perception.segmentation`).

Otsu's threshold and the brightness histogram, the hysteresis and the clean-up of the
mask (flood fills), and each cable's own threshold (profiles across its centreline).
Plain versions: ``tests/perception/references/segmentation.py``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from service.perception._shared_kernels import ORTHOGONAL_FIRST_DC, ORTHOGONAL_FIRST_DR

# --------------------------------------------------------------------------- thresholds


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

    Two loops, not one: the channel maximum over flat memory vectorizes, and eight
    interleaved histograms keep consecutive pixels of one level from waiting on each
    other's increment (an increment waits on the store of the one before it to the
    same count: with four, the dark background's runs of one level still did). Their
    counts are 32-bit (an eighth of the pixels each: under 2**32 for any image a
    detection takes), half the cache of 64-bit ones, and summed as 64-bit.
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
    partial = np.zeros((8, 256), np.uint32)
    whole = count - count % 8
    for i in range(0, whole, 8):
        partial[0, brightness[i]] += 1
        partial[1, brightness[i + 1]] += 1
        partial[2, brightness[i + 2]] += 1
        partial[3, brightness[i + 3]] += 1
        partial[4, brightness[i + 4]] += 1
        partial[5, brightness[i + 5]] += 1
        partial[6, brightness[i + 6]] += 1
        partial[7, brightness[i + 7]] += 1
    for i in range(whole, count):
        partial[0, brightness[i]] += 1
    counts = np.zeros(256, np.int64)
    for k in range(8):
        for level in range(256):
            counts[level] += partial[k, level]
    return brightness.reshape(height, width), counts


# --------------------------------------------------------------------------- clean-up


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
                    rr = r + ORTHOGONAL_FIRST_DR[k]
                    cc = c + ORTHOGONAL_FIRST_DC[k]
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
def _neighbour_offsets(width, count):
    """Flat-index offsets of the first ``count`` neighbours in ``ORTHOGONAL_FIRST`` order
    (4: the 4-connected ones) in an image ``width`` pixels wide."""
    offsets = np.empty(count, np.int64)
    for k in range(count):
        offsets[k] = ORTHOGONAL_FIRST_DR[k] * width + ORTHOGONAL_FIRST_DC[k]
    return offsets


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
    Neighbours are found by flat offsets, without bounds checks, away from the image's
    border (a fill's pixels always are: one on the border ends it).
    """
    height, width = mask.shape
    size = height * width
    flat = mask.reshape(size)
    state = np.zeros(size, np.uint8)
    offsets = _neighbour_offsets(width, 4)
    # A fill stops before it holds more than ``max_hole_area`` pixels.
    members = np.empty(max_hole_area + 1, np.int64)
    for i0 in range(n_foreground):
        seed = foreground[i0]
        # Most of the foreground lies inside it: told without its row and column when
        # the pixels one row up and down and one index either side are all set (at the
        # first or last column one of those is in the next row, set or not: a pixel the
        # test passes has every neighbour inside the image set, and no fill starts there).
        if (
            width <= seed < size - width
            and flat[seed - 1]
            and flat[seed + 1]
            and flat[seed - width]
            and flat[seed + width]
        ):
            continue
        r0 = seed // width
        c0 = seed - r0 * width
        inner = 0 < r0 < height - 1 and 0 < c0 < width - 1
        for k0 in range(4):
            if inner:
                start = seed + offsets[k0]
            else:
                rs = r0 + ORTHOGONAL_FIRST_DR[k0]
                cs = c0 + ORTHOGONAL_FIRST_DC[k0]
                if not (0 <= rs < height and 0 <= cs < width):
                    continue
                start = rs * width + cs
            if flat[start] or state[start] != _UNSEEN:
                continue
            state[start] = _SMALL_HOLE
            members[0] = start
            count = 1
            head = 0
            is_hole = True
            while head < count and is_hole:
                pixel = members[head]
                head += 1
                r = pixel // width
                c = pixel - r * width
                if r == 0 or c == 0 or r == height - 1 or c == width - 1:
                    is_hole = False
                    break
                for k in range(4):
                    there = pixel + offsets[k]
                    if flat[there]:
                        continue
                    if state[there] == _OPEN:
                        is_hole = False
                        break
                    if state[there] == _UNSEEN:
                        if count >= max_hole_area:
                            is_hole = False
                            break
                        state[there] = _SMALL_HOLE
                        members[count] = there
                        count += 1
            for i in range(count):
                if is_hole:
                    flat[members[i]] = 1
                else:
                    state[members[i]] = _OPEN


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


# Pixels per block of the seeds' scan: a block with no seed is passed over after one
# comparison of its bytes with the seed level, which the compiler vectorizes.
SEED_BLOCK = 64


@njit(cache=True, nogil=True)
def first_level_above(low, high):
    """The first level 0-255 above both thresholds, 256 when none is.

    A level is above both exactly when it is at least this one (the test is monotone in
    the level; a NaN threshold has none above it): ``level > high and level > low``,
    each level compared as ``threshold_and_clean`` compares its ``uint8`` pixels.
    """
    for level in range(256):
        value = np.uint8(level)
        if (value > high) & (value > low):
            return level
    return 256


@njit(cache=True, nogil=True)
def threshold_and_clean(cue, low, high, weak_count, min_area, max_hole_area):
    """Hysteresis threshold, speck removal and hole filling in one pass over the result.

    The hysteresis keeps the pixels above ``low`` that are 8-connected to a pixel above
    ``high``; the result is that mask after ``segmentation.clean_mask(mask, min_area,
    max_hole_area)`` (with both 0, the plain hysteresis). Each flood fill of the
    hysteresis is a whole 8-connected component of the result (two floods never touch,
    or they would be one), so a flood of fewer than ``min_area`` pixels is exactly a
    speck. ``weak_count`` is the number of pixels above ``low`` (from the histogram).

    The seeds (above both thresholds: at least ``first_level_above(low, high)``) are
    visited in raster order, blocks of ``SEED_BLOCK`` pixels without one passed over
    (told by a first pass the compiler vectorizes, without an image of marks); a flood
    finds the neighbours of a pixel away from the image's border by flat offsets,
    without bounds checks. The floods, and so the order of ``members``, are those of a
    plain raster scan. A small hole borders the foreground 4-connected, so only the
    kept pixels with a 4-neighbour at or under ``low`` (every such neighbour is
    background: a pixel above ``low`` next to a flood joins it), and those on the
    image's border, are listed for the holes' fills, as the floods meet them.
    """
    height, width = cue.shape
    size = height * width
    result = np.zeros((height, width), np.uint8)
    flat_cue = cue.reshape(size)
    flat_result = result.reshape(size)
    offsets = _neighbour_offsets(width, 8)
    # Kept components fill ``members`` from the front, removed ones from the back.
    members = np.empty(max(weak_count, 1), np.int64)
    # The kept pixels a hole can border: a speck's are dropped with it.
    edges = np.empty(max(weak_count, 1), np.int64)
    speck = np.empty(max(min_area, 1), np.int64)
    seed_level = first_level_above(low, high)
    seed = np.uint8(min(seed_level, 255))
    n_blocks = (size + SEED_BLOCK - 1) // SEED_BLOCK if seed_level < 256 else 0
    whole_blocks = size // SEED_BLOCK
    has_seed = np.zeros(n_blocks + 1, np.uint8)
    for block in range(min(whole_blocks, n_blocks)):
        hit = 0
        for i in range(SEED_BLOCK * block, SEED_BLOCK * block + SEED_BLOCK):
            hit |= flat_cue[i] >= seed
        has_seed[block] = hit
    if n_blocks > whole_blocks:
        has_seed[whole_blocks] = 1  # the short last block: looked at pixel by pixel
    kept = 0
    removed = 0
    n_edges = 0
    for block in range(n_blocks):
        if has_seed[block] == 0:
            continue
        for index in range(SEED_BLOCK * block, min(SEED_BLOCK * block + SEED_BLOCK, size)):
            if flat_cue[index] < seed or flat_result[index]:
                continue
            flat_result[index] = 1
            members[kept] = index
            edges_before = n_edges
            count = 1
            head = 0
            while head < count:
                here = members[kept + head]
                head += 1
                r = here // width
                c = here - r * width
                if 0 < r < height - 1 and 0 < c < width - 1:
                    # The four 4-connected neighbours come first (ORTHOGONAL_FIRST).
                    edge = False
                    for k in range(4):
                        there = here + offsets[k]
                        if not flat_result[there]:
                            if flat_cue[there] > low:
                                flat_result[there] = 1
                                members[kept + count] = there
                                count += 1
                            else:
                                edge = True
                    for k in range(4, 8):
                        there = here + offsets[k]
                        if not flat_result[there] and flat_cue[there] > low:
                            flat_result[there] = 1
                            members[kept + count] = there
                            count += 1
                    if edge:
                        edges[n_edges] = here
                        n_edges += 1
                    continue
                edges[n_edges] = here
                n_edges += 1
                for k in range(8):
                    rr = r + ORTHOGONAL_FIRST_DR[k]
                    cc = c + ORTHOGONAL_FIRST_DC[k]
                    inside = 0 <= rr < height and 0 <= cc < width
                    if inside and not result[rr, cc] and cue[rr, cc] > low:
                        result[rr, cc] = 1
                        members[kept + count] = rr * width + cc
                        count += 1
            if count >= min_area:
                kept += count
            else:
                n_edges = edges_before
                # Still marked in ``result`` so no pixel of it seeds again; cleared below.
                # Through a buffer: the two stretches of ``members`` may overlap.
                speck[:count] = members[kept : kept + count]
                for i in range(count):
                    members[members.size - 1 - removed - i] = speck[i]
                removed += count
    for i in range(removed):
        flat_result[members[members.size - 1 - i]] = 0
    if max_hole_area > 0:
        _fill_holes_next_to(result, edges, n_edges, max_hole_area)
    return result


@njit(cache=True, nogil=True)
def full_blocks(mask, block):
    """1 for each ``block`` x ``block`` square of a 0/1 image more than half of whose
    pixels are set, else 0: ``cv2.resize(mask, (width // block, height // block),
    interpolation=cv2.INTER_AREA) == 1`` for an image a whole number of blocks wide and
    high and ``block`` 3 to 255 (OpenCV then takes each square's mean, rounded half to
    even: a square exactly half set is 0; its 2 x 2 path rounds halves up). Whole rows
    are added at a time, which vectorizes.
    """
    height, width = mask.shape
    rows, cols = height // block, width // block
    # Per column, the set pixels of the block's rows: whole rows added at a time, in
    # bytes (at most ``block`` each, under 256; 64 columns to a vector instruction).
    # Whole 32-bit words, the spare bytes 0.
    column_counts = np.zeros((width + 3) // 4 * 4, np.uint8)
    quads = column_counts.view(np.uint32)
    full = np.empty((rows, cols), np.uint8)
    for block_row in range(rows):
        column_counts[:] = 0
        for row in range(block_row * block, (block_row + 1) * block):
            for col in range(width):
                column_counts[col] += mask[row, col]
        if block == 4:
            # A block's four counts are one 32-bit word: times 0x01010101 their sum (at
            # most 16, no carry, in either byte order) lands in its top byte. One
            # multiplication per block, not a loop of four, which cost ten times the
            # rows' adds.
            for block_col in range(cols):
                total = ((quads[block_col] * np.uint32(0x01010101)) >> np.uint32(24)) & np.uint32(
                    0xFF
                )
                full[block_row, block_col] = 2 * total > 16
            continue
        for block_col in range(cols):
            total = 0
            for col in range(block_col * block, (block_col + 1) * block):
                total += column_counts[col]
            full[block_row, block_col] = 2 * total > block * block
    return full


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
