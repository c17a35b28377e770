"""Plain NumPy versions of the cable-contrast kernels (step 1, ``segmentation=contrast``).

Slow and direct: every line segment is summed sample by sample, every pixel judged on
its own; the kernels must give the same numbers (to float32 rounding).
"""

import numpy as np


def lab_float(lab8):
    lab = lab8.astype(np.float64)
    lab[:, :, 0] *= 100.0 / 255.0
    lab[:, :, 1:] -= 128.0
    return lab


def _round_half_up(values):
    return np.floor(values + 0.5).astype(np.int64)


def line_samples(height, width, angle, half_length, rows, cols):
    """For pixels ``(rows, cols)``: the pixels of the digital line segment through each.

    Lines closer to horizontal step along x and visit ``y = line + round(x * slope)``;
    steeper ones step along y. The segment holds ``round(half_length * |cos|)`` (or
    ``|sin|``) steps on each side, cut at the image border.

    Returns a list, per step offset, of ``(sample_rows, sample_cols, inside)``.
    """
    cos_t, sin_t = np.cos(angle), np.sin(angle)
    along_x = abs(cos_t) >= abs(sin_t)
    # In (along, across) coordinates: x and y for lines nearer horizontal, else y and x.
    along, across = (cols, rows) if along_x else (rows, cols)
    n_along, n_across = (width, height) if along_x else (height, width)
    slope = sin_t / cos_t if along_x else cos_t / sin_t
    steps = round(half_length * (abs(cos_t) if along_x else abs(sin_t)))
    line = across - _round_half_up(along * slope)
    out = []
    for j in range(-steps, steps + 1):
        s = along + j
        o = line + _round_half_up(s * slope)
        inside = (s >= 0) & (s < n_along) & (o >= 0) & (o < n_across)
        out.append((o, s, inside) if along_x else (s, o, inside))
    return out


def line_mean_and_spread(lab, angle, half_length):
    """Mean colour and colour variance over each pixel's line segment."""
    height, width, _ = lab.shape
    rows, cols = np.mgrid[0:height, 0:width]
    total = np.zeros((height, width, 3))
    square = np.zeros((height, width))
    count = np.zeros((height, width))
    for sample_rows, sample_cols, inside in line_samples(
        height, width, angle, half_length, rows, cols
    ):
        values = lab[np.clip(sample_rows, 0, height - 1), np.clip(sample_cols, 0, width - 1)]
        total += np.where(inside[:, :, None], values, 0.0)
        square += np.where(inside, (values**2).sum(axis=2), 0.0)
        count += inside
    mean = total / count[:, :, None]
    spread = np.maximum(square / count - (mean**2).sum(axis=2), 0.0)
    return mean, spread


def orientation_ratios(lab8, background8, wide8, n_orientations, half_length, offset, floor2):
    """``(n_orientations, H, W)``: every pixel's line ratio at every angle."""
    lab = lab_float(lab8)
    background = lab_float(background8)
    wide = lab_float(wide8)
    height, width, _ = lab.shape
    rows, cols = np.mgrid[0:height, 0:width]
    ratios = np.zeros((n_orientations, height, width))
    for k in range(n_orientations):
        angle = np.pi * k / n_orientations
        mean, spread = line_mean_and_spread(lab, angle, half_length)
        dy = round(offset * np.cos(angle))
        dx = round(-offset * np.sin(angle))
        side_one = mean[np.clip(rows + dy, 0, height - 1), np.clip(cols + dx, 0, width - 1)]
        side_two = mean[np.clip(rows - dy, 0, height - 1), np.clip(cols - dx, 0, width - 1)]
        # A side outside the picture is not known to differ: no line at that angle.
        seen = (
            (rows + dy >= 0)
            & (rows + dy < height)
            & (cols + dx >= 0)
            & (cols + dx < width)
            & (rows - dy >= 0)
            & (rows - dy < height)
            & (cols - dx >= 0)
            & (cols - dx < width)
        )
        contrast2 = np.minimum.reduce(
            [
                ((mean - side_one) ** 2).sum(axis=2),
                ((mean - side_two) ** 2).sum(axis=2),
                ((mean - background) ** 2).sum(axis=2),
                ((mean - wide) ** 2).sum(axis=2),
            ]
        )
        ratios[k] = np.where(seen, np.sqrt(contrast2 / (spread + floor2)), 0.0)
    return ratios


def level_contrast(lab8, background8, wide8, n_orientations, half_length, offset, floor2):
    """The line ratio of every pixel and the index of the (first) angle that gives it."""
    ratios = orientation_ratios(
        lab8, background8, wide8, n_orientations, half_length, offset, floor2
    )
    return ratios.max(axis=0), ratios.argmax(axis=0)


def seed_colours(lab8, background8, rows, cols, orientation, n_orientations, half_length, offset):
    """Per seed: the mean colour along its line, along the lines beside it, and the
    background there."""
    lab = lab_float(lab8)
    background = lab_float(background8)
    height, width, _ = lab.shape
    out = np.zeros((len(rows), 4, 3))
    for i, (row, col) in enumerate(zip(rows, cols, strict=True)):
        angle = np.pi * orientation[row, col] / n_orientations
        dy = round(offset * np.cos(angle))
        dx = round(-offset * np.sin(angle))
        for which, (sy, sx) in enumerate(((0, 0), (dy, dx), (-dy, -dx))):
            cy = int(np.clip(row + sy, 0, height - 1))
            cx = int(np.clip(col + sx, 0, width - 1))
            samples = line_samples(
                height, width, angle, half_length, np.array([cy]), np.array([cx])
            )
            values = [lab[r[0], c[0]] for r, c, inside in samples if inside[0]]
            out[i, which] = np.mean(values, axis=0)
        out[i, 3] = background[row, col]
    return out


def merge_level(best, best_level, ratio, level):
    grid_h, grid_w = best.shape
    level_h, level_w = ratio.shape
    ly = np.minimum(((np.arange(grid_h) + 0.5) * level_h / grid_h).astype(int), level_h - 1)
    lx = np.minimum(((np.arange(grid_w) + 0.5) * level_w / grid_w).astype(int), level_w - 1)
    values = ratio[ly[:, None], lx[None, :]]
    better = values > best
    best[better] = values[better]
    best_level[better] = level


def nearest_colour_class(lab8, nearest, distance, grid_step, reach, colours):
    lab = lab_float(lab8)
    height, width, _ = lab.shape
    grid_h, grid_w = nearest.shape
    gy = np.minimum(((np.arange(height) + 0.5) * grid_h / height).astype(int), grid_h - 1)
    gx = np.minimum(((np.arange(width) + 0.5) * grid_w / width).astype(int), grid_w - 1)
    seed = nearest[gy[:, None], gx[None, :]]
    near = (seed >= 0) & (
        distance[gy[:, None], gx[None, :]] * grid_step <= reach[np.maximum(seed, 0)]
    )
    chosen = colours[np.maximum(seed, 0)]  # (H, W, 4, 3)
    to = ((lab[:, :, None, :] - chosen) ** 2).sum(axis=3)  # (H, W, 4)
    nearest_is_cable = (to[:, :, :1] < to[:, :, 1:]).all(axis=2)
    return (near & nearest_is_cable).astype(np.uint8)
