"""The ends of pieces too short for their skeleton to show the cable's direction.

A stretch of cable seen between two objects is a blob cut off at both ends; when it is
no longer than the cable is wide, its skeleton (the medial axis) runs along the blob's
longer diagonal, often across the cable: its two or three joints give a direction tens
of degrees off, up to a right angle, and a bridge leaving it along that direction
misses the cable's hidden stretch. The blob's own outline holds the direction: the
cable's two sides are straight and parallel, the cable's width apart, while the cuts
are the objects' outlines. :func:`ends_of_stubs` reads the direction across which the
blob is as wide as the cable. Up to twice as long, the skeleton is no better a reading:
the end fit leaves out a radius at the tip and the cut's narrow joints at the other
end, and the cable width or less left between is where thinning bends the axis toward
the cuts' corners.
"""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np

from service.perception import _merging_kernels
from service.perception.appearance import SCRAP_RADII, EndColours, colour_penalty
from service.perception.geometry import polyline_length
from service.perception.junction_widths import distance_at

# The directions tried for a stub's sides, over half a turn.
SIDE_DIRECTIONS = 90


def ends_of_stubs(
    pieces: list[np.ndarray],
    ends: list,
    mask: np.ndarray,
    radius: float,
    distance: np.ndarray | None = None,
) -> list:
    """``ends`` with those of every isolated stub read from the stub's sides.

    A stub is a piece whose skeleton is shorter than twice the cable's full width
    (``2 radius + 1``) and whose foreground blob is its own: a connected part of ``mask`` that
    holds no other piece's joint (not at a crossing, not touching another cable).
    Its direction is the one across which the blob's extent is a local minimum (a
    pair of parallel straight sides), of the minima the one nearest the cable's full
    width: between two cuts closer together than the cable is wide, the cuts' own
    direction is a narrower minimum, but not the cable's width. The stub's two ends lie
    where its middle line (the line along that direction through the blob's centre)
    leaves the blob; the start end points back along the skeleton's first-to-last
    joint, as before. Their curvature is 0: a stub shows no bend.

    With ``distance`` (the mask's distance transform), a stub's ends also take the
    half width of its widest joint, tips included, where that is wider than the median
    they read (:func:`stub_width`): its two or three joints lie where thinning bends
    the axis into the cuts' corners, and their median reads the cable a quarter to a
    half too narrow to look like the rest of it (:func:`.appearance.ends_alike`).

    Parameters
    ----------
    pieces : list of ndarray
        ``(K, 2)`` joints of the pieces (x, y).
    ends : list of ChainEnd
        Both ends of every piece (piece i: ends 2i, 2i+1).
    mask : ndarray of bool
        The foreground.
    radius : float
        Typical cable half width in pixels.

    Returns
    -------
    list of ChainEnd
    """
    full_width = 2.0 * radius + 1.0
    stubs = [k for k, points in enumerate(pieces) if polyline_length(points) < 2.0 * full_width]
    if not stubs:
        return ends
    height, width = mask.shape[:2]
    joints = np.rint(np.concatenate(pieces)).astype(np.int64)
    owner = np.repeat(np.arange(len(pieces)), [len(points) for points in pieces])
    reach = int(np.ceil(2.0 * full_width))
    adjusted = list(ends)
    for piece in stubs:
        centre = np.rint(pieces[piece].mean(0)).astype(np.int64)
        x0, y0 = max(int(centre[0]) - reach, 0), max(int(centre[1]) - reach, 0)
        x1, y1 = min(int(centre[0]) + reach + 1, width), min(int(centre[1]) + reach + 1, height)
        window = np.ascontiguousarray(mask[y0:y1, x0:x1], np.uint8)
        _, labels = cv2.connectedComponents(window, connectivity=8)
        inside = (
            (joints[:, 0] >= x0) & (joints[:, 0] < x1) & (joints[:, 1] >= y0) & (joints[:, 1] < y1)
        )
        label_of = np.zeros(len(joints), np.int64)
        label_of[inside] = labels[joints[inside, 1] - y0, joints[inside, 0] - x0]
        own = label_of[owner == piece]
        if own.min() == 0 or (own != own[0]).any():
            continue
        blob = labels == own[0]
        if (label_of[inside & (owner != piece)] == own[0]).any():
            continue  # another piece's blob too: a crossing or a touching cable
        if blob[0].any() or blob[-1].any() or blob[:, 0].any() or blob[:, -1].any():
            continue  # runs on beyond the window: no stub
        if distance is not None:
            width_now = stub_width(pieces[piece], distance, ends[2 * piece].width)
            for index in (2 * piece, 2 * piece + 1):
                adjusted[index] = replace(adjusted[index], width=width_now)
        ys, xs = np.nonzero(blob)
        pixels = np.stack([xs + x0, ys + y0], axis=1).astype(np.float64)
        axis = _side_direction(pixels, full_width)
        if axis is None:
            continue
        points = pieces[piece]
        if axis @ (points[-1] - points[0]) < 0:
            axis = -axis
        middle = pixels.mean(0)
        along = (pixels - middle) @ axis
        across = (pixels - middle) @ np.array([-axis[1], axis[0]])
        on_line = np.abs(across) <= 1.0
        if not on_line.any():
            continue
        first, last = float(along[on_line].min()), float(along[on_line].max())
        start, end = adjusted[2 * piece], adjusted[2 * piece + 1]
        adjusted[2 * piece] = replace(
            start, position=middle + first * axis, direction=-axis, curvature=0.0
        )
        adjusted[2 * piece + 1] = replace(
            end, position=middle + last * axis, direction=axis.copy(), curvature=0.0
        )
    return adjusted


