"""Plain step 6: the end fits piece by piece (the code ``_merging_kernels.fit_chain_ends``
replaced), the junction zone of each end (the labelling ``_merging_kernels.grown_zone_labels``
replaced), the gap curves (the natural curve's three shapes and the smooth cubic), and the
choice of joins costing every pair of chain ends (the code the grid of
``_merging_kernels.candidate_joins`` replaced)."""

import cv2
import numpy as np

from service.perception import _geometry_kernels, _merging_kernels, merging, paths
from service.perception.appearance import colour_penalty
from service.perception.geometry import angle_between, end_fit, polyline_length
from service.perception.pairing import Components


def chain_ends(pieces, span, skip=0.0, distance=None, full_width=0.0, bend_aware=None):
    """:func:`service.perception.merging.chain_ends` end by end, through
    :func:`service.perception.geometry.end_fit` (over :func:`bend_aware_span` for the
    ends flagged in ``bend_aware``)."""
    ends = []
    medians = None
    interior = np.zeros(len(pieces))
    if distance is not None and pieces:
        # Cables differ in width: a piece's own full width is the typical distance to
        # the border at its joints, and for a long piece also that away from both ends
        # (more than merging.NARROW_END_JOINTS in), where no cut end narrows it.
        minimum = 2 * merging.NARROW_END_JOINTS + merging.MIN_INTERIOR_JOINTS
        long = [k for k, points in enumerate(pieces) if len(points) >= minimum]
        middles = [pieces[k][merging.NARROW_END_JOINTS : -merging.NARROW_END_JOINTS] for k in long]
        parts = list(pieces) + middles
        starts = np.cumsum([0] + [len(points) for points in parts]).astype(np.int64)
        joints = np.ascontiguousarray(np.concatenate(parts), dtype=np.float64)
        values = _merging_kernels.median_distance_per_piece(
            np.ascontiguousarray(distance, np.float32), joints, starts
        )
        medians, interior[long] = values[: len(pieces)], values[len(pieces) :]
    for index, points in enumerate(pieces):
        piece_full = full_width
        if medians is not None and len(points) >= 3:
            piece_full = max(full_width, merging.FULL_WIDTH_FRACTION * float(medians[index]))
        if interior[index] > 0:
            # A cable thinner than the picture's typical one is at its full width
            # where its own middle is: held to the typical width, its every joint
            # would look narrow, and a joint widened by a bend or a touching strand
            # would cut the end's fit short by several joints. (Only ever lower: a
            # blob the piece runs through widens its middle.)
            piece_full = min(piece_full, merging.FULL_WIDTH_FRACTION * float(interior[index]))
        piece_width = float(medians[index]) if medians is not None else 0.0
        minimum = 2 * merging.NARROW_END_JOINTS + merging.MIN_INTERIOR_JOINTS
        if medians is not None and 3 <= len(points) < minimum:
            # A short piece narrowed by cuts (often at a slant) at both ends: its widest
            # joint between the end joints.
            height, width = distance.shape
            inner = np.rint(points[1:-1]).astype(np.int64)
            values = distance[inner[:, 1].clip(0, height - 1), inner[:, 0].clip(0, width - 1)]
            widest = float(values.max())
            if piece_width < merging.FULL_WIDTH_FRACTION * widest:
                piece_width = widest
        skips = [skip, skip]
        if distance is not None:
            skips = [
                max(skip, _narrow_end_length(points, at_start, distance, piece_full))
                for at_start in (True, False)
            ]
        length = polyline_length(points)
        for at_start in (True, False):
            end_skip, far_skip = skips if at_start else skips[::-1]
            # A short piece's fit stops short of its other end's narrow tip: a cut
            # there bends toward the cut's corner and would tilt this end.
            reach = length - end_skip - far_skip
            end_span = min(span, reach) if far_skip > skip and reach >= 0.5 * span else span
            if bend_aware is not None and bend_aware[2 * index + (0 if at_start else 1)]:
                end_span = bend_aware_span(points, at_start, end_skip, end_span)
            position, direction, curvature = end_fit(points, at_start, end_span, end_skip)
            ends.append(
                merging.ChainEnd(
                    index, at_start, position, direction, curvature, end_skip, piece_width
                )
            )
    return ends


