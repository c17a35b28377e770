"""The detection runtime under both transports (HTTP in :mod:`service.http`, zenoh in
:mod:`service.bus`): what one request is (:class:`Frame`), why it is refused
(:class:`RequestError`), the jobs run for it (decode, detect, render, plan a grasp), the
bounded worker pool, the metrics and the settings.

It imports neither transport, so each can run without the other.
"""

from service.runtime.errors import RequestError
from service.runtime.frames import Frame, check_frame, check_upload, image_size
from service.runtime.jobs import DetectFunction, default_detect, run_detection, run_overlay
from service.runtime.metrics import Metrics
from service.runtime.pool import PoolBusyError, WorkerPool
from service.runtime.settings import Settings

__all__ = [
    "DetectFunction",
    "Frame",
    "Metrics",
    "PoolBusyError",
    "RequestError",
    "Settings",
    "WorkerPool",
    "check_frame",
    "check_upload",
    "default_detect",
    "image_size",
    "run_detection",
    "run_overlay",
]
