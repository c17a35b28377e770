"""UR3 pick adapter against the in-process fake: exact commands, refusals, lost links."""

from __future__ import annotations

import math
import os
import threading

import pytest

from adapters.errors import UnsafeTargetError
from adapters.grasp.motions import (
    GripperOutput,
    UR3Config,
    plan_motions,
    tool_down_rotation_vector,
)
from adapters.ur3.driver import (
    RobotNotReadyError,
    UR3Picker,
    motion_deadline_s,
    trapezoid_duration_s,
)
from adapters.ur3.fakes import FakeRobot
from tests.adapters.builders import grasp_target as target


def picker(robot: FakeRobot, config: UR3Config | None = None) -> tuple[UR3Picker, list[float]]:
    sleeps: list[float] = []
    return UR3Picker("10.0.0.2", config, connect=robot.connect, sleep=sleeps.append), sleeps


# --- pick against the fake ----------------------------------------------------------------


def test_pick_sends_exactly_the_plan_and_reports_each_step():
    robot = FakeRobot()
    p, sleeps = picker(robot)
    report = p.pick(target())
    rot = list(tool_down_rotation_vector(0.3))
    approach = [0.3, 0.1, 0.115, *rot]
    grasp = [0.3, 0.1, 0.015, *rot]
    sent = [(c.interface, c.method, c.args) for c in robot.sent()]
    assert sent == [
        ("control", "moveL", (pytest.approx(approach), 0.25, 0.5, False)),
        ("control", "moveL", (pytest.approx(grasp), 0.25, 0.5, False)),
        ("io", "setToolDigitalOut", (0, True)),
        ("control", "moveL", (pytest.approx(approach), 0.25, 0.5, False)),
    ]
    assert report.ok and report.reason is None and not report.stop_sent
    assert [s.motion.label for s in report.steps] == [
        "approach",
        "descend",
        "close_gripper",
        "lift",
    ]
    assert all(s.ok and s.duration_s >= 0 for s in report.steps)
    assert report.steps[1].reached_pose == pytest.approx(grasp)
    assert report.steps[3].reached_pose == pytest.approx(approach)
    assert sleeps == [0.5]
    assert robot.connected_to == ["10.0.0.2"]
    # Every check ran before the first command.
    first_command = robot.calls.index(robot.sent()[0])
    queries = robot.methods()[:first_command]
    for method in (
        "isEmergencyStopped",
        "isProtectiveStopped",
        "getSafetyMode",
        "isProgramRunning",
        "isPoseWithinSafetyLimits",
        "getActualTCPPose",
    ):
        assert method in queries
    assert queries.count("isPoseWithinSafetyLimits") == 3


def test_standard_output_gripper():
    robot = FakeRobot()
    config = UR3Config(gripper=GripperOutput(kind="standard", index=5, close_value=False))
    picker(robot, config)[0].pick(target())
    assert ("setStandardDigitalOut", (5, False)) in [(c.method, c.args) for c in robot.sent()]
    assert robot.digital_outputs == {("standard", 5): False}
    with pytest.raises(ValueError, match=r"tool digital output index must be 0\.\.1"):
        GripperOutput(kind="tool", index=2)


def _grasp_z_below(limit: float):
    return lambda pose: pose[2] >= limit


@pytest.mark.parametrize(
    ("robot_settings", "goal", "error", "message"),
    [
        ({"emergency_stopped": True}, target(), RobotNotReadyError, "emergency stopped"),
        ({"protective_stopped": True}, target(), RobotNotReadyError, "protective stopped"),
        ({"program_running": False}, target(), RobotNotReadyError, "control script is not running"),
        ({"connected": False}, target(), RobotNotReadyError, "control interface is not connected"),
        (
            {"within_safety_limits": _grasp_z_below(0.05)},
            target(),
            UnsafeTargetError,
            "descend pose .* outside the robot's safety limits",
        ),
        ({}, target(x=0.5, y=0.2), UnsafeTargetError, "approach position .* beyond the 0.450 m"),
        ({}, target(z=-0.01), UnsafeTargetError, "descend height .* below the table clearance"),
        ({}, target(x=0.05, y=0.05), UnsafeTargetError, "inside the 0.100 m keep-out cylinder"),
        (
            {"tcp_pose": [-0.3, 0.02, 0.3, math.pi, 0, 0]},
            target(x=0.3, y=0.0),
            UnsafeTargetError,
            "straight path from the current tool position",
        ),
    ],
)
def test_every_refusal_sends_nothing(robot_settings, goal, error, message):
    robot = FakeRobot(**robot_settings)
    p, sleeps = picker(robot)
    with pytest.raises(error, match=message):
        p.pick(goal)
    assert robot.sent() == []
    assert robot.motions() == []
    assert sleeps == []


