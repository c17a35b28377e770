"""Tracking: one id and one fixed chain per cable through a video or a live stream.

:func:`advance` is the tracker: a pure function from the tracker's state and one frame's
detection (with the image, for colours and crossings) to the next state and the frame's
:class:`schemas.Tracks`. :class:`Tracker` holds the state for callers that want an object
(``tracker.update(image)`` detects, then advances). Nothing here reads or writes files.

Per frame:

1. **Predict.** Every track's joints move on with their smoothed velocity (px/s times
   the time since the last frame, so dropped frames are crossed).
2. **Register** (:mod:`~service.perception.track_matching`,
   :mod:`~service.perception.track_update`). The detection's chains are cut into pieces
   that are surely one cable; each piece is laid along the track it fits, as one offset
   of arc (a cable does not stretch, so a piece is a stretch of its track's arc); its
   joints' targets come from there, pinned by the cable's free ends where they are seen;
   the rest of the track follows its seen neighbours' motion; segment lengths are
   restored exactly, with a bending limit where nothing is seen. Open ends grow as more
   of the cable comes into view.
3. **Begin and recognise** (:mod:`~service.perception.track_identity`). Stretches no
   track holds become candidates, and tracks once seen in ``confirm_frames`` consecutive
   frames, with an old id when they are a remembered cable come back.
4. **Forget.** A track not seen for ``coast_s`` (or whose cable has left the picture) is
   only remembered, for ``memory_s``.

The detection seeds the tracks (the first frame of a session starts them at once) and
re-seeds them (a cable lost and found again), as the seed paper intends its detector to
serve a tracker.
"""

from __future__ import annotations

import math
import time
import uuid
from dataclasses import dataclass, replace

import numpy as np

from schemas import Detection, DetectParams, Track, TrackingStatus, TrackParams, Tracks
from service.perception import _tracking_kernels
from service.perception.errors import InvalidInputError
from service.perception.geometry import distances_to_polyline
from service.perception.pipeline import detect
from service.perception.segmenter import Segmenter
from service.perception.track_crossings import track_crossings
from service.perception.track_identity import (
    COLOUR_TOLERANCE,
    Candidate,
    Continuation,
    OtherEnd,
    colour_distance,
    confirm,
    continuation,
    orientation,
    other_end,
    revived_joints,
    similarity,
    unclaimed_stretches,
    waits,
    where_it_left,
)
from service.perception.track_matching import (
    Chains,
    Piece,
    cut_at_met_ends,
    detection_pieces,
    fit_pieces,
)
from service.perception.track_merging import Bridge, Join, bridges, joins
from service.perception.track_motion import ShapeWindow, motion, shape_window, tangents
from service.perception.track_splitting import Seam, split_tracks, track_seams
from service.perception.track_update import Observation, exact_chain, observe, register

VELOCITY_SMOOTHING = 0.5
"""Weight of this frame's motion in a track's velocity (the rest: the velocity before)."""
COLOUR_SMOOTHING = 0.1
"""Weight of this frame's colour in a track's colour."""
UNSEEN_DAMPING = 0.7
"""A track not seen in a frame keeps this share of its velocity."""
MAX_STEP_S = 10.0
STEADY_FRAMES = 3
"""Frames a track must have been seen in a row before its velocity narrows its search."""
"""Longest time step used for prediction (a stream that stalled)."""


