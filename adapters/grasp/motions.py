"""A top-down arm pick as UR poses: approach, descend, close the gripper, lift; and the
offline workspace check.

Pure: what :func:`plan_motions` returns is what :meth:`adapters.ur3.driver.UR3Picker.pick`
sends, and what ``dlo ur3 plan`` and ``POST /v1/grasp`` show without a robot. Poses are
UR's ``[x, y, z, rx, ry, rz]`` (metres, rotation vector) in the robot base frame; speeds and
accelerations are clamped to :data:`MAX_SPEED_M_S` and :data:`MAX_ACCELERATION_M_S2`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

from adapters.errors import UnsafeTargetError
from schemas import GraspTarget, Motion

MAX_SPEED_M_S = 0.25
"""Hard cap on the tool speed of every move, whatever the configuration asks."""
MAX_ACCELERATION_M_S2 = 0.5
"""Hard cap on the tool acceleration of every move."""


@dataclass(frozen=True)
class Workspace:
    """Where the tool may go, in the base frame (metres).

    * every commanded position within ``reach_m - reach_margin_m`` of the base origin;
    * every commanded position at least ``clearance_m`` above ``table_z_m``;
    * every commanded position, and the straight path from the current tool position
      to the approach pose, outside the vertical keep-out cylinder of radius
      ``keep_out_radius_m`` around the base z axis.
    """

    reach_m: float = 0.50
    reach_margin_m: float = 0.05
    table_z_m: float = 0.0
    clearance_m: float = 0.01
    keep_out_radius_m: float = 0.10

    @property
    def max_radius_m(self) -> float:
        """Largest allowed distance of a tool position from the base origin."""
        return self.reach_m - self.reach_margin_m


@dataclass(frozen=True)
class GripperOutput:
    """The digital output that drives the gripper.

    ``kind`` ``"tool"`` uses ``setToolDigitalOut``, ``"standard"``
    ``setStandardDigitalOut``; ``close_value`` is the level that closes it.
    """

    kind: Literal["tool", "standard"] = "tool"
    index: int = 0
    close_value: bool = True

    def __post_init__(self) -> None:
        limit = 1 if self.kind == "tool" else 7
        if not 0 <= self.index <= limit:
            raise ValueError(
                f"{self.kind} digital output index must be 0..{limit}, got {self.index}"
            )


@dataclass(frozen=True)
class UR3Config:
    """Pick parameters; lengths in metres, speeds in m/s, accelerations in m/s^2.

    ``grasp_height_m`` is the tool (TCP) height above the target point at the grasp;
    with a fingertip TCP and a cable on the table it keeps the fingers off the table.
    ``gripper_yaw_offset_rad`` is the angle from the tool x axis to the direction the
    fingers close (0: they close along tool x). ``speed_m_s`` and
    ``acceleration_m_s2`` are clamped to the module caps.

    Deadlines (seconds): a ``moveL`` may take ``motion_timeout_factor`` times its
    trapezoidal profile time plus ``motion_timeout_margin_s`` (see
    :func:`motion_deadline_s`); ``stopL`` and the gripper output ``command_timeout_s``;
    each ``reconnect`` ``reconnect_timeout_s`` (ur_rtde's control reconnect uploads its
    script again and waits up to 5 s for it to start). A factor below 1 fails healthy
    moves: it is allowed (tests use it) but only makes the picker give up sooner.
    """

    approach_height_m: float = 0.10
    grasp_height_m: float = 0.015
    speed_m_s: float = MAX_SPEED_M_S
    acceleration_m_s2: float = MAX_ACCELERATION_M_S2
    stop_deceleration_m_s2: float = 2.0
    gripper_settle_s: float = 0.5
    gripper_yaw_offset_rad: float = 0.0
    motion_timeout_factor: float = 2.0
    motion_timeout_margin_s: float = 2.0
    command_timeout_s: float = 2.0
    reconnect_timeout_s: float = 10.0
    workspace: Workspace = field(default_factory=Workspace)
    gripper: GripperOutput = field(default_factory=GripperOutput)

    def __post_init__(self) -> None:
        positive = (
            "approach_height_m",
            "speed_m_s",
            "acceleration_m_s2",
            "stop_deceleration_m_s2",
            "motion_timeout_factor",
            "command_timeout_s",
            "reconnect_timeout_s",
        )
        for name in positive:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number, got {value}")
        for name in ("grasp_height_m", "gripper_settle_s", "motion_timeout_margin_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be >= 0, got {value}")

    @property
    def speed(self) -> float:
        """The tool speed actually commanded (clamped)."""
        return min(self.speed_m_s, MAX_SPEED_M_S)

    @property
    def acceleration(self) -> float:
        """The tool acceleration actually commanded (clamped)."""
        return min(self.acceleration_m_s2, MAX_ACCELERATION_M_S2)


def tool_down_rotation_vector(yaw: float) -> tuple[float, float, float]:
    """Rotation vector of a tool pointing straight down, its x axis at ``yaw`` about base z.

    The orientation is ``R = Rz(yaw) @ Rx(pi)``: a half turn about base x (roll = pi)
    points the tool z axis down, then ``yaw`` turns it about base z. Its columns are
    tool x = ``(cos yaw, sin yaw, 0)``, tool y = ``(sin yaw, -cos yaw, 0)`` and tool
    z = ``(0, 0, -1)``. The trace is -1, so ``R`` is a half turn, ``R = 2 n n^T - I``,
    about the horizontal axis ``n = (cos(yaw/2), sin(yaw/2), 0)``; the rotation
    vector (UR's ``[rx, ry, rz]``) is ``pi * n``. Yaw 0 gives ``[pi, 0, 0]``.
    """
    half = yaw / 2
    return math.pi * math.cos(half), math.pi * math.sin(half), 0.0


def grasp_poses(target: GraspTarget, config: UR3Config) -> tuple[tuple, tuple]:
    """The approach pose (above the target) and the grasp pose, as UR poses."""
    x, y, z = target.position_m
    rotation = tool_down_rotation_vector(target.yaw_rad - config.gripper_yaw_offset_rad)
    grasp_z = z + config.grasp_height_m
    approach = (x, y, grasp_z + config.approach_height_m, *rotation)
    grasp = (x, y, grasp_z, *rotation)
    return approach, grasp


def plan_motions(target: GraspTarget, config: UR3Config) -> list[Motion]:
    """The pick as a list of commands: approach, descend, close the gripper, lift.

    Pure: no robot involved; :meth:`UR3Picker.pick` sends exactly this list and a dry
    run can print it. The tool points down with the fingers closing along
    ``target.yaw_rad`` (see :func:`tool_down_rotation_vector`).
    """
    approach, grasp = grasp_poses(target, config)
    speed, acceleration = config.speed, config.acceleration

    def move(label: Any, pose: tuple) -> Motion:
        return Motion(
            label=label, kind="moveL", pose=pose, speed_m_s=speed, acceleration_m_s2=acceleration
        )

    return [
        move("approach", approach),
        move("descend", grasp),
        Motion(label="close_gripper", kind="gripper", output_value=config.gripper.close_value),
        move("lift", approach),
    ]


def check_workspace(
    motions: Sequence[Motion],
    workspace: Workspace,
    current_position: Sequence[float] | None = None,
) -> None:
    """Refuse a plan with a position outside ``workspace``.

    Parameters
    ----------
    motions
        The plan; every moveL position is checked.
    workspace
        The limits.
    current_position
        The tool position now; when given, the straight path from it to the first
        move must stay outside the keep-out cylinder too.

    Raises
    ------
    UnsafeTargetError
        Naming the move and the rule broken.
    """
    floor = workspace.table_z_m + workspace.clearance_m
    for motion in motions:
        if motion.pose is None:
            continue
        x, y, z = motion.pose[:3]
        if not all(math.isfinite(v) for v in motion.pose):
            raise UnsafeTargetError(f"{motion.label} pose {list(motion.pose)} is not finite")
        distance = math.sqrt(x * x + y * y + z * z)
        if distance > workspace.max_radius_m:
            raise UnsafeTargetError(
                f"{motion.label} position ({x:.3f}, {y:.3f}, {z:.3f}) m is {distance:.3f} m from "
                f"the base, beyond the {workspace.max_radius_m:.3f} m allowed"
            )
        if z < floor:
            raise UnsafeTargetError(
                f"{motion.label} height z = {z:.4f} m is below the table clearance "
                f"z = {floor:.4f} m"
            )
        radial = math.hypot(x, y)
        if radial < workspace.keep_out_radius_m:
            raise UnsafeTargetError(
                f"{motion.label} position is {radial:.3f} m from the base axis, inside the "
                f"{workspace.keep_out_radius_m:.3f} m keep-out cylinder"
            )
    first = next((motion for motion in motions if motion.pose is not None), None)
    if current_position is not None and first is not None:
        start = (float(current_position[0]), float(current_position[1]))
        radial = _segment_distance_to_origin(start, (first.pose[0], first.pose[1]))
        if radial < workspace.keep_out_radius_m:
            raise UnsafeTargetError(
                f"the straight path from the current tool position to the {first.label} pose "
                f"passes {radial:.3f} m from the base axis, inside the "
                f"{workspace.keep_out_radius_m:.3f} m keep-out cylinder"
            )


def _segment_distance_to_origin(a: tuple[float, float], b: tuple[float, float]) -> float:
    """Distance from the origin to the 2D segment ``a``-``b``."""
    dx, dy = b[0] - a[0], b[1] - a[1]
    squared = dx * dx + dy * dy
    t = 0.0 if squared == 0 else min(max(-(a[0] * dx + a[1] * dy) / squared, 0.0), 1.0)
    return math.hypot(a[0] + t * dx, a[1] + t * dy)
