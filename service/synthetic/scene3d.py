"""Generated 3-D cable scenes seen by a known camera, with their exact centrelines.

:func:`make_scene_3d` lays cables (tubes of a given radius around closed-form centrelines)
on a table ``z = 0`` of the robot base frame, optionally over a box, and renders what a
calibrated camera sees: a BGR image (shaded, with sensor noise) and the depth image
(camera ``z`` of the first surface each pixel's ray meets, cables included, as a depth
camera aligned with the colour camera measures it). It is an independent ray caster, not
the code under test: pixels are undistorted with OpenCV (the camera model's definition of
distortion), and each ray is met with the table, the box and every cable (a union of
spheres along the centreline, closer together than a twelfth of the radius, so the tube
is exact to well under a micrometre of ripple).

The kinds (:data:`SCENE_KINDS`):

* ``down``: a camera 0.5 m above the table looking straight down; two cables.
* ``tilted``: looking down at 35 degrees from the vertical; two cables.
* ``distorted``: tilted 20 degrees with strong radial and tangential distortion.
* ``box``: looking straight down at a 60 mm box; one cable lies across its top, over its
  edge (wrapped round it), down a straight slope and round a bend onto the table, the
  other on the table.
* ``box_tilted``: the same seen from 25 degrees, the slope facing the camera.
* ``crossing``: straight down; one cable lying across another (raised over it by a
  smooth bump that keeps their surfaces apart), so the detector reports a crossing.

Coordinates: metres in the base frame; pixels as in :mod:`schemas.detection`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np
from scipy.spatial import cKDTree

from schemas import CameraModel

SceneKind = Literal["down", "tilted", "distorted", "box", "box_tilted", "crossing"]
SCENE_KINDS: tuple[SceneKind, ...] = (
    "down",
    "tilted",
    "distorted",
    "box",
    "box_tilted",
    "crossing",
)

SPHERE_SPACING = 1.0 / 12.0
"""Spheres along a centreline this many radii apart: the tube's ripple is r/1150."""
SAMPLE_SPACING_M = 2e-4
"""Centreline samples (the ground truth) are at most this far apart."""

_CABLE_COLOURS_BGR = ((45, 45, 215), (50, 215, 225), (70, 195, 70), (225, 120, 40), (235, 235, 232))
_TABLE_BGR = (52, 55, 58)
_BOX_BGR = (78, 74, 70)
_SIDE_LAMP = np.array([0.3, -0.4, 0.87]) / np.linalg.norm([0.3, -0.4, 0.87])


@dataclass(frozen=True, eq=False)
class Cable3D:
    """One cable: its centreline (``(N, 3)`` metres, samples <= 0.2 mm apart) and radius."""

    centreline: np.ndarray
    radius: float
    colour: tuple[int, int, int]


@dataclass(frozen=True, eq=False)
class Box:
    """An axis-aligned box standing on the table: ``low`` and ``high`` corners (metres)."""

    low: np.ndarray
    high: np.ndarray


@dataclass(frozen=True, eq=False)
class Scene3D:
    """A rendered 3-D scene and its truth.

    Attributes
    ----------
    image : ndarray (H, W, 3) uint8
        What the colour camera sees (BGR).
    depth_m : ndarray (H, W) float32
        Camera ``z`` of the first surface on each pixel's ray (metres); NaN where the
        pixel could not be undistorted.
    labels : ndarray (H, W) int16
        Index of the cable seen at each pixel, -1 elsewhere.
    camera : CameraModel
        The camera, its surface the table plane ``z = 0``.
    depth_camera : CameraModel
        The same camera whose surface is the depth image (float metres, ``depth_scale`` 1).
    cables : list of Cable3D
    box : Box or None
    """

    image: np.ndarray
    depth_m: np.ndarray
    labels: np.ndarray
    camera: CameraModel
    depth_camera: CameraModel
    cables: list[Cable3D]
    box: Box | None

    def distance_to_centrelines(self, points: np.ndarray) -> np.ndarray:
        """Distance (metres) from each point to the nearest cable centreline (NaN rows: NaN)."""
        return distance_to_polylines(points, [cable.centreline for cable in self.cables])

    def depth_mm_png(self) -> np.ndarray:
        """The depth image as uint16 millimetres (0 where unknown), as a 16-bit PNG holds it."""
        millimetres = np.where(np.isfinite(self.depth_m), np.round(self.depth_m * 1000.0), 0)
        return np.clip(millimetres, 0, 65535).astype(np.uint16)


