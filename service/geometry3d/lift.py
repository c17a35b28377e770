"""Chains lifted to the robot base frame: every joint on the cable's centreline, in metres.

:func:`lift` places each joint's ray (:mod:`service.geometry3d.camera`, the code grasp
planning uses) on the camera model's surface:

* **Plane** (:class:`~schemas.grasp.PlaneSurface`): the cable lies on the table, so its
  centreline is the plane ``z = plane_z + radius_m``; every joint is its ray's point at
  that height, hidden ones included (a cable hidden under an occluder still lies on the
  table). The radius: the chain's pixel radius times the angle a pixel spans across the
  chain times the distance along the ray (the median over the chain's joints).
* **Depth image** (:class:`~schemas.grasp.DepthSurface`): a depth camera aligned with the
  colour camera sees the cable itself, so the depth at a joint's nearest pixel is the near
  side of the cable, and the centreline lies further along the ray by ``radius_m /
  sin(a)`` (``a`` the angle between the ray and the cable, from the neighbouring joints:
  exactly where a ray through the axis of a cylinder enters it). The radius is measured in
  the depth image where the cable lies on a surface: the surface on either side of it (a
  few radii out across the chain) and the chain's direction give the surface's plane, the
  near side is ``r (1 - u.n / sin(a))`` above it (``u`` the ray, ``n`` the plane's normal;
  ``2 r`` seen from straight above), and the median over the joints where both sides lie
  on one plane and the result is within a factor of two of the pixel radius is taken; with
  fewer than three such joints, the pixel radius as on a plane. A joint whose depth is
  missing around it (:func:`~service.geometry3d.depth.depth_at`) is ``null``. A joint on
  an inferred segment (hidden under an occluder or another cable) is not where its depth
  sample is (that sees what hides it): it is put on its own ray at the depth interpolated
  between the nearest located seen joints on either side (inverse depth, linear in the
  image, which is exact for a cable lying on any plane).

Crossings: see :mod:`service.geometry3d.crossings` (the upper strand lies on the lower one).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from schemas import CameraModel, Chain, DepthSurface, Detection, PlaneSurface
from service.geometry3d.camera import (
    base_from_camera,
    plane_depths,
    ray_directions,
    undistort_points,
)
from service.geometry3d.crossings import hidden_at_crossings, raise_upper_strands
from service.geometry3d.depth import checked_depth, depth_at_pixels
from service.geometry3d.errors import LiftError

MIN_SINE = 0.5
"""Rays meeting the cable at less than 30 degrees are taken at 30 degrees: the offset from
the near side to the axis grows as ``1 / sin`` and would magnify depth noise without bound."""

SIDE_RADII = 2.5
"""The surface beside a cable is sampled this many pixel radii out across the chain (at
least :data:`SIDE_MARGIN_PX` beyond the radius): clear of the cable even when its pixel
radius is underestimated by a third."""
SIDE_MARGIN_PX = 4.0

MIN_MEASURED = 3
"""Joints at which the radius must be measured in the depth image for it to be used."""


def lift(detection: Detection, camera: CameraModel, depth: np.ndarray | None = None) -> Detection:
    """The detection with every chain's joints in the robot base frame (``points_3d``).

    Parameters
    ----------
    detection
        Chains in pixels of an image of ``camera.width`` x ``camera.height``.
    camera
        Intrinsics, distortion, the camera's pose in the base frame and the surface.
    depth
        The depth image, required when ``camera.surface`` is a
        :class:`~schemas.grasp.DepthSurface` and refused otherwise: ``(height, width)``
        uint16 or float samples in units of ``camera.surface.depth_scale`` metres.

    Returns
    -------
    Detection
        A copy whose chains carry ``points_3d`` (metres, base frame; None for a joint that
        could not be located) and ``radius_m`` (None when no joint of the chain could be).

    Raises
    ------
    LiftError
        The detection's image size differs from the camera's.
    DepthImageError
        The depth image is missing for a depth surface, given for a plane, or of another
        size or an unusable type.
    """
    if (detection.width, detection.height) != (camera.width, camera.height):
        raise LiftError(
            f"detection is {detection.width}x{detection.height} px but the camera model is "
            f"{camera.width}x{camera.height} px"
        )
    samples = checked_depth(camera, depth)
    if not detection.chains:
        return detection.model_copy()
    surface = camera.surface
    if samples is None:
        assert isinstance(surface, PlaneSurface)  # checked_depth wants a depth otherwise
        joints = _Joints.of(camera, detection.chains, sides=False)
        points, radii = _on_plane(joints, surface.plane_z)
    else:
        assert isinstance(surface, DepthSurface)
        joints = _Joints.of(camera, detection.chains, sides=True)
        hidden = _hidden(detection) | ~joints.ok
        points, radii = _on_depth(joints, samples, surface, hidden)
    points = raise_upper_strands(detection, points, radii, joints.starts, joints.units)
    chains = [
        chain.model_copy(
            update={
                "points_3d": _as_points(points[joints.starts[index] : joints.starts[index + 1]]),
                "radius_m": None if math.isnan(radii[index]) else float(radii[index]),
            }
        )
        for index, chain in enumerate(detection.chains)
    ]
    return detection.model_copy(update={"chains": chains})


@dataclass
class _Joints:
    """Every joint of every chain, chain after chain, with its ray."""

    camera: CameraModel
    origin: np.ndarray  # (3,) the camera centre, base frame
    pixels: np.ndarray  # (M, 2)
    starts: np.ndarray  # (K + 1,) chain k's joints are starts[k]:starts[k + 1]
    radius_px: np.ndarray  # (M,) the pixel radius of each joint's chain
    directions: np.ndarray  # (M, 3) base frame, scaled to camera z = 1
    lengths: np.ndarray  # (M,) |direction|: distance along the ray per unit of depth
    units: np.ndarray  # (M, 3) unit rays
    normalised: np.ndarray  # (M, 2) undistorted image coordinates
    ok: np.ndarray  # (M,) undistorted
    pixel_angles: np.ndarray  # (M,) radians spanned by a pixel across the chain (NaN: unknown)
    side_pixels: np.ndarray | None  # (2, M, 2) beside the cable, both sides
    side_directions: np.ndarray | None  # (2, M, 3)
    previous: np.ndarray  # (M,) the joint before on the same chain (itself at a start)
    following: np.ndarray  # (M,) the joint after on the same chain (itself at an end)

    @classmethod
    def of(cls, camera: CameraModel, chains: list[Chain], *, sides: bool) -> _Joints:
        counts = np.array([len(chain.points) for chain in chains])
        starts = np.concatenate(([0], np.cumsum(counts)))
        pixels = np.concatenate([np.asarray(chain.points, dtype=float) for chain in chains])
        across = np.concatenate([_normals(np.asarray(c.points, dtype=float)) for c in chains])
        radius_px = np.repeat([chain.radius for chain in chains], counts).astype(float)
        # One pixel across the chain gives the angle a pixel spans; the sides (when asked
        # for) give it over their span, and the surface beside the cable.
        count = len(pixels)
        if sides:
            reach = np.maximum(SIDE_RADII * radius_px, radius_px + SIDE_MARGIN_PX)
            offsets = across * reach[:, None]
            probes = np.concatenate((pixels, pixels - offsets, pixels + offsets))
        else:  # one pixel across is enough for the angle a pixel spans
            reach = np.full(count, 0.5)
            probes = np.concatenate((pixels, pixels - 0.5 * across, pixels + 0.5 * across))
        normalised, ok = undistort_points(camera, probes)
        directions = ray_directions(camera, normalised)
        units = directions / np.linalg.norm(directions, axis=1)[:, None]
        first, second = units[count : 2 * count], units[2 * count :]
        chord = np.linalg.norm(first - second, axis=1)
        pixel_angles = 2.0 * np.arcsin(np.clip(chord / 2.0, 0.0, 1.0)) / (2.0 * reach)
        # Probes that could not be undistorted (beyond a strongly distorted image's edge)
        # leave the angle unknown there: those joints do not count towards the radius.
        pixel_angles[~(ok[count : 2 * count] & ok[2 * count :])] = np.nan
        index = np.arange(count)
        chain_of = np.repeat(np.arange(len(chains)), counts)
        previous = np.where(index > starts[chain_of], index - 1, index)
        following = np.where(index < starts[chain_of + 1] - 1, index + 1, index)
        return cls(
            camera=camera,
            origin=base_from_camera(camera)[1],
            pixels=pixels,
            starts=starts,
            radius_px=radius_px,
            directions=directions[:count],
            lengths=np.linalg.norm(directions[:count], axis=1),
            units=units[:count],
            normalised=normalised[:count],
            ok=ok[:count],
            pixel_angles=pixel_angles,
            side_pixels=np.stack((probes[count : 2 * count], probes[2 * count :]))
            if sides
            else None,
            side_directions=(
                np.stack((directions[count : 2 * count], directions[2 * count :]))
                if sides
                else None
            ),
            previous=previous,
            following=following,
        )

    def per_chain_median(self, values: np.ndarray) -> np.ndarray:
        """The median of each chain's finite ``values`` (NaN for a chain with none)."""
        medians = np.full(len(self.starts) - 1, np.nan)
        for index in range(len(medians)):
            chain_values = values[self.starts[index] : self.starts[index + 1]]
            chain_values = chain_values[np.isfinite(chain_values)]
            if chain_values.size:
                medians[index] = np.median(chain_values)
        return medians

    def per_joint(self, per_chain: np.ndarray) -> np.ndarray:
        return np.repeat(per_chain, np.diff(self.starts))