def stub_width(points: np.ndarray, distance: np.ndarray, median: float) -> float:
    """The half width of a stub (``points``, its joints, whose blob is its own): the
    larger of its ``median`` and its widest joint's ``distance`` (the mask's distance
    transform), tips included.

    A cut only ever narrows a cable, and a blob that is the stub's own holds no other
    cable or crossing to widen it: no joint reads wider than the cable (the distance
    transform is at most the half width anywhere on it), and the widest reads it to
    within a pixel's rounding. Between two cuts less than two widths apart, every joint
    but one or two lies where a cut narrows the section."""
    joints = np.asarray(points, np.float64)
    return max(float(median), float(distance_at(joints[:, 0], joints[:, 1], distance).max()))


def _side_direction(pixels: np.ndarray, full_width: float) -> np.ndarray | None:
    """The unit direction of a blob's pair of parallel sides nearest ``full_width``
    apart: of the local minima of the blob's extent across a direction (of the pixels
    ``pixels``, each a unit square), the one nearest ``full_width`` by ratio; None for
    a blob with no minimum (round)."""
    reading = _side_reading(pixels, full_width)
    return None if reading is None else reading[0]


def _side_reading(pixels: np.ndarray, full_width: float) -> tuple[np.ndarray, float] | None:
    """:func:`_side_direction` and the blob's extent across it (px), or None."""
    angles = np.arange(SIDE_DIRECTIONS) * (np.pi / SIDE_DIRECTIONS)
    normals = np.stack([-np.sin(angles), np.cos(angles)], axis=1)
    projections = pixels @ normals.T
    # A pixel is a unit square: across a slanted direction it spans |nx| + |ny|.
    footprint = np.abs(normals).sum(1)
    extents = projections.max(0) - projections.min(0) + footprint
    before, after = np.roll(extents, 1), np.roll(extents, -1)
    minima = np.flatnonzero((extents <= before) & (extents <= after) & (extents < extents.max()))
    if len(minima) == 0:
        return None
    best = minima[np.argmin(np.abs(np.log(extents[minima] / full_width)))]
    return np.array([np.cos(angles[best]), np.sin(angles[best])]), float(extents[best])


