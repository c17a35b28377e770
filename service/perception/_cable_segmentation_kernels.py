"""Compiled pixel loops of the cable-contrast segmentation (:mod:`cable_segmentation`).

Colours are CIELAB as OpenCV stores it in ``uint8`` (L scaled by 255/100, a and b
offset by 128); the kernels convert to CIELAB units (L 0..100, a and b about -128..127)
as they read, so that every distance is a CIELAB colour difference (Delta E 1976).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from service.perception._shared_kernels import RING_DC, RING_DR

_L_SCALE = np.float32(100.0 / 255.0)
_AB_OFFSET = np.float32(128.0)


@njit(cache=True, nogil=True, inline="always")
def _distance2(c0, c1, c2, colours, y, x):
    """Squared CIELAB distance from ``(c0, c1, c2)`` to ``colours[y, x]``."""
    d0 = c0 - colours[y, x, 0]
    d1 = c1 - colours[y, x, 1]
    d2 = c2 - colours[y, x, 2]
    return d0 * d0 + d1 * d1 + d2 * d2


@njit(cache=True, nogil=True)
def _line_geometry(cos_t, sin_t, half_length, height, width):
    """How a family of parallel digital lines at angle ``t`` crosses the image.

    Lines run along x (``along_x``) when they are closer to horizontal, else along y;
    a line with offset ``o`` visits ``(s, o + round(s * slope))`` in (along, across)
    coordinates. Returns ``along_x, slope, n_along, n_across, half_samples``, where
    ``half_samples`` is the number of steps along the line on each side of a pixel
    that spans ``half_length`` px.
    """
    along_x = abs(cos_t) >= abs(sin_t)
    if along_x:
        slope = sin_t / cos_t
        n_along, n_across = width, height
        half_samples = round(half_length * abs(cos_t))
    else:
        slope = cos_t / sin_t
        n_along, n_across = height, width
        half_samples = round(half_length * abs(sin_t))
    return along_x, slope, n_along, n_across, half_samples


@njit(cache=True, nogil=True)
def _planar(lab8):
    """``uint8`` OpenCV Lab to float32 CIELAB units, one plane per channel: ``(3, H, W)``."""
    height, width, _ = lab8.shape
    out = np.empty((3, height, width), np.float32)
    for y in range(height):
        for x in range(width):
            out[0, y, x] = lab8[y, x, 0] * _L_SCALE
            out[1, y, x] = np.float32(lab8[y, x, 1]) - _AB_OFFSET
            out[2, y, x] = np.float32(lab8[y, x, 2]) - _AB_OFFSET
    return out


@njit(cache=True, nogil=True, inline="always")
def _window_add(lab, y, x, sign, t0, t1, t2, t3):
    """A window's sums of the three channels and of their squares, with the colour at
    ``(y, x)`` added (``sign`` 1) or taken off (-1)."""
    c0 = lab[0, y, x]
    c1 = lab[1, y, x]
    c2 = lab[2, y, x]
    return (
        t0 + sign * c0,
        t1 + sign * c1,
        t2 + sign * c2,
        t3 + sign * (c0 * c0 + c1 * c1 + c2 * c2),
    )


@njit(cache=True, nogil=True)
def _line_means(lab, cos_t, sin_t, half_length, mean, var, buf_y, buf_x):
    """Mean colour and colour variance over the line segment through each pixel.

    ``lab`` and ``mean`` are ``(3, H, W)`` planes. The segment is ``2 * half_length`` px
    long at angle ``t`` (cosine and sine given) and centred on the pixel, cut short at
    the image border. Sums sliding along each digital line of the family make it O(1)
    per pixel whatever the length.
    """
    _, height, width = lab.shape
    along_x, slope, n_along, n_across, a = _line_geometry(cos_t, sin_t, half_length, height, width)
    # A line with offset ``line`` visits (s, line + rise[s]); ``rise`` is monotonic, so the
    # stretch inside the image is one run of s, found by bisection.
    rise = np.empty(n_along, np.int64)
    for s in range(n_along):
        rise[s] = int(np.floor(s * slope + 0.5))
    ascending = rise if slope >= 0 else rise[::-1].copy()
    reach = int(np.ceil(abs(slope) * n_along)) + 1
    for line in range(-reach, n_across + reach):
        # 0 <= line + rise[s] <= n_across - 1
        if slope >= 0:
            first = np.searchsorted(ascending, -line, side="left")
            stop = np.searchsorted(ascending, n_across - 1 - line, side="right")
        else:
            # rise[s] = ascending[n_along - 1 - s]
            first = n_along - np.searchsorted(ascending, n_across - 1 - line, side="right")
            stop = n_along - np.searchsorted(ascending, -line, side="left")
        n = stop - first
        if n <= 0:
            continue
        for i in range(n):
            s = first + i
            o = line + rise[s]
            if along_x:
                buf_y[i] = o
                buf_x[i] = s
            else:
                buf_y[i] = s
                buf_x[i] = o
        # A window of 2a + 1 samples slides along the line: each sample is added once
        # as it enters and taken off once as it leaves.
        t0 = t1 = t2 = t3 = 0.0
        count = 0
        for j in range(min(a, n - 1) + 1):
            t0, t1, t2, t3 = _window_add(lab, buf_y[j], buf_x[j], 1.0, t0, t1, t2, t3)
            count += 1
        for i in range(n):
            if i > 0:
                j = i + a
                if j < n:
                    t0, t1, t2, t3 = _window_add(lab, buf_y[j], buf_x[j], 1.0, t0, t1, t2, t3)
                    count += 1
                j = i - a - 1
                if j >= 0:
                    t0, t1, t2, t3 = _window_add(lab, buf_y[j], buf_x[j], -1.0, t0, t1, t2, t3)
                    count -= 1
            inv = 1.0 / count
            m0 = t0 * inv
            m1 = t1 * inv
            m2 = t2 * inv
            y = buf_y[i]
            x = buf_x[i]
            mean[0, y, x] = m0
            mean[1, y, x] = m1
            mean[2, y, x] = m2
            v = t3 * inv - (m0 * m0 + m1 * m1 + m2 * m2)
            var[y, x] = v if v > 0.0 else 0.0


@njit(cache=True, nogil=True, inline="always")
def _planar_distance2(m0, m1, m2, planes, y, x):
    """Squared CIELAB distance from ``(m0, m1, m2)`` to ``planes[:, y, x]``."""
    d0 = m0 - planes[0, y, x]
    d1 = m1 - planes[1, y, x]
    d2 = m2 - planes[2, y, x]
    return d0 * d0 + d1 * d1 + d2 * d2


@njit(cache=True, nogil=True, inline="always")
def _side_contrast(mean, background, wide, var, floor, y, x, y1, x1, y2, x2):
    """Squared line ratio of pixel ``(y, x)`` with its sides at ``(y1, x1)`` and ``(y2, x2)``."""
    m0 = mean[0, y, x]
    m1 = mean[1, y, x]
    m2 = mean[2, y, x]
    contrast2 = min(
        min(
            _planar_distance2(m0, m1, m2, mean, y1, x1),
            _planar_distance2(m0, m1, m2, mean, y2, x2),
        ),
        min(
            _planar_distance2(m0, m1, m2, background, y, x),
            _planar_distance2(m0, m1, m2, wide, y, x),
        ),
    )
    return contrast2 / (var[y, x] + floor)


@njit(cache=True, nogil=True)
def level_contrast(lab8, background8, wide8, n_orientations, half_length, offset, floor2):
    """Line contrast of every pixel of one pyramid level, and the angle that gives it.

    For each of ``n_orientations`` angles, the mean colour along the line segment
    through a pixel is compared with the means along the parallel segments ``offset``
    px to either side and with the local background colours (``background8`` and
    ``wide8``, medians over two windows); the smallest of the colour differences is the
    line's contrast, and divided by the spread of colours along the line (``floor2``
    added to the variance) it is the line's contrast-to-spread ratio. A cable along the
    line gives a high ratio: a uniform colour that differs from both sides and from the
    background. A step edge (one side the same), texture (a large spread) and the
    background between two cables (the background colour) give a low one. A side segment
    that would lie beyond the picture is taken at the picture's edge.

    Returns
    -------
    ratio : ndarray of float32
        ``(H, W)``: the largest ratio over the angles.
    orientation : ndarray of uint8
        ``(H, W)``: the index of the angle (``pi * k / n_orientations``) that gave it.
    """
    height, width, _ = lab8.shape
    lab = _planar(lab8)
    background = _planar(background8)
    wide = _planar(wide8)
    mean = np.empty((3, height, width), np.float32)
    var = np.empty((height, width), np.float32)
    longest = max(height, width) + 2
    buf_y = np.empty(longest, np.int64)
    buf_x = np.empty(longest, np.int64)
    best = np.zeros((height, width), np.float32)
    orientation = np.zeros((height, width), np.uint8)
    row = np.empty(width, np.float32)
    floor = np.float32(floor2)
    for k in range(n_orientations):
        angle = np.pi * k / n_orientations
        cos_t = np.cos(angle)
        sin_t = np.sin(angle)
        _line_means(lab, cos_t, sin_t, half_length, mean, var, buf_y, buf_x)
        dy = round(offset * cos_t)
        dx = round(-offset * sin_t)
        # A side beyond the picture is taken at its edge: a line running out of the
        # picture is judged up to the edge, and one along the edge, whose clamped side
        # falls on the line itself, is not taken for a line.
        x_lo = min(abs(dx), width)
        x_hi = max(width - abs(dx), x_lo)
        for y in range(height):
            y1 = min(max(y + dy, 0), height - 1)
            y2 = min(max(y - dy, 0), height - 1)
            for x in range(x_lo, x_hi):
                row[x] = _side_contrast(
                    mean, background, wide, var, floor, y, x, y1, x + dx, y2, x - dx
                )
            # The columns near the left and right edges, their sides clamped.
            for edge in range(x_lo + width - x_hi):
                x = edge if edge < x_lo else x_hi + edge - x_lo
                x1 = min(max(x + dx, 0), width - 1)
                x2 = min(max(x - dx, 0), width - 1)
                row[x] = _side_contrast(mean, background, wide, var, floor, y, x, y1, x1, y2, x2)
            for x in range(width):
                if row[x] > best[y, x]:
                    best[y, x] = row[x]
                    orientation[y, x] = k
    for y in range(height):
        for x in range(width):
            best[y, x] = np.sqrt(best[y, x])
    return best, orientation


@njit(cache=True, nogil=True)
def keep_larger(best, best_level, values, level):
    """Where ``values`` exceeds ``best``, take it and mark the pixel as ``level``'s (ties
    stay with the level already there)."""
    height, width = best.shape
    for y in range(height):
        for x in range(width):
            if values[y, x] > best[y, x]:
                best[y, x] = values[y, x]
                best_level[y, x] = level


@njit(cache=True, nogil=True)
def seed_colours(lab8, background8, rows, cols, orientation, n_orientations, half_length, offset):
    """The cable colour and the colours around it at seed pixels of one level.

    The same line means as :func:`level_contrast`, summed directly at each seed (in
    the seed's own best angle): the mean colour along the line, and along the parallel
    lines ``offset`` px to either side; and the local background colour there.

    Returns
    -------
    ndarray of float32
        ``(N, 4, 3)``: per seed, the cable colour, side one, side two and the
        background (CIELAB).
    """
    height, width, _ = lab8.shape
    n = rows.size
    out = np.zeros((n, 4, 3), np.float32)
    for i in range(n):
        y0 = rows[i]
        x0 = cols[i]
        angle = np.pi * orientation[y0, x0] / n_orientations
        cos_t = np.cos(angle)
        sin_t = np.sin(angle)
        along_x, slope, n_along, n_across, a = _line_geometry(
            cos_t, sin_t, half_length, height, width
        )
        dy = round(offset * cos_t)
        dx = round(-offset * sin_t)
        for which in range(3):
            sy = dy if which == 1 else (-dy if which == 2 else 0)
            sx = dx if which == 1 else (-dx if which == 2 else 0)
            cy = min(max(y0 + sy, 0), height - 1)
            cx = min(max(x0 + sx, 0), width - 1)
            # Walk the digital line through (cy, cx) as _line_means does.
            if along_x:
                s0 = cx
                line = cy - int(np.floor(s0 * slope + 0.5))
            else:
                s0 = cy
                line = cx - int(np.floor(s0 * slope + 0.5))
            total0 = 0.0
            total1 = 0.0
            total2 = 0.0
            count = 0
            for s in range(s0 - a, s0 + a + 1):
                if s < 0 or s >= n_along:
                    continue
                o = line + int(np.floor(s * slope + 0.5))
                if o < 0 or o >= n_across:
                    continue
                if along_x:
                    py, px = o, s
                else:
                    py, px = s, o
                total0 += lab8[py, px, 0] * _L_SCALE
                total1 += np.float32(lab8[py, px, 1]) - _AB_OFFSET
                total2 += np.float32(lab8[py, px, 2]) - _AB_OFFSET
                count += 1
            if count:
                out[i, which, 0] = total0 / count
                out[i, which, 1] = total1 / count
                out[i, which, 2] = total2 / count
        out[i, 3, 0] = background8[y0, x0, 0] * _L_SCALE
        out[i, 3, 1] = np.float32(background8[y0, x0, 1]) - _AB_OFFSET
        out[i, 3, 2] = np.float32(background8[y0, x0, 2]) - _AB_OFFSET
    return out


@njit(cache=True, nogil=True)
def colour_class_within_reach(
    lab8, centres_y, centres_x, angles, steps, ahead, behind, reach, core, side, colours
):
    """Cable pixels: near in colour to the cable colour of some seed within reach.

    Seed ``i`` at ``(centres_y[i], centres_x[i])`` (image px) judges the pixels within
    ``reach * steps[i]`` px of it. A pixel is cable when its colour lies within half the
    distance from ``colours[i, 0]`` (the cable) to the nearest of ``colours[i, 1:]`` (its
    sides and the background): at most half way to what lies round the cable, and not of
    some third colour. A pixel any seed takes is cable.

    A seed that ends a line also follows it ``ahead[i]`` px forward (direction
    ``(cos, sin)`` of ``angles[i]`` in ``(x, y)``) and ``behind[i]`` px back, one pixel
    at a time, for as long as the line stays a line: the pixel on it of the cable's colour
    and the pixels ``side * steps[i]`` px to either side (where its sides were seen) not.
    The pixels within ``core * steps[i]`` px of the line there are judged as above.

    Returns
    -------
    ndarray of uint8
        ``(H, W)``, 1 on cable pixels.
    """
    height, width, _ = lab8.shape
    out = np.zeros((height, width), np.uint8)
    for seed in range(centres_y.size):
        ball2 = _nearest_around2(colours, seed)
        cy = centres_y[seed]
        cx = centres_x[seed]
        r = reach * steps[seed]
        r2 = r * r
        y0 = max(int(np.ceil(cy - r)), 0)
        y1 = min(int(np.floor(cy + r)), height - 1)
        x0 = max(int(np.ceil(cx - r)), 0)
        x1 = min(int(np.floor(cx + r)), width - 1)
        for y in range(y0, y1 + 1):
            for x in range(x0, x1 + 1):
                if out[y, x] or (x - cx) * (x - cx) + (y - cy) * (y - cy) > r2:
                    continue
                if _near_cable(lab8, y, x, colours, seed, ball2):
                    out[y, x] = 1
        ux = np.cos(angles[seed])
        uy = np.sin(angles[seed])
        c = core * steps[seed]
        for sign, length in ((1.0, ahead[seed]), (-1.0, behind[seed])):
            t = 1.0
            while t <= length:
                px = cx + sign * t * ux
                py = cy + sign * t * uy
                if not _line_goes_on(
                    lab8, py, px, ux, -uy, side * steps[seed], colours, seed, ball2
                ):
                    break
                # The core's cross-section here.
                a = -c
                while a <= c:
                    qy = int(np.floor(py + a * ux + 0.5))
                    qx = int(np.floor(px - a * uy + 0.5))
                    if (
                        0 <= qy < height
                        and 0 <= qx < width
                        and not out[qy, qx]
                        and _near_cable(lab8, qy, qx, colours, seed, ball2)
                    ):
                        out[qy, qx] = 1
                    a += 0.5
                t += 1.0
    return out


@njit(cache=True, nogil=True, inline="always")
def _near_cable(lab8, y, x, colours, seed, ball2):
    """Is the colour of pixel ``(y, x)`` within half of ``ball2``'s root of the seed's cable?"""
    c0 = lab8[y, x, 0] * _L_SCALE
    c1 = np.float32(lab8[y, x, 1]) - _AB_OFFSET
    c2 = np.float32(lab8[y, x, 2]) - _AB_OFFSET
    return 4.0 * _distance2(c0, c1, c2, colours, seed, 0) < ball2


@njit(cache=True, nogil=True)
def _line_goes_on(lab8, py, px, ny, nx, side, colours, seed, ball2):
    """At ``(py, px)``: the pixel of the cable's colour, those ``side`` px across (along the
    normal ``(ny, nx)``) either way not (or beyond the picture)."""
    height, width, _ = lab8.shape
    y = int(np.floor(py + 0.5))
    x = int(np.floor(px + 0.5))
    if not (0 <= y < height and 0 <= x < width) or not _near_cable(
        lab8, y, x, colours, seed, ball2
    ):
        return False
    for sign in (1.0, -1.0):
        sy = int(np.floor(py + sign * side * ny + 0.5))
        sx = int(np.floor(px + sign * side * nx + 0.5))
        if 0 <= sy < height and 0 <= sx < width and _near_cable(lab8, sy, sx, colours, seed, ball2):
            return False
    return True


@njit(cache=True, nogil=True, inline="always")
def _nearest_around2(colours, seed):
    """Squared distance from a seed's cable colour to the nearest colour round it."""
    c0 = colours[seed, 0, 0]
    c1 = colours[seed, 0, 1]
    c2 = colours[seed, 0, 2]
    return min(
        _distance2(c0, c1, c2, colours, seed, 1),
        _distance2(c0, c1, c2, colours, seed, 2),
        _distance2(c0, c1, c2, colours, seed, 3),
    )


