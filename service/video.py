"""Detecting cables in videos and live streams, one :class:`schemas.Detection` per frame.

A video is read as a :class:`FrameSource`: an iterable of :class:`Frame` (index,
timestamp, image) plus what is known about the stream (name, frame rate, frame
count). :func:`open_video` and :func:`open_camera` make one from a file or from a
camera / stream URL with OpenCV; tests and other callers can build one from any
iterable of frames. :func:`process_stream` runs the detection on every frame and
writes

``<stem>.jsonl``
    JSON Lines, one :class:`FrameRecord` per processed frame:
    ``{"frame": 0, "timestamp_s": 0.0, "detection": {...}}``. Every line is written
    whole and flushed before the next frame is read, so the file can be followed
    while it grows and stays valid when processing stops early.
``<stem>.overlay.mp4`` (optional)
    The detections drawn over the frames (``mp4v``), one video frame per processed
    frame, at the source frame rate (30 when unknown).
``<stem>.mcap`` (optional)
    A ROS 2 recording (:mod:`service.ros.recording`): per processed frame, the frame as a
    ``sensor_msgs/msg/CompressedImage`` on ``/dlo/image`` and the detection as a
    ``visualization_msgs/msg/MarkerArray`` on ``/dlo/chains``, stamped with the frame's
    time (a camera's: Unix time; a video file's: from its start).

Bad input never raises out of :func:`process_stream`: an unreadable frame or a
frame the detection fails on is skipped and counted, a source that stops
delivering frames (camera unplugged, stream cut, truncated file) ends the run with
the frames written so far kept, and Ctrl-C (``KeyboardInterrupt``) stops it
cleanly. The returned :class:`StreamSummary` tells what happened.

These are plain functions behind the ``dlo`` command line; they print nothing.
"""

from __future__ import annotations

import contextlib
import math
import os
import re
import statistics
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple, Protocol, TypeVar
from urllib.parse import urlsplit

import cv2
import numpy as np
from pydantic import BaseModel, Field, SerializeAsAny

from schemas import Detection, DetectParams
from service.imageio import OutputWriteError, _opencv_quiet
from service.interrupts import interrupts_held, raise_if_interrupted
from service.perception import InvalidInputError, detect, render_overlay
from service.perception.segmenter import Segmenter

# FFmpeg, which OpenCV reads most videos with, prints its own complaints about damaged
# files straight to stderr; this program reports problems itself, on one line. Read by
# OpenCV when it first opens a video; set OPENCV_FFMPEG_LOGLEVEL yourself to see them.
os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")

VIDEO_SUFFIXES = (".avi", ".m4v", ".mkv", ".mov", ".mp4", ".mpeg", ".mpg", ".webm")
"""File name endings (lower case) that :func:`is_video_path` recognises as videos."""

DEFAULT_FPS = 30.0
"""Frame rate assumed when a source does not tell its own (overlay video, timestamps)."""

OVERLAY_FOURCC = "mp4v"
"""Codec of the overlay video; MPEG-4 part 2 is written by every OpenCV build."""

MAX_FILE_READ_FAILURES = 8
"""Consecutive frames of a video file that may fail to decode before reading gives up."""

CAMERA_TIMEOUT_S = 3.0
"""A camera or stream that delivers no frame for this long is considered lost."""


class Frame(NamedTuple):
    """One frame of a video or stream.

    Attributes
    ----------
    index : int
        Position in the stream, from 0; unreadable frames take an index too.
    timestamp_s : float
        Presentation time in seconds: from the container for files, since reading
        started for cameras and streams.
    image : ndarray or None
        ``(H, W, 3)`` BGR or ``(H, W)`` gray ``uint8``; None when the frame could not
        be read or decoded (it is then skipped and counted).
    """

    index: int
    timestamp_s: float
    image: np.ndarray | None


class VideoSourceError(Exception):
    """A video or stream cannot be opened, or stopped delivering frames.

    ``str()`` is one line, ``"<source>: <problem>"``.

    Parameters
    ----------
    source : str
        How the user named the source: a path, ``camera 0``, a URL.
    problem : str
        What went wrong, one line, lower case.
    lost_frames : int
        Frames known to exist that will not be delivered (a truncated file); counted
        as unreadable by :func:`process_stream`.
    """

    def __init__(self, source: str, problem: str, lost_frames: int = 0) -> None:
        self.source = source
        self.problem = problem
        self.lost_frames = lost_frames
        super().__init__(f"{source}: {problem}")


