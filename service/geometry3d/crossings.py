"""Crossings in 3-D: which joints of the lower strand the upper one hides, and the upper
strand raised to lie on the lower one.

A strand seen on top of another lies on it, its centreline the sum of the two radii above
the lower one's. On a plane surface both would be lifted to the table, so the upper strand
is raised there: by that much at the crossing and less with distance along it (a
cosine-squared bump :data:`BUMP_HALF_LENGTH` ``(r_over + r_under) / sin(angle)`` long on
each side, the angle being the crossing's in the image, at most doubled for shallow
crossings), each joint along its own ray towards the camera, so that it is still seen where
it was. With a depth image the upper strand is measured there already and needs no raising.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from schemas import Chain, Detection

BUMP_HALF_LENGTH = 3.0
"""Half length of the raised stretch, in sums of the two radii (when crossing at right angles)."""

MIN_SINE = 0.5
"""Shallower crossings are raised over the length of a 30-degree one."""

MIN_RAISE_M = 1e-4
"""An upper strand already this close to lying on the lower one is left as it is."""

STEEP_RAY = -0.3
"""Joints whose ray's base ``z`` component is below this are raised along the ray; others
(rays nearly parallel to the table) straight up."""

NEAR_SEGMENTS = 5
"""Joints of the lower strand this many segments either side of a crossing are checked."""


def hidden_at_crossings(detection: Detection) -> Iterator[tuple[int, np.ndarray]]:
    """Per crossing, the lower strand's index and which of its joints the upper one covers.

    Covered: within the upper strand's pixel radius and one pixel of its centreline (near
    the crossing): a depth image sees the upper strand there, not the lower one.
    """
    index_of = {chain.id: index for index, chain in enumerate(detection.chains)}
    for crossing in detection.crossings:
        if crossing.over not in index_of or crossing.under not in index_of:
            continue
        over = detection.chains[index_of[crossing.over]]
        under = detection.chains[index_of[crossing.under]]
        low = max(crossing.under_segment - NEAR_SEGMENTS + 1, 0)
        high = min(crossing.under_segment + NEAR_SEGMENTS + 1, len(under.points))
        first = max(crossing.over_segment - NEAR_SEGMENTS + 1, 0)
        band = np.asarray(over.points[first : crossing.over_segment + NEAR_SEGMENTS + 1], float)
        joints = np.asarray(under.points[low:high], dtype=float)
        if len(band) < 2 or len(joints) == 0:
            continue
        covered = np.zeros(len(under.points), dtype=bool)
        covered[low:high] = _distances_to_polyline(joints, band) <= over.radius + 1.0
        yield index_of[crossing.under], covered


def raise_upper_strands(
    detection: Detection,
    points: np.ndarray,
    radii: np.ndarray,
    starts: np.ndarray,
    units: np.ndarray,
) -> np.ndarray:
    """The joints' points (``(M, 3)``, chain after chain from ``starts``) with every upper
    strand lying on the lower one at its crossings.

    ``radii`` are the chains' radii in metres (NaN unknown) and ``units`` the joints' unit
    rays.
    """
    index_of = {chain.id: index for index, chain in enumerate(detection.chains)}
    raises = np.zeros(len(points))
    for crossing in detection.crossings:
        over, under = index_of.get(crossing.over), index_of.get(crossing.under)
        if over is None or under is None or np.isnan(radii[over]) or np.isnan(radii[under]):
            continue
        pixel = np.array([crossing.x, crossing.y])
        over_points = points[starts[over] : starts[over + 1]]
        under_points = points[starts[under] : starts[under + 1]]
        over_at = _point_at(detection.chains[over], over_points, crossing.over_segment, pixel)
        under_at = _point_at(detection.chains[under], under_points, crossing.under_segment, pixel)
        if over_at is None or under_at is None:
            continue
        over_point, fraction, over_direction = over_at
        under_point, _, under_direction = under_at
        needed = under_point[2] + radii[over] + radii[under] - over_point[2]
        if not needed > MIN_RAISE_M:
            continue
        sine = abs(over_direction[0] * under_direction[1] - over_direction[1] * under_direction[0])
        half = BUMP_HALF_LENGTH * (radii[over] + radii[under]) / max(sine, MIN_SINE)
        along = _arc_lengths(over_points)
        segment = crossing.over_segment
        at = along[segment] + fraction * (along[segment + 1] - along[segment])
        distance = np.abs(along - at)
        bump = np.where(distance < half, needed * np.cos(np.pi * distance / (2 * half)) ** 2, 0.0)
        chain = slice(starts[over], starts[over + 1])
        raises[chain] = np.maximum(raises[chain], bump)
    if not raises.any():
        return points
    steep = units[:, 2] < STEEP_RAY
    steps = np.tile((0.0, 0.0, 1.0), (len(points), 1))
    steps[steep] = -units[steep] / -units[steep, 2:3]  # unit height along the ray
    return points + raises[:, None] * steps


def _point_at(chain: Chain, points: np.ndarray, segment: int, pixel: np.ndarray):
    """The 3-D point of ``chain`` at the image point nearest ``pixel`` on ``segment``.

    Returns ``(point, fraction along the segment, unit image direction of the segment)``,
    or None when the segment does not exist or an end of it was not located.
    """
    if not 0 <= segment < len(chain.points) - 1:
        return None
    start, end = np.asarray(chain.points[segment]), np.asarray(chain.points[segment + 1])
    step = end - start
    length = float(np.hypot(*step))
    if length == 0 or not np.isfinite(points[segment : segment + 2]).all():
        return None
    fraction = float(np.clip(np.dot(pixel - start, step) / length**2, 0.0, 1.0))
    point = points[segment] + fraction * (points[segment + 1] - points[segment])
    return point, fraction, step / length


def _arc_lengths(points: np.ndarray) -> np.ndarray:
    """Cumulative 3-D arc length along a chain (segments with an unknown end count as 0)."""
    steps = np.linalg.norm(np.diff(points, axis=0), axis=1)
    return np.concatenate(([0.0], np.cumsum(np.where(np.isfinite(steps), steps, 0.0))))


def _distances_to_polyline(queries: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    """Distance from each query point to a polyline (pixels)."""
    starts, ends = polyline[:-1], polyline[1:]
    directions = ends - starts
    squared = np.einsum("ij,ij->i", directions, directions)
    offsets = queries[:, None, :] - starts[None, :, :]
    t = np.einsum("qsj,sj->qs", offsets, directions) / np.where(squared > 0, squared, 1.0)
    t = np.clip(np.where(squared > 0, t, 0.0), 0.0, 1.0)
    closest = starts[None] + t[..., None] * directions[None]
    return np.linalg.norm(queries[:, None, :] - closest, axis=2).min(axis=1)
