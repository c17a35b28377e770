"""Occluders: objects laid across the cables, hiding a stretch of one of them."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from service.synthetic.curves import _true_runs
from service.synthetic.render import _Paint, _smooth_noise

_OCCLUDER_ATTEMPTS = 300


@dataclass(frozen=True)
class _Rect:
    """A rotated rectangle: centre, direction of its length, and half sizes."""

    centre: np.ndarray
    angle: float
    half_length: float
    half_width: float

    def local(self, points):
        """Coordinates along the length (u) and across it (v)."""
        along = np.array([math.cos(self.angle), math.sin(self.angle)])
        across = np.array([-along[1], along[0]])
        offset = np.asarray(points, dtype=float) - self.centre
        return offset @ along, offset @ across

    def contains(self, points, pad=0.0):
        u, v = self.local(points)
        return (np.abs(u) <= self.half_length + pad) & (np.abs(v) <= self.half_width + pad)

    def corners(self):
        signs = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])
        along = np.array([math.cos(self.angle), math.sin(self.angle)])
        across = np.array([-along[1], along[0]])
        return (
            self.centre
            + (signs[:, :1] * self.half_length) * along
            + (signs[:, 1:] * self.half_width) * across
        )


def _place_occluders(rng, count, curves, crossings, width, height):
    rects: list[_Rect] = []
    for number in range(count):
        for _ in range(_OCCLUDER_ATTEMPTS):
            target = int(rng.integers(len(curves)))
            rect = _propose_occluder(rng, curves[target])
            if rect is not None and _occluder_fits(
                rect, target, curves, crossings, rects, width, height
            ):
                rects.append(rect)
                break
        else:
            raise RuntimeError(
                f"could not place occluder {number + 1} of {count} across a cable without "
                "covering a crossing or a cable end; use fewer occluders or more cables"
            )
    return rects


def _propose_occluder(rng, curve):
    """A rectangle laid across ``curve``, hiding a 20-80 px stretch of it."""
    radius = curve.radius
    half_length = rng.uniform(20.0, 80.0) / 2.0
    half_width = rng.uniform(3.0, 10.0) * radius / 2.0
    # The hidden stretch, its padding and 3 radii on both sides must fit inside the cable.
    reach = half_length + 2.0 * radius + 2.0 + 3.0 * radius
    if curve.length <= 2.0 * reach:
        return None
    centre_arc = rng.uniform(reach, curve.length - reach)
    index = int(np.searchsorted(curve.arc, centre_arc))
    behind, ahead = max(index - 4, 0), min(index + 4, len(curve.points) - 1)
    tangent = curve.points[ahead] - curve.points[behind]
    # Tilt and shift only as far as the rectangle still covers the cable's whole width.
    slack = half_width - radius
    max_tilt = 0.8 * math.atan2(slack, half_length + radius)
    angle = math.atan2(tangent[1], tangent[0]) + rng.uniform(-max_tilt, max_tilt)
    normal = np.array([-tangent[1], tangent[0]]) / np.linalg.norm(tangent)
    centre = curve.points[index] + rng.uniform(-0.3, 0.3) * slack * normal
    return _Rect(centre=centre, angle=angle, half_length=half_length, half_width=half_width)


def _occluder_fits(rect, target, curves, crossings, rects, width, height):
    corners = rect.corners()
    if corners.min() < 0 or np.any(corners.max(axis=0) > [width - 1, height - 1]):
        return False
    size = math.hypot(rect.half_length, rect.half_width)
    for other in rects:
        other_size = math.hypot(other.half_length, other.half_width)
        if np.linalg.norm(rect.centre - other.centre) < size + other_size + 4.0:
            return False
    for crossing in crossings:
        if rect.contains([crossing.x, crossing.y], pad=3.0 * crossing.reach):
            return False
    for index, curve in enumerate(curves):
        radius = curve.radius
        near = rect.contains(curve.points, pad=radius + 2.0)
        if index != target:
            # Covering a second cable would cut it arbitrarily; keep occluders to one.
            if np.any(near):
                return False
            continue
        starts, stops = _true_runs(near)
        if len(starts) != 1:
            return False
        first_arc, last_arc = curve.arc[starts[0]], curve.arc[stops[0] - 1]
        if first_arc < 3.0 * radius or last_arc > curve.length - 3.0 * radius:
            return False
        # Wherever the cable is level with the rectangle it must be covered across its whole
        # width, so it disappears at the short sides instead of peeking out along the long.
        u, v = rect.local(curve.points)
        level = near & (np.abs(u) <= rect.half_length + radius)
        if np.any(np.abs(v[level]) > rect.half_width - radius):
            return False
        if not np.any(rect.contains(curve.points)):
            return False
    return True


def _hidden_samples(points, shapes):
    """Which centreline samples lie under one of the occluders' shapes."""
    hidden = np.zeros(len(points), dtype=bool)
    for shape in shapes:
        hidden |= shape.contains(points)
    return hidden


def _draw_occluder(rng, labels, rect, background_level):
    """Clear the labels under the rectangle and return it painted dull, textured grey."""
    height, width = labels.shape
    corners = rect.corners()
    x0, y0 = np.maximum(np.floor(corners.min(axis=0)).astype(int), 0)
    x1 = min(math.ceil(corners[:, 0].max()), width - 1)
    y1 = min(math.ceil(corners[:, 1].max()), height - 1)
    rows, cols = np.mgrid[y0 : y1 + 1, x0 : x1 + 1]
    u, v = rect.local(np.column_stack([cols.ravel(), rows.ravel()]))
    inside = (np.abs(u) <= rect.half_length) & (np.abs(v) <= rect.half_width)
    rows, cols, u, v = rows.ravel()[inside], cols.ravel()[inside], u[inside], v[inside]

    grey = np.clip(background_level + rng.uniform(-8.0, 12.0), 35.0, 90.0)
    texture = _smooth_noise(rng, x1 - x0 + 1, y1 - y0 + 1, 6.0)[rows - y0, cols - x0]
    # A slightly darker rim makes it read as an object rather than a hole in the image.
    rim = np.minimum(rect.half_length - np.abs(u), rect.half_width - np.abs(v))
    value = (grey + 4.0 * texture) * (0.8 + 0.2 * np.clip(rim / 2.0, 0.0, 1.0))
    tint = 1.0 + rng.uniform(-0.05, 0.05, 3)
    labels[rows, cols] = 0
    return _Paint(rows, cols, (value[:, None] * tint[None, :]).astype(np.float32))
