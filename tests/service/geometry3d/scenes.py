"""Generated 3-D scenes and their detections, made once per test session.

Import as ``from tests.service.geometry3d.scenes import detected, true_detection``.
"""

from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np

from schemas import Chain, Crossing, Detection
from service.perception import detect
from service.synthetic3d import Scene3D, make_scene_3d

SEGMENT_PX = 10.0


@lru_cache(maxsize=16)
def scene(kind: str, seed: int) -> Scene3D:
    return make_scene_3d(kind, seed=seed)


@lru_cache(maxsize=16)
def detected(kind: str, seed: int) -> Detection:
    """What the detector finds in the rendered image (default parameters)."""
    return detect(scene(kind, seed).image)


def project(scene_3d: Scene3D, points: np.ndarray) -> np.ndarray:
    """Base-frame points to pixels, with OpenCV's projection (the camera model's definition)."""
    camera = scene_3d.camera
    transform = np.asarray(camera.T_base_camera)
    rotation, origin = transform[:3, :3], transform[:3, 3]
    K = np.array([[camera.fx, 0, camera.cx], [0, camera.fy, camera.cy], [0, 0, 1.0]])
    in_camera = (points - origin) @ rotation
    pixels, _ = cv2.projectPoints(in_camera, np.zeros(3), np.zeros(3), K, np.array(camera.dist))
    return pixels.reshape(-1, 2)


def true_detection(kind: str, seed: int) -> Detection:
    """A perfect detection: each true centreline projected, joints 10 px apart along it,
    its radius the projected radius (median along the cable); where two cross, the
    crossing (the higher one on top) and the lower one's segments under the upper one's
    band inferred, as the detector reports them."""
    scene_3d = scene(kind, seed)
    camera = scene_3d.camera
    chains = []
    for index, cable in enumerate(scene_3d.cables):
        pixels = project(scene_3d, cable.centreline)
        steps = np.linalg.norm(np.diff(pixels, axis=0), axis=1)
        along = np.concatenate(([0.0], np.cumsum(steps)))
        stations = np.arange(0.0, along[-1], SEGMENT_PX)
        joints = np.column_stack([np.interp(stations, along, pixels[:, axis]) for axis in range(2)])
        transform = np.asarray(camera.T_base_camera)
        depth = ((cable.centreline - transform[:3, 3]) @ transform[:3, :3])[:, 2]
        radius_px = float(np.median(camera.fx * cable.radius / depth))
        chains.append(
            Chain(
                id=index,
                points=[tuple(point) for point in joints],
                radius=radius_px,
                inferred=[False] * (len(joints) - 1),
            )
        )
    crossings = []
    for over_index, under_index in ((1, 0), (0, 1)):
        if max(over_index, under_index) >= len(chains):
            continue
        found = _crossing(scene_3d, chains, over_index, under_index)
        if found is not None:
            crossings.append(found)
    for crossing in crossings:
        under, over = chains[crossing.under], chains[crossing.over]
        joints = np.asarray(under.points)
        middles = 0.5 * (joints[:-1] + joints[1:])
        band = np.asarray(over.points)
        covered = _distances(middles, band) <= over.radius
        chains[crossing.under] = under.model_copy(
            update={
                "inferred": [a or bool(b) for a, b in zip(under.inferred, covered, strict=True)]
            }
        )
    return Detection(
        width=camera.width,
        height=camera.height,
        segment_length=SEGMENT_PX,
        chains=chains,
        crossings=crossings,
    )


def _crossing(scene_3d: Scene3D, chains, over_index: int, under_index: int) -> Crossing | None:
    """Where chain ``over_index`` crosses ``under_index`` in the image, if it lies higher."""
    over, under = np.asarray(chains[over_index].points), np.asarray(chains[under_index].points)
    for i in range(len(over) - 1):
        for j in range(len(under) - 1):
            p, r = over[i], over[i + 1] - over[i]
            q, s = under[j], under[j + 1] - under[j]
            denominator = r[0] * s[1] - r[1] * s[0]
            if denominator == 0:
                continue
            t = ((q - p)[0] * s[1] - (q - p)[1] * s[0]) / denominator
            u = ((q - p)[0] * r[1] - (q - p)[1] * r[0]) / denominator
            if 0 <= t < 1 and 0 <= u < 1:
                at = p + t * r
                heights = [float(np.max(cable.centreline[:, 2])) for cable in scene_3d.cables]
                if heights[over_index] <= heights[under_index]:
                    return None
                return Crossing(
                    x=float(at[0]),
                    y=float(at[1]),
                    over=over_index,
                    under=under_index,
                    over_segment=i,
                    under_segment=j,
                    confidence=1.0,
                )
    return None


def _distances(queries: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    starts, steps = polyline[:-1], np.diff(polyline, axis=0)
    t = np.einsum("qsj,sj->qs", queries[:, None] - starts[None], steps) / np.einsum(
        "sj,sj->s", steps, steps
    )
    closest = starts[None] + np.clip(t, 0, 1)[..., None] * steps[None]
    return np.linalg.norm(queries[:, None] - closest, axis=2).min(axis=1)


def lifted_points(detection: Detection) -> np.ndarray:
    """All ``points_3d`` of a lifted detection as one ``(N, 3)`` array, NaN for null."""
    return np.array(
        [
            point if point is not None else (np.nan, np.nan, np.nan)
            for chain in detection.chains
            for point in chain.points_3d
        ],
        dtype=float,
    )
