"""Joins where a cable turns sharply out of sight: a U-turn or a tight bend under an object.

The join cost (:func:`.merging.join_cost`) charges for the turn between two ends'
directions, as it must: two free ends that point the same way side by side are, on
geometry alone, two cables. But a cable that turns by 90-180 degrees under an occluder
leaves exactly that: two ends of one cable that both point into the same object. Such a
join is made here only on the image's evidence, after every other join
(:func:`turn_joins`):

- a natural curve between the two ends along their directions, bending no tighter
  than a cable can (:data:`MIN_BEND_RADII` of its radius, the tightest loops the issue
  asks for), exists (:func:`natural_turn`), and the image says something hides a cable
  along it (``hidden``: the merging step's one test of that evidence, as for straight
  gaps: an object shows over the curve, :func:`.appearance.gap_hidden`, or both ends
  are cut square and alike and the curve no longer than an object of the background's
  own colour hides, :func:`.merging._cut_ends_alike`): not open background beyond two
  round tips, which is what lies beyond two cables that end side by side;
- the two pieces agree in colour and width (:func:`.appearance.ends_alike`);
- neither end has a better partner: the turns and every free pair the merging step
  could have joined without evidence are paired together by the cheapest matching,
  each end left free at an explicit cost (:func:`.pairing.cheapest_pairing`), and only
  the turns it chooses are made.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from service.perception._merging_kernels import MIN_BEND_RADII
from service.perception.appearance import EndColours, ends_alike
from service.perception.pairing import Components, cheapest_pairing

NEAR_U_TURN = 0.75 * np.pi
"""Turns sharper than this (radians) may have gone either way round (:func:`natural_turn`)."""


def natural_turn(
    start: np.ndarray,
    leaving: np.ndarray,
    end: np.ndarray,
    arriving: np.ndarray,
    min_radius: float,
    step: float = 1.0,
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
        narrower than twice ``min_radius``) or the ends do not turn.
    """
    leaving = np.asarray(leaving, np.float64)
    arriving = np.asarray(arriving, np.float64)
    start = np.asarray(start, np.float64)
    offset = np.asarray(end, np.float64) - start
    turn = float(np.arctan2(*_cross_dot(leaving, arriving)))
    if abs(turn) < 1e-6:
        return None
    readings = [turn]
    if abs(turn) > NEAR_U_TURN:
        readings.append(turn - np.copysign(2 * np.pi, turn))
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
    hidden: Callable[[int, int, np.ndarray], bool],
    reach: Callable[[int, int], float],
    free_cost: float,
    rival_limit: float,
    max_group: int,
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
    hidden : callable (i, j, curve) -> bool
        Whether the image says something hides a cable along the curve (the same test
        merging applies to its gaps).
    reach : callable (i, j) -> float
        The longest gap (px) between the two ends that anything hides.
    free_cost : float
        What leaving an end free costs in the matching.
    rival_limit : float
        A free pair up to this cost counts as a rival partner, evidence or not.
    max_group : int
        Groups of ends linked by candidates larger than this are left alone.

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
    rivals: dict[tuple[int, int], float] = {}
    for a_pos, i in enumerate(members):
        for b_pos in range(a_pos + 1, len(members)):
            j = members[b_pos]
            if component.find(ends[i].piece) == component.find(ends[j].piece):
                continue
            distance = float(np.hypot(*(positions[a_pos] - positions[b_pos])))
            if distance > reach(i, j):
                continue
            pair_cost = cost(i, j)
            if pair_cost <= rival_limit:
                rivals[i, j] = pair_cost
                continue
            if not ends_alike(colours, i, j, (ends[i].width, ends[j].width)):
                continue
            cable = 0.5 * (ends[i].width + ends[j].width) or radius
            a, b = ends[i], ends[j]
            curve = natural_turn(
                a.position, a.direction, b.position, -b.direction, MIN_BEND_RADII * cable
            )
            if curve is not None and hidden(i, j, curve):
                turns[i, j] = pair_cost
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
    return sorted(made, key=lambda item: item[2])


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