def bend_aware_span(points, at_start, skip, span):
    """The span ``_geometry_kernels.bend_aware_fit`` fits over: halved while the turns at
    the joints between ``skip`` and ``skip + span`` of arc length from the end add up to
    more than ``END_FIT_MAX_TURNING``."""
    ordered = np.asarray(points if at_start else points[::-1], np.float64)
    steps = np.diff(ordered, axis=0)
    arcs = np.concatenate([[0.0], np.cumsum(np.hypot(steps[:, 0], steps[:, 1]))])
    # The signed turn at each inner joint, from the step before it to the step after.
    turns = np.arctan2(
        steps[:-1, 0] * steps[1:, 1] - steps[:-1, 1] * steps[1:, 0],
        steps[:-1, 0] * steps[1:, 0] + steps[:-1, 1] * steps[1:, 1],
    )
    inner = arcs[1:-1]

    def turning(reach):
        # The kernel stops at the first joint past the reach: the arcs only grow.
        return abs(float(turns[(inner >= skip) & (inner <= reach)].sum()))

    while span > 1.0 and turning(skip + span) > _geometry_kernels.END_FIT_MAX_TURNING:
        span *= 0.5
    return span


def _narrow_end_length(points, at_start, distance, full_width, limit=merging.NARROW_END_JOINTS):
    """Arc length from the tip to the first joint where the cable has its full width
    (0 when none of the first ``limit`` joints reaches it)."""
    ordered = points if at_start else points[::-1]
    height, width = distance.shape
    length = 0.0
    for k in range(min(len(ordered), limit + 1)):
        if k:
            length += float(np.hypot(*(ordered[k] - ordered[k - 1])))
        col = min(max(round(float(ordered[k][0])), 0), width - 1)
        row = min(max(round(float(ordered[k][1])), 0), height - 1)
        if distance[row, col] >= full_width:
            return length
    return 0.0


def junctions_of_ends(ends, zones, reach=3):
    """:func:`service.perception.merging.junctions_of_ends` by growing (``cv2.dilate``)
    and labelling (``cv2.connectedComponents``) the zones' box plus the reach."""
    if zones is None or not zones.any():
        return [-1] * len(ends)
    zones_u8 = zones.astype(np.uint8)
    height, width = zones.shape
    x, y, w, h = cv2.boundingRect(zones_u8)
    left, top = max(x - reach, 0), max(y - reach, 0)
    right, bottom = min(x + w + reach, width), min(y + h + reach, height)
    kernel = np.ones((2 * reach + 1, 2 * reach + 1), np.uint8)
    grown = cv2.dilate(zones_u8[top:bottom, left:right], kernel)
    _, labels = cv2.connectedComponents(grown, connectivity=8)
    result = []
    for end in ends:
        col = min(max(round(float(end.position[0])), 0), width - 1) - left
        row = min(max(round(float(end.position[1])), 0), height - 1) - top
        inside = 0 <= row < bottom - top and 0 <= col < right - left
        result.append(int(labels[row, col]) - 1 if inside and labels[row, col] > 0 else -1)
    return result


def on_grown_zones(zones, positions, reach=3):
    """``_merging_kernels.on_grown_zones``: the whole picture's zones grown
    (``cv2.dilate``) by a ``2 reach + 1`` square, read at each position rounded half to
    even and clipped to the picture."""
    height, width = zones.shape
    square = np.ones((2 * reach + 1, 2 * reach + 1), np.uint8)
    grown = cv2.dilate(zones.astype(np.uint8), square)
    cols = np.clip(np.rint(positions[:, 0]).astype(np.int64), 0, width - 1)
    rows = np.clip(np.rint(positions[:, 1]).astype(np.int64), 0, height - 1)
    return grown[rows, cols] > 0


def _arc(start: np.ndarray, heading: np.ndarray, turn: float, radius: float, step: float):
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


def _without_repeats(points: np.ndarray) -> np.ndarray:
    """Drop points that repeat their predecessor (a straight part of zero length)."""
    steps = np.hypot(*np.diff(points, axis=0).T)
    keep = np.concatenate([[True], steps > 1e-9])
    return points[keep]


def _segment(a: np.ndarray, b: np.ndarray, step: float) -> np.ndarray:
    count = max(2, int(np.ceil(np.hypot(*(b - a)) / step)) + 1)
    return a + np.linspace(0.0, 1.0, count)[:, None] * (b - a)


