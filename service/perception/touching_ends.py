"""Touching strands that stop where an object hides them (step 6, issue 13).

Where a cable doubled back on itself touches all along up to an object that hides its
turn, thinning draws one line down the middle of the two strands, from the three-way
junction where they part to the object's border, and no junction there: the line ends
in a free end. Where only one strand stops at the object and the other bends away
beside it, the line runs on from the middle of the two into the strand that goes on,
or, where the zone there takes the line's end with the going-on strand's tip, ends in a
junction of two ends whose other is that strand's own piece. Either way the line belongs
to both strands along the stretch where the mask is both strands wide.
:func:`split_stretches_ending` and :func:`split_stretches_going_on` split such a line
into one piece per strand, as :func:`.touching.split_touching_strands` splits a line between two
junctions, and leaves the strands' tips at the object free: whether the cable turns
round out of sight there is the turn pass's question (:mod:`.turn_joins`), asked of
the strands' own ends.
"""

from __future__ import annotations

import numpy as np

from service.perception.appearance import WIDTH_AGREEMENT, cut_or_lopsided
from service.perception.geometry import arc_lengths, points_along, polyline_length
from service.perception.junction_widths import narrowest, widest
from service.perception.strand_sides import (
    SIDE_BY_SIDE_WIDTH_FRACTION,
    end_kind,
    offset_strands,
    point_in,
    short_strand,
    side_offsets,
)

# A strand running on past the end of the stretch is told from the hook thinning draws
# into a corner of the object's cut by its length: at least this many times the two
# strands' half widths together (the hook is at most about one strand's width long).
RUN_ON_STRETCH_WIDTHS = 2.0


def split_stretches_ending(
    candidates, result, positions, directions, labels, members, distance, leaving, widths
) -> set[int]:
    """Split the ``candidates`` (pieces with a three-way junction at one end and a free
    end in the picture at the other) that are two touching strands from that junction
    on, into ``result`` (a :class:`.touching.TouchingSplit`); the junctions handled.

    A candidate is split when its junction's two other strands are long (at least
    :data:`RUN_ON_STRETCH_WIDTHS` times the stretch's width, or going on through another
    junction or out of the picture)
    and alike in width (:data:`.appearance.WIDTH_AGREEMENT`: two strands of one cable,
    not a cable and its shadow), and the mask along the piece,
    from the junction on, keeps ``SIDE_BY_SIDE_WIDTH_FRACTION`` of their two widths
    together over a stretch longer than it is wide, then narrows for good. Where it
    narrows:

    - both strands stop (what is left of the line is no longer than
      :data:`RUN_ON_STRETCH_WIDTHS` stretch widths, the hook thinning bends into a
      corner of the cut) when the piece's end is cut by an object's border, straight or
      at a slant (:func:`.appearance.cut_or_lopsided`), not the round tip of a bulb too
      tight to leave a hole: each strand is run straight on to the mask's border;
    - or one strand goes on, as wide as one of the two: the line beyond is its, and
      joins the offset strand on the side it lies; the other strand is run straight on
      to the mask's border, where the object cuts it. The strand going on may leave the
      picture (a loop whose strands touch from its crossing down to the object that
      hides where they part: doubled_back 480171, 490151).

    ``widths``: every piece's half width (median distance at its joints).
    """
    handled: set[int] = set()
    pieces = list(result.pieces)
    mask = distance > 0
    for index in candidates:
        at_junction = 0 if labels[2 * index] >= 0 else 1
        end, free = 2 * index + at_junction, 2 * index + 1 - at_junction
        if labels[end] in handled or (leaving is not None and leaving[end]):
            continue
        found = _parting_strands(
            end, index, labels, members, positions, directions, pieces, leaving, widths
        )
        if found is None:
            continue
        side, side_widths = found
        strands = float(sum(side_widths))
        # From the junction towards the free end.
        points = np.asarray(pieces[index], np.float64)
        oriented = points if at_junction == 0 else points[::-1]
        parting = _where_parting(oriented, distance, strands, float(widths[index]))
        if parting is None:
            continue
        along = arc_lengths(oriented)
        rest = float(along[-1]) - parting
        stop = max(parting - 0.5 * strands, 0.0)
        shared = _up_to(oriented, along, stop)
        left, right = offset_strands(shared, strands)
        if rest <= RUN_ON_STRETCH_WIDTHS * strands:
            # Both strands stop: at an object that cuts them, never at the picture's
            # border (two strands leaving side by side look as a crossing the border
            # cuts: ariadne simple/00017).
            if leaving is not None and leaving[free]:
                continue
            if not cut_or_lopsided(mask, positions[free], directions[free], strands):
                continue
            left, right = (_run_on(strand, distance, strands) for strand in (left, right))
            turn = True
        else:
            turn = False
            beyond = _from(oriented, along, parting + 0.5 * strands)
            if not _one_strand_wide(beyond, distance, side_widths):
                continue
            heading = shared[-1] - shared[max(len(shared) - 3, 0)]
            offset = side_offsets(heading, shared[-1], [beyond[0]])[0]
            if offset < 0:
                left, right = np.concatenate([left, beyond]), _run_on(right, distance, strands)
            else:
                left, right = _run_on(left, distance, strands), np.concatenate([right, beyond])
        if at_junction == 1:
            # Back in the piece's own order: the right of the reversed line is the left.
            left, right = right[::-1], left[::-1]
        right_index = result.split_in_two(index, left, right)
        result.pairs.extend([(side[0], end), (side[1], 2 * right_index + at_junction)])
        result.partings.append((side[0] ^ 1, side[1] ^ 1))
        # The strands' own half widths: refitted without the mask, their free ends would
        # have none for the turns' tests of width and cut.
        result.strand_widths.update({index: side_widths[0], right_index: side_widths[1]})
        tips = (2 * index + 1 - at_junction, 2 * right_index + 1 - at_junction)
        result.partings.append(tips)
        if turn:
            result.turns.append(tips)
        elif leaving is not None and leaving[free]:
            # The strand going on takes the line's free end out of the picture; the
            # other's tip is where the object cuts it (the right one where offset < 0,
            # read from the junction: the sides swap where the piece starts at its
            # free end).
            result.cut_tips.append(tips[1] if (offset < 0) != (at_junction == 1) else tips[0])
        handled.add(labels[end])
    return handled


