"""The fake hexarotor, driven by a bare pymavlink ground station over loopback UDP."""

from __future__ import annotations

import math
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest

from adapters.hexarotor.fake_dynamics import Disturbance, Dynamics, step_dynamics
from adapters.hexarotor.fake_vehicle import FakeVehicle
from adapters.hexarotor.protocol import (
    ARDUPILOT_MODES,
    POSITION_YAW_TYPE_MASK,
    PX4_MAIN_AUTO,
    PX4_MAIN_OFFBOARD,
    PX4_SUB_AUTO_LOITER,
    mavlink,
    mavutil,
    px4_custom_mode,
)
from tests.helpers import DEFAULT_TIMEOUT_S, free_udp_port, wait_until

REPO_ROOT = Path(__file__).resolve().parents[3]
QUIET = Disturbance(gust_std_m_s2=0.0, position_noise_m=0.0, attitude_noise_rad=0.0)


class GroundStation:
    """A minimal pymavlink peer listening with ``udpin:`` as the adapter does.

    It answers the vehicle's TIMESYNC requests at once, as a ground station that is not in
    lockstep does, while it waits for a message: a lockstep vehicle then runs as fast as
    the exchange allows, and stands still between the station's waits.
    """

    def __init__(self, port: int) -> None:
        self.connection = mavutil.mavlink_connection(
            f"udpin:127.0.0.1:{port}", source_system=255, source_component=190
        )
        self.first_heartbeat = None

    def receive(self, kind: str, condition: Callable[[object], bool] = lambda m: True):
        deadline = time.monotonic() + DEFAULT_TIMEOUT_S
        while time.monotonic() < deadline:
            message = self.connection.recv_match(blocking=True, timeout=0.2)
            if message is None:
                continue
            if message.get_type() == "TIMESYNC" and message.tc1 == 0:
                self.connection.mav.timesync_send(time.monotonic_ns(), message.ts1)
            elif message.get_type() == kind and condition(message):
                return message
        raise AssertionError(f"no matching {kind} within {DEFAULT_TIMEOUT_S} s")

    def command(self, command: int, *params: float) -> int:
        padded = list(params) + [0.0] * (7 - len(params))
        self.connection.mav.command_long_send(1, 1, command, 0, *padded)
        return self.receive("COMMAND_ACK", lambda m: m.command == command).result

    def setpoint(self, north: float, east: float, down: float, yaw: float = 0.0, mask=None):
        self.connection.mav.set_position_target_local_ned_send(
            0,
            1,
            1,
            mavlink.MAV_FRAME_LOCAL_NED,
            POSITION_YAW_TYPE_MASK if mask is None else mask,
            north,
            east,
            down,
            0,
            0,
            0,
            0,
            0,
            0,
            yaw,
            0,
        )


@pytest.fixture
def link_pair() -> Iterator[Callable[..., tuple[FakeVehicle, GroundStation]]]:
    started: list[tuple[FakeVehicle, GroundStation]] = []

    def start(**options) -> tuple[FakeVehicle, GroundStation]:
        port = free_udp_port()
        station = GroundStation(port)
        vehicle = FakeVehicle(f"udpout:127.0.0.1:{port}", **options).start()
        started.append((vehicle, station))
        station.first_heartbeat = station.receive("HEARTBEAT")  # learns the vehicle's address
        return vehicle, station

    yield start
    for vehicle, station in started:
        vehicle.stop()
        station.connection.close()


def test_heartbeat_announces_an_ardupilot_hexarotor(link_pair) -> None:
    _, station = link_pair(autopilot="ardupilot")
    beat = station.first_heartbeat
    assert beat.autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
    assert beat.type == mavlink.MAV_TYPE_HEXAROTOR
    assert beat.custom_mode == ARDUPILOT_MODES["LOITER"]
    assert not beat.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    assert beat.get_msgbuf()[0] == 0xFD  # MAVLink 2 framing


