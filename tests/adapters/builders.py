"""Builders shared by the adapter tests: a camera looking down at the table, a grasp target.

Import as ``from tests.adapters.builders import grasp_target, looking_down``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from schemas import CameraModel, GraspTarget

DOWN = np.diag([1.0, -1.0, -1.0])
"""Straight down: camera x along base +x, camera y along base -y, optical axis down."""


def looking_down(
    origin: Sequence[float],
    *,
    rotation: np.ndarray = DOWN,
    fx: float = 800.0,
    fy: float = 800.0,
    cx: float = 320.0,
    cy: float = 240.0,
    width: int = 640,
    height: int = 480,
    plane_z: float = 0.0,
    dist: Sequence[float] = (0.0, 0.0, 0.0, 0.0, 0.0),
) -> CameraModel:
    """A camera at ``origin`` (base frame, m) turned by ``rotation``, seeing the plane
    ``z = plane_z``."""
    transform = np.eye(4)
    transform[:3, :3] = rotation
    transform[:3, 3] = origin
    return CameraModel(
        fx=fx,
        fy=fy,
        cx=cx,
        cy=cy,
        width=width,
        height=height,
        dist=tuple(dist),
        T_base_camera=transform.tolist(),
        surface={"plane_z": plane_z},
    )


def grasp_target(
    x: float = 0.3, y: float = 0.1, z: float = 0.0, yaw: float = 0.3, **fields: object
) -> GraspTarget:
    """A grasp target at ``(x, y, z)`` (base frame, m) closing along ``yaw`` (rad)."""
    values: dict[str, object] = {
        "chain_id": 0,
        "segment_index": 2,
        "inferred": False,
        "pixel": (320.0, 240.0),
        **fields,
    }
    return GraspTarget(position_m=(x, y, z), yaw_rad=yaw, **values)
