"""Occluders of the scene families: rectangles and discs, on straight stretches, on bends
and at the picture's edge, coloured like the background or not.

Each hides one stretch of one cable, 3-15 cable radii long (the family's range), with
visible cable on both sides of it (so the hidden stretch can be inferred), clear of
crossings and of every other cable. An occluder may stick out of the picture when it is
placed at the edge.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from service.synthetic.curves import _true_runs
from service.synthetic.render import _Paint, _smooth_noise

_ATTEMPTS = 400
_DISC_SIDES = 32
# Where a cable passes under an occluder's side at a slant, part of its width shows for a
# while; it must go under at 40 degrees or steeper, so that stays short.
_MIN_ENTRY_ANGLE = math.radians(40.0)

# Objects that differ from every background (BGR): black, white, blue tape, red box,
# green lid, cardboard, grey metal, yellow.
_OBJECT_COLOURS = (
    (28, 28, 30),
    (236, 236, 234),
    (150, 80, 30),
    (45, 45, 185),
    (70, 150, 60),
    (95, 145, 190),
    (128, 128, 132),
    (60, 200, 220),
)


@dataclass(frozen=True)
class OccluderStyle:
    """How a family lays its occluders.

    Attributes
    ----------
    hidden_radii : (float, float)
        Length of the hidden stretch, in radii of the cable it hides.
    disc_share : float
        Share of discs (a roll of tape, a cup); the rest are rectangles.
    on_bend : float
        Share placed where the cable bends most (chosen with weight curvature squared).
    at_edge : float
        Share placed near a cable's end at the picture's edge, 3-10 radii of visible cable
        left between the occluder and the edge; these may stick out of the picture.
    like_background : float
        Share coloured like the background (a patch of the background itself, lifted);
        the rest are objects of a colour that differs from it.
    """

    hidden_radii: tuple[float, float] = (3.0, 15.0)
    disc_share: float = 0.4
    on_bend: float = 0.5
    at_edge: float = 0.0
    like_background: float = 0.5


@dataclass(frozen=True, eq=False)
class Polygon:
    """A convex polygon; a pixel is covered when its centre lies inside."""

    vertices: np.ndarray

    @classmethod
    def rectangle(cls, centre, angle, half_length, half_width) -> Polygon:
        along = np.array([math.cos(angle), math.sin(angle)])
        across = np.array([-along[1], along[0]])
        signs = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])
        return cls(
            centre + (signs[:, :1] * half_length) * along + (signs[:, 1:] * half_width) * across
        )

    @classmethod
    def disc(cls, centre, radius) -> Polygon:
        angles = np.arange(_DISC_SIDES) * (2.0 * math.pi / _DISC_SIDES)
        return cls(centre + radius * np.column_stack([np.cos(angles), np.sin(angles)]))

    def signed_distance(self, points) -> np.ndarray:
        """Largest signed distance to the edges' lines: <= 0 inside, and, inside, minus the
        distance to the border; outside, at most the distance to the polygon."""
        vertices = self.vertices
        edges = np.roll(vertices, -1, axis=0) - vertices
        # Outward normals whatever the vertex order.
        orientation = np.sign(
            np.sum(edges[:, 0] * np.roll(edges[:, 1], -1) - edges[:, 1] * np.roll(edges[:, 0], -1))
        )
        normals = orientation * np.column_stack([edges[:, 1], -edges[:, 0]])
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        offsets = np.einsum("ij,ij->i", normals, vertices)
        points = np.asarray(points, dtype=float).reshape(-1, 2)
        return (points @ normals.T - offsets[None, :]).max(axis=1)

    def contains(self, points, pad=0.0) -> np.ndarray:
        return self.signed_distance(points) <= pad

    @property
    def centre(self) -> np.ndarray:
        return self.vertices.mean(axis=0)

    @property
    def size(self) -> float:
        return float(np.linalg.norm(self.vertices - self.centre, axis=1).max())


@dataclass(frozen=True, eq=False)
class PlacedOccluder:
    polygon: Polygon
    target: int
    like_background: bool
    placement: str  # "anywhere", "bend" or "edge"


def place_family_occluders(rng, count, curves, crossings, width, height, style):
    """Lay ``count`` occluders; returns the list, or None if one could not be placed."""
    placed: list[PlacedOccluder] = []
    for _ in range(count):
        for _ in range(_ATTEMPTS):
            target = int(rng.integers(len(curves)))
            proposal = _propose(rng, curves[target], style, width, height)
            if proposal is None:
                continue
            polygon, placement = proposal
            if _fits(polygon, target, curves, crossings, placed, width, height, style, placement):
                like = bool(rng.random() < style.like_background)
                placed.append(PlacedOccluder(polygon, target, like, placement))
                break
        else:
            return None
    return placed


def _propose(rng, curve, style, width, height):
    radius = curve.radius
    hidden = rng.uniform(*style.hidden_radii) * radius
    draw = rng.random()
    if draw < style.at_edge:
        placement = "edge"
        ends = _ends_at_border(curve, width, height)
        if not ends:
            return None
        end_arc = ends[int(rng.integers(len(ends)))]
        visible = rng.uniform(3.5, 10.0) * radius
        centre_arc = visible + hidden / 2.0
        if end_arc > 0:
            centre_arc = curve.length - centre_arc
    else:
        reach = hidden / 2.0 + 5.0 * radius + 2.0
        if curve.length <= 2.0 * reach:
            return None
        if draw < style.at_edge + style.on_bend:
            placement = "bend"
            arcs = np.linspace(reach, curve.length - reach, 64)
            weights = _curvature_at(curve, arcs) ** 2
            if weights.sum() <= 0:
                return None
            centre_arc = float(rng.choice(arcs, p=weights / weights.sum()))
        else:
            placement = "anywhere"
            centre_arc = rng.uniform(reach, curve.length - reach)
    if not 0.0 < centre_arc < curve.length:
        return None
    index = int(np.searchsorted(curve.arc, centre_arc))
    behind, ahead = max(index - 4, 0), min(index + 4, len(curve.points) - 1)
    tangent = curve.points[ahead] - curve.points[behind]
    tangent = tangent / np.linalg.norm(tangent)
    normal = np.array([-tangent[1], tangent[0]])
    if rng.random() < style.disc_share:
        disc_radius = max(hidden / 2.0, 1.6 * radius)
        shift = rng.uniform(-0.3, 0.3) * (disc_radius - radius)
        return Polygon.disc(curve.points[index] + shift * normal, disc_radius), placement
    half_width = rng.uniform(1.5, 4.0) * radius
    tilt = rng.uniform(-0.25, 0.25)
    shift = rng.uniform(-0.3, 0.3) * (half_width - radius)
    angle = math.atan2(tangent[1], tangent[0]) + tilt
    polygon = Polygon.rectangle(
        curve.points[index] + shift * normal, angle, hidden / 2.0, half_width
    )
    return polygon, placement


def _ends_at_border(curve, width, height):
    """Arc positions (0 or the length) of the ends that lie on the picture's border."""
    ends = []
    for arc, (x, y) in ((0.0, curve.points[0]), (curve.length, curve.points[-1])):
        if min(x, y) < 0.5 or x > width - 1.5 or y > height - 1.5:
            ends.append(arc)
    return ends


