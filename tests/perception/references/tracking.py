"""Plain versions of the tracker's kernels (service/perception/_tracking_kernels.py)."""

import math

import numpy as np


def _foot(p, a, b):
    ab = b - a
    length_sq = float(ab @ ab)
    t = 0.0 if length_sq == 0 else min(max(float((p - a) @ ab) / length_sq, 0.0), 1.0)
    foot = a + t * ab
    return float((foot - p) @ (foot - p)), t


def nearest_on_polylines(points, directions, joints, starts, counts, gate):
    n_points, n_lines = len(points), len(starts)
    distance = np.full((n_points, n_lines), np.inf)
    arc = np.zeros((n_points, n_lines))
    cosine = np.zeros((n_points, n_lines))
    for line in range(n_lines):
        polyline = joints[starts[line] : starts[line] + counts[line]]
        for p in range(n_points):
            best, best_k, best_t = np.inf, -1, 0.0
            for k in range(len(polyline) - 1):
                d_sq, t = _foot(points[p], polyline[k], polyline[k + 1])
                if d_sq < best:
                    best, best_k, best_t = d_sq, k, t
            beyond = (best_k == 0 and best_t <= 0) or (best_k == len(polyline) - 2 and best_t >= 1)
            if best_k >= 0 and best <= gate[line] ** 2 and not beyond:
                distance[p, line] = math.sqrt(best)
                arc[p, line] = best_k + best_t
                segment = polyline[best_k + 1] - polyline[best_k]
                length = float(np.hypot(*segment))
                if length > 0:
                    cosine[p, line] = float(directions[p] @ segment) / length
    return distance, arc, cosine


def _segment_distance(a, b, c, e):
    def cross(o, p, q):
        return (p[0] - o[0]) * (q[1] - o[1]) - (p[1] - o[1]) * (q[0] - o[0])

    if cross(a, b, c) * cross(a, b, e) < 0 and cross(c, e, a) * cross(c, e, b) < 0:
        return 0.0
    return min(_foot(a, c, e)[0], _foot(b, c, e)[0], _foot(c, a, b)[0], _foot(e, a, b)[0])


def crowded_segments(joints, starts, counts, reach, self_gap):
    segments = []
    for chain in range(len(starts)):
        for k in range(counts[chain] - 1):
            a = starts[chain] + k
            segments.append((chain, k, joints[a], joints[a + 1]))
    crowded = np.zeros(len(segments), bool)
    for i, (ci, ki, a, b) in enumerate(segments):
        for j, (cj, kj, c, e) in enumerate(segments):
            if i == j or (ci == cj and abs(ki - kj) < self_gap[ci]):
                continue
            if _segment_distance(a, b, c, e) <= (reach[ci] + reach[cj]) ** 2:
                crowded[i] = True
    return crowded


def near_any_segment(points, reach, seg_starts, seg_ends):
    return np.array(
        [
            any(_foot(p, a, b)[0] <= r * r for a, b in zip(seg_starts, seg_ends, strict=True))
            for p, r in zip(points, reach, strict=True)
        ],
        bool,
    )


def fit_statistics(
    distance, arc, cosine, sample_arc, starts, counts, gates, min_cosine, track_lengths
):
    n_pieces, n_tracks = len(starts), len(gates)
    ok = np.zeros((n_pieces, n_tracks), bool)
    sign = np.ones((n_pieces, n_tracks), int)
    offset = np.zeros((n_pieces, n_tracks))
    cost = np.full((n_pieces, n_tracks), np.inf)
    share = np.zeros((n_pieces, n_tracks))
    for p in range(n_pieces):
        rows = slice(starts[p], starts[p] + counts[p])
        u = sample_arc[rows]
        for t in range(n_tracks):
            d, s, c = distance[rows, t], arc[rows, t], cosine[rows, t]
            near = np.isfinite(d) & (np.abs(c) >= min_cosine)
            n_near = int(near.sum())
            along_track = (counts[p] - 1) * track_lengths[t] / max(u[-1], 1e-9) + 1
            if n_near < 3 or n_near < 0.5 * min(counts[p], along_track):
                continue
            direction = 1 if c[near].sum() >= 0 else -1
            values = s[near] - direction * u[near]
            middle = float(np.median(values))
            spread = float(np.median(np.abs(values - middle)))
            if spread > 0.5 * max(u[-1], 1.0):
                continue
            ok[p, t] = True
            sign[p, t] = direction
            offset[p, t] = middle
            share[p, t] = n_near / counts[p]
            cost[p, t] = d[near].mean() + (1 - n_near / counts[p]) * gates[t] + 0.25 * spread
    return ok, sign, offset, cost, share


def _at(points, arcs, u):
    return np.array([np.interp(u, arcs, points[:, 0]), np.interp(u, arcs, points[:, 1])])


