"""Grasp targets: from a detected chain in pixels to a grasp target in the robot base frame.

Everything here is a pure function of a :class:`~schemas.Detection`, a
:class:`~schemas.CameraModel` and a :class:`~schemas.GraspSelector`; no hardware.

The pixel is undistorted with OpenCV (``cv2.undistortPoints``), turned into a ray from
the camera centre, carried to the base frame with ``T_base_camera`` and met with the
surface:

* a :class:`~schemas.grasp.PlaneSurface`: intersected with the table plane ``z = plane_z``;
* a :class:`~schemas.grasp.DepthSurface`: scaled so that its camera ``z`` is the depth
  measured at the pixel. The depth is the sample of the *nearest* pixel, not a bilinear
  blend: across the edge of a box or a cable lying on another, a blend would invent a
  point in mid-air, while the nearest sample always lies on something seen (on a smooth
  slope it costs at most half a pixel's change of depth). A missing sample is filled with
  the median of the valid samples in the surface's window around the pixel; none there
  refuses the grasp.

The gripper yaw comes from the segment the point lies on: its two end joints located the
same way (on a depth surface each from its own depth, or, when none is valid around a
joint, from the grasp point's depth), their difference projected on the base x-y plane.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from adapters.grasp.depth import depth_at, depth_in_metres, describe_valid_depth
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
    PlaneSurface,
    SegmentPoint,
)

PARALLEL_TOLERANCE = 1e-9
"""Rays whose base-frame direction has ``|d_z| / |d|`` below this count as parallel."""

REPROJECTION_TOLERANCE_PX = 1e-3
"""Undistortion is checked by distorting the result again; a larger error is refused."""


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
    if depth_m is None:
        position = pixel_to_plane(camera, pixel)
        start, end = (pixel_to_plane(camera, joint) for joint in joints)
    else:
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


def camera_matrix(camera: CameraModel) -> np.ndarray:
    """The 3x3 intrinsic matrix ``K`` of ``camera``."""
    return np.array(
        [[camera.fx, 0.0, camera.cx], [0.0, camera.fy, camera.cy], [0.0, 0.0, 1.0]], dtype=float
    )


def undistort_pixel(camera: CameraModel, pixel: tuple[float, float]) -> tuple[float, float]:
    """Normalised, undistorted image coordinates ``(x, y)`` (the ray ``(x, y, 1)``) of a pixel.

    Raises
    ------
    GraspPlanningError
        When distorting the result again misses the pixel by more than
        :data:`REPROJECTION_TOLERANCE_PX` (the iteration did not converge, typically
        far outside the calibrated field of view).
    """
    K = camera_matrix(camera)
    dist = np.asarray(camera.dist, dtype=float)
    source = np.array([[pixel]], dtype=np.float64)
    if not any(camera.dist):
        return (pixel[0] - camera.cx) / camera.fx, (pixel[1] - camera.cy) / camera.fy
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)
    try:
        normalised = cv2.undistortPoints(source, K, dist, None, None, None, criteria)
    except cv2.error:
        # OpenCV releases whose undistortPoints takes no criteria have undistortPointsIter.
        normalised = cv2.undistortPointsIter(source, K, dist, None, None, criteria)
    x, y = (float(v) for v in normalised.reshape(2))
    again, _ = cv2.projectPoints(np.array([[x, y, 1.0]]), np.zeros(3), np.zeros(3), K, dist)
    error = float(np.hypot(*(again.reshape(2) - np.asarray(pixel, dtype=float))))
    if not error <= REPROJECTION_TOLERANCE_PX:
        raise GraspPlanningError(
            f"pixel {pixel} could not be undistorted (reprojection error {error:.3g} px)"
        )
    return x, y


def pixel_to_plane(camera: CameraModel, pixel: tuple[float, float]) -> np.ndarray:
    """Intersect the ray through ``pixel`` with the table plane; the point in the base frame.

    Raises
    ------
    GraspPlanningError
        When the ray is parallel to the plane or meets it behind the camera.
    """
    surface = camera.surface
    if not isinstance(surface, PlaneSurface):
        raise GraspPlanningError("the camera's surface is a depth image, not a plane")
    x, y = undistort_pixel(camera, pixel)
    transform = np.asarray(camera.T_base_camera, dtype=float)
    rotation, origin = transform[:3, :3], transform[:3, 3]
    direction = rotation @ np.array([x, y, 1.0])
    if abs(direction[2]) < PARALLEL_TOLERANCE * np.linalg.norm(direction):
        raise GraspPlanningError(f"the ray through pixel {pixel} is parallel to the table plane")
    distance = (surface.plane_z - origin[2]) / direction[2]
    if distance <= 0:
        raise GraspPlanningError(
            f"the ray through pixel {pixel} meets the table plane z = "
            f"{surface.plane_z} m behind the camera"
        )
    return origin + distance * direction


def pixel_to_depth_point(
    camera: CameraModel, pixel: tuple[float, float], depth_m: float
) -> np.ndarray:
    """The point seen at ``pixel`` at ``depth_m`` along the optical axis, in the base frame."""
    x, y = undistort_pixel(camera, pixel)
    transform = np.asarray(camera.T_base_camera, dtype=float)
    return transform[:3, :3] @ (depth_m * np.array([x, y, 1.0])) + transform[:3, 3]


def _or(value: float | None, fallback: float) -> float:
    return fallback if value is None else value
