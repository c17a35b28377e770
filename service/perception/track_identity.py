"""Tracking, step 3: new cables, and cables that come back.

Stretches of the detection that no track holds become *candidates*; a candidate seen in
consecutive frames (``confirm_frames``) becomes a track, so that a chain the detector
finds in one frame only does not start one. Before it gets a new id it is compared with
the tracks out of view (and those predicted but not seen for a moment): a cable that
comes back is recognised by its colour (the median Lab colour along it), its width and
its length (a whole cable, both ends seen, must match a whole cable's length; part of
one may not be longer), and takes its old id, joints and end back. Which end is which
follows from the ends' last sightings: a cable that left through an edge comes back
through it with the end that left last.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from service.perception import _geometry_kernels
from service.perception.geometry import arc_lengths, distances_to_polyline, points_along, rigid_fit
from service.perception.track_matching import Chains, Piece

MIN_CANDIDATE_SEGMENTS = 3
"""A stretch shorter than this many segments does not start a track."""
COLOUR_TOLERANCE = 22.0
"""Largest distance between the colours of a cable and a remembered track: Lab (OpenCV's
8-bit scaling) with lightness weighted by half (:data:`LAB_WEIGHTS`)."""
LAB_WEIGHTS = np.array([0.5, 1.0, 1.0])
RADIUS_TOLERANCE = 1.6
"""Largest ratio between their radii."""
LENGTH_TOLERANCE = 0.15
"""Largest relative difference between whole cables' lengths (plus two segments)."""
SHAPE_MARGIN = 1.5
"""The shape decides which end is which when one way fits this much worse than the other."""
LEFT_GATE = 5.0
"""A candidate lies where its cable left the view when its joints are this many segments
(or 4 radii) from the joints of the track seen last, on average ..."""
LEFT_OVERLAP = 3
"""... over at least this many joints."""
NEAR_END_RATIO = 0.5
"""A free end back in view is the track's end last seen nearest it when that one is at
most this share as far as the other (else the end seen last)."""
MAX_JOIN_GAP = 10.0
"""A candidate continues a track only from within this many segments of its end ..."""
MAX_JOIN_TURN = math.radians(40.0)
"""... turning no more than this from the track's end direction."""


@dataclass(frozen=True, eq=False)
class Candidate:
    """A stretch of detection no track holds: perhaps a new cable.

    Attributes
    ----------
    joints : (n, 2) ndarray
        ``segment_length`` apart.
    tips : (bool, bool)
    radius : float
    colour : (3,) ndarray or None
        Median Lab colour along it (None without an image).
    hits : int
        Consecutive frames it has been seen in.
    """

    joints: np.ndarray
    tips: tuple[bool, bool]
    radius: float
    colour: np.ndarray | None
    hits: int = 1

    @property
    def length(self) -> float:
        return float(np.linalg.norm(np.diff(self.joints, axis=0), axis=1).sum())


def unclaimed_stretches(
    chains: Chains,
    pieces: list[Piece],
    used: np.ndarray,
    image: np.ndarray | None,
    colours: list[np.ndarray | None],
) -> list[Candidate]:
    """Candidates from the pieces no track holds: consecutive free pieces of a chain
    (with what lies between them) make one candidate, unless their colours differ
    (``colours``: per piece)."""
    step = chains.step
    by_chain: dict[int, list[int]] = {}
    for index, piece in enumerate(pieces):
        by_chain.setdefault(piece.chain, []).append(index)
    found = []
    for chain_index, members in by_chain.items():
        run: list[int] = []
        for index in [*members, None]:
            if index is not None and not used[index]:
                # Pieces of other colours are other cables the detection joined to this
                # one at a crossing: the run stops there.
                if run and colour_distance(colours[run[-1]], colours[index]) > COLOUR_TOLERANCE:
                    found.extend(_candidate(chains, chain_index, pieces, run, image, step))
                    run = []
                run.append(index)
                continue
            found.extend(_candidate(chains, chain_index, pieces, run, image, step))
            run = []
    return found


def _candidate(chains, chain_index, pieces, run, image, step) -> list[Candidate]:
    """The candidate a run of a chain's pieces makes (none when it is too short)."""
    if not run:
        return []
    first, last = pieces[run[0]], pieces[run[-1]]
    stretch = chains.joints[chain_index][first.first : last.last + 1]
    if (len(stretch) - 1) * step < MIN_CANDIDATE_SEGMENTS * step - 1e-9:
        return []
    return [
        Candidate(
            joints=stretch,
            tips=(first.tips[0], last.tips[1]),
            radius=chains.radii[chain_index],
            colour=chains.colour(chain_index, first.first, last.last),
        )
    ]