def _own_blob(points: np.ndarray, mask: np.ndarray, margin: float) -> np.ndarray | None:
    """The pixels (x, y) of the connected part of ``mask`` that holds every joint of
    ``points``, when it lies within ``margin`` px of the joints' bounding box (or runs
    off the picture there); None when a joint is off the mask, the joints lie on
    different parts, or the part runs on beyond that box (a longer stretch of mask: the
    piece is not all of it)."""
    height, width = mask.shape[:2]
    low = np.floor(points.min(0) - margin).astype(np.int64)
    high = np.ceil(points.max(0) + margin).astype(np.int64) + 1
    x0, y0 = max(int(low[0]), 0), max(int(low[1]), 0)
    x1, y1 = min(int(high[0]), width), min(int(high[1]), height)
    window = np.ascontiguousarray(mask[y0:y1, x0:x1], np.uint8)
    _, labels = cv2.connectedComponents(window, connectivity=8)
    joints = np.rint(points).astype(np.int64)
    inside = (joints[:, 0] >= x0) & (joints[:, 0] < x1) & (joints[:, 1] >= y0) & (joints[:, 1] < y1)
    if not inside.all():
        return None
    own = labels[joints[:, 1] - y0, joints[:, 0] - x0]
    if own.min() == 0 or (own != own[0]).any():
        return None
    blob = labels == own[0]
    # A window side inside the picture that the blob reaches: it runs on beyond.
    if (blob[0].any() and y0 > 0) or (blob[-1].any() and y1 < height):
        return None
    if (blob[:, 0].any() and x0 > 0) or (blob[:, -1].any() and x1 < width):
        return None
    ys, xs = np.nonzero(blob)
    return np.stack([xs + x0, ys + y0], axis=1).astype(np.float64)


# A blob's two sides are straight and parallel when its narrowest extent is its cable's
# full width to within the pixel steps of two straight borders drawn at a slant, a pixel
# each (a bend over the blob's length adds its sagitta).
STRAIGHT_SIDES_PX = 2.0


def ends_along_straight_sides(
    pieces: list[np.ndarray],
    ends: list,
    joins: list[tuple[int, int, float]],
    junction_of_end: list[int],
    mask: np.ndarray,
    shorter_than: float,
    curve_given: frozenset[int] = frozenset(),
) -> list:
    """Ends for bridging, with a short piece joined at one end only pointing along its
    own straight sides.

    A piece seen between an object and the picture's edge (or its own free tip) is
    joined across the object's gap at one end only. Its skeleton is too short to give
    the cable's direction: thinning bends it toward the cut's corners and toward the
    border's, 10-40 degrees off; nor does its partner's bend, carried on along a
    circle, where the hidden stretch bends otherwise. Its blob's outline holds the
    direction: where the blob's narrowest extent is its cable's full width
    (``2 width + 1``) to within :data:`STRAIGHT_SIDES_PX`, its two long sides are the
    cable's, straight and parallel, and the cable runs between them. (Tuning block
    edge 350000-350119, true mask: of 185 such ends, 30 bridged more than 8 degrees
    off the true tangent before, 4 along the sides.) The end then points along them,
    out of the piece through the end, from its tip taken across onto the blob's
    middle line (the line along the sides through the blob's centre): a tip thinning
    bent toward a corner is taken back to the middle.

    Only a piece shorter than ``2 shorter_than`` (twice the end-fit span; longer ones
    fit their own ends), whose blob is its own (:func:`_own_blob`: no crossing, no
    cable touching it), joined across a gap (no junction at either end) at one end and
    at its other not at all, of known width, and not an end whose bridge is a curve
    found elsewhere (``curve_given``). The joins are left as they were.
    """
    partner = np.full(len(ends), -1)
    for i, j, _ in joins:
        partner[i], partner[j] = j, i
    adjusted = list(ends)
    for own, other in enumerate(partner.tolist()):
        if other < 0 or partner[own ^ 1] >= 0 or own in curve_given:
            continue
        if junction_of_end[own] >= 0 or junction_of_end[other] >= 0:
            continue
        end = ends[own]
        points = pieces[end.piece]
        if end.width <= 0 or len(points) < 2 or polyline_length(points) >= 2.0 * shorter_than:
            continue
        full_width = 2.0 * end.width + 1.0
        pixels = _own_blob(points, mask, 2.0 * full_width)
        if pixels is None:
            continue
        reading = _side_reading(pixels, full_width)
        if reading is None or reading[1] > full_width + STRAIGHT_SIDES_PX:
            continue
        axis = reading[0]
        outwards = points[0] - points[-1] if end.at_start else points[-1] - points[0]
        if axis @ outwards < 0:
            axis = -axis
        # The tip taken across onto the blob's middle line, as far along as it reached:
        # thinning bends a cut tip sideways toward a corner; where the middle line
        # leaves the blob is no better a reach on a blob that bends a little.
        middle = pixels.mean(0)
        position = middle + float((end.position - middle) @ axis) * axis
        adjusted[own] = replace(end, position=position, direction=axis)
    return adjusted


