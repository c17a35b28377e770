"""Hexarotor adapter over MAVLink 2 (pymavlink): connect, guided mode, arm, stream setpoints, grasp.

The frames (local NED, robot cell ENU, body FRD) and the approach plan are pure and live
in :mod:`adapters.hexarotor.approach`; this module is the link.

Safety rules
------------
* Nothing is sent without a heartbeat from the vehicle in the last
  :attr:`LinkConfig.link_loss_s` seconds (2 s): commands raise :class:`LinkLostError`,
  the setpoint stream pauses.
* Every ``COMMAND_LONG`` waits for its ``COMMAND_ACK``; anything but ``MAV_RESULT_ACCEPTED``
  raises :class:`CommandRejectedError`, silence raises :class:`CommandTimeoutError`.
* Every setpoint and every point of an approach is checked against the :class:`Geofence`
  before anything is sent; a refusal raises :class:`~adapters.errors.UnsafeTargetError`.
* Streamed setpoints move towards their goal at no more than the requested speed, itself
  capped at :data:`MAX_SPEED_M_S`.
* A lost link, a mode change away from GUIDED / OFFBOARD, disarming or a timeout during an
  approach freezes the setpoint and returns a failed :class:`ApproachReport`; the vehicle
  holds (the autopilot holds at its last setpoint, or brakes when setpoints stop).
"""

from __future__ import annotations

import contextlib
import math
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from adapters.errors import UnsafeTargetError
from adapters.hexarotor.approach import (
    MAX_SPEED_M_S,
    ApproachConfig,
    ApproachPlan,
    Geofence,
    check_plan,
    end_effector_ned,
    finite3,
    plan_approach,
    require_positive,
)
from adapters.hexarotor.clock import Clock, PeriodicTask, WallClock
from adapters.hexarotor.protocol import (
    ARDUPILOT_MODES,
    POSITION_YAW_TYPE_MASK,
    PX4_MAIN_OFFBOARD,
    mavlink,
    mavutil,
    px4_main_mode,
)

MIN_SETPOINT_RATE_HZ = 10.0
"""Below this, ArduPilot and PX4 treat the stream as lost."""


class MavlinkError(RuntimeError):
    """Base class of the link's failures."""


class LinkTimeoutError(MavlinkError):
    """No heartbeat from a vehicle arrived in time."""


class LinkLostError(MavlinkError):
    """The vehicle's heartbeat is older than the link-loss limit; nothing was sent."""


class CommandRejectedError(MavlinkError):
    """A command was answered with something other than ``MAV_RESULT_ACCEPTED``."""


class CommandTimeoutError(MavlinkError):
    """A command got no ``COMMAND_ACK`` after all retries."""


class VehicleNotReadyError(MavlinkError):
    """The vehicle is not armed in its guided mode, or sent no position yet."""


@dataclass(frozen=True)
class LinkConfig:
    """Timing of the MAVLink link."""

    heartbeat_timeout_s: float = 10.0
    """How long :meth:`MavlinkVehicle.connect` waits for the vehicle's first heartbeat."""
    link_loss_s: float = 2.0
    """A vehicle heartbeat older than this means the link is lost."""
    setpoint_rate_hz: float = 20.0
    command_timeout_s: float = 1.5
    """Wait for each ``COMMAND_ACK``; the command is resent up to ``command_attempts`` times."""
    command_attempts: int = 3
    offboard_warmup_s: float = 0.25
    """PX4: how long setpoints stream before OFFBOARD is requested. PX4 accepts OFFBOARD
    once a stream (> 2 Hz) is present (PX4 user guide, "Offboard Mode"); a few setpoints
    at the stream's 20 Hz make it so."""
    takeoff_timeout_s: float = 20.0
    """How long a take-off or a landing may take before it counts as failed."""
    mode_timeout_s: float = 5.0
    """After an accepted mode or arming command, wait this long to see it in the heartbeat."""

    def __post_init__(self) -> None:
        if not self.setpoint_rate_hz >= MIN_SETPOINT_RATE_HZ:
            raise ValueError(
                f"setpoint_rate_hz must be >= {MIN_SETPOINT_RATE_HZ}, got {self.setpoint_rate_hz}"
            )
        require_positive(
            self,
            (
                "heartbeat_timeout_s",
                "link_loss_s",
                "command_timeout_s",
                "offboard_warmup_s",
                "takeoff_timeout_s",
                "mode_timeout_s",
            ),
        )
        if self.command_attempts < 1:
            raise ValueError(f"command_attempts must be >= 1, got {self.command_attempts}")


