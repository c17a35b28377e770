"""The MAVLink adapter against the fake vehicle over loopback UDP."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator

import numpy as np
import pytest

from adapters.errors import UnsafeTargetError
from adapters.hexarotor.approach import ApproachConfig, Geofence, plan_approach
from adapters.hexarotor.driver import (
    CommandRejectedError,
    LinkConfig,
    LinkLostError,
    LinkTimeoutError,
    MavlinkVehicle,
    VehicleNotReadyError,
)
from adapters.hexarotor.fake_dynamics import Disturbance
from adapters.hexarotor.fake_vehicle import FakeVehicle
from adapters.hexarotor.protocol import POSITION_YAW_TYPE_MASK, mavlink
from tests.helpers import free_udp_port, wait_until

QUIET = Disturbance(gust_std_m_s2=0.0, position_noise_m=0.0, attitude_noise_rad=0.0)
FAST = ApproachConfig(dwell_s=0.1, approach_speed_m_s=0.5, timeout_s=60.0)


def let_the_stream_run(fake: FakeVehicle, adapter: MavlinkVehicle, cycles: int = 3) -> None:
    """Return once the adapter's setpoint stream has had ``cycles`` chances to send and all
    it sent has reached the fake: our next heartbeat, sent after those cycles on the same
    socket, has arrived."""
    start = adapter.stream_cycles
    wait_until(lambda: adapter.stream_cycles >= start + cycles, "the stream's cycles")
    heard = fake.gcs_heartbeats
    wait_until(lambda: fake.gcs_heartbeats > heard, "our next heartbeat at the vehicle")


@pytest.fixture
def connect() -> Iterator[Callable[..., tuple[FakeVehicle, MavlinkVehicle]]]:
    """Start a fake on ``udpout:`` and connect the adapter on ``udpin:`` (a free port)."""
    opened: list[tuple[FakeVehicle, MavlinkVehicle]] = []

    def start(link: LinkConfig | None = None, fence: Geofence | None = None, **fake_options):
        port = free_udp_port()
        adapter = MavlinkVehicle(f"udpin:127.0.0.1:{port}", link=link, fence=fence)
        fake = FakeVehicle(f"udpout:127.0.0.1:{port}", **fake_options).start()
        opened.append((fake, adapter))
        adapter.connect()
        adapter.wait_for_state()
        return fake, adapter

    yield start
    for fake, adapter in opened:
        adapter.close()
        fake.stop()


def test_connect_times_out_without_a_vehicle() -> None:
    adapter = MavlinkVehicle(
        f"udpin:127.0.0.1:{free_udp_port()}", link=LinkConfig(heartbeat_timeout_s=0.3)
    )
    with pytest.raises(LinkTimeoutError, match="no vehicle heartbeat"):
        adapter.connect()


def test_ardupilot_guided_and_arming(connect) -> None:
    fake, adapter = connect(autopilot="ardupilot")
    assert adapter.autopilot == "ardupilot"
    adapter.set_guided_mode()
    adapter.arm()
    assert fake.guided and fake.armed
    assert adapter.in_guided_mode and adapter.armed
    wait_until(lambda: fake.gcs_heartbeats >= 1, "our heartbeat to reach the vehicle")


def test_px4_offboard_after_streaming_setpoints(connect) -> None:
    fake, adapter = connect(autopilot="px4")
    assert adapter.autopilot == "px4"
    adapter.set_guided_mode()
    assert fake.guided and adapter.in_guided_mode
    assert fake.setpoints_received >= 2  # the stream ran before the switch


@pytest.mark.parametrize(
    ("autopilot", "result"),
    [("ardupilot", "MAV_RESULT_FAILED"), ("px4", "MAV_RESULT_TEMPORARILY_REJECTED")],
)
def test_a_refused_command_raises(connect, autopilot, result) -> None:
    _, adapter = connect(autopilot=autopilot)
    with pytest.raises(CommandRejectedError, match=result):  # take-off while disarmed
        adapter.command(mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, 0, 0, 1.0)
    with pytest.raises(CommandRejectedError, match="MAV_RESULT_UNSUPPORTED"):
        adapter.command(mavlink.MAV_CMD_DO_ORBIT)


@pytest.mark.parametrize("autopilot", ["ardupilot", "px4"])
def test_take_off_then_land_from_the_ground(connect, autopilot) -> None:
    fake, adapter = connect(autopilot=autopilot, disturbance=QUIET)
    assert adapter.landed is not False  # on the ground (or not reported yet)
    adapter.set_guided_mode()
    adapter.arm()
    adapter.take_off(0.8)
    assert fake.true_position[2] == pytest.approx(-0.8, abs=0.11)
    wait_until(lambda: adapter.landed is False, "the vehicle to report itself in the air")
    adapter.land()
    assert adapter.landed
    wait_until(lambda: not adapter.armed, "the vehicle to disarm itself after landing")
    assert fake.true_position[2] == pytest.approx(0.0, abs=0.02)


def test_ardupilot_stays_on_the_ground_for_setpoints_until_it_takes_off(connect) -> None:
    fake, adapter = connect(autopilot="ardupilot", disturbance=QUIET)
    adapter.set_guided_mode()
    adapter.arm()
    adapter.goto((0.0, 0.0, -0.5), 0.0, 1.0)
    received = fake.setpoints_received
    let_the_stream_run(fake, adapter, cycles=20)  # a second of setpoints at 20 Hz
    assert fake.setpoints_received >= received + 20
    assert fake.true_position[2] == pytest.approx(0.0, abs=1e-9)


def test_setpoints_are_position_and_yaw_at_the_configured_rate(connect) -> None:
    fake, adapter = connect(
        disturbance=QUIET, link=LinkConfig(setpoint_rate_hz=25.0), start_ned=(0.0, 0.0, -1.0)
    )
    adapter.set_guided_mode()
    adapter.arm()
    adapter.goto((0.1, -0.1, -1.2), 0.25, speed_m_s=1.0)
    wait_until(
        lambda: np.linalg.norm(fake.true_position - [0.1, -0.1, -1.2]) < 0.01,
        "the vehicle to reach the setpoint",
    )
    assert fake.rejected_setpoints == 0
    assert fake.true_yaw == pytest.approx(0.25, abs=1e-3)
    assert POSITION_YAW_TYPE_MASK == 0x09F8


def test_approach_closes_the_gripper_within_tolerance(connect) -> None:
    config = FAST
    target = np.array([1.0, 0.5, -1.0])
    plan = plan_approach(target, 0.3, config)
    fake, adapter = connect(
        start_ned=tuple(plan.standoff_ned),
        end_effector_frd=config.end_effector_frd,
        disturbance=Disturbance(),  # gusts and noise on
    )
    adapter.set_guided_mode()
    adapter.arm()
    phases: list[str] = []
    report = adapter.approach(target, 0.3, config, on_phase=phases.append)
    assert report.ok and report.reason == "closed"
    assert report.error_m <= config.tolerance_m
    assert phases == ["standoff", "final", "close"]
    (event,) = fake.gripper_events
    assert event.grab
    # Ground truth: within tolerance plus what sensor noise can hide.
    assert np.linalg.norm(np.array(event.end_effector_ned) - target) < 0.03


def test_targets_outside_the_fence_are_refused_before_anything_is_sent(connect) -> None:
    fence = Geofence(north=(-2, 2), east=(-2, 2), down=(-2, 0.1))
    fake, adapter = connect(fence=fence, start_ned=(0.0, 0.0, -1.0))
    adapter.set_guided_mode()
    adapter.arm()
    with pytest.raises(UnsafeTargetError):
        # Facing south, the gripper would reach 1.9 m north but the vehicle be at 2.3 m.
        adapter.approach((1.9, 0.0, -1.0), math.pi)
    with pytest.raises(UnsafeTargetError):
        adapter.goto((0.0, 0.0, -2.5), 0.0, 0.5)
    let_the_stream_run(fake, adapter)
    assert fake.setpoints_received == 0
    assert adapter.commanded_setpoint() is None


def test_approach_needs_the_guided_mode_and_arming(connect) -> None:
    fake, adapter = connect()
    with pytest.raises(VehicleNotReadyError, match="armed"):
        adapter.approach((1.0, 0.0, -1.0), 0.0)
    assert fake.setpoints_received == 0


def test_no_command_without_a_recent_heartbeat(connect) -> None:
    fake, adapter = connect(link=LinkConfig(link_loss_s=0.5))
    adapter.set_guided_mode()
    adapter.arm()
    adapter.goto((0.0, 0.0, -0.5), 0.0, 0.5)
    wait_until(lambda: fake.setpoints_received > 0, "the stream")
    fake.heartbeats_enabled = False  # telemetry still flows; only the heartbeat stops
    wait_until(lambda: not adapter.link_ok(), "the link to count as lost")
    with pytest.raises(LinkLostError):
        adapter.set_gripper(True)
    with pytest.raises(LinkLostError):
        adapter.goto((0.0, 0.0, -1.0), 0.0, 0.5)
    received = fake.setpoints_received
    let_the_stream_run(fake, adapter)  # our heartbeat keeps going when the vehicle's stops
    assert fake.setpoints_received == received
    assert mavlink.MAV_CMD_DO_GRIPPER not in fake.commands_received


def test_a_lost_link_aborts_the_approach_and_the_vehicle_holds(connect) -> None:
    config = FAST
    target = np.array([1.0, 0.0, -1.0])
    plan = plan_approach(target, 0.0, config)
    fake, adapter = connect(
        link=LinkConfig(link_loss_s=0.5),  # the default is 2 s; shorter keeps the test quick
        start_ned=tuple(plan.standoff_ned),
        end_effector_frd=config.end_effector_frd,
        disturbance=QUIET,
    )
    adapter.set_guided_mode()
    adapter.arm()

    def cut_on_final(phase: str) -> None:
        if phase == "final":
            fake.set_link(False)

    report = adapter.approach(target, 0.0, config, on_phase=cut_on_final)
    assert not report.ok and report.reason == "link lost"
    assert fake.gripper_events == []
    wait_until(lambda: np.linalg.norm(fake.true_velocity) < 0.01, "the vehicle to hold")
    held = fake.true_position
    # It stopped where the link died, short of the final position, and stays there.
    assert np.linalg.norm(held - plan.final_ned) > 0.05
    simulated = fake.simulated_s
    wait_until(lambda: fake.simulated_s >= simulated + 0.3, "0.3 s more of simulation")
    assert fake.true_position == pytest.approx(held, abs=1e-3)


def test_leaving_the_guided_mode_aborts_the_approach(connect) -> None:
    config = FAST
    target = np.array([1.0, 0.0, -1.0])
    plan = plan_approach(target, 0.0, config)
    fake, adapter = connect(
        start_ned=tuple(plan.standoff_ned),
        end_effector_frd=config.end_effector_frd,
        disturbance=QUIET,
    )
    adapter.set_guided_mode()
    adapter.arm()

    def pilot_takes_over(phase: str) -> None:
        if phase == "final":
            fake.switch_mode(5)  # LOITER, from the transmitter

    report = adapter.approach(target, 0.0, config, on_phase=pilot_takes_over)
    assert not report.ok and report.reason == "left guided mode"
    assert fake.gripper_events == []
