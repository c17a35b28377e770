"""UR3Picker through the real ur_rtde client against a fake UR controller on loopback.

Each test starts :mod:`adapters.ur3.fake_controller` in a subprocess on its own
address (fixture ``fake_ur``) and drives it with :func:`adapters.ur3.driver.connect`, i.e.
ur_rtde's ``RTDEControlInterface``, ``RTDEReceiveInterface`` and ``RTDEIOInterface``.
What the controller received is read back from the fake's log: the command codes the
control script was given, the registers' pose, speed and acceleration, and the
digital outputs the IO interface set.
"""

from __future__ import annotations

import math
import os
import signal
import socket
import struct
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

from adapters.errors import UnsafeTargetError
from adapters.grasp.motions import GripperOutput, UR3Config, plan_motions
from adapters.ur3.driver import RobotNotReadyError, UR3Picker, motion_deadline_s
from adapters.ur3.fake_controller.robot import trapezoid_duration, trapezoid_fraction
from adapters.ur3.fake_controller.rtde import HEADER, package, variable_type
from schemas import GraspTarget, PickReport
from tests.adapters.builders import grasp_target as target
from tests.helpers import wait_until

pytest.importorskip("rtde_control", reason="needs the ur_rtde client")
pytestmark = pytest.mark.usefixtures("hang_guard")

REPO_ROOT = Path(__file__).resolve().parents[3]
ACTUATING = ("moveL", "stopL", "stopJ", "setToolDigitalOut", "setStandardDigitalOut")


def picker(host: str, config: UR3Config | None = None) -> UR3Picker:
    # The gripper settle time is real time here; keep it short.
    return UR3Picker(host, config or UR3Config(gripper_settle_s=0.05))


def moves(entries: list[dict]) -> list[tuple[list[float], float, float]]:
    return [(e["pose"], e["speed"], e["acceleration"]) for e in entries if e["command"] == "moveL"]


# --- the fake itself, spoken to by hand (no ur_rtde) -------------------------------------


@pytest.mark.parametrize(("distance", "expected_s"), [(0.1, 2 * math.sqrt(0.1 / 0.5)), (0.3, 1.7)])
def test_trapezoid_profile_of_simulated_moves(distance, expected_s):
    # 0.25 m/s, 0.5 m/s^2: 0.125 m to reach full speed and stop; shorter is triangular.
    assert trapezoid_duration(distance, 0.25, 0.5) == pytest.approx(expected_s)
    assert trapezoid_fraction(0.0, distance, 0.25, 0.5) == 0.0
    assert trapezoid_fraction(expected_s / 2, distance, 0.25, 0.5) == pytest.approx(0.5)
    assert trapezoid_fraction(expected_s, distance, 0.25, 0.5) == 1.0
    samples = [trapezoid_fraction(t / 100 * expected_s, distance, 0.25, 0.5) for t in range(101)]
    assert samples == sorted(samples)


def test_rtde_variable_types():
    assert variable_type("actual_TCP_pose") == "VECTOR6D"
    assert variable_type("safety_status_bits") == "UINT32"
    assert variable_type("input_int_register_47") == "INT32"
    assert variable_type("input_int_register_48") is None
    assert variable_type("output_bit_register_64") == "BOOL"
    assert variable_type("output_bit_register_0") is None  # 0-63: fieldbus/PLC, not RTDE
    assert variable_type("no_such_field") is None


def rtde_exchange(sock: socket.socket, command: str, payload: bytes = b"") -> tuple[str, bytes]:
    """Send one RTDE package and read the next package back: (command, payload)."""
    sock.sendall(package(ord(command), payload))
    return read_package(sock)


def read_package(sock: socket.socket) -> tuple[str, bytes]:
    header = b""
    while len(header) < HEADER.size:
        header += sock.recv(HEADER.size - len(header))
    size, command = HEADER.unpack(header)
    payload = b""
    while len(payload) < size - HEADER.size:
        payload += sock.recv(size - HEADER.size - len(payload))
    return chr(command), payload


