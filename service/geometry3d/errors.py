"""Why a pixel cannot be placed in the robot base frame."""

from __future__ import annotations


class LiftError(ValueError):
    """A pixel, chain or detection cannot be lifted to the base frame.

    The detection's image size differs from the camera's, the ray through a pixel misses
    the table plane (parallel to it, or meeting it behind the camera), or undistortion does
    not converge (far outside the calibrated field of view).
    """


class DepthImageError(LiftError):
    """The depth image is missing, unreadable, of another size or type, or not wanted.

    Not wanted: a depth image given with a camera whose surface is a plane.
    """
