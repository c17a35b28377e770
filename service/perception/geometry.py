"""Small geometric helpers on polylines (``(N, 2)`` arrays of ``[x, y]``)."""

from __future__ import annotations

import math

import numpy as np

from service.perception import _geometry_kernels


def unit(vector: np.ndarray) -> np.ndarray:
    """The vector scaled to length one (zero stays zero)."""
    norm = float(np.hypot(vector[0], vector[1]))
    return vector / norm if norm > 1e-12 else np.zeros(2)


def angle_between(a: np.ndarray, b: np.ndarray) -> float:
    """Unsigned angle between two unit vectors, in radians (0..pi)."""
    # Plain floats and math: this runs thousands of times per frame on scalars, where
    # NumPy's per-call overhead is most of the cost (same libm acos, same result).
    cosine = float(a[0]) * float(b[0]) + float(a[1]) * float(b[1])
    return math.acos(min(max(cosine, -1.0), 1.0))


def end_tangent(
    points: np.ndarray, at_start: bool, span: float, skip: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Position and outward unit tangent at one end of a polyline.

    The points between ``skip`` and ``skip + span`` of arc length from the end are
    fitted with a quadratic in arc length, extrapolated to the end. A plain chord
    would lag behind the tangent of a curving cable by half its turn; skipping the
    last stretch ignores the hook that thinning leaves at a square-cut end (such as
    the edge of an occluder).

    Parameters
    ----------
    points : ndarray
        ``(N, 2)`` polyline, ``N >= 2``.
    at_start : bool
        The end at ``points[0]`` (the direction points away from the polyline,
        backwards) or at ``points[-1]``.
    span : float
        Arc length used for the fit; longer is steadier, shorter follows the very end.
    skip : float
        Arc length at the very end left out of the fit.

    Returns
    -------
    position, direction : ndarray
        The fitted end point and the unit tangent pointing out of the polyline.
    """
    position, direction, _ = end_fit(points, at_start, span, skip)
    return position, direction


def end_fit(
    points: np.ndarray, at_start: bool, span: float, skip: float = 0.0
) -> tuple[np.ndarray, np.ndarray, float]:
    """:func:`end_tangent` and the signed curvature (1/px) of the fit at the end.

    The curvature is that of the polyline travelled outwards, through the end: positive
    when the outward direction turns the way of a positive angle (from +x towards +y),
    0 when the stretch was too short to fit.
    """
    ordered = points[::-1] if at_start else points
    backwards = np.ascontiguousarray(ordered[::-1], dtype=np.float64)
    fitted, x0, y0, dx, dy, last, ddx, ddy = _geometry_kernels.end_fit(
        backwards, float(skip), float(span)
    )
    # The linear term points into the polyline; outwards is its opposite.
    tangent = np.array([-dx, -dy])
    speed = float(np.hypot(dx, dy))
    if fitted and speed > 1e-9:
        # Travelled inwards the curvature is (x'y'' - y'x'') / |v|^3; outwards (the
        # tangent reversed) its sign flips.
        curvature = -(dx * ddy - dy * ddx) / speed**3
        return np.array([x0, y0]), unit(tangent), float(curvature)
    return backwards[0].copy(), unit(backwards[0] - backwards[last]), 0.0


def fit_where_skipped(
    points: np.ndarray, at_start: bool, span: float, skip: float
) -> tuple[np.ndarray, np.ndarray] | None:
    """The fit of :func:`end_fit` evaluated at ``skip`` of arc length from the end,
    where the stretch it fits begins, rather than extrapolated over the skipped tip.

    Returns the position and the outward unit tangent there, or None when nothing was
    skipped or the stretch was too short to fit.
    """
    ordered = points[::-1] if at_start else points
    backwards = np.ascontiguousarray(ordered[::-1], dtype=np.float64)
    fitted, x0, y0, dx, dy, _, ddx, ddy = _geometry_kernels.end_fit(
        backwards, float(skip), float(span)
    )
    if not fitted or skip <= 0 or polyline_length(backwards) < 2.0 * skip + 1.0:
        return None
    return fit_at(x0, y0, dx, dy, ddx, ddy, skip)


def fit_at(
    x0: float, y0: float, dx: float, dy: float, ddx: float, ddy: float, arc: float
) -> tuple[np.ndarray, np.ndarray] | None:
    """A quadratic end fit (``_geometry_kernels.end_fit``'s position at the end, first and
    second derivatives along the arc inwards) evaluated at ``arc`` from the end: the
    position and the outward unit tangent there, or None where the tangent vanishes."""
    # In Python floats, one by one as NumPy would (unit: the tangent over its np.hypot).
    inwards_x, inwards_y = dx + ddx * arc, dy + ddy * arc
    norm = float(np.hypot(inwards_x, inwards_y))
    if norm < 1e-9:
        return None
    position = np.array([x0 + dx * arc + 0.5 * ddx * arc**2, y0 + dy * arc + 0.5 * ddy * arc**2])
    if not norm > 1e-12:  # NaN: as unit() has it
        return position, np.zeros(2)
    return position, np.array([-inwards_x / norm, -inwards_y / norm])


def end_direction(points: np.ndarray, at_start: bool, span: float) -> np.ndarray:
    """Outward unit tangent at one end of a polyline (see :func:`end_tangent`)."""
    return end_tangent(points, at_start, span)[1]


def resample(points: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Joints along a polyline with consecutive joints exactly ``step`` apart.

    Each joint is where a circle of radius ``step`` around the previous joint first
    leaves the polyline, so the chord, not the arc, is ``step``. The last joint is
    the polyline's end, so the last segment may be shorter.

    Returns
    -------
    joints : ndarray
        ``(K, 2)`` joints.
    source_edge : ndarray
        ``(K,)`` index of the polyline edge each joint lies on.
    """
    # The loop is compiled (_geometry_kernels.resample_kernel). It takes np.sqrt where the
    # first plain loop took ``disc ** 0.5`` (NumPy's scalar pow, at times 1 ulp off the
    # root), so a joint may move by round-off (about 1e-14 px), never more.
    points_f64 = np.ascontiguousarray(points, np.float64)
    joints, edges = _geometry_kernels.resample_kernel(points_f64, step)
    tail = points_f64[-1]
    # The polyline's end is the last joint, unless the last one found is on it already
    # (a lone first joint never is).
    if len(joints) == 1 or np.hypot(*(tail - joints[-1])) > 1e-6 * step:
        joints = np.vstack([joints, tail])
        edges = np.append(edges, len(points) - 2)
    return joints, edges


def arc_lengths(points: np.ndarray) -> np.ndarray:
    """Arc of each vertex of a polyline from its first (px)."""
    if _compiled_layout(points):
        return _geometry_kernels.arc_lengths(points)
    steps = np.diff(points, axis=0)
    return np.concatenate([[0.0], np.cumsum(np.sqrt((steps * steps).sum(axis=1)))])


def points_along(points: np.ndarray, arcs: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Points at arcs ``at`` along a polyline whose vertices are at ``arcs``
    (:func:`arc_lengths`)."""
    x = np.interp(at, arcs, points[:, 0])
    y = np.interp(at, arcs, points[:, 1])
    return np.column_stack([x, y])


def median(values: np.ndarray):
    """``np.median`` of a 1-D float array of at least one value, none of them NaN, without
    its overhead (its partition and mean, done directly).

    The middle value, or the mean of the two middle ones in the array's own type (a
    ``float32`` sum halved in ``float32``, as ``np.mean`` of two takes it); the same
    value ``np.median`` gives, for a fraction of its cost on the few values a chain has.
    """
    half = values.size // 2
    if values.size % 2:
        return np.partition(values, half)[half]
    middle = np.partition(values, (half - 1, half))
    return (middle[half - 1] + middle[half]) / values.dtype.type(2)


def rigid_fit(source: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rotation and translation taking ``source`` onto ``target`` (paired points, least
    squares): ``(source_mean, rotation, target_mean)``, so a point ``p`` goes to
    ``(p - source_mean) @ rotation.T + target_mean``."""
    source_mean, target_mean = source.mean(axis=0), target.mean(axis=0)
    a, b = source - source_mean, target - target_mean
    angle = math.atan2(float((a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]).sum()), float((a * b).sum()))
    c, s = math.cos(angle), math.sin(angle)
    return source_mean, np.array([[c, -s], [s, c]]), target_mean