def _curvature_at(curve, arcs):
    """Absolute curvature (1/px) at the given arc positions, over a few radii."""
    span = 2.0 * curve.radius
    result = np.zeros(len(arcs))
    for k, arc in enumerate(arcs):
        a, b, c = (
            curve.points[int(np.searchsorted(curve.arc, s))] for s in (arc - span, arc, arc + span)
        )
        cross = (b - a)[0] * (c - a)[1] - (b - a)[1] * (c - a)[0]
        lengths = np.linalg.norm(b - a) * np.linalg.norm(c - b) * np.linalg.norm(a - c)
        result[k] = 2.0 * abs(cross) / lengths if lengths > 0 else 0.0
    return result


def _fits(polygon, target, curves, crossings, placed, width, height, style, placement):
    """The layout rules of an occluder (see the module docstring)."""
    if placement != "edge":
        vertices = polygon.vertices
        if vertices.min() < 0 or np.any(vertices.max(axis=0) > [width - 1, height - 1]):
            return False
    for other in placed:
        distance = np.linalg.norm(polygon.centre - other.polygon.centre)
        if distance < polygon.size + other.polygon.size + 4.0:
            return False
    for crossing in crossings:
        if polygon.contains(np.array([[crossing.x, crossing.y]]), pad=3.0 * crossing.reach).any():
            return False
    for index, curve in enumerate(curves):
        if index != target:
            # Covering a second cable would cut it arbitrarily; keep occluders to one.
            if polygon.contains(curve.points, pad=curve.radius + 2.0).any():
                return False
            continue
        if not _hides_one_stretch_cleanly(polygon, curve, style):
            return False
    return True


