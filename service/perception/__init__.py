"""The perception core: pure functions from arrays to :class:`schemas.Detection`.

Public API
----------
detect(image, params=None, mask=None, *, segmenter=None, deadline=None) -> Detection
    The whole pipeline; ``deadline`` (a :class:`Deadline`) is an optional time budget,
    past which it raises :class:`DeadlineExceeded`.
detect_full(image, params=None, mask=None, *, segmenter=None, deadline=None) -> DetectionResult
    The same, also returning the foreground mask it used (for ``render_labels``).
render_labels(detection, mask, image=None) -> np.ndarray (uint16)
render_overlay(image, detection) -> np.ndarray (BGR uint8)
warm_up() -> None
    Load (on a machine's first run: compile) every compiled kernel, so that the next
    detection's timings are detection time alone.
kernels_cached(group="detection") -> bool
    Whether the kernels are already compiled into numba's cache on this machine (a
    cheap check, before ``warm_up``, for front ends that say when a run compiles); other
    groups are sets of kernels with warm-ups of their own (``service.console.KERNEL_SETS``).
"""

from service.perception._kernel_cache import kernels_cached
from service.perception.deadline import Deadline, DeadlineExceeded
from service.perception.errors import InvalidInputError
from service.perception.pipeline import DetectionResult, detect, detect_full, warm_up
from service.perception.render import render_labels, render_overlay

__all__ = [
    "Deadline",
    "DeadlineExceeded",
    "DetectionResult",
    "InvalidInputError",
    "detect",
    "detect_full",
    "kernels_cached",
    "render_labels",
    "render_overlay",
    "warm_up",
]
