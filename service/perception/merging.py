"""Step 6: merging, joining chain pieces into whole DLOs across gaps and crossings.

Every pair of chain ends gets a cost from three parts, as in Keipour et al. (RA-L
2022): the distance between the ends, the difference of their directions, and the
turning a curve needs to connect them (:func:`join_cost`). The ends that meet in one
junction zone are paired first, by the cheapest matching of that zone; then the
remaining pairs are joined cheapest first, never closing a chain on itself, until the
cheapest remaining join is implausible or the expected number of DLOs is reached; last,
two free ends across a short gap that are each other's clearly cheapest partner are
joined up to a looser limit (:func:`choose_joins`).

Beyond the paper, the cost uses what the image shows (issue 13): an end's own bending
is expected to go on across a gap, so a hidden stretch of a loop costs no more than a
straight one; two ends of clearly different colour (:mod:`.appearance`) cost more; an
end whose cable runs on to the picture's border, and any gap whose curve would run
outside the picture, is a cable leaving the picture, never a gap to bridge.

Each gap is filled with the curve ``DetectParams.gap_curve`` names
(:func:`.paths.gap_curve`): by default "smooth", a cubic along both end directions that
spreads the turn over the whole gap as an elastic cable bends; or the paper's "natural"
curve, straight along the end directions and then one arc of constant curvature. The
joined pieces and their bridges are strung into paths by :func:`.paths.assemble_paths`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from schemas import DetectParams
from service.perception import _merging_kernels, _pruning_kernels
from service.perception.appearance import (
    EndColours,
    colour_penalty,
    end_colours,
    gap_hidden,
)
from service.perception.bridge_ends import (
    FULL_WIDTH_FRACTION,
    bridge_from_the_fits,
    ends_of_short_pieces_from_partners,
    ends_through_short_pieces,
    free_ends_beside_crossings,
    unfitted_pieces,
)
from service.perception.crossing_stubs import ends_past_crossings, evidence_ends, stub_fronts
from service.perception.cut_ends import bridges_from_the_cuts
from service.perception.cut_middles import short_ends_at_cut_middles
from service.perception.deadline import Deadline, check
from service.perception.end_readings import ends_refitted_onto_the_mask
from service.perception.gap_evidence import (
    TURN_EVIDENCE_ALONG_CURVE,
    beyond_hiding,
    cut_bridge_gives_way,
    cut_ends_alike,
    open_gap_limit,
    open_gap_too_long,
    own_tips_rule,
    points_out_of_picture,
    turn_evidence,
    turn_hiding_extent,
    turn_out_of_view,
)
from service.perception.geometry import polyline_length
from service.perception.occluder_outline import turns_within_outlines
from service.perception.pairing import Components, cheapest_pairing
from service.perception.paths import MergedPath, assemble_paths, gap_curve
from service.perception.short_pieces import (
    ends_along_straight_sides,
    ends_of_stubs,
    scraps_through_junctions,
    short_piece_widths,
    widths_clear_of_crossings,
)
from service.perception.touching import (
    TouchingSplit,
    absorb_shared_pieces,
    split_touching_strands,
    split_where_leaving_together,
)
from service.perception.touching_ends import keep_turns_free
from service.perception.traced_cuts import traced_cut_tests
from service.perception.turn_joins import HIDDEN_BEND_RADII, turn_joins

# An end whose cable runs on along its direction, within this many radii plus
# BORDER_REACH_PX, to the picture's border (or within BORDER_MARGIN_PX of it) is a cable
# leaving the picture: it is never joined across a gap.
BORDER_REACH_RADII = 6.0
BORDER_REACH_PX = 2.0
END_FIT_SPAN_PX = 40.0
END_FIT_SPAN_RADII = 6.0
# Thinning stops about a radius from the edge of the picture; an end this much
# further in still counts as at the edge.
BORDER_MARGIN_PX = 2.0
# At most this many joints at an end are left out of its fit for being narrow (below
# bridge_ends.FULL_WIDTH_FRACTION of the full half width: part of a cut end).
NARROW_END_JOINTS = 4
# A piece measures its own full width when it has this many joints beyond those.
MIN_INTERIOR_JOINTS = 3
# The fewest joints a piece has a middle with (both ends' narrow joints and an interior).
MIDDLE_JOINTS = 2 * NARROW_END_JOINTS + MIN_INTERIOR_JOINTS


@dataclass(frozen=True)
class ChainEnd:
    """One end of a chain piece: where it is and which way it points (outwards).

    ``skip`` is the arc length at the tip its fit left out (a cut end's hook); ``width``
    its piece's typical half width (px; 0 when not measured).
    """

    piece: int
    at_start: bool
    position: np.ndarray
    direction: np.ndarray
    curvature: float = 0.0
    skip: float = 0.0
    width: float = 0.0


@dataclass(frozen=True)
class Join:
    """A join the merging step made, for evaluation and debugging."""

    end_a: ChainEnd
    end_b: ChainEnd
    cost: float


@dataclass
class MergeResult:
    paths: list[MergedPath]
    joins: list[Join]


def chain_ends(
    pieces: list[np.ndarray],
    span: float,
    skip: float = 0.0,
    distance: np.ndarray | None = None,
    full_width: float = 0.0,
    bend_aware: np.ndarray | None = None,
) -> list[ChainEnd]:
    """Both ends of every piece with their outward directions (piece i: ends 2i, 2i+1).

    The end fit leaves out the last ``skip`` of arc length, and with ``distance`` (the
    mask's distance transform) also every joint at the end where the cable is narrower
    than its full width (``full_width``, or more for a piece whose joints are typically
    wider, less for a long piece thinner in its middle): where an occluder cuts a cable
    at a slant, thinning bends the end toward the cut's far corner over more than one
    radius, and that stretch would tilt the end's direction. For the same reason a short
    piece's end fit stops short of its other end's narrow tip.

    The ends flagged in ``bend_aware`` (one flag per end) are fitted over a shorter span
    where their piece bends tightly (``_geometry_kernels.bend_aware_fit``): see
    :func:`merge_chains` for which.
    """
    if not pieces:
        return []
    counts = [len(points) for points in pieces]
    starts = np.cumsum([0, *counts]).astype(np.int64)
    joints = np.ascontiguousarray(np.concatenate(pieces), dtype=np.float64)
    widths = np.zeros(len(pieces))
    full_widths = np.full(len(pieces), float(full_width))
    narrow_in = np.zeros((0, 0), np.float32)  # empty: no end is left out for being narrow
    if distance is not None:
        narrow_in = np.ascontiguousarray(distance, np.float32)
        # Cables differ in width: a piece's own full width is the typical distance to
        # the border at its joints, and for a long piece also that away from both ends
        # (more than NARROW_END_JOINTS in), where no cut end narrows it.
        long = np.flatnonzero(np.diff(starts) >= MIDDLE_JOINTS)
        middles = [pieces[k][NARROW_END_JOINTS:-NARROW_END_JOINTS] for k in long]
        part_starts = np.cumsum([0, *counts, *(len(points) for points in middles)])
        values = _merging_kernels.median_distance_per_piece(
            narrow_in,
            np.ascontiguousarray(np.concatenate([joints, *middles]), dtype=np.float64),
            part_starts.astype(np.int64),
        )
        widths, interior = values[: len(pieces)], values[len(pieces) :]
        long_enough = np.diff(starts) >= 3
        full_widths[long_enough] = np.maximum(
            full_widths[long_enough], FULL_WIDTH_FRACTION * widths[long_enough]
        )
        # A cable thinner than the picture's typical one is at its full width where its
        # own middle is: held to the typical width, its every joint would look narrow,
        # and a joint widened by a bend or a touching strand would cut the end's fit
        # short by several joints. (Only ever lower: a blob the piece runs through
        # widens its middle.)
        thinner = interior > 0
        held = long[thinner]
        full_widths[held] = np.minimum(full_widths[held], FULL_WIDTH_FRACTION * interior[thinner])
        widths = short_piece_widths(
            pieces,
            widths,
            narrow_in,
            MIDDLE_JOINTS,
            FULL_WIDTH_FRACTION,
        )
    # Both fits of every piece in one compiled loop (geometry.end_fit's, end by end); a
    # short piece's fit stops short of its other end's narrow tip (its length is needed).
    # (Every piece's polyline_length in one call: the same sums, in NumPy's order.)
    lengths = _pruning_kernels.chain_lengths(joints, starts[1:])
    positions, directions, curvatures, skips = _merging_kernels.fit_chain_ends(
        joints,
        starts,
        lengths,
        narrow_in,
        full_widths,
        float(skip),
        float(span),
        NARROW_END_JOINTS,
        np.zeros(0, np.bool_) if bend_aware is None else np.ascontiguousarray(bend_aware, np.bool_),
    )
    curvatures, skips, widths = curvatures.tolist(), skips.tolist(), widths.tolist()
    # Each row its own array, as ``positions[end].copy()`` gives (one split, not a copy
    # per end); each end made as the dataclass's ``__init__`` would, without its
    # ``object.__setattr__`` per field of a frozen class (every end of every frame).
    positions, directions = list(positions.copy()), list(directions.copy())
    made = []
    for end in range(2 * len(pieces)):
        chain_end = object.__new__(ChainEnd)
        chain_end.__dict__.update(
            piece=end // 2,
            at_start=end % 2 == 0,
            position=positions[end],
            direction=directions[end],
            curvature=curvatures[end],
            skip=skips[end],
            width=widths[end // 2],
        )
        made.append(chain_end)
    return made


def join_cost(a: ChainEnd, b: ChainEnd, params: DetectParams, radius: float) -> float:
    """Cost of joining two chain ends: distance, direction difference and curvature.

    ``distance_weight * d / max_gap + direction_weight * angle / pi + curvature_weight *
    fade * turning / (2 pi)``, with ``d`` the gap's length, ``angle`` (0 to pi) the turn
    from the direction leaving ``a`` to the direction arriving at ``b`` that the ends'
    own bending does not explain, ``turning`` (0 to 2 pi) the turn from the leaving
    direction onto the gap's heading plus the turn from there onto the arriving
    direction, less what the ends' bending explains, and ``fade = min(1, d / (3
    radius))``.

    A cable bends smoothly: across a gap of length ``L`` an end whose stretch curves
    by ``kappa`` (at most a tight loop's, ``1 / (MIN_BEND_RADII * radius)``) may go on
    turning, by about ``kappa L`` in all, so a hidden stretch of a loop or a bend costs
    no more than a straight one. It may as well straighten out of sight: the direction
    and turning parts are the cheaper of the two readings, never dearer than the paper's.

    Parameters
    ----------
    a, b : ChainEnd
    params : DetectParams
        Weights and ``max_gap``.
    radius : float
        Cable half width: below about three radii the direction of the gap itself is
        noise, so the curvature part fades out.

    Returns
    -------
    float
        0 for ends that touch and continue each other straight; the usual limit of
        plausibility is ``params.merge_cost_threshold``.
    """
    return float(
        _merging_kernels.join_cost(
            float(a.position[0]),
            float(a.position[1]),
            float(a.direction[0]),
            float(a.direction[1]),
            float(a.curvature),
            float(b.position[0]),
            float(b.position[1]),
            float(b.direction[0]),
            float(b.direction[1]),
            float(b.curvature),
            np.array([params.distance_weight, params.direction_weight, params.curvature_weight]),
            float(params.max_gap),
            float(radius),
        )
    )


def _best_matchings(
    junctions: list[list[int]],
    ends: list[ChainEnd],
    params: DetectParams,
    radius: float,
    colours: EndColours | None = None,
) -> list[tuple[int, int, float]]:
    """Cheapest way to pair up the ends that meet at each junction (``junctions``: the
    ends of each), their pairs all costed in one kernel call.

    Every pairing of a junction's ends is considered (junctions are small: a crossing
    has four ends, a loop touching a cable four, a triple crossing six), with a penalty
    for each end left unpaired, since a strand rarely ends inside a junction. Two ends of
    the same piece are never paired. The ends' curvature is not carried across: inside a
    junction thinning bends each strand toward where the strands meet, so the bending
    there is not the cable's, and the gaps are short.
    """
    # Every pair of ends of different pieces, junction by junction.
    pairs = [
        [
            (a, b)
            for a_pos, a in enumerate(members)
            for b in members[a_pos + 1 :]
            if ends[a].piece != ends[b].piece
        ]
        for members in junctions
    ]
    flat = [pair for junction_pairs in pairs for pair in junction_pairs]
    costs = np.zeros(0)
    if flat:
        first = np.array([a for a, _ in flat], np.int64)
        second = np.array([b for _, b in flat], np.int64)
        # join_cost of every pair, with the ends' curvature set to 0.
        costs = _merging_kernels.pair_join_costs(
            np.array([end.position for end in ends], np.float64),
            np.array([end.direction for end in ends], np.float64),
            np.zeros(len(ends)),
            first,
            second,
            np.array([params.distance_weight, params.direction_weight, params.curvature_weight]),
            float(params.max_gap),
            float(radius),
        )
        if colours is not None:
            costs = costs + params.colour_weight * colour_penalty(colours, first, second)
    costs_left = iter(costs.tolist())
    found = []
    for members, junction_pairs in zip(junctions, pairs, strict=True):
        junction_costs = {pair: next(costs_left) for pair in junction_pairs}
        found.extend(cheapest_pairing(members, junction_costs, params.merge_cost_threshold))
    return found


# Junctions with more ends than this are paired greedily (the matching is exponential).
MAX_JUNCTION_ENDS = 10

# Candidate joins tried between two looks at the deadline.
DEADLINE_CHECK_EVERY = 4096


def choose_joins(
    ends: list[ChainEnd],
    piece_count: int,
    params: DetectParams,
    radius: float,
    junction_of_end: list[int] | None = None,
    at_border: np.ndarray | None = None,
    deadline: Deadline | None = None,
    colours: EndColours | None = None,
    leaving: np.ndarray | None = None,
    picture: tuple[int, int] | None = None,
    preset: list[tuple[int, int]] | None = None,
    hidden_gap: Callable[[int, int], bool] | None = None,
    runs_out: np.ndarray | None = None,
    open_gap: Callable[[int, int], bool] | None = None,
    tips: Callable[[np.ndarray, np.ndarray, float], np.ndarray] | None = None,
    through_crossings: Callable[[list], list[ChainEnd]] | None = None,
) -> list[tuple[int, int, float]]:
    """Decide which chain ends to join.

    The ``preset`` pairs (touching strands told apart by
    :func:`.touching.split_touching_strands`) are joined before anything else. Then the ends
    that meet at each junction (``junction_of_end[i] >= 0``) are paired by the cheapest
    matching of that junction; then the remaining ends are joined greedily, cheapest first,
    across gaps, up to ``merge_cost_threshold``; last, two free ends that are each other's
    clearly cheapest partner are joined up to a looser limit, unless either is
    ``at_border``: across a short gap (:data:`MUTUAL_GAP_RADII`), or a longer one
    that ``hidden_gap(i, j)`` says something in the image hides
    (:func:`.appearance.gap_hidden`, or, up to :data:`.gap_evidence.CUT_GAP_RADII`, two
    ends cut square and alike: :func:`.gap_evidence.cut_ends_alike`). A join never closes
    a chain on itself.
    ``deadline`` (optional) is checked while the joins are made.

    The evidence of the image, when given: ``colours`` (:func:`.appearance.end_colours`)
    adds ``params.colour_weight`` times :func:`.appearance.colour_penalty` to every
    join; ends marked ``leaving`` (cables leaving the picture) are never joined across a
    gap; and with ``picture`` ((height, width)) no gap is bridged by a curve that runs
    outside the picture. The last two do not apply when ``expected_count`` asks for
    joins past the threshold. With ``runs_out`` (the ends whose cable runs on along
    their direction to the border, a part of ``leaving``), an end that is only
    ``at_border`` (near the picture's edge, but its cable stops short of it) may still
    be joined across a gap that ``hidden_gap`` says something hides: an object lying
    at the picture's edge, not the edge, cuts that cable (:func:`_border_pairs_hidden`).
    With ``open_gap``, a join across more than :data:`.gap_evidence.OPEN_GAP_RADII` (the
    ends' chord) is left out, however cheap, when ``open_gap(i, j)`` says its bridge runs
    that far over open background that nothing in the image hides
    (:func:`.gap_evidence.open_gap_too_long`); with ``tips``, two cables' own tips stay ends
    (:func:`.gap_evidence.tips_stay_ends`); ``through_crossings`` (given the joins made
    through junctions) returns the ends to cost the joins across gaps with (a short
    piece's free end read through its crossing,
    :func:`.bridge_ends.free_ends_beside_crossings`). In the last step, a partner that
    ``hidden_gap`` does not let an end join across a longer gap is no rival.

    Returns
    -------
    list of (int, int, float)
        Joined end indices and their cost, in the order they were made.
    """
    components = Components(piece_count)
    used = np.zeros(len(ends), bool)
    chains_left = piece_count
    joins = []

    def _could_join(i: int, j: int) -> bool:
        if used[i] or used[j]:
            return False
        return components.find(ends[i].piece) != components.find(ends[j].piece)

    def try_join(i: int, j: int, cost: float) -> bool:
        nonlocal chains_left
        if not _could_join(i, j):
            return False
        piece_i, piece_j = ends[i].piece, ends[j].piece
        components.union(piece_i, piece_j)
        used[i] = used[j] = True
        chains_left -= 1
        joins.append((i, j, cost))
        return True

    for i, j in preset or ():
        straight_i, straight_j = (replace(ends[k], curvature=0.0) for k in (i, j))
        try_join(i, j, join_cost(straight_i, straight_j, params, radius))
    if junction_of_end is not None:
        groups: dict[int, list[int]] = {}
        for index, junction in enumerate(junction_of_end):
            if junction >= 0:
                groups.setdefault(junction, []).append(index)
        paired = [members for members in groups.values() if 2 <= len(members) <= MAX_JUNCTION_ENDS]
        proposals = _best_matchings(paired, ends, params, radius, colours)
        for i, j, cost in sorted(proposals, key=lambda item: item[2]):
            try_join(i, j, cost)
        if through_crossings is not None:
            ends = through_crossings(joins)

    # Only pairs within max_gap can be joined (any pair when expected_count asks): the
    # compiled kernel finds them on a grid and costs them, in time that grows with the
    # pairs found rather than with the square of the number of ends.
    positions = np.array([end.position for end in ends], np.float64).reshape(-1, 2)
    directions = np.array([end.direction for end in ends], np.float64).reshape(-1, 2)
    pairs, distances, costs = _merging_kernels.candidate_joins(
        positions,
        directions,
        np.array([end.curvature for end in ends], np.float64),
        np.array([end.piece for end in ends], np.int64),
        np.flatnonzero(~used).astype(np.int64),
        np.inf if params.expected_count is not None else float(params.max_gap),
        float(params.max_gap),
        np.array([params.distance_weight, params.direction_weight, params.curvature_weight]),
        float(radius),
    )
    if colours is not None and len(costs):
        costs = costs + params.colour_weight * colour_penalty(colours, pairs[:, 0], pairs[:, 1])
    border_ok = np.zeros(len(ends), bool)
    if leaving is not None and params.expected_count is None and len(costs):
        keep = ~(leaving[pairs[:, 0]] | leaving[pairs[:, 1]])
        if runs_out is not None and at_border is not None and hidden_gap is not None:
            hidden = _border_pairs_hidden(pairs, costs, keep, runs_out, at_border, params)
            for index in hidden.tolist():
                keep[index] = hidden_gap(*pairs[index].tolist())
                border_ok[pairs[index]] |= keep[index]
        pairs, distances, costs = pairs[keep], distances[keep], costs[keep]
    if picture is not None and params.expected_count is None and len(costs):
        keep = _bridges_inside(ends, pairs, costs, picture, params, deadline)
        pairs, distances, costs = pairs[keep], distances[keep], costs[keep]
    if tips is not None and params.expected_count is None and len(costs):
        keep = tips(pairs, costs, MUTUAL_COST_FACTOR * params.merge_cost_threshold)
        pairs, distances, costs = pairs[keep], distances[keep], costs[keep]
    check(deadline, "merging")
    # Cheapest first, ties by end indices (as sorting (cost, i, j) tuples).
    order = np.lexsort((pairs[:, 1], pairs[:, 0], costs))
    pairs, distances, costs = pairs[order], distances[order], costs[order]
    greedy = len(costs)
    if params.expected_count is None:  # the loop would stop at the first dearer join
        greedy = int(np.searchsorted(costs, params.merge_cost_threshold, side="right"))
    too_open = np.zeros(greedy, bool)
    if open_gap is not None and params.expected_count is None:
        too_open = beyond_hiding(ends, pairs[:greedy], distances[:greedy], radius)
    for index, (cost, i, j) in enumerate(
        zip(costs[:greedy].tolist(), *pairs[:greedy].T.tolist(), strict=True)
    ):
        if index % DEADLINE_CHECK_EVERY == 0:
            check(deadline, "merging")
        if params.expected_count is not None and chains_left <= params.expected_count:
            break
        if too_open[index] and _could_join(i, j) and open_gap(i, j):
            # Longer than anything of the background's own colour hides, over open
            # background: nothing explains the gap.
            continue
        try_join(i, j, cost)
    if params.expected_count is None:
        # A cable bending out of sight under an occluder costs a little more than the
        # limit; when two free ends have no other plausible partner, nothing else can
        # explain either of them, and they are joined up to a looser limit.
        # Ends at the edge of the picture are cables leaving it, never gaps.
        excluded = used if at_border is None else used | (at_border & ~border_ok)
        close = distances <= MUTUAL_GAP_RADII * radius
        if hidden_gap is not None and len(costs):
            # A longer gap only where the image shows something lying over it; looked
            # at only for two free ends that have no cheaper partner they could be
            # joined to (a partner over open background that nothing hides is none).
            open_pair = (costs <= MUTUAL_COST_FACTOR * params.merge_cost_threshold) & ~(
                excluded[pairs[:, 0]] | excluded[pairs[:, 1]]
            )
            cheapest = np.full(len(ends), np.inf)
            for index in np.flatnonzero(open_pair).tolist():  # cheapest first
                i, j = pairs[index].tolist()
                if costs[index] > min(cheapest[i], cheapest[j]):
                    continue
                close[index] = close[index] or hidden_gap(i, j)
                if close[index]:
                    cheapest[i] = cheapest[j] = costs[index]
        near = list(zip(costs[close].tolist(), *pairs[close].T.tolist(), strict=True))
        for cost, i, j in _mutual_best(near, excluded, params.merge_cost_threshold):
            try_join(i, j, cost)
    return joins


def _border_pairs_hidden(pairs, costs, keep, runs_out, at_border, params) -> np.ndarray:
    """Indices of the candidate joins left out only for an end :func:`choose_joins` found
    ``at_border`` whose cable does not run on to the border (not ``runs_out``), within
    the mutual limit: an object lying at the picture's edge may have cut it there."""
    first, second = pairs[:, 0], pairs[:, 1]
    near_edge = at_border[first] | at_border[second]
    runs = runs_out[first] | runs_out[second]
    limit = MUTUAL_COST_FACTOR * params.merge_cost_threshold
    return np.flatnonzero(~keep & near_edge & ~runs & (costs <= limit))


# How many candidate curves :func:`_bridges_inside` draws between looks at the deadline.
DEADLINE_EVERY_CURVES = 64


def _bridges_inside(ends, pairs, costs, picture, params, deadline=None) -> np.ndarray:
    """Which candidate joins' gap curves stay inside the picture (``picture`` is its
    (height, width)): a cable whose hidden stretch would run outside it left the
    picture there, and what it did out of sight cannot be told. Only joins that could
    be made (at most the mutual limit) have their curve drawn."""
    height, width = picture
    keep = np.ones(len(costs), bool)
    limit = MUTUAL_COST_FACTOR * params.merge_cost_threshold
    for count, index in enumerate(np.flatnonzero(costs <= limit).tolist()):
        if count % DEADLINE_EVERY_CURVES == 0:
            # Tens of thousands of candidates on a crowded frame (a large turn's curve,
            # the Euler spiral, takes about half a millisecond): the budget is kept here.
            check(deadline, "merging")
        a, b = ends[pairs[index, 0]], ends[pairs[index, 1]]
        curve = gap_curve(a.position, a.direction, b.position, -b.direction, shape=params.gap_curve)
        keep[index] = bool(
            (curve[:, 0] >= -0.5).all()
            and (curve[:, 1] >= -0.5).all()
            and (curve[:, 0] <= width - 0.5).all()
            and (curve[:, 1] <= height - 0.5).all()
        )
    return keep


# The looser limit of a join between two ends that are each other's only candidate,
# as a multiple of merge_cost_threshold, and how much cheaper than any alternative
# of either end it must be.
MUTUAL_COST_FACTOR = 1.5
MUTUAL_MARGIN = 0.5
# Only short gaps, at most this many radii (five cable widths), get the looser limit:
# an object that hides a cable's bend is about as wide as the bend is tight, while two
# cable tips far apart that merely face each other are not evidence of one cable.
MUTUAL_GAP_RADII = 10.0


def _mutual_best(
    candidates: list[tuple[float, int, int]], used: np.ndarray, threshold: float
) -> list[tuple[float, int, int]]:
    """Pairs of free ends that are each other's clearly cheapest, within the looser limit."""
    best: dict[int, list[tuple[float, int]]] = {}
    for cost, i, j in candidates:
        if used[i] or used[j]:
            continue
        best.setdefault(i, []).append((cost, j))
        best.setdefault(j, []).append((cost, i))
    for options in best.values():
        options.sort()
    pairs = []
    limit = MUTUAL_COST_FACTOR * threshold
    for i, options in best.items():
        cost, j = options[0]
        if j < i or cost > limit or best[j][0][1] != i:
            continue
        rivals = [c for c, _ in options[1:2]] + [c for c, _ in best[j][1:2]]
        if all(rival - cost >= MUTUAL_MARGIN * threshold for rival in rivals):
            pairs.append((cost, i, j))
    return sorted(pairs)


def _ends_of_split_pieces(
    ends: list[ChainEnd],
    pieces: list[np.ndarray],
    touching: TouchingSplit,
    span: float,
    skip: float,
) -> list[ChainEnd]:
    """The ends with those of the pieces :func:`.touching.split_touching_strands` made
    fitted anew (and the new pieces' appended).

    Each strand's fit leaves out the tip's ``skip`` (the cable's radius), as every end's
    does (:func:`chain_ends`): two touching strands going into an object side by side (a
    doubled-back cable turning round under it) end at its border as any cut end does,
    their shared line's tip hooked into the cut's corner, and the strand's line is that
    tip moved to its side. Fitted over the tip, the end keeps the hook's position and
    direction (on 440065 and 450230 the tips lay 4.7-8.3 px off the cable's middle,
    23-30 degrees off its tangent), and an end that left no tip out is never traced to
    its cut (:func:`.cut_ends.bridges_from_the_cuts`): the gap's bridge was drawn from
    the hook. The distance transform is not read for the narrow tips here: the split
    strand's line is the shared line moved across, not where the mask's own narrowing
    was measured."""
    ends = list(ends)
    changed = sorted(set(touching.split) | set(range(len(ends) // 2, len(pieces))))
    fitted = chain_ends([pieces[index] for index in changed], span, skip=skip)
    for local, index in enumerate(changed):
        for side in (0, 1):
            end = replace(fitted[2 * local + side], piece=index)
            if 2 * index + side < len(ends):
                ends[2 * index + side] = end
            else:
                ends.append(end)
    for index, width in touching.strand_widths.items():
        ends[2 * index] = replace(ends[2 * index], width=width)
        ends[2 * index + 1] = replace(ends[2 * index + 1], width=width)
    return ends


def tips_in_junctions(pieces: list[np.ndarray], zones: np.ndarray | None) -> np.ndarray:
    """Per end (piece i: ends 2i, 2i+1), whether the piece's tip joint is in a junction
    zone (as :func:`junctions_of_ends` reaches it)."""
    if zones is None or not pieces:
        return np.zeros(2 * len(pieces), bool)
    # Both tips of every piece, (start, end) in turn, without building ChainEnds.
    tips = np.array([(points[0], points[-1]) for points in pieces], np.float64).reshape(-1, 2)
    # In a zone or not needs no labels, so no fill of the zone's piece: a look round each tip.
    zones_u8 = zones.view(np.uint8) if zones.dtype == np.bool_ else zones.astype(np.uint8)
    return _merging_kernels.on_grown_zones(np.ascontiguousarray(zones_u8), tips, 3)


def junctions_of_ends(ends: list[ChainEnd], zones: np.ndarray, reach: int = 3) -> list[int]:
    """The junction zone each end touches, or -1: the 8-connected pieces of the zones
    grown by a ``2 reach + 1`` square (``cv2.dilate``), numbered in the order the ends
    reach them. Compiled (``_merging_kernels.grown_zone_labels``): only the pieces the
    ends lie in are filled; the plain version, which grows and labels the zones' box,
    is the reference in ``tests/perception/references/merging.py``."""
    if zones is None:
        return [-1] * len(ends)
    positions = np.array([end.position for end in ends], np.float64).reshape(-1, 2)
    return _grown_zone_labels(positions, zones, reach).tolist()


def _grown_zone_labels(positions: np.ndarray, zones: np.ndarray, reach: int = 3) -> np.ndarray:
    """:func:`junctions_of_ends` for ``(E, 2)`` end positions, as an array."""
    zones_u8 = zones.view(np.uint8) if zones.dtype == np.bool_ else zones.astype(np.uint8)
    labels = _merging_kernels.grown_zone_labels(
        np.ascontiguousarray(zones_u8), positions, int(reach)
    )
    return labels


def merge_chains(
    pieces: list[np.ndarray],
    params: DetectParams,
    radius: float,
    zones: np.ndarray | None = None,
    distance: np.ndarray | None = None,
    deadline: Deadline | None = None,
    image: np.ndarray | None = None,
    mask: np.ndarray | None = None,
) -> MergeResult:
    """Step 6 of the pipeline: join pieces into whole DLOs and fill the gaps.

    Parameters
    ----------
    pieces : list of ndarray
        Non-overlapping ``(K, 2)`` joint arrays from pruning.
    params : DetectParams
    radius : float
        Typical cable half width in pixels.
    zones : ndarray of bool, optional
        Junction zones from fitting: the ends that meet in one zone are paired
        together first.
    distance : ndarray, optional
        Distance transform of the mask: end fits then leave out narrow (cut) ends.
    deadline : Deadline, optional
        Checked between the phases and while joins are made
        (:class:`~service.perception.deadline.DeadlineExceeded` past it).
    image : ndarray (H, W, 3) uint8, optional
        The BGR image: joins between ends of clearly different colour cost
        ``params.colour_weight`` more per step of difference (:mod:`.appearance`).
    mask : ndarray of bool, optional
        The foreground: an end whose cable runs on to the picture's border leaves the
        picture and is never joined across a gap.

    Returns
    -------
    MergeResult
        The merged paths (dense polylines with per-edge "filled" flags) and the joins.
    """
    # End tangents are fitted over a few cable widths: long enough to average out
    # the pixel steps of the skeleton, short enough to follow a bending cable.
    span = max(END_FIT_SPAN_PX, END_FIT_SPAN_RADII * radius)
    # The distance transform counts to the nearest background pixel centre, half a
    # pixel beyond the border: the full half width is radius + 0.5.
    full_width = FULL_WIDTH_FRACTION * (radius + 0.5)
    if mask is not None and pieces:
        pieces = split_where_leaving_together(
            pieces, mask, radius, radius + BORDER_MARGIN_PX, BORDER_MARGIN_PX, span
        )
    # An end at a crossing is where the skeleton was cut at the other strand, not a cut
    # end's hook: its fit may stay near the tip, and on a tight loop it must. Fitted over
    # the usual span, a quadratic spans half the loop and puts the end several px off
    # the cable, pointing tens of degrees off, and the crossing's bridge swings out of it.
    at_crossing = tips_in_junctions(pieces, zones)
    ends = chain_ends(
        pieces, span, skip=radius, distance=distance, full_width=full_width, bend_aware=at_crossing
    )
    if mask is not None:
        # A fit over a tight bend may land beside the cable: refitted nearer the tip.
        ends = ends_refitted_onto_the_mask(pieces, ends, mask, span, radius)
    if distance is not None and zones is not None:
        ends = widths_clear_of_crossings(pieces, ends, distance, zones, at_crossing, MIDDLE_JOINTS)
    if mask is not None:
        # A stub's skeleton runs across it, and reads it narrow.
        ends = ends_of_stubs(pieces, ends, mask, radius, distance)
    check(deadline, "merging")
    # Every end's position and direction as arrays, once (until touching strands split).
    end_positions = np.array([end.position for end in ends], np.float64).reshape(-1, 2)
    end_directions = np.array([end.direction for end in ends], np.float64).reshape(-1, 2)
    at_border = None
    if zones is not None or mask is not None:
        at_border = points_out_of_picture(
            end_positions,
            end_directions,
            (zones if zones is not None else mask).shape,
            radius + BORDER_MARGIN_PX,
        )
    leaving = runs_out = None
    if mask is not None and ends:
        leaving = runs_out = _merging_kernels.runs_to_border(
            np.ascontiguousarray(mask, np.bool_),
            end_positions,
            end_directions,
            BORDER_REACH_RADII * radius + BORDER_REACH_PX,
            BORDER_MARGIN_PX,
        )
    if at_border is not None:
        # An end at the picture's edge is a cable leaving it, too.
        leaving = at_border if leaving is None else leaving | at_border
    if zones is not None and ends:
        # The piece was cut at its junction: an end belongs there though its fit,
        # extrapolated over a tip bending into the zone, ends a few px outside it.
        fitted = end_positions
        tips = np.array([(points[0], points[-1]) for points in pieces], np.float64)
        both = _grown_zone_labels(np.concatenate([fitted, tips.reshape(-1, 2)]), zones)
        junction_of_end = np.where(both[: len(ends)] >= 0, both[: len(ends)], both[len(ends) :])
        junction_of_end = junction_of_end.tolist()
    else:
        junction_of_end = junctions_of_ends(ends, zones)
    touching = TouchingSplit(pieces, list(range(len(pieces))), junction_of_end)
    if distance is not None and pieces:
        touching = split_touching_strands(
            pieces,
            end_positions,
            end_directions,
            junction_of_end,
            distance,
            leaving,
        )
    if touching.split:
        # Each strand of a shared stretch is a piece of its own now: new ends for them,
        # and its far ends meet the picture's border where the shared piece's did.
        pieces = touching.pieces
        at_crossing = tips_in_junctions(pieces, zones)
        ends = _ends_of_split_pieces(ends, pieces, touching, span, radius)
        end_positions = np.array([end.position for end in ends], np.float64).reshape(-1, 2)
        end_directions = np.array([end.direction for end in ends], np.float64).reshape(-1, 2)
        from_ends = np.repeat(np.array(touching.origin), 2) * 2 + np.tile([0, 1], len(pieces))
        at_border = None if at_border is None else at_border[from_ends]
        leaving = None if leaving is None else leaving[from_ends]
        runs_out = None if runs_out is None else runs_out[from_ends]
        for flags in (at_border, leaving, runs_out):
            if flags is not None:
                flags[touching.cut_tips] = False  # an object cuts them, not the border
    junction_of_end, dropped, crossing_pairs = absorb_shared_pieces(
        pieces,
        touching.junction_of_end,
        radius,
        distance,
        end_positions,
        end_directions,
        leaving,
    )
    colours = None
    if image is not None and params.colour_weight > 0:
        free = None if zones is None else ~at_crossing.reshape(-1, 2).any(1)
        if free is not None and touching.strand_widths:
            # A short strand parting from a touching stretch is no scrap either (its
            # width said so, :func:`.touching.split_touching_strands`): its whole length.
            free[list(touching.strand_widths)] = True
        own_widths = np.array([end.width for end in ends], np.float64)
        colours = end_colours(image, pieces, ends, radius, distance, free, own_widths)
    picture = None
    if zones is not None or mask is not None:
        picture = (zones if zones is not None else mask).shape[:2]
    hidden_gap = None
    # A strand crossing another just before it passes out of sight is cut beyond the
    # crossing: the image's evidence for its end is read there (:mod:`.crossing_stubs`).
    seen_from = ends
    if zones is not None and mask is not None and ends:
        seen_from = ends_past_crossings(pieces, ends, at_crossing, mask, zones, span)
    if image is not None and mask is not None:

        def hidden_gap(i: int, j: int, curve: np.ndarray | None = None) -> bool:
            # The one test of the image's evidence that something hides a cable between
            # ends i and j, along ``curve`` (the gap's own curve when None): for the
            # joins across gaps and for the turns under objects alike.
            a, b = ends[i], ends[j]
            if curve is None:
                curve = gap_curve(
                    a.position, a.direction, b.position, -b.direction, shape=params.gap_curve
                )
            a, b = seen_from[i], seen_from[j]
            if gap_hidden(image, mask, curve, (a, b), radius):
                return True
            return cut_ends_alike(a, b, i, j, curve, mask, colours, radius, image=image)

    open_gap = None
    if hidden_gap is not None:

        def open_gap(i: int, j: int) -> bool:
            a, b = ends[i], ends[j]
            curve = gap_curve(
                a.position, a.direction, b.position, -b.direction, shape=params.gap_curve
            )
            limit = float(open_gap_limit(radius, a.width, b.width))
            return open_gap_too_long(curve, mask, limit, lambda: hidden_gap(i, j, curve))

    joins = choose_joins(
        ends,
        len(pieces),
        params,
        radius,
        junction_of_end,
        at_border,
        deadline,
        colours,
        leaving,
        picture,
        touching.pairs + crossing_pairs,
        hidden_gap,
        runs_out,
        open_gap,
        keep_turns_free(own_tips_rule(ends, mask, hidden_gap), touching.turns),
        lambda made: free_ends_beside_crossings(pieces, ends, made, span, junction_of_end),
    )
    turn_bridges: dict[tuple[int, int], np.ndarray] = {}
    depth_bounded: dict[tuple[int, int], Callable] = {}
    turn_hidden = None
    turn_pairs: frozenset[tuple[int, int]] = frozenset()
    if hidden_gap is not None and params.expected_count is None and ends:
        # Sharp turns under an object, on the image's evidence (:mod:`.turn_joins`); a
        # scrap joined through its crossing is judged as the strand it continues.
        mutual = MUTUAL_COST_FACTOR * params.merge_cost_threshold
        seen, hues = scraps_through_junctions(
            ends,
            colours,
            joins,
            junction_of_end,
            pieces,
            radius,
            MIDDLE_JOINTS,
            frozenset(touching.pairs),
        )
        widths = np.array([end.width for end in seen], np.float64)
        judged = evidence_ends(seen, ends, seen_from)
        turn_hidden = turn_out_of_view(image, mask, seen, radius)
        turned = turn_joins(
            seen,
            joins,
            ~leaving & ~np.isin([end.piece for end in ends], sorted(dropped)),
            radius,
            hues,
            lambda i, j: (
                join_cost(ends[i], ends[j], params, radius)
                + params.colour_weight * float(colour_penalty(hues, [i], [j])[0])
            ),
            turn_evidence(image, mask, judged, hues, radius, set(touching.partings))
            + traced_cut_tests(judged, mask, hues, radius, image, pieces, distance),
            lambda i, j: open_gap_limit(radius, widths[i], widths[j]),
            mutual,
            mutual,
            MAX_JUNCTION_ENDS,
            turn_bridges,
            TURN_EVIDENCE_ALONG_CURVE,
            turn_hidden,
            distance,
            turn_hiding_extent(image, mask, seen, radius),
            turns_within_outlines(image, mask, seen) if image is not None else None,
            depth_bounded,
        )
        joins = joins + turned
        turn_pairs = frozenset((i, j) for i, j, _ in turned)
    check(deadline, "merging")
    # A dropped piece's ends are never joined, so it would come out alone: skip it.
    bridges = {**touching.bridges, **turn_bridges}
    curve_given = frozenset(end for pair in bridges for end in pair)
    # A gap from a crossing's end whose strand runs on as a stub to the object.
    fronts = stub_fronts(pieces, joins, junction_of_end, ends, seen_from, curve_given)
    inner_ends, trims = bridge_from_the_fits(
        pieces, ends, joins, span, junction_of_end, distance, radius, curve_given, frozenset(fronts)
    )
    inner_ends = ends_of_short_pieces_from_partners(
        pieces, inner_ends, joins, span, junction_of_end
    )
    if mask is not None:
        inner_ends = ends_along_straight_sides(
            pieces, inner_ends, joins, junction_of_end, mask, span, curve_given
        )
    bridging_ends = ends_through_short_pieces(
        pieces, inner_ends, joins, span, junction_of_end, turn_pairs
    )
    if mask is not None:
        # A short piece's skeleton tip lies in the cut's corner: its bridges leave the
        # cable's middle at the cut instead.
        bridging_ends = short_ends_at_cut_middles(
            pieces, ends, bridging_ends, joins, junction_of_end, mask, radius, span, curve_given
        )
        # A gap's bridge leaves the cable where it passes out of sight, not where the
        # end's fit begins a radius or two before (on a tight bend, 30-60 degrees back).
        # A turn under an object whose strands lie far enough apart to turn round in
        # one arc: the cuts say where and which way the cable passes out of sight.
        wide_turns = frozenset(
            (i, j)
            for i, j in turn_bridges
            if np.hypot(*(ends[i].position - ends[j].position))
            >= 2.0 * HIDDEN_BEND_RADII[0] * (0.5 * (ends[i].width + ends[j].width) or radius)
        )
        cut_bridges = bridges_from_the_cuts(
            bridging_ends,
            joins,
            junction_of_end,
            mask,
            radius,
            curve_given,
            params.gap_curve,
            wide_turns,
            {
                k: (pieces[end.piece], inner_ends[k].width)
                for k, end in enumerate(bridging_ends)
                if end is not inner_ends[k]
            },
            unfitted_pieces(pieces, bridging_ends, ends, joins, junction_of_end, fronts),
            image,
            fronts,
        )
        if turn_hidden is not None:
            cut_bridges = {
                pair: curve
                for pair, curve in cut_bridges.items()
                if not cut_bridge_gives_way(
                    pair, curve, turn_bridges, wide_turns, turn_hidden, depth_bounded
                )
            }
        bridges = {**bridges, **cut_bridges}
    assembled = assemble_paths(pieces, bridging_ends, joins, params.gap_curve, trims, bridges)
    paths = [p for p in assembled if p.pieces[0] not in dropped]
    paths = [path for path in paths if polyline_length(path.vertices) > 0]
    return MergeResult(paths, [Join(ends[i], ends[j], cost) for i, j, cost in joins])
