"""Error types shared by every robot adapter."""

from __future__ import annotations


class UnsafeTargetError(ValueError):
    """A target or a pose of the plan is outside the workspace, the geofence or the robot's
    safety limits; nothing was sent."""
