"""Scoring tracks on generated videos, whose every material point is known.

Videos come from :func:`service.synthetic.make_video`. Every frame is tracked
(:class:`service.perception.Tracker`) and, for comparison, the detection of the same
frame is scored the same way with its chains' ids taken as they come. The rules:

in view
    A cable counts in a frame when at least :data:`MIN_VISIBLE_SEGMENTS` segment lengths
    of it are visible (in the picture and not under an occluder).
matching
    In each frame, chains are matched one-to-one to cables (Hungarian assignment) by how
    many of the chain's seen joints in the picture lie on the cable: within its radius
    plus ``max(3 px, l_s / 2)`` of its centreline. A chain needs half of those joints (and
    two at least) on a cable to match it.
identity
    Per cable, the share of its counted frames in which its matched chain carries the id
    it carries most often (a frame without a matched chain counts against it).
same end
    Per cable and id, the share of frames in which the chain runs from the same end of
    the cable (its joints' material positions rise, or fall, with the joint number) as
    in most of that id's frames.
id switches
    Changes of a cable's matched id between consecutive frames in which it is matched,
    per 10 cable-minutes (counted frames at the video's frame rate).
joint error
    A track's joint ``j`` is given the material point of the cable it lies on (its
    nearest centreline sample) in the first frame that track and cable are matched and
    the joint is in the picture; in every later frame of the pair, the distance from the
    joint to where that material point now is, averaged over the joints whose material
    point is in the picture (hidden ones included), in segment lengths. ``after 300``:
    the mean over frames 290-299 (the last ten of a 300-frame video).

Seeds follow :mod:`service.evaluation.conventions`: 0-99999 to tune on, 100000 and up
held out.
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree

from schemas import Detection, DetectParams, TrackParams
from service.perception import detect
from service.perception.tracking import Tracker
from service.synthetic.videos import VideoFrame, make_video

MIN_VISIBLE_SEGMENTS = 3.0
"""A cable counts in a frame when this many segment lengths of it are visible."""
LATE_FRAMES = (290, 300)
"""Frames whose joint error is reported as "after 300 frames"."""


@dataclass
class CableScore:
    """The counts of one cable of one video, for one chain source (tracks or detection)."""

    frames: int = 0  # counted frames
    matched: int = 0
    ids: Counter = field(default_factory=Counter)
    ends: dict = field(default_factory=dict)  # id -> Counter of orientation (+1 / -1)
    switches: int = 0
    last_id: int | None = None


@dataclass
class VideoScore:
    """One video's scores for tracks and for detection alone."""

    seed: int
    kind: str
    cables: int
    frames: int
    fps: float
    identity: tuple[int, int]  # (frames with the most common id, counted frames)
    same_end: tuple[int, int]
    switches: int
    cable_frames: int
    error_sum: float  # joint error, in segment lengths, summed over matched frames
    error_frames: int
    late_error_sum: float
    late_error_frames: int
    detection_identity: tuple[int, int]
    detection_same_end: tuple[int, int]
    detection_switches: int
    tracking_ms: list[float] = field(default_factory=list)
    detection_ms: list[float] = field(default_factory=list)


@dataclass
class _Source:
    """Scoring state of one chain source over a video."""

    cables: list[CableScore]
    reference: dict = field(default_factory=dict)  # (cable, id, joint) -> material arc
    error_sum: float = 0.0
    error_frames: int = 0
    late_sum: float = 0.0
    late_frames: int = 0


def evaluate_video(
    seed: int,
    kind: str | None = None,
    *,
    n_frames: int = 300,
    params: DetectParams | None = None,
    track_params: TrackParams | None = None,
    use_mask: bool = False,
    on_frame: Callable[[int], None] | None = None,
) -> VideoScore:
    """Track video ``seed`` (of ``kind``) and score the tracks and the bare detection.

    ``use_mask`` gives the detector the true visible-cable mask with each image.
    """
    video = make_video(seed, kind, n_frames=n_frames)
    params = DetectParams() if params is None else params
    tracker = Tracker(params, track_params)
    tracks_source = _Source([CableScore() for _ in range(video.n_cables)])
    detection_source = _Source([CableScore() for _ in range(video.n_cables)])
    tracking_ms, detection_ms = [], []
    for frame in video.frames():
        started = time.perf_counter()
        detection = detect(frame.image, params, frame.mask if use_mask else None)
        detection_ms.append((time.perf_counter() - started) * 1000.0)
        tracks = tracker.follow(detection, frame.image, frame.timestamp_s)
        tracking_ms.append(tracks.tracking.tracking_ms)
        step = detection.segment_length
        _score_frame(tracks_source, frame, tracks, step, materials=True)
        _score_frame(detection_source, frame, detection, step, materials=False)
        if on_frame is not None:
            on_frame(frame.index)
    identity, same_end, switches, cable_frames = _summary(tracks_source.cables)
    detection_identity, detection_same_end, detection_switches, _ = _summary(
        detection_source.cables
    )
    return VideoScore(
        seed=seed,
        kind=video.kind,
        cables=video.n_cables,
        frames=video.n_frames,
        fps=video.fps,
        identity=identity,
        same_end=same_end,
        switches=switches,
        cable_frames=cable_frames,
        error_sum=tracks_source.error_sum,
        error_frames=tracks_source.error_frames,
        late_error_sum=tracks_source.late_sum,
        late_error_frames=tracks_source.late_frames,
        detection_identity=detection_identity,
        detection_same_end=detection_same_end,
        detection_switches=detection_switches,
        tracking_ms=tracking_ms,
        detection_ms=detection_ms,
    )


