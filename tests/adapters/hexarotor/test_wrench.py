"""Wrench-set feasibility: analytic cases, symmetries, and an independent brute-force check."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from scipy.spatial import ConvexHull

from adapters.hexarotor.wrench import (
    GRAVITY_M_S2,
    HexarotorGeometry,
    InfeasibleHoverError,
    allocation_matrix,
    max_force_along,
    pull_feasibility,
    rotor_axes,
    slice_axis_for,
    slice_polygon,
)

DEFAULT = HexarotorGeometry()


def rotation_z(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def test_rotor_axes_are_unit_and_tilted_about_their_arms() -> None:
    geometry = HexarotorGeometry(tilt_deg=20.0)
    positions, axes = rotor_axes(geometry)
    assert np.linalg.norm(axes, axis=1) == pytest.approx(np.ones(6))
    assert axes[:, 2] == pytest.approx(np.full(6, math.cos(math.radians(20.0))))
    # Tilting about the radial axis keeps the axis perpendicular to the arm.
    assert np.einsum("ij,ij->i", positions, axes) == pytest.approx(np.zeros(6), abs=1e-12)
    # Rotor 0 sits on +x; +20 deg about +x (right hand) leans its axis towards -y.
    assert positions[0] == pytest.approx([0.3, 0.0, 0.0])
    tilt = math.radians(20.0)
    assert axes[0] == pytest.approx([0.0, -math.sin(tilt), math.cos(tilt)])
    # Rotor 1 (odd, -20 deg) leans the other way: along its arm's counter-clockwise tangent.
    tangent = np.array([-math.sin(math.pi / 3), math.cos(math.pi / 3), 0.0])
    assert axes[1] @ tangent == pytest.approx(math.sin(tilt))


def test_drag_torque_alternates_with_even_rotors_counter_clockwise() -> None:
    flat = HexarotorGeometry(tilt_deg=0.0, drag_coeff_m=0.02)
    yaw_torque = allocation_matrix(flat)[5]
    assert yaw_torque == pytest.approx([0.02, -0.02] * 3)


def test_zero_tilt_gives_no_lateral_force_at_zero_torque() -> None:
    flat = HexarotorGeometry(tilt_deg=0.0)
    for angle in np.linspace(0.0, 2 * math.pi, 7):
        assert max_force_along(flat, (math.cos(angle), math.sin(angle), 0.0)) == pytest.approx(
            0.0, abs=1e-7
        )
    assert slice_polygon(flat, samples=24)[:, 0] == pytest.approx(np.zeros(24), abs=1e-7)


@pytest.mark.parametrize("tilt_deg", [0.0, 15.0, 30.0])
def test_vertical_reach_is_all_rotors_at_full_thrust_or_all_off(tilt_deg: float) -> None:
    geometry = HexarotorGeometry(tilt_deg=tilt_deg)
    weight = geometry.mass_kg * GRAVITY_M_S2
    up = 6 * geometry.max_thrust_n * math.cos(math.radians(tilt_deg)) - weight
    assert max_force_along(geometry, (0, 0, 1)) == pytest.approx(up)
    # Pushing down on the environment: rotors off, the weight rests on it. This is the sign
    # convention: the force is the one the vehicle exerts on the environment.
    assert max_force_along(geometry, (0, 0, -1)) == pytest.approx(weight)


def test_a_third_turn_and_the_fore_aft_mirror_are_symmetries() -> None:
    rng = np.random.default_rng(7)
    third_turn = rotation_z(2 * math.pi / 3)
    for direction in rng.normal(size=(6, 3)):
        reach = max_force_along(DEFAULT, direction)
        assert max_force_along(DEFAULT, third_turn @ direction) == pytest.approx(reach, rel=1e-6)
        mirrored = direction * np.array([-1.0, 1.0, 1.0])
        assert max_force_along(DEFAULT, mirrored) == pytest.approx(reach, rel=1e-6)


def test_direction_length_does_not_matter() -> None:
    assert max_force_along(DEFAULT, (2.0, 0.0, 0.0)) == pytest.approx(
        max_force_along(DEFAULT, (0.5, 0.0, 0.0))
    )


def brute_force_reach(geometry: HexarotorGeometry, direction: np.ndarray) -> float:
    """Independent of the LP: every vertex of {thrusts in the box, zero torque}, their forces'
    convex hull, then how far the ray from the hover force along ``direction`` stays inside."""
    allocation = allocation_matrix(geometry)
    forces, torques = allocation[:3], allocation[3:]
    vertices = []
    for fixed in itertools.combinations(range(6), 3):
        free = [i for i in range(6) if i not in fixed]
        square = torques[:, free]
        if abs(np.linalg.det(square)) < 1e-12:
            continue
        for levels in itertools.product((0.0, geometry.max_thrust_n), repeat=3):
            thrusts = np.zeros(6)
            thrusts[list(fixed)] = levels
            thrusts[free] = np.linalg.solve(square, -torques[:, list(fixed)] @ np.array(levels))
            if np.all(thrusts >= -1e-9) and np.all(thrusts <= geometry.max_thrust_n + 1e-9):
                vertices.append(forces @ thrusts)
    hull = ConvexHull(np.array(vertices))
    hover = np.array([0.0, 0.0, geometry.mass_kg * GRAVITY_M_S2])
    unit = direction / np.linalg.norm(direction)
    normals, offsets = hull.equations[:, :3], hull.equations[:, 3]
    assert np.all(normals @ hover + offsets <= 1e-9), "hover must be attainable"
    ahead = normals @ unit > 1e-12
    return float(np.min(-(normals[ahead] @ hover + offsets[ahead]) / (normals[ahead] @ unit)))


@pytest.mark.parametrize(
    "geometry",
    [
        DEFAULT,
        HexarotorGeometry(mass_kg=2.0, tilt_deg=20.0, max_thrust_n=10.0, drag_coeff_m=0.01),
        HexarotorGeometry(mass_kg=4.0, arm_length_m=0.4, tilt_deg=35.0, max_thrust_n=20.0),
    ],
)
def test_agrees_with_brute_force_over_the_thrusts(geometry: HexarotorGeometry) -> None:
    rng = np.random.default_rng(11)
    for direction in [*np.eye(3), *rng.normal(size=(8, 3))]:
        assert max_force_along(geometry, direction) == pytest.approx(
            brute_force_reach(geometry, direction), rel=1e-6, abs=1e-6
        )


def test_pull_feasibility_reports_the_margin() -> None:
    reach = max_force_along(DEFAULT, (1, 0, 0))
    easy = pull_feasibility(DEFAULT, reach / 2, (1, 0, 0))
    assert easy.feasible and easy.hover_feasible
    assert easy.max_force_n == pytest.approx(reach)
    assert easy.margin_n == pytest.approx(reach / 2)
    hard = pull_feasibility(DEFAULT, reach + 1.0, (1, 0, 0))
    assert not hard.feasible
    assert hard.margin_n == pytest.approx(-1.0)
    assert pull_feasibility(DEFAULT, reach, (1, 0, 0)).feasible  # exactly at the limit


def test_a_vehicle_too_heavy_to_hover() -> None:
    heavy = HexarotorGeometry(mass_kg=50.0)
    with pytest.raises(InfeasibleHoverError, match="cannot hold its weight"):
        max_force_along(heavy, (1, 0, 0))
    answer = pull_feasibility(heavy, 1.0, (1, 0, 0))
    assert not answer.feasible and not answer.hover_feasible
    assert answer.max_force_n == 0.0 and answer.margin_n == -1.0


def test_slice_is_a_convex_polygon_around_the_origin() -> None:
    polygon = slice_polygon(DEFAULT, (1.0, 0.0, 0.0), samples=36)
    hull = ConvexHull(polygon)
    assert len(hull.vertices) >= 4
    assert np.all(hull.equations[:, :2] @ np.zeros(2) + hull.equations[:, 2] < 0)
    up = polygon[9]  # sample 9 of 36 points straight up
    assert up == pytest.approx([0.0, max_force_along(DEFAULT, (0, 0, 1))], abs=1e-6)


def test_slice_axis_keeps_the_pull_in_the_plane() -> None:
    assert slice_axis_for((1, 0, 0)) == pytest.approx([1, 0, 0])
    assert slice_axis_for((0, -2, 1)) == pytest.approx([0, 1, 0])  # drawn pointing left
    assert slice_axis_for((0, 0, -1)) == pytest.approx([0, 1, 0])  # vertical: the y-z view


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("mass_kg", 0.0),
        ("arm_length_m", -1.0),
        ("tilt_deg", 90.0),
        ("max_thrust_n", math.nan),
        ("drag_coeff_m", -0.1),
    ],
)
def test_invalid_geometry_is_refused(field: str, value: float) -> None:
    with pytest.raises(ValueError, match=field):
        HexarotorGeometry(**{field: value})


def test_invalid_questions_are_refused() -> None:
    with pytest.raises(ValueError, match="zero vector"):
        max_force_along(DEFAULT, (0, 0, 0))
    with pytest.raises(ValueError, match="three finite"):
        max_force_along(DEFAULT, (1, 0))
    with pytest.raises(ValueError, match="pull"):
        pull_feasibility(DEFAULT, -1.0, (1, 0, 0))
    with pytest.raises(ValueError, match="horizontal"):
        slice_polygon(DEFAULT, (0, 0, 1))
