"""Where things travel on zenoh (the key expressions of the detection service) and
:func:`make_config`, the session configuration the service, the router and clients share.

Imports zenoh and the settings only: ``dlo router`` needs no detector.
"""

from __future__ import annotations

import json
from pathlib import Path

import zenoh

from service.runtime.settings import DEFAULT_ZENOH_LISTEN, IMAGE_KEYS

__all__ = [
    "CDR",
    "DEFAULT_ZENOH_LISTEN",
    "IMAGE_KEYS",
    "JSON",
    "QUERY_KEY",
    "chains_key",
    "describe_config",
    "errors_key",
    "make_config",
    "markers_key",
    "ros_image_keys",
    "service_config",
]
QUERY_KEY = "dlo/detect"
"""The queryable: ``get`` with the image as payload."""
JSON = "application/json"
CDR = zenoh.Encoding.APPLICATION_CDR
RAW_IMAGE_SUFFIX = "image_raw"
"""``dlo/<camera>/image_raw``: a CDR ``sensor_msgs/msg/Image`` (ROS 2's camera topic name)."""
COMPRESSED_IMAGE_SUFFIX = "image_raw/compressed"
"""``dlo/<camera>/image_raw/compressed``: a CDR ``sensor_msgs/msg/CompressedImage``."""


def chains_key(camera: str) -> str:
    """Where the Detections of ``camera``'s frames are published."""
    return f"dlo/{camera}/chains"


def errors_key(camera: str) -> str:
    """Where the error records of ``camera``'s unprocessable frames are published."""
    return f"dlo/{camera}/errors"


def markers_key(camera: str) -> str:
    """Where ``camera``'s Detections are published as a CDR ``visualization_msgs/msg/MarkerArray``
    (the ROS 2 topic ``/dlo/<camera>/markers`` through zenoh-bridge-ros2dds)."""
    return f"dlo/{camera}/markers"


def ros_image_keys(image_key: str) -> tuple[str, str]:
    """The ROS 2 image keys beside an image key ``dlo/<camera or pattern>/image``:
    ``.../image_raw`` (``sensor_msgs/msg/Image``) and ``.../image_raw/compressed``
    (``sensor_msgs/msg/CompressedImage``), for the same cameras."""
    prefix = image_key.rsplit("/", 1)[0]
    return f"{prefix}/{RAW_IMAGE_SUFFIX}", f"{prefix}/{COMPRESSED_IMAGE_SUFFIX}"


def make_config(
    path: str | Path | None = None,
    *,
    mode: str | None = None,
    multicast: bool | None = None,
    listen: list[str] | None = None,
    connect: list[str] | None = None,
    gossip: bool | None = None,
) -> zenoh.Config:
    """A zenoh configuration: the JSON5 file at ``path`` (else zenoh's default, a peer),
    with the given settings written over it (None: leave as is).

    ``gossip`` is zenoh's gossip scouting (peers telling each other of further peers); a
    session that connects to explicit endpoints only needs none of it."""
    config = zenoh.Config.from_file(str(path)) if path is not None else zenoh.Config()
    if mode is not None:
        config.insert_json5("mode", json.dumps(mode))
    if multicast is not None:
        config.insert_json5("scouting/multicast/enabled", json.dumps(multicast))
    if listen is not None:
        config.insert_json5("listen/endpoints", json.dumps(listen))
    if connect is not None:
        config.insert_json5("connect/endpoints", json.dumps(connect))
    if gossip is not None:
        config.insert_json5("scouting/gossip/enabled", json.dumps(gossip))
    return config


def service_config(
    path: str | Path | None = None,
    *,
    listen: list[str] | None = None,
    multicast: bool | None = None,
) -> zenoh.Config:
    """The session of ``dlo serve``: the JSON5 file at ``path`` with ``listen`` and
    ``multicast`` written over it when given; without a file, a peer that listens on
    ``listen`` (default :data:`DEFAULT_ZENOH_LISTEN`, loopback only) and scouts nothing
    unless ``multicast`` says so: reaching the network is an explicit choice."""
    if path is not None:
        return make_config(path, listen=listen, multicast=multicast)
    scouting = bool(multicast)
    return make_config(
        mode="peer",
        listen=listen or [DEFAULT_ZENOH_LISTEN],
        connect=[],
        multicast=scouting,
        gossip=scouting,
    )


def describe_config(config: zenoh.Config) -> str:
    """Where a session of ``config`` listens and connects, in a few words for a log line,
    e.g. ``zenoh peer listening on tcp/127.0.0.1:7447, multicast scouting off``."""

    def setting(key: str) -> object:
        return json.loads(config.get_json(key))

    mode = setting("mode") or "peer"
    listen = setting("listen/endpoints")
    if isinstance(listen, dict):  # zenoh's own default: one list per mode
        listen = listen.get(mode, [])
    connect = setting("connect/endpoints")
    if isinstance(connect, dict):
        connect = connect.get(mode, [])
    where = []
    if listen:
        where.append(f"listening on {', '.join(listen)}")
    if connect:
        where.append(f"connecting to {', '.join(connect)}")
    multicast = setting("scouting/multicast/enabled")  # zenoh's default (None): on
    where.append(f"multicast scouting {'off' if multicast is False else 'on'}")
    return f"zenoh {mode} " + ", ".join(where)
