"""Where a tracker's tracks cross, and which strand is on top (moved from
:mod:`service.perception.tracking`, which calls :func:`track_crossings` once per frame).

A track here is anything with ``id``, ``joints`` (an (n, 2) array) and ``radius``:
the tracker's ``TrackRecord``.
"""

from __future__ import annotations

import math

import numpy as np

from schemas import Crossing, Detection
from service.perception.crossings import detect_crossings, find_intersections
from service.perception.segmentation import as_bgr


def track_crossings(kept: list, detection: Detection, image: np.ndarray | None) -> list[Crossing]:
    """Where the tracks cross in the picture, and which is on top.

    The detection has already judged the order of the strands at its crossings
    (:mod:`service.perception.crossings`): a track crossing takes the order of the
    detection's crossing within reach of it, the strand on top being the track that
    runs along the detection's top strand there. Only a crossing the detection does not
    have (hidden, or missed) is judged from the image here.
    """
    if not kept:
        return []
    width, height = detection.width, detection.height
    found = find_intersections([track.joints for track in kept])
    result = []
    pending = []
    for a, seg_a, b, seg_b, point in found:
        x, y = float(point[0]), float(point[1])
        if not (0 <= x <= width - 1 and 0 <= y <= height - 1):
            continue
        reach = max(kept[a].radius, kept[b].radius) + detection.segment_length
        order = _order_from_detection(kept, (a, seg_a), (b, seg_b), x, y, reach, detection)
        if order is None:
            pending.append((a, seg_a, b, seg_b, point))
            continue
        (over, over_seg), (under, under_seg), confidence = order
        result.append(
            Crossing(
                x=x,
                y=y,
                over=kept[over].id,
                under=kept[under].id,
                over_segment=over_seg,
                under_segment=under_seg,
                confidence=confidence,
            )
        )
    if pending:
        judged = detect_crossings(
            [track.joints for track in kept],
            [track.radius for track in kept],
            None if image is None else as_bgr(image),
        )
        for a, seg_a, b, seg_b, _ in pending:
            for crossing in judged:
                if {
                    (crossing.over, crossing.over_segment),
                    (crossing.under, crossing.under_segment),
                } == {
                    (a, seg_a),
                    (b, seg_b),
                }:
                    result.append(
                        Crossing(
                            x=crossing.x,
                            y=crossing.y,
                            over=kept[crossing.over].id,
                            under=kept[crossing.under].id,
                            over_segment=crossing.over_segment,
                            under_segment=crossing.under_segment,
                            confidence=crossing.confidence,
                        )
                    )
    return result


def _order_from_detection(kept, first, second, x, y, reach, detection):
    """``((over, segment), (under, segment), confidence)`` from the detection's crossing
    within ``reach`` of ``(x, y)``, or None when it has none there."""
    nearest, best = None, reach
    for crossing in detection.crossings:
        distance = math.hypot(crossing.x - x, crossing.y - y)
        if distance <= best:
            nearest, best = crossing, distance
    if nearest is None:
        return None
    top = np.asarray(detection.chain(nearest.over).points, dtype=np.float64)
    k = min(nearest.over_segment, len(top) - 2)
    direction = top[k + 1] - top[k]
    direction /= max(float(np.linalg.norm(direction)), 1e-12)

    def alignment(strand):
        index, segment = strand
        joints = kept[index].joints
        along = joints[segment + 1] - joints[segment]
        return abs(float(along @ direction)) / max(float(np.linalg.norm(along)), 1e-12)

    if alignment(first) >= alignment(second):
        return first, second, nearest.confidence
    return second, first, nearest.confidence
