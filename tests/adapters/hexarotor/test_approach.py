"""Frames, the approach plan and the geofence of the hexarotor (pure)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from adapters.errors import UnsafeTargetError
from adapters.hexarotor.approach import (
    ApproachConfig,
    Geofence,
    body_to_ned,
    check_plan,
    end_effector_ned,
    enu_from_ned,
    ned_from_enu,
    plan_approach,
    yaw_ned_from_enu,
)
from adapters.hexarotor.driver import LinkConfig

# -- frames ------------------------------------------------------------------------------


def test_ned_from_enu_swaps_the_horizontal_axes_and_flips_up() -> None:
    assert ned_from_enu((1.0, 2.0, 3.0)) == pytest.approx([2.0, 1.0, -3.0])
    assert ned_from_enu((1.0, 2.0, 3.0), (10.0, 20.0, -1.0)) == pytest.approx([12.0, 21.0, -4.0])


def test_enu_and_ned_round_trip() -> None:
    rng = np.random.default_rng(3)
    origin = rng.normal(size=3)
    for point in rng.normal(size=(20, 3)):
        assert enu_from_ned(ned_from_enu(point, origin), origin) == pytest.approx(point)


def test_yaw_conversion_maps_compass_directions() -> None:
    assert yaw_ned_from_enu(0.0) == pytest.approx(math.pi / 2)  # facing east
    assert yaw_ned_from_enu(math.pi / 2) == pytest.approx(0.0)  # facing north
    assert yaw_ned_from_enu(yaw_ned_from_enu(0.7)) == pytest.approx(0.7)


def test_yaw_conversion_agrees_with_the_point_conversion() -> None:
    yaw_enu = 0.4
    heading_enu = (math.cos(yaw_enu), math.sin(yaw_enu), 0.0)
    heading_ned = ned_from_enu(heading_enu)
    yaw_ned = yaw_ned_from_enu(yaw_enu)
    assert heading_ned == pytest.approx([math.cos(yaw_ned), math.sin(yaw_ned), 0.0])


def test_body_to_ned_is_a_rotation_and_yaw_turns_forward_east() -> None:
    rotation = body_to_ned(0.1, -0.2, 0.3)
    assert rotation @ rotation.T == pytest.approx(np.eye(3))
    assert np.linalg.det(rotation) == pytest.approx(1.0)
    assert body_to_ned(0, 0, math.pi / 2) @ [1, 0, 0] == pytest.approx([0, 1, 0], abs=1e-12)
    # Pitching nose up lifts a point ahead of the vehicle (NED: more negative down).
    assert (body_to_ned(0, 0.1, 0) @ [1, 0, 0])[2] < 0


def test_end_effector_follows_position_and_heading() -> None:
    where = end_effector_ned((1.0, 2.0, -1.0), 0.0, 0.0, math.pi, (0.4, 0.0, 0.2))
    assert where == pytest.approx([0.6, 2.0, -0.8])


# -- planning and the fence --------------------------------------------------------------


def test_plan_puts_the_gripper_on_the_target_after_a_standoff() -> None:
    config = ApproachConfig(end_effector_frd=(0.4, 0.1, 0.2), standoff_m=0.5)
    target = np.array([2.0, 1.0, -1.0])
    plan = plan_approach(target, 0.6, config)
    final_gripper = end_effector_ned(plan.final_ned, 0, 0, 0.6, config.end_effector_frd)
    standoff_gripper = end_effector_ned(plan.standoff_ned, 0, 0, 0.6, config.end_effector_frd)
    assert final_gripper == pytest.approx(target)
    heading = np.array([math.cos(0.6), math.sin(0.6), 0.0])
    assert target - standoff_gripper == pytest.approx(0.5 * heading)


def test_fence_refuses_points_outside() -> None:
    fence = Geofence(north=(-1, 1), east=(-1, 1), down=(-2, 0))
    assert fence.contains((0.5, -0.5, -1.0))
    assert not fence.contains((0.5, -0.5, -2.5))
    with pytest.raises(UnsafeTargetError, match="outside the geofence"):
        fence.check((1.5, 0, -1), "setpoint")
    # The target inside but the standoff (0.5 m behind it) outside: refused.
    plan = plan_approach((-0.9, 0.0, -1.0), 0.0, ApproachConfig(end_effector_frd=(0, 0, 0)))
    with pytest.raises(UnsafeTargetError, match="standoff"):
        check_plan(plan, fence)


def test_configurations_are_validated() -> None:
    assert LinkConfig().link_loss_s == 2.0
    assert ApproachConfig().tolerance_m == 0.010
    with pytest.raises(ValueError, match="setpoint_rate_hz"):
        LinkConfig(setpoint_rate_hz=5.0)
    with pytest.raises(ValueError, match="low < high"):
        Geofence(north=(1.0, -1.0))
    with pytest.raises(ValueError, match="tolerance_m"):
        ApproachConfig(tolerance_m=0.0)
    with pytest.raises(ValueError, match=r"<= 2\.0"):
        ApproachConfig(transit_speed_m_s=5.0)