@dataclass
class FrameSource:
    """Frames to process and what is known about where they come from.

    Attributes
    ----------
    name : str
        Stem of the output files (``<name>.jsonl``).
    label : str
        How messages name the source (the path, ``camera 0``, the URL).
    frames : iterable of Frame
        The frames, in order. The iterator may raise :class:`VideoSourceError` when
        the source is lost; any other exception is reported the same way.
    fps : float or None
        Frame rate, when known.
    frame_count : int or None
        Number of frames, when known (video files).
    release : callable or None
        Called once by :meth:`close` (releases the capture device).
    epoch_s : float or None
        For a live source, the Unix time of timestamp 0, so that frames can be stamped
        with the wall-clock time they were read (recordings); None for files.
    """

    name: str
    label: str
    frames: Iterable[Frame]
    fps: float | None = None
    frame_count: int | None = None
    release: Callable[[], None] | None = None
    epoch_s: float | None = None

    def close(self) -> None:
        """Release the underlying capture; safe to call more than once."""
        release, self.release = self.release, None
        if release is not None:
            release()


class FrameRecord(BaseModel):
    """One line of the JSON Lines output: a frame's detection with its position.

    ``detection`` is written with every field of its own class: a
    :class:`schemas.Tracks` (``dlo track``) keeps its tracks' fields and its ``tracking``.
    """

    frame: int = Field(ge=0, description="Frame index in the stream, from 0.")
    timestamp_s: float = Field(description="Presentation time of the frame in seconds.")
    detection: SerializeAsAny[Detection]


_Record = TypeVar("_Record", bound=FrameRecord)


class StreamAnalyser(Protocol):
    """What :func:`process_stream` runs on each frame instead of plain detection (the
    tracker of :mod:`service.tracking`, which keeps state from frame to frame)."""

    def __call__(self, frame: Frame) -> Detection:
        """The frame's result; raises :class:`InvalidInputError` for a frame it cannot use."""

    def lost(self, frame: Frame) -> None:
        """A frame that could not be read (the next result may say so)."""


@dataclass(frozen=True)
class StreamOutputs:
    """Where the outputs for one video or stream go."""

    jsonl: Path
    """``<stem>.jsonl``: one :class:`FrameRecord` per line."""
    overlay_video: Path
    """``<stem>.overlay.mp4``: the detections drawn over the frames."""
    mcap: Path
    """``<stem>.mcap``: the ROS 2 recording of the frames and their detections."""

    @classmethod
    def for_stem(cls, stem: str, out_dir: str | os.PathLike[str]) -> StreamOutputs:
        """Output paths in ``out_dir`` named ``<stem>.jsonl``, ``<stem>.overlay.mp4`` and
        ``<stem>.mcap``."""
        directory = Path(out_dir)
        return cls(
            jsonl=directory / f"{stem}.jsonl",
            overlay_video=directory / f"{stem}.overlay.mp4",
            mcap=directory / f"{stem}.mcap",
        )


@dataclass(frozen=True)
class FrameOutcome:
    """What happened to one frame; passed to the ``on_frame`` callback.

    Attributes
    ----------
    index : int
    timestamp_s : float
    detection : Detection or None
        None when the frame was skipped.
    elapsed_ms : float
        Time spent on the frame: detection and writing, not waiting for the source.
    problem : str or None
        Why the frame was skipped, one line (``"frame 5: unreadable frame"``).
    """

    index: int
    timestamp_s: float
    detection: Detection | None
    elapsed_ms: float
    problem: str | None = None