def natural_curve_shape(start, leaving, end, arriving) -> str:
    """Which shape the natural curve takes: "point", "straight", "arc" or "bezier"."""
    gap = end - start
    distance = float(np.hypot(*gap))
    if distance < 1e-9:
        return "point"
    cross = leaving[0] * arriving[1] - leaving[1] * arriving[0]
    dot = leaving[0] * arriving[0] + leaving[1] * arriving[1]
    if abs(cross) < 1e-6:
        straight = dot > 0 and angle_between(leaving, gap / distance) < 1e-3
        return "straight" if straight else "bezier"
    matrix = np.array([[leaving[0], arriving[0]], [leaving[1], arriving[1]]])
    t_a, t_b = np.linalg.solve(matrix, gap)
    return "arc" if t_a > 0 and t_b > 0 else "bezier"


def natural_curve(start, leaving, end, arriving, step=1.0):
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
            return _segment(start, end, step)
    else:
        # start + t_a * leaving = end - t_b * arriving
        matrix = np.array([[leaving[0], arriving[0]], [leaving[1], arriving[1]]])
        t_a, t_b = np.linalg.solve(matrix, gap)
        if t_a > 0 and t_b > 0:
            corner = start + t_a * leaving
            tangent = min(t_a, t_b)
            arc_start = corner - tangent * leaving
            arc_radius = tangent / np.tan(abs(turn) / 2.0)
            arc = _arc(arc_start, leaving, turn, arc_radius, step)
            parts = [
                _segment(start, arc_start, step),
                arc[1:],
                _segment(arc[-1], end, step)[1:],
            ]
            curve = np.concatenate(parts)
            curve[-1] = end
            return _without_repeats(curve)
    handle = 0.4 * distance
    control = np.array([start, start + handle * leaving, end - handle * arriving, end])
    count = max(4, int(np.ceil(1.3 * distance / step)) + 1)
    t = np.linspace(0.0, 1.0, count)[:, None]
    weights = [(1 - t) ** 3, 3 * (1 - t) ** 2 * t, 3 * (1 - t) * t**2, t**3]
    return sum(w * c for w, c in zip(weights, control, strict=True))


def smooth_curve(start, leaving, end, arriving, step=1.0):
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


def _signed_angle(u, w):
    return float(np.arctan2(u[0] * w[1] - u[1] * w[0], u[0] * w[0] + u[1] * w[1]))


def _wrapped(angle):
    return float((angle + np.pi) % (2.0 * np.pi) - np.pi)


def _bending(turn, first, second, distance, length, kappa_a, kappa_b, params, radius):
    expected = (kappa_a + kappa_b) / 2.0 * length
    cost = params.direction_weight * abs(_wrapped(turn - expected)) / np.pi
    if distance > 1e-9:
        expected_first = length * (2.0 * kappa_a + kappa_b) / 6.0
        turning = abs(_wrapped(first - expected_first))
        turning += abs(_wrapped(second - (expected - expected_first)))
        fade = min(1.0, distance / max(3.0 * radius, 1e-9))
        cost += params.curvature_weight * fade * turning / (2.0 * np.pi)
    return cost


def join_cost(a, b, params, radius):
    """:func:`service.perception.merging.join_cost` in plain Python: the paper's three
    parts, the direction and turning ones less the turning that the ends' curvature
    (capped at a bend of MIN_BEND_RADII radii) carries on across the gap when that is
    cheaper than the paper's."""
    gap = b.position - a.position
    distance = float(np.hypot(*gap))
    leaving, arriving = a.direction, -b.direction
    turn = _signed_angle(leaving, arriving)
    limit = 1.0 / max(_merging_kernels.MIN_BEND_RADII * radius, 1e-9)
    kappa_a = float(np.clip(a.curvature, -limit, limit))
    kappa_b = float(np.clip(-b.curvature, -limit, limit))
    # The arc length of a circle through both ends with that turn.
    half = abs(turn) / 2.0
    length = distance * half / np.sin(half) if half > 1e-6 else distance
    first = second = 0.0
    if distance > 1e-9:
        heading = gap / distance
        first, second = _signed_angle(leaving, heading), _signed_angle(heading, arriving)
    shape = (turn, first, second, distance, length)
    bent = _bending(*shape, kappa_a, kappa_b, params, radius)
    straight = _bending(*shape, 0.0, 0.0, params, radius)
    return params.distance_weight * distance / max(params.max_gap, 1e-9) + min(bent, straight)


