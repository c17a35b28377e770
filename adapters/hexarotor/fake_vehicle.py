"""A SITL-free fake hexarotor that speaks MAVLink 2 over UDP, as PX4 or ArduCopter do.

It imitates what a ground station (MAVSDK, QGroundControl, :mod:`adapters.hexarotor.driver`)
sees of PX4 or ArduCopter, following their documentation; each behaviour and its source
is listed in :mod:`adapters.hexarotor.fake_autopilot`, and docs/HEXAROTOR.md sums them up.

Toward the ground station:

* ``HEARTBEAT`` at 1 Hz (``MAV_TYPE_HEXAROTOR``, the flavour's ``MAV_AUTOPILOT`` and
  ``custom_mode``); ``SYS_STATUS`` (sensors present, enabled and healthy, pre-arm checks
  passed, the battery), ``BATTERY_STATUS`` (a simple discharge model), and
  ``EXTENDED_SYS_STATE`` (landed state) at 2 Hz; ``LOCAL_POSITION_NED`` and ``ATTITUDE``
  at ``telemetry_hz`` (40 Hz); ``GLOBAL_POSITION_INT`` at 10 Hz from a configurable home;
  ``HOME_POSITION`` at 0.5 Hz, when asked (``MAV_CMD_REQUEST_MESSAGE``) and when home is
  set at arming.
* ``COMMAND_LONG`` and ``COMMAND_INT``, each answered with ``COMMAND_ACK`` as the real one
  answers: ``MAV_CMD_DO_SET_MODE``, ``MAV_CMD_COMPONENT_ARM_DISARM``,
  ``MAV_CMD_NAV_TAKEOFF``, ``MAV_CMD_NAV_LAND``, ``MAV_CMD_NAV_RETURN_TO_LAUNCH``,
  ``MAV_CMD_DO_GRIPPER``, ``MAV_CMD_SET_MESSAGE_INTERVAL``, ``MAV_CMD_REQUEST_MESSAGE``;
  anything else ``MAV_RESULT_UNSUPPORTED``.
* ``SET_POSITION_TARGET_LOCAL_NED`` with ``type_mask`` 0x09F8 (position and yaw) in
  ``MAV_FRAME_LOCAL_NED``, followed in GUIDED / OFFBOARD; any other mask or frame is
  ignored and counted in :attr:`FakeVehicle.rejected_setpoints`.
* ``TIMESYNC`` requests, in lockstep (below).

Dynamics (:mod:`adapters.hexarotor.fake_dynamics`; a fully-actuated vehicle, so it stays
level): a cascaded position loop with bounded speed and acceleration, Ornstein-Uhlenbeck
gusts, white noise on the reported position and attitude, the ground at ``z = 0``.
Disarmed it does not move (started above the ground, it hangs there: a test convenience,
as if it had flown there).

Time: by default the simulation follows the wall clock, so two runs with the same seed are
statistically alike, not bit for bit. With ``lockstep=True`` it runs on a simulated clock,
one telemetry period per step, each step answered by the ground station over the link
(:meth:`FakeVehicle._run_lockstep`): faster than real time, and the same seed and the same
ground station give the same flight on every run.

Run it as a process with ``dlo hexa fake-vehicle --url udpout:127.0.0.1:14550`` or
``python -m adapters.hexarotor.fake_vehicle --url udpout:127.0.0.1:14550``.
"""

from __future__ import annotations

import argparse
import math
import threading
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from adapters.hexarotor.fake_autopilot import (
    PREFLIGHT_DISARM_S,
    STREAM_FRESH_S,
    Autopilot,
    Behaviour,
    rules_for,
)
from adapters.hexarotor.fake_dynamics import (
    PHYSICS_STEP_S,
    Battery,
    Disturbance,
    Dynamics,
    RigidState,
    step_dynamics,
    wrap_angle,
    yaw_matrix,
)
from adapters.hexarotor.protocol import POSITION_YAW_TYPE_MASK, mavlink, mavutil

SYNC_RESEND_S = 0.5
"""Lockstep: wall-clock seconds before an unanswered TIMESYNC request is sent again."""

STATUS_PERIOD_S = 0.5
"""SYS_STATUS, BATTERY_STATUS and EXTENDED_SYS_STATE go out this often."""
GLOBAL_POSITION_PERIOD_S = 0.1
HOME_PERIOD_S = 2.0
"""HOME_POSITION goes out this often (PX4 streams it at 0.5 Hz), on request and on arming."""
EARTH_RADIUS_M = 6_378_137.0
DEFAULT_HOME = (47.397742, 8.545594, 488.0)
"""Latitude, longitude (deg) and altitude AMSL (m) of home: PX4 SITL's default location."""