@dataclass
class StreamSummary:
    """The result of :func:`process_stream`.

    Attributes
    ----------
    source : str
        The source's label.
    jsonl_path, overlay_path, mcap_path : Path or None
        The outputs written (None when not asked for).
    processed : int
        Frames whose detection was written.
    unreadable : int
        Frames the source could not read or decode (or lost, see
        :class:`VideoSourceError`).
    failed : int
        Frames the detection failed on.
    interrupted : bool
        Stopped by Ctrl-C (``KeyboardInterrupt``).
    stop_reason : str or None
        Why reading stopped before the end of the source, one line (source lost).
    output_error : str or None
        An output could not be written; processing stopped there.
    elapsed_s : float
        Wall-clock time of the whole run.
    frame_ms : list of float
        Per processed frame, the time spent on it (see :class:`FrameOutcome`).
    """

    source: str
    jsonl_path: Path | None = None
    overlay_path: Path | None = None
    mcap_path: Path | None = None
    processed: int = 0
    unreadable: int = 0
    failed: int = 0
    interrupted: bool = False
    stop_reason: str | None = None
    output_error: str | None = None
    elapsed_s: float = 0.0
    frame_ms: list[float] = field(default_factory=list)

    @property
    def frames(self) -> int:
        """Frames taken from the source: processed, unreadable and failed."""
        return self.processed + self.unreadable + self.failed

    @property
    def skipped(self) -> int:
        """Frames without a detection: unreadable or failed."""
        return self.unreadable + self.failed

    @property
    def p50_ms(self) -> float | None:
        """Median time per processed frame in ms; None when nothing was processed."""
        return statistics.median(self.frame_ms) if self.frame_ms else None

    @property
    def fps(self) -> float:
        """Processed frames per second of wall-clock time."""
        return self.processed / self.elapsed_s if self.elapsed_s > 0 else 0.0

    @property
    def succeeded(self) -> bool:
        """At least one frame was processed and every output could be written."""
        return self.processed > 0 and self.output_error is None