def test_query_failure_during_checks_is_not_ready_and_sends_nothing():
    robot = FakeRobot()
    robot.within_safety_limits = lambda pose: (_ for _ in ()).throw(RuntimeError("timeout"))
    with pytest.raises(RobotNotReadyError, match="could not read the robot state: RuntimeError"):
        picker(robot)[0].pick(target())
    assert robot.sent() == []


@pytest.mark.parametrize("raises", [True, False])
def test_lost_connection_mid_move_stops_reconnects_once_and_fails(raises):
    robot = FakeRobot(disconnect_after=1, disconnect_raises=raises)
    report = picker(robot)[0].pick(target())
    assert not report.ok
    assert report.reason.startswith("descend:")
    assert [s.ok for s in report.steps] == [True, False]
    methods = robot.methods()
    failed_move = [i for i, m in enumerate(methods) if m == "moveL"][1]
    after = methods[failed_move + 1 :]
    assert "moveL" not in after and "setToolDigitalOut" not in after
    assert after.count("reconnect") == 1
    assert after.index("stopL") < after.index("reconnect")
    assert report.reconnect_attempted and report.reconnected
    # stopL first went down the dead link; once reconnected it went through.
    assert methods.count("stopL") == 2 and report.stop_sent
    assert robot.motions()[-1].args[0] == pytest.approx(report.steps[1].motion.pose)
    assert robot.tcp_pose == pytest.approx(report.steps[0].motion.pose)  # never moved again


def test_lost_connection_without_reconnect_reports_it():
    robot = FakeRobot(disconnect_after=2, reconnect_succeeds=False)
    report = picker(robot)[0].pick(target())
    assert not report.ok and report.reason.startswith("close_gripper:")
    assert report.reconnect_attempted and not report.reconnected and not report.stop_sent
    methods = robot.methods()
    assert methods.count("reconnect") == 1
    assert methods.count("stopL") == 1
    assert methods.count("moveL") == 2
    assert robot.digital_outputs == {}


def test_disconnect_noticed_after_a_move_stops_before_the_next():
    robot = FakeRobot()
    p, _ = picker(robot)
    original = robot.control.moveL

    def move_then_drop(*args):
        done = original(*args)
        robot.connected = False
        robot.disconnect_raises = False
        return done

    robot.control.moveL = move_then_drop
    report = p.pick(target())
    assert not report.ok and "lost its connection" in report.reason
    assert robot.methods().count("moveL") == 1
    assert robot.methods().count("reconnect") == 1


def test_refused_move_stops_without_reconnecting():
    robot = FakeRobot(move_fails=True)
    report = picker(robot)[0].pick(target())
    assert not report.ok and "moveL was not completed" in report.reason
    assert robot.methods().count("moveL") == 1
    assert report.stop_sent and not report.reconnect_attempted
    assert robot.sent()[-1].method == "stopL"
    assert robot.sent()[-1].args == (2.0, False)


# --- deadlines ------------------------------------------------------------------------------

# Deadlines small enough to keep these tests fast, large enough that a fake call that
# returns at once never misses one on a loaded machine.
SHORT_DEADLINES = UR3Config(
    motion_timeout_factor=0.01,
    motion_timeout_margin_s=0.5,
    command_timeout_s=0.5,
    reconnect_timeout_s=0.5,
)


@pytest.mark.parametrize(
    ("distance", "expected_s"),
    [(0.0, 0.0), (0.1, 2 * math.sqrt(0.1 / 0.5)), (0.125, 1.0), (0.3, 0.3 / 0.25 + 0.25 / 0.5)],
)
def test_trapezoid_duration(distance, expected_s):
    # 0.25 m/s and 0.5 m/s^2 reach full speed after 0.0625 m: 0.125 m is the last triangle.
    assert trapezoid_duration_s(distance, 0.25, 0.5) == pytest.approx(expected_s)


def test_motion_deadline_is_factor_times_profile_plus_margin():
    config = UR3Config(motion_timeout_factor=3.0, motion_timeout_margin_s=1.5)
    approach, descend = plan_motions(target(yaw=0.3), config)[:2]
    # The descent: 0.1 m straight down, no turn.
    expected = 3.0 * trapezoid_duration_s(0.1, 0.25, 0.5) + 1.5
    assert motion_deadline_s(list(approach.pose), descend, config) == pytest.approx(expected)
    # A turn of 0.3 rad on the spot is paced like 0.3 m.
    start = [*approach.pose[:3], *tool_down_rotation_vector(0.0)]
    expected = 3.0 * trapezoid_duration_s(0.3, 0.25, 0.5) + 1.5
    assert motion_deadline_s(start, approach, config) == pytest.approx(expected)
    with pytest.raises(ValueError, match="motion_timeout_factor must be a positive number"):
        UR3Config(motion_timeout_factor=0.0)
    with pytest.raises(ValueError, match="motion_timeout_margin_s must be >= 0"):
        UR3Config(motion_timeout_margin_s=-1.0)