def make_scene_3d(
    kind: SceneKind = "down",
    seed: int = 0,
    *,
    width: int = 1280,
    height: int = 960,
    focal: float = 1400.0,
    noise_sigma: float = 3.0,
    lighting: Literal["ring", "side"] = "ring",
) -> Scene3D:
    """Lay out and render a scene of ``kind`` (:data:`SCENE_KINDS`); same seed, same scene.

    The default camera (1280 x 960 px, focal length 1400 px: 0.36 mm per pixel at 0.5 m)
    resolves the millimetre a robot needs; the layout is in metres, so a smaller image or
    focal length sees the same scene more coarsely. ``lighting``: the ceiling and a ring
    light round the lens, or the ceiling and a lamp off to one side (which shades cables
    brighter on one side, and so shifts where a detector puts their centrelines).

    Raises
    ------
    ValueError
        For an unknown kind.
    """
    if kind not in SCENE_KINDS:
        raise ValueError(f"unknown scene kind {kind!r}; choose from {', '.join(SCENE_KINDS)}")
    rng = np.random.default_rng(seed)
    box = None
    optics = {"width": width, "height": height, "focal": focal}
    if kind == "down":
        camera = look_at((0.3, 0.0, 0.5), (0.3, 0.0, 0.0), **optics)
        cables = _flat_cables(rng, 2, centre=(0.3, 0.0), extent=(0.34, 0.24))
    elif kind == "tilted":
        camera = look_at(_eye((0.3, 0.0, 0.0), 0.55, 35.0), (0.3, 0.0, 0.0), **optics)
        cables = _flat_cables(rng, 2, centre=(0.3, 0.0), extent=(0.32, 0.2))
    elif kind == "distorted":
        dist = (-0.28, 0.09, 0.0012, -0.0015, -0.012)
        camera = look_at(_eye((0.3, 0.0, 0.0), 0.5, 20.0), (0.3, 0.0, 0.0), dist=dist, **optics)
        cables = _flat_cables(rng, 2, centre=(0.3, 0.0), extent=(0.34, 0.24))
    elif kind in ("box", "box_tilted"):
        box = Box(low=np.array([0.22, -0.16, 0.0]), high=np.array([0.40, -0.02, 0.06]))
        if kind == "box":
            camera = look_at((0.3, 0.0, 0.55), (0.3, 0.0, 0.0), **optics)
        else:
            camera = look_at(_eye((0.3, 0.02, 0.0), 0.6, -25.0), (0.3, 0.02, 0.0), **optics)
        side = _flat_cables(rng, 1, centre=(0.47, 0.0), extent=(0.24, 0.04), heading=math.pi / 2)
        cables = [_draped_cable(rng, box), *side]
    else:  # crossing
        camera = look_at((0.3, 0.0, 0.5), (0.3, 0.0, 0.0), **optics)
        cables = _crossing_cables(rng)
    image, depth_m, labels = render(camera, cables, box, rng, noise_sigma, lighting)
    depth_camera = camera.model_copy(update={"surface": _depth_surface()})
    return Scene3D(
        image=image,
        depth_m=depth_m,
        labels=labels,
        camera=camera,
        depth_camera=depth_camera,
        cables=cables,
        box=box,
    )


def _depth_surface():
    from schemas import DepthSurface

    return DepthSurface(kind="depth", depth_scale=1.0, window=5)


# --------------------------------------------------------------------------- cameras


