"""Joins where a cable turns sharply out of sight: a U-turn or a tight bend under an object.

The join cost (:func:`.merging.join_cost`) charges for the turn between two ends'
directions, as it must: two free ends that point the same way side by side are, on
geometry alone, two cables. But a cable that turns by 90-180 degrees under an occluder
leaves exactly that: two ends of one cable that both point into the same object. Such a
join is made here only on the image's evidence, after every other join
(:func:`turn_joins`):

- a curve a cable could have taken between the two ends, bending no tighter than
  :data:`HIDDEN_BEND_RADII` ``[0]`` of its radius, exists, and the image says
  something hides a cable along it (``evidence``, the merging step's tests, strongest
  first: an object shows over the curve, :func:`.appearance.gap_hidden`; both ends are
  cut square and alike and the curve no longer than an object of the background's own
  colour hides, :func:`.gap_evidence.cut_ends_alike`; one end cut square and the other
  lopsided, as where an object's corner or rim cuts a strand that bends into the
  turn): not open background beyond two round tips, which is what lies beyond two
  cables that end side by side. The curves tried (:func:`hidden_turn_curves`) are the
  natural curve (:func:`natural_turn`) and the bulbs a cable doubled back on itself
  swings out into, turning round by up to :data:`MAX_HIDDEN_TURN` (:func:`bulb_turns`),
  from the ends' fitted directions and from tilted ones (from each end's tip where the
  cable is seen whole and straight up to it, else from where its fit begins:
  :func:`_turn_leaves_at`); the join is bridged along the
  shortest curve the strongest test passes (a curve an object is seen over before the
  shortest the ends' cuts allow; under an object, the shortest that bends as a cable does
  and along which the object hides a cable's whole tube, of every curve built:
  :func:`_likeliest_shape`), except that a turn seen on the cuts alone, its strands
  far enough apart to turn round in one arc, is bridged as any gap is (the cuts say
  nothing of the curve's shape, :mod:`.bridge_ends`);
- the two pieces agree in colour and width (:func:`.appearance.ends_alike`);
- neither end has a better partner: the turns and every free pair of alike ends the
  merging step could have joined without evidence are paired together by the cheapest
  matching, each end left free at an explicit cost (:func:`.pairing.cheapest_pairing`),
  and only the turns it chooses are made.

A free pair cheap enough for merging to have joined on geometry alone, left free because
the evidence failed along its gap's one curve (a gap whose object cut one end at a
slant), is tried here as well, with the turns' curves and tests.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from functools import partial
from itertools import chain, islice
from typing import NamedTuple

import numpy as np

from service.perception.appearance import EndColours, ends_alike
from service.perception.geometry import reach_along, rotated
from service.perception.pairing import Components, cheapest_pairing

NEAR_U_TURN = 0.75 * np.pi
"""Turns sharper than this (radians) may have gone either way round (:func:`natural_turn`)."""
HIDDEN_BEND_RADII = (2.0, 2.5, 3.0, 4.0, 5.0)
"""Bend radii (cable radii) of the turns tried out of sight (:func:`hidden_turn_curves`):
the first, the tightest a cable takes, bounds every arc; the bulbs take each."""
MAX_HIDDEN_TURN = np.radians(300.0)
"""The most a bulb's round arc turns (radians): a cable doubled back on itself swings
out and round by more than a half turn, but not into a loop that crosses itself."""
BULB_STEP = np.radians(6.0)
"""Steps of a bulb's outward swing (radians) tried."""
BULB_TOLERANCE_RADII = 0.15
"""A bulb reaches the second end when it passes within this share of its bend radius."""
DIRECTION_SLACK = np.radians(30.0)
"""How far (radians) a cut end's fitted direction may be from the cable's where it
disappears: the end of a piece bending into the turn, and the hook a slanted cut leaves."""
DIRECTION_TILTS = [(0.0, 0.0)] + [
    (first * DIRECTION_SLACK, last * DIRECTION_SLACK)
    for first in (-1.0, 0.0, 1.0)
    for last in (-1.0, 0.0, 1.0)
    if first or last
]
"""The tilts of the two ends' directions tried."""
BULB_REACH_RADII = 4.0 * HIDDEN_BEND_RADII[-1]
"""Ends further apart than this (cable radii) turn round in room enough for a natural
curve: no bulbs, and no tilts, are tried for them."""
BULB_MIN_TURN = 0.5 * np.pi
"""Ends whose fitted directions turn by less than this (radians) are not doubled back:
no bulbs, and no tilts, are tried for them."""
MAX_TURN_TRIALS = 8
"""The most curves (the shortest) tried for one pair of ends."""
PIXEL_ROUNDING = 1.0
"""How far (px) the mask's distance transform at a point on a cable's middle may fall
short of its half width for the pixel grid alone (:func:`_turn_leaves_at`)."""
WHOLE_TUBE_OUT_OF_VIEW = 2
"""What a turn's ``out_of_view`` test gives a curve a cable's whole tube along which the
object seen over the turn hides (1: its middle alone): the most a curve may be hidden."""
KINK_SHARE = 0.75
"""A curve whose samples bend, over a stretch one cable radius long, tighter than this
share of the tightest bend a cable takes (:data:`HIDDEN_BEND_RADII` ``[0]``) has a kink
(:func:`bends_as_a_cable`). The arcs the curves are built of measure 0.95 of their radius
and more on their samples; a bulb closing the miss to the second end
(:data:`BULB_TOLERANCE_RADII`) in one step, 0.7 and less."""