ON_GROUND_M = 0.02
"""Within this height of the ground (and barely moving vertically) counts as landed."""
TAKEOFF_REACHED_M = 0.1
TAKEOFF_ALTITUDE_M = 2.5
"""A NAV_TAKEOFF without an altitude climbs this high (PX4's ``MIS_TAKEOFF_ALT``)."""

SENSORS = (
    mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO
    | mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG
    | mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    | mavlink.MAV_SYS_STATUS_SENSOR_GPS
    | mavlink.MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL
    | mavlink.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
    | mavlink.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
    | mavlink.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
    | mavlink.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
    | mavlink.MAV_SYS_STATUS_SENSOR_BATTERY
)
"""What SYS_STATUS reports present, enabled and healthy (the simulated sensors are)."""

# Messages a ground station may ask for (MAV_CMD_REQUEST_MESSAGE) or set the rate of.
REQUESTABLE = {
    mavlink.MAVLINK_MSG_ID_HEARTBEAT,
    mavlink.MAVLINK_MSG_ID_SYS_STATUS,
    mavlink.MAVLINK_MSG_ID_BATTERY_STATUS,
    mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE,
    mavlink.MAVLINK_MSG_ID_HOME_POSITION,
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
    mavlink.MAVLINK_MSG_ID_ATTITUDE,
    mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION,
}


@dataclass(frozen=True)
class GripperEvent:
    """A gripper command the fake received, with the ground truth at that instant."""

    grab: bool
    time_s: float
    position_ned: tuple[float, float, float]
    yaw_rad: float
    end_effector_ned: tuple[float, float, float]


