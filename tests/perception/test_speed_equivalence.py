"""The compiled kernels give exactly what plain implementations give.

The ``_reference_*`` functions below are plain NumPy / OpenCV versions of thinning
(written straight from the rule in ``skeleton.thin``), spur removal, radius estimate,
junction zones, fitting, pruning and segmentation clean-up, most of them the code the
numba kernels replaced (issue 4). They live here, not in the package, as the
specification the kernels are held to: identical arrays and identical chains (same
joints, same order) on hand-made shapes, generated scenes and random masks with
holes, specks and pixels on the image border.
"""

from pathlib import Path

import cv2
import numpy as np
import pytest

from service.perception import _kernels
from service.perception.contours import extract_contours
from service.perception.fitting import (
    BRIDGE_RADII,
    fit_chains,
    junction_zones,
    split_contour,
    walk_joints,
)
from service.perception.geometry import angle_between
from service.perception.pruning import prune_overlaps
from service.perception.skeleton import (
    _BRANCH_COUNT,
    NEIGHBOUR_OFFSETS,
    branch_counts,
    distance_transform,
    estimate_radius,
    remove_spurs,
    skeletonize,
)
from service.synthetic import make_scene

MBEST = Path(__file__).resolve().parents[3] / "shared" / "datasets" / "mbest"

# --------------------------------------------------------------------------- references


_ZS_RING = ((-1, 0), (-1, 1), (0, 1), (1, 1), (1, 0), (1, -1), (0, -1), (-1, -1))


def _reference_ring(image, row, col):
    """The values of P2..P9 round (row, col); outside the image is 0."""
    height, width = image.shape
    return [
        int(0 <= row + dr < height and 0 <= col + dc < width and image[row + dr, col + dc])
        for dr, dc in _ZS_RING
    ]


def _reference_zhang_suen_removes(ring, first):
    north, east, south, west = ring[0], ring[2], ring[4], ring[6]
    steps = sum(1 for k in range(8) if not ring[k] and ring[(k + 1) % 8])
    if not (2 <= sum(ring) <= 6 and steps == 1):
        return False
    if first:
        return not (north and east and south) and not (east and south and west)
    return not (north and east and west) and not (north and south and west)


def _reference_staircase_removes(ring):
    north, east, south, west = ring[0], ring[2], ring[4], ring[6]
    if sum(ring) < 2 or (north and east and south and west):
        return False
    if not ((north and east) or (east and south) or (south and west) or (west and north)):
        return False
    # The set neighbours must be one 8-connected group: label the 3x3 patch.
    patch = np.zeros((3, 3), np.uint8)
    for value, (dr, dc) in zip(ring, _ZS_RING, strict=True):
        patch[1 + dr, 1 + dc] = value
    return cv2.connectedComponents(patch, connectivity=8)[0] - 1 == 1


def _reference_thin(mask):
    """Zhang-Suen sub-iterations on the whole image, then the raster staircase pass."""
    image = (np.asarray(mask) != 0).astype(np.uint8)
    rows, cols = np.nonzero(image)
    quiet, first = 0, True
    while quiet < 2:
        rows, cols = np.nonzero(image)
        doomed = [
            (r, c)
            for r, c in zip(rows, cols, strict=True)
            if _reference_zhang_suen_removes(_reference_ring(image, r, c), first)
        ]
        for r, c in doomed:
            image[r, c] = 0
        quiet = 0 if doomed else quiet + 1
        first = not first
    for r, c in zip(*np.nonzero(image), strict=True):
        if image[r, c] and _reference_staircase_removes(_reference_ring(image, r, c)):
            image[r, c] = 0
    return image > 0


def _reference_branch_counts(skeleton):
    kernel = np.zeros((3, 3), np.float32)
    for bit, (dr, dc) in enumerate(NEIGHBOUR_OFFSETS):
        kernel[1 + dr, 1 + dc] = 1 << bit
    pattern = cv2.filter2D(
        skeleton.astype(np.uint8), cv2.CV_32F, kernel, borderType=cv2.BORDER_CONSTANT
    ).astype(np.uint8)
    counts = _BRANCH_COUNT[pattern]
    counts[~skeleton] = 0
    return counts


def _reference_next_pixels(skeleton, row, col, visited):
    height, width = skeleton.shape
    found = []
    for dr, dc in ((0, 1), (1, 0), (0, -1), (-1, 0), (1, 1), (1, -1), (-1, -1), (-1, 1)):
        r, c = row + dr, col + dc
        if 0 <= r < height and 0 <= c < width and skeleton[r, c] and (r, c) not in visited:
            found.append((r, c))
    return found


def _reference_remove_spurs(skeleton, spur_length, passes=2):
    skeleton = skeleton.copy()
    for _ in range(passes):
        counts = _reference_branch_counts(skeleton)
        removed_any = False
        for row, col in np.argwhere(counts == 1):
            if not skeleton[row, col]:
                continue
            path = [(row, col)]
            visited = {(row, col)}
            length = 0.0
            reached_junction = False
            while length <= spur_length:
                row_c, col_c = path[-1]
                candidates = _reference_next_pixels(skeleton, row_c, col_c, visited)
                if not candidates:
                    break
                nxt = candidates[0]
                if counts[nxt] >= 3 or len(candidates) > 2:
                    reached_junction = True
                    break
                length += 1.0 if (nxt[0] == row_c or nxt[1] == col_c) else 1.4142
                path.append(nxt)
                visited.add(nxt)
                for extra in candidates[1:]:
                    if abs(extra[0] - nxt[0]) <= 1 and abs(extra[1] - nxt[1]) <= 1:
                        visited.add(extra)
            if reached_junction and length < spur_length:
                for r, c in path:
                    skeleton[r, c] = False
                removed_any = True
        if not removed_any:
            break
        skeleton = _reference_thin(skeleton)
    return skeleton