@dataclass(frozen=True, eq=False)
class TrackRecord:
    """One track in the tracker's state (arrays are never changed after creation).

    Attributes
    ----------
    id : int
    joints, velocity : (N, 2) ndarray
        Positions (px) and velocities (px/s) of the joints.
    first_joint : int
        The number of ``joints[0]`` (0, or negative after growth at the first end).
    tips : (bool, bool)
        Whether each end is the cable's free end.
    radius : float
    colour : (3,) ndarray or None
        Lab colour (OpenCV's uint8 scaling).
    born : int
        Frame (of the session) it began in.
    seen_frame : int
        Last frame it was seen in.
    seen_s : float
        Time of that frame.
    ends_seen_s : (float, float)
        Last time each end joint was seen.
    ends_last : (2, 2) ndarray
        Where each end joint was then.
    unseen : int
        Consecutive frames without being seen.
    steady : int
        Frames it was seen in a row since it began or came back: until a few, its
        velocity is not known and it looks for its cable further afield.
    seen : (N,) bool ndarray or None
        Which joints a piece of the detection placed, the last frame it was seen (None:
        all of them).
    free_end_points : (2, 2) ndarray or None
        Where each end's free end was seen the last frame (NaN: not seen).
    length_known : bool
        Both free ends of the cable were once seen in one frame, as far apart as the
        track's ends: it is as long as its cable, and never grows (cable seen beyond
        one end moves it along instead).
    last_seen : ((M,) int ndarray, (M, 2) ndarray) or None
        The joints (their indices into ``joints``) seen the last frame it was seen, and
        where they were then: where its cable went out of view.
    """

    id: int
    joints: np.ndarray
    velocity: np.ndarray
    first_joint: int
    tips: tuple[bool, bool]
    radius: float
    colour: np.ndarray | None
    born: int
    seen_frame: int
    seen_s: float
    ends_seen_s: tuple[float, float]
    ends_last: np.ndarray
    unseen: int = 0
    steady: int = 0  # frames seen in a row since it began or came back (its velocity known)
    seen: np.ndarray | None = None  # (N,) bool: joints seen in the last frame it was seen
    shape: ShapeWindow | None = None  # does its shape in view keep (shape_window)?
    free_end_points: np.ndarray | None = None  # (2, 2): free ends seen last frame (NaN: not)
    length_known: bool = False  # both free ends once seen at once, as far apart as its ends
    last_seen: tuple[np.ndarray, np.ndarray] | None = None  # (joint numbers, points) seen last
    seams: tuple[Seam, ...] = ()  # where it was joined on one frame's evidence (track_splitting)

    @property
    def length(self) -> float:
        return float(np.linalg.norm(np.diff(self.joints, axis=0), axis=1).sum())


@dataclass(frozen=True, eq=False)
class TrackerState:
    """Everything the tracker carries from one frame to the next.

    Attributes
    ----------
    session : str
        Names this run of the tracker (ids are unique within it).
    size : (int, int) or None
        ``(width, height)`` of its frames, once it has seen one.
    segment_length : float or None
    frame : int
        Frames given so far (lost ones included).
    time_s : float or None
        Time of the last frame.
    tracks : tuple of TrackRecord
        The tracks published: seen, or predicted for up to ``coast_s``.
    remembered : tuple of (TrackRecord, float)
        Tracks out of view and the time they went, for ``memory_s``.
    candidates : tuple of Candidate
    next_id : int
    frames_lost_total : int
    """

    session: str
    size: tuple[int, int] | None = None
    segment_length: float | None = None
    frame: int = 0
    time_s: float | None = None
    tracks: tuple[TrackRecord, ...] = ()
    remembered: tuple[tuple[TrackRecord, float], ...] = ()
    candidates: tuple[Candidate, ...] = ()
    next_id: int = 0
    frames_lost_total: int = 0


def new_state(session: str | None = None) -> TrackerState:
    """A tracker state with no tracks, in a new session (a random name by default)."""
    return TrackerState(session=session or uuid.uuid4().hex[:12])