def test_rtde_handshake_recipes_and_data_packages(fake_ur):
    with socket.create_connection((fake_ur.host, 30004), timeout=10) as sock:
        assert rtde_exchange(sock, "V", struct.pack(">H", 2)) == ("V", b"\x01")
        command, payload = rtde_exchange(sock, "v")
        assert command == "v" and struct.unpack(">IIII", payload)[0] == 5
        # An unknown field makes the whole output recipe fail, as on a controller.
        names = b"timestamp,actual_TCP_pose,no_such_field"
        command, payload = rtde_exchange(sock, "O", struct.pack(">d", 125.0) + names)
        assert (command, payload) == ("O", b"\x00DOUBLE,VECTOR6D,NOT_FOUND")
        names = b"actual_TCP_pose,safety_status_bits,runtime_state,output_int_register_0"
        command, payload = rtde_exchange(sock, "O", struct.pack(">d", 125.0) + names)
        assert (command, payload) == ("O", b"\x01VECTOR6D,UINT32,UINT32,INT32")
        command, payload = rtde_exchange(sock, "I", b"tool_digital_output_mask,tool_digital_output")
        assert (command, payload) == ("I", b"\x01UINT8,UINT8")
        assert rtde_exchange(sock, "S") == ("S", b"\x01")
        command, payload = read_package(sock)
        assert command == "U" and payload[0] == 1
        pose_and_bits = struct.unpack(">6dIIi", payload[1:])
        assert list(pose_and_bits[:6]) == pytest.approx([0.3, 0.0, 0.3, math.pi, 0.0, 0.0])
        assert pose_and_bits[6:] == (1, 1, 0)  # normal mode; runtime stopped; no script
        # Input recipe 1: mask 0b10, level 0b10 sets tool output 1.
        sock.sendall(package(ord("U"), bytes([1]) + struct.pack(">BB", 2, 2)))
        sock.sendall(package(ord("P")))
        while read_package(sock) != ("P", b"\x01"):  # data packages may still be queued
            pass
    assert fake_ur.state()["digital_outputs"] == 1 << 17
    outputs = fake_ur.commands("setToolDigitalOut")
    assert [(e["index"], e["level"], e["executed"]) for e in outputs] == [(1, True, True)]


def test_dashboard_welcome_and_sigterm_shutdown(fake_ur):
    with socket.create_connection((fake_ur.host, 29999), timeout=10) as sock:
        stream = sock.makefile("rwb")
        assert stream.readline() == b"Connected: Universal Robots Dashboard Server\n"
        stream.write(b"robotmode\n")
        stream.flush()
        assert stream.readline() == b"Robotmode: RUNNING\n"
    fake_ur.process.send_signal(signal.SIGTERM)
    assert fake_ur.process.wait(timeout=10) == 0


# --- the real ur_rtde client ----------------------------------------------------------


def test_full_pick_sends_the_exact_moves_and_closes_the_gripper(fake_ur):
    goal = target()
    plan = plan_motions(goal, UR3Config())
    with picker(fake_ur.host) as p:
        report = p.pick(goal)

    assert report.ok, report.reason
    log = fake_ur.commands(*ACTUATING, "isPoseWithinSafetyLimits")
    # Registers carry IEEE doubles, so the controller gets the planned values exactly.
    planned_moves = [(list(m.pose), 0.25, 0.5) for m in plan if m.kind == "moveL"]
    assert moves(log) == planned_moves
    assert [(e["command"], e.get("code")) for e in log] == [
        ("isPoseWithinSafetyLimits", 36),
        ("isPoseWithinSafetyLimits", 36),
        ("isPoseWithinSafetyLimits", 36),
        ("moveL", 3),
        ("moveL", 3),
        ("setToolDigitalOut", None),
        ("moveL", 3),
    ]
    assert all(e["executed"] and not e.get("asynchronous", False) for e in log)
    assert [e["pose"] for e in log[:3]] == [list(m.pose) for m in plan if m.pose is not None]
    gripper = log[5]
    assert (gripper["index"], gripper["level"]) == (0, True)

    state = fake_ur.state()
    assert state["digital_outputs"] == 1 << 16  # tool output 0
    assert state["tcp_pose"] == list(plan[-1].pose)
    assert state["program_running"]
    # reached_pose is getActualTCPPose from the receive link, which lags the control
    # link's "done" by at least one package (more on a loaded machine): only its shape
    # is checked; the controller's own final pose is checked exactly above.
    assert all(len(step.reached_pose or ()) == 6 for step in report.steps)


