"""A fake Universal Robots controller on the network, for driving the real ur_rtde client.

It listens on one loopback address, on the controller's fixed ports:

* **30004, RTDE**: protocol version 2 (``V``), controller version (``v``), output and
  input recipe setup (``O``/``I``), start/pause (``S``/``P``), and data packages
  (``U``) both ways; every package starts with the header ``>HB`` (uint16 size
  including the header, uint8 command). Output packages are streamed to each started
  client from the simulated robot state.
* **30003, script**: accepts the URScript program a client writes. A program that
  reads the command register (``read_input_integer_register``) is taken to be
  ur_rtde's control script: the fake then plays that script's side of the register
  handshake (see :class:`ControlScript`).
* **29999, dashboard**: the welcome line and the few queries ur_rtde makes.
* **a JSON control channel** (``--control-port``, default 30999) for tests: read the
  state and the log of commands received, trigger a protective stop, an emergency
  stop or a dropped connection, and shut down. One JSON object per line each way.

The simulated robot has a TCP pose that ``moveL`` moves along a straight line with a
trapezoidal speed profile (optionally faster than real time, ``--time-scale``), robot
mode, safety mode/status bits, runtime state, digital outputs, protective and
emergency stops, and a link that can drop.

It must run in its own process: ur_rtde's constructors hold the GIL while they wait
for the controller, so a fake in a thread of the client's process deadlocks.

Examples
--------
``python -m adapters.fake_ur_controller --host 127.0.0.2 --time-scale 0.2``
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import re
import signal
import socket
import struct
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

RTDE_PORT = 30004
SCRIPT_PORT = 30003
DASHBOARD_PORT = 29999
DEFAULT_CONTROL_PORT = 30999

HEADER = struct.Struct(">HB")
"""Every RTDE package: total size in bytes (header included), command byte."""

# RTDE command bytes.
REQUEST_PROTOCOL_VERSION = ord("V")
GET_URCONTROL_VERSION = ord("v")
TEXT_MESSAGE = ord("M")
DATA_PACKAGE = ord("U")
SETUP_OUTPUTS = ord("O")
SETUP_INPUTS = ord("I")
START = ord("S")
PAUSE = ord("P")

# RTDE type names and their big-endian struct codes.
TYPE_FORMATS = {
    "BOOL": "?",
    "UINT8": "B",
    "UINT32": "I",
    "UINT64": "Q",
    "INT32": "i",
    "DOUBLE": "d",
    "VECTOR3D": "3d",
    "VECTOR6D": "6d",
    "VECTOR6INT32": "6i",
    "VECTOR6UINT32": "6I",
}

# Robot modes, safety modes and runtime states as the RTDE guide numbers them.
ROBOT_MODE_POWER_OFF, ROBOT_MODE_RUNNING = 3, 7
SAFETY_NORMAL, SAFETY_PROTECTIVE_STOP, SAFETY_ROBOT_EMERGENCY_STOP = 1, 3, 7
RUNTIME_STOPPED, RUNTIME_PLAYING, RUNTIME_PAUSED = 1, 2, 4

# Bits of safety_status_bits.
SAFETY_BIT_NORMAL = 1 << 0
SAFETY_BIT_PROTECTIVE_STOPPED = 1 << 2
SAFETY_BIT_ROBOT_EMERGENCY_STOPPED = 1 << 6
SAFETY_BIT_EMERGENCY_STOPPED = 1 << 7
SAFETY_BIT_STOPPED_DUE_TO_SAFETY = 1 << 10
# Bits of robot_status_bits.
STATUS_BIT_POWER_ON = 1 << 0
STATUS_BIT_PROGRAM_RUNNING = 1 << 1

MAX_STREAM_HZ = 125.0
"""Output packages are streamed at the client's frequency capped here: Python on a
shared 2-core machine cannot keep 500 Hz on three links, and ur_rtde only needs fresh
state, not every controller cycle."""

VECTOR_OUTPUTS = {
    "target_q",
    "target_qd",
    "target_qdd",
    "target_current",
    "target_moment",
    "actual_q",
    "actual_qd",
    "actual_current",
    "actual_current_window",
    "joint_control_output",
    "actual_TCP_pose",
    "actual_TCP_speed",
    "actual_TCP_force",
    "target_TCP_pose",
    "target_TCP_speed",
    "joint_temperatures",
    "actual_joint_voltage",
    "payload_inertia",
    "ft_raw_wrench",
    "actual_current_as_torque",
    "external_force_torque",
}
"""RTDE variables of type VECTOR6D."""

TYPED_VARIABLES = {
    "timestamp": "DOUBLE",
    "actual_execution_time": "DOUBLE",
    "robot_mode": "INT32",
    "joint_mode": "VECTOR6INT32",
    "safety_mode": "INT32",
    "safety_status": "INT32",
    "actual_tool_accelerometer": "VECTOR3D",
    "speed_scaling": "DOUBLE",
    "target_speed_fraction": "DOUBLE",
    "actual_momentum": "DOUBLE",
    "actual_main_voltage": "DOUBLE",
    "actual_robot_voltage": "DOUBLE",
    "actual_robot_current": "DOUBLE",
    "actual_digital_input_bits": "UINT64",
    "actual_digital_output_bits": "UINT64",
    "runtime_state": "UINT32",
    "elbow_position": "VECTOR3D",
    "elbow_velocity": "VECTOR3D",
    "robot_status_bits": "UINT32",
    "safety_status_bits": "UINT32",
    "analog_io_types": "UINT32",
    "standard_analog_input0": "DOUBLE",
    "standard_analog_input1": "DOUBLE",
    "standard_analog_output0": "DOUBLE",
    "standard_analog_output1": "DOUBLE",
    "io_current": "DOUBLE",
    "euromap67_input_bits": "UINT32",
    "euromap67_output_bits": "UINT32",
    "euromap67_24V_voltage": "DOUBLE",
    "euromap67_24V_current": "DOUBLE",
    "tool_mode": "UINT32",
    "tool_analog_input_types": "UINT32",
    "tool_analog_input0": "DOUBLE",
    "tool_analog_input1": "DOUBLE",
    "tool_output_voltage": "INT32",
    "tool_output_current": "DOUBLE",
    "tool_temperature": "DOUBLE",
    "tcp_force_scalar": "DOUBLE",
    "output_bit_registers0_to_31": "UINT32",
    "output_bit_registers32_to_63": "UINT32",
    "input_bit_registers0_to_31": "UINT32",
    "input_bit_registers32_to_63": "UINT32",
    "tool_output_mode": "UINT8",
    "tool_digital_output0_mode": "UINT8",
    "tool_digital_output1_mode": "UINT8",
    "payload": "DOUBLE",
    "payload_cog": "VECTOR3D",
    "script_control_line": "UINT32",
    "joint_position_deviation_ratio": "DOUBLE",
    "collision_detection_ratio": "DOUBLE",
    "time_scale_source": "UINT32",
    # Inputs (client -> controller).
    "speed_slider_mask": "UINT32",
    "speed_slider_fraction": "DOUBLE",
    "standard_digital_output_mask": "UINT8",
    "standard_digital_output": "UINT8",
    "configurable_digital_output_mask": "UINT8",
    "configurable_digital_output": "UINT8",
    "tool_digital_output_mask": "UINT8",
    "tool_digital_output": "UINT8",
    "standard_analog_output_mask": "UINT8",
    "standard_analog_output_type": "UINT8",
    "standard_analog_output_0": "DOUBLE",
    "standard_analog_output_1": "DOUBLE",
}
TYPED_VARIABLES.update(dict.fromkeys(VECTOR_OUTPUTS, "VECTOR6D"))

REGISTER_PATTERN = re.compile(r"^(input|output)_(bit|int|double)_register_(\d+)$")
REGISTER_TYPES = {"bit": "BOOL", "int": "INT32", "double": "DOUBLE"}
REGISTER_RANGES = {"bit": range(64, 128), "int": range(48), "double": range(48)}


def variable_type(name: str) -> str | None:
    """The RTDE type of a variable name, or None when the controller has no such field."""
    if name in TYPED_VARIABLES:
        return TYPED_VARIABLES[name]
    match = REGISTER_PATTERN.match(name)
    if match and int(match.group(3)) in REGISTER_RANGES[match.group(2)]:
        return REGISTER_TYPES[match.group(2)]
    return None


def zero_value(rtde_type: str) -> Any:
    """The value a field of ``rtde_type`` has before anything sets it."""
    fmt = TYPE_FORMATS[rtde_type]
    if fmt[0].isdigit():
        kind = float if fmt.endswith("d") else int
        return [kind(0)] * int(fmt[0])
    return {"?": False, "d": 0.0}.get(fmt, 0)


def pack_values(types: list[str], values: list[Any]) -> bytes:
    """Serialize ``values`` as the fields of a recipe with ``types``, big-endian."""
    fmt = ">" + "".join(TYPE_FORMATS[t] for t in types)
    flat: list[Any] = []
    for value in values:
        flat.extend(value if isinstance(value, list | tuple) else [value])
    return struct.pack(fmt, *flat)


def unpack_values(types: list[str], payload: bytes) -> list[Any]:
    """Parse a data package payload (recipe id removed) into one value per field."""
    flat = list(struct.unpack(">" + "".join(TYPE_FORMATS[t] for t in types), payload))
    values: list[Any] = []
    for rtde_type in types:
        fmt = TYPE_FORMATS[rtde_type]
        count = int(fmt[0]) if fmt[0].isdigit() else 1
        chunk, flat = flat[:count], flat[count:]
        values.append(chunk if count > 1 else chunk[0])
    return values


def package(command: int, payload: bytes = b"") -> bytes:
    """One RTDE package: the ``>HB`` header then the payload."""
    return HEADER.pack(HEADER.size + len(payload), command) + payload


def trapezoid_duration(distance: float, speed: float, acceleration: float) -> float:
    """Time to travel ``distance`` from rest to rest with a trapezoidal speed profile."""
    if distance <= 0:
        return 0.0
    ramp = speed * speed / acceleration  # distance spent accelerating plus decelerating
    if distance <= ramp:
        return 2.0 * math.sqrt(distance / acceleration)
    return 2.0 * speed / acceleration + (distance - ramp) / speed


def trapezoid_fraction(elapsed: float, distance: float, speed: float, acceleration: float) -> float:
    """Fraction of ``distance`` covered ``elapsed`` seconds into a trapezoidal move."""
    total = trapezoid_duration(distance, speed, acceleration)
    if distance <= 0 or elapsed >= total:
        return 1.0
    peak = min(speed, math.sqrt(distance * acceleration))  # triangular when too short
    ramp_time = peak / acceleration
    ramp_distance = 0.5 * acceleration * ramp_time**2
    if elapsed < ramp_time:
        covered = 0.5 * acceleration * elapsed**2
    elif elapsed < total - ramp_time:
        covered = ramp_distance + peak * (elapsed - ramp_time)
    else:
        remaining = total - elapsed
        covered = distance - 0.5 * acceleration * remaining**2
    return min(max(covered / distance, 0.0), 1.0)


@dataclass
class LinearMove:
    """A moveL in progress: from ``start`` to ``goal``, begun at monotonic time ``started``."""

    start: list[float]
    goal: list[float]
    speed: float
    acceleration: float
    started: float

    def pose_at(self, now: float, time_scale: float) -> list[float]:
        """The interpolated pose (position along the line; orientation snaps at the end)."""
        distance = math.dist(self.start[:3], self.goal[:3])
        elapsed = (now - self.started) / time_scale
        fraction = trapezoid_fraction(elapsed, distance, self.speed, self.acceleration)
        if fraction >= 1.0:
            return list(self.goal)
        position = [
            a + fraction * (b - a) for a, b in zip(self.start[:3], self.goal[:3], strict=True)
        ]
        return position + list(self.start[3:])


@dataclass
class RobotState:
    """Everything the fake controller simulates, guarded by :attr:`FakeController.lock`."""

    tcp_pose: list[float] = field(default_factory=lambda: [0.3, 0.0, 0.3, math.pi, 0.0, 0.0])
    joints: list[float] = field(default_factory=lambda: [0.0, -1.57, 1.57, -1.57, -1.57, 0.0])
    protective_stopped: bool = False
    emergency_stopped: bool = False
    program_running: bool = False
    motion: LinearMove | None = None
    digital_outputs: int = 0
    """actual_digital_output_bits: standard 0-7, configurable 8-15, tool 16-17."""
    inputs: dict[str, Any] = field(default_factory=dict)
    """The last value the clients wrote to each input field."""
    outputs: dict[str, Any] = field(default_factory=dict)
    """Output registers the simulated script wrote."""

    def safety_mode(self) -> int:
        """``safety_mode`` / ``safety_status``: 1 normal, 3 protective stop, 7 robot e-stop."""
        if self.emergency_stopped:
            return SAFETY_ROBOT_EMERGENCY_STOP
        if self.protective_stopped:
            return SAFETY_PROTECTIVE_STOP
        return SAFETY_NORMAL

    def safety_status_bits(self) -> int:
        """``safety_status_bits``, which ur_rtde's ``isProtectiveStopped`` and
        ``isEmergencyStopped`` read."""
        if self.emergency_stopped:
            return (
                SAFETY_BIT_ROBOT_EMERGENCY_STOPPED
                | SAFETY_BIT_EMERGENCY_STOPPED
                | SAFETY_BIT_STOPPED_DUE_TO_SAFETY
            )
        if self.protective_stopped:
            return SAFETY_BIT_PROTECTIVE_STOPPED | SAFETY_BIT_STOPPED_DUE_TO_SAFETY
        return SAFETY_BIT_NORMAL

    def robot_status_bits(self) -> int:
        """``robot_status_bits``: power on, and program running (ur_rtde's
        ``isProgramRunning``)."""
        bits = 0 if self.emergency_stopped else STATUS_BIT_POWER_ON
        return bits | (STATUS_BIT_PROGRAM_RUNNING if self.program_running else 0)

    def runtime_state(self) -> int:
        """``runtime_state``: stopped, playing, or paused by a protective stop."""
        if not self.program_running:
            return RUNTIME_STOPPED
        return RUNTIME_PAUSED if self.protective_stopped else RUNTIME_PLAYING


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

# Which input fields set which digital outputs: (mask field, value field, log name,
# first bit in actual_digital_output_bits, number of outputs).
DIGITAL_OUTPUT_FIELDS = (
    ("standard_digital_output_mask", "standard_digital_output", "setStandardDigitalOut", 0, 8),
    (
        "configurable_digital_output_mask",
        "configurable_digital_output",
        "setConfigurableDigitalOut",
        8,
        8,
    ),
    ("tool_digital_output_mask", "tool_digital_output", "setToolDigitalOut", 16, 2),
)

DROP_SCOPES = ("all", "rtde")
"""What a dropped link cuts: every connection, or only the RTDE ones (port 30004)."""

SCRIPT_QUIET_S = 0.1
"""A program sent to the script port is complete once the sender paused this long:
ur_rtde writes the whole program at once and keeps the socket open."""
SCRIPT_CYCLE_S = 0.004
"""How often the simulated control script polls its command register when nothing
wakes it (the real one runs every controller cycle, 2 ms)."""
REGISTER_OFFSET_PATTERN = re.compile(r"reg_offset_int\s*=\s*(?:#[^\n]*\n)?\s*(\d+)")


def _log(message: str) -> None:
    print(f"fake-ur {time.monotonic():.3f} {message}", file=sys.stderr, flush=True)


def _recv_exactly(sock: socket.socket, size: int) -> bytes:
    """Read ``size`` bytes; raise ConnectionError when the peer closes first."""
    chunks = bytearray()
    while len(chunks) < size:
        chunk = sock.recv(size - len(chunks))
        if not chunk:
            raise ConnectionError("peer closed the connection")
        chunks.extend(chunk)
    return bytes(chunks)


@dataclass
class Trigger:
    """An event armed to fire when the robot receives its next actuating command.

    It fires when ``after_commands`` actuating commands have already been received
    and another one arrives; that command is then treated as lost on the way (logged
    with ``executed: False``, never run, no "done" answered).
    """

    event: str
    """``"drop"``, ``"protective_stop"`` or ``"emergency_stop"``."""
    after_commands: int
    reconnect: bool = True
    """For ``"drop"``: whether the controller accepts connections again afterwards."""
    scope: str = "all"
    """For ``"drop"``: ``"all"`` connections or only the ``"rtde"`` ones (30004)."""


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

    def __init__(self, controller: FakeController, name: str, register_offset: int) -> None:
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


class FakeController:
    """The simulated controller: robot state, the four servers and the command log.

    Parameters
    ----------
    host
        Loopback address to listen on; every controller port is fixed, so each
        fake needs its own address.
    control_port
        Port of the JSON control channel.
    time_scale
        Wall-clock seconds per simulated second of motion (0.2: moves run 5x faster).
    controller_version
        ``(major, minor, bugfix, build)`` answered to ``v``; 5.x is an e-Series.
    safety_max_reach_m, safety_min_z_m
        What ``isPoseWithinSafetyLimits`` accepts: within this distance of the base
        and not below this height.
    """

    def __init__(
        self,
        host: str,
        *,
        control_port: int = DEFAULT_CONTROL_PORT,
        time_scale: float = 1.0,
        controller_version: tuple[int, int, int, int] = (5, 11, 1, 108318),
        safety_max_reach_m: float = 0.5,
        safety_min_z_m: float = -math.inf,
        verbose: bool = False,
    ) -> None:
        if not time_scale > 0:
            raise ValueError(f"time_scale must be > 0, got {time_scale}")
        self.host = host
        self.control_port = control_port
        self.time_scale = time_scale
        self.controller_version = controller_version
        self.safety_max_reach_m = safety_max_reach_m
        self.safety_min_z_m = safety_min_z_m
        self.verbose = verbose
        self.lock = threading.RLock()
        self.changed = threading.Condition(self.lock)
        self.state = RobotState()
        self.log: list[dict[str, Any]] = []
        self.triggers: list[Trigger] = []
        self.actuating_received = 0
        self.refuse_programs = False
        self.script: ControlScript | None = None
        self.command_register_offset = 0
        """Register offset of the last control script (0 unless ur_rtde's upper range)."""
        self.started = time.monotonic()
        self.shutdown_requested = threading.Event()
        self._listeners: dict[int, socket.socket] = {}
        self._connections: set[socket.socket] = set()
        self._rtde_connections: set[socket.socket] = set()

    # --- simulated robot ----------------------------------------------------------------

    def wake(self) -> None:
        """Wake the script: an input changed or the robot state did."""
        with self.changed:
            self.changed.notify_all()

    def is_protective_stopped(self) -> bool:
        with self.lock:
            return self.state.protective_stopped

    def wait_for_change(self, timeout: float) -> None:
        with self.changed:
            self.changed.wait(timeout)

    def record(self, entry: dict[str, Any]) -> None:
        """Append to the command log (with the time since start)."""
        entry = {"t": round(time.monotonic() - self.started, 4), **entry}
        with self.lock:
            self.log.append(entry)
        if self.verbose:
            _log(f"log {entry}")

    def receive_command(self, entry: dict[str, Any]) -> bool:
        """Log a command; False when an armed trigger fired and it must not run."""
        with self.lock:
            actuating = entry["command"] in ACTUATING_COMMANDS
            trigger = None
            if actuating:
                trigger = next(
                    (t for t in self.triggers if t.after_commands == self.actuating_received),
                    None,
                )
                self.actuating_received += 1
            entry["executed"] = trigger is None
            self.record(entry)
            if trigger is not None:
                self.triggers.remove(trigger)
                self.fire(trigger.event, reconnect=trigger.reconnect, scope=trigger.scope)
            return trigger is None

    def fire(self, event: str, *, reconnect: bool = True, scope: str = "all") -> None:
        if event == "drop":
            self.drop_link(reconnect=reconnect, scope=scope)
        elif event == "protective_stop":
            self.protective_stop()
        elif event == "emergency_stop":
            self.emergency_stop()
        else:
            raise ValueError(f"unknown event {event!r}")

    def current_pose(self) -> list[float]:
        """The TCP pose now, advancing the motion in progress."""
        with self.lock:
            motion = self.state.motion
            if motion is not None:
                pose = motion.pose_at(time.monotonic(), self.time_scale)
                self.state.tcp_pose = pose
                if pose == motion.goal:
                    self.state.motion = None
            return list(self.state.tcp_pose)

    def pose_within_safety_limits(self, pose: list[float]) -> bool:
        x, y, z = pose[:3]
        return (
            all(math.isfinite(v) for v in pose)
            and math.sqrt(x * x + y * y + z * z) <= self.safety_max_reach_m
            and z >= self.safety_min_z_m
        )

    def move_linear(
        self, goal: list[float], speed: float, acceleration: float, script: ControlScript
    ) -> None:
        """Blocking moveL as the script's ``movel`` does it; returns when reached.

        A protective stop freezes the tool where it is and the program pauses; after a
        release the move continues to the goal. An e-stop or the end of the script
        abandons it.
        """
        while not script.stopped.is_set():
            with self.lock:
                if not self.state.protective_stopped:
                    if self.state.motion is None:
                        start = self.current_pose()
                        if start == goal:
                            return
                        self.state.motion = LinearMove(
                            start=start,
                            goal=list(goal),
                            speed=max(speed, 1e-6),
                            acceleration=max(acceleration, 1e-6),
                            started=time.monotonic(),
                        )
                    self.current_pose()
                    if self.state.motion is None:
                        return
            self.wait_for_change(SCRIPT_CYCLE_S)

    def halt_motion(self) -> None:
        """Stop where the tool is (stopL/stopJ; stops are instantaneous here)."""
        with self.lock:
            self.current_pose()
            self.state.motion = None

    def protective_stop(self) -> None:
        with self.lock:
            self.halt_motion()
            self.state.protective_stopped = True
            self.record({"command": "event", "event": "protective_stop"})
        self.wake()

    def emergency_stop(self) -> None:
        with self.lock:
            self.halt_motion()
            self.state.emergency_stopped = True
            self.record({"command": "event", "event": "emergency_stop"})
            script = self.script
        if script is not None:
            script.stop()  # an e-stop ends the program

    def release(self) -> None:
        """Clear the stops (unlock protective stop / reset e-stop); a paused program resumes."""
        with self.lock:
            self.state.protective_stopped = False
            self.state.emergency_stopped = False
            self.record({"command": "event", "event": "release"})
        self.wake()

    def stop_program(self, reason: str) -> None:
        """Stop the running program, as the pendant's or dashboard's stop does."""
        with self.lock:
            script = self.script
            self.record({"command": "event", "event": "program_stopped", "reason": reason})
        if script is not None:
            script.stop()
        self.halt_motion()

    def script_ended(self, script: ControlScript) -> None:
        with self.lock:
            if self.script is script:
                self.script = None
                self.state.program_running = False
                if not script.stopped.is_set():
                    self.record({"command": "event", "event": "script_ended"})
        self.wake()

    def run_program(self, text: str) -> None:
        """A program arrived on the script port: it replaces the running one."""
        name_match = re.search(r"^def\s+(\w+)\s*\(", text, re.MULTILINE)
        name = name_match.group(1) if name_match else "<unnamed>"
        is_control_script = "read_input_integer_reg" in text
        with self.lock:
            refused = (
                self.refuse_programs
                or self.state.emergency_stopped
                or self.state.protective_stopped
            )
            self.record(
                {
                    "command": "script",
                    "name": name,
                    "bytes": len(text.encode()),
                    "started": not refused and is_control_script,
                }
            )
            previous = self.script
        if previous is not None:
            previous.stop()
        if refused or not is_control_script:
            return
        offset_match = REGISTER_OFFSET_PATTERN.search(text)
        script = ControlScript(self, name, int(offset_match.group(1)) if offset_match else 0)
        with self.lock:
            self.script = script
            self.command_register_offset = script.offset
            self.state.program_running = True
        script.start()

    def apply_inputs(self, values: dict[str, Any]) -> None:
        """Store what a client wrote; digital output fields act on the outputs at once.

        A command code written while no control script runs is logged as not executed
        (nobody reads the register), so a test can tell a command the client sent into
        the void from one it never sent.
        """
        with self.lock:
            command_register = f"input_int_register_{self.command_register_offset}"
            code = int(values.get(command_register, 0))
            if code and code != self.state.inputs.get(command_register) and self.script is None:
                self.record(
                    {
                        "command": SCRIPT_COMMANDS.get(code, f"code_{code}"),
                        "code": code,
                        "executed": False,
                        "reason": "no control script running",
                    }
                )
            self.state.inputs.update(values)
            for mask_field, value_field, method, first_bit, count in DIGITAL_OUTPUT_FIELDS:
                mask = int(values.get(mask_field, 0))
                if not mask:
                    continue
                level_bits = int(values.get(value_field, 0))
                for index in range(count):
                    if not mask >> index & 1:
                        continue
                    level = bool(level_bits >> index & 1)
                    entry = {"command": method, "index": index, "level": level}
                    if self.receive_command(entry):
                        bit = 1 << (first_bit + index)
                        outputs = self.state.digital_outputs
                        self.state.digital_outputs = (outputs | bit) if level else (outputs & ~bit)
        self.wake()

    def output_value(self, name: str, rtde_type: str) -> Any:
        """The current value of an RTDE output field (call with the lock held)."""
        state = self.state
        if name in ("actual_TCP_pose", "target_TCP_pose"):
            return self.current_pose()
        if name in ("actual_q", "target_q"):
            return list(state.joints)
        computed: dict[str, Callable[[], Any]] = {
            "timestamp": lambda: time.monotonic() - self.started,
            "robot_mode": lambda: (
                ROBOT_MODE_POWER_OFF if state.emergency_stopped else ROBOT_MODE_RUNNING
            ),
            "safety_mode": state.safety_mode,
            "safety_status": state.safety_mode,
            "safety_status_bits": state.safety_status_bits,
            "robot_status_bits": state.robot_status_bits,
            "runtime_state": state.runtime_state,
            "actual_digital_output_bits": lambda: state.digital_outputs,
            "speed_scaling": lambda: 1.0,
            "target_speed_fraction": lambda: 1.0,
            "actual_main_voltage": lambda: 48.0,
            "actual_robot_voltage": lambda: 48.0,
        }
        if name in computed:
            return computed[name]()
        if name in state.outputs:
            return state.outputs[name]
        if name in state.inputs:
            return state.inputs[name]
        return zero_value(rtde_type)

    def snapshot(self) -> dict[str, Any]:
        """The state and the log, as JSON-ready values (the control channel's ``state``)."""
        with self.lock:
            state = self.state
            return {
                "tcp_pose": self.current_pose(),
                "moving": state.motion is not None,
                "program_running": state.program_running,
                "protective_stopped": state.protective_stopped,
                "emergency_stopped": state.emergency_stopped,
                "safety_mode": state.safety_mode(),
                "runtime_state": state.runtime_state(),
                "digital_outputs": state.digital_outputs,
                "link_up": bool(self._listeners),
                "connections": len(self._connections),
                "log": [dict(entry) for entry in self.log],
            }

    # --- network ------------------------------------------------------------------------

    def open_listeners(self) -> None:
        """Bind the RTDE, script and dashboard ports (again, after a drop)."""
        handlers = {
            RTDE_PORT: self._serve_rtde,
            SCRIPT_PORT: self._serve_script,
            DASHBOARD_PORT: self._serve_dashboard,
        }
        with self.lock:
            for port, handler in handlers.items():
                if port in self._listeners:
                    continue
                listener = socket.create_server((self.host, port))
                self._listeners[port] = listener
                threading.Thread(target=self._accept, args=(listener, handler), daemon=True).start()

    def close_listeners(self) -> None:
        with self.lock:
            listeners, self._listeners = list(self._listeners.values()), {}
        for listener in listeners:
            _close(listener)

    def drop_link(self, *, reconnect: bool = True, scope: str = "all") -> None:
        """Cut client connections: every one (``scope="all"``) or only the RTDE ones.

        The program keeps running on the controller, as it does on a real robot. With
        ``reconnect`` False the ports stay closed (connection refused) until
        ``restore_link``.
        """
        if scope not in DROP_SCOPES:
            raise ValueError(f"scope must be one of {DROP_SCOPES}, got {scope!r}")
        self.record({"command": "event", "event": "drop", "reconnect": reconnect, "scope": scope})
        if not reconnect:
            self.close_listeners()
        with self.lock:
            connections = [
                c for c in self._connections if scope == "all" or c in self._rtde_connections
            ]
            self._connections.difference_update(connections)
            self._rtde_connections.difference_update(connections)
        for connection in connections:
            _close(connection)

    def restore_link(self) -> None:
        self.record({"command": "event", "event": "restore"})
        self.open_listeners()

    def _accept(self, listener: socket.socket, handler: Callable[[socket.socket], None]) -> None:
        while True:
            try:
                connection, _ = listener.accept()
            except OSError:
                return  # the listener was closed
            connection.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self.record({"command": "connect", "port": listener.getsockname()[1]})
            with self.lock:
                self._connections.add(connection)
            threading.Thread(target=self._serve, args=(handler, connection), daemon=True).start()

    def _serve(self, handler: Callable[[socket.socket], None], connection: socket.socket) -> None:
        try:
            handler(connection)
        except (OSError, ValueError, struct.error) as error:  # the peer or a drop closed it
            if self.verbose:
                _log(f"{handler.__name__} closed: {error!r}")
        finally:
            with self.lock:
                self._connections.discard(connection)
            _close(connection)

    def _serve_rtde(self, connection: socket.socket) -> None:
        """One RTDE client: setup, then data packages in both directions."""
        self._rtde_connections.add(connection)
        send_lock = threading.Lock()
        input_recipes: dict[int, tuple[list[str], list[str]]] = {}
        output_recipe: list[tuple[list[str], list[str], float]] = []
        streaming = threading.Event()
        closed = threading.Event()

        def send(command: int, payload: bytes) -> None:
            with send_lock:
                connection.sendall(package(command, payload))

        def stream() -> None:
            names, types, frequency = output_recipe[0]
            period = 1.0 / min(frequency, MAX_STREAM_HZ)
            next_send = time.monotonic()
            while not closed.is_set():
                if not streaming.wait(0.1):
                    continue
                with self.lock:
                    values = [self.output_value(n, t) for n, t in zip(names, types, strict=True)]
                try:
                    send(DATA_PACKAGE, bytes([1]) + pack_values(types, values))
                except OSError:
                    return
                next_send = max(next_send + period, time.monotonic())
                closed.wait(max(next_send - time.monotonic(), 0.0))

        try:
            while True:
                size, command = HEADER.unpack(_recv_exactly(connection, HEADER.size))
                payload = _recv_exactly(connection, size - HEADER.size)
                if command == REQUEST_PROTOCOL_VERSION:
                    (version,) = struct.unpack(">H", payload)
                    send(command, bytes([version == 2]))
                elif command == GET_URCONTROL_VERSION:
                    send(command, struct.pack(">IIII", *self.controller_version))
                elif command == SETUP_OUTPUTS:
                    (frequency,) = struct.unpack(">d", payload[:8])
                    names = [n for n in payload[8:].decode().split(",") if n]
                    types = [variable_type(n) or "NOT_FOUND" for n in names]
                    accepted = "NOT_FOUND" not in types and not output_recipe
                    send(command, bytes([1 if accepted else 0]) + ",".join(types).encode())
                    if accepted:
                        output_recipe.append((names, types, frequency))
                        threading.Thread(target=stream, daemon=True).start()
                elif command == SETUP_INPUTS:
                    names = [n for n in payload.decode().split(",") if n]
                    types = [variable_type(n) or "NOT_FOUND" for n in names]
                    recipe_id = 0
                    if "NOT_FOUND" not in types and len(input_recipes) < 255:
                        recipe_id = len(input_recipes) + 1
                        input_recipes[recipe_id] = (names, types)
                    send(command, bytes([recipe_id]) + ",".join(types).encode())
                elif command == START:
                    streaming.set()
                    send(command, b"\x01")
                elif command == PAUSE:
                    streaming.clear()
                    send(command, b"\x01")
                elif command == DATA_PACKAGE and payload[0] not in input_recipes:
                    self.record({"command": "rtde_error", "unknown_input_recipe": payload[0]})
                elif command == DATA_PACKAGE:
                    names, types = input_recipes[payload[0]]
                    self.apply_inputs(
                        dict(zip(names, unpack_values(types, payload[1:]), strict=True))
                    )
                elif command == TEXT_MESSAGE:
                    self.record({"command": "text_message", "bytes": len(payload)})
                elif self.verbose:
                    _log(f"rtde: ignoring command {command}")
        finally:
            closed.set()

    def _serve_script(self, connection: socket.socket) -> None:
        """Collect programs: each burst of text followed by a pause is one program."""
        connection.settimeout(SCRIPT_QUIET_S)
        pending = bytearray()
        while True:
            try:
                chunk = connection.recv(65536)
            except TimeoutError:
                if pending:
                    self.run_program(pending.decode(errors="replace"))
                    pending.clear()
                continue
            if not chunk:
                if pending:
                    self.run_program(pending.decode(errors="replace"))
                return
            pending.extend(chunk)

    def _serve_dashboard(self, connection: socket.socket) -> None:
        connection.sendall(b"Connected: Universal Robots Dashboard Server\n")
        for raw in connection.makefile("rb"):
            request = raw.decode(errors="replace").strip()
            self.record({"command": "dashboard", "request": request})
            reply = self._dashboard_reply(request)
            connection.sendall(reply.encode() + b"\n")
            if request == "quit":
                return

    def _dashboard_reply(self, request: str) -> str:
        with self.lock:
            state = self.state
            running = state.program_running
            program = self.script.name if self.script else "<unnamed>"
        if request == "PolyscopeVersion":
            major, minor, bugfix, build = self.controller_version
            return f"URSoftware {major}.{minor}.{bugfix}.{build} (Jan 01 2024)"
        if request == "get serial number":
            return "20235300001"
        if request == "get robot model":
            return "UR3"
        if request == "is in remote control":
            return "true"
        if request == "robotmode":
            return "Robotmode: POWER_OFF" if state.emergency_stopped else "Robotmode: RUNNING"
        if request in ("safetymode", "safetystatus"):
            word = {1: "NORMAL", 3: "PROTECTIVE_STOP", 7: "ROBOT_EMERGENCY_STOP"}
            return f"{request.capitalize()}: {word[state.safety_mode()]}"
        if request == "programState":
            return f"PLAYING {program}" if running else f"STOPPED {program}"
        if request == "running":
            return f"Program running: {str(running).lower()}"
        if request == "stop":
            self.stop_program("dashboard stop")
            return "Stopped"
        if request == "unlock protective stop":
            self.release()
            return "Protective stop releasing"
        if request == "close safety popup":
            return "closing safety popup"
        if request.startswith("popup "):
            return "showing popup"
        if request == "close popup":
            return "closing popup"
        if request == "quit":
            return "Disconnected"
        return f"could not understand: '{request}'"

    # --- test control channel -----------------------------------------------------------

    def _serve_control(self, listener: socket.socket) -> None:
        while True:
            try:
                connection, _ = listener.accept()
            except OSError:
                return
            threading.Thread(target=self._control_session, args=(connection,), daemon=True).start()

    def _control_session(self, connection: socket.socket) -> None:
        with contextlib.closing(connection), connection.makefile("rwb") as stream:
            for raw in stream:
                try:
                    reply = self.handle_control(json.loads(raw))
                except Exception as error:  # reported to the test, not fatal here
                    reply = {"ok": False, "error": f"{type(error).__name__}: {error}"}
                stream.write(json.dumps(reply).encode() + b"\n")
                stream.flush()

    def handle_control(self, request: dict[str, Any]) -> dict[str, Any]:
        """Execute one control request; see :func:`main` for the operations."""
        op = request.get("op")
        if op == "state":
            return {"ok": True, **self.snapshot()}
        if op in ("protective_stop", "emergency_stop"):
            self.fire(op)
        elif op == "release":
            self.release()
        elif op == "drop":
            self.drop_link(
                reconnect=bool(request.get("reconnect", True)),
                scope=str(request.get("scope", "all")),
            )
        elif op == "restore":
            self.restore_link()
        elif op == "stop_program":
            self.stop_program("pendant stop")
        elif op == "arm":
            trigger = Trigger(
                event=str(request["event"]),
                after_commands=int(request["after_commands"]),
                reconnect=bool(request.get("reconnect", True)),
                scope=str(request.get("scope", "all")),
            )
            if trigger.scope not in DROP_SCOPES:
                raise ValueError(f"scope must be one of {DROP_SCOPES}, got {trigger.scope!r}")
            if trigger.event not in ("drop", "protective_stop", "emergency_stop"):
                raise ValueError(f"unknown event {trigger.event!r}")
            with self.lock:
                self.triggers.append(trigger)
        elif op == "set":
            self._set(request.get("fields", {}))
        elif op == "shutdown":
            self.shutdown_requested.set()
        else:
            raise ValueError(f"unknown op {op!r}")
        return {"ok": True}

    def _set(self, fields: dict[str, Any]) -> None:
        with self.lock:
            for key, value in fields.items():
                if key == "tcp_pose":
                    self.halt_motion()
                    self.state.tcp_pose = [float(v) for v in value]
                elif key in ("safety_min_z_m", "safety_max_reach_m"):
                    setattr(self, key, float(value))
                elif key == "refuse_programs":
                    self.refuse_programs = bool(value)
                else:
                    raise ValueError(f"cannot set {key!r}")

    # --- lifecycle ----------------------------------------------------------------------

    def run(self) -> None:
        """Serve until a ``shutdown`` request or SIGTERM, then close everything."""
        control = socket.create_server((self.host, self.control_port))
        self.open_listeners()
        threading.Thread(target=self._serve_control, args=(control,), daemon=True).start()
        print(f"fake UR controller ready on {self.host}", flush=True)
        try:
            self.shutdown_requested.wait()
        finally:
            _close(control)
            with self.lock:
                script = self.script
            if script is not None:
                script.stop()
            self.drop_link(reconnect=False)


def _close(sock: socket.socket) -> None:
    with contextlib.suppress(OSError):
        sock.shutdown(socket.SHUT_RDWR)
    with contextlib.suppress(OSError):
        sock.close()


def _shut_down_when_orphaned(controller: FakeController) -> None:
    """Shut down once the parent is gone (re-parented), so a crashed test run that
    could not tear its fixtures down leaves no fake listening behind."""
    parent = os.getppid()
    while not controller.shutdown_requested.wait(0.5):
        if os.getppid() != parent:
            controller.shutdown_requested.set()


def main(argv: list[str] | None = None) -> int:
    """Command line: start the fake and serve until SIGTERM or a ``shutdown`` request.

    Control channel operations (JSON lines on ``--control-port``): ``state``,
    ``protective_stop``, ``emergency_stop``, ``release``, ``stop_program``,
    ``drop`` (``reconnect``: bool, ``scope``: ``"all"``/``"rtde"``), ``restore``, ``arm``
    (``event``, ``after_commands``, ``reconnect``, ``scope``), ``set`` (``fields``: ``tcp_pose``,
    ``safety_min_z_m``, ``safety_max_reach_m``, ``refuse_programs``), ``shutdown``.
    """
    parser = argparse.ArgumentParser(prog="python -m adapters.fake_ur_controller")
    parser.add_argument("--host", default="127.0.0.2", help="loopback address to listen on")
    parser.add_argument("--control-port", type=int, default=DEFAULT_CONTROL_PORT)
    parser.add_argument(
        "--time-scale", type=float, default=1.0, help="wall seconds per simulated second"
    )
    parser.add_argument("--protective-stop", action="store_true", help="start protective stopped")
    parser.add_argument("--estop", action="store_true", help="start emergency stopped")
    parser.add_argument(
        "--refuse-programs", action="store_true", help="never run an uploaded program"
    )
    parser.add_argument(
        "--drop-after",
        type=int,
        metavar="N",
        help="drop every connection when the (N+1)th actuating command arrives",
    )
    parser.add_argument(
        "--no-reconnect", action="store_true", help="after a drop, refuse new connections"
    )
    parser.add_argument(
        "--drop-scope", choices=DROP_SCOPES, default="all", help="which connections drop"
    )
    parser.add_argument("--safety-min-z", type=float, default=-math.inf, metavar="METRES")
    parser.add_argument("--safety-max-reach", type=float, default=0.5, metavar="METRES")
    parser.add_argument(
        "--exit-with-parent",
        action="store_true",
        help="shut down when the process that started this one exits (for test fixtures)",
    )
    parser.add_argument("--verbose", action="store_true")
    args = parser.parse_args(argv)

    controller = FakeController(
        args.host,
        control_port=args.control_port,
        time_scale=args.time_scale,
        safety_max_reach_m=args.safety_max_reach,
        safety_min_z_m=args.safety_min_z,
        verbose=args.verbose,
    )
    controller.state.protective_stopped = args.protective_stop
    controller.state.emergency_stopped = args.estop
    controller.refuse_programs = args.refuse_programs
    if args.drop_after is not None:
        controller.triggers.append(
            Trigger("drop", args.drop_after, not args.no_reconnect, args.drop_scope)
        )
    signal.signal(signal.SIGTERM, lambda *_: controller.shutdown_requested.set())
    signal.signal(signal.SIGINT, lambda *_: controller.shutdown_requested.set())
    if args.exit_with_parent:
        threading.Thread(target=_shut_down_when_orphaned, args=(controller,), daemon=True).start()
    controller.run()
    return 0


if __name__ == "__main__":
    sys.exit(main())
