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


@njit(cache=True, nogil=True)
def _line_means(lab, cos_t, sin_t, half_length, mean, var, buf_y, buf_x, prefix):
    """Mean colour and colour variance over the line segment through each pixel.

    ``lab`` and ``mean`` are ``(3, H, W)`` planes. The segment is ``2 * half_length`` px
    long at angle ``t`` (cosine and sine given) and centred on the pixel, cut short at
    the image border. Running sums along each digital line of the family make it O(1)
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
        p0 = 0.0
        p1 = 0.0
        p2 = 0.0
        p3 = 0.0
        prefix[0, 0] = 0.0
        prefix[0, 1] = 0.0
        prefix[0, 2] = 0.0
        prefix[0, 3] = 0.0
        for i in range(n):
            s = first + i
            o = line + rise[s]
            if along_x:
                y, x = o, s
            else:
                y, x = s, o
            buf_y[i] = y
            buf_x[i] = x
            c0 = lab[0, y, x]
            c1 = lab[1, y, x]
            c2 = lab[2, y, x]
            p0 += c0
            p1 += c1
            p2 += c2
            p3 += c0 * c0 + c1 * c1 + c2 * c2
            prefix[i + 1, 0] = p0
            prefix[i + 1, 1] = p1
            prefix[i + 1, 2] = p2
            prefix[i + 1, 3] = p3
        for i in range(n):
            lo = max(i - a, 0)
            hi = min(i + a + 1, n)
            inv = 1.0 / (hi - lo)
            m0 = (prefix[hi, 0] - prefix[lo, 0]) * inv
            m1 = (prefix[hi, 1] - prefix[lo, 1]) * inv
            m2 = (prefix[hi, 2] - prefix[lo, 2]) * inv
            y = buf_y[i]
            x = buf_x[i]
            mean[0, y, x] = m0
            mean[1, y, x] = m1
            mean[2, y, x] = m2
            v = (prefix[hi, 3] - prefix[lo, 3]) * inv - (m0 * m0 + m1 * m1 + m2 * m2)
            var[y, x] = v if v > 0.0 else 0.0


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
    background between two cables (the background colour) give a low one. A pixel whose
    side segment would lie outside the picture gets no ratio at that angle.

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
    prefix = np.empty((longest + 1, 4), np.float64)
    best = np.zeros((height, width), np.float32)
    orientation = np.zeros((height, width), np.uint8)
    row = np.empty(width, np.float32)
    floor = np.float32(floor2)
    for k in range(n_orientations):
        angle = np.pi * k / n_orientations
        cos_t = np.cos(angle)
        sin_t = np.sin(angle)
        _line_means(lab, cos_t, sin_t, half_length, mean, var, buf_y, buf_x, prefix)
        dy = round(offset * cos_t)
        dx = round(-offset * sin_t)
        # Sides outside the picture are not known to differ: those pixels get no ratio.
        x_lo = abs(dx)
        x_hi = width - abs(dx)
        for y in range(abs(dy), height - abs(dy)):
            y1 = y + dy
            y2 = y - dy
            for x in range(x_lo, x_hi):
                m0 = mean[0, y, x]
                m1 = mean[1, y, x]
                m2 = mean[2, y, x]
                a0 = m0 - mean[0, y1, x + dx]
                a1 = m1 - mean[1, y1, x + dx]
                a2 = m2 - mean[2, y1, x + dx]
                b0 = m0 - mean[0, y2, x - dx]
                b1 = m1 - mean[1, y2, x - dx]
                b2 = m2 - mean[2, y2, x - dx]
                c0 = m0 - background[0, y, x]
                c1 = m1 - background[1, y, x]
                c2 = m2 - background[2, y, x]
                d0 = m0 - wide[0, y, x]
                d1 = m1 - wide[1, y, x]
                d2 = m2 - wide[2, y, x]
                contrast2 = min(
                    min(a0 * a0 + a1 * a1 + a2 * a2, b0 * b0 + b1 * b1 + b2 * b2),
                    min(c0 * c0 + c1 * c1 + c2 * c2, d0 * d0 + d1 * d1 + d2 * d2),
                )
                row[x] = contrast2 / (var[y, x] + floor)
            for x in range(x_lo, x_hi):
                if row[x] > best[y, x]:
                    best[y, x] = row[x]
                    orientation[y, x] = k
    for y in range(height):
        for x in range(width):
            best[y, x] = np.sqrt(best[y, x])
    return best, orientation


@njit(cache=True, nogil=True)
def merge_level(best, best_level, ratio, level):
    """Keep, per pixel of the finest grid, the level whose (nearest) ratio is largest."""
    grid_h, grid_w = best.shape
    level_h, level_w = ratio.shape
    scale_y = level_h / grid_h
    scale_x = level_w / grid_w
    for y in range(grid_h):
        ly = min(int((y + 0.5) * scale_y), level_h - 1)
        for x in range(grid_w):
            lx = min(int((x + 0.5) * scale_x), level_w - 1)
            value = ratio[ly, lx]
            if value > best[y, x]:
                best[y, x] = value
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
def nearest_colour_class(lab8, nearest, distance, grid_step, reach, colours):
    """Cable pixels: nearer in colour to the nearest seed's cable than to what is round it.

    ``nearest`` and ``distance`` are, on the seeds' grid, the index of the nearest seed
    and the distance to it (grid px, ``grid_step`` image px each); a pixel of the image
    is judged against that seed when it lies within ``reach[seed]`` image px of it.

    Returns
    -------
    ndarray of uint8
        ``(H, W)``, 1 on cable pixels.
    """
    height, width, _ = lab8.shape
    grid_h, grid_w = nearest.shape
    out = np.zeros((height, width), np.uint8)
    for y in range(height):
        gy = min(int((y + 0.5) * grid_h / height), grid_h - 1)
        for x in range(width):
            gx = min(int((x + 0.5) * grid_w / width), grid_w - 1)
            seed = nearest[gy, gx]
            if seed < 0 or distance[gy, gx] * grid_step > reach[seed]:
                continue
            c0 = lab8[y, x, 0] * _L_SCALE
            c1 = np.float32(lab8[y, x, 1]) - _AB_OFFSET
            c2 = np.float32(lab8[y, x, 2]) - _AB_OFFSET
            to_cable = _distance2(c0, c1, c2, colours, seed, 0)
            around = min(
                _distance2(c0, c1, c2, colours, seed, 1),
                _distance2(c0, c1, c2, colours, seed, 2),
                _distance2(c0, c1, c2, colours, seed, 3),
            )
            if to_cable < around:
                out[y, x] = 1
    return out


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
