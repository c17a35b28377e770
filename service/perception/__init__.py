"""The perception core: pure functions from arrays to :class:`schemas.Detection`.

Public API
----------
detect(image, params=None, mask=None) -> Detection
    The whole six-step pipeline.
detect_full(image, params=None, mask=None) -> DetectionResult
    The same, also returning the foreground mask it used (for ``render_labels``).
render_labels(detection, mask, image=None) -> np.ndarray (uint16)
render_overlay(image, detection) -> np.ndarray (BGR uint8)
"""

from service.perception.errors import InvalidInputError
from service.perception.pipeline import DetectionResult, detect, detect_full
from service.perception.render import render_labels, render_overlay

__all__ = [
    "DetectionResult",
    "InvalidInputError",
    "detect",
    "detect_full",
    "render_labels",
    "render_overlay",
]
