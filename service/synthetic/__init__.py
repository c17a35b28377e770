"""Synthetic cable scenes with exact ground truth, for tests, benchmarks and demos.

:func:`make_scene` draws smooth, shaded cables (some with a loop that crosses itself) on a
dark, low-saturation background, optionally hides short stretches of them under
background-like occluders, adds sensor noise, and returns the image together with
everything a perfect detector would report: the visible-cable mask, a per-cable label
image, every cable's whole centreline (hidden stretches included) and every crossing with
the cable on top. :func:`make_family_scene` draws scenes of named families
(:data:`FAMILIES`: tight loops, cables doubled back, shallow crossings, cables side by
side, many cables, occluders on bends and at the edge, bright and busy backgrounds, cables
of one colour), with the same ground truth. :func:`make_video` makes videos of moving
cables with the true position of every material point in every frame, for tracking.

Coordinates are pixels as ``[x, y]`` with pixel centres at integer positions (the OpenCV
convention): ``image[row, col]`` is centred on ``x = col, y = row``. The same arguments
and seed always give the same scene.
"""

from service.synthetic.families import FAMILIES, FAMILY_NAMES, Family, make_family_scene
from service.synthetic.layout import MIN_CROSSING_ANGLE
from service.synthetic.scene import MAX_CABLES, MIN_CABLE_RADIUS, MIN_IMAGE_SIDE, make_scene
from service.synthetic.scene_types import (
    Occluder,
    SceneFeature,
    SyntheticCable,
    SyntheticCrossing,
    SyntheticScene,
)
from service.synthetic.videos import (
    VIDEO_KINDS,
    CableTruth,
    SyntheticVideo,
    VideoFrame,
    make_video,
    write_video,
)

__all__ = [
    "FAMILIES",
    "FAMILY_NAMES",
    "MAX_CABLES",
    "MIN_CABLE_RADIUS",
    "MIN_CROSSING_ANGLE",
    "MIN_IMAGE_SIDE",
    "VIDEO_KINDS",
    "CableTruth",
    "Family",
    "Occluder",
    "SceneFeature",
    "SyntheticCable",
    "SyntheticCrossing",
    "SyntheticScene",
    "SyntheticVideo",
    "VideoFrame",
    "make_family_scene",
    "make_scene",
    "make_video",
    "write_video",
]