def _normals(points: np.ndarray) -> np.ndarray:
    """Unit image normals of a polyline at its points (of the central difference)."""
    tangents = np.empty_like(points)
    tangents[1:-1] = points[2:] - points[:-2]
    tangents[0] = points[1] - points[0]
    tangents[-1] = points[-1] - points[-2]
    lengths = np.linalg.norm(tangents, axis=1)
    tangents = np.where(lengths[:, None] > 0, tangents / np.maximum(lengths, 1e-12)[:, None], 0.0)
    normals = np.column_stack((-tangents[:, 1], tangents[:, 0]))
    normals[lengths == 0] = (1.0, 0.0)  # a degenerate chain: any direction will do
    return normals


def _on_plane(joints: _Joints, plane_z: float) -> tuple[np.ndarray, np.ndarray]:
    """Every joint on the plane ``z = plane_z + radius``: ``(M, 3)`` points and the radii."""
    table = plane_depths(joints.camera, joints.directions, plane_z)
    table = np.where(joints.ok, table, np.nan)
    radii = joints.per_chain_median(joints.radius_px * joints.pixel_angles * table * joints.lengths)
    heights = plane_z + joints.per_joint(radii)
    depths = np.where(joints.ok, plane_depths(joints.camera, joints.directions, heights), np.nan)
    return joints.origin + depths[:, None] * joints.directions, radii


