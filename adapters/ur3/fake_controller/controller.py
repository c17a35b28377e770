"""The fake controller: the simulated robot behind the RTDE, script and dashboard servers,
the command log, the armed failure triggers and the JSON control channel for tests.

See :mod:`adapters.ur3.fake_controller` for the ports and what each one does.
"""

from __future__ import annotations

import contextlib
import json
import math
import re
import socket
import struct
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from adapters.ur3.fake_controller.robot import (
    ROBOT_MODE_POWER_OFF,
    ROBOT_MODE_RUNNING,
    LinearMove,
    RobotState,
)
from adapters.ur3.fake_controller.rtde import (
    DATA_PACKAGE,
    GET_URCONTROL_VERSION,
    HEADER,
    PAUSE,
    REQUEST_PROTOCOL_VERSION,
    RTDE_PORT,
    SETUP_INPUTS,
    SETUP_OUTPUTS,
    START,
    TEXT_MESSAGE,
    pack_values,
    package,
    recv_exactly,
    unpack_values,
    variable_type,
    zero_value,
)
from adapters.ur3.fake_controller.script import (
    ACTUATING_COMMANDS,
    REGISTER_OFFSET_PATTERN,
    SCRIPT_COMMANDS,
    SCRIPT_CYCLE_S,
    ControlScript,
)

SCRIPT_PORT = 30003
DASHBOARD_PORT = 29999
DEFAULT_CONTROL_PORT = 30999


MAX_STREAM_HZ = 125.0
"""Output packages are streamed at the client's frequency capped here: Python on a
shared 2-core machine cannot keep 500 Hz on three links, and ur_rtde only needs fresh
state, not every controller cycle."""


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


def _log(message: str) -> None:
    print(f"fake-ur {time.monotonic():.3f} {message}", file=sys.stderr, flush=True)


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
                size, command = HEADER.unpack(recv_exactly(connection, HEADER.size))
                payload = recv_exactly(connection, size - HEADER.size)
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
