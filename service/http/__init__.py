"""The HTTP service: ``create_app(settings) -> FastAPI`` and its :class:`Settings`.

Routes: ``POST /v1/detect`` (Detection JSON), ``POST /v1/detect/overlay`` (PNG),
``POST /v1/detect/labels`` (16-bit PNG), ``POST /v1/grasp`` (GraspPlan JSON),
``POST /v1/model`` (MJCF), ``GET /v1/live/cameras`` and the WebSocket ``/v1/live/{camera}``
(the viewer's live mode), ``GET /`` (the viewer page), ``GET /healthz``, ``GET /readyz``,
``GET /metrics`` (Prometheus), ``/docs`` (OpenAPI).
Detection runs in a bounded thread pool; when it and its queue are full, requests are
refused at once with 503 and ``Retry-After``. The detection runtime itself (jobs, pool,
metrics, settings) is :mod:`service.runtime`, shared with the zenoh bus.
"""

from service.http.app import create_app
from service.runtime.settings import Settings

__all__ = ["Settings", "create_app"]