def split_stretches_going_on(
    candidates, result, positions, directions, labels, members, distance, leaving, widths
) -> set[int]:
    """Split the ``candidates`` (pieces with a three-way junction at one end and a
    junction of two ends at the other) that are two touching strands all along, one of
    which stops where an object cuts it at the two-end junction while the other goes on
    there as a piece of its own, into ``result`` (a :class:`.touching.TouchingSplit`);
    the three-way junctions handled.

    Where a cable doubled back on itself touches up to the object that hides its turn,
    and the strand that goes on bends away beside the object a little before the other
    stops, the zone there takes the line's end, the strand going on and the cut strand's
    tip together: a junction of two ends, the line's and the going-on strand's. Paired
    as it stands, the line (both strands) would run on into the one strand, and the cut
    strand's tip, the turn's other end, would be no end at all (doubled_back 480099,
    440060: a chain too many). As :func:`split_stretches_ending` reads a line that runs
    on into the strand going on itself, a candidate is split when its three-way
    junction's two other strands are long (:data:`RUN_ON_STRETCH_WIDTHS`, or going on
    through another junction or out of the picture) and alike in width, the mask along
    the whole line keeps ``SIDE_BY_SIDE_WIDTH_FRACTION`` of their two widths together,
    and the piece going on is as wide as one of the two
    (:data:`.appearance.WIDTH_AGREEMENT`). The strand on the side the piece going on lies
    keeps the two-end junction (the matching pairs it with that piece); the other is
    run straight on to the mask's border, where the object cuts it, its tip free.

    ``widths``: every piece's half width (median distance at its joints).
    """
    handled: set[int] = set()
    pieces = list(result.pieces)
    for index in candidates:
        at_junction = 0 if len(members.get(labels[2 * index], ())) == 3 else 1
        end, far = 2 * index + at_junction, 2 * index + 1 - at_junction
        if labels[end] in handled:
            continue
        beyond = [other for other in members[labels[far]] if other != far]
        if len(beyond) != 1 or beyond[0] // 2 == index:
            continue
        beyond = beyond[0]
        found = _parting_strands(
            end, index, labels, members, positions, directions, pieces, leaving, widths
        )
        if found is None:
            continue
        side, side_widths = found
        strands = float(sum(side_widths))
        points = np.asarray(pieces[index], np.float64)
        if narrowest(points, distance, float(widths[index]), short_at_middle=True) < (
            SIDE_BY_SIDE_WIDTH_FRACTION * strands
        ):
            continue
        going_on = _going_on_width(beyond, pieces, widths[index], distance, leaving, widths)
        strand = float(np.mean(side_widths))
        if min(going_on, strand) < WIDTH_AGREEMENT * max(going_on, strand):
            continue
        # Which side of the line the piece going on leaves by, read clear of the zone
        # (thinning bends its tip toward the line's), in the piece's own order (the
        # sides offset_strands puts its strands on).
        heading = directions[far] if far % 2 else -directions[far]
        offset = side_offsets(
            heading, positions[far], [point_in(pieces, beyond, float(widths[index]))]
        )[0]
        left, right = offset_strands(points, float(widths[index]))
        cut_left = offset >= 0  # the piece going on lies on the right: the left stops
        stops = left if cut_left else right
        stops = stops if far % 2 else stops[::-1]  # its tip at the two-end junction last
        stops = _run_on(stops, distance, strands)
        stops = stops if far % 2 else stops[::-1]
        left, right = (stops, right) if cut_left else (left, stops)
        right_index = result.split_in_two(index, left, right)
        result.pairs.extend([(side[0], end), (side[1], 2 * right_index + end % 2)])
        result.strand_widths.update({index: side_widths[0], right_index: side_widths[1]})
        # The strands part at the two-end junction: the cut strand's tip and the far end
        # of the piece going on are where the cable may turn round out of sight (the
        # strands' far ends at the three-way junction are long strands' own, no turn's).
        cut_tip = far if cut_left else 2 * right_index + far % 2
        result.partings.append((cut_tip, beyond ^ 1))
        if cut_left:
            # The right strand goes on: its tip takes the two-end junction, the left's
            # is free.
            result.junction_of_end[2 * right_index + far % 2] = labels[far]
            result.junction_of_end[far] = -1
        handled.add(labels[end])
    return handled