def advance(
    state: TrackerState,
    detection: Detection,
    image: np.ndarray | None = None,
    *,
    timestamp_s: float | None = None,
    frames_lost: int = 0,
    params: TrackParams | None = None,
) -> tuple[TrackerState, Tracks]:
    """Track one frame: the next state and the frame's tracks.

    Parameters
    ----------
    state : TrackerState
        From :func:`new_state` or the previous call.
    detection : Detection
        This frame's detection (:func:`service.perception.detect`).
    image : ndarray, optional
        The frame (BGR or gray ``uint8``), for the cables' colours (to recognise one
        that comes back) and which strand is on top at crossings.
    timestamp_s : float, optional
        The frame's time in seconds; by default ``frame / params.fps``.
    frames_lost : int
        Frames lost (dropped, unreadable) since the previous call: the tracks are
        predicted across them and the count is reported.
    params : TrackParams, optional

    Returns
    -------
    (TrackerState, Tracks)
        A frame of another size (or segment length) than the session's starts a new
        session: ``tracks.tracking.reset`` says why.

    Raises
    ------
    InvalidInputError
        ``image`` does not match the detection's size, or ``frames_lost`` is negative.
    """
    started = time.perf_counter()
    params = TrackParams() if params is None else params
    if frames_lost < 0:
        raise InvalidInputError(f"frames_lost must be 0 or more, got {frames_lost}")
    size = (detection.width, detection.height)
    if image is not None and tuple(image.shape[:2]) != (detection.height, detection.width):
        raise InvalidInputError(
            f"image is {image.shape[1]}x{image.shape[0]} but the detection is "
            f"{detection.width}x{detection.height}"
        )
    reset = None
    step = detection.segment_length
    if state.size is not None and state.size != size:
        reset = (
            f"frame size changed from {state.size[0]}x{state.size[1]} to "
            f"{size[0]}x{size[1]}; tracks started afresh"
        )
    elif state.segment_length is not None and state.segment_length != step:
        reset = (
            f"segment length changed from {state.segment_length:g} to {step:g} px; "
            "tracks started afresh"
        )
    if reset is not None:
        state = new_state()
    frame = state.frame + frames_lost
    now = frame / params.fps if timestamp_s is None else float(timestamp_s)
    dt = 1.0 / params.fps if state.time_s is None else now - state.time_s
    dt = min(max(dt, 1e-3), MAX_STEP_S)

    predicted = [_predicted(track, dt) for track in state.tracks]
    chains = Chains.of(detection, image)
    gates = np.array([_gate(track, step, dt) for track in state.tracks])
    pieces = cut_at_met_ends(
        detection_pieces(chains), predicted, [t.tips for t in state.tracks], gates, step
    )
    # A piece of a colour unlike a track's is another cable's (where the detection
    # joined two cables at a crossing, say).
    colours = [chains.colour(piece.chain, piece.first, piece.last) for piece in pieces]
    compatible = np.array(
        [[colour_distance(c, t.colour) <= COLOUR_TOLERANCE for t in state.tracks] for c in colours],
        dtype=bool,
    ).reshape(len(pieces), len(state.tracks))
    fits = fit_pieces(pieces, predicted, gates, step, compatible)
    claimed = np.array([fit is not None for fit in fits], dtype=bool)
    chain_of_piece = [(p.chain, p.first, p.first + len(p.joints) - 1) for p in pieces]

    tracks: list[TrackRecord] = []
    for index, track in enumerate(state.tracks):
        fitted = [(p, f) for p, f in zip(pieces, fits, strict=True) if f and f.track == index]
        if not fitted:
            tracks.append(_unseen(track, predicted[index]))
            continue
        # Growth may take free pieces of the track's own colour only.
        taken = claimed | ~compatible[:, index]
        observation = observe(
            predicted[index],
            track.tips,
            fitted,
            chains,
            taken,
            chain_of_piece,
            _moving_tips(track),
            track.length_known,
        )
        seen_colour = chains.colour_of([piece for piece, _ in fitted])
        moved = _moved(track, predicted[index], observation, step, dt, now, frame, seen_colour)
        seams = track_seams(
            track.seams, track.first_joint, len(track.joints), fitted, step, now, params.memory_s
        )
        # Grown past a free end it had seen: the cable may go on there, or the detection
        # joined another cable to it.
        ends = (track.first_joint, track.first_joint + len(track.joints) - 1)
        grown = (observation.head_growth, observation.tail_growth)
        seams += tuple(
            Seam(ends[end], end, None, frame, now)
            for end in (0, 1)
            if track.tips[end] and len(grown[end])
        )
        tracks.append(replace(moved, seams=seams) if seams or track.seams else moved)
    tracks = _joined(tracks, joins(tracks, pieces, fits, chains), now)
    tracks = _bridged(tracks, bridges(tracks, step, set()), now)
    tracks, next_id = split_tracks(tracks, state.next_id, params.confirm_frames, frame)

    # Pieces near a track (held by it, or passed over as it grew) start nothing new.
    used = claimed | _near_tracks(pieces, tracks)
    found = unclaimed_stretches(chains, pieces, used, image, colours)
    gate = max([_gate_base(c.radius, step) for c in found], default=0.0)
    candidates = confirm(found, list(state.candidates), gate)
    seeding = state.frame == 0 and not state.tracks
    ready = [c for c in candidates if seeding or c.hits >= params.confirm_frames]
    waiting = [c for c in candidates if not (seeding or c.hits >= params.confirm_frames)]

    remembered = [
        (track, gone_s) for track, gone_s in state.remembered if now - gone_s <= params.memory_s
    ]
    for candidate in sorted(ready, key=lambda c: -c.length):
        joined = continuation(
            candidate, [(t.joints, _seen_mask(t), t.radius, t.colour) for t in tracks], step
        )
        if joined is not None:
            tracks[joined.track] = _extended(tracks[joined.track], joined, now)
            continue
        reached = other_end(
            candidate,
            [(t.joints, _seen_mask(t), t.radius, t.colour) for t in tracks if t.unseen == 0],
            step,
        )
        if reached is not None:
            tracks = _reached(tracks, reached, now, step)
            continue
        young = [(t.colour, t.radius) for t in tracks if _young(t) and not seeding]
        if waits(candidate, young, step):
            waiting.append(candidate)
            continue
        revived, tracks, remembered = _recognise(candidate, tracks, remembered, step, now, frame)
        if revived is None:
            tracks.append(_started(candidate, next_id, step, now, frame))
            next_id += 1
        else:
            tracks.append(revived)

    kept: list[TrackRecord] = []
    for track in tracks:
        gone = track.unseen > 0 and (
            (now - track.seen_s) > params.coast_s or not _in_picture(track, size, step)
        )
        if gone:
            remembered.append((track, now))
        else:
            kept.append(track)
    kept.sort(key=lambda t: t.id)

    output = _tracks(
        kept,
        detection,
        chains,
        image,
        TrackingStatus(
            session=state.session,
            frame=state.frame,
            frames_lost=frames_lost,
            frames_lost_total=state.frames_lost_total + frames_lost,
            reset=reset,
            remembered=sorted(track.id for track, _ in remembered),
        ),
    )
    next_state = TrackerState(
        session=state.session,
        size=size,
        segment_length=step,
        frame=frame + 1,
        time_s=now,
        tracks=tuple(kept),
        remembered=tuple(remembered),
        candidates=tuple(waiting),
        next_id=next_id,
        frames_lost_total=state.frames_lost_total + frames_lost,
    )
    elapsed = (time.perf_counter() - started) * 1000.0
    status = output.tracking.model_copy(update={"tracking_ms": elapsed})
    return next_state, output.model_copy(update={"tracking": status})


