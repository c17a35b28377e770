"""MCAP recordings of detections as ROS 2 messages, for Foxglove, RViz and ``ros2 bag``.

:class:`McapRecorder` writes one ``.mcap`` file (profile ``ros2``, ``ros2msg`` schemas, CDR
messages; ``mcap``'s writer, LZ4-compressed chunks with the usual indexes and summary: the
JPEG frames do not compress, and zstd costs 0.2 ms a frame more for 2 % less).
Per frame it writes two messages, both stamped with the frame's time (``log_time``,
``publish_time`` and the messages' ``header.stamp``):

``/dlo/image``
    ``sensor_msgs/msg/CompressedImage``: the frame as JPEG (quality :data:`JPEG_QUALITY`),
    or an image file's own JPEG or PNG bytes, unchanged.
``/dlo/chains``
    ``visualization_msgs/msg/MarkerArray``: the detection
    (:func:`service.ros.messages.marker_array`).

A frame is written whole or not at all: Ctrl-C (SIGINT) while its two messages go in is
held back until both are in, so that a recording stopped by Ctrl-C and closed
(:meth:`McapRecorder.close`, which the front ends call on the way out) holds every whole
frame up to the last and reads back with the stock reader.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from schemas import Detection
from service.interrupts import interrupts_held
from service.ros.messages import (
    COMPRESSED_IMAGE,
    MARKER_ARRAY,
    compressed_image_cdr,
    markers_cdr,
    message_definition,
    warm_up,
)

IMAGE_TOPIC = "/dlo/image"
CHAINS_TOPIC = "/dlo/chains"
JPEG_QUALITY = 90
"""Quality of the JPEG frames of videos and cameras (about 55 kB for 640x480, 0.5 ms)."""
CHUNK_BYTES = 1024 * 1024
"""MCAP chunk size: messages reach the file a chunk at a time (all of them on close)."""
MIN_STEP_NS = 1_000_000
"""Image files are stamped at least this long after the previous one (see
:func:`file_stamp_ns`)."""
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


class RecordingError(OSError):
    """A recording cannot be written, or an image file read for it; ``str()`` is one line
    naming the file."""


class McapRecorder:
    """One MCAP file of a stream of detections and their frames; see the module.

    Parameters
    ----------
    path : str or Path
        The file, created or replaced.

    Raises
    ------
    RecordingError
        The file cannot be created.
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        from mcap.writer import CompressionType, Writer

        self.path = Path(path)
        self.frames = 0
        """Frames written so far."""
        self._last_stamp_ns: int | None = None
        warm_up()  # rosbags generates its serializers on first use
        try:
            self._file = open(self.path, "wb")  # noqa: SIM115 (closed in close())
        except OSError as exc:
            raise RecordingError(f"cannot write {self.path}: {exc.strerror or exc}") from exc
        try:
            self._writer = Writer(
                self._file, chunk_size=CHUNK_BYTES, compression=CompressionType.LZ4
            )
            self._writer.start(profile="ros2", library=_library())
            self._image_channel = self._channel(IMAGE_TOPIC, COMPRESSED_IMAGE)
            self._chains_channel = self._channel(CHAINS_TOPIC, MARKER_ARRAY)
        except OSError as exc:
            self._file.close()
            raise RecordingError(f"cannot write {self.path}: {exc.strerror or exc}") from exc

    def _channel(self, topic: str, msgtype: str) -> int:
        schema = self._writer.register_schema(
            name=msgtype, encoding="ros2msg", data=message_definition(msgtype).encode()
        )
        return self._writer.register_channel(topic=topic, message_encoding="cdr", schema_id=schema)

    def write(
        self,
        stamp_ns: int,
        detection: Detection,
        *,
        image: np.ndarray | None = None,
        encoded: tuple[bytes, str] | None = None,
    ) -> None:
        """Write one frame: its image and its detection's markers, stamped ``stamp_ns``.

        Parameters
        ----------
        stamp_ns : int
            The frame's time in nanoseconds (Unix epoch, or from the video's start).
        detection : Detection
        image : ndarray, optional
            The frame (BGR or gray ``uint8``), encoded here as JPEG.
        encoded : (bytes, str), optional
            Instead of ``image``: the frame already encoded, and its format (``"jpeg"`` or
            ``"png"``).

        Raises
        ------
        RecordingError
            The file cannot be written.
        """
        if encoded is None:
            if image is None:
                raise ValueError("give the frame: image or encoded")
            encoded = encode_jpeg(image), "jpeg"
        stamp_ns = max(int(stamp_ns), 0)
        image_message = compressed_image_cdr(encoded[0], encoded[1], stamp_ns)
        markers = markers_cdr(detection, stamp_ns)
        with interrupts_held(), self._errors():
            sequence = self.frames
            self._writer.add_message(
                self._image_channel, stamp_ns, image_message, stamp_ns, sequence
            )
            self._writer.add_message(self._chains_channel, stamp_ns, markers, stamp_ns, sequence)
            self.frames += 1
            self._last_stamp_ns = stamp_ns

    def write_file(self, path: str | os.PathLike[str], detection: Detection) -> None:
        """Write an image file's frame: its own JPEG or PNG bytes (:func:`file_image`),
        stamped with its modification time (:func:`file_stamp_ns`).

        Raises
        ------
        RecordingError
            The recording cannot be written, or the image file can no longer be read.
        """
        try:
            encoded = file_image(path)
            stamp_ns = file_stamp_ns(path, self._last_stamp_ns)
        except OSError as exc:
            raise RecordingError(f"{path}: cannot read: {exc.strerror or exc}") from None
        self.write(stamp_ns, detection, encoded=encoded)

    def close(self) -> None:
        """Write the last chunk, the indexes and the summary, and close the file; safe to
        call more than once."""
        if self._file.closed:
            return
        with interrupts_held(), self._errors():
            try:
                self._writer.finish()
            finally:
                self._file.close()

    def __enter__(self) -> McapRecorder:
        return self

    def __exit__(self, *_: object) -> None:
        self.close()

    @contextlib.contextmanager
    def _errors(self) -> Iterator[None]:
        try:
            yield
        except RecordingError:
            raise
        except OSError as exc:
            raise RecordingError(f"cannot write {self.path}: {exc.strerror or exc}") from exc


