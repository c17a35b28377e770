"""Tracking: two tracks that are one cable, joined.

A cable can start as two tracks: the detection of the first frame was cut where the
cable crossed another one, or the cable was seen in two parts (under something, at the
picture's edge) before the parts were known to be one. When a later detection joins
them, one chain of it holding pieces of both, with their ends facing each other
across what lies between those pieces (a crossing, a hidden stretch), the two look
alike (colour, width) and the gap is short, the younger track is joined onto the older.
Each track's end is taken at its outermost joint seen this frame (the joints beyond it
are guesses); the younger's must be open, the older's open or a free end hidden now (a
free end the track remembers, while its stretch beyond the last seen joint went astray).
The younger's joints are laid on from the older's outermost seen joint, through the
chain's stretch between the pieces, each ``l_s`` from the one before (the older's hidden
joints beyond are laid again; none is dropped); the older track keeps its id and its
joints' numbers (joints added before its first one count down from it), the younger
one's id is retired.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from service.perception import _geometry_kernels
from service.perception.track_identity import COLOUR_TOLERANCE, RADIUS_TOLERANCE, colour_distance
from service.perception.track_matching import Chains, Fit, Piece
from service.perception.track_update import turns_too_sharply

MAX_GAP_SEGMENTS = 8.0
"""Chain arc (in segments) between the two pieces beyond which they are not joined."""


@dataclass(frozen=True)
class Join:
    """Track ``younger`` joined onto end ``end`` of track ``older`` (indices)."""

    older: int
    younger: int
    end: int
    anchor: int  # the older track's outermost joint seen at that end: the join starts there
    joints: np.ndarray  # the joints laid beyond the anchor, nearest first
    younger_end: int  # the end of the younger track that faced the older one
    tip: bool  # whether the younger track's far end is a tip


def joins(
    tracks,
    pieces: list[Piece],
    fits: list[Fit | None],
    chains: Chains,
) -> list[Join]:
    """The joins this frame's detection calls for (see the module's documentation).

    ``tracks`` are the tracker's records after this frame's registration (with
    ``joints``, ``tips``, ``colour``, ``radius``, ``born``, ``id``, ``seen``).
    """
    step = chains.step
    by_chain: dict[int, list[int]] = {}
    for index, (piece, fit) in enumerate(zip(pieces, fits, strict=True)):
        if fit is not None:
            by_chain.setdefault(piece.chain, []).append(index)
    found: list[Join] = []
    used: set[int] = set()
    for chain_index, members in by_chain.items():
        members.sort(key=lambda i: pieces[i].first)
        for a, b in itertools.pairwise(members):
            first, second = fits[a], fits[b]
            assert first is not None and second is not None
            if first.track == second.track or {first.track, second.track} & used:
                continue
            gap = (
                chains.arcs[chain_index][pieces[b].first] - chains.arcs[chain_index][pieces[a].last]
            )
            if gap > MAX_GAP_SEGMENTS * step:
                continue
            # Along the chain, piece a runs towards its track's end 1 when its sign is +1.
            end_a = 1 if first.sign > 0 else 0
            end_b = 0 if second.sign > 0 else 1
            track_a, track_b = tracks[first.track], tracks[second.track]
            anchor_a, anchor_b = _anchor(track_a, end_a), _anchor(track_b, end_b)
            a_is_older = (track_a.born, track_a.id) <= (track_b.born, track_b.id)
            if _stops(track_a, end_a, anchor_a, a_is_older) or _stops(
                track_b, end_b, anchor_b, not a_is_older
            ):
                continue
            if colour_distance(track_a.colour, track_b.colour) > COLOUR_TOLERANCE:
                continue
            ratio = max(track_a.radius, track_b.radius) / max(
                min(track_a.radius, track_b.radius), 1e-6
            )
            if ratio > RADIUS_TOLERANCE:
                continue
            if not _faces(end_a, anchor_a, pieces[a], first, step) or not _faces(
                end_b, anchor_b, pieces[b], second, step
            ):
                continue
            if a_is_older:
                older, younger, older_end, younger_end = first.track, second.track, end_a, end_b
                older_anchor, younger_anchor = anchor_a, anchor_b
                bridge = chains.joints[chain_index][pieces[a].last : pieces[b].first + 1]
            else:
                older, younger, older_end, younger_end = second.track, first.track, end_b, end_a
                older_anchor, younger_anchor = anchor_b, anchor_a
                bridge = chains.joints[chain_index][pieces[a].last : pieces[b].first + 1][::-1]
            laid = _laid(
                tracks[older].joints[older_anchor],
                bridge,
                tracks[younger].joints,
                younger_end,
                younger_anchor,
                step,
            )
            if laid is None or _too_sharp(
                tracks, (older, younger), (older_end, younger_end), (older_anchor, younger_anchor)
            ):
                continue
            tip = tracks[younger].tips[1 - younger_end]
            found.append(Join(older, younger, older_end, older_anchor, laid, younger_end, tip))
            used |= {first.track, second.track}
    return found


def _too_sharp(tracks, pair, ends, anchors) -> bool:
    """Whether a cable cannot go on from the older track's outermost seen joint at its
    end into the younger's at its end
    (:func:`~service.perception.track_update.turns_too_sharply`)."""
    parts = []
    for index, end, anchor in zip(pair, ends, anchors, strict=True):
        joints = tracks[index].joints
        # In order towards the junction.
        parts.append(
            joints[anchor : anchor + 3][::-1]
            if end == 0
            else joints[max(anchor - 2, 0) : anchor + 1]
        )
    radius = min(tracks[pair[0]].radius, tracks[pair[1]].radius)
    return turns_too_sharply(parts[0], parts[1][::-1], radius)


def _anchor(track, end: int) -> int:
    """The track's outermost joint seen this frame at one end: the joints beyond it are
    guesses (hidden, predicted), so a join is measured, and laid, from there."""
    seen = np.ones(len(track.joints), bool) if track.seen is None else track.seen
    seen_at = np.flatnonzero(seen)
    if len(seen_at) == 0:
        return 0 if end == 0 else len(track.joints) - 1
    return int(seen_at[0] if end == 0 else seen_at[-1])


def _stops(track, end: int, anchor: int, older: bool) -> bool:
    """Whether the track's end is a free end that nothing goes on from: always for the
    younger track (what it knows of its ends is recent), and for the older one when the
    end was seen this frame. A free end of the older track that is hidden is where the
    track last saw it, and its joints beyond the outermost seen one are guesses that a
    chain showing the cable going on from there replaces."""
    if not track.tips[end]:
        return False
    return not older or anchor == (0 if end == 0 else len(track.joints) - 1)


def _faces(end: int, anchor: int, piece: Piece, fit: Fit, step: float) -> bool:
    """Whether the piece reaches to within a few segments of the track's outermost seen
    joint at that end (``anchor``), or beyond it."""
    ends = (fit.offset, fit.sign * piece.length + fit.offset)
    limit = 3.0 * step
    if end == 0:
        return min(ends) <= anchor * step + limit
    return max(ends) >= anchor * step - limit


def _laid(start, bridge, younger_joints, younger_end, younger_anchor, step):
    """The joints that continue the older track from ``start`` (its anchor) through the
    bridge along the younger one, each ``step`` from the one before: the younger
    track's joints from its own anchor on (the ones beyond it are guesses)."""
    rest = (
        younger_joints[younger_anchor:]
        if younger_end == 0
        else younger_joints[: younger_anchor + 1][::-1]
    )
    # From the older end, along the detection's stretch between the pieces, then along
    # the younger track from its facing end (skipping its joints before the bridge's end).
    target = bridge[-1] if len(bridge) else rest[0]
    nearest = int(np.argmin(np.linalg.norm(rest - target, axis=1)))
    line = np.vstack([start, bridge, rest[nearest:]])
    keep = np.concatenate([[True], np.linalg.norm(np.diff(line, axis=0), axis=1) > 1e-9])
    line = np.ascontiguousarray(line[keep])
    if len(line) < 2:
        return None
    walked, _ = _geometry_kernels.resample_kernel(line, float(step))
    if len(walked) < 2 or not math.isfinite(float(walked[-1, 0])):
        return None
    return walked[1:]


