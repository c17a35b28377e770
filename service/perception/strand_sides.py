"""Which side of a touching stretch each strand keeps (step 6, issue 13).

Shared by :mod:`.touching` (a line between two junctions, or a junction of four ends)
and :mod:`.touching_ends` (a line from a junction to where an object cuts it off):
strands that touch all along cannot cross, so the strand on the left where they meet
is the one on the left where they part, and each strand of the stretch is the line
moved to its own side.
"""

from __future__ import annotations

import numpy as np

from service.perception.geometry import arc_lengths, points_along

# Two strands lie side by side along a piece when its mask never narrows below this
# fraction of their two widths together: where two cables cross, even at a shallow
# angle, the mask narrows to one cable's width (half of the two), while strands that
# touch all along keep both widths (all of it).
SIDE_BY_SIDE_WIDTH_FRACTION = 0.75


def short_strand(other, lengths, stretch_width, leaving) -> bool:
    """Whether the strand ending at ``other`` (an end; ``lengths`` by piece) is shorter
    than the stretch is wide (``stretch_width``) and does not leave the picture: an
    object cuts it a little past the junction, and the median of its few joints falls in
    its cut's narrowing tip, so its width is read as the widest its mask gets."""
    return lengths[other // 2] < stretch_width and (leaving is None or not leaving[other ^ 1])


def end_kind(end, index, labels, members, positions, directions, pieces, reach):
    """What one end of piece ``index`` meets: the two other strands of a three-way
    junction, left one first; or None (anything else).

    The sides are read on the other strands clear of the junction, at the points
    ``reach`` (the stretch's half width) along them, as :mod:`.touching` reads a
    junction of four ends: thinning bends the strands' tips toward each other where they
    meet, and the ends' fits, extrapolated over those tips, may swap them (the two ends
    of the bulb a doubled-back cable turns round through, which thinning starts together
    at the junction, each bending toward the other's side). Where those points do not
    tell (both on one side of the end's line), from where the other strands' ends lie.
    """
    label = labels[end]
    others = [member for member in members[label] if member // 2 != index]
    if len(members[label]) != 3 or len(others) != 2:
        return None
    heading = -directions[end] if end % 2 == 0 else directions[end]
    offsets = side_offsets(
        heading, positions[end], [point_in(pieces, other, reach) for other in others]
    )
    if offsets[0] * offsets[1] >= 0:
        at_tips = side_offsets(heading, positions[end], [positions[other] for other in others])
        if at_tips[0] * at_tips[1] < 0:
            return others if at_tips[0] < 0 else others[::-1]
        # Both on one side of the end's line: on a stretch bending into the junction
        # the end's fit lags the bend and tilts that line. Two strands parting side by
        # side still lie a strand's width apart across it (the stretch's half width,
        # ``reach``); the one further left is on the left.
        if abs(offsets[0] - offsets[1]) < 0.5 * reach:
            return None
        return others if offsets[0] < offsets[1] else others[::-1]
    return others if offsets[0] < 0 else others[::-1]


def side_offsets(heading, origin, points) -> list[float]:
    """Signed offsets of ``points`` from the line through ``origin`` along ``heading``
    (negative: on its left)."""
    return [
        float(heading[0] * (point[1] - origin[1])) - float(heading[1] * (point[0] - origin[0]))
        for point in points
    ]


def point_in(pieces, end, reach: float) -> np.ndarray:
    """The point ``reach`` along piece ``end // 2`` from that end (at most half the piece)."""
    points = np.asarray(pieces[end // 2], np.float64)
    if end % 2:
        points = points[::-1]
    along = arc_lengths(points)
    at = min(reach, 0.5 * float(along[-1]))
    return points_along(points, along, np.array([at]))[0]


def offset_strands(points: np.ndarray, half_width: float) -> tuple[np.ndarray, np.ndarray]:
    """The piece's line moved half its half width to the left and to the right (the
    sides :func:`end_kind` orders by)."""
    points = np.asarray(points, np.float64)
    tangents = np.gradient(points, axis=0)
    tangents /= np.maximum(np.hypot(tangents[:, 0], tangents[:, 1]), 1e-9)[:, None]
    left = np.column_stack([tangents[:, 1], -tangents[:, 0]])
    shift = 0.5 * max(half_width - 0.5, 0.0)
    return points + shift * left, points - shift * left
