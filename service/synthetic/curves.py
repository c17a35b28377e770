"""Cable centrelines: random smooth curves, clipping to the picture, and their crossings.

Every centreline is sampled :data:`SAMPLE_SPACING` px apart along its arc length.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy.spatial import cKDTree

# Centreline samples are this far apart (px): fine enough that the distance to the sampled
# polyline is the distance to the smooth curve, to a few thousandths of a pixel.
SAMPLE_SPACING = 0.5

_INTERSECTION_CHUNK = 8  # segments per bounding box when searching for crossings


@dataclass(frozen=True, eq=False)
class _Curve:
    """A cable centreline with its arc lengths and a nearest-sample index."""

    points: np.ndarray
    arc: np.ndarray
    radius: float
    tree: cKDTree

    @classmethod
    def from_points(cls, points: np.ndarray, radius: float) -> _Curve:
        steps = np.linalg.norm(np.diff(points, axis=0), axis=1)
        arc = np.concatenate([[0.0], np.cumsum(steps)])
        return cls(points=points, arc=arc, radius=radius, tree=cKDTree(points))

    @property
    def length(self) -> float:
        return float(self.arc[-1])

    @cached_property
    def chunk_boxes(self) -> np.ndarray:
        return _chunk_boxes(self.points, _INTERSECTION_CHUNK)


@dataclass(frozen=True)
class _Crossing:
    """Two centrelines crossing, before depths decide which one is on top."""

    x: float
    y: float
    first: int
    second: int
    first_arc: float
    second_arc: float
    angle: float  # between the two tangents, 0 to pi/2
    reach: float  # largest radius of the two cables: sets how far apart crossings stay


def _random_centreline(rng, radius, length, diagonal, with_loop):
    """Integrate a smoothly varying curvature into a centreline, optionally with a loop.

    Returns the ``(N, 2)`` samples and the index of the anchor sample, which sits at the
    origin: a point near the middle, or the far side of the loop if there is one.
    """
    n_segments = max(2, math.ceil(length / SAMPLE_SPACING))
    total = n_segments * SAMPLE_SPACING
    # Bending tighter than 4 radii would pinch the drawn tube into a kink.
    max_curvature = 1.0 / (4.0 * radius)
    curvature = _smooth_random_curvature(rng, n_segments, diagonal, max_curvature)
    segment_mid_arc = (np.arange(n_segments) + 0.5) * SAMPLE_SPACING

    anchor_arc = rng.uniform(0.35, 0.65) * total
    if with_loop:
        # A loop is a straight arm, a circular arc turning by pi + beta, and a straight arm
        # back: the arms are tangent to the circle and meet where they started, so the
        # cable crosses itself there at angle beta. Its radius of >= 5 cable radii keeps the
        # hole open.
        loop_radius = rng.uniform(5.0 * radius, max(7.0 * radius, 0.04 * diagonal))
        beta = rng.uniform(math.radians(45.0), math.radians(100.0))
        arm = loop_radius / math.tan(beta / 2.0)
        turn_length = loop_radius * (math.pi + beta)
        loop_length = 2.0 * arm + turn_length
        if loop_length <= 0.5 * total:
            start = rng.uniform(0.25 * total, 0.75 * total - loop_length)
            turn_start, turn_end = start + arm, start + arm + turn_length
            in_loop = (segment_mid_arc >= start) & (segment_mid_arc < start + loop_length)
            curvature[in_loop] = 0.0
            turning = (segment_mid_arc >= turn_start) & (segment_mid_arc < turn_end)
            curvature[turning] = rng.choice([-1.0, 1.0]) / loop_radius
            anchor_arc = (turn_start + turn_end) / 2.0

    # Each step follows the heading at its middle, which is exact for circular arcs.
    headings = rng.uniform(0.0, 2.0 * math.pi) + (np.cumsum(curvature) - curvature / 2.0) * (
        SAMPLE_SPACING
    )
    steps = SAMPLE_SPACING * np.column_stack([np.cos(headings), np.sin(headings)])
    points = np.vstack([np.zeros((1, 2)), np.cumsum(steps, axis=0)])
    anchor_index = min(round(anchor_arc / SAMPLE_SPACING), n_segments)
    return points - points[anchor_index], anchor_index


def _smooth_random_curvature(rng, n_segments, diagonal, max_curvature):
    """Curvature per segment: random knots, linearly joined, then box-smoothed."""
    knot_spacing = diagonal * rng.uniform(0.05, 0.12)
    typical_curvature = 1.0 / (diagonal * rng.uniform(0.08, 0.2))
    n_knots = int(n_segments * SAMPLE_SPACING / knot_spacing) + 3
    knots = rng.normal(0.0, typical_curvature, n_knots)
    knot_arcs = (np.arange(n_knots) - 1.0) * knot_spacing
    segment_mid_arc = (np.arange(n_segments) + 0.5) * SAMPLE_SPACING
    curvature = np.interp(segment_mid_arc, knot_arcs, knots)
    # Smoothing over one knot spacing rounds off the corners of the linear joins, so the
    # curvature changes gradually and the cable has no visible bends at the knots.
    window = max(1, int(knot_spacing / SAMPLE_SPACING))
    padded = np.pad(curvature, (window // 2, window - 1 - window // 2), mode="edge")
    curvature = np.convolve(padded, np.full(window, 1.0 / window), mode="valid")
    return np.clip(curvature, -0.8 * max_curvature, 0.8 * max_curvature)


def _fit_inside_box(rng, points, box, tries=8):
    """Turn and shift the whole curve to a random place inside ``box``, or return None.

    Turning the curve keeps its shape; for each random turn the shifts that fit form a
    rectangle, so one can be drawn directly instead of by trial and error.
    """
    for _ in range(tries):
        angle = rng.uniform(0.0, 2.0 * math.pi)
        rotation = np.array(
            [[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]]
        )
        turned = points @ rotation.T
        low = np.array(box[:2]) - turned.min(axis=0)
        high = np.array(box[2:]) - turned.max(axis=0)
        if np.all(low <= high):
            return turned + rng.uniform(low, high)
    return None


def _clip_to_box(points, anchor_index, box):
    """Keep the contiguous piece inside ``box`` around the anchor, ends cut at the border."""
    clipped = _clip_to_box_with_offset(points, anchor_index, box)
    return None if clipped is None else clipped[0]


def _clip_to_box_with_offset(points, anchor_index, box):
    """:func:`_clip_to_box`, and the index in the result of original sample 0.

    Returns ``(points, offset)``: original sample ``i`` (if kept) is ``points[i + offset]``.
    """
    x_min, y_min, x_max, y_max = box
    inside = (
        (points[:, 0] >= x_min)
        & (points[:, 0] <= x_max)
        & (points[:, 1] >= y_min)
        & (points[:, 1] <= y_max)
    )
    outside_before = np.flatnonzero(~inside[:anchor_index])
    outside_after = np.flatnonzero(~inside[anchor_index:])
    first = outside_before[-1] + 1 if outside_before.size else 0
    last = anchor_index + outside_after[0] - 1 if outside_after.size else len(points) - 1
    if last - first < 1:
        return None
    pieces = [points[first : last + 1]]
    if first > 0:
        pieces.insert(0, _border_point(points[first], points[first - 1], box))
    if last < len(points) - 1:
        pieces.append(_border_point(points[last], points[last + 1], box))
    prepended = len(pieces[0]) if first > 0 else 0
    return np.vstack(pieces), prepended - first


def _border_point(inside, outside, box):
    """Where the step from ``inside`` to ``outside`` leaves ``box``, as a (0 or 1, 2) array."""
    step = outside - inside
    fraction = 1.0
    for axis, (low, high) in enumerate(((box[0], box[2]), (box[1], box[3]))):
        if outside[axis] < low:
            fraction = min(fraction, (low - inside[axis]) / step[axis])
        elif outside[axis] > high:
            fraction = min(fraction, (high - inside[axis]) / step[axis])
    # A border point on top of the last inside sample would make a zero-length segment.
    if fraction * np.linalg.norm(step) < 1e-6:
        return np.empty((0, 2))
    # Clipping removes rounding error that would leave the point a hair outside the box.
    point = np.clip(inside + fraction * step, [box[0], box[1]], [box[2], box[3]])
    return point[None, :]


def _true_runs(flags):
    """Start and stop (exclusive) indices of the runs of True in a 1-D bool array."""
    padded = np.concatenate([[False], flags, [False]]).astype(np.int8)
    edges = np.diff(padded)
    return np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)


def _intersections(a, b, *, same):
    """Every crossing of two polylines (or of one with itself) as tuples.

    Each tuple is ``(x, y, arc_a, arc_b, angle)``. Segments are grouped into short chunks
    whose bounding boxes are compared first, so only segments near each other are tested
    exactly. Parameters run over ``[0, 1)`` so a crossing through a sample counts once.
    """
    chunk = _INTERSECTION_CHUNK
    # Only chunks inside the other curve's bounding box can meet it: usually a few.
    chunks_a = _chunks_overlapping(a.chunk_boxes, _bounding_box(b.points))
    chunks_b = _chunks_overlapping(b.chunk_boxes, _bounding_box(a.points))
    boxes_a, boxes_b = a.chunk_boxes[chunks_a], b.chunk_boxes[chunks_b]
    overlap = (
        (boxes_a[:, None, 0] <= boxes_b[None, :, 2])
        & (boxes_b[None, :, 0] <= boxes_a[:, None, 2])
        & (boxes_a[:, None, 1] <= boxes_b[None, :, 3])
        & (boxes_b[None, :, 1] <= boxes_a[:, None, 3])
    )
    if same:
        # Neighbouring chunks share a sample; a smooth curve cannot cross itself that soon.
        overlap &= chunks_b[None, :] >= chunks_a[:, None] + 2
    pair_a, pair_b = np.nonzero(overlap)
    chunks_a, chunks_b = chunks_a[pair_a], chunks_b[pair_b]
    if chunks_a.size == 0:
        return []
    offsets = np.arange(chunk)
    seg_a = (chunks_a[:, None, None] * chunk + offsets[None, :, None]).repeat(chunk, axis=2)
    seg_b = (chunks_b[:, None, None] * chunk + offsets[None, None, :]).repeat(chunk, axis=1)
    seg_a, seg_b = seg_a.ravel(), seg_b.ravel()
    valid = (seg_a < len(a.points) - 1) & (seg_b < len(b.points) - 1)
    seg_a, seg_b = seg_a[valid], seg_b[valid]

    start_a, start_b = a.points[seg_a], b.points[seg_b]
    dir_a, dir_b = a.points[seg_a + 1] - start_a, b.points[seg_b + 1] - start_b
    gap = start_b - start_a
    denominator = dir_a[:, 0] * dir_b[:, 1] - dir_a[:, 1] * dir_b[:, 0]
    parallel = np.abs(denominator) < 1e-12
    denominator = np.where(parallel, 1.0, denominator)
    t = (gap[:, 0] * dir_b[:, 1] - gap[:, 1] * dir_b[:, 0]) / denominator
    u = (gap[:, 0] * dir_a[:, 1] - gap[:, 1] * dir_a[:, 0]) / denominator
    hit = ~parallel & (t >= 0) & (t < 1) & (u >= 0) & (u < 1)

    length_a = np.linalg.norm(dir_a[hit], axis=1)
    length_b = np.linalg.norm(dir_b[hit], axis=1)
    where = start_a[hit] + t[hit, None] * dir_a[hit]
    arc_a = a.arc[seg_a[hit]] + t[hit] * length_a
    arc_b = b.arc[seg_b[hit]] + u[hit] * length_b
    sine = np.clip(np.abs(denominator[hit]) / (length_a * length_b), 0.0, 1.0)
    angle = np.arcsin(sine)
    order = np.argsort(arc_a)
    return [
        (float(where[i, 0]), float(where[i, 1]), float(arc_a[i]), float(arc_b[i]), float(angle[i]))
        for i in order
    ]


def _bounding_box(points):
    return np.concatenate([points.min(axis=0), points.max(axis=0)])


def _chunks_overlapping(chunk_boxes, box):
    """Indices of the chunk boxes that overlap ``box`` (both ``[x0, y0, x1, y1]``)."""
    return np.flatnonzero(
        (chunk_boxes[:, 0] <= box[2])
        & (chunk_boxes[:, 2] >= box[0])
        & (chunk_boxes[:, 1] <= box[3])
        & (chunk_boxes[:, 3] >= box[1])
    )


def _chunk_boxes(points, chunk):
    """Bounding boxes ``[x_min, y_min, x_max, y_max]`` of consecutive ``chunk`` segments."""
    low = np.minimum(points[:-1], points[1:])
    high = np.maximum(points[:-1], points[1:])
    n_chunks = -(-len(low) // chunk)
    pad = n_chunks * chunk - len(low)
    low = np.pad(low, ((0, pad), (0, 0)), mode="edge").reshape(n_chunks, chunk, 2).min(axis=1)
    high = np.pad(high, ((0, pad), (0, 0)), mode="edge").reshape(n_chunks, chunk, 2).max(axis=1)
    return np.hstack([low, high])
