"""A SITL-free fake hexarotor that speaks MAVLink 2 over UDP, for tests and the ``dlo hexa`` trial.

It is neither ArduPilot nor PX4: it imitates what a ground station sees of them, enough
to exercise :mod:`adapters.hexarotor.driver` over real sockets.

* Heartbeat at 1 Hz as an ArduCopter-like (``MAV_AUTOPILOT_ARDUPILOTMEGA``, custom modes
  STABILIZE 0, GUIDED 4, LOITER 5, LAND 9) or a PX4-like (``MAV_AUTOPILOT_PX4``, main mode in
  bits 16-23 and sub mode in bits 24-31 of ``custom_mode``: POSCTL 3, AUTO 4 with LOITER 3,
  OFFBOARD 6) hexarotor.
* ``MAV_CMD_DO_SET_MODE``, ``MAV_CMD_COMPONENT_ARM_DISARM`` and ``MAV_CMD_DO_GRIPPER`` are
  answered with ``COMMAND_ACK``; other commands get ``MAV_RESULT_UNSUPPORTED``. Like PX4, the
  PX4 flavour denies OFFBOARD unless setpoints have streamed for ``offboard_warmup_s``.
* ``SET_POSITION_TARGET_LOCAL_NED`` with ``type_mask`` 0x09F8 (position and yaw) in
  ``MAV_FRAME_LOCAL_NED`` is followed when armed and in GUIDED / OFFBOARD; any other mask or
  frame is ignored and counted in :attr:`FakeVehicle.rejected_setpoints`.
* ``LOCAL_POSITION_NED`` and ``ATTITUDE`` at ``telemetry_hz`` (default 40 Hz).

Dynamics (a fully-actuated vehicle, so it stays level): a cascaded position controller,
``v_des = clip(k_p (x_sp - x), v_max)`` and ``a = clip(k_v (v_des - v), a_max) + gust``,
integrated in steps of at most 5 ms. Gusts are an Ornstein-Uhlenbeck
acceleration per axis (standard deviation ``gust_std_m_s2``, time constant
``gust_time_constant_s``); the reported position and attitude carry white Gaussian noise.
When setpoints stop for ``setpoint_timeout_s`` the vehicle brakes and holds where it is
(the PX4 flavour also falls back to AUTO.LOITER, as PX4's offboard-loss failsafe does).
There is no takeoff procedure: when armed in the guided mode it simply follows setpoints;
disarmed it does not move.

Time: by default the simulation follows the wall clock, so two runs with the same seed are
statistically alike, not bit for bit. With ``lockstep=True`` it runs on a simulated clock,
one telemetry period per step, each step answered by the ground station over the link
(:meth:`FakeVehicle._run_lockstep`): faster than real time, and the same seed and the same
ground station give the same flight on every run.

Run it as a process with ``python -m adapters.hexarotor.fake_vehicle --url udpout:127.0.0.1:14550``.

The physics (closed position loop, gusts, noise) is :mod:`adapters.hexarotor.fake_dynamics`;
this module is the MAVLink side.
"""

from __future__ import annotations

import argparse
import math
import threading
import time
from dataclasses import dataclass
from typing import Literal

import numpy as np

from adapters.hexarotor.fake_dynamics import (
    PHYSICS_STEP_S,
    Disturbance,
    Dynamics,
    RigidState,
    step_dynamics,
    wrap_angle,
    yaw_matrix,
)
from adapters.hexarotor.protocol import (
    ARDUPILOT_MODES,
    POSITION_YAW_TYPE_MASK,
    PX4_MAIN_AUTO,
    PX4_MAIN_OFFBOARD,
    PX4_MAIN_POSCTL,
    PX4_SUB_AUTO_LOITER,
    mavlink,
    mavutil,
    px4_custom_mode,
)

Autopilot = Literal["ardupilot", "px4"]

