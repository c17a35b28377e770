"""UR3 pick adapter: grasp a cable at a :class:`~schemas.GraspTarget` with ur_rtde.

Ports and adapters
------------------
The robot is reached through three ports with the method names of ur_rtde's
``RTDEControlInterface``, ``RTDEReceiveInterface`` and ``RTDEIOInterface``. A factory
``connect(robot_ip) -> (control, receive, io)`` makes them; the default,
:func:`connect`, runs the real ur_rtde client in a worker process of its own
(:mod:`adapters.ur3.rtde_worker`) and returns proxies to it, and tests inject
:mod:`adapters.ur3.fakes`.

Planning (:func:`~adapters.grasp.motions.plan_motions`,
:func:`~adapters.grasp.motions.check_workspace`) is pure and lives in
:mod:`adapters.grasp.motions`; :class:`UR3Picker` adds the robot-state pre-checks and sends
the plan.

Safety rules
------------
* Every check runs before anything is sent; a refusal raises and sends nothing.
* Speed and acceleration are clamped to the caps of :mod:`adapters.grasp.motions`.
* After a failure mid-sequence (an exception, a command refused, or a link that
  reports itself disconnected) the picker sends ``stopL``, tries to reconnect once
  and reports the failure. It never resumes the motion.
* Every blocking command (``moveL``, ``stopL``, the gripper output, ``reconnect``) runs
  on a worker thread and the picker waits for it at most a deadline (see
  :func:`motion_deadline_s`). ur_rtde's synchronous ``moveL`` can block forever on a
  link that died (seen with ur_rtde 1.6.5 when the controller refuses new
  connections); a missed deadline is handled as a lost link, and the picker refuses
  every later pick, since the abandoned call is still inside the client.
* ur_rtde 1.6.5 aborts its process when an interface whose socket died is
  disconnected or destroyed, and its background threads, which keep reconnecting,
  were seen to crash a process at exit (SIGSEGV). So the real client runs in a worker
  process: whatever ur_rtde does there, the user's process only sees a call fail.
  After a failure that may have involved a broken link, :meth:`UR3Picker.close` does
  not disconnect the interfaces but ends the worker with SIGKILL
  (:func:`retire_interfaces`): the operating system closes its sockets and no C++
  teardown runs anywhere. Nothing is left behind in the user's process, and a new
  ``open()`` starts a fresh worker.
* A worker that ends on its own (crash, killed) fails every pending and later call at
  once; a pick in progress fails like one on a lost link.
"""

from __future__ import annotations

import contextlib
import ctypes
import math
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any, Protocol

from adapters.errors import UnsafeTargetError
from adapters.grasp.motions import UR3Config, check_workspace, plan_motions
from adapters.ur3.rtde_worker import RTDEWorker
from schemas import GraspTarget, Motion, PickReport, PickStep


class RobotNotReadyError(RuntimeError):
    """The robot cannot move now: disconnected, stopped or no control script running."""


class ControlPort(Protocol):
    """The subset of ``rtde_control.RTDEControlInterface`` the picker uses."""

    def moveL(
        self, pose: list[float], speed: float, acceleration: float, asynchronous: bool = False
    ) -> bool: ...
    def stopL(self, a: float = 10.0, asynchronous: bool = False) -> None: ...
    def isPoseWithinSafetyLimits(self, pose: list[float]) -> bool: ...
    def isProgramRunning(self) -> bool: ...
    def isConnected(self) -> bool: ...
    def reconnect(self) -> bool: ...


class ReceivePort(Protocol):
    """The subset of ``rtde_receive.RTDEReceiveInterface`` the picker uses."""

    def getActualTCPPose(self) -> list[float]: ...
    def isProtectiveStopped(self) -> bool: ...
    def isEmergencyStopped(self) -> bool: ...
    def getSafetyMode(self) -> int: ...
    def isConnected(self) -> bool: ...
    def reconnect(self) -> bool: ...


class IOPort(Protocol):
    """The subset of ``rtde_io.RTDEIOInterface`` the picker uses."""

    def setToolDigitalOut(self, output_id: int, level: bool) -> bool: ...
    def setStandardDigitalOut(self, output_id: int, level: bool) -> bool: ...
    def isConnected(self) -> bool: ...
    def reconnect(self) -> bool: ...


