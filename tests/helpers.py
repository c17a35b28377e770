"""Helpers shared by the test modules: free loopback ports, waiting on a condition, and a
camera looking straight down at the table.

Import as ``from tests.helpers import free_port, wait_until`` (the repository root is on
``sys.path`` through ``tests/conftest.py``).
"""

from __future__ import annotations

import socket
import time
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from schemas import CameraModel

DEFAULT_TIMEOUT_S = 15.0
"""Generous for a loaded 2-core machine; a wait ends as soon as its condition holds."""

POLL_S = 0.01


def free_port(host: str = "127.0.0.1", kind: int = socket.SOCK_STREAM) -> int:
    """A port on ``host`` that nothing was bound to a moment ago (TCP by default)."""
    with socket.socket(socket.AF_INET, kind) as probe:
        probe.bind((host, 0))
        return int(probe.getsockname()[1])


def free_udp_port(host: str = "127.0.0.1") -> int:
    """A UDP port on ``host`` that nothing was bound to a moment ago."""
    return free_port(host, socket.SOCK_DGRAM)


def wait_until(
    condition: Callable[[], bool],
    what: str = "the condition",
    timeout: float = DEFAULT_TIMEOUT_S,
    action: Callable[[], None] | None = None,
) -> None:
    """Return as soon as ``condition()`` holds; fail the test after ``timeout`` seconds.

    ``action``, when given, runs before each check (e.g. to pump a message loop).
    The poll is the event here: the wait ends on the condition, never on a fixed sleep.
    """
    deadline = time.monotonic() + timeout
    while True:
        if action is not None:
            action()
        if condition():
            return
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout:.0f} s waiting for {what}")
        time.sleep(POLL_S)


def camera_looking_down(
    origin: Sequence[float],
    width: int,
    height: int,
    focal: float,
    principal: tuple[float, float] | None = None,
) -> CameraModel:
    """A pinhole camera at ``origin`` (metres, robot base frame) looking straight down.

    Camera x runs along base +x, camera y along base -y, the optical axis along base -z;
    the table is the plane z = 0. ``principal`` defaults to the image's centre.
    """
    import numpy as np

    from schemas import CameraModel

    cx, cy = (width / 2, height / 2) if principal is None else principal
    transform = np.eye(4)
    transform[:3, :3] = np.diag([1.0, -1.0, -1.0])
    transform[:3, 3] = origin
    return CameraModel(
        fx=focal,
        fy=focal,
        cx=cx,
        cy=cy,
        width=width,
        height=height,
        T_base_camera=transform.tolist(),
        surface={"plane_z": 0.0},
    )
