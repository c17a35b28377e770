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
        # A side beyond the picture is taken at the picture's edge.
        side_one = mean[np.clip(rows + dy, 0, height - 1), np.clip(cols + dx, 0, width - 1)]
        side_two = mean[np.clip(rows - dy, 0, height - 1), np.clip(cols - dx, 0, width - 1)]
        contrast2 = np.minimum.reduce(
            [
                ((mean - side_one) ** 2).sum(axis=2),
                ((mean - side_two) ** 2).sum(axis=2),
                ((mean - background) ** 2).sum(axis=2),
                ((mean - wide) ** 2).sum(axis=2),
            ]
        )
        ratios[k] = np.sqrt(contrast2 / (spread + floor2))
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


def colour_class_within_reach(
    lab8, centres_y, centres_x, angles, steps, ahead, behind, reach, core, side, colours
):
    """Pixels within ``reach * step`` of a seed whose colour lies within half the distance
    from the seed's cable colour to the nearest colour round it; and, ahead of a line's
    end, those within ``core * step`` of its line while the line goes on (its pixel of the
    cable's colour, those ``side * step`` to either side not)."""
    lab = lab_float(lab8)
    height, width, _ = lab.shape
    rows, cols = np.mgrid[0:height, 0:width]
    out = np.zeros((height, width), bool)

    def near(cable, ball2, y, x):
        return 4.0 * ((lab[y, x] - cable) ** 2).sum() < ball2

    for i in range(len(centres_y)):
        cable = colours[i, 0].astype(np.float64)
        ball2 = min(((cable - colours[i, k]) ** 2).sum() for k in (1, 2, 3))
        disc = (cols - centres_x[i]) ** 2 + (rows - centres_y[i]) ** 2 <= (reach * steps[i]) ** 2
        out |= disc & (4.0 * ((lab - cable) ** 2).sum(axis=2) < ball2)
        ux, uy = np.cos(angles[i]), np.sin(angles[i])
        for sign, length in ((1.0, ahead[i]), (-1.0, behind[i])):
            t = 1.0
            while t <= length:
                px, py = centres_x[i] + sign * t * ux, centres_y[i] + sign * t * uy
                y, x = int(np.floor(py + 0.5)), int(np.floor(px + 0.5))
                if not (0 <= y < height and 0 <= x < width) or not near(cable, ball2, y, x):
                    break
                blocked = False
                for s in (1.0, -1.0):
                    sy = int(np.floor(py + s * side * steps[i] * ux + 0.5))
                    sx = int(np.floor(px - s * side * steps[i] * uy + 0.5))
                    if 0 <= sy < height and 0 <= sx < width and near(cable, ball2, sy, sx):
                        blocked = True
                if blocked:
                    break
                for a in np.arange(-core * steps[i], core * steps[i] + 1e-9, 0.5):
                    qy, qx = int(np.floor(py + a * ux + 0.5)), int(np.floor(px - a * uy + 0.5))
                    if 0 <= qy < height and 0 <= qx < width and near(cable, ball2, qy, qx):
                        out[qy, qx] = True
                t += 1.0
    return out.astype(np.uint8)
