"""The arm pick as motions: tool-down orientation, approach-descend-close-lift, speed caps."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from adapters.grasp.motions import (
    MAX_ACCELERATION_M_S2,
    MAX_SPEED_M_S,
    UR3Config,
    Workspace,
    plan_motions,
    tool_down_rotation_vector,
)
from tests.adapters.builders import grasp_target as target


def rz(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


RX_PI = np.diag([1.0, -1.0, -1.0])


@pytest.mark.parametrize("yaw", [0.0, 0.3, -1.2, math.pi / 2, -math.pi / 2 + 1e-6])
def test_tool_down_rotation_vector_is_rz_yaw_times_rx_pi(yaw):
    rotvec = np.array(tool_down_rotation_vector(yaw))
    assert np.linalg.norm(rotvec) == pytest.approx(math.pi)
    matrix, _ = cv2.Rodrigues(rotvec)
    np.testing.assert_allclose(matrix, rz(yaw) @ RX_PI, atol=1e-12)
    np.testing.assert_allclose(matrix[:, 0], [math.cos(yaw), math.sin(yaw), 0], atol=1e-12)
    np.testing.assert_allclose(matrix[:, 2], [0, 0, -1], atol=1e-12)


def test_plan_motions_is_approach_descend_close_lift_in_metres():
    motions = plan_motions(target(yaw=0.3), UR3Config())
    rot = tool_down_rotation_vector(0.3)
    approach = (0.3, 0.1, 0.015 + 0.10, *rot)
    grasp = (0.3, 0.1, 0.015, *rot)
    assert [(m.label, m.kind) for m in motions] == [
        ("approach", "moveL"),
        ("descend", "moveL"),
        ("close_gripper", "gripper"),
        ("lift", "moveL"),
    ]
    assert [m.pose for m in motions] == [
        pytest.approx(approach),
        pytest.approx(grasp),
        None,
        pytest.approx(approach),
    ]
    assert {(m.speed_m_s, m.acceleration_m_s2) for m in motions if m.kind == "moveL"} == {
        (0.25, 0.5)
    }
    assert motions[2].output_value is True


def test_speeds_are_clamped_to_the_caps():
    config = UR3Config(speed_m_s=3.0, acceleration_m_s2=10.0)
    for motion in plan_motions(target(), config):
        if motion.kind == "moveL":
            assert motion.speed_m_s == MAX_SPEED_M_S
            assert motion.acceleration_m_s2 == MAX_ACCELERATION_M_S2
    slow = plan_motions(target(), UR3Config(speed_m_s=0.05, acceleration_m_s2=0.2))
    assert (slow[0].speed_m_s, slow[0].acceleration_m_s2) == (0.05, 0.2)
    with pytest.raises(ValueError, match="speed_m_s must be a positive number"):
        UR3Config(speed_m_s=0.0)


def test_gripper_yaw_offset_turns_the_tool():
    motions = plan_motions(target(yaw=0.3), UR3Config(gripper_yaw_offset_rad=math.pi / 2))
    assert motions[0].pose[3:] == pytest.approx(tool_down_rotation_vector(0.3 - math.pi / 2))


def test_workspace_defaults():
    workspace = Workspace()
    assert workspace.max_radius_m == pytest.approx(0.45)
    assert (workspace.table_z_m, workspace.clearance_m, workspace.keep_out_radius_m) == (
        0.0,
        0.01,
        0.10,
    )