class Tracker:
    """The tracker with its state: ``update(image)`` per frame gives that frame's tracks.

    Parameters
    ----------
    params : DetectParams, optional
        For the detection that :meth:`update` runs.
    track_params : TrackParams, optional
    segmenter : callable, optional
        For ``params.segmentation == "model"`` (:mod:`service.perception.segmenter`).

    Examples
    --------
    >>> import cv2, numpy as np
    >>> tracker = Tracker()
    >>> for shift in range(3):
    ...     image = np.zeros((120, 200, 3), np.uint8)
    ...     _ = cv2.line(image, (10 + shift, 40), (190, 70 + shift), (0, 200, 255), 9)
    ...     tracks = tracker.update(image)
    >>> [(track.id, len(track.points)) for track in tracks.chains]
    [(0, 19)]
    """

    def __init__(
        self,
        params: DetectParams | None = None,
        track_params: TrackParams | None = None,
        *,
        segmenter: Segmenter | None = None,
    ) -> None:
        self.params = DetectParams() if params is None else params
        self.track_params = TrackParams() if track_params is None else track_params
        self.segmenter = segmenter
        self.state = new_state()
        self._lost = 0

    def update(
        self,
        image: np.ndarray | None,
        mask: np.ndarray | None = None,
        timestamp_s: float | None = None,
    ) -> Tracks:
        """Detect the cables in a frame and track them (see :func:`advance`).

        Raises
        ------
        InvalidInputError
            The frame cannot be used (see :func:`service.perception.detect`); the tracks
            are kept and the frame counts as lost (so does one the detection fails on).
        """
        try:
            detection = detect(image, self.params, mask, segmenter=self.segmenter)
        except BaseException:
            self._lost += 1  # the frame is lost to the tracks, whatever went wrong
            raise
        return self.follow(detection, image, timestamp_s)

    def follow(
        self,
        detection: Detection,
        image: np.ndarray | None = None,
        timestamp_s: float | None = None,
    ) -> Tracks:
        """Track a frame whose detection is already made."""
        self.state, tracks = advance(
            self.state,
            detection,
            image,
            timestamp_s=timestamp_s,
            frames_lost=self._lost,
            params=self.track_params,
        )
        self._lost = 0
        return tracks

    def lose(self, frames: int = 1) -> None:
        """Count frames that never arrived (dropped, unreadable) before the next one."""
        self._lost += frames

    def reset(self) -> None:
        """Forget every track and start a new session."""
        self.state = new_state()
        self._lost = 0


# --------------------------------------------------------------------------- per track


def _gate_base(radius: float, step: float) -> float:
    return max(2.5 * radius, 0.8 * step, 6.0)


def _gate(track: TrackRecord, step: float, dt: float) -> float:
    """How far (px) a detected point may lie from the predicted track and still count."""
    base = _gate_base(track.radius, step)
    if track.steady < STEADY_FRAMES:  # just begun or back: its speed is not known yet
        return 4.0 * base
    velocity = track.velocity  # np.linalg.norm's sums, without its per-call cost
    speed = float(np.sqrt((velocity * velocity).sum(axis=1)).max()) if len(velocity) else 0.0
    return min(base + 0.5 * speed * dt + 2.0 * track.unseen, 4.0 * base)


