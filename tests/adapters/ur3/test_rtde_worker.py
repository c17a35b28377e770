"""The ur_rtde worker process behind :func:`adapters.ur3.driver.connect`, with the real
client against the fake controller: how it ends, and what a call sees once it has.

A worker killed from outside stands for any way it can die (a crash in ur_rtde, the OOM
killer): the user's process must see failed calls at once, never a hang or a crash.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from adapters.grasp.motions import UR3Config, plan_motions
from adapters.ur3.driver import RobotNotReadyError, UR3Picker, connect, retire_interfaces
from adapters.ur3.rtde_worker import WorkerEndedError
from schemas import PickReport
from tests.adapters.builders import grasp_target as target
from tests.adapters.ur3.test_network import process_exists
from tests.helpers import wait_until

pytest.importorskip("rtde_control", reason="needs the ur_rtde client")
pytestmark = pytest.mark.usefixtures("hang_guard")

REPO_ROOT = Path(__file__).resolve().parents[3]
UNUSED_LOOPBACK_HOST = "127.250.250.253"
"""No fake listens here: the conftest's addresses never end in .253."""
SLOW_MOTION = ("--time-scale", "100")
"""The fake's moves take 100x their real duration: the approach lasts well over a minute,
so a test can act while the picker's moveL is blocked in the worker."""


def child_pids() -> set[int]:
    """This process's children, zombies included (an unreaped worker counts)."""
    children = set()
    for stat in Path("/proc").glob("[0-9]*/stat"):
        with contextlib.suppress(OSError):
            if int(stat.read_text().rsplit(")", 1)[1].split()[1]) == os.getpid():
                children.add(int(stat.parent.name))
    return children


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads /proc")
def test_unreachable_robot_raises_as_ur_rtde_does_and_leaves_no_worker():
    before = child_pids()
    with pytest.raises(RuntimeError, match=f"Could not connect to: {UNUSED_LOOPBACK_HOST}"):
        connect(UNUSED_LOOPBACK_HOST)
    assert child_pids() <= before


def test_calls_after_the_worker_was_killed_raise_a_one_line_error(fake_ur):
    control, receive, io = connect(fake_ur.host)
    worker = control.worker
    assert receive.worker is worker and io.worker is worker
    assert control.isConnected() and receive.getSafetyMode() == 1

    os.kill(worker.pid, signal.SIGKILL)
    assert worker.wait_ended(timeout_s=10)
    for call in (control.isConnected, control.isProgramRunning, receive.getActualTCPPose):
        with pytest.raises(WorkerEndedError) as raised:
            call()
        message = str(raised.value)
        assert "\n" not in message and f"pid {worker.pid}" in message, message
    with pytest.raises(ConnectionError, match="has ended"):
        io.setToolDigitalOut(0, True)

    retire_interfaces((control, receive, io))
    assert worker.exitcode == -signal.SIGKILL and not process_exists(worker.pid)
    assert fake_ur.commands("setToolDigitalOut") == []


def test_calls_after_a_clean_close_raise_and_the_worker_exited_normally(fake_ur):
    with UR3Picker(fake_ur.host) as picker:
        control, receive, _ = picker.interfaces
        worker = control.worker
        assert picker.check(target())
    assert worker.exitcode == 0 and not process_exists(worker.pid)
    with pytest.raises(WorkerEndedError, match="has ended"):
        receive.isConnected()


def test_an_exception_inside_the_worker_comes_back_as_a_one_line_runtime_error(fake_ur):
    control, receive, _ = connect(fake_ur.host)
    try:
        with pytest.raises(RuntimeError, match=r"^AttributeError: .*noSuchMethod") as raised:
            control.worker.call("control", "noSuchMethod", 1)
        assert "\n" not in str(raised.value)
        # The worker keeps serving after a failed call.
        assert receive.isConnected()
    finally:
        control.worker.close()
    assert control.worker.exitcode == 0