def natural_turn(
    start: np.ndarray,
    leaving: np.ndarray,
    end: np.ndarray,
    arriving: np.ndarray,
    min_radius: float,
    step: float = 1.0,
    turn: float | None = None,
) -> np.ndarray | None:
    """The natural curve (Keipour et al.'s gap curve) of a turn no tighter than a cable
    takes: from ``start`` straight along ``leaving``, one arc of radius at least
    ``min_radius``, straight along ``arriving`` to ``end`` (straight stretches of length
    >= 0), with the tightest such arc (the shortest curve that keeps to the limit).

    Near a U-turn the fitted directions cannot tell which way round the cable turned,
    and both ways are tried (the shorter curve wins). A U-turn's arc is the half circle
    across the two ends' offset.

    Returns
    -------
    ndarray or None
        ``(M, 2)`` samples about ``step`` apart from ``start`` to ``end``; None when no
        such curve exists (an S-shaped gap, a turn away from the other end, a U-turn
        narrower than twice ``min_radius``) or the ends do not turn. Given ``turn``
        (signed, radians: which way round), only that way is tried.
    """
    leaving = np.asarray(leaving, np.float64)
    arriving = np.asarray(arriving, np.float64)
    start = np.asarray(start, np.float64)
    offset = np.asarray(end, np.float64) - start
    if turn is not None:
        readings = [turn]
    else:
        turn = float(np.arctan2(*_cross_dot(leaving, arriving)))
        readings = [turn]
        if abs(turn) > NEAR_U_TURN:
            readings.append(turn - np.copysign(2 * np.pi, turn))
    if abs(turn) < 1e-6:
        return None
    best = None
    for reading in readings:
        shape = _arc_shape(offset, leaving, arriving, reading, min_radius)
        if shape is not None and (best is None or shape[0] < best[0]):
            best = (*shape, reading)
    if best is None:
        return None
    _, first, radius, last, reading = best
    side = np.sign(reading) * np.array([-leaving[1], leaving[0]])
    corner = start + first * leaving
    centre = corner + radius * side
    parts = [start + np.outer(np.arange(0.0, first, step), leaving)]
    angles = np.arange(0.0, abs(reading), step / radius)
    parts.append(
        centre + radius * (np.outer(np.sin(angles), leaving) - np.outer(np.cos(angles), side))
    )
    leave_arc = centre + radius * (np.sin(abs(reading)) * leaving - np.cos(abs(reading)) * side)
    parts.append(leave_arc + np.outer(np.arange(0.0, last, step), arriving))
    parts.append(np.asarray(end, np.float64)[None])
    return np.concatenate(parts)


def _arc_shape(offset, leaving, arriving, turn, min_radius):
    """(length, first straight, radius, last straight) of the natural curve of one way
    round (``turn``, signed, radians) with the tightest arc of at least ``min_radius``,
    or None."""
    side = np.sign(turn) * np.array([-leaving[1], leaving[0]])  # towards the turn
    # The arc of radius R moves R (sin |turn| leaving + (1 - cos |turn|) side).
    per_radius = np.sin(abs(turn)) * leaving + (1.0 - np.cos(abs(turn))) * side
    if abs(np.sin(turn)) < 1e-3:  # a U-turn: the offset across is the half circle's width
        radius = 0.5 * float(offset @ side)
        along = float(offset @ leaving)
        first, last = max(along, 0.0), max(-along, 0.0)
    else:
        basis = np.column_stack([leaving, arriving])
        straight = np.linalg.solve(basis, offset)  # the stretches with no arc
        shrink = np.linalg.solve(basis, per_radius)  # how each shortens per unit radius
        low, high = min_radius, float("inf")
        for length, rate in zip(straight, shrink, strict=True):
            if rate > 1e-12:
                high = min(high, length / rate)
            elif rate < -1e-12:
                low = max(low, length / rate)
            elif length < 0:
                return None
        if low > high:
            return None
        radius = low
        first, last = (straight - radius * shrink).tolist()
    if radius < min_radius or first < -1e-6 or last < -1e-6:
        return None
    first, last = max(first, 0.0), max(last, 0.0)
    return first + radius * abs(turn) + last, first, radius, last


def hidden_turn_curves(
    start: np.ndarray,
    leaving: np.ndarray,
    end: np.ndarray,
    arriving: np.ndarray,
    cable_radius: float,
    step: float = 1.0,
    limit: int | None = MAX_TURN_TRIALS,
) -> Iterator[np.ndarray]:
    """The shapes a cable may have taken between two ends where it turned out of sight,
    shortest (most compact) first: the join is made when something lies over any one.

    A cable bends no tighter than :data:`HIDDEN_BEND_RADII` ``[0]`` of its radius. Where
    the two ends lie closer side by side than twice that (a cable doubled back on
    itself, its strands touching), it cannot turn round in one arc: it swings out into a
    bulb, bending away from the other strand, round by more than a half turn, and away
    again (:func:`bulb_turns`). So the candidates are, for each way round the cable may
    have turned (both near a U-turn, :data:`NEAR_U_TURN`, and, for ends close enough for
    a bulb, wherever the long way round turns no more than :data:`MAX_HIDDEN_TURN`:
    strands that already swing apart where they pass out of sight point away from each
    other, and only the long way reaches, :func:`_long_way_round`): the natural curve with the
    tightest arc allowed (:func:`natural_turn`), and a bulb of each bend radius in
    :data:`HIDDEN_BEND_RADII`, the round arc turning at most :data:`MAX_HIDDEN_TURN`.
    A cut end's fitted direction is uncertain where the piece already bends into the
    turn, or a slanted cut leaves a hook, so each is also tried tilted
    (:data:`DIRECTION_TILTS`). Ends further apart than :data:`BULB_REACH_RADII`, or
    turning by less than :data:`BULB_MIN_TURN` the short way and by more than
    :data:`MAX_HIDDEN_TURN` the long way with one direction tilted towards it, get the
    natural curves alone. At most ``limit`` (:data:`MAX_TURN_TRIALS`; None: every one)
    distinct curves are yielded, lazily: a pair whose first curve is hidden is tested
    once.

    Parameters
    ----------
    start, leaving : array_like (2,)
        The first end and its direction out of the piece (unit).
    end, arriving : array_like (2,)
        The second end and the direction the cable arrives there in (unit, into it).
    cable_radius : float
        The cable's half width (px).
    step : float
        Sample spacing (px).
    limit : int or None
        The most curves yielded.
    """
    apart = float(np.hypot(*(np.asarray(end, np.float64) - np.asarray(start, np.float64))))
    fitted_turn = abs(float(np.arctan2(*_cross_dot(leaving, arriving))))
    # The long way round turns by more than a half turn: doubled back, whatever the
    # short way's turn.
    doubled_back = fitted_turn >= BULB_MIN_TURN or _long_way_round(fitted_turn, DIRECTION_SLACK)
    near = apart <= BULB_REACH_RADII * cable_radius and doubled_back
    curves = []
    for tilt_first, tilt_last in DIRECTION_TILTS if near else DIRECTION_TILTS[:1]:
        first = rotated(leaving, tilt_first)
        last = rotated(arriving, tilt_last)
        turn = float(np.arctan2(*_cross_dot(first, last)))
        if abs(turn) < 1e-6:
            continue
        readings = [turn]
        if abs(turn) > NEAR_U_TURN or (near and _long_way_round(abs(turn))):
            readings.append(turn - np.copysign(2 * np.pi, turn))
        for reading in readings:
            tightest = HIDDEN_BEND_RADII[0] * cable_radius
            curve = natural_turn(start, first, end, last, tightest, step, reading)
            if curve is not None:
                curves.append((len(curve), curve))
            if near:
                bends = [radii * cable_radius for radii in HIDDEN_BEND_RADII]
                for length, segments in _bulb_shapes(start, first, end, last, reading, bends):
                    curves.append((length / step, (first, segments)))
    seen: list[np.ndarray] = []
    for _, curve in sorted(curves, key=lambda item: item[0]):
        if len(seen) == limit:
            return
        if isinstance(curve, tuple):
            curve = _trace_to(start, curve[0], end, curve[1], step)
        if any(len(curve) == len(other) and np.allclose(curve, other, atol=1.0) for other in seen):
            continue
        seen.append(curve)
        yield curve


