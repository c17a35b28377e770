"""Tracking, step 2: a track moved onto what this frame shows of its cable.

Every piece fitted to a track (:mod:`service.perception.track_matching`) gives target
positions to the joints it covers: joint ``k`` sits at track arc ``k * l_s``, which is
piece arc ``sign * (k * l_s - offset)``. Where the piece ends at the cable's free end and
the track's end is a tip, the offset is taken from the tip instead (a tip pins the
sliding along the cable that the shape alone cannot). Joints no piece covers (hidden,
at a crossing, outside the picture) move with their seen neighbours: each run of them
follows the rigid motion of the seen joints on either side, blended along the run (the
motion coherence of CPD-style trackers, along the cable rather than across the image);
beyond the outermost seen joints (an end outside the picture or hidden) the joints keep
the last frame's shape, moved rigidly with the seen joints next to them.
Then the joints are made exactly ``l_s`` apart, the unseen ones moving most, with a
bending limit where nothing was seen (:func:`_tracking_kernels.constrain_chain`).

An ``open`` end (at the picture's edge or hidden when last seen) grows when the chain
that covers it goes on beyond it: new joints are added there, along that chain.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from service.perception import _tracking_kernels
from service.perception.geometry import points_along
from service.perception.track_matching import Chains, Fit, Piece, clear_of_edge

TIP_WINDOW = 5.0
"""A piece's free end within this many segments of a track's end is that end."""
TIP_TOLERANCE = 1.5
"""Both ends in view make the cable this many segments shorter than the track at most,
or one of them is hidden."""
TIP_GROWTH = 3
"""Segments of cable seen beyond a tip before the track grows there (the tip was an end
hidden under something)."""
TIP_GAIN = 0.4
"""Share of the slide its free ends show that a track takes per frame (a free end is
found to a pixel or two: this smooths that)."""
TIP_INWARD = 0.3
"""... and so does one short of it by up to this many (further in, it is taken for an
end hidden under something)."""
NEIGHBOURS = 6
"""Seen joints on each side whose motion an unseen run follows."""
UNSEEN_MOBILITY = 25.0
"""How much more an unseen joint moves than a seen one to keep the segment lengths."""
MIN_BEND_RADII = 2.5
"""The tightest bend assumed where nothing is seen, in cable radii."""
SWEEPS = 24
REFINE_STEPS = 2
BENT_TURN = 0.6
"""Total turn (radians) of the seen stretches from which their registration alone is
trusted for the slide along the cable ..."""
BENT_SLIDE = 0.3
"""... and how far (segments) the free ends may then still slide the track per frame."""
CHAIN_AGREEMENT = 1.5


@dataclass(frozen=True, eq=False)
class Observation:
    """What this frame shows of one track.

    Attributes
    ----------
    targets : (N, 2) ndarray
        Where the pieces put each joint (meaningful where ``covered``).
    covered : (N,) bool ndarray
    tips : (bool, bool)
        Whether each end is a tip after this frame: an open end that a free end reaches
        becomes one; an end the cable was seen to go on beyond is one only if the
        growth ended at a free end.
    head_growth, tail_growth : (n, 2) ndarray
        Joints to add before the first / after the last one (nearest first).
    slide : float
        How far (px) the free ends showed the cable slid along itself, beyond what the
        registration of its body found.
    free_ends : (bool, bool)
        Whether a free end of the cable was seen at each end of the track this frame.
    free_end_points : (2, 2) ndarray
        Where (px), NaN where none was seen.
    length_known : bool
        Both free ends were seen this frame, as far apart along the cable as the track's
        ends (within :data:`TIP_TOLERANCE` segments): the track is as long as its cable.
    """

    targets: np.ndarray
    covered: np.ndarray
    tips: tuple[bool, bool]
    head_growth: np.ndarray
    tail_growth: np.ndarray
    slide: float = 0.0
    free_ends: tuple[bool, bool] = (False, False)
    free_end_points: np.ndarray = field(default_factory=lambda: np.full((2, 2), np.nan))
    length_known: bool = False


def observe(
    joints: np.ndarray,
    tips: tuple[bool, bool],
    fitted: list[tuple[Piece, Fit]],
    chains: Chains,
    claimed: np.ndarray,
    chain_of_piece: list[tuple[int, int, int]],
    moving_tips: tuple[bool, bool] = (False, False),
    length_known: bool = False,
) -> Observation:
    """The targets the fitted pieces give a track's joints, and how its ends grow.

    A piece's free end within :data:`TIP_TOLERANCE` segments of the track's end pins
    that end (the offset is taken from it). A free end further in is taken for an end
    hidden by something (the track is not pulled in); a piece going on beyond an end,
    by more than that tolerance, makes the track grow there (an end that was hidden, or
    outside the picture, came into view).

    Parameters
    ----------
    joints : (N, 2) ndarray
        The track's joints as predicted for this frame.
    tips : (bool, bool)
        Whether its first / last end is a tip.
    fitted : list of (Piece, Fit)
        The pieces that fit this track.
    chains : Chains
        Their detection's chains (which ends grow along).
    claimed : (S,) bool ndarray
        Per piece of the detection, whether it is out of this track's reach: a track
        already fits it, or its colour is not this track's (growth stops there).
    chain_of_piece : list of (chain, first joint, last joint)
        Per piece of the detection, where it lies in its chain.
    moving_tips : (bool, bool)
        Per end, whether it is a free end seen in the last frame while the track's
        velocity is not known yet (just begun or back): the cable seen beyond it then is
        the cable moving along itself, not more cable (which only an end that was hidden
        could show), so it does not grow there.
    length_known : bool
        Whether the track is known to be as long as its cable (both its free ends were
        seen at once, :attr:`Observation.length_known`): it then never grows (a cable
        does not stretch): cable seen going on beyond one end is the track slid the
        other way, and moves it back (a share of the way per frame).
    """
    step = chains.step
    n = len(joints)
    total = (n - 1) * step
    new_tips = list(tips)
    placed = []
    for piece, fit in fitted:
        arcs = piece.arcs
        offset = _tracking_kernels.refine_offset(
            joints, piece.joints, arcs, fit.sign, fit.offset, step, REFINE_STEPS
        )
        placed.append((piece, fit.sign, offset, arcs))
    placed = _one_offset_per_chain(placed, chains)
    # A cable that bends where it is seen shows a slide along itself to the registration
    # of its body: one end alone may then only correct that a little per frame. It still
    # corrects it when the end went in while the cable may go out of the picture at its
    # other end: a bend travelling along the cable drags the registration of its body
    # along (the cable itself does not move so), and a free end seen is the one sure
    # mark of where the cable lies along itself. Both ends of a whole cable are trusted
    # over its body.
    limit = _slide_limit(joints, placed, step)
    going_out = _going_out(joints, placed, chains)
    slide = _slide(placed, total, step, going_out, _chain_tips(joints, placed, chains))
    if not slide.whole:  # a whole cable's two ends outweigh its body (a bend may travel)
        slide = replace(slide, shift=float(np.clip(slide.shift, -limit, limit)))
    for end in (0, 1):
        if slide.tips[end]:
            new_tips[end] = True
    # The piece reaching furthest towards each end: the cable may go on beyond that end
    # along the piece's chain.
    sums, weights, reach_source = _laid(placed, slide.shift, n, step)
    growth = []
    for end in (0, 1):
        source = reach_source[end]
        points = np.empty((0, 2))
        if source is not None:
            piece, sign, offset = source
            points, reached_tip = _grow(
                piece, sign, offset, end, total, chains, claimed, chain_of_piece, tips[end]
            )
            if tips[end] and (len(points) < TIP_GROWTH or moving_tips[end]):
                points = np.empty((0, 2))  # a tip seen a little further out: not more cable
            elif tips[end] and turns_too_sharply(*_junction(joints, end, points), piece.radius):
                points = np.empty((0, 2))  # past its free end, round a corner: another cable
            if len(points) and not length_known:
                new_tips[end] = reached_tip
        growth.append(points)
    shift = slide.shift
    if length_known:
        # A track as long as its cable never grows: cable seen going on beyond one of
        # its ends is the track slid along the cable, the other way.
        if (len(growth[0]) > 0) != (len(growth[1]) > 0):
            shift += TIP_GAIN * step * (len(growth[0]) - len(growth[1]))
            sums, weights, _ = _laid(placed, shift, n, step)
        growth = [np.empty((0, 2)), np.empty((0, 2))]
    covered = weights > 0
    targets = joints.copy()
    targets[covered] = sums[covered] / weights[covered, None]
    return Observation(
        targets=targets,
        covered=covered,
        tips=(new_tips[0], new_tips[1]),
        head_growth=growth[0],
        tail_growth=growth[1],
        slide=shift,
        free_ends=slide.tips,
        free_end_points=slide.points,
        length_known=slide.exact,
    )


def turns_too_sharply(before: np.ndarray, after: np.ndarray, radius: float) -> bool:
    """Whether a cable of ``radius`` cannot run from the end of ``before`` (joints in
    order, ending at a junction) on to the start of ``after`` (joints in order from it).

    The cable leaves ``before``'s last segment heading ``u`` and reaches ``after``'s first
    heading ``v``, turned by ``theta``. A curve whose bend radius is nowhere below ``r``
    and which turns one way by ``theta`` moves sideways (across ``u``) by at least
    ``r (1 - cos theta)``, whatever its length: the integral of ``sin`` of its heading
    over arc, ``r dphi`` at least per ``dphi`` of turn. That is 2 ``r`` for a U-turn and
    nothing for a straight gap. With ``r`` the tightest bend a cable makes
    (``MIN_BEND_RADII`` radii, the bend :func:`register` allows), less the cable's
    radius for the noise of its centreline, a junction closer sideways than that is no
    cable's: the detection joined two cables there (a V where two meet at the picture's
    edge, say).

    Examples
    --------
    >>> up = np.array([[0.0, 20.0], [0.0, 10.0], [0.0, 0.0]])
    >>> impossible_v = up[::-1] + [12.0, 0.0]  # back down 12 px to the side
    >>> turns_too_sharply(up, impossible_v, 4.0)
    True
    >>> turns_too_sharply(up, up - [0.0, 40.0], 4.0)  # on across a gap
    False
    """
    if len(before) < 2 or len(after) < 2:
        return False
    heading_in = before[-1] - before[-2]
    heading_out = after[1] - after[0]
    norms = float(np.linalg.norm(heading_in)), float(np.linalg.norm(heading_out))
    if min(norms) < 1e-9:
        return False
    heading_in, heading_out = heading_in / norms[0], heading_out / norms[1]
    cos_theta = float(np.clip(heading_in @ heading_out, -1.0, 1.0))
    # Measured between the segments' middles, where their directions are the cable's.
    gap = 0.5 * (after[0] + after[1]) - 0.5 * (before[-1] + before[-2])
    sideways = abs(float(heading_in[0] * gap[1] - heading_in[1] * gap[0]))
    return sideways < MIN_BEND_RADII * radius * (1.0 - cos_theta) - radius


def _junction(joints: np.ndarray, end: int, growth: np.ndarray):
    """The track's last joints towards ``end``, and the first grown beyond it."""
    return (joints[2::-1] if end == 0 else joints[-3:]), growth[:3]


