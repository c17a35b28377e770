"""Plain colour samples along chain ends (what ``_appearance_kernels`` compiles)."""

import cv2
import numpy as np

from service.perception.appearance import EndColours, colour_penalty


def end_stretch(points, at_start, skip, length):
    """Points 1 px apart along a piece from ``skip`` to ``skip + length`` of arc from an
    end, stopping ``skip`` before the other end (the whole piece if under 1 px is left)."""
    ordered = points if at_start else points[::-1]
    steps = np.hypot(*np.diff(ordered, axis=0).T)
    arc = np.concatenate([[0.0], np.cumsum(steps)])
    start, stop = skip, min(skip + length, arc[-1] - skip)
    if stop - start < 1.0:
        start, stop = 0.0, arc[-1]
    s = np.arange(start, stop + 1e-9, 1.0)
    return np.column_stack([np.interp(s, arc, ordered[:, 0]), np.interp(s, arc, ordered[:, 1])])


def bgr_means(image_bgr, points):
    """BGR (0-1) mean of the 3x3 pixels round each point, clipped to the image."""
    height, width = image_bgr.shape[:2]
    cols = np.clip(np.rint(points[:, 0]).astype(np.int64), 0, width - 1)
    rows = np.clip(np.rint(points[:, 1]).astype(np.int64), 0, height - 1)
    total = np.zeros((len(points), 3))
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            r = np.clip(rows + dr, 0, height - 1)
            c = np.clip(cols + dc, 0, width - 1)
            total += image_bgr[r, c].astype(np.float64)
    return total / (9.0 * 255.0)


def stretch_colours(image_bgr, pieces, ends, skip, length, distance, max_distance, min_samples):
    """Per end: the median Lab colour along its stretch from ``skip`` and the samples'
    median distance, of the samples (1 px apart) more than ``ceil(max_distance)`` before
    the first where ``distance`` exceeds ``max_distance`` (NaN with fewer than
    ``min_samples``)."""
    colour, spread = np.full((len(ends), 3), np.nan), np.full(len(ends), np.nan)
    for index, end in enumerate(ends):
        points = end_stretch(pieces[end.piece], end.at_start, skip, length)
        if distance is not None:
            height, width = distance.shape
            cols = np.clip(np.rint(points[:, 0]).astype(np.int64), 0, width - 1)
            rows = np.clip(np.rint(points[:, 1]).astype(np.int64), 0, height - 1)
            wide = np.flatnonzero(distance[rows, cols] > max_distance)
            if len(wide):
                points = points[: max(wide[0] - int(np.ceil(max_distance)), 0)]
        if len(points) < min_samples:
            continue
        bgr = bgr_means(image_bgr, points)
        lab = cv2.cvtColor(bgr.astype(np.float32).reshape(-1, 1, 3), cv2.COLOR_BGR2LAB)
        lab = lab.reshape(-1, 3).astype(np.float64)
        colour[index] = np.median(lab, axis=0)
        spread[index] = np.median(np.sqrt(((lab - colour[index]) ** 2).sum(axis=1)))
    return colour, spread