def _long_way_round(turn: float, slack: float = 0.0) -> bool:
    """Whether a cable whose ends' directions turn by ``turn`` (radians, unsigned, the
    short way) may have turned the long way round out of sight, by ``2 pi - turn``: no
    more than :data:`MAX_HIDDEN_TURN`, the directions read up to ``slack`` (radians)
    off. A doubled-back cable whose strands already swing apart where they pass out of
    sight (the bulb's first bend seen) leaves two ends pointing apart, the short way a
    turn away from each other that no curve reaches.

    The fitted directions are given one end's slack (:data:`DIRECTION_SLACK`), not
    both ends': with both, two ends side by side pointing the same way (a cable that
    would have looped round whole, crossing itself) would pass, as two pieces of one
    cable passing under an object do (occluded 86078: the long way round paired the
    wrong ends there)."""
    return 2.0 * np.pi - turn - slack <= MAX_HIDDEN_TURN


def tightest_bend(curve: np.ndarray, window: float) -> float:
    """The smallest radius (px) the polyline ``curve`` bends at: over every stretch of
    at least ``window`` px of arc (from one step's start to a later step's), the
    stretch's length over the angle its steps' headings turn by; ``inf`` for a curve
    shorter than ``window`` or turning nowhere."""
    steps = np.diff(np.asarray(curve, np.float64), axis=0)
    lengths = np.hypot(*steps.T)
    moving = lengths > 1e-9
    steps, lengths = steps[moving], lengths[moving]
    if len(steps) < 2:
        return float("inf")
    headings = np.unwrap(np.arctan2(steps[:, 1], steps[:, 0]))
    arc = np.concatenate([[0.0], np.cumsum(lengths)])
    # For each step, the first later step whose start lies ``window`` past its own.
    later = np.searchsorted(arc, arc[:-1] + window)
    within = later < len(steps)
    first = np.flatnonzero(within)
    if not len(first):
        return float("inf")
    last = later[within]
    turned = np.abs(headings[last] - headings[first])
    spans = arc[last] - arc[first]
    bending = turned > 1e-12
    if not bending.any():
        return float("inf")
    return float(np.min(spans[bending] / turned[bending]))


def bends_as_a_cable(curve: np.ndarray, cable_radius: float) -> bool:
    """Whether ``curve`` bends nowhere tighter than a cable of half width
    ``cable_radius`` takes (:data:`HIDDEN_BEND_RADII` ``[0]``, measured over a radius,
    :data:`KINK_SHARE`): not a bulb that meets the second end with a kink."""
    tightest = KINK_SHARE * HIDDEN_BEND_RADII[0] * cable_radius
    return tightest_bend(curve, cable_radius) >= tightest


def turns_round_in_one_arc(
    first: np.ndarray,
    first_heading: np.ndarray,
    second: np.ndarray,
    second_heading: np.ndarray,
    cable_radius: float,
) -> bool:
    """Whether a cable turning out of sight from ``first`` to ``second`` (points, each
    with its heading out of its strand, into the gap) has room to turn round in one arc
    no tighter than it bends (:data:`HIDDEN_BEND_RADII` ``[0]`` of ``cable_radius``);
    where it has not, it swings out into a bulb.

    A cable turning round by a half turn in one arc of radius ``R`` spans ``2 R``
    across its strands' direction, whatever the stretch of straight strand before the
    arc: two strands doubled back (their headings within a quarter turn of each other,
    :data:`BULB_MIN_TURN`, both into the object) need to lie twice the tightest bend
    apart ACROSS their mean heading, not merely end that far apart. Where one strand
    runs on past the other's cut (the cuts staggered along the strands), the ends lie
    far apart while the strands beside each other are too close for one arc: a bulb.
    Ends that do not turn back on each other keep the plain spacing."""
    offset = np.asarray(second, np.float64) - np.asarray(first, np.float64)
    room = 2.0 * HIDDEN_BEND_RADII[0] * cable_radius
    if float(np.hypot(*offset)) < room:
        return False
    heading = np.asarray(first_heading, np.float64) + np.asarray(second_heading, np.float64)
    length = float(np.hypot(*heading))
    # Two unit headings within BULB_MIN_TURN of a half turn of each other's reverse
    # (a turn of at least BULB_MIN_TURN) sum to at least 2 cos(half the rest).
    if length < 2.0 * np.cos(0.5 * (np.pi - BULB_MIN_TURN)):
        return True
    across = abs(float(offset[0] * heading[1] - offset[1] * heading[0])) / length
    return across >= room