def _predicted(track: TrackRecord, dt: float) -> np.ndarray:
    return track.joints + track.velocity * dt


def _unseen(track: TrackRecord, predicted: np.ndarray) -> TrackRecord:
    return replace(
        track,
        joints=predicted,
        velocity=track.velocity * UNSEEN_DAMPING,
        unseen=track.unseen + 1,
        steady=0,
        free_end_points=None,
    )


def _moved(
    track: TrackRecord,
    predicted: np.ndarray,
    observation: Observation,
    step: float,
    dt: float,
    now: float,
    frame: int,
    seen_colour: np.ndarray | None,
) -> TrackRecord:
    """The track registered onto what the frame shows of it (growth included);
    ``seen_colour``: the colour of the pieces of the detection that show it."""
    head, tail = observation.head_growth[::-1], observation.tail_growth
    covered, before, grown = observation.covered, predicted, observation
    previous, velocity = track.joints, track.velocity
    if len(head) or len(tail):  # grown this frame (arrays are never changed: else shared)
        targets = np.vstack([head, observation.targets, tail])
        covered = np.concatenate([np.ones(len(head), bool), covered, np.ones(len(tail), bool)])
        before = np.vstack([head, predicted, tail])
        grown = replace(observation, targets=targets, covered=covered)
        previous = np.vstack([head, track.joints, tail])
        velocity = np.vstack(
            [
                np.repeat(track.velocity[:1], len(head), axis=0),
                track.velocity,
                np.repeat(track.velocity[-1:], len(tail), axis=0),
            ]
        )
    joints = register(before, grown, step, track.radius, previous)
    shape = shape_window(track.shape, track.first_joint - len(head), joints, covered, step, frame)
    at = np.arange(len(covered))  # the joints grown this frame were not measured
    use = covered & (at >= len(head)) & (at < len(covered) - len(tail))
    if np.count_nonzero(use) >= 3:
        # A free end seen in this frame and the last is a material point found again:
        # its whole motion is seen, along the cable too.
        pinned = []
        if track.free_end_points is not None:
            moved = observation.free_end_points - track.free_end_points
            for end, grown in ((0, len(head)), (1, len(tail))):
                if not grown and np.all(np.isfinite(moved[end])):
                    pinned.append((0 if end == 0 else len(previous) - 1, moved[end]))
        tangent = tangents(joints)
        # Beyond the outermost seen joints (outside the picture, or hidden at an end)
        # nothing is measured: those joints move with the cable as a whole.
        seen_at = np.flatnonzero(covered)
        beyond = np.ones(len(covered), bool)
        beyond[seen_at[0] : seen_at[-1] + 1] = False
        carried = velocity * dt if shape.travelling else None  # bends travel: no slide from shape
        measured = motion(previous, joints, use, pinned, tangent, beyond, carried) / dt
        # A slide moves each joint back along the track (lower joint numbers) by its size.
        measured -= (observation.slide / dt) * tangent
        velocity = VELOCITY_SMOOTHING * measured + (1.0 - VELOCITY_SMOOTHING) * velocity
    colour = seen_colour
    if track.colour is not None and colour is not None:
        colour = (1.0 - COLOUR_SMOOTHING) * track.colour + COLOUR_SMOOTHING * colour
    elif colour is None:
        colour = track.colour
    tips = observation.tips
    ends_seen = (
        now if covered[0] else track.ends_seen_s[0],
        now if covered[-1] else track.ends_seen_s[1],
    )
    ends_last = track.ends_last.copy()
    if covered[0]:
        ends_last[0] = joints[0]
    if covered[-1]:
        ends_last[1] = joints[-1]
    return replace(
        track,
        joints=joints,
        velocity=velocity,
        first_joint=track.first_joint - len(head),
        tips=tips,
        colour=colour,
        seen_frame=frame,
        seen_s=now,
        ends_seen_s=ends_seen,
        ends_last=ends_last,
        unseen=0,
        steady=track.steady + 1,
        seen=covered,
        free_end_points=observation.free_end_points,
        length_known=track.length_known or observation.length_known,
        last_seen=(np.flatnonzero(covered), joints[covered]),
        shape=shape,
    )


