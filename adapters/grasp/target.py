"""Grasp targets: from a detected chain in pixels to a grasp target in the robot base frame.

Everything here is a pure function of a :class:`~schemas.Detection`, a
:class:`~schemas.CameraModel` and a :class:`~schemas.GraspSelector`; no hardware.

The pixel is placed in the base frame by :mod:`service.geometry3d` (the same camera, ray
and depth code that lifts whole chains to 3-D):

* a :class:`~schemas.grasp.PlaneSurface`: its ray intersected with the table plane
  ``z = plane_z``;
* a :class:`~schemas.grasp.DepthSurface`: its ray scaled so that its camera ``z`` is the
  depth measured at the nearest pixel (:mod:`service.geometry3d.depth`). A missing sample
  is filled with the median of the valid samples in the surface's window around the
  pixel; none there refuses the grasp.

The gripper yaw comes from the segment the point lies on: its two end joints located the
same way (on a depth surface each from its own depth, or, when none is valid around a
joint, from the grasp point's depth), their difference projected on the base x-y plane.
"""

from __future__ import annotations

import math

import numpy as np

from adapters.grasp.errors import GraspPlanningError, InferredSegmentError
from schemas import (
    CameraModel,
    Chain,
    DepthSurface,
    Detection,
    EndPoint,
    FractionPoint,
    GraspSelector,
    GraspTarget,
    PixelPoint,
    SegmentPoint,
)
from service.geometry3d.camera import pixel_to_depth_point, pixel_to_plane
from service.geometry3d.depth import depth_at, depth_in_metres, describe_valid_depth
from service.geometry3d.errors import DepthImageError, LiftError


def plan_grasp(
    detection: Detection,
    camera: CameraModel,
    selector: GraspSelector,
    depth: np.ndarray | None = None,
) -> GraspTarget:
    """Choose a point on a detected chain and locate it on the surface in the base frame.

    Parameters
    ----------
    detection
        The chains, in pixels of an image of ``camera.width`` x ``camera.height``.
    camera
        Intrinsics, distortion, camera pose in the base frame and the surface.
    selector
        Which chain and which point of it; whether inferred segments may be grasped.
    depth
        The depth image, required when ``camera.surface`` is a
        :class:`~schemas.grasp.DepthSurface` and refused otherwise: ``(height, width)``
        (or ``(height, width, 1)``) uint16 or float samples in units of
        ``camera.surface.depth_scale`` metres, aligned with the colour image.

    Returns
    -------
    GraspTarget
        The point on the surface and the yaw of the gripper closing across the cable.

    Raises
    ------
    DepthImageError
        When the depth image is missing for a depth surface, given for a plane, of
        another size than the camera's or of an unusable shape or sample type.
    GraspPlanningError
        When the image size does not match the camera, the chain or segment does not
        exist, the ray misses the plane (parallel to it or meeting it behind the camera),
        no valid depth lies within the window around the grasp point, or the
        undistortion does not converge.
    InferredSegmentError
        When the point lies on an inferred segment and ``selector.allow_inferred`` is
        false.
    """
    if (detection.width, detection.height) != (camera.width, camera.height):
        raise GraspPlanningError(
            f"detection is {detection.width}x{detection.height} px but the camera model is "
            f"{camera.width}x{camera.height} px"
        )
    depth_m = depth_in_metres(camera, depth)
    chain = select_chain(detection, selector.chain)
    pixel, segment = locate_on_chain(chain, selector.point)
    inferred = chain.inferred[segment]
    if inferred and not selector.allow_inferred:
        raise InferredSegmentError(
            f"chain {chain.id} segment {segment} was inferred (not seen in the image); "
            "set allow_inferred to grasp it anyway"
        )
    joints = (chain.points[segment], chain.points[segment + 1])
    try:
        position, start, end = _locate(camera, depth_m, pixel, joints)
    except DepthImageError:
        raise
    except LiftError as error:  # the ray misses the table, or undistortion fails
        raise GraspPlanningError(str(error)) from None
    tangent = end - start
    if math.hypot(tangent[0], tangent[1]) < 1e-12:
        raise GraspPlanningError(
            f"chain {chain.id} segment {segment} has no length on the table; no yaw"
        )
    yaw = closing_yaw(float(tangent[0]), float(tangent[1]))
    return GraspTarget(
        position_m=(float(position[0]), float(position[1]), float(position[2])),
        yaw_rad=yaw,
        chain_id=chain.id,
        segment_index=segment,
        inferred=inferred,
        pixel=(float(pixel[0]), float(pixel[1])),
    )