def _reference_estimate_radius(mask, skeleton):
    if not skeleton.any():
        return 0.0
    distance = cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, 5)
    return max(float(np.median(distance[skeleton])) - 0.5, 0.5)


def _reference_junction_zones(skeleton, radius):
    junctions = (_reference_branch_counts(skeleton) >= 3).astype(np.uint8)
    if not junctions.any():
        return np.zeros_like(skeleton, dtype=bool)
    zone_radius = max(2, round(1.5 * radius))
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * zone_radius + 1,) * 2)
    zones = cv2.dilate(junctions, disc) > 0
    outside = (skeleton & ~zones).astype(np.uint8)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(outside, connectivity=8)
    if count > 1:
        tips = _reference_branch_counts(skeleton) == 1
        has_tip = np.zeros(count, bool)
        has_tip[np.unique(labels[tips & (labels > 0)])] = True
        short = (stats[:, cv2.CC_STAT_AREA] < BRIDGE_RADII * radius) & ~has_tip
        short[0] = False
        zones |= short[labels]
    return zones


def _reference_fit_chains(contours, skeleton, zones, segment_length):
    tips = _reference_branch_counts(skeleton) == 1
    chains = []
    for contour in contours:
        xs, ys = contour[:, 0], contour[:, 1]
        for run in split_contour(contour, tips[ys, xs], zones[ys, xs]):
            chains.append(walk_joints(run, segment_length))
    return chains


def _reference_chain_length(joints):
    return float(np.linalg.norm(np.diff(joints, axis=0), axis=1).sum()) if len(joints) > 1 else 0.0


def _reference_prune_overlaps(chains, shape, tolerance=2.0):
    fractions = np.array([0.25, 0.5, 0.75])
    coverage = np.zeros(shape, np.uint8)
    thickness = max(1, round(2 * tolerance + 1))
    kept = []
    for joints in sorted(chains, key=_reference_chain_length, reverse=True):
        if len(joints) < 2:
            continue
        starts, ends = joints[:-1], joints[1:]
        samples = starts[:, None, :] + fractions[None, :, None] * (ends - starts)[:, None, :]
        cols = np.clip(np.rint(samples[..., 0]).astype(int), 0, shape[1] - 1)
        rows = np.clip(np.rint(samples[..., 1]).astype(int), 0, shape[0] - 1)
        covered = coverage[rows, cols].sum(axis=1) >= 2
        runs, start = [], None
        for k, is_covered in enumerate(covered):
            if not is_covered and start is None:
                start = k
            if is_covered and start is not None:
                runs.append(joints[start : k + 1])
                start = None
        if start is not None:
            runs.append(joints[start:])
        for run in runs:
            if _reference_chain_length(run) < 1.0:
                continue
            kept.append(run)
            cv2.polylines(coverage, [np.rint(run).astype(np.int32)], False, 1, thickness)
    return kept


# --------------------------------------------------------------------------- inputs


def _thick(shape, polylines, thickness):
    mask = np.zeros(shape, np.uint8)
    for points in polylines:
        cv2.polylines(mask, [np.array(points, np.int32)], False, 1, thickness)
    return mask > 0


def _random_mask(seed, shape=(150, 200)):
    """Random thick strokes and rings, with pinholes and specks, some off the edges."""
    rng = np.random.default_rng(seed)
    height, width = shape
    mask = np.zeros(shape, np.uint8)
    for _ in range(5):
        points = rng.integers(-15, [width + 15, height + 15], size=(rng.integers(2, 5), 2))
        cv2.polylines(
            mask, [points.astype(np.int32)], bool(rng.integers(0, 2)), 1, int(rng.integers(2, 18))
        )
    centre = tuple(int(v) for v in rng.integers(0, [width, height]))
    cv2.circle(mask, centre, int(rng.integers(8, 40)), 1, int(rng.integers(2, 9)))
    near = cv2.dilate(mask, np.ones((3, 3), np.uint8)) > 0
    return (mask > 0) ^ (near & (rng.random(shape) < 0.02))


def _inputs():
    shape = (120, 160)
    cases = {
        "band": _thick(shape, [[(10, 60), (150, 60)]], 11),
        "cross": _thick(shape, [[(10, 20), (150, 100)], [(10, 100), (150, 20)]], 9),
        "ragged": _thick(shape, [[(5, 30), (155, 35)], [(80, 30), (80, 118)]], 7)
        | _thick(shape, [[(40, 30), (43, 24)], [(120, 35), (122, 42)]], 3),
        "loop": _thick(shape, [[(20, 100), (80, 10), (140, 100), (20, 40)]], 8),
        "edges": _thick(shape, [[(-5, 0), (165, 119)], [(0, 119), (159, 0)]], 6),
        "block": np.pad(np.ones((40, 60), bool), 20),
        "speck": np.pad(np.ones((1, 1), bool), 3),
        "empty": np.zeros((20, 30), bool),
    }
    for seed in range(6):
        cases[f"random{seed}"] = _random_mask(seed)
    for seed, (width, height, n) in enumerate([(200, 150, 2), (256, 192, 3), (320, 240, 3)]):
        cases[f"scene{seed}"] = make_scene(width, height, n, seed=seed, radius_range=(3, 6)).mask
    return cases