def distances_to_polyline(points: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    """Each point's distance (px) from a polyline of two vertices or more (its nearest
    segment)."""
    a = polyline[:-1]
    ab = polyline[1:] - a
    ap = points[:, None, :] - a[None, :, :]
    t = np.clip((ap * ab).sum(axis=2) / np.maximum((ab * ab).sum(axis=1), 1e-12), 0.0, 1.0)
    gap = ap - t[:, :, None] * ab[None, :, :]
    return np.sqrt((gap * gap).sum(axis=2)).min(axis=1)


def reach_along(points: np.ndarray, origin: np.ndarray, axis: np.ndarray) -> float:
    """How far (px) ``points`` reach past ``origin`` along the unit ``axis`` (the
    largest projection; negative where they all lie behind it).

    Examples
    --------
    >>> import numpy as np
    >>> reach_along(np.array([[0.0, 0.0], [3.0, -8.0]]), np.zeros(2), np.array([0.0, -1.0]))
    8.0
    """
    return float(np.max((np.asarray(points) - origin) @ axis))


def rotated(direction: np.ndarray, angle: float) -> np.ndarray:
    """The 2-D ``direction`` turned by ``angle`` radians (counter-clockwise in x, y)."""
    direction = np.asarray(direction, np.float64)
    cos, sin = np.cos(angle), np.sin(angle)
    return np.array(
        [cos * direction[0] - sin * direction[1], sin * direction[0] + cos * direction[1]]
    )


def polyline_length(points: np.ndarray) -> float:
    """Arc length of a polyline."""
    if len(points) < 2:
        return 0.0
    # Called for every piece and path of a frame, a few times: compiled for the float64
    # polylines the steps hand it, where NumPy's calls took most of the time.
    if _compiled_layout(points):
        return _geometry_kernels.polyline_length(points)
    points = np.asarray(points)
    steps = points[1:] - points[:-1]
    if not np.issubdtype(steps.dtype, np.inexact):
        steps = steps.astype(np.float64)
    # What np.linalg.norm(steps, axis=1) computes, without its checks (called for
    # every piece and path of a frame).
    return float(np.sqrt((steps * steps).sum(axis=1)).sum())


# numpy's ndarray.flags.num bits: C order, aligned, writeable (as _aot checks a kernel's
# array arguments).
_C_ALIGNED_WRITEABLE = 0x1 | 0x100 | 0x400


def _compiled_layout(points) -> bool:
    """Is ``points`` an ``(N, 2)`` float64 array in the layout the geometry kernels are
    compiled for (C order, aligned, writeable)? Others take NumPy's path, to the same
    result, rather than a kernel compiled for them."""
    return (
        type(points) is np.ndarray
        and points.dtype == np.float64
        and points.ndim == 2
        and points.shape[1] == 2
        and points.flags.num & _C_ALIGNED_WRITEABLE == _C_ALIGNED_WRITEABLE
    )


def on_mask(mask: np.ndarray, x: float, y: float) -> bool:
    """Whether the pixel nearest ``(x, y)`` is on ``mask`` (False outside the picture)."""
    column, row = round(x), round(y)
    return 0 <= column < mask.shape[1] and 0 <= row < mask.shape[0] and bool(mask[row, column])
