"""Wrench-set feasibility of a fully-actuated hexarotor: can it pull this hard and still hover?

Everything here is a pure function of a :class:`HexarotorGeometry`; no hardware, no I/O.

Frames and conventions
----------------------
* Body frame: ``x`` forward, ``y`` left, ``z`` up, origin at the centre of mass. The
  vehicle is level (its body ``z`` is the world's up), so its weight is ``(0, 0, -m g)``.
* Rotor ``i`` (``i = 0..5``) sits at azimuth ``60 i`` degrees (counter-clockwise from
  ``x`` seen from above), ``arm_length`` from the origin in the ``x-y`` plane. Its thrust
  axis is body ``z`` turned about the arm's radial axis by ``+tilt`` for even ``i`` and
  ``-tilt`` for odd ``i`` (right-hand rule), so with ``e_t`` the arm's tangential unit
  vector (counter-clockwise) the axis is ``u_i = cos(a_i) z - sin(a_i) e_t``.
* Thrust ``f_i`` lies in ``[0, max_thrust]`` and acts along ``u_i``. The rotor's drag
  torque is ``drag_coeff * f_i`` about ``u_i``, counter-clockwise (``+u_i``) for even ``i``
  and clockwise (``-u_i``) for odd ``i``.
* **Sign of the pull.** ``pull`` newtons along a unit ``direction`` is the force the
  vehicle exerts *on the environment*. The environment pushes back on the vehicle with
  ``-pull * direction``, so in equilibrium the rotors must produce
  ``sum_i f_i u_i = m g z + pull * direction`` and, the contact force being taken to act
  through the centre of mass, zero net torque ``sum_i f_i (r_i x u_i +/- drag_coeff u_i) = 0``.
  The "remaining" force of the slice plots is the same quantity: rotor force minus what
  holding the weight takes, i.e. what the vehicle can push (or pull) on the world with.

Every question is a linear program over the six thrusts (:func:`scipy.optimize.linprog`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

GRAVITY_M_S2 = 9.80665
ROTORS = 6

DEFAULT_MASS_KG = 3.0
"""A 3 kg fully-actuated hexarotor with a light gripper (the defaults of ``dlo feasibility``)."""
DEFAULT_ARM_LENGTH_M = 0.30
DEFAULT_TILT_DEG = 30.0
DEFAULT_MAX_THRUST_N = 15.0
"""Per rotor: about 1.5 kgf, a 10-11 inch propeller on a 4S motor; thrust-to-weight about 2.6."""
DEFAULT_DRAG_COEFF_M = 0.016
"""Drag torque per newton of thrust, metres (typical for 10-inch propellers)."""


class InfeasibleHoverError(ValueError):
    """The vehicle cannot hold its own weight with zero net torque, whatever it pulls."""


@dataclass(frozen=True)
class HexarotorGeometry:
    """Mass and rotor layout of a fully-actuated hexarotor (see the module docstring).

    Attributes
    ----------
    mass_kg : float
        Total mass, kg (> 0).
    arm_length_m : float
        Distance of each rotor from the centre, m (> 0).
    tilt_deg : float
        Magnitude of the alternating rotor tilt, degrees, in ``[0, 90)``.
    max_thrust_n : float
        Largest thrust of one rotor, N (> 0).
    drag_coeff_m : float
        Drag torque per unit thrust, m (>= 0).
    """

    mass_kg: float = DEFAULT_MASS_KG
    arm_length_m: float = DEFAULT_ARM_LENGTH_M
    tilt_deg: float = DEFAULT_TILT_DEG
    max_thrust_n: float = DEFAULT_MAX_THRUST_N
    drag_coeff_m: float = DEFAULT_DRAG_COEFF_M

    def __post_init__(self) -> None:
        checks = {
            "mass_kg": self.mass_kg > 0,
            "arm_length_m": self.arm_length_m > 0,
            "tilt_deg": 0 <= self.tilt_deg < 90,
            "max_thrust_n": self.max_thrust_n > 0,
            "drag_coeff_m": self.drag_coeff_m >= 0,
        }
        for name, ok in checks.items():
            value = getattr(self, name)
            if not math.isfinite(value) or not ok:
                allowed = {
                    "tilt_deg": "in [0, 90)",
                    "drag_coeff_m": ">= 0",
                }.get(name, "> 0")
                raise ValueError(f"{name} must be finite and {allowed}, got {value}")

    @property
    def weight_n(self) -> float:
        """The weight ``m g``, N."""
        return self.mass_kg * GRAVITY_M_S2


@dataclass(frozen=True)
class PullFeasibility:
    """The answer of :func:`pull_feasibility`.

    Attributes
    ----------
    feasible : bool
        The requested pull can be exerted while hovering with zero net torque.
    max_force_n : float
        Largest force the vehicle can exert along the direction while hovering, N
        (0 when it cannot even hover; see :attr:`hover_feasible`).
    margin_n : float
        ``max_force_n - pull``: positive means force to spare, N.
    hover_feasible : bool
        The vehicle can hold its weight with zero torque at all.
    """

    feasible: bool
    max_force_n: float
    margin_n: float
    hover_feasible: bool


def rotor_axes(geometry: HexarotorGeometry) -> tuple[np.ndarray, np.ndarray]:
    """Positions and unit thrust axes of the six rotors in the body frame.

    Returns
    -------
    positions, axes : ndarray, shape (6, 3)
    """
    azimuths = np.radians(60.0 * np.arange(ROTORS))
    tilts = np.radians(geometry.tilt_deg) * np.where(np.arange(ROTORS) % 2 == 0, 1.0, -1.0)
    radial = np.stack([np.cos(azimuths), np.sin(azimuths), np.zeros(ROTORS)], axis=1)
    tangential = np.stack([-np.sin(azimuths), np.cos(azimuths), np.zeros(ROTORS)], axis=1)
    up = np.array([0.0, 0.0, 1.0])
    # Rodrigues about the radial axis: z -> cos(a) z + sin(a) (radial x z) = cos(a) z - sin(a) t.
    axes = np.cos(tilts)[:, None] * up - np.sin(tilts)[:, None] * tangential
    return geometry.arm_length_m * radial, axes


def allocation_matrix(geometry: HexarotorGeometry) -> np.ndarray:
    """The 6 x 6 map from rotor thrusts to the body wrench ``[force; torque]``.

    Column ``i`` is the wrench of one newton of thrust on rotor ``i``: force ``u_i`` and
    torque ``r_i x u_i + s_i drag_coeff u_i`` with ``s_i = +1`` for even ``i``, ``-1`` odd.
    """
    positions, axes = rotor_axes(geometry)
    spin = np.where(np.arange(ROTORS) % 2 == 0, 1.0, -1.0)
    torques = np.cross(positions, axes) + geometry.drag_coeff_m * spin[:, None] * axes
    return np.vstack([axes.T, torques.T])


def _unit(direction: np.ndarray | tuple[float, float, float]) -> np.ndarray:
    vector = np.asarray(direction, dtype=float)
    if vector.shape != (3,) or not np.all(np.isfinite(vector)):
        raise ValueError(f"direction must be three finite numbers, got {direction!r}")
    norm = float(np.linalg.norm(vector))
    if norm < 1e-12:
        raise ValueError("direction must not be the zero vector")
    return vector / norm


def max_force_along(geometry: HexarotorGeometry, direction: np.ndarray | tuple) -> float:
    """Largest force the hovering vehicle can exert on the environment along ``direction``.

    Solves ``max p`` over thrusts ``f`` in ``[0, max_thrust]^6`` and ``p >= 0`` subject to
    ``forces(f) = m g z + p d`` and ``torques(f) = 0``.

    Parameters
    ----------
    geometry
        The vehicle.
    direction
        Body-frame direction ``d`` (normalised here), three numbers, not all zero.

    Returns
    -------
    float
        ``p`` in newtons.

    Raises
    ------
    InfeasibleHoverError
        When no thrusts hold the weight with zero torque even without pulling.
    ValueError
        On a zero or non-finite direction.
    """
    from scipy.optimize import linprog  # here: importing the module stays light for the CLI

    unit = _unit(direction)
    allocation = allocation_matrix(geometry)
    # Variables [f_0..f_5, p]; equality rows: A f - p [d; 0] = [m g z; 0].
    equality = np.hstack([allocation, -np.concatenate([unit, np.zeros(3)])[:, None]])
    target = np.array([0.0, 0.0, geometry.weight_n, 0.0, 0.0, 0.0])
    cost = np.zeros(ROTORS + 1)
    cost[-1] = -1.0
    bounds = [(0.0, geometry.max_thrust_n)] * ROTORS + [(0.0, None)]
    result = linprog(cost, A_eq=equality, b_eq=target, bounds=bounds, method="highs")
    if result.status == 2:
        raise InfeasibleHoverError(
            f"a {geometry.mass_kg} kg vehicle with {ROTORS} x {geometry.max_thrust_n} N rotors "
            f"tilted {geometry.tilt_deg} deg cannot hold its weight with zero net torque"
        )
    if result.status != 0:  # pragma: no cover - bounded thrusts keep the problem bounded
        raise RuntimeError(f"linear program failed: {result.message}")
    return max(float(result.x[-1]), 0.0)


def pull_feasibility(
    geometry: HexarotorGeometry, pull_n: float, direction: np.ndarray | tuple
) -> PullFeasibility:
    """Can the vehicle exert ``pull_n`` newtons on the environment along ``direction``?

    Parameters
    ----------
    geometry
        The vehicle.
    pull_n
        Required force on the environment, N (>= 0).
    direction
        Body-frame direction of that force (normalised here).

    Returns
    -------
    PullFeasibility
        Feasibility, the largest force along ``direction`` and the margin. When the
        vehicle cannot hover at all, ``max_force_n`` is 0 and ``hover_feasible`` false.
    """
    if not math.isfinite(pull_n) or pull_n < 0:
        raise ValueError(f"pull must be finite and >= 0 N, got {pull_n}")
    try:
        max_force = max_force_along(geometry, direction)
        hover = True
    except InfeasibleHoverError:
        max_force, hover = 0.0, False
    # A hair of slack: the LP optimum carries ~1e-9 N of solver tolerance.
    feasible = hover and max_force >= pull_n - 1e-7
    return PullFeasibility(feasible, max_force, max_force - pull_n, hover)


def slice_polygon(
    geometry: HexarotorGeometry,
    horizontal: np.ndarray | tuple = (0.0, 1.0, 0.0),
    samples: int = 180,
) -> np.ndarray:
    """The slice of the hover-and-zero-torque force set by a vertical plane, as a polygon.

    The plane is spanned by the horizontal unit vector ``horizontal`` and body ``z``; the
    slice holds every force the vehicle can exert on the environment in that plane.
    Its boundary is traced by :func:`max_force_along` over ``samples`` directions.

    Returns
    -------
    ndarray, shape (samples, 2)
        Boundary points as ``(along horizontal, along z)`` in newtons, counter-clockwise.

    Raises
    ------
    InfeasibleHoverError
        When the vehicle cannot hover (the slice is empty).
    ValueError
        When ``horizontal`` has a vertical component or is zero, or ``samples < 8``.
    """
    axis = _unit(horizontal)
    if abs(axis[2]) > 1e-9:
        raise ValueError(f"horizontal must lie in the body x-y plane, got {horizontal!r}")
    if samples < 8:
        raise ValueError(f"samples must be at least 8, got {samples}")
    angles = np.linspace(0.0, 2.0 * math.pi, samples, endpoint=False)
    up = np.array([0.0, 0.0, 1.0])
    points = []
    for angle in angles:
        direction = math.cos(angle) * axis + math.sin(angle) * up
        reach = max_force_along(geometry, direction)
        points.append((reach * math.cos(angle), reach * math.sin(angle)))
    return np.array(points)


def slice_axis_for(direction: np.ndarray | tuple) -> np.ndarray:
    """The horizontal axis of the slice plane that contains ``direction`` and body ``z``.

    A vertical direction has no horizontal part; body ``y`` is used then (the paper's
    ``y-z`` view). The sign is chosen so that the larger of the axis's ``x`` and ``y``
    components is positive: a pull along ``-y`` is drawn in the ``y-z`` plane, pointing left.
    """
    unit = _unit(direction)
    horizontal = np.array([unit[0], unit[1], 0.0])
    norm = float(np.linalg.norm(horizontal))
    if norm < 1e-9:
        return np.array([0.0, 1.0, 0.0])
    dominant = horizontal[0] if abs(horizontal[0]) >= abs(horizontal[1]) else horizontal[1]
    return horizontal / norm * math.copysign(1.0, dominant)