INPUTS = _inputs()


def _reference_steps(mask, segment_length=10.0):
    skeleton = _reference_thin(mask)
    radius = max(_reference_estimate_radius(mask, skeleton), 1.0)
    pruned_skeleton = _reference_remove_spurs(skeleton, 2.5 * radius)
    contours = extract_contours(pruned_skeleton)
    zones = _reference_junction_zones(pruned_skeleton, radius)
    pieces = _reference_fit_chains(contours, pruned_skeleton, zones, segment_length)
    kept = _reference_prune_overlaps(pieces, mask.shape)
    return skeleton, radius, pruned_skeleton, zones, pieces, kept


def _assert_same_chains(fast, reference):
    assert len(fast) == len(reference)
    for a, b in zip(fast, reference, strict=True):
        assert a.dtype == b.dtype and a.shape == b.shape
        np.testing.assert_array_equal(a, b)


def _assert_steps_match(mask, segment_length=10.0):
    skeleton, radius, pruned_skeleton, zones, pieces, kept = _reference_steps(mask, segment_length)

    fast_skeleton = skeletonize(mask)
    assert fast_skeleton.dtype == bool
    np.testing.assert_array_equal(fast_skeleton, skeleton)
    fast_radius = max(estimate_radius(mask, fast_skeleton), 1.0)
    assert fast_radius == radius
    assert estimate_radius(mask, fast_skeleton, distance_transform(mask)) == estimate_radius(
        mask, fast_skeleton
    )
    fast_pruned = remove_spurs(fast_skeleton, 2.5 * fast_radius)
    np.testing.assert_array_equal(fast_pruned, pruned_skeleton)
    np.testing.assert_array_equal(
        branch_counts(fast_pruned), _reference_branch_counts(pruned_skeleton)
    )
    fast_zones = junction_zones(fast_pruned, fast_radius)
    assert fast_zones.dtype == bool
    np.testing.assert_array_equal(fast_zones, zones)
    fast_pieces = fit_chains(extract_contours(fast_pruned), fast_pruned, fast_zones, segment_length)
    _assert_same_chains(fast_pieces, pieces)
    _assert_same_chains(prune_overlaps(fast_pieces, mask.shape), kept)


def _reference_arc(start: np.ndarray, heading: np.ndarray, turn: float, radius: float, step: float):
    """Points of a circular arc leaving ``start`` along ``heading`` and turning ``turn`` rad."""
    sign = 1.0 if turn >= 0 else -1.0
    normal = sign * np.array([-heading[1], heading[0]])
    centre = start + radius * normal
    offset = start - centre
    count = max(2, int(np.ceil(abs(turn) * radius / step)) + 1)
    angles = np.linspace(0.0, turn, count)
    cos, sin = np.cos(angles), np.sin(angles)
    rotated_x = cos * offset[0] - sin * offset[1]
    rotated_y = sin * offset[0] + cos * offset[1]
    return centre + np.stack([rotated_x, rotated_y], axis=1)


def _reference_without_repeats(points: np.ndarray) -> np.ndarray:
    """Drop points that repeat their predecessor (a straight part of zero length)."""
    steps = np.hypot(*np.diff(points, axis=0).T)
    keep = np.concatenate([[True], steps > 1e-9])
    return points[keep]


def _reference_segment(a: np.ndarray, b: np.ndarray, step: float) -> np.ndarray:
    count = max(2, int(np.ceil(np.hypot(*(b - a)) / step)) + 1)
    return a + np.linspace(0.0, 1.0, count)[:, None] * (b - a)


def _reference_natural_curve(start, leaving, end, arriving, step=1.0):
    gap = end - start
    distance = float(np.hypot(*gap))
    if distance < 1e-9:
        return np.array([start, end])
    cross = leaving[0] * arriving[1] - leaving[1] * arriving[0]
    dot = leaving[0] * arriving[0] + leaving[1] * arriving[1]
    turn = float(np.arctan2(cross, dot))
    heading = gap / distance
    if abs(cross) < 1e-6:
        if dot > 0 and angle_between(leaving, heading) < 1e-3:
            return _reference_segment(start, end, step)
    else:
        # start + t_a * leaving = end - t_b * arriving
        matrix = np.array([[leaving[0], arriving[0]], [leaving[1], arriving[1]]])
        t_a, t_b = np.linalg.solve(matrix, gap)
        if t_a > 0 and t_b > 0:
            corner = start + t_a * leaving
            tangent = min(t_a, t_b)
            arc_start = corner - tangent * leaving
            arc_radius = tangent / np.tan(abs(turn) / 2.0)
            arc = _reference_arc(arc_start, leaving, turn, arc_radius, step)
            parts = [
                _reference_segment(start, arc_start, step),
                arc[1:],
                _reference_segment(arc[-1], end, step)[1:],
            ]
            curve = np.concatenate(parts)
            curve[-1] = end
            return _reference_without_repeats(curve)
    handle = 0.4 * distance
    control = np.array([start, start + handle * leaving, end - handle * arriving, end])
    count = max(4, int(np.ceil(1.3 * distance / step)) + 1)
    t = np.linspace(0.0, 1.0, count)[:, None]
    weights = [(1 - t) ** 3, 3 * (1 - t) ** 2 * t, 3 * (1 - t) * t**2, t**3]
    return sum(w * c for w, c in zip(weights, control, strict=True))


