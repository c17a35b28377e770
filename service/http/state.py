"""What one running HTTP service holds: settings, metrics, the worker pool, the zenoh bus
and readiness."""

from __future__ import annotations

import asyncio
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from service.runtime.jobs import DetectFunction
from service.runtime.metrics import Metrics
from service.runtime.pool import WorkerPool
from service.runtime.settings import Settings

if TYPE_CHECKING:
    from service.bus.detection import DetectionBus
    from service.bus.live import LiveHub
    from service.perception.segmenter import Segmenter


@dataclass
class AppState:
    """Everything the routes need, created by the app's lifespan.

    The zenoh front end (:class:`service.bus.DetectionBus`, in ``bus`` when enabled)
    shares the metrics and the detect function; it runs detection in a thread of its own.
    """

    settings: Settings
    metrics: Metrics
    detect: DetectFunction
    pool: WorkerPool
    api_token: str | None = None
    """The bearer token required on /v1/* (:mod:`service.http.auth`); None: open."""
    segmenter: Segmenter | None = None
    """The model for ``segmentation=model`` (``DLO_SEGMENTER_MODEL``), for the routes that
    run the pipeline themselves (the label image); None: none loaded."""
    ready: bool = False
    warm_up_error: str | None = None
    background: list[asyncio.Task[Any] | Future[Any]] = field(default_factory=list)
    bus: DetectionBus | None = None
    bus_error: str | None = None
    live: LiveHub | None = None
    """The viewer's live mode on the bus's session, made on first use (:mod:`.live`)."""

    @property
    def bus_ready(self) -> bool:
        """True when zenoh is disabled, or its session is open."""
        return not self.settings.zenoh or (self.bus is not None and self.bus.is_open)

    @classmethod
    def start(
        cls,
        settings: Settings,
        metrics: Metrics,
        detect: DetectFunction,
        api_token: str | None = None,
        segmenter: Segmenter | None = None,
    ) -> AppState:
        pool = WorkerPool(settings.workers, settings.queue_size)
        metrics.in_flight.set_function(lambda: pool.admitted)
        return cls(
            settings=settings,
            metrics=metrics,
            detect=detect,
            pool=pool,
            api_token=api_token,
            segmenter=segmenter,
        )

    async def close(self) -> None:
        for task in self.background:
            task.cancel()
        if self.live is not None:
            self.live.close()
        if self.bus is not None:
            await asyncio.to_thread(self.bus.close)
        self.pool.shutdown()