def _young(track: TrackRecord) -> bool:
    """Seen, just begun or come back (not steady yet), and its cable goes on out of view."""
    return track.unseen == 0 and track.steady < STEADY_FRAMES and not all(track.tips)


def _moving_tips(track: TrackRecord) -> tuple[bool, bool]:
    """Per end: a free end seen in the last frame, the track's velocity not known yet."""
    if track.steady >= STEADY_FRAMES or track.free_end_points is None:
        return (False, False)
    seen = np.isfinite(track.free_end_points[:, 0])
    return (bool(track.tips[0] and seen[0]), bool(track.tips[1] and seen[1]))


def _started(
    candidate: Candidate, track_id: int, step: float, now: float, frame: int
) -> TrackRecord:
    """A new track on a candidate: joint 0 at its free end when it shows exactly one."""
    joints, tips = _whole_segments(candidate.joints, step), candidate.tips
    # No end to go by (both free, or neither): start nearest the picture's top left.
    flip = (tips[1] and not tips[0]) or (tips[0] == tips[1] and joints[-1].sum() < joints[0].sum())
    if flip:
        joints, tips = joints[::-1], (tips[1], tips[0])
    return TrackRecord(
        id=track_id,
        joints=joints,
        velocity=np.zeros_like(joints),
        first_joint=0,
        tips=tips,
        radius=candidate.radius,
        colour=candidate.colour,
        born=frame,
        seen_frame=frame,
        seen_s=now,
        ends_seen_s=(now, now),
        ends_last=np.array([joints[0], joints[-1]]),
        free_end_points=np.where(np.array(tips)[:, None], joints[[0, -1]], np.nan),
        last_seen=(np.arange(len(joints)), joints),
    )


def _whole_segments(joints: np.ndarray, step: float) -> np.ndarray:
    """Joints exactly ``step`` apart: a short last segment (a detection's chain may end
    with one) is dropped, or made whole when it is at least half a segment."""
    last = float(np.linalg.norm(joints[-1] - joints[-2])) if len(joints) > 1 else 0.0
    if len(joints) > 2 and last < 0.5 * step:
        joints = joints[:-1]
    return exact_chain(joints, step)


def _joined(tracks: list[TrackRecord], found: list[Join], now: float) -> list[TrackRecord]:
    """The tracks with each join made: the older track continued from its outermost seen
    joint at that end (the hidden joints beyond it laid again), the younger retired."""
    if not found:
        return tracks
    result = list(tracks)
    for join in found:
        older = result[join.older]
        joined = Continuation(join.older, join.end, join.anchor, join.joints, join.tip)
        # Joints are never dropped (a track's joints keep their numbers, and the first
        # is 0 or below): hidden ones beyond the younger track's far end keep their shape.
        younger = result[join.younger]
        seam = Seam(
            older.first_joint + join.anchor,
            join.end,
            younger.id,
            younger.born,
            now,
            from_seam=join.younger_end == 0,
        )
        extended = _extended(older, joined, now)
        result[join.older] = replace(extended, seams=(*extended.seams, seam))
    retired = {join.younger for join in found}
    return [track for index, track in enumerate(result) if index not in retired]


def _bridged(tracks: list[TrackRecord], found: list[Bridge], now: float) -> list[TrackRecord]:
    """The tracks with each bridge made: the older track continued, the younger retired."""
    if not found:
        return tracks
    result = list(tracks)
    for bridge in found:
        joined = Continuation(bridge.older, bridge.end, bridge.anchor, bridge.joints, bridge.tip)
        result[bridge.older] = _extended(result[bridge.older], joined, now)
    retired = {bridge.younger for bridge in found}
    return [track for index, track in enumerate(result) if index not in retired]


def _seen_mask(track: TrackRecord) -> np.ndarray:
    return np.ones(len(track.joints), bool) if track.seen is None else track.seen


