"""Tracking: a track that is two cables, split again.

Two tracks are joined (:mod:`~service.perception.track_merging`), and a track grows past
a free end it had seen (:func:`~service.perception.track_update.observe`), on one frame's
detection: a chain holding both. A detection may join two cables of one colour where
they meet (a crossing passing through the picture's edge leaves a V there), and then
one track holds two cables. Each such junction is kept on the track as a :class:`Seam`
for ``memory_s``. When, in ``confirm_frames`` frames in a row, the parts on either side
of a seam fit two separate chains of the detection, no chain holds both, and the two
parts' ends do not face each other across a straight gap (where the tracker would join
them again, ``track_merging.bridges``), the track is split there: the older part keeps
the id, the newer part gets back the id it had before the join (a new one when it was
grown, not joined).

A cable with one stretch hidden (under something) also fits two chains on either side
of a gap; where its parts' ends face each other across it, it is not split. The
geometry alone cannot tell two cables from one: two cables leaving the picture side by
side look like one cable bending round just outside it (a U-turn of width ``2 r`` for a
cable whose tightest bend has radius ``r``). What tells them apart is the history: they
were two tracks, joined on a few frames' detection, and the detection now shows them
apart, frame after frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from service.perception.track_matching import Fit, Piece
from service.perception.track_merging import ends_face

MIN_PART_SEGMENTS = 3.0
"""Segments of a track each of two chains must hold, on its own side of a seam, for the
two to be taken for two cables."""
SEAM_SLACK_SEGMENTS = 1.0
"""How far (segments) a chain may reach past a seam and still be on one side of it."""


@dataclass(frozen=True)
class Seam:
    """Where a track was joined (or grown past a free end) on one frame's evidence.

    Attributes
    ----------
    number : int
        Joint number (``first_joint`` + index) of the older part's joint at the seam.
    side : int
        0: the newer part is the joints numbered below ``number``; 1: above it.
    revive : int or None
        Id of the track joined on there (None: the track grew there).
    born : int
        The frame that track began in (the track's own when it grew).
    made_s : float
        When the seam was made.
    apart : int
        Frames in a row its two parts fitted two separate chains.
    from_seam : bool
        Whether the track joined on was numbered from its end at the seam.
    """

    number: int
    side: int
    revive: int | None
    born: int
    made_s: float
    apart: int = 0
    from_seam: bool = False


@dataclass(frozen=True)
class _End:
    """A chain's end on one side of a seam: its outermost point towards the seam and the
    direction out of it (towards the seam)."""

    point: np.ndarray
    outward: np.ndarray


def _face(a: _End, b: _End) -> bool:
    """Whether two parts' ends face each other across a straight gap, as the tracker
    joins parts without a chain between them (``track_merging.bridges``)."""
    return ends_face(a.point, a.outward, b.point, b.outward)


def track_seams(
    seams: tuple[Seam, ...],
    first_joint: int,
    n: int,
    fitted: list[tuple[Piece, Fit]],
    step: float,
    now: float,
    memory_s: float,
) -> tuple[Seam, ...]:
    """The seams of a track after this frame's fit: each one's count of frames in a row
    apart (see the module's documentation); seams older than ``memory_s``, or no longer
    on the track, are dropped.

    ``fitted`` are the detection's pieces that fit the track, as laid along its joints
    before this frame's growth (``first_joint`` and ``n`` are those joints').
    """
    kept = []
    for seam in seams:
        index = seam.number - first_joint
        if now - seam.made_s > memory_s or not 0 <= index < n:
            continue
        apart = _apart(index, fitted, step)
        kept.append(replace(seam, apart=seam.apart + 1 if apart else 0))
    return tuple(kept)


def _apart(index: int, fitted, step: float) -> bool:
    """Whether the parts on either side of joint ``index`` fit two separate chains whose
    ends there do not face each other."""
    if len(fitted) < 2:
        return False
    spans: dict[int, list[float]] = {}
    ends: dict[tuple[int, int], tuple[float, _End]] = {}
    for piece, fit in fitted:
        arcs = (fit.offset, fit.offset + fit.sign * piece.length)
        for arc, at in zip(arcs, (0, len(piece.joints) - 1), strict=True):
            spans.setdefault(piece.chain, [math.inf, -math.inf])
            low, high = spans[piece.chain]
            spans[piece.chain] = [min(low, arc / step), max(high, arc / step)]
            inward = 1 if at == 0 else -1
            reach = min(2, len(piece.joints) - 1)
            outward = piece.joints[at] - piece.joints[at + inward * reach]
            norm = float(np.linalg.norm(outward))
            if norm < 1e-9:
                continue
            end = _End(piece.joints[at], outward / norm)
            # Per chain, its end nearest the seam from below (0) and from above (1).
            for towards in (0, 1):
                key = (piece.chain, towards)
                distance = index - arc / step if towards == 0 else arc / step - index
                if key not in ends or distance < ends[key][0]:
                    ends[key] = (distance, end)
    slack = SEAM_SLACK_SEGMENTS
    below, above = [], []
    for chain, (low, high) in spans.items():
        under = index - low  # segments it holds below the seam
        over = high - index
        if under > slack and over > slack:
            return False  # one chain holds both parts: one cable
        if under >= MIN_PART_SEGMENTS and over <= slack:
            below.append(chain)
        elif over >= MIN_PART_SEGMENTS and under <= slack:
            above.append(chain)
    for low_chain in below:
        for high_chain in above:
            a, b = ends.get((low_chain, 0)), ends.get((high_chain, 1))
            if a is None or b is None:
                continue
            if not _face(a[1], b[1]):
                return True
    return False


def split_parts(joints: np.ndarray, first_joint: int, seam: Seam) -> tuple[slice, slice]:
    """The older and the newer part of a track's joints at a seam (index slices); the
    seam's joint stays with the older part."""
    index = seam.number - first_joint
    if seam.side == 0:
        return slice(index, len(joints)), slice(0, index)
    return slice(0, index + 1), slice(index + 1, len(joints))


def split_tracks(tracks: list, next_id: int, confirm_frames: int, frame: int) -> tuple[list, int]:
    """The tracks with each one whose seam has been apart for ``confirm_frames`` frames in
    a row split there (the same evidence a new track needs), and the next free id.

    ``tracks`` are the tracker's records (``dataclasses.replace`` makes the parts): the
    older part keeps the record's id, the newer one takes the id it had before it was
    joined on when no track holds that id now (numbered from the same end as then),
    otherwise ``next_id`` (numbered from its far end).
    """
    result = []
    for track in tracks:
        due = [seam for seam in track.seams if seam.apart >= confirm_frames]
        if not due:
            result.append(track)
            continue
        seam = max(due, key=lambda s: s.made_s)  # the latest join is undone first
        older, newer = split_parts(track.joints, track.first_joint, seam)
        # The id the newer part had: joined on at this seam, or at one within it (a
        # track that grew past its end along another cable, then that cable's track
        # joined on).
        held = {t.id for t in tracks} | {t.id for t in result}
        before = [seam, *(s for s in track.seams if _within(s, track, newer))]
        known = [s for s in before if s.revive is not None and s.revive not in held]
        revived = max(known, key=lambda s: s.made_s) if known else None
        if revived is not None:
            new_id, born = revived.revive, revived.born
        else:
            new_id, born = next_id, frame
            next_id += 1
        kept_seams = tuple(s for s in track.seams if s is not seam and _within(s, track, older))
        result.append(_part(track, older, seam.side, track.id, track.born, kept_seams, True))
        part = _part(track, newer, seam.side, new_id, born, (), False)
        # Numbered as it was: from its far end, or from its end towards the seam.
        result.append(_reversed(part) if revived is not None and revived.from_seam else part)
    return result, next_id


def _reversed(track):
    """The track numbered from its other end."""
    free = None if track.free_end_points is None else track.free_end_points[::-1].copy()
    return replace(
        track,
        joints=np.ascontiguousarray(track.joints[::-1]),
        velocity=np.ascontiguousarray(track.velocity[::-1]),
        tips=(track.tips[1], track.tips[0]),
        ends_seen_s=(track.ends_seen_s[1], track.ends_seen_s[0]),
        ends_last=track.ends_last[::-1].copy(),
        seen=None if track.seen is None else track.seen[::-1],
        free_end_points=free,
    )


def _within(seam: Seam, track, part: slice) -> bool:
    index = seam.number - track.first_joint
    return part.start <= index < part.stop


def _part(track, part: slice, side: int, track_id: int, born: int, seams, older: bool):
    """One part of a split track: its end at the seam is open. The older part keeps the
    joints' numbers; the newer one is numbered from its far end (its end beyond which the
    track went on), the seam being where it was joined on."""
    joints, velocity = track.joints[part], track.velocity[part]
    seen = None if track.seen is None else track.seen[part]
    # Which end of the part lies at the seam: the older part's end on the newer's side.
    seam_end = side if older else 1 - side
    tips = [track.tips[0], track.tips[1]]
    tips[seam_end] = False
    first_joint = track.first_joint + part.start if older else 0
    ends_seen = list(track.ends_seen_s)
    if not older and seam_end == 0:  # number the newer part from its far end
        joints, velocity = joints[::-1], velocity[::-1]
        seen = None if seen is None else seen[::-1]
        tips = tips[::-1]
        ends_seen = ends_seen[::-1]
    free = track.free_end_points
    if free is not None:
        free = free.copy() if older else free[[1, 0] if seam_end == 0 else [0, 1]].copy()
        free[seam_end if older else 1] = np.nan
    return replace(
        track,
        id=track_id,
        joints=np.ascontiguousarray(joints),
        velocity=np.ascontiguousarray(velocity),
        first_joint=first_joint,
        tips=(tips[0], tips[1]),
        born=born,
        ends_seen_s=(ends_seen[0], ends_seen[1]),
        ends_last=np.array([joints[0], joints[-1]]),
        seen=seen,
        shape=None,
        free_end_points=free,
        length_known=False,
        last_seen=None,
        seams=seams,
    )
