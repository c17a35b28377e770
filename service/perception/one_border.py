"""A doubled-back cable's two strands cut by one straight border: an object's edge.

Where a rectangle lies over a cable's turn, one of its straight edges crosses both
strands as they run in under it, and the turn lies out of sight beyond that edge. Of
an object of the ground's own colour nothing else shows. The turn pass's tests of the
cuts (:func:`.gap_evidence.cut_ends_alike`, :mod:`.traced_cuts`) read each end's front
along its own axis: where a strand bends into the turn right at the edge, its front,
read along the bend or along the line from its fit, bulges as a cable's own round tip
does, and no test passes. Read across the line through the two cuts instead (the edge
itself), that strand's front is as straight as the other's: both strands stop on one
straight line, each cut straight across it. A cable's own tip is round read along any
line; two cables that merely end side by side would have to stop, each straight
across, on one line through both.

:func:`one_border_test` gives the turn pass that test, after the tests of the cuts.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from service.perception.appearance import (
    CUT_AHEAD_RADII,
    CUT_BULGE_SHARE,
    CUT_PROBE_SHARE,
    _front,
    _front_reading,
    cut_square,
)
from service.perception.gap_evidence import alike_and_short_enough_to_hide


def _front_points(mask, centre, along, outward, half_width, count) -> np.ndarray | None:
    """Where the foreground stops on three lines along unit ``outward`` from ``centre``
    and from :data:`.appearance.CUT_PROBE_SHARE` of ``half_width`` to either side of it
    along unit ``along`` (``(3, 2)`` points, px); None where any line starts off the
    mask or runs on past ``count`` half-pixel steps."""
    points = []
    for share in (-CUT_PROBE_SHARE, 0.0, CUT_PROBE_SHARE):
        start = centre + share * half_width * along
        ahead = _front(mask, start, outward, count)
        if np.isnan(ahead):
            return None
        points.append(start + ahead * outward)
    return np.array(points)


def _outward_normal(along: np.ndarray, heading: np.ndarray) -> np.ndarray:
    """The unit normal of a line along unit ``along`` on the side ``heading`` points to."""
    normal = np.array([-along[1], along[0]])
    return normal if float(normal @ heading) >= 0.0 else -normal


def _straight_across(points: np.ndarray, outward: np.ndarray, half_width: float) -> bool:
    """Whether a front's three points (:func:`_front_points`) lie on one line across
    ``outward``: the sides level with each other and the middle neither ahead of their
    mean nor behind it by more than a cut's bulge (:data:`.appearance.CUT_BULGE_SHARE`
    of the half width; a round tip's middle runs 0.29 of it ahead)."""
    reach = (points @ outward) / half_width
    level = abs(reach[0] - reach[2]) <= 2.0 * CUT_BULGE_SHARE
    flat = abs(reach[1] - 0.5 * (reach[0] + reach[2])) <= CUT_BULGE_SHARE
    return bool(level and flat)


def cut_along_one_border(mask: np.ndarray, square_end, other_end) -> bool:
    """Whether two chain ends (:class:`.merging.ChainEnd`), ``square_end`` cut square
    along its own axis (:func:`.appearance.cut_square`), stop on one straight line,
    each cut straight across it (the module's docstring).

    The square end's cut gives the line's direction first (its front's two sides); the
    other end's front, read across that line from its own cross-section, gives a point
    on its cut; the line through the two fronts' middles is the border, and each front
    read across it must be straight (:func:`_straight_across`), both ends leaving on
    its one side. The fronts are read as :func:`.appearance.end_front` reads them: from
    the cable's cross-section just behind the front (its middle and half width)."""
    readings = []
    for end in (square_end, other_end):
        reading = _front_reading(mask, end.position, end.direction, end.width, end.skip)
        if reading is None:
            return False
        _, centre, axis, local, _, _ = reading
        count = int(np.ceil(2.0 * (CUT_AHEAD_RADII + 2.0) * local)) + 1
        readings.append((centre, axis, local, count))
    (square_centre, square_axis, square_width, square_count), other = readings
    across = np.array([-square_axis[1], square_axis[0]])
    square_front = _front_points(
        mask, square_centre, across, square_axis, square_width, square_count
    )
    if square_front is None:
        return False
    side = square_front[2] - square_front[0]
    along = side / max(float(np.hypot(*side)), 1e-9)
    outward = _outward_normal(along, square_axis)
    other_front = _front_points(mask, other[0], along, outward, other[2], other[3])
    if other_front is None:
        return False
    chord = other_front[1] - square_front[1]
    span = float(np.hypot(*chord))
    if span <= 0.0:
        return False
    along = chord / span
    outward = _outward_normal(along, square_axis)
    if float(outward @ other[1]) <= 0.0:
        return False  # the two strands leave the line on its two sides: no one border
    for centre, _, local, count in readings:
        front = _front_points(mask, centre, along, outward, local, count)
        if front is None or not _straight_across(front, outward, local):
            return False
    return True


def one_border_test(
    ends, readings: Callable[[int], tuple], mask, colours, radius, image
) -> Callable[[int, int, np.ndarray], bool]:
    """The turn pass's test (:func:`.turn_joins.turn_joins`' ``evidence``, a callable
    ``(i, j, curve)``) that one end is cut square, at its fit or at its traced cut (the
    end's ``readings(index)``, :func:`.traced_cuts.ends_at_the_cuts`), the two ends stop
    on one straight border, each cut straight across it, read at either reading of
    the other (:func:`cut_along_one_border`), and they are alike and the curve no longer
    than an object of the ground's own colour hides
    (:func:`.gap_evidence.alike_and_short_enough_to_hide`, read at the traced cuts).
    What depends on the two ends alone is read once per pair."""
    square: dict[int, list] = {}
    bordered: dict[tuple[int, int], bool] = {}

    def squares(index: int) -> list:
        # The end's readings that are cut square, once per end.
        if index not in square:
            square[index] = [
                end
                for end in readings(index)
                if cut_square(mask, end.position, end.direction, end.width, end.skip)
            ]
        return square[index]

    def on_one_border(i: int, j: int) -> bool:
        if (i, j) not in bordered:
            bordered[i, j] = any(
                cut_along_one_border(mask, cut, other)
                for first, second in ((i, j), (j, i))
                for cut in squares(first)
                for other in readings(second)
            )
        return bordered[i, j]

    def passes(i: int, j: int, curve: np.ndarray) -> bool:
        if not (squares(i) or squares(j)) or not on_one_border(i, j):
            return False
        first, second = readings(i)[-1], readings(j)[-1]
        return alike_and_short_enough_to_hide(
            first, second, i, j, curve, mask, colours, radius, image
        )

    return passes