@njit(cache=True, nogil=True)
def component_widths(mask, distance):
    """Label the 8-connected components of a mask and measure each.

    Returns
    -------
    labels : ndarray of int64
        ``(H, W)``: 0 on background, ``1..n`` on the components (in scan order).
    area, width : ndarray of float64
        Per label (index 0 unused): the pixel count, and four times the mean of
        ``distance`` over the component (the width of a band: its distances spread
        evenly over 0..w/2).
    """
    height, width = mask.shape
    labels = np.zeros((height, width), np.int64)
    stack = np.empty(max(np.count_nonzero(mask), 1), np.int64)
    areas = [0.0]
    widths = [0.0]
    label = 0
    for r0 in range(height):
        for c0 in range(width):
            if not mask[r0, c0] or labels[r0, c0]:
                continue
            label += 1
            labels[r0, c0] = label
            stack[0] = r0 * width + c0
            top = 1
            count = 0
            total = 0.0
            while top:
                top -= 1
                r = stack[top] // width
                c = stack[top] - r * width
                count += 1
                total += distance[r, c]
                for k in range(8):
                    rr = r + RING_DR[k]
                    cc = c + RING_DC[k]
                    if 0 <= rr < height and 0 <= cc < width and mask[rr, cc] and not labels[rr, cc]:
                        labels[rr, cc] = label
                        stack[top] = rr * width + cc
                        top += 1
            areas.append(float(count))
            widths.append(4.0 * total / count)
    return labels, np.array(areas), np.array(widths)


