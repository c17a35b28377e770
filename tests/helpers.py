"""Helpers shared by the test modules: free loopback ports, waiting on a condition, a
``dlo serve`` process, and PNGs made without an image (:func:`blank_png`, decompression
bombs among them).

Import as ``from tests.helpers import free_port, wait_until`` (the repository root is on
``sys.path`` through ``tests/conftest.py``).
"""

from __future__ import annotations

import contextlib
import json
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

from service.bench.bombs import blank_png

__all__ = [
    "DLO",
    "READY_TIMEOUT_S",
    "accepts_connections",
    "blank_png",
    "dlo_serve",
    "free_port",
    "free_udp_port",
    "python_json",
    "wait_until",
]

DEFAULT_TIMEOUT_S = 15.0
"""Generous for a loaded 2-core machine; a wait ends as soon as its condition holds."""

POLL_S = 0.01

DLO = [sys.executable, "-c", "from service.cli import main; main()"]
"""The ``dlo`` command of this checkout, for child processes."""
READY_TIMEOUT_S = 120.0
"""A first start on a machine compiles the numba kernels before a service is ready."""
ROOT = Path(__file__).resolve().parents[1]


def python_json(code: str, *args: str, env: dict[str, str] | None = None) -> object:
    """Run ``code`` in a fresh Python of this checkout (``args`` as its ``sys.argv[1:]``)
    and return the JSON of the last line it prints; fails the test when it fails."""
    result = subprocess.run(
        [sys.executable, "-c", code, *args],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout.strip().splitlines()[-1])


def free_port(host: str = "127.0.0.1", kind: int = socket.SOCK_STREAM) -> int:
    """A port on ``host`` that nothing was bound to a moment ago (TCP by default)."""
    with socket.socket(socket.AF_INET, kind) as probe:
        probe.bind((host, 0))
        return int(probe.getsockname()[1])


def free_udp_port(host: str = "127.0.0.1") -> int:
    """A UDP port on ``host`` that nothing was bound to a moment ago."""
    return free_port(host, socket.SOCK_DGRAM)


def accepts_connections(port: int, host: str = "127.0.0.1") -> bool:
    """True when a TCP connection to ``host:port`` is accepted (something listens)."""
    with contextlib.suppress(OSError), socket.create_connection((host, port), 1):
        return True
    return False


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


@contextlib.contextmanager
def dlo_serve(
    arguments: list[str], log: Path, environment: dict[str, str] | None = None
) -> Iterator[tuple[subprocess.Popen[bytes], str]]:
    """``dlo serve --port <free> ARGUMENTS``, its output in ``log``, until ``/readyz`` says
    200; yields the process and its base URL, and terminates it on the way out."""
    import httpx

    port = free_port()
    with log.open("wb") as output:
        process = subprocess.Popen(
            [*DLO, "serve", "--port", str(port), *arguments],
            stdout=output,
            stderr=subprocess.STDOUT,
            env=environment,
        )
    base = f"http://127.0.0.1:{port}"

    def ready_or_exited() -> bool:
        if process.poll() is not None:
            return True
        with contextlib.suppress(httpx.TransportError):
            return httpx.get(f"{base}/readyz").status_code == 200
        return False

    try:
        wait_until(ready_or_exited, "dlo serve to become ready", READY_TIMEOUT_S)
        assert process.poll() is None, log.read_text()
        yield process, base
    finally:
        if process.poll() is None:
            process.terminate()
        process.wait(timeout=30)