def _laid(placed, shift: float, n: int, step: float):
    """The pieces laid along a track of ``n`` joints, each offset moved on by ``shift``:
    per joint the sum of the targets they give and their count, and per end the piece
    reaching furthest that way as ``(piece, sign, offset)`` (None: no piece)."""
    sums = np.zeros((n, 2))
    weights = np.zeros(n)
    reach = [np.inf, -np.inf]
    reach_source: list[tuple[Piece, int, float] | None] = [None, None]
    track_arc = np.arange(n) * step
    for piece, sign, offset, arcs in placed:
        offset += shift
        u = sign * (track_arc - offset)
        inside = np.flatnonzero((u >= 0.0) & (u <= arcs[-1]))
        if len(inside):
            walked = _tracking_kernels.chord_walk(
                piece.joints, arcs, float(u[inside[0]]), sign, step, len(inside)
            )
            count = min(len(walked), len(inside))
            rows = inside[0] + np.arange(count)
            sums[rows] += walked[:count]
            weights[rows] += 1.0
        lo, hi = offset, sign * float(arcs[-1]) + offset
        if min(lo, hi) < reach[0]:
            reach[0] = min(lo, hi)
            reach_source[0] = (piece, sign, offset)
        if max(lo, hi) > reach[1]:
            reach[1] = max(lo, hi)
            reach_source[1] = (piece, sign, offset)
    return sums, weights, reach_source


