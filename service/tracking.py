"""Tracking videos and live streams: one :class:`schemas.Tracks` per frame.

:class:`StreamTracker` is the :class:`~service.video.StreamAnalyser` that ``dlo track``
gives :func:`service.video.process_stream`: for each frame it detects the cables
(:func:`service.perception.detect_full`, with the stream's parameters) and advances a
:class:`service.perception.Tracker`. The outputs are those of ``dlo detect`` for videos
(``<stem>.jsonl``, ``<stem>.overlay.mp4``, ``<stem>.mcap``), each line's ``detection``
being the frame's Tracks: the Detection's fields, each chain a track (its id kept from
frame to frame, joint ``j`` on the same point of the cable) and ``tracking`` (see
:class:`schemas.TrackingStatus`).

Bad frames lose nothing: a frame the source could not read, or the detection failed
on, is counted, the tracks are predicted across it, and the next frame's
``tracking.frames_lost`` says how many were lost before it. A frame of another size
starts the tracks afresh (``tracking.reset`` says why, and ``on_reset`` is told, for a
one-line warning).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator

from schemas import DetectParams, TrackParams, Tracks
from service.perception import Tracker
from service.perception.segmenter import Segmenter
from service.video import Frame, FrameRecord, read_frame_records


class TrackRecord(FrameRecord):
    """One line of ``dlo track``'s JSON Lines: a frame's tracks with its position."""

    detection: Tracks


class StreamTracker:
    """Detect and track every frame of one stream (see the module's documentation).

    Parameters
    ----------
    params : DetectParams, optional
    track_params : TrackParams, optional
    segmenter : callable, optional
        For ``params.segmentation == "model"``.
    on_reset : callable, optional
        Called with the frame and the reason when the tracks start afresh.
    """

    def __init__(
        self,
        params: DetectParams | None = None,
        track_params: TrackParams | None = None,
        *,
        segmenter: Segmenter | None = None,
        on_reset: Callable[[Frame, str], None] | None = None,
    ) -> None:
        self.tracker = Tracker(params, track_params, segmenter=segmenter)
        self.on_reset = on_reset

    def __call__(self, frame: Frame) -> Tracks:
        """The frame's tracks; a frame that cannot be used is counted as lost and raises."""
        tracks = self.tracker.update(frame.image, timestamp_s=float(frame.timestamp_s))
        if tracks.tracking.reset is not None and self.on_reset is not None:
            self.on_reset(frame, tracks.tracking.reset)
        return tracks

    def lost(self, frame: Frame) -> None:
        """A frame the source could not read."""
        self.tracker.lose()


def read_track_records(path: str | os.PathLike[str]) -> Iterator[TrackRecord]:
    """Read back ``dlo track``'s JSON Lines, line by line.

    Raises
    ------
    pydantic.ValidationError
        A line is not a valid :class:`TrackRecord`.
    """
    return read_frame_records(path, TrackRecord)