def end_colours(
    image_bgr, pieces, ends, skip, length, distance=None, max_distance=np.inf, min_samples=1
):
    """Per end: :func:`stretch_colours` from ``skip``; NaN for every end of a piece
    shorter than ``3 * skip``, and for an end whose colour differs (a colour penalty above
    0) from its piece's next stretch (from ``skip + length``, where the piece is at least
    ``2 * skip + length + 1`` long), unless the stretch after that (from
    ``skip + 2 * length``, where the piece is at least ``2 * (skip + 2 * length) + 1``
    long) is known and alike (a colour penalty of 0) the next: then the next's colour."""

    def colours(start):
        return stretch_colours(
            image_bgr, pieces, ends, start, length, distance, max_distance, min_samples
        )

    colour, spread = colours(skip)
    body, body_spread = colours(skip + length)
    deep, deep_spread = colours(skip + 2 * length)
    for index, end in enumerate(ends):
        total = np.hypot(*np.diff(pieces[end.piece], axis=0).T).sum()
        if total < 3 * skip:
            colour[index], spread[index] = np.nan, np.nan
            continue
        if total - (skip + length) - skip < 1.0:
            continue
        both = EndColours(
            np.array([colour[index], body[index]]),
            np.array([spread[index], body_spread[index]]),
        )
        if colour_penalty(both, np.array([0]), np.array([1]))[0] > 0:
            colour[index], spread[index] = np.nan, np.nan
            if total - 2 * (skip + 2 * length) < 1.0:
                continue
            inner = EndColours(
                np.array([body[index], deep[index]]),
                np.array([body_spread[index], deep_spread[index]]),
            )
            known = not np.isnan(inner.spread).any()
            if known and colour_penalty(inner, np.array([0]), np.array([1]))[0] == 0:
                colour[index], spread[index] = body[index], body_spread[index]
    return colour, spread


def first_wide_less_margin(at, bounds, limits):
    """``appearance._first_wide_less_margin`` end by end: per end, the first sample past
    its limit (compared as NumPy compares the array with a Python float), less that
    limit rounded up, marked alone."""
    wide = np.zeros(len(at), np.bool_)
    for end, limit in enumerate(limits.tolist()):
        start, stop = int(bounds[end]), int(bounds[end + 1])
        past = np.flatnonzero(at[start:stop] > limit)
        if len(past):
            wide[max(start + int(past[0]) - int(np.ceil(limit)), start)] = True
    return wide


def lab_beside(image_bgr, mask, points):
    """Lab colour of the mean of the off-mask pixels in the 3x3 patch round each point
    (NaN where the point's pixel is on the mask or the patch leaves the picture): the
    NumPy reading ``appearance._lab_beside`` compiled."""
    height, width = mask.shape
    cols = np.rint(points[:, 0]).astype(np.int64)
    rows = np.rint(points[:, 1]).astype(np.int64)
    inside = (cols >= 1) & (rows >= 1) & (cols <= width - 2) & (rows <= height - 2)
    cols, rows = np.where(inside, cols, 1), np.where(inside, rows, 1)
    readable = inside & ~mask[rows, cols]
    sums = np.zeros((len(points), 3), np.float32)
    counts = np.zeros(len(points), np.float32)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            off = ~mask[rows + dy, cols + dx]
            sums += off[:, None] * image_bgr[rows + dy, cols + dx].astype(np.float32)
            counts += off
    patches = sums / np.maximum(counts, 1.0)[:, None] / 255.0
    lab = cv2.cvtColor(patches.reshape(-1, 1, 3), cv2.COLOR_BGR2LAB).reshape(-1, 3)
    lab[~readable] = np.nan
    return lab


def first_off(mask, points):
    """Arc (px, ``points`` 0.5 px apart) to the first point on the picture and off
    ``mask``; NaN when the first is off the mask or the picture, or none is off: the
    NumPy reading ``appearance._first_off`` compiled."""
    height, width = mask.shape
    count = len(points)
    cols = np.rint(points[:, 0]).astype(np.int64)
    rows = np.rint(points[:, 1]).astype(np.int64)
    inside = (cols >= 0) & (rows >= 0) & (cols < width) & (rows < height)
    if not inside[0] or not mask[rows[0], cols[0]]:
        return np.nan
    on = np.ones(count, bool)
    on[inside] = mask[rows[inside], cols[inside]]
    off = np.flatnonzero(~on)
    if len(off) == 0 or not inside[off[0]]:
        return np.nan
    return 0.5 * float(off[0])


def front(mask, start, direction, count):
    """:func:`first_off` along ``count`` points 0.5 px apart from ``start`` along
    ``direction``: ``appearance._front`` as NumPy read it."""
    points = start[None, :] + (0.5 * np.arange(count))[:, None] * direction[None, :]
    return first_off(mask, points)