SYNC_RESEND_S = 0.5
"""Lockstep: wall-clock seconds before an unanswered TIMESYNC request is sent again."""


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
        pymavlink connection string, normally ``udpout:127.0.0.1:PORT`` (the adapter
        listens with ``udpin:``).
    autopilot
        ``"ardupilot"`` or ``"px4"``: the heartbeat, mode numbers and OFFBOARD rule.
    seed
        Seed of the gust and noise streams.
    disturbance, dynamics
        Gusts and noise; controller gains and limits.
    start_ned
        Initial position in the local NED frame, m.
    end_effector_frd
        Where the gripper sits in the body frame (forward, right, down), m; only used to
        record the ground truth of :attr:`gripper_events`.
    offboard_warmup_s
        PX4 flavour: how long setpoints must have streamed before OFFBOARD is accepted.
    system_id
        MAVLink system id of the vehicle.
    lockstep
        Step the simulation in lockstep with the ground station instead of following the
        wall clock (see :meth:`_run_lockstep`): each telemetry period is one step, ended
        by a ``TIMESYNC`` request the ground station must answer before the next one.
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
        offboard_warmup_s: float = 1.0,
        system_id: int = 1,
        lockstep: bool = False,
    ) -> None:
        if autopilot not in ("ardupilot", "px4"):
            raise ValueError(f"autopilot must be 'ardupilot' or 'px4', got {autopilot!r}")
        self.url = url
        self.autopilot: Autopilot = autopilot
        self.disturbance = disturbance or Disturbance()
        self.dynamics = dynamics or Dynamics()
        self.end_effector_frd = np.asarray(end_effector_frd, dtype=float)
        self.offboard_warmup_s = offboard_warmup_s
        self.system_id = system_id
        self.lockstep = lockstep
        gust_seed, noise_seed = np.random.SeedSequence(seed).spawn(2)
        self._gust_rng = np.random.default_rng(gust_seed)
        self._noise_rng = np.random.default_rng(noise_seed)
        self._state = RigidState(position=np.asarray(start_ned, dtype=float).copy())
        self._hold_point: np.ndarray | None = self._state.position.copy()
        self._hold_yaw = 0.0
        self._lock = threading.Lock()
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

        self.armed = False
        self.custom_mode = (
            ARDUPILOT_MODES["LOITER"]
            if autopilot == "ardupilot"
            else px4_custom_mode(PX4_MAIN_POSCTL)
        )
        self.setpoint: tuple[np.ndarray, float] | None = None
        self.setpoints_received = 0
        self.rejected_setpoints = 0
        self.commands_received: list[int] = []
        self.gripper_events: list[GripperEvent] = []
        self.gcs_heartbeats = 0
        self.telemetry_cycles = 0
        """Telemetry periods so far, counted whether or not the link is up."""
        self.simulated_s = 0.0
        """Seconds of motion simulated so far."""
        self.sync_answers = 0
        """Lockstep: steps the ground station has answered."""
        self._last_setpoint_at = -math.inf
        self._stream_started_at = math.inf

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
            self.custom_mode = custom_mode
            self._hold_point = self._state.position.copy()
            self._hold_yaw = self._state.yaw
        self._heartbeat_due = True  # sent by the simulation thread, the only one that writes

    # -- ground truth for tests ------------------------------------------------------

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
    def guided(self) -> bool:
        """In the mode that follows external setpoints (GUIDED or OFFBOARD)."""
        if self.autopilot == "ardupilot":
            return self.custom_mode == ARDUPILOT_MODES["GUIDED"]
        return self.custom_mode == px4_custom_mode(PX4_MAIN_OFFBOARD)

    def true_end_effector(self) -> np.ndarray:
        """Actual gripper position in the local NED frame (the vehicle is level), m."""
        with self._lock:
            return self._state.position + yaw_matrix(self._state.yaw) @ self.end_effector_frd

    # -- the loop --------------------------------------------------------------------

    @property
    def sim_time_s(self) -> float:
        """The vehicle's time: seconds since it started (simulated steps in lockstep)."""
        return self._time()

    def _time(self) -> float:
        if self.lockstep:
            return self._step / self.dynamics.telemetry_hz
        return time.monotonic() - self._started_at

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
        sends the heartbeat (when due) and the telemetry of ``t``, then a ``TIMESYNC``
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
            self.telemetry_cycles += 1
            self._send_telemetry(now)
            self._await_sync(round(now * 1e9))

    def _await_sync(self, ts1: int) -> None:
        """Send a TIMESYNC request and apply what arrives until it is answered (lockstep)."""
        self._awaiting_sync = ts1
        while self._awaiting_sync is not None and not self._stop.is_set():
            self._send_sync_request(ts1)
            resend_at = time.monotonic() + SYNC_RESEND_S
            while self._awaiting_sync is not None and time.monotonic() < resend_at:
                message = self._connection.recv_match(blocking=True, timeout=0.05)
                if message is not None and self._link_up:
                    self._handle(message)

    def _send_sync_request(self, ts1: int) -> None:
        if self._link_up:
            self._connection.mav.timesync_send(0, ts1)

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
            if now >= next_telemetry:
                self.telemetry_cycles += 1
                self._send_telemetry(now)
                # Skip missed ticks instead of bursting after a stall of the machine.
                next_telemetry = max(next_telemetry + period, now)

    def _advance(self, elapsed: float, now: float) -> None:
        self.simulated_s += max(elapsed, 0.0)
        steps = max(1, math.ceil(elapsed / PHYSICS_STEP_S))
        dt = elapsed / steps
        if dt <= 0:
            return
        dyn, dist = self.dynamics, self.disturbance
        with self._lock:
            state = self._state
            if not self.armed:
                state.velocity[:] = 0.0
                return
            target, target_yaw = self._target(now)
            decay = math.exp(-dt / dist.gust_time_constant_s)
            spread = dist.gust_std_m_s2 * math.sqrt(1.0 - decay * decay)
            for _ in range(steps):
                state.gust = decay * state.gust + spread * self._gust_rng.standard_normal(3)
                state.position, state.velocity, state.yaw = step_dynamics(
                    state.position,
                    state.velocity,
                    state.yaw,
                    target,
                    target_yaw,
                    dt,
                    dyn,
                    state.gust,
                )

    def _target(self, now: float) -> tuple[np.ndarray, float]:
        """Setpoint to follow, or the hold point once setpoints have stopped (lock held)."""
        fresh = now - self._last_setpoint_at <= self.dynamics.setpoint_timeout_s
        if self.guided and self.setpoint is not None and fresh:
            self._hold_point = None
            return self.setpoint
        if self._hold_point is None:
            # Setpoints just stopped: brake and hold here (where we would stop braking).
            self._hold_point = self._state.position.copy()
            self._hold_yaw = self._state.yaw
            if self.autopilot == "px4" and self.guided:
                self.custom_mode = px4_custom_mode(PX4_MAIN_AUTO, PX4_SUB_AUTO_LOITER)
        return self._hold_point, self._hold_yaw

    # -- messages --------------------------------------------------------------------

    def _handle(self, message: object) -> None:
        kind = message.get_type()
        if kind == "HEARTBEAT":
            self.gcs_heartbeats += 1
        elif kind == "TIMESYNC":
            if message.tc1 != 0 and message.ts1 == self._awaiting_sync:
                self._awaiting_sync = None
                self.sync_answers += 1
        elif kind == "SET_POSITION_TARGET_LOCAL_NED":
            self._handle_setpoint(message)
        elif kind == "COMMAND_LONG":
            self._handle_command(message)

    def _handle_setpoint(self, message: object) -> None:
        if message.target_system not in (0, self.system_id):
            return
        if (
            message.type_mask != POSITION_YAW_TYPE_MASK
            or message.coordinate_frame != mavlink.MAV_FRAME_LOCAL_NED
        ):
            self.rejected_setpoints += 1
            return
        now = self._time()
        with self._lock:
            if now - self._last_setpoint_at > self.dynamics.setpoint_timeout_s:
                self._stream_started_at = now
            self._last_setpoint_at = now
            self.setpoint = (np.array([message.x, message.y, message.z]), float(message.yaw))
            self.setpoints_received += 1

    def _handle_command(self, message: object) -> None:
        if message.target_system not in (0, self.system_id):
            return
        command = message.command
        self.commands_received.append(command)
        if command == mavlink.MAV_CMD_DO_SET_MODE:
            result = self._set_mode(message.param1, message.param2, message.param3)
        elif command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
            self.armed = message.param1 >= 0.5
            result = mavlink.MAV_RESULT_ACCEPTED
        elif command == mavlink.MAV_CMD_DO_GRIPPER:
            result = self._gripper(message.param2)
        else:
            result = mavlink.MAV_RESULT_UNSUPPORTED
        self._connection.mav.command_ack_send(
            command,
            result,
            target_system=message.get_srcSystem(),
            target_component=message.get_srcComponent(),
        )
        if result == mavlink.MAV_RESULT_ACCEPTED and command != mavlink.MAV_CMD_DO_GRIPPER:
            self._send_heartbeat()  # announce the new mode or arming state at once

    def _set_mode(self, base_mode: float, first: float, second: float) -> int:
        if not int(base_mode) & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return mavlink.MAV_RESULT_UNSUPPORTED
        if self.autopilot == "ardupilot":
            if int(first) not in ARDUPILOT_MODES.values():
                return mavlink.MAV_RESULT_DENIED
            mode = int(first)
        else:
            main, sub = int(first), int(second)
            if main not in (PX4_MAIN_POSCTL, PX4_MAIN_AUTO, PX4_MAIN_OFFBOARD):
                return mavlink.MAV_RESULT_DENIED
            if main == PX4_MAIN_OFFBOARD and not self._setpoints_streaming():
                return mavlink.MAV_RESULT_DENIED
            mode = px4_custom_mode(main, sub)
        with self._lock:
            self.custom_mode = mode
            self._hold_point = self._state.position.copy()
            self._hold_yaw = self._state.yaw
        return mavlink.MAV_RESULT_ACCEPTED

    def _setpoints_streaming(self) -> bool:
        now = self._time()
        with self._lock:
            fresh = now - self._last_setpoint_at <= self.dynamics.setpoint_timeout_s
            return fresh and now - self._stream_started_at >= self.offboard_warmup_s

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

    def _send_heartbeat(self) -> None:
        if not (self._link_up and self.heartbeats_enabled):
            return
        autopilot = (
            mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
            if self.autopilot == "ardupilot"
            else mavlink.MAV_AUTOPILOT_PX4
        )
        base_mode = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if self.armed:
            base_mode |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        status = mavlink.MAV_STATE_ACTIVE if self.armed else mavlink.MAV_STATE_STANDBY
        self._connection.mav.heartbeat_send(
            mavlink.MAV_TYPE_HEXAROTOR, autopilot, base_mode, self.custom_mode, status
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
    parser.add_argument("--gust-std", type=float, default=Disturbance.gust_std_m_s2)
    parser.add_argument("--position-noise", type=float, default=Disturbance.position_noise_m)
    args = parser.parse_args(argv)
    disturbance = Disturbance(gust_std_m_s2=args.gust_std, position_noise_m=args.position_noise)
    vehicle = FakeVehicle(
        args.url, autopilot=args.autopilot, seed=args.seed, disturbance=disturbance
    ).start()
    print(f"fake {args.autopilot} hexarotor on {args.url}; Ctrl-C stops it", flush=True)
    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        pass
    finally:
        vehicle.stop()


if __name__ == "__main__":
    main()