def runs_to_border(mask, positions, directions, reach, margin):
    """``_merging_kernels.runs_to_border`` as a plain loop."""
    height, width = mask.shape
    result = np.zeros(len(positions), bool)
    for index, ((x, y), (dx, dy)) in enumerate(zip(positions, directions, strict=True)):
        step = 0.0
        while step <= reach:
            col, row = round(x + step * dx), round(y + step * dy)
            if not (0 <= col < width and 0 <= row < height):
                result[index] = True
                break
            if not mask[row, col]:
                col, row = round(x + (step + margin) * dx), round(y + (step + margin) * dy)
                result[index] = not (0 <= col < width and 0 <= row < height)
                break
            step += 1.0
    return result


def choose_joins(
    ends,
    piece_count,
    params,
    radius,
    junction_of_end=None,
    at_border=None,
    colours=None,
    leaving=None,
    picture=None,
):
    """:func:`service.perception.merging.choose_joins` over every pair of ends: a distance
    matrix of all ends and a plain loop over every pair of free ends."""
    components = Components(piece_count)
    used = np.zeros(len(ends), bool)
    chains_left = piece_count
    joins = []

    def try_join(i, j, cost):
        nonlocal chains_left
        if used[i] or used[j]:
            return False
        piece_i, piece_j = ends[i].piece, ends[j].piece
        if components.find(piece_i) == components.find(piece_j):
            return False
        components.union(piece_i, piece_j)
        used[i] = used[j] = True
        chains_left -= 1
        joins.append((i, j, cost))
        return True

    if junction_of_end is not None:
        groups = {}
        for index, junction in enumerate(junction_of_end):
            if junction >= 0:
                groups.setdefault(junction, []).append(index)
        proposals = []
        for members in groups.values():
            if 2 <= len(members) <= merging.MAX_JUNCTION_ENDS:
                proposals.extend(merging._best_matchings([members], ends, params, radius, colours))
        for i, j, cost in sorted(proposals, key=lambda item: item[2]):
            try_join(i, j, cost)

    positions = np.array([end.position for end in ends]) if ends else np.zeros((0, 2))
    distances = np.hypot(*(positions[:, None, :] - positions[None, :, :]).transpose(2, 0, 1))
    unlimited = params.expected_count is not None
    candidates = []
    free = np.flatnonzero(~used)
    for a_pos, i in enumerate(free):
        for j in free[a_pos + 1 :]:
            if ends[i].piece == ends[j].piece:
                continue
            if not unlimited and distances[i, j] > params.max_gap:
                continue
            if not unlimited and leaving is not None and (leaving[i] or leaving[j]):
                continue
            cost = merging.join_cost(ends[i], ends[j], params, radius)
            if colours is not None:
                cost += params.colour_weight * float(
                    colour_penalty(colours, np.array(i), np.array(j))
                )
            limit = merging.MUTUAL_COST_FACTOR * params.merge_cost_threshold
            if not unlimited and picture is not None and cost <= limit:
                a, b = ends[i], ends[j]
                curve = paths.gap_curve(
                    a.position, a.direction, b.position, -b.direction, shape=params.gap_curve
                )
                height, width = picture
                inside = (curve >= -0.5).all() and (curve[:, 0] <= width - 0.5).all()
                if not (inside and (curve[:, 1] <= height - 0.5).all()):
                    continue
            candidates.append((cost, int(i), int(j)))
    candidates.sort()
    for cost, i, j in candidates:
        if params.expected_count is not None and chains_left <= params.expected_count:
            break
        if params.expected_count is None and cost > params.merge_cost_threshold:
            break
        try_join(i, j, cost)
    if params.expected_count is None:
        excluded = used if at_border is None else used | at_border
        near = [
            (cost, i, j)
            for cost, i, j in candidates
            if distances[i, j] <= merging.MUTUAL_GAP_RADII * radius
        ]
        for cost, i, j in merging._mutual_best(near, excluded, params.merge_cost_threshold):
            try_join(i, j, cost)
    return joins