@dataclass(frozen=True)
class VehicleState:
    """The latest telemetry: position and velocity in NED, attitude, and when it arrived."""

    position_ned: np.ndarray
    velocity_ned: np.ndarray
    roll: float
    pitch: float
    yaw: float
    received_at: float
    """Time, on the adapter's clock, of the newer of the two messages."""


@dataclass(frozen=True)
class ApproachReport:
    """The outcome of :meth:`MavlinkVehicle.approach`."""

    ok: bool
    """The gripper closed on target."""
    error_m: float | None
    """Measured end-effector error when the gripper closed (None when it did not)."""
    reason: str
    """``"closed"``, ``"link lost"``, ``"left guided mode"`` or ``"timeout"``."""
    duration_s: float


@dataclass
class _Setpoint:
    goal: np.ndarray
    commanded: np.ndarray
    yaw: float
    speed: float


@dataclass
class _Inbox:
    heartbeat_at: float = -math.inf
    autopilot: int | None = None
    custom_mode: int | None = None
    base_mode: int = 0
    system: int = 0
    component: int = 0
    position: np.ndarray | None = None
    velocity: np.ndarray | None = None
    position_at: float = -math.inf
    attitude: tuple[float, float, float] | None = None
    attitude_at: float = -math.inf
    landed_state: int | None = None
    acks: list[tuple[int, int]] = field(default_factory=list)


