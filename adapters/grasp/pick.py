"""A pick planned without a robot: grasp target, UR3 motions and the offline workspace check.

What ``dlo ur3 plan``, ``dlo ur3 pick --dry-run`` and ``POST /v1/grasp`` return. Pure:
no robot is contacted, so the checks that need one (``isPoseWithinSafetyLimits``, stops,
the path from the current tool position) are left to
:meth:`adapters.ur3.driver.UR3Picker.pick`.
"""

from __future__ import annotations

import numpy as np

from adapters.errors import UnsafeTargetError
from adapters.grasp.motions import UR3Config, check_workspace, plan_motions
from adapters.grasp.target import plan_grasp
from schemas import CameraModel, Detection, GraspSelector
from schemas.grasp import GraspPlan


def plan_pick(
    detection: Detection,
    camera: CameraModel,
    selector: GraspSelector,
    config: UR3Config | None = None,
    depth: np.ndarray | None = None,
) -> GraspPlan:
    """Plan the grasp and the motions a UR3 pick would send, and check them against the workspace.

    Parameters
    ----------
    detection, camera, selector
        As for :func:`adapters.grasp.target.plan_grasp`.
    depth
        The depth image, for a camera whose surface is a depth image (as
        :func:`adapters.grasp.target.plan_grasp`).
    config
        Heights, speeds and workspace of the pick; :class:`UR3Config` defaults when None.

    Returns
    -------
    GraspPlan
        A target outside the workspace is not an error here: the plan is returned with
        ``within_workspace`` false and the reason in ``refusal``.

    Raises
    ------
    GraspPlanningError
        As :func:`adapters.grasp.target.plan_grasp` (including ``InferredSegmentError`` and
        ``DepthImageError``).
    """
    config = UR3Config() if config is None else config
    target = plan_grasp(detection, camera, selector, depth)
    motions = plan_motions(target, config)
    try:
        check_workspace(motions, config.workspace)
    except UnsafeTargetError as error:
        return GraspPlan(target=target, motions=motions, within_workspace=False, refusal=str(error))
    return GraspPlan(target=target, motions=motions, within_workspace=True)
