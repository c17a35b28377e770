"""What the viewer's live mode watches on zenoh: the cameras' frames and their results.

:class:`LiveHub` rides on a session that is already open (the service's own) and

* notes every camera that publishes on ``dlo/<camera>/image`` (the camera list of the
  viewer), without copying frames nobody watches;
* for each camera someone watches (:meth:`LiveHub.watch`), keeps its last frames and
  subscribes to what the service's replicas publish for it: ``dlo/<camera>/chains``, the
  tracks on ``dlo/<camera>/tracks`` when a replica tracks it, and the error records on
  ``dlo/<camera>/errors``. The replica that detects a camera need not be this one (replicas
  own cameras), so results are taken from zenoh, never from this process's detector;
* pairs each result with the frame it was made from, through the identity the result's
  attachment gives back (:class:`schemas.ResultAttachment`): the camera's ``frame_id``,
  else the zenoh timestamp of the frame's sample, else (a camera that sends neither) the
  newest frame that had arrived when the detection began. A result can overtake its own
  frame (the replica's and the hub's callbacks run on different threads); such a result
  waits, briefly, for its frame instead of being dropped;
* hands every paired frame (:class:`LiveView`) to the watchers' callbacks. While no
  result comes for a camera (no replica detects it, or none yet), its frames are handed
  on bare, so that the viewer still shows the camera.

The callbacks run on zenoh's threads and must be quick: the HTTP side only stores the
newest view for each client (latest wins) and sends it when the client is ready.
Encoding a PNG frame as JPEG for the browser happens later, in the sender, once per view
(:meth:`LiveView.jpeg`).
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
import zenoh

from service.runtime.errors import RequestError
from service.runtime.frames import check_upload

logger = logging.getLogger(__name__)

CAMERAS_KEY = "dlo/*/image"
"""Where cameras publish their frames: the viewer's camera list comes from these keys."""
RESULT_KINDS = ("chains", "tracks", "errors")
"""The results published for a camera's frame, each on ``dlo/<camera>/<kind>``."""
JPEG_QUALITY = 85
"""Frames that are not JPEG already are re-encoded at this quality for the browser."""
RING_FRAMES = 32
"""Frames kept per watched camera to pair results with: 2 s at 15 fps."""
RING_BYTES = 64 * 1024 * 1024
"""... and at most this many bytes of them (large PNG frames)."""
BARE_AFTER_S = 1.0
"""A camera without any result for this long gets its frames handed on bare."""
FORGET_CAMERA_S = 60.0
"""A camera silent for this long leaves the camera list."""
PREFER_TRACKS_S = 2.0
EARLY_RESULTS = 8
"""Results whose frame has not arrived yet, kept per watched camera ..."""
EARLY_RESULT_S = 2.0
"""... for at most this long: then they count as unpaired."""
"""While tracks came for a camera within this long, ``auto`` watchers take tracks only."""
_CAMERA_NAME_FORBIDDEN = frozenset("/*$?#")


def camera_name_problem(camera: str) -> str | None:
    """Why ``camera`` cannot be watched (one line), or None: a single key chunk, no wildcard."""
    if not camera or len(camera) > 200:
        return "the camera name must have 1 to 200 characters"
    if any(character in _CAMERA_NAME_FORBIDDEN for character in camera):
        return f"camera {camera!r}: a single key chunk without / * $ ? #"
    return None


@dataclass
class LiveFrame:
    """One frame of a watched camera, as it arrived."""

    seq: int
    """Its number among the frames of this camera the hub has seen (from 1)."""
    arrived: float
    """``time.monotonic()`` when it arrived."""
    payload: bytes
    frame_id: int | str | None = None
    capture_time: float | None = None
    sample_timestamp: str | None = None
    _jpeg: bytes | None = field(default=None, repr=False)
    _jpeg_error: str | None = field(default=None, repr=False)
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def jpeg(self, max_pixels: int) -> bytes:
        """The frame as JPEG: its own bytes when it is one, else re-encoded (once).

        Raises
        ------
        ValueError
            It cannot be decoded, or it declares more than ``max_pixels`` pixels.
        """
        if self.payload.startswith(b"\xff\xd8"):
            return self.payload
        with self._lock:
            if self._jpeg is None and self._jpeg_error is None:
                try:
                    self._jpeg = _to_jpeg(self.payload, max_pixels)
                except ValueError as exc:
                    self._jpeg_error = str(exc)
            if self._jpeg is None:
                raise ValueError(self._jpeg_error)
            return self._jpeg


