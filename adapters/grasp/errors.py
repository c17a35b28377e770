"""Why a grasp cannot be planned: the errors of :mod:`adapters.grasp`."""

from __future__ import annotations


class GraspPlanningError(ValueError):
    """The selector, detection or camera does not give a graspable point."""


class InferredSegmentError(GraspPlanningError):
    """The chosen point lies on a segment that was inferred, and that was not allowed."""


class DepthImageError(GraspPlanningError):
    """The depth image is missing, unreadable, of another size or type, or not wanted.

    Not wanted: a depth image given with a camera whose surface is a plane.
    """
