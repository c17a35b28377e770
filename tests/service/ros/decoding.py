"""Reading our ROS 2 output back with tools that are not the ones that wrote it.

Recordings are read with ``mcap``'s stock reader, and every message (recorded or sent over
zenoh) is decoded with ``mcap-ros2-support``'s CDR decoder, which parses the ``ros2msg``
schema text itself: an implementation independent of ``rosbags``, whose serializer wrote
the messages.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from mcap.reader import make_reader
from mcap.records import Schema
from mcap_ros2.decoder import DecoderFactory

from service.ros.messages import message_definition

LINE_STRIP, LINE_LIST, SPHERE_LIST, TEXT_VIEW_FACING = 4, 5, 7, 9
DELETEALL = 3


@dataclass
class Recorded:
    topic: str
    log_time: int
    publish_time: int
    sequence: int
    schema_name: str
    message: Any


def read_recording(path: Path) -> list[Recorded]:
    """Every message of an MCAP file, in log-time order, decoded (stock reader)."""
    with path.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        header = reader.get_header()
        assert header.profile == "ros2"
        return [
            Recorded(
                channel.topic,
                message.log_time,
                message.publish_time,
                message.sequence,
                schema.name,
                decoded,
            )
            for schema, channel, message, decoded in reader.iter_decoded_messages(
                log_time_order=True
            )
        ]


def decode_cdr(payload: bytes, msgtype: str) -> Any:
    """A CDR payload decoded by mcap-ros2-support with the ``ros2msg`` definition of
    ``msgtype`` (rosbags' text of it: the schema we store in recordings)."""
    schema = Schema(
        id=1, name=msgtype, encoding="ros2msg", data=message_definition(msgtype).encode()
    )
    decoder = DecoderFactory().decoder_for("cdr", schema)
    assert decoder is not None
    return decoder(payload)


def line_strips(markers: Any) -> dict[int, list[tuple[float, float, float]]]:
    """The LINE_STRIP markers of a MarkerArray: chain id -> points."""
    return {
        marker.id: [(point.x, point.y, point.z) for point in marker.points]
        for marker in markers.markers
        if marker.type == LINE_STRIP and marker.action == 0
    }


def decoded_image(message: Any) -> np.ndarray:
    """A decoded sensor_msgs/msg/CompressedImage's pixels (OpenCV, from its bytes)."""
    image = cv2.imdecode(np.frombuffer(bytes(message.data), np.uint8), cv2.IMREAD_UNCHANGED)
    assert image is not None, f"the {message.format} image does not decode"
    return image


# The ROS 2 message definitions of sensor_msgs' images as the .msg files give them, typed
# here rather than taken from rosbags, so that the messages the tests send are written
# by mcap-ros2-support's encoder from a definition of their own.
_HEADER = """
================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
"""
IMAGE_DEFINITION = (
    """std_msgs/Header header
uint32 height
uint32 width
string encoding
uint8 is_bigendian
uint32 step
uint8[] data"""
    + _HEADER
)
COMPRESSED_IMAGE_DEFINITION = (
    """std_msgs/Header header
string format
uint8[] data"""
    + _HEADER
)


def _encoder(msgtype: str, definition: str):
    from mcap_ros2._dynamic import serialize_dynamic  # the encoder its Writer uses

    return serialize_dynamic(msgtype, definition)[msgtype]


def _header(stamp_ns: int, frame_id: str) -> dict:
    seconds, nanoseconds = divmod(stamp_ns, 1_000_000_000)
    return {"stamp": {"sec": seconds, "nanosec": nanoseconds}, "frame_id": frame_id}


def image_message(
    pixels: np.ndarray,
    encoding: str,
    stamp_ns: int = 0,
    *,
    step: int | None = None,
    big_endian: bool = False,
) -> bytes:
    """A CDR sensor_msgs/msg/Image of ``pixels`` (rows padded to ``step`` bytes)."""
    height, width = pixels.shape[:2]
    dtype = pixels.dtype.newbyteorder(">" if big_endian else "<")
    rows = pixels.astype(dtype).reshape(height, width * pixels[0:1, 0:1].size).view(np.uint8)
    step = rows.shape[1] if step is None else step
    padded = np.zeros((height, step), np.uint8)
    kept = min(step, rows.shape[1])  # a step shorter than a row makes a broken message
    padded[:, :kept] = rows[:, :kept]
    message = {
        "header": _header(stamp_ns, "cam_optical_frame"),
        "height": height,
        "width": width,
        "encoding": encoding,
        "is_bigendian": int(big_endian),
        "step": step,
        "data": padded.tobytes(),
    }
    return bytes(_encoder("sensor_msgs/msg/Image", IMAGE_DEFINITION)(message))


def compressed_image_message(data: bytes, image_format: str, stamp_ns: int = 0) -> bytes:
    """A CDR sensor_msgs/msg/CompressedImage of encoded ``data``."""
    message = {"header": _header(stamp_ns, "cam"), "format": image_format, "data": data}
    return bytes(_encoder("sensor_msgs/msg/CompressedImage", COMPRESSED_IMAGE_DEFINITION)(message))
