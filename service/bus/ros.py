"""ROS 2 on the zenoh bus: camera frames as CDR ``sensor_msgs`` samples in, markers out.

``zenoh-bridge-ros2dds`` maps a ROS 2 topic ``/a/b`` to the zenoh key ``a/b`` with the
CDR-encoded message as the payload, so a ROS 2 camera publishing ``/dlo/cam1/image_raw``
reaches the service on ``dlo/cam1/image_raw``, and the service's
``dlo/cam1/markers`` reaches ROS 2 as ``/dlo/cam1/markers``. This module reads those
frames (:func:`read_ros_frame`) and builds the markers (:func:`markers_payload`); the
messages themselves are :mod:`service.ros.messages`' (``rosbags``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import zenoh

from schemas import Detection, FrameIdentity
from service.bus.config import COMPRESSED_IMAGE_SUFFIX, RAW_IMAGE_SUFFIX
from service.ros.messages import (
    RosMessageError,
    markers_cdr,
    read_compressed_image_message,
    read_image_message,
    seconds_to_ns,
)
from service.runtime.errors import RequestError
from service.runtime.frames import check_pixels

ENCODED = "image"
"""The kind of a frame on ``dlo/<camera>/image``: an encoded JPEG or PNG."""
RAW = RAW_IMAGE_SUFFIX
COMPRESSED = COMPRESSED_IMAGE_SUFFIX
PIXEL_FRAME_SUFFIX = "_pixels"
"""The markers of camera ``cam1`` are in the frame ``cam1_pixels``."""


def frame_kind(key: str) -> str:
    """What a frame on ``key`` holds: :data:`ENCODED`, :data:`RAW` or :data:`COMPRESSED`
    (``dlo/<camera>/image``, ``.../image_raw``, ``.../image_raw/compressed``)."""
    return key.split("/", 2)[2]


def ros_attachment(attachment: zenoh.ZBytes | None) -> zenoh.ZBytes | None:
    """The part of a ROS 2 frame's attachment that is ours: a JSON object (parameters and
    frame identity, as on ``dlo/<camera>/image``) is kept; anything else, such as the
    binary attachment ``rmw_zenoh`` adds (sequence number, time, publisher id), is not
    meant for us and is ignored."""
    if attachment is None or attachment.to_bytes().lstrip()[:1] != b"{":
        return None
    return attachment


@dataclass(frozen=True)
class RosFrame:
    """A frame a ROS 2 message carried: still encoded, or already pixels."""

    stamp_s: float | None
    encoded: bytes | None = None
    image: np.ndarray | None = None


def read_ros_frame(kind: str, payload: bytes, max_pixels: int) -> RosFrame:
    """Read a CDR ``sensor_msgs/msg/Image`` (:data:`RAW`) or ``CompressedImage``.

    Raises
    ------
    RequestError
        422 ``invalid_image`` when the payload is not such a message or its image cannot be
        used (the message says why), 413 ``image_too_large`` beyond ``max_pixels``.
    """
    name = "image_raw" if kind == RAW else "image_raw/compressed"
    try:
        if kind == RAW:
            received = read_image_message(
                payload, lambda width, height: check_pixels(width, height, max_pixels)
            )
        else:
            received = read_compressed_image_message(payload)
    except RosMessageError as exc:
        raise RequestError(422, "invalid_image", f"{name}: {exc}") from None
    if received.encoded is not None and not received.encoded:
        raise RequestError(422, "invalid_image", f"{name}: the message holds no image data")
    return RosFrame(received.stamp_s, encoded=received.encoded, image=received.image)


def with_stamp(identity: FrameIdentity, stamp_s: float | None) -> FrameIdentity:
    """The frame's identity, its ``capture_time`` the message's ``header.stamp`` unless the
    attachment gave one."""
    if identity.capture_time is not None or stamp_s is None:
        return identity
    return identity.model_copy(update={"capture_time": stamp_s})


def markers_payload(
    detection: Detection,
    camera: str,
    identity: FrameIdentity,
    sample_timestamp: zenoh.Timestamp | None,
) -> bytes:
    """The CDR ``visualization_msgs/msg/MarkerArray`` of a camera's detection, in the frame
    ``<camera>_pixels``, stamped with the frame's capture time (the attachment's, or the
    ROS 2 message's ``header.stamp``), else the zenoh timestamp of its sample, else now."""
    if identity.capture_time is not None:
        stamp_ns = seconds_to_ns(identity.capture_time)
    elif sample_timestamp is not None:
        stamp_ns = seconds_to_ns(sample_timestamp.get_time().timestamp())
    else:
        stamp_ns = time.time_ns()
    return markers_cdr(detection, max(stamp_ns, 0), frame_id=camera + PIXEL_FRAME_SUFFIX)
