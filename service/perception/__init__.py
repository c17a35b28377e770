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
compiled_ahead_of_time(group="detection") -> bool
    Whether the kernels of ``group`` run compiled ahead of time in this process (a
    build of ``python -m service.build_kernels`` for these kernel sources), without numba.
kernels_cached(group="detection") -> bool
    Whether the kernels are already compiled into numba's cache on this machine (a
    cheap check, before ``warm_up``, for front ends that say when a run compiles); other
    groups are sets of kernels with warm-ups of their own (``service.console.KERNEL_SETS``).
Tracker(params=None, track_params=None)
    Follows cables through a video: ``tracker.update(image)`` detects and returns the
    frame's :class:`schemas.Tracks`; :func:`advance` is the same step as a pure function
    of a :class:`TrackerState` (see :mod:`service.perception.tracking`).
"""

import sys as _sys

from service.perception import _aot

# Before any step module imports its kernels: run the ahead-of-time compiled ones when a
# fresh build is there (see service.perception._aot), else numba's.
_aot.install(_sys.modules[__name__])
compiled_ahead_of_time = _aot.covers

from service.perception._kernel_cache import kernels_cached  # noqa: E402
from service.perception.deadline import Deadline, DeadlineExceeded  # noqa: E402
from service.perception.errors import InvalidInputError  # noqa: E402
from service.perception.pipeline import DetectionResult, detect, detect_full, warm_up  # noqa: E402
from service.perception.render import render_labels, render_overlay  # noqa: E402
from service.perception.tracking import Tracker, TrackerState, advance, new_state  # noqa: E402

__all__ = [
    "Deadline",
    "DeadlineExceeded",
    "DetectionResult",
    "InvalidInputError",
    "Tracker",
    "TrackerState",
    "advance",
    "compiled_ahead_of_time",
    "detect",
    "detect_full",
    "kernels_cached",
    "new_state",
    "render_labels",
    "render_overlay",
    "warm_up",
]