@dataclass(frozen=True)
class _Slide:
    """How far the track slid along itself beyond what the body showed (px of arc, added
    to every piece's offset), and which ends were seen as free ends."""

    shift: float = 0.0
    tips: tuple[bool, bool] = (False, False)
    whole: bool = False  # both ends seen, the cable not clearly shorter than the track
    exact: bool = False  # both ends seen, the cable as long as the track
    points: np.ndarray = field(default_factory=lambda: np.full((2, 2), np.nan))


def _slide(
    placed, total: float, step: float, outside: tuple[bool, bool], chain_tips=None
) -> _Slide:
    """The slide along the cable that the free ends in view show.

    A stretch of cable looks the same slid along itself, so the body's registration
    (each piece's offset) sees motion along the cable only where the cable bends; a free
    end sees it directly. Each free end near one of the track's ends gives how far
    beyond that end (``outward``, px) the cable now ends. Both ends in view, and the
    cable not clearly shorter than the track: it slid by half their difference (which
    leaves a small error in the track's length evenly at both ends). Otherwise an end
    that went in
    is taken for one hidden under something (an occluder hides, it never adds) unless the
    track's other end is outside the picture (where the cable can go on), and the one
    that went out (or stayed) tells the slide. ``chain_tips``: per end, the free ends
    of the detected chains beyond the pieces (:func:`_chain_tips`), for an end no
    piece's free end shows.
    """
    tolerance = TIP_TOLERANCE * step
    window = TIP_WINDOW * step
    # per end: (outward, offset change, x, y of the free end)
    seen: list[list[tuple[float, float, float, float]]] = [[], []]
    for piece, sign, offset, arcs in placed:
        for end, u_end in ((0, 0.0), (1, float(arcs[-1]))):
            if not piece.tips[end]:
                continue
            s_tip = sign * u_end + offset
            x, y = piece.joints[-end]
            if abs(s_tip) <= window and s_tip < 0.5 * total:
                seen[0].append((-s_tip, -s_tip, x, y))
            elif abs(s_tip - total) <= window and s_tip > 0.5 * total:
                seen[1].append((s_tip - total, total - s_tip, x, y))
    for end in (0, 1):
        if not seen[end] and chain_tips is not None:
            for s_tip, x, y in chain_tips[end]:
                if end == 0:
                    seen[0].append((-s_tip, -s_tip, x, y))
                else:
                    seen[1].append((s_tip - total, total - s_tip, x, y))
    outward = [max(found)[0] if found else None for found in seen]
    change = [max(found)[1] if found else None for found in seen]
    points = np.array([max(found)[2:] if found else (np.nan, np.nan) for found in seen])
    inward = TIP_INWARD * step
    tips = (bool(seen[0]), bool(seen[1]))
    if outward[0] is not None and outward[1] is not None:
        if outward[0] + outward[1] >= -tolerance:  # not much shorter: both are real ends
            shift = TIP_GAIN * 0.5 * (change[0] + change[1])
            exact = abs(outward[0] + outward[1]) <= tolerance
            return _Slide(shift, tips, whole=True, exact=exact, points=points)
        end = 0 if outward[0] > outward[1] else 1  # the other one is hidden
    elif outward[0] is not None:
        end = 0
    elif outward[1] is not None:
        end = 1
    else:
        return _Slide(0.0, tips, points=points)
    if outward[end] < -inward and not outside[1 - end]:
        return _Slide(0.0, tips, points=points)  # went in: hidden, more likely than slid
    return _Slide(TIP_GAIN * change[end], tips, points=points)