def test_heartbeat_announces_a_px4_hexarotor(link_pair) -> None:
    _, station = link_pair(autopilot="px4")
    beat = station.first_heartbeat
    assert beat.autopilot == mavlink.MAV_AUTOPILOT_PX4
    assert (beat.custom_mode >> 16) & 0xFF == 3  # POSCTL


def test_telemetry_streams_position_and_attitude(link_pair) -> None:
    _, station = link_pair(start_ned=(1.0, 2.0, -3.0), disturbance=QUIET)
    position = station.receive("LOCAL_POSITION_NED")
    attitude = station.receive("ATTITUDE")
    assert (position.x, position.y, position.z) == pytest.approx((1.0, 2.0, -3.0))
    assert attitude.roll == pytest.approx(0.0)


def test_mode_and_arming_commands_are_acknowledged(link_pair) -> None:
    vehicle, station = link_pair(autopilot="ardupilot")
    custom = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    assert station.command(mavlink.MAV_CMD_DO_SET_MODE, custom, 4) == mavlink.MAV_RESULT_ACCEPTED
    # ArduCopter refuses a mode it does not have with FAILED (GCS_MAVLINK::_set_mode_common).
    assert station.command(mavlink.MAV_CMD_DO_SET_MODE, custom, 77) == mavlink.MAV_RESULT_FAILED
    assert station.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mavlink.MAV_RESULT_ACCEPTED
    beat = station.receive("HEARTBEAT", lambda m: m.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
    assert beat.custom_mode == ARDUPILOT_MODES["GUIDED"]
    assert vehicle.armed and vehicle.guided
    assert station.command(mavlink.MAV_CMD_DO_ORBIT) == mavlink.MAV_RESULT_UNSUPPORTED


def stream_setpoints(station: GroundStation, vehicle: FakeVehicle, count: int) -> None:
    """Send ``count`` setpoints, each once the vehicle has taken the one before."""
    for _ in range(count):
        received = vehicle.setpoints_received
        station.setpoint(0.0, 0.0, -1.0)
        wait_until(lambda r=received: vehicle.setpoints_received > r, "the setpoint")


def test_px4_takes_offboard_only_with_a_setpoint_stream(link_pair) -> None:
    vehicle, station = link_pair(autopilot="px4", lockstep=True)
    custom = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    offboard = (mavlink.MAV_CMD_DO_SET_MODE, custom, PX4_MAIN_OFFBOARD, 0)
    rejected = mavlink.MAV_RESULT_TEMPORARILY_REJECTED  # PX4's commander
    assert station.command(*offboard) == rejected
    stream_setpoints(station, vehicle, 2)
    # PX4 takes OFFBOARD once the stream is present: no warm-up beyond that.
    assert station.command(*offboard) == mavlink.MAV_RESULT_ACCEPTED
    assert vehicle.custom_mode == px4_custom_mode(PX4_MAIN_OFFBOARD)


def test_px4_falls_back_to_hold_when_the_stream_stops(link_pair) -> None:
    vehicle, station = link_pair(autopilot="px4", disturbance=QUIET, start_ned=(0.0, 0.0, -1.0))
    custom = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    stream_setpoints(station, vehicle, 2)
    assert station.command(mavlink.MAV_CMD_DO_SET_MODE, custom, PX4_MAIN_OFFBOARD, 0) == (
        mavlink.MAV_RESULT_ACCEPTED
    )
    # Silence: after COM_OF_LOSS_T the offboard-loss failsafe switches to Hold.
    beat = station.receive("HEARTBEAT", lambda m: (m.custom_mode >> 16) & 0xFF == PX4_MAIN_AUTO)
    assert (beat.custom_mode >> 24) & 0xFF == PX4_SUB_AUTO_LOITER


def test_follows_position_setpoints_and_ignores_other_masks(link_pair) -> None:
    vehicle, station = link_pair(disturbance=QUIET, start_ned=(0.0, 0.0, -1.0))
    custom = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    station.command(mavlink.MAV_CMD_DO_SET_MODE, custom, ARDUPILOT_MODES["GUIDED"])
    station.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    station.setpoint(0.0, 0.0, -1.0, mask=0x0FF8)  # velocity fields not masked: refused
    wait_until(lambda: vehicle.rejected_setpoints == 1, "the refusal")
    target = np.array([0.5, -0.3, -1.0])
    wait_until(
        lambda: np.linalg.norm(vehicle.true_position - target) < 0.01,
        "the vehicle to reach the setpoint",
        action=lambda: station.setpoint(*target, yaw=0.5),
    )
    wait_until(lambda: abs(vehicle.true_yaw - 0.5) < 0.01, "the yaw")


def test_ardupilot_keeps_flying_to_the_last_target_when_setpoints_stop(link_pair) -> None:
    vehicle, station = link_pair(disturbance=QUIET, start_ned=(0.0, 0.0, -1.0))
    custom = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    station.command(mavlink.MAV_CMD_DO_SET_MODE, custom, ARDUPILOT_MODES["GUIDED"])
    station.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    station.setpoint(1.0, 0.0, -1.0)  # one position target, then silence
    wait_until(
        lambda: np.linalg.norm(vehicle.true_position - [1.0, 0.0, -1.0]) < 0.01,
        "the vehicle to reach the last target",
    )
    assert vehicle.guided  # ArduCopter stays in GUIDED


@pytest.mark.parametrize("autopilot", ["ardupilot", "px4"])
def test_take_off_land_and_disarm_by_command(link_pair, autopilot) -> None:
    vehicle, station = link_pair(autopilot=autopilot, disturbance=QUIET, lockstep=True)
    custom = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    if autopilot == "ardupilot":  # ArduCopter takes off in GUIDED
        station.command(mavlink.MAV_CMD_DO_SET_MODE, custom, ARDUPILOT_MODES["GUIDED"])
    takeoff = (mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, 0, 0)
    height = 1.0 if autopilot == "ardupilot" else vehicle.home[2] + 1.0  # PX4: AMSL
    assert station.command(*takeoff, height) == vehicle.rules.refused  # not armed yet
    assert station.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mavlink.MAV_RESULT_ACCEPTED
    assert station.command(*takeoff, height) == mavlink.MAV_RESULT_ACCEPTED
    station.receive(
        "EXTENDED_SYS_STATE", lambda m: m.landed_state == mavlink.MAV_LANDED_STATE_IN_AIR
    )
    assert vehicle.true_position[2] == pytest.approx(-1.0, abs=0.11)
    assert station.command(mavlink.MAV_CMD_NAV_LAND, 0, 0, 0, math.nan) == (
        mavlink.MAV_RESULT_ACCEPTED
    )
    station.receive("HEARTBEAT", lambda m: not m.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
    assert vehicle.landed_state == mavlink.MAV_LANDED_STATE_ON_GROUND


def test_battery_and_home_telemetry(link_pair) -> None:
    _, station = link_pair(home=(10.0, 20.0, 100.0), start_ned=(3.0, 4.0, 0.0))
    battery = station.receive("BATTERY_STATUS")
    assert battery.battery_remaining == 100 and battery.voltages[4] == 65535
    status = station.receive("SYS_STATUS")
    assert status.onboard_control_sensors_health & mavlink.MAV_SYS_STATUS_PREARM_CHECK
    position = station.receive("GLOBAL_POSITION_INT")
    assert position.lat / 1e7 == pytest.approx(10.0 + math.degrees(3.0 / 6378137.0), abs=1e-7)
    assert position.alt == 100_000 and position.relative_alt == 0
    home = station.receive("HOME_POSITION")
    assert (home.latitude, home.longitude, home.altitude) == (100_000_000, 200_000_000, 100_000)


def test_gripper_command_records_the_ground_truth(link_pair) -> None:
    vehicle, station = link_pair(
        disturbance=QUIET, start_ned=(1.0, 0.0, -1.0), end_effector_frd=(0.4, 0.0, 0.2)
    )
    result = station.command(mavlink.MAV_CMD_DO_GRIPPER, 1, mavlink.GRIPPER_ACTION_GRAB)
    assert result == mavlink.MAV_RESULT_ACCEPTED
    (event,) = vehicle.gripper_events
    assert event.grab
    assert event.end_effector_ned == pytest.approx((1.4, 0.0, -0.8))


def test_a_cut_link_sends_and_hears_nothing(link_pair) -> None:
    vehicle, station = link_pair()
    vehicle.set_link(False)
    # On loopback a datagram is in our socket once the fake's send returned; so after
    # whole telemetry periods with the link cut, draining leaves nothing sent before it.
    cut_at = vehicle.telemetry_cycles
    wait_until(lambda: vehicle.telemetry_cycles >= cut_at + 2, "telemetry periods while cut")
    while station.connection.recv_match(blocking=False) is not None:
        pass
    drained_at = vehicle.telemetry_cycles
    wait_until(lambda: vehicle.telemetry_cycles >= drained_at + 3, "three more periods")
    assert station.connection.recv_match(blocking=False) is None
    vehicle.set_link(True)
    station.receive("LOCAL_POSITION_NED")


def test_step_dynamics_bounds_the_acceleration() -> None:
    dynamics = Dynamics(max_accel_m_s2=2.0)
    position, velocity = np.zeros(3), np.zeros(3)
    target = np.array([10.0, 0.0, 0.0])
    dt = 0.005
    for _ in range(400):
        previous = velocity
        position, velocity, _ = step_dynamics(position, velocity, 0.0, target, 0.0, dt, dynamics)
        assert np.linalg.norm(velocity - previous) / dt <= 2.0 + 1e-9
        assert np.linalg.norm(velocity) <= dynamics.max_speed_m_s + 1e-9


def test_step_dynamics_settles_on_the_target_and_stops_at_the_ground() -> None:
    dynamics = Dynamics()
    position, velocity, yaw = np.array([0.0, 0.0, -0.5]), np.zeros(3), 0.0
    target = np.array([1.0, -1.0, 0.3])  # below ground: it must stop at z = 0
    for _ in range(4000):
        position, velocity, yaw = step_dynamics(
            position, velocity, yaw, target, 3.0, 0.005, dynamics
        )
        assert position[2] <= 0.0
    assert position[:2] == pytest.approx([1.0, -1.0], abs=1e-3)
    assert yaw == pytest.approx(3.0)


def test_invalid_settings_are_refused() -> None:
    with pytest.raises(ValueError, match="autopilot"):
        FakeVehicle("udpout:127.0.0.1:1", autopilot="betaflight")
    with pytest.raises(ValueError, match="gust_std_m_s2"):
        Disturbance(gust_std_m_s2=-1.0)
    with pytest.raises(ValueError, match="telemetry_hz"):
        Dynamics(telemetry_hz=0.0)


def test_runs_as_a_separate_process() -> None:
    port = free_udp_port()
    station = GroundStation(port)
    process = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "adapters.hexarotor.fake_vehicle",
            "--url",
            f"udpout:127.0.0.1:{port}",
        ],
        cwd=REPO_ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + 30.0  # interpreter start-up on a loaded machine
        beat = None
        while beat is None and time.monotonic() < deadline and process.poll() is None:
            beat = station.connection.recv_match(type="HEARTBEAT", blocking=True, timeout=0.5)
        assert beat is not None, process.stderr.read() if process.poll() is not None else ""
        assert beat.type == mavlink.MAV_TYPE_HEXAROTOR
    finally:
        process.terminate()
        process.wait(timeout=10)
        station.connection.close()