def _locate(
    camera: CameraModel,
    depth_m: np.ndarray | None,
    pixel: tuple[float, float],
    joints: tuple[tuple[float, float], tuple[float, float]],
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The grasp point and the two joints of its segment in the base frame."""
    if depth_m is None:
        position = pixel_to_plane(camera, pixel)
        start, end = (pixel_to_plane(camera, joint) for joint in joints)
        return position, start, end
    surface = camera.surface
    assert isinstance(surface, DepthSurface)  # depth_in_metres refuses a depth for a plane
    grasp_depth = depth_at(depth_m, pixel, surface.window)
    if grasp_depth is None:
        raise GraspPlanningError(
            f"no valid depth at pixel ({pixel[0]:.1f}, {pixel[1]:.1f}) nor in the "
            f"{surface.window}x{surface.window} px window around it "
            f"({describe_valid_depth(surface)}); the surface there was not measured"
        )
    position = pixel_to_depth_point(camera, pixel, grasp_depth)
    # A joint with no valid depth around it (off the measured surface) is put on its own
    # ray at the grasp point's depth: exact on a surface facing the camera, and the yaw
    # needs only the joint's direction from the grasp point, not its height.
    start, end = (
        pixel_to_depth_point(
            camera, joint, _or(depth_at(depth_m, joint, surface.window), grasp_depth)
        )
        for joint in joints
    )
    return position, start, end


def select_chain(detection: Detection, choice: int | str) -> Chain:
    """Return the chain with id ``choice``, or the longest one (ties: lowest id)."""
    if not detection.chains:
        raise GraspPlanningError("the detection has no chains")
    if choice == "longest":
        return min(detection.chains, key=lambda chain: (-chain.length, chain.id))
    try:
        return detection.chain(int(choice))
    except KeyError:
        ids = sorted(chain.id for chain in detection.chains)
        raise GraspPlanningError(f"no chain with id {choice}; the ids are {ids}") from None


def locate_on_chain(
    chain: Chain, point: FractionPoint | SegmentPoint | PixelPoint | EndPoint
) -> tuple[tuple[float, float], int]:
    """Return the selected pixel on ``chain`` and the index of the segment it lies on.

    A point exactly on a joint belongs to the segment that starts there, except the
    last point, which belongs to the last segment.
    """
    points = np.asarray(chain.points, dtype=float)
    segments = len(points) - 1
    if isinstance(point, EndPoint):
        if point.end == "start":
            return _as_pixel(points[0]), 0
        return _as_pixel(points[-1]), segments - 1
    if isinstance(point, SegmentPoint):
        if point.index >= segments:
            raise GraspPlanningError(
                f"chain {chain.id} has {segments} segments; there is no segment {point.index}"
            )
        return _as_pixel((points[point.index] + points[point.index + 1]) / 2), point.index
    if isinstance(point, FractionPoint):
        return _at_fraction(chain.id, points, point.value)
    if isinstance(point, PixelPoint):
        return _nearest(points, np.array([point.x, point.y], dtype=float))
    raise GraspPlanningError(f"unknown grasp point {point!r}")  # pragma: no cover


def _as_pixel(point: np.ndarray) -> tuple[float, float]:
    return float(point[0]), float(point[1])


def _at_fraction(chain_id: int, points: np.ndarray, fraction: float) -> tuple[tuple, int]:
    lengths = np.linalg.norm(np.diff(points, axis=0), axis=1)
    total = float(lengths.sum())
    if total <= 0:
        raise GraspPlanningError(f"chain {chain_id} has zero length")
    target = fraction * total
    travelled = 0.0
    last = len(lengths) - 1
    for index, length in enumerate(lengths):
        if length > 0 and (target < travelled + length or index == last):
            t = min(max((target - travelled) / length, 0.0), 1.0)
            return _as_pixel(points[index] + t * (points[index + 1] - points[index])), index
        travelled += length
    # Trailing zero-length segments: the end of the chain lies on the last real one.
    real = [index for index, length in enumerate(lengths) if length > 0]
    return _as_pixel(points[real[-1] + 1]), real[-1]


def _nearest(points: np.ndarray, query: np.ndarray) -> tuple[tuple[float, float], int]:
    starts, ends = points[:-1], points[1:]
    directions = ends - starts
    squared = np.einsum("ij,ij->i", directions, directions)
    safe = np.where(squared > 0, squared, 1.0)
    t = np.clip(np.einsum("ij,ij->i", query - starts, directions) / safe, 0.0, 1.0)
    t = np.where(squared > 0, t, 0.0)
    closest = starts + t[:, None] * directions
    distances = np.linalg.norm(closest - query, axis=1)
    index = int(np.argmin(distances))
    return _as_pixel(closest[index]), index


def closing_yaw(tangent_x: float, tangent_y: float) -> float:
    """Yaw of a gripper closing across a cable with tangent ``(tangent_x, tangent_y)``.

    The closing direction is the tangent turned by +90 degrees about base ``+z``,
    folded into ``(-pi/2, pi/2]`` because a parallel gripper is symmetric under a half
    turn.
    """
    return normalize_half_turn(math.atan2(tangent_y, tangent_x) + math.pi / 2)


def normalize_half_turn(angle: float) -> float:
    """Fold ``angle`` (radians) into ``(-pi/2, pi/2]`` modulo pi."""
    folded = math.remainder(angle, math.pi)
    if folded <= -math.pi / 2:
        folded += math.pi
    if folded > math.pi / 2:  # rounding at the upper edge
        folded -= math.pi
    return folded


def _or(value: float | None, fallback: float) -> float:
    return fallback if value is None else value
