"""The MAVLink adapter: frames and planning, then the link against the fake over loopback UDP."""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator

import numpy as np
import pytest

from adapters.fake_vehicle import Disturbance, FakeVehicle, free_udp_port
from adapters.mavlink import (
    POSITION_YAW_TYPE_MASK,
    ApproachConfig,
    CommandRejectedError,
    Geofence,
    LinkConfig,
    LinkLostError,
    LinkTimeoutError,
    MavlinkVehicle,
    UnsafeTargetError,
    VehicleNotReadyError,
    body_to_ned,
    check_plan,
    end_effector_ned,
    enu_from_ned,
    mavlink,
    ned_from_enu,
    plan_approach,
    yaw_ned_from_enu,
)

TIMEOUT_S = 15.0
"""Generous for a loaded 2-core machine; waits end as soon as their condition holds."""
QUIET = Disturbance(gust_std_m_s2=0.0, position_noise_m=0.0, attitude_noise_rad=0.0)
FAST = ApproachConfig(dwell_s=0.1, approach_speed_m_s=0.5, timeout_s=60.0)


def wait_until(condition: Callable[[], bool], what: str) -> None:
    deadline = time.monotonic() + TIMEOUT_S
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.02)


# -- frames ------------------------------------------------------------------------------


def test_ned_from_enu_swaps_the_horizontal_axes_and_flips_up() -> None:
    assert ned_from_enu((1.0, 2.0, 3.0)) == pytest.approx([2.0, 1.0, -3.0])
    assert ned_from_enu((1.0, 2.0, 3.0), (10.0, 20.0, -1.0)) == pytest.approx([12.0, 21.0, -4.0])


def test_enu_and_ned_round_trip() -> None:
    rng = np.random.default_rng(3)
    origin = rng.normal(size=3)
    for point in rng.normal(size=(20, 3)):
        assert enu_from_ned(ned_from_enu(point, origin), origin) == pytest.approx(point)


def test_yaw_conversion_maps_compass_directions() -> None:
    assert yaw_ned_from_enu(0.0) == pytest.approx(math.pi / 2)  # facing east
    assert yaw_ned_from_enu(math.pi / 2) == pytest.approx(0.0)  # facing north
    assert yaw_ned_from_enu(yaw_ned_from_enu(0.7)) == pytest.approx(0.7)


def test_yaw_conversion_agrees_with_the_point_conversion() -> None:
    yaw_enu = 0.4
    heading_enu = (math.cos(yaw_enu), math.sin(yaw_enu), 0.0)
    heading_ned = ned_from_enu(heading_enu)
    yaw_ned = yaw_ned_from_enu(yaw_enu)
    assert heading_ned == pytest.approx([math.cos(yaw_ned), math.sin(yaw_ned), 0.0])


def test_body_to_ned_is_a_rotation_and_yaw_turns_forward_east() -> None:
    rotation = body_to_ned(0.1, -0.2, 0.3)
    assert rotation @ rotation.T == pytest.approx(np.eye(3))
    assert np.linalg.det(rotation) == pytest.approx(1.0)
    assert body_to_ned(0, 0, math.pi / 2) @ [1, 0, 0] == pytest.approx([0, 1, 0], abs=1e-12)
    # Pitching nose up lifts a point ahead of the vehicle (NED: more negative down).
    assert (body_to_ned(0, 0.1, 0) @ [1, 0, 0])[2] < 0


def test_end_effector_follows_position_and_heading() -> None:
    where = end_effector_ned((1.0, 2.0, -1.0), 0.0, 0.0, math.pi, (0.4, 0.0, 0.2))
    assert where == pytest.approx([0.6, 2.0, -0.8])


# -- planning and the fence --------------------------------------------------------------


def test_plan_puts_the_gripper_on_the_target_after_a_standoff() -> None:
    config = ApproachConfig(end_effector_frd=(0.4, 0.1, 0.2), standoff_m=0.5)
    target = np.array([2.0, 1.0, -1.0])
    plan = plan_approach(target, 0.6, config)
    final_gripper = end_effector_ned(plan.final_ned, 0, 0, 0.6, config.end_effector_frd)
    standoff_gripper = end_effector_ned(plan.standoff_ned, 0, 0, 0.6, config.end_effector_frd)
    assert final_gripper == pytest.approx(target)
    heading = np.array([math.cos(0.6), math.sin(0.6), 0.0])
    assert target - standoff_gripper == pytest.approx(0.5 * heading)


def test_fence_refuses_points_outside() -> None:
    fence = Geofence(north=(-1, 1), east=(-1, 1), down=(-2, 0))
    assert fence.contains((0.5, -0.5, -1.0))
    assert not fence.contains((0.5, -0.5, -2.5))
    with pytest.raises(UnsafeTargetError, match="outside the geofence"):
        fence.check((1.5, 0, -1), "setpoint")
    # The target inside but the standoff (0.5 m behind it) outside: refused.
    plan = plan_approach((-0.9, 0.0, -1.0), 0.0, ApproachConfig(end_effector_frd=(0, 0, 0)))
    with pytest.raises(UnsafeTargetError, match="standoff"):
        check_plan(plan, fence)


def test_configurations_are_validated() -> None:
    assert LinkConfig().link_loss_s == 2.0
    assert ApproachConfig().tolerance_m == 0.010
    with pytest.raises(ValueError, match="setpoint_rate_hz"):
        LinkConfig(setpoint_rate_hz=5.0)
    with pytest.raises(ValueError, match="low < high"):
        Geofence(north=(1.0, -1.0))
    with pytest.raises(ValueError, match="tolerance_m"):
        ApproachConfig(tolerance_m=0.0)
    with pytest.raises(ValueError, match=r"<= 2\.0"):
        ApproachConfig(transit_speed_m_s=5.0)


# -- the link, against the fake ----------------------------------------------------------


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
        adapter.wait_for_state(TIMEOUT_S)
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
    fake, adapter = connect(autopilot="px4", offboard_warmup_s=0.5)
    assert adapter.autopilot == "px4"
    adapter.set_guided_mode()
    assert fake.guided and adapter.in_guided_mode
    assert fake.setpoints_received >= 5  # the stream ran before the switch


def test_a_refused_command_raises(connect) -> None:
    _, adapter = connect()
    with pytest.raises(CommandRejectedError, match="MAV_RESULT_UNSUPPORTED"):
        adapter.command(mavlink.MAV_CMD_NAV_TAKEOFF)


def test_setpoints_are_position_and_yaw_at_the_configured_rate(connect) -> None:
    fake, adapter = connect(disturbance=QUIET, link=LinkConfig(setpoint_rate_hz=25.0))
    adapter.set_guided_mode()
    adapter.arm()
    adapter.goto((0.1, -0.1, -0.2), 0.25, speed_m_s=1.0)
    wait_until(
        lambda: np.linalg.norm(fake.true_position - [0.1, -0.1, -0.2]) < 0.01,
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
    fake, adapter = connect(fence=fence)
    adapter.set_guided_mode()
    adapter.arm()
    with pytest.raises(UnsafeTargetError):
        # Facing south, the gripper would reach 1.9 m north but the vehicle be at 2.3 m.
        adapter.approach((1.9, 0.0, -1.0), math.pi)
    with pytest.raises(UnsafeTargetError):
        adapter.goto((0.0, 0.0, -2.5), 0.0, 0.5)
    time.sleep(0.2)  # a stream, had one started, would have sent several setpoints by now
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
    time.sleep(0.3)
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
    time.sleep(0.3)
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
