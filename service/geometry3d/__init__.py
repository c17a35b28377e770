"""Pixels to the robot base frame: the camera, ray, plane and depth code that grasp planning
and 3-D chains share.

* :mod:`.camera`: undistortion, rays in the base frame, their points on a plane or at a
  depth (many pixels at once, or one with the reason it cannot be placed).
* :mod:`.depth`: depth images: decoding, checking against the camera, sampling.
* :mod:`.lift`: :func:`lift`, every chain of a detection on its centreline in metres.
* :mod:`.errors`: :class:`LiftError`, :class:`DepthImageError`.

Pure (schemas, numpy and OpenCV; no file other than an explicit depth file read, no state),
and it imports nothing else of :mod:`service`, so :mod:`adapters.grasp` builds on it
without a cycle.
"""

from service.geometry3d.errors import DepthImageError, LiftError
from service.geometry3d.lift import lift

__all__ = ["DepthImageError", "LiftError", "lift"]