# A new cable's candidate is looked for this many gates from where it was last frame: a
# cable coming in fast moves more than one gate a frame while its visible stretch grows.
CONFIRM_GATES = 4.0


def confirm(new: list[Candidate], previous: list[Candidate], gate: float) -> list[Candidate]:
    """``new`` with their hit counts: one more than the previous candidate they overlap
    within :data:`CONFIRM_GATES` times ``gate`` (px) of its cable's edge."""
    reach = CONFIRM_GATES * gate
    confirmed = []
    for candidate in new:
        hits = 1
        for old in previous:
            if _overlap(candidate.joints, old.joints, reach + old.radius) >= 0.5:
                hits = max(hits, old.hits + 1)
        confirmed.append(
            Candidate(candidate.joints, candidate.tips, candidate.radius, candidate.colour, hits)
        )
    return confirmed


@dataclass(frozen=True, eq=False)
class Continuation:
    """A candidate that continues a track's end across a short gap (a hidden stretch).

    Attributes
    ----------
    track : int
        Index of the track.
    end : int
        0: its first end; 1: its last.
    anchor : int
        The track's outermost joint seen at that end, from which it is continued.
    joints : (n, 2) ndarray
        The joints beyond the anchor, nearest first, each ``step`` from the one before.
    tip : bool
        Whether the far end of the candidate is a free end.
    """

    track: int
    end: int
    anchor: int
    joints: np.ndarray
    tip: bool


def continuation(
    candidate: Candidate,
    tracks: list[tuple[np.ndarray, np.ndarray, float, np.ndarray | None]],
    step: float,
) -> Continuation | None:
    """The track end the candidate continues, if one does: an end seen where something
    lay on the cable, and the rest of the cable has come out from under it.

    Measured from the track's outermost joint seen at that end (the joints beyond it
    are guesses), the candidate must begin within :data:`MAX_JOIN_GAP` segments, go on
    the way the track ends (the gap and both ends within :data:`MAX_JOIN_TURN` of each
    other) and look like the track (colour, width). ``tracks`` are ``(joints, seen,
    radius, colour)``.
    """
    best, best_gap = None, math.inf
    limit = math.cos(MAX_JOIN_TURN)
    for index, joints, seen_at in _alike(candidate, tracks, step):
        for end in (0, 1):
            anchor = int(seen_at[0] if end == 0 else seen_at[-1])
            body = joints[anchor:] if end == 0 else joints[: anchor + 1]
            outward = _end_direction(body, end)
            track_end = joints[anchor]
            for candidate_end in (0, 1):
                start = candidate.joints[0] if candidate_end == 0 else candidate.joints[-1]
                gap_vector = start - track_end
                gap = float(np.linalg.norm(gap_vector))
                if gap > MAX_JOIN_GAP * step or gap >= best_gap:
                    continue
                inward = -_end_direction(candidate.joints, candidate_end)
                if float(outward @ inward) < limit:
                    continue
                if gap > step and float(outward @ (gap_vector / gap)) < limit:
                    continue
                rest = candidate.joints if candidate_end == 0 else candidate.joints[::-1]
                line = np.ascontiguousarray(np.vstack([track_end, rest]))
                walked, _ = _geometry_kernels.resample_kernel(line, step)
                if len(walked) < 2:
                    continue
                tip = candidate.tips[1 - candidate_end]
                best = Continuation(index, end, anchor, walked[1:], tip)
                best_gap = gap
    return best


def waits(candidate: Candidate, young: list[tuple[np.ndarray | None, float]], step: float) -> bool:
    """Whether a confirmed candidate should wait before it starts a track: it is not a
    whole cable (at most one free end) and a track just begun or come back, alike in
    colour and width (``young``: their ``(colour, radius)``), has an open end, its cable
    going on out of view. They may be two pieces of one cable coming in (broadside over
    an edge, say) that the next frames show joined; the wait lasts until that track is
    steady (``tracking.STEADY_FRAMES``), then the candidate goes on as any other."""
    if all(candidate.tips):
        return False
    return any(
        similarity(candidate, colour, radius, math.inf, (False, False), step) is not None
        for colour, radius in young
    )


