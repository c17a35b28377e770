"""Where a short piece's bridge leaves it: the middle of the cable at the cut.

A piece shorter than the end fit's span (a stretch of cable seen between two objects, or
between an object and a crossing) has no fit to start its bridges from: they start at
its skeleton's tips (:func:`.bridge_ends.ends_through_short_pieces` only turns them). An
object's border cuts the cable at a slant, and thinning runs the skeleton's tip into the
cut's far corner, on the cable's border: up to a half width off its middle line. The
bridge drawn from that corner runs a half width beside the hidden stretch all the way to
the other end, and on a cable as wide as the tolerance that misses it.

The cable's middle line is still where the mask says: halfway between its two borders.
:func:`short_ends_at_cut_middles` reads a cross-section of the piece that is the cable's
own width (both borders the cable's, clear of the cuts), takes its middle, and traces the
middle line on from there along the end's direction to where the cut begins
(:func:`.cut_ends.middle_line`): the bridge starts there, at the cut's middle, in the
direction the end already had.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from service.perception.cut_ends import (
    REACH_PAST_SKIP_RADII,
    SECTION_STEP_PX,
    _border_distance,
    middle_line,
)
from service.perception.geometry import polyline_length, unit

OWN_SECTION_PX = 2.0
"""A cross-section is the cable's own (both borders the cable's, no cut on either side)
when its width is the cable's full width to within this (px: a pixel's rounding at
either border)."""


def section_middle(
    mask: np.ndarray, point: np.ndarray, heading: np.ndarray, half_width: float
) -> np.ndarray | None:
    """The middle of the cross-section of ``mask`` through ``point`` across ``heading``
    (unit), where it is the cable's own: as wide as the cable (``2 half_width``) to
    within :data:`OWN_SECTION_PX`; None where it is narrower (a cut, another object's
    border) or wider (another strand), or ``point`` is off the mask.

    Examples
    --------
    >>> import numpy as np

    A band of rows 6-13 (middle 9.5), read at quarter pixels from a point near its edge:

    >>> band = np.zeros((20, 20), bool); band[6:14] = True
    >>> section_middle(band, np.array([5.0, 12.0]), np.array([1.0, 0.0]), 4.0).round(1).tolist()
    [5.0, 9.4]
    """
    x, y = (float(value) for value in point)
    column, row = round(x), round(y)
    if not (0 <= column < mask.shape[1] and 0 <= row < mask.shape[0] and mask[row, column]):
        return None
    reach = 2.5 * half_width + 2.0
    steps = np.arange(SECTION_STEP_PX, reach + 1e-9, SECTION_STEP_PX)
    nx, ny = -float(heading[1]), float(heading[0])
    plus = _border_distance(mask, x, y, nx, ny, steps, reach)
    minus = _border_distance(mask, x, y, -nx, -ny, steps, reach)
    if abs(plus + minus - 2.0 * half_width) > OWN_SECTION_PX:
        return None
    shift = 0.5 * (plus - minus)
    return np.array([x + shift * nx, y + shift * ny])


def cut_middle(
    mask: np.ndarray,
    points: np.ndarray,
    at_start: bool,
    tip: np.ndarray,
    heading: np.ndarray,
    half_width: float,
) -> np.ndarray | None:
    """Where the cable of a short piece (joints ``points``) passes out of sight at its
    end ``at_start`` (or the other), on its middle line: the middle of the first
    cross-section of the cable's own width (:func:`section_middle`, across ``heading``,
    the end's outward direction) at a joint in from the tip, traced on along
    ``heading`` (:func:`.cut_ends.middle_line`) to where the cut begins, at most
    :data:`.cut_ends.REACH_PAST_SKIP_RADII` half widths past the tip ``tip``.
    None where no joint's section is the cable's own or the trace meets no cut.
    """
    inwards = points if at_start else points[::-1]
    heading = unit(np.asarray(heading, np.float64))
    for joint in inwards[1:]:
        middle = section_middle(mask, joint, heading, half_width)
        if middle is None:
            continue
        ahead = float((np.asarray(tip, np.float64) - middle) @ heading)
        limit = max(ahead, 0.0) + REACH_PAST_SKIP_RADII * half_width + 2.0
        traced, cut, _shortfall = middle_line(mask, middle, heading, 0.0, half_width, limit)
        return traced[-1].copy() if cut else None
    return None


def short_ends_at_cut_middles(
    pieces: list[np.ndarray],
    ends: list,
    bridging_ends: list,
    joins: list[tuple[int, int, float]],
    junction_of_end: list[int],
    mask: np.ndarray,
    radius: float,
    shorter_than: float,
    curve_given: frozenset[int] = frozenset(),
) -> list:
    """``bridging_ends`` with each gap end of a piece shorter than ``shorter_than`` (the
    end fit's span) moved to the middle of the cable where it passes out of sight
    (:func:`cut_middle`), its direction kept.

    Only joins across a gap (no junction at either end), and not an end whose bridge is
    a curve found elsewhere (``curve_given``). The cable's half width is the longer
    piece's of the join (``ends``' fitted widths; a short piece's skeleton runs near its
    corners, where the mask is narrow), else ``radius``. The joins are left as they were.

    Parameters
    ----------
    pieces : list of ndarray
        ``(K, 2)`` joints of the pieces.
    ends : list of ChainEnd
        The pieces' fitted ends (their widths are read).
    bridging_ends : list of ChainEnd
        Where each end's bridge starts now (:func:`.bridge_ends.ends_through_short_pieces`).
    joins : list of (int, int, float)
    junction_of_end : list of int
    mask : ndarray of bool
    radius : float
        Typical cable half width (px).
    shorter_than : float
        The end fit's span (px).
    curve_given : frozenset of int

    Returns
    -------
    list of ChainEnd
    """
    adjusted = list(bridging_ends)
    lengths = {}
    for i, j, _ in joins:
        if junction_of_end[i] >= 0 or junction_of_end[j] >= 0:
            continue
        for own, other in ((i, j), (j, i)):
            if own in curve_given:
                continue
            piece = ends[own].piece
            for k in (piece, ends[other].piece):
                if k not in lengths:
                    lengths[k] = polyline_length(pieces[k])
            if lengths[piece] >= max(shorter_than, 2.0 * ends[own].skip + 1.0):
                continue  # long enough to fit beyond its tip: its bridge starts on the fit
            longer = own if lengths[piece] >= lengths[ends[other].piece] else other
            half_width = (ends[longer].width or radius) + 0.5
            end = bridging_ends[own]
            points = pieces[piece]
            tip = points[0] if ends[own].at_start else points[-1]
            middle = cut_middle(mask, points, ends[own].at_start, tip, end.direction, half_width)
            if middle is not None:
                adjusted[own] = replace(end, position=middle)
    return adjusted
