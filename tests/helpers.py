"""Helpers shared by the test modules: free loopback ports and waiting on a condition.

Import as ``from tests.helpers import free_port, wait_until`` (the repository root is on
``sys.path`` through ``tests/conftest.py``).
"""

from __future__ import annotations

import socket
import time
from collections.abc import Callable

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


def blank_png(width: int, height: int, bit_depth: int = 1) -> bytes:
    """A valid greyscale PNG of ``width`` x ``height`` zeros, built without decoding anything.

    With the default 1-bit samples a 30000x30000 one is about 110 KB that decodes to
    900 megapixels (a decompression bomb); built in under a second, row blocks at a time.
    """
    import struct
    import zlib

    def chunk(kind: bytes, data: bytes) -> bytes:
        crc = zlib.crc32(kind + data) & 0xFFFFFFFF
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", crc)

    row = b"\0" * (1 + (width * bit_depth + 7) // 8)
    rows_per_block = max(1, 4_000_000 // len(row))
    compressor = zlib.compressobj(9)
    parts = []
    for start in range(0, height, rows_per_block):
        parts.append(compressor.compress(row * min(rows_per_block, height - start)))
    parts.append(compressor.flush())
    header = struct.pack(">IIBBBBB", width, height, bit_depth, 0, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", header)
        + chunk(b"IDAT", b"".join(parts))
        + chunk(b"IEND", b"")
    )