def look_at(
    eye,
    target,
    *,
    width: int = 640,
    height: int = 480,
    focal: float = 800.0,
    dist=(0.0, 0.0, 0.0, 0.0, 0.0),
) -> CameraModel:
    """A camera at ``eye`` looking at ``target`` (base frame), image rows along base -y
    as far as the view allows; its surface the table ``z = 0``."""
    eye, target = np.asarray(eye, dtype=float), np.asarray(target, dtype=float)
    forward = (target - eye) / np.linalg.norm(target - eye)
    across = np.array([1.0, 0.0, 0.0]) - forward[0] * forward
    across /= np.linalg.norm(across)
    rows = np.cross(forward, across)
    transform = np.eye(4)
    transform[:3, :3] = np.column_stack((across, rows, forward))
    transform[:3, 3] = eye
    return CameraModel(
        fx=focal,
        fy=focal,
        cx=(width - 1) / 2.0,
        cy=(height - 1) / 2.0,
        width=width,
        height=height,
        dist=tuple(dist),
        T_base_camera=transform.tolist(),
        surface={"plane_z": 0.0},
    )


def _eye(target, distance: float, tilt_deg: float) -> tuple[float, float, float]:
    """A point ``distance`` from ``target``, tilted from the vertical towards base -y
    (towards +y for a negative tilt)."""
    tilt = math.radians(tilt_deg)
    return (
        target[0],
        target[1] - distance * math.sin(tilt),
        target[2] + distance * math.cos(tilt),
    )


# --------------------------------------------------------------------------- cables


def _flat_cables(rng, count: int, centre, extent, heading: float = 0.0) -> list[Cable3D]:
    """``count`` cables lying on the table: gentle waves across a rectangle, not touching."""
    cables = []
    for index in range(count):
        radius = float(rng.uniform(0.0025, 0.004))
        along = np.linspace(-extent[0] / 2, extent[0] / 2, 4000)
        lane = (index - (count - 1) / 2) * extent[1] / max(count, 1)
        amplitude = rng.uniform(0.01, 0.025)
        wavelength = rng.uniform(0.12, 0.25)
        phase = rng.uniform(0, 2 * math.pi)
        sideways = lane + amplitude * np.sin(2 * math.pi * along / wavelength + phase)
        sideways += 0.2 * amplitude * np.sin(2 * math.pi * along / (0.45 * wavelength))
        angle = heading + rng.uniform(-0.25, 0.25)
        x = centre[0] + along * math.cos(angle) - sideways * math.sin(angle)
        y = centre[1] + along * math.sin(angle) + sideways * math.cos(angle)
        centreline = np.column_stack((x, y, np.full_like(x, radius)))
        cables.append(Cable3D(_densify(centreline), radius, _CABLE_COLOURS_BGR[index % 5]))
    return cables


def _draped_cable(rng, box: Box) -> Cable3D:
    """A cable across the top of ``box``, wrapped over its +y edge, down a straight slope
    and round a bend onto the table, in the vertical plane ``x = const``.

    In that plane, with ``s`` along +y and ``z`` up: flat at ``z = H + r`` on the box; a
    circle of radius ``r`` round the edge ``(e, H)`` down to the slope angle ``theta``; a
    straight line at ``theta`` below the horizontal; a circle of radius ``rho`` bending it
    back to horizontal at ``z = r``; flat on the table.
    """
    radius = float(rng.uniform(0.0028, 0.0038))
    height = float(box.high[2])
    edge = float(box.high[1])
    theta = math.radians(rng.uniform(40.0, 60.0))
    rho = float(rng.uniform(0.02, 0.035))
    x = float(rng.uniform(box.low[0] + 0.04, box.high[0] - 0.04))
    s_top = np.linspace(edge - 0.1, edge, 1000)
    top = np.column_stack((s_top, np.full_like(s_top, height + radius)))
    angles = np.linspace(0.0, theta, 200)
    wrap = np.column_stack((edge + radius * np.sin(angles), height + radius * np.cos(angles)))
    leave = wrap[-1]
    direction = np.array([math.cos(theta), -math.sin(theta)])
    outward = np.array([math.sin(theta), math.cos(theta)])
    run = (leave[1] + rho * math.cos(theta) - radius - rho) / math.sin(theta)
    slope_end = leave + run * direction
    slope = leave + np.linspace(0.0, run, 800)[:, None] * direction
    bend_centre = slope_end + rho * outward
    bend_angles = np.linspace(-math.pi / 2 - theta, -math.pi / 2, 300)
    bend = bend_centre + rho * np.column_stack((np.cos(bend_angles), np.sin(bend_angles)))
    flat_s = np.linspace(bend[-1, 0], bend[-1, 0] + 0.07, 700)
    flat = np.column_stack((flat_s, np.full_like(flat_s, radius)))
    profile = np.vstack((top, wrap[1:], slope[1:], bend[1:], flat[1:]))
    centreline = np.column_stack((np.full(len(profile), x), profile[:, 0], profile[:, 1]))
    return Cable3D(_densify(centreline), radius, _CABLE_COLOURS_BGR[int(rng.integers(0, 5))])