def _likeliest_shape(
    first: np.ndarray,
    others: Iterator[np.ndarray],
    cable_radius: float,
    out_of_view: Callable[[np.ndarray], int] | None,
    leads: tuple[int, int] = (0, 0),
    among: Callable[[list[np.ndarray]], np.ndarray] | None = None,
) -> np.ndarray:
    """Of the curves a test passes on, shortest first (``first``, then ``others``,
    drawn only while needed), the one a hidden cable most likely took: the first that
    lies out of view all the way (``out_of_view``, when given: the cable is not where
    the image shows open background; how much of it, :data:`WHOLE_TUBE_OUT_OF_VIEW`
    the most: its whole tube, then its middle alone) and bends as a cable does
    (:func:`bends_as_a_cable`: a bulb meeting the second end with a kink is no cable's
    shape); failing both, the first most out of view; failing that, the first that
    bends as a cable does; else ``first``.

    ``leads`` (samples) are each curve's straight lead-in and tail (:func:`_led_in`),
    left out of the kink test: they run along the ends' fits over the strands' seen
    tips, and a curve tilted at its start (:data:`DIRECTION_TILTS`, the fit's direction
    read up to :data:`DIRECTION_SLACK` off) meets its lead-in at a corner of the tilt
    itself, the fit's uncertainty, not a bend of the hidden cable.

    ``among``, when given, chooses among every curve hidden whole and bending as a cable
    does (all of them drawn, shortest first), not the shortest of them: where the
    object's outline says how deep the turn may go (:func:`_nearest_the_middle_depth`)."""
    lead, tail = leads

    def rank(curve: np.ndarray) -> tuple[int, bool]:
        hidden = WHOLE_TUBE_OUT_OF_VIEW if out_of_view is None else int(out_of_view(curve))
        return hidden, bends_as_a_cable(curve[lead : len(curve) - tail], cable_radius)

    held_whole = (WHOLE_TUBE_OUT_OF_VIEW, True)
    best, best_rank = first, rank(first)
    held = [first] if best_rank == held_whole else []
    while among is not None or best_rank != held_whole:
        curve = next(others, None)
        if curve is None:
            break
        curve_rank = rank(curve)
        if curve_rank == held_whole:
            held.append(curve)
        if curve_rank > best_rank:
            best, best_rank = curve, curve_rank
    return among(held) if among is not None and len(held) > 1 else best


def _nearest_the_middle_depth(
    held: list[np.ndarray],
    origin: np.ndarray,
    axis: np.ndarray,
    extent: Callable[[], tuple[float, float] | None],
    cable_radius: float,
) -> np.ndarray:
    """Of the curves a region hides whole (``held``, shortest first), the one whose apex
    lies nearest the middle of the region's depth past the cuts.

    A doubled-back cable passing under a region's near rim (its two cuts on the rim)
    turns round out of sight somewhere under it: the most compact curve is the
    shallowest turn the cable's tightest bend allows, and deeper ones are hidden as
    well, up to the region's far rim. Where in between the turn lies nothing seen says:
    the middle of the region's depth halves the worst error. Depth is read along
    ``axis`` (unit: the strands' common direction out into the turn) from ``origin``
    (the cuts' midpoint): ``extent()`` is how far the region reaches behind the origin
    and ahead of it (px; None: not known), and its middle lies half the reach ahead.

    The shortest curve is kept where it already reaches the middle (the cable's bend
    allows no shallower turn), where the extent is not known, and where the region
    reaches behind the cuts by more than the cable's half width ``cable_radius`` (the
    cuts' midpoint lies off the near rim by no more than that on a rim slanting across
    the strands): there the strands pass out from under the region's sides, not its near
    rim, and its depth on the axis does not bound the turn from the cuts on.

    ``extent`` is the region's outline read on the axis: the object's, where it shows
    unlike the ground (:func:`.gap_evidence.turn_hiding_extent`); any other reading of
    where the region that hides the turn stops (a faint outline of an object of the
    ground's colour) would give the same two numbers."""
    reach = extent()
    if reach is None or reach[0] > cable_radius:
        return held[0]
    middle = 0.5 * reach[1]
    apexes = np.array([reach_along(curve, origin, axis) for curve in held])
    if apexes[0] >= middle:
        return held[0]
    return held[int(np.argmin(np.abs(apexes - middle)))]


def _apex_off_the_middle(
    curve: np.ndarray,
    origin: np.ndarray,
    axis: np.ndarray,
    extent: Callable[[], tuple[float, float]],
) -> float:
    """How far (px) ``curve``'s apex lies from the middle of the depth the region that
    hides it allows past the cuts (half its reach ahead of ``origin`` along ``axis``,
    ``extent()``: :func:`_nearest_the_middle_depth`): the measure the turn's curve was
    chosen by, for any other curve of the same turn."""
    return abs(reach_along(curve, origin, axis) - 0.5 * extent()[1])


class _DepthChoice(NamedTuple):
    """How the object's depth chooses a turn's curve (:func:`_by_depth`)."""

    choose: Callable[[list[np.ndarray]], np.ndarray]
    """Of the curves the object hides whole, the one to take
    (:func:`_nearest_the_middle_depth`)."""
    off_the_middle: Callable[[np.ndarray], float]
    """How far (px) a curve's apex lies from the middle of that depth
    (:func:`_apex_off_the_middle`): the measure ``choose`` chose by."""