KILLED_MID_PICK_CHILD = """
import sys
from adapters.grasp.motions import UR3Config
from adapters.ur3.driver import RobotNotReadyError, UR3Picker
from schemas import GraspTarget

host, goal = sys.argv[1], GraspTarget.model_validate_json(sys.argv[2])
# Deadlines far beyond the test: the pick can only end early because the worker died.
config = UR3Config(gripper_settle_s=0.05, motion_timeout_margin_s=600.0)
picker = UR3Picker(host, config)
picker.open()
print("WORKER", picker.interfaces[0].worker.pid, flush=True)
print("REPORT " + picker.pick(goal).model_dump_json(), flush=True)
try:
    picker.pick(goal)
except RobotNotReadyError as error:
    print("REFUSED", error, flush=True)
picker.close()
print("CLOSED", flush=True)
"""


class ChildProcess:
    """A Python child whose stdout is read line by line as it runs."""

    def __init__(
        self,
        code: str,
        *arguments: str,
        stderr_path: Path,
        script_dir: Path | None = None,
    ) -> None:
        """Run ``code`` with ``-c`` from the repository, or, given ``script_dir``, as the
        file ``script.py`` there (``python script.py``, cwd ``script_dir``, the
        repository importable through ``PYTHONPATH``): a user's own script."""
        self.stderr_path = stderr_path
        self.lines: list[str] = []
        command, cwd, env = [sys.executable, "-c", code], REPO_ROOT, None
        if script_dir is not None:
            (script_dir / "script.py").write_text(code)
            command, cwd = [sys.executable, "script.py"], script_dir
            path = os.environ.get("PYTHONPATH")
            env = {
                **os.environ,
                "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO_ROOT), path])),
            }
        with stderr_path.open("wb") as stderr:
            self.process = subprocess.Popen(
                [*command, *arguments],
                cwd=cwd,
                env=env,
                stdin=subprocess.PIPE,  # never written: a child reading it waits
                stdout=subprocess.PIPE,
                stderr=stderr,
                text=True,
            )

    def next_line(self, prefix: str) -> str:
        """The rest of the next stdout line starting with ``prefix`` (ur_rtde prints too)."""
        assert self.process.stdout is not None
        for line in self.process.stdout:
            self.lines.append(line.rstrip("\n"))
            if line.startswith(prefix):
                return line[len(prefix) :].strip()
        raise AssertionError(f"the child ended before printing {prefix!r}:\n{self.output()}")

    def output(self) -> str:
        return "\n".join(self.lines) + "\n--- stderr ---\n" + self.stderr_path.read_text()

    def wait(self, timeout: float) -> int:
        assert self.process.stdout is not None
        self.lines.extend(self.process.stdout.read().splitlines())
        return self.process.wait(timeout=timeout)

    def kill(self) -> None:
        if self.process.poll() is None:
            self.process.kill()
            self.process.wait()
        for stream in (self.process.stdin, self.process.stdout):
            if stream is not None:
                stream.close()


@pytest.mark.fake_ur_args(*SLOW_MOTION)
def test_worker_killed_mid_pick_fails_the_pick_at_once_and_the_process_exits_cleanly(
    fake_ur, tmp_path
):
    plan = plan_motions(target(), UR3Config())
    child = ChildProcess(
        KILLED_MID_PICK_CHILD,
        fake_ur.host,
        target().model_dump_json(),
        stderr_path=tmp_path / "child.stderr",
    )
    try:
        worker_pid = int(child.next_line("WORKER "))
        wait_until(lambda: fake_ur.state()["moving"], "the approach move to start")
        killed_at = time.monotonic()
        os.kill(worker_pid, signal.SIGKILL)
        report = PickReport.model_validate_json(child.next_line("REPORT "))
        reported_after_s = time.monotonic() - killed_at
        refusal = child.next_line("REFUSED ")
        child.next_line("CLOSED")
        returncode = child.wait(timeout=60)
    finally:
        child.kill()

    # The blocked moveL failed as soon as the worker died, not at its deadline (600 s on
    # top of a move that lasts over a minute here); stopL and the one reconnect failed
    # at once as well.
    assert reported_after_s < 10.0, (reported_after_s, child.output())
    assert not report.ok and report.reason.startswith("approach:"), report.reason
    assert f"worker process (pid {worker_pid})" in report.reason
    assert [step.ok for step in report.steps] == [False]
    assert not report.stop_sent and report.reconnect_attempted and not report.reconnected
    # Later picks are refused by the pre-checks (the links cannot be read), nothing sent.
    assert refusal.startswith("could not read the robot state: WorkerEndedError"), refusal
    assert [e["executed"] for e in fake_ur.commands("moveL")] == [True]
    assert fake_ur.commands("setToolDigitalOut") == []
    assert fake_ur.commands("moveL")[0]["pose"] == list(plan[0].pose)
    assert returncode == 0, child.output()
    assert not process_exists(worker_pid)