def _chain_tips(joints, placed, chains):
    """Free ends of the detected chains beyond the pieces, lying on the track's ends.

    A piece stops short of its chain's end where the chain runs near another one (a
    crossing, a touching cable) or changes colour; the chain may still end there at the
    cable's free end. Such an end counts as one seen when the chain is sure of the
    stretch from the piece on (no inferred segment, no change of colour), the end is
    clear of the picture's edge and within :data:`TIP_TOLERANCE` segments of the track's
    end along the piece's registration, and every joint of that stretch lies on the
    track as predicted (within the cable's radius and half a segment): it is the track's
    own cable ending, not another cable that the detection joined on at a crossing.

    Returns, per end of the track, a list of ``(s_tip, x, y)``: the track arc (px) the
    free end lies at, and where it is.
    """
    step = chains.step
    total = (len(joints) - 1) * step
    tolerance = TIP_TOLERANCE * step
    found: list[list[tuple[float, float, float]]] = [[], []]
    # The track, straight on beyond its ends as far as an end may have slid.
    heads = joints[[0, -1]] - joints[[1, -2]]
    heads *= tolerance / np.maximum(np.sqrt((heads * heads).sum(axis=1)), 1e-12)[:, None]
    extended = np.empty((len(joints) + 2, 2))
    extended[0] = joints[0] + heads[0]
    extended[1:-1] = joints
    extended[-1] = joints[-1] + heads[1]
    for piece, sign, offset, _ in placed:
        index = piece.chain
        arcs = chains.arcs[index]
        points = chains.joints[index]
        inferred = chains.inferred[index]
        breaks = chains.colour_breaks[index]
        last = len(points) - 1
        base = arcs[piece.first]
        for chain_end, stretch in ((0, slice(0, piece.first)), (last, slice(piece.last, last))):
            if stretch.start == stretch.stop:
                continue  # the piece reaches it: its own tip flag says
            if inferred[stretch].any() or breaks[stretch].any():
                continue
            radius = chains.radii[index]
            if not clear_of_edge(points[chain_end], radius, chains.width, chains.height):
                continue
            s_tip = sign * (float(arcs[chain_end]) - base) + offset
            end = 0 if abs(s_tip) <= tolerance else 1 if abs(s_tip - total) <= tolerance else None
            if end is None:
                continue
            beyond = points[stretch.start : stretch.stop + 1]
            reach = radius + 0.5 * step
            if _tracking_kernels.farthest_from_polyline(beyond, extended) > reach:
                continue
            found[end].append((s_tip, *points[chain_end]))
    return found