Interfaces = tuple[ControlPort, ReceivePort, IOPort]
ConnectFactory = Callable[[str], Interfaces]


def connect(robot_ip: str) -> Interfaces:
    """Open the three ur_rtde interfaces to the robot at ``robot_ip`` in a worker process.

    One worker process (:class:`~adapters.ur3.rtde_worker.RTDEWorker`) constructs
    ``RTDEControlInterface``, ``RTDEReceiveInterface`` and ``RTDEIOInterface`` and serves
    calls on them; the returned proxies forward each call to it. ur_rtde is imported
    only in the worker, so planning and tests work without it. Constructing
    ``RTDEControlInterface`` uploads ur_rtde's control script, which makes the robot
    controllable remotely.

    The worker is a fresh interpreter running only :mod:`adapters.ur3.rtde_worker`
    (never a fork: this process has threads). It never imports the caller's main
    module, so a plain script that connects at top level works, with or without
    ``if __name__ == "__main__":``, as do ``python -c``, ``python -m`` and the ``dlo``
    command.

    Returns
    -------
    tuple
        ``(control, receive, io)`` proxies; each has ``worker`` (its pid is
        ``worker.pid``). :meth:`UR3Picker.close` ends the worker.

    Raises
    ------
    RuntimeError
        ur_rtde could not connect (its message, one line), as when it ran in this
        process; no worker is left running.
    ConnectionError
        The worker process ended while connecting.
    """
    return RTDEWorker(robot_ip).proxies()


SAFETY_MODES_READY = frozenset({1, 2})
"""``getSafetyMode`` values that allow motion: 1 normal, 2 reduced."""


def trapezoid_duration_s(distance: float, speed: float, acceleration: float) -> float:
    """Time of a rest-to-rest move over ``distance`` with a trapezoidal speed profile.

    It accelerates at ``acceleration`` to ``speed``, cruises, and decelerates alike; a
    move too short to reach ``speed`` (``distance < speed**2 / acceleration``) is a
    triangle, ``2 * sqrt(distance / acceleration)``. Units are any consistent pair,
    metres or radians.
    """
    distance = abs(distance)
    if distance * acceleration >= speed * speed:
        return distance / speed + speed / acceleration
    return 2.0 * math.sqrt(distance / acceleration)


def rotation_angle_between(first: Sequence[float], second: Sequence[float]) -> float:
    """Angle (rad, 0..pi) of the rotation from one rotation vector to another."""
    first_quaternion = _quaternion(first)
    second_quaternion = _quaternion(second)
    dot = abs(sum(a * b for a, b in zip(first_quaternion, second_quaternion, strict=True)))
    return 2.0 * math.acos(min(dot, 1.0))


def _quaternion(rotation_vector: Sequence[float]) -> tuple[float, float, float, float]:
    angle = math.sqrt(sum(v * v for v in rotation_vector))
    if angle == 0.0:
        return 1.0, 0.0, 0.0, 0.0
    scale = math.sin(angle / 2) / angle
    x, y, z = rotation_vector
    return math.cos(angle / 2), x * scale, y * scale, z * scale


def motion_deadline_s(start_pose: Sequence[float], motion: Motion, config: UR3Config) -> float:
    """How long the picker waits for ``motion`` (a moveL) from ``start_pose`` to return.

    ``factor * trapezoid_duration_s(d, v, a) + margin``, where ``d`` is the larger of
    the straight-line distance (m) and the tool's rotation angle (rad): ``moveL``
    takes one speed and acceleration, and when the turn dominates, the controller
    paces it too, so the angle is read with the same numbers (rad/s, rad/s^2). The
    factor covers a loaded controller and the slower ends of the profile; the margin
    covers the command round trip (a few RTDE cycles) and the settling at the goal.

    Parameters
    ----------
    start_pose
        Where the tool is when the move starts, ``[x, y, z, rx, ry, rz]``.
    motion
        The ``moveL``, with its pose, speed and acceleration.
    config
        ``motion_timeout_factor`` and ``motion_timeout_margin_s``.

    Returns
    -------
    float
        The deadline in seconds.
    """
    assert motion.pose is not None and motion.speed_m_s and motion.acceleration_m_s2
    translation = math.dist(start_pose[:3], motion.pose[:3])
    rotation = rotation_angle_between(start_pose[3:6], motion.pose[3:6])
    profile = trapezoid_duration_s(
        max(translation, rotation), motion.speed_m_s, motion.acceleration_m_s2
    )
    return config.motion_timeout_factor * profile + config.motion_timeout_margin_s


