"""``python -m adapters.ur3.fake_controller``: start the fake and serve until told to stop."""

from __future__ import annotations

import argparse
import math
import os
import signal
import sys
import threading

from adapters.ur3.fake_controller.controller import (
    DEFAULT_CONTROL_PORT,
    DROP_SCOPES,
    FakeController,
    Trigger,
)


def _shut_down_when_orphaned(controller: FakeController) -> None:
    """Shut down once the parent is gone (re-parented), so a crashed test run that
    could not tear its fixtures down leaves no fake listening behind."""
    parent = os.getppid()
    while not controller.shutdown_requested.wait(0.5):
        if os.getppid() != parent:
            controller.shutdown_requested.set()


def main(argv: list[str] | None = None) -> int:
    """Command line: start the fake and serve until SIGTERM or a ``shutdown`` request.

    Control channel operations (JSON lines on ``--control-port``): ``state``,
    ``protective_stop``, ``emergency_stop``, ``release``, ``stop_program``,
    ``drop`` (``reconnect``: bool, ``scope``: ``"all"``/``"rtde"``), ``restore``, ``arm``
    (``event``, ``after_commands``, ``reconnect``, ``scope``), ``set`` (``fields``: ``tcp_pose``,
    ``safety_min_z_m``, ``safety_max_reach_m``, ``refuse_programs``), ``shutdown``.
    """
    parser = argparse.ArgumentParser(prog="python -m adapters.ur3.fake_controller")
    parser.add_argument("--host", default="127.0.0.2", help="loopback address to listen on")
    parser.add_argument("--control-port", type=int, default=DEFAULT_CONTROL_PORT)
    parser.add_argument(
        "--time-scale", type=float, default=1.0, help="wall seconds per simulated second"
    )
    parser.add_argument("--protective-stop", action="store_true", help="start protective stopped")
    parser.add_argument("--estop", action="store_true", help="start emergency stopped")
    parser.add_argument(
        "--refuse-programs", action="store_true", help="never run an uploaded program"
    )
    parser.add_argument(
        "--drop-after",
        type=int,
        metavar="N",
        help="drop every connection when the (N+1)th actuating command arrives",
    )
    parser.add_argument(
        "--no-reconnect", action="store_true", help="after a drop, refuse new connections"
    )
    parser.add_argument(
        "--drop-scope", choices=DROP_SCOPES, default="all", help="which connections drop"
    )
    parser.add_argument("--safety-min-z", type=float, default=-math.inf, metavar="METRES")
    parser.add_argument("--safety-max-reach", type=float, default=0.5, metavar="METRES")
    parser.add_argument(
        "--exit-with-parent",
        action="store_true",
        help="shut down when the process that started this one exits (for test fixtures)",
    )
    parser.add_argument("--verbose", action="store_true")
    args = parser.parse_args(argv)

    controller = FakeController(
        args.host,
        control_port=args.control_port,
        time_scale=args.time_scale,
        safety_max_reach_m=args.safety_max_reach,
        safety_min_z_m=args.safety_min_z,
        verbose=args.verbose,
    )
    controller.state.protective_stopped = args.protective_stop
    controller.state.emergency_stopped = args.estop
    controller.refuse_programs = args.refuse_programs
    if args.drop_after is not None:
        controller.triggers.append(
            Trigger("drop", args.drop_after, not args.no_reconnect, args.drop_scope)
        )
    signal.signal(signal.SIGTERM, lambda *_: controller.shutdown_requested.set())
    signal.signal(signal.SIGINT, lambda *_: controller.shutdown_requested.set())
    if args.exit_with_parent:
        threading.Thread(target=_shut_down_when_orphaned, args=(controller,), daemon=True).start()
    controller.run()
    return 0


if __name__ == "__main__":
    sys.exit(main())