def _alike(candidate: Candidate, tracks, step: float):
    """``(index, joints, seen joints' indices)`` of the tracks seen at two joints or more
    that look like the candidate (colour, width)."""
    for index, (joints, seen, radius, colour) in enumerate(tracks):
        seen_at = np.flatnonzero(seen)
        if len(seen_at) < 2:
            continue
        if similarity(candidate, colour, radius, math.inf, (False, False), step) is None:
            continue
        yield index, joints, seen_at


def _end_direction(joints: np.ndarray, end: int) -> np.ndarray:
    """Unit direction pointing out of a polyline at one end (over up to three segments)."""
    span = min(3, len(joints) - 1)
    vector = joints[0] - joints[span] if end == 0 else joints[-1] - joints[-1 - span]
    return vector / max(float(np.linalg.norm(vector)), 1e-12)


def similarity(
    candidate: Candidate,
    colour: np.ndarray | None,
    radius: float,
    length: float,
    tips: tuple[bool, bool],
    step: float,
) -> float | None:
    """How unlike a remembered track the candidate is (lower is closer); None: not it."""
    score = 0.0
    if colour is not None and candidate.colour is not None:
        # Lightness changes with the light and the shading across a cable; the hue and
        # the saturation (a, b) far less.
        distance = colour_distance(colour, candidate.colour)
        if distance > COLOUR_TOLERANCE:
            return None
        score += distance / COLOUR_TOLERANCE
    ratio = max(radius, candidate.radius) / max(min(radius, candidate.radius), 1e-6)
    if ratio > RADIUS_TOLERANCE:
        return None
    score += math.log(ratio)
    slack = LENGTH_TOLERANCE * length + 2.0 * step
    whole_track = all(tips)
    if whole_track and candidate.length > length + slack:
        return None
    if whole_track and all(candidate.tips):
        if abs(candidate.length - length) > slack:
            return None
        score += abs(candidate.length - length) / slack
    return score


def colour_distance(first: np.ndarray | None, second: np.ndarray | None) -> float:
    """Distance between two Lab colours, lightness weighted by half (:data:`LAB_WEIGHTS`);
    0 when either is unknown."""
    if first is None or second is None:
        return 0.0
    return float(np.linalg.norm((first - second) * LAB_WEIGHTS))


def orientation(
    candidate: Candidate,
    track_joints: np.ndarray,
    track_tips: tuple[bool, bool],
    ends_last_seen: tuple[np.ndarray, np.ndarray],
    ends_seen_s: tuple[float, float],
) -> bool:
    """Whether the candidate's first joint is the track's first end (else its last).

    A free end is the same free end: when the candidate shows exactly one and the track
    knows exactly one, they pair. Otherwise by shape: the candidate laid rigidly
    (turned and moved) onto the track's joints from either end, the way that fits
    clearly better (a cable keeps its shape while it is out of view, more or less).
    A candidate without a free end may show any stretch of the cable: it is laid along
    the track at every offset, and the best fit counts.
    When the shape cannot tell (a nearly straight cable): with one free end in view,
    that end is the track's end last seen clearly nearest it (:data:`NEAR_END_RATIO`:
    a cable that left broadside comes back with its ends where they were), else the
    end seen last (a cable that left along itself, through an edge, comes back with
    the end that left last); otherwise the pairing of the ends that puts them nearest
    where they were last seen.
    """
    if candidate.tips[0] != candidate.tips[1] and track_tips[0] != track_tips[1]:
        return candidate.tips[0] == track_tips[0]
    fits = []
    for first_is_head in (True, False):
        if candidate.tips[0] or candidate.tips[1]:
            fits.append(_shape_misfit(candidate, track_joints, first_is_head))
        else:  # a stretch from anywhere along the cable (between edges, say)
            seen = candidate.joints if first_is_head else candidate.joints[::-1]
            fits.append(_sliding_misfit(seen, track_joints)[0])
    better, worse = sorted(fits)
    if worse > SHAPE_MARGIN * better + 1.0:
        return fits[0] <= fits[1]
    first, last = candidate.joints[0], candidate.joints[-1]
    head, tail = ends_last_seen
    if candidate.tips[0] != candidate.tips[1]:
        tip = first if candidate.tips[0] else last
        to_head, to_tail = float(np.linalg.norm(tip - head)), float(np.linalg.norm(tip - tail))
        if min(to_head, to_tail) <= NEAR_END_RATIO * max(to_head, to_tail):
            # Back where one end was last seen, far from the other (a cable that left
            # broadside, its ends apart): it is that end.
            head_is_tip = to_head < to_tail
        elif abs(ends_seen_s[0] - ends_seen_s[1]) > 1e-6:
            head_is_tip = ends_seen_s[0] > ends_seen_s[1]
        else:
            head_is_tip = to_head <= to_tail
        return head_is_tip == candidate.tips[0]
    straight = np.linalg.norm(first - head) + np.linalg.norm(last - tail)
    crossed = np.linalg.norm(first - tail) + np.linalg.norm(last - head)
    return straight <= crossed