class _StepFailed(Exception):
    """Internal: a step failed; the message goes to the report.

    ``call_abandoned``: the step's call missed its deadline and is still inside the
    client, so the link is handled as lost even if ur_rtde reports it connected.
    """

    def __init__(self, message: str, *, call_abandoned: bool = False) -> None:
        super().__init__(message)
        self.call_abandoned = call_abandoned


class _DeadlineMissed(Exception):
    """Internal: a robot call did not return in time; its worker thread was abandoned."""


class _CommandRunner:
    """Runs one blocking ur_rtde call on a worker thread and waits for it until a deadline.

    A proxy of :func:`connect` waits for the worker process on an event, and ur_rtde in
    this process releases the GIL while a call blocks, so the picker's thread keeps
    running and can give up. Every call gets its own daemon thread: a call that missed its
    deadline still occupies its thread (it is blocked inside the client), and the
    ``stopL`` and ``reconnect`` that follow must not queue behind it.

    An abandoned call is left to the client's own timeout, which may never come: its
    thread only ever makes that one call, so it cannot send anything else; its result
    or exception is discarded; being a daemon it never holds up interpreter exit. With
    the worker process, :meth:`UR3Picker.close` ends the worker, which fails the
    abandoned call, so its thread returns. Its name is kept in :attr:`abandoned`, and
    the picker issues no command afterwards except the ``stopL`` and the single
    ``reconnect`` of the failure handling.
    """

    def __init__(self) -> None:
        self.abandoned: list[str] = []

    def call(self, name: str, function: Callable[..., Any], *args: Any, timeout_s: float) -> Any:
        """Return ``function(*args)``, re-raise its exception, or raise :class:`_DeadlineMissed`."""
        finished = threading.Event()
        outcome: dict[str, Any] = {}

        def work() -> None:
            try:
                outcome["value"] = function(*args)
            except BaseException as error:  # handed to the waiting thread, never lost
                outcome["error"] = error
            finally:
                finished.set()

        threading.Thread(target=work, name=f"ur3-{name}", daemon=True).start()
        if not finished.wait(timeout_s):
            self.abandoned.append(name)
            raise _DeadlineMissed(f"{name} did not return within {timeout_s:.2f} s")
        if "error" in outcome:
            raise outcome["error"]
        return outcome.get("value")