def _crossing_cables(rng) -> list[Cable3D]:
    """Two cables crossing at 50-90 degrees; the second lies over the first, raised by a
    Gaussian bump whose height keeps their surfaces apart."""
    radius = float(rng.uniform(0.0028, 0.0035))
    crossing = np.array([0.3 + rng.uniform(-0.03, 0.03), rng.uniform(-0.02, 0.02)])
    cables = []
    angles = (rng.uniform(-0.3, 0.3), 0.0)
    angles = (angles[0], angles[0] + math.radians(rng.uniform(50, 90)))
    for index, angle in enumerate(angles):
        along = np.linspace(-0.15, 0.15, 3000)
        bow = 0.015 * np.sin(2 * math.pi * along / 0.3 + index)
        x = crossing[0] + along * math.cos(angle) - bow * math.sin(angle)
        y = crossing[1] + along * math.sin(angle) + bow * math.cos(angle)
        cables.append(np.column_stack((x, y, np.full_like(x, radius))))
    lower = cKDTree(cables[0][:, :2])
    apart, _ = lower.query(cables[1][:, :2])
    cables[1][:, 2] += 2 * radius * np.exp(-((apart / (3 * radius)) ** 2))
    return [
        Cable3D(_densify(points), radius, _CABLE_COLOURS_BGR[index])
        for index, points in enumerate(cables)
    ]


def _densify(points: np.ndarray) -> np.ndarray:
    """Insert samples so that consecutive ones are at most :data:`SAMPLE_SPACING_M` apart."""
    steps = np.linalg.norm(np.diff(points, axis=0), axis=1)
    pieces = np.maximum(np.ceil(steps / SAMPLE_SPACING_M).astype(int), 1)
    out = [points[:1]]
    for start, end, count in zip(points[:-1], points[1:], pieces, strict=True):
        t = np.arange(1, count + 1)[:, None] / count
        out.append(start + t * (end - start))
    return np.vstack(out)


def distance_to_polylines(points: np.ndarray, polylines: list[np.ndarray]) -> np.ndarray:
    """Exact distance from each point to the nearest of ``polylines`` (NaN rows give NaN)."""
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    best = np.full(len(points), np.inf)
    finite = np.isfinite(points).all(axis=1)
    for line in polylines:
        tree = cKDTree(line)
        _, nearest = tree.query(points[finite])
        for offset in (-1, 0):  # the segments before and after the nearest sample
            first = np.clip(nearest + offset, 0, len(line) - 2)
            start, end = line[first], line[first + 1]
            step = end - start
            t = np.einsum("ij,ij->i", points[finite] - start, step) / np.maximum(
                np.einsum("ij,ij->i", step, step), 1e-30
            )
            closest = start + np.clip(t, 0.0, 1.0)[:, None] * step
            distance = np.linalg.norm(points[finite] - closest, axis=1)
            best[finite] = np.minimum(best[finite], distance)
    best[~finite] = np.nan
    return best


# --------------------------------------------------------------------------- rendering