def test_move_that_never_returns_misses_its_deadline_stops_reconnects_once_and_fails():
    robot = FakeRobot(block_moves_after=1)  # the descent blocks, the link looks up
    p, sleeps = picker(robot, SHORT_DEADLINES)
    try:
        report = p.pick(target())
        assert not report.ok
        assert report.reason.startswith("descend: moveL did not return within"), report.reason
        assert "treated as lost" in report.reason
        assert [s.ok for s in report.steps] == [True, False]
        methods = robot.methods()
        blocked_move = [i for i, m in enumerate(methods) if m == "moveL"][1]
        after = methods[blocked_move + 1 :]
        assert after.index("stopL") < after.index("reconnect")
        # The control link reported itself up, yet it is the one reconnected, once.
        assert [c.interface for c in robot.calls if c.method == "reconnect"] == ["control"]
        assert report.stop_sent and report.reconnect_attempted and report.reconnected
        assert "setToolDigitalOut" not in after and sleeps == []

        # The picker sends nothing more, even on a link that reconnected.
        calls_before = len(robot.calls)
        with pytest.raises(RobotNotReadyError, match="moveL missed its deadline"):
            p.pick(target())
        assert robot.calls[calls_before:] == []
        p.close()
        assert "disconnect" not in robot.methods()  # retired, see UR3Picker.close
    finally:
        robot.release_blocked_moves.set()
    assert robot.methods().count("moveL") == 2
    assert robot.tcp_pose == pytest.approx(report.steps[0].motion.pose)


def test_stop_that_never_returns_counts_as_not_sent():
    robot = FakeRobot(move_fails=True)
    release = threading.Event()
    robot.control.stopL = lambda *args: release.wait()
    p, _ = picker(robot, SHORT_DEADLINES)
    try:
        report = p.pick(target())
    finally:
        release.set()
    assert not report.ok and "moveL was not completed" in report.reason
    assert not report.stop_sent and not report.reconnect_attempted
    assert robot.methods().count("moveL") == 1
    with pytest.raises(RobotNotReadyError, match="stopL missed its deadline"):
        p.pick(target())


def test_close_disconnects_healthy_links_and_retires_doubtful_ones():
    healthy = FakeRobot()
    with picker(healthy)[0] as p:
        assert p.pick(target()).ok
    assert healthy.methods()[-3:] == ["disconnect"] * 3

    protective = FakeRobot()
    original = protective.control.moveL

    def stop_on_descent(*args):
        protective.protective_stopped = len(protective.motions()) >= 1
        return original(*args)

    protective.control.moveL = stop_on_descent
    with picker(protective)[0] as p:
        assert not p.pick(target()).ok
    # A failure the robot's stop explains leaves the links trusted.
    assert protective.methods()[-3:] == ["disconnect"] * 3

    dropped = FakeRobot(disconnect_after=1)
    with picker(dropped)[0] as p:
        assert not p.pick(target()).ok
    assert "disconnect" not in dropped.methods()


# --- live robot (opt-in) ------------------------------------------------------------------


@pytest.mark.ur_live
@pytest.mark.usefixtures("hang_guard")
def test_live_pick_on_a_real_ur3():
    """Runs the full pick on UR_ROBOT_IP at UR_LIVE_TARGET="x,y,z[,yaw]" (metres, radians).

    Both must be set; the target must be a free spot on the table, since the arm goes
    down to it and closes the gripper. The picker's deadlines bound every command; the
    hang guard also ends the session if a ur_rtde call blocks while holding the GIL
    (the constructors do), so a dropped link cannot hang CI.
    """
    robot_ip = os.environ.get("UR_ROBOT_IP")
    spot = os.environ.get("UR_LIVE_TARGET")
    if not robot_ip or not spot:
        pytest.skip("set UR_ROBOT_IP and UR_LIVE_TARGET to run against a real robot")
    values = [float(v) for v in spot.split(",")]
    goal = target(*values[:3], yaw=values[3] if len(values) > 3 else 0.0)
    with UR3Picker(robot_ip, UR3Config(speed_m_s=0.1, acceleration_m_s2=0.3)) as p:
        report = p.pick(goal)
    assert report.ok, report.reason
    for step in report.steps:
        if step.motion.kind == "moveL":
            assert step.reached_pose[:3] == pytest.approx(step.motion.pose[:3], abs=2e-3)