def scraps_through_junctions(
    ends: list,
    colours: EndColours | None,
    joins: list[tuple[int, int, float]],
    junction_of_end: list[int],
    pieces: list[np.ndarray],
    radius: float,
    middle_joints: int = 0,
    paired_in_junctions: frozenset[tuple[int, int]] = frozenset(),
) -> tuple[list, EndColours]:
    """``ends`` and ``colours`` with every scrap joined through its junction seen as
    the strand it continues.

    A scrap is a piece shorter than :data:`.appearance.SCRAP_RADII` radii with no colour
    of its own (:func:`.appearance.end_colours`): where a cable runs out of a crossing
    straight under an object, the skeleton between the two is such a
    scrap, its joints widened by the other strand at one end and narrowed by the cut
    at the other, so that neither its colour nor its width is the cable's. Once the
    junction pairing has joined its junction end (``junction_of_end`` >= 0) to an end
    of a known colour, the two are one strand through the crossing: the scrap's other
    end, where the object cuts it, takes that strand's colour and half width, and its
    gap beyond the object is judged as that cable's (the evidence tests of
    :mod:`.gap_evidence` ask both ends to look alike).

    A stub is a piece with a colour of its own but too few joints for a middle of its
    own (fewer than ``middle_joints``), run from a crossing to an object: its joint in
    the crossing is left out of its width as widened (:func:`widths_clear_of_crossings`)
    and its others lie where the object's rim or corner cuts it at a slant, so that its
    width is only ever read low (3.2 px for a cable of 4.4, 6.6 for one of 8.7). Joined
    through its junction to an end of its own colour, its cut end takes that strand's
    half width where the stub's own is narrower: a cut only narrows. So does a stub
    joined across a gap (neither end of the join in a junction) to an end of its own
    colour: a strand's tip split off where the cable passes close to another (a
    doubled-back cable's two strands nearly touching before the object) is such a stub,
    its few joints all in the cut's narrowing (doubled_back 460113: 3.6 px for a cable
    of 5.8). A scrap's colour is taken only through a junction: one whose ends
    ``junction_of_end`` still names, or one of ``paired_in_junctions``, the pairs made
    in a junction that was handled before the matching (the two strands through each end
    of a touching stretch, :func:`.touching.split_touching_strands`, whose ends no longer
    name it). A doubled-back cable's strands that nearly touch right before the object
    leave such a scrap at the cut, between the stretch's end and the object: paired with
    the strand it continues, it is that strand (doubled_back 480022).

    Parameters
    ----------
    ends : list of ChainEnd
        Both ends of every piece (piece i: ends 2i, 2i+1).
    colours : EndColours
    joins : list of (int, int, float)
        The joins made so far.
    junction_of_end : list of int
        Per end, the junction zone it lies in, or -1.
    pieces : list of ndarray
        The pieces' joints (only the candidates' lengths are measured).
    radius : float
        Typical cable half width in pixels.
    middle_joints : int, optional
        The fewest joints a piece has a middle with; shorter stubs take their strand's
        width (0: none do).
    paired_in_junctions : frozenset of (int, int), optional
        Joined pairs of ends that met in a junction ``junction_of_end`` no longer names
        (either order).

    Returns
    -------
    (list of ChainEnd, EndColours or None)
        New lists; the inputs are left as they were (and returned without colours).
    """
    if colours is None:
        return ends, colours
    known = colours.known
    colour, spread = colours.colour.copy(), colours.spread.copy()
    adjusted = list(ends)
    for first, second, _ in joins:
        for own, other in ((first, second), (second, first)):
            piece = ends[own].piece
            far = own ^ 1  # the piece's other end
            through_junction = (
                (junction_of_end[own] >= 0 and junction_of_end[other] == junction_of_end[own])
                or (own, other) in paired_in_junctions
                or (other, own) in paired_in_junctions
            )
            across_a_gap = (
                not through_junction and junction_of_end[own] < 0 and junction_of_end[other] < 0
            )
            if (
                not (through_junction or across_a_gap)
                or junction_of_end[far] >= 0
                or not known[other]
            ):
                continue
            if known[far]:
                if (
                    len(pieces[piece]) < middle_joints
                    and ends[far].width < ends[other].width
                    and colour_penalty(colours, np.array([far]), np.array([other]))[0] == 0
                ):
                    adjusted[far] = replace(ends[far], width=ends[other].width)
                continue
            if across_a_gap or known[own] or polyline_length(pieces[piece]) >= SCRAP_RADII * radius:
                continue
            colour[far], spread[far] = colours.colour[other], colours.spread[other]
            # A strand whose width could not be read (0) leaves the scrap its own.
            adjusted[far] = replace(ends[far], width=ends[other].width or ends[far].width)
    return adjusted, EndColours(colour, spread)


