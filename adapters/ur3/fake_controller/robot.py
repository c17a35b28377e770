"""The simulated arm: robot, safety and runtime modes, and moveL along a trapezoidal profile."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

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