def _reference_farthest_ahead(tip, direction, mask, limit, cos_half_angle, rim):
    """The middle of the mask's farthest rim from ``tip``: the pixels at most ``limit``
    px away, within the cone of ``cos_half_angle`` round ``direction`` and connected to
    the tip through the mask near it, that lie within FAR_RIM_PX of the largest
    distance. None when there is none."""
    height, width = mask.shape
    r = int(np.ceil(limit))
    col, row = round(float(tip[0])), round(float(tip[1]))
    x0, y0 = max(col - r, 0), max(row - r, 0)
    x1, y1 = min(col + r + 1, width), min(row + r + 1, height)
    window = mask[y0:y1, x0:x1].astype(np.uint8)
    ty, tx = row - y0, col - x0
    if not (0 <= ty < window.shape[0] and 0 <= tx < window.shape[1]) or not window[ty, tx]:
        return None
    _, labels = cv2.connectedComponents(window, connectivity=8)
    ys, xs = np.nonzero(labels == labels[ty, tx])
    vx = xs + x0 - tip[0]
    vy = ys + y0 - tip[1]
    dist = np.hypot(vx, vy)
    ahead = vx * direction[0] + vy * direction[1] >= cos_half_angle * dist
    ok = (dist <= limit) & (dist > 0) & ahead
    if not ok.any():
        return None
    # The middle of the farthest rim, not one pixel of it: the corners of a square-cut
    # end are equally far and would pull the end sideways.
    far = ok & (dist >= dist[ok].max() - rim)
    return np.array([tip[0] + vx[far].mean(), tip[1] + vy[far].mean()])


def _reference_smooth_curve(start, leaving, end, arriving, step=1.0):
    distance = float(np.hypot(*(end - start)))
    if distance < 1e-9:
        return np.array([start, end])
    cross = leaving[0] * arriving[1] - leaving[1] * arriving[0]
    dot = leaving[0] * arriving[0] + leaving[1] * arriving[1]
    theta = min(abs(float(np.arctan2(cross, dot))), 0.95 * np.pi)
    if theta < 1e-6:
        handle = distance / 3.0
    else:
        handle = (2.0 / 3.0) * distance * np.tan(theta / 4.0) / np.sin(theta / 2.0)
    control = np.array([start, start + handle * leaving, end - handle * arriving, end])
    count = max(4, int(np.ceil(1.3 * distance / step)) + 1)
    t = np.linspace(0.0, 1.0, count)[:, None]
    weights = [(1 - t) ** 3, 3 * (1 - t) ** 2 * t, 3 * (1 - t) * t**2, t**3]
    return sum(w * c for w, c in zip(weights, control, strict=True))


def _reference_profile_feet(points, seen, avoid_xy, avoid_reach, per_pixel):
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


def _reference_pixel(value):
    return int(np.floor(value + 0.5))


def _reference_profile_histogram(cue, points, seen, avoid_xy, avoid_reach, span, stride):
    feet, normals, clear = _reference_profile_feet(points, seen, avoid_xy, avoid_reach, 1)
    hist = np.zeros(256)
    used = 0
    for index in range(0, len(feet), stride):
        if not clear[index]:
            continue
        used += 1
        for t in range(-span, span + 1):
            col = _reference_pixel(feet[index, 0] + t * normals[index, 0])
            row = _reference_pixel(feet[index, 1] + t * normals[index, 1])
            if 0 <= row < cue.shape[0] and 0 <= col < cue.shape[1]:
                hist[cue[row, col]] += 1
    return hist, used


def _reference_grow(cue, before, points, seen, avoid_xy, avoid_reach, start, reach, low):
    feet, normals, clear = _reference_profile_feet(points, seen, avoid_xy, avoid_reach, 2)
    grown = before.copy()
    for foot, normal in zip(feet[clear], normals[clear], strict=True):
        for sign in (1, -1):
            col = _reference_pixel(foot[0] + sign * start * normal[0])
            row = _reference_pixel(foot[1] + sign * start * normal[1])
            inside = 0 <= row < cue.shape[0] and 0 <= col < cue.shape[1]
            first = start if inside and before[row, col] else 0
            for t in range(first, reach + 1):
                col = _reference_pixel(foot[0] + sign * t * normal[0])
                row = _reference_pixel(foot[1] + sign * t * normal[1])
                if not (0 <= row < cue.shape[0] and 0 <= col < cue.shape[1]):
                    break
                if not before[row, col] and not cue[row, col] > low:
                    break
                grown[row, col] = True
    return grown


def _reference_otsu(hist):
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


# --------------------------------------------------------------------------- tests


@pytest.mark.parametrize("name", sorted(INPUTS))
def test_fast_steps_equal_the_reference_steps(name):
    _assert_steps_match(INPUTS[name])


