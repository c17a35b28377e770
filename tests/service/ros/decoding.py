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
