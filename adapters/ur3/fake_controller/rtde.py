"""The RTDE wire format (Universal Robots' Real-Time Data Exchange, protocol version 2).

Every package starts with the header ``>HB``: uint16 size including the header, uint8
command. Data packages carry a recipe id and the recipe's fields, big-endian.
"""

from __future__ import annotations

import re
import socket
import struct
from typing import Any

RTDE_PORT = 30004

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


def recv_exactly(sock: socket.socket, size: int) -> bytes:
    """Read ``size`` bytes; raise ConnectionError when the peer closes first."""
    chunks = bytearray()
    while len(chunks) < size:
        chunk = sock.recv(size - len(chunks))
        if not chunk:
            raise ConnectionError("peer closed the connection")
        chunks.extend(chunk)
    return bytes(chunks)