def _grow(piece, sign, offset, end, total, chains, claimed, chain_of_piece, at_tip):
    """Joints beyond a track's end along the piece's chain, and whether they end at a tip.

    The chain is followed from the piece on, beyond the end: through the segments
    between pieces (a crossing, a filled gap) but only as far as the last joint that
    lies on cable no other track holds (the piece itself, or a free piece of the chain);
    a piece held by a track stops it. Beyond an end seen as the cable's tip (``at_tip``)
    only the piece itself counts: the cable seen going on there (it was hidden) is the
    piece's; joining a piece beyond a gap there is left to
    :func:`~service.perception.track_identity.continuation`, which checks that it looks
    like the track.
    """
    step = chains.step
    chain_joints = chains.joints[piece.chain]
    chain_arcs = chains.arcs[piece.chain]
    base = chain_arcs[piece.first]  # chain arc of the piece's first joint
    # Track arc s lies at chain arc base + sign * (s - offset); beyond the end means s
    # below 0 (end 0) or above total (end 1).
    direction = -sign if end == 0 else sign  # +1: towards the chain's last joint
    spans = []  # (low arc, high arc, free) of the chain's other pieces
    for index, (c, first, last) in enumerate(chain_of_piece):
        if c == piece.chain and first != piece.first:
            spans.append((chain_arcs[first], chain_arcs[last], not claimed[index]))
    own = (base, chain_arcs[piece.first + len(piece.joints) - 1])
    slack = 0.25 * step
    new = []
    keep = 0  # joints up to here lie on free cable
    reached_end = False
    for k in range(1, len(chain_joints) + 1):
        s = -k * step if end == 0 else total + k * step
        a = base + sign * (s - offset)
        if a < -slack or a > chain_arcs[-1] + slack:
            break
        a = min(max(a, 0.0), float(chain_arcs[-1]))
        held = [free for low, high, free in spans if low - slack <= a <= high + slack]
        if held and (at_tip or not all(held)):
            break  # another track's cable (or, beyond a tip, another piece)
        new.append(points_along(chain_joints, chain_arcs, np.array([a]))[0])
        if held or own[0] - slack <= a <= own[1] + slack:
            keep = len(new)
            reached_end = (a >= chain_arcs[-1] - slack) if direction > 0 else (a <= slack)
    if keep == 0:
        return np.empty((0, 2)), False
    chain_end = len(chain_joints) - 1 if direction > 0 else 0
    flags = chains.inferred[piece.chain]
    end_inferred = bool(flags[-1] if direction > 0 else flags[0]) if len(flags) else False
    at_tip = (
        reached_end
        and clear_of_edge(
            chain_joints[chain_end], chains.radii[piece.chain], chains.width, chains.height
        )
        and not end_inferred
    )
    return np.array(new[:keep]), at_tip