def _by_depth(a, b, cable: float, hiding_extent) -> _DepthChoice | None:
    """The choice among the curves an object hides whole for a turn from end ``a`` to
    end ``b`` (:class:`.merging.ChainEnd`; ``cable``: the cable's half width) by how deep
    the object lets it go (:func:`_nearest_the_middle_depth`), with ``hiding_extent``
    ``(origin, axis) -> (behind, ahead) or None`` the object's reach on that line, and
    the measure it chose by; None (the shortest) without it, or where the strands are
    not doubled back (turning by less than :data:`BULB_MIN_TURN`: no common direction
    out into the turn to read its depth along)."""
    if hiding_extent is None:
        return None
    axis = np.asarray(a.direction, np.float64) + np.asarray(b.direction, np.float64)
    length = float(np.hypot(*axis))
    # The ends point out into the turn: a turn of BULB_MIN_TURN or more between a's
    # direction and b's reversed leaves their directions at most a quarter turn apart.
    if float(np.dot(a.direction, b.direction)) < np.cos(np.pi - BULB_MIN_TURN) or length < 1e-9:
        return None
    axis /= length
    origin = 0.5 * (np.asarray(a.position, np.float64) + np.asarray(b.position, np.float64))
    # Read the object's reach first: where it does not bound the turn the shortest curve
    # is the choice, and the curves past it need not all be built and tested.
    reach = hiding_extent(origin, axis)
    if reach is None or reach[0] > cable:
        return None
    return _DepthChoice(
        partial(
            _nearest_the_middle_depth,
            origin=origin,
            axis=axis,
            extent=lambda: reach,
            cable_radius=cable,
        ),
        partial(_apex_off_the_middle, origin=origin, axis=axis, extent=lambda: reach),
    )


def _within_outline(within_outline, i: int, j: int, compact, candidates, tried):
    """``within_outline``'s curve for the turn from end ``i`` to end ``j`` (None: the
    image shows no outline), of every curve :func:`hidden_turn_curves` builds (drawn
    into ``tried`` from ``candidates``): the outline, not the order of compactness,
    bounds the turn. The curves are drawn only once an outline is read: most turns
    show none, and building all of them costs more than reading it."""

    def every_curve() -> list[np.ndarray]:
        for _ in candidates:
            pass
        return tried

    return within_outline(i, j, compact, every_curve)


def _turn_leaves_at(end, distance, cable: float) -> np.ndarray:
    """Where a turn out of sight leaves ``end``'s strand (:class:`.merging.ChainEnd`):
    its tip, where the cable is seen whole and straight along the fit's line from where
    the fit begins; else (or without ``distance``) where the fit begins.

    An end's fit leaves out its tip (``skip``: a radius at least, more over a cut's
    hook). Where the cable is seen straight up to the tip, it runs on that far: a turn
    drawn from where the fit begins swings out of the strand before the tip, where the
    cable would show, and its most compact bulb falls short of the hidden turn. The
    cable is seen whole and straight there when the mask's distance transform
    (``distance``) along the fit's line keeps to the cable's half width ``cable`` (less
    a pixel's rounding) up to a half width before the tip, where a square cut's own face
    comes near, and the line stays on the mask up to the tip. Where the line drifts off
    the middle sooner, the strand bends away from its fit (into the turn, or into a
    cut's hook), or an object's rim has already taken one side of it (a slanted cut,
    whose wedge of mask may run on past where the cable turns): the turn is drawn from
    where the fit begins, as the other hidden turns."""
    start = end.position - end.skip * end.direction
    if distance is None or end.skip <= 0:
        return start
    height, width = distance.shape[:2]
    along = np.append(np.arange(0.0, end.skip, 1.0), end.skip)
    points = start + np.outer(along, end.direction)
    cols, rows = np.rint(points[:, 0]).astype(np.int64), np.rint(points[:, 1]).astype(np.int64)
    if not ((cols >= 0) & (cols < width) & (rows >= 0) & (rows < height)).all():
        return start
    depth = distance[rows, cols]
    before_the_cut = along <= end.skip - cable
    if (depth <= 0).any() or (depth[before_the_cut] < cable - PIXEL_ROUNDING).any():
        return start
    return end.position


def _led_in(
    curves: Iterator[np.ndarray], first: np.ndarray, last: np.ndarray, step: float = 1.0
) -> Iterator[np.ndarray]:
    """Each of ``curves`` led in straight from ``first`` and out straight to ``last``
    (where the two ends' fits begin: the bridge starts there)."""
    for curve in curves:
        lead = _straight(first, curve[0], step)
        tail = _straight(curve[-1], last, step)
        yield np.concatenate([lead, curve, tail[1:], np.asarray(last, np.float64)[None]])


def _straight(start: np.ndarray, stop: np.ndarray, step: float) -> np.ndarray:
    """Samples about ``step`` apart from ``start`` up to (not including) ``stop``."""
    start = np.asarray(start, np.float64)
    offset = np.asarray(stop, np.float64) - start
    length = float(np.hypot(*offset))
    if length < 1e-9:
        return start[None][:0]
    along = np.arange(0.0, length, step)
    return start + np.outer(along / length, offset)


def _cached(curves: Iterator[np.ndarray], tried: list[np.ndarray]) -> Iterator[np.ndarray]:
    """The curves in ``tried``, then the rest of ``curves``, each kept in ``tried``: the
    curves are drawn lazily and once, however many tests ask for them."""
    yield from tried
    for curve in curves:
        tried.append(curve)
        yield curve


def bulb_turns(
    start: np.ndarray,
    leaving: np.ndarray,
    end: np.ndarray,
    arriving: np.ndarray,
    turn: float,
    bends: list[float],
    step: float = 1.0,
) -> list[np.ndarray]:
    """Turns through a bulb, one for each bend radius in ``bends`` that has one: from
    ``start`` straight along ``leaving``, an arc of radius ``bend`` away from the turn by
    ``psi_1``, one of the same radius round by ``|turn| + psi_1 + psi_2``, away again
    by ``psi_2``, and straight along ``arriving`` to ``end`` (straight stretches of
    length >= 0, neither longer than the ends are apart plus ``bend``: that would carry
    the cable past the other end). Of the swings (0 up to what keeps the round arc
    within :data:`MAX_HIDDEN_TURN`, in steps of :data:`BULB_STEP`) that reach ``end`` to
    within :data:`BULB_TOLERANCE_RADII` of ``bend``, the shortest curve (the most
    compact: what fits under the smallest object).

    This is how a cable turns round between two strands closer than twice its tightest
    bend (the round arc swings out past both; one strand may already have begun its
    swing where it disappears, so the two swings differ), and, with no swing, a natural
    curve whose arc has radius ``bend`` exactly (not the tightest, as
    :func:`natural_turn`).

    Parameters
    ----------
    turn : float
        The signed turn (radians) from ``leaving`` to ``arriving`` the cable makes: which
        way round it goes.
    bends : list of float
        Bend radii (px).

    Returns
    -------
    list of ndarray
        ``(M, 2)`` samples about ``step`` apart from ``start`` to ``end``.
    """
    return [
        _trace_to(start, leaving, end, segments, step)
        for _, segments in _bulb_shapes(start, leaving, end, arriving, turn, bends)
    ]