def _hides_one_stretch_cleanly(polygon, curve, style):
    radius = curve.radius
    signed = polygon.signed_distance(curve.points)
    starts, _ = _true_runs(signed <= radius + 2.0)
    if len(starts) != 1:
        return False
    inside = np.flatnonzero(signed <= 0.0)
    if inside.size == 0:
        return False
    first_arc, last_arc = curve.arc[inside[0]], curve.arc[inside[-1]]
    # Visible cable on both sides, so the hidden stretch can be inferred.
    if first_arc < 3.0 * radius or last_arc > curve.length - 3.0 * radius:
        return False
    low, high = style.hidden_radii
    if not low * radius <= last_arc - first_arc <= high * radius:
        return False
    # Where the tube straddles the border, it must be close to where the centreline crosses
    # it: the cable goes under at a steep angle and does not peek out along a side.
    straddling = np.abs(signed) < radius
    near_entry = np.minimum(np.abs(curve.arc - first_arc), np.abs(curve.arc - last_arc))
    return not np.any(straddling & (near_entry > radius / math.sin(_MIN_ENTRY_ANGLE) + 2.0))


def draw_family_occluder(rng, labels, occluder, base):
    """Clear the labels under the occluder; return it painted, with a darker rim.

    Like the background: the background itself from elsewhere in the picture, slightly
    lighter or darker (a sheet of the same paper, a flap of the same cloth). Otherwise an
    object colour at least 80 grey levels (BGR distance) from the background under it.
    """
    height, width = labels.shape
    vertices = occluder.polygon.vertices
    x0, y0 = np.maximum(np.floor(vertices.min(axis=0)).astype(int), 0)
    x1 = min(math.ceil(vertices[:, 0].max()), width - 1)
    y1 = min(math.ceil(vertices[:, 1].max()), height - 1)
    rows, cols = np.mgrid[y0 : y1 + 1, x0 : x1 + 1]
    rows, cols = rows.ravel(), cols.ravel()
    depth = -occluder.polygon.signed_distance(np.column_stack([cols, rows]))
    inside = depth >= 0
    rows, cols, depth = rows[inside], cols[inside], depth[inside]
    texture = _smooth_noise(rng, x1 - x0 + 1, y1 - y0 + 1, 6.0)[rows - y0, cols - x0]
    below = base[rows, cols].mean(axis=0)
    if occluder.like_background:
        shift_x, shift_y = rng.uniform(60.0, 200.0, 2) * rng.choice([-1.0, 1.0], 2)
        source_rows = np.clip(np.rint(rows + shift_y).astype(int), 0, height - 1)
        source_cols = np.clip(np.rint(cols + shift_x).astype(int), 0, width - 1)
        colour = base[source_rows, source_cols] * rng.uniform(0.92, 1.06)
        colour = colour + 2.0 * texture[:, None]
    else:
        choices = [c for c in _OBJECT_COLOURS if np.linalg.norm(np.subtract(c, below)) >= 80.0]
        choice = np.array(choices[int(rng.integers(len(choices)))], dtype=float)
        colour = choice[None, :] * (1.0 + 0.03 * texture[:, None]) + rng.integers(-8, 9, 3)
    # A slightly darker rim makes it read as an object rather than a hole in the image.
    rim = 0.8 + 0.2 * np.clip(depth / 2.0, 0.0, 1.0)
    labels[rows, cols] = 0
    return _Paint(rows, cols, np.clip(colour * rim[:, None], 0, 255).astype(np.float32))
