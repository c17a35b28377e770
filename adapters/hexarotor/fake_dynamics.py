"""The fake vehicle's physics: a closed position loop, bounded acceleration, gusts, noise.

Pure: :func:`step_dynamics` advances the state by one step; :class:`Disturbance` and
:class:`Dynamics` hold the settings.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

PHYSICS_STEP_S = 0.005


@dataclass(frozen=True)
class Disturbance:
    """Wind gusts and sensor noise of the fake (the defaults are the ``dlo hexa trial`` ones).

    Attributes
    ----------
    gust_std_m_s2 : float
        Standard deviation of the gust acceleration per axis, m/s^2; 0.05 m/s^2 on a 3 kg
        vehicle is a 0.15 N push, a light indoor draught.
    gust_time_constant_s : float
        Correlation time of the gusts, s.
    position_noise_m : float
        Standard deviation of the reported position per axis, m (motion capture to good
        visual-inertial odometry).
    attitude_noise_rad : float
        Standard deviation of the reported roll, pitch and yaw, rad.
    """

    gust_std_m_s2: float = 0.05
    gust_time_constant_s: float = 1.0
    position_noise_m: float = 0.002
    attitude_noise_rad: float = 0.002

    def __post_init__(self) -> None:
        for name in ("gust_std_m_s2", "position_noise_m", "attitude_noise_rad"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        if not self.gust_time_constant_s > 0:
            raise ValueError(f"gust_time_constant_s must be > 0, got {self.gust_time_constant_s}")


@dataclass(frozen=True)
class Dynamics:
    """Controller gains and limits of the fake's position loop.

    The defaults make a stiff indoor position loop (natural frequency
    ``sqrt(k_p k_v)`` = 4.6 rad/s, damping 0.76), as on a fully-actuated vehicle under
    motion capture; a steady push ``d`` leaves an offset of ``d / (k_p k_v)``.
    """

    position_gain: float = 3.0
    """1/s: desired speed per metre of position error."""
    velocity_gain: float = 7.0
    """1/s: commanded acceleration per m/s of speed error."""
    max_speed_m_s: float = 2.0
    max_accel_m_s2: float = 3.0
    yaw_rate_rad_s: float = 1.5
    telemetry_hz: float = 40.0

    def __post_init__(self) -> None:
        for name, value in vars(self).items():
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be finite and > 0, got {value}")


@dataclass
class RigidState:
    """Position and velocity (NED), yaw and the current gust of the simulated vehicle."""

    position: np.ndarray
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    yaw: float = 0.0
    gust: np.ndarray = field(default_factory=lambda: np.zeros(3))


def wrap_angle(angle: float) -> float:
    """``angle`` wrapped to ``[-pi, pi]``."""
    return math.remainder(angle, 2.0 * math.pi)


def _clip_norm(vector: np.ndarray, limit: float) -> np.ndarray:
    norm = float(np.linalg.norm(vector))
    return vector * (limit / norm) if norm > limit else vector


def step_dynamics(
    position: np.ndarray,
    velocity: np.ndarray,
    yaw: float,
    target: np.ndarray,
    target_yaw: float,
    dt: float,
    dynamics: Dynamics,
    disturbance_m_s2: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, float]:
    """One semi-implicit Euler step of the fake's closed-loop position dynamics.

    ``v_des = clip(k_p (target - x), v_max)``, ``a = clip(k_v (v_des - v), a_max) + d``;
    yaw turns towards ``target_yaw`` at no more than ``yaw_rate_rad_s``. The ground
    (``z = 0`` in NED) stops downward motion.

    Parameters
    ----------
    position, velocity : ndarray, shape (3,)
        NED, m and m/s.
    yaw, target_yaw : float
        rad.
    target : ndarray, shape (3,)
        Position setpoint, NED, m.
    dt : float
        Step, s (> 0).
    dynamics : Dynamics
        Gains and limits.
    disturbance_m_s2 : ndarray, shape (3,), optional
        External acceleration (gusts) added after the controller's bounded command.

    Returns
    -------
    position, velocity, yaw
        The new state (new arrays).
    """
    desired = _clip_norm(dynamics.position_gain * (target - position), dynamics.max_speed_m_s)
    accel = _clip_norm(dynamics.velocity_gain * (desired - velocity), dynamics.max_accel_m_s2)
    if disturbance_m_s2 is not None:
        accel = accel + disturbance_m_s2
    velocity = velocity + accel * dt
    position = position + velocity * dt
    if position[2] > 0.0:  # the ground (NED: z down, ground at z = 0)
        position[2] = 0.0
        velocity[2] = min(velocity[2], 0.0)
    yaw_error = wrap_angle(target_yaw - yaw)
    turn = math.copysign(min(abs(yaw_error), dynamics.yaw_rate_rad_s * dt), yaw_error)
    return position, velocity, wrap_angle(yaw + turn)


def yaw_matrix(yaw: float) -> np.ndarray:
    """Rotation about the vertical (NED ``z``) by ``yaw``."""
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@dataclass
class Battery:
    """A simple LiPo discharge model: charge drawn at a current set by what the vehicle does.

    The cell voltage falls linearly from 4.2 V (full) to 3.5 V (empty) and sags under load
    by ``internal_resistance_ohm`` per cell. Currents: ``idle_a`` disarmed, ``armed_a``
    armed on the ground, ``hover_a`` flying (a 3 kg hexarotor hovers at a few hundred W).
    """

    capacity_mah: float = 5000.0
    cells: int = 4
    idle_a: float = 0.4
    armed_a: float = 3.0
    hover_a: float = 18.0
    internal_resistance_ohm: float = 0.004
    consumed_mah: float = 0.0
    current_a: float = 0.4

    def drain(self, current_a: float, dt: float) -> None:
        """Draw ``current_a`` for ``dt`` seconds."""
        self.current_a = current_a
        self.consumed_mah = min(self.capacity_mah, self.consumed_mah + current_a * dt / 3.6)

    @property
    def remaining(self) -> float:
        """Charge left, 0..1."""
        return max(0.0, 1.0 - self.consumed_mah / self.capacity_mah)

    @property
    def cell_voltage_v(self) -> float:
        return 3.5 + 0.7 * self.remaining - self.internal_resistance_ohm * self.current_a

    @property
    def voltage_v(self) -> float:
        return self.cells * self.cell_voltage_v