def test_standard_output_gripper_and_slow_speed(fake_ur):
    config = UR3Config(
        speed_m_s=0.1,
        acceleration_m_s2=0.3,
        gripper_settle_s=0.05,
        gripper=GripperOutput(kind="standard", index=5, close_value=False),
    )
    with picker(fake_ur.host, config) as p:
        p.open()
        # Set output 5 first, so closing (level False) visibly changes it.
        p.interfaces[2].setStandardDigitalOut(5, True)
        wait_until(lambda: fake_ur.state()["digital_outputs"] == 1 << 5)
        report = p.pick(target())

    assert report.ok, report.reason
    outputs = fake_ur.commands("setStandardDigitalOut")
    assert [(e["index"], e["level"]) for e in outputs] == [(5, True), (5, False)]
    assert fake_ur.state()["digital_outputs"] == 0
    assert {(speed, acceleration) for _, speed, acceleration in moves(fake_ur.commands())} == {
        (0.1, 0.3)
    }


def test_robot_not_ready_is_refused_before_any_motion(fake_ur):
    # One connection for all three states (each connect/close costs ur_rtde ~2 s):
    # protective stop, then released; program stopped; emergency stop.
    with picker(fake_ur.host) as p:
        p.open()  # connected while the robot was fine; then it stops
        control, receive, _ = p.interfaces
        for op, client_sees_it, message in (
            ("protective_stop", receive.isProtectiveStopped, "protective stopped"),
            ("stop_program", lambda: not control.isProgramRunning(), "script is not running"),
            ("emergency_stop", receive.isEmergencyStopped, "emergency stopped"),
        ):
            fake_ur.request(op)
            # The client learns the new state from the next RTDE package (<= 8 ms later).
            wait_until(client_sees_it)
            with pytest.raises(RobotNotReadyError, match=message):
                p.pick(target())
            if op == "protective_stop":
                fake_ur.request("release")
                wait_until(lambda: not receive.isProtectiveStopped())
    assert fake_ur.commands(*ACTUATING) == []
    assert fake_ur.state()["tcp_pose"][:3] == [0.3, 0.0, 0.3]


def test_pose_outside_the_controller_safety_limits_is_refused_with_nothing_sent(fake_ur):
    # The controller's own limits (not the adapter's workspace) reject the descent.
    fake_ur.request("set", fields={"safety_min_z_m": 0.05})
    with picker(fake_ur.host) as p, pytest.raises(UnsafeTargetError, match="descend pose"):
        p.pick(target())
    checks = fake_ur.commands("isPoseWithinSafetyLimits")
    assert [e["result"] for e in checks] == [True, False]
    assert fake_ur.commands(*ACTUATING) == []


# ur_rtde 1.6.5 is not robust to a link that drops mid-command: it aborts its process
# (std::terminate on "write: Broken pipe" or "read: End of file") when an interface
# whose socket died is disconnected or destroyed, its background threads were seen to
# crash a process at exit (SIGSEGV), and its synchronous moveL blocks forever once the
# controller refuses connections. The picker avoids all three (ur_rtde runs in a worker
# process, killed rather than disconnected after such a failure, and each command is
# waited for at most a deadline), but the pick still runs in a child process here, so a
# regression cannot take the test session down; the child prints its worker's pid and
# the report before it closes the picker, and exits normally (interpreter shutdown is
# where an abort or a crash would show).
PICK_IN_CHILD = """
import sys
from adapters.grasp.motions import UR3Config
from adapters.ur3.driver import UR3Picker
from schemas import GraspTarget

host, goal = sys.argv[1], GraspTarget.model_validate_json(sys.argv[2])
picker = UR3Picker(host, UR3Config(gripper_settle_s=0.05))
picker.open()
print("WORKER", picker.interfaces[0].worker.pid, flush=True)
report = picker.pick(goal)
print("REPORT " + report.model_dump_json(), flush=True)
picker.close()
print("CLOSED", flush=True)
"""


@dataclass
class ChildPick:
    report: PickReport | None
    """None when ``pick`` never returned."""
    closed: bool
    returncode: int | None
    output: str
    worker_pid: int | None
    """The pid of the child's ur_rtde worker process; None when it never connected."""

    @property
    def worker_gone(self) -> bool:
        """Whether the worker process no longer exists (the child exited and was reaped)."""
        assert self.worker_pid is not None, self.output
        return not process_exists(self.worker_pid)