def encode_jpeg(image: np.ndarray) -> bytes:
    """``image`` as JPEG of quality :data:`JPEG_QUALITY`."""
    ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:
        raise RuntimeError("OpenCV could not encode the frame as JPEG")
    return data.tobytes()


def file_image(path: str | os.PathLike[str]) -> tuple[bytes, str]:
    """An image file as a recording holds it: a JPEG or PNG file's own bytes, any other
    format (BMP, TIFF, WebP) decoded and encoded as PNG (lossless).

    Raises
    ------
    OSError
        The file cannot be read (a :class:`RecordingError` when it is not an image).
    """
    data = Path(path).read_bytes()
    if data.startswith(PNG_SIGNATURE):
        return data, "png"
    if data.startswith(b"\xff\xd8"):
        return data, "jpeg"
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    ok, png = (False, None) if image is None else cv2.imencode(".png", image)
    if not ok:
        raise RecordingError(f"{path}: OpenCV cannot decode it for the recording")
    return png.tobytes(), "png"


def file_stamp_ns(path: str | os.PathLike[str], previous_ns: int | None) -> int:
    """An image file's stamp: its modification time, or :data:`MIN_STEP_NS` after the
    previous file's stamp when not later, so that a player shows every image in turn."""
    stamp = os.stat(path).st_mtime_ns
    if previous_ns is not None and stamp < previous_ns + MIN_STEP_NS:
        stamp = previous_ns + MIN_STEP_NS
    return stamp


def _library() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return f"dlo-service {version('dlo-service')}"
    except PackageNotFoundError:
        return "dlo-service"
