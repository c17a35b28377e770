"""Frames and the grasp approach of the hexarotor, as pure functions (no link, no pymavlink).

Frames
------
* **Local NED** (what the autopilot speaks): ``x`` north, ``y`` east, ``z`` down, metres,
  origin at the autopilot's local origin; yaw from north towards east, radians.
* **Robot cell ENU**: ``x`` east, ``y`` north, ``z`` up, metres; this is the base frame of
  :class:`~schemas.GraspTarget` when the cell is laid out along the compass. Its origin
  sits at ``cell_origin_ned`` in the local NED frame; :func:`ned_from_enu` and
  :func:`yaw_ned_from_enu` convert, :func:`enu_from_ned` goes back.
* **Body FRD**: ``x`` forward, ``y`` right, ``z`` down; the gripper sits at
  :attr:`ApproachConfig.end_effector_frd` in it.

The approach (:func:`plan_approach`) holds a standoff before the target along the heading,
then moves the gripper onto it; :func:`check_plan` refuses a plan that leaves the
:class:`Geofence` (:class:`~adapters.errors.UnsafeTargetError`) before anything is sent.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from adapters.errors import UnsafeTargetError

MAX_SPEED_M_S = 2.0
"""Hard cap on the speed of the streamed setpoints, whatever the caller asks."""

Vector3 = tuple[float, float, float]


# -- frames (pure) ------------------------------------------------------------------------


def ned_from_enu(point_enu: Sequence[float], cell_origin_ned: Sequence[float] = (0, 0, 0)):
    """Convert a point from the robot-cell ENU frame to the local NED frame.

    ``(east, north, up)`` becomes ``(north, east, -up)``, then the cell origin (given in
    NED) is added: ``p_ned = (y, x, -z) + cell_origin_ned``.

    Parameters
    ----------
    point_enu
        ``(x_east, y_north, z_up)``, metres.
    cell_origin_ned
        Where the cell's origin lies in the local NED frame, metres.

    Returns
    -------
    ndarray, shape (3,)
    """
    x, y, z = finite3(point_enu, "point_enu")
    return np.array([y, x, -z]) + finite3(cell_origin_ned, "cell_origin_ned")


def enu_from_ned(point_ned: Sequence[float], cell_origin_ned: Sequence[float] = (0, 0, 0)):
    """Inverse of :func:`ned_from_enu`: a local NED point in the robot-cell ENU frame."""
    north, east, down = finite3(point_ned, "point_ned") - finite3(
        cell_origin_ned, "cell_origin_ned"
    )
    return np.array([east, north, -down])


def yaw_ned_from_enu(yaw_enu: float) -> float:
    """Heading in NED (from north towards east) of a yaw in ENU (from east towards north).

    ``psi_ned = pi/2 - psi_enu``, wrapped to ``[-pi, pi]``; the map is its own inverse.
    """
    return math.remainder(math.pi / 2 - yaw_enu, 2 * math.pi)


def body_to_ned(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Rotation taking body FRD vectors to NED (aerospace Z-Y-X order: yaw, pitch, roll)."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def end_effector_ned(
    position_ned: Sequence[float],
    roll: float,
    pitch: float,
    yaw: float,
    end_effector_frd: Sequence[float],
) -> np.ndarray:
    """Where the gripper is in NED, given the vehicle's position and attitude."""
    return np.asarray(position_ned, dtype=float) + body_to_ned(roll, pitch, yaw) @ np.asarray(
        end_effector_frd, dtype=float
    )


def require_positive(config: object, names: Sequence[str]) -> None:
    """Raise ValueError unless each named field of ``config`` is finite and > 0."""
    for name in names:
        value = getattr(config, name)
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be finite and > 0, got {value}")


def finite3(values: Sequence[float], name: str) -> np.ndarray:
    """``values`` as a float array of shape (3,); ValueError unless three finite numbers."""
    vector = np.asarray(values, dtype=float)
    if vector.shape != (3,) or not np.all(np.isfinite(vector)):
        raise ValueError(f"{name} must be three finite numbers, got {values!r}")
    return vector


# -- configuration, fence and approach planning (pure) ------------------------------------