MAX_BRIDGE_SEGMENTS = 5.0
"""Gap (in segments) between two tracks' facing ends across which they may be joined
without a chain of the detection between them ..."""
MAX_BRIDGE_TURN = math.radians(30.0)
"""... going on straight to within this angle (less than the shallowest crossing)."""


@dataclass(frozen=True)
class Bridge:
    """Track ``younger`` joined onto track ``older`` across a short straight gap: the
    joints beyond ``older``'s ``anchor`` (its outermost seen joint at ``end``) are laid
    again, through the gap and along the younger track (``joints``, nearest first)."""

    older: int
    younger: int
    end: int
    anchor: int
    joints: np.ndarray
    tip: bool


def ends_face(point_a, outward_a, point_b, outward_b) -> bool:
    """Whether two ends (points, unit directions out of their tracks) face each other
    across a straight gap: each end's direction and the gap line up to within
    :data:`MAX_BRIDGE_TURN`."""
    limit = math.cos(MAX_BRIDGE_TURN)
    if float(outward_a @ -outward_b) < limit:
        return False
    gap = point_b - point_a
    length = float(np.linalg.norm(gap))
    if length < 1e-9:
        return True
    gap = gap / length
    return float(outward_a @ gap) >= limit and float(outward_b @ -gap) >= limit