def _to_jpeg(payload: bytes, max_pixels: int) -> bytes:
    try:
        check_upload(payload, "frame", max_pixels)  # the header, before decoding
    except RequestError as exc:
        raise ValueError(exc.message) from None
    image = cv2.imdecode(np.frombuffer(payload, np.uint8), cv2.IMREAD_COLOR)
    if image is None:
        raise ValueError("the frame is not an image OpenCV can decode")
    if image.shape[0] * image.shape[1] > max_pixels:
        raise ValueError(f"the frame is {image.shape[1]}x{image.shape[0]}, over the limit")
    ok, encoded = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:
        raise ValueError("OpenCV could not encode the frame as JPEG")
    return encoded.tobytes()


@dataclass(frozen=True)
class LiveView:
    """A frame with the result made from it (or bare: ``kind`` None)."""

    camera: str
    frame: LiveFrame
    kind: str | None = None
    """``chains``, ``tracks``, ``errors``, or None for a bare frame."""
    result: bytes | None = None
    """The result sample's payload (Detection JSON, or the error record), unparsed."""
    pairing: str | None = None
    """How the frame was found: ``frame_id``, ``sample_timestamp`` or ``arrival``."""
    latency_ms: float | None = None
    """From the frame's arrival here to its result's."""
    replica: str | None = None
    """The replica that made the result, from its attachment."""


Deliver = Callable[[LiveView], None]


@dataclass
class _CameraSeen:
    frames: int = 0
    last: float = 0.0
    interval_s: float | None = None
    """Smoothed time between frames."""

    def saw_frame(self, now: float) -> None:
        if self.frames:
            gap = now - self.last
            self.interval_s = gap if self.interval_s is None else 0.8 * self.interval_s + 0.2 * gap
        self.frames += 1
        self.last = now

    def fps(self, now: float) -> float | None:
        if self.interval_s is None or self.interval_s <= 0 or now - self.last > 5 * self.interval_s:
            return None
        return 1.0 / self.interval_s


@dataclass
class _Watcher:
    deliver: Deliver
    results: str
    """``auto`` (tracks when there are some, else chains), ``chains`` or ``tracks``."""


@dataclass(frozen=True)
class _ResultSample:
    """A result as it came (kept in ``_Feed.early`` while its frame has not arrived)."""

    kind: str
    attachment: dict[str, Any]
    payload: bytes
    arrived: float

    def made_from(self, frame: LiveFrame) -> str | None:
        """How this result pairs with ``frame`` (``frame_id``, ``sample_timestamp``), or
        None when it was made from another frame."""
        frame_id = self.attachment.get("frame_id")
        if frame_id is not None:
            return "frame_id" if frame.frame_id == frame_id else None
        stamp = self.attachment.get("sample_timestamp")
        if stamp is not None and frame.sample_timestamp == stamp:
            return "sample_timestamp"
        return None


@dataclass
class _Feed:
    """One watched camera: its last frames, its result subscribers and its watchers."""

    camera: str
    watchers: list[_Watcher] = field(default_factory=list)
    frames: deque[LiveFrame] = field(default_factory=deque)
    frame_bytes: int = 0
    subscribers: list[Any] = field(default_factory=list)
    last_result: float = float("-inf")
    last_tracks: float = float("-inf")
    early: deque[_ResultSample] = field(default_factory=deque)
    """Results that came before their frame (paired by ``frame_id`` or timestamp)."""
    unpaired: int = 0
    too_large: int = 0

    def keep_early(self, result: _ResultSample) -> None:
        self.early.append(result)
        while len(self.early) > EARLY_RESULTS:
            self.early.popleft()
            self.unpaired += 1

    def early_results_of(self, frame: LiveFrame, now: float) -> list[tuple[_ResultSample, str]]:
        """The waiting results made from ``frame`` (taken out) and how each was paired;
        stale ones are dropped."""
        while self.early and now - self.early[0].arrived > EARLY_RESULT_S:
            self.early.popleft()
            self.unpaired += 1
        found = [(early, how) for early in self.early if (how := early.made_from(frame))]
        for early, _ in found:
            self.early.remove(early)
        return found