def test_fitting_with_short_segments_equals_the_reference():
    _assert_steps_match(INPUTS["random3"], segment_length=3.0)


@pytest.mark.parametrize("seed", range(4))
def test_thinning_equals_the_reference_on_random_noise(seed):
    # Dense noise makes every removal pattern of the thinning tables occur.
    rng = np.random.default_rng(seed)
    mask = rng.random((64, 80)) < (0.5 + 0.1 * seed)
    np.testing.assert_array_equal(skeletonize(mask), _reference_thin(mask))
    full = np.ones((7 + seed, 9), bool)
    np.testing.assert_array_equal(skeletonize(full), _reference_thin(full))


@pytest.mark.parametrize("seed", range(4))
def test_thinning_keeps_topology_and_leaves_lines_one_pixel_wide(seed):
    # Rings, thick strokes and solid blobs, overlapping at random.
    rng = np.random.default_rng(seed)
    shapes = np.zeros((120, 160), np.uint8)
    for _ in range(12):
        centre = (int(rng.integers(10, 150)), int(rng.integers(10, 110)))
        radius = int(rng.integers(5, 14))
        cv2.circle(shapes, centre, radius, 1, int(rng.choice([-1, 3, 5])))
        end = (int(rng.integers(0, 160)), int(rng.integers(0, 120)))
        cv2.line(shapes, centre, end, 1, int(rng.integers(3, 9)))
    skeleton = skeletonize(shapes).astype(np.uint8)

    def components(image):
        # Background round the image, as the thinning assumes: a hole is a 4-connected
        # background component that does not reach it.
        padded = np.pad(image, 1)
        return (
            cv2.connectedComponents(padded, connectivity=8)[0],
            cv2.connectedComponents(1 - padded, connectivity=4)[0],
        )

    assert components(skeleton) == components(shapes)
    blocks = skeleton[:-1, :-1] & skeleton[1:, :-1] & skeleton[:-1, 1:] & skeleton[1:, 1:]
    assert not blocks.any()
    # Lines, not clumps: most pixels have exactly two branches.
    counts = branch_counts(skeleton > 0)
    assert np.count_nonzero(counts == 2) > 0.8 * np.count_nonzero(skeleton)


def test_thinning_a_bar_leaves_its_centre_line():
    bar = np.zeros((21, 60), bool)
    bar[6:15, 5:55] = True
    rows, cols = np.nonzero(skeletonize(bar))
    assert set(rows[(cols > 12) & (cols < 48)]) == {10}


@pytest.mark.parametrize("seed", range(3))
def test_distance_transform_equals_opencv(seed):
    rng = np.random.default_rng(seed)
    mask = cv2.dilate((rng.random((90, 70)) < 0.05).astype(np.uint8), np.ones((9, 9), np.uint8))
    mask[rng.random(mask.shape) < 0.03] = 0
    for image in (mask, np.ones((6, 9), np.uint8), np.zeros((5, 5), np.uint8)):
        np.testing.assert_array_equal(
            distance_transform(image > 0), cv2.distanceTransform(image, cv2.DIST_L2, 5)
        )


def test_chain_lengths_add_up_like_numpy():
    rng = np.random.default_rng(0)
    arrays = [rng.random((n, 2)) * 300 for n in (0, 1, 2, 7, 8, 9, 130, 300, 1100)]
    ends = np.cumsum([len(a) for a in arrays])
    lengths = _kernels.chain_lengths(np.concatenate(arrays), ends)
    assert list(lengths) == [_reference_chain_length(a) for a in arrays]


def test_warm_up_runs_and_is_cheap_the_second_time():
    _kernels.warm_up()
    _kernels.warm_up()


@pytest.mark.slow
@pytest.mark.shared_data
def test_fast_steps_equal_the_reference_steps_on_mbest_labels():
    if not MBEST.is_dir():
        pytest.skip(f"{MBEST} not present")
    labels = sorted(MBEST.glob("S*/labels/*.png"))[::25]
    assert labels
    for path in labels:
        mask = cv2.imread(str(path), cv2.IMREAD_UNCHANGED) > 0
        _assert_steps_match(mask)


# --------------------------------------------------------------------------- steps 1 and 6
# Plain versions of the segmentation clean-up and of the merging stage's loops that
# faster code replaced; the replacements must give the same results.


def _reference_otsu_hist(feature):
    return np.bincount(feature.ravel(), minlength=256).astype(np.float64)


def _reference_hysteresis(cue, low, high):
    weak = (cue > low).astype(np.uint8)
    count, labels = cv2.connectedComponents(weak, connectivity=8)
    keep = np.zeros(count, bool)
    keep[np.unique(labels[cue > high])] = True
    keep[0] = False
    return keep[labels]


def _reference_clean_mask(mask, min_component_area, max_hole_area):
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