def _trace_to(start, leaving, end, segments, step: float) -> np.ndarray:
    """:func:`_trace` from ``start`` along ``leaving``, ending exactly at ``end``."""
    curve = _trace(complex(*np.asarray(start, np.float64)), complex(*leaving), segments, step)
    return np.concatenate([curve, np.asarray(end, np.float64)[None]])


def _bulb_shapes(start, leaving, end, arriving, turn: float, bends: list[float]):
    """The bulbs of :func:`bulb_turns` as (length, segments): straight and circular
    segments (length, signed curvature) from ``start`` along ``leaving``."""
    if abs(turn) < 1e-6 or abs(turn) > MAX_HIDDEN_TURN:
        return []
    leaving = complex(*np.asarray(leaving, np.float64))
    arriving = complex(*np.asarray(arriving, np.float64))
    offset = complex(*np.asarray(end, np.float64)) - complex(*np.asarray(start, np.float64))
    side = np.sign(turn)
    swings = np.arange(0.0, MAX_HIDDEN_TURN - abs(turn) + 1e-9, BULB_STEP)
    first_swing, last_swing = (grid.ravel() for grid in np.meshgrid(swings, swings))
    keep = first_swing + last_swing <= MAX_HIDDEN_TURN - abs(turn) + 1e-9
    first_swing, last_swing = first_swing[keep], last_swing[keep]
    arcs = (
        (-side, first_swing),
        (side, abs(turn) + first_swing + last_swing),
        (-side, last_swing),
    )
    # Where the arcs of unit radius take the cable (they scale with the radius).
    heading = np.full(len(first_swing), leaving)
    unit_reach = np.zeros(len(first_swing), complex)
    for sense, angle in arcs:
        turned = heading * np.exp(1j * sense * angle)
        unit_reach += (turned - heading) / (1j * sense)
        heading = turned
    shapes = []
    # Every bend radius at once (one row each): the straights are elementwise, and a
    # crowded frame asks for them thousands of times.
    radii = np.asarray(bends, np.float64)[:, None]
    all_first, all_last, all_miss = _straights(leaving, arriving, offset - radii * unit_reach)
    for row, bend in enumerate(bends):
        first, last, miss = all_first[row], all_last[row], all_miss[row]
        reached = np.flatnonzero(
            (miss <= BULB_TOLERANCE_RADII * bend)
            & (first <= abs(offset) + bend)
            & (last <= abs(offset) + bend)
        )
        if len(reached) == 0:
            continue
        length = first + last + 2.0 * bend * (first_swing + last_swing)
        pick = reached[np.argmin(length[reached])]
        segments = [(float(first[pick]), 0.0)]
        segments += [(bend * float(angle[pick]), sense / bend) for sense, angle in arcs]
        segments.append((float(last[pick]), 0.0))
        shapes.append((float(length[pick]) + bend * abs(turn), segments))
    return shapes


def _straights(leaving: complex, arriving: complex, rest: np.ndarray):
    """Straight lengths ``first`` along ``leaving`` and ``last`` along ``arriving``
    (both >= 0) that come closest to making up ``rest`` (complex, one per candidate),
    and how far they miss it."""
    along_first = np.maximum((rest * np.conj(leaving)).real, 0.0)
    along_last = np.maximum((rest * np.conj(arriving)).real, 0.0)
    only_first = np.abs(rest - along_first * leaving)
    only_last = np.abs(rest - along_last * arriving)
    first = np.where(only_first <= only_last, along_first, 0.0)
    last = np.where(only_first <= only_last, 0.0, along_last)
    miss = np.minimum(only_first, only_last)
    det = (np.conj(leaving) * arriving).imag
    if abs(det) > 1e-3:
        both_first = (np.conj(rest) * arriving).imag / det
        both_last = (np.conj(leaving) * rest).imag / det
        exact = (both_first >= 0) & (both_last >= 0)
        first = np.where(exact, both_first, first)
        last = np.where(exact, both_last, last)
        miss = np.where(exact, 0.0, miss)
    return first, last, miss


def _trace(start: complex, heading: complex, segments, step: float) -> np.ndarray:
    """Samples about ``step`` apart along straight and circular ``segments`` (length,
    signed curvature) from ``start`` along unit ``heading``: ``(M, 2)`` (x, y)."""
    parts = []
    for length, curvature in segments:
        along = np.arange(0.0, length, step)
        if curvature == 0.0:
            points = start + along * heading
            start = start + length * heading
        else:
            points = start + heading * (np.exp(1j * curvature * along) - 1) / (1j * curvature)
            start = start + heading * (np.exp(1j * curvature * length) - 1) / (1j * curvature)
            heading = heading * np.exp(1j * curvature * length)
        parts.append(points)
    points = np.concatenate(parts) if parts else np.zeros(0, complex)
    return np.column_stack([points.real, points.imag])


def _cross_dot(first: np.ndarray, second: np.ndarray) -> tuple[float, float]:
    return (
        float(first[0] * second[1] - first[1] * second[0]),
        float(first[0] * second[0] + first[1] * second[1]),
    )