def _extended(track: TrackRecord, joined: Continuation, now: float) -> TrackRecord:
    """A track continued by a candidate from its outermost seen joint at one end.

    The joints beyond that one (hidden: the end they led to was the edge of something
    lying on the cable) are laid along the candidate, and joints are added if it goes
    further; if it does not reach as far, the rest keep their shape, moved on.
    """
    joints = track.joints
    anchor = joined.anchor
    added = joined.joints
    # The hidden joints beyond the anchor, nearest it first.
    hidden = joints[:anchor][::-1] if joined.end == 0 else joints[anchor + 1 :]
    if len(added) < len(hidden):
        rest = hidden[len(added) :] + (added[-1] - hidden[len(added) - 1] if len(added) else 0.0)
        added = np.vstack([added, rest]) if len(added) else hidden
    grown = len(added) - len(hidden)
    motion = track.velocity[0] if joined.end == 0 else track.velocity[-1]
    new_velocity = np.repeat(motion[None, :], len(added), axis=0)
    if joined.end == 0:
        joints = np.vstack([added[::-1], joints[anchor:]])
        velocity = np.vstack([new_velocity, track.velocity[anchor:]])
        tips = (joined.tip, track.tips[1])
        first_joint = track.first_joint - grown
        ends_seen = (now, track.ends_seen_s[1])
    else:
        joints = np.vstack([joints[: anchor + 1], added])
        velocity = np.vstack([track.velocity[: anchor + 1], new_velocity])
        tips = (track.tips[0], joined.tip)
        first_joint = track.first_joint
        ends_seen = (track.ends_seen_s[0], now)
    if track.length_known and grown > 0:
        # As long as its cable, the track cannot grow: more cable beyond this end means
        # it had slid the other way, and its joints beyond the other end lay off the
        # cable. It slides back: the joints keep their numbers and their count.
        keep = slice(grown, None) if joined.end == 1 else slice(None, -grown)
        joints, velocity = joints[keep], velocity[keep]
        first_joint = track.first_joint
    return replace(
        track,
        joints=joints,
        velocity=velocity,
        tips=tips,
        first_joint=first_joint,
        ends_seen_s=ends_seen,
        ends_last=np.array([joints[0], joints[-1]]),
        seen=None,
        last_seen=None,
    )


def _reached(tracks: list[TrackRecord], reached: OtherEnd, now: float, step: float):
    """The tracks with one laid on more of its cable come into view (:func:`other_end`)."""
    live = [t for t in tracks if t.unseen == 0]
    track = live[reached.track]
    joints = exact_chain(reached.joints, step)
    ends_seen = list(track.ends_seen_s)
    tips = list(track.tips)
    if reached.tip:
        ends_seen[reached.end] = now
        tips[reached.end] = True
    new = replace(
        track,
        joints=joints,
        tips=(tips[0], tips[1]),
        ends_seen_s=(ends_seen[0], ends_seen[1]),
        ends_last=np.array([joints[0], joints[-1]]),
        seen=None,
        last_seen=None,
    )
    return [new if t is track else t for t in tracks]


def _with_whole_segments(candidate: Candidate, step: float) -> Candidate:
    return replace(candidate, joints=_whole_segments(candidate.joints, step))


def _recognise(
    candidate: Candidate,
    tracks: list[TrackRecord],
    remembered: list[tuple[TrackRecord, float]],
    step: float,
    now: float,
    frame: int,
) -> tuple[TrackRecord | None, list[TrackRecord], list[tuple[TrackRecord, float]]]:
    """A remembered (or predicted, unseen) track the candidate shows again, brought back.

    Returns the revived track (or None) and the tracks and memory without it.
    """
    options = [(t, "tracks") for t in tracks if t.unseen > 0]
    options += [(t, "remembered") for t, _ in remembered]
    best, best_score = None, math.inf
    for track, where in options:
        score = similarity(candidate, track.colour, track.radius, track.length, track.tips, step)
        if score is not None and score < best_score:
            best, best_score = (track, where), score
    if best is None:
        return None, tracks, remembered
    track, where = best
    if where == "tracks":
        tracks = [t for t in tracks if t is not track]
    else:
        remembered = [(t, s) for t, s in remembered if t is not track]
    # Where it went out of view, when it is back there, tells which way round it is.
    left = where_it_left(candidate, len(track.joints), track.last_seen, track.radius, step)
    offset = None
    if left is not None:
        first_is_head, offset = left
    else:
        first_is_head = orientation(
            candidate,
            track.joints,
            track.tips,
            (track.ends_last[0], track.ends_last[1]),
            track.ends_seen_s,
        )
    joints = revived_joints(
        track.joints, _with_whole_segments(candidate, step), first_is_head, step, offset
    )
    joints = exact_chain(joints, step)
    seen_tips = candidate.tips if first_is_head else candidate.tips[::-1]
    # The candidate's free ends are seen this frame: where the track's ends now are.
    seen_ends = candidate.joints[[0, -1]] if first_is_head else candidate.joints[[-1, 0]]
    free_end_points = np.where(np.array(seen_tips)[:, None], seen_ends, np.nan)
    revived = replace(
        track,
        joints=joints,
        velocity=np.zeros_like(joints),
        tips=(track.tips[0] or seen_tips[0], track.tips[1] or seen_tips[1]),
        seen_frame=frame,
        seen_s=now,
        ends_seen_s=(now, now),
        ends_last=np.array([joints[0], joints[-1]]),
        unseen=0,
        steady=0,
        free_end_points=free_end_points,
        seen=distances_to_polyline(joints, candidate.joints) <= 0.5 * step,  # laid on it
        last_seen=None,
    )
    return revived, tracks, remembered