def _reference_resample(points, step):
    joints, edges = [points[0]], [0]
    current, edge, n, step_sq = points[0], 0, len(points), step * step
    while edge < n - 1:
        a, b = points[edge], points[edge + 1]
        if (b[0] - current[0]) ** 2 + (b[1] - current[1]) ** 2 < step_sq:
            edge += 1
            continue
        d, f = b - a, a - current
        qa = d[0] * d[0] + d[1] * d[1]
        qb = 2.0 * (f[0] * d[0] + f[1] * d[1])
        qc = f[0] * f[0] + f[1] * f[1] - step_sq
        disc = max(qb * qb - 4.0 * qa * qc, 0.0)
        t = (-qb + np.sqrt(disc)) / (2.0 * qa) if qa > 0 else 1.0
        current = a + min(max(t, 0.0), 1.0) * d
        joints.append(current)
        edges.append(edge)
    return np.array(joints), np.array(edges)


def _reference_intersections(chains):
    starts = np.concatenate([c[:-1] for c in chains])
    ends = np.concatenate([c[1:] for c in chains])
    chain_ids = np.concatenate([np.full(len(c) - 1, i) for i, c in enumerate(chains)])
    indices = np.concatenate([np.arange(len(c) - 1) for c in chains])
    lo, hi = np.minimum(starts, ends), np.maximum(starts, ends)
    found = []
    order = np.argsort(lo[:, 0])
    lo_sorted_x = lo[order, 0]
    for position, a in enumerate(order):
        others = order[position + 1 : np.searchsorted(lo_sorted_x, hi[a, 0], side="right")]
        others = others[(lo[others, 1] <= hi[a, 1]) & (hi[others, 1] >= lo[a, 1])]
        near = np.abs(indices[others] - indices[a]) <= 2
        others = others[~((chain_ids[others] == chain_ids[a]) & near)]
        if len(others) == 0:
            continue
        p, r = starts[a], ends[a] - starts[a]
        q, s = starts[others], ends[others] - starts[others]
        denom = r[0] * s[:, 1] - r[1] * s[:, 0]
        qp = q - p
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (qp[:, 0] * s[:, 1] - qp[:, 1] * s[:, 0]) / denom
            u = (qp[:, 0] * r[1] - qp[:, 1] * r[0]) / denom
        hit = (np.abs(denom) > 1e-12) & (t >= 0) & (t < 1) & (u >= 0) & (u < 1)
        for b, t_hit in zip(others[hit], t[hit], strict=True):
            key_a, key_b = (chain_ids[a], indices[a]), (chain_ids[b], indices[b])
            first, second = (a, b) if key_a <= key_b else (b, a)
            found.append(
                (
                    int(chain_ids[first]),
                    int(indices[first]),
                    int(chain_ids[second]),
                    int(indices[second]),
                    p + t_hit * r,
                )
            )
    return found


def _speckled_mask(seed, shape=(90, 120)):
    rng = np.random.default_rng(seed)
    mask = cv2.dilate((rng.random(shape) < 0.02).astype(np.uint8), np.ones((7, 7), np.uint8))
    mask[rng.random(shape) < 0.08] ^= 1  # specks and holes, some on the border
    mask[0, rng.integers(0, shape[1], 5)] = 1
    return mask > 0


@pytest.mark.parametrize("seed", range(6))
def test_clean_mask_equals_the_reference(seed):
    from service.perception.segmentation import clean_mask

    mask = _speckled_mask(seed)
    for min_area, max_hole in ((0, 0), (5, 0), (0, 6), (5, 6), (30, 40), (1000, 3)):
        np.testing.assert_array_equal(
            clean_mask(mask, min_area, max_hole), _reference_clean_mask(mask, min_area, max_hole)
        )
    for edge_case in (np.zeros((9, 11), bool), np.ones((9, 11), bool)):
        np.testing.assert_array_equal(
            clean_mask(edge_case, 5, 6), _reference_clean_mask(edge_case, 5, 6)
        )
    # Many specks: the whole-box lookup path.
    specks = np.random.default_rng(seed).random((60, 60)) < 0.05
    np.testing.assert_array_equal(clean_mask(specks, 3, 2), _reference_clean_mask(specks, 3, 2))


@pytest.mark.parametrize("seed", range(4))
def test_hysteresis_and_histogram_equal_the_reference(seed):
    from service.perception.segmentation import _histogram, hysteresis_threshold

    rng = np.random.default_rng(seed)
    cue = cv2.GaussianBlur((rng.random((70, 90)) * 255).astype(np.uint8), (5, 5), 0)
    for low, high in ((120.0, 135.0), (127.5, 127.5), (250.0, 254.0), (0.0, 10.0)):
        np.testing.assert_array_equal(
            hysteresis_threshold(cue, low, high), _reference_hysteresis(cue, low, high)
        )
    np.testing.assert_array_equal(_histogram(cue), _reference_otsu_hist(cue))


@pytest.mark.parametrize("seed", range(3))
def test_brightness_and_cleaning_equal_the_reference_on_scenes(seed):
    from service.perception.segmentation import clean_mask

    image = make_scene(seed=seed, width=320, height=240, n_cables=3).image
    brightness, counts = _kernels.brightness_histogram(image)
    channels = cv2.split(image)
    np.testing.assert_array_equal(
        brightness, cv2.max(cv2.max(channels[0], channels[1]), channels[2])
    )
    np.testing.assert_array_equal(counts, _reference_otsu_hist(brightness))
    # Noisy thresholds of a real scene: many specks and holes, of every size.
    rng = np.random.default_rng(seed)
    mask = (brightness > np.median(brightness)) ^ (rng.random(brightness.shape) < 0.02)
    for min_area, max_hole in ((120, 60), (1, 1), (400, 0), (0, 400)):
        np.testing.assert_array_equal(
            clean_mask(mask, min_area, max_hole), _reference_clean_mask(mask, min_area, max_hole)
        )