def turn_joins(
    ends: list,
    joins: list[tuple[int, int, float]],
    free: np.ndarray,
    radius: float,
    colours: EndColours | None,
    cost: Callable[[int, int], float],
    evidence: Sequence[Callable[[int, int, np.ndarray], bool]],
    reach: Callable[[int, int], float],
    free_cost: float,
    rival_limit: float,
    max_group: int,
    bridges: dict[tuple[int, int], np.ndarray] | None = None,
    along_curve: Sequence[bool] = (True,),
    out_of_view: Callable[[int, int, np.ndarray], bool] | None = None,
    distance: np.ndarray | None = None,
    hiding_extent: Callable[..., tuple[float, float] | None] | None = None,
    within_outline: Callable[[int, int, np.ndarray, Callable[[], list]], np.ndarray | None]
    | None = None,
    depth_bounded: dict[tuple[int, int], Callable[[np.ndarray], float]] | None = None,
) -> list[tuple[int, int, float]]:
    """Joins of free chain ends where the cable turns sharply under something.

    Parameters
    ----------
    ends : list of ChainEnd
        All ends (``position``, ``direction`` outwards, ``piece``, ``width``).
    joins : list of (int, int, float)
        The joins made so far: their ends are not free, and no new join closes a chain
        on itself.
    free : ndarray of bool
        The ends that may be joined here (not leaving the picture, not dropped).
    radius : float
        The picture's typical cable half width (px), when a piece's own is unknown.
    colours : EndColours or None
        The ends' colours; without them no turn is joined (the pieces must agree).
    cost : callable (i, j) -> float
        The join cost of ends ``i`` and ``j``, colour included.
    evidence : sequence of callable (i, j, curve) -> bool
        Tests of whether the image says something hides a cable along the curve,
        strongest first (the tests merging applies to its gaps): a pair is joined when
        any passes on any curve, and bridged along the shortest curve the strongest
        test that passes at all passes on.
    reach : callable (i, j) -> float or ndarray
        The longest gap (px) between the two ends that anything hides; called on
        arrays of ends ``i`` and ``j`` (every pair of free ends, a block at a time),
        elementwise.
    free_cost : float
        What leaving an end free costs in the matching.
    rival_limit : float
        A free pair of alike ends up to this cost counts as a rival partner, evidence
        or not.
    max_group : int
        Groups of ends linked by candidates larger than this are left alone.
    bridges : dict or None
        When given, each turn joined ``(i, j)`` gets the curve found hidden, from end
        ``i`` to end ``j``, to bridge it with.
    along_curve : sequence of bool
        Per test of ``evidence`` (False past its end), whether a turn it finds is
        bridged along the curve it passed on, however far apart the ends: an object
        seen over the curve (the first test), or two strands parting from a stretch
        where they touch, whose bulb a gap's bridge would cut across. The others say
        only that the gap is short enough to hide.
    out_of_view : callable (i, j, curve) -> int, optional
        How much of a cable along the curve would be hidden all the way from end ``i``
        to end ``j`` (nowhere over open background): :data:`WHOLE_TUBE_OUT_OF_VIEW`
        its whole tube, 1 its middle alone, 0 neither; of the curves the first test
        passes on, the shortest most hidden is the bridge (:func:`_likeliest_shape`),
        every curve :func:`hidden_turn_curves` builds tried until one is hidden whole.
    distance : ndarray, optional
        The mask's distance transform: an end whose strand it reads whole and straight
        up to the tip has its turns drawn from there (:func:`_turn_leaves_at`).
    hiding_extent : callable (i, j, origin, axis) -> (float, float) or None, optional
        How far the object seen over a turn from end ``i`` to end ``j`` reaches behind
        ``origin`` and ahead of it along ``axis`` (px; None: not known). Given with
        ``out_of_view``, a doubled-back turn under an object takes, of the curves it
        hides whole, the one whose apex lies nearest the middle of that extent
        (:func:`_nearest_the_middle_depth`), not the shortest.
    within_outline : callable (i, j, compact, curves) -> ndarray or None, optional
        For a turn no object is seen over (its cuts' evidence alone): where the image
        shows the outline of an object of the ground's colour over it, the curve of
        ``curves()`` (every one built, built when asked) in the middle of the depths
        the outline allows, from ``compact`` (the curve the evidence chose) to the
        deepest under it
        (:func:`.occluder_outline.turns_within_outlines`); the turn is then bridged
        along it, however far apart its strands (:func:`_within_outline`).
    depth_bounded : dict, optional
        When given, gets for each pair ``(i, j)`` whose curve was chosen by the object's
        depth (:func:`_by_depth`: the cuts lie on its near rim) how far a curve's apex
        lies from the middle of that depth (:func:`_apex_off_the_middle`).

    Returns
    -------
    list of (int, int, float)
        The turns joined, with their join costs.
    """
    if colours is None:
        return []
    eligible = np.asarray(free, bool).copy()
    component = _components(ends, joins)
    for i, j, _ in joins:
        eligible[i] = eligible[j] = False
    members = np.flatnonzero(eligible).tolist()
    positions = np.array([ends[k].position for k in members], np.float64).reshape(-1, 2)
    turns: dict[tuple[int, int], float] = {}
    hidden_curves: dict[tuple[int, int], np.ndarray] = {}
    rivals: dict[tuple[int, int], float] = {}
    for a_pos, b_pos in _pairs_within_reach(members, positions, reach):
        i, j = members[a_pos], members[b_pos]
        if component.find(ends[i].piece) == component.find(ends[j].piece):
            continue
        # Two pieces of clearly different colour or width are not one cable: no turn,
        # and no rival to one either, however cheap their geometry.
        if not ends_alike(colours, i, j, (ends[i].width, ends[j].width)):
            continue
        pair_cost = cost(i, j)
        if pair_cost <= rival_limit:
            # A pair merging could have joined on geometry alone, had the evidence for
            # its gap's one curve held: a rival to every turn, and a turn itself where
            # the evidence holds on a curve of the turn's (a gap cut at a slant).
            rivals[i, j] = pair_cost
        cable = 0.5 * (ends[i].width + ends[j].width) or radius
        a, b = ends[i], ends[j]
        # From each end's tip where the cable is seen whole and straight along the
        # fit's line up to it, else from where the fit begins (:func:`_turn_leaves_at`):
        # over a cut's hook the fit's extrapolation may leave the cable. The bridge
        # starts where the fits begin either way (:func:`.bridge_ends.bridge_from_the_fits`).
        a_from, b_from = a.position - a.skip * a.direction, b.position - b.skip * b.direction
        a_leaves, b_leaves = (
            _turn_leaves_at(a, distance, cable),
            _turn_leaves_at(b, distance, cable),
        )
        curves = _led_in(
            hidden_turn_curves(
                a_leaves,
                a.direction,
                b_leaves,
                -b.direction,
                cable,
                limit=None,
            ),
            a_from,
            b_from,
        )
        # The strongest evidence any curve has picks the bridge: a curve an object
        # is seen over before the shortest one the ends' cuts allow.
        tried: list[np.ndarray] = []
        for strength, test in enumerate(evidence):
            candidates = _cached(curves, tried)
            first_few = islice(candidates, MAX_TURN_TRIALS)
            passing = (curve for curve in first_few if test(i, j, curve))
            found = next(passing, None)
            if found is not None:
                # Where an object is seen over the turn, the cable lies under it all
                # the way round, not out past its rim on open background. The first
                # few curves say whether the evidence holds; the object's outline
                # then bounds the turn's shape, and every curve is tried against it
                # (the most compact ones may all reach out past it).
                hidden_all_along, leads, among = None, (0, 0), None
                if strength == 0 and out_of_view is not None:
                    hidden_all_along = partial(out_of_view, i, j)
                    rest = (curve for curve in candidates if test(i, j, curve))
                    passing = chain(passing, rest)
                    # The object's outline reads how the curve leaves the strands (a
                    # curve tilted off a strand seen straight up to its tip reaches out
                    # past the object's rim there): the kink test reads the hidden curve
                    # alone, between every curve's lead-in and tail (samples,
                    # :func:`_led_in`). With no object, the kink test alone reads it,
                    # lead-in and all.
                    leads = (
                        len(_straight(a_from, a_leaves, 1.0)),
                        len(_straight(b_leaves, b_from, 1.0)),
                    )
                    by_depth = _by_depth(
                        a, b, cable, partial(hiding_extent, i, j) if hiding_extent else None
                    )
                    if by_depth is not None:
                        among = by_depth.choose
                        if depth_bounded is not None:
                            depth_bounded[i, j] = by_depth.off_the_middle
                found = _likeliest_shape(found, passing, cable, hidden_all_along, leads, among)
                bounded = None
                if strength > 0 and within_outline is not None:
                    bounded = _within_outline(within_outline, i, j, found, candidates, tried)
                    found = found if bounded is None else bounded
                turns[i, j] = pair_cost
                # The ends' cuts say only that the gap is short enough for an object of
                # the background's own colour to hide: a turn seen on them alone is
                # bridged as any gap is (from where the fits begin, a short piece along
                # its partner, :mod:`.bridge_ends`), unless its strands lie too close to
                # turn round in one arc (a bulb, which only the turn's curve follows).
                shaped = strength < len(along_curve) and along_curve[strength]
                if (
                    bounded is not None
                    or shaped
                    or not turns_round_in_one_arc(
                        a.position, a.direction, b.position, b.direction, cable
                    )
                ):
                    hidden_curves[i, j] = found
                break
    if not turns:
        return []
    made = []
    for group in _groups(list(turns) + list(rivals)):
        if len(group) > max_group:
            continue
        costs = {
            pair: value for pair, value in (*turns.items(), *rivals.items()) if pair[0] in group
        }
        for i, j, value in cheapest_pairing(sorted(group), costs, free_cost):
            if (i, j) in turns:
                made.append((i, j, value))
                if bridges is not None and (i, j) in hidden_curves:
                    bridges[i, j] = hidden_curves[i, j]
    return sorted(made, key=lambda item: item[2])


