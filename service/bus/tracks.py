"""Tracking over zenoh: per camera, the chains followed from frame to frame.

A :class:`CameraTrackers` given to :class:`~service.bus.detection.DetectionBus` keeps one
:class:`service.perception.Tracker` per tracked camera: after a camera frame's detection
the bus hands it the Detection and the decoded image, and publishes the resulting
:class:`schemas.Tracks` JSON on ``dlo/<camera>/tracks`` beside ``dlo/<camera>/chains``,
with the same attachment (:class:`schemas.ResultAttachment`). Queries on ``dlo/detect``
are never tracked: a query is one image.

Which cameras: all of them (``cameras=("*",)``), or those whose names match one of the
key expressions given (``cam1``, ``line1-$*``).

Time and lost frames: a frame's time is its ``capture_time`` when the camera sends one,
else when the sample arrived. Frames of the camera that were replaced before detection
(latest frame wins), rejected or failed count as lost: the tracks are predicted across
them and the next Tracks says how many (``tracking.frames_lost``).

Hand-over: a replica keeps a camera's tracker only while it owns the camera. Once it sees
a frame of that camera it does not own (another replica took it over), it forgets the
tracker; should the camera come back to it, it starts a new session (a new
``tracking.session``, ids from 0 again). The replica taking a camera over starts fresh
tracks the same way: track ids are unique within a session, and a hand-over begins a new
one, which ``tracking.session`` (and the attachment's ``replica``) tell.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence

import numpy as np
import zenoh

from schemas import Detection, FrameIdentity, TrackParams, Tracks
from service.perception import Tracker

ALL_CAMERAS = "*"


def tracks_key(camera: str) -> str:
    """Where the Tracks of ``camera``'s frames are published."""
    return f"dlo/{camera}/tracks"


class CameraTrackers:
    """One tracker per tracked camera (see the module's documentation).

    Parameters
    ----------
    cameras : sequence of str
        Key expressions of the camera names to track; ``("*",)``: every camera.
    params : TrackParams, optional
    """

    def __init__(
        self, cameras: Sequence[str] = (ALL_CAMERAS,), params: TrackParams | None = None
    ) -> None:
        if not cameras:
            raise ValueError("give at least one camera name or pattern ('*': all)")
        self.patterns = tuple(zenoh.KeyExpr(pattern) for pattern in dict.fromkeys(cameras))
        self.params = TrackParams() if params is None else params
        self._trackers: dict[str, Tracker] = {}
        self._lost: dict[str, int] = {}
        self._lock = threading.Lock()

    def tracks(self, camera: str) -> bool:
        """Whether ``camera``'s frames are tracked."""
        try:
            name = zenoh.KeyExpr(camera)
        except Exception:  # not a key expression chunk: matches no pattern
            return False
        return any(pattern.intersects(name) for pattern in self.patterns)

    def follow(
        self,
        camera: str,
        detection: Detection,
        image: np.ndarray | None,
        identity: FrameIdentity,
        received_s: float,
    ) -> Tracks:
        """Track a camera frame's detection: the frame's :class:`schemas.Tracks`."""
        with self._lock:
            tracker = self._trackers.get(camera)
            if tracker is None:
                tracker = self._trackers[camera] = Tracker(track_params=self.params)
            tracker.lose(self._lost.pop(camera, 0))
        when = identity.capture_time if identity.capture_time is not None else received_s
        return tracker.follow(detection, image, when)

    def lose(self, camera: str) -> None:
        """A frame of ``camera`` that will not be tracked (replaced, rejected, failed)."""
        with self._lock:
            if camera in self._trackers:
                self._lost[camera] = self._lost.get(camera, 0) + 1

    def forget(self, camera: str) -> None:
        """Drop ``camera``'s tracker (another replica owns the camera now)."""
        with self._lock:
            self._trackers.pop(camera, None)
            self._lost.pop(camera, None)

    def tracked(self) -> list[str]:
        """The cameras with a tracker now."""
        with self._lock:
            return sorted(self._trackers)
