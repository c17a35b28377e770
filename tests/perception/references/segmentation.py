"""Plain Otsu threshold, hysteresis, mask clean-up and own-threshold profiles (step 1)."""

import cv2
import numpy as np


def histogram(feature):
    return np.bincount(feature.ravel(), minlength=256).astype(np.float64)


def otsu(hist):
    """Otsu's threshold over a 256-level histogram, in plain NumPy: the middle of the
    levels whose between-class variance is within 1e-12 of the best, and the best
    over the total variance."""
    total = hist.sum()
    levels = np.arange(256, dtype=np.float64)
    mean_all = (hist * levels).sum() / total
    var_all = (hist * (levels - mean_all) ** 2).sum() / total
    if var_all <= 1e-9:
        return 255.0, 0.0
    weight_low = np.cumsum(hist) / total
    mean_low_sum = np.cumsum(hist * levels) / total
    weight_high = 1.0 - weight_low
    valid = (weight_low > 0) & (weight_high > 0)
    between = np.zeros(256)
    between[valid] = (mean_all * weight_low[valid] - mean_low_sum[valid]) ** 2 / (
        weight_low[valid] * weight_high[valid]
    )
    peak = between.max()
    best_levels = np.flatnonzero(between >= peak * (1.0 - 1e-12))
    return float(best_levels[len(best_levels) // 2]), float(peak / var_all)


def hysteresis(cue, low, high):
    weak = (cue > low).astype(np.uint8)
    count, labels = cv2.connectedComponents(weak, connectivity=8)
    keep = np.zeros(count, bool)
    keep[np.unique(labels[cue > high])] = True
    keep[0] = False
    return keep[labels]


def full_blocks(mask, block):
    """The blocks of a 0/1 ``uint8`` image that OpenCV's area resize makes 1 (the plain
    code of segmentation._thin_bright_class)."""
    height, width = mask.shape
    blocks = cv2.resize(mask, (width // block, height // block), interpolation=cv2.INTER_AREA)
    return (blocks == 1).view(np.uint8)


def clean_mask(mask, min_component_area, max_hole_area):
    mask_u8 = mask.astype(np.uint8)
    if min_component_area > 0:
        _, labels, stats, _ = cv2.connectedComponentsWithStats(mask_u8, connectivity=8)
        keep = stats[:, cv2.CC_STAT_AREA] >= min_component_area
        keep[0] = False
        mask_u8 = keep[labels].astype(np.uint8)
    if max_hole_area > 0:
        background = (1 - mask_u8).astype(np.uint8)
        _, labels, stats, _ = cv2.connectedComponentsWithStats(background, connectivity=4)
        x, y, w, h, area = (stats[:, k] for k in range(5))
        height, width = mask.shape
        touches_border = (x == 0) | (y == 0) | (x + w == width) | (y + h == height)
        fill = (area <= max_hole_area) & ~touches_border
        fill[0] = False if background[0, 0] == 0 else fill[0]
        mask_u8 = np.where(fill[labels], 1, mask_u8).astype(np.uint8)
    return mask_u8 > 0


def _profile_feet(points, seen, avoid_xy, avoid_reach, per_pixel):
    """Feet ``per_pixel`` to a pixel along each seen segment (the first at its start),
    with their unit normals, and whether each is clear of every avoided disc."""
    feet, normals, clear = [], [], []
    for k in range(len(points) - 1):
        a, b = points[k], points[k + 1]
        length = float(np.hypot(*(b - a)))
        count = max(int(np.ceil(per_pixel * length)), 1)
        for step in range(count):
            ok = bool(seen[k]) and length > 1e-9
            if ok:
                foot = a + (b - a) * (step / count)
                ok = all(
                    np.hypot(*(foot - c)) >= r for c, r in zip(avoid_xy, avoid_reach, strict=True)
                )
            feet.append(foot if ok else np.zeros(2))
            normals.append(np.array([-(b - a)[1], (b - a)[0]]) / length if ok else np.zeros(2))
            clear.append(ok)
    return np.array(feet).reshape(-1, 2), np.array(normals).reshape(-1, 2), np.array(clear)


def _pixel(value):
    return int(np.floor(value + 0.5))


def profile_histogram(cue, points, seen, avoid_xy, avoid_reach, span, stride):
    feet, normals, clear = _profile_feet(points, seen, avoid_xy, avoid_reach, 1)
    hist = np.zeros(256)
    used = 0
    for index in range(0, len(feet), stride):
        if not clear[index]:
            continue
        used += 1
        for t in range(-span, span + 1):
            col = _pixel(feet[index, 0] + t * normals[index, 0])
            row = _pixel(feet[index, 1] + t * normals[index, 1])
            if 0 <= row < cue.shape[0] and 0 <= col < cue.shape[1]:
                hist[cue[row, col]] += 1
    return hist, used


def grow_along_profiles(cue, before, points, seen, avoid_xy, avoid_reach, start, reach, low):
    feet, normals, clear = _profile_feet(points, seen, avoid_xy, avoid_reach, 2)
    grown = before.copy()
    for foot, normal in zip(feet[clear], normals[clear], strict=True):
        for sign in (1, -1):
            col = _pixel(foot[0] + sign * start * normal[0])
            row = _pixel(foot[1] + sign * start * normal[1])
            inside = 0 <= row < cue.shape[0] and 0 <= col < cue.shape[1]
            first = start if inside and before[row, col] else 0
            for t in range(first, reach + 1):
                col = _pixel(foot[0] + sign * t * normal[0])
                row = _pixel(foot[1] + sign * t * normal[1])
                if not (0 <= row < cue.shape[0] and 0 <= col < cue.shape[1]):
                    break
                if not before[row, col] and not cue[row, col] > low:
                    break
                grown[row, col] = True
    return grown


def ridges(distance, mask):
    """The distances of the mask's pixels, away from the image's border, that no
    neighbour's exceeds (raster order), and the largest on the mask (0 when none): the
    plain code of objects.typical_half_width's ridge reading."""
    distance = np.asarray(distance)
    mask = np.asarray(mask, bool)
    largest = float(distance[mask].max()) if mask.any() else 0.0
    height, width = distance.shape
    if height < 3 or width < 3:
        return np.zeros(0, distance.dtype), largest
    middle = distance[1:-1, 1:-1]
    kept = mask[1:-1, 1:-1].copy()
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            if dr or dc:
                kept &= middle >= distance[1 + dr : height - 1 + dr, 1 + dc : width - 1 + dc]
    return middle[kept], largest