PAIR_BLOCK = 1 << 22
"""About how many pairs of ends :func:`_pairs_within_reach` measures at once."""


def _pairs_within_reach(
    members: list[int], positions: np.ndarray, reach: Callable
) -> Iterator[tuple[int, int]]:
    """The pairs ``(a, b)``, ``a < b``, of positions in ``members`` whose ends lie no
    further apart than ``reach`` (called on arrays of end indices, elementwise), in
    order of ``a`` then ``b``: every pair's gap against its reach, vectorised, a block
    of first ends at a time. A frame of textured background leaves hundreds of free
    ends, and one crowded with small cables thousands, whose pairs (half the square of
    their number) would not all fit in memory at once; only a dozen or so per end lie
    within reach."""
    count = len(members)
    member_index = np.asarray(members, np.int64)
    rows = max(1, PAIR_BLOCK // max(count, 1))
    for start in range(0, max(count - 1, 0), rows):
        first, second = _upper_pairs(count, start, min(start + rows, count))
        gaps = np.hypot(*(positions[first] - positions[second]).T)
        within = gaps <= reach(member_index[first], member_index[second])
        yield from zip(first[within].tolist(), second[within].tolist(), strict=True)


def _upper_pairs(count: int, start: int, stop: int) -> tuple[np.ndarray, np.ndarray]:
    """The pairs ``(a, b)`` with ``start <= a < stop`` and ``a < b < count``, in order
    of ``a`` then ``b`` (the rows of :func:`numpy.triu_indices` from ``start``)."""
    firsts = np.arange(start, stop, dtype=np.int64)
    lengths = count - 1 - firsts
    first = np.repeat(firsts, lengths)
    # Within each row, b runs from a + 1 up: its offset from the row's beginning.
    row_starts = np.cumsum(lengths) - lengths
    second = first + 1 + (np.arange(len(first), dtype=np.int64) - np.repeat(row_starts, lengths))
    return first, second


def _components(ends: list, joins: list[tuple[int, int, float]]) -> Components:
    """The pieces' chains: pieces the joins link share a root."""
    components = Components(max((end.piece for end in ends), default=-1) + 1)
    for i, j, _ in joins:
        components.union(ends[i].piece, ends[j].piece)
    return components


def _groups(pairs: list[tuple[int, int]]) -> list[set[int]]:
    """The ends linked, directly or through others, by ``pairs``."""
    linked = Components(max((max(pair) for pair in pairs), default=-1) + 1)
    for i, j in pairs:
        linked.union(i, j)
    groups: dict[int, set[int]] = {}
    for pair in pairs:
        groups.setdefault(linked.find(pair[0]), set()).update(pair)
    return list(groups.values())