def _near_tracks(pieces: list[Piece], tracks: list[TrackRecord]) -> np.ndarray:
    """Per piece: whether most of its joints lie on a track (within its radius + 3 px)."""
    near = np.zeros(len(pieces), dtype=bool)
    if not tracks or not pieces:
        return near
    starts = np.concatenate([t.joints[:-1] for t in tracks])
    ends = np.concatenate([t.joints[1:] for t in tracks])
    radius = max(t.radius for t in tracks)
    for index, piece in enumerate(pieces):
        reach = np.full(len(piece.joints), max(piece.radius, radius) + 3.0)
        hits = _tracking_kernels.near_any_segment(
            np.ascontiguousarray(piece.joints), reach, starts, ends
        )
        near[index] = np.count_nonzero(hits) >= 0.5 * len(piece.joints)
    return near


def _in_picture(track: TrackRecord, size: tuple[int, int], step: float) -> bool:
    """Whether at least one segment's length of the track lies in the picture."""
    width, height = size
    x, y = track.joints[:, 0], track.joints[:, 1]
    inside = (x >= 0) & (x <= width - 1) & (y >= 0) & (y <= height - 1)
    return int(np.count_nonzero(inside)) >= 2


# --------------------------------------------------------------------------- output


def _tracks(
    kept: list[TrackRecord],
    detection: Detection,
    chains: Chains,
    image: np.ndarray | None,
    status: TrackingStatus,
) -> Tracks:
    """The published tracks: inferred flags (unseen, hidden, underneath) and crossings."""
    width, height = detection.width, detection.height
    step = detection.segment_length
    seen_starts, seen_ends = _seen_segments(chains)
    flags = []
    for track in kept:
        midpoints = 0.5 * (track.joints[:-1] + track.joints[1:])
        inside = (
            (midpoints[:, 0] >= 0)
            & (midpoints[:, 0] <= width - 1)
            & (midpoints[:, 1] >= 0)
            & (midpoints[:, 1] <= height - 1)
        )
        if track.unseen or len(seen_starts) == 0:
            seen = np.zeros(len(midpoints), dtype=bool)
        else:
            seen = _tracking_kernels.near_any_segment(
                np.ascontiguousarray(midpoints),
                np.full(len(midpoints), track.radius + 2.0),
                seen_starts,
                seen_ends,
            )
        flags.append(~(seen & inside))
    crossings = track_crossings(kept, detection, image)
    for crossing in crossings:
        under = next(i for i, t in enumerate(kept) if t.id == crossing.under)
        over = next(i for i, t in enumerate(kept) if t.id == crossing.over)
        joints = kept[under].joints
        reach = kept[over].radius + 0.5 * step
        midpoints = 0.5 * (joints[:-1] + joints[1:])
        near = np.hypot(midpoints[:, 0] - crossing.x, midpoints[:, 1] - crossing.y) < reach
        flags[under][near] = True
    chains = [
        Track(
            id=track.id,
            points=track.joints.tolist(),
            radius=track.radius,
            inferred=inferred.tolist(),
            first_joint=track.first_joint,
            ends=("tip" if track.tips[0] else "open", "tip" if track.tips[1] else "open"),
            age=status.frame - track.born + 1 if status.frame >= track.born else 1,
            unseen=track.unseen,
        )
        for track, inferred in zip(kept, flags, strict=True)
    ]
    return Tracks(
        width=width,
        height=height,
        segment_length=step,
        chains=chains,
        crossings=crossings,
        timings_ms=detection.timings_ms,
        tracking=status,
    )


def _seen_segments(chains: Chains) -> tuple[np.ndarray, np.ndarray]:
    """Start and end points of the detection's segments that were seen (not inferred)."""
    if not chains.joints:
        return np.empty((0, 2)), np.empty((0, 2))
    starts = [
        points[:-1][~flags] for points, flags in zip(chains.joints, chains.inferred, strict=True)
    ]
    ends = [
        points[1:][~flags] for points, flags in zip(chains.joints, chains.inferred, strict=True)
    ]
    return np.ascontiguousarray(np.concatenate(starts)), np.ascontiguousarray(np.concatenate(ends))