def _score_frame(source: _Source, frame: VideoFrame, result: Detection, step: float, *, materials):
    cables = frame.cables
    counted = [c.visible_length >= MIN_VISIBLE_SEGMENTS * step for c in cables]
    trees = [cKDTree(c.points) for c in cables]
    width, height = result.width, result.height
    chains = result.chains
    # For each chain: its seen joints in the picture, their nearest distance and sample
    # on each cable.
    hits = np.zeros((len(cables), len(chains)))
    nearest: dict[tuple[int, int], tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    for j, chain in enumerate(chains):
        points = np.asarray(chain.points, dtype=np.float64)
        inferred = np.asarray(chain.inferred, dtype=bool)
        seen = np.zeros(len(points), dtype=bool)
        seen[:-1] |= ~inferred
        seen[1:] |= ~inferred
        inside = (
            (points[:, 0] >= 0)
            & (points[:, 0] <= width - 1)
            & (points[:, 1] >= 0)
            & (points[:, 1] <= height - 1)
        )
        use = seen & inside
        if np.count_nonzero(use) < 2:
            continue
        for i, (cable, tree) in enumerate(zip(cables, trees, strict=True)):
            distance, sample = tree.query(points)
            tolerance = cable.radius + max(3.0, 0.5 * step)
            on = (distance <= tolerance) & use
            if np.count_nonzero(on) >= max(2, 0.5 * np.count_nonzero(use)):
                hits[i, j] = np.count_nonzero(on)
            nearest[i, j] = (distance, sample, inside, use)
    pairs = {}
    if hits.size:
        rows, cols = linear_sum_assignment(-hits)
        pairs = {int(i): int(j) for i, j in zip(rows, cols, strict=True) if hits[i, j] > 0}
    errors = []
    for i, cable in enumerate(cables):
        score = source.cables[i]
        if not counted[i]:
            continue
        score.frames += 1
        if i not in pairs:
            continue
        j = pairs[i]
        chain = chains[j]
        score.matched += 1
        score.ids[chain.id] += 1
        if score.last_id is not None and score.last_id != chain.id:
            score.switches += 1
        score.last_id = chain.id
        distance, sample, inside, use = nearest[i, j]
        arcs = sample * cable.spacing
        if len(arcs) >= 2:
            numbers = np.arange(len(arcs))
            slope = np.polyfit(numbers[inside], arcs[inside], 1)[0] if inside.sum() >= 2 else 0
            score.ends.setdefault(chain.id, Counter())[1 if slope >= 0 else -1] += 1
        if materials:
            errors.append(_joint_error(source, i, chain, arcs, use, cable, step))
    errors = [e for e in errors if e is not None]
    if errors:
        mean = float(np.mean(errors))
        source.error_sum += mean
        source.error_frames += 1
        if LATE_FRAMES[0] <= frame.index < LATE_FRAMES[1]:
            source.late_sum += mean
            source.late_frames += 1


def _joint_error(source, cable_index, chain, arcs, seen, cable, step):
    """Mean distance (segment lengths) between the joints and their material points.

    A joint's material point is set the first time it is seen in the picture."""
    first = getattr(chain, "first_joint", 0)
    points = np.asarray(chain.points, dtype=np.float64)
    n_samples = len(cable.points)
    distances = []
    for k in range(len(points)):
        key = (cable_index, chain.id, first + k)
        if key not in source.reference:
            if seen[k]:
                source.reference[key] = arcs[k]
            continue
        sample = round(source.reference[key] / cable.spacing)
        if not 0 <= sample < n_samples or not cable.in_picture[sample]:
            continue
        distances.append(float(np.linalg.norm(points[k] - cable.points[sample])))
    if not distances:
        return None
    return float(np.mean(distances)) / step


def _summary(cables: Iterable[CableScore]):
    """(identity, same end, switches, counted frames) over a video's cables."""
    identity = [0, 0]
    same_end = [0, 0]
    switches = 0
    frames = 0
    for score in cables:
        frames += score.frames
        identity[1] += score.frames
        switches += score.switches
        if score.ids:
            _, top_count = score.ids.most_common(1)[0]
            identity[0] += top_count
            for ends in score.ends.values():
                same_end[0] += ends.most_common(1)[0][1]
                same_end[1] += sum(ends.values())
    return tuple(identity), tuple(same_end), switches, frames