@pytest.mark.parametrize("seed", range(4))
def test_threshold_and_clean_equals_hysteresis_then_clean_mask(seed):
    rng = np.random.default_rng(seed)
    cue = cv2.GaussianBlur((rng.random((80, 110)) * 255).astype(np.uint8), (5, 5), 0)
    counts = np.bincount(cue.ravel(), minlength=256)
    for low, high in ((120.0, 135.0), (127.5, 127.5), (130.0, 125.0), (0.0, 10.0)):
        weak_count = int(counts[max(int(np.floor(low)) + 1, 0) :].sum())
        for min_area, max_hole in ((0, 0), (1, 1), (30, 12), (120, 60), (5000, 5)):
            fused = _kernels.threshold_and_clean(cue, low, high, weak_count, min_area, max_hole)
            expected = _reference_clean_mask(
                _reference_hysteresis(cue, low, high), min_area, max_hole
            )
            np.testing.assert_array_equal(fused.view(bool), expected)


@pytest.mark.parametrize("seed", range(3))
def test_natural_curve_kernel_equals_the_reference(seed):
    from service.perception.merging import natural_curve

    rng = np.random.default_rng(seed)
    cases = 0
    for _ in range(400):
        start, end = rng.uniform(0, 300, 2), rng.uniform(0, 300, 2)
        leaving, arriving = (v / np.linalg.norm(v) for v in rng.normal(size=(2, 2)))
        if rng.random() < 0.1:  # aligned ends: the straight case
            leaving = arriving = (end - start) / np.linalg.norm(end - start)
        step = float(rng.choice([0.5, 1.0, 3.0]))
        fast = natural_curve(start, leaving, end, arriving, step)
        expected = _reference_natural_curve(start, leaving, end, arriving, step)
        assert fast.shape == expected.shape
        np.testing.assert_allclose(fast, expected, rtol=0, atol=1e-9)
        fast = natural_curve(start, leaving, end, arriving, step, shape="smooth")
        expected = _reference_smooth_curve(start, leaving, end, arriving, step)
        assert fast.shape == expected.shape
        np.testing.assert_allclose(fast, expected, rtol=0, atol=1e-9)
        cases += 1
    assert cases == 400


@pytest.mark.parametrize("seed", range(3))
def test_median_distance_per_piece_equals_numpy(seed):
    rng = np.random.default_rng(seed)
    distance = (rng.random((60, 80)) * 9).astype(np.float32)
    pieces = [rng.uniform(-5, 85, (int(rng.integers(1, 30)), 2)) for _ in range(8)]
    starts = np.cumsum([0] + [len(points) for points in pieces]).astype(np.int64)
    medians = _kernels.median_distance_per_piece(distance, np.concatenate(pieces), starts)
    for points, median in zip(pieces, medians, strict=True):
        cols = np.clip(np.rint(points[:, 0]).astype(int), 0, 79)
        rows = np.clip(np.rint(points[:, 1]).astype(int), 0, 59)
        assert float(np.median(distance[rows, cols])) == float(median)


@pytest.mark.parametrize("seed", range(3))
def test_farthest_rim_ahead_equals_the_reference(seed):
    from service.perception.pipeline import FAR_RIM_PX, TIP_SEARCH_COS, _farthest_ahead

    rng = np.random.default_rng(seed)
    found = 0
    for _ in range(100):
        mask = np.zeros((90, 120), np.uint8)
        for _ in range(3):
            start = tuple(int(v) for v in rng.integers(0, 120, 2))
            end = tuple(int(v) for v in rng.integers(0, 90, 2))
            cv2.line(mask, start, end, 1, int(rng.integers(5, 15)))
        rows, cols = np.nonzero(mask)
        pick = rng.integers(rows.size)
        tip = np.array([cols[pick], rows[pick]]) + rng.uniform(-0.4, 0.4, 2)
        direction = rng.normal(size=2)
        direction /= np.linalg.norm(direction)
        limit = float(rng.uniform(5, 40))
        fast = _farthest_ahead(tip, direction, mask > 0, limit)
        expected = _reference_farthest_ahead(
            tip, direction, mask > 0, limit, TIP_SEARCH_COS, FAR_RIM_PX
        )
        assert (fast is None) == (expected is None)
        if fast is not None:
            np.testing.assert_allclose(fast, expected, rtol=0, atol=1e-9)
            found += 1
    assert found > 50


@pytest.mark.parametrize("seed", range(4))
def test_resample_kernel_equals_the_reference(seed):
    from service.perception.geometry import resample

    rng = np.random.default_rng(seed)
    for _ in range(50):
        points = np.cumsum(rng.normal(0, 3, (rng.integers(2, 50), 2)), axis=0) + 400.0
        step = float(rng.uniform(1.0, 12.0))
        joints, edges = _kernels.resample_kernel(points, step)
        expected_joints, expected_edges = _reference_resample(points, step)
        np.testing.assert_array_equal(joints, expected_joints)
        np.testing.assert_array_equal(edges, expected_edges)
        full_joints, _ = resample(points, step)
        np.testing.assert_array_equal(full_joints[: len(joints)], joints)


