"""Synthetic cable scenes with exact ground truth, for tests, benchmarks and demos.

:func:`make_scene` draws smooth, shaded cables (some with a loop that crosses itself) on a
dark, low-saturation background, optionally hides short stretches of them under
background-like occluders, adds sensor noise, and returns the image together with
everything a perfect detector would report: the visible-cable mask, a per-cable label
image, every cable's whole centreline (hidden stretches included) and every crossing with
the cable on top.

Coordinates are pixels as ``[x, y]`` with pixel centres at integer positions (the OpenCV
convention): ``image[row, col]`` is centred on ``x = col, y = row``. The same arguments
and seed always give the same scene.
"""

from service.synthetic.layout import MIN_CROSSING_ANGLE
from service.synthetic.scene import MAX_CABLES, MIN_CABLE_RADIUS, MIN_IMAGE_SIDE, make_scene
from service.synthetic.scene_types import (
    Occluder,
    SyntheticCable,
    SyntheticCrossing,
    SyntheticScene,
)

__all__ = [
    "MAX_CABLES",
    "MIN_CABLE_RADIUS",
    "MIN_CROSSING_ANGLE",
    "MIN_IMAGE_SIDE",
    "Occluder",
    "SyntheticCable",
    "SyntheticCrossing",
    "SyntheticScene",
    "make_scene",
]