def register(
    predicted: np.ndarray,
    observation: Observation,
    step: float,
    radius: float,
    previous: np.ndarray | None = None,
) -> np.ndarray:
    """The track's new joints: covered ones at their targets, the rest carried along,
    all exactly ``step`` apart (see the module's documentation).

    Between its first and last covered joint, each run of uncovered joints follows the
    rigid motion of the covered joints on either side, blended along the run, and the
    joints are then made ``step`` apart, the uncovered ones moving most, with a bending
    limit where nothing was seen. Beyond the first and the last covered joint (an end
    hidden, or outside the picture) the joints keep the shape they had in the last
    frame (``previous``; by default as predicted) and move as a rigid whole with the
    covered joints next to them (a fit over :data:`NEIGHBOURS` of them, so that one
    joint a chain cut by the picture's edge bends astray does not turn the rest): a
    cable keeps its shape where it is not seen, and nothing seen bends it.
    """
    covered = observation.covered
    targets = observation.targets
    joints = predicted.copy()
    joints[covered] = targets[covered]
    seen = np.flatnonzero(covered)
    if len(seen) == 0:
        return exact_chain(joints, step)
    first, last = int(seen[0]), int(seen[-1])
    for begin, end in _uncovered_runs(covered):
        if begin < first or end > last:
            continue  # an end: below
        left = seen[seen < begin][-NEIGHBOURS:]
        right = seen[seen > end][:NEIGHBOURS]
        moved_left = _rigid(predicted[left], targets[left], predicted[begin : end + 1])
        moved_right = _rigid(predicted[right], targets[right], predicted[begin : end + 1])
        weight = (np.arange(begin, end + 1) - begin + 1.0) / (end - begin + 2.0)
        joints[begin : end + 1] = (1.0 - weight)[:, None] * moved_left + weight[
            :, None
        ] * moved_right
    turn = min(1.2, 2.0 * math.asin(min(1.0, step / (2.0 * MIN_BEND_RADII * max(radius, 1.0)))))
    core = slice(first, last + 1)
    if last > first:
        inverse_mass = np.where(covered[core], 1.0, UNSEEN_MOBILITY)
        min_span = np.where(covered[core], 0.0, 2.0 * step * math.cos(turn / 2.0))
        min_span[0] = min_span[-1] = 0.0
        middle = seen[len(seen) // 2] - first
        joints[core] = _tracking_kernels.constrain_chain(
            np.ascontiguousarray(joints[core]),
            np.ascontiguousarray(inverse_mass),
            float(step),
            np.ascontiguousarray(min_span),
            SWEEPS,
            int(middle),
        )
    if first > 0 or last < len(joints) - 1:
        _ends_rigidly(joints, predicted if previous is None else previous, seen, first, last)
    return joints


def _ends_rigidly(joints, shape, seen, first, last) -> None:
    """Lay the joints before ``first`` and after ``last`` (in place) as ``shape`` lays
    them, moved by the rigid motion taking the nearest :data:`NEIGHBOURS` seen joints of
    ``shape`` onto where they are now (``joints``), and joined on at ``first`` /
    ``last`` (see :func:`register`)."""
    if last < len(joints) - 1:
        near = seen[-NEIGHBOURS:]
        moved = _rigid(shape[near], joints[near], shape[last:])
        joints[last + 1 :] = moved[1:] + (joints[last] - moved[0])
    if first > 0:
        near = seen[:NEIGHBOURS]
        moved = _rigid(shape[near], joints[near], shape[: first + 1])
        joints[:first] = moved[:-1] + (joints[first] - moved[-1])


def exact_chain(joints: np.ndarray, step: float) -> np.ndarray:
    """``joints`` made exactly ``step`` apart, every joint moving alike."""
    n = len(joints)
    return _tracking_kernels.constrain_chain(
        np.ascontiguousarray(joints, dtype=np.float64),
        np.ones(n),
        float(step),
        np.zeros(n),
        SWEEPS,
        n // 2,
    )


def _rigid(source: np.ndarray, target: np.ndarray, points: np.ndarray) -> np.ndarray | None:
    """``points`` moved by the rotation and translation taking ``source`` onto ``target``
    (least squares); a translation alone from one pair; None from none."""
    if len(source) == 0:
        return None
    if len(source) == 1:
        return points + (target.mean(axis=0) - source.mean(axis=0))
    # geometry.rigid_fit's sums in one compiled loop (the same bits).
    sums = _tracking_kernels.rigid_sums(
        np.ascontiguousarray(source, dtype=np.float64),
        np.ascontiguousarray(target, dtype=np.float64),
    )
    angle = math.atan2(float(sums[4]), float(sums[5]))
    c, s = math.cos(angle), math.sin(angle)
    return (points - sums[:2]) @ np.array([[c, -s], [s, c]]).T + sums[2:4]


def _uncovered_runs(covered: np.ndarray) -> list[tuple[int, int]]:
    padded = np.concatenate([[True], covered, [True]])
    steps = padded.astype(np.int8)
    edges = steps[1:] - steps[:-1]
    begins = np.flatnonzero(edges == -1)
    ends = np.flatnonzero(edges == 1) - 1
    return [(int(b), int(e)) for b, e in zip(begins, ends, strict=True)]


def _one_offset_per_chain(placed, chains):
    """Pieces of one detected chain that lie on the track the same way share one offset.

    The chain's own arc between two of its pieces (across the crossing or gap that split
    them) is the cable's; registering each piece alone would let the track's arc between
    them stretch or shrink, and the joints there buckle. Pieces whose offsets, measured
    along their chain, agree within :data:`CHAIN_AGREEMENT` segments get their
    length-weighted mean.
    """
    groups: dict[tuple[int, int], list[int]] = {}
    for index, (piece, sign, _, _) in enumerate(placed):
        groups.setdefault((piece.chain, sign), []).append(index)
    result = list(placed)
    for (chain_index, sign), members in groups.items():
        if len(members) < 2:
            continue
        chain_arcs = chains.arcs[chain_index]
        along_chain = np.array(
            [placed[i][2] - sign * chain_arcs[placed[i][0].first] for i in members]
        )
        weights = np.array([placed[i][3][-1] for i in members])
        centre = along_chain[np.argmax(weights)]
        agree = np.abs(along_chain - centre) <= CHAIN_AGREEMENT * chains.step
        kept = weights[agree]  # np.average's sums, without its per-call cost
        common = float((along_chain[agree] * kept).sum() / kept.sum())
        for i, keep in zip(members, agree, strict=True):
            if keep:
                piece, _, _, arcs = placed[i]
                result[i] = (piece, sign, common + sign * chain_arcs[piece.first], arcs)
    return result


def _slide_limit(joints, placed, step) -> float:
    """How far (px) the free ends may slide the track this frame: unbounded where the
    seen stretches are nearly straight, :data:`BENT_SLIDE` segments where they turn by
    :data:`BENT_TURN` radians or more in all (in between, in proportion)."""
    n = len(joints)
    seen = np.zeros(n, dtype=bool)
    track_arc = np.arange(n) * step
    for _, sign, offset, arcs in placed:
        lo, hi = sorted((offset, sign * float(arcs[-1]) + offset))
        seen |= (track_arc >= lo) & (track_arc <= hi)
    steps = joints[1:] - joints[:-1]
    angles = np.arctan2(steps[:, 1], steps[:, 0])
    turns = np.abs((angles[1:] - angles[:-1] + math.pi) % (2.0 * math.pi) - math.pi)
    inner = seen[1:-1] & seen[:-2] & seen[2:]
    bent = float(turns[inner].sum()) / BENT_TURN
    if bent >= 1.0:
        return BENT_SLIDE * step
    return BENT_SLIDE * step / max(bent, 1e-6)


def _going_out(joints, placed, chains) -> tuple[bool, bool]:
    """Per end of the track: whether the cable may go on out of the picture that way
    (the end is outside it, or the seen cable furthest that way ends at its edge)."""
    width, height = chains.width, chains.height
    result = []
    for end in (0, 1):
        if not _in_picture(joints[-end], width, height):
            result.append(True)
            continue
        extreme, at_edge = None, False
        for piece, sign, offset, arcs in placed:
            for piece_end, u_end in ((0, 0.0), (1, float(arcs[-1]))):
                s_end = sign * u_end + offset
                further = extreme is None or (s_end < extreme if end == 0 else s_end > extreme)
                if further:
                    extreme = s_end
                    point = piece.joints[-piece_end]
                    at_edge = not clear_of_edge(point, piece.radius, width, height)
        result.append(at_edge)
    return result[0], result[1]


def _in_picture(point, width: int, height: int) -> bool:
    return 0.0 <= point[0] <= width - 1 and 0.0 <= point[1] <= height - 1