def _on_depth(
    joints: _Joints, samples: np.ndarray, surface: DepthSurface, hidden: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Every joint from the depth image: ``(M, 3)`` centreline points and the radii."""
    assert joints.side_pixels is not None and joints.side_directions is not None
    count = len(joints.units)
    probes = np.concatenate((joints.pixels, *joints.side_pixels))
    sampled = depth_at_pixels(samples, probes, surface.window, surface)
    near_depths = np.where(~hidden, sampled[:count], np.nan)
    near = joints.origin + near_depths[:, None] * joints.directions
    distances = near_depths * joints.lengths
    tangents = _tangents(near, joints)
    sines = _sines(joints.units, tangents)
    sides = [
        joints.origin + sampled[(k + 1) * count : (k + 2) * count, None] * joints.side_directions[k]
        for k in range(2)
    ]
    measured = _radii_from_surface(joints, near, sides, tangents, sines, distances)
    from_pixels = joints.radius_px * joints.pixel_angles * distances
    radii = joints.per_chain_median(from_pixels)
    for index in range(len(radii)):
        chain = slice(joints.starts[index], joints.starts[index + 1])
        values = measured[chain][np.isfinite(measured[chain])]
        if values.size >= MIN_MEASURED:
            radii[index] = np.median(values)
    offsets = joints.per_joint(radii) / np.maximum(sines, MIN_SINE)
    depths = (distances + offsets) / joints.lengths
    _fill_hidden(joints, depths, hidden)
    return joints.origin + depths[:, None] * joints.directions, radii


def _radii_from_surface(joints, near, sides, tangents, sines, distances) -> np.ndarray:
    """Per joint, the radius measured from the surface beside the cable (NaN where not)."""
    left, right = sides
    across = right - left
    normals = np.cross(across, tangents)
    norms = np.linalg.norm(normals, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        normals = normals / norms[:, None]
        facing = np.einsum("ij,ij->i", normals, joints.units)
        normals = np.where((facing > 0)[:, None], -normals, normals)  # towards the camera
        facing = -np.abs(facing)
        heights = np.einsum("ij,ij->i", near - 0.5 * (left + right), normals)
        radii = heights / (1.0 - facing / np.maximum(sines, MIN_SINE))
        from_pixels = joints.radius_px * joints.pixel_angles * distances
        # Both sides on one plane with the cable: as far apart as the image says they
        # are (within a factor of two either way; a step between them is much more).
        apart_px = np.linalg.norm(joints.side_pixels[1] - joints.side_pixels[0], axis=1)
        expected = apart_px * joints.pixel_angles * distances
        ratio = np.linalg.norm(across, axis=1) / expected
        good = (
            np.isfinite(radii)
            & (norms > 0)
            & (ratio > 0.5)
            & (ratio < 2.0)
            & (radii > 0.5 * from_pixels)
            & (radii < 2.0 * from_pixels)
        )
    return np.where(good, radii, np.nan)


def _tangents(points: np.ndarray, joints: _Joints) -> np.ndarray:
    """Each joint's direction along its chain from its located neighbours (zero if none)."""
    valid = np.isfinite(points).all(axis=1)
    before = np.where(valid[joints.previous], joints.previous, np.arange(len(points)))
    after = np.where(valid[joints.following], joints.following, np.arange(len(points)))
    tangents = points[after] - points[before]
    return np.where(np.isfinite(tangents) & valid[:, None], tangents, 0.0)


def _sines(units: np.ndarray, tangents: np.ndarray) -> np.ndarray:
    """Sine of the angle between each ray and the cable (1 where the cable's is unknown)."""
    norms = np.linalg.norm(tangents, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        sines = np.linalg.norm(np.cross(units, tangents), axis=1) / norms
    return np.where(norms > 0, sines, 1.0)


def _fill_hidden(joints: _Joints, depths: np.ndarray, hidden: np.ndarray) -> None:
    """Hidden joints: inverse depth interpolated along the chain in normalised image
    coordinates between the located seen joints (held beyond the last one)."""
    steps = np.linalg.norm(np.diff(joints.normalised, axis=0), axis=1)
    along = np.concatenate(([0.0], np.cumsum(np.where(np.isfinite(steps), steps, 0.0))))
    fill = hidden & joints.ok
    located = np.isfinite(depths) & ~hidden
    for index in range(len(joints.starts) - 1):
        chain = slice(joints.starts[index], joints.starts[index + 1])
        if not fill[chain].any() or not located[chain].any():
            continue
        known = located[chain]
        inverse = np.interp(
            along[chain][fill[chain]], along[chain][known], 1.0 / depths[chain][known]
        )
        depths[chain][fill[chain]] = 1.0 / inverse


def _hidden(detection: Detection) -> np.ndarray:
    """Joints whose depth sample does not see their own chain: on an inferred segment
    (either side), or under the upper strand at a crossing."""
    flags = []
    for chain in detection.chains:
        inferred = np.asarray(chain.inferred, dtype=bool)
        chain_flags = np.zeros(len(chain.points), dtype=bool)
        chain_flags[:-1] |= inferred
        chain_flags[1:] |= inferred
        flags.append(chain_flags)
    for index, covered in hidden_at_crossings(detection):
        flags[index] |= covered
    return np.concatenate(flags)


def _as_points(points: np.ndarray) -> list[tuple[float, float, float] | None]:
    return [
        (float(x), float(y), float(z)) if math.isfinite(x + y + z) else None
        for x, y, z in points.tolist()
    ]
