"""In-process fakes of ur_rtde's control, receive and IO interfaces, for tests and dry runs.

:class:`FakeRobot` holds the simulated robot state and one call log shared by its
three interfaces (``robot.control``, ``robot.receive``, ``robot.io``); pass
``robot.connect`` wherever a ``connect(robot_ip)`` factory is expected.

The fake speaks only the Python method names, not the RTDE network protocol.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

COMMANDS = frozenset({"moveL", "stopL", "setToolDigitalOut", "setStandardDigitalOut"})
"""Methods that send something to the robot; everything else only queries."""
MOTIONS = frozenset({"moveL"})
"""Methods that move the arm."""

SAFETY_NORMAL, SAFETY_PROTECTIVE_STOP, SAFETY_ROBOT_EMERGENCY_STOP = 1, 3, 7


class FakeConnectionLost(RuntimeError):
    """Raised by a fake interface call after the simulated link dropped."""


@dataclass(frozen=True)
class Call:
    """One recorded call: which interface, which method, the arguments."""

    interface: str
    method: str
    args: tuple[Any, ...]


@dataclass
class FakeRobot:
    """Simulated robot state behind the three fake interfaces.

    Attributes
    ----------
    tcp_pose
        The tool pose; a completed ``moveL`` sets it to the commanded pose.
    protective_stopped, emergency_stopped
        Reported by the receive interface (and through ``getSafetyMode``).
    program_running
        What ``isProgramRunning`` reports (the ur_rtde control script).
    within_safety_limits
        ``isPoseWithinSafetyLimits(pose)`` answers this predicate.
    disconnect_after
        After this many commands (:data:`COMMANDS`) have been sent, the link drops:
        the next command and every later call except ``isConnected`` and
        ``reconnect`` fail, and ``isConnected`` reports False. None: never.
    disconnect_raises
        True: calls on a dropped link raise :class:`FakeConnectionLost` (like
        ur_rtde). False: they return quietly (False / None) and only ``isConnected``
        tells; the command that hits the limit is not executed.
    reconnect_succeeds
        What ``reconnect`` does once the link dropped.
    move_fails
        ``moveL`` returns False without moving (the controller refused).
    block_moves_after
        After this many ``moveL`` calls have completed, every later ``moveL`` is logged
        and then blocks until ``release_blocked_moves`` is set, as ur_rtde's synchronous
        ``moveL`` does on a link that died without the client noticing; once released
        it returns False without moving (the command was lost with the link). The link
        stays "connected" meanwhile, so only a deadline can tell. None: never blocks.
    release_blocked_moves
        Set it to let blocked ``moveL`` calls return (tests set it when they finish,
        so no thread stays blocked).
    """

    tcp_pose: list[float] = field(default_factory=lambda: [0.3, 0.0, 0.3, 3.14159, 0.0, 0.0])
    protective_stopped: bool = False
    emergency_stopped: bool = False
    program_running: bool = True
    within_safety_limits: Callable[[Sequence[float]], bool] = lambda pose: True
    disconnect_after: int | None = None
    disconnect_raises: bool = True
    reconnect_succeeds: bool = True
    move_fails: bool = False
    block_moves_after: int | None = None
    release_blocked_moves: threading.Event = field(default_factory=threading.Event)
    connected: bool = True
    calls: list[Call] = field(default_factory=list)
    digital_outputs: dict[tuple[str, int], bool] = field(default_factory=dict)
    commands_sent: int = 0
    moves_completed: int = 0

    def __post_init__(self) -> None:
        self.control = FakeControl(self)
        self.receive = FakeReceive(self)
        self.io = FakeIO(self)
        self.connected_to: list[str] = []

    def connect(self, robot_ip: str) -> tuple[FakeControl, FakeReceive, FakeIO]:
        """A ``connect(robot_ip)`` factory returning the three fake interfaces."""
        self.connected_to.append(robot_ip)
        return self.control, self.receive, self.io

    def methods(self, interface: str | None = None) -> list[str]:
        """The method names called, in order (optionally on one interface only)."""
        return [c.method for c in self.calls if interface is None or c.interface == interface]

    def sent(self) -> list[Call]:
        """The calls that sent something (:data:`COMMANDS`)."""
        return [call for call in self.calls if call.method in COMMANDS]

    def motions(self) -> list[Call]:
        """The calls that move the arm (:data:`MOTIONS`)."""
        return [call for call in self.calls if call.method in MOTIONS]

    def _enter(self, interface: str, method: str, args: tuple[Any, ...]) -> bool:
        """Log a call; return whether it may act (False: the link is down, quietly)."""
        self.calls.append(Call(interface, method, args))
        if method in ("isConnected", "reconnect"):
            return True
        limit = self.disconnect_after
        if self.connected and method in COMMANDS and limit is not None:
            self.connected = self.commands_sent < limit
        if not self.connected:
            if self.disconnect_raises:
                raise FakeConnectionLost(f"{interface}.{method}: RTDE connection lost")
            return False
        if method in COMMANDS:
            self.commands_sent += 1
        return True

    def _reconnect(self, interface: str) -> bool:
        self._enter(interface, "reconnect", ())
        if self.connected:
            return True
        if self.reconnect_succeeds:
            self.connected = True
            self.disconnect_after = None
        return self.connected

    def _safety_mode(self) -> int:
        if self.emergency_stopped:
            return SAFETY_ROBOT_EMERGENCY_STOP
        if self.protective_stopped:
            return SAFETY_PROTECTIVE_STOP
        return SAFETY_NORMAL


class FakeControl:
    """Fake ``rtde_control.RTDEControlInterface``."""

    def __init__(self, robot: FakeRobot) -> None:
        self._robot = robot

    def moveL(
        self,
        pose: Sequence[float],
        speed: float = 0.25,
        acceleration: float = 1.2,
        asynchronous: bool = False,
    ) -> bool:
        robot = self._robot
        if not robot._enter("control", "moveL", (list(pose), speed, acceleration, asynchronous)):
            return False
        if robot.block_moves_after is not None and robot.moves_completed >= robot.block_moves_after:
            robot.release_blocked_moves.wait()
            return False
        if robot.move_fails or robot.protective_stopped or robot.emergency_stopped:
            return False
        robot.tcp_pose = [float(v) for v in pose]
        robot.moves_completed += 1
        return True

    def stopL(self, a: float = 10.0, asynchronous: bool = False) -> None:
        self._robot._enter("control", "stopL", (a, asynchronous))

    def isPoseWithinSafetyLimits(self, pose: Sequence[float]) -> bool:
        if not self._robot._enter("control", "isPoseWithinSafetyLimits", (list(pose),)):
            return False
        return bool(self._robot.within_safety_limits(pose))

    def isProgramRunning(self) -> bool:
        return self._robot._enter("control", "isProgramRunning", ()) and self._robot.program_running

    def getRobotStatus(self) -> int:
        if not self._robot._enter("control", "getRobotStatus", ()):
            return 0
        return 1 | (2 if self._robot.program_running else 0)

    def isConnected(self) -> bool:
        self._robot._enter("control", "isConnected", ())
        return self._robot.connected

    def reconnect(self) -> bool:
        return self._robot._reconnect("control")

    def disconnect(self) -> None:
        self._robot.calls.append(Call("control", "disconnect", ()))


class FakeReceive:
    """Fake ``rtde_receive.RTDEReceiveInterface``."""

    def __init__(self, robot: FakeRobot) -> None:
        self._robot = robot

    def getActualTCPPose(self) -> list[float]:
        if not self._robot._enter("receive", "getActualTCPPose", ()):
            return []
        return list(self._robot.tcp_pose)

    def isProtectiveStopped(self) -> bool:
        return self._robot._enter("receive", "isProtectiveStopped", ()) and (
            self._robot.protective_stopped
        )

    def isEmergencyStopped(self) -> bool:
        return self._robot._enter("receive", "isEmergencyStopped", ()) and (
            self._robot.emergency_stopped
        )

    def getSafetyMode(self) -> int:
        if not self._robot._enter("receive", "getSafetyMode", ()):
            return 0
        return self._robot._safety_mode()

    def isConnected(self) -> bool:
        self._robot._enter("receive", "isConnected", ())
        return self._robot.connected

    def reconnect(self) -> bool:
        return self._robot._reconnect("receive")

    def disconnect(self) -> None:
        self._robot.calls.append(Call("receive", "disconnect", ()))


class FakeIO:
    """Fake ``rtde_io.RTDEIOInterface``."""

    def __init__(self, robot: FakeRobot) -> None:
        self._robot = robot

    def setToolDigitalOut(self, output_id: int, level: bool) -> bool:
        return self._set("tool", "setToolDigitalOut", output_id, level)

    def setStandardDigitalOut(self, output_id: int, level: bool) -> bool:
        return self._set("standard", "setStandardDigitalOut", output_id, level)

    def _set(self, kind: str, method: str, output_id: int, level: bool) -> bool:
        if not self._robot._enter("io", method, (output_id, level)):
            return False
        self._robot.digital_outputs[(kind, output_id)] = bool(level)
        return True

    def isConnected(self) -> bool:
        self._robot._enter("io", "isConnected", ())
        return self._robot.connected

    def reconnect(self) -> bool:
        return self._robot._reconnect("io")

    def disconnect(self) -> None:
        self._robot.calls.append(Call("io", "disconnect", ()))
