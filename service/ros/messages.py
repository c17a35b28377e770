"""ROS 2 messages of a detection, built and read with ``rosbags`` (no hand-written CDR).

A detection becomes a ``visualization_msgs/msg/MarkerArray`` (:func:`marker_array`), in
this order:

=========== =============== ====================================================================
namespace   type            what
=========== =============== ====================================================================
(none)      DELETEALL       clears the previous frame's markers (a cable that left the view)
``chains``  LINE_STRIP      one per chain, ``id`` = chain id, ``points`` = its joints in order;
                            the chain's overlay colour, width = the cable's diameter
``inferred`` LINE_LIST      per chain with filled stretches, ``id`` = chain id: each inferred
                            segment as a pair of joints, white, half the width, a hair in
                            front of the chain (1 px towards the camera, 1 mm up)
``crossings`` SPHERE_LIST   ``id`` 0, one sphere per crossing in the colour of the chain on top
``ids``     TEXT_VIEW_FACING one per chain, ``id`` = chain id, at its first joint: the id, so
                            that a chain's identity and its joint 0 end can be seen
=========== =============== ====================================================================

Coordinates are pixels on ``z = 0`` in the frame :data:`PIXEL_FRAME` (``x`` the column,
``y`` the row, ``z`` away from the camera, as in an optical frame), or, for a detection
lifted to 3-D (every chain has ``points_3d``), metres in :data:`BASE_FRAME` with joints that
could not be located left out. Every marker carries the frame's stamp; ``lifetime`` 0 (until
the next frame's DELETEALL).

Frames travel as ``sensor_msgs/msg/CompressedImage`` (:func:`compressed_image_cdr`), and
cameras may send ``sensor_msgs/msg/Image`` or ``CompressedImage`` (:func:`read_image_message`,
:func:`read_compressed_image_message`).

The definitions are ROS 2 Humble's from ``rosbags``' built-in type store; Jazzy and Kilted
lay these messages out the same on the wire (Jazzy only adds the constant ``ARROW_STRIP``),
so one encoding serves all three.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from schemas import Chain, Detection
from service.perception.render import chain_colour

MARKER_ARRAY = "visualization_msgs/msg/MarkerArray"
IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"

PIXEL_FRAME = "camera_pixels"
"""The frame of markers in pixels: ``x`` = column, ``y`` = row, ``z`` = 0."""
BASE_FRAME = "base"
"""The frame of markers in metres: the robot base frame of the camera model (for a UR arm,
the controller's base frame, which ``ur_robot_driver`` calls ``base``)."""
CAMERA_FRAME = "camera"
"""The ``header.frame_id`` of recorded images."""

NANOSECONDS = 1_000_000_000
LINE_STRIP, LINE_LIST, SPHERE_LIST, TEXT_VIEW_FACING = 4, 5, 7, 9
ADD, DELETEALL = 0, 3
INFERRED_COLOUR = (1.0, 1.0, 1.0, 0.9)
MIN_WIDTH_PX = 1.0
DEFAULT_RADIUS_M = 0.003
"""Line half width in metres for a lifted chain without ``radius_m``."""
TEXT_HEIGHT_PX, TEXT_HEIGHT_M = 14.0, 0.02
IN_FRONT_PX, IN_FRONT_M = -1.0, 0.001
"""How far the inferred stretches are drawn in front of their chain: towards the camera
(``-z``) in pixels, up (``+z``) in the base frame, so that the two lines do not z-fight."""

_ENCODINGS = {
    # ROS encoding: (channels, dtype, conversion to BGR or gray uint8; None = as it is)
    "bgr8": (3, np.uint8, None),
    "8UC3": (3, np.uint8, None),
    "rgb8": (3, np.uint8, cv2.COLOR_RGB2BGR),
    "bgra8": (4, np.uint8, cv2.COLOR_BGRA2BGR),
    "8UC4": (4, np.uint8, cv2.COLOR_BGRA2BGR),
    "rgba8": (4, np.uint8, cv2.COLOR_RGBA2BGR),
    "mono8": (1, np.uint8, None),
    "8UC1": (1, np.uint8, None),
    "mono16": (1, np.uint16, None),
    "16UC1": (1, np.uint16, None),
}
IMAGE_ENCODINGS = tuple(_ENCODINGS)
"""The ``sensor_msgs/msg/Image`` encodings the service takes (16-bit ones are stretched
to 8 bits between their darkest and brightest pixel)."""


class RosMessageError(ValueError):
    """A ROS 2 message that cannot be read as what it should be; ``str()`` is one line."""


@functools.cache
def typestore() -> Any:
    """``rosbags``' type store of ROS 2 Humble (built once, about 0.2 s)."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE)


@functools.cache
def message_definition(msgtype: str) -> str:
    """The ``ros2msg`` schema text of ``msgtype`` with its dependencies, as MCAP holds it."""
    text, _ = typestore().generate_msgdef(msgtype, ros_version=2)
    return text


def seconds_to_ns(seconds: float) -> int:
    """Seconds (e.g. since the Unix epoch) as whole nanoseconds, the whole seconds kept
    exact (a float of about 1.8e18 ns would be off by up to 128 ns).

    Examples
    --------
    >>> seconds_to_ns(1767225600.125)
    1767225600125000000
    """
    whole = math.floor(seconds)
    return whole * NANOSECONDS + round((seconds - whole) * NANOSECONDS)


def serialize(message: Any, msgtype: str) -> bytes:
    """CDR (little-endian, with its 4-byte encapsulation header) of a ``rosbags`` message."""
    return bytes(typestore().serialize_cdr(message, msgtype))


def warm_up() -> None:
    """Build the type store and ``rosbags``' serializers of every message used here, so that
    the first frame does not pay for generating them (tens of milliseconds)."""
    serialize(marker_array(_WARM_UP, 0), MARKER_ARRAY)
    compressed_image_cdr(b"", "jpeg", 0)
    empty = np.zeros(0, np.uint8)
    image = _types()["Image"](
        header=_header(0, ""), height=0, width=0, encoding="", is_bigendian=0, step=0, data=empty
    )
    typestore().deserialize_cdr(serialize(image, IMAGE), IMAGE)
    typestore().deserialize_cdr(compressed_image_cdr(b"", "jpeg", 0), COMPRESSED_IMAGE)


# ----------------------------------------------------------------------------- markers


def marker_array(detection: Detection, stamp_ns: int, frame_id: str | None = None) -> Any:
    """The ``visualization_msgs/msg/MarkerArray`` of ``detection`` (see the module's table).

    Parameters
    ----------
    detection : Detection
        In pixels, or lifted to 3-D (every chain with ``points_3d``: metres).
    stamp_ns : int
        The frame's time, nanoseconds since the Unix epoch (or since the video's start).
    frame_id : str, optional
        Default :data:`PIXEL_FRAME`, or :data:`BASE_FRAME` for a lifted detection.
    """
    types = _types()
    metric = bool(detection.chains) and all(
        chain.points_3d is not None for chain in detection.chains
    )
    if frame_id is None:
        frame_id = BASE_FRAME if metric else PIXEL_FRAME
    header = _header(stamp_ns, frame_id)
    markers = [_marker(header, "", 0, 0, action=DELETEALL)]
    placed = {chain.id: _placed(chain, metric) for chain in detection.chains}
    widths = {chain.id: _width(chain, metric) for chain in detection.chains}
    in_front = IN_FRONT_M if metric else IN_FRONT_PX
    for chain in detection.chains:
        points = [point for point in placed[chain.id] if point is not None]
        colour = _rgba(chain.id)
        markers.append(
            _marker(header, "chains", chain.id, LINE_STRIP, widths[chain.id], colour, points=points)
        )
        stretches = []
        for k, inferred in enumerate(chain.inferred):
            start, end = placed[chain.id][k], placed[chain.id][k + 1]
            if inferred and start is not None and end is not None:
                stretches += [_shifted(start, in_front), _shifted(end, in_front)]
        if stretches:
            width = widths[chain.id] / 2
            markers.append(
                _marker(
                    header,
                    "inferred",
                    chain.id,
                    LINE_LIST,
                    width,
                    INFERRED_COLOUR,
                    points=stretches,
                )
            )
    spheres, colours = [], []
    for crossing in detection.crossings:
        point = _crossing_point(detection, crossing, placed, metric)
        if point is not None:
            spheres.append(point)
            colours.append(types["ColorRGBA"](*_rgba(crossing.over)))
    if spheres:
        diameter = 2.5 * max(widths.values())
        markers.append(
            _marker(header, "crossings", 0, SPHERE_LIST, diameter, points=spheres, colours=colours)
        )
    for chain in detection.chains:
        first = next((point for point in placed[chain.id] if point is not None), None)
        if first is not None:
            height = TEXT_HEIGHT_M if metric else max(TEXT_HEIGHT_PX, 4 * chain.radius)
            markers.append(
                _marker(
                    header,
                    "ids",
                    chain.id,
                    TEXT_VIEW_FACING,
                    colour=_rgba(chain.id),
                    position=first,
                    text=str(chain.id),
                    height=height,
                )
            )
    return types["MarkerArray"](markers=markers)


def markers_cdr(detection: Detection, stamp_ns: int, frame_id: str | None = None) -> bytes:
    """:func:`marker_array` serialized as CDR."""
    return serialize(marker_array(detection, stamp_ns, frame_id), MARKER_ARRAY)


def _placed(chain: Chain, metric: bool) -> list[Any]:
    """The chain's joints as ``geometry_msgs/Point`` (None where a 3-D joint is unknown)."""
    point = _types()["Point"]
    if metric:
        return [None if p is None else point(x=p[0], y=p[1], z=p[2]) for p in chain.points_3d]
    return [point(x=x, y=y, z=0.0) for x, y in chain.points]


def _width(chain: Chain, metric: bool) -> float:
    if metric:
        return 2.0 * (DEFAULT_RADIUS_M if chain.radius_m is None else chain.radius_m)
    return max(2.0 * chain.radius, MIN_WIDTH_PX)


def _shifted(point: Any, dz: float) -> Any:
    return _types()["Point"](x=point.x, y=point.y, z=point.z + dz)


def _crossing_point(detection: Detection, crossing: Any, placed: dict, metric: bool) -> Any:
    """Where a crossing is drawn: its pixel, or its place on the upper strand in 3-D."""
    if not metric:
        return _types()["Point"](x=crossing.x, y=crossing.y, z=0.0)
    chain = next((c for c in detection.chains if c.id == crossing.over), None)
    if chain is None or crossing.over_segment + 1 >= len(chain.points):
        return None
    k = crossing.over_segment
    start, end = placed[chain.id][k], placed[chain.id][k + 1]
    if start is None or end is None:
        return None
    (x0, y0), (x1, y1) = chain.points[k], chain.points[k + 1]
    dx, dy = x1 - x0, y1 - y0
    length_sq = dx * dx + dy * dy
    along = ((crossing.x - x0) * dx + (crossing.y - y0) * dy) / length_sq if length_sq else 0.0
    t = min(max(along, 0.0), 1.0)
    return _types()["Point"](
        x=start.x + t * (end.x - start.x),
        y=start.y + t * (end.y - start.y),
        z=start.z + t * (end.z - start.z),
    )


def _rgba(chain_id: int) -> tuple[float, float, float, float]:
    blue, green, red = chain_colour(chain_id)
    return red / 255.0, green / 255.0, blue / 255.0, 1.0


def _marker(
    header: Any,
    namespace: str,
    marker_id: int,
    kind: int,
    width: float = 0.0,
    colour: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0),
    *,
    points: list[Any] | None = None,
    action: int = ADD,
    colours: list[Any] | None = None,
    position: Any = None,
    text: str = "",
    height: float = 0.0,
) -> Any:
    types = _types()
    if kind == SPHERE_LIST:
        scale = types["Vector3"](x=width, y=width, z=width)
    else:  # lines: x is the width; text: z is the height
        scale = types["Vector3"](x=width, y=0.0, z=height)
    return types["Marker"](
        header=header,
        ns=namespace,
        id=marker_id,
        type=kind,
        action=action,
        pose=types["Pose"](
            position=position if position is not None else _origin(), orientation=_identity()
        ),
        scale=scale,
        color=types["ColorRGBA"](*colour),
        lifetime=types["Duration"](sec=0, nanosec=0),
        frame_locked=False,
        points=points or [],
        colors=colours or [],
        texture_resource="",
        texture=types["CompressedImage"](
            header=_header(0, ""), format="", data=np.zeros(0, np.uint8)
        ),
        uv_coordinates=[],
        text=text,
        mesh_resource="",
        mesh_file=types["MeshFile"](filename="", data=np.zeros(0, np.uint8)),
        mesh_use_embedded_materials=False,
    )