def refine_offset(joints, points, arcs, sign, offset, step, iterations):
    for _ in range(iterations):
        residuals = []
        for k in range(len(joints)):
            u = sign * (k * step - offset)
            if u < 0 or u > arcs[-1]:
                continue
            s = min(max(np.searchsorted(arcs, u, side="right") - 1, 0), len(points) - 2)
            direction = points[s + 1] - points[s]
            norm = float(np.hypot(*direction))
            if norm <= 0:
                continue
            residuals.append(float((joints[k] - _at(points, arcs, u)) @ direction) / norm)
        if len(residuals) < 2:
            break
        offset -= sign * float(np.mean(residuals))
    return offset


def chord_walk(points, arcs, start, sign, step, limit):
    """Points exactly ``step`` apart in a straight line, walking the polyline from arc
    ``start``; found by bisection on the arc (the polyline turns no more than a circle of
    radius ``step`` can cross twice in these tests)."""
    out = [_at(points, arcs, start)]
    u = start
    end = arcs[-1] if sign > 0 else 0.0
    while len(out) < limit:
        if np.hypot(*(_at(points, arcs, end) - out[-1])) < step:
            break
        lo, hi = u, end
        for _ in range(200):
            mid = 0.5 * (lo + hi)
            if np.hypot(*(_at(points, arcs, mid) - out[-1])) < step:
                lo = mid
            else:
                hi = mid
        u = 0.5 * (lo + hi)
        out.append(_at(points, arcs, u))
    return np.array(out)


def motion_numpy(previous, current, use, pinned, tangent, rigid_only):
    """track_motion.motion as written in NumPy before its kernels (no carried slide):
    the kernels must give its bits exactly."""
    normal = np.column_stack([-tangent[:, 1], tangent[:, 0]])
    across = ((current - previous) * normal).sum(axis=1)
    centre = previous[use].mean(axis=0)
    arm = previous - centre
    turned = np.column_stack([-arm[:, 1], arm[:, 0]])
    design = np.column_stack([normal, (turned * normal).sum(axis=1)])
    count = np.count_nonzero(use)
    scale = max(float(np.sqrt((arm[use] ** 2).sum(axis=1).mean())), 1.0)
    ridge = 0.02 * count * np.diag([1.0, 1.0, scale * scale])
    rows = design[use]
    values = across[use]
    if len(pinned):
        weight = math.sqrt(count / (2.0 * len(pinned)))
        extra_rows, extra_values = [], []
        for joint, displacement in pinned:
            extra_rows += [[weight, 0.0, weight * turned[joint, 0]]]
            extra_rows += [[0.0, weight, weight * turned[joint, 1]]]
            extra_values += [weight * displacement[0], weight * displacement[1]]
        rows = np.vstack([rows, extra_rows])
        values = np.concatenate([values, extra_values])
    fitted = np.linalg.solve(rows.T @ rows + ridge, rows.T @ values)
    translation_x, translation_y, rotation = fitted
    rigid = np.array([translation_x, translation_y]) + rotation * turned
    remainder = across - (rigid * normal).sum(axis=1)
    kernel = np.array([1.0, 2.0, 3.0, 2.0, 1.0]) / 9.0
    if len(remainder) >= 3:
        padded = np.concatenate([remainder[:1]] * 2 + [remainder] + [remainder[-1:]] * 2)
        remainder = sum(kernel[i] * padded[i : i + len(remainder)] for i in range(5))
    result = rigid + remainder[:, None] * normal
    result[rigid_only] = rigid[rigid_only]
    return result


def piece_samples(joints):
    """track_matching._samples as written in NumPy before its kernel."""
    n = len(joints)
    points = np.empty((2 * n - 1, 2))
    points[0::2] = joints
    points[1::2] = 0.5 * (joints[:-1] + joints[1:])
    steps = np.diff(joints, axis=0)
    lengths = np.linalg.norm(steps, axis=1)
    unit = steps / np.maximum(lengths, 1e-12)[:, None]
    directions = np.empty_like(points)
    directions[1::2] = unit
    directions[0] = unit[0]
    directions[-1] = unit[-1]
    if n > 2:
        inner = unit[:-1] + unit[1:]
        directions[2:-1:2] = inner / np.maximum(np.linalg.norm(inner, axis=1), 1e-12)[:, None]
    arc = np.concatenate([[0.0], np.cumsum(np.repeat(lengths / 2.0, 2))])
    return points, directions, arc


def unit_tangents(joints):
    """track_motion.tangents as written in NumPy before its kernel."""
    tangent = np.empty_like(joints)
    tangent[0] = joints[1] - joints[0]
    tangent[-1] = joints[-1] - joints[-2]
    tangent[1:-1] = (joints[2:] - joints[:-2]) / 2.0
    length = np.sqrt(tangent[:, 0] ** 2 + tangent[:, 1] ** 2)
    return tangent / np.maximum(length, 1e-12)[:, None]
