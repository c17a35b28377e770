"""Fixtures for the adapter tests: a fake UR controller in a subprocess, and a hang guard.

The fake (:mod:`adapters.ur3.fake_controller`) listens on the controller's fixed ports
(30004, 30003, 29999), so every test gets its own loopback address: Linux routes all
of 127.0.0.0/8 to the loopback interface. The address mixes in this process id so two
test sessions on one machine do not collide either.
"""

from __future__ import annotations

import contextlib
import faulthandler
import itertools
import json
import os
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from adapters.ur3.fake_controller.controller import DEFAULT_CONTROL_PORT

REPO_ROOT = Path(__file__).resolve().parents[3]
STARTUP_TIMEOUT_S = 20.0
"""Generous: Python start-up on a loaded 2-core machine can take seconds."""
ADDRESS_ATTEMPTS = 5
HANG_GUARD_S = 120.0
"""A ur_rtde call that blocks while holding the GIL cannot be interrupted from Python;
past this, faulthandler dumps every thread's stack and ends the session instead of
letting CI hang."""

_host_numbers = itertools.count(2)


def _next_host() -> str:
    """A loopback address unused by this session: 127.<pid-derived>.<pid-derived>.<n>."""
    pid = os.getpid()
    number = next(_host_numbers)
    return f"127.{1 + pid % 250}.{(pid // 250) % 250 + 1 + number // 250}.{number % 250 + 2}"


class FakeControllerProcess:
    """A running fake controller and its JSON control channel.

    Attributes
    ----------
    host
        The loopback address the fake serves; give it to ``UR3Picker``.
    """

    def __init__(self, host: str, process: subprocess.Popen, stderr_path: Path) -> None:
        self.host = host
        self.process = process
        self.stderr_path = stderr_path

    def request(self, op: str, **fields: Any) -> dict[str, Any]:
        """Send one control request and return the reply; raise if the fake refused it."""
        with socket.create_connection((self.host, DEFAULT_CONTROL_PORT), timeout=10) as sock:
            stream = sock.makefile("rwb")
            stream.write(json.dumps({"op": op, **fields}).encode() + b"\n")
            stream.flush()
            reply = json.loads(stream.readline())
        if not reply.get("ok"):
            raise RuntimeError(f"fake controller refused {op}: {reply.get('error')}")
        return reply

    def state(self) -> dict[str, Any]:
        """The simulated robot state and the log of everything received."""
        return self.request("state")

    def commands(self, *names: str) -> list[dict[str, Any]]:
        """The logged commands, optionally only those named ``names``."""
        log = self.state()["log"]
        return [entry for entry in log if not names or entry["command"] in names]

    def stderr(self) -> str:
        return self.stderr_path.read_text(errors="replace")

    def stop(self) -> None:
        """Ask for a clean shutdown; kill the process if it does not exit."""
        if self.process.poll() is None:
            with contextlib.suppress(OSError, RuntimeError, ValueError):
                self.request("shutdown")
            try:
                self.process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(timeout=10)


def start_fake_controller(tmp_path: Path, *arguments: str) -> FakeControllerProcess:
    """Start ``python -m adapters.ur3.fake_controller`` and wait until it answers.

    Retries on a fresh address when the chosen one is taken.
    """
    for _attempt in range(ADDRESS_ATTEMPTS):
        host = _next_host()
        stderr_path = tmp_path / f"fake_ur_{host}.log"
        with stderr_path.open("wb") as stderr:
            process = subprocess.Popen(
                [
                    sys.executable,
                    "-m",
                    "adapters.ur3.fake_controller",
                    "--host",
                    host,
                    "--exit-with-parent",
                    *arguments,
                ],
                cwd=REPO_ROOT,
                stdout=subprocess.DEVNULL,
                stderr=stderr,
            )
        fake = FakeControllerProcess(host, process, stderr_path)
        deadline = time.monotonic() + STARTUP_TIMEOUT_S
        while time.monotonic() < deadline and process.poll() is None:
            try:
                fake.state()
                return fake
            except OSError:
                time.sleep(0.05)
        fake.stop()
        if "Address already in use" not in fake.stderr():
            raise RuntimeError(f"the fake UR controller did not start:\n{fake.stderr()}")
    raise RuntimeError(f"no free loopback address after {ADDRESS_ATTEMPTS} attempts")


@pytest.fixture
def fake_ur(tmp_path: Path, request: pytest.FixtureRequest) -> Iterator[FakeControllerProcess]:
    """A fake UR controller on its own loopback address, moves at 10x speed.

    Extra command line arguments come from ``@pytest.mark.fake_ur_args(...)``.
    """
    marker = request.node.get_closest_marker("fake_ur_args")
    extra = marker.args if marker else ()
    fake = start_fake_controller(tmp_path, "--time-scale", "0.1", *extra)
    try:
        yield fake
    finally:
        fake.stop()


@pytest.fixture
def hang_guard() -> Iterator[None]:
    """End the session with a stack dump if the test blocks past :data:`HANG_GUARD_S`."""
    faulthandler.dump_traceback_later(HANG_GUARD_S, exit=True)
    try:
        yield
    finally:
        faulthandler.cancel_dump_traceback_later()


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers", "fake_ur_args(*args): extra command line arguments for the fake_ur fixture"
    )