def _origin() -> Any:
    return _types()["Point"](x=0.0, y=0.0, z=0.0)


def _identity() -> Any:
    return _types()["Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)


# ------------------------------------------------------------------------------ images


def compressed_image_cdr(
    data: bytes, image_format: str, stamp_ns: int, frame_id: str = CAMERA_FRAME
) -> bytes:
    """A ``sensor_msgs/msg/CompressedImage`` of encoded ``data`` (``"jpeg"`` or ``"png"``)."""
    message = _types()["CompressedImage"](
        header=_header(stamp_ns, frame_id),
        format=image_format,
        data=np.frombuffer(data, np.uint8),
    )
    return serialize(message, COMPRESSED_IMAGE)


@dataclass(frozen=True)
class ReceivedImage:
    """An image a camera sent as a ROS 2 message."""

    stamp_s: float | None
    """``header.stamp`` in seconds since the Unix epoch; None when it is zero (unset)."""
    image: np.ndarray | None = None
    """A ``sensor_msgs/msg/Image`` as a BGR or gray ``uint8`` array."""
    encoded: bytes | None = None
    """A ``sensor_msgs/msg/CompressedImage``'s data (JPEG or PNG), still encoded."""


def read_compressed_image_message(payload: bytes) -> ReceivedImage:
    """A CDR ``sensor_msgs/msg/CompressedImage``: its stamp and its encoded data.

    Raises
    ------
    RosMessageError
        The payload is not such a message.
    """
    message = _deserialize(payload, COMPRESSED_IMAGE)
    return ReceivedImage(_stamp_s(message.header.stamp), encoded=message.data.tobytes())


def read_image_message(
    payload: bytes, check_size: Callable[[int, int], None] | None = None
) -> ReceivedImage:
    """A CDR ``sensor_msgs/msg/Image`` as a BGR (or gray) ``uint8`` array and its stamp.

    Parameters
    ----------
    payload : bytes
    check_size : callable, optional
        Called with the image's width and height before its pixels are converted; raises
        to refuse it (too large).

    Raises
    ------
    RosMessageError
        The payload is not such a message, its encoding is not one of
        :data:`IMAGE_ENCODINGS`, or its size, step and data disagree.
    """
    message = _deserialize(payload, IMAGE)
    width, height, step = int(message.width), int(message.height), int(message.step)
    if check_size is not None:
        check_size(width, height)
    if width == 0 or height == 0:
        raise RosMessageError(f"sensor_msgs/msg/Image: empty image ({width}x{height})")
    encoding = str(message.encoding)
    if encoding not in _ENCODINGS:
        raise RosMessageError(
            f"sensor_msgs/msg/Image: encoding {encoding!r} is not supported; "
            f"send one of {', '.join(IMAGE_ENCODINGS)} (or a CompressedImage)"
        )
    channels, dtype, conversion = _ENCODINGS[encoding]
    item = np.dtype(dtype).itemsize
    row = width * channels * item
    data = message.data
    if step < row or len(data) < step * (height - 1) + row:
        raise RosMessageError(
            f"sensor_msgs/msg/Image: {len(data)} bytes of data for {width}x{height} "
            f"{encoding} with a step of {step}"
        )
    rows = np.lib.stride_tricks.as_strided(
        data, shape=(height, row), strides=(step, 1), writeable=False
    )
    order = ">" if message.is_bigendian else "<"
    pixels = rows.view(np.dtype(dtype).newbyteorder(order)).reshape(height, width, channels)
    if channels == 1:
        pixels = pixels[:, :, 0]
    if item == 2:
        wide = pixels.astype(np.float32)  # native byte order, whatever the message's
        pixels = cv2.normalize(wide, None, 0, 255, cv2.NORM_MINMAX, dtype=cv2.CV_8U)
    image = np.ascontiguousarray(pixels) if conversion is None else cv2.cvtColor(pixels, conversion)
    return ReceivedImage(_stamp_s(message.header.stamp), image=image)


def _deserialize(payload: bytes, msgtype: str) -> Any:
    try:
        return typestore().deserialize_cdr(payload, msgtype)
    except Exception as exc:  # rosbags raises SerdeError, or struct/index errors inside it
        detail = " ".join(str(exc).split()) or type(exc).__name__
        raise RosMessageError(f"not a CDR {msgtype}: {detail}") from None


def _stamp_s(stamp: Any) -> float | None:
    if stamp.sec == 0 and stamp.nanosec == 0:
        return None
    seconds = stamp.sec + stamp.nanosec / NANOSECONDS
    return seconds if math.isfinite(seconds) else None


# ----------------------------------------------------------------------------- helpers


@functools.cache
def _types() -> dict[str, Any]:
    """The message classes used here, by their short names."""
    names = {
        "Marker": "visualization_msgs/msg/Marker",
        "MarkerArray": MARKER_ARRAY,
        "MeshFile": "visualization_msgs/msg/MeshFile",
        "Header": "std_msgs/msg/Header",
        "ColorRGBA": "std_msgs/msg/ColorRGBA",
        "Time": "builtin_interfaces/msg/Time",
        "Duration": "builtin_interfaces/msg/Duration",
        "Point": "geometry_msgs/msg/Point",
        "Pose": "geometry_msgs/msg/Pose",
        "Quaternion": "geometry_msgs/msg/Quaternion",
        "Vector3": "geometry_msgs/msg/Vector3",
        "Image": IMAGE,
        "CompressedImage": COMPRESSED_IMAGE,
    }
    store = typestore()
    return {short: store.types[full] for short, full in names.items()}


def _header(stamp_ns: int, frame_id: str) -> Any:
    types = _types()
    seconds, nanoseconds = divmod(int(stamp_ns), NANOSECONDS)
    return types["Header"](stamp=types["Time"](sec=seconds, nanosec=nanoseconds), frame_id=frame_id)


_WARM_UP = Detection(
    width=8,
    height=8,
    segment_length=2.0,
    chains=[
        Chain(id=0, points=[(1.0, 1.0), (3.0, 1.0), (5.0, 1.0)], radius=1.0, inferred=[False, True])
    ],
)