#: Rows ray-cast at a time. A pixel's ray and what it meets do not depend on its
#: neighbours, so the image is cast in bands: whole-image arrays of rays, normals and
#: colours (about a dozen float arrays of 3 x 8 bytes per pixel) made a 1280 x 960 scene
#: peak near 800 MB, which set ``dlo bench``'s peak memory rather than the detector.
RENDER_BAND_ROWS = 64


def render(
    camera: CameraModel,
    cables: list[Cable3D],
    box: Box | None,
    rng,
    noise_sigma: float,
    lighting: str = "ring",
):
    """Ray-cast the scene: (BGR image, depth in metres, cable labels).

    Cast in bands of :data:`RENDER_BAND_ROWS` rows, top to bottom, the noise drawn band
    after band from ``rng`` (the same values as one draw for the whole image).
    """
    width, height = camera.width, camera.height
    K = np.array([[camera.fx, 0, camera.cx], [0, camera.fy, camera.cy], [0, 0, 1.0]])
    dist = np.asarray(camera.dist, dtype=float)
    origin = np.asarray(camera.T_base_camera)[:3, 3]
    spheres = [_cable_spheres(cable, camera, K, dist, origin) for cable in cables]
    image = np.empty((height, width, 3), dtype=np.uint8)
    depth_m = np.empty((height, width), dtype=np.float32)
    labels = np.empty((height, width), dtype=np.int16)
    for top in range(0, height, RENDER_BAND_ROWS):
        bottom = min(top + RENDER_BAND_ROWS, height)
        band = _render_band(
            camera, top, bottom, K, dist, cables, spheres, box, rng, noise_sigma, lighting
        )
        image[top:bottom], depth_m[top:bottom], labels[top:bottom] = band
    return image, depth_m, labels


def _render_band(camera, top, bottom, K, dist, cables, spheres, box, rng, noise_sigma, lighting):
    """Rows ``top:bottom`` of :func:`render`'s three images."""
    width = camera.width
    columns, rows = np.meshgrid(np.arange(width, dtype=float), np.arange(top, bottom, dtype=float))
    pixels = np.column_stack((columns.ravel(), rows.ravel()))
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)
    source = pixels.reshape(-1, 1, 2)
    try:
        normalised = cv2.undistortPoints(source, K, dist, None, None, None, criteria)
    except cv2.error:  # OpenCV releases whose undistortPoints takes no criteria
        normalised = cv2.undistortPointsIter(source, K, dist, None, None, criteria)
    normalised = normalised.reshape(-1, 2)
    rays_cam = np.column_stack((normalised, np.ones(len(normalised))))
    again, _ = cv2.projectPoints(rays_cam, np.zeros(3), np.zeros(3), K, dist)
    converged = np.hypot(*(again.reshape(-1, 2) - pixels).T) < 1e-3
    transform = np.asarray(camera.T_base_camera)
    rotation, origin = transform[:3, :3], transform[:3, 3]
    directions = rays_cam @ rotation.T
    directions /= np.linalg.norm(directions, axis=1)[:, None]

    count = len(pixels)
    hit = np.full(count, np.inf)
    normals = np.zeros((count, 3))
    albedo = np.zeros((count, 3))
    labels = np.full(count, -1, dtype=np.int16)

    with np.errstate(divide="ignore", invalid="ignore"):
        table = -origin[2] / directions[:, 2]
    on_table = converged & (table > 0)
    hit[on_table] = table[on_table]
    normals[on_table] = (0.0, 0.0, 1.0)
    albedo[on_table] = _TABLE_BGR
    if box is not None:
        _hit_box(box, origin, directions, converged, hit, normals, albedo)
    rays = (origin, directions, converged, width, top, bottom)
    for index, (cable, cable_spheres) in enumerate(zip(cables, spheres, strict=True)):
        _hit_cable(cable, index, cable_spheres, rays, hit, normals, albedo, labels)

    # A lit room: light from the whole ceiling (a surface facing sideways gets half of it)
    # and a lamp: a ring light round the lens (cables darker towards their rims on both
    # sides), or off to one side (brighter on one side).
    sky = 0.5 + 0.5 * normals[:, 2]
    light = _SIDE_LAMP if lighting == "side" else -rotation[:, 2]
    lambert = np.clip(normals @ light, 0.0, 1.0)
    shade = 0.6 * sky + 0.4 * lambert
    colour = albedo * shade[:, None]
    colour += rng.normal(0.0, noise_sigma, colour.shape)
    shape = (bottom - top, width)
    image = np.clip(np.round(colour), 0, 255).astype(np.uint8).reshape(*shape, 3)
    points = origin + np.where(np.isfinite(hit), hit, np.nan)[:, None] * directions
    depth = ((points - origin) @ rotation)[:, 2]
    return image, depth.astype(np.float32).reshape(shape), labels.reshape(shape)