def process_exists(pid: int) -> bool:
    """Whether a process ``pid`` exists (a zombie counts: it was not reaped)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def pick_in_child(host: str, goal: GraspTarget, timeout: float) -> ChildPick:
    """Run a pick with the real client in a child process; None fields when it died/hung."""
    command = [sys.executable, "-c", PICK_IN_CHILD, host, goal.model_dump_json()]
    try:
        done = subprocess.run(
            command, cwd=REPO_ROOT, capture_output=True, text=True, timeout=timeout, check=False
        )
        output, returncode = done.stdout + done.stderr, done.returncode
    except subprocess.TimeoutExpired as expired:
        output = _text(expired.stdout) + _text(expired.stderr)
        returncode = None
    lines = output.splitlines()
    report_lines = [line for line in lines if line.startswith("REPORT ")]
    report = PickReport.model_validate_json(report_lines[0][7:]) if report_lines else None
    worker_lines = [line.split()[1] for line in lines if line.startswith("WORKER ")]
    worker_pid = int(worker_lines[0]) if worker_lines else None
    return ChildPick(report, "CLOSED" in lines, returncode, output, worker_pid)


def _text(data: bytes | str | None) -> str:
    return data.decode(errors="replace") if isinstance(data, bytes) else data or ""


def test_dropped_rtde_link_mid_sequence_fails_and_never_resumes(fake_ur):
    plan = plan_motions(target(), UR3Config())
    # The RTDE links drop as the second move (the descent) reaches the controller.
    fake_ur.request("arm", event="drop", after_commands=1, reconnect=True, scope="rtde")
    child = pick_in_child(fake_ur.host, target(), timeout=60)

    report = child.report
    assert report is not None, child.output
    assert not report.ok
    assert report.reason.startswith("descend:"), report.reason
    assert [s.ok for s in report.steps] == [True, False]
    # On loopback a reconnect works. Whether the picker needs one depends on whether
    # the receive link has noticed the drop yet (ur_rtde's control link reconnects by
    # itself inside moveL; the IO link has no reader and never notices).
    assert report.reconnected == report.reconnect_attempted
    assert child.closed and child.returncode == 0 and child.worker_gone, child.output
    log = fake_ur.commands()
    drop = next(i for i, e in enumerate(log) if e.get("event") == "drop")
    before, after = log[:drop], log[drop + 1 :]
    assert moves(before) == [(list(plan[0].pose), 0.25, 0.5), (list(plan[1].pose), 0.25, 0.5)]
    assert [e["executed"] for e in before if e["command"] == "moveL"] == [True, False]
    # At most two new RTDE links: ur_rtde's control interface reconnecting by itself
    # inside moveL, and the picker's single reconnect of the receive interface.
    rtde_connects = [e for e in after if e["command"] == "connect" and e["port"] == 30004]
    assert 1 <= len(rtde_connects) <= 2
    # Nothing moved or switched after the drop. What reaches the controller depends on
    # timing inside ur_rtde's own reconnect: the control script runs the picker's
    # stopL; or ur_rtde has already stopped its script (code 255, then the dashboard's
    # "stop") and drops the stopL client-side or writes it to a register no script
    # reads (logged as not executed); or, under load, the stopL is dropped client-side
    # before ur_rtde's reconnect completes. The arm is idle in every case, since the
    # descent never started.
    sent_after = [e["command"] for e in after if e["command"] in (*ACTUATING, "stopScript")]
    assert set(sent_after) <= {"stopL", "stopScript"}, sent_after
    # report.stop_sent is not compared with the log: it is the client's belief
    # (isProgramRunning after stopL), and right after ur_rtde's internal reconnect that
    # cached state was seen wrong in both directions.
    if "stopScript" in sent_after:
        # The script ends once it has read the stop (a moment after logging it), unless
        # ur_rtde's reconnect uploaded its control script again after stopping it.
        wait_until(
            lambda: _program_running_as_logged(fake_ur.state(), drop),
            "the program state to follow the last stop or upload",
        )
    state = fake_ur.state()
    assert not state["moving"]
    assert state["tcp_pose"] == list(plan[0].pose)
    assert state["digital_outputs"] == 0


def _program_running_as_logged(state: dict, drop: int) -> bool:
    """Whether ``program_running`` is what the log after entry ``drop`` implies: a stop
    ends the program, a control script uploaded after it runs again."""
    after = state["log"][drop + 1 :]
    last_stop = max(i for i, e in enumerate(after) if e["command"] == "stopScript")
    uploads = [e for e in after[last_stop + 1 :] if e["command"] == "script"]
    return state["program_running"] == any(e["started"] for e in uploads)


def test_closing_the_interfaces_after_a_dropped_link_does_not_abort(fake_ur):
    # Closing used to abort the process here: ur_rtde's disconnect and destructors
    # write to the dead sockets. Then the picker leaked the interfaces instead, and
    # their threads sometimes crashed the process at exit (SIGSEGV, exit -11). Now
    # UR3Picker.close kills the worker process that holds them.
    fake_ur.request("arm", event="drop", after_commands=1, reconnect=True, scope="rtde")
    child = pick_in_child(fake_ur.host, target(), timeout=60)
    assert child.report is not None and not child.report.ok, child.output
    assert child.returncode not in (-signal.SIGABRT, -signal.SIGSEGV), child.output
    assert child.closed and child.returncode == 0, child.output
    assert child.worker_gone, child.output


def test_dropped_link_of_every_connection_never_resumes(fake_ur):
    """Every socket drops (RTDE, script, dashboard) and the controller accepts again.

    ur_rtde's moveL reconnects by itself and returns False; the pick fails. Closing
    the interfaces used to abort the process (ur_rtde's disconnect and destructors
    write to the dead port-30003 socket: std::terminate, "write: Broken pipe", exit
    status -6); the picker now kills the worker process that holds them (see
    ``UR3Picker.close``), so the child closes, exits normally, and leaves no worker.
    ur_rtde's control interface may have reconnected and uploaded its script before the
    kill; it never moves the arm.
    """
    plan = plan_motions(target(), UR3Config())
    fake_ur.request("arm", event="drop", after_commands=1, reconnect=True, scope="all")
    child = pick_in_child(fake_ur.host, target(), timeout=60)

    assert child.report is not None, "the pick never returned:\n" + child.output
    assert not child.report.ok and child.report.reason.startswith("descend:")
    assert child.closed and child.returncode == 0, child.output
    assert child.worker_gone, child.output
    log = fake_ur.commands()
    drop = next(i for i, e in enumerate(log) if e.get("event") == "drop")
    assert [e["executed"] for e in log[:drop] if e["command"] == "moveL"] == [True, False]
    after = [e["command"] for e in log[drop + 1 :]]
    assert "moveL" not in after and "setToolDigitalOut" not in after
    assert fake_ur.state()["tcp_pose"] == list(plan[0].pose)


def test_link_that_stays_down_is_reported_as_a_failure(fake_ur):
    """Every socket drops and the ports then refuse connections.

    ur_rtde 1.6.5's synchronous moveL never returns here (its internal reconnect fails
    on the dashboard port; waited 60 s). The picker's deadline for the descent turns
    that into a failed report; stopL and the reconnect fail within their own deadlines.
    """
    config = UR3Config()
    plan = plan_motions(target(), config)
    fake_ur.request("arm", event="drop", after_commands=1, reconnect=False, scope="all")
    child = pick_in_child(fake_ur.host, target(), timeout=30)

    assert child.report is not None, "the pick never returned:\n" + child.output
    report = child.report
    assert not report.ok, report.reason
    # The picker gave up on its own deadline for the descent (not on ur_rtde, which
    # never returns here), and stopL and the reconnect failed within theirs.
    descent_deadline = motion_deadline_s(plan[0].pose, plan[1], config)
    expected = f"descend: moveL did not return within {descent_deadline:.2f} s"
    assert report.reason.startswith(expected), report.reason
    assert report.reconnect_attempted and not report.reconnected and not report.stop_sent
    assert child.closed and child.returncode == 0, child.output
    assert child.worker_gone, child.output
    assert [e["executed"] for e in fake_ur.commands("moveL")] == [True, False]
    assert fake_ur.commands("stopL", "setToolDigitalOut") == []
    assert fake_ur.state()["tcp_pose"] == list(plan[0].pose)


def test_protective_stop_during_the_sequence_stops_and_fails(fake_ur):
    plan = plan_motions(target(), UR3Config())
    fake_ur.request("arm", event="protective_stop", after_commands=1)
    with picker(fake_ur.host) as p:
        report = p.pick(target())

    assert not report.ok and report.reason.startswith("descend:"), report.reason
    assert not report.reconnect_attempted
    assert [e["executed"] for e in fake_ur.commands("moveL")] == [True, False]
    assert fake_ur.commands("setToolDigitalOut") == []
    state = fake_ur.state()
    assert state["protective_stopped"]
    assert state["tcp_pose"] == list(plan[0].pose)


@pytest.mark.slow
@pytest.mark.fake_ur_args("--refuse-programs")
def test_control_script_that_never_starts_is_not_ready(fake_ur):
    # ur_rtde waits (5 s) for its uploaded script to run, then gives up.
    with pytest.raises(RobotNotReadyError, match="could not read the robot state"):
        picker(fake_ur.host).pick(target())
    assert fake_ur.commands("script")[0]["started"] is False
    assert fake_ur.commands(*ACTUATING) == []