class FakeVehicle:
    """A simulated MAVLink hexarotor on its own thread (see the module docstring).

    Parameters
    ----------
    url
        pymavlink connection string, normally ``udpout:127.0.0.1:PORT`` (the ground
        station listens with ``udpin:``).
    autopilot
        ``"ardupilot"`` or ``"px4"``: heartbeat, modes, commands and their answers.
    seed
        Seed of the gust and noise streams.
    disturbance, dynamics
        Gusts and noise; controller gains and limits.
    start_ned
        Initial position in the local NED frame, m (``z = 0``: on the ground).
    end_effector_frd
        Where the gripper sits in the body frame (forward, right, down), m; only used to
        record the ground truth of :attr:`gripper_events`.
    home
        Latitude, longitude (deg) and altitude AMSL (m) of the local origin.
    rtl_altitude_m
        Lowest height of a return to launch.
    system_id
        MAVLink system id of the vehicle.
    lockstep
        Step the simulation in lockstep with the ground station instead of following the
        wall clock (see :meth:`_run_lockstep`).
    """

    def __init__(
        self,
        url: str,
        *,
        autopilot: Autopilot = "ardupilot",
        seed: int = 0,
        disturbance: Disturbance | None = None,
        dynamics: Dynamics | None = None,
        start_ned: tuple[float, float, float] = (0.0, 0.0, 0.0),
        end_effector_frd: tuple[float, float, float] = (0.0, 0.0, 0.0),
        home: tuple[float, float, float] = DEFAULT_HOME,
        rtl_altitude_m: float = 2.0,
        system_id: int = 1,
        lockstep: bool = False,
    ) -> None:
        self.rules = rules_for(autopilot)
        self.url = url
        self.autopilot: Autopilot = self.rules.name
        self.disturbance = disturbance or Disturbance()
        self.dynamics = dynamics or Dynamics()
        self.end_effector_frd = np.asarray(end_effector_frd, dtype=float)
        self.home = tuple(float(v) for v in home)
        self._origin_lla = self.home
        """Latitude, longitude and altitude of the local NED origin."""
        self._home_due = False
        self.rtl_altitude_m = rtl_altitude_m
        self.system_id = system_id
        self.lockstep = lockstep
        gust_seed, noise_seed = np.random.SeedSequence(seed).spawn(2)
        self._gust_rng = np.random.default_rng(gust_seed)
        self._noise_rng = np.random.default_rng(noise_seed)
        self._state = RigidState(position=np.asarray(start_ned, dtype=float).copy())
        self.battery = Battery()
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._connection: mavutil.mavfile | None = None
        self._link_up = True
        self.heartbeats_enabled = True
        """False silences the heartbeat only (telemetry and commands still flow)."""
        self._heartbeat_due = False
        self._started_at = time.monotonic()
        self._step = 0
        self._awaiting_sync: int | None = None
        self._intervals: dict[int, float] = {}
        self._next_status = 0.0
        self._next_global = 0.0
        self._next_home = 0.0

        self.armed = False
        self.custom_mode = self.rules.initial_mode()
        self.setpoint: tuple[np.ndarray, float] | None = None
        self.setpoints_received = 0
        self.rejected_setpoints = 0
        self.commands_received: list[int] = []
        self.acks_sent: list[tuple[int, int]] = []
        """``(command, result)`` of every COMMAND_ACK sent, in order."""
        self.gripper_events: list[GripperEvent] = []
        self.gcs_heartbeats = 0
        self.telemetry_cycles = 0
        """Telemetry periods so far, counted whether or not the link is up."""
        self.simulated_s = 0.0
        """Seconds of motion simulated so far."""
        self.sync_answers = 0
        """Lockstep: steps the ground station has answered."""
        self._last_setpoint_at = -math.inf
        self._hold_point = self._state.position.copy()
        self._hold_yaw = 0.0
        self._takeoff_height: float | None = None
        self._flying = self._state.position[2] < -ON_GROUND_M
        """ArduCopter's "taken off" (auto-armed): set by a takeoff, or by starting aloft."""
        self._armed_on_ground_since: float | None = None
        self._landed_since: float | None = None

    # -- lifecycle -------------------------------------------------------------------

    def start(self) -> FakeVehicle:
        """Open the link and start simulating on a daemon thread; returns ``self``."""
        if self._thread is not None:
            raise RuntimeError("the fake vehicle is already running")
        self._connection = mavutil.mavlink_connection(
            self.url, source_system=self.system_id, source_component=1
        )
        self._started_at = time.monotonic()
        self._thread = threading.Thread(target=self._run, name="fake-vehicle", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop the simulation thread and close the link (idempotent)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        if self._connection is not None:
            self._connection.close()
            self._connection = None

    def __enter__(self) -> FakeVehicle:
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.stop()

    def set_link(self, up: bool) -> None:
        """Cut (``False``) or restore the radio: nothing is sent or received while cut."""
        self._link_up = up

    def switch_mode(self, custom_mode: int) -> None:
        """Change mode as a pilot's transmitter would (no command), and announce it."""
        with self._lock:
            self._enter_mode(custom_mode)
        self._heartbeat_due = True  # sent by the simulation thread, the only one that writes

    # -- what the vehicle is doing ---------------------------------------------------

    @property
    def true_position(self) -> np.ndarray:
        """Actual position in the local NED frame (no noise), m."""
        with self._lock:
            return self._state.position.copy()

    @property
    def true_velocity(self) -> np.ndarray:
        with self._lock:
            return self._state.velocity.copy()

    @property
    def true_yaw(self) -> float:
        with self._lock:
            return self._state.yaw

    @property
    def behaviour(self) -> Behaviour:
        """What the current mode makes the vehicle do (see :mod:`.fake_autopilot`)."""
        return self.rules.behaviour(self.custom_mode)

    @property
    def guided(self) -> bool:
        """In the mode that follows external setpoints (GUIDED or OFFBOARD)."""
        return self.behaviour == "follow"

    @property
    def on_ground(self) -> bool:
        with self._lock:
            state = self._state
            return state.position[2] >= -ON_GROUND_M and abs(state.velocity[2]) < 0.1

    @property
    def landed_state(self) -> int:
        """``MAV_LANDED_STATE`` of EXTENDED_SYS_STATE."""
        if self.on_ground:
            return mavlink.MAV_LANDED_STATE_ON_GROUND
        if self._takeoff_height is not None:
            return mavlink.MAV_LANDED_STATE_TAKEOFF
        if self.behaviour == "land":
            return mavlink.MAV_LANDED_STATE_LANDING
        return mavlink.MAV_LANDED_STATE_IN_AIR

    def true_end_effector(self) -> np.ndarray:
        """Actual gripper position in the local NED frame (the vehicle is level), m."""
        with self._lock:
            return self._state.position + yaw_matrix(self._state.yaw) @ self.end_effector_frd

    @property
    def sim_time_s(self) -> float:
        """The vehicle's time: seconds since it started (simulated steps in lockstep)."""
        return self._time()

    def _time(self) -> float:
        if self.lockstep:
            return self._step / self.dynamics.telemetry_hz
        return time.monotonic() - self._started_at

    # -- the loops -------------------------------------------------------------------

    def _run(self) -> None:
        if self.lockstep:
            self._run_lockstep()
        else:
            self._run_realtime()

    def _run_lockstep(self) -> None:
        """Simulate in steps of one telemetry period, each answered by the ground station.

        First a lone ``TIMESYNC`` request at time 0, sent until the ground station answers
        it: then it is surely listening, and it receives every message of every step from
        the first on. Each step then advances the physics by one period to time ``t`` and
        sends what falls due at ``t`` (heartbeat, status, telemetry), then a ``TIMESYNC``
        request with ``ts1 = t`` in nanoseconds. Until the answer comes back, every message
        received is applied at ``t``. As on one link the answer arrives after everything the
        ground station sent before it, each setpoint and command takes effect at a definite
        simulated time, and the run depends only on the seed and on what the ground station
        does. A request is sent again every :data:`SYNC_RESEND_S` of wall-clock time
        without an answer.
        """
        period = 1.0 / self.dynamics.telemetry_hz
        next_heartbeat = period
        self._await_sync(0)
        while not self._stop.is_set():
            self._advance(period, self._time())
            self._step += 1
            now = self._time()
            if now >= next_heartbeat or self._heartbeat_due:
                self._heartbeat_due = False
                self._send_heartbeat()
                next_heartbeat = now + 1.0
            self._send_periodic(now)
            self.telemetry_cycles += 1
            self._send_telemetry(now)
            self._await_sync(round(now * 1e9))

    def _await_sync(self, ts1: int) -> None:
        """Send a TIMESYNC request and apply what arrives until it is answered (lockstep)."""
        self._awaiting_sync = ts1
        while self._awaiting_sync is not None and not self._stop.is_set():
            if self._link_up:
                self._connection.mav.timesync_send(0, ts1)
            resend_at = time.monotonic() + SYNC_RESEND_S
            while self._awaiting_sync is not None and time.monotonic() < resend_at:
                message = self._connection.recv_match(blocking=True, timeout=0.05)
                if message is not None and self._link_up:
                    self._handle(message)

    def _run_realtime(self) -> None:
        period = 1.0 / self.dynamics.telemetry_hz
        now = self._time()
        last_step = now
        next_telemetry = now
        next_heartbeat = now
        while not self._stop.is_set():
            now = self._time()
            wait = max(0.0, min(next_telemetry, next_heartbeat) - now)
            message = self._connection.recv_match(blocking=True, timeout=min(wait, 0.02))
            while message is not None:
                if self._link_up:
                    self._handle(message)
                message = self._connection.recv_match(blocking=False)
            now = self._time()
            self._advance(now - last_step, now)
            last_step = now
            if now >= next_heartbeat or self._heartbeat_due:
                self._heartbeat_due = False
                self._send_heartbeat()
                next_heartbeat = now + 1.0
            self._send_periodic(now)
            if now >= next_telemetry:
                self.telemetry_cycles += 1
                self._send_telemetry(now)
                # Skip missed ticks instead of bursting after a stall of the machine.
                next_telemetry = max(next_telemetry + period, now)

    # -- simulation ------------------------------------------------------------------

    def _advance(self, elapsed: float, now: float) -> None:
        self.simulated_s += max(elapsed, 0.0)
        steps = max(1, math.ceil(elapsed / PHYSICS_STEP_S))
        dt = elapsed / steps
        if dt <= 0:
            return
        dyn, dist = self.dynamics, self.disturbance
        with self._lock:
            self._update_autopilot(now)
            state = self._state
            self.battery.drain(self._current_draw(), elapsed)
            if not self.armed:
                state.velocity[:] = 0.0
                return
            target, target_yaw = self._target(now)
            decay = math.exp(-dt / dist.gust_time_constant_s)
            spread = dist.gust_std_m_s2 * math.sqrt(1.0 - decay * decay)
            on_ground = self._grounded()
            for _ in range(steps):
                state.gust = decay * state.gust + spread * self._gust_rng.standard_normal(3)
                gust = state.gust if not on_ground else np.zeros(3)
                state.position, state.velocity, state.yaw = step_dynamics(
                    state.position, state.velocity, state.yaw, target, target_yaw, dt, dyn, gust
                )

    def _current_draw(self) -> float:
        if not self.armed:
            return self.battery.idle_a
        return self.battery.armed_a if self._grounded() else self.battery.hover_a

    def _grounded(self) -> bool:
        """On the ground and not climbing away from it (lock held)."""
        state = self._state
        return state.position[2] >= -ON_GROUND_M and state.velocity[2] >= -0.05

    def _update_autopilot(self, now: float) -> None:
        """Mode changes the autopilot makes on its own: failsafes, takeoff done, landed,
        automatic disarming (lock held)."""
        rules = self.rules
        behaviour = self.behaviour
        lost = rules.offboard_loss_s is not None and (
            now - self._last_setpoint_at > rules.offboard_loss_s
        )
        if behaviour == "follow" and lost:
            self._enter_mode(rules.mode_for("hold"))  # PX4's offboard-loss failsafe
            self._heartbeat_due = True
        if self._takeoff_height is not None:
            height = -self._state.position[2]
            if height >= self._takeoff_height - TAKEOFF_REACHED_M:
                reached = np.array([*self._hold_point[:2], -self._takeoff_height])
                self._takeoff_height = None
                self._flying = True
                mode = rules.after_takeoff()
                if mode != self.custom_mode:
                    self._enter_mode(mode)
                    self._heartbeat_due = True
                self._hold_point = reached  # the takeoff point is the target from now on
        grounded = self._grounded()
        if not grounded:
            self._flying = self._flying or self.armed
            self._armed_on_ground_since = None
            self._landed_since = None
            return
        if not self.armed:
            return
        if behaviour in ("land", "rtl") and self._flying:
            self._landed_since = now if self._landed_since is None else self._landed_since
            if now - self._landed_since >= rules.landed_disarm_s:
                self._disarm()
            return
        if self._takeoff_height is None and not self._climbing_setpoint():
            since = self._armed_on_ground_since
            self._armed_on_ground_since = now if since is None else since
            if now - self._armed_on_ground_since >= PREFLIGHT_DISARM_S:
                self._disarm()

    def _climbing_setpoint(self) -> bool:
        """Following a setpoint above the ground that lifts the vehicle off (PX4)."""
        return (
            self.behaviour == "follow"
            and not self.rules.takeoff_needed_on_ground
            and self.setpoint is not None
            and self.setpoint[0][2] < -ON_GROUND_M
        )

    def _disarm(self) -> None:
        self.armed = False
        self._flying = False
        self._takeoff_height = None
        self._armed_on_ground_since = None
        self._landed_since = None
        self._heartbeat_due = True

    def _enter_mode(self, custom_mode: int) -> None:
        """Switch mode; hold where the vehicle is when the new mode holds (lock held).

        Entering ArduCopter's GUIDED forgets any earlier position target: it holds where
        it is until a new one comes (its guided mode starts at the stopping point).
        """
        self.custom_mode = custom_mode
        self._hold_point = self._state.position.copy()
        self._hold_yaw = self._state.yaw
        behaviour = self.rules.behaviour(custom_mode)
        if behaviour not in ("takeoff", "follow"):
            self._takeoff_height = None
        if behaviour == "follow" and self.rules.offboard_loss_s is None:
            self.setpoint = None

    def _target(self, now: float) -> tuple[np.ndarray, float]:
        """Where the position loop steers to now (lock held)."""
        state, rules = self._state, self.rules
        behaviour = self.behaviour
        here = state.position
        if self._takeoff_height is not None:
            hold = self._hold_point
            return np.array([hold[0], hold[1], -self._takeoff_height]), self._hold_yaw
        if behaviour == "follow" and self.setpoint is not None:
            if rules.takeoff_needed_on_ground and not self._flying:
                return np.array([here[0], here[1], 0.0]), state.yaw  # waits for NAV_TAKEOFF
            return self.setpoint
        if behaviour == "land":
            return self._descend(rules.land_speed_m_s), self._hold_yaw
        if behaviour == "rtl":
            home_north, home_east, _ = self._local(self.home)
            away = math.hypot(here[0] - home_north, here[1] - home_east) > 0.05
            height = max(-self._hold_point[2], self.rtl_altitude_m)
            if away and -here[2] < height - TAKEOFF_REACHED_M:
                return np.array([here[0], here[1], -height]), self._hold_yaw  # climb first
            if away:
                return np.array([home_north, home_east, -height]), self._hold_yaw
            return self._descend(rules.land_speed_m_s), self._hold_yaw
        return self._hold_point, self._hold_yaw

    def _descend(self, speed: float) -> np.ndarray:
        """A target below the vehicle that the position loop follows down at ``speed``."""
        here = self._state.position
        return np.array([here[0], here[1], here[2] + speed / self.dynamics.position_gain])

    # -- messages in -----------------------------------------------------------------

    def _handle(self, message: Any) -> None:
        kind = message.get_type()
        if kind == "HEARTBEAT":
            self.gcs_heartbeats += 1
        elif kind == "TIMESYNC":
            if message.tc1 == 0:  # a request: answered as PX4 and ArduPilot do
                self._connection.mav.timesync_send(max(1, round(self._time() * 1e9)), message.ts1)
            elif message.ts1 == self._awaiting_sync:
                self._awaiting_sync = None
                self.sync_answers += 1
        elif kind == "SET_POSITION_TARGET_LOCAL_NED":
            self._handle_setpoint(message)
        elif kind in ("COMMAND_LONG", "COMMAND_INT"):
            self._handle_command(message)

    def _handle_setpoint(self, message: Any) -> None:
        if message.target_system not in (0, self.system_id):
            return
        if (
            message.type_mask != POSITION_YAW_TYPE_MASK
            or message.coordinate_frame != mavlink.MAV_FRAME_LOCAL_NED
        ):
            self.rejected_setpoints += 1
            return
        with self._lock:
            self._last_setpoint_at = self._time()
            self.setpoint = (np.array([message.x, message.y, message.z]), float(message.yaw))
            self.setpoints_received += 1

    def _stream_fresh(self) -> bool:
        return self._time() - self._last_setpoint_at <= STREAM_FRESH_S

    def _handle_command(self, message: Any) -> None:
        if message.target_system not in (0, self.system_id):
            return
        command = message.command
        self.commands_received.append(command)
        if message.get_type() == "COMMAND_INT":
            params = (message.param1, message.param2, message.param3, message.param4)
            params += (message.x, message.y, message.z)
        else:
            params = tuple(getattr(message, f"param{i}") for i in range(1, 8))
        handlers = {
            mavlink.MAV_CMD_DO_SET_MODE: self._command_set_mode,
            mavlink.MAV_CMD_COMPONENT_ARM_DISARM: self._command_arm,
            mavlink.MAV_CMD_NAV_TAKEOFF: self._command_takeoff,
            mavlink.MAV_CMD_NAV_LAND: lambda p: self._command_mode_of("land"),
            mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH: lambda p: self._command_mode_of("rtl"),
            mavlink.MAV_CMD_DO_GRIPPER: lambda p: self._gripper(p[1]),
            mavlink.MAV_CMD_SET_MESSAGE_INTERVAL: self._command_interval,
            mavlink.MAV_CMD_REQUEST_MESSAGE: lambda p: (
                mavlink.MAV_RESULT_ACCEPTED
                if int(p[0]) in REQUESTABLE
                else mavlink.MAV_RESULT_DENIED
            ),
        }
        handler = handlers.get(command)
        with self._lock:
            before = (self.custom_mode, self.armed)
            result = handler(params) if handler else mavlink.MAV_RESULT_UNSUPPORTED
            changed = (self.custom_mode, self.armed) != before
        self.acks_sent.append((command, result))
        self._connection.mav.command_ack_send(
            command,
            result,
            target_system=message.get_srcSystem(),
            target_component=message.get_srcComponent(),
        )
        if command == mavlink.MAV_CMD_REQUEST_MESSAGE and result == mavlink.MAV_RESULT_ACCEPTED:
            self._send_message(int(params[0]))
        if changed:
            self._send_heartbeat()  # announce the new mode or arming state at once

    def _command_set_mode(self, params: tuple) -> int:
        if not int(params[0]) & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return mavlink.MAV_RESULT_UNSUPPORTED
        mode = self.rules.requested_mode(params[1], params[2])
        if mode is None or not self.rules.may_enter(mode, self._stream_fresh()):
            return self.rules.refused
        if self.rules.behaviour(mode) == "takeoff":
            return self._start_takeoff(math.nan) if self.armed else self.rules.refused
        self._enter_mode(mode)
        return mavlink.MAV_RESULT_ACCEPTED

    def _command_arm(self, params: tuple) -> int:
        if params[0] < 0.5:
            if self.armed and not self._grounded() and int(params[1]) != 21196:
                return self.rules.refused  # no disarming in flight unless forced
            self._disarm()
            return mavlink.MAV_RESULT_ACCEPTED
        if not self.armed:
            if not self.rules.may_arm(self.custom_mode, self._stream_fresh()):
                return self.rules.refused
            self.armed = True
            self._armed_on_ground_since = None
            self.home = self._home_here()
            self._home_due = True
        return mavlink.MAV_RESULT_ACCEPTED

    def _command_takeoff(self, params: tuple) -> int:
        if not self.armed or not self._grounded():
            return self.rules.refused
        if self.rules.name == "ardupilot" and self.behaviour != "follow":
            return self.rules.refused  # ArduCopter takes off by command in GUIDED
        return self._start_takeoff(params[6])

    def _start_takeoff(self, param7: float) -> int:
        height = self.rules.takeoff_altitude_m(param7, self.home[2], TAKEOFF_ALTITUDE_M)
        if not height > ON_GROUND_M:
            return self.rules.refused  # "can't takeoff downwards"
        mode = self.rules.mode_for("takeoff")
        if mode != self.custom_mode:
            self._enter_mode(mode)
        self._takeoff_height = float(height)
        self._hold_point = self._state.position.copy()
        self._hold_yaw = self._state.yaw
        return mavlink.MAV_RESULT_ACCEPTED

    def _command_mode_of(self, behaviour: Behaviour) -> int:
        self._enter_mode(self.rules.mode_for(behaviour))
        return mavlink.MAV_RESULT_ACCEPTED

    def _command_request(self, params: tuple) -> int:
        if int(params[0]) not in REQUESTABLE:
            return mavlink.MAV_RESULT_DENIED
        return mavlink.MAV_RESULT_ACCEPTED  # the message follows the acknowledgement

    def _command_interval(self, params: tuple) -> int:
        message_id = int(params[0])
        if message_id not in REQUESTABLE:
            return mavlink.MAV_RESULT_DENIED
        self._intervals[message_id] = float(params[1])
        return mavlink.MAV_RESULT_ACCEPTED

    def _gripper(self, action: float) -> int:
        grab = int(action) == mavlink.GRIPPER_ACTION_GRAB
        with self._lock:
            position = self._state.position.copy()
            yaw = self._state.yaw
        end_effector = position + yaw_matrix(yaw) @ self.end_effector_frd
        self.gripper_events.append(
            GripperEvent(
                grab=grab,
                time_s=self._time(),
                position_ned=tuple(float(v) for v in position),
                yaw_rad=yaw,
                end_effector_ned=tuple(float(v) for v in end_effector),
            )
        )
        return mavlink.MAV_RESULT_ACCEPTED

    # -- messages out ----------------------------------------------------------------

    def _send_periodic(self, now: float) -> None:
        """The status messages and the global position, when they fall due."""
        if now >= self._next_status:
            self._next_status = now + STATUS_PERIOD_S
            for message_id in (
                mavlink.MAVLINK_MSG_ID_SYS_STATUS,
                mavlink.MAVLINK_MSG_ID_BATTERY_STATUS,
                mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE,
            ):
                if self._intervals.get(message_id, 0.0) != -1:
                    self._send_message(message_id)
        if now >= self._next_global:
            self._next_global = now + GLOBAL_POSITION_PERIOD_S
            if self._intervals.get(mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, 0.0) != -1:
                self._send_message(mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT)
        if self._home_due or now >= self._next_home:
            self._home_due = False
            self._next_home = now + HOME_PERIOD_S
            self._send_message(mavlink.MAVLINK_MSG_ID_HOME_POSITION)

    def _send_message(self, message_id: int) -> None:
        if not self._link_up:
            return
        mav = self._connection.mav
        now = self._time()
        boot_ms = int(now * 1000) & 0xFFFFFFFF
        with self._lock:
            position = self._state.position.copy()
            velocity = self._state.velocity.copy()
            yaw = self._state.yaw
            battery = self.battery
            remaining = round(100 * battery.remaining)
            if message_id == mavlink.MAVLINK_MSG_ID_SYS_STATUS:
                health = SENSORS | mavlink.MAV_SYS_STATUS_PREARM_CHECK
                mav.sys_status_send(
                    SENSORS | mavlink.MAV_SYS_STATUS_PREARM_CHECK,
                    SENSORS,
                    health,
                    250,
                    round(battery.voltage_v * 1000),
                    round(battery.current_a * 100),
                    remaining,
                    0,
                    0,
                    0,
                    0,
                    0,
                    0,
                )
            elif message_id == mavlink.MAVLINK_MSG_ID_BATTERY_STATUS:
                cells = [round(battery.cell_voltage_v * 1000)] * battery.cells
                mav.battery_status_send(
                    0,
                    mavlink.MAV_BATTERY_FUNCTION_ALL,
                    mavlink.MAV_BATTERY_TYPE_LIPO,
                    32767,  # temperature unknown
                    cells + [65535] * (10 - battery.cells),
                    round(battery.current_a * 100),
                    round(battery.consumed_mah),
                    -1,
                    remaining,
                    0,
                    mavlink.MAV_BATTERY_CHARGE_STATE_OK,
                    [0, 0, 0, 0],
                    0,
                    0,
                )
            elif message_id == mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE:
                mav.extended_sys_state_send(mavlink.MAV_VTOL_STATE_UNDEFINED, self.landed_state)
            elif message_id == mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT:
                lat, lon, alt = self._global(position)
                mav.global_position_int_send(
                    boot_ms,
                    round(lat * 1e7),
                    round(lon * 1e7),
                    round(alt * 1000),
                    round(-position[2] * 1000),
                    *(round(v * 100) for v in velocity),
                    round(math.degrees(yaw) % 360 * 100),
                )
            elif message_id == mavlink.MAVLINK_MSG_ID_HOME_POSITION:
                lat, lon, alt = self.home
                x, y, z = self._local(self.home)
                mav.home_position_send(
                    round(lat * 1e7),
                    round(lon * 1e7),
                    round(alt * 1000),
                    x,
                    y,
                    z,
                    [1.0, 0.0, 0.0, 0.0],
                    0.0,
                    0.0,
                    0.0,
                    int(now * 1e6),
                )
            elif message_id == mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
                capabilities = (
                    mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
                    | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
                    | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                )
                mav.autopilot_version_send(
                    capabilities, 0, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, self.system_id
                )
            elif message_id == mavlink.MAVLINK_MSG_ID_HEARTBEAT:
                self._send_heartbeat()
            elif message_id == mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED:
                self._send_telemetry(now)

    def _global(self, position: np.ndarray) -> tuple[float, float, float]:
        """Latitude, longitude (deg) and altitude AMSL (m) of a local NED point (flat Earth
        around the origin, fine over a robot cell)."""
        lat0, lon0, alt0 = self._origin_lla
        lat = lat0 + math.degrees(position[0] / EARTH_RADIUS_M)
        lon = lon0 + math.degrees(position[1] / (EARTH_RADIUS_M * math.cos(math.radians(lat0))))
        return lat, lon, alt0 - float(position[2])

    def _local(self, lla: tuple[float, float, float]) -> tuple[float, float, float]:
        lat0, lon0, alt0 = self._origin_lla
        north = math.radians(lla[0] - lat0) * EARTH_RADIUS_M
        east = math.radians(lla[1] - lon0) * EARTH_RADIUS_M * math.cos(math.radians(lat0))
        return north, east, alt0 - lla[2]

    def _home_here(self) -> tuple[float, float, float]:
        return self._global(self._state.position)

    def _send_heartbeat(self) -> None:
        if not (self._link_up and self.heartbeats_enabled):
            return
        base_mode = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if self.armed:
            base_mode |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        status = mavlink.MAV_STATE_ACTIVE if self.armed else mavlink.MAV_STATE_STANDBY
        self._connection.mav.heartbeat_send(
            mavlink.MAV_TYPE_HEXAROTOR,
            self.rules.mav_autopilot,
            base_mode,
            self.custom_mode,
            status,
        )

    def _send_telemetry(self, now: float) -> None:
        if not self._link_up:
            return
        dist = self.disturbance
        with self._lock:
            position = self._state.position.copy()
            velocity = self._state.velocity.copy()
            yaw = self._state.yaw
        position_noise = self._noise_rng.normal(0.0, dist.position_noise_m, 3)
        attitude_noise = self._noise_rng.normal(0.0, dist.attitude_noise_rad, 3)
        boot_ms = int(now * 1000) & 0xFFFFFFFF
        x, y, z = position + position_noise
        self._connection.mav.local_position_ned_send(boot_ms, x, y, z, *velocity)
        self._connection.mav.attitude_send(
            boot_ms,
            attitude_noise[0],
            attitude_noise[1],
            wrap_angle(yaw + attitude_noise[2]),
            0.0,
            0.0,
            0.0,
        )


def main(argv: list[str] | None = None) -> None:
    """``python -m adapters.hexarotor.fake_vehicle``: run a fake vehicle until Ctrl-C."""
    parser = argparse.ArgumentParser(
        prog="python -m adapters.hexarotor.fake_vehicle",
        description="A SITL-free fake hexarotor that speaks MAVLink 2 over UDP.",
    )
    parser.add_argument("--url", default="udpout:127.0.0.1:14550", help="pymavlink URL")
    parser.add_argument("--autopilot", choices=("ardupilot", "px4"), default="ardupilot")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    vehicle = FakeVehicle(args.url, autopilot=args.autopilot, seed=args.seed).start()
    print(f"fake {args.autopilot} hexarotor on {args.url}; Ctrl-C stops it", flush=True)
    run_until_interrupted(vehicle)


def run_until_interrupted(vehicle: FakeVehicle) -> None:
    """Keep the started ``vehicle`` running until Ctrl-C, then stop it."""
    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        pass
    finally:
        vehicle.stop()


if __name__ == "__main__":
    main()