class MavlinkVehicle:
    """A hexarotor reached over MAVLink 2 (see the module docstring for the rules).

    Parameters
    ----------
    url
        pymavlink connection string: ``udpin:127.0.0.1:14550`` (a vehicle sending to us,
        the usual case), ``udpout:HOST:PORT``, ``tcp:HOST:PORT`` or a serial device
        (``/dev/ttyUSB0``, with ``baud``).
    fence
        Geofence in the local NED frame.
    link
        Link timing.
    baud
        Serial speed (ignored for network URLs).
    source_system, source_component
        Our MAVLink ids (a ground station by default).
    clock
        Where time comes from (:mod:`adapters.hexarotor.clock`): the wall clock by default;
        a :class:`~adapters.hexarotor.clock.LockstepClock` follows a simulator's time.

    Examples
    --------
    >>> with MavlinkVehicle("udpin:127.0.0.1:14550") as vehicle:  # doctest: +SKIP
    ...     vehicle.set_guided_mode()
    ...     vehicle.arm()
    ...     report = vehicle.approach((1.0, 0.5, -1.0), yaw_ned=0.0)
    """

    def __init__(
        self,
        url: str,
        *,
        fence: Geofence | None = None,
        link: LinkConfig | None = None,
        baud: int = 57600,
        source_system: int = 255,
        source_component: int = mavlink.MAV_COMP_ID_MISSIONPLANNER,
        clock: Clock | None = None,
    ) -> None:
        self.url = url
        self.fence = fence or Geofence()
        self.link = link or LinkConfig()
        self._baud = baud
        self._source = (source_system, source_component)
        self._connection: mavutil.mavfile | None = None
        self._send_lock = threading.Lock()
        self._condition = threading.Condition()
        self._inbox = _Inbox()
        self._setpoint: _Setpoint | None = None
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self.clock: Clock = clock or WallClock()
        self._stream_last: float | None = None
        self._started_at = 0.0
        self.stream_cycles = 0
        """Cycles of the setpoint stream so far (each sends one setpoint when one streams
        and the link is up): what a test waits on to know the stream had its chance."""

    # -- lifecycle -------------------------------------------------------------------

    def connect(self) -> MavlinkVehicle:
        """Open the link, wait for the vehicle's heartbeat, start our heartbeat and stream.

        Raises
        ------
        LinkTimeoutError
            No vehicle heartbeat within ``link.heartbeat_timeout_s``.
        """
        if self._connection is not None:
            raise MavlinkError("already connected")
        self._connection = mavutil.mavlink_connection(
            self.url,
            baud=self._baud,
            source_system=self._source[0],
            source_component=self._source[1],
        )
        self._stop.clear()
        self._started_at = self.clock.now()
        self._stream_last = None
        period = 1.0 / self.link.setpoint_rate_hz
        tasks = (
            PeriodicTask("mavlink-heartbeat", 1.0, self._heartbeat_step, immediately=True),
            PeriodicTask("mavlink-setpoints", period, self._stream_step),
        )
        self._threads.extend(self.clock.start(tasks, self._stop))
        receiver = threading.Thread(target=self._receive_loop, name="mavlink-rx", daemon=True)
        receiver.start()
        self._threads.append(receiver)
        if not self._wait_for(
            lambda: self._inbox.autopilot is not None, self.link.heartbeat_timeout_s
        ):
            self.close()
            raise LinkTimeoutError(
                f"no vehicle heartbeat on {self.url} within {self.link.heartbeat_timeout_s} s"
            )
        return self

    def close(self) -> None:
        """Stop the threads and close the link (idempotent). The vehicle keeps holding."""
        self._stop.set()
        self.clock.close()
        for thread in self._threads:
            thread.join(timeout=5.0)
        self._threads.clear()
        if self._connection is not None:
            self._connection.close()
            self._connection = None

    def __enter__(self) -> MavlinkVehicle:
        return self.connect()

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # -- what we know about the vehicle ----------------------------------------------

    @property
    def autopilot(self) -> Literal["ardupilot", "px4", "other"]:
        """The autopilot family the heartbeat announces."""
        kind = self._inbox.autopilot
        if kind == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA:
            return "ardupilot"
        if kind == mavlink.MAV_AUTOPILOT_PX4:
            return "px4"
        return "other"

    def heartbeat_age(self) -> float:
        """Seconds since the vehicle's last heartbeat (``inf`` before the first)."""
        return self.clock.now() - self._inbox.heartbeat_at

    def link_ok(self) -> bool:
        """The vehicle's heartbeat is recent enough to command it."""
        return self.heartbeat_age() <= self.link.link_loss_s

    @property
    def armed(self) -> bool:
        return bool(self._inbox.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)

    @property
    def in_guided_mode(self) -> bool:
        """The heartbeat reports GUIDED (ArduPilot) or OFFBOARD (PX4)."""
        mode = self._inbox.custom_mode
        if mode is None:
            return False
        if self.autopilot == "ardupilot":
            return mode == ARDUPILOT_MODES["GUIDED"]
        if self.autopilot == "px4":
            return px4_main_mode(mode) == PX4_MAIN_OFFBOARD
        return False

    def state(self) -> VehicleState | None:
        """The latest position and attitude, or None before both have arrived."""
        with self._condition:
            inbox = self._inbox
            if inbox.position is None or inbox.attitude is None:
                return None
            return VehicleState(
                position_ned=inbox.position.copy(),
                velocity_ned=inbox.velocity.copy(),
                roll=inbox.attitude[0],
                pitch=inbox.attitude[1],
                yaw=inbox.attitude[2],
                received_at=max(inbox.position_at, inbox.attitude_at),
            )

    def wait_for_state(self, timeout_s: float = 5.0) -> VehicleState:
        """Block until telemetry has arrived; raise :class:`VehicleNotReadyError` otherwise."""
        if not self._wait_for(lambda: self.state() is not None, timeout_s):
            raise VehicleNotReadyError(f"no LOCAL_POSITION_NED and ATTITUDE within {timeout_s} s")
        return self.state()

    # -- commands --------------------------------------------------------------------

    def command(self, command: int, *params: float) -> None:
        """Send ``COMMAND_LONG`` and wait for an accepting ``COMMAND_ACK``.

        Resent (with ``confirmation`` counting up) when no ack arrives in
        ``link.command_timeout_s``; ``MAV_RESULT_IN_PROGRESS`` keeps waiting.

        Raises
        ------
        LinkLostError, CommandRejectedError, CommandTimeoutError
        """
        if len(params) > 7:
            raise ValueError("COMMAND_LONG has 7 parameters")
        padded = [float(p) for p in params] + [0.0] * (7 - len(params))
        name = (
            mavlink.enums["MAV_CMD"][command].name
            if command in mavlink.enums["MAV_CMD"]
            else command
        )
        for confirmation in range(self.link.command_attempts):
            self._require_link()
            with self._condition:
                self._inbox.acks = [ack for ack in self._inbox.acks if ack[0] != command]
            self._send(
                lambda conn, c=confirmation: conn.mav.command_long_send(
                    self._inbox.system, self._inbox.component, command, c, *padded
                )
            )
            deadline = self.clock.now() + self.link.command_timeout_s
            while True:
                result = self._pop_ack(command, deadline)
                if result is None:
                    break  # timed out: resend
                if result == mavlink.MAV_RESULT_IN_PROGRESS:
                    deadline = self.clock.now() + self.link.command_timeout_s
                    continue
                if result != mavlink.MAV_RESULT_ACCEPTED:
                    label = (
                        mavlink.enums["MAV_RESULT"][result].name
                        if result in mavlink.enums["MAV_RESULT"]
                        else str(result)
                    )
                    raise CommandRejectedError(f"{name} was refused: {label}")
                return
        raise CommandTimeoutError(
            f"{name}: no COMMAND_ACK after {self.link.command_attempts} attempts"
        )

    def set_guided_mode(self) -> None:
        """Switch to GUIDED (ArduPilot) or OFFBOARD (PX4) and wait to see it in the heartbeat.

        For PX4, a hold setpoint at the current position streams for
        ``link.offboard_warmup_s`` first, because PX4 refuses OFFBOARD without a stream.
        """
        base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if self.autopilot == "ardupilot":
            self.command(mavlink.MAV_CMD_DO_SET_MODE, base, ARDUPILOT_MODES["GUIDED"])
        elif self.autopilot == "px4":
            self.hold()
            self._sleep_checking_link(self.link.offboard_warmup_s)
            self.command(mavlink.MAV_CMD_DO_SET_MODE, base, PX4_MAIN_OFFBOARD, 0)
        else:
            raise VehicleNotReadyError("unknown autopilot: only ArduPilot and PX4 are supported")
        if not self._wait_for(lambda: self.in_guided_mode, self.link.mode_timeout_s):
            raise VehicleNotReadyError(
                "the mode change was accepted but the heartbeat never showed it"
            )

    def arm(self) -> None:
        """Arm the motors (``MAV_CMD_COMPONENT_ARM_DISARM``) and wait to see it."""
        self.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        if not self._wait_for(lambda: self.armed, self.link.mode_timeout_s):
            raise VehicleNotReadyError("arming was accepted but the heartbeat never showed it")

    @property
    def landed(self) -> bool | None:
        """On the ground, as the vehicle's EXTENDED_SYS_STATE says (None before the first)."""
        state = self._inbox.landed_state
        if state is None or state == mavlink.MAV_LANDED_STATE_UNDEFINED:
            return None
        return state == mavlink.MAV_LANDED_STATE_ON_GROUND

    def take_off(self, height_m: float, speed_m_s: float = 0.5) -> None:
        """Climb to ``height_m`` above the local origin and hold there (armed, guided mode).

        ArduCopter does not leave the ground for position targets in GUIDED: it takes off
        with ``MAV_CMD_NAV_TAKEOFF`` (param7, metres above home; ArduPilot, "Copter Commands
        in Guided Mode"), after which the climb point is its target. PX4 in OFFBOARD flies
        the setpoints it is sent, from the ground too, so the stream climbs (a PX4
        ``NAV_TAKEOFF`` would leave OFFBOARD for AUTO.TAKEOFF). Returns once the measured
        height is within 10 cm of ``height_m``, with the setpoint there.

        Raises
        ------
        UnsafeTargetError
            The climb point is outside the geofence; nothing was sent.
        VehicleNotReadyError
            Not armed in the guided mode, or the climb took longer than
            ``link.takeoff_timeout_s``.
        """
        if not (math.isfinite(height_m) and height_m > 0):
            raise UnsafeTargetError(f"take-off height must be finite and > 0, got {height_m}")
        here = self._measured_position()
        goal = np.array([here[0], here[1], -height_m])
        self.fence.check(goal, "take-off point")
        self._require_link()
        if not (self.armed and self.in_guided_mode):
            raise VehicleNotReadyError("the vehicle must be armed and in its guided mode")
        yaw = self.wait_for_state().yaw
        if self.autopilot == "ardupilot":
            self.command(mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, 0, 0, height_m)
        else:
            self.goto(goal, yaw, speed_m_s)

        def reached() -> bool:
            position = self._inbox.position
            return position is not None and abs(position[2] - goal[2]) <= 0.1

        if not self._wait_for(reached, self.link.takeoff_timeout_s):
            raise VehicleNotReadyError(f"the take-off did not reach {height_m} m in time")
        with self._condition:
            if self.autopilot == "ardupilot":  # it holds the climb point: stream that
                self._setpoint = _Setpoint(goal.copy(), goal.copy(), yaw, speed_m_s)
        if not self._wait_for(self._setpoint_reached, self.link.takeoff_timeout_s):
            raise VehicleNotReadyError("the take-off setpoint was not reached in time")

    def land(self) -> None:
        """Land where the vehicle is (``MAV_CMD_NAV_LAND``) and wait until it is on the ground.

        Both autopilots switch to their landing mode (LAND; AUTO.LAND), descend and disarm
        on their own after touching down; the setpoint stream stops first.

        Raises
        ------
        VehicleNotReadyError
            Not on the ground within ``link.takeoff_timeout_s``.
        """
        with self._condition:
            self._setpoint = None
        self.command(mavlink.MAV_CMD_NAV_LAND, 0, 0, 0, math.nan)

        def down() -> bool:
            if self.landed is not None:
                return bool(self.landed)
            return self._inbox.position is not None and self._inbox.position[2] > -0.05

        if not self._wait_for(down, self.link.takeoff_timeout_s):
            raise VehicleNotReadyError("the vehicle did not land in time")

    def disarm(self) -> None:
        """Disarm the motors."""
        self.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0)

    def set_gripper(self, grab: bool) -> None:
        """Close (``grab``) or open gripper 1 with ``MAV_CMD_DO_GRIPPER``."""
        action = mavlink.GRIPPER_ACTION_GRAB if grab else mavlink.GRIPPER_ACTION_RELEASE
        self.command(mavlink.MAV_CMD_DO_GRIPPER, 1, action)

    # -- setpoints -------------------------------------------------------------------

    def goto(self, position_ned: Sequence[float], yaw_ned: float, speed_m_s: float) -> None:
        """Stream setpoints moving towards ``position_ned`` at ``speed_m_s`` (capped).

        The stream starts from the current setpoint, or from the measured position when
        none is streaming. Raises :class:`UnsafeTargetError` outside the fence (nothing is
        sent) and :class:`LinkLostError` without a recent heartbeat.
        """
        goal = finite3(position_ned, "position_ned")
        if not math.isfinite(yaw_ned):
            raise UnsafeTargetError(f"yaw must be finite, got {yaw_ned}")
        if not (math.isfinite(speed_m_s) and speed_m_s > 0):
            raise UnsafeTargetError(f"speed must be finite and > 0, got {speed_m_s}")
        self.fence.check(goal, "setpoint")
        self._require_link()
        speed = min(speed_m_s, MAX_SPEED_M_S)
        if self.commanded_setpoint() is None:
            start = self._measured_position()
            self.fence.check(start, "current position")
        with self._condition:
            if self._setpoint is None:
                self._setpoint = _Setpoint(goal, start, yaw_ned, speed)
            else:
                self._setpoint = _Setpoint(goal, self._setpoint.commanded, yaw_ned, speed)

    def hold(self) -> None:
        """Freeze the setpoint where it is now (the measured position if none streams)."""
        with self._condition:
            if self._setpoint is not None:
                here = self._setpoint.commanded.copy()
                self._setpoint = _Setpoint(here, here, self._setpoint.yaw, self._setpoint.speed)
                return
        position = self._measured_position()
        self.fence.check(position, "current position")
        yaw = self.wait_for_state().yaw
        with self._condition:
            self._setpoint = _Setpoint(position, position.copy(), yaw, MAX_SPEED_M_S)

    def commanded_setpoint(self) -> tuple[np.ndarray, float] | None:
        """The position and yaw being streamed now, or None."""
        with self._condition:
            if self._setpoint is None:
                return None
            return self._setpoint.commanded.copy(), self._setpoint.yaw

    # -- the grasp approach ----------------------------------------------------------

    def approach(
        self,
        target_ned: Sequence[float],
        yaw_ned: float,
        config: ApproachConfig | None = None,
        *,
        on_phase: Callable[[str], None] | None = None,
    ) -> ApproachReport:
        """Bring the end-effector onto ``target_ned`` as in the paper and close the gripper.

        Holds the standoff (``config.standoff_m`` before the target along the heading
        ``yaw_ned``), moves forward until the measured end-effector error stayed below
        ``config.tolerance_m`` for ``config.dwell_s``, then closes the gripper.

        Raises
        ------
        UnsafeTargetError
            A point of the approach leaves the fence; nothing was sent.
        VehicleNotReadyError
            Not armed in the guided mode, or no telemetry; nothing was sent.
        LinkLostError
            No recent heartbeat at the start; nothing was sent.

        Returns
        -------
        ApproachReport
            ``ok`` with the measured error at closure, or the reason it gave up (link lost,
            the vehicle left the guided mode or was disarmed, timeout); then the setpoint is
            frozen and the vehicle left holding.
        """
        config = config or ApproachConfig()
        plan = plan_approach(target_ned, yaw_ned, config)
        check_plan(plan, self.fence)
        self._require_link()
        if not (self.armed and self.in_guided_mode):
            raise VehicleNotReadyError("the vehicle must be armed and in its guided mode")
        self.wait_for_state()
        started = self.clock.now()
        deadline = started + config.timeout_s

        def report(ok: bool, error: float | None, reason: str) -> ApproachReport:
            if not ok:
                self.hold()
            return ApproachReport(ok, error, reason, self.clock.now() - started)

        def phase(name: str) -> None:
            if on_phase is not None:
                on_phase(name)

        phase("standoff")
        self.goto(plan.standoff_ned, plan.yaw_ned, config.transit_speed_m_s)
        while True:
            outcome = self._watch(deadline)
            if outcome is not None:
                return report(False, None, outcome)
            state = self.state()
            close = (
                np.linalg.norm(state.position_ned - plan.standoff_ned)
                <= config.standoff_tolerance_m
            )
            slow = np.linalg.norm(state.velocity_ned) <= config.settle_speed_m_s
            if close and slow and self._setpoint_reached():
                break

        phase("final")
        self.goto(plan.final_ned, plan.yaw_ned, config.approach_speed_m_s)
        within_since: float | None = None
        while True:
            outcome = self._watch(deadline)
            if outcome is not None:
                return report(False, None, outcome)
            state = self.state()
            error = self._end_effector_error(state, plan, config)
            if error > config.tolerance_m or not self._setpoint_reached():
                within_since = None
                continue
            within_since = within_since if within_since is not None else state.received_at
            if state.received_at - within_since >= config.dwell_s:
                break

        phase("close")
        self._require_link()
        self.set_gripper(True)
        return report(True, error, "closed")

    def _watch(self, deadline: float) -> str | None:
        """Wait for fresh telemetry; a reason to give up, or None to carry on."""
        seen = self._inbox.position_at
        self._wait_for(lambda: self._inbox.position_at > seen, 0.1)
        if not self.link_ok():
            return "link lost"
        if not (self.armed and self.in_guided_mode):
            return "left guided mode"  # a pilot or a failsafe took over: do not fight it
        if self.clock.now() > deadline:
            return "timeout"
        return None

    def _setpoint_reached(self) -> bool:
        with self._condition:
            setpoint = self._setpoint
            return setpoint is not None and bool(np.all(setpoint.commanded == setpoint.goal))

    @staticmethod
    def _end_effector_error(state: VehicleState, plan: ApproachPlan, config: ApproachConfig):
        where = end_effector_ned(
            state.position_ned, state.roll, state.pitch, state.yaw, config.end_effector_frd
        )
        return float(np.linalg.norm(where - plan.target_ned))

    # -- threads ---------------------------------------------------------------------

    def _receive_loop(self) -> None:
        while not self._stop.is_set():
            try:
                message = self._connection.recv_match(blocking=True, timeout=0.1)
            except (OSError, ValueError):  # closed underneath us
                if self._stop.wait(0.05):
                    return
                continue
            if message is None:
                continue
            if message.get_type() == "TIMESYNC" and message.tc1 == 0:
                request = message.ts1
                self.clock.vehicle_step(request / 1e9, lambda ts1=request: self._answer_sync(ts1))
            else:
                self.clock.deliver(lambda message=message: self._dispatch(message))

    def _answer_sync(self, ts1: int) -> None:
        """Answer a TIMESYNC request: our time in ``tc1`` (never 0), theirs back in ``ts1``."""
        ours = time.monotonic_ns() or 1
        self._send_from_thread(lambda conn: conn.mav.timesync_send(ours, ts1))

    def _dispatch(self, message: object) -> None:
        kind = message.get_type()
        now = self.clock.now()
        with self._condition:
            inbox = self._inbox
            if kind == "HEARTBEAT":
                if message.type == mavlink.MAV_TYPE_GCS or (
                    message.autopilot == mavlink.MAV_AUTOPILOT_INVALID
                ):
                    return  # another ground station or a peripheral, not the vehicle
                if inbox.autopilot is None:
                    inbox.system = message.get_srcSystem()
                    inbox.component = message.get_srcComponent()
                if message.get_srcSystem() != inbox.system:
                    return
                inbox.heartbeat_at = now
                inbox.autopilot = message.autopilot
                inbox.custom_mode = message.custom_mode
                inbox.base_mode = message.base_mode
            elif message.get_srcSystem() != inbox.system:
                return
            elif kind == "LOCAL_POSITION_NED":
                inbox.position = np.array([message.x, message.y, message.z])
                inbox.velocity = np.array([message.vx, message.vy, message.vz])
                inbox.position_at = now
            elif kind == "ATTITUDE":
                inbox.attitude = (message.roll, message.pitch, message.yaw)
                inbox.attitude_at = now
            elif kind == "EXTENDED_SYS_STATE":
                inbox.landed_state = message.landed_state
            elif kind == "COMMAND_ACK":
                inbox.acks.append((message.command, message.result))
            else:
                return
            self._condition.notify_all()

    def _heartbeat_step(self, now: float) -> None:
        self._send_from_thread(
            lambda conn: conn.mav.heartbeat_send(
                mavlink.MAV_TYPE_GCS,
                mavlink.MAV_AUTOPILOT_INVALID,
                0,
                0,
                mavlink.MAV_STATE_ACTIVE,
            )
        )

    def _stream_step(self, now: float) -> None:
        """One cycle of the setpoint stream: move the commanded point and send it."""
        self.stream_cycles += 1
        period = 1.0 / self.link.setpoint_rate_hz
        last = self._started_at if self._stream_last is None else self._stream_last
        # A stalled thread must not make the setpoint jump: cap the step at 3 periods.
        elapsed = min(now - last, 3 * period)
        self._stream_last = now
        if not self.link_ok():
            return  # no command without a recent heartbeat; the vehicle holds
        with self._condition:
            setpoint = self._setpoint
            if setpoint is None:
                return
            offset = setpoint.goal - setpoint.commanded
            distance = float(np.linalg.norm(offset))
            step = setpoint.speed * elapsed
            if distance <= step:
                setpoint.commanded = setpoint.goal.copy()
            else:
                setpoint.commanded = setpoint.commanded + offset * (step / distance)
            x, y, z = setpoint.commanded
            yaw = setpoint.yaw
        boot_ms = int((now - self._started_at) * 1000) & 0xFFFFFFFF
        self._send_from_thread(
            lambda conn: conn.mav.set_position_target_local_ned_send(
                boot_ms,
                self._inbox.system,
                self._inbox.component,
                mavlink.MAV_FRAME_LOCAL_NED,
                POSITION_YAW_TYPE_MASK,
                x,
                y,
                z,
                0.0,
                0.0,
                0.0,
                0.0,
                0.0,
                0.0,
                yaw,
                0.0,
            )
        )

    # -- helpers ---------------------------------------------------------------------

    def _send(self, write: Callable[[mavutil.mavfile], None]) -> None:
        with self._send_lock:
            if self._connection is None:
                raise MavlinkError("not connected")
            write(self._connection)

    def _send_from_thread(self, write: Callable[[mavutil.mavfile], None]) -> None:
        """Send from a background loop: a failed write must not end the loop, and a link
        that stays broken shows up as a stale heartbeat, which stops everything else."""
        with contextlib.suppress(OSError, MavlinkError):
            self._send(write)

    def _require_link(self) -> None:
        if self._connection is None:
            raise MavlinkError("not connected")
        if not self.link_ok():
            raise LinkLostError(
                f"no vehicle heartbeat for {self.heartbeat_age():.1f} s "
                f"(limit {self.link.link_loss_s} s); nothing sent"
            )

    def _measured_position(self) -> np.ndarray:
        return self.wait_for_state().position_ned

    def _wait_for(self, predicate: Callable[[], bool], timeout_s: float) -> bool:
        """Wait on the clock until ``predicate()`` (evaluated under the lock) holds."""
        return self.clock.wait_for(self._condition, predicate, timeout_s)

    def _pop_ack(self, command: int, deadline: float) -> int | None:
        results: list[int] = []

        def arrived() -> bool:
            for index, (acked, result) in enumerate(self._inbox.acks):
                if acked == command:
                    del self._inbox.acks[index]
                    results.append(result)
                    return True
            return False

        if self._wait_for(arrived, deadline - self.clock.now()):
            return results[0]
        return None

    def _sleep_checking_link(self, seconds: float) -> None:
        """Let ``seconds`` pass on the clock; raise :class:`LinkLostError` if the link drops."""
        self._wait_for(lambda: self._stop.is_set() or not self.link_ok(), seconds)
        self._require_link()
