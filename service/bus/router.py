"""A zenoh router that cameras, services and clients connect to (``dlo router``)."""

from __future__ import annotations

import signal
import threading
from pathlib import Path

import zenoh

from service.bus.config import make_config


class RouterStartError(RuntimeError):
    """The router could not start (a bad endpoint or configuration file); one line."""


def open_router(
    config_file: Path | None = None,
    *,
    listen: list[str] | None = None,
    multicast: bool | None = None,
) -> zenoh.Session:
    """A zenoh session in router mode: ``config_file`` (else zenoh's defaults) with
    ``listen`` and ``multicast`` written over it when given.

    Raises
    ------
    RouterStartError
        zenoh refused the configuration or an endpoint.
    """
    try:
        return zenoh.open(
            make_config(config_file, mode="router", multicast=multicast, listen=listen)
        )
    except Exception as exc:  # zenoh reports bad endpoints and files as ZError
        raise RouterStartError(f"cannot start the zenoh router: {exc}") from None


def run_until_stopped(session: zenoh.Session) -> None:
    """Route until SIGINT or SIGTERM, then close ``session``."""
    stop = threading.Event()
    for number in (signal.SIGINT, signal.SIGTERM):
        signal.signal(number, lambda *_: stop.set())
    try:
        while not stop.wait(0.5):  # a timeout, so that the signal handler gets to run
            pass
    finally:
        session.close()
