"""Grasp planning: from a detected chain in pixels to a grasp target in the robot base frame.

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


class GraspPlanningError(ValueError):
    """The selector, detection or camera does not give a graspable point."""


class InferredSegmentError(GraspPlanningError):
    """The chosen point lies on a segment that was inferred, and that was not allowed."""


class DepthImageError(GraspPlanningError):
    """The depth image is missing, unreadable, of another size or type, or not wanted.

    Not wanted: a depth image given with a camera whose surface is a plane.
    """


PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"

DEPTH_SAMPLE_TYPES = (np.dtype(np.uint16), np.dtype(np.float32), np.dtype(np.float64))
"""Sample types of a depth image: uint16 (16-bit PNG) or float (``.npy``)."""


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


# --- depth surface ---------------------------------------------------------------------------


def depth_in_metres(camera: CameraModel, depth: np.ndarray | None) -> np.ndarray | None:
    """Check ``depth`` against ``camera`` and convert it to metres, NaN where not valid.

    Returns
    -------
    np.ndarray or None
        ``(height, width)`` float64 metres along the optical axis; NaN where the sample
        is not finite, not positive or outside the surface's ``[min_depth_m,
        max_depth_m]``. None for a plane surface (and no depth image).

    Raises
    ------
    DepthImageError
        A depth surface without a depth image, a plane surface with one, or a depth
        image of another size than the camera's, with more than one channel or with
        samples other than uint16 or float.
    """
    surface = camera.surface
    if not isinstance(surface, DepthSurface):
        if depth is not None:
            raise DepthImageError(
                f"a depth image was given but the camera's surface is the plane z = "
                f"{surface.plane_z} m; set the surface to "
                '{"kind": "depth", "depth_scale": ...} to use it'
            )
        return None
    if depth is None:
        raise DepthImageError(
            "the camera's surface is a depth image (kind 'depth') but no depth image was given"
        )
    samples = check_depth_image(camera, depth)
    metres = samples.astype(np.float64) * surface.depth_scale
    with np.errstate(invalid="ignore"):
        invalid = ~np.isfinite(metres) | (metres <= 0)
        if surface.min_depth_m is not None:
            invalid |= metres < surface.min_depth_m
        if surface.max_depth_m is not None:
            invalid |= metres > surface.max_depth_m
    metres[invalid] = np.nan
    return metres


def check_depth_image(camera: CameraModel, depth: np.ndarray) -> np.ndarray:
    """``depth`` as a ``(height, width)`` array after checking its shape and sample type.

    Raises
    ------
    DepthImageError
        When it is not a single-channel uint16 or float array of the camera's size.
    """
    if not isinstance(depth, np.ndarray):
        raise DepthImageError(f"a depth image is an array, not {type(depth).__name__}")
    if depth.ndim == 3 and depth.shape[2] == 1:
        depth = depth[:, :, 0]
    if depth.ndim != 2:
        channels = f"{depth.shape[2]} channels" if depth.ndim == 3 else f"shape {depth.shape}"
        raise DepthImageError(f"a depth image has one channel, not {channels}")
    if depth.dtype not in DEPTH_SAMPLE_TYPES:
        raise DepthImageError(
            f"depth samples are uint16 (a 16-bit PNG) or float32/float64 (.npy), not {depth.dtype}"
        )
    height, width = depth.shape
    if (width, height) != (camera.width, camera.height):
        raise DepthImageError(
            f"depth image is {width}x{height} px but the camera model is "
            f"{camera.width}x{camera.height} px"
        )
    return depth


def depth_at(depth_m: np.ndarray, pixel: tuple[float, float], window: int) -> float | None:
    """The depth (metres) at the pixel nearest to ``pixel``, filled when missing.

    Parameters
    ----------
    depth_m
        Depth in metres, NaN where missing (:func:`depth_in_metres`).
    pixel
        ``(x, y)``, pixel centres at integer coordinates.
    window
        Side (odd, pixels) of the square around the pixel whose valid samples' median
        fills a missing one.

    Returns
    -------
    float or None
        None when neither the pixel nor its window (clipped to the image) holds a valid
        sample; a pixel outside the image has no sample of its own but may still have
        valid ones in its window.
    """
    height, width = depth_m.shape
    column, row = math.floor(pixel[0] + 0.5), math.floor(pixel[1] + 0.5)
    if 0 <= row < height and 0 <= column < width:
        value = depth_m[row, column]
        if not math.isnan(value):
            return float(value)
    half = window // 2
    rows = slice(max(row - half, 0), max(min(row + half + 1, height), 0))
    columns = slice(max(column - half, 0), max(min(column + half + 1, width), 0))
    samples = depth_m[rows, columns]
    valid = samples[~np.isnan(samples)]
    if valid.size == 0:
        return None
    return float(np.median(valid))


def describe_valid_depth(surface: DepthSurface) -> str:
    """What counts as a valid depth sample, for error messages."""
    low = "> 0 m" if surface.min_depth_m is None else f">= {surface.min_depth_m} m"
    high = "" if surface.max_depth_m is None else f" and <= {surface.max_depth_m} m"
    return f"valid: finite, {low}{high}"


def pixel_to_depth_point(
    camera: CameraModel, pixel: tuple[float, float], depth_m: float
) -> np.ndarray:
    """The point seen at ``pixel`` at ``depth_m`` along the optical axis, in the base frame."""
    x, y = undistort_pixel(camera, pixel)
    transform = np.asarray(camera.T_base_camera, dtype=float)
    return transform[:3, :3] @ (depth_m * np.array([x, y, 1.0])) + transform[:3, 3]


def decode_depth_image(data: bytes) -> np.ndarray:
    """Decode an encoded depth image (a 16-bit single-channel PNG), samples unchanged.

    Returns
    -------
    np.ndarray
        ``(height, width)`` uint16 (or float32, for a float TIFF) samples, unscaled.

    Raises
    ------
    DepthImageError
        When ``data`` is empty, truncated or not an image, has more than one channel,
        or has 8-bit samples (a picture of the depth, not the depth).
    """
    if not data:
        raise DepthImageError("empty file (0 bytes)")
    previous = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)  # errors are ours
    try:
        image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    except cv2.error as error:
        raise DepthImageError(f"cannot decode: {' '.join(str(error).split())}") from None
    finally:
        cv2.utils.logging.setLogLevel(previous)
    if image is None or image.size == 0:
        if data.startswith(PNG_SIGNATURE):
            raise DepthImageError("truncated or corrupt PNG file")
        raise DepthImageError("not an image, or a format OpenCV cannot decode")
    if image.ndim == 3 and image.shape[2] != 1:
        raise DepthImageError(
            f"has {image.shape[2]} channels; a depth image is a single-channel 16-bit PNG"
        )
    if image.dtype == np.uint8:
        raise DepthImageError(
            "has 8-bit samples; a depth image is a 16-bit PNG (an 8-bit one is a picture of "
            "the depth, too coarse to measure it)"
        )
    return image.reshape(image.shape[:2])


def _or(value: float | None, fallback: float) -> float:
    return fallback if value is None else value
