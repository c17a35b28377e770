"""Layout rules: where a cable may lie so that the ground truth stays unambiguous.

Cables are drawn one at a time and resampled until they obey the rules: crossings at a
clear angle and spread out, cable ends clear of other cables, and no two cables (or two
parts of one) running close together except briefly at a crossing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from service.synthetic.curves import (
    _clip_to_box,
    _Crossing,
    _Curve,
    _fit_inside_box,
    _intersections,
    _random_centreline,
    _true_runs,
)
from service.synthetic.scene_types import SyntheticCrossing

# Detectors cannot be expected to untangle shallower crossings, so scenes never have them.
MIN_CROSSING_ANGLE = math.radians(30.0)

_CABLE_ATTEMPTS = 150


def _place_cables(rng, width, height, n_cables, radius_range, loops, margin):
    """Draw cables one at a time, resampling each until it obeys the layout rules."""
    if margin is None:
        box = (0.0, 0.0, width - 1.0, height - 1.0)
    else:
        box = (margin, margin, width - 1.0 - margin, height - 1.0 - margin)
    box_width, box_height = box[2] - box[0], box[3] - box[1]
    # Cables that may run off the image are grown around a point in the middle, so that
    # most of each stays in view.
    anchor_box = (
        box[0] + 0.2 * box_width,
        box[1] + 0.2 * box_height,
        box[2] - 0.2 * box_width,
        box[3] - 0.2 * box_height,
    )
    diagonal = math.hypot(width, height)

    curves: list[_Curve] = []
    crossings: list[_Crossing] = []
    for index in range(n_cables):
        for attempt in range(_CABLE_ATTEMPTS):
            radius = float(rng.uniform(*radius_range))
            # Shorter cables fit more easily; shrink them if the first tries keep failing.
            shrink = 1.0 - 0.5 * attempt / _CABLE_ATTEMPTS
            if margin is None:
                length = rng.uniform(0.6, 1.2) * diagonal * shrink
            else:
                length = rng.uniform(0.6, 1.2) * math.hypot(box_width, box_height) * shrink
            with_loop = loops and rng.random() < 0.5
            points, anchor_index = _random_centreline(rng, radius, length, diagonal, with_loop)
            if margin is None:
                points = points + rng.uniform(anchor_box[:2], anchor_box[2:])
                points = _clip_to_box(points, anchor_index, box)
            else:
                points = _fit_inside_box(rng, points, box)
            if points is None:
                continue
            curve = _Curve.from_points(points, radius)
            if curve.length < max(0.25 * min(box_width, box_height), 8.0 * radius):
                continue
            new_crossings = _crossings_if_well_placed(curve, index, curves, crossings)
            if new_crossings is not None:
                curves.append(curve)
                crossings.extend(new_crossings)
                break
        else:
            raise RuntimeError(
                f"could not place cable {index + 1} of {n_cables} in a {width}x{height} image "
                f"with radius_range={radius_range!r}; use fewer or thinner cables or a "
                "larger image"
            )
    return curves, crossings


# --------------------------------------------------------------------------- layout rules


@dataclass(frozen=True)
class _Exemption:
    """Stretches allowed to run close together: a designed feature of a scene family.

    The stretch ``own`` (arc range, px) of the cable being placed may run close to the
    stretch ``theirs`` of cable ``other`` (the same cable for a hairpin), as long as the two
    do not cross there: two cables lying side by side, or a cable doubled back on itself.
    """

    other: int
    own: tuple[float, float]
    theirs: tuple[float, float]

    def covers_own(self, arc):
        return (arc >= self.own[0]) & (arc <= self.own[1])

    def covers_theirs(self, arc):
        return (arc >= self.theirs[0]) & (arc <= self.theirs[1])


def _crossings_if_well_placed(
    curve, index, placed, existing_crossings, *, min_angle=MIN_CROSSING_ANGLE, exempt=()
):
    """Crossings the new curve adds, or None if it breaks a layout rule.

    The cheap rules (crossing angles and spacing, cable ends) are checked before the
    costlier search for stretches where two cables run close together. ``min_angle`` is
    the shallowest crossing allowed; ``exempt`` lists :class:`_Exemption` stretches that
    may run close together but must not cross.
    """
    radius = curve.radius
    # Beyond this arc distance two parts of one curve can only be near each other by coming
    # back (the curve bends no tighter than 4 radii).
    same_curve_window = 8.0 * radius

    self_crossings = [
        _Crossing(*hit[:2], index, index, *hit[2:], reach=radius)
        for hit in _intersections(curve, curve, same=True)
    ]
    pair_crossings = [
        [
            _Crossing(*hit[:2], index, other_index, *hit[2:], reach=max(radius, other.radius))
            for hit in _intersections(curve, other, same=False)
        ]
        for other_index, other in enumerate(placed)
    ]
    found = self_crossings + [crossing for pair in pair_crossings for crossing in pair]
    if any(crossing.angle < min_angle for crossing in found):
        return None
    if any(_crosses_in_exempt_stretch(c, exempt) for c in found):
        return None
    if not _crossings_spread_out(found, existing_crossings):
        return None

    # A cable end lying on a cable would look like a junction.
    for end_arc, end in ((0.0, curve.points[0]), (curve.length, curve.points[-1])):
        nearby = curve.tree.query_ball_point(end, 3.0 * radius)
        if np.any(np.abs(curve.arc[nearby] - end_arc) > same_curve_window):
            return None
    for other in placed:
        end_clearance = 3.0 * max(radius, other.radius)
        if np.min(other.tree.query(curve.points[[0, -1]])[0]) < end_clearance:
            return None
        if np.min(curve.tree.query(other.points[[0, -1]])[0]) < end_clearance:
            return None

    coarse = slice(None, None, 4)  # 2 px apart: plenty for measuring close stretches
    coarse_arc = curve.arc[coarse]
    clearance = 5.0 * radius
    pairs = cKDTree(curve.points[coarse]).query_pairs(clearance, output_type="ndarray")
    if len(pairs):
        pairs = pairs[np.abs(coarse_arc[pairs[:, 0]] - coarse_arc[pairs[:, 1]]) > same_curve_window]
    for exemption in exempt:
        if exemption.other == index and len(pairs):
            allowed = exemption.covers_own(coarse_arc[pairs[:, 0]])
            allowed &= exemption.covers_own(coarse_arc[pairs[:, 1]])
            pairs = pairs[~allowed]
    close = np.zeros(len(coarse_arc), dtype=bool)
    close[pairs.ravel()] = True
    events = [c.first_arc for c in self_crossings] + [c.second_arc for c in self_crossings]
    angles = [c.angle for c in self_crossings] * 2
    if not _close_stretches_ok(close, coarse_arc, events, angles, clearance, 6 * radius, min_angle):
        return None
    for other_index, (other, crossings) in enumerate(zip(placed, pair_crossings, strict=True)):
        radius_sum = radius + other.radius
        clearance = 2.5 * radius_sum
        angles = [c.angle for c in crossings]
        own_close = other.tree.query(curve.points[coarse], distance_upper_bound=clearance)[0]
        own_close = own_close < clearance
        other_close = curve.tree.query(other.points[coarse], distance_upper_bound=clearance)[0]
        other_close = other_close < clearance
        for exemption in exempt:
            if exemption.other == other_index:
                own_close &= ~exemption.covers_own(coarse_arc)
                other_close &= ~exemption.covers_theirs(other.arc[coarse])
        events = [c.first_arc for c in crossings]
        if not _close_stretches_ok(
            own_close, coarse_arc, events, angles, clearance, 3 * radius_sum, min_angle
        ):
            return None
        events = [c.second_arc for c in crossings]
        if not _close_stretches_ok(
            other_close, other.arc[coarse], events, angles, clearance, 3 * radius_sum, min_angle
        ):
            return None
    return found


def _crosses_in_exempt_stretch(crossing, exempt):
    """Whether a crossing lies in a stretch exempted for lying close (it must not)."""
    for exemption in exempt:
        if exemption.other != crossing.second:
            continue
        if exemption.covers_own(crossing.first_arc):
            return True
        if crossing.first == crossing.second:
            if exemption.covers_own(crossing.second_arc):
                return True
        elif exemption.covers_theirs(crossing.second_arc):
            return True
    return False


def _crossings_spread_out(new_crossings, existing_crossings):
    """Crossings closer than a few cable widths would merge into one tangle."""
    every = list(existing_crossings) + list(new_crossings)
    for position, crossing in enumerate(new_crossings, start=len(existing_crossings)):
        for other_position, other in enumerate(every):
            if other_position == position:
                continue
            distance = math.hypot(crossing.x - other.x, crossing.y - other.y)
            if distance < 6.0 * max(crossing.reach, other.reach):
                return False
    return True


def _close_stretches_ok(
    close, arc, event_arcs, event_angles, clearance, free_length, min_angle=MIN_CROSSING_ANGLE
):
    """Check every stretch of ``close`` samples against the length a crossing explains.

    A stretch with no crossing may be ``free_length`` long; one with a crossing at angle
    ``a`` may also span the ``2 * clearance / sin(a)`` that crossing lines stay close for;
    a stretch holding two crossings means the cables wind round each other.
    """
    event_arcs = np.asarray(event_arcs, dtype=float)
    event_angles = np.asarray(event_angles, dtype=float)
    step = arc[1] - arc[0] if len(arc) > 1 else 0.0
    for start, stop in zip(*_true_runs(close), strict=True):
        low, high = arc[start] - step, arc[stop - 1] + step
        inside = (event_arcs >= low) & (event_arcs <= high)
        stretch = arc[stop - 1] - arc[start]
        if np.count_nonzero(inside) > 1:
            return False
        allowed = free_length
        if np.any(inside):
            angle = max(float(event_angles[inside][0]), min_angle)
            allowed += 2.0 * clearance / math.sin(angle)
        if stretch > allowed:
            return False
    return True


def _public_crossing(crossing, depths):
    """Name the cable on top: higher depth, or the later part of a self-crossing loop."""
    first_on_top = (
        crossing.first_arc > crossing.second_arc
        if crossing.first == crossing.second
        else depths[crossing.first] > depths[crossing.second]
    )
    if first_on_top:
        over, under = crossing.first, crossing.second
        over_arc, under_arc = crossing.first_arc, crossing.second_arc
    else:
        over, under = crossing.second, crossing.first
        over_arc, under_arc = crossing.second_arc, crossing.first_arc
    return SyntheticCrossing(
        x=crossing.x,
        y=crossing.y,
        over=int(over),
        under=int(under),
        over_arc=over_arc,
        under_arc=under_arc,
    )