def is_video_path(path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` names a video file, by its extension (:data:`VIDEO_SUFFIXES`).

    Examples
    --------
    >>> is_video_path("clips/run1.MP4"), is_video_path("scene.png")
    (True, False)
    """
    return Path(path).suffix.lower() in VIDEO_SUFFIXES


def parse_camera(text: str) -> int | str:
    """A ``--camera`` value: a device index (an integer) or a stream URL / device path.

    Examples
    --------
    >>> parse_camera("0"), parse_camera("rtsp://10.0.0.5/live")
    (0, 'rtsp://10.0.0.5/live')
    """
    text = text.strip()
    return int(text) if re.fullmatch(r"-?\d+", text) else text


def open_video(path: str | os.PathLike[str]) -> FrameSource:
    """Open a video file (any container and codec OpenCV reads) as a :class:`FrameSource`.

    Timestamps come from the container (``CAP_PROP_POS_MSEC``), or are
    ``index / fps`` when it gives none. A frame that fails to decode is delivered
    as ``image=None`` and reading goes on; when more than
    :data:`MAX_FILE_READ_FAILURES` frames in a row fail, or the file ends before the
    frame count its container announces, the iterator raises
    :class:`VideoSourceError` with the missing frames in ``lost_frames``.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    FrameSource
        Named after the file stem. Call :meth:`FrameSource.close` when done
        (:func:`process_stream` does).

    Raises
    ------
    VideoSourceError
        The file is missing, empty, a directory, or not a video OpenCV can open.
    """
    label = str(path)
    file_path = Path(path)
    if not file_path.exists():
        raise VideoSourceError(label, "no such file or directory")
    if file_path.is_dir():
        raise VideoSourceError(label, "is a directory, not a video file")
    try:
        size = file_path.stat().st_size
    except OSError as exc:
        raise VideoSourceError(label, f"cannot read: {exc.strerror or exc}") from exc
    if size == 0:
        raise VideoSourceError(label, "empty file (0 bytes)")
    if not os.access(file_path, os.R_OK):
        raise VideoSourceError(label, "cannot read: permission denied")
    capture = _open_capture(str(file_path))
    if capture is None:
        raise VideoSourceError(
            label, "cannot open as a video (damaged file, or a format OpenCV cannot read)"
        )
    fps = _positive(capture.get(cv2.CAP_PROP_FPS), upper=1000.0)
    count = _positive(capture.get(cv2.CAP_PROP_FRAME_COUNT), upper=1e9)
    frame_count = round(count) if count is not None else None
    return FrameSource(
        name=file_path.stem,
        label=label,
        frames=_file_frames(capture, label, fps or DEFAULT_FPS, frame_count),
        fps=fps,
        frame_count=frame_count,
        release=capture.release,
    )


def open_camera(
    source: int | str, *, timeout_s: float | None = None, name: str | None = None
) -> FrameSource:
    """Open a camera (device index) or a stream (URL, device path) as a :class:`FrameSource`.

    Timestamps are seconds since reading started. A read that fails is retried
    about once per frame interval; when the read succeeds again, each failed read
    is delivered as one ``image=None`` frame (a dropped frame). When no frame comes
    for ``timeout_s`` seconds the iterator raises :class:`VideoSourceError`.

    Parameters
    ----------
    source : int or str
        Device index (``0`` is the first camera) or anything OpenCV opens as a
        stream: ``rtsp://``, ``http://`` URLs, ``/dev/video2``, a file.
    timeout_s : float, optional
        How long to wait for a frame before the source is considered lost;
        :data:`CAMERA_TIMEOUT_S` by default.
    name : str, optional
        Stem of the output files; by default ``camera<index>``, or the last part of
        the URL's path (``stream`` when it has none).

    Returns
    -------
    FrameSource

    Raises
    ------
    VideoSourceError
        The camera or stream cannot be opened.
    """
    label = f"camera {source}" if isinstance(source, int) else str(source)
    capture = _open_capture(source)
    if capture is None:
        raise VideoSourceError(label, "cannot open camera or stream")
    fps = _positive(capture.get(cv2.CAP_PROP_FPS), upper=1000.0)
    started, epoch = time.monotonic(), time.time()
    return FrameSource(
        name=name or stream_name(source),
        label=label,
        frames=_camera_frames(
            capture,
            label,
            fps or DEFAULT_FPS,
            CAMERA_TIMEOUT_S if timeout_s is None else timeout_s,
            started,
        ),
        fps=fps,
        release=capture.release,
        epoch_s=epoch,
    )


def stream_name(source: int | str) -> str:
    """The default output stem of a camera or stream.

    Examples
    --------
    >>> stream_name(0), stream_name("rtsp://10.0.0.5:554/live/cam1"), stream_name("udp://@:5000")
    ('camera0', 'cam1', 'stream')
    """
    if isinstance(source, int):
        return f"camera{source}"
    stem = Path(urlsplit(source).path).stem
    stem = re.sub(r"[^A-Za-z0-9._-]+", "_", stem).strip("._")
    return stem or "stream"


def process_stream(
    source: FrameSource,
    params: DetectParams | None,
    out_dir: str | os.PathLike[str],
    *,
    jsonl: bool = True,
    overlay_video: bool = False,
    mcap: bool = False,
    max_frames: int | None = None,
    on_frame: Callable[[FrameOutcome], None] | None = None,
    segmenter: Segmenter | None = None,
    analyser: StreamAnalyser | None = None,
) -> StreamSummary:
    """Detect the cables in every frame of a source and write the outputs as it goes.

    Parameters
    ----------
    source : FrameSource
        Closed when this returns, whatever happened.
    params : DetectParams or None
        Detection parameters; None for the defaults.
    out_dir : str or Path
        Existing directory for the files of :class:`StreamOutputs`.
    jsonl : bool
        Write ``<stem>.jsonl``, one :class:`FrameRecord` per processed frame.
    overlay_video : bool
        Write ``<stem>.overlay.mp4``.
    mcap : bool
        Write ``<stem>.mcap``, the ROS 2 recording.
    max_frames : int, optional
        Stop after taking this many frames from the source.
    on_frame : callable, optional
        Called with a :class:`FrameOutcome` after each frame (progress, messages).
    segmenter : callable, optional
        The segmenter for ``params.segmentation == "model"`` (see
        :mod:`service.perception.segmenter`).
    analyser : StreamAnalyser, optional
        Runs on each frame instead of :func:`service.perception.detect` (and is told of
        the frames that could not be read): the tracker, for ``dlo track``.

    Returns
    -------
    StreamSummary
        Counts, timings and why processing stopped early, if it did.

    Raises
    ------
    OutputWriteError
        Only when ``<stem>.jsonl`` or ``<stem>.mcap`` cannot be created; a write error later stops
        processing and is reported in :attr:`StreamSummary.output_error`.

    Notes
    -----
    Never raises ``KeyboardInterrupt``: Ctrl-C stops reading, the outputs are
    closed (the JSON Lines file holding only complete lines, the overlay video
    finalised, the recording holding whole frames, with its summary) and the summary has
    ``interrupted=True``.

    Examples
    --------
    >>> import tempfile
    >>> import cv2, numpy as np
    >>> frames = []
    >>> for index in range(3):
    ...     image = np.zeros((120, 200, 3), np.uint8)
    ...     _ = cv2.line(image, (10, 40 + 10 * index), (190, 60), (0, 200, 255), 9)
    ...     frames.append(Frame(index, index / 10, image))
    >>> source = FrameSource(name="clip", label="clip", frames=frames, fps=10)
    >>> summary = process_stream(source, None, tempfile.mkdtemp())
    >>> summary.processed, summary.skipped
    (3, 0)
    >>> [(r.frame, len(r.detection.chains)) for r in read_frame_records(summary.jsonl_path)]
    [(0, 1), (1, 1), (2, 1)]
    """
    outputs = StreamOutputs.for_stem(source.name, out_dir)
    summary = StreamSummary(
        source=source.label,
        jsonl_path=outputs.jsonl if jsonl else None,
        overlay_path=outputs.overlay_video if overlay_video else None,
        mcap_path=outputs.mcap if mcap else None,
    )
    started = time.perf_counter()
    lines: _JsonLinesWriter | None = None
    overlay: _OverlayVideoWriter | None = None
    recording: _Recording | None = None
    try:
        lines = _JsonLinesWriter(outputs.jsonl) if jsonl else None
        if overlay_video:
            overlay = _OverlayVideoWriter(outputs.overlay_video, source.fps or DEFAULT_FPS)
        if mcap:
            recording = _Recording(outputs.mcap, source.epoch_s)
        writers = (lines, overlay, recording)
        _run(source, params, summary, writers, max_frames, on_frame, segmenter, analyser)
    except KeyboardInterrupt:
        summary.interrupted = True
    finally:
        problems = []
        for output in (lines, overlay, recording):
            if output is not None:
                try:
                    output.close()
                except OutputWriteError as exc:
                    problems.append(str(exc))
        source.close()
        summary.elapsed_s = time.perf_counter() - started
    if problems and summary.output_error is None:
        summary.output_error = problems[0]
    return summary


def read_frame_records(
    path: str | os.PathLike[str], record_type: type[_Record] = FrameRecord
) -> Iterator[_Record]:
    """Read back a JSON Lines file written by :func:`process_stream`, line by line.

    Parameters
    ----------
    path : str or Path
    record_type : type of FrameRecord
        The class of each line (``service.tracking.TrackRecord`` for ``dlo track``'s).

    Yields
    ------
    FrameRecord

    Raises
    ------
    pydantic.ValidationError
        A line is not a valid ``record_type``.
    """
    with open(path, encoding="utf-8") as stream:
        for line in stream:
            if line.strip():
                yield record_type.model_validate_json(line)


def _run(
    source: FrameSource,
    params: DetectParams | None,
    summary: StreamSummary,
    writers: tuple[_JsonLinesWriter | None, _OverlayVideoWriter | None, _Recording | None],
    max_frames: int | None,
    on_frame: Callable[[FrameOutcome], None] | None,
    segmenter: Segmenter | None = None,
    analyser: StreamAnalyser | None = None,
) -> None:
    """The frame loop of :func:`process_stream`; fills ``summary`` in place."""
    lines, overlay, recording = writers
    frames = iter(source.frames)
    while max_frames is None or summary.frames < max_frames:
        try:
            frame = next(frames)
        except StopIteration:
            return
        except VideoSourceError as exc:
            summary.unreadable += exc.lost_frames
            summary.stop_reason = exc.problem
            return
        except Exception as exc:  # a broken source ends the stream, it does not crash it
            summary.stop_reason = f"reading failed: {type(exc).__name__}: {_one_line(exc)}"
            return

        started = time.perf_counter()
        index, timestamp = frame.index, float(frame.timestamp_s)
        detection = None
        problem = None
        if frame.image is None:
            summary.unreadable += 1
            problem = f"frame {index}: unreadable frame, skipped"
            if analyser is not None:
                analyser.lost(frame)
        else:
            try:
                if analyser is not None:
                    detection = analyser(frame)
                else:
                    detection = detect(frame.image, params, segmenter=segmenter)
            except InvalidInputError as exc:
                problem = f"frame {index}: {_one_line(exc)}"
            except Exception as exc:  # one bad frame does not end the stream
                raise_if_interrupted(exc)
                problem = f"frame {index}: internal error: {type(exc).__name__}: {_one_line(exc)}"
            if detection is None:
                summary.failed += 1
            else:
                # Ctrl-C waits until this frame's outputs are whole (a KeyboardInterrupt
                # inside pydantic's serialiser would surface as an internal error).
                try:
                    with interrupts_held():
                        if overlay is not None:
                            overlay.write(render_overlay(frame.image, detection))
                        if lines is not None:
                            record = FrameRecord(
                                frame=index, timestamp_s=round(timestamp, 6), detection=detection
                            )
                            lines.write(record.model_dump_json() + "\n")
                        if recording is not None:
                            recording.write(timestamp, detection, frame.image)
                except OutputWriteError as exc:
                    summary.output_error = str(exc)
                    return
                summary.processed += 1
        elapsed_ms = (time.perf_counter() - started) * 1000.0
        if detection is not None:
            summary.frame_ms.append(elapsed_ms)
        if on_frame is not None:
            on_frame(FrameOutcome(index, timestamp, detection, elapsed_ms, problem))


class _JsonLinesWriter:
    """Appends whole lines, flushed one by one; on close, drops any incomplete tail.

    A line counts as written once ``write`` returns. Should ``write`` be cut short
    (Ctrl-C while the bytes go out), :meth:`close` truncates the file back to the
    last complete line, so the file is always valid JSON Lines.
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self._committed = 0
        try:
            self._file = open(path, "w+b")  # noqa: SIM115  (closed in close())
        except OSError as exc:
            raise OutputWriteError(f"cannot write {path}: {exc.strerror or exc}") from exc

    def write(self, line: str) -> None:
        data = line.encode("utf-8")
        try:
            self._file.write(data)
            self._file.flush()
        except OSError as exc:
            raise OutputWriteError(f"cannot write {self.path}: {exc.strerror or exc}") from exc
        self._committed += len(data)

    def close(self) -> None:
        if self._file.closed:
            return
        try:
            self._file.flush()
            size = self._file.seek(0, os.SEEK_END)
            if size > self._committed:
                # Ctrl-C may land after a line's bytes went out but before write() noted
                # them: keep every line that ends in its newline, drop only a broken tail.
                self._file.seek(self._committed)
                tail = self._file.read(size - self._committed)
                self._committed += tail.rfind(b"\n") + 1
            self._file.truncate(self._committed)
            self._file.close()
        except OSError as exc:
            raise OutputWriteError(f"cannot write {self.path}: {exc.strerror or exc}") from exc


class _Recording:
    """``<stem>.mcap``: a :class:`service.ros.recording.McapRecorder`, frames stamped with
    the source's epoch (when live) plus their timestamp."""

    def __init__(self, path: Path, epoch_s: float | None) -> None:
        from service.ros.messages import seconds_to_ns
        from service.ros.recording import McapRecorder, RecordingError

        self._failed = RecordingError
        with self._errors():
            self._recorder = McapRecorder(path)
        self._epoch_ns = 0 if epoch_s is None else seconds_to_ns(epoch_s)
        self._to_ns = seconds_to_ns

    def write(self, timestamp_s: float, detection: Detection, image: np.ndarray) -> None:
        stamp_ns = self._epoch_ns + self._to_ns(timestamp_s)
        with self._errors():
            self._recorder.write(stamp_ns, detection, image=image)

    def close(self) -> None:
        with self._errors():
            self._recorder.close()

    @contextlib.contextmanager
    def _errors(self) -> Iterator[None]:
        try:
            yield
        except self._failed as exc:
            raise OutputWriteError(str(exc)) from exc


class _OverlayVideoWriter:
    """An ``mp4v`` video opened at the first frame, whose size it keeps."""

    def __init__(self, path: Path, fps: float) -> None:
        self.path = path
        self.fps = fps
        self._writer: cv2.VideoWriter | None = None
        self._size: tuple[int, int] | None = None

    def write(self, image: np.ndarray) -> None:
        height, width = image.shape[:2]
        if self._writer is None:
            with _opencv_quiet():
                fourcc = cv2.VideoWriter_fourcc(*OVERLAY_FOURCC)
                writer = cv2.VideoWriter(str(self.path), fourcc, self.fps, (width, height))
            if not writer.isOpened():
                raise OutputWriteError(f"cannot write {self.path}: OpenCV cannot create the video")
            self._writer, self._size = writer, (width, height)
        if (width, height) != self._size:  # a stream may change resolution
            image = cv2.resize(image, self._size, interpolation=cv2.INTER_AREA)
        with _opencv_quiet():
            self._writer.write(image)

    def close(self) -> None:
        writer, self._writer = self._writer, None
        if writer is not None:
            writer.release()


def _open_capture(source: int | str) -> cv2.VideoCapture | None:
    """A ``cv2.VideoCapture`` that is open, or None; OpenCV's own messages silenced."""
    try:
        with _opencv_quiet():
            capture = cv2.VideoCapture(source)
    except cv2.error:
        return None
    if not capture.isOpened():
        capture.release()
        return None
    return capture


def _read(capture: cv2.VideoCapture) -> np.ndarray | None:
    try:
        with _opencv_quiet():
            ok, image = capture.read()
    except cv2.error:
        return None
    if not ok or image is None or image.size == 0:
        return None
    return image


def _file_frames(
    capture: cv2.VideoCapture, label: str, fps: float, frame_count: int | None
) -> Iterator[Frame]:
    """Frames of a video file; see :func:`open_video`."""
    index = 0
    failures = 0  # consecutive failed reads, not yet known to be frames or the end
    while True:
        image = _read(capture)
        if image is None:
            failures += 1
            past_end = frame_count is not None and index + failures > frame_count
            if failures > MAX_FILE_READ_FAILURES or past_end:
                break
            continue
        for _ in range(failures):
            yield Frame(index, index / fps, None)
            index += 1
        failures = 0
        milliseconds = capture.get(cv2.CAP_PROP_POS_MSEC)
        if math.isfinite(milliseconds) and (milliseconds > 0 or index == 0):
            timestamp = milliseconds / 1000.0
        else:
            timestamp = index / fps
        yield Frame(index, timestamp, image)
        index += 1
    if frame_count is not None and index < frame_count:
        missing = frame_count - index
        raise VideoSourceError(
            label,
            f"no frame could be read after frame {index - 1}; {missing} of the "
            f"{frame_count} frames the file announces are missing (truncated or damaged)",
            lost_frames=missing,
        )


def _camera_frames(
    capture: cv2.VideoCapture, label: str, fps: float, timeout_s: float, started: float
) -> Iterator[Frame]:
    """Frames of a camera or stream, timed from ``started`` (``time.monotonic()``); see
    :func:`open_camera`."""
    retry_interval = min(max(1.0 / fps, 0.005), 0.2)
    index = 0
    failed_at: list[float] = []  # times of the failed reads since the last frame
    last_frame = started
    while True:
        image = _read(capture)
        now = time.monotonic()
        if image is None:
            if now - last_frame > timeout_s:
                raise VideoSourceError(
                    label, f"stopped delivering frames (none for {timeout_s:g} s)"
                )
            failed_at.append(now - started)
            time.sleep(retry_interval)
            continue
        for timestamp in failed_at:
            yield Frame(index, timestamp, None)
            index += 1
        failed_at.clear()
        last_frame = now
        yield Frame(index, now - started, image)
        index += 1


def _positive(value: float, upper: float) -> float | None:
    """``value`` when it is a plausible positive number below ``upper``, else None."""
    if math.isfinite(value) and 0 < value < upper:
        return float(value)
    return None


def _one_line(error: BaseException) -> str:
    text = " ".join(line.strip() for line in str(error).splitlines() if line.strip())
    return text or type(error).__name__