class LiveHub:
    """The live mode's view of zenoh; see the module's documentation.

    Parameters
    ----------
    session : zenoh.Session
        An open session; the hub declares its subscribers on it and never closes it.
    max_bytes, max_pixels : int
        Frames larger than this (encoded bytes, declared pixels) are not kept or shown.
    """

    def __init__(self, session: zenoh.Session, *, max_bytes: int, max_pixels: int) -> None:
        self._session = session
        self.max_bytes = max_bytes
        self.max_pixels = max_pixels
        self._lock = threading.Lock()
        self._seen: dict[str, _CameraSeen] = {}
        self._feeds: dict[str, _Feed] = {}
        self._closed = False
        self._cameras_subscriber = session.declare_subscriber(CAMERAS_KEY, self._on_image)

    def close(self) -> None:
        """Undeclare every subscriber; watchers get nothing more."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            feeds = list(self._feeds.values())
            self._feeds.clear()
        for feed in feeds:
            _undeclare(feed.subscribers)
        _undeclare([self._cameras_subscriber])

    # -- what the HTTP side asks ---------------------------------------------------------

    def cameras(self) -> list[dict[str, Any]]:
        """The cameras seen on ``dlo/*/image`` lately: name, frames per second (None when
        unknown or stopped), seconds since the last frame, frames seen, watched or not."""
        now = time.monotonic()
        with self._lock:
            for name in [n for n, s in self._seen.items() if now - s.last > FORGET_CAMERA_S]:
                del self._seen[name]
            return [
                {
                    "camera": name,
                    "fps": None if (fps := seen.fps(now)) is None else round(fps, 2),
                    "last_frame_s": round(now - seen.last, 3),
                    "frames": seen.frames,
                    "watchers": len(self._feeds[name].watchers) if name in self._feeds else 0,
                }
                for name, seen in sorted(self._seen.items())
            ]

    def camera_fps(self, camera: str) -> float | None:
        """The camera's frame rate as seen here (None: unknown, or no frame lately)."""
        with self._lock:
            seen = self._seen.get(camera)
            return None if seen is None else seen.fps(time.monotonic())

    def last_frame_s(self, camera: str) -> float | None:
        """Seconds since the camera's last frame (None: none seen)."""
        with self._lock:
            seen = self._seen.get(camera)
            return None if seen is None else time.monotonic() - seen.last

    def watch(self, camera: str, deliver: Deliver, results: str = "auto") -> Callable[[], None]:
        """Hand ``camera``'s views to ``deliver`` (on zenoh's threads) until the returned
        function is called. ``results``: ``auto``, ``chains`` or ``tracks``."""
        problem = camera_name_problem(camera)
        if problem is not None:
            raise ValueError(problem)
        if results not in ("auto", "chains", "tracks"):
            raise ValueError(f"results {results!r}: auto, chains or tracks")
        watcher = _Watcher(deliver, results)
        with self._lock:
            if self._closed:
                raise RuntimeError("the live hub is closed")
            feed = self._feeds.get(camera)
            if feed is None:
                feed = self._feeds[camera] = _Feed(camera)
                new = True
            else:
                new = False
            feed.watchers.append(watcher)
        if new:
            subscribers = [
                self._session.declare_subscriber(
                    f"dlo/{camera}/{kind}",
                    lambda sample, kind=kind: self._on_result(camera, kind, sample),
                )
                for kind in RESULT_KINDS
            ]
            with self._lock:
                if self._feeds.get(camera) is feed and not self._closed:
                    feed.subscribers = subscribers
                    subscribers = []
            _undeclare(subscribers)  # the feed ended (or the hub closed) meanwhile
        logger.debug("live: watching camera %s (%s)", camera, results)
        return lambda: self._unwatch(camera, watcher)

    def _unwatch(self, camera: str, watcher: _Watcher) -> None:
        with self._lock:
            feed = self._feeds.get(camera)
            if feed is None or watcher not in feed.watchers:
                return
            feed.watchers.remove(watcher)
            if feed.watchers:
                return
            del self._feeds[camera]  # the last watcher: frames and subscribers go
        _undeclare(feed.subscribers)

    # -- zenoh callbacks --------------------------------------------------------------------

    def _on_image(self, sample: zenoh.Sample) -> None:
        if sample.kind != zenoh.SampleKind.PUT:
            return
        camera = str(sample.key_expr).split("/")[1]
        now = time.monotonic()
        with self._lock:
            seen = self._seen.setdefault(camera, _CameraSeen())
            seen.saw_frame(now)
            seq = seen.frames
            if camera not in self._feeds:
                return  # nobody watches: not even copied
        payload = sample.payload.to_bytes()
        frame_id, capture_time = _identity_of(sample.attachment)
        stamp = sample.timestamp
        frame = LiveFrame(
            seq=seq,
            arrived=now,
            payload=payload,
            frame_id=frame_id,
            capture_time=capture_time,
            sample_timestamp=None if stamp is None else stamp.to_string_rfc3339_lossy(),
        )
        with self._lock:
            feed = self._feeds.get(camera)
            if feed is None:
                return
            if len(payload) > self.max_bytes:
                feed.too_large += 1
                return
            feed.frames.append(frame)
            feed.frame_bytes += len(payload)
            while len(feed.frames) > RING_FRAMES or (
                feed.frame_bytes > RING_BYTES and len(feed.frames) > 1
            ):
                feed.frame_bytes -= len(feed.frames.popleft().payload)
            early = [
                (
                    _paired_view(camera, frame, result, pairing, now),
                    _watchers_for(feed, result.kind, now),
                )
                for result, pairing in feed.early_results_of(frame, now)
            ]
            bare = now - feed.last_result > BARE_AFTER_S
            watchers = list(feed.watchers) if bare and not early else []
        view = LiveView(camera, frame)
        for watcher in watchers:
            watcher.deliver(view)
        for paired_view, paired_watchers in early:  # results that came before this frame
            for watcher in paired_watchers:
                watcher.deliver(paired_view)

    def _on_result(self, camera: str, kind: str, sample: zenoh.Sample) -> None:
        if sample.kind != zenoh.SampleKind.PUT:
            return
        now = time.monotonic()
        result = _ResultSample(
            kind, _json_object(sample.attachment), sample.payload.to_bytes(), now
        )
        with self._lock:
            feed = self._feeds.get(camera)
            if feed is None:
                return
            feed.last_result = now
            if kind == "tracks":
                feed.last_tracks = now
            frame, pairing = _pair(feed.frames, result.attachment, result.payload, now)
            if frame is None:
                if pairing is None:
                    feed.unpaired += 1
                else:  # its frame may still be on its way here
                    feed.keep_early(result)
                return
            watchers = _watchers_for(feed, kind, now)
        view = _paired_view(camera, frame, result, pairing, now)
        for watcher in watchers:
            watcher.deliver(view)


def _watchers_for(feed: _Feed, kind: str, now: float) -> list[_Watcher]:
    """The watchers of ``feed`` that take a ``kind`` result now."""
    prefer_tracks = now - feed.last_tracks <= PREFER_TRACKS_S
    return [w for w in feed.watchers if _wants(w.results, kind, prefer_tracks)]


def _paired_view(
    camera: str, frame: LiveFrame, result: _ResultSample, pairing: str, now: float
) -> LiveView:
    replica = result.attachment.get("replica")
    return LiveView(
        camera,
        frame,
        kind=result.kind,
        result=result.payload,
        pairing=pairing,
        latency_ms=round(max(0.0, now - frame.arrived) * 1000.0, 2),
        replica=replica if isinstance(replica, str) else None,
    )


def _wants(results: str, kind: str, prefer_tracks: bool) -> bool:
    if kind == "errors":
        return True
    if results == "auto":
        return kind == ("tracks" if prefer_tracks else "chains")
    return kind == results


def _pair(
    frames: deque[LiveFrame], attachment: dict[str, Any], payload: bytes, now: float
) -> tuple[LiveFrame | None, str | None]:
    """The frame a result was made from, and how it was found (see the module's doc).

    A result that names its frame (``frame_id``, ``sample_timestamp``) which is not among
    ``frames`` gives None and how it would be paired: its frame may not have come yet.
    """
    frame_id = attachment.get("frame_id")
    if frame_id is not None:
        for frame in reversed(frames):
            if frame.frame_id == frame_id:
                return frame, "frame_id"
        return None, "frame_id"
    stamp = attachment.get("sample_timestamp")
    if stamp is not None:
        for frame in reversed(frames):
            if frame.sample_timestamp == stamp:
                return frame, "sample_timestamp"
        return None, "sample_timestamp"
    # Neither: the replica took the newest frame waiting when it began (latest wins), so
    # the newest that had arrived by then, the detection's own time before the result.
    began = now - _detection_seconds(payload)
    for frame in reversed(frames):
        if frame.arrived <= began:
            return frame, "arrival"
    return (frames[0], "arrival") if frames else (None, None)


def _detection_seconds(payload: bytes) -> float:
    try:
        total = json.loads(payload)["timings_ms"]["total"]
    except (ValueError, KeyError, TypeError):
        return 0.0
    return float(total) / 1000.0 if isinstance(total, int | float) and total > 0 else 0.0


def _json_object(attachment: zenoh.ZBytes | None) -> dict[str, Any]:
    if attachment is None:
        return {}
    try:
        value = json.loads(attachment.to_bytes())
    except (ValueError, UnicodeDecodeError):
        return {}
    return value if isinstance(value, dict) else {}


def _identity_of(attachment: zenoh.ZBytes | None) -> tuple[int | str | None, float | None]:
    """A frame's ``frame_id`` and ``capture_time`` from its attachment, when usable."""
    fields = _json_object(attachment)
    frame_id = fields.get("frame_id")
    if isinstance(frame_id, bool) or not isinstance(frame_id, int | str):
        frame_id = None
    capture_time = fields.get("capture_time")
    if isinstance(capture_time, bool) or not isinstance(capture_time, int | float):
        capture_time = None
    return frame_id, None if capture_time is None else float(capture_time)


def _undeclare(entities: list[Any]) -> None:
    for entity in entities:
        try:
            entity.undeclare()
        except Exception:  # the session closed first: nothing left to undeclare
            logger.debug("live: undeclare failed", exc_info=True)