def bridges(tracks, step: float, taken: set[int]) -> list[Bridge]:
    """Joins of tracks whose open ends face each other across a short, straight gap.

    Both must have been seen this frame and look alike; measured from each one's
    outermost seen joint at that end, the gap is at most :data:`MAX_BRIDGE_SEGMENTS`
    segments and the ends and the gap line up within :data:`MAX_BRIDGE_TURN`. Tracks in
    ``taken`` (already joined this frame) are left alone.
    """
    ends = []
    for index, track in enumerate(tracks):
        if track.unseen or index in taken:
            continue
        seen = np.ones(len(track.joints), bool) if track.seen is None else track.seen
        seen_at = np.flatnonzero(seen)
        if len(seen_at) < 3:
            continue
        for end in (0, 1):
            if track.tips[end]:
                continue
            anchor = int(seen_at[0] if end == 0 else seen_at[-1])
            body = track.joints[anchor:] if end == 0 else track.joints[: anchor + 1]
            span = min(3, len(body) - 1)
            outward = body[0] - body[span] if end == 0 else body[-1] - body[-1 - span]
            outward = outward / max(float(np.linalg.norm(outward)), 1e-12)
            ends.append((index, end, anchor, track.joints[anchor], outward))
    found: list[Bridge] = []
    used: set[int] = set()
    pairs = []
    for i, (a, end_a, anchor_a, point_a, out_a) in enumerate(ends):
        for b, end_b, anchor_b, point_b, out_b in ends[i + 1 :]:
            if a == b:
                continue
            length = float(np.linalg.norm(point_b - point_a))
            if length > MAX_BRIDGE_SEGMENTS * step or not ends_face(point_a, out_a, point_b, out_b):
                continue
            first, second = tracks[a], tracks[b]
            if colour_distance(first.colour, second.colour) > COLOUR_TOLERANCE:
                continue
            ratio = max(first.radius, second.radius) / max(min(first.radius, second.radius), 1e-6)
            if ratio > RADIUS_TOLERANCE:
                continue
            pairs.append((length, (a, end_a, anchor_a), (b, end_b, anchor_b)))
    for _, one, other in sorted(pairs, key=lambda item: item[0]):
        if one[0] in used or other[0] in used:
            continue
        (older, end, anchor), (younger, younger_end, younger_anchor) = sorted(
            (one, other), key=lambda item: (tracks[item[0]].born, tracks[item[0]].id)
        )
        young = tracks[younger].joints
        rest = young[younger_anchor:] if younger_end == 0 else young[: younger_anchor + 1][::-1]
        line = np.ascontiguousarray(np.vstack([tracks[older].joints[anchor], rest]))
        walked, _ = _geometry_kernels.resample_kernel(line, float(step))
        if len(walked) < 2:
            continue
        tip = tracks[younger].tips[1 - younger_end]
        found.append(Bridge(older, younger, end, anchor, walked[1:], tip))
        used |= {older, younger}
    return found
