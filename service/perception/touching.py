"""Strands that touch along a stretch, told apart for merging (step 6, issue 13).

Where two strands touch along a stretch (two cables side by side, a cable doubled back
on itself), thinning draws one line down the middle of the stretch, with a three-way
junction where the strands meet and part. That line belongs to both strands. Strands
that touch all along cannot cross there (crossing, the mask would narrow to one cable's
width), so each keeps its side: the strand on the left where they meet is the one on
the left where they part. :func:`split_touching_strands` finds such lines by their
width and replaces each with two pieces, one per strand, and says which ends join; and
where the stretch is short enough for the junction zone to take it whole (no line, one
junction of four ends), it says which of the four join, by the same sides. The curve
across each such join follows its strand's own side of the stretch
(:func:`_side_bridge`), whatever the ends' fits say: thinning bends the strands' tips
toward the middle where they meet, and a curve along those tips cut across the stretch.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from service.perception import _merging_kernels
from service.perception.appearance import WIDTH_AGREEMENT
from service.perception.geometry import arc_lengths, points_along, polyline_length
from service.perception.junction_widths import (
    TOUCHING_MIDDLE_FRACTION,
    distance_at,
    middle_of_stretch,
    narrowest,
    narrows_between_shoulders,
    widest,
    widest_between,
)
from service.perception.strand_sides import (
    SIDE_BY_SIDE_WIDTH_FRACTION,
    end_kind,
    offset_strands,
    point_in,
    short_strand,
    side_offsets,
)
from service.perception.touching_ends import split_stretches_ending, split_stretches_going_on


@dataclass
class TouchingSplit:
    """The pieces with every shared line split in two (:func:`split_touching_strands`).

    ``pieces[k]`` for ``k < len(input)`` is the input piece, or the left strand of a
    shared one; the right strands are appended, ``origin[k]`` the input piece each
    came from (``origin[k] == k`` for the input's). ``junction_of_end`` has the handled
    junctions' ends (and the new pieces' ends) at -1; ``pairs`` are the ends to join
    (end ``2 k`` is piece ``k``'s start, ``2 k + 1`` its end), two by two: the two strands
    through one end of a stretch. ``bridges[i, j]`` is the curve from end ``i``'s tip to
    end ``j``'s along its strand's side (:func:`_side_bridge`), one per pair.
    ``partings`` are, per end of every split stretch, the far ends of the two strands
    parting there (where a cable doubled back on itself turns round, out of sight when
    both stop: :func:`.gap_evidence.turn_evidence`); ``strand_widths`` the half widths of
    the strands shorter than their stretch is wide, read from their mask
    (:func:`_strand_widths`), by piece; ``turns`` the two tips of the strands of a
    stretch that both stop where an object cuts it off (:mod:`.touching_ends`), left
    to the turn pass (:func:`.touching_ends.keep_turns_free`); ``cut_tips`` the tips of
    strands an object cuts where the piece they were split from left the picture (the
    strand going on leaves it, not they).
    """

    pieces: list[np.ndarray]
    origin: list[int]
    junction_of_end: list[int]
    pairs: list[tuple[int, int]] = field(default_factory=list)
    split: list[int] = field(default_factory=list)
    bridges: dict[tuple[int, int], np.ndarray] = field(default_factory=dict)
    partings: list[tuple[int, int]] = field(default_factory=list)
    strand_widths: dict[int, float] = field(default_factory=dict)
    turns: list[tuple[int, int]] = field(default_factory=list)
    cut_tips: list[int] = field(default_factory=list)

    def split_in_two(self, index: int, left: np.ndarray, right: np.ndarray) -> int:
        """Put piece ``index``'s ``left`` strand in its place and append its ``right``
        one (its ends free of junctions); the right one's index."""
        right_index = len(self.pieces)
        self.pieces[index] = left
        self.pieces.append(right)
        self.origin.append(index)
        self.junction_of_end.extend([-1, -1])
        self.split.append(index)
        return right_index


def split_touching_strands(
    pieces: list[np.ndarray],
    positions: np.ndarray,
    directions: np.ndarray,
    junction_of_end: list[int],
    distance: np.ndarray,
    leaving: np.ndarray | None = None,
) -> TouchingSplit:
    """Split the pieces two touching strands share into one piece per strand.

    A shared piece is told by its width: the distance transform along it, half its
    width clear of its ends (at its middle when it is shorter than it is wide), never
    under ``SIDE_BY_SIDE_WIDTH_FRACTION`` of the two other strands' half widths at its
    junction(s) together, however long it is. At both of its ends there is a
    three-way junction where the two strands meet it on two sides of its line. The
    other strands must be at least as long as the stretch is wide (not the scraps
    thinning leaves where a blob bulges), or leave the picture at their far end, or be
    as wide as the strand beside them (:func:`_cable_wide_pair`: a doubled-back cable's
    strand an object cuts short of its bulb). Each
    strand runs along the piece's line moved half the piece's half width to its side
    (the middle of one of two touching cables of one width).

    Parameters
    ----------
    pieces : list of ndarray
        ``(K, 2)`` joints.
    positions, directions : ndarray
        ``(2 N, 2)`` every piece's ends (start then end) and their outward directions.
    junction_of_end : list of int
        The junction each end touches, or -1.
    distance : ndarray
        Distance transform of the mask.
    leaving : ndarray of bool, optional
        Ends whose cable leaves the picture there.

    Returns
    -------
    TouchingSplit
    """
    labels = list(junction_of_end)
    result = TouchingSplit(list(pieces), list(range(len(pieces))), list(labels))
    members: dict[int, list[int]] = {}
    for index, label in enumerate(labels):
        if label >= 0:
            members.setdefault(label, []).append(index)
    # Only pieces with a three-way junction at both ends are looked at. A free end is
    # not: where a cable doubled back round a tight bend ends the stretch in a tip, so
    # does a cable segmented with its shadow (bright scenes end to end), and at the
    # picture's border two strands leaving side by side look as a crossing the border
    # cuts (ariadne simple/00017).
    candidates = [
        index
        for index in range(len(pieces))
        if all(len(members.get(labels[end], ())) == 3 for end in (2 * index, 2 * index + 1))
    ]
    # A stretch an object cuts off (:mod:`.touching_ends`): a three-way junction at one
    # end, a free end at the other (in the picture, unless the line runs on into the
    # one strand that goes on: that strand may leave the picture).
    ending = [
        index
        for index in range(len(pieces))
        if sorted(len(members.get(labels[end], ())) for end in (2 * index, 2 * index + 1)) == [0, 3]
    ]
    # A stretch whose one strand goes on as a piece of its own where the object cuts the
    # other (:mod:`.touching_ends`): a three-way junction at one end, two ends at the other.
    going_on = [
        index
        for index in range(len(pieces))
        if sorted(len(members.get(labels[end], ())) for end in (2 * index, 2 * index + 1)) == [2, 3]
    ]
    four_way = [label for label, ends in members.items() if len(ends) == 4]
    crowded = [label for label, ends in members.items() if len(ends) in (5, 6)]
    if not candidates and not four_way and not ending and not crowded and not going_on:
        return result
    # Every piece's half width (median distance at its joints), once: the shared pieces
    # and the four-way junctions (several per photograph) read them piece by piece.
    widths = _merging_kernels.median_distance_per_piece(
        np.ascontiguousarray(distance, np.float32),
        np.ascontiguousarray(np.concatenate(pieces), dtype=np.float64),
        np.cumsum([0] + [len(points) for points in pieces]).astype(np.int64),
    )
    # A cable crossing right where a touching stretch's strands meet or part: the two
    # junction zones merge into one of five or six ends. The crossing cable runs
    # straight through; without it the stretch's junction is read as any other, and
    # the crossing's two ends are left to the junction's pairing.
    through: dict[int, tuple[int, int]] = {}
    for label in crowded:
        pair = _straight_through(members[label], positions, directions, widths)
        if pair is not None:
            through[label] = pair
            members[label] = [end for end in members[label] if end not in pair]
            for end in pair:
                labels[end] = -1
    if through:
        candidates = [
            index
            for index in range(len(pieces))
            if all(len(members.get(labels[end], ())) == 3 for end in (2 * index, 2 * index + 1))
        ]
        four_way = [label for label, ends in members.items() if len(ends) == 4]
    handled = _split_shared_pieces(
        candidates, result, positions, directions, labels, members, distance, leaving, widths
    )
    if ending:
        handled |= split_stretches_ending(
            ending, result, positions, directions, labels, members, distance, leaving, widths
        )
    if going_on:
        handled |= split_stretches_going_on(
            going_on, result, positions, directions, labels, members, distance, leaving, widths
        )
    # A touching stretch short enough for the junction zone to take whole leaves no
    # shared piece: one junction of four ends.
    for label in four_way:
        if label in handled:
            continue
        ends = members[label]
        found = _touching_junction_pairs(
            ends, positions, directions, pieces, distance, leaving, widths
        )
        if found is not None:
            pairs, parting, short_widths = found
            result.pairs.extend(pairs)
            handled.add(label)
            if parting is not None:
                # Strands cut short past the stretch: it may turn round there, out of sight.
                result.partings.append(parting)
                result.strand_widths.update(short_widths)
    kept = {end for label, pair in through.items() if label in handled for end in pair}
    result.junction_of_end = [
        -1 if label in handled and end not in kept else label
        for end, label in enumerate(result.junction_of_end)
    ]
    result.bridges = _side_bridges(result, len(pieces), distance, widths)
    return result


def _straight_through(ends, positions, directions, widths) -> tuple[int, int] | None:
    """The one pair of a junction's ``ends`` (of two pieces) that a cable runs straight
    through, or None (none, or more than one).

    A cable crossing the junction zone keeps its line: each of the two ends faces the
    other, each tip lies on the other end's line within that strand's half width
    (``widths``, per piece), and the two agree in width as two pieces of one cable must
    (:data:`.appearance.WIDTH_AGREEMENT`): a strand running straight on into the line
    two touching strands share meets a piece of both their widths. The tips of a
    doubled-back cable's strands where they meet in the zone are bent by thinning and
    fail it one way or the other.
    """
    found = []
    for k, first in enumerate(ends):
        for second in ends[k + 1 :]:
            near, far = sorted((float(widths[first // 2]), float(widths[second // 2])))
            if first // 2 == second // 2 or near < WIDTH_AGREEMENT * far:
                continue
            gap = positions[second] - positions[first]
            if float(directions[first] @ gap) <= 0 or float(directions[second] @ gap) >= 0:
                continue
            if all(
                abs(side_offsets(directions[end], positions[end], [positions[other]])[0])
                <= float(widths[end // 2])
                for end, other in ((first, second), (second, first))
            ):
                found.append((first, second))
    return found[0] if len(found) == 1 else None


def _side_bridges(result: TouchingSplit, count: int, distance: np.ndarray, widths) -> dict:
    """The curve across every pair of ``result`` (:attr:`TouchingSplit.bridges`), each
    kept on its own side, away from the other pair through the same end of the stretch.
    A strand's half width is its pieces' (``widths``, of the ``count`` input pieces),
    not a split piece's: that is both strands' together."""
    bridges = {}
    tips = [
        np.asarray(result.pieces[end // 2][-(end % 2)], np.float64)
        for pair in result.pairs
        for end in pair
    ]
    for index, (first, second) in enumerate(result.pairs):
        own = [
            float(widths[end // 2])
            for end in (first, second)
            if end // 2 < count and end // 2 not in result.split
        ]
        if not own:
            continue
        other = 2 * (index ^ 1)  # the other pair of the same two (its tips in ``tips``)
        away_from = 0.5 * (tips[other] + tips[other + 1])
        bridges[first, second] = _side_bridge(
            tips[2 * index], tips[2 * index + 1], away_from, float(np.mean(own)), distance
        )
    return bridges


def _side_bridge(start, end, away_from, half_width: float, distance: np.ndarray) -> np.ndarray:
    """A strand's curve from ``start`` to ``end`` (tips of its pieces) along its own side
    of a stretch where it touches another strand, the side away from ``away_from``.

    Where two strands touch, the mask is both strands wide and each strand's middle lies
    its own half width in from the mask's border on its side, wherever the other strand
    is. So every point of the chord between the tips is moved across the chord to
    ``half_width`` (the distance transform's, to the background pixels' centres) from
    the first background pixel on its side, found within the two strands' width of the
    chord (two half widths and a pixel: the chord runs between the stretch's middle and
    the strand's; left where none is, as where another cable crossing there widens the
    mask, doubled_back 310129). The moves are smoothed along the chord over about a
    strand's width (a running median): a pixel's step of the border is not the strand's.

    Returns
    -------
    ndarray
        ``(M, 2)`` points about 1 px apart, ``start`` and ``end`` included.
    """
    start, end = np.asarray(start, np.float64), np.asarray(end, np.float64)
    length = float(np.hypot(*(end - start)))
    if length < 2.0 or half_width <= 0:
        return np.array([start, end])
    axis = (end - start) / length
    across = np.array([-axis[1], axis[0]])
    if float(across @ (0.5 * (start + end) - np.asarray(away_from, np.float64))) < 0:
        across = -across
    along = np.linspace(0.0, length, int(np.ceil(length)) + 1)
    points = start + along[:, None] * axis
    steps = np.arange(0.0, 2.0 * half_width + 1.0, 0.5)
    scanned = points[:, None, :] + steps[None, :, None] * across
    height, width = distance.shape
    cols, rows = np.rint(scanned[..., 0]).astype(int), np.rint(scanned[..., 1]).astype(int)
    inside = (cols >= 0) & (cols < width) & (rows >= 0) & (rows < height)
    outside = ~inside
    outside[inside] = distance[rows[inside], cols[inside]] <= 0
    found = outside.any(axis=1)
    moves = np.where(found, steps[outside.argmax(axis=1)] - half_width, 0.0)
    window = 2 * round(half_width) + 1
    padded = np.pad(moves, window // 2, mode="edge")
    moves = np.median(np.lib.stride_tricks.sliding_window_view(padded, window), axis=1)
    moves[[0, -1]] = 0.0  # the tips are the pieces'
    return points + moves[:, None] * across


def _split_shared_pieces(
    candidates, result, positions, directions, labels, members, distance, leaving, widths
) -> set[int]:
    """Split the ``candidates`` (pieces with a three-way junction at both ends) that two
    strands share, into ``result`` (:func:`split_touching_strands`); the junctions
    handled. ``widths``: every piece's half width (median distance at its joints)."""
    handled: set[int] = set()
    if not candidates:
        return handled
    pieces = list(result.pieces)
    lengths: dict[int, float] = {}
    for index in candidates:
        points = pieces[index]
        ends = (2 * index, 2 * index + 1)
        if {labels[end] for end in ends} & handled:
            continue
        # Per end, its junction's two other strands, left one first.
        sides = [
            end_kind(
                end, index, labels, members, positions, directions, pieces, float(widths[index])
            )
            for end in ends
        ]
        if None in sides:
            continue
        for other in (other for side in sides for other in side):
            if other // 2 not in lengths:
                lengths[other // 2] = polyline_length(pieces[other // 2])
        # Each junction's two other strands' half widths, the short ones' by their mask,
        # held to the strands beside them or, failing that, to the other junction's.
        short_widths: dict[int, float] = {}
        long_sides = [
            _long_strands(side, lengths, widths, 2 * widths[index], leaving) for side in sides
        ]
        strand_widths = [
            _strand_widths(
                side,
                pieces,
                lengths,
                widths,
                2 * widths[index],
                distance,
                leaving,
                short_widths,
                long_sides[1 - at],
            )
            for at, side in enumerate(sides)
        ]
        if None in strand_widths:
            continue
        strands = np.mean([sum(side_widths) for side_widths in strand_widths])
        # A piece shorter than its width (a stretch a little longer than the junction
        # zones) is judged at its middle: its ends are in the zones' rims.
        if narrowest(points, distance, float(widths[index]), short_at_middle=True) < (
            SIDE_BY_SIDE_WIDTH_FRACTION * strands
        ):
            continue
        right_index = result.split_in_two(index, *offset_strands(points, float(widths[index])))
        for end, side in zip(ends, sides, strict=True):
            result.pairs.extend([(side[0], end), (side[1], 2 * right_index + end % 2)])
            result.partings.append((side[0] ^ 1, side[1] ^ 1))
        result.strand_widths.update(short_widths)
        handled |= {labels[end] for end in ends} - {-1}
    return handled


def _long_strands(side, lengths, widths, stretch_width, leaving) -> list[float] | None:
    """The half widths (``widths``: medians of their joints) of a junction's two other
    strands (ends ``side``) when neither is short (:func:`.strand_sides.short_strand`),
    else None."""
    if any(short_strand(other, lengths, stretch_width, leaving) for other in side):
        return None
    return [float(widths[other // 2]) for other in side]


def _strand_widths(
    side, pieces, lengths, widths, stretch_width, distance, leaving, short_widths, beyond=None
):
    """The half widths of a junction's two other strands (ends ``side``), or None when
    one is a scrap, not a strand (:func:`_cable_wide_pair`). A strand shorter than the
    stretch is wide (``stretch_width``) that does not leave the picture is short: its
    half width is the widest its mask gets (:func:`widest`; the median of its few
    joints falls in the hook an object's slanted cut leaves), put in ``short_widths``
    (by piece); the others' their median (``widths``). ``beyond``: the half widths of
    the two long strands at the stretch's other junction, or None."""
    short = [short_strand(other, lengths, stretch_width, leaving) for other in side]
    side_widths = [
        widest(pieces[other // 2], distance) if is_short else float(widths[other // 2])
        for other, is_short in zip(side, short, strict=True)
    ]
    if any(short) and not _cable_wide_pair(side_widths, short, beyond):
        return None
    short_widths.update(
        (other // 2, width)
        for other, width, is_short in zip(side, side_widths, short, strict=True)
        if is_short
    )
    return side_widths


def _cable_wide_pair(
    side_widths: list[float], short: list[bool], beyond: list[float] | None = None
) -> bool:
    """Whether a junction's two other strands, one or both shorter than the stretch is
    wide (``short``), are two strands of one cable's width, not a strand and a scrap.

    A cable doubled back on itself, its bulb hidden by an object, leaves one strand cut
    a few radii past the junction: shorter than the stretch is wide, but as wide as the
    strand beside it, both strands being the one cable. Thinning's scraps where a blob
    bulges (a cable segmented with its shadow: ariadne simple/00004 end to end, the
    shadow half the cable's width) are narrower than the strand they part from. So a
    short strand counts when the two agree in width as two pieces of one cable must
    (:data:`.appearance.WIDTH_AGREEMENT`).

    Where the object cuts both strands a little past the junction, both are short, or
    the one a little longer reads narrow (the median of its few joints falls in its
    cut's hook): the two strands at the stretch's other junction, long (``beyond``, when
    given), are the same two strands of the one cable, and each short strand counts when
    it agrees in width with those (as a junction of four ends holds its strands cut
    short, :func:`_cut_short_pair`). Without them, two short ones are both scraps or both
    strands, and are not told apart here.
    """
    if beyond:
        long = float(np.mean(beyond))
        if all(
            min(width, long) >= WIDTH_AGREEMENT * max(width, long)
            for width, is_short in zip(side_widths, short, strict=True)
            if is_short
        ):
            return True
    if all(short):
        return False
    narrow, wide = sorted(side_widths)
    return narrow > 0 and narrow >= WIDTH_AGREEMENT * wide


# The three ways of splitting four ends into two pairs, end 0's partner 1, 2, 3 in turn.
_FOUR_END_PARTITIONS = (((0, 1), (2, 3)), ((0, 2), (1, 3)), ((0, 3), (1, 2)))


def _touching_junction_pairs(ends, positions, directions, pieces, distance, leaving, widths):
    """The two pairs of ends to join at a four-way junction that is a touching stretch
    short enough for the junction zone to take it whole, the far ends of a pair of
    strands an object cuts short past the stretch (:func:`_cut_short_pair`, or None)
    and those strands' half widths (by piece: the widest their mask gets); or None.
    ``widths``: every piece's half width (median distance at its joints).

    The two strands enter the stretch side by side at one end and leave it side by side
    at the other: the ends fall into two close pairs (the partition whose pairs lie
    closest together) at the stretch's two ends, each pointing along the stretch
    towards the other pair. The mask is wider somewhere on the middle third of the line
    between them than any crossing's middle (:data:`TOUCHING_MIDDLE_FRACTION` of both
    strands' widths, a short strand's the widest its mask gets: a right-angle crossing's
    middle is wider than one cable's, :func:`widest_between`), and along the middle
    third of the line between them (:func:`middle_of_stretch`) keeps both strands' widths
    (:data:`SIDE_BY_SIDE_WIDTH_FRACTION`, as a shared piece must): where two cables
    cross, even at a shallow angle, it narrows to one cable's there, at the crossing.
    Strands that touch all along cannot cross there, so each keeps its side:
    the left end of one pair joins the left end of the other (read as
    :func:`end_kind` reads a junction's sides), not the one straight across, as the
    cheapest matching of a crossing would.
    """
    ends = list(ends)
    points = positions[ends].tolist()
    # The partition whose pairs lie closest together (the first of equals).
    closest = min(
        _FOUR_END_PARTITIONS,
        key=lambda pairs: (
            math.dist(*(points[k] for k in pairs[0])) + math.dist(*(points[k] for k in pairs[1]))
        ),
    )
    pair_a, pair_b = (tuple(ends[k] for k in pair) for pair in closest)
    middle_a = 0.5 * (positions[pair_a[0]] + positions[pair_a[1]])
    middle_b = 0.5 * (positions[pair_b[0]] + positions[pair_b[1]])
    length = float(np.hypot(*(middle_b - middle_a)))
    if length <= 0:
        return None
    axis = (middle_b - middle_a) / length
    if any(float(directions[end] @ axis) <= 0 for end in pair_a) or any(
        float(directions[end] @ axis) >= 0 for end in pair_b
    ):
        return None
    half_widths = widths[[end // 2 for end in ends]]
    strands = 0.5 * float(half_widths.sum())  # the two strands' half widths together
    # Most four-way junctions are crossings, narrowest at their middle: one read against
    # the pieces' own widths tells most of them at once (a short strand's widest, read
    # below, only ever raises the bar it is held to).
    middle = widest_between(middle_a, middle_b, distance)
    if middle < TOUCHING_MIDDLE_FRACTION * strands:
        return None
    # Strands, not the scraps thinning leaves where a blob bulges (as for a shared piece).
    short = {
        end
        for end in ends
        if polyline_length(pieces[end // 2]) < 2 * strands
        and (leaving is None or not leaving[end ^ 1])
    }
    if short:
        # A short strand's median falls where an object cuts it (a cut only narrows): its
        # width is the widest its mask gets, as :func:`_strand_widths` reads one. Read
        # narrow, it lowers the middle a crossing is held to below a loop's own crossing
        # beside the object that cuts the strand (loops 400162).
        half_widths = np.array(
            [
                max(float(width), widest(pieces[end // 2], distance)) if end in short else width
                for end, width in zip(ends, half_widths.tolist(), strict=True)
            ]
        )
        strands = 0.5 * float(half_widths.sum())
    # Most four-way junctions are crossings, narrowest at their middle and widest there
    # along the line between the pairs. There a crossing at any angle is at most a
    # right-angle one's sqrt(1/2) of the two strands wide, well over a shallow crossing's
    # half (a loop's own crossing, loops 20020, 20174, 20192, 290195), so the middle is
    # held to halfway between that and touching strands' whole two widths.
    if middle < TOUCHING_MIDDLE_FRACTION * strands:
        return None
    if short and not _cut_short_pair(short, (pair_a, pair_b), pieces, distance, widths):
        return None
    line = np.array([middle_a, middle_b])
    if narrows_between_shoulders(
        line,
        distance,
        middle_of_stretch(length, strands),
        SIDE_BY_SIDE_WIDTH_FRACTION * strands,
        strands,
    ):
        return None
    sides = []
    for pair in (pair_a, pair_b):
        # Each pair's two ends on the two sides of the stretch's line, read on the
        # strands clear of the junction: the ends' fits, extrapolated over the tips
        # thinning bends together, may swap them (a bulb's two ends, which thinning
        # starts at one point, each bending toward the other's side); where the points
        # there do not tell, from the ends.
        origin = 0.5 * (positions[pair[0]] + positions[pair[1]])
        points = [point_in(pieces, end, strands) for end in pair]
        offsets = side_offsets(axis, origin, points)
        if offsets[0] * offsets[1] >= 0:
            offsets = side_offsets(axis, origin, [positions[end] for end in pair])
            if offsets[0] * offsets[1] >= 0:
                return None
        sides.append(pair if offsets[0] < 0 else pair[::-1])
    if any(first // 2 == second // 2 for first, second in zip(*sides, strict=True)):
        return None
    pairs = [tuple(pair) for pair in zip(*sides, strict=True)]
    if not short:
        return pairs, None, {}
    cut = pair_a if short <= set(pair_a) else pair_b
    short_widths = {end // 2: widest(pieces[end // 2], distance) for end in short}
    return pairs, (cut[0] ^ 1, cut[1] ^ 1), short_widths


def _cut_short_pair(short, pairs, pieces, distance, widths) -> bool:
    """Whether the ``short`` ends of a four-way junction's two close ``pairs`` (strands
    shorter than the stretch is wide) are a doubled-back cable's two strands an object
    cuts short of its hidden bulb, not the scraps thinning leaves where a blob bulges:
    of one pair, the other pair's two strands long, and each as wide as those
    (:data:`.appearance.WIDTH_AGREEMENT`; the widest its mask gets, as
    :func:`_strand_widths` reads a short strand)."""
    cut = next((pair for pair in pairs if short <= set(pair)), None)
    if cut is None:
        return False
    other = pairs[1] if pairs[0] == cut else pairs[0]
    long = float(np.mean([widths[end // 2] for end in other]))
    for end in short:
        own = widest(pieces[end // 2], distance)
        if min(own, long) < WIDTH_AGREEMENT * max(own, long):
            return False
    return True


def split_where_leaving_together(
    pieces: list[np.ndarray],
    mask: np.ndarray,
    radius: float,
    margin: float,
    slack: float,
    min_length: float = 0.0,
) -> list[np.ndarray]:
    """Cut the pieces where two strands leave the picture touching (ariadne simple/00012).

    Two cables that touch where they leave the picture (or one cable leaving and coming
    back) make a mask shaped as a V whose point the border cuts off: thinning draws one
    line round its point, with no junction. Such a line comes within the picture's
    border ``margin`` of it at a joint inside the piece, nearest the border of the joints
    about it; the mask runs on from that joint to the border (the strands leave there);
    the line on both sides of that joint heads into the picture, away from the border
    (two marks out by at least the cable's half width: not along it); and it turns
    there, at that joint or over it and the next, by far more than the stretches on
    either side turn (a corner, :func:`_is_corner`): a cable running along the border, or
    one bending round close to it (mbest S2/img13, a loop the border clips), does not,
    its bending changing smoothly along it. Each such piece is cut at that joint into
    two pieces, each ending at the border.

    Parameters
    ----------
    pieces : list of ndarray
        ``(K, 2)`` joints (x, y).
    mask : ndarray of bool
        The foreground.
    radius : float
        The cable's half width.
    margin : float
        How close to the border an end is at it (the merging's ``radius + BORDER_MARGIN_PX``).
    slack : float
        How far short of the border the mask may stop and still leave the picture (the
        merging's ``BORDER_MARGIN_PX``: masks often leave out the outermost pixels).
    min_length : float
        Both parts must be at least this long (the merging's end-fit span: a strand
        whose end direction can be fitted, not a scrap of clutter).

    Returns
    -------
    pieces : list of ndarray
        The input pieces, a cut one replaced by its first part, the second parts appended.
    """
    height, width = mask.shape[:2]
    result = list(pieces)
    if not pieces:
        return result
    # One pass over every joint: the inner joints within the margin that lie nearest
    # the border of the line about them (the joints either side no nearer it), where a
    # V's point would be. Most pictures have none, and nothing more is done.
    joints = np.concatenate([np.asarray(points, np.float64) for points in pieces])
    xs, ys = joints[:, 0], joints[:, 1]
    to_border = np.minimum(np.minimum(xs, ys), np.minimum(width - 1 - xs, height - 1 - ys))
    starts = np.cumsum([0] + [len(points) for points in pieces])
    near = to_border <= margin
    near[starts[:-1]] = False
    near[starts[1:] - 1] = False
    candidates = np.flatnonzero(near)
    if not len(candidates):
        return result
    gaps = np.column_stack([xs, ys, width - 1 - xs, height - 1 - ys])[candidates]
    inward = _INWARD[gaps.argmin(axis=1)]
    offsets = [
        np.einsum("ij,ij->i", joints[candidates + step] - joints[candidates], inward)
        for step in (-1, 1)
    ]
    lowest = (np.minimum(*offsets) >= 0) & (np.maximum(*offsets) > 0)
    candidates = candidates[lowest]
    if not len(candidates):
        return result
    owners = np.searchsorted(starts, candidates, side="right") - 1
    reach = 2.0 * radius
    for index in sorted(set(owners.tolist())):
        points = np.asarray(pieces[index], np.float64)
        own = candidates[owners == index]
        own = own[np.argsort(to_border[own], kind="stable")] - starts[index]
        along = arc_lengths(points)
        at = next(
            (int(at) for at in own if _leave_together(points, along, int(at), mask, reach, slack)),
            None,
        )
        if at is None or min(along[at], along[-1] - along[at]) < min_length:
            continue
        result[index] = points[: at + 1]
        result.append(points[at:])
    return result


# The direction into the picture from its left, top, right and bottom border.
_INWARD = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])


def _leave_together(points, along, at, mask, reach, slack) -> bool:
    """Whether two strands leave the picture at joint ``at`` (:func:`split_where_leaving_together`):
    the mask runs from it to the nearest border, the line ``reach`` before and after it
    lies further into the picture (two marks out, by the cable's half width), and it
    turns there at a corner, not a bend."""
    height, width = mask.shape[:2]
    gaps = (points[at, 0], points[at, 1], width - 1 - points[at, 0], height - 1 - points[at, 1])
    side = int(np.argmin(gaps))
    inward = _INWARD[side]
    steps = np.arange(0.0, max(gaps[side] - slack, 0.0) + 1e-9, 1.0)
    xs = np.clip(np.rint(points[at, 0] - steps * inward[0]).astype(int), 0, width - 1)
    ys = np.clip(np.rint(points[at, 1] - steps * inward[1]).astype(int), 0, height - 1)
    if not mask[ys, xs].all():
        return False
    if along[at] < reach or along[-1] - along[at] < reach:
        return False
    before, after = points_along(points, along, np.array([along[at] - reach, along[at] + reach]))
    if min(float((before - points[at]) @ inward), float((after - points[at]) @ inward)) <= 0:
        return False
    half_width = 0.5 * reach
    reach = max(reach, float(np.diff(along)[max(at - 1, 0) : at + 1].max()))
    if along[at] < 2 * reach or along[-1] - along[at] < 2 * reach:
        return False
    # Both strands rise away from the border: two marks out, each lies a cable's half
    # width further in than the joint (a V's arms), not running along the border.
    ends = points_along(points, along, along[at] + np.array([-2.0, 2.0]) * reach)
    if float(((ends - points[at]) @ inward).min()) < half_width:
        return False
    return _is_corner(points, along, at, reach)


def _is_corner(points, along, at, reach) -> bool:
    """Whether the line turns at joint ``at`` at a corner, not a bend, seen at marks
    ``reach`` apart (at least a joint step).

    A cable's bending changes smoothly along it, so it turns at a mark no more than the
    stretches either side of that mark turn together; two strands meeting at the
    border turn there far more than along either (ariadne simple/00012: 55 degrees
    against 35 and 0; mbest S2/img13, a loop the border clips: 12.9 against 4.7 and
    6.5). Thinning rounds the V's cut-off point over about the cable's width, which
    ``reach`` is no less than, so the corner's turn falls at one mark or is spread over
    two adjacent ones (tracking video 440004 frames 72-74: 55.5 and 51.2 degrees at the
    joint and the next, 17.0 and 0.7 beyond). Over two marks (a stretch twice as long)
    the corner must turn by more than twice what the marks either side of the two turn
    together (the same ratio of bending along it as at one mark: twice the mean about).
    Joints lie on the pixel grid: each step's direction is known to about a pixel in
    ``reach``, so the corner must stand out by more than two such errors.
    """
    noise = 2.0 * float(np.arctan(1.0 / reach))
    ks = [k for k in range(-3, 4) if 0.0 <= along[at] + k * reach <= along[-1]]
    marks = dict(
        zip(ks, points_along(points, along, along[at] + reach * np.array(ks, float)), strict=True)
    )
    turns = {k: _signed_turn(marks[k - 1], marks[k], marks[k + 1]) for k in ks[1:-1]}
    for first, count in _CORNER_WINDOWS:
        flanks = first - 1, first + count
        if not all(k in turns for k in flanks):
            continue
        corner = abs(sum(turns[k] for k in range(first, first + count)))
        if corner > count * sum(abs(turns[k]) for k in flanks) + noise:
            return True
    return False


# The stretches of ``count`` marks from mark ``first`` (0: the joint) over which a
# corner's turn may fall. Not three marks: a cable doubled back round a bend of 3 cable
# radii (the loops family's tightest) turns by about 150 degrees over three marks.
_CORNER_WINDOWS = ((0, 1), (0, 2), (-1, 2))


def _signed_turn(before: np.ndarray, at: np.ndarray, after: np.ndarray) -> float:
    """The angle (radians, counter-clockwise in x, y positive) from the step ``before``
    to ``at`` to the step ``at`` to ``after``."""
    arriving, leaving = at - before, after - at
    cross = float(arriving[0] * leaving[1] - arriving[1] * leaving[0])
    return float(np.arctan2(cross, float(arriving @ leaving)))


# A piece between two three-way junctions up to this many radii long is taken as shared
# by two strands crossing at a shallow angle on its junctions alone. Two strands of
# half width r crossing at an angle a (radians) overlap over about 4 r / a: up to 16
# radii, crossings steeper than about 14 degrees; a longer piece is shared only when
# its mask says so (:func:`_crossed_along`).
SHARED_PIECE_RADII = 16.0


def absorb_shared_pieces(
    pieces: list[np.ndarray],
    junction_of_end: list[int],
    radius: float,
    distance: np.ndarray | None = None,
    positions: np.ndarray | None = None,
    directions: np.ndarray | None = None,
    leaving: np.ndarray | None = None,
) -> tuple[list[int], set[int], list[tuple[int, int]]]:
    """Fold pieces that two strands share into one junction.

    Where two strands cross at a shallow angle, thinning draws one line along the
    stretch where they overlap, with a three-way junction at each end. That piece
    belongs to both strands, so it is dropped and its two junctions become one
    crossing whose four ends are paired like any other. A piece longer than
    ``SHARED_PIECE_RADII`` (a crossing shallower than about 14 degrees, or one strand
    between two places where others touch it) is dropped only when ``distance`` (the
    mask's distance transform) shows two strands overlapping along it and crossing
    (:func:`_crossed_along`), and no strand meeting it leaves the picture (``leaving``,
    per end) within the stretch's width: two strands leaving side by side, the border
    cutting them, look the same. With the ends' ``positions`` and ``directions`` (``(2 N,
    2)``, start then end of every piece, pointing out of it), the strands are paired
    across the crossing by their sides: two strands that cross swap sides, so the strand
    on the left of the shared line where they meet is the one on its right where they
    part (read as :func:`end_kind` reads a touching stretch's sides, whose strands keep
    them). The ends' fits near a shallow crossing follow the line down both strands'
    middle, and their directions, bent toward it, cannot tell the pairs apart.

    Returns
    -------
    junction_of_end : list of int
        Updated junction labels (the dropped pieces' ends get -1).
    dropped : set of int
        Indices of the dropped pieces.
    pairs : list of (int, int)
        The ends to join across each dropped piece whose sides could be read.
    """
    labels = list(junction_of_end)
    sizes: dict[int, int] = {}
    for label in labels:
        if label >= 0:
            sizes[label] = sizes.get(label, 0) + 1
    dropped: set[int] = set()
    pairs: list[tuple[int, int]] = []
    widths = None
    for index, points in enumerate(pieces):
        first, second = labels[2 * index], labels[2 * index + 1]
        if first < 0 or second < 0 or first == second:
            continue
        if sizes.get(first) != 3 or sizes.get(second) != 3:
            continue
        long = polyline_length(points) > SHARED_PIECE_RADII * radius
        if (long or positions is not None) and distance is not None and widths is None:
            widths = _merging_kernels.median_distance_per_piece(
                np.ascontiguousarray(distance, np.float32),
                np.ascontiguousarray(np.concatenate(pieces), dtype=np.float64),
                np.cumsum([0] + [len(piece) for piece in pieces]).astype(np.int64),
            )
        if long:
            if distance is None:
                continue
            # A strand meeting it that leaves the picture within the stretch's width:
            # the border cuts the band there, and two strands leaving side by side look
            # as a crossing the border cuts.
            if leaving is not None and any(
                leaving[end ^ 1] and polyline_length(pieces[end // 2]) < 2 * widths[index]
                for end in range(len(labels))
                if labels[end] in (first, second) and end // 2 != index
            ):
                continue
            # The two other strands at each of its junctions.
            strands = [
                [
                    float(widths[end // 2])
                    for end in range(len(labels))
                    if labels[end] == label and end // 2 != index
                ]
                for label in (first, second)
            ]
            if not _crossed_along(points, distance, strands):
                continue
        if positions is not None and directions is not None:
            members = {
                label: [end for end, at in enumerate(labels) if at == label]
                for label in (first, second)
            }
            reach = float(widths[index]) if widths is not None else radius
            sides = [
                end_kind(end, index, labels, members, positions, directions, pieces, reach)
                for end in (2 * index, 2 * index + 1)
            ]
            if None not in sides:
                pairs.extend([(sides[0][0], sides[1][1]), (sides[0][1], sides[1][0])])
        dropped.add(index)
        labels[2 * index] = labels[2 * index + 1] = -1
        labels = [first if label == second else label for label in labels]
        sizes[first] = 4
        sizes.pop(second, None)
    return labels, dropped, pairs


def _crossed_along(points: np.ndarray, distance: np.ndarray, strands: list[list[float]]) -> bool:
    """Whether two strands overlap along a piece and cross within it, read from the
    mask's half width along it (``distance`` at every pixel of its line) against the
    half widths of the two strands meeting it at each of its junctions (``strands``).

    Two strands crossing at a shallow angle make one band whose width grows from one
    strand's at the crossing to both strands' where they part: a quarter of the way in
    from each end it is half-way, wider than either strand alone, which a single strand
    between two junctions never is. Where they cross it narrows to one strand's width,
    below ``SIDE_BY_SIDE_WIDTH_FRACTION`` of the two together, which strands touching
    all along never do (those :func:`split_touching_strands` has taken).
    """
    points = np.asarray(points, np.float64)
    along = arc_lengths(points)
    length = float(along[-1])
    samples = np.arange(0.0, length + 1e-9, 1.0)
    xs, ys = points_along(points, along, samples).T
    half_widths = distance_at(xs, ys, distance).astype(np.float64)
    widest = max(max(side) for side in strands)
    for low, high in ((0.125, 0.375), (0.625, 0.875)):
        span = (samples >= low * length) & (samples <= high * length)
        if not span.any() or float(np.median(half_widths[span])) <= widest:
            return False
    together = min(sum(side) for side in strands)
    middle = (samples >= 0.25 * length) & (samples <= 0.75 * length)
    return float(half_widths[middle].min()) < SIDE_BY_SIDE_WIDTH_FRACTION * together
