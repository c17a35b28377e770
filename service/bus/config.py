"""Where things travel on zenoh (the key expressions of the detection service) and
:func:`make_config`, the session configuration the service, the router and clients share.

Imports zenoh only: ``dlo router`` needs no detector.
"""

from __future__ import annotations

import json
from pathlib import Path

import zenoh

IMAGE_KEYS = "dlo/*/image"
"""Where cameras publish their frames; ``*`` is the camera's name."""
QUERY_KEY = "dlo/detect"
"""The queryable: ``get`` with the image as payload."""
JSON = "application/json"


def chains_key(camera: str) -> str:
    """Where the Detections of ``camera``'s frames are published."""
    return f"dlo/{camera}/chains"


def errors_key(camera: str) -> str:
    """Where the error records of ``camera``'s unprocessable frames are published."""
    return f"dlo/{camera}/errors"


def make_config(
    path: str | Path | None = None,
    *,
    mode: str | None = None,
    multicast: bool | None = None,
    listen: list[str] | None = None,
    connect: list[str] | None = None,
) -> zenoh.Config:
    """A zenoh configuration: the JSON5 file at ``path`` (else zenoh's default, a peer),
    with the given settings written over it (None: leave as is)."""
    config = zenoh.Config.from_file(str(path)) if path is not None else zenoh.Config()
    if mode is not None:
        config.insert_json5("mode", json.dumps(mode))
    if multicast is not None:
        config.insert_json5("scouting/multicast/enabled", json.dumps(multicast))
    if listen is not None:
        config.insert_json5("listen/endpoints", json.dumps(listen))
    if connect is not None:
        config.insert_json5("connect/endpoints", json.dumps(connect))
    return config