def _rigid_misfit(a: np.ndarray, b: np.ndarray) -> float:
    """RMS distance (px) between two point lists laid rigidly (turned and moved) on each
    other."""
    a_mean, rotation, b_mean = rigid_fit(a, b)
    laid = (a - a_mean) @ rotation.T
    return float(np.sqrt(((laid - (b - b_mean)) ** 2).sum(axis=1).mean()))


def _sliding_misfit(seen: np.ndarray, track_joints: np.ndarray) -> tuple[float, int]:
    """The best rigid misfit (px) of ``seen`` laid along the track from each of its
    joints on (joint ``i`` of ``seen`` on joint ``k + i`` of the track), and that ``k``;
    0 where the shape cannot tell (no offset fits clearly better than from the track's
    first joint)."""
    count = min(len(seen), len(track_joints))
    if count < 3:
        return 0.0, 0
    misfits = [
        _rigid_misfit(track_joints[k : k + count], seen[:count])
        for k in range(len(track_joints) - count + 1)
    ]
    best = int(np.argmin(misfits))
    if misfits[0] <= SHAPE_MARGIN * misfits[best] + 1.0:
        return misfits[best], 0
    return misfits[best], best


def _shape_misfit(candidate: Candidate, track_joints: np.ndarray, first_is_head: bool) -> float:
    """RMS distance (px) between the candidate's joints and the track's, laid rigidly on
    each other from one end: the candidate's free end when it has exactly one (it may
    show only part of the cable), else its first joint, paired with the track's end the
    hypothesis (``first_is_head``) gives it."""
    from_last = candidate.tips[1] and not candidate.tips[0]
    seen = candidate.joints[::-1] if from_last else candidate.joints
    # The track's end paired with the candidate's chosen end under the hypothesis.
    track = track_joints if first_is_head != from_last else track_joints[::-1]
    count = min(len(seen), len(track))
    if count < 3:
        return 0.0
    return _rigid_misfit(track[:count], seen[:count])


def where_it_left(
    candidate: Candidate,
    track_length: int,
    last_seen: tuple[np.ndarray, np.ndarray] | None,
    radius: float,
    step: float,
) -> tuple[bool, int | None] | None:
    """Which way round, and from which of the track's joints on, the candidate shows its
    cable, when it lies where the track was seen last: cable comes back into view where
    it went out, the material that left last coming back first (the cable is continuous
    across the picture's edge, or the edge of what hid it).

    ``last_seen`` is ``(joint numbers, points)``: the track's joints seen the last frame
    it was seen, and where they were then. The candidate lies there when one of its
    joints is within :data:`LEFT_GATE` segments (or 4 radii) of one of those points.
    Then a free end it shows (exactly one) is the track's end nearest, along the track,
    to the stretch seen last (when clearly nearer than the other: at most half as far);
    a candidate without one is laid on the track at the offset and way round that put
    its joints nearest the joints seen last (the candidate's joint ``i``, from the chosen
    end, on the track's joint ``offset + i``, over :data:`LEFT_OVERLAP` joints or more,
    the other way round clearly worse).
    Returns ``(first_is_head, offset)`` (offset None: lay from the free end; else
    clipped at 0), or None when this cannot tell (the shape must).
    """
    if last_seen is None or len(last_seen[0]) == 0:
        return None
    numbers, points = last_seen
    gate = max(LEFT_GATE * step, 4.0 * radius)
    apart = np.linalg.norm(candidate.joints[:, None, :] - points[None, :, :], axis=2)
    if float(apart.min()) > gate:
        return None
    if candidate.tips[0] != candidate.tips[1]:
        to_first = int(numbers.min())
        to_last = track_length - 1 - int(numbers.max())
        if min(to_first, to_last) > 0.5 * max(to_first, to_last):
            return None
        free_end_is_head = to_first < to_last
        return free_end_is_head == candidate.tips[0], None
    if candidate.tips[0] or len(numbers) < LEFT_OVERLAP:
        return None
    where = np.full((track_length, 2), np.nan)
    where[numbers] = points
    count = len(candidate.joints)
    best: dict[bool, tuple[float, int]] = {}
    for first_is_head in (True, False):
        seen = candidate.joints if first_is_head else candidate.joints[::-1]
        for offset in range(-count + LEFT_OVERLAP, track_length - LEFT_OVERLAP + 1):
            paired_numbers = offset + np.arange(count)
            inside = (paired_numbers >= 0) & (paired_numbers < track_length)
            paired = where[paired_numbers[inside]]
            known = np.isfinite(paired[:, 0])
            if np.count_nonzero(known) < LEFT_OVERLAP:
                continue
            cost = float(np.linalg.norm(seen[inside][known] - paired[known], axis=1).mean())
            if first_is_head not in best or cost < best[first_is_head][0]:
                best[first_is_head] = (cost, offset)
    if not best:
        return None
    way = min(best, key=lambda k: best[k][0])
    cost, offset = best[way]
    if cost > gate:
        return None
    if (not way) in best and best[not way][0] <= SHAPE_MARGIN * cost + 1.0:
        return None
    return way, max(offset, 0)


