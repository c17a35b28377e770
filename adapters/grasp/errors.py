"""Why a grasp cannot be planned: the errors of :mod:`adapters.grasp`.

A depth image that does not fit the camera is a :class:`DepthImageError` of
:mod:`service.geometry3d` (which reads depth images for grasping and lifting alike); it is
re-exported here so that callers of the grasp planning find every refusal in one place.
"""

from __future__ import annotations

from service.geometry3d.errors import DepthImageError

__all__ = ["DepthImageError", "GraspPlanningError", "InferredSegmentError"]


class GraspPlanningError(ValueError):
    """The selector, detection or camera does not give a graspable point."""


class InferredSegmentError(GraspPlanningError):
    """The chosen point lies on a segment that was inferred, and that was not allowed."""
