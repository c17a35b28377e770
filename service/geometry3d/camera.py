"""From pixels to rays and points in the robot base frame, through a :class:`CameraModel`.

A pixel is undistorted with OpenCV (``cv2.undistortPoints``, checked by distorting the
result again), giving the normalised image coordinates ``(x, y)`` of the ray
``(x, y, 1)`` in the camera frame; ``T_base_camera`` carries it to the base frame, where it
meets the surface:

* a horizontal plane ``z = height``: the ray intersected with it;
* a depth: the ray scaled so that its camera ``z`` is the depth (depth cameras report the
  distance along the optical axis, not along the ray).

The functions taking many pixels return NaN for a pixel that cannot be placed and say
nothing of why; the single-pixel ones (the grasp planning's) raise :class:`LiftError` with
the reason.
"""

from __future__ import annotations

import cv2
import numpy as np

from schemas import CameraModel, PlaneSurface
from service.geometry3d.errors import LiftError

PARALLEL_TOLERANCE = 1e-9
"""Rays whose base-frame direction has ``|d_z| / |d|`` below this count as parallel."""

REPROJECTION_TOLERANCE_PX = 1e-3
"""Undistortion is checked by distorting the result again; a larger error is refused."""

_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
"""Converged to about 1e-12 px (checked by distorting again); a tighter epsilon costs eight
times the time for nothing a robot could use."""


def camera_matrix(camera: CameraModel) -> np.ndarray:
    """The 3x3 intrinsic matrix ``K`` of ``camera``."""
    return np.array(
        [[camera.fx, 0.0, camera.cx], [0.0, camera.fy, camera.cy], [0.0, 0.0, 1.0]], dtype=float
    )


def base_from_camera(camera: CameraModel) -> tuple[np.ndarray, np.ndarray]:
    """The rotation ``R`` (3x3) and the camera centre ``t`` (3,) of ``T_base_camera``."""
    transform = np.asarray(camera.T_base_camera, dtype=float)
    return transform[:3, :3], transform[:3, 3]