@njit(cache=True, nogil=True)
def phase_mosaic(image, factor, margin):
    """The ``factor`` x ``factor`` phases of an image side by side, each with a margin.

    Phase ``(p, q)`` is ``image[p::factor, q::factor]``; it fills tile ``(p, q)`` of the
    mosaic, every tile ``ceil(H / factor) + 2 * margin`` by ``ceil(W / factor) + 2 *
    margin`` px, with the phase's own edge pixels repeated into the margin and into the
    row or column a shorter phase lacks: a median filter of the mosaic then gives, within
    each tile, what a filter of that phase alone (edges replicated) gives.

    Returns
    -------
    ndarray of uint8
        ``(factor * tile_h, factor * tile_w, C)``.
    """
    height, width, channels = image.shape
    rows = (height + factor - 1) // factor
    cols = (width + factor - 1) // factor
    tile_h = rows + 2 * margin
    tile_w = cols + 2 * margin
    out = np.empty((factor * tile_h, factor * tile_w, channels), np.uint8)
    for p in range(factor):
        last_row = (height - 1 - p) // factor
        for q in range(factor):
            last_col = (width - 1 - q) // factor
            for i in range(tile_h):
                y = p + factor * min(max(i - margin, 0), last_row)
                for j in range(tile_w):
                    x = q + factor * min(max(j - margin, 0), last_col)
                    for c in range(channels):
                        out[p * tile_h + i, q * tile_w + j, c] = image[y, x, c]
    return out


@njit(cache=True, nogil=True)
def from_phase_mosaic(mosaic, factor, margin, height, width):
    """The image back from a mosaic of :func:`phase_mosaic` (its margins left out)."""
    channels = mosaic.shape[2]
    tile_h = mosaic.shape[0] // factor
    tile_w = mosaic.shape[1] // factor
    out = np.empty((height, width, channels), np.uint8)
    for p in range(factor):
        for q in range(factor):
            for i in range((height - p + factor - 1) // factor):
                row = p * tile_h + margin + i
                for j in range((width - q + factor - 1) // factor):
                    col = q * tile_w + margin + j
                    for c in range(channels):
                        out[p + factor * i, q + factor * j, c] = mosaic[row, col, c]
    return out