def revived_joints(
    old: np.ndarray,
    candidate: Candidate,
    first_is_head: bool,
    step: float,
    offset: int | None = None,
) -> np.ndarray:
    """A remembered track's joints laid along a candidate that shows its cable again.

    The joints from the matching end follow the candidate; the rest keep the track's old
    shape, moved rigidly to join on (they are outside the picture or hidden). The
    matching end is the track's end the candidate's free end is, when it shows exactly
    one (the other end of the candidate may be the picture's edge, mid-cable). One that
    shows no free end is laid from joint ``offset`` on when that is known
    (:func:`where_it_left`), else where along the track its shape fits best
    (:func:`_sliding_misfit`), else from the track's first end.
    """
    seen = candidate.joints if first_is_head else candidate.joints[::-1]
    tips = candidate.tips if first_is_head else candidate.tips[::-1]
    if tips[1] and not tips[0]:  # the candidate shows the track's last end
        return _laid_from_first(old[::-1], seen[::-1], step)[::-1]
    if offset is None and not tips[0]:
        offset = _sliding_misfit(seen, old)[1]
    if not tips[0] and offset and offset > 0:
        # From joint ``offset`` on along the candidate; the joints before it keep their
        # shape, moved rigidly to join on.
        laid = _laid_from_first(old[offset:], seen, step)
        reference = slice(0, min(6, len(laid)))
        head = _rigidly(old[:offset], old[offset:][reference], laid[reference])
        return np.vstack([head, laid])
    return _laid_from_first(old, seen, step)


def _laid_from_first(old: np.ndarray, seen: np.ndarray, step: float) -> np.ndarray:
    """``old``'s joints laid along ``seen`` from its first joint on, ``step`` apart; those
    beyond its end keep ``old``'s shape, moved rigidly to join on."""
    arcs = arc_lengths(seen)
    n = len(old)
    wanted = np.arange(n) * step
    inside = wanted <= arcs[-1] + 1e-9
    joints = old.copy()
    placed = points_along(seen, arcs, wanted[inside])
    count = int(np.count_nonzero(inside))
    if count == n:
        return placed
    reference = slice(max(count - 6, 0), count)
    joints[:count] = placed
    joints[count:] = _rigidly(old[count:], old[reference], placed[reference])
    return joints