def short_piece_widths(
    pieces: list[np.ndarray],
    widths: np.ndarray,
    distance: np.ndarray,
    middle_joints: int,
    full_width_fraction: float,
) -> np.ndarray:
    """``widths`` (the pieces' median half widths) with each piece too short for a middle
    of its own (fewer than ``middle_joints`` joints) whose median is narrow (below
    ``full_width_fraction`` of its widest joint between its two end joints) measured at
    that widest joint.

    A short piece seen between two objects is cut at both ends, often at a slant:
    most of its few joints lie where a cut has narrowed the cable, and their median
    is far below the cable's half width (2.6 px for a cable of 6), so the piece would
    not look like the rest of its own cable (:func:`.appearance.ends_alike`). A cut only
    ever narrows: between the cuts, the widest joint is the cable's width. A piece
    whose median is not narrow keeps it: the widest of a few joints is the median's
    own noise and more (a wider piece may bridge longer open gaps,
    :func:`.gap_evidence.open_gap_limit`). Only the ends' widths change; the end fits
    keep the median's full width."""
    short = [k for k, points in enumerate(pieces) if 3 <= len(points) < middle_joints]
    if not short:
        return widths
    height, width = distance.shape
    inner = [pieces[k][1:-1] for k in short]
    joints = np.rint(np.concatenate(inner)).astype(np.int64)
    # np.clip's values on integers, without its checks.
    rows = np.minimum(np.maximum(joints[:, 1], 0), height - 1)
    values = distance[rows, np.minimum(np.maximum(joints[:, 0], 0), width - 1)]
    starts = np.cumsum([0, *(len(points) for points in inner[:-1])])
    widest = np.maximum.reduceat(values, starts).astype(np.float64)
    narrow = widths[short] < full_width_fraction * widest
    widths = widths.copy()
    widths[np.array(short)[narrow]] = widest[narrow]
    return widths


def widths_clear_of_crossings(
    pieces: list[np.ndarray],
    ends: list,
    distance: np.ndarray,
    zones: np.ndarray,
    at_crossing: np.ndarray,
    middle_joints: int,
    reach: int = 3,
) -> list:
    """``ends`` with the width of each piece cut at a crossing (an end flagged in
    ``at_crossing``) measured on its joints outside the junction zones (grown by
    ``reach`` px, as the tips are looked for), where there are at least two of them.

    Where two strands cross the mask is wider than either: on a short piece between a
    crossing and an object most joints lie in or beside the crossing, and the median
    half width there is up to half as much again as the cable's (9.2 px for a cable of
    6.6), so the piece would not look like the rest of its own cable across the object
    (:func:`.appearance.ends_alike`). A crossing only ever widens: the width is only
    ever lowered."""
    flagged = [
        k
        for k in np.flatnonzero(np.asarray(at_crossing, bool).reshape(-1, 2).any(axis=1))
        if len(pieces[k]) < middle_joints
    ]
    if not flagged:
        return ends
    # One look round each joint (the compiled test the tips get, tips_in_junctions), not
    # the whole picture's zones grown.
    zones_u8 = np.ascontiguousarray(
        zones.view(np.uint8) if zones.dtype == np.bool_ else zones.astype(np.uint8)
    )
    height, width = distance.shape
    ends = list(ends)
    for k in flagged:
        joints = np.rint(pieces[k]).astype(np.int64)
        rows = np.minimum(np.maximum(joints[:, 1], 0), height - 1)
        cols = np.minimum(np.maximum(joints[:, 0], 0), width - 1)
        clear = ~_merging_kernels.on_grown_zones(
            zones_u8, np.ascontiguousarray(pieces[k], np.float64), reach
        )
        clear[[0, -1]] = False  # a tip joint: cut or in the crossing
        if clear.sum() < 2:
            continue
        # A cut only narrows and a crossing only widens: clear of the crossing, the
        # widest joint is the cable's width.
        measured = float(distance[rows[clear], cols[clear]].max())
        for end in (2 * k, 2 * k + 1):
            if measured < ends[end].width:
                ends[end] = replace(ends[end], width=measured)
    return ends