def test_a_picker_whose_worker_died_refuses_then_reopens_with_a_fresh_worker(fake_ur):
    # The worker dies between picks: the next pick's pre-checks cannot read the robot.
    picker = UR3Picker(fake_ur.host, UR3Config(gripper_settle_s=0.05))
    picker.open()
    first = picker.interfaces[0].worker
    os.kill(first.pid, signal.SIGKILL)
    assert first.wait_ended(timeout_s=10)
    with pytest.raises(RobotNotReadyError, match=r"could not read the robot state.*has ended"):
        picker.pick(target())
    picker.close()
    assert first.exitcode == -signal.SIGKILL and not process_exists(first.pid)
    assert fake_ur.commands("moveL") == []

    # The next pick connects again, through a fresh worker, and works.
    report = picker.pick(target())
    second = picker.interfaces[0].worker
    picker.close()
    assert report.ok, report.reason
    assert second.pid != first.pid
    assert second.exitcode == 0 and not process_exists(second.pid)


CONNECT_AND_WAIT_CHILD = """
import sys
from adapters.ur3.driver import connect

control, receive, io = connect(sys.argv[1])
print("WORKER", control.worker.pid, flush=True)
sys.stdin.read()  # until the test kills this process
"""


def process_running(pid: int) -> bool:
    """Whether ``pid`` exists and is not a zombie (an orphan's zombie may wait for a
    container's init to reap it)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except FileNotFoundError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads /proc")
def test_the_worker_ends_when_its_parent_is_killed(fake_ur, tmp_path):
    child = ChildProcess(CONNECT_AND_WAIT_CHILD, fake_ur.host, stderr_path=tmp_path / "err")
    try:
        worker_pid = int(child.next_line("WORKER "))
        assert process_running(worker_pid)
        assert child.process.poll() is None  # still waiting on its stdin
        child.process.kill()  # no close, no atexit: the worker only sees its pipe close
        child.process.wait(timeout=10)
    finally:
        child.kill()
    wait_until(lambda: not process_running(worker_pid), "the orphaned worker to exit")


USER_SCRIPT = """
# A user's plain script: it connects at top level, with no `if __name__ == "__main__":`.
import os
import sys

from adapters.grasp.motions import UR3Config
from adapters.ur3.driver import UR3Picker
from schemas import GraspTarget

host, goal = sys.argv[1], GraspTarget.model_validate_json(sys.argv[2])
picker = UR3Picker(host, UR3Config(gripper_settle_s=0.05))
picker.open()
worker = picker.interfaces[0].worker
print("WORKER", worker.pid, flush=True)
report = picker.pick(goal)
picker.close()
print("REPORT " + report.model_dump_json(), flush=True)
print("EXITCODE", worker.exitcode, flush=True)
"""


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads /proc")
def test_a_plain_user_script_without_a_main_guard_picks(fake_ur, tmp_path):
    script_dir = tmp_path / "user"
    script_dir.mkdir()
    child = ChildProcess(
        USER_SCRIPT,
        fake_ur.host,
        target().model_dump_json(),
        stderr_path=tmp_path / "child.stderr",
        script_dir=script_dir,
    )
    try:
        worker_pid = int(child.next_line("WORKER "))
        report = PickReport.model_validate_json(child.next_line("REPORT "))
        exitcode = child.next_line("EXITCODE ")
        returncode = child.wait(timeout=60)
    finally:
        child.kill()
    assert report.ok, (report.reason, child.output())
    assert exitcode == "0", child.output()
    assert returncode == 0, child.output()
    assert not process_running(worker_pid)
    moves = fake_ur.commands("moveL")
    assert moves and all(move["executed"] for move in moves), moves