def undistort_points(camera: CameraModel, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Normalised, undistorted image coordinates of many pixels.

    Parameters
    ----------
    pixels
        ``(N, 2)`` ``[x, y]`` in pixels.

    Returns
    -------
    normalised : ndarray, shape (N, 2)
        ``(x, y)`` of each pixel's ray ``(x, y, 1)`` in the camera frame.
    ok : ndarray of bool, shape (N,)
        False where the pixel is not finite or distorting the result again misses it by
        more than :data:`REPROJECTION_TOLERANCE_PX` (the iteration did not converge,
        typically far outside the calibrated field of view).
    """
    pixels = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    finite = np.isfinite(pixels).all(axis=1)
    if not any(camera.dist):
        normalised = np.column_stack(
            ((pixels[:, 0] - camera.cx) / camera.fx, (pixels[:, 1] - camera.cy) / camera.fy)
        )
        return normalised, finite & np.isfinite(normalised).all(axis=1)
    K = camera_matrix(camera)
    dist = np.asarray(camera.dist, dtype=float)
    source = np.where(finite[:, None], pixels, 0.0).reshape(-1, 1, 2)
    if len(source) == 0:
        return np.zeros((0, 2)), np.zeros(0, dtype=bool)
    try:
        normalised = cv2.undistortPoints(source, K, dist, None, None, None, _UNDISTORT_CRITERIA)
    except cv2.error:
        # OpenCV releases whose undistortPoints takes no criteria have undistortPointsIter.
        normalised = cv2.undistortPointsIter(source, K, dist, None, None, _UNDISTORT_CRITERIA)
    normalised = normalised.reshape(-1, 2)
    rays = np.column_stack((normalised, np.ones(len(normalised))))
    again, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), K, dist)
    error = np.hypot(*(again.reshape(-1, 2) - pixels).T)
    with np.errstate(invalid="ignore"):
        ok = finite & (error <= REPROJECTION_TOLERANCE_PX)
    return normalised, ok


def undistort_pixel(camera: CameraModel, pixel: tuple[float, float]) -> tuple[float, float]:
    """Normalised, undistorted image coordinates ``(x, y)`` (the ray ``(x, y, 1)``) of a pixel.

    Raises
    ------
    LiftError
        When distorting the result again misses the pixel by more than
        :data:`REPROJECTION_TOLERANCE_PX` (the iteration did not converge, typically
        far outside the calibrated field of view).
    """
    normalised, ok = undistort_points(camera, np.asarray([pixel], dtype=float))
    if not ok[0]:
        raise LiftError(f"pixel {tuple(pixel)} could not be undistorted")
    return float(normalised[0, 0]), float(normalised[0, 1])


def ray_directions(camera: CameraModel, normalised: np.ndarray) -> np.ndarray:
    """Base-frame directions ``R (x, y, 1)`` of the rays with normalised coordinates ``(x, y)``.

    Not unit vectors: each is scaled so that its camera ``z`` is 1, so a point at depth
    ``d`` (along the optical axis) is ``t + d * direction``.
    """
    rotation, _ = base_from_camera(camera)
    normalised = np.asarray(normalised, dtype=float).reshape(-1, 2)
    rays = np.column_stack((normalised, np.ones(len(normalised))))
    return rays @ rotation.T


def plane_depths(
    camera: CameraModel, directions: np.ndarray, height: float | np.ndarray
) -> np.ndarray:
    """Depth (camera ``z``) at which each ray meets the plane ``z = height`` of the base frame.

    NaN where the ray is parallel to the plane or meets it behind the camera.
    """
    _, origin = base_from_camera(camera)
    directions = np.asarray(directions, dtype=float).reshape(-1, 3)
    down = directions[:, 2]
    norms = np.linalg.norm(directions, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        depths = (np.asarray(height, dtype=float) - origin[2]) / down
    meets = (np.abs(down) >= PARALLEL_TOLERANCE * norms) & (depths > 0)
    return np.where(meets, depths, np.nan)


def pixels_to_plane(
    camera: CameraModel, pixels: np.ndarray, height: float | np.ndarray | None = None
) -> np.ndarray:
    """Many pixels on the plane ``z = height`` (default: the camera's table plane).

    Returns ``(N, 3)`` base-frame points, NaN rows where a pixel cannot be placed
    (undistortion fails, the ray is parallel to the plane or meets it behind the camera).
    """
    if height is None:
        height = _table_height(camera)
    normalised, ok = undistort_points(camera, pixels)
    directions = ray_directions(camera, normalised)
    depths = np.where(ok, plane_depths(camera, directions, height), np.nan)
    return points_at_depths(camera, directions, depths)


def points_at_depths(camera: CameraModel, directions: np.ndarray, depths: np.ndarray) -> np.ndarray:
    """The base-frame points ``t + depth * direction`` (NaN rows where the depth is NaN)."""
    _, origin = base_from_camera(camera)
    return origin + np.asarray(depths, dtype=float)[:, None] * directions


def pixel_to_plane(camera: CameraModel, pixel: tuple[float, float]) -> np.ndarray:
    """Intersect the ray through ``pixel`` with the table plane; the point in the base frame.

    Raises
    ------
    LiftError
        When the camera's surface is not a plane, the ray is parallel to the plane or
        meets it behind the camera, or the pixel cannot be undistorted.
    """
    height = _table_height(camera)
    x, y = undistort_pixel(camera, pixel)
    directions = ray_directions(camera, np.array([[x, y]]))
    depth = plane_depths(camera, directions, height)[0]
    if np.isnan(depth):
        down = directions[0, 2]
        if abs(down) < PARALLEL_TOLERANCE * np.linalg.norm(directions[0]):
            raise LiftError(f"the ray through pixel {pixel} is parallel to the table plane")
        raise LiftError(
            f"the ray through pixel {pixel} meets the table plane z = {height} m behind the camera"
        )
    return points_at_depths(camera, directions, np.array([depth]))[0]


def pixel_to_depth_point(
    camera: CameraModel, pixel: tuple[float, float], depth_m: float
) -> np.ndarray:
    """The point seen at ``pixel`` at ``depth_m`` along the optical axis, in the base frame.

    Raises
    ------
    LiftError
        When the pixel cannot be undistorted.
    """
    x, y = undistort_pixel(camera, pixel)
    directions = ray_directions(camera, np.array([[x, y]]))
    return points_at_depths(camera, directions, np.array([depth_m]))[0]


def _table_height(camera: CameraModel) -> float:
    surface = camera.surface
    if not isinstance(surface, PlaneSurface):
        raise LiftError("the camera's surface is a depth image, not a plane")
    return surface.plane_z