def _rigidly(points: np.ndarray, source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """``points`` turned and moved as the rigid motion taking ``source`` onto ``target``
    (least squares)."""
    source_mean, rotation, target_mean = rigid_fit(source, target)
    return (points - source_mean) @ rotation.T + target_mean


def _overlap(points: np.ndarray, polyline: np.ndarray, gate: float) -> float:
    """Share of ``points`` within ``gate`` of the polyline's vertices or segments."""
    if len(polyline) < 2:
        return 0.0
    return float(np.mean(distances_to_polyline(points, polyline) <= gate))


OTHER_END_TURN = 0.5
"""A candidate is more of a track seen in part, come into view elsewhere, when turning
the track's stretch out of view about its outermost seen joint by at most this much
(radians) ..."""
OTHER_END_FIT = 2.0
"""... lays that stretch's joints within this many segments of it, on average."""


@dataclass(frozen=True)
class OtherEnd:
    """A candidate that is more of a track seen in part (its stretch out of view): its far
    end, or a stretch of it with no free end.

    Attributes
    ----------
    track : int
    end : int
        The track's end beyond whose outermost seen joint the candidate lies.
    joints : (N, 2) ndarray
        The track's joints, its stretch beyond that joint turned (and bent, towards the
        candidate) onto the candidate.
    tip : bool
        Whether the candidate shows that end (its free end).
    """

    track: int
    end: int
    joints: np.ndarray
    tip: bool = True


def other_end(
    candidate: Candidate,
    tracks: list[tuple[np.ndarray, np.ndarray, float, np.ndarray | None]],
    step: float,
) -> OtherEnd | None:
    """The track the candidate is more of, if one is: a cable seen in part (out of view
    beyond one end) whose far end, or another stretch, comes into view elsewhere (across
    the picture, or as a cable comes in broadside over an edge, in pieces).

    The track's stretch beyond its outermost seen joint keeps the shape it had (out of
    view nothing measures it), but turned a little about that joint it must lay its
    joints on the candidate's (within :data:`OTHER_END_TURN` and
    :data:`OTHER_END_FIT`): a candidate with exactly one free end from the track's end
    inwards, one with none either way round at the offset along the stretch that fits
    best (turning about the seen joint fixes how far out it lies). It must look like
    the track (colour, width). ``tracks`` are ``(joints, seen, radius, colour)`` of the
    tracks seen this frame.
    """
    if candidate.tips[0] and candidate.tips[1]:
        return None
    tip = candidate.tips[0] or candidate.tips[1]
    if tip:
        ways = [candidate.joints if candidate.tips[0] else candidate.joints[::-1]]
    else:
        ways = [candidate.joints, candidate.joints[::-1]]
    m = len(candidate.joints)
    best, best_fit = None, OTHER_END_FIT * step
    for index, joints, seen_at in _alike(candidate, tracks, step):
        n = len(joints)
        for end in (0, 1):
            anchor = int(seen_at[0] if end == 0 else seen_at[-1])
            beyond = anchor if end == 0 else n - 1 - anchor
            if beyond < m + (2 if tip else 1):
                continue
            # Joints out from the anchor (``reach`` of them) paired with the candidate's:
            # from the track's end inwards with the candidate's free end, or at every
            # offset out along the stretch.
            firsts = np.array([beyond - m + 1]) if tip else np.arange(1, beyond - m + 2)
            reach = firsts[:, None] + np.arange(m)[None, :]
            if tip:
                reach = reach[:, ::-1]
            numbers = anchor - reach if end == 0 else anchor + reach
            pivot = joints[anchor]
            q = joints[numbers] - pivot  # (offsets, m, 2)
            for seen in ways:
                c = seen - pivot
                cross = np.sum(q[..., 0] * c[:, 1] - q[..., 1] * c[:, 0], axis=1)
                dot = np.sum(q[..., 0] * c[:, 0] + q[..., 1] * c[:, 1], axis=1)
                angles = np.arctan2(cross, dot)
                cos, sin = np.cos(angles)[:, None], np.sin(angles)[:, None]
                turned = np.stack(
                    [cos * q[..., 0] - sin * q[..., 1], sin * q[..., 0] + cos * q[..., 1]],
                    axis=2,
                )
                misfits = np.mean(np.linalg.norm(turned - c[None], axis=2), axis=1)
                misfits[np.abs(angles) > OTHER_END_TURN] = np.inf
                k = int(np.argmin(misfits))
                if misfits[k] >= best_fit:
                    continue
                laid = _turned_onto(joints, anchor, end, float(angles[k]), numbers[k], seen)
                best, best_fit = OtherEnd(index, end, laid, tip), float(misfits[k])
    return best


def _turned_onto(joints, anchor, end, angle, numbers, seen) -> np.ndarray:
    """The track's joints, its stretch beyond ``anchor`` turned by ``angle`` about it,
    then bent so that joints ``numbers`` lie on ``seen``: the shift they need grows from
    nothing at the anchor to the whole at the farthest of them, and the joints beyond
    take it whole."""
    pivot = joints[anchor]
    cos, sin = math.cos(angle), math.sin(angle)
    rotation = np.array([[cos, -sin], [sin, cos]])
    stretch = np.arange(anchor) if end == 0 else np.arange(anchor + 1, len(joints))
    new = joints.copy()
    new[stretch] = (joints[stretch] - pivot) @ rotation.T + pivot
    shift = np.mean(seen - new[numbers], axis=0)
    farthest = float(np.max(np.abs(numbers - anchor)))
    ramp = np.minimum(np.abs(stretch - anchor) / farthest, 1.0)
    new[stretch] += ramp[:, None] * shift[None, :]
    new[numbers] = seen
    return new
