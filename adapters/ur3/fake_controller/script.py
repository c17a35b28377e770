"""ur_rtde's control script, played: the controller side of its register handshake."""

from __future__ import annotations

import re
import threading
from typing import Any, Protocol

from adapters.ur3.fake_controller.robot import RobotState

SCRIPT_COMMANDS = {
    1: "moveJ",
    2: "moveJ_IK",
    3: "moveL",
    4: "moveL_FK",
    31: "triggerProtectiveStop",
    33: "stopL",
    34: "stopJ",
    36: "isPoseWithinSafetyLimits",
    255: "stopScript",
}
"""The codes ur_rtde's control script reads from its command register that this fake
acts on (learned from the script ur_rtde 1.6 uploads). Other codes are logged and
acknowledged without effect."""

REALTIME_COMMANDS = frozenset({6, 9, 10, 11, 24, 25, 26, 27, 38, 58, 66, 67, 68, 69, 70, 71})
"""Codes the script answers with "ready" at once instead of "done" (servo/speed
streaming and fast getters)."""

ACTUATING_COMMANDS = frozenset(
    {"moveJ", "moveJ_IK", "moveL", "moveL_FK", "stopL", "stopJ", "setStandardDigitalOut"}
    | {"setToolDigitalOut", "setConfigurableDigitalOut"}
)
"""Commands that make the robot do something; triggers count these."""

SCRIPT_CYCLE_S = 0.004
"""How often the simulated control script polls its command register when nothing
wakes it (the real one runs every controller cycle, 2 ms)."""
REGISTER_OFFSET_PATTERN = re.compile(r"reg_offset_int\s*=\s*(?:#[^\n]*\n)?\s*(\d+)")


class ScriptHost(Protocol):
    """What the script needs of the controller it runs on (:class:`~.controller.FakeController`)."""

    lock: Any
    state: RobotState

    def wake(self) -> None: ...
    def wait_for_change(self, timeout: float) -> None: ...
    def is_protective_stopped(self) -> bool: ...
    def receive_command(self, entry: dict[str, Any]) -> bool: ...
    def pose_within_safety_limits(self, pose: list[float]) -> bool: ...
    def move_linear(
        self, goal: list[float], speed: float, acceleration: float, script: ControlScript
    ) -> None: ...
    def halt_motion(self) -> None: ...
    def protective_stop(self) -> None: ...
    def script_ended(self, script: ControlScript) -> None: ...


class ControlScript:
    """Plays the controller side of ur_rtde's control script.

    The real script loops once per controller cycle: it reads the command register
    (``input_int_register_<offset>``); 0 means idle, and it answers "ready" (1) in
    ``output_int_register_<offset>``. A non-zero code is executed once (a blocking
    ``movel`` for moveL), then the script answers "done" (2) and waits for the client
    to clear the register. Real-time codes answer "ready" directly. Code 255 ends the
    script. Arguments come from ``input_double_register_<offset>+0..`` (pose, then
    speed and acceleration in 6 and 7) and ``input_int_register_<offset>+1``
    (asynchronous flag); results go to ``output_int_register_<offset>+1``.

    Parameters
    ----------
    controller
        The simulated controller whose registers and robot the script uses.
    name
        The program's name (``rtde_control``), for the dashboard's ``programState``.
    register_offset
        The script's ``reg_offset_int``: 0, or 24 with ur_rtde's upper register range.
    """

    def __init__(self, controller: ScriptHost, name: str, register_offset: int) -> None:
        self.controller = controller
        self.name = name
        self.offset = register_offset
        self.stopped = threading.Event()
        self.thread = threading.Thread(target=self._run, name=f"script-{name}", daemon=True)

    def start(self) -> None:
        self.thread.start()

    def stop(self) -> None:
        """End the script (a new program, the dashboard ``stop``, an e-stop)."""
        self.stopped.set()
        self.controller.wake()

    def _int_in(self, index: int) -> int:
        return int(self.controller.state.inputs.get(f"input_int_register_{self.offset + index}", 0))

    def _double_in(self, index: int) -> float:
        key = f"input_double_register_{self.offset + index}"
        return float(self.controller.state.inputs.get(key, 0.0))

    def _int_out(self, index: int, value: int) -> None:
        self.controller.state.outputs[f"output_int_register_{self.offset + index}"] = value

    def _run(self) -> None:
        controller = self.controller
        with controller.lock:
            self._int_out(0, 1)  # signal_ready
        executing = False
        while not self.stopped.is_set():
            controller.wait_for_change(SCRIPT_CYCLE_S)
            with controller.lock:
                if self.stopped.is_set():
                    break
                if controller.state.protective_stopped:
                    continue  # a protective stop pauses the program
                code = self._int_in(0)
                if code in REALTIME_COMMANDS:
                    self._execute(code)
                    self._int_out(0, 1)
                    continue
                if code == 0:
                    executing = False
                    self._int_out(0, 1)
                    continue
                if executing:
                    continue
                executing = True
            # Executed outside the lock: a moveL blocks for the duration of the motion.
            outcome = self._execute(code)
            # A protective stop pauses the program: "done" only follows a release.
            while controller.is_protective_stopped() and not self.stopped.is_set():
                controller.wait_for_change(SCRIPT_CYCLE_S)
            with controller.lock:
                if outcome == "end":
                    break
                if outcome == "lost":
                    executing = False  # never arrived: idle again, "ready" next cycle
                elif not self.stopped.is_set():
                    self._int_out(0, 2)  # signal_done_with_cmd
        controller.script_ended(self)

    def _execute(self, code: int) -> str:
        """Run one command.

        Returns
        -------
        str
            ``"done"``; ``"end"`` when it ends the script; ``"lost"`` when an armed
            trigger fired as it arrived: the command is then treated as never received
            (its register is cleared), as a package lost with a dropped link would be.
        """
        controller = self.controller
        name = SCRIPT_COMMANDS.get(code, f"code_{code}")
        with controller.lock:
            pose = [self._double_in(i) for i in range(6)]
            entry: dict[str, Any] = {"command": name, "code": code}
            if name == "moveL":
                entry.update(
                    pose=pose,
                    speed=self._double_in(6),
                    acceleration=self._double_in(7),
                    asynchronous=self._int_in(1) == 1,
                )
            elif name in ("stopL", "stopJ"):
                entry.update(deceleration=self._double_in(0), asynchronous=self._int_in(1) == 1)
            elif name == "isPoseWithinSafetyLimits":
                within = controller.pose_within_safety_limits(pose)
                entry.update(pose=pose, result=within)
                self._int_out(1, 1 if within else 0)
            if not controller.receive_command(entry):
                controller.state.inputs[f"input_int_register_{self.offset}"] = 0
                return "lost"
        if name == "moveL":
            controller.move_linear(entry["pose"], entry["speed"], entry["acceleration"], self)
        elif name in ("stopL", "stopJ"):
            controller.halt_motion()
        elif name == "triggerProtectiveStop":
            controller.protective_stop()
        return "end" if name == "stopScript" else "done"
