"""Generated 3-D scenes and their detections, made once per test session.

Import as ``from tests.service.geometry3d.scenes import detected, true_detection``.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from schemas import Detection
from service.evaluation.lifting import perfect_detection
from service.perception import detect
from service.synthetic.scene3d import Scene3D, make_scene_3d


@lru_cache(maxsize=16)
def scene(kind: str, seed: int) -> Scene3D:
    return make_scene_3d(kind, seed=seed)


@lru_cache(maxsize=16)
def detected(kind: str, seed: int) -> Detection:
    """What the detector finds in the rendered image (default parameters)."""
    return detect(scene(kind, seed).image)


def true_detection(kind: str, seed: int) -> Detection:
    """:func:`service.evaluation.lifting.perfect_detection` of a scene."""
    return perfect_detection(scene(kind, seed))


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
