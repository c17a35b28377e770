"""How wide a cable mask is along a piece and across a four-way junction's middle.

The readings of the distance transform that tell two cables crossing from two strands
touching side by side (:mod:`service.perception.touching`): at a crossing the mask is
narrowest at the X's middle and widens again on both sides; where strands touch it keeps
two strands' width, and where they part it narrows from the notch between them inwards.
"""

from __future__ import annotations

import math

import numpy as np

from service.perception.geometry import arc_lengths, points_along


def distance_at(xs: np.ndarray, ys: np.ndarray, distance: np.ndarray) -> np.ndarray:
    """The distance transform at the pixel nearest each point (clipped to the picture)."""
    height, width = distance.shape
    # np.clip's values on integers, without its checks (read at every four-way junction).
    cols = np.minimum(np.maximum(np.rint(xs).astype(int), 0), width - 1)
    rows = np.minimum(np.maximum(np.rint(ys).astype(int), 0), height - 1)
    return distance[rows, cols]


def widest(points: np.ndarray, distance: np.ndarray) -> float:
    """The largest distance transform along the piece, at every pixel of its line."""
    points = np.asarray(points, np.float64)
    along = arc_lengths(points)
    xs, ys = points_along(points, along, np.arange(0.0, along[-1] + 1e-9, 1.0)).T
    return float(distance_at(xs, ys, distance).max())


# Where two strands cross at angle theta, the middle of the crossing lies r / cos(theta / 2)
# from the background, sqrt(2) r at most (a right angle; past it the other angle is the
# acute one): sqrt(1/2) of the two strands' widths together, against all of it where
# they touch side by side. A four-way junction's middle is held to halfway between.
TOUCHING_MIDDLE_FRACTION = 0.5 * (1.0 + math.sqrt(0.5))


def widest_between(start: np.ndarray, end: np.ndarray, distance: np.ndarray) -> float:
    """The largest distance transform on the middle third of the line from ``start`` to
    ``end`` (every pixel of it; the middle pixel when shorter): the crossing's middle,
    the point of an X farthest from the background, or the touching stretch's width,
    read where a pixel's rounding off the middle does not lose it."""
    length = float(np.hypot(*(end - start)))
    if length >= 3.0:
        along = np.arange(length / 3.0, 2.0 * length / 3.0 + 1e-9, 1.0)
    else:
        along = np.array([0.5 * length])
    points = start + along[:, None] * ((end - start) / max(length, 1e-9))
    return float(distance_at(points[:, 0], points[:, 1], distance).max())


def middle_of_stretch(length: float, strands: float) -> float:
    """How far clear of each end (px) the width of a stretch ``length`` px long between
    a four-way junction's two pairs of ends is read (:func:`.touching._touching_junction_pairs`):
    a third of its length, and at least the two strands' half widths together
    (``strands``).

    The line runs from between one pair's ends to between the other's: at a bulb's two
    ends it starts in the bulb's hole, and where the strands part it ends in the notch
    between them, which narrows the mask over a few radii when they part at a shallow
    angle (2.7 radii at 20 degrees), whether the strands touch or cross. Where two
    cables cross, the mask is narrowest at the crossing, the middle of the line."""
    return max(strands, length / 3.0)


def narrows_between_shoulders(
    line: np.ndarray, distance: np.ndarray, clear: float, level: float, touch: float
) -> bool:
    """Whether the mask along ``line`` (from between one pair of a four-way junction's
    ends to between the other's) narrows below ``level`` on its middle, ``clear`` px
    clear of each end, as a crossing does, not as touching strands parting.

    Where two cables cross, the mask is narrowest at the crossing and widens again on
    both sides of it, where the strands lie side by side before they part; at a wide
    angle it is as wide as ``level`` only for a pixel or two round the X's middle. Where
    two touching strands part at a shallow angle, the notch between them narrows the
    mask from the stretch's end inwards, over more than the ends' clearance when they
    part slowly (a doubled-back cable's bulb opening from its neck, doubled_back 400158,
    400267). So the narrowing is the parting's when the mask keeps ``level`` along a
    stretch at least ``touch`` px long (the strands touching over a cable's width) and
    the narrowest reading is not between two wider places: the mask narrows on towards
    that end and never widens again. Wider means by more than a pixel, the distance
    transform's own step (readings a pixel apart differ by up to ~0.7 px).

    Parameters
    ----------
    line : ndarray
        ``(2, 2)`` the line's two ends.
    distance : ndarray
        Distance transform of the mask.
    clear : float
        How far from each end the narrowing is looked for (px).
    level : float
        The width (distance transform) under which the mask narrows.
    touch : float
        How long (px) the mask must keep ``level`` for the strands to touch.

    Returns
    -------
    bool
        True also when the line is too short to leave a middle (as :func:`narrowest`
        reads 0 there).
    """
    points = np.asarray(line, np.float64)
    length = float(np.hypot(*(points[1] - points[0])))
    if length <= 2 * clear:
        return True
    # The middle sampled as :func:`narrowest` samples it, the rest a pixel apart.
    middle_along = np.arange(clear, length - clear + 1e-9, 1.0)
    if not len(middle_along):
        return True
    before = np.arange(0.0, clear, 1.0)
    after = np.arange(middle_along[-1] + 1.0, length + 1e-9, 1.0)
    along = np.concatenate([before, middle_along, after])
    middle = np.zeros(len(along), bool)
    middle[len(before) : len(before) + len(middle_along)] = True
    samples = points[0] + along[:, None] * ((points[1] - points[0]) / length)
    widths = distance_at(samples[:, 0], samples[:, 1], distance).astype(np.float64)
    at = int(np.flatnonzero(middle)[np.argmin(widths[middle])])
    narrowest = widths[at]
    if narrowest >= level:
        return False
    # The longest run of readings keeping the level: the stretch the strands touch along.
    keeps = np.concatenate([[False], widths >= level, [False]])
    starts, stops = np.flatnonzero(~keeps[:-1] & keeps[1:]), np.flatnonzero(keeps[:-1] & ~keeps[1:])
    if not len(starts) or float((along[stops - 1] - along[starts]).max()) < touch:
        return True
    wider = narrowest + 1.0
    return bool(widths[:at].max(initial=0.0) > wider and widths[at + 1 :].max(initial=0.0) > wider)


def narrowest(
    points: np.ndarray, distance: np.ndarray, half_width: float, short_at_middle: bool = False
) -> float:
    """The least distance transform along the piece (every pixel of it) half its width
    clear of its ends; 0 when nothing is left, or with ``short_at_middle`` the distance
    at the middle of a piece that short. (Where two cables cross, the middle of what
    they share is where they cross, the narrowest.)"""
    points = np.asarray(points, np.float64)
    along = arc_lengths(points)
    if along[-1] <= 2 * half_width:
        if not short_at_middle or along[-1] <= 0:
            return 0.0
        half_width = 0.5 * float(along[-1])
    samples = np.arange(half_width, along[-1] - half_width + 1e-9, 1.0)
    xs, ys = points_along(points, along, samples).T
    return float(distance_at(xs, ys, distance).min())
