"""Helpers shared by the test modules: free loopback ports, waiting on a condition, and
PNGs made without an image (:func:`blank_png`, decompression bombs among them).

Import as ``from tests.helpers import free_port, wait_until`` (the repository root is on
``sys.path`` through ``tests/conftest.py``).
"""

from __future__ import annotations

import socket
import time
from collections.abc import Callable

from service.bench.bombs import blank_png

__all__ = ["blank_png", "free_port", "free_udp_port", "wait_until"]

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