class UR3Picker:
    """Picks with a UR3 through the three ur_rtde ports.

    Parameters
    ----------
    robot_ip
        Address given to the ``connect`` factory.
    config
        Heights, speeds, workspace and gripper output.
    connect
        ``connect(robot_ip) -> (control, receive, io)``; by default :func:`connect`, the
        real ur_rtde client in a worker process.
    clock, sleep
        Injectable time source (seconds) and wait, for the step durations and the
        gripper settle time.

    Examples
    --------
    >>> with UR3Picker("192.168.1.10") as picker:  # doctest: +SKIP
    ...     report = picker.pick(target)
    """

    def __init__(
        self,
        robot_ip: str,
        config: UR3Config | None = None,
        *,
        connect: ConnectFactory = connect,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        self.robot_ip = robot_ip
        self.config = config or UR3Config()
        self._connect = connect
        self._clock = clock
        self._sleep = sleep
        self._interfaces: Interfaces | None = None
        self._runner = _CommandRunner()
        self._links_in_doubt = False

    def open(self) -> None:
        """Connect (once); later calls do nothing."""
        if self._interfaces is None:
            self._interfaces = self._connect(self.robot_ip)

    def close(self) -> None:
        """Disconnect the interfaces, or retire them after a failure on a doubtful link.

        Links fine: the ur_rtde worker process (the default ``connect``) is asked to
        disconnect its interfaces and exit, and is joined (killed if it does not exit in
        time); other interfaces (fakes) get ``disconnect()`` when they have it.

        After a pick failure that may have involved a broken link, nothing is
        disconnected: the interfaces go to :func:`retire_interfaces`, which ends the
        worker with SIGKILL. With ur_rtde 1.6.5, ``disconnect()`` or the destructor of
        an interface whose socket died throws from C++ ("write: Broken pipe", "read: End
        of file") and aborts its process; killed, the worker runs no C++ teardown, and
        the operating system closes its sockets. Nothing of the lost link stays in this
        process. A failure counts as possibly involving a link unless every link
        reported itself up, no command missed its deadline, and the robot reported a
        protective or emergency stop that explains the failure. (The IO interface has
        no reader thread and never notices its link dropped, so "every link reported
        up" alone proves nothing.)

        A later :meth:`open` (or pick) connects again, with a fresh worker. The refusal
        after a missed deadline stays: this picker sends nothing more.
        """
        interfaces, self._interfaces = self._interfaces, None
        # The doubt is about the interfaces closed now, not the ones a later open makes.
        links_in_doubt, self._links_in_doubt = self._links_in_doubt, False
        if interfaces is None:
            return
        if links_in_doubt:
            retire_interfaces(interfaces)
            return
        for interface in interfaces:
            if _worker_of(interface) is not None:
                continue  # the worker disconnects all of its interfaces as it exits
            disconnect = getattr(interface, "disconnect", None)
            if disconnect is not None:
                with contextlib.suppress(Exception):  # closing must not hide an error
                    disconnect()
        for worker in _workers_of(interfaces):
            worker.close()

    def __enter__(self) -> UR3Picker:
        self.open()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    @property
    def interfaces(self) -> Interfaces:
        """The connected ``(control, receive, io)``; connects on first use."""
        self.open()
        assert self._interfaces is not None
        return self._interfaces

    def check(self, target: GraspTarget) -> list[Motion]:
        """Run every pre-check and return the plan; sends no command.

        Raises
        ------
        UnsafeTargetError
            A pose outside the workspace, a path through the keep-out cylinder, or a
            pose ur_rtde's ``isPoseWithinSafetyLimits`` rejects.
        RobotNotReadyError
            A link down, an emergency or protective stop, a safety mode other than
            normal or reduced, no control script running, or an earlier command of this
            picker that missed its deadline.
        """
        return self._checked_plan(target)[0]

    def _checked_plan(self, target: GraspTarget) -> tuple[list[Motion], list[float]]:
        """:meth:`check`, also returning the current TCP pose the plan starts from."""
        if self._runner.abandoned:
            raise RobotNotReadyError(
                f"an earlier {self._runner.abandoned[0]} missed its deadline and may still be "
                "blocked inside ur_rtde; this picker sends nothing more (close it and check "
                "the robot before making a new one)"
            )
        motions = plan_motions(target, self.config)
        check_workspace(motions, self.config.workspace)
        try:
            current = self._check_robot(motions)
        except (UnsafeTargetError, RobotNotReadyError):
            raise
        except Exception as error:
            raise RobotNotReadyError(
                f"could not read the robot state: {type(error).__name__}: {error}"
            ) from error
        check_workspace(motions, self.config.workspace, current_position=current[:3])
        return motions, current

    def _check_robot(self, motions: list[Motion]) -> list[float]:
        """The robot-state pre-checks (queries only); returns the current TCP pose."""
        control, receive, io = self.interfaces
        for name, interface in (("control", control), ("receive", receive), ("io", io)):
            if not interface.isConnected():
                raise RobotNotReadyError(f"the RTDE {name} interface is not connected")
        if receive.isEmergencyStopped():
            raise RobotNotReadyError("the robot is emergency stopped")
        if receive.isProtectiveStopped():
            raise RobotNotReadyError("the robot is protective stopped")
        mode = receive.getSafetyMode()
        if mode not in SAFETY_MODES_READY:
            raise RobotNotReadyError(
                f"the robot safety mode is {mode}, not normal (1) or reduced (2)"
            )
        if not control.isProgramRunning():
            raise RobotNotReadyError(
                "the ur_rtde control script is not running on the robot "
                "(is the robot in remote control, and was it stopped from the pendant?)"
            )
        for motion in motions:
            if motion.pose is not None and not control.isPoseWithinSafetyLimits(list(motion.pose)):
                raise UnsafeTargetError(
                    f"{motion.label} pose {[round(v, 4) for v in motion.pose]} is outside the "
                    "robot's safety limits or unreachable (isPoseWithinSafetyLimits)"
                )
        current = list(receive.getActualTCPPose())
        if len(current) != 6:
            raise RobotNotReadyError(f"getActualTCPPose returned {current!r}, not 6 values")
        return current

    def pick(self, target: GraspTarget) -> PickReport:
        """Check, then approach, descend, close the gripper and lift.

        Returns
        -------
        PickReport
            ``ok`` with one step per motion, or ``ok=False`` with the reason, the steps
            sent so far, and whether ``stopL`` was sent and a reconnect worked.

        Raises
        ------
        UnsafeTargetError, RobotNotReadyError
            From :meth:`check`; nothing has been sent.
        """
        motions, start_pose = self._checked_plan(target)
        steps: list[PickStep] = []
        for motion in motions:
            started = self._clock()
            try:
                reached = self._send(motion, start_pose)
            except _StepFailed as failure:
                reason = f"{motion.label}: {failure}"
                steps.append(
                    PickStep(
                        motion=motion,
                        ok=False,
                        duration_s=max(self._clock() - started, 0.0),
                        error=str(failure),
                    )
                )
                return self._abort(target, steps, reason, call_abandoned=failure.call_abandoned)
            if motion.pose is not None:
                start_pose = list(motion.pose)
            steps.append(
                PickStep(
                    motion=motion,
                    ok=True,
                    reached_pose=reached,
                    duration_s=max(self._clock() - started, 0.0),
                )
            )
        return PickReport(ok=True, target=target, steps=steps)

    def _send(self, motion: Motion, start_pose: Sequence[float]) -> tuple | None:
        """Send one motion and return the pose reached; raise :class:`_StepFailed`.

        ``start_pose`` is where the tool should be when the motion starts (the pose
        read before the first move, then each move's goal); it sizes the deadline.
        """
        control, receive, io = self.interfaces
        try:
            self._require_links()
            if motion.kind == "moveL":
                assert motion.pose is not None
                deadline_s = motion_deadline_s(start_pose, motion, self.config)
                done = self._runner.call(
                    "moveL",
                    control.moveL,
                    list(motion.pose),
                    motion.speed_m_s,
                    motion.acceleration_m_s2,
                    False,
                    timeout_s=deadline_s,
                )
                if not done:
                    raise _StepFailed(
                        "moveL was not completed (the controller refused or stopped it)"
                    )
            else:
                gripper = self.config.gripper
                name = "setToolDigitalOut" if gripper.kind == "tool" else "setStandardDigitalOut"
                level = bool(motion.output_value)
                timeout_s = self.config.command_timeout_s
                setter = getattr(io, name)
                if not self._runner.call(name, setter, gripper.index, level, timeout_s=timeout_s):
                    raise _StepFailed(f"setting the {gripper.kind} digital output failed")
                self._sleep(self.config.gripper_settle_s)
            self._require_links()
            pose = receive.getActualTCPPose()
        except _StepFailed:
            raise
        except _DeadlineMissed as missed:
            raise _StepFailed(
                f"{missed} (the deadline for this command); the link is treated as lost",
                call_abandoned=True,
            ) from missed
        except Exception as error:
            raise _StepFailed(f"{type(error).__name__}: {error}") from error
        return tuple(float(v) for v in pose) if pose is not None and len(pose) == 6 else None

    def _require_links(self) -> None:
        for name, interface in zip(("control", "receive", "io"), self.interfaces, strict=True):
            if not interface.isConnected():
                raise _StepFailed(f"the RTDE {name} interface lost its connection")

    def _abort(
        self,
        target: GraspTarget,
        steps: list[PickStep],
        reason: str,
        *,
        call_abandoned: bool = False,
    ) -> PickReport:
        """stopL, then one reconnect attempt, then a failed report; never more motion.

        Each interface that reports itself disconnected gets one ``reconnect`` call, in
        the order control, receive, io, stopping at the first that fails. After a
        command missed its deadline (``call_abandoned``) the control interface counts
        as disconnected whatever it reports. ``stopL`` and each ``reconnect`` have
        their own deadline; a missed one counts as failed. When the first stopL could
        not go out and the reconnect worked, stopL is sent again.
        """
        control = self.interfaces[0]
        stop_sent = self._stop(control)
        attempted, reconnected = False, True
        for interface in self.interfaces:
            if not (call_abandoned and interface is control) and _is_connected(interface):
                continue
            attempted = True
            try:
                reconnected = bool(
                    self._runner.call(
                        "reconnect",
                        interface.reconnect,
                        timeout_s=self.config.reconnect_timeout_s,
                    )
                )
            except Exception:
                reconnected = False
            if not reconnected:
                break  # the robot is unreachable; one attempt is all we make
        if attempted and reconnected and not stop_sent:
            stop_sent = self._stop(control)
        if attempted or call_abandoned or not self._robot_reports_a_stop():
            self._links_in_doubt = True
        return PickReport(
            ok=False,
            reason=reason,
            target=target,
            steps=steps,
            stop_sent=stop_sent,
            reconnect_attempted=attempted,
            reconnected=attempted and reconnected,
        )

    def _robot_reports_a_stop(self) -> bool:
        """Whether the receive link reports a protective or emergency stop (False if unsure)."""
        receive = self.interfaces[1]

        def stopped() -> bool:
            return bool(receive.isProtectiveStopped() or receive.isEmergencyStopped())

        try:
            return bool(
                self._runner.call("stop state", stopped, timeout_s=self.config.command_timeout_s)
            )
        except Exception:
            return False

    def _stop(self, control: ControlPort) -> bool:
        """Send stopL; True when it went out on a link that is still up.

        ur_rtde's ``stopL`` returns nothing and is silently dropped when its control
        script is not running (after a lost link ur_rtde itself stops the script while
        reconnecting), so the script must be running too for the stop to count as sent.
        That is judged from ur_rtde's cached state, which right after its own reconnect
        can be a package out of date: the flag is the client's best knowledge. The
        whole exchange has ``command_timeout_s``; missing it counts as not sent.
        """

        def stop_and_confirm() -> bool:
            control.stopL(self.config.stop_deceleration_m_s2)
            return _is_connected(control) and bool(control.isProgramRunning())

        try:
            return bool(
                self._runner.call(
                    "stopL", stop_and_confirm, timeout_s=self.config.command_timeout_s
                )
            )
        except Exception:
            return False


_RETIRED_INTERFACES: list[Any] = []
"""Interfaces other than worker proxies kept alive by :func:`retire_interfaces` (for
inspection; the extra reference count is what keeps them alive through interpreter
shutdown)."""


def retire_interfaces(interfaces: Sequence[Any]) -> None:
    """Get rid of interfaces whose link may be broken without disconnecting them.

    ur_rtde 1.6.5 aborts its process (``std::terminate``) when an interface whose socket
    died is disconnected or destroyed. Worker proxies (the default ``connect``): their
    worker process is ended with SIGKILL and reaped, so no disconnect or destructor
    runs, the operating system closes the sockets, and ur_rtde's background threads end
    with the worker; nothing stays behind in this process.

    Any other object (ur_rtde interfaces constructed in this process, fakes) gets no
    method call and one extra reference that is never released: it is never destroyed,
    and the operating system closes its sockets at exit. That keeps its background
    threads for the rest of the process, which is why :func:`connect` uses a worker.

    Parameters
    ----------
    interfaces
        The ``(control, receive, io)`` objects; any objects work (fakes too).
    """
    for worker in _workers_of(interfaces):
        worker.kill()
    for interface in interfaces:
        if _worker_of(interface) is None:
            _RETIRED_INTERFACES.append(interface)
            # Deliberate leak: module globals are cleared at shutdown, this count is not.
            ctypes.pythonapi.Py_IncRef(ctypes.py_object(interface))


def _worker_of(interface: Any) -> RTDEWorker | None:
    """The worker process behind a proxy from :func:`connect`; None for other objects."""
    worker = getattr(interface, "worker", None)
    return worker if isinstance(worker, RTDEWorker) else None


def _workers_of(interfaces: Sequence[Any]) -> list[RTDEWorker]:
    """The distinct workers behind ``interfaces``, in order (one per :func:`connect`)."""
    workers: list[RTDEWorker] = []
    for interface in interfaces:
        worker = _worker_of(interface)
        if worker is not None and worker not in workers:
            workers.append(worker)
    return workers


def _is_connected(interface: Any) -> bool:
    try:
        return bool(interface.isConnected())
    except Exception:
        return False