def _going_on_width(beyond, pieces, stretch_half_width, distance, leaving, widths) -> float:
    """The half width of the piece going on past a stretch's two-end junction (``beyond``:
    its end there): the median of its joints (``widths``), or, where it is shorter than
    the stretch is wide and does not leave the picture, the widest its mask gets, as a
    short strand's at a three-way junction (:func:`.touching._strand_widths`): the object
    cuts it a little past the junction, and the median of its few joints falls in its
    cut's narrowing tip (doubled_back 384092: 6.4 px against the strands' 8.3)."""
    points = pieces[beyond // 2]
    lengths = {beyond // 2: polyline_length(points)}
    if short_strand(beyond, lengths, 2.0 * stretch_half_width, leaving):
        return widest(points, distance)
    return float(widths[beyond // 2])


def _parting_strands(end, index, labels, members, positions, directions, pieces, leaving, widths):
    """The two strands parting at the three-way junction of the stretch ``index``'s
    ``end`` (:func:`.strand_sides.end_kind`: their ends, left one first) and their half
    widths, where both are long and alike (:func:`_long_alike_strands`); None otherwise."""
    side = end_kind(
        end, index, labels, members, positions, directions, pieces, float(widths[index])
    )
    if side is None:
        return None
    side_widths = _long_alike_strands(side, index, pieces, labels, leaving, widths)
    return None if side_widths is None else (side, side_widths)


def _long_alike_strands(side, index, pieces, labels, leaving, widths) -> list[float] | None:
    """The half widths of the two strands (``side``: their ends at the stretch
    ``index``'s three-way junction) where both are long where they part, at least twice
    the stretch's width (:data:`RUN_ON_STRETCH_WIDTHS`), or go on through another
    junction or out of the picture (a scrap there, as wide as a strand, may be clutter
    the segmentation joins to a cable: bright 96001 end to end, 22 px), and alike in
    width (:data:`.appearance.WIDTH_AGREEMENT`); None otherwise."""
    if any(
        polyline_length(pieces[other // 2]) < RUN_ON_STRETCH_WIDTHS * 2 * widths[index]
        and labels[other ^ 1] < 0
        and not (leaving is not None and leaving[other ^ 1])
        for other in side
    ):
        return None
    side_widths = [float(widths[other // 2]) for other in side]
    if min(side_widths) < WIDTH_AGREEMENT * max(side_widths):
        return None
    return side_widths


def _where_parting(points, distance, strands: float, half_width: float) -> float | None:
    """How far along ``points`` (from the junction) the mask, both strands wide
    (``strands``: their half widths together) from ``half_width`` clear of the
    junction on, narrows for good; None when it is never both wide over a stretch
    longer than it is wide, or never narrows, or widens again."""
    along = arc_lengths(points)
    samples = np.arange(half_width, float(along[-1]) + 1e-9, 1.0)
    if not len(samples):
        return None
    xs, ys = points_along(points, along, samples).T
    height, width = distance.shape
    cols = np.clip(np.rint(xs).astype(int), 0, width - 1)
    rows = np.clip(np.rint(ys).astype(int), 0, height - 1)
    wide = distance[rows, cols] >= SIDE_BY_SIDE_WIDTH_FRACTION * strands
    if wide.all() or not wide[0]:
        return None
    first_narrow = int(np.argmin(wide))
    if wide[first_narrow:].any() or samples[first_narrow] - samples[0] < 2.0 * strands:
        return None
    return float(samples[first_narrow])


def _up_to(points, along, stop: float) -> np.ndarray:
    """The line from its start to ``stop`` px along it."""
    inside = along < stop - 0.5  # no joint within half a pixel of the last point
    return np.concatenate([points[inside], points_along(points, along, np.array([stop]))])


def _from(points, along, start: float) -> np.ndarray:
    """The line from ``start`` px along it to its end."""
    inside = along > start + 0.5
    return np.concatenate([points_along(points, along, np.array([start])), points[inside]])


def _one_strand_wide(points, distance, side_widths) -> bool:
    """Whether the median distance along ``points`` (every pixel of the line, not its
    few joints: on a line a few joints long, the one at a cut's narrow tip would be the
    median) agrees with the mean of the two strands' half widths (``side_widths``) as
    two pieces of one cable must."""
    points = np.asarray(points, np.float64)
    along = arc_lengths(points)
    xs, ys = points_along(points, along, np.arange(0.0, float(along[-1]) + 1e-9, 1.0)).T
    height, width = distance.shape
    cols = np.clip(np.rint(xs).astype(int), 0, width - 1)
    rows = np.clip(np.rint(ys).astype(int), 0, height - 1)
    own = float(np.median(distance[rows, cols]))
    strand = float(np.mean(side_widths))
    return min(own, strand) >= WIDTH_AGREEMENT * max(own, strand)


def _run_on(strand: np.ndarray, distance: np.ndarray, strands: float) -> np.ndarray:
    """``strand`` run on straight, along its direction over its last half of ``strands``
    (a strand's width), to the last pixel of the mask ahead (the object's border), up to
    twice ``strands`` further."""
    along = arc_lengths(strand)
    back = points_along(strand, along, np.array([max(float(along[-1]) - 0.5 * strands, 0.0)]))[0]
    heading = strand[-1] - back
    length = float(np.hypot(*heading))
    if length <= 0:
        return strand
    steps = strand[-1] + np.arange(1.0, 2.0 * strands, 1.0)[:, None] * (heading / length)
    height, width = distance.shape
    cols, rows = np.rint(steps[:, 0]).astype(int), np.rint(steps[:, 1]).astype(int)
    inside = (cols >= 0) & (cols < width) & (rows >= 0) & (rows < height)
    on = np.zeros(len(steps), bool)
    on[inside] = distance[rows[inside], cols[inside]] > 0
    run = len(on) if on.all() else int(np.argmin(on))
    return np.concatenate([strand, steps[:run]]) if run else strand


def keep_turns_free(rule, turns):
    """``rule`` (a callable ``(pairs, costs, limit)`` -> which joins may be made, or
    None) that also leaves the ``turns`` (pairs of ends) to the turn pass."""
    if not turns:
        return rule
    turns = {frozenset(pair) for pair in turns}

    def keep(pairs, costs, limit):
        allowed = np.ones(len(costs), bool) if rule is None else rule(pairs, costs, limit)
        return allowed & np.array([frozenset(pair) not in turns for pair in pairs.tolist()], bool)

    return keep