@pytest.mark.parametrize("seed", range(4))
def test_intersection_kernel_equals_the_reference(seed):
    from service.perception.crossings import find_intersections

    rng = np.random.default_rng(seed)
    chains = [
        np.cumsum(rng.normal(0, 6, (int(rng.integers(2, 40)), 2)), axis=0) + 100.0 for _ in range(4)
    ]
    chains.append(np.array([[0.0, 100.0], [200.0, 100.0], [0.0, 100.0]]))  # collinear
    found, expected = find_intersections(chains), _reference_intersections(chains)
    assert [f[:4] for f in found] == [e[:4] for e in expected]
    for f, e in zip(found, expected, strict=True):
        np.testing.assert_array_equal(f[4], e[4])


def test_crossing_profiles_on_patches_equal_the_whole_image():
    from service.perception.crossings import _lab, profile_variation, profile_variations

    image = make_scene(320, 180, 3, seed=2).image
    lab = _lab(image)
    rng = np.random.default_rng(0)
    for _ in range(40):
        # Most lines lie inside; some reach the border and use the whole image.
        centre = rng.uniform([0, 0], [320, 180])
        angle = rng.uniform(0, np.pi)
        lines = [(centre, np.array([np.cos(a), np.sin(a)]), 7.5) for a in (angle, angle + 1.0)]
        values, _ = profile_variations(image, lines)
        assert values == [profile_variation(lab, *line) for line in lines]


def _reference_inferred(source_edge, edge_lengths, hidden_edge):
    inferred = np.zeros(len(source_edge) - 1, bool)
    for k in range(len(source_edge) - 1):
        span_edges = slice(source_edge[k], source_edge[k + 1] + 1)
        weights = edge_lengths[span_edges]
        if weights.sum() > 0:
            inferred[k] = (weights * hidden_edge[span_edges]).sum() > 0.5 * weights.sum()
        else:
            inferred[k] = bool(hidden_edge[source_edge[k]])
    return inferred


@pytest.mark.parametrize("seed", range(4))
def test_inferred_segments_kernel_equals_the_reference(seed):
    rng = np.random.default_rng(seed)
    for _ in range(40):
        n_edges = int(rng.integers(1, 400))
        edge_lengths = rng.random(n_edges) * rng.choice([0.0, 1.0, 3.0])
        edge_lengths[rng.random(n_edges) < 0.1] = 0.0
        hidden_edge = rng.random(n_edges) < rng.random()
        source_edge = np.sort(rng.integers(0, n_edges, int(rng.integers(2, 60))))
        np.testing.assert_array_equal(
            _kernels.inferred_segments(source_edge, edge_lengths, hidden_edge),
            _reference_inferred(source_edge, edge_lengths, hidden_edge),
        )


@pytest.mark.parametrize("seed", range(6))
def test_own_threshold_kernels_equal_the_reference(seed):
    rng = np.random.default_rng(seed)
    height, width = 60, 80
    cue = cv2.GaussianBlur(rng.integers(0, 256, (height, width)).astype(np.uint8), (5, 5), 0)
    before = cue > np.percentile(cue, 70)
    points = np.cumsum(rng.normal(0.0, 6.0, (7, 2)), axis=0) + np.array([width, height]) / 2
    points[3] = points[2]  # a zero-length segment
    seen = rng.random(len(points) - 1) > 0.25
    avoid_xy = rng.uniform(0, [width, height], (2, 2))
    avoid_reach = rng.uniform(3.0, 12.0, 2)
    span, stride, start, reach = 7, 1 + seed % 3, seed % 3, 4
    low = float(rng.integers(60, 200))
    hist, feet = _kernels.profile_histogram(cue, points, seen, avoid_xy, avoid_reach, span, stride)
    want_hist, want_feet = _reference_profile_histogram(
        cue, points, seen, avoid_xy, avoid_reach, span, stride
    )
    assert feet == want_feet and np.array_equal(hist, want_hist)
    grown = before.view(np.uint8).copy()
    _kernels.grow_along_profiles(
        cue, before.view(np.uint8), grown, points, seen, avoid_xy, avoid_reach, start, reach, low
    )
    want = _reference_grow(cue, before, points, seen, avoid_xy, avoid_reach, start, reach, low)
    assert np.array_equal(grown.view(bool), want)


@pytest.mark.parametrize("seed", range(8))
def test_otsu_kernel_equals_the_reference(seed):
    rng = np.random.default_rng(seed)
    hists = [
        rng.integers(0, 1000, 256).astype(np.float64),
        np.bincount(rng.integers(0, 256, 5000), minlength=256).astype(np.float64),
    ]
    # Two classes with an empty stretch between them (a plateau of equal thresholds),
    # and a histogram of one level.
    gapped = np.zeros(256)
    gapped[rng.integers(0, 60, 300)] += 1
    gapped[rng.integers(150, 256, 100)] += 1
    single = np.zeros(256)
    single[rng.integers(0, 256)] = 7
    for hist in [*hists, gapped, single]:
        threshold, separability = _kernels.otsu_kernel(hist)
        want_threshold, want_separability = _reference_otsu(hist)
        assert threshold == want_threshold
        assert separability == pytest.approx(want_separability, rel=1e-12, abs=1e-15)