def _hit_box(box, origin, directions, converged, hit, normals, albedo):
    """Slab test against the box; the nearest entry face wins where it is nearer."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t_low = (box.low - origin) / directions
        t_high = (box.high - origin) / directions
    near = np.minimum(t_low, t_high)
    far = np.maximum(t_low, t_high)
    entry = np.nanmax(near, axis=1)
    leave = np.nanmin(far, axis=1)
    axis = np.nanargmax(near, axis=1)
    inside = converged & (entry <= leave) & (entry > 0) & (entry < hit)
    hit[inside] = entry[inside]
    face = np.zeros((inside.sum(), 3))
    face[np.arange(len(face)), axis[inside]] = -np.sign(directions[inside, axis[inside]])
    normals[inside] = face
    albedo[inside] = _BOX_BGR


def _cable_spheres(cable, camera, K, dist, origin):
    """The spheres :func:`_hit_cable` casts a cable as: (centres, pixel centres, pixel reach)."""
    step = max(1, int(cable.radius * SPHERE_SPACING / SAMPLE_SPACING_M))
    centres = cable.centreline[::step]
    if not np.array_equal(centres[-1], cable.centreline[-1]):
        centres = np.vstack((centres, cable.centreline[-1:]))
    rotation = np.asarray(camera.T_base_camera)[:3, :3]
    in_camera = (centres - origin) @ rotation
    projected, _ = cv2.projectPoints(in_camera, np.zeros(3), np.zeros(3), K, dist)
    projected = projected.reshape(-1, 2)
    reach = 1.6 * camera.fx * cable.radius / np.maximum(in_camera[:, 2], 1e-6) + 3
    return centres, projected, reach


def _hit_cable(cable, index, spheres, rays, hit, normals, albedo, labels):
    """Every pixel of the band whose ray meets a sphere along the cable nearer than what it
    hit so far (``rays``: origin, directions, converged, width and the band's rows)."""
    origin, directions, converged, width, band_top, band_bottom = rays
    radius_sq = cable.radius**2
    for centre, (u, v), extent in zip(*spheres, strict=True):
        left, right = max(int(u - extent), 0), min(int(u + extent) + 1, width)
        top, bottom = max(int(v - extent), band_top), min(int(v + extent) + 1, band_bottom)
        if left >= right or top >= bottom:
            continue
        grid_rows, grid_columns = np.mgrid[top - band_top : bottom - band_top, left:right]
        candidates = (grid_rows * width + grid_columns).ravel()
        candidates = candidates[converged[candidates]]
        towards = centre - origin
        along = directions[candidates] @ towards
        miss_sq = towards @ towards - along**2
        meets = miss_sq < radius_sq
        if not meets.any():
            continue
        candidates, along, miss_sq = candidates[meets], along[meets], miss_sq[meets]
        t = along - np.sqrt(radius_sq - miss_sq)
        nearer = (t > 0) & (t < hit[candidates])
        candidates, t = candidates[nearer], t[nearer]
        hit[candidates] = t
        surface = origin + t[:, None] * directions[candidates]
        normals[candidates] = (surface - centre) / cable.radius
        albedo[candidates] = cable.colour
        labels[candidates] = index