@dataclass(frozen=True)
class Geofence:
    """An axis-aligned box in the local NED frame, metres (``down`` < 0 is above the origin).

    The default reaches 10 cm below the origin so that a vehicle standing on the ground
    at the origin, its position a little noisy, is still inside.
    """

    north: tuple[float, float] = (-5.0, 5.0)
    east: tuple[float, float] = (-5.0, 5.0)
    down: tuple[float, float] = (-3.0, 0.1)

    def __post_init__(self) -> None:
        for name in ("north", "east", "down"):
            low, high = getattr(self, name)
            if not (math.isfinite(low) and math.isfinite(high) and low < high):
                raise ValueError(f"geofence {name} must be finite with low < high")

    def contains(self, point_ned: Sequence[float]) -> bool:
        """True when ``point_ned`` lies inside the box (borders included)."""
        north, east, down = finite3(point_ned, "point_ned")
        return (
            self.north[0] <= north <= self.north[1]
            and self.east[0] <= east <= self.east[1]
            and self.down[0] <= down <= self.down[1]
        )

    def check(self, point_ned: Sequence[float], what: str) -> None:
        """Raise :class:`UnsafeTargetError` when ``point_ned`` is outside the box."""
        if not self.contains(point_ned):
            shown = ", ".join(f"{v:.3f}" for v in np.asarray(point_ned, dtype=float))
            raise UnsafeTargetError(
                f"{what} [{shown}] (NED, m) is outside the geofence north {self.north}, "
                f"east {self.east}, down {self.down}"
            )


@dataclass(frozen=True)
class ApproachConfig:
    """The grasp approach: standoff, final move, closing rule and limits."""

    end_effector_frd: Vector3 = (0.40, 0.0, 0.20)
    """Gripper position in the body frame (forward, right, down), m."""
    standoff_m: float = 0.5
    """Distance of the standoff from the grasp point, against the approach direction."""
    tolerance_m: float = 0.010
    """The gripper closes once the end-effector error stayed below this ..."""
    dwell_s: float = 0.3
    """... for this long, s."""
    standoff_tolerance_m: float = 0.05
    """The final move starts once the vehicle is this close to the standoff ..."""
    settle_speed_m_s: float = 0.1
    """... and slower than this."""
    transit_speed_m_s: float = 1.0
    """Setpoint speed to the standoff."""
    approach_speed_m_s: float = 0.25
    """Setpoint speed of the final move onto the target."""
    timeout_s: float = 30.0
    """Give up (and hold) when the approach takes longer."""

    def __post_init__(self) -> None:
        finite3(self.end_effector_frd, "end_effector_frd")
        require_positive(
            self,
            (
                "standoff_m",
                "tolerance_m",
                "standoff_tolerance_m",
                "settle_speed_m_s",
                "transit_speed_m_s",
                "approach_speed_m_s",
                "timeout_s",
            ),
        )
        if not (math.isfinite(self.dwell_s) and self.dwell_s >= 0):
            raise ValueError(f"dwell_s must be finite and >= 0, got {self.dwell_s}")
        for name in ("transit_speed_m_s", "approach_speed_m_s"):
            if getattr(self, name) > MAX_SPEED_M_S:
                raise ValueError(f"{name} must be <= {MAX_SPEED_M_S} m/s")


@dataclass(frozen=True)
class ApproachPlan:
    """Vehicle positions (NED) of the two legs of an approach, and the heading."""

    target_ned: np.ndarray
    """The grasp point the end-effector must reach."""
    standoff_ned: np.ndarray
    """Vehicle position with the end-effector ``standoff_m`` short of the target."""
    final_ned: np.ndarray
    """Vehicle position with the end-effector on the target."""
    yaw_ned: float
    """Heading of the vehicle; the approach runs along it."""


def plan_approach(
    target_ned: Sequence[float], yaw_ned: float, config: ApproachConfig
) -> ApproachPlan:
    """Where the vehicle must be to hold the standoff and to put the gripper on the target.

    The vehicle is level and faces ``yaw_ned``; the approach direction is that heading,
    horizontal. The end-effector first waits ``standoff_m`` before the target along it,
    then moves forward onto the target.
    """
    target = finite3(target_ned, "target_ned")
    if not math.isfinite(yaw_ned):
        raise ValueError(f"yaw_ned must be finite, got {yaw_ned}")
    offset = body_to_ned(0.0, 0.0, yaw_ned) @ np.asarray(config.end_effector_frd, dtype=float)
    heading = np.array([math.cos(yaw_ned), math.sin(yaw_ned), 0.0])
    final = target - offset
    return ApproachPlan(
        target_ned=target,
        standoff_ned=final - config.standoff_m * heading,
        final_ned=final,
        yaw_ned=yaw_ned,
    )


def check_plan(plan: ApproachPlan, fence: Geofence) -> None:
    """Refuse a plan any point of which (target, standoff, final position) leaves the fence."""
    fence.check(plan.target_ned, "grasp target")
    fence.check(plan.standoff_ned, "standoff position")
    fence.check(plan.final_ned, "final vehicle position")
